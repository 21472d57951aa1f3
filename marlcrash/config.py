"""Config plumbing: YAML files to typed dataclasses, with errors that name the key.

Each component has one dataclass schema whose defaults are *not* the source of
truth: values live in ``configs/*.yaml``. :func:`from_dict` builds a schema from a
mapping, rejecting unknown keys and wrong types with the dotted key and the file,
and calls the schema's ``validate()`` for cross-field checks.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from marlcrash.errors import ConfigError

T = TypeVar("T")


def config_dir() -> Path:
    """The folder of YAML configs: ``$MARLCRASH_CONFIGS``, else the copy a non-editable install ships inside the
    package (``marlcrash/configs``), else the repository's ``configs/`` beside the package (a checkout, an editable
    install).

    Raises:
        ConfigError: ``$MARLCRASH_CONFIGS`` names no folder (every config then read as missing: "unknown scenario
            'full_width_40'; registered: []").
    """
    env = os.environ.get("MARLCRASH_CONFIGS")
    if env:
        if not Path(env).is_dir():
            raise ConfigError(f"{env} is no folder; expected the folder of marlcrash's YAML configs (a copy of the "
                              "repository's configs/), or unset it", key="MARLCRASH_CONFIGS")  # fmt: skip
        return Path(env)
    package = Path(__file__).resolve().parent
    shipped = package / "configs"
    return shipped if shipped.is_dir() else package.parent / "configs"


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats (``3e-4`` is a number; YAML 1.1 needs ``3.0e-4``) that refuses a
    key given twice in one mapping (PyYAML keeps the last silently: ``hood: [1]`` then ``hood: [2]`` dropped part 1)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, yaml.Mark] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<: *anchor` merges, it is not a key
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.setdefault(key, key_node.start_mark)
            except TypeError:  # an unhashable (complex) key: SafeLoader refuses it below
                continue
            if first is not key_node.start_mark:  # by position: two keys of a one-line `{...}` share their line
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} given twice (first at line {first.line + 1}, column {first.column + 1}); expected "
                    "each key once",
                    key_node.start_mark,
                )
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; raise :class:`ConfigError` naming the file on any problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"cannot read config file ({e.strerror})", path=path) from None
    except UnicodeDecodeError as e:  # binary junk, a file of another kind
        raise ConfigError(f"not a text file (byte {e.start} is not UTF-8); expected YAML", path=path) from None
    try:
        data = yaml.load(text, Loader=_Loader)  # a SafeLoader that also reads 3e-4 as a number
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"invalid YAML{where}: {getattr(e, 'problem', e)}", path=path) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping at the top level, got {type(data).__name__}", path=path)
    return data


def _check_type(value: Any, tp: Any, key: str, path: str | Path | None) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return _check_type(value, options[0], key, path)
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_type(value, a, key, path)
            except ConfigError as e:
                errors.append(e.reason)
        got = f", got {value!r}"
        if all(r.startswith("expected ") and r.endswith(got) for r in errors):  # one message: "expected A or B, got x"
            wanted = [r[len("expected ") : -len(got)] for r in errors]
            raise ConfigError(f"expected {' or '.join(wanted)}{got}", key=key, path=path)
        raise ConfigError("; ".join(errors), key=key, path=path)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if isinstance(value, tp):  # a schema made in Python, inside one being checked (checked())
            value = _fields_of(value)
        if not isinstance(value, dict):
            raise ConfigError(f"expected a mapping, got {value!r}", key=key, path=path)
        return from_dict(tp, value, prefix=key, path=path)
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"expected a list, got {value!r}", key=key, path=path)
        inner = args[0] if args else Any
        items = [_check_type(v, inner, f"{key}[{i}]", path) for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"expected a mapping, got {value!r}", key=key, path=path)
        vt = args[1] if len(args) == 2 else Any
        return {k: _check_type(v, vt, f"{key}.{k}", path) for k, v in value.items()}
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"expected one of {list(args)}, got {value!r}", key=key, path=path)
        return value
    if tp is float:  # numbers.Real: a numpy scalar (np.int64, np.float32) of a computed override too
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ConfigError(f"expected a number, got {value!r}", key=key, path=path)
        if not math.isfinite(value):  # no setting of this project means anything by inf or nan
            raise ConfigError(f"expected a finite number, got {value!r}", key=key, path=path)
        return float(value)
    if tp is int:  # numbers.Integral: np.int64 of a computed override too (np.bool_ is none)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise ConfigError(f"expected an integer, got {value!r}", key=key, path=path)
        return int(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"expected true or false, got {value!r}", key=key, path=path)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {value!r}", key=key, path=path)
        return value
    return value


def _unknown_key(cls: type, name: str, key: str, path: str | Path | None) -> ConfigError:
    """The error for key ``name`` that schema ``cls`` does not have: why, where the schema lists it among its
    ``RETIRED_KEYS`` (a mapping of removed key to what replaced it), else the keys there are."""
    retired = getattr(cls, "RETIRED_KEYS", {})
    if name in retired:
        return ConfigError(f"this key was removed: {retired[name]}; delete it", key=key, path=path)
    names = sorted(f.name for f in dataclasses.fields(cls))
    return ConfigError(f"unknown key; expected one of {names}", key=key, path=path)


def from_dict(cls: type[T], data: dict[str, Any], prefix: str = "", path: str | Path | None = None) -> T:
    """Build dataclass ``cls`` from ``data``, checking keys and types, then ``validate()``.

    Args:
        cls: a dataclass schema.
        data: the mapping (e.g. from :func:`load_yaml`); missing keys keep defaults.
        prefix: dotted key of ``data`` inside a larger config, for messages.
        path: the file the mapping came from, for messages.

    Raises:
        ConfigError: unknown key, wrong type, or a failed ``validate()``.
    """
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    kwargs = {}
    for k, v in data.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if k not in names:
            raise _unknown_key(cls, str(k), key, path)
        kwargs[k] = _check_type(v, hints[k], key, path)
    required = [
        f.name
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.init and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    absent = [name for name in required if name not in kwargs]
    if absent:
        more = f" (and {', '.join(absent[1:])})" if len(absent) > 1 else ""
        raise ConfigError(
            f"missing: expected this key{more}", key=f"{prefix}.{absent[0]}" if prefix else absent[0], path=path
        )
    try:
        obj = cls(**kwargs)
    except TypeError as e:
        raise ConfigError(str(e), key=prefix or None, path=path) from None
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except ConfigError as e:
            raise nested_error(e, prefix, path) from None
    return obj


def _fields_of(obj: Any) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}


def checked(obj: T, prefix: str = "") -> T:
    """A config schema made in Python, checked as a file's values are: types, then ``validate()``.

    The loaders check what a file holds; an object built in Python (``DiscretizationConfig(overlaps=["0.4"])``)
    skipped that and failed deep inside numpy. Returns an equal object (ints given for floats become floats).

    Raises:
        ConfigError: a wrong type or a failed ``validate()``, naming the key.
    """
    return from_dict(type(obj), _fields_of(obj), prefix)


def nested_error(e: ConfigError, prefix: str, path: str | Path | None = None) -> ConfigError:
    """``e``, raised by the section at dotted key ``prefix`` of a config read from ``path``, keyed as the user sets it.

    A section names its keys relative to itself (``require`` in a schema's ``validate()``, a bad override of a config
    it names): the key becomes ``<prefix>.<key>`` (one already under ``prefix``, or ``prefix`` itself, the section
    naming itself, is kept) and the error takes ``path``
    where it names no file. An error that names another file is about that file's own keys: it is returned as it is.
    """
    if e.path is not None and (path is None or Path(e.path) != Path(path)):
        return e
    key = e.key
    if prefix and key is not None and key != prefix and not key.startswith(prefix + "."):
        key = f"{prefix}.{key}"
    return ConfigError(e.reason, key=key or prefix or None, path=e.path or path)


def missing_keys(cls: type, data: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys of schema ``cls`` (recursing into nested dataclass sections given as mappings) that ``data``
    lacks: the fields that would silently take the dataclass default."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        key = f"{prefix}{f.name}"
        if f.name not in data:
            out.append(key)
        elif dataclasses.is_dataclass(hints[f.name]) and isinstance(data[f.name], dict):
            out += missing_keys(hints[f.name], data[f.name], key + ".")
    return out


def require_complete(
    cls: type, data: dict[str, Any], path: str | Path | None, prefix: str = "", what: str = ""
) -> None:
    """Values live in the YAML files, not in the schemas: a config file must give every key of ``cls``.

    ``prefix`` and ``what``: where ``data`` sits in the file (``"params."``) and what the keys are (``" (a parameter
    of the 'log_ratio' form)"``), for the message.

    Raises:
        ConfigError: naming the first missing key (and how many more there are).
    """
    missing = missing_keys(cls, data, prefix)
    if missing:
        more = f" (and {len(missing) - 1} more: {', '.join(missing[1:4])}{', ...' if len(missing) > 4 else ''})"
        raise ConfigError(
            f"missing: every value lives in the config file; add this key{what}"
            + (f" to {path}" if path is not None else "")  # the whole path: every run folder has a config.yaml
            + (more if len(missing) > 1 else ""),
            key=missing[0],
            path=path,
        )


def _field_type(cls: type, parts: list[str]) -> Any:
    """The annotated type at the dotted path ``parts`` of schema ``cls`` (``X | None`` unwrapped), or ``None``."""
    t: Any = cls
    for p in parts:
        if not (isinstance(t, type) and dataclasses.is_dataclass(t)):
            return None
        hints = typing.get_type_hints(t)
        if p not in hints:
            return None
        t = hints[p]
        args = [a for a in typing.get_args(t) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(t)) == 2:
            t = args[0]
    return t


def check_override(cls: type, dotted: str, value: Any, key: str | None = None, path: str | Path | None = None) -> None:
    """Refuse a dotted key that schema ``cls`` does not have (``eval.iteration``), or a value of the wrong type for it,
    as :func:`from_dict` would: for an override held to be applied later (a ``ci`` block), checked now. A key inside
    a mapping-valued field (``scenarios``, ``agents.merge``) is the user's to choose and passes; so does its value.
    Cross-field checks (``validate()``) wait for the override to be applied.

    Raises:
        ConfigError: the first unknown part, with the keys there are, or a wrong type; keyed ``key`` (default
            ``dotted``).
    """
    t: Any = cls
    hint: Any = None
    for p in dotted.split("."):
        if not (isinstance(t, type) and dataclasses.is_dataclass(t)):
            return  # inside a mapping (or a plain value, whose override fails when it is applied)
        hints = typing.get_type_hints(t)
        if p not in hints:
            raise _unknown_key(t, p, key or dotted, path)
        hint = hints[p]
        t = _field_type(t, [p])
    _check_type(value, hint, key or dotted, path)


def flatten_overrides(cls: type, overrides: dict[str, Any]) -> dict[str, Any]:
    """Overrides with every mapping aimed at a section of schema ``cls`` spread into dotted keys.

    ``{"termination": {"failure_dfd": 10.0}}`` (what Hydra makes of ``+env_overrides.termination.failure_dfd=10``)
    becomes ``{"termination.failure_dfd": 10.0}``: it changes that key and keeps the section's others, where
    setting the mapping whole reset them to the schema's defaults. A mapping for a mapping-valued field
    (``scenarios``, ``agents.merge``) stays whole: it is the value.
    """
    if not isinstance(overrides, Mapping):
        # a list of "k=v" strings (the command line's form) failed with "'list' object has no attribute 'items'"
        raise ConfigError(
            f"expected a mapping of dotted keys to values ({{'termination.failure_dfd': 10.0}}), "
            f"got {type(overrides).__name__} {overrides!r}",
            key="overrides",
        )
    out: dict[str, Any] = {}

    def spread(parts: list[str], value: Any) -> None:
        t = _field_type(cls, parts)
        if isinstance(value, dict) and isinstance(t, type) and dataclasses.is_dataclass(t):
            for k, v in value.items():
                spread([*parts, str(k)], v)
        else:
            out[".".join(parts)] = value

    for dotted, value in overrides.items():
        spread(str(dotted).split("."), value)
    return out


def merge_overrides(cls: type, *layers: dict[str, Any]) -> dict[str, Any]:
    """Dotted-key overrides of schema ``cls`` from ``layers``, a later layer's value winning key by key.

    Each layer is spread first (:func:`flatten_overrides`), so two layers that each give a mapping for one section
    (``{"masking": {"min_fraction": 0.5}}`` and ``{"masking": {"primary_depth": 1.0}}``) both apply; merged as
    they are, the later mapping replaced the earlier one whole and its keys were lost without a word.
    """
    out: dict[str, Any] = {}
    for layer in layers:
        out.update(flatten_overrides(cls, layer))
    return out


def load_config(
    cls: type[T], path: str | Path, overrides: dict[str, Any] | None = None, *, complete: bool = False
) -> T:
    """Load a YAML file into ``cls``, applying dotted-key ``overrides`` first (:func:`flatten_overrides`: a
    mapping for a section changes only the keys it gives).

    ``complete=True``: the file (with the overrides) must give every key of ``cls`` (:func:`require_complete`), for
    a file whose values are the source of truth: a key left out would silently take the schema's default, which
    need not be the shipped file's value.
    """
    data = load_yaml(path)
    applied: list[str] = []
    for dotted, value in flatten_overrides(cls, {} if overrides is None else overrides).items():
        node = data
        parts = dotted.split(".")
        for i, p in enumerate(parts[:-1]):
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                inner = ".".join(parts[: i + 1])
                if inner in applied:  # an earlier override set a section to a plain value: that one is wrong
                    raise ConfigError(f"expected a mapping, got {node!r}", key=inner, path=path)
                raise ConfigError(f"cannot override inside a non-mapping value ({inner} is {node!r})", key=dotted,
                                  path=path)  # fmt: skip
        node[parts[-1]] = value
        applied.append(dotted)
    if complete:
        require_complete(cls, data, path)
    return from_dict(cls, data, path=path)


MAX_STEPS = 2**63 - 1
"""Most calibration steps an episode may be given (``termination.max_iterations``, ``eval.iterations``): the env
counts steps in int64, which holds no more (torch compared 2**63 as -2**63 and truncated at the first step)."""

MAX_SEED = 2**64 - 1
"""Largest seed a run takes: torch's generators (``torch.manual_seed``, gradient descent, ``lm``, the PPO runs)
refuse a larger one ("Overflow when unpacking long long"), where numpy's take any."""


def require_seed(value: int, key: str) -> None:
    """Refuse, naming ``key``, a seed outside ``[0, 2**64 - 1]`` (:data:`MAX_SEED`), before any run."""
    require(0 <= value <= MAX_SEED, key, f"expected a seed in [0, 2**64 - 1], got {value}")


MAX_THREADS = 1024
"""Most torch intra-op threads a setting may ask for (``threads`` of training, comparison and ablation PPO runs,
``gradient.threads``) [-]: a fixed bound, not this machine's CPU count, so that a config written on one machine loads
on another. torch starts a pool of as many threads as asked: 100,000 crashed the process at the first matrix product
(a segmentation fault under a process limit), 10**6 were set as given. More threads than CPUs only wait on each
other."""


def require_threads(value: int, key: str) -> None:
    """Refuse, naming ``key``, a torch thread count outside ``[0, MAX_THREADS]`` (0: torch's own setting)."""
    require(0 <= value <= MAX_THREADS, key,
            f"expected a thread count in [0, {MAX_THREADS}] (0: torch's setting; MAX_THREADS = {MAX_THREADS}), "
            f"got {value}")  # fmt: skip


def require_device(value: Any, key: str) -> None:
    """Refuse, naming ``key``, a torch device that is not ``cpu`` or a CUDA device this machine has."""
    import torch  # here, not at the top: reading a config needs no torch

    try:
        dev = torch.device(value)
    except (RuntimeError, TypeError):
        raise ConfigError(f"expected a torch device such as 'cpu' or 'cuda:0', got {value!r}", key=key) from None
    n_cuda = torch.cuda.device_count() if dev.type == "cuda" else 0
    require(dev.type in ("cpu", "cuda"), key, f"expected a cpu or cuda device, got {value!r}")
    require(dev.type == "cpu" or (n_cuda > 0 and (dev.index is None or dev.index < n_cuda)), key,
            f"device {value!r} is not available here ({n_cuda} CUDA devices); expected 'cpu'"
            + (f" or cuda:0..{n_cuda - 1}" if n_cuda else ""))  # fmt: skip


def require(condition: bool, key: str, message: str) -> None:
    """Raise :class:`ConfigError` for ``key`` unless ``condition`` holds (for ``validate()``).

    ``key`` is relative to the schema being validated; :func:`from_dict` prefixes it
    with the schema's own position in a larger config.
    """
    if not condition:
        raise ConfigError(message, key=key)
