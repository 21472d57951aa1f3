"""The README's commands (and those of the pages it links in ``docs/``) work as written, as far as that can be checked
without running them.

Every ``python train/<script>.py`` command of a ```bash block (and every inline one) composes with Hydra and passes
the script's config loader, every ``marlcrash`` command of a ```bash block parses, and every inline
``python benchmarks/<script>.py`` command's options parse. A command whose override cannot reach the script (a
quoted mapping broken over two lines: Hydra's grammar refuses the newline) fails here, not on a user's machine.
"""

from __future__ import annotations

import argparse
import re
import runpy
import shlex
import sys
from pathlib import Path

import pytest

from marlcrash.calibrate.entry import check_overrides
from marlcrash.config import config_dir
from marlcrash.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
README = "\n".join(p.read_text() for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
"""The README and the study pages it links (``docs/*.md``): their commands are the README's too."""

PLACEHOLDERS = {"<name>": "x", "<time stamp>": "x", "N": "1000", "S": "0", "V": "1e-3"}
"""Words the README writes for a value of the user's, and a value of that kind."""

PLACEHOLDER_FILES = ("car.k", "car_map.yaml", "lsopt_small_car5.k", "test123.csv")
"""Files the README's examples name that the repository does not hold (a user's deck, ../shared/data)."""


def _argv(command: str) -> list[str]:
    argv = shlex.split(command, comments=True)
    while argv and re.match(r"^[A-Z_]+=", argv[0]):  # VAR=value prefixes
        argv = argv[1:]
    out = []
    for a in argv:
        if re.fullmatch(r"\[--[\w-]+\]", a):  # an optional flag, written [--flag]
            a = a[1:-1]
        a = a.replace("<name>", PLACEHOLDERS["<name>"]).replace("<time stamp>", PLACEHOLDERS["<time stamp>"])
        key, eq, value = a.rpartition("=")
        if value in PLACEHOLDERS:
            a = f"{key}{eq}{PLACEHOLDERS[value]}"
        out.append(a)
    return out


def _block_commands() -> list[str]:
    """The commands of the README's ```bash blocks, one string each (continuation lines and quotes joined)."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README, re.S):
        buf = ""
        for line in re.sub(r"\\\n", " ", block).splitlines(keepends=True):
            buf += line
            try:
                shlex.split(buf, comments=True)
            except ValueError:  # an open quote: the command goes on (with the newline in the argument)
                continue
            commands += [c for c in re.split(r"&&", buf) if c.strip()]
            buf = ""
    return commands


def _inline_commands(program: str) -> list[str]:
    return [" ".join(c.split()) for c in re.findall(rf"`(python\s+{program}/[^`]+)`", README)]


def _commands(script_dir: str, inline: bool = True) -> list[list[str]]:
    found = {}
    for c in _block_commands() + (_inline_commands(script_dir) if inline else []):
        argv = _argv(c)
        if len(argv) >= 2 and Path(argv[0]).name.startswith("python") and argv[1].startswith(f"{script_dir}/"):
            found[tuple(argv[1:])] = argv[1:]
    return list(found.values())


TRAIN = _commands("train")
BENCHMARKS = _commands("benchmarks")
CLI = [a[1:] for a in map(_argv, _block_commands()) if a and a[0] == "marlcrash"]


def test_the_readme_shows_commands_of_every_kind():
    scripts = {Path(a[0]).stem for a in TRAIN}
    assert {"train", "evaluate", "baseline", "compare", "ablate", "amortized"} <= scripts
    assert len(BENCHMARKS) >= 8 and len(CLI) >= 10


def _loader(name: str):
    from marlcrash.calibrate.ablate import load_ablation_config
    from marlcrash.calibrate.amortized import load_amortized_config
    from marlcrash.calibrate.baselines import load_run_config
    from marlcrash.calibrate.compare import load_compare_config
    from marlcrash.calibrate.evaluate import load_evaluate_config
    from marlcrash.calibrate.marl import load_train_config

    return {
        "train": lambda d: load_train_config(d, source="configs/train/train.yaml", ci=False),
        "baseline": lambda d: load_run_config(d, source="configs/train/baseline.yaml"),
        "compare": lambda d: load_compare_config(d, source="configs/train/compare.yaml"),
        "ablate": lambda d: load_ablation_config(d, source="configs/train/ablate.yaml"),
        "amortized": lambda d: load_amortized_config(d, source="configs/train/amortized.yaml"),
        "evaluate": lambda d: load_evaluate_config(d, source="configs/train/evaluate.yaml"),
    }[name]


@pytest.mark.parametrize("argv", TRAIN, ids=lambda a: " ".join(a)[:80])
def test_a_readme_train_command_composes_and_loads(argv):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    name = Path(argv[0]).stem
    overrides = argv[1:]
    if "-m" in overrides or "--multirun" in overrides:  # a sweep: each job gets the first value of each list
        overrides = [o.split(",")[0] if "=" in o and "[" not in o and "{" not in o else o for o in overrides]
        overrides = [o for o in overrides if o not in ("-m", "--multirun")]
    check_overrides(config_dir() / "train", name, overrides)  # what the script runs before Hydra
    with initialize_config_dir(config_dir=str(config_dir() / "train"), version_base=None):
        cfg = compose(name, overrides=overrides)
    data = OmegaConf.to_container(cfg, resolve=False)
    if isinstance(data.get("name"), str) and "${now:" in data["name"]:
        data["name"] = "stamp"  # Hydra's ${now:} resolver needs a running app
    data = OmegaConf.to_container(OmegaConf.create(data), resolve=True)
    try:
        _loader(name)(data)
    except ConfigError as e:  # a file of the user's that the example only names
        if not any(f in str(e) for f in PLACEHOLDER_FILES):
            raise


@pytest.mark.parametrize("argv", CLI, ids=lambda a: " ".join(a)[:80])
def test_a_readme_marlcrash_command_parses(argv):
    from marlcrash.cli import build_parser

    build_parser().parse_args(argv)


class _Parsed(Exception):
    pass


@pytest.mark.parametrize("argv", BENCHMARKS, ids=lambda a: " ".join(a)[:80])
def test_a_readme_benchmark_command_parses(argv, monkeypatch):
    script = ROOT / argv[0]
    assert script.is_file(), argv[0]
    parse = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        parse(self, args, namespace)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    monkeypatch.setattr(sys, "argv", [str(script), *argv[1:]])
    main = runpy.run_path(str(script), run_name="readme_check")["main"]
    with pytest.raises(_Parsed):
        main()


def test_the_readmes_links_into_the_repository_reach_a_file_and_heading():
    """A relative link of the README or a ``docs/`` page (``docs/x.md#heading``, ``../README.md#heading``,
    ``#heading``) names a file that exists and, with an anchor, a heading of it (GitHub's anchor rule: lower case,
    punctuation dropped, spaces to hyphens): moving a section to a study page must not leave a link behind."""

    def anchors(text: str) -> set[str]:
        heads = re.findall(r"^#+ (.+)$", re.sub(r"```.*?```", "", text, flags=re.S), re.M)
        return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in heads}

    broken = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = page.read_text()
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and file.suffix == ".md" and anchor not in anchors(file.read_text()):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert not broken, broken
