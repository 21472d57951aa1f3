"""Transmission factors: the paper's A1 / B1 / D1 situations and the five boundary conditions."""

from __future__ import annotations

import numpy as np
import pytest
from test_cells_helpers import build_model, plate, tube_x

from marlcrash.cells import DiscretizationConfig, SensorSpec, discretize
from marlcrash.cells.model import DIRECTIONS
from marlcrash.cells.transmission import Links, orient_x_links, transmission_factors, x_cycles
from marlcrash.vehicle.model import COMPARTMENT

T1, T2, TT = 2e-3, 1e-3, 1.5e-3  # plate strip and tube wall thicknesses [m]
X, Y, YN, Z, ZN = range(5)


def _cfg(depth):
    # 0.1 m uniform cells, only the centre-line plane, a single sensor in the compartment
    return DiscretizationConfig(
        roi_depth=depth,
        target_cell_volume=0.1**3,
        overlaps=[],
        upfront_sensor_x=0.05,
        sensors=[SensorSpec("tunnel", "compartment")],
    )


def _compartment():
    return (COMPARTMENT, "shell", plate([0.3, -0.3, -0.05], [0, 0.6, 0], [0.2, 0, 0.1], 2, 2), 0.01, 2)


def _cell_at(cells, p):
    idx = [int(np.searchsorted(e, v, side="right") - 1) for e, v in zip(cells.grid_edges, p, strict=True)]
    return int(cells.grid_labels[tuple(idx)])


def _links(cells, src, dst=None, d=None):
    m = cells.link_src == src
    if dst is not None:
        m &= cells.link_dst == dst
    if d is not None:
        m &= cells.link_dir == d
    return np.flatnonzero(m)


def check_invariants(cells):
    """Boundary conditions every cell model must satisfy."""
    p = cells.params
    active = ~cells.is_null & ~cells.is_rigid
    f = p[:, 2:]
    np.testing.assert_allclose(f[active].sum(axis=1), 1.0, atol=1e-9)
    assert (f >= 0).all() and (f <= 1 + 1e-12).all()
    assert (p[~active] == 0).all(), "null cells and the compartment carry no parameters"
    assert (f[~cells.feasible] == 0).all(), "infeasible factors are exactly 0"
    assert not cells.feasible[~active].any()
    assert (p[active, :2] > 0).all(), "every cell with material gets positive E_x, E_s"
    # links: no -x direction, none from/to null cells, none owned by the compartment, shares sum to 1
    assert set(np.unique(cells.link_dir).tolist()) <= set(range(len(DIRECTIONS)))
    assert not cells.is_null[cells.link_src].any() and not cells.is_null[cells.link_dst].any()
    assert not cells.is_rigid[cells.link_src].any()
    assert (cells.link_src != cells.link_dst).all()
    g = cells.link_src * 5 + cells.link_dir
    sums = np.bincount(g, weights=cells.link_share, minlength=5 * cells.n_cells)
    np.testing.assert_allclose(sums[np.unique(g)], 1.0, atol=1e-9)
    # x links point rearward: the destination reaches behind the source's front
    x = cells.link_dir == X
    assert (cells.hi[cells.link_dst[x], 0] > cells.lo[cells.link_src[x], 0]).all()
    # every +x voxel face between two non-null cells is a +x link; none runs the other way unless
    # the pair also touches that way round (interlocked shapes)
    lab = cells.grid_labels
    a, b = lab[:-1].ravel(), lab[1:].ravel()
    m = (a != b) & ~cells.is_null[a] & ~cells.is_null[b] & ~cells.is_rigid[a]
    pairs = set(zip(a[m].tolist(), b[m].tolist(), strict=True))
    xl = set(
        zip(
            cells.link_src[x & (cells.link_gap == 0)].tolist(),
            cells.link_dst[x & (cells.link_gap == 0)].tolist(),
            strict=True,
        )
    )
    # cells interleaved along x touch both ways round; their link follows the x centroids instead
    assert pairs <= xl | {(b, a) for a, b in xl}
    turned = {(a, b) for a, b in pairs if (a, b) not in xl}
    assert all(cells.centroid[b, 0] <= cells.centroid[a, 0] for a, b in turned)
    assert np.bincount(x_cycles(cells.link_src[x], cells.link_dst[x], cells.n_cells)).max() == 1, "a +x cycle"
    # the minimum principal share where +x material continuity exists
    A = np.bincount(g, weights=cells.link_material_area, minlength=5 * cells.n_cells).reshape(-1, 5)
    cont = active & (A[:, X] > 0)
    mins = cells.meta["config"]["principal_min_share"]
    assert (f[cont, X] >= mins - 1e-12).all()


