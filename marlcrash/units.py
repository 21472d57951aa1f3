"""Unit systems and conversion to SI at the edges.

Everything inside marlcrash is SI (m, kg, s, N, Pa, J). Decks come in the usual
consistent unit systems of explicit crash codes; a :class:`UnitSystem` records
the SI value of one length, mass and time unit, and all derived conversions
follow from those three.
"""

from __future__ import annotations

import math
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


INCH = 0.0254
"""One inch [m] (exact)."""
POUND_FORCE = 4.4482216152605
"""One pound-force [N] (exact: 0.45359237 kg x standard gravity)."""

UNIT_SYSTEMS: dict[str, UnitSystem] = {
    "mm-t-s": UnitSystem("mm-t-s", 1e-3, 1e3, 1.0),  # N, MPa: the usual crash deck
    "mm-kg-ms": UnitSystem("mm-kg-ms", 1e-3, 1.0, 1e-3),  # kN, GPa
    "m-kg-s": UnitSystem("m-kg-s", 1.0, 1.0, 1.0),  # SI
    "mm-g-ms": UnitSystem("mm-g-ms", 1e-3, 1e-3, 1e-3),  # N, MPa
    "cm-g-us": UnitSystem("cm-g-us", 1e-2, 1e-3, 1e-6),  # 1e7 N, Mbar
    # the US customary crash system: length inch, force lbf, time s, so the mass unit is 1 lbf s^2/in (175.1 kg)
    "in-lbf-s": UnitSystem("in-lbf-s", INCH, POUND_FORCE / INCH, 1.0),  # lbf, psi
}
"""The unit systems a deck may use, by name."""

UNIT_SYSTEM_NAMES = ", ".join(UNIT_SYSTEMS)
"""The names of :data:`UNIT_SYSTEMS`, for messages and help texts."""


def get_unit_system(name: str) -> UnitSystem:
    """Look up a unit system by name (one of :data:`UNIT_SYSTEMS`: ``mm-t-s``, ``mm-kg-ms``, ``m-kg-s``,
    ``mm-g-ms``, ``cm-g-us``, ``in-lbf-s``)."""
    try:
        return UNIT_SYSTEMS[name]
    except KeyError:
        raise ConfigError(
            f"unknown unit system {name!r}; expected one of {sorted(UNIT_SYSTEMS)}", key="units"
        ) from None


# Structural materials in a car body span about 1e3 to 1.2e4 kg/m^3, and moduli from
# about 1e9 (polymers) to 4e11 Pa. Mass-scaled decks (density raised to enlarge the
# explicit time step) reach ten times steel, so the density window is wide. The density
# units of mm-t-s, mm-kg-ms, m-kg-s and cm-g-us differ by factors of 1e3 or more, so at
# most one of them fits; mm-g-ms and in-lbf-s differ by 10.7x only, and a steel deck in
# mm-g-ms read as in-lbf-s has a density of 84,000 kg/m^3 (mass-scaled steel) and a
# modulus of 1.4 GPa (a polymer's). The wave speed sqrt(E/rho) of that pair, 130 m/s, is
# no material's: metals and glass have about 5,000 m/s, polymers 1,300 m/s, steel
# mass-scaled 10x 1,600 m/s; so the materials' median wave speed must lie in its window too.
DENSITY_WINDOW = (1e2, 1.5e5)
_MODULUS_WINDOW = (1e8, 1e12)
WAVE_SPEED_WINDOW = (3e2, 1e4)
# One material card is checked against a window 3x wider above: a lumped block with its density lowered (a
# powertrain modelled as a box: cast iron at 850 kg/m^3 has 11,400 m/s) lies above the deck's window. A modulus
# typed in another unit system than the deck's is off by 1e3 or more, its wave speed by 31.6x or more: steel's
# 5,000 m/s becomes 160 or 160,000 m/s, mass-scaled steel's 1,600 becomes 50 or 50,000, all outside.
CARD_WAVE_SPEED_WINDOW = (3e2, 3e4)


def density_fits(density: float, system: UnitSystem) -> bool:
    """Whether a raw density written in ``system``'s units is that of a structural material."""
    return DENSITY_WINDOW[0] <= density * system.density <= DENSITY_WINDOW[1]


def wave_speed(density: np.ndarray | float, modulus: np.ndarray | float, system: UnitSystem) -> np.ndarray:
    """The bar wave speed sqrt(E/rho) [m/s] of raw densities and Young's moduli written in ``system``'s units."""
    e = np.asarray(modulus, dtype=float)
    return np.sqrt(e / np.asarray(density, dtype=float)) * math.sqrt(system.stress / system.density)


def detect_unit_system(densities: np.ndarray, moduli: np.ndarray) -> UnitSystem | None:
    """Guess the unit system from raw material densities and Young's moduli.

    Args:
        densities: raw density values as written in the deck (zeros ignored).
        moduli: raw Young's moduli as written in the deck (zeros ignored), one per density: the same
            materials in the same order.

    Returns:
        The single unit system under which the median density, the median modulus and the median
        wave speed sqrt(E/rho) of the materials that have both are physically plausible, or ``None``
        if none or several fit (the caller must then ask for one).
    """
    rho = np.asarray(densities, dtype=float)
    e = np.asarray(moduli, dtype=float)
    if rho.shape != e.shape:
        raise ValueError(f"expected one modulus per density, got {rho.shape} densities and {e.shape} moduli")
    has_rho = np.isfinite(rho) & (rho > 0)
    has_e = np.isfinite(e) & (e > 0)
    if not has_rho.any():
        return None
    rho_med = float(np.median(rho[has_rho]))
    both = has_rho & has_e
    fits = []
    for system in UNIT_SYSTEMS.values():
        ok = density_fits(rho_med, system)
        if ok and has_e.any():
            m = float(np.median(e[has_e])) * system.stress
            ok = _MODULUS_WINDOW[0] <= m <= _MODULUS_WINDOW[1]
        if ok and both.any():
            c = float(np.median(wave_speed(rho[both], e[both], system)))
            ok = WAVE_SPEED_WINDOW[0] <= c <= WAVE_SPEED_WINDOW[1]
        if ok:
            fits.append(system)
    return fits[0] if len(fits) == 1 else None
