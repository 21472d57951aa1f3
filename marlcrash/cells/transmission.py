"""Links between cells and the initial transmission factors (DESIGN 1.3).

Links come from the voxel label array: every pair of face-adjacent voxels with
different cell labels contributes its face area to the link ``src -> dst`` in
the direction from ``src`` to ``dst``. Along x only the rearward link exists
(energy never flows toward -x; the link is owned by the upstream cell); a
lateral or vertical pair gives one link each way. Null cells get no links, the
rigid compartment owns none. Where a cell's rear face borders null space, a
*gap link* joins it to the next non-null cell along +x in that voxel column
(``gap`` = null distance to close). A virtual voxel layer of the compartment
sits behind the ROI, so rear cells link +x into the compartment.

Cells whose voxels interleave along x (a sub-assembly's voxels at x = 1 and 3 of a
column, another's at 2) meet face to face both ways, so the voxel faces alone gave
a link ``A -> B`` and one ``B -> A``, or a longer cycle of +x links (23 pairs and a
cycle of 18 cells on the LS-OPT small car; energy then flowed forward, against
rule 1 below). :func:`orient_x_links` orders the cells of every such cycle by their
x centroid: each +x link inside one points from the cell with the smaller centroid
to the larger, and a pair's two links become one with both contact and material
areas. The +x links then form no cycle (:meth:`CellModel.validate` refuses one).

Transmission factors, per non-null, non-rigid cell, with ``A_d`` the material
area and ``C_d`` the contact area summed over the cell's links in direction
``d`` (the five boundary conditions of DESIGN 1.3):

1. no -x direction exists;
2. null cells have no links, so no factor points at them;
3. with +x continuity ``f_x >= principal_min_share``: material continuity (``A_x > 0``) or
   contact (a touching or gap link): a cell whose material does not continue rearward (a
   panel facing x, a member ending on the dash) still pushes on its rear neighbour in
   compression, and x stays the principal direction of force. Without this, such cells
   got ``f_x = 0`` and the load paths ended in mid-air (rails on the dash, dash on the
   compartment, powertrain on the dash);
4. ``f_d`` is proportional to ``w_d A_d`` (``w`` = x, lateral, vertical weights),
   so within a lateral pair ``f_y : f_y' = A_+y : A_-y`` (likewise z). Sign
   convention: ``f_y`` points toward +y, so for a cell D between C (at -y) and
   E (at +y), ``f_y / (f_y + f_y') = A_DE / (A_DC + A_DE)`` (paper Eq. 4, 5);
5. the five sum to one: ``f = w A / sum(w A)``, then, if ``f_x`` is below the
   minimum share, ``f_x`` is raised to it and the others are rescaled by
   ``(1 - min_share) / (1 - f_x)``, which keeps their ratios.

A cell with no material continuity in any direction uses contact areas
(gap links included) instead of ``A`` (the minimum x share then applies if it
has +x contact); a cell with no link at all gets ``f_x = 1`` (load goes
rearward by contact). ``feasible`` marks directions with at least one link;
other factors are exactly 0. ``link_share`` splits a (src, direction) factor
over its links in proportion to material area (contact area if that is zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from marlcrash.cells.grid import FineGrid

DIR_X, DIR_PY, DIR_NY, DIR_PZ, DIR_NZ = range(5)


@dataclass
class Faces:
    """Directed voxel faces between two cells, one row per face (``[F]`` per field).

    Attributes:
        src, dst: cell labels (``src`` upstream).
        dir: direction index (:data:`marlcrash.cells.model.DIRECTIONS`).
        axis: normal axis of the face's plane, 0..2.
        plane: index into ``grid.edges[axis]`` of the face's plane, or -1 for gap faces.
        iu, iv: column of the face along the two other axes.
        area: face (contact) area [m^2].
        gap: null-space distance along x before contact [m] (0 for touching faces).
    """

    src: np.ndarray
    dst: np.ndarray
    dir: np.ndarray
    axis: np.ndarray
    plane: np.ndarray
    iu: np.ndarray
    iv: np.ndarray
    area: np.ndarray
    gap: np.ndarray

    @staticmethod
    def concat(parts: list[Faces]) -> Faces:
        return Faces(*(np.concatenate([getattr(p, f) for p in parts]) for f in Faces.__dataclass_fields__))

    def needed_planes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per axis, the sorted plane indices where material areas are needed."""
        ok = self.plane >= 0
        return tuple(np.unique(self.plane[ok & (self.axis == a)]) for a in range(3))  # type: ignore[return-value]


