"""Ablations (DESIGN 6): masking level x scenario x action granularity x reward form x algorithm x seeds.

One command (``python train/ablate.py``) runs the full product of the factor levels in
``configs/train/ablate.yaml``, every combination (a *cell*) on every reference seed, and writes one
results table (CSV and Markdown), a JSON record and plots.

Protocol (the results table's, :mod:`marlcrash.calibrate.compare`, so the numbers compare):

- A run calibrates ONE reference: the twin of the cell's scenario drawn with reference seed ``s``; the
  run's own seed is ``s`` too. The PPO algorithm trains on an environment pinned to that reference
  (:func:`~marlcrash.calibrate.compare.run_ppo`) with the cell's masking level, action granularity and
  reward form as env settings; everything else (vehicle, agents, bounds, observation scales) is the
  same in every cell. A masking level is a mode with optional modifiers (:func:`masking_overrides`):
  ``primary+region`` restricts active agents to their in-region cells (DESIGN 1.4 per cell),
  ``+nosat`` turns the saturation preference off.
- Budget: ``budget`` simulations per run, counted as the results table counts them; a wall cap per run.
- Result of a run: the best candidate of all its simulations.
- One yardstick for every cell: candidates are ranked by the ``score`` reward form's fit score (by
  default ``log_ratio``), whatever reward the cell trained on, and tested against the ``success``
  thresholds; the metrics (area, DFD, RMSE per sensor) do not depend on the reward form at all.
  ``param_error`` is the mean relative error of every sub-assembly's parameters against the twin
  truth, masked agents' included, so a masking level that leaves part of the truth out of reach pays for
  it there; ``active_agents`` counts the agents the cell's masking level lets act on its reference, and
  ``acting_cells`` the cells their actions reach (all their cells, or with ``+region`` those in the region; a
  ``+region`` level keeps the agents and shrinks this count).
- Gain: a run's best score minus the score of the initial parameters on its reference. References
  differ in how far the initial parameters are from them (by far the largest spread between runs), so
  the gain, not the score, is what compares across scenarios and seeds.
- Paired effects: for every factor with more than one level, each level is compared with the factor's
  first level (the baseline) on runs that agree in every other factor and in the seed (same reference,
  same other settings; for the scenario factor, the same seed): the mean difference of the gain with its
  standard error (both over references, see below), how many pairs the level wins (and ties), and the geometric
  mean ratio of the worst-sensor area.
  Pairs of one reference (a scenario's seed; for the scenario factor, a seed) are not independent, so the mean and
  its standard error are taken over references, of the differences averaged per reference (a reference with more
  pairs, as in a partial or resumed ablation, does not weigh more).

:func:`run_ablation` rewrites ``ablate.json``, ``ablate.csv`` and ``ablate.md`` atomically after every
finished run and draws ``ablate.png`` at the end (a picture an earlier run left in the folder is removed when
the run starts, so with ``plots=false`` none stays beside tables it does not show), so a kill loses nothing finished;
``resume`` skips finished runs (levels and seeds may be added, the protocol may not change). A picture that cannot be
drawn (matplotlib failing) is a warning naming it; the tables, written before it, stay. As in the results table
(:mod:`marlcrash.calibrate.compare`), a non-finite number (the score and gain of a run whose every candidate
diverged) is ``None`` in a row, ``null`` in ``ablate.json``, an empty field in the CSV and ``-`` in the tables; a
run without a gain loses to a paired run with one.
"""

from __future__ import annotations

import copy
import itertools
import math
import warnings
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from marlcrash.calibrate.amortized import _fmt, pm
from marlcrash.calibrate.compare import (
    COLUMNS,
    SIMS_TO_SUCCESS,
    CompareConfig,
    PPOBudgetConfig,
    budget_algorithm,
    check_env_overrides,
    csv_text,
    hold_run_dir,
    initial_score,
    open_run_dir,
    outcome_row,
    problem_config,
    ranked,
    run_ppo,
    summarize,
)
from marlcrash.calibrate.marl import ALGORITHMS, AlgorithmConfig
from marlcrash.calibrate.problem import CalibrationProblem, SuccessConfig, build_problem
from marlcrash.cells.model import CellModel
from marlcrash.config import from_dict, merge_overrides, require, require_complete, require_seed
from marlcrash.envs.agents import AgentLayout, build_agents
from marlcrash.envs.core import EnvConfig, build_cells, load_env_config, require_env, require_env_keys_unset
from marlcrash.envs.masking import ImpactRegions
from marlcrash.errors import ConfigError
from marlcrash.outputs import finite_or_null, json_text, require_run_name, save_figure, write_text
from marlcrash.reward import load_reward_config
from marlcrash.sim.scenario import get_scenario, list_scenarios, scenario_tensors

FACTORS: tuple[str, ...] = ("algorithm", "masking", "scenario", "granularity", "reward")
"""The factors of a cell, in the order of its name (``mappo-none-offset40_left-subassembly-log_ratio``)."""

LEVEL_KEYS: dict[str, str] = {
    "algorithm": "algorithms",
    "masking": "masking",
    "scenario": "scenarios",
    "granularity": "granularity",
    "reward": "rewards",
}
"""Config key holding each factor's levels."""

ENV_KEYS: dict[str, tuple[str, ...]] = {
    "masking": ("masking.mode", "masking.cells", "masking.saturation_preference"),
    "granularity": ("granularity",),
    "reward": ("reward",),
}
"""Env-config keys each env factor sets (a masking level sets the mode and, through its modifiers, the other two)."""

MASKING_MODIFIERS: dict[str, tuple[str, Any]] = {
    "region": ("masking.cells", "region"),
    "agent": ("masking.cells", "agent"),
    "sat": ("masking.saturation_preference", True),
    "nosat": ("masking.saturation_preference", False),
}
"""Modifiers of a masking level (``primary_secondary+region+nosat``): the env key each sets and its value."""