def test_d1_lateral_split_follows_material_areas():
    """Cell D between C (-y) and E (+y): f_y / (f_y + f_y') = A_DE / (A_DC + A_DE) (paper Eq. 4, 5).

    Sign convention: f_y points toward +y, so E is D's +y neighbour.
    """
    model = build_model(
        [
            ("panel", "shell", plate([0.0, -0.3, 0.0], [0, 0.35, 0], [0.15, 0, 0], 7, 3), T1, 1),
            ("panel", "shell", plate([0.0, 0.05, 0.0], [0, 0.25, 0], [0.15, 0, 0], 5, 3), T2, 1),
            _compartment(),
        ]
    )
    cells = discretize(model, _cfg(0.1), method="uniform")
    check_invariants(cells)
    d, c, e = (_cell_at(cells, (0.05, y, 0.0)) for y in (0.05, -0.05, 0.15))
    a_de = cells.link_material_area[_links(cells, d, e, Y)].sum()
    a_dc = cells.link_material_area[_links(cells, d, c, YN)].sum()
    # closed form: the boundary at y = 0 (y = 0.1) crosses 0.1 m of the 2 mm (1 mm) strip inside the ROI
    assert a_dc == pytest.approx(0.1 * T1, rel=1e-9)
    assert a_de == pytest.approx(0.1 * T2, rel=1e-9)
    f = cells.params[d, 2:]
    assert f[Y] / (f[Y] + f[YN]) == pytest.approx(a_de / (a_dc + a_de), abs=1e-9)
    assert f[Y] / (f[Y] + f[YN]) == pytest.approx(1 / 3, abs=1e-9)
    # the panel continues rearward across x = roi_depth: f_x is raised to the minimum share
    assert f[X] == pytest.approx(cells.meta["config"]["principal_min_share"], abs=1e-12)
    assert f[Z] == 0 and f[ZN] == 0


def test_a1_no_lateral_material_continuity_gives_zero_lateral_factors():
    """Two separate tubes side by side: the cells touch laterally but no material crosses."""
    model = build_model(
        [
            ("tube_d", "shell", tube_x(0.0, 0.2, 0.01, 0.09, -0.04, 0.04, 8, 3), TT, 1),
            ("tube_e", "shell", tube_x(0.0, 0.2, 0.11, 0.19, -0.04, 0.04, 8, 3), TT, 1),
            _compartment(),
        ]
    )
    cells = discretize(model, _cfg(0.1), method="uniform")
    check_invariants(cells)
    d, e = _cell_at(cells, (0.05, 0.05, 0.0)), _cell_at(cells, (0.05, 0.15, 0.0))
    lat = _links(cells, d, e, Y)
    assert lat.size == 1 and cells.link_contact_area[lat[0]] > 0
    assert cells.link_material_area[lat[0]] == 0.0
    np.testing.assert_allclose(cells.params[d, 2:], [1, 0, 0, 0, 0], atol=1e-12)
    assert cells.feasible[d, Y] and not cells.feasible[d, YN]  # contact on +y, null space on -y


