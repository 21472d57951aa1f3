"""Sub-assembly maps: which parts of a deck form which sub-assembly (DESIGN 1.1, 3).

A sub-assembly map is a small YAML file::

    subassemblies:            # name -> list of part ids, part-name globs, or "set:<id>"
      bumper: [2]             # part id 2
      hood: ["hood*"]         # every part whose title matches hood* (case-insensitive)
      rails: ["set:10"]       # the parts of *SET_PART 10 of the deck
      compartment: [5, 6]

Rules: every entry names at least one part; an integer is a part id that must exist;
a string is a glob on part titles (``fnmatch``, case-insensitive) that must match at
least one part, or ``set:<id>`` naming a ``*SET_PART`` of the deck; a part may belong
to one group only. Parts the map leaves out are their own ``part_<id>`` sub-assembly
once the reader completes the map, so a group named ``part_<id>`` after a part of the
model must hold that part. Problems raise :class:`ConfigError` naming the file and the
key (``subassemblies.hood[0]``).
"""

from __future__ import annotations

import fnmatch
import math
from pathlib import Path
from typing import Any

from marlcrash.config import load_yaml
from marlcrash.errors import ConfigError
from marlcrash.outputs import write_text
from marlcrash.vehicle.model import VehicleModel, default_group_part

__all__ = ["dump_subassembly_map", "load_subassembly_map", "resolve_subassemblies"]

PartSets = dict[int, tuple[str, list[int]]]
"""``*SET_PART`` contents: set id -> (title, part ids)."""


def resolve_subassemblies(
    spec: dict[str, Any],
    model: VehicleModel,
    *,
    part_sets: PartSets | None = None,
    path: str | Path | None = None,
) -> dict[str, list[int]]:
    """Resolve a mapping name -> entries (ids, globs, ``set:<id>``) into name -> part ids.

    Args:
        spec: the ``subassemblies`` mapping.
        model: the model whose parts the entries refer to.
        part_sets: the deck's ``*SET_PART`` contents, for ``set:<id>`` entries.
        path: the file the mapping came from, for messages.

    Returns:
        name -> sorted-as-listed, de-duplicated part ids.

    Raises:
        ConfigError: unknown part or set, a glob matching nothing, a part in two groups,
            an entry of the wrong type.
    """
    if not isinstance(spec, dict):
        raise ConfigError(f"expected a mapping name -> list of parts, got {spec!r}", key="subassemblies", path=path)
    part_sets = part_sets or {}
    owner: dict[int, str] = {}
    out: dict[str, list[int]] = {}
    names = {pid: (p.name or "").lower() for pid, p in model.parts.items()}
    for group, entries in spec.items():
        key = f"subassemblies.{group}"
        if not isinstance(group, str) or not group.strip():
            raise ConfigError(f"expected a non-empty sub-assembly name, got {group!r}", key=key, path=path)
        if not isinstance(entries, list | tuple) or not entries:
            raise ConfigError(
                f"expected a non-empty list of part ids or name patterns, got {entries!r}", key=key, path=path
            )
        pids: list[int] = []
        for i, entry in enumerate(entries):
            ekey = f"{key}[{i}]"
            if isinstance(entry, bool) or not isinstance(entry, int | str):
                raise ConfigError(
                    f"expected a part id, a name pattern or 'set:<id>', got {entry!r}", key=ekey, path=path
                )
            if isinstance(entry, int):
                if entry in model.left_out:
                    raise ConfigError(f"{model.left_out[entry]}; remove it from the map", key=ekey, path=path)
                if entry not in model.parts:
                    raise ConfigError(
                        f"unknown part {entry}; the model has parts {sorted(model.parts)[:20]}", key=ekey, path=path
                    )
                found = [entry]
            elif entry.strip().lower().startswith("set:"):
                ref = entry.strip()[4:].strip()
                try:
                    sid = int(ref)
                except ValueError:
                    raise ConfigError(f"expected 'set:<integer id>', got {entry!r}", key=ekey, path=path) from None
                if sid not in part_sets:
                    raise ConfigError(
                        f"unknown *SET_PART {sid}; the deck defines {sorted(part_sets)}", key=ekey, path=path
                    )
                if not part_sets[sid][1]:  # the group would be a sub-assembly (an agent) of nothing
                    raise ConfigError(f"*SET_PART {sid} holds no part; expected a set of at least one part",
                                      key=ekey, path=path)  # fmt: skip
                found = [p for p in part_sets[sid][1] if p not in model.left_out]  # a set may hold the barrier
                if not found:
                    raise ConfigError(
                        f"*SET_PART {sid} holds only parts left out of the vehicle: "
                        + "; ".join(model.left_out[p] for p in part_sets[sid][1]),
                        key=ekey,
                        path=path,
                    )
                bad = [p for p in found if p not in model.parts]
                if bad:
                    raise ConfigError(f"*SET_PART {sid} lists unknown parts {bad[:10]}", key=ekey, path=path)
            else:
                pattern = entry.strip().lower()
                found = sorted(pid for pid, n in names.items() if fnmatch.fnmatchcase(n, pattern))
                if not found:
                    gone = "".join(f"; not matched, left out of the vehicle: {why}" for why in model.left_out.values())
                    raise ConfigError(f"pattern {entry!r} matches no part title{gone}", key=ekey, path=path)
            for pid in found:
                if pid in owner and owner[pid] != group:
                    raise ConfigError(
                        f"part {pid} ({model.parts[pid].name!r}) is in two sub-assemblies, "
                        f"{owner[pid]!r} and {group!r}",
                        key=ekey,
                        path=path,
                    )
                if pid not in owner:
                    owner[pid] = group
                    pids.append(int(pid))
        own = default_group_part(group, model.parts)
        if own is not None and own not in pids:
            raise ConfigError(
                f"{group!r} is the name of part {own}'s own sub-assembly (a part the map leaves out gets it), but "
                f"the group does not hold part {own}; rename it or add part {own} to it",
                key=key,
                path=path,
            )
        out[group] = pids
    return out


