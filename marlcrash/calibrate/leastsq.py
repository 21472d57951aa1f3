"""Levenberg-Marquardt steps on pulse residuals, shared by the ``lm`` baseline and ``local_fit``.

The residual of a candidate is its compared velocity minus the reference's, times ``sqrt(dt)``
(:meth:`~marlcrash.calibrate.problem.CalibrationProblem.residuals`), over every sensor and the
output samples of a window, so the cost ``|r|^2`` is the summed ``integral (v - v_ref)^2 dt``.
One iteration:

1. :func:`fd_points`: a forward finite-difference Jacobian over the ``n`` free log-scale
   coordinates, ``n`` simulations in one batch (backward at the upper bound of the box, a shorter
   one-sided step where the box is narrower than the step: every point stays in the box; the
   current point's residual is reused).
2. :func:`damped_steps`: candidates ``z + s(lambda f)`` for the damping factors ``f`` of
   ``STEP_FACTORS`` in one more batch, ``s`` solving ``(J^T J + lambda f D) s = -J^T r``, clipped
   to the box. ``D`` is the diagonal of ``J^T J`` floored at ``DIAG_FLOOR`` of its largest entry:
   without the floor, coordinates the pulses barely see took steps to the edge of the box and
   every step was rejected. A Jacobian column with a non-finite entry (a finite-difference point
   the simulator could not run) is zeroed, so its coordinate is held for the iteration instead of
   poisoning every step; a step that still comes out non-finite (a non-finite residual ``r``) is
   zero, so no candidate is ever non-finite.
3. :func:`next_damping`: the best candidate is kept if it lowers the cost and ``lambda`` becomes
   ``lambda f / 3``; otherwise ``lambda`` grows 30x.

:func:`lm_iteration` runs the three; a candidate with a NaN residual never wins.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from marlcrash.errors import ConfigError

STEP_FACTORS: tuple[float, ...] = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)
"""Damping factors tried per iteration, one batch [-]."""
DIAG_FLOOR = 1e-3
"""Floor of the scaling diagonal ``D`` relative to its largest entry [-]."""


FLOAT32_FD_STEP = 1e-3
"""Smallest finite-difference step on a ``float32`` simulation [-]: at 1e-5 a float32 simulation's differences are
rounding noise (Jacobian 4.5x off float64's over 50 ms), at 1e-3 within a fifth of it."""


def check_fd_step(fd_step: float, sim_dtype: str, key: str, source: str | None = None) -> None:
    """Refuse a finite-difference step that the simulations' rounding swamps, before any simulation.

    Args:
        fd_step: the log-scale step [-].
        sim_dtype: the precision the problem simulates in (the env's ``sim_dtype``).
        key: the setting to name in the error (``lm.fd_step``, ``fd_step``).
        source: the config file, if any.

    Raises:
        ConfigError: (``key``) ``float32`` simulations and ``fd_step`` below :data:`FLOAT32_FD_STEP`.
    """
    if sim_dtype == "float32" and fd_step < FLOAT32_FD_STEP:
        raise ConfigError(
            f"the env simulates in float32 (sim_dtype), whose rounding swamps a finite difference of "
            f"{fd_step:g} (the Jacobian came out several times off float64's); expected a step of at least "
            f"{FLOAT32_FD_STEP:g}, or a float64 env",
            key=key,
            path=source,
        )


def fd_points(z: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, fd_step: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Finite-difference points ``[n, n]`` around ``z [n]`` (in the box ``[lo, hi]``) and their signed steps ``h [n]``.

    Row ``i`` is ``z + h_i e_i``, inside the box: ``h_i = fd_step``, or ``-fd_step`` where that would leave the box
    above; where neither fits (a box narrower than ``fd_step`` along ``i``: the whole step backward left it below)
    the point is the farther bound, a shorter one-sided step, and ``h_i = 0`` where the box has no width there
    (:func:`jacobian` gives that column zero).
    """
    fwd = z + fd_step <= hi
    bwd = ~fwd & (z - fd_step >= lo)
    edge = torch.where(hi - z >= z - lo, hi, lo)  # the farther bound
    point = torch.where(fwd, z + fd_step, torch.where(bwd, z - fd_step, edge))
    h = torch.where(fwd, fd_step, torch.where(bwd, -fd_step, edge - z))
    points = z.expand(z.numel(), -1).clone()
    points.diagonal().copy_(point)
    return points, h


def jacobian(r_fd: torch.Tensor, r: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """``[m, n]`` Jacobian from the residuals ``r_fd [n, m]`` of :func:`fd_points` and ``r [m]`` at ``z`` (a zero
    column where ``h`` is zero: a coordinate whose box has no width)."""
    moved = h != 0
    return torch.where(moved, (r_fd - r).T / torch.where(moved, h, torch.ones_like(h)), 0.0)


def damped_steps(
    jac: torch.Tensor,
    r: torch.Tensor,
    z: torch.Tensor,
    lam: float,
    lo: torch.Tensor,
    hi: torch.Tensor,
    factors: tuple[float, ...] = STEP_FACTORS,
) -> torch.Tensor:
    """Candidates ``[len(factors), n]``: ``z`` plus the damped Gauss-Newton step per factor, clipped to the box.

    Non-finite Jacobian columns are zeroed (their coordinates do not move) and non-finite steps are zero
    (module docstring), so every candidate is finite.
    """
    jac = torch.where(torch.isfinite(jac).all(0), jac, torch.zeros_like(jac))
    jtj, grad = jac.T @ jac, jac.T @ r
    d = torch.diagonal(jtj)
    top = float(d.max())
    diag = torch.diag(d.clamp_min(DIAG_FLOOR * top + 1e-300) if top > 0 else torch.ones_like(d))  # J = 0: no step
    steps = [torch.linalg.solve(jtj + lam * f * diag, -grad) for f in factors]
    steps = [torch.where(torch.isfinite(s).all(), s, torch.zeros_like(s)) for s in steps]
    return torch.stack([torch.minimum(torch.maximum(z + s, lo), hi) for s in steps])


def next_damping(lam: float, accepted_factor: float | None) -> float:
    """``lambda`` after an iteration: ``lambda f / 3`` if the step with factor ``f`` was kept, else ``30 lambda``."""
    return lam * accepted_factor / 3.0 if accepted_factor is not None else lam * 30.0


@dataclass
class LMStep:
    """Outcome of :func:`lm_iteration`: the point ``z``, its residual ``r`` and ``lam`` to go on with;
    ``rel``, the relative cost decrease (0 when rejected); ``accepted``, the index of the kept candidate
    (``None``: rejected, ``z`` and ``r`` unchanged); ``aux``, what ``run`` returned with the candidates."""

    z: torch.Tensor
    r: torch.Tensor
    lam: float
    rel: float
    accepted: int | None
    aux: Any


def lm_iteration(
    run: Callable[[torch.Tensor], tuple[torch.Tensor, Any]],
    z: torch.Tensor,
    r: torch.Tensor,
    lam: float,
    lo: torch.Tensor,
    hi: torch.Tensor,
    fd_step: float,
) -> LMStep:
    """One Levenberg-Marquardt iteration from ``z [n]`` with residual ``r [m]`` (module docstring).

    ``run(zs [N, n])`` simulates a batch and returns its residuals ``[N, m]`` and anything else
    (``aux``); it is called twice, for the ``n`` finite-difference points and the ``len(STEP_FACTORS)``
    candidates.
    """
    points, h = fd_points(z, lo, hi, fd_step)
    r_fd, _ = run(points)
    cand = damped_steps(jacobian(r_fd, r, h), r, z, lam, lo, hi)
    r_c, aux = run(cand)
    cost = torch.nan_to_num((r_c**2).sum(1), nan=math.inf)
    b, c0 = int(cost.argmin()), float((r**2).sum())
    if float(cost[b]) < c0:
        return LMStep(cand[b], r_c[b], next_damping(lam, STEP_FACTORS[b]), 1.0 - float(cost[b]) / c0, b, aux)
    return LMStep(z, r, next_damping(lam, None), 0.0, None, aux)
