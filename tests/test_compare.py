"""The issue-5 results table: pinned references, best-so-far of PPO runs, wall cap, resume, the script.

Runs on a shortened copy of configs/ (every scenario simulated for 30 ms instead of 150 ms).
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from marlcrash.calibrate.budget import Progress
from marlcrash.calibrate.compare import (
    COLUMNS,
    METHODS,
    CompareConfig,
    evaluate_params,
    load_compare_config,
    outcome_row,
    ppo_train_config,
    problem_config,
    run_comparison,
    run_optimizer,
    run_ppo,
    winners,
)
from marlcrash.calibrate.logging import read_log
from marlcrash.calibrate.marl import ProgressHook, build_trainer, train_iteration
from marlcrash.calibrate.problem import build_problem
from marlcrash.envs.core import CalibrationCore, load_env_config
from marlcrash.errors import ConfigError
from marlcrash.metrics import Metrics

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def problem0(short, tmp_path_factory):
    """The optimizers' problem of reference seed 0 (built once: its twin-truth fit takes seconds)."""
    return build_problem(problem_config(tiny(tmp_path_factory.mktemp("p")), 0))


def tiny(tmp_path: Path, **kw) -> CompareConfig:
    """A comparison of seconds: budget 24, 2 envs x 3 steps per PPO iteration, small networks and batches."""
    data = yaml.safe_load((REPO / "configs" / "train" / "compare.yaml").read_text())
    for k in ("defaults", "hydra", "name"):
        data.pop(k)
    for m in ("mappo", "ippo", "ppo_single"):
        algo = yaml.safe_load((REPO / "configs" / "train" / "algorithm" / f"{m}.yaml").read_text())
        data[m] = {**algo, "hidden": [16, 16], "minibatch_size": 3, "epochs": 2}
    for m in ("random_search", "cmaes", "gradient", "lm"):
        data[m] = yaml.safe_load((REPO / "configs" / "train" / "baseline" / f"{m}.yaml").read_text())
    data["random_search"]["batch_size"] = 8
    data["cmaes"]["popsize"] = 8
    data["gradient"]["batch_size"] = 2
    data.update(budget=24, seeds=[0], out_dir=str(tmp_path / "runs"), name="t", max_wall_s=None)
    data["ppo"].update(n_envs=2, episode_length=3)
    for k, v in kw.items():
        node, parts = data, k.split(".")
        for p in parts[:-1]:
            node = node[p]
        node[parts[-1]] = v
    return load_compare_config(data, source="test")


def test_the_optimizers_problem_runs_the_envs_engines(tmp_path):
    """The problem of a comparison and of a run's evaluation scores candidates on the env's simulator and metrics
    engines (``auto``: numba without gradients); the evaluation's problem took the defaults whatever the env said."""
    from test_train_marl import tiny as tiny_train

    from marlcrash.calibrate.evaluate import evaluation_problem

    over = {"sim_backend": "torch", "metrics_backend": "torch"}
    pc = problem_config(tiny(tmp_path, env_overrides=over), 0)
    assert (pc.sim_backend, pc.metrics_backend) == ("torch", "torch")
    assert (problem_config(tiny(tmp_path), 0).sim_backend, problem_config(tiny(tmp_path), 0).metrics_backend) == (
        "numba", "numba")  # fmt: skip
    problem = evaluation_problem(tiny_train(tmp_path / "train", env_overrides=over))
    assert (problem.sim_backend, problem.metrics_backend) == ("torch", "torch")


# ------------------------------------------------------------------------------------- pinned env
@pytest.mark.parametrize("seed", [0, 3])
def test_pinned_env_reference_is_the_problems_bit_for_bit(short, problem0, tmp_path, seed):
    problem = problem0 if seed == 0 else build_problem(problem_config(tiny(tmp_path, seeds=[seed]), seed))
    env_cfg = load_env_config("default", {"scenarios": {"full_width_40": 1.0}, "reference.pin_seed": seed})
    core = CalibrationCore(env_cfg, batch_size=3)
    for reset_seed in (None, 99):  # the core's own generator plays no part
        core.reset(seed=reset_seed)
        for b in range(3):
            assert torch.equal(core.ref_velocity[b], problem.ref_velocity)
            assert torch.equal(core.true_params[b], problem.true_params)
            assert core.scenario[b] == "full_width_40"
        assert torch.equal(core.speed, problem.speed.expand(3))
    core.reset(mask=torch.tensor([False, True, False]))  # partial resets get it too
    assert torch.equal(core.ref_velocity[1], problem.ref_velocity)
    # the env's metrics of the initial parameters are the problem's (batched vs single simulation: round-off)
    m0 = problem.evaluate(problem.zeros(1))
    for got, want in zip(core.metrics, m0, strict=True):
        torch.testing.assert_close(got, want.expand_as(got), rtol=0, atol=1e-9)


def test_unpinned_env_still_draws_a_reference_per_episode(short):
    cfg = load_env_config("default", {"scenarios": {"full_width_40": 1.0}})
    assert cfg.reference.pin_seed is None  # the default: configs/env/default.yaml says null
    core = CalibrationCore(cfg, batch_size=2)
    core.reset(seed=0)
    assert not torch.equal(core.ref_velocity[0], core.ref_velocity[1])
    first = core.ref_velocity.clone()
    core.reset()
    assert not torch.equal(core.ref_velocity, first)


def test_pin_seed_is_validated(short):
    with pytest.raises(ConfigError) as e:
        load_env_config("default", {"reference.pin_seed": -1})
    assert e.value.key == "reference.pin_seed" and "seed >= 0" in str(e.value)
    with pytest.raises(ConfigError) as e:
        load_env_config("default", {"reference.pin_seed": "zero"})
    assert e.value.key == "reference.pin_seed"


# ------------------------------------------------------------------------------------ best so far
def _train(cfg: CompareConfig, method: str, tmp: Path, hooks: list) -> tuple:
    tc = ppo_train_config(cfg, method, 0, tmp)
    tr = build_trainer(tc, tmp / "log")
    for h in hooks:
        if isinstance(h, ProgressHook):
            h.attach(tr.env)
        else:
            tr.env.core.simulation_hooks.append(h)
    rows = [train_iteration(tr) for _ in range(2)]
    return tr, rows


