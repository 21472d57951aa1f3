"""The calibration problem: same numbers as a direct simulation, twin ground truth, gradients, errors."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from marlcrash.calibrate import ProblemConfig, Progress, SmoothLoss, build_problem
from marlcrash.calibrate.budget import ranked_scores
from marlcrash.calibrate.problem import problem_env_config
from marlcrash.cells.parameterization import apply_increments
from marlcrash.config import config_dir, from_dict
from marlcrash.envs.core import build_cells, load_env_config
from marlcrash.envs.masking import ImpactRegions
from marlcrash.errors import ConfigError, ModelError
from marlcrash.metrics import Metrics, compute_metrics
from marlcrash.pulse.signal import compared_velocity
from marlcrash.references import ReferenceSampler
from marlcrash.sim.scenario import get_scenario

DURATION = 0.02  # a short window keeps every simulation cheap [s]


@pytest.fixture(scope="module")
def cells():
    return build_cells("b_segment", None, "optimized")


def make(cells, **over):
    over.setdefault("duration", DURATION)
    return build_problem(from_dict(ProblemConfig, over), cells=cells)


@pytest.fixture(scope="module")
def problem(cells):
    return make(cells)


@pytest.fixture(scope="module")
def exact_twin(cells):
    """A twin whose truth lies exactly in the search space (no transmission perturbation)."""
    return make(cells, env_overrides={"reference.twin.transmission_spread": 0.0}, reference_seed=3)


def random_x(problem, n, seed=0, scale=0.2):
    g = torch.Generator().manual_seed(seed)
    return problem.clip((torch.rand(n, problem.n_agents, 7, generator=g, dtype=torch.float64) * 2 - 1) * scale)


def test_evaluate_equals_direct_simulation_and_metrics(problem, cells):
    x = random_x(problem, 3)
    before = problem.n_simulations
    m = problem.evaluate(x)
    assert problem.n_simulations - before == 3
    # independent path: the env's update rule by hand, the scenario object, the torch metrics
    env = load_env_config("default")
    inc = x[:, problem.layout.agent_of_cell.clamp_min(0)] * problem.layout.owned[None, :, None]
    init = torch.as_tensor(cells.params, dtype=torch.float64)
    params = apply_increments(init.expand(3, -1, -1), inc, init, torch.as_tensor(cells.feasible),
                              tuple(env.behaviour_bounds), env.transmission_floor)  # fmt: skip
    sc = get_scenario("full_width_40")
    sampler = ReferenceSampler(cells, problem.sim, problem.sensors, {"full_width_40": 1.0}, env.reference,
                               bounds=tuple(env.behaviour_bounds), floor=env.transmission_floor)  # fmt: skip
    raw_ref = sampler.sample(np.random.default_rng(0), 1).raw_velocity[0, :, : problem.T]
    with torch.no_grad():
        v = problem.sim.run(params, sc, duration=DURATION, sensors=problem.sensors, record_cells="none",
                            backend=problem.sim_backend).velocity  # fmt: skip
    # both compared as the integral of the CFC60 acceleration over the same window (DESIGN 1.5)
    cfc = env.reference.compare_cfc
    ref = compared_velocity(raw_ref.double(), sc.output_dt, cfc)
    direct = compute_metrics(compared_velocity(v.double(), sc.output_dt, cfc), ref, dt=sc.output_dt)
    for got, want in zip(m, direct, strict=True):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-9)
    assert m.area.shape == (3, len(problem.sensors))


def test_params_are_the_env_update_and_feasible(problem, cells):
    init = torch.as_tensor(cells.params, dtype=torch.float64)
    assert torch.equal(problem.params(problem.zeros(2)), init.expand(2, -1, -1))
    p = problem.params(random_x(problem, 4, scale=1.0))
    deform = torch.as_tensor(~cells.is_null & ~cells.is_rigid)
    f = p[:, deform, 2:]
    torch.testing.assert_close(f.sum(-1), torch.ones_like(f[..., 0]), rtol=0, atol=1e-12)
    assert (f >= 0).all() and (f[:, ~torch.as_tensor(cells.feasible)[deform]] == 0).all()
    lo, hi = problem.bounds
    e, e0 = p[:, deform, :2], init[deform, :2]
    assert (e >= lo * e0 * (1 - 1e-12)).all() and (e <= hi * e0 * (1 + 1e-12)).all()
    # gradient path gives the same values
    xg = random_x(problem, 2, seed=5).requires_grad_(True)
    torch.testing.assert_close(problem.params(xg).detach(), problem.params(xg.detach()), rtol=0, atol=0)


def test_a_point_is_where_one_env_step_lands_and_near_where_several_do(problem):
    """The module docstring's claim: ``params(x)`` is bit for bit the env's update by one step of increments ``x``;
    steps summing to ``x`` reach its ``E_x``, ``E_s`` to rounding, but its transmission factors only near (each step
    renormalises, and the floor shift does not commute with that; the docstring said "exactly")."""
    x = random_x(problem, 1, seed=3, scale=0.05)
    init, feas = problem.init[None], problem.feasible
    inc = x[:, problem.layout.agent_of_cell.clamp_min(0)] * problem._owned
    one = apply_increments(init, inc, problem.init, feas, problem.bounds, problem.floor)
    assert torch.equal(problem.params(x), one)
    p = init
    for _ in range(3):
        p = apply_increments(p, inc / 3, problem.init, feas, problem.bounds, problem.floor)
    torch.testing.assert_close(p[..., :2], one[..., :2], rtol=1e-12, atol=0)
    gap = float((p[..., 2:] - one[..., 2:]).abs().max())
    assert 1e-6 < gap < problem.floor * 0.05 * 2


def test_region_cells_mode_leaves_cells_outside_the_impact_region_as_the_env_does(cells):
    """With ``masking.cells: region`` a baseline's agent factors reach only the agent's cells in the impact region,
    the cells the environment lets it act on: a driver-side small overlap leaves the rest at their initial values."""
    over = {"scenario": "small_overlap_left", "env_overrides": {"masking.cells": "region"}}
    region_problem, agent_problem = make(cells, **over), make(cells, scenario="small_overlap_left")
    x = region_problem.clip(torch.full((1, region_problem.n_agents, 7), 0.5, dtype=torch.float64))
    init = torch.as_tensor(cells.params, dtype=torch.float64)
    moved = {k: (p.params(x)[0] != init).any(-1) for k, p in (("region", region_problem), ("agent", agent_problem))}
    env = problem_env_config(from_dict(ProblemConfig, over))
    regions = ImpactRegions(cells, region_problem.layout, env.masking)
    region = regions.region(region_problem.overlap, region_problem.side, region_problem.speed)[0]
    assert (moved["agent"] & ~region).any()  # an active agent's cells outside the region: moved by default
    assert moved["region"].any() and not (moved["region"] & ~region).any()
    assert torch.equal(moved["region"], moved["agent"] & region)


def test_box_and_free_coordinates(problem):
    x = problem.clip(torch.full((1, problem.n_agents, 7), 10.0, dtype=torch.float64))
    top = min(1.0, float(np.log(problem.bounds[1])))  # box_radius 1 and the behaviour bound
    assert torch.allclose(x[0, :, :2][problem.free[:, :2]], torch.tensor(top, dtype=torch.float64))
    assert torch.allclose(x[0, :, 2:][problem.free[:, 2:]], torch.tensor(1.0, dtype=torch.float64))
    assert (x[0][~problem.free] == 0).all()
    lo, hi = problem.flat_box()
    assert torch.equal(hi, problem.flat(x)[0])
    assert torch.equal(lo, problem.flat(problem.clip(-x.abs() - 10.0))[0])
    assert problem.n_free == int(problem.free.sum()) and problem.n_free > 2 * problem.n_agents
    z = torch.arange(problem.n_free, dtype=torch.float64)[None]
    assert torch.equal(problem.flat(problem.unflat(z)), z)


def test_twin_truth_has_zero_metrics_and_zero_param_error(exact_twin):
    p = exact_twin
    x = torch.stack([p.zeros(1)[0], p.true_x])
    m = p.evaluate(x)
    for t in m:
        assert float(t[1].abs().max()) < 1e-9
        assert float(t[0].min()) > 1e-4  # the initial parameters do not fit the twin
    assert p.success(m).tolist() == [False, True]
    err = p.param_error(x)
    assert float(err[1].abs().max()) < 1e-12
    assert float(err[0, :, :2].max()) > 0.05
    assert set(p.param_error_table(p.true_x)) == set(p.subassembly_names)


def test_twin_truth_is_exact_with_the_default_spreads(problem):
    """Every agent owns one sub-assembly: ``true_x`` is the twin's increments, its parameters the truth bit for bit."""
    assert problem.reference.true_increments is not None
    assert torch.equal(problem.params(problem.true_x[None])[0], problem.true_params)
    m = problem.evaluate(torch.stack([problem.zeros(1)[0], problem.true_x]))
    for t in m:
        assert float(t[1].abs().max()) == 0.0  # compared signals do not depend on the batch they came in
        assert float(t[0].min()) > 1e-4
    assert float(problem.param_error(problem.true_x[None]).abs().max()) == 0.0


