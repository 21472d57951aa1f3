"""Amortized calibration comparison: a tiny trained MAPPO policy vs optimizers from scratch on held-out twins.

Runs on the shortened copy of configs/ of test_train_marl.py (every scenario simulated for 30 ms),
with a 2-iteration training run and budgets of a few simulations.
"""

from __future__ import annotations

import copy
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from test_train_marl import tiny  # helper shared with the MARL tests (short_configs comes from conftest)

from marlcrash.calibrate.amortized import (
    COLUMNS,
    FILES,
    AmortizedConfig,
    amortized_comparison,
    held_out_config,
    load_amortized_config,
    load_policy,
    sims_to_reach,
    write_comparison,
)
from marlcrash.calibrate.evaluate import evaluation_problem
from marlcrash.calibrate.marl import build_trainer, train
from marlcrash.errors import ConfigError
from marlcrash.metrics import compute_metrics

REPO = Path(__file__).resolve().parents[1]
SEEDS = [101, 102]
ITERATIONS = 2  # policy steps: 3 simulations per reference


@pytest.fixture(scope="module")
def run_dir(short, tmp_path_factory) -> Path:
    """A 2-iteration MAPPO run (tiny networks, 4 envs, 2 steps), checkpoint only."""
    cfg = tiny(tmp_path_factory.mktemp("amortized"), iterations=2, name="src")
    return train(cfg, evaluate=False).run_dir


def small_config(run: Path, **kw) -> AmortizedConfig:
    data = {
        "run": str(run),
        "reference_seeds": SEEDS,
        "iterations": ITERATIONS,
        "budgets": {"cmaes": [1, 2], "random_search": [1], "gradient": [1]},
        "cmaes": {"popsize": 4, "sigma0": 0.2},
        "random_search": {"batch_size": 2},
        "gradient": {"batch_size": 2},
    }
    data.update(kw)
    return load_amortized_config(data)


@pytest.fixture(scope="module")
def comparison(run_dir):
    return amortized_comparison(small_config(run_dir))


def test_table_shape_and_keys(comparison, run_dir, tmp_path):
    # the policy's run was recorded when it started and nothing changed since; a changed file would be listed
    assert comparison.meta["provenance"] == {"recorded": True, "config_changes": [], "code_changes": []}
    rows = comparison.rows
    # per reference: policy best + last, cmaes 1x and 2x, random search 1x, gradient 1x
    assert len(rows) == len(SEEDS) * 6
    assert all(tuple(r) == COLUMNS for r in rows)
    assert [r["reference_seed"] for r in rows] == [s for s in SEEDS for _ in range(6)]
    methods = [r["method"] for r in rows[:6]]
    assert methods == ["policy_best", "policy_last", "cmaes", "cmaes", "random_search", "gradient"]
    assert len(comparison.aggregate) == 6
    agg = {(a["method"], a["multiplier"]): a for a in comparison.aggregate}
    for (method, mult), a in agg.items():
        group = [r for r in rows if r["method"] == method and r["multiplier"] == mult]
        scores = np.array([r["score"] for r in group])
        assert a["references"] == len(SEEDS)
        assert a["score_mean"] == pytest.approx(scores.mean()) and a["score_std"] == pytest.approx(scores.std())
    for r in rows:
        assert all(np.isfinite(r[k]) for k in ("area", "dfd", "rmse", "score", "param_error"))
        assert r["score"] >= r["initial_score"] - 1e-12 or r["method"] == "policy_last"
    paths = write_comparison(comparison, tmp_path, command="python train/amortized.py run=x")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(FILES)  # no temporary file left behind
    back = list(csv.DictReader(paths["amortized.csv"].open()))
    assert len(back) == len(rows) and tuple(back[0]) == COLUMNS
    assert float(back[2]["score"]) == pytest.approx(rows[2]["score"])
    md = paths["amortized.md"].read_text()
    assert "## Aggregate over 2 references" in md and "| 101 | cmaes 2x |" in md and "python train/amortized.py" in md
    data = json.loads(paths["amortized.json"].read_text())
    assert data["meta"]["policy_simulations"] == ITERATIONS + 1 and len(data["rows"]) == len(rows)
    with pytest.raises(ConfigError, match=r"key 'out_dir': .* already holds a comparison"):  # was replaced silently
        write_comparison(comparison, tmp_path)
    assert write_comparison(comparison, tmp_path, replace=True) == paths
    made = write_comparison(comparison, tmp_path / "new" / "cmp")  # a missing folder is made
    assert json.loads(made["amortized.json"].read_text())["rows"] == data["rows"]
    (tmp_path / "afile").write_text("")
    with pytest.raises(ConfigError, match=r"key 'out_dir'.*afile is a file"):
        write_comparison(comparison, tmp_path / "afile")


def test_a_diverged_run_is_written_as_standard_json(comparison, tmp_path):
    """amortized.json held ``-Infinity`` (the best score of an optimizer whose every candidate diverged) and ``NaN``
    (its metrics, their means): jq and JavaScript refuse the whole file. They are null there, empty in the CSV and
    ``-`` in the tables."""
    import re

    from test_outputs import _strict

    from marlcrash.calibrate.amortized import Comparison, aggregate

    rows = copy.deepcopy(comparison.rows)
    i = next(i for i, r in enumerate(rows) if r["method"] == "random_search")
    rows[i].update(score=float("-inf"), area=float("nan"))
    paths = write_comparison(Comparison(rows, aggregate(rows), copy.deepcopy(comparison.meta)), tmp_path)
    data = _strict(paths["amortized.json"].read_text())
    assert data["rows"][i]["score"] is None and data["rows"][i]["area"] is None
    assert data["rows"][i - 1]["score"] == rows[i - 1]["score"]
    [a] = [a for a in data["aggregate"] if a["method"] == "random_search"]
    assert a["score_mean"] is None and a["area_mean"] is None and a["dfd_mean"] is not None
    back = list(csv.DictReader(paths["amortized.csv"].open()))
    assert back[i]["score"] == back[i]["area"] == "" and back[i]["dfd"] != ""
    md = paths["amortized.md"].read_text()
    assert not re.search(r"\b(inf|nan)\b", md, re.IGNORECASE), md
    seed = rows[i]["reference_seed"]
    line = next(ln for ln in md.splitlines() if ln.startswith(f"| {seed} | random_search 1x |"))
    assert line.split(" | ")[3] == "-" and line.split(" | ")[6] == "-"  # area, score


def test_budgets_are_respected(comparison):
    nominal = ITERATIONS + 1
    for r in comparison.rows:
        if r["method"].startswith("policy"):
            assert r["simulations"] == nominal  # no early termination on a 30 ms twin with a 2-iteration policy
            assert r["sims_to_policy"] is None
        else:
            assert r["budget"] == round(r["multiplier"] * nominal)
            assert r["simulations"] == r["budget"]  # every optimizer spends exactly its budget
            reached = r["sims_to_policy"]
            best = next(p for p in comparison.rows if p["method"] == "policy_best" and
                        p["reference_seed"] == r["reference_seed"])  # fmt: skip
            if r["score"] >= best["score"]:
                assert reached is not None and 1 <= reached <= r["simulations"]
            else:
                assert reached is None


