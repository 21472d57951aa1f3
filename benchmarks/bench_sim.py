"""Surrogate throughput: complete 150 ms simulations per second at B = 1, 64, 1024.

Builds a synthetic ~531-cell, ~1600-link block (tests/sim_fixtures.vehicle_block),
then times the fused numba kernel (environment forward, per-cell energies at the
final step only) and the differentiable torch reference (forward, and forward +
backward), and prints ratios measured in this one run.

Usage: python benchmarks/bench_sim.py [--substeps N] [--batches 1 64 1024] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from sim_fixtures import vehicle_block  # noqa: E402

from marlcrash.sim import Surrogate, get_scenario, load_sim_config  # noqa: E402


def _time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--substeps", type=int, default=None, help="override configs/sim.yaml substeps")
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    ap.add_argument("--torch-batches", type=int, nargs="+", default=[1, 64])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    overrides = {} if args.substeps is None else {"substeps": args.substeps}
    cfg = load_sim_config(overrides=overrides)
    cells = vehicle_block()
    sim = Surrogate(cells, cfg)
    scenario = get_scenario("full_width_56")
    steps = (scenario.n_outputs - 1) * cfg.substeps
    print(
        f"model: {cells.n_cells} cells ({cells.n_null} null), {cells.n_links} links; "
        f"{steps} steps of {sim.dt * 1e3:.3f} ms; torch threads {torch.get_num_threads()}"
    )
    base = torch.as_tensor(cells.params)
    sim.run(base[None], scenario, backend="numba", record_cells="final")  # compile / load cache
    rates: dict[tuple[str, int], float] = {}
    for B in args.batches:
        p = base[None].repeat(B, 1, 1)
        t = _time(lambda p=p: sim.run(p, scenario, backend="numba", record_cells="final"), args.repeat)
        rates["numba", B] = B / t
        mlu = B * steps * cells.n_links / t / 1e6
        print(f"numba  B={B:5d}: {B / t:9.1f} sims/s  ({t * 1e3:8.1f} ms/batch, {mlu:7.1f} M link-updates/s)")
    for B in args.torch_batches:
        p = base[None].repeat(B, 1, 1)
        with torch.no_grad():
            t = _time(lambda p=p: sim.run(p, scenario, backend="torch", record_cells="final"), 1)
        rates["torch", B] = B / t
        print(f"torch  B={B:5d}: {B / t:9.1f} sims/s  (forward, no grad)")
        pg = p.clone().requires_grad_(True)

        def fwd_bwd(pg=pg):
            out = sim.run(pg, scenario, backend="torch", record_cells="none")
            out.velocity.square().mean().backward()

        t = _time(fwd_bwd, 1)
        rates["torch+grad", B] = B / t
        print(f"torch  B={B:5d}: {B / t:9.1f} sims/s  (forward + backward)")
    print("ratios (measured in this run):")
    bmax = max(args.batches)
    for B in args.batches:
        print(f"  numba B={B} / numba B=1: {rates['numba', B] / rates['numba', 1]:.1f}x")
    for B in args.torch_batches:
        if ("numba", B) in rates:
            print(f"  numba / torch forward at B={B}: {rates['numba', B] / rates['torch', B]:.1f}x")
            print(f"  numba / torch forward+backward at B={B}: {rates['numba', B] / rates['torch+grad', B]:.1f}x")
    target = 1000.0
    best = rates["numba", bmax]
    print(f"  numba B={bmax}: {best:.0f} sims/s = {best / target:.2f}x the {target:.0f} sims/s target")


if __name__ == "__main__":
    main()
