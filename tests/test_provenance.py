"""Run provenance: config and code digests recorded in run folders, checked on resume and evaluation."""

from __future__ import annotations

import json
import logging
import platform
import shutil
from pathlib import Path

import pytest

from marlcrash import provenance
from marlcrash.errors import ConfigError


@pytest.fixture
def configs(short_configs, tmp_path, monkeypatch) -> Path:
    """A private copy of the short-scenario configs in effect: tests edit it."""
    dst = tmp_path / "configs"
    shutil.copytree(short_configs, dst)
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(dst))
    return dst


def _touch(path: Path) -> None:
    """Change a file's bytes without changing what it configures (a YAML comment)."""
    path.write_text(path.read_text() + "\n# edited\n")


def test_digests_cover_every_input_config_but_not_the_saved_training_configs(configs, tmp_path):
    outside = tmp_path / "deck.k"
    outside.write_text("*KEYWORD\n*END\n")
    d = provenance.config_digests([outside, configs / "sim.yaml", tmp_path / "missing.csv"])
    names = {p.relative_to(configs).as_posix() for p in configs.rglob("*") if p.is_file()}
    expected = {f"configs/{n}" for n in names if not n.startswith("train/")}
    assert expected <= set(d) and "configs/sim.yaml" in expected and "configs/env/default.yaml" in expected
    assert not any(k.startswith("configs/train/") for k in d)
    assert set(d) - expected == {str(outside.resolve())}  # a file inside configs/ is not named twice
    import hashlib

    assert d["configs/sim.yaml"] == hashlib.sha256((configs / "sim.yaml").read_bytes()).hexdigest()


def test_changes_name_changed_added_and_removed_files():
    saved = {"configs/a.yaml": "1", "configs/b.yaml": "2", "configs/c.yaml": "3"}
    now = {"configs/a.yaml": "1", "configs/b.yaml": "9", "configs/d.yaml": "4"}
    assert provenance.config_changes(saved, now) == [
        "configs/b.yaml changed",
        "configs/c.yaml removed",
        "configs/d.yaml added",
    ]
    assert provenance.config_changes(saved, dict(saved)) == []


def test_check_run_finds_config_edits_and_code_changes(configs, tmp_path, monkeypatch, caplog):
    run = tmp_path / "run"
    run.mkdir()
    rec = provenance.write_record(run)
    assert json.loads((run / provenance.PROVENANCE_FILE).read_text()) == rec
    assert rec["code"]["source_sha256"] == provenance.source_digest()
    clean = provenance.check_run(run)
    assert clean.recorded and clean.configs == [] and clean.code == []
    provenance.require_unchanged(run)  # nothing changed: no error

    _touch(configs / "sim.yaml")
    (configs / "scenarios" / "extra.yaml").write_text("speed: 1\n")
    check = provenance.check_run(run)
    assert check.configs == ["configs/scenarios/extra.yaml added", "configs/sim.yaml changed"]
    with pytest.raises(ConfigError, match=r"configs/sim\.yaml changed") as e:
        provenance.require_unchanged(run)
    assert e.value.key == "resume" and provenance.PROVENANCE_FILE in str(e.value)
    assert "extra.yaml" not in str(e.value)  # an added file is no reason to refuse: no run read it
    (configs / "sim.yaml").write_text((configs / "sim.yaml").read_text().removesuffix("\n# edited\n"))
    assert provenance.require_unchanged(run).configs == ["configs/scenarios/extra.yaml added"]  # warned only

    # code changes warn, they do not refuse
    (configs / "scenarios" / "extra.yaml").unlink()
    rec["configs"] = provenance.config_digests()
    (run / provenance.PROVENANCE_FILE).write_text(json.dumps(rec))
    monkeypatch.setattr(provenance, "source_digest", lambda: "0" * 64)
    with caplog.at_level(logging.WARNING, logger="marlcrash.provenance"):
        check = provenance.require_unchanged(run)
    assert check.configs == [] and check.code and check.code[0].startswith("marlcrash source changed")
    assert "marlcrash source changed" in caplog.text


