"""Per-agent contributions (marlcrash.analysis): Shapley values against a brute-force reference, and on the
surrogate against direct simulations."""

from __future__ import annotations

import dataclasses
import itertools
import math
import re

import numpy as np
import pytest
import torch
from test_cells_helpers import drawn_figures, drawn_turn_from_x_to_y

from marlcrash.analysis import (
    agent_changes,
    agent_contributions,
    coalition_params,
    exact_shapley,
    one_at_a_time,
    plot_cells_by_contribution,
    plot_contributions,
    run_calibration,
    sampled_shapley,
    step_directions,
)
from marlcrash.analysis.shapley import MAX_EXACT_PLAYERS, from_table
from marlcrash.calibrate.compare import evaluate_params
from marlcrash.calibrate.problem import ProblemConfig, build_problem
from marlcrash.errors import ConfigError, ModelError

# ------------------------------------------------------------------------------------------ toy games
A_ADD = torch.tensor([0.5, -1.0, 2.0, 0.0, 0.25], dtype=torch.float64)


def toy_game(masks: torch.Tensor) -> torch.Tensor:
    """Two quantities: additive plus a pair synergy (players 0 and 1) plus a 3-majority bonus; and additive only."""
    m = masks.to(torch.float64)
    add = m @ A_ADD
    pair = 3.0 * m[:, 0] * m[:, 1]
    majority = 1.5 * (m.sum(1) >= 3).to(torch.float64)
    return torch.stack([add + pair + majority, add], dim=1)


def brute_force_shapley(value, n: int) -> np.ndarray:
    """The textbook definition: the average marginal contribution over all n! orderings, one coalition at a time."""

    def v(members: set[int]) -> np.ndarray:
        mask = torch.zeros(1, n, dtype=torch.bool)
        mask[0, list(members)] = True
        return value(mask)[0].numpy()

    phi = np.zeros((n, 2))
    for order in itertools.permutations(range(n)):
        members: set[int] = set()
        for i in order:
            before = v(members)
            members.add(i)
            phi[i] += v(members) - before
    return phi / math.factorial(n)


def test_exact_shapley_equals_the_brute_force_definition_and_closed_forms():
    att = exact_shapley(toy_game, 5, batch=7)  # a batch that does not divide 32
    np.testing.assert_allclose(att.phi.numpy(), brute_force_shapley(toy_game, 5), rtol=0, atol=1e-12)
    # closed forms: the pair synergy is split equally, the 3-majority bonus symmetrically over the 5 players
    expected0 = 0.5 + 3.0 / 2 + 1.5 / 5
    assert float(att.phi[0, 0]) == pytest.approx(expected0, abs=1e-12)
    assert float(att.phi[3, 0]) == pytest.approx(0.0 + 1.5 / 5, abs=1e-12)
    torch.testing.assert_close(att.phi[:, 1], A_ADD, rtol=0, atol=1e-12)  # additive: each player's own term
    torch.testing.assert_close(att.phi.sum(0), att.full - att.empty, rtol=0, atol=1e-12)  # efficiency
    assert att.stderr is None and att.n_evaluations == 32


def test_sampled_shapley_is_efficient_unbiased_and_exact_on_additive_games():
    exact = exact_shapley(toy_game, 5).phi
    est = sampled_shapley(toy_game, 5, 400, seed=3, batch=50)
    torch.testing.assert_close(est.phi.sum(0), est.full - est.empty, rtol=0, atol=1e-12)  # every ordering telescopes
    z = (est.phi[:, 0] - exact[:, 0]) / est.stderr[:, 0]
    assert float(z.abs().max()) < 4.5, z
    assert float(est.stderr[:, 0].max()) < 0.1
    torch.testing.assert_close(est.phi[:, 1], A_ADD, rtol=0, atol=1e-12)  # no interaction: no sampling error
    assert float(est.stderr[:, 1].max()) < 1e-12
    assert est.n_evaluations <= 32  # shared coalitions are asked once
    again = sampled_shapley(toy_game, 5, 400, seed=3)
    torch.testing.assert_close(again.phi, est.phi, rtol=0, atol=0)  # seeded


def test_a_sampled_player_never_pivotal_gets_no_standard_error_of_zero():
    """Worth 1 only when players 0, 1 and 2 all take part: with 4 orderings, one of them is often never the one that
    completes the three, its sampled marginals all 0, and it was reported 0 +- 0 ("exact") against its 1/3. Its
    leave-one-out effect (1) contradicts them: the error is unavailable. The null players 3 and 4 stay exact."""

    def and3(m: torch.Tensor) -> torch.Tensor:
        return (m[:, 0] & m[:, 1] & m[:, 2]).to(torch.float64)[:, None]

    exact = exact_shapley(and3, 5).phi[:, 0]
    np.testing.assert_allclose(exact.numpy(), [1 / 3, 1 / 3, 1 / 3, 0, 0], rtol=0, atol=1e-12)
    overconfident = never_pivotal = null_exact = 0
    for seed in range(100):
        est = sampled_shapley(and3, 5, 4, seed=seed)
        off = (est.phi[:, 0] - exact).abs() > 0.1
        overconfident += int(((est.stderr[:, 0] == 0) & off).sum())
        never_pivotal += int((est.phi[:3, 0] == 0).sum())
        assert est.phi[3:, 0].tolist() == [0.0, 0.0]
        null_exact += int((est.stderr[3:, 0] == 0).sum())  # else NaN: every pair split the others alike
    assert never_pivotal > 10 and overconfident == 0 and null_exact > 150


def glove_game(masks: torch.Tensor) -> torch.Tensor:
    """Players 0 and 1 hold left gloves, 2 and 3 right ones (a pair is worth 1), player 4 holds nothing."""
    m = masks.to(torch.float64)
    return torch.minimum(m[:, :2].sum(1), m[:, 2:4].sum(1))[:, None]


def test_shapley_axioms_symmetry_and_null_player_exact_and_sampled():
    """Symmetric players get equal values, a null player exactly zero (no sampling error either), and the values
    add up; different seeds draw other orderings (other estimates of a game with three-way interactions), the same
    seed the same ones."""
    exact = exact_shapley(glove_game, 5)
    np.testing.assert_allclose(exact.phi[:, 0].numpy(), [0.5, 0.5, 0.5, 0.5, 0.0], rtol=0, atol=1e-12)
    for seed in (0, 1):
        est = sampled_shapley(glove_game, 5, 6, seed=seed)
        assert float(est.phi[4, 0]) == 0.0 and float(est.stderr[4, 0]) == 0.0  # null player
        assert float(est.phi.sum()) == pytest.approx(2.0, abs=1e-12)  # v(N) - v({}) = 2 pairs
    a, b = sampled_shapley(toy_game, 5, 6, seed=0), sampled_shapley(toy_game, 5, 6, seed=1)
    assert not torch.equal(a.phi[:, 0], b.phi[:, 0])
    torch.testing.assert_close(sampled_shapley(toy_game, 5, 6, seed=1).phi, b.phi, rtol=0, atol=0)


def cubic_game(masks: torch.Tensor) -> torch.Tensor:
    """``(sum of the members' weights 1, 2, 3, ...)**3``: three-way interactions, which antithetic pairs do not
    cancel."""
    m = masks.to(torch.float64)
    w = torch.arange(1, m.shape[1] + 1, dtype=torch.float64)
    return ((m @ w) ** 3)[:, None]


