"""Amortized calibration, measured (DESIGN 6): a trained policy against optimizers started from scratch.

A policy trained on many randomized twin references should calibrate an *unseen* reference in a
few iterations, where an optimizer starts from scratch every time. :func:`amortized_comparison`
measures that on held-out twin references (``reference_seeds``; each must differ from the run's
evaluation seed ``eval.reference_seed``, from its training seed, whose generator draws the
training references, and from ``reference.pin_seed`` of a run trained on that one reference):

- the trained policy alone (:func:`~marlcrash.calibrate.evaluate.evaluate_policy`, the mean action)
  for ``iterations`` calibration steps; it uses ``iterations + 1`` simulations (the reset simulates the
  initial parameters, then one per step), the same accounting as the baselines, whose first candidate
  is the initial point. Rows ``policy_best`` (best iterate by fit score, a passing one before any other) and
  ``policy_last``;
- every optimizer of ``budgets`` (:data:`~marlcrash.calibrate.baselines.BASELINES`: CMA-ES, random
  search, gradient descent) on the SAME reference (:func:`~marlcrash.calibrate.evaluate.evaluation_problem`
  with that seed; the reference pulses are checked to agree), one fresh run per budget. A budget is a
  multiple of the policy's nominal simulation count ``iterations + 1``. Each row reports the best
  candidate's metrics and ``sims_to_policy``: the simulations after which the optimizer's best score
  first reached the policy's target score (``target``: its best or last iterate), resolved to the
  optimizer's batch (a CMA-ES generation, a random-search batch, a gradient step), ``None`` if never.

``wall_time_s`` times the calibration alone: the policy's from its env's reset (the draw of the twin reference, the
initial simulation, then its steps: :attr:`~marlcrash.calibrate.evaluate.EvalResult.wall_time_s`), an optimizer's
from its start on the problem already built (its initial simulation, then its candidates); building the env or the
problem (vehicle, cells, simulator) is in neither.

Metrics in the tables are sensor means (area [m], DFD [m/s], RMSE [m/s]); ``score`` is the reward
form's fit score (higher is better); ``passed``: every sensor below every success threshold
(``eval.thresholds`` of the run); ``param_error``: mean relative error of the per-sub-assembly
``E_x``, ``E_s`` and transmission factors against the twin's truth; ``generations`` (CSV and JSON rows): the
CMA-ES generations a run completed (:attr:`~marlcrash.calibrate.baselines.CalibrationResult.generations`), ``None``
for the other methods; 0 where the budget is below ``1 + popsize`` (a random sample around the start), marked
:data:`NO_GENERATION` in the Markdown tables with a footnote.

:func:`write_comparison` writes ``amortized.csv`` (one row per reference and method/budget),
``amortized.md`` (per-reference and aggregated tables: mean and standard deviation over
references) and ``amortized.json`` (standard JSON: a non-finite number, e.g. the score of a run whose every
candidate diverged, is ``null``; an empty field in the CSV, ``-`` in the tables) atomically into a folder (by
default the run folder). The script
writes them after every finished piece too (``meta.complete`` false, the Markdown says *incomplete*), so an
optimizer that fails or a kill keeps what finished; ``resume=true`` continues such a comparison in its folder
(:func:`read_comparison`, ``done=`` of :func:`amortized_comparison`), running only the pieces it lacks; ``meta.configs``
(the digests of the files of ``configs/`` the simulations read) refuses a resume after one of them changed.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import hashlib
import io
import json
import logging
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from tensordict.nn import TensorDictModuleBase

from marlcrash import provenance
from marlcrash.calibrate.baselines import (
    BASELINES,
    CalibrationResult,
    CMAESConfig,
    GradientConfig,
    RandomSearchConfig,
)
from marlcrash.calibrate.budget import best_index, ranked_scores
from marlcrash.calibrate.checkpoint import CHECKPOINT_FILE, load_training_checkpoint
from marlcrash.calibrate.evaluate import (
    EvalResult,
    evaluate_policy,
    evaluation_problem,
    param_errors,
    policy_from_checkpoint,
)
from marlcrash.calibrate.marl import TrainConfig, load_run_config, make_env_config, require_same_run
from marlcrash.calibrate.problem import CalibrationProblem
from marlcrash.calibrate.runlock import hold_output_dir
from marlcrash.config import MAX_STEPS, checked, from_dict, require, require_complete, require_seed
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics
from marlcrash.outputs import check_output_dir, finite_or_null, json_text, write_text
from marlcrash.sim import adjoint
from marlcrash.sim.scenario import list_scenarios
from marlcrash.sim.surrogate import load_sim_config

log = logging.getLogger(__name__)

_OWN_CHECKPOINT = "expected the checkpoint this run wrote; use another run's policy in its own folder (run=<folder>)"

POLICY_METHODS = ("policy_best", "policy_last")
"""Row names of the policy: its best iterate by fit score and its last iterate."""

FILES = ("amortized.csv", "amortized.md", "amortized.json")
"""What :func:`write_comparison` writes."""

COLUMNS = (
    "reference_seed", "method", "multiplier", "budget", "simulations", "generations", "iteration", "area", "dfd",
    "rmse", "score", "initial_score", "passed", "param_error", "initial_param_error", "sims_to_policy", "wall_time_s",
)  # fmt: skip
"""Columns of ``amortized.csv``, in order (the keys of the rows of ``amortized.json``)."""

NO_GENERATION = "†"
"""Mark of the Markdown tables' CMA-ES rows that completed no generation (``generations`` 0), with a footnote."""


# ------------------------------------------------------------------------------------------- config
MAX_BUDGET = 2**53
"""Most simulations a budget may have: the best-score history counts them in float64, exact up to 2**53."""

