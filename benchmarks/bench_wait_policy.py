"""OpenMP threads that sleep when idle (``OMP_WAIT_POLICY=PASSIVE``, marlcrash's default) against threads that spin.

A marlcrash process holds two OpenMP runtimes: the system's libgomp, which runs numba's parallel kernels, and the
copy torch bundles. Each keeps its own pool of worker threads, and with the ``ACTIVE`` policy (libgomp's behaviour
when the variable is unset) the threads of one pool spin on the cores after a parallel region while the other's
work waits for them: the torch work between the simulator's numba kernels. ``import marlcrash`` therefore sets
``OMP_WAIT_POLICY=PASSIVE`` unless the variable is set already (a user's value is kept).

This script times the same batched simulation (``Surrogate.run``, numba backend, per-cell energies at the final step,
as the environments run it) in child processes with each policy, interleaved round by round, and prints per round the
median wall time, the part spent outside the numba kernel, and the ratio ACTIVE / PASSIVE. ``--busy N`` runs N
busy-looping processes beside the timed one, as on a machine shared with other work.

Usage: python benchmarks/bench_wait_policy.py [--batch 48] [--repeat 5] [--rounds 3] [--busy 0] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

POLICIES = ("ACTIVE", "PASSIVE")


def _child(batch: int, repeat: int) -> dict[str, float]:
    """Median wall and outside-the-kernel time [s] of ``repeat`` simulations of ``batch`` rows (after a warm-up)."""
    import torch

    from marlcrash.cells import discretize
    from marlcrash.sim import Surrogate, get_scenario, kernels
    from marlcrash.vehicle.synthetic import default_vehicle

    cells = discretize(default_vehicle())
    sim, scenario = Surrogate(cells), get_scenario("full_width_40")
    params = torch.as_tensor(cells.params)[None].repeat(batch, 1, 1)
    sim.run(params, scenario, backend="numba", record_cells="final")  # compile and warm the caches
    wall, other = [], []
    for _ in range(repeat):
        k0, t0 = kernels.KERNEL_SECONDS[0], time.perf_counter()
        sim.run(params, scenario, backend="numba", record_cells="final")
        t = time.perf_counter() - t0
        wall.append(t)
        other.append(t - (kernels.KERNEL_SECONDS[0] - k0))
    return {"wall_s": statistics.median(wall), "outside_kernel_s": statistics.median(other)}


def _timed(policy: str, batch: int, repeat: int) -> dict[str, float]:
    env = {**os.environ, "OMP_WAIT_POLICY": policy, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, __file__, "--child", "--batch", str(batch), "--repeat", str(repeat)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"the {policy} child failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def study(batch: int, repeat: int, rounds: int, busy: int) -> dict:
    """Per round, each policy's child times, and the ratios ACTIVE / PASSIVE (above 1: PASSIVE is faster)."""
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        rows = []
        for r in range(rounds):
            got = {p: _timed(p, batch, repeat) for p in (POLICIES if r % 2 == 0 else POLICIES[::-1])}
            ratio = got["ACTIVE"]["wall_s"] / got["PASSIVE"]["wall_s"]
            rows.append({"round": r + 1, **{p: got[p] for p in POLICIES}, "wall_ratio_active_over_passive": ratio})
    finally:
        for p in spin:
            p.kill()
    return {"batch": batch, "repeat": repeat, "busy": busy, "rounds": rows}


def main() -> None:
    from marlcrash.cli import _batch_size, _positive_int

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=_batch_size, default=48, help="simulations per timed run (the main job's 48)")
    ap.add_argument("--repeat", type=_positive_int, default=5, help="timed runs per child; each reports the median")
    ap.add_argument("--rounds", type=_positive_int, default=3, help="interleaved rounds of both policies")
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes beside the timed one")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(args.batch, args.repeat)))
        return
    if args.busy < 0:
        ap.error(f"argument --busy: expected an integer >= 0, got {args.busy}")
    res = study(args.batch, args.repeat, args.rounds, args.busy)
    if args.json:
        print(json.dumps(res, indent=1))
        return
    print(f"B = {res['batch']}, {res['busy']} busy processes beside; median of {res['repeat']} runs per child")
    for row in res["rounds"]:
        cells = "  ".join(f"{p} {1e3 * row[p]['wall_s']:7.1f} ms ({1e3 * row[p]['outside_kernel_s']:6.1f} outside "
                          "the kernel)" for p in POLICIES)  # fmt: skip
        print(f"round {row['round']}: {cells}  ratio {row['wall_ratio_active_over_passive']:.2f}")


if __name__ == "__main__":
    main()