@pytest.mark.parametrize("method", ["mappo", "ppo_single"])
def test_progress_hook_records_the_best_candidate_without_changing_training(short, problem0, tmp_path, method):
    cfg, problem = tiny(tmp_path), problem0
    seen: list[tuple[torch.Tensor, Metrics]] = []
    progress = Progress(20)  # more than the 2 iterations x 2 envs x (3 steps + 1 reset) = 16 simulations
    hook = ProgressHook(progress, problem.score, problem.success)
    with_hook, rows_hook = _train(cfg, method, tmp_path / "a", [hook, lambda p, m: seen.append((p, m))])
    plain, rows_plain = _train(cfg, method, tmp_path / "b", [])
    # training numbers unchanged: same log rows (wall times apart) and the same networks
    drop = ("wall_time_s", "env_steps_per_s")
    assert [{k: v for k, v in r.items() if k not in drop} for r in rows_hook] == [
        {k: v for k, v in r.items() if k not in drop} for r in rows_plain
    ]
    for a, b in zip(with_hook.policy.parameters(), plain.policy.parameters(), strict=True):
        assert torch.equal(a, b)
    # the hook saw every simulation the trainer charged, in batches of resets and steps
    assert hook.seen == with_hook.simulations == sum(p.shape[0] for p, _ in seen) == 16
    # independent reference: rank every candidate the env simulated
    params = torch.cat([p for p, _ in seen])
    metrics = Metrics(*(torch.cat([m[j] for _, m in seen]) for j in range(3)))
    scores = problem.score(metrics)
    k = int(torch.argmax(scores))
    assert progress.used == 16 and progress.best_score == float(scores[k])
    assert torch.equal(progress.best_x, params[k])
    # the recorded metrics are those of a fresh simulation of the best parameters on the problem's reference
    # (the env simulated it in a batch of n_envs rows, this in a batch of one: round-off only)
    fresh = evaluate_params(problem, progress.best_x[None])
    for got, want in zip(progress.best_metrics, fresh, strict=True):
        torch.testing.assert_close(got, want[0], rtol=0, atol=1e-9)
    best = progress.history_array()[:, 1]
    assert np.all(np.diff(best) >= 0) and best[-1] == progress.best_score


def test_progress_hook_success_count_and_budget_truncation(short, problem0, tmp_path):
    cfg, problem = tiny(tmp_path), problem0
    seen: list[tuple[torch.Tensor, Metrics]] = []
    tr, _ = _train(cfg, "ippo", tmp_path / "a", [lambda p, m: seen.append((p, m))])
    metrics = Metrics(*(torch.cat([m[j] for _, m in seen]) for j in range(3)))
    area = metrics.area.max(-1).values  # worst-sensor area of every candidate, in simulation order
    limit = float(area.median())
    first_pass = int(torch.nonzero(area < limit)[0, 0]) + 1

    def success(m: Metrics) -> torch.Tensor:
        return m.area.max(-1).values < limit

    # replay the same candidates (the hook is a plain callable) into budgets that cut the run short
    for budget in (first_pass - 1, first_pass, 16):
        if budget < 1:
            continue
        progress = Progress(budget)
        hook = ProgressHook(progress, problem.score, success)
        for p, m in seen:
            hook(p, m)
        assert hook.seen == 16 and progress.used == budget
        assert progress.sims_to_success == (first_pass if budget >= first_pass else None)
        scores = problem.score(Metrics(*(t[:budget] for t in metrics)))
        kept = scores[area[:budget] < limit] if budget >= first_pass else scores  # a passing candidate first
        assert progress.best_score == float(kept.max())
        assert bool(success(Metrics(*(t[None] for t in progress.best_metrics)))[0]) == (budget >= first_pass)
    assert tr.simulations == 16


# ---------------------------------------------------------------------------- runs, rows, wall cap
def test_optimizer_run_stopped_by_the_wall_cap_is_kept_and_flagged(short, problem0, tmp_path):
    cfg, problem = tiny(tmp_path, max_wall_s=1e-6), problem0
    out = run_optimizer(cfg, "random_search", 0, problem)
    assert out.stop == "wall_cap" and out.progress.used == 1  # the initial point, then the cap
    row = outcome_row(cfg, problem, out)
    assert row["simulations"] == 1 and row["stop"] == "wall_cap"
    assert row["score"] == pytest.approx(row["initial_score"], abs=1e-12)
    full = run_optimizer(tiny(tmp_path), "cmaes", 0, problem)
    assert full.stop == "budget" and full.progress.used == 24
    # the row's metrics are those of its best parameters
    fresh = evaluate_params(problem, full.best_params[None])
    assert float(fresh.area.mean()) == pytest.approx(outcome_row(cfg, problem, full)["area_mean"], abs=1e-12)


def test_passed_and_sims_to_success_columns_count_runs_that_meet_the_thresholds(short, problem0, tmp_path):
    # no method meets the paper's thresholds on the default car, so these columns are exercised with
    # thresholds of this test: every candidate passes, one between the initial and the best worst-sensor
    # area, and the paper's own
    from marlcrash.calibrate.compare import aggregate, markdown
    from marlcrash.reward import TerminationConfig

    cfg = tiny(tmp_path)

    def run(area: float, dfd: float, rmse: float, seed: int) -> dict:
        problem = copy.copy(problem0)
        problem.success_cfg = TerminationConfig(success_area=area, success_dfd=dfd, success_rmse=rmse, max_iterations=1)
        # optimizer seed 2: a run whose best candidate also lowers the worst-sensor area (asserted below)
        row = outcome_row(cfg, problem, run_optimizer(cfg, "random_search", 2, problem))
        return {**row, "seed": seed}

    strict = run(0.0015, 0.335, 0.1511, 2)
    assert not strict["passed"] and strict["sims_to_success"] is None
    lax = run(1e9, 1e9, 1e9, 0)
    assert lax["passed"] and lax["sims_to_success"] == 1  # the initial point, the first candidate, passes
    best_worst = strict["area_worst"]
    assert float(evaluate_params(problem0, problem0.init[None]).area.max()) > best_worst  # the search improved it
    mid = run(best_worst * (1 + 1e-9), 1e9, 1e9, 1)
    assert mid["passed"] and 1 < mid["sims_to_success"] <= strict["simulations"]
    (a,) = aggregate([lax, mid, strict], ["random_search"])
    assert a["passed"] == 2 and a["seeds"] == 3
    assert a["sims_to_success_median"] == (1 + mid["sims_to_success"]) / 2  # over the runs that passed
    md = markdown(cfg, [lax, mid, strict], None, "today")
    m = a["sims_to_success_median"]  # a median of two counts may end in .5, which the table keeps
    assert f"| random_search | 2/3 | {m:.0f} | " in md if float(m).is_integer() else f"| 2/3 | {m:.1f} | " in md