def test_changed_source_at_one_commit_is_said_to_be_uncommitted_changes(configs, tmp_path, monkeypatch):
    """Source edited in a checkout without a commit (the usual case while developing) was said as
    'marlcrash source changed (git 1c27aa5 -> 1c27aa5)': a change between a commit and itself, which reads as a
    fault of the check. It now says the commit was the same and the change is uncommitted; other commits and no git
    read as before."""
    run = tmp_path / "run"
    run.mkdir()
    monkeypatch.setattr(provenance, "git_commit", lambda: "1c27aa5" + "0" * 33)
    provenance.write_record(run)
    monkeypatch.setattr(provenance, "source_digest", lambda: "0" * 64)
    assert provenance.check_run(run).code == ["marlcrash source changed (uncommitted changes at git 1c27aa5)"]
    monkeypatch.setattr(provenance, "git_commit", lambda: "5d0f473" + "0" * 33)
    assert provenance.check_run(run).code == ["marlcrash source changed (git 1c27aa5 -> 5d0f473)"]
    monkeypatch.setattr(provenance, "git_commit", lambda: None)
    assert provenance.check_run(run).code == ["marlcrash source changed (git 1c27aa5 -> None)"]


def test_the_source_digest_skips_editor_files_beside_the_sources(tmp_path, monkeypatch):
    """Emacs marks a file being edited with a lock, ``.#cli.py``: a symbolic link to nowhere. The source digest hashed
    every ``*.py`` under the package, hidden ones too, so with a source file open in Emacs every run start, resume and
    evaluation failed with FileNotFoundError on the lock. Hidden files and folders are skipped, and only files are
    hashed, so the digest is that of the sources alone."""
    pkg = tmp_path / "marlcrash"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "cli.py").write_text("x = 1\n")
    (pkg / "sub" / "m.py").write_text("y = 2\n")
    monkeypatch.setattr(provenance, "_package_root", lambda: pkg)
    clean = provenance.source_digest()
    (pkg / ".#cli.py").symlink_to("user@host.12345:1700000000")  # Emacs' lock: a dangling link
    (pkg / ".ipynb_checkpoints").mkdir()
    (pkg / ".ipynb_checkpoints" / "cli-checkpoint.py").write_text("x = 0\n")
    (pkg / "sub" / "dir.py").mkdir()  # a folder whose name ends in .py: nothing to hash
    assert provenance.source_digest() == clean
    (pkg / "sub" / "m.py").write_text("y = 3\n")
    assert provenance.source_digest() != clean


def test_the_git_commit_is_the_packages_whatever_git_variables_say(tmp_path, monkeypatch):
    """``git -C <checkout> rev-parse HEAD`` obeys GIT_DIR (exported by dotfile managers, set in git hooks): with it
    naming another repository the record took that repository's commit for marlcrash's. The commit is now read from
    the package's own checkout, whatever GIT_* variables are set."""
    import subprocess

    if provenance.git_commit() is None:
        pytest.skip("the package is not in a git checkout here")
    ours = provenance.git_commit()
    other = tmp_path / "other"
    other.mkdir()
    git = ["git", "-C", str(other), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "commit", "-q", "--allow-empty", "-m", "x"], check=True)
    monkeypatch.setenv("GIT_DIR", str(other / ".git"))
    monkeypatch.setenv("GIT_WORK_TREE", str(other))
    assert provenance.git_commit() == ours


