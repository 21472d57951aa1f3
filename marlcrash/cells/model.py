"""The cell model: what a batched simulator needs, as arrays (DESIGN 1.2, 1.3).

A :class:`CellModel` is the output of discretization and the only input the
surrogate needs. Cells are indexed ``0 .. n_cells-1``; the last cell is the rigid
passenger compartment (``is_rigid``). Null cells (ROI space enveloped by no
sub-assembly) are kept as rows with ``is_null`` set: they have no mass, no
parameters and no links.

Connectivity is a list of directed links ``src -> dst`` owned by the upstream
cell ``src``, one per (src, dst, direction). Directions are indexed by
:data:`DIRECTIONS`; energy never flows toward -x, so there is no -x direction.
A link with ``gap > 0`` joins two cells separated along x by null space: it
carries load only once the gap has closed (e.g. powertrain onto the dash).

The seven parameters per cell (paper Eq. 7), in :data:`PARAM_NAMES` order:

- ``E_x`` [J]: elastic energy the cell stores at crush onset along x; with the
  crush force it sets the cell's elastic stiffness ``k = F_c^2 / (2 E_x)``.
- ``E_s`` [J]: saturation energy, the most the cell can absorb by crushing;
  once absorbed, the cell bottoms out and transmits all further load.
- ``f_x, f_y, f_y', f_z, f_z'`` [-]: transmission factors to the +x, +y, -y,
  +z and -z neighbours; zero where transfer is impossible, summing to one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from marlcrash.errors import ModelError
from marlcrash.outputs import atomic_output

PARAM_NAMES: tuple[str, ...] = ("E_x", "E_s", "f_x", "f_y", "f_yn", "f_z", "f_zn")
"""The seven cell parameters; ``f_yn``/``f_zn`` are the paper's ``f_y'``/``f_z'``."""
PARAM_UNITS: tuple[str, ...] = ("J", "J", "-", "-", "-", "-", "-")
N_PARAMS = 7
BEHAVIOUR = slice(0, 2)
"""Slice of the behaviour parameters ``E_x, E_s`` in the 7-vector."""
TRANSMISSION = slice(2, 7)
"""Slice of the five transmission factors in the 7-vector."""