DEFAULT_BUDGETS = {"cmaes": [1.0, 10.0, 40.0], "random_search": [1.0, 10.0], "gradient": [1.0, 10.0, 40.0]}
"""``budgets`` of ``configs/train/amortized.yaml``, the default of an :class:`AmortizedConfig` made in Python."""


@dataclass
class AmortizedConfig:
    """One comparison; values and their meaning in ``configs/train/amortized.yaml``.

    Attributes:
        run: the trained run folder (``config.yaml``, ``checkpoint.pt``); ``None`` only when a policy is passed.
        reference_seeds: held-out twin seeds (not the run's evaluation, training or pinned reference seed).
        scenario: evaluation scenario (registered name).
        iterations: policy calibration steps; ``None`` = the run's ``eval.iterations``.
        target: the policy iterate whose score the optimizers must reach: ``best`` or ``last``.
        budgets: per optimizer, budgets as multiples of the policy's nominal simulation count ``iterations + 1``
            (at least one each, of distinct budgets once rounded; an optimizer left out is skipped, but at least one
            must stay).
        seed: the optimizers' seed.
        out_dir: folder of the output files; ``None`` = the run folder.
        resume: continue the comparison in that folder: its finished pieces are kept, the others run.
        random_search, cmaes, gradient: the optimizers' settings (``configs/train/baseline/``).
    """

    run: str | None = None
    reference_seeds: list[int] = field(default_factory=lambda: [101, 102, 103])
    scenario: str = "full_width_40"
    iterations: int | None = 12
    target: Literal["best", "last"] = "best"
    budgets: dict[str, list[float]] = field(default_factory=lambda: {k: list(v) for k, v in DEFAULT_BUDGETS.items()})
    seed: int = 0
    out_dir: str | None = None
    resume: bool = False
    random_search: RandomSearchConfig = field(default_factory=RandomSearchConfig)
    cmaes: CMAESConfig = field(default_factory=CMAESConfig)
    gradient: GradientConfig = field(default_factory=GradientConfig)

    def validate(self) -> None:
        # '' (run= on the command line) was the launch folder: the run found there, the tables written there
        for key, like in (("run", ", e.g. run=runs/mappo/<name>"), ("out_dir", " or null (the run folder)")):
            require(getattr(self, key) != "", key, f"expected a folder{like}, got an empty one")
        require(len(self.reference_seeds) >= 1, "reference_seeds", "expected at least one held-out reference seed")
        require(len(set(self.reference_seeds)) == len(self.reference_seeds), "reference_seeds",
                f"expected distinct seeds, got {self.reference_seeds}")  # fmt: skip
        for i, s in enumerate(self.reference_seeds):
            require_seed(s, f"reference_seeds[{i}]")
        known = list_scenarios()
        require(self.scenario in known, "scenario", f"unknown scenario {self.scenario!r}; registered: {known}")
        require(self.iterations is None or 1 <= self.iterations <= MAX_STEPS, "iterations",
                f"expected 1 to 2**63 - 1 (MAX_STEPS) calibration steps or null, got {self.iterations}")  # fmt: skip
        optimizers = sorted(f.name for f in fields(self) if f.name in BASELINES)  # those with settings here
        # with none, the tables held the policy alone under "policy vs optimizers", nothing to compare it with
        require(len(self.budgets) >= 1, "budgets",
                f"expected at least one optimizer of {optimizers} with budgets, got none: the comparison measures the "
                f"policy against optimizers from scratch. To keep the policy's rows on the held-out references at "
                f"little cost, keep one with a small budget (e.g. budgets.random_search=[1]: as many simulations as "
                f"the policy's); to evaluate the policy alone on its run's reference: python train/evaluate.py "
                f"run=<run>")  # fmt: skip
        for name, mults in self.budgets.items():
            require(name in optimizers, f"budgets.{name}",
                    f"unknown optimizer {name!r}; expected one of {optimizers}")  # fmt: skip
            # an empty list ran nothing for the optimizer while its settings went into the comparison's meta
            require(len(mults) >= 1, f"budgets.{name}",
                    f"expected at least one budget multiple, got []; leave the optimizer out to skip it "
                    f"(command line: ~budgets.{name})")  # fmt: skip
            for i, m in enumerate(mults):
                require(math.isfinite(m) and m > 0, f"budgets.{name}[{i}]",
                        f"expected a budget multiple > 0 of the policy's simulations, got {m}")  # fmt: skip
                # rows are aggregated per (optimizer, multiple): a repeated one merged its runs ("reached 6/3")
                require(m not in mults[:i], f"budgets.{name}[{i}]",
                        f"expected distinct budget multiples, got {m} twice in {mults}")  # fmt: skip

        if self.iterations is not None:  # else the run's eval.iterations: checked by amortized_comparison
            self.check_budgets(self.iterations + 1)
        # the optimizers' generators: numpy refused a negative seed only after the policy had run
        require_seed(self.seed, "seed")
        if self.out_dir is not None:  # before any work, not at the end; a missing folder is made when writing
            check_output_dir(self.out_dir, "out_dir")

    def budget(self, multiplier: float, policy_sims: int) -> int:
        """Simulations of a budget: ``max(1, round(multiplier * policy_sims))``."""
        return max(1, round(multiplier * policy_sims))

    def check_budgets(self, policy_sims: int) -> None:
        """Refuse a multiple whose budget is beyond :data:`MAX_BUDGET` simulations (``1e308`` overflowed to
        ``inf``: an ``OverflowError`` after the policy had run), or whose budget is that of an earlier multiple of the
        same optimizer (``[1, 1.1]`` x 3 simulations: 3 twice, one budget run twice and tabled as two).

        Raises:
            ConfigError: (key ``budgets.<optimizer>[i]``) the first such multiple.
        """
        for name, mults in self.budgets.items():
            seen: dict[int, int] = {}  # budget -> index of the first multiple giving it
            for i, m in enumerate(mults):
                require(m * policy_sims <= MAX_BUDGET, f"budgets.{name}[{i}]",
                        f"a budget of {m:g} x {policy_sims} simulations is beyond 2**53 = {MAX_BUDGET}, the largest "
                        f"count the best-score history (float64) holds exactly; expected a multiple <= "
                        f"{MAX_BUDGET / policy_sims:g}")  # fmt: skip
                b = self.budget(m, policy_sims)
                if b in seen:
                    j = seen[b]
                    raise ConfigError(f"{m:g} x {policy_sims} simulations rounds to a budget of {b} simulations, as "
                                      f"budgets.{name}[{j}] ({mults[j]:g} x {policy_sims}) does; expected multiples "
                                      f"of distinct budgets (budget: max(1, round(multiple x {policy_sims})))",
                                      key=f"budgets.{name}[{i}]")  # fmt: skip
                seen[b] = i


