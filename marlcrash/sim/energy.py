"""Energy accounting of the cell surrogate (DESIGN 4).

The integrator is symplectic Euler (leapfrog): ``v^{n+1/2} = v^{n-1/2} + dt F^n / m``,
``s^{n+1} = s^n + dt v^{n+1/2}``. With the leapfrog kinetic energy
``KE^n = sum(m v^{n-1/2} v^{n+1/2}) / 2`` one has exactly

    KE^n - KE^{n-1} = sum((F^n + F^{n-1}) / 2 * (s^n - s^{n-1})),

so accumulating every element's work with the *same* discrete forces (trapezoid
over each displacement increment) closes the balance
``KE + W_links + W_wall = KE^0`` to rounding. Element work splits into stored
(elastic, ``f^2 / 2k``) and absorbed (plastic, densification, viscous) parts:
``absorbed = work - stored``. The return-mapping plastic work is tracked
separately, as an independent check of that split.

Per-cell energy flow is measured in the inertial frame moving with the initial
vehicle velocity (the frame in which the wall drives into a resting vehicle, as
the paper pictures energy flowing rearward). With ``r = v0 t - s`` the rearward
displacement in that frame, a link ``src -> dst`` with compression force ``f``
takes ``f dr_src`` from ``src`` and passes ``T = f dr_dst`` on to ``dst``; the
difference is its own work. So for a cell ``c``:

- input: sum of ``T`` over links into ``c``, plus the wall work ``f_w v0 dt`` on it;
- absorbed: absorbed part of its own links' (and its wall contact's) work;
- transmitted: sum of ``T`` over its own links (to downstream cells).
"""

from __future__ import annotations

import numpy as np
import torch

from marlcrash.errors import ModelError


def scatter_sum(values: torch.Tensor, index: torch.Tensor, n: int) -> torch.Tensor:
    """Sum ``values [B, L, *]`` into ``n`` bins along dim 1 by ``index [L]`` -> ``[B, n, *]``."""
    out = values.new_zeros((values.shape[0], n, *values.shape[2:]))
    return out.index_add(1, index, values)


def cell_energies(
    link_work: torch.Tensor,
    link_passed: torch.Tensor,
    link_stored: torch.Tensor,
    wall_work: torch.Tensor,
    wall_input: torch.Tensor,
    wall_stored: torch.Tensor,
    src: torch.Tensor,
    dst: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-cell cumulative input, absorbed and transmitted energy.

    Args:
        link_work: ``[B, L, *]`` work done on each link [J].
        link_passed: ``[B, L, *]`` work each link passed on to its ``dst`` cell [J].
        link_stored: ``[B, L, *]`` elastic energy stored in each link [J].
        wall_work: ``[B, n, *]`` work done on each cell's wall contact [J].
        wall_input: ``[B, n, *]`` wall work entering each cell (moving frame) [J].
        wall_stored: ``[B, n, *]`` elastic energy in each wall contact [J].
        src, dst: ``[L]`` link end cells.

    Returns:
        ``(input, absorbed, transmitted)``, each ``[B, n, *]`` [J].
    """
    n = wall_work.shape[1]
    inp = scatter_sum(link_passed, dst, n) + wall_input
    absorbed = scatter_sum(link_work - link_stored, src, n) + (wall_work - wall_stored)
    transmitted = scatter_sum(link_passed, src, n)
    return inp, absorbed, transmitted


def balance_error(kinetic: torch.Tensor, stored: torch.Tensor, absorbed: torch.Tensor, initial: torch.Tensor):
    """Relative energy balance error ``|KE + stored + absorbed - E0| / E0``.

    Args:
        kinetic, stored, absorbed: ``[B, T]`` totals [J].
        initial: ``[B]`` initial kinetic energy [J].

    Returns:
        ``[B, T]`` relative error [-].
    """
    return (kinetic + stored + absorbed - initial[:, None]).abs() / initial[:, None]


def max_balance_error(result) -> float:
    """Largest relative balance error over batch and output steps of a :class:`SimResult`.

    Raises:
        ModelError: a result of no batch rows (a slice of none: the largest of nothing failed inside torch).
    """
    if result.initial.shape[0] == 0:
        raise ModelError("max_balance_error: the result has no batch rows (B = 0); give a result of at least one row")
    err = balance_error(result.kinetic, result.stored, result.absorbed, result.initial)
    return float(err.max())


def behaviour_curve(result, cell: int, batch: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's behaviour relation of one cell: absorbed vs input energy over time.

    Args:
        result: a :class:`SimResult` recorded with per-cell series.
        cell: cell index.
        batch: batch row.

    Returns:
        ``(input [T], absorbed [T])`` [J].

    Raises:
        ModelError: a result without per-cell series (``record_cells`` ``final`` or ``none``: one point or none), or
            a cell or batch row outside the result.
    """
    B, n, records = result.cell_input.shape
    if records != result.time.shape[0]:
        mode = "final" if records == 1 else "none"
        raise ModelError(
            f"the behaviour curve needs the per-cell energy series: run with record_cells='series' (this result "
            f"has {records} per-cell record{'s' if records != 1 else ''}, record_cells='{mode}')"
        )
    for name, i, size in (("cell", cell, n), ("batch row", batch, B)):
        if isinstance(i, bool) or not isinstance(i, int | np.integer) or not 0 <= i < size:
            raise ModelError(f"{name} {i!r} is not in [0, {size}) of this result")
    return result.cell_input[batch, cell], result.cell_absorbed[batch, cell]