def test_a_sampled_standard_error_is_never_zero_for_an_estimate_that_is_off():
    """With few orderings of few players two antithetic pairs can give one player the same value (an end of one
    ordering is an end of its reverse): their spread, 0, was reported as a standard error of 0 beside an estimate
    off by 6 (3 players, 4 orderings, seed 0). Where the player's marginals differ yet every pair agrees, the sample
    cannot tell the spread: NaN (unavailable), never 0."""
    for n in (3, 4, 5):
        exact = exact_shapley(cubic_game, n).phi[:, 0]
        for seed in range(8):
            est = sampled_shapley(cubic_game, n, 4, seed=seed)
            off = (est.phi[:, 0] - exact).abs() > 1e-9
            se = est.stderr[:, 0]
            assert not bool((off & (se == 0)).any()), (n, seed, est.phi[:, 0] - exact, se)
            assert bool((torch.isnan(se) | (se > 0) | ~off).all())
    est = sampled_shapley(cubic_game, 3, 4, seed=0)  # the case of the docstring: player 2 at an end in both pairs
    assert float((est.phi[2, 0] - exact_shapley(cubic_game, 3).phi[2, 0]).abs()) == pytest.approx(6.0)
    assert math.isnan(float(est.stderr[2, 0])) and bool((est.stderr[:2, 0] > 0).all())
    # two players: the one antithetic pair is every ordering, the estimate exact, its error 0
    two = sampled_shapley(cubic_game, 2, 4, seed=0)
    torch.testing.assert_close(two.phi, exact_shapley(cubic_game, 2).phi, rtol=0, atol=1e-12)
    assert float(two.stderr.abs().max()) == 0.0


def test_contributions_say_a_standard_error_they_cannot_tell(problem, tmp_path):
    """Three agents, 3 antithetic pairs (seed 5): every pair puts bumper_beam_left at an end, so it read
    ``0.00226 ± 0`` as if exact, its add-one and leave-one-out effects 0.0001 and 0.0044 apart. Now ``± n/a`` with a
    note, an empty CSV field (``None``), ``null`` in JSON; the others keep theirs."""
    calibrated, _ = _three_agents_at_the_truth(problem)
    c = agent_contributions(problem, calibrated, exact_max=2, n_permutations=6, seed=5)
    i, j = c.agents.index("bumper_beam_left"), c.column("score")
    assert math.isnan(float(c.shapley_stderr[i, j])) and float(c.add_one[i, j]) != float(c.leave_one_out[i, j])
    assert bool((c.shapley_stderr[c.players][:, j].nan_to_num(1.0) > 0).all())
    md = c.markdown("score")
    assert "| bumper_beam_left | " in md and " ± n/a |" in md and "\nn/a: no standard error" in md
    assert " ± nan" not in md and md.count(" ± n/a") == 1
    row = next(r for r in c.rows() if r["agent"] == "bumper_beam_left" and r["quantity"] == "score")
    assert row["shapley_stderr"] is None
    text = c.write_csv(tmp_path / "c.csv").read_text()
    assert "nan" not in text.lower()


def test_one_at_a_time_effects_and_bad_arguments():
    loo, add, ends = one_at_a_time(toy_game, 5)
    full, empty = toy_game(torch.ones(1, 5, dtype=torch.bool))[0], toy_game(torch.zeros(1, 5, dtype=torch.bool))[0]
    torch.testing.assert_close(ends, torch.stack([empty, full]))
    # leaving player 0 out of the grand coalition loses its own 0.5 and the pair's 3 (majority stays): 3.5
    assert float(loo[0, 0]) == pytest.approx(3.5, abs=1e-12)
    assert float(add[0, 0]) == pytest.approx(0.5, abs=1e-12)
    for bad in (3, 2):  # odd; one antithetic pair has no standard error
        with pytest.raises(ValueError, match="even number of orderings >= 4"):
            sampled_shapley(toy_game, 5, bad)
    exact = exact_shapley(toy_game, 5)
    for got, want in zip(from_table(exact.table), (loo, add), strict=True):  # the exact table holds them too
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    with pytest.raises(ValueError, match="use sampled_shapley"):
        exact_shapley(toy_game, MAX_EXACT_PLAYERS + 1)
    with pytest.raises(ValueError, match="expected \\[coalitions, quantities\\]"):
        exact_shapley(lambda m: torch.zeros(m.shape[0]), 2)
    with pytest.raises(ValueError, match="players >= 1"):
        one_at_a_time(toy_game, 0)


def test_counts_of_any_integer_type_are_counts():
    """A numpy or 0-d torch integer (``players.sum()``, ``np.count_nonzero``) is a number of players or orderings:
    it was refused as 'expected a number of players >= 1, got np.int64(5)'. Bools and floats still are refused."""
    exact = exact_shapley(toy_game, 5)
    for n in (np.int64(5), torch.tensor(5)):
        torch.testing.assert_close(exact_shapley(toy_game, n).phi, exact.phi, rtol=0, atol=0)
        torch.testing.assert_close(one_at_a_time(toy_game, n)[0], one_at_a_time(toy_game, 5)[0], rtol=0, atol=0)
    est = sampled_shapley(toy_game, np.int32(5), np.int64(8), seed=1)
    torch.testing.assert_close(est.phi, sampled_shapley(toy_game, 5, 8, seed=1).phi, rtol=0, atol=0)
    for bad in (True, 5.0, "5"):
        with pytest.raises(ValueError, match="players >= 1"):
            exact_shapley(toy_game, bad)
    with pytest.raises(ValueError, match="even number of orderings"):
        sampled_shapley(toy_game, 5, 8.0)


# ----------------------------------------------------------------------------------- the surrogate
@pytest.fixture(scope="module")
def problem():
    return build_problem(ProblemConfig(duration=0.05))  # the twin of full_width_40 over 50 ms


def _three_agents_at_the_truth(problem) -> tuple[torch.Tensor, list[int]]:
    names = ["crash_box_left", "front_rail_right", "bumper_beam_left"]
    agents = [problem.agent_names.index(a) for a in names]
    members = torch.zeros(1, problem.n_agents, dtype=torch.bool)
    members[0, agents] = True
    return coalition_params(problem, problem.init, problem.true_params, members)[0], agents


def test_contributions_on_the_surrogate_add_up_and_match_direct_simulations(problem):
    calibrated, agents = _three_agents_at_the_truth(problem)
    c = agent_contributions(problem, calibrated)
    assert c.exact and c.n_simulations == 8  # 2**3 coalitions, which hold the one-at-a-time effects too
    assert sorted(np.flatnonzero(c.players.numpy()).tolist()) == sorted(agents)
    others = [i for i in range(problem.n_agents) if i not in agents]
    assert float(c.shapley[others].abs().max()) == 0.0 and float(c.leave_one_out[others].abs().max()) == 0.0
    direct = evaluate_params(problem, torch.stack([problem.init, calibrated]))
    K = len(problem.sensors)
    for j, name in enumerate(("area", "dfd", "rmse")):
        torch.testing.assert_close(c.initial[j * K : (j + 1) * K], getattr(direct, name)[0], rtol=0, atol=1e-12)
        torch.testing.assert_close(c.calibrated[j * K : (j + 1) * K], getattr(direct, name)[1], rtol=0, atol=1e-12)
    torch.testing.assert_close(c.shapley.sum(0), c.calibrated - c.initial, rtol=0, atol=1e-9)
    # leave-one-out of one agent against a simulation of the calibration without that agent's cells
    i = agents[1]
    members = torch.zeros(1, problem.n_agents, dtype=torch.bool)
    members[0, [a for a in agents if a != i]] = True
    without = evaluate_params(problem, coalition_params(problem, problem.init, calibrated, members))
    j = c.column(f"area/{problem.sensors[-1]}")
    assert float(c.leave_one_out[i, j]) == pytest.approx(float(c.calibrated[j] - without.area[0, -1]), abs=1e-12)
    # the sampled estimate agrees with the enumeration (three players: every ordering is one of six)
    s = agent_contributions(problem, calibrated, exact_max=0, n_permutations=200, seed=1)
    assert not s.exact
    err = (s.shapley - c.shapley).abs()
    assert bool((err <= 4.5 * s.shapley_stderr + 1e-9).all())
    assert "| agent | Shapley |" in c.markdown("area/tunnel")
    for q, order in (("area/tunnel", 1.0), ("score", -1.0)):  # largest improvement first: error down, score up
        ranked = c.ranking(q)
        assert sorted(problem.agent_names.index(a) for a, _ in ranked) == sorted(agents)  # the moving agents only
        values = [order * v for _, v in ranked]
        assert values == sorted(values)