def test_lm_run_is_recorded_through_its_residual_batches(short, problem0, tmp_path):
    """LM evaluates candidates through ``residuals``: the recorder sees each batch as LM records it."""
    problem = problem0
    budget = 1 + 2 * (problem.n_free + 6) + 3
    out = run_optimizer(tiny(tmp_path, budget=budget), "lm", 0, problem)  # raises if the two records disagree
    assert out.stop == "budget" and out.progress.used == budget - 3  # 3 left: not enough for an iteration
    assert out.progress.best_score > float(out.progress.history[0].best)
    capped = run_optimizer(tiny(tmp_path, budget=budget, max_wall_s=1e-6), "lm", 0, problem)
    assert capped.stop == "wall_cap" and capped.progress.used == 1


def test_an_optimizer_that_ends_on_its_own_is_not_labelled_budget(short, problem0, tmp_path):
    """cmaes without restarts ends when CMA-ES's own criteria fire, lm without restarts (restart_radius 0) after its
    windows; both left most of the budget unused and were labelled ``stop = budget``, as if it had run out."""
    from marlcrash.calibrate.compare import markdown
    from marlcrash.calibrate.leastsq import STEP_FACTORS

    problem = problem0
    cfg = tiny(tmp_path, **{"cmaes.restarts": False, "cmaes.sigma0": 1e-13})  # tolx fires after one generation
    out = run_optimizer(cfg, "cmaes", 0, problem)
    assert out.progress.used == 1 + 8 < cfg.budget  # the start and one population of 8
    assert out.stop == "ended"
    per_iter = problem.n_free + len(STEP_FACTORS)  # one lm iteration
    budget = 1 + 3 * per_iter
    lm_cfg = tiny(tmp_path, budget=budget, **{"lm.restart_radius": 0.0, "lm.iterations": 1})
    lm = run_optimizer(lm_cfg, "lm", 0, problem)
    assert lm.progress.used == 1 + per_iter and lm.stop == "ended"  # one iteration, two more paid for
    row = outcome_row(lm_cfg, problem, lm)
    assert row["stop"] == "ended"
    md = markdown(lm_cfg, [row], None, "today")
    assert f"| {1 + per_iter} | ended on its own (windows) |" in md and "ended on its own (1/1)" in md
    # the same settings with the budget spent: budget
    short_lm = run_optimizer(tiny(tmp_path, budget=1 + per_iter + 3, **{"lm.restart_radius": 0.0}), "lm", 0, problem)
    assert short_lm.progress.used == 1 + per_iter and short_lm.stop == "budget"  # 3 left: not an iteration


def test_the_stop_column_is_the_optimizers_own_report(short, problem0, tmp_path):
    """``stop`` was inferred from the budget left after the run: lm without restarts whose one-iteration window ended
    with 3 simulations left (less than an iteration) was ``budget``, though its own rule ended it; now every
    optimizer reports why it stopped, and CMA-ES's criteria (``es.stop()`` keys) reach the CSV and the tables as
    ``stop_reason``."""
    from marlcrash.calibrate.compare import csv_text, markdown
    from marlcrash.calibrate.leastsq import STEP_FACTORS

    problem = problem0
    per_iter = problem.n_free + len(STEP_FACTORS)
    cfg = tiny(tmp_path, budget=1 + per_iter + 3, **{"lm.restart_radius": 0.0, "lm.iterations": 1})
    lm = run_optimizer(cfg, "lm", 0, problem)
    assert lm.progress.used == 1 + per_iter and (lm.stop, lm.stop_reason) == ("ended", "windows")
    cm_cfg = tiny(tmp_path, **{"cmaes.restarts": False, "cmaes.sigma0": 1e-13})
    cm = run_optimizer(cm_cfg, "cmaes", 0, problem)
    assert cm.stop == "ended" and "tolx" in cm.stop_reason.split(", ")
    row = outcome_row(cm_cfg, problem, cm)
    assert (row["stop"], row["stop_reason"]) == ("ended", cm.stop_reason) and "stop_reason" in COLUMNS
    (got,) = csv.DictReader(csv_text([row]).splitlines())
    assert (got["stop"], got["stop_reason"]) == ("ended", cm.stop_reason)
    assert f"| ended on its own ({cm.stop_reason}) |" in markdown(cm_cfg, [row], None, "today")
    spent = run_optimizer(tiny(tmp_path), "random_search", 0, problem)
    assert (spent.stop, spent.stop_reason) == ("budget", None)


def test_ppo_run_keeps_the_budget_and_reports_its_best(short, problem0, tmp_path):
    cfg, problem = tiny(tmp_path, budget=20), problem0  # 2 x (3 + 1) = 8 per iteration: 2 iterations, 16 sims
    out = run_ppo(cfg, "mappo", 0, problem, tmp_path / "run")
    assert out.stop == "budget" and out.extra == {"iterations": 2, "env_steps": 12, "trained_simulations": 16}
    assert out.progress.used == 16 <= cfg.budget
    assert len(read_log(tmp_path / "run" / "ppo" / "mappo" / "seed0" / "log.csv")) == 2
    row = outcome_row(cfg, problem, out)
    assert row["score"] >= row["initial_score"]  # the initial parameters are candidates too
    assert row["param_error"] is not None and row["iterations"] == 2