def test_a_record_names_cma_and_numba_and_a_changed_train_script_warns_like_changed_source(
    configs, tmp_path, monkeypatch, caplog
):
    """CMA-ES (``cma``) and the compiled kernels (``numba``) make the numbers too, and the ``train/`` entry scripts
    hold logic of their own (which library calls, in which order): a record left them out, so a resume after a
    script changed said nothing. A changed script warns, as changed package source does; an old record without the
    new fields is read as before."""
    import cma
    import numba

    run = tmp_path / "run"
    run.mkdir()
    rec = provenance.write_record(run)
    assert rec["cma"] == cma.__version__ and rec["numba"] == numba.__version__
    assert rec["code"]["train_sha256"] == provenance.train_digest() is not None  # this checkout has train/

    scripts = tmp_path / "train"
    scripts.mkdir()
    (scripts / "other.py").write_text("print('another distribution')\n")
    monkeypatch.setattr(provenance, "_train_root", lambda: scripts)
    assert provenance.train_digest() is None  # a site-packages/train of another distribution is not ours
    (scripts / "baseline.py").write_text("print('baseline')\n")
    (scripts / "train.py").write_text("print('train')\n")
    assert provenance.train_digest() is not None
    provenance.write_record(run)
    assert provenance.check_run(run).code == []
    (scripts / "train.py").write_text("print('train, differently')\n")
    with caplog.at_level(logging.WARNING, logger="marlcrash.provenance"):
        check = provenance.require_unchanged(run)  # warned, not refused
    assert check.configs == [] and len(check.code) == 1 and check.code[0].startswith("train/ scripts changed")
    assert "train/ scripts changed" in caplog.text

    old = json.loads((run / provenance.PROVENANCE_FILE).read_text())  # a record of before these fields
    for k in ("cma", "numba"):
        del old[k]
    del old["code"]["train_sha256"]
    (run / provenance.PROVENANCE_FILE).write_text(json.dumps(old))
    check = provenance.require_unchanged(run)
    assert check.recorded and check.configs == [] and check.code == []


def test_other_library_versions_at_a_resume_or_evaluation_are_warned_about(configs, tmp_path, caplog):
    """The record keeps the versions of Python, torch, numpy, cma and numba, but nothing compared them: a run
    resumed or evaluated after ``pip install -U torch`` (other kernels, other random streams) went on without a word,
    though its numbers no longer come from the same code. Now each version that differs is a code change (a
    warning, not a refusal), naming the library and both versions; a record without a field is compared on what it
    holds."""
    import torch

    run = tmp_path / "run"
    run.mkdir()
    rec = provenance.write_record(run)
    assert provenance.check_run(run).code == []
    rec["torch"], rec["python"] = "1.0.0", "3.0.1"
    del rec["numba"]  # an older record without it
    (run / provenance.PROVENANCE_FILE).write_text(json.dumps(rec))
    with caplog.at_level(logging.WARNING, logger="marlcrash.provenance"):
        check = provenance.require_unchanged(run)  # warned, not refused
    assert check.configs == []
    assert check.code == [f"python 3.0.1 -> {platform.python_version()}", f"torch 1.0.0 -> {torch.__version__}"]
    assert f"torch 1.0.0 -> {torch.__version__} since the run started" in caplog.text


def test_a_folder_without_a_record_warns_and_a_broken_record_is_named(configs, tmp_path, caplog):
    run = tmp_path / "old_run"
    run.mkdir()
    with caplog.at_level(logging.WARNING, logger="marlcrash.provenance"):
        check = provenance.require_unchanged(run)
    assert not check.recorded and check.as_dict() == {"recorded": False, "config_changes": [], "code_changes": []}
    assert "has no provenance.json" in caplog.text
    assert json.loads((run / provenance.PROVENANCE_FILE).read_text())["note"] == provenance.RESUME_NOTE  # guarded again
    (run / provenance.PROVENANCE_FILE).write_text("{not json")
    with pytest.raises(ConfigError, match=r"provenance\.json cannot be read") as e:
        provenance.check_run(run)
    assert e.value.key == "resume"
    with caplog.at_level(logging.WARNING, logger="marlcrash.provenance"):  # an evaluation goes on, warned
        assert not provenance.check_run(run, key=None).recorded
    assert "cannot be read as a provenance record; going on without it" in caplog.text


def test_env_inputs_are_files_named_by_path():
    from marlcrash.envs.core import load_env_config

    cfg = load_env_config("default", {"vehicle": "decks/car.k"})
    assert provenance.env_inputs(cfg) == ["decks/car.k"]
    assert provenance.env_inputs(load_env_config("default")) == []  # a registered vehicle lives in configs/


