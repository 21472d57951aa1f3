"""Round trips: VehicleModel -> write_deck -> read_deck gives the same model."""

from __future__ import annotations

import math
import os
import stat
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from marlcrash.errors import ConfigError, DeckError, ModelError
from marlcrash.units import UNIT_SYSTEMS
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.keyword_writer import write_deck
from marlcrash.vehicle.materials import MATERIAL_FIELDS, Material, complete_material
from marlcrash.vehicle.model import Part, VehicleModel
from marlcrash.vehicle.subassembly_map import dump_subassembly_map

REPO = Path(__file__).resolve().parents[1]


def _model() -> VehicleModel:
    """A model already in marlcrash axes: front at x = 0, centred in y."""
    rng = np.random.default_rng(3)
    coords = np.array(
        [
            [0.0, -0.5, 0.1],
            [0.1, -0.5, 0.1],
            [0.1, 0.5, 0.1],
            [0.0, 0.5, 0.1],
            [0.2, 0.0, 0.3],  # tri apex
            [0.3, -0.1, 0.0],  # hex 8 nodes
            [0.4, -0.1, 0.0],
            [0.4, 0.1, 0.0],
            [0.3, 0.1, 0.0],
            [0.3, -0.1, 0.2],
            [0.4, -0.1, 0.2],
            [0.4, 0.1, 0.2],
            [0.3, 0.1, 0.2],
            [0.5, 0.0, 0.0],  # tet apex
            [0.6, 0.2, 0.5],  # beam end
        ]
    )
    coords[:, 0] += rng.uniform(0, 1e-3, len(coords)) * np.r_[0, rng.uniform(0, 1, len(coords) - 1)]
    coords[:, 2] += rng.uniform(-1e-3, 1e-3, len(coords))
    node_ids = np.arange(101, 101 + len(coords)) * 7
    mats = {
        1: complete_material(Material(1, "mild steel", "elastic", 7850.0, 2.1e11, poisson_ratio=0.3)),
        2: complete_material(
            Material(
                2,
                "DP600",
                "plastic_kinematic",
                7850.0,
                2.1e11,
                yield_strength=3.5e8,
                ultimate_strength=6.1e8,
                poisson_ratio=0.3,
            )
        ),
        3: complete_material(
            Material(
                3,
                "AA6061",
                "piecewise_linear",
                2700.0,
                7.0e10,
                yield_strength=2.4e8,
                ultimate_strength=3.1e8,
                fracture_strength=2.9e8,
                poisson_ratio=0.33,
            )
        ),
        4: complete_material(Material(4, "rigid wall", "rigid", 7800.0, 2.0e11, poisson_ratio=0.29)),
    }
    parts = {
        10: Part(10, "bumper beam", 2, 10, thickness=1.7e-3),
        11: Part(11, "crash box", 3, 11, thickness=2.25e-3),
        12: Part(12, "engine block", 1, 12),
        13: Part(13, "rail link", 4, 13, beam_area=3.3e-4),
    }
    return VehicleModel(
        node_ids=node_ids,
        coords=coords,
        shell_ids=np.array([5, 6]),
        shell_part=np.array([10, 11]),
        shell_nodes=np.array([[0, 1, 2, 3], [1, 4, 2, 2]]),
        shell_thickness=np.array([1.7e-3, 2.6e-3]),
        solid_ids=np.array([20, 21]),
        solid_part=np.array([12, 12]),
        solid_nodes=np.array([[5, 6, 7, 8, 9, 10, 11, 12], [6, 13, 7, 10, 10, 10, 10, 10]]),
        beam_ids=np.array([30]),
        beam_part=np.array([13]),
        beam_nodes=np.array([[4, 14]]),
        beam_area=np.array([4.1e-4]),
        parts=parts,
        materials=mats,
        subassemblies={"bumper": [10, 11], "powertrain": [12], "rails": [13]},
        name="round trip car",
    )


