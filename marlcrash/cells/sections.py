"""Material cross-sections at grid planes (DESIGN 1.3 rule 4, paper Eq. 4-5).

The material area crossing a plane is, for shells, the length of the plane's
cut through the shell mid-surface times the shell thickness (trimesh plane
cuts); for solids, the sub-element volume over its extent normal to the plane;
for beams, their section area. Areas are binned into the voxel columns of the
fine grid by the position of each cut piece, giving the material area crossing
each voxel face of a plane: ``[n_planes, n_u, n_v]`` where ``u, v`` are the two
other axes in ``xyz`` order.
"""

from __future__ import annotations

import numpy as np
import trimesh

from marlcrash.cells.grid import FineGrid, _solid_samples, _subdivisions, bin_index
from marlcrash.vehicle.model import VehicleModel

PLANE_NUDGE = 1e-6
"""Offset [m] of every cut plane from its grid edge (lateral planes: away from y = 0), so nodes that sit
exactly on a grid plane (common in generated meshes) never produce degenerate on-plane cuts."""


def _other_axes(axis: int) -> tuple[int, int]:
    return tuple(a for a in range(3) if a != axis)  # type: ignore[return-value]


def _bin(
    out: np.ndarray,
    plane: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    area: np.ndarray,
    eu: np.ndarray,
    ev: np.ndarray,
    mirror: tuple[bool, bool] = (False, False),
) -> None:
    """Add ``area`` at (plane, column of (u, v)) into ``out`` ``[n_planes, nu, nv]``; points outside are dropped.

    ``mirror`` marks which of u, v is the lateral axis (ties fall away from y = 0, see
    :func:`~marlcrash.cells.grid.bin_index`).
    """
    tol = 1e-9  # material lying exactly on the box boundary (a wall on the ROI's top face) belongs to the box
    iu = np.clip(bin_index(eu, u, mirror[0]), 0, len(eu) - 2)
    iv = np.clip(bin_index(ev, v, mirror[1]), 0, len(ev) - 2)
    ok = (u >= eu[0] - tol) & (u <= eu[-1] + tol) & (v >= ev[0] - tol) & (v <= ev[-1] + tol)
    if not ok.any():
        return
    flat = np.ravel_multi_index((plane[ok], iu[ok], iv[ok]), out.shape)
    out += np.bincount(flat, weights=area[ok], minlength=out.size).reshape(out.shape)


