"""Gradients of the sensor velocities: the compiled adjoint against torch autograd, in one run.

Times forward plus backward of a weighted sum of the sensor velocities over a full 150 ms crash of the
default car (``full_width_40``) for ``B`` random parameter sets with ``backend="adjoint"``
(:mod:`marlcrash.sim.adjoint`) and ``backend="torch"`` (autograd over the explicit steps), interleaved
``--repeat`` times, and prints seconds per candidate, their ratio, the largest relative difference of
the two gradients and the process's peak resident memory after each path (the adjoint runs first, so
its figure is not inflated by torch's graph).

Usage: python benchmarks/bench_adjoint.py [--batch 4] [--repeat 2] [--json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import sys
import time
from pathlib import Path
from typing import Literal

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from marlcrash.cells import discretize
from marlcrash.cli import _batch_size, _positive_int
from marlcrash.sim import Surrogate, get_scenario
from marlcrash.vehicle.synthetic import default_vehicle


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # Linux: kB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=_batch_size, default=4, help="candidates per call (the gradient baseline's 4)")
    ap.add_argument("--repeat", type=_positive_int, default=2, help="interleaved rounds; the best of each path is kept")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()

    cells = discretize(default_vehicle())
    sim = Surrogate(cells)
    sc = get_scenario("full_width_40")
    g = torch.Generator().manual_seed(0)
    base = torch.as_tensor(cells.params, dtype=torch.float64)
    p0 = base[None] * torch.exp(0.2 * torch.randn(args.batch, *base.shape, generator=g, dtype=torch.float64))
    w = torch.randn(args.batch, len(cells.sensor_names), sc.n_outputs, generator=g, dtype=torch.float64)

    def grad(backend: Literal["adjoint", "torch"], rows: int = args.batch, scenario=sc) -> tuple[float, torch.Tensor]:
        p = p0[:rows].clone().requires_grad_(True)
        t0 = time.perf_counter()
        res = sim.run(p, scenario, record_cells="none", backend=backend)
        (res.velocity * w[:rows, :, : scenario.n_outputs]).sum().backward()
        assert p.grad is not None  # p requires grad and the sensor velocities depend on it
        return time.perf_counter() - t0, p.grad

    grad("adjoint")  # compile or load the numba cache
    # torch's first backward pays for its own set-up (--repeat 1 timed it cold); one row over 10 ms keeps the warm-up
    # out of the peak memory measured after the adjoint
    grad("torch", 1, dataclasses.replace(sc, duration=0.01))
    best = {"adjoint": float("inf"), "torch": float("inf")}
    rss: dict[str, float] = {}
    grads = {}
    for _ in range(max(args.repeat, 1)):
        for backend in ("adjoint", "torch"):
            t, gr = grad(backend)
            best[backend] = min(best[backend], t)
            grads[backend] = gr
            rss.setdefault(backend, peak_rss_gb())
    diff = float((grads["adjoint"] - grads["torch"]).norm() / grads["torch"].norm())
    out = {
        "batch": args.batch,
        "steps_per_sim": (sc.n_outputs - 1) * sim.config.substeps,
        "s_per_candidate_adjoint": best["adjoint"] / args.batch,
        "s_per_candidate_torch": best["torch"] / args.batch,
        "torch_over_adjoint": best["torch"] / best["adjoint"],
        "gradient_rel_difference": diff,
        "peak_rss_gb_after_adjoint": rss["adjoint"],
        "peak_rss_gb_after_torch": rss["torch"],
    }
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"default car, full_width_40, 150 ms ({out['steps_per_sim']} steps), B = {args.batch}, best of "
          f"{args.repeat} interleaved rounds")  # fmt: skip
    print(f"adjoint: {out['s_per_candidate_adjoint']:.3f} s per candidate, peak RSS {rss['adjoint']:.2f} GB")
    print(f"torch:   {out['s_per_candidate_torch']:.3f} s per candidate, peak RSS {rss['torch']:.2f} GB")
    print(f"torch / adjoint: {out['torch_over_adjoint']:.1f}x; gradients differ by {diff:.1e} (relative norm)")


if __name__ == "__main__":
    main()
