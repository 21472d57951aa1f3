"""Output files and folders: checked before the work, written whole or not at all.

:func:`check_output_file` and :func:`check_output_dir` fail early, with the user's key or option in the message,
where a path can never be written (its folder is missing or not writable, it names a folder, a file stands where
a folder must be). :func:`atomic_output` writes through a temporary sibling that replaces the target only once it
is complete and is removed if writing fails, so an interrupted or failed write leaves neither a partial file nor a
stray one; :func:`sync_folder` puts a folder assembled that way on disk before it is renamed into place.
:func:`read_npz` reads a ``.npz`` file back, saying in words what is wrong with a damaged or foreign one.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import secrets
import stat
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from marlcrash.errors import ConfigError


def check_output_file(
    path: str | Path | None,
    key: str | None,
    *,
    suffix: str | None = None,
    inputs: tuple[str | Path | None, ...] = (),
) -> Path | None:
    """Raise :class:`ConfigError` (naming ``key``, if given) unless ``path`` can be written as a file (``None`` passes).

    The folder must exist and take a new file (it is not created for a single output file: a typo should not
    create folders); an existing ``path`` must be a regular file (a device or pipe would be replaced by one).
    With ``suffix`` (e.g. ``".png"``) the name must end in it (the file is written in that format); a path
    that is one of ``inputs`` (the files the command reads or writes otherwise) is refused, so an output
    never replaces them.
    """
    if path is None:
        return None
    p = Path(path)
    if isinstance(path, str) and path.endswith(("/", os.sep)):  # Path drops it: 'results/' was written as a file
        raise ConfigError(f"{path} ends in '/', so names a folder; expected a file name", key=key)
    _check_name_length(p, key)  # first: a name the file system refuses fails even p.is_dir()
    if p.is_dir():
        raise ConfigError(f"{p} is a folder; expected a file name", key=key)
    if p.exists() and not p.is_file():  # a pipe, a device: the atomic write would rename a regular file over it
        raise ConfigError(f"{p} is not a regular file (a device or a pipe); expected a file name", key=key)
    if not p.parent.is_dir():
        raise ConfigError(f"the folder of {p} does not exist", key=key)
    for other in inputs:
        if other is not None and p.resolve() == Path(other).resolve():
            raise ConfigError(f"{p} is also {other!s} of this command; choose another file name", key=key)
    if suffix is not None and p.suffix.lower() != suffix:
        raise ConfigError(f"{p}: expected a {suffix} file name (it is written in that format)", key=key)
    _check_writable(p.parent, key)
    return p


def _check_name_length(p: Path, key: str | None) -> None:
    """Raise :class:`ConfigError` where ``p``'s name, or the name of the temporary sibling :func:`atomic_output`
    writes it through (:func:`_temporary_name`, 14 bytes longer), is longer than its folder's file system takes: that
    failed with "File name too long" after the work, even for a name the file system takes."""
    try:
        limit = os.pathconf(p.parent, "PC_NAME_MAX")
    except (AttributeError, OSError, ValueError):  # no pathconf (Windows), or the folder does not say
        return
    extra = len(os.fsencode(_temporary_name(p.name, "0" * 8))) - len(os.fsencode(p.name))
    size = len(os.fsencode(p.name))
    if size + extra > limit:
        raise ConfigError(f"{p}: the file name is too long for its folder's file system: {size} bytes, at most "
                          f"{limit - extra} bytes here (it is written through a temporary file whose name is {extra} "
                          "bytes longer)", key=key)  # fmt: skip


def _check_writable(folder: Path, key: str | None) -> None:
    """Raise :class:`ConfigError` unless a file can be created in the existing ``folder`` (a probe, removed at once):
    no permission, a read-only or virtual file system (``/proc``) show up now, not after the work."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".marlcrash-probe-"):
            pass
    except OSError as e:
        raise ConfigError(f"cannot write in the folder {folder} ({e.strerror or e})", key=key) from None


def check_output_dir(path: str | Path, key: str) -> Path:
    """Raise :class:`ConfigError` naming ``key`` if ``path`` or one of its existing ancestors is not a folder, or
    nothing can be created in the nearest existing one."""
    p = Path(path)
    for q in (p, *p.parents):
        if q.exists():
            if not q.is_dir():
                why = "expected a folder" if q == p else f"so the folder {p} cannot be created"
                raise ConfigError(f"{q} is a file; {why}", key=key)
            _check_writable(q, key)
            break
    return p


