"""The public LS-OPT small-car deck (../shared/data), checked against a hand computation."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from marlcrash.errors import DeckError
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.model import AxisMap

PARAMS = {"tbumper": 3, "thood": 1}


def _hand_masses(path) -> tuple[int, int, dict[int, float]]:
    """Part masses [kg] from a plain line-by-line read, independent of the reader.

    The deck's facts, read by eye: section thicknesses 2 (part 1), &tbumper (2),
    &thood (3, 4, 5), 0 (6) mm; element thicknesses 0 (use the section) or 0.2 mm;
    densities in t/mm^3; nodes in 8+16+16+16 columns with blanks meaning 0.
    """
    lines = path.read_text().splitlines()
    section_t = {1: 2.0, 2: PARAMS["tbumper"], 3: PARAMS["thood"], 4: PARAMS["thood"], 5: PARAMS["thood"], 6: 0.0}
    density = {}
    nodes: dict[int, np.ndarray] = {}
    shells = []
    block = None
    data: list[str] = []
    for ln in [*lines, "*END"]:
        if ln.startswith("$"):
            continue
        if ln.startswith("*"):
            if block and block.startswith("*MAT_"):
                density[int(data[0][:10])] = float(data[0][10:20])
            block, data = ln.strip(), []
            continue
        data.append(ln)
        if block == "*NODE":
            f = [ln[0:8], ln[8:24], ln[24:40], ln[40:56]]
            nodes[int(f[0])] = np.array([float(v) if v.strip() else 0.0 for v in f[1:]])
        elif block == "*ELEMENT_SHELL_THICKNESS" and len(data) % 2 == 0:
            head, thick = data[-2], data[-1]
            ids = [int(head[i : i + 8]) for i in range(0, 48, 8)]
            t = [float(v) for v in thick.split()]
            shells.append((ids[1], ids[2:], t))
    masses = dict.fromkeys(range(1, 7), 0.0)
    for pid, nids, t in shells:
        p = [nodes[n] for n in nids]
        area = 0.5 * (
            np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0])) + np.linalg.norm(np.cross(p[2] - p[0], p[3] - p[0]))
        )
        th = np.mean([x if x > 0 else section_t[pid] for x in t])
        masses[pid] += area * th * density[pid] * 1000.0  # mm^3 * t/mm^3 -> t -> kg
    return len(nodes), len(shells), masses


def test_counts_and_part_masses_match_hand_computation(lsopt_deck):
    with pytest.warns(UserWarning, match="skipped"):
        m = read_deck(lsopt_deck, params=PARAMS)
    n_nodes, n_shells, expect = _hand_masses(lsopt_deck)
    n_block = 590  # part 6's shells, by eye
    assert (m.n_nodes, m.n_shells, len(m.parts)) == (1236, 1174 - n_block, 5) == (n_nodes, n_shells - n_block, 5)
    got = m.part_masses()
    for pid in range(1, 6):
        assert got[pid] == pytest.approx(expect[pid], rel=1e-9), f"part {pid}"
    # the rigid part 6 (0.2 mm element thickness; its section's is 0) is a fixed block in front of the car
    assert f"({n_block} elements, {expect[6]:.1f} kg)" in m.left_out[6]
    assert m.units == "mm-t-s"
    assert m.materials[6].kind == "rigid" and m.materials[1].kind == "plastic_kinematic"
    assert m.parts[2].thickness == pytest.approx(3e-3) and m.parts[3].thickness == pytest.approx(1e-3)


def test_the_fixed_rigid_block_in_front_of_the_car_is_not_vehicle(lsopt_deck):
    """Part 6 is *MAT_RIGID with CMO = 1, CON1 = CON2 = 7 and gets no *INITIAL_VELOCITY_NODE: it stays put.

    Read as vehicle, it was the car's front (26 mm ahead of the bumper) and its width (2.03 m against the
    car's 1.40 m), so the surrogate's region of interest and every overlap were measured on the barrier.
    """
    text = lsopt_deck.read_text().splitlines()
    i = text.index("*INITIAL_VELOCITY_NODE")
    moving = set()
    for ln in text[i + 1 :]:
        if ln.startswith("*"):
            break
        if not ln.startswith("$"):
            moving.add(int(ln[:10]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS, axis_map=AxisMap(x="+x", y="+z", z="+y"))
    in_vehicle = set(m.node_ids[m.used_nodes()].tolist())
    assert in_vehicle == moving  # exactly the nodes the deck sets moving
    assert "CMO=1, CON1=7" in m.left_out[6] and "barrier or fixture" in m.left_out[6]
    assert m.skipped_cards["HOURGLASS"] == 6
    assert "SET_NODE_LIST" not in m.skipped_cards and "INITIAL_VELOCITY_NODE" not in m.skipped_cards  # read


def test_undefined_parameters_are_named_with_their_line(lsopt_deck):
    with pytest.raises(DeckError, match=r"lsopt_small_car5.k line \d+: parameter 'tbumper' is used but not defined"):
        read_deck(lsopt_deck)
    with pytest.raises(DeckError, match=r"line \d+: parameter 'thood'"):
        read_deck(lsopt_deck, params={"tbumper": 3})


def test_axis_map_makes_the_vertical_deck_axis_z(lsopt_deck):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS, axis_map=AxisMap(x="+x", y="+z", z="+y"))
    lo, hi = m.bounds()
    assert hi[2] - lo[2] == pytest.approx(1.397, abs=1e-3)  # roof at 1397 mm over the ground
    assert lo[0] == pytest.approx(0.0) and lo[1] == pytest.approx(-hi[1])  # front at x = 0, centred laterally
    # the car's deck z spans 0 .. 1397 mm (the fixed block's -254 .. 1778, left out)
    assert hi[1] - lo[1] == pytest.approx(1.397, abs=1e-3)
    assert hi[0] - lo[0] == pytest.approx(4.699 - 0.381, abs=1e-3)  # the car's deck x spans 381 .. 4699 mm


def test_the_block_is_left_out_by_its_initial_velocity_alone(lsopt_deck, tmp_path):
    """With its constraints cleared, part 6 is still at rest: *INITIAL_VELOCITY_NODE moves only the car's nodes."""
    text = lsopt_deck.read_text()
    assert text.count("  1.000000         7         7\n") == 1  # *MAT_RIGID 6: CMO CON1 CON2
    free = tmp_path / "free_block.k"
    free.write_text(text.replace("  1.000000         7         7\n", "       0.0         0         0\n"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(free, params=PARAMS)
    assert sorted(m.parts) == [1, 2, 3, 4, 5] and list(m.left_out) == [6]
    assert "initial velocities set none of its nodes moving while 576 nodes move" in m.left_out[6]


def test_a_deck_read_in_the_wrong_units_is_caught_before_memory_runs_out(lsopt_deck):
    """Forcing metres on a millimetre deck: the reader warns that the materials read otherwise and refuses a
    4 km car; a model built in Python at 1000x gets a discretization that refuses a region of interest 1000x a
    front end instead of allocating hundreds of GB."""
    from dataclasses import replace

    from marlcrash.cells.discretize import discretize
    from marlcrash.errors import DeckError, ModelError

    with (
        pytest.warns(UserWarning, match="units m-kg-s given, but the material densities .* read as mm-t-s"),
        pytest.raises(DeckError, match=r"spans 4318 m, more than any vehicle .* \(read as m-kg-s; --units\)"),
    ):
        read_deck(lsopt_deck, params=PARAMS, units="m-kg-s")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS)
    m = replace(m, coords=m.coords * 1000.0)
    with pytest.raises(
        ModelError, match=r"region of interest, .* would take .*check the deck's length unit \(--units\)"
    ):
        discretize(m)


def test_a_flat_deck_is_a_clear_error(lsopt_deck):
    """Two parts pressed flat into a side plane (a collapsed model): the sub-assembly without a cell of its own is
    named."""
    from dataclasses import replace

    from marlcrash.cells.discretize import discretize
    from marlcrash.errors import ModelError

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS)
    coords = m.coords.copy()
    flat = np.unique(m.shell_nodes[np.isin(m.shell_part, [3, 4])])
    coords[flat, 1] = coords[:, 1].min()  # parts 3 and 4 pressed into the vehicle's side plane
    with pytest.raises(ModelError, match=r"sub-assembly 'part_\d' has .* no (cell of its own|mass).*flat or collapsed"):
        discretize(replace(m, coords=coords))


