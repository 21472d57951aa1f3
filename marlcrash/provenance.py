"""Provenance of a run folder: which configs and which code produced its numbers.

A run folder keeps its own resolved training config (``config.yaml``), but the simulator and the
environments read the rest at run time from ``configs/``: the env config, ``sim.yaml``, ``cells.yaml``,
``materials.yaml``, the vehicle, the scenarios, the reward forms and measured reference pulses. A run
resumed or evaluated after one of them changed would silently mix two physics. So every run folder
gets ``provenance.json`` when it starts: the SHA-256 of every file under ``configs/`` except ``configs/train/``
(saved resolved in the run) and an editor's leftovers (``sim.yaml~``, ``#sim.yaml#``, ``sim.yaml.orig``, hidden
files), of an env config, vehicle deck or reference pulse named by a path outside ``configs/`` (with a deck's
``*INCLUDE`` files, an ISO-MME test's channel files), of the package's source and of the
``train/`` entry scripts beside it (plus the git commit where there is one), and the versions of Python and of the
libraries that make the numbers (torch, numpy, cma, numba).

:func:`check_run` compares a run folder's record with the files now:

- changed, added or removed config files (``kind="configs"``): a resume refuses them, naming the
  files; an evaluation warns and reports them in its summary;
- changed code (``kind="code"``: the package's source, a ``train/`` script, or the version of Python or of one of
  those libraries): always a warning, because a resumed run is still that run's training (but no longer
  bit-identical to an uninterrupted one).

A vehicle deck (its sub-assembly map, an env config file) named by a relative path is read from the working
directory, by the run (``chdir: false``) and by the record alike, which keeps that directory (``cwd``): a resume or
evaluation started in another folder reads another file (or none), and the check names the relative path, the file
then and now, and where to start the run. A measured reference pulse named by a relative path is read from
``configs/`` wherever the run starts (:func:`env_inputs`).

A folder without a record (written before this module existed) is resumed and evaluated with a warning; a record
written before the ``train/`` scripts were hashed is compared on what it holds.
Deleting a run's ``provenance.json`` is how to resume it anyway after a deliberate config change.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import shlex
import subprocess
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from marlcrash.config import config_dir
from marlcrash.errors import ConfigError

log = logging.getLogger(__name__)

PROVENANCE_FILE = "provenance.json"
"""The record in a run folder."""

_SKIPPED_DIRS = ("train",)
"""Folders of ``configs/`` that runs save resolved themselves (their own ``config.yaml`` / ``config`` record)."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def config_digests(extra: Iterable[str | Path] = ()) -> dict[str, str]:
    """SHA-256 of the files a simulation or an environment may read (:func:`config_files` and ``extra``).

    Args:
        extra: further input files (a vehicle deck, a measured pulse) named by paths outside ``configs/``;
            missing ones are left out (the run that needs them fails on them with its own error). A keyword deck
            brings the files it ``*INCLUDE``s, an ISO-MME test the files it is read from (:func:`with_includes`).

    Returns:
        ``{name: hex digest}``: files under ``configs/`` (:func:`config_files`) named by their path
        relative to it, as ``configs/<path>``; ``extra`` files by their resolved path.
    """
    root = config_dir()
    out = {f"configs/{p.relative_to(root).as_posix()}": _sha256(p) for p in config_files()}
    for e in extra:
        for p in with_includes(Path(e).resolve()):
            if p.is_file() and not p.is_relative_to(root.resolve()):
                out[str(p)] = _sha256(p)
    return out


def config_files() -> list[Path]:
    """The input files under the configs folder, sorted: all but ``configs/train/`` (:data:`_SKIPPED_DIRS`) and an
    editor's leftovers (:func:`_editor_leftover`), which no loader reads. The one rule for the run's record and the
    cell-model cache (:func:`marlcrash.envs.core.build_cells`)."""
    root = config_dir()
    if not root.is_dir():
        return []
    out = []
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if p.is_file() and rel.parts[0] not in _SKIPPED_DIRS and not any(_editor_leftover(s) for s in rel.parts):
            out.append(p)
    return out


_LEFTOVER_SUFFIXES = ("~", ".swp", ".swo", ".bak", ".orig", ".rej")
"""Endings of an editor's backup or swap file, and of what ``git mergetool`` (``.orig``) or ``patch`` (``.orig``,
``.rej``) leave beside a file."""


