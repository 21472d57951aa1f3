"""VehicleModel -> CellModel: uniform and optimized discretization (DESIGN 1.2, 1.3).

Steps: crop the ROI and place the section planes (:mod:`.roi`); build the fine
voxel grid and sample every ROI element into it (:mod:`.grid`); label voxels
with cells (uniform blocks, or per sub-assembly envelopes split into pieces of
about the target volume, null space and sensor cells); extract links and
their material sections (:mod:`.transmission`, :mod:`.sections`); initialise
the seven parameters (:mod:`.transmission`, :mod:`.params`).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import time
import warnings
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from marlcrash.cells.grid import EDGE_TOL, KIND_SOLID, FineGrid, Samples, build_grid, sample_elements
from marlcrash.cells.model import CellModel
from marlcrash.cells.params import behaviour_params
from marlcrash.cells.roi import Roi, region_of_interest
from marlcrash.cells.sections import grid_sections
from marlcrash.cells.transmission import aggregate_links, extract_faces, orient_x_links, transmission_factors
from marlcrash.config import checked, config_dir, load_config, require
from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.model import COMPARTMENT, VehicleModel

SENSOR_RULES = ("upfront_left", "upfront_right", "compartment", "position")


@dataclass
class SensorSpec:
    """One acceleration sensor, clustered as its own cell.

    Attributes:
        name: sensor name.
        rule: ``upfront_left`` / ``upfront_right`` (``x = upfront_sensor_x``,
            ``y = y0 +- upfront_sensor_y_fraction * W`` about the centre line ``y0``, z at the ROI
            mid-height, snapped to the nearest voxel with material), ``compartment`` (the rigid
            compartment cell) or ``position`` (the explicit position; inside the ROI snapped like
            up-front sensors, outside it the compartment). An up-front rule's position must lie inside the ROI;
            any other given position inside the vehicle's bounding box (give or take ``sensor_snap_distance``).
        position: ``[x, y, z]`` [m] overriding the rule's position, or ``None``.

    Snapping keeps a sensor on its side of the centre line (one requested on the line may go either
    way) and moves it at most ``sensor_snap_distance``; otherwise discretization stops with a
    :class:`ModelError` naming the sensor, the requested and the nearest position. Two sensors that
    would land in one deformable cell record one signal: refused, naming both. Sensors in the rigid
    compartment share its cell by design.
    """

    name: str
    rule: Literal["upfront_left", "upfront_right", "compartment", "position"] = "position"
    position: list[float] | None = None

    def validate(self) -> None:
        require(bool(self.name), "name", "sensor name must not be empty")
        if self.position is not None:
            require(
                len(self.position) == 3 and all(np.isfinite(self.position)),
                "position",
                f"expected [x, y, z] in m, got {self.position}",
            )
        require(
            self.rule != "position" or self.position is not None,
            "position",
            f"sensor {self.name!r} with rule 'position' needs a position [x, y, z] in m",
        )


def _default_sensors() -> list[SensorSpec]:
    return [
        SensorSpec("upfront_left", "upfront_left"),
        SensorSpec("upfront_right", "upfront_right"),
        SensorSpec("tunnel", "compartment"),
    ]


@dataclass
class DiscretizationConfig:
    """Schema of ``configs/cells.yaml`` (each key is documented there with its unit)."""

    roi_depth: float = 1.2
    target_cell_volume: float = 3e-4
    solid_target_cell_volume: float = 0.03
    subassembly_target_cell_volume: dict[str, float] = field(
        default_factory=lambda: {"wheel_left": 0.01, "wheel_right": 0.01}
    )
    method: Literal["optimized", "uniform"] = "optimized"
    uniform_cells: Literal["per_subassembly", "per_block"] = "per_subassembly"
    overlaps: list[float] = field(default_factory=lambda: [0.4, 0.25])
    voxels_per_cell_edge: int = 4
    samples_per_pitch: int = 2
    max_subdivision: int = 32
    envelope_closing_iterations: int = 1
    principal_min_share: float = 0.6
    weight_x: float = 2.0
    weight_lateral: float = 1.0
    weight_vertical: float = 1.0
    crush_efficiency_shell: float = 0.22
    crush_efficiency_solid: float = 1.0
    compaction_shell: float = 0.3
    compaction_solid: float = 0.9
    min_section_fraction: float = 0.1
    upfront_sensor_x: float = 0.2
    upfront_sensor_y_fraction: float = 0.3
    sensor_snap_distance: float = 0.15
    sensors: list[SensorSpec] = field(default_factory=_default_sensors)

    def validate(self) -> None:
        """Cross-field checks; raise :class:`ConfigError` naming the key and value."""
        require(self.roi_depth > 0, "roi_depth", f"expected a depth > 0 m, got {self.roi_depth}")
        require(self.target_cell_volume > 0, "target_cell_volume", f"expected > 0 m^3, got {self.target_cell_volume}")
        require(
            self.target_cell_volume ** (1 / 3) <= self.roi_depth * (1 + 1e-9),  # 1e-3 ** (1/3) = 0.10000000000000002
            "target_cell_volume",
            f"cell edge {self.target_cell_volume ** (1 / 3):.3g} m exceeds roi_depth {self.roi_depth} m",
        )
        require(
            self.solid_target_cell_volume >= self.target_cell_volume,
            "solid_target_cell_volume",
            f"expected >= target_cell_volume = {self.target_cell_volume} m^3, got {self.solid_target_cell_volume}",
        )
        for name, v in self.subassembly_target_cell_volume.items():
            require(v > 0, f"subassembly_target_cell_volume.{name}", f"expected a volume > 0 m^3, got {v}")
        require(  # the name is the rigid compartment's in every model (its sub-assembly, or its rigid parts)
            COMPARTMENT not in self.subassembly_target_cell_volume,
            f"subassembly_target_cell_volume.{COMPARTMENT}",
            "the compartment is one rigid cell and is not discretized, so a target cell volume for it would change "
            "nothing: remove the key (a sub-assembly to split into cells needs a name of its own)",
        )
        for i, o in enumerate(self.overlaps):
            require(0 < o < 1, f"overlaps[{i}]", f"expected a fraction in (0, 1), got {o}")
        for key in ("voxels_per_cell_edge", "samples_per_pitch", "max_subdivision"):
            require(getattr(self, key) >= 1, key, f"expected an integer >= 1, got {getattr(self, key)}")
        require(
            self.voxels_per_cell_edge <= 16, "voxels_per_cell_edge", f"expected <= 16, got {self.voxels_per_cell_edge}"
        )
        voxel = self.target_cell_volume / self.voxels_per_cell_edge**3
        for name, v in self.subassembly_target_cell_volume.items():
            require(
                v >= voxel * (1 - 1e-9),
                f"subassembly_target_cell_volume.{name}",
                f"expected at least the fine voxel's volume, target_cell_volume / voxels_per_cell_edge^3 = {voxel:.3g} "
                f"m^3 (no cell is smaller than a voxel), got {v}",
            )
        require(  # each iteration pads every sub-assembly's crop by a voxel a side: 400 ran for minutes
            0 <= self.envelope_closing_iterations <= 16,
            "envelope_closing_iterations",
            f"expected 0 to 16 voxels (n seals gaps up to 2n voxels wide; 16 is four cell edges of the default "
            f"voxels_per_cell_edge), got {self.envelope_closing_iterations}",
        )
        require(  # above 0.5, f_x exceeds the other four factors, which sum to at most 1 - f_x
            0.5 < self.principal_min_share <= 1,
            "principal_min_share",
            f"expected a share in (0.5, 1], got {self.principal_min_share}: boundary condition 3 (DESIGN 1.3) wants "
            "f_x higher than any lateral or vertical factor where load continues rearward, which only a share above "
            "0.5 ensures",
        )
        for key in ("weight_x", "weight_lateral", "weight_vertical"):
            require(getattr(self, key) > 0, key, f"expected a weight > 0, got {getattr(self, key)}")
        for key in ("crush_efficiency_shell", "crush_efficiency_solid"):
            require(0 < getattr(self, key) <= 1, key, f"expected an efficiency in (0, 1], got {getattr(self, key)}")
        for key in ("compaction_shell", "compaction_solid"):
            require(0 <= getattr(self, key) < 1, key, f"expected a fraction in [0, 1), got {getattr(self, key)}")
        require(
            0 < self.min_section_fraction <= 1,
            "min_section_fraction",
            f"expected a fraction in (0, 1], got {self.min_section_fraction}",
        )
        require(
            0 <= self.upfront_sensor_x <= self.roi_depth,
            "upfront_sensor_x",
            f"expected a value in [0, roi_depth = {self.roi_depth}] m, got {self.upfront_sensor_x}",
        )
        require(
            0 <= self.upfront_sensor_y_fraction <= 0.5,
            "upfront_sensor_y_fraction",
            f"expected a fraction in [0, 0.5], got {self.upfront_sensor_y_fraction}",
        )
        require(
            self.sensor_snap_distance > 0,
            "sensor_snap_distance",
            f"expected a distance > 0 m, got {self.sensor_snap_distance}",
        )
        names = [s.name for s in self.sensors]
        for i, s in enumerate(self.sensors):
            try:
                s.validate()
            except ConfigError as e:
                raise ConfigError(e.reason, key=f"sensors[{i}].{e.key}") from None
        dup = sorted({n for n in names if names.count(n) > 1})
        require(not dup, "sensors", f"sensor names must be unique, repeated: {dup}")


def load_discretization_config(path=None, overrides: dict | None = None) -> DiscretizationConfig:
    """Load ``configs/cells.yaml`` (or ``path``) with optional dotted-key overrides."""
    return load_config(DiscretizationConfig, path or (config_dir() / "cells.yaml"), overrides, complete=True)


# ----------------------------------------------------------------------------- labelling
@dataclass
class _Labels:
    labels: np.ndarray  # [nx, ny, nz] cell per voxel
    cell_sub: np.ndarray  # [n] sub-assembly index, -1 null, n_sub for the compartment
    is_null: np.ndarray  # [n]
    is_sensor: np.ndarray  # [n]
    cell_of_sample: np.ndarray  # [P]
    sensor_cell: np.ndarray  # [K]
    sensor_position: np.ndarray  # [K, 3]


_CROSS = ndimage.generate_binary_structure(3, 1)
_YZ = np.zeros((3, 3, 3), dtype=bool)
_YZ[1] = ndimage.generate_binary_structure(2, 1)


def _envelope(occ: np.ndarray, iterations: int) -> np.ndarray:
    """Closed, y-z hole-filled envelope of an occupancy crop (padded internally)."""
    r = iterations + 1
    pad = np.pad(occ, r)
    if iterations > 0:
        pad = ndimage.binary_closing(pad, structure=_CROSS, iterations=iterations)
    pad = ndimage.binary_fill_holes(pad, structure=_YZ)
    return pad[r:-r, r:-r, r:-r] | occ


def _resolve_owners(
    grid: FineGrid, vox: np.ndarray, samples: Samples, n_sub: int, comp_vox: np.ndarray, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per voxel owning sub-assembly (-1 none, ``n_sub`` compartment) and the owner's mass in it."""
    nvox = grid.n_voxels
    shape = grid.shape
    best = np.full(nvox, -1.0)
    owner = np.full(nvox, -1, dtype=np.int64)
    own_mass = np.zeros(nvox)
    key = samples.subassembly * nvox + vox
    uk, inv = np.unique(key, return_inverse=True)
    mass = np.bincount(inv, weights=samples.mass, minlength=uk.size)
    ksub, kvox = uk // nvox, uk % nvox
    groups: list[tuple[int, np.ndarray, np.ndarray]] = [(n_sub, comp_vox, np.zeros(comp_vox.size))]
    starts = np.searchsorted(ksub, np.arange(n_sub + 1))
    groups += [(s, kvox[starts[s] : starts[s + 1]], mass[starts[s] : starts[s + 1]]) for s in range(n_sub)]
    for s, vv, mm in groups:  # a loop over sub-assemblies, each vectorized over its voxels
        if vv.size == 0:
            continue
        ijk = np.array(np.unravel_index(vv, shape))
        lo = np.maximum(ijk.min(axis=1) - iterations - 1, 0)
        hi = np.minimum(ijk.max(axis=1) + iterations + 2, shape)
        crop = tuple(hi - lo)
        occ = np.zeros(crop, dtype=bool)
        local = tuple(ijk - lo[:, None])
        occ[local] = True
        env = _envelope(occ, iterations)
        m = np.zeros(crop)
        m[local] = mm
        e = np.nonzero(env)
        flat = np.ravel_multi_index(tuple(e[a] + lo[a] for a in range(3)), shape)
        if s == n_sub:
            score = np.full(flat.size, -0.5)  # the compartment yields to any deformable envelope
        else:
            tie = 1e-9 * mm.sum() / max(int(env.sum()), 1)  # empty voxels go to the denser envelope
            score = m[e] + tie
        better = score > best[flat]
        best[flat[better]] = score[better]
        owner[flat[better]] = s
        own_mass[flat[better]] = m[e][better] if s != n_sub else 0.0
    # every sub-assembly with material keeps at least its densest voxel
    present = np.unique(ksub)
    missing = np.setdiff1d(present, np.unique(owner[owner >= 0]))
    for s in missing.tolist():
        sel = np.flatnonzero(ksub == s)
        v = kvox[sel[np.argmax(mass[sel])]]
        owner[v] = s
        own_mass[v] = mass[sel].max()
    return owner, own_mass


