"""Implicit study integrator: the surrogate's physics with 0.5-0.125 ms steps and no stability caps.

Issue 3 names three routes to a 0.25-0.5 ms step: stiffness caps, mass scaling and a semi-implicit
scheme. The first two are explicit and graded by :func:`marlcrash.sim.bench.substep_study`; this module
measures the third: :func:`run_implicit` integrates the same element laws (the surrogate's
:meth:`~marlcrash.sim.surrogate.Surrogate._step`: return-mapped elastic-plastic links, gap contact,
saturation within the step, damped wall contact, the same energy ledgers) implicitly, on a
:class:`~marlcrash.sim.surrogate.Surrogate` built with ``stability_caps=False``: every element keeps its
raw stiffness. A step with the node increments ``ds = dt (v + theta u)`` and the velocity change ``u``
solves ``R(u) = M u - dt ((1 - theta) F_n + theta F(ds)) = 0`` (``theta = 1``: backward Euler, the default;
``0.5``: the trapezoidal rule, whose discrete work equals the ledgers' trapezoid, so its energy balance
closes to 1e-9, but the stiff wall contact chatters: 1.3-1.6x the closed-form crush on the single-cell case).

- **Newton** (default): semismooth Newton on ``u``. Each iteration evaluates the element forces and their
  tangent (stiffness plus damping ``/ dt`` of every element that stays elastic; 0 while it yields, is open
  or does not push; checked against finite differences), solves ``(M + theta^2 dt^2 J) du = -R`` (``J`` the
  tangents' graph Laplacian plus the wall's diagonal; ``scipy.sparse.linalg.spsolve`` per simulation) and
  searches along ``du``: ``R`` is the gradient of a convex function of ``u`` wherever no cell bottoms out
  (monotone element laws), so ``du . R(u + a du)`` rises with ``a``, and a safeguarded secant search finds
  where it has fallen to half. It stops when ``max |R|`` is below ``newton_rtol`` of the momentum
  ``sum m |v|``, or after ``max_newton`` iterations (counted as unsolved; the step then goes on from the
  last iterate, so an unsolved step is not a converged result). Then the step is committed with the
  forces reached. On the single-cell closed form (``tests/test_sim_implicit.py``) it matches crush and stop
  time within 1 % at 0.5 ms steps, where the explicit step needs stability caps.
- **Linearly implicit** (``linear=True``, the textbook "semi-implicit" step): one solve per step with the
  tangent at the predictor ``ds = dt v``, and ``u`` from that solve. No iteration, but an element that the
  predictor finds elastic and that yields within the step is treated as elastic (stiffness up to
  ``10^9`` N/m against a crush force of ``10^5`` N), so the velocities see forces the elements never carry.

Solver cost, the question that decides the speed: every linear solve is repeated with conjugate gradients
and a Jacobi preconditioner (a step's first solve warm-started from the last step's) to relative residual
``cg_rtol``, and its iterations are counted. Each costs one sparse matrix-vector product, one pass over
the links; every force evaluation (Newton iterate, line-search point) is one more. So a fused
implementation streams ``link_passes_per_step`` link passes per step against the explicit scheme's one.
The physics uses the direct solution, so it does not depend on that tolerance. This is a study path (a
Python loop over steps, scipy per simulation, no gradients): :func:`marlcrash.sim.bench.implicit_study`
and ``benchmarks/bench_implicit.py`` grade it.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import cg, spsolve

from marlcrash.errors import ModelError
from marlcrash.sim.scenario import CrashScenario
from marlcrash.sim.surrogate import SimResult, Surrogate


def run_implicit(
    sim: Surrogate,
    params: torch.Tensor | np.ndarray,
    scenario: CrashScenario | None = None,
    *,
    speed: torch.Tensor | None = None,
    overlap: torch.Tensor | None = None,
    side: torch.Tensor | None = None,
    duration: float | None = None,
    sensors: list[str] | None = None,
    record_cells: str = "final",
    theta: float = 1.0,
    max_newton: int = 30,
    linear: bool = False,
    newton_rtol: float = 1e-10,
    cg_rtol: float = 1e-6,
) -> tuple[SimResult, dict]:
    """Simulate ``B`` crashes with the implicit study integrator (module doc).

    Args:
        sim: the surrogate; its time step is ``output_dt / substeps``. Build it with ``stability_caps=False``
            for the raw element stiffnesses (with caps it integrates the capped model, for comparison).
        params, scenario, speed, overlap, side, duration, sensors, record_cells: as :meth:`Surrogate.run`.
        theta: weight of the end-of-step forces, in [0.5, 1] (1 backward Euler, 0.5 trapezoidal rule).
        max_newton: Newton iterations per step before the step counts as unsolved (>= 1).
        linear: one linear solve per step instead of Newton (the linearly implicit scheme).
        newton_rtol: Newton's tolerance on ``max |R|`` relative to the momentum ``sum m |v|`` (> 0).
        cg_rtol: relative residual the counted conjugate-gradient solves reach (> 0).

    Returns:
        ``(result, stats)``: the :class:`SimResult` and ``stats`` with ``steps``, ``newton_mean`` and
        ``newton_max`` (iterations per step), ``unconverged_steps`` (steps that reached ``max_newton``),
        ``cg_iters_mean`` and ``cg_iters_max`` (per linear solve), ``solves_per_step`` and
        ``force_evals_per_step`` (per step of the batch), ``link_passes_per_step`` (force evaluations plus CG
        iterations per step of one simulation) and ``n_links`` (links with a non-zero share in some row).

    Raises:
        ModelError: an argument out of range, an unknown ``record_cells``, a float32 surrogate, and every input
            error of :meth:`Surrogate.run`.
    """

    def number(x) -> bool:  # None, text and bools failed inside int() or '<=' ("x" a ValueError), or passed as 1
        return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool | np.bool_)

    if not (number(max_newton) and math.isfinite(max_newton) and int(max_newton) == max_newton and max_newton >= 1):
        raise ModelError(f"max_newton must be an integer >= 1, got {max_newton!r}")
    if not (number(theta) and 0.5 <= theta <= 1.0):
        raise ModelError(f"theta must be in [0.5, 1] (0.5 trapezoidal rule, 1 backward Euler), got {theta!r}")
    max_newton = int(max_newton)
    for name, val in (("newton_rtol", newton_rtol), ("cg_rtol", cg_rtol)):
        if not (number(val) and val > 0):
            raise ModelError(f"{name} must be a number > 0, got {val!r}")
    if not isinstance(linear, bool | np.bool_):  # bool("no") is True: the linearly implicit scheme ran
        raise ModelError(f"linear must be True or False, got {linear!r}")
    if record_cells not in ("series", "final", "none"):  # as Surrogate.run: "all" ran as "none" without a word
        raise ModelError(f"record_cells must be one of series, final, none; got {record_cells!r}")
    if sim.dtype != torch.float64:
        raise ModelError("the implicit study integrator runs in float64; set dtype: float64")
    _, props, wall, n_out, sensor_idx = sim.prepare(params, scenario, speed, overlap, side, duration, sensors)
    B, n, dt = props.k.shape[0], sim.n, sim.dt
    src, dst = sim.src.numpy(), sim.dst.numpy()
    mass = sim.mass.numpy()
    rows = np.concatenate([src, dst, src, dst, np.arange(n)])
    cols = np.concatenate([src, dst, dst, src, np.arange(n)])
    u_prev = np.zeros((B, n))
    iters: list[int] = []
    newton_iters: list[int] = []
    unconverged = [0]
    evals = [0]
    m_t = sim.mass[None]

    def solve(b: int, w: np.ndarray, diag: np.ndarray, rhs: np.ndarray, first: bool) -> np.ndarray:
        a = sp.coo_matrix((np.concatenate([w, w, -w, -w, diag]), (rows, cols)), shape=(n, n)).tocsr()
        u = spsolve(a.tocsc(), rhs)
        count = [0]

        def tick(_):
            count[0] += 1

        pre = sp.diags(1.0 / a.diagonal())
        # warm start: a step's first correction from the last step's, later ones (residuals) from zero
        cg(a, rhs, x0=u_prev[b] if first else None, rtol=cg_rtol, M=pre, callback=tick)
        iters.append(count[0])
        if first:
            u_prev[b] = u
        return u

    def forces(props, wall, f_el, o, plastic, yielded, s, v, force, u):
        """Increments, element state, node forces and residual ``R = M u - dt ((1 - theta) F_n + theta F)``."""
        ds = dt * v + theta * dt * u
        st = sim._step(props, wall, f_el, o, plastic, yielded, s + ds, ds, ds / dt, tangent=True)
        evals[0] += 1
        return ds, st, m_t * u - dt * ((1.0 - theta) * force + theta * sim._node_force(st))

    def correction(st, r, todo: list[int], first: bool) -> torch.Tensor:
        """``du [B, n]`` solving ``(M + theta^2 dt^2 J) du = -r`` in the rows ``todo`` (0 elsewhere)."""
        w = (st.k_t * (theta * theta * dt * dt)).numpy()
        wall_t = (st.kw_t * (theta * theta * dt * dt)).numpy()
        du = torch.zeros_like(r)
        for b in todo:
            du[b] = torch.from_numpy(solve(b, w[b], mass + wall_t[b], -r[b].numpy(), first))
        return du

    def increment(props, wall, f_el, o, plastic, yielded, s, v, force):
        # semismooth Newton on u (the element laws are piecewise linear: full steps converge once the set of
        # elastic / closed elements settles), globalised by the line search below
        tol = newton_rtol * (m_t * v.abs()).sum(dim=1)  # [B] momentum scale [kg m/s]
        u = torch.zeros_like(v)
        ds, st, r = forces(props, wall, f_el, o, plastic, yielded, s, v, force, u)
        for it in range(max_newton + 1):
            norm = r.abs().amax(dim=1)
            todo = norm > tol
            if not bool(todo.any()):
                newton_iters.append(it)
                return ds, None
            if it == max_newton:
                break
            du = correction(st, r, torch.nonzero(todo).flatten().tolist(), it == 0)
            # line search along du: R is the gradient of a convex function of u (inertia plus the elements'
            # incremental potentials; their laws are monotone), so g(a) = du . R(u + a du) rises with a; keep a = 1
            # where g(1) <= 0, else bracket and find a with |g(a)| <= |g(0)| / 2 (safeguarded secant steps)
            g0 = (du * r).sum(dim=1)
            lo, hi = torch.zeros(B, dtype=u.dtype), torch.ones(B, dtype=u.dtype)
            g_lo, g_hi = g0.clone(), torch.zeros(B, dtype=u.dtype)
            alpha = torch.ones(B, dtype=u.dtype)
            done = ~todo
            for ls in range(12):
                cand = forces(props, wall, f_el, o, plastic, yielded, s, v, force, u + alpha[:, None] * du)
                g = (du * cand[2]).sum(dim=1)
                done = done | ((g <= 0) & ((ls == 0) | (g.abs() <= 0.5 * g0.abs())))
                if bool(done.all()):
                    break
                below = g <= 0
                lo, g_lo = torch.where(below, alpha, lo), torch.where(below, g, g_lo)
                hi, g_hi = torch.where(below, hi, alpha), torch.where(below, g_hi, g)
                sec = lo + (hi - lo) * g_lo / (g_lo - g_hi).clamp_min(1e-300)
                width = hi - lo
                alpha = torch.where(done, alpha, torch.minimum(torch.maximum(sec, lo + 0.1 * width), hi - 0.1 * width))
            else:  # not bracketed closely enough: the last point where g <= 0 still lowers the convex function
                alpha = torch.where(done, alpha, lo)
                cand = forces(props, wall, f_el, o, plastic, yielded, s, v, force, u + alpha[:, None] * du)
            u = u + alpha[:, None] * du
            ds, st, r = cand
        newton_iters.append(max_newton)
        unconverged[0] += 1
        return ds, None

    def linear_increment(props, wall, f_el, o, plastic, yielded, s, v, force):
        # one solve with the tangent at the predictor dt v; the velocity change is the solve's
        _, st, r = forces(props, wall, f_el, o, plastic, yielded, s, v, force, torch.zeros_like(v))
        u = correction(st, r, list(range(B)), True)
        newton_iters.append(1)
        return dt * v + theta * dt * u, u

    with torch.no_grad():
        step = linear_increment if linear else increment
        res = sim._run_torch(props, wall, n_out, sensor_idx, record_cells, increment=step, theta=theta)
    live = int((props.yield_c != 0).any(dim=0).sum())
    steps = (n_out - 1) * sim.substeps
    solves = len(iters) / max(B * steps, 1)  # linear solves per simulation step
    stats = {
        "steps": steps,
        "newton_mean": float(np.mean(newton_iters)),
        "newton_max": int(max(newton_iters, default=0)),
        "unconverged_steps": unconverged[0],
        "cg_iters_mean": float(np.mean(iters)) if iters else 0.0,
        "cg_iters_max": int(max(iters, default=0)),
        "force_evals_per_step": evals[0] / max(steps, 1),
        "link_passes_per_step": evals[0] / max(steps, 1) + float(np.sum(iters)) / max(B * steps, 1),
        "solves_per_step": solves,
        "n_links": live,
    }
    return res, stats