_PROTECTED_ENV_KEYS: dict[str, str] = {
    **{keys[0]: f"the ablation's {f} factor (list its levels in {LEVEL_KEYS[f]})" for f, keys in ENV_KEYS.items()},
    **{k: "the ablation's masking factor (a level's modifier: "
          f"{', '.join(m for m, (mk, _) in MASKING_MODIFIERS.items() if mk == k)}; e.g. primary+region)"
       for k in ENV_KEYS["masking"][1:]},
    **dict.fromkeys(("scenarios", "reference.kind", "reference.pin_seed", "reference.file_scenario", "seed",
                     "termination.max_iterations"),
                    "the ablation's protocol (scenarios, seeds, ppo.episode_length)"),
}  # fmt: skip
"""Env keys the factors or the protocol set (``env_overrides`` and ``ppo.env_overrides`` may not change them; the
other ``reference`` keys, e.g. the twin spreads, are shared env settings, and ``ppo.env_overrides`` may not change
any, :class:`~marlcrash.calibrate.compare.PPOBudgetConfig`)."""

FILES = ("ablate.json", "ablate.csv", "ablate.md", "ablate.png")
"""The results a finished ablation writes into its run folder (besides ``provenance.json`` and the PPO logs)."""

CSV_COLUMNS = ("cell", *FACTORS, "active_agents", "n_agents", "acting_cells", "gain",
               *(c for c in COLUMNS if c not in ("method", "stop_reason")))  # fmt: skip
"""Columns of ``ablate.csv``, in order (the results table's columns, with the factors for ``method``; without
``stop_reason``, which only an optimizer that ends by its own rule has)."""

_ADDED_COLUMNS = ("acting_cells",)
"""Columns a finished row of an older ablation may lack (a resume reads it, the tables show ``-``)."""

_AGG_KEYS = ("gain", "score", "area_worst", "dfd_worst", "rmse_worst", "param_error", "simulations", "wall_time_s")


# ------------------------------------------------------------------------------------------- config
@dataclass
class AblationConfig:
    """One ablation; values and their meaning in ``configs/train/ablate.yaml``."""

    algorithms: list[str] = field(default_factory=lambda: ["mappo"])
    masking: list[str] = field(default_factory=lambda: ["none", "primary", "primary_secondary"])
    scenarios: list[str] = field(default_factory=lambda: ["offset40_left", "small_overlap_right"])
    granularity: list[str] = field(default_factory=lambda: ["subassembly"])
    rewards: list[str] = field(default_factory=lambda: ["log_ratio"])
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    budget: int = 1000
    max_wall_s: float | None = 300.0
    score: str = "log_ratio"
    env: str = "default"
    env_overrides: dict[str, Any] = field(default_factory=dict)
    success: SuccessConfig = field(default_factory=SuccessConfig)
    out_dir: str = "runs"
    name: str = "ablate"
    resume: bool = False
    plots: bool = True
    ppo: PPOBudgetConfig = field(default_factory=PPOBudgetConfig)
    mappo: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("mappo"))
    ippo: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("ippo"))
    ppo_single: AlgorithmConfig = field(default_factory=lambda: budget_algorithm("ppo_single"))

    def levels(self, factor: str) -> list[Any]:
        """The levels of ``factor`` (one of :data:`FACTORS`)."""
        return list(getattr(self, LEVEL_KEYS[factor]))

    def varied(self) -> list[str]:
        """Factors with more than one level."""
        return [f for f in FACTORS if len(self.levels(f)) > 1]

    def cells(self) -> list[dict[str, Any]]:
        """Every combination of the factor levels, as ``{factor: level}`` in :data:`FACTORS` order."""
        return [dict(zip(FACTORS, combo, strict=True)) for combo in itertools.product(*map(self.levels, FACTORS))]

    def validate(self) -> None:
        for factor in FACTORS:
            key = LEVEL_KEYS[factor]
            levels = self.levels(factor)
            require(len(levels) >= 1, key, f"expected at least one {factor} level")
            require(len(set(levels)) == len(levels), key, f"expected distinct levels, got {levels}")
            for i, level in enumerate(levels):  # a level is part of the cell's name and folder
                require(bool(level) and not any(c in str(level) for c in "/-\\"), f"{key}[{i}]",
                        f"expected a registered name without '/', '\\' or '-', got {level!r}")  # fmt: skip
        for i, level in enumerate(self.masking):
            try:
                masking_overrides(level)
            except ConfigError as e:
                raise ConfigError(e.reason, key=f"masking[{i}]") from None
        for i, a in enumerate(self.algorithms):
            require(a in ALGORITHMS, f"algorithms[{i}]", f"unknown algorithm {a!r}; expected one of {list(ALGORITHMS)}")
        known = list_scenarios()
        for i, s in enumerate(self.scenarios):
            require(s in known, f"scenarios[{i}]", f"unknown scenario {s!r}; registered: {known}")
        require(len(self.seeds) >= 1, "seeds", "expected at least one reference seed, e.g. [0, 1, 2]")
        for i, seed in enumerate(self.seeds):
            require_seed(seed, f"seeds[{i}]")
        require(len(set(self.seeds)) == len(self.seeds), "seeds", f"expected distinct seeds, got {self.seeds}")
        require(self.budget >= 1, "budget", f"expected a simulation budget >= 1, got {self.budget}")
        require(self.max_wall_s is None or (math.isfinite(self.max_wall_s) and self.max_wall_s > 0), "max_wall_s",
                f"expected a wall-time cap > 0 s per run or null, got {self.max_wall_s}")  # fmt: skip
        require_env(self.env, "env")
        require_run_name(self.name)
        require(bool(self.out_dir), "out_dir", "expected an output folder")
        require_env_keys_unset(self.env_overrides, _PROTECTED_ENV_KEYS)
        require_env_keys_unset(self.ppo.env_overrides, _PROTECTED_ENV_KEYS, "ppo.env_overrides")
        frames = self.ppo.n_envs * self.ppo.episode_length
        for a in self.algorithms:
            algo: AlgorithmConfig = getattr(self, a)
            require(algo.name == a, f"{a}.name", f"expected the {a} settings (name {a!r}), got name {algo.name!r}")
            require(frames % algo.minibatch_size == 0, f"{a}.minibatch_size",
                    f"expected a divisor of ppo.n_envs * ppo.episode_length = {frames} env steps, "
                    f"got {algo.minibatch_size}")  # fmt: skip
        cost = self.ppo.iteration_cost
        require(self.budget >= cost, "budget",
                f"expected at least one PPO iteration of ppo.n_envs * (ppo.episode_length + 1) = {cost} "
                f"simulations, got {self.budget}")  # fmt: skip

    @property
    def run_dir(self) -> Path:
        """``<out_dir>/ablate/<name>/``."""
        return Path(self.out_dir) / "ablate" / self.name