def _editor_leftover(name: str) -> bool:
    """A hidden file or folder (a swap file ``.sim.yaml.swp``, an Emacs lock ``.#sim.yaml``), a backup ``sim.yaml~``
    or ``sim.yaml.bak``, an Emacs autosave ``#sim.yaml#``, a swap file ``sim.yaml.swp``, or a merge or patch leftover
    ``sim.yaml.orig``, ``sim.yaml.rej`` (:data:`_LEFTOVER_SUFFIXES`): deleting one is no config change."""
    return name.startswith(".") or name.endswith(_LEFTOVER_SUFFIXES) or (name.startswith("#") and name.endswith("#"))


def with_includes(path: Path) -> list[Path]:
    """``path`` and, for a keyword deck, the files it ``*INCLUDE``s; for an ISO-MME test (its folder or ``.mme``
    file), the files it is read from (:func:`marlcrash.pulse.io.mme_files`). A deck or test that cannot be read:
    ``path`` only (reading it in the run reports the problem)."""
    from marlcrash.errors import MarlcrashError
    from marlcrash.pulse.io import is_mme, mme_files
    from marlcrash.vehicle.registry import DECK_SUFFIXES

    try:
        if path.exists() and is_mme(path):
            return mme_files(path)
        if path.suffix.lower() not in DECK_SUFFIXES or not path.is_file():
            return [path]
        from marlcrash.vehicle.keyword import deck_files

        return deck_files(path)
    except (MarlcrashError, OSError):
        return [path]


def _package_root() -> Path:
    return Path(__file__).resolve().parent


def _train_root() -> Path:
    return _package_root().parent / "train"


def source_digest() -> str:
    """SHA-256 over the package's Python sources (relative path and contents of each, sorted)."""
    return _tree_digest(_package_root())


#: Entry scripts that mark a ``train/`` folder beside the package as marlcrash's own (an installed copy sits in
#: ``site-packages``, where a ``train`` folder, if any, belongs to another distribution).
TRAIN_SCRIPTS = ("train.py", "baseline.py")


def train_digest() -> str | None:
    """SHA-256 over the ``train/`` entry scripts beside the package (as :func:`source_digest`), or ``None`` where
    there is no such folder holding :data:`TRAIN_SCRIPTS` (an installed copy)."""
    root = _train_root()
    return _tree_digest(root) if all((root / name).is_file() for name in TRAIN_SCRIPTS) else None


def _tree_digest(root: Path) -> str:
    """SHA-256 over the ``*.py`` files under ``root`` (relative path and contents of each, sorted).

    An editor's leftovers are no source (:func:`_editor_leftover`, the rule of :func:`config_files`), e.g. Emacs'
    lock ``.#cli.py``, a symbolic link to nowhere, or ``.ipynb_checkpoints/``; nor is anything but a file.
    """
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        rel = p.relative_to(root)
        if any(_editor_leftover(s) for s in rel.parts) or not p.is_file():
            continue
        h.update(rel.as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def git_commit() -> str | None:
    """The commit of the git work tree the package lives in, or ``None`` (installed copy, no git)."""
    repo = _package_root().parent
    if not (repo / ".git").exists():
        return None
    env = {k: v for k, v in os.environ.items() if not k.startswith("GIT_")}  # GIT_DIR would name another repository
    try:
        out = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10, check=False, env=env)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


def record(extra: Iterable[str | Path] = ()) -> dict[str, Any]:
    """The provenance of a run starting now (see the module docstring); ``extra`` as in :func:`config_digests`."""
    from marlcrash import __version__

    return {
        "configs": config_digests(extra),
        "cwd": _cwd(),  # where the inputs named by relative paths were read from (check_run)
        "code": {
            "marlcrash": __version__,
            "source_sha256": source_digest(),
            "train_sha256": train_digest(),
            "git_commit": git_commit(),
        },
        **versions(),
    }


