"""Optimizer baselines: they improve the fit, keep the budget exactly, are seeded, and configs fail early."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from marlcrash.calibrate import (
    BASELINES,
    CMAESConfig,
    GradientConfig,
    LMConfig,
    ProblemConfig,
    RandomSearchConfig,
    build_problem,
    load_run_config,
)
from marlcrash.calibrate.problem import SmoothLoss
from marlcrash.config import config_dir, from_dict, load_yaml
from marlcrash.envs.core import build_cells
from marlcrash.errors import ConfigError

DURATION = 0.02  # short window: every simulation is cheap [s]
SMALL = {
    "random_search": (RandomSearchConfig(batch_size=32), 200),
    "cmaes": (CMAESConfig(popsize=16), 200),
    "gradient": (GradientConfig(batch_size=2, lr=0.03), 12),
    "lm": (LMConfig(iterations=2), 200),
}


@pytest.fixture(scope="module")
def problem():
    cells = build_cells("b_segment", None, "optimized")
    return build_problem(from_dict(ProblemConfig, {"duration": DURATION}), cells=cells)


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.mark.parametrize("method", sorted(BASELINES))
def test_baseline_improves_and_keeps_budget(problem, method):
    config, budget = SMALL[method]
    before = problem.n_simulations
    result = BASELINES[method][1](problem, budget, config, 0)
    spent = result.simulations
    assert problem.n_simulations - before == spent and result.history[-1, 0] == spent
    # the others stop exactly at the budget; LM when the rest cannot pay for a whole iteration
    assert spent == budget if method != "lm" else 0 <= budget - spent < problem.n_free + 7
    assert np.all(np.diff(result.history[:, 0]) > 0)
    assert np.all(np.diff(result.history[:, 1]) >= 0)  # best so far never gets worse
    assert result.best_score > result.initial_score + 0.02
    # the reported metrics are those of best_x, and the initial ones those of x = 0 (gradient descent
    # measures them on the torch path, re-evaluated here on numba: round-off apart)
    again = problem.evaluate(torch.stack([problem.zeros(1)[0], result.best_x]))
    for got, init, final in zip(again, result.initial_metrics, result.final_metrics, strict=True):
        torch.testing.assert_close(got[0], init, rtol=0, atol=1e-7)
        torch.testing.assert_close(got[1], final, rtol=0, atol=1e-7)
    assert torch.equal(result.best_x, problem.clip(result.best_x))
    s = result.summary()
    assert set(s["final_metrics"]) == set(problem.sensors)
    assert set(s["param_error"]) == set(problem.subassembly_names)
    assert s["sims_to_success"] is None  # the paper's thresholds are far from reach in so few simulations


@pytest.mark.parametrize("method", ["random_search", "cmaes"])
def test_seeded_runs_are_deterministic_and_leave_global_rng_alone(problem, method):
    config = SMALL[method][0]
    fn = BASELINES[method][1]
    np_state, torch_state = np.random.get_state()[1].copy(), torch.get_rng_state().clone()  # noqa: NPY002
    a, b, c = fn(problem, 48, config, 7), fn(problem, 48, config, 7), fn(problem, 48, config, 8)
    assert torch.equal(a.best_x, b.best_x) and np.array_equal(a.history, b.history)
    assert not torch.equal(a.best_x, c.best_x)
    assert np.array_equal(np.random.get_state()[1], np_state)  # noqa: NPY002
    assert torch.equal(torch.get_rng_state(), torch_state)


def test_a_baseline_reports_why_it_stopped(problem):
    """A result says why its run ended (``stop``, and in the summary): ``budget``, ``success`` (``stop_on_success``),
    or ``ended`` by the method's own rule, which ``stop_reason`` names (CMA-ES's termination criteria, as
    ``es.stop()`` keys them; lm's last window). Nothing reported it: a comparison inferred it from the budget left,
    and an lm without restarts whose window ended by its own iteration cap with less than an iteration left was
    ``budget``."""
    per_iter = problem.n_free + 6
    rs = BASELINES["random_search"][1](problem, 40, SMALL["random_search"][0], 0)
    assert (rs.stop, rs.stop_reason) == ("budget", None) and rs.simulations == 40
    cm = BASELINES["cmaes"][1](problem, 200, CMAESConfig(popsize=8, sigma0=1e-13, restarts=False), 0)
    assert cm.stop == "ended" and "tolx" in cm.stop_reason.split(", ") and cm.simulations == 1 + 8
    assert {k: cm.summary()[k] for k in ("stop", "stop_reason")} == {"stop": "ended", "stop_reason": cm.stop_reason}
    restarted = BASELINES["cmaes"][1](problem, 40, CMAESConfig(popsize=8, sigma0=1e-13, restarts=True), 0)
    assert (restarted.stop, restarted.stop_reason) == ("budget", None) and restarted.simulations == 40
    lm = BASELINES["lm"][1](problem, 1 + per_iter + 3, LMConfig(iterations=1, restart_radius=0.0), 0)
    assert lm.simulations == 1 + per_iter and (lm.stop, lm.stop_reason) == ("ended", "windows")  # its cap, not 3 left
    cut = BASELINES["lm"][1](problem, 1 + per_iter + 3, LMConfig(iterations=12, restart_radius=0.0), 0)
    assert cut.simulations == 1 + per_iter and (cut.stop, cut.stop_reason) == ("budget", None)  # 3 left: no iteration
    loose = build_problem(
        from_dict(ProblemConfig, {"duration": DURATION, "success": {"area": 10.0, "dfd": None, "rmse": None}}),
        cells=problem.cells,
    )
    for method in ("random_search", "lm"):
        won = BASELINES[method][1](loose, SMALL[method][1], SMALL[method][0], 0, stop_on_success=True)
        assert (won.stop, won.stop_reason) == ("success", None), method


def test_lm_is_seeded_and_its_restarts_use_the_seed(problem):
    """One iteration per window, so the budget goes to restarts, whose noise is the only random draw."""
    config = LMConfig(iterations=1, restart_radius=0.05)
    a, b, c = (BASELINES["lm"][1](problem, 3 * (problem.n_free + 7), config, seed) for seed in (3, 3, 4))
    assert torch.equal(a.best_x, b.best_x) and np.array_equal(a.history, b.history)
    assert not np.array_equal(a.history, c.history)
    per_iter = problem.n_free + 6
    assert a.simulations == (1 + per_iter) * 3  # start + 1 iteration, then two restarts of (start + 1 iteration)


def test_lm_without_restarts_stops_when_the_window_stalls(problem):
    per_iter = problem.n_free + 6
    capped = BASELINES["lm"][1](problem, 20_000, LMConfig(restart_radius=0.0, iterations=8, stall=8), 0)
    assert capped.simulations == 1 + 8 * per_iter  # no restarts: the window's iteration cap ends the run
    # an iteration lowering the cost by less than half counts as stalled here: two in a row end it early
    stalled = BASELINES["lm"][1](problem, 20_000, LMConfig(restart_radius=0.0, iterations=8, rtol=0.5, stall=2), 0)
    assert (stalled.simulations - 1) % per_iter == 0 and stalled.simulations < capped.simulations


def test_lm_recovers_a_near_twin_truth_and_fits_windows_in_turn(problem):
    """A twin whose hidden perturbation is 2 % per parameter: LM passes the paper's test within a few iterations,
    fitting the whole 50 ms window at once or its first 30 ms before the whole (a first window of 20 ms stalls at
    1.1x the mark within this budget)."""
    near = build_problem(
        from_dict(ProblemConfig, {"duration": 0.05, "env_overrides": {
            "reference.twin.e_x_spread": 0.02, "reference.twin.e_s_spread": 0.02,
            "reference.twin.transmission_spread": 0.02}}),
        cells=problem.cells,
    )  # fmt: skip
    assert not bool(near.success(near.evaluate(near.zeros(1)))[0])  # the initial parameters fail
    per_iter = near.n_free + 6
    for windows in ([1.0], [0.6, 1.0]):
        res = BASELINES["lm"][1](near, 1 + 4 * per_iter, LMConfig(windows=windows), 0, stop_on_success=True)
        assert res.sims_to_success is not None, windows
        worst = max(v["area"] for v in res.summary()["final_metrics"].values())
        assert worst < 0.0015


def test_gradient_is_deterministic(problem):
    config = GradientConfig(batch_size=2)
    a, b = (BASELINES["gradient"][1](problem, 4, config, 3) for _ in range(2))
    assert torch.equal(a.best_x, b.best_x) and np.array_equal(a.history, b.history)


def test_sims_to_success_and_stop_on_success(problem):
    loose = build_problem(
        from_dict(ProblemConfig, {"duration": DURATION, "success": {"area": 10.0, "dfd": None, "rmse": None}}),
        cells=problem.cells,
    )
    r = BASELINES["random_search"][1](loose, 100, SMALL["random_search"][0], 0, stop_on_success=True)
    assert r.sims_to_success == 1 and r.simulations == 1  # the initial point already passes


def test_success_counts_the_candidate_that_passed(problem):
    """A threshold between the initial fit and a better one: success is found at the recorded count."""
    init_area = float(problem.evaluate(problem.zeros(1)).area.max())
    mid = build_problem(
        from_dict(ProblemConfig, {"duration": DURATION, "success": {"area": init_area * 0.999, "dfd": None,
                                                                     "rmse": None}}),
        cells=problem.cells,
    )  # fmt: skip
    r = BASELINES["cmaes"][1](mid, 64, SMALL["cmaes"][0], 0)
    assert r.sims_to_success is not None and 1 < r.sims_to_success <= 64
    assert float(r.history[0, 1]) == r.initial_score  # the first batch is x = 0 alone, which fails


def test_random_search_recentres_on_a_first_passing_candidate_of_a_lower_score(problem, monkeypatch):
    """The success test ranks a passing candidate first; the worst of the second batch passing (a lower score than
    the failing best) was kept as the best, but the search recentred only on a higher score, so it went on drawing
    around the failing one and shrinking its radius."""
    calls = []
    evaluate, score = problem.evaluate, problem.score

    def success(m):
        s = score(m)
        ok = torch.zeros(s.shape[0], dtype=torch.bool)
        if len(calls) == 3:  # the start, batch 1, batch 2: the worst of batch 2 passes
            ok[int(torch.argmin(s))] = True
        return ok

    def recorded(x):
        calls.append(x.clone())
        return evaluate(x)

    monkeypatch.setattr(problem, "success", success)
    monkeypatch.setattr(problem, "evaluate", recorded)
    config = RandomSearchConfig(batch_size=8)
    r = BASELINES["random_search"][1](problem, 1 + 3 * 8, config, 0)
    assert any(torch.equal(r.best_x, c) for c in calls[2]) and r.sims_to_success is not None
    centre = problem.flat(r.best_x[None])[0].numpy()
    lo, hi = (b.numpy() for b in problem.flat_box())
    z3 = problem.flat(calls[3]).numpy()
    reach = config.radius * 0.5 * (hi - lo)  # the radius is kept where the centre moves
    inner = (z3 > lo) & (z3 < hi)  # draws the box did not clip
    assert (np.abs(z3 - centre)[inner] <= np.broadcast_to(reach, z3.shape)[inner] * (1 + 1e-9)).all()


@pytest.mark.parametrize(
    ("over", "key"),
    [
        ({"method": "annealing"}, "method"),
        ({"budget": 0}, "budget"),
        ({"gradient": {"lr": -0.1}}, "gradient.lr"),
        ({"gradient": {"backend": "numba"}}, "gradient.backend"),
        ({"gradient": {"loss": {"area_scale": 0.0}}}, "gradient.loss.area_scale"),
        ({"gradient": {"loss": {"w_area": float("inf")}}}, "gradient.loss.w_area"),
        ({"gradient": {"loss": {"w_rmse": 1e308}}}, "gradient.loss.w_rmse"),  # the loss overflowed to inf
        ({"gradient": {"loss": {"rmse_scale": 1e-310}}}, "gradient.loss.rmse_scale"),
        ({"random_search": {"radius": float("nan")}}, "random_search.radius"),
        ({"cmaes": {"popsize": 1}}, "cmaes.popsize"),
        ({"random_search": {"shrink": 1.5}}, "random_search.shrink"),
        ({"lm": {"windows": [0.5, 0.3, 1.0]}}, "lm.windows"),
        ({"lm": {"windows": [0.5]}}, "lm.windows"),
        ({"lm": {"fd_step": 0.0}}, "lm.fd_step"),
        ({"lm": {"restart_radius": -0.1}}, "lm.restart_radius"),
        ({"lm": {"stall": 0}}, "lm.stall"),
        ({"problem": {"box_radius": 0.0}}, "problem.box_radius"),
        ({"seed": -1}, "seed"),
        ({"seed": 2**64}, "seed"),  # torch's generators refused it after the problem was built, with a traceback
        ({"problem": {"scenario": "nope"}}, "problem.scenario"),
        ({"problem": {"reference_seed": -2}}, "problem.reference_seed"),
        ({"problem": {"success": {"dfd": -0.3}}}, "problem.success.dfd"),
        ({"name": "a/b"}, "name"),
        ({"seeds": 3}, "seeds"),
        # the key the user set, not the reward form's 'name', the env loader's 'env' or the env file's own keys
        ({"problem": {"fit": "nope"}}, "problem.fit"),
        ({"problem": {"env": "nope"}}, "problem.env"),
        ({"problem": {"env_overrides": {"max_step": 9.0}}}, "problem.env_overrides.max_step"),
        ({"problem": {"env_overrides": {"reward": "nope"}}}, "problem.env_overrides.reward"),
        ({"problem": {"env_overrides": {"termination": 3}}}, "problem.env_overrides.termination"),
        ({"problem": {"env_overrides": {"reference.kind": "file"}}}, "problem.env_overrides.reference.kind"),
        ({"problem": {"env_overrides": {"scenarios": {"offset40_left": 1.0}}}}, "problem.env_overrides.scenarios"),
    ],
)
def test_bad_run_configs_fail_before_running(over, key):
    with pytest.raises(ConfigError) as e:
        load_run_config(over)
    assert e.value.key == key
    if any(isinstance(v, float) and not math.isfinite(v) for v in _leaves(over)):
        assert "expected a finite number" in str(e.value)


def test_adjoint_gradient_on_a_float32_env_fails_at_load_naming_the_backend():
    """The adjoint differentiates float64 simulations only: the run used to build the problem and then stop with a
    keyless ModelError."""
    f32 = {"problem": {"env_overrides": {"sim_dtype": "float32"}}}
    with pytest.raises(ConfigError, match="needs dtype float64") as e:
        load_run_config({"method": "gradient", **f32})
    assert e.value.key == "gradient.backend"
    load_run_config({"method": "gradient", "gradient": {"backend": "torch"}, **f32})  # the torch path takes float32
    load_run_config({"method": "lm", "lm": {"fd_step": 1e-3}, **f32})  # another method does not use the backend


def test_the_largest_seed_runs_every_seeded_method(problem):
    """2**64 - 1 is the largest seed torch's generators take (gradient descent, lm); the config refuses larger."""
    from marlcrash.config import MAX_SEED

    for method in ("gradient", "lm"):
        config, budget = SMALL[method]
        assert BASELINES[method][1](problem, budget, config, MAX_SEED).simulations > 0
    assert load_run_config({"seed": MAX_SEED}).seed == MAX_SEED


