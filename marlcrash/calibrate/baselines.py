"""Optimizer baselines on a simulation budget (DESIGN 6): random search, CMA-ES, gradient descent, LM.

All four search the agents' space of a :class:`~marlcrash.calibrate.problem.CalibrationProblem`
(``x [n_agents, 7]`` log-scale factors, only its free coordinates), charge every simulated
candidate to one :class:`~marlcrash.calibrate.budget.Progress`, rank candidates by the
problem's fit score, and return a :class:`CalibrationResult` with the same fields. The
first candidate of every run is the initial parameters (``x = 0``), so ``initial_metrics``
and the first history row are measured, not assumed.

- :func:`random_search`: batches drawn uniformly in a box around the best point so far
  (``recenter``; half-widths ``radius`` times the search box's), the box shrinking by ``shrink``
  after a batch without improvement, to ``min_radius`` at least; with ``recenter: false`` it is pure
  uniform sampling of the search box (``shrink`` then has no effect). A coordinate drawn beyond the
  search box is clipped onto its face, the projection every method's candidates get: where the
  sampling box crosses a bound, the draws beyond it lie on it, so the sampling is uniform in the
  search box only where the sampling box lies inside it. In a 2000-simulation run of the default
  problem (twin of ``full_width_40``, 127 free coordinates, a 20 ms window) at most 4 % of a batch's
  coordinates lie on a bound, and no candidate repeats (that takes every coordinate of two draws
  clipped alike).
- :func:`cmaes`: the ``cma`` package's ask/tell loop, one generation simulated as one batch,
  box bounds by its ``BoundTransform``; normal draws come from the run's numpy Generator
  (``cma``'s own seeding of the global RNG is switched off, and the global state is restored).
  Only a whole population is told to CMA-ES: what is left of the budget after the last whole generation is
  simulated (its candidates can still be the best) but updates nothing. A budget below ``1 + popsize``
  completes no generation at all (a random sample around the start); the run warns, and
  :attr:`CalibrationResult.generations` counts the generations completed.
- :func:`gradient_descent`: projected Adam on the free log-scales of ``batch_size`` starting
  points at once (the first at ``x = 0``, the others uniform within ``start_radius``), loss
  :class:`~marlcrash.calibrate.problem.SmoothLoss` through the differentiable simulator (``backend``:
  the compiled adjoint of :mod:`marlcrash.sim.adjoint` by default, or torch autograd, the same
  gradients). Cost: one simulation per candidate per step (the forward pass; its backward pass is not
  charged separately). The metrics of each step's forward pass rank the candidates. A candidate whose
  gradient is not finite (its simulation diverged) gets none for that step (Adam's momentum alone moves it).
- :func:`levenberg_marquardt`: least squares on the velocity residuals of every sensor
  (:mod:`~marlcrash.calibrate.leastsq`: a finite-difference Jacobian of ``n_free`` simulations
  and six damped steps per iteration, ``n_free + 6`` simulations in two batches). It fits the
  windows of ``windows`` in turn (``[1.0]``: the whole pulse at once), each for at most
  ``iterations`` iterations and until ``stall`` iterations in a row lower its cost by less than
  ``rtol``; then, while the budget pays for an iteration, it restarts from the lowest-cost point
  so far plus ``restart_radius`` normal noise (basin hopping: the landscape has many local minima
  at the 1e-2 m area scale) and keeps the best candidate. With restarts it stops when the rest of
  the budget cannot pay for a whole iteration, leaving up to ``n_free + 6`` simulations unspent;
  with ``restart_radius: 0`` it stops after the last window, possibly far below the budget.
  Deterministic for a seed (restart noise).

Every result says why its run ended (:attr:`CalibrationResult.stop`): the budget, success (``stop_on_success``), or
the method's own rule with budget left (``ended``: cmaes without restarts once CMA-ES's termination criteria fire,
lm without restarts after its windows), which :attr:`CalibrationResult.stop_reason` names.

Every method refuses a problem with no free coordinate (its masking left no agent active in the scenario:
:func:`check_free_coordinates`) and settings made in Python that a config file could not hold (checked as the
loaders check a file's, keys named ``<method>.<key>``) before it simulates anything.
"""

from __future__ import annotations

import csv
import itertools
import json
import os
import shutil
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from marlcrash import provenance
from marlcrash.calibrate.budget import Progress
from marlcrash.calibrate.leastsq import STEP_FACTORS, check_fd_step, lm_iteration
from marlcrash.calibrate.problem import CalibrationProblem, ProblemConfig, SmoothLoss, problem_env_config
from marlcrash.calibrate.runlock import claim_dir
from marlcrash.config import (
    checked,
    from_dict,
    nested_error,
    require,
    require_complete,
    require_seed,
    require_threads,
)
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics
from marlcrash.outputs import (
    atomic_output,
    check_output_dir,
    json_text,
    new_sibling,
    require_run_name,
    sync_folder,
)

# ----------------------------------------------------------------------------------------- configs

