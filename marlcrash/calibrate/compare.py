"""The results table of issue 5: MAPPO, IPPO, single-agent PPO, random search, CMA-ES, gradient descent, LM (DESIGN 6).

Protocol (the paper's: calibration of ONE reference per run):

- References: the twin of ``scenario`` (default ``full_width_40``) with reference seed ``s`` for every
  ``s`` in ``seeds`` (default 0, 1, 2); a method's own random seed is the same ``s``. The optimizers
  get it from :func:`~marlcrash.calibrate.problem.build_problem` (``reference_seed = s``); the PPO
  methods train on an environment pinned to it (``reference.pin_seed = s``, scenario distribution
  ``{scenario: 1}``: :meth:`~marlcrash.references.ReferenceSampler.pinned`), and the two reference
  pulses are checked to be bit-identical before a PPO run starts.
- RL calibration is training on that reference: every episode starts from the initial parameters
  and its candidates are simulated by the environment; the calibrated result of a PPO run is the
  best candidate any of its simulations produced (:class:`~marlcrash.calibrate.marl.ProgressHook`),
  as for the optimizers (their best candidate, :class:`~marlcrash.calibrate.budget.Progress`).
- Budget: ``budget`` simulations per run, every simulated candidate counts one. PPO: one per env
  step of one episode and one per episode reset (the initial parameters' simulation), as
  ``Trainer.simulations`` counts; training stops before an iteration whose nominal cost
  ``n_envs * (episode_length + 1)`` exceeds what is left (the learning-rate and entropy schedules
  span ``budget // cost`` iterations); candidates of rare extra in-place resets beyond the budget are
  not counted for the result. Random search, CMA-ES and gradient descent stop exactly at the budget;
  lm when the rest cannot pay for a whole iteration, up to ``n_free + 6`` simulations below it
  (:func:`~marlcrash.calibrate.baselines.levenberg_marquardt`).
- Wall cap: a run stops before a batch (an optimizer batch, a PPO iteration) that would end after
  ``max_wall_s``, judged by the previous batch's duration; such a run is kept, with the simulations
  it used and ``stop = wall_cap`` ("stopped by wall cap" in the table). Gradient descent through the
  torch simulator (~4 s per simulation at 150 ms) is the method that hits it.
- An optimizer that stops by its own rule before its budget ran out (cmaes with ``restarts: false`` once CMA-ES's
  termination criteria fire, lm with ``restart_radius: 0`` after its windows) is kept with ``stop = ended``
  ("ended on its own"), and ``stop_reason`` names the rule (the criteria, e.g. ``tolx``; ``windows``), as the
  optimizer reports it (:attr:`~marlcrash.calibrate.baselines.CalibrationResult.stop`).
- Success: the configured thresholds, by default the paper's (:class:`~marlcrash.calibrate.problem.SuccessConfig`:
  every sensor A < 0.0015 m, DFD < 0.335 m/s, RMSE < 0.1511 m/s), the same test for all methods;
  ``sims_to_success``: the simulation count at which a candidate first passed it. A passing candidate outranks
  every failing one in a run's record (:class:`~marlcrash.calibrate.budget.Progress`), so a run passed exactly
  when it has a ``sims_to_success``.
- Ranking: the fit score of the env's reward form (``CalibrationProblem.score``, higher is better)
  for every method; the winner of a reference is the method whose best candidate passed the success test, before
  any other, then scores highest.

:func:`run_comparison` runs methods x seeds, each run independent; after every finished run it
rewrites ``compare.json`` (config, rows, per-sensor metrics and best-so-far histories),
``compare.csv`` (:data:`COLUMNS`, one row per method and seed) and ``compare.md`` (per method: mean
± std over seeds, passed k/n, median sims to success; per reference: the winner) atomically, so a
crash or kill loses nothing finished, and ``resume`` skips finished method/seed pairs.

A number that is not finite (the score of a run whose every candidate diverged is ``-inf``, a diverged metric
``nan``) has no place in standard JSON: a row holds ``None`` for it from the start (:func:`outcome_row`), written
``null`` to the JSON record, an empty field to the CSV and ``-`` to the tables, so a resumed run reads back the
rows it wrote. A run without a score ranks below every run with one (:func:`winners`); a mean over runs of
which one has no number has none either (:func:`summarize`).
"""

from __future__ import annotations

import contextlib
import copy
import csv
import io
import json
import math
import shutil
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch

from marlcrash import provenance
from marlcrash.calibrate.amortized import _fmt, _mean_param_error, csv_field, pm
from marlcrash.calibrate.baselines import (
    BASELINES,
    CMAESConfig,
    GradientConfig,
    LMConfig,
    RandomSearchConfig,
    check_free_coordinates,
    check_gradient_backend,
    check_lm_budget,
    check_lm_fd_step,
)
from marlcrash.calibrate.budget import Progress
from marlcrash.calibrate.evaluate import param_errors
from marlcrash.calibrate.marl import (
    ALGORITHMS,
    TRAIN_ENV_OVERRIDES,
    AlgorithmConfig,
    ProgressHook,
    TrainConfig,
    build_trainer,
    require_batch_shape,
    train_iteration,
)
from marlcrash.calibrate.problem import (
    CalibrationProblem,
    ProblemConfig,
    SmoothLoss,
    SuccessConfig,
    build_problem,
    env_backends,
)
from marlcrash.calibrate.runlock import run_lock
from marlcrash.config import (
    flatten_overrides,
    from_dict,
    merge_overrides,
    nested_error,
    require,
    require_complete,
    require_seed,
    require_threads,
)
from marlcrash.envs.core import EnvConfig, env_config_of, load_env_config, require_env, require_env_keys_unset
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics
from marlcrash.outputs import (
    check_output_dir,
    finite_or_null,
    json_text,
    remove_temporaries_of,
    require_run_name,
    write_text,
)
from marlcrash.reward import load_reward_config
from marlcrash.sim.scenario import list_scenarios

METHODS: tuple[str, ...] = (*ALGORITHMS, *BASELINES)
"""Comparable methods: the PPO variants (:data:`~marlcrash.calibrate.marl.ALGORITHMS`) and the optimizers."""

FILES = ("compare.json", "compare.csv", "compare.md")
"""What :func:`write_results` writes into the run folder."""