def _leaves(d):
    for v in d.values():
        yield from _leaves(v) if isinstance(v, dict) else (v,)


def test_yaml_registry_and_comments():
    folder = config_dir() / "train" / "baseline"
    assert sorted(p.stem for p in folder.glob("*.yaml")) == sorted(BASELINES)
    for name, (cls, _) in BASELINES.items():
        from_dict(cls, load_yaml(folder / f"{name}.yaml"))  # every file is a valid schema
    for path in [config_dir() / "train" / "baseline.yaml", *folder.glob("*.yaml")]:
        for i, line in enumerate(Path(path).read_text().splitlines(), 1):
            if re.match(r"^\s*[\w@/-]+\s*:", line) or re.match(r"^\s*- ", line):
                assert "#" in line, f"{path.name} line {i}: key without a comment: {line!r}"


def test_hydra_composes_the_primary_config():
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(str(config_dir() / "train"), version_base=None):
        cfg = compose("baseline", overrides=["method=gradient", "budget=10", "gradient.lr=0.01", "name=x"])
    run = load_run_config(OmegaConf.to_container(cfg, resolve=True))
    assert run.method == "gradient" and run.budget == 10 and run.method_config.lr == 0.01
    assert run.problem.success.area == 0.0015 and run.problem.success.rmse == 0.1511


