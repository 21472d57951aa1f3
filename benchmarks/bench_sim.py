"""Surrogate throughput on the default car: complete 150 ms simulations per second, with ratios from one run.

Builds the DEFAULT car's optimized CellModel (``discretize(default_vehicle())``), times the fused numba
kernel at B = 1, 64, 1024 (environment forward, per-cell energies at the final step only), the uniform
(fine) model at B = 64, the share of wall time spent outside the numeric kernel (parameter checks,
element properties, layout changes), and a roofline: a fused numba pass over the same ``[chunks, L, lanes]``
link arrays with the same step count and about the same arithmetic per link (one elastic-plastic update,
work accumulation, scatter of forces to both end nodes), without the model's logic. Achieved rates are
printed as fractions of that roofline, all measured in this one run.

Usage: python benchmarks/bench_sim.py [--batches 1 64 1024] [--repeat 2] [--skip-uniform]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import marlcrash.sim.kernels as kernels  # noqa: E402
from marlcrash.cells import discretize  # noqa: E402
from marlcrash.sim import Surrogate, get_scenario, load_sim_config  # noqa: E402
from marlcrash.vehicle.synthetic import default_vehicle  # noqa: E402


@numba.njit(cache=True, fastmath=True, parallel=True)
def _roofline(k, y, src, dst, n, n_steps):
    """Link-update roofline: ``[chunks, L, lanes]`` elastic-plastic update + scatter, no model logic."""
    n_chunks, L, CH = k.shape
    total = 0.0
    for ch in numba.prange(n_chunks):
        f = np.zeros((L, CH))
        w = np.zeros((L, CH))
        ds = np.full((n, CH), 1e-5)
        force = np.zeros((n, CH))
        for _ in range(n_steps):
            for l in range(L):
                a = src[l]
                c = dst[l]
                for j in range(CH):
                    dd = ds[c, j] - ds[a, j]
                    ft = f[l, j] + k[ch, l, j] * dd
                    fn = min(max(ft, -y[ch, l, j]), y[ch, l, j])
                    w[l, j] += 0.5 * (f[l, j] + fn) * dd
                    f[l, j] = fn
                    force[a, j] += fn
                    force[c, j] -= fn
            for i in range(n):
                for j in range(CH):
                    ds[i, j] = 1e-12 * force[i, j]
                    force[i, j] = 0.0
        total += w.sum()
    return total


def _time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--skip-uniform", action="store_true", help="do not time the uniform (fine) model")
    args = ap.parse_args()
    cfg = load_sim_config()
    vehicle = default_vehicle()
    cells = discretize(vehicle)
    sim = Surrogate(cells, cfg)
    scenario = get_scenario("full_width_56")
    steps = (scenario.n_outputs - 1) * cfg.substeps
    print(
        f"default car: {cells.n_cells} cells ({cells.n_null} null), {cells.n_links} links; "
        f"{steps} steps of {sim.dt * 1e6:.1f} us; numba threads {numba.get_num_threads()}"
    )
    base = torch.as_tensor(cells.params)
    sim.run(base[None], scenario, backend="numba", record_cells="final")  # compile / load cache

    kernel_time = [0.0]
    inner = kernels._simulate

    def timed(*a):
        t0 = time.perf_counter()
        inner(*a)
        kernel_time[0] += time.perf_counter() - t0

    rates: dict[int, float] = {}
    kernels._simulate = timed
    try:
        for B in args.batches:
            p = base[None].repeat(B, 1, 1)
            kernel_time[0] = 0.0
            t = _time(lambda p=p: sim.run(p, scenario, backend="numba", record_cells="final"), args.repeat)
            share = 1.0 - kernel_time[0] / args.repeat / t
            rates[B] = B / t
            mlu = B * steps * cells.n_links / t / 1e6
            print(
                f"numba B={B:5d}: {B / t:9.1f} sims/s ({t * 1e3:9.1f} ms/batch, {mlu:7.1f} M link-updates/s, "
                f"~{100 * max(share, 0.0):.0f} % outside the kernel)"
            )
    finally:
        kernels._simulate = inner

    bmax = max(args.batches)
    lanes = min(kernels.CHUNK, bmax)
    n_chunks = -(-bmax // lanes)
    rng = np.random.default_rng(0)
    k = rng.uniform(1e5, 1e6, (n_chunks, cells.n_links, lanes))
    y = rng.uniform(1e3, 1e4, (n_chunks, cells.n_links, lanes))
    src, dst = cells.link_src.astype(np.int64), cells.link_dst.astype(np.int64)
    _roofline(k[:1], y[:1], src, dst, cells.n_cells, 2)
    t = _time(lambda: _roofline(k, y, src, dst, cells.n_cells, steps), 1)
    roof = n_chunks * lanes / t
    print(f"roofline (fused link pass, B={bmax}): {roof:9.1f} sims/s equivalent")

    if not args.skip_uniform:
        fine = discretize(vehicle, method="uniform")
        usim = Surrogate(fine, cfg)
        up = torch.as_tensor(fine.params)[None].repeat(64, 1, 1)
        usim.run(up[:1], scenario, backend="numba", record_cells="final")
        tu = _time(lambda: usim.run(up, scenario, backend="numba", record_cells="final"), 1)
        rates[-64] = 64 / tu
        print(f"uniform model ({fine.n_cells} cells, {fine.n_links} links) B=64: {64 / tu:9.1f} sims/s")

    print("ratios (measured in this run):")
    for B in args.batches:
        print(f"  numba B={B} / numba B={args.batches[0]}: {rates[B] / rates[args.batches[0]]:.1f}x")
    print(f"  numba B={bmax} / roofline: {rates[bmax] / roof:.2f}")
    if -64 in rates and 64 in rates:
        print(f"  optimized / uniform model at B=64: {rates[64] / rates[-64]:.1f}x")
    target = 1000.0
    print(f"  numba B={bmax}: {rates[bmax]:.0f} sims/s = {rates[bmax] / target:.2f}x the {target:.0f} sims/s target")


if __name__ == "__main__":
    main()
