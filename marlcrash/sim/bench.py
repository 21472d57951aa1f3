"""Surrogate throughput benchmark on the default car, with a roofline measured in the same run (DESIGN 8).

:func:`run_benchmark` builds the DEFAULT car's optimized and uniform CellModels
(``discretize(default_vehicle())``), times complete simulations of the ``full_width_56``
window (150 ms at 2 kHz) with the numba fast path as the environments call it (per-cell
energies at the final step only), and measures on this machine, in the same run, a
*roofline*: a fused numba pass over the same ``[chunk, L, fields, lanes]`` link arrays with
the same step count and the same arithmetic per link-step (return-mapped elastic-plastic
force, plastic work, damping, stored energy, scatter of the force to both end nodes) but
none of the model's logic (saturation, wall contact, ledgers, outputs). Achieved rates are
reported as ratios to it, so the numbers compare across machines.
"""

from __future__ import annotations

import time

import numba
import numpy as np
import torch

from marlcrash.sim import kernels
from marlcrash.sim.scenario import get_scenario
from marlcrash.sim.surrogate import Surrogate, load_sim_config

SCENARIO = "full_width_56"
"""Load case timed (its 150 ms window and 2 kHz output define the step count)."""


@numba.njit(cache=True, fastmath=kernels._FASTMATH, parallel=True)
def _roofline(lp, src, dst, n, n_steps, cst):
    """Link-update roofline: ``lp [C, L, N_PROP, lanes]``; elastic-plastic update + scatter, no model logic."""
    n_chunks, L, _, CH = lp.shape
    half, zero, inv_dt = cst[0], cst[1], cst[3]
    total = np.zeros(n_chunks)
    for ch in numba.prange(n_chunks):
        P = lp[ch]
        f = np.zeros((L, CH), lp.dtype)
        ds = np.zeros((n, CH), lp.dtype)
        fs = np.zeros((n, CH), lp.dtype)
        fd = np.zeros((n, CH), lp.dtype)
        plastic = np.zeros((n, CH), lp.dtype)
        st = np.zeros(CH, lp.dtype)
        for _ in range(n_steps):
            for ll in range(L):
                a = src[ll]
                c = dst[ll]
                for j in range(CH):
                    dd = ds[c, j] - ds[a, j]
                    y = P[ll, kernels.P_YC, j]
                    ft = f[ll, j] + P[ll, kernels.P_K0, j] * dd
                    fn = min(max(ft, -y), y)
                    plastic[a, j] += fn * (ft - fn) * P[ll, kernels.P_IK0, j]
                    f[ll, j] = fn
                    st[j] += half * fn * fn * P[ll, kernels.P_IK0, j]
                    ftot = fn + (P[ll, kernels.P_DAMP, j] * dd * inv_dt if ft == fn else zero)
                    fs[a, j] += ftot
                    fd[c, j] += ftot
            for i in range(n):
                for j in range(CH):
                    ds[i, j] = 1e-12 * (fs[i, j] - fd[i, j])
                    fs[i, j] = zero
                    fd[i, j] = zero
        total[ch] = st.sum() + plastic.sum()
    return total.sum()


