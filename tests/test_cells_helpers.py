"""Tiny hand-made vehicle models for the cells tests (shell tubes, plates, solid blocks).

Other ``test_cells_*`` files import the builders from here; the tests below check
the builders themselves against closed-form masses.
"""

from __future__ import annotations

import numpy as np
import pytest

from marlcrash.vehicle import shapes
from marlcrash.vehicle.materials import Material, complete_material
from marlcrash.vehicle.model import COMPARTMENT, Part, VehicleModel, empty_float, empty_int

STEEL = complete_material(
    Material(
        1, "steel", "piecewise_linear", 7850.0, 210e9, yield_strength=3e8, ultimate_strength=5e8, poisson_ratio=0.3
    )
)
RIGID = complete_material(Material(2, "rigid", "rigid", 7850.0, 210e9, poisson_ratio=0.3))


def tube_x(x0, x1, y0, y1, z0, z1, n_x=10, n_side=4):
    """Square tube along x, open ends: ``(nodes [N, 3], quads [Q, 4])``."""
    t = np.arange(4 * n_side) / n_side
    s, f = np.floor(t).astype(int), t - np.floor(t)
    c = np.array([[y0, z0], [y1, z0], [y1, z1], [y0, z1], [y0, z0]])
    ring = c[s] + f[:, None] * (c[s + 1] - c[s])
    xs = np.linspace(x0, x1, n_x + 1)
    nodes = np.concatenate([np.column_stack([np.full(len(ring), x), ring]) for x in xs])
    r = len(ring)
    i, j = np.meshgrid(np.arange(n_x), np.arange(r), indexing="ij")
    i, j = i.ravel(), j.ravel()
    j1 = (j + 1) % r
    quads = np.stack([i * r + j, (i + 1) * r + j, (i + 1) * r + j1, i * r + j1], axis=1)
    return nodes, quads


def plate(origin, e1, e2, n1=4, n2=4):
    """Flat plate ``origin + a e1 + b e2`` for a, b in [0, 1]: ``(nodes, quads)``."""
    a, b = np.meshgrid(np.linspace(0, 1, n1 + 1), np.linspace(0, 1, n2 + 1), indexing="ij")
    nodes = np.asarray(origin) + a.ravel()[:, None] * np.asarray(e1) + b.ravel()[:, None] * np.asarray(e2)
    i, j = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    i, j = i.ravel(), j.ravel()
    w = n2 + 1
    quads = np.stack([i * w + j, (i + 1) * w + j, (i + 1) * w + j + 1, i * w + j + 1], axis=1)
    return nodes, quads