def test_a_twin_truth_outside_the_search_box_is_named_when_the_problem_is_built(cells):
    """The twin's log factors are normal (``reference.twin.*_spread`` their sigmas), so a wide spread draws truths
    past ``box_radius``: ``true_x`` was clipped to the box without a word, and no calibrator could reach the truth
    (``param_error`` 0.49 at ``true_x`` with a transmission spread of 1). Building such a problem warns, naming the
    agent, its sub-assembly and the parameter; the default spreads' truths lie inside, and a wider box takes them."""
    from marlcrash.cells.model import PARAM_NAMES

    wide = {"reference.twin.transmission_spread": 1.0}
    with pytest.warns(UserWarning, match=r"outside the search box \(box_radius = 1\b") as rec:
        p = make(cells, env_overrides=wide)
    msg = " ".join(str(w.message) for w in rec)
    raw = p.reference.true_increments[0, [p.cells.subassembly_names.index(s[0]) for s in p.layout.subassemblies]]
    out = p.free & ((raw > p.upper) | (raw < p.lower))
    a, j = (int(i) for i in torch.nonzero(out)[0])
    assert f"agent {p.agent_names[a]!r} (sub-assembly {p.layout.subassemblies[a][0]}) {PARAM_NAMES[j]}" in msg
    assert f"{int(out.sum())} of the {p.n_free} free coordinates" in msg
    assert "reference.twin.transmission_spread" in msg and float(p.param_error(p.true_x[None]).max()) > 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for seed in range(3):  # the default spreads (0.2) draw their truths inside the default box
            inside = make(cells, reference_seed=seed)
            assert float(inside.param_error(inside.true_x[None]).abs().max()) == 0.0
        make(cells, env_overrides=wide, box_radius=5.0)  # the box holds the wide truth


