"""Discretization: counts, mass conservation, planes, sensors, parameters, IO, config errors."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from sim_fixtures import grid_model
from test_cells_helpers import (
    box_shell,
    build_model,
    drawn_figures,
    drawn_turn_from_x_to_y,
    hex_block,
    mini_car,
    plate,
    tube_x,
)
from test_cells_transmission import check_invariants

from marlcrash.cells import (
    CellModel,
    DiscretizationConfig,
    SensorSpec,
    discretization_summary,
    discretize,
    format_discretization_summary,
    load_discretization_config,
    summarize_cells,
)
from marlcrash.cells.plot import plot_cells
from marlcrash.config import config_dir, from_dict
from marlcrash.errors import ConfigError, ModelError
from marlcrash.sim import SimConfig, Surrogate
from marlcrash.vehicle.model import COMPARTMENT


@pytest.fixture(scope="module")
def car():
    return mini_car()


@pytest.fixture(scope="module")
def cfg():
    return load_discretization_config()


@pytest.fixture(scope="module")
def uniform(car, cfg):
    return discretize(car, cfg, method="uniform")


@pytest.fixture(scope="module")
def uniform_blocks(car, cfg):
    """The strict grid: one cell per block (``uniform_cells: per_block``)."""
    return discretize(car, dataclasses.replace(cfg, uniform_cells="per_block"), method="uniform")


@pytest.fixture(scope="module")
def optimized(car, cfg):
    return discretize(car, cfg, method="optimized")


def _roi_mass_reference(model, depth):
    """Independent ROI mass: non-compartment elements with centroid x < depth."""
    em = model.element_masses()
    comp = set(model.subassemblies.get(COMPARTMENT, []))
    total = 0.0
    for kind, parts, nodes in (
        ("shell", model.shell_part, model.shell_nodes),
        ("solid", model.solid_part, model.solid_nodes),
    ):
        cx = model.coords[nodes][:, :, 0].mean(axis=1)
        keep = (cx < depth) & ~np.isin(parts, list(comp))
        total += em[kind][keep].sum()
    return total


def _assert_counts_and_mass(model, cfg, uni, opt):
    roi_cells = uni.roi_volume / cfg.target_cell_volume
    assert uni.meta["n_cells_uniform"] == pytest.approx(roi_cells, rel=0.10)
    assert opt.n_cells <= uni.meta["n_cells_uniform"] / 8
    ref = _roi_mass_reference(model, cfg.roi_depth)
    for c in (uni, opt):
        cell_mass = c.mass[~c.is_rigid].sum()
        assert cell_mass == pytest.approx(ref, rel=5e-3)
        assert c.mass[c.compartment] == pytest.approx(model.total_mass() - cell_mass, rel=1e-9)
        assert c.mass.sum() == pytest.approx(model.total_mass(), rel=1e-12)
        assert (c.mass[c.is_null] == 0).all() and (c.mass[~c.is_null] > 0).all()


def test_counts_and_mass_on_hand_built_car(car, cfg, uniform_blocks, uniform, optimized):
    # per block: uniform cells = grid blocks, except blocks holding only compartment material, which join the
    # compartment
    vpe = cfg.voxels_per_cell_edge
    nx, ny, nz = uniform_blocks.grid_labels.shape
    block_label = uniform_blocks.grid_labels[::vpe, ::vpe, ::vpe]
    n_comp_blocks = int((block_label == uniform_blocks.compartment).sum())
    assert block_label.size == uniform_blocks.meta["n_cells_uniform"] == (nx // vpe) * (ny // vpe) * (nz // vpe)
    assert uniform_blocks.n_cells == uniform_blocks.meta["n_cells_uniform"] - n_comp_blocks + 1
    _assert_counts_and_mass(car, cfg, uniform_blocks, optimized)
    _assert_counts_and_mass(car, cfg, uniform, optimized)


def _blocks(labels, vpe):
    nx, ny, nz = labels.shape
    return labels.reshape(nx // vpe, vpe, ny // vpe, vpe, nz // vpe, vpe).transpose(0, 2, 4, 1, 3, 5)


def test_uniform_cells_split_blocks_by_subassembly(uniform, uniform_blocks, cfg):
    """``per_subassembly`` (the default): every cell lies within one block, no block holds two cells of one
    sub-assembly, and blocks where two parts meet hold a cell of each (so there are more cells than blocks; what
    each cell weighs: the next test)."""
    vpe = cfg.voxels_per_cell_edge
    blk = _blocks(uniform.grid_labels, vpe).reshape(-1, vpe**3)
    block_of = {}
    for b, cells in enumerate(blk):
        per_block = np.unique(cells[cells != uniform.compartment])
        subs = uniform.subassembly[per_block[~uniform.is_null[per_block]]]
        assert np.unique(subs).size == subs.size  # one cell per (block, sub-assembly)
        for c in per_block.tolist():
            assert block_of.setdefault(c, b) == b  # a cell never spans blocks
    assert uniform.n_cells > uniform_blocks.n_cells
    # the hand-built car has blocks where two parts meet: the split grid gives each its own cell
    mixed = 0
    for cells in blk:
        split = {int(uniform.subassembly[c]) for c in np.unique(cells)
                 if not uniform.is_null[c] and c != uniform.compartment}  # fmt: skip
        mixed += len(split) > 1
    assert mixed > 0


def test_uniform_cells_hold_their_own_subassembly_mass(uniform, uniform_blocks, optimized):
    """Per sub-assembly, the split grid's cells weigh what the optimized model's do (each sample in a cell of its
    own sub-assembly); the strict grid's block cells take their neighbours' material."""

    def by_sub(c):
        keep = ~c.is_null & ~c.is_rigid
        names = np.asarray(c.subassembly_names)[c.subassembly[keep]] if c.subassembly_names else None
        out = {}
        for name, m in zip(names, c.mass[keep], strict=True):
            out[name] = out.get(name, 0.0) + float(m)
        return out

    ref = by_sub(optimized)
    assert by_sub(uniform) == pytest.approx(ref, rel=1e-9)
    strict = by_sub(uniform_blocks)
    assert any(abs(strict.get(k, 0.0) - v) > 1e-3 * v for k, v in ref.items())


def test_uniform_blocks_are_exact_voxel_blocks(uniform_blocks, cfg):
    uniform = uniform_blocks
    vpe = cfg.voxels_per_cell_edge
    lab = uniform.grid_labels
    nx, ny, nz = lab.shape
    blocks = lab.reshape(nx // vpe, vpe, ny // vpe, vpe, nz // vpe, vpe)
    # every block of vpe^3 voxels carries one label
    assert (blocks == blocks[:, :1, :, :1, :, :1]).all()
    expected = cfg.target_cell_volume
    vols = uniform.volume[~uniform.is_rigid]
    assert np.median(vols) == pytest.approx(expected, rel=0.15)


def test_cells_never_straddle_section_planes(uniform, optimized):
    for c in (uniform, optimized):
        assert c.planes_y.tolist() == pytest.approx([-0.25 * 1.6, -0.1 * 1.6, 0.0, 0.1 * 1.6, 0.25 * 1.6])
        ey = c.grid_edges[1]
        for p in c.planes_y:
            j = int(np.argmin(np.abs(ey - p)))
            assert abs(ey[j] - p) < 1e-12
            left, right = c.grid_labels[:, j - 1, :], c.grid_labels[:, j, :]
            shared = np.intersect1d(left, right)
            assert shared.size == 0 or (c.is_rigid[shared]).all()


def _tube_before_a_box(tube, box_lo, box_hi, depth, cell_edge, method):
    """A 2 mm shell tube ahead of a shell compartment box, and its cells (no overlaps: one plane, at y = 0)."""
    m = build_model(
        [
            ("tube", "shell", tube, 2e-3, 1),
            (COMPARTMENT, "shell", box_shell(box_lo, box_hi, 2), 0.003, 2),
        ]
    )
    cfg = DiscretizationConfig(
        roi_depth=depth, target_cell_volume=cell_edge**3, overlaps=[], sensors=[SensorSpec("t", "compartment")]
    )
    return m, discretize(m, cfg, method=method)


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_massless_cells_merge_within_their_band(method):
    """A hollow tube whose section reaches just across the centre plane (y in [-0.3, 0.03]): the cells of its
    interior (no material) joined the nearest material cell of the tube, often one across the plane, so 31 cells
    spanned y = 0 and no overlap edge there covered whole cells (DESIGN 1.2); on the LS-OPT deck 37 did."""
    m, c = _tube_before_a_box(tube_x(0.0, 0.3, -0.3, 0.03, 0.0, 0.4, 12, 12), [0.4, -0.35, -0.05], [1.0, 0.35, 0.45],
                              depth=0.3, cell_edge=0.05, method=method)  # fmt: skip
    assert c.planes_y.tolist() == [0.0]
    j0 = int(np.searchsorted(c.grid_edges[1], 0.0))
    both = np.intersect1d(c.grid_labels[:, :j0], c.grid_labels[:, j0:])
    assert (c.is_rigid[both] | c.is_null[both]).all(), both[~(c.is_rigid[both] | c.is_null[both])]
    assert c.mass.sum() == pytest.approx(m.total_mass(), rel=1e-9)


def test_every_cell_holds_only_its_own_subassembly(car, optimized):
    # per sub-assembly, the cells' masses add up to that sub-assembly's ROI mass
    em = car.element_masses()
    pm = {}
    for kind, parts, nodes in (("shell", car.shell_part, car.shell_nodes), ("solid", car.solid_part, car.solid_nodes)):
        cx = car.coords[nodes][:, :, 0].mean(axis=1)
        for pid in np.unique(parts):
            sel = (parts == pid) & (cx < optimized.roi_depth)
            pm[int(pid)] = pm.get(int(pid), 0.0) + em[kind][sel].sum()
    for name, pids in car.subassemblies.items():
        if name == COMPARTMENT:
            continue
        got = optimized.mass[optimized.cells_of(name)].sum()
        assert got == pytest.approx(sum(pm[p] for p in pids), rel=1e-9), name


def test_invariants_and_sensors(uniform, optimized):
    for c in (uniform, optimized):
        check_invariants(c)
        assert c.sensor_names == ["upfront_left", "upfront_right", "tunnel"]
        left, right, tunnel = c.sensor_cell
        assert tunnel == c.compartment
        assert c.is_sensor[left] and c.is_sensor[right] and left != right
        assert not c.is_null[[left, right]].any()
        assert c.sensor_position[0, 1] > 0 > c.sensor_position[1, 1]
        # the barrier plane meets some cell in every column: front areas tile the ROI's y-z face
        face = np.prod((c.roi_hi - c.roi_lo)[1:])
        assert c.front_area.sum() == pytest.approx(face, rel=1e-12)
    # the optimized sensor cell is about one target volume
    s = optimized.sensor_cell[0]
    assert optimized.volume[s] <= 1.01 * optimized.target_cell_volume


def test_gap_links_cross_null_space(optimized):
    gap = optimized.link_gap > 0
    assert gap.any()
    assert (optimized.link_dir[gap] == 0).all()
    assert (optimized.link_material_area[gap] == 0).all()
    # the cooling plate (x 0.15) reaches the powertrain (x 0.45) across ~0.3 m of null space minus cell extents
    cool, pt = optimized.cells_of("cooling"), optimized.cells_of("powertrain")
    sel = np.isin(optimized.link_src, cool) & np.isin(optimized.link_dst, pt)
    assert sel.any() and (optimized.link_gap[sel] > 0.1).all()


def test_behaviour_parameters_of_a_tube_cell_match_closed_form():
    t, side = 1.5e-3, 0.08
    model = build_model(
        [
            ("rail", "shell", tube_x(0.0, 0.3, 0.01, 0.09, -0.04, 0.04, 12, 3), t, 1),
            (COMPARTMENT, "shell", plate([0.3, -0.3, -0.05], [0, 0.6, 0], [0.2, 0, 0.1], 2, 2), 0.01, 2),
        ]
    )
    cfg = DiscretizationConfig(
        roi_depth=0.2,
        target_cell_volume=0.1**3,
        overlaps=[],
        upfront_sensor_x=0.05,
        sensors=[SensorSpec("c", "compartment")],
    )
    cells = discretize(model, cfg, method="uniform")
    c = int(cells.grid_labels[2, np.searchsorted(cells.grid_edges[1], 0.05) - 1, 1])
    area = 4 * side * t  # tube walls along x
    length = 0.1
    force = cfg.crush_efficiency_shell * 0.5 * (3e8 + 5e8) * area
    assert cells.crush_length[c] == pytest.approx(length, rel=1e-12)
    assert cells.stroke[c] == pytest.approx((1 - cfg.compaction_shell) * length, rel=1e-12)
    assert cells.params[c, 1] == pytest.approx(force * (1 - cfg.compaction_shell) * length, rel=1e-9)
    assert cells.params[c, 0] == pytest.approx(force**2 / (2 * 210e9 * area / length), rel=1e-9)


def test_the_simulator_crushes_a_solid_cell_at_its_closed_form_force():
    """A solid cell's stroke is short (compaction_solid 0.9), so its E_s = F_c * 0.1 L; the simulator took every
    cell's stroke as 0.7 L and crushed solid cells (the powertrain) at 1/7 of F_c, with 1/49 of their stiffness."""
    model = build_model(
        [
            ("block", "solid", hex_block([0.0, 0.01, -0.04], [0.3, 0.09, 0.04], (6, 2, 2)), None, 1),
            (COMPARTMENT, "shell", plate([0.3, -0.3, -0.05], [0, 0.6, 0], [0.2, 0, 0.1], 2, 2), 0.01, 2),
        ]
    )
    cfg = DiscretizationConfig(
        roi_depth=0.2,
        target_cell_volume=0.1**3,
        solid_target_cell_volume=0.1**3,
        overlaps=[],
        upfront_sensor_x=0.05,
        sensors=[SensorSpec("c", "compartment")],
    )
    with pytest.warns(UserWarning, match="exceeds the height"):  # the 8 cm block is thinner than a cell
        cells = discretize(model, cfg, method="uniform")
    c = int(cells.grid_labels[0, np.searchsorted(cells.grid_edges[1], 0.05) - 1, 1])
    length, area = 0.1, 0.08 * 0.08
    force = cfg.crush_efficiency_solid * 0.5 * (3e8 + 5e8) * area
    assert cells.crush_length[c] == pytest.approx(length, rel=1e-12)
    assert cells.stroke[c] == pytest.approx((1 - cfg.compaction_solid) * length, rel=1e-12)
    assert cells.params[c, 1] == pytest.approx(force * (1 - cfg.compaction_solid) * length, rel=1e-9)
    sim = Surrogate(cells, SimConfig())
    props = sim.link_props(sim.check_params(cells.params[None]))
    axial = np.flatnonzero((cells.link_src == c) & (cells.link_dir == 0))
    assert axial.size
    yield_c = props.yield_c[0, axial].numpy()
    np.testing.assert_allclose(yield_c, force * cells.link_share[axial], rtol=1e-9)


