"""MAPPO / IPPO / joint-action PPO building blocks, the agent mask in the loss, resume and evaluation.

Runs on a shortened copy of configs/ (every scenario simulated for 30 ms instead of 150 ms)
so that tiny training runs take seconds.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import shutil
import stat
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from marlcrash.calibrate.checkpoint import load_checkpoint, save_checkpoint
from marlcrash.calibrate.evaluate import update_summary
from marlcrash.calibrate.logging import CSVLogger, read_log
from marlcrash.calibrate.marl import (
    JointActionEnv,
    batch_stats,
    collect,
    expand_team,
    load_algorithm_config,
    load_run_config,
    load_train_config,
    make_advantage,
    make_critic,
    make_env,
    make_loss,
    make_policy,
    masked_standardize,
    train,
    update,
)
from marlcrash.errors import ConfigError, ModelError


@pytest.fixture
def short(short_configs, monkeypatch) -> Path:
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(short_configs))
    return short_configs


def tiny(tmp_path: Path, algorithm: str = "mappo", **kw):
    """A training config of a few seconds: 4 envs, 2 steps, 4 iterations, small networks."""
    algo = dataclasses.asdict(load_algorithm_config(algorithm))
    algo.update(hidden=[16, 16], minibatch_size=4, epochs=2)
    data = {
        "algorithm": algo,
        "env": "default",
        "env_overrides": {},
        "n_envs": 4,
        "episode_length": 2,
        "iterations": 4,
        "time_limit_s": None,
        "seed": 0,
        "logger": "csv",
        "checkpoint_every": 1,
        "progress_bar": False,
        "out_dir": str(tmp_path / "runs"),
        "name": "straight",
        "eval": {"iterations": 2, "plots": False},
    }
    for k, v in kw.items():
        node, parts = data, k.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = v
    return load_train_config(data, ci=False)


def test_policy_and_critics_shapes(short, tmp_path):
    for name in ("mappo", "ippo", "ppo_single"):
        cfg = tiny(tmp_path, name)
        env = make_env(cfg)
        policy, critic = make_policy(env, cfg.algorithm), make_critic(env, cfg.algorithm)
        td = critic(policy(env.reset()))
        A = env.observation_spec["agents", "observation"].shape[-2]
        act = td["agents", "action"]
        assert act.shape == env.action_spec["agents", "action"].shape
        assert td["agents", "state_value"].shape == (4, A, 1)
        assert bool((act.abs() <= 1).all())
        assert td["agents", "action_log_prob"].shape == (4, A)
        if name == "ppo_single":
            assert A == 1 and act.shape[-1] == env.core.A * env.core.act_dim
        if cfg.algorithm.centralised_critic:  # one team value for all agents
            v = td["agents", "state_value"]
            assert torch.equal(v, v[:, :1].expand_as(v))


@pytest.mark.parametrize("algorithm", ["ppo_single", "mappo"])
def test_action_entries_that_do_not_act_leave_the_loss(short, tmp_path, algorithm):
    """ppo_single's log-probability summed the whole joint action, inactive agents' entries included (the env ignores
    them): changing only those entries of a batch moved the clipped objective from -0.41 to -2e-5 and the KL
    estimate from 0 to 766. MAPPO's loss mask leaves inactive agents out, but an active agent's factors that no cell
    takes (20 of the default car's 147) were in its importance ratio and entropy. The distribution of every entry the
    env's action mask leaves out is now fixed (mean 0, scale init_std), whatever the weights: its log importance
    ratio is 0."""
    cfg = tiny(tmp_path, algorithm)
    env = make_env(cfg)
    torch.manual_seed(0)
    policy, other = make_policy(env, cfg.algorithm), make_policy(env, cfg.algorithm)
    with torch.no_grad():
        for w in other.parameters():  # another policy: every weight moved
            w.add_(0.3 * torch.randn_like(w))
        td = policy(env.reset())
    active = td["agents", "action_mask"]
    assert active.shape == td["agents", "action"].shape and active.any() and (~active).any()
    if algorithm == "mappo":  # entries of active agents are among those left out
        assert (~active & td["agents", "mask"][..., None]).any()
    a = td["agents", "action"]
    b = torch.where(active, a, (0.7 - a).clamp(-0.95, 0.95))  # the entries that do not act changed

    def change(pol):  # log pi(b) - log pi(a): those entries' part of the log-probability
        with torch.no_grad():
            dist = pol.get_dist(td.clone())
            return dist.log_prob(b) - dist.log_prob(a)

    torch.testing.assert_close(change(policy), change(other), rtol=1e-5, atol=1e-3)  # float32 sums of ~300
    with torch.no_grad():  # the active entries still follow the weights
        assert not torch.allclose(policy(td.clone())["agents", "loc"], other(td.clone())["agents", "loc"])


def test_the_logged_return_and_final_metrics_are_those_of_each_rows_first_episode():
    """An episode that ended early (success) was reset in place and its row went on with a new one: the logged
    return added up both, and the final metrics were the new episode's, half run."""
    from tensordict import TensorDict

    done = torch.tensor([[False, True, False, False], [False, False, False, False]])[..., None]  # row 0 ends at t=1
    reward = torch.tensor([[1.0, 2.0, -5.0, -5.0], [0.5, 0.5, 0.5, 0.5]])[..., None]
    area = torch.tensor([[[0.4, 0.2], [0.01, 0.03], [0.5, 0.5], [0.4, 0.4]], [[0.3, 0.1], [0.2, 0.1], [0.1, 0.1],
                                                                                [0.05, 0.07]]])  # fmt: skip
    start = torch.tensor([[[0.6, 0.4]] * 4, [[0.5, 0.3]] * 4])
    metrics = dict.fromkeys(("area", "dfd", "rmse"), start)
    nxt = dict.fromkeys(("area", "dfd", "rmse"), area)
    data = TensorDict({"metrics": metrics, "next": {"reward": reward, "done": done, "metrics": nxt}}, batch_size=(2, 4))
    s = batch_stats(data)
    assert s["reward_mean"] == pytest.approx(float(reward.mean()))
    assert s["return_mean"] == pytest.approx((3.0 + 2.0) / 2)  # row 0: its episode's two steps, not -7
    assert s["area_final"] == pytest.approx((0.02 + 0.06) / 2)  # row 0 at t=1 (sensor mean 0.02), row 1 at t=3
    assert s["area_initial"] == pytest.approx((0.5 + 0.4) / 2)


def test_training_does_not_depend_on_torchs_default_dtype(short, tmp_path):
    """A notebook that set ``torch.set_default_dtype(torch.float64)`` (for the simulator, say) trains as any other:
    the networks take the env's float32 observations, and the numbers are those of a float32 default."""
    ref = train(tiny(tmp_path, name="f32", iterations=1), evaluate=False)
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        cfg = tiny(tmp_path, name="f64", iterations=1)
        env = make_env(cfg)
        for net in (make_policy(env, cfg.algorithm), make_critic(env, cfg.algorithm)):
            assert {p.dtype for p in net.parameters()} == {torch.float32}
        run = train(cfg, evaluate=False)
    finally:
        torch.set_default_dtype(previous)
    assert _comparable_log(run.run_dir) == _comparable_log(ref.run_dir)


def test_untrained_mean_action_is_near_zero(short, tmp_path):
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    cfg = tiny(tmp_path)
    env = make_env(cfg)
    policy = make_policy(env, cfg.algorithm)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        a = policy(env.reset())["agents", "action"]
    assert float(a.abs().max()) < 0.05  # mean_init_gain 0.01: the first deterministic step barely moves


def test_the_policy_std_starts_at_init_std_and_is_bounded_below_by_min_std(short, tmp_path):
    """TorchRL's ``biased_softplus_<init_std>`` adds a floor of 0.01 of its own: with ``min_std`` 0.001 the policy's
    standard deviation never went below 0.01, and ``init_std`` 0.005 started at 0.01."""
    cfg = tiny(tmp_path, **{"algorithm.init_std": 0.005, "algorithm.min_std": 0.001})
    env = make_env(cfg)
    policy = make_policy(env, cfg.algorithm)
    td = env.reset()
    with torch.no_grad():
        scale = policy(td.clone())["agents", "scale"]
        torch.testing.assert_close(scale, torch.full_like(scale, 0.005), rtol=0.02, atol=0)  # mean_init_gain: near
        net = policy.module[0].module[0]  # the MultiAgentMLP before the scale head
        last = str(max(int(k) for k in net.params.keys()))  # noqa: SIM118
        net.params[last, "bias"].fill_(-100.0)  # as far down as the head goes
        scale = policy(td.clone())["agents", "scale"]
    acts = td["agents", "action_mask"]  # the entries that do not act keep init_std whatever the weights
    torch.testing.assert_close(scale[acts], torch.full_like(scale[acts], 0.001), rtol=1e-3, atol=0)
    assert bool((scale[~acts] == 0.005).all())
    default = tiny(tmp_path).algorithm  # the shipped values (min_std 0.01 = TorchRL's floor) are unchanged
    with torch.no_grad():
        scale = make_policy(env, default)(td.clone())["agents", "scale"]
    torch.testing.assert_close(scale, torch.full_like(scale, default.init_std), rtol=0.02, atol=0)


def test_joint_action_env_is_the_multi_agent_env(short, tmp_path):
    from torchrl.envs.utils import check_env_specs

    cfg = tiny(tmp_path, "ppo_single")
    joint = make_env(cfg)
    assert isinstance(joint, JointActionEnv)
    check_env_specs(joint, seed=3)
    multi = make_env(tiny(tmp_path, "mappo"))
    joint.set_seed(5)
    multi.set_seed(5)
    tj, tm = joint.reset(), multi.reset()
    c = multi.core
    a = torch.rand(4, c.A, c.act_dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    tm["agents", "action"] = a
    tj["agents", "action"] = a.reshape(4, 1, -1)
    nj, nm = joint.step(tj)["next"], multi.step(tm)["next"]
    assert torch.equal(joint.core.params, multi.core.params)
    assert torch.equal(nj["reward"], nm["reward"])
    assert torch.equal(nj["agents", "observation"][:, 0], nm["state"])
    assert torch.equal(nj["agents", "mask"][:, 0], nm["agents", "mask"].any(-1))


@pytest.mark.parametrize(
    "device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA"))]
)
def test_the_env_of_a_run_is_on_the_runs_device(short, tmp_path, monkeypatch, device):
    """``device`` of a run places the env's specs and outputs too (TorchRL's ``EnvBase(device=...)``), so a collected
    batch is where the policy and the PPO update are; the env was built on the CPU whatever the run's device."""
    import marlcrash.calibrate.marl as marl

    built = []

    class Recorded(marl.CalibrationTorchEnv):
        def __init__(self, *args, **kwargs):
            built.append(kwargs.get("device"))
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(marl, "CalibrationTorchEnv", Recorded)
    for name in ("mappo", "ppo_single"):
        cfg = tiny(tmp_path, name, device=device)
        env = make_env(cfg)
        assert built[-1] == device and env.device == torch.device(device), name
        policy = make_policy(env, cfg.algorithm).to(device)
        data, _ = collect(env, policy, 2)
        assert data.device == torch.device(device) and data.get(("next", "reward")).device == torch.device(device)


