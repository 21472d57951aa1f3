"""The batched calibration core: action application, feasibility, masking, rewards, errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from marlcrash.cells.parameterization import movable_factors
from marlcrash.envs.core import (
    ActionError,
    CalibrationCore,
    apply_increments,
    build_cells,
    env_config_of,
    load_env_config,
)
from marlcrash.errors import ConfigError, MarlcrashError
from marlcrash.metrics import compute_metrics
from marlcrash.reward import Reward, load_reward_config


@pytest.fixture(scope="session")
def cells():
    return build_cells("b_segment", None, "optimized")


def make(cells, B=2, **over):
    over.setdefault("termination.max_iterations", 5)
    return CalibrationCore(load_env_config(overrides=over), B, cells)


def feasibility(core):
    p, init = core.params, core.init
    deform = torch.as_tensor(~core.cells.is_null & ~core.cells.is_rigid)
    f = p[:, deform, 2:]
    lo, hi = core.config.behaviour_bounds
    e0 = init[deform, :2]
    assert torch.allclose(f.sum(-1), torch.ones((), dtype=torch.float64), atol=1e-12)
    assert (f >= 0).all()
    assert (f[:, ~core.feasible[deform]] == 0).all()
    # DESIGN 1.3 boundary condition 3: x, where feasible, transmits no less than any lateral direction
    x_ok = core.feasible[deform][:, 0]
    assert (f[:, x_ok, 0] >= f[:, x_ok, 1:].amax(-1)).all()
    e = p[:, deform, :2]
    assert (e >= lo * e0 * (1 - 1e-12)).all() and (e <= hi * e0 * (1 + 1e-12)).all()
    assert torch.equal(p[:, ~deform], init[~deform].expand(p.shape[0], -1, -1))


@pytest.mark.parametrize(("granularity", "steps"), [("subassembly", 100), ("cell", 20)])
def test_feasibility_after_10000_random_actions(cells, granularity, steps):
    # a fresh core holds the initial parameters with every agent active (mode none): no reset, no simulation
    core = make(cells, 100, granularity=granularity, **{"masking.mode": "none"})
    g = torch.Generator().manual_seed(0)
    core.saturated = torch.rand(100, cells.n_cells, generator=g) < 0.3
    for _ in range(steps):  # 100 envs x 100 steps = 10,000 random actions (2,000 per-cell ones)
        core.apply_actions(torch.rand(100, core.A, core.act_dim, generator=g) * 2.4 - 1.2)
    feasibility(core)
    assert (core.params[..., :2] != core.init[..., :2]).any()
    # no early ends: a row that reached a success or failure threshold in a random walk refused the next step
    no_end = {f"termination.{k}": None for k in ("failure_area", "failure_dfd", "failure_rmse", "success_area")}
    small = make(cells, 3, granularity=granularity, **no_end)
    small.reset(seed=1)
    for _ in range(3):  # a few full steps
        small.step(torch.rand(3, small.A, small.act_dim, generator=g) * 2 - 1)
        feasibility(small)


def test_zero_action_and_inactive_agents_change_nothing(cells):
    no_failure = {f"termination.failure_{m}": None for m in ("area", "dfd", "rmse")}  # three steps of one episode
    core = make(cells, 4, scenarios={"small_overlap_left": 1.0}, **no_failure)
    core.reset(seed=2)
    inactive = ~core.active
    assert inactive.any(dim=1).all()
    for name in ("crash_box_right", "front_rail_right"):
        assert not core.active[:, core.layout.index(name)].any()
    p0, v0 = core.params.clone(), core.est_velocity.clone()
    g = torch.Generator().manual_seed(1)
    act = (torch.rand(4, core.A, 7, generator=g) * 2 - 1) * inactive[..., None]
    core.step(act)
    assert torch.equal(core.params, p0)
    assert torch.equal(core.est_velocity, v0)
    assert torch.all(core.reward == 0)
    core.step(torch.zeros(4, core.A, 7))
    assert torch.equal(core.params, p0)
    act = (torch.rand(4, core.A, 7, generator=g) * 2 - 1) * core.active[..., None]
    core.step(act)
    assert not torch.equal(core.params, p0)


@pytest.mark.parametrize("granularity", ["subassembly", "cell"])
def test_region_cells_mode_acts_only_on_the_impact_region(cells, granularity):
    """``masking.cells: region`` takes DESIGN 1.4's rule per cell: in a driver-side small overlap an active agent's
    cells outside the primary and secondary region keep their parameters (the per-cell action mask leaves their
    slots out), and its cells inside change; the default ``agent`` changes every cell of an active agent."""
    over = {
        "scenarios": {"small_overlap_left": 1.0},
        "masking.saturation_preference": False,
        "granularity": granularity,
    }
    moved = {}
    for mode in ("agent", "region"):
        core = make(cells, 1, **over, **{"masking.cells": mode})
        core.reset(seed=0)
        region = core.regions.region(core.overlap, core.side, core.speed)[0]
        lay = core.layout
        owned_active = core.active[0][lay.agent_of_cell.clamp_min(0)] & lay.owned
        assert (owned_active & ~region).any()  # active agents own cells outside the region (the bumper beam's)
        before = core.params.clone()
        core.apply_actions(torch.ones(1, core.A, core.act_dim))
        moved[mode] = (core.params[0] != before[0]).any(-1)
        if mode == "region":
            assert torch.equal(core.acting[0], region)
            assert not moved[mode][~region].any()
            if granularity == "cell":
                slots = core.action_mask()[0].view(core.A, core.M, 7).any(-1)  # [A, M]
                assert torch.equal(slots, lay.valid & region[lay.cells] & core.active[0][:, None])
        assert torch.equal(moved[mode], owned_active if mode == "agent" else owned_active & region)
    with pytest.raises(ConfigError, match=r"masking.cells"):
        make(cells, 1, **{"masking.cells": "cell"})


@pytest.mark.parametrize("cells_mode", ["agent", "region"])
def test_subassembly_action_mask_leaves_out_factors_no_acting_cell_takes(cells, cells_mode):
    """A sub-assembly agent's transmission entry acts only where one of the cells its factors reach (all its cells,
    or its in-region ones with ``masking.cells: region``) may transmit that way: the mask says so, as the baselines'
    free coordinates do. Before, every entry of an active agent was in the mask (44 that move nothing in this batch:
    e.g. the hood's +-z); with ``region`` the set changes per episode row."""
    scenarios = {"small_overlap_left": 1.0, "offset40_right": 1.0, "full_width_40": 1.0}
    core = make(cells, 3, scenarios=scenarios, **{"masking.cells": cells_mode})
    core.reset(seed=1)
    lay = core.layout
    acting = core.acting[:, lay.cells] & lay.valid  # [B, A, M]
    takes = (movable_factors(core.feasible)[lay.cells][None] & acting[..., None]).any(2)  # [B, A, 5]
    mask = core.action_mask()
    assert torch.equal(mask[..., :2], core.active[..., None].expand(-1, -1, 2))
    assert torch.equal(mask[..., 2:], takes & core.active[..., None])
    assert (core.active[..., None] & ~takes).any()  # some active agent has a direction none of its cells takes
    before = core.params.clone()
    core.apply_actions(torch.where(mask, 0.0, 1.0))  # entries outside the mask move nothing
    assert torch.equal(core.params, before)


def test_cell_action_mask_leaves_out_a_cells_only_feasible_factor(cells):
    """A cell with one feasible direction transmits all its load that way: an increment of that factor is
    renormalised back to one, so its entry moves nothing and is out of the mask (26 deformable cells of the default
    car); every other feasible factor of an active agent's cell is in it."""
    core = make(cells, 1, granularity="cell", **{"masking.mode": "none", "masking.saturation_preference": False})
    core.reset(seed=0)
    lay = core.layout
    mask = core.action_mask()[0].reshape(core.A, core.M, 7)[..., 2:]  # [A, M, 5]
    feas = core.feasible[lay.cells] & lay.valid[..., None]
    lone = feas & (feas.sum(-1, keepdim=True) == 1)
    assert int(lone.any(-1).sum()) == int(((core.feasible.sum(1) == 1) & core.layout.owned).sum()) > 0
    assert not (mask & lone).any() and torch.equal(mask, feas & ~lone)
    before = core.params.clone()
    act = torch.zeros(1, core.A, core.M, 7)
    act[..., 2:] = lone.to(act.dtype)  # a full step on every lone factor
    core.apply_actions(act.reshape(1, core.A, -1))
    assert torch.equal(core.params, before)


def test_subassembly_action_scales_all_its_cells(cells):
    core = make(cells, 1, **{"masking.mode": "none", "masking.saturation_preference": False})
    core.reset(seed=0)
    a = core.layout.index("front_rail_left")
    act = torch.zeros(1, core.A, 7)
    act[0, a, 0] = 0.5  # E_x of every front_rail_left cell times exp(0.5 * max_step)
    act[0, a, 2] = 1.0  # f_x up, then renormalised
    before = core.params.clone()
    core.apply_actions(act)
    own = core.layout.cells[a][core.layout.valid[a]]
    ratio = core.params[0, own, 0] / before[0, own, 0]
    torch.testing.assert_close(ratio, torch.full_like(ratio, float(np.exp(0.05))))
    others = torch.ones(cells.n_cells, dtype=torch.bool)
    others[own] = False
    assert torch.equal(core.params[0, others], before[0, others])
    fx_new, fx_old = core.params[0, own, 2], before[0, own, 2]
    multi = core.feasible[own].sum(-1) > 1
    assert (fx_new[multi & (fx_old > 0)] > fx_old[multi & (fx_old > 0)]).all()


def test_cell_granularity_moves_one_cell_and_saturation_damps_behaviour(cells):
    core = make(cells, 1, granularity="cell", **{"masking.mode": "none", "masking.saturation_damping": 0.25})
    core.reset(seed=0)
    assert core.act_dim == 7 * core.M
    a = core.layout.index("crash_box_left")
    c0, c1 = (int(c) for c in core.layout.cells[a, :2])
    core.saturated[:] = False
    core.saturated[0, c1] = True
    mask = core.action_mask()
    assert mask.shape == (1, core.A, core.act_dim)
    assert not mask[0, a, 7 * int(core.layout.count[a]) :].any()
    act = torch.zeros(1, core.A, core.act_dim)
    act[0, a, 1] = 1.0  # E_s of slot 0
    act[0, a, 7 + 1] = 1.0  # E_s of slot 1 (saturated: damped)
    before = core.params.clone()
    core.apply_actions(act)
    changed = (core.params != before).any(-1)[0]
    assert set(torch.nonzero(changed).flatten().tolist()) == {c0, c1}
    r0 = core.params[0, c0, 1] / before[0, c0, 1]
    r1 = core.params[0, c1, 1] / before[0, c1, 1]
    torch.testing.assert_close(r0, torch.tensor(np.exp(0.1), dtype=torch.float64))
    torch.testing.assert_close(r1, torch.tensor(np.exp(0.025), dtype=torch.float64))


@pytest.mark.parametrize("granularity", ["subassembly", "cell"])
def test_increments_are_max_step_and_damping_in_float64(cells, granularity):
    """A full action is a log increment of exactly ``max_step`` (``max_step * saturation_damping`` on a saturated
    cell's behaviour), in float64, as a baseline's ``x`` is. Before, both factors went through a float32 tensor
    (``0.1 * bool``, ``torch.where(saturated, 0.2, 1.0)``): a full action moved 0.100000001 > max_step."""
    over = {"granularity": granularity, "masking.mode": "none", "masking.saturation_damping": 0.2}
    core = make(cells, 1, **over)
    core.saturated[0, ::2] = True
    inc = core.increments(core.check_actions(core.action_mask().float()))[0]
    moved = core._owned[0] & (inc != 0)
    sat = core.saturated[0][:, None].expand(-1, 7) & (torch.arange(7) < 2)
    assert moved.any() and (moved & sat).any()
    assert torch.equal(inc[moved & ~sat], torch.full_like(inc[moved & ~sat], 0.1))
    assert torch.equal(inc[moved & sat], torch.full_like(inc[moved & sat], 0.1 * 0.2))
    assert float(inc.abs().max()) <= core.config.max_step


def test_apply_increments_revives_zero_feasible_factors():
    init = torch.tensor([[1.0, 2.0, 1.0, 0.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    feas = torch.tensor([[True, True, False, False, False]])
    inc = torch.tensor([[[0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0]]], dtype=torch.float64)
    out = apply_increments(init[None], inc, init, feas, (0.5, 2.0), 0.01)[0, 0]
    g = 0.01 * (np.e - 1)  # (0 + floor) * e - floor; f_yn infeasible stays zero
    torch.testing.assert_close(out[2:], torch.tensor([1 / (1 + g), g / (1 + g), 0, 0, 0], dtype=torch.float64))


def test_increments_on_infeasible_factors_alone_leave_a_cell_bit_exact():
    """Such an increment moves nothing; the cell used to be renormalised anyway, changing factors by 1e-16."""
    gen = torch.Generator().manual_seed(0)
    n = 200
    feas = torch.rand(n, 5, generator=gen) < 0.6
    feas[:, 0] = True
    f = torch.rand(1, n, 5, generator=gen, dtype=torch.float64) * feas
    p = torch.cat([1 + torch.rand(1, n, 2, generator=gen, dtype=torch.float64), f / f.sum(-1, keepdim=True)], -1)
    inc = torch.zeros_like(p)
    inc[..., 2:] = torch.randn(1, n, 5, generator=gen, dtype=torch.float64) * ~feas
    assert (inc != 0).any()
    assert torch.equal(apply_increments(p, inc, p[0], feas, (0.5, 2.0), 0.01), p)
    inc[0, 0, 2] = 1e-3  # a feasible one: the cell changes and is renormalised, the others stay
    out = apply_increments(p, inc, p[0], feas, (0.5, 2.0), 0.01)
    assert not torch.equal(out[0, 0], p[0, 0]) and torch.equal(out[0, 1:], p[0, 1:])
    torch.testing.assert_close(out[0, 0, 2:].sum(), torch.tensor(1.0, dtype=torch.float64))


def test_a_factor_that_starts_at_zero_or_falls_to_it_is_observed(cells):
    """Own parameters are observed in the coordinate the update moves: ``log((f + floor) / (f0 + floor))`` for a
    feasible factor. As ``log(f / f0)`` a factor that started at 0 (40 feasible ones on the default car) stayed
    0 in the observation while the agent grew it, and one driven to 0 read as untouched."""
    core = make(cells, 1, granularity="cell", **{"masking.mode": "none"})
    core.reset(seed=0)
    zero = torch.nonzero((core.init[:, 2:] == 0) & core.feasible)
    assert zero.shape[0] > 0
    cell, d = (int(x) for x in zero[0])
    a, slot = int(core.layout.agent_of_cell[cell]), int(core.layout.slot_of_cell[cell])
    act = torch.zeros(1, core.A, core.act_dim)
    act[0, a, 7 * slot + 2 + d] = 1.0
    core.apply_actions(act)
    f, floor = float(core.params[0, cell, 2 + d]), core.config.transmission_floor
    assert f > 0
    obs, _ = core.observations()
    kt, scale = core.K * core.T, core.config.observation.param_scale
    seen = float(obs[0, a, kt + 7 * slot + 2 + d])
    assert seen == pytest.approx(np.log((f + floor) / floor) * scale, rel=1e-6) and seen > 0
    assert float(obs[0, a, kt + 7 * slot + 2 : kt + 7 * slot + 7].abs().sum()) > seen  # the others renormalised


def test_actions_from_numpy_are_copied_and_checked(cells):
    core = make(cells, 1)
    core.reset(seed=0)
    flipped = np.flip(np.linspace(-1, 1, core.A * 7).reshape(1, core.A, 7), axis=2)  # negative strides
    flipped.setflags(write=False)
    torch.testing.assert_close(core.check_actions(flipped), torch.as_tensor(flipped.copy()))
    with pytest.raises(ActionError, match=r"floating point .* numpy object"):
        core.check_actions(np.zeros((1, core.A, 7), dtype=object))
    with pytest.raises(ConfigError, match=r"\['tunnel'\] more than once") as e:
        load_env_config(overrides={"sensors": ["tunnel", "tunnel", "upfront_left"]})
    assert e.value.key == "sensors"


def test_observations_state_and_reward(cells):
    core = make(cells, 3)
    core.reset(seed=4)
    obs, state = core.observations()
    assert obs.shape == (3, core.A, core.obs_dim) and state.shape == (3, core.state_dim)
    assert obs.dtype == torch.float32
    kt = core.K * core.T
    diff = (core.ref_velocity - core.est_velocity).reshape(3, -1).float()
    torch.testing.assert_close(obs[:, 5, :kt], diff)
    torch.testing.assert_close(state[:, :kt], diff)
    assert torch.equal(obs[:, :, kt : kt + 7], torch.zeros(3, core.A, 7))  # params at their initial values
    assert torch.equal(obs[:, :, -core.A :], torch.eye(core.A).expand(3, -1, -1))
    energy = obs[:, :, kt + 7 : kt + 7 + core.M]
    assert (energy >= 0).all() and (energy > 0).any()
    prev = core.metrics
    g = torch.Generator().manual_seed(3)
    core.step(torch.rand(3, core.A, 7, generator=g) * 2 - 1)
    rw = Reward(load_reward_config("log_ratio"))
    ref = compute_metrics(core.est_velocity, core.ref_velocity, dt=core.dt)
    for a, b in zip(core.metrics, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close(core.reward, rw(ref, prev))
    obs, _ = core.observations()
    assert obs[:, :, kt : kt + 7].abs().sum() > 0


def test_float32_simulations_match_float64_to_the_noise_floor(cells):
    """``sim_dtype: float32`` runs the episodes' simulations (the twin reference's too) in single precision.

    Same seed, same references and actions: the fit metrics move by far less than the paper's marks (area
    0.0015 m, RMSE 0.1511 m/s; measured at the twin's truth: 1.4e-5 m and 1.5e-4 m/s), rewards stay close.
    The reference velocities agree to 1e-2 m/s (0.07 % of the impact speed): at the window's end of a small
    overlap an up-front sensor's cell chatters (velocity steps of 2 m/s per sample), float32 moves it by 2e-3 m/s
    and the CFC60 filter's end handling of the last samples by up to 7.5e-3 m/s.

    The saturation preference is off here: its flag is a threshold (plastic work reached ``E_s``), and a cell that
    ends within float32's rounding of it flips (one of the default car's ends an offset40 1.8e-6 below it),
    damping that cell's next increments: a different action, not a precision difference.
    """
    off = {"masking.saturation_preference": False}
    a, b = make(cells, 3, **off), make(cells, 3, sim_dtype="float32", **off)
    assert a.sim.dtype == torch.float64 and b.sim.dtype == torch.float32
    act = torch.linspace(-1, 1, 3 * a.A * 7).reshape(3, a.A, 7)
    for core in (a, b):
        core.reset(seed=5)
        core.step(act)
    assert b.est_velocity.dtype == torch.float64  # compared in float64 whatever the simulation's precision
    torch.testing.assert_close(b.ref_velocity, a.ref_velocity, rtol=0, atol=1e-2)
    for x, y in zip(b.metrics, a.metrics, strict=True):
        assert float((x - y).abs().max()) < 1e-3 * float(y.abs().max()) + 1e-5
    torch.testing.assert_close(b.reward, a.reward, rtol=0, atol=2e-3)
    with pytest.raises(ConfigError, match="sim_dtype"):
        load_env_config(overrides={"sim_dtype": "float16"})


def test_termination_and_truncation(cells):
    core = make(cells, 2, **{"termination.max_iterations": 2, "reference.twin.e_x_spread": 0.0,
                             "reference.twin.e_s_spread": 0.0, "reference.twin.transmission_spread": 0.0})  # fmt: skip
    core.reset(seed=0)
    assert torch.allclose(core.metrics.rmse, torch.zeros(()).double())  # the twin without spread is the model
    core.step(torch.zeros(2, core.A, 7))
    assert core.success.all() and core.terminated.all() and not core.truncated.any()
    core = make(cells, 2, **{"termination.max_iterations": 2, "termination.failure_dfd": None,
                             "termination.failure_rmse": None, "termination.failure_area": None})  # fmt: skip
    core.reset(seed=0)
    for i in range(2):
        core.step(torch.zeros(2, core.A, 7))
        assert core.truncated.all() == (i == 1)


def test_seeding_is_deterministic_and_leaves_global_rng_alone(cells):
    torch.manual_seed(123)
    np.random.seed(123)  # noqa: NPY002 - the legacy global RNG is what must stay untouched
    t_state, n_state = torch.get_rng_state(), np.random.get_state()[1].copy()  # noqa: NPY002
    a, b = make(cells, 3), make(cells, 3)
    a.reset(seed=9)
    b.reset(seed=9)
    act = torch.linspace(-1, 1, 3 * a.A * 7).reshape(3, a.A, 7)
    a.step(act)
    b.step(act)
    assert a.scenario == b.scenario
    assert torch.equal(a.observations()[0], b.observations()[0]) and torch.equal(a.reward, b.reward)
    assert torch.equal(torch.get_rng_state(), t_state) and np.array_equal(np.random.get_state()[1], n_state)  # noqa: NPY002
    a.reset(seed=10)
    assert not torch.equal(a.ref_velocity, b.ref_velocity)
    # partial reset leaves the other rows alone
    keep = b.params[1:].clone()
    b.reset(mask=torch.tensor([True, False, False]))
    assert torch.equal(b.params[1:], keep) and int(b.iteration[0]) == 0 and int(b.iteration[1]) == 1


def test_the_first_reset_gives_a_row_the_same_episode_whatever_the_batch_size(cells):
    """Row-by-row reference draws: after reset(seed=s), rows 0-1 of a batch of 4 calibrate what a batch of 2 does,
    so a run with more parallel episodes adds episodes instead of replacing them."""
    small, large = make(cells, 2), make(cells, 4)
    small.reset(seed=21)
    large.reset(seed=21)
    assert large.scenario[:2] == small.scenario
    assert torch.equal(large.ref_velocity[:2], small.ref_velocity)
    assert torch.equal(large.true_params[:2], small.true_params)
    assert torch.equal(large.observations()[0][:2], small.observations()[0])
    assert not torch.equal(large.true_params[2], large.true_params[0])


def test_bad_input_raises_clear_errors(cells):
    core = make(cells, 2)
    core.reset(seed=0)
    with pytest.raises(ActionError, match=r"shape \[B=2, n_agents=21, act_dim=7\]"):
        core.step(torch.zeros(2, core.A, 6))
    with pytest.raises(ActionError, match="floating point"):
        core.step(torch.zeros(2, core.A, 7, dtype=torch.int64))
    bad = torch.zeros(2, core.A, 7)
    used = core.action_mask()
    a = int(used[1, :, 2].nonzero()[0])  # an active agent: an inactive one's actions are ignored
    bad[1, a, 2] = float("nan")
    with pytest.raises(ActionError, match=rf"actions\[1, {a}, 2\].*nan"):
        core.step(bad)
    ignored = torch.where(used, 0.0, float("nan"))
    core.step(ignored)  # NaN only where action_mask() is false: ignored, as the PettingZoo door ignores them
    with pytest.raises(ConfigError, match=r"key 'seed': expected a seed >= 0, got -1"):
        load_env_config(overrides={"seed": -1})
    assert issubclass(ActionError, MarlcrashError) and issubclass(ActionError, ValueError)
    with pytest.raises(ConfigError, match="unknown scenario 'moon_landing'"):
        make(cells, 1, scenarios={"moon_landing": 1.0})
    with pytest.raises(ConfigError, match="behaviour_bounds"):
        load_env_config(overrides={"behaviour_bounds": [2.0, 4.0]})
    # 1e300 let a float32 run's E_s grow to inf mid-training, refused then naming a cell, not the setting
    for bad in ([0.25, 1e300], [1e-300, 4.0], [0.25, 1001.0]):
        with pytest.raises(ConfigError, match=r"key 'behaviour_bounds': expected \[lo, hi\] with 0.001 <= lo <= 1 "
                           r"<= hi <= 1000 .*MAX_BEHAVIOUR_FACTOR"):  # fmt: skip
            load_env_config(overrides={"behaviour_bounds": bad, "sim_dtype": "float32"})
    assert load_env_config(overrides={"behaviour_bounds": [1e-3, 1e3]}).behaviour_bounds == [1e-3, 1e3]
    with pytest.raises(ConfigError, match="unknown env config"):
        load_env_config("nope")
    with pytest.raises(ConfigError, match="granularity"):
        load_env_config(overrides={"granularity": "part"})


def test_an_observation_scale_that_overflows_float32_is_refused(cells):
    """``observation.velocity_scale: 1e308`` loaded, and every observation and state was inf or NaN in float32, fed
    to the policy without a word. The scales are bounded (MAX_OBSERVATION_SCALE), naming the key; at the bound the
    observations stay finite."""
    from marlcrash.envs.core import MAX_OBSERVATION_SCALE

    for k in ("velocity_scale", "param_scale", "energy_scale"):
        with pytest.raises(ConfigError, match=rf"key 'observation\.{k}': expected a finite scale in \(0, ") as e:
            load_env_config(overrides={f"observation.{k}": 1e308})
        assert "MAX_OBSERVATION_SCALE" in str(e.value)
    scales = {f"observation.{k}": MAX_OBSERVATION_SCALE for k in ("velocity_scale", "param_scale", "energy_scale")}
    core = make(cells, 2, **scales)
    core.reset(seed=0)
    core.step(torch.ones(2, core.A, core.act_dim))
    obs, state = core.observations()
    assert torch.isfinite(obs).all() and torch.isfinite(state).all()


def test_constructor_arguments_are_checked_as_arguments(cells):
    """A bad batch size was reported as a key of the env's YAML file (``default.yaml key 'batch_size'``), a numpy
    integer was refused, a float or a string failed inside ``torch.Size`` (TorchRL door), and a config given by name
    failed with ``AttributeError: 'str' object has no attribute 'vehicle'``."""
    from marlcrash.envs.pettingzoo_env import CalibrationParallelEnv
    from marlcrash.envs.torchrl_env import CalibrationTorchEnv

    config = load_env_config()
    for door in (CalibrationCore, CalibrationTorchEnv):
        for bad in (0, 2.5, "3", True):
            with pytest.raises(ConfigError, match=r"^key 'batch_size': batch_size must be a positive integer") as e:
                door(config, bad, cells)
            assert e.value.path is None
    assert CalibrationTorchEnv(config, np.int64(2), cells).batch_size == (2,)
    assert CalibrationCore(config, np.int64(2), cells).B == 2
    for door in (CalibrationParallelEnv, CalibrationTorchEnv):
        with pytest.raises(ConfigError, match=r"key 'config': expected an EnvConfig \(load_env_config\('default'\)\)"):
            door("default", cells=cells)
    for door in (
        CalibrationCore,
        CalibrationParallelEnv,
        CalibrationTorchEnv,
    ):  # was an AttributeError on .sensor_names
        with pytest.raises(ConfigError, match=r"^key 'cells': expected a CellModel or None .*config.vehicle.*got str"):
            door(config, cells="b_segment")


def test_a_config_made_in_python_is_checked_as_a_file_is(cells):
    """An ``EnvConfig`` made in Python skipped the loader's checks: a misspelt ``masking.mode`` ran
    ``primary_secondary``, a ``granularity`` of ``cells`` per-cell actions and a negative ``max_step`` inverted
    every action, all without a word."""
    from marlcrash.envs.core import EnvConfig
    from marlcrash.envs.masking import MaskingConfig

    bad = {
        "masking.mode": EnvConfig(masking=MaskingConfig(mode="primry")),
        "granularity": EnvConfig(granularity="cells"),
        "max_step": EnvConfig(max_step=-0.5),
        "masking.min_fraction": EnvConfig(masking=MaskingConfig(min_fraction=0.0)),
        # a direction twice was taken once, so a typo for another one ran without it
        "masking.secondary_directions": EnvConfig(masking=MaskingConfig(secondary_directions=["+x", "+y", "+y"])),
    }
    for key, config in bad.items():
        with pytest.raises(ConfigError, match=rf"^key '{key}'"):
            CalibrationCore(config, 1, cells)
    config = load_env_config()
    config.masking.secondary_hops = -1  # changed after loading: named with the file it was loaded from
    with pytest.raises(ConfigError, match=r"default\.yaml key 'masking\.secondary_hops'"):
        CalibrationCore(config, 1, cells)
    assert CalibrationCore(EnvConfig(), 1, cells).config == EnvConfig()


def test_a_section_given_as_a_mapping_in_python_is_used_as_the_checked_section(cells):
    """The check converted ``EnvConfig(masking={"mode": "none"})`` into its section but the env kept the mapping, and
    failed with "'dict' object has no attribute 'secondary_directions'" (at build, or at the first reset)."""
    from marlcrash.envs.core import EnvConfig
    from marlcrash.envs.masking import MaskingConfig

    for kw, typed in (
        ({"masking": {"mode": "none"}}, {"masking": MaskingConfig(mode="none")}),
        ({"agents": {"split_lr": []}}, None),
        ({"observation": {"velocity_scale": 2.0}}, None),
    ):
        core = CalibrationCore(EnvConfig(**kw), 1, cells)
        core.reset(seed=0)
        if typed is not None:
            assert core.config == EnvConfig(**typed)
        key, value = next(iter(kw.items()))
        section = getattr(core.config, key)
        assert not isinstance(section, dict) and all(getattr(section, k) == v for k, v in value.items())


def test_a_bad_seed_is_named(cells):
    """numpy's own messages ("expected non-negative integer", "SeedSequence expects int ...") named no value."""
    from marlcrash.envs.pettingzoo_env import CalibrationParallelEnv
    from marlcrash.envs.torchrl_env import CalibrationTorchEnv

    core = make(cells, 1)
    for bad in (-1, 1.5, "a", True):
        with pytest.raises(ActionError, match=rf"seed must be an integer >= 0 or None, got {bad!r}"):
            core.reset(seed=bad)
    pz = CalibrationParallelEnv(core.config, cells)
    with pytest.raises(ActionError, match=r"seed must be an integer >= 0 or None, got -3"):
        pz.reset(seed=-3)
    with pytest.raises(ActionError, match=r"got -3"):
        CalibrationTorchEnv(core.config, 1, cells).set_seed(-3)
    core.reset(seed=np.int64(4))
    first = core.ref_velocity.clone()
    core.reset(seed=4)
    assert torch.equal(core.ref_velocity, first)


def test_a_row_mask_that_is_no_flag_per_row_is_refused_naming_it(cells):
    """Cast to bool first, row indices ``[0, 2, 1, 3]`` read as ``[F, T, T, T]``, a float mask as non-zero and a
    ``[2, 2]`` one as four rows: the wrong rows were reset or stepped without a word."""
    core = make(cells, 4)
    core.reset(seed=1)
    act = torch.zeros(4, core.A, core.act_dim)
    core.step(act)
    for bad, said in (
        (
            torch.tensor([0, 2, 1, 3]),
            r"reset mask must be \[4\] bool \(one flag per row, not row indices\), got "
            r"dtype int64 with values \[0, 2, 1, 3\]",
        ),
        (torch.tensor([0.2, 0.0, 0.0, 1.0]), r"got dtype float32"),
        (torch.ones(2, 2, dtype=torch.bool), r"reset mask must be \[4\] bool, got shape \[2, 2\]"),
        ("rows", r"reset mask must be \[4\] bool, got str"),
    ):
        with pytest.raises(ActionError, match=said):
            core.reset(mask=bad)
    assert core.iteration.tolist() == [1, 1, 1, 1]  # nothing reset
    with pytest.raises(ActionError, match=r"step mask must be \[4\] bool \(one flag"):
        core.step(act, mask=[1, 0, 2, 0])
    core.step(act, mask=[[1], [0], [0], [1]])  # 0/1 integers, [B, 1]: flags
    core.reset(mask=np.array([True, False, False, False]))
    assert core.iteration.tolist() == [0, 1, 1, 2]


def test_a_refused_reset_leaves_the_generator_alone(cells):
    """``reset(seed=s, mask=bad)`` re-seeded the generator and then refused the mask: the refused call moved the
    episodes every later ``reset()`` draws. A refused call changes nothing."""
    a, b = make(cells, 2), make(cells, 2)
    a.reset(seed=1)
    b.reset(seed=1)
    with pytest.raises(ActionError, match=r"reset mask must be \[2\] bool"):
        a.reset(seed=5, mask=torch.ones(3, dtype=torch.bool))
    a.reset()
    b.reset()
    assert torch.equal(a.ref_velocity, b.ref_velocity)


def test_step_before_reset_is_refused_naming_the_rows(cells):
    """A row never reset has no reference (speed 0): the simulator refused it with its own message
    ("need speed > 0 m/s, ..."), which did not say that reset() was missing; the TorchRL door too."""
    from marlcrash.envs.torchrl_env import CalibrationTorchEnv

    core = make(cells, 3)
    with pytest.raises(ActionError, match=r"call reset\(\) before step\(\): rows \[0, 1, 2\] of 3"):
        core.step(torch.zeros(3, core.A, 7))
    core.reset(seed=0, mask=torch.tensor([True, False, True]))
    with pytest.raises(ActionError, match=r"call reset\(\) before step\(\): rows \[1\] of 3"):
        core.step(torch.zeros(3, core.A, 7))
    core.reset(mask=torch.tensor([False, True, False]))
    core.step(torch.zeros(3, core.A, 7))
    assert core.iteration.tolist() == [1, 1, 1]
    env = CalibrationTorchEnv(core.config, batch_size=2, cells=cells)
    with pytest.raises(ActionError, match=r"call reset\(\) before step\(\)"):
        env.step(env.rand_action())


def test_a_nested_override_changes_only_the_keys_it_gives():
    """Hydra makes ``+env_overrides.termination.failure_dfd=10`` a mapping; it must not reset the section's other
    keys to the schema's defaults (the success thresholds went to None: success was switched off)."""
    base = load_env_config()
    nested = load_env_config(overrides={"termination": {"failure_dfd": 10.0}, "observation.param_scale": 5.0,
                                        "observation": {"velocity_scale": 3.0}})  # fmt: skip
    assert nested.termination == dataclasses.replace(base.termination, failure_dfd=10.0)
    assert nested.termination.success_area == base.termination.success_area is not None
    assert (nested.observation.velocity_scale, nested.observation.param_scale) == (3.0, 5.0)
    # a mapping-valued field is replaced whole: it is the value
    assert load_env_config(overrides={"scenarios": {"offset40_left": 1.0}}).scenarios == {"offset40_left": 1.0}
    with pytest.raises(ConfigError, match=r"key 'termination\.failure_dfdx': unknown key"):
        load_env_config(overrides={"termination": {"failure_dfdx": 10.0}})
    # steps are counted in int64: 2**63 compared as -2**63 (every episode truncated at its first step)
    with pytest.raises(ConfigError, match=r"key 'termination\.max_iterations': must be in \[1, 2\*\*63 - 1\]"):
        load_env_config(overrides={"termination.max_iterations": 2**63})


def test_an_override_inside_a_plain_value_names_the_key_that_set_it():
    """``termination=3`` then ``termination.max_iterations=8`` (a training adds that one): the first is wrong."""
    with pytest.raises(ConfigError, match=r"default\.yaml key 'termination': expected a mapping, got 3"):
        load_env_config(overrides={"termination": 3, "termination.max_iterations": 8})
    with pytest.raises(ConfigError, match=r"key 'max_step\.x': cannot override inside a non-mapping value \(max_step"):
        load_env_config(overrides={"max_step.x": 1.0})
    with pytest.raises(ConfigError, match=r"default\.yaml key 'reward': unknown reward form 'nope'"):
        load_env_config(overrides={"reward": "nope"})  # when the config is loaded, not when an env is built
    with pytest.raises(ConfigError, match=r"key 'env_overrides\.reward': unknown reward form") as e:
        env_config_of("default", {"reward": "nope"}, {"seed": 1})  # named as the config that names the env sets it
    assert e.value.path is None
    with pytest.raises(ConfigError) as e:
        env_config_of("nope", {}, env_key="problem.env")
    assert e.value.key == "problem.env"


def test_errors_found_while_building_name_the_yaml_file(cells):
    """A bad agent split is found when the core is built; the message names the env YAML and the key."""
    cfg = load_env_config("default", overrides={"agents.merge": {"front": ["nose_cone"]}})
    with pytest.raises(ConfigError, match=r"default\.yaml.*unknown sub-assembly 'nose_cone'"):
        CalibrationCore(cfg, batch_size=1, cells=cells)


def test_env_calibrates_a_deck_read_with_its_vehicle_options(lsopt_deck, tmp_path):
    """A deck that needs *PARAMETER values and a sub-assembly map is an env's vehicle through ``vehicle_options``
    (as ``marlcrash simulate DECK --param ... --subassemblies ...``); its map's groups are the agents."""
    from marlcrash.cells.discretize import discretize
    from marlcrash.provenance import env_inputs
    from marlcrash.vehicle.keyword import read_deck

    amap = tmp_path / "map.yaml"
    amap.write_text("subassemblies:\n  front: [1, 2]\n")
    params = {"tbumper": 3.0, "thood": 1.0}
    over = {"vehicle": str(lsopt_deck), "vehicle_options": {"params": params, "subassemblies": str(amap)},
            "agents.split_lr": [], "scenarios": {"full_width_40": 1.0}}  # fmt: skip
    cfg = load_env_config("default", over)
    with pytest.warns(UserWarning):  # the deck's barrier block is left out, some cards skipped
        core = CalibrationCore(cfg, batch_size=2)
        want = discretize(read_deck(lsopt_deck, params=params, subassemblies=amap), method="optimized")
    assert core.cells.n_cells == want.n_cells
    np.testing.assert_array_equal(core.cells.centroid, want.centroid)
    np.testing.assert_array_equal(core.cells.params, want.params)
    assert core.cells.subassembly_names == want.subassembly_names
    assert "front" in core.layout.names and not any(n.startswith("part_1") for n in core.layout.names)
    core.reset(seed=0)
    core.step(torch.zeros(2, core.A, core.act_dim))
    assert torch.isfinite(core.reward).all()
    assert str(amap) in env_inputs(cfg)  # a run records the map as an input
    with pytest.raises(ConfigError, match="keyword decks only") as e:
        load_env_config("default", {"vehicle_options.params": params})
    assert e.value.key == "vehicle_options.params"


def test_a_vehicle_seed_for_a_deck_is_refused_when_the_config_loads(lsopt_deck):
    """A deck has no variants: ``vehicle_seed: 1`` with a deck vehicle loaded and failed when the env was built,
    named as the env's ``seed`` (another setting); a cross-fidelity ``vehicle_seeds: [null, 1]`` failed only when
    seed 1 was first drawn, mid-training. Both are refused at load, naming the key; null (the nominal car) loads."""
    deck = {"vehicle": str(lsopt_deck)}
    with pytest.raises(ConfigError, match="keyword deck") as e:
        load_env_config("default", {**deck, "vehicle_seed": 1})
    assert e.value.key == "vehicle_seed"
    cross = {**deck, "reference.kind": "cross_fidelity"}
    with pytest.raises(ConfigError, match="keyword deck") as e:
        load_env_config("default", {**cross, "reference.cross_fidelity.vehicle_seeds": [None, 1]})
    assert e.value.key == "reference.cross_fidelity.vehicle_seeds[1]"
    assert load_env_config("default", {**cross, "reference.cross_fidelity.vehicle_seeds": [None]}).vehicle == str(
        lsopt_deck
    )
    # a synthetic car has variants: its seeds load
    load_env_config("default", {"vehicle_seed": 1, "reference.kind": "cross_fidelity",
                                "reference.cross_fidelity.vehicle_seeds": [None, 1]})  # fmt: skip


def test_a_scenario_that_activates_no_agent_is_named_when_the_env_is_built(lsopt_deck, tmp_path, monkeypatch):
    """The deck read with its height as marlcrash's width (a wrong ``axis_map``) strikes almost nothing on the
    left: those scenarios' episodes would mask every action, and the env says so; read with its own axes, none.
    So read, it has no material within 0.75 m of the default up-front left sensor on its side, which discretization
    refuses (tests/test_sensor_placement.py): the configs here leave that sensor out."""
    import shutil
    import warnings

    import yaml

    from marlcrash.config import config_dir

    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    cells_yaml = configs / "cells.yaml"
    data = yaml.safe_load(cells_yaml.read_text())
    data["sensors"] = [s for s in data["sensors"] if s["name"] != "upfront_left"]
    cells_yaml.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    base = {"vehicle": str(lsopt_deck), "agents.split_lr": []}
    # with the walls sampled without gaps (max_subdivision 32) the 40 % offset on the left reaches enough of one agent
    for axis_map, idle in (("x=+x,y=+z,z=+y", ["small_overlap_left"]), (None, [])):
        opts = {"params": {"tbumper": 3.0, "thood": 1.0}, "axis_map": axis_map}
        cfg = load_env_config("default", {**base, "vehicle_options": opts})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            CalibrationCore(cfg, batch_size=1)
        said = [str(w.message) for w in caught if "activates no agent" in str(w.message)]
        assert len(said) == (1 if idle else 0), said
        for name in idle:
            assert f"scenario {name!r} activates no agent" in said[0] and "axis_map" in said[0]
        assert not idle or "offset40_right" not in said[0]


def test_a_cell_model_without_sensors_is_refused_naming_the_key(tmp_path, monkeypatch):
    """configs/cells.yaml with ``sensors: []`` discretizes (a cell model may have none), but an environment has no
    pulse to compare: it failed at its first reset inside a reduction over zero sensors (IndexError from amax)."""
    import shutil

    import yaml

    from marlcrash.config import config_dir

    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    cells_yaml = configs / "cells.yaml"
    data = yaml.safe_load(cells_yaml.read_text())
    data["sensors"] = []
    cells_yaml.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    with pytest.raises(ConfigError, match=r"key 'sensors'.*no sensors to compare: .* configs/cells.yaml") as e:
        CalibrationCore(load_env_config("default"), batch_size=1)
    assert str(e.value.path).endswith("default.yaml")  # the env's own sensors key is there


def test_episodes_that_start_past_the_failure_limits_are_named_once(cells):
    """The uniform model's small-overlap pulses lie up to 5.4 m/s RMSE from this model's
    (benchmarks/bench_cross_fidelity.py), past a failure limit of 3 m/s: such an episode ends as a failure at its
    first step whatever the agents do, and the env says so, once. Without failure limits nothing is said."""
    import warnings

    over = {"reference.kind": "cross_fidelity", "scenarios": {"small_overlap_left": 1.0}}
    core = make(cells, 1, **over, **{"termination.failure_rmse": 3.0})
    with pytest.warns(UserWarning, match=r"start past the failure limits: .*rmse [\d.]+ > failure_rmse 3 "
                                         r"\(small_overlap_left\).*reference.kind cross_fidelity"):  # fmt: skip
        core.reset(seed=0)
    core.step(torch.zeros(1, core.A, 7))
    assert bool(core.terminated[0]) and not bool(core.success[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        core.reset(seed=1)  # once per env
        free = {f"termination.failure_{m}": None for m in ("area", "dfd", "rmse")}
        make(cells, 1, **over, **free).reset(seed=0)


def test_no_episode_of_the_default_distribution_starts_past_the_shipped_failure_limits(cells):
    """A failure limit is a hopeless state, so the shipped ones lie past every start the default scenarios' twins
    draw: the limits before (area 0.5 m, DFD 5 m/s, RMSE 3 m/s) ended 1.5 % of them at their first step whatever
    the agents did (15 of 1024; small-overlap starts reach 0.42 m, 5.1 m/s and 3.4 m/s in 512), and the README's
    main job warned about it. A margin of 1.5x on each is asked of these 256 starts."""
    import warnings

    core = make(cells, 256)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        core.reset(seed=0)
    limits = core.reward_fn.cfg.termination
    for metric, value in zip(("area", "dfd", "rmse"), core.metrics, strict=True):
        worst = float(value.amax())
        assert 1.5 * worst < getattr(limits, f"failure_{metric}"), (metric, worst)


def test_the_cell_model_cache_follows_the_configs_folder(tmp_path, monkeypatch):
    """``build_cells`` caches per process; a configs folder with other cell settings gets its own model, not the one
    built from the folder before (it did: the key held the vehicle and its options only)."""
    import shutil

    import yaml

    from marlcrash.config import config_dir
    from marlcrash.envs import core

    for seed in range(core._CELLS_KEPT):  # a full cache whose oldest entry is the one used next (kept: used last)
        build_cells("b_segment", seed, "optimized")
    first = build_cells("b_segment", 0, "optimized")
    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    data = yaml.safe_load((configs / "cells.yaml").read_text())
    data["target_cell_volume"] = 2 * data["target_cell_volume"]
    (configs / "cells.yaml").write_text(yaml.safe_dump(data))
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    coarse = build_cells("b_segment", 0, "optimized")
    assert coarse.n_cells < first.n_cells
    monkeypatch.delenv("MARLCRASH_CONFIGS")
    assert build_cells("b_segment", 0, "optimized") is first


def test_the_cell_model_cache_reads_a_changed_vehicle_file_again(tmp_path, monkeypatch):
    """A vehicle file edited in the same process, or one named by a relative path after a change of folder, gets its own
    cells: the cache was keyed by the path as typed and gave the first file's cells (DESIGN 3: a deck is read anew)."""
    import yaml

    from marlcrash.config import config_dir
    from marlcrash.vehicle.registry import vehicle_config_path

    data = yaml.safe_load(vehicle_config_path("b_segment").read_text())
    data["materials"] = str((config_dir() / data["materials"]).resolve())  # the copies are read outside configs/
    heavy = dict(data, total_mass=1800.0)
    for folder, car in (("a", data), ("b", heavy)):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "car.yaml").write_text(yaml.safe_dump(car))
    monkeypatch.chdir(tmp_path / "a")
    first = build_cells("car.yaml", None, "optimized")
    monkeypatch.chdir(tmp_path / "b")
    other = build_cells("car.yaml", None, "optimized")  # the same path as typed, another file
    assert other.total_mass == pytest.approx(1800.0) and first.total_mass == pytest.approx(1600.0)
    assert build_cells("car.yaml", None, "optimized") is other  # unchanged: kept
    (tmp_path / "b" / "car.yaml").write_text(yaml.safe_dump(dict(data, total_mass=1700.0)))
    assert build_cells("car.yaml", None, "optimized").total_mass == pytest.approx(1700.0)
