"""The two front doors: PettingZoo ParallelEnv and native batched TorchRL EnvBase."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from pettingzoo.test import parallel_api_test, parallel_seed_test
from tensordict import TensorDict
from torchrl.envs import PettingZooWrapper
from torchrl.envs.utils import MarlGroupMapType, check_env_specs

from marlcrash.envs.core import ActionError, build_cells, load_env_config
from marlcrash.envs.pettingzoo_env import CalibrationParallelEnv
from marlcrash.envs.torchrl_env import CalibrationTorchEnv
from marlcrash.errors import ConfigError


@pytest.fixture(scope="session")
def cells():
    return build_cells("b_segment", None, "optimized")


def cfg(**over):
    over.setdefault("termination.max_iterations", 4)
    return load_env_config(overrides=over)


def test_parallel_api_and_seed_tests(cells):
    """PettingZoo's own tests pass. The one warning they give is by design: agents outside the episode's impact
    region are never live (not in ``agents`` at reset), so they never get a termination flag, which the API
    test's end-of-episode check counts as missing. Any other warning fails here."""
    for reset_agents in ("possible", "live"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            parallel_api_test(CalibrationParallelEnv(cfg(), cells, reset_agents=reset_agents), num_cycles=20)
        said = {str(w.message) for w in caught}
        assert said <= {"No agents present but not all possible_agents are terminated or truncated"}, said
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_seed_test(lambda: CalibrationParallelEnv(cfg(), cells), num_cycles=20)


def test_reset_returns_every_agent_but_only_active_ones_live(cells):
    env = CalibrationParallelEnv(cfg(scenarios={"small_overlap_left": 1.0}), cells)
    with pytest.raises(ActionError, match=r"call reset\(\) before state\(\)"):
        env.state()
    obs, infos = env.reset(seed=0)
    assert set(obs) == set(infos) == set(env.possible_agents)
    assert "crash_box_right" not in env.agents and "crash_box_left" in env.agents
    assert env.observation_space("hood_left") is env.observation_space("hood_left")
    assert obs["hood_left"].shape == env.observation_space("hood_left").shape
    assert infos["hood_left"]["rmse"].shape == (3,)
    act = {a: env.action_space(a).sample() for a in env.possible_agents}
    obs, rew, _, _, _ = env.step(act)  # actions of inactive agents are ignored
    assert set(obs) == set(rew) == set(env.agents)
    assert len(set(rew.values())) == 1
    with pytest.raises(ActionError, match="unknown agent 'nose'"):
        env.step({"nose": np.zeros(7, np.float32)})
    with pytest.raises(ActionError, match=r"shape \[7\]"):
        env.step({"crash_box_left": np.zeros(3, np.float32)})
    with pytest.raises(ActionError, match="floating point"):
        env.step({"crash_box_left": np.zeros(7, np.int64)})
    with pytest.raises(ActionError, match="finite"):
        env.step({"crash_box_left": np.full(7, np.nan, np.float32)})
    assert env.state().shape == env.state_space.shape


def test_an_episode_without_active_agents_says_so(cells):
    """Masking settings that leave no agent active: step() said "the episode is over; call reset()", and every
    reset gave the same."""
    strict = cfg(scenarios={"small_overlap_left": 1.0},
                 **{"masking.mode": "primary", "masking.min_fraction": 1.0, "masking.primary_depth": 0.05})  # fmt: skip
    with pytest.warns(UserWarning, match="scenario 'small_overlap_left' activates no agent"):  # said when built
        env = CalibrationParallelEnv(strict, cells)
    env.reset(seed=0)
    assert env.agents == []
    with pytest.raises(ActionError, match=r"no agent is active in this episode \(small_overlap_left: .*'primary'"):
        env.step({})
    env = CalibrationParallelEnv(cfg(**{"termination.max_iterations": 1}), cells)
    env.reset(seed=0)
    env.step({})
    with pytest.raises(ActionError, match=r"the episode is over"):
        env.step({})


def test_the_aec_conversion_gets_the_live_agents_infos(cells):
    """``reset_agents="live"``: PettingZoo's ``parallel_to_aec`` takes the reset infos as they are (with every
    possible agent's, it copied the whole dict under each agent) and passes its API test without a warning."""
    from pettingzoo.test import api_test
    from pettingzoo.utils.conversions import parallel_to_aec

    config = cfg(scenarios={"small_overlap_left": 1.0})
    aec = parallel_to_aec(CalibrationParallelEnv(config, cells, reset_agents="live"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        aec.reset(seed=0)
    assert set(aec.infos) == set(aec.agents) and "crash_box_right" not in aec.agents
    assert set(aec.infos["crash_box_left"]) == {"area", "dfd", "rmse", "action_entries"}
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*(seed|observation space|action space|named in the format).*")
        api_test(parallel_to_aec(CalibrationParallelEnv(config, cells, reset_agents="live")), num_cycles=5)
    with pytest.raises(ActionError, match="reset_agents must be 'possible' or 'live'"):
        CalibrationParallelEnv(config, cells, reset_agents="all")


@pytest.mark.parametrize("granularity", ["subassembly", "cell"])
def test_native_torchrl_env_specs(cells, granularity):
    env = CalibrationTorchEnv(cfg(granularity=granularity), batch_size=3, cells=cells)
    check_env_specs(env, seed=0)
    td = env.reset()
    assert td["agents", "observation"].shape == (3, env.core.A, env.core.obs_dim)
    assert td["agents", "mask"].dtype == torch.bool and td["agents", "mask"].shape == (3, env.core.A)
    assert td["done"].shape == (3, 1) and td["state"].shape == (3, env.core.state_dim)
    td = env.rand_step(td)
    assert td["next", "reward"].shape == (3, 1)
    roll = env.rollout(6, break_when_any_done=False)  # auto-resets rows that finished (max 4 iterations)
    assert roll.shape == (3, 6) and roll["next", "truncated"].any()


def test_pettingzoo_wrapper_specs(cells):
    env = PettingZooWrapper(CalibrationParallelEnv(cfg(), cells), use_mask=True, done_on_any=False)
    check_env_specs(env, seed=0)


def test_the_documented_wrapping_runs_an_offset_episode_to_its_end(cells):
    """In an offset crash some agents are outside the impact region, never in ``agents``; the wrapper counts them as
    done, and its parallel-env default ``done_on_any=True`` ended the episode after one step. The wrapping the
    module doc and README give runs it to the env's own end (4 iterations here)."""
    config = cfg(scenarios={"offset40_left": 1.0})
    default = PettingZooWrapper(CalibrationParallelEnv(config, cells), use_mask=True)
    default.set_seed(0)
    assert default.rollout(10).shape[0] == 1  # why the docs name done_on_any
    wrapped = PettingZooWrapper(CalibrationParallelEnv(config, cells), use_mask=True, done_on_any=False)
    wrapped.set_seed(0)
    roll = wrapped.rollout(10)
    assert roll.shape[0] == 4 and roll["next", "done"][-1].all() and not roll["next", "done"][:-1].any()


@pytest.mark.parametrize("granularity", ["subassembly", "cell"])
def test_the_pettingzoo_door_gives_each_agent_the_native_action_mask(cells, granularity):
    """Per cell with ``masking.cells: region`` in a driver-side small overlap, the active left bumper beam's
    passenger-side cells do not act: the PettingZoo infos carry each agent's row of the native env's
    ``("agents", "action_mask")`` as ``action_entries`` (all ``False`` for an agent inactive in the episode), which
    TorchRL's ``PettingZooWrapper`` passes on as ``(group, "info", "action_entries")``."""
    config = cfg(scenarios={"small_overlap_left": 1.0}, granularity=granularity, **{"masking.cells": "region"})
    native = CalibrationTorchEnv(config, batch_size=1, cells=cells)
    mask = native.reset(seed=3)["agents", "action_mask"][0]
    env = CalibrationParallelEnv(config, cells)
    _, infos = env.reset(seed=3)
    for i, a in enumerate(env.possible_agents):
        assert infos[a]["action_entries"].dtype == np.bool_ and infos[a]["action_entries"].shape == (env.core.act_dim,)
        assert np.array_equal(infos[a]["action_entries"], mask[i].numpy()), a
        assert infos[a]["action_entries"].any() == (a in env.agents), a
    beam = env.possible_agents.index("bumper_beam_left")
    if granularity == "cell":  # some of the beam's valid cell slots lie outside the region
        valid = env.core.layout.valid[beam].repeat_interleave(7)
        assert bool(mask[beam].any()) and bool((valid & ~mask[beam]).any())
    _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
    assert all(np.array_equal(infos[a]["action_entries"], mask[env.possible_agents.index(a)].numpy()) for a in infos)
    wrapped = PettingZooWrapper(CalibrationParallelEnv(config, cells), use_mask=True, done_on_any=False,
                                group_map=MarlGroupMapType.ALL_IN_ONE_GROUP)  # fmt: skip
    group = next(iter(wrapped.group_map))
    td = wrapped.reset(seed=3)
    live = td[group, "mask"]
    assert torch.equal(td[group, "info", "action_entries"][live], mask[live])


def test_copies_of_the_env_draw_the_same_episodes_until_seeded(cells):
    """Every copy starts from the config's ``seed``: the workers of a ``SerialEnv`` replay one another's episodes
    (a batch of duplicates) until ``set_seed`` gives each its own seed, as the docstring says."""
    from torchrl.envs import SerialEnv

    def make():
        return CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)

    env = SerialEnv(2, make)
    td = env.reset()
    assert torch.equal(td["state"][0], td["state"][1])
    env.set_seed(7)
    first = env.reset()
    assert not torch.equal(first["state"][0], first["state"][1])
    env.set_seed(7)
    assert torch.equal(env.reset()["state"], first["state"])
    env.close()


def test_both_doors_give_identical_numbers(cells):
    config = cfg(scenarios={"offset40_right": 1.0, "small_overlap_left": 1.0, "full_width_40": 1.0})
    native = CalibrationTorchEnv(config, batch_size=1, cells=cells)
    wrapped = PettingZooWrapper(CalibrationParallelEnv(config, cells), use_mask=True, done_on_any=False,
                                group_map=MarlGroupMapType.ALL_IN_ONE_GROUP)  # fmt: skip
    group = next(iter(wrapped.group_map))
    assert wrapped.group_map[group] == native.agent_names
    for seed in (11, 12):
        a = native.reset(seed=seed)
        b = wrapped.reset(seed=seed)
        assert torch.equal(a["agents", "observation"][0], b[group, "observation"])
        assert torch.equal(a["agents", "mask"][0], b[group, "mask"])
        g = torch.Generator().manual_seed(seed)
        for _ in range(4):
            act = torch.rand(1, native.core.A, 7, generator=g) * 2 - 1
            act[0, ~a["agents", "mask"][0]] = float("nan")  # inactive agents' actions are ignored by both doors
            a = native.step(a.set(("agents", "action"), act))["next"]
            b = wrapped.step(b.set((group, "action"), act[0]))["next"]
            live = a["agents", "mask"][0]
            assert torch.equal(a["agents", "observation"][0][live], b[group, "observation"][live])
            # the wrapper zero-fills agents absent from the episode and clears its mask once all are done
            assert torch.equal(b[group, "mask"], live & ~a["done"][0])
            assert torch.equal(b[group, "reward"][live, 0], a["reward"][0].expand(int(live.sum())))
            for k in ("done", "terminated", "truncated"):
                assert torch.equal(a[k][0], b[k]), k
            torch.testing.assert_close(b[group, "info", "rmse"][live][0], a["metrics", "rmse"][0].float())
            if bool(a["done"]):
                break
            a, b = a.clone(), b.clone()


def test_native_seed_and_partial_reset(cells):
    env = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)
    env.set_seed(5)
    first = env.reset()
    env.set_seed(5)
    again = env.reset()
    assert torch.equal(first["agents", "observation"], again["agents", "observation"])
    td = env.rand_step(again)
    before = env.core.params[1].clone()
    env.reset(TensorDict({"_reset": torch.tensor([[True], [False]])}, batch_size=[2]))
    assert torch.equal(env.core.params[1], before) and int(env.core.iteration[0]) == 0
    assert td["next", "reward"].dtype == torch.float32


def test_actions_taken_with_gradients_are_used_as_values(cells):
    """A policy's output outside ``torch.no_grad()`` (``env.rollout(n, policy)``): the env takes the values. It tied
    the parameters and every later observation to the policy's graph (which grew each step), and the PettingZoo
    door failed inside numpy (``Can't call numpy() on Tensor that requires grad``)."""
    from tensordict.nn import TensorDictModule

    env = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)
    lin = torch.nn.Linear(env.core.obs_dim, env.core.act_dim)
    policy = TensorDictModule(lambda o: torch.tanh(lin(o)), in_keys=[("agents", "observation")],
                              out_keys=[("agents", "action")])  # fmt: skip
    roll = env.rollout(2, policy, break_when_any_done=False)
    assert roll["agents", "action"].requires_grad  # the policy's graph, as the user built it
    assert not env.core.params.requires_grad and env.core.params.grad_fn is None
    assert not roll["next", "agents", "observation"].requires_grad and not roll["next", "state"].requires_grad
    pz, plain = CalibrationParallelEnv(cfg(), cells), CalibrationParallelEnv(cfg(), cells)
    pz.reset(seed=3)
    plain.reset(seed=3)
    act = {a: torch.full((7,), 0.5, requires_grad=True) for a in pz.agents}
    obs, rew, _, _, _ = pz.step(act)
    obs0, rew0, _, _, _ = plain.step({a: np.full(7, 0.5, np.float32) for a in plain.agents})
    assert rew == rew0 and all(np.array_equal(obs[a], obs0[a]) for a in obs0)


