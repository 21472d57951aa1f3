"""Atomic checkpoints of training runs, and the random-generator state they must carry (DESIGN 8).

A checkpoint is one ``torch.save`` file holding everything a resumed run needs to
continue *bit-for-bit* like an uninterrupted one: network and optimizer state, the
iteration and budget counters, the logger position, and every random generator that
the next iteration draws from (torch's global generator -- action sampling and
minibatch order -- and the environment core's own numpy generator -- scenarios and
twin references). Every training iteration starts from freshly reset episodes
(:func:`marlcrash.calibrate.marl.collect`), so no half-finished episode has to be saved.

Writes are atomic: the file is written to a temporary sibling, flushed, and moved into
place with :func:`os.replace`, so a run killed at any moment leaves either the previous
checkpoint or the new one, never a torn file.
"""

from __future__ import annotations

import math
import os
import re
import secrets
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from marlcrash.errors import ConfigError
from marlcrash.outputs import ZIP_STARTS, remove_temporaries_of, write_error

CHECKPOINT_FILE = "checkpoint.pt"
"""Name of the latest checkpoint inside a run folder."""
SNAPSHOT_DIR = "checkpoints"
"""Folder of a run that keeps a copy of the checkpoint every ``snapshot_every`` iterations."""


def snapshot_path(run_dir: str | Path, iteration: int) -> Path:
    """``<run_dir>/checkpoints/iter_<iteration, 5 digits>.pt``: the kept checkpoint after ``iteration``."""
    return Path(run_dir) / SNAPSHOT_DIR / f"iter_{int(iteration):05d}.pt"


def kept_snapshots(run_dir: str | Path) -> list[Path]:
    """The kept snapshots of a run (``checkpoints/iter_<n>.pt``), in iteration order (by name, iteration 100000 came
    before 20000); files of that pattern without a number last."""

    def iteration(p: Path) -> tuple[float, str]:
        n = p.stem.removeprefix("iter_")
        return (int(n) if n.isdecimal() and n.isascii() else math.inf, p.name)

    return sorted((Path(run_dir) / SNAPSHOT_DIR).glob("iter_*.pt"), key=iteration)


def find_checkpoint(run_dir: str | Path, which: str | int | None = None) -> Path:
    """The checkpoint file of a run that ``which`` names.

    Args:
        run_dir: the run folder.
        which: ``None`` or ``"latest"``: ``checkpoint.pt``; an iteration number: its kept snapshot
            (:func:`snapshot_path`); else a file path, as given or relative to ``run_dir``.

    Raises:
        ConfigError: no such file (key ``checkpoint``; the message lists the kept snapshots).
    """
    run_dir = Path(run_dir)
    if which is None or which == "latest":
        path = run_dir / CHECKPOINT_FILE
    elif isinstance(which, int) or (isinstance(which, str) and which.isdecimal()):
        path = snapshot_path(run_dir, int(which))
    else:
        path = Path(which) if Path(which).is_file() else run_dir / which
    if not path.is_file():
        kept = [p.name for p in kept_snapshots(run_dir)]
        raise ConfigError(
            f"no checkpoint {path}; expected 'latest', an iteration with a kept snapshot "
            f"({', '.join(kept) if kept else f'none in {run_dir / SNAPSHOT_DIR}'}) or a checkpoint file",
            key="checkpoint",
        )
    return path


