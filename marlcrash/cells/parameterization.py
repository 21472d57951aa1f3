"""The calibration parameter space of a cell model: log-scale increments to feasible parameters.

Agents, baselines and the twin reference all move through this one mapping, so a hidden
twin perturbation is exactly reachable by the calibrators:

- behaviour: ``E <- clip(E * exp(d), lo * E0, hi * E0)`` for ``E_x`` and ``E_s``;
- transmission: ``g = ((f + floor) * exp(d) - floor)^+`` on feasible entries (zero elsewhere),
  with ``g_x`` raised to the largest lateral ``g`` where x is feasible (DESIGN 1.3 boundary condition 3: x,
  the principal direction of force, transmits no less than any lateral direction), renormalised to sum one.
  The shift ``floor`` lets a feasible factor that is currently zero grow again; a zero increment (or one on
  infeasible factors only) leaves the cell unchanged (bit-exact).

  Without the condition an increment of -5 on ``f_x`` left the lateral links as the principal direction and the
  axial ones with a share near 0: the cells behind a front cell, the up-front sensors among them, drove on at the
  impact speed through it and through the wall (the simulator's cells interact only through their links).
"""

from __future__ import annotations

import torch


def apply_increments(
    params: torch.Tensor,
    inc: torch.Tensor,
    init: torch.Tensor,
    feasible: torch.Tensor,
    bounds: tuple[float, float],
    floor: float,
) -> torch.Tensor:
    """Apply per-cell log increments to parameters, keeping them feasible.

    Args:
        params: ``[B, n_cells, 7]`` current parameters.
        inc: ``[B, n_cells, 7]`` log increments (zero: unchanged).
        init: ``[n_cells, 7]`` initial parameters (bounds of ``E_x``, ``E_s``).
        feasible: ``[n_cells, 5]`` bool feasible transmission factors.
        bounds: ``(lo, hi)``: ``E`` stays within ``[lo, hi] * E0``.
        floor: shift of the multiplicative transmission update (module docstring).

    Returns:
        ``[B, n_cells, 7]`` new parameters: ``E`` in bounds, factors ``>= 0``, zero where
        infeasible, ``f_x`` no lower than a lateral factor where x is feasible, summing to one (cells with a non-zero
        increment on a feasible factor; others untouched).
    """
    e0 = init[None, :, :2]
    e = (params[..., :2] * torch.exp(inc[..., :2])).clamp(min=bounds[0] * e0, max=bounds[1] * e0)
    f = params[..., 2:]
    g = moved_factors(f, inc[..., 2:], feasible, floor)
    total = g.sum(-1, keepdim=True)
    # only a cell with a non-zero increment on a feasible factor changes: one on an infeasible factor alone (an
    # action slot of a per-cell policy that moves nothing) leaves the cell bit-exact, not renormalised by an ulp
    changed = ((inc[..., 2:] != 0) & feasible).any(-1, keepdim=True) & (total > 0)
    f_new = torch.where(changed, g / torch.where(total > 0, total, torch.ones_like(total)), f)
    return torch.cat([e, f_new], dim=-1)


def moved_factors(f: torch.Tensor, inc: torch.Tensor, feasible: torch.Tensor, floor: float) -> torch.Tensor:
    """Transmission factors ``f [..., 5]`` moved by log increments ``inc [..., 5]``, before they are renormalised.

    ``((f + floor) * exp(inc) - floor)^+`` on feasible entries (zero elsewhere), ``f_x`` then raised to the largest
    lateral factor where x is feasible (boundary condition 3, module docstring). Differentiable.
    """
    g = ((f + floor) * torch.exp(inc) - floor).clamp_min(0.0) * feasible
    g_x = torch.where(feasible[..., :1], torch.maximum(g[..., :1], g[..., 1:].amax(-1, keepdim=True)), g[..., :1])
    return torch.cat([g_x, g[..., 1:]], dim=-1)


def log_ratios(params: torch.Tensor, init: torch.Tensor, observed: torch.Tensor, floor: float) -> torch.Tensor:
    """``[..., n_cells, 7]`` the log-scale coordinates of ``params`` against ``init [n_cells, 7]``: ``log(E / E0)`` of
    ``E_x`` and ``E_s``, ``log((f + floor) / (f0 + floor))`` of a transmission factor; 0 where ``observed [n_cells, 7]``
    is False (a null cell's E, an infeasible factor) or the shifted value is not positive."""
    shift = torch.zeros(7, dtype=params.dtype)
    shift[2:] = floor
    num, den = params + shift, (init + shift).expand_as(params)
    ok = observed & (num > 0)
    return torch.where(ok, torch.log(torch.where(ok, num, 1.0) / torch.where(ok, den, 1.0)), 0.0)


def movable_factors(feasible: torch.Tensor) -> torch.Tensor:
    """``[n_cells, 5]`` bool: the transmission factors an increment can change.

    A feasible factor of a cell with at least two feasible ones. A cell with a single feasible direction
    transmits all of its load that way: whatever its increment, the renormalised factor stays one, so that
    entry of an action (or coordinate of a search) moves nothing.
    """
    return feasible & (feasible.sum(-1, keepdim=True) >= 2)
