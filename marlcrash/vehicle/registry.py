"""Vehicle registry: names -> vehicle config files in ``configs/vehicle/``.

A vehicle is named by a registered name (``b_segment``), by the path of a synthetic-car
YAML file, or by the path of an LS-DYNA keyword deck (``.k``, ``.key``, ``.dyn``, ``.kw``), which is
read with :func:`marlcrash.vehicle.keyword.read_deck` (imported only when needed).
:class:`VehicleOptions` are the settings of the ``marlcrash`` command's ``--param``, ``--units``, ``--axis-map``
and ``--subassemblies`` as a config section (an env config's ``vehicle_options``), and
:func:`load_configured_vehicle` reads a vehicle with them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from marlcrash.config import checked, config_dir, require
from marlcrash.errors import ConfigError
from marlcrash.vehicle.model import AxisMap, VehicleModel

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


def is_deck(name_or_path: str | Path) -> bool:
    """Whether ``name_or_path`` names a keyword deck (by its suffix, :data:`DECK_SUFFIXES`)."""
    return Path(str(name_or_path)).suffix.lower() in DECK_SUFFIXES


@dataclass
class VehicleOptions:
    """How a vehicle is read: the ``marlcrash`` command's vehicle options as a config section.

    Attributes:
        params: values of ``*PARAMETER`` names the deck uses (``--param``; they override the deck's own) [deck units].
        units: the deck's unit system, a name of :data:`marlcrash.units.UNIT_SYSTEMS` (``--units``); ``None``: detected.
        axis_map: deck axes to marlcrash's, e.g. ``"x=+x,y=+z,z=+y"`` (``--axis-map``); ``None``: the identity.
        subassemblies: a sub-assembly map YAML file (``--subassemblies``, :mod:`marlcrash.vehicle.subassembly_map`),
            for a deck or a synthetic car; ``None``: a deck's parts are their own sub-assemblies, a synthetic car
            keeps its own.

    ``params``, ``units`` and ``axis_map`` apply to keyword decks only (:meth:`require_fits`).
    """

    params: dict[str, float] = field(default_factory=dict)
    units: str | None = None
    axis_map: str | None = None
    subassemblies: str | None = None

    def validate(self) -> None:
        """Finite parameter values, a known unit system, a well-formed axis map, an existing map file."""
        from marlcrash.units import get_unit_system

        for name, value in self.params.items():
            require(math.isfinite(value), f"params.{name}", f"expected a finite number, got {value}")
        if self.units is not None:
            get_unit_system(self.units)  # its error names the key 'units'
        if self.axis_map is not None:
            AxisMap.parse(self.axis_map)  # ... 'axis_map' (or 'axis_map.x')
        if self.subassemblies is not None:
            require(Path(self.subassemblies).is_file(), "subassemblies",
                    f"no sub-assembly map file {self.subassemblies!r}")  # fmt: skip

    def require_fits(self, vehicle: str | Path) -> None:
        """Refuse deck-only options for a vehicle that is not a keyword deck, naming the option (relative key)."""
        if is_deck(vehicle):
            return
        for key in ("params", "units", "axis_map"):
            if getattr(self, key):
                raise ConfigError(
                    f"applies to keyword decks only ({', '.join(DECK_SUFFIXES)}); the vehicle {str(vehicle)!r} is a "
                    "synthetic car",
                    key=key,
                )

    def key(self) -> tuple:
        """A hashable summary (for caches keyed by how a vehicle was read)."""
        return (tuple(sorted(self.params.items())), self.units, self.axis_map, self.subassemblies)


def load_configured_vehicle(
    name_or_path: str | Path, seed: int | None = None, options: VehicleOptions | None = None
) -> VehicleModel:
    """:func:`load_vehicle` with :class:`VehicleOptions` (``None``: the defaults), as the ``marlcrash`` command reads a
    vehicle with its options: a deck read with them, a synthetic car regrouped by the sub-assembly map.

    Raises:
        ConfigError: as :func:`load_vehicle`; options that are no :class:`VehicleOptions` or hold a bad value (checked
            as a config file's are, naming the key); deck-only options for a synthetic car
            (:meth:`VehicleOptions.require_fits`).
    """
    if options is not None and not isinstance(options, VehicleOptions):  # a mapping: "has no attribute require_fits"
        raise ConfigError(
            f"options must be a VehicleOptions, got {type(options).__name__} {options!r:.80}", key="vehicle_options"
        )
    opts = VehicleOptions() if options is None else checked(options)  # one made in Python: as a file's are
    opts.require_fits(name_or_path)
    if is_deck(name_or_path):
        deck = {"params": dict(opts.params) or None, "units": opts.units, "subassemblies": opts.subassemblies,
                "axis_map": AxisMap.parse(opts.axis_map) if opts.axis_map is not None else None}  # fmt: skip
        return load_vehicle(name_or_path, seed=seed, **{k: v for k, v in deck.items() if v is not None})
    model = load_vehicle(name_or_path, seed=seed)
    if opts.subassemblies is not None:
        from marlcrash.vehicle.subassembly_map import load_subassembly_map

        model = model.with_subassemblies(load_subassembly_map(opts.subassemblies, model))
    return model