def _same(a: VehicleModel, b: VehicleModel) -> None:
    np.testing.assert_array_equal(a.node_ids, b.node_ids)
    np.testing.assert_allclose(a.coords, b.coords, rtol=1e-9, atol=1e-12)
    for kind in ("shell", "solid", "beam"):
        for attr in ("ids", "part", "nodes"):
            np.testing.assert_array_equal(getattr(a, f"{kind}_{attr}"), getattr(b, f"{kind}_{attr}"))
    np.testing.assert_allclose(a.shell_thickness, b.shell_thickness, rtol=1e-9)
    np.testing.assert_allclose(a.beam_area, b.beam_area, rtol=1e-9)
    assert a.parts.keys() == b.parts.keys()
    for pid, p in a.parts.items():
        q = b.parts[pid]
        assert (p.name, p.material_id, p.section_id) == (q.name, q.material_id, q.section_id)
        for x, y in ((p.thickness, q.thickness), (p.beam_area, q.beam_area)):
            assert (x is None) == (y is None)
            if x is not None:
                assert y == pytest.approx(x, rel=1e-12)
    assert a.materials.keys() == b.materials.keys()
    for mid, m in a.materials.items():
        n = b.materials[mid]
        assert (m.kind, m.name) == (n.kind, n.name)
        for f, x, y in zip(MATERIAL_FIELDS, m.vector(), n.vector(), strict=True):
            assert y == pytest.approx(x, rel=1e-10), f"material {mid} {f}"
    assert a.subassemblies == b.subassemblies
    np.testing.assert_allclose(a.total_mass(), b.total_mass(), rtol=1e-9)


@pytest.mark.parametrize("units", list(UNIT_SYSTEMS))
def test_round_trip_is_identical(tmp_path, units):
    m = _model()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every value of this model is carried by the cards
        deck = write_deck(m, tmp_path / "car.k", units=units)
    yaml_path = tmp_path / "car.subassemblies.yaml"
    assert yaml_path.is_file()
    back = read_deck(deck, units=units, subassemblies=yaml_path)
    _same(m, back)
    assert back.units == units
    assert back.skipped_cards == {}


def test_units_are_detected_and_values_scaled(tmp_path):
    m = _model()
    deck = write_deck(m, tmp_path / "car.k", units="mm-t-s")
    text = deck.read_text()
    # steel density in t/mm^3 and a coordinate in mm appear literally
    assert "7.850000000000e-09" in text
    back = read_deck(deck, subassemblies=tmp_path / "car.subassemblies.yaml")
    assert back.units == "mm-t-s"
    _same(m, back)


def test_mass_matches_independent_sum(tmp_path):
    m = _model()
    back = read_deck(write_deck(m, tmp_path / "c.k"), subassemblies=tmp_path / "c.subassemblies.yaml")
    c = m.coords
    quad = 0.5 * (
        np.linalg.norm(np.cross(c[1] - c[0], c[2] - c[0])) + np.linalg.norm(np.cross(c[2] - c[0], c[3] - c[0]))
    )
    tri = 0.5 * np.linalg.norm(np.cross(c[4] - c[1], c[2] - c[1]))
    hexv = abs(np.linalg.det(np.stack([c[6] - c[5], c[8] - c[5], c[9] - c[5]])))  # near-box: edge triple product
    tet = abs(np.linalg.det(np.stack([c[13] - c[6], c[7] - c[6], c[10] - c[6]]))) / 6
    beam = np.linalg.norm(c[14] - c[4])
    expected = {
        10: quad * 1.7e-3 * 7850,
        11: tri * 2.6e-3 * 2700,
        12: (hexv + tet) * 7850,
        13: beam * 4.1e-4 * 7800,
    }
    got = back.part_masses()
    for pid, v in expected.items():
        assert got[pid] == pytest.approx(v, rel=2e-2 if pid == 12 else 1e-9)


def test_writer_warns_about_values_it_cannot_carry(tmp_path):
    m = _model()
    mats = dict(m.materials)
    mats[1] = complete_material(Material(1, "odd", "elastic", 7850.0, 2.1e11, yield_strength=9e8, poisson_ratio=0.3))
    m.materials = mats
    with pytest.warns(UserWarning, match="material 1: yield_strength"):
        write_deck(m, tmp_path / "x.k")


def test_zero_element_values_read_back_as_zero_or_are_named(tmp_path):
    """An element of thickness or area 0 reads back as its section's value (LS-DYNA's rule). The writer gave a beam
    part without an area of its own the median of its elements' (a 0.314 kg model read back at 0.3925 kg) and named
    neither case; now a beam part without an area gets section area 0, and a nonzero section value is named."""
    m = _model()
    two = (np.array([30, 31]), np.array([13, 13]), np.array([[4, 14], [13, 14]]), np.array([4.1e-4, 0.0]))
    m = replace(m, beam_ids=two[0], beam_part=two[1], beam_nodes=two[2], beam_area=two[3])
    m.parts = {**m.parts, 13: replace(m.parts[13], beam_area=None)}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # carried: section area 0
        back = read_deck(write_deck(m, tmp_path / "beam.k"), subassemblies=tmp_path / "beam.subassemblies.yaml")
    _same(m, back)
    m = replace(_model(), shell_thickness=np.array([1.7e-3, 0.0]))
    with pytest.warns(UserWarning, match=r"part 11: 1 shells of thickness 0 \(read back, they take the section's 2.25"):
        deck = write_deck(m, tmp_path / "shell.k", units="mm-t-s")
    assert read_deck(deck).shell_thickness[1] == pytest.approx(2.25e-3)  # as the warning says