@pytest.mark.parametrize("named", ["folder", "mme"])
def test_a_measured_iso_mme_test_outside_configs_is_recorded_by_its_channel_files(configs, tmp_path, named):
    """A measured reference given as an ISO-MME test (its folder, or its ``.mme`` file) outside ``configs/`` is
    read from the ``.mme`` file, the channel list and the channel files, but the record hashed only a file: a folder
    not at all, a ``.mme`` file without the measured signals. Editing a measured channel then resumed a run on
    other reference data without a word. Now every file the test is read from is recorded, and a changed channel
    refuses the resume naming it."""
    import numpy as np

    from marlcrash.pulse.io import Pulse, write_mme

    t = np.arange(0.0, 0.1, 1e-4)
    mme = write_mme(Pulse(t, np.stack([-np.sin(t * 30.0), -np.sin(t * 25.0)]), ("tunnel", "radsup")),
                    tmp_path / "T1", "T1")  # fmt: skip
    channel = (tmp_path / "T1" / "Channel" / "T1.002").resolve()
    test = str(mme if named == "mme" else tmp_path / "T1")
    recorded = provenance.config_digests([test])
    assert {str(mme.resolve()), str(channel)} <= set(recorded)
    run = tmp_path / "run"
    run.mkdir()
    provenance.write_record(run, [test])
    assert provenance.require_unchanged(run, [test]).configs == []
    lines = channel.read_text().splitlines()
    channel.write_text("\n".join([*lines[:-1], "0.5", ""]))  # the last sample measured otherwise
    with pytest.raises(ConfigError, match=f"{channel} changed") as e:
        provenance.require_unchanged(run, [test])
    assert e.value.key == "resume"


def test_an_env_config_file_outside_configs_is_an_input(configs, tmp_path):
    """An env config named by its path (``env=my_env.yaml``) holds the vehicle, scenarios, reward and reference a
    run reads at a resume, but was not recorded: editing it changed a resumed run's physics without a word."""
    from marlcrash.envs.core import load_env_config

    mine = tmp_path / "my_env.yaml"
    mine.write_text((configs / "env" / "default.yaml").read_text())
    inputs = provenance.env_inputs(load_env_config(str(mine)))
    assert str(mine.resolve()) in provenance.config_digests(inputs)
    run = tmp_path / "run"
    run.mkdir()
    provenance.write_record(run, inputs)
    _touch(mine)
    with pytest.raises(ConfigError, match=r"my_env\.yaml changed"):
        provenance.require_unchanged(run, provenance.env_inputs(load_env_config(str(mine))))
    assert provenance.env_inputs(load_env_config("default")) == []  # a registered env is under configs/ already


def test_a_reward_file_outside_configs_is_an_input(configs, tmp_path):
    """An env's ``reward`` (or a baseline's ``problem.fit``) may name a YAML file by its path; it was not recorded, so
    editing its weights between the start and a resume mixed two rewards in one run without a word."""
    from marlcrash.calibrate import ProblemConfig
    from marlcrash.calibrate.baselines import BaselineRunConfig, run_record
    from marlcrash.config import from_dict
    from marlcrash.envs.core import load_env_config

    mine = tmp_path / "my_reward.yaml"
    mine.write_text((configs / "reward" / "log_ratio.yaml").read_text())
    inputs = provenance.env_inputs(load_env_config("default", {"reward": str(mine)}))
    assert inputs == [str(mine)]
    run = tmp_path / "run"
    run.mkdir()
    provenance.write_record(run, inputs)
    _touch(mine)
    with pytest.raises(ConfigError, match=r"my_reward\.yaml changed"):
        provenance.require_unchanged(run, inputs)
    baseline = BaselineRunConfig(problem=from_dict(ProblemConfig, {"fit": str(mine)}))
    assert str(mine.resolve()) in run_record(baseline)["configs"]
    assert provenance.reward_input("log_ratio") == [] and provenance.env_inputs(load_env_config("default")) == []


