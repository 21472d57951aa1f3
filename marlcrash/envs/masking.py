"""The impact-region rule (DESIGN 1.4, 5): which agents may act in an episode.

Regions, batched over ``B`` scenarios (overlap fraction, struck side, speed):

- *Primary*: deformable cells struck by the barrier: the barrier's lateral band
  (:func:`marlcrash.sim.scenario.barrier_fraction` ``> 0`` over the cell's y-extent)
  and no deeper than ``primary_depth`` metres behind the front-most struck cell.
- *Secondary*: cells the load reaches early, i.e. not primary, reachable from a
  primary cell along at most ``secondary_hops`` directed links (load-path direction
  ``src -> dst``) whose directions are in ``secondary_directions``, and whose
  centroid lies at most ``secondary_depth`` metres behind the front-most struck cell.
  At ``speed_depth_time > 0`` both depths grow with the impact speed by
  ``speed * speed_depth_time`` (faster crashes load deeper structure within the window).

An agent is active when at least ``min_fraction`` of its cells (and at least one)
lie in the region of the mode: ``none`` (every agent active), ``primary``,
``primary_secondary`` (union of both regions).

What an active agent acts on (``cells``): ``agent``, all its cells (a sub-assembly's seven factors scale all of
them); ``region``, only its cells in the region, DESIGN 1.4's rule taken per cell ("no actions on cells outside
the primary or secondary impact region"): in a driver-side small overlap, the passenger-side half of an active
bumper beam keeps its parameters. ``agent`` is the default the documented runs used; ``region`` is the ablation.

The saturation preference (DESIGN 1.4) is configured here too: when
``saturation_preference`` is on, behaviour-parameter changes of cells that saturated
in the last simulation are multiplied by ``saturation_damping``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch

from marlcrash.cells.model import DIRECTIONS, CellModel
from marlcrash.config import require
from marlcrash.envs.agents import AgentLayout
from marlcrash.sim.scenario import CrashScenario, barrier_fraction, scenario_tensors


@dataclass
class MaskingConfig:
    """Impact-region masking and saturation preference (module docstring); values in ``configs/env``."""

    mode: Literal["none", "primary", "primary_secondary"] = "primary_secondary"
    primary_depth: float = 1.2
    secondary_hops: int = 2
    secondary_depth: float = 0.6
    secondary_directions: list[str] = field(default_factory=lambda: list(DIRECTIONS))
    speed_depth_time: float = 0.0
    min_fraction: float = 0.1
    cells: Literal["agent", "region"] = "agent"
    saturation_preference: bool = True
    saturation_damping: float = 0.2

    def validate(self) -> None:
        require(self.primary_depth > 0, "primary_depth", f"must be > 0 m, got {self.primary_depth}")
        require(self.secondary_hops >= 0, "secondary_hops", f"must be >= 0, got {self.secondary_hops}")
        require(self.secondary_depth >= 0, "secondary_depth", f"must be >= 0 m, got {self.secondary_depth}")
        bad = [d for d in self.secondary_directions if d not in DIRECTIONS]
        require(not bad, "secondary_directions", f"expected directions from {list(DIRECTIONS)}, got {bad}")
        twice = sorted({d for d in self.secondary_directions if self.secondary_directions.count(d) > 1})
        require(not twice, "secondary_directions", f"expected each direction at most once, got {twice} more than "
                "once (a typo for another direction?); [] follows no link, as secondary_hops: 0")  # fmt: skip
        require(self.speed_depth_time >= 0, "speed_depth_time", f"must be >= 0 s, got {self.speed_depth_time}")
        require(0.0 < self.min_fraction <= 1.0, "min_fraction", f"must be in (0, 1], got {self.min_fraction}")
        require(0.0 <= self.saturation_damping <= 1.0, "saturation_damping",
                f"must be in [0, 1], got {self.saturation_damping}")  # fmt: skip


_ON_DEPTH_LIMIT = 1e-9
"""[m] A cell this close to a region's depth limit lies on it, inside the region."""


