"""train/train.py and train/evaluate.py smoke-run in a subprocess with tiny overrides (TorchRL's practice)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from marlcrash.calibrate.checkpoint import load_checkpoint
from marlcrash.calibrate.marl import ALGORITHMS

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "n_envs=4",
    "episode_length=2",
    "iterations=2",
    "algorithm.minibatch_size=4",
    "algorithm.hidden=[16,16]",
    "eval.iterations=2",
    "progress_bar=false",
    "snapshot_every=1",
]


def run(script: str, args: list[str], configs: Path, cwd: Path, ci: bool = False) -> subprocess.CompletedProcess:
    env = {**os.environ, "MARLCRASH_CONFIGS": str(configs)}
    env.pop("MARLCRASH_CI", None)
    if ci:
        env["MARLCRASH_CI"] = "1"
    return subprocess.run([sys.executable, str(REPO / "train" / script), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_train_script_writes_a_summary(algorithm, short_configs, tmp_path):
    # mappo with MARLCRASH_CI=1: the command line's values must win over the ci: block (checked below)
    p = run("train.py", [f"algorithm={algorithm}", "name=smoke", *TINY], short_configs, tmp_path, algorithm == "mappo")
    assert p.returncode == 0, p.stderr[-3000:]
    run_dir = tmp_path / "runs" / algorithm / "smoke"
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["algorithm"] == algorithm
    assert s["env_steps"] == 2 * 4 * 2
    assert s["iterations_trained"] == 2
    for key in ("final_metrics", "initial_metrics", "simulations", "wall_time_s", "param_error"):
        assert key in s, key
    assert set(next(iter(s["final_metrics"].values()))) == {"area", "dfd", "rmse"}
    for f in ("config.yaml", "log.csv", "checkpoint.pt", "eval_metrics.md", "pulses.png", "learning_curves.png"):
        assert (run_dir / f).is_file(), f
    out = json.loads(p.stdout[p.stdout.index("{") :])
    assert out["run"] == str(Path("runs") / algorithm / "smoke")

    e = run("evaluate.py", [f"run={run_dir}"], short_configs, tmp_path)
    assert e.returncode == 0, e.stderr[-3000:]
    assert json.loads(e.stdout)["final_metrics"] == s["final_metrics"]
    assert (run_dir / "checkpoints" / "iter_00001.pt").is_file()  # snapshot_every=1 in TINY
    k = run("evaluate.py", [f"run={run_dir}", "checkpoint=1", "iterations=1"], short_configs, tmp_path)
    assert k.returncode == 0, k.stderr[-3000:]
    assert json.loads(k.stdout)["iterations_trained"] == 1
    assert json.loads(k.stdout)["eval_dir"] == str(run_dir / "eval" / "iter_00001_steps1")  # TINY evaluates 2 steps
    assert (run_dir / "eval" / "iter_00001_steps1" / "summary.json").is_file()


@pytest.mark.slow
def test_a_multirun_seed_sweep_writes_one_run_per_seed_and_nothing_in_the_launch_directory(short_configs, tmp_path):
    p = run("train.py", ["-m", "seed=0,1", "name=sweep_s${seed}", *TINY, "iterations=1"], short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["runs"]  # Hydra's default would add multirun/ here
    walls = []
    for seed in (0, 1):
        s = json.loads((tmp_path / "runs" / "mappo" / f"sweep_s{seed}" / "summary.json").read_text())
        assert s["seed"] == seed
        walls.append(s["process_wall_time_s"])
    assert walls[1] < walls[0]  # the second job's own time; it counted the first job's too (the imports only in it)
    (record,) = (tmp_path / "runs" / "multirun").glob("*/multirun.yaml")
    assert sorted(x.name for x in record.parent.iterdir()) == ["multirun.yaml"]  # no empty per-job folders


def test_a_multirun_with_a_bad_job_runs_none(short_configs, tmp_path):
    """Each job of ``-m`` checked its values as it started: job 1 trained, job 2 stopped the sweep, job 3 never ran."""
    p = run("train.py", ["-m", "seed=0,-1,2", "name=s${seed}", *TINY, "iterations=1"], short_configs, tmp_path)
    assert p.returncode == 2, p.stderr[-3000:]
    assert "key 'seed': multirun job 2 of 3 (seed=-1 name=s${seed}" in p.stderr and "no job was run" in p.stderr
    p = run("baseline.py", ["-m", "seed=0,1", "name=same", "method=random_search", "budget=8"], short_configs, tmp_path)
    assert p.returncode == 2 and "multirun jobs 1 and 2 of 2 would write one run folder" in p.stderr, p.stderr[-3000:]
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("override", "key"),
    [("algorithm.lr=-1", "algorithm.lr"), ("algorithm.minibatch_size=3", "algorithm.minibatch_size")],
)
def test_bad_config_fails_before_training(override, key, short_configs, tmp_path):
    p = run("train.py", [*TINY, override], short_configs, tmp_path)
    assert p.returncode == 2
    assert f"key '{key}'" in p.stderr
    assert not (tmp_path / "runs").exists()  # nothing was started, nothing written


def test_unknown_algorithm_or_key_lists_the_options_and_starts_nothing(short_configs, tmp_path):
    """Hydra's composition errors come out as the scripts' own: ``error:``, the key, the options, exit 2."""
    p = run("train.py", ["algorithm=sac", *TINY], short_configs, tmp_path)
    assert p.returncode == 2, p.stderr[-2000:]
    assert p.stderr.startswith("error: train.yaml key 'algorithm': no config 'sac'") and "'mappo'" in p.stderr
    p = run("train.py", [*TINY, "algorithm.lrr=1e-3"], short_configs, tmp_path)
    assert p.returncode == 2 and "key 'algorithm.lrr': unknown key; expected one of [" in p.stderr
    assert not (tmp_path / "runs").exists()


def test_resume_of_a_named_run_that_does_not_exist_never_takes_the_newest_run(short_configs, tmp_path):
    newest = tmp_path / "runs" / "mappo" / "real"
    newest.mkdir(parents=True)
    (newest / "checkpoint.pt").write_bytes(b"")  # what resume=true alone would pick
    p = run("train.py", ["resume=true", "name=typo"], short_configs, tmp_path)
    assert p.returncode == 2, p.stderr[-2000:]
    assert "key 'resume'" in p.stderr and str(Path("runs") / "mappo" / "typo") in p.stderr
    assert "ignored" not in p.stderr and not (tmp_path / "runs" / "mappo" / "typo").exists()


def test_a_resume_of_a_given_folder_reports_the_keys_that_locate_a_run_as_ignored(short_configs, tmp_path):
    """``resume=<folder>`` continues that folder's run as it was: ``algorithm=ippo name=x`` did not switch it to
    another algorithm or folder, and were dropped without a word (they locate the run only with ``resume=true``)."""
    p = run("train.py", [f"resume={tmp_path / 'gone'}", "algorithm=ippo", "name=x", "out_dir=o"], short_configs,
            tmp_path)  # fmt: skip
    assert p.returncode == 2 and "key 'resume'" in p.stderr, p.stderr[-2000:]
    assert "ignored: algorithm=ippo name=x out_dir=o" in p.stderr


@pytest.mark.slow
def test_a_resume_takes_a_free_override_and_refuses_one_that_changes_the_run(short_configs, tmp_path):
    """``resume=<run> algorithm.lr=1e-4`` went on with the run's lr, and ``resume=<run> time_limit_s=1200`` with its
    time limit, both behind a warning that they were ignored. A setting a resume may change now takes effect and is
    kept in config.yaml; another one is refused naming it and both values, before anything runs."""
    p = run("train.py", [*TINY, "name=r", "checkpoint_every=1"], short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    run_dir = tmp_path / "runs" / "mappo" / "r"
    ckpt = (run_dir / "checkpoint.pt").read_bytes()
    p = run("train.py", [f"resume={run_dir}", "algorithm.lr=1e-4", "seed=0"], short_configs, tmp_path)
    assert p.returncode == 2, p.stderr[-2000:]
    assert "key 'algorithm.lr': resume: the run has algorithm.lr = 0.001, the command line gives 0.0001" in p.stderr
    assert "ignored" not in p.stderr and (run_dir / "checkpoint.pt").read_bytes() == ckpt
    p = run("train.py", ["resume=true", "name=r", "checkpoint_every=2", "eval.plots=false"], short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "ignored" not in p.stderr
    saved = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert (saved["checkpoint_every"], saved["eval"]["plots"], saved["algorithm"]["lr"]) == (2, False, 1e-3)


@pytest.mark.slow
def test_evaluate_script_reports_a_missing_run(short_configs, tmp_path):
    p = run("evaluate.py", [f"run={tmp_path / 'nope'}"], short_configs, tmp_path)
    assert p.returncode == 2 and "config.yaml" in p.stderr
    p = run("evaluate.py", [], short_configs, tmp_path)
    assert p.returncode == 2 and "key 'run'" in p.stderr


@pytest.mark.slow
def test_a_killed_training_process_resumes_to_the_uninterrupted_result(short_configs, tmp_path):
    """SIGKILL during training (after the second checkpoint), then `resume=<run>`: the same final metrics,
    counters and log as the run that was never interrupted; a resume's override that changes the run is refused,
    one that only restates it or that a resume may change (``checkpoint_every``) is taken."""
    args = [*TINY, "iterations=8", "time_limit_s=null"]
    straight = run("train.py", [*args, "name=straight"], short_configs, tmp_path)
    assert straight.returncode == 0, straight.stderr[-3000:]

    env = {**os.environ, "MARLCRASH_CONFIGS": str(short_configs)}
    env.pop("MARLCRASH_CI", None)
    proc = subprocess.Popen([sys.executable, str(REPO / "train" / "train.py"), *args, "name=killed"], cwd=tmp_path,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    run_dir = tmp_path / "runs" / "mappo" / "killed"
    killed_at = None
    deadline = time.monotonic() + 300
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if (run_dir / "checkpoint.pt").is_file():
                it = load_checkpoint(run_dir / "checkpoint.pt")["iteration"]
                if it >= 2:
                    proc.send_signal(signal.SIGKILL)
                    killed_at = it
                    break
            time.sleep(0.02)
    finally:
        proc.kill()
        proc.wait()
    assert killed_at is not None and killed_at < 8, "the process finished before it could be killed"
    assert not (run_dir / "summary.json").exists()

    refused = run("train.py", [f"resume={run_dir}", "iterations=99"], short_configs, tmp_path)
    assert refused.returncode == 2 and "key 'iterations': resume: the run has iterations = 8" in refused.stderr
    resumed = run("train.py", [f"resume={run_dir}", "iterations=8", "checkpoint_every=2"], short_configs, tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    a = json.loads((tmp_path / "runs" / "mappo" / "straight" / "summary.json").read_text())
    b = json.loads((run_dir / "summary.json").read_text())
    for key in ("final_metrics", "initial_metrics", "selected_iteration", "param_error", "env_steps", "simulations"):
        assert a[key] == b[key], key
    assert b["iterations_trained"] == 8
    # a resume stamps no process wall time (train/train.py's doc): its printed summary says null, not 0.0 s
    assert "process_wall_time_s" not in b and json.loads(resumed.stdout)["process_wall_time_s"] is None