def masking_overrides(level: str) -> dict[str, Any]:
    """The env overrides of a masking level: ``<mode>[+<modifier>...]``.

    The mode (``none``, ``primary``, ``primary_secondary``) sets ``masking.mode``; the modifiers of
    :data:`MASKING_MODIFIERS` set what an active agent acts on (``region``: only its cells in the impact
    region, DESIGN 1.4's rule per cell; ``agent``: all its cells) and the saturation preference (``sat``,
    ``nosat``). A key no modifier sets keeps the env config's value. ``primary+region`` is the ablation of
    DESIGN 1.4's per-cell rule against ``primary``.

    Raises:
        ConfigError: an unknown modifier, two modifiers of one key, or ``region`` with mode ``none`` (where
            every cell is in the region, so it would run ``none`` again under another name); no key.
    """
    mode, *mods = str(level).split("+")
    out: dict[str, Any] = {"masking.mode": mode}
    for m in mods:
        if m not in MASKING_MODIFIERS:
            raise ConfigError(f"unknown modifier {m!r} in masking level {level!r}; expected <mode>[+<modifier>...] "
                              f"with modifiers from {list(MASKING_MODIFIERS)}")  # fmt: skip
        key, value = MASKING_MODIFIERS[m]
        if key in out:
            raise ConfigError(f"masking level {level!r} sets {key} twice; give one of its modifiers")
        out[key] = value
    if mode == "none" and out.get("masking.cells") == "region":
        raise ConfigError(f"masking level {level!r}: with mode none every cell is in the region, so +region "
                          "changes nothing; use it with primary or primary_secondary")  # fmt: skip
    return out


def masking_setting(env: EnvConfig) -> tuple[str, str, bool]:
    """What a masking level runs: ``(mode, cells, saturation_preference)`` of the env config built for it.

    Mode ``none`` acts on every cell whatever ``masking.cells`` says (its region is every cell), so its cells read
    ``agent``. Two levels with one setting are one level under two names (``primary+region+nosat`` and
    ``primary+nosat+region``; ``primary`` and ``primary+agent`` where the env config's cells are ``agent``).
    """
    m = env.masking
    return m.mode, "agent" if m.mode == "none" else m.cells, bool(m.saturation_preference)


def _masking_settings(config: AblationConfig, levels: list[str]) -> list[tuple[str, str, bool]]:
    """:func:`masking_setting` of each masking level, with the env config and overrides of ``config``'s runs."""
    over = merge_overrides(EnvConfig, config.env_overrides, config.ppo.env_overrides)
    return [masking_setting(load_env_config(config.env, {**over, **masking_overrides(lv)})) for lv in levels]


def _describe(setting: tuple[str, str, bool]) -> str:
    mode, cells, sat = setting
    return f"masking.mode {mode}, masking.cells {cells}, masking.saturation_preference {str(sat).lower()}"


def require_distinct_masking(config: AblationConfig, finished: Iterable[str] = ()) -> None:
    """Refuse a masking level that runs the setting of an earlier level, or of a finished row's level of another name.

    Its runs would repeat those runs under another row name: counted as a level of their own in the tables, and
    run again on resume where the finished rows' spelling was changed.

    Raises:
        ConfigError: naming ``masking[i]`` and the level of the same setting.
    """
    settings = _masking_settings(config, config.masking)
    for i, s in enumerate(settings):
        for j in range(i):
            if settings[j] == s:
                raise ConfigError(f"masking level {config.masking[i]!r} runs the same setting as masking[{j}] "
                                  f"{config.masking[j]!r} ({_describe(s)}); list it once",
                                  key=f"masking[{i}]")  # fmt: skip
    old = [lv for lv in dict.fromkeys(finished) if lv not in config.masking]
    for lv, s in zip(old, _masking_settings(config, old), strict=True):
        if s in settings:
            i = settings.index(s)
            raise ConfigError(f"resume: masking level {config.masking[i]!r} runs the setting of the finished rows' "
                              f"level {lv!r} ({_describe(s)}); name it {lv!r} so its finished runs are skipped "
                              "and compared", key=f"masking[{i}]")  # fmt: skip


def _runs_cells_and_agents(config: AblationConfig) -> tuple[dict[str, Any], CellModel, AgentLayout]:
    """The env overrides of the PPO runs (``env_overrides`` and ``ppo.env_overrides``), their cell model and agents
    (the masking keys change neither)."""
    over = merge_overrides(EnvConfig, config.env_overrides, config.ppo.env_overrides)
    env = load_env_config(config.env, over)
    cells = build_cells(env.vehicle, env.vehicle_seed, env.discretization, env.vehicle_options)
    return over, cells, build_agents(cells, env.agents)