DIRECTIONS: tuple[str, ...] = ("+x", "+y", "-y", "+z", "-z")
"""Link directions, aligned with the transmission factors."""
DIRECTION_VECTORS = np.array([[1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)

FORMAT_VERSION = 2
"""2: per-cell ``stroke`` (version 1 files took 0.7 of ``crush_length`` for every cell)."""


@dataclass
class CellModel:
    """A discretized vehicle front, ready for simulation. SI units throughout.

    Shapes: ``n`` cells (the compartment included), ``L`` links, ``K`` sensors,
    ``A`` sub-assemblies.

    Attributes:
        lo, hi: ``[n, 3]`` axis-aligned bounding box of each cell [m].
        centroid: ``[n, 3]`` mass centroid (geometric centre for massless cells) [m].
        volume: ``[n]`` enveloped volume [m^3].
        mass: ``[n]`` mass [kg]; the compartment carries everything outside the ROI.
        material: ``[n, 8]`` mass-weighted aggregate material 8-vector (SI).
        params: ``[n, 7]`` initial parameters (:data:`PARAM_NAMES`).
        feasible: ``[n, 5]`` bool, where a transmission factor may be non-zero.
        subassembly: ``[n]`` int64 index into ``subassembly_names`` (-1 for null cells).
        is_null, is_sensor, is_rigid: ``[n]`` bool flags.
        front_area: ``[n]`` projected area [m^2] the cell exposes to a rigid wall
            at the front (non-zero only for cells the barrier plane meets first).
        crush_length: ``[n]`` length [m] of the cell along x.
        stroke: ``[n]`` crushable stroke [m]: ``crush_length`` less the compacted material
            (:mod:`marlcrash.cells.params`); the simulator's crush force is ``E_s / stroke``.
        link_src, link_dst: ``[L]`` int64 cell indices (``src`` upstream).
        link_dir: ``[L]`` int64 index into :data:`DIRECTIONS`.
        link_contact_area: ``[L]`` shared face area between the two cells [m^2].
        link_material_area: ``[L]`` material cross-section at the shared boundary [m^2]
            (zero where there is no material continuity).
        link_gap: ``[L]`` null-space gap [m] along x that must close before contact.
        link_share: ``[L]`` share of the source's direction factor carried by this
            link; shares of one (src, direction) sum to one.
        sensor_names: ``[K]`` names; ``sensor_cell``: ``[K]`` cell index;
            ``sensor_position``: ``[K, 3]`` [m].
        subassembly_names: ``[A]`` names.
        method: ``uniform`` or ``optimized``.
        target_cell_volume: [m^3].
        roi_depth: crop depth [m]; ``roi_lo``, ``roi_hi``: ``[3]`` ROI box [m].
        planes_y: sorted y positions of the section planes [m].
        vehicle_width: lateral extent of the vehicle [m] (overlaps are fractions of it, measured from the struck
            side's outer edge ``centre_y +- vehicle_width / 2``; :attr:`centre_y`).
        roi_mass: mass of the elements inside the ROI [kg], their added mass included (compartment parts
            excluded; point masses on nodes not counted).
        total_mass: vehicle mass [kg].
        grid_edges: x, y, z edges of the fine voxel grid [m] (for plots and masks).
        grid_labels: ``[nx, ny, nz]`` int64 cell index per voxel, -1 outside cells.
        name: model name; ``meta``: free JSON-serialisable notes (warnings, config).
    """

    lo: np.ndarray
    hi: np.ndarray
    centroid: np.ndarray
    volume: np.ndarray
    mass: np.ndarray
    material: np.ndarray
    params: np.ndarray
    feasible: np.ndarray
    subassembly: np.ndarray
    is_null: np.ndarray
    is_sensor: np.ndarray
    is_rigid: np.ndarray
    front_area: np.ndarray
    crush_length: np.ndarray
    stroke: np.ndarray
    link_src: np.ndarray
    link_dst: np.ndarray
    link_dir: np.ndarray
    link_contact_area: np.ndarray
    link_material_area: np.ndarray
    link_gap: np.ndarray
    link_share: np.ndarray
    sensor_names: list[str]
    sensor_cell: np.ndarray
    sensor_position: np.ndarray
    subassembly_names: list[str]
    method: str
    target_cell_volume: float
    roi_depth: float
    roi_lo: np.ndarray
    roi_hi: np.ndarray
    planes_y: np.ndarray
    vehicle_width: float
    roi_mass: float
    total_mass: float
    grid_edges: tuple[np.ndarray, np.ndarray, np.ndarray]
    grid_labels: np.ndarray
    name: str = "vehicle"
    meta: dict = field(default_factory=dict)

    # ----------------------------------------------------------- properties
    @property
    def n_cells(self) -> int:
        return int(self.mass.shape[0])

    @property
    def n_links(self) -> int:
        return int(self.link_src.shape[0])

    @property
    def n_null(self) -> int:
        return int(self.is_null.sum())

    @property
    def n_active(self) -> int:
        """Number of non-null, non-rigid cells (the ones with parameters to tune)."""
        return int((~self.is_null & ~self.is_rigid).sum())

    @property
    def compartment(self) -> int:
        """Index of the rigid compartment cell."""
        return int(np.flatnonzero(self.is_rigid)[0])

    @property
    def centre_y(self) -> float:
        """The vehicle's centre line ``y0`` [m]: the middle of the ROI box, which spans the vehicle's width.

        Not ``y = 0`` for a model read with an ``AxisMap.y_center`` off its middle: the section planes and the
        barrier edges (:func:`marlcrash.cells.roi.barrier_edge`) are measured from it.
        """
        return float(0.5 * (self.roi_lo[1] + self.roi_hi[1]))

    @property
    def front_x(self) -> np.ndarray:
        """``[n]`` x [m] where a rigid wall at the front first meets each cell: the front face of its foremost voxel
        among the voxel columns it exposes (:attr:`front_area`); ``lo[:, 0]`` for a cell that exposes none.

        Not the bounding box front: a cell of a sloping panel (the hood) has its foremost voxel in a column another
        cell covers, and the wall met it there up to 8 cm before it reached the cell's material.
        """
        from marlcrash.cells.transmission import front_voxels

        out = self.lo[:, 0].astype(np.float64, copy=True)
        if not self.grid_labels.size:
            return out
        first, cell = front_voxels(self.grid_labels, self.is_null)
        hit = cell >= 0
        at = np.full(self.n_cells, np.inf)
        np.minimum.at(at, cell[hit], self.grid_edges[0][first[hit]])
        return np.where(np.isfinite(at), at, out)

    @property
    def roi_volume(self) -> float:
        """Volume of the ROI box [m^3]."""
        return float(np.prod(self.roi_hi - self.roi_lo))

    def cells_of(self, subassembly: str) -> np.ndarray:
        """Indices of the cells of one sub-assembly."""
        try:
            k = self.subassembly_names.index(subassembly)
        except ValueError:
            raise ModelError(f"unknown sub-assembly {subassembly!r}; known: {self.subassembly_names}") from None
        return np.flatnonzero(self.subassembly == k)

    # ----------------------------------------------------------- validation
    def validate(self) -> None:
        """Check shapes and invariants; raise :class:`ModelError` on the first violation."""
        n = self.n_cells
        for f in ("lo", "hi", "centroid", "material", "params", "feasible"):
            a = getattr(self, f)
            width = {"lo": 3, "hi": 3, "centroid": 3, "material": 8, "params": N_PARAMS, "feasible": 5}[f]
            if a.shape != (n, width):
                raise ModelError(f"CellModel.{f} must be [{n}, {width}], got {list(a.shape)}")
        for f in (
            "volume", "mass", "subassembly", "is_null", "is_sensor", "is_rigid", "front_area", "crush_length", "stroke"
        ):  # fmt: skip
            if getattr(self, f).shape != (n,):
                raise ModelError(f"CellModel.{f} must be [{n}], got {list(getattr(self, f).shape)}")
        L = self.n_links
        for f in ("link_dst", "link_dir", "link_contact_area", "link_material_area", "link_gap", "link_share"):
            if getattr(self, f).shape != (L,):
                raise ModelError(f"CellModel.{f} must be [{L}], got {list(getattr(self, f).shape)}")
        if int(self.is_rigid.sum()) != 1:
            raise ModelError(f"CellModel needs exactly one rigid compartment cell, got {int(self.is_rigid.sum())}")
        for f in (
            "mass", "params", "material", "lo", "hi", "centroid", "crush_length", "stroke", "link_gap", "link_share"
        ):  # fmt: skip
            if not np.isfinite(getattr(self, f)).all():
                raise ModelError(f"CellModel.{f} contains non-finite values")
        for f in ("link_share", "link_gap", "front_area", "stroke"):  # a negative share made every output NaN
            a = getattr(self, f)
            if (a < 0).any():
                bad = int(np.flatnonzero(a < 0)[0])
                raise ModelError(f"CellModel.{f} must be >= 0, got {a[bad]:g} at {bad}")
        self._validate_parameters()
        longer = self.stroke > self.crush_length * (1.0 + 1e-12)
        if longer.any():
            bad = int(np.flatnonzero(longer)[0])
            raise ModelError(
                f"CellModel.stroke must be at most the cell's crush_length, got {self.stroke[bad]:g} m > "
                f"{self.crush_length[bad]:g} m at {bad}"
            )
        if L and (
            min(self.link_src.min(), self.link_dst.min()) < 0 or max(self.link_src.max(), self.link_dst.max()) >= n
        ):
            raise ModelError("CellModel links refer to cells outside 0..n_cells-1")
        self._validate_x_order()
        self._validate_references()

    def _validate_x_order(self) -> None:
        """Energy never flows toward -x (DESIGN 1.3, rule 1): no cycle of +x links, a pair of cells linked +x both
        ways included (what the discretizer gave interleaved cells before it turned their links along the x
        centroids)."""
        from marlcrash.cells.transmission import DIR_X, x_cycles

        ax = self.link_dir == DIR_X
        group = x_cycles(self.link_src[ax], self.link_dst[ax], self.n_cells)
        size = np.bincount(group)
        if (size > 1).any():
            cells = np.flatnonzero(group == int(np.argmax(size > 1)))
            raise ModelError(
                f"CellModel: the +x links of cells {cells.tolist()[:12]}{' ...' if cells.size > 12 else ''} form a "
                f"cycle, so energy would flow toward -x (DESIGN 1.3, rule 1); rebuild the model from its deck "
                f"(`marlcrash discretize DECK --save CELLS.npz`), which turns such links along the cells' x centroids"
            )

    def _validate_parameters(self) -> None:
        """The boundary conditions of the module docstring, naming the cell: energies >= 0; a null cell
        without mass or parameters, the compartment without parameters; transmission factors >= 0, 0 where transfer
        is impossible (``feasible``), summing to one on every cell with material (a model saved with factors summing
        to 3 or an infeasible factor loaded and simulated without a word; the simulator's shares are f / max f)."""
        neg = np.argwhere(self.params < 0)  # a negative mass: the surrogate names it (with the mass floor's rule)
        if neg.size:
            c, k = (int(v) for v in neg[0])
            raise ModelError(f"CellModel.params must be >= 0, got {PARAM_NAMES[k]} {self.params[c, k]:g} at cell {c}")
        active = ~self.is_null & ~self.is_rigid
        carries = np.flatnonzero(~active & (self.params != 0).any(axis=1))
        if carries.size:
            c = int(carries[0])
            raise ModelError(f"cell {c} is {'null' if self.is_null[c] else 'the rigid compartment'}, so has no "
                             f"parameters; got {self.params[c].tolist()}")  # fmt: skip
        heavy = np.flatnonzero(self.is_null & (self.mass != 0))
        if heavy.size:
            raise ModelError(f"cell {int(heavy[0])} is null, so has no mass; got {self.mass[heavy[0]]:g} kg")
        f = self.params[:, TRANSMISSION]
        off = np.argwhere(~self.feasible & (f != 0))
        if off.size:
            c, d = (int(v) for v in off[0])
            raise ModelError(f"cell {c}: transmission factor {PARAM_NAMES[2 + d]} must be 0 where transfer "
                             f"{DIRECTIONS[d]} is impossible (feasible), got {f[c, d]:g}")  # fmt: skip
        total = f.sum(axis=1)
        bad = np.flatnonzero(active & (np.abs(total - 1.0) > 1e-6))
        if bad.size:
            c = int(bad[0])
            raise ModelError(f"cell {c}: transmission factors must sum to 1, got {total[c]:.9g} ({f[c].tolist()})")

    def _validate_references(self) -> None:
        """Sensors, sub-assembly indices and voxel labels refer to cells and names that exist."""
        n = self.n_cells
        k = len(self.sensor_names)
        if self.sensor_cell.shape != (k,) or self.sensor_position.shape != (k, 3):
            what = "sensor_cell" if self.sensor_cell.shape != (k,) else "sensor_position"
            raise ModelError(
                f"CellModel.{what} must be [{k}{']' if what == 'sensor_cell' else ', 3]'} for the {k} sensor_names "
                f"{list(self.sensor_names)}, got {list(getattr(self, what).shape)}"
            )
        bad = [(nm, int(c)) for nm, c in zip(self.sensor_names, self.sensor_cell, strict=True) if not 0 <= c < n]
        if bad:
            raise ModelError(
                f"CellModel.sensor_cell: sensor {bad[0][0]!r} refers to cell {bad[0][1]}, not in 0..{n - 1}"
            )
        on_null = [(nm, int(c)) for nm, c in zip(self.sensor_names, self.sensor_cell, strict=True) if self.is_null[c]]
        if on_null:
            raise ModelError(
                f"CellModel.sensor_cell: sensor {on_null[0][0]!r} is in null cell {on_null[0][1]}, which has no mass"
            )
        a = len(self.subassembly_names)
        if self.subassembly.size and (self.subassembly.min() < -1 or self.subassembly.max() >= a):
            raise ModelError(f"CellModel.subassembly must index subassembly_names (0..{a - 1}) or be -1 for null cells")
        shape = tuple(len(e) - 1 for e in self.grid_edges)
        if self.grid_labels.shape != shape:
            raise ModelError(
                f"CellModel.grid_labels must be {list(shape)} (the voxels of grid_edges), "
                f"got {list(self.grid_labels.shape)}"
            )
        if self.grid_labels.size and (self.grid_labels.min() < -1 or self.grid_labels.max() >= n):
            raise ModelError(f"CellModel.grid_labels must be cell indices 0..{n - 1} or -1")

    # ----------------------------------------------------------- save / load
    def save(self, path: str | Path) -> None:
        """Write to a ``.npz`` file: arrays plus a JSON header, no pickled objects."""
        arrays: dict[str, np.ndarray] = {}
        header: dict = {"format_version": FORMAT_VERSION}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "grid_edges":
                for axis, e in zip("xyz", v, strict=True):
                    arrays[f"grid_edges_{axis}"] = np.asarray(e)
            elif isinstance(v, np.ndarray):
                arrays[f.name] = v
            else:
                header[f.name] = v
        arrays["__header__"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
        path = Path(path)
        with atomic_output(path) as tmp, open(tmp, "wb") as fh:
            # numpy's stub types **kwds as its allow_pickle: bool keyword; these are arrays saved under their names
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]

    @classmethod
    def load(cls, path: str | Path) -> CellModel:
        """Read a file written by :meth:`save` (``allow_pickle=False``)."""
        from marlcrash.outputs import read_npz

        path = Path(path)
        try:
            arrays = read_npz(path)
        except ValueError as e:  # in words: empty, not an archive, damaged, objects (never numpy's pickle advice)
            raise ModelError(f"{path}: not a readable CellModel file ({e})") from None
        if "__header__" not in arrays:
            raise ModelError(f"{path}: not a CellModel file (no header)")
        try:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
            header = json.loads(arrays.pop("__header__").tobytes().decode())
        except ValueError as e:
            raise ModelError(f"{path}: not a CellModel file (its header is not JSON text: {e})") from None
        if not isinstance(header, dict):
            raise ModelError(f"{path}: not a CellModel file (its header is not a JSON object)")
        version = header.pop("format_version", None)
        if version == 1:
            raise ModelError(
                f"{path}: CellModel format version 1, written before cells had their own stroke (the simulator then "
                f"gave solid cells 1/7 of their crush force); rebuild it from the deck with "
                f"`marlcrash discretize DECK --save CELLS.npz`"
            )
        if version != FORMAT_VERSION:
            raise ModelError(
                f"{path}: unsupported CellModel format version {version!r} (this marlcrash reads {FORMAT_VERSION})"
            )
        kwargs = dict(header)
        edges = [f"grid_edges_{a}" for a in "xyz"]
        if all(e in arrays for e in edges):
            kwargs["grid_edges"] = tuple(arrays.pop(e) for e in edges)
        kwargs.update(arrays)
        names = {f.name for f in fields(cls)}
        missing = names - set(kwargs)
        if missing:  # the grid edges named by the members that hold them
            listed = sorted(missing - {"grid_edges"})
            if "grid_edges" in missing:
                listed += [e for e in edges if e not in arrays]
            raise ModelError(f"{path}: CellModel file lacks {sorted(listed)}")
        out = cls(**{k: v for k, v in kwargs.items() if k in names})
        out.validate()
        return out