def test_baseline_results_go_beside_a_folder_another_run_took_meanwhile(tmp_path):
    from marlcrash.calibrate import BASELINES, build_problem, write_run
    from marlcrash.calibrate.baselines import BaselineRunConfig, RandomSearchConfig
    from marlcrash.calibrate.problem import ProblemConfig

    cfg = BaselineRunConfig(method="random_search", name="b", out_dir=str(tmp_path / "runs"), plot=False,
                            problem=ProblemConfig(duration=0.01))  # fmt: skip
    problem = build_problem(cfg.problem)
    result = BASELINES["random_search"][1](problem, 4, RandomSearchConfig(batch_size=4), 0)
    final = tmp_path / "runs" / "random_search" / "b"
    final.mkdir(parents=True)
    (final / "summary.json").write_text("{}")  # another run of this name finished while this one ran
    (final.parent / "b-2").mkdir()  # ... and one more started
    with pytest.warns(UserWarning, match="results are in .*b-3"):
        got = write_run(cfg, problem, result)
    assert got == final.parent / "b-3" and (got / "summary.json").stat().st_size > 100
    assert (final / "summary.json").read_text() == "{}" and not any((final.parent / "b-2").iterdir())
    assert sorted(p.name for p in final.parent.iterdir()) == ["b", "b-2", "b-3"]  # no temporary folder left