def test_comparison_resumes_and_refuses_changed_protocols(short, tmp_path):
    cfg = tiny(tmp_path, methods=["random_search"], seeds=[0])
    run_dir, rows = run_comparison(cfg)
    assert [(r["method"], r["seed"]) for r in rows] == [("random_search", 0)]
    with pytest.raises(ConfigError) as e:  # a fresh run never overwrites
        run_comparison(cfg)
    assert e.value.key == "name"
    more = tiny(tmp_path, methods=["random_search", "cmaes"], seeds=[0], resume=True)
    _, rows2 = run_comparison(more)
    assert [(r["method"], r["seed"]) for r in rows2] == [("random_search", 0), ("cmaes", 0)]
    assert rows2[0] == json.loads(json.dumps(rows[0]))  # the finished row was kept, not rerun
    with pytest.raises(ConfigError) as e:
        run_comparison(tiny(tmp_path, methods=["cmaes"], budget=32, resume=True))
    assert e.value.key == "budget" and "24" in str(e.value)
    # a method without finished rows may have other settings (e.g. added later); a finished one may not
    _, rows3 = run_comparison(tiny(tmp_path, methods=["cmaes"], resume=True, **{"lm.stall": 5, "mappo.lr": 1e-3}))
    assert rows3 == rows2
    with pytest.raises(ConfigError) as e:
        run_comparison(tiny(tmp_path, methods=["cmaes"], resume=True, **{"cmaes.popsize": 12}))
    assert e.value.key == "cmaes.popsize"
    data = json.loads((run_dir / "compare.json").read_text())
    assert len(data["rows"]) == 2 and data["config"]["budget"] == 24
    for r in data["rows"]:  # a record written before stop_reason was a column resumes, the reason unknown there
        del r["stop_reason"]
    (run_dir / "compare.json").write_text(json.dumps(data))
    # a resume with other seeds adds references: the table names every seed its rows cover
    _, rows5 = run_comparison(tiny(tmp_path, methods=["random_search"], seeds=[1], resume=True))
    assert sorted({r["seed"] for r in rows5}) == [0, 1] and [r["stop_reason"] for r in rows5] == [None] * 3
    assert [r["stop_reason"] for r in csv.DictReader((run_dir / "compare.csv").open())] == [""] * 3
    md = (run_dir / "compare.md").read_text()
    assert "with seeds [0, 1];" in md and "mean ± std over 2 references" in md
    moved = tmp_path / "moved"
    shutil.copytree(tmp_path / "runs", moved)  # a run folder moved elsewhere resumes there
    _, rows4 = run_comparison(tiny(tmp_path, methods=["cmaes"], resume=True, out_dir=str(moved)))
    assert rows4 == rows5


def test_a_first_run_that_failed_before_any_row_does_not_block_its_rerun(short, tmp_path, monkeypatch):
    import marlcrash.calibrate.compare as compare

    cfg = tiny(tmp_path, methods=["random_search"], seeds=[0])

    def broken(*args, **kwargs):
        raise RuntimeError("killed")

    with monkeypatch.context() as m:
        m.setattr(compare, "run_method", broken)
        with pytest.raises(RuntimeError):
            run_comparison(cfg)
    assert json.loads((cfg.run_dir / "compare.json").read_text())["rows"] == []
    _, rows = run_comparison(cfg)  # the same command again: nothing finished to protect
    assert [(r["method"], r["seed"]) for r in rows] == [("random_search", 0)]
    other = tiny(tmp_path, methods=["random_search"], seeds=[0], name="other")
    other.run_dir.mkdir(parents=True)
    (other.run_dir / "compare.json").write_text("{not json")  # not ours to overwrite
    with pytest.raises(ConfigError, match="exists already") as e:
        run_comparison(other)
    assert e.value.key == "name" and (other.run_dir / "compare.json").read_text() == "{not json"


def test_a_resume_removes_the_temporaries_of_the_tables_a_kill_left(short, tmp_path):
    """A kill while compare.json (.csv, .md, provenance.json) was rewritten left ``.compare.<hex>.tmp.json``
    beside it, which nothing removed. The comparison, which holds its folder, removes those of its own files;
    other names (another process's outputs) stay."""
    cfg = tiny(tmp_path, methods=["random_search"], seeds=[0])
    run_dir, _ = run_comparison(cfg)
    stale = [run_dir / ".compare.0badf00d.tmp.json", run_dir / ".compare.deadbeef.tmp.md",
             run_dir / ".provenance.0badf00d.tmp.json"]  # fmt: skip
    kept = [run_dir / ".notes.0badf00d.tmp.json", run_dir / ".compare.0badf00d.tmp.png"]
    for p in [*stale, *kept]:
        p.write_text("half a file")
    run_comparison(tiny(tmp_path, methods=["random_search"], seeds=[0], resume=True))
    assert sorted(p for p in run_dir.iterdir() if ".tmp" in p.name) == sorted(kept)


def _diverging(real, method: str):
    """``run_method`` whose ``method`` runs as if every candidate had diverged: no finite score, NaN areas."""

    def run(config, m, seed, problem, run_root):
        out = real(config, m, seed, problem, run_root)
        if m == method:
            p = out.progress
            p.best_score = float("-inf")
            p.history = [dataclasses.replace(h, best=float("-inf")) for h in p.history]
            p.best_metrics = Metrics(p.best_metrics.area * float("nan"), p.best_metrics.dfd, p.best_metrics.rmse)
        return out

    return run


