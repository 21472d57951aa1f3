"""Command-line checks shared by the Hydra entry scripts in ``train/``.

Hydra composes a script's config from its YAML files and the command line's overrides before the script
runs, so an override it cannot apply never reaches the scripts' own validation (which names the key, exits 2
and starts nothing). Hydra then prints its own message and exits 1. :func:`check_overrides` composes the same
config first, with Hydra's compose API, and turns Hydra's errors into :class:`~marlcrash.errors.ConfigError`
messages in the form of every other config error: the key, what was expected and the options there are::

    $ python train/train.py algorithm.lrr=1e-3
    error: train.yaml key 'algorithm.lrr': unknown key; expected one of ['clip_epsilon', ..., 'lr', ...]
    $ python train/train.py algorithm=sac
    error: train.yaml key 'algorithm': no config 'sac' in configs/train/algorithm/; expected one of [...]

Hydra's own flags (``--help``, ``--cfg job``, ...) leave the command line to Hydra. A multirun (``-m`` or
``--multirun``, alone among the flags) of a script that gives :func:`exit_on_bad_overrides` its job check is checked
job by job before the first starts (:func:`check_sweep`): Hydra runs the jobs one after the other, so a bad value
of the third job (``seed=0,-1,2``) or two jobs of one run folder (``name=same``) stopped the sweep after the
first had trained, and the jobs after it never ran.

:func:`name_default_run` gives a run whose name is the default launch time stamp a folder of its own: the jobs of a
multirun (``--multirun seed=0,1,2``) start within one second and would share it.

:func:`run_script` runs a script's Hydra main as the ``marlcrash`` command runs its subcommands: a Ctrl-C prints
``interrupted`` and what the run kept (where to resume it), not a traceback from wherever the work was.
"""

from __future__ import annotations

import filecmp
import os
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

from marlcrash.errors import ConfigError, MarlcrashError, end_by_sigint, report_interrupt

__all__ = [
    "check_overrides",
    "check_sweep",
    "exit_on_bad_overrides",
    "fixed_run_folder",
    "name_default_run",
    "run_script",
]

MULTIRUN_FLAGS = ("-m", "--multirun")

JobCheck = Callable[[Any, dict[str, Any], list[str]], "Path | None"]
"""``check(cfg, mapping, given)`` of a multirun job: its composed config, that as a plain mapping
(:func:`config_mapping`) and the keys its overrides set; validates the values as the script does before it works
(raising :class:`~marlcrash.errors.ConfigError`) and returns the run folder the job writes, or ``None`` where the job
picks its own (:func:`fixed_run_folder`)."""


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def _first_line(e: Exception) -> str:
    return str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__


def _whole(e: Exception) -> str:
    """Hydra's message on one line (some carry their advice on the lines after the first)."""
    return " ".join(line.strip() for line in str(e).strip().splitlines() if line.strip()) or type(e).__name__


def _named(e: Exception) -> str | None:
    """The key of the override a Hydra message quotes (``... argument 'seed=0,1,2'``), if any."""
    found = re.search(r"'([+~]?[\w.]+)=", str(e))
    return None if found is None else _key(found.group(1))


def _options(config_dir: Path, group: str) -> list[str]:
    return sorted(p.stem for p in (config_dir / group).glob("*.yaml"))


