"""Output paths: checked before the work, written whole or not at all (marlcrash.outputs)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from marlcrash.errors import ConfigError
from marlcrash.outputs import atomic_output, check_output_dir, check_output_file, require_run_name

REPO = Path(__file__).resolve().parents[1]


def test_check_output_file_names_the_key(tmp_path):
    assert check_output_file(None, "--csv") is None
    assert check_output_file(tmp_path / "a.csv", "--csv") == tmp_path / "a.csv"
    with pytest.raises(ConfigError, match=r"'--csv'.*is a folder"):
        check_output_file(tmp_path, "--csv")
    with pytest.raises(ConfigError, match=r"'--plot'.*does not exist"):
        check_output_file(tmp_path / "nope" / "a.png", "--plot")


def test_an_output_that_is_a_device_or_a_pipe_is_refused_not_replaced(tmp_path):
    """An output path naming a named pipe or a device (``/dev/null`` to throw a table away) passed the check, and the
    atomic write then renamed its temporary file over it: the pipe (for root, ``/dev/null`` itself) was replaced by a
    regular file. Such a path is refused, naming the key, and left as it was."""
    fifo = tmp_path / "table.csv"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=r"key '--csv': .*table\.csv is not a regular file"):
        check_output_file(fifo, "--csv")
    with pytest.raises(ConfigError, match=r"table\.csv is not a regular file"), atomic_output(fifo) as tmp:
        tmp.write_text("a,b\n")
    assert fifo.is_fifo() and sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"]


def test_check_output_dir_refuses_a_file_on_the_way(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    assert check_output_dir(tmp_path / "new" / "deeper", "out_dir") == tmp_path / "new" / "deeper"
    with pytest.raises(ConfigError, match=r"'out_dir'.*afile is a file; expected a folder"):
        check_output_dir(f, "out_dir")
    with pytest.raises(ConfigError, match=r"afile is a file; so the folder .*runs cannot be created"):
        check_output_dir(f / "runs", "out_dir")


def test_folders_that_cannot_be_written_in_are_refused_before_the_work(tmp_path, monkeypatch):
    import os
    import tempfile

    if os.path.isdir("/proc"):  # a virtual file system: it exists, it is a folder, and nothing can be created there
        with pytest.raises(ConfigError, match=r"'--plot'.*cannot write in the folder /proc"):
            check_output_file("/proc/x.png", "--plot")
        with pytest.raises(ConfigError, match=r"'out_dir'.*cannot write in the folder /proc"):
            check_output_dir("/proc/runs/mappo", "out_dir")

    def denied(*args, **kwargs):  # a folder without write permission (root ignores chmod, so simulate it)
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "NamedTemporaryFile", denied)
    with pytest.raises(ConfigError, match=r"'--csv'.*cannot write in the folder .*\(Permission denied\)"):
        check_output_file(tmp_path / "a.csv", "--csv")
    with pytest.raises(ConfigError, match=r"'out_dir'.*cannot write in the folder"):
        check_output_dir(tmp_path / "new", "out_dir")
    monkeypatch.undo()
    assert check_output_dir(tmp_path / "new", "out_dir") == tmp_path / "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the probes left nothing behind


def test_a_file_name_too_long_for_the_file_system_is_refused_before_the_work(tmp_path):
    """``simulate --csv <250 characters>.csv`` passed the check (the folder takes files) and failed after the
    simulation with "File name too long": the file is written through a temporary sibling whose name is 14 bytes
    longer, so even a name the file system takes (``touch`` makes it) could never be written. The check refuses it
    at once, naming the key and the longest name that can be written there; a name just short enough is written."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    extra = len(".") + len(".01234567.tmp")  # the temporary name's additions (the suffix is the name's own)
    fits = tmp_path / ("a" * (limit - extra - 4) + ".csv")
    for name in ("a" * (limit - 4) + ".csv", "b" * (limit + 10) + ".csv"):
        with pytest.raises(ConfigError, match=rf"key '--csv': .*file name is too long .*at most {limit - extra} bytes"):
            check_output_file(tmp_path / name, "--csv", suffix=".csv")
    assert check_output_file(fits, "--csv", suffix=".csv") == fits
    with atomic_output(fits) as tmp:
        tmp.write_text("a,b\n")
    assert fits.read_text() == "a,b\n" and [p.name for p in tmp_path.iterdir()] == [fits.name]