def load_amortized_config(data: dict[str, Any], source: str | None = None) -> AmortizedConfig:
    """Validate a comparison config mapping (e.g. Hydra's, without its ``hydra`` node).

    Raises:
        ConfigError: unknown key, wrong type or bad value, naming the dotted key.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if source is not None:
        require_complete(AmortizedConfig, data, source)
    return from_dict(AmortizedConfig, data, path=source)


# ------------------------------------------------------------------------------------------ policy
def load_policy(run_dir: str | Path) -> tuple[TensorDictModuleBase, TrainConfig, provenance.ProvenanceCheck]:
    """The trained policy of a run folder (its latest checkpoint), the run's config, and what changed since the run
    started (:func:`marlcrash.provenance.check_run`; logged as warnings: a policy trained on other physics still
    calibrates).

    Raises:
        ConfigError: (key ``run``) no such folder, or no ``config.yaml`` / ``checkpoint.pt`` in it, or a
            ``checkpoint.pt`` written under other settings than the ``config.yaml`` (another run's file of the same
            network shapes), naming the first setting that differs.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        what = "is a file" if run_dir.exists() else "does not exist"  # run=<run>/checkpoint.pt: it exists
        raise ConfigError(f"{run_dir} {what}; expected a training run folder", key="run")
    config = load_run_config(run_dir, device="cpu")  # the policy runs on the CPU: a GPU-trained run is read here
    check = provenance.check_run(run_dir, provenance.env_inputs(make_env_config(config)), key=None)
    provenance.warn_changes(run_dir, check, "amortized")  # a policy trained on other physics still calibrates
    if not (run_dir / CHECKPOINT_FILE).is_file():
        raise ConfigError(f"expected a run folder with {CHECKPOINT_FILE}, found none in {run_dir}", key="run")
    path = run_dir / CHECKPOINT_FILE
    state = load_training_checkpoint(path, key="run")
    policy = policy_from_checkpoint(config, state, path, key="run")
    require_same_run(state.get("config"), config, path, "run", hint=_OWN_CHECKPOINT)  # same shapes, another run's
    return policy, config, check


def held_out_config(train_config: TrainConfig, seed: int, scenario: str, iterations: int) -> TrainConfig:
    """A copy of the run's config whose evaluation is twin ``seed`` of ``scenario`` for ``iterations`` steps."""
    cfg = copy.deepcopy(train_config)
    cfg.eval.reference = "twin"  # held-out twins, with their truth, whatever the run trained against
    cfg.eval.reference_seed = seed
    cfg.eval.scenario = scenario
    cfg.eval.iterations = iterations
    cfg.eval.select = "best"
    return cfg


# -------------------------------------------------------------------------------------------- rows
def _mean_param_error(table: dict[str, dict[str, float]] | None) -> float | None:
    """Mean of all ``{sub-assembly: {E_x, E_s, transmission}}`` relative errors."""
    if table is None:
        return None
    return float(np.mean([v for sub in table.values() for v in sub.values()]))


def _sensor_mean(m: Metrics) -> dict[str, float]:
    """Sensor means of per-sensor metrics ``[K]``."""
    return {"area": float(m.area.mean()), "dfd": float(m.dfd.mean()), "rmse": float(m.rmse.mean())}


def policy_rows(
    problem: CalibrationProblem, result: EvalResult, seed: int, wall_time_s: float | None
) -> list[dict[str, Any]]:
    """Rows ``policy_best`` and ``policy_last`` of one reference (scores by the problem's fit, as the baselines)."""
    scores = ranked_scores(problem.score(result.metrics))  # [I + 1]; a NaN never wins, as in the evaluation
    passed = problem.success(result.metrics)  # [I + 1]
    sims = result.iterations + 1
    rows = []
    for method, i in (("policy_best", best_index(scores, passed)), ("policy_last", result.iterations)):
        m = Metrics(*(t[i] for t in result.metrics))
        err = init_err = None
        if result.true_params is not None:
            err = _mean_param_error(param_errors(problem, result.params[i], result.true_params))
            init_err = _mean_param_error(param_errors(problem, result.params[0], result.true_params))
        rows.append({
            "reference_seed": seed, "method": method, "multiplier": None, "budget": sims, "simulations": sims,
            "generations": None, "iteration": i, **_sensor_mean(m), "score": float(scores[i]),
            "initial_score": float(scores[0]),
            "passed": bool(passed[i]), "param_error": err, "initial_param_error": init_err, "sims_to_policy": None,
            "wall_time_s": wall_time_s,
        })  # fmt: skip
    return rows


