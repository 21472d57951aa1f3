"""How precisely a calibration must recover the twin truth: the fit landscape around it.

A twin reference (:mod:`marlcrash.references`) has a known truth :attr:`CalibrationProblem.true_x`
with zero metrics. :func:`truth_neighbourhood` evaluates random points at a log-scale distance
``r`` from it (every free coordinate of a parameter group moved by ``r * N(0, 1)``, so ``r`` is the
rms log error per coordinate: ``r = 0.01`` is about 1 % per parameter) and reports, per group and
radius, the median over draws of the worst sensor's metrics and the share of draws that pass the
success test. Two figures answer whether a threshold is reachable:

- ``radius_needed``: the largest radius whose median passes every threshold, i.e. the parameter
  precision a calibrator needs to pass (``None``: not even the smallest radius passes).
- ``slope``: ``d log A / d log r`` of the median worst-sensor area between successive radii. A
  smooth landscape has slope 1 (the error is linear in the parameter error); a slope near 0 at
  small radii means the pulse jumps (discrete events such as a cell bottoming out one explicit
  step earlier), so no calibrator gets below that floor by refining its parameters.

A ``float32`` problem (``sim_dtype``) needs radii of at least
:data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP`, as its finite differences need such a step: below it the
simulation's rounding swamps the pulse change (on the full-width twin, E_x moved by 1e-6 and 1e-5 gave 23x and 5x the
float64 area and a slope of 0.3-0.4, which would read as a jumping pulse). The default radii, from 1e-6, are for
float64; on float32 they are refused (key ``radii``).

Every candidate counts one simulation of the problem; one batched simulation per group.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import torch

from marlcrash.calibrate.leastsq import FLOAT32_FD_STEP, check_fd_step, fd_points, jacobian, lm_iteration
from marlcrash.calibrate.problem import CalibrationProblem
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics, area_between

GROUPS: dict[str, slice] = {"E_x": slice(0, 1), "E_s": slice(1, 2), "transmission": slice(2, 7), "all": slice(0, 7)}
DEFAULT_RADII = (1e-6, 1e-5, 1e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1)


def _check(problem: CalibrationProblem, groups: list[str] | tuple[str, ...]) -> torch.Tensor:
    """The problem's twin truth :attr:`~CalibrationProblem.true_x`, once it has one and ``groups`` are known."""
    true_x = problem.true_x
    if true_x is None:
        raise ConfigError("the landscape study needs a twin reference with ground truth", key="problem.reference")
    if isinstance(groups, str):  # iterated letter by letter: "unknown parameter group 'a'"
        raise ConfigError(f"expected a list of parameter groups, e.g. [{groups!r}], got {groups!r}", key="groups")
    for group in groups:
        if group not in GROUPS:
            raise ConfigError(f"unknown parameter group {group!r}; expected one of {list(GROUPS)}", key="groups")
    return true_x


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool | np.bool_)


def _require_count(value: Any, key: str) -> int:
    """``value`` as an integer >= 1, or a :class:`ConfigError` naming ``key`` (2.5 is not 2)."""
    if not _is_number(value) or not (np.isfinite(value) and value >= 1 and float(value).is_integer()):
        raise ConfigError(f"expected an integer >= 1, got {value!r}", key=key)
    return int(value)


def _check_radii(radii, draws, problem: CalibrationProblem) -> tuple[list[float], int]:
    """``radii`` as floats and ``draws`` as an int, else a :class:`ConfigError` naming the key; on a ``float32``
    problem the radii start at :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP` (module docstring)."""
    if isinstance(radii, str) or not isinstance(radii, list | tuple | np.ndarray) or not all(map(_is_number, radii)):
        raise ConfigError(f"expected a list of strictly increasing radii > 0, got {radii!r}", key="radii")
    radii = [float(r) for r in radii]
    if not radii or any(not (np.isfinite(r) and r > 0) for r in radii) or sorted(set(radii)) != radii:
        raise ConfigError(f"expected strictly increasing radii > 0, got {radii}", key="radii")
    if problem.sim.config.dtype == "float32" and radii[0] < FLOAT32_FD_STEP:
        raise ConfigError(
            f"the env simulates in float32 (sim_dtype), whose rounding swamps the pulse change of a parameter change "
            f"below {FLOAT32_FD_STEP:g} (a slope near 0 there is rounding, not a jumping pulse); got radii {radii}, "
            f"expected radii of at least {FLOAT32_FD_STEP:g}, or a float64 env",
            key="radii",
        )
    return radii, _require_count(draws, "draws")