def output_record(inputs: Iterable[str | Path] = (), command: list[str] | None = None) -> dict[str, Any]:
    """The provenance of a command's outputs (``marlcrash simulate``'s crash record, ``marlcrash discretize``'s cell
    model): :func:`record` of its input files, with the command line that made them (``command``: the arguments after
    ``marlcrash``) and the configs folder read (``MARLCRASH_CONFIGS`` may name another than the checkout's).

    Args:
        inputs: input files named by paths outside ``configs/`` (a deck, with the files it ``*INCLUDE``s; a cells
            config or sub-assembly map given by path), as ``extra`` of :func:`config_digests`.
        command: the command's arguments, e.g. ``["simulate", "--scenario", "full_width_40"]``.
    """
    out: dict[str, Any] = {} if command is None else {"command": shlex.join(["marlcrash", *command])}
    out["configs_folder"] = str(config_dir().resolve())
    return {**out, **record(inputs)}


def record_path(output: str | Path) -> Path:
    """Where a command writes the provenance of a data file it writes (:func:`output_record`), beside it:
    ``crash.csv`` -> ``crash.provenance.json``. The data file stays as it was (a comment block above a CSV's header
    breaks ``pandas.read_csv`` and ``numpy.loadtxt(skiprows=1)``)."""
    p = Path(output)
    return p.with_name(f"{p.stem}.provenance.json")


def check_record_path(output: str | Path, key: str) -> Path:
    """:func:`record_path` of ``output``, refused (:class:`ConfigError` naming ``key``) where a file is there that is
    not such a record of a file of ``output``'s name: the command writes it without being asked by name, so it must
    not replace the user's ``lab.provenance.json`` beside ``lab.csv``."""
    rec = record_path(output)
    if not rec.exists():
        return rec
    try:
        earlier = json.loads(rec.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        earlier = None
    name = Path(output).name
    if not (isinstance(earlier, dict) and "provenance" in earlier and Path(str(earlier.get("csv", ""))).name == name):
        raise ConfigError(
            f"{rec} exists and is not the provenance record of an earlier {name}, which this command writes there; "
            "move it or choose another name",
            key=key,
        )
    return rec


def versions() -> dict[str, str]:
    """The versions of Python and of the libraries that make a run's numbers, as :func:`record` keeps them."""
    import cma
    import numba
    import numpy
    import torch

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "cma": cma.__version__,
        "numba": numba.__version__,
    }


def _cwd() -> str | None:
    """The working directory, resolved; ``None`` where it is gone."""
    try:
        return str(Path.cwd().resolve())
    except OSError:
        return None


def _outside_configs(path: str | Path) -> bool:
    return not Path(path).resolve().is_relative_to(config_dir().resolve())


def reward_input(reward: Any) -> list[str]:
    """A reward config named by a YAML path outside ``configs/`` (``EnvConfig.reward``, ``ProblemConfig.fit``); a form
    name's file is under ``configs/reward`` and recorded with ``configs/``."""
    r = str(reward)
    return [r] if Path(r).suffix in (".yaml", ".yml") and _outside_configs(r) else []


def env_inputs(env_config: Any) -> list[str]:
    """Input files of an env config named by a path outside ``configs/``: the env config file itself, its reward
    file, a vehicle file, its sub-assembly map, measured pulses."""
    paths: list[str] = []
    source = getattr(env_config, "_source", None)  # the YAML file it was loaded from (load_env_config)
    if source is not None and _outside_configs(source):
        paths.append(str(source))  # one under configs/ is recorded with configs/
    paths += reward_input(getattr(env_config, "reward", ""))
    vehicle = str(getattr(env_config, "vehicle", ""))
    if Path(vehicle).suffix:  # a registered vehicle has no suffix; its YAML is under configs/ already
        paths.append(vehicle)
    subassemblies = getattr(getattr(env_config, "vehicle_options", None), "subassemblies", None)
    if subassemblies is not None:
        paths.append(str(subassemblies))
    reference = getattr(env_config, "reference", None)
    for f in getattr(reference, "files", None) or []:
        p = Path(f.path)
        paths.append(str(p if p.is_absolute() else config_dir() / p))
    return paths


def write_record(run_dir: str | Path, extra: Iterable[str | Path] = (), note: str | None = None) -> dict[str, Any]:
    """Write ``provenance.json`` into ``run_dir`` (atomically) and return the record (with ``note``, if given)."""
    from marlcrash.outputs import write_text

    rec = record(extra)
    if note is not None:
        rec["note"] = note
    write_text(Path(run_dir) / PROVENANCE_FILE, json.dumps(rec, indent=1))
    return rec


