"""One process per run folder: the folder of a fresh run is created exclusively, and a run holds a lock on it.

Two processes writing one run folder would interleave their checkpoints, logs and results, and whichever wrote
last would silently decide what the folder holds. That happens with two resumes of one run (a second terminal, a
requeued cluster job whose first start still runs), and with two fresh runs given the same name at the same
moment (a parallel Hydra launcher; the default name is the launch second). So:

- :func:`claim_dir` creates a fresh run's folder with one ``mkdir`` that fails where the folder exists, instead of
  testing first and creating later;
- :func:`run_lock` holds an exclusive advisory lock (``flock``) on ``<run folder>/.lock`` while the run writes,
  and removes the file when it ends. The operating system drops the lock when the process ends, killed or not, so
  a crashed run never blocks its own resume (its file stays, unlocked). The file records the holder's process id
  for the message. On Windows, where there is no ``flock``, the lock is ``msvcrt.locking`` on one byte of the file
  (away from the process id: a Windows lock also bars reads of what it covers), which Windows drops with the
  process too; the file is removed after the lock is released (Windows does not remove an open file, so a waiting
  process that opened it keeps it).
"""

from __future__ import annotations

import contextlib
import importlib
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import ModuleType

from marlcrash.errors import ConfigError


def _module(name: str) -> ModuleType | None:
    """The standard-library module ``name`` where this platform has it (``fcntl``: POSIX; ``msvcrt``: Windows)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


fcntl = _module("fcntl")
msvcrt = _module("msvcrt")

_WINDOWS_LOCK_OFFSET = 1 << 20
"""The byte ``msvcrt.locking`` locks: away from the process id at the start of the file, which others must read."""

LOCK_FILE = ".lock"
"""The lock file inside a run folder while a run writes it (left unlocked by a killed run: nobody writes it)."""

__all__ = ["LOCK_FILE", "claim_dir", "hold_output_dir", "run_lock"]


def claim_dir(path: str | Path) -> bool:
    """Create ``path`` (and its missing parents) unless it exists; True when this call created it.

    The creation and the test are one step, so of two processes claiming one folder exactly one gets True.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        path.mkdir()
    except FileExistsError:
        return False
    return True


@contextlib.contextmanager
def run_lock(run_dir: str | Path, key: str, create: bool = False, name: str = LOCK_FILE) -> Iterator[Path]:
    """Hold the run folder's lock for the ``with`` block; yields the folder.

    Args:
        run_dir: the run folder.
        key: the config key that chose the folder, named in the error (``name``, ``resume``, ...).
        create: make the folder (and its parents) where it is missing. Otherwise a missing folder is left to the
            caller to report, and the block runs without a lock (there is nothing in it to protect).
        name: the lock file's name (:data:`LOCK_FILE`; another one for a writer beside the run, such as the
            amortized comparison, which may write into the folder of a run that still trains).

    Raises:
        ConfigError: another process holds the lock (with its process id), or the folder takes no lock file (read
            only: no permission, a read-only file system), before anything is written.
    """
    run_dir = Path(run_dir)
    if create:
        run_dir.mkdir(parents=True, exist_ok=True)
    if (fcntl is None and msvcrt is None) or not run_dir.is_dir():  # no lock; or a missing folder, for the caller
        yield run_dir
        return
    path = run_dir / name
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_BINARY", 0), 0o644)  # Windows: untranslated
        except OSError as e:  # a read-only file system or folder: said as such, not as a traceback
            raise ConfigError(
                f"cannot write in the run folder {run_dir} ({e.strerror or e}); expected a folder this process may "
                f"write in (its lock file {name} and the results go there)",
                key=key,
            ) from None
        if not _try_lock(fd):
            os.lseek(fd, 0, os.SEEK_SET)
            holder = os.read(fd, 32).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise ConfigError(
                f"run folder {run_dir} is in use by another process (pid {holder}); wait for it to end or stop it",
                key=key,
            )
        try:  # the holder before may have removed the file between our open and our lock: lock the one there is
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        _unlock(fd)
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield run_dir
    finally:
        if fcntl is not None:
            with contextlib.suppress(FileNotFoundError):  # the run removed its folder (a fresh run that failed)
                path.unlink()  # while still locked, so the folder is left as the run wrote it
            os.close(fd)  # releases the lock
        else:  # Windows removes no open file: release, close, then remove it unless a waiting process opened it
            _unlock(fd)
            os.close(fd)
            with contextlib.suppress(OSError):
                path.unlink()


@contextlib.contextmanager
def hold_output_dir(
    out_dir: str | Path, key: str, name: str, outputs: Iterable[str], create: bool = True
) -> Iterator[Path]:
    """One writer of ``outputs`` per folder: hold ``out_dir``'s lock file ``name`` for the ``with`` block (made with its
    missing parents where missing with ``create``, and those removed again if the block fails leaving them empty);
    yields the folder.

    For a tool that writes its files beside others' (a run's, or the working folder): two of them into one folder
    at once would each pass a check for earlier results before either wrote, then replace each other's files. The
    temporary files a kill left writing ``outputs`` are removed here
    (:func:`~marlcrash.outputs.remove_temporaries_of`).

    Raises:
        ConfigError: (key ``key``) another process holds the folder (with its process id), or it takes no lock file.
    """
    from marlcrash.outputs import remove_temporaries_of

    out = Path(out_dir)
    made = [q for q in (out, *out.parents) if not q.exists()] if create else []  # the deepest first
    try:
        with run_lock(out, key, create=create, name=name):
            remove_temporaries_of(out, outputs)
            yield out
    except BaseException:
        for q in made:  # a refused or failed writer leaves no empty folder behind (nor the parents it made)
            try:
                q.rmdir()
            except OSError:  # not empty: what it holds stays, and so do the folders around it
                break
        raise


def _try_lock(fd: int) -> bool:
    """Take the exclusive lock on the open file ``fd`` without waiting; False where another holds it."""
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        return True
    assert msvcrt is not None  # run_lock takes no lock where neither module is there
    os.lseek(fd, _WINDOWS_LOCK_OFFSET, os.SEEK_SET)
    try:
        msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
    except OSError:  # "Permission denied" while another handle holds the byte
        return False
    return True


def _unlock(fd: int) -> None:
    """Release :func:`_try_lock`'s lock (closing the file releases it too)."""
    if fcntl is not None:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return
    assert msvcrt is not None  # run_lock takes no lock where neither module is there
    os.lseek(fd, _WINDOWS_LOCK_OFFSET, os.SEEK_SET)
    msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