def check_overrides(config_dir: str | Path, config_name: str, overrides: Sequence[str]) -> Any:
    """Compose ``config_name`` with ``overrides`` as Hydra will, and name what it cannot apply.

    Args:
        config_dir: the scripts' Hydra config directory (``configs/train``).
        config_name: the primary config, without ``.yaml``.
        overrides: the command line's ``key=value`` overrides.

    Returns:
        The composed config (a ``DictConfig``).

    Raises:
        ConfigError: an override that sets a key the config does not have (with the keys there are), picks a
            config-group option that does not exist (with the options), or cannot be parsed.
    """
    from hydra import compose, initialize_config_dir
    from hydra.errors import ConfigCompositionException, HydraException, MissingConfigException

    config_dir = Path(config_dir).resolve()
    source = f"{config_name}.yaml"

    def composed(ov: Sequence[str]):
        with initialize_config_dir(config_dir=str(config_dir), version_base=None):
            return compose(config_name, overrides=list(ov))

    def named(e: Exception) -> str | None:  # the key a message quotes, else that of the override it fails at
        return _named(e) or _culprit(composed, overrides, e)

    try:
        return composed(overrides)
    except MissingConfigException as e:
        # an unknown choice, an empty one (algorithm=) and one of a list (algorithm=[mappo,sac]) alike
        found = re.search(r"Could not (?:find|load) '([^']+)/([^'/]*)'", str(e))
        if found is None:
            raise ConfigError(_whole(e), key=named(e), path=source) from None
        group, option = found.groups()
        raise ConfigError(
            f"no config '{option}' in configs/train/{group}/; expected one of {_options(config_dir, group)}",
            key=group,
            path=source,
        ) from None
    except ConfigCompositionException as e:
        key = getattr(e.__cause__, "full_key", None)
        if not key:
            raise ConfigError(_whole(e), key=named(e), path=source) from None
        parent, _, _ = str(key).rpartition(".")
        groups = [o for o in overrides if (config_dir / _key(o)).is_dir()]  # the group files the user picked
        try:
            node = composed(groups)
            for part in parent.split(".") if parent else ():
                node = node[part]
            keys = sorted(node.keys())
        except (HydraException, KeyError, AttributeError, TypeError):
            keys = None
        k = str(key)
        bad = next((o for o in overrides if k == _key(o) or f"{k}.".startswith(_key(o) + ".")
                    or _key(o).startswith(k + ".")), None)  # fmt: skip
        if bad is not None and (keys == [] or "overrides" in _key(bad)):
            # a free-form mapping (env_overrides): its keys are the user's to add, with Hydra's '+'
            raise ConfigError(f"a key the config does not have yet (a mapping of overrides); add it with '+': "
                              f"+{bad.lstrip('+~')}", key=_key(bad), path=source) from None  # fmt: skip
        expected = "" if keys is None else f"; expected one of {keys}"
        raise ConfigError(f"unknown key{expected}", key=str(key), path=source) from None
    except HydraException as e:  # a malformed override (OverrideParseException) and the rest of Hydra's errors
        bad = _unparsable(overrides)
        if bad is None:
            raise ConfigError(_whole(e), key=named(e), path=source) from None
        raise ConfigError(
            f"cannot parse the override {bad!r}: {_first_line(e)}; expected key=value in Hydra's override grammar "
            f"(quote values with brackets, commas or spaces: key='[1, 2]')",
            key=_key(bad),
            path=source,
        ) from None
    except ValueError as e:  # Hydra's check of a config-group choice (algorithm=null) is not a HydraException
        key = named(e)
        group = None if key is None else key.split("@")[0]  # algorithm@mappo: a choice of algorithm/
        expected = ""
        if group is not None and (config_dir / group).is_dir():
            expected = f"; expected one of {_options(config_dir, group)}"
        raise ConfigError(f"{_whole(e)}{expected}", key=key, path=source) from None


def _culprit(composed: Callable[[Sequence[str]], Any], overrides: Sequence[str], error: Exception) -> str | None:
    """The key of the override behind a Hydra ``error`` that quotes none: the one that alone fails with the same
    message, else the first that composition fails at."""
    for o in overrides:
        try:
            composed([o])
        except Exception as e:  # any failure: compared with the one to explain
            if type(e) is type(error) and str(e) == str(error):
                return _key(o)
    for i in range(len(overrides)):
        try:
            composed(overrides[: i + 1])
        except Exception:  # any failure: this override is the first that breaks the composition
            return _key(overrides[i])
    return None