def rng_state(env_rng: np.random.Generator) -> dict[str, Any]:
    """Snapshot of torch's global CPU generator, its CUDA generators (where CUDA is in use: a policy on the GPU
    samples its actions there) and the environment's numpy generator."""
    state = {"torch": torch.get_rng_state(), "env": env_rng.bit_generator.state}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng(state: dict[str, Any], env_rng: np.random.Generator) -> None:
    """Restore a :func:`rng_state` snapshot in place (the env generator object is kept).

    Raises:
        ConfigError: (key ``resume``) the snapshot holds CUDA generators and this machine has no CUDA device, so
            the resumed run could not draw the numbers the uninterrupted one would have.
    """
    torch.set_rng_state(state["torch"])
    env_rng.bit_generator.state = state["env"]
    cuda = state.get("cuda")
    if cuda:
        if not torch.cuda.is_available():
            raise ConfigError(
                "the checkpoint was written with CUDA in use and this machine has no CUDA device, so the run "
                "cannot continue bit for bit",
                key="resume",
            )
        for i, s in enumerate(cuda[: torch.cuda.device_count()]):  # the devices a run uses are the first ones
            torch.cuda.set_rng_state(s, i)


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` atomically (temporary sibling, fsync, :func:`os.replace`).

    The file gets the permissions of every other file of a run (``0o666`` less the umask): ``tempfile.mkstemp``
    made it ``0o600``, so nobody else could evaluate a run whose results they could read.

    Args:
        path: destination file.
        state: anything ``torch.save`` accepts (state dicts, tensors, plain data).

    Returns:
        The path written.

    Raises:
        OSError: the write failed (disk full, no permission); the message and ``filename`` name ``path``, not the
            temporary file (:func:`marlcrash.outputs.write_error`). The old checkpoint stays.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = _create_sibling(path)
    except OSError as e:
        raise write_error(e, path, Path(e.filename or path)) from e  # it names the temporary file or none
    try:
        with os.fdopen(fd, "wb") as fh:
            torch.save(state, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError) and (err := write_error(e, path, Path(tmp))) is not e:
            raise err from e  # disk full, no permission: the checkpoint named, not the temporary file or none
        raise
    return path


def _create_sibling(path: Path) -> tuple[int, str]:
    """Create a new temporary file beside ``path`` (a name no other writer has) with mode ``0o666`` as the umask
    allows, as ``open`` creates files; return its descriptor and name."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), str(tmp)
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name beside {path}")


_TEMPORARY = re.compile(r"\..+\.[0-9a-f]{8}\.tmp")
"""Names :func:`_create_sibling` gives the temporary files of :func:`save_checkpoint`: ``.<name>.<8 hex>.tmp``."""


def remove_stale_temporaries(run_dir: str | Path, outputs: Iterable[str] = ()) -> list[Path]:
    """Remove the temporary files of checkpoint writes that a kill interrupted, and those of the files named
    ``outputs`` in ``run_dir`` (written through :func:`marlcrash.outputs.atomic_output`); return them.

    A run killed while it wrote ``checkpoint.pt`` or a kept snapshot left ``.checkpoint.pt.<8 hex>.tmp`` (or
    ``checkpoints/.iter_<n>.pt.<8 hex>.tmp``), a whole checkpoint's size, which nothing else ever removes; one killed
    while it wrote ``log.csv`` left ``.log.<8 hex>.tmp.csv``. Call this only while holding the run folder's lock
    (:func:`marlcrash.calibrate.runlock.run_lock`), with ``outputs`` the files only the process holding it writes:
    the temporaries of other files there may be another process's (a user's output written into the run folder).
    """
    removed = remove_temporaries_of(run_dir, outputs)
    for folder in (Path(run_dir), Path(run_dir) / SNAPSHOT_DIR):
        if not folder.is_dir():
            continue
        for p in folder.iterdir():
            if _TEMPORARY.fullmatch(p.name) and p.is_file() and not p.is_symlink():
                p.unlink(missing_ok=True)
                removed.append(p)
    return removed


TRAINING_KEYS = ("policy", "critic", "optimizer", "rng", "iteration", "env_steps", "simulations", "wall_time_s")
"""Entries every training checkpoint holds (:meth:`marlcrash.calibrate.marl.Trainer.state_dict`)."""


def load_checkpoint(path: str | Path, key: str = "resume") -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Args:
        path: the checkpoint file.
        key: the config key that named it, for the error messages (``resume`` or ``checkpoint``).

    The file is read with torch's weights-only unpickler: a checkpoint holds tensors and plain data only, and a file
    from elsewhere (``checkpoint=<file>``) must not run the code a full unpickling would.

    Raises:
        ConfigError: the file is missing, unreadable (empty, not a checkpoint, damaged: said in words), or holds
            other objects.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no checkpoint at {path}; expected a run folder with {CHECKPOINT_FILE}", key=key)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a torn or foreign file: say which and why, in words
        raise ConfigError(f"cannot read checkpoint {path}: {_what_is_wrong(path, e)}", key=key) from None


def _what_is_wrong(path: Path, error: Exception) -> str:
    """What is wrong with a file ``torch.load`` refused (``error``), in words and without torch's advice (to load it
    with ``weights_only=False``, which is not for a foreign file) or internals: torch said nothing for an empty file,
    and for one cut short '[Errno 22] Invalid argument' or its zip reader's 'failed finding central directory. This is
    an internal miniz error...'; a text file got the advice."""
    import pickle

    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as e:
        return f"cannot read it ({e.strerror or e})"
    if not head:
        return "the file is empty"
    foreign = "not a checkpoint: it does not begin as torch.save's files do; expected a checkpoint written by marlcrash"
    if head not in ZIP_STARTS and not head.startswith(b"\x80"):  # torch.save's zip archive, an older torch's pickle
        return foreign
    if isinstance(error, pickle.UnpicklingError):  # the weights-only unpickler met an object it does not build
        what = str(error).strip().splitlines()
        found = next((line.strip() for line in what if "Unsupported global" in line), what[0] if what else "")
        found = found.split(" Please use")[0]  # not torch's advice to allow the object's class
        return (
            f"it holds objects other than tensors and plain data ({found}); expected a checkpoint written by marlcrash"
        )
    if head not in ZIP_STARTS:  # a pickle that torch cannot read
        return foreign
    return "damaged, cut short or overwritten (or a zip archive that torch.save did not write)"


def load_training_checkpoint(path: str | Path, key: str = "resume") -> dict[str, Any]:
    """:func:`load_checkpoint`, checked to be a training run's (it holds every entry of :data:`TRAINING_KEYS`).

    Raises:
        ConfigError: as :func:`load_checkpoint`, or the file is another kind of checkpoint (a baseline's
            ``best.pt``, say): the message names the file and the entries it lacks.
    """
    state = load_checkpoint(path, key=key)
    missing = [k for k in TRAINING_KEYS if not isinstance(state, dict) or k not in state]
    if missing:
        raise ConfigError(
            f"{path} is not a training checkpoint (no {', '.join(missing)}); expected a {CHECKPOINT_FILE} or "
            f"{SNAPSHOT_DIR}/iter_<n>.pt written by train/train.py",
            key=key,
        )
    return state
