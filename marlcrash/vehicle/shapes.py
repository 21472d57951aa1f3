"""Structured mesh primitives for the synthetic vehicle, built with numpy (no per-element loops).

Every primitive returns ``(coords, elements)``: ``coords [N, 3]`` node positions [m] and
``elements [E, 4]`` shell quads (a triangle repeats its third node, ``n4 == n3``) or
``[E, 8]`` hexahedra in LS-DYNA node order. Node indices are local to the primitive.
Closed shells are oriented with outward normals (right-hand rule over ``n1 n2 n3``), so
:mod:`trimesh` sees them as watertight, winding-consistent volumes.

Tubes and cylinders are built in a local frame ``(u, v, w)``: ``u`` along the axis,
the section in ``(v, w)``. The local frame maps onto the global one by a cyclic
permutation, which keeps it right-handed: axis ``x``: ``(u, v, w) = (x, y, z)``;
axis ``y``: ``(y, z, x)``; axis ``z``: ``(z, x, y)``.
"""

from __future__ import annotations

import math

import numpy as np

_CYCLIC = {"x": (0, 1, 2), "y": (1, 2, 0), "z": (2, 0, 1)}
"""Global axis index of local (u, v, w) for each tube axis."""

MERGE_TOLERANCE = 1e-7
"""Nodes closer than this [m] (on a grid of this pitch) are merged by :func:`merge_nodes`."""


def divisions(length: float, size: float) -> int:
    """Number of elements along ``length`` [m] so that none is longer than ``size`` [m] (at least 1)."""
    return max(1, math.ceil(length / size - 1e-9))


def _to_global(local: np.ndarray, axis: str, origin: np.ndarray) -> np.ndarray:
    """Map ``[N, 3]`` local ``(u, v, w)`` coordinates to global ones and translate by ``origin``."""
    out = np.empty_like(local)
    out[:, list(_CYCLIC[axis])] = local
    return out + np.asarray(origin, dtype=np.float64)


def grid_quads(n1: int, n2: int, periodic1: bool = False) -> np.ndarray:
    """Quads of a structured grid of ``(n1 + 1) x (n2 + 1)`` nodes (``n1 x (n2 + 1)`` if periodic).

    Node ``(i, j)`` has index ``i * (n2 + 1) + j``. Quad ``(i, j)`` is
    ``(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)``: its normal is ``d/di x d/dj``.

    Returns:
        ``[n1 * n2, 4]`` int64 node indices.
    """
    rows = n1 if periodic1 else n1 + 1
    gi, gj = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    i, j = gi.ravel(), gj.ravel()
    i1 = (i + 1) % rows
    m = n2 + 1
    return np.stack([i * m + j, i1 * m + j, i1 * m + j + 1, i * m + j + 1], axis=1).astype(np.int64)


