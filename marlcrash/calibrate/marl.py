"""Multi-agent PPO calibration with TorchRL: MAPPO, IPPO and single-agent PPO on the joint action (DESIGN 6).

The pieces, each a small function, in the order a training iteration uses them:

- :func:`make_env`: the native batched :class:`~marlcrash.envs.torchrl_env.CalibrationTorchEnv`
  (``B = n_envs`` episodes of ``episode_length`` calibration steps); for ``ppo_single`` wrapped in
  :class:`JointActionEnv` (one agent that observes the global ``"state"`` and acts on the
  concatenation of all agents' actions).
- :func:`make_policy`: TorchRL ``MultiAgentMLP`` (decentralised, shared or per-agent parameters)
  -> ``NormalParamExtractor`` -> ``ProbabilisticActor`` with a ``TanhNormal`` on ``[-1, 1]``;
  the mean head starts near zero, so the untrained policy's mean action leaves the car unchanged.
- :func:`make_critic`: MAPPO and ``ppo_single``: a centralised critic, one MLP on the global
  ``"state"`` whose value is broadcast to every agent (the reward is a team reward, so one
  value serves all); IPPO: a decentralised ``MultiAgentMLP`` on each agent's own observation.
- :func:`make_loss`: ``ClipPPOLoss`` with multi-agent keys and ``loss_mask_key = ("agents", "mask")``:
  inactive agents' actions (impact-region rule) are excluded from the policy, entropy and critic
  losses; :func:`make_advantage`: ``GAE`` on the agent-level keys.
- :func:`collect`: one rollout of ``episode_length`` steps from freshly reset episodes (finished
  episodes are reset in place); every iteration starts from a reset, so a checkpoint never has
  to hold a half-finished episode. :func:`expand_team`: copies the team reward and end flags to
  the agent dimension (``[B, L, n_agents, 1]``) for GAE and the loss.
- :func:`update`: GAE, masked advantage standardisation, ``epochs`` passes over shuffled
  minibatches, gradient clipping.
- :func:`train`: the loop with seeding, learning-rate and entropy schedules, CSV/TensorBoard
  logging, a tqdm bar, atomic checkpoints and resume; then the evaluation
  (:func:`marlcrash.calibrate.evaluate.evaluate_run`).

Budget accounting is the baselines' (:mod:`marlcrash.calibrate.budget`): every simulated
candidate parameter set costs one simulation -- one per environment step and one per episode
reset (the initial parameters' simulation); the reference pulses themselves are not charged.
:class:`ProgressHook` keeps the baselines' best-so-far record (:class:`~marlcrash.calibrate.budget.Progress`)
of a training run from the candidates the environment simulates anyway (no second simulation,
no change to the training numbers): the calibrated result of RL training on one pinned reference.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch
import yaml
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictModuleBase
from torch import nn
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, MultiAgentMLP, ProbabilisticActor, TanhNormal
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from marlcrash import provenance
from marlcrash.calibrate.baselines import MAX_BATCH
from marlcrash.calibrate.budget import Progress
from marlcrash.calibrate.checkpoint import (
    CHECKPOINT_FILE,
    SNAPSHOT_DIR,
    kept_snapshots,
    load_training_checkpoint,
    remove_stale_temporaries,
    restore_rng,
    rng_state,
    save_checkpoint,
    snapshot_path,
)
from marlcrash.calibrate.logging import LOG_FILE, LOGGERS, CSVLogger, make_logger
from marlcrash.calibrate.problem import SuccessConfig
from marlcrash.calibrate.runlock import claim_dir, run_lock
from marlcrash.config import (
    MAX_STEPS,
    check_override,
    config_dir,
    flatten_overrides,
    from_dict,
    load_config,
    load_yaml,
    nested_error,
    require,
    require_complete,
    require_device,
    require_seed,
    require_threads,
)
from marlcrash.envs.core import EnvConfig, env_config_of, require_env, require_env_keys_unset
from marlcrash.envs.torchrl_env import GROUP, CalibrationTorchEnv
from marlcrash.errors import ConfigError, ModelError
from marlcrash.metrics import Metrics
from marlcrash.outputs import check_output_dir, require_run_name, write_text
from marlcrash.sim.scenario import list_scenarios

ALGORITHMS: tuple[str, ...] = ("mappo", "ippo", "ppo_single")
"""Registered algorithms; each has ``configs/train/algorithm/<name>.yaml``."""

CONFIG_FILE = "config.yaml"
"""The resolved run config inside a run folder."""

CI_ENV = "MARLCRASH_CI"
"""Environment variable that shrinks a run to its ``ci`` overrides (a 1-2 minute smoke run)."""

TRAIN_ENV_OVERRIDES = {"max_step": 0.1, "observation.velocity_scale": 2.0, "observation.param_scale": 5.0}
"""``env_overrides`` of ``configs/train/train.yaml`` (and of ``ppo`` in ``compare.yaml`` and ``ablate.yaml``), the
defaults of the schemas built in Python (``tests/test_config_defaults.py`` keeps them equal to the files)."""

_ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}

_F32_MAX = float(torch.finfo(torch.float32).max)
"""Largest float32: the loss holds its coefficients in float32 buffers."""
_MAX_LR = _F32_MAX * (1.0 - 0.9)
"""Largest learning rate: Adam (beta1 = 0.9) divides it by 1 - beta1 on the float32 weights (torch raised "value
cannot be converted to type float without overflow" from inside its step above this)."""
MAX_HIDDEN_WIDTH = 16_384
"""Widest hidden layer of a policy or critic network [-]: a square layer of it holds 1 GiB of float32 weights (the
shipped networks are 128 wide); 10**9 failed allocating 3.9 TB with a torch traceback instead of naming the key."""

MAX_FRAMES_PER_BATCH = 100_000
"""Most env steps one training iteration may collect, ``n_envs * episode_length`` [-]: the rollout holds them all
(about 175 kB a step at the default env, so 17 GB here), and 4.8e13 (``episode_length: 10**12``) never finished its
first iteration. The default batch is 288."""


def require_batch_shape(n_envs: int, episode_length: int) -> None:
    """Refuse, naming ``n_envs`` or ``episode_length`` (keys relative to the schema being validated), a PPO batch
    beyond one batched simulation of :data:`~marlcrash.calibrate.baselines.MAX_BATCH` episodes per step or
    :data:`MAX_FRAMES_PER_BATCH` env steps per iteration: ``n_envs: 10**12`` failed allocating 29 PB after the run
    folder existed."""
    require(1 <= n_envs <= MAX_BATCH, "n_envs",
            f"expected [1, {MAX_BATCH}] parallel episodes (each step simulates them in one batch; "
            f"MAX_BATCH = {MAX_BATCH}), got {n_envs}")  # fmt: skip
    require(episode_length >= 1, "episode_length", f"expected >= 1 steps, got {episode_length}")
    require(n_envs * episode_length <= MAX_FRAMES_PER_BATCH, "episode_length",
            f"expected at most {MAX_FRAMES_PER_BATCH} env steps per iteration (MAX_FRAMES_PER_BATCH; the rollout "
            f"holds them all), got n_envs * episode_length = {n_envs} * {episode_length} = "
            f"{n_envs * episode_length}")  # fmt: skip


# ---------------------------------------------------------------------------------------- configs
@dataclass
class AlgorithmConfig:
    """PPO variant and its hyperparameters; values in ``configs/train/algorithm/<name>.yaml``."""

    name: str = "mappo"
    centralised_critic: bool = True
    share_policy_params: bool = True
    share_critic_params: bool = True
    hidden: list[int] = field(default_factory=lambda: [128, 128])
    activation: Literal["tanh", "relu", "elu"] = "tanh"
    init_std: float = 0.3
    min_std: float = 0.01
    mean_init_gain: float = 0.01
    lr: float = 1e-3
    lr_final: float = 2e-4
    entropy_coef: float = 1e-3
    entropy_coef_final: float = 0.0
    clip_epsilon: float = 0.2
    gamma: float = 0.9
    lmbda: float = 0.9
    epochs: int = 4
    minibatch_size: int = 48
    max_grad_norm: float = 1.0
    critic_coef: float = 1.0
    normalize_advantage: bool = True

    def validate(self) -> None:
        require(self.name in ALGORITHMS, "name", f"unknown algorithm {self.name!r}; expected one of {list(ALGORITHMS)}")
        require(self.name != "ippo" or not self.centralised_critic, "centralised_critic",
                "ippo has a decentralised critic by definition; expected false")  # fmt: skip
        require(self.name == "ippo" or self.centralised_critic, "centralised_critic",
                f"{self.name} uses the centralised critic on the global state; expected true")  # fmt: skip
        # one network values the global state for every agent: false was accepted, saved, and built the shared critic
        require(not self.centralised_critic or self.share_critic_params, "share_critic_params",
                f"{self.name}'s centralised critic is one network on the global state, shared by every agent; "
                "expected true")  # fmt: skip
        require(bool(self.hidden) and all(1 <= h <= MAX_HIDDEN_WIDTH for h in self.hidden), "hidden",
                f"expected a non-empty list of layer widths in [1, {MAX_HIDDEN_WIDTH}] (MAX_HIDDEN_WIDTH), "
                f"got {self.hidden}")  # fmt: skip
        for k in ("lr", "lr_final"):  # Adam's first step size lr / (1 - beta1) on float32 weights: 4e37 overflowed
            v = getattr(self, k)
            require(math.isfinite(v) and 0 < v <= _MAX_LR, k,
                    f"expected a learning rate > 0 whose Adam step (10 x lr) float32 holds (at most {_MAX_LR:.4g}), "
                    f"got {v}")  # fmt: skip
        for k in ("entropy_coef", "entropy_coef_final", "critic_coef"):  # float32 buffers of the loss: 1e39 is inf
            v = getattr(self, k)
            require(math.isfinite(v) and 0 <= v <= _F32_MAX, k,
                    f"expected a coefficient >= 0 that float32 holds (at most {_F32_MAX:.4g}), got {v}")  # fmt: skip
        require(self.min_std > 0, "min_std", f"expected a standard deviation floor > 0, got {self.min_std}")
        require(self.min_std < self.init_std, "init_std",
                f"expected 0 < min_std ({self.min_std}) < init_std ({self.init_std})")  # fmt: skip
        require(math.isfinite(initial_std(self.init_std, self.min_std)), "init_std",
                f"expected an initial standard deviation the policy's softplus head can represent in float32 "
                f"(below about 88; tanh saturates far below that), got {self.init_std}")  # fmt: skip
        gain = self.mean_init_gain
        require(0 < gain <= _F32_MAX, "mean_init_gain",
                f"expected a factor > 0 that float32 holds (at most {_F32_MAX:.4g}), got {gain}")  # fmt: skip
        require(0 < self.clip_epsilon < 1, "clip_epsilon", f"expected a ratio clip in (0, 1), got {self.clip_epsilon}")
        for k in ("gamma", "lmbda"):
            v = getattr(self, k)
            require(0 <= v <= 1, k, f"expected a discount in [0, 1], got {v}")
        require(self.epochs >= 1, "epochs", f"expected >= 1 passes over each batch, got {self.epochs}")
        require(self.minibatch_size >= 1, "minibatch_size", f"expected >= 1 env steps, got {self.minibatch_size}")
        require(self.max_grad_norm > 0, "max_grad_norm", f"expected > 0, got {self.max_grad_norm}")


def initial_std(init_std: float, min_std: float) -> float:
    """The standard deviation the policy's scale head (:func:`scale_head`) gives before training: ``init_std``, or
    ``inf`` where float32 cannot hold the inverse softplus of ``init_std`` (above about 88), and the first update's
    loss is NaN."""
    return float(scale_head(init_std, min_std)(torch.zeros(2))[1][0])


def scale_head(init_std: float, min_std: float) -> NormalParamExtractor:
    """Splits the policy network's output into the mean and the standard deviation ``softplus(x + b) + min_std``,
    with ``b`` such that ``x = 0`` gives ``init_std``.

    TorchRL's ``biased_softplus_<init_std>`` alone adds a floor of its own, 0.01, whatever ``scale_lb`` says: a
    ``min_std`` below 0.01 was never reached and an ``init_std`` below it started at 0.01. The mapping is given the
    floor (``biased_softplus_<init_std>_<min_std>``), and ``scale_lb`` keeps it under rounding.
    """
    return NormalParamExtractor(scale_mapping=f"biased_softplus_{init_std}_{min_std}", scale_lb=min_std)


@dataclass
class EvalConfig:
    """The end-of-run evaluation (deterministic policy on one reference); see ``configs/train/train.yaml``."""

    scenario: str = "full_width_40"
    reference: Literal["env", "twin", "cross_fidelity", "file"] = "env"
    reference_seed: int = 0
    iterations: int = 24
    select: Literal["best", "last"] = "best"
    plots: bool = True
    thresholds: SuccessConfig = field(default_factory=SuccessConfig)

    def validate(self) -> None:
        require(1 <= self.iterations <= MAX_STEPS, "iterations",
                f"expected >= 1 calibration steps and at most 2**63 - 1 (MAX_STEPS: the env counts them in "
                f"int64), got {self.iterations}")  # fmt: skip
        require(self.scenario in list_scenarios(), "scenario",
                f"unknown scenario {self.scenario!r}; registered: {list_scenarios()}")  # fmt: skip
        require(self.reference_seed >= 0, "reference_seed", f"expected a seed >= 0, got {self.reference_seed}")


@dataclass
class TrainConfig:
    """One training run; values and their meaning in ``configs/train/train.yaml``."""

    algorithm: AlgorithmConfig = field(default_factory=AlgorithmConfig)
    env: str = "default"
    env_overrides: dict[str, Any] = field(default_factory=lambda: dict(TRAIN_ENV_OVERRIDES))
    n_envs: int = 48
    episode_length: int = 6
    iterations: int = 400
    time_limit_s: float | None = 660.0
    seed: int = 0
    device: str = "cpu"
    threads: int = 0
    logger: str = "csv"
    checkpoint_every: int = 1
    snapshot_every: int = 20
    progress_bar: bool = True
    out_dir: str = "runs"
    name: str = "run"
    resume: bool | str = False
    eval: EvalConfig = field(default_factory=EvalConfig)
    ci: dict[str, Any] = field(default_factory=dict)

    @property
    def frames_per_batch(self) -> int:
        """Environment steps per iteration, ``n_envs * episode_length``."""
        return self.n_envs * self.episode_length

    def validate(self) -> None:
        require_batch_shape(self.n_envs, self.episode_length)
        require(self.iterations >= 1, "iterations", f"expected >= 1 training iterations, got {self.iterations}")
        require_seed(self.seed, "seed")  # torch.manual_seed takes 64 bits
        require(self.time_limit_s is None or self.time_limit_s > 0, "time_limit_s",
                f"expected a limit > 0 s or null, got {self.time_limit_s}")  # fmt: skip
        require_threads(self.threads, "threads")
        require(self.logger in LOGGERS, "logger", f"unknown logger {self.logger!r}; expected one of {list(LOGGERS)}")
        require_env(self.env, "env")
        require_env_keys_unset(self.env_overrides, TRAINING_ENV_KEYS)
        require(
            self.checkpoint_every >= 1, "checkpoint_every", f"expected >= 1 iterations, got {self.checkpoint_every}"
        )
        require(self.snapshot_every >= 0, "snapshot_every",
                f"expected >= 0 iterations (0: only the latest checkpoint), got {self.snapshot_every}")  # fmt: skip
        require_run_name(self.name)
        require(bool(self.out_dir), "out_dir", "expected an output folder")
        # '' (resume=$RUN, the variable unset) was the launch folder: the run found there was continued unasked
        require(self.resume != "", "resume", "expected true, false or a run folder, got an empty one")
        require_device(self.device, "device")
        mb = self.algorithm.minibatch_size
        require(self.frames_per_batch % mb == 0, "algorithm.minibatch_size",
                f"expected a divisor of the batch n_envs * episode_length = {self.n_envs} * {self.episode_length} "
                f"= {self.frames_per_batch} env steps, got {mb}")  # fmt: skip


def algorithm_config_path(name: str) -> Path:
    """``configs/train/algorithm/<name>.yaml``."""
    return config_dir() / "train" / "algorithm" / f"{name}.yaml"


def load_algorithm_config(name: str, overrides: dict[str, Any] | None = None) -> AlgorithmConfig:
    """Load a registered algorithm's settings by name.

    Raises:
        ConfigError: unknown name (the registered ones listed) or an invalid file (a key left out of it too).
    """
    path = algorithm_config_path(name)
    if name not in ALGORITHMS or not path.is_file():
        raise ConfigError(f"unknown algorithm {name!r}; expected one of {list(ALGORITHMS)}", key="algorithm")
    return load_config(AlgorithmConfig, path, overrides, complete=True)  # values live in the file, not the schema


def _set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError("cannot override inside a non-mapping value", key=f"ci.{dotted}")
    node[parts[-1]] = value


def _ci_items(over: dict[str, Any]) -> dict[str, Any]:
    """The ``ci`` block as dotted keys. A mapping in it (``+ci.eval.iterations=2`` on the command line is
    ``{"eval": {"iterations": 2}}``) changes only the keys it gives, of a section and of ``env_overrides`` alike;
    applied whole, it replaced the section (``env_overrides`` lost train.yaml's observation scales silently)."""
    out: dict[str, Any] = {}
    for k, v in flatten_overrides(TrainConfig, over).items():
        if k == "env_overrides" and isinstance(v, dict):  # dotted env keys (EnvConfig's sections spread): merged
            out.update({f"{k}.{ek}": ev for ek, ev in flatten_overrides(EnvConfig, v).items()})
        else:
            out[k] = v
    return out


def _apply_ci(data: dict[str, Any], key: str, value: Any) -> None:
    """Set one ``ci`` entry of :func:`_ci_items`; an env key stays one dotted key of ``env_overrides``."""
    env = data.get("env_overrides")
    if key.startswith("env_overrides.") and isinstance(env, dict):
        env[key.removeprefix("env_overrides.")] = value
    else:
        _set_dotted(data, key, value)


def value_keys(keys: Sequence[str]) -> list[str]:
    """The command-line override keys that set values, for ``load_train_config(explicit=...)``.

    A key naming a config group of the training configs Hydra composes (``algorithm=ippo``: the checkout's
    ``configs/train/``, :func:`~marlcrash.calibrate.entry.train_config_dir`) picks a file; it is left out, so the
    ``ci`` block's ``algorithm.*`` keys still apply to the file picked. (With ``$MARLCRASH_CONFIGS`` set to a folder
    without ``train/`` the group was looked for there, and ``algorithm=ippo`` taken as a value.)
    """
    from marlcrash.calibrate.entry import train_config_dir

    return [k for k in keys if not (train_config_dir() / k).is_dir()]


def load_train_config(
    data: dict[str, Any], source: str | None = None, ci: bool | None = None, explicit: Sequence[str] = ()
) -> TrainConfig:
    """Validate a training config mapping (e.g. Hydra's, without its ``hydra`` node).

    Args:
        data: the mapping; its ``ci`` entry holds dotted-key overrides.
        source: file name for messages.
        ci: apply the ``ci`` overrides; ``None`` reads ``$MARLCRASH_CI`` (``1``: apply).
        explicit: dotted keys the user set on the command line; the ``ci`` overrides leave them, and every key under
            them, as they are (``eval='{iterations: 9}'`` keeps ``eval.iterations`` too). Not config-group choices
            (``algorithm=ippo`` picks a file; the ``ci`` block's ``algorithm.*`` keys still apply).

    Raises:
        ConfigError: unknown key, wrong type or bad value (an ``env_overrides`` entry too), naming the dotted key --
            before any training; a bad value that came from the ``ci`` block is named ``ci.<key>``.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if ci is None:
        ci = os.environ.get(CI_ENV, "") not in ("", "0")
    applied: list[str] = []
    over = data.get("ci") or {}
    if not isinstance(over, dict):
        raise ConfigError(f"expected a mapping of dotted overrides, got {over!r}", key="ci", path=source)
    items = _ci_items(over)
    for k, v in items.items():  # keys and types on every run, so that a typo fails where it is made, not first in CI
        env_key = k.removeprefix("env_overrides.")
        if env_key != k:
            check_override(EnvConfig, env_key, v, key=f"ci.{k}", path=source)
        else:
            check_override(TrainConfig, k, v, key=f"ci.{k}", path=source)
    if ci:
        for k, v in items.items():
            if not any(k == e or k.startswith(e + ".") for e in explicit):
                _apply_ci(data, k, v)
                applied.append(k)
    try:
        if source is not None:
            require_complete(TrainConfig, data, source)
        config = from_dict(TrainConfig, data, path=source)
        try:  # a bad env override fails now, named in this file, not when the run folder exists
            make_env_config(config)
        except ConfigError as e:
            raise nested_error(e, "", source) from None
        return config
    except ConfigError as e:
        if e.key is not None and any(e.key == k or e.key.startswith(k + ".") for k in applied):
            raise ConfigError(f"{e.reason} ({CI_ENV}=1 applied it)", key=f"ci.{e.key}", path=e.path) from None
        raise


TRAINING_ENV_KEYS = {
    "termination.max_iterations": "episode_length (eval.iterations in the evaluation)",
    "seed": "the run's seed",
}
"""Env keys a training sets from its own settings (:func:`make_env_config`): ``env_overrides`` may not set them."""


def make_env_config(config: TrainConfig, overrides: dict[str, Any] | None = None) -> EnvConfig:
    """The env config of a run: ``config.env`` with ``env_overrides``, episode length and seed, then ``overrides``.

    Raises:
        ConfigError: a bad ``env_overrides`` entry named ``env_overrides.<key>`` (:func:`env_config_of`).
    """
    extra = {"termination.max_iterations": config.episode_length, "seed": config.seed, **(overrides or {})}
    return env_config_of(config.env, config.env_overrides, extra)


# -------------------------------------------------------------------------------- joint-action env
class JointActionEnv(EnvBase):
    """Single-agent view of a :class:`CalibrationTorchEnv` for ``ppo_single`` (same core, same budget).

    One agent in the group ``"agents"``: observation ``[B, 1, state_dim]`` (the global state),
    action ``[B, 1, n_agents * act_dim]`` (all agents' actions concatenated; the env ignores
    the parts of inactive agents), mask ``[B, 1]`` (some agent active), ``action_mask``
    ``[B, 1, n_agents * act_dim]`` (the joint action's entries that act: the agents' ``action_mask``
    concatenated; :func:`make_policy` holds the others' distribution fixed, so they leave the loss). Reward, end flags,
    ``"state"`` and ``"metrics"`` pass through unchanged.

    Args:
        base: the multi-agent env.
    """

    batch_locked = True

    def __init__(self, base: CalibrationTorchEnv):
        super().__init__(device=base.device, batch_size=base.batch_size)
        self.base = base
        c = base.core
        B = c.B
        self._joint = c.A * c.act_dim
        group = Composite(
            {
                "observation": Unbounded(shape=(B, 1, c.state_dim), dtype=torch.float32),
                "mask": Categorical(n=2, shape=(B, 1), dtype=torch.bool),
                "action_mask": Categorical(n=2, shape=(B, 1, self._joint), dtype=torch.bool),
            },
            shape=(B, 1),
        )
        obs = base.observation_spec.clone()
        del obs[GROUP]
        obs[GROUP] = group
        self.observation_spec = obs
        self.action_spec = Composite(
            {GROUP: Composite({"action": Bounded(-1.0, 1.0, shape=(B, 1, self._joint))}, shape=(B, 1))}, shape=(B,)
        )
        self.reward_spec = base.reward_spec.clone()
        self.done_spec = base.done_spec.clone()

    @property
    def core(self):
        """The shared :class:`~marlcrash.envs.core.CalibrationCore`."""
        return self.base.core

    def _convert(self, td: TensorDictBase) -> TensorDictBase:
        c = self.core
        acts = td.get((GROUP, "action_mask")).reshape(c.B, 1, self._joint)  # [B, 1, A * act_dim]
        group = TensorDict(
            {"observation": td.get("state")[:, None], "mask": c.active.any(-1, keepdim=True), "action_mask": acts},
            batch_size=(c.B, 1),
        )
        td.set(GROUP, group)
        return td

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        return self._convert(self.base._reset(tensordict, **kwargs))

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        c = self.core
        a = tensordict.get((GROUP, "action")).reshape(c.B, c.A, c.act_dim)
        inner = TensorDict({GROUP: TensorDict({"action": a}, batch_size=(c.B, c.A))}, batch_size=self.batch_size)
        if "_step" in tensordict:  # TorchRL's partial step: the base steps only these rows
            inner.set("_step", tensordict.get("_step"))
        return self._convert(self.base._step(inner))

    def _set_seed(self, seed: int | None) -> None:
        self.base._set_seed(seed)


def make_env(config: TrainConfig, n_envs: int | None = None, overrides: dict[str, Any] | None = None) -> EnvBase:
    """The training (or evaluation) environment of a run on the run's ``device`` (its specs and outputs; the
    simulator runs on the CPU), ``ppo_single`` wrapped in :class:`JointActionEnv`."""
    env_cfg = make_env_config(config, overrides)
    env = CalibrationTorchEnv(env_cfg, batch_size=n_envs or config.n_envs, device=config.device)
    return JointActionEnv(env) if config.algorithm.name == "ppo_single" else env


def env_dims(env: EnvBase) -> tuple[int, int, int, int]:
    """``(n_agents, obs_dim, act_dim, state_dim)`` of an env's agent group."""
    obs = env.observation_spec[GROUP, "observation"].shape
    act = env.action_spec[GROUP, "action"].shape
    return int(obs[-2]), int(obs[-1]), int(act[-1]), int(env.observation_spec["state"].shape[-1])


# ------------------------------------------------------------------------------------ best so far
class ProgressHook:
    """Best-so-far record of a training run in the baselines' terms, from what the env simulated anyway.

    Attach it with :meth:`attach`: the core calls it after every simulation (episode resets and
    env steps, in simulation order, rows in batch order) with the simulated cell parameters
    ``[n, n_cells, 7]`` and their per-sensor metrics ``[n, K]``; it ranks them with ``score``
    and tests them with ``success`` (e.g. :meth:`CalibrationProblem.score
    <marlcrash.calibrate.problem.CalibrationProblem.score>` and ``.success``) and records them in
    ``progress``. Candidates beyond the progress's budget are counted in :attr:`seen` but not
    recorded, so the record is that of a run stopped exactly at its budget. The best "candidate"
    (``progress.best_x``) is a cell-parameter set ``[n_cells, 7]``: an agent's cells need not move
    together (saturation damping, bounds), so it is not a point of the problem's search space.

    Args:
        progress: budget and best-so-far record.
        score: ``[N]`` fit scores (higher is better) of metrics ``[N, K]``.
        success: ``[N]`` bool success test of metrics ``[N, K]``.

    Attributes:
        seen: simulations reported by the core since :meth:`attach` (equals the trainer's count).
    """

    def __init__(
        self,
        progress: Progress,
        score: Callable[[Metrics], torch.Tensor],
        success: Callable[[Metrics], torch.Tensor],
    ):
        self.progress, self.score, self.success = progress, score, success
        self.seen = 0
        self._core: Any = None

    def __call__(self, params: torch.Tensor, metrics: Metrics) -> None:
        n_all = int(params.shape[0])
        self.seen += n_all
        n = self.progress.grant(n_all)
        if n == 0:
            return
        m = Metrics(*(t[:n] for t in metrics))
        self.progress.record(params[:n], m, self.score(m), self.success(m))

    def attach(self, env: EnvBase) -> ProgressHook:
        """Register with the env's core (``env.core``, also through :class:`JointActionEnv`); returns ``self``."""
        self._core = env.core
        self._core.simulation_hooks.append(self)
        return self

    def detach(self) -> None:
        """Unregister from the core it was attached to."""
        if self._core is not None and self in self._core.simulation_hooks:
            self._core.simulation_hooks.remove(self)
        self._core = None


# ---------------------------------------------------------------------------------------- networks
class StateValue(nn.Module):
    """Centralised critic: an MLP on the global state ``[*, state_dim]``, value broadcast to ``[*, n_agents, 1]``."""

    def __init__(self, state_dim: int, n_agents: int, hidden: list[int], activation: type[nn.Module]):
        super().__init__()
        self.n_agents = n_agents
        self.mlp = MLP(in_features=state_dim, out_features=1, num_cells=list(hidden), activation_class=activation)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        v = self.mlp(state)
        return v.unsqueeze(-2).expand(*v.shape[:-1], self.n_agents, 1)


@contextlib.contextmanager
def float32_default() -> Iterator[None]:
    """torch's default dtype float32 while in it (a context manager and a decorator), as it was before.

    The networks take the envs' float32 observations, and their initial weights, the PPO loss and the advantages
    are those of torch's own default: a caller that set ``torch.set_default_dtype(torch.float64)`` (common in
    scientific code) gets the same runs, not networks of the wrong dtype.
    """
    previous = torch.get_default_dtype()
    torch.set_default_dtype(torch.float32)
    try:
        yield
    finally:
        torch.set_default_dtype(previous)


class _FixedWhereNoEffect(nn.Sequential):
    """The policy network and its scale head (:func:`make_policy`), whose mean and scale are 0 and ``init_std`` on the
    action entries that do not act (the env's ``("agents", "action_mask")`` false: an inactive agent's, a factor no
    cell of the agent takes, a padded cell slot, a cell outside the region with ``masking.cells: region``).

    Those entries' distribution then does not depend on the weights: their log importance ratio is 0 and their
    entropy has no gradient, so they leave the PPO loss, as the loss mask takes inactive agents out of MAPPO's.
    Summed over the whole joint action, changing only the inactive agents' actions of a batch moved single-agent
    PPO's clipped objective from -0.41 to -2e-5 and the KL estimate from 0 to 766; in MAPPO's and IPPO's loss the
    20 of the default car's 147 sub-assembly factors that no cell takes (transmission factors of directions without
    links) entered every active agent's importance ratio and entropy. The entries are those of
    ``nn.Sequential(net, head)``, so a checkpoint's weights load either way.
    """

    def __init__(self, net: nn.Module, head: nn.Module, init_std: float):
        super().__init__(net, head)
        self.init_std = init_std

    def forward(self, obs: torch.Tensor, acts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # type: ignore[override]
        loc, scale = super().forward(obs)
        return torch.where(acts, loc, torch.zeros_like(loc)), torch.where(acts, scale, self.init_std)


@float32_default()
def make_policy(env: EnvBase, algo: AlgorithmConfig) -> ProbabilisticActor:
    """TanhNormal policy on ``("agents", "observation")`` writing ``("agents", "action")`` and its log-prob; the
    entries the env's ``("agents", "action_mask")`` leaves out have a fixed distribution (:class:`_FixedWhereNoEffect`).
    """
    A, obs_dim, act_dim, _ = env_dims(env)
    net = MultiAgentMLP(
        n_agent_inputs=obs_dim, n_agent_outputs=2 * act_dim, n_agents=A, centralized=False,
        share_params=algo.share_policy_params, depth=len(algo.hidden), num_cells=list(algo.hidden),
        activation_class=_ACTIVATIONS[algo.activation],
    )  # fmt: skip
    last = str(max(int(k) for k in net.params.keys()))  # noqa: SIM118 -- TensorDictParams is not iterable by key
    with torch.no_grad():  # mean and log-scale heads start near zero: mean action 0, std = init_std
        net.params[last, "weight"].mul_(algo.mean_init_gain)
        net.params[last, "bias"].zero_()
    extractor = scale_head(algo.init_std, algo.min_std)
    module = TensorDictModule(
        _FixedWhereNoEffect(net, extractor, algo.init_std),
        in_keys=[(GROUP, "observation"), (GROUP, "action_mask")], out_keys=[(GROUP, "loc"), (GROUP, "scale")],
    )  # fmt: skip
    return ProbabilisticActor(
        module, in_keys=[(GROUP, "loc"), (GROUP, "scale")], out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal, distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True, log_prob_key=(GROUP, "action_log_prob"),
    )  # fmt: skip


@float32_default()
def make_critic(env: EnvBase, algo: AlgorithmConfig) -> TensorDictModule:
    """Value network writing ``("agents", "state_value")`` ``[*, n_agents, 1]`` (module docstring)."""
    A, obs_dim, _, state_dim = env_dims(env)
    act = _ACTIVATIONS[algo.activation]
    if algo.centralised_critic:
        return TensorDictModule(StateValue(state_dim, A, algo.hidden, act), in_keys=["state"],
                                out_keys=[(GROUP, "state_value")])  # fmt: skip
    net = MultiAgentMLP(
        n_agent_inputs=obs_dim, n_agent_outputs=1, n_agents=A, centralized=False,
        share_params=algo.share_critic_params, depth=len(algo.hidden), num_cells=list(algo.hidden),
        activation_class=act,
    )  # fmt: skip
    return TensorDictModule(net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")])


_AGENT_KEYS = {
    "action": (GROUP, "action"),
    "sample_log_prob": (GROUP, "action_log_prob"),
    "value": (GROUP, "state_value"),
    "reward": (GROUP, "reward"),
    "done": (GROUP, "done"),
    "terminated": (GROUP, "terminated"),
    "advantage": (GROUP, "advantage"),
    "value_target": (GROUP, "value_target"),
}


LOG_RATIO_LIMIT = 10.0
"""Largest magnitude of a sample's log importance ratio ``log pi_new / pi_old`` the PPO loss uses [-]."""


class MaskedClipPPOLoss(ClipPPOLoss):
    """``ClipPPOLoss`` whose logged diagnostics ``entropy`` and ``kl_approx`` average over active agents only, and
    whose log importance ratio is bounded.

    TorchRL 0.14 applies ``loss_mask_key`` to the loss terms (``loss_*``) but logs the plain mean of the
    per-sample entropy and KL estimate, inactive agents included: with the impact-region rule the logged
    entropy then mixes in agents whose actions are ignored. This subclass keeps both per-sample tensors
    and reduces them with the same mask as the loss terms.

    The log ratio is clamped to ``+-LOG_RATIO_LIMIT`` (the clipped objective uses ``+-0.2``, so only runaway
    samples are touched). A joint action of thousands of dimensions (single-agent PPO with per-cell actions:
    21 agents x 357) sums so many log densities that one optimizer step moved it by hundreds: the ratio
    overflowed to ``inf``, the gradient became NaN, and the NaN weights were checkpointed.
    """

    def _log_weight(self, tensordict: TensorDictBase, adv_shape: torch.Size):
        log_weight, *rest = super()._log_weight(tensordict, adv_shape)
        self._diagnostics["kl_approx"] = rest[1].detach()
        return (log_weight.clamp(-LOG_RATIO_LIMIT, LOG_RATIO_LIMIT), *rest)

    def _get_entropy(self, dist, adv_shape: torch.Size):
        entropy = super()._get_entropy(dist, adv_shape)
        self._diagnostics["entropy"] = entropy.detach()
        return entropy

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._diagnostics: dict[str, torch.Tensor] = {}
        out = super().forward(tensordict)
        for key, value in self._diagnostics.items():
            out.set(key, self._reduce_loss(value, tensordict, reduction="mean"))
        return out


def make_loss(policy: ProbabilisticActor, critic: TensorDictModule, algo: AlgorithmConfig) -> ClipPPOLoss:
    """``ClipPPOLoss`` on the agent-level keys, inactive agents masked out via ``("agents", "mask")`` (of the
    loss terms and of the logged ``entropy`` and ``kl_approx``: :class:`MaskedClipPPOLoss`)."""
    loss = MaskedClipPPOLoss(
        actor_network=policy, critic_network=critic, clip_epsilon=algo.clip_epsilon, entropy_bonus=True,
        entropy_coeff=algo.entropy_coef, critic_coeff=algo.critic_coef, normalize_advantage=False,
    )  # fmt: skip
    loss.set_keys(**_AGENT_KEYS)
    loss.loss_mask_key = (GROUP, "mask")
    return loss


def make_advantage(critic: TensorDictModule, algo: AlgorithmConfig) -> GAE:
    """``GAE`` over the time dimension of ``[B, L]`` batches, on the agent-level reward and flags."""
    gae = GAE(gamma=algo.gamma, lmbda=algo.lmbda, value_network=critic, average_gae=False)
    gae.set_keys(**{k: v for k, v in _AGENT_KEYS.items() if k not in ("action", "sample_log_prob")})
    return gae


# ------------------------------------------------------------------------------------ the iteration
def module_device(module: torch.nn.Module) -> torch.device:
    """The device of a module's parameters (CPU for a module without any)."""
    return next((p.device for p in module.parameters()), torch.device("cpu"))


def act(policy: TensorDictModuleBase, td: TensorDictBase) -> TensorDictBase:
    """Run the policy on the env's tensordict ``td``, moved to the policy's device and back where the two differ (a
    policy read onto the CPU for an env of a GPU run; a run's env and networks are both on its ``device``)."""
    dev = module_device(policy)
    if dev == td.device:
        return policy(td)
    return policy(td.to(dev)).to(td.device)


def collect(env: EnvBase, policy: ProbabilisticActor, steps: int) -> tuple[TensorDictBase, int]:
    """Roll out ``steps`` steps from freshly reset episodes, sampling from the policy.

    Episodes that end before the last step are reset in place (their rows restart); no reset
    follows the last step, so the next iteration's reset is the only one.

    Returns:
        ``[B, steps]`` transitions (root keys at ``t``, ``"next"`` at ``t + 1``) and the number
        of episode resets (each costs one simulation of the initial parameters).
    """
    out = []
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        td = env.reset()
        resets = env.batch_size.numel()
        for t in range(steps):
            td = act(policy, td)
            if t < steps - 1:
                data, td = env.step_and_maybe_reset(td)
                resets += int(data.get(("next", "done")).sum())
            else:
                data = env.step(td)
            out.append(data)
    return torch.stack(out, dim=1), resets


def expand_team(data: TensorDictBase) -> TensorDictBase:
    """Copy the team ``reward``, ``done``, ``terminated`` ``[B, L, 1]`` to ``("next", "agents", k)`` ``[B, L, A, 1]``.

    GAE and the loss read agent-level keys; inactive agents get the team reward too (DESIGN 5).
    """
    A = data.get((GROUP, "mask")).shape[-1]
    for k in ("reward", "done", "terminated"):
        v = data.get(("next", k))
        data.set(("next", GROUP, k), v.unsqueeze(-2).expand(*v.shape[:-1], A, 1).clone())
    return data


def masked_standardize(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Standardise ``x [..., A, 1]`` over the entries where ``mask [..., A]`` is true (others left as they are)."""
    m = mask.unsqueeze(-1).expand_as(x)
    n = m.sum().clamp_min(1)
    mean = (x * m).sum() / n
    var = (((x - mean) ** 2) * m).sum() / n
    return torch.where(m, (x - mean) / var.sqrt().clamp_min(1e-6), x)


def update(
    data: TensorDictBase,
    loss: ClipPPOLoss,
    gae: GAE,
    optimizer: torch.optim.Optimizer,
    algo: AlgorithmConfig,
) -> dict[str, float]:
    """One PPO update on a ``[B, L]`` batch: GAE, masked advantage standardisation, epochs of minibatches.

    Returns:
        Means over minibatches of the loss terms and diagnostics (``loss_objective``, ``loss_critic``,
        ``loss_entropy``, ``entropy``, ``kl_approx``, ``grad_norm``).

    Raises:
        ModelError: the batch holds a non-finite reward (before any step: the weights stay as they were).
        ConfigError: a minibatch's loss or gradient is not finite (``algorithm.lr``), before its step.
    """
    reward = data.get(("next", GROUP, "reward"))
    finite = torch.isfinite(reward).reshape(*data.batch_size, -1).all(-1)  # [B, L]
    if not bool(finite.all()):
        rows = sorted({int(i) for i in (~finite).nonzero()[:, 0]})
        raise ModelError(
            f"{int((~finite).sum())} of {finite.numel()} env steps of the batch have a non-finite reward (episodes "
            f"{rows[:8]}{' ...' if len(rows) > 8 else ''}): a simulation gave non-finite metrics, or the reward form "
            "an infinite score. No update was made; the last checkpoint holds the weights before this iteration"
        )
    data = data.to(module_device(loss))
    with torch.no_grad():
        gae(data)
    if algo.normalize_advantage:
        adv = data.get((GROUP, "advantage"))
        data.set((GROUP, "advantage"), masked_standardize(adv, data.get((GROUP, "mask"))))
    flat = data.reshape(-1)
    n = flat.batch_size[0]
    params = [p for g in optimizer.param_groups for p in g["params"]]
    sums: dict[str, float] = {}
    count = 0
    for _ in range(algo.epochs):
        for idx in torch.randperm(n).split(algo.minibatch_size):
            out = loss(flat[idx])
            total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
            optimizer.zero_grad()
            total.backward()
            gn = torch.nn.utils.clip_grad_norm_(params, algo.max_grad_norm)
            if not (torch.isfinite(total) and torch.isfinite(gn)):  # before the step: the weights stay usable
                raise _diverged(out, total, gn, optimizer.param_groups[0]["lr"], loss)
            optimizer.step()
            for k in ("loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx"):
                sums[k] = sums.get(k, 0.0) + float(out[k].detach())
            sums["grad_norm"] = sums.get("grad_norm", 0.0) + float(gn)
            count += 1
    return {k: v / count for k, v in sums.items()}


def _diverged(out: TensorDictBase, total: torch.Tensor, gn: torch.Tensor, lr: float, loss: Any) -> ConfigError:
    """The error of a PPO minibatch whose loss or gradient is not finite, keyed by its likeliest cause: the
    coefficient of the one loss term that is not finite (an entropy or critic coefficient too large for the loss,
    which blamed the learning rate before), else the learning rate."""
    terms = {k: float(out[k]) for k in ("loss_objective", "loss_critic", "loss_entropy")}
    bad = [k for k, v in terms.items() if not math.isfinite(v)]
    said = ", ".join(f"{k} {v:.3g}" for k, v in terms.items())
    if bad in (["loss_entropy"], ["loss_critic"]):
        name = "entropy_coef" if bad == ["loss_entropy"] else "critic_coef"
        coef = float(loss.entropy_coeff if name == "entropy_coef" else loss.critic_coeff)
        return ConfigError(
            f"the PPO update diverged: {bad[0]} is not finite ({said}) at {name} {coef:.3g}; the last checkpoint "
            f"holds the weights before it. Lower {name}",
            key=f"algorithm.{name}",
        )
    return ConfigError(
        f"the PPO update diverged at learning rate {lr:.3g} (loss {float(total):.3g}: {said}; gradient norm "
        f"{float(gn):.3g}, approximate KL {float(out['kl_approx']):.3g}); the last checkpoint holds the weights before "
        "it. Lower the learning rate (or use per-sub-assembly actions for a joint policy of many cells)",
        key="algorithm.lr",
    )


def schedule(start: float, end: float, iteration: int, iterations: int) -> float:
    """Linear schedule from ``start`` (iteration 0) to ``end`` (the last iteration)."""
    frac = iteration / max(1, iterations - 1)
    return start + (end - start) * min(1.0, frac)


def batch_stats(data: TensorDictBase) -> dict[str, float]:
    """Fit statistics of a ``[B, L]`` batch: mean team reward per step, and of the episode each row starts with (the
    iteration's fresh one, :func:`collect`): its return, initial and final metrics (sensor means).

    An episode that ends before the last step is reset in place and its row goes on with another: its return
    stops at its end and its final metrics are those of its last step. Taken over the whole row, the return added
    up two episodes and the final metrics were those of the restarted one, half run, instead of the one that had
    succeeded.
    """
    reward = data.get(("next", "reward"))[..., 0]  # [B, L]
    done = data.get(("next", "done"))[..., 0]
    B, L = done.shape
    first = done.long().cumsum(1) - done.long() == 0  # steps of each row's first episode, its last step included
    last = torch.where(done.any(1), done.long().argmax(1), L - 1)  # [B] its last step
    rows = torch.arange(B, device=done.device)
    out = {"reward_mean": float(reward.mean()), "return_mean": float((reward * first).sum(1).mean())}
    for k in ("area", "dfd", "rmse"):
        out[f"{k}_initial"] = float(data.get(("metrics", k))[:, 0].mean())
        out[f"{k}_final"] = float(data.get(("next", "metrics", k))[rows, last].mean())
    return out


# -------------------------------------------------------------------------------------- run folder
def run_dir_of(config: TrainConfig) -> Path:
    """``<out_dir>/<algorithm>/<name>/``."""
    return Path(config.out_dir) / config.algorithm.name / config.name


def find_resume_dir(config: TrainConfig) -> Path:
    """The run folder to resume: ``resume`` as a path, or (``resume: true``) the named run if it has a
    checkpoint, else the newest run of the algorithm with one.

    Raises:
        ConfigError: no such run folder or no checkpoint in it.
    """
    named = Path(config.resume) if isinstance(config.resume, str) else run_dir_of(config)
    if (named / CHECKPOINT_FILE).is_file():
        return named
    if (named / CONFIG_FILE).is_file():  # never fall back to another run when this one was named
        raise ConfigError(
            f"run folder {named} has no {CHECKPOINT_FILE} (the run stopped before its first checkpoint, "
            f"every {config.checkpoint_every} iterations); delete the folder and start the run again",
            key="resume",
        )
    if isinstance(config.resume, str) or named.exists():
        raise ConfigError(f"expected a run folder with {CHECKPOINT_FILE}, found none in {named}", key="resume")
    parent = Path(config.out_dir) / config.algorithm.name
    runs = sorted(parent.glob(f"*/{CHECKPOINT_FILE}"), key=lambda p: p.stat().st_mtime) if parent.is_dir() else []
    if not runs:
        raise ConfigError(f"resume=true but no run with {CHECKPOINT_FILE} under {parent}", key="resume")
    return runs[-1].parent


def save_run_config(config: TrainConfig, run_dir: Path) -> None:
    """Write the resolved config as ``config.yaml`` (atomically)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text(run_dir / CONFIG_FILE, yaml.safe_dump(dataclasses.asdict(config), sort_keys=False))


def load_run_config(run_dir: str | Path, device: str | None = None) -> TrainConfig:
    """The resolved config saved in a run folder (the ``ci`` overrides were applied when it was saved).

    Args:
        run_dir: the run folder.
        device: the torch device to use instead of the saved ``device`` (``None``: the saved one, which must exist
            here, as a resume trains on it). The evaluations run the policy on the CPU and pass ``"cpu"``, so a run
            trained on a GPU is evaluated on a machine without one.

    Raises:
        ConfigError: no ``config.yaml`` (key ``run``), or one that is not a YAML mapping of valid settings (the
            file, and the line of a YAML error).
    """
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        hint, home = "", Path(run_dir).resolve().parent
        if Path(run_dir).is_dir() and (home / CONFIG_FILE).is_file():  # <run>/eval: the run or <run>/eval/<checkpoint>
            inside = sorted(str(Path(run_dir) / p.name) for p in Path(run_dir).iterdir() if p.is_dir())
            hint = f", a folder inside the run {home}: name the run (train/evaluate.py, resume)"
            hint += f" or one of its re-evaluations (marlcrash contributions): {', '.join(inside)}" if inside else ""
        raise ConfigError(f"expected a run folder with {CONFIG_FILE}, found none in {run_dir}{hint}", key="run")
    data = load_yaml(path)  # a torn or hand-edited file: the file, the line and what was expected
    if not data:  # else every key would be reported missing, one at a time
        raise ConfigError("empty; expected the run's settings (a mapping) as train/train.py saved them", path=path)
    if isinstance(data.get("eval"), dict):  # a run saved before eval.reference existed
        data["eval"].setdefault("reference", "twin")  # was evaluated on the twin, whatever it trained against
    if device is not None:
        data["device"] = device
    return load_train_config(data, source=str(path), ci=False)


def require_fits(own: dict[str, Any], saved: Any, what: str, path: Path, key: str) -> None:
    """Refuse a checkpoint's network weights ``saved`` that do not fit a run's network (state dict ``own``).

    Checked here: TorchRL's ``MultiAgentMLP`` keeps its weights in a TensorDict, whose loading broadcasts a tensor of
    another shape into place instead of refusing it (or fails deep inside tensordict).

    Raises:
        ConfigError: (``key``) naming the file, the network (``what``) and the first mismatches.
    """
    saved = saved if isinstance(saved, dict) else {}
    problems = [f"missing {k}" for k in own if k not in saved] + [f"unexpected {k}" for k in saved if k not in own]
    problems += [
        f"{k} has shape {tuple(saved[k].shape)}, expected {tuple(v.shape)}"
        for k, v in own.items()
        if k in saved and tuple(getattr(saved[k], "shape", ())) != tuple(v.shape)
    ]
    if problems:
        more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
        raise ConfigError(f"{path} does not fit this run's {what}: {'; '.join(problems[:3])}{more}", key=key)


RESUME_FREE_KEYS = ("name", "out_dir", "resume", "ci", "progress_bar", "logger", "checkpoint_every", "snapshot_every",
                    "eval.plots", "time_limit_s", "threads", "device")  # fmt: skip
"""Settings a checkpoint's saved config may hold otherwise than the run's ``config.yaml`` (:func:`require_same_run`):
where the run folder is (a moved or renamed folder), how the run shows its progress and which copies it keeps, how
long it may train (``time_limit_s``: a killed run given more time, ``resume=true time_limit_s=1200``; the schedules
follow ``iterations``) and what it runs on (``threads``, ``device``: a run moved to another machine); none changes
what an iteration computes beyond rounding. A resume takes these from the command line (:func:`resumed_config`)."""


def _flat(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A saved config's settings as dotted keys (``env_overrides`` and ``ci`` stay one value each)."""
    out: dict[str, Any] = {}
    for k, v in config.items():
        if isinstance(v, dict) and k not in ("env_overrides", "ci"):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


_LOCATING_KEYS = ("name", "out_dir", "resume")
"""Settings of :data:`RESUME_FREE_KEYS` that say which run a resume continues, never replaced in its config."""


def resumed_config(run_dir: Path, config: TrainConfig, given: Sequence[str]) -> tuple[TrainConfig, list[str]]:
    """The config a resume of the run in ``run_dir`` trains with: its ``config.yaml``, with the settings of
    :data:`RESUME_FREE_KEYS` the command line set replaced by theirs.

    Args:
        run_dir: the run folder.
        config: the command line's config; only the settings under ``given`` are read from it.
        given: the dotted keys set on the command line (``eval`` stands for every ``eval.*`` setting;
            ``env_overrides.<key>`` for all of ``env_overrides``); keys that are no setting (Hydra's) are skipped.

    Returns:
        The config and the dotted keys whose values it changed (to be saved in ``config.yaml`` once the run resumes).

    Raises:
        ConfigError: (the dotted key) a given setting outside :data:`RESUME_FREE_KEYS` that is not the run's (it would
            change what an iteration computes, or where it stops), naming the run's value and the given one.
    """
    keys = list(given)

    def named(k: str) -> bool:
        return any(k == g or k.startswith(g + ".") or g.startswith(k + ".") for g in keys)

    saved = load_run_config(run_dir, device=config.device if named("device") else None)  # may not exist here
    data = dataclasses.asdict(saved)
    now, before = _flat(dataclasses.asdict(config)), _flat(data)
    if named("device"):
        before["device"] = load_yaml(run_dir / CONFIG_FILE).get("device")  # as the run has it, to record the change
    changed = [k for k, v in now.items() if named(k) and k not in _LOCATING_KEYS and before.get(k) != v]
    free = ", ".join(k for k in RESUME_FREE_KEYS if k not in (*_LOCATING_KEYS, "ci"))
    for k in changed:
        if k not in RESUME_FREE_KEYS:
            raise ConfigError(
                f"resume: the run has {k} = {before.get(k)!r}, the command line gives {now[k]!r}; a resume continues "
                f"the run with its settings ({run_dir / CONFIG_FILE}), of which only {free} "
                f"may change: drop {k} or start a new run with it",
                key=k,
            )
    for k in changed:
        *parents, last = k.split(".")
        node = data
        for part in parents:
            node = node[part]
        node[last] = now[k]
    if not changed:
        return saved, []
    return load_train_config(data, source=str(run_dir / CONFIG_FILE), ci=False), changed


_RESUME_HINT = (
    "expected this run's checkpoint (a kept snapshot in {snapshots}/ to go back to), or start a new run with those "
    "settings"
)


def require_same_run(
    saved: Any, config: TrainConfig, path: Path, key: str = "resume", run_dir: Path | None = None,
    hint: str = _RESUME_HINT,
) -> None:  # fmt: skip
    """Refuse a checkpoint written under other settings than ``config`` (the ``config.yaml`` of ``run_dir``, by
    default the checkpoint's folder); ``hint`` says what was expected (``{snapshots}``: the kept snapshots' folder).

    :func:`require_fits` refuses weights of other shapes only: a checkpoint copied from a run with another ``n_envs``,
    seed or learning rate fits, and its optimizer, generators, counters and log position went on under settings that
    are not its own. Settings of :data:`RESUME_FREE_KEYS` may differ, and so may one that only one of the two has (a
    checkpoint written before the setting existed).

    Raises:
        ConfigError: (``key``) naming the file and the first setting that differs, with both values.
    """
    if not isinstance(saved, dict):  # no config saved in it: nothing to compare
        return
    a, b = _flat(saved), _flat(dataclasses.asdict(config))
    for k in a:
        if k in b and k not in RESUME_FREE_KEYS and a[k] != b[k]:
            raise ConfigError(
                f"{path} was written by a run with other settings: {k} is {a[k]!r} in it, {b[k]!r} in "
                f"{(path.parent if run_dir is None else run_dir) / CONFIG_FILE}; {hint.format(snapshots=SNAPSHOT_DIR)}",
                key=key,
            )


# ------------------------------------------------------------------------------------- the trainer
@dataclass
class TrainResult:
    """Outcome of :func:`train`: the run folder, counters, and the summary written there (if evaluated)."""

    run_dir: Path
    iterations: int
    env_steps: int
    simulations: int
    wall_time_s: float
    summary: dict[str, Any] | None


@dataclass
class Trainer:
    """Everything one run holds: config, env, networks, loss, optimizer, logger and counters."""

    config: TrainConfig
    run_dir: Path
    env: EnvBase
    policy: ProbabilisticActor
    critic: TensorDictModule
    loss: ClipPPOLoss
    gae: GAE
    optimizer: torch.optim.Optimizer
    logger: CSVLogger
    iteration: int = 0
    env_steps: int = 0
    simulations: int = 0
    wall_time_s: float = 0.0
    last_iteration_s: float = 0.0
    finished: bool = False
    saved_iteration: int | None = None
    """The iteration ``checkpoint.pt`` holds: the last one written or the one resumed from (``None``: none yet)."""

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint contents (:mod:`marlcrash.calibrate.checkpoint`)."""
        return {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "simulations": self.simulations,
            "wall_time_s": self.wall_time_s,
            "last_iteration_s": self.last_iteration_s,
            "finished": self.finished,
            "policy": self.policy.state_dict(),
            "critic": self.critic.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "rng": rng_state(self.env.core.rng),
            "log_position": self.logger.position,
            "config": dataclasses.asdict(self.config),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint; the CSV log is cut back to the checkpoint's position."""
        self.policy.load_state_dict(state["policy"])
        self.critic.load_state_dict(state["critic"])
        self.optimizer.load_state_dict(state["optimizer"])
        restore_rng(state["rng"], self.env.core.rng)
        self.iteration = int(state["iteration"])
        self.env_steps = int(state["env_steps"])
        self.simulations = int(state["simulations"])
        self.wall_time_s = float(state["wall_time_s"])
        self.last_iteration_s = float(state.get("last_iteration_s", 0.0))
        self.finished = bool(state.get("finished", False))  # checkpoints before this key: not known, train on
        self.saved_iteration = self.iteration
        self.logger.truncate(int(state["log_position"]))

    def checkpoint_due(self) -> bool:
        """Whether the iteration just finished is checkpointed: every ``checkpoint_every`` iterations, every
        ``snapshot_every`` (a kept snapshot is a copy of the checkpoint written then) and at the iteration cap."""
        c, i = self.config, self.iteration
        return i % c.checkpoint_every == 0 or bool(c.snapshot_every and i % c.snapshot_every == 0) or i == c.iterations

    def checkpoint(self) -> Path:
        """Write ``checkpoint.pt`` atomically; every ``snapshot_every`` iterations also keep a copy in
        ``checkpoints/`` (:func:`~marlcrash.calibrate.checkpoint.snapshot_path`) for later evaluation."""
        state = self.state_dict()
        every = self.config.snapshot_every
        if every and self.iteration % every == 0:
            save_checkpoint(snapshot_path(self.run_dir, self.iteration), state)
        path = save_checkpoint(self.run_dir / CHECKPOINT_FILE, state)
        self.saved_iteration = self.iteration
        return path


def _interrupt_note(run_dir: Path, kept: str | None) -> str:
    """What a Ctrl-C left of a run, for the message of the interrupt (:func:`marlcrash.errors.report_interrupt`):
    ``kept`` says what its ``checkpoint.pt`` holds, ``None``: the folder was removed (a fresh run with none yet)."""
    if kept is None:
        return f"{run_dir} was removed (no checkpoint yet): the same command starts the run again"
    return f"{run_dir} keeps the run ({CHECKPOINT_FILE}: {kept}); resume={run_dir} continues it"


def build_trainer(config: TrainConfig, run_dir: Path) -> Trainer:
    """Seed, then build env, networks, loss, advantage, optimizer and logger of a run (no training)."""
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    env = make_env(config)
    env.set_seed(config.seed)
    algo = config.algorithm
    device = torch.device(config.device)
    policy, critic = make_policy(env, algo).to(device), make_critic(env, algo).to(device)
    loss = make_loss(policy, critic, algo).to(device)
    gae = make_advantage(critic, algo)
    optimizer = torch.optim.Adam(loss.parameters(), lr=algo.lr)
    logger = make_logger(config.logger, run_dir)
    return Trainer(config, run_dir, env, policy, critic, loss, gae, optimizer, logger)


LOG_ROW_COLUMNS = ("iteration", "env_steps", "simulations", "wall_time_s", "env_steps_per_s", "lr", "entropy_coef",
                   "reward_mean", "return_mean",
                   *(f"{k}_{w}" for k in ("area", "dfd", "rmse") for w in ("initial", "final")),
                   "loss_objective", "loss_critic", "loss_entropy", "entropy", "kl_approx", "grad_norm")  # fmt: skip
"""Columns of the rows :func:`train_iteration` returns, in order: the columns of a run's ``log.csv``."""


def train_iteration(tr: Trainer) -> dict[str, float]:
    """Collect one batch, update, advance the counters; return the log row."""
    cfg, algo = tr.config, tr.config.algorithm
    t0 = time.perf_counter()
    lr = schedule(algo.lr, algo.lr_final, tr.iteration, cfg.iterations)
    ent = schedule(algo.entropy_coef, algo.entropy_coef_final, tr.iteration, cfg.iterations)
    for g in tr.optimizer.param_groups:
        g["lr"] = lr
    tr.loss.entropy_coeff.fill_(ent)
    data, resets = collect(tr.env, tr.policy, cfg.episode_length)
    t_collect = time.perf_counter() - t0
    stats = batch_stats(data)
    losses = update(expand_team(data), tr.loss, tr.gae, tr.optimizer, algo)
    steps = cfg.frames_per_batch
    tr.iteration += 1
    tr.env_steps += steps
    tr.simulations += steps + resets
    dt = time.perf_counter() - t0
    tr.wall_time_s += dt
    tr.last_iteration_s = dt
    return {
        "iteration": tr.iteration,
        "env_steps": tr.env_steps,
        "simulations": tr.simulations,
        "wall_time_s": tr.wall_time_s,
        "env_steps_per_s": steps / t_collect,
        "lr": lr,
        "entropy_coef": ent,
        **stats,
        **losses,
    }


def train(
    config: TrainConfig,
    *,
    stop_at: int | None = None,
    evaluate: bool = True,
    summary_extra: Callable[[], dict[str, Any]] | None = None,
    given: Sequence[str] = (),
) -> TrainResult:
    """Train (or resume) one run, checkpointing atomically, then evaluate it.

    Args:
        config: the run config; ``resume`` true or a run folder continues that run with ITS saved config, changed only
            where ``given`` names a setting of :data:`RESUME_FREE_KEYS` (:func:`resumed_config`).
        stop_at: stop after this iteration as if the process were killed there (after its checkpoint);
            no evaluation. For resume tests and staged runs.
        evaluate: run the end-of-run evaluation (:func:`marlcrash.calibrate.evaluate.evaluate_run`).
        summary_extra: called after the evaluation; its entries are added to ``summary.json`` while the run
            folder is still held (train/train.py's ``process_wall_time_s``), so no other process rewrites the
            file between the evaluation and them.
        given: the dotted keys of ``config`` set on the command line; a resume takes those of
            :data:`RESUME_FREE_KEYS` (recorded in the run's ``config.yaml``) and refuses any other that is not the
            run's.

    Returns:
        A :class:`TrainResult`.

    Raises:
        ConfigError: the run folder exists (fresh run), cannot be resumed (a given setting that is not the run's: that
            key), or another process writes it (:func:`marlcrash.calibrate.runlock.run_lock`).
    """
    if config.resume is not False:
        run_dir = find_resume_dir(config)
        with run_lock(run_dir, "resume"):
            return _train(config, run_dir, stop_at, evaluate, summary_extra, given)
    run_dir = run_dir_of(config)
    check_output_dir(run_dir, "out_dir")  # the nearest existing folder of the run's (<out_dir>/<algorithm>)
    if not claim_dir(run_dir):  # created here or refused, in one step: two runs of one name never share it
        hint = "resume=true" if (run_dir / CHECKPOINT_FILE).is_file() else "delete it (it has no checkpoint)"
        raise ConfigError(f"run folder {run_dir} exists already; choose another name or {hint}", key="name")
    with run_lock(run_dir, "name"):
        return _train(config, run_dir, stop_at, evaluate, summary_extra)


@float32_default()
def _train(
    config: TrainConfig,
    run_dir: Path,
    stop_at: int | None,
    evaluate: bool,
    summary_extra: Callable[[], dict[str, Any]] | None = None,
    given: Sequence[str] = (),
) -> TrainResult:
    """:func:`train` in its run folder, which this process holds."""
    from tqdm import tqdm

    from marlcrash.calibrate.evaluate import EVAL_FILES

    # of checkpoint writes and of the run's own files a kill interrupted: this process holds the folder
    remove_stale_temporaries(run_dir, (CONFIG_FILE, LOG_FILE, provenance.PROVENANCE_FILE, *EVAL_FILES))

    resume = config.resume
    changed: list[str] = []
    if resume is not False:
        config, changed = resumed_config(run_dir, config, given)
        try:
            state = load_training_checkpoint(run_dir / CHECKPOINT_FILE)
        except ConfigError as e:  # a damaged checkpoint.pt: the kept snapshots are where the run can go on from
            kept = kept_snapshots(run_dir)
            if not kept:
                raise
            raise ConfigError(f"{e.reason}; to go on from the last kept snapshot, copy {kept[-1]} over it",
                              key=e.key, path=e.path) from None  # fmt: skip
        extra = provenance.env_inputs(make_env_config(config))
        provenance.require_unchanged(run_dir, extra, finished=bool(state.get("finished", False)))
    else:
        state = None
    try:  # a fresh run's start-up: its files, the evaluation's check and the networks
        if resume is False:
            save_run_config(config, run_dir)
        if evaluate:  # an evaluation that cannot be built is refused now, not after the training time
            from marlcrash.calibrate.evaluate import evaluation_overrides

            make_env_config(config, evaluation_overrides(config))
            trained = make_env_config(config)
            pin = trained.reference.pin_seed
            if pin is not None and pin != config.eval.reference_seed:
                warnings.warn(
                    f"training calibrates the pinned reference {pin} (reference.pin_seed); the evaluation "
                    f"calibrates reference {config.eval.reference_seed} (eval.reference_seed)",
                    stacklevel=2,
                )
            if config.eval.scenario not in trained.scenarios:  # the policy never saw this load case
                warnings.warn(
                    f"the evaluation's scenario {config.eval.scenario!r} (eval.scenario) is not among the training's "
                    f"scenarios {sorted(trained.scenarios)} (the env's scenarios): the policy is evaluated on a "
                    "load case it never trained on",
                    stacklevel=2,
                )
        tr = build_trainer(config, run_dir)
        if resume is False:  # which configs and code the run's numbers come from, checked by a resume, an evaluation
            provenance.write_record(run_dir, provenance.env_inputs(make_env_config(config)))
    except BaseException as e:  # Ctrl-C too: building the env (discretizing a deck) takes seconds
        if resume is False:  # a fresh run that cannot start leaves no folder behind to block a rerun
            shutil.rmtree(run_dir, ignore_errors=True)
            with contextlib.suppress(OSError):  # and no empty <out_dir>/<algorithm>/ it created
                run_dir.parent.rmdir()
        if isinstance(e, KeyboardInterrupt):
            e.add_note(_interrupt_note(run_dir, None if resume is False else "as before this resume"))
        raise
    if state is not None:  # weights of other networks (config.yaml edited, a checkpoint of another run): refused
        for what, module in (("policy", tr.policy), ("critic", tr.critic)):
            name = f"{config.algorithm.name} {what}"
            require_fits(module.state_dict(), state[what], name, run_dir / CHECKPOINT_FILE, "resume")
        require_same_run(state.get("config"), config, run_dir / CHECKPOINT_FILE)  # same shapes, another run's
        if not state.get("finished", False):  # rows will be appended (a finished run is only evaluated again)
            tr.logger.require_columns(LOG_ROW_COLUMNS, key="resume")
        tr.load_state_dict(state)
        if changed:  # the settings the command line changed, for the next resume and the evaluations
            save_run_config(config, run_dir)
            if tr.finished and "time_limit_s" in changed:
                warnings.warn(f"the run in {run_dir} is finished: a resume evaluates it again, it trains no "
                              f"further (time_limit_s={config.time_limit_s} is recorded, to no effect)",
                              stacklevel=2)  # fmt: skip
    was_finished = tr.finished  # a finished run's checkpoint is its record: a resume only evaluates it again
    # with a time limit the iteration count is only a cap: say when training will stop
    desc = config.algorithm.name
    if config.time_limit_s is not None:
        desc += f" (stops by {config.time_limit_s:.0f} s)"
    bar = tqdm(total=config.iterations, initial=tr.iteration, disable=not config.progress_bar, unit="it",
               desc=desc)  # fmt: skip
    try:
        while not tr.finished and tr.iteration < config.iterations:
            if stop_at is not None and tr.iteration >= stop_at:
                bar.close()
                tr.logger.close()
                return TrainResult(run_dir, tr.iteration, tr.env_steps, tr.simulations, tr.wall_time_s, None)
            # The clock is the run's own training time, saved in every checkpoint, so a resumed run stops
            # where the uninterrupted one would have (a restarted process clock would train on).
            limit = config.time_limit_s
            if limit is not None and tr.iteration > 0 and tr.wall_time_s + tr.last_iteration_s > limit:
                break
            row = train_iteration(tr)
            tr.logger.log(row)
            if tr.checkpoint_due():
                tr.checkpoint()
            bar.update(1)
            bar.set_postfix(R=f"{row['reward_mean']:+.3f}", A=f"{row['area_final']:.4f}",
                            DFD=f"{row['dfd_final']:.3f}", RMSE=f"{row['rmse_final']:.3f}",
                            sps=f"{row['env_steps_per_s']:.0f}")  # fmt: skip
        tr.finished = True  # by the time limit or the iteration cap: a resume evaluates, it trains no further
    except BaseException as e:
        # A fresh run stopped (Ctrl-C, an error) before its first checkpoint cannot be resumed: remove its
        # folder so that the same command can start it again.
        saved = resume is not False or (run_dir / CHECKPOINT_FILE).is_file()
        if not saved:
            bar.close()
            tr.logger.close()
            shutil.rmtree(run_dir, ignore_errors=True)
        if isinstance(e, KeyboardInterrupt):
            e.add_note(_interrupt_note(run_dir, f"training at iteration {tr.saved_iteration} of {config.iterations}"
                                       if saved else None))  # fmt: skip
        raise
    finally:
        bar.close()
        tr.logger.close()
    if not was_finished:
        tr.checkpoint()
    summary = None
    if evaluate:
        from marlcrash.calibrate.evaluate import evaluate_run, update_summary

        try:
            summary = evaluate_run(run_dir, trainer=tr, finished_before=was_finished)
        except KeyboardInterrupt as e:
            e.add_note(_interrupt_note(run_dir, "finished training; its evaluation was interrupted"))
            raise
        if summary_extra is not None:
            summary = update_summary(run_dir, **summary_extra())
    return TrainResult(run_dir, tr.iteration, tr.env_steps, tr.simulations, tr.wall_time_s, summary)