def test_an_up_front_sensor_with_no_material_near_it_on_its_side_is_named(lsopt_deck):
    """Read with x=+x,y=+z,z=+y the car has no material left of its centre line near the default up-front left
    position (0.2, 0.3 W, mid-height): the sensor went 0.51 m away to a voxel right of the centre line, silently.
    Now discretization stops naming it, its requested position and the nearest material on its side (0.75 m away);
    given the reach, it lands left of the centre line."""
    from dataclasses import replace

    from marlcrash.cells.discretize import discretize, load_discretization_config
    from marlcrash.errors import ModelError

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS, axis_map=AxisMap(x="+x", y="+z", z="+y"))
    width = float(np.ptp(m.coords[m.used_nodes(), 1]))
    cfg = load_discretization_config()
    with pytest.raises(ModelError) as e:
        discretize(m, cfg)
    msg = str(e.value)
    y = f"{cfg.upfront_sensor_y_fraction * width:.3f}"
    assert msg.startswith("sensor 'upfront_left': no material within sensor_snap_distance = 0.15 m"), msg
    assert f"requested position [{cfg.upfront_sensor_x:.3f}, {y}, " in msg and "left of the centre line" in msg, msg
    far = float(msg.split(" m away")[0].split(", ")[-1])
    assert 0.7 < far < 0.8, msg
    cells = discretize(m, replace(cfg, sensor_snap_distance=1.0))
    left, right = cells.sensor_position[:2]
    assert left[1] > 0 > right[1]
    assert np.hypot(left[0] - cfg.upfront_sensor_x, left[1] - float(y)) <= far  # the nearest the message named