def test_a_training_resume_refuses_changed_configs_and_an_evaluation_reports_them(configs, tmp_path):
    from test_train_marl import tiny

    from marlcrash.calibrate.evaluate import evaluate_run
    from marlcrash.calibrate.marl import train

    part = train(tiny(tmp_path, name="p", iterations=2), stop_at=1, evaluate=False)
    rec = json.loads((part.run_dir / provenance.PROVENANCE_FILE).read_text())
    assert "configs/env/default.yaml" in rec["configs"] and rec["code"]["marlcrash"]
    _touch(configs / "materials.yaml")
    with pytest.raises(ConfigError, match=r"configs/materials\.yaml changed") as e:
        train(tiny(tmp_path, name="p", iterations=2, resume=str(part.run_dir)))
    assert e.value.key == "resume"
    summary = evaluate_run(part.run_dir)  # evaluating an old run on today's configs is allowed, and reported
    assert summary["provenance"]["config_changes"] == ["configs/materials.yaml changed"]
    assert json.loads((part.run_dir / "summary.json").read_text())["provenance"]["recorded"] is True
    own = (part.run_dir / "summary.json").read_text()  # the run's first evaluation went into the run folder;
    again = evaluate_run(part.run_dir)  # with results there, one on changed inputs goes beside them
    assert again["eval_dir"] == str(part.run_dir / "eval" / "checkpoint") and again["provenance"]["config_changes"]
    assert (part.run_dir / "summary.json").read_text() == own
    (part.run_dir / provenance.PROVENANCE_FILE).unlink()  # the documented way to go on anyway
    done = train(tiny(tmp_path, name="p", iterations=2, resume=str(part.run_dir)))
    assert done.iterations == 2  # the resume wrote a new record, saying so: later changes are caught again
    assert done.summary["provenance"] == {"recorded": True, "config_changes": [], "code_changes": [],
                                          "note": provenance.RESUME_NOTE}  # fmt: skip
    _touch(configs / "sim.yaml")
    with pytest.raises(ConfigError, match=r"it is finished.*python train/evaluate\.py run=") as e:
        train(tiny(tmp_path, name="p", iterations=2, resume=str(part.run_dir)))  # a finished run: how to evaluate


def test_a_resume_of_a_finished_run_after_the_code_changed_keeps_the_runs_results(configs, tmp_path, caplog):
    """A finished run resumed evaluates its checkpoint again, as ``train/evaluate.py`` does: after the code changed
    the evaluation goes beside the run's own (it rewrote ``summary.json``, calibrated parameters and plots)."""
    from test_train_marl import tiny

    from marlcrash.calibrate.marl import train

    done = train(tiny(tmp_path, name="f", iterations=1))
    own = {f: (done.run_dir / f).read_bytes() for f in ("summary.json", "calibrated.npz")}
    path = done.run_dir / provenance.PROVENANCE_FILE
    rec = json.loads(path.read_text())
    rec["code"]["source_sha256"] = "0" * 64  # the code the run started with was other
    path.write_text(json.dumps(rec))
    again = train(tiny(tmp_path, name="f", iterations=1, resume=str(done.run_dir)))
    assert again.iterations == 1 and "since the run started" in caplog.text
    assert again.summary["eval_dir"] == str(done.run_dir / "eval" / "checkpoint")
    assert again.summary["provenance"]["code_changes"]
    assert {f: (done.run_dir / f).read_bytes() for f in own} == own


def test_a_resumed_table_of_runs_refuses_changed_configs(configs, tmp_path):
    from test_compare import tiny

    from marlcrash.calibrate.compare import run_comparison

    cfg = tiny(tmp_path, methods=["random_search"], seeds=[0])
    run_dir, _ = run_comparison(cfg)
    assert (run_dir / provenance.PROVENANCE_FILE).is_file()
    _touch(configs / "cells.yaml")
    with pytest.raises(ConfigError, match=r"configs/cells\.yaml changed") as e:
        run_comparison(tiny(tmp_path, methods=["random_search", "cmaes"], seeds=[0], resume=True))
    assert e.value.key == "resume"