def test_b1_no_reverse_flow_toward_the_cell_ahead():
    """A tube through two cells along x: the rear cell B1 never sends energy to A ahead of it."""
    model = build_model([("rail", "shell", tube_x(0.0, 0.3, 0.01, 0.09, -0.04, 0.04, 12, 3), TT, 1), _compartment()])
    cells = discretize(model, _cfg(0.2), method="uniform")
    check_invariants(cells)
    a, b1 = _cell_at(cells, (0.05, 0.05, 0.0)), _cell_at(cells, (0.15, 0.05, 0.0))
    assert a != b1
    assert _links(cells, b1, a).size == 0, "no link from B1 back to A (-x flow)"
    fwd = _links(cells, a, b1)
    assert fwd.size == 1 and cells.link_dir[fwd[0]] == X
    assert cells.link_material_area[fwd[0]] == pytest.approx(4 * 0.08 * TT, rel=1e-2)
    np.testing.assert_allclose(cells.params[b1, 2:], [1, 0, 0, 0, 0], atol=1e-12)
    np.testing.assert_array_equal(cells.feasible[b1], [True, False, False, False, False])
    rear = _links(cells, b1, cells.compartment, X)
    assert rear.size == 1 and cells.link_material_area[rear[0]] > 0


def test_factor_formula_min_share_and_ratios():
    # one cell, material areas +x 1, +y 3, -y 1 (weights 2, 1, 1): raw 2:3:1 -> f_x 1/3 < 0.6
    links = Links(
        src=np.array([0, 0, 0, 1]),
        dst=np.array([1, 2, 3, 0]),
        dir=np.array([X, Y, YN, X]),
        contact_area=np.array([1.0, 1.0, 1.0, 1.0]),
        material_area=np.array([1.0, 3.0, 1.0, 0.0]),
        gap=np.zeros(4),
    )
    active = np.array([True, True, False, False])
    f, feas, share = transmission_factors(4, links, active, (2.0, 1.0, 1.0), 0.6)
    np.testing.assert_allclose(f[0], [0.6, 0.3, 0.1, 0.0, 0.0], atol=1e-15)
    # cell 1 has only contact (no material anywhere): falls back to contact areas
    np.testing.assert_allclose(f[1], [1.0, 0, 0, 0, 0], atol=1e-15)
    assert (f[2:] == 0).all() and not feas[2:].any()
    np.testing.assert_allclose(share, 1.0)


def test_a_principal_share_that_lets_a_lateral_factor_exceed_f_x_is_refused():
    """Boundary condition 3 (DESIGN 1.3): with +x continuity f_x is higher than laterally. principal_min_share is
    what enforces it, yet any share in [0, 1] was taken: at 0.4 the cell above got f_x 0.4 and f_y 0.45."""
    from marlcrash.cells import DiscretizationConfig
    from marlcrash.config import from_dict
    from marlcrash.errors import ConfigError

    for bad in (0.0, 0.4, 0.5):
        with pytest.raises(ConfigError, match="boundary condition 3") as err:
            from_dict(DiscretizationConfig, {"principal_min_share": bad})
        assert err.value.key == "principal_min_share"
    assert from_dict(DiscretizationConfig, {"principal_min_share": 0.51}).principal_min_share == 0.51


def test_contact_fallback_and_link_shares():
    # no material at all: contact areas 1 (+x) and 1 (+z), equal weights -> 0.5/0.5, then x raised to 0.6;
    # two +x links with contact 1 and 3 share 1:3
    links = Links(
        src=np.array([0, 0, 0]),
        dst=np.array([1, 2, 3]),
        dir=np.array([X, X, Z]),
        contact_area=np.array([1.0, 3.0, 4.0]),
        material_area=np.zeros(3),
        gap=np.array([0.0, 0.05, 0.0]),
    )
    f, _, share = transmission_factors(4, links, np.array([True, False, False, False]), (1.0, 1.0, 1.0), 0.6)
    np.testing.assert_allclose(f[0], [0.6, 0, 0, 0.4, 0], atol=1e-15)
    np.testing.assert_allclose(share, [0.25, 0.75, 1.0])


def _x_links(src, dst, contact, material, gap):
    n = len(src)
    return Links(
        src=np.array(src),
        dst=np.array(dst),
        dir=np.full(n, X),
        contact_area=np.array(contact, dtype=float),
        material_area=np.array(material, dtype=float),
        gap=np.array(gap, dtype=float),
    )