def test_sims_to_reach_reads_the_best_so_far_column():
    h = np.array([[1, -1.0, -1.0], [5, -0.5, -0.5], [9, -0.5, -0.7], [13, 0.2, 0.2]])
    assert sims_to_reach(h, -0.5) == 5
    assert sims_to_reach(h, 0.0) == 13
    assert sims_to_reach(h, 0.3) is None
    assert sims_to_reach(h, -2.0) == 1


def test_policy_rows_match_an_independent_resimulation(comparison, run_dir):
    """Re-simulate the policy's selected parameters and recompute the metrics with the torch reference engine."""
    policy, cfg, _ = load_policy(run_dir)
    from marlcrash.calibrate.evaluate import evaluate_policy

    seed = SEEDS[0]
    hc = held_out_config(cfg, seed, "full_width_40", ITERATIONS)
    result = evaluate_policy(policy, hc)
    problem = evaluation_problem(hc)
    row = next(r for r in comparison.rows if r["method"] == "policy_best" and r["reference_seed"] == seed)
    p = result.params[row["iteration"]][None]
    with torch.no_grad():
        res = problem.sim.run(p, speed=problem.speed, overlap=problem.overlap, side=problem.side,
                              duration=problem.sim_duration, sensors=problem.sensors, record_cells="none")  # fmt: skip
    m = compute_metrics(problem.compared(res.velocity), problem.ref_velocity, dt=problem.dt,
                        config=problem.fit.cfg.metrics, backend="torch")  # fmt: skip
    assert float(m.area.mean()) == pytest.approx(row["area"], rel=1e-6, abs=1e-12)
    assert float(m.rmse.mean()) == pytest.approx(row["rmse"], rel=1e-6, abs=1e-12)
    assert float(m.dfd.mean()) == pytest.approx(row["dfd"], rel=1e-6, abs=1e-12)
    assert float(problem.score(m)[0]) == pytest.approx(row["score"], rel=1e-6, abs=1e-9)


def test_a_run_whose_checkpoint_was_written_under_other_settings_is_refused(run_dir, tmp_path):
    """A run folder whose ``checkpoint.pt`` was written under other settings than its ``config.yaml`` (another run's
    file of the same network shapes copied in): ``load_policy`` took the weights and the folder's settings, and the
    amortized comparison reported that policy as the run's. It is refused as a resume refuses it, naming the setting."""
    import shutil

    from marlcrash.calibrate.checkpoint import load_checkpoint, save_checkpoint

    copied = tmp_path / "copied"
    shutil.copytree(run_dir, copied)
    state = load_checkpoint(copied / "checkpoint.pt")
    state["config"]["algorithm"]["lr"] = 0.5
    save_checkpoint(copied / "checkpoint.pt", state)
    with pytest.raises(ConfigError, match=r"checkpoint\.pt was written by a run with other settings: algorithm\.lr "
                       r"is 0\.5 in it, 0\.001 in .*copied/config\.yaml") as e:  # fmt: skip
        load_policy(copied)
    assert e.value.key == "run"


def test_held_out_references_differ_from_the_evaluation_reference(run_dir):
    _, cfg, _ = load_policy(run_dir)
    assert cfg.eval.reference_seed == 0 and cfg.seed == 0
    refs = {s: evaluation_problem(held_out_config(cfg, s, "full_width_40", 1)) for s in [0, *SEEDS]}
    for s in SEEDS:
        assert not torch.allclose(refs[s].ref_velocity, refs[0].ref_velocity, atol=1e-3)
        assert not torch.allclose(refs[s].true_params, refs[0].true_params)
    assert not torch.allclose(refs[SEEDS[0]].ref_velocity, refs[SEEDS[1]].ref_velocity, atol=1e-3)
    for bad in (0, cfg.seed):  # the evaluation seed, the training seed
        with pytest.raises(ConfigError, match=r"reference_seeds\[1\]"):
            amortized_comparison(small_config(run_dir, reference_seeds=[101, bad]))
    # a run trained on one pinned reference (reference.pin_seed): that seed is the one reference it has seen
    policy, _, _ = load_policy(run_dir)
    # the training seed apart from the evaluation seed (above both are 0): its generator's first draw is the reference
    # of held-out seed 7, which training row 0 calibrated
    seeded = copy.deepcopy(cfg)
    seeded.seed = 7
    trainer = build_trainer(seeded, run_dir.parent / "seeded")  # seeds its env as a training run does
    trainer.env.reset()
    assert torch.equal(trainer.env.core.true_params[0], evaluation_problem(held_out_config(seeded, 7, "full_width_40",
                                                                                          1)).true_params)  # fmt: skip
    with pytest.raises(ConfigError, match=r"reference_seeds\[1\]': seed 7 is the run's training seed"):
        amortized_comparison(small_config(run_dir, reference_seeds=[101, 7]), policy=policy, train_config=seeded)
    pinned = copy.deepcopy(cfg)
    pinned.env_overrides = {**pinned.env_overrides, "reference.pin_seed": 102}
    with pytest.raises(ConfigError, match=r"reference_seeds\[1\]': seed 102 is the reference the run trained on"):
        amortized_comparison(small_config(run_dir, reference_seeds=[101, 102]), policy=policy, train_config=pinned)


def test_an_adjoint_the_run_cannot_use_is_refused_before_any_simulation(run_dir):
    """A run trained on float32 simulations (env sim_dtype, 1.9x faster): the adjoint's reverse pass is float64 only.

    The gradient runs failed with a ModelError after the policy, CMA-ES and random search had run on the first
    reference, and the rows were lost.
    """
    policy, cfg, _ = load_policy(run_dir)
    f32 = copy.deepcopy(cfg)
    f32.env_overrides = {**f32.env_overrides, "sim_dtype": "float32"}
    said: list[str] = []
    with pytest.raises(ConfigError, match=r"key 'gradient\.backend'.*needs dtype float64"):
        amortized_comparison(small_config(run_dir), policy=policy, train_config=f32, progress=said.append)
    assert said == []  # refused before the policy ran
    # the torch backend differentiates float32 simulations, and the other optimizers need no gradient: no refusal
    for kw in ({"gradient": {"batch_size": 2, "backend": "torch"}}, {"budgets": {"cmaes": [1]}}):
        with pytest.raises(ConfigError, match=r"reference_seeds\[0\]"):  # the next check, still before any work
            amortized_comparison(small_config(run_dir, reference_seeds=[0], **kw), policy=policy, train_config=f32)


