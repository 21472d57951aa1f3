"""One process per run folder: exclusive creation, the run lock, and what the writers do with them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from marlcrash.calibrate import runlock
from marlcrash.calibrate.runlock import LOCK_FILE, claim_dir, run_lock
from marlcrash.errors import ConfigError

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="these tests kill with SIGKILL and emulate with flock")

# Windows' lock, emulated: msvcrt.locking's contract on a POSIX machine, a whole-file flock standing for the one
# byte locked. runlock takes its Windows branch (no fcntl, this msvcrt) in this process and in the children.
EMULATED_MSVCRT = """
import errno, fcntl, os
class EmulatedMsvcrt:
    LK_UNLCK, LK_NBLCK = 0, 2
    locked = []
    @classmethod
    def locking(cls, fd, mode, nbytes):
        cls.locked.append((os.lseek(fd, 0, os.SEEK_CUR), mode, nbytes))
        if mode == cls.LK_UNLCK:
            fcntl.flock(fd, fcntl.LOCK_UN)
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise PermissionError(errno.EACCES, "Permission denied") from None
from marlcrash.calibrate import runlock
runlock.fcntl, runlock.msvcrt = None, EmulatedMsvcrt
"""


@pytest.fixture(params=["flock", "windows"])
def lock_setup(request, monkeypatch):
    """The code a child runs first to take the lock the same way (``""`` for flock)."""
    if request.param == "flock":
        return ""
    monkeypatch.setattr(runlock, "fcntl", runlock.fcntl)  # restored after the test
    monkeypatch.setattr(runlock, "msvcrt", runlock.msvcrt)
    exec(EMULATED_MSVCRT, {})
    return EMULATED_MSVCRT


def test_claim_creates_once_with_parents(tmp_path):
    folder = tmp_path / "runs" / "mappo" / "a"
    assert claim_dir(folder) and folder.is_dir()
    assert not claim_dir(folder)


def test_a_second_holder_is_refused_with_the_first_ones_pid_and_the_key(tmp_path, lock_setup):
    with run_lock(tmp_path, "resume"):
        with pytest.raises(ConfigError) as e, run_lock(tmp_path, "resume"):
            pass
        assert e.value.key == "resume"
        assert f"{tmp_path} is in use by another process (pid {os.getpid()})" in str(e.value)
    with run_lock(tmp_path, "resume"):  # released at the end of the block
        pass


def test_a_killed_holder_leaves_no_lock_behind(tmp_path, lock_setup):
    code = lock_setup + (
        "import sys, time\nfrom marlcrash.calibrate.runlock import run_lock\n"
        "with run_lock(sys.argv[1], 'name'):\n    print('held', flush=True)\n    time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match=f"pid {proc.pid}"), run_lock(tmp_path, "name"):
            pass
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    deadline = time.monotonic() + 10
    while True:  # the kernel drops the lock with the process
        try:
            with run_lock(tmp_path, "name"):
                assert (tmp_path / LOCK_FILE).read_text() == f"{os.getpid()}\n"
                break
        except ConfigError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    assert not (tmp_path / LOCK_FILE).exists()  # removed by the holder that ends normally


def test_a_missing_folder_is_left_to_the_caller_unless_created(tmp_path, lock_setup):
    with run_lock(tmp_path / "gone", "resume") as d:
        assert not d.exists()
    with run_lock(tmp_path / "new" / "run", "name", create=True) as d:
        assert (d / LOCK_FILE).is_file()


def test_a_folder_the_lock_cannot_be_written_in_is_named_with_the_key(tmp_path, monkeypatch):
    """A run folder on a read-only file system, or without write permission (an archived or a colleague's run,
    resumed or evaluated): creating its lock file raised a bare PermissionError naming ``.lock``, a traceback from
    train.py and evaluate.py, which report only marlcrash's errors."""
    real_open = os.open

    def read_only(path, *args, **kwargs):  # root ignores chmod: simulate the folder that refuses a new file
        if os.fspath(path).endswith(LOCK_FILE):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    said = rf"cannot write in the run folder {tmp_path} \(Permission denied\)"
    with pytest.raises(ConfigError, match=said) as e, run_lock(tmp_path, "resume"):
        pass
    assert e.value.key == "resume"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("lock_setup", ["windows"], indirect=True)
def test_the_windows_lock_is_one_byte_past_the_pid(tmp_path, lock_setup):
    """On Windows a locked byte cannot be read by others, so the lock sits past the pid the refusal message reads;
    it is released before the file is removed (Windows removes no open file)."""
    lk = runlock.msvcrt
    lk.locked.clear()
    with run_lock(tmp_path, "name"):
        assert (tmp_path / LOCK_FILE).read_text() == f"{os.getpid()}\n"
    off = runlock._WINDOWS_LOCK_OFFSET
    assert off > 32 and lk.locked == [(off, lk.LK_NBLCK, 1), (off, lk.LK_UNLCK, 1)]
    assert not (tmp_path / LOCK_FILE).exists()