def test_atomic_output_replaces_whole_or_leaves_the_old_file(tmp_path):
    target = tmp_path / "out.png"
    target.write_text("old")
    with atomic_output(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png" and tmp != target
        tmp.write_text("new")
    assert target.read_text() == "new"
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer failed")
    assert target.read_text() == "new"  # the old file stays, no temporary file is left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]
    with pytest.raises(ConfigError, match="is a folder"), atomic_output(tmp_path, key="--plot"):
        pass


@pytest.mark.skipif(os.name != "posix", reason="symbolic links and permission bits as on POSIX")
def test_atomic_output_writes_through_a_link_and_keeps_the_files_permissions(tmp_path):
    shared, here = tmp_path / "shared", tmp_path / "run"
    shared.mkdir(), here.mkdir()
    target = shared / "pulse.csv"
    target.write_text("old")
    os.chmod(target, 0o640)
    link = here / "pulse.csv"
    link.symlink_to(target)
    with atomic_output(link) as tmp:
        assert tmp.parent == shared  # renamed within the target's folder
        tmp.write_text("new")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text() == "new" and (target.stat().st_mode & 0o777) == 0o640
    assert sorted(p.name for p in shared.iterdir()) == ["pulse.csv"]
    fresh = here / "fresh.csv"  # a new file: 0o666 less the umask, as open() makes it
    umask = os.umask(0o022)
    try:
        with atomic_output(fresh) as tmp:
            tmp.write_text("x")
    finally:
        os.umask(umask)
    assert (fresh.stat().st_mode & 0o777) == 0o644


def test_a_failed_write_names_the_file_asked_for_not_the_temporary_one(tmp_path):
    import errno

    target = tmp_path / "summary.json"
    with (
        pytest.raises(OSError, match=r"cannot write .*summary\.json: No space left") as e,
        atomic_output(target) as tmp,
    ):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert e.value.filename == str(target) and e.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []


def test_the_run_folders_own_parent_is_probed_not_only_out_dir(tmp_path):
    """``<out_dir>/<method>`` may be another user's or unwritable while ``out_dir`` is fine: the baseline spent its
    whole budget and then failed to create its folder (a traceback)."""
    import os

    from test_train_marl import tiny

    from marlcrash.calibrate.baselines import BaselineRunConfig, run_folder
    from marlcrash.calibrate.marl import train

    if not os.path.isdir("/proc"):
        pytest.skip("needs a folder nothing can be created in (/proc)")
    for sub in ("random_search", "mappo"):
        (tmp_path / "runs" / sub).parent.mkdir(exist_ok=True)
        (tmp_path / "runs" / sub).symlink_to("/proc")
    out = str(tmp_path / "runs")
    with pytest.raises(ConfigError, match=r"'out_dir'.*cannot write in the folder .*random_search") as e:
        run_folder(BaselineRunConfig(method="random_search", name="b1", out_dir=out))
    assert e.value.key == "out_dir"
    with pytest.raises(ConfigError, match=r"'out_dir'.*cannot write in the folder .*mappo") as e:
        train(tiny(tmp_path, name="m1"))  # refused before the run folder or any environment is made
    assert e.value.key == "out_dir"
    assert run_folder(BaselineRunConfig(method="cmaes", name="b1", out_dir=out)) == tmp_path / "runs" / "cmaes" / "b1"


@pytest.mark.parametrize(
    ("name", "words"),
    [
        ("", "got an empty one"),
        ("a/b", "without '/' (one folder, not a path)"),
        (".", "names the output folder itself"),
        ("..", "names the output folder's parent"),  # it has no '/': the message must not blame one
    ],
)
def test_a_run_name_must_be_one_new_folder(name, words):
    with pytest.raises(ConfigError, match=re.escape(words)) as e:
        require_run_name(name, "name")
    assert e.value.key == "name" and ("/" in name or "'/'" not in str(e.value))
    require_run_name("..x")


def _strict(text: str):
    """``json.loads`` as a standard parser (jq, JavaScript) reads: NaN and Infinity are no JSON."""
    import json

    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_json_text_is_standard_json_with_non_finite_numbers_as_null():
    """summary.json of a run whose every candidate diverged held ``-Infinity`` (a best score of -inf) or ``NaN``
    (metrics): Python reads it back, jq and JavaScript refuse the whole file."""
    import numpy as np

    from marlcrash.outputs import json_text

    obj = {"a": float("nan"), "b": [float("inf"), -float("inf"), 1.5], "c": {"d": np.float64("nan"), "e": 2},
           "f": (1.0, float("nan")), "g": None, "h": "NaN"}  # fmt: skip
    assert _strict(json_text(obj)) == {"a": None, "b": [None, None, 1.5], "c": {"d": None, "e": 2},
                                       "f": [1.0, None], "g": None, "h": "NaN"}  # fmt: skip


def test_a_runs_summary_is_standard_json(tmp_path):
    from marlcrash.calibrate.evaluate import update_summary

    (tmp_path / "summary.json").write_text('{"best_score": 1.0}')
    update_summary(tmp_path, best_score=float("-inf"), final_metrics={"tunnel": {"area": float("nan")}})
    assert _strict((tmp_path / "summary.json").read_text()) == {
        "best_score": None,
        "final_metrics": {"tunnel": {"area": None}},
    }


def test_atomic_output_flushes_the_file_to_disk_before_it_replaces_the_old_one(tmp_path, monkeypatch):
    """Without an fsync before os.replace, a power cut or system crash soon after can leave the new name pointing at
    a file whose data never reached the disk: an empty summary.json or config.yaml where the old one was whole."""
    import os

    events = []
    fsync, replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (events.append(("fsync", os.fstat(fd).st_size)), fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (events.append(("replace", Path(b).name)), replace(a, b))[1])
    with atomic_output(tmp_path / "summary.json") as tmp:
        tmp.write_text('{"a": 1}')
    assert events == [("fsync", 8), ("replace", "summary.json")]


def test_two_writers_of_one_file_each_write_it_whole(tmp_path):
    """Every writer of a path got the same temporary name (``.summary.tmp.json``), so two writers of one output at
    once (two processes) wrote into one file: the first to finish renamed it into place whatever the other had
    written into it meanwhile, and the other then failed ("cannot write ...: No such file or directory"). Each writer
    has a temporary file of its own now; each replaces the target whole, the last one to finish last."""
    target = tmp_path / "summary.json"
    with atomic_output(target) as first:
        first.write_text('{"first": "a longer text than the second"}')
        with atomic_output(target) as second:
            second.write_text('{"second": 2}')
        assert target.read_text() == '{"second": 2}'
    assert target.read_text() == '{"first": "a longer text than the second"}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
    assert second != first and second.suffix == ".json" and second.name.startswith(".summary.")


def test_text_outputs_and_configs_are_utf8_whatever_the_locale(tmp_path):
    """Files were written and configs read in the locale's encoding, while the log reader (a resume) decodes UTF-8
    and the YAML reader's error says "not UTF-8": under an ASCII locale (``LC_ALL=C`` without UTF-8 mode) the
    comparison tables' "±" stopped the write with a UnicodeEncodeError, a config with "ß" in a comment could not be
    read, and on a cp1252 system a log's non-ASCII column came back as another name on resume. All are UTF-8 now."""
    (tmp_path / "c.yaml").write_bytes("# Stoßfänger: the bumper\nname: Stoßfänger\n".encode())
    script = (
        "import sys; from marlcrash.outputs import write_text; from marlcrash.config import load_yaml;"
        "from marlcrash.calibrate.logging import CSVLogger;"
        f"d = {str(tmp_path)!r};"
        "write_text(d + '/t.md', %s);"
        "assert load_yaml(d + '/c.yaml') == {'name': %s}, load_yaml(d + '/c.yaml');"
        "log = CSVLogger(d); log.log({%s: 1.0}); log.truncate(1); assert CSVLogger(d).columns == [%s]"
    ) % (ascii("-1.84 ± 0.22 †"), ascii("Stoßfänger"), ascii("area_Stoßfänger"), ascii("area_Stoßfänger"))
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, "-X", "utf8=0", "-c", script], cwd=REPO, env=env, capture_output=True)
    assert run.returncode == 0, run.stderr.decode(errors="replace")[-600:]
    assert (tmp_path / "t.md").read_bytes() == "-1.84 ± 0.22 †".encode()
    assert (tmp_path / "log.csv").read_bytes().splitlines()[0] == "area_Stoßfänger".encode()


def test_save_figure_writes_the_format_its_suffix_names_and_closes_the_figure_whatever_happens(tmp_path):
    """One figure writer for every picture (analysis, ablation, crash and pulse plots): the ablation's left its
    figure open when the save failed, and the pulse plot wrote PNG bytes into a file named ``.svg``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from marlcrash.outputs import save_figure

    fig = plt.figure()
    assert save_figure(fig, tmp_path / "picture") == tmp_path / "picture"
    assert (tmp_path / "picture").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not plt.get_fignums()
    save_figure(plt.figure(), tmp_path / "picture.svg")
    assert b"<svg" in (tmp_path / "picture.svg").read_bytes()[:400]
    with pytest.raises(ValueError, match="xyz"):
        save_figure(plt.figure(), tmp_path / "picture.xyz")
    assert not plt.get_fignums() and sorted(p.name for p in tmp_path.iterdir()) == ["picture", "picture.svg"]