def test_contributions_refuse_changes_no_agent_owns(problem):
    calibrated = problem.true_params.clone()
    unowned = int(torch.nonzero(problem.layout.agent_of_cell < 0)[0])
    calibrated[unowned, 1] += 1.0  # (a null cell's E_s is 0)
    with pytest.raises(ValueError, match="no agent owns"):
        agent_contributions(problem, calibrated)
    with pytest.raises(ValueError, match="calibrated: expected cell parameters of shape"):
        agent_contributions(problem, calibrated[:5])
    nothing = agent_contributions(problem, problem.init)
    assert not bool(nothing.players.any()) and float(nothing.shapley.abs().max()) == 0.0
    # the table says so rather than showing a header without rows; the CSV tells "never moved" from "no effect"
    assert "no agent's cells moved" in nothing.markdown("score")
    assert {r["moved"] for r in nothing.rows()} == {False}
    # parameters stored by a float32 run differ from the initial ones by rounding everywhere: not moves
    three, agents = _three_agents_at_the_truth(problem)
    rounded = agent_contributions(problem, three.float().double())
    assert sorted(np.flatnonzero(rounded.players.numpy()).tolist()) == sorted(agents)
    moved_rows = {r["agent"] for r in rounded.rows() if r["moved"]}
    assert moved_rows == {rounded.agents[i] for i in agents}
    assert "no agent's cells moved" not in rounded.markdown("score")
    for kwargs in ({"exact_max": 17}, {"n_permutations": 2}):
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            agent_contributions(problem, three, **kwargs)


def test_contributions_name_an_invalid_parameter_by_its_array_not_a_coalition(problem):
    """A negative ``E_x`` of an owned cell (finite, so past the shape and finiteness checks) is refused before any
    simulation, naming ``calibrated`` or ``initial`` and the cell: not by the batch index of whichever coalition
    happened to take that agent's cells first (``params[23, ...]`` for a sampled ordering)."""
    cell = int(torch.nonzero(problem.layout.agent_of_cell >= 0)[0])
    bad = problem.true_params.clone()
    bad[cell, 0] = -1.0
    for kwargs in ({}, {"exact_max": 0, "n_permutations": 4}):
        with pytest.raises(ValueError, match=rf"^calibrated: params\[0, {cell}, 0\] \(E_x\) of active cell {cell}"):
            agent_contributions(problem, bad, **kwargs)
    with pytest.raises(ValueError, match=rf"^initial: params\[0, {cell}, 0\] \(E_x\)"):
        agent_contributions(problem, problem.true_params, bad, exact_max=0, n_permutations=4)


def nan_where_moved(monkeypatch, cells: torch.Tensor) -> None:
    """Make every simulation whose parameters move ``cells`` give a NaN area (a simulator failure; the clamped link
    stiffness leaves no parameters the input checks accept that do, so the failure is injected)."""
    from marlcrash.analysis import contributions

    real = contributions.evaluate_params

    def failing(problem, params):
        m = real(problem, params)
        moved = (params[:, cells] != problem.init[cells]).flatten(1).any(1)
        m.area[moved] = float("nan")
        return m

    monkeypatch.setattr(contributions, "evaluate_params", failing)


def test_contributions_refuse_parameters_that_simulate_to_nan(problem, monkeypatch):
    """Parameters that pass every input check but simulate to NaN: the library refuses them naming the quantities
    and the agent, exact or sampled, instead of returning a table of NaN (only the CLI checked)."""
    three, agents = _three_agents_at_the_truth(problem)
    name = problem.agent_names[agents[0]]
    nan_where_moved(monkeypatch, problem.layout.agent_of_cell == agents[0])
    for kwargs in ({}, {"exact_max": 0, "n_permutations": 4}):
        with pytest.raises(
            ModelError,
            match=r"^the simulations give non-finite area/upfront_left, area/upfront_right, area/tunnel, score "
            rf"\(first with the changes of [^)]*\b{name}\b[^)]*\): the parameters lie out of the surrogate's range",
        ):
            agent_contributions(problem, three, **kwargs)


def test_coalition_params_names_members_of_the_wrong_shape_or_type(problem):
    """``members`` is ``[C, A]`` bool over every agent of the layout: one column per moving agent, a single row or
    0/1 integers are refused naming ``members``, not by torch's IndexError or ``where`` from inside."""
    A = problem.n_agents
    ok = coalition_params(problem, problem.init, problem.true_params, torch.ones(2, A, dtype=torch.bool))
    torch.testing.assert_close(ok[1], coalition_params(problem, problem.init, problem.true_params,
                                                       torch.ones(1, A, dtype=torch.bool))[0])  # fmt: skip
    for bad in (
        torch.ones(1, 3, dtype=torch.bool),
        torch.ones(A, dtype=torch.bool),
        torch.ones(1, A, dtype=torch.int64),
    ):
        with pytest.raises(ValueError, match=rf"^members: expected bool \[coalitions, {A}\]"):
            coalition_params(problem, problem.init, problem.true_params, bad)


def test_agent_changes_reads_each_agents_factors(problem):
    a = problem.agent_names.index("front_rail_left")
    cells = problem.layout.agent_of_cell == a
    p = problem.init.clone()
    p[cells, 1] *= 1.1  # E_s of every cell of the agent +10 %
    ch = agent_changes(problem, torch.stack([problem.init, p]))
    assert ch["E_s"].shape == (2, problem.n_agents)
    assert ch["E_s"][1, a] == pytest.approx(math.log(1.1), abs=1e-12)
    assert np.abs(np.delete(ch["E_s"][1], a)).max() == 0.0 and np.abs(ch["E_x"]).max() == 0.0
    assert ch["step"][1, a] == pytest.approx(math.log(1.1) / math.sqrt(2), abs=1e-12)
    assert np.abs(ch["transmission"]).max() == 0.0
    with pytest.raises(ValueError, match="params: expected"):
        agent_changes(problem, p[:3])
    # no iteration: accepted as [0, A] tables, and a notebook's max over them failed inside numpy
    with pytest.raises(ValueError, match=r"with at least one iteration, got \(0, "):
        agent_changes(problem, p[None][:0])


def _line(problem, coefficients, direction) -> torch.Tensor:
    """Cell parameters of the candidates ``k * direction`` (per-agent log increments), one per coefficient."""
    x = torch.stack([k * direction for k in coefficients])
    return problem.params(x)


def test_step_directions_measure_parallel_reversed_and_turning_steps_against_the_truth(problem):
    """Steps along one line: parallel (cosine 1 to each other and to the net move), at the truth until they pass it
    (cosine +1), away after (-1), with distances |k - 2.5| times the step; a step back reverses (-1); a step on
    another agent's coordinate is orthogonal (0). E_x and E_s only, so the log coordinates are linear in the increments
    and every figure has its closed form."""
    a, b = problem.agent_names.index("front_rail_left"), problem.agent_names.index("crash_box_right")
    d = torch.zeros(problem.n_agents, 7, dtype=torch.float64)
    d[a, 0], d[a, 1] = 0.02, -0.01
    truth = _line(problem, [2.5], d)[0]
    out = step_directions(problem, _line(problem, [0, 1, 2, 3, 4], d), truth)
    assert np.isnan(out["cos_previous"][0])
    np.testing.assert_allclose(out["cos_previous"][1:], 1.0, atol=1e-12)
    np.testing.assert_allclose(out["cos_net"], 1.0, atol=1e-12)
    np.testing.assert_allclose(out["cos_truth"], [1, 1, 1, -1], atol=1e-12)
    # the rms runs over every agent's coordinates some cell of it defines (E > 0, a feasible transmission factor)
    owner = problem.layout.agent_of_cell
    defined = torch.cat([problem.init[:, :2] > 0, problem.feasible], dim=1)
    dims = sum(int(defined[owner == i].any(0).sum()) for i in range(problem.n_agents))
    step = math.hypot(0.02, 0.01) / math.sqrt(dims)
    np.testing.assert_allclose(out["size"], step, rtol=1e-9)
    np.testing.assert_allclose(out["distance_truth"], step * np.abs(np.arange(5) - 2.5), rtol=1e-9)
    e = torch.zeros_like(d)
    e[b, 1] = 0.03
    zigzag = problem.params(torch.stack([0 * d, d, 0 * d, e]))  # out, back, then sideways on another agent
    out = step_directions(problem, zigzag)
    np.testing.assert_allclose(out["cos_previous"][1:], [-1.0, 0.0], atol=1e-12)
    assert np.isnan(out["cos_net"][:2]).sum() == 0 and "cos_truth" not in out and "distance_truth" not in out
    np.testing.assert_allclose(out["size"][0], out["size"][1], rtol=1e-12)
    still = step_directions(problem, torch.stack([problem.init, problem.init]))
    assert still["size"][0] == 0.0 and np.isnan(still["cos_net"][0])  # a zero step has no direction
    with pytest.raises(ValueError, match="at least two iterations"):
        step_directions(problem, problem.init[None])
    with pytest.raises(ValueError, match="truth: expected"):
        step_directions(problem, zigzag, truth=problem.init[:3])


