"""A non-editable install (a wheel) ships the configs and runs the ``marlcrash`` commands on the embedded default.

The repository keeps ``configs/`` at its root, beside the package; pyproject.toml maps it into the wheel as
``marlcrash/configs``. These tests build the wheel from a copy of the sources (setuptools writes ``build/`` and
``*.egg-info`` beside the sources it builds), install it into a folder of its own and run it from outside the
checkout, so a config the package needs but the wheel lacks fails here and not on a user's machine.
"""

import glob
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from marlcrash.provenance import _editor_leftover

ROOT = Path(__file__).resolve().parent.parent


def _pyproject() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def test_pyproject_lists_every_package():
    """The explicit package list (needed for the configs mapping) names every package under marlcrash/."""
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    on_disk = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for init in (ROOT / "marlcrash").rglob("__init__.py")
        if "__pycache__" not in init.parts
    }
    assert on_disk <= listed, f"packages missing from pyproject.toml [tool.setuptools] packages: {on_disk - listed}"
    # configs/ and each of its folders (setuptools warned "Package 'marlcrash.configs.env' is absent from the
    # `packages` configuration ... would be ignored" for every folder not listed)
    folders = {
        ".".join(("marlcrash", "configs", *d.relative_to(ROOT / "configs").parts))
        for d in [ROOT / "configs", *(ROOT / "configs").rglob("*")]
        if d.is_dir() and "__pycache__" not in d.parts
    }
    assert listed - on_disk == folders, (
        f"listed but not packages: {listed - on_disk - folders}; configs folders not listed: {folders - listed}"
    )


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("marlcrash", "configs"):
        shutil.copytree(ROOT / name, src / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    out = tmp_path_factory.mktemp("wheel")
    cmd = [sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "--no-build-isolation", str(src), "-w", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=src)
    assert done.returncode == 0, done.stderr
    # setuptools' warning for a data folder it may drop from future wheels (pip shows the build's output with -v)
    assert "is absent from the `packages` configuration" not in done.stdout + done.stderr, done.stdout[-3000:]
    (found,) = out.glob("marlcrash-*.whl")
    return found


def test_wheel_ships_every_config(wheel):
    with zipfile.ZipFile(wheel) as z:
        shipped = {n.removeprefix("marlcrash/configs/") for n in z.namelist() if n.startswith("marlcrash/configs/")}
    # every file a loader could read, not only *.yaml: a scenario saved as extra.yml ran in a checkout and was an
    # "unknown scenario" after pip install, and the test, looking for *.yaml alone, passed
    files = [p for p in (ROOT / "configs").rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    expected = {p.relative_to(ROOT / "configs").as_posix() for p in files}
    expected = {n for n in expected if not any(_editor_leftover(part) for part in n.split("/"))}
    assert expected, "no configs found in the repository"
    assert expected == shipped, f"missing from the wheel: {expected - shipped}; not in configs/: {shipped - expected}"


def test_wheel_ships_the_license_it_declares(wheel):
    """``license = "MIT"`` was declared with no licence text in the repository or the wheel."""
    with zipfile.ZipFile(wheel) as z:
        (name,) = [n for n in z.namelist() if n.endswith(".dist-info/licenses/LICENSE")]
        text = z.read(name).decode()
    assert text.startswith("MIT License") and text == (ROOT / "LICENSE").read_text()


def test_package_data_ships_every_ending_the_config_loaders_read(tmp_path):
    """The loaders read scenarios, rewards and vehicles from ``*.yaml`` and ``*.yml``; package-data shipped
    ``*.yaml`` alone. The patterns are expanded as setuptools does (``glob`` in the package folder, recursive)."""
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    names = ["sim.yaml", "sim.yml", "scenarios/extra.yml", "scenarios/extra.yaml", "train/algorithm/x.yml"]
    for name in names:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("a: 1\n")
    found = {f for pat in patterns["marlcrash.configs"] for f in glob.glob(pat, root_dir=tmp_path, recursive=True)}
    assert set(names) <= found, f"not shipped: {set(names) - found}"


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """The wheel installed into a folder of its own, and an environment that imports it from there: the folder is
    put before the checkout's editable install on ``sys.path``."""
    target = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    env = {k: v for k, v in os.environ.items() if k != "MARLCRASH_CONFIGS"}
    env["PYTHONPATH"] = str(target)
    return target, env


def test_installed_wheel_reads_its_shipped_configs(installed, tmp_path):
    target, env = installed
    code = "import marlcrash, marlcrash.config as c; print(marlcrash.__file__); print(c.config_dir())"
    where = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert where.returncode == 0, where.stderr
    module, configs = where.stdout.split()
    assert Path(module).is_relative_to(target)
    assert Path(configs) == target / "marlcrash" / "configs"


@pytest.mark.slow
def test_installed_wheel_simulates_the_default_car(installed, tmp_path):
    """Outside the checkout, the installed package simulates the embedded default car (its numba kernels compile
    afresh there, hence slow)."""
    _, env = installed
    done = subprocess.run(
        [sys.executable, "-m", "marlcrash", "simulate", "--json", "--csv", "pulse.csv"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["scenario"] == "full_width_40"
    assert (tmp_path / "pulse.csv").stat().st_size > 0