def test_space_lookup_of_an_unknown_agent_names_it_and_the_possible_agents(cells):
    """``observation_space``/``action_space`` of a name not in ``possible_agents``: a bare ``KeyError: 'nose'``
    from a private dict; now the env's API error naming the agent and listing the possible agents, as step() does."""
    env = CalibrationParallelEnv(cfg(), cells)
    for lookup in (env.observation_space, env.action_space):
        with pytest.raises(ActionError, match=r"unknown agent 'nose'; possible agents are \['") as err:
            lookup("nose")
        assert all(a in str(err.value) for a in env.possible_agents)
        assert lookup.__name__ in str(err.value)
        with pytest.raises(ActionError, match=r"unknown agent \['nose'\]"):  # unhashable: was a TypeError
            lookup(["nose"])
    assert env.action_space(env.possible_agents[0]).shape == (7,)


def test_the_pettingzoo_wrapper_rounds_the_info_metrics_to_float32_as_documented(cells):
    """The PettingZoo infos hold float64 metrics and a bool ``action_entries``; TorchRL's ``PettingZooWrapper`` builds
    its info spec without a dtype (float32) and has no option to set one, so it hands every info entry on as float32:
    the metrics rounded (relative 6e-8 at most, 2**-24) and ``action_entries`` as 1.0 / 0.0. The env's docstring and
    the README say so; this pins what they say."""
    env = CalibrationParallelEnv(cfg(), cells)
    _, infos = env.reset(seed=3)
    wrapped = PettingZooWrapper(CalibrationParallelEnv(cfg(), cells), use_mask=True, done_on_any=False,
                                group_map=MarlGroupMapType.ALL_IN_ONE_GROUP)  # fmt: skip
    group = next(iter(wrapped.group_map))
    td = wrapped.reset(seed=3)
    for i, a in enumerate(env.possible_agents):
        for k in ("area", "dfd", "rmse"):
            exact = torch.as_tensor(infos[a][k])
            got = td[group, "info", k][i]
            assert exact.dtype == torch.float64 and got.dtype == torch.float32
            assert torch.equal(got, exact.float())  # the float32 nearest to the float64 value
            assert float(((got.double() - exact) / exact).abs().max()) <= 2.0**-24
        entries = td[group, "info", "action_entries"][i]
        assert entries.dtype == torch.float32
        assert torch.equal(entries.bool(), torch.as_tensor(infos[a]["action_entries"]))