def test_a_failing_optimizer_keeps_the_pieces_that_finished(run_dir, tmp_path, monkeypatch):
    """The comparison hands its rows so far to ``partial`` after every finished piece, marked incomplete; the
    tables used to be written only at the end, so an error in the last optimizer run lost every finished row."""
    import marlcrash.calibrate.amortized as amortized

    name, _ = amortized.BASELINES["random_search"]

    def broken(*args, **kwargs):
        raise RuntimeError("the optimizer failed")

    monkeypatch.setitem(amortized.BASELINES, "random_search", (name, broken))
    config = small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"cmaes": [1], "random_search": [1]})
    seen = []

    def keep(partial):
        seen.append(len(partial.rows))
        write_comparison(partial, tmp_path, replace=True)

    with pytest.raises(RuntimeError, match="the optimizer failed"):
        amortized_comparison(config, partial=keep)
    assert seen == [2, 3]  # the policy's two rows (best, last), then CMA-ES
    record = json.loads((tmp_path / "amortized.json").read_text())
    assert record["meta"]["complete"] is False and len(record["rows"]) == 3
    assert [r["method"] for r in record["rows"]][-1] == "cmaes"
    assert "**incomplete**" in (tmp_path / "amortized.md").read_text()


def test_an_incomplete_table_counts_over_the_references_it_has(comparison):
    """The tables written after every finished piece counted passes, reached and beaten references out of every
    reference asked for: with one of two references finished, "passed 0/2", "reached policy 1/2" as if the second had
    been measured and failed. They count out of the references a row has, and say how many that is."""
    import marlcrash.calibrate.amortized as amortized

    rows = [r for r in comparison.rows if r["reference_seed"] == SEEDS[0]]
    partial = amortized.Comparison(rows, amortized.aggregate(rows), dict(comparison.meta, complete=False))
    text = amortized.markdown(partial)
    assert "## Aggregate over 1 of 2 references" in text
    table = text.split("## Per reference")[0]
    lines = [ln for ln in table.splitlines() if ln.startswith("| cmaes") or ln.startswith("| random_search")]
    assert lines and all("/2" not in ln and "/1 |" in ln for ln in lines)
    assert "## Aggregate over 2 references" in amortized.markdown(comparison)  # complete: as before


def test_the_policy_compared_is_the_one_whose_checkpoint_is_recorded(run_dir, tmp_path, monkeypatch):
    """A comparison of a run that still trains: its next checkpoint.pt replaced the one just read (building the
    policy's env takes seconds), and meta.checkpoint_sha256, taken after the policy was read, named the new file
    while the rows were of the old policy; a resume after the run stopped on that checkpoint kept those rows as its
    own. The checkpoint is read again until it stays the same while read."""
    import hashlib
    import shutil

    import marlcrash.calibrate.amortized as amortized
    from marlcrash.calibrate.checkpoint import load_checkpoint, save_checkpoint

    run = Path(shutil.copytree(run_dir, tmp_path / "run"))
    ckpt = run / "checkpoint.pt"
    later = load_checkpoint(ckpt)  # the run's next checkpoint: other weights
    later["policy"] = {k: v + 0.01 if v.is_floating_point() else v for k, v in later["policy"].items()}
    later["iteration"] += 1
    real_load, real_evaluate = amortized.load_policy, amortized.evaluate_policy
    used = []

    def training_goes_on(path):
        out = real_load(path)
        if not used:
            save_checkpoint(ckpt, later)  # replaced while the first policy was read
            used.append(None)
        return out

    def spy(policy, cfg):
        used.append({k: v.clone() for k, v in policy.state_dict().items()})
        return real_evaluate(policy, cfg)

    monkeypatch.setattr(amortized, "load_policy", training_goes_on)
    monkeypatch.setattr(amortized, "evaluate_policy", spy)
    comp = amortized_comparison(small_config(run, reference_seeds=[SEEDS[0]], budgets={"random_search": [1]}))
    assert comp.meta["checkpoint_sha256"] == hashlib.sha256(ckpt.read_bytes()).hexdigest()
    for k, v in later["policy"].items():  # the rows are of the policy recorded
        assert torch.equal(used[-1][k], v), k


def _strip(rows):
    return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rows]


def test_an_interrupted_comparison_resumes_to_the_uninterrupted_rows(comparison, run_dir, tmp_path, monkeypatch):
    """There was no resume: a comparison killed or failed late had to start again from nothing. ``done=`` (the
    script's ``resume=true``) keeps the finished pieces of the folder's ``amortized.json`` and runs only the
    missing ones; every piece is a fresh, seeded run, so the rows equal the uninterrupted comparison's."""
    import marlcrash.calibrate.amortized as amortized

    config = small_config(run_dir, reference_seeds=SEEDS, budgets={"cmaes": [1], "random_search": [1]})
    name, search = amortized.BASELINES["random_search"]

    def broken(*args, **kwargs):
        raise RuntimeError("killed")

    monkeypatch.setitem(amortized.BASELINES, "random_search", (name, broken))
    with pytest.raises(RuntimeError, match="killed"):
        amortized_comparison(config, partial=lambda c: write_comparison(c, tmp_path, replace=True))
    done = amortized.read_comparison(tmp_path)
    assert done.meta["complete"] is False and [r["method"] for r in done.rows] == ["policy_best", "policy_last",
                                                                                     "cmaes"]  # fmt: skip
    ran = []

    def counted(*args, **kwargs):
        ran.append("random_search")
        return search(*args, **kwargs)

    monkeypatch.setitem(amortized.BASELINES, "random_search", (name, counted))
    resumed = amortized_comparison(config, done=done)
    assert resumed.meta["complete"] is True
    assert ran == ["random_search"] * 2  # the finished pieces (the policy and CMA-ES on SEEDS[0]) did not run again
    expected = [r for r in comparison.rows if r["method"] in ("policy_best", "policy_last", "random_search")
                or (r["method"] == "cmaes" and r["multiplier"] == 1)]  # fmt: skip
    assert _strip(resumed.rows) == _strip(expected)
    assert resumed.aggregate == amortized.aggregate(resumed.rows)