def test_cells_interleaved_along_x_get_one_link_along_their_centroids():
    """Two cells whose voxels interleave along x touch face to face both ways round: the faces alone gave a link
    A -> B and one B -> A, so energy flowed toward -x (DESIGN 1.3, rule 1; 23 such pairs on the LS-OPT small car).
    The pair becomes one link from the cell with the smaller x centroid, with both links' areas and the smaller gap;
    links outside a cycle keep their direction even against the centroids (a member's rear end ahead of a large
    cell's centroid), and lateral pairs stay two-way."""
    x = np.array([0.5, 0.3, 0.9, 0.2, 0.0])
    links = _x_links([0, 1, 0, 2], [1, 0, 2, 3], [1.0, 2.0, 0.5, 0.25], [0.1, 0.2, 0.0, 0.0], [0.0, 0.02, 0.0, 0.01])
    lateral = Links(np.array([0, 1]), np.array([1, 0]), np.array([Y, YN]), np.ones(2), np.ones(2), np.zeros(2))
    both = Links(*(np.concatenate([getattr(links, f), getattr(lateral, f)]) for f in Links.__dataclass_fields__))
    out, turned = orient_x_links(both, x)
    assert turned == 1
    got = {(int(s), int(d), int(k)): (c, m, g) for s, d, k, c, m, g in zip(out.src, out.dst, out.dir,
           out.contact_area, out.material_area, out.gap, strict=True)}  # fmt: skip
    assert got == {
        (1, 0, X): (3.0, pytest.approx(0.3), 0.0),  # 0 -> 1 turned round and merged: x 0.3 < 0.5
        (0, 2, X): (0.5, 0.0, 0.0),
        (2, 3, X): (0.25, 0.0, 0.01),  # against the centroids (0.9 > 0.2) but in no cycle: kept
        (0, 1, Y): (1.0, 1.0, 0.0),
        (1, 0, YN): (1.0, 1.0, 0.0),
    }


def test_a_longer_cycle_of_x_links_is_ordered_along_the_centroids_with_ties_by_index():
    # 0 -> 1 -> 2 -> 0: a cycle of three interleaved cells; 1 and 2 share their centroid
    links = _x_links([0, 1, 2], [1, 2, 0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0])
    out, turned = orient_x_links(links, np.array([0.4, 0.1, 0.1]))
    assert turned == 1  # 0 -> 1 only: 1 -> 2 goes along the tie by index, 2 -> 0 along the centroids
    assert sorted(zip(out.src.tolist(), out.dst.tolist(), strict=True)) == [(1, 0), (1, 2), (2, 0)]
    assert np.bincount(x_cycles(out.src, out.dst, 3)).max() == 1
    same, none = orient_x_links(out, np.array([0.4, 0.1, 0.1]))
    assert none == 0 and same is out


def test_a_cell_model_with_a_cycle_of_x_links_is_refused(default_cells):
    """A model saved before the discretizer turned interleaved cells' links (or one built by hand) with +x links
    both ways round between two cells is refused, naming them, instead of letting energy flow toward -x."""
    import dataclasses

    from marlcrash.errors import ModelError

    c = default_cells
    i = int(np.flatnonzero((c.link_dir == X) & ~c.is_rigid[c.link_dst])[0])
    a, b = int(c.link_src[i]), int(c.link_dst[i])

    def add(v, extra):
        return np.concatenate([v, np.asarray([extra], dtype=v.dtype)])

    bad = dataclasses.replace(
        c,
        link_src=add(c.link_src, b),
        link_dst=add(c.link_dst, a),
        link_dir=add(c.link_dir, X),
        link_contact_area=add(c.link_contact_area, 1e-4),
        link_material_area=add(c.link_material_area, 0.0),
        link_gap=add(c.link_gap, 0.0),
        link_share=add(c.link_share, 0.0),
    )
    with pytest.raises(ModelError, match=rf"the \+x links of cells \[{min(a, b)}, {max(a, b)}\] form a cycle.*-x"):
        bad.validate()