def sims_to_reach(history: np.ndarray, target: float) -> int | None:
    """Simulations after which the best score so far first reached ``target`` (``None``: never).

    Args:
        history: ``[H, 3]`` simulations, best score so far, batch best score (:attr:`CalibrationResult.history`).
        target: the score to reach (higher is better).
    """
    hit = np.nonzero(history[:, 1] >= target)[0]
    return int(history[hit[0], 0]) if hit.size else None


def baseline_row(
    problem: CalibrationProblem, result: CalibrationResult, seed: int, multiplier: float, budget: int, target: float
) -> dict:
    """One optimizer run on one reference as a table row (``passed``: its best candidate passes)."""
    passed = bool(problem.success(Metrics(*(m[None] for m in result.final_metrics)))[0])
    return {
        "reference_seed": seed, "method": result.method, "multiplier": multiplier, "budget": budget,
        "simulations": result.simulations, "generations": result.generations, "iteration": None,
        **_sensor_mean(result.final_metrics),
        "score": result.best_score, "initial_score": result.initial_score,
        "passed": passed, "param_error": _mean_param_error(result.param_error),
        "initial_param_error": _mean_param_error(result.initial_param_error),
        "sims_to_policy": sims_to_reach(result.history, target), "wall_time_s": result.wall_time_s,
    }  # fmt: skip


# ------------------------------------------------------------------------------------- comparison
@dataclass
class Comparison:
    """Outcome of :func:`amortized_comparison`.

    Attributes:
        rows: one dict per reference and method/budget (keys :data:`COLUMNS`).
        aggregate: one dict per method/budget: means and standard deviations over references.
        meta: run folder, scenario, iterations, policy simulations, target, seeds, optimizer settings.
    """

    rows: list[dict[str, Any]]
    aggregate: list[dict[str, Any]]
    meta: dict[str, Any]