@dataclass
class ProvenanceCheck:
    """What changed since a run folder's record was written (:func:`check_run`)."""

    recorded: bool
    """The folder has a readable record."""
    configs: list[str]
    """Changed, added or removed input files, e.g. ``"configs/sim.yaml changed"``."""
    code: list[str]
    """Code changes, e.g. ``"marlcrash source changed (git 1c27aa5 -> 5d0f473)"``, ``"train/ scripts changed
    (uncommitted changes at git 1c27aa5)"``, ``"torch 2.3.1 -> 2.4.0"``."""
    note: str | None = None
    """The record's note (:data:`RESUME_NOTE`: written at a resume, not when the run started)."""

    def as_dict(self) -> dict[str, Any]:
        out = {"recorded": self.recorded, "config_changes": self.configs, "code_changes": self.code}
        return out if self.note is None else {**out, "note": self.note}


RESUME_NOTE = "written at a resume that found no record: the part of the run before it ran with unrecorded inputs"


def config_changes(saved: dict[str, str], now: dict[str, str]) -> list[str]:
    """Readable differences of two :func:`config_digests` maps, sorted by file name."""
    out = []
    for name in sorted(set(saved) | set(now)):
        if name not in now:
            out.append(f"{name} removed")
        elif name not in saved:
            out.append(f"{name} added")
        elif saved[name] != now[name]:
            out.append(f"{name} changed")
    return out


def _explained(saved: dict[str, str], now: dict[str, str], extra: list[str | Path], started_in: Any) -> list[str]:
    """:func:`config_changes` of the record's digests (``saved``) and today's (``now``) told as the run reads its
    inputs.

    An input named by a relative path (a vehicle deck ``decks/car.k``) is read from the working directory, by the
    run as by :func:`config_digests`: from another folder than the run started in (``started_in``, the record's
    ``cwd``) it is another file, or none. That is one entry, naming the path, both files and where to start, in
    place of the old file and its includes "removed" and the new ones "added". Where the file the run read is not
    here (the run folder was copied to another machine, or its project moved), the files read now are compared
    with those recorded at the same place relative to ``started_in``: the same bytes are no change, and a changed
    one is named as it is here and as it was recorded. A file outside ``configs/`` that is still there but no
    longer read (an include the deck dropped) is said so, not "removed".
    """
    changes = config_changes(saved, now)
    out: list[str] = []
    covered: set[str] = set()
    here = _cwd()
    if isinstance(started_in, str) and here is not None and Path(started_in) != Path(here):
        for e in extra:
            if Path(e).is_absolute():
                continue
            then, read = (Path(started_in) / e).resolve(), Path(e).resolve()
            if then == read:
                continue
            if not then.is_file() and read.is_file():  # on another machine, or in a moved project
                for p in with_includes(read):
                    if str(p) in saved:  # an include named by an absolute path: read from the same place
                        continue
                    q = os.path.normpath(Path(started_in) / os.path.relpath(p, here))  # where the run read it
                    covered |= {f"{q} removed", f"{p} added"}
                    if q not in saved:
                        out.append(f"{p} added")
                    elif saved[q] != now.get(str(p)):
                        out.append(f"{p} changed (read as {q} where the run started, in {started_in})")
                continue
            covered |= {f"{p} removed" for p in with_includes(then)} | {f"{p} added" for p in with_includes(read)}
            missing = "" if read.is_file() else " (no such file)"
            out.append(f"{str(e)!r} is a relative path, read from the working directory: {then} where the run "
                       f"started, {read} here{missing}; start it from {started_in}, or name it by an absolute "
                       "path")  # fmt: skip
    for change in changes:
        if change in covered:
            continue
        name, _, what = change.rpartition(" ")
        if what == "removed" and not name.startswith("configs/") and Path(name).is_file():
            change = f"{name} is no longer read (the file is still there)"
        out.append(change)
    return out