class ImpactRegions:
    """Batched impact regions and agent activity for one cell model and agent layout.

    Args:
        cells: the cell model.
        layout: the agents.
        config: masking settings.
    """

    def __init__(self, cells: CellModel, layout: AgentLayout, config: MaskingConfig):
        self.config = config
        self.layout = layout
        dt = torch.float64
        self.lo_y = torch.as_tensor(cells.lo[:, 1], dtype=dt)
        self.hi_y = torch.as_tensor(cells.hi[:, 1], dtype=dt)
        self.x = torch.as_tensor(cells.centroid[:, 0], dtype=dt)
        self.lo_x = torch.as_tensor(cells.lo[:, 0], dtype=dt)
        self.width = float(cells.vehicle_width)
        self.centre_y = cells.centre_y
        self.deformable = torch.as_tensor(~cells.is_null & ~cells.is_rigid)
        keep = np.isin(cells.link_dir, [DIRECTIONS.index(d) for d in config.secondary_directions])
        self.src = torch.as_tensor(cells.link_src[keep].astype(np.int64))
        self.dst = torch.as_tensor(cells.link_dst[keep].astype(np.int64))
        self.n = cells.n_cells

    def _depth(self, base: float, speed: torch.Tensor) -> torch.Tensor:
        # a cell on the limit within round-off lies inside (a centroid 0.6 m behind the front came out 0.6 + 2e-15 m)
        return base + self.config.speed_depth_time * speed.to(torch.float64) + _ON_DEPTH_LIMIT  # [B]

    def primary(self, overlap: torch.Tensor, side: torch.Tensor, speed: torch.Tensor) -> torch.Tensor:
        """``[B, n_cells]`` bool primary region for ``[B]`` overlaps, sides (+1 left, -1 right), speeds [m/s]."""
        ov = overlap.to(torch.float64)
        frac = barrier_fraction(self.lo_y, self.hi_y, self.width, ov, side, centre_y=self.centre_y)
        struck = (frac > 0) & self.deformable
        front = torch.where(struck, self.lo_x, torch.full_like(frac, float("inf"))).amin(dim=1, keepdim=True)
        self._front = front
        return struck & (self.lo_x - front <= self._depth(self.config.primary_depth, speed)[:, None])

    def regions(
        self, overlap: torch.Tensor, side: torch.Tensor, speed: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Primary and secondary regions, each ``[B, n_cells]`` bool (disjoint)."""
        prim = self.primary(overlap, side, speed)
        reach = prim.clone()
        frontier = prim.to(torch.float64)
        for _ in range(self.config.secondary_hops):  # loop over hops, vectorized over cells and links
            step = torch.zeros_like(frontier).index_add_(1, self.dst, frontier[:, self.src])
            new = (step > 0) & ~reach
            if not bool(new.any()):  # the reach stopped growing: further hops add nothing (a large count ends here)
                break
            reach |= new
            frontier = new.to(torch.float64)
        near = self.x[None, :] - self._front <= self._depth(self.config.secondary_depth, speed)[:, None]
        second = reach & ~prim & near & self.deformable
        return prim, second

    def region(self, overlap: torch.Tensor, side: torch.Tensor, speed: torch.Tensor) -> torch.Tensor:
        """``[B, n_cells]`` bool: the region of the configured mode (every cell for ``none``)."""
        if self.config.mode == "none":
            return torch.ones(overlap.shape[0], self.n, dtype=torch.bool)
        prim, second = self.regions(overlap, side, speed)
        return prim if self.config.mode == "primary" else prim | second

    def active(
        self, overlap: torch.Tensor, side: torch.Tensor, speed: torch.Tensor, region: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``[B, n_agents]`` bool activity flags for the configured mode (``region``: :meth:`region`, if known)."""
        B = overlap.shape[0]
        if self.config.mode == "none":
            return torch.ones(B, self.layout.n_agents, dtype=torch.bool)
        region = self.region(overlap, side, speed) if region is None else region
        inside = region[:, self.layout.cells] & self.layout.valid  # [B, A, M]
        n_in = inside.sum(-1)
        # the share in float64, a correctly rounded quotient: 15 / 50 is the float 0.3 exactly, where 0.3 * 50 (float32
        # from a Python float times int64 counts) was 15.000001 and left an agent with exactly min_fraction inactive
        share = n_in.to(torch.float64) / self.layout.count.to(torch.float64)
        return (n_in > 0) & (share >= self.config.min_fraction)

    def acting(
        self, overlap: torch.Tensor, side: torch.Tensor, speed: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(active [B, n_agents], acting [B, n_cells])``: the agents active on ``[B]`` load cases and the cells their
        actions reach (every cell they own, or with ``cells: region`` their cells in the region), as
        :class:`~marlcrash.envs.core.CalibrationCore` applies them."""
        region = self.region(overlap, side, speed)
        active = self.active(overlap, side, speed, region)
        owner = self.layout.agent_of_cell
        acting = (owner >= 0)[None] & active[:, owner.clamp_min(0)]
        if self.config.cells == "region":
            acting &= region
        return active, acting

    def idle_scenarios(self, scenarios: list[CrashScenario]) -> list[str]:
        """Sentences for the scenarios whose episodes would activate no agent (empty where every one has some).

        Such an episode calibrates nothing: every action is masked. On a deck it mostly means its lateral axis is
        not marlcrash's y (``vehicle_options.axis_map``: a height read as the width strikes almost nothing on one
        side); otherwise ``min_fraction`` or the depths are too strict for the agents' sizes.
        """
        if not scenarios or self.config.mode == "none":
            return []
        rows = scenario_tensors(scenarios)
        ov, sd, sp = rows["overlap"], rows["side"], rows["speed"]
        active = self.active(ov, sd, sp).any(dim=1)
        struck = self.primary(ov, sd, sp).sum(dim=1)
        total, mode, frac = int(self.deformable.sum()), self.config.mode, self.config.min_fraction
        return [f"scenario {s.name!r} activates no agent: its barrier strikes {int(n)} of {total} deformable cells, "
                f"too few of any agent's (masking.mode {mode}, min_fraction {frac:g})"
                for s, a, n in zip(scenarios, active, struck, strict=True) if not a]  # fmt: skip