def test_a_resume_with_other_settings_or_no_record_is_refused_naming_them(run_dir, tmp_path):
    import marlcrash.calibrate.amortized as amortized

    with pytest.raises(ConfigError, match=r"key 'resume': no comparison to continue in .* \(no amortized.json\)"):
        amortized.read_comparison(tmp_path)
    config = small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"cmaes": [1]})
    write_comparison(amortized_comparison(config), tmp_path)
    done = amortized.read_comparison(tmp_path)
    again = amortized_comparison(config, done=done)  # nothing left to run: the same rows
    assert again.rows == done.rows
    for change, said in (({"iterations": ITERATIONS + 1}, r"iterations: 2 then, 3 now"),
                         ({"cmaes": {"popsize": 6, "sigma0": 0.2}}, r"optimizers\.cmaes: .*'popsize': 4.* then"),
                         ({"target": "last"}, r"target: 'best' then, 'last' now")):  # fmt: skip
        with pytest.raises(ConfigError, match=r"key 'resume': cannot continue the comparison: .*" + said):
            amortized_comparison(small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"cmaes": [1]}, **change),
                                 done=done)  # fmt: skip
    other = dict(done.meta, checkpoint_sha256="0" * 64)
    with pytest.raises(ConfigError, match=r"checkpoint_sha256"):
        amortized_comparison(config, done=amortized.Comparison(done.rows, done.aggregate, other))
    (tmp_path / "amortized.json").write_text('{"rows": [{"a": 1}], "meta": {}}')
    with pytest.raises(ConfigError, match=r"key 'resume': .*amortized.json is not a comparison this tool wrote"):
        amortized.read_comparison(tmp_path)


def test_deterministic_and_independent_of_the_other_runs(comparison, run_dir):
    """One seed and one optimizer alone give exactly the rows of the full comparison (fresh, seeded runs)."""
    again = amortized_comparison(small_config(run_dir, reference_seeds=[SEEDS[1]], budgets={"cmaes": [1, 2]}))

    expected = [r for r in comparison.rows if r["reference_seed"] == SEEDS[1] and r["method"] not in
                ("random_search", "gradient")]  # fmt: skip
    assert len(again.rows) == 4
    assert _strip(again.rows) == _strip(expected)


def test_bad_configs_name_the_key(run_dir, tmp_path):
    with pytest.raises(ConfigError, match="key 'run'"):
        amortized_comparison(small_config(tmp_path / "no_such_run"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="key 'run'"):
        amortized_comparison(small_config(tmp_path / "empty"))
    with pytest.raises(ConfigError, match="key 'run'"):
        amortized_comparison(load_amortized_config({"run": None}))
    for mults, key in (([1, 0], r"budgets\.cmaes\[1\]"), ([-2.0], r"budgets\.cmaes\[0\]")):
        with pytest.raises(ConfigError, match=key):
            small_config(run_dir, budgets={"cmaes": mults})
    with pytest.raises(ConfigError, match=r"budgets\.cmaes\[2\]': expected distinct budget multiples"):
        small_config(run_dir, budgets={"cmaes": [1, 2, 1.0]})  # aggregated as one group: "reached 4/2" in the table
    with pytest.raises(ConfigError, match=r"budgets\.lbfgs.*unknown optimizer"):
        small_config(run_dir, budgets={"lbfgs": [1]})
    with pytest.raises(ConfigError, match=r"budgets\.lm.*unknown optimizer"):  # a baseline without settings here
        small_config(run_dir, budgets={"lm": [1]})
    (tmp_path / "afile").write_text("")
    with pytest.raises(ConfigError, match=r"key 'out_dir'.*afile is a file"):  # at once, not after the work
        small_config(run_dir, out_dir=str(tmp_path / "afile" / "cmp"))
    assert small_config(run_dir, out_dir=str(tmp_path / "missing")).out_dir == str(tmp_path / "missing")  # made later
    with pytest.raises(ConfigError, match="iterations"):
        small_config(run_dir, iterations=0)
    with pytest.raises(ConfigError, match=r"2\*\*63 - 1 \(MAX_STEPS\)") as e:  # was refused as budgets.<optimizer>[0]
        small_config(run_dir, iterations=2**63)
    assert e.value.key == "iterations"
    with pytest.raises(ConfigError, match=r"key 'scenario': unknown scenario 'ful_width_40'"):  # not default.yaml's
        small_config(run_dir, scenario="ful_width_40")
    with pytest.raises(ConfigError, match="reference_seeds"):
        small_config(run_dir, reference_seeds=[101, 101])
    with pytest.raises(ConfigError, match=r"cmaes\.popsize"):
        small_config(run_dir, cmaes={"popsize": 1})
    with pytest.raises(ConfigError, match="key 'speed'"):
        small_config(run_dir, speed=3)
    with pytest.raises(ConfigError, match=r"key 'seed': expected a seed in \[0, 2\*\*64 - 1\], got -1"):  # late
        small_config(run_dir, seed=-1)
    # torch's generators (gradient descent) refused it only after the policy had run
    with pytest.raises(
        ConfigError, match=r"key 'seed': expected a seed in \[0, 2\*\*64 - 1\], got 18446744073709551616"
    ):
        small_config(run_dir, seed=2**64)
    with pytest.raises(ConfigError, match=r"key 'reference_seeds\[1\]'"):
        small_config(run_dir, reference_seeds=[101, 2**64])


def test_a_budget_multiple_beyond_an_exact_simulation_count_is_refused_before_any_simulation(run_dir, monkeypatch):
    """``budgets.cmaes=[1e308]`` passed validation; ``round(1e308 * 13)`` then raised "OverflowError: cannot convert
    float infinity to integer" after the policy had run. A budget is counted in float64 (the history's simulations
    column), exact only up to 2**53: a multiple above that is refused naming it, before any simulation -- also when
    the policy's simulation count comes from the run (``iterations: null``)."""
    import marlcrash.calibrate.amortized as amortized

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated before the budgets were checked")

    monkeypatch.setattr(amortized, "evaluate_policy", no_simulation)
    with pytest.raises(ConfigError, match=r"key 'budgets\.cmaes\[1\]': .*1e\+308 x 3 simulations.*2\*\*53"):
        small_config(run_dir, budgets={"cmaes": [1, 1e308]})  # iterations 2: 3 simulations, known at once
    cfg = small_config(run_dir, iterations=None, budgets={"random_search": [4e15]})  # the run's eval.iterations
    with pytest.raises(ConfigError, match=r"key 'budgets\.random_search\[0\]': .*4e\+15 x 3 simulations"):
        amortized_comparison(cfg)
    assert small_config(run_dir, budgets={"cmaes": [1e15]}).budget(1e15, 3) == 3 * 10**15  # exact: accepted


def test_budget_multiples_that_round_to_one_budget_are_refused_naming_the_key(run_dir, monkeypatch):
    """Distinct multiples can round to one simulation count (``[1, 1.1]`` x 3 simulations: 3 and 3; ``[0.1, 0.2]``:
    1 and 1): the optimizer ran the same budget twice and the tables showed it as two. Refused naming the key, both
    multiples and the budget, before any simulation -- also when the count comes from the run (``iterations: null``)."""
    import marlcrash.calibrate.amortized as amortized

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated before the budgets were checked")

    monkeypatch.setattr(amortized, "evaluate_policy", no_simulation)
    with pytest.raises(ConfigError, match=r"key 'budgets\.cmaes\[1\]': .*1\.1 x 3 simulations.*budget of 3 "
                                          r"simulations.*budgets\.cmaes\[0\] \(1 x 3\)"):  # fmt: skip
        small_config(run_dir, budgets={"cmaes": [1, 1.1]})
    with pytest.raises(ConfigError, match=r"key 'budgets\.gradient\[2\]'.*budget of 1 simulations"):
        small_config(run_dir, budgets={"gradient": [1, 0.1, 0.2]})
    cfg = small_config(run_dir, iterations=None, budgets={"random_search": [1, 1.01]})  # the run's eval.iterations
    with pytest.raises(ConfigError, match=r"key 'budgets\.random_search\[1\]'"):
        amortized_comparison(cfg)
    assert small_config(run_dir, budgets={"cmaes": [1, 1.5], "gradient": [1]}).budgets["cmaes"] == [1, 1.5]  # 3, 4


@pytest.mark.parametrize("name", ["cmaes", "random_search", "gradient"])
def test_an_empty_budget_list_is_refused_naming_the_key(name, tmp_path):
    """``budgets.<optimizer>=[]`` was accepted and ran nothing for that optimizer, while its settings were recorded
    in the comparison's meta as if it took part (and ``gradient: []`` still ran the adjoint check); leaving the key
    out (``~budgets.<optimizer>``) is the documented way to skip one."""
    budgets = {"cmaes": [1, 2], "random_search": [1], "gradient": [1], name: []}
    with pytest.raises(ConfigError, match=rf"key 'budgets\.{name}': expected at least one budget multiple.*"
                                          rf"~budgets\.{name}"):  # fmt: skip
        small_config(tmp_path, budgets=budgets)
    del budgets[name]
    assert name not in small_config(tmp_path, budgets=budgets).budgets  # left out: skipped


def test_no_optimizer_at_all_is_refused_naming_budgets(tmp_path):
    """``budgets: {}`` (every optimizer left out, e.g. ``~budgets.cmaes ~budgets.random_search ~budgets.gradient``)
    was accepted and gave a table of the policy alone, headed "policy vs optimizers", with nothing to compare it
    with, where an empty list of one optimizer and an empty list of reference seeds are refused. Refused before
    any work, saying how to keep the policy's rows (one small budget) or evaluate it alone (train/evaluate.py)."""
    with pytest.raises(ConfigError, match=r"key 'budgets': expected at least one optimizer.*"
                                          r"budgets\.random_search=\[1\].*train/evaluate\.py") as e:  # fmt: skip
        small_config(tmp_path, budgets={})
    assert e.value.key == "budgets"
    with pytest.raises(ConfigError, match=r"key 'budgets'"):  # a config made in Python is refused the same way
        AmortizedConfig(run=str(tmp_path), budgets={}).validate()
    assert small_config(tmp_path, budgets={"random_search": [1]}).budgets == {"random_search": [1]}


def test_a_config_made_in_python_is_checked_as_a_files_values(tmp_path, monkeypatch):
    """``amortized_comparison`` took an :class:`AmortizedConfig` made in Python unchecked: ``target="lats"`` compared
    the optimizers with the policy's last iterate without a word, repeated reference seeds gave repeated rows
    (aggregated as "passed 2/1"), an unknown scenario failed after the policy was read. Refused naming the key, before
    any work, as a config file's values are."""
    import marlcrash.calibrate.amortized as amortized

    def never(*args, **kwargs):
        raise AssertionError("nothing is read or simulated for a refused config")

    monkeypatch.setattr(amortized, "load_policy", never)
    monkeypatch.setattr(amortized, "evaluate_policy", never)
    for kw, key in (({"target": "lats"}, "target"), ({"reference_seeds": [101, 101]}, "reference_seeds"),
                    ({"scenario": "ful_width_40"}, "scenario"), ({"budgets": {"cmaes": [0.0]}}, r"budgets\.cmaes\[0\]"),
                    ({"cmaes": amortized.CMAESConfig(popsize=1)}, r"cmaes\.popsize")):  # fmt: skip
        with pytest.raises(ConfigError, match=rf"key '{key}'"):
            amortized_comparison(AmortizedConfig(run=str(tmp_path), **kw))


def test_the_yaml_config_loads_through_hydra():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(REPO / "configs" / "train"), version_base=None):
        cfg = compose("amortized", overrides=["run=runs/mappo/x"])
    from omegaconf import OmegaConf

    config = load_amortized_config(OmegaConf.to_container(cfg, resolve=True), source="amortized.yaml")
    assert config.run == "runs/mappo/x" and config.scenario == "full_width_40"
    assert set(config.budgets) <= {"cmaes", "random_search", "gradient"}
    assert config.cmaes.popsize >= 2 and config.gradient.batch_size >= 1
    assert not {0} & set(config.reference_seeds)  # held out from the default evaluation seed