def test_lm_refuses_a_budget_below_one_iteration(problem):
    """It spent one simulation and reported stop reason 'budget' next to methods that spent the whole budget."""
    need = 1 + problem.n_free + 6
    with pytest.raises(ConfigError, match=f"key 'budget': lm needs at least .* = {need} simulations, got a budget of"):
        BASELINES["lm"][1](problem, need - 1, LMConfig(), 0)
    assert BASELINES["lm"][1](problem, need, LMConfig(iterations=1), 0).simulations == need


def test_a_baseline_whose_candidates_all_diverged_writes_standard_json(tmp_path):
    """Every candidate non-finite: the best score is -inf, and summary.json held ``-Infinity`` (no JSON)."""
    import dataclasses
    import json

    from marlcrash.calibrate import BASELINES, build_problem, write_run
    from marlcrash.calibrate.baselines import BaselineRunConfig, RandomSearchConfig
    from marlcrash.calibrate.problem import ProblemConfig

    cfg = BaselineRunConfig(method="random_search", name="nan", out_dir=str(tmp_path / "runs"), plot=False,
                            problem=ProblemConfig(duration=0.01))  # fmt: skip
    problem = build_problem(cfg.problem)
    result = BASELINES["random_search"][1](problem, 4, RandomSearchConfig(batch_size=4), 0)
    result = dataclasses.replace(result, best_score=float("-inf"), initial_score=float("nan"))
    folder = write_run(cfg, problem, result)

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    s = json.loads((folder / "summary.json").read_text(), parse_constant=refuse)
    assert s["best_score"] is None and s["initial_score"] is None


