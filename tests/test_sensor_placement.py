"""Sensor placement: a sensor snaps to material on its own side of the centre line, within sensor_snap_distance, and
two sensors never share a deformable cell.

Before, a sensor snapped to the nearest voxel with material anywhere: the LS-OPT small car's default up-front left
sensor landed 0.51 m away, right of the centre line, without a word; two sensors snapped to one voxel shared a cell
silently (uniform), or the second took a one-voxel cell out of the first's, or discretization died with an
IndexError (optimized).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_cells_helpers import box_shell, build_model, tube_x

from marlcrash.cells import DiscretizationConfig, SensorSpec, discretize, load_discretization_config
from marlcrash.config import from_dict
from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.model import COMPARTMENT

METHODS = ["optimized", "uniform"]
Z0, Z1 = 0.35, 0.47  # [m] height of every front tube: the ROI's z range, so the up-front sensors sit at z = 0.41
WIDTH = 1.6  # [m] the compartment's width, the widest part
VOXEL = 0.02  # [m] a little more than the voxel pitch (1/60 m): a snapped voxel centre lies within it of the tube


def _car(left_inner: bool = False, left_rail: bool = True):
    """A lopsided front: a right rail, a tube just right of the centre line, a short left rail starting 0.9 m back
    (0.7 m from the default up-front left position) and, with ``left_inner``, a tube just left of the centre line."""
    pieces = [
        ("rail_right", "shell", tube_x(0.0, 1.2, -0.60, -0.40, Z0, Z1, 24, 3), 2e-3, 1),
        ("centre_right", "shell", tube_x(0.0, 1.2, -0.10, -0.02, Z0, Z1, 24, 3), 2e-3, 1),
        (COMPARTMENT, "shell", box_shell([1.2, -0.5 * WIDTH, 0.05], [3.2, 0.5 * WIDTH, 1.3], 4), 0.03, 2),
    ]
    if left_rail:
        pieces.insert(2, ("rail_left", "shell", tube_x(0.9, 1.2, 0.40, 0.50, Z0, Z1, 6, 3), 2e-3, 1))
    if left_inner:
        pieces.insert(2, ("centre_left", "shell", tube_x(0.0, 1.2, 0.06, 0.14, Z0, Z1, 24, 3), 2e-3, 1))
    return build_model(pieces, name="lopsided")


@pytest.fixture(scope="module")
def cfg():
    return load_discretization_config()


@pytest.mark.parametrize("method", METHODS)
def test_a_sensor_with_no_material_near_it_on_its_side_is_refused_naming_it(cfg, method):
    """upfront_left is asked for at (upfront_sensor_x, 0.3 W, mid-height) = (0.2, 0.48, 0.41) m; the nearest material
    left of the centre line is the short left rail 0.7 m away, the nearest anywhere the tube right of the centre line
    (where it used to go)."""
    req = f"[{cfg.upfront_sensor_x:.3f}, {cfg.upfront_sensor_y_fraction * WIDTH:.3f}, {0.5 * (Z0 + Z1):.3f}]"
    with pytest.raises(ModelError) as e:
        discretize(_car(), cfg, method=method)
    msg = str(e.value)
    assert msg.startswith("sensor 'upfront_left': no material within sensor_snap_distance = 0.15 m"), msg
    assert f"requested position {req} m left of the centre line y = 0.000 m" in msg, msg
    nearest = np.array([float(v) for v in msg.split("the nearest is at [")[1].split("]")[0].split(",")])
    assert nearest[0] > 0.9 and 0.4 - VOXEL < nearest[1] < 0.5 + VOXEL, msg  # on the left rail
    assert "sensors[0].position" in msg and "sensor_snap_distance" in msg


@pytest.mark.parametrize("method", METHODS)
def test_a_sensor_just_left_of_the_centre_line_stays_left_of_it(cfg, method):
    """The tube right of the centre line is nearer (3-4 cm) than the one left of it (5-6 cm): it took the sensor."""
    near = dataclasses.replace(
        cfg, sensors=[SensorSpec("s", "position", [0.3, 0.01, 0.41]), SensorSpec("t", "compartment")]
    )
    cells = discretize(_car(left_inner=True), near, method=method)
    s = cells.sensor_position[0]
    assert 0.06 - VOXEL < s[1] < 0.14 + VOXEL  # the tube left of the centre line
    assert np.linalg.norm(s - [0.3, 0.01, 0.41]) < 0.07
    assert cells.subassembly_names[cells.subassembly[cells.sensor_cell[0]]] == "centre_left"


@pytest.mark.parametrize("method", METHODS)
def test_up_front_sensors_in_reach_snap_on_their_own_side(cfg, method):
    far = dataclasses.replace(cfg, sensor_snap_distance=1.0)  # the left rail is in reach
    cells = discretize(_car(), far, method=method)
    left, right = cells.sensor_position[:2]
    assert left[0] > 0.9 and 0.4 - VOXEL < left[1] < 0.5 + VOXEL  # the left rail, not the tube right of the centre
    assert -0.6 - VOXEL < right[1] < -0.4 + VOXEL  # the right rail
    assert np.linalg.norm(left - [0.2, 0.48, 0.41]) == pytest.approx(0.7, abs=0.03)


def test_no_material_at_all_on_a_sensors_side_is_refused(cfg):
    right_only = _car(left_rail=False)
    with pytest.raises(ModelError, match=r"sensor 'upfront_left': no material left of the centre line y = 0\.000 m "
                                         r"to place it on \(requested \[0\.200, 0\.480, 0\.410\] m\)"):  # fmt: skip
        discretize(right_only, dataclasses.replace(cfg, sensor_snap_distance=10.0))


@pytest.mark.parametrize("method", METHODS)
def test_two_sensors_in_one_deformable_cell_are_refused_naming_both(cfg, method):
    car = _car(left_inner=True)
    twins = [SensorSpec("a", "position", [0.3, 0.1, 0.41]), SensorSpec("b", "position", [0.3, 0.1, 0.41])]
    said = r"sensors 'a' and 'b' land in one (voxel|cell) at \[0\.\d+, 0\.\d+, 0\.\d+\] m "
    said += r"\(requested \[0\.300, 0\.100, 0\.410\] and \[0\.300, 0\.100, 0\.410\] m\): they would record one"
    with pytest.raises(ModelError, match=said):
        discretize(car, dataclasses.replace(cfg, sensors=twins), method=method)
    # up-front sensors both on the centre line (y fraction 0): one point, refused naming both
    with pytest.raises(ModelError, match=r"sensors 'upfront_left' and 'upfront_right' land in one"):
        discretize(
            car, dataclasses.replace(cfg, upfront_sensor_y_fraction=0.0, sensor_snap_distance=1.0), method=method
        )
    # compartment sensors share the rigid compartment by design
    rigid = [
        SensorSpec("tunnel", "compartment"),
        SensorSpec("seat", "compartment"),
        SensorSpec("s", "position", [0.3, 0.1, 0.41]),
    ]
    cells = discretize(car, dataclasses.replace(cfg, sensors=rigid), method=method)
    assert cells.sensor_cell[0] == cells.sensor_cell[1] == cells.compartment != cells.sensor_cell[2]


def test_the_snap_distance_is_checked():
    with pytest.raises(ConfigError, match="expected a distance > 0 m, got 0") as e:
        from_dict(DiscretizationConfig, {"sensor_snap_distance": 0})
    assert e.value.key == "sensor_snap_distance"


def test_messages_give_positions_in_the_models_own_frame():
    """Discretization runs in the frame centred on the vehicle; a message must still name the positions the user
    configured (they read 0.25 m off, the car's offset, for a car read with ``AxisMap(y_center=-0.25)``)."""
    from marlcrash.vehicle.model import AxisMap

    cfg = load_discretization_config()
    far = dataclasses.replace(cfg, sensors=[SensorSpec("s", "position", [0.3, 0.73, 0.41])])
    with pytest.raises(ModelError, match=r"requested position \[0\.300, 0\.730, 0\.410\] m left of the centre line "
                                         r"y = 0\.250 m"):  # fmt: skip
        discretize(_car().transformed(AxisMap(y_center=-0.25)), far, method="optimized")
    twice = dataclasses.replace(cfg, sensors=[SensorSpec(n, "position", [0.3, 0.2, 0.41]) for n in "ab"])
    with pytest.raises(ModelError, match=r"requested \[0\.300, 0\.200, 0\.410\] and \[0\.300, 0\.200, 0\.410\] m"):
        discretize(_car(left_inner=True).transformed(AxisMap(y_center=-0.25)), twice, method="uniform")


@pytest.mark.parametrize("method", METHODS)
def test_an_up_front_sensor_outside_the_region_is_refused_naming_it(cfg, method):
    """An up-front sensor whose position lies outside the ROI (given in mm, or beside the car) silently became a
    compartment sensor; a 'position' sensor outside the ROI still is one, as documented."""
    car = _car(left_inner=True)
    mm = dataclasses.replace(cfg, sensors=[SensorSpec("s", "upfront_left", [300.0, 100.0, 410.0])])
    said = r"sensor 's' \(rule 'upfront_left'\): requested position \[300\.000, 100\.000, 410\.000\] m, from its "
    with pytest.raises(ModelError, match=said + "position, is outside the region of interest"):
        discretize(car, mm, method=method)
    wide = dataclasses.replace(cfg, sensors=[SensorSpec("r", "upfront_right", [0.3, -5.0, 0.41])])
    with pytest.raises(ModelError, match=r"sensor 'r' \(rule 'upfront_right'\): requested position \[0\.300, -5\.000"):
        discretize(car, wide, method=method)
    tunnel = dataclasses.replace(cfg, sensors=[SensorSpec("t", "position", [2.0, 0.0, 0.5])])
    cells = discretize(car, tunnel, method=method)
    assert cells.subassembly_names[cells.subassembly[cells.sensor_cell[0]]] == COMPARTMENT


@pytest.mark.parametrize("method", METHODS)
def test_a_sensor_position_off_the_vehicle_is_refused_naming_it(cfg, method):
    """A 'position' or 'compartment' sensor given in mm ([2000, 0, 500] for a tunnel at [2.0, 0.0, 0.5] m) became a
    compartment sensor recorded 2 km behind the car without a word; a position outside the vehicle's bounding box
    (by more than sensor_snap_distance) is refused, naming the sensor, its position and the vehicle's bounds."""
    car = _car(left_inner=True)
    for rule in ("position", "compartment"):
        mm = dataclasses.replace(cfg, sensors=[SensorSpec("t", rule, [2000.0, 0.0, 500.0])])
        with pytest.raises(
            ModelError,
            match=rf"sensor 't' \(rule '{rule}'\): position \[2000\.000, 0\.000, 500\.000\] m lies outside the "
            r"vehicle \[0\.000, -0\.800, 0\.050\] to \[3\.200, 0\.800, 1\.300\] m",
        ):
            discretize(car, mm, method=method)
    # just outside the bounds, within the snap distance (a sensor on the skin), and inside them: accepted
    for p in ([3.25, 0.0, 0.5], [2.0, 0.0, 0.5]):
        cells = discretize(car, dataclasses.replace(cfg, sensors=[SensorSpec("t", "position", p)]), method=method)
        assert cells.subassembly_names[cells.subassembly[cells.sensor_cell[0]]] == COMPARTMENT
        np.testing.assert_allclose(cells.sensor_position[0], p)


def test_the_vehicle_a_sensor_must_lie_in_is_that_of_its_elements_not_of_every_node(cfg):
    """The LS-OPT small car's deck keeps the nodes of the barrier it leaves out (x down to -0.381 m, z up to
    1.778 m, the car's elements end at 0 and 1.397 m): a sensor 0.3 m above the roof was accepted against a
    bounding box of every node, and the message gave that box as the vehicle's. Unused nodes now count for nothing."""
    car = _car(left_inner=True)
    far = np.array([[-0.4, 0.0, 2.0]])  # an unused node, ahead of and above the car
    car = dataclasses.replace(
        car, node_ids=np.append(car.node_ids, car.node_ids.max() + 1), coords=np.vstack([car.coords, far])
    )
    roof = dataclasses.replace(cfg, sensors=[SensorSpec("t", "position", [2.0, 0.0, 1.7])])
    with pytest.raises(
        ModelError,
        match=r"sensor 't' \(rule 'position'\): position \[2\.000, 0\.000, 1\.700\] m lies outside the "
        r"vehicle \[0\.000, -0\.800, 0\.050\] to \[3\.200, 0\.800, 1\.300\] m",
    ):
        discretize(car, roof)