def test_a_partial_step_moves_only_the_rows_it_names(cells):
    """TorchRL steps a batch-locked env with a ``"_step"`` mask (``rollout(..., break_when_all_done=True)`` sets it to
    the rows whose episodes go on) and trusts ``_step`` to step only those rows. The env stepped every row: a row whose
    episode had ended went on past ``max_iterations`` (its parameters, metrics and iteration moved, its candidates
    reached the simulation hooks), and a row held back by ``_step=False`` moved like the others."""
    env = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)
    whole = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)
    seen = []
    env.core.simulation_hooks.append(lambda p, m: seen.append(p.shape[0]))
    td, ref = env.reset(seed=1), whole.reset(seed=1)
    before = env._observation_td()
    params, metrics = env.core.params.clone(), [m.clone() for m in env.core.metrics]
    act = torch.rand(2, env.core.A, env.core.act_dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    act[1] = float("nan")  # a row that is not stepped: its actions are not used
    seen.clear()
    out = env.step(td.set(("agents", "action"), act).set("_step", torch.tensor([True, False])))["next"]
    full = whole.step(ref.set(("agents", "action"), act.nan_to_num(0.0)))["next"]
    assert seen == [1]  # one candidate simulated, the stepped row's
    assert env.core.iteration.tolist() == [1, 0]
    assert torch.equal(env.core.params[1], params[1]) and not torch.equal(env.core.params[0], params[0])
    assert all(torch.equal(m[1], m0[1]) for m, m0 in zip(env.core.metrics, metrics, strict=True))
    for k in (("agents", "observation"), ("agents", "mask"), ("agents", "action_mask"), "state", ("metrics", "rmse")):
        assert torch.equal(out[k][1], before[k][1]), k  # the held row: as it stood
        assert torch.equal(out[k][0], full[k][0]), k  # the stepped row: as a whole step gives it
    assert float(out["reward"][1]) == 0.0 and float(out["reward"][0]) == float(full["reward"][0])
    assert not bool(out["done"][1])
    with pytest.raises(ActionError, match=r"step mask must be \[2\] bool, got shape \[3\]"):
        env.core.step(act, mask=torch.ones(3, dtype=torch.bool))

    # rows that end at different iterations: a rollout to the end of all of them steps no row past its end
    env.core.simulation_hooks.clear()
    td = env.step_mdp(env.rand_step(env.reset(seed=1)))
    td = env.reset(td.set("_reset", torch.tensor([[True], [False]])))  # row 1 one iteration ahead of row 0
    roll = env.rollout(6, tensordict=td, auto_reset=False, break_when_all_done=True, break_when_any_done=False)
    assert roll.shape == (2, 4) and env.core.iteration.tolist() == [4, 4]  # cfg(): max_iterations 4
    assert roll["next", "truncated"][:, -1].all()


def test_the_joint_action_view_passes_a_partial_step_on(cells):
    """``ppo_single``'s :class:`~marlcrash.calibrate.marl.JointActionEnv` hands its ``"_step"`` rows to the
    multi-agent env it wraps (it stepped every row)."""
    from marlcrash.calibrate.marl import JointActionEnv

    env = JointActionEnv(CalibrationTorchEnv(cfg(), batch_size=2, cells=cells))
    td = env.reset(seed=1)
    params = env.core.params.clone()
    env.rand_step(td.set("_step", torch.tensor([False, True])))
    assert env.core.iteration.tolist() == [0, 1]
    assert torch.equal(env.core.params[0], params[0]) and not torch.equal(env.core.params[1], params[1])


_DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA"))]


@pytest.mark.parametrize("device", _DEVICES)
def test_the_native_env_puts_its_specs_and_outputs_on_its_device(cells, device):
    """``CalibrationTorchEnv(device=...)``, as TorchRL's ``EnvBase(device=...)``: specs and every output on that device,
    actions and ``"_reset"``/``"_step"`` masks taken from it; the simulation stays on the CPU and gives the numbers a
    CPU env gives. The constructor took no ``device`` (a TypeError), and its env was always on the CPU."""
    from marlcrash.calibrate.marl import JointActionEnv

    dev = torch.device(device)
    env = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells, device=device)
    ref = CalibrationTorchEnv(cfg(), batch_size=2, cells=cells)
    assert env.device == dev
    for spec in (env.full_observation_spec, env.full_action_spec, env.full_reward_spec, env.full_done_spec):
        assert {leaf.device for leaf in spec.values(True, True)} == {dev}
    check_env_specs(env, seed=0)
    check_env_specs(JointActionEnv(env), seed=0)  # ppo_single's view: on the device of the env it wraps
    td, td0 = env.reset(seed=2), ref.reset(seed=2)
    assert td.device == dev and {t.device for t in td.values(True, True)} == {dev}
    act = torch.rand(2, env.core.A, env.core.act_dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    out = env.step(td.set(("agents", "action"), act.to(dev)).set("_step", torch.tensor([True, False], device=dev)))
    out0 = ref.step(td0.set(("agents", "action"), act).set("_step", torch.tensor([True, False])))
    assert {t.device for t in out["next"].values(True, True)} == {dev}
    assert (out["next"].cpu() == out0["next"]).all()
    reset = env.reset(out["next"].set("_reset", torch.tensor([[False], [True]], device=dev)))
    assert reset.device == dev and env.core.iteration.tolist() == [1, 0]
    assert JointActionEnv(env).reset(seed=2).device == dev


def test_a_bad_device_is_named(cells):
    with pytest.raises(ConfigError, match="torch device") as e:
        CalibrationTorchEnv(cfg(), batch_size=1, cells=cells, device="gpu0")
    assert e.value.key == "device"
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"'cuda' is not available here \(0 CUDA devices\)") as e:
            CalibrationTorchEnv(cfg(), batch_size=1, cells=cells, device="cuda")
        assert e.value.key == "device"