def test_save_load_round_trip(optimized, tmp_path):
    path = tmp_path / "cells.npz"
    optimized.save(path)
    back = CellModel.load(path)
    for f in optimized.__dataclass_fields__:
        a, b = getattr(optimized, f), getattr(back, f)
        if f == "grid_edges":
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y)
        elif isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == b.dtype
        elif f != "meta":
            assert a == b, f
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"\x80\x04junk, not an archive")
    with pytest.raises(ModelError, match=r"junk\.npz: not a readable CellModel file \(not a \.npz archive") as info:
        CellModel.load(junk)
    assert "allow_pickle" not in str(info.value)
    junk.write_bytes(path.read_bytes()[:5000])  # cut short
    with pytest.raises(ModelError, match=r"junk\.npz: not a readable CellModel file \(a damaged \.npz archive"):
        CellModel.load(junk)
    assert back.meta["n_cells_uniform"] == optimized.meta["n_cells_uniform"]


@pytest.mark.parametrize(
    ("damage", "match"),
    [
        ("drop grid_edges_y", r"lacks \['grid_edges_y'\]"),
        ("header not JSON", "header is not JSON"),
        ("header not UTF-8", "header is not JSON"),
        ("header a list", "header is not a JSON object"),
    ],
)
def test_a_damaged_cell_model_file_is_a_model_error_naming_the_file(optimized, tmp_path, damage, match):
    """A file missing a grid-edge member, or whose header is not a JSON object, failed with a bare KeyError,
    JSONDecodeError, UnicodeDecodeError or TypeError; a file missing any other member already said which."""
    good = tmp_path / "good.npz"
    optimized.save(good)
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    if damage.startswith("drop "):
        del arrays[damage.split()[1]]
    else:
        text = {"header not JSON": b"{not json", "header not UTF-8": b"\xff\xfe", "header a list": b"[1]"}[damage]
        arrays["__header__"] = np.frombuffer(text, dtype=np.uint8)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(ModelError, match=match) as info:
        CellModel.load(bad)
    assert str(info.value).startswith(f"{bad}: ")


