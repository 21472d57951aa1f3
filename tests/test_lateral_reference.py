"""One lateral reference for section planes, barrier and impact regions, wherever the vehicle sits in y.

A deck read with ``AxisMap(y_center=...)`` off its middle is not centred on y = 0. A barrier covering the fraction
``o`` of the width covers ``o W`` from the struck side's outer edge (as a crash test measures it), so its edge is
``y_left - o W`` or ``y_right + o W``: computed here from the node coordinates alone. The section planes sat about
the box middle while the barrier was measured from y = 0: 3 cm off centre, cells straddled the barrier edges and
the pulse moved by 2 m/s.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_cells_helpers import mini_car

from marlcrash.cells import discretize, load_discretization_config
from marlcrash.envs.agents import AgentsConfig, build_agents
from marlcrash.envs.masking import ImpactRegions, MaskingConfig
from marlcrash.sim.scenario import barrier_mask, get_scenario
from marlcrash.sim.surrogate import Surrogate
from marlcrash.vehicle.model import AxisMap

SHIFT = 0.03  # [m] the off-centre car's box middle sits at y = +SHIFT
OFFSETS = ["offset40_left", "offset40_right", "small_overlap_left", "small_overlap_right"]
TOL = 1e-9  # [m]


@pytest.fixture(scope="module")
def cars():
    car = mini_car()
    off = car.transformed(AxisMap(y_center=-SHIFT))  # the mapped y = -SHIFT becomes 0: the car moves to +y
    lo, hi = off.bounds()[:, 1]
    assert 0.5 * (lo + hi) == pytest.approx(SHIFT, abs=1e-12)  # the premise: off centre
    return car, off


@pytest.fixture(scope="module")
def uniform(cars):
    cfg = load_discretization_config()
    return tuple(discretize(c, cfg, method="uniform") for c in cars)


def _struck_band(model, scenario):
    """``(edge, side)`` of the barrier from the node coordinates: ``overlap * W`` from the struck side's edge."""
    y = model.coords[model.used_nodes(), 1]
    width = y.max() - y.min()
    if scenario.side == "left":
        return y.max() - scenario.overlap * width, 1.0
    return y.min() + scenario.overlap * width, -1.0


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_barrier_edges_of_an_off_centre_car_are_section_planes_and_no_cell_straddles_them(cars, method):
    off = cars[1]
    cells = discretize(off, load_discretization_config(), method=method)
    exposed = (cells.front_area > 0) & ~cells.is_null & ~cells.is_rigid
    for name in OFFSETS:
        sc = get_scenario(name)
        edge, side = _struck_band(off, sc)
        assert np.abs(cells.planes_y - edge).min() < TOL, (name, edge, cells.planes_y)
        a, b = np.sort(side * np.stack([cells.lo[:, 1], cells.hi[:, 1]]), axis=0)  # mirrored: band is y' >= e'
        inside, outside = a >= side * edge - TOL, b <= side * edge + TOL
        assert (inside | outside)[exposed].all(), f"{name}: cells straddle the barrier edge y = {edge:.4f} m"
        mask = barrier_mask(cells, sc)
        np.testing.assert_array_equal(mask, (exposed & inside).astype(float), err_msg=name)
        assert (mask > 0).any()


def test_impact_regions_of_an_off_centre_car_lie_in_the_struck_band(cars, uniform):
    off, cells = cars[1], uniform[1]
    layout = build_agents(cells, AgentsConfig())
    regions = ImpactRegions(cells, layout, MaskingConfig())
    exposed = (cells.front_area > 0) & ~cells.is_null & ~cells.is_rigid
    for name in OFFSETS:
        sc = get_scenario(name)
        edge, side = _struck_band(off, sc)
        t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
        prim = regions.primary(t(sc.overlap), t(sc.side_sign), t(sc.speed))[0].numpy()
        near = np.minimum(side * cells.lo[:, 1], side * cells.hi[:, 1])  # mirrored: the bound nearer the far side
        assert prim.any() and (near[prim] >= side * edge - TOL).all(), name
        assert prim[exposed & (near >= side * edge - TOL)].all(), name  # every struck front cell is primary