def amortized_comparison(
    config: AmortizedConfig,
    policy: TensorDictModuleBase | None = None,
    train_config: TrainConfig | None = None,
    progress: Any = None,
    partial: Callable[[Comparison], None] | None = None,
    done: Comparison | None = None,
) -> Comparison:
    """Compare the trained policy with optimizers from scratch on held-out twin references (module docstring).

    Args:
        config: the comparison settings (``config.run`` names the run folder unless ``policy`` is given).
        policy: a trained policy (e.g. ``Trainer.policy``); requires ``train_config``.
        train_config: the config it was trained with.
        progress: optional callable ``progress(message: str)`` told about each finished piece.
        partial: optional callable given the comparison so far after each finished piece (the policy on a
            reference, one optimizer run), its ``meta["complete"]`` false; e.g. :func:`write_comparison` with
            ``replace=True``, so a failure or a kill later keeps what finished.
        done: an earlier, interrupted comparison (:func:`read_comparison`) to continue: its rows of the pieces this
            config asks for are kept, in their places, and only the missing pieces run; the policy and the settings
            must be its own (:func:`resume_mismatch`; reference seeds and budgets may be added, not left out where they
            have rows). Every
            piece is a fresh, seeded run, so the result equals an uninterrupted comparison's.

    Returns:
        A :class:`Comparison` (``meta["complete"]`` true).

    Raises:
        ConfigError: a ``config`` made in Python with a bad value (checked as a file's, naming the key), no run
            folder (key ``run``) or a checkpoint replaced every time it was read (a run that still
            trains checkpointing faster than the policy is read), a reference seed that is not held out (key
            ``reference_seeds[i]``), a policy without its training config, or gradient budgets with
            ``gradient.backend: adjoint`` on a simulator the adjoint does not cover (the run's float32
            ``sim_dtype``, springback relief; key ``gradient.backend``), or a ``done`` comparison of another
            policy, other settings or other files of ``configs/``, or one with rows of reference seeds or budgets
            this config leaves out (key ``resume``), all before any simulation.
    """
    config = checked(config)  # one made in Python skipped the checks a file's values get (target "lats": "last")
    changes = digest = None  # a policy given as an object: its run's files are not known
    if policy is None:
        if config.run is None:
            raise ConfigError("expected a training run folder (or a policy and its training config)", key="run")
        for _ in range(READ_TRIES):  # a run that still trains replaces checkpoint.pt: record the policy read
            digest = _checkpoint_digest(config.run)
            policy, train_config, check = load_policy(config.run)
            if _checkpoint_digest(config.run) == digest:
                break
        else:
            raise ConfigError(
                f"{Path(config.run) / CHECKPOINT_FILE} was replaced each of the {READ_TRIES} times its policy was read "
                "(the run still trains); compare it once it has stopped",
                key="run",
            )
        changes = check.as_dict()
    elif train_config is None:
        raise ConfigError("a policy needs the training config it was trained with", key="train_config")
    if "gradient" in config.budgets and config.gradient.backend == "adjoint":  # the problems' simulator, as built
        why = adjoint.unsupported(load_sim_config(overrides={"dtype": make_env_config(train_config).sim_dtype}))
        if why is not None:  # it failed at the first gradient run, after the policy and the other optimizers
            raise ConfigError(f"the run's simulator: {why} (gradient.backend=torch)", key="gradient.backend")
    pin = make_env_config(train_config).reference.pin_seed  # a run trained on one reference: that one's seed
    for i, s in enumerate(config.reference_seeds):
        if s == pin:
            raise ConfigError(f"seed {s} is the reference the run trained on (reference.pin_seed), not held out",
                              key=f"reference_seeds[{i}]")  # fmt: skip
        if s == train_config.eval.reference_seed:
            raise ConfigError(f"seed {s} is the run's evaluation reference (eval.reference_seed), not held out",
                              key=f"reference_seeds[{i}]")  # fmt: skip
        if s == train_config.seed:
            raise ConfigError(f"seed {s} is the run's training seed (its reference generator), not held out",
                              key=f"reference_seeds[{i}]")  # fmt: skip
    iterations = config.iterations if config.iterations is not None else train_config.eval.iterations
    nominal = iterations + 1
    config.check_budgets(nominal)  # before any simulation: the run's eval.iterations is known only now
    say = progress or (lambda _msg: None)
    inputs = provenance.env_inputs(make_env_config(train_config))
    meta = {
        "run": None if config.run is None else str(config.run),
        "algorithm": train_config.algorithm.name,
        "scenario": config.scenario,
        "iterations": iterations,
        "policy_simulations": nominal,
        "target": config.target,
        "reference_seeds": list(config.reference_seeds),
        "eval_reference_seed": train_config.eval.reference_seed,
        "train_seed": train_config.seed,
        "optimizer_seed": config.seed,
        "budgets": {k: list(v) for k, v in config.budgets.items()},
        "optimizers": {k: asdict(getattr(config, k)) for k in config.budgets},
        "thresholds": asdict(train_config.eval.thresholds),
        "checkpoint_sha256": digest if digest is not None or config.run is None else _checkpoint_digest(config.run),
        # the files the simulations read (simulator, cells, scenarios, reward), the code and the libraries, as a run's
        # provenance.json holds them: a resume after a file changed mixed physics (resume_mismatch)
        "record": provenance.record(inputs),
        "provenance": changes,  # configs or code changed since the policy's run started
        "complete": False,  # every reference and budget finished
    }
    kept: dict[tuple[int, str, Any], dict[str, Any]] = {}  # (reference seed, method, multiplier) -> row
    if done is not None:
        why = resume_mismatch(done.meta, meta, inputs)
        if why is not None:
            raise ConfigError(f"cannot continue the comparison: {why}", key="resume")
        kept = {(r["reference_seed"], r["method"], r["multiplier"]): r for r in done.rows}
        # the comparison is rewritten with the pieces asked for: finished rows of others would be deleted from disk
        gone_seeds = sorted({s for s, _, _ in kept} - set(config.reference_seeds))
        gone: dict[str, list[Any]] = {}
        for s, method, m in kept:
            if s in config.reference_seeds and method not in POLICY_METHODS and m not in config.budgets.get(method, []):
                gone.setdefault(method, []).append(m)
        if gone_seeds or gone:
            said = "; ".join([f"reference_seeds: {gone_seeds}"] if gone_seeds else []
                             + [f"budgets.{k}: [{', '.join(f'{m:g}' for m in sorted(set(v)))}]"
                                for k, v in gone.items()])  # fmt: skip
            raise ConfigError(
                f"cannot continue the comparison: it has finished rows this config leaves out ({said}), and a resume "
                "rewrites amortized.json with the rows asked for; add them back or start a new one in another folder",
                key="resume",
            )
    rows: list[dict[str, Any]] = []

    def finished_piece() -> None:
        if partial is not None:
            partial(Comparison(rows=list(rows), aggregate=aggregate(rows), meta=copy.deepcopy(meta)))

    for seed in config.reference_seeds:
        cfg = held_out_config(train_config, seed, config.scenario, iterations)
        pieces = [(name, m) for name, mults in config.budgets.items() for m in mults]
        pol = [kept[(seed, method, None)] for method in POLICY_METHODS if (seed, method, None) in kept]
        policy_kept = len(pol) == len(POLICY_METHODS)
        if policy_kept and all((seed, name, m) in kept for name, m in pieces):
            rows += pol + [kept[(seed, name, m)] for name, m in pieces]  # the whole reference finished before
            finished_piece()
            say(f"seed {seed}: kept from the earlier comparison")
            continue
        problem = evaluation_problem(cfg)
        if policy_kept:
            say(f"seed {seed}: policy kept from the earlier comparison")
        else:
            result = evaluate_policy(policy, cfg)
            if problem.ref_velocity.shape != result.ref_velocity.shape or not torch.allclose(
                problem.ref_velocity, result.ref_velocity, rtol=0, atol=1e-9
            ):
                raise ConfigError(f"the policy's env and the optimizers' problem drew different references for "
                                  f"seed {seed}", key="reference_seeds")  # fmt: skip
            pol = policy_rows(problem, result, seed, result.wall_time_s)
            say(f"seed {seed}: policy best score {_fmt(pol[0]['score'])} in {pol[0]['simulations']} simulations")
        rows += pol
        finished_piece()
        target = pol[0 if config.target == "best" else 1]["score"]
        for name, m in pieces:
            if (seed, name, m) in kept:
                rows.append(kept[(seed, name, m)])
                continue
            _, fn = BASELINES[name]
            b = config.budget(m, nominal)
            res = fn(problem, b, getattr(config, name), config.seed, False)
            rows.append(baseline_row(problem, res, seed, m, b, target))
            finished_piece()
            say(f"seed {seed}: {name} budget {b}: best score {_fmt(res.best_score)} ({res.wall_time_s:.1f} s)")
    meta["complete"] = True
    return Comparison(rows=rows, aggregate=aggregate(rows), meta=meta)


READ_TRIES = 3
"""Times :func:`amortized_comparison` reads a run's policy, while another checkpoint replaces the one it read."""


def _checkpoint_digest(run_dir: str | Path) -> str | None:
    """SHA-256 of the run's ``checkpoint.pt`` (which policy the rows are of), ``None`` without one."""
    path = Path(run_dir) / CHECKPOINT_FILE
    if not path.is_file():
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


