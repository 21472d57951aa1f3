"""Materials as the 8-vector of the method (DESIGN 1.1), in SI units.

``M = (rho, Y, G, K, sigma_y, sigma_u, sigma_f, nu)``: density [kg/m^3], Young's,
shear and bulk moduli [Pa], yield, ultimate and fracture strength [Pa] and
Poisson's ratio [-]. Decks rarely give all eight; :func:`complete_material`
derives what follows from elasticity and defaults the rest, recording a warning
for every defaulted value so nothing is filled in silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from marlcrash.errors import ModelError

MATERIAL_FIELDS: tuple[str, ...] = (
    "density",
    "youngs_modulus",
    "shear_modulus",
    "bulk_modulus",
    "yield_strength",
    "ultimate_strength",
    "fracture_strength",
    "poisson_ratio",
)
"""Order of the material 8-vector (paper Eq. 2)."""

DEFAULT_POISSON = 0.3
# Ratios used only when a deck gives no strength at all (e.g. *MAT_ELASTIC, *MAT_RIGID):
# yield strain of common car-body steels and aluminium alloys is 1e-3 to 3e-3.
DEFAULT_YIELD_STRAIN = 1.2e-3
DEFAULT_ULTIMATE_OVER_YIELD = 1.3


@dataclass(frozen=True)
class Material:
    """One material in SI units.

    Attributes:
        id: material id in the deck.
        name: readable name (card title or keyword).
        kind: source model: ``elastic``, ``plastic_kinematic``, ``piecewise_linear``,
            ``rigid`` or ``other``.
        density .. poisson_ratio: the 8-vector entries, ``nan`` where unknown before
            :func:`complete_material`.
        warnings: one line per value that was defaulted rather than read or derived.
    """

    id: int
    name: str
    kind: str
    density: float
    youngs_modulus: float
    shear_modulus: float = math.nan
    bulk_modulus: float = math.nan
    yield_strength: float = math.nan
    ultimate_strength: float = math.nan
    fracture_strength: float = math.nan
    poisson_ratio: float = math.nan
    warnings: tuple[str, ...] = field(default=(), compare=False)

    @property
    def is_rigid(self) -> bool:
        """Whether the material is a rigid body (``*MAT_RIGID``)."""
        return self.kind == "rigid"

    def vector(self) -> np.ndarray:
        """The 8-vector ``[rho, Y, G, K, sigma_y, sigma_u, sigma_f, nu]`` (float64)."""
        return np.array([getattr(self, f) for f in MATERIAL_FIELDS], dtype=np.float64)


def complete_material(m: Material) -> Material:
    """Fill the missing entries of a material's 8-vector.

    ``G = Y / (2 (1 + nu))`` and ``K = Y / (3 (1 - 2 nu))`` are derived; a missing
    Poisson's ratio (``nan``; a given 0 is kept), yield, ultimate or fracture strength
    (``nan`` or 0) is defaulted, and each default is recorded in ``warnings``.

    Raises:
        ModelError: density or Young's modulus missing, non-finite or not positive
            (they cannot be guessed), a negative strength, or Poisson's ratio outside (-1, 0.5).
    """
    where = f"material {m.id} ({m.name})"
    if not (math.isfinite(m.density) and m.density >= 0):
        raise ModelError(f"{where}: density must be a finite value >= 0, got {m.density}")
    if not (math.isfinite(m.youngs_modulus) and m.youngs_modulus > 0):
        raise ModelError(f"{where}: Young's modulus must be a finite value > 0, got {m.youngs_modulus}")
    warnings = list(m.warnings)
    nu = m.poisson_ratio
    if not math.isfinite(nu):  # nan: not given (a blank field); 0 is a Poisson's ratio (cork, foams, honeycombs)
        nu = DEFAULT_POISSON
        warnings.append(f"{where}: Poisson's ratio missing, defaulted to {nu}")
    if not -1.0 < nu < 0.5:
        raise ModelError(f"{where}: Poisson's ratio must lie in (-1, 0.5), got {nu}")
    y = m.youngs_modulus
    g = m.shear_modulus if math.isfinite(m.shear_modulus) and m.shear_modulus > 0 else y / (2 * (1 + nu))
    k = m.bulk_modulus if math.isfinite(m.bulk_modulus) and m.bulk_modulus > 0 else y / (3 * (1 - 2 * nu))
    given = {"yield": m.yield_strength, "ultimate": m.ultimate_strength, "fracture": m.fracture_strength}
    for label, val in given.items():
        if math.isfinite(val) and val < 0:  # 0 or blank reads as "not given"; a negative strength is a typo
            raise ModelError(f"{where}: {label} strength must be > 0 (0 or blank: not given), got {val:.4g} Pa")
    sy = m.yield_strength
    if not (math.isfinite(sy) and sy > 0):
        sy = DEFAULT_YIELD_STRAIN * y
        warnings.append(f"{where}: yield strength missing, defaulted to {sy:.4g} Pa (Y x {DEFAULT_YIELD_STRAIN})")
    su = m.ultimate_strength
    if not (math.isfinite(su) and su > 0):
        su = DEFAULT_ULTIMATE_OVER_YIELD * sy
        warnings.append(
            f"{where}: ultimate strength missing, defaulted to {su:.4g} Pa (yield x {DEFAULT_ULTIMATE_OVER_YIELD})"
        )
    if su < sy:  # e.g. a stress-strain curve whose maximum is below SIGY; sigma_u >= sigma_y by definition
        warnings.append(f"{where}: ultimate strength {su:.4g} Pa is below the yield strength {sy:.4g} Pa; raised to it")
        su = sy
    sf = m.fracture_strength
    if not (math.isfinite(sf) and sf > 0):
        sf = su
        warnings.append(f"{where}: fracture strength missing, defaulted to the ultimate strength")
    return replace(
        m,
        shear_modulus=g,
        bulk_modulus=k,
        yield_strength=sy,
        ultimate_strength=su,
        fracture_strength=sf,
        poisson_ratio=nu,
        warnings=tuple(warnings),
    )


def mass_weighted(vectors: np.ndarray, masses: np.ndarray) -> np.ndarray:
    """Mass-weighted aggregate of material 8-vectors.

    Args:
        vectors: ``[n, 8]`` material vectors.
        masses: ``[n]`` masses [kg] with which each vector is present.

    Returns:
        ``[8]`` aggregate; zeros if the total mass is zero.
    """
    masses = np.asarray(masses, dtype=np.float64)
    total = masses.sum()
    if total <= 0:
        return np.zeros(len(MATERIAL_FIELDS))
    return (np.asarray(vectors, dtype=np.float64) * masses[:, None]).sum(axis=0) / total