COLUMNS = (
    "method", "seed", "budget", "simulations", "stop", "stop_reason", "area_mean", "area_worst", "dfd_mean",
    "dfd_worst", "rmse_mean", "rmse_worst", "score", "initial_score", "passed", "sims_to_success", "param_error",
    "initial_param_error", "wall_time_s", "iterations", "env_steps", "trained_simulations",
)  # fmt: skip
"""Columns of ``compare.csv``, in order (empty field: not applicable, never reached, or not a finite number)."""

_ADDED_COLUMNS = ("stop_reason",)
"""Columns a finished row of an older comparison may lack (a resume reads it, the column ``None`` there: unknown)."""

SIMS_TO_SUCCESS = "sims to success: simulations until the first candidate met it (median over the runs where one did)"
"""What the tables' 'sims to success' column and its median are (:func:`summarize`), after the success test ('it')."""

STOP_LABELS = {"wall_cap": "stopped by wall cap", "ended": "ended on its own"}
"""How the tables say a run's ``stop`` (``budget`` as it is): :class:`RunOutcome`."""

_PROTOCOL = "the comparison protocol (scenario, seeds, ppo.episode_length)"
_SHARED_ENV_KEYS = dict.fromkeys(("scenarios", "reference.kind", "reference.pin_seed", "reference.file_scenario",
                                  "seed", "termination.max_iterations"), _PROTOCOL)  # fmt: skip
"""Env keys the protocol sets for every method (an ``env_overrides`` entry may not change them)."""
_PPO_ENV_KEYS = {**_SHARED_ENV_KEYS, "reference": f"{_PROTOCOL} for the pinned PPO runs; put shared env settings "
                 "in the top-level env_overrides"}  # fmt: skip
"""Env keys a ``ppo.env_overrides`` entry may not change: the PPO runs' reference must be the problem's."""
_REFERENCE_ENV_KEYS = ("vehicle", "vehicle_seed", "vehicle_options", "discretization", "sensors", "transmission_floor",
                       "behaviour_bounds", "sim_dtype", "sim_backend")  # fmt: skip
"""Env keys that shape the reference pulse besides ``reference`` (the car, its cells, the sensors compared, the twin's
mapping, the bounds its draws are clipped to, and the simulator): a ``ppo.env_overrides`` entry may not make them
differ from the optimizers' problem, whose reference the pinned PPO runs must draw bit for bit
(:func:`check_env_overrides`)."""


# ------------------------------------------------------------------------------------------- config
def budget_algorithm(name: str) -> AlgorithmConfig:
    """A PPO method's settings in ``compare.yaml`` and ``ablate.yaml``: its algorithm file with minibatches of 32 env
    steps (the default ``ppo`` batch, 8 episodes of 8 steps, is 64)."""
    return AlgorithmConfig(name=name, centralised_critic=name != "ippo", minibatch_size=32)


@dataclass
class PPOBudgetConfig:
    """How the PPO methods spend the budget; values in ``configs/train/compare.yaml`` (``ppo:``).

    Attributes:
        n_envs: parallel episodes per iteration.
        episode_length: calibration steps per episode.
        threads: torch intra-op threads during a PPO run (0: keep torch's setting).
        env_overrides: env overrides of the PPO runs only (observation scales, ``max_step``), on top of
            the comparison's ``env_overrides``.
    """

    n_envs: int = 8
    episode_length: int = 8
    threads: int = 0
    env_overrides: dict[str, Any] = field(default_factory=lambda: dict(TRAIN_ENV_OVERRIDES))

    @property
    def iteration_cost(self) -> int:
        """Nominal simulations of one iteration: ``n_envs`` resets plus ``n_envs * episode_length`` steps."""
        return self.n_envs * (self.episode_length + 1)

    def validate(self) -> None:
        require_batch_shape(self.n_envs, self.episode_length)
        require_threads(self.threads, "threads")
        require_env_keys_unset(self.env_overrides, _PPO_ENV_KEYS)


@dataclass
class CompareConfig:
    """One comparison; values and their meaning in ``configs/train/compare.yaml``."""

    methods: list[str] = field(default_factory=lambda: list(METHODS))
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    budget: int = 2000
    max_wall_s: float | None = 300.0
    scenario: str = "full_width_40"
    env: str = "default"
    env_overrides: dict[str, Any] = field(default_factory=dict)
    box_radius: float = 1.0
    masking: bool = True
    success: SuccessConfig = field(default_factory=SuccessConfig)
    out_dir: str = "runs"
    name: str = "compare"
    resume: bool = False
    ppo: PPOBudgetConfig = field(default_factory=PPOBudgetConfig)
    mappo: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("mappo"))
    ippo: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("ippo"))
    ppo_single: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("ppo_single"))
    random_search: RandomSearchConfig = field(default_factory=RandomSearchConfig)
    cmaes: CMAESConfig = field(default_factory=CMAESConfig)
    gradient: GradientConfig = field(default_factory=GradientConfig)
    lm: LMConfig = field(default_factory=LMConfig)

    def validate(self) -> None:
        require(len(self.methods) >= 1, "methods", f"expected at least one of {list(METHODS)}")
        for i, m in enumerate(self.methods):
            require(m in METHODS, f"methods[{i}]", f"unknown method {m!r}; expected one of {list(METHODS)}")
        require(len(set(self.methods)) == len(self.methods), "methods",
                f"expected distinct methods, got {self.methods}")  # fmt: skip
        require(len(self.seeds) >= 1, "seeds", "expected at least one reference seed, e.g. [0, 1, 2]")
        for i, s in enumerate(self.seeds):
            require_seed(s, f"seeds[{i}]")
        require(len(set(self.seeds)) == len(self.seeds), "seeds", f"expected distinct seeds, got {self.seeds}")
        require(self.budget >= 1, "budget", f"expected a simulation budget >= 1, got {self.budget}")
        require(self.max_wall_s is None or (math.isfinite(self.max_wall_s) and self.max_wall_s > 0), "max_wall_s",
                f"expected a wall-time cap > 0 s per run or null, got {self.max_wall_s}")  # fmt: skip
        require(np.isfinite(self.box_radius) and 0 < self.box_radius <= 5.0, "box_radius",
                f"expected a log-scale half-width in (0, 5], got {self.box_radius}")  # fmt: skip
        require(self.scenario in list_scenarios(), "scenario",
                f"unknown scenario {self.scenario!r}; registered: {list_scenarios()}")  # fmt: skip
        require_env(self.env, "env")
        require_env_keys_unset(self.env_overrides, _SHARED_ENV_KEYS)
        require_run_name(self.name)
        require(bool(self.out_dir), "out_dir", "expected an output folder")
        ppo = [m for m in self.methods if m in ALGORITHMS]
        for m in ppo:
            algo: AlgorithmConfig = getattr(self, m)
            require(algo.name == m, f"{m}.name", f"expected the {m} settings (name {m!r}), got name {algo.name!r}")
            frames = self.ppo.n_envs * self.ppo.episode_length
            require(frames % algo.minibatch_size == 0, f"{m}.minibatch_size",
                    f"expected a divisor of ppo.n_envs * ppo.episode_length = {frames} env steps, "
                    f"got {algo.minibatch_size}")  # fmt: skip
        if ppo:
            cost = self.ppo.iteration_cost
            require(self.budget >= cost, "budget",
                    f"the PPO methods {ppo} need at least one iteration of ppo.n_envs * (ppo.episode_length + 1) = "
                    f"{cost} simulations, got a budget of {self.budget}")  # fmt: skip

    @property
    def run_dir(self) -> Path:
        """``<out_dir>/compare/<name>/``."""
        return Path(self.out_dir) / "compare" / self.name