def test_a_baseline_run_folder_gets_the_permissions_of_any_other_folder(tmp_path, umask):
    """The folder was assembled in ``tempfile.mkdtemp`` (mode ``0o700``) and renamed into place, so nobody else could
    read a run whose files were ``0o644``; it gets ``0o777`` less the umask, as ``mkdir`` makes every other folder."""

    from marlcrash.calibrate import BASELINES, build_problem, write_run
    from marlcrash.calibrate.baselines import BaselineRunConfig, RandomSearchConfig
    from marlcrash.calibrate.problem import ProblemConfig

    cfg = BaselineRunConfig(method="random_search", name="perm", out_dir=str(tmp_path / "runs"), plot=False,
                            problem=ProblemConfig(duration=0.01))  # fmt: skip
    problem = build_problem(cfg.problem)
    result = BASELINES["random_search"][1](problem, 2, RandomSearchConfig(batch_size=2), 0)
    umask(0o022)
    folder = write_run(cfg, problem, result)
    assert folder.stat().st_mode & 0o777 == 0o755
    assert (folder / "summary.json").stat().st_mode & 0o777 == 0o644
    assert sorted(p.name for p in folder.parent.iterdir()) == ["perm"]  # no temporary folder left


def test_gradient_descent_goes_on_past_a_candidate_whose_gradient_is_not_finite(problem, monkeypatch):
    """A candidate whose simulation diverges has a NaN gradient; Adam made its log-scales NaN and the next step's
    simulation refused them ("candidate 1: x[0, 0] ... is not finite"), ending the run with a ModelError after part
    of the budget was spent. That candidate's gradient is dropped for the step; the others move as before."""
    loss = problem.loss
    seen: list[torch.Tensor] = []

    def watched(nan_row):
        def fn(x, weights, backend="adjoint"):
            seen.append(x.detach().clone())
            if nan_row is not None:
                x.register_hook(lambda g: torch.where(torch.arange(g.shape[0])[:, None, None] == nan_row, torch.nan, g))
            return loss(x, weights, backend)

        return fn

    config = GradientConfig(batch_size=2)
    monkeypatch.setattr(problem, "loss", watched(None))
    BASELINES["gradient"][1](problem, 6, config, 0)
    clean, seen[:] = list(seen), []
    monkeypatch.setattr(problem, "loss", watched(1))
    got = BASELINES["gradient"][1](problem, 6, config, 0)
    assert got.simulations == 6 and len(seen) == 3 and all(bool(torch.isfinite(x).all()) for x in seen)
    for a, b in zip(clean, seen, strict=True):
        assert torch.equal(a[0], b[0])  # the other candidate's steps are those of the clean run
    assert not torch.equal(seen[1][0], seen[0][0])  # ... which do move it
    assert torch.equal(seen[1][1], seen[0][1])  # the diverged one is held (Adam has no momentum yet)


def test_lm_on_a_float32_env_needs_a_finite_difference_step_above_its_rounding(problem):
    """At the default step (1e-5) a float32 simulation's finite differences are rounding noise: the Jacobian's
    columns came out 4.5x off float64's, and lm ran on a noise Jacobian without a word. Refused at load (key
    ``lm.fd_step``), as the adjoint's float32 limit is; from 1e-3 its error is within a fifth."""
    f32 = {"problem": {"env_overrides": {"sim_dtype": "float32"}}}
    with pytest.raises(ConfigError, match=r"float32 .* at least 0\.001") as e:
        load_run_config({"method": "lm", **f32})
    assert e.value.key == "lm.fd_step"
    assert load_run_config({"method": "lm", "lm": {"fd_step": 1e-3}, **f32}).lm.fd_step == 1e-3
    load_run_config({"method": "cmaes", **f32})  # other methods take no finite differences
    load_run_config({"method": "lm"})  # float64: the default step

    single = build_problem(from_dict(ProblemConfig, {"duration": 0.05, "env_overrides": {"sim_dtype": "float32"}}),
                           cells=problem.cells)  # fmt: skip
    double = build_problem(from_dict(ProblemConfig, {"duration": 0.05}), cells=problem.cells)
    n = 12

    def jacobian(p, h):
        z = torch.cat([torch.zeros(1, p.n_free, dtype=torch.float64), h * torch.eye(p.n_free)[:n]])
        r = p.residuals(p.unflat(z))[0].flatten(1)
        return (r[1:] - r[0]) / h

    exact = jacobian(double, 1e-5)

    def error(h):
        return float((jacobian(single, h) - exact).norm() / exact.norm())

    assert error(1e-5) > 1.0 and error(1e-3) < 0.2