def test_a_cell_model_file_of_format_1_asks_for_a_rebuild(optimized, tmp_path):
    """Format 1 files have no per-cell stroke; the simulator took 0.7 of every cell's length from them."""
    good = tmp_path / "good.npz"
    optimized.save(good)
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files if k != "stroke"}
    header = json.loads(arrays["__header__"].tobytes().decode())
    header["format_version"] = 1
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    with pytest.raises(ModelError, match=r"old\.npz: CellModel format version 1.*rebuild it"):
        CellModel.load(old)
    header["format_version"] = 99
    arrays["__header__"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(old, **arrays)
    with pytest.raises(ModelError, match=r"old\.npz: unsupported CellModel format version 99"):
        CellModel.load(old)


def _corrupt(cells, field):
    """``cells`` with one field made inconsistent (what a hand-edited or mismatched file holds)."""
    null = int(np.flatnonzero(cells.is_null)[0])
    change = {
        "sensor_cell": {"sensor_cell": np.where(np.arange(len(cells.sensor_names)) == 0, 10**6, cells.sensor_cell)},
        "sensor_cell null": {"sensor_cell": np.where(np.arange(len(cells.sensor_names)) == 0, null, cells.sensor_cell)},
        "sensor_names": {"sensor_names": cells.sensor_names[:-1]},
        "sensor_position": {"sensor_position": cells.sensor_position[:-1]},
        "subassembly": {
            "subassembly": np.where(cells.subassembly == 0, len(cells.subassembly_names), cells.subassembly)
        },
        "grid_labels": {"grid_labels": np.where(cells.grid_labels == 0, cells.n_cells, cells.grid_labels)},
    }[field]
    return dataclasses.replace(cells, **change)


@pytest.mark.parametrize(
    "field", ["sensor_cell", "sensor_cell null", "sensor_names", "sensor_position", "subassembly", "grid_labels"]
)
def test_an_inconsistent_cell_model_file_is_refused_naming_the_field(optimized, tmp_path, field):
    """A cell file whose sensors, sub-assembly indices or voxel labels do not fit its cells loaded, and failed later
    in the simulator with an IndexError (a sensor cell out of range) or recorded the wrong cell without a word."""
    path = tmp_path / "bad.npz"
    _corrupt(optimized, field).save(path)
    with pytest.raises(ModelError, match=field.split()[0]):
        CellModel.load(path)


def _broken_parameters(cells, change):
    """A copy of ``cells`` whose parameters break one boundary condition (module doc of marlcrash.cells.model)."""
    p = cells.params.copy()
    c = int(np.flatnonzero(~cells.is_null & ~cells.is_rigid & (cells.feasible.sum(axis=1) >= 2))[0])
    shut = np.flatnonzero(~cells.is_null & ~cells.is_rigid & ~cells.feasible.all(axis=1))[0]
    if change == "negative E_s":
        p[c, 1] = -5.0
    elif change == "sum 3":
        p[c, 2:] = np.where(cells.feasible[c], 1.0, 0.0) * 3.0 / cells.feasible[c].sum()
    elif change == "null cell":
        p[int(np.flatnonzero(cells.is_null)[0]), 1] = 100.0
    elif change == "infeasible":
        d = int(np.flatnonzero(~cells.feasible[shut])[0])
        p[shut, 2:] *= 0.5
        p[shut, 2 + d] = 0.5
    return dataclasses.replace(cells, params=p)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("negative E_s", r"CellModel.params must be >= 0, got E_s -5 at cell"),
        ("sum 3", r"transmission factors must sum to 1, got 3"),
        ("null cell", r"is null, so has no parameters"),
        ("infeasible", r"transmission factor f_\w+ must be 0 where transfer [-+][xyz] is impossible"),
    ],
)
def test_a_cell_model_file_breaking_a_boundary_condition_is_refused(optimized, tmp_path, change, message):
    """Only finiteness was checked: factors summing to 3, one on an impossible direction (the simulator's shares are
    f / max f, so it changed every share of the cell), a null cell with energy or a negative E_s loaded and ran."""
    path = tmp_path / "bad.npz"
    _broken_parameters(optimized, change).save(path)
    with pytest.raises(ModelError, match=message):
        CellModel.load(path)


