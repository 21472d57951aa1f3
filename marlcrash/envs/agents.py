"""Agents: which cells each calibration agent owns (DESIGN 5).

By default every sub-assembly of the :class:`~marlcrash.cells.model.CellModel` is one
agent, named after it (``front_rail_left``, ``cooling_module``); the rigid compartment
and null cells belong to no agent. :class:`AgentsConfig` changes that layout:

- ``split_lr``: sub-assemblies split into ``<name>_left`` (cell centroid ``y > y0``) and
  ``<name>_right`` (``y < y0``); a centroid exactly on ``y0`` goes to ``split_centre``. ``y0`` is
  the vehicle's centre line (``CellModel.centre_y``; 0 for a centred vehicle), the reference of
  the section planes and the barrier too.
- ``merge``: new agent name -> sub-assemblies that form one agent (small parts).
- ``custom``: explicit agents, each a list of sub-assemblies restricted to a side.
- ``rest``: ``auto`` makes one agent of every sub-assembly not named above; ``none``
  creates no further agents (then every deformable cell must be covered explicitly).

Every deformable (non-null, non-rigid) cell must be owned by exactly one agent; a
layout that leaves a cell unowned or owns one twice is a :class:`ConfigError` naming
the cell and its sub-assembly.

:class:`AgentLayout` is the result as index tensors: ``cells [n_agents, max_cells]``
padded with the compartment index, ``valid [n_agents, max_cells]``, and the inverse
maps ``agent_of_cell [n_cells]`` / ``slot_of_cell [n_cells]`` (-1 where unowned).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch

from marlcrash.cells.grid import EDGE_TOL
from marlcrash.cells.model import CellModel
from marlcrash.config import require
from marlcrash.errors import ConfigError


@dataclass
class AgentSpec:
    """One explicitly defined agent.

    Attributes:
        name: agent name (unique).
        subassemblies: sub-assembly names whose cells it owns.
        side: ``any``, ``left`` (centroid ``y > y0``, the centre line, plus ``y = y0`` when ``split_centre``
            is ``left``) or ``right``.
    """

    name: str = ""
    subassemblies: list[str] = field(default_factory=list)
    side: Literal["any", "left", "right"] = "any"

    def validate(self) -> None:
        require(bool(self.name), "name", "an agent needs a non-empty name")
        require(bool(self.subassemblies), "subassemblies", f"agent {self.name!r} lists no sub-assembly")


@dataclass
class AgentsConfig:
    """How sub-assemblies become agents (module docstring); values in ``configs/env/*.yaml``."""

    split_lr: list[str] = field(default_factory=list)
    split_centre: Literal["left", "right"] = "left"
    merge: dict[str, list[str]] = field(default_factory=dict)
    custom: list[AgentSpec] = field(default_factory=list)
    rest: Literal["auto", "none"] = "auto"

    def validate(self) -> None:
        require(len(set(self.split_lr)) == len(self.split_lr), "split_lr", f"duplicate names in {self.split_lr}")
        for name, subs in self.merge.items():
            # as a custom agent's name: an agent named '' was built (a blank PettingZoo agent, a blank column)
            require(bool(name), "merge", f"a merge group needs a non-empty agent name, got {name!r} for {subs}")
            require(bool(subs), f"merge.{name}", f"merge group {name!r} lists no sub-assembly")
        names = [c.name for c in self.custom]
        require(len(set(names)) == len(names), "custom", f"duplicate custom agent names in {names}")


@dataclass
class AgentLayout:
    """Agents and the cells they own, as tensors (shapes with ``A`` agents, ``M`` max cells).

    Attributes:
        names: ``[A]`` agent names.
        subassemblies: ``[A]`` tuples of the sub-assembly names each agent draws from.
        cells: ``[A, M]`` int64 owned cell indices, padded with the compartment index.
        valid: ``[A, M]`` bool, which slots of ``cells`` are real.
        count: ``[A]`` int64 cells per agent.
        agent_of_cell: ``[n_cells]`` int64 owning agent, -1 for unowned (null, rigid) cells.
        slot_of_cell: ``[n_cells]`` int64 slot of the cell in its agent's row, -1 if unowned.
    """

    names: list[str]
    subassemblies: list[tuple[str, ...]]
    cells: torch.Tensor
    valid: torch.Tensor
    count: torch.Tensor
    agent_of_cell: torch.Tensor
    slot_of_cell: torch.Tensor

    @property
    def n_agents(self) -> int:
        return len(self.names)

    @property
    def max_cells(self) -> int:
        return int(self.cells.shape[1])

    @property
    def owned(self) -> torch.Tensor:
        """``[n_cells]`` bool, cell owned by some agent."""
        return self.agent_of_cell >= 0

    def index(self, name: str) -> int:
        """Index of an agent by name; :class:`ConfigError` listing the names if unknown."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(f"unknown agent {name!r}; agents are {self.names}", key="agent") from None


def _side_mask(cells: CellModel, side: str, centre: str) -> np.ndarray:
    y = cells.centroid[:, 1] - cells.centre_y  # sides of the centre line, not of y = 0 (AxisMap.y_center)
    # on the line within rounding: the centre line of a car off y = 0 carries the round-off of its shift (-2.8e-17 m
    # sent a centre-plane plate's 36 cells right instead of to split_centre's left)
    on = np.abs(y) <= _ON_CENTRE_LINE
    if side == "any":
        return np.ones(cells.n_cells, dtype=bool)
    if side == "left":
        return ((y > 0) & ~on) | (on & (centre == "left"))
    return ((y < 0) & ~on) | (on & (centre == "right"))


_ON_CENTRE_LINE = 4 * EDGE_TOL
"""[m] A centroid this close to the vehicle's centre line lies on it (``split_centre`` decides its side): material in
the centre plane is split into halves ``2 EDGE_TOL`` either side of it (:mod:`marlcrash.cells.grid`), whose cells
are on the line."""


def build_agents(cells: CellModel, config: AgentsConfig) -> AgentLayout:
    """Build the agent layout of a cell model.

    Args:
        cells: the cell model.
        config: splits, merges, custom agents (module docstring).

    Returns:
        The :class:`AgentLayout`; agents in order: custom, merges, the ``split_lr`` sub-assemblies in the config's
        order (each as ``_left``, then ``_right``), then the remaining ones in the model's order.

    Raises:
        ConfigError: an unknown sub-assembly name, an empty agent, a duplicate name, a cell
            owned twice or a deformable cell left unowned (the message names the cell and
            its sub-assembly).
    """
    known = [s for k, s in enumerate(cells.subassembly_names) if not cells.is_rigid[cells.subassembly == k].any()]
    deformable = ~cells.is_null & ~cells.is_rigid & (cells.subassembly >= 0)

    def sub_mask(name: str, key: str) -> np.ndarray:
        if name not in known:
            raise ConfigError(f"unknown sub-assembly {name!r}; the cell model has {known}", key=key)
        return deformable & (cells.subassembly == cells.subassembly_names.index(name))

    groups: list[tuple[str, tuple[str, ...], np.ndarray, str]] = []  # name, subs, mask, config key
    named: set[str] = set()
    for i, spec in enumerate(config.custom):
        key = f"agents.custom[{i}]"
        mask = np.zeros(cells.n_cells, dtype=bool)
        for s in spec.subassemblies:
            mask |= sub_mask(s, f"{key}.subassemblies")
        mask &= _side_mask(cells, spec.side, config.split_centre)
        groups.append((spec.name, tuple(spec.subassemblies), mask, key))
        named.update(spec.subassemblies)
    for name, subs in config.merge.items():
        mask = np.zeros(cells.n_cells, dtype=bool)
        for s in subs:
            mask |= sub_mask(s, f"agents.merge.{name}")
        groups.append((name, tuple(subs), mask, f"agents.merge.{name}"))
        named.update(subs)
    for s in config.split_lr:
        m = sub_mask(s, "agents.split_lr")
        for side in ("left", "right"):
            groups.append((f"{s}_{side}", (s,), m & _side_mask(cells, side, config.split_centre), "agents.split_lr"))
        named.add(s)
    if config.rest == "auto":
        for s in known:
            if s not in named:
                groups.append((s, (s,), sub_mask(s, "agents"), "agents.rest"))

    names = [g[0] for g in groups]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"agent names must be unique; {dup} defined more than once", key="agents")
    for name, members, mask, key in groups:
        if not mask.any():
            raise ConfigError(f"agent {name!r} (from {list(members)}) owns no deformable cell", key=key)

    owners = np.stack([g[2] for g in groups]) if groups else np.zeros((0, cells.n_cells), dtype=bool)
    n_owners = owners.sum(axis=0)
    twice = np.flatnonzero(n_owners > 1)
    if twice.size:
        c = int(twice[0])
        who = [names[a] for a in np.flatnonzero(owners[:, c])]
        raise ConfigError(
            f"cell {c} of sub-assembly {cells.subassembly_names[cells.subassembly[c]]!r} is owned by several "
            f"agents {who}; every cell must belong to exactly one agent ({twice.size} such cells)",
            key="agents",
        )
    unowned = np.flatnonzero(deformable & (n_owners == 0))
    if unowned.size:
        c = int(unowned[0])
        raise ConfigError(
            f"cell {c} of sub-assembly {cells.subassembly_names[cells.subassembly[c]]!r} (centroid y = "
            f"{cells.centroid[c, 1]:.3f} m) is owned by no agent; expected every deformable cell to belong to "
            f"one ({unowned.size} unowned cells)",
            key="agents",
        )

    count = owners.sum(axis=1)
    max_cells = int(count.max())
    idx = np.full((len(groups), max_cells), cells.compartment, dtype=np.int64)
    valid = np.zeros((len(groups), max_cells), dtype=bool)
    agent_of = np.full(cells.n_cells, -1, dtype=np.int64)
    slot_of = np.full(cells.n_cells, -1, dtype=np.int64)
    for a, row in enumerate(owners):  # loop over agents at construction only (I/O edge)
        own = np.flatnonzero(row)
        idx[a, : own.size] = own
        valid[a, : own.size] = True
        agent_of[own] = a
        slot_of[own] = np.arange(own.size)
    return AgentLayout(
        names=names,
        subassemblies=[g[1] for g in groups],
        cells=torch.as_tensor(idx),
        valid=torch.as_tensor(valid),
        count=torch.as_tensor(count.astype(np.int64)),
        agent_of_cell=torch.as_tensor(agent_of),
        slot_of_cell=torch.as_tensor(slot_of),
    )