@pytest.mark.parametrize("name", ["offset40_left", "small_overlap_right"])
def test_moving_the_car_sideways_changes_neither_the_struck_cells_nor_the_pulse(uniform, name):
    """The same car 3 cm to the left is the same crash: the uniform grid moves with it (same labels), and the
    barrier, the impact regions and the sensor velocities must follow (before: up to 2.0-2.3 m/s apart in 30 ms)."""
    centred, off = uniform
    np.testing.assert_array_equal(centred.grid_labels, off.grid_labels)  # the premise: the same cells
    np.testing.assert_array_equal(centred.sensor_cell, off.sensor_cell)  # sensors placed about the centre line
    np.testing.assert_allclose(off.sensor_position - [0.0, SHIFT, 0.0], centred.sensor_position, rtol=0, atol=1e-12)
    sc = get_scenario(name)
    np.testing.assert_array_equal(barrier_mask(centred, sc), barrier_mask(off, sc))
    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    args = (t(sc.overlap), t(sc.side_sign), t(sc.speed))
    for a, b in zip(*(ImpactRegions(c, build_agents(c, AgentsConfig()), MaskingConfig()).regions(*args)
                      for c in uniform), strict=True):  # fmt: skip
        assert torch.equal(a, b)
    runs = [Surrogate(c).run(torch.as_tensor(c.params)[None], sc, duration=0.03, record_cells="none") for c in uniform]
    torch.testing.assert_close(runs[1].velocity, runs[0].velocity, rtol=0, atol=1e-9)
    assert float(runs[0].crush[0, -1]) > 0.1  # the crash happened


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_left_and_right_agents_split_at_the_centre_line(cars, method):
    """``split_lr`` halves meet at the vehicle's centre line, not at y = 0: 3 cm off centre, a cell wholly right of
    the centre line whose centroid lay in 0 < y < 3 cm joined the left agent (and was struck by a right crash)."""
    cells = discretize(cars[1], load_discretization_config(), method=method)
    split = ["bumper", "cooling", "powertrain", "dash"]  # the sub-assemblies across the centre line
    layout = build_agents(cells, AgentsConfig(split_lr=split))
    centre = 0.5 * (cells.roi_lo[1] + cells.roi_hi[1])
    for name in split:
        for side, sign in (("left", 1.0), ("right", -1.0)):
            k = layout.index(f"{name}_{side}")
            own = layout.cells[k][layout.valid[k]].numpy()
            assert own.size > 0
            # each cell lies wholly on its agent's side of the centre plane (cells never straddle it)
            assert (sign * (cells.centroid[own, 1] - centre) > 0).all(), (name, side)
            assert (np.minimum(sign * (cells.lo[own, 1] - centre), sign * (cells.hi[own, 1] - centre)) >= -TOL).all()


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_the_cells_move_with_the_car(cars, method):
    """Discretization runs in the frame centred on the vehicle's centre line, so a car off y = 0 gets the same cells,
    moved: the grid's mirror rules (ties away from y = 0, bisection mirrored about it) used to act about y = 0, and
    the default car 1 mm sideways got 505 cells instead of 518."""
    from marlcrash.vehicle.registry import load_vehicle

    cfg = load_discretization_config()
    default = load_vehicle("b_segment")
    pairs = [cars] + ([(default, default.transformed(AxisMap(y_center=-0.001)))] if method == "optimized" else [])
    for centred, off in pairs:
        a, b = (discretize(c, cfg, method=method) for c in (centred, off))
        dy = b.centre_y - a.centre_y
        assert abs(dy) > 5e-4  # the premise: moved
        assert b.n_cells == a.n_cells and b.n_links == a.n_links
        np.testing.assert_array_equal(b.link_src, a.link_src)
        np.testing.assert_array_equal(b.link_dst, a.link_dst)
        np.testing.assert_array_equal(b.sensor_cell, a.sensor_cell)
        np.testing.assert_allclose(b.params, a.params, rtol=1e-12, atol=1e-12 * np.abs(a.params).max())
        for field in ("lo", "hi", "centroid", "sensor_position"):
            moved = getattr(b, field) - [0.0, dy, 0.0]
            np.testing.assert_allclose(moved, getattr(a, field), rtol=0, atol=1e-9, err_msg=field)
        np.testing.assert_allclose(b.planes_y - dy, a.planes_y, rtol=0, atol=1e-9)


def test_cells_on_the_centre_line_of_a_car_off_y0_go_to_split_centre():
    """A plate in the centre plane: its cells' centroids lie on the centre line, to the round-off of the car's
    shift (-2.8e-17 m 3 cm off centre, which sent all 36 to the right agent); ``split_centre`` decides."""
    from test_cells_helpers import _tube_y, box_shell, build_model, plate, tube_x

    from marlcrash.envs.agents import _side_mask
    from marlcrash.vehicle.model import COMPARTMENT

    car = build_model([
        ("bumper", "shell", _tube_y(0.0, 0.1, -0.7, 0.7, 0.35, 0.47), 2.0e-3, 1),
        ("rail_left", "shell", tube_x(0.1, 1.35, 0.4, 0.5, 0.33, 0.49, 30, 4), 2.0e-3, 1),
        ("rail_right", "shell", tube_x(0.1, 1.35, -0.5, -0.4, 0.33, 0.49, 30, 4), 2.0e-3, 1),
        ("web", "shell", plate([0.2, 0.0, 0.25], [0.6, 0, 0], [0, 0, 0.3], 12, 6), 3e-3, 1),
        (COMPARTMENT, "shell", box_shell([1.2, -0.8, 0.05], [3.2, 0.8, 1.3], 4), 0.03, 2),
    ], name="webcar")  # fmt: skip
    cfg = load_discretization_config()
    for shift in (0.0, 0.03, -0.37):
        cells = discretize(car.transformed(AxisMap(y_center=-shift)), cfg, method="uniform")
        web = np.flatnonzero(cells.subassembly == cells.subassembly_names.index("web"))
        # the premise: on the line (the plate's material is split into halves 2 nm either side, mirror twins)
        assert np.abs(cells.centroid[web, 1] - cells.centre_y).max() < 3e-9
        for centre in ("left", "right"):
            for side in ("left", "right"):
                took = _side_mask(cells, side, centre)[web]
                assert took.all() if side == centre else not took.any(), (shift, centre, side)