def _best(fn, repeats: int) -> float:
    """Best wall time of ``repeats`` calls [s]."""
    best = float("inf")
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure_roofline(sim: Surrogate, batch: int, n_steps: int, repeats: int = 1) -> float:
    """Roofline of this machine in complete simulations per second at ``batch`` (see module doc).

    Args:
        sim: the surrogate whose link count, node count, dtype and chunk width are used.
        batch: simulations ``B``.
        n_steps: explicit steps per simulation.
        repeats: timed runs (best is kept).
    """
    npdt = np.float32 if sim.dtype == torch.float32 else np.float64
    lanes = min(kernels.default_lanes(sim.L, np.dtype(npdt).itemsize, 1), batch)
    n_chunks = -(-batch // lanes)
    rng = np.random.default_rng(0)
    lp = rng.uniform(1e3, 1e5, (n_chunks, sim.L, kernels.N_PROP, lanes)).astype(npdt)
    lp[:, :, kernels.P_IK0] = 1.0 / lp[:, :, kernels.P_K0]
    src = sim.src.numpy()[sim.link_order]
    dst = sim.dst.numpy()[sim.link_order]
    cst = np.array([0.5, 0.0, 1.0, 1.0 / sim.dt, sim.dt, kernels._BIG], dtype=npdt)
    _roofline(lp[:1], src, dst, sim.n, 2, cst)  # compile or load the cache
    t = _best(lambda: _roofline(lp, src, dst, sim.n, n_steps, cst), repeats)
    return n_chunks * lanes / t


def run_benchmark(
    batch_sizes: tuple[int, ...] = (1, 64, 1024),
    repeats: int = 2,
    include_uniform: bool = True,
    sim_overrides: dict | None = None,
) -> dict:
    """Throughput of the surrogate on the default car, with ratios measured in this run.

    Args:
        batch_sizes: batch sizes ``B`` timed on the optimized model.
        repeats: timed runs per batch size (best is kept); the JIT is warmed up first.
        include_uniform: also time the uniform (fine) model at ``B = 64``.
        sim_overrides: dotted-key overrides of ``configs/sim.yaml`` (e.g. ``{"dtype": "float32"}``).

    Returns:
        A JSON-serialisable dict: ``sims_per_s_optimized`` (keyed by ``str(B)``),
        ``sims_per_s_uniform_b64`` (or ``None``), ``n_cells_optimized``, ``n_cells_uniform``,
        ``n_links_optimized``, ``steps_per_sim``, ``substeps``, ``dtype``, ``threads``,
        ``link_updates_per_s`` (keyed by ``str(B)``), ``overhead_share`` (keyed by ``str(B)``:
        share of wall time outside the compiled kernel), ``roofline_sims_per_s`` (at the largest
        ``B``), ``roofline_ratio`` (achieved / roofline at the largest ``B``), ``target_sims_per_s``
        and ``target_ratio``.
    """
    from marlcrash.cells import discretize
    from marlcrash.vehicle.synthetic import default_vehicle

    cfg = load_sim_config(overrides=sim_overrides)
    vehicle = default_vehicle()
    cells = discretize(vehicle)
    sim = Surrogate(cells, cfg)
    scenario = get_scenario(SCENARIO)
    steps = (scenario.n_outputs - 1) * cfg.substeps
    base = torch.as_tensor(cells.params)[None]
    sim.run(base, scenario, backend="numba", record_cells="final")  # compile or load the cache

    rates: dict[str, float] = {}
    overhead: dict[str, float] = {}
    updates: dict[str, float] = {}
    for B in batch_sizes:
        p = base.repeat(B, 1, 1)
        best, share = float("inf"), 0.0
        for _ in range(max(repeats, 1)):
            k0 = kernels.KERNEL_SECONDS[0]
            t0 = time.perf_counter()
            sim.run(p, scenario, backend="numba", record_cells="final")
            t = time.perf_counter() - t0
            if t < best:
                best, share = t, max(0.0, 1.0 - (kernels.KERNEL_SECONDS[0] - k0) / t)
        rates[str(B)] = B / best
        overhead[str(B)] = share
        updates[str(B)] = B * steps * cells.n_links / best

    bmax = max(batch_sizes)
    roof = measure_roofline(sim, bmax, steps, repeats=1)

    uniform_rate, n_uniform = None, None
    if include_uniform:
        fine = discretize(vehicle, method="uniform")
        n_uniform = fine.n_cells
        usim = Surrogate(fine, cfg)
        up = torch.as_tensor(fine.params)[None].repeat(64, 1, 1)
        usim.run(up[:1], scenario, backend="numba", record_cells="final")
        uniform_rate = 64 / _best(lambda: usim.run(up, scenario, backend="numba", record_cells="final"), 1)

    target = 1000.0
    return {
        "scenario": SCENARIO,
        "sims_per_s_optimized": rates,
        "sims_per_s_uniform_b64": uniform_rate,
        "n_cells_optimized": cells.n_cells,
        "n_cells_uniform": n_uniform,
        "n_links_optimized": cells.n_links,
        "steps_per_sim": steps,
        "substeps": cfg.substeps,
        "dtype": cfg.dtype,
        "threads": numba.get_num_threads(),
        "link_updates_per_s": updates,
        "overhead_share": overhead,
        "roofline_sims_per_s": roof,
        "roofline_ratio": rates[str(bmax)] / roof,
        "speedup_vs_b1": {k: r / rates[str(min(batch_sizes))] for k, r in rates.items()},
        "optimized_over_uniform_b64": (rates["64"] / uniform_rate) if (uniform_rate and "64" in rates) else None,
        "target_sims_per_s": target,
        "target_ratio": rates[str(bmax)] / target,
    }


def format_benchmark(res: dict) -> str:
    """Render :func:`run_benchmark`'s result as the lines ``marlcrash bench`` prints."""
    lines = [
        f"default car: {res['n_cells_optimized']} cells, {res['n_links_optimized']} links; {res['steps_per_sim']} "
        f"steps per simulation ({res['substeps']} per output step), {res['dtype']}, {res['threads']} threads"
    ]
    for b, rate in res["sims_per_s_optimized"].items():
        lines.append(
            f"B={b:>5}: {rate:9.1f} sims/s, {res['link_updates_per_s'][b] / 1e6:7.1f} M link-updates/s, "
            f"{100 * res['overhead_share'][b]:4.1f} % outside the kernel, {res['speedup_vs_b1'][b]:.1f}x the smallest B"
        )
    lines.append(f"roofline (fused link pass, largest B): {res['roofline_sims_per_s']:.1f} sims/s")
    lines.append(f"achieved / roofline: {res['roofline_ratio']:.2f}")
    if res["sims_per_s_uniform_b64"] is not None:
        lines.append(f"uniform model ({res['n_cells_uniform']} cells) B=64: {res['sims_per_s_uniform_b64']:.1f} sims/s")
        if res["optimized_over_uniform_b64"] is not None:
            lines.append(f"optimized / uniform at B=64: {res['optimized_over_uniform_b64']:.1f}x")
    lines.append(f"largest B vs the {res['target_sims_per_s']:.0f} sims/s target: {res['target_ratio']:.3f}x")
    return "\n".join(lines)