MAX_BATCH = 10_000
"""Most candidates of one batched simulation a setting may ask for (``cmaes.popsize``, ``gradient.batch_size``,
``random_search.batch_size``) [-]: a batch is simulated at once (about 0.3 MB per candidate at the default 150 ms,
more with gradients) and ``cma`` and the gradient's starting points hold arrays of it, so 10**9 ran out of memory
deep inside them (a random-search batch is at most the budget's candidates); 10,000 is far above any
population CMA-ES is run with (its own default is ``4 + 3 ln n``, 18 for 127 free coordinates)."""


def require_batch_size(value: Any, key: str) -> None:
    """Refuse, naming ``key``, a batch size of one batched simulation that is no integer in ``[1, MAX_BATCH]``
    (10**9 ran on into torch's "can't allocate memory")."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool) and bool(1 <= value <= MAX_BATCH)
    require(ok, key, f"expected a batch size in [1, {MAX_BATCH}] (MAX_BATCH: one batch is simulated at once), "
                     f"got {value!r}")  # fmt: skip


@dataclass
class RandomSearchConfig:
    """Random search settings; values in ``configs/train/baseline/random_search.yaml``."""

    batch_size: int = 64
    recenter: bool = True
    radius: float = 0.5
    shrink: float = 0.7
    min_radius: float = 0.02

    def validate(self) -> None:
        require(1 <= self.batch_size <= MAX_BATCH, "batch_size",
                f"expected [1, {MAX_BATCH}] candidates per batch (one batched simulation; MAX_BATCH = {MAX_BATCH}), "
                f"got {self.batch_size}")  # fmt: skip
        require(0 < self.radius <= 1, "radius", f"expected a fraction of the box in (0, 1], got {self.radius}")
        require(0 < self.shrink <= 1, "shrink", f"expected a factor in (0, 1], got {self.shrink}")
        require(0 < self.min_radius <= self.radius, "min_radius",
                f"expected 0 < min_radius <= radius ({self.radius}), got {self.min_radius}")  # fmt: skip


@dataclass
class CMAESConfig:
    """CMA-ES settings; values in ``configs/train/baseline/cmaes.yaml``."""

    popsize: int = 32
    sigma0: float = 0.2
    diagonal: bool = False
    restarts: bool = True

    def validate(self) -> None:
        require(2 <= self.popsize <= MAX_BATCH, "popsize",
                f"expected a population in [2, {MAX_BATCH}] (one generation is one batched simulation; CMA-ES's "
                f"own default is 4 + 3 ln n), got {self.popsize}")  # fmt: skip
        require(np.isfinite(self.sigma0) and self.sigma0 > 0, "sigma0", f"expected a step > 0, got {self.sigma0}")


@dataclass
class GradientConfig:
    """Gradient descent settings; values in ``configs/train/baseline/gradient.yaml``."""

    batch_size: int = 4
    lr: float = 0.03
    beta1: float = 0.9
    beta2: float = 0.999
    start_radius: float = 0.1
    threads: int = 1
    backend: str = "adjoint"
    loss: SmoothLoss = field(default_factory=SmoothLoss)

    def validate(self) -> None:
        require(1 <= self.batch_size <= MAX_BATCH, "batch_size",
                f"expected [1, {MAX_BATCH}] starting points (each step simulates them in one batch; "
                f"MAX_BATCH = {MAX_BATCH}), got {self.batch_size}")  # fmt: skip
        require(np.isfinite(self.lr) and self.lr > 0, "lr", f"expected a learning rate > 0, got {self.lr}")
        for k in ("beta1", "beta2"):
            require(0 <= getattr(self, k) < 1, k, f"expected a decay in [0, 1), got {getattr(self, k)}")
        require(self.start_radius >= 0, "start_radius", f"expected >= 0, got {self.start_radius}")
        require_threads(self.threads, "threads")
        require(self.backend in ("adjoint", "torch"), "backend", f"expected adjoint or torch, got {self.backend!r}")


@dataclass
class LMConfig:
    """Levenberg-Marquardt settings; values in ``configs/train/baseline/lm.yaml``."""

    windows: list[float] = field(default_factory=lambda: [1.0])
    iterations: int = 12
    rtol: float = 1e-3
    stall: int = 3
    fd_step: float = 1e-5
    damping: float = 1e-2
    restart_radius: float = 0.05

    def validate(self) -> None:
        w = [float(v) for v in self.windows]
        ok = bool(w) and all(0 < v <= 1 for v in w) and all(a < b for a, b in itertools.pairwise(w)) and w[-1] == 1.0
        require(ok, "windows", f"expected strictly increasing fractions in (0, 1] ending at 1.0, got {self.windows}")
        require(self.iterations >= 1, "iterations", f"expected >= 1 iterations per window, got {self.iterations}")
        require(np.isfinite(self.rtol) and 0 < self.rtol < 1, "rtol", f"expected a fraction in (0, 1), got {self.rtol}")
        require(self.stall >= 1, "stall", f"expected >= 1 iterations, got {self.stall}")
        require(np.isfinite(self.fd_step) and 0 < self.fd_step <= 1e-2, "fd_step",
                f"expected a log-scale step in (0, 0.01], got {self.fd_step}")  # fmt: skip
        require(np.isfinite(self.damping) and self.damping > 0, "damping", f"expected > 0, got {self.damping}")
        require(np.isfinite(self.restart_radius) and self.restart_radius >= 0, "restart_radius",
                f"expected a log-scale radius >= 0 (0: no restarts), got {self.restart_radius}")  # fmt: skip


# ----------------------------------------------------------------------------------------- results


@dataclass
class CalibrationResult:
    """Outcome of one calibration run (any method), ``K`` sensors.

    Attributes:
        method: the baseline's name.
        best_x: ``[n_agents, 7]`` best candidate; ``best_params``: ``[n_cells, 7]`` its cell parameters.
        sensor_names: ``[K]``.
        initial_metrics, final_metrics: per-sensor :class:`Metrics` ``[K]`` at ``x = 0`` and at ``best_x``.
        initial_score, best_score: fit scores (higher is better).
        history: ``[H, 3]`` simulations used, best score so far, best score of the batch.
        simulations: simulations used; ``wall_time_s``: [s].
        sims_to_success: simulations until the first candidate passing the success test, else ``None``.
        param_error, initial_param_error: ``{sub-assembly: {E_x, E_s, transmission}}`` relative errors
            of ``best_x`` and of ``x = 0`` against a twin's truth (``None`` for other references).
        generations: CMA-ES generations completed (whole populations told to it, over all restarts); ``None``
            for the other methods.
        stop: why the run ended: ``budget`` (spent, or what was left cannot pay for the method's next batch),
            ``success`` (a candidate passed, with ``stop_on_success``), or ``ended`` (the method's own rule, before
            the budget ran out).
        stop_reason: for ``ended``, the rule: the CMA-ES termination criteria that fired, as ``cma``'s
            ``es.stop()`` names them (``tolx``, ``tolfun``, ...; comma-separated), or ``windows`` (lm without
            restarts fitted its last window: its iteration cap or ``stall``); ``None`` otherwise.
    """

    method: str
    best_x: torch.Tensor
    best_params: torch.Tensor
    sensor_names: list[str]
    initial_metrics: Metrics
    final_metrics: Metrics
    initial_score: float
    best_score: float
    history: np.ndarray
    simulations: int
    wall_time_s: float
    sims_to_success: int | None
    param_error: dict[str, dict[str, float]] | None = None
    initial_param_error: dict[str, dict[str, float]] | None = None
    generations: int | None = None
    stop: str = "budget"
    stop_reason: str | None = None

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: metrics per sensor ``{area, dfd, rmse}`` (SI), budget use, errors."""
        out: dict[str, Any] = {
            "method": self.method,
            "final_metrics": self.final_metrics.per_sensor(self.sensor_names),
            "initial_metrics": self.initial_metrics.per_sensor(self.sensor_names),
            "initial_score": self.initial_score,
            "best_score": self.best_score,
            "simulations": self.simulations,
            "sims_to_success": self.sims_to_success,
            "wall_time_s": self.wall_time_s,
            "stop": self.stop,
            "stop_reason": self.stop_reason,
        }
        if self.param_error is not None:
            out["param_error"] = self.param_error
            out["initial_param_error"] = self.initial_param_error
        if self.generations is not None:
            out["generations"] = self.generations
        return out


def check_free_coordinates(
    problem: CalibrationProblem, method: str, key: str = "problem.masking", source: str | None = None
) -> None:
    """Refuse a problem with no free coordinate, before any simulation: its masking left no agent active.

    Args:
        problem: the problem to search.
        method: who refuses it, for the message.
        key: the masking switch's dotted key in the config the user ran (``problem.masking`` in a baseline run,
            ``masking`` in a comparison); the message names its siblings (``env_overrides``, ``scenario``) alike.
        source: that config file, for the message.

    Raises:
        ConfigError: (``key``) ``problem.n_free`` is 0 (cmaes failed inside ``cma`` with a ZeroDivisionError, lm in a
            reshape of its empty Jacobian; random search and gradient descent spent the budget on the start alone).
    """
    if problem.n_free > 0:
        return
    node = key.rpartition(".")[0]
    at = f"{node}." if node else ""
    raise ConfigError(
        f"{method}: the problem has no free coordinate to search: none of its {problem.n_agents} agents is active in "
        f"scenario {problem.scenario.name!r}, as the env's impact-region rule (masking.mode, masking.min_fraction, "
        f"masking.primary_depth, masking.secondary_depth) leaves them; turn masking off ({key}: false; every agent "
        f"active), loosen the env's masking (in its file or {at}env_overrides), or choose another {at}scenario",
        key=key,
        path=source,
    )


def _evaluate(problem: CalibrationProblem, progress: Progress, x: torch.Tensor) -> torch.Tensor:
    """Simulate and record a batch ``x [N, n_agents, 7]`` (``N`` already granted); return its ``[N]`` scores."""
    m = problem.evaluate(x)
    s = problem.score(m)
    progress.record(x, m, s, problem.success(m))
    return s


def _finish(
    method: str,
    problem: CalibrationProblem,
    progress: Progress,
    initial: Metrics,
    generations: int | None = None,
    ended: str | None = None,
) -> CalibrationResult:
    """The result of a run; ``ended``: the method's own rule that ended it with budget left
    (:attr:`CalibrationResult.stop_reason`), ``None`` where the budget or success ended it."""
    best_x, best_metrics = progress.best_x, progress.best_metrics
    assert best_x is not None and best_metrics is not None  # the start (or the first step) was recorded
    if ended is not None:
        stop = "ended"
    else:
        stop = "success" if progress.stop_on_success and progress.sims_to_success is not None else "budget"
    x0 = problem.zeros(1)
    truth = problem.true_params is not None
    return CalibrationResult(
        method=method,
        best_x=best_x,
        best_params=problem.params(best_x[None])[0].detach(),
        sensor_names=list(problem.sensors),
        initial_metrics=initial,
        final_metrics=best_metrics,
        initial_score=float(problem.score(Metrics(*(m[None] for m in initial)))[0]),
        best_score=progress.best_score,
        history=progress.history_array(),
        simulations=progress.used,
        wall_time_s=progress.wall_time,
        sims_to_success=progress.sims_to_success,
        param_error=problem.param_error_table(best_x) if truth else None,
        initial_param_error=problem.param_error_table(x0[0]) if truth else None,
        generations=generations,
        stop=stop,
        stop_reason=ended,
    )


def _start(problem: CalibrationProblem, progress: Progress) -> Metrics:
    """Evaluate the initial point (one simulation) and return its per-sensor metrics ``[K]``."""
    x0 = problem.zeros(1)
    m = problem.evaluate(x0)
    progress.record(x0, m, problem.score(m), problem.success(m))
    return Metrics(*(t[0] for t in m))


# ------------------------------------------------------------------------------------- the methods


def random_search(
    problem: CalibrationProblem, budget: int, config: RandomSearchConfig, seed: int, stop_on_success: bool = False
) -> CalibrationResult:
    """Batched random search (module docstring) with a seeded numpy Generator."""
    config = checked(config, "random_search")  # settings made in Python: no loader checked them
    check_free_coordinates(problem, "random_search")
    rng = np.random.default_rng(seed)
    progress = Progress(budget, stop_on_success)
    initial = _start(problem, progress)
    lo, hi = (b.numpy() for b in problem.flat_box())
    half = 0.5 * (hi - lo)
    centre = np.zeros_like(lo)
    radius = config.radius if config.recenter else 1.0
    while not progress.done:
        n = progress.grant(config.batch_size)
        u = rng.uniform(-1.0, 1.0, size=(n, lo.size))
        z = np.clip(centre + radius * half * u, lo, hi) if config.recenter else lo + (u + 1.0) * half
        before = progress.best_x  # record() keeps a fresh clone whenever the best changes
        _evaluate(problem, progress, problem.unflat(torch.as_tensor(z)))
        if config.recenter:
            # the best changed, not its score rose: a first passing candidate is kept with a lower score
            if progress.best_x is not before:
                assert progress.best_x is not None  # the start was recorded
                centre = problem.flat(progress.best_x[None])[0].numpy()
            else:
                radius = max(config.min_radius, radius * config.shrink)
    return _finish("random_search", problem, progress, initial)


def cmaes(
    problem: CalibrationProblem, budget: int, config: CMAESConfig, seed: int, stop_on_success: bool = False
) -> CalibrationResult:
    """CMA-ES (``cma`` package) with one batched simulation per generation (module docstring).

    Warns where ``budget`` cannot pay for the start and one whole population (``1 + popsize``).
    """
    import cma

    config = checked(config, "cmaes")  # settings made in Python: no loader checked them
    check_free_coordinates(problem, "cmaes")
    if budget < 1 + config.popsize:
        warnings.warn(
            f"cmaes: a budget of {budget} simulations cannot complete one generation of cmaes.popsize = "
            f"{config.popsize} (that needs 1 + {config.popsize} = {1 + config.popsize}: the start, then a whole "
            f"population); the run is {budget - 1} candidates drawn around the start, which CMA-ES never learns "
            f"from (generations: 0). Give a budget of at least {1 + config.popsize} or a smaller cmaes.popsize",
            stacklevel=2,
        )
    rng = np.random.default_rng(seed)
    progress = Progress(budget, stop_on_success)
    initial = _start(problem, progress)
    lo, hi = (b.numpy() for b in problem.flat_box())
    opts = {
        "popsize": config.popsize,
        "bounds": [lo.tolist(), hi.tolist()],
        "seed": np.nan,  # never seed numpy's global RNG; draws come from `randn` below
        "randn": lambda *shape: rng.standard_normal(shape),
        "verbose": -9,
        "verb_disp": 0,
        "verb_log": 0,
        "CMA_diagonal": bool(config.diagonal),
        "tolfun": 0.0,
        "tolflatfitness": 1000,
        "tolx": 1e-12,
    }
    global_state = np.random.get_state()  # noqa: NPY002 -- restored below: cma must not disturb the global RNG
    try:
        es = cma.CMAEvolutionStrategy(np.zeros(lo.size), config.sigma0, opts)
        generations, ended = 0, None
        while not progress.done:
            stopped = es.stop()  # the termination criteria that fired: {"tolx": 1e-12, ...}
            if stopped:
                if not config.restarts:
                    ended = ", ".join(stopped)
                    break
                assert progress.best_x is not None  # the start was recorded
                es = cma.CMAEvolutionStrategy(problem.flat(progress.best_x[None])[0].numpy(), config.sigma0, opts)
            n = progress.grant(config.popsize)
            pop = np.asarray(es.ask())
            s = _evaluate(problem, progress, problem.unflat(torch.as_tensor(pop[:n])))
            if n == config.popsize:
                f = -s.numpy()
                es.tell(list(pop), np.where(np.isfinite(f), f, 1e30).tolist())
                generations += 1
    finally:
        np.random.set_state(global_state)  # noqa: NPY002
    return _finish("cmaes", problem, progress, initial, generations, ended)


def gradient_descent(
    problem: CalibrationProblem, budget: int, config: GradientConfig, seed: int, stop_on_success: bool = False
) -> CalibrationResult:
    """Projected Adam through the differentiable surrogate (module docstring), seeded torch Generator."""
    config = checked(config, "gradient")  # settings made in Python: no loader checked them
    check_free_coordinates(problem, "gradient")
    gen = torch.Generator().manual_seed(seed)
    progress = Progress(budget, stop_on_success)
    lo, hi = problem.flat_box()
    B = config.batch_size
    z0 = (torch.rand(B, lo.numel(), generator=gen, dtype=torch.float64) * 2 - 1) * config.start_radius
    z0[0] = 0.0
    z = torch.minimum(torch.maximum(z0, lo), hi).requires_grad_(True)
    opt = torch.optim.Adam([z], lr=config.lr, betas=(config.beta1, config.beta2))
    initial = None
    threads = torch.get_num_threads()
    if config.threads:
        # [B, n_links] tensors are too small for intra-op threads; on a busy machine their spin-waits cost 10-50x
        torch.set_num_threads(config.threads)
    try:
        initial = _adam_loop(problem, progress, z, lo, hi, opt, config)
    finally:
        torch.set_num_threads(threads)
    return _finish("gradient", problem, progress, initial)


def _adam_loop(
    problem: CalibrationProblem,
    progress: Progress,
    z: torch.Tensor,
    lo: torch.Tensor,
    hi: torch.Tensor,
    opt: torch.optim.Optimizer,
    config: GradientConfig,
) -> Metrics:
    """Projected Adam steps on the free coordinates ``z [B, n_free]`` until the budget is spent."""
    B = z.shape[0]
    initial = None
    while not progress.done:
        n = progress.grant(B)
        opt.zero_grad()
        x = problem.unflat(z[:n])  # differentiable scatter into [n, n_agents, 7]
        loss, m = problem.loss(x, config.loss, config.backend)
        progress.record(x.detach(), m, problem.score(m), problem.success(m))
        if initial is None:
            initial = Metrics(*(t[0] for t in m))
        if progress.done:
            break
        loss.sum().backward()
        assert z.grad is not None  # z requires grad and the loss depends on it
        with torch.no_grad():  # a diverged candidate's NaN gradient made its log-scales NaN: drop it for this step
            z.grad[~torch.isfinite(z.grad).all(1)] = 0.0
        opt.step()
        with torch.no_grad():
            z.copy_(torch.minimum(torch.maximum(z, lo), hi))
    assert initial is not None  # a Progress has a budget >= 1: the loop ran at least once
    return initial


def check_gradient_backend(config: GradientConfig, sim_dtype: str, key: str = "gradient.backend",
                           source: str | None = None) -> None:  # fmt: skip
    """Refuse gradient descent on the ``adjoint`` backend where it cannot differentiate the simulator (a ``float32``
    env, springback relief in ``configs/sim.yaml``: :func:`marlcrash.sim.adjoint.unsupported`), before any simulation.

    Args:
        config: the gradient settings.
        sim_dtype: the env's ``sim_dtype`` (the problem simulates in it).
        key, source: the backend's dotted key and the config file, for the message.

    Raises:
        ConfigError: (``key``) the adjoint does not cover that simulator; the run failed with a keyless ModelError
            after the problem was built (a comparison: mid-table, after the runs before it).
    """
    if config.backend != "adjoint":
        return
    from marlcrash.sim.adjoint import unsupported
    from marlcrash.sim.surrogate import load_sim_config

    why = unsupported(load_sim_config(overrides={"dtype": sim_dtype}))
    if why is not None:
        raise ConfigError(f"{why} (the env's sim_dtype is {sim_dtype})", key=key, path=source)


def check_lm_fd_step(config: LMConfig, sim_dtype: str, key: str = "lm.fd_step", source: str | None = None) -> None:
    """Refuse ``lm``'s finite-difference step where the env's simulations round more than it resolves, before any
    simulation.

    Raises:
        ConfigError: (``key``) a ``float32`` env and ``fd_step`` below
            :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP` (:func:`~marlcrash.calibrate.leastsq.check_fd_step`).
    """
    check_fd_step(config.fd_step, sim_dtype, key, source)


def check_lm_budget(problem: CalibrationProblem, budget: int) -> None:
    """Refuse a budget below lm's first iteration (it spent 1 simulation and reported stop reason "budget").

    The minimum needs the problem: its free coordinates follow from the cell model (the vehicle's discretization),
    the agent layout and, with masking, the scenario's impact region, so no config loader can know it without
    building those (the discretization is most of a problem's cost). :func:`levenberg_marquardt` checks it first
    thing, ``compare`` on its first problem before it makes its folder; both before any simulation of lm's. A
    problem lm runs has at least 2 free coordinates (an active agent's ``E_x`` and ``E_s``, or where the behaviour
    bounds freeze those, two transmission directions of a cell: one alone never moves; a problem with none is refused,
    :func:`check_free_coordinates`), so no budget below ``1 + 2 + len(STEP_FACTORS)`` = 9 can ever do.

    Raises:
        ConfigError: (key ``budget``) fewer than 1 + free coordinates + step sizes simulations.
    """
    n = problem.flat_box()[0].numel()
    need = 1 + n + len(STEP_FACTORS)
    require(budget >= need, "budget",
            f"lm needs at least 1 + one iteration of (free coordinates + step sizes) = 1 + {n} + "
            f"{len(STEP_FACTORS)} = {need} simulations, got a budget of {budget}")  # fmt: skip


def levenberg_marquardt(
    problem: CalibrationProblem, budget: int, config: LMConfig, seed: int, stop_on_success: bool = False
) -> CalibrationResult:
    """Levenberg-Marquardt on the velocity residuals over growing windows, then restarts (module docstring).

    Raises:
        ConfigError: before any simulation: ``config.fd_step`` below the rounding of a ``float32`` problem (key
            ``lm.fd_step``, :func:`check_lm_fd_step`), a problem with no free coordinate (key ``problem.masking``,
            :func:`check_free_coordinates`), or a budget below one iteration (key ``budget``,
            :func:`check_lm_budget`).
    """
    config = checked(config, "lm")  # settings made in Python: no loader checked them
    check_lm_fd_step(config, problem.sim.config.dtype)  # nor the step against the problem's precision
    check_free_coordinates(problem, "lm")
    check_lm_budget(problem, budget)
    gen = torch.Generator().manual_seed(seed)
    progress = Progress(budget, stop_on_success)
    lo, hi = problem.flat_box()
    per_iter = lo.numel() + len(STEP_FACTORS)
    r0, m0 = _residuals(problem, progress, problem.zeros(1))
    initial = Metrics(*(t[0] for t in m0))
    ends = [max(2, round(float(w) * (problem.T - 1)) + 1) for w in config.windows]
    z, r = torch.zeros_like(lo), r0[0]
    best_z, best_r = z, r
    schedule, ended = ends, None
    while True:
        for end in schedule:
            z, r, cut = _lm_window(problem, progress, config, z, r, end)
        if float((r**2).sum()) < float((best_r**2).sum()):
            best_z, best_r = z, r
        if config.restart_radius == 0:  # no restarts: its windows end it, unless the budget or success cut the last
            ended = None if cut or progress.done else "windows"
            break
        if progress.done or progress.grant(1 + per_iter) < 1 + per_iter:
            break
        noise = torch.randn(lo.shape, generator=gen, dtype=torch.float64)
        z = torch.minimum(torch.maximum(best_z + config.restart_radius * noise, lo), hi)
        r = _residuals(problem, progress, problem.unflat(z[None]))[0][0]
        schedule = ends[-1:]
    return _finish("lm", problem, progress, initial, ended=ended)


def _residuals(problem: CalibrationProblem, progress: Progress, x: torch.Tensor) -> tuple[torch.Tensor, Metrics]:
    """Simulate and record a batch ``x [N, n_agents, 7]`` (already granted); its residuals ``[N, K, T]`` and metrics."""
    r, m = problem.residuals(x)
    progress.record(x, m, problem.score(m), problem.success(m))
    return r, m


def _lm_window(
    problem: CalibrationProblem, progress: Progress, config: LMConfig, z: torch.Tensor, r: torch.Tensor, end: int
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Levenberg-Marquardt iterations on the first ``end`` output samples, from ``z [n]`` with residual ``r [K, T]``.

    Ends after ``config.iterations`` iterations, after ``config.stall`` successive iterations that each
    lowered the window's cost by less than ``config.rtol`` (a rejected step lowers it by 0), or when the
    budget cannot pay for a whole iteration (or a candidate passed, ``stop_on_success``). Returns the last accepted
    point, its full residual, and whether the budget (or success) ended the window rather than its own rule.
    """
    lo, hi = problem.flat_box()
    n = lo.numel()
    lam, stalled = float(config.damping), 0

    def run(zs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # window residuals, full residuals
        if progress.done:  # a finite-difference point passed (stop_on_success): the damped steps are not simulated;
            full = torch.full((zs.shape[0], *r.shape), float("nan"), dtype=torch.float64)  # NaN: never accepted
            return full[:, :, :end].reshape(zs.shape[0], -1), full
        full = _residuals(problem, progress, problem.unflat(zs))[0]
        return full[:, :, :end].reshape(zs.shape[0], -1), full

    for _ in range(config.iterations):
        if progress.done or progress.grant(n + len(STEP_FACTORS)) < n + len(STEP_FACTORS):
            return z, r, True
        step = lm_iteration(run, z, r[:, :end].reshape(-1), lam, lo, hi, config.fd_step)
        lam = step.lam
        if step.accepted is not None:
            z, r = step.z, step.aux[step.accepted]
        stalled = stalled + 1 if step.rel < config.rtol else 0
        if stalled >= config.stall:
            break
    return z, r, False


BASELINES: dict[str, tuple[type, Callable[..., CalibrationResult]]] = {
    "random_search": (RandomSearchConfig, random_search),
    "cmaes": (CMAESConfig, cmaes),
    "gradient": (GradientConfig, gradient_descent),
    "lm": (LMConfig, levenberg_marquardt),
}
"""Baselines by name: (settings schema, function)."""


# ---------------------------------------------------------------------------------------- run config


@dataclass
class BaselineRunConfig:
    """One baseline run (``configs/train/baseline.yaml``, every key commented there)."""

    method: str = "cmaes"
    budget: int = 2000
    seed: int = 0
    stop_on_success: bool = False
    out_dir: str = "runs"
    name: str = "run"
    plot: bool = True
    problem: ProblemConfig = field(default_factory=ProblemConfig)
    random_search: RandomSearchConfig = field(default_factory=RandomSearchConfig)
    cmaes: CMAESConfig = field(default_factory=CMAESConfig)
    gradient: GradientConfig = field(default_factory=GradientConfig)
    lm: LMConfig = field(default_factory=LMConfig)

    def validate(self) -> None:
        require(
            self.method in BASELINES, "method", f"unknown method {self.method!r}; expected one of {sorted(BASELINES)}"
        )
        require(self.budget >= 1, "budget", f"expected a simulation budget >= 1, got {self.budget}")
        require_seed(self.seed, "seed")
        require_run_name(self.name)
        require(bool(self.out_dir), "out_dir", "expected an output folder")

    @property
    def method_config(self) -> Any:
        """The settings of the selected method."""
        return getattr(self, self.method)


def load_run_config(data: dict[str, Any], source: str | None = None) -> BaselineRunConfig:
    """Validate a run config mapping (e.g. Hydra's, without its ``hydra`` node).

    Also loads the problem's env config with its overrides, so a bad env key fails here, and checks that gradient
    descent's backend can differentiate that env's simulator (:func:`check_gradient_backend`) and that ``lm``'s
    finite-difference step is above its rounding (:func:`check_lm_fd_step`).

    Raises:
        ConfigError: unknown key, wrong type or bad value, naming the dotted key.
    """
    data = {k: v for k, v in data.items() if k != "hydra"}
    if source is not None:
        require_complete(BaselineRunConfig, data, source)
    config = from_dict(BaselineRunConfig, data, path=source)
    try:
        env = problem_env_config(config.problem)
    except ConfigError as e:  # keyed within the problem: problem.env_overrides.<key>, as the user set it
        raise nested_error(e, "problem", source) from None
    if config.method == "gradient":
        check_gradient_backend(config.gradient, env.sim_dtype, source=source)
    if config.method == "lm":
        check_lm_fd_step(config.lm, env.sim_dtype, source=source)
    return config


def run_baseline(config: BaselineRunConfig, problem: CalibrationProblem) -> CalibrationResult:
    """Run the configured method on ``problem`` with the configured budget and seed."""
    _, fn = BASELINES[config.method]
    return fn(problem, config.budget, config.method_config, config.seed, config.stop_on_success)


# --------------------------------------------------------------------------------------- run folder


def write_history_csv(result: CalibrationResult, path: Path) -> None:
    """``iteration, simulations, best_score, batch_best_score`` per recorded batch."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["iteration", "simulations", "best_score", "batch_best_score"])
        for i, (sims, best, batch) in enumerate(result.history):
            w.writerow([i, int(sims), repr(float(best)), repr(float(batch))])


def plot_velocities(problem: CalibrationProblem, result: CalibrationResult, path: Path) -> None:
    """Reference vs initial vs calibrated velocity per sensor as compared (re-simulated, not charged to the budget).

    All three curves are the compared signal (:meth:`CalibrationProblem.compared`), the one the metrics measure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with torch.no_grad():
        v = problem.compared(problem.simulate(torch.stack([problem.zeros(1)[0], result.best_x]), count=False).velocity)
    t = np.arange(problem.T) * problem.dt * 1e3
    K = len(problem.sensors)
    fig, axes = plt.subplots(1, K, figsize=(4.5 * K, 3.6), squeeze=False, sharey=True)
    for k, ax in enumerate(axes[0]):
        ax.plot(t, problem.ref_velocity[k].numpy(), "k-", lw=2, label="reference")
        ax.plot(t, v[0, k].numpy(), "C0--", label="initial")
        ax.plot(t, v[1, k].numpy(), "C3-", label=f"calibrated ({result.method})")
        ax.set_title(problem.sensors[k])
        ax.set_xlabel("time [ms]")
        ax.grid(alpha=0.3)
    filt = f" (CFC{problem.compare_cfc}, as compared)" if problem.compare_cfc is not None else ""
    axes[0, 0].set_ylabel(f"velocity [m/s]{filt}")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_path(config: BaselineRunConfig) -> Path:
    """``<out_dir>/<method>/<name>/``, unchecked (:func:`run_folder` checks it)."""
    return Path(config.out_dir) / config.method / config.name


def run_folder(config: BaselineRunConfig) -> Path:
    """``<out_dir>/<method>/<name>/``, checked so a run can fail before it simulates rather than after.

    Raises:
        ConfigError: the folder exists already (key ``name``), or ``out_dir`` is a file (key ``out_dir``).
    """
    final = run_path(config)
    check_output_dir(final, "out_dir")  # its nearest existing folder: <out_dir>/<method> may be another user's
    if final.exists():
        raise ConfigError(f"run folder {final} exists already; choose another name", key="name")
    return final


def run_record(config: BaselineRunConfig) -> dict[str, Any]:
    """The provenance record of a baseline run (:func:`marlcrash.provenance.record`): ``configs/``, the code, and
    the input files its problem names outside ``configs/`` (a vehicle deck, measured pulses). Take it when the run
    starts, so it holds the files the run read."""
    inputs = provenance.env_inputs(problem_env_config(config.problem)) + provenance.reward_input(config.problem.fit)
    return provenance.record(inputs)


def write_run(
    config: BaselineRunConfig,
    problem: CalibrationProblem,
    result: CalibrationResult,
    record: dict[str, Any] | None = None,
) -> Path:
    """Write ``<out_dir>/<method>/<name>/``: ``summary.json``, ``history.csv``, ``best.pt``, ``config.json``,
    ``provenance.json`` (``record``: :func:`run_record` taken when the run started; default: now), then
    ``velocity.png``.

    The results are assembled in a temporary sibling, flushed to disk and renamed into place, so a failed run
    leaves nothing half-written and a system crash after the rename cannot leave empty files. Where another run
    took the folder's name while this one ran (two runs of one name, or of the default launch-second name, at
    once), the results go to the first free ``<name>-<n>`` beside it, with a warning, rather than being lost after
    the budget was spent. The plot (``config.plot``) is drawn into the written folder afterwards: a plotting
    failure is a warning naming the file, never the loss of the results.

    Returns:
        The run folder written.

    Raises:
        ConfigError: ``out_dir`` is a file (:func:`marlcrash.outputs.check_output_dir`).
    """
    final = run_path(config)
    check_output_dir(final, "out_dir")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_sibling(final)
    try:
        summary = result.summary()
        summary.update(
            {"seed": config.seed, "budget": config.budget, "scenario": problem.scenario.name,
             "reference": problem.reference.source[0], "agents": problem.agent_names, "n_free": problem.n_free}
        )  # fmt: skip
        (tmp / "summary.json").write_text(json_text(summary), encoding="utf-8")
        (tmp / "config.json").write_text(json.dumps(asdict(config), indent=2), encoding="utf-8")
        rec = run_record(config) if record is None else record
        (tmp / provenance.PROVENANCE_FILE).write_text(json.dumps(rec, indent=1), encoding="utf-8")
        write_history_csv(result, tmp / "history.csv")
        torch.save({"best_x": result.best_x, "best_params": result.best_params}, tmp / "best.pt")
        sync_folder(tmp)  # on disk before a name points at it
        final = _claim_free(final)
        try:
            os.replace(tmp, final)  # onto the empty folder just claimed
        except BaseException:
            final.rmdir()
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    sync_folder(final.parent, files=False)  # the rename
    if config.plot:
        _plot_into(problem, result, final / "velocity.png")
    return final


def _plot_into(problem: CalibrationProblem, result: CalibrationResult, path: Path) -> None:
    """:func:`plot_velocities` to ``path`` (whole or not at all); a failure is a warning naming the file."""
    try:
        with atomic_output(path) as tmp:
            plot_velocities(problem, result, tmp)
    except Exception as e:  # matplotlib, its backend, the re-simulation: the written results stay
        warnings.warn(f"{path} was not written: plotting failed ({type(e).__name__}: {e}); the run's results are "
                      f"in {path.parent}", stacklevel=3)  # fmt: skip


def _temporary_sibling(folder: Path) -> Path:
    """A new hidden folder beside ``folder`` (:func:`marlcrash.outputs.new_sibling`) with the mode ``mkdir`` gives
    every other folder (``0o777`` less the umask): ``tempfile.mkdtemp`` made it ``0o700``, and renamed into place it
    kept nobody else out of a run whose files they could read."""
    return new_sibling(folder, lambda token: f".{folder.name}.{token}", claim_dir)


def _claim_free(folder: Path) -> Path:
    """``folder``, created here, or where another process has it, the first ``<folder>-<n>`` this call creates."""
    taken = folder
    for n in itertools.count(2):
        if claim_dir(folder):
            break
        folder = taken.with_name(f"{taken.name}-{n}")
    if folder != taken:
        warnings.warn(f"run folder {taken} was made by another run while this one ran; its results are in {folder}",
                      stacklevel=3)  # fmt: skip
    return folder