def test_problem_simulates_in_the_env_configs_precision(cells):
    """``env_overrides: {sim_dtype: float32}`` gives the problem (reference and candidates) the environments'
    single-precision simulator, so a float32 training run is evaluated against the twin its env drew; its truth
    still fits to float32 rounding, far inside the paper's marks."""
    p = make(cells, env_overrides={"sim_dtype": "float32"})
    assert p.sim.dtype == torch.float32
    m = p.evaluate(torch.stack([p.zeros(1)[0], p.true_x]))
    assert float(m.area[1].max()) < 1e-5 and float(m.rmse[1].max()) < 1e-3
    assert p.success(m).tolist() == [False, True]


def test_merged_agents_fall_back_to_a_least_squares_truth(cells):
    """An agent over two sub-assemblies cannot follow both twin increments: the fit is approximate. With the default
    spreads the twin's draws lie in the search box but the fit to them leaves it (5 coordinates for reference seed 0),
    and clipping it to the box raised those parameters' error without a word: now said."""
    merge = {"agents.merge": {"left_structure": ["crash_box_left", "front_rail_left"]}}
    msg = r"least-squares point that represents the twin's truth for the merged agents lies outside the search box"
    with pytest.warns(UserWarning, match=msg + r" \(box_radius = 1\) at \d+ of the \d+ free coordinates: agent "
                      r"'left_structure' \(sub-assemblies crash_box_left, front_rail_left\)") as record:  # fmt: skip
        p = make(cells, reference_seed=0, env_overrides=merge)
    assert not any("twin's hidden truth lies outside" in str(w.message) for w in record)  # the draws lie inside
    a = p.layout.index("left_structure")
    at_edge = (p.true_x[a] == p.lower[a]) | (p.true_x[a] == p.upper[a])
    assert p.free[a].any() and bool(at_edge[p.free[a]].any())  # clipped there
    assert ("crash_box_left", "front_rail_left") in p.layout.subassemblies
    err = p.param_error(p.true_x[None])[0]  # [S, 7] per sub-assembly
    names = p.subassembly_names
    merged = [names.index("crash_box_left"), names.index("front_rail_left")]
    alone = [i for i in range(len(names)) if i not in merged]
    assert float(err[alone, :2].abs().max()) < 1e-12  # single-sub-assembly agents: E exact
    assert float(err[merged, :2].abs().max()) > 1e-3  # one factor for two different truths
    s = p.score(p.evaluate(torch.stack([p.zeros(1)[0], p.true_x])))
    assert float(s[1]) > float(s[0])