def test_a_single_reference_has_no_spread_in_amortized_md(comparison, tmp_path):
    """One held-out reference printed ``score ± 0`` (the population std of one value), read as a measured zero
    spread; compare.md and ablate.md print ``± -`` there, and so does amortized.md now (the JSON's std is null)."""
    from marlcrash.calibrate.amortized import Comparison, aggregate

    one = [r for r in copy.deepcopy(comparison.rows) if r["reference_seed"] == SEEDS[0]]
    agg = aggregate(one)
    assert all(a[f"{k}_std"] is None for a in agg for k in ("score", "area", "simulations"))
    assert all(a["score_mean"] is not None for a in agg)
    md = write_comparison(Comparison(one, agg, copy.deepcopy(comparison.meta)), tmp_path)["amortized.md"].read_text()
    assert " ± -" in md and " ± 0 " not in md and " ± 0|" not in md
    two = aggregate(copy.deepcopy(comparison.rows))  # SEEDS has two references at least: a spread again
    assert len(SEEDS) >= 2 and all(a["score_std"] is not None for a in two)


def test_the_yaml_config_says_what_the_script_prints_on_stdout():
    """The file said "stdout is the JSON"; the script prints its progress lines and the Markdown tables, and only
    its last line is JSON (the files written), as :func:`test_script_smoke` checks."""
    text = (REPO / "configs" / "train" / "amortized.yaml").read_text()
    comment = next(line for line in text.splitlines() if "hydra/job_logging" in line).split("#", 1)[1]
    assert "stdout is the JSON" not in comment
    assert all(w in comment for w in ("stdout", "progress", "Markdown", "last line", "JSON")), comment