def neighbourhood_points(
    problem: CalibrationProblem, radii: list[float], group: str, draws: int, seed: int = 0
) -> torch.Tensor:
    """Candidates ``[len(radii) * draws, n_agents, 7]`` around the truth, radius-major.

    Row ``i * draws + j`` is ``true_x + radii[i] * d_j`` clipped to the search box, with the same
    standard normal directions ``d_j`` (non-zero only on the group's free coordinates) at every
    radius, so the radii compare like with like.
    """
    true_x = _check(problem, [group])
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(draws, problem.n_agents, 7, generator=g, dtype=torch.float64)
    mask = torch.zeros(7, dtype=torch.bool)
    mask[GROUPS[group]] = True
    d = d * (problem.free & mask)
    r = torch.as_tensor(radii, dtype=torch.float64)[:, None, None, None]
    return problem.clip((true_x + r * d[None]).reshape(-1, problem.n_agents, 7))


def loglog_slopes(radii: list[float], values: list[float]) -> list[float | None]:
    """``d log v / d log r`` between successive radii (``None`` where a value is not positive)."""
    out: list[float | None] = []
    for i in range(len(radii) - 1):
        (r0, v0), (r1, v1) = (radii[i], values[i]), (radii[i + 1], values[i + 1])
        out.append(math.log(v1 / v0) / math.log(r1 / r0) if v0 > 0 and v1 > 0 else None)
    return out


def truth_neighbourhood(
    problem: CalibrationProblem,
    radii: list[float] | tuple[float, ...] = DEFAULT_RADII,
    groups: list[str] | tuple[str, ...] = tuple(GROUPS),
    draws: int = 8,
    seed: int = 0,
) -> dict[str, Any]:
    """The fit landscape around the twin truth (module docstring).

    Args:
        problem: a twin calibration problem (:func:`~marlcrash.calibrate.problem.build_problem`).
        radii: increasing log-scale radii ``> 0`` (rms per coordinate); at least
            :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP` on a ``float32`` problem (module docstring).
        groups: parameter groups to move: ``E_x``, ``E_s``, ``transmission``, ``all``.
        draws: random directions per radius.
        seed: seed of the directions.

    Returns:
        ``{"sensors", "thresholds", "radii", "draws", "at_truth": {metric: [K]}, "groups": {group:
        {"area", "dfd", "rmse": [R] medians of the worst sensor, "area_per_sensor": [R][K] medians,
        "pass_share": [R], "slope": [R - 1], "radius_needed"}}}``.

    Raises:
        ConfigError: no ground truth, an unknown group, radii not increasing and positive (or below the float32
            limit on a float32 problem), draws < 1.
    """
    radii, draws = _check_radii(radii, draws, problem)
    thresholds = {
        "area": problem.success_cfg.success_area,
        "dfd": problem.success_cfg.success_dfd,
        "rmse": problem.success_cfg.success_rmse,
    }
    true_x = _check(problem, groups)  # before simulating anything
    m0 = problem.evaluate(true_x[None])
    out: dict[str, Any] = {"sensors": list(problem.sensors), "thresholds": thresholds, "radii": radii, "draws": draws,
                           "at_truth": {k: getattr(m0, k)[0].tolist() for k in thresholds}, "groups": {}}  # fmt: skip
    R, K = len(radii), len(problem.sensors)
    for group in groups:
        m = problem.evaluate(neighbourhood_points(problem, radii, group, draws, seed))
        passed = problem.success(m)
        worst = {k: getattr(m, k).reshape(R, draws, K).amax(-1).median(dim=1).values.tolist() for k in thresholds}
        per_sensor = m.area.reshape(R, draws, K).median(dim=1).values.tolist()
        share = passed.reshape(R, draws).to(torch.float64).mean(1).tolist()
        ok = [all(t is None or worst[k][i] < t for k, t in thresholds.items()) for i in range(R)]
        needed = None
        for i in range(R):
            if not ok[i]:
                break
            needed = radii[i]
        out["groups"][group] = {**worst, "area_per_sensor": per_sensor, "pass_share": share,
                                "slope": loglog_slopes(radii, worst["area"]), "radius_needed": needed}  # fmt: skip
    return out