def test_a_run_without_a_finite_score_is_standard_json_ranks_last_and_resumes(short, tmp_path, monkeypatch):
    """compare.json held ``-Infinity`` and ``NaN`` for a run whose every candidate diverged: jq and JavaScript refuse
    the whole file. They are null there (empty in the CSV, ``-`` in the tables), and a resume reads them back."""
    from test_outputs import _strict

    import marlcrash.calibrate.compare as compare

    monkeypatch.setattr(compare, "run_method", _diverging(compare.run_method, "cmaes"))
    said: list[str] = []
    cfg = tiny(tmp_path, methods=["cmaes", "random_search"], seeds=[0])
    run_dir, rows = run_comparison(cfg, progress=said.append)
    assert rows[0]["score"] is None and rows[0]["area_mean"] is None and rows[0]["history"][0][1] is None
    assert said[0].startswith("seed 0 cmaes: score - (initial ")

    def check(data):
        by = {r["method"]: r for r in data["rows"] if r["seed"] == 0}
        assert by["cmaes"]["score"] is None and by["cmaes"]["metrics"]["tunnel"]["area"] is None
        assert isinstance(by["random_search"]["score"], float)
        [w] = [w for w in data["winners"] if w["seed"] == 0]
        assert w["winner"] == ["random_search"] and w["score"] == by["random_search"]["score"]  # cmaes ranks last
        agg = {a["method"]: a for a in data["aggregate"]}
        assert agg["cmaes"]["score_mean"] is None and agg["random_search"]["score_mean"] is not None
        with open(run_dir / "compare.csv") as fh:
            table = {t["method"]: t for t in csv.DictReader(fh) if t["seed"] == "0"}
        assert table["cmaes"]["score"] == table["cmaes"]["area_mean"] == ""
        md = (run_dir / "compare.md").read_text()
        assert not re.search(r"\b(inf|nan)\b", md, re.IGNORECASE), md
        wins = md.split("## Winner per reference")[1].split("## Per run")[0].splitlines()
        head = next(ln for ln in wins if ln.startswith("| reference seed |")).strip("| ").split(" | ")
        cells = dict(zip(head, next(ln for ln in wins if ln.startswith("| 0 |")).strip("| ").split(" | "), strict=True))
        assert cells["cmaes"] == "-" and cells["winner"] == "random_search"
        per_run = md.split("## Per run")[1].splitlines()
        assert next(ln for ln in per_run if ln.startswith("| 0 | cmaes |")).count("| - |") >= 2  # area, score

    check(_strict((run_dir / "compare.json").read_text()))
    # a record from before: Python's json wrote -Infinity and NaN; a resume reads them as the rows' None
    record = json.loads((run_dir / "compare.json").read_text())
    record["rows"][0]["score"] = float("-inf")
    record["rows"][0]["metrics"]["tunnel"]["area"] = float("nan")
    (run_dir / "compare.json").write_text(json.dumps(record))
    _, more = run_comparison(tiny(tmp_path, methods=["cmaes", "random_search"], seeds=[0], resume=True))
    assert more == rows  # nothing left to run: the record read back, nulls as None
    check(_strict((run_dir / "compare.json").read_text()))
    # a resume that adds a run ranks and renders with the null read back
    _, more = run_comparison(tiny(tmp_path, methods=["random_search"], seeds=[1], resume=True))
    assert [(r["method"], r["seed"]) for r in more] == [("cmaes", 0), ("random_search", 0), ("random_search", 1)]
    data = _strict((run_dir / "compare.json").read_text())
    check(data)
    assert [(w["seed"], w["winner"]) for w in data["winners"]] == [(1, ["random_search"]), (0, ["random_search"])]


# --------------------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    ("override", "key", "words"),
    [
        ({"methods": ["mappo", "sgd"]}, "methods[1]", "unknown method 'sgd'"),
        ({"methods": []}, "methods", "at least one"),
        ({"budget": 0}, "budget", ">= 1"),
        ({"seeds": []}, "seeds", "at least one reference seed"),
        ({"seeds": [0, 0]}, "seeds", "distinct"),
        ({"seeds": [0, 2**64]}, "seeds[1]", "2**64 - 1"),  # torch.manual_seed of a PPO run refused it mid-table
        ({"max_wall_s": -1.0}, "max_wall_s", "> 0"),
        ({"ppo.threads": 100_000}, "ppo.threads", "thread count in [0, 1024]"),  # torch started them as asked
        ({"budget": 10**15, "ppo.n_envs": 10**12}, "ppo.n_envs", "[1, 10000] parallel episodes"),
        ({"budget": 10**15, "ppo.episode_length": 10**12}, "ppo.episode_length", "at most 100000 env steps"),
        ({"budget": 7}, "budget", "at least one iteration"),
        ({"mappo.minibatch_size": 4}, "mappo.minibatch_size", "divisor"),
        ({"ppo.env_overrides": {"reference.pin_seed": 3}}, "ppo.env_overrides.reference.pin_seed", "protocol"),
        ({"ppo.env_overrides": {"reference": {"pin_seed": 3}}}, "ppo.env_overrides.reference.pin_seed", "protocol"),
        ({"env_overrides": {"max_step": 9.0}}, "env_overrides.max_step", "log increment"),
        ({"scenario": "nope"}, "scenario", "unknown scenario 'nope'"),
        ({"env": "nope"}, "env", "unknown env config 'nope'"),  # not env_overrides.env
        ({"env_overrides": {"reward": "nope"}}, "env_overrides.reward", "unknown reward form 'nope'"),
        ({"ppo.env_overrides": {"termination": 3}}, "ppo.env_overrides.termination", "expected a mapping, got 3"),
        # set by the protocol for every method: an override would be replaced without a word
        ({"env_overrides": {"seed": 4}}, "env_overrides.seed", "protocol"),
        (
            {"env_overrides": {"termination": {"max_iterations": 4}}},
            "env_overrides.termination.max_iterations",
            "ppo.episode_length",
        ),
        (
            {"ppo.env_overrides": {"termination.max_iterations": 4}},
            "ppo.env_overrides.termination.max_iterations",
            "protocol",
        ),
    ],
)
def test_bad_config_fails_naming_the_key(short, tmp_path, override, key, words):
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, **override)
    assert e.value.key == key and words in str(e.value)
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ({"sim_dtype": "float32"}, "ppo.env_overrides.sim_dtype"),
        ({"sim_backend": "torch"}, "ppo.env_overrides.sim_backend"),
        ({"sensors": ["tunnel"]}, "ppo.env_overrides.sensors"),
        ({"discretization": "uniform"}, "ppo.env_overrides.discretization"),
        ({"transmission_floor": 0.05}, "ppo.env_overrides.transmission_floor"),
        ({"vehicle_seed": 3}, "ppo.env_overrides.vehicle_seed"),
        # the twin's draws are clipped to the bounds: accepted, and the table stopped at its first PPO run
        ({"behaviour_bounds": [0.9, 1.1]}, "ppo.env_overrides.behaviour_bounds"),
    ],
)
def test_ppo_env_overrides_that_change_the_reference_fail_before_any_run(short, tmp_path, override, key):
    """Each of these made the pinned PPO env draw another reference than the optimizers' problem: the table stopped
    at its first PPO run (after the optimizers' runs before it, key ``ppo.env_overrides``), and a resume without the
    entry was refused as another protocol. Now the config fails, naming the entry."""
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, **{"ppo.env_overrides": override})
    assert e.value.key == key and "shapes the reference pulse" in str(e.value)
    assert "top-level env_overrides" in str(e.value)
    # the same setting for every method is fine, and so are the PPO runs' own settings and restatements
    fine = {"ppo.env_overrides": override, "gradient.backend": "torch", "lm.fd_step": 1e-3}  # float32: see below
    tiny(tmp_path, env_overrides=override, **fine)
    tiny(tmp_path, **{"ppo.env_overrides": {"sim_backend": "numba", "reward": "paper_factor", "max_step": 0.05}})