@pytest.mark.slow
def test_script_smoke(run_dir, short, tmp_path):
    env = {**os.environ, "MARLCRASH_CONFIGS": str(short)}
    cmd = [sys.executable, str(REPO / "train" / "amortized.py"), f"run={run_dir}", "reference_seeds=[101]",
           "iterations=1", "budgets={cmaes: [1]}", "cmaes.popsize=2", f"out_dir={tmp_path}"]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(FILES)
    # what configs/train/amortized.yaml says stdout holds: progress lines, the Markdown tables, the files as JSON last
    *head, last = out.stdout.strip().splitlines()
    assert json.loads(last) == {name: str(tmp_path / name) for name in FILES}
    assert "seed 101" in head[0] and (tmp_path / "amortized.md").read_text().strip() in "\n".join(head)
    bad = subprocess.run([*cmd[:2], f"run={tmp_path / 'nope'}"], capture_output=True, text=True, env=env, cwd=REPO,
                         timeout=300)  # fmt: skip
    assert bad.returncode == 2 and "key 'run'" in bad.stderr
    again = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, timeout=300)  # refused up front
    assert again.returncode == 2 and "key 'out_dir'" in again.stderr and "already holds a comparison" in again.stderr
    assert "seed 101" not in again.stdout  # nothing was run
    resumed = subprocess.run([*cmd, "resume=true"], capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert "seed 101: kept from the earlier comparison" in resumed.stdout  # finished: nothing runs again
    assert json.loads((tmp_path / "amortized.json").read_text())["meta"]["complete"] is True


def test_ctrl_c_in_the_script_says_the_finished_pieces_are_kept_and_how_to_resume(run_dir, short, tmp_path):
    """Ctrl-C in train/amortized.py printed a traceback; it prints ``interrupted`` and which folder keeps the
    finished pieces with the ``resume=true`` that continues them, and ends by SIGINT; the resume finishes it."""
    import signal

    first_piece_then_ctrl_c = (
        "import runpy, sys\n"
        "import marlcrash.calibrate.amortized as amortized\n"
        "real = amortized.amortized_comparison\n"
        "def interrupted(config, progress, partial, done):\n"
        "    def keep_then_stop(c):\n"
        "        partial(c)\n"
        "        raise KeyboardInterrupt\n"
        "    return real(config, progress=progress, partial=keep_then_stop, done=done)\n"
        "amortized.amortized_comparison = interrupted\n"
        f"sys.argv = [{str(REPO / 'train' / 'amortized.py')!r}, *sys.argv[1:]]\n"
        "runpy.run_path(sys.argv[0], run_name='__main__')\n"
    )
    args = [f"run={run_dir}", "reference_seeds=[101,102]", "iterations=1", "budgets={cmaes: [1]}", "cmaes.popsize=2",
            f"out_dir={tmp_path}"]  # fmt: skip
    env = {**os.environ, "MARLCRASH_CONFIGS": str(short)}
    p = subprocess.run([sys.executable, "-c", first_piece_then_ctrl_c, *args], capture_output=True, text=True, env=env,
                       cwd=REPO, timeout=300)  # fmt: skip
    note = f"{tmp_path} keeps the finished pieces (amortized.json); the same command with resume=true continues it"
    assert p.returncode == -signal.SIGINT and "Traceback" not in p.stderr, p.stderr[-3000:]
    assert p.stderr.endswith(f"interrupted\n{note}\n"), p.stderr[-3000:]
    assert json.loads((tmp_path / "amortized.json").read_text())["meta"]["complete"] is False
    cmd = [sys.executable, str(REPO / "train" / "amortized.py"), *args, "resume=true"]
    resumed = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads((tmp_path / "amortized.json").read_text())["meta"]["complete"] is True


def test_the_documented_budget_overrides_compose():
    """train/amortized.py's docstring: change one optimizer's budgets, drop another (Hydra merges mappings)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from marlcrash.config import config_dir

    with initialize_config_dir(str(config_dir() / "train"), version_base=None):
        cfg = compose("amortized", overrides=["run=x", "budgets.cmaes=[1,10,100]", "~budgets.gradient"])
    budgets = OmegaConf.to_container(cfg)["budgets"]
    assert budgets["cmaes"] == [1, 10, 100] and "gradient" not in budgets and "random_search" in budgets


def test_a_median_of_counts_keeps_its_half():
    from marlcrash.calibrate.amortized import _fmt

    # ".0f" rounds halves to even: a median of 2 and 3 simulations read "2" in the tables, 2.5 in the JSON
    assert [_fmt(v, ".0f") for v in (2.5, 3.5, 1500.0, None)] == ["2.5", "3.5", "1500", "-"]


def test_cmaes_rows_count_their_generations_and_the_tables_mark_those_without_one(comparison, run_dir, tmp_path):
    """``CalibrationResult.generations`` (0: a budget below 1 + popsize, a random sample around the start) reached no
    table: "cmaes 1x" read as CMA-ES. The rows hold it (JSON, CSV; ``None`` for other methods), the Markdown marks
    the CMA-ES rows without a generation, and a comparison written before the column resumes with it filled in."""
    import marlcrash.calibrate.amortized as amortized

    popsize = comparison.meta["optimizers"]["cmaes"]["popsize"]  # 4: 1x = 3 simulations, 2x = 6
    gens = {(r["method"], r["multiplier"]): r["generations"] for r in comparison.rows}
    assert gens == {("policy_best", None): None, ("policy_last", None): None, ("cmaes", 1): 0, ("cmaes", 2): 1,
                    ("random_search", 1): None, ("gradient", 1): None}  # fmt: skip
    assert all(r["generations"] == (r["simulations"] - 1) // popsize for r in comparison.rows if r["method"] == "cmaes")
    paths = write_comparison(comparison, tmp_path / "new")
    back = list(csv.DictReader(paths["amortized.csv"].open()))
    assert [b["generations"] for b in back[:6]] == ["", "", "0", "1", "", ""]
    assert [r["generations"] for r in json.loads(paths["amortized.json"].read_text())["rows"]][:4] == [None, None, 0, 1]
    md = paths["amortized.md"].read_text()
    assert "| 101 | cmaes 1x † |" in md and "| 101 | cmaes 2x |" in md and "| cmaes 1x † |" in md
    assert f"† CMA-ES completed no generation: a budget below 1 + cmaes.popsize ({1 + popsize})" in md
    assert md.count("† CMA-ES completed no generation") == 1  # once, under the first table that uses the mark
    assert md.index("† CMA-ES completed no generation") < md.index("## Per reference")

    old = tmp_path / "old"  # amortized.json of before the column: resumed, its generations filled in
    paths = write_comparison(comparison, old)
    record = json.loads(paths["amortized.json"].read_text())
    for r in record["rows"]:
        del r["generations"]
    paths["amortized.json"].write_text(json.dumps(record))
    done = amortized.read_comparison(old)
    assert done.rows == json.loads(json.dumps(comparison.rows)) and all(tuple(r) == COLUMNS for r in done.rows)
    again = amortized_comparison(small_config(run_dir), done=done)  # nothing left to run
    assert again.rows == done.rows


def test_the_script_without_a_run_says_so_even_when_resuming(tmp_path):
    """``resume=true`` without ``run=`` looked for a comparison in the launch folder and failed with "key 'resume': no
    comparison to continue in ." (or, where the launch folder held one, went on to the missing run only then); without
    ``resume`` a launch folder holding an ``amortized.json`` was refused as "key 'out_dir'". The missing run is said."""
    (tmp_path / "amortized.json").write_text("{}")  # an earlier comparison in the launch folder
    for extra in (["resume=true"], []):
        out = subprocess.run([sys.executable, str(REPO / "train" / "amortized.py"), *extra], capture_output=True,
                             text=True, cwd=tmp_path, timeout=300)  # fmt: skip
        assert out.returncode == 2 and "key 'run'" in out.stderr and "run=runs/mappo/<name>" in out.stderr, extra
        assert "Traceback" not in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["amortized.json"]


def test_an_empty_run_or_out_dir_is_refused_naming_the_key(run_dir, tmp_path):
    """``run=''`` (or ``run=$RUN`` with the variable unset) was the launch folder: "found none in ." there, and the
    policy of whatever run the script was started in otherwise; ``out_dir=''`` wrote the tables into the launch
    folder. Both are refused naming the key, also for a config made in Python."""
    for key in ("run", "out_dir"):
        with pytest.raises(ConfigError, match=rf"key '{key}': expected a folder.*got an empty one") as e:
            load_amortized_config({"run": str(run_dir), key: ""})
        assert e.value.key == key
        with pytest.raises(ConfigError, match=rf"key '{key}'"):
            AmortizedConfig(**{"run": str(run_dir), key: ""}).validate()
    out = subprocess.run([sys.executable, str(REPO / "train" / "amortized.py"), "run="], capture_output=True,
                         text=True, cwd=run_dir, timeout=300)  # fmt: skip
    assert out.returncode == 2 and "key 'run'" in out.stderr and "empty" in out.stderr, out.stderr


def test_the_policys_wall_time_leaves_out_building_its_env_as_the_optimizers_leave_out_their_problem(
    run_dir, monkeypatch
):
    """The policy's ``wall_time_s`` timed :func:`evaluate_policy` whole, building its env (vehicle, cells, simulator)
    included, while an optimizer's clock starts on a problem already built: 1.7 s for the policy's 13 simulations
    against 0.3 s for CMA-ES's. Both now time the calibration alone (the policy's from its reset: the reference draw
    and the initial simulation, then its steps)."""
    import marlcrash.calibrate.evaluate as evaluate

    built = evaluate.make_env
    delay = 5.0

    def slow_build(*args, **kwargs):
        time.sleep(delay)
        return built(*args, **kwargs)

    monkeypatch.setattr(evaluate, "make_env", slow_build)
    out = amortized_comparison(small_config(run_dir, reference_seeds=[101], budgets={"random_search": [1]}))
    policy = [r for r in out.rows if r["method"] in ("policy_best", "policy_last")]
    assert len(policy) == 2 and all(0 < r["wall_time_s"] < delay for r in policy), policy


def test_a_resume_after_a_config_file_changed_is_refused_naming_it(run_dir, tmp_path, monkeypatch):
    """The rows kept at a resume were made with the files of ``configs/`` (simulator, cells, scenarios, reward) as they
    were then; a resume after one changed mixed two physics in one table without a word (the settings check saw only
    the comparison's own settings). The comparison records their digests, and a resume refuses a changed file."""
    import marlcrash.calibrate.amortized as amortized
    from marlcrash import provenance
    from marlcrash.calibrate.marl import make_env_config

    config = small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"random_search": [1]})
    first = amortized_comparison(config)
    _, cfg, _ = load_policy(run_dir)
    now = provenance.config_digests(provenance.env_inputs(make_env_config(cfg)))
    assert first.meta["record"]["configs"] == now
    write_comparison(first, tmp_path)
    done = amortized.read_comparison(tmp_path)
    assert amortized_comparison(config, done=done).rows == done.rows  # unchanged files: the rows stand

    changed = dict(now, **{"configs/sim.yaml": "0" * 64})
    monkeypatch.setattr(amortized.provenance, "config_digests", lambda extra=(): changed)
    said: list[str] = []
    with pytest.raises(ConfigError, match=r"key 'resume': cannot continue the comparison: .*configs/sim\.yaml changed"):
        amortized_comparison(config, done=done, progress=said.append)
    assert said == []  # refused before anything ran
    added = dict(now, **{"configs/scenarios/new_one.yaml": "0" * 64})  # a file the earlier rows did not read
    monkeypatch.setattr(amortized.provenance, "config_digests", lambda extra=(): added)
    assert amortized_comparison(config, done=done).rows == done.rows
    monkeypatch.setattr(amortized.provenance, "config_digests", lambda extra=(): changed)
    older = amortized.Comparison(done.rows, done.aggregate, {k: v for k, v in done.meta.items() if k != "record"})
    assert amortized_comparison(config, done=older).rows == done.rows  # written before any record: cannot tell
    digests = dict(older.meta, configs=now)  # written with the input files' digests only: still checked on them
    with pytest.raises(ConfigError, match=r"configs/sim\.yaml changed"):
        amortized_comparison(config, done=amortized.Comparison(done.rows, done.aggregate, digests))