def test_summary_and_plot(car, cfg, optimized, tmp_path):
    s, cells = discretization_summary(car, cfg)
    assert cells.n_cells == optimized.n_cells
    assert s["n_cells_optimized"] == optimized.n_cells
    assert s["n_cells_uniform"] == optimized.meta["n_cells_uniform"]
    assert s["roi_volume_mm3"] == pytest.approx(optimized.roi_volume * 1e9)
    assert s["target_cell_volume_mm3"] == pytest.approx(3e5)
    assert s["cell_mass_kg"] == pytest.approx(s["roi_mass_kg"], rel=5e-3)
    assert s["n_sensors"] == 3 and s["n_subassemblies"] == 8
    assert sum(s["cells_per_subassembly"].values()) == optimized.n_cells - optimized.n_null
    s_uniform, uniform = discretization_summary(car, cfg, method="uniform")
    assert s_uniform["method"] == "uniform" and s_uniform["n_cells"] == uniform.n_cells
    assert s_uniform["n_cells_optimized"] == optimized.n_cells
    assert s_uniform["cell_mass_kg"] == pytest.approx(s["cell_mass_kg"], rel=1e-9)
    table = format_discretization_summary(s)
    assert f"{optimized.n_cells}" in table and "cells per sub-assembly" in table
    for summary, method in ((s, "optimized"), (s_uniform, "uniform")):  # "of which" counts follow the model's own
        lines = format_discretization_summary(summary).splitlines()
        at = next(i for i, line in enumerate(lines) if "of which null cells" in line)
        assert lines[at - 1].startswith(f"cells, {method} discretization")
        assert lines[at - 1].split()[-1] == str(summary["n_cells"])  # this model's count, not the grid's blocks
        assert lines[at].split()[-1] == str(summary["n_null_cells"])
    png = plot_cells(optimized, tmp_path / "cells.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_summary_of_a_per_block_uniform_model_does_not_call_its_cells_split(uniform_blocks, optimized):
    """``uniform_cells: per_block`` splits no block: its count differs from the grid's blocks by the compartment
    (a cell of its own, and the blocks of compartment material it takes in). The table printed it as "blocks split by
    sub-assembly", the other setting's row."""
    s = summarize_cells(uniform_blocks, optimized.n_cells)
    assert s["n_cells"] != s["n_cells_uniform"]
    lines = format_discretization_summary(s).splitlines()
    assert not any("split by sub-assembly" in line for line in lines), lines
    at = next(i for i, line in enumerate(lines) if "of which null cells" in line)
    assert lines[at - 1].startswith("cells, uniform discretization (one per block")
    assert lines[at - 1].split()[-1] == str(uniform_blocks.n_cells)
    assert s["uniform_cells"] == "per_block"


def test_the_summary_of_a_hand_built_model_leaves_the_discretizers_block_count_unknown():
    """A model not built by the discretizer (built in Python, or a file without its notes) has no
    ``meta["n_cells_uniform"]``, the count of the discretizer's grid blocks: summarize_cells failed with a bare
    ``KeyError: 'n_cells_uniform'``. The block count is not a property of the cells, so it is ``None`` (JSON null)
    and the table prints ``-``; everything else is counted from the model."""
    cells = grid_model(3, 2, 2, null_cells=((2, 1, 1),), sensors=(("tunnel", None), ("front", (0, 0, 0))))
    assert "n_cells_uniform" not in cells.meta
    s = summarize_cells(cells)
    assert s["n_cells_uniform"] is None and s["n_cells_optimized"] is None and s["uniform_cells"] is None
    assert s["n_cells"] == 3 * 2 * 2 + 1 and s["n_null_cells"] == 1 and s["n_sensor_cells"] == 2
    assert s["compartment_mass_kg"] == pytest.approx(1200.0) and s["cell_mass_kg"] == pytest.approx(400.0)
    assert s["cells_per_subassembly"] == {"right": 6, "centre": 5, "left": 0, "compartment": 1}  # j 0, 1 of 2
    lines = format_discretization_summary(s).splitlines()
    assert not any("None" in line for line in lines), lines
    assert next(line for line in lines if "(grid blocks)" in line).split()[-1] == "-"
    assert next(line for line in lines if "optimized discretization" in line).split()[-1] == "-"


@pytest.mark.parametrize("bad", [0, -5, 2.5, True, "100"])
def test_plot_cells_refuses_a_max_points_that_is_not_a_positive_whole_number(bad, tmp_path):
    """``max_points=0`` wrote a picture without a single voxel and a negative one failed inside numpy ("Number of
    samples, -5, must be non-negative"); now the argument is named before anything is drawn."""
    cells = grid_model(3, 2, 2)
    with pytest.raises(ValueError, match=r"max_points: expected a whole number of voxels >= 1, got"):
        plot_cells(cells, tmp_path / "cells.png", max_points=bad)
    assert not (tmp_path / "cells.png").exists()
    assert plot_cells(cells, tmp_path / "one.png", max_points=1).read_bytes()[:4] == b"\x89PNG"


def test_plot_cells_writes_the_picture_whole_or_not_at_all(tmp_path, monkeypatch):
    """``marlcrash discretize --plot`` wrote its picture straight to the user's path: a failed write (disk full) left
    a truncated PNG in place of the earlier picture, and the figure open. Now it goes through a temporary sibling
    (:func:`marlcrash.outputs.atomic_output`), as every other output does: the earlier file stays as it was, nothing
    else is left in the folder, and the figure is closed."""
    import errno

    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    cells = grid_model(3, 2, 2)
    png = plot_cells(cells, tmp_path / "cells.png")
    before = png.read_bytes()

    def full_disk(self, fname, *args, **kwargs):
        Path(fname).write_bytes(b"\x89PNG\r\n\x1a\npartial")
        raise OSError(errno.ENOSPC, "No space left on device", str(fname))

    monkeypatch.setattr(Figure, "savefig", full_disk)
    open_before = set(plt.get_fignums())
    with pytest.raises(OSError):
        plot_cells(cells, png)
    assert png.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cells.png"]
    assert set(plt.get_fignums()) == open_before


def test_the_3d_view_draws_the_cars_left_on_its_left(optimized, tmp_path, monkeypatch):
    """marlcrash's frame (x rearward, y left, z up) is left-handed and matplotlib draws its 3D axes right-handed:
    the cells were drawn mirrored, the car's left (the up-front left sensor, +y) on its right side."""
    figs = drawn_figures(monkeypatch)
    plot_cells(optimized, tmp_path / "cells.png")
    ax = figs[0].axes[0]
    # the drawn points are the voxels' own centres: the left sensor's cell on the left (+y)
    xs, ys, zs = (np.asarray(a) for a in ax.collections[-1]._offsets3d)  # the sensor cells, drawn last
    ix, iy, iz = np.nonzero(optimized.grid_labels == optimized.sensor_cell[0])
    centre = [0.5 * (np.asarray(e)[1:] + np.asarray(e)[:-1]) for e in optimized.grid_edges]
    left = np.column_stack([centre[0][ix], centre[1][iy], centre[2][iz]])
    assert (left[:, 1] > 0).all()
    drawn = {tuple(p) for p in np.round(np.column_stack([xs, ys, zs]), 9).tolist()}
    assert {tuple(p) for p in np.round(left, 9).tolist()} <= drawn
    assert drawn_turn_from_x_to_y(ax) == -1.0  # ... and the frame drawn as the left-handed frame it is


def test_config_file_and_errors():
    cfg = load_discretization_config(config_dir() / "cells.yaml")
    assert cfg.method == "optimized" and cfg.overlaps == [0.4, 0.25]
    with pytest.raises(ConfigError, match=r"overlaps\[1\]"):
        from_dict(DiscretizationConfig, {"overlaps": [0.4, 1.5]})
    with pytest.raises(ConfigError, match="roi_depth"):
        from_dict(DiscretizationConfig, {"roi_depth": -1.0})
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(DiscretizationConfig, {"roi_dept": 1.0})
    with pytest.raises(ConfigError, match=r"sensors\[0\].position"):
        from_dict(DiscretizationConfig, {"sensors": [{"name": "s", "rule": "position"}]})
    with pytest.raises(ConfigError, match="method"):
        discretize(mini_car(), cfg, method="voronoi")


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"voxels_per_cell_edge": 0}, "voxels_per_cell_edge"),  # was numpy's "zero-size array"
        ({"target_cell_volume": -1e-4}, "target_cell_volume"),  # was a complex cube root's TypeError
        ({"overlaps": ["0.4"]}, r"overlaps\[0\]"),
        ({"compaction_shell": 1.0}, "compaction_shell"),  # ran, with E_s = 0 in every cell
        ({"crush_efficiency_shell": 0.0}, "crush_efficiency_shell"),
        ({"roi_depth": float("nan")}, "roi_depth"),
    ],
)
def test_a_config_made_in_python_is_checked_as_a_file_is(change, key):
    from dataclasses import replace

    with pytest.raises(ConfigError, match=f"key '{key}'"):
        discretize(mini_car(), replace(load_discretization_config(), **change))