def test_writer_rejects_mixed_parts_and_leaves_nothing_behind(tmp_path):
    m = _model()
    m.solid_part = np.array([12, 10])
    with pytest.raises(ModelError, match="part 10 holds both shell and solid"):
        write_deck(m, tmp_path / "bad.k")
    assert list(tmp_path.iterdir()) == []


def test_numpy_integer_ids_are_written_as_integers(tmp_path):
    """Ids held as numpy integers (a model built from arrays) went into the long-format cards as floats
    (``MID 1.000000000000e+00``) where the keyword format wants an integer field."""
    m = _model()
    m.materials = {np.int64(k): replace(v, id=np.int64(v.id)) for k, v in m.materials.items()}
    i64 = np.int64
    m.parts = {
        i64(k): replace(p, id=i64(p.id), material_id=i64(p.material_id), section_id=i64(p.section_id))
        for k, p in m.parts.items()
    }
    m.part_mass = {np.int64(13): 0.5}
    m.part_added_mass = {np.int64(10): 0.25}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        lines = write_deck(m, tmp_path / "np.k").read_text().splitlines()
    for head, skip in (
        ("*MAT_ELASTIC_TITLE+", 2),
        ("*MAT_RIGID_TITLE+", 2),
        ("*PART_INERTIA+", 2),
        ("*SECTION_SHELL+", 1),
        ("*ELEMENT_MASS_PART+", 1),
    ):
        first = lines[lines.index(head) + skip][:20]
        assert first.strip().isdigit(), f"{head}: id field {first!r}"


def test_a_set_mass_the_cards_cannot_carry_is_warned_and_the_deck_reads_back(tmp_path):
    """``*PART_INERTIA`` TM sets a rigid part's mass only (the reader ignores it on a deformable part, as LS-DYNA
    does) and must be positive: a deformable part's set mass was dropped on the way back without a word, and a rigid
    part's zero mass gave a deck its own reader refused."""
    m = _model()
    m.part_mass = {12: 3.0, 13: 0.0}  # 12 is elastic, 13 rigid
    with pytest.warns(UserWarning, match=r"part 12: its set mass 3 kg.*part 13: its set mass 0 kg"):
        deck = write_deck(m, tmp_path / "pm.k")
    assert "*PART_INERTIA" not in deck.read_text()
    back = read_deck(deck, subassemblies=tmp_path / "pm.subassemblies.yaml")
    assert back.part_mass == {}
    m.part_mass = {13: 2.0}  # what the cards carry goes through without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        deck = write_deck(m, tmp_path / "ok.k")
    back = read_deck(deck, subassemblies=tmp_path / "ok.subassemblies.yaml")
    assert back.part_mass == {13: pytest.approx(2.0, rel=1e-12)}


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permission bits")
def test_a_written_deck_and_map_get_the_umask_mode_and_a_missing_folder_is_named(tmp_path, umask):
    """tempfile.mkstemp made the deck and its sub-assembly map 0o600 whatever the umask (every other output of
    marlcrash gets 0o666 less the umask, marlcrash.outputs.atomic_output): a deck written for a colleague could not
    be read by the group. A missing folder raised FileNotFoundError naming the temporary file."""
    m = _model()
    umask(0o022)
    write_deck(m, tmp_path / "car.k")
    umask(0o027)
    dump_subassembly_map({"hood": [10]}, tmp_path / "map.yaml")
    assert stat.S_IMODE((tmp_path / "car.k").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "car.subassemblies.yaml").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "map.yaml").stat().st_mode) == 0o640  # the umask still decides
    assert sorted(p.name for p in tmp_path.iterdir()) == ["car.k", "car.subassemblies.yaml", "map.yaml"]
    for write in (lambda p: write_deck(m, p), lambda p: dump_subassembly_map({"hood": [10]}, p)):
        with pytest.raises(ConfigError, match=r"the folder of .*missing/out\.k does not exist"):
            write(tmp_path / "missing" / "out.k")