def test_a_deck_outside_configs_is_recorded_with_its_includes_by_tables_and_baselines(configs, tmp_path):
    """A vehicle deck named by ``env_overrides.vehicle`` is an input of a table of runs and of a baseline, and so
    are the files it ``*INCLUDE``s (real models are mostly includes): editing one refuses a resume."""
    from marlcrash.calibrate.baselines import BaselineRunConfig, run_record
    from marlcrash.calibrate.compare import open_run_dir
    from marlcrash.calibrate.problem import ProblemConfig

    decks = tmp_path / "decks"
    (decks / "sub").mkdir(parents=True)
    (decks / "car.k").write_text("*KEYWORD\n*INCLUDE\nsub/part.k\n*END\n")
    (decks / "sub" / "part.k").write_text("*KEYWORD\n$ shells of the bumper\n*END\n")
    names = {str((decks / "car.k").resolve()), str((decks / "sub" / "part.k").resolve())}
    assert names <= set(provenance.config_digests([decks / "car.k"]))

    env = ("default", {"vehicle": str(decks / "car.k")})
    run = tmp_path / "table"
    open_run_dir(run, "compare.json", {"a": 1}, False, lambda rows: [], env, ("method",))
    assert names <= set(json.loads((run / provenance.PROVENANCE_FILE).read_text())["configs"])
    (run / "compare.json").write_text(json.dumps({"config": {"a": 1}, "rows": []}))
    open_run_dir(run, "compare.json", {"a": 1}, True, lambda rows: [], env, ("method",))  # unchanged: resumes
    (decks / "sub" / "part.k").write_text("*KEYWORD\n$ thicker shells of the bumper\n*END\n")
    with pytest.raises(ConfigError, match=r"part\.k changed") as e:
        open_run_dir(run, "compare.json", {"a": 1}, True, lambda rows: [], env, ("method",))
    assert e.value.key == "resume"

    rec = run_record(BaselineRunConfig(problem=ProblemConfig(env_overrides={"vehicle": str(decks / "car.k")})))
    assert names <= set(rec["configs"])


def test_a_deck_named_by_a_relative_path_is_read_from_the_working_directory_and_so_said(configs, tmp_path, monkeypatch):
    """A run reads a vehicle deck named by a relative path from the working directory (Hydra's ``chdir: false``:
    ``load_vehicle`` opens ``Path('decks/car.k')``), and provenance resolves it alike: a resume started in another
    folder reads another file, or none, and is refused. But the refusal said the deck and its include were
    "removed", though both were still where the run started: nothing told the user the path was relative. Now the
    record keeps its working directory, and a resume elsewhere names the relative path, the file it named then and
    the one it names now, and where to start; a file still on disk that the run no longer reads is not "removed"."""
    from marlcrash.calibrate.compare import open_run_dir
    from marlcrash.envs.core import load_env_config

    proj, elsewhere = tmp_path / "proj", tmp_path / "elsewhere"
    (proj / "decks" / "sub").mkdir(parents=True)
    elsewhere.mkdir()
    (proj / "decks" / "car.k").write_text("*KEYWORD\n*INCLUDE\nsub/part.k\n*END\n")
    (proj / "decks" / "sub" / "part.k").write_text("*KEYWORD\n$ shells of the bumper\n*END\n")
    env = ("default", {"vehicle": "decks/car.k"})
    run = tmp_path / "table"
    monkeypatch.chdir(proj)
    open_run_dir(run, "compare.json", {"a": 1}, False, lambda rows: [], env, ("method",))
    (run / "compare.json").write_text(json.dumps({"config": {"a": 1}, "rows": []}))
    open_run_dir(run, "compare.json", {"a": 1}, True, lambda rows: [], env, ("method",))  # same folder: resumes

    monkeypatch.chdir(elsewhere)
    with pytest.raises(ConfigError) as e:
        open_run_dir(run, "compare.json", {"a": 1}, True, lambda rows: [], env, ("method",))
    assert e.value.key == "resume"
    said = str(e.value)
    then, now = (proj / "decks" / "car.k").resolve(), (elsewhere / "decks" / "car.k").resolve()
    hint = (f"'decks/car.k' is a relative path, read from the working directory: {then} where the run started, "
            f"{now} here (no such file); start it from {proj.resolve()}, or name it by an absolute path")  # fmt: skip
    assert f"was started with other configs ({hint});" in said  # one entry: the deck and its include alike
    assert "removed" not in said

    shutil.copytree(proj / "decks", elsewhere / "decks")  # a copy here: another file all the same, named so
    check = provenance.check_run(run, provenance.env_inputs(load_env_config(*env)), key=None)
    assert check.configs == [hint.replace(" (no such file)", "")]
    monkeypatch.chdir(proj)
    assert provenance.check_run(run, ["decks/car.k"]).configs == []  # back where it started
    (proj / "decks" / "car.k").write_text("*KEYWORD\n*END\n")  # the include dropped: still there, no longer read
    assert provenance.check_run(run, ["decks/car.k"]).configs == [
        f"{then} changed",
        f"{(proj / 'decks' / 'sub' / 'part.k').resolve()} is no longer read (the file is still there)",
    ]


