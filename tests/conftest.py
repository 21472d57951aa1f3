"""Shared fixtures: paths to optional shared test data, small configs."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

# the suite tests the configs/ it ships: a MARLCRASH_CONFIGS of the user's shell made the "shipped configs" tests read
# another folder (a false "differs from configs/sim.yaml", or drift hidden); tests that want one set it themselves
os.environ.pop("MARLCRASH_CONFIGS", None)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
LSOPT_DECK = SHARED_DATA / "lsopt_small_car5.k"


@pytest.fixture
def umask() -> Iterator[Callable[[int], None]]:
    """Set the process umask for a test (``umask(0o022)``); the one before the test is restored after it."""
    old = os.umask(0o022)
    os.umask(old)
    yield os.umask
    os.umask(old)


@pytest.fixture
def lsopt_deck() -> Path:
    """The public LS-OPT small-car deck; the test is skipped where ../shared is absent."""
    if not LSOPT_DECK.is_file():
        pytest.skip("../shared/data/lsopt_small_car5.k not available")
    return LSOPT_DECK


SHORT_DURATION = 0.03  # [s] simulated window of the shortened scenarios


@pytest.fixture(scope="session")
def short_configs(tmp_path_factory) -> Path:
    """A copy of configs/ whose scenarios last SHORT_DURATION s (scripts read it via $MARLCRASH_CONFIGS)."""
    import shutil

    import yaml

    from marlcrash.config import config_dir

    dst = tmp_path_factory.mktemp("configs") / "configs"
    shutil.copytree(config_dir(), dst)
    for p in (dst / "scenarios").glob("*.yaml"):
        data = yaml.safe_load(p.read_text())
        data["duration"] = SHORT_DURATION
        p.write_text(yaml.safe_dump(data))
    return dst


@pytest.fixture(scope="module")
def short(short_configs) -> Path:
    """``short_configs`` in effect ($MARLCRASH_CONFIGS) for a whole test module."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MARLCRASH_CONFIGS", str(short_configs))
        yield short_configs


@pytest.fixture(scope="session")
def default_cells():
    """The embedded default car's optimized cell model (discretized once per test session)."""
    from marlcrash.cells import discretize
    from marlcrash.vehicle.synthetic import default_vehicle

    return discretize(default_vehicle())


@pytest.fixture(scope="session")
def default_sim(default_cells):
    """The surrogate of :func:`default_cells` with ``configs/sim.yaml``."""
    from marlcrash.sim import Surrogate

    return Surrogate(default_cells)