def test_titles_that_begin_as_a_comment_or_a_keyword_read_back(tmp_path):
    """A title line is read whole, but a line that begins with ``$`` is a comment and one that begins with ``*`` a
    keyword: a deck whose titles were indented (`` $ mild steel``, `` *** bumper``) read fine, its titles stripped,
    and writing that model back gave a deck nobody could read. The writer indents such a title by one space."""
    m = _model()
    m.name = "*round trip car"
    m.parts = {pid: replace(p, name=("*** " if pid % 2 else "$ ") + p.name) for pid, p in m.parts.items()}
    m.materials = {mid: replace(mat, name="$" + mat.name) for mid, mat in m.materials.items()}
    deck = write_deck(m, tmp_path / "c.k")
    back = read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml")
    assert back.name == m.name
    assert {pid: p.name for pid, p in back.parts.items()} == {pid: p.name for pid, p in m.parts.items()}
    assert {mid: x.name for mid, x in back.materials.items()} == {mid: x.name for mid, x in m.materials.items()}


def test_titles_longer_than_their_field_are_cut_with_a_warning(tmp_path):
    """*TITLE and a material's title are one line of 80 characters, a part's heading 70 (LS-DYNA reads no more):
    the writer cut them to 80 without a word, so a long name came back shortened; and a part heading of 71-80
    characters was written whole, past its field. What is cut (or a line break joined) is named in the warning."""
    m = _model()
    m.name = "a vehicle model whose name runs on " + "and on " * 10  # 105 characters
    m.parts = {pid: replace(p, name=p.name + " " + "x" * 64) if pid == 11 else p for pid, p in m.parts.items()}
    m.materials = {mid: replace(x, name="line one\nline two") if mid == 3 else x for mid, x in m.materials.items()}
    with pytest.warns(UserWarning) as caught:
        deck = write_deck(m, tmp_path / "c.k")
    text = " ".join(str(w.message) for w in caught)
    assert f"*TITLE {m.name!r} is cut to its 80 columns: it reads back as {m.name[:80].strip()!r}" in text
    assert f"part 11: its heading {m.parts[11].name!r} is cut to its 70 columns" in text
    assert "material 3: its title 'line one\\nline two' is written on one line: it reads back as 'line one line" in text
    assert "part 10" not in text and "material 1" not in text  # what fits goes through without a word
    lines = deck.read_text().splitlines()
    titles = [lines[k + 1] for k, s in enumerate(lines) if s == "*TITLE" or s.endswith("_TITLE+")]
    assert len(titles) == 5 and max(len(s) for s in titles) == 80
    headings = [lines[k + 1] for k, s in enumerate(lines) if s.startswith("*PART")]
    assert len(headings) == 4 and max(len(s) for s in headings) == 70
    back = read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml")
    assert back.name == m.name[:80].strip() and back.parts[11].name == m.parts[11].name[:70]
    assert back.materials[3].name == "line one line two"


def _renumbered(m: VehicleModel, pids: dict[int, int], mids: dict[int, int] | None = None) -> VehicleModel:
    """``m`` with parts (and materials) renumbered by the maps given, section ids following the part ids."""
    mids = mids or {k: k for k in m.materials}
    m.materials = {mids[k]: replace(x, id=mids[k]) for k, x in m.materials.items()}
    m.parts = {
        pids[k]: replace(p, id=pids[k], material_id=mids[p.material_id], section_id=pids[k]) for k, p in m.parts.items()
    }
    for kind in ("shell", "solid", "beam"):
        setattr(m, f"{kind}_part", np.array([pids[k] for k in getattr(m, f"{kind}_part").tolist()], dtype=np.int64))
    m.subassemblies = {name: [pids[k] for k in v] for name, v in m.subassemblies.items()}
    return m