def test_step_directions_read_the_coordinates_the_environment_observes(problem):
    """Against the environment's own observation (every agent's mean log-ratios, ``param_scale`` 1): a random walk of
    every free coordinate, transmission factors included (renormalised, some at zero), from another starting set
    than the problem's initial one, gives the same cosines and relative step sizes from either."""
    from marlcrash.envs.core import CalibrationCore, load_env_config

    core = CalibrationCore(load_env_config(overrides={"observation.param_scale": 1.0}), 1)
    core.reset(seed=0)
    assert torch.equal(core.init, problem.init)  # the same cells and agents
    gen = torch.Generator().manual_seed(3)
    walk = torch.cumsum(0.05 * torch.randn(6, problem.n_agents, 7, generator=gen, dtype=torch.float64), 0)
    walk[0] = 0.0
    start = problem.params(0.1 * torch.randn(1, problem.n_agents, 7, generator=gen, dtype=torch.float64))[0]
    params = problem.params(walk)  # moves from the problem's initial parameters, read against `start`
    assert (params[:, :, 2:] == 0).any() and not torch.equal(start, problem.init)
    core.init = start.clone()
    KT = core.K * core.T
    seen = []
    for q in params:
        core.params = q[None].clone()
        seen.append(core.observations()[0][0, :, KT : KT + 7].reshape(-1).double())
    z = torch.stack(seen)
    steps = z[1:] - z[:-1]
    cos = lambda a, b: float(a @ b / (a.norm() * b.norm()))  # noqa: E731
    truth = problem.true_params
    core.params = truth[None].clone()
    at_truth = core.observations()[0][0, :, KT : KT + 7].reshape(-1).double()
    out = step_directions(problem, params, truth, initial=start)
    np.testing.assert_allclose(out["cos_previous"][1:], [cos(steps[k], steps[k - 1]) for k in range(1, 5)], atol=1e-5)
    np.testing.assert_allclose(out["cos_net"], [cos(s, z[-1] - z[0]) for s in steps], atol=1e-5)
    np.testing.assert_allclose(out["cos_truth"], [cos(steps[k], at_truth - z[k]) for k in range(5)], atol=1e-5)
    np.testing.assert_allclose(out["size"] / out["size"][0], (steps.norm(dim=1) / steps[0].norm()).numpy(), rtol=1e-5)
    dist = (at_truth - z).norm(dim=1)
    np.testing.assert_allclose(out["distance_truth"] / out["distance_truth"][0], (dist / dist[0]).numpy(), rtol=1e-5)


def test_parameters_that_carry_gradients_are_read_as_their_values(problem):
    """Parameters of a differentiable calibration (``problem.params(x)`` of an ``x`` that requires grad) failed inside
    torch's ``numpy()`` ("Can't call numpy() on Tensor that requires grad") in every entry point; bfloat16 ones as an
    "unsupported ScalarType". They are read as their values."""
    calibrated, _ = _three_agents_at_the_truth(problem)
    tracked = calibrated.clone().requires_grad_(True)
    want = agent_contributions(problem, calibrated)
    got = agent_contributions(problem, tracked, problem.init.clone().requires_grad_(True))
    assert torch.equal(got.shapley, want.shapley) and torch.equal(got.calibrated, want.calibrated)
    members = torch.ones(1, problem.n_agents, dtype=torch.bool)
    assert torch.equal(coalition_params(problem, problem.init, tracked, members)[0], calibrated)
    ch = agent_changes(problem, torch.stack([problem.init, tracked]))
    assert np.array_equal(ch["E_s"], agent_changes(problem, torch.stack([problem.init, calibrated]))["E_s"])
    rounded = calibrated.to(torch.bfloat16)
    assert np.array_equal(agent_changes(problem, rounded)["E_x"], agent_changes(problem, rounded.double())["E_x"])


def test_plots_and_tables_are_written(problem, tmp_path):
    calibrated, _ = _three_agents_at_the_truth(problem)
    c = agent_contributions(problem, calibrated)
    written = [
        plot_contributions(c, tmp_path / "bars.png"),
        c.write_csv(tmp_path / "c.csv"),
        plot_cells_by_contribution(problem, c, tmp_path / "3d.png"),
        c.write_markdown(tmp_path / "c.md"),
    ]
    for path in written:
        assert path.stat().st_size > 200
    rows = (tmp_path / "c.csv").read_text().splitlines()
    assert len(rows) == 1 + problem.n_agents * len(c.quantities)


def test_the_markdown_tables_are_headed_by_the_settings_they_were_computed_with(problem, tmp_path):
    """contributions.md as the notebook writes it (no heading given) had no heading at all and no word of how the
    Shapley values were computed (exact, or how many orderings of which seed); the command's heading was one plain
    line. Now a title, the settings as a list, and one section per quantity, as compare.md and ablate.md are laid
    out."""
    calibrated, _ = _three_agents_at_the_truth(problem)
    sampled = agent_contributions(problem, calibrated, exact_max=2, n_permutations=6, seed=5)
    text = sampled.write_markdown(tmp_path / "s.md").read_text()
    lines = text.splitlines()
    assert lines[0] == "# Per-agent contributions" and lines[1] == ""
    settings = [x for x in lines if x.startswith("- ")]
    assert any("sampled" in x and "6 orderings" in x and "seed 5" in x and "exact_max 2" in x for x in settings), text
    assert any("3 of 21 agents moved" in x and f"{sampled.n_simulations} simulations" in x for x in settings), text
    # 3 orderings' prefixes, each agent alone and all but each: the 2**3 coalitions, each simulated once (the
    # one-at-a-time effects simulated the 2 * 3 + 2 end coalitions again, and counted 16)
    assert sampled.n_simulations == 8
    sections = [x for x in lines if x.startswith("## ")]
    assert [x.split(" ")[1] for x in sections] == sampled.selected()  # score, then every sensor's area
    exact = agent_contributions(problem, calibrated, exact_max=3, n_permutations=6, seed=5)
    text = exact.write_markdown(tmp_path / "e.md", heading="Contributions: the truth").read_text()
    assert text.startswith("# Contributions: the truth\n\n- ")
    assert "exact: all 2**3 coalitions of the 3 agents that moved (exact_max 3)" in text and "seed" not in text


def test_the_contribution_view_draws_the_cars_left_on_its_left(problem, tmp_path, monkeypatch):
    """The cells coloured by contribution were drawn mirrored (matplotlib's axes are right-handed, marlcrash's frame
    x rearward, y left, z up is not): a left offset impact's agents were coloured on the car's right side."""
    calibrated, _ = _three_agents_at_the_truth(problem)
    figs = drawn_figures(monkeypatch)
    plot_cells_by_contribution(problem, agent_contributions(problem, calibrated), tmp_path / "3d.png")
    ax = figs[0].axes[0]
    xyz = np.concatenate([np.column_stack([np.asarray(a) for a in c._offsets3d]) for c in ax.collections])
    np.testing.assert_allclose(np.sort(xyz, axis=0), np.sort(np.asarray(problem.cells.centroid), axis=0), atol=1e-12)
    assert drawn_turn_from_x_to_y(ax) == -1.0