def test_adjoint_gradient_on_a_float32_env_fails_before_any_run(short, tmp_path):
    """A float32 comparison used to stop at its first gradient run, after the runs before it, with a keyless
    ModelError of the adjoint; now the config names gradient.backend."""
    f32 = {"env_overrides": {"sim_dtype": "float32"}}
    with pytest.raises(ConfigError, match="needs dtype float64") as e:
        tiny(tmp_path, methods=["random_search", "gradient"], **f32)
    assert e.value.key == "gradient.backend"
    assert not (tmp_path / "runs").exists()
    tiny(tmp_path, methods=["random_search", "gradient"], **{"gradient.backend": "torch"}, **f32)
    tiny(tmp_path, methods=["random_search", "cmaes"], **f32)
    # lm's finite differences at the default step are float32 rounding noise (tests/test_calibrate_baselines.py)
    with pytest.raises(ConfigError, match=r"float32 .* at least 0\.001") as e:
        tiny(tmp_path, methods=["random_search", "lm"], **f32)
    assert e.value.key == "lm.fd_step"
    tiny(tmp_path, methods=["random_search", "lm"], **{"lm.fd_step": 1e-3}, **f32)


def test_config_file_registers_every_method(short, tmp_path):
    cfg = tiny(tmp_path)
    assert tuple(cfg.methods) == METHODS and cfg.seeds == [0] and cfg.success.area == 0.0015
    for m in ("mappo", "ippo", "ppo_single"):
        assert getattr(cfg, m).name == m
    full = yaml.safe_load((REPO / "configs" / "train" / "compare.yaml").read_text())
    assert full["seeds"] == [0, 1, 2] and full["methods"] == list(METHODS)
    assert dataclasses.asdict(copy.deepcopy(cfg)) == dataclasses.asdict(cfg)