def test_stepping_an_ended_episode_is_refused_naming_its_rows(cells):
    """A row whose episode ended (terminated or truncated) and was not reset: the native env stepped it on past
    ``max_iterations`` (iterations 2, 3, ... of a one-step episode), moving its parameters and giving rewards of no
    episode, where the PettingZoo door refuses ("the episode is over"). Now refused, naming the rows, until they are
    reset; an ended row held back by ``"_step"`` is fine (TorchRL's ``rollout(..., break_when_all_done=True)``)."""
    env = CalibrationTorchEnv(cfg(**{"termination.max_iterations": 1}), batch_size=2, cells=cells)
    td = env.step_mdp(env.rand_step(env.reset(seed=0)))
    assert td["done"].all()
    params = env.core.params.clone()
    with pytest.raises(ActionError, match=r"rows \[0, 1\] of 2 have ended .*; reset them"):
        env.rand_step(td)
    assert torch.equal(env.core.params, params) and env.core.iteration.tolist() == [1, 1]  # a refused step: nothing
    td = env.reset(td.set("_reset", torch.tensor([[True], [False]])))
    with pytest.raises(ActionError, match=r"rows \[1\] of 2 have ended"):
        env.rand_step(td)
    env.rand_step(td.set("_step", torch.tensor([True, False])))
    assert env.core.iteration.tolist() == [1, 1]
    roll = env.rollout(3, break_when_any_done=False)  # TorchRL resets ended rows itself
    assert roll.shape == (2, 3) and env.core.iteration.tolist() == [1, 1]