def test_expand_team_and_masked_standardize(short, tmp_path):
    cfg = tiny(tmp_path)
    env = make_env(cfg)
    data, resets = collect(env, make_policy(env, cfg.algorithm), 3)
    assert data.batch_size == (4, 3) and resets >= 4
    expand_team(data)
    A = env.core.A
    r = data["next", "agents", "reward"]
    assert r.shape == (4, 3, A, 1)
    assert torch.equal(r, data["next", "reward"][:, :, None].expand(4, 3, A, 1))
    assert data["next", "agents", "done"].shape == (4, 3, A, 1)
    x = torch.randn(4, 3, A, 1, dtype=torch.float64)
    mask = torch.rand(4, 3, A) > 0.3
    y = masked_standardize(x, mask)
    sel = y[mask.unsqueeze(-1)]
    assert abs(float(sel.mean())) < 1e-9 and abs(float(sel.std(unbiased=False)) - 1) < 1e-9
    assert torch.equal(y[~mask.unsqueeze(-1)], x[~mask.unsqueeze(-1)])


@pytest.mark.parametrize("name", ["mappo", "ippo"])
def test_inactive_agents_are_masked_out_of_the_loss(short, tmp_path, name):
    # offset crashes on one side leave agents inactive (impact-region rule)
    cfg = tiny(tmp_path, name, env_overrides={"scenarios": {"small_overlap_left": 1.0}})
    torch.manual_seed(0)
    env = make_env(cfg)
    policy, critic = make_policy(env, cfg.algorithm), make_critic(env, cfg.algorithm)
    loss, gae = make_loss(policy, critic, cfg.algorithm), make_advantage(critic, cfg.algorithm)
    assert loss.loss_mask_key == ("agents", "mask")
    data, _ = collect(env, policy, 2)
    expand_team(data)
    with torch.no_grad():
        gae(data)
    flat = data.reshape(-1)
    mask = flat["agents", "mask"]
    assert bool((~mask).any()) and bool(mask.any())
    torch.manual_seed(1)  # TanhNormal's entropy is a Monte-Carlo estimate: same draws for every call
    base = loss(flat.clone())

    def perturbed(where: torch.Tensor) -> dict:
        td = flat.clone()
        adv = td["agents", "advantage"].clone()
        adv[where] = 1e3
        td["agents", "advantage"] = adv
        vt = td["agents", "value_target"].clone()
        vt[where] = 1e3
        td["agents", "value_target"] = vt
        torch.manual_seed(1)
        return loss(td)

    inactive = perturbed(~mask)
    for k in ("loss_objective", "loss_critic"):
        assert torch.equal(inactive[k], base[k]), k  # inactive agents' entries change nothing
    # the entropy term depends on the policy's distribution: move the inactive agents' observations
    td = flat.clone()
    obs = td["agents", "observation"].clone()
    obs[~mask] += 3.0
    td["agents", "observation"] = obs
    torch.manual_seed(1)
    moved = loss(td)
    # the logged diagnostics are masked like the loss terms (TorchRL's own average every entry)
    for k in ("loss_entropy", "loss_objective", "entropy", "kl_approx"):
        assert torch.equal(moved[k], base[k]), k
    entropy, loss_entropy = float(base["entropy"].detach()), float(base["loss_entropy"].detach())
    assert entropy == pytest.approx(-loss_entropy / cfg.algorithm.entropy_coef, rel=1e-5)
    td["agents", "observation"] = flat["agents", "observation"] + 3.0 * mask[..., None]  # the active ones instead
    torch.manual_seed(1)
    shifted = loss(td)
    for k in ("loss_entropy", "entropy", "kl_approx"):
        assert not torch.equal(shifted[k], base[k]), k
    active = perturbed(mask)
    assert not torch.allclose(active["loss_objective"], base["loss_objective"])
    assert not torch.allclose(active["loss_critic"], base["loss_critic"])


def _collected(tmp_path):
    """A tiny run's config, PPO loss and GAE, and one collected batch of 2 steps (team reward expanded)."""
    cfg = tiny(tmp_path)
    torch.manual_seed(0)
    env = make_env(cfg)
    policy, critic = make_policy(env, cfg.algorithm), make_critic(env, cfg.algorithm)
    loss, gae = make_loss(policy, critic, cfg.algorithm), make_advantage(critic, cfg.algorithm)
    data, _ = collect(env, policy, 2)
    expand_team(data)
    return cfg, loss, gae, data


def test_a_runaway_ratio_is_bounded_and_a_diverged_update_is_refused_before_the_step(short, tmp_path):
    """Single-agent PPO on per-cell actions (thousands of joint dimensions) moved the summed log density by hundreds
    in one step: the ratio overflowed, the gradient was NaN, and the NaN weights were checkpointed. The log ratio
    is now bounded, so such a batch gives a finite loss; and an update whose loss or gradient is still not finite
    raises, naming ``algorithm.lr``, before the optimizer touches the weights."""
    cfg, loss, gae, data = _collected(tmp_path)
    with torch.no_grad():
        gae(data)
    far = data.clone()
    far["agents", "action_log_prob"] = far["agents", "action_log_prob"] - 5e3  # the old policy: far less likely
    adv = far["agents", "advantage"]
    far["agents", "advantage"] = -adv.abs() - 1.0  # negative: the unclipped, exploding branch of the objective
    out = loss(far.reshape(-1))
    assert torch.isfinite(out["loss_objective"]) and float(out["loss_objective"]) > 0
    optimizer = torch.optim.Adam(list(loss.parameters()), lr=1e-3)
    algo = dataclasses.replace(cfg.algorithm, normalize_advantage=False, epochs=1)
    before = [p.detach().clone() for p in loss.parameters()]
    nan = data.clone()
    nan["agents", "action_log_prob"] = torch.full_like(nan["agents", "action_log_prob"], float("nan"))
    with pytest.raises(ConfigError, match=r"key 'algorithm.lr': the PPO update diverged at learning rate 0.001"):
        update(nan, loss, gae, optimizer, algo)
    assert all(torch.equal(a, b) for a, b in zip(before, loss.parameters(), strict=True))  # untouched


def test_a_batch_with_a_non_finite_reward_is_refused_naming_it(tmp_path):
    """A NaN reward (a diverged simulation) reached GAE and the loss, and the update then failed as "the PPO update
    diverged at learning rate ...", naming algorithm.lr; the batch itself is now refused, before any step."""
    cfg, loss, gae, data = _collected(tmp_path)
    optimizer = torch.optim.Adam(list(loss.parameters()), lr=1e-3)
    before = [p.detach().clone() for p in loss.parameters()]
    bad = data.clone()
    r = bad["next", "agents", "reward"].clone()
    r[1, 1] = float("nan")
    r[3, 0] = float("inf")
    bad["next", "agents", "reward"] = r
    n = data.batch_size.numel()
    with pytest.raises(ModelError, match=rf"^2 of {n} env steps of the batch have a non-finite reward \(episodes "
                       r"\[1, 3\]\): a simulation gave non-finite metrics"):  # fmt: skip
        update(bad, loss, gae, optimizer, cfg.algorithm)
    assert all(torch.equal(a, b) for a, b in zip(before, loss.parameters(), strict=True))  # untouched