def check_run(run_dir: str | Path, extra: Iterable[str | Path] = (), key: str | None = "resume") -> ProvenanceCheck:
    """Compare a run folder's ``provenance.json`` with the configs and code of this process.

    Args:
        run_dir: the run folder.
        extra: the run's input files outside ``configs/`` (:func:`env_inputs`).
        key: the key an unreadable record is reported under; ``None``: log a warning and go on as without one
            (an evaluation only reports changes, so a damaged record need not stop it).

    Returns:
        The differences; ``recorded`` is false (and both lists empty) for a folder without a (readable) record. An
        input named by a relative path that names another file from this working directory than from the record's
        is one entry saying so (:func:`_explained`).

    Raises:
        ConfigError: (key ``key``) the record exists but cannot be read.
    """
    path = Path(run_dir) / PROVENANCE_FILE
    if not path.exists():
        return ProvenanceCheck(recorded=False, configs=[], code=[])
    try:
        return check_record(json.loads(path.read_text(encoding="utf-8")), extra)
    except (OSError, ValueError):
        if key is None:
            log.warning("%s cannot be read as a provenance record; going on without it", path)
            return ProvenanceCheck(recorded=False, configs=[], code=[])
        raise ConfigError(f"{path} cannot be read as a provenance record; delete it to go on without one",
                          key=key) from None  # fmt: skip


def check_record(saved: Any, extra: Iterable[str | Path] = ()) -> ProvenanceCheck:
    """Compare a provenance record (:func:`record`, as a run folder's ``provenance.json`` or a results file holds it)
    with the configs and code of this process: :func:`check_run` without the file.

    Raises:
        ValueError: ``saved`` is not a record (no ``configs`` and ``code`` mappings).
    """
    extra = list(extra)
    try:
        saved_configs, saved_code = dict(saved["configs"]), dict(saved["code"])
    except (KeyError, TypeError, ValueError):
        raise ValueError("not a provenance record (expected 'configs' and 'code' mappings)") from None
    configs = _explained(saved_configs, config_digests(extra), extra, saved.get("cwd"))
    code: list[str] = []
    if saved_code.get("source_sha256") != source_digest():
        code.append("marlcrash source")
    if "train_sha256" in saved_code and saved_code["train_sha256"] != train_digest():  # older records lack it
        code.append("train/ scripts")
    if code:
        then, now = saved_code.get("git_commit"), git_commit()
        if then is not None and then == now:  # one commit: edits not committed (then, now or both)
            where = f" (uncommitted changes at git {str(now)[:7]})"
        else:
            where = f" (git {str(then)[:7]} -> {str(now)[:7]})" if then or now else ""
        code = [f"{what} changed{where}" for what in code]
    code += [f"{lib} {saved[lib]} -> {v}" for lib, v in versions().items() if lib in saved and saved[lib] != v]
    note = saved.get("note")
    return ProvenanceCheck(recorded=True, configs=configs, code=code, note=None if note is None else str(note))


def require_unchanged(
    run_dir: str | Path, extra: Iterable[str | Path] = (), what: str = "resume", finished: bool = False
) -> ProvenanceCheck:
    """:func:`check_run` for a resume: refuse changed or removed input files; warn about added ones (no run reads a
    file that did not exist when it started), changed code or a missing record.

    A resume that finds no record writes a new one (:func:`write_record`), so the rest of the run is guarded
    again, also after the record was deleted to go on past a refusal.

    Args:
        finished: the run is finished and a resume would only evaluate it again (the message says how to
            evaluate it on today's files without replacing its results).

    Raises:
        ConfigError: (key ``resume``) an input file changed or was removed since the run started.
    """
    check = check_run(run_dir, extra)
    refused = [c for c in check.configs if not c.endswith(" added")]
    if refused:
        shown = "; ".join(refused[:6]) + ("; ..." if len(refused) > 6 else "")
        if finished:
            why = (
                f"it is finished, and a resume would evaluate it again over its results. Restore them, or "
                f"evaluate it on today's files beside its results: python train/evaluate.py run={run_dir}"
            )
        else:
            why = (
                f"its finished part would not compare with the rest. Restore them, start a new run, or delete "
                f"{PROVENANCE_FILE} there to go on anyway (a new record is then written)"
            )
        raise ConfigError(f"{what}: {run_dir} was started with other configs ({shown}); {why}",
                          key="resume")  # fmt: skip
    warn_changes(run_dir, check, what)
    if not check.recorded:
        write_record(run_dir, extra, note=RESUME_NOTE)
    return check


def warn_changes(run_dir: str | Path, check: ProvenanceCheck, what: str) -> None:
    """Log a warning for each difference of ``check`` (and for a missing record)."""
    if not check.recorded:
        log.warning("%s: %s has no %s; cannot tell whether configs or code changed since it ran",
                    what, run_dir, PROVENANCE_FILE)  # fmt: skip
    for change in check.configs + check.code:
        log.warning("%s: %s: %s since the run started", what, run_dir, change)