def test_cmaes_says_when_its_budget_cannot_complete_a_generation(problem):
    """A budget below 1 + popsize (the amortized comparison's "cmaes 1x": 13 simulations, popsize 32) simulated the
    start and part of one population and never told CMA-ES anything: a random sample around the start, reported as a
    CMA-ES run without a word. It warns, naming the key and the budget, and the result counts the generations."""
    config = CMAESConfig(popsize=16)
    with pytest.warns(UserWarning, match=r"budget of 13 simulations .* cmaes\.popsize = 16 .* 1 \+ 16 = 17"):
        short = BASELINES["cmaes"][1](problem, 13, config, 0)
    assert short.simulations == 13 and short.generations == 0 and short.summary()["generations"] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a budget that pays for a generation says nothing
        full = BASELINES["cmaes"][1](problem, 1 + 16, config, 0)
        partial = BASELINES["cmaes"][1](problem, 1 + 2 * 16 + 5, config, 0)  # the last 5 are no whole generation
    assert full.generations == 1 and partial.generations == 2 and partial.summary()["generations"] == 2
    assert BASELINES["random_search"][1](problem, 4, RandomSearchConfig(batch_size=2), 0).generations is None


@pytest.mark.parametrize(
    ("over", "key", "bound"),
    [
        ({"cmaes": {"popsize": 10**9}}, "cmaes.popsize", "10000"),
        ({"random_search": {"batch_size": 10**9}}, "random_search.batch_size", "10000"),
        ({"gradient": {"batch_size": 10**9}}, "gradient.batch_size", "10000"),
        ({"gradient": {"threads": 10**6}}, "gradient.threads", "1024"),
    ],
)
def test_population_batch_and_thread_counts_have_an_upper_bound(over, key, bound):
    """A population of 10**9 (one batched simulation, cma's arrays) or a gradient batch of 10**9 (its starting points
    are drawn at once) ran out of memory deep inside cma or torch after the problem was built; 10**6 torch threads were
    set as given. A random-search batch is one batched simulation too (of at most the budget's candidates): it was
    left unbounded. Refused at load, naming the key and the bound."""
    with pytest.raises(ConfigError, match=re.escape(bound)) as e:
        load_run_config(over)
    assert e.value.key == key
    assert load_run_config({"cmaes": {"popsize": 10_000}, "gradient": {"threads": 1024, "batch_size": 10_000},
                            "random_search": {"batch_size": 10_000}})  # fmt: skip


def test_lm_simulates_nothing_outside_a_box_narrower_than_its_finite_difference_step(problem, monkeypatch):
    """``problem.box_radius`` below ``lm.fd_step`` (both valid): the finite-difference points stepped out of the box
    by the whole step (to -1e-5 in a box of +-2e-6). Every candidate lm simulates is now inside it."""
    narrow = build_problem(from_dict(ProblemConfig, {"duration": DURATION, "box_radius": 2e-6}), cells=problem.cells)
    seen: list[torch.Tensor] = []
    residuals = narrow.residuals

    def watched(x):
        seen.append(torch.as_tensor(x).clone())
        return residuals(x)

    monkeypatch.setattr(narrow, "residuals", watched)
    result = BASELINES["lm"][1](narrow, 1 + 2 * (narrow.n_free + 6), LMConfig(iterations=2, restart_radius=0.0), 0)
    x = torch.cat(seen)
    assert x.shape[0] == result.simulations
    outside = (x < narrow.lower) | (x > narrow.upper)
    assert not bool(outside.any()), f"{int(outside.any(2).sum())} candidates outside the box, e.g. {x[outside][:3]}"


def _small_run(tmp_path, name, plot):
    from marlcrash.calibrate import build_problem
    from marlcrash.calibrate.baselines import BaselineRunConfig

    cfg = BaselineRunConfig(method="random_search", name=name, out_dir=str(tmp_path / "runs"), plot=plot,
                            problem=ProblemConfig(duration=0.01))  # fmt: skip
    problem = build_problem(cfg.problem)
    return cfg, problem, BASELINES["random_search"][1](problem, 2, RandomSearchConfig(batch_size=2), 0)


RESULT_FILES = ["best.pt", "config.json", "history.csv", "provenance.json", "summary.json"]