def test_checkpoint_is_atomic(tmp_path):
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, {"a": torch.arange(3)})
    with pytest.raises(Exception):  # noqa: B017 -- pickling a lambda fails inside torch.save
        save_checkpoint(path, {"a": lambda: 0})
    assert torch.equal(load_checkpoint(path)["a"], torch.arange(3))  # old checkpoint intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]  # no temp file left
    (tmp_path / "torn.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path / "torn.pt")
    with pytest.raises(ConfigError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")


def test_a_damaged_checkpoint_is_said_to_be_so_in_words(tmp_path):
    """An empty checkpoint.pt (a crash before its data reached the disk, a copy that failed) read 'cannot read
    checkpoint <file>: ' with nothing after the colon; one cut short '[Errno 22] Invalid argument' or torch's 'failed
    finding central directory. This is an internal miniz error. If you are seeing this error, there is...'; a text
    file (checkpoint=log.csv) got torch's advice to load it with weights_only=False. Now what is wrong, in words,
    and no torch internals or advice."""
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, {"a": torch.zeros(1000), "iteration": 3})
    whole = path.read_bytes()
    for data, said in ((b"", "the file is empty"),
                       (b"iteration,reward\n1,2\n", "not a checkpoint: it does not begin as torch.save's files do"),
                       (b"\x80\x02junk", "not a checkpoint: it does not begin as torch.save's files do"),
                       (whole[: len(whole) // 2], "damaged, cut short or overwritten"),
                       (whole[:-30], "damaged, cut short or overwritten"),
                       (whole[:100] + b"\0" * 200 + whole[300:], "damaged, cut short or overwritten")):  # fmt: skip
        path.write_bytes(data)
        with pytest.raises(ConfigError, match=rf"cannot read checkpoint {path}: {said}") as e:
            load_checkpoint(path)
        assert not any(w in str(e.value) for w in ("miniz", "Errno", "weights_only"))


def test_a_checkpoint_write_that_fails_names_the_checkpoint(tmp_path, monkeypatch):
    """A full disk (or a folder that takes no new file) at a checkpoint's write raised '[Errno 28] No space left on
    device' naming no file, or naming the temporary '.checkpoint.pt.<hex>.tmp'; now the checkpoint, as
    atomic_output names the output it writes, and the old checkpoint stays."""
    import errno
    import os

    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, {"a": torch.arange(3)})

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match=rf"cannot write {path}: No space left on device") as e:
        save_checkpoint(path, {"a": torch.arange(4)})
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(path)
    monkeypatch.undo()
    real_open = os.open

    def denied(name, *args, **kwargs):
        if os.fspath(name).endswith(".tmp"):
            raise PermissionError(errno.EACCES, "Permission denied", os.fspath(name))
        return real_open(name, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    with pytest.raises(PermissionError, match=rf"cannot write {path}: Permission denied") as e:
        save_checkpoint(path, {"a": torch.arange(4)})
    assert e.value.filename == str(path)
    monkeypatch.undo()
    assert torch.equal(load_checkpoint(path)["a"], torch.arange(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_reading_a_checkpoint_runs_no_code_it_holds(tmp_path):
    """``train/evaluate.py checkpoint=<file>`` and the amortized comparison read a checkpoint named by the user with
    ``torch.load(weights_only=False)``: a file from elsewhere ran any code its pickle named. Checkpoints hold only
    tensors and plain data, which torch's weights-only reader takes; anything else is refused, naming the file."""
    marker = tmp_path / "ran"
    torch.save({"policy": _RunsCode(str(marker))}, tmp_path / "foreign.pt")
    with pytest.raises(ConfigError, match=r"cannot read checkpoint .*foreign\.pt") as e:
        load_checkpoint(tmp_path / "foreign.pt", key="checkpoint")
    assert e.value.key == "checkpoint"
    assert not marker.exists()
    state = {"policy": {"w": torch.ones(2)}, "rng": {"env": {"state": {"state": 2**100, "inc": 3}}}, "it": 4,
             "config": {"hidden": [16, 16], "name": "x", "t": None, "lr": 1e-3}}  # fmt: skip
    save_checkpoint(tmp_path / "ok.pt", state)
    back = load_checkpoint(tmp_path / "ok.pt")
    assert torch.equal(back["policy"]["w"], torch.ones(2)) and back["rng"] == state["rng"]
    assert back["config"] == state["config"]


class _RunsCode:
    """An object whose unpickling runs code (here: creates a file)."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permission bits")
def test_a_checkpoint_is_as_readable_as_the_other_files_of_its_run(tmp_path, umask):
    """tempfile.mkstemp made every checkpoint 0o600 whatever the umask: on a shared machine the run's summary and
    plots could be read by the group, its checkpoints not, so nobody else could evaluate them."""
    umask(0o022)
    save_checkpoint(tmp_path / "checkpoint.pt", {"a": 1})
    save_checkpoint(tmp_path / "checkpoint.pt", {"a": 2})  # replaced: the new file's mode
    (tmp_path / "summary.json").write_text("{}")
    umask(0o077)
    save_checkpoint(tmp_path / "private.pt", {"a": 3})
    assert stat.S_IMODE((tmp_path / "checkpoint.pt").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "summary.json").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "private.pt").stat().st_mode) == 0o600  # the umask still decides
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt", "private.pt", "summary.json"]


def test_rng_snapshot_round_trip_and_cuda_generators():
    from marlcrash.calibrate.checkpoint import restore_rng, rng_state

    env_rng = np.random.default_rng(5)
    snap = rng_state(env_rng)
    a, b = torch.rand(3), env_rng.random(3)
    restore_rng(snap, env_rng)
    assert torch.equal(torch.rand(3), a) and np.array_equal(env_rng.random(3), b)
    if torch.cuda.is_available():
        pytest.skip("a GPU is present: the refusal below is for machines without one")
    assert "cuda" not in snap  # CUDA generators only where CUDA is in use
    with pytest.raises(ConfigError, match="no CUDA device") as e:
        restore_rng({**snap, "cuda": [torch.zeros(8, dtype=torch.uint8)] * 2}, env_rng)
    assert e.value.key == "resume"


def test_csv_logger_truncates_to_a_checkpoint(tmp_path):
    log = CSVLogger(tmp_path)
    for i in range(5):
        log.log({"iteration": float(i + 1), "x": i * 0.1})
    assert log.position == 5
    again = CSVLogger(tmp_path)
    assert again.position == 5
    again.truncate(3)
    rows = read_log(tmp_path / "log.csv")
    assert [r["iteration"] for r in rows] == [1.0, 2.0, 3.0]
    assert rows[2]["x"] == 0.2  # repr round trip: the float written is the float read
    with pytest.raises(ValueError, match="differ from the columns"):
        again.log({"iteration": 4.0})
    with pytest.warns(UserWarning, match=r"holds 3 rows, the checkpoint counts 5: the log of iterations 4-5 is lost"):
        again.truncate(5)  # a log cut short since the checkpoint: said, not hidden
    assert again.position == 3 and len(read_log(tmp_path / "log.csv")) == 3
    (tmp_path / "log.csv").unlink()
    with pytest.warns(UserWarning, match=r"log\.csv is missing, the checkpoint counts 5: the log of iterations 1-5"):
        again.truncate(5)
    assert again.position == 0


def test_csv_logger_writes_counts_as_integers(tmp_path):
    """Iteration, env step and simulation counts read as integers in pandas or a text editor ("3", not "3.0")."""
    import numpy as np

    log = CSVLogger(tmp_path)
    log.log({"iteration": 3, "env_steps": np.int64(288), "x": 0.25, "y": float("nan")})
    assert (tmp_path / "log.csv").read_text().splitlines()[1] == "3,288,0.25,nan"
    assert read_log(tmp_path / "log.csv") == [
        {"iteration": 3.0, "env_steps": 288.0, "x": 0.25, "y": pytest.approx(float("nan"), nan_ok=True)}
    ]


def test_a_torn_row_after_the_checkpoint_is_cut_and_a_malformed_row_before_it_is_named(tmp_path):
    """A kill while a row is written leaves it torn (no newline, fields missing, junk bytes): a resume cuts it
    unread. A malformed row that a resume keeps, or that an evaluation reads, is an error naming the file and
    line, not a float() traceback."""
    log = CSVLogger(tmp_path)
    for i in range(3):
        log.log({"iteration": float(i + 1), "x": i * 0.1})
    path = tmp_path / "log.csv"
    good = path.read_bytes()
    path.write_bytes(good + b"4.0,0.3\r\n5.0")  # row 4 written, then a kill in the middle of row 5
    assert [r["iteration"] for r in read_log(path, rows=3)] == [1.0, 2.0, 3.0]  # the rows a checkpoint counts
    with pytest.raises(ConfigError, match=r"log\.csv: line 6: expected 2 values.*got 1 \(a row cut short") as e:
        read_log(path)
    assert e.value.path == str(path)
    again = CSVLogger(tmp_path)
    again.truncate(3)  # the checkpoint's position: the rows after it are dropped, the torn one too
    assert path.read_bytes() == good and again.position == 3
    again.log({"iteration": 4.0, "x": 9.0})
    assert [r["x"] for r in read_log(path)] == [0.0, 0.1, 0.2, 9.0]

    path.write_bytes(good + b"\xff\x00garbage")  # junk after the checkpoint's rows, not even text
    CSVLogger(tmp_path).truncate(3)
    assert path.read_bytes() == good

    lines = good.decode().splitlines(keepends=True)
    path.write_text(lines[0] + lines[1] + "3.0,0.2,7\r\n" + lines[3])  # a row the checkpoint counts is malformed
    with pytest.raises(ConfigError, match=r"log\.csv: line 3: expected 2 values, one per column of line 1, got 3"):
        read_log(path)
    with pytest.raises(ConfigError, match=r"log\.csv: line 3"):
        CSVLogger(tmp_path).truncate(3)
    path.write_text(lines[0] + lines[1] + "garbage,,\r\n" + lines[3])
    with pytest.raises(ConfigError, match=r"log\.csv: line 3: expected a number in column 'iteration', got 'garbage'"):
        CSVLogger(tmp_path).truncate(2)
    assert read_log(path, rows=1) == [{"iteration": 1.0, "x": 0.0}]
    with pytest.raises(ConfigError, match=r"log\.csv: line 1: no column 'reward_mean'"):
        read_log(path, rows=1, columns=("iteration", "reward_mean"))


def _comparable_log(run: Path) -> list[dict]:
    drop = ("wall_time_s", "env_steps_per_s")
    return [{k: v for k, v in r.items() if k not in drop} for r in read_log(run / "log.csv")]


def test_resume_reaches_the_same_result_as_a_straight_run(short, tmp_path):
    straight = train(tiny(tmp_path, name="straight"))
    torch.manual_seed(123)  # a resumed process starts with other global RNG state
    part = train(tiny(tmp_path, name="killed"), stop_at=2, evaluate=False)
    assert part.iterations == 2 and part.summary is None
    with open(part.run_dir / "log.csv", "a") as fh:  # a row logged after the checkpoint, before the "kill"
        fh.write(",".join(["9"] * len(read_log(part.run_dir / "log.csv")[0])) + "\n")
        fh.write("9,9")  # and a row torn by the kill: cut unread, as the row before it
    resumed = train(tiny(tmp_path, name="killed", resume=str(part.run_dir)))
    assert resumed.iterations == straight.iterations == 4
    assert resumed.env_steps == straight.env_steps and resumed.simulations == straight.simulations
    a, b = straight.summary, resumed.summary
    assert a["final_metrics"] == b["final_metrics"]
    assert a["selected_iteration"] == b["selected_iteration"]
    assert a["param_error"] == b["param_error"]
    pa, pb = np.load(straight.run_dir / "calibrated.npz"), np.load(resumed.run_dir / "calibrated.npz")
    np.testing.assert_array_equal(pa["per_iteration"], pb["per_iteration"])
    assert _comparable_log(straight.run_dir) == _comparable_log(resumed.run_dir)
    sa = load_checkpoint(straight.run_dir / "checkpoint.pt")["policy"]
    sb = load_checkpoint(resumed.run_dir / "checkpoint.pt")["policy"]
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


def test_resuming_a_finished_run_evaluates_without_training_further(short, tmp_path):
    """A run that the time limit stopped is finished: resume=true re-evaluates it, the same numbers (more time given
    with it is said to change nothing)."""
    done = train(tiny(tmp_path, name="limited", time_limit_s=1e-6))  # stops after its first iteration
    assert done.iterations == 1
    state = load_checkpoint(done.run_dir / "checkpoint.pt")
    state["wall_time_s"] = state["last_iteration_s"] = 0.0  # no clock could stop it now: only "finished" does
    save_checkpoint(done.run_dir / "checkpoint.pt", state)
    update_summary(done.run_dir, process_wall_time_s=12.5)  # as train/train.py stamps it
    ckpt = (done.run_dir / "checkpoint.pt").read_bytes()
    with pytest.warns(UserWarning, match=r"is finished: a resume evaluates it again.*time_limit_s=100.0"):
        again = train(tiny(tmp_path, name="limited", resume=True, time_limit_s=100.0), given=["time_limit_s"])
    assert again.iterations == 1 and again.simulations == done.simulations
    assert again.summary["final_metrics"] == done.summary["final_metrics"]
    assert len(read_log(done.run_dir / "log.csv")) == 1
    assert (done.run_dir / "checkpoint.pt").read_bytes() == ckpt  # the finished run's record is not rewritten
    assert json.loads((done.run_dir / "summary.json").read_text())["process_wall_time_s"] == 12.5


def test_the_time_limit_clock_is_the_runs_own_and_survives_a_kill(short, tmp_path):
    """A run killed at iteration 2 with 999.5 of its 1000 s of training time spent stops at once when
    resumed, as the uninterrupted run would have: the clock is the checkpointed training time, not the
    new process's."""
    part = train(tiny(tmp_path, name="clock", time_limit_s=1000.0), stop_at=2, evaluate=False)
    state = load_checkpoint(part.run_dir / "checkpoint.pt")
    state["wall_time_s"], state["last_iteration_s"] = 999.5, 1.0
    save_checkpoint(part.run_dir / "checkpoint.pt", state)
    resumed = train(tiny(tmp_path, name="clock", resume=str(part.run_dir)))
    assert resumed.iterations == 2
    assert resumed.summary is not None


def test_a_resume_takes_the_given_free_settings_and_refuses_the_others_naming_them(short, tmp_path):
    """A resume trained on with the run's config.yaml whatever the command line gave: ``time_limit_s=5000`` (a
    killed run given more time) was dropped, and so was ``algorithm.lr=1e-4``, the run going on with its own lr.
    The settings a resume may change (``RESUME_FREE_KEYS``) now take effect and are recorded in config.yaml; any
    other given setting must be the run's, else the resume is refused naming it and both values."""
    part = train(tiny(tmp_path, name="more", time_limit_s=1000.0), stop_at=2, evaluate=False)
    state = load_checkpoint(part.run_dir / "checkpoint.pt")
    state["wall_time_s"], state["last_iteration_s"] = 999.5, 1.0  # the run's 1000 s are spent
    save_checkpoint(part.run_dir / "checkpoint.pt", state)
    ckpt = (part.run_dir / "checkpoint.pt").read_bytes()
    for key, given, saved in (("algorithm.lr", 1e-4, 1e-3), ("seed", 5, 0), ("iterations", 9, 4), ("n_envs", 8, 4)):
        with pytest.raises(ConfigError, match=rf"the run has {key} = {saved!r}, the command line gives {given!r}") as e:
            train(tiny(tmp_path, name="more", resume=True, **{key: given}), given=[key])
        assert e.value.key == key
        assert (part.run_dir / "checkpoint.pt").read_bytes() == ckpt  # refused before any training
    # a run moved from a machine with a GPU this one lacks: its device is refused, unless the resume names another
    yaml_path = part.run_dir / "config.yaml"
    yaml_path.write_text(yaml_path.read_text().replace("device: cpu", "device: cuda:99"))
    with pytest.raises(ConfigError, match=r"key 'device': device 'cuda:99' is not available here"):
        train(tiny(tmp_path, name="more", resume=True, time_limit_s=5000.0), given=["time_limit_s"])
    # a given setting equal to the run's is no change; the free ones are taken, and kept for the next resume
    resumed = train(tiny(tmp_path, name="more", resume=True, time_limit_s=5000.0, checkpoint_every=2,
                         **{"eval.plots": True}), evaluate=False,
                    given=["time_limit_s", "seed", "checkpoint_every", "eval.plots", "device"])  # fmt: skip
    assert resumed.iterations == 4  # trained on: with the run's own 1000 s it stopped at once (iteration 2)
    saved_config = load_run_config(part.run_dir)
    assert (saved_config.time_limit_s, saved_config.checkpoint_every, saved_config.eval.plots) == (5000.0, 2, True)
    assert saved_config.device == "cpu"
    assert (saved_config.algorithm.lr, saved_config.seed) == (1e-3, 0)


def test_resume_true_finds_the_run_and_fresh_runs_refuse_to_overwrite(short, tmp_path):
    part = train(tiny(tmp_path, name="r1", iterations=2), stop_at=1, evaluate=False)
    with pytest.raises(ConfigError, match="exists already"):
        train(tiny(tmp_path, name="r1", iterations=2))
    done = train(tiny(tmp_path, name="other", iterations=2, resume=True), evaluate=False)
    assert done.run_dir == part.run_dir and done.iterations == 2
    with pytest.raises(ConfigError, match=r"no run with checkpoint\.pt"):
        train(tiny(tmp_path / "empty", resume=True))
    # a named run without a checkpoint (killed before its first one) is not swapped for the newest run
    (part.run_dir.parent / "killed_early").mkdir()
    with pytest.raises(ConfigError, match=r"expected a run folder with checkpoint\.pt, found none in .*killed_early"):
        train(tiny(tmp_path, name="killed_early", resume=True))
    (part.run_dir.parent / "killed_early" / "config.yaml").write_text("{}\n")  # a run that had started: how to go on
    for resume in (True, str(part.run_dir.parent / "killed_early")):  # named, or given as a path (train.py name=)
        with pytest.raises(ConfigError, match=r"has no checkpoint\.pt \(the run stopped before its first") as e:
            train(tiny(tmp_path, name="killed_early", resume=resume))
        assert e.value.key == "resume"
    with pytest.raises(ConfigError, match=r"delete it \(it has no checkpoint\)"):
        train(tiny(tmp_path, name="killed_early"))


def test_resuming_a_checkpoint_of_other_networks_names_the_file(short, tmp_path):
    """config.yaml edited to other layer widths (or a checkpoint copied from another run): the resume failed deep
    inside tensordict ("Failed to update '0' in tensordict"); now the error names the file and the mismatch, as the
    evaluation's does, and leaves the run as it was."""
    part = train(tiny(tmp_path, name="edited", iterations=2), stop_at=1, evaluate=False)
    cfg = part.run_dir / "config.yaml"
    cfg.write_text(cfg.read_text().replace("  - 16\n", "  - 32\n"))
    ckpt, log = (part.run_dir / "checkpoint.pt").read_bytes(), (part.run_dir / "log.csv").read_text()
    with pytest.raises(ConfigError, match=r"checkpoint\.pt does not fit this run's mappo policy: .* has shape") as e:
        train(tiny(tmp_path, name="edited", resume=str(part.run_dir)))
    assert e.value.key == "resume"
    assert (part.run_dir / "checkpoint.pt").read_bytes() == ckpt and (part.run_dir / "log.csv").read_text() == log
    cfg.write_text(cfg.read_text().replace("  - 32\n", "  - 16\n"))
    state = load_checkpoint(part.run_dir / "checkpoint.pt")
    state["critic"] = {k: v[..., :1] for k, v in state["critic"].items()}  # would broadcast into place
    save_checkpoint(part.run_dir / "checkpoint.pt", state)
    with pytest.raises(ConfigError, match=r"does not fit this run's mappo critic"):
        train(tiny(tmp_path, name="edited", resume=str(part.run_dir)))


def test_resuming_the_checkpoint_of_a_run_with_other_settings_names_the_setting(short, tmp_path):
    """A checkpoint.pt copied from another run whose networks have the same shapes (another n_envs, seed, learning
    rate, env override) was resumed without a word: its weights, optimizer, generators, counters and log position
    went on under this run's config.yaml, a run neither of the two configs describes. The checkpoint holds the config
    it was written under; a setting that differs is named. Where the run folder is (name, out_dir: a moved or
    renamed folder), what only shows or keeps the numbers (progress bar, logger, checkpoint intervals, plots), the
    time limit (a killed run given more time) and where it runs (threads, device) may differ."""
    part = train(tiny(tmp_path, name="mine", iterations=2), stop_at=1, evaluate=False)
    ckpt = part.run_dir / "checkpoint.pt"
    mine, log = load_checkpoint(ckpt), (part.run_dir / "log.csv").read_text()
    for key, value in (("n_envs", 8), ("algorithm.lr", 0.5), ("env_overrides", {"max_step": 0.2}),
                       ("eval.thresholds.area", 1.0)):  # fmt: skip
        other = copy.deepcopy(mine)
        node, parts = other["config"], key.split(".")
        for p in parts[:-1]:
            node = node[p]
        saved = node[parts[-1]]
        node[parts[-1]] = value
        save_checkpoint(ckpt, other)
        with pytest.raises(ConfigError, match=rf"checkpoint\.pt was written by a run with other settings: {key} "
                           rf"is {value!r} in it, {saved!r} in .*config\.yaml") as e:  # fmt: skip
            train(tiny(tmp_path, name="mine", resume=str(part.run_dir)), evaluate=False)
        assert e.value.key == "resume" and (part.run_dir / "log.csv").read_text() == log
    moved = copy.deepcopy(mine)
    moved["config"].update(
        name="old_name",
        out_dir="elsewhere",
        progress_bar=True,
        snapshot_every=5,
        time_limit_s=1.0,
        threads=1,
        device="cuda",
    )  # more time, another machine
    moved["config"]["eval"]["plots"] = True
    save_checkpoint(ckpt, moved)
    assert train(tiny(tmp_path, name="mine", resume=str(part.run_dir)), stop_at=1, evaluate=False).iterations == 1
    save_checkpoint(ckpt, mine)


def test_evaluating_the_checkpoint_of_a_run_with_other_settings_names_the_setting(short, tmp_path):
    """``evaluate_run(run, checkpoint=<a file of another run>)`` checked the network shapes only: a checkpoint of a
    run with other settings and the same shapes was evaluated as this run's, its numbers reported under this run's
    config. It is refused as a resume refuses it, naming the setting and this run's config.yaml; a copy of this
    run's own checkpoint, and a re-evaluation with other ``iterations``, still evaluate."""
    from marlcrash.calibrate.evaluate import evaluate_run

    part = train(tiny(tmp_path, name="mine", iterations=1), evaluate=False)
    mine = load_checkpoint(part.run_dir / "checkpoint.pt")
    other = copy.deepcopy(mine)
    other["config"]["algorithm"]["lr"] = 0.5
    foreign = tmp_path / "foreign.pt"
    save_checkpoint(foreign, other)
    with pytest.raises(ConfigError, match=r"foreign\.pt was written by a run with other settings: algorithm\.lr is "
                       r"0\.5 in it, 0\.001 in .*mine/config\.yaml") as e:  # fmt: skip
        evaluate_run(part.run_dir, checkpoint=str(foreign))
    assert e.value.key == "checkpoint" and not (part.run_dir / "eval").exists()
    save_checkpoint(foreign, mine)
    assert evaluate_run(part.run_dir, checkpoint=str(foreign), iterations=1)["eval_iterations"] == 1


def test_resuming_a_run_whose_log_has_other_columns_is_refused_before_training(short, tmp_path, monkeypatch):
    """A run started by a version that logged other columns: the resume trained a whole iteration, then failed with a
    bare ValueError from the logger (and did so again on every resume). It is refused before any training, naming
    log.csv and the columns that differ; the log is left as it was."""
    import marlcrash.calibrate.marl as marl

    part = train(tiny(tmp_path, name="older", iterations=2), stop_at=1, evaluate=False)
    path = part.run_dir / "log.csv"
    lines = path.read_text().splitlines(keepends=True)
    header = lines[0].rstrip("\r\n").split(",")
    assert header == list(marl.LOG_ROW_COLUMNS)
    old = [c for c in header if c != "grad_norm"] + ["old_stat"]  # one column gone, one added since
    rows = [",".join([*line.rstrip("\r\n").split(",")[:-1], "1.0"]) + "\n" for line in lines[1:]]
    path.write_text(",".join(old) + "\n" + "".join(rows))
    log = path.read_text()

    def trained(tr):
        raise AssertionError("a resume that cannot log trained an iteration")

    monkeypatch.setattr(marl, "train_iteration", trained)
    differ = r"columns of .*older/log\.csv differ.*not written now: 'old_stat'; columns missing: 'grad_norm'"
    with pytest.raises(ConfigError, match=differ) as e:
        train(tiny(tmp_path, name="older", resume=str(part.run_dir)), evaluate=False)
    assert e.value.key == "resume" and e.value.path == str(path)
    assert path.read_text() == log
    state = load_checkpoint(part.run_dir / "checkpoint.pt")
    state["finished"] = True  # a finished run's resume only evaluates it again: it appends no row, and is not refused
    save_checkpoint(part.run_dir / "checkpoint.pt", state)
    assert train(tiny(tmp_path, name="older", resume=str(part.run_dir)), evaluate=False).iterations == 1


def test_a_fresh_run_interrupted_before_its_first_checkpoint_leaves_no_folder(short, tmp_path, monkeypatch):
    import marlcrash.calibrate.marl as marl

    def interrupted(tr):
        raise KeyboardInterrupt

    with monkeypatch.context() as m, pytest.raises(KeyboardInterrupt) as e:  # undo() would drop `short`'s configs too
        m.setattr(marl, "train_iteration", interrupted)
        train(tiny(tmp_path, name="ctrl_c", iterations=2))
    assert not any((tmp_path / "runs").rglob("ctrl_c"))
    run_dir = tmp_path / "runs" / "mappo" / "ctrl_c"
    assert e.value.__notes__ == [f"{run_dir} was removed (no checkpoint yet): the same command starts the run again"]
    assert train(tiny(tmp_path, name="ctrl_c", iterations=1), evaluate=False).iterations == 1


def test_an_interrupted_run_says_which_iteration_its_folder_keeps_and_how_to_continue_it(short, tmp_path, monkeypatch):
    """Ctrl-C ended train/train.py with a traceback and no word of what was kept: the interrupt now carries a note
    (printed by the scripts, train/ entry.run_script) naming the folder, the iteration its checkpoint holds and the
    ``resume=`` that continues it; that resume does, to the iteration cap. Ctrl-C during the evaluation of a finished
    run says that the training is finished and its evaluation was interrupted."""
    import marlcrash.calibrate.marl as marl

    real = marl.train_iteration

    def third_interrupted(tr):
        if tr.iteration == 2:
            raise KeyboardInterrupt
        return real(tr)

    with monkeypatch.context() as m, pytest.raises(KeyboardInterrupt) as e:
        m.setattr(marl, "train_iteration", third_interrupted)
        train(tiny(tmp_path, name="ctrl_c", iterations=4, checkpoint_every=2, snapshot_every=0))
    run_dir = tmp_path / "runs" / "mappo" / "ctrl_c"
    note = f"{run_dir} keeps the run (checkpoint.pt: training at iteration 2 of 4); resume={run_dir} continues it"
    assert e.value.__notes__ == [note]
    resume = note.rsplit("resume=", 1)[1].split(" ", 1)[0]
    assert train(tiny(tmp_path, resume=resume), evaluate=False).iterations == 4

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("marlcrash.calibrate.evaluate.evaluate_run", interrupted)
    with pytest.raises(KeyboardInterrupt) as e:
        train(tiny(tmp_path, resume=str(run_dir)))
    assert e.value.__notes__ == [f"{run_dir} keeps the run (checkpoint.pt: finished training; its evaluation was "
                                 f"interrupted); resume={run_dir} continues it"]  # fmt: skip


def test_a_fresh_run_stopped_while_it_starts_leaves_no_folder(short, tmp_path, monkeypatch):
    """Ctrl-C while a fresh run builds its env (discretizing a deck takes seconds: when a wrong option is noticed),
    or a start-up file that cannot be written (config.yaml, provenance.json: a full disk), left the folder with
    config.yaml and no checkpoint, and the same command was refused ('exists already; ... delete it')."""
    import marlcrash.calibrate.marl as marl

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    for target, name, stop, caught in ((marl, "build_trainer", interrupted, KeyboardInterrupt),
                                       (marl.provenance, "write_record", full, OSError),
                                       (marl, "save_run_config", full, OSError)):  # fmt: skip
        with monkeypatch.context() as m:
            m.setattr(target, name, stop)
            with pytest.raises(caught):
                train(tiny(tmp_path, name="stopped", iterations=1))
        assert not any((tmp_path / "runs").rglob("*")), name  # nor the <out_dir>/<algorithm>/ it made


def test_a_run_that_cannot_start_leaves_no_folder(short, tmp_path):
    """An env override the env config refuses fails when the config is loaded; one set after that fails while
    building, before training, and leaves no folder; the same name works after."""
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, name="bad", env_overrides={"max_step": -1})
    assert e.value.key == "env_overrides.max_step"
    cfg = tiny(tmp_path, name="bad")
    cfg.env_overrides = {"max_step": -1}
    with pytest.raises(ConfigError) as e:
        train(cfg)
    assert e.value.key == "env_overrides.max_step"
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").rglob("bad"))
    assert train(tiny(tmp_path, name="bad", iterations=1), evaluate=False).iterations == 1


def test_summary_and_evaluation_of_a_checkpoint(short, tmp_path):
    from marlcrash.calibrate.evaluate import evaluate_run

    res = train(tiny(tmp_path, "ippo", iterations=2, **{"eval.plots": True}))
    s = json.loads((res.run_dir / "summary.json").read_text())
    assert s == res.summary
    sensors = list(s["final_metrics"])
    assert sensors and set(s["initial_metrics"]) == set(sensors)
    for v in (*s["final_metrics"].values(), *s["initial_metrics"].values()):
        assert set(v) == {"area", "dfd", "rmse"} and all(np.isfinite(x) and x >= 0 for x in v.values())
    assert s["env_steps"] == 2 * 4 * 2 and s["simulations"] >= s["env_steps"] + 2 * 4
    assert s["wall_time_s"] > 0 and s["param_error"]
    for errs in s["param_error"].values():
        assert set(errs) == {"E_x", "E_s", "transmission"}
    # the reported iterate is the best by score, never worse than the initial parameters
    rows = [r for r in _read_csv(res.run_dir / "eval_metrics.csv") if r["sensor"] == "mean"]
    scores = [float(r["score"]) for r in rows]
    assert s["selected_iteration"] == int(np.argmax(scores))
    assert "| A |" in (res.run_dir / "eval_metrics.md").read_text()
    for f in ("pulses.png", "learning_curves.png", "calibrated.npz"):
        assert (res.run_dir / f).stat().st_size > 0
    log = res.run_dir / "log.csv"
    good = log.read_text()
    log.write_text(good + "3.0,48")  # a row torn by a kill after the checkpoint: not the checkpoint's, not read
    again = evaluate_run(res.run_dir)  # from the checkpoint alone: same deterministic numbers
    assert again["final_metrics"] == s["final_metrics"]
    lines = good.splitlines(keepends=True)
    log.write_text(lines[0] + "garbage" + lines[1][lines[1].index(",") :] + lines[2])  # a row the evaluation reads
    with pytest.raises(ConfigError, match=r"log\.csv: line 2: expected a number in column 'iteration', got 'garbage'"):
        evaluate_run(res.run_dir)


def test_a_run_trained_on_a_gpu_is_evaluated_on_a_machine_without_one(short, tmp_path, monkeypatch):
    """The evaluation runs the policy on the CPU: a run folder whose config.yaml says ``device: cuda`` (trained on a
    GPU, copied to a machine without one) was refused by the check a resume needs ("device 'cuda' is not available
    here"), so its checkpoints could not be evaluated at all."""
    from marlcrash.calibrate.evaluate import evaluate_run

    res = train(tiny(tmp_path, name="gpu", iterations=1, **{"eval.iterations": 1}))
    cfg = res.run_dir / "config.yaml"
    cfg.write_text(cfg.read_text().replace("device: cpu\n", "device: cuda\n"))
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)  # no GPU here, whatever the test machine has
    s = evaluate_run(res.run_dir)
    assert s["eval_dir"] == str(res.run_dir) and s["final_metrics"] == res.summary["final_metrics"]
    from marlcrash.analysis.contributions import run_calibration
    from marlcrash.calibrate.amortized import load_policy

    assert load_policy(res.run_dir)[1].device == "cpu"  # the amortized comparison's policy
    assert run_calibration(res.run_dir).calibrated.shape[1] == 7  # marlcrash contributions
    with pytest.raises(ConfigError) as e:  # a resume trains on the saved device: still refused before anything
        train(tiny(tmp_path, name="gpu", resume=str(res.run_dir)))
    assert e.value.key == "device"


def test_the_evaluation_keeps_its_results_when_a_picture_or_a_table_cannot_be_written(short, tmp_path, monkeypatch):
    """The evaluation drew pulses.png and learning_curves.png before writing summary.json: a plotting failure (a
    matplotlib error, a full disk) after the training and the evaluation's simulations left no summary.json, and a
    picture or table cut short by the failure stayed as its file (eval_metrics.csv/.md and the pictures were written
    in place, not atomically). Now a picture that cannot be drawn is a warning naming it, and every file is written
    whole or not at all."""
    import csv

    import marlcrash.calibrate.evaluate as evaluate

    def broken(*args, **kwargs):
        raise RuntimeError("matplotlib failed")

    with (
        monkeypatch.context() as m,
        pytest.warns(UserWarning, match=r"pulses\.png was not drawn: RuntimeError: matplotlib failed; the results are"),
    ):
        m.setattr(evaluate, "plot_pulses", broken)
        res = train(tiny(tmp_path, name="plots", iterations=1, **{"eval.plots": True, "eval.iterations": 1}))
    assert json.loads((res.run_dir / "summary.json").read_text()) == res.summary
    assert (res.run_dir / "learning_curves.png").stat().st_size > 0 and not (res.run_dir / "pulses.png").exists()
    tables = {f: (res.run_dir / f).read_bytes() for f in ("eval_metrics.csv", "eval_metrics.md")}
    real = csv.DictWriter.writerows

    def full(self, rows):  # the disk fills while the table is written
        real(self, rows[:1])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(csv.DictWriter, "writerows", full)
    with pytest.raises(OSError, match=r"eval_metrics\.csv: No space left on device"):
        evaluate.evaluate_run(res.run_dir)
    assert {f: (res.run_dir / f).read_bytes() for f in tables} == tables  # the earlier tables, whole
    assert not [p.name for p in res.run_dir.iterdir() if p.name.endswith(".tmp") or ".tmp." in p.name]


def test_an_earlier_evaluations_pictures_do_not_stay_beside_new_results(short, tmp_path, monkeypatch):
    """A resume with eval.plots=false rewrote summary.json and left the earlier evaluation's pulses.png and
    learning_curves.png (of the policy of iteration 1) beside it; a picture that failed to draw left its old file
    the same way. Now both are removed."""
    import marlcrash.calibrate.evaluate as evaluate

    res = train(tiny(tmp_path, name="pics", iterations=1, **{"eval.plots": True, "eval.iterations": 1}))
    pics = [res.run_dir / "pulses.png", res.run_dir / "learning_curves.png"]
    assert all(p.stat().st_size > 0 for p in pics)

    def broken(*args, **kwargs):
        raise RuntimeError("matplotlib failed")

    with monkeypatch.context() as m, pytest.warns(UserWarning, match=r"pulses\.png was not drawn"):
        m.setattr(evaluate, "plot_pulses", broken)
        evaluate.evaluate_run(res.run_dir)
    assert not pics[0].exists() and pics[1].stat().st_size > 0
    more = train(tiny(tmp_path, name="pics", resume=True, **{"eval.plots": False}), given=["eval.plots"])
    assert more.summary["iterations_trained"] == 1 and (more.run_dir / "summary.json").is_file()
    assert not any(p.exists() for p in pics)


def test_evaluating_a_run_whose_folder_cannot_be_written_is_refused_before_the_work(short, tmp_path, monkeypatch):
    """A read-only run folder (an archived or a colleague's run): the evaluation made eval/<checkpoint>_steps<n>/
    (or, as root, went on), ran the policy and the baselines' problem, and only then failed to write its first file,
    leaving an empty folder; where the folder refused it, mkdir raised a bare PermissionError. Now the folder is
    checked first and named, with the key run."""
    import tempfile

    from marlcrash.calibrate.evaluate import evaluate_run

    res = train(tiny(tmp_path, name="archived", iterations=1), evaluate=False)
    before = sorted(p.relative_to(res.run_dir) for p in res.run_dir.rglob("*"))

    def denied(*args, **kwargs):  # a folder without write permission (root ignores chmod, so simulate it)
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "NamedTemporaryFile", denied)
    for kw in ({"iterations": 3}, {}):  # into eval/checkpoint_steps3/, and the run's own evaluation
        with pytest.raises(ConfigError, match=rf"cannot write in the folder {res.run_dir} \(Permission denied\)") as e:
            evaluate_run(res.run_dir, **kw)
        assert e.value.key == "run"
        assert sorted(p.relative_to(res.run_dir) for p in res.run_dir.rglob("*")) == before


def test_kept_snapshots_are_evaluated_beside_the_run_results(short, tmp_path):
    from marlcrash.calibrate.evaluate import evaluate_run

    res = train(
        tiny(tmp_path, iterations=3, snapshot_every=2, checkpoint_every=3)
    )  # a snapshot is due before a checkpoint
    kept = sorted(p.name for p in (res.run_dir / "checkpoints").iterdir())
    assert kept == ["iter_00002.pt"]
    final = (res.run_dir / "summary.json").read_text()
    from marlcrash.calibrate.runlock import run_lock

    with run_lock(res.run_dir, "name"):  # the run still trains (another process holds its folder)
        with pytest.raises(ConfigError, match="in use by another process") as e:  # its own results: refused
            evaluate_run(res.run_dir)
        assert e.value.key == "run" and (res.run_dir / "summary.json").read_text() == final
        early = evaluate_run(res.run_dir, checkpoint="2")  # a kept snapshot goes beside them: allowed meanwhile
    assert early["iterations_trained"] == 2 and early["env_steps"] == 2 * 4 * 2
    assert early["checkpoint"].endswith("iter_00002.pt")
    out = res.run_dir / "eval" / "iter_00002"
    assert json.loads((out / "summary.json").read_text()) == early
    assert (out / "calibrated.npz").is_file()
    assert (res.run_dir / "summary.json").read_text() == final  # the run's own results stay
    other = evaluate_run(res.run_dir, iterations=1)  # other settings: beside the run's results, never over them
    assert other["eval_dir"] == str(res.run_dir / "eval" / "checkpoint_steps1") and other["eval_iterations"] == 1
    assert json.loads((res.run_dir / "eval" / "checkpoint_steps1" / "summary.json").read_text()) == other
    assert (res.run_dir / "summary.json").read_text() == final
    latest = evaluate_run(res.run_dir, checkpoint="latest")
    assert latest["final_metrics"] == json.loads(final)["final_metrics"] and latest["iterations_trained"] == 3
    copies = []  # two checkpoint files of one name elsewhere: each its own folder, none over the run's
    for where in ("a", "b"):
        (tmp_path / where).mkdir()
        shutil.copy(res.run_dir / "checkpoints" / "iter_00002.pt", tmp_path / where / "checkpoint.pt")
        copies.append(evaluate_run(res.run_dir, checkpoint=str(tmp_path / where / "checkpoint.pt"), iterations=1))
    dirs = {Path(c["eval_dir"]) for c in copies}
    assert len(dirs) == 2 and all(d.parent == res.run_dir / "eval" and d.name.startswith("checkpoint_") for d in dirs)
    assert res.run_dir / "eval" / "checkpoint_steps1" not in dirs and all((d / "summary.json").is_file() for d in dirs)
    with pytest.raises(ConfigError, match=r"iter_00002\.pt") as e:
        evaluate_run(res.run_dir, checkpoint=5)
    assert e.value.key == "checkpoint"
    # another kind of checkpoint (a baseline's best.pt) or one of other networks: an error naming the file,
    # and no empty eval/<stem>/ folder left behind
    save_checkpoint(tmp_path / "best.pt", {"x": torch.zeros(3), "metrics": {}})
    with pytest.raises(ConfigError, match=r"best\.pt is not a training checkpoint \(no policy") as e:
        evaluate_run(res.run_dir, checkpoint=str(tmp_path / "best.pt"))
    assert e.value.key == "checkpoint" and not (res.run_dir / "eval" / "best").exists()
    state = load_checkpoint(res.run_dir / "checkpoint.pt")
    state["policy"] = {k: v[..., :1] for k, v in state["policy"].items()}
    save_checkpoint(res.run_dir / "narrow.pt", state)
    with pytest.raises(ConfigError, match=r"narrow\.pt does not fit this run's mappo policy") as e:
        evaluate_run(res.run_dir, checkpoint="narrow.pt")
    assert e.value.key == "checkpoint" and not (res.run_dir / "eval" / "narrow").exists()


def _read_csv(path: Path) -> list[dict]:
    import csv

    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_run_trained_against_measured_tests_is_evaluated_on_the_test_of_its_scenario(short, tmp_path):
    """Two tests of two load cases (the model's own simulations, written as CSV) as ``reference.files``: the
    run trains against both, and its evaluation calibrates against the test of ``eval.scenario`` (it used to
    swap in the twin): the initial parameters fit it exactly, the summary names it, and there are no parameter
    errors (a test has no known truth). ``eval.reference: twin`` still evaluates on the twin; a scenario that
    no test is of is refused before training starts."""
    from marlcrash.envs.core import build_cells
    from marlcrash.pulse.simulation import write_crash_csv
    from marlcrash.sim import Surrogate, get_scenario

    cells = build_cells("b_segment", None, "optimized")
    sim = Surrogate(cells)
    files = []
    for name in ("full_width_40", "offset40_left"):
        result = sim.run(torch.as_tensor(cells.params)[None], get_scenario(name), record_cells="none")
        path = write_crash_csv(result, tmp_path / f"{name}.csv")
        channels = {s: f"{s}_acc_g" for s in cells.sensor_names}
        files.append({"path": str(path), "scenario": name, "channels": channels, "weight": 1.0 + 8 * len(files)})
    over = {"reference.kind": "file", "reference.files": files}  # drawn by weight, the offset test is 9 in 10
    res = train(tiny(tmp_path, iterations=1, env_overrides=over, **{"eval.scenario": "full_width_40"}))
    s = res.summary
    assert s["reference"] == "file" and s["reference_source"] == files[0]["path"]
    assert "param_error" not in s
    assert max(v["area"] for v in s["initial_metrics"].values()) < 1e-6  # the 40 km/h test, not the twin or offset
    assert "full_width_40.csv" in (res.run_dir / "eval_metrics.md").read_text().splitlines()[0]

    one = {**over, "reference.file_scenario": "offset40_left"}  # trained on one test: the twin's evaluation drops it
    twin = train(tiny(tmp_path, iterations=1, name="twin", env_overrides=one, **{"eval.reference": "twin"}))
    assert twin.summary["reference"] == "twin" and twin.summary["param_error"]
    assert max(v["area"] for v in twin.summary["initial_metrics"].values()) > 1e-3

    with pytest.raises(ConfigError, match=r"no test of reference\.files is of scenario 'small_overlap_left'") as e:
        train(tiny(tmp_path, name="none", env_overrides=over, **{"eval.scenario": "small_overlap_left"}))
    assert e.value.key == "eval.scenario" and not (tmp_path / "runs" / "mappo" / "none").exists()
    with pytest.raises(ConfigError, match=r"needs tests in the env's reference\.files") as e:
        train(tiny(tmp_path, name="none", **{"eval.reference": "file"}))
    assert e.value.key == "eval.reference"

    # a run saved before eval.reference existed was evaluated on the twin, and still is
    from marlcrash.calibrate.evaluate import evaluate_run

    path = res.run_dir / "config.yaml"
    path.write_text(path.read_text().replace("  reference: env\n", ""))
    assert "reference: env" not in path.read_text()
    ckpt = res.run_dir / "checkpoint.pt"  # its checkpoint was written without the key too
    state = load_checkpoint(ckpt)
    del state["config"]["eval"]["reference"]
    save_checkpoint(ckpt, state)
    old = evaluate_run(res.run_dir)
    assert old["reference"] == "twin" and old["param_error"]


def test_a_run_on_a_pinned_reference_is_evaluated_on_its_evaluation_seed(short, tmp_path):
    """``reference.pin_seed`` pins the training episodes only: the evaluation env and the evaluation problem both
    draw ``eval.reference_seed`` (the env used the pinned one, and the run failed after training); a warning says
    that the two differ."""
    with pytest.warns(UserWarning, match=r"pinned reference 3 .* calibrates reference 0"):
        res = train(tiny(tmp_path, iterations=1, env_overrides={"reference.pin_seed": 3}))
    assert res.summary["reference"] == "twin" and res.summary["reference_seed"] == 0


def test_an_evaluation_on_a_scenario_the_training_never_drew_is_named_in_a_warning(short, tmp_path):
    """Training on offset40_left alone and evaluating on full_width_40 (the default eval.scenario) went unremarked."""
    with pytest.warns(UserWarning, match=r"scenario 'full_width_40' \(eval.scenario\) is not among the training's "
                                         r"scenarios \['offset40_left'\]"):  # fmt: skip
        res = train(tiny(tmp_path, iterations=1, env_overrides={"scenarios": {"offset40_left": 1.0}}), evaluate=True)
    assert res.summary["scenario"] == "full_width_40"


def test_a_training_resume_of_a_run_another_process_writes_is_refused_before_reading_it(short_configs, tmp_path,
                                                                                        monkeypatch):  # fmt: skip
    from marlcrash.calibrate.runlock import run_lock

    monkeypatch.setenv("MARLCRASH_CONFIGS", str(short_configs))
    run_dir = tmp_path / "runs" / "mappo" / "busy"
    run_dir.mkdir(parents=True)
    (run_dir / "checkpoint.pt").write_bytes(b"not read")  # a resume that got past the lock would fail to load it
    with run_lock(run_dir, "name"), pytest.raises(ConfigError, match="in use by another process") as e:
        train(tiny(tmp_path, resume=str(run_dir)))
    assert e.value.key == "resume"
    assert (run_dir / "checkpoint.pt").read_bytes() == b"not read"
    with pytest.raises(ConfigError, match="exists already") as e:  # a fresh run of that name: refused, untouched
        train(tiny(tmp_path, name="busy"))
    assert e.value.key == "name" and sorted(p.name for p in run_dir.iterdir()) == ["checkpoint.pt"]


def test_only_the_temporaries_of_checkpoint_writes_are_removed(tmp_path):
    """And those of the run's own files written through atomic_output (``.<stem>.<8 hex>.tmp<suffix>``, which a kill
    during the write leaves) where their names are given: not those of other files, which a process that does not
    hold the run folder (a user's output written there) may be writing."""
    from marlcrash.calibrate.checkpoint import remove_stale_temporaries
    from marlcrash.outputs import atomic_output, is_temporary_of

    (tmp_path / "checkpoints").mkdir()
    left = [".checkpoint.pt.0badf00d.tmp", "checkpoints/.iter_00020.pt.deadbeef.tmp", ".log.0badf00d.tmp.csv",
            ".summary.deadbeef.tmp.json"]  # fmt: skip
    kept = ["checkpoint.pt", "checkpoints/iter_00020.pt", ".hidden", "notes.tmp", ".summary.tmp.json", ".lock",
            ".x.0badf00d.tmpfile", ".y.NOTHEX00.tmp", ".contrib.0badf00d.tmp.csv", ".log.0badf00d.tmp.csv.bak",
            ".log.0badf00d.tmp.json", "checkpoints/.log.0badf00d.tmp.csv"]  # fmt: skip
    for name in left + kept:
        (tmp_path / name).write_text("x")
    removed = remove_stale_temporaries(tmp_path, outputs=("log.csv", "summary.json"))
    assert sorted(p.relative_to(tmp_path).as_posix() for p in removed) == sorted(left)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()) == sorted(kept)
    with atomic_output(tmp_path / "checkpoints" / "log.csv") as tmp:  # the names matched are the ones it gives
        assert is_temporary_of(tmp.name, "log.csv") and not is_temporary_of(tmp.name, "summary.json")