def test_a_subassembly_target_of_one_voxel_gives_cells_of_one_voxel():
    """A per-sub-assembly target volume down to the fine voxel's (``target_cell_volume / voxels_per_cell_edge^3``) is
    a valid setting; for the powertrain block of the mini car it stopped with "bisection did not converge", because
    the bisection's slot array doubled for every group at every level, finished ones too."""
    cfg = load_discretization_config()
    voxel = cfg.target_cell_volume / cfg.voxels_per_cell_edge**3
    cfg = dataclasses.replace(cfg, subassembly_target_cell_volume={"powertrain": voxel})
    cells = discretize(mini_car(), cfg)
    pt = cells.cells_of("powertrain")
    voxels = np.bincount(cells.grid_labels.ravel() + 1, minlength=cells.n_cells + 1)[1:][pt]
    assert pt.size > 5000 and np.median(voxels) <= 2


def test_a_subassembly_target_finer_than_a_voxel_is_refused_naming_the_key():
    """No cell is smaller than a fine voxel: a target below it gave one-voxel cells, larger than asked, without a word
    (and, before the bisection was fixed, "bisection did not converge")."""
    with pytest.raises(ConfigError, match="voxel") as err:
        load_discretization_config(overrides={"subassembly_target_cell_volume": {"powertrain": 1e-7}})
    assert err.value.key == "subassembly_target_cell_volume.powertrain"


def test_a_roi_depth_in_mm_names_the_keys_that_set_the_grid():
    """``roi_depth: 1200`` (mm given as m) asked for 4e8 voxels; the refusal blamed the deck's unit and a cell-size key
    ``target_volume`` that does not exist, not the cells config's ``roi_depth`` and ``target_cell_volume``."""
    cfg = dataclasses.replace(load_discretization_config(), roi_depth=1200.0)
    with pytest.raises(ModelError, match="roi_depth") as err:
        discretize(mini_car(), cfg)
    assert "target_cell_volume" in str(err.value) and "target_volume " not in str(err.value)


@pytest.mark.parametrize(
    ("args", "error", "said"),
    [
        ((None,), ModelError, "model must be a VehicleModel"),  # was "'NoneType' object has no attribute 'validate'"
        (("car.k",), ModelError, "model must be a VehicleModel"),
        (("mini", "configs/cells.yaml"), ConfigError, "config must be a DiscretizationConfig"),  # a dataclasses error
        (("mini", {"roi_depth": 1.0}), ConfigError, "config must be a DiscretizationConfig"),
    ],
)
def test_discretize_refuses_arguments_of_the_wrong_kind_in_words(args, error, said):
    args = tuple(mini_car() if a == "mini" else a for a in args)
    with pytest.raises(error, match=said):
        discretize(*args)


def test_the_cells_of_two_near_sensors_do_not_depend_on_their_order_in_the_config():
    """Each sensor's cell is a block around its voxel; where two blocks overlapped, the sensor listed first took the
    shared voxels: on the default car's left rail, sensors 2 cm apart got 15 and 5 voxels (59 and 16 g) listed one
    way, 5 and 15 the other, so a sensor's signal changed with the order of the config's list."""
    base = load_discretization_config()
    a = SensorSpec("a", "position", [0.6, 0.45, 0.41])
    b = SensorSpec("b", "position", [0.62, 0.45, 0.41])
    got = []
    for sensors in ([a, b], [b, a]):
        cells = discretize(mini_car(), dataclasses.replace(base, sensors=sensors))
        voxels = {n: frozenset(np.flatnonzero(cells.grid_labels.ravel() == c).tolist())
                  for n, c in zip(cells.sensor_names, cells.sensor_cell, strict=True)}  # fmt: skip
        assert voxels["a"] and voxels["b"] and not voxels["a"] & voxels["b"]
        got.append(voxels)
    assert got[0] == got[1]


def test_a_sampling_density_that_would_take_gigabytes_names_its_keys():
    """samples_per_pitch and max_subdivision had no bound: 40 and 80 on the default car ran a minute and died with
    numpy's "Unable to allocate 19.8 GiB"; the sample count is now known before any is made."""
    cfg = load_discretization_config(overrides={"samples_per_pitch": 1000, "max_subdivision": 4000})
    with pytest.raises(ModelError, match="samples_per_pitch") as err:
        discretize(mini_car(), cfg)
    assert "max_subdivision" in str(err.value)


def test_an_envelope_closing_beyond_a_few_cell_edges_is_refused_naming_the_key():
    """envelope_closing_iterations had no upper bound: 400 (a gap of 800 voxels sealed, far beyond any vehicle's
    front) ran the mini car for minutes on crops padded by 400 voxels a side, where 1 is the default."""
    with pytest.raises(ConfigError, match="expected 0 to 16") as err:
        from_dict(DiscretizationConfig, {"envelope_closing_iterations": 400})
    assert err.value.key == "envelope_closing_iterations"
    assert from_dict(DiscretizationConfig, {"envelope_closing_iterations": 16}).envelope_closing_iterations == 16