# --------------------------------------------------------------------------------------- script
def _script(args: list[str], configs: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MARLCRASH_CONFIGS": str(configs), "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, str(REPO / "train" / "compare.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


TINY_ARGS = [
    "budget=24",
    "seeds=[0,1]",
    "max_wall_s=null",
    "ppo.n_envs=2",
    "ppo.episode_length=3",
    *(f"{m}.{k}" for m in ("mappo", "ippo", "ppo_single") for k in ("minibatch_size=3", "hidden=[16,16]")),
    "gradient.batch_size=2",
    "cmaes.popsize=8",
    "random_search.batch_size=8",
    "name=smoke",
]


@pytest.mark.slow
def test_script_runs_every_method(short_configs, tmp_path):
    """Every method but lm at a budget of 24; lm needs 134 for one iteration and is refused before anything runs
    (it ran 1 simulation and reported stop reason 'budget'). Its runs in a comparison are tested in-process."""
    methods = [m for m in METHODS if m != "lm"]
    lm = _script([*TINY_ARGS, "methods=[lm]", "name=lm_small"], short_configs, tmp_path)
    assert lm.returncode == 2 and "key 'budget': lm needs at least" in lm.stderr, lm.stderr[-3000:]
    assert not (tmp_path / "runs" / "compare" / "lm_small").exists()  # the refused name stays free
    p = _script([*TINY_ARGS, f"methods=[{','.join(methods)}]"], short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    run_dir = tmp_path / "runs" / "compare" / "smoke"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["runs"]  # Hydra wrote nothing else
    with open(run_dir / "compare.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(COLUMNS)
    assert sorted((r["method"], int(r["seed"])) for r in rows) == sorted((m, s) for m in methods for s in (0, 1))
    for r in rows:
        assert 1 <= int(r["simulations"]) <= 24 and r["stop"] == "budget"
        assert float(r["score"]) >= float(r["initial_score"]) - 1e-12
        assert r["passed"] in ("True", "False") and float(r["param_error"]) >= 0
    data = json.loads((run_dir / "compare.json").read_text())
    assert len(data["rows"]) == 2 * len(methods) and {w["seed"] for w in data["winners"]} == {0, 1}
    assert all(set(r["metrics"]) == {"upfront_left", "upfront_right", "tunnel"} for r in data["rows"])
    md = (run_dir / "compare.md").read_text()
    for m in methods:
        assert f"| {m} | " in md
    assert "## Winner per reference" in md and "Wins:" in md
    for m in ("mappo", "ippo", "ppo_single"):
        assert (run_dir / "ppo" / m / "seed1" / "log.csv").is_file()


def test_ctrl_c_in_the_script_says_what_the_folder_keeps_and_the_resume_that_continues_it(short_configs, tmp_path):
    """Ctrl-C in train/compare.py printed a traceback from wherever the work was (exit -2), and the user had to know
    that the finished rows were kept and that ``name=<the time stamp> resume=true`` goes on. It prints
    ``interrupted`` and that note, no traceback, and the process still ends by SIGINT (a shell loop stops there);
    the command the note names continues the comparison, skipping the finished row."""
    import signal

    interrupted_second = (
        "import runpy, sys\n"
        "import marlcrash.calibrate.compare as compare\n"
        "real, calls = compare.run_method, []\n"
        "def second_interrupted(*args, **kwargs):\n"
        "    calls.append(1)\n"
        "    if len(calls) == 2:\n"
        "        raise KeyboardInterrupt\n"
        "    return real(*args, **kwargs)\n"
        "compare.run_method = second_interrupted\n"
        f"sys.argv = [{str(REPO / 'train' / 'compare.py')!r}, *sys.argv[1:]]\n"
        "runpy.run_path(sys.argv[0], run_name='__main__')\n"
    )
    args = ["budget=16", "seeds=[0,1]", "max_wall_s=null", "methods=[random_search]", "random_search.batch_size=8"]
    env = {**os.environ, "MARLCRASH_CONFIGS": str(short_configs)}
    p = subprocess.run([sys.executable, "-c", interrupted_second, *args], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=600)  # fmt: skip
    (run_dir,) = (tmp_path / "runs" / "compare").iterdir()  # the default name: the launch time stamp
    note = (f"runs/compare/{run_dir.name} keeps the finished runs (compare.json); the same command with "
            f"name={run_dir.name} resume=true continues it, skipping them")  # fmt: skip
    assert p.returncode == -signal.SIGINT and "Traceback" not in p.stderr, p.stderr[-3000:]
    assert p.stderr.endswith(f"interrupted\n{note}\n"), p.stderr[-3000:]
    assert [r["seed"] for r in json.loads((run_dir / "compare.json").read_text())["rows"]] == [0]
    p = _script([*args, f"name={run_dir.name}", "resume=true"], short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    assert [r["seed"] for r in json.loads((run_dir / "compare.json").read_text())["rows"]] == [0, 1]


@pytest.mark.slow
def test_script_rejects_bad_config_before_running(short_configs, tmp_path):
    p = _script(["methods=[mappo,sgd]", "name=bad"], short_configs, tmp_path)
    assert p.returncode == 2
    assert "methods[1]" in p.stderr and "unknown method 'sgd'" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "runs").exists()


def test_a_comparison_whose_folder_another_process_writes_is_refused(short_configs, tmp_path, monkeypatch):
    from marlcrash.calibrate.runlock import run_lock

    monkeypatch.setenv("MARLCRASH_CONFIGS", str(short_configs))
    cfg = tiny(tmp_path, methods=["random_search"], seeds=[0])
    with run_lock(cfg.run_dir, "name", create=True), pytest.raises(ConfigError, match="in use") as e:
        run_comparison(cfg)
    assert e.value.key == "name" and not (cfg.run_dir / "compare.json").exists()


def test_the_recorder_stores_a_single_gradient_candidate_as_one_of_a_batch(short, problem0):
    """``CalibrationProblem.loss`` takes one ``[n_agents, 7]`` candidate as a batch of one; the comparison's recorder
    stored it unchecked, so the best candidate became one agent's row ``[7]``."""
    from marlcrash.calibrate.budget import Progress
    from marlcrash.calibrate.compare import _Recorder
    from marlcrash.calibrate.problem import SmoothLoss

    rec = _Recorder(problem0, Progress(2), max_wall_s=None)
    x = problem0.zeros(1)[0].requires_grad_()
    loss, _ = rec.loss(x, SmoothLoss())
    loss.sum().backward()
    assert tuple(rec.progress.best_x.shape) == (problem0.n_agents, 7) and rec.progress.used == 1
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())


@pytest.mark.parametrize("methods", [["random_search"], ["cmaes", "lm"]])
def test_a_comparison_whose_masking_leaves_no_agent_active_names_its_own_key_before_its_folder(
    short, tmp_path, methods
):
    """Masking that leaves no agent active in the comparison's scenario: the optimizers' refusal named the key
    ``problem.masking``, which compare.yaml does not have (its key is ``masking``), and came after the run folder
    was made; with lm it was lm's budget minimum (1 + 0 free coordinates + 6), not the masking, that was named. Now
    the comparison names its own ``masking`` and ``env_overrides`` before it makes its folder."""
    strict = {"masking.min_fraction": 1.0, "masking.primary_depth": 0.01, "masking.secondary_hops": 0}
    cfg = tiny(tmp_path, methods=methods, scenario="small_overlap_left", env_overrides=strict, budget=5)
    with pytest.raises(ConfigError, match=r"no free coordinate") as e:
        run_comparison(cfg)
    assert e.value.key == "masking", str(e.value)
    assert "masking: false" in str(e.value) and "problem." not in str(e.value)
    assert "env_overrides" in str(e.value) and not (tmp_path / "runs").exists()


def test_a_passing_run_wins_its_reference_over_a_higher_score():
    """A run whose best candidate passes the success test wins its reference over one that scores higher without
    passing, as a run's own record ranks its candidates (``Progress``): the winner used to be the highest score alone,
    so a table could name a failing method the winner beside a method that met the paper's thresholds."""
    rows = [
        {"method": "cmaes", "seed": 0, "score": 2.0, "passed": False},
        {"method": "lm", "seed": 0, "score": 1.0, "passed": True},
        {"method": "random_search", "seed": 0, "score": 0.5, "passed": True},
        {"method": "cmaes", "seed": 1, "score": 2.0, "passed": False},
        {"method": "lm", "seed": 1, "score": 1.0, "passed": False},
        {"method": "lm", "seed": 2, "score": None, "passed": False},
    ]
    w = {x["seed"]: x for x in winners(rows, [0, 1, 2])}
    assert w[0]["winner"] == ["lm"] and w[0]["score"] == 1.0
    assert w[1]["winner"] == ["cmaes"] and w[1]["score"] == 2.0
    assert w[2]["winner"] == [] and w[2]["score"] is None


@pytest.mark.parametrize(
    ("name", "override", "key"),
    [
        ("compare", "+env_overrides.max_step=0.2", "env_overrides.max_step"),
        ("compare", "+env_overrides.observation.velocity_scale=3", "env_overrides.observation.velocity_scale"),
        ("ablate", "+env_overrides.max_step=0.2", "env_overrides.max_step"),
    ],
)
def test_an_env_override_the_ppo_ones_replace_in_every_run_that_reads_it_is_refused(name, override, key):
    """``python train/compare.py +env_overrides.max_step=0.2`` ran with max_step 0.1: ``ppo.env_overrides`` (0.1)
    replaces it in the PPO runs, and no optimizer reads it; an ablation's runs are all PPO runs. The setting did
    nothing, without a word."""
    from test_train_config import composed

    from marlcrash.calibrate.ablate import load_ablation_config

    load = {"compare": load_compare_config, "ablate": load_ablation_config}[name]
    with pytest.raises(ConfigError, match=re.escape(f"ppo.env_overrides.{key.removeprefix('env_overrides.')}")) as e:
        load(composed([override], name=name), source=f"configs/train/{name}.yaml")
    assert e.value.key == key and e.value.path == f"configs/train/{name}.yaml"
    same = composed(["+env_overrides.max_step=0.1"], name=name)  # the value the PPO runs take anyway: no conflict
    load(same, source=f"configs/train/{name}.yaml")
    if name == "compare":  # a key the optimizers read too is theirs to set (the PPO runs take their own)
        load(composed(["+env_overrides.masking.min_fraction=0.2", "+ppo.env_overrides.masking.min_fraction=0.3"],
                      name=name), source="configs/train/compare.yaml")  # fmt: skip


def test_compare_md_says_no_wall_cap_where_there_is_none():
    """``max_wall_s: null`` (no cap) read 'wall cap - s per run' in compare.md; it says 'no wall cap', as ablate.md."""
    from marlcrash.calibrate.compare import CompareConfig, markdown

    assert "iteration); no wall cap\n" in markdown(CompareConfig(max_wall_s=None), [], None, "today")
    assert "iteration); wall cap 300 s per run\n" in markdown(CompareConfig(max_wall_s=300.0), [], None, "today")


def _md_row(method: str, seed: int, score: float) -> dict:
    """A finished row with every column ``compare.md`` reads."""
    r: dict = dict.fromkeys(COLUMNS)
    r.update(method=method, seed=seed, budget=1500, simulations=1500, stop="budget", area_mean=0.02, area_worst=0.03,
             dfd_mean=0.4, dfd_worst=0.7, rmse_mean=0.2, rmse_worst=0.3, score=score, initial_score=-2.0,
             passed=False, param_error=0.2, wall_time_s=10.0)  # fmt: skip
    return r


def test_a_single_run_has_no_spread_in_compare_md():
    """With one seed per method the per-method table printed '± 0' (the population std of one value), which reads as a
    measured zero spread. Below two runs it prints '± -' (no spread); two runs or more keep the population std, a
    measured 0 included."""
    from marlcrash.calibrate.compare import markdown

    rows = [_md_row("cmaes", 0, -1.0), _md_row("lm", 0, -1.0), _md_row("lm", 1, -2.0)]
    md = markdown(CompareConfig(methods=["cmaes", "lm"], seeds=[0, 1]), rows, None, "today")
    [one] = [line for line in md.splitlines() if line.startswith("| cmaes | 0/1 |")]
    assert "± 0" not in one and "| 1500 ± - | 0.02 ± - |" in one and "| -1 ± - |" in one
    [two] = [line for line in md.splitlines() if line.startswith("| lm | 0/2 |")]
    assert "| 1500 ± 0 | 0.02 ± 0 |" in two and "| -1.5 ± 0.5 |" in two
    assert "a single reference: no std (-)" in md


def test_compare_md_names_the_papers_thresholds_only_when_they_are_the_papers():
    """compare.md called the success thresholds 'the paper's best Table 3 row' whatever they were, so a comparison
    run with ``success.area=0.002`` claimed the paper's test. It says so only for the paper's thresholds (the
    :class:`SuccessConfig` defaults) and otherwise states them as configured."""
    from marlcrash.calibrate.compare import markdown
    from marlcrash.calibrate.problem import SuccessConfig

    paper = markdown(CompareConfig(), [], None, "today")
    assert (
        "success = every sensor A < 0.0015 m, DFD < 0.335 m/s, RMSE < 0.1511 m/s (the paper's best Table 3 row)"
        in paper
    )
    for th in (SuccessConfig(area=0.002), SuccessConfig(rmse=None)):
        md = markdown(CompareConfig(success=th), [], None, "today")
        assert "(the paper's best Table 3 row)" not in md
        assert f"success = every sensor {th.describe()} (as configured, not the paper's best Table 3 row)" in md


def test_a_ppo_reward_form_that_measures_differently_fails_before_any_run(short, tmp_path):
    """A ppo.env_overrides.reward form with other metrics settings (trapezoid area, a DFD time scale of 1000) was
    accepted: the PPO rows' area, DFD, RMSE and success were measured by another definition than the optimizers'
    (a DFD of 0.58 recorded where the problem measured 0.25 for the same parameters)."""
    import yaml

    from marlcrash.config import config_dir

    form = yaml.safe_load((config_dir() / "reward" / "log_ratio.yaml").read_text())
    form["metrics"] = {**form["metrics"], "area_method": "trapezoid", "dfd_time_scale": 1000.0}
    path = tmp_path / "other_metrics.yaml"
    path.write_text(yaml.safe_dump(form))
    with pytest.raises(ConfigError, match=r"measures A, DFD and RMSE differently from the shared env's") as e:
        tiny(tmp_path, **{"ppo.env_overrides": {"reward": str(path)}})
    assert e.value.key == "ppo.env_overrides.reward"
    assert not (tmp_path / "runs").exists()