def box_shell(lo, hi, n=2):
    """Closed box surface of six plates: ``(nodes, quads)``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    d = hi - lo
    ex, ey, ez = np.diag(d)
    faces = [
        (lo, ey, ex),
        (lo + ez, ex, ey),
        (lo, ex, ez),
        (lo + ey, ez, ex),
        (lo, ez, ey),
        (lo + ex, ey, ez),
    ]
    return _merge([plate(o, a, b, n, n) for o, a, b in faces])


def hex_block(lo, hi, n=(2, 2, 2)):
    """Solid brick block: ``(nodes, hexes [H, 8])`` in LS-DYNA node order, ``n`` elements per axis."""
    return shapes.hex_block(lo, hi, counts=n)


def _merge(meshes):
    nodes, elems, off = [], [], 0
    for nd, el in meshes:
        nodes.append(nd)
        elems.append(el + off)
        off += len(nd)
    return np.concatenate(nodes), np.concatenate(elems)


def build_model(pieces, name="fixture"):
    """Assemble a :class:`VehicleModel`.

    Args:
        pieces: list of ``(subassembly, kind, (nodes, elems), thickness_or_None, material_id)``,
            kind ``"shell"`` or ``"solid"``; each piece becomes one part. The sub-assembly
            :data:`COMPARTMENT` is the rigid compartment.
    """
    coords, shells, shell_part, thick, solids, solid_part = [], [], [], [], [], []
    parts, subs = {}, {}
    off = 0
    for pid, (sub, kind, (nd, el), t, mat) in enumerate(pieces, start=1):
        coords.append(nd)
        if kind == "shell":
            shells.append(el + off)
            shell_part.append(np.full(len(el), pid))
            thick.append(np.full(len(el), t))
        else:
            solids.append(el + off)
            solid_part.append(np.full(len(el), pid))
        off += len(nd)
        parts[pid] = Part(pid, f"{sub}_{pid}", mat, pid, t if kind == "shell" else None)
        subs.setdefault(sub, []).append(pid)
    coords = np.concatenate(coords)
    sn = np.concatenate(shells) if shells else empty_int(0, 4)
    vn = np.concatenate(solids) if solids else empty_int(0, 8)
    model = VehicleModel(
        node_ids=np.arange(1, len(coords) + 1),
        coords=coords,
        shell_ids=np.arange(1, len(sn) + 1),
        shell_part=np.concatenate(shell_part) if shells else empty_int(0),
        shell_nodes=sn,
        shell_thickness=np.concatenate(thick) if shells else empty_float(0),
        solid_ids=np.arange(1, len(vn) + 1),
        solid_part=np.concatenate(solid_part) if solids else empty_int(0),
        solid_nodes=vn,
        beam_ids=empty_int(0),
        beam_part=empty_int(0),
        beam_nodes=empty_int(0, 2),
        beam_area=empty_float(0),
        parts=parts,
        materials={1: STEEL, 2: RIGID},
        subassemblies=subs,
        name=name,
    )
    model.validate()
    return model


def mini_car():
    """A small front: bumper, crash boxes, rails, cooling plate, powertrain block, dash, compartment."""
    t = 1.5e-3
    return build_model(
        [
            ("bumper", "shell", _tube_y(0.0, 0.1, -0.7, 0.7, 0.35, 0.47), 2.0e-3, 1),
            ("crash_box_left", "shell", tube_x(0.1, 0.25, 0.4, 0.5, 0.35, 0.47, 6, 4), t, 1),
            ("crash_box_right", "shell", tube_x(0.1, 0.25, -0.5, -0.4, 0.35, 0.47, 6, 4), t, 1),
            ("rail_left", "shell", tube_x(0.25, 1.35, 0.4, 0.5, 0.33, 0.49, 30, 4), 2.0e-3, 1),
            ("rail_right", "shell", tube_x(0.25, 1.35, -0.5, -0.4, 0.33, 0.49, 30, 4), 2.0e-3, 1),
            ("cooling", "shell", plate([0.15, -0.35, 0.25], [0, 0.7, 0], [0, 0, 0.4], 14, 8), 1.0e-3, 1),
            ("powertrain", "solid", hex_block([0.45, -0.3, 0.25], [0.85, 0.3, 0.65], (6, 8, 6)), None, 1),
            ("dash", "shell", plate([1.1, -0.75, 0.1], [0, 1.5, 0], [0, 0, 0.8], 20, 10), 1.0e-3, 1),
            (COMPARTMENT, "shell", box_shell([1.2, -0.8, 0.05], [3.2, 0.8, 1.3], 4), 0.03, 2),
        ],
        name="mini_car",
    )


def _tube_y(x0, x1, y0, y1, z0, z1):
    """Square tube along y (the bumper beam)."""
    nodes, quads = tube_x(y0, y1, x0, x1, z0, z1, 24, 3)
    return nodes[:, [1, 0, 2]], quads[:, [0, 3, 2, 1]]


def drawn_figures(monkeypatch) -> list:
    """The matplotlib figures saved from now on (``Figure.savefig`` records its figure, then saves as before)."""
    from matplotlib.figure import Figure

    figs, save = [], Figure.savefig

    def recording(fig, *args, **kwargs):
        figs.append(fig)
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recording)
    return figs


def drawn_turn_from_x_to_y(ax) -> float:
    """The turn from the drawn +x axis to the drawn +y axis of 3D ``ax`` seen from above (+z toward the viewer):
    +1 counter-clockwise (a right-handed frame, as matplotlib draws its axes), -1 clockwise (a left-handed one).

    marlcrash's frame (x rearward, y left, z up) is left-handed: drawn as it is, a car seen from above with its
    nose up the page has its left (+y) on the page's left, and x turns clockwise to y. The view is restored.
    """
    from mpl_toolkits.mplot3d import proj3d

    elev, azim = ax.elev, ax.azim
    ax.view_init(elev=89.0, azim=azim)  # from above; 90 exactly leaves the screen's up direction undefined
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    c, d = lims.mean(axis=1), 0.1 * np.abs(lims[:, 1] - lims[:, 0])
    pts = c + np.vstack([np.zeros(3), np.diag(d)[:2]])  # the centre, a step along x, a step along y
    u, v, _ = proj3d.proj_transform(pts[:, 0], pts[:, 1], pts[:, 2], ax.get_proj())
    ax.view_init(elev=elev, azim=azim)
    return float(np.sign((u[1] - u[0]) * (v[2] - v[0]) - (v[1] - v[0]) * (u[2] - u[0])))


def test_tube_mass_matches_closed_form():
    nodes, quads = tube_x(0.0, 0.6, -0.05, 0.05, 0.0, 0.08, 12, 5)
    m = build_model([("rail", "shell", (nodes, quads), 2e-3, 1)])
    expected = 7850.0 * 2 * (0.1 + 0.08) * 0.6 * 2e-3
    assert m.total_mass() == pytest.approx(expected, rel=1e-12)


def test_hex_block_and_box_masses_match_closed_form():
    m = build_model(
        [
            ("block", "solid", hex_block([0, 0, 0], [0.2, 0.3, 0.4], (2, 3, 4)), None, 1),
            ("box", "shell", box_shell([1, 0, 0], [1.5, 0.2, 0.3], 3), 1e-3, 1),
        ]
    )
    pm = m.part_masses()
    assert pm[1] == pytest.approx(7850.0 * 0.2 * 0.3 * 0.4, rel=1e-12)
    assert pm[2] == pytest.approx(7850.0 * 2 * (0.5 * 0.2 + 0.5 * 0.3 + 0.2 * 0.3) * 1e-3, rel=1e-12)