def _faces(src, dst, d, axis, plane, iu, iv, area, gap=None) -> Faces:
    n = src.shape[0]
    return Faces(
        src=src.astype(np.int64),
        dst=dst.astype(np.int64),
        dir=np.full(n, d, np.int64),
        axis=np.full(n, axis, np.int64),
        plane=plane.astype(np.int64),
        iu=iu.astype(np.int64),
        iv=iv.astype(np.int64),
        area=area,
        gap=np.zeros(n) if gap is None else gap,
    )


def extract_faces(
    labels: np.ndarray, grid: FineGrid, is_null: np.ndarray, compartment: int
) -> tuple[Faces, np.ndarray]:
    """All directed faces between different cells, gap faces and the front area.

    Args:
        labels: ``[nx, ny, nz]`` cell index per voxel.
        grid: the fine grid.
        is_null: ``[n]`` bool, null cells.
        compartment: index of the rigid compartment cell.

    Returns:
        ``(faces, front_area)``: the :class:`Faces` and ``[n]`` front area [m^2], the face
        area of every voxel column given to the first non-null cell along +x in it (the
        compartment where the column is empty).
    """
    n = is_null.shape[0]
    nx, ny, nz = labels.shape
    dx, dy, dz = (grid.widths(a) for a in range(3))
    nonnull = ~is_null
    owner = nonnull.copy()
    owner[compartment] = False  # the compartment owns no links
    padded = np.concatenate([labels, np.full((1, ny, nz), compartment, labels.dtype)], axis=0)
    parts = []
    # +x between touching voxels (the last plane joins the virtual compartment layer)
    a, b = padded[:-1], padded[1:]
    m = (a != b) & owner[a] & nonnull[b]
    i, j, k = np.nonzero(m)
    parts.append(_faces(a[m], b[m], DIR_X, 0, i + 1, j, k, dy[j] * dz[k]))
    # lateral and vertical pairs: one link each way
    for axis, (d_pos, d_neg) in ((1, (DIR_PY, DIR_NY)), (2, (DIR_PZ, DIR_NZ))):
        sl_a = [slice(None)] * 3
        sl_b = [slice(None)] * 3
        sl_a[axis] = slice(None, -1)
        sl_b[axis] = slice(1, None)
        a, b = labels[tuple(sl_a)], labels[tuple(sl_b)]
        m = (a != b) & nonnull[a] & nonnull[b]
        i, j, k = np.nonzero(m)
        if axis == 1:
            area, plane, iu, iv = dx[i] * dz[k], j + 1, i, k
        else:
            area, plane, iu, iv = dx[i] * dy[j], k + 1, i, j
        fa = m & owner[a]
        fb = m & owner[b]
        ma, mb = fa[m], fb[m]
        parts.append(_faces(a[fa], b[fa], d_pos, axis, plane[ma], iu[ma], iv[ma], area[ma]))
        parts.append(_faces(b[fb], a[fb], d_neg, axis, plane[mb], iu[mb], iv[mb], area[mb]))
    # gap faces: next non-null voxel along +x after a run of null voxels
    big = nx + 1
    pos = np.where(nonnull[padded], np.arange(nx + 1)[:, None, None], big)
    nxt = np.minimum.accumulate(pos[::-1], axis=0)[::-1]  # [nx+1, ny, nz] first non-null index >= i
    v = padded[:-1]
    after = padded[1:]
    m = owner[v] & is_null[after]
    i, j, k = np.nonzero(m)
    t = nxt[i + 1, j, k]
    dst = padded[t, j, k]
    gap = grid.edges[0][t] - grid.edges[0][i + 1]
    keep = dst != v[m]
    parts.append(
        _faces(
            v[m][keep],
            dst[keep],
            DIR_X,
            0,
            np.full(int(keep.sum()), -1),
            j[keep],
            k[keep],
            (dy[j] * dz[k])[keep],
            gap[keep],
        )
    )
    _, front = front_voxels(labels, is_null)
    front = np.where(front >= 0, front, compartment)
    front_area = np.bincount(front.ravel(), weights=(dy[:, None] * dz[None, :]).ravel(), minlength=n)
    return Faces.concat(parts), front_area