def test_a_resume_removes_the_temporary_checkpoints_a_kill_left(short, tmp_path):
    """A kill during a checkpoint's write leaves ``.checkpoint.pt.<hex>.tmp`` (and, for a kept snapshot,
    ``checkpoints/.iter_<n>.pt.<hex>.tmp``): a whole checkpoint's size each, which no resume removed."""
    part = train(tiny(tmp_path, name="torn", snapshot_every=1), stop_at=1, evaluate=False)
    stale = [part.run_dir / ".checkpoint.pt.0badf00d.tmp", part.run_dir / "checkpoints" / ".iter_00002.pt.deadbeef.tmp",
             part.run_dir / ".log.0badf00d.tmp.csv"]  # fmt: skip
    for p in stale:
        p.write_bytes(b"half a checkpoint")
    other = part.run_dir / ".notes.0badf00d.tmp.txt"  # a file the run does not write: another process's, kept
    other.write_text("x")
    done = train(tiny(tmp_path, name="torn", resume=str(part.run_dir)), evaluate=False)
    assert done.iterations == 4
    assert not [p for p in stale if p.exists()]
    assert list(part.run_dir.rglob("*.tmp*")) == [other]


def test_an_evaluation_removes_the_temporaries_of_its_files_a_kill_left(short, tmp_path):
    """A kill during an evaluation's write leaves ``.summary.<hex>.tmp.json`` (``.calibrated.<hex>.tmp.npz``, ...)
    in the folder it writes: no resume ever looks into ``eval/<checkpoint>/``, so nothing removed them. The
    evaluation, which holds that folder, removes those of its own files there; other names stay."""
    from marlcrash.calibrate.evaluate import evaluate_run

    res = train(tiny(tmp_path, iterations=2, snapshot_every=1), evaluate=False)
    out = res.run_dir / "eval" / "iter_00001"
    out.mkdir(parents=True)
    stale = [out / ".summary.0badf00d.tmp.json", out / ".calibrated.deadbeef.tmp.npz", out / ".pulses.0badf00d.tmp.png"]
    stale_own = res.run_dir / ".eval_metrics.0badf00d.tmp.csv"  # the run's own evaluation, in the run folder
    kept = [out / ".notes.0badf00d.tmp.txt", out / ".checkpoint.pt.0badf00d.tmp", res.run_dir / ".x.0badf00d.tmp.md"]
    for p in [*stale, stale_own, *kept]:
        p.write_bytes(b"half a file")
    evaluate_run(res.run_dir, checkpoint="1")
    assert not [p for p in stale if p.exists()] and stale_own.exists()  # the run folder is not the one written
    assert (out / "summary.json").is_file()
    evaluate_run(res.run_dir)
    assert not stale_own.exists() and all(p.exists() for p in kept)
    assert sorted(res.run_dir.rglob("*.tmp*")) == sorted(kept)