def test_part_ids_too_wide_for_the_part_card_go_long_format(tmp_path):
    """*PART's card has 10-column fields: a part, section or material id of 11 digits was written past its column
    (``12345678901         1``) and the deck read back as SECID '1         1', or a wrong section."""
    big = 12_345_678_901
    m = _renumbered(_model(), {10: big, 11: 11, 12: 9_999_999_999, 13: 13}, {1: 1, 2: 2, 3: big + 7, 4: 4})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        deck = write_deck(m, tmp_path / "c.k")
    _same(m, read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml"))
    heads = [s for s in deck.read_text().splitlines() if s.startswith("*PART")]
    assert heads == ["*PART+", "*PART", "*PART", "*PART+"]  # parts 11 (material big + 7), 13, 9999999999, big


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda m: m.node_ids.__setitem__(0, -123_456_789),
            r"node id -123456789 is not positive \(\*NODE takes ids from 1\)",
        ),
        (
            lambda m: m.shell_ids.__setitem__(1, 0),
            r"shell id 0 is not positive \(\*ELEMENT_SHELL_THICKNESS takes ids from 1\)",
        ),
        (
            lambda m: m.solid_ids.__setitem__(0, -20),
            r"solid id -20 is not positive \(\*ELEMENT_SOLID takes ids from 1\)",
        ),
        (
            lambda m: m.beam_ids.__setitem__(0, 0),
            r"beam id 0 is not positive \(\*ELEMENT_BEAM_THICKNESS takes ids from 1\)",
        ),
        (
            lambda m: _renumbered(m, {10: 10, 11: -11, 12: 12, 13: 13}),
            r"part id -11 is not positive \(\*PART takes ids from 1\)",
        ),
        (lambda m: _renumbered(m, {k: k for k in m.parts}, {1: 1, 2: 2, 3: 3, 4: 0}), r"material id 0 is not pos"),
        (
            lambda m: m.parts.__setitem__(12, replace(m.parts[12], section_id=-4)),
            r"part 12's section id -4 is not positive \(\*SECTION_SOLID takes ids from 1\)",
        ),
    ],
)
def test_ids_ls_dyna_does_not_take_are_refused_by_name(tmp_path, change, message):
    """Every id of a keyword deck is a positive integer. The writer wrote a negative or zero id as it came, a deck
    its own reader refused ('*NODE expects a positive node id'); a negative node id of 9 characters ran into the x
    column, and the reader complained of a bad coordinate."""
    m = _model()
    m.node_ids, m.shell_ids, m.solid_ids, m.beam_ids = (
        a.copy() for a in (m.node_ids, m.shell_ids, m.solid_ids, m.beam_ids)
    )
    change(m)
    with pytest.raises(ModelError, match=message):
        write_deck(m, tmp_path / "c.k")
    assert list(tmp_path.iterdir()) == []