def test_scientific_notation_reads_as_a_number(tmp_path):
    """YAML 1.1 (PyYAML) reads 3e-4 as a string; the loader reads it as YAML 1.2 does."""
    text = (config_dir() / "cells.yaml").read_text()
    path = tmp_path / "cells.yaml"
    path.write_text(text.replace("target_cell_volume: 3.0e-4", "target_cell_volume: 3e-4", 1))
    assert "target_cell_volume: 3e-4" in path.read_text()
    assert load_discretization_config(path).target_cell_volume == 3e-4


def test_a_car_inside_the_roi_warns_that_the_compartment_has_no_mass(cfg):
    car = build_model([("rail", "shell", tube_x(0.0, 0.5, -0.1, 0.1, 0.2, 0.4), 2e-3, 1)], name="short")
    with pytest.warns(UserWarning, match=r"the compartment has no mass \(0 kg\)"):
        cells = discretize(car, cfg)
    assert cells.mass[cells.compartment] == 0.0  # not -1.7e-15 (printed -0.000 kg)


def test_simulating_a_car_inside_the_roi_blames_roi_depth_not_the_units(cfg):
    """The surrogate's mass floor is paid by the compartment; with the whole car in the region of interest it has
    0 kg, and the error said "a deck read in the wrong unit system is this light: check its units"."""
    from marlcrash.sim import Surrogate

    car = build_model([("rail", "shell", tube_x(0.0, 0.5, -0.1, 0.1, 0.2, 0.4), 2e-3, 1)], name="short")
    with pytest.warns(UserWarning, match="compartment has no mass"):
        cells = discretize(car, cfg)
    with pytest.raises(ModelError, match=r"short: the compartment has no mass .* roi_depth \(cells config\)") as e:
        Surrogate(cells)
    assert "units" not in str(e.value)


def test_elements_sampled_sparser_than_the_voxel_pitch_warn_naming_max_subdivision(cfg):
    """A coarse mesh was sampled at most max_subdivision times per edge without a word: at the former default of 12,
    98 of the LS-OPT small car's 284 shells in the ROI got samples up to 22 mm apart against 17 mm voxels, its walls
    were voxelized with gaps (18034 wall voxels instead of 27112, 307 cells instead of 401, 1424 links instead of 2230
    with the 17 the warning asks for)."""
    car = build_model(
        [
            ("rail", "shell", tube_x(0.0, 1.2, -0.1, 0.1, 0.2, 0.4, 2, 1), 2e-3, 1),
            (COMPARTMENT, "shell", tube_x(1.2, 2.0, -0.5, 0.5, 0.1, 0.8, 2, 2), 2e-3, 2),
        ],
        name="coarse",
    )
    few = dataclasses.replace(cfg, sensors=[])
    with pytest.warns(UserWarning, match=r"coarse: 8 of 8 elements .* raise max_subdivision \(32\) to \d+ ") as w:
        discretize(car, few)
    need = int(str(w[0].message).split("to ")[-1].split()[0])
    assert need >= 0.6 / 0.0167  # one sample per voxel pitch along the 0.6 m elements at least
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        discretize(car, dataclasses.replace(few, max_subdivision=need))


def test_the_public_deck_is_sampled_densely_enough_by_default(cfg, lsopt_deck):
    """The default ``max_subdivision`` was 12, which left the LS-OPT small car (elements up to 0.37 m) voxelized with
    gaps and warned on every discretization of the one real deck here; 32 samples its largest shells at least once
    per voxel pitch. The synthetic default car's cells are the same at either value (its elements are small)."""
    from marlcrash.vehicle.keyword import read_deck

    car = read_deck(lsopt_deck, params={"tbumper": 3.0, "thood": 1.0})
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        cells = discretize(car, cfg)
    assert not [w for w in seen if "max_subdivision" in str(w.message)], [str(w.message) for w in seen]
    assert cells.n_cells > 380  # 307 with the gaps of max_subdivision 12 (401 at 17, 411 at 32)


def test_a_uniform_summary_warns_once_not_again_for_the_optimized_count(cfg):
    """``marlcrash discretize --method uniform`` also discretizes by the optimized method for Table 2's other count;
    its warnings (the same sampling, here max_subdivision's) were printed a second time."""
    car = build_model(
        [
            ("rail", "shell", tube_x(0.0, 1.2, -0.1, 0.1, 0.2, 0.4, 2, 1), 2e-3, 1),
            (COMPARTMENT, "shell", tube_x(1.2, 2.0, -0.5, 0.5, 0.1, 0.8, 2, 2), 2e-3, 2),
        ],
        name="coarse",
    )
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        s, _ = discretization_summary(car, dataclasses.replace(cfg, sensors=[]), method="uniform")
    assert s["n_cells_optimized"] is not None
    assert len([w for w in seen if "max_subdivision" in str(w.message)]) == 1


def test_no_material_in_front_of_the_roi_depth_is_a_model_error(cfg):
    model = build_model(
        [
            ("rail", "shell", tube_x(2.0, 2.5, -0.1, 0.1, 0.0, 0.1, 4, 2), 1e-3, 1),
            ("rail", "shell", tube_x(0.0, 0.1, -0.8, -0.7, 0, 0.1, 2, 2), 1e-3, 2),
        ]
    )
    model = model.with_subassemblies({COMPARTMENT: [2], "rail": [1]})
    with pytest.raises(ModelError, match="roi_depth"):
        discretize(model, cfg)


@pytest.mark.parametrize("dx", [-0.3, 0.3])
def test_a_model_whose_front_is_not_at_x_0_is_a_model_error(cfg, dx):
    """The ROI is the box x in [0, roi_depth]: a model built with its front elsewhere had material in front of x = 0
    clamped into the first voxel layer (front at -0.3 m: 27 cells instead of 35) or cropped 0.3 m short (front at
    +0.3 m), without a word."""
    nodes, quads = tube_x(0.0, 0.8, -0.05, 0.05, 0.3, 0.4, 10, 4)
    nodes = nodes + np.array([dx, 0.0, 0.0])
    model = build_model([("rail", "shell", (nodes, quads), 2e-3, 1)], name="moved")
    with pytest.raises(ModelError, match=rf"moved: the front-most node is at x = {dx:g} m.*front at x = 0"):
        discretize(model, cfg)


def test_a_massless_subassembly_is_named_with_its_cause(cfg):
    """Elements without mass (a deck's zero density or thickness) own no voxel: the error says so, not that the
    geometry is flat."""
    model = mini_car()
    massless = model.subassemblies["cooling"][0]
    model.shell_thickness[model.shell_part == massless] = 0.0
    with pytest.raises(ModelError, match="sub-assembly 'cooling' has elements in the region of interest but no mass"):
        discretize(model, cfg, method="optimized")