def load_subassembly_map(
    path: str | Path, model: VehicleModel, *, part_sets: PartSets | None = None
) -> dict[str, list[int]]:
    """Read a sub-assembly YAML file (format in the module docstring) for ``model``.

    Raises:
        ConfigError: unreadable or invalid YAML, unknown keys, or any problem of
            :func:`resolve_subassemblies`; the message names the file and key.
    """
    data = load_yaml(path)
    unknown = set(data) - {"subassemblies"}
    if unknown:
        first = sorted(map(str, unknown))[0]  # YAML keys may be numbers too: sorted as text
        raise ConfigError("unknown key; expected only 'subassemblies'", key=first, path=path)
    if "subassemblies" not in data:
        raise ConfigError("missing; expected a mapping name -> list of parts", key="subassemblies", path=path)
    return resolve_subassemblies(data["subassemblies"], model, part_sets=part_sets, path=path)


def dump_subassembly_map(mapping: dict[str, list[int]], path: str | Path) -> Path:
    """Write ``mapping`` (name -> part ids) as a sub-assembly YAML file, atomically
    (:func:`marlcrash.outputs.write_text`).

    Returns:
        The path written.

    Raises:
        ConfigError: ``path`` cannot be written (its folder is missing or not writable).
    """
    path = Path(path)
    lines = [
        "# Sub-assembly map written by marlcrash (see marlcrash/vehicle/subassembly_map.py).",
        "subassemblies:  # name -> list of part ids (or part-title globs, or 'set:<id>')",
    ]
    for name, pids in mapping.items():
        ids = ", ".join(str(int(p)) for p in pids)
        lines.append(f"  {_yaml_key(name)}: [{ids}]")
    text = "\n".join(lines) + "\n"
    return write_text(path, text)


def _yaml_key(name: str) -> str:
    import yaml

    # one line whatever its length: at the emitter's default width (80) a long name with spaces was folded over two
    # lines, which broke the map's "name: [ids]" line; a name holding a line break is double-quoted (escaped as \n),
    # not a single-quoted scalar over several lines
    text = yaml.safe_dump(str(name), default_style=None, width=math.inf).strip().removesuffix("\n...").strip()
    if "\n" in text:
        text = yaml.safe_dump(str(name), default_style='"', width=math.inf).strip()
    return text
