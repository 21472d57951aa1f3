"""The finite-element vehicle model (DESIGN 1.1) as plain arrays in SI units.

Elements refer to nodes by *index* into ``coords`` (ids are kept beside for
round trips and messages). Shells are stored as quads; a triangle repeats its
third node (``n4 == n3``), as LS-DYNA writes it. Solids are stored as 8-node
bricks with LS-DYNA's degenerate forms (tetrahedra ``n1 n2 n3 n4 n4 n4 n4 n4``,
pentahedra ``n1 .. n5 n5 n6 n6``).

Axes follow marlcrash's convention once :meth:`VehicleModel.transformed` has
applied an :class:`AxisMap`: x points rearward from the front-most point, y is
lateral with +y to the driver's left, z is up.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.materials import MATERIAL_FIELDS, Material

COMPARTMENT = "compartment"
"""Name of the sub-assembly treated as the rigid passenger compartment."""

# Hexahedron faces in LS-DYNA node order (0-based), outward normals for a
# right-handed element; degenerate tets and pentas collapse some faces to zero area.
HEX_FACES = np.array(
    [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]],
    dtype=np.int64,
)


@dataclass(frozen=True)
class Part:
    """A part: elements sharing one section and one material.

    Attributes:
        id: part id in the deck.
        name: part title (may be empty).
        material_id: id of its material.
        section_id: id of its section card (``None`` if the deck gives none).
        thickness: section shell thickness [m] (``None`` for non-shell sections).
        beam_area: section beam cross-sectional area [m^2] (``None`` for non-beams).
    """

    id: int
    name: str
    material_id: int
    section_id: int | None = None
    thickness: float | None = None
    beam_area: float | None = None


# What validate expects of each entry of a material's 8-vector (MATERIAL_FIELDS order): label, rule.
_MATERIAL_RULES = (
    ("density", "be finite and >= 0 kg/m^3"),
    ("Young's modulus", "be finite and > 0 Pa"),
    ("shear modulus", "be finite and > 0 Pa"),
    ("bulk modulus", "be finite and > 0 Pa"),
    ("yield strength", "be finite and > 0 Pa"),
    ("ultimate strength", "be finite and > 0 Pa"),
    ("fracture strength", "be finite and > 0 Pa"),
    ("Poisson's ratio", "lie in (-1, 0.5)"),
)
_AXIS_RE = re.compile(r"^([+-]?)([xyz])$")
_DEFAULT_GROUP_RE = re.compile(r"part_([1-9][0-9]*)")


def default_group_part(name: str, parts) -> int | None:
    """The part whose own sub-assembly name ``name`` is (``part_<id>``, what a part in no group gets), else ``None``.

    A group of that name must hold that part: :meth:`VehicleModel.with_default_subassemblies` would replace its
    parts by part ``<id>``, and :meth:`VehicleModel.subassembly_of_part` would look part ``<id>`` up into it.
    """
    m = _DEFAULT_GROUP_RE.fullmatch(str(name))
    return int(m.group(1)) if m and int(m.group(1)) in parts else None


@dataclass(frozen=True)
class AxisMap:
    """Maps a deck's axes onto marlcrash's (x rearward, y left, z up).

    Each field names the deck axis, with sign, that becomes that marlcrash axis:
    ``AxisMap(x="+x", y="+z", z="+y")`` reads a deck whose y axis is vertical and
    whose z axis is lateral. After the rotation, the model is shifted so the
    front-most point is at x = 0 and the lateral centre of its bounding box at
    y = 0 (or at ``y_center`` if given, in metres of the mapped frame); z keeps
    the deck's origin. ``y_center`` moves the frame only: the vehicle's centre line, its
    section planes and every barrier overlap stay measured from its bounding box (an overlap
    from the struck side's outer edge, :func:`marlcrash.cells.roi.barrier_edge`).

    marlcrash's frame is left-handed (x rearward, y left, z up), so a map with an odd number of sign changes
    and swaps is no mistake: a right-handed deck with x rearward, y to the right and z up (a common crash frame)
    is read with ``AxisMap(y="-y")``. What decides is where the driver's left ends up: at +y.
    """

    x: str = "+x"
    y: str = "+y"
    z: str = "+z"
    y_center: float | None = None

    @classmethod
    def parse(cls, text: str) -> AxisMap:
        """Parse ``"x=+x,y=+z,z=+y"`` (missing axes keep the identity; text naming no axis at all is refused)."""
        if not any(t.strip() for t in str(text).split(",")):  # "" read as the identity would be a silent no-op
            raise ConfigError(f"no axis given in {text!r}; expected items like 'x=+x,y=+z,z=+y'", key="axis_map")
        fields: dict[str, Any] = {}  # keys x, y, z only: their direction strings
        for item in filter(None, (t.strip() for t in text.split(","))):
            key, sep, value = item.partition("=")
            key = key.strip()
            if not sep or key not in ("x", "y", "z"):
                raise ConfigError(f"expected items like 'x=+x,y=+z,z=+y', got {item!r}", key="axis_map")
            if key in fields:  # the later one would silently win, and the axis meant keep the identity
                raise ConfigError(f"axis {key!r} is given twice in {text!r}; expected each of x, y, z at most once",
                                  key="axis_map")  # fmt: skip
            fields[key] = value.strip()
        out = cls(**fields)
        try:
            out.matrix()  # validates
        except ConfigError as e:  # an axis left out keeps the identity: say so, the clash may come from it
            kept = [f"{k} not given, kept as {getattr(out, k)}" for k in ("x", "y", "z") if k not in fields]
            if not kept:
                raise
            raise ConfigError(f"{e.reason} ({'; '.join(kept)})", key=e.key) from None
        return out

    def matrix(self) -> np.ndarray:
        """The 3x3 signed permutation ``R`` with ``mapped = R @ deck``."""
        rows = []
        used = set()
        for target, spec in (("x", self.x), ("y", self.y), ("z", self.z)):
            m = _AXIS_RE.match(str(spec).strip())
            if not m:
                raise ConfigError(f"expected a deck axis like '+x', '-z', got {spec!r}", key=f"axis_map.{target}")
            sign = -1.0 if m.group(1) == "-" else 1.0
            axis = "xyz".index(m.group(2))
            if axis in used:
                raise ConfigError(f"deck axis {m.group(2)!r} is used twice in {self}", key=f"axis_map.{target}")
            used.add(axis)
            row = np.zeros(3)
            row[axis] = sign
            rows.append(row)
        return np.array(rows)


@dataclass
class VehicleModel:
    """Nodes, elements, parts, materials and sub-assemblies of a vehicle, in SI.

    Shapes: ``N`` nodes, ``S`` shells, ``V`` solids, ``B`` beams.

    Attributes:
        node_ids: ``[N]`` int64 node ids.
        coords: ``[N, 3]`` float64 node coordinates [m].
        shell_ids, shell_part: ``[S]`` int64 element and part ids.
        shell_nodes: ``[S, 4]`` int64 node indices.
        shell_thickness: ``[S]`` float64 thickness [m] (element value, else section).
        solid_ids, solid_part: ``[V]`` int64.
        solid_nodes: ``[V, 8]`` int64 node indices.
        beam_ids, beam_part: ``[B]`` int64.
        beam_nodes: ``[B, 2]`` int64 node indices.
        beam_area: ``[B]`` float64 cross-sectional area [m^2].
        parts: part id -> :class:`Part`.
        materials: material id -> :class:`Material` (complete 8-vectors).
        subassemblies: name -> part ids; every part is in at most one.
        name: a readable model name.
        units: the unit system the source was written in.
        skipped_cards: keyword -> count of cards the reader did not interpret.
        warnings: everything defaulted or skipped while building the model.
        left_out: part id -> why the part is not part of the vehicle, for parts a source
            holds fixed in space (a barrier or fixture in the deck,
            :meth:`without_parts`); their elements are gone, their nodes stay.
        point_mass_ids, point_mass_nodes, point_mass: ``[M]`` int64 ids, int64 node indices and
            float64 masses [kg] of lumped masses on nodes (a deck's ``*ELEMENT_MASS``). They add
            inertia where they sit and no material.
        part_added_mass: part id -> non-structural mass [kg] spread over the part's elements in
            proportion to their area (shells), volume (solids) or length (beams), as LS-DYNA spreads
            ``*ELEMENT_MASS_PART`` and ``*SECTION_SHELL`` MAREA.
        part_mass: part id -> the part's structural mass [kg] as the source sets it, replacing
            density times volume (a rigid body's ``*PART_INERTIA`` TM); spread over its elements in
            proportion to their structural mass, or their measure where that is zero.
    """

    node_ids: np.ndarray
    coords: np.ndarray
    shell_ids: np.ndarray
    shell_part: np.ndarray
    shell_nodes: np.ndarray
    shell_thickness: np.ndarray
    solid_ids: np.ndarray
    solid_part: np.ndarray
    solid_nodes: np.ndarray
    beam_ids: np.ndarray
    beam_part: np.ndarray
    beam_nodes: np.ndarray
    beam_area: np.ndarray
    parts: dict[int, Part]
    materials: dict[int, Material]
    subassemblies: dict[str, list[int]]
    name: str = "vehicle"
    units: str = "m-kg-s"
    skipped_cards: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    left_out: dict[int, str] = field(default_factory=dict)
    point_mass_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    point_mass_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    point_mass: np.ndarray = field(default_factory=lambda: np.zeros(0))
    part_added_mass: dict[int, float] = field(default_factory=dict)
    part_mass: dict[int, float] = field(default_factory=dict)

    # ------------------------------------------------------------------ sizes
    @property
    def n_nodes(self) -> int:
        return int(self.node_ids.shape[0])

    @property
    def n_shells(self) -> int:
        return int(self.shell_ids.shape[0])

    @property
    def n_solids(self) -> int:
        return int(self.solid_ids.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.beam_ids.shape[0])

    # ------------------------------------------------------------- geometry
    def shell_areas(self) -> np.ndarray:
        """``[S]`` shell mid-surface areas [m^2] (quads as two triangles)."""
        p = self.coords[self.shell_nodes]  # [S, 4, 3]
        a1 = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        a2 = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])
        return 0.5 * (np.linalg.norm(a1, axis=1) + np.linalg.norm(a2, axis=1))

    def solid_volumes(self) -> np.ndarray:
        """``[V]`` solid volumes [m^3] by the divergence theorem over the 6 faces.

        Exact for bricks with planar faces and for the degenerate tet/penta forms.
        """
        p = self.coords[self.solid_nodes]  # [V, 8, 3]
        c = p.mean(axis=1, keepdims=True)
        f = p[:, HEX_FACES] - c[:, None]  # [V, 6, 4, 3]
        t1 = np.einsum("vfi,vfi->vf", f[:, :, 0], np.cross(f[:, :, 1], f[:, :, 2]))
        t2 = np.einsum("vfi,vfi->vf", f[:, :, 0], np.cross(f[:, :, 2], f[:, :, 3]))
        return np.abs((t1 + t2).sum(axis=1) / 6.0)

    def beam_lengths(self) -> np.ndarray:
        """``[B]`` beam lengths [m]."""
        p = self.coords[self.beam_nodes]
        return np.linalg.norm(p[:, 1] - p[:, 0], axis=1)

    def _density_of_parts(self, part_ids: np.ndarray) -> np.ndarray:
        if part_ids.size == 0:
            return np.zeros(0)
        uniq, inv = np.unique(part_ids, return_inverse=True)
        rho = np.array([self.materials[self.parts[int(p)].material_id].density for p in uniq])
        return rho[inv]

    def element_measures(self) -> dict[str, np.ndarray]:
        """What added mass is spread by: shell area [m^2], solid volume [m^3], beam length [m], keyed as
        :meth:`element_masses`."""
        return {"shell": self.shell_areas(), "solid": self.solid_volumes(), "beam": self.beam_lengths()}

    def element_masses(self) -> dict[str, np.ndarray]:
        """Structural masses [kg] of every element, ``{"shell": [S], "solid": [V], "beam": [B]}``.

        Density times volume, or a share of the part's :attr:`part_mass` where the source sets it. This is
        the mass that carries the material (it weights a cell's material); :meth:`element_added_masses`
        is the inertia on top.
        """
        measure = self.element_measures()
        out = {
            "shell": measure["shell"] * self.shell_thickness * self._density_of_parts(self.shell_part),
            "solid": measure["solid"] * self._density_of_parts(self.solid_part),
            "beam": measure["beam"] * self.beam_area * self._density_of_parts(self.beam_part),
        }
        if self.part_mass:
            self._spread(out, self.part_mass, {k: np.where(out[k] > 0, out[k], 0.0) for k in out}, measure, True)
        return out

    def element_added_masses(self) -> dict[str, np.ndarray]:
        """Non-structural masses [kg] per element (:attr:`part_added_mass` spread by measure), as
        :meth:`element_masses`."""
        measure = self.element_measures()
        out = {k: np.zeros_like(v) for k, v in measure.items()}
        if self.part_added_mass:
            self._spread(out, self.part_added_mass, measure, measure, False)
        return out

    def _spread(self, out, totals: dict[int, float], weights, fallback, replace_: bool) -> None:
        """Spread ``totals`` (part id -> kg) over each part's elements in proportion to ``weights``
        (``fallback`` where a part's weights sum to zero); replace or add to ``out`` in place. Vectorised:
        one pass over the elements whatever the number of parts."""
        kinds = ("shell", "solid", "beam")
        pids = np.array(sorted(totals), dtype=np.int64)
        tot = np.array([totals[int(p)] for p in pids])
        pos = {}
        for k in kinds:
            part = getattr(self, f"{k}_part")
            i = np.clip(np.searchsorted(pids, part), 0, pids.size - 1)
            pos[k] = np.where(pids[i] == part, i, -1)

        def sums(w):
            acc = np.zeros(pids.size)
            for k in kinds:
                sel = pos[k] >= 0
                acc += np.bincount(pos[k][sel], weights=w[k][sel], minlength=pids.size)
            return acc

        wsum, fsum = sums(weights), sums(fallback)
        if ((wsum <= 0) & (fsum <= 0)).any():
            p = int(pids[np.flatnonzero((wsum <= 0) & (fsum <= 0))[0]])
            raise ModelError(f"{self.name}: part {p} has no element with a size to carry its {totals[p]:.4g} kg")
        use_w = wsum > 0
        for k in kinds:
            sel = pos[k] >= 0
            j = pos[k][sel]
            w = np.where(use_w[j], weights[k][sel], fallback[k][sel])
            share = tot[j] * w / np.where(use_w[j], wsum[j], fsum[j])
            out[k][sel] = share if replace_ else out[k][sel] + share

    def sum_by_part(self, values: dict[str, np.ndarray]) -> dict[int, float]:
        """Part id -> sum of per-element ``values`` (keyed ``shell``, ``solid``, ``beam``; a kind left out
        counts 0), every part included."""
        out = dict.fromkeys(self.parts, 0.0)
        for kind, parts in (
            ("shell", self.shell_part),
            ("solid", self.solid_part),
            ("beam", self.beam_part),
        ):
            if parts.size and kind in values:
                uniq, inv = np.unique(parts, return_inverse=True)
                sums = np.bincount(inv, weights=values[kind])
                for pid, m in zip(uniq.tolist(), sums.tolist(), strict=True):
                    out[int(pid)] = out.get(int(pid), 0.0) + float(m)
        return out

    def part_masses(self) -> dict[int, float]:
        """Part id -> mass [kg]: structural plus added (point masses on nodes not included)."""
        em, ea = self.element_masses(), self.element_added_masses()
        return self.sum_by_part({k: em[k] + ea[k] for k in em})

    def total_mass(self) -> float:
        """Total mass [kg]: every part's (:meth:`part_masses`) and every point mass."""
        return float(sum(self.part_masses().values())) + float(self.point_mass.sum())

    def bounds(self) -> np.ndarray:
        """``[2, 3]`` min and max corner of the nodes actually used by elements [m]."""
        used = self.used_nodes()
        if used.size == 0:
            raise ModelError(f"{self.name}: the model has no elements")
        c = self.coords[used]
        return np.stack([c.min(axis=0), c.max(axis=0)])

    def used_nodes(self) -> np.ndarray:
        """Sorted indices of nodes referenced by at least one element."""
        used = np.zeros(self.n_nodes, dtype=bool)
        for nodes in (self.shell_nodes, self.solid_nodes, self.beam_nodes):
            used[nodes.ravel()] = True
        return np.flatnonzero(used)

    # --------------------------------------------------------- sub-assemblies
    def subassembly_of_part(self) -> dict[int, str]:
        """Part id -> sub-assembly name; parts in none map to ``part_<id>``."""
        out = {pid: f"part_{pid}" for pid in self.parts}
        for name, pids in self.subassemblies.items():
            for pid in pids:
                out[int(pid)] = name
        return out

    def with_subassemblies(self, mapping: dict[str, list[int]]) -> VehicleModel:
        """A copy whose sub-assemblies are ``mapping`` (validated)."""
        out = replace(self, subassemblies={k: [int(p) for p in v] for k, v in mapping.items()})
        out.validate()
        return out

    def with_default_subassemblies(self) -> VehicleModel:
        """A copy in which every part without a sub-assembly is its own, ``part_<id>``."""
        mapping = {k: list(v) for k, v in self.subassemblies.items()}
        owned = {p for v in mapping.values() for p in v}
        for pid in sorted(self.parts):
            if pid not in owned:
                mapping[f"part_{pid}"] = [pid]
        return replace(self, subassemblies=mapping)

    def without_parts(self, reasons: dict[int, str]) -> VehicleModel:
        """A copy without the parts ``reasons`` names (part id -> why), recorded in ``left_out``.

        Their elements, part entries, added masses and sub-assembly memberships go, and so do point
        masses on nodes that only their elements use; nodes stay (unused nodes do not count in
        :meth:`bounds`). Sub-assemblies left empty are dropped.
        """
        drop = np.array(sorted(reasons), dtype=np.int64)
        keep = {kind: ~np.isin(getattr(self, f"{kind}_part"), drop) for kind in ("shell", "solid", "beam")}
        kept_node = np.zeros(self.n_nodes, dtype=bool)
        dropped_node = np.zeros(self.n_nodes, dtype=bool)
        for kind in ("shell", "solid", "beam"):
            nodes = getattr(self, f"{kind}_nodes")
            kept_node[nodes[keep[kind]].ravel()] = True
            dropped_node[nodes[~keep[kind]].ravel()] = True
        pm_keep = ~(dropped_node & ~kept_node)[self.point_mass_nodes]
        arrays = {
            f"{kind}_{name}": getattr(self, f"{kind}_{name}")[keep[kind]]
            for kind, names in (
                ("shell", ("ids", "part", "nodes", "thickness")),
                ("solid", ("ids", "part", "nodes")),
                ("beam", ("ids", "part", "nodes", "area")),
            )
            for name in names
        }
        subs = {k: [p for p in v if p not in reasons] for k, v in self.subassemblies.items()}
        return replace(
            self,
            **arrays,
            parts={pid: p for pid, p in self.parts.items() if pid not in reasons},
            point_mass_ids=self.point_mass_ids[pm_keep],
            point_mass_nodes=self.point_mass_nodes[pm_keep],
            point_mass=self.point_mass[pm_keep],
            part_added_mass={pid: m for pid, m in self.part_added_mass.items() if pid not in reasons},
            part_mass={pid: m for pid, m in self.part_mass.items() if pid not in reasons},
            subassemblies={k: v for k, v in subs.items() if v},
            left_out={**self.left_out, **{int(k): v for k, v in reasons.items()}},
        )

    # ------------------------------------------------------------ transforms
    def transformed(self, axis_map: AxisMap) -> VehicleModel:
        """A copy in marlcrash axes: rotated by ``axis_map``, front at x = 0, centred in y."""
        r = axis_map.matrix()
        # a signed permutation: gather columns instead of a matrix product
        axis = np.abs(r).argmax(axis=1)
        c = self.coords[:, axis] * r[np.arange(3), axis]
        used = self.used_nodes()
        ref = c[used] if used.size < self.n_nodes else c
        if ref.size:
            lo, hi = ref.min(axis=0), ref.max(axis=0)
            shift = np.array(
                [
                    lo[0],
                    0.5 * (lo[1] + hi[1]) if axis_map.y_center is None else axis_map.y_center,
                    0.0,
                ]
            )
            c = c - shift
        return replace(self, coords=c)

    # ------------------------------------------------------------ validation
    def validate(self) -> None:
        """Check internal consistency; raise :class:`ModelError` naming the first problem."""
        n = self.n_nodes
        if self.coords.shape != (n, 3):
            raise ModelError(f"{self.name}: coords must be [{n}, 3], got {self.coords.shape}")
        bad = ~np.isfinite(self.coords).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ModelError(
                f"{self.name}: node {int(self.node_ids[i])} has a non-finite coordinate {self.coords[i].tolist()}"
            )
        _refuse_repeated_ids(self.name, "node", self.node_ids)
        for kind, ids, parts, nodes, width in (
            ("shell", self.shell_ids, self.shell_part, self.shell_nodes, 4),
            ("solid", self.solid_ids, self.solid_part, self.solid_nodes, 8),
            ("beam", self.beam_ids, self.beam_part, self.beam_nodes, 2),
        ):
            if nodes.shape != (ids.shape[0], width) or parts.shape != ids.shape:
                raise ModelError(
                    f"{self.name}: {kind} arrays disagree: ids {ids.shape}, parts {parts.shape}, nodes {nodes.shape}"
                )
            _refuse_repeated_ids(self.name, kind, ids)
            if nodes.size and (nodes.min() < 0 or nodes.max() >= n):
                i = int(np.flatnonzero(((nodes < 0) | (nodes >= n)).any(axis=1))[0])
                raise ModelError(f"{self.name}: {kind} {int(ids[i])} refers to a node index outside 0..{n - 1}")
            unknown = np.setdiff1d(np.unique(parts), np.fromiter(self.parts, dtype=np.int64))
            if unknown.size:
                i = int(np.flatnonzero(parts == unknown[0])[0])
                raise ModelError(f"{self.name}: {kind} {int(ids[i])} refers to unknown part {int(unknown[0])}")
        for what, table in (("part", self.parts), ("material", self.materials)):
            wrong = [k for k, x in table.items() if x.id != k]
            if wrong:
                k, x = wrong[0], table[wrong[0]]
                raise ModelError(f"{self.name}: {what}s[{k}] is {what} {x.id} ({x.name!r}); expected {what} {k}")
        for pid, p in self.parts.items():
            if p.material_id not in self.materials:
                raise ModelError(f"{self.name}: part {pid} refers to unknown material {p.material_id}")
        self._check_materials()
        self._check_weightless_parts()
        seen: dict[int, str] = {}
        for name, pids in self.subassemblies.items():
            if not len(pids):
                raise ModelError(f"{self.name}: sub-assembly {name!r} lists no part")
            own = default_group_part(name, self.parts)
            if own is not None and own not in pids:
                raise ModelError(
                    f"{self.name}: {name!r} is the name of part {own}'s own sub-assembly (a part in no group gets "
                    f"it), but the sub-assembly does not hold part {own}; rename it or add part {own} to it"
                )
            for pid in pids:
                if pid not in self.parts:
                    raise ModelError(f"{self.name}: sub-assembly {name!r} lists unknown part {pid}")
                if pid in seen:
                    raise ModelError(f"{self.name}: part {pid} is in two sub-assemblies, {seen[pid]!r} and {name!r}")
                seen[pid] = name
        element_values = (("shell", "thickness", "m", self.shell_thickness, self.shell_ids),
                          ("beam", "cross-sectional area", "m^2", self.beam_area, self.beam_ids))  # fmt: skip
        for kind, what, unit, values, ids in element_values:
            if values.shape != ids.shape:
                raise ModelError(f"{self.name}: {kind} {what} is {values.shape}, expected one value per element "
                                 f"{ids.shape}")  # fmt: skip
            bad = ~(np.isfinite(values) & (values >= 0))
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ModelError(f"{self.name}: {kind} {int(ids[i])}'s {what} must be finite and >= 0 {unit}, "
                                 f"got {float(values[i])}")  # fmt: skip
        m = self.point_mass.shape[0]
        if self.point_mass_nodes.shape != (m,) or self.point_mass_ids.shape != (m,):
            raise ModelError(
                f"{self.name}: point mass arrays disagree: ids {self.point_mass_ids.shape}, "
                f"nodes {self.point_mass_nodes.shape}, masses {self.point_mass.shape}"
            )
        if m and (self.point_mass_nodes.min() < 0 or self.point_mass_nodes.max() >= n):
            i = int(np.flatnonzero((self.point_mass_nodes < 0) | (self.point_mass_nodes >= n))[0])
            pm = int(self.point_mass_ids[i])
            raise ModelError(f"{self.name}: point mass {pm} refers to a node index outside 0..{n - 1}")
        bad = ~(np.isfinite(self.point_mass) & (self.point_mass >= 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            pm, val = int(self.point_mass_ids[i]), float(self.point_mass[i])
            raise ModelError(f"{self.name}: point mass {pm} must be finite and >= 0 kg, got {val}")
        for what, masses in (("added mass", self.part_added_mass), ("mass", self.part_mass)):
            for pid, mass in masses.items():
                if pid not in self.parts:
                    raise ModelError(f"{self.name}: {what} {mass:.4g} kg is given for unknown part {pid}")
                if not (math.isfinite(mass) and mass >= 0):
                    raise ModelError(f"{self.name}: part {pid}'s {what} must be finite and >= 0 kg, got {mass}")

    def _check_materials(self) -> None:
        """Refuse a material value that is missing or not physical, as :func:`complete_material` would: density
        finite and >= 0 (0: a massless material, refused for a part it would leave weightless:
        :meth:`_check_weightless_parts`), moduli and strengths finite and > 0, Poisson's ratio in
        (-1, 0.5)."""
        if not self.materials:
            return
        mats = list(self.materials.values())
        vec = np.array([m.vector() for m in mats])  # [n_materials, 8]
        lo = np.zeros(len(MATERIAL_FIELDS))
        lo[-1] = -1.0
        ok = np.isfinite(vec) & (vec > lo)
        ok[:, 0] |= vec[:, 0] == 0.0  # density may be 0
        ok[:, -1] &= vec[:, -1] < 0.5
        if ok.all():
            return
        i, j = (int(k) for k in np.argwhere(~ok)[0])
        m, v = mats[i], float(vec[i, j])
        label, expected = _MATERIAL_RULES[j]
        missing = " (missing: complete_material derives or defaults it)" if math.isnan(v) else ""
        raise ModelError(f"{self.name}: material {m.id} ({m.name})'s {label} must {expected}, got {v}{missing}")

    def weightless_parts(self) -> list[tuple[int, int]]:
        """``(part id, elements)`` of every part with elements whose material has density 0 and whose mass nothing
        else sets (:attr:`part_mass`): its elements would weigh nothing, own no cell and leave its strength out of
        the cells. A material of density 0 is valid as such (one no part with elements uses, a rigid body's whose
        mass is set)."""
        zero = {mid for mid, m in self.materials.items() if m.density == 0.0}
        if not zero:
            return []
        found = []
        for pid, p in sorted(self.parts.items()):
            if p.material_id not in zero or self.part_mass.get(pid, 0.0) > 0:
                continue
            n = sum(int((getattr(self, f"{k}_part") == pid).sum()) for k in ("shell", "solid", "beam"))
            if n:
                found.append((pid, n))
        return found

    def _check_weightless_parts(self) -> None:
        """Refuse the first of :meth:`weightless_parts`, naming the part and its material."""
        for pid, n in self.weightless_parts()[:1]:
            p = self.parts[pid]
            m = self.materials[p.material_id]
            raise ModelError(
                f"{self.name}: part {pid} ({p.name!r}, {n} elements) is of material {m.id} ({m.name}), whose "
                "density is 0, and no part mass sets its own: its elements would weigh nothing; expected a "
                "density > 0 kg/m^3"
            )

    # --------------------------------------------------------------- meshes
    def shell_triangles(self, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Triangulate shells.

        Args:
            mask: optional ``[S]`` bool selecting shells.

        Returns:
            ``(tri, owner)``: ``[T, 3]`` node indices and ``[T]`` shell index of each
            triangle; degenerate second triangles of 3-node shells are dropped.
        """
        idx = np.arange(self.n_shells) if mask is None else np.flatnonzero(mask)
        q = self.shell_nodes[idx]
        t1 = q[:, [0, 1, 2]]
        t2 = q[:, [0, 2, 3]]
        keep2 = q[:, 3] != q[:, 2]
        tri = np.concatenate([t1, t2[keep2]])
        owner = np.concatenate([idx, idx[keep2]])
        return tri, owner

    def solid_boundary_triangles(self, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Boundary faces of the selected solids, triangulated.

        Faces shared by two solids are interior and dropped. Returns ``(tri, owner)``
        as :meth:`shell_triangles`, ``owner`` indexing solids.
        """
        idx = np.arange(self.n_solids) if mask is None else np.flatnonzero(mask)
        if idx.size == 0:
            return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
        quads = self.solid_nodes[idx][:, HEX_FACES].reshape(-1, 4)  # [6V, 4]
        owner = np.repeat(idx, 6)
        key = np.sort(quads, axis=1)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        boundary = counts[inv.ravel()] == 1
        # drop faces collapsed to a point or a line
        distinct = (np.diff(key, axis=1) != 0).sum(axis=1) + 1
        boundary &= distinct >= 3
        quads, owner = quads[boundary], owner[boundary]
        t1 = quads[:, [0, 1, 2]]
        t2 = quads[:, [0, 2, 3]]
        ok1 = (t1[:, 0] != t1[:, 1]) & (t1[:, 1] != t1[:, 2]) & (t1[:, 0] != t1[:, 2])
        ok2 = (t2[:, 0] != t2[:, 1]) & (t2[:, 1] != t2[:, 2]) & (t2[:, 0] != t2[:, 2])
        return np.concatenate([t1[ok1], t2[ok2]]), np.concatenate([owner[ok1], owner[ok2]])

    def part_mesh(self, part_id: int):
        """A :class:`trimesh.Trimesh` of one part (shells and solid boundary faces)."""
        import trimesh

        tri_s, _ = self.shell_triangles(self.shell_part == part_id)
        tri_v, _ = self.solid_boundary_triangles(self.solid_part == part_id)
        tri = np.concatenate([tri_s, tri_v])
        used, inv = np.unique(tri.ravel(), return_inverse=True)
        return trimesh.Trimesh(self.coords[used], inv.reshape(-1, 3), process=False)


def _refuse_repeated_ids(name: str, what: str, ids: np.ndarray) -> None:
    """Raise :class:`ModelError` naming the first id ``ids`` holds twice, with both indices. Ids a deck or a builder
    numbers in order cost one pass; others are sorted, not passed through ``np.unique`` (numpy 2's hash-based one
    takes seconds per million ids)."""
    if ids.size < 2 or (ids[1:] > ids[:-1]).all():
        return
    s = np.sort(ids)
    dup = np.flatnonzero(s[1:] == s[:-1])
    if dup.size:
        i, j = np.flatnonzero(ids == s[dup[0]])[:2].tolist()
        raise ModelError(
            f"{name}: {what} id {int(ids[i])} is given twice ({what} indices {i} and {j}); expected each {what} id once"
        )


def empty_int(*shape: int) -> np.ndarray:
    """An empty int64 array of the given trailing shape (``empty_int(0, 4)``)."""
    return np.zeros(shape, dtype=np.int64)


def empty_float(*shape: int) -> np.ndarray:
    """An empty float64 array of the given shape."""
    return np.zeros(shape, dtype=np.float64)