def test_the_entries_train_py_adds_to_the_summary_are_written_while_the_run_is_held(short, tmp_path):
    """train/train.py added process_wall_time_s to summary.json after train() had released the run folder: an
    evaluation or a resume that took the folder then rewrote summary.json beside it, and one of the two lost."""
    from marlcrash.calibrate.runlock import run_lock

    held = []

    def extra():
        try:
            with run_lock(tmp_path / "runs" / "mappo" / "stamped", "resume"):
                held.append(False)
        except ConfigError:
            held.append(True)
        return {"process_wall_time_s": 12.5}

    done = train(tiny(tmp_path, name="stamped", iterations=1, eval={"iterations": 1, "plots": False}),
                 summary_extra=extra)  # fmt: skip
    assert held == [True]
    assert done.summary["process_wall_time_s"] == 12.5
    assert json.loads((done.run_dir / "summary.json").read_text())["process_wall_time_s"] == 12.5


def test_a_resume_of_an_unreadable_checkpoint_says_how_to_go_on_from_a_kept_snapshot(short, tmp_path):
    """checkpoint.pt damaged (a disk fault, a copy cut short): the resume said only that it cannot be read, though the
    run kept snapshots it can go on from."""
    part = train(tiny(tmp_path, name="damaged", snapshot_every=1), stop_at=2, evaluate=False)
    (part.run_dir / "checkpoint.pt").write_bytes(b"PK\x03\x04 cut short")
    with pytest.raises(ConfigError, match=r"cannot read checkpoint .*checkpoint\.pt.*to go on from the last kept "
                                          r"snapshot, copy .*iter_00002\.pt over it") as e:  # fmt: skip
        train(tiny(tmp_path, name="damaged", resume=str(part.run_dir)))
    assert e.value.key == "resume"
    shutil.copyfile(part.run_dir / "checkpoints" / "iter_00002.pt", part.run_dir / "checkpoint.pt")
    assert train(tiny(tmp_path, name="damaged", resume=str(part.run_dir)), evaluate=False).iterations == 4