def _unparsable(overrides: Sequence[str]) -> str | None:
    """The first override Hydra's grammar rejects on its own, if any."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    for o in overrides:
        try:
            parser.parse_overrides([o])
        except HydraException:
            return o
    return None


def exit_on_bad_overrides(
    script: str | Path,
    config_name: str,
    config_path: str = "../configs/train",
    argv: Sequence[str] | None = None,
    check_job: JobCheck | None = None,
) -> None:
    """:func:`check_overrides` on an entry script's command line: ``error: ...`` on stderr and exit status 2.

    Args:
        script: the entry script's ``__file__``; ``config_path`` is relative to its folder, as in ``hydra.main``.
        config_name: the script's primary config, as in ``hydra.main``.
        config_path: as in ``hydra.main``.
        argv: the command line's arguments (default ``sys.argv[1:]``).
        check_job: the script's check of one job's values (:data:`JobCheck`): with it, a multirun is checked job by
            job before the first runs (:func:`check_sweep`).

    A command line with another flag (``--help``, ``--cfg``, ``--config-name``, ...), or a multirun without
    ``check_job``, is left to Hydra as it is: those change what is composed, or compose nothing.

    Where ``$MARLCRASH_CONFIGS`` holds a ``train/`` folder that differs from the checkout's, a warning says which
    configs the variable gives and which it does not (the script's own, :func:`train_config_dir`).

    First, a script of a checkout (a ``marlcrash/`` package beside its ``train/`` folder) that imports marlcrash
    from elsewhere (a non-editable install, another checkout's editable one) exits the same way: it would run
    that copy's code and configs under the checkout's training configs, and edits to the checkout go unseen.
    """
    _exit_on_other_package(Path(script).resolve())
    _warn_configs_env(config_name)
    args = list(sys.argv[1:] if argv is None else argv)
    flags = [a for a in args if a.startswith("-")]
    config_dir = Path(script).resolve().parent / config_path
    try:
        if not flags:
            check_overrides(config_dir, config_name, args)
        elif check_job is not None and set(flags) <= set(MULTIRUN_FLAGS):
            check_sweep(config_dir, config_name, [a for a in args if not a.startswith("-")], check_job)
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


def train_config_dir() -> Path:
    """The training configs the ``train/`` scripts' ``hydra.main`` composes: the checkout's ``configs/train``.

    Not ``$MARLCRASH_CONFIGS``: Hydra's search path is the scripts' own (``--config-dir`` adds another); that
    variable points the library's configs (env, reward, scenario, sim, cells) elsewhere, which
    :func:`exit_on_bad_overrides` says in a warning.
    """
    return Path(__file__).resolve().parents[2] / "configs" / "train"


def _same_tree(a: Path, b: Path) -> bool:
    """Folders ``a`` and ``b`` hold the same files with the same contents (recursively)."""
    cmp = filecmp.dircmp(a, b)
    _, mismatch, errors = filecmp.cmpfiles(a, b, cmp.common_files, shallow=False)
    if cmp.left_only or cmp.right_only or cmp.common_funny or mismatch or errors:
        return False
    return all(_same_tree(a / d, b / d) for d in cmp.common_dirs)


def _warn_configs_env(config_name: str) -> None:
    """A warning on standard error where ``$MARLCRASH_CONFIGS`` holds a ``train/`` folder other than the checkout's:
    the variable moves the library's configs, not the script's own, so an edited copy there went unread without a
    word."""
    env = os.environ.get("MARLCRASH_CONFIGS")
    if not env or not (Path(env) / "train").is_dir() or _same_tree(Path(env) / "train", train_config_dir()):
        return
    print(
        f"warning: MARLCRASH_CONFIGS={env} gives the env, reward, scenario, sim and cells configs; this script's own "
        f"({config_name}.yaml and its groups) come from {train_config_dir()}, not from its train/, which differs "
        "(Hydra's --config-dir adds a folder searched before it)",
        file=sys.stderr,
    )


def run_script(main: Callable[[], Any]) -> None:
    """Run an entry script's ``hydra.main`` function; a Ctrl-C (at any job of a multirun) prints ``interrupted`` and
    the notes the work added to it (:func:`~marlcrash.errors.report_interrupt`: which run folder keeps what, the
    command that continues it) on standard error, not a traceback, and ends the process by SIGINT, as the
    ``marlcrash`` command does (:func:`~marlcrash.errors.end_by_sigint`): a shell loop of runs stops there."""
    try:
        main()
    except KeyboardInterrupt as e:
        report_interrupt(e)
        end_by_sigint()
        sys.exit(130)  # where a process cannot end by a signal


def sweep_jobs(overrides: Sequence[str]) -> list[list[str]]:
    """The overrides of every job of a multirun's command line, in Hydra's order (its basic sweeper's expansion:
    ``seed=0,1 lr=1,2`` is four jobs).

    Raises:
        ConfigError: an override Hydra's grammar cannot parse, naming it.
    """
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_overrides(list(overrides))
    except HydraException as e:
        bad = _unparsable(overrides) or " ".join(overrides)
        raise ConfigError(f"cannot parse the override {bad!r}: {_first_line(e)}", key=_key(bad)) from None
    return [list(job) for batch in BasicSweeper.split_arguments(parsed, None) for job in batch]


def check_sweep(config_dir: str | Path, config_name: str, overrides: Sequence[str], check: JobCheck) -> None:
    """Check every job of a multirun before the first runs (module doc): its overrides (:func:`check_overrides`), its
    values (``check``) and that no two jobs write one run folder.

    Raises:
        ConfigError: the first job that fails, named with its overrides; or two jobs of one run folder (key
            ``name``).
    """
    jobs = sweep_jobs(overrides)
    folders: dict[Path, int] = {}
    for i, job in enumerate(jobs):
        try:
            cfg = check_overrides(config_dir, config_name, job)
            folder = check(cfg, config_mapping(cfg), [_key(o) for o in job])
        except ConfigError as e:
            shown = " ".join(job).replace("\\{", "{").replace("\\}", "}")  # Hydra's sweeper escapes s${seed}
            raise ConfigError(f"multirun job {i + 1} of {len(jobs)} ({shown}): {e.reason}; no job was run",
                              key=e.key, path=e.path) from None  # fmt: skip
        if folder is None:
            continue
        folder = folder.absolute()
        if folder in folders:
            raise ConfigError(
                f"multirun jobs {folders[folder] + 1} and {i + 1} of {len(jobs)} would write one run folder {folder}; "
                f"give each its own name (name=run_${{seed}}, or leave name out: every job then gets a time stamp of "
                f"its own); no job was run",
                key="name",
            )
        folders[folder] = i


def fixed_run_folder(cfg: Any, config: Any, run_dir: Callable[[Any], Path], given: Sequence[str]) -> Path | None:
    """The run folder of a job whose name is fixed (given, or a plain value in the YAML file): ``None`` for the
    default time-stamped name (:func:`name_default_run` gives each job its own) and for a resume (``resume`` set),
    which continues a run."""
    from omegaconf import OmegaConf

    if getattr(config, "resume", False) not in (False, None):
        return None
    if "name" not in given and OmegaConf.is_interpolation(cfg, "name"):
        return None
    return run_dir(config)


def _exit_on_other_package(script: Path) -> None:
    """``error: ...`` and exit status 2 where ``script``'s checkout has a ``marlcrash`` package other than the one
    imported (see :func:`exit_on_bad_overrides`)."""
    import marlcrash

    checkout = script.parent.parent
    beside = (checkout / "marlcrash").resolve()
    imported = Path(marlcrash.__file__).resolve().parent
    if (beside / "__init__.py").is_file() and imported != beside:
        print(f"error: {script} belongs to the checkout {checkout}, but Python imports marlcrash from {imported} "
              "(a non-editable install, or another checkout's): that copy's code and configs would run, not the "
              f"checkout's; install the checkout editable (pip install -e {checkout}) or run that copy's own "
              "scripts", file=sys.stderr)  # fmt: skip
        sys.exit(2)


def config_mapping(cfg: Any) -> dict[str, Any]:
    """A script's composed Hydra config (a ``DictConfig``, interpolations resolved) as the plain mapping the config
    loaders take; its keys are strings (OmegaConf's type says any container).

    Raises:
        ConfigError: an interpolation that does not resolve (``name=s${sed}``, ``${oc.env:UNSET}``), naming its key
            (OmegaConf's traceback before).
    """
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    try:
        return cast(dict[str, Any], OmegaConf.to_container(cfg, resolve=True))
    except OmegaConfBaseException as e:
        reason = str(getattr(e, "msg", None) or e).splitlines()[0]
        raise ConfigError(f"cannot resolve the value: {reason}", key=str(e.full_key) or None) from None


def name_default_run(cfg: Any, config: Any, run_dir: Callable[[Any], Path], given: Sequence[str] | None = None) -> None:
    """Give a fresh run whose name is the default the first free folder: ``<stamp>``, else ``<stamp>-2``, ``-3``, ...

    The default name is the launch time stamp (``name: ${now:%Y%m%d-%H%M%S}``, to the second), so the jobs of a Hydra
    multirun, which start within a second of each other, shared it and every job after the first was refused as
    "exists already". A name the user gave (on the command line, or as a plain value in the YAML file) is kept, and
    refused later where its folder exists; so is a resumed run's (``resume`` set), which names the run to continue.

    Args:
        cfg: the script's composed Hydra config (its ``name`` node not yet resolved).
        config: the validated config; its ``name`` is changed in place.
        run_dir: the run folder of a config (``<out_dir>/<algorithm>/<name>``, ...).
        given: the keys set on the command line; default: Hydra's record of this job's overrides.
    """
    from omegaconf import OmegaConf

    if given is None:
        from hydra.core.hydra_config import HydraConfig

        given = [_key(o) for o in HydraConfig.get().overrides.task]
    if "name" in given or not OmegaConf.is_interpolation(cfg, "name"):
        return
    if getattr(config, "resume", False) not in (False, None):
        return
    stamp, n = config.name, 1
    while run_dir(config).exists():
        n += 1
        config.name = f"{stamp}-{n}"