def format_landscape(res: dict[str, Any]) -> str:
    """A readable table of :func:`truth_neighbourhood`'s result."""
    th = res["thresholds"]
    lines = [
        f"sensors: {', '.join(res['sensors'])}; thresholds: area {th['area']} m, dfd {th['dfd']} m/s, "
        f"rmse {th['rmse']} m/s; {res['draws']} random directions per radius",
        "at the truth: worst area {:.2e} m, dfd {:.2e} m/s, rmse {:.2e} m/s".format(
            *(max(res["at_truth"][k]) for k in ("area", "dfd", "rmse"))
        ),
    ]
    for group, g in res["groups"].items():
        lines += ["", f"group {group}: radius needed to pass (median) = {g['radius_needed']}",
                  f"{'radius':>8} {'worst A [m]':>12} {'slope':>6} {'worst DFD':>10} {'worst RMSE':>10} {'pass':>5}  "
                  "median A per sensor [m]"]  # fmt: skip
        for i, r in enumerate(res["radii"]):
            slope = "" if i == 0 or g["slope"][i - 1] is None else f"{g['slope'][i - 1]:.2f}"
            per = " ".join(f"{a:.1e}" for a in g["area_per_sensor"][i])
            lines.append(f"{r:8.0e} {g['area'][i]:12.2e} {slope:>6} {g['dfd'][i]:10.3f} {g['rmse'][i]:10.4f} "
                         f"{g['pass_share'][i]:5.2f}  {per}")  # fmt: skip
    return "\n".join(lines)


# ------------------------------------------------------------------ sensor clusters
def sensor_clusters(cells, sensors: list[str], radius: float) -> list[np.ndarray]:
    """Per sensor, the cells with mass whose centroid lies within ``radius`` [m] of the sensor cell's.

    The sensor cell itself is always a member (``radius = 0`` gives the single-cell sensor).
    """
    names = list(cells.sensor_names)
    has_mass = ~cells.is_null & (cells.mass > 0)
    out = []
    for s in sensors:
        c = int(cells.sensor_cell[names.index(s)])
        near = np.linalg.norm(cells.centroid - cells.centroid[c], axis=1) <= radius
        out.append(np.union1d(np.flatnonzero(has_mass & near), [c]))
    return out