def _renumbered(m, shift: int):
    """``m`` with every node, shell, part, section and material id moved up by ``shift``."""
    from dataclasses import replace

    m = replace(m)
    m.node_ids = m.node_ids + shift
    m.shell_ids, m.shell_part = m.shell_ids + shift, m.shell_part + shift
    m.materials = {k + shift: replace(x, id=k + shift) for k, x in m.materials.items()}
    m.parts = {
        k + shift: replace(p, id=k + shift, material_id=p.material_id + shift, section_id=p.section_id + shift)
        for k, p in m.parts.items()
    }
    m.subassemblies = {name: [k + shift for k in v] for name, v in m.subassemblies.items()}
    return m


@pytest.mark.parametrize(("units", "shift"), [("mm-t-s", 0), ("m-kg-s", 0), ("mm-t-s", 123_456_789_000)])
def test_the_deck_written_back_reads_as_the_same_model(lsopt_deck, tmp_path, units, shift):
    """read -> write_deck -> read gives the model the surrogate is built from: nodes, shells, parts, sections,
    materials and masses, to the 10 significant digits of a fixed-format coordinate. Shifted, every id needs more
    columns than the fixed format has (12 digits: *NODE's and the elements' 8, *PART's 10), so a field written past
    its column would read back as another id or a wrong value."""
    from marlcrash.vehicle.keyword_writer import write_deck

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the deck's skipped cards and left-out barrier
        m = _renumbered(read_deck(lsopt_deck, params=PARAMS, axis_map=AxisMap(x="+x", y="+z", z="+y")), shift)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the cards carry every value of this model
        deck = write_deck(m, tmp_path / "car.k", units=units)
        back = read_deck(deck, subassemblies=tmp_path / "car.subassemblies.yaml")
    assert back.units == units and back.skipped_cards == {} and back.left_out == {}
    np.testing.assert_array_equal(back.node_ids, m.node_ids)
    np.testing.assert_allclose(back.coords, m.coords, rtol=1e-9, atol=1e-12)
    for attr in ("shell_ids", "shell_part", "shell_nodes"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(m, attr))
    np.testing.assert_allclose(back.shell_thickness, m.shell_thickness, rtol=1e-9)
    assert back.parts.keys() == m.parts.keys() and back.materials.keys() == m.materials.keys()
    for pid, p in m.parts.items():
        q = back.parts[pid]
        assert (q.name, q.material_id, q.section_id) == (p.name, p.material_id, p.section_id)
        assert q.thickness == pytest.approx(p.thickness, rel=1e-12)
    for mid, x in m.materials.items():
        assert back.materials[mid].kind == x.kind
        np.testing.assert_allclose(back.materials[mid].vector(), x.vector(), rtol=1e-10)
    assert back.subassemblies == m.subassemblies
    assert back.part_masses() == pytest.approx(m.part_masses(), rel=1e-9)
    assert sum(m.part_masses().values()) == pytest.approx(4443.797, rel=1e-6)  # parts 1-5, as read from the deck


def test_interleaved_cells_of_the_deck_link_along_x_one_way(lsopt_deck):
    """The LS-OPT small car's sub-assemblies interleave along x: its faces gave 23 pairs of cells linked +x both ways
    round and a cycle of 18 cells, by either method. Now no +x link closes a cycle, and the turned links are counted."""
    from dataclasses import replace

    from marlcrash.cells.discretize import discretize, load_discretization_config
    from marlcrash.cells.transmission import DIR_X, x_cycles

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        m = read_deck(lsopt_deck, params=PARAMS, axis_map=AxisMap(x="+x", y="+z", z="+y"))
        cfg = replace(load_discretization_config(), sensor_snap_distance=1.0)
        for method in ("optimized", "uniform"):
            cells = discretize(m, cfg, method=method)
            x = cells.link_dir == DIR_X
            assert np.bincount(x_cycles(cells.link_src[x], cells.link_dst[x], cells.n_cells)).max() == 1, method
            assert cells.meta["x_links_turned"] >= 23, method