def test_evaluating_a_live_trainer_with_other_iterations_leaves_its_config_as_it_was(short, tmp_path):
    """``evaluate_run(trainer=..., iterations=n)`` set ``trainer.config.eval.iterations = n``: the caller's config
    (and every later evaluation or checkpoint of that trainer) changed under it."""
    from marlcrash.calibrate.evaluate import evaluate_run
    from marlcrash.calibrate.marl import build_trainer

    cfg = tiny(tmp_path, name="live", iterations=1)
    run_dir = tmp_path / "live"
    run_dir.mkdir()
    tr = build_trainer(cfg, run_dir)
    try:
        # a checkpoint beside a trainer was ignored: the trainer's networks were evaluated, the summary said none
        with pytest.raises(ConfigError, match="either a live trainer or a checkpoint") as e:
            evaluate_run(run_dir, trainer=tr, checkpoint="2")
        assert e.value.key == "checkpoint" and not (run_dir / "summary.json").exists()
        # range(1.5) raised a TypeError after the env was built; True ran one step; 2**63 was refused as the env
        # file's termination.max_iterations (a key the user never set) after an empty eval/ folder was made
        for bad in (1.5, True, "2", 0, 2**63):
            with pytest.raises(ConfigError, match="expected a whole number of calibration steps from 1 to 2") as e:
                evaluate_run(run_dir, trainer=tr, iterations=bad)
            assert e.value.key == "iterations" and not (run_dir / "eval").exists()
        s = evaluate_run(run_dir, trainer=tr, iterations=1)
    finally:
        tr.logger.close()
    assert s["eval_iterations"] == 1
    assert tr.config is cfg and cfg.eval.iterations == 2


