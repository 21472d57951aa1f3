"""Evaluation of a trained calibration policy on one reference (DESIGN 6; paper Table 3).

:func:`evaluate_policy` runs the policy *deterministically* (the mean action of its
TanhNormal) for ``eval.iterations`` calibration steps on a single environment reset with a
fixed seed in the evaluation scenario (default: the env's reference kind, the twin reference at
``full_width_40``, seed 0 -- the same twin the baselines calibrate with ``reference_seed: 0``), and records the
per-sensor metrics and the parameters after every iteration. The reported calibration is the
``best`` iterate by the reward form's score, one that passes ``eval.thresholds`` before any other (a calibration
engineer keeps the best fit seen; :func:`select_iterate`) or the ``last`` one (``eval.select``); ``summary.json``
says which (``selected_iteration``).

:func:`evaluate_run` writes into a run folder:

- ``summary.json``: ``final_metrics`` (selected iterate) and ``initial_metrics`` per sensor
  ``{area, dfd, rmse}`` [m, m/s, m/s], ``last_metrics``, ``selected_iteration``, ``passed``
  against the thresholds (paper Table 3, best iteration I5), ``env_steps``, ``simulations``,
  ``wall_time_s``, ``env_steps_per_s``, ``param_error`` and ``initial_param_error`` per
  sub-assembly ``{E_x, E_s, transmission}`` (relative errors against the twin's truth; a twin only);
- ``eval_metrics.csv`` and ``eval_metrics.md``: the three metrics and the paper's reward factor
  ``1/A + 1/DFD + 1/RMSE`` per iteration and sensor (Table 3's layout);
- ``calibrated.npz``: initial, selected, true and per-iteration cell parameters ``[n_cells, 7]``;
- ``pulses.png`` (reference vs initial vs calibrated acceleration and velocity per sensor, as
  compared) and ``learning_curves.png`` (from ``log.csv``).

The reference is of the kind the run trained against (``eval.reference: env``): a run trained against
measured tests (``reference.kind: file``) is evaluated on the test of ``eval.scenario`` (``reference`` and
``reference_source`` in the summary name it), with no parameter errors, as a test has no known truth.
``eval.reference`` picks another kind.

Any kept checkpoint can be evaluated later (``python train/evaluate.py run=<run> checkpoint=<iteration>``;
training keeps one every ``snapshot_every`` iterations); those files go into ``<run>/eval/<checkpoint>/``
(:func:`eval_name`), and so does a re-evaluation of the latest checkpoint with other settings (``iterations=40``:
``<run>/eval/checkpoint_steps40/``) or after the run's inputs or the code changed: the run's own results stay.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import json
import numbers
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from marlcrash import provenance
from marlcrash.calibrate.budget import best_index, ranked_scores
from marlcrash.calibrate.checkpoint import (
    CHECKPOINT_FILE,
    SNAPSHOT_DIR,
    find_checkpoint,
    load_training_checkpoint,
    snapshot_path,
)
from marlcrash.calibrate.logging import LOG_FILE, read_log
from marlcrash.calibrate.marl import (
    TrainConfig,
    act,
    float32_default,
    load_run_config,
    make_env,
    make_env_config,
    make_policy,
    require_fits,
    require_same_run,
)
from marlcrash.calibrate.problem import (
    CalibrationProblem,
    ProblemConfig,
    SuccessConfig,
    build_problem,
    env_backends,
)
from marlcrash.calibrate.runlock import run_lock
from marlcrash.config import MAX_STEPS, flatten_overrides, from_dict, require, require_complete
from marlcrash.envs import EnvConfig
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics
from marlcrash.outputs import (
    atomic_output,
    check_output_dir,
    json_text,
    remove_temporaries_of,
    save_figure,
    write_text,
)
from marlcrash.references import require_file_scenario
from marlcrash.reward import paper_factor
from marlcrash.units import G0

if TYPE_CHECKING:
    from marlcrash.calibrate.marl import Trainer

SUMMARY_FILE = "summary.json"
"""Name of the evaluation summary inside a run folder."""
EVAL_FILES = (
    SUMMARY_FILE,
    "eval_metrics.csv",
    "eval_metrics.md",
    "calibrated.npz",
    "pulses.png",
    "learning_curves.png",
)
"""Files :func:`evaluate_run` writes into the folder it evaluates into (each through :func:`atomic_output`)."""
KEPT_SUMMARY_KEY = "process_wall_time_s"
"""Summary entry written by the training script, kept when a run is evaluated again."""
EVAL_DIR = "eval"
"""Folder of a run that holds the evaluations of kept checkpoints, one sub-folder per checkpoint."""
LOG_COLUMNS = ("iteration", "env_steps", "env_steps_per_s", "reward_mean", "return_mean",
               *(f"{k}_{w}" for k in ("area", "dfd", "rmse") for w in ("initial", "final")))  # fmt: skip
"""Columns of ``log.csv`` that the evaluation reads (summary and learning curves)."""


@dataclass
class EvaluateRunConfig:
    """What ``train/evaluate.py`` evaluates; values and their meaning in ``configs/train/evaluate.yaml``."""

    run: str | None = None
    checkpoint: str = "latest"
    iterations: int | None = None

    def validate(self) -> None:
        require(bool(self.run), "run", "expected a run folder, e.g. run=runs/mappo/<name>")
        require(bool(self.checkpoint), "checkpoint", "expected latest, an iteration or a checkpoint file")
        require(self.iterations is None or 1 <= self.iterations <= MAX_STEPS, "iterations",
                f"expected 1 to 2**63 - 1 (MAX_STEPS) calibration steps or null, got {self.iterations}")  # fmt: skip


def load_evaluate_config(data: dict[str, Any], source: str | None = None) -> EvaluateRunConfig:
    """Validate an evaluation config mapping (Hydra's, without its ``hydra`` node); an integer checkpoint
    (``checkpoint=40`` on the command line) names the snapshot kept after that iteration.

    Raises:
        ConfigError: unknown key, wrong type or bad value, naming the key.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if source is not None:  # values live in the file: a key left out of it is named, not defaulted
        require_complete(EvaluateRunConfig, data, source)
    if isinstance(data.get("checkpoint"), int) and not isinstance(data.get("checkpoint"), bool):
        data["checkpoint"] = str(data["checkpoint"])
    return from_dict(EvaluateRunConfig, data, path=source)


@dataclass
class EvalResult:
    """Deterministic calibration of one reference by a policy, ``I`` iterations, ``K`` sensors.

    Attributes:
        sensors: ``[K]`` sensor names.
        metrics: per-iteration :class:`Metrics`, each ``[I + 1, K]`` (row 0: initial parameters).
        scores: ``[I + 1]`` reward-form scores (higher is better).
        params: ``[I + 1, n_cells, 7]`` cell parameters after each iteration (row 0: initial).
        selected: index of the reported iterate (``best`` score or ``last``).
        select: ``best`` or ``last``.
        true_params: ``[n_cells, 7]`` the twin's hidden truth (``None`` for other references).
        ref_velocity: ``[K, T]`` the reference velocity [m/s].
        scenario: the evaluation scenario's name; ``seed``: its reset seed.
        reference: the reference kind (``twin``, ``cross_fidelity``, ``file``); ``source``: its origin
            (:attr:`marlcrash.references.ReferenceBatch.source`: ``twin``, the fine model, the test's path).
        wall_time_s: seconds of the calibration [s]: from the env's reset (the reference draw and the initial
            simulation) to the last step, building the env left out, as an optimizer's clock starts on a problem
            already built (:attr:`~marlcrash.calibrate.baselines.CalibrationResult.wall_time_s`); ``None`` where a
            result is made otherwise.
    """

    sensors: list[str]
    metrics: Metrics
    scores: torch.Tensor
    params: torch.Tensor
    selected: int
    select: str
    true_params: torch.Tensor | None
    ref_velocity: torch.Tensor
    scenario: str
    seed: int
    reference: str = "twin"
    source: str = "twin"
    wall_time_s: float | None = None

    @property
    def iterations(self) -> int:
        """Calibration steps taken (``I``)."""
        return self.params.shape[0] - 1

    def per_sensor(self, i: int) -> dict[str, dict[str, float]]:
        """``{sensor: {area, dfd, rmse}}`` of iterate ``i``."""
        return Metrics(*(t[i] for t in self.metrics)).per_sensor(self.sensors)


def evaluation_reference(config: TrainConfig) -> Literal["twin", "cross_fidelity", "file"]:
    """The evaluation's reference kind: ``eval.reference``, or for ``env`` the kind the run trained against.

    Raises:
        ConfigError: a file reference with no test of ``eval.scenario`` in ``reference.files`` (key ``eval.scenario``).
    """
    kind = config.eval.reference
    if kind == "env" or kind == "file":
        ref = make_env_config(config).reference
        kind = ref.kind if kind == "env" else kind
        if kind == "file":
            require(bool(ref.files), "eval.reference", "the file reference needs tests in the env's reference.files")
            require_file_scenario(ref, config.eval.scenario, "eval.scenario")
    return kind


def evaluation_overrides(config: TrainConfig) -> dict[str, Any]:
    """Env overrides of the evaluation: one scenario, its reference kind, ``eval.iterations`` steps."""
    kind = evaluation_reference(config)
    over: dict[str, Any] = {
        "scenarios": {config.eval.scenario: 1.0},
        "reference.kind": kind,
        "termination.max_iterations": config.eval.iterations,
        "reference.pin_seed": None,  # the reset seed is eval.reference_seed, as the problem's draw (a pinned
    }  # training reference would replace it in the env only, and the two would differ)
    # the test of the evaluation scenario, of a set that may hold several load cases; none for a simulated reference
    over["reference.file_scenario"] = config.eval.scenario if kind == "file" else None
    return over


def select_iterate(metrics: Metrics, scores: torch.Tensor, thresholds: SuccessConfig, select: str) -> int:
    """The reported iterate of per-iterate metrics ``[I, K]`` and ``scores [I]``: the ``last``, or the ``best``: the
    highest-scoring one that passes ``thresholds`` where any does, else the highest-scoring one, as a run's record
    ranks its candidates (:func:`~marlcrash.calibrate.budget.best_index`)."""
    if select == "last":
        return int(scores.shape[0]) - 1
    return best_index(scores, thresholds.passes(metrics))


@float32_default()
def evaluate_policy(policy: TensorDictModuleBase, config: TrainConfig) -> EvalResult:
    """Run the policy's mean action for ``eval.iterations`` steps on the evaluation reference (module docstring).

    Stops early if the environment's own termination (success or failure) ends the episode.
    """
    ev = config.eval
    env = make_env(config, n_envs=1, overrides=evaluation_overrides(config))
    core = env.core
    metrics, params = [], []
    t0 = time.perf_counter()  # the calibration, not the env's construction (EvalResult.wall_time_s)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset(seed=ev.reference_seed)
        metrics.append(Metrics(*(m[0].clone() for m in core.metrics)))
        params.append(core.params[0].clone())
        for _ in range(ev.iterations):
            td = env.step(act(policy, td))
            metrics.append(Metrics(*(m[0].clone() for m in core.metrics)))
            params.append(core.params[0].clone())
            if bool(td.get(("next", "done")).any()):
                break
            td = td.get("next")
    wall = time.perf_counter() - t0
    m = Metrics(*(torch.stack([x[j] for x in metrics]) for j in range(3)))
    scores = ranked_scores(core.reward_fn.score(m))
    selected = select_iterate(m, scores, ev.thresholds, ev.select)
    truth = None if core.true_params is None else core.true_params[0].clone()
    return EvalResult(
        sensors=list(core.sensors), metrics=m, scores=scores, params=torch.stack(params), selected=selected,
        select=ev.select, true_params=truth, ref_velocity=core.ref_velocity[0].clone(), scenario=ev.scenario,
        seed=ev.reference_seed, reference=core.config.reference.kind, source=core.source[0], wall_time_s=wall,
    )  # fmt: skip


def reference_label(result: EvalResult) -> str:
    """``twin seed 0``, ``cross_fidelity uniform:seed=None``, ``test ../tests/x.csv``: what was calibrated against."""
    if result.reference == "twin":
        return f"twin seed {result.seed}"
    if result.reference == "file":
        return f"test {result.source}"
    return f"{result.reference} {result.source}"


def evaluation_problem(config: TrainConfig) -> CalibrationProblem:
    """The baselines' :class:`CalibrationProblem` of the same reference (simulator, truth, sub-assembly sums)."""
    env_cfg = make_env_config(config)
    kind = evaluation_reference(config)
    over = flatten_overrides(EnvConfig, config.env_overrides)  # the evaluation's kind, not the training's
    over["reference.kind"] = kind
    over.pop("reference.file_scenario", None)  # the problem's file test is the one of its scenario
    pc = ProblemConfig(env=config.env, env_overrides=over, scenario=config.eval.scenario, reference=kind,
                       reference_seed=config.eval.reference_seed, fit=env_cfg.reward,
                       success=config.eval.thresholds, **env_backends(env_cfg))  # fmt: skip
    return build_problem(pc)


# ----------------------------------------------------------------------------------------- metrics
def param_errors(problem: CalibrationProblem, params: torch.Tensor, truth: torch.Tensor) -> dict[str, dict[str, float]]:
    """``{sub-assembly: {E_x, E_s, transmission}}`` relative errors of cell parameters ``[n_cells, 7]``.

    The baselines' definition (:meth:`CalibrationProblem.params_error`), so the numbers compare.
    """
    err = problem.params_error(params[None], truth)[0]
    return {s: {"E_x": float(err[i, 0]), "E_s": float(err[i, 1]), "transmission": float(err[i, 2])}
            for i, s in enumerate(problem.subassembly_names)}  # fmt: skip


def metrics_rows(result: EvalResult) -> list[dict[str, Any]]:
    """One row per iteration and sensor (plus ``mean`` over sensors): area, dfd, rmse, paper factor."""
    rows = []
    m = result.metrics
    for i in range(result.iterations + 1):
        names = [*result.sensors, "mean"]
        for k, s in enumerate(names):
            if s == "mean":
                a, d, r = (float(x[i].mean()) for x in m)
            else:
                a, d, r = float(m.area[i, k]), float(m.dfd[i, k]), float(m.rmse[i, k])
            f = float(paper_factor(a, d, r))
            rows.append({"iteration": i, "sensor": s, "area": a, "dfd": d, "rmse": r, "factor": f,
                         "score": float(result.scores[i]), "selected": i == result.selected})  # fmt: skip
    return rows


def write_metrics_tables(result: EvalResult, csv_path: Path, md_path: Path) -> None:
    """Per-iteration metrics as CSV (long format) and Markdown (one Table-3-like block per sensor)."""
    rows = metrics_rows(result)
    with atomic_output(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:  # whole or not at all
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    n = result.iterations + 1
    head = "| | " + " | ".join(f"I{i}{'*' if i == result.selected else ''}" for i in range(n)) + " |"
    sep = "|---|" + "---|" * n
    lines = [
        f"# Calibration metrics per iteration ({result.scenario}, {reference_label(result)})",
        "",
        "I0 = initial parameters; * = the reported iterate "
        f"({result.select}). A [m], DFD [m/s, time in s], RMSE [m/s]; factor = 1/A + 1/DFD + 1/RMSE.",
    ]
    fmt = {"area": "{:.4f}", "dfd": "{:.3f}", "rmse": "{:.4f}", "factor": "{:.2f}"}
    label = {"area": "A", "dfd": "DFD", "rmse": "RMSE", "factor": "factor"}
    for s in [*result.sensors, "mean"]:
        sub = [r for r in rows if r["sensor"] == s]
        lines += ["", f"## {s}", "", head, sep]
        for key in ("area", "dfd", "rmse", "factor"):
            lines.append(f"| {label[key]} | " + " | ".join(fmt[key].format(r[key]) for r in sub) + " |")
    write_text(md_path, "\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------------- plots
def plot_pulses(problem: CalibrationProblem, result: EvalResult, path: Path) -> None:
    """Reference vs initial vs calibrated pulse per sensor (re-simulated), as the metrics compare them.

    Velocities are the compared signals (:meth:`CalibrationProblem.compared`: the integral of the
    CFC-filtered acceleration) for the reference and both candidates alike; accelerations [g] are their
    time derivative. Raw simulated velocities of the light up-front cells ring by several m/s around
    that signal, so plotting them against the compared reference would show a mismatch the metrics
    never see.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = torch.stack([result.params[0], result.params[result.selected]])
    with torch.no_grad():
        res = problem.sim.run(p, speed=problem.speed.expand(2), overlap=problem.overlap.expand(2),
                              side=problem.side.expand(2), duration=problem.sim_duration, sensors=problem.sensors,
                              record_cells="none")  # fmt: skip
    vel = torch.cat([problem.ref_velocity[None], problem.compared(res.velocity)]).double()  # [3, K, T]
    acc = torch.gradient(vel, spacing=problem.dt, dim=-1)[0] / G0
    T = problem.T
    t = np.arange(T) * problem.dt * 1e3
    K = len(problem.sensors)
    fig, axes = plt.subplots(2, K, figsize=(4.6 * K, 6.4), squeeze=False, sharex=True)
    for k in range(K):
        for row, series in enumerate((acc[:, k], vel[:, k])):
            ax = axes[row, k]
            ax.plot(t, series[0].numpy(), "k-", lw=2, label=f"reference ({reference_label(result)})")
            ax.plot(t, series[1].numpy(), "C0--", label="initial")
            ax.plot(t, series[2].numpy(), "C3-", label=f"calibrated (I{result.selected})")
            ax.grid(alpha=0.3)
        axes[0, k].set_title(problem.sensors[k])
        axes[1, k].set_xlabel("time [ms]")
    filt = f"CFC{problem.compare_cfc}, " if problem.compare_cfc is not None else ""
    axes[0, 0].set_ylabel(f"acceleration [g] ({filt}as compared)")
    axes[1, 0].set_ylabel(f"velocity [m/s] ({filt}as compared)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def plot_learning_curves(log_rows: list[dict[str, float]], result: EvalResult, path: Path) -> None:
    """Training reward/return and batch-final metrics vs env steps, and the evaluation's metrics per iteration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    if log_rows:
        x = np.array([r["env_steps"] for r in log_rows])
        axes[0].plot(x, [r["return_mean"] for r in log_rows], "C0-", label="episode return")
        axes[0].plot(x, [r["reward_mean"] for r in log_rows], "C1-", label="step reward")
        for key, c in (("area", "C0"), ("dfd", "C1"), ("rmse", "C2")):
            axes[1].semilogy(x, [r[f"{key}_final"] for r in log_rows], f"{c}-", label=f"{key} (episode end)")
            axes[1].semilogy(x, [r[f"{key}_initial"] for r in log_rows], f"{c}:", alpha=0.6)
    axes[0].set_xlabel("env steps")
    axes[0].set_title("training reward")
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("env steps")
    axes[1].set_title("training batch metrics (dotted: episode start)")
    axes[1].legend(fontsize=8)
    it = np.arange(result.iterations + 1)
    for key, c in (("area", "C0"), ("dfd", "C1"), ("rmse", "C2")):
        axes[2].semilogy(it, getattr(result.metrics, key).double().mean(-1).numpy(), f"{c}-o", ms=3, label=key)
    axes[2].axvline(result.selected, color="k", ls=":", lw=1)
    axes[2].set_xlabel("calibration iteration")
    axes[2].set_title(f"evaluation ({result.scenario}), sensor mean")
    axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def _draw(plot: Any, path: Path, *args: Any) -> None:
    """``plot(*args, path)``; a failure (matplotlib, a full disk) is a warning naming the picture, so the evaluation's
    results are still written (:func:`evaluate_run`), and removes an earlier evaluation's picture there, which would
    stand beside results it does not show."""
    try:
        plot(*args, path)
    except Exception as e:
        path.unlink(missing_ok=True)
        warnings.warn(f"{path} was not drawn: {type(e).__name__}: {e}; the results are in {SUMMARY_FILE}, "
                      "eval_metrics.csv/.md and calibrated.npz beside it", stacklevel=3)  # fmt: skip


# --------------------------------------------------------------------------------------- run folder
def update_summary(run_dir: str | Path, **entries: Any) -> dict[str, Any]:
    """Add entries to a run's ``summary.json`` (rewritten atomically); return the new summary."""
    path = Path(run_dir) / SUMMARY_FILE
    summary = json.loads(path.read_text(encoding="utf-8"))
    summary.update(entries)
    write_text(path, json_text(summary))
    return summary


def policy_from_checkpoint(config: TrainConfig, state: dict[str, Any], path: Path, key: str) -> TensorDictModuleBase:
    """The policy network of ``config`` with the weights of a training checkpoint ``state`` read from ``path``.

    Raises:
        ConfigError: (``key``) the weights do not fit the run's networks (a checkpoint of another algorithm
            or agent layout); the message names the file and the first mismatches.
    """
    torch.manual_seed(config.seed)  # the networks' initial draw, overwritten by the checkpoint
    policy = make_policy(make_env(config, n_envs=1), config.algorithm)
    require_fits(policy.state_dict(), state["policy"], f"{config.algorithm.name} policy", path, key)
    policy.load_state_dict(state["policy"])
    return policy


def eval_name(run_dir: Path, ckpt: Path) -> str:
    """The ``eval/`` folder name of a checkpoint file: its stem for the run's ``checkpoint.pt`` and kept snapshots
    (``checkpoint``, ``iter_00040``); for any other file the stem and 8 hex digits of its absolute path
    (``best_3f2a9c01``), so two files of one name (``a/best.pt``, ``b/best.pt``) never share a folder."""
    where = ckpt.resolve()
    if where == (run_dir / CHECKPOINT_FILE).resolve() or where.parent == (run_dir / SNAPSHOT_DIR).resolve():
        return ckpt.stem
    return f"{ckpt.stem}_{hashlib.sha256(str(where).encode()).hexdigest()[:8]}"


_OWN_CHECKPOINT = (
    "expected a checkpoint of this run (latest, an iteration with a kept snapshot in {snapshots}/, or a copy of one); "
    "evaluate another run's checkpoint in that run (run=<its folder>)"
)


def evaluate_run(
    run_dir: str | Path,
    trainer: Trainer | None = None,
    iterations: int | None = None,
    checkpoint: str | int | None = None,
    *,
    finished_before: bool = False,
) -> dict[str, Any]:
    """Evaluate a run's latest checkpoint, a kept one, or a live trainer; write the files of the module docstring.

    Args:
        run_dir: the run folder (``config.yaml``, ``checkpoint.pt``, ``log.csv``).
        trainer: the trainer that just finished (its networks and counters are used as they are).
        iterations: override ``eval.iterations``.
        checkpoint: ``None`` or ``"latest"``: ``checkpoint.pt``; otherwise an iteration with a kept snapshot or a
            checkpoint file (:func:`find_checkpoint`), and the learning curves then end at that checkpoint's
            iteration. ``None`` with a ``trainer``, whose networks are evaluated.
        finished_before: the ``trainer`` resumed a run that had finished (it trained no further): its evaluation is
            one of the run's checkpoint, with that one's rule on changed inputs.

    Where the files go: the run's own evaluation (by ``trainer``, or of ``checkpoint.pt``, with the run's
    ``eval.iterations``; of ``checkpoint.pt`` with the inputs it started with, or its first) is written into
    ``run_dir``. Any other never replaces it: it goes into ``run_dir/eval/<name>/`` (:func:`eval_name`; a trainer's
    networks after iteration ``i`` are those of the snapshot ``iter_<i>``), with ``_steps<n>`` added for another
    ``iterations`` (``eval/checkpoint_steps40/``, ``eval/iter_00040/``), so a re-evaluation with other settings or
    after ``configs/`` or the code changed (``provenance.json``) keeps the run's results.

    Returns:
        The summary written to ``summary.json`` (with ``checkpoint``: the file evaluated, ``None`` for a trainer,
        and ``eval_dir``: the folder written).

    Raises:
        ConfigError: a ``trainer`` and a ``checkpoint`` both (key ``checkpoint``); no run config or no such
            checkpoint in ``run_dir``; a checkpoint written under other settings than the run's ``config.yaml``
            (another run's, of the same network shapes: key ``checkpoint``, the setting named, as a resume refuses
            it); the folder to write cannot be written (key ``run``: a read-only run folder), before the evaluation's
            work, or is in use by another process (a run still training, or another
            evaluation of the same checkpoint: :func:`marlcrash.calibrate.runlock.run_lock`).
    """
    t0 = time.perf_counter()
    if trainer is not None and checkpoint is not None:
        raise ConfigError(f"evaluate either a live trainer or a checkpoint, got a trainer and checkpoint="
                          f"{checkpoint!r}", key="checkpoint")  # fmt: skip
    run_dir = Path(run_dir)
    out_dir = run_dir
    config = trainer.config if trainer is not None else load_run_config(run_dir, device="cpu")  # policy on the CPU
    run_config = config  # before an iterations override: what the checkpoint's saved config is compared with
    own_steps = config.eval.iterations
    if iterations is not None:
        whole = isinstance(iterations, numbers.Integral) and not isinstance(iterations, (bool, np.bool_))
        if not whole or not 1 <= iterations <= MAX_STEPS:  # 1.5 and 2**63 were refused as the env file's
            # termination.max_iterations, a key the user never set, after the evaluation's folder was made
            raise ConfigError(f"expected a whole number of calibration steps from 1 to 2**63 - 1 (MAX_STEPS), got "
                              f"{iterations!r}", key="iterations")  # fmt: skip
        iterations = int(iterations)
        # a copy: a live trainer's config (the caller's) keeps its own eval.iterations
        config = dataclasses.replace(config, eval=dataclasses.replace(config.eval, iterations=iterations))
    check = provenance.check_run(run_dir, provenance.env_inputs(make_env_config(config)), key=None)
    if trainer is not None:
        policy, counters = trainer.policy, trainer.state_dict()
        own, name = config.eval.iterations == own_steps, snapshot_path(run_dir, trainer.iteration).stem
        if finished_before:  # a resume of a finished run evaluates its checkpoint again: as evaluate.py would
            name = eval_name(run_dir, run_dir / CHECKPOINT_FILE)
    else:
        ckpt = find_checkpoint(run_dir, checkpoint)
        counters = load_training_checkpoint(ckpt, key="checkpoint")
        policy = policy_from_checkpoint(config, counters, ckpt, key="checkpoint")
        require_same_run(counters.get("config"), run_config, ckpt, "checkpoint", run_dir, _OWN_CHECKPOINT)
        own, name = checkpoint in (None, "latest") and config.eval.iterations == own_steps, eval_name(run_dir, ckpt)
    if (trainer is None or finished_before) and own and (run_dir / SUMMARY_FILE).is_file():
        # the run's results exist: only the same evaluation redoes them (a resume of a finished run after the code
        # changed rewrote them, where train/evaluate.py of the same checkpoint wrote eval/checkpoint/)
        own = not (check.configs or check.code)
    if not own:  # only once the checkpoint proved usable: no empty folders
        suffix = "" if config.eval.iterations == own_steps else f"_steps{config.eval.iterations}"
        out_dir = run_dir / EVAL_DIR / f"{name}{suffix}"
    check_output_dir(out_dir, "run")  # a read-only run folder: said now, not after the work (or by mkdir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # a trainer holds its run folder already (its own evaluation goes there); otherwise hold the folder written, so
    # an evaluation neither writes a run that still trains nor interleaves its files with another of the same folder
    with contextlib.nullcontext() if out_dir == run_dir and trainer is not None else run_lock(out_dir, "run"):
        remove_temporaries_of(out_dir, EVAL_FILES)  # of its files' writes a kill interrupted: this process holds it
        provenance.warn_changes(run_dir, check, "evaluate")
        log_path = run_dir / LOG_FILE  # read before the evaluation's work: a malformed row fails now
        position = counters.get("log_position")  # the rows the checkpoint counts; a torn one after them is not read
        log_rows = read_log(log_path, rows=position, columns=LOG_COLUMNS) if log_path.is_file() else []
        log_rows = [r for r in log_rows if r["iteration"] <= int(counters["iteration"])]
        result = evaluate_policy(policy, config)
        problem = evaluation_problem(config)
        if not torch.allclose(problem.ref_velocity, result.ref_velocity, rtol=0, atol=1e-9):
            raise ConfigError("the evaluation env and the baselines' problem drew different references", key="eval")
        th = config.eval.thresholds
        final = result.per_sensor(result.selected)
        ok = th.passes(Metrics(*(t[..., None] for t in result.metrics)))  # [I + 1, K]: each sensor on its own
        passed = dict(zip(result.sensors, ok[result.selected].tolist(), strict=True))
        train_time = float(counters["wall_time_s"])
        steps = int(counters["env_steps"])
        collect_rates = [r["env_steps_per_s"] for r in log_rows]
        summary: dict[str, Any] = {
            "algorithm": config.algorithm.name,
            "checkpoint": None if trainer is not None else str(ckpt),
            "eval_dir": str(out_dir),
            "seed": config.seed,
            "scenario": result.scenario,
            "reference": result.reference,
            "reference_source": result.source,
            "reference_seed": result.seed,
            "select": result.select,
            "selected_iteration": result.selected,
            "eval_iterations": result.iterations,
            "final_metrics": final,
            "initial_metrics": result.per_sensor(0),
            "last_metrics": result.per_sensor(result.iterations),
            "thresholds": {"area": th.area, "dfd": th.dfd, "rmse": th.rmse},
            "passed": passed,
            "all_passed": all(passed.values()),
            "initial_passed": bool(ok[0].all()),
            "iterations_trained": int(counters["iteration"]),
            "env_steps": steps,
            "simulations": int(counters["simulations"]),
            "train_wall_time_s": train_time,
            "env_steps_per_s": steps / train_time if train_time > 0 else None,
            "collect_env_steps_per_s": float(np.median(collect_rates)) if collect_rates else None,
            "provenance": check.as_dict(),  # configs or code changed since the run started (provenance.json)
        }
        if result.true_params is not None:
            summary["param_error"] = param_errors(problem, result.params[result.selected], result.true_params)
            summary["initial_param_error"] = param_errors(problem, result.params[0], result.true_params)
        write_metrics_tables(result, out_dir / "eval_metrics.csv", out_dir / "eval_metrics.md")
        arrays = {"initial": result.params[0].numpy(), "calibrated": result.params[result.selected].numpy(),
                  "per_iteration": result.params.numpy(), "selected_iteration": np.array(result.selected)}  # fmt: skip
        if result.true_params is not None:
            arrays["true"] = result.true_params.numpy()
        with atomic_output(out_dir / "calibrated.npz") as tmp:
            np.savez(tmp, **arrays)  # type: ignore[arg-type]  # numpy's stub matches **arrays against allow_pickle
        if config.eval.plots:  # a picture that cannot be drawn costs no result: summary.json is written after them
            _draw(plot_pulses, out_dir / "pulses.png", problem, result)
            _draw(plot_learning_curves, out_dir / "learning_curves.png", log_rows, result)
        else:  # an earlier evaluation's pictures (a resume with eval.plots=false) do not show these results
            for name in ("pulses.png", "learning_curves.png"):
                (out_dir / name).unlink(missing_ok=True)
        summary["eval_wall_time_s"] = time.perf_counter() - t0
        summary["wall_time_s"] = train_time + summary["eval_wall_time_s"]
        old = out_dir / SUMMARY_FILE
        if old.is_file():  # the training process's wall time (train/train.py) is not the evaluation's to drop
            with contextlib.suppress(ValueError, OSError, AttributeError):
                earlier = json.loads(old.read_text(encoding="utf-8")).get(KEPT_SUMMARY_KEY)
                if earlier is not None:
                    summary[KEPT_SUMMARY_KEY] = earlier
        write_text(out_dir / SUMMARY_FILE, json_text(summary))
        return summary