def _crossings(cmin: np.ndarray, cmax: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (item, plane) pairs with ``cmin <= plane <= cmax``; ``planes`` sorted."""
    a = np.searchsorted(planes, cmin, side="left")
    b = np.searchsorted(planes, cmax, side="right")
    count = np.maximum(b - a, 0)
    item = np.repeat(np.arange(cmin.shape[0]), count)
    start = np.repeat(np.cumsum(count) - count, count)
    plane = np.repeat(a, count) + (np.arange(item.shape[0]) - start)
    return item, plane


def shell_sections(
    coords: np.ndarray,
    tri: np.ndarray,
    thickness: np.ndarray,
    axis: int,
    planes: np.ndarray,
    eu: np.ndarray,
    ev: np.ndarray,
) -> np.ndarray:
    """Material area of shells crossing each plane, binned by column.

    Each plane is cut with :func:`trimesh.intersections.mesh_plane` through a mesh of
    only the triangles that straddle it (so the cost is the number of crossings, not
    triangles x planes). Cut segments longer than half a column are split so each
    piece is binned where it lies.

    Args:
        coords: ``[N, 3]`` node coordinates [m].
        tri: ``[T, 3]`` triangle node indices.
        thickness: ``[T]`` shell thickness of each triangle [m].
        axis: plane normal axis (0, 1, 2).
        planes: ``[P]`` sorted plane positions along ``axis`` [m].
        eu, ev: column edges [m] along the two other axes (xyz order).

    Returns:
        ``[P, len(eu)-1, len(ev)-1]`` material area [m^2].
    """
    out = np.zeros((len(planes), len(eu) - 1, len(ev) - 1))
    if tri.shape[0] == 0 or len(planes) == 0:
        return out
    u_ax, v_ax = _other_axes(axis)
    c = coords[tri][:, :, axis]
    item, plane = _crossings(c.min(axis=1), c.max(axis=1), planes)
    if item.size == 0:
        return out
    order = np.argsort(plane, kind="stable")
    item, plane = item[order], plane[order]
    bounds = np.flatnonzero(np.diff(plane)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [plane.size]])
    normal = np.zeros(3)
    normal[axis] = 1.0
    seg_all, t_all, p_all = [], [], []
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        faces = tri[item[s:e]]
        mesh = trimesh.Trimesh(
            vertices=coords[faces].reshape(-1, 3),
            faces=np.arange(3 * faces.shape[0]).reshape(-1, 3),
            process=False,
            validate=False,
        )
        origin = np.zeros(3)
        origin[axis] = planes[plane[s]]
        seg, fidx = trimesh.intersections.mesh_plane(mesh, normal, origin, return_faces=True)
        if len(seg):
            seg_all.append(seg)
            t_all.append(thickness[item[s:e]][fidx])
            p_all.append(np.full(len(seg), plane[s]))
    if not seg_all:
        return out
    seg = np.concatenate(seg_all)
    t = np.concatenate(t_all)
    pl = np.concatenate(p_all)
    d = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(d, axis=1)
    rep, t0, t1 = _column_pieces(seg[:, 0, u_ax], seg[:, 1, u_ax], seg[:, 0, v_ax], seg[:, 1, v_ax], eu, ev)
    mid = seg[rep, 0] + (0.5 * (t0 + t1))[:, None] * d[rep]
    _bin(out, pl[rep], mid[:, u_ax], mid[:, v_ax], (length * t)[rep] * (t1 - t0), eu, ev, (u_ax == 1, v_ax == 1))
    return out


def _edge_crossings(a0: np.ndarray, a1: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(segment, t)`` of every point ``a0 + t (a1 - a0)``, ``0 < t < 1``, where a segment crosses an edge."""
    lo, hi = np.minimum(a0, a1), np.maximum(a0, a1)
    first = np.searchsorted(edges, lo, side="right")
    count = np.maximum(np.searchsorted(edges, hi, side="left") - first, 0)
    segment = np.repeat(np.arange(a0.size), count)
    k = np.repeat(first, count) + np.arange(segment.size) - np.repeat(np.cumsum(count) - count, count)
    return segment, (edges[k] - a0[segment]) / (a1[segment] - a0[segment])


def _column_pieces(
    u0: np.ndarray, u1: np.ndarray, v0: np.ndarray, v1: np.ndarray, eu: np.ndarray, ev: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments ``(u0, v0) -> (u1, v1)`` cut where they cross a column edge: ``(segment, t0, t1)`` per piece.

    Each piece lies in one column, so its length goes where it lies exactly. Binning fixed fractions of a
    segment by their midpoints (as before) depended on how a quad was split into triangles: mirror twins,
    whose quads split along mirrored diagonals, got transmission factors up to 100 % apart.
    """
    su, tu = _edge_crossings(u0, u1, eu)
    sv, tv = _edge_crossings(v0, v1, ev)
    n = u0.size
    segment = np.concatenate([np.arange(n), np.arange(n), su, sv])
    t = np.concatenate([np.zeros(n), np.ones(n), tu, tv])
    order = np.lexsort((t, segment))
    segment, t = segment[order], t[order]
    keep = (segment[1:] == segment[:-1]) & (t[1:] > t[:-1])
    return segment[:-1][keep], t[:-1][keep], t[1:][keep]


def solid_subbricks(model: VehicleModel, mask: np.ndarray, pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-bricks of the selected solids, about two per pitch along each edge.

    Returns:
        ``(pos [m, 3], volume [m], extent [m, 3])``: centres [m], volumes [m^3] and
        extents along x, y, z [m] of every sub-brick.
    """
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    p = model.coords[model.solid_nodes[idx]]
    ext_all = p.max(axis=1) - p.min(axis=1)
    k = _subdivisions(ext_all.max(axis=1), pitch, 2, 8)
    vol = model.solid_volumes()[idx]
    pos_l, vol_l, ext_l = [], [], []
    for kk in np.unique(k):
        g = k == kk
        pos, w = _solid_samples(p[g], int(kk))
        pos_l.append(pos.reshape(-1, 3))
        vol_l.append((w * vol[g][:, None]).ravel())
        ext_l.append(np.repeat(ext_all[g] / kk, int(kk) ** 3, axis=0))
    return np.concatenate(pos_l), np.concatenate(vol_l), np.concatenate(ext_l)


def solid_sections(
    bricks: tuple[np.ndarray, np.ndarray, np.ndarray], axis: int, planes: np.ndarray, eu: np.ndarray, ev: np.ndarray
) -> np.ndarray:
    """Material area of solids crossing each plane: sub-brick volume / sub-brick extent.

    A sub-brick (from :func:`solid_subbricks`) whose extent along ``axis`` contains the
    plane contributes ``volume / extent`` at its centre's column.

    Returns:
        ``[P, len(eu)-1, len(ev)-1]`` material area [m^2].
    """
    out = np.zeros((len(planes), len(eu) - 1, len(ev) - 1))
    pos, vol, ext3 = bricks
    if vol.size == 0 or len(planes) == 0:
        return out
    u_ax, v_ax = _other_axes(axis)
    ext = ext3[:, axis]
    ok = ext > 0
    c = pos[:, axis]
    item, plane = _crossings(np.where(ok, c - 0.5 * ext, np.inf), np.where(ok, c + 0.5 * ext, -np.inf), planes)
    if item.size:
        _bin(out, plane, pos[item, u_ax], pos[item, v_ax], vol[item] / ext[item], eu, ev, (u_ax == 1, v_ax == 1))
    return out


def beam_sections(
    model: VehicleModel, mask: np.ndarray, axis: int, planes: np.ndarray, eu: np.ndarray, ev: np.ndarray
) -> np.ndarray:
    """Section area of beams crossing each plane, binned at the crossing point.

    Returns:
        ``[P, len(eu)-1, len(ev)-1]`` material area [m^2].
    """
    out = np.zeros((len(planes), len(eu) - 1, len(ev) - 1))
    idx = np.flatnonzero(mask)
    if idx.size == 0 or len(planes) == 0:
        return out
    u_ax, v_ax = _other_axes(axis)
    p = model.coords[model.beam_nodes[idx]]
    a, b = p[:, 0, axis], p[:, 1, axis]
    item, plane = _crossings(np.minimum(a, b), np.maximum(a, b), planes)
    denom = (b - a)[item]
    ok = np.abs(denom) > 0
    item, plane, denom = item[ok], plane[ok], denom[ok]
    t = (planes[plane] - a[item]) / denom
    x = p[item, 0] + t[:, None] * (p[item, 1] - p[item, 0])
    _bin(out, plane, x[:, u_ax], x[:, v_ax], model.beam_area[idx][item], eu, ev, (u_ax == 1, v_ax == 1))
    return out


def grid_sections(
    model: VehicleModel,
    grid: FineGrid,
    plane_index: tuple[np.ndarray, np.ndarray, np.ndarray],
    shell_mask: np.ndarray | None = None,
    solid_mask: np.ndarray | None = None,
    beam_mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Material area crossing each voxel face of selected grid planes, per axis.

    Args:
        model: the vehicle.
        grid: the fine grid.
        plane_index: per axis, sorted indices into ``grid.edges[axis]`` of the planes to cut.
        shell_mask, solid_mask, beam_mask: elements to include (all if ``None``).

    Returns:
        Per axis ``a``, ``[len(plane_index[a]), n_u, n_v]`` material area [m^2] crossing
        the face of column ``(u, v)`` at that plane (``u, v`` the other axes in xyz order).
    """
    sm = np.ones(model.n_shells, bool) if shell_mask is None else shell_mask
    vm = np.ones(model.n_solids, bool) if solid_mask is None else solid_mask
    bm = np.ones(model.n_beams, bool) if beam_mask is None else beam_mask
    tri, owner = model.shell_triangles(sm)
    thick = model.shell_thickness[owner]
    bricks = solid_subbricks(model, vm, grid.min_pitch())
    out = []
    for axis in range(3):
        u_ax, v_ax = _other_axes(axis)
        eu, ev = grid.edges[u_ax], grid.edges[v_ax]
        planes = grid.edges[axis][plane_index[axis]]
        # lateral planes are nudged away from y = 0, so mirror twins are cut at mirrored positions
        planes = planes + (np.where(planes < 0, -PLANE_NUDGE, PLANE_NUDGE) if axis == 1 else PLANE_NUDGE)
        a = shell_sections(model.coords, tri, thick, axis, planes, eu, ev)
        a += solid_sections(bricks, axis, planes, eu, ev)
        a += beam_sections(model, bm, axis, planes, eu, ev)
        out.append(a)
    return tuple(out)  # type: ignore[return-value]


def section_area(model: VehicleModel, axis: int, position: float, shell_mask: np.ndarray | None = None) -> float:
    """Total material cross-section [m^2] of the model at one plane ``coord[axis] = position``.

    Uses the same cuts as :func:`grid_sections` with a single column spanning the model.
    """
    b = model.bounds()
    u_ax, v_ax = _other_axes(axis)
    eu = np.array([b[0, u_ax] - 1.0, b[1, u_ax] + 1.0])
    ev = np.array([b[0, v_ax] - 1.0, b[1, v_ax] + 1.0])
    planes = np.array([float(position)])
    sm = np.ones(model.n_shells, bool) if shell_mask is None else shell_mask
    tri, owner = model.shell_triangles(sm)
    a = shell_sections(model.coords, tri, model.shell_thickness[owner], axis, planes, eu, ev)
    bricks = solid_subbricks(model, np.ones(model.n_solids, bool), float((b[1] - b[0]).max()) / 8 + 1e-9)
    a += solid_sections(bricks, axis, planes, eu, ev)
    a += beam_sections(model, np.ones(model.n_beams, bool), axis, planes, eu, ev)
    return float(a.sum())