def test_evaluating_a_live_trainer_with_other_iterations_keeps_the_runs_own_results(short, tmp_path):
    """``evaluate_run(trainer=..., iterations=n)`` with ``n`` other than the run's ``eval.iterations`` wrote into the
    run folder, over the run's own evaluation; it goes beside it, into ``eval/iter_<iteration>_steps<n>/`` (the
    folder an evaluation of the snapshot kept after that iteration with ``iterations=n`` writes), as a checkpoint's
    re-evaluation with other settings does."""
    from marlcrash.calibrate.evaluate import evaluate_run
    from marlcrash.calibrate.marl import build_trainer

    cfg = tiny(tmp_path, name="live", iterations=1)
    run_dir = tmp_path / "live"
    run_dir.mkdir()
    tr = build_trainer(cfg, run_dir)
    try:
        own = evaluate_run(run_dir, trainer=tr)  # the run's own evaluation: eval.iterations = 2
        before = {f: (run_dir / f).read_bytes() for f in ("summary.json", "eval_metrics.csv", "calibrated.npz")}
        other = evaluate_run(run_dir, trainer=tr, iterations=1)
    finally:
        tr.logger.close()
    assert own["eval_dir"] == str(run_dir) and own["eval_iterations"] == 2
    out = run_dir / "eval" / "iter_00000_steps1"
    assert other["eval_dir"] == str(out) and other["eval_iterations"] == 1
    assert json.loads((out / "summary.json").read_text()) == other and (out / "calibrated.npz").is_file()
    assert {f: (run_dir / f).read_bytes() for f in before} == before  # the run's own results stay


