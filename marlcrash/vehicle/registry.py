"""Vehicle registry: names -> vehicle config files in ``configs/vehicle/``.

A vehicle is named by a registered name (``b_segment``), by the path of a synthetic-car
YAML file, or by the path of an LS-DYNA keyword deck (``.k``, ``.key``, ``.dyn``, ``.kw``), which is
read with :func:`marlcrash.vehicle.keyword.read_deck` (imported only when needed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from marlcrash.config import config_dir
from marlcrash.errors import ConfigError
from marlcrash.vehicle.model import VehicleModel

VEHICLES: dict[str, str] = {
    "b_segment": "b_segment.yaml",
}
"""Registered vehicle name -> YAML file name inside ``configs/vehicle/``."""

DEFAULT_VEHICLE = "b_segment"
"""The embedded default vehicle."""

DECK_SUFFIXES = (".k", ".key", ".dyn", ".kw")
"""File suffixes read as LS-DYNA keyword decks (the ``marlcrash`` command's too)."""


def vehicle_dir() -> Path:
    """The folder of vehicle configs (``<configs>/vehicle``)."""
    return config_dir() / "vehicle"


def list_vehicles() -> list[str]:
    """Registered vehicle names, sorted."""
    return sorted(VEHICLES)


def vehicle_config_path(name: str) -> Path:
    """The YAML file of a registered vehicle.

    Raises:
        ConfigError: ``name`` is not registered (the message lists the known names).
    """
    try:
        return vehicle_dir() / VEHICLES[name]
    except KeyError:
        raise ConfigError(
            f"unknown vehicle {name!r}; expected a registered name {list_vehicles()}, "
            f"a synthetic-car .yaml file or a keyword deck ({', '.join(DECK_SUFFIXES)})",
            key="vehicle",
        ) from None


def load_vehicle(name_or_path: str | Path, seed: int | None = None, **deck_options: Any) -> VehicleModel:
    """Build or read a vehicle.

    Args:
        name_or_path: a registered name (:func:`list_vehicles`), the path of a synthetic-car
            YAML file, or the path of a keyword deck (``.k``, ``.key``, ``.dyn``, ``.kw``).
        seed: variant seed for synthetic cars (``None``: nominal). A deck has no variants.
        **deck_options: keyword arguments of :func:`marlcrash.vehicle.keyword.read_deck`
            (``params``, ``units``, ``axis_map``, ``subassemblies``, ``name``); decks only.

    Returns:
        A validated :class:`VehicleModel` in SI units and marlcrash axes.

    Raises:
        ConfigError: unknown name, missing file, a seed given for a deck, or deck options
            given for a synthetic car.
    """
    from marlcrash.vehicle.synthetic import build_vehicle, load_synthetic_config

    text = str(name_or_path)
    path = Path(text)
    suffix = path.suffix.lower()
    if suffix in DECK_SUFFIXES:
        if seed is not None:
            raise ConfigError(
                f"seed={seed} given for the deck {path.name}; only synthetic cars have variants", key="seed"
            )
        if not path.is_file():
            raise ConfigError(f"deck file not found: {path}", key="vehicle")
        from marlcrash.vehicle.keyword import read_deck

        return read_deck(path, **deck_options)
    if deck_options:
        raise ConfigError(
            f"options {sorted(deck_options)} apply to keyword decks only, not to the synthetic car {text!r}",
            key="vehicle",
        )
    if suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise ConfigError(f"vehicle config file not found: {path}", key="vehicle")
        return build_vehicle(load_synthetic_config(path), seed=seed)
    return build_vehicle(load_synthetic_config(vehicle_config_path(text)), seed=seed)
