"""The fine voxel grid over the ROI and the material samples binned into it (DESIGN 1.2).

One grid serves both discretization methods. Along x and z it is uniform; along
y it is built band by band between the section planes, so no voxel (and no
cell made of voxels) straddles a plane. The uniform cell edge is
``h = target_volume ** (1/3)``; each band or axis length ``len`` is divided into
``max(1, round(len / h))`` uniform cells and each uniform cell into
``voxels_per_cell_edge`` voxels per axis, so uniform cells are exact blocks of
fine voxels.

Material is represented by *samples*: every element is subdivided into
``k x k`` (shells), ``k x k x k`` (solids) or ``k`` (beams) sub-elements, ``k``
chosen from the element size relative to the voxel pitch, and each sub-element
carries its exact share of the element's mass and volume. Binning samples into
voxels therefore conserves mass exactly.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from marlcrash.errors import ModelError
from marlcrash.vehicle.model import VehicleModel

KIND_SHELL, KIND_SOLID, KIND_BEAM = 0, 1, 2
"""Element kinds carried by samples."""

EDGE_TOL = 1e-9  # m: a sample point this close to a grid edge is on it (binning decided by geometry, not rounding)

MAX_SAMPLES = 50_000_000
"""Most material samples :func:`sample_elements` makes (the default car takes 1.1 million; this many take gigabytes):
beyond it ``samples_per_pitch`` and ``max_subdivision`` ask for far more than the grid can tell apart."""

MAX_VOXELS = 50_000_000
"""Largest fine grid :func:`build_grid` builds (the default car's has 0.45 million voxels; this one would take
gigabytes): beyond it the ROI is far larger than a vehicle's front end for the cell size, which is what a deck
read in the wrong length unit gives."""


@dataclass
class FineGrid:
    """Fine voxel grid over the ROI box.

    Attributes:
        edges: x, y, z edge positions [m], shapes ``[nx+1]``, ``[ny+1]``, ``[nz+1]``.
        block: per axis, the uniform-cell (block) index of each voxel, ``[nx]``, ``[ny]``, ``[nz]``.
        n_blocks: number of uniform cells along x, y, z.
        band_y: ``[ny]`` index of the y band (between consecutive planes) of each voxel column.
    """

    edges: tuple[np.ndarray, np.ndarray, np.ndarray]
    block: tuple[np.ndarray, np.ndarray, np.ndarray]
    n_blocks: tuple[int, int, int]
    band_y: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(nx, ny, nz)`` voxel counts."""
        return tuple(len(e) - 1 for e in self.edges)  # type: ignore[return-value]

    @property
    def n_voxels(self) -> int:
        return int(np.prod(self.shape))

    @property
    def n_uniform_cells(self) -> int:
        """Number of uniform cells (blocks) of the grid."""
        return int(np.prod(self.n_blocks))

    def widths(self, axis: int) -> np.ndarray:
        """Voxel widths [m] along one axis."""
        return np.diff(self.edges[axis])

    def centers(self, axis: int) -> np.ndarray:
        """Voxel centres [m] along one axis."""
        e = self.edges[axis]
        return 0.5 * (e[1:] + e[:-1])

    def voxel_volume(self) -> np.ndarray:
        """``[nx, ny, nz]`` voxel volumes [m^3]."""
        dx, dy, dz = (self.widths(a) for a in range(3))
        return dx[:, None, None] * dy[None, :, None] * dz[None, None, :]

    def voxel_centers(self, flat: np.ndarray) -> np.ndarray:
        """``[m, 3]`` centres [m] of voxels given by flat (C-order) indices ``[m]``."""
        ix, iy, iz = np.unravel_index(flat, self.shape)
        return np.stack([self.centers(0)[ix], self.centers(1)[iy], self.centers(2)[iz]], axis=1)

    def min_pitch(self) -> float:
        """Smallest voxel width [m] over all axes."""
        return float(min(self.widths(a).min() for a in range(3)))

    def locate(self, points: np.ndarray, clamp: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Voxel of each point.

        Args:
            points: ``[m, 3]`` positions [m].
            clamp: clamp points outside the box onto the nearest boundary voxel.

        Returns:
            ``(flat, inside)``: ``[m]`` flat voxel indices (valid where ``inside`` or clamped)
            and ``[m]`` bool, whether the point lies inside the box (to :data:`EDGE_TOL`, as the binning: a point
            on an outer face to rounding is inside).
        """
        idx = []
        inside = np.ones(points.shape[0], dtype=bool)
        for a in range(3):
            e = self.edges[a]
            i = bin_index(e, points[:, a], mirror=a == 1)
            # the outer faces with the binning's tolerance: the default car's compartment panels lie in the box's
            # outer y faces, their samples (interpolated between nodes on the face) outside it by rounding, on one
            # side more often than the other, and their voxels became 17 null cells (8 left, 9 right), not the
            # compartment's
            inside &= (points[:, a] >= e[0] - EDGE_TOL) & (points[:, a] <= e[-1] + EDGE_TOL)
            i = np.clip(i, 0, len(e) - 2)
            idx.append(i)
        flat = np.ravel_multi_index(tuple(idx), self.shape)
        if not clamp:
            flat = np.where(inside, flat, -1)
        return flat, inside


def bin_index(edges: np.ndarray, values: np.ndarray, mirror: bool = False) -> np.ndarray:
    """Bin of each value in sorted ``edges`` (unclamped: -1 below, ``len(edges)-1`` above).

    A value exactly on an inner edge goes to the bin above it. With ``mirror`` (the
    lateral axis, whose edges are symmetric about y = 0), a negative value on an edge
    goes to the bin below instead, so ties always fall away from the centre plane and
    a mirror-symmetric vehicle gives a mirror-symmetric binning (panels lying exactly
    in a grid plane, like a wheel's flat side, are common in generated meshes).
    """
    if len(edges) > 1 and values.size:
        # a point within EDGE_TOL of an edge is on it: a mirror-symmetric mesh is symmetric only to rounding
        # (2e-16 m on the default car), and a tie decided by that rounding put mirror twins in different bins.
        # Along x and z too: a wall lying in a grid plane (z = 0.35 m, the hand-built car's bumper) had its samples
        # in the voxel layer above or below it by their rounding, alternating along the wall and between twins
        j = np.clip(np.searchsorted(edges, values), 1, len(edges) - 1)
        values = np.where(np.abs(values - edges[j - 1]) <= EDGE_TOL, edges[j - 1], values)
        values = np.where(np.abs(edges[j] - values) <= EDGE_TOL, edges[j], values)
    i = np.searchsorted(edges, values, side="right") - 1
    if mirror:
        neg = values < 0
        i[neg] = np.searchsorted(edges, values[neg], side="left") - 1
    return i


def _band_blocks(bounds: np.ndarray, h: float) -> list[int]:
    """Uniform cells of edge about ``h`` in each band between consecutive ``bounds`` (at least one)."""
    return [max(1, round((c - a) / h)) for a, c in itertools.pairwise(bounds)]


def _axis_edges(bounds: np.ndarray, h: float, voxels_per_edge: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Edges, block index and band index along one axis from band boundaries ``bounds``."""
    edges = [np.array([bounds[0]])]
    block = []
    band = []
    n_blocks = 0
    for b, ((a, c), n) in enumerate(zip(itertools.pairwise(bounds), _band_blocks(bounds, h), strict=True)):
        fine = np.linspace(a, c, n * voxels_per_edge + 1)
        edges.append(fine[1:])
        block.append(n_blocks + np.repeat(np.arange(n), voxels_per_edge))
        band.append(np.full(n * voxels_per_edge, b))
        n_blocks += n
    return np.concatenate(edges), np.concatenate(block), np.concatenate(band), n_blocks


def build_grid(
    lo: np.ndarray, hi: np.ndarray, planes_y: np.ndarray, target_volume: float, voxels_per_edge: int
) -> FineGrid:
    """Build the fine grid over the box ``[lo, hi]`` respecting the y section planes.

    Args:
        lo, hi: ``[3]`` ROI box corners [m].
        planes_y: section plane positions [m] (those strictly inside ``(lo[1], hi[1])`` are used).
        target_volume: uniform cell volume target [m^3].
        voxels_per_edge: fine voxels per uniform cell edge.

    Returns:
        The :class:`FineGrid`.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if not (hi > lo).all():
        raise ModelError(f"ROI box is empty: lo {lo.tolist()} m, hi {hi.tolist()} m")
    h = float(target_volume) ** (1.0 / 3.0)
    inner = np.unique(np.asarray(planes_y, dtype=np.float64))
    inner = inner[(inner > lo[1] + 1e-9) & (inner < hi[1] - 1e-9)]
    bands = [np.array([lo[0], hi[0]]), np.concatenate([[lo[1]], inner, [hi[1]]]), np.array([lo[2], hi[2]])]
    per_axis = [sum(_band_blocks(b, h)) for b in bands]
    n_voxels = float(np.prod(per_axis, dtype=np.float64)) * voxels_per_edge**3
    if n_voxels > MAX_VOXELS:
        raise ModelError(
            f"the region of interest, {' x '.join(f'{x:.4g}' for x in hi - lo)} m, would take "
            f"{' x '.join(map(str, per_axis))} cells of {h:.4g} m ({n_voxels:.3g} voxels, more than {MAX_VOXELS:.0e}); "
            "a vehicle's front end is about 1-2 m: check the deck's length unit (--units) and, in the cells config, "
            f"roi_depth (the box's x length, {hi[0] - lo[0]:.4g} m) and target_cell_volume ({target_volume:.4g} m^3)"
        )
    ex, bx, _, nbx = _axis_edges(np.array([lo[0], hi[0]]), h, voxels_per_edge)
    ey, by, band, nby = _axis_edges(np.concatenate([[lo[1]], inner, [hi[1]]]), h, voxels_per_edge)
    if np.abs(ey + ey[::-1]).max() <= EDGE_TOL and (by[::-1] == by.max() - by).all():
        # symmetric about y = 0 up to linspace's rounding (28 of 105 edges of the default car were not exact
        # negatives): made exact, so the mirror tie rule of bin_index sees mirrored edges
        ey = 0.5 * (ey - ey[::-1])
    ez, bz, _, nbz = _axis_edges(np.array([lo[2], hi[2]]), h, voxels_per_edge)
    return FineGrid(edges=(ex, ey, ez), block=(bx, by, bz), n_blocks=(nbx, nby, nbz), band_y=band)


# --------------------------------------------------------------------------- sampling
@dataclass
class Samples:
    """Material samples (sub-elements) of a set of elements. Shape ``[P]`` per field.

    Attributes:
        pos: ``[P, 3]`` sample positions [m].
        mass: ``[P]`` mass [kg]; per element the samples' masses sum to its mass.
        volume: ``[P]`` material volume [m^3].
        axial_volume: ``[P]`` material volume times the element's axial factor
            (``sqrt(1 - n_x^2)`` for a shell with unit normal ``n``, ``|d_x|`` for a beam
            along unit ``d``, 1 for solids); summed over a cell and divided by its x
            length it is the cell's mean material cross-section normal to x (coarea formula).
        kind: ``[P]`` int8 element kind (:data:`KIND_SHELL`, ...).
        material: ``[P]`` int64 row into the material table.
        subassembly: ``[P]`` int64 sub-assembly index.
        added: ``[P]`` non-structural mass [kg] riding on the sample (the element's share of its part's added
            mass): inertia without material, so it does not weight the cell's material.
    """

    pos: np.ndarray
    mass: np.ndarray
    volume: np.ndarray
    axial_volume: np.ndarray
    kind: np.ndarray
    material: np.ndarray
    subassembly: np.ndarray
    added: np.ndarray

    @property
    def n(self) -> int:
        return int(self.mass.shape[0])

    def select(self, mask: np.ndarray) -> Samples:
        """The samples where ``mask`` is true."""
        return Samples(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))

    @staticmethod
    def concat(parts: list[Samples]) -> Samples:
        """Concatenate sample sets."""
        return Samples(*(np.concatenate([getattr(p, f) for p in parts]) for f in Samples.__dataclass_fields__))


def _lookup(keys: np.ndarray, table_keys: np.ndarray, table_values: np.ndarray) -> np.ndarray:
    """Vectorized dictionary lookup of ``keys`` in sorted ``table_keys``."""
    i = np.searchsorted(table_keys, keys)
    return table_values[np.clip(i, 0, len(table_keys) - 1)]


def _subdivisions(lengths: np.ndarray, pitch: float, samples_per_pitch: int, max_sub: int) -> np.ndarray:
    k = np.ceil(lengths * samples_per_pitch / pitch).astype(np.int64)
    return np.clip(k, 1, max_sub)


def _normalise_weights(w: np.ndarray) -> np.ndarray:
    """Rows of ``w`` scaled to sum to one (equal weights for degenerate rows)."""
    s = w.sum(axis=1, keepdims=True)
    eq = np.full_like(w, 1.0 / w.shape[1])
    return np.where(s > 0, w / np.where(s > 0, s, 1.0), eq)


def _shell_samples(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear sub-quad centres ``[S, k*k, 3]`` and area weights ``[S, k*k]`` of quads ``p`` ``[S, 4, 3]``."""
    t = (np.arange(k) + 0.5) / k
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    n = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=1)  # [k2, 4]
    pos = n @ p  # [k2, 4] @ [S, 4, 3] -> [S, k2, 3]
    du = (1 - v)[None, :, None] * (p[:, 1] - p[:, 0])[:, None] + v[None, :, None] * (p[:, 2] - p[:, 3])[:, None]
    dv = (1 - u)[None, :, None] * (p[:, 3] - p[:, 0])[:, None] + u[None, :, None] * (p[:, 2] - p[:, 1])[:, None]
    w = np.linalg.norm(np.cross(du, dv), axis=2)
    return pos, _normalise_weights(w)


def _triangle_samples(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroids ``[S, k*k, 3]`` of the ``k*k`` congruent sub-triangles of triangles ``p`` ``[S, 3, 3]``, equal weights.

    The set of points does not depend on the order of the vertices, as a collapsed quad's bilinear samples do: the
    mirror twin of a triangle written from another vertex was sampled up to 0.6 mm off the mirror of its samples, so
    the default car's left and right wheels fell into different voxels (uniform cells 0.08 % apart).
    """
    i, j = (a.ravel() for a in np.meshgrid(np.arange(k), np.arange(k), indexing="ij"))
    up, down = i + j <= k - 1, i + j <= k - 2
    b = np.concatenate([i[up] + 1 / 3, i[down] + 2 / 3]) / k  # barycentric weights of vertices 1 and 2
    c = np.concatenate([j[up] + 1 / 3, j[down] + 2 / 3]) / k
    n = np.stack([1 - b - c, b, c], axis=1)  # [k2, 3]
    return n @ p, np.full((p.shape[0], k * k), 1.0 / (k * k))


def _solid_samples(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Trilinear sub-brick centres ``[V, k^3, 3]`` and volume weights of bricks ``p`` ``[V, 8, 3]``."""
    t = (np.arange(k) + 0.5) / k
    r, s, q = (a.ravel() for a in np.meshgrid(t, t, t, indexing="ij"))
    # LS-DYNA brick node order: bottom face 1-2-3-4, top face 5-6-7-8
    sr = np.array([0, 1, 1, 0, 0, 1, 1, 0])
    ss = np.array([0, 0, 1, 1, 0, 0, 1, 1])
    sq = np.array([0, 0, 0, 0, 1, 1, 1, 1])

    def f(a, sa):
        return np.where(sa[None, :] == 1, a[:, None], 1 - a[:, None])  # [m, 8]

    fr, fs, fq = f(r, sr), f(s, ss), f(q, sq)
    n = fr * fs * fq
    dsign = lambda sa: np.where(sa == 1, 1.0, -1.0)[None, :]  # noqa: E731
    dn_r = dsign(sr) * fs * fq
    dn_s = fr * dsign(ss) * fq
    dn_q = fr * fs * dsign(sq)
    pos = n @ p  # [m, 8] @ [V, 8, 3] -> [V, m, 3]
    jr, js, jq = dn_r @ p, dn_s @ p, dn_q @ p
    w = np.abs((jr * np.cross(js, jq)).sum(axis=2))
    return pos, _normalise_weights(w)


def _warn_sparse(name: str, voxel: np.ndarray, max_subdivision: int, groups) -> None:
    """Warn when samples lie farther apart than a voxel along some axis (``voxel``: ``[3]`` smallest voxel width per
    axis [m]; ``groups``: per element kind, ``[E, 3]`` extents along x, y, z of its edges [m], ``[E]`` subdivisions,
    and how many times its cap ``max_subdivision`` is: 2 for solids, capped at half of it)."""
    n = total = 0
    spacing, need = 0.0, max_subdivision
    for extent, k, ratio in groups:
        step = extent / k[:, None]
        sparse = (step > voxel * (1 + 1e-9)).any(axis=1)
        total += k.size
        if sparse.any():
            n += int(sparse.sum())
            spacing = max(spacing, float(step[sparse].max()))
            need = max(need, int(np.ceil(ratio * np.ceil((extent[sparse] / voxel).max() * (1 - 1e-9)))))
    if n:
        warnings.warn(
            f"{name}: {n} of {total} elements in the region of interest are sampled up to {spacing:.3g} m apart, "
            f"farther than a voxel ({', '.join(f'{v:.3g}' for v in voxel)} m along x, y, z): their walls are "
            f"voxelized with gaps, which splits cells and drops links; raise max_subdivision ({max_subdivision}) to "
            f"{need} in the cells config",
            UserWarning,
            stacklevel=4,
        )


def sample_elements(
    model: VehicleModel,
    shell_mask: np.ndarray,
    solid_mask: np.ndarray,
    beam_mask: np.ndarray,
    part_material_row: dict[int, int],
    part_subassembly: dict[int, int],
    pitch: float,
    samples_per_pitch: int = 2,
    max_subdivision: int = 32,
    masses: dict[str, np.ndarray] | None = None,
    added: dict[str, np.ndarray] | None = None,
    voxel: np.ndarray | None = None,
) -> Samples:
    """Sample the selected elements into sub-elements carrying mass, volume and material.

    Elements are grouped by subdivision count ``k`` so each group is one vectorized pass.

    Args:
        model: the vehicle.
        shell_mask, solid_mask, beam_mask: ``[S]``, ``[V]``, ``[B]`` bool selections.
        part_material_row: part id -> row of its material in the caller's material table.
        part_subassembly: part id -> sub-assembly index.
        pitch: smallest voxel pitch [m]; elements are subdivided to ``samples_per_pitch`` per pitch.
        samples_per_pitch: sampling density along an element edge per voxel pitch.
        max_subdivision: cap on ``k``.
        masses: precomputed :meth:`VehicleModel.element_masses` (computed if ``None``).
        added: precomputed :meth:`VehicleModel.element_added_masses` (computed if ``None``).
        voxel: ``[3]`` smallest voxel width along x, y, z [m]: warn (naming ``max_subdivision``) where its cap
            leaves samples farther apart than a voxel, so walls are voxelized with gaps; ``None``: no check.

    Returns:
        The :class:`Samples` of all selected elements.
    """
    em = model.element_masses() if masses is None else masses
    ea = model.element_added_masses() if added is None else added
    pkeys = np.array(sorted(model.parts), dtype=np.int64)
    mat_lut = np.array([part_material_row[int(p)] for p in pkeys], dtype=np.int64)
    sub_lut = np.array([part_subassembly[int(p)] for p in pkeys], dtype=np.int64)
    out: list[Samples] = []

    def emit(pos, w, idx, vol, ax, kind, part):
        m = w.shape[1]
        name = {KIND_SHELL: "shell", KIND_SOLID: "solid", KIND_BEAM: "beam"}[kind]
        mass, add = em[name][idx], ea[name][idx]
        out.append(
            Samples(
                pos=pos.reshape(-1, 3),
                mass=(w * mass[:, None]).ravel(),
                volume=(w * vol[:, None]).ravel(),
                axial_volume=(w * (vol * ax)[:, None]).ravel(),
                kind=np.full(w.size, kind, dtype=np.int8),
                material=np.repeat(_lookup(part, pkeys, mat_lut), m),
                subassembly=np.repeat(_lookup(part, pkeys, sub_lut), m),
                added=(w * add[:, None]).ravel(),
            )
        )

    coords = model.coords
    # subdivisions first: the sample count is known before any sample is made
    s_idx, v_idx, b_idx = np.flatnonzero(shell_mask), np.flatnonzero(solid_mask), np.flatnonzero(beam_mask)
    s_p, v_p, b_p = coords[model.shell_nodes[s_idx]], coords[model.solid_nodes[v_idx]], coords[model.beam_nodes[b_idx]]
    s_edge = np.linalg.norm(s_p - np.roll(s_p, 1, axis=1), axis=2).max(axis=1, initial=0.0)
    s_k = _subdivisions(s_edge, pitch, samples_per_pitch, max_subdivision)
    v_k = _subdivisions((v_p.max(axis=1, initial=-np.inf) - v_p.min(axis=1, initial=np.inf)).max(axis=1, initial=0.0),
                        pitch, samples_per_pitch, max(1, max_subdivision // 2))  # fmt: skip
    b_length = np.linalg.norm(b_p[:, 1] - b_p[:, 0], axis=1)
    b_k = _subdivisions(b_length, pitch, samples_per_pitch, max_subdivision)
    n_samples = float((s_k.astype(np.float64) ** 2).sum() + (v_k.astype(np.float64) ** 3).sum() + b_k.sum())
    if n_samples > MAX_SAMPLES:
        raise ModelError(
            f"sampling the region's {s_idx.size} shells, {v_idx.size} solids and {b_idx.size} beams would take "
            f"{n_samples:.3g} samples, more than {MAX_SAMPLES:.0e} (gigabytes): lower samples_per_pitch "
            f"({samples_per_pitch}) or max_subdivision ({max_subdivision}) of the cells config"
        )
    if voxel is not None:
        s_ext = np.abs(s_p - np.roll(s_p, 1, axis=1)).max(axis=1, initial=0.0)
        v_ext = v_p.max(axis=1, initial=-np.inf) - v_p.min(axis=1, initial=np.inf)
        b_ext = np.abs(b_p[:, 1] - b_p[:, 0])
        _warn_sparse(model.name, voxel, max_subdivision, [(s_ext, s_k, 1), (v_ext, v_k, 2), (b_ext, b_k, 1)])
    # shells
    idx = s_idx
    if idx.size:
        p, k = s_p, s_k
        nrm = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
        nn = np.linalg.norm(nrm, axis=1)
        nx = np.divide(np.abs(nrm[:, 0]), nn, out=np.zeros_like(nn), where=nn > 0)
        ax = np.sqrt(np.clip(1.0 - nx**2, 0.0, 1.0))
        vol = model.shell_areas()[idx] * model.shell_thickness[idx]
        tri = model.shell_nodes[idx, 2] == model.shell_nodes[idx, 3]
        for kk in np.unique(k):
            for is_tri in (False, True):
                g = (k == kk) & (tri == is_tri)
                if g.any():
                    pos, w = _triangle_samples(p[g, :3], int(kk)) if is_tri else _shell_samples(p[g], int(kk))
                    emit(pos, w, idx[g], vol[g], ax[g], KIND_SHELL, model.shell_part[idx[g]])
    # solids
    idx = v_idx
    if idx.size:
        p, k = v_p, v_k
        vol = model.solid_volumes()[idx]
        for kk in np.unique(k):
            g = k == kk
            pos, w = _solid_samples(p[g], int(kk))
            emit(pos, w, idx[g], vol[g], np.ones(int(g.sum())), KIND_SOLID, model.solid_part[idx[g]])
    # beams
    idx = b_idx
    if idx.size:
        p, k, length = b_p, b_k, b_length
        d = p[:, 1] - p[:, 0]
        ax = np.divide(np.abs(d[:, 0]), length, out=np.zeros_like(length), where=length > 0)
        vol = length * model.beam_area[idx]
        for kk in np.unique(k):
            g = k == kk
            t = (np.arange(kk) + 0.5) / kk
            pos = p[g, 0][:, None] + t[None, :, None] * d[g][:, None]
            w = np.full((int(g.sum()), int(kk)), 1.0 / kk)
            emit(pos, w, idx[g], vol[g], ax[g], KIND_BEAM, model.beam_part[idx[g]])
    if not out:
        return Samples(
            np.zeros((0, 3)),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0, np.int8),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0),
        )
    return _split_on_centre_plane(Samples.concat(out))


def _split_on_centre_plane(s: Samples) -> Samples:
    """Samples on the centre plane y = 0 (within :data:`EDGE_TOL`) split into two halves, one either side.

    A mirror-symmetric mesh with an odd number of elements across the centre line, subdivided an odd number of times,
    has sample centres on the plane; binned, every one of them went to the left (+y) voxel, and the left cells of a
    symmetric tube weighed 3 % more than the right ones. Each half sits ``2 EDGE_TOL`` off the plane.
    """
    on = np.flatnonzero(np.abs(s.pos[:, 1]) <= EDGE_TOL)
    if on.size == 0:
        return s
    right = s.select(on)
    for f in ("mass", "volume", "axial_volume", "added"):
        getattr(right, f)[:] *= 0.5
        getattr(s, f)[on] *= 0.5
    s.pos[on, 1] = 2 * EDGE_TOL
    right.pos[:, 1] = -2 * EDGE_TOL
    return Samples.concat([s, right])
