"""Agents (ownership, splits, merges) and the impact-region masking rule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from marlcrash.envs.agents import AgentsConfig, AgentSpec, build_agents
from marlcrash.envs.core import build_cells, load_env_config
from marlcrash.envs.masking import ImpactRegions, MaskingConfig
from marlcrash.errors import ConfigError
from marlcrash.sim import get_scenario

SPLIT = ["bumper_beam", "subframe", "cooling_module", "dash_firewall", "hood"]


@pytest.fixture(scope="session")
def cells():
    return build_cells("b_segment", None, "optimized")


@pytest.fixture(scope="session")
def layout(cells):
    return build_agents(cells, AgentsConfig(split_lr=SPLIT))


def test_every_deformable_cell_owned_exactly_once(cells, layout):
    deform = ~cells.is_null & ~cells.is_rigid
    owned = layout.cells[layout.valid].numpy()
    assert np.sort(owned).tolist() == np.flatnonzero(deform).tolist()
    assert (layout.agent_of_cell.numpy()[~deform] == -1).all()
    a, s = layout.agent_of_cell[deform], layout.slot_of_cell[deform]
    assert torch.equal(layout.cells[a, s], torch.as_tensor(np.flatnonzero(deform)))
    assert "compartment" not in layout.names
    for side in ("left", "right"):
        assert f"front_rail_{side}" in layout.names and f"bumper_beam_{side}" in layout.names
    y = cells.centroid[:, 1]
    left = layout.cells[layout.index("hood_left")][layout.valid[layout.index("hood_left")]]
    assert (y[left.numpy()] >= 0).all()
    assert layout.count.sum() == deform.sum()


def test_merge_and_custom_agents(cells):
    cfg = AgentsConfig(merge={"wheels": ["wheel_left", "wheel_right"]},
                       custom=[AgentSpec("hood_front", ["hood"], "any")])  # fmt: skip
    lay = build_agents(cells, cfg)
    assert lay.names[:2] == ["hood_front", "wheels"]
    assert int(lay.count[1]) == len(cells.cells_of("wheel_left")) + len(cells.cells_of("wheel_right"))
    assert "wheel_left" not in lay.names and "hood" not in lay.names


def test_bad_layouts_are_config_errors_naming_the_cell(cells):
    with pytest.raises(ConfigError, match=r"cell \d+ of sub-assembly 'hood'.*owned by no agent"):
        others = [s for s in cells.subassembly_names[:-1] if s != "hood"]
        layout = AgentsConfig(custom=[AgentSpec("hood_l", ["hood"], "left")], rest="none", merge={"others": others})
        build_agents(cells, layout)
    with pytest.raises(ConfigError, match=r"sub-assembly 'hood' is owned by several agents"):
        build_agents(cells, AgentsConfig(split_lr=["hood"], merge={"top": ["hood", "dash_firewall"]}))
    with pytest.raises(ConfigError, match="unknown sub-assembly 'nose'"):
        build_agents(cells, AgentsConfig(split_lr=["nose"]))
    with pytest.raises(ConfigError, match="owns no deformable cell"):
        build_agents(cells, AgentsConfig(custom=[AgentSpec("w", ["wheel_left"], "right")]))
    with pytest.raises(ConfigError, match=r"agents\.custom"):
        load_env_config(overrides={"agents.custom": [{"name": "x", "subassemblies": []}]})
    with pytest.raises(ConfigError, match=r"key 'agents\.merge': a merge group needs a non-empty agent name"):
        load_env_config(overrides={"agents.merge": {"": ["wheel_left", "wheel_right"]}})  # built an agent named ''


def _active(cells, layout, mode, name, **kw):
    sc = get_scenario(name)
    reg = ImpactRegions(cells, layout, MaskingConfig(mode=mode, **kw))
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    act = reg.active(t(sc.overlap), t(sc.side_sign), t(sc.speed))[0]
    return {n for n, a in zip(layout.names, act.tolist(), strict=True) if a}


@pytest.mark.parametrize("mode", ["primary", "primary_secondary"])
def test_small_overlap_left_leaves_right_front_inactive(cells, layout, mode):
    on = _active(cells, layout, mode, "small_overlap_left")
    for agent in ("crash_box_right", "front_rail_right", "bumper_beam_right", "upper_load_path_right"):
        assert agent not in on
    for agent in ("crash_box_left", "front_rail_left", "bumper_beam_left"):
        assert agent in on
    mirror = _active(cells, layout, mode, "small_overlap_right")
    assert "crash_box_right" in mirror and "crash_box_left" not in mirror


def test_full_width_activates_all_front_agents_and_modes_nest(cells, layout):
    assert _active(cells, layout, "primary_secondary", "full_width_40") == set(layout.names)
    assert _active(cells, layout, "none", "small_overlap_left") == set(layout.names)
    for sc in ("offset40_left", "small_overlap_left", "offset40_right"):
        prim = _active(cells, layout, "primary", sc)
        both = _active(cells, layout, "primary_secondary", sc)
        assert prim <= both and len(prim) < len(layout.names)


def test_secondary_region_definition(cells, layout):
    cfg = MaskingConfig(secondary_hops=1, secondary_depth=0.3)
    reg = ImpactRegions(cells, layout, cfg)
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    prim, sec = (r[0].numpy() for r in reg.regions(t(0.25), t(1.0), t(17.8)))
    assert not (prim & sec).any()
    # independent re-derivation: one hop along any link from a primary cell, within 0.3 m of the struck front
    hop = np.zeros_like(prim)
    hop[cells.link_dst[prim[cells.link_src]]] = True
    front = cells.lo[prim, 0].min()
    expect = hop & ~prim & (cells.centroid[:, 0] - front <= 0.3) & ~cells.is_null & ~cells.is_rigid
    assert np.array_equal(sec, expect) and sec.any()
    # the struck band is y >= W/2 - 0.25 W on the left; every primary cell reaches into it
    assert (cells.hi[prim, 1] > cells.vehicle_width / 2 - 0.25 * cells.vehicle_width).all()
    none = ImpactRegions(cells, layout, MaskingConfig(secondary_hops=0)).regions(t(0.25), t(1.0), t(17.8))[1]
    assert not none.any()


def test_a_secondary_hop_count_beyond_the_reach_ends_when_the_reach_stops_growing(cells, layout):
    """``masking.secondary_hops`` has no upper bound (a large one: follow the links as far as they go), but every hop
    was walked whether it reached a new cell or not: 10**6 took 27 s per region (every reset of every episode),
    10**9 about 8 hours."""
    from torch.overrides import TorchFunctionMode

    class CountHops(TorchFunctionMode):  # one index_add_ per hop walked
        hops = 0

        def __torch_function__(self, func, types, args=(), kwargs=None):
            CountHops.hops += func is torch.Tensor.index_add_
            return func(*args, **(kwargs or {}))

    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    args = (t(0.25), t(1.0), t(17.8))
    every = ImpactRegions(cells, layout, MaskingConfig(secondary_hops=cells.n_cells)).regions(*args)
    with CountHops():
        far = ImpactRegions(cells, layout, MaskingConfig(secondary_hops=10**6)).regions(*args)
    assert 1 <= CountHops.hops < 100  # the reach stops growing within a few dozen hops, not 10**6
    assert all(torch.equal(a, b) for a, b in zip(far, every, strict=True))


def test_an_agent_with_exactly_min_fraction_of_its_cells_in_the_region_is_active(cells):
    """ "At least ``min_fraction`` of its cells": 15 of 50 cells is 0.3 exactly, but the rule compared 15 with
    ``0.3 * 50`` taken in float32 (a Python float times the int64 cell counts), ``15.000001``, so an agent with
    exactly that share was left inactive (0.15 of 100 cells, 0.3 of 90, ... too)."""
    from marlcrash.envs.agents import AgentLayout

    own = torch.as_tensor(np.flatnonzero(~cells.is_null & ~cells.is_rigid)[:50])
    one = AgentLayout(names=["a"], subassemblies=[("a",)], cells=own[None], valid=torch.ones(1, 50, dtype=torch.bool),
                      count=torch.tensor([50]), agent_of_cell=torch.full((cells.n_cells,), -1),
                      slot_of_cell=torch.full((cells.n_cells,), -1))  # fmt: skip
    region = torch.zeros(2, cells.n_cells, dtype=torch.bool)
    region[0, own[:15]] = True  # 15 of 50: the share asked for
    region[1, own[:14]] = True  # 14 of 50: below it
    t = torch.ones(2, dtype=torch.float64)
    reg = ImpactRegions(cells, one, MaskingConfig(mode="primary", min_fraction=0.3))
    assert reg.active(t, t, t, region=region)[:, 0].tolist() == [True, False]


def test_a_cell_on_the_secondary_depth_limit_is_in_the_region_whatever_its_round_off(cells, layout):
    """In the shipped small overlaps a subframe cell that the load reaches has its centroid 0.6 m
    (``secondary_depth``) behind the struck front, stored as 0.6000000000000019 m: "at most ``secondary_depth``
    behind" left it out on round-off (the compartment's cells on that plane sit at 0.6 exactly). A hair more depth
    now changes nothing, and the cell is in the secondary region."""
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    shipped = load_env_config().masking
    hair = MaskingConfig(**{**shipped.__dict__, "secondary_depth": shipped.secondary_depth + 1e-7})
    for side in (1.0, -1.0):
        prim, sec = (r[0] for r in ImpactRegions(cells, layout, shipped).regions(t(0.25), t(side), t(17.8)))
        more = ImpactRegions(cells, layout, hair).regions(t(0.25), t(side), t(17.8))[1][0]
        assert torch.equal(sec, more), side
        front = float(cells.lo[prim.numpy(), 0].min())
        on = np.abs(cells.centroid[:, 0] - front - shipped.secondary_depth) < 1e-12
        sub = on & (cells.subassembly == cells.subassembly_names.index("subframe"))
        assert bool(sec[torch.as_tensor(sub)].any()), side  # the struck side's one of the two on that plane