def test_a_run_moved_with_its_project_to_another_machine_resumes_on_the_same_relative_deck(
    configs, tmp_path, monkeypatch
):
    """A run folder copied to another machine (or its project moved to another folder) with the deck at the same
    path relative to where the run starts was refused though every byte was the same: the record names the files by
    their resolved paths on the first machine, and the check told the user to start from a folder this machine does
    not have; deleting the record was the only way on, which dropped the guard. Where the file the run read is not
    here, the files read now are compared with the recorded ones at the same place relative to the working
    directory: the same bytes resume, a changed include is still refused, naming it here and as recorded."""
    first, second = tmp_path / "first" / "proj", tmp_path / "second" / "home" / "proj"
    (first / "decks" / "sub").mkdir(parents=True)
    shared = tmp_path / "barrier.k"  # named by an absolute path: the same file on both machines
    shared.write_text("*KEYWORD\n$ a rigid wall\n*END\n")
    (first / "decks" / "car.k").write_text(f"*KEYWORD\n*INCLUDE\nsub/part.k\n*INCLUDE\n{shared}\n*END\n")
    (first / "decks" / "sub" / "part.k").write_text("*KEYWORD\n$ shells of the bumper\n*END\n")
    run = tmp_path / "run"
    run.mkdir()
    monkeypatch.chdir(first)
    assert str(shared.resolve()) in provenance.write_record(run, ["decks/car.k"])["configs"]
    second.parent.mkdir(parents=True)
    first.rename(second)  # the first machine's folder is not here
    monkeypatch.chdir(second)
    assert provenance.require_unchanged(run, ["decks/car.k"]).configs == []

    (second / "decks" / "sub" / "part.k").write_text("*KEYWORD\n$ thicker shells of the bumper\n*END\n")
    with pytest.raises(ConfigError) as e:
        provenance.require_unchanged(run, ["decks/car.k"])
    assert e.value.key == "resume"
    part, recorded = (second / "decks" / "sub" / "part.k").resolve(), first.resolve() / "decks" / "sub" / "part.k"
    assert f"other configs ({part} changed (read as {recorded} where the run started, in {first.resolve()}));" in (
        str(e.value)
    )


@pytest.mark.parametrize(
    ("rows", "says"),
    [([{"method": "cmaes"}], r"row 0 of .*compare\.json lacks seed, score"),
     ([{"method": "cmaes", "seed": 0, "score": 1.0}, ["cmaes", 0]],
      r"row 1 of .*compare\.json is list, not an object")],
)  # fmt: skip
def test_a_resumed_record_with_a_malformed_row_is_refused_naming_the_row(tmp_path, rows, says):
    """A hand-edited record (or one of another version) is refused before any run, not a KeyError later."""
    from marlcrash.calibrate.compare import open_run_dir

    run, env = tmp_path / "table", ("default", {})
    open_run_dir(run, "compare.json", {"a": 1}, False, lambda rows: [], env, ())
    (run / "compare.json").write_text(json.dumps({"config": {"a": 1}, "rows": rows}))
    with pytest.raises(ConfigError, match=says) as e:
        open_run_dir(run, "compare.json", {"a": 1}, True, lambda rows: [r["method"] for r in rows], env,
                     ("method", "seed", "score"))  # fmt: skip
    assert e.value.key == "resume"