def test_the_strict_uniform_grid_gives_massless_material_no_cell(cfg):
    """``uniform_cells: per_block`` made a cell of every block with samples, massless ones included (a part of zero
    thickness): 42 non-null cells without mass, linked into the load paths, where the other methods give such
    material no cell; and a sub-assembly without any mass was accepted where they name it."""
    model = mini_car()
    cooling = model.subassemblies["cooling"][0]
    left = model.coords[model.shell_nodes][:, :, 1].mean(axis=1) > 0
    strict = dataclasses.replace(cfg, uniform_cells="per_block")
    model.shell_thickness[(model.shell_part == cooling) & left] = 0.0  # half the cooling module weighs nothing
    on_it = SensorSpec("on_the_massless_half", "position", [0.15, 0.2, 0.45])  # snaps to material with mass
    cells = discretize(model, dataclasses.replace(strict, sensors=[on_it]), method="uniform")
    assert (cells.mass[~cells.is_null] > 0).all()
    assert not cells.is_null[cells.sensor_cell].any() and not cells.is_null[cells.is_sensor].any()
    assert cells.mass.sum() == pytest.approx(model.total_mass(), rel=1e-12)
    check_invariants(cells)
    model.shell_thickness[model.shell_part == cooling] = 0.0  # all of it
    with pytest.raises(ModelError, match="sub-assembly 'cooling' has elements in the region of interest but no mass"):
        discretize(model, strict, method="uniform")


# ------------------------------------------------------------------ the synthetic B-segment car
@pytest.fixture(scope="module")
def synthetic():
    import marlcrash.vehicle.synthetic as syn

    model = syn.default_vehicle()
    cfg = load_discretization_config()
    return model, cfg, discretize(model, cfg, method="uniform"), discretize(model, cfg, method="optimized")


def test_synthetic_car_counts_mass_and_invariants(synthetic):
    model, cfg, uni, opt = synthetic
    _assert_counts_and_mass(model, cfg, uni, opt)
    check_invariants(uni)
    check_invariants(opt)


def test_synthetic_car_round_trip(synthetic, tmp_path):
    _, _, _, opt = synthetic
    opt.save(tmp_path / "syn.npz")
    back = CellModel.load(tmp_path / "syn.npz")
    for f in ("params", "feasible", "mass", "link_src", "link_dst", "link_dir", "link_share", "grid_labels"):
        np.testing.assert_array_equal(getattr(back, f), getattr(opt, f))
    assert back.subassembly_names == opt.subassembly_names and back.sensor_names == opt.sensor_names


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_symmetric_car_gives_mirror_symmetric_cells(method):
    """The nominal synthetic car is mirror-symmetric, so its cell model must be too, voxel for voxel.

    Panels lying exactly in a grid plane (a wheel's flat side) used to be binned to the
    inner voxel on one side and the outer one on the other. The compartment's panels in the box's outer y faces
    had samples outside the box by rounding, more on one side: 42 voxels differed from their mirror image, 17 of
    them null cells of the optimized model (8 left, 9 right) where the compartment is.
    """
    import marlcrash.vehicle.synthetic as synthetic

    cells = discretize(synthetic.default_vehicle(), method=method)
    names = cells.subassembly_names
    for name in names:
        if name.endswith("_left"):
            twin = name[: -len("_left")] + "_right"
            assert cells.cells_of(name).size == cells.cells_of(twin).size, name
            np.testing.assert_allclose(cells.mass[cells.cells_of(name)].sum(), cells.mass[cells.cells_of(twin)].sum())
    sub, mirrored = _subassembly_voxels_and_mirror(cells)
    assert (mirrored == sub).all(), int((mirrored != sub).sum())
    null_y = cells.centroid[cells.is_null, 1]
    np.testing.assert_allclose(np.sort(null_y), np.sort(-null_y), atol=1e-9)
    # cell for cell: the uniform wheels' triangles were sampled from the vertex each was written from, so 12 wheel
    # cells weighed up to 0.08 % more than their twins
    act = np.flatnonzero(~cells.is_null & ~cells.is_rigid)
    dist, twin = cKDTree(cells.centroid[act]).query(cells.centroid[act] * [1.0, -1.0, 1.0])
    assert dist.max() < 1e-9
    np.testing.assert_allclose(cells.mass[act[twin]], cells.mass[act], rtol=1e-9)
    mirrored = cells.params[act][:, [0, 1, 2, 4, 3, 5, 6]]  # E_x, E_s, f_x, f_yn, f_y, f_z, f_zn
    np.testing.assert_allclose(cells.params[act[twin]], mirrored, rtol=1e-9, atol=1e-12)


def _subassembly_voxels_and_mirror(cells):
    """Sub-assembly per voxel (-1 null) and its mirror image about y = 0 with left and right names swapped."""
    names = cells.subassembly_names
    lab = cells.grid_labels
    sub = np.where(lab >= 0, cells.subassembly[np.maximum(lab, 0)], -1)
    swap = np.arange(-1, len(names))
    for i, n in enumerate(names):
        other = n.replace("_left", "_tmp").replace("_right", "_left").replace("_tmp", "_right")
        swap[i + 1] = names.index(other)
    return sub, swap[sub[:, ::-1, :] + 1]


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_material_on_the_centre_plane_is_shared_by_both_sides(method):
    """A mirror-symmetric tube with 5 elements across: one element straddles y = 0, and its samples on the plane all
    went to the left voxel (left 1.724 kg, right 1.667 kg of cells); split half to each side they are equal."""
    m, c = _tube_before_a_box(tube_x(0.0, 0.6, -0.05, 0.05, 0.0, 0.08, 12, 5), [0.7, -0.2, -0.1], [1.5, 0.2, 0.2],
                              depth=0.6, cell_edge=0.1, method=method)  # fmt: skip
    act = ~c.is_null & ~c.is_rigid
    left, right = act & (c.centroid[:, 1] > 0), act & (c.centroid[:, 1] < 0)
    assert c.mass[left].sum() == pytest.approx(c.mass[right].sum(), rel=1e-12)
    assert c.params[left, 1].sum() == pytest.approx(c.params[right, 1].sum(), rel=1e-12)  # E_s
    assert c.mass.sum() == pytest.approx(m.total_mass(), rel=1e-12)


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_walls_lying_in_a_grid_plane_bin_alike_on_both_sides(car, cfg, method):
    """The hand-built car is mirror-symmetric to 2e-16 m, and its bumper's bottom wall lies in the grid plane
    z = 0.35 m. Ties were broken by rounding along x and z (only y snapped to the edge): the wall's voxels
    alternated between the layers below and above it along y, 1388 voxels differed from their mirror image, and a
    sensor at (0.05, +-0.45, 0.41) m snapped to the bumper's front wall on the left, its rear wall on the right."""
    sub, mirrored = _subassembly_voxels_and_mirror(discretize(car, cfg, method=method))
    assert (mirrored == sub).all(), int((mirrored != sub).sum())
    pos = []
    for y in (0.45, -0.45):
        c = dataclasses.replace(cfg, sensors=[SensorSpec("s", "position", [0.05, y, 0.41])])
        pos.append(discretize(car, c, method=method).sensor_position[0])
    np.testing.assert_allclose(pos[0] * [1, -1, 1], pos[1], atol=1e-12)