def test_a_resume_compares_the_record_as_a_training_resume_does(run_dir, tmp_path, caplog):
    """The comparison kept the input files' digests only: a resume after a library upgrade went on without a word (a
    training resume warns), and one whose record cannot be read is refused, naming it."""
    import marlcrash.calibrate.amortized as amortized

    config = small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"random_search": [1]})
    first = amortized_comparison(config)
    assert {"configs", "code", "cwd", "torch", "numba"} <= set(first.meta["record"])
    meta = dict(first.meta, record=dict(first.meta["record"], numba="0.1.0"))
    with caplog.at_level("WARNING", logger="marlcrash.calibrate.amortized"):
        rows = amortized_comparison(config, done=amortized.Comparison(first.rows, first.aggregate, meta)).rows
    assert rows == first.rows
    assert any("numba 0.1.0 -> " in r.getMessage() for r in caplog.records), caplog.text
    broken = dict(first.meta, record=["not", "a", "record"])
    with pytest.raises(ConfigError, match=r"key 'resume': .*record of the input files cannot be read"):
        amortized_comparison(config, done=amortized.Comparison(first.rows, first.aggregate, broken))


@pytest.mark.parametrize(
    "corrupt",
    [
        lambda r: r["rows"][0].update(score="abc"),  # numpy's "could not convert string to float" from aggregate
        lambda r: r["rows"][2].update(simulations=[3]),
        lambda r: r.update(rows=[x for x in r["rows"] if x["method"] != "policy_best"]),  # KeyError in aggregate
        lambda r: r.update(meta=[]),  # AttributeError at the settings check
        # the keys a resume matches rows by: a ValueError/TypeError formatting them, or rows never matched
        lambda r: r["rows"][2].update(multiplier="1"),
        lambda r: r["rows"][2].update(multiplier=None),
        lambda r: r["rows"][0].update(multiplier=1.0),
        lambda r: r["rows"][2].update(method="lm"),
        lambda r: r["rows"][2].update(reference_seed="101"),
    ],
)
def test_a_damaged_comparison_record_is_refused_naming_resume(comparison, tmp_path, corrupt):
    """``read_comparison`` checked the rows' columns but not their values: an edited or damaged ``amortized.json``
    failed with a traceback from deep in numpy (or a KeyError, an AttributeError) instead of naming the file."""
    import marlcrash.calibrate.amortized as amortized

    paths = write_comparison(comparison, tmp_path)
    record = json.loads(paths["amortized.json"].read_text())
    corrupt(record)
    paths["amortized.json"].write_text(json.dumps(record))
    with pytest.raises(ConfigError, match=r"key 'resume': .*amortized.json is not a comparison this tool wrote"):
        amortized.read_comparison(tmp_path)