def front_voxels(labels: np.ndarray, is_null: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The voxel a rigid wall at the front meets first in each voxel column.

    Args:
        labels: ``[nx, ny, nz]`` cell index per voxel (-1 outside cells).
        is_null: ``[n]`` bool, null cells.

    Returns:
        ``(first, cell)``, each ``[ny, nz]``: the x index of the column's first voxel of a non-null cell
        (``nx`` where the column has none) and that cell (-1 where none).
    """
    nx = labels.shape[0]
    solid = (labels >= 0) & ~is_null[np.maximum(labels, 0)]
    first = np.where(solid.any(axis=0), solid.argmax(axis=0), nx)
    j, k = np.indices(first.shape)
    cell = np.where(first < nx, labels[np.minimum(first, nx - 1), j, k], -1)
    return first, cell


@dataclass
class Links:
    """Aggregated links, one per (src, dst, direction), ``[L]`` per field."""

    src: np.ndarray
    dst: np.ndarray
    dir: np.ndarray
    contact_area: np.ndarray
    material_area: np.ndarray
    gap: np.ndarray


def aggregate_links(
    faces: Faces, sections: tuple[np.ndarray, np.ndarray, np.ndarray], planes: tuple[np.ndarray, ...], n: int
) -> Links:
    """Sum face areas into links.

    Args:
        faces: the directed faces.
        sections: per axis ``[len(planes[a]), n_u, n_v]`` material area crossing each face [m^2]
            (from :func:`marlcrash.cells.sections.grid_sections`).
        planes: per axis, the plane indices ``sections`` was computed at.
        n: number of cells.

    Returns:
        The :class:`Links`, sorted by (src, dst, direction). A link's gap is the smallest
        gap of its faces (contact starts when the nearest face closes), 0 if any face touches.
    """
    mat = np.zeros(faces.src.shape[0])
    for a in range(3):
        sel = (faces.axis == a) & (faces.plane >= 0)
        if sel.any():
            p = np.searchsorted(planes[a], faces.plane[sel])
            mat[sel] = sections[a][p, faces.iu[sel], faces.iv[sel]]
    return _summed(faces.src, faces.dst, faces.dir, faces.area, mat, faces.gap, n)


def _summed(src, dst, d, contact, material, gap, n: int) -> Links:
    """One link per (src, dst, direction) of the rows given: areas summed, the smallest gap; sorted by that key."""
    key = (src * n + dst) * 5 + d
    uk, inv = np.unique(key, return_inverse=True)
    least = np.full(uk.size, np.inf)
    np.minimum.at(least, inv, gap)
    return Links(
        src=uk // 5 // n,
        dst=(uk // 5) % n,
        dir=uk % 5,
        contact_area=np.bincount(inv, weights=contact, minlength=uk.size),
        material_area=np.bincount(inv, weights=material, minlength=uk.size),
        gap=least,
    )


def x_cycles(src: np.ndarray, dst: np.ndarray, n: int) -> np.ndarray:
    """``[n]`` label of each cell's strongly connected set under the +x links ``src -> dst``; two cells share a
    label exactly when +x links lead from each to the other (a cycle), every other cell has its own."""
    graph = coo_matrix((np.ones(src.size), (src, dst)), shape=(n, n))
    return connected_components(graph, directed=True, connection="strong")[1]


def orient_x_links(links: Links, x: np.ndarray) -> tuple[Links, int]:
    """Orient the +x links inside every cycle along the cells' x centroids (module doc).

    Args:
        links: the aggregated links (:func:`aggregate_links`).
        x: ``[n]`` x centroid of every cell [m]; ties go to the lower cell index.

    Returns:
        ``(links, n_flipped)``: the links (sorted and aggregated as :func:`aggregate_links` gives them; the input
        itself where no cycle exists) and how many were turned round.
    """
    n = x.shape[0]
    ax = links.dir == DIR_X
    s, d = links.src[ax], links.dst[ax]
    group = x_cycles(s, d, n)
    rank = np.empty(n, dtype=np.int64)
    rank[np.lexsort((np.arange(n), x))] = np.arange(n)
    flip = np.zeros(links.src.shape[0], dtype=bool)
    flip[ax] = (group[s] == group[d]) & (rank[s] > rank[d])
    if not flip.any():
        return links, 0
    src = np.where(flip, links.dst, links.src)
    dst = np.where(flip, links.src, links.dst)
    out = _summed(src, dst, links.dir, links.contact_area, links.material_area, links.gap, n)
    return out, int(flip.sum())


def transmission_factors(
    n: int,
    links: Links,
    active: np.ndarray,
    weights: tuple[float, float, float],
    principal_min_share: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Initial transmission factors, feasibility mask and link shares (rules in the module doc).

    Args:
        n: number of cells.
        links: the cell links.
        active: ``[n]`` bool, non-null non-rigid cells (all others get zeros).
        weights: ``(w_x, w_lateral, w_vertical)``.
        principal_min_share: least ``f_x`` of a cell with a +x link (material continuity or contact, rule 3).

    Returns:
        ``(factors [n, 5], feasible [n, 5], link_share [L])``.
    """
    w = np.array([weights[0], weights[1], weights[1], weights[2], weights[2]], dtype=np.float64)
    g = links.src * 5 + links.dir
    A = np.bincount(g, weights=links.material_area, minlength=5 * n).reshape(n, 5)
    C = np.bincount(g, weights=links.contact_area, minlength=5 * n).reshape(n, 5)
    count = np.bincount(g, minlength=5 * n).reshape(n, 5)
    has_mat = A.sum(axis=1) > 0
    basis = np.where(has_mat[:, None], A, C)
    raw = basis * w[None, :]
    tot = raw.sum(axis=1, keepdims=True)
    lone = np.zeros((n, 5))
    lone[:, DIR_X] = 1.0
    f = np.where(tot > 0, raw / np.where(tot > 0, tot, 1.0), lone)
    # Rule 3 on material *or contact* continuity: where material does not continue rearward (a panel
    # facing x, a part ending on the dash, a gap link across empty space), the cell still pushes on its
    # rear neighbour in compression, and x stays the principal direction of force.
    raise_x = (count[:, DIR_X] > 0) & (f[:, DIR_X] < principal_min_share)
    rest = 1.0 - f[:, DIR_X]
    scale = np.where(raise_x, (1.0 - principal_min_share) / np.where(rest > 0, rest, 1.0), 1.0)
    f = f * scale[:, None]
    f[:, DIR_X] = np.where(raise_x, principal_min_share, f[:, DIR_X])
    feasible = (count > 0) | ((tot == 0) & (np.arange(5) == DIR_X)[None, :])
    f = np.where(active[:, None], f, 0.0)
    feasible &= active[:, None]
    f = np.where(feasible, f, 0.0)
    # link shares within each (src, direction)
    gm = np.bincount(g, weights=links.material_area, minlength=5 * n)
    gc = np.bincount(g, weights=links.contact_area, minlength=5 * n)
    use_mat = gm[g] > 0
    num = np.where(use_mat, links.material_area, links.contact_area)
    den = np.where(use_mat, gm[g], gc[g])
    share = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return f, feasible, share