def test_a_subassembly_target_whose_name_looks_like_a_typo_warns_naming_the_close_name(car, cfg):
    """Names a model lacks are ignored (the shared config names the synthetic car's wheels), but one that is a near
    miss of a sub-assembly the model has is most likely a typo, which would otherwise change nothing in silence."""
    typo = dataclasses.replace(cfg, subassembly_target_cell_volume={"powertrian": 0.002, "wheel_left": 0.002})
    with pytest.warns(UserWarning, match=r"subassembly_target_cell_volume\.powertrian.*did you mean 'powertrain'"):
        discretize(car, typo)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        discretize(car, dataclasses.replace(cfg, subassembly_target_cell_volume={"wheel_left": 0.002}))
    # the compartment's own key is refused (one rigid cell); a near miss of it changed nothing without a word
    typo = dataclasses.replace(cfg, subassembly_target_cell_volume={"compartmnet": 0.002})
    with pytest.warns(UserWarning, match=r"\.compartmnet.*did you mean 'compartment'\? \(the compartment is one rigid"):
        discretize(car, typo)


def test_a_roi_depth_longer_than_the_vehicle_warns_naming_the_key_and_the_length(car, cfg):
    """``roi_depth: 12`` (1.2 mistyped) was taken without a word: the region of interest ran 8 m past the default
    car's rear, its grid changed (539 cells instead of 518, 40.8 g instead of 37.5 g at 40 km/h), and the LS-OPT small
    car (no compartment sub-assembly) was discretized whole, leaving a compartment of 0 kg that `marlcrash simulate`
    then refused as a deck read in the wrong units. The model is still valid: a warning names the key, the value and
    the vehicle's length."""
    with pytest.warns(UserWarning, match=r"mini_car: roi_depth = 4 m is longer than the vehicle \(3\.200 m") as w:
        cells = discretize(car, dataclasses.replace(cfg, roi_depth=4.0))
    assert cells.roi_depth == 4.0 and any("roi_depth = 4 m" in n for n in cells.meta["warnings"])
    assert len([x for x in w if "roi_depth" in str(x.message)]) == 1
    short = build_model([("rail", "shell", tube_x(0.0, 0.5, -0.1, 0.1, 0.2, 0.4), 2e-3, 1)], name="short")
    with pytest.warns(UserWarning, match=r"short: roi_depth = 1\.2 m is longer than the vehicle \(0\.500 m"):
        discretize(short, cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        discretize(car, dataclasses.replace(cfg, roi_depth=3.2))  # the whole car, not past it


@pytest.mark.parametrize("method", ["optimized", "uniform"])
def test_a_target_cell_larger_than_the_vehicle_front_warns_naming_the_key(car, cfg, method):
    """A target cell volume whose edge exceeds the vehicle's width or its front's height cannot be had: the grid gets
    one block across each section band and the box height, the optimized method one cell per band of a sub-assembly
    (the default car at target_cell_volume 1.5 m^3: 57 cells; 8 m^3, edge 2 m against 1.7 m of width: 48), and this
    was taken without a word. The model is still valid: a warning names the key, its value and the dimension."""
    big = dataclasses.replace(
        cfg, target_cell_volume=1.0, solid_target_cell_volume=1.0, subassembly_target_cell_volume={}
    )
    with pytest.warns(
        UserWarning, match=r"mini_car: target_cell_volume = 1 m\^3, a cell edge of 1 m, exceeds the height of the"
    ) as w:
        cells = discretize(car, big, method=method)
    assert "0.800 m" in str(w[0].message) and "1.600" not in str(w[0].message)
    assert any("target_cell_volume = 1 m^3" in n for n in cells.meta["warnings"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        discretize(car, dataclasses.replace(big, target_cell_volume=0.5, solid_target_cell_volume=0.5), method=method)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"solid_target_cell_volume": 2.0}, r"solid_target_cell_volume = 2 m\^3 \(powertrain\)"),
        ({"subassembly_target_cell_volume": {"powertrain": 0.7}}, r"subassembly_target_cell_volume\.powertrain = 0\.7"),
    ],
)
def test_a_subassembly_target_larger_than_the_vehicle_front_warns_naming_the_key(car, cfg, change, key):
    """The per-sub-assembly targets alike (optimized method): an edge beyond the front's width or height makes each of
    the sub-assembly's y bands one cell whatever the number. A target for a sub-assembly the model lacks changes
    nothing and does not warn."""
    with pytest.warns(UserWarning, match=rf"{key}.* exceeds the height of the vehicle's front"):
        discretize(car, dataclasses.replace(cfg, **change))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        discretize(car, dataclasses.replace(cfg, subassembly_target_cell_volume={"wheel_left": 8.0}))
        discretize(car, dataclasses.replace(cfg, solid_target_cell_volume=2.0), method="uniform")  # not used there


def test_a_target_cell_volume_for_the_compartment_is_refused_naming_the_key(car, cfg, tmp_path):
    """The compartment is one rigid cell, never discretized: a target cell volume given for it (the default car, the
    LS-OPT small car alike: 518 and 304 cells, as without it) changed nothing without a word, while the user believed
    the compartment was split. The name is the compartment's in every model, so the config itself is refused."""
    text = (config_dir() / "cells.yaml").read_text()
    path = tmp_path / "cells.yaml"
    path.write_text(text.replace("  wheel_right: 0.01", "  wheel_right: 0.01\n  compartment: 0.05", 1))
    with pytest.raises(ConfigError, match=r"compartment is one rigid cell and is not discretized") as err:
        load_discretization_config(path)
    assert err.value.key == "subassembly_target_cell_volume.compartment"
    assert "cells.yaml" in str(err.value)
    with pytest.raises(ConfigError, match=r"subassembly_target_cell_volume\.compartment"):
        discretize(car, dataclasses.replace(cfg, subassembly_target_cell_volume={COMPARTMENT: 0.05}))


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_triangle_samples_do_not_depend_on_the_vertex_order(k):
    """The k*k sub-triangle centroids of a triangle: the same points from every vertex order, of equal weights, with
    the triangle's centroid as their mean (an independent check: the mean of a uniform density on it)."""
    from itertools import permutations

    from marlcrash.cells.grid import _triangle_samples

    p = np.random.default_rng(k).normal(size=(4, 3, 3))
    ref, w = _triangle_samples(p, k)
    assert ref.shape == (4, k * k, 3) and np.allclose(w, 1.0 / (k * k))
    np.testing.assert_allclose(ref.mean(axis=1), p.mean(axis=1), atol=1e-12)
    for order in permutations(range(3)):
        pos, _ = _triangle_samples(p[:, list(order)], k)
        for a, b in zip(ref, pos, strict=True):
            np.testing.assert_allclose(a[np.lexsort(a.T)], b[np.lexsort(b.T)], atol=1e-12)


@pytest.mark.parametrize(
    ("overlaps", "message"),
    [
        ([0.4, 0.4000001], r"two section planes lie 1\.6e-07 m apart \(y - y0 = -0\.16 and -0\.15999984 m\)"),
        ([0.4, 0.9999999], r"a section plane and the side of the region of interest lie"),
    ],
)
def test_overlaps_whose_planes_lie_closer_than_a_voxel_are_refused(overlaps, message):
    """Planes were deduplicated only where equal: [0.4, 0.4000001] made a band of 1.6e-7 m, voxels of 4e-8 m and a
    warning to raise max_subdivision to 3,750,000; refused before the work, naming ``overlaps``."""
    cfg = dataclasses.replace(load_discretization_config(), overlaps=overlaps)
    with pytest.raises(ConfigError, match=message) as e:
        discretize(mini_car(), cfg)
    assert e.value.key == "overlaps"
