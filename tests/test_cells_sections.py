"""Material cross-sections from plane cuts against closed-form areas."""

from __future__ import annotations

import numpy as np
import pytest
from test_cells_helpers import build_model, hex_block, tube_x

from marlcrash.cells.grid import build_grid
from marlcrash.cells.sections import grid_sections, section_area


def _tube_model(t=1.8e-3):
    return build_model([("rail", "shell", tube_x(0.0, 0.8, -0.06, 0.04, 0.1, 0.22, 16, 5), t, 1)])


@pytest.mark.parametrize("x", [0.0537, 0.25, 0.5 + 1e-7])
def test_tube_section_is_perimeter_times_thickness(x):
    t = 1.8e-3
    perimeter = 2 * (0.1 + 0.12)
    assert section_area(_tube_model(t), axis=0, position=x) == pytest.approx(perimeter * t, rel=1e-2)


def test_tube_section_at_a_node_ring_counts_once():
    # x = 0.25 is a ring of nodes (0.8 / 16 = 0.05 spacing): on-plane edges must not double count
    t = 1.8e-3
    assert section_area(_tube_model(t), axis=0, position=0.25) == pytest.approx(2 * 0.22 * t, rel=1e-2)


def test_tube_wall_sections_in_y_and_z():
    t = 1.8e-3
    m = _tube_model(t)
    # a plane y = const cuts the top and bottom walls along the full length
    assert section_area(m, axis=1, position=-0.0123) == pytest.approx(2 * 0.8 * t, rel=1e-2)
    assert section_area(m, axis=2, position=0.1777) == pytest.approx(2 * 0.8 * t, rel=1e-2)


def test_solid_block_section_equals_face_area():
    m = build_model([("block", "solid", hex_block([0.0, -0.1, 0.0], [0.3, 0.2, 0.25], (3, 3, 5)), None, 1)])
    assert section_area(m, axis=0, position=0.1234) == pytest.approx(0.3 * 0.25, rel=1e-2)
    assert section_area(m, axis=2, position=0.0777) == pytest.approx(0.3 * 0.3, rel=1e-2)


def test_grid_sections_bin_the_tube_into_its_columns():
    t = 1.8e-3
    m = _tube_model(t)
    grid = build_grid(np.array([0.0, -0.1, 0.08]), np.array([0.8, 0.1, 0.24]), np.array([0.0]), 0.05**3, 4)
    planes = (np.array([5, 17]), np.zeros(0, np.int64), np.zeros(0, np.int64))
    sx, sy, sz = grid_sections(m, grid, planes)
    assert sx.shape == (2, len(grid.edges[1]) - 1, len(grid.edges[2]) - 1)
    assert sx.sum(axis=(1, 2)) == pytest.approx([2 * 0.22 * t] * 2, rel=1e-2)
    # all area lies in columns the tube walls pass through
    yc = 0.5 * (grid.edges[1][1:] + grid.edges[1][:-1])
    outside = (yc < -0.07) | (yc > 0.05)
    assert sx[:, outside, :].sum() == 0.0
    assert sy.shape[0] == 0 and sz.shape[0] == 0


def test_a_point_on_an_outer_face_to_rounding_is_inside_the_grid():
    """``locate(clamp=False)`` decided "inside" without the binning's tolerance: a compartment sample interpolated
    between nodes on the box's outer face fell outside by rounding, and its voxel was left to a null cell."""
    from marlcrash.cells.grid import EDGE_TOL

    grid = build_grid(np.array([0.0, -0.85, 0.0]), np.array([1.2, 0.85, 1.0]), np.array([0.0]), 3e-4, 4)
    on_faces = np.array([[0.6, 0.85 + 2e-16, 0.5], [0.6, -0.85 - 2e-16, 0.5], [1.2 + 1e-15, 0.1, -1e-17]])
    flat, inside = grid.locate(on_faces, clamp=False)
    assert inside.all() and (flat >= 0).all()
    clamped, _ = grid.locate(on_faces, clamp=True)
    np.testing.assert_array_equal(flat, clamped)  # the boundary voxels
    beyond = np.array([[0.6, 0.85 + 10 * EDGE_TOL, 0.5], [-10 * EDGE_TOL, 0.0, 0.5]])
    flat, inside = grid.locate(beyond, clamp=False)
    assert not inside.any() and (flat == -1).all()