def require_run_name(name: str, key: str = "name") -> None:
    """Refuse, naming ``key`` (relative, for a schema's ``validate()``), a run folder name that is not one new
    folder inside the output folder: empty, a path (with ``/``), or ``.`` or ``..`` (the output folder itself, its
    parent)."""
    if not name:
        raise ConfigError("expected a run folder name, got an empty one", key=key)
    if "/" in name:
        raise ConfigError(f"expected a run folder name without '/' (one folder, not a path), got {name!r}", key=key)
    if name in (".", ".."):
        where = "the output folder itself" if name == "." else "the output folder's parent"
        raise ConfigError(f"expected a run folder name, got {name!r}, which names {where}, not a folder in it",
                          key=key)  # fmt: skip


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, inf) in its dicts, lists and tuples replaced by ``None``: standard
    JSON has no such numbers, and a value that could not be computed reads as ``null``."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_or_null(v) for v in obj]
    return obj


def json_text(obj: Any, indent: int | None = 2) -> str:
    """``obj`` as standard JSON (:func:`finite_or_null`): ``json.dumps`` writes NaN and Infinity, which jq,
    JavaScript and most parsers other than Python's refuse, so one diverged number made a whole file unreadable."""
    return json.dumps(finite_or_null(obj), indent=indent, allow_nan=False)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through :func:`atomic_output` (whole or not at all)."""
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(fig: Any, path: str | Path, key: str | None = None, dpi: float | str = 110) -> Path:
    """Save a matplotlib ``fig`` to ``path`` through :func:`atomic_output` (``key`` as there), in the format its
    suffix names (where it has none, matplotlib's ``savefig.format``: PNG), and close it, saved or not.

    The format is passed: the temporary file's name ends in ``.tmp`` where ``path`` has no suffix, which matplotlib
    would read as the format.
    """
    import matplotlib.pyplot as plt

    try:
        fmt = Path(path).suffix[1:].lower() or plt.rcParams["savefig.format"]
        with atomic_output(path, key=key) as tmp:
            fig.savefig(tmp, dpi=dpi, format=fmt)
    finally:
        plt.close(fig)
    return Path(path)


@contextmanager
def atomic_output(path: str | Path, key: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is flushed to disk and replaces ``path``, on failure it
    is removed.

    The temporary name keeps ``path``'s suffix (``.name.<8 hex>.tmp.png``), so writers that pick a format by suffix
    (matplotlib) see the right one. It is created empty here (``0o666`` less the umask) under a name no other writer
    has: with one name per path, two writers of one output at once wrote into one file, and the first to finish
    renamed the other's partial writing into place.

    Where ``path`` is a symbolic link, the file it points at is replaced (the temporary file lies beside that one),
    not the link; where ``path`` exists, the new file takes its permissions. A link to shared storage was replaced by
    a local file, and a file a group could read came back readable by its owner alone.

    Raises:
        ConfigError: ``path`` cannot be written (see :func:`check_output_file`); the message names the path
            (and ``key``, if given).
        OSError: writing failed (disk full, no permission); its ``filename`` is ``path``, not the temporary file.
    """
    final = check_output_file(path, key)
    if final is None:  # check_output_file lets None pass (an output not asked for); here one was
        raise TypeError(f"expected an output path{f' for {key}' if key else ''}, got None")
    if final.is_symlink():
        final = final.resolve()  # the file the link points at is the output; the link stays
    tmp = _new_sibling(final)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:  # on disk before the name points at it: a system crash leaves old or new
            os.fsync(fh.fileno())
        _keep_mode(tmp, final)
        os.replace(tmp, final)
    except OSError as e:  # disk full, no permission: name the file the user asked for, not the temporary one
        err = write_error(e, final, tmp)
        if err is e:
            raise
        raise err from e
    finally:
        tmp.unlink(missing_ok=True)


def _keep_mode(tmp: Path, final: Path) -> None:
    """Give ``tmp`` the permission bits of ``final``, where ``final`` exists (:func:`atomic_output`)."""
    try:
        mode = stat.S_IMODE(final.stat().st_mode)
    except FileNotFoundError:
        return
    os.chmod(tmp, mode)


def write_error(e: OSError, final: Path, tmp: Path) -> OSError:
    """The error to raise for ``e``, raised while ``final`` was written through its temporary sibling ``tmp``: one
    naming ``final`` (``cannot write <final>: <reason>``, ``filename`` and ``errno`` as ``e``'s) where ``e`` names no
    file or the temporary one; ``e`` itself where it names another file."""
    if e.filename is not None and Path(e.filename) != tmp:
        return e
    if e.errno is None:
        err = OSError(f"cannot write {final}: {e}")
        err.filename = str(final)
        return err
    return OSError(e.errno, f"cannot write {final}: {e.strerror or e}", str(final))


def new_sibling(target: Path, name: Callable[[str], str], create: Callable[[Path], bool]) -> Path:
    """A new hidden temporary entry beside ``target`` that no other writer has: the first of up to 100 random names
    ``name(token)`` (``token``: 8 hex digits) that ``create`` makes, in one step that fails where the name exists
    (``create`` returns False where it is taken, True where it made it).

    :func:`atomic_output` makes an empty file with it, ``write_run`` of the baselines a folder.

    Raises:
        FileExistsError: every name tried was taken; the message and ``filename`` name ``target``.
        OSError: what ``create`` raises.
    """
    for _ in range(100):
        tmp = target.with_name(name(secrets.token_hex(4)))
        if create(tmp):
            return tmp
    raise FileExistsError(errno.EEXIST, f"cannot write {target}: no free temporary name beside it", str(target))


def _new_sibling(final: Path) -> Path:
    """Create an empty, hidden temporary file beside ``final`` that no other writer has (:func:`atomic_output`).

    Raises:
        OSError: it cannot be created; the message and ``filename`` name ``final``.
    """

    def create(tmp: Path) -> bool:
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            return False
        except OSError as e:
            raise OSError(e.errno, f"cannot write {final}: {e.strerror or e}", str(final)) from e
        return True

    return new_sibling(final, lambda token: _temporary_name(final.name, token), create)


def _temporary_name(name: str, token: str) -> str:
    """The name :func:`atomic_output` gives the temporary file of an output named ``name``: ``.<stem>.<token>.tmp``
    and ``name``'s suffix."""
    p = Path(name)
    return f".{p.stem}.{token}.tmp{p.suffix}"


def is_temporary_of(name: str, output: str) -> bool:
    """Whether ``name`` is the name of a temporary file of :func:`atomic_output` writing the file named ``output``
    (``.<stem>.<8 hex digits>.tmp<suffix>``; a kill during the write leaves it)."""
    head, tail = _temporary_name(output, "\0").split("\0")  # no file name holds a NUL
    return re.fullmatch(f"{re.escape(head)}[0-9a-f]{{8}}{re.escape(tail)}", name) is not None


def remove_temporaries_of(folder: str | Path, outputs: Iterable[str]) -> list[Path]:
    """Remove the temporary files :func:`atomic_output` left in ``folder`` writing the files named ``outputs`` (a kill
    during the write leaves them; :func:`is_temporary_of`); return them.

    Call this only while holding ``folder`` (:func:`marlcrash.calibrate.runlock.run_lock`), with ``outputs`` the files
    only the process holding it writes: the temporaries of other files there may be another process's, being written.
    """
    folder, outputs = Path(folder), tuple(outputs)
    removed = []
    if folder.is_dir():
        for p in folder.iterdir():
            if any(is_temporary_of(p.name, o) for o in outputs) and p.is_file() and not p.is_symlink():
                p.unlink(missing_ok=True)
                removed.append(p)
    return removed


def sync_folder(folder: str | Path, files: bool = True) -> None:
    """Flush ``folder``'s own entries to disk and, with ``files``, every file directly in it first: before a folder
    assembled beside its final name is renamed there (a system crash after the rename then leaves the old state or
    the whole new folder, never empty files), and after, on its parent (the rename itself).

    A file system that cannot flush a folder (``EINVAL``, ``ENOTSUP``: some network and virtual ones) is skipped.
    """
    folder = Path(folder)
    if files:
        for p in sorted(folder.iterdir()):
            if p.is_file() and not p.is_symlink():
                with open(p, "rb") as fh:
                    os.fsync(fh.fileno())
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as e:
        if e.errno not in (errno.EINVAL, errno.ENOTSUP):
            raise
    finally:
        os.close(fd)


ZIP_STARTS = (b"PK\x03\x04", b"PK\x05\x06")
"""How a zip archive begins: its first member, or an empty archive (``.npz`` files, ``torch.save``'s files)."""


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of a ``.npz`` file, all read now (a damaged member shows here, not later), none of objects.

    Raises:
        ValueError: what is wrong, in words (callers add the file and their error type): it cannot be read, is
            empty, is not a zip archive, is cut short or damaged, or holds something other than numeric arrays.
            Never numpy's advice to unpickle a file that is junk.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as e:
        raise ValueError(f"cannot read it ({e.strerror or e})") from None
    if not head:
        raise ValueError("the file is empty")
    if head not in ZIP_STARTS:  # numpy would try it as a pickle, and say so
        raise ValueError("not a .npz archive (it does not begin as a zip file does)")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as e:  # zipfile, zlib, numpy's header parser: all say "damaged" in their own words
        if "pickle" in str(e):
            raise ValueError("an array holds Python objects; expected numeric arrays") from None
        raise ValueError(f"a damaged .npz archive, cut short or overwritten ({type(e).__name__}: {e})") from None
    for k, v in arrays.items():
        if not isinstance(v, np.ndarray) or not (np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_):
            raise ValueError(f"member {k!r} is not a numeric array")
    return arrays