RESUME_FREE = ("run", "reference_seeds", "budgets", "optimizers", "configs", "record", "provenance", "complete")
"""Entries of ``meta`` a resumed comparison may change: how the run folder is spelled (``checkpoint_sha256`` names
the policy), which pieces it asks for (the settings of the optimizers both ask for are compared), what changed since
the policy's run started, and whether it finished. ``record`` (the provenance of the input files, code and
libraries; ``configs``, the input files' digests, in a comparison written before it) is compared as a training
resume compares its run's ``provenance.json``."""


def resume_mismatch(earlier: dict[str, Any], now: dict[str, Any], inputs: Iterable[str | Path] = ()) -> str | None:
    """Why the rows of comparison ``earlier`` (its ``meta``) cannot stand in a comparison with ``now``'s settings,
    or ``None``: the policy (checkpoint digest), every setting a row depends on and the input files (``configs/``
    and ``inputs``, those outside it: :func:`marlcrash.provenance.env_inputs`) must be equal.

    The files are compared as :func:`marlcrash.provenance.require_unchanged` compares a training run's: a deck named
    by a relative path is followed into a moved project, a file added since is one the rows did not read; changed
    code or libraries are logged as warnings. A comparison written before either record is not checked on them."""

    def settings(meta: dict[str, Any]) -> dict[str, Any]:
        meta = json.loads(json_text(meta))  # as the JSON holds it
        out = {k: v for k, v in meta.items() if k not in RESUME_FREE}
        return out | {f"optimizers.{k}": v for k, v in (meta.get("optimizers") or {}).items()}

    a, b = settings(earlier), settings(now)
    differ = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k) and not (k.startswith("optimizers.")
              and (k not in a or k not in b))]  # fmt: skip
    files: list[str] = []
    if "record" in earlier:
        try:
            check = provenance.check_record(earlier["record"], inputs)
        except ValueError as e:
            return f"its record of the input files cannot be read ({e})"
        files = check.configs
        for change in check.code:
            log.warning("amortized resume: %s since the comparison started", change)
    elif isinstance(earlier.get("configs"), dict):  # written before the full record: the input files' digests
        files = provenance.config_changes(earlier["configs"], provenance.config_digests(inputs))
    files = [c for c in files if not c.endswith(" added")]  # a file added since is one the earlier rows did not read
    if not differ and not files:
        return None
    said = "; ".join([f"{k}: {a.get(k)!r} then, {b.get(k)!r} now" for k in differ] + files)
    return (
        f"its rows were made with other settings, another policy or other input files ({said}); restore them or "
        "start a new one in another folder"
    )


def read_comparison(out_dir: str | Path) -> Comparison:
    """The comparison in ``out_dir``'s ``amortized.json`` (finished or not), to continue with ``done=``.

    A number written as ``null`` because it was not finite is read back as the comparison held it: a score as
    ``-inf`` (no candidate's simulation gave one), a metric as NaN. Rows written before the ``generations`` column get
    it as a fresh run gives it (:func:`_generations`), so an older comparison resumes with every row alike.

    Raises:
        ConfigError: (key ``resume``) no ``amortized.json`` there, or one that is not a comparison's (its columns, or
            values the tables cannot be made of).
    """
    path = Path(out_dir) / "amortized.json"
    if not path.is_file():
        raise ConfigError(f"no comparison to continue in {Path(out_dir)} (no amortized.json)", key="resume")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        rows, meta = record["rows"], record["meta"]
        if not isinstance(meta, dict):
            raise ValueError(f"expected an object as meta, got {type(meta).__name__}")
        older = set(COLUMNS) - {"generations"}  # written before the column
        if not (isinstance(rows, list) and all(isinstance(r, dict) and set(r) in (set(COLUMNS), older) for r in rows)):
            raise ValueError(f"expected rows with the columns {list(COLUMNS)}")
        rows = [{k: r[k] if k in r else _generations(r, meta) for k in COLUMNS} for r in rows]
        for r in rows:  # the keys a resume matches rows by: a bad one failed formatting it, or was never matched
            _check_row_key(r)
        for r in rows:
            for k, gone in (("area", math.nan), ("dfd", math.nan), ("rmse", math.nan), ("score", -math.inf),
                            ("initial_score", -math.inf)):  # fmt: skip
                if r[k] is None:
                    r[k] = gone
        table = aggregate(rows)  # here: a damaged value failed deep in numpy ("could not convert string to float")
    except (ValueError, KeyError, TypeError) as e:
        raise ConfigError(
            f"{path} is not a comparison this tool wrote: {type(e).__name__}: {e}", key="resume"
        ) from None
    return Comparison(rows=rows, aggregate=table, meta=meta)


def _check_row_key(row: dict[str, Any]) -> None:
    """Raise ``ValueError`` unless ``row``'s ``reference_seed``, ``method`` and ``multiplier`` are a comparison's: an
    integer seed, a policy row (no multiplier) or one of an optimizer the comparison runs, with a multiple > 0."""
    seed, method, mult = row["reference_seed"], row["method"], row["multiplier"]
    optimizers = [f.name for f in fields(AmortizedConfig) if f.name in BASELINES]
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"expected a reference_seed >= 0, got {seed!r}")
    if method in POLICY_METHODS:
        if mult is not None:
            raise ValueError(f"expected no multiplier in a {method} row, got {mult!r}")
    elif method not in optimizers:
        raise ValueError(f"expected a method of {[*POLICY_METHODS, *optimizers]}, got {method!r}")
    elif isinstance(mult, bool) or not isinstance(mult, (int, float)) or not (math.isfinite(mult) and mult > 0):
        raise ValueError(f"expected a budget multiplier > 0 in a {method} row, got {mult!r}")


