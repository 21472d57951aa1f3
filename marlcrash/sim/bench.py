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

The roofline pass is the fastest form of that loop found on this machine: the fused loop of the kernel, with its
arrays compiled ``noalias`` (:mod:`marlcrash.sim.noalias`; without that mark LLVM guards every lane loop with
runtime overlap tests of each pair of arrays, once per link). The simulation kernel is compiled the same way.
Before both were, the roofline pass computed a link's lanes into stack scratch and added them to each node array in
a loop of its own, which avoided the tests at the price of extra passes: the fused ``noalias`` pass ran 1.09-1.10x
as fast as that (float64, B = 1024, 3 interleaved rounds, measured once before the scratch form was removed; the
commit before ``njit_noalias`` has it). ``benchmarks/bench_noalias.py`` times both passes against their unmarked
compilation.
"""

from __future__ import annotations

import time
import types as pytypes
from typing import Any

import numba
import numpy as np
import torch

from marlcrash.config import require, require_device
from marlcrash.sim import kernels
from marlcrash.sim.noalias import njit_noalias
from marlcrash.sim.scenario import get_scenario, scenario_tensors
from marlcrash.sim.surrogate import Backend, Surrogate, load_sim_config

SCENARIO = "full_width_56"
"""Load case timed (its 150 ms window and 2 kHz output define the step count)."""


@njit_noalias(cache=True, fastmath=kernels._FASTMATH)
def _roofline_chunk(P, f, ds, fs, fd, plastic, st, src, dst, n_steps, cst):
    """The roofline's link pass over one chunk (``P [L, N_PROP, lanes]``); its arrays are compiled ``noalias``."""
    L, _, CH = P.shape
    n = ds.shape[0]
    half, zero = cst[0], cst[1]
    for _ in range(n_steps):
        for ll in range(L):
            a = src[ll]
            c = dst[ll]
            for j in range(CH):
                dd = ds[c, j] - ds[a, j]
                y = P[ll, kernels.H_YU, j]
                f0 = f[ll, j]
                ft = f0 + P[ll, kernels.H_K, j] * dd
                fn = min(max(ft, -y), y)
                plastic[a, j] += fn * (ft - fn) * P[ll, kernels.H_IK, j]
                tot = fn + P[ll, kernels.H_DC, j] * (fn - f0)
                f[ll, j] = fn
                st[j] += half * fn * fn * P[ll, kernels.H_IK, j]
                fs[a, j] += tot
                fd[c, j] += tot
        for i in range(n):
            for j in range(CH):
                ds[i, j] = 1e-12 * (fs[i, j] - fd[i, j])
                fs[i, j] = zero
                fd[i, j] = zero


@numba.njit(cache=True, fastmath=kernels._FASTMATH, parallel=True)
def _roofline(lp, src, dst, n, n_steps, cst):
    """Link-update roofline: ``lp [C, L, N_PROP, lanes]``; elastic-plastic update + scatter, no model logic."""
    n_chunks, L, _, CH = lp.shape
    total = np.zeros(n_chunks)
    for ch in numba.prange(n_chunks):
        f = np.zeros((L, CH), lp.dtype)
        ds = np.zeros((n, CH), lp.dtype)
        fs = np.zeros((n, CH), lp.dtype)
        fd = np.zeros((n, CH), lp.dtype)
        plastic = np.zeros((n, CH), lp.dtype)
        st = np.zeros(CH, lp.dtype)
        _roofline_chunk(lp[ch], f, ds, fs, fd, plastic, st, src, dst, n_steps, cst)
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


def measure_roofline(
    sim: Surrogate, batch: int, n_steps: int, repeats: int = 1, n_links: int | None = None, link_pass=None
) -> float:
    """Roofline of this machine in complete simulations per second at ``batch`` (see module doc): ``batch`` over the
    best time of ``repeats`` calls of :func:`roofline_pass`. Where it is compared with a kernel's rate, time both in
    turn (:func:`interleaved_best`): a change of the machine's load between two phases goes into their ratio."""
    return batch / _best(roofline_pass(sim, batch, n_steps, n_links, link_pass), repeats)


def interleaved_best(fns: dict[str, Any], repeats: int) -> dict[str, float]:
    """Best wall time [s] of each of ``fns`` over ``repeats`` rounds, each round calling every one in turn: rates
    measured so share the machine's state, and a ratio of two does not take in a change of load between them (timed
    one after the other, the roofline alone moved 2x between two runs)."""
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(max(repeats, 1)):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    return best