def test_merged_agents_least_squares_truth_fits_the_cells_the_agent_reaches(cells):
    """With ``masking.cells: region`` a merged agent's factors reach only its in-region cells, so the least-squares
    truth's ``E`` is the mean log ratio over those cells (the others keep their initial values whatever ``x`` is).
    Before, it was the mean over all its cells: in a driver-side small overlap 3 of the 39 cells of crash box plus
    front rail lie outside the region, and ``E_s`` came out 0.0206 instead of 0.0164."""
    merge = {"agents.merge": {"left_structure": ["crash_box_left", "front_rail_left"]}}
    p = make(cells, scenario="small_overlap_left", env_overrides={**merge, "masking.cells": "region"})
    a = p.layout.index("left_structure")
    own = p.layout.agent_of_cell == a
    reach = p.params(torch.ones(1, p.n_agents, 7, dtype=torch.float64) * 0.1)[0, :, 0] != p.init[:, 0]
    assert (own & reach).any() and (own & ~reach).any()
    log_ratio = torch.log(p.true_params[:, :2] / p.init[:, :2])
    torch.testing.assert_close(p.true_x[a, :2], log_ratio[own & reach].mean(0), rtol=0, atol=1e-12)


def test_loss_gradient_is_finite_and_nonzero_at_the_start(problem):
    x = problem.zeros(2).requires_grad_(True)
    before = problem.n_simulations
    loss, m = problem.loss(x, SmoothLoss())
    assert problem.n_simulations - before == 2
    loss.sum().backward()
    g = x.grad
    assert torch.isfinite(g).all()
    assert float(g[:, :, :2].abs().max()) > 0
    assert float(g[:, :, 2:].abs().max()) > 0  # transmission coordinates too, also at x = 0
    assert (g[:, ~problem.free] == 0).all()
    # torch path against the numba path: round-off, amplified a little by the filter's derivative
    torch.testing.assert_close(m.rmse, problem.evaluate(problem.zeros(2)).rmse, rtol=0, atol=1e-8)


def test_loss_gradient_of_the_adjoint_equals_torch_autograd(problem):
    """The default (compiled adjoint) and the torch autograd reference give the same loss and gradient."""
    out = {}
    for backend in ("adjoint", "torch"):
        x = random_x(problem, 2, seed=5).requires_grad_(True)
        loss, _ = problem.loss(x, SmoothLoss(), backend)
        loss.sum().backward()
        out[backend] = (loss.detach(), x.grad)
    torch.testing.assert_close(out["adjoint"][0], out["torch"][0], rtol=1e-7, atol=0)
    scale = float(out["torch"][1].abs().max())
    torch.testing.assert_close(out["adjoint"][1], out["torch"][1], rtol=1e-6, atol=1e-9 * scale)
    assert float(out["torch"][1].abs().max()) > 0
    with pytest.raises(ConfigError, match="adjoint or torch") as e:
        problem.loss(problem.zeros(1), SmoothLoss(), "numba")
    assert e.value.key == "backend"


def test_loss_is_zero_at_exact_truth(exact_twin):
    loss, _ = exact_twin.loss(exact_twin.true_x[None], SmoothLoss())
    assert float(loss[0]) < 1e-6  # torch path against a numba reference: round-off only