def test_a_second_comparison_into_a_folder_in_use_is_refused(run_dir, short, tmp_path):
    """Two comparisons into one folder at once (the jobs of a parallel multirun launcher with the default out_dir, the
    run folder; a second ``resume=true`` in another terminal) both passed the check for an earlier amortized.json
    before either had written one, then replaced each other's files after every piece: one's rows were lost. A
    comparison holds its folder while it runs (its own lock file, not the run's ``.lock``: a run that still trains
    may be compared)."""
    import marlcrash.calibrate.amortized as amortized
    from marlcrash.calibrate.runlock import LOCK_FILE

    env = {**os.environ, "MARLCRASH_CONFIGS": str(short)}
    cmd = [sys.executable, str(REPO / "train" / "amortized.py"), f"run={run_dir}", "reference_seeds=[101]",
           "iterations=1", "budgets={cmaes: [1]}", "~budgets.random_search", "~budgets.gradient", "cmaes.popsize=2",
           f"out_dir={tmp_path}"]  # fmt: skip
    with amortized.hold_comparison_dir(tmp_path, key="out_dir"):
        assert amortized.COMPARISON_LOCK != LOCK_FILE
        out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    assert out.returncode == 2 and "key 'out_dir'" in out.stderr and "in use by another process" in out.stderr
    assert "seed 101" not in out.stdout and not (tmp_path / "amortized.json").exists()  # nothing ran
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the lock file went with its holder
    fresh = tmp_path / "fresh"  # a folder made for a comparison that is refused is not left behind, empty
    with pytest.raises(RuntimeError, match="refused"), amortized.hold_comparison_dir(fresh):
        assert (fresh / amortized.COMPARISON_LOCK).is_file()
        raise RuntimeError("refused")
    assert not fresh.exists()


def test_the_policys_best_iterate_passes_before_it_scores():
    """``policy_best`` is the highest-scoring iterate that passes the success test where any does, as an optimizer's
    best candidate is (``Progress``) and as the evaluation reports: it was the highest score alone, so the policy's row
    could say ``passed: false`` beside an iterate of its own that passed, while the optimizers' rows put a passing
    candidate first."""
    from types import SimpleNamespace

    from marlcrash.calibrate.amortized import policy_rows
    from marlcrash.calibrate.evaluate import EvalResult
    from marlcrash.calibrate.problem import SuccessConfig
    from marlcrash.metrics import Metrics

    area = torch.tensor([[0.05], [0.002], [0.001]], dtype=torch.float64)
    m = Metrics(area, torch.full_like(area, 0.1), torch.full_like(area, 0.1))
    scores = torch.tensor([-3.0, 2.0, 1.0], dtype=torch.float64)  # I1 scores highest, only I2 passes
    problem = SimpleNamespace(score=lambda _: scores, success=SuccessConfig().passes)
    result = EvalResult(sensors=["tunnel"], metrics=m, scores=scores, params=torch.zeros(3, 1, 7), selected=2,
                        select="best", true_params=None, ref_velocity=torch.zeros(1, 5), scenario="full_width_40",
                        seed=101)  # fmt: skip
    best, last = policy_rows(problem, result, 101, 1.0)
    assert (best["method"], best["iteration"], best["passed"], best["score"]) == ("policy_best", 2, True, 1.0)
    assert (last["method"], last["iteration"]) == ("policy_last", 2)


def test_a_resume_that_leaves_out_finished_rows_is_refused_naming_them(run_dir, tmp_path):
    """A resume rewrites ``amortized.json`` with the pieces its config asks for, so one that left out a reference
    seed or a budget of the earlier comparison deleted those finished rows from disk without a word. It is refused,
    naming what it leaves out; adding seeds and budgets still works."""
    import marlcrash.calibrate.amortized as amortized

    config = small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"cmaes": [1, 2]})
    write_comparison(amortized_comparison(config), tmp_path)
    done = amortized.read_comparison(tmp_path)
    for seeds, budgets, said in (
        ([SEEDS[1]], {"cmaes": [1, 2]}, rf"reference_seeds: \[{SEEDS[0]}\]"),
        ([SEEDS[0]], {"cmaes": [1]}, r"budgets\.cmaes: \[2\]\)"),
        ([SEEDS[0]], {"random_search": [1]}, r"budgets\.cmaes: \[1, 2\]\)"),
    ):
        with pytest.raises(ConfigError, match=r"key 'resume': .*finished rows this config leaves out .*" + said):
            amortized_comparison(small_config(run_dir, reference_seeds=seeds, budgets=budgets), done=done)
    more = amortized_comparison(small_config(run_dir, reference_seeds=[SEEDS[0]], budgets={"cmaes": [1, 2, 3]}),
                                done=done)  # fmt: skip
    assert [r["multiplier"] for r in more.rows] == [None, None, 1, 2, 3]


def test_a_run_that_names_a_file_is_refused_as_the_run_not_as_out_dir(run_dir, tmp_path):
    """``run=<run>/checkpoint.pt`` (the checkpoint, not its folder) was refused as "key 'out_dir': ... is a file",
    a key the command did not give (out_dir null: the tables go into the run folder); with an ``out_dir`` the file
    was said not to exist. Both name ``run``, and say that it is a file."""
    ckpt = run_dir / "checkpoint.pt"
    with pytest.raises(ConfigError, match=r"is a file; expected a training run folder") as e:
        load_policy(ckpt)
    assert e.value.key == "run" and "does not exist" not in str(e.value)
    out = subprocess.run([sys.executable, str(REPO / "train" / "amortized.py"), f"run={ckpt}"], capture_output=True,
                         text=True, cwd=tmp_path, timeout=300)  # fmt: skip
    assert out.returncode == 2 and "key 'run'" in out.stderr and "is a file" in out.stderr, out.stderr
    assert "out_dir" not in out.stderr and sorted(tmp_path.iterdir()) == []