def cluster_sensor_study(
    problem: CalibrationProblem,
    cluster_radii: list[float] | tuple[float, ...] = (0.0, 0.08, 0.15, 0.25),
    radii: list[float] | tuple[float, ...] = (1e-4, 1e-3, 1e-2),
    group: str = "all",
    draws: int = 8,
    seed: int = 0,
) -> dict[str, Any]:
    """Would a sensor that reads a bracket (a cluster of cells) instead of one light cell flatten the landscape?

    Each sensor's velocity is replaced by the mass-weighted mean velocity of its cluster
    (:func:`sensor_clusters`, one per ``cluster_radii`` entry [m]) for the truth and for the same
    neighbourhood points as :func:`truth_neighbourhood` alike, then compared as the problem compares
    (:meth:`CalibrationProblem.compared`, area of Eq. 8 by the fit's ``metrics.area_method``). One batched
    simulation records every cluster cell (``1 + len(radii) * draws`` simulations).

    Returns:
        ``{"sensors", "radii", "draws", "group", "clusters": [{"radius_m", "cells": [K], "mass_kg": [K],
        "area_per_sensor": [R][K] medians over the draws}]}``.

    Raises:
        ConfigError: no ground truth, an unknown group, negative cluster radii, radii not increasing and
            positive (or below the float32 limit on a float32 problem, as for :func:`truth_neighbourhood`), draws < 1.
    """
    true_x = _check(problem, [group])
    radii, draws = _check_radii(radii, draws, problem)
    if (
        isinstance(cluster_radii, str)
        or not cluster_radii
        or any(not (_is_number(c) and np.isfinite(c) and c >= 0) for c in cluster_radii)
    ):
        raise ConfigError(f"expected cluster radii >= 0 m, got {list(cluster_radii)}", key="cluster_radii")
    cells = problem.cells
    clusters = [sensor_clusters(cells, problem.sensors, float(c)) for c in cluster_radii]
    probe = np.unique(np.concatenate([m for cl in clusters for m in cl]))
    col = {int(c): i for i, c in enumerate(probe)}
    x = torch.cat([true_x[None], neighbourhood_points(problem, radii, group, draws, seed)])
    with torch.no_grad():
        res = problem.simulate(x, probe_cells=probe)
    mass = torch.as_tensor(cells.mass, dtype=torch.float64)
    out: dict[str, Any] = {"sensors": list(problem.sensors), "radii": radii, "draws": draws, "group": group,
                           "clusters": []}  # fmt: skip
    for c, members in zip(cluster_radii, clusters, strict=True):
        v = []
        for m in members:
            w = mass[m] / mass[m].sum()
            v.append((res.velocity[:, [col[int(i)] for i in m]] * w[None, :, None]).sum(1))
        vc = problem.compared(torch.stack(v, dim=1))  # [N, K, T]
        area = area_between(vc[1:], vc[:1], dt=problem.dt, method=problem.fit.cfg.metrics.area_method)
        area = area.reshape(len(radii), draws, -1).median(dim=1).values
        out["clusters"].append({"radius_m": float(c), "cells": [len(m) for m in members],
                                "mass_kg": [float(mass[m].sum()) for m in members],
                                "area_per_sensor": area.tolist()})  # fmt: skip
    return out


def format_cluster_study(res: dict[str, Any]) -> str:
    """A readable table of :func:`cluster_sensor_study`'s result."""
    lines = [f"sensors read as mass-weighted clusters; group {res['group']}, {res['draws']} directions per radius; "
             f"median area [m] per sensor ({', '.join(res['sensors'])})",
             f"{'cluster':>8} {'cells':>12} {'mass [kg]':>20}  " + "  ".join(f"{'r=' + format(r, 'g'):>26}"
                                                                          for r in res["radii"])]  # fmt: skip
    for c in res["clusters"]:
        cells = "/".join(str(n) for n in c["cells"])
        mass = "/".join(f"{m:.2f}" for m in c["mass_kg"])
        per = "  ".join(f"{' '.join(f'{a:.1e}' for a in row):>26}" for row in c["area_per_sensor"])
        lines.append(f"{c['radius_m']:7.2f}m {cells:>12} {mass:>20}  {per}")
    return "\n".join(lines)


