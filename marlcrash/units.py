"""Unit systems and conversion to SI at the edges.

Everything inside marlcrash is SI (m, kg, s, N, Pa, J). Decks come in the usual
consistent unit systems of explicit crash codes; a :class:`UnitSystem` records
the SI value of one length, mass and time unit, and all derived conversions
follow from those three.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlcrash.errors import ConfigError

G0 = 9.80665
"""Standard gravity [m/s^2], used to express accelerations in g."""


@dataclass(frozen=True)
class UnitSystem:
    """A consistent unit system: SI value of its length, mass and time unit."""

    name: str
    length: float  # [m] per length unit
    mass: float  # [kg] per mass unit
    time: float  # [s] per time unit

    @property
    def density(self) -> float:
        """SI value [kg/m^3] of one density unit."""
        return self.mass / self.length**3

    @property
    def stress(self) -> float:
        """SI value [Pa] of one stress unit."""
        return self.mass / (self.length * self.time**2)

    @property
    def force(self) -> float:
        """SI value [N] of one force unit."""
        return self.mass * self.length / self.time**2

    @property
    def energy(self) -> float:
        """SI value [J] of one energy unit."""
        return self.force * self.length

    @property
    def velocity(self) -> float:
        """SI value [m/s] of one velocity unit."""
        return self.length / self.time

    @property
    def area(self) -> float:
        """SI value [m^2] of one area unit."""
        return self.length**2


UNIT_SYSTEMS: dict[str, UnitSystem] = {
    "mm-t-s": UnitSystem("mm-t-s", 1e-3, 1e3, 1.0),
    "mm-kg-ms": UnitSystem("mm-kg-ms", 1e-3, 1.0, 1e-3),
    "m-kg-s": UnitSystem("m-kg-s", 1.0, 1.0, 1.0),
}
"""The unit systems a deck may use, by name."""


def get_unit_system(name: str) -> UnitSystem:
    """Look up a unit system by name (``mm-t-s``, ``mm-kg-ms``, ``m-kg-s``)."""
    try:
        return UNIT_SYSTEMS[name]
    except KeyError:
        raise ConfigError(
            f"unknown unit system {name!r}; expected one of {sorted(UNIT_SYSTEMS)}", key="units"
        ) from None


# Structural materials in a car body span about 1e3 to 1.2e4 kg/m^3, and moduli from
# about 1e9 (polymers) to 4e11 Pa. Mass-scaled decks (density raised to enlarge the
# explicit time step) reach ten times steel, so the density window is wide; the three
# unit systems still differ by factors of 1e3 or more, so at most one fits.
DENSITY_WINDOW = (1e2, 1.5e5)
_MODULUS_WINDOW = (1e8, 1e12)


def density_fits(density: float, system: UnitSystem) -> bool:
    """Whether a raw density written in ``system``'s units is that of a structural material."""
    return DENSITY_WINDOW[0] <= density * system.density <= DENSITY_WINDOW[1]


def detect_unit_system(densities: np.ndarray, moduli: np.ndarray) -> UnitSystem | None:
    """Guess the unit system from raw material densities and Young's moduli.

    Args:
        densities: raw density values as written in the deck (zeros ignored).
        moduli: raw Young's moduli as written in the deck (zeros ignored).

    Returns:
        The single unit system under which both medians are physically plausible,
        or ``None`` if none or several fit (the caller must then ask for one).
    """
    rho = np.asarray(densities, dtype=float)
    e = np.asarray(moduli, dtype=float)
    rho = rho[np.isfinite(rho) & (rho > 0)]
    e = e[np.isfinite(e) & (e > 0)]
    if rho.size == 0:
        return None
    fits = []
    for system in UNIT_SYSTEMS.values():
        ok = density_fits(float(np.median(rho)), system)
        if ok and e.size:
            m = float(np.median(e)) * system.stress
            ok = _MODULUS_WINDOW[0] <= m <= _MODULUS_WINDOW[1]
        if ok:
            fits.append(system)
    return fits[0] if len(fits) == 1 else None