def test_actions_outside_the_box_act_as_its_bound_and_non_finite_ones_are_refused(cells):
    """As both doors' docstrings say: an action value outside ``[-1, 1]`` is clipped to the bound (the step is the
    clipped action's, bit for bit), a NaN in an entry that acts is an :class:`ActionError` naming the entry."""
    env, ref = (CalibrationTorchEnv(cfg(), batch_size=1, cells=cells) for _ in range(2))
    act = (torch.rand(1, env.core.A, env.core.act_dim, generator=torch.Generator().manual_seed(1)) * 2 - 1) * 3
    assert (act.abs() > 1).any()
    out = env.step(env.reset(seed=4).set(("agents", "action"), act))["next"]
    out0 = ref.step(ref.reset(seed=4).set(("agents", "action"), act.clamp(-1, 1)))["next"]
    assert (out == out0).all() and torch.equal(env.core.params, ref.core.params)
    td = env.reset(seed=4)
    a, j = (int(x) for x in torch.nonzero(td["agents", "action_mask"][0])[0])
    act[0, a, j] = float("nan")
    with pytest.raises(ActionError, match=rf"actions\[0, {a}, {j}\] \(agent '{env.agent_names[a]}'\) is nan"):
        env.step(td.set(("agents", "action"), act))
    pz, pz0 = CalibrationParallelEnv(cfg(), cells), CalibrationParallelEnv(cfg(), cells)
    pz.reset(seed=4)
    pz0.reset(seed=4)
    big = {n: np.full(7, 5.0, np.float32) for n in pz.agents}
    obs, rew, _, _, _ = pz.step(big)
    obs0, rew0, _, _, _ = pz0.step({n: np.ones(7, np.float32) for n in pz0.agents})
    assert rew == rew0 and all(np.array_equal(obs[n], obs0[n]) for n in obs0)


def test_the_pettingzoo_door_reads_a_bfloat16_policy_output_and_names_a_ragged_action(cells):
    """A bfloat16 tensor (a mixed-precision policy's output) was torch's "unsupported ScalarType BFloat16" from inside
    ``numpy()``, and a ragged list numpy's "inhomogeneous shape" ValueError, neither naming the agent. The bfloat16
    action acts as its values do; the ragged one is an :class:`ActionError` naming the agent and the shape wanted."""
    env, ref = CalibrationParallelEnv(cfg(), cells), CalibrationParallelEnv(cfg(), cells)
    env.reset(seed=2)
    ref.reset(seed=2)
    act = torch.linspace(-1, 1, 7, dtype=torch.bfloat16)
    _, rew, _, _, _ = env.step(dict.fromkeys(env.agents, act))
    _, rew0, _, _, _ = ref.step({n: act.float().numpy() for n in ref.agents})
    assert rew == rew0 and torch.equal(env.core.params, ref.core.params)
    env.reset(seed=2)
    name = env.agents[0]
    with pytest.raises(ActionError, match=rf"action of agent '{name}' must be an array of shape \[7\]"):
        env.step({name: [[0.0] * 3, [0.0] * 4]})