def test_point_mass_ids_that_are_not_positive_are_renumbered(tmp_path):
    """A point mass's id labels its *ELEMENT_MASS card only (the model refers to none): ids that repeat were renumbered
    from 1, ids of 0 or below went into the deck as they came and it could not be read back."""
    m = _model()
    m.point_mass_ids, m.point_mass_nodes, m.point_mass = np.array([0, -7]), np.array([2, 5]), np.array([1.5, 2.5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        deck = write_deck(m, tmp_path / "c.k")
    back = read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml")
    _same(m, back)
    assert back.point_mass_ids.tolist() == [1, 2]
    np.testing.assert_array_equal(back.node_ids[back.point_mass_nodes], m.node_ids[m.point_mass_nodes])
    np.testing.assert_allclose(back.point_mass, m.point_mass, rtol=1e-9)


def test_a_coordinate_too_wide_for_its_column_goes_long_format(tmp_path):
    """*NODE's coordinates have 16 columns: -2e100 mm written as ``-2.000000000e+100`` took 17 and pushed the rest
    of the line one column on, so a fixed-column reader took z for -2e+07 mm (``-2.000000000e+10`` and a ``0``
    left over). A block holding a value that needs a 3-digit exponent is written in long format (20 columns)."""
    m = _model()
    m.coords = m.coords.copy()
    m.coords[3, 2] = -2e97  # m: -2e100 mm
    deck = write_deck(m, tmp_path / "c.k")
    lines = deck.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if s.startswith("*NODE"))
    w, cw = (20, 20) if lines[k] == "*NODE+" else (8, 16)
    row = lines[k + 4]  # the fourth node
    assert int(row[:w]) == m.node_ids[3]
    assert [float(row[w + j * cw : w + (j + 1) * cw]) for j in range(3)] == pytest.approx(m.coords[3] * 1e3, rel=1e-9)
    # the reader takes it as written, and names the node as lying where the model has it (too far for a vehicle)
    with pytest.raises(DeckError, match=rf"node {m.node_ids[3]} at \(.*, -2e\+97\) m"):
        read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml")


@pytest.mark.parametrize(
    ("pid", "field", "value", "message"),
    [
        (10, "thickness", math.nan, r"part 10's thickness nan m is not finite and >= 0 \(\*SECTION_SHELL T1"),
        (11, "thickness", -1e-3, r"part 11's thickness -0.001 m is not finite and >= 0 \(\*SECTION_SHELL T1"),
        (13, "beam_area", math.inf, r"part 13's beam area inf m\^2 is not finite and >= 0 \(\*SECTION_BEAM A\)"),
    ],
)
def test_a_section_value_ls_dyna_cannot_read_is_refused_by_part(tmp_path, pid, field, value, message):
    """A part's thickness or beam area goes into its section card as it is: NaN or a negative thickness gave a deck
    its own reader refused (``*SECTION_SHELL expects thicknesses T1..T4 >= 0, got [nan, ...]``) and an infinite
    area one that read back as ``inf``. The writer names the part instead."""
    m = _model()
    m.parts = {k: replace(p, **{field: value}) if k == pid else p for k, p in m.parts.items()}
    with pytest.raises(ModelError, match=message):
        write_deck(m, tmp_path / "c.k")
    assert list(tmp_path.iterdir()) == []


def test_a_non_ascii_name_is_written_in_utf8_and_its_columns_are_bytes(tmp_path):
    """The deck was opened in the locale's encoding: under an ASCII locale (``LC_ALL=C`` without UTF-8 mode) a part
    named "Stoßfänger" stopped the writer with a UnicodeEncodeError, and on a cp1252 system it went out in a code
    page the reader takes for Latin-1. It is UTF-8 now, as the reader reads first; and a title's 80 columns are 80
    bytes, as a fixed-format reader counts them (50 "ä" are 100 bytes: 40 of them fit)."""
    script = (
        "import sys; from dataclasses import replace; sys.path.insert(0, 'tests');"
        "from test_keyword_writer import _model; from marlcrash.vehicle.keyword_writer import write_deck;"
        "m = _model(); m.parts = {k: replace(p, name=%s) if k == 10 else p for k, p in m.parts.items()};"
        f"write_deck(m, {str(tmp_path / 'c.k')!r})"
    ) % ascii("Stoßfänger 前")  # the command line itself in ASCII, as the locale wants
    env = {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, "-X", "utf8=0", "-c", script], cwd=REPO, env=env, capture_output=True)
    assert run.returncode == 0, run.stderr.decode(errors="replace")[-400:]
    back = read_deck(tmp_path / "c.k", subassemblies=tmp_path / "c.subassemblies.yaml")
    assert back.parts[10].name == "Stoßfänger 前"
    m = _model()
    m.materials = {k: replace(x, name="ä" * 50) if k == 1 else x for k, x in m.materials.items()}
    with pytest.warns(UserWarning, match=r"material 1: its title 'ä{50}' is cut to its 80 columns: it reads back as"):
        deck = write_deck(m, tmp_path / "d.k")
    lines = deck.read_bytes().splitlines()
    assert lines[lines.index(b"*MAT_ELASTIC_TITLE+") + 1] == ("ä" * 40).encode()
    assert read_deck(deck, subassemblies=tmp_path / "d.subassemblies.yaml").materials[1].name == "ä" * 40


def test_parts_that_share_a_section_keep_it_and_one_whose_values_differ_is_named(tmp_path):
    """LS-DYNA lets parts share a *SECTION card. The writer gave every part its own, so the second of two parts
    sharing section 10 read back with section 14, unsaid, where the deck could have carried the shared id. Parts
    whose section values agree share the card now; one whose values differ gets a fresh id, with a warning."""
    m = _model()
    m.parts = {**m.parts, 11: replace(m.parts[11], section_id=10, thickness=1.7e-3)}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the cards carry the shared section
        deck = write_deck(m, tmp_path / "c.k")
    back = read_deck(deck, subassemblies=tmp_path / "c.subassemblies.yaml")
    _same(m, back)
    assert deck.read_text().count("*SECTION_SHELL") == 1
    m.parts = {**m.parts, 11: replace(m.parts[11], thickness=2.25e-3)}
    with pytest.warns(UserWarning, match=r"part 11: its section 10 \(shared with part 10, whose section values differ"
                                         r"\) is written as section 14"):  # fmt: skip
        deck = write_deck(m, tmp_path / "d.k")
    back = read_deck(deck, subassemblies=tmp_path / "d.subassemblies.yaml")
    assert back.parts[10].section_id == 10 and back.parts[11].section_id == 14
    assert back.parts[11].thickness == pytest.approx(2.25e-3, rel=1e-12)