def test_cells_are_coloured_only_by_contributions_of_the_problems_agents(problem, tmp_path):
    """Contributions of another agent layout (``agents.split_lr: []`` has 16 agents, in another order) are refused
    naming ``contrib``: with fewer agents numpy's IndexError came from deep inside, and with as many (or more) the
    cells were silently coloured by other agents' values."""
    import dataclasses

    calibrated, _ = _three_agents_at_the_truth(problem)
    c = agent_contributions(problem, calibrated)
    A = problem.n_agents
    more = {"agents": [*c.agents, "extra"], "players": torch.cat([c.players, c.players[:1]]),
            "shapley": torch.cat([c.shapley, c.shapley[:1]])}  # fmt: skip
    for other in (
        dataclasses.replace(c, agents=c.agents[::-1]),  # as many agents, in another order: the wrong colours
        dataclasses.replace(c, agents=c.agents[:16], players=c.players[:16], shapley=c.shapley[:16]),
        dataclasses.replace(c, **more),
    ):
        with pytest.raises(ValueError, match=rf"^contrib: .*not the {A} agents of the problem"):
            plot_cells_by_contribution(problem, other, tmp_path / "3d.png")
    assert not (tmp_path / "3d.png").exists()


def test_an_empty_list_of_quantities_is_refused_not_read_as_the_default(problem, tmp_path):
    """``quantities=[]`` (e.g. a filter on the names that matched nothing) asks for no panel and no table: refused
    naming ``quantities``, where it drew and wrote the default ones (score and every area) as if it were ``None``."""
    c = agent_contributions(problem, problem.init)  # nothing moved: one simulation
    for call in (lambda: plot_contributions(c, tmp_path / "bars.png", quantities=[]),
                 lambda: c.write_markdown(tmp_path / "c.md", quantities=[])):  # fmt: skip
        with pytest.raises(ValueError, match=r"^quantities: expected at least one quantity of \['area/"):
            call()
    assert not any(tmp_path.iterdir())
    assert c.write_markdown(tmp_path / "c.md").read_text().count("| agent |") == 1 + len(problem.sensors)


def write_evaluated_run(run_dir, reference_seed: int = 2):
    """A run folder as train/train.py leaves it for the analysis: config.yaml and calibrated.npz (two iterates: the
    initial parameters and the twin's truth). Returns the problem of that twin."""
    from test_train_config import composed

    from marlcrash.calibrate.marl import load_train_config, save_run_config

    save_run_config(load_train_config(composed([f"eval.reference_seed={reference_seed}"]), ci=False), run_dir)
    problem = build_problem(ProblemConfig(reference_seed=reference_seed))
    per_it = torch.stack([problem.init, problem.true_params])
    arrays = {"initial": per_it[0].numpy(), "calibrated": per_it[1].numpy(), "per_iteration": per_it.numpy(),
              "selected_iteration": np.array(1), "true": problem.true_params.numpy()}  # fmt: skip
    np.savez(run_dir / "calibrated.npz", **arrays)
    return problem