def require_active_agents(config: AblationConfig) -> None:
    """Refuse a masking level under which a scenario of the ablation activates no agent (the env's own test,
    :meth:`~marlcrash.envs.masking.ImpactRegions.idle_scenarios`, with ``env_overrides`` and ``ppo.env_overrides``).

    Its runs would spend their budget with every action masked and report a gain of 0 as a result; the env only
    warns, inside each run.

    Raises:
        ConfigError: naming ``masking[i]``, the level and the scenarios it leaves idle.
    """
    levels = [(i, lv) for i, lv in enumerate(config.masking) if masking_overrides(lv)["masking.mode"] != "none"]
    if not levels:  # mode none: every agent acts
        return
    over, cells, layout = _runs_cells_and_agents(config)
    scenarios = [get_scenario(s) for s in config.scenarios]
    for i, lv in levels:
        masking = load_env_config(config.env, {**over, **masking_overrides(lv)}).masking
        idle = ImpactRegions(cells, layout, masking).idle_scenarios(scenarios)
        if idle:
            raise ConfigError(f"masking level {lv!r}: {'; '.join(idle)}; its runs would calibrate nothing (every "
                              "action masked) and report a gain of 0: lower masking.min_fraction or widen the depths "
                              "in env_overrides, or leave the level or the scenario out",
                              key=f"masking[{i}]")  # fmt: skip


def factor_overrides(cell: dict[str, Any]) -> dict[str, Any]:
    """The env overrides the env factors of ``cell`` set (:data:`ENV_KEYS`)."""
    return {**masking_overrides(cell["masking"]), "granularity": cell["granularity"], "reward": cell["reward"]}


def cell_name(cell: dict[str, Any]) -> str:
    """``algorithm-masking-scenario-granularity-reward``: the cell's folder and row name."""
    return "-".join(str(cell[f]) for f in FACTORS)


def load_ablation_config(data: dict[str, Any], source: str | None = None) -> AblationConfig:
    """Validate an ablation config mapping (e.g. Hydra's, without its ``hydra`` node).

    Every level of an env factor is loaded into the env config (with ``env_overrides`` and the PPO
    ones), so an unknown masking level (mode or modifier), granularity or reward form fails here, naming
    its list entry; so does a masking level that runs the setting of an earlier one
    (:func:`require_distinct_masking`), activates no agent on a scenario (:func:`require_active_agents`) or lets
    the same agents act on the same cells as an earlier one on every scenario (:func:`require_masking_differs`).

    Raises:
        ConfigError: unknown key, wrong type or bad value, naming the dotted key -- before any run.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if source is not None:
        require_complete(AblationConfig, data, source)
    config = from_dict(AblationConfig, data, path=source)
    check_env_overrides(config.env, config.env_overrides, config.ppo.env_overrides, source)
    over = merge_overrides(EnvConfig, config.env_overrides, config.ppo.env_overrides)
    try:
        yardstick = load_reward_config(config.score)
    except ConfigError as e:
        raise ConfigError(e.reason, key="score", path=source) from None
    for factor in ENV_KEYS:
        for i, level in enumerate(config.levels(factor)):
            try:
                set_by = masking_overrides(level) if factor == "masking" else {ENV_KEYS[factor][0]: level}
                load_env_config(config.env, {**over, **set_by})
                if factor == "reward":  # the env config names the form; its file is read when an env is built
                    measured = load_reward_config(level).metrics
                    require(measured == yardstick.metrics, "",
                            f"the reward form measures A, DFD and RMSE differently from the score form "
                            f"{config.score!r} ({measured} against {yardstick.metrics}); their scores would not "
                            "compare")  # fmt: skip
            except ConfigError as e:
                raise ConfigError(e.reason, key=f"{LEVEL_KEYS[factor]}[{i}]", path=source) from None
    try:
        require_distinct_masking(config)
        require_active_agents(config)
        require_masking_differs(config)
    except ConfigError as e:
        raise ConfigError(e.reason, key=e.key, path=source) from None
    return config


# ------------------------------------------------------------------------------------------- runs
def cell_compare_config(config: AblationConfig, cell: dict[str, Any], seed: int) -> CompareConfig:
    """The results-table config of one PPO run of ``cell`` on reference ``seed``."""
    over = {**config.env_overrides, **factor_overrides(cell)}
    algo = cell["algorithm"]
    return CompareConfig(
        methods=[algo], seeds=[seed], budget=config.budget, max_wall_s=config.max_wall_s, scenario=cell["scenario"],
        env=config.env, env_overrides=over, masking=False, success=copy.deepcopy(config.success),
        out_dir=config.out_dir, name=config.name, ppo=copy.deepcopy(config.ppo),
        **{algo: copy.deepcopy(getattr(config, algo))},
    )  # fmt: skip


def reference_problem(config: AblationConfig, scenario: str, seed: int) -> CalibrationProblem:
    """The yardstick of every cell of ``scenario`` on reference ``seed``.

    The twin of ``scenario`` drawn with ``seed``, ranked by the ``score`` form, no agent frozen (the
    parameter error covers every sub-assembly); the env factors do not change the reference.
    """
    cell = {f: config.levels(f)[0] for f in FACTORS} | {"scenario": scenario}
    pc = problem_config(cell_compare_config(config, cell, seed), seed)
    pc.fit = config.score
    return build_problem(pc)


def require_masking_differs(config: AblationConfig) -> None:
    """Refuse a masking level that lets the same agents act on the same cells as an earlier level, with the same
    saturation preference, on every scenario of the ablation; warn where they coincide on some scenarios.

    Such levels run the same calibration: on a full-width scenario ``none``, ``primary`` and ``primary_secondary``
    all activate every agent, and ``secondary_hops: 0`` makes ``primary_secondary`` ``primary``. Their rows were
    bit-identical and read as a measured effect of exactly 0 ("+0.0000, 1 tie").

    Raises:
        ConfigError: naming ``masking[i]``, the level it duplicates and what both let act.
    """
    if len(config.masking) < 2:
        return
    over, cells, layout = _runs_cells_and_agents(config)
    rows = scenario_tensors([get_scenario(s) for s in config.scenarios])
    acts = []
    for lv in config.masking:
        masking = load_env_config(config.env, {**over, **masking_overrides(lv)}).masking
        active, acting = ImpactRegions(cells, layout, masking).acting(rows["overlap"], rows["side"], rows["speed"])
        acts.append((active, acting, bool(masking.saturation_preference)))
    for i, (a_i, c_i, sat_i) in enumerate(acts):
        for j in range(i):
            a_j, c_j, sat_j = acts[j]
            if sat_i != sat_j:
                continue
            same = (a_i == a_j).all(dim=1) & (c_i == c_j).all(dim=1)  # [scenarios]
            both = [f"{s} ({int(a.sum())} of {layout.n_agents} agents, {int(c.sum())} cells acting)"
                    for s, a, c, hit in zip(config.scenarios, a_i, c_i, same, strict=True) if hit]  # fmt: skip
            if not both:
                continue
            pair = f"masking level {config.masking[i]!r} lets the same agents act on the same cells as masking[{j}] "
            pair += f"{config.masking[j]!r}"
            if bool(same.all()):
                raise ConfigError(f"{pair} on every scenario of the ablation: {'; '.join(both)}; its runs would "
                                  "repeat those runs and report an effect of exactly 0; leave one out, or add a "
                                  "scenario where they differ (an offset or small overlap) or the env_overrides "
                                  "that make them differ", key=f"masking[{i}]")  # fmt: skip
            warnings.warn(f"{pair} on {'; '.join(both)}: their runs there are the same calibration, and the effect "
                          "between them there is 0 by construction, not measured", stacklevel=2)  # fmt: skip


def masking_reach(config: AblationConfig, problem: CalibrationProblem, masking: str) -> dict[str, int]:
    """What masking level ``masking`` lets act on the problem's reference in the PPO runs' env (``ppo.env_overrides``
    may set the agents, which the problem does not see).

    Returns:
        ``active_agents`` (the agents it activates), ``n_agents`` (all agents) and ``acting_cells`` (the cells the
        active agents' actions reach: every cell they own, or with ``masking.cells: region`` their cells in the
        region, as :class:`~marlcrash.envs.core.CalibrationCore` applies them).
    """
    over = merge_overrides(EnvConfig, config.env_overrides, config.ppo.env_overrides, masking_overrides(masking))
    env = load_env_config(config.env, over)
    ref = problem.reference
    layout = build_agents(problem.cells, env.agents)
    active, acting = ImpactRegions(problem.cells, layout, env.masking).acting(ref.overlap, ref.side, ref.speed)
    return {"active_agents": int(active[0].sum()), "n_agents": layout.n_agents, "acting_cells": int(acting[0].sum())}


def run_cell(
    config: AblationConfig, cell: dict[str, Any], seed: int, problem: CalibrationProblem, run_dir: Path,
    initial: float | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Run one cell on reference ``seed`` and return its row (keys :data:`CSV_COLUMNS`, ``metrics``, ``history``).

    The PPO training log goes to ``<run folder>/runs/<cell>/ppo/<algorithm>/seed<s>/log.csv``.
    """
    cc = cell_compare_config(config, cell, seed)
    out = run_ppo(cc, cell["algorithm"], seed, problem, run_dir / "runs" / cell_name(cell))
    row = outcome_row(cc, problem, out, initial)  # a non-finite score: None
    row.pop("method")
    gain = None if row["score"] is None or row["initial_score"] is None else row["score"] - row["initial_score"]
    head = {"cell": cell_name(cell), **cell, **masking_reach(config, problem, cell["masking"]),
            "gain": finite_or_null(gain)}  # fmt: skip
    return {**head, **row}


