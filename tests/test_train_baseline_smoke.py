"""Smoke runs of train/baseline.py in a subprocess with tiny overrides (as TorchRL tests its scripts)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "train" / "baseline.py"
TINY = ["budget=32", "problem.duration=0.01", "gradient.batch_size=4", "cmaes.popsize=8", "random_search.batch_size=8"]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, HYDRA_FULL_ERROR="0")
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize(
    ("method", "budget", "spent"),
    # lm: one iteration costs n_free + 6 = 133 simulations, the last 5 cannot pay for a second
    [("random_search", 32, 32), ("cmaes", 32, 32), ("gradient", 32, 32), ("lm", 139, 134)],
)
def test_script_writes_a_run_folder(tmp_path, method, budget, spent):
    out = tmp_path / "runs"
    p = run(f"method={method}", *TINY, f"budget={budget}", f"out_dir={out}", "name=smoke", "seed=1", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    folder = out / method / "smoke"
    summary = json.loads((folder / "summary.json").read_text())
    for key in ("final_metrics", "initial_metrics", "simulations", "sims_to_success", "wall_time_s", "param_error"):
        assert key in summary
    assert summary["simulations"] == spent and (summary["stop"], summary["stop_reason"]) == ("budget", None)
    printed = json.loads(p.stdout.strip().splitlines()[-1])
    assert (printed["stop"], printed["stop_reason"]) == ("budget", None)
    assert set(summary["final_metrics"]) == {"upfront_left", "upfront_right", "tunnel"}
    assert set(next(iter(summary["final_metrics"].values()))) == {"area", "dfd", "rmse"}
    assert all(set(v) == {"E_x", "E_s", "transmission"} for v in summary["param_error"].values())
    with open(folder / "history.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert int(rows[-1]["simulations"]) == spent and float(rows[-1]["best_score"]) == summary["best_score"]
    assert (folder / "velocity.png").stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # Hydra wrote nothing else


def test_script_rejects_bad_config_before_running(tmp_path):
    p = run("method=gradient", "gradient.lr=-0.5", f"out_dir={tmp_path / 'runs'}", "name=bad", cwd=tmp_path)
    assert p.returncode == 2
    assert "gradient.lr" in p.stderr and "learning rate" in p.stderr
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "runs").exists()


def test_script_refuses_an_existing_run_name_or_a_file_as_out_dir_before_simulating(tmp_path):
    out = tmp_path / "runs"
    (out / "cmaes" / "taken").mkdir(parents=True)
    (out / "cmaes" / "taken" / "keep.txt").write_text("earlier results")
    p = run("method=cmaes", "budget=100000", f"out_dir={out}", "name=taken", cwd=tmp_path)
    assert p.returncode == 2 and "key 'name'" in p.stderr and "exists already" in p.stderr
    assert "Traceback" not in p.stderr and "simulations" not in p.stdout  # failed before the budget was spent
    assert (out / "cmaes" / "taken" / "keep.txt").read_text() == "earlier results"
    afile = tmp_path / "afile"
    afile.write_text("x")
    p = run("method=cmaes", "budget=100000", f"out_dir={afile}", cwd=tmp_path)
    assert p.returncode == 2 and "key 'out_dir'" in p.stderr and "is a file" in p.stderr


def test_a_default_run_name_that_is_taken_gets_the_next_free_folder(tmp_path):
    """The default name is the launch second, which the jobs of a multirun (``--multirun seed=0,1,2``) share: a job
    whose stamp is taken runs in ``<stamp>-2``, where it was refused ("exists already") after the first job."""
    out = tmp_path / "runs"
    now = time.time()
    stamps = {time.strftime("%Y%m%d-%H%M%S", time.localtime(now + s)) for s in range(-2, 120)}
    for stamp in stamps:  # every second the run may start in is taken, as by an earlier job of the multirun
        (out / "random_search" / stamp).mkdir(parents=True)
        (out / "random_search" / stamp / "keep.txt").write_text("earlier job")
    p = run("method=random_search", "budget=1", "plot=false", "problem.duration=0.01", f"out_dir={out}", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    folder = Path(json.loads(p.stdout.strip().splitlines()[-1])["run"])
    assert folder.name.endswith("-2") and folder.name[:-2] in stamps and (folder / "summary.json").is_file()
    assert all((out / "random_search" / s / "keep.txt").read_text() == "earlier job" for s in stamps)