def test_a_baseline_run_folder_is_on_disk_before_its_name_points_at_it(tmp_path, monkeypatch):
    """The files were written and the folder renamed into place without an fsync: a system crash after the rename
    could leave a run folder of empty files, after the whole budget was spent."""
    import os

    from marlcrash.calibrate import write_run

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc/self/fd to name a file descriptor")
    events: list[tuple[str, str]] = []
    fsync, replace = os.fsync, os.replace

    def synced(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return fsync(fd)

    def renamed(src, dst):
        events.append(("replace", str(Path(src).resolve())))
        return replace(src, dst)

    cfg, problem, result = _small_run(tmp_path, "sync", plot=False)
    monkeypatch.setattr(os, "fsync", synced)
    monkeypatch.setattr(os, "replace", renamed)
    folder = write_run(cfg, problem, result)
    monkeypatch.undo()
    assert sorted(p.name for p in folder.iterdir()) == RESULT_FILES
    (move,) = [i for i, (what, _) in enumerate(events) if what == "replace"]
    tmp = Path(events[move][1])
    before = {Path(p) for what, p in events[:move] if what == "fsync"}
    assert {tmp / f for f in RESULT_FILES} | {tmp} <= before, events
    assert ("fsync", str(folder.parent.resolve())) in events[move:]  # the rename itself


def test_a_plot_that_fails_keeps_the_baseline_results(tmp_path, monkeypatch):
    """The plot was drawn before the folder was renamed into place, so a plotting failure (matplotlib, a backend, the
    re-simulation) discarded a run whose budget was spent. The results are written first; the failure is a warning
    naming the file."""
    from marlcrash.calibrate import baselines, write_run

    def broken(problem, result, path):
        Path(path).write_bytes(b"half a png")
        raise RuntimeError("no font cache")

    cfg, problem, result = _small_run(tmp_path, "plotfail", plot=True)
    monkeypatch.setattr(baselines, "plot_velocities", broken)
    failed = r"velocity\.png was not written: plotting failed \(RuntimeError: no font cache\)"
    with pytest.warns(UserWarning, match=failed):
        folder = write_run(cfg, problem, result)
    assert sorted(p.name for p in folder.iterdir()) == RESULT_FILES  # no partial plot, no temporary file
    assert (folder / "summary.json").stat().st_size > 100
    assert sorted(p.name for p in folder.parent.iterdir()) == ["plotfail"]
    monkeypatch.undo()
    cfg, problem, result = _small_run(tmp_path, "plotted", plot=True)
    assert (write_run(cfg, problem, result) / "velocity.png").stat().st_size > 1000


def test_lm_called_from_python_refuses_a_float32_problem_with_a_step_below_its_rounding(problem):
    """``load_run_config`` and ``compare`` refuse ``lm.fd_step`` below the float32 limit, but ``levenberg_marquardt``
    called from Python with a float32 problem ran its finite differences on rounding noise without a word. The
    function itself refuses now, before any simulation; a step from 1e-3 runs."""
    single = build_problem(from_dict(ProblemConfig, {"duration": DURATION, "env_overrides": {"sim_dtype": "float32"}}),
                           cells=problem.cells)  # fmt: skip
    before = single.n_simulations
    with pytest.raises(ConfigError, match=r"float32 .* at least 0\.001") as e:
        BASELINES["lm"][1](single, 1 + single.n_free + 6, LMConfig(), 0)
    assert e.value.key == "lm.fd_step" and single.n_simulations == before
    run = BASELINES["lm"][1](single, 1 + single.n_free + 6, LMConfig(fd_step=1e-3, iterations=1), 0)
    assert run.simulations == 1 + single.n_free + 6
    BASELINES["lm"][1](problem, 1 + problem.n_free + 6, LMConfig(iterations=1), 0)  # float64: the default step


@pytest.mark.parametrize("method", sorted(BASELINES))
def test_a_problem_whose_masking_leaves_no_agent_active_is_refused_by_every_baseline(problem, method):
    """Masking that leaves no agent active in the problem's scenario (here every agent must lie wholly in a shallow
    struck band) gives a problem of zero free coordinates: cmaes failed deep inside ``cma`` (ZeroDivisionError) and lm
    in a reshape of its empty Jacobian, after simulating the start; random search and gradient descent spent their
    budget on the start alone. Every baseline refuses it before simulating, naming the masking and the ways out."""
    strict = {"masking.min_fraction": 1.0, "masking.primary_depth": 0.01, "masking.secondary_hops": 0}
    idle = build_problem(from_dict(ProblemConfig, {"duration": DURATION, "scenario": "small_overlap_left",
                                                   "env_overrides": strict}), cells=problem.cells)  # fmt: skip
    assert idle.n_free == 0 and not bool(idle.active.any())
    config, _ = SMALL[method]
    before = idle.n_simulations
    with pytest.raises(ConfigError, match=r"no free coordinate.* none of its 21 agents is active in scenario "
                                          r"'small_overlap_left'.*problem\.masking: false") as e:  # fmt: skip
        BASELINES[method][1](idle, 20, config, 0)
    assert e.value.key == "problem.masking" and idle.n_simulations == before


def test_a_budget_is_any_whole_number_and_anything_else_is_named_as_such(problem):
    """A numpy integer budget (``np.arange``, ``np.geomspace(...).astype(int)``) was refused as "expected a simulation
    budget >= 1, got 40", a message its own value contradicts; a float budget read alike. A whole number of any integer
    type runs; a float or a bool is refused as not a whole number."""
    from marlcrash.calibrate.budget import Progress

    before = problem.n_simulations
    run = BASELINES["random_search"][1](problem, np.int64(40), RandomSearchConfig(batch_size=16), 0)
    assert run.simulations == 40 and problem.n_simulations - before == 40 and type(run.simulations) is int
    assert Progress(np.int32(3)).budget == 3 and type(Progress(np.int32(3)).budget) is int
    for bad in (40.0, True, "40"):
        with pytest.raises(ConfigError, match=r"key 'budget': expected a whole number of simulations >= 1, got") as e:
            Progress(bad)
        assert repr(bad) in str(e.value)
    with pytest.raises(ConfigError, match=r"expected a whole number of simulations >= 1, got 0"):
        Progress(np.int64(0))


def test_stiffnesses_frozen_by_the_behaviour_bounds_are_no_search_coordinates(problem):
    """``behaviour_bounds: [1.0, 1.0]`` (the env accepts it: E_x, E_s stay at their initial values) gives E_x, E_s a
    search box of no width. They were still counted free: cmaes failed inside ``cma`` with a ValueError ("Lower bounds
    need to be smaller than upper bounds") after simulating the start, and lm simulated a finite-difference point per
    frozen coordinate that moved nothing (42 of its 127 per iteration). Now a coordinate whose box has no width is
    fixed like any other that cannot change anything; every baseline runs on the transmission factors alone."""
    frozen = build_problem(from_dict(ProblemConfig, {"duration": DURATION, "env_overrides": {
        "behaviour_bounds": [1.0, 1.0]}}), cells=problem.cells)  # fmt: skip
    assert not bool(frozen.free[:, :2].any()) and torch.equal(frozen.free[:, 2:], problem.free[:, 2:])
    lo, hi = frozen.flat_box()
    assert frozen.n_free == int(problem.free[:, 2:].sum()) and bool((lo < hi).all())
    for method in sorted(BASELINES):
        config, _ = SMALL[method]
        budget = {"lm": frozen.n_free + 7, "gradient": 4}.get(method, 20)
        run = BASELINES[method][1](frozen, budget, config, 0)
        assert run.simulations == budget and bool((run.best_x[:, :2] == 0).all()), method


def test_lm_stops_on_success_found_by_a_finite_difference_point(problem):
    """With ``stop_on_success`` a run ends with the batch that holds the first passing candidate. lm's iteration is
    two batches, the Jacobian's finite-difference points and then the damped steps; where a finite-difference point
    passed, lm still simulated the damped steps (6 more simulations past the success). A threshold between the
    initial fit and the best finite-difference point's makes the first pass one of those points."""
    from marlcrash.calibrate.leastsq import fd_points

    lo, hi = problem.flat_box()
    points, _ = fd_points(torch.zeros_like(lo), lo, hi, LMConfig().fd_step)
    init = float(problem.evaluate(problem.zeros(1)).area.max())
    best = float(problem.evaluate(problem.unflat(points)).area.max(-1).values.min())
    assert best < init
    mid = build_problem(
        from_dict(ProblemConfig, {"duration": DURATION, "success": {"area": 0.5 * (best + init), "dfd": None,
                                                                     "rmse": None}}),
        cells=problem.cells,
    )  # fmt: skip
    run = BASELINES["lm"][1](mid, 1 + 3 * (mid.n_free + 6), LMConfig(), 0, stop_on_success=True)
    assert run.sims_to_success is not None and 1 < run.sims_to_success <= 1 + mid.n_free
    assert run.simulations == 1 + mid.n_free  # the start and the finite-difference batch, no damped steps
    assert run.history[-1, 0] == run.simulations and mid.n_simulations == run.simulations


@pytest.mark.parametrize(
    ("method", "config", "key"),
    [
        ("cmaes", CMAESConfig(sigma0=-1.0), "cmaes.sigma0"),  # ran, with a negative step
        ("cmaes", CMAESConfig(popsize=0), "cmaes.popsize"),  # ValueError inside cma after the start
        ("gradient", GradientConfig(batch_size=0), "gradient.batch_size"),  # IndexError
        ("gradient", GradientConfig(loss=SmoothLoss(area_scale=0.0)), "gradient.loss.area_scale"),
        ("lm", LMConfig(windows=[0.5]), "lm.windows"),  # fitted half the window and stopped
        ("random_search", RandomSearchConfig(radius=0.0), "random_search.radius"),  # drew the centre alone
        ("random_search", RandomSearchConfig(batch_size=0), "random_search.batch_size"),  # never ended
    ],
)
def test_settings_made_in_python_are_checked_before_any_simulation(problem, method, config, key):
    """The loaders check a config file's settings; a baseline called from Python with settings made there ran them
    unchecked: random search with batch_size 0 granted 0 candidates per batch forever, cmaes with popsize 0 failed
    inside ``cma``, gradient descent with batch_size 0 in an IndexError, and cmaes with sigma0 -1, lm with windows
    [0.5] or random search with radius 0 ran without a word. Each is refused before the start is simulated, naming the
    key as the config file has it."""
    before = problem.n_simulations
    with pytest.raises(ConfigError) as e:
        BASELINES[method][1](problem, problem.n_free + 7, config, 0)  # one lm iteration
    assert e.value.key == key and problem.n_simulations == before
