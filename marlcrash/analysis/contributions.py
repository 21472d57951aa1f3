"""Per-agent contributions to a calibration (DESIGN 7): which agent's parameter changes moved which metric.

A calibration moves the cell parameters from ``initial`` to ``calibrated``; every agent owns some cells. The
game: a coalition ``S`` of agents is the parameter set with the cells of the agents in ``S`` at their
calibrated values and every other cell at its initial one; its value is every metric of every sensor
(area [m], DFD [m/s] of the (t [s], v [m/s]) curves, RMSE [m/s] against the problem's reference, as the evaluation
computes them) and the fit score [-] (higher is better), all from one batched simulation of the coalitions. Then:

- Shapley values (:mod:`marlcrash.analysis.shapley`): exact for up to ``exact_max`` moving agents, sampled
  orderings otherwise. They add up to the whole calibration's change of each quantity, split fairly over
  interactions (two agents that only help together share the gain).
- Leave-one-out (``v(all) - v(all but i)``: what agent ``i``'s changes are worth at the end) and add-one
  (``v({i}) - v({})``: what they do alone).

Agents whose cells did not move are null players: their contributions are exactly zero and they are not
enumerated. A contribution below zero to an error metric means the agent's changes lowered that error.

:func:`agent_changes` summarizes the calibration per agent and iteration (the actions' net effect on its
cells), :func:`step_directions` where its steps point (do they turn and shorten near a minimum, or walk on past it),
and :func:`run_calibration` loads a training run's evaluated calibration (``calibrated.npz``) with the problem it was
evaluated on.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from marlcrash.analysis.shapley import (
    Attribution,
    check_batch,
    check_exact_max,
    check_permutations,
    check_seed,
    exact_shapley,
    from_table,
    one_at_a_time,
    sampled_shapley,
)
from marlcrash.calibrate.compare import evaluate_params
from marlcrash.calibrate.problem import CalibrationProblem
from marlcrash.cells.parameterization import log_ratios
from marlcrash.errors import ConfigError, ModelError
from marlcrash.metrics import Metrics
from marlcrash.outputs import atomic_output, read_npz, write_text

METRICS = ("area", "dfd", "rmse")
UNITS = {"area": "m", "dfd": "m/s", "rmse": "m/s", "score": "-"}
"""Unit of each metric and of the score (DFD: of the (t [s], v [m/s]) curves, as the evaluation's tables say)."""
MOVE_RTOL = 1e-6
"""A cell parameter counts as moved when it differs from the initial one by more than this relative amount: a run
simulated in float32 stores parameters rounded at about 6e-8 (its unowned cells must not look moved)."""


@dataclass
class Contributions:
    """Per-agent contributions to every quantity (module docstring).

    Attributes:
        agents: ``[A]`` agent names (every agent of the layout).
        quantities: ``[Q]`` names: ``<metric>/<sensor>`` for area, DFD and RMSE of every sensor, then ``score``.
        players: ``[A]`` bool, agents whose cells moved (the others contribute exactly zero).
        initial, calibrated: ``[Q]`` values with no agent's and with every agent's changes.
        shapley: ``[A, Q]`` Shapley values.
        shapley_stderr: ``[A, Q]`` their standard errors (zero for exact values and null players; NaN where the
            sampled orderings cannot tell it: :func:`~marlcrash.analysis.shapley.sampled_shapley`).
        exact: whether the Shapley values were enumerated.
        leave_one_out, add_one: ``[A, Q]`` one-at-a-time effects.
        n_simulations: coalitions simulated.
        settings: ``exact_max``, ``n_permutations`` and ``seed`` the values were computed with
            (:func:`agent_contributions`; ``None`` where not known), listed at the head of :meth:`write_markdown`.
    """

    agents: list[str]
    quantities: list[str]
    players: torch.Tensor
    initial: torch.Tensor
    calibrated: torch.Tensor
    shapley: torch.Tensor
    shapley_stderr: torch.Tensor
    exact: bool
    leave_one_out: torch.Tensor
    add_one: torch.Tensor
    n_simulations: int
    settings: dict[str, int] | None = None

    def column(self, quantity: str) -> int:
        """Index of a quantity by name; :class:`ValueError` listing the names if unknown."""
        if quantity not in self.quantities:
            raise ValueError(f"unknown quantity {quantity!r}; expected one of {self.quantities}")
        return self.quantities.index(quantity)

    def selected(self, quantities: list[str] | None = None) -> list[str]:
        """``quantities`` checked by name, or where ``None`` the default ones: ``score`` and every sensor's area.

        Raises:
            ValueError: an empty list (no panel, no table: not the default's stand-in), one name given as a string
                (not read letter by letter), or an unknown name.
        """
        if quantities is None:
            return ["score", *(q for q in self.quantities if q.startswith("area/"))]
        if isinstance(quantities, str):
            raise ValueError(f"quantities: expected a list of quantity names, got the string {quantities!r} "
                             f"(for one quantity: [{quantities!r}])")  # fmt: skip
        qs = list(quantities)
        if not qs:
            raise ValueError(f"quantities: expected at least one quantity of {self.quantities}, or None for the "
                             "default (score and every sensor's area); got an empty list")  # fmt: skip
        for q in qs:
            self.column(q)
        return qs

    def ranking(self, quantity: str = "score") -> list[tuple[str, float]]:
        """``(agent, Shapley value)`` of the moving agents, largest improvement first (most negative error, most
        positive score)."""
        j = self.column(quantity)
        sign = -1.0 if quantity == "score" else 1.0
        rows = [(a, float(self.shapley[i, j])) for i, a in enumerate(self.agents) if bool(self.players[i])]
        return sorted(rows, key=lambda r: sign * r[1])

    def rows(self) -> list[dict[str, object]]:
        """One row per agent and quantity: ``agent, moved, quantity, unit, shapley, shapley_stderr, leave_one_out,
        add_one`` (the values in the quantity's unit, :func:`quantity_unit`; ``moved``: whether the agent's cells
        moved, so a zero of an agent that never moved reads apart from a move without effect; ``shapley_stderr``
        ``None`` where the sampled orderings cannot tell it, an empty field in the CSV)."""
        return [
            {"agent": a, "moved": bool(self.players[i]), "quantity": q, "unit": quantity_unit(q),
             "shapley": float(self.shapley[i, j]),
             "shapley_stderr": _stderr(self.shapley_stderr[i, j]), "leave_one_out": float(self.leave_one_out[i, j]),
             "add_one": float(self.add_one[i, j])}
            for i, a in enumerate(self.agents) for j, q in enumerate(self.quantities)
        ]  # fmt: skip

    def write_csv(self, path: str | Path) -> Path:
        """All :meth:`rows` as CSV (written atomically)."""
        rows = self.rows()
        with atomic_output(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        return Path(path)

    def markdown(self, quantity: str = "score") -> str:
        """A Markdown table of one quantity (its unit in brackets): the moving agents' contributions, largest
        improvement first."""
        j = self.column(quantity)
        how = "exact" if self.exact else "sampled, ± one standard error"
        lines = [
            f"{quantity} [{quantity_unit(quantity)}]: {float(self.initial[j]):.6g} -> {float(self.calibrated[j]):.6g} "
            f"(Shapley values {how}; {self.n_simulations} simulations)",
            "",
            "| agent | Shapley | leave-one-out | add-one |",
            "|---|---|---|---|",
        ]
        ranked = self.ranking(quantity)
        if not ranked:
            lines.append("| (no agent's cells moved: nothing to credit) | 0 | 0 | 0 |")
        unknown = False
        for a, _ in ranked:
            i = self.agents.index(a)
            err = _stderr(self.shapley_stderr[i, j])
            unknown |= err is None and not self.exact
            se = "" if self.exact else " ± n/a" if err is None else f" ± {err:.3g}"
            lines.append(f"| {a} | {float(self.shapley[i, j]):.4g}{se} | {float(self.leave_one_out[i, j]):.4g} "
                         f"| {float(self.add_one[i, j]):.4g} |")  # fmt: skip
        if unknown:
            lines += ["", "n/a: no standard error can be told from these orderings (every antithetic pair gave the "
                      "agent one value, by the draw); more orderings give one"]  # fmt: skip
        return "\n".join(lines) + "\n"

    def settings_lines(self) -> list[str]:
        """The settings the values were computed with, as Markdown list items: how the Shapley values were computed
        (exact over all coalitions, or how many orderings of which seed, and ``exact_max``), the agents that moved and
        the simulations."""
        s = self.settings or {}
        moved, cap = int(self.players.sum()), f"exact_max {s['exact_max']}" if "exact_max" in s else None
        if moved == 0:
            how = "none to compute: no agent's cells moved"
        elif self.exact:
            who = f"the {moved} agent{'s' if moved > 1 else ''} that moved"
            how = f"exact: all 2**{moved} coalitions of {who}" + (f" ({cap})" if cap else "")
        elif "n_permutations" in s:
            how = (f"sampled: {s['n_permutations']} orderings in antithetic pairs, seed {s['seed']}"
                   + (f" (more agents moved than {cap})" if cap else "") + "; ± one standard error")  # fmt: skip
        else:
            how = "sampled (orderings and seed not recorded); ± one standard error"
        return [f"- Shapley values: {how}",
                f"- {moved} of {len(self.agents)} agents moved; {self.n_simulations} simulations"]  # fmt: skip

    def write_markdown(self, path: str | Path, quantities: list[str] | None = None, heading: str | None = None) -> Path:
        """``# heading`` (default: ``Per-agent contributions``; e.g. what was analysed), the settings
        (:meth:`settings_lines`), then a ``##`` section of :meth:`markdown` per quantity of ``quantities`` (default:
        ``score`` and every sensor's area); written atomically."""
        qs = self.selected(quantities)
        head = [f"# {heading or 'Per-agent contributions'}", "", *self.settings_lines(), ""]
        return write_text(path, "\n".join([*head, *(f"## {self.markdown(q)}" for q in qs)]))


def _stderr(x: torch.Tensor) -> float | None:
    """A standard error as a float, ``None`` where it is NaN (the orderings cannot tell it)."""
    v = float(x)
    return None if math.isnan(v) else v


def quantity_names(sensors: list[str]) -> list[str]:
    """``<metric>/<sensor>`` for every metric and sensor, then ``score`` (the columns of :class:`Contributions`)."""
    return [f"{m}/{s}" for m in METRICS for s in sensors] + ["score"]


def quantity_unit(quantity: str) -> str:
    """Unit of a quantity of :func:`quantity_names` (``m`` for ``area/<sensor>``, ``m/s`` for DFD and RMSE, ``-``
    for ``score``); :class:`ValueError` naming an unknown one."""
    metric = quantity.split("/", 1)[0] if quantity.count("/") == 1 else quantity
    if metric not in UNITS or (metric == "score") != (quantity == "score"):
        raise ValueError(f"unknown quantity {quantity!r}; expected <metric>/<sensor> with a metric of {METRICS}, "
                         "or score")  # fmt: skip
    return UNITS[metric]


def _float64(p: torch.Tensor | np.ndarray, name: str) -> torch.Tensor:
    """Parameters as a float64 CPU tensor of their values: a tensor detached first (a differentiable calibration's
    ``problem.params(x)`` carries gradients; numpy reads neither those, nor bfloat16, nor a GPU's).

    Raises:
        ValueError: naming ``name``, where ``p`` is no array of numbers (``None``, a ragged list, text).
    """
    if isinstance(p, torch.Tensor):
        return p.detach().to("cpu", torch.float64)
    if p is not None and not isinstance(p, str | bytes):
        with contextlib.suppress(TypeError, ValueError):  # what numpy cannot read as numbers: said below
            return torch.as_tensor(np.asarray(p, dtype=np.float64))
    what = type(p).__name__ + ("" if p is None else f" {str(p)[:40]!r}")
    raise ValueError(f"{name}: expected cell parameters (a tensor or an array of numbers), got {what}")


def _check_params(problem: CalibrationProblem, name: str, p: torch.Tensor | np.ndarray) -> torch.Tensor:
    t = _float64(p, name)
    shape = tuple(problem.init.shape)
    if tuple(t.shape) != shape:
        raise ValueError(f"{name}: expected cell parameters of shape {shape}, got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name}: parameters must be finite")
    return t


def _simulable(problem: CalibrationProblem, name: str, p: torch.Tensor, note: str = "") -> None:
    """The simulator's own check of parameters ``[B, n_cells, 7]``, its :class:`ModelError` named ``name`` (and
    ``note``): a bad value is named by its array, not later by a coalition's index or as a NaN in a table."""
    try:
        problem.sim.check_params(p)
    except ModelError as e:
        raise ModelError(f"{name}: {e}{note}") from None


def coalition_params(
    problem: CalibrationProblem,
    initial: torch.Tensor | np.ndarray,
    calibrated: torch.Tensor | np.ndarray,
    members: torch.Tensor,
) -> torch.Tensor:
    """Cell parameters ``[C, n_cells, 7]`` (float64) of coalitions ``members [C, A]`` (bool over every agent).

    Raises:
        ValueError: ``initial`` or ``calibrated`` not finite ``[n_cells, 7]``, or ``members`` not bool ``[C, A]``
            with one column per agent of the layout.
    """
    initial, calibrated = _check_params(problem, "initial", initial), _check_params(problem, "calibrated", calibrated)
    shape_ok = isinstance(members, torch.Tensor) and members.dim() == 2 and members.shape[1] == problem.n_agents
    if not shape_ok or members.dtype != torch.bool:
        got = f"{members.dtype} {list(members.shape)}" if isinstance(members, torch.Tensor) else type(members).__name__
        raise ValueError(f"members: expected bool [coalitions, {problem.n_agents}] (a column for every agent of the "
                         f"layout, {problem.agent_names[0]!r} first), got {got}")  # fmt: skip
    agent = problem.layout.agent_of_cell  # [n], -1 unowned
    take = members[:, agent.clamp_min(0)] & (agent >= 0)[None]  # [C, n]
    return torch.where(take[..., None], calibrated[None], initial[None])


def agent_contributions(
    problem: CalibrationProblem,
    calibrated: torch.Tensor | np.ndarray,
    initial: torch.Tensor | np.ndarray | None = None,
    *,
    exact_max: int = 10,
    n_permutations: int = 64,
    seed: int = 0,
    batch: int = 256,
) -> Contributions:
    """Contributions of every agent's parameter changes to every metric and the fit score (module docstring).

    Args:
        problem: the reference, scenario, window and agents (e.g. :func:`run_calibration`'s).
        calibrated: ``[n_cells, 7]`` calibrated cell parameters.
        initial: ``[n_cells, 7]`` parameters before calibration (default: the problem's initial ones).
        exact_max: enumerate all coalitions when at most this many agents moved (at most
            :data:`~marlcrash.analysis.shapley.MAX_EXACT_PLAYERS`), else sample orderings.
        n_permutations: sampled orderings (even, >= 4; antithetic pairs).
        seed: seed of the orderings.
        batch: coalitions per simulation batch.

    Returns:
        The :class:`Contributions`; the Shapley values of every quantity add up to ``calibrated - initial``.

    Raises:
        ValueError: parameters of the wrong shape, non-finite, or changed in cells no agent owns (then no agent
            can be credited with the change); a bad ``exact_max``, ``n_permutations``, ``seed`` or ``batch``
            (named).
        ModelError: (a :class:`ValueError`) parameters the simulator refuses (``E_x <= 0``, a negative transmission
            factor of an active cell), named ``initial`` or ``calibrated`` and by the cell, before any simulation.
            Also parameters that pass those checks but simulate to a non-finite metric or score, naming the
            quantities and the first coalition that gave one (a guard: since link stiffnesses are clamped, no
            accepted parameters are known to do so; ``E_s`` times 1e200 did before).
    """
    exact_max = check_exact_max(exact_max)
    n_permutations = check_permutations(n_permutations)
    seed, batch = check_seed(seed), check_batch(batch)  # up front: when nothing moved, neither is used
    init = problem.init if initial is None else _check_params(problem, "initial", initial)
    cal = _check_params(problem, "calibrated", calibrated)
    for name, p in (("initial", init), ("calibrated", cal)):
        _simulable(problem, name, p[None])  # up front, before any simulation
    moved_cells = ((cal - init).abs() > MOVE_RTOL * init.abs()).any(-1)  # [n]
    agent = problem.layout.agent_of_cell
    stray = moved_cells & (agent < 0)
    if bool(stray.any()):
        raise ValueError(f"calibrated: {int(stray.sum())} cells that no agent owns differ from the initial "
                         "parameters; their change cannot be credited to an agent")  # fmt: skip
    A = problem.n_agents
    players = torch.zeros(A, dtype=torch.bool)
    players[agent[moved_cells].unique()] = True
    idx = torch.nonzero(players).flatten()
    sensors = list(problem.sensors)
    names = quantity_names(sensors)
    counted = 0

    def value(masks: torch.Tensor) -> torch.Tensor:
        nonlocal counted
        members = torch.zeros(masks.shape[0], A, dtype=torch.bool)
        members[:, idx] = masks
        m = evaluate_params(problem, coalition_params(problem, init, cal, members))
        counted += masks.shape[0]
        score = problem.score(m).to(torch.float64)
        v = torch.cat([m.area, m.dfd, m.rmse, score[:, None]], dim=1).to(torch.float64)
        bad = ~torch.isfinite(v)
        if bool(bad.any()):  # no Shapley table of NaN: stop at the first batch that has one
            row = int(bad.any(1).nonzero()[0])
            cols = [q for q, b in zip(names, bad.any(0).tolist(), strict=True) if b]
            who = [problem.agent_names[i] for i in idx[masks[row]].tolist()] or ["none"]
            raise ModelError(f"the simulations give non-finite {', '.join(cols[:4])}"
                             f"{f' (and {len(cols) - 4} more)' if len(cols) > 4 else ''} (first with the changes of "
                             f"{', '.join(who)}): the parameters lie out of the surrogate's range")  # fmt: skip
        return v

    Q = len(names)
    settings = {"exact_max": exact_max, "n_permutations": n_permutations, "seed": seed}
    zeros = torch.zeros(A, Q, dtype=torch.float64)
    n = int(idx.numel())
    if n == 0:  # nothing moved
        v = value(torch.zeros(1, 0, dtype=torch.bool))[0]
        return Contributions(list(problem.agent_names), names, players, v, v.clone(), zeros, zeros.clone(), True,
                             zeros.clone(), zeros.clone(), counted, settings)  # fmt: skip
    if n <= exact_max:
        att: Attribution = exact_shapley(value, n, batch=batch)
        assert att.table is not None  # exact_shapley always fills the table
        loo, add = from_table(att.table)
    else:
        asked: dict[bytes, torch.Tensor] = {}

        def remembered(masks: torch.Tensor) -> torch.Tensor:  # sampled_shapley's coalitions, seen again below
            keys = [bytes(row) for row in masks.numpy().astype(np.uint8)]
            new = [i for i, k in enumerate(keys) if k not in asked]
            if new:
                for i, row in zip(new, value(masks[new]), strict=True):
                    asked[keys[i]] = row
            return torch.stack([asked[k] for k in keys])

        att = sampled_shapley(remembered, n, n_permutations, seed=seed, batch=batch)
        # the empty and full coalitions, each agent alone and all but each: all simulated above (its end effects),
        # and simulated again, counted twice in n_simulations (44 of 1218 for 21 agents)
        loo, add, _ = one_at_a_time(remembered, n, batch=batch)

    def spread(t: torch.Tensor | None) -> torch.Tensor:
        out = zeros.clone()
        if t is not None:
            out[idx] = t
        return out

    return Contributions(
        agents=list(problem.agent_names), quantities=names, players=players, initial=att.empty, calibrated=att.full,
        shapley=spread(att.phi), shapley_stderr=spread(att.stderr), exact=att.stderr is None,
        leave_one_out=spread(loo), add_one=spread(add), n_simulations=counted, settings=settings,
    )  # fmt: skip


def agent_changes(
    problem: CalibrationProblem, params: torch.Tensor | np.ndarray, initial: torch.Tensor | np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """What the calibration did to each agent's cells, per iteration.

    Args:
        problem: supplies the agents (and the initial parameters where ``initial`` is not given).
        params: ``[I, n_cells, 7]`` cell parameters per calibration iteration (``calibrated.npz``'s
            ``per_iteration``), or one set ``[n_cells, 7]``.
        initial: ``[n_cells, 7]`` the parameters the calibration started from (a run's: :class:`RunCalibration`'s
            ``initial``, as :func:`agent_contributions` is given them; today's problem's may differ where
            ``configs/`` changed since the run); default: the problem's initial parameters.

    Returns:
        ``{"E_x", "E_s"}``: ``[I, A]`` mean log factor of the agent's cells against the initial parameters
        (``log(E / E0)``, ``E0`` of ``initial``, 0.1 = +10.5 %); ``"transmission"``: ``[I, A]`` mean share of load
        moved to other directions (half the L1 change of a cell's five factors, 0 to 1); ``"step"``: ``[I, A]`` the
        root mean square log change of ``E_x, E_s`` from the previous iteration (0 for the first).

    Raises:
        ValueError: ``params`` or ``initial`` of another shape, or no array of numbers.
        ModelError: (a :class:`ValueError`) parameters the simulator refuses (non-finite, ``E_x`` or ``E_s <= 0``, a
            negative transmission factor of an active cell), named by iteration and cell (``initial`` by its name).
    """
    p = _float64(params, "params")
    if p.dim() == 2:
        p = p[None]
    if p.dim() != 3 or tuple(p.shape[1:]) != tuple(problem.init.shape) or p.shape[0] < 1:
        raise ValueError(f"params: expected [iterations, {problem.init.shape[0]}, 7] with at least one iteration, "
                         f"got {tuple(p.shape)}")  # fmt: skip
    # the simulator's check: a log factor of E <= 0 or NaN would be a silent NaN or -inf in the table
    _simulable(problem, "params", p, " (the first index is the iteration)")
    init = problem.init[None] if initial is None else _check_params(problem, "initial", initial)[None]
    _simulable(problem, "initial", init)
    agent = problem.layout.agent_of_cell
    owned = agent >= 0
    A = problem.n_agents
    count = torch.zeros(A, dtype=torch.float64).index_add_(
        0, agent[owned], torch.ones(int(owned.sum()), dtype=torch.float64)
    )
    count = count.clamp_min(1.0)

    def per_agent(x: torch.Tensor) -> np.ndarray:  # [I, n] -> [I, A] means over each agent's cells
        out = torch.zeros(x.shape[0], A, dtype=torch.float64).index_add_(1, agent[owned], x[:, owned])
        return (out / count).numpy()

    log_e = torch.log(p[..., :2] / init[..., :2])  # [I, n, 2]
    moved = 0.5 * (p[..., 2:] - init[..., 2:]).abs().sum(-1)  # [I, n]
    step = torch.zeros_like(log_e[..., 0])
    if p.shape[0] > 1:
        step[1:] = torch.sqrt(0.5 * ((log_e[1:] - log_e[:-1]) ** 2).sum(-1))
    return {"E_x": per_agent(log_e[..., 0]), "E_s": per_agent(log_e[..., 1]), "transmission": per_agent(moved),
            "step": per_agent(step)}  # fmt: skip


def step_directions(
    problem: CalibrationProblem,
    params: torch.Tensor | np.ndarray,
    truth: torch.Tensor | np.ndarray | None = None,
    initial: torch.Tensor | np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Where the calibration's steps point, in the coordinates the agents observe and move.

    A point is every agent's 7 mean log-ratios against ``initial`` (the environment's own-parameter observation:
    ``log(E / E0)`` of ``E_x`` and ``E_s``, ``log((f + floor) / (f0 + floor))`` of a feasible transmission factor, each
    the mean over the agent's cells where it is defined), one vector of ``7 * n_agents`` log-scale values; a step is
    the difference of two successive points. A learned optimizer that settles turns and shortens its steps as the fit
    nears a minimum; one that keeps its steps parallel (``cos_previous`` near 1) walks past it.

    Args:
        problem: supplies the agents, the transmission floor and (where ``initial`` is not given) the initial
            parameters.
        params: ``[I, n_cells, 7]`` cell parameters per calibration iteration, ``I >= 2`` (``calibrated.npz``'s
            ``per_iteration``: the initial parameters first).
        truth: ``[n_cells, 7]`` the twin's hidden parameters, or None.
        initial: ``[n_cells, 7]`` the parameters the log-ratios are taken against (a run's own, as for
            :func:`agent_changes`); default: the problem's initial parameters.

    Returns:
        ``"size"``: ``[I - 1]`` root mean square of each step over the coordinates defined (log scale; 0.1 = 10.5 %);
        ``"cos_previous"``: ``[I - 1]`` cosine of each step to the one before (NaN for the first, or beside a step of
        zero length); ``"cos_net"``: ``[I - 1]`` cosine of each step to the whole move, last point minus first.
        With ``truth``, also ``"cos_truth"``: ``[I - 1]`` cosine of each step to the way from where it started to the
        truth (1: straight at it; below 0: away from it), and ``"distance_truth"``: ``[I]`` root mean square distance
        of each point to the truth's. Both count the coordinates no step of the calibration could move (agents the
        impact-region rule left inactive) too, so a calibration that could not reach the truth reads that way.

    Raises:
        ValueError: ``params`` (fewer than two iterations), ``truth`` or ``initial`` of another shape, or no array of
            numbers.
        ModelError: (a :class:`ValueError`) parameters the simulator refuses, named by array (and iteration).
    """
    p = _float64(params, "params")
    if p.dim() != 3 or tuple(p.shape[1:]) != tuple(problem.init.shape) or p.shape[0] < 2:
        raise ValueError(f"params: expected [iterations, {problem.init.shape[0]}, 7] with at least two iterations (a "
                         f"step), got {tuple(p.shape)}")  # fmt: skip
    _simulable(problem, "params", p, " (the first index is the iteration)")
    init = problem.init if initial is None else _check_params(problem, "initial", initial)
    _simulable(problem, "initial", init[None])
    if truth is not None:
        true = _check_params(problem, "truth", truth)[None]
        _simulable(problem, "truth", true)
    defined = torch.cat([init[:, :2] > 0, problem.feasible], dim=1)  # [n, 7]: as the environment observes
    agent = problem.layout.agent_of_cell
    owned = agent >= 0
    w = torch.zeros(problem.n_agents, init.shape[0], 7, dtype=torch.float64)  # [A, n, 7] mean weights
    w[agent[owned], owned.nonzero()[:, 0]] = defined[owned].to(torch.float64)
    count = w.sum(1)  # [A, 7]
    w = w / count.clamp_min(1.0)[:, None]

    def coordinates(q: torch.Tensor) -> torch.Tensor:  # [I, n, 7] -> [I, D] over the coordinates defined
        return torch.einsum("anc,inc->iac", w, log_ratios(q, init, defined, problem.floor))[:, count > 0]

    z = coordinates(p)
    steps = z[1:] - z[:-1]  # [S, D]
    dims = math.sqrt(z.shape[1])

    def cos(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        na, nb = a.norm(dim=-1), b.norm(dim=-1)
        ok = (na > 0) & (nb > 0)
        return torch.where(ok, (a * b).sum(-1) / torch.where(ok, na * nb, 1.0), torch.nan)

    previous = torch.full((steps.shape[0],), torch.nan, dtype=torch.float64)
    previous[1:] = cos(steps[1:], steps[:-1])
    out = {"size": (steps.norm(dim=-1) / dims).numpy(), "cos_previous": previous.numpy(),
           "cos_net": cos(steps, (z[-1] - z[0]).expand_as(steps)).numpy()}  # fmt: skip
    if truth is not None:
        to_truth = coordinates(true) - z  # [I, D]
        out["cos_truth"] = cos(steps, to_truth[:-1]).numpy()
        out["distance_truth"] = (to_truth.norm(dim=-1) / dims).numpy()
    return out


@dataclass
class RunCalibration:
    """A training run's evaluated calibration: its problem and the cell parameters of ``calibrated.npz``."""

    problem: CalibrationProblem
    initial: torch.Tensor
    calibrated: torch.Tensor
    per_iteration: torch.Tensor
    selected_iteration: int
    true: torch.Tensor | None
    provenance: dict | None = None
    """What changed in ``configs/`` or the code since the run started (the problem is rebuilt from today's files;
    :meth:`marlcrash.provenance.ProvenanceCheck.as_dict`)."""


def require_run_folder(run_dir: str | Path) -> Path:
    """``run_dir`` as a path, refused (key ``run``) where it is not a folder (a file of the run, a typo)."""
    run = Path(run_dir)
    if not run.is_dir():
        raise ConfigError(f"{run} is not a folder; expected a run folder (runs/<algorithm>/<name>) or one of its "
                          "re-evaluations (<run>/eval/<checkpoint>/)", key="run")  # fmt: skip
    return run


RECORDED_RTOL = 1e-6
"""Relative tolerance of :func:`_require_recorded_metrics` (the rebuilt problem gives the evaluation's metrics to the
last digit; float32 runs and another machine's arithmetic stay far inside it)."""


def _require_recorded_metrics(
    run: Path, problem: CalibrationProblem, initial: torch.Tensor, calibrated: torch.Tensor, again: str
) -> None:
    """Refuse (key ``run``) where the rebuilt problem does not give the initial and calibrated metrics that the
    evaluation in ``run`` recorded in its ``summary.json`` (``initial_metrics``, ``final_metrics``): its reference is
    another one. A re-evaluation made while ``configs/`` differed (``<run>/eval/<checkpoint>/``) was analysed against
    the reference of today's files, with no word, since only the run's own start record was checked. Two
    simulations; a folder without those entries (an older evaluation) is not checked."""
    from marlcrash.calibrate.evaluate import SUMMARY_FILE

    try:
        summary = json.loads((run / SUMMARY_FILE).read_text(encoding="utf-8"))
        recorded = [summary["initial_metrics"], summary["final_metrics"]]
    except (OSError, ValueError, KeyError, TypeError):
        return
    now = evaluate_params(problem, torch.stack([initial, calibrated]))
    for row, (what, rec) in enumerate(zip(("initial", "final"), recorded, strict=True)):
        per_sensor = Metrics(now.area[row], now.dfd[row], now.rmse[row]).per_sensor(list(problem.sensors))
        for name, got in per_sensor.items():
            for metric, value in got.items():
                old = rec.get(name, {}).get(metric) if isinstance(rec, dict) else None
                if isinstance(old, int | float) and not math.isclose(value, old, rel_tol=RECORDED_RTOL, abs_tol=1e-12):
                    raise ConfigError(
                        f"{run / SUMMARY_FILE} records {what} {metric} {old:.6g} for {name}, the reference rebuilt "
                        f"from today's configs and code gives {value:.6g}: the evaluation there used other inputs "
                        f"(its summary's provenance says which); {again}, or analyse it with the configs it used",
                        key="run",
                    )


def run_calibration(run_dir: str | Path) -> RunCalibration:
    """Load ``<run>/calibrated.npz`` and rebuild the problem the run was evaluated on (its reference).

    ``run_dir`` is a run folder or one of its re-evaluations (``<run>/eval/<checkpoint>/``, which hold no
    ``config.yaml``: the run's is used). Input files or code changed since the run started are logged as warnings
    and returned (``provenance``): the problem is rebuilt from today's files.

    Raises:
        ConfigError: (key ``run``) no run folder, no ``config.yaml`` or no ``calibrated.npz`` (the run was not
            evaluated yet: ``python train/evaluate.py run=<run>``), or an unreadable one: a member missing, of
            another shape, or parameters the simulator refuses (``initial``, ``calibrated``, ``per_iteration`` and,
            where present, ``true``), named.
    """
    from marlcrash import provenance
    from marlcrash.calibrate.evaluate import EVAL_DIR, evaluation_problem
    from marlcrash.calibrate.marl import CONFIG_FILE, load_run_config, make_env_config

    run = require_run_folder(run_dir)
    where = run.resolve()  # '.' or 'ck' typed inside <run>/eval/ is a re-evaluation too
    home = where.parent.parent if not (run / CONFIG_FILE).is_file() and where.parent.name == EVAL_DIR else run
    config = load_run_config(home, device="cpu")  # no training here: a GPU-trained run is read on any machine
    check = provenance.check_run(home, provenance.env_inputs(make_env_config(config)), key=None)
    provenance.warn_changes(home, check, "contributions")
    path = run / "calibrated.npz"
    if not path.is_file():
        raise ConfigError(f"no calibrated.npz in {run}: evaluate the run first (python train/evaluate.py run={home})",
                          key="run")  # fmt: skip
    again = f"evaluate the run again (python train/evaluate.py run={home})"
    try:
        arrays = read_npz(path)
    except ValueError as e:  # junk, an empty or a cut-short file: say so, not numpy's advice to unpickle it
        raise ConfigError(f"cannot read {path}: {e}; expected the evaluation's calibrated.npz: {again}",
                          key="run") from None  # fmt: skip
    missing = [k for k in ("initial", "calibrated", "per_iteration", "selected_iteration") if k not in arrays]
    if missing:
        raise ConfigError(f"{path} lacks {missing}; expected the evaluation's calibrated.npz: {again}", key="run")
    problem = evaluation_problem(config)
    t = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in arrays.items() if k != "selected_iteration"}
    for k in ("initial", "calibrated", "true"):
        if k not in t:  # no truth: a run evaluated on a test, not a twin
            continue
        try:
            _check_params(problem, f"{path}[{k}]", t[k])
        except ValueError as e:
            raise ConfigError(f"{e} (a run of another vehicle or discretization?)", key="run") from None
    per_it, shape = t["per_iteration"], tuple(problem.init.shape)
    if per_it.ndim != len(shape) + 1 or tuple(per_it.shape[1:]) != shape or per_it.shape[0] < 1:
        raise ConfigError(f"{path}[per_iteration]: expected cell parameters of shape [iterations, {shape[0]}, "
                          f"{shape[1]}], got {tuple(per_it.shape)}: {again}", key="run")  # fmt: skip
    checked = [
        ("initial", t["initial"][None]),
        ("calibrated", t["calibrated"][None]),
        ("per_iteration", per_it),
    ]
    if "true" in t:
        checked.append(("true", t["true"][None]))
    for name, p in checked:
        try:  # the simulator's own check, before any simulation: its batch index is then the step, not a coalition
            problem.sim.check_params(p)
        except ModelError as e:
            step = "" if name != "per_iteration" else " (the first index is the calibration step)"
            raise ConfigError(f"{path}[{name}]: {e}{step}: {again}", key="run") from None
    sel = arrays["selected_iteration"]
    if sel.shape != () or not np.issubdtype(sel.dtype, np.integer) or not 0 <= int(sel) < per_it.shape[0]:
        raise ConfigError(f"{path}[selected_iteration]: expected an iteration in 0..{per_it.shape[0] - 1} of "
                          f"per_iteration, got {sel.tolist()!r}: {again}", key="run")  # fmt: skip
    _require_recorded_metrics(run, problem, t["initial"], t["calibrated"], again)
    return RunCalibration(problem=problem, initial=t["initial"], calibrated=t["calibrated"],
                          per_iteration=t["per_iteration"], selected_iteration=int(arrays["selected_iteration"]),
                          true=t.get("true"), provenance=check.as_dict())  # fmt: skip