def test_a_checkpoint_named_by_a_digit_int_cannot_read_is_no_iteration(tmp_path):
    """``checkpoint=²``: ``str.isdigit`` takes a superscript two, ``int()`` refuses it (a ValueError from deep inside);
    it is a file name like any other, refused naming the key."""
    from marlcrash.calibrate.checkpoint import find_checkpoint, snapshot_path

    with pytest.raises(ConfigError, match="no checkpoint") as e:
        find_checkpoint(tmp_path, "\u00b2")
    assert e.value.key == "checkpoint"
    kept = snapshot_path(tmp_path, 40)  # the iteration form still finds a kept snapshot by its number
    kept.parent.mkdir(parents=True)
    kept.write_bytes(b"")
    assert find_checkpoint(tmp_path, "40") == kept


def test_the_kept_snapshots_a_missing_checkpoint_lists_are_in_iteration_order(tmp_path):
    """The refusal of a checkpoint with no file lists the kept snapshots; sorted by name, iteration 100000 (six digits
    of ``iter_%05d``) came before 20000."""
    from marlcrash.calibrate.checkpoint import find_checkpoint, snapshot_path

    for i in (100000, 20000, 40):
        snapshot_path(tmp_path, i).parent.mkdir(parents=True, exist_ok=True)
        snapshot_path(tmp_path, i).write_bytes(b"")
    with pytest.raises(ConfigError, match=r"\(iter_00040\.pt, iter_20000\.pt, iter_100000\.pt\)"):
        find_checkpoint(tmp_path, "7")
    assert find_checkpoint(tmp_path, 100000) == snapshot_path(tmp_path, 100000)


def test_the_reported_iterate_passes_before_it_scores():
    """``eval.select: best`` reports the highest-scoring iterate that passes the evaluation's thresholds where any
    does, as a run's record ranks its candidates: it used to report the highest score alone, so an evaluation could
    name a failing iterate (``passed`` false) while another of its iterates met every threshold."""
    from marlcrash.calibrate.evaluate import select_iterate
    from marlcrash.calibrate.problem import SuccessConfig
    from marlcrash.metrics import Metrics

    area = torch.tensor([[0.05, 0.05], [0.0016, 0.0001], [0.0014, 0.0014], [0.0010, 0.0012]], dtype=torch.float64)
    m = Metrics(area, torch.full_like(area, 0.1), torch.full_like(area, 0.1))
    scores = torch.tensor([-5.0, 3.0, 1.0, 2.0], dtype=torch.float64)  # I1 scores highest but fails on one sensor
    th = SuccessConfig()
    assert select_iterate(m, scores, th, "best") == 3  # the better of the passing I2, I3
    assert select_iterate(m, scores, th, "last") == 3
    assert select_iterate(m, scores, SuccessConfig(area=0.001), "best") == 1  # none passes: the highest score
    nan = torch.tensor([float("nan"), 0.0, -1.0, float("nan")], dtype=torch.float64)
    assert select_iterate(m, nan, SuccessConfig(area=0.001), "best") == 1  # a NaN score never wins


def test_the_summary_says_per_sensor_which_thresholds_the_reported_iterate_meets(short, tmp_path):
    """``passed`` (per sensor), ``all_passed`` and ``initial_passed`` of ``summary.json`` against the evaluation's
    thresholds, recomputed here from the summary's own metrics: loose thresholds pass every sensor, before and after."""
    loose = {"eval.thresholds.area": 10.0, "eval.thresholds.dfd": 100.0, "eval.thresholds.rmse": 100.0}
    for over, everything in (({}, False), (loose, True)):
        s = train(tiny(tmp_path, name=f"t{len(over)}", iterations=1, **{"eval.plots": False}, **over)).summary
        th = s["thresholds"]

        def meets(m, th=th):
            return all(th[k] is None or m[k] < th[k] for k in ("area", "dfd", "rmse"))

        assert s["passed"] == {k: meets(m) for k, m in s["final_metrics"].items()}
        assert s["all_passed"] is all(s["passed"].values()) is everything
        assert s["initial_passed"] is all(meets(m) for m in s["initial_metrics"].values()) is everything