def test_bad_candidates_are_named(problem):
    with pytest.raises(ModelError, match="n_agents"):
        problem.evaluate(torch.zeros(2, problem.n_agents + 1, 7, dtype=torch.float64))
    x = problem.zeros(1)
    x[0, 2, 1] = float("nan")
    with pytest.raises(ModelError, match=rf"{problem.agent_names[2]}.*E_s"):
        problem.evaluate(x)


def test_candidates_with_gradients_are_checked_as_the_others_are(problem):
    """``loss`` and ``simulate`` skipped :meth:`check_x` for a candidate that requires grad (the gradient baseline's):
    a wrong shape failed deep in torch (``The size of tensor a (6) must match ...``), a single ``[n_agents, 7]``
    candidate with gradients with an ``IndexError``, a NaN was named as a cell's ``E_x`` by the simulator, not as the
    candidate's coordinate; and ``simulate`` of a numpy array failed on ``.requires_grad``."""
    A = problem.n_agents
    with pytest.raises(ModelError, match="n_agents"):
        problem.loss(torch.zeros(1, A, 6, dtype=torch.float64, requires_grad=True), SmoothLoss())
    x = problem.zeros(1)
    x[0, 2, 1] = float("nan")
    with pytest.raises(ModelError, match=rf"{problem.agent_names[2]}.*E_s"):
        problem.loss(x.requires_grad_(True), SmoothLoss())
    single = torch.zeros(A, 7, dtype=torch.float64, requires_grad=True)  # one candidate, as evaluate takes it
    loss, _ = problem.loss(single, SmoothLoss())
    loss.sum().backward()
    assert loss.shape == (1,) and single.grad.shape == (A, 7) and torch.isfinite(single.grad).all()
    torch.testing.assert_close(loss.detach(), problem.loss(problem.zeros(1), SmoothLoss())[0], rtol=1e-12, atol=0)
    res = problem.simulate(np.zeros((1, A, 7)), count=False)
    assert torch.equal(res.velocity, problem.simulate(problem.zeros(1), count=False).velocity)


