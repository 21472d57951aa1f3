"""Shared fixtures: paths to optional shared test data, small configs."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
LSOPT_DECK = SHARED_DATA / "lsopt_small_car5.k"


@pytest.fixture
def lsopt_deck() -> Path:
    """The public LS-OPT small-car deck; the test is skipped where ../shared is absent."""
    if not LSOPT_DECK.is_file():
        pytest.skip("../shared/data/lsopt_small_car5.k not available")
    return LSOPT_DECK
