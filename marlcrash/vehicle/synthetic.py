"""The synthetic B-segment car: the embedded default vehicle (DESIGN section 3).

:func:`build_vehicle` turns a :class:`SyntheticCarConfig` (``configs/vehicle/b_segment.yaml``)
into a :class:`~marlcrash.vehicle.model.VehicleModel` in marlcrash axes: x rearward with
x = 0 at the bumper face, y lateral with +y to the left, z up with the ground at z = 0, the
car centred on y = 0. The front structure is meshed with shells (closed box sections,
panels, closed boxes) and one solid block (the powertrain); the passenger compartment is a
closed rigid shell box whose density is solved so the car weighs exactly ``total_mass``.

Seeded variants (domain randomization) scale dimensions, rail sections, thicknesses and
masses by factors drawn from ``numpy.random.default_rng(seed)``; ``seed=None`` is the
nominal, mirror-symmetric car. The total mass is the configured one for every variant.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from marlcrash.config import checked, config_dir, load_config, require, require_seed
from marlcrash.errors import ConfigError
from marlcrash.vehicle import shapes
from marlcrash.vehicle.materials import Material, complete_material
from marlcrash.vehicle.model import COMPARTMENT, Part, VehicleModel, empty_float, empty_int

MATERIAL_KINDS = ("elastic", "plastic_kinematic", "piecewise_linear", "rigid")
"""Material kinds the keyword writer can write."""

SUBASSEMBLIES: tuple[str, ...] = (
    "bumper_beam",
    "crash_box_left",
    "crash_box_right",
    "front_rail_left",
    "front_rail_right",
    "upper_load_path_left",
    "upper_load_path_right",
    "shock_tower_left",
    "shock_tower_right",
    "subframe",
    "cooling_module",
    "powertrain",
    "dash_firewall",
    "hood",
    "wheel_left",
    "wheel_right",
    COMPARTMENT,
)
"""Sub-assemblies of the synthetic car, in part-id order."""

SIDES: tuple[tuple[str, float], ...] = (("left", 1.0), ("right", -1.0))
"""Paired parts: name suffix and sign of y."""

# Fields scaled by the ``variation.dimensions`` spread, per component (one factor per field).
_VARIED_DIMENSIONS: dict[str, tuple[str, ...]] = {
    "bumper_beam": ("depth", "height"),
    "crash_box": ("length", "width", "height"),
    "upper_load_path": ("width", "height"),
    "shock_tower": ("length", "width"),
    "subframe": ("width", "height"),
    "cooling_module": ("depth", "width", "height"),
    "powertrain": ("length", "width", "height"),
}
# Keys that may be zero; every other number of a component must be > 0.
_MAY_BE_ZERO = {"bumper_beam.sweep", "compartment.gap"}
_MAX_THICKNESS = 0.01  # [m]; a car-body sheet beyond 10 mm is a unit mistake (mm given as m)
_MAX_ELEMENT_SIZE = 0.04  # [m]; the cell discretization samples shells and needs a fine mesh
_MIN_ELEMENT_SIZE = 0.002  # [m]; finer than crash meshes (about 5 mm): at 1e-5 m the mesh would take ~100 GB
_SCENE_COLORS = np.array(
    [
        [31, 119, 180],
        [255, 127, 14],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [140, 86, 75],
        [227, 119, 194],
        [188, 189, 34],
        [23, 190, 207],
        [127, 127, 127],
    ],
    dtype=np.uint8,
)


# ----------------------------------------------------------------------------- materials
@dataclass
class MaterialSpec:
    """One material of the library (``configs/materials.yaml``); strengths in MPa, moduli in GPa."""

    kind: Literal["elastic", "plastic_kinematic", "piecewise_linear", "rigid"]
    density: float
    youngs_modulus_gpa: float
    poisson_ratio: float
    yield_strength_mpa: float
    ultimate_strength_mpa: float
    fracture_strength_mpa: float
    description: str = ""


@dataclass
class MaterialLibraryConfig:
    """The material library: name -> :class:`MaterialSpec`."""

    materials: dict[str, MaterialSpec]

    def validate(self) -> None:
        require(bool(self.materials), "materials", "the library lists no material")
        for name, m in self.materials.items():
            key = f"materials.{name}"
            for f in ("density", "youngs_modulus_gpa", "yield_strength_mpa", "ultimate_strength_mpa"):
                v = getattr(m, f)
                require(math.isfinite(v) and v > 0, f"{key}.{f}", f"expected a finite value > 0, got {v}")
            v = m.fracture_strength_mpa
            require(math.isfinite(v) and v > 0, f"{key}.fracture_strength_mpa", f"expected a value > 0, got {v}")
            require(
                -1.0 < m.poisson_ratio < 0.5,
                f"{key}.poisson_ratio",
                f"expected a value in (-1, 0.5), got {m.poisson_ratio}",
            )
            require(
                m.ultimate_strength_mpa >= m.yield_strength_mpa,
                f"{key}.ultimate_strength_mpa",
                f"ultimate strength {m.ultimate_strength_mpa} MPa is below yield {m.yield_strength_mpa} MPa",
            )
            require(  # engineering values: the ultimate strength is the largest engineering stress
                m.fracture_strength_mpa <= m.ultimate_strength_mpa,
                f"{key}.fracture_strength_mpa",
                f"fracture strength {m.fracture_strength_mpa} MPa is above the ultimate {m.ultimate_strength_mpa} MPa "
                "(engineering stresses: the ultimate is the largest)",
            )


def load_material_library(path: str | Path | None = None) -> dict[str, Material]:
    """Read the material library into complete SI materials.

    Args:
        path: YAML file; ``None`` reads ``materials.yaml`` in the configs folder.

    Returns:
        Name -> :class:`Material` (``id`` 0; the builder assigns ids), all 8 entries filled
        (shear and bulk moduli derived from Young's modulus and Poisson's ratio).

    Raises:
        ConfigError: unreadable file, unknown key, or an impossible value (named by key).
    """
    path = config_dir() / "materials.yaml" if path is None else Path(path)
    lib = load_config(MaterialLibraryConfig, path)
    out = {}
    for name, m in lib.materials.items():
        out[name] = complete_material(
            Material(
                id=0,
                name=name,
                kind=m.kind,
                density=m.density,
                youngs_modulus=m.youngs_modulus_gpa * 1e9,
                poisson_ratio=m.poisson_ratio,
                yield_strength=m.yield_strength_mpa * 1e6,
                ultimate_strength=m.ultimate_strength_mpa * 1e6,
                fracture_strength=m.fracture_strength_mpa * 1e6,
            )
        )
    return out


# -------------------------------------------------------------------------- config schema
@dataclass
class MeshConfig:
    """Mesh resolution [m]."""

    element_size: float
    compartment_element_size: float


@dataclass
class BodyConfig:
    """Overall dimensions [m]."""

    length: float
    width: float
    height: float
    floor_z: float
    front_overhang: float
    dash_x: float


@dataclass
class CompartmentConfig:
    """The rigid passenger compartment box."""

    gap: float
    thickness: float
    material: str


@dataclass
class BumperBeamConfig:
    """Closed box-section bumper beam along y."""

    width: float
    depth: float
    height: float
    z_center: float
    sweep: float
    thickness: float
    material: str


@dataclass
class CrashBoxConfig:
    """Closed box-section crash boxes between bumper beam and rails (on the rail axis)."""

    length: float
    width: float
    height: float
    thickness: float
    material: str


@dataclass
class FrontRailConfig:
    """Closed box-section front rails from the crash boxes to the dash."""

    y_center: float
    z_center: float
    width: float
    height: float
    thickness: float
    material: str


@dataclass
class UpperLoadPathConfig:
    """Closed box-section upper (apron) rails at shock-tower height, running to the dash."""

    x_front: float
    y_center: float
    z_center: float
    width: float
    height: float
    thickness: float
    material: str


@dataclass
class ShockTowerConfig:
    """Shock towers: vertical box sections, closed at the top, open at the bottom."""

    x_center: float
    y_center: float
    length: float
    width: float
    z_bottom: float
    z_top: float
    thickness: float
    material: str


@dataclass
class SubframeConfig:
    """Engine cradle: two side members and two cross members, closed box sections."""

    x_front: float
    x_rear: float
    y_center: float
    z_center: float
    width: float
    height: float
    thickness: float
    material: str


@dataclass
class CoolingModuleConfig:
    """Radiator pack: a closed shell box."""

    x_front: float
    depth: float
    width: float
    height: float
    z_center: float
    thickness: float
    material: str


@dataclass
class PowertrainConfig:
    """Engine and gearbox: a solid hex block of effective density."""

    x_front: float
    length: float
    width: float
    height: float
    z_bottom: float
    mass: float
    material: str


@dataclass
class DashConfig:
    """Dash/firewall: a transverse panel at ``body.dash_x``."""

    width: float
    z_bottom: float
    z_top: float
    thickness: float
    material: str


@dataclass
class HoodConfig:
    """Hood (bonnet): an inclined panel from its front edge to the dash."""

    x_front: float
    z_front: float
    z_rear: float
    width: float
    thickness: float
    material: str


@dataclass
class WheelConfig:
    """Front wheels: closed cylindrical shells about the front axle, of effective density."""

    track: float
    radius: float
    width: float
    mass: float
    thickness: float
    material: str


@dataclass
class VariationConfig:
    """Relative spreads (uniform +-) of the seeded variants."""

    dimensions: float
    rail_section: float
    thickness: float
    mass: float


@dataclass
class SyntheticCarConfig:
    """Schema of a synthetic car (``configs/vehicle/*.yaml``); SI units (m, kg)."""

    name: str
    total_mass: float
    materials: str
    mesh: MeshConfig
    body: BodyConfig
    compartment: CompartmentConfig
    bumper_beam: BumperBeamConfig
    crash_box: CrashBoxConfig
    front_rail: FrontRailConfig
    upper_load_path: UpperLoadPathConfig
    shock_tower: ShockTowerConfig
    subframe: SubframeConfig
    cooling_module: CoolingModuleConfig
    powertrain: PowertrainConfig
    dash_firewall: DashConfig
    hood: HoodConfig
    wheel: WheelConfig
    variation: VariationConfig

    def components(self) -> dict[str, Any]:
        """Section name -> nested config, in declaration order."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if dataclasses.is_dataclass(getattr(self, f.name))
        }

    def rail_front_x(self, y: float) -> float:
        """x [m] of the back of the (swept) bumper beam at lateral position ``y``."""
        b = self.bumper_beam
        return b.depth + b.sweep * (y / (0.5 * b.width)) ** 2

    def validate(self) -> None:
        """Check every value and the geometric consistency; raise :class:`ConfigError` naming the key."""
        require(
            math.isfinite(self.total_mass) and self.total_mass > 0,
            "total_mass",
            f"expected > 0 kg, got {self.total_mass}",
        )
        for section, comp in self.components().items():
            for f in dataclasses.fields(comp):
                v = getattr(comp, f.name)
                if not isinstance(v, float):
                    continue
                key = f"{section}.{f.name}"
                if section == "variation":
                    require(0.0 <= v < 0.5, key, f"expected a relative spread in [0, 0.5), got {v}")
                elif key in _MAY_BE_ZERO:
                    require(math.isfinite(v) and v >= 0, key, f"expected a finite value >= 0, got {v}")
                else:
                    require(math.isfinite(v) and v > 0, key, f"expected a finite value > 0, got {v}")
                if f.name == "thickness" and section != "variation":
                    require(
                        v <= _MAX_THICKNESS,
                        key,
                        f"expected a sheet thickness in metres <= {_MAX_THICKNESS}, got {v} (mm given as m?)",
                    )
        require(bool(self.name.strip()), "name", "expected a non-empty model name")
        for section, comp in self.components().items():
            t = getattr(comp, "thickness", None)
            dims = [d for d in (getattr(comp, k, None) for k in ("width", "height", "depth")) if d is not None]
            if t is not None and dims and section not in ("dash_firewall", "hood", "compartment"):
                require(
                    4 * t < min(dims),
                    f"{section}.thickness",
                    f"a {t} m wall does not fit a {min(dims)} m section (expected thickness < section / 4)",
                )
        m = self.mesh
        require(
            _MIN_ELEMENT_SIZE <= m.element_size <= _MAX_ELEMENT_SIZE,
            "mesh.element_size",
            f"expected {_MIN_ELEMENT_SIZE}-{_MAX_ELEMENT_SIZE} m (cells sample shells; finer only costs memory), "
            f"got {m.element_size}",
        )
        require(
            m.compartment_element_size >= _MIN_ELEMENT_SIZE,
            "mesh.compartment_element_size",
            f"expected >= {_MIN_ELEMENT_SIZE} m (a finer mesh only costs memory), got {m.compartment_element_size}",
        )
        self._validate_geometry()

    def _validate_geometry(self) -> None:
        bd, b, cb, r = self.body, self.bumper_beam, self.crash_box, self.front_rail
        u, st, sf = self.upper_load_path, self.shock_tower, self.subframe
        cm, pt, d, h, w = self.cooling_module, self.powertrain, self.dash_firewall, self.hood, self.wheel

        def need(cond: bool, key: str, msg: str) -> None:
            require(bool(cond), key, msg)

        comp_x = bd.dash_x + self.compartment.gap
        need(comp_x + 0.5 < bd.length, "body.length", f"length {bd.length} leaves no compartment behind x={comp_x}")
        need(bd.floor_z < d.z_top < bd.height, "dash_firewall.z_top", f"{d.z_top} not in ({bd.floor_z}, {bd.height})")
        need(d.z_bottom < d.z_top, "dash_firewall.z_bottom", f"z_bottom {d.z_bottom} >= z_top {d.z_top}")
        need(b.width < bd.width, "bumper_beam.width", f"bumper width {b.width} exceeds body width {bd.width}")
        outer = r.y_center + 0.5 * max(r.width, cb.width)
        need(outer <= 0.5 * b.width, "front_rail.y_center", f"rail outer face y={outer} is beyond the bumper end")
        inner = r.y_center - 0.5 * max(r.width, cb.width)
        need(inner > 0, "front_rail.y_center", f"rails cross the centre line (inner face y={inner})")
        rail_x = self.rail_front_x(r.y_center) + cb.length
        need(rail_x + 0.2 < bd.dash_x, "body.dash_x", f"dash at {bd.dash_x} leaves < 0.2 m of rail behind x={rail_x}")
        need(u.x_front < bd.dash_x, "upper_load_path.x_front", f"{u.x_front} is behind the dash at {bd.dash_x}")
        need(
            u.y_center + 0.5 * u.width <= 0.5 * bd.width,
            "upper_load_path.y_center",
            f"outer face y={u.y_center + 0.5 * u.width} is outside the body half width {0.5 * bd.width}",
        )
        need(st.z_top > st.z_bottom, "shock_tower.z_top", f"z_top {st.z_top} <= z_bottom {st.z_bottom}")
        need(
            st.z_bottom > r.z_center + 0.5 * r.height,
            "shock_tower.z_bottom",
            f"{st.z_bottom} is not above the rail top z={r.z_center + 0.5 * r.height}",
        )
        need(
            st.y_center + 0.5 * st.width < u.y_center - 0.5 * u.width,
            "shock_tower.y_center",
            "the shock tower overlaps the upper load path laterally",
        )
        need(
            st.y_center - 0.5 * st.width > 0.5 * pt.width,
            "shock_tower.y_center",
            f"the shock tower (inner face y={st.y_center - 0.5 * st.width}) overlaps the powertrain",
        )
        need(
            rail_x < st.x_center - 0.5 * st.length and st.x_center + 0.5 * st.length < bd.dash_x,
            "shock_tower.x_center",
            f"tower x range must lie between x={rail_x} and the dash at {bd.dash_x}",
        )
        need(sf.x_front + 2 * sf.width < sf.x_rear, "subframe.x_rear", f"{sf.x_rear} too close to x_front")
        need(sf.x_rear <= bd.dash_x, "subframe.x_rear", f"{sf.x_rear} is behind the dash at {bd.dash_x}")
        need(sf.y_center > sf.width, "subframe.y_center", f"{sf.y_center} leaves no cross-member length")
        need(
            sf.y_center + 0.5 * sf.width < 0.5 * (w.track - w.width),
            "subframe.y_center",
            f"the side members (outer face y={sf.y_center + 0.5 * sf.width}) reach the wheel's inner face "
            f"y={0.5 * (w.track - w.width)}",
        )
        need(sf.z_center > 0.5 * sf.height, "subframe.z_center", "the subframe reaches below the ground")
        need(
            pt.z_bottom > sf.z_center + 0.5 * sf.height,
            "powertrain.z_bottom",
            f"{pt.z_bottom} is not above the subframe top z={sf.z_center + 0.5 * sf.height}",
        )
        need(
            0.5 * pt.width < inner,
            "powertrain.width",
            f"half width {0.5 * pt.width} reaches the rails' inner face at y={inner}",
        )
        need(
            pt.x_front + pt.length < bd.dash_x,
            "powertrain.length",
            f"powertrain rear x={pt.x_front + pt.length} is behind the dash at {bd.dash_x}",
        )
        need(
            cm.x_front > self.rail_front_x(0.5 * cm.width),
            "cooling_module.x_front",
            f"{cm.x_front} overlaps the bumper beam",
        )
        need(
            cm.x_front + cm.depth <= pt.x_front,
            "cooling_module.depth",
            f"cooling module rear x={cm.x_front + cm.depth} overlaps the powertrain front x={pt.x_front}",
        )
        need(0.5 * cm.width < inner, "cooling_module.width", f"half width {0.5 * cm.width} reaches the crash boxes")
        need(cm.z_center > 0.5 * cm.height, "cooling_module.z_center", "the cooling module reaches below the ground")
        need(h.x_front < bd.dash_x, "hood.x_front", f"{h.x_front} is behind the dash at {bd.dash_x}")
        need(h.width <= bd.width, "hood.width", f"{h.width} exceeds the body width {bd.width}")
        need(
            h.z_front > pt.z_bottom + pt.height and h.z_front > u.z_center + 0.5 * u.height,
            "hood.z_front",
            f"{h.z_front} cuts the powertrain or the upper load path",
        )
        need(
            w.radius + bd.front_overhang < comp_x,
            "wheel.radius",
            f"the wheel (rear x={bd.front_overhang + w.radius}) reaches the compartment at x={comp_x}",
        )
        need(
            0.5 * (w.track + w.width) <= 0.5 * bd.width,
            "wheel.track",
            f"the wheel's outer face y={0.5 * (w.track + w.width)} is outside the body half width {0.5 * bd.width}",
        )
        need(
            0.5 * d.width < 0.5 * (w.track - w.width),
            "dash_firewall.width",
            f"the dash (half width {0.5 * d.width}) reaches the wheel's inner face y={0.5 * (w.track - w.width)}",
        )
        need(
            0.5 * (w.track - w.width) > max(st.y_center + 0.5 * st.width, r.y_center + 0.5 * r.width),
            "wheel.track",
            "the wheel overlaps the shock tower or the front rail laterally",
        )
        need(w.radius * 2 < u.z_center - 0.5 * u.height, "wheel.radius", "the wheel reaches the upper load path")
        need(
            bd.front_overhang > w.radius,
            "body.front_overhang",
            f"the wheel (front x={bd.front_overhang - w.radius:.3g}) reaches ahead of the bumper face at x=0",
        )
        # nothing below the ground (z = 0) or through the hood, whose lower edge is min(z_front, z_rear)
        need(b.z_center > 0.5 * b.height, "bumper_beam.z_center", "the bumper beam reaches below the ground")
        need(
            r.z_center > 0.5 * max(r.height, cb.height),
            "front_rail.z_center",
            "the front rails or crash boxes reach below the ground",
        )
        need(
            h.z_rear > pt.z_bottom + pt.height and h.z_rear > u.z_center + 0.5 * u.height,
            "hood.z_rear",
            f"{h.z_rear} cuts the powertrain or the upper load path",
        )
        need(
            max(h.z_front, h.z_rear) <= bd.height,
            "hood.z_rear" if h.z_rear >= h.z_front else "hood.z_front",
            f"the hood (top z={max(h.z_front, h.z_rear)}) is above the body height {bd.height}",
        )
        hood_low = min(h.z_front, h.z_rear)
        need(
            cm.z_center + 0.5 * cm.height < hood_low,
            "cooling_module.z_center",
            f"the cooling module (top z={cm.z_center + 0.5 * cm.height}) reaches the hood at z={hood_low}",
        )
        need(st.z_top < hood_low, "shock_tower.z_top", f"{st.z_top} reaches the hood at z={hood_low}")


def load_synthetic_config(path: str | Path, overrides: dict | None = None) -> SyntheticCarConfig:
    """Load a synthetic car YAML (dotted-key ``overrides`` applied first)."""
    return load_config(SyntheticCarConfig, path, overrides)


# --------------------------------------------------------------------------- variation
@dataclass(frozen=True)
class _Draw:
    """Factors of one seeded variant (all ones for the nominal car)."""

    rail_section: dict[str, tuple[float, float]]  # side -> (width, height) factors
    thickness: dict[str, float]  # part name -> factor


def _part_names() -> list[str]:
    """Part names in part-id order (the parts behind :data:`SUBASSEMBLIES`)."""
    names = []
    for sub in SUBASSEMBLIES:
        if sub == "subframe":
            names += ["subframe_front_member", "subframe_rear_member", "subframe_side_left", "subframe_side_right"]
        else:
            names.append(sub)
    return names


def _vary(config: SyntheticCarConfig, seed: int | None) -> tuple[SyntheticCarConfig, _Draw]:
    """The varied config and per-part factors for ``seed`` (``None``: nominal, no draw)."""
    parts = _part_names()
    if seed is None:
        return config, _Draw({s: (1.0, 1.0) for s, _ in SIDES}, dict.fromkeys(parts, 1.0))
    rng = np.random.default_rng(seed)
    v = config.variation

    def factors(spread: float, n: int) -> np.ndarray:
        return 1.0 + spread * rng.uniform(-1.0, 1.0, size=n)

    changes = {}
    for section, keys in _VARIED_DIMENSIONS.items():
        comp = getattr(config, section)
        f = factors(v.dimensions, len(keys))
        changes[section] = replace(comp, **{k: getattr(comp, k) * float(fk) for k, fk in zip(keys, f, strict=True)})
    fm = factors(v.mass, 2)
    changes["powertrain"] = replace(changes["powertrain"], mass=config.powertrain.mass * float(fm[0]))
    changes["wheel"] = replace(config.wheel, mass=config.wheel.mass * float(fm[1]))
    fr = factors(v.rail_section, 2 * len(SIDES)).reshape(len(SIDES), 2)
    ft = factors(v.thickness, len(parts))
    varied = replace(config, **changes)
    # each side's rail has its own section: check the variant with either, or a rail may grow into its neighbours
    checks = [("", varied)]
    for i, (side, _) in enumerate(SIDES):
        r = varied.front_rail
        rail = replace(r, width=r.width * float(fr[i, 0]), height=r.height * float(fr[i, 1]))
        checks.append((f" with the front_rail_{side} section drawn", replace(varied, front_rail=rail)))
    for what, candidate in checks:
        try:
            candidate.validate()
        except ConfigError as e:
            raise ConfigError(
                f"the variant for seed {seed} is geometrically impossible{what} ({e}); reduce the variation spreads",
                key="variation",
            ) from None
    draw = _Draw(
        {s: (float(fr[i, 0]), float(fr[i, 1])) for i, (s, _) in enumerate(SIDES)},
        {p: float(f) for p, f in zip(parts, ft, strict=True)},
    )
    return varied, draw


# ------------------------------------------------------------------------------ geometry
@dataclass
class _PartGeometry:
    name: str
    subassembly: str
    material: str  # library key
    thickness: float | None  # [m]; None for solids
    coords: np.ndarray  # [N, 3]
    shells: np.ndarray  # [Q, 4] local node indices
    solids: np.ndarray  # [H, 8] local node indices
    mass: float | None = None  # target mass [kg] (effective density); None: library density


def _shell(name: str, sub: str, material: str, thickness: float, mesh: tuple[np.ndarray, np.ndarray], **kw):
    return _PartGeometry(name, sub, material, thickness, mesh[0], mesh[1], empty_int(0, 8), **kw)


def _geometry(c: SyntheticCarConfig, draw: _Draw) -> list[_PartGeometry]:
    """All parts of the car, in part-id order, before the x shift to the bumper face."""
    h = c.mesh.element_size
    bd, b, cb, r = c.body, c.bumper_beam, c.crash_box, c.front_rail
    out: list[_PartGeometry] = []

    # bumper beam: a tube along y (section: width along z, height along x), swept rearward at its ends
    half = 0.5 * b.width
    h_swept = h / math.hypot(1.0, 2.0 * b.sweep / half)  # the sweep lengthens edges near the ends by <= this
    xyz, q = shapes.rect_tube([0.5 * b.depth, -half, b.z_center], "y", b.width, b.height, b.depth, h_swept)
    s2 = (xyz[:, 1] / half) ** 2
    xyz[:, 0] += b.sweep * (s2 - s2.min())  # the node nearest the centre line stays at x = 0
    out.append(_shell("bumper_beam", "bumper_beam", b.material, b.thickness, (xyz, q)))

    x_box = c.rail_front_x(r.y_center)
    x_rail = x_box + cb.length
    for side, sign in SIDES:
        y = sign * r.y_center
        mesh = shapes.rect_tube([x_box, y, r.z_center], "x", cb.length, cb.width, cb.height, h)
        out.append(_shell(f"crash_box_{side}", f"crash_box_{side}", cb.material, cb.thickness, mesh))
    for side, sign in SIDES:
        fw, fh = draw.rail_section[side]
        mesh = shapes.rect_tube(
            [x_rail, sign * r.y_center, r.z_center], "x", bd.dash_x - x_rail, r.width * fw, r.height * fh, h
        )
        out.append(_shell(f"front_rail_{side}", f"front_rail_{side}", r.material, r.thickness, mesh))
    u = c.upper_load_path
    for side, sign in SIDES:
        mesh = shapes.rect_tube(
            [u.x_front, sign * u.y_center, u.z_center], "x", bd.dash_x - u.x_front, u.width, u.height, h
        )
        out.append(_shell(f"upper_load_path_{side}", f"upper_load_path_{side}", u.material, u.thickness, mesh))
    st = c.shock_tower
    for side, sign in SIDES:
        # axis z: section width along x, height along y; closed at the top
        mesh = shapes.rect_tube(
            [st.x_center, sign * st.y_center, st.z_bottom],
            "z",
            st.z_top - st.z_bottom,
            st.length,
            st.width,
            h,
            cap_end=True,
        )
        out.append(_shell(f"shock_tower_{side}", f"shock_tower_{side}", st.material, st.thickness, mesh))

    sf = c.subframe
    cross = 2.0 * (sf.y_center - 0.5 * sf.width)  # cross members span between the side members' inner faces
    for name, xc in (("front", sf.x_front + 0.5 * sf.width), ("rear", sf.x_rear - 0.5 * sf.width)):
        mesh = shapes.rect_tube([xc, -0.5 * cross, sf.z_center], "y", cross, sf.height, sf.width, h)
        out.append(_shell(f"subframe_{name}_member", "subframe", sf.material, sf.thickness, mesh))
    for side, sign in SIDES:
        mesh = shapes.rect_tube(
            [sf.x_front, sign * sf.y_center, sf.z_center], "x", sf.x_rear - sf.x_front, sf.width, sf.height, h
        )
        out.append(_shell(f"subframe_side_{side}", "subframe", sf.material, sf.thickness, mesh))

    cm = c.cooling_module
    lo = [cm.x_front, -0.5 * cm.width, cm.z_center - 0.5 * cm.height]
    hi = [cm.x_front + cm.depth, 0.5 * cm.width, cm.z_center + 0.5 * cm.height]
    out.append(_shell("cooling_module", "cooling_module", cm.material, cm.thickness, shapes.closed_box(lo, hi, h)))

    pt = c.powertrain
    lo = [pt.x_front, -0.5 * pt.width, pt.z_bottom]
    hi = [pt.x_front + pt.length, 0.5 * pt.width, pt.z_bottom + pt.height]
    xyz, hexes = shapes.hex_block(lo, hi, h)
    out.append(_PartGeometry("powertrain", "powertrain", pt.material, None, xyz, empty_int(0, 4), hexes, pt.mass))

    d = c.dash_firewall
    mesh = shapes.plate([bd.dash_x, -0.5 * d.width, d.z_bottom], [0, d.width, 0], [0, 0, d.z_top - d.z_bottom], h)
    out.append(_shell("dash_firewall", "dash_firewall", d.material, d.thickness, mesh))

    hd = c.hood
    mesh = shapes.plate(
        [hd.x_front, -0.5 * hd.width, hd.z_front],
        [bd.dash_x - hd.x_front, 0, hd.z_rear - hd.z_front],
        [0, hd.width, 0],
        h,
    )
    out.append(_shell("hood", "hood", hd.material, hd.thickness, mesh))

    w = c.wheel
    for side, sign in SIDES:
        mesh = shapes.wheel([bd.front_overhang, sign * 0.5 * w.track, w.radius], w.radius, w.width, h)
        out.append(_shell(f"wheel_{side}", f"wheel_{side}", w.material, w.thickness, mesh, mass=w.mass))

    cp = c.compartment
    lo = [bd.dash_x + cp.gap, -0.5 * bd.width, bd.floor_z]
    hi = [bd.length, 0.5 * bd.width, bd.height]
    mesh = shapes.closed_box(lo, hi, c.mesh.compartment_element_size)
    out.append(_shell(COMPARTMENT, COMPARTMENT, cp.material, cp.thickness, mesh))

    for g in out:
        if g.thickness is not None:
            g.thickness *= draw.thickness[g.name]
    return out


# ------------------------------------------------------------------------------ assembly
def _resolve_materials(config: SyntheticCarConfig) -> dict[str, Material]:
    path = Path(config.materials)
    if not path.is_absolute():
        path = config_dir() / path
    if not path.is_file():  # named without its key or where it was looked for ('nope.yaml: cannot read config file')
        raise ConfigError(
            f"material library {config.materials!r} not found: {path} is no file (a relative path is read from the "
            f"configs folder {config_dir()}, not from the vehicle file's)",
            key="materials",
        )
    library = load_material_library(path)
    for section, comp in config.components().items():
        name = getattr(comp, "material", None)
        if name is None:
            continue
        if name not in library:
            raise ConfigError(
                f"unknown material {name!r}; the library {path.name} has {sorted(library)}", key=f"{section}.material"
            )
        if library[name].kind not in MATERIAL_KINDS:
            raise ConfigError(
                f"material {name!r} has kind {library[name].kind!r}; expected one of {MATERIAL_KINDS}",
                key=f"{section}.material",
            )
    rigid = library[config.compartment.material]
    if not rigid.is_rigid:
        raise ConfigError(
            f"the compartment must be a rigid material, {rigid.name!r} has kind {rigid.kind!r}",
            key="compartment.material",
        )
    for section, comp in config.components().items():
        name = getattr(comp, "material", None)
        if section != "compartment" and name is not None and library[name].is_rigid:
            raise ConfigError(f"only the compartment may be rigid, got {name!r}", key=f"{section}.material")
    return library


def build_vehicle(config: SyntheticCarConfig, seed: int | None = None) -> VehicleModel:
    """Build the synthetic car, nominal or a seeded variant.

    Args:
        config: the car (e.g. ``load_synthetic_config("configs/vehicle/b_segment.yaml")``).
        seed: ``None`` for the nominal car; an integer draws a variant with
            ``numpy.random.default_rng(seed)`` (the global RNG is not touched).

    Returns:
        A validated :class:`VehicleModel` in SI units and marlcrash axes, x-min = 0, with one
        part per structural member, the sub-assemblies of :data:`SUBASSEMBLIES`, and a total
        mass of exactly ``config.total_mass``.

    Raises:
        ConfigError: a config that is no :class:`SyntheticCarConfig`, a seed that is not an integer in
            ``[0, 2**64 - 1]``, a value of ``config`` (one made in Python is checked as a file's values are) or a
            variant that is geometrically impossible, unknown material, or a front structure heavier than
            ``total_mass``.
    """
    if not isinstance(config, SyntheticCarConfig):  # a path or a mapping: a TypeError of dataclasses
        raise ConfigError(
            "config must be a SyntheticCarConfig (load_synthetic_config(path, overrides)), got "
            f"{type(config).__name__} {config!r:.80}",
            key="config",
        )
    if seed is not None:
        if isinstance(seed, bool | np.bool_) or not isinstance(seed, int | np.integer):
            raise ConfigError(f"expected an integer seed (None: the nominal car), got {seed!r}", key="seed")
        seed = int(seed)
        require_seed(seed, "seed")  # the range every seed of the project takes
    config = checked(config)  # one made or changed in Python skipped the checks a file's values get
    library = _resolve_materials(config)
    varied, draw = _vary(config, seed)
    geoms = _geometry(varied, draw)

    # ---- arrays: nodes, shells, solids; ids 1.. in part order
    coords, shells, solids = [], [], []
    shell_part, solid_part, shell_thickness = [], [], []
    offset = 0
    for pid, g in enumerate(geoms, start=1):
        coords.append(g.coords)
        shells.append(g.shells + offset)
        solids.append(g.solids + offset)
        shell_part.append(np.full(len(g.shells), pid, dtype=np.int64))
        solid_part.append(np.full(len(g.solids), pid, dtype=np.int64))
        shell_thickness.append(np.full(len(g.shells), g.thickness or 0.0))
        offset += g.coords.shape[0]
    xyz = np.concatenate(coords)
    xyz[:, 0] -= xyz[:, 0].min()  # bumper face at x = 0 (a no-op unless the bumper is moved)
    n_s = sum(len(s) for s in shells)
    n_v = sum(len(s) for s in solids)

    # ---- materials: one per library key in first-use order; effective-density parts get their own
    keys: dict[str, int] = {}
    part_key = []
    for g in geoms:
        key = g.material if g.mass is None and g.name != COMPARTMENT else f"{g.name}_{g.material}"
        keys.setdefault(key, len(keys) + 1)
        part_key.append(key)
    base_of = {k: g.material for k, g in zip(part_key, geoms, strict=True)}
    materials = {mid: replace(library[base_of[k]], id=mid, name=k) for k, mid in keys.items()}
    parts = {
        pid: Part(pid, g.name, keys[k], section_id=pid, thickness=g.thickness)
        for pid, (g, k) in enumerate(zip(geoms, part_key, strict=True), start=1)
    }
    subassemblies: dict[str, list[int]] = {}
    for pid, g in enumerate(geoms, start=1):
        subassemblies.setdefault(g.subassembly, []).append(pid)

    model = VehicleModel(
        node_ids=np.arange(1, xyz.shape[0] + 1, dtype=np.int64),
        coords=xyz,
        shell_ids=np.arange(1, n_s + 1, dtype=np.int64),
        shell_part=np.concatenate(shell_part),
        shell_nodes=np.concatenate(shells),
        shell_thickness=np.concatenate(shell_thickness),
        solid_ids=np.arange(n_s + 1, n_s + n_v + 1, dtype=np.int64),
        solid_part=np.concatenate(solid_part),
        solid_nodes=np.concatenate(solids),
        beam_ids=empty_int(0),
        beam_part=empty_int(0),
        beam_nodes=empty_int(0, 2),
        beam_area=empty_float(0),
        parts=parts,
        materials=materials,
        subassemblies=subassemblies,
        name=config.name if seed is None else f"{config.name}_seed{seed}",
        units="m-kg-s",
    )

    # ---- effective densities: target masses, then the compartment takes the remainder
    masses = model.part_masses()
    comp_pid = subassemblies[COMPARTMENT][0]
    structure = 0.0
    for pid, g in enumerate(geoms, start=1):
        if g.mass is not None:
            mat = materials[parts[pid].material_id]
            materials[mat.id] = replace(mat, density=mat.density * g.mass / masses[pid])
            structure += g.mass
        elif pid != comp_pid:
            structure += masses[pid]
    remainder = varied.total_mass - structure
    if remainder <= 0:
        raise ConfigError(
            f"the front structure weighs {structure:.1f} kg, not less than the total {varied.total_mass} kg",
            key="total_mass",
        )
    mat = materials[parts[comp_pid].material_id]
    materials[mat.id] = replace(mat, density=mat.density * remainder / masses[comp_pid])
    model.warnings.extend(w for m in materials.values() for w in m.warnings)
    model.validate()
    return model


def default_vehicle(seed: int | None = None) -> VehicleModel:
    """The registered default vehicle (``b_segment``), nominal or a seeded variant."""
    from marlcrash.vehicle.registry import DEFAULT_VEHICLE, load_vehicle

    return load_vehicle(DEFAULT_VEHICLE, seed=seed)


# --------------------------------------------------------------------------------- scene
def vehicle_scene(model: VehicleModel):
    """A :class:`trimesh.Scene` with one coloured mesh per sub-assembly (named after it).

    Parts in no sub-assembly appear as ``part_<id>``. The compartment is drawn translucent grey.
    """
    import trimesh

    scene = trimesh.Scene()
    full = model.with_default_subassemblies()
    for i, (name, pids) in enumerate(full.subassemblies.items()):
        meshes = [m for m in (model.part_mesh(p) for p in pids) if len(m.faces)]
        if not meshes:
            continue
        mesh = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        rgba = np.array([160, 160, 160, 90], np.uint8) if name == COMPARTMENT else np.append(_SCENE_COLORS[i % 10], 255)
        # trimesh types concatenate() as any Geometry; of Trimesh meshes it returns a Trimesh
        mesh.visual.face_colors = np.tile(rgba, (len(mesh.faces), 1))  # type: ignore[union-attr]
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    return scene


__all__ = [
    "SUBASSEMBLIES",
    "MaterialLibraryConfig",
    "MaterialSpec",
    "SyntheticCarConfig",
    "build_vehicle",
    "default_vehicle",
    "load_material_library",
    "load_synthetic_config",
    "vehicle_scene",
]