# ----------------------------------------------------------------------------------------- tables
def aggregate_cells(rows: list[dict[str, Any]], cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per cell (in ``cells`` order, those with rows): mean and std (ddof 0) over seeds, passed, sims to success."""
    out = []
    for cell in cells:
        name = cell_name(cell)
        g = [r for r in rows if r["cell"] == name]
        if g:
            # the same for every seed; an older ablation's rows may lack acting_cells (None)
            reach = {
                k: next((r[k] for r in g if r.get(k) is not None), None) for k in ("active_agents", "acting_cells")
            }
            out.append({"cell": name, **cell, **reach, **summarize(g, _AGG_KEYS)})
    return out


def paired_effects(rows: list[dict[str, Any]], levels: dict[str, list[Any]]) -> list[dict[str, Any]]:
    """Each level of every factor with more than one level against that factor's first level (module docstring).

    Args:
        rows: finished runs.
        levels: ``{factor: levels}``; the first level is the baseline.

    Returns:
        One entry per (factor, non-baseline level): ``pairs`` (runs matched on every other factor and the
        seed), ``references`` (the references they are on: a scenario and a seed, or for the scenario factor a seed;
        pairs of one reference are not independent), ``gain_diff_mean`` and ``gain_diff_se`` (mean and standard error
        over references of the differences averaged per reference, ddof 1; ``None`` below 2 references; with the
        same number of pairs on every reference the mean is the mean over pairs),
        ``wins`` (pairs where the level gains more), ``ties`` (pairs where both gain the same, or neither has a
        gain: neither a win nor a loss), ``area_worst_ratio`` (geometric mean of the level's
        worst-sensor area over the baseline's, over the ``ratio_pairs`` pairs where both are finite
        and > 0), and ``gain_mean`` / ``baseline_gain_mean`` over the pairs. A run without a gain (``None``:
        every candidate diverged) loses to one with a gain, and leaves the means and the standard error
        without a number (``None``).
    """
    out = []
    for factor, lv in levels.items():
        if len(lv) < 2:
            continue
        others = [f for f in FACTORS if f != factor]

        def key(r: dict[str, Any], others: list[str] = others) -> tuple:
            return (*(r[f] for f in others), r["seed"])

        base = {key(r): r for r in rows if r[factor] == lv[0]}
        for level in lv[1:]:
            pairs = [(r, base[key(r)]) for r in rows if r[factor] == level and key(r) in base]
            gains = np.array([(r["gain"], b["gain"]) for r, b in pairs], dtype=np.float64).reshape(-1, 2)  # None: nan
            d = gains[:, 0] - gains[:, 1]
            whole = bool(np.isfinite(d).all())
            areas = np.array([(r["area_worst"], b["area_worst"]) for r, b in pairs], dtype=np.float64).reshape(-1, 2)
            ok = np.isfinite(areas).all(axis=1) & (areas > 0).all(axis=1)  # a ratio of zero areas says nothing
            ratio = areas[ok, 0] / areas[ok, 1]
            n = len(pairs)
            # pairs of one reference share it (the scenario's pairs at every other level share the seed's two), so
            # the error is over references: the differences averaged per reference, as independent samples
            ref = [(r["seed"],) if factor == "scenario" else (r["scenario"], r["seed"]) for r, _ in pairs]
            per_ref = np.array([d[[k == g for k in ref]].mean() for g in dict.fromkeys(ref)], dtype=np.float64)
            m = per_ref.size
            out.append(finite_or_null({
                "factor": factor, "baseline": lv[0], "level": level, "pairs": n, "references": m,
                "gain_diff_mean": float(per_ref.mean()) if n and whole else None,  # the estimator the s.e. is of
                "gain_diff_se": float(per_ref.std(ddof=1) / math.sqrt(m)) if m >= 2 and whole else None,
                "wins": sum(ranked(r["gain"]) > ranked(b["gain"]) for r, b in pairs),
                "ties": sum(ranked(r["gain"]) == ranked(b["gain"]) for r, b in pairs),
                "area_worst_ratio": float(np.exp(np.log(ratio).mean())) if ratio.size else None,
                "ratio_pairs": int(ok.sum()),
                "gain_mean": float(gains[:, 0].mean()) if n else None,
                "baseline_gain_mean": float(gains[:, 1].mean()) if n else None,
            }))  # fmt: skip
    return out


def present_levels(config: AblationConfig, rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Per factor: the config's levels that have rows, then levels only a resumed run's rows have."""
    out = {}
    for f in FACTORS:
        lv = [*config.levels(f), *sorted({r[f] for r in rows} - set(config.levels(f)), key=str)]
        out[f] = [x for x in lv if any(r[f] == x for r in rows)]
    return out


def _present_cells(config: AblationConfig, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    lv = present_levels(config, rows)
    names = {r["cell"] for r in rows}
    combos = (dict(zip(FACTORS, c, strict=True)) for c in itertools.product(*(lv[f] for f in FACTORS)))
    return [c for c in combos if cell_name(c) in names]


def markdown(config: AblationConfig, rows: list[dict[str, Any]], command: str | None, date: str) -> str:
    """``ablate.md``: protocol, paired effects, per-cell table (mean ± std over seeds), per-run table."""
    lv = present_levels(config, rows)
    cells = _present_cells(config, rows)
    agg = aggregate_cells(rows, cells)
    th = config.success
    shown = lv if rows else {f: config.levels(f) for f in FACTORS}  # before the first run: the ablation planned
    fixed = [f"{f} `{shown[f][0]}`" for f in FACTORS if len(shown[f]) == 1]
    varied = [f for f in FACTORS if len(shown[f]) > 1]
    seeds = sorted({r["seed"] for r in rows}) if rows else list(config.seeds)
    plan = {(cell_name(c), s) for c in config.cells() for s in config.seeds}
    outside = len({(r["cell"], r["seed"]) for r in rows} - plan)  # a resumed run's rows of levels or seeds dropped
    wall = "no wall cap" if config.max_wall_s is None else f"wall cap {config.max_wall_s:g} s"
    lines = ["# Ablation: masking level x scenario x action granularity x reward form", "", f"- date: {date}"]
    if command:
        lines.append(f"- command: `{command}`")
    lines += [
        f"- runs finished: {len(rows)} of {len(plan) + outside} ({len(config.cells())} cells x {len(config.seeds)} "
        "reference seeds"
        + (f", and {outside} finished earlier of levels or seeds no longer in the config" if outside else "")
        + ")",
        f"- varied: {'; '.join(f + ' (' + ', '.join(map(str, shown[f])) + ')' for f in varied) or 'nothing'}; "
        f"fixed: {', '.join(fixed) or 'nothing'}; reference seeds {seeds} (the twin of "
        "the cell's scenario drawn with the seed; the run's own seed is the same)",
        f"- every run: {config.budget} simulations of PPO training on its pinned reference ({config.ppo.n_envs} "
        f"envs x {config.ppo.episode_length} steps per iteration), {wall}; "
        "its result is the best candidate of all its simulations",
        f"- one yardstick for every cell: score = fit score of the `{config.score}` form (higher is better) "
        "whatever reward the cell trained on; gain = score minus the initial parameters' score on the same "
        f"reference; passed = every sensor {th.describe()}; {SIMS_TO_SUCCESS}; "
        "param err = mean relative error of every "
        "sub-assembly's parameters (masked ones included) against the twin truth; active = agents the masking level "
        "lets act",
        "",
    ]
    effects = paired_effects(rows, lv)
    if effects:
        lines += [
            "## Paired effects (each level against the factor's first level; pairs share every other factor "
            "and the reference seed)",
            "",
            "| factor | level vs baseline | pairs | gain difference (± s.e.) | level wins | worst-area ratio "
            "(geometric mean) | gain (level / baseline) |",
            "|---|---|---|---|---|---|---|",
        ]
        for e in effects:
            diff = _fmt(e["gain_diff_mean"], "+.4f")
            if e["gain_diff_se"] is not None:
                diff += f" ± {_fmt(e['gain_diff_se'], '.4f')}"
            ratio = _fmt(e["area_worst_ratio"], ".3f")
            wins = f"{e['wins']}/{e['pairs']}" + (
                f" ({e['ties']} tie{'s' if e['ties'] > 1 else ''})" if e["ties"] else ""
            )
            if e["area_worst_ratio"] is not None and e["ratio_pairs"] < e["pairs"]:  # a zero or missing area
                ratio += f" ({e['ratio_pairs']} of {e['pairs']} pairs)"
            pairs = f"{e['pairs']}" + (
                f" ({e['references']} reference{'s' if e['references'] > 1 else ''})"
                if e["references"] < e["pairs"]
                else ""
            )
            lines.append(
                f"| {e['factor']} | {e['level']} vs {e['baseline']} | {pairs} | {diff} | {wins} "
                f"| {ratio} | {_fmt(e['gain_mean'], '.4f')} / "
                f"{_fmt(e['baseline_gain_mean'], '.4f')} |"
            )
        lines.append("")

    lines += [
        "## Per cell (mean ± std over reference seeds; population std, ddof 0"
        + ("; a single seed: no std (-))" if any(a["seeds"] < 2 for a in agg) else ")"),
        "",
        "| " + " | ".join(FACTORS) + " | active | acting cells | passed | gain | score | area worst [m] "
        "| DFD worst [m/s] | RMSE worst [m/s] | param err | median sims to success | wall [s] | note |",
        "|" + "---|" * (len(FACTORS) + 12),
    ]
    for a in agg:
        note = f"stopped by wall cap ({a['wall_capped']}/{a['seeds']})" if a["wall_capped"] else ""
        lines.append(
            "| " + " | ".join(str(a[f]) for f in FACTORS) + f" | {a['active_agents']} | {_fmt(a['acting_cells'])} | "
            f"{a['passed']}/{a['seeds']} | "
            f"{pm(a, 'gain')} | {pm(a, 'score')} | {pm(a, 'area_worst')} | {pm(a, 'dfd_worst')} | "
            f"{pm(a, 'rmse_worst')} | "
            f"{pm(a, 'param_error', '.3f')} | {_fmt(a['sims_to_success_median'], '.0f')} | "
            f"{pm(a, 'wall_time_s', '.1f')} | {note} |"
        )
    lines += [
        "",
        "## Per run",
        "",
        "| cell | seed | simulations | stop | gain | score | initial score | area worst [m] | DFD worst [m/s] "
        "| RMSE worst [m/s] | passed | sims to success | param err | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = [cell_name(c) for c in cells]
    for r in sorted(rows, key=lambda r: (order.index(r["cell"]), r["seed"])):
        stop = "stopped by wall cap" if r["stop"] == "wall_cap" else r["stop"]
        lines.append(
            f"| {r['cell']} | {r['seed']} | {r['simulations']} | {stop} | {_fmt(r['gain'])} | {_fmt(r['score'])} | "
            f"{_fmt(r['initial_score'])} | {_fmt(r['area_worst'])} | {_fmt(r['dfd_worst'])} | "
            f"{_fmt(r['rmse_worst'])} | "
            f"{_fmt(r['passed'])} | {_fmt(r['sims_to_success'])} | {_fmt(r['param_error'], '.3f')} | "
            f"{_fmt(r['wall_time_s'], '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def write_results(config: AblationConfig, rows: list[dict[str, Any]], run_dir: Path, command: str | None) -> None:
    """Rewrite ``ablate.json``, ``ablate.csv`` and ``ablate.md`` in ``run_dir`` atomically."""
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lv = present_levels(config, rows)
    cells = aggregate_cells(rows, _present_cells(config, rows))
    payload = {"date": date, "command": command, "config": asdict(config), "rows": rows, "cells": cells,
               "effects": paired_effects(rows, lv)}  # fmt: skip
    write_text(run_dir / "ablate.json", json_text(payload))  # standard JSON: non-finite numbers as null
    write_text(run_dir / "ablate.csv", csv_text(rows, CSV_COLUMNS))
    write_text(run_dir / "ablate.md", markdown(config, rows, command, date))


# ------------------------------------------------------------------------------------------- plots
def best_so_far_curve(history: list[list[float]], grid: np.ndarray) -> np.ndarray:
    """A run's best score after each simulation count of ``grid`` (NaN before its first candidate).

    ``history`` is the results table's ``[[simulations, best score], ...]`` record (best so far after
    that many simulations, increasing); a best score without a number (``None``: every candidate so far
    diverged) is NaN.
    """
    sims = np.array([h[0] for h in history], dtype=np.float64)
    best = np.array([h[1] for h in history], dtype=np.float64)
    idx = np.searchsorted(sims, grid, side="right") - 1
    return np.where(idx >= 0, best[np.clip(idx, 0, None)], np.nan) if sims.size else np.full(grid.shape, np.nan)


def plot_ablation(config: AblationConfig, rows: list[dict[str, Any]], path: Path) -> Path:
    """``ablate.png``: per varied factor, the runs' gains per level and the mean best-so-far gain curves.

    One column per factor with more than one level (one column for the single cell if none varies): on
    top every run's gain (best score minus the initial score; dots) and the level means (lines); below
    the gain so far against the simulations spent, averaged over the runs of each level. As in the tables, a level
    with a run without a gain (every candidate diverged) has no mean: no line on top, none below, and its legend
    entry says how many runs lack one.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lv = present_levels(config, rows)
    varied = [f for f in FACTORS if len(lv[f]) > 1] or [FACTORS[0]]
    budget = max([config.budget, *(r["simulations"] for r in rows)])
    grid = np.linspace(0, budget, 201)
    fig, axes = plt.subplots(2, len(varied), figsize=(4.2 * len(varied), 6.4), squeeze=False)
    rng = np.random.default_rng(0)  # dot jitter only
    for j, factor in enumerate(varied):
        top, bottom = axes[0, j], axes[1, j]
        for i, level in enumerate(lv[factor]):
            g = [r for r in rows if r[factor] == level]
            gains = np.array([r["gain"] for r in g], dtype=np.float64)  # None (no gain: diverged): nan, no dot
            if np.isfinite(gains).all():  # as the tables: no mean where a run has no gain
                top.hlines(gains.mean(), i - 0.3, i + 0.3, color=f"C{i}", linewidth=2.5)
            top.scatter(i + rng.uniform(-0.18, 0.18, gains.size), gains, color=f"C{i}", s=14, zorder=3)
            initial = np.array([r["initial_score"] for r in g], dtype=np.float64)[:, None]
            curves = np.array([best_so_far_curve(r["history"], grid) for r in g]) - initial
            curves[~np.isfinite(curves)] = np.nan  # a diverged best so far: no number
            # as the tables: a mean where every run of the level has a number (a run without a gain: nowhere)
            mean = curves.mean(axis=0)
            lost = int((~np.isfinite(gains)).sum())
            note = f", {lost} without a gain: no mean" if lost else ""
            bottom.plot(grid, mean, color=f"C{i}", label=f"{level} ({len(g)} runs{note})")
        top.set_xticks(range(len(lv[factor])), [str(x) for x in lv[factor]], rotation=15, fontsize=8)
        top.set_title(f"{factor}: gain of each run", fontsize=9)
        top.set_ylabel(f"best - initial fit score ({config.score})", fontsize=8)
        bottom.set_xlabel("simulations", fontsize=8)
        bottom.set_ylabel("gain so far (mean over runs)", fontsize=8)
        bottom.legend(fontsize=7)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return save_figure(fig, path, key="out_dir")


# ------------------------------------------------------------------------------------------- driver
_RESUMABLE_DIFF_OK = (*LEVEL_KEYS.values(), "seeds", "resume", "out_dir", "plots")
"""Settings a resumed ablation may change: levels and seeds may be added; the rest is the protocol."""


def run_ablation(
    config: AblationConfig, command: str | None = None, progress: Callable[[str], None] | None = None
) -> tuple[Path, list[dict[str, Any]]]:
    """Run every cell on every reference seed and write the results after each run (module docstring).

    Runs go seed by seed, so a stopped ablation has whole comparisons of the first seeds.

    Args:
        config: the ablation.
        command: the command line, recorded in the files.
        progress: optional callable told about each finished run.

    Returns:
        The run folder and all rows (finished earlier and now).

    Raises:
        ConfigError: the run folder exists (without ``resume``), or ``resume`` with other protocol settings, or
            a masking level that renames the setting of finished rows (:func:`require_distinct_masking`).
    """
    say = progress or (lambda _msg: None)

    def free(rows: list[dict[str, Any]]) -> list[str]:  # an algorithm's settings only define its own rows
        done = {r["algorithm"] for r in rows}
        return [*_RESUMABLE_DIFF_OK, *(a for a in ALGORITHMS if a not in done)]

    env = (config.env, dict(config.env_overrides))
    with hold_run_dir(config.run_dir, config.resume, FILES):  # one process per run folder
        keys = (*(c for c in CSV_COLUMNS if c not in _ADDED_COLUMNS), "metrics", "history")
        run_dir, rows = open_run_dir(config.run_dir, "ablate.json", asdict(config), config.resume, free, env, keys)
        for r in rows:  # rows of an ablation started before a column was added: unknown there
            for c in _ADDED_COLUMNS:
                r.setdefault(c, None)
        require_distinct_masking(config, [r["masking"] for r in rows])
        done = {(r["cell"], r["seed"]) for r in rows}
        # an earlier run's picture is not this run's: drawn anew at the end (plots), else none stays beside the tables
        (run_dir / "ablate.png").unlink(missing_ok=True)
        write_results(config, rows, run_dir, command)
        cells = config.cells()
        for seed in config.seeds:
            for scenario in config.scenarios:
                todo = [c for c in cells if c["scenario"] == scenario and (cell_name(c), seed) not in done]
                if not todo:
                    continue
                problem = reference_problem(config, scenario, seed)
                initial = initial_score(problem)
                saved = {r["initial_score"] for r in rows if r["scenario"] == scenario and r["seed"] == seed}
                # same settings, yet another reference or metric: configs/ changed (a non-finite score: None in rows)
                if saved and saved != {finite_or_null(initial)}:
                    raise ConfigError(f"resume: the initial parameters score {initial!r} on the {scenario} "
                                      f"reference of seed {seed}, the finished runs of {run_dir} recorded "
                                      f"{sorted(saved)}; the config files or the simulator changed since, so the "
                                      "rows would not compare", key="resume")  # fmt: skip
                for cell in todo:
                    row = run_cell(config, cell, seed, problem, run_dir, initial)
                    rows.append(row)
                    write_results(config, rows, run_dir, command)
                    say(f"seed {seed} {row['cell']}: score {_fmt(row['score'], '.4f')} (initial "
                        f"{_fmt(row['initial_score'], '.4f')}), worst area {_fmt(row['area_worst'])} m, "
                        f"{row['simulations']} simulations, "
                        f"{row['active_agents']}/{row['n_agents']} agents active ({row['acting_cells']} cells), "
                        f"stop {row['stop']}, "
                        f"{_fmt(row['wall_time_s'], '.1f')} s")  # fmt: skip
        if config.plots and rows:
            _draw(config, rows, run_dir / "ablate.png")
        return run_dir, rows


def _draw(config: AblationConfig, rows: list[dict[str, Any]], path: Path) -> None:
    """:func:`plot_ablation` to ``path`` (whole or not at all) after the tables are written; a failure of the picture
    (matplotlib, its backend, a full disk) is a warning naming it, not a traceback that hides the finished tables."""
    try:
        plot_ablation(config, rows, path)
    except Exception as e:  # the rows are in ablate.json, ablate.csv and ablate.md already
        warnings.warn(f"{path} was not drawn: {type(e).__name__}: {e}; the results are in "
                      f"{path.with_name('ablate.json')}, ablate.csv and ablate.md beside it", stacklevel=3)  # fmt: skip