def plate(origin, e1, e2, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat quad grid over the parallelogram ``origin + s e1 + t e2``, ``s, t`` in [0, 1].

    Args:
        origin: ``[3]`` corner [m].
        e1, e2: ``[3]`` edge vectors [m]; the quads' normal is ``e1 x e2``.
        size: largest element edge [m].

    Returns:
        ``coords [N, 3]``, ``quads [Q, 4]``.
    """
    origin, e1, e2 = (np.asarray(a, dtype=np.float64) for a in (origin, e1, e2))
    n1 = divisions(float(np.linalg.norm(e1)), size)
    n2 = divisions(float(np.linalg.norm(e2)), size)
    s = np.linspace(0.0, 1.0, n1 + 1)
    t = np.linspace(0.0, 1.0, n2 + 1)
    coords = origin + s[:, None, None] * e1 + t[None, :, None] * e2
    return coords.reshape(-1, 3), grid_quads(n1, n2)


def _rect_perimeter(width: float, height: float, size: float) -> np.ndarray:
    """Counter-clockwise points ``[P, 2]`` around a centred ``width x height`` rectangle.

    Starts at the corner ``(-width/2, -height/2)``; the sides are divided as :func:`plate`
    divides them, so caps built with :func:`plate` share the tube's edge nodes.
    """
    nw, nh = divisions(width, size), divisions(height, size)
    a, b = 0.5 * width, 0.5 * height
    sw = np.linspace(-a, a, nw + 1)[:-1]
    sh = np.linspace(-b, b, nh + 1)[:-1]
    bottom = np.stack([sw, np.full(nw, -b)], axis=1)
    right = np.stack([np.full(nh, a), sh], axis=1)
    top = np.stack([-sw, np.full(nw, b)], axis=1)
    left = np.stack([np.full(nh, -a), -sh], axis=1)
    return np.concatenate([bottom, right, top, left])


def rect_tube(
    start,
    axis: str,
    length: float,
    width: float,
    height: float,
    size: float,
    cap_start: bool = False,
    cap_end: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """A thin-walled rectangular tube (closed box section), optionally capped.

    The section is centred on the axis line through ``start``; ``width`` is measured along
    local ``v`` and ``height`` along local ``w`` (axis ``x``: width along y, height along z;
    axis ``y``: width along z, height along x; axis ``z``: width along x, height along y).

    Args:
        start: ``[3]`` centre of the section at the tube's start [m].
        axis: ``"x"``, ``"y"`` or ``"z"``; the tube runs toward the positive axis.
        length, width, height: tube length and section outer dimensions [m].
        size: largest element edge [m].
        cap_start, cap_end: close the start / end section with a plate.

    Returns:
        ``coords [N, 3]``, ``quads [Q, 4]``, outward normals.
    """
    perim = _rect_perimeter(width, height, size)
    nu = divisions(length, size)
    u = np.linspace(0.0, length, nu + 1)
    n_p = perim.shape[0]
    # node (p, j): perimeter point p at axial station j; quads' normal is d/dp x d/du, outward
    local = np.empty((n_p, nu + 1, 3))
    local[:, :, 0] = u[None, :]
    local[:, :, 1] = perim[:, 0, None]
    local[:, :, 2] = perim[:, 1, None]
    coords = [local.reshape(-1, 3)]
    quads = [grid_quads(n_p, nu, periodic1=True)]
    offset = coords[0].shape[0]
    a, b = 0.5 * width, 0.5 * height
    for cap, at, sign in ((cap_start, 0.0, -1.0), (cap_end, length, 1.0)):
        if not cap:
            continue
        ev, ew = np.array([0.0, 2 * a, 0.0]), np.array([0.0, 0.0, 2 * b])
        # normal ev x ew points to +u; swap for the start cap so it points to -u
        e1, e2 = (ev, ew) if sign > 0 else (ew, ev)
        c, q = plate([at, -a, -b], e1, e2, size)
        coords.append(c)
        quads.append(q + offset)
        offset += c.shape[0]
    out_c = _to_global(np.concatenate(coords), axis, start)
    out_q = np.concatenate(quads)
    if cap_start or cap_end:
        out_c, out_q = merge_nodes(out_c, out_q)
    return out_c, out_q


def closed_box(lo, hi, size: float) -> tuple[np.ndarray, np.ndarray]:
    """The six faces of the axis-aligned box ``[lo, hi]`` as one watertight quad shell.

    Returns:
        ``coords [N, 3]``, ``quads [Q, 4]``, outward normals.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    ext = hi - lo
    start = np.array([lo[0], 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])])
    return rect_tube(start, "x", ext[0], ext[1], ext[2], size, cap_start=True, cap_end=True)