def roofline_pass(sim: Surrogate, batch: int, n_steps: int, n_links: int | None = None, link_pass=None):
    """A call of the roofline pass (see module doc) at ``batch``: its arrays made and its code compiled, so calling it
    times the pass alone.

    The pass streams the same chunks as the kernel, the last one padded to the chunk width; like the kernel's rate
    (``batch`` over its time) it counts the ``batch`` simulations asked for, not the padded lanes.

    Args:
        sim: the surrogate whose node count, dtype, springback setting and link ends are used.
        batch: simulations ``B``.
        n_steps: explicit steps per simulation.
        n_links: links streamed per step (default: all of ``sim``; the fast path streams only the links
            with a non-zero transmission share, :func:`live_links`).
        link_pass: the compiled pass timed (default :func:`_roofline`; :func:`noalias_study` passes its unmarked
            compilation).

    Raises:
        ConfigError: ``batch`` is no integer in ``[1, MAX_BATCH]`` (key ``batch``; 0 streamed no chunk and
            reported 0 sims/s).
    """
    from marlcrash.calibrate.baselines import require_batch_size

    require_batch_size(batch, "batch")
    link_pass = _roofline if link_pass is None else link_pass
    npdt = np.float32 if sim.dtype == torch.float32 else np.float64
    L = sim.L if n_links is None else int(n_links)
    nprop = kernels.n_hot(bool(sim.config.springback_relief))
    lanes = kernels.lanes_for(batch, L, sim.n, np.dtype(npdt).name)
    n_chunks = -(-batch // lanes)
    rng = np.random.default_rng(0)
    lp: np.ndarray = rng.uniform(1e3, 1e5, (n_chunks, L, nprop, lanes)).astype(npdt)
    lp[:, :, kernels.H_IK] = 1.0 / lp[:, :, kernels.H_K]
    lp[:, :, kernels.H_DC] = rng.uniform(0.0, 0.1, lp[:, :, kernels.H_DC].shape)  # c / (k dt): a fraction
    src = sim.src.numpy()[sim.link_order][:L]
    dst = sim.dst.numpy()[sim.link_order][:L]
    cst = np.array([0.5, 0.0, 1.0, 1.0 / sim.dt, sim.dt, kernels._BIG], dtype=npdt)
    link_pass(lp[:1], src, dst, sim.n, 2, cst)  # compile or load the cache
    return lambda: link_pass(lp, src, dst, sim.n, n_steps, cst)


def live_links(sim: Surrogate, params: torch.Tensor) -> int:
    """Links the fast path streams for ``params [B, n, 7]``: those with a non-zero share in some row."""
    with torch.no_grad():
        return int((sim.link_props(sim.check_params(params)).yield_c != 0).any(dim=0).sum())


def run_benchmark(
    batch_sizes: tuple[int, ...] = (1, 64, 1024),
    repeats: int = 2,
    include_uniform: bool = True,
    sim_overrides: dict | None = None,
) -> dict:
    """Throughput of the surrogate on the default car, with ratios measured in this run.

    Args:
        batch_sizes: batch sizes ``B`` timed on the optimized model, each in ``[1, MAX_BATCH]``
            (:data:`~marlcrash.calibrate.baselines.MAX_BATCH`).
        repeats: timed runs of every rate (each batch size, the roofline, the uniform model; the best is kept,
            so the ratios compare like with like); the JIT is warmed up first.
        include_uniform: also time the uniform (fine) model at ``B = 64``.
        sim_overrides: dotted-key overrides of ``configs/sim.yaml`` (e.g. ``{"dtype": "float32"}``).

    Returns:
        A JSON-serialisable dict: ``sims_per_s_optimized`` (keyed by ``str(B)``),
        ``sims_per_s_uniform_b64`` (or ``None``), ``n_cells_optimized``, ``n_cells_uniform``,
        ``n_links_optimized``, ``n_links_live`` (links with a non-zero share, the ones streamed),
        ``steps_per_sim``, ``substeps``, ``dtype``, ``threads``,
        ``link_updates_per_s`` (keyed by ``str(B)``), ``overhead_share`` (keyed by ``str(B)``:
        share of wall time outside the compiled kernel), ``roofline_sims_per_s`` (at the largest
        ``B``), ``roofline_ratio`` (achieved / roofline at the largest ``B``: the best time of each, the two timed
        in turn, round by round), ``roofline_ratio_rounds`` (that ratio in each round), ``target_sims_per_s``
        and ``target_ratio``.

    Raises:
        ConfigError: no batch size, or one that is no integer in ``[1, MAX_BATCH]`` (key ``batch_sizes[i]``).
    """
    from marlcrash.calibrate.baselines import require_batch_size
    from marlcrash.cells import discretize
    from marlcrash.vehicle.synthetic import default_vehicle

    require(len(batch_sizes) > 0, "batch_sizes", "expected at least one batch size")
    for i, b in enumerate(batch_sizes):  # before the car is built: a huge one ran into torch's allocation error
        require_batch_size(b, f"batch_sizes[{i}]")
    cfg = load_sim_config(overrides=sim_overrides)
    vehicle = default_vehicle()
    cells = discretize(vehicle)
    sim = Surrogate(cells, cfg)
    scenario = get_scenario(SCENARIO)
    steps = (scenario.n_outputs - 1) * cfg.substeps
    base = torch.as_tensor(cells.params)[None]
    sim.run(base, scenario, backend="numba", record_cells="final")  # compile or load the cache
    live = live_links(sim, base)

    rates: dict[str, float] = {}
    overhead: dict[str, float] = {}
    updates: dict[str, float] = {}
    bmax = max(batch_sizes)
    roof_pass = roofline_pass(sim, bmax, steps, n_links=live)
    roof_times: list[float] = []
    kernel_times: list[float] = []  # at bmax, each timed just before a roofline pass
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
            if p.shape[0] == bmax and len(roof_times) < max(repeats, 1):  # in turn with the kernel (interleaved_best)
                kernel_times.append(t)
                t0 = time.perf_counter()
                roof_pass()
                roof_times.append(time.perf_counter() - t0)
        rates[str(B)] = B / best
        overhead[str(B)] = share
        updates[str(B)] = B * steps * live / best
    roof = bmax / min(roof_times)

    uniform_rate, n_uniform = None, None
    if include_uniform:
        fine = discretize(vehicle, method="uniform")
        n_uniform = fine.n_cells
        usim = Surrogate(fine, cfg)
        up = torch.as_tensor(fine.params)[None].repeat(64, 1, 1)
        usim.run(up[:1], scenario, backend="numba", record_cells="final")
        uniform_rate = 64 / _best(lambda: usim.run(up, scenario, backend="numba", record_cells="final"), repeats)

    target = 1000.0
    return {
        "scenario": SCENARIO,
        "sims_per_s_optimized": rates,
        "sims_per_s_uniform_b64": uniform_rate,
        "n_cells_optimized": cells.n_cells,
        "n_cells_uniform": n_uniform,
        "n_links_optimized": cells.n_links,
        "n_links_live": live,
        "steps_per_sim": steps,
        "substeps": cfg.substeps,
        "dtype": cfg.dtype,
        "threads": numba.get_num_threads(),
        "link_updates_per_s": updates,
        "overhead_share": overhead,
        "roofline_sims_per_s": roof,
        "roofline_ratio": rates[str(bmax)] / roof,
        "roofline_ratio_rounds": [r / k for k, r in zip(kernel_times, roof_times, strict=True)],
        "smallest_b": min(batch_sizes),
        "speedup_vs_smallest_b": {k: r / rates[str(min(batch_sizes))] for k, r in rates.items()},
        "optimized_over_uniform_b64": (rates["64"] / uniform_rate) if (uniform_rate and "64" in rates) else None,
        "target_sims_per_s": target,
        "target_ratio": rates[str(bmax)] / target,
    }


def format_benchmark(res: dict) -> str:
    """Render :func:`run_benchmark`'s result as the lines ``marlcrash bench`` prints."""
    lines = [
        f"default car: {res['n_cells_optimized']} cells, {res['n_links_optimized']} links "
        f"({res['n_links_live']} with a non-zero share); {res['steps_per_sim']} steps per simulation "
        f"({res['substeps']} per output step), {res['dtype']}, {res['threads']} threads"
    ]
    for b, rate in res["sims_per_s_optimized"].items():
        lines.append(
            f"B={b:>5}: {rate:9.1f} sims/s, {res['link_updates_per_s'][b] / 1e6:7.1f} M link-updates/s, "
            f"{100 * res['overhead_share'][b]:4.1f} % outside the kernel, "
            f"{res['speedup_vs_smallest_b'][b]:.1f}x B={res['smallest_b']}"
        )
    lines.append(f"roofline (fused link pass, largest B): {res['roofline_sims_per_s']:.1f} sims/s")
    rounds = res["roofline_ratio_rounds"]
    lines.append(f"achieved / roofline: {res['roofline_ratio']:.2f} (best of each, timed in turn; per round "
                 f"{min(rounds):.2f}-{max(rounds):.2f})")  # fmt: skip
    if res["sims_per_s_uniform_b64"] is not None:
        lines.append(f"uniform model ({res['n_cells_uniform']} cells) B=64: {res['sims_per_s_uniform_b64']:.1f} sims/s")
        if res["optimized_over_uniform_b64"] is not None:
            lines.append(f"optimized / uniform at B=64: {res['optimized_over_uniform_b64']:.1f}x")
    lines.append(f"largest B vs the {res['target_sims_per_s']:.0f} sims/s target: {res['target_ratio']:.3f}x")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ precision
def dtype_study(batch: int = 1024, repeats: int = 3) -> dict:
    """float64 against float32 on the default car, timed in turn within one run (ratios, not absolute rates).

    Each precision runs ``batch`` complete ``full_width_56`` simulations at its own default chunk width
    (:func:`marlcrash.sim.kernels.default_lanes`; 16 lanes in both at large batches) with per-cell
    energies at the final step, as the environments call it; the two alternate for ``repeats`` rounds and
    each keeps its best time. It also reports how far the float32 sensor velocities and crush move from
    float64 (same parameters), the precision cost of the speed.

    Returns:
        ``batch``, ``threads``, ``lanes`` and ``sims_per_s`` (keyed by dtype), ``float32_over_float64``
        (speed ratio), ``max_velocity_diff_ms`` [m/s] and ``max_crush_diff_m`` [m].

    Raises:
        ValueError: ``batch`` or ``repeats`` below 1.
    """
    if batch < 1 or repeats < 1:
        raise ValueError(f"batch and repeats must be >= 1, got {batch} and {repeats}")
    cells = load_sim_cells()
    scenario = get_scenario(SCENARIO)
    base = torch.as_tensor(cells.params)[None]
    threads = numba.get_num_threads()
    sims, lanes, out = {}, {}, {}
    for name in ("float64", "float32"):
        sim = Surrogate(cells, load_sim_config(overrides={"dtype": name}))
        sims[name] = sim
        out[name] = sim.run(base, scenario, backend="numba", record_cells="final")  # compile or load the cache
        lanes[name] = kernels.lanes_for(batch, live_links(sim, base), sim.n, name)
    p = base.repeat(batch, 1, 1)
    best = {name: float("inf") for name in sims}
    for _ in range(repeats):
        for name, sim in sims.items():
            t0 = time.perf_counter()
            sim.run(p, scenario, backend="numba", record_cells="final")
            best[name] = min(best[name], time.perf_counter() - t0)
    rates = {name: batch / t for name, t in best.items()}
    a, b = out["float64"], out["float32"]
    return {
        "batch": batch,
        "threads": threads,
        "lanes": lanes,
        "sims_per_s": rates,
        "float32_over_float64": rates["float32"] / rates["float64"],
        "max_velocity_diff_ms": float((a.velocity - b.velocity.double()).abs().max()),
        "max_crush_diff_m": float((a.crush - b.crush.double()).abs().max()),
    }


def format_dtype_study(res: dict) -> str:
    """The lines of :func:`dtype_study`."""
    r, w = res["sims_per_s"], res["lanes"]
    return "\n".join(
        [
            f"precision study: default car, B={res['batch']}, {res['threads']} threads "
            "(best of the rounds, interleaved)",
            f"float64: {r['float64']:8.1f} sims/s ({w['float64']} lanes)",
            f"float32: {r['float32']:8.1f} sims/s ({w['float32']} lanes)",
            f"float32 / float64: {res['float32_over_float64']:.2f}x",
            f"float32 - float64: sensor velocity up to {res['max_velocity_diff_ms']:.1e} m/s, "
            f"crush up to {res['max_crush_diff_m']:.1e} m",
        ]
    )


# ------------------------------------------------------------------------------------------ device
def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def copy_bandwidth(device: torch.device, dtype: torch.dtype, nbytes: int = 1 << 28, repeats: int = 3) -> float:
    """Bytes per second a device-to-device copy of ``nbytes`` moves on ``device``, read and written counted (best of
    ``repeats``)."""
    x = torch.ones(nbytes // dtype.itemsize, dtype=dtype, device=device)
    y = torch.empty_like(x)
    y.copy_(x)

    def copy():
        y.copy_(x)
        _synchronize(device)

    return 2.0 * x.numel() * x.element_size() / _best(copy, repeats)


def _device_rate(sim: Surrogate, p: torch.Tensor, scenario, backend: Backend, repeats: int) -> float:
    """Complete simulations per second of ``sim`` on ``p`` with ``backend``, waiting for the device (best of
    ``repeats``)."""

    def once():
        sim.run(p, scenario, backend=backend, record_cells="final")
        _synchronize(sim.device)

    return p.shape[0] / _best(once, repeats)


def device_study(
    device: str | torch.device = "cuda",
    batch_sizes: tuple[int, ...] = (1, 64, 1024, 8192),
    dtypes: tuple[str, ...] = ("float64", "float32"),
    repeats: int = 2,
    duration: float | None = None,
) -> dict:
    """The ``torch`` backend, and on a GPU its ``cuda_graph`` replay, on ``device`` (:meth:`Surrogate.to`), default car.

    Times complete ``full_width_56`` simulations (per-cell energies at the final step, no gradient) at each batch
    size and precision, and measures in the same run two limits of that device: the *launch floor* (the eager
    ``torch`` backend's time per integration step at the smallest batch, where the step's few dozen kernels do almost
    no work, so its time is their Python, launch and synchronisation cost) and a *bandwidth roofline* (a device copy's
    bytes per second over the bytes one link-step must move at least: the streamed link fields
    :func:`marlcrash.sim.kernels.n_hot` and the link force read and written, for the live links, as the fused CPU
    kernel streams them; it binds a GPU at large batches, whose link arrays outgrow its cache). It also times the
    compiled CPU kernel (``numba``, all this machine's cores) at the largest batch up to 1024, so the engines
    compare within one run.

    Args:
        device: a torch device (``cpu`` times the eager torch reference path on this machine).
        batch_sizes: ``B`` timed, each in ``[1, MAX_BATCH]``.
        dtypes: simulation precisions timed (``float64``, ``float32``).
        repeats: timed runs of each rate (best kept).
        duration: simulated window [s] (default the scenario's 150 ms; tests pass a short one).

    Returns:
        ``device`` (its name), ``n_cells``, ``n_links_live``, ``steps_per_sim``, ``batch_sizes``, ``backends`` and
        per dtype (keyed by name): ``sims_per_s`` (keyed by backend, then ``str(B)``), ``step_floor_s`` [s per
        step], ``copy_bandwidth_bytes_per_s``, ``roofline_sims_per_s`` (bandwidth-bound, any ``B``),
        ``roofline_ratio`` (each backend's rate at the largest ``B`` over the roofline), ``cpu_numba_sims_per_s``,
        ``cpu_numba_batch`` and ``threads`` (numba's).

    Raises:
        ConfigError: a ``device`` this machine lacks (key ``device``), a batch size out of range
            (``batch_sizes[i]``), an unknown dtype (``dtype``).
    """
    from marlcrash.calibrate.baselines import require_batch_size

    require_device(device, "device")
    require(len(batch_sizes) > 0, "batch_sizes", "expected at least one batch size")
    for i, b in enumerate(batch_sizes):
        require_batch_size(b, f"batch_sizes[{i}]")
    dev = torch.device(device)
    backends: tuple[Backend, ...] = ("torch", "cuda_graph") if dev.type == "cuda" else ("torch",)
    cells = load_sim_cells()
    scenario = get_scenario(SCENARIO, None if duration is None else {"duration": duration})
    base = torch.as_tensor(cells.params)[None]
    bmin, bmax = min(batch_sizes), max(batch_sizes)
    cpu_b = min(bmax, 1024)
    out: dict[str, Any] = {
        "device": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
        "n_cells": cells.n_cells,
        "batch_sizes": list(batch_sizes),
        "backends": list(backends),
        "scenario": scenario.name,
        "duration_s": scenario.duration,
    }
    for name in dtypes:
        cfg = load_sim_config(overrides={"dtype": name})
        steps = (scenario.n_outputs - 1) * cfg.substeps
        cpu_sim = Surrogate(cells, cfg)
        live = live_links(cpu_sim, base)
        sim = Surrogate(cells, cfg).to(dev)
        rates: dict[str, dict[str, float]] = {k: {} for k in backends}
        with torch.no_grad():
            for backend in backends:
                sim.run(base, scenario, backend=backend, record_cells="final")  # CUDA context, allocator, caches
                for B in batch_sizes:
                    rates[backend][str(B)] = _device_rate(sim, base.repeat(B, 1, 1).to(dev), scenario, backend, repeats)
            cpu_sim.run(base, scenario, backend="numba", record_cells="final")  # compile or load the cache
            cpu_rate = _device_rate(cpu_sim, base.repeat(cpu_b, 1, 1), scenario, "numba", repeats)
        bw = copy_bandwidth(dev, cfg.torch_dtype)
        roof = bw / ((kernels.n_hot(bool(cfg.springback_relief)) + 2) * cfg.torch_dtype.itemsize * live * steps)
        out["steps_per_sim"], out["n_links_live"] = steps, live
        out[name] = {
            "sims_per_s": rates,
            "step_floor_s": bmin / rates["torch"][str(bmin)] / steps,
            "copy_bandwidth_bytes_per_s": bw,
            "roofline_sims_per_s": roof,
            "roofline_ratio": {k: r[str(bmax)] / roof for k, r in rates.items()},
            "cpu_numba_sims_per_s": cpu_rate,
            "cpu_numba_batch": cpu_b,
            "threads": numba.get_num_threads(),
        }
    return out


def format_device_study(res: dict) -> str:
    """The lines of :func:`device_study`."""
    lines = [
        f"{res['device']}: default car, {res['n_cells']} cells, {res['n_links_live']} live links, "
        f"{res['steps_per_sim']} steps per {1e3 * res['duration_s']:.0f} ms simulation ({res['scenario']})"
    ]
    bmax = str(max(res["batch_sizes"]))
    for name in ("float64", "float32"):
        if name not in res:
            continue
        r = res[name]
        lines.append(
            f"{name}: eager launch floor {1e6 * r['step_floor_s']:.0f} us per step; copy bandwidth "
            f"{r['copy_bandwidth_bytes_per_s'] / 1e9:.0f} GB/s -> roofline {r['roofline_sims_per_s']:.0f} sims/s"
        )
        for backend, by_b in r["sims_per_s"].items():
            cells = ", ".join(f"B={b}: {rate:.1f}" for b, rate in by_b.items())
            lines.append(f"  {backend:>10}: {cells} sims/s; largest B / roofline {r['roofline_ratio'][backend]:.3f}")
        best = max(by_b[bmax] for by_b in r["sims_per_s"].values())
        lines.append(
            f"  compiled CPU kernel (numba, {r['threads']} threads) B={r['cpu_numba_batch']}: "
            f"{r['cpu_numba_sims_per_s']:.1f} sims/s; the best at B={bmax} over that: "
            f"{best / r['cpu_numba_sims_per_s']:.2f}x"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ noalias
def _recompiled(disp, parallel: bool = False, **replace):
    """``disp``'s Python function compiled by plain ``numba.njit`` (no ``noalias``), some globals replaced."""
    fn = disp.py_func
    g = {**fn.__globals__, **replace}
    copy = pytypes.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)
    return numba.njit(fastmath=kernels._FASTMATH, parallel=parallel)(copy)


def noalias_study(batch: int = 1024, repeats: int = 3, dtype: str = "float64") -> dict:
    """The fast path and the roofline pass with their arrays compiled ``noalias`` against the same code without.

    :mod:`marlcrash.sim.noalias` marks the array arguments of the kernel's per-chunk function
    (:func:`marlcrash.sim.kernels._chunk`) and of the roofline's (:func:`_roofline_chunk`) as not overlapping. This
    recompiles both from their own source with plain ``numba.njit`` and times the four in turn within one run
    (``batch`` complete ``full_width_56`` simulations of the default car, per-cell energies at the final step, as
    the environments call it; each keeps its best of ``repeats`` rounds). The two kernels must give the same numbers
    to rounding: LLVM may contract or vectorize the two compilations differently.

    Returns:
        ``batch``, ``dtype``, ``threads``, ``lanes``, ``noalias_active`` (:data:`marlcrash.sim.noalias.ACTIVE`),
        ``sims_per_s`` (``kernel_noalias``, ``kernel_plain``, ``roofline_noalias``, ``roofline_plain``),
        ``kernel_ratio`` and ``roofline_ratio`` (noalias / plain) and ``max_rel_diff`` (largest difference of any
        output between the two kernels, relative to that output's largest magnitude).

    Raises:
        ValueError: ``batch`` or ``repeats`` below 1, or an unknown ``dtype``.
    """
    from marlcrash.sim import noalias

    if batch < 1 or repeats < 1:
        raise ValueError(f"batch and repeats must be >= 1, got {batch} and {repeats}")
    if dtype not in kernels.LANE_EFFICIENCY:
        raise ValueError(f"dtype must be one of {sorted(kernels.LANE_EFFICIENCY)}, got {dtype!r}")
    cells = load_sim_cells()
    scenario = get_scenario(SCENARIO)
    sim = Surrogate(cells, load_sim_config(overrides={"dtype": dtype}))
    base = torch.as_tensor(cells.params)[None]
    p = base.repeat(batch, 1, 1)
    steps = (scenario.n_outputs - 1) * sim.substeps
    live = live_links(sim, base)
    plain_sim = _recompiled(kernels._simulate, parallel=True, _chunk=_recompiled(kernels._chunk))
    plain_roof = _recompiled(_roofline, parallel=True, _roofline_chunk=_recompiled(_roofline_chunk))

    def kernel(impl):
        saved = kernels._simulate
        kernels._simulate = impl
        try:
            return sim.run(p, scenario, backend="numba", record_cells="final")
        finally:
            kernels._simulate = saved

    def roofline(impl):
        return measure_roofline(sim, batch, steps, n_links=live, link_pass=impl)

    out = {"noalias": kernel(kernels._simulate), "plain": kernel(plain_sim)}  # also compiles
    roofline(plain_roof)
    best = dict.fromkeys(("kernel_noalias", "kernel_plain"), float("inf"))
    roof = dict.fromkeys(("roofline_noalias", "roofline_plain"), 0.0)
    for _ in range(repeats):
        for name, impl in (("kernel_noalias", kernels._simulate), ("kernel_plain", plain_sim)):
            t0 = time.perf_counter()
            kernel(impl)
            best[name] = min(best[name], time.perf_counter() - t0)
        for name, impl in (("roofline_noalias", _roofline), ("roofline_plain", plain_roof)):
            roof[name] = max(roof[name], roofline(impl))
    rates = {**{k: batch / t for k, t in best.items()}, **roof}
    a, b = out["noalias"], out["plain"]
    diff = max(
        float((x - y).abs().max() / x.abs().max().clamp(min=torch.finfo(x.dtype).tiny))
        for x, y in ((a.velocity, b.velocity), (a.crush, b.crush), (a.absorbed, b.absorbed),
                     (a.cell_absorbed, b.cell_absorbed), (a.cell_transmitted, b.cell_transmitted))
    )  # fmt: skip
    return {
        "batch": batch,
        "dtype": dtype,
        "threads": numba.get_num_threads(),
        "lanes": kernels.lanes_for(batch, live, sim.n, dtype),
        "noalias_active": noalias.ACTIVE,
        "sims_per_s": rates,
        "kernel_ratio": rates["kernel_noalias"] / rates["kernel_plain"],
        "roofline_ratio": rates["roofline_noalias"] / rates["roofline_plain"],
        "max_rel_diff": diff,
    }


def format_noalias_study(res: dict) -> str:
    """The lines of :func:`noalias_study`."""
    r = res["sims_per_s"]
    return "\n".join(
        [
            f"noalias study: default car, B={res['batch']}, {res['dtype']}, {res['lanes']} lanes, {res['threads']} "
            f"threads (best of the rounds, interleaved; noalias active: {res['noalias_active']})",
            f"kernel   noalias: {r['kernel_noalias']:8.1f} sims/s   plain: {r['kernel_plain']:8.1f} sims/s   "
            f"ratio {res['kernel_ratio']:.2f}x",
            f"roofline noalias: {r['roofline_noalias']:8.1f} sims/s   plain: {r['roofline_plain']:8.1f} sims/s   "
            f"ratio {res['roofline_ratio']:.2f}x",
            f"kernel noalias - plain: every output within {res['max_rel_diff']:.1e} of its largest magnitude",
        ]
    )


# ------------------------------------------------------------------------------------------ chunk width
def lane_study(
    widths: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64, 128),
    batch: int = 128,
    repeats: int = 3,
    sim_overrides: dict | None = None,
) -> dict:
    """Throughput per simulation of the fast path at each chunk width, measured in one run.

    What :data:`marlcrash.sim.kernels.LANE_EFFICIENCY` holds: the default car, the ``full_width_56``
    window, per-cell energies at the final step. Each width runs ``max(batch, threads * width)``
    simulations, so no width pads a chunk or leaves a core idle; the widths are timed in turn,
    ``repeats`` rounds, and each keeps its best time (timings on a shared machine drift; ratios
    taken within a round do not).

    Returns:
        ``rows`` (``width``, ``batch``, ``sims_per_s``, ``efficiency`` relative to the fastest width),
        ``best_width``, ``threads``, ``dtype`` and ``lane_efficiency_in_use`` (the kernel's table, keyed
        by ``str(width)``).

    Raises:
        ValueError: a width below 1.
    """
    cfg = load_sim_config(overrides=sim_overrides)
    cells = load_sim_cells()
    sim = Surrogate(cells, cfg)
    base = torch.as_tensor(cells.params)[None]
    scenario = get_scenario(SCENARIO)
    threads = numba.get_num_threads()
    names = sim._sensor_index(list(scenario.sensors))
    cases = []
    for w in widths:
        if w < 1:
            raise ValueError(f"chunk widths must be >= 1, got {w}")
        B = max(batch, threads * w)
        p = sim.check_params(base.repeat(B, 1, 1))
        cases.append((w, B, sim.link_props(p), sim.scenario_tensors(B, scenario)))
    kernels.run_numba(sim, *cases[0][2:], scenario.n_outputs, names, "final", lanes=1)  # compile or load the cache
    best = {w: float("inf") for w in widths}
    for _ in range(max(repeats, 1)):
        for w, B, props, wall in cases:
            t0 = time.perf_counter()
            kernels.run_numba(sim, props, wall, scenario.n_outputs, names, "final", lanes=w)
            best[w] = min(best[w], (time.perf_counter() - t0) / B)
    fastest = min(best.values())
    rows = [
        {"width": w, "batch": B, "sims_per_s": 1.0 / best[w], "efficiency": fastest / best[w]} for w, B, _, _ in cases
    ]
    return {
        "rows": rows,
        "best_width": min(best, key=lambda w: best[w]),
        "threads": threads,
        "dtype": cfg.dtype,
        "lane_efficiency_in_use": {str(w): e for w, e in kernels.LANE_EFFICIENCY[cfg.dtype].items()},
    }


def format_lane_study(res: dict) -> str:
    """The table :func:`lane_study` measured, next to the efficiencies the kernel uses."""
    used = res["lane_efficiency_in_use"]
    lines = [f"chunk width study: default car, {res['dtype']}, {res['threads']} threads (best of the rounds)"]
    lines.append(f"{'width':>5} {'batch':>6} {'sims/s':>8} {'efficiency':>10} {'in use':>7}")
    for r in res["rows"]:
        u = used.get(str(r["width"]))
        lines.append(
            f"{r['width']:>5} {r['batch']:>6} {r['sims_per_s']:>8.1f} {r['efficiency']:>10.2f} "
            f"{'-' if u is None else f'{u:.2f}':>7}"
        )
    lines.append(f"fastest width: {res['best_width']}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ step count
PLAUSIBILITY = {
    "peak_g": (20.0, 45.0),
    "crush_m": (0.35, 0.70),
    "t_zero_ms": (50.0, 110.0),
    "rebound": (0.05, 0.20),
}
"""DESIGN 4 ranges for the default car at 40 km/h, full width (as tested in ``tests/test_sim_default_car.py``)."""

PARTIAL = ("offset40_left", "offset40_right", "small_overlap_left", "small_overlap_right")
"""Partial-overlap scenarios that must give a lower peak and a longer pulse than full width at 40 km/h."""


def plausibility_checks(sim: Surrogate, params: torch.Tensor | None = None, run=None) -> dict:
    """Run the default-car plausibility cases of DESIGN 4 with ``sim`` and grade them.

    One batch: full width at 40 km/h, the four partial-overlap scenarios at 40 km/h, and full width
    at 56 km/h. Criteria (those of ``tests/test_sim_default_car.py``): :data:`PLAUSIBILITY` ranges at full
    width 40 (tunnel CFC60 peak, maximum dynamic crush, time to zero velocity, rebound fraction);
    every partial overlap a lower peak and a time to zero velocity at least 10 % longer; 56 km/h
    at least 1.2x the crush of 40 km/h; up-front sensor peaks earlier than the tunnel peak; energy
    balance within 0.5 % at every output step.

    ``known_failures`` grades the up-front sensors' CFC60 peak against 10-150 g apart from ``passed``:
    no setting of this surrogate meets it (the sensor cells stop within 1-2 ms at the wall, about 315 g
    CFC60 on the default car). It used to count and to pass, but only because the simulator's
    acceleration output was its instantaneous value at the 2 kHz samples, aliased far down
    (86-93 g); the output is now the sampled derivative of the velocity
    (:func:`~marlcrash.pulse.signal.sampled_acceleration`).

    ``run(sim, params, **kwargs)`` simulates the batch (default: :meth:`Surrogate.run` on the fast path; the
    implicit study passes :func:`marlcrash.sim.implicit.run_implicit`'s result).

    Returns:
        A JSON-ready dict: ``figures`` (scenario -> crash figures), ``checks`` (criterion -> bool),
        ``passed`` (all checks) and ``known_failures`` (criterion -> bool, not in ``passed``).
    """
    from marlcrash.pulse.simulation import crash_summary

    kmh40 = {"speed_kmh": 40.0}
    scs = [get_scenario("full_width_40")] + [get_scenario(n, kmh40) for n in PARTIAL] + [get_scenario("full_width_56")]
    p = torch.as_tensor(sim.cells.params if params is None else params)
    p = p.reshape(1, sim.n, -1).repeat(len(scs), 1, 1)
    run = run or (lambda sim, p, **kw: sim.run(p, backend="numba", **kw))
    res = run(
        sim,
        p,
        **scenario_tensors(scs),
        duration=scs[0].duration,
        record_cells="final",
    )
    figures = {}
    for i, sc in enumerate(scs):
        f = crash_summary(res, sim.cells, sc, row=i)
        t0 = f["time_to_zero_velocity_ms"]
        figures[f"{sc.name}@{sc.speed_kmh:g}"] = {
            "peak_g": f["peak_decel_g"],
            "t_peak_ms": f["t_peak_ms"],
            "t_zero_ms": float("inf") if t0 is None else t0,
            "crush_m": f["max_crush_m"],
            "rebound": f["rebound_fraction"],
            "balance": f["energy_balance_max_rel_error"],
            "sensors": f["sensors"],
        }
    fw = figures["full_width_40@40"]
    checks = {f"full_width_40 {k} in [{lo:g}, {hi:g}]": lo <= fw[k] <= hi for k, (lo, hi) in PLAUSIBILITY.items()}
    for name in PARTIAL:
        o = figures[f"{name}@40"]
        checks[f"{name} softer and longer"] = o["peak_g"] < fw["peak_g"] and o["t_zero_ms"] > 1.1 * fw["t_zero_ms"]
    checks["56 km/h crushes 1.2x more"] = figures["full_width_56@56"]["crush_m"] > 1.2 * fw["crush_m"]
    sensors = fw["sensors"]
    known = {}
    for name, s in sensors.items():
        if name.startswith("upfront"):
            checks[f"{name} peak before the tunnel"] = s["t_peak_ms"] < sensors["tunnel"]["t_peak_ms"]
            known[f"{name} peak 10-150 g"] = 10.0 <= s["peak_g"] <= 150.0
    checks["energy balance < 0.5 %"] = max(f["balance"] for f in figures.values()) < 5e-3
    return {"figures": figures, "checks": checks, "passed": all(checks.values()), "known_failures": known}


def substep_study(
    variants: tuple[tuple, ...] = (
        (1, False),
        (1, True),
        (1, False, 1.0),
        (1, False, 2.0),
        (2, False),
        (2, True),
        (2, False, 1.0),
        (2, False, 2.0),
        (4, False),
        (4, True),
        (4, False, 1.0),
        (4, False, 2.0),
        (6, False),
        (7, False),
        (8, False),
    ),
    batch: int = 256,
    repeats: int = 1,
    vehicle_seeds: tuple[int, ...] = (1, 2, 3, 4),
    target_cell_volume: float | None = None,
) -> dict:
    """How many explicit steps plausible physics needs, and what the machine allows at each count.

    For every ``(substeps, springback_relief[, mass_floor])`` variant (``mass_floor`` in kg, the
    configured one when left out) it grades the DESIGN 4 plausibility cases
    (:func:`plausibility_checks`), times the fast path at ``batch`` (``full_width_56``, per-cell energies
    at the final step, as the environments run it) and measures the roofline (:func:`measure_roofline`,
    same step count) in the same run. The smallest step count that passes every check bounds what
    any kernel of this explicit scheme can reach: its roofline. As a robustness margin it also grades
    the seeded variants of the default vehicle (``vehicle_seeds``) with the same checks.

    Higher mass floors are the mass-scaling answer to a larger step: the stability cap grows with the cell
    mass, so the links stay stiffer, but the added mass (taken from the compartment, :class:`Surrogate`)
    moves inertia into the crush zone, up to the floor the compartment can pay for (:func:`mass_floor_limit`).

    ``target_cell_volume`` [m^3] discretizes the default car (and its seeded variants) with cells of that volume
    instead of ``configs/cells.yaml``'s: coarser cells merge the light sheet-metal cells into heavier ones, the other
    way to a larger stable step.

    Returns:
        A JSON-ready dict: ``rows`` (one per variant: ``substeps``, ``springback_relief``, ``mass_floor``
        [kg], ``mass_added_kg`` (moved from the compartment to light cells), ``steps_per_sim``, ``passed``,
        ``failed`` (names of failed checks), ``figures`` (full width 40),
        ``variants_passed`` (how many seeded vehicle variants pass every check), ``sims_per_s``,
        ``roofline_sims_per_s``), ``needed`` (the passing row with the fewest steps or ``None``),
        ``vehicle_seeds``, ``target_sims_per_s``, ``mass_floor_limit_kg`` (the default car's), ``target_cell_volume``
        (``None``: the configured one) and ``n_cells``.
    """
    rows = []
    scenario = get_scenario(SCENARIO)
    nominal = load_sim_cells(target_cell_volume=target_cell_volume)
    variant_cells = [load_sim_cells(int(seed), target_cell_volume) for seed in vehicle_seeds]
    for sub, relief, *floor in variants:
        overrides: dict[str, int | bool | float] = {"substeps": int(sub), "springback_relief": bool(relief)}
        if floor:
            overrides["mass_floor"] = float(floor[0])
        cfg = load_sim_config(overrides=overrides)
        sim = Surrogate(nominal, cfg)
        grade = plausibility_checks(sim)
        variants_passed = sum(plausibility_checks(Surrogate(c, cfg))["passed"] for c in variant_cells)
        p = torch.as_tensor(sim.cells.params)[None].repeat(batch, 1, 1)
        sim.run(p[:1], scenario, backend="numba", record_cells="final")  # compile or load the cache
        steps = (scenario.n_outputs - 1) * sim.substeps
        best = interleaved_best(
            {
                "kernel": lambda: sim.run(p, scenario, backend="numba", record_cells="final"),  # noqa: B023
                "roofline": roofline_pass(sim, batch, steps, n_links=live_links(sim, p[:1])),
            },
            repeats,
        )
        t, roof = best["kernel"], batch / best["roofline"]
        fw = grade["figures"]["full_width_40@40"]
        rows.append(
            {
                "substeps": int(sub),
                "springback_relief": bool(relief),
                "mass_floor": float(cfg.mass_floor),
                "mass_added_kg": sim.mass_added,
                "steps_per_sim": steps,
                "passed": grade["passed"],
                "failed": [k for k, ok in grade["checks"].items() if not ok],
                "figures": {k: fw[k] for k in ("peak_g", "crush_m", "t_zero_ms", "rebound")},
                "variants_passed": int(variants_passed),
                "sims_per_s": batch / t,
                "roofline_sims_per_s": roof,
            }
        )
    passing = [r for r in rows if r["passed"]]
    needed = min(passing, key=lambda r: r["steps_per_sim"]) if passing else None
    return {"batch": batch, "rows": rows, "needed": needed, "vehicle_seeds": [int(v) for v in vehicle_seeds],
            "target_sims_per_s": 1000.0, "mass_floor_limit_kg": mass_floor_limit(nominal),
            "target_cell_volume": target_cell_volume, "n_cells": int(nominal.n_cells)}  # fmt: skip


def implicit_study(
    substeps: tuple[int, ...] = (1, 2, 4), window_s: float = 0.010, explicit: dict | None = None
) -> dict:
    """Issue 3's third route to a 0.25-0.5 ms step, measured: implicit integration without stability caps.

    For every step count (``substeps`` per 0.5 ms output step) on the default car, with raw element stiffnesses
    and no mass scaling (``Surrogate(..., stability_caps=False)``, ``mass_floor = 0``):

    - **Backward Euler, Newton-solved** (:func:`marlcrash.sim.implicit.run_implicit`): the first ``window_s`` of
      the full-width 40 km/h crash (the impact, where most elements switch between elastic and plastic), with
      how many steps the Newton iteration solved within its 30 iterations, iterations per step, conjugate-gradient
      iterations per linear solve and link passes per step (force evaluations plus CG iterations).
    - **Linearly implicit** (one solve per step with the predictor's tangent, ``linear=True``): the DESIGN 4
      plausibility grades of the whole 150 ms (:func:`plausibility_checks`).

    ``explicit``: a row of :func:`substep_study` (``steps_per_sim``, ``roofline_sims_per_s``); the roofline of the
    implicit scheme is that one scaled by the link passes, ``roofline * explicit_steps / (steps * passes)`` (a fused
    pass costs the same whichever solver issues it).

    Returns:
        A JSON-ready dict: ``rows`` (``substeps``, ``steps_per_sim``, ``newton``: the stats of ``run_implicit``
        plus ``window_s``, ``linear``: ``passed``, ``failed``, ``figures`` (full width 40), ``balance`` (largest
        energy-balance error of the six cases), and ``roofline_sims_per_s`` when ``explicit`` is given).
    """
    from marlcrash.sim.implicit import run_implicit

    cells = load_sim_cells()
    p = torch.as_tensor(cells.params)[None]
    rows = []
    for sub in substeps:
        cfg = load_sim_config(overrides={"substeps": int(sub), "mass_floor": 0.0})
        sim = Surrogate(cells, cfg, stability_caps=False)
        _, newton = run_implicit(sim, p, get_scenario("full_width_40"), duration=window_s)
        newton["window_s"] = window_s
        lin: dict = {}

        def run(sim, params, lin=lin, **kw):
            res, st = run_implicit(sim, params, linear=True, **kw)
            lin.update(st)
            return res

        grade = plausibility_checks(sim, run=run)
        fw = grade["figures"]["full_width_40@40"]
        steps = (get_scenario(SCENARIO).n_outputs - 1) * int(sub)
        row: dict[str, Any] = {
            "substeps": int(sub),
            "steps_per_sim": steps,
            "newton": newton,
            "linear": {
                "passed": grade["passed"],
                "failed": [k for k, ok in grade["checks"].items() if not ok],
                "figures": {k: fw[k] for k in ("peak_g", "crush_m", "t_zero_ms", "rebound")},
                "balance": max(f["balance"] for f in grade["figures"].values()),
                "link_passes_per_step": lin["link_passes_per_step"],
            },
        }
        if explicit is not None:
            scale = explicit["roofline_sims_per_s"] * explicit["steps_per_sim"] / steps
            row["roofline_sims_per_s"] = scale / newton["link_passes_per_step"]
            row["linear"]["roofline_sims_per_s"] = scale / lin["link_passes_per_step"]
        rows.append(row)
    return {"rows": rows, "explicit": explicit, "target_sims_per_s": 1000.0}


def format_implicit_study(res: dict) -> str:
    """Render :func:`implicit_study`."""
    roof = res["explicit"] is not None
    lines = [
        "backward Euler, Newton-solved, raw stiffnesses, no mass scaling (first "
        f"{res['rows'][0]['newton']['window_s'] * 1e3:g} ms of full_width_40):",
        f"{'steps':>6} {'unsolved':>9} {'newton/step':>11} {'cg/solve':>9} {'passes/step':>11}"
        + (f" {'roofline':>9}" if roof else ""),
    ]
    for r in res["rows"]:
        nw = r["newton"]
        lines.append(
            f"{r['steps_per_sim']:>6} {nw['unconverged_steps']:>4}/{nw['steps']:<4} {nw['newton_mean']:>11.1f} "
            f"{nw['cg_iters_mean']:>9.0f} {nw['link_passes_per_step']:>11.0f}"
            + (f" {r['roofline_sims_per_s']:>9.2f}" if roof else "")
        )
    lines.append("linearly implicit (one solve per step), the DESIGN 4 plausibility cases over 150 ms:")
    lines.append(
        f"{'steps':>6} {'peak g':>9} {'crush m':>8} {'balance':>9} {'passes/step':>11}"
        + (f" {'roofline':>9}" if roof else "")
        + "  plausibility"
    )
    for r in res["rows"]:
        li = r["linear"]
        f = li["figures"]
        verdict = "all checks pass" if li["passed"] else f"fails {len(li['failed'])} checks: " + "; ".join(li["failed"])
        lines.append(
            f"{r['steps_per_sim']:>6} {f['peak_g']:>9.3g} {f['crush_m']:>8.3f} {li['balance']:>9.2g} "
            f"{li['link_passes_per_step']:>11.0f}"
            + (f" {li['roofline_sims_per_s']:>9.2f}" if roof else "")
            + f"  {verdict}"
        )
    if roof:
        ex = res["explicit"]
        lines.append(
            f"roofline: the explicit scheme's at {ex['steps_per_sim']} steps ({ex['roofline_sims_per_s']:.1f} sims/s) "
            "scaled by link passes per simulation; target "
            f"{res['target_sims_per_s']:.0f} sims/s"
        )
    return "\n".join(lines)


def mass_floor_limit(cells) -> float:
    """The largest ``mass_floor`` [kg] whose added mass the rigid compartment can pay for.

    :class:`Surrogate` raises every deformable (non-null, non-rigid) cell to the floor and takes the added
    mass from the compartment; at this floor the compartment's mass reaches zero.
    """
    null, rigid = cells.is_null.astype(bool), cells.is_rigid.astype(bool)
    m = np.sort(cells.mass[~null & ~rigid].astype(np.float64))
    budget = float(cells.mass[cells.compartment])
    # with the k lightest cells below the floor f: added = k f - sum(m[:k]); solve added = budget per k
    for k in range(1, m.size + 1):
        f = (budget + m[:k].sum()) / k
        if k == m.size or f <= m[k]:
            return float(f)
    return float("inf")  # no deformable cells


def load_sim_cells(seed: int | None = None, target_cell_volume: float | None = None):
    """The default car's (or its seeded variant's) optimized CellModel; with ``target_cell_volume`` [m^3]
    discretized with cells of that volume instead of ``configs/cells.yaml``'s (cached per process otherwise)."""
    from marlcrash.envs.core import build_cells
    from marlcrash.vehicle.registry import DEFAULT_VEHICLE

    if target_cell_volume is None:
        return build_cells(DEFAULT_VEHICLE, seed, "optimized")
    from marlcrash.cells.discretize import discretize, load_discretization_config
    from marlcrash.vehicle.registry import load_configured_vehicle

    cfg = load_discretization_config(overrides={"target_cell_volume": float(target_cell_volume)})
    return discretize(load_configured_vehicle(DEFAULT_VEHICLE, seed), cfg, method="optimized")


def format_substep_study(res: dict) -> str:
    """Render :func:`substep_study` as a table plus the conclusion."""
    vol = res.get("target_cell_volume")
    lines = [] if vol is None else [f"cells of {vol:g} m^3: {res['n_cells']} cells"]
    lines += [
        f"{'substeps':>8} {'relief':>6} {'floor kg':>8} {'added kg':>8} {'steps':>6} {'peak g':>7} {'crush m':>8} "
        f"{'t0 ms':>6} {'rebound':>8} "
        f"{'variants':>8} {'sims/s':>8} {'roofline':>9}  plausibility (default car)",
    ]
    n_var = len(res["vehicle_seeds"])
    for r in res["rows"]:
        f = r["figures"]
        verdict = "all checks pass" if r["passed"] else "fails: " + "; ".join(r["failed"])
        var = f"{r['variants_passed']}/{n_var}"
        lines.append(
            f"{r['substeps']:>8} {('on' if r['springback_relief'] else 'off'):>6} {r['mass_floor']:>8.2f} "
            f"{r['mass_added_kg']:>8.0f} {r['steps_per_sim']:>6} "
            f"{f['peak_g']:>7.1f} {f['crush_m']:>8.3f} {f['t_zero_ms']:>6.1f} {f['rebound']:>8.3f} "
            f"{var:>8} {r['sims_per_s']:>8.1f} {r['roofline_sims_per_s']:>9.1f}  {verdict}"
        )
    need = res["needed"]
    if need is None:
        lines.append("no step count passes every plausibility check")
    else:
        lines.append(
            f"fewest steps that pass every check on the default car: {need['steps_per_sim']} "
            f"({need['substeps']} substeps, {need['variants_passed']}/{n_var} seeded variants pass too); the "
            f"roofline there is {need['roofline_sims_per_s']:.1f} sims/s = "
            f"{need['roofline_sims_per_s'] / res['target_sims_per_s']:.3f}x the {res['target_sims_per_s']:.0f} sims/s "
            f"target; the kernel reaches {need['sims_per_s'] / need['roofline_sims_per_s']:.2f} of it "
            f"(B={res['batch']})"
        )
        fewer = [r for r in res["rows"] if r["steps_per_sim"] < need["steps_per_sim"]]
        if fewer:
            most = max(fewer, key=lambda r: r["mass_added_kg"])
            relief = " or springback relief" if any(r["springback_relief"] for r in fewer) else ""
            lines.append(
                f"no variant with fewer steps passes, with mass scaling up to {most['mass_floor']:g} kg per cell "
                f"({most['mass_added_kg']:.0f} kg moved from the compartment into the crush zone){relief}; "
                f"the compartment can pay for floors up to {res['mass_floor_limit_kg']:.2f} kg"
            )
    return "\n".join(lines)
