"""Simulation budget and best-so-far bookkeeping shared by all calibrators (DESIGN 6).

Every simulated candidate costs one simulation, whatever the method: a random-search
batch of 64 costs 64, a CMA-ES generation costs its population, a gradient step of a
batch of 4 starting points costs 4 (forward and backward pass together count as one
simulation per candidate). A :class:`Progress` hands out simulations (:meth:`Progress.grant`)
so that an optimizer stops exactly at its budget, and records after every batch the
best fit score reached per simulation count, the best candidate, and the simulation
count at which a candidate first passed the success test.

The best candidate is the one a calibration keeps: a candidate that passes the success test
outranks every one that does not, and the fit score ranks the rest. So a run's result passes
exactly when some candidate passed (``sims_to_success`` is set), and a run stopped on success
returns the candidate it stopped for; the best score can drop once, when the first passing
candidate scores below the failing best before it.
"""

from __future__ import annotations

import numbers
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics


def ranked_scores(score: torch.Tensor) -> torch.Tensor:
    """Fit scores as float64 for ranking (higher is better): a NaN (a failed simulation) becomes ``-inf`` so it
    never wins; ``+inf`` stays the best score there is (no shipped form scores it: ``log_ratio`` needs ``eps > 0``)."""
    s = score.detach().to(torch.float64)
    return torch.where(s.isnan(), torch.full_like(s, float("-inf")), s)


def best_index(score: torch.Tensor, success: torch.Tensor) -> int:
    """Index of the best of ``[N]`` candidates: the highest-scoring one that passes (``success [N]`` bool) where any
    does, else the highest-scoring one (a NaN score never wins, :func:`ranked_scores`). The one rule by which a
    run's record, an evaluation's reported iterate and a comparison's winner rank candidates."""
    s = ranked_scores(score)
    passing = torch.nonzero(success.to(torch.bool))[:, 0]
    return int(passing[torch.argmax(s[passing])]) if passing.numel() else int(torch.argmax(s))


@dataclass
class HistoryRow:
    """One line of the best-score log: after ``simulations`` simulations and ``iteration`` batches."""

    iteration: int
    simulations: int
    batch_best: float
    best: float
    success: bool


@dataclass
class Progress:
    """Budget plus best-so-far record of one calibration run.

    Scores are "higher is better" (the reward form's score, see
    :meth:`marlcrash.calibrate.problem.CalibrationProblem.score`); a candidate that passes the success test
    outranks every one that does not (module docstring).

    Args:
        budget: the number of simulations the run may use, a whole number (any integer type, a numpy one too) >= 1.
        stop_on_success: end the run (``done``) as soon as a candidate passes the success test.

    Attributes:
        used: simulations charged so far.
        best_score: the best candidate's score (``-inf`` before the first record).
        best_x: ``[n_agents, 7]`` the best candidate: the highest-scoring passing one once any passed, else the
            highest-scoring one (``None`` before the first record).
        best_metrics: per-sensor :class:`Metrics` ``[K]`` of the best candidate.
        sims_to_success: simulation count (1-based, counting every candidate evaluated before it)
            at which the first successful candidate was evaluated; ``None`` if none yet.
        history: one :class:`HistoryRow` per recorded batch.
    """

    budget: int
    stop_on_success: bool = False
    used: int = 0
    best_score: float = float("-inf")
    best_x: torch.Tensor | None = None
    best_metrics: Metrics | None = None
    sims_to_success: int | None = None
    history: list[HistoryRow] = field(default_factory=list)
    started: float = field(default_factory=time.perf_counter)

    def __post_init__(self) -> None:
        whole = isinstance(self.budget, numbers.Integral) and not isinstance(self.budget, (bool, np.bool_))
        if not whole or self.budget < 1:  # a numpy integer is a whole number too (np.arange, astype(int))
            got = int(self.budget) if whole else repr(self.budget)
            raise ConfigError(f"expected a whole number of simulations >= 1, got {got}", key="budget")
        self.budget = int(self.budget)

    @property
    def remaining(self) -> int:
        """Simulations left."""
        return self.budget - self.used

    @property
    def done(self) -> bool:
        """Budget spent, or success reached with ``stop_on_success``."""
        return self.remaining <= 0 or (self.stop_on_success and self.sims_to_success is not None)

    @property
    def wall_time(self) -> float:
        """Seconds since the run started [s]."""
        return time.perf_counter() - self.started

    def grant(self, n: int) -> int:
        """How many of ``n`` requested candidates may be simulated (``min(n, remaining)``, >= 0)."""
        return max(0, min(int(n), self.remaining))

    def record(self, x: torch.Tensor, metrics: Metrics, score: torch.Tensor, success: torch.Tensor) -> None:
        """Charge and record one evaluated batch (an empty one, e.g. of ``grant() == 0`` candidates, records nothing).

        Args:
            x: ``[N, n_agents, 7]`` candidates.
            metrics: per-sensor metrics, each ``[N, K]``.
            score: ``[N]`` fit scores (higher is better).
            success: ``[N]`` bool, candidate passes the success test.

        Raises:
            RuntimeError: the batch would exceed the budget (an optimizer skipped :meth:`grant`).
        """
        n = int(score.shape[0])
        if n == 0:  # argmax of nothing raised an IndexError
            return
        if n > self.remaining:
            raise RuntimeError(f"batch of {n} simulations exceeds the remaining budget of {self.remaining}")
        s = ranked_scores(score)  # a NaN never wins
        ok = success.to(torch.bool)
        passing = torch.nonzero(ok)[:, 0]
        k = best_index(s, ok)  # the batch's best
        had = self.sims_to_success is not None  # the best so far passes
        if not had and passing.numel():
            self.sims_to_success = self.used + int(passing[0]) + 1
        self.used += n
        won = bool(ok[k])
        if self.best_x is None or (won and not had) or (won == had and float(s[k]) > self.best_score):
            self.best_score = float(s[k])
            self.best_x = x[k].detach().clone()
            self.best_metrics = Metrics(*(m[k].detach().clone() for m in metrics))
        self.history.append(
            HistoryRow(len(self.history), self.used, float(s[k]), self.best_score, self.sims_to_success is not None)
        )

    def history_array(self) -> np.ndarray:
        """``[H, 3]`` float64: simulations, best candidate's score so far, the batch's best candidate's score, per
        recorded batch (best as :meth:`record` ranks: a passing candidate first)."""
        return np.array([[h.simulations, h.best, h.batch_best] for h in self.history], dtype=np.float64)