def _generations(row: dict[str, Any], meta: dict[str, Any]) -> int | None:
    """The ``generations`` of a row of a comparison written before that column: a CMA-ES run tells CMA-ES every whole
    population after its start and nothing else, so ``(simulations - 1) // popsize`` (``popsize`` of ``meta``'s CMA-ES
    settings, which a resume must share); ``None`` for the other methods."""
    if row["method"] != "cmaes":
        return None
    return (int(row["simulations"]) - 1) // int(meta["optimizers"]["cmaes"]["popsize"])


def aggregate(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method and budget multiple: means and standard deviations (ddof 0) over references; the std is ``None``
    where fewer than two references have a value.

    Also ``passed`` (references passing), ``reached`` (references where the optimizer reached the
    policy's target score), ``beats_policy`` (references where its best score is at least the
    policy's best score) and the median ``sims_to_policy`` over the references that reached it.
    """
    best = {r["reference_seed"]: r["score"] for r in rows if r["method"] == "policy_best"}
    groups: dict[tuple[str, Any], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], r["multiplier"]), []).append(r)
    out = []
    for (method, mult), g in groups.items():
        a: dict[str, Any] = {"method": method, "multiplier": mult, "references": len(g)}
        for k in ("budget", "simulations", "area", "dfd", "rmse", "score", "param_error", "wall_time_s"):
            v = np.array([r[k] for r in g if r[k] is not None], dtype=np.float64)
            a[f"{k}_mean"] = float(v.mean()) if v.size else None
            a[f"{k}_std"] = float(v.std()) if v.size >= 2 else None  # one value has no spread (0 is not measured)
        a["passed"] = sum(bool(r["passed"]) for r in g)
        if method in POLICY_METHODS:
            a["reached"] = a["beats_policy"] = a["sims_to_policy_median"] = None
        else:
            hit = [r["sims_to_policy"] for r in g if r["sims_to_policy"] is not None]
            a["reached"] = len(hit)
            a["sims_to_policy_median"] = float(np.median(hit)) if hit else None
            a["beats_policy"] = sum(r["score"] >= best[r["reference_seed"]] for r in g)
        out.append(a)
    return out


# ----------------------------------------------------------------------------------------- writing
def _fmt(v: Any, spec: str = ".4g") -> str:
    """``v`` for a Markdown table: ``-`` for ``None`` and for a non-finite number (written as ``null`` to the JSON
    record, so a resumed table shows what the first one did), ``yes``/``no`` for a bool."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if spec == ".0f" and math.isfinite(v) and not v.is_integer():  # a median of two counts: 2.5, not "2"
            spec = ".1f"
        return format(v, spec)
    return str(v)


def pm(a: dict[str, Any], k: str, spec: str = ".4g") -> str:
    """``mean ± std`` of an aggregate's ``<k>_mean`` and ``<k>_std`` (:func:`aggregate`, and the results table's and
    the ablation's :func:`marlcrash.calibrate.compare.summarize`), ``-`` for ``None``: no number, or a std of fewer
    than two values (the population std of one value is 0, not a measured spread)."""
    return f"{_fmt(a[f'{k}_mean'], spec)} ± {_fmt(a[f'{k}_std'], spec)}"


def _label(method: str, mult: Any) -> str:
    return method if mult is None else f"{method} {_fmt(mult, 'g')}x"


def markdown(comparison: Comparison, command: str | None = None, date: str | None = None) -> str:
    """The Markdown report: settings, aggregated table (mean ± std over references), per-reference table."""
    meta = comparison.meta
    n = len(meta["reference_seeds"])
    measured = len({r["reference_seed"] for r in comparison.rows})  # an incomplete table: those with rows so far
    over = n if measured == n else f"{measured} of {n}"
    lines = [
        f"# Amortized calibration: trained {meta['algorithm']} policy vs optimizers from scratch",
        "",
        f"- date: {date or datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}",
    ]
    if command:
        lines.append(f"- command: `{command}`")
    if not meta.get("complete", True):
        done = sorted({r["reference_seed"] for r in comparison.rows})
        lines.append(f"- **incomplete**: the rows finished so far (references {done} of {meta['reference_seeds']}); "
                     "the comparison is still running, or it stopped")  # fmt: skip
    lines += [
        f"- run: `{meta['run']}`; scenario `{meta['scenario']}`; held-out twin seeds {meta['reference_seeds']} "
        f"(evaluation seed {meta['eval_reference_seed']}, training seed {meta['train_seed']})",
        f"- policy: {meta['iterations']} deterministic steps = {meta['policy_simulations']} simulations "
        "(initial + one per step); optimizers: one fresh run per budget, budgets as multiples of that count, "
        f"seed {meta['optimizer_seed']}",
        "- metrics: sensor means of the best candidate (area [m], DFD [m/s], RMSE [m/s]); score: fit score, "
        "higher is better; param err: mean relative error of the sub-assembly parameters vs the twin truth",
        "- wall: seconds of the calibration alone; the policy's from its env's reset (the reference draw, the initial "
        "simulation, its steps), an optimizer's from its start on a problem already built; neither building the "
        "env nor the problem is counted",
        f"- sims to policy: simulations until the optimizer's best score reached the policy's {meta['target']} "
        "score, resolved to the optimizer's batch (CMA-ES generation, random-search batch, gradient step); "
        "- = never within the budget",
        "",
        f"## Aggregate over {over} references (mean ± std; population std, ddof 0)",
        "",
        "| method | budget | area | DFD | RMSE | score | param err | passed | reached policy | median sims to policy "
        "| beats policy best | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def of_n(v: int | None, a: dict[str, Any]) -> str:  # out of the references the row has (all, once complete)
        return "-" if v is None else f"{v}/{a['references']}"

    idle = {(r["method"], r["multiplier"]) for r in comparison.rows if r.get("generations") == 0}

    def label(method: str, mult: Any) -> str:
        return _label(method, mult) + (f" {NO_GENERATION}" if (method, mult) in idle else "")

    for a in comparison.aggregate:
        budget = _fmt(a["budget_mean"], ".0f")
        lines.append(
            f"| {label(a['method'], a['multiplier'])} | {budget} | {pm(a, 'area')} | {pm(a, 'dfd')} | "
            f"{pm(a, 'rmse')} | {pm(a, 'score')} | {pm(a, 'param_error', '.3f')} | {of_n(a['passed'], a)} | "
            f"{of_n(a['reached'], a)} | {_fmt(a['sims_to_policy_median'], '.0f')} | "
            f"{of_n(a['beats_policy'], a)} | {pm(a, 'wall_time_s', '.1f')} |"
        )
    popsize = (meta.get("optimizers") or {}).get("cmaes", {}).get("popsize")
    footnote = [] if not idle else [
        "",
        f"{NO_GENERATION} CMA-ES completed no generation: a budget below 1 + cmaes.popsize ({1 + popsize}) simulates "
        "the start and part of one population, which CMA-ES never learns from (a random sample around the start; "
        "generations 0 in the CSV and JSON)",
    ]  # fmt: skip
    lines += [*footnote,
        "",
        "## Per reference",
        "",
        "| seed | method | simulations | area | DFD | RMSE | score | initial score | param err | passed "
        "| sims to policy | wall [s] |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in comparison.rows:
        mark = f" {NO_GENERATION}" if r.get("generations") == 0 else ""
        lines.append(
            f"| {r['reference_seed']} | {_label(r['method'], r['multiplier'])}{mark} | {r['simulations']} | "
            f"{_fmt(r['area'])} | {_fmt(r['dfd'])} | {_fmt(r['rmse'])} | {_fmt(r['score'])} | "
            f"{_fmt(r['initial_score'])} | {_fmt(r['param_error'], '.3f')} | {_fmt(r['passed'])} | "
            f"{_fmt(r['sims_to_policy'])} | {_fmt(r['wall_time_s'], '.1f')} |"
        )
    return "\n".join(lines) + "\n"


def csv_text(comparison: Comparison) -> str:
    """The rows as CSV (columns :data:`COLUMNS`; ``None`` and non-finite numbers as an empty field, as the JSON
    record has them as ``null``)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(COLUMNS), lineterminator="\n")
    w.writeheader()
    for r in comparison.rows:
        w.writerow({k: csv_field(r[k]) for k in COLUMNS})
    return buf.getvalue()


def csv_field(v: Any) -> Any:
    """``v`` as a CSV field: empty for ``None`` and for a non-finite number (``inf``, ``nan``: no number)."""
    return "" if finite_or_null(v) is None else v


def check_comparison_dir(out_dir: str | Path) -> Path:
    """``out_dir`` if it can take a new comparison: not a file, and holding no earlier ``amortized.json``.

    A second run into the same folder (by default the run folder) replaced the first one's tables without a word;
    ``compare`` and ``ablate`` refuse an existing name the same way.

    Raises:
        ConfigError: (key ``out_dir``) a file in the way, or an earlier comparison there.
    """
    out = check_output_dir(out_dir, "out_dir")
    if (out / "amortized.json").exists():
        raise ConfigError(
            f"{out} already holds a comparison (amortized.json); give another folder (out_dir=...) or move that one "
            "away: it would be replaced",
            key="out_dir",
        )
    return out


COMPARISON_LOCK = ".amortized.lock"
"""The lock file in a comparison's folder while a comparison writes it (:func:`hold_comparison_dir`); not the run's
own ``.lock`` (:data:`~marlcrash.calibrate.runlock.LOCK_FILE`), since the folder may be that of a run still training."""


@contextlib.contextmanager
def hold_comparison_dir(out_dir: str | Path, key: str = "out_dir", create: bool = True) -> Iterator[Path]:
    """One comparison per folder: hold ``out_dir``'s :data:`COMPARISON_LOCK` for the ``with`` block (made where
    missing with ``create``, and removed again if the block fails leaving it empty); yields the folder.

    Two comparisons into one folder at once (the jobs of a parallel multirun launcher with the default ``out_dir``, a
    second ``resume=true``) both passed :func:`check_comparison_dir` before either wrote, then replaced each other's
    files after every piece. The temporary files a kill left writing :data:`FILES` are removed here.

    Raises:
        ConfigError: (key ``key``) another process holds the folder (with its process id), or it takes no lock file.
    """
    with hold_output_dir(out_dir, key, COMPARISON_LOCK, FILES, create=create) as out:
        yield out


def write_comparison(
    comparison: Comparison, out_dir: str | Path, command: str | None = None, replace: bool = False
) -> dict[str, Path]:
    """Write :data:`FILES` into ``out_dir`` atomically (each file replaced whole; the folder made if missing);
    return their paths. An earlier comparison there is refused unless ``replace``.

    Raises:
        ConfigError: (key ``out_dir``) ``out_dir`` or an ancestor is a file, the folder cannot be written, or it
            holds an earlier comparison (:func:`check_comparison_dir`).
    """
    out = check_output_dir(out_dir, "out_dir") if replace else check_comparison_dir(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    payload = {"date": date, "command": command, "meta": comparison.meta, "aggregate": comparison.aggregate,
               "rows": comparison.rows}  # fmt: skip
    paths = {name: out / name for name in FILES}
    write_text(paths["amortized.csv"], csv_text(comparison))
    write_text(paths["amortized.md"], markdown(comparison, command, date))
    write_text(paths["amortized.json"], json_text(payload))  # standard JSON: non-finite numbers as null
    return paths