def test_run_calibration_loads_an_evaluated_run(tmp_path):
    problem = write_evaluated_run(tmp_path)
    rc = run_calibration(tmp_path)
    torch.testing.assert_close(rc.problem.true_params, problem.true_params, rtol=0, atol=0)  # the same twin
    assert rc.selected_iteration == 1 and rc.per_iteration.shape == (2, *problem.init.shape)
    (tmp_path / "calibrated.npz").rename(tmp_path / "keep.npz")
    np.savez(tmp_path / "calibrated.npz", initial=problem.init.numpy())
    with pytest.raises(ConfigError, match="lacks"):
        run_calibration(tmp_path)
    np.savez(tmp_path / "calibrated.npz", **{k: np.zeros((2, 7)) if k in ("initial", "calibrated") else v
                                             for k, v in np.load(tmp_path / "keep.npz").items()})  # fmt: skip
    with pytest.raises(ConfigError, match="another vehicle or discretization") as e:
        run_calibration(tmp_path)
    (tmp_path / "calibrated.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ConfigError, match="cannot read") as e:
        run_calibration(tmp_path)
    real = (tmp_path / "keep.npz").read_bytes()
    for junk, words in [
        (b"junk\n", "not a .npz archive"),  # numpy would suggest allow_pickle= for this
        (b"", "the file is empty"),
        (real[: len(real) // 2], "a damaged .npz archive, cut short"),  # a copy or a write that stopped midway
    ]:
        (tmp_path / "calibrated.npz").write_bytes(junk)
        with pytest.raises(ConfigError, match=re.escape(f"cannot read {tmp_path / 'calibrated.npz'}: {words}")) as e:
            run_calibration(tmp_path)
        assert "pickle" not in str(e.value) and "evaluate the run again" in str(e.value) and e.value.key == "run"
    keep = dict(np.load(tmp_path / "keep.npz"))
    np.savez(tmp_path / "calibrated.npz", **{**keep, "selected_iteration": np.array([object()], dtype=object)})
    with pytest.raises(ConfigError, match="an array holds Python objects; expected numeric arrays"):
        run_calibration(tmp_path)
    for bad, words in [
        ({"selected_iteration": np.array(2)}, r"\[selected_iteration\]: expected an iteration in 0\.\.1 of "),
        ({"selected_iteration": np.array(0.5)}, r"\[selected_iteration\]: expected an iteration"),
        ({"per_iteration": keep["per_iteration"][0]}, r"\[per_iteration\]: expected cell parameters of shape"),
        ({"calibrated": np.array(["a"])}, r"member 'calibrated' is not a numeric array"),
    ]:
        np.savez(tmp_path / "calibrated.npz", **{**keep, **bad})
        with pytest.raises(ConfigError, match=r"calibrated\.npz.*" + words):
            run_calibration(tmp_path)
    (tmp_path / "calibrated.npz").unlink()
    with pytest.raises(ConfigError, match=r"no calibrated\.npz") as e:
        run_calibration(tmp_path)
    assert e.value.key == "run"


def test_a_folder_whose_evaluation_used_another_reference_is_refused(tmp_path):
    """A re-evaluation made while configs/ differed (<run>/eval/<checkpoint>/, a changed twin spread) was analysed
    against the reference of today's files with no word: only the run's start record was checked. The metrics its
    summary.json records for the initial and calibrated parameters are now compared with the rebuilt problem's."""
    import json

    from marlcrash.metrics import Metrics

    problem = write_evaluated_run(tmp_path)
    m = evaluate_params(problem, torch.stack([problem.init, problem.true_params]))
    rows = [Metrics(m.area[i], m.dfd[i], m.rmse[i]).per_sensor(list(problem.sensors)) for i in range(2)]
    summary = {"initial_metrics": rows[0], "final_metrics": rows[1]}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert run_calibration(tmp_path).selected_iteration == 1  # the evaluation's own reference: accepted
    sensor = problem.sensors[0]
    rows[0][sensor]["area"] *= 1.01  # the evaluation's twin was another one
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(ConfigError, match=rf"records initial area .* for {sensor}, the reference rebuilt") as e:
        run_calibration(tmp_path)
    assert e.value.key == "run" and "evaluate the run again" in str(e.value)


def test_contributions_command_analyses_a_run_and_names_bad_arguments(tmp_path, capsys, monkeypatch):
    """``marlcrash contributions RUN``: the evaluated run's iterate, Shapley values that add up to the whole change
    (here: to the twin's truth, every area to zero), the tables and pictures; bad arguments exit 2 naming the flag."""
    import csv
    import json

    from marlcrash.cli import main

    run = tmp_path / "run"
    run.mkdir()
    write_evaluated_run(run)
    out = tmp_path / "c"
    assert main(["contributions", str(run), "--permutations", "4", "--out", str(out), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["iteration"] == 1 and s["agents_moved"] == s["n_agents"] == 21 and not s["exact"]
    assert s["settings"] == {"exact_max": 10, "n_permutations": 4, "seed": 0}  # which orderings made the values
    names = ("contributions.csv", "contributions.md", "contributions.png", "cells.png")
    assert sorted(s["files"]) == sorted(str(out / f) for f in names)
    for q, v in s["quantities"].items():
        assert sum(v["shapley"].values()) == pytest.approx(v["calibrated"] - v["initial"], abs=1e-9), q
        if q.startswith("area/"):
            assert v["calibrated"] == pytest.approx(0.0, abs=1e-12) and v["initial"] > 0.01
    assert len((out / "contributions.csv").read_text().splitlines()) == 1 + 21 * len(s["quantities"])

    # no RUN: the twin's truth of the main job's evaluation reference (seed 0), what a calibration must find
    assert main(["contributions", "--permutations", "4", "--no-plots", "--out", str(out / "truth"), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["analysed"].startswith("twin truth") and st["iteration"] is None and st["agents_moved"] == 21
    assert st["quantities"]["area/tunnel"]["calibrated"] == pytest.approx(0.0, abs=1e-12)
    assert st["quantities"]["area/tunnel"]["initial"] != pytest.approx(s["quantities"]["area/tunnel"]["initial"])

    # step 0 is the initial parameters: nothing moved, nothing to credit
    assert main(["contributions", str(run), "--iteration", "0", "--no-plots", "--out", str(out / "i0"), "--json"]) == 0
    s0 = json.loads(capsys.readouterr().out)
    assert s0["agents_moved"] == 0
    for v in s0["quantities"].values():
        assert v["calibrated"] == v["initial"] and v["shapley"] == {}  # no moving agent is ranked
    rows0 = list(csv.DictReader((out / "i0" / "contributions.csv").open()))
    assert len(rows0) == 21 * len(s0["quantities"]) and all(float(r["shapley"]) == 0.0 for r in rows0)
    assert s0["provenance"]["recorded"] is False  # this folder has no provenance.json: changes cannot be told

    # without --out: one folder per analysed step inside the run, so another step never replaces its files; a
    # re-evaluation folder (<run>/eval/<checkpoint>/, no config.yaml of its own) is analysed with the run's config
    again = run / "eval" / "checkpoint_steps2"
    again.mkdir(parents=True)
    (again / "calibrated.npz").write_bytes((run / "calibrated.npz").read_bytes())
    for where in (run, again):
        assert main(["contributions", str(where), "--iteration", "0", "--no-plots", "--json"]) == 0
        files = json.loads(capsys.readouterr().out)["files"]
        assert files[0] == str(where / "contributions" / "iteration_0" / "contributions.csv")

    # an earlier analysis is refused before any simulation (its tables do not say their settings), and with
    # --replace it goes whole: no picture of it stays beside tables of another
    assert main(["contributions", str(run), "--permutations", "4", "--out", str(out)]) == 2
    assert "key '--out'" in (err := capsys.readouterr().err) and "holds an earlier analysis" in err
    assert main(["contributions", str(run), "--iteration", "0", "--no-plots", "--out", str(out), "--replace"]) == 0
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == ["contributions.csv", "contributions.md"]
    assert (out / "contributions.md").read_text().startswith(f"# Contributions: {run}, calibration step 0\n\n- ")
    capsys.readouterr()
    monkeypatch.chdir(again)  # a re-evaluation folder named as '.' (no config.yaml of its own) is one still
    assert main(["contributions", ".", "--iteration", "0", "--no-plots", "--out", str(out / "dot"), "--json"]) == 0
    capsys.readouterr()
    monkeypatch.chdir(tmp_path)

    for argv, flag in (
        ([str(run / "calibrated.npz")], "run"),  # a file of the run, not the run
        ([str(run), "--iteration", "2"], "--iteration"),
        ([str(run), "--permutations", "6", "--exact-max", "17"], "--exact-max"),
        ([str(run), "--permutations", "5"], "--permutations"),
        ([str(run), "--out", str(run / "calibrated.npz")], "--out"),
        ([str(tmp_path)], "run"),  # no run folder
    ):
        assert main(["contributions", *argv]) == 2, argv
        assert f"key '{flag}'" in capsys.readouterr().err, argv
    (run / "calibrated.npz").unlink()  # a run not evaluated yet
    assert main(["contributions", str(run)]) == 2
    assert "evaluate the run first" in capsys.readouterr().err
    (again / "calibrated.npz").unlink()  # its eval subfolder: the hint names the run, which evaluate.py accepts
    assert main(["contributions", str(again)]) == 2
    assert f"(python train/evaluate.py run={run})" in capsys.readouterr().err


def test_contributions_of_parameters_that_simulate_to_nan_are_refused(tmp_path, capsys, monkeypatch):
    """Simulations that give NaN: an error naming the run, its step and the quantities, not a table of NaN and
    JSON that is not JSON, and no files."""
    from marlcrash.cli import main

    problem = write_evaluated_run(tmp_path)
    nan_where_moved(monkeypatch, problem.layout.agent_of_cell >= 0)
    assert main(["contributions", str(tmp_path), "--permutations", "4", "--no-plots", "--json"]) == 2
    err = capsys.readouterr().err
    assert "key 'run'" in err and f"{tmp_path}, calibration step 1: the simulations give non-finite area/" in err
    assert "out of the surrogate's range" in err
    assert not (tmp_path / "contributions").exists()  # nor an empty folder it made for its files


def test_an_invalid_parameter_in_calibrated_npz_is_named_by_file_and_step(tmp_path):
    """A negative ``E_x`` at step 1 is refused when the run is loaded, naming the file and the step: not later, by
    the index of a coalition inside a simulation batch."""
    problem = write_evaluated_run(tmp_path)
    arrays = dict(np.load(tmp_path / "calibrated.npz"))
    cell = int(torch.nonzero(problem.layout.agent_of_cell >= 0)[0])
    arrays["per_iteration"][1][cell, 0] = -1.0
    np.savez(tmp_path / "calibrated.npz", **arrays)
    with pytest.raises(ConfigError, match=rf"calibrated\.npz\[per_iteration\]: params\[1, {cell}, 0\] \(E_x\).*"
                                          r"the first index is the calibration step") as e:  # fmt: skip
        run_calibration(tmp_path)
    assert e.value.key == "run"


def test_bad_seed_batch_and_exact_max_are_refused_naming_the_argument(problem):
    """A negative or non-integer ``seed``, a ``batch`` below 1 or not an integer and an ``exact_max`` that is not an
    integer are refused naming the argument: they got numpy's 'expected non-negative integer', 'SeedSequence expects
    int', torch's "'float' object cannot be interpreted as an integer" or a TypeError of '<=' from inside."""
    for seed in (-1, 1.5, "0", True):
        with pytest.raises(ValueError, match=r"^seed: expected an integer seed >= 0"):
            sampled_shapley(toy_game, 5, 8, seed=seed)
    for batch in (0, 1.5, "2"):
        for call in (exact_shapley, one_at_a_time, lambda g, n, batch: sampled_shapley(g, n, 4, batch=batch)):
            with pytest.raises(ValueError, match=r"^batch: expected a number of coalitions >= 1"):
                call(toy_game, 3, batch=batch)
    est = sampled_shapley(toy_game, 5, 8, seed=np.uint64(2**64 - 1), batch=np.int64(3))  # integers of any kind
    torch.testing.assert_close(est.phi, sampled_shapley(toy_game, 5, 8, seed=2**64 - 1).phi, rtol=0, atol=0)
    for kwargs, name in (({"exact_max": "3"}, "exact_max"), ({"exact_max": 2.5}, "exact_max"),
                         ({"exact_max": 0, "seed": -1}, "seed"), ({"batch": 0}, "batch")):  # fmt: skip
        with pytest.raises(ValueError, match=rf"^{name}: expected"):
            agent_contributions(problem, problem.init, **kwargs)


def test_tables_and_plots_give_each_quantitys_unit(problem, tmp_path, monkeypatch):
    """Areas are in m, DFD and RMSE in m/s (the project's convention: DFD of (t [s], v [m/s]) points), the score has
    none: the Markdown tables, the CSV and both pictures said no unit at all (bars without an axis label, a colour
    bar of an area in no unit), and the module docstring called the DFD dimensionless."""
    import csv

    import matplotlib.figure

    from marlcrash.analysis.contributions import quantity_unit

    assert [quantity_unit(q) for q in ("area/tunnel", "dfd/upfront_left", "rmse/tunnel", "score")] == [
        "m", "m/s", "m/s", "-"
    ]  # fmt: skip
    with pytest.raises(ValueError, match="unknown quantity 'energy/tunnel'"):
        quantity_unit("energy/tunnel")
    calibrated, _ = _three_agents_at_the_truth(problem)
    c = agent_contributions(problem, calibrated)
    assert c.markdown("area/tunnel").startswith("area/tunnel [m]: ")
    assert c.markdown("rmse/upfront_left").startswith("rmse/upfront_left [m/s]: ")
    assert c.markdown("score").startswith("score [-]: ")
    rows = list(csv.DictReader(c.write_csv(tmp_path / "c.csv").open()))
    assert {(r["quantity"], r["unit"]) for r in rows if r["quantity"] in ("dfd/tunnel", "score")} == {
        ("dfd/tunnel", "m/s"), ("score", "-")
    }  # fmt: skip
    labels: list[str] = []
    real = matplotlib.figure.Figure.savefig

    def record(fig, *args, **kwargs):  # every axis label and colour-bar label of the saved figure
        labels.extend(ax.get_xlabel() for ax in fig.axes)
        labels.extend(ax.get_ylabel() for ax in fig.axes)
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", record)
    plot_contributions(c, tmp_path / "bars.png", quantities=["score", "area/tunnel", "dfd/tunnel"])
    assert {"contribution [-]", "contribution [m]", "contribution [m/s]"} <= set(labels), labels
    labels.clear()
    plot_cells_by_contribution(problem, c, tmp_path / "3d.png", quantity="area/tunnel")
    assert any(lab.endswith("-area/tunnel [m] (> 0 improves)") for lab in labels), labels


def test_agent_changes_refuse_parameters_whose_log_factor_is_not_a_number(problem):
    """A non-finite, zero or negative ``E_x`` or ``E_s`` of an owned cell is refused naming ``params``, the step and
    the cell (the simulator's check, as :func:`agent_contributions` names its arrays): the table of mean log factors
    held a silent NaN or -inf for that agent."""
    cell = int(torch.nonzero(problem.layout.agent_of_cell >= 0)[0])
    for value in (float("nan"), 0.0, -1.0):
        p = torch.stack([problem.init, problem.init.clone()])
        p[1, cell, 1] = value
        with pytest.raises(ModelError, match=rf"^params: params\[1, {cell}, 1\] \(E_s\) of active cell {cell}"):
            agent_changes(problem, p)
    torch.testing.assert_close(torch.as_tensor(agent_changes(problem, problem.init)["E_s"]),
                               torch.zeros(1, problem.n_agents, dtype=torch.float64), rtol=0, atol=0)  # fmt: skip


def test_coalition_params_names_parameters_of_the_wrong_shape(problem):
    """``initial`` and ``calibrated`` are ``[n_cells, 7]`` (a tensor or an array, as :func:`agent_contributions`
    takes them): another shape got torch's 'The size of tensor a (518) must match ...' from inside ``where``, and a
    numpy array a TypeError listing ``where``'s overloads."""
    members = torch.ones(2, problem.n_agents, dtype=torch.bool)
    want = coalition_params(problem, problem.init, problem.true_params, members)
    got = coalition_params(problem, problem.init.numpy(), problem.true_params.numpy(), members)
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    n = problem.init.shape[0]
    with pytest.raises(ValueError, match=rf"^calibrated: expected cell parameters of shape \({n}, 7\), got \(5, 7\)"):
        coalition_params(problem, problem.init, problem.true_params[:5], members)
    with pytest.raises(ValueError, match=rf"^initial: expected cell parameters of shape \({n}, 7\), got \(1, {n}, 7\)"):
        coalition_params(problem, problem.init[None], problem.true_params, members)


def test_pictures_are_written_to_a_path_without_a_suffix_and_a_failed_one_leaves_no_figure_open(problem, tmp_path):
    """A picture path without a suffix is written as PNG, as matplotlib writes one: the temporary name beside it
    ends in ``.tmp``, and matplotlib read that as the format ('Format 'tmp' is not supported'), a name the user
    never gave. A save that fails (a suffix matplotlib has no writer for) closes its figure: it stayed open, one more
    per failed call in a session."""
    import matplotlib.pyplot as plt

    c = agent_contributions(problem, problem.init)  # nothing moved: one simulation
    plt.close("all")
    for draw in (lambda p: plot_contributions(c, p), lambda p: plot_cells_by_contribution(problem, c, p)):
        path = tmp_path / "picture"
        assert draw(path) == path and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        path.unlink()
        with pytest.raises(ValueError, match="Format 'xyz' is not supported"):
            draw(tmp_path / "picture.xyz")
        assert plt.get_fignums() == []
    assert not any(tmp_path.iterdir())  # no picture and no temporary file stays


def test_the_truth_in_calibrated_npz_is_checked_when_the_run_is_loaded(tmp_path):
    """``true`` (the twin's hidden parameters, which the notebook tabulates beside the calibrated ones) is checked as
    ``initial`` and ``calibrated`` are, naming the file: it was returned unchecked, so one of another shape or with a
    NaN failed later as ``params: expected [iterations, 518, 7]`` or ``params: params[0, ...]``, naming no file."""
    problem = write_evaluated_run(tmp_path)
    keep = dict(np.load(tmp_path / "calibrated.npz"))
    nan = keep["true"].copy()
    cell = int(torch.nonzero(problem.layout.agent_of_cell >= 0)[0])
    nan[cell, 0] = np.nan
    for bad, words in [
        (keep["true"][:5], r"\[true\]: expected cell parameters of shape"),
        (nan, r"\[true\]: parameters must be finite"),
    ]:
        np.savez(tmp_path / "calibrated.npz", **{**keep, "true": bad})
        with pytest.raises(ConfigError, match=r"calibrated\.npz" + words) as e:
            run_calibration(tmp_path)
        assert e.value.key == "run"
    np.savez(tmp_path / "calibrated.npz", **{k: v for k, v in keep.items() if k != "true"})  # no truth: a test's
    assert run_calibration(tmp_path).true is None


def test_one_quantity_name_given_as_quantities_is_refused_naming_the_list_expected(problem, tmp_path):
    """``quantities="score"`` (one name where a list is expected) is refused naming ``quantities`` and the string:
    it was read letter by letter, as "unknown quantity 's'"."""
    c = agent_contributions(problem, problem.init)  # nothing moved: one simulation
    for call in (lambda: plot_contributions(c, tmp_path / "bars.png", quantities="score"),
                 lambda: c.write_markdown(tmp_path / "c.md", quantities="score")):  # fmt: skip
        with pytest.raises(ValueError, match=r"^quantities: expected a list of quantity names, got the string 'score'"):
            call()
    assert not any(tmp_path.iterdir())
    assert c.selected(("score",)) == ["score"]  # any sequence of names


def test_the_bars_say_what_their_whiskers_are_and_where_none_can_be_told(tmp_path, monkeypatch):
    """Sampled Shapley values are drawn with whiskers of one standard error, but nothing said so (the legend read
    'Shapley'), and an agent whose standard error the orderings cannot tell (NaN, ``± n/a`` in the Markdown) was drawn
    without a whisker: as if exact. Now the legend names the whiskers and such a bar is marked ``s.e. n/a``; exact
    values keep a plain legend and no mark."""
    from marlcrash.analysis.contributions import Contributions

    nan = float("nan")
    t = lambda x: torch.tensor(x, dtype=torch.float64)  # noqa: E731
    sampled = Contributions(agents=["a", "b", "c"], quantities=["area/tunnel", "score"],
                            players=torch.tensor([True, True, False]), initial=t([0.1, -2.0]),
                            calibrated=t([0.05, -1.0]), shapley=t([[-0.02, 0.6], [-0.03, 0.4], [0.0, 0.0]]),
                            shapley_stderr=t([[0.01, nan], [nan, 0.1], [0.0, 0.0]]), exact=False,
                            leave_one_out=t([[-0.02, 0.6], [-0.03, 0.4], [0.0, 0.0]]),
                            add_one=t([[-0.02, 0.6], [-0.03, 0.4], [0.0, 0.0]]), n_simulations=10)  # fmt: skip
    figs = drawn_figures(monkeypatch)
    plot_contributions(sampled, tmp_path / "bars.png")
    score, area = figs[0].axes[:2]
    legend = [tx.get_text() for tx in score.get_legend().get_texts()]
    assert "Shapley ± one standard error" in legend, legend
    for ax, unknown in ((score, "a"), (area, "b")):  # the bars run in the score's ranking: a, then b
        marks = [(tx.get_text(), tx.xy[1]) for tx in ax.texts]
        assert marks == [("s.e. n/a", ["a", "b"].index(unknown))], marks
    exact = dataclasses.replace(sampled, exact=True, shapley_stderr=torch.zeros(3, 2, dtype=torch.float64))
    plot_contributions(exact, tmp_path / "exact.png")
    score = figs[1].axes[0]
    assert sorted(tx.get_text() for tx in score.get_legend().get_texts()) == ["Shapley", "leave-one-out"]
    assert not any(ax.texts for ax in figs[1].axes)


def test_contributions_json_gives_the_one_at_a_time_effects_beside_the_shapley_values(tmp_path, capsys):
    """``marlcrash contributions --json`` (for scripts) gave every quantity's Shapley values and their standard
    errors, but not the leave-one-out and add-one effects that the tables give beside them: a script had to read them
    back from the CSV. Now both are there, per moving agent, as in the CSV."""
    import csv
    import json

    from marlcrash.cli import main

    out = tmp_path / "c"
    assert main(["contributions", "--permutations", "4", "--no-plots", "--out", str(out), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    table = {(r["agent"], r["quantity"]): r for r in csv.DictReader((out / "contributions.csv").open())}
    for q, v in s["quantities"].items():
        assert list(v["leave_one_out"]) == list(v["add_one"]) == list(v["shapley"]), q  # the moving agents, ranked
        for a in v["shapley"]:
            assert v["leave_one_out"][a] == float(table[a, q]["leave_one_out"])
            assert v["add_one"][a] == float(table[a, q]["add_one"])


def test_the_settings_of_one_moving_agent_read_in_the_singular():
    """One agent that moved was 'the 1 agents that moved' in the heading of contributions.md."""
    from marlcrash.analysis.contributions import Contributions

    z = torch.zeros(2, 1, dtype=torch.float64)
    c = Contributions(agents=["a", "b"], quantities=["score"], players=torch.tensor([True, False]),
                      initial=torch.zeros(1, dtype=torch.float64), calibrated=torch.ones(1, dtype=torch.float64),
                      shapley=z, shapley_stderr=z, exact=True, leave_one_out=z, add_one=z, n_simulations=2,
                      settings={"exact_max": 10, "n_permutations": 64, "seed": 0})  # fmt: skip
    want = "- Shapley values: exact: all 2**1 coalitions of the 1 agent that moved (exact_max 10)"
    assert c.settings_lines()[0] == want


def test_two_analyses_into_one_folder_at_once_do_not_replace_each_other(problem, tmp_path, capsys, monkeypatch):
    """Two ``marlcrash contributions`` into one folder at once (two terminals, two seeds, the default folder) both
    passed the check for an earlier analysis before either wrote, so the one that finished last replaced the other's
    tables and pictures without a word (or left a mix of both). Now the second is refused while the first computes,
    naming ``--out``, and the first's files are its own."""
    import marlcrash.analysis as analysis
    import marlcrash.calibrate.problem as problem_module
    from marlcrash.cli import main

    monkeypatch.setattr(problem_module, "build_problem", lambda cfg: problem)  # the short twin: quicker
    real, nested = analysis.agent_contributions, []

    def while_computing(*args, **kwargs):  # a second analysis of the same folder starts while this one computes
        if not nested:
            nested.append(None)
            nested[0] = main(["contributions", "--permutations", "4", "--seed", "1", "--no-plots", "--out", str(out)])
        return real(*args, **kwargs)

    monkeypatch.setattr(analysis, "agent_contributions", while_computing)
    out = tmp_path / "c"
    assert main(["contributions", "--permutations", "4", "--no-plots", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert nested == [2] and "key '--out'" in err and "in use by another process" in err, (nested, err)
    assert "orderings in antithetic pairs, seed 0" in (out / "contributions.md").read_text()
    assert sorted(p.name for p in out.iterdir()) == ["contributions.csv", "contributions.md"]  # no lock file left


def test_contributions_on_the_surrogate_equal_a_brute_force_game_of_direct_simulations(problem):
    """An independent calculation: every coalition of three agents built by hand (their cells at the truth, every other
    cell initial), simulated directly, and the Shapley values by the textbook average over all 3! orderings;
    leave-one-out and add-one from the same table. Every quantity of every agent, exact and sampled."""
    names = ["crash_box_left", "front_rail_right", "bumper_beam_left"]
    agents = [problem.agent_names.index(a) for a in names]
    owner = problem.layout.agent_of_cell

    def params(members) -> torch.Tensor:
        p = problem.init.clone()
        for a in members:
            p[owner == a] = problem.true_params[owner == a]
        return p

    coalitions = [frozenset(s) for k in range(4) for s in itertools.combinations(agents, k)]
    m = evaluate_params(problem, torch.stack([params(s) for s in coalitions]))
    values = torch.cat([m.area, m.dfd, m.rmse, problem.score(m)[:, None]], dim=1)
    v = dict(zip(coalitions, values, strict=True))
    full, empty = v[frozenset(agents)], v[frozenset()]
    shapley = {a: torch.zeros_like(full) for a in agents}
    for order in itertools.permutations(agents):
        before: frozenset[int] = frozenset()
        for a in order:
            shapley[a] += (v[before | {a}] - v[before]) / math.factorial(len(agents))
            before = before | {a}
    calibrated = params(agents)
    for c in (agent_contributions(problem, calibrated), agent_contributions(problem, calibrated, exact_max=0)):
        assert c.quantities[-1] == "score" and c.quantities[: len(problem.sensors)] == [
            f"area/{s}" for s in problem.sensors
        ]
        torch.testing.assert_close(c.initial, empty, rtol=0, atol=1e-12)
        torch.testing.assert_close(c.calibrated, full, rtol=0, atol=1e-12)
        for a in agents:
            torch.testing.assert_close(c.leave_one_out[a], full - v[frozenset(agents) - {a}], rtol=0, atol=1e-12)
            torch.testing.assert_close(c.add_one[a], v[frozenset({a})] - empty, rtol=0, atol=1e-12)
            if c.exact:
                torch.testing.assert_close(c.shapley[a], shapley[a], rtol=0, atol=1e-12)
        others = [i for i in range(problem.n_agents) if i not in agents]
        assert float(c.shapley[others].abs().max()) == float(c.add_one[others].abs().max()) == 0.0


def test_parameters_that_are_no_array_of_numbers_are_named(problem):
    """``None`` (``run.true`` of a run evaluated on a measured test, which has no truth) or a ragged list as the
    parameters: numpy's and torch's "can't convert np.ndarray of type numpy.object_" named neither the argument nor
    what was expected. Now a ValueError names it and what it got."""
    cal = problem.true_params
    for call, name in [
        (lambda bad: agent_contributions(problem, bad), "calibrated"),
        (lambda bad: agent_changes(problem, bad), "params"),
        (lambda bad: coalition_params(problem, bad, cal, torch.ones(1, problem.n_agents, dtype=torch.bool)), "initial"),
    ]:
        for bad, got in ((None, "None"), ([[1.0, 2.0], [3.0]], "list"), ("E_x", "str")):
            with pytest.raises(ValueError, match=rf"^{name}: expected cell parameters .*got {got}"):
                call(bad)


def test_agent_changes_are_read_against_the_initial_parameters_given(problem):
    """A run's changes against the parameters it started from (``initial``), which differ from today's problem's where
    ``configs/`` changed since the run: they were always read against the problem's."""
    start = problem.init.clone()
    start[problem.layout.agent_of_cell >= 0, 0] *= 1.05
    same = agent_changes(problem, start, start)
    assert all(np.abs(v).max() == 0.0 for v in same.values())
    assert float(np.abs(agent_changes(problem, start)["E_x"]).max()) == pytest.approx(math.log(1.05), abs=1e-12)
    bad = start.clone()
    bad[int(torch.nonzero(problem.layout.agent_of_cell >= 0)[0]), 0] = -1.0
    with pytest.raises(ModelError, match=r"^initial: "):
        agent_changes(problem, start, bad)
    with pytest.raises(ValueError, match="initial: expected cell parameters of shape"):
        agent_changes(problem, start, start[:3])