def load_compare_config(data: dict[str, Any], source: str | None = None) -> CompareConfig:
    """Validate a comparison config mapping (e.g. Hydra's, without its ``hydra`` node).

    Also loads the env config with ``env_overrides`` (and the PPO ones), so a bad env key fails here, and checks that
    gradient descent's backend can differentiate that env's simulator
    (:func:`~marlcrash.calibrate.baselines.check_gradient_backend`) and that ``lm``'s finite-difference step is above
    its rounding (:func:`~marlcrash.calibrate.baselines.check_lm_fd_step`).

    Raises:
        ConfigError: unknown key, wrong type or bad value, naming the dotted key -- before any run.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if source is not None:
        require_complete(CompareConfig, data, source)
    config = from_dict(CompareConfig, data, path=source)
    check_env_overrides(config.env, config.env_overrides, config.ppo.env_overrides, source, _PPO_ONLY_ENV_KEYS)
    sim_dtype = load_env_config(config.env, config.env_overrides).sim_dtype
    if "gradient" in config.methods:
        check_gradient_backend(config.gradient, sim_dtype, source=source)
    if "lm" in config.methods:
        check_lm_fd_step(config.lm, sim_dtype, source=source)
    return config


_PPO_ONLY_ENV_KEYS = ("max_step", "observation", "granularity", "termination")
"""Env keys only the PPO runs of a comparison read: the optimizers' problem searches the sub-assembly log-scales in its
own box (``box_radius``) with its own success test (``success``)."""


def check_env_overrides(
    env: str, shared: dict[str, Any], ppo: dict[str, Any], source: str | None, ppo_only: Sequence[str] | None = None
) -> None:
    """Load env config ``env`` with the ``env_overrides`` and, on top, the ``ppo.env_overrides`` of a table of runs.

    An ``env_overrides`` entry that a ``ppo.env_overrides`` entry sets to another value is refused where only the PPO
    runs read it (``ppo_only`` keys; ``None``: every key, all runs being PPO runs): the PPO value replaced it and the
    setting did nothing (``+env_overrides.max_step=0.2`` ran with ``ppo.env_overrides.max_step`` 0.1).

    The PPO runs' env may differ from the optimizers' problem in how the agents act and learn, not in the reference
    they calibrate against: a ``ppo.env_overrides`` entry that changes a key of :data:`_REFERENCE_ENV_KEYS` made every
    PPO run stop at its start ("drew different references"), after the optimizers' runs before it, and a resume with
    the entry removed was refused as another protocol.

    Nor may they measure differently: a ``ppo.env_overrides.reward`` form whose ``metrics`` (area method, DFD
    scales) differ from the shared env's form recorded the PPO runs' area, DFD and RMSE, and tested their success,
    by another definition than the optimizers' rows of the same table.

    Raises:
        ConfigError: a bad override, named by its dotted key under ``env_overrides`` or ``ppo.env_overrides``, a
            ``ppo.env_overrides`` entry that changes the reference pulse or the metrics, or an ``env_overrides``
            entry it replaces.
    """
    envs = []
    for key, over in (("env_overrides", shared), ("ppo.env_overrides", merge_overrides(EnvConfig, shared, ppo))):
        try:
            envs.append(env_config_of(env, over, overrides_key=key))
        except ConfigError as e:  # an override named in this file; an error of the env file's own keys in that one
            raise nested_error(e, "", source) from None
    replaced = flatten_overrides(EnvConfig, ppo)
    for k, v in flatten_overrides(EnvConfig, shared).items():
        if k in replaced and replaced[k] != v and (ppo_only is None or any(k == p or k.startswith(p + ".")
                                                                            for p in ppo_only)):  # fmt: skip
            runs = "the only runs" if ppo_only is None else "the only runs that read it"
            raise ConfigError(f"ppo.env_overrides.{k} ({replaced[k]!r}) replaces this value ({v!r}) in the PPO runs, "
                              f"{runs}; set ppo.env_overrides.{k} instead", key=f"env_overrides.{k}",
                              path=source)  # fmt: skip
    for k in _REFERENCE_ENV_KEYS:
        every, own = (_reference_setting(e, k) for e in envs)
        if own != every:
            given = [o for o in flatten_overrides(EnvConfig, ppo) if o == k or o.startswith(k + ".")]
            raise ConfigError(f"{k} shapes the reference pulse, which the pinned PPO runs must share bit for bit with "
                              f"the optimizers' problem ({every!r}, here {own!r}); set it in the top-level "
                              "env_overrides", key=f"ppo.env_overrides.{given[0] if given else k}",
                              path=source)  # fmt: skip
    every, own = (load_reward_config(e.reward).metrics for e in envs)
    if own != every:
        raise ConfigError(f"the reward form {envs[1].reward!r} measures A, DFD and RMSE differently from the shared "
                          f"env's {envs[0].reward!r} ({own} against {every}); the PPO rows would not compare with the "
                          "others", key="ppo.env_overrides.reward", path=source)  # fmt: skip


def _reference_setting(env: EnvConfig, key: str) -> Any:
    """The value of a :data:`_REFERENCE_ENV_KEYS` key that decides the reference (``sim_backend`` ``auto`` simulates
    without gradients on ``numba``, as the problem does: :func:`~marlcrash.calibrate.problem.env_backends`)."""
    value = getattr(env, key)
    return "numba" if key == "sim_backend" and value == "auto" else value


# ------------------------------------------------------------------------------------------ problem
def problem_config(config: CompareConfig, seed: int) -> ProblemConfig:
    """The optimizers' problem of reference ``seed``: twin of ``scenario``, ranked by the env's reward form."""
    env = load_env_config(config.env, config.env_overrides)
    return ProblemConfig(env=config.env, env_overrides=dict(config.env_overrides), scenario=config.scenario,
                         reference="twin", reference_seed=seed, box_radius=config.box_radius,
                         masking=config.masking, fit=env.reward, success=copy.deepcopy(config.success),
                         **env_backends(env))  # fmt: skip


def evaluate_params(problem: CalibrationProblem, params: torch.Tensor) -> Metrics:
    """Per-sensor metrics ``[N, K]`` of cell parameters ``[N, n_cells, 7]`` on the problem's reference.

    One no-grad simulation on the problem's backend, not charged to its simulation count (for
    checking and reporting a candidate found by a PPO run, whose parameters are cell parameters).
    """
    p = params.to(torch.float64)
    n = p.shape[0]
    with torch.no_grad():
        res = problem.sim.run(p, speed=problem.speed.expand(n), overlap=problem.overlap.expand(n),
                              side=problem.side.expand(n), duration=problem.sim_duration, sensors=problem.sensors,
                              record_cells="none", backend=problem.sim_backend)  # fmt: skip
    return problem.metrics(res.velocity)


# ------------------------------------------------------------------------------------------- runs
class _WallCap(Exception):
    """Raised inside an optimizer to stop it before a batch that would end after the wall cap."""


class _Recorder:
    """A :class:`CalibrationProblem` as an optimizer sees it, with a wall clock and its own record.

    Every batch the optimizer evaluates (``evaluate``, ``loss`` for gradient descent, ``residuals`` for
    Levenberg-Marquardt) is recorded into ``progress`` exactly as the optimizer records it; before a
    batch that would end after ``max_wall_s`` (judged by the time since the previous batch started:
    forward, backward and optimizer step) it raises :class:`_WallCap`, so a stopped run's record
    survives it.
    """

    def __init__(self, problem: CalibrationProblem, progress: Progress, max_wall_s: float | None):
        self._problem, self.progress, self.max_wall_s = problem, progress, max_wall_s
        self._last_start: float | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._problem, name)

    def _gate(self) -> None:
        now = time.perf_counter()
        last = self._last_start
        if self.max_wall_s is not None and last is not None and self.progress.wall_time + now - last > self.max_wall_s:
            raise _WallCap
        self._last_start = now

    def _record(self, x: torch.Tensor, m: Metrics) -> None:
        p = self._problem
        self.progress.record(x.detach(), m, p.score(m), p.success(m))

    def evaluate(self, x: torch.Tensor | np.ndarray) -> Metrics:
        self._gate()
        m = self._problem.evaluate(x)
        self._record(self._problem.check_x(x), m)
        return m

    def loss(self, x: torch.Tensor, weights: SmoothLoss, backend: str = "adjoint") -> tuple[torch.Tensor, Metrics]:
        self._gate()
        loss, m = self._problem.loss(x, weights, backend)
        self._record(self._problem.check_x(x.detach()), m)  # one [n_agents, 7] candidate is a batch of one
        return loss, m

    def residuals(self, x: torch.Tensor | np.ndarray) -> tuple[torch.Tensor, Metrics]:
        self._gate()
        r, m = self._problem.residuals(x)
        self._record(self._problem.check_x(x), m)
        return r, m


@dataclass
class RunOutcome:
    """One method on one reference: its best-so-far record and what it cost.

    Attributes:
        method, seed: the run.
        progress: budget and best-so-far record (``best_x``: ``[n_agents, 7]`` for optimizers).
        best_params: ``[n_cells, 7]`` cell parameters of the best candidate.
        stop: ``budget`` (spent, or the next batch would not fit), ``wall_cap``, or ``ended`` (an optimizer that
            stopped by its own rule with budget left: :func:`run_optimizer`).
        wall_time_s: [s].
        extra: PPO counters (``iterations``, ``env_steps``, ``trained_simulations``).
        stop_reason: for ``ended``, the optimizer's rule
            (:attr:`~marlcrash.calibrate.baselines.CalibrationResult.stop_reason`); ``None`` otherwise.
    """

    method: str
    seed: int
    progress: Progress
    best_params: torch.Tensor
    stop: str
    wall_time_s: float
    extra: dict[str, Any] = field(default_factory=dict)
    stop_reason: str | None = None


def run_optimizer(config: CompareConfig, method: str, seed: int, problem: CalibrationProblem) -> RunOutcome:
    """One optimizer run (``random_search``, ``cmaes``, ``gradient``, ``lm``) with the wall cap.

    Its ``stop`` is ``wall_cap``, or what the optimizer reports
    (:attr:`~marlcrash.calibrate.baselines.CalibrationResult.stop`): ``budget`` (what is left cannot pay for its next
    batch), or ``ended`` with its ``stop_reason``: it stopped by its own rule (cmaes without restarts, once CMA-ES's
    termination criteria fire; lm without restarts, ``lm.restart_radius = 0``, after its windows).
    """
    t0 = time.perf_counter()
    rec = _Recorder(problem, Progress(config.budget), config.max_wall_s)
    _, fn = BASELINES[method]
    stop, reason = "wall_cap", None
    try:
        result = fn(rec, config.budget, getattr(config, method), seed, False)
    except _WallCap:
        pass
    else:  # the recorder saw exactly what the optimizer recorded
        if result.simulations != rec.progress.used or result.best_score != rec.progress.best_score:
            raise RuntimeError(f"{method}: the record ({rec.progress.used} simulations, best "
                               f"{rec.progress.best_score}) disagrees with the optimizer's ({result.simulations}, "
                               f"{result.best_score})")  # fmt: skip
        stop, reason = result.stop, result.stop_reason
    prog = rec.progress
    assert prog.best_x is not None  # the recorder's first evaluation is never capped: it was recorded
    best = problem.params(prog.best_x[None])[0].detach()
    return RunOutcome(method, seed, prog, best, stop, time.perf_counter() - t0, stop_reason=reason)


def ppo_train_config(config: CompareConfig, method: str, seed: int, run_root: Path) -> TrainConfig:
    """The training config of a PPO method on pinned reference ``seed`` (module docstring)."""
    over = {**merge_overrides(EnvConfig, config.env_overrides, config.ppo.env_overrides),
            "scenarios": {config.scenario: 1.0}, "reference.kind": "twin", "reference.pin_seed": seed,
            "reference.file_scenario": None}  # fmt: skip
    p = config.ppo
    tc = TrainConfig(
        algorithm=copy.deepcopy(getattr(config, method)), env=config.env, env_overrides=over, n_envs=p.n_envs,
        episode_length=p.episode_length, iterations=max(1, config.budget // p.iteration_cost), time_limit_s=None,
        seed=seed, threads=p.threads, logger="csv", checkpoint_every=1, snapshot_every=0, progress_bar=False,
        out_dir=str(run_root / "ppo"), name=f"seed{seed}",
    )  # fmt: skip
    tc.validate()
    tc.algorithm.validate()
    return tc


def run_ppo(config: CompareConfig, method: str, seed: int, problem: CalibrationProblem, run_root: Path) -> RunOutcome:
    """One PPO run: training on the pinned reference, best candidate of all its simulations.

    Its training log goes to ``<run folder>/ppo/<method>/seed<s>/log.csv`` (replaced if a killed
    run left one).

    Raises:
        ConfigError: the pinned env's reference differs from the problem's (settings that change the
            reference in ``ppo.env_overrides``).
    """
    t0 = time.perf_counter()
    tc = ppo_train_config(config, method, seed, run_root)
    log_dir = run_root / "ppo" / method / f"seed{seed}"
    shutil.rmtree(log_dir, ignore_errors=True)
    threads = torch.get_num_threads()
    tr = build_trainer(tc, log_dir)
    pinned = tr.env.core.sampler.pinned(seed, 1)  # what every reset of the run uses (drawn once, cached)
    margin = 0 if pinned.margin is None else int(pinned.margin[0])  # how far candidates are simulated past it
    if not torch.equal(pinned.velocity[0], problem.ref_velocity) or margin != problem.margin:
        torch.set_num_threads(threads)
        tr.logger.close()
        raise ConfigError(f"the pinned env of {method} and the optimizers' problem drew different references "
                          f"for seed {seed}", key="ppo.env_overrides")  # fmt: skip
    progress = Progress(config.budget)
    hook = ProgressHook(progress, problem.score, problem.success).attach(tr.env)
    cost = config.ppo.iteration_cost
    stop, last_dt = "budget", 0.0
    try:
        while tr.iteration < tc.iterations and progress.remaining >= cost:
            elapsed = time.perf_counter() - t0
            if config.max_wall_s is not None and tr.iteration > 0 and elapsed + last_dt > config.max_wall_s:
                stop = "wall_cap"
                break
            t_it = time.perf_counter()
            tr.logger.log(train_iteration(tr))
            last_dt = time.perf_counter() - t_it
    finally:
        hook.detach()
        tr.logger.close()
        torch.set_num_threads(threads)
    if hook.seen != tr.simulations:
        raise RuntimeError(f"{method}: the env reported {hook.seen} simulations, the trainer counted {tr.simulations}")
    extra = {"iterations": tr.iteration, "env_steps": tr.env_steps, "trained_simulations": tr.simulations}
    assert progress.best_x is not None  # validate(): the budget pays for one iteration, which no wall cap stops
    return RunOutcome(method, seed, progress, progress.best_x.clone(), stop, time.perf_counter() - t0, extra)


def run_method(
    config: CompareConfig, method: str, seed: int, problem: CalibrationProblem, run_root: Path
) -> RunOutcome:
    """Run one method on reference ``seed`` (its own seed is ``seed`` too)."""
    if method in ALGORITHMS:
        return run_ppo(config, method, seed, problem, run_root)
    return run_optimizer(config, method, seed, problem)


# ------------------------------------------------------------------------------------------- rows
def initial_score(problem: CalibrationProblem) -> float:
    """Fit score of the initial parameters (every method's first candidate), re-simulated without charge."""
    return float(problem.score(evaluate_params(problem, problem.init[None]))[0])


def outcome_row(
    config: CompareConfig, problem: CalibrationProblem, out: RunOutcome, initial: float | None = None
) -> dict[str, Any]:
    """A table row (keys :data:`COLUMNS`) plus ``metrics`` per sensor and the best-so-far ``history``.

    A non-finite number (``score`` ``-inf`` where every candidate diverged, a ``nan`` metric) is ``None`` in it, as
    the JSON record has it (``null``) and a resumed run reads it back (:func:`marlcrash.outputs.finite_or_null`).

    Args:
        config: the comparison.
        problem: the run's reference problem.
        out: the run.
        initial: the initial parameters' score (:func:`initial_score`; computed if ``None``).
    """
    prog = out.progress
    m = prog.best_metrics
    assert m is not None  # a RunOutcome's run recorded a candidate (run_optimizer, run_ppo)
    passed = bool(problem.success(Metrics(*(t[None] for t in m)))[0])
    err = init_err = None
    if problem.true_params is not None:
        err = _mean_param_error(param_errors(problem, out.best_params, problem.true_params))
        init_err = _mean_param_error(param_errors(problem, problem.init, problem.true_params))
    row: dict[str, Any] = {"method": out.method, "seed": out.seed, "budget": config.budget,
                           "simulations": prog.used, "stop": out.stop, "stop_reason": out.stop_reason}  # fmt: skip
    for k in ("area", "dfd", "rmse"):
        v = getattr(m, k)
        row[f"{k}_mean"], row[f"{k}_worst"] = float(v.mean()), float(v.max())
    row.update({
        "score": prog.best_score, "initial_score": initial_score(problem) if initial is None else initial,
        "passed": passed,
        "sims_to_success": prog.sims_to_success, "param_error": err, "initial_param_error": init_err,
        "wall_time_s": out.wall_time_s, "iterations": out.extra.get("iterations"),
        "env_steps": out.extra.get("env_steps"), "trained_simulations": out.extra.get("trained_simulations"),
        "metrics": m.per_sensor(problem.sensors),
        "history": [[h.simulations, h.best] for h in prog.history],
    })  # fmt: skip
    return finite_or_null(row)


# ----------------------------------------------------------------------------------------- tables
def aggregate(rows: list[dict[str, Any]], methods: list[str]) -> list[dict[str, Any]]:
    """Per method (in ``methods`` order): mean and std (ddof 0) over seeds, passed, median sims to success.

    ``passed``: runs whose best candidate meets the success thresholds; ``sims_to_success_median``: median over
    the runs in which any candidate met them (the same runs: a passing candidate outranks every failing one,
    :class:`~marlcrash.calibrate.budget.Progress`); ``wall_capped``: runs stopped by the wall cap.
    """
    keys = ("simulations", "area_mean", "area_worst", "dfd_mean", "dfd_worst", "rmse_mean", "rmse_worst", "score",
            "param_error", "wall_time_s")  # fmt: skip
    out = []
    for method in methods:
        g = [r for r in rows if r["method"] == method]
        if g:
            out.append({"method": method, **summarize(g, keys)})
    return out


def summarize(group: list[dict[str, Any]], keys: tuple[str, ...]) -> dict[str, Any]:
    """Runs of one group (a method, an ablation cell): ``seeds``, mean and std (ddof 0) of ``keys``, ``passed``,
    ``sims_to_success_median`` and ``wall_capped`` (:func:`aggregate`).

    The std is ``None`` for a group of one run. The mean and std of a key are ``None`` where a run of the group has
    no number for it (``None``: not
    applicable, or not finite, as a run whose every candidate diverged has no score): leaving that run out would
    rank a method that failed on one reference by its other runs.
    """
    a: dict[str, Any] = {"seeds": len(group)}
    for k in keys:
        v = np.array([r[k] for r in group], dtype=np.float64)  # None: nan
        whole = v.size and np.isfinite(v).all()
        a[f"{k}_mean"] = float(v.mean()) if whole else None
        a[f"{k}_std"] = float(v.std()) if whole and v.size >= 2 else None  # one run has no spread (0 is not one)
    a["passed"] = sum(bool(r["passed"]) for r in group)
    hit = [r["sims_to_success"] for r in group if r["sims_to_success"] is not None]
    a["sims_to_success_median"] = float(np.median(hit)) if hit else None
    a["wall_capped"] = sum(r["stop"] == "wall_cap" for r in group)
    return a


def ranked(score: float | None) -> float:
    """A row's ``score`` for ranking: ``None`` (no finite score: every candidate diverged) below every number."""
    return -math.inf if score is None or math.isnan(score) else score


def winners(rows: list[dict[str, Any]], seeds: list[int]) -> list[dict[str, Any]]:
    """Per reference seed: every method's best score and the winner (a run that passed before any other, then the
    highest score, as a run's record ranks its candidates; ties name all; none where no run of the reference has a
    score) with its ``score``."""
    out = []
    for s in seeds:
        g = [r for r in rows if r["seed"] == s]
        if not g:
            continue
        rank = [(bool(r["passed"]), ranked(r["score"])) for r in g]
        best = max(rank)
        win = [r["method"] for r, k in zip(g, rank, strict=True) if k == best] if best[1] > -math.inf else []
        out.append({"seed": s, "scores": {r["method"]: r["score"] for r in g}, "winner": win,
                    "score": best[1] if win else None})  # fmt: skip
    return out


def _present(config: CompareConfig, rows: list[dict[str, Any]]) -> tuple[list[str], list[int]]:
    """Methods and seeds that have rows: the config's order first, then others (rows of a resumed run)."""
    methods = [m for m in [*config.methods, *METHODS] if any(r["method"] == m for r in rows)]
    seeds = [*config.seeds, *sorted({r["seed"] for r in rows} - set(config.seeds))]
    return list(dict.fromkeys(methods)), [s for s in seeds if any(r["seed"] == s for r in rows)]


def markdown(config: CompareConfig, rows: list[dict[str, Any]], command: str | None, date: str) -> str:
    """``compare.md``: protocol, per-method table (mean ± std over seeds), winner per reference, per-run table.

    The references it names are this run's seeds and those of the rows finished before (a resume may name other
    seeds: ``seeds=[2]`` after a table of seeds 0 and 1 is a table of three references).
    """
    methods, seeds = _present(config, rows)
    listed = sorted({*config.seeds, *(r["seed"] for r in rows)})
    agg = aggregate(rows, methods)
    win = winners(rows, seeds)
    th = config.success
    lines = [
        "# Calibration of one reference: MAPPO, IPPO, single-agent PPO, random search, CMA-ES, gradient descent, "
        "Levenberg-Marquardt",
        "",
        f"- date: {date}",
    ]
    if command:
        lines.append(f"- command: `{command}`")
    lines += [
        f"- references: twin of `{config.scenario}` with seeds {listed}; each method's own seed = the "
        "reference seed; PPO methods train on the pinned reference (RL calibration = training on it)",
        f"- budget: {config.budget} simulations per run (every simulated candidate counts one; PPO: one per env "
        f"step and one per episode reset, {config.ppo.n_envs} envs x {config.ppo.episode_length} steps per "
        f"iteration); {'no wall cap' if config.max_wall_s is None else f'wall cap {config.max_wall_s:g} s per run'}",
        f"- result of a run: its best candidate by fit score, a passing one before any other; success = every "
        f"sensor {th.describe()} "
        f"({'the' if th.is_paper() else 'as configured, not the'} paper's best Table 3 row); passed: "
        f"the best candidate meets it; {SIMS_TO_SUCCESS}",
        "- area [m], DFD [m/s], RMSE [m/s] of the best candidate: mean over sensors and worst sensor; score: fit "
        "score, higher is better; param err: mean relative error of the sub-assembly parameters vs the twin truth",
        "",
    ]
    n = len(seeds)

    lines += [
        f"## Per method (mean ± std over {n} reference{'s' if n != 1 else ''}; population std, ddof 0"
        + ("; a single reference: no std (-))" if any(a["seeds"] < 2 for a in agg) else ")"),
        "",
        "| method | passed | median sims to success | simulations | area mean | area worst | DFD mean | DFD worst "
        "| RMSE mean | RMSE worst | score | param err | wall [s] | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for a in agg:
        note = f"stopped by wall cap ({a['wall_capped']}/{a['seeds']})" if a["wall_capped"] else ""
        ended = sum(r["stop"] == "ended" for r in rows if r["method"] == a["method"])
        if ended:
            note = (note + "; " if note else "") + f"ended on its own ({ended}/{a['seeds']})"
        if a["seeds"] < n:
            note = (note + "; " if note else "") + f"{a['seeds']}/{n} references run"
        lines.append(
            f"| {a['method']} | {a['passed']}/{a['seeds']} | {_fmt(a['sims_to_success_median'], '.0f')} | "
            f"{pm(a, 'simulations', '.0f')} | {pm(a, 'area_mean')} | {pm(a, 'area_worst')} | {pm(a, 'dfd_mean')} | "
            f"{pm(a, 'dfd_worst')} | {pm(a, 'rmse_mean')} | {pm(a, 'rmse_worst')} | {pm(a, 'score')} | "
            f"{pm(a, 'param_error', '.3f')} | {pm(a, 'wall_time_s', '.1f')} | {note} |"
        )
    lines += [
        "",
        "## Winner per reference (a run that passed first, then the highest fit score of the best candidate)",
        "",
        "| reference seed | " + " | ".join(methods) + " | winner |",
        "|---|" + "---|" * len(methods) + "---|",
    ]
    for w in win:
        cells = [_fmt(w["scores"].get(m), ".4f") for m in methods]
        lines.append(f"| {w['seed']} | " + " | ".join(cells) + f" | {', '.join(w['winner']) or '-'} |")
    tally: dict[str, int] = {}
    for w in win:
        for m in w["winner"]:
            tally[m] = tally.get(m, 0) + 1
    if win:
        wins = ", ".join(f"{m} on {k}/{len(win)}" for m, k in sorted(tally.items(), key=lambda t: -t[1]))
        lines += ["", f"Wins: {wins} references."]
    lines += [
        "",
        "## Per run",
        "",
        "| seed | method | simulations | stop | area mean | DFD mean | RMSE mean | area worst | DFD worst "
        "| RMSE worst | score | initial score | passed | sims to success | param err | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (seeds.index(r["seed"]), methods.index(r["method"]))):
        stop = STOP_LABELS.get(r["stop"], r["stop"]) + (f" ({r['stop_reason']})" if r["stop_reason"] else "")
        lines.append(
            f"| {r['seed']} | {r['method']} | {r['simulations']} | {stop} | {_fmt(r['area_mean'])} | "
            f"{_fmt(r['dfd_mean'])} | {_fmt(r['rmse_mean'])} | {_fmt(r['area_worst'])} | {_fmt(r['dfd_worst'])} | "
            f"{_fmt(r['rmse_worst'])} | {_fmt(r['score'])} | {_fmt(r['initial_score'])} | {_fmt(r['passed'])} | "
            f"{_fmt(r['sims_to_success'])} | {_fmt(r['param_error'], '.3f')} | {_fmt(r['wall_time_s'], '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def csv_text(rows: list[dict[str, Any]], columns: tuple[str, ...] = COLUMNS) -> str:
    """The rows as CSV (``columns``, by default :data:`COLUMNS`; ``None`` and a non-finite number as an empty
    field)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: csv_field(r[k]) for k in columns})
    return buf.getvalue()


def write_results(config: CompareConfig, rows: list[dict[str, Any]], run_dir: Path, command: str | None) -> None:
    """Rewrite :data:`FILES` in ``run_dir`` atomically (each file replaced whole)."""
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    methods, seeds = _present(config, rows)
    payload = {"date": date, "command": command, "config": asdict(config), "rows": rows,
               "aggregate": aggregate(rows, methods), "winners": winners(rows, seeds)}  # fmt: skip
    write_text(run_dir / "compare.json", json_text(payload))  # standard JSON: non-finite numbers as null
    write_text(run_dir / "compare.csv", csv_text(rows))
    write_text(run_dir / "compare.md", markdown(config, rows, command, date))


# ------------------------------------------------------------------------------------------- driver
_RESUMABLE_DIFF_OK = ("methods", "seeds", "resume", "out_dir")
"""Settings a resumed comparison may change (the others define the protocol of the rows already there; ``out_dir``
may differ when the run folder was moved), besides
the settings of methods that have no finished row yet (e.g. a method added to an earlier comparison)."""


def _first_difference(a: Any, b: Any, key: str = "") -> str | None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            d = _first_difference(a.get(k), b.get(k), f"{key}.{k}" if key else str(k))
            if d is not None:
                return d
        return None
    return None if a == b else key


@contextlib.contextmanager
def hold_run_dir(run_dir: Path, resume: bool, outputs: Iterable[str]) -> Iterator[None]:
    """Hold the run folder of a table of runs for the ``with`` block (:func:`marlcrash.calibrate.runlock.run_lock`):
    a second run of this name, or a second resume, fails there before it reads or writes a row. A fresh run's folder
    is made here; a resumed one's must exist (:func:`open_run_dir` names it where it does not).

    The temporaries a kill left writing ``outputs`` (the files the run writes into the folder, its record first) or
    ``provenance.json`` there are removed once the folder is held (:func:`marlcrash.outputs.remove_temporaries_of`).
    A Ctrl-C in the block gets a note of what the folder keeps and how to continue it
    (:func:`marlcrash.errors.report_interrupt` prints it)."""
    check_output_dir(run_dir, "out_dir")  # before the folder is made: out_dir may be a file
    outputs = tuple(outputs)
    with run_lock(run_dir, "resume" if resume else "name", create=not resume):
        remove_temporaries_of(run_dir, (*outputs, provenance.PROVENANCE_FILE))
        try:
            yield
        except KeyboardInterrupt as e:
            if (run_dir / outputs[0]).is_file():
                e.add_note(f"{run_dir} keeps the finished runs ({outputs[0]}); the same command with "
                           f"name={run_dir.name} resume=true continues it, skipping them")  # fmt: skip
            raise


def open_run_dir(
    run_dir: Path,
    filename: str,
    config: dict[str, Any],
    resume: bool,
    free_keys: Callable[[list[dict[str, Any]]], Iterable[str]],
    env: tuple[str, dict[str, Any]],
    row_keys: Iterable[str],
) -> tuple[Path, list[dict[str, Any]]]:
    """The run folder of a table of runs and the rows already finished in it, after checking settings agree.

    Args:
        run_dir: the run folder.
        filename: its JSON record (``{"config": ..., "rows": [...]}``).
        config: this run's settings (``asdict`` of its config).
        resume: continue the rows there; otherwise the folder must hold no finished row.
        free_keys: top-level settings that may differ from the saved ones, given the saved rows.
        env: the env config name and overrides the runs use; their input files outside ``configs/`` (a vehicle
            deck, measured pulses) are recorded and checked with ``configs/`` (:func:`marlcrash.provenance.env_inputs`).
        row_keys: the keys every finished row has (those its tables and the resumed run read).

    Returns:
        The run folder and the finished rows, a non-finite number in them as ``None`` (a record written before
        the records were standard JSON holds ``NaN`` or ``-Infinity``, which Python reads), as a fresh row has it.

    Raises:
        ConfigError: the record exists without ``resume`` (key ``name``), is missing or unreadable with it
            (key ``resume``), has a row that is not an object with ``row_keys`` (key ``resume``, naming the row
            and the keys it lacks: a record edited by hand or written by another version), was run with other
            settings (the first differing dotted key), or with other files in ``configs/`` (key ``resume``,
            :func:`marlcrash.provenance.require_unchanged`).
    """
    check_output_dir(run_dir, "out_dir")  # the nearest existing folder of the run's
    inputs = provenance.env_inputs(load_env_config(*env))
    path = run_dir / filename
    if not resume:
        if path.exists() and _saved_rows(path) != []:  # no finished row (a first run that failed): started over
            raise ConfigError(f"{path} exists already; choose another name or resume=true", key="name")
        run_dir.mkdir(parents=True, exist_ok=True)
        provenance.write_record(run_dir, inputs)
        return run_dir, []
    if not path.is_file():
        raise ConfigError(f"resume=true but {path} does not exist", key="resume")
    rows = _saved_rows(path)
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))["config"]
    except (OSError, ValueError, KeyError, TypeError):
        rows = None
    if rows is None or not isinstance(saved, dict):
        raise ConfigError(f"resume=true but {path} cannot be read as a record of finished runs", key="resume")
    need = tuple(row_keys)
    for i, row in enumerate(rows):
        lacks = [k for k in need if k not in row] if isinstance(row, dict) else None
        if lacks is None or lacks:
            what = f"lacks {', '.join(lacks)}" if lacks else f"is {type(row).__name__}, not an object"
            raise ConfigError(f"resume=true but row {i} of {path} {what}; a finished row has {', '.join(need)} "
                              "(the record was edited, or written by another version)", key="resume")  # fmt: skip
    old, new = copy.deepcopy(saved), copy.deepcopy(config)
    for k in free_keys(rows):
        old.pop(k, None)
        new.pop(k, None)
    diff = _first_difference(old, new)
    if diff is not None:
        raise ConfigError(f"resume: {run_dir} was run with {diff} = {_lookup(saved, diff)!r}, this config "
                          f"has {_lookup(config, diff)!r}; the finished rows would not compare", key=diff)  # fmt: skip
    provenance.require_unchanged(run_dir, inputs)
    return run_dir, finite_or_null(rows)


def _start_run_dir(config: CompareConfig) -> tuple[Path, list[dict[str, Any]]]:
    """The run folder and the rows already finished in it (resume), after checking the settings agree.

    A method's own settings only define its own rows: those of methods without finished rows may differ.
    """

    def free(rows: list[dict[str, Any]]) -> list[str]:
        done = {r["method"] for r in rows}
        return [*_RESUMABLE_DIFF_OK, *(m for m in METHODS if m not in done)]

    env = (config.env, dict(config.env_overrides))
    keys = (*(c for c in COLUMNS if c not in _ADDED_COLUMNS), "metrics", "history")
    run_dir, rows = open_run_dir(config.run_dir, "compare.json", asdict(config), config.resume, free, env, keys)
    for r in rows:  # rows of a comparison started before a column was added: unknown there
        for c in _ADDED_COLUMNS:
            r.setdefault(c, None)
    return run_dir, rows


def _saved_rows(path: Path) -> list[dict[str, Any]] | None:
    """The rows of a run record (``compare.json``, ``ablate.json``); ``None`` where it cannot be read.

    An unreadable record is kept: it is not ours to overwrite.
    """
    try:
        return list(json.loads(path.read_text(encoding="utf-8"))["rows"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _lookup(d: Any, dotted: str) -> Any:
    for p in dotted.split("."):
        if not isinstance(d, dict):
            return None
        d = d.get(p)
    return d


def check_searchable(config: CompareConfig, problem: CalibrationProblem, optimizers: list[str]) -> None:
    """Refuse a problem the comparison's ``optimizers`` cannot search, naming the comparison's keys: one with no free
    coordinate (key ``masking``: :func:`~marlcrash.calibrate.baselines.check_free_coordinates`; each optimizer
    refused it as ``problem.masking``, a key of baseline runs, after the run folder was made), then a budget below
    lm's first iteration (key ``budget``: :func:`~marlcrash.calibrate.baselines.check_lm_budget`)."""
    check_free_coordinates(problem, ", ".join(optimizers), key="masking")
    if "lm" in optimizers:
        check_lm_budget(problem, config.budget)


def run_comparison(
    config: CompareConfig, command: str | None = None, progress: Callable[[str], None] | None = None
) -> tuple[Path, list[dict[str, Any]]]:
    """Run every method on every reference seed and write the results after each run (module docstring).

    Args:
        config: the comparison.
        command: the command line, recorded in the files.
        progress: optional callable told about each finished run.

    Returns:
        The run folder and all rows (finished earlier and now).

    Raises:
        ConfigError: the run folder exists (without ``resume``), or ``resume`` with other protocol settings; before
            the folder is made, a problem the optimizers cannot search (:func:`check_searchable`).
    """
    say = progress or (lambda _msg: None)
    optimizers = [m for m in config.methods if m in BASELINES]
    first = None  # the optimizers' problem is checked before the run folder is made: a refused run must not block
    if optimizers and config.seeds:  # its name
        first = build_problem(problem_config(config, config.seeds[0]))
        check_searchable(config, first, optimizers)
    with hold_run_dir(config.run_dir, config.resume, FILES):  # one process per run folder
        run_dir, rows = _start_run_dir(config)
        done = {(r["method"], r["seed"]) for r in rows}
        write_results(config, rows, run_dir, command)
        for seed in config.seeds:
            todo = [m for m in config.methods if (m, seed) not in done]
            if not todo:
                continue
            problem = (
                first if first is not None and seed == config.seeds[0] else build_problem(problem_config(config, seed))
            )
            if optimizers and problem is not first:
                check_searchable(config, problem, optimizers)
            initial = initial_score(problem)
            for method in todo:
                out = run_method(config, method, seed, problem, run_dir)
                row = outcome_row(config, problem, out, initial)
                rows.append(row)
                write_results(config, rows, run_dir, command)
                say(f"seed {seed} {method}: score {_fmt(row['score'], '.4f')} (initial "
                    f"{_fmt(row['initial_score'], '.4f')}), {row['simulations']} simulations, passed {row['passed']}, "
                    f"stop {row['stop']}, {_fmt(row['wall_time_s'], '.1f')} s")  # fmt: skip
        return run_dir, rows