def _bisect(coords: np.ndarray, group: np.ndarray, n_pieces: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Split voxel groups recursively into pieces, vectorized over all pieces of a level.

    Each piece with a target count ``n > 1`` is cut along its longest extent at the
    voxel-count quantile ``floor(n/2) / n`` (cut between voxel planes; lateral cuts
    counted from the side nearer y = 0, so mirrored pieces split alike), the halves
    getting ``floor(n/2)`` and ``n - floor(n/2)`` pieces, until every piece has ``n = 1``. A group gets at most
    as many pieces as it has voxels.

    Args:
        coords: ``[m, 3]`` voxel centres [m].
        group: ``[m]`` initial piece (0..G-1) of each voxel.
        n_pieces: ``[G]`` target piece count per group.
        pitch: ``[3]`` representative voxel pitch [m] (added to extents).

    Returns:
        ``[m]`` piece index of each voxel (0..P-1, compact).
    """
    piece = group.copy()
    # a piece holds at least one voxel: a group gets no more pieces than it has voxels
    n_of = np.minimum(n_pieces.astype(np.int64), np.bincount(group, minlength=n_pieces.size))
    levels = 0
    while True:
        act_p = n_of > 1
        if not act_p.any():
            break
        act = act_p[piece]
        idx = np.flatnonzero(act)
        p = piece[idx]
        c = coords[idx]
        npc = n_of.size
        lo = np.full((npc, 3), np.inf)
        hi = np.full((npc, 3), -np.inf)
        for a in range(3):
            np.minimum.at(lo[:, a], p, c[:, a])
            np.maximum.at(hi[:, a], p, c[:, a])
        ext = np.where(np.isfinite(lo), hi - lo, 0.0)
        axis = np.argmax(ext + pitch[None, :] * (ext > 0), axis=1)
        cannot = ext[np.arange(npc), axis] <= 0
        n_of[cannot & act_p] = 1  # a single voxel plane cannot be split
        v = c[np.arange(idx.size), axis[p]]
        # Lateral cuts are counted from the side nearer the centre plane y = 0, so a piece
        # right of it is split as the mirror image of its twin on the left.
        flip = (axis[p] == 1) & ((lo[p, 1] + hi[p, 1]) < 0)
        v = np.where(flip, -v, v)
        order = np.lexsort((v, p))
        vs = v[order]
        count = np.bincount(p, minlength=npc)
        start = np.cumsum(count) - count
        n1 = n_of // 2
        k = np.clip(np.floor(count * n1 / np.maximum(n_of, 1)).astype(np.int64), 0, np.maximum(count - 1, 0))
        t = np.full(npc, np.inf)
        has = count > 0
        t[has] = vs[(start + k)[has]]
        left_strict = np.bincount(p, weights=(v < t[p]).astype(float), minlength=npc)
        use_le = left_strict == 0
        left = np.where(use_le[p], v <= t[p], v < t[p])
        split = (n_of[p] > 1) & ~left
        # new slots only for the pieces split at this level, numbered in the order of their source: the final
        # numbering is that of giving every slot a twin (which doubled the slot array of every group at every level,
        # finished pieces too, and stopped a one-voxel-cell target with "bisection did not converge")
        halves = n_of > 1
        new_id = npc + np.cumsum(halves) - 1
        piece[idx[split]] = new_id[p[split]]
        n_of = np.concatenate([np.where(halves, n1, n_of), (n_of - n1)[halves]])
        levels += 1
        if levels > 64:  # defensive: the largest count halves at every level
            raise ModelError("bisection did not converge")
    _, compact = np.unique(piece, return_inverse=True)
    return compact.ravel()


def _snap(grid: FineGrid, candidates: np.ndarray, position: np.ndarray, centre_y: float) -> int:
    """Flat index of the candidate voxel nearest to ``position``.

    Ties (a position midway between voxel centres) go to the voxel farther from the
    centre line ``y = centre_y``, then to larger x (deeper into the structure) and smaller z,
    so mirrored positions snap to mirrored voxels.
    """
    centres = grid.voxel_centers(candidates)
    dist = np.linalg.norm(centres - position[None, :], axis=1)
    near = np.flatnonzero(dist <= dist.min() + 1e-9)
    c = centres[near]
    i = near[np.lexsort((c[:, 2], -c[:, 0], -np.abs(c[:, 1] - centre_y)))[0]]
    return int(candidates[i])


def _sensor_requests(cfg: DiscretizationConfig, roi: Roi) -> list[tuple[str, np.ndarray | None]]:
    """(name, position or None for the compartment) per sensor, before snapping."""
    out = []
    zmid = 0.5 * (roi.lo[2] + roi.hi[2])
    ymid = roi.centre_y
    for s in cfg.sensors:
        if s.position is not None:
            p = np.array(s.position, dtype=np.float64)
        elif s.rule == "compartment":
            p = None
        else:
            sign = 1.0 if s.rule == "upfront_left" else -1.0
            p = np.array([cfg.upfront_sensor_x, ymid + sign * cfg.upfront_sensor_y_fraction * roi.width, zmid])
        inside = p is not None and bool(((p >= roi.lo) & (p <= roi.hi)).all())
        if p is not None and not inside and s.rule in ("upfront_left", "upfront_right"):  # their p is never None
            # an up-front sensor is on the deformable front by definition: outside the ROI (a position in mm, or
            # beside the car) it used to become a compartment sensor without a word
            at = functools.partial(_fmt, frame_y=roi.frame_y)
            given = "its position" if s.position is not None else "upfront_sensor_x and upfront_sensor_y_fraction"
            raise ModelError(
                f"sensor {s.name!r} (rule {s.rule!r}): requested position {at(p)} m, from {given}, is outside the "
                f"region of interest {at(roi.lo)} to {at(roi.hi)} m (positions in m, x rearward from the front); "
                "an up-front sensor must sit on the deformable front: give a position inside it, or the rule "
                "'position' (outside the region: the compartment) or 'compartment'"
            )
        out.append((s.name, p if (inside and s.rule != "compartment") else None))
    return out


def _refuse_off_vehicle(cfg: DiscretizationConfig, model: VehicleModel) -> None:
    """Refuse a ``position`` or ``compartment`` sensor whose given position lies outside the vehicle's bounding box by
    more than ``sensor_snap_distance`` (a position in mm: outside the ROI such a sensor is the compartment's, and it
    was recorded kilometres behind the car without a word). Up-front sensors are checked against the ROI later.

    Raises:
        ModelError: naming the sensor, its position and the vehicle's bounds, in the model's own frame.
    """
    lo, hi = model.bounds()  # of the nodes of its elements: a deck keeps those of a barrier it leaves out
    pad = cfg.sensor_snap_distance
    for s in cfg.sensors:
        if s.position is None or s.rule in ("upfront_left", "upfront_right"):
            continue
        p = np.asarray(s.position, dtype=np.float64)
        if ((p < lo - pad) | (p > hi + pad)).any():
            raise ModelError(
                f"sensor {s.name!r} (rule {s.rule!r}): position {_fmt(p)} m lies outside the vehicle {_fmt(lo)} to "
                f"{_fmt(hi)} m by more than sensor_snap_distance = {pad:g} m; positions are in m, x rearward from the "
                "front (a position in mm?)"
            )


def _fmt(p: np.ndarray, frame_y: float = 0.0) -> str:
    """A position for a message, moved by ``frame_y`` into the model's own frame (:attr:`Roi.frame_y`)."""
    q = np.array(p, dtype=np.float64)
    q[1] += frame_y
    return "[" + ", ".join(f"{v:.3f}" for v in q) + "]"


def _snap_sensors(
    grid: FineGrid, candidates: np.ndarray, reqs: list[tuple[str, np.ndarray | None]], roi: Roi, limit: float
) -> list[int | None]:
    """The voxel each sensor is clustered around (``None``: the compartment), on its own side of the centre line.

    A sensor requested left of the centre line ``y0`` (:attr:`Roi.centre_y`) snaps to the nearest candidate voxel
    left of it, one requested right of it to the nearest right of it, one on it to the nearest anywhere. The nearest
    material overall put the default ``upfront_left`` of the LS-OPT small car (read with ``x=+x,y=+z,z=+y``), which has
    none near it, 0.51 m away and right of the centre line, without a word.

    Raises:
        ModelError: a sensor has no candidate voxel on its side, or the nearest is farther than ``limit``
            (``sensor_snap_distance``) [m]; the message names it with its requested and nearest positions.
    """
    centre = roi.centre_y
    at = functools.partial(_fmt, frame_y=roi.frame_y)  # positions in messages: in the model's own frame
    cy = grid.voxel_centers(candidates)[:, 1] - centre if candidates.size else np.zeros(0)
    out: list[int | None] = []
    for i, (name, p) in enumerate(reqs):  # loop over a handful of sensors
        if p is None or candidates.size == 0:
            out.append(None)
            continue
        side = float(np.sign(p[1] - centre)) if abs(p[1] - centre) > 1e-9 else 0.0
        own = candidates[side * cy > 0] if side else candidates  # voxels never straddle the centre plane
        where = {1.0: "left", -1.0: "right", 0.0: "on either side"}[side]
        where += f" of the centre line y = {centre + roi.frame_y:.3f} m" if side else ""
        fix = (
            f"give it a position (sensors[{i}].position [x, y, z] in m) or the rule 'compartment', move the up-front "
            "sensors (upfront_sensor_x, upfront_sensor_y_fraction), or raise sensor_snap_distance (a deck whose "
            "lateral axis is not marlcrash's y, --axis-map, has this too)"
        )
        if own.size == 0:
            raise ModelError(f"sensor {name!r}: no material {where} to place it on (requested {at(p)} m); {fix}")
        v = _snap(grid, own, p, centre)
        q = grid.voxel_centers(np.array([v]))[0]
        d = float(np.linalg.norm(q - p))
        if d > limit:
            raise ModelError(
                f"sensor {name!r}: no material within sensor_snap_distance = {limit:g} m of its requested position "
                f"{at(p)} m {where}; the nearest is at {at(q)} m, {d:.3f} m away; {fix}"
            )
        out.append(v)
    return out


def _refuse_shared(
    reqs: list[tuple[str, np.ndarray | None]],
    voxels: list[int | None],
    key: np.ndarray,
    grid: FineGrid,
    what: str,
    cell_edge: float,
    frame_y: float = 0.0,
) -> None:
    """Raise :class:`ModelError` naming the first two sensors whose snapped voxels share ``key[voxel]`` (their cell,
    or the voxel itself where every sensor gets a cell of its own): both would record one and the same signal.

    Refused rather than warned: the calibration compares each sensor's signal, so a duplicate doubles one signal's
    weight while the user believes two places are measured; and the optimized method, which gives every sensor a
    cell of its own, handed the second sensor a one-voxel cell carved out of the first's (or failed with an
    IndexError when a third took that voxel too).
    """
    at = functools.partial(_fmt, frame_y=frame_y)  # positions in messages: in the model's own frame
    seen: dict[int, int] = {}
    for k, v in enumerate(voxels):
        if v is None:
            continue
        j = seen.setdefault(int(key[v]), k)
        if j != k:
            q = grid.voxel_centers(np.array([v]))[0]
            (a, pa), (b, pb) = reqs[j], reqs[k]
            assert pa is not None and pb is not None  # a snapped voxel comes from a requested position
            raise ModelError(
                f"sensors {a!r} and {b!r} land in one {what} at {at(q)} m (requested {at(pa)} and {at(pb)} m): "
                "they would record one and the same signal. Move one farther from the other (a cell edge is about "
                f"{cell_edge:.3g} m) or drop it; sensors in the rigid compartment share its cell by design"
            )


def _no_cell(grid: FineGrid, name: str, mass: float) -> ModelError:
    """The error for a sub-assembly whose material ends up in no cell of its own: no mass (``mass``, that of its
    elements in the ROI, is 0: zero density or thickness, or elements of no area or volume) or an envelope thinner
    than the voxel pitch."""
    if not mass > 0:  # voxels are owned by mass: massless elements own none, whatever their shape
        return ModelError(
            f"sub-assembly {name!r} has elements in the region of interest but no mass: their density or "
            "thickness is 0, or they are flat or collapsed (no area or volume: check the deck's coordinates and "
            "units); `marlcrash inspect` lists each part's thickness and mass"
        )
    return ModelError(
        f"sub-assembly {name!r} has material but no cell of its own: its envelope is thinner than the "
        f"{grid.min_pitch():.3g} m voxel pitch; is the geometry flat or collapsed (check the deck's coordinates and "
        "its units, --units)?"
    )


def _attribute_samples(
    grid: FineGrid, labels_flat: np.ndarray, cell_sub: np.ndarray, vox: np.ndarray, samples: Samples, names: list[str]
) -> np.ndarray:
    """Cell of every sample: its voxel's cell if of its own sub-assembly, else the nearest such cell."""
    cell = labels_flat[vox]
    bad = cell_sub[cell] != samples.subassembly
    for s in np.unique(samples.subassembly[bad]).tolist():  # loop over sub-assemblies
        own = np.flatnonzero(cell_sub[labels_flat] == s)
        if own.size == 0:
            raise _no_cell(grid, names[s], float(samples.mass[samples.subassembly == s].sum()))
        tree = cKDTree(grid.voxel_centers(own))
        q = np.flatnonzero(bad & (samples.subassembly == s))
        _, nearest = tree.query(samples.pos[q])
        cell[q] = labels_flat[own[nearest]]
    return cell


def _oversized_cell(volume: float, roi: Roi) -> str | None:
    """How a cell of ``volume`` [m^3] overflows the region of interest, for a warning: its edge against the vehicle's
    width and its front's height (the box's), the ones it exceeds; ``None`` where it fits both. (Its depth is
    ``roi_depth``, which the config checks against ``target_cell_volume``.)"""
    edge = volume ** (1 / 3)
    size = roi.hi - roi.lo
    dims = ((1, "the vehicle's width"), (2, "the height of the vehicle's front in the region of interest"))
    over = [f"{what} ({size[a]:.3f} m)" for a, what in dims if edge > size[a] * (1 + 1e-9)]
    return f"a cell edge of {edge:.3g} m, exceeds {' and '.join(over)}" if over else None


def _subassembly_targets(
    samples: Samples, n_sub: int, names: list[str], cfg: DiscretizationConfig, roi: Roi
) -> np.ndarray:
    """``[n_sub]`` target cell volume [m^3] per sub-assembly.

    ``subassembly_target_cell_volume`` overrides by name; otherwise sub-assemblies whose
    material volume is mostly solid elements (near-rigid blocks such as a powertrain, which
    crush little and move as a few lumped masses) use ``solid_target_cell_volume``; all
    others ``target_cell_volume``. Warns, naming the key, where one of the first two sets a target whose cell
    edge exceeds the vehicle's width or its front's height (``discretize`` warns for ``target_cell_volume``).
    """
    vol = np.bincount(samples.subassembly, weights=samples.volume, minlength=n_sub)[:n_sub]
    solid = np.bincount(
        samples.subassembly, weights=np.where(samples.kind == KIND_SOLID, samples.volume, 0.0), minlength=n_sub
    )[:n_sub]
    target = np.where(solid > 0.5 * vol, cfg.solid_target_cell_volume, cfg.target_cell_volume)
    for i, name in enumerate(names[:n_sub]):
        if name in cfg.subassembly_target_cell_volume:
            target[i] = cfg.subassembly_target_cell_volume[name]
    big: dict[tuple[str, float], list[str]] = {}  # (key, value) -> the sub-assemblies with material it sets it for
    for i, name in enumerate(names[:n_sub]):
        if name in cfg.subassembly_target_cell_volume:
            key = f"subassembly_target_cell_volume.{name}"
        elif solid[i] > 0.5 * vol[i]:
            key = "solid_target_cell_volume"
        else:
            continue  # target_cell_volume: discretize warns
        if vol[i] > 0 and _oversized_cell(float(target[i]), roi):
            big.setdefault((key, float(target[i])), []).append(name)
    for (key, v), subs in big.items():
        what = f" ({', '.join(subs)})" if key == "solid_target_cell_volume" else ""
        warnings.warn(
            f"{key} = {v:g} m^3{what}, {_oversized_cell(v, roi)}: no cell fits that size, each y band of the "
            "sub-assembly's material becomes about one cell (a volume in other units?)",
            UserWarning,
            stacklevel=4,
        )
    known = names[:n_sub]
    for name in cfg.subassembly_target_cell_volume:
        # the compartment's name too: its key is refused (validate), a near miss of it changed nothing in silence
        close = [] if name in known else difflib.get_close_matches(name, [*known, COMPARTMENT], n=1, cutoff=0.8)
        if close:  # names a model lacks are ignored (the shared config's wheels), a near miss is most likely a typo
            why = (
                " (the compartment is one rigid cell and is not discretized: remove the key)"
                if close[0] == COMPARTMENT
                else ""
            )
            warnings.warn(
                f"subassembly_target_cell_volume.{name}: the model has no sub-assembly of this name, so it changes "
                f"nothing; did you mean '{close[0]}'?{why}",
                UserWarning,
                stacklevel=4,
            )
    return target


def _optimized(
    grid: FineGrid,
    roi: Roi,
    vox: np.ndarray,
    samples: Samples,
    n_sub: int,
    comp_vox: np.ndarray,
    cfg: DiscretizationConfig,
    names: list[str],
) -> _Labels:
    shape = grid.shape
    nvox = grid.n_voxels
    target = _subassembly_targets(samples, n_sub, names, cfg, roi)
    n_bands = int(grid.band_y.max()) + 1
    owner, own_mass = _resolve_owners(grid, vox, samples, n_sub, comp_vox, cfg.envelope_closing_iterations)
    _, iy, _ = np.unravel_index(np.arange(nvox), shape)
    band = grid.band_y[iy]
    vvol = grid.voxel_volume().ravel()
    # sensors: a block of about one target volume around the snapped voxel, same sub-assembly and band
    group = np.full(nvox, -1, dtype=np.int64)
    sensor_groups: list[int] = []
    sensor_pos: list[np.ndarray | None] = []  # None: the compartment's sensor
    sensor_is_comp: list[bool] = []
    cand = np.flatnonzero((owner >= 0) & (owner < n_sub) & (own_mass > 0))
    half = cfg.voxels_per_cell_edge // 2
    reqs = _sensor_requests(cfg, roi)
    snapped = _snap_sensors(grid, cand, reqs, roi, cfg.sensor_snap_distance)
    # every sensor gets a cell of its own around its voxel: two on one voxel cannot
    _refuse_shared(reqs, snapped, np.arange(nvox), grid, "voxel", cfg.target_cell_volume ** (1 / 3), roi.frame_y)
    n_groups_base = n_sub * (int(grid.band_y.max()) + 1)
    blocks = []
    for k, ((_, p), v) in enumerate(zip(reqs, snapped, strict=True)):  # loop over a handful of sensors
        if v is None:
            sensor_is_comp.append(True)
            sensor_pos.append(None)
            continue
        assert p is not None  # a snapped voxel comes from a requested position
        vi = np.array(np.unravel_index(v, shape))
        before = np.full(3, half)
        if p[1] < roi.centre_y:  # mirror the block's lateral extent for sensors right of the centre plane
            before[1] = cfg.voxels_per_cell_edge - 1 - half
        lo = np.maximum(vi - before, 0)
        hi = np.minimum(lo + cfg.voxels_per_cell_edge, shape)
        sl = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi, strict=True))
        block = np.zeros(shape, dtype=bool)
        block[sl] = True
        blocks.append((k, v, np.flatnonzero(block.ravel() & (owner == owner[v]) & (band == band[v]))))
        sensor_groups.append(n_groups_base + k)
        sensor_is_comp.append(False)
        sensor_pos.append(grid.voxel_centers(np.array([v]))[0])
    # A voxel in the blocks of several sensors goes to the nearest sensor's voxel, a tie to the smaller voxel index, so
    # no sensor's cell depends on where the config lists it (the first listed took the shared voxels; its own voxel
    # is nearest to every sensor)
    near = np.full(nvox, np.inf)
    for k, v, idx in sorted(blocks, key=lambda b: b[1]):
        d = ((grid.voxel_centers(idx) - grid.voxel_centers(np.array([v]))) ** 2).sum(axis=1)
        better = d < near[idx]
        near[idx[better]] = d[better]
        group[idx[better]] = n_groups_base + k
    # sub-assembly envelopes per y band, split into pieces of about the target volume
    owned = (owner >= 0) & (owner < n_sub) & (group < 0)
    group[owned] = owner[owned] * (int(grid.band_y.max()) + 1) + band[owned]
    member = np.flatnonzero(group >= 0)
    ug, ginv = np.unique(group[member], return_inverse=True)
    gvol = np.bincount(ginv, weights=vvol[member])
    n_pieces = np.maximum(1, np.round(gvol / target[np.minimum(ug // n_bands, n_sub - 1)])).astype(np.int64)
    n_pieces[np.isin(ug, sensor_groups)] = 1
    pitch = np.array([grid.widths(a).mean() for a in range(3)])
    piece = _bisect(grid.voxel_centers(member), ginv.ravel(), n_pieces, pitch)
    n_cells_mat = int(piece.max()) + 1 if piece.size else 0
    labels = np.full(nvox, -1, dtype=np.int64)
    labels[member] = piece
    cell_sub = np.zeros(n_cells_mat, dtype=np.int64)
    cell_sub[piece] = np.where(group[member] >= n_groups_base, owner[member], group[member] // (grid.band_y.max() + 1))
    is_sensor = np.zeros(n_cells_mat, dtype=bool)
    sensor_cell_mat = {}
    for g in sensor_groups:
        c = int(piece[np.flatnonzero(group[member] == g)[0]])
        is_sensor[c] = True
        sensor_cell_mat[g - n_groups_base] = c
    # null space: connected empty components per y band
    empty = (owner < 0).reshape(shape)
    null_lab = np.zeros(shape, dtype=np.int64)
    n_null = 0
    for b in range(int(grid.band_y.max()) + 1):  # loop over the few y bands
        cols = np.flatnonzero(grid.band_y == b)
        lab, nb = ndimage.label(empty[:, cols, :])
        null_lab[:, cols, :] = np.where(lab > 0, lab + n_null, 0)
        n_null += nb
    nl = null_lab.ravel()
    labels[nl > 0] = n_cells_mat + nl[nl > 0] - 1
    n = n_cells_mat + n_null + 1
    comp = n - 1
    labels[owner == n_sub] = comp
    cell_sub = np.concatenate([cell_sub, np.full(n_null, -1), [n_sub]])
    is_null = np.zeros(n, dtype=bool)
    is_null[n_cells_mat:comp] = True
    is_sensor = np.concatenate([is_sensor, np.zeros(n_null + 1, dtype=bool)])
    cell_of_sample = _attribute_samples(grid, labels, cell_sub, vox, samples, names)
    labels, cell_of_sample, keep = _merge_massless(grid, labels, cell_of_sample, cell_sub, is_null, samples, names)
    if keep is not None:
        new = np.cumsum(keep) - 1
        cell_sub, is_null, is_sensor = cell_sub[keep], is_null[keep], is_sensor[keep]
        sensor_cell_mat = {k: int(new[c]) for k, c in sensor_cell_mat.items()}
        n = int(keep.sum())
        comp = n - 1
    sensor_cell = np.array([sensor_cell_mat.get(k, comp) for k in range(len(reqs))], dtype=np.int64)
    return _Labels(
        labels=labels.reshape(shape),
        cell_sub=cell_sub,
        is_null=is_null,
        is_sensor=is_sensor,
        cell_of_sample=cell_of_sample,
        sensor_cell=sensor_cell,
        sensor_position=_sensor_positions(sensor_pos),
    )


MIN_BAND = 1e-3
"""[m] The narrowest band between section planes (or a plane and the side of the region of interest): barrier
overlaps whose edges differ by less are one load case to any test (a barrier is placed to about 2 cm)."""


def _refuse_slivers(roi: Roi, cfg: DiscretizationConfig) -> None:
    """Raise :class:`ConfigError` (key ``overlaps``) where two section planes, or a plane and the side of the region
    of interest, lie closer than :data:`MIN_BAND`: the band between them gets a column of cells that thin
    (``overlaps: [0.4, 0.4000001]`` made voxels of 4e-8 m, and a warning to raise max_subdivision to 3,750,000)."""
    lo, hi = roi.lo[1], roi.hi[1]
    inner = roi.planes_y[(roi.planes_y > lo + EDGE_TOL) & (roi.planes_y < hi - EDGE_TOL)]
    bounds = np.concatenate([[lo], inner, [hi]])
    gaps = np.diff(bounds)
    if gaps.size > 1 and gaps.min() < MIN_BAND:
        i = int(np.argmin(gaps))
        a, b = (float(v - roi.centre_y) for v in bounds[i : i + 2])
        what = (
            "a section plane and the side of the region of interest"
            if i in (0, gaps.size - 1)
            else "two section planes"
        )
        raise ConfigError(
            f"{what} lie {gaps[i]:.3g} m apart (y - y0 = {a:.9g} and {b:.9g} m), less than {MIN_BAND:g} m: the band "
            f"between them would be a sliver of cells; drop one of the overlaps {cfg.overlaps} or make their barrier "
            "edges differ by more",
            key="overlaps",
        )


def _merge_massless(
    grid: FineGrid,
    labels: np.ndarray,
    cell_of_sample: np.ndarray,
    cell_sub: np.ndarray,
    is_null: np.ndarray,
    samples: Samples,
    names: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Material cells given no material (envelope interior only) join the nearest cell of their sub-assembly in
    their y band: a cell spanning a section plane would break the overlaps' whole cells (DESIGN 1.2). Only where the
    sub-assembly has no material in that band do they join its nearest cell across the plane.

    Returns the renumbered voxel labels and sample cells, and the mask of the cells kept (``None`` when every cell
    has material and nothing changed); the compartment (last cell) is always kept.
    """
    n = cell_sub.size
    mass = np.bincount(cell_of_sample, weights=samples.mass, minlength=n)
    empty = ~is_null & (mass <= 0)
    empty[n - 1] = False
    if not empty.any():
        return labels, cell_of_sample, None
    _, ny, nz = grid.shape
    band = grid.band_y[(np.arange(labels.size) // nz) % ny]
    for s in np.unique(cell_sub[empty]).tolist():
        own = cell_sub[labels] == s
        if not (own & ~empty[labels]).any():  # every cell of the sub-assembly is empty
            raise _no_cell(grid, names[s], float(samples.mass[samples.subassembly == s].sum()))
        for b in np.unique(band[own & empty[labels]]).tolist():  # a handful of bands
            src = np.flatnonzero(own & empty[labels] & (band == b))
            dst = np.flatnonzero(own & ~empty[labels] & (band == b))
            if dst.size == 0:
                dst = np.flatnonzero(own & ~empty[labels])
            _, nearest = cKDTree(grid.voxel_centers(dst)).query(grid.voxel_centers(src))
            labels[src] = labels[dst[nearest]]
    keep = ~empty
    new = np.cumsum(keep) - 1
    return new[labels], new[cell_of_sample], keep


def _sensor_positions(pos: list) -> np.ndarray:
    return np.array([[np.nan] * 3 if p is None else list(p) for p in pos], dtype=np.float64).reshape(-1, 3)


def _uniform(
    grid: FineGrid,
    roi: Roi,
    vox: np.ndarray,
    samples: Samples,
    n_sub: int,
    comp_vox: np.ndarray,
    cfg: DiscretizationConfig,
    names: list[str],
) -> _Labels:
    """Cells of the regular grid: one per block (``uniform_cells: per_block``), or one per block and sub-assembly
    owning voxels in it (``per_subassembly``, the default), so that no cell fuses two parts' material (a block
    straddling the gap between the powertrain and a rail otherwise bonds them, and gives the rail the engine's
    strength)."""
    shape = grid.shape
    _, nby, nbz = grid.n_blocks
    bx, by, bz = grid.block
    bid = ((bx[:, None, None] * nby + by[None, :, None]) * nbz + bz[None, None, :]).ravel()
    if cfg.uniform_cells == "per_block":
        count = np.bincount(samples.subassembly, minlength=n_sub)
        weight = np.bincount(samples.subassembly, weights=samples.mass, minlength=n_sub)
        for s in np.flatnonzero((count > 0) & ~(weight > 0)).tolist():  # named, as the other methods do
            raise _no_cell(grid, names[s], float(weight[s]))
        labels, cell_sub, is_null = _uniform_blocks(bid, grid.n_uniform_cells, vox, samples, n_sub, comp_vox)
        cell_of_sample, cand = labels[vox], np.unique(vox[samples.mass > 0])  # a sensor sits on a cell with mass
    else:
        labels, cell_sub, is_null, cell_of_sample, cand = _uniform_split(grid, bid, vox, samples, n_sub, comp_vox,
                                                                         cfg, names)  # fmt: skip
    n = cell_sub.size
    comp = n - 1
    is_sensor = np.zeros(n, dtype=bool)
    sensor_cell: list[int] = []
    sensor_pos: list[np.ndarray | None] = []  # None: the compartment's sensor
    reqs = _sensor_requests(cfg, roi)
    snapped = _snap_sensors(grid, cand, reqs, roi, cfg.sensor_snap_distance)
    _refuse_shared(reqs, snapped, labels, grid, "cell", cfg.target_cell_volume ** (1 / 3), roi.frame_y)
    for v in snapped:
        if v is None:
            sensor_cell.append(comp)
            sensor_pos.append(None)
            continue
        sensor_cell.append(int(labels[v]))
        is_sensor[labels[v]] = True
        sensor_pos.append(grid.voxel_centers(np.array([v]))[0])
    return _Labels(
        labels=labels.reshape(shape),
        cell_sub=cell_sub,
        is_null=is_null,
        is_sensor=is_sensor,
        cell_of_sample=cell_of_sample,
        sensor_cell=np.array(sensor_cell, dtype=np.int64),
        sensor_position=_sensor_positions(sensor_pos),
    )


def _uniform_blocks(
    bid: np.ndarray, nb: int, vox: np.ndarray, samples: Samples, n_sub: int, comp_vox: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One cell per block with material, labelled by its heaviest sub-assembly and holding all of the block's
    material; empty blocks are null cells, blocks of compartment material only join the compartment (last).
    Material without mass (a part of zero thickness or density) makes no block a cell: a cell without mass has
    no inertia and no parameters, and the other methods give such material no cell either."""
    heavy = samples.mass > 0
    sb = bid[vox[heavy]]
    key = sb * n_sub + samples.subassembly[heavy]
    uk, inv = np.unique(key, return_inverse=True)
    m = np.bincount(inv, weights=samples.mass[heavy], minlength=uk.size)
    kb, ks = uk // n_sub, uk % n_sub
    order = np.lexsort((-m, kb))
    first = np.ones(order.size, dtype=bool)
    first[1:] = kb[order][1:] != kb[order][:-1]
    dom = np.full(nb, -1, dtype=np.int64)
    dom[kb[order][first]] = ks[order][first]
    has_mat = dom >= 0
    has_comp = np.zeros(nb, dtype=bool)
    has_comp[bid[comp_vox]] = True
    n_mat = int(has_mat.sum())
    null_blocks = ~has_mat & ~has_comp
    n_null = int(null_blocks.sum())
    n = n_mat + n_null + 1
    cell_of_block = np.full(nb, n - 1, dtype=np.int64)
    cell_of_block[has_mat] = np.arange(n_mat)
    cell_of_block[null_blocks] = n_mat + np.arange(n_null)
    cell_sub = np.concatenate([dom[has_mat], np.full(n_null, -1), [n_sub]])
    is_null = np.zeros(n, dtype=bool)
    is_null[n_mat : n - 1] = True
    return cell_of_block[bid], cell_sub, is_null


def _uniform_split(
    grid: FineGrid,
    bid: np.ndarray,
    vox: np.ndarray,
    samples: Samples,
    n_sub: int,
    comp_vox: np.ndarray,
    cfg: DiscretizationConfig,
    names: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One cell per block and owning sub-assembly (voxel ownership as in the optimized method, every sample in a
    cell of its own sub-assembly); a block's unowned voxels are one null cell, compartment voxels the compartment.
    A piece that receives no material joins the nearest piece of its sub-assembly. Returns voxel labels, the
    cells' sub-assemblies, null flags, the cell of every sample, and the voxels a sensor may snap to."""
    owner, own_mass = _resolve_owners(grid, vox, samples, n_sub, comp_vox, cfg.envelope_closing_iterations)
    mat = (owner >= 0) & (owner < n_sub)
    uk, inv = np.unique(bid[mat] * n_sub + owner[mat], return_inverse=True)
    n_mat = uk.size
    labels = np.full(grid.n_voxels, -1, dtype=np.int64)
    labels[mat] = inv.ravel()
    empty = owner < 0
    ub, binv = np.unique(bid[empty], return_inverse=True)
    n_null = ub.size
    labels[empty] = n_mat + binv.ravel()
    n = n_mat + n_null + 1
    labels[owner == n_sub] = n - 1
    cell_sub = np.concatenate([uk % n_sub, np.full(n_null, -1), [n_sub]]).astype(np.int64)
    is_null = np.zeros(n, dtype=bool)
    is_null[n_mat : n - 1] = True
    cell_of_sample = _attribute_samples(grid, labels, cell_sub, vox, samples, names)
    labels, cell_of_sample, keep = _merge_massless(grid, labels, cell_of_sample, cell_sub, is_null, samples, names)
    if keep is not None:
        cell_sub, is_null = cell_sub[keep], is_null[keep]
    return labels, cell_sub, is_null, cell_of_sample, np.flatnonzero(mat & (own_mass > 0))


# ----------------------------------------------------------------------------- assembly
def _subassembly_table(model: VehicleModel, comp_parts: np.ndarray) -> tuple[list[str], dict[int, int]]:
    """Sub-assembly names (compartment last) and part id -> index."""
    of_part = model.subassembly_of_part()
    comp_set = set(comp_parts.tolist())
    names = [n for n in model.subassemblies if n != COMPARTMENT]
    names += sorted({of_part[p] for p in model.parts if of_part[p] not in names and p not in comp_set})
    names = [n for n in names if n != COMPARTMENT] + [COMPARTMENT]
    index = {n: i for i, n in enumerate(names)}
    part_sub = {p: (len(names) - 1 if p in comp_set else index[of_part[p]]) for p in model.parts}
    return names, part_sub


def _voxel_boxes(grid: FineGrid, labels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-cell voxel bounding boxes ``[n, 3]`` x2 and voxel volume ``[n]`` (cells without voxels: nan, 0)."""
    flat = labels.ravel()
    order = np.argsort(flat, kind="stable")
    fl = flat[order]
    cells, starts = np.unique(fl, return_index=True)
    lo = np.full((n, 3), np.nan)
    hi = np.full((n, 3), np.nan)
    idx = np.unravel_index(order, grid.shape)
    for a in range(3):
        e = grid.edges[a]
        lo[cells, a] = e[np.minimum.reduceat(idx[a], starts)]
        hi[cells, a] = e[np.maximum.reduceat(idx[a], starts) + 1]
    vol = np.bincount(flat, weights=grid.voxel_volume().ravel(), minlength=n)
    return lo, hi, vol


def _material_table(model: VehicleModel) -> tuple[np.ndarray, dict[int, int]]:
    mids = sorted(model.materials)
    table = np.stack([model.materials[m].vector() for m in mids]) if mids else np.zeros((0, 8))
    row = {m: i for i, m in enumerate(mids)}
    return table, {pid: row[p.material_id] for pid, p in model.parts.items()}


def _point_masses(
    model: VehicleModel,
    grid: FineGrid,
    labels: np.ndarray,
    structural: np.ndarray,
    roi: Roi,
    samples: Samples,
    cell_of_sample: np.ndarray,
) -> np.ndarray:
    """``[n]`` point mass [kg] in each cell: a node's lumped mass goes to the cell of its voxel.

    A mass on a node of a discretized element whose voxel holds no cell of structure (``structural``: ``[n]``
    bool; null space beside a wall whose samples lie in the next voxel, a compartment voxel, or outside the box at
    the rear of an element straddling ``roi_depth``) goes to the cell of the nearest material sample: it rode with
    the rigid compartment. Any other mass outside the ROI box or in a cell without structure is left out here; the
    caller leaves it to the rigid compartment, which takes the rest of the vehicle's total mass.
    """
    out = np.zeros(structural.size)
    if model.point_mass.size:
        pts = model.coords[model.point_mass_nodes]
        vox, inside = grid.locate(pts, clamp=False)
        cell = np.where(inside, labels.ravel()[np.where(inside, vox, 0)], -1)
        front = np.concatenate([model.shell_nodes[roi.shell_in].ravel(), model.solid_nodes[roi.solid_in].ravel(),
                                model.beam_nodes[roi.beam_in].ravel()])  # fmt: skip
        stray = np.isin(model.point_mass_nodes, front) & ((cell < 0) | ~structural[np.maximum(cell, 0)])
        if stray.any() and samples.n:
            _, nearest = cKDTree(samples.pos).query(pts[stray])
            cell[stray] = cell_of_sample[nearest]
        ok = cell >= 0
        np.add.at(out, cell[ok], model.point_mass[ok])
    return out


def _compartment_aggregate(
    model: VehicleModel, roi: Roi, mat_table, part_row
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Material 8-vector, mass centroid and bounding box of everything not discretized."""
    vec_sum = np.zeros(8)
    mom = np.zeros(3)
    mtot = 0.0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for kind, sel, parts, nodes in (
        ("shell", ~roi.shell_in, model.shell_part, model.shell_nodes),
        ("solid", ~roi.solid_in, model.solid_part, model.solid_nodes),
        ("beam", ~roi.beam_in, model.beam_part, model.beam_nodes),
    ):
        if not sel.any():
            continue
        m = roi.masses[kind][sel]
        pts = model.coords[nodes[sel]]
        c = pts.mean(axis=1)
        rows = np.array([part_row[int(p)] for p in np.unique(parts[sel])])
        uniq, inv = np.unique(parts[sel], return_inverse=True)
        msum = np.bincount(inv, weights=m, minlength=uniq.size)
        vec_sum += (mat_table[rows] * msum[:, None]).sum(axis=0)
        mom += (c * m[:, None]).sum(axis=0)
        mtot += float(m.sum())
        lo = np.minimum(lo, pts.reshape(-1, 3).min(axis=0))
        hi = np.maximum(hi, pts.reshape(-1, 3).max(axis=0))
    if mtot <= 0:
        return np.zeros(8), np.full(3, np.nan), lo, hi
    return vec_sum / mtot, mom / mtot, lo, hi


def discretize(model: VehicleModel, config: DiscretizationConfig | None = None, method: str | None = None) -> CellModel:
    """Discretize a vehicle's front into a :class:`CellModel`.

    Args:
        model: the vehicle in marlcrash axes (x rearward from the front at 0, y left, z up).
        config: discretization settings; ``None`` loads ``configs/cells.yaml``.
        method: ``"optimized"`` or ``"uniform"``; overrides ``config.method``.

    Returns:
        The validated :class:`CellModel` (compartment last).

    Raises:
        ConfigError: unknown method, a config that is no :class:`DiscretizationConfig`, or an invalid one.
        ModelError: ``model`` is no :class:`VehicleModel`, is inconsistent, or has no deformable material in the ROI.
    """
    if not isinstance(model, VehicleModel):  # None or a deck path failed with "has no attribute 'validate'"
        raise ModelError(
            f"model must be a VehicleModel (marlcrash.vehicle.load_vehicle(name or path)), got {type(model).__name__} "
            f"{model!r:.80}"
        )
    if config is not None and not isinstance(config, DiscretizationConfig):  # a path: a TypeError of dataclasses
        raise ConfigError(
            "config must be a DiscretizationConfig (load_discretization_config(path, overrides)), got "
            f"{type(config).__name__} {config!r:.80}",
            key="config",
        )
    cfg = load_discretization_config() if config is None else checked(config)  # one made in Python: unchecked
    method = cfg.method if method is None else method
    if method not in ("optimized", "uniform"):
        raise ConfigError(f"expected 'optimized' or 'uniform', got {method!r}", key="method")
    t0 = time.perf_counter()
    timings: dict[str, float] = {}

    def tick(name):
        nonlocal t0
        t1 = time.perf_counter()
        timings[name] = round(t1 - t0, 4)
        t0 = t1

    model.validate()
    _refuse_off_vehicle(cfg, model)
    roi = region_of_interest(model, cfg.roi_depth, cfg.overlaps)
    _refuse_slivers(roi, cfg)
    notes = []
    length = float(np.ptp(model.bounds()[:, 0]))  # the front is at x = 0 (region_of_interest checked it)
    if cfg.roi_depth > length * (1 + 1e-9):  # a valid model all the same: the box behind the rear is null space
        notes.append(
            f"roi_depth = {cfg.roi_depth:g} m is longer than the vehicle ({length:.3f} m from its front-most to its "
            f"rear-most node): the region of interest runs {cfg.roi_depth - length:.3g} m past its rear, every "
            "element but the rigid compartment's is discretized and the rest of the box is null space; roi_depth is "
            "the crop depth in m behind the front (1.2 in the paper)"
        )
        warnings.warn(f"{model.name}: {notes[-1]}", UserWarning, stacklevel=2)
    oversized = _oversized_cell(cfg.target_cell_volume, roi)
    if oversized:  # a valid model all the same, of a few cells cut to the box
        notes.append(
            f"target_cell_volume = {cfg.target_cell_volume:g} m^3, {oversized}: no cell fits that size, the grid "
            "gets about one block across each band between section planes and the box's height (a volume in other "
            "units?)"
        )
        warnings.warn(f"{model.name}: {notes[-1]}", UserWarning, stacklevel=2)
    # Discretize in the frame centred on the vehicle's centre line, where the grid's mirror rules hold (ties fall
    # away from y = 0, the bisection mirrors about it): a model read with AxisMap.y_center off its middle, 1 mm
    # sideways, got 505 cells instead of the default car's 518. Moved back at the end.
    shift_y = roi.centre_y
    cfg_user = cfg
    if shift_y != 0.0:
        model = dataclasses.replace(model, coords=model.coords - np.array([0.0, shift_y, 0.0]))
        roi = dataclasses.replace(region_of_interest(model, cfg.roi_depth, cfg.overlaps), frame_y=shift_y)
        cfg = dataclasses.replace(
            cfg,
            sensors=[
                s if s.position is None else dataclasses.replace(s, position=_moved(s.position, -shift_y).tolist())
                for s in cfg.sensors
            ],
        )
    grid = build_grid(roi.lo, roi.hi, roi.planes_y, cfg.target_cell_volume, cfg.voxels_per_cell_edge)
    names, part_sub = _subassembly_table(model, roi.compartment_parts)
    n_sub = len(names) - 1
    mat_table, part_row = _material_table(model)
    pitch = grid.min_pitch()
    tick("roi_grid")
    samples = sample_elements(
        model, roi.shell_in, roi.solid_in, roi.beam_in, part_row, part_sub, pitch,
        cfg.samples_per_pitch, cfg.max_subdivision, roi.masses, roi.added,
        np.array([grid.widths(a).min() for a in range(3)]),
    )  # fmt: skip
    vox, _ = grid.locate(samples.pos, clamp=True)
    # compartment material inside the ROI box labels its voxels as the compartment
    comp_parts = roi.compartment_parts
    near = []
    for parts, nodes in ((model.shell_part, model.shell_nodes), (model.solid_part, model.solid_nodes)):
        x = model.coords[nodes][:, :, 0]
        near.append(np.isin(parts, comp_parts) & (x.min(axis=1) < roi.hi[0]))
    beam_x = model.coords[model.beam_nodes][:, :, 0]
    near.append(np.isin(model.beam_part, comp_parts) & (beam_x.min(axis=1) < roi.hi[0]))
    comp_samples = sample_elements(
        model, near[0], near[1], near[2], part_row, part_sub, pitch, 1, cfg.max_subdivision, roi.masses, roi.added
    )
    cv, inside = grid.locate(comp_samples.pos, clamp=False)
    comp_vox = np.unique(cv[inside])
    tick("sampling")
    builder = _optimized if method == "optimized" else _uniform
    lab = builder(grid, roi, vox, samples, n_sub, comp_vox, cfg, names)
    tick("labelling")
    n = lab.is_null.shape[0]
    comp = n - 1
    cos = lab.cell_of_sample
    # material and centroid weighted by the structural mass
    smass = np.bincount(cos, weights=samples.mass, minlength=n)
    smass[comp] = 0.0
    mvec = np.stack(
        [np.bincount(cos, weights=samples.mass * mat_table[samples.material, j], minlength=n) for j in range(8)], axis=1
    )
    material = np.divide(mvec, smass[:, None], out=np.zeros((n, 8)), where=smass[:, None] > 0)
    mom = np.stack([np.bincount(cos, weights=samples.mass * samples.pos[:, a], minlength=n) for a in range(3)], axis=1)
    lo, hi, volume = _voxel_boxes(grid, lab.labels, n)
    geo_centre = 0.5 * (lo + hi)
    centroid = np.where(smass[:, None] > 0, mom / np.where(smass > 0, smass, 1.0)[:, None], geo_centre)
    # inertia: structural, added and point masses; what lands in a cell without structure rides with the compartment
    mass = np.bincount(cos, weights=samples.mass + samples.added, minlength=n)
    mass += _point_masses(model, grid, lab.labels, smass > 0, roi, samples, cos)
    mass[smass <= 0] = 0.0
    cvec, ccen, clo, chi = _compartment_aggregate(model, roi, mat_table, part_row)
    comp_mass = roi.total_mass - float(mass.sum())
    if abs(comp_mass) <= 1e-9 * roi.total_mass:  # rounding of the sum, either sign (-1.7e-15 kg was printed -0.000;
        comp_mass = 0.0  # 8e-14 kg, with finer sampling, read as a compartment with mass)
    mass[comp] = comp_mass
    material[comp] = cvec
    if not np.isfinite(ccen).all():
        ccen = np.array([roi.hi[0], 0.5 * (roi.lo[1] + roi.hi[1]), 0.5 * (roi.lo[2] + roi.hi[2])])
        clo = np.array([roi.hi[0], roi.lo[1], roi.lo[2]])
        chi = np.array([roi.hi[0], roi.hi[1], roi.hi[2]])
    centroid[comp] = ccen
    lo[comp] = np.minimum(clo, np.where(np.isfinite(lo[comp]), lo[comp], np.inf))
    hi[comp] = np.maximum(chi, np.where(np.isfinite(hi[comp]), hi[comp], -np.inf))
    volume[comp] = float(np.prod(hi[comp] - lo[comp]))
    tick("aggregate")
    # links, sections, factors
    faces, front_area = extract_faces(lab.labels, grid, lab.is_null, comp)
    planes = faces.needed_planes()
    reach = roi.hi[0] + 2 * pitch
    near_roi = [
        model.coords[nodes][:, :, 0].min(axis=1) < reach
        for nodes in (model.shell_nodes, model.solid_nodes, model.beam_nodes)
    ]
    sections = grid_sections(model, grid, planes, *near_roi)
    links, n_turned = orient_x_links(aggregate_links(faces, sections, planes, n), centroid[:, 0])
    tick("links_sections")
    is_rigid = np.zeros(n, dtype=bool)
    is_rigid[comp] = True
    active = ~lab.is_null & ~is_rigid & (mass > 0)
    factors, feasible, share = transmission_factors(
        n, links, active, (cfg.weight_x, cfg.weight_lateral, cfg.weight_vertical), cfg.principal_min_share
    )
    crush_length = np.where(lab.is_null | is_rigid, 0.0, hi[:, 0] - lo[:, 0])
    crush_length = np.where(np.isfinite(crush_length), crush_length, 0.0)
    e_x, e_s, _, stroke = behaviour_params(
        samples, cos, n, material, crush_length, active,
        cfg.crush_efficiency_shell, cfg.crush_efficiency_solid, cfg.compaction_shell, cfg.compaction_solid,
        cfg.min_section_fraction,
    )  # fmt: skip
    params = np.concatenate([e_x[:, None], e_s[:, None], factors], axis=1)
    tick("params")
    # sub-assembly indices: keep names that own a cell, compartment included
    used = np.unique(lab.cell_sub[lab.cell_sub >= 0])
    remap = np.full(n_sub + 1, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    cell_sub = np.where(lab.cell_sub >= 0, remap[np.maximum(lab.cell_sub, 0)], -1)
    sensor_pos = lab.sensor_position.copy()
    for k in range(sensor_pos.shape[0]):
        if not np.isfinite(sensor_pos[k]).all():
            spec = cfg.sensors[k]
            sensor_pos[k] = spec.position if spec.position is not None else ccen
    if comp_mass <= 0:
        notes.append(f"the compartment has no mass ({comp_mass:.3g} kg): every element lies in the ROI")
        warnings.warn(f"{model.name}: {notes[-1]}", UserWarning, stacklevel=2)  # was only kept in meta
    out = CellModel(
        lo=np.where(np.isfinite(lo), lo, 0.0),
        hi=np.where(np.isfinite(hi), hi, 0.0),
        centroid=centroid,
        volume=volume,
        mass=mass,
        material=material,
        params=params,
        feasible=feasible,
        subassembly=cell_sub,
        is_null=lab.is_null,
        is_sensor=lab.is_sensor,
        is_rigid=is_rigid,
        front_area=front_area,
        crush_length=crush_length,
        stroke=stroke,
        link_src=links.src,
        link_dst=links.dst,
        link_dir=links.dir,
        link_contact_area=links.contact_area,
        link_material_area=links.material_area,
        link_gap=links.gap,
        link_share=share,
        sensor_names=[s.name for s in cfg.sensors],
        sensor_cell=lab.sensor_cell,
        sensor_position=sensor_pos,
        subassembly_names=[names[i] for i in used.tolist()],
        method=method,
        target_cell_volume=float(cfg.target_cell_volume),
        roi_depth=float(cfg.roi_depth),
        roi_lo=roi.lo,
        roi_hi=roi.hi,
        planes_y=roi.planes_y,
        vehicle_width=roi.width,
        roi_mass=roi.roi_mass,
        total_mass=roi.total_mass,
        grid_edges=grid.edges,
        grid_labels=lab.labels,
        name=model.name,
        meta={
            "config": dataclasses.asdict(cfg_user),
            "n_cells_uniform": grid.n_uniform_cells,
            "grid_shape": list(grid.shape),
            "n_samples": samples.n,
            "timings_s": timings,
            "x_links_turned": n_turned,  # +x links of interleaved cells turned along the x centroids (transmission)
            "warnings": notes,
        },
    )
    if shift_y != 0.0:  # back to the model's own frame
        out = dataclasses.replace(
            out,
            lo=_moved(out.lo, shift_y),
            hi=_moved(out.hi, shift_y),
            centroid=_moved(out.centroid, shift_y),
            sensor_position=_moved(out.sensor_position, shift_y),
            roi_lo=_moved(out.roi_lo, shift_y),
            roi_hi=_moved(out.roi_hi, shift_y),
            planes_y=out.planes_y + shift_y,
            grid_edges=(out.grid_edges[0], out.grid_edges[1] + shift_y, out.grid_edges[2]),
        )
    out.validate()
    return out


def _moved(points, dy: float) -> np.ndarray:
    """``points`` (``[..., 3]``) moved by ``dy`` along y."""
    out = np.array(points, dtype=np.float64)
    out[..., 1] += dy
    return out