def local_fit(
    problem: CalibrationProblem,
    *,
    start_radius: float | None = None,
    x0: torch.Tensor | None = None,
    iterations: int = 10,
    fd_step: float = 1e-5,
    damping: float = 1e-2,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """Does a local least-squares method reach the success test? Levenberg-Marquardt on the pulse residuals.

    The residual is ``(v_sim - v_ref) sqrt(dt)`` over every sensor and output sample (its squared norm is
    the summed ``integral (dv)^2 dt``). Each iteration takes a forward finite-difference Jacobian
    over the free coordinates (``n_free`` simulations in one batch, the current point's residual reused;
    steps backward at the upper bound of the box), then tries six damping values
    ``lambda * (0.01 .. 1000)`` on ``J^T J + lambda D`` in one more batch and keeps the best step if it
    lowers the cost (``lambda`` then shrinks 3x, else it grows 30x). ``D`` is the diagonal of ``J^T J``
    floored at 1e-3 of its largest entry: without the floor, coordinates the pulses barely see took
    steps to the edge of the search box and every step was rejected. Steps are clipped to the search
    box. It checks the landscape locally: near a smooth optimum this converges in a few iterations.

    Args:
        problem: a twin calibration problem.
        start_radius: ``None`` starts at the initial parameters (``x = 0``); a value starts at
            ``true_x + start_radius * u`` with ``u`` uniform in ``[-1, 1]`` per free coordinate.
        x0: instead, start at this candidate ``[n_agents, 7]`` (e.g. another calibrator's result),
            clipped to the search box.
        iterations: Levenberg-Marquardt iterations.
        fd_step: finite-difference step in log-scale [-]; at least
            :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP` on a ``float32`` problem (its rounding swamps a
            smaller one).
        damping: initial ``lambda`` [-].
        seed: seed of the start point's draw.

    Returns:
        One record per iterate (the start first): ``simulations`` (cumulative, counted by the
        problem), ``cost``, ``distance`` (largest absolute log error to the truth), and per sensor
        ``area``, ``dfd``, ``rmse``, ``passed``.

    Raises:
        ConfigError: no twin truth, ``iterations`` not an integer >= 1, a non-positive ``fd_step`` (or one below
            the float32 limit) or ``damping``, or a negative or non-finite ``start_radius`` (key named).
    """
    true_x = _check(problem, ())
    iterations = _require_count(iterations, "iterations")
    if start_radius is not None and not (_is_number(start_radius) and np.isfinite(start_radius) and start_radius >= 0):
        raise ConfigError(f"expected a start radius >= 0 or None, got {start_radius!r}", key="start_radius")
    for key, val in (("fd_step", fd_step), ("damping", damping)):
        if not (_is_number(val) and np.isfinite(val) and val > 0):
            raise ConfigError(f"expected {key} > 0, got {val!r}", key=key)
    check_fd_step(fd_step, problem.sim.config.dtype, "fd_step")
    lo, hi = problem.flat_box()
    truth = problem.flat(true_x[None])[0]
    if x0 is not None:
        if start_radius is not None:
            raise ConfigError("give either start_radius or x0, not both", key="start_radius")
        z = problem.flat(problem.clip(problem.check_x(x0)))[0]
    elif start_radius is None:
        z = torch.zeros_like(truth)
    else:
        g = torch.Generator().manual_seed(int(seed))
        u = 2.0 * torch.rand(truth.shape, generator=g, dtype=torch.float64) - 1.0
        z = torch.minimum(torch.maximum(truth + float(start_radius) * u, lo), hi)

    def run(zs: torch.Tensor):
        r, m = problem.residuals(problem.unflat(zs))
        return r.reshape(zs.shape[0], -1), m

    def record(zi: torch.Tensor, row: torch.Tensor, m, i: int) -> dict[str, Any]:
        ok = problem.success(Metrics(*(t[i : i + 1] for t in m)))[0]
        out: dict[str, Any] = {"simulations": problem.n_simulations, "cost": float((row**2).sum()),
               "distance": float((zi - truth).abs().max()), "passed": bool(ok)}  # fmt: skip
        out["sensors"] = Metrics(*(t[i] for t in m)).per_sensor(problem.sensors)
        return out

    r_all, m = run(z[None])
    r = r_all[0]
    history = [record(z, r, m, 0)]
    lam = float(damping)
    for _ in range(int(iterations)):
        step = lm_iteration(run, z, r, lam, lo, hi, fd_step)
        z, r, lam = step.z, step.r, step.lam
        if step.accepted is not None:
            history.append(record(z, r, step.aux, step.accepted))
        else:
            history.append({**history[-1], "simulations": problem.n_simulations})
    return history


SPECTRUM_BANDS: tuple[float, ...] = (1e-1, 1e-2, 1e-3, 1e-4)
"""Relative singular-value thresholds of :func:`sensitivity_spectrum`'s bands [-]."""


def _band_labels(bands: tuple[float, ...]) -> list[str]:
    edges = [f"{b:g}" for b in bands]
    return [f">{edges[0]}", *(f"{lo}-{hi}" for hi, lo in itertools.pairwise(edges)), f"<={edges[-1]}"]


BLIND_RTOL = 1e-8
"""A Jacobian column whose norm is at most this fraction of the largest column's is *blind*. The compared
signals are bitwise independent of the batch layout (the base point is simulated alone, the finite-difference
points in one batch), so an untouched coordinate's column is exactly zero; the tolerance keeps the count
robust to rounding-level differences (a matrix-product CFC filter left about 1e-10 of the largest column over
a 10 ms window)."""


def _blind_columns(jac: torch.Tensor) -> int:
    norms = torch.linalg.vector_norm(jac, dim=0)
    top = float(norms.max()) if norms.numel() else 0.0
    return int((norms <= BLIND_RTOL * top).sum())


def sensitivity_spectrum(
    problem: CalibrationProblem,
    *,
    x: torch.Tensor | None = None,
    candidate: torch.Tensor | None = None,
    fd_step: float = 1e-5,
    bands: tuple[float, ...] = SPECTRUM_BANDS,
) -> dict[str, Any]:
    """What the sensors see of the parameters: the singular values of the residual Jacobian at a point.

    The Jacobian of the velocity residuals (:meth:`CalibrationProblem.residuals`: every sensor and
    output sample) over the ``n_free`` free log-scale coordinates, by forward finite differences
    (:mod:`~marlcrash.calibrate.leastsq`, ``n_free + 1`` simulations). A singular value ``s_i`` is how
    much the pulses change per unit log-scale change along its direction ``v_i``; a parameter error
    along directions whose ``s_i / s_max`` is small barely moves the pulses, so no calibrator can
    tell those directions apart from these pulses (locally).

    Args:
        problem: the calibration problem.
        x: ``[n_agents, 7]`` the point (``None``: the twin truth ``true_x``).
        candidate: optionally another ``[n_agents, 7]`` point (e.g. a calibration result): how its
            difference ``d`` from ``x`` splits over the bands, and whether the linear model holds there.
        fd_step: finite-difference step in log-scale [-]; at least
            :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP` on a ``float32`` problem.
        bands: decreasing relative singular-value thresholds.

    Returns:
        ``n_free``, ``n_residuals``, ``singular_values`` (``n_free`` of them, descending, zeros where the
        residuals are fewer than the coordinates; [m/s^0.5] per unit log-scale),
        ``relative`` (``s / s_max``), ``above`` (``{threshold: count}``), ``blind_coordinates`` (free
        coordinates whose Jacobian column is below :data:`BLIND_RTOL` of the largest: the load does not
        reach them in the window), ``simulations``; with ``candidate`` also ``candidate``: ``distance_rms`` (rms of
        ``d``), ``error_share`` (share of ``|d|^2`` per band, keyed as ``band_labels``),
        ``linear_residual`` ``|J d|``, ``residual`` (the actual ``|r(candidate)|``) and
        ``residual_at_x`` (``|r(x)|``); and ``band_labels``.

    Raises:
        ConfigError: no truth and no ``x``, a non-positive ``fd_step`` (or one below the float32 limit), or bands
            not decreasing in (0, 1).
    """
    if x is None:
        x = _check(problem, ())
    if not (_is_number(fd_step) and np.isfinite(fd_step) and fd_step > 0):
        raise ConfigError(f"expected fd_step > 0, got {fd_step!r}", key="fd_step")
    check_fd_step(fd_step, problem.sim.config.dtype, "fd_step")
    if isinstance(bands, str) or not all(map(_is_number, bands)):
        raise ConfigError(f"expected decreasing thresholds in (0, 1), got {bands!r}", key="bands")
    b = [float(v) for v in bands]
    if not b or any(not 0 < v < 1 for v in b) or any(a <= c for a, c in itertools.pairwise(b)):
        raise ConfigError(f"expected decreasing thresholds in (0, 1), got {bands}", key="bands")
    before = problem.n_simulations
    lo, hi = problem.flat_box()
    z = problem.flat(problem.clip(problem.check_x(x)))[0]
    r0 = problem.residuals(problem.unflat(z[None]))[0].reshape(-1)
    points, h = fd_points(z, lo, hi, fd_step)
    r_fd = problem.residuals(problem.unflat(points))[0].reshape(len(h), -1)
    jac = jacobian(r_fd, r0, h)
    _, s, vt = torch.linalg.svd(jac, full_matrices=True)  # vt [n, n]: with fewer residuals than n, the rest is null
    s = torch.cat([s, s.new_zeros(vt.shape[0] - s.numel())])
    rel = s / s[0] if float(s[0]) > 0 else torch.zeros_like(s)
    labels = _band_labels(tuple(b))
    out: dict[str, Any] = {
        "n_free": int(z.numel()),
        "n_residuals": int(r0.numel()),
        "singular_values": s.tolist(),
        "relative": rel.tolist(),
        "above": {f"{v:g}": int((rel > v).sum()) for v in b},
        "blind_coordinates": _blind_columns(jac),
        "band_labels": labels,
    }
    if candidate is not None:
        zc = problem.flat(problem.clip(problem.check_x(candidate)))[0]
        d = zc - z
        c2 = (vt @ d) ** 2
        edges = [float("inf"), *b, 0.0]
        total = c2.sum().clamp_min(1e-300)
        share = [float(c2[(rel <= hi_) & (rel > lo_)].sum() / total) for hi_, lo_ in itertools.pairwise(edges)]
        share[-1] += float(c2[rel <= 0].sum() / total)
        out["candidate"] = {
            "distance_rms": float(d.pow(2).mean().sqrt()),
            "error_share": dict(zip(labels, share, strict=True)),
            "linear_residual": float((jac @ d).norm()),
            "residual": float(problem.residuals(problem.unflat(zc[None]))[0].norm()),
            "residual_at_x": float(r0.norm()),
        }
    out["simulations"] = problem.n_simulations - before
    return out


def format_spectrum(res: dict[str, Any]) -> str:
    """A few lines of text for :func:`sensitivity_spectrum`'s result."""
    n = res["n_free"]
    above = ", ".join(f"{cnt} above {thr}" for thr, cnt in res["above"].items())
    rel = res["relative"]
    every = max(1, len(rel) // 16)
    lines = [
        f"residual Jacobian: {res['n_residuals']} residuals x {n} free coordinates ({res['simulations']} simulations)",
        f"singular values relative to the largest: {above} (of {n}); "
        f"{res['blind_coordinates']} coordinates the load never reaches in the window",
        f"sampled (every {every}): " + " ".join(f"{v:.1e}" for v in rel[::every]),
    ]
    c = res.get("candidate")
    if c is not None:
        share = "  ".join(f"{k}: {v:.3f}" for k, v in c["error_share"].items())
        lines += [
            f"candidate: rms log-scale distance {c['distance_rms']:.3g}; share of its squared error per band: {share}",
            f"residual norm: {c['residual']:.3e} actual, {c['linear_residual']:.3e} linearized "
            f"(at the point: {c['residual_at_x']:.3e})",
        ]
    return "\n".join(lines)