@pytest.mark.parametrize(
    ("over", "key"),
    [
        ({"box_radius": -1.0}, "box_radius"),
        ({"duration": 0.0123}, "problem.duration"),
        ({"duration": 0.5}, "problem.duration"),
        ({"duration": 0.005}, "problem.duration"),  # shorter than a period of CFC 60's 100 Hz: no compared signal
        ({"success": {"area": -1.0}}, "success.area"),
        ({"reference": "file"}, "reference"),
        ({"scenario": "moon_landing"}, "scenario"),
        ({"fit": "nope"}, "fit"),  # the problem's key, not the reward form's 'name'
        ({"env": "nope"}, "env"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_problem_configs_name_the_key(cells, over, key):
    with pytest.raises(ConfigError) as e:
        build_problem(from_dict(ProblemConfig, over), cells=cells)
    assert e.value.key is not None and key in e.value.key


@pytest.mark.parametrize(
    ("over", "key"),
    [({"sensors": ["nope"]}, "env_overrides.sensors"), ({"agents.rest": "none"}, "env_overrides.agents")],
)
def test_env_errors_found_while_building_name_the_override(cells, over, key):
    """An env value that only building refuses (a sensor the model lacks, a layout leaving cells unowned) was named
    by its bare env key (``key 'sensors'``), a key the problem config does not have: the override that set it is
    named, as for the values the env file's loader refuses."""
    with pytest.raises(ConfigError) as e:
        make(cells, env_overrides=over)
    assert e.value.key == key and e.value.path is None


def test_env_errors_found_while_building_name_the_env_file(cells, tmp_path):
    """The same values in an env file of the problem's ``env``: that file and its key, as the environment names."""
    text = (config_dir() / "env" / "default.yaml").read_text()
    assert "\nsensors: []" in text
    path = tmp_path / "bad_sensors.yaml"
    path.write_text(text.replace("\nsensors: []", "\nsensors: [nope]"))
    with pytest.raises(ConfigError, match="unknown sensors") as e:
        make(cells, env=str(path))
    assert e.value.key == "sensors" and e.value.path == str(path)


def test_progress_counts_exactly():
    p = Progress(10)
    x = torch.zeros(4, 2, 7)
    m = Metrics(*(torch.ones(4, 3) for _ in range(3)))
    assert p.grant(4) == 4
    p.record(x, m, torch.tensor([0.0, 1.0, 3.0, 2.0]), torch.tensor([False, False, True, True]))
    assert p.sims_to_success == 3 and p.best_score == 3.0 and p.used == 4
    p.record(x, m, torch.tensor([float("nan"), 1.0, 2.0, 0.0]), torch.zeros(4, dtype=torch.bool))
    assert p.grant(4) == 2 and p.best_score == 3.0
    with pytest.raises(RuntimeError, match="exceeds"):
        p.record(x, m, torch.zeros(4), torch.zeros(4, dtype=torch.bool))
    assert p.history_array()[:, 1].tolist() == [3.0, 3.0]
    with pytest.raises(ConfigError, match="budget"):
        Progress(0)


def test_progress_keeps_a_perfect_fit_whose_score_is_infinite():
    """A score of ``+inf`` (what ``log_ratio`` with ``eps: 0`` gave a perfect fit, before it needed eps > 0) is the
    best fit possible. Mapping every non-finite score to ``-inf`` made it the worst, so a later, worse candidate
    replaced it."""
    p = Progress(10)
    x = torch.arange(4, dtype=torch.float64)[:, None, None].expand(4, 2, 7)
    m = Metrics(*(torch.ones(4, 3) for _ in range(3)))
    p.record(x[:2], Metrics(*(t[:2] for t in m)), torch.tensor([1.0, float("inf")]),
             torch.zeros(2, dtype=torch.bool))  # fmt: skip
    p.record(x[2:], Metrics(*(t[2:] for t in m)), torch.tensor([5.0, float("nan")]), torch.zeros(2, dtype=torch.bool))
    assert p.best_score == float("inf") and float(p.best_x[0, 0]) == 1.0
    # the evaluation of a policy selects its best iterate by the same ranking
    ranked = ranked_scores(torch.tensor([1.0, float("inf"), float("nan"), float("-inf")], dtype=torch.float32))
    assert ranked.dtype == torch.float64 and int(ranked.argmax()) == 1 and ranked[2] == float("-inf")


def test_progress_keeps_a_passing_candidate_over_a_higher_scoring_one_that_fails():
    """``passed`` (the kept candidate meets the success thresholds) and ``sims_to_success`` (some candidate met them)
    disagreed where the best candidate by score missed a threshold that a lower-scoring one met: a run reported a
    success count and a result that does not pass, and with ``stop_on_success`` the passing candidate it stopped for
    was not the one it returned. A passing candidate now outranks every failing one; among passing (or among
    failing) candidates the higher score wins."""
    p = Progress(10)
    x = torch.arange(6, dtype=torch.float64)[:, None, None].expand(6, 2, 7)
    m = Metrics(*(torch.arange(6, dtype=torch.float64)[:, None].expand(6, 3) for _ in range(3)))

    def record(i: slice, score: list[float], success: list[bool]) -> None:
        p.record(x[i], Metrics(*(t[i] for t in m)), torch.tensor(score), torch.tensor(success))

    record(slice(0, 2), [5.0, 1.0], [False, False])
    record(slice(2, 4), [4.0, 2.0], [False, True])  # the passing candidate scores below the best so far
    assert p.sims_to_success == 4 and float(p.best_x[0, 0]) == 3.0 and p.best_score == 2.0
    assert float(p.best_metrics.area[0]) == 3.0
    record(slice(4, 6), [9.0, 3.0], [False, True])  # a failing one never replaces it, a better passing one does
    assert float(p.best_x[0, 0]) == 5.0 and p.best_score == 3.0 and p.sims_to_success == 4
    assert p.history_array().tolist() == [[2.0, 5.0, 5.0], [4.0, 2.0, 2.0], [6.0, 3.0, 3.0]]


def test_progress_records_an_empty_batch_as_nothing():
    p = Progress(3)
    empty = Metrics(*(torch.ones(0, 3) for _ in range(3)))
    p.record(torch.zeros(0, 2, 7), empty, torch.zeros(0), torch.zeros(0, dtype=torch.bool))  # raised IndexError
    assert p.used == 0 and p.history == [] and p.best_x is None