def test_editor_leftovers_in_configs_are_no_inputs_of_a_run_or_of_the_cell_model(configs, tmp_path):
    """An editor's backup ``sim.yaml~``, autosave ``#sim.yaml#`` or swap file beside the configs was hashed into the
    record as an input, so deleting it refused the resume as "configs/sim.yaml~ removed"; no loader reads one."""
    from marlcrash.envs.core import _input_files
    from marlcrash.vehicle.registry import VehicleOptions

    leftovers = [configs / "sim.yaml~", configs / "#sim.yaml#", configs / ".sim.yaml.swp",
                 configs / "vehicle" / "b_segment.yaml.swp", configs / "reward" / "#default.yaml#"]  # fmt: skip
    for p in leftovers:
        p.write_text("sim: old\n")
    run = tmp_path / "run"
    run.mkdir()
    rec = provenance.write_record(run)
    assert not any("~" in n or "#" in n or n.endswith(".swp") for n in rec["configs"])
    assert not any(p in leftovers for p in _input_files("b_segment", VehicleOptions()))
    assert (configs / "materials.yaml") in _input_files("b_segment", VehicleOptions())
    for p in leftovers:
        p.unlink()
    assert provenance.require_unchanged(run).configs == []  # resumes without refusal
    _touch(configs / "sim.yaml")
    with pytest.raises(ConfigError, match=r"configs/sim\.yaml changed"):  # a real config edit still refuses
        provenance.require_unchanged(run)


def test_merge_and_patch_leftovers_in_configs_are_no_inputs(configs, tmp_path):
    """``git mergetool`` keeps ``sim.yaml.orig`` beside a resolved conflict, ``patch`` leaves ``.orig`` and ``.rej``
    files, and many tools a ``.bak``: the record hashed them as inputs, so cleaning them up refused the resume
    ("configs/sim.yaml.orig removed") though no loader reads one. A real edit still refuses."""
    leftovers = [configs / "sim.yaml.orig", configs / "scenarios" / "full_width_40.yaml.rej",
                 configs / "cells.yaml.bak"]  # fmt: skip
    for p in leftovers:
        p.write_text("sim: old\n")
    run = tmp_path / "run"
    run.mkdir()
    rec = provenance.write_record(run)
    assert not any(n.endswith((".orig", ".rej", ".bak")) for n in rec["configs"])
    for p in leftovers:
        p.unlink()
    assert provenance.require_unchanged(run).configs == []
    _touch(configs / "cells.yaml")
    with pytest.raises(ConfigError, match=r"configs/cells\.yaml changed"):
        provenance.require_unchanged(run)


def test_an_output_record_names_the_command_and_every_input(configs, tmp_path):
    """A command's record (``marlcrash simulate --csv``, ``discretize --save``): the command line as a shell would take
    it back, the configs folder read and every input with its SHA-256, a deck outside ``configs/`` by its path."""
    import hashlib

    deck = tmp_path / "my car.k"
    deck.write_text("*KEYWORD\n*END\n")
    rec = provenance.output_record([deck], ["simulate", str(deck), "--json"])
    assert rec["command"] == f"marlcrash simulate '{deck}' --json" and rec["configs_folder"] == str(configs.resolve())
    assert rec["configs"][str(deck.resolve())] == hashlib.sha256(deck.read_bytes()).hexdigest()
    assert len(rec["configs"]) == len(provenance.config_files()) + 1 and rec["code"]["source_sha256"]
    assert "command" not in provenance.output_record()
    assert provenance.record_path(tmp_path / "crash.csv") == tmp_path / "crash.provenance.json"