def hex_block(lo, hi, size: float | None = None, counts=None) -> tuple[np.ndarray, np.ndarray]:
    """A structured block of 8-node hexahedra filling the box ``[lo, hi]``.

    Node order per hex is LS-DYNA's: bottom face ``n1..n4`` counter-clockwise seen from +z,
    top face ``n5..n8`` above them (positive Jacobian).

    Args:
        lo, hi: ``[3]`` box corners [m].
        size: largest element edge [m]; or
        counts: ``(nx, ny, nz)`` elements per axis.

    Returns:
        ``coords [N, 3]``, ``hexes [H, 8]``.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if counts is not None:
        n = [int(c) for c in counts]
    elif size is not None:
        n = [divisions(float(hi[k] - lo[k]), size) for k in range(3)]
    else:
        raise ValueError("hex_block needs size (largest element edge [m]) or counts (nx, ny, nz); got neither")
    axes = [np.linspace(lo[k], hi[k], n[k] + 1) for k in range(3)]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    coords = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(m) for m in n), indexing="ij"))
    ny, nz = n[1] + 1, n[2] + 1

    def idx(di: int, dj: int, dk: int) -> np.ndarray:
        return ((i + di) * ny + (j + dj)) * nz + (k + dk)

    hexes = np.stack(
        [
            idx(0, 0, 0),
            idx(1, 0, 0),
            idx(1, 1, 0),
            idx(0, 1, 0),
            idx(0, 0, 1),
            idx(1, 0, 1),
            idx(1, 1, 1),
            idx(0, 1, 1),
        ],
        axis=1,
    )
    return coords, hexes.astype(np.int64)


def wheel(center, radius: float, width: float, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder about the y axis (tread band and two side discs), watertight.

    Args:
        center: ``[3]`` wheel centre [m].
        radius: outer radius [m]; width: extent along y [m]; size: largest element edge [m].

    Returns:
        ``coords [N, 3]``, ``quads [Q, 4]`` (centre triangles as ``n4 == n3``), outward normals.
    """
    n_t = max(12, math.ceil(2 * math.pi * radius / size - 1e-9))
    n_r = divisions(radius, size)
    n_u = divisions(width, size)
    theta = 2 * math.pi * np.arange(n_t) / n_t
    ring = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # [n_t, 2] in local (v, w)
    half = 0.5 * width
    # tread: periodic in theta, along u; d/dtheta x d/du points outward for a CCW ring
    u = np.linspace(-half, half, n_u + 1)
    tread = np.empty((n_t, n_u + 1, 3))
    tread[:, :, 0] = u[None, :]
    tread[:, :, 1:] = radius * ring[:, None, :]
    coords = [tread.reshape(-1, 3)]
    quads = [grid_quads(n_t, n_u, periodic1=True)]
    offset = coords[0].shape[0]
    radii = radius * np.arange(1, n_r + 1) / n_r  # ring k = 1..n_r (index k-1)
    for at, sign in ((-half, -1.0), (half, 1.0)):
        # node (t, k): angle t, radius radii[k]; quad (t, k) over rings k, k+1: d/dt x d/dk = -u
        disc = np.empty((n_t, n_r, 3))
        disc[:, :, 0] = at
        disc[:, :, 1:] = radii[None, :, None] * ring[:, None, :]
        q = grid_quads(n_t, n_r - 1, periodic1=True) if n_r > 1 else np.zeros((0, 4), np.int64)
        t = np.arange(n_t)
        centre = n_t * n_r
        tri = np.stack([np.full(n_t, centre), t * n_r, ((t + 1) % n_t) * n_r], axis=1)  # normal +u
        if sign < 0:
            tri = np.stack([tri[:, 0], tri[:, 2], tri[:, 1], tri[:, 1]], axis=1)
        else:
            q = q[:, ::-1]
            tri = np.stack([tri[:, 0], tri[:, 1], tri[:, 2], tri[:, 2]], axis=1)
        c = np.concatenate([disc.reshape(-1, 3), [[at, 0.0, 0.0]]])
        coords.append(c)
        quads.append(np.concatenate([q, tri]) + offset)
        offset += c.shape[0]
    out_c = _to_global(np.concatenate(coords), "y", center)
    return merge_nodes(out_c, np.concatenate(quads))


def merge_nodes(
    coords: np.ndarray, elements: np.ndarray, tol: float = MERGE_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Merge coincident nodes (equal on a grid of pitch ``tol``) and drop unused ones.

    Args:
        coords: ``[N, 3]`` node positions [m].
        elements: ``[E, k]`` node indices.
        tol: merge pitch [m].

    Returns:
        ``coords [N', 3]`` (first occurrence kept, in order of first use) and re-indexed elements.
    """
    key = np.rint(coords / tol).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    # renumber in order of first occurrence so the result does not depend on sort order of keys
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    new_elems = rank[inv[elements]]
    return coords[first[order]], new_elems
