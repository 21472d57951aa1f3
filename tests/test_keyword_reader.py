"""The LS-DYNA keyword reader: formats, cards, parameters, includes, errors."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from marlcrash.errors import ConfigError, DeckError
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.model import AxisMap
from marlcrash.vehicle.subassembly_map import dump_subassembly_map, load_subassembly_map
from marlcrash.vehicle.summary import format_vehicle_summary, vehicle_summary

HEAD = """*KEYWORD
*TITLE
test deck
*PART
front plate
         1         1         1
*SECTION_SHELL
         1         2
       2.0       2.0       2.0       2.0
*MAT_ELASTIC
         1  7.85e-09  210000.0       0.3
"""
NODES = """*NODE
       1
       2           100.0
       3           100.0           100.0
       4                           100.0
"""
SHELL = """*ELEMENT_SHELL
       1       1       1       2       3       4
"""


def _write(tmp_path, text, name="deck.k"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return read_deck(path, **kw)


def test_minimal_fixed_deck_in_si(tmp_path):
    m = _read(_write(tmp_path, HEAD + NODES + SHELL + "*END\n"))
    assert m.name == "test deck" and m.units == "mm-t-s"
    assert m.n_nodes == 4 and m.n_shells == 1
    np.testing.assert_allclose(m.bounds(), [[0, -0.05, 0], [0.1, 0.05, 0]])  # shifted: front x = 0, centred y
    assert m.shell_thickness[0] == pytest.approx(2e-3)
    # 0.1 m x 0.1 m x 2 mm x 7850 kg/m^3
    assert m.total_mass() == pytest.approx(0.01 * 2e-3 * 7850, rel=1e-12)
    assert m.subassemblies == {"part_1": [1]}
    assert m.materials[1].kind == "elastic" and m.materials[1].youngs_modulus == pytest.approx(2.1e11)


def test_free_long_i10_and_mixed_formats_agree(tmp_path):
    ref = _read(_write(tmp_path, HEAD + NODES + SHELL))
    free_nodes = "*NODE\n1,0,0,0\n2,100.0\n       3           100.0           100.0\n4,,100\n"
    m_free = _read(_write(tmp_path, HEAD + free_nodes + "*ELEMENT_SHELL\n1,1,1,2,3,4\n", "free.k"))
    long_nodes = "*NODE +\n" + "".join(
        f"{i:20d}{x:20.4f}{y:20.4f}{0.0:20.4f}\n" for i, x, y in ((1, 0, 0), (2, 100, 0), (3, 100, 100), (4, 0, 100))
    )
    long_shell = "*ELEMENT_SHELL+\n" + "".join(f"{v:20d}" for v in (1, 1, 1, 2, 3, 4)) + "\n"
    m_long = _read(_write(tmp_path, HEAD + long_nodes + long_shell, "long.k"))
    glob_long = "*KEYWORD LONG=Y\n" + HEAD.replace("*KEYWORD\n", "").replace(
        "\n         1         1         1", "\n" + "".join(f"{1:20d}" for _ in range(3))
    )
    glob_long = glob_long.replace(
        "         1         2\n       2.0       2.0       2.0       2.0", f"{1:20d}{2:20d}\n" + f"{2.0:20.1f}" * 4
    )
    glob_long = glob_long.replace(
        "         1  7.85e-09  210000.0       0.3", f"{1:20d}{7.85e-9:20.3e}{210000.0:20.1f}{0.3:20.2f}"
    )
    m_glob = _read(_write(tmp_path, glob_long + long_nodes.replace(" +", "") + long_shell.replace("+", ""), "glob.k"))
    i10 = "*NODE %\n" + "".join(
        f"{i:10d}{x:16.4f}{y:16.4f}{0.0:16.4f}\n" for i, x, y in ((1, 0, 0), (2, 100, 0), (3, 100, 100), (4, 0, 100))
    )
    m_i10 = _read(
        _write(
            tmp_path, HEAD + i10 + "*ELEMENT_SHELL%\n" + "".join(f"{v:10d}" for v in (1, 1, 1, 2, 3, 4)) + "\n", "i10.k"
        )
    )
    for m in (m_free, m_long, m_glob, m_i10):
        np.testing.assert_array_equal(m.node_ids, ref.node_ids)
        np.testing.assert_allclose(m.coords, ref.coords)
        np.testing.assert_array_equal(m.shell_nodes, ref.shell_nodes)
        assert m.total_mass() == pytest.approx(ref.total_mass())


def test_an_include_suffix_sets_the_format_of_the_included_file(tmp_path):
    """LS-DYNA reads an include file in the including deck's format unless the *INCLUDE keyword has a format suffix
    ('+' long, '%' I10, '-' standard), which then holds for the whole included file. The suffix was ignored: a
    long-format file under '*INCLUDE +' was read in 8/16-column fields."""
    ref = _read(_write(tmp_path, HEAD + NODES + SHELL))
    xy = ((1, 0, 0), (2, 100, 0), (3, 100, 100), (4, 0, 100))
    long_mesh = "*KEYWORD\n*NODE\n" + "".join(f"{i:20d}{x:20.4f}{y:20.4f}{0.0:20.4f}\n" for i, x, y in xy)
    long_mesh += "*ELEMENT_SHELL\n" + "".join(f"{v:20d}" for v in (1, 1, 1, 2, 3, 4)) + "\n"
    _write(tmp_path, long_mesh, "long_mesh.k")
    i10_mesh = "*KEYWORD\n*NODE\n" + "".join(f"{i:10d}{x:16.4f}{y:16.4f}{0.0:16.4f}\n" for i, x, y in xy)
    i10_mesh += "*ELEMENT_SHELL\n" + "".join(f"{v:10d}" for v in (1, 1, 1, 2, 3, 4)) + "\n"
    _write(tmp_path, i10_mesh, "i10_mesh.k")
    _write(tmp_path, "*KEYWORD\n" + NODES + SHELL, "std_mesh.k")
    long_head = "*KEYWORD LONG=Y\n" + HEAD.replace("*KEYWORD\n", "").replace(
        "\n         1         1         1", "\n" + "".join(f"{1:20d}" for _ in range(3))
    ).replace(
        "         1         2\n       2.0       2.0       2.0       2.0", f"{1:20d}{2:20d}\n" + f"{2.0:20.1f}" * 4
    )
    long_head = long_head.replace(
        "         1  7.85e-09  210000.0       0.3", f"{1:20d}{7.85e-9:20.3e}{210000.0:20.1f}{0.3:20.2f}"
    )
    for name, deck in (
        ("long.k", HEAD + "*INCLUDE +\nlong_mesh.k\n*END\n"),
        ("i10.k", HEAD + "*INCLUDE%\ni10_mesh.k\n*END\n"),
        ("std.k", long_head + "*INCLUDE -\nstd_mesh.k\n*END\n"),
    ):
        m = _read(_write(tmp_path, deck, name))
        np.testing.assert_allclose(m.coords, ref.coords, err_msg=name)
        assert m.n_shells == 1 and m.total_mass() == pytest.approx(ref.total_mass()), name


def test_fast_and_slow_paths_agree_on_a_large_block(tmp_path):
    rng = np.random.default_rng(0)
    n = 3000
    xyz = rng.uniform(-2000, 2000, (n, 3))
    lines = [f"{i + 1:8d}{x:16.6f}{y:16.6f}{z:16.6f}" for i, (x, y, z) in enumerate(xyz)]
    lines[17] = f"18,{float(xyz[17, 0])!r},{float(xyz[17, 1])!r},{float(xyz[17, 2])!r}"  # free format in a fixed block
    lines[2500] = f"{2501:8d}{'1.5D+02':>16}{xyz[2500, 1]:16.6f}"  # Fortran exponent and blank z: per-line parser
    lines.insert(1000, "$ a comment inside the block")
    lines.insert(2000, "")
    shells = "".join(f"{k + 1:8d}{1:8d}{k + 1:8d}{k + 2:8d}{k + 3:8d}{k + 3:8d}\n" for k in range(n - 3))
    deck = HEAD + "*NODE\n" + "\n".join(lines) + "\n*ELEMENT_SHELL\n" + shells
    m = _read(_write(tmp_path, deck))
    assert m.n_nodes == n and m.n_shells == n - 3
    # an independent per-line read with Python float()
    expect = np.array(
        [
            [float(t) for t in ln.split(",")[1:]]
            if "," in ln
            else [
                float(ln[a:b].replace("D", "E")) if ln[a:b].strip() else 0.0 for a, b in ((8, 24), (24, 40), (40, 56))
            ]
            for ln in lines
            if ln and not ln.startswith("$")
        ]
    )
    assert expect[2500, 0] == 150.0 and expect[2500, 2] == 0.0
    np.testing.assert_allclose((m.coords - m.coords[0]) * 1000, expect - expect[0], rtol=0, atol=1e-9)


def test_parameters_and_references(tmp_path):
    deck = """*KEYWORD
*PARAMETER
R tbumper 3.0
Ithree     3
*PARAMETER_EXPRESSION
R twice    tbumper*2 + sqrt(4) - 2
*PART
p
         1         1         1
*SECTION_SHELL
         1         2
&twice,&twice,&twice,&twice
*MAT_ELASTIC
         1  7.85e-09  210000.0       0.3
*NODE
       1
       2      &tbumper
       3           100.0         -&tsize
       4
*ELEMENT_SHELL
       1       1       1       2  &three
"""
    p = _write(tmp_path, deck)
    with pytest.raises(DeckError, match=r"deck.k line 18: parameter 'tsize' is used but not defined"):
        _read(p)
    m = _read(p, params={"tsize": 50})
    assert m.shell_thickness[0] == pytest.approx(6e-3)
    np.testing.assert_allclose(m.coords[1] - m.coords[0], [3e-3, 0, 0])
    assert m.coords[2, 1] - m.coords[0, 1] == pytest.approx(-0.05)  # y field of node 3
    m2 = _read(p, params={"tsize": 50, "tbumper": 4.0})  # params= override the deck, recorded
    assert m2.shell_thickness[0] == pytest.approx(8e-3)
    assert any("overridden" in w for w in m2.warnings)
    # a name the deck neither defines nor uses (a typo: 'tbumper' would keep its deck value) is refused
    with pytest.raises(DeckError, match=r"deck.k: parameter\(s\) 'tbumpr' given .* its parameters: .*tbumper"):
        _read(p, params={"tsize": 50, "tbumpr": 4.0})


def _part_with_shell(pid: int, thickness: str) -> str:
    """Part ``pid`` (section and element ``pid``) of one shell on four nodes of its own, ``thickness`` a field."""
    n = 4 * pid
    nodes = "".join(f"{n + k},{100.0 * k},{10.0 * pid},0\n" for k in range(4))
    return (
        f"*PART\npart {pid}\n{pid},{pid},1\n*SECTION_SHELL\n{pid},2\n{thickness},{thickness},{thickness},"
        f"{thickness}\n*NODE\n{nodes}*ELEMENT_SHELL\n{pid},{pid},{n},{n + 1},{n + 2},{n + 3}\n"
    )


def test_local_parameters_hold_in_their_file_and_its_includes(tmp_path):
    """Two component files each define their own ``t`` with ``*PARAMETER_LOCAL`` (1 and 2 mm) beside the deck's
    ``*PARAMETER`` t = 5 mm: each file's parts, and those of the files it includes, take its own value; a
    ``*PARAMETER_EXPRESSION_LOCAL`` and a global expression written in a component see that component's ``t``.
    Read as global, every part took the first definition's 5 mm (two notes said the later ones were ignored)."""
    _write(tmp_path, "*KEYWORD\n" + _part_with_shell(3, "&t"), "sub_a.k")
    comp_a = "*KEYWORD\n*PARAMETER_LOCAL\nR t,1.0\n*PARAMETER_EXPRESSION\nR tg,t*10\n" + _part_with_shell(2, "&t")
    _write(tmp_path, comp_a + "*INCLUDE\nsub_a.k\n", "comp_a.k")
    comp_b = "*KEYWORD\n*PARAMETER_LOCAL\nR t,2.0\n*PARAMETER_EXPRESSION_LOCAL\nR t2,t*2\n"
    _write(tmp_path, comp_b + _part_with_shell(4, "&t") + _part_with_shell(5, "&t2"), "comp_b.k")
    main = (
        "*KEYWORD\n*PARAMETER\nR t,5.0\n*MAT_ELASTIC\n1,7.85e-09,210000.0,0.3\n"
        + _part_with_shell(1, "&t") + _part_with_shell(6, "&tg") + "*INCLUDE\ncomp_a.k\n*INCLUDE\ncomp_b.k\n"
    )  # fmt: skip
    m = _read(_write(tmp_path, main))
    by_part = dict(zip(m.shell_part.tolist(), (m.shell_thickness * 1e3).tolist(), strict=True))
    assert by_part == pytest.approx({1: 5.0, 2: 1.0, 3: 1.0, 4: 2.0, 5: 4.0, 6: 10.0})
    assert not any("defined again" in w for w in m.warnings)
    # a local name in one component is not the other's: used there without a definition, it is refused
    _write(tmp_path, "*KEYWORD\n" + _part_with_shell(7, "&t2"), "comp_c.k")
    with pytest.raises(DeckError, match=r"comp_c.k line \d+: parameter 't2' is used but not defined"):
        _read(_write(tmp_path, main + "*INCLUDE\ncomp_c.k\n", "main_c.k"))
    # params= overrides every definition, local ones too, and says so
    m = _read(_write(tmp_path, main), params={"t": 3.0})
    assert {p: round(t * 1e3, 9) for p, t in zip(m.shell_part.tolist(), m.shell_thickness, strict=True)} == {
        1: 3.0, 2: 3.0, 3: 3.0, 4: 3.0, 5: 6.0, 6: 30.0
    }  # fmt: skip
    assert any("local value 1.0 of comp_a.k overridden by params= 3.0" in w for w in m.warnings)


def test_nested_includes_relative_to_including_file(tmp_path):
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "deeper").mkdir()
    _write(sub / "deeper", "*KEYWORD\n" + SHELL + "*END\nthis line after *END is ignored\n", "elems.k")
    _write(sub, "*KEYWORD\n" + NODES + "*INCLUDE\ndeeper/elems.k\n", "mesh.k")
    m = _read(_write(tmp_path, HEAD + "*INCLUDE\nsub/mesh.k\n"))
    assert m.n_nodes == 4 and m.n_shells == 1
    p = _write(tmp_path, HEAD + "$ comment\n*INCLUDE\nsub/missing.k\n", "bad.k")
    with pytest.raises(DeckError, match=r"bad.k line 14: \*INCLUDE file 'sub/missing.k' not found"):
        _read(p)
    p = _write(tmp_path, HEAD + "*INCLUDE\nsub/deeper\n", "folder.k")
    with pytest.raises(
        DeckError, match=r"folder.k line 13: \*INCLUDE 'sub/deeper' is a folder .*expected a keyword file"
    ):
        _read(p)
    _write(tmp_path, "*KEYWORD\n*INCLUDE\nloop.k\n", "loop.k")
    with pytest.raises(DeckError, match=r"loop.k line 3: \*INCLUDE 'loop.k' makes a cycle: loop.k -> loop.k"):
        _read(tmp_path / "loop.k")
    # a cycle through two files names the chain, not "includes itself"
    _write(tmp_path, "*KEYWORD\n*INCLUDE\nsub/b.k\n", "a.k")
    _write(sub, "*KEYWORD\n$ back up\n*INCLUDE\n../a.k\n", "b.k")
    with pytest.raises(DeckError, match=r"b.k line 4: \*INCLUDE '../a.k' makes a cycle: main.k -> a.k -> b.k -> a.k"):
        _read(_write(tmp_path, HEAD + "*INCLUDE\na.k\n", "main.k"))


def test_an_include_without_a_file_name_is_refused_where_it_stands(tmp_path):
    """An *INCLUDE whose file name card is blank, or missing, read as including nothing: the file meant was silently
    left out of the vehicle. It is refused naming the file and line, as an *INCLUDE_<option> without its name is."""
    cases = {
        "blank.k": (HEAD + NODES + SHELL + "*INCLUDE\n\n*END\n", 20),
        "none.k": (HEAD + NODES + SHELL + "*INCLUDE\n$ the file name was here\n*END\n", 19),
        "last.k": (HEAD + NODES + SHELL + "*INCLUDE\n", 19),
        "option.k": (HEAD + NODES + SHELL + "*INCLUDE_TRANSFORM\n   \n         0         0         0\n", 20),
    }
    for name, (text, line) in cases.items():
        with pytest.raises(DeckError, match=rf"{name} line {line}: \*INCLUDE\w* expects a file name, got "):
            _read(_write(tmp_path, text, name))


def test_an_include_with_a_blank_card_before_its_file_name_reads_the_file(tmp_path):
    """A blank card is skipped among a plain *INCLUDE's file names (only an *INCLUDE_<option>, whose first card must
    be the name, is refused at it). The name-reading helper's ``first`` flag was shadowed by a loop variable, so a
    plain *INCLUDE was refused too: 'expects a file name, got a blank card' for a deck that names its file."""
    _write(tmp_path, "*KEYWORD\n" + SHELL, "elems.k")
    m = _read(_write(tmp_path, HEAD + NODES + "*INCLUDE\n\nelems.k\n*END\n"))
    assert m.shell_part.tolist() == [1]


def test_shell_thickness_rules_and_triangles(tmp_path):
    nodes = NODES + "       5           200.0\n"
    shells = """*ELEMENT_SHELL_THICKNESS
       1       1       1       2       3       4
           0.000           0.000           0.000           0.000
       2       1       2       5       3       3
             1.0             2.0             3.0            99.0
       3       1       1       2       3
             1.0             1.0             1.0             3.0
"""
    m = _read(
        _write(
            tmp_path, HEAD.replace("       2.0       2.0       2.0       2.0", "       2.0       4.0") + nodes + shells
        )
    )
    # section: t1=2, t2=4, t3=t4 default to t1 -> mean 2.5; element 0 -> section
    assert m.parts[1].thickness == pytest.approx(2.5e-3)
    np.testing.assert_allclose(m.shell_thickness, [2.5e-3, 2e-3, 1e-3])  # triangles use THIC1..3
    assert m.shell_nodes[2, 3] == m.shell_nodes[2, 2]  # blank n4 -> triangle
    # tri area 0.5 * 0.1 * 0.1
    assert m.element_masses()["shell"][1] == pytest.approx(0.005 * 2e-3 * 7850)


def test_solids_beams_and_sections(tmp_path):
    deck = """*KEYWORD
*PART
block
         1         1         1
*SECTION_SOLID_TITLE
brick
         1         1
*PART
bar
         2         2         1
*SECTION_BEAM
         2         2
      50.0
*PART
tube
         3         3         1
*SECTION_BEAM
         3         1       1.0       2.0       1.0
      20.0      20.0      10.0      10.0
*MAT_PLASTIC_KINEMATIC_TITLE
steel
         1  7.85e-09  200000.0       0.3     300.0    2000.0
       0.0       0.0       0.2
*NODE
1,0,0,0
2,10,0,0
3,10,10,0
4,0,10,0
5,0,0,10
6,10,0,10
7,10,10,10
8,0,10,10
9,20,0,0
*ELEMENT_SOLID
       1       1       1       2       3       4       5       6       7       8
       2       1       2       9       3       6
*ELEMENT_SOLID
       3       1
       1       2       4       5       0       0       0       0       0       0
*ELEMENT_BEAM
       4       2       1       9
       5       3       1       9
*ELEMENT_BEAM_THICKNESS
       6       2       2       9
            75.0
"""
    m = _read(_write(tmp_path, deck))
    vol = m.solid_volumes()
    np.testing.assert_allclose(vol, [1e-6, 1e-6 / 6, 1e-6 / 6], rtol=1e-12)
    np.testing.assert_allclose(m.beam_area, [50e-6, math.pi / 4 * (20**2 - 10**2) * 1e-6, 75e-6])
    mat = m.materials[1]
    assert mat.name == "steel" and mat.kind == "plastic_kinematic"
    eh = 200000.0 * 2000.0 / (200000.0 - 2000.0)
    assert mat.ultimate_strength == pytest.approx((300.0 + eh * 0.2) * 1e6)
    assert mat.fracture_strength == pytest.approx(mat.ultimate_strength)
    assert mat.shear_modulus == pytest.approx(2e11 / 2.6)


@pytest.mark.parametrize("kind", ["solid", "beam"])
def test_user_element_cards_after_a_section_are_not_read_as_sections(tmp_path, kind):
    # ELFORM 101-105: the integration card (NIP, NXDOF, ...) and NIP integration point cards follow the section
    # cards; read as sections they defined section 2 (then a clash with part 2's) or ran out of cards
    if kind == "solid":
        section = "*SECTION_SOLID\n         3       101\n"
        user = "         1" + "         0" * 6 + "\n       0.0       0.0       0.0       8.0\n"
    else:
        section = "*SECTION_BEAM\n         3       101       1.0\n      50.0\n"
        user = "         2" + "         0" * 7 + "\n       0.5       0.5       1.0\n      -0.5      -0.5       1.0\n"
    deck = (
        HEAD
        + f"*PART\nuser part\n         3         3         1\n{section}{user}"
        + ("*PART\nsecond\n         2         2         1\n*SECTION_SHELL\n         2\n       1.0\n")
        + NODES
        + SHELL
        + "*ELEMENT_SHELL\n       2       2       1       2       3       4\n*END\n"
    )
    m = _read(_write(tmp_path, deck))
    assert sorted(m.parts) == [1, 2, 3] and m.parts[3].section_id == 3
    np.testing.assert_allclose(m.shell_thickness, [2e-3, 1e-3])


def test_material_cards(tmp_path):
    mats = """*MAT_PIECEWISE_LINEAR_PLASTICITY
         1  7.85e-09  210000.0       0.3     250.0       0.0      0.25
       0.0       0.0         0
       0.0       0.1       0.2       0.3
     250.0     350.0     420.0     400.0
*MAT_024_TITLE
curve driven
         2  7.85e-09  210000.0       0.3       0.0       0.0       0.0
       0.0       0.0        77
*DEFINE_CURVE
        77                 1.0    1000.0
                 0.0                0.30
                 0.5                0.45
*MAT_RIGID
         3  7.85e-09  210000.0       0.3
*MAT_HONEYCOMB
         4  1.00e-10    1000.0      0.01
*MAT_NULL
         5  1.00e-09       0.0       0.0       0.0       0.0    5000.0      0.25
*MAT_ADD_EROSION
         1
"""
    parts = "".join(f"*PART\np{i}\n{i:10d}{1:10d}{i:10d}\n" for i in range(1, 6))
    base = "*KEYWORD\n*SECTION_SHELL\n         1\n       1.0\n*NODE\n1\n2,1\n3,1,1\n"
    shells = "*ELEMENT_SHELL\n" + "".join(f"{i:8d}{i:8d}       1       2       3\n" for i in range(1, 6))
    with pytest.warns(UserWarning, match=r"skipped 1 card\(s\).*\*MAT_ADD_EROSION x1") as rec:
        m = read_deck(_write(tmp_path, base + parts + mats + shells))
    assert len([r for r in rec if "skipped" in str(r.message)]) == 1
    assert m.skipped_cards == {"MAT_ADD_EROSION": 1}
    a, b, r, h, n = (m.materials[i] for i in range(1, 6))
    assert (a.kind, b.kind, r.kind, h.kind, n.kind) == (
        "piecewise_linear",
        "piecewise_linear",
        "rigid",
        "other",
        "other",
    )
    assert a.yield_strength == pytest.approx(250e6) and a.ultimate_strength == pytest.approx(420e6)
    assert a.fracture_strength == pytest.approx(np.interp(0.25, [0, 0.1, 0.2, 0.3], [250, 350, 420, 400]) * 1e6)
    assert b.name == "curve driven"
    assert b.yield_strength == pytest.approx(300e6) and b.ultimate_strength == pytest.approx(450e6)
    assert h.density == pytest.approx(100.0) and h.youngs_modulus == pytest.approx(1e9)
    assert n.youngs_modulus == pytest.approx(5e9) and n.poisson_ratio == 0.25
    assert r.is_rigid
    # a negative yield stress is refused where it is written, not replaced by a default
    kinematic = (
        "*MAT_PLASTIC_KINEMATIC\n         1  7.85e-09  210000.0       0.3    -250.0\n       0.0       0.0       0.2\n"
    )
    with pytest.raises(DeckError, match=r"deck.k line 13: material 1 .*yield strength must be > 0 .*got -2.5e\+08 Pa"):
        read_deck(_write(tmp_path, base + "*PART\np1\n         1         1         1\n" + kinematic + shells[:59]))


def test_an_explicit_poisson_ratio_of_zero_is_read_as_zero_and_a_blank_one_defaulted(tmp_path):
    """An explicit PR 0.0 (LS-DYNA takes it as 0: foams, honeycombs) was defaulted to 0.3 like a blank field."""
    zero = HEAD.replace("210000.0       0.3", "210000.0       0.0")
    m = _read(_write(tmp_path, zero + NODES + SHELL + "*END\n"))
    assert m.materials[1].poisson_ratio == 0.0 and not any("Poisson" in w for w in m.warnings)
    assert m.materials[1].shear_modulus == pytest.approx(2.1e11 / 2)
    blank = HEAD.replace("210000.0       0.3", "210000.0")
    m = _read(_write(tmp_path, blank + NODES + SHELL + "*END\n", "blank.k"))
    assert m.materials[1].poisson_ratio == 0.3
    assert any("material 1 (MAT_ELASTIC): Poisson's ratio missing, defaulted to 0.3" in w for w in m.warnings)


def test_curve_offsets_apply_before_the_scale_factors(tmp_path):
    """*DEFINE_CURVE scales after the offsets (LS-DYNA manual, *DEFINE_CURVE remark 1): abscissa SFA (x + OFFA),
    ordinate SFO (y + OFFO). The reader took x SFA + OFFA and y SFO + OFFO, the same only where an offset is 0."""
    curve = """*MAT_024
         1  7.85e-09  210000.0       0.3       0.0       0.0       0.4
       0.0       0.0        77
*DEFINE_CURVE_TITLE
scaled and offset
        77         0       2.0    1000.0      0.05       0.1
                 0.0                0.25
                 0.1                0.35
                 0.2                0.45
"""
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", curve) + NODES + SHELL
    mat = _read(_write(tmp_path, deck)).materials[1]
    x, y = 2.0 * (np.array([0.0, 0.1, 0.2]) + 0.05), 1000.0 * (np.array([0.25, 0.35, 0.45]) + 0.1)  # 0.1..0.5, 350..550
    assert mat.yield_strength == pytest.approx(y[0] * 1e6)
    assert mat.ultimate_strength == pytest.approx(y[-1] * 1e6)
    assert mat.fracture_strength == pytest.approx(np.interp(0.4, x, y) * 1e6)  # FAIL 0.4 on the scaled abscissa


def test_a_curve_defined_twice_is_refused(tmp_path):
    """Two *DEFINE_CURVE of one LCID: the last silently replaced the first, so an LCSS stress-strain curve could be
    another than the one meant; refused naming both, as duplicate material and section ids are (and as LS-DYNA does)."""
    mat = "*MAT_024\n         1  7.85e-09  210000.0       0.3\n       0.0       0.0        77\n"
    curves = "*DEFINE_CURVE\n        77\n0.0,300.0\n1.0,400.0\n*DEFINE_CURVE_TITLE\nagain\n        77\n0.0,100.0\n"
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", mat + curves) + NODES + SHELL
    with pytest.raises(
        DeckError, match=r"deck.k line 19: \*DEFINE_CURVE_TITLE LCID 77 is defined twice \(first in deck.k line 14\)"
    ):
        _read(_write(tmp_path, deck))


@pytest.mark.parametrize(
    "curve",
    [
        "       0.0       0.0        77\n*DEFINE_CURVE\n        77\n0.0,300.0\n0.1,350.0\n0.5,400.0\n",
        "       0.0       0.0         0\n       0.0       0.1       0.5\n     300.0     350.0     400.0\n",
    ],
    ids=["lcss", "eps-es"],
)
def test_sigy_is_ignored_where_a_curve_gives_the_yield(tmp_path, curve):
    """LS-DYNA ignores *MAT_024's SIGY where LCSS or the EPS/ES points give the curve: the yield is its first point.
    A SIGY left beside a curve (common in decks) was read as the yield strength."""
    mat = "*MAT_024\n         1  7.85e-09  210000.0       0.3     200.0\n" + curve
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", mat) + NODES + SHELL
    m = _read(_write(tmp_path, deck)).materials[1]
    assert m.yield_strength == pytest.approx(300e6) and m.ultimate_strength == pytest.approx(400e6)


_MAT024_LCSS = "*MAT_024\n         1  7.85e-09  210000.0       0.3     200.0\n       0.0       0.0         7\n"


def _curve(lcid: int, stress: float) -> str:
    return f"*DEFINE_CURVE\n{lcid:>10}\n0.0,{stress}\n0.5,{stress + 100.0}\n"


@pytest.mark.parametrize(
    ("table", "rate"),
    [
        (
            "*DEFINE_TABLE\n         7\n0.001\n1.0\n100.0\n"
            + _curve(101, 300.0)
            + _curve(102, 330.0)
            + _curve(103, 380.0),
            "0.001/s, LCID 101",
        ),
        (
            "*DEFINE_TABLE_TITLE\nln rates\n         7       1.0\n-6.907755\n0.0\n4.60517\n"
            + _curve(101, 300.0)
            + _curve(102, 330.0)
            + _curve(103, 380.0),
            "0.001/s, LCID 101",
        ),  # a first value < 0: ln(strain rate)
        (
            _curve(102, 330.0) + _curve(101, 300.0) + "*DEFINE_TABLE_2D\n         7\n0.001,101\n1.0,102\n",
            "0.001/s, LCID 101",
        ),
    ],
    ids=["table", "ln-rates", "table-2d"],
)
def test_an_lcss_table_of_strain_rates_gives_its_lowest_rates_curve(tmp_path, table, rate):
    """*MAT_024 LCSS naming a *DEFINE_TABLE (a curve per strain rate, the common form in crash decks) fell back to
    SIGY and ETAN with a note ('not a *DEFINE_CURVE'): 200 MPa and no hardening where the deck's quasi-static curve
    says 300 to 400 MPa. The curve of the table's lowest rate is read (the cells' eta carries rate effects), with a
    note; the curves of a *DEFINE_TABLE are the *DEFINE_CURVE keywords right after it, as LS-DYNA reads them."""
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", _MAT024_LCSS + table)
    m = _read(_write(tmp_path, deck + NODES + SHELL))
    assert m.materials[1].yield_strength == pytest.approx(300e6)
    assert m.materials[1].ultimate_strength == pytest.approx(400e6)
    assert any("LCSS 7 is a *DEFINE_TABLE of" in w and f"the lowest ({rate})" in w for w in m.warnings), m.warnings


@pytest.mark.parametrize(
    ("table", "after", "pattern"),
    [
        (
            "*DEFINE_TABLE\n         7\n0.001\n1.0\n" + _curve(101, 300.0),
            "",
            r"deck.k line 14: \*DEFINE_TABLE 7 lists 2 values but 1 \*DEFINE_CURVE follow it before \*NODE \(deck.k "
            r"line 21\); LS-DYNA reads a table's curves from the keywords right after it",
        ),
        (
            "*DEFINE_TABLE\n         7\n0.001\n1.0\n" + _curve(101, 300.0),
            "_end",
            r"deck.k line 14: \*DEFINE_TABLE 7 lists 2 values but 1 \*DEFINE_CURVE follow it before the end of the "
            r"deck",
        ),
        (
            "*DEFINE_TABLE\n         7\n1.0\n0.001\n" + _curve(101, 300.0) + _curve(102, 330.0),
            "",
            r"deck.k line 16: \*DEFINE_TABLE TBID 7: the values must increase, value 2 is 0.001 after 1",
        ),
        (
            "*DEFINE_TABLE_2D\n         7\n0.001,101\n1.0,102\n" + _curve(101, 300.0),
            "",
            r"deck.k line 14: \*DEFINE_TABLE_2D 7 \(LCSS of material 1\) names curve 102, which the deck does not "
            r"define",
        ),
        (
            _curve(7, 300.0) + "*DEFINE_TABLE_2D\n         7\n0.001,101\n",
            "",
            r"deck.k line 18: \*DEFINE_TABLE_2D TBID 7 is defined twice \(first in deck.k line 14\)",
        ),
        ("*DEFINE_TABLE\n         7\n", "", r"deck.k line 14: \*DEFINE_TABLE TBID 7 lists no value"),
    ],
    ids=["curves-missing", "deck-ends", "values-decrease", "2d-curve-undefined", "id-of-a-curve", "no-values"],
)
def test_a_table_lcss_that_cannot_give_a_curve_is_refused_at_its_line(tmp_path, table, after, pattern):
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", _MAT024_LCSS)
    if after == "_end":  # the table last in the deck, its curves missing
        text = deck + NODES + SHELL + table
        pattern = pattern.replace("line 14", "line 21")
    else:
        text = deck + table + NODES + SHELL
    with pytest.raises(DeckError, match=pattern):
        _read(_write(tmp_path, text))


def test_a_curve_whose_abscissae_decrease_is_refused(tmp_path):
    """An LCSS curve out of order was interpolated as given: FAIL 0.2 on (0, 200), (0.5, 400), (0.1, 300) gave a
    fracture strength of 300 MPa where the ordered curve gives 325 MPa. LS-DYNA refuses such a curve."""
    mat = "*MAT_024\n         1  7.85e-09  210000.0       0.3       0.0       0.0       0.2\n"
    mat += "       0.0       0.0        77\n"
    curve = "*DEFINE_CURVE\n        77\n0.0,200.0\n0.5,400.0\n0.1,300.0\n"
    deck = HEAD.replace("*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n", mat + curve) + NODES + SHELL
    with pytest.raises(
        DeckError,
        match=r"deck.k line 17: \*DEFINE_CURVE LCID 77: the abscissae must not decrease, point 3 has 0.1 after 0.5",
    ):
        _read(_write(tmp_path, deck))


def test_a_negative_fourth_node_is_refused_not_read_as_a_triangle(tmp_path):
    """N4 < 0 (a typo) made a triangle of half the quad's mass without a word; only blank or 0 means a triangle."""
    shell = "*ELEMENT_SHELL\n       1       1       1       2       3      -4\n"
    with pytest.raises(DeckError, match=r"deck.k line 18: \*ELEMENT_SHELL element 1: N4 -4 is no node id"):
        _read(_write(tmp_path, HEAD + NODES + shell))


@pytest.mark.parametrize(
    "keyword", ["ELASTIC_SPRING_DISCRETE_BEAM", "074", "121", "GENERAL_NONLINEAR_6DOF_DISCRETE_BEAM", "146"]
)
def test_discrete_beam_stiffness_is_not_read_as_a_youngs_modulus(tmp_path, keyword):
    """*MAT_074, 119, 121 and 146 give a spring stiffness [force/length] where most materials give E: it was read as a
    Young's modulus of 5e8 Pa (and fed the median that defaults other materials' E and the unit detection)."""
    spring = (
        "*PART\nspring\n         2         2         2\n*SECTION_BEAM\n         2         6\n       1.0\n"
        f"*MAT_{keyword}\n         2  7.85e-09     500.0       0.0\n*ELEMENT_BEAM\n       2       2       1       2\n"
    )
    m = _read(_write(tmp_path, HEAD + spring + NODES + SHELL))
    assert m.materials[2].youngs_modulus == pytest.approx(2.1e11)  # defaulted, not 5e8
    assert any(f"material 2 (*MAT_{keyword}): its first card gives no Young's modulus" in w for w in m.warnings)


def test_skipped_cards_counted_in_one_warning(tmp_path):
    extra = (
        "*CONTROL_TERMINATION\n0.1\n*DATABASE_GLSTAT\n1e-4\n*DATABASE_GLSTAT\n1e-4\n*FOO_BAR\nx\n"
        "*SET_SHELL_LIST\n1\n1\n"
    )
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_deck(_write(tmp_path, HEAD + extra + NODES + SHELL))
    msgs = [str(r.message) for r in rec if issubclass(r.category, UserWarning)]
    assert len(msgs) == 1 and "skipped 5 card(s)" in msgs[0]
    assert m.skipped_cards == {"CONTROL_TERMINATION": 1, "DATABASE_GLSTAT": 2, "FOO_BAR": 1, "SET_SHELL_LIST": 1}


@pytest.mark.parametrize(
    ("body", "pattern"),
    [
        (
            NODES.replace("       2           100.0", "       2           abc  "),
            r"line 14: \*NODE expects a numeric x coordinate in columns 9-24, got 'abc'",
        ),
        (NODES + "       1             1.0\n", r"line 17: node id 1 is defined twice \(first in deck.k line 13\)"),
        (
            NODES.replace("           100.0           100.0", "             nan           100.0"),
            r"line 15: \*NODE expects a finite x coordinate in columns 9-24, got 'nan'",
        ),
        (NODES + SHELL.replace("       4\n", "       9\n"), r"line 18: shell element 1 refers to undefined node 9"),
        (
            NODES + SHELL.replace("       1       1       1", "       1       7       1"),
            r"line 18: shell element 1 refers to undefined part 7",
        ),
        (
            NODES + "*ELEMENT_SHELL\n       1       1       1       2\n",
            r"line 18: \*ELEMENT_SHELL expects node id n3 in columns 33-40, got blank",
        ),
        (
            NODES + "*ELEMENT_SHELL_THICKNESS\n       1       1       1       2       3       4\n",
            r"line 18: \*ELEMENT_SHELL_THICKNESS expects 2 lines per element",
        ),
        (
            NODES + "*ELEMENT_SHELL\n       1     1.5       1       2       3\n",
            r"line 18: .*integer part id in columns 9-16, got '1.5'",
        ),
    ],
)
def test_errors_name_file_line_and_what(tmp_path, body, pattern):
    with pytest.raises(DeckError, match=r"deck.k " + pattern):
        _read(_write(tmp_path, HEAD + body))


@pytest.mark.parametrize("word", ["nan", "inf", "-Infinity", "1e999"])
def test_a_non_finite_number_is_refused_where_it_is_written(tmp_path, word):
    """A field reading as NaN or infinity (a script that wrote ``nan`` into the deck, an exponent typo) is refused
    naming its line and columns. A material's PR or SIGY of 'inf' read as "missing" (NaN is the reader's mark for a
    field not given): defaulted to 0.3 or 0.12 % of E with a note saying the deck had no value."""
    cases = {
        "pr": (
            HEAD.replace("  210000.0       0.3", f"  210000.0{word:>10}"),
            r"line 11: \*MAT_ELASTIC expects a finite PR in columns 31-40",
        ),
        "sigy": (
            HEAD.replace(
                "*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3",
                f"*MAT_024\n         1  7.85e-09  210000.0       0.3{word:>10}",
            ),
            r"line 11: \*MAT_024 expects a finite SIGY in columns 41-50",
        ),
        "param": (
            HEAD.replace("*KEYWORD\n", f"*KEYWORD\n*PARAMETER\nR t       {word:>10}\n"),
            r"line 3: \*PARAMETER expects a R value for 't'",
        ),
    }
    for name, (head, pattern) in cases.items():
        with pytest.raises(DeckError, match=rf"{name}.k {pattern}, got '{re.escape(word)}'"):
            _read(_write(tmp_path, head + NODES + SHELL, f"{name}.k"))
    nodes = NODES.replace("           100.0           100.0", f"{word:>16}           100.0")
    with pytest.raises(DeckError, match=rf"line 15: \*NODE expects a finite x coordinate .*, got '{re.escape(word)}'"):
        _read(_write(tmp_path, HEAD + nodes + SHELL))


def test_reference_errors_on_parts(tmp_path):
    bad_sec = HEAD.replace("         1         1         1", "         1         4         1")
    with pytest.raises(DeckError, match=r"deck.k line 6: \*PART 1 refers to undefined section 4"):
        _read(_write(tmp_path, bad_sec + NODES + SHELL))
    bad_mat = HEAD.replace("         1         1         1", "         1         1         3")
    with pytest.raises(DeckError, match=r"deck.k line 6: \*PART 1 refers to undefined material 3"):
        _read(_write(tmp_path, bad_mat + NODES + SHELL))
    with pytest.raises(DeckError, match="no \\*NODE"):
        _read(_write(tmp_path, HEAD))
    with pytest.raises(DeckError, match="cannot read the deck"):
        _read(tmp_path / "nope.k")
    with pytest.raises(DeckError, match=r"lead.k line 2: expected a keyword line starting with '\*', got data"):
        _read(_write(tmp_path, "$ header\n       5\n" + HEAD + NODES + SHELL, "lead.k"))


def test_units_detection_and_override(tmp_path):
    si = HEAD.replace("  7.85e-09  210000.0", "    7850.0   2.1e+11").replace(
        "       2.0       2.0       2.0       2.0", "     0.002"
    )
    m = _read(_write(tmp_path, si + NODES.replace("100.0", "  0.1") + SHELL))
    assert m.units == "m-kg-s" and m.total_mass() == pytest.approx(0.01 * 2e-3 * 7850)
    mixed = HEAD.replace("  7.85e-09  210000.0", "       1.0   2.1e+11")
    with pytest.raises(DeckError, match=r"give it: --units on the command line, units= in Python, one of"):
        _read(_write(tmp_path, mixed + NODES + SHELL))
    m2 = _read(_write(tmp_path, mixed + NODES.replace("100.0", "  0.1") + SHELL), units="m-kg-s")
    assert m2.materials[1].density == 1.0
    with pytest.raises(DeckError, match=r"spans 100 m, more than any vehicle .* wrong unit system \(read as m-kg-s"):
        _read(_write(tmp_path, mixed + NODES + SHELL), units="m-kg-s")  # millimetres read as metres
    with pytest.raises(ConfigError, match="unknown unit system"):
        _read(_write(tmp_path, HEAD + NODES + SHELL), units="furlongs")


def test_a_material_whose_density_reads_in_another_unit_system_is_named(tmp_path):
    # a steel card pasted from a mm-kg-ms library (RO 7.85e-6 kg/mm^3) into a mm-t-s deck: 1000x the mass
    more = "*PART\nrail\n         2         1         2\n*MAT_ELASTIC\n         2   7.85e-6  210000.0       0.3\n"
    more += (
        "*PART\ncrossmember\n         3         1         3\n*MAT_ELASTIC\n         3    2.7e-9   70000.0      0.33\n"
    )
    shells = (
        SHELL + "       2       2       1       2       3       4\n       3       3       1       2       3       4\n"
    )
    deck = _write(tmp_path, HEAD + more + NODES + shells)
    with pytest.warns(
        UserWarning,
        match=r"material 2 \(\*MAT_ELASTIC\) density RO 7.85e-06 \(deck.k line 16\) as mm-t-s "
        r"is 7\.85e\+06 kg/m\^3, outside .*; as mm-kg-ms it is 7850 kg/m\^3",
    ):
        m = read_deck(deck)
    assert m.units == "mm-t-s" and m.part_masses()[2] == pytest.approx(1000 * m.part_masses()[1])
    assert any("material 2" in w and "mm-kg-ms" in w for w in m.warnings)
    with pytest.warns(UserWarning) as seen:  # the whole deck read in other units: one warning, not one per card
        read_deck(_write(tmp_path, HEAD + NODES + SHELL, "ok.k"), units="mm-kg-ms")
    assert [str(w.message) for w in seen if "density RO" in str(w.message)] == []
    with warnings.catch_warnings():  # a plausible density in the deck's units: no such warning
        warnings.simplefilter("error")
        read_deck(_write(tmp_path, HEAD + NODES + SHELL, "ok.k"))


def test_a_material_whose_modulus_reads_in_another_unit_system_is_named(tmp_path):
    # an SI deck (m-kg-s) with three steel parts, one of whose E was typed in MPa: its wave speed
    # sqrt(E/RO) is 5.2 m/s, 1000x below steel's; the median still picks m-kg-s, and the card was taken silently
    si = HEAD.replace("  7.85e-09  210000.0", "    7850.0   2.1e+11").replace(
        "       2.0       2.0       2.0       2.0", "     0.002"
    )
    more = "".join(
        f"*PART\npart {i}\n{i:10d}         1{i:10d}\n*MAT_PLASTIC_KINEMATIC\n{i:10d}    7850.0{e:>10}       0.3\n\n"
        for i, e in ((2, "2.1e+11"), (3, "210000.0"))
    )
    shells = SHELL + "".join(f"{i:8d}{i:8d}       1       2       3       4\n" for i in (2, 3))
    deck = _write(tmp_path, si + more + NODES.replace("100.0", "  0.1") + shells)
    line = deck.read_text().splitlines().index(f"{3:10d}    7850.0  210000.0       0.3") + 1
    with pytest.warns(
        UserWarning,
        match=rf"material 3 \(\*MAT_PLASTIC_KINEMATIC\) \(deck.k line {line}\): RO 7850 and E 210000 as m-kg-s give "
        r"a wave speed sqrt\(E/RO\) of 5\.172 m/s, outside the 300 to 30000 m/s of metals and structural polymers",
    ):
        m = read_deck(deck)
    assert m.units == "m-kg-s" and m.materials[3].youngs_modulus == 210000.0  # read as written, and said so
    assert any("material 3" in w and "wave speed" in w for w in m.warnings)
    assert [w for w in m.warnings if "wave speed" in w and "material 3" not in w] == []
    for units in ("m-kg-s", None):  # the same deck with E right: no such warning, given or detected units
        fixed = _write(tmp_path, deck.read_text().replace("  210000.0       0.3", "   2.1e+11       0.3"), "ok.k")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert read_deck(fixed, units=units).units == "m-kg-s"


def test_axis_map_rotates_then_shifts(tmp_path):
    m = _read(_write(tmp_path, HEAD + NODES + SHELL), axis_map=AxisMap(x="-y", y="+x", z="+z"))
    b = m.bounds()
    np.testing.assert_allclose(b, [[0, -0.05, 0], [0.1, 0.05, 0]], atol=1e-15)


def test_given_units_under_which_no_density_is_a_structural_materials_are_named(tmp_path):
    # a density that is no structural material's in any known system (RO typed 1000x too small in a mm-t-s deck);
    # given as mm-t-s it weighs 1/1000 of steel, read as asked and said so
    typo = HEAD.replace("  7.85e-09  210000.0", "  7.85e-12  210000.0")
    with pytest.warns(
        UserWarning,
        match=r"units mm-t-s given, but the material densities \(median 7.85e-12\) read as "
        r"7\.85 kg/m\^3 in it, outside the structural materials' 100 to 150000 kg/m\^3: .*\(the reader knows "
        r"mm-t-s, mm-kg-ms, m-kg-s, mm-g-ms, cm-g-us, in-lbf-s only",
    ):
        m = read_deck(_write(tmp_path, typo + NODES + SHELL), units="mm-t-s")
    assert m.total_mass() == pytest.approx(0.01 * 2e-3 * 7.85)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_deck(_write(tmp_path, HEAD + NODES + SHELL, "ok.k"), units="mm-t-s")


# The same 100 mm x 100 mm x 2 mm steel plate (SI: 7850 kg/m^3, 210 GPa, mass 0.157 kg) written in each unit
# system a crash deck uses, with the conversion factors typed from their definitions (not taken from
# marlcrash.units): length unit [m], density unit [kg/m^3], stress unit [Pa].
_PSI = 4.4482216152605 / 0.0254**2
_PLATE_IN = {
    "mm-t-s": (1e-3, 1e12, 1e6),  # t/mm^3 = 1e3 kg / 1e-9 m^3; MPa
    "mm-kg-ms": (1e-3, 1e9, 1e9),  # kg/mm^3; kN/mm^2 = GPa
    "m-kg-s": (1.0, 1.0, 1.0),
    "mm-g-ms": (1e-3, 1e6, 1e6),  # g/mm^3; g/(mm ms^2) = 1e-3 kg / (1e-3 m 1e-6 s^2) = MPa
    "cm-g-us": (1e-2, 1e3, 1e11),  # g/cm^3; Mbar
    "in-lbf-s": (0.0254, 4.4482216152605 / 0.0254**4, _PSI),  # (lbf s^2/in)/in^3; psi
}


@pytest.mark.parametrize("units", list(_PLATE_IN))
def test_every_unit_system_is_detected_and_read_to_the_same_plate(tmp_path, units):
    length, density, stress = _PLATE_IN[units]
    fields = f"{7850.0 / density:10.4g}{2.1e11 / stress:10.4g}"
    deck = HEAD.replace("  7.85e-09  210000.0", fields).replace(
        "       2.0       2.0       2.0       2.0", "".join(f"{0.002 / length:10.5g}" for _ in range(4))
    )
    nodes = NODES.replace("100.0", f"{0.1 / length:5.4g}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing odd about any of them
        m = read_deck(_write(tmp_path, deck + nodes + SHELL))
    assert m.units == units
    assert m.total_mass() == pytest.approx(0.1 * 0.1 * 0.002 * 7850, rel=1e-3)
    np.testing.assert_allclose(m.bounds(), [[0, -0.05, 0], [0.1, 0.05, 0]], atol=1e-6)
    assert m.materials[1].youngs_modulus == pytest.approx(2.1e11, rel=1e-3)


def test_a_mm_g_ms_deck_given_as_mm_kg_ms_is_named(tmp_path):
    gms = HEAD.replace("  7.85e-09  210000.0", "   7.85e-3  210000.0")  # steel in g/mm^3 and MPa
    with pytest.warns(UserWarning, match=r"units mm-kg-ms given, but the material densities .* read as mm-g-ms"):
        m = read_deck(_write(tmp_path, gms + NODES + SHELL), units="mm-kg-ms")
    assert m.total_mass() == pytest.approx(1000 * 0.01 * 2e-3 * 7850)  # read as asked, and said so


def test_initial_velocities_that_move_the_vehicle_other_than_front_first_are_named(tmp_path):
    def deck(vx, vy, name):
        vel = "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{vx:10.1f}{vy:10.1f}\n" for n in (1, 2, 3, 4))
        return _write(tmp_path, HEAD + NODES + SHELL + vel, name)

    def travel_warnings(path, **kw):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            read_deck(path, **kw)
        return [str(w.message) for w in seen if "front first" in str(w.message)]

    assert travel_warnings(deck(-15640.0, 0.0, "ahead.k")) == []  # x rearward: the vehicle moves along -x
    (msg,) = travel_warnings(deck(15640.0, 0.0, "back.k"))  # its rear would be read as its front
    assert re.search(r"back.k line 20: the deck's initial velocities move the vehicle along deck \+x, marlcrash \+x "
                     r"under the axis map .*smallest x.*--axis-map x=-x,y=-y,z=\+z", msg), msg  # fmt: skip
    assert travel_warnings(deck(15640.0, 0.0, "back.k"), axis_map=AxisMap(x="-x", y="-y")) == []
    (msg,) = travel_warnings(deck(0.0, 15640.0, "side.k"))
    assert "along deck +y, marlcrash +y" in msg and "--axis-map x=-y,y=+x,z=+z" in msg
    assert travel_warnings(deck(0.0, 15640.0, "side.k"), axis_map=AxisMap(x="-y", y="+x")) == []


@pytest.mark.parametrize(
    "cards",
    [
        # ICID, the eighth field: the velocity is in local system 7, whose x is the deck's -x (the vehicle moves
        # front first); read as global it looked like +x travel and drew a wrong --axis-map advice
        "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{15640.0:10.1f}{'':50}{7:10d}\n" for n in (1, 2, 3, 4)),
        f"*INITIAL_VELOCITY_RIGID_BODY\n{1:10d}{15640.0:10.1f}{'':50}{7:10d}\n",
        f"*INITIAL_VELOCITY\n{0:10d}{'':30}{7:10d}\n{15640.0:10.1f}\n",  # NSID NSIDEX BOXID IRIGID ICID
        f"*INITIAL_VELOCITY_GENERATION\n{1:10d}{2:10d}{0.0:10.1f}{15640.0:10.1f}{'':30}{7:10d}\n\n",
    ],
)
def test_initial_velocities_in_a_local_system_are_not_read_as_global(tmp_path, cards):
    local_x_is_minus_x = "*DEFINE_COORDINATE_VECTOR\n         7      -1.0       0.0       0.0       0.0       1.0\n"
    path = _write(tmp_path, HEAD + NODES + SHELL + local_x_is_minus_x + cards)
    line = path.read_text().splitlines().index(cards.splitlines()[0]) + 2  # the first card after the keyword
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        read_deck(path)
    said = [str(w.message) for w in seen]
    assert not [w for w in said if "--axis-map" in w], said
    (msg,) = [w for w in said if "local coordinate system" in w]
    assert f"deck.k line {line}: " in msg and "ICID 7" in msg and "not checked" in msg, msg


def test_subassembly_map_yaml_sets_and_errors(tmp_path):
    parts = "".join(
        f"*PART\n{name}\n{i:10d}{1:10d}{1:10d}\n" for i, name in ((1, "hood outer"), (2, "Hood inner"), (3, "bumper"))
    )
    shells = "*ELEMENT_SHELL\n" + "".join(f"{i:8d}{i:8d}       1       2       3       4\n" for i in (1, 2, 3))
    sets = "*SET_PART_LIST_TITLE\nfront\n        10\n         3\n"
    deck = _write(
        tmp_path,
        HEAD.split("*PART")[0]
        + parts
        + HEAD.split("front plate\n         1         1         1\n")[1]
        + sets
        + NODES
        + shells,
    )
    y = tmp_path / "map.yaml"
    y.write_text("subassemblies:  # name -> parts\n  hood: ['hood*']\n  front: ['set:10']\n")
    m = _read(deck, subassemblies=y)
    assert m.subassemblies == {"hood": [1, 2], "front": [3]}
    m2 = _read(deck, subassemblies={"bumper": [3]})
    assert m2.subassemblies == {"bumper": [3], "part_1": [1], "part_2": [2]}
    for text, pattern in (
        ("subassemblies:\n  a: [9]\n", r"map.yaml key 'subassemblies.a\[0\]': unknown part 9"),
        ("subassemblies:\n  a: [3]\n  b: ['bump*']\n", r"key 'subassemblies.b\[0\]': part 3 .* in two sub-assemblies"),
        ("subassemblies:\n  a: ['door*']\n", r"pattern 'door\*' matches no part"),
        ("subassemblies:\n  a: ['set:4']\n", r"unknown \*SET_PART 4"),
        ("subassemblies:\n  a: [1\n", r"map.yaml: invalid YAML"),
        ("groups:\n  a: [1]\n", r"key 'groups': unknown key"),
        ("subassemblies:\n  a: 1\n", r"expected a non-empty list"),
    ):
        y.write_text(text)
        with pytest.raises(ConfigError, match=pattern):
            _read(deck, subassemblies=y)
    out = dump_subassembly_map({"hood": [1, 2], "front bumper": [3]}, tmp_path / "d.yaml")
    assert load_subassembly_map(out, m) == {"hood": [1, 2], "front bumper": [3]}


# part 2: a rigid block 50 mm in front of the plate (x = -60 .. -50 mm), its card 2 "CMO CON1 CON2" filled in
def _with_rigid_block(cmo: str, con1: str, con2: str) -> str:
    block = f"""*PART
rigid block
         2         1         2
*MAT_RIGID
         2  7.85e-09  210000.0       0.3
{cmo:>10}{con1:>10}{con2:>10}
*NODE
      11           -60.0
      12           -50.0
      13           -50.0           300.0
      14           -60.0           300.0
*ELEMENT_SHELL
       2       2      11      12      13      14
"""
    return HEAD + NODES + SHELL + block


@pytest.mark.parametrize(
    ("cmo", "con1", "con2", "axis_map", "left_out"),
    [
        ("1.0", "7", "7", None, True),  # held in x, y and z: the barrier of the LS-OPT small car
        ("1.0", "1", "0", None, True),  # held along the direction of travel alone is enough
        ("1.0", "5", "0", None, False),  # held in y and z only: it can still move with the vehicle (a sled)
        ("1.0", "1", "0", AxisMap(x="+z", y="+y", z="+x"), False),  # travel is along the deck's z: x is not it
        ("1.0", "4", "0", None, True),  # x and y
        ("1.0", "6", "0", None, True),  # z and x
        ("1.0", "2", "0", None, False),  # y
        ("1.0", "3", "0", None, False),  # z
        ("1.0", "2", "0", AxisMap(x="+y", y="+z", z="+x"), True),  # a cyclic map: travel along the deck's y
        ("1.0", "3", "0", AxisMap(x="+y", y="+z", z="+x"), False),
        ("1.0", "9", "0", None, False),  # not a CON1 code: a note, kept
        ("-1.0", "0", "111000.5", None, False),  # not an SPC code: a note, kept
        ("2.0", "7", "7", None, False),  # not a CMO: a note, kept
        ("-1.0", "3", "111000", None, True),  # local system, every translation held: whichever the system
        ("-1.0", "3", "100000", None, False),  # local system, one translation: the reader cannot tell which
        ("0.0", "0", "0", None, False),  # unconstrained
    ],
)
def test_rigid_parts_held_along_the_travel_are_left_out(tmp_path, cmo, con1, con2, axis_map, left_out):
    deck = _write(tmp_path, _with_rigid_block(cmo, con1, con2))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_deck(deck, **({"axis_map": axis_map} if axis_map else {}))
    plate_mass = 0.01 * 2e-3 * 7850
    said = [str(r.message) for r in rec]
    if left_out:
        assert sorted(m.parts) == [1] and m.n_shells == 1 and m.subassemblies == {"part_1": [1]}
        assert "barrier or fixture" in m.left_out[2] and "1 elements" in m.left_out[2]
        assert any("deck.k: part 2 ('rigid block')" in w for w in said)
        assert m.total_mass() == pytest.approx(plate_mass, rel=1e-12)
        plate = _read(_write(tmp_path, HEAD + NODES + SHELL, name="plate.k"), axis_map=axis_map or AxisMap())
        np.testing.assert_allclose(m.bounds(), plate.bounds(), atol=1e-15)  # front and width: the plate's
    else:
        assert sorted(m.parts) == [1, 2] and m.left_out == {}
        assert m.total_mass() > plate_mass
        assert np.ptp(m.bounds(), axis=0).max() > 0.2  # the 0.3 m block is part of the vehicle (plate: 0.1 m)
    assert any("local system 3" in w for w in m.warnings) == (con2 == "100000")
    assert any("read as unconstrained" in w for w in m.warnings) == (con1 == "9" or cmo == "2.0" or "." in con2)


def test_rigid_parts_merged_into_a_fixed_body_are_left_out_with_it(tmp_path):
    """*CONSTRAINED_RIGID_BODIES: the merged body moves under its master's constraints, not the slave's."""
    slave = """*PART
merged plate
         3         1         3
*MAT_RIGID
         3  7.85e-09  210000.0       0.3
{cmo:>10}{con1:>10}{con2:>10}
*NODE
      21           -60.0           400.0
      22           -50.0           400.0
      23           -50.0           500.0
*ELEMENT_SHELL
       3       3      21      22      23      23
*CONSTRAINED_RIGID_BODIES
{pidm:>10}{pids:>10}
"""
    for (cmo2, con2), (cmo3, con3), (pidm, pids), out in (
        (("1.0", "7"), ("0.0", "0"), (2, 3), [2, 3]),  # the free slave of a fixed master is fixed
        (("0.0", "0"), ("1.0", "7"), (2, 3), []),  # a held slave of a free master moves with it
        (("0.0", "0"), ("1.0", "7"), (3, 2), [2, 3]),  # the same parts, the other way round
        (("1.0", "7"), ("0.0", "0"), (9, 3), [2]),  # a merge naming no part changes nothing
    ):
        text = _with_rigid_block(cmo2, con2, con2) + slave.format(cmo=cmo3, con1=con3, con2=con3, pidm=pidm, pids=pids)
        m = _read(_write(tmp_path, text))
        assert sorted(m.left_out) == out, (cmo2, cmo3, pidm, pids)
        if 3 in out and (pidm, pids) == (2, 3):
            assert "merged into rigid part 2 by *CONSTRAINED_RIGID_BODIES" in m.left_out[3]


def test_a_deck_of_fixed_parts_only_and_maps_naming_them_are_refused(tmp_path):
    text = _with_rigid_block("1.0", "7", "7")
    only = _write(tmp_path, text.replace(SHELL, ""), name="only.k")
    with pytest.raises(DeckError, match=r"only.k: no vehicle structure is left: part 2 \('rigid block'\)"):
        _read(only)
    sets = "*SET_PART_LIST\n        10\n         1         2\n*SET_PART_LIST\n        11\n         2\n"
    deck = _write(tmp_path, text + sets)
    y = tmp_path / "map.yaml"
    y.write_text("subassemblies:\n  front: ['set:10']\n")
    assert _read(deck, subassemblies=y).subassemblies == {"front": [1]}  # a set keeps its vehicle parts
    for text, pattern in (
        ("subassemblies:\n  front: [1, 2]\n", r"key 'subassemblies.front\[1\]': part 2 .* barrier or fixture"),
        ("subassemblies:\n  barrier: ['set:11']\n", r"\*SET_PART 11 holds only parts left out of the vehicle"),
        (
            "subassemblies:\n  barrier: ['rigid*']\n",
            r"pattern 'rigid\*' matches no part title; not matched, left out of the vehicle: part 2 \('rigid block'\)",
        ),
    ):
        y.write_text(text)
        with pytest.raises(ConfigError, match=pattern):
            _read(deck, subassemblies=y)


def test_summary_counts_the_nodes_the_vehicle_uses(tmp_path):
    """A left-out barrier's elements go, its nodes stay: inspect says how many the vehicle uses."""
    m = _read(_write(tmp_path, _with_rigid_block("1.0", "7", "7")))
    s = vehicle_summary(m)
    assert (s["n_nodes"], s["n_nodes_used"]) == (8, 4)
    assert "nodes      8 (4 used by the vehicle's elements)" in format_vehicle_summary(s)
    plate = vehicle_summary(_read(_write(tmp_path, HEAD + NODES + SHELL, name="plate.k")))
    assert (plate["n_nodes"], plate["n_nodes_used"]) == (4, 4)
    assert format_vehicle_summary(plate).splitlines()[1] == "nodes      4"


def test_summary_table_shows_long_names_in_full_and_aligned(tmp_path):
    """The inspect table cut part names at 28 characters and material labels at 24: two rails whose titles differ
    only at their end ('... inner left', '... inner right') read alike, and a part id over 6 digits pushed its row
    out of line. Each column is now as wide as its longest entry: every name in full, every row's columns where the
    header's are."""
    left, right = "front longitudinal rail, inner panel, left", "front longitudinal rail, inner panel, right"
    mat = "*MAT_ELASTIC_TITLE\nDP600 dual-phase steel, 1.5 mm coil, batch 7\n"
    two = (
        HEAD.replace("front plate", left).replace("*MAT_ELASTIC\n", mat)
        + f"*PART\n{right}\n  12345678         1         1\n"
        + NODES
        + "      11           100.0           200.0\n      12                           200.0\n"
        + SHELL
        + "       212345678       4       3      11      12\n"
    )
    table = format_vehicle_summary(vehicle_summary(_read(_write(tmp_path, two))))
    lines = table.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("part  name"))
    rows = lines[head + 1 : head + 3]
    assert [r.split()[0] for r in rows] == ["1", "12345678"]  # an id of 8 digits: the id column widens too
    assert left in rows[0] and right in rows[1] and right not in rows[0]
    assert all("DP600 dual-phase steel, 1.5 mm coil, batch 7 (elastic)" in r for r in rows)
    for col in ("name", "material"):  # each column starts where its header does
        at = lines[head].index(col)
        assert rows[0][at:].startswith((left, "DP600")[col == "material"]) and rows[1][at:].startswith(
            (right, "DP600")[col == "material"]
        )
    assert {len(r) for r in rows} == {len(lines[head])}  # the numbers end under 'mass [kg]'


# part 2: a deformable block (a honeycomb barrier) 50 mm in front of the plate, on nodes 11-14
AT_REST = _with_rigid_block("", "", "").replace("*MAT_RIGID", "*MAT_ELASTIC").replace("rigid block", "honeycomb")
V = f"{-15640.0:10.1f}"  # 56 km/h in mm/s, toward -x
PLATE_NODES = "*SET_NODE_LIST\n         5\n         1         2         3         4\n"
BLOCK_NODES = "*SET_NODE_LIST_GENERATE\n         6\n        11        14\n"


@pytest.mark.parametrize(
    ("cards", "left_out"),
    [
        ("*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{V}\n" for n in (1, 2, 3, 4)), True),
        ("*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{V}\n" for n in (1, 2, 3, 4, 11)), False),  # one node moves
        (f"*INITIAL_VELOCITY\n         0         6\n{V}\n\n", True),  # all but the exempted set 6
        (f"*INITIAL_VELOCITY\n         0         6\n{V}\n{V}\n", False),  # ... which moves too
        (f"*INITIAL_VELOCITY\n         0\n{V}\n", False),  # everything moves
        (f"*INITIAL_VELOCITY\n         5\n{V}\n", True),  # node set 5: the plate
        (f"*INITIAL_VELOCITY_GENERATION\n         1         2       0.0{V}\n\n", True),  # part 1
        (f"*INITIAL_VELOCITY_GENERATION\n        10         1       0.0{V}\n\n", True),  # part set 10 = {1}
        (f"*INITIAL_VELOCITY_GENERATION\n         5         3       0.0{V}\n\n", True),  # node set 5
        (f"*INITIAL_VELOCITY_GENERATION\n         2         2       0.0{V}\n\n", False),  # only the block moves
        ("*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{0.0:10.1f}\n" for n in (1, 2, 3, 4)), False),  # at rest
        (f"*INITIAL_VELOCITY\n        99\n{V}\n", False),  # a set the deck lacks: nothing is decided
        ("", False),  # no initial velocity: nothing to go by
    ],
)
def test_parts_the_initial_velocities_leave_at_rest_are_left_out(tmp_path, cards, left_out):
    sets = PLATE_NODES + BLOCK_NODES + "*SET_PART_LIST\n        10\n         1\n"
    m = _read(_write(tmp_path, AT_REST + sets + cards))
    assert (2 in m.left_out) == left_out and (2 in m.parts) != left_out
    if left_out:
        assert "initial velocities set none of its nodes moving" in m.left_out[2]
        np.testing.assert_allclose(m.bounds(), [[0, -0.05, 0], [0.1, 0.05, 0]], atol=1e-15)  # the plate alone
    assert any("refers to a set the reader lacks" in w for w in m.warnings) == (" 99\n" in cards)


def test_reader_benchmark_runs_with_initial_velocities():
    """benchmarks/bench_reader.py --velocities --masses: every node in a set, moving and carrying a point mass;
    nothing is left out and the total mass counts the point masses (the script checks both)."""
    bench = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_reader.py"
    args = ["--nodes", "2000", "--velocities", "--masses", "--skip-dynakw"]
    proc = subprocess.run([sys.executable, str(bench), *args], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "OK: read_deck within" in proc.stdout


def _duplicate_t(dflag: str) -> str:
    head = HEAD.replace("       2.0       2.0       2.0       2.0", "&t,&t,&t,&t")
    return "*KEYWORD\n*PARAMETER\nR t       2.0\n" + dflag + head[len("*KEYWORD\n") :] + NODES + SHELL


@pytest.mark.parametrize(
    ("dflag", "thickness", "note"),
    [
        ("", 2e-3, "first definition is kept"),  # LS-DYNA's default, DFLAG 1
        ("*PARAMETER_DUPLICATION\n         2\n", 1e-3, "new definition replaces it"),
        ("*PARAMETER_DUPLICATION\n         3\n", 2e-3, None),
        ("*PARAMETER_DUPLICATION\n         4\n", 1e-3, None),
    ],
)
def test_a_parameter_defined_twice_keeps_the_first_value_as_ls_dyna_does(tmp_path, dflag, thickness, note):
    """An include that defines a deck's parameter again (here in a component file read after the main deck's
    definition) does not silently change what the main deck's fields read."""
    _write(tmp_path, "*KEYWORD\n*PARAMETER\nR t       1.0\n*END\n", "component.k")
    m = _read(_write(tmp_path, _duplicate_t(dflag) + "*INCLUDE\ncomponent.k\n*END\n"))
    assert m.shell_thickness[0] == pytest.approx(thickness)
    said = [w for w in m.warnings if "defined again" in w]
    assert (said[0] if said else None) is None if note is None else note in said[0]
    if note is not None:
        assert "component.k line 3: parameter 't'" in said[0] and "first in deck.k line 3" in said[0]
    same = _read(_write(tmp_path, _duplicate_t("") + "*PARAMETER\nR t       2.0\n*END\n", "same.k"))
    assert not any("defined again" in w for w in same.warnings)  # the same value again: nothing to say
    strict = _duplicate_t("*PARAMETER_DUPLICATION\n         5\n") + "*INCLUDE\ncomponent.k\n"
    with pytest.raises(
        DeckError, match=r"component.k line 3: parameter 't' is defined twice \(first in strict.k line 3\)"
    ):
        _read(_write(tmp_path, strict, "strict.k"))
    with pytest.raises(DeckError, match=r"bad.k line 3: \*PARAMETER_DUPLICATION expects DFLAG 0 to 5"):
        _read(_write(tmp_path, "*KEYWORD\n*PARAMETER_DUPLICATION\n         7\n", "bad.k"))
    zero = _duplicate_t("*PARAMETER_DUPLICATION\n         0\n") + "*INCLUDE\ncomponent.k\n*END\n"
    assert _read(_write(tmp_path, zero, "zero.k")).shell_thickness[0] == pytest.approx(2e-3)  # 0: the default


FULL_VEHICLE_EXTRAS = """*PART
bumper foam
        11        11        11
*SECTION_SOLID
        11         1
*MAT_LOW_DENSITY_FOAM
        11  5.0e-11       2.0       100       0.0       1.2
*PART
crash box
        12         1        12
*MAT_JOHNSON_COOK
        12  7.85e-09   80000.0  210000.0      0.28
*PART
engine mount spring
        13        13        13
*SECTION_DISCRETE
        13         0
*MAT_SPRING_ELASTIC
        13     100.0
*ELEMENT_DISCRETE
     901      13       1       2
*PART
door trim
        14         1        14
*MAT_SOME_FUTURE_MODEL
        14  1.0e-09    2000.0     100.0
*PART
belt
        15        15        16
*SECTION_SEATBELT
        15
*MAT_SEATBELT
        16   1.0e-06       100       100
*ELEMENT_SEATBELT
     902      15       3       4
*PART
lining
        17         1        17
*MAT_FABRIC
        17  1.0e-09    5000.0    4000.0    4000.0      0.35
"""
FULL_VEHICLE_ELEMENTS = """*NODE
       5                           100.0           100.0
       6           100.0           100.0           100.0
       7           100.0                           100.0
       8                                           100.0
*ELEMENT_SOLID
       2      11       1       2       3       4       8       7       6       5
*ELEMENT_SHELL
       3      12       1       2       3       4
       4      14       1       2       3       4
       5      17       1       2       3       4
"""


def test_materials_and_sections_of_a_full_vehicle_deck(tmp_path):
    """A full-vehicle deck has springs, belts, foams and material models whose first card is not MID RO E PR. Each
    material is read by its own layout; parts of elements the reader skips (discrete, seatbelt) are left out with a
    note instead of refusing the deck; a material of a layout the reader does not know keeps its density, and its
    modulus is defaulted with a note rather than reading a curve id as Poisson's ratio."""
    m = _read(_write(tmp_path, HEAD + NODES + SHELL + FULL_VEHICLE_EXTRAS + FULL_VEHICLE_ELEMENTS))
    assert m.units == "mm-t-s"  # the spring stiffness and the belt's mass per length are not densities
    foam, jc, other, fabric = (m.materials[i] for i in (11, 12, 14, 17))
    assert foam.density == pytest.approx(50.0) and foam.youngs_modulus == pytest.approx(2e6)
    assert foam.poisson_ratio == pytest.approx(0.3)  # LCID 100 is not a Poisson's ratio: defaulted
    assert jc.youngs_modulus == pytest.approx(210e9) and jc.poisson_ratio == pytest.approx(0.28)  # after G
    assert fabric.youngs_modulus == pytest.approx(5e9) and fabric.density == pytest.approx(1000.0)  # EA
    assert other.density == pytest.approx(1000.0)
    assert other.youngs_modulus == pytest.approx(np.median([210e9, 2e6, 210e9, 5e9]))  # of the parts' materials
    assert any("material 14 (*MAT_SOME_FUTURE_MODEL): its first card does not read as MID RO E PR" in w
               for w in m.warnings)  # fmt: skip
    assert 13 not in m.parts and 15 not in m.parts and 13 not in m.materials and 16 not in m.materials
    assert "part 13 ('engine mount spring') has no shell, solid or beam elements" in m.left_out[13]  # maps say so
    masses = "*ELEMENT_MASS_PART\n      13     2.0e-3\n"  # a spring's added mass: not modelled with it, a note
    m = _read(_write(tmp_path, HEAD + NODES + SHELL + FULL_VEHICLE_EXTRAS + FULL_VEHICLE_ELEMENTS + masses, "m.k"))
    assert any("*ELEMENT_MASS_PART 13 adds nothing to part(s) [13]: left out" in w for w in m.warnings)
    assert any("2 part(s) without shell, solid or beam elements and with a section the reader does not read left "
               "out: [13, 15]" in w for w in m.warnings)  # fmt: skip
    assert any("material 16 (*MAT_SEATBELT) left out" in w and "no density" in w for w in m.warnings)

    def with_sheet(name: str, secid: int, mid: int, extra: str = "") -> Path:
        """The deck with a shell of a new part 18 of section ``secid`` and material ``mid``."""
        shell = "".join(f"{i:8d}" for i in (6, 18, 1, 2, 3, 4))
        sheet = f"*PART\nsheet\n{18:10d}{secid:10d}{mid:10d}\n{extra}*ELEMENT_SHELL\n{shell}\n"
        return _write(tmp_path, HEAD + NODES + SHELL + FULL_VEHICLE_EXTRAS + FULL_VEHICLE_ELEMENTS + sheet, name)

    # a part with elements the reader reads still needs a section, a material and a density it reads
    with pytest.raises(DeckError, match=r"used.k line \d+: \*PART 18 refers to section 13, a \*SECTION_DISCRETE "
                                        r"\(used.k line 35\) that the reader does not read"):  # fmt: skip
        _read(with_sheet("used.k", 13, 1))
    with pytest.raises(DeckError, match=r"spring.k line 37: material 13 \(\*MAT_SPRING_ELASTIC\) is a spring, .* "
                                        r"yet part 18 uses it"):  # fmt: skip
        _read(with_sheet("spring.k", 1, 13))
    with pytest.raises(DeckError, match=r"line \d+: \*MAT card 18 expects a numeric density RO in columns 11-20"):
        _read(with_sheet("ro.k", 1, 18, "*MAT_012\n        18\n"))


def test_includes_resolve_against_the_main_deck_folder_too(tmp_path):
    """LS-DYNA resolves a relative *INCLUDE name against the main deck's folder: an include inside ``sub/`` that
    names ``sub/nodes.k`` is found, while a name found beside the including file still wins."""
    sub = tmp_path / "sub"
    sub.mkdir()
    _write(sub, "*KEYWORD\n" + NODES + "*END\n", "nodes.k")
    _write(sub, "*KEYWORD\n*INCLUDE\nsub/nodes.k\n" + SHELL + "*END\n", "mesh.k")
    m = _read(_write(tmp_path, HEAD + "*INCLUDE\nsub/mesh.k\n*END\n"))
    assert m.n_nodes == 4 and m.n_shells == 1
    _write(sub, "*KEYWORD\n*INCLUDE\nsub/none.k\n*END\n", "bad.k")
    with pytest.raises(DeckError, match=r"bad.k line 3: \*INCLUDE file 'sub/none.k' not found \(looked in .*sub/sub, "):
        _read(_write(tmp_path, HEAD + "*INCLUDE\nsub/bad.k\n*END\n", "main2.k"))


def test_a_blank_last_card_is_a_card_of_defaults(tmp_path):
    """A blank line is a card of defaults also at the end of a block: a section whose thickness card is blank (the
    elements carry it), the last element's blank thickness line; a stray blank line after a block stays harmless."""
    thick = "*ELEMENT_SHELL_THICKNESS\n       1       1       1       2       3       4\n{}\n"
    sec = HEAD.replace("       2.0       2.0       2.0       2.0\n", "\n")
    blank_sec = sec.replace("*MAT_ELASTIC", NODES + thick.format(f"{3.0:16}" * 4) + "*MAT_ELASTIC")
    m = _read(_write(tmp_path, blank_sec + "*END\n"))
    assert m.shell_thickness[0] == pytest.approx(3e-3)  # the element's thickness; the section gives none
    m = _read(_write(tmp_path, HEAD + NODES + thick.format("") + "\n\n*END\n", "last.k"))
    assert m.shell_thickness[0] == pytest.approx(2e-3)  # the blank line: the section's thickness
    m = _read(_write(tmp_path, HEAD + "\n\n" + NODES + "\n" + SHELL + "\n\n*END\n", "stray.k"))
    assert m.n_shells == 1 and m.shell_thickness[0] == pytest.approx(2e-3)


def test_utf8_titles_and_an_early_end(tmp_path):
    p = tmp_path / "utf8.k"
    p.write_bytes((HEAD.replace("front plate", "Stoßfänger vorne") + NODES + SHELL).encode("utf-8"))
    assert _read(p).parts[1].name == "Stoßfänger vorne"
    p.write_bytes((HEAD.replace("front plate", "Stoßfänger vorne") + NODES + SHELL).encode("latin-1"))
    assert _read(p).parts[1].name == "Stoßfänger vorne"  # an older deck in Latin-1
    with pytest.raises(DeckError, match=r"no \*ELEMENT_SHELL.*reading stopped at the \*END in end.k line 17"):
        _read(_write(tmp_path, HEAD + NODES + "*END\n" + SHELL + "*END\n", "end.k"))


def test_line_endings_of_any_platform_read_alike(tmp_path):
    text = HEAD + NODES + SHELL + "*END\n"
    ref = _read(_write(tmp_path, text))
    for name, eol in (("crlf.k", b"\r\n"), ("cr.k", b"\r")):  # CR alone read as one line: "no *NODE"
        p = tmp_path / name
        p.write_bytes(text.encode().replace(b"\n", eol))
        m = _read(p)
        assert m.n_shells == 1 and np.array_equal(m.coords, ref.coords) and m.total_mass() == ref.total_mass()
    with pytest.raises(DeckError, match=r"cr\.k line 18: shell element 1 refers to undefined node 9"):
        p.write_bytes(
            (text + "").replace(SHELL, SHELL.replace("       4\n", "       9\n")).encode().replace(b"\n", b"\r")
        )
        _read(p)


def test_a_shell_thicker_than_it_is_wide_is_noted_as_a_thickness_typo(lsopt_deck, tmp_path):
    """A coordinate typo was noted, a thickness typo not: 2000. for 2.0 mm made a 157 kg plate of a 0.157 kg one."""
    thick = HEAD.replace("       2.0       2.0       2.0       2.0\n", "    2000.0    2000.0    2000.0    2000.0\n")
    m = _read(_write(tmp_path, thick + NODES + SHELL))
    (note,) = [w for w in m.warnings if "thicker than" in w]
    assert "shell 1 of part 1 is 2000 mm thick; a thickness typo" in note, note
    assert not [w for w in _read(_write(tmp_path, HEAD + NODES + SHELL)).warnings if "thicker than" in w]
    # the real deck: 3 mm bumper, and the same bumper 3000 mm thick
    assert not [w for w in _read(lsopt_deck, params={"tbumper": 3, "thood": 1}).warnings if "thicker than" in w]
    (note,) = [w for w in _read(lsopt_deck, params={"tbumper": 3000, "thood": 1}).warnings if "thicker than" in w]
    assert "is 3000 mm thick" in note, note


def _lsopt_with_node_500_x(lsopt_deck, tmp_path, x: str) -> Path:
    lines = lsopt_deck.read_text().splitlines(keepends=True)
    start = lines.index("*NODE\n")
    k = next(i for i in range(start, len(lines)) if lines[i][:8].strip() == "500")
    lines[k] = lines[k][:8] + f"{x:>16}" + lines[k][24:]
    return _write(tmp_path, "".join(lines), "typo.k")


def test_a_coordinate_typo_is_refused_or_noted_naming_the_node(lsopt_deck, tmp_path):
    params = {"tbumper": 3, "thood": 1}
    clean = _read(lsopt_deck, params=params)
    assert not any("median size" in w for w in clean.warnings)
    # 1.5e12 mm for 4318 mm: an 8e10 kg car was read without a word
    with pytest.raises(DeckError, match=r"typo\.k line 3666: the structure spans 1\.5e\+09 m, more than any vehicle"):
        _read(_lsopt_with_node_500_x(lsopt_deck, tmp_path, "1.5e12"), params=params)
    # a decimal point one place off: inside 50 m, but its shells are 140x their part's median
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        m = read_deck(_lsopt_with_node_500_x(lsopt_deck, tmp_path, "43180."), params=params)
    note = r"4 shell element\(s\) .* shell 491 of part 1 spans 39\.6 m .* node 500 \(typo\.k line 3666\)"
    assert any(re.search(note, str(w.message)) for w in seen) and any(re.search(note, w) for w in m.warnings)
    assert m.total_mass() > 1.5 * clean.total_mass()  # why the note matters


def test_an_include_with_options_is_named_as_not_read(tmp_path):
    """*INCLUDE_TRANSFORM's file was only counted among the skipped cards: its parts went missing unnamed."""
    _write(tmp_path, "*KEYWORD\n" + NODES.replace("       1\n", "").replace("*NODE\n", "*NODE\n       5\n"), "half.k")
    transform = "*INCLUDE_TRANSFORM\nhalf.k\n         0         0         0\n         0\n       1.0\n         0\n"
    with pytest.warns(UserWarning, match=r"\*INCLUDE_TRANSFORM 'half\.k' \(deck\.k line 3\) is not read: the nodes"):
        m = read_deck(_write(tmp_path, "*KEYWORD\n" + transform + HEAD.replace("*KEYWORD\n", "") + NODES + SHELL))
    assert m.n_shells == 1 and any("INCLUDE_TRANSFORM 'half.k'" in w for w in m.warnings)
    # an element on a node only the unread file defines: the error says where that node may be
    missing = NODES.replace("       4                           100.0\n", "")
    with pytest.raises(DeckError, match=r"undefined node 4; note: \*INCLUDE_TRANSFORM 'half\.k' \(deck\.k line 3\)"):
        _read(_write(tmp_path, "*KEYWORD\n" + transform + HEAD.replace("*KEYWORD\n", "") + missing + SHELL))


def test_fortran_exponents_without_the_letter_read_as_ls_dyna_reads_them(tmp_path):
    """Fortran's formatted input (which LS-DYNA's fixed fields follow) takes ``7.85-9`` as 7.85e-9 and ``1.0+2`` as
    100: a signed exponent needs no E. Decks written by Fortran tools carry such numbers; they were refused."""
    ref = _read(_write(tmp_path, HEAD + NODES + SHELL))
    fortran = (HEAD + NODES + SHELL).replace("  7.85e-09  210000.0", "    7.85-9     2.1+5")
    fortran = fortran.replace("       2           100.0", "       2           1.0+2")  # the fast path's fallback
    m = _read(_write(tmp_path, fortran, "fortran.k"))
    assert m.materials[1].density == pytest.approx(7850.0) and m.materials[1].youngs_modulus == pytest.approx(2.1e11)
    np.testing.assert_allclose(m.coords, ref.coords, rtol=1e-12)
    assert m.total_mass() == pytest.approx(ref.total_mass(), rel=1e-12)
    free = (HEAD + NODES + SHELL).replace("       2           100.0", "2,1.0+2,-0.0d0")
    np.testing.assert_allclose(_read(_write(tmp_path, free, "free.k")).coords, ref.coords, rtol=1e-12)
    # what is still no number stays an error naming the field
    bad = (HEAD + NODES + SHELL).replace("       2           100.0", "       2           1.0+-2")
    with pytest.raises(DeckError, match=r"bad\.k line 14: \*NODE expects a numeric x coordinate in columns 9-24"):
        _read(_write(tmp_path, bad, "bad.k"))


def test_a_line_of_tabs_and_spaces_is_a_blank_line(tmp_path):
    """A line holding only whitespace with a tab in it (an editor's indentation) was taken for a card in *NODE and
    *ELEMENT_SHELL blocks ('expects node id in columns 1-8, got blank'), while a line of spaces is skipped there."""
    ref = _read(_write(tmp_path, HEAD + NODES + SHELL))
    nodes = NODES.replace("       2 ", "\t\n  \t  \n       2 ")
    m = _read(_write(tmp_path, HEAD + nodes + SHELL + " \t \n", "tabs.k"))
    assert m.n_nodes == 4 and m.n_shells == 1 and m.total_mass() == ref.total_mass()
    solid = HEAD.replace("*SECTION_SHELL\n         1         2\n       2.0       2.0       2.0       2.0\n",
                         "*SECTION_SOLID\n         1         1\n")  # fmt: skip
    nodes = "*NODE\n1,0,0,0\n2,10,0,0\n3,10,20,0\n4,0,20,0\n5,0,0,30\n6,10,0,30\n7,10,20,30\n8,0,20,30\n"
    one = "       1       1       1       2       3       4       5       6       7       8\n"
    m = _read(_write(tmp_path, solid + nodes + "*ELEMENT_SOLID\n\t\n" + one, "solid.k"))
    assert m.n_solids == 1


@pytest.mark.parametrize(
    ("card", "pattern"),
    [
        (
            "*MAT_ELASTIC\n         1   7.8x-09  210000.0       0.3\n",
            r"line 11: \*MAT_ELASTIC expects a numeric RO in columns 11-20, got '7.8x-09'",
        ),
        (
            "*MAT_PLASTIC_KINEMATIC\n         1  7.85e-09  210000.0       0.3     25O.0\n",
            r"line 11: \*MAT_PLASTIC_KINEMATIC expects a numeric SIGY in columns 41-50, got '25O.0'",
        ),
        (
            "*MAT_PLASTIC_KINEMATIC\n         1  7.85e-09  210000.0       0.3     250.0\n"
            "       0.0       0.0      0.2x\n",
            r"line 12: \*MAT_PLASTIC_KINEMATIC expects a numeric FS in columns 21-30, got '0.2x'",
        ),
        (
            "*MAT_PIECEWISE_LINEAR_PLASTICITY\n         1  7.85e-09  210000.0       0.3     250.0\n"
            "       0.0       0.0     curve\n",
            r"line 12: \*MAT_PIECEWISE_LINEAR_PLASTICITY expects a numeric LCSS in columns 21-30, got 'curve'",
        ),
        (
            "*MAT_024\n         1  7.85e-09  210000.0       0.3     250.0\n       0.0       0.0\n"
            "       0.0       0.1\n     250.0      3OO.\n",
            r"line 14: \*MAT_024 expects a numeric ES2 in columns 11-20, got '3OO.'",
        ),
        (
            "*MAT_RIGID\n         1  7.85e-09  210000.0       0.3\n       1.0       x.0\n",
            r"line 12: \*MAT_RIGID expects a numeric CON1 in columns 11-20, got 'x.0'",
        ),
    ],
)
def test_material_card_errors_name_the_field_as_the_manual_does(tmp_path, card, pattern):
    """The material cards' fields were named C1..C7 in errors ('expects a numeric C4' for SIGY)."""
    head = HEAD.split("*MAT_ELASTIC")[0]
    with pytest.raises(DeckError, match=r"deck.k " + pattern):
        _read(_write(tmp_path, head + card + NODES + SHELL))


def test_a_rigid_material_with_an_alias_name_reads(tmp_path):
    """*MAT_RIGID's eighth field ALIAS is a name (a VDA surface); it was read as a number and refused."""
    head = HEAD.split("*MAT_ELASTIC")[0]
    rigid = "*MAT_RIGID\n         1  7.85e-09  210000.0       0.3       0.0       0.0       0.0     wheel\n"
    m = _read(_write(tmp_path, head + rigid + NODES + SHELL))
    assert m.materials[1].is_rigid and m.total_mass() == pytest.approx(0.1 * 0.1 * 0.002 * 7850.0)


def test_a_blank_density_is_named_at_its_card(tmp_path):
    """A blank RO left the unit detection with 'median nan' and no line; with units given, the card was named."""
    blank = (HEAD + NODES + SHELL).replace("  7.85e-09  210000.0", "            210000.0")
    for units in (None, "mm-t-s"):
        with pytest.raises(DeckError, match=r"deck.k line 11: \*MAT card 1 expects a numeric density RO in columns "
                           r"11-20, got blank \(\*MAT_ELASTIC, used by part 1\)"):  # fmt: skip
            _read(_write(tmp_path, blank), units=units)


@pytest.mark.parametrize(
    "card", ["       2.0      -2.0       2.0       2.0", "       2.0       2.0       2.0      -0.5"]
)
def test_a_negative_section_thickness_t2_to_t4_is_refused(tmp_path, card):
    """A blank or zero T2..T4 of *SECTION_SHELL is T1, as in LS-DYNA; a negative one was taken as T1 as well, without
    a word, while a negative T1 and any negative *ELEMENT_SHELL_THICKNESS value were refused. Now refused alike, with
    the values as written."""
    deck = _write(tmp_path, (HEAD + NODES + SHELL).replace("       2.0       2.0       2.0       2.0", card))
    written = "[" + ", ".join(f"{float(v)}" for v in card.split()) + "]"
    with pytest.raises(DeckError, match=rf"deck.k line 9: \*SECTION_SHELL expects thicknesses T1..T4 >= 0, got "
                       rf"{re.escape(written)}"):  # fmt: skip
        _read(deck)
    blank = _read(_write(tmp_path, (HEAD + NODES + SHELL).replace("       2.0       2.0       2.0       2.0",
                                                                    "       2.0")))  # fmt: skip
    assert blank.shell_thickness[0] == pytest.approx(2e-3)  # blank T2..T4: T1


def test_elements_of_a_composite_part_name_the_card_the_reader_skips(tmp_path):
    """*PART_COMPOSITE is skipped (a layup, not one section and material), and its elements were refused as
    'shell element 2 refers to undefined part 2', though the deck defines part 2: now the error names the card, its
    file and line, and that the reader does not read it."""
    comp = (
        "*PART_COMPOSITE\ncomposite panel\n         2         2       0.0         0       0.0         0         0"
        "         0\n         1       1.0       0.0         0         1       1.0       0.0         0\n"
        "*NODE\n      11           100.0           200.0\n      12                           200.0\n"
        "*ELEMENT_SHELL\n       2       2       4       3      11      12\n"
    )
    with pytest.raises(DeckError, match=r"deck.k line 27: shell element 2 refers to part 2, a \*PART_COMPOSITE "
                       r"\(deck.k line 21\) that the reader does not read; expected a \*PART"):  # fmt: skip
        _read(_write(tmp_path, HEAD + NODES + SHELL + comp))
    with pytest.raises(DeckError, match=r"deck.k line 27: shell element 2 refers to undefined part 7$"):
        _read(
            _write(
                tmp_path, HEAD + NODES + SHELL + comp.replace("       2       2       4", "       2       7       4")
            )
        )


def test_a_zero_density_is_refused_at_its_card(tmp_path):
    """RO = 0 was read without a word: the part weighed nothing, and the error came only from the discretizer, far
    from the card (a sub-assembly 'has no mass', or, grouped with a heavy part, 'the mass floor ... a deck read in the
    wrong unit system'). It is refused at the *MAT card now, naming the part that uses it."""
    zero = (HEAD + NODES + SHELL).replace("  7.85e-09  210000.0", "       0.0  210000.0")
    said = (
        r"deck.k line 11: material 1 \(\*MAT_ELASTIC\) has density RO 0, yet part 1 \('front plate', 1 elements\) "
        r"uses it: its elements would weigh nothing; expected RO > 0"
    )
    with pytest.raises(DeckError, match=said):
        _read(_write(tmp_path, zero), units="mm-t-s")
    # a fixed barrier of RO 0 is left out of the vehicle, not refused; a rigid part's *PART_INERTIA TM sets its mass
    barrier = _with_rigid_block("1.0", "7", "7").replace("         2  7.85e-09", "         2       0.0")
    m = _read(_write(tmp_path, barrier), units="mm-t-s")
    assert sorted(m.parts) == [1] and 2 in m.left_out
    inertia = (
        barrier.replace("*PART\nrigid block", "*PART_INERTIA\nrigid block")
        .replace(
            "         2         1         2\n",
            "         2         1         2\n     -55.0     150.0       0.0     0.005\n"
            "       1.0       0.0       0.0       1.0       0.0       1.0\n\n",
        )
        .replace("       1.0         7         7", "       0.0         0         0")
    )
    m = _read(_write(tmp_path, inertia), units="mm-t-s")
    assert m.part_masses()[2] == pytest.approx(5.0) and m.left_out == {}


@pytest.mark.parametrize(
    ("card1", "card2", "area_mm2"),
    [
        ("1,1,1.0,2,0,0.0", "20.0,20.0,10.0,10.0,0.0,0.0", 200.0),  # TS1 TS2 TT1 TT2 NSLOC NTLOC: 20 x 10
        ("1,1,1.0,2,1,0.0", "20.0,20.0,10.0,10.0,0.0,0.0", math.pi / 4 * (20.0**2 - 10.0**2)),  # a tube
        ("1,2,1.0,2,0,0.0,0.0", "50.0,100.0,100.0,200.0,0.0,1", 50.0),  # A ISS ITT J SA IST
        ("1,3", "50.0,0.0,0.0", 50.0),  # A RAMPT STRESS
        ("1,9,1.0,2,1", "5.0,5.0,0.0,0.0,1.0", math.pi / 4 * 25.0),  # spot weld: TS1 TS2 TT1 TT2 PRINT
    ],
)
def test_section_beam_second_cards_of_each_formulation_are_read(tmp_path, card1, card2, area_mm2):
    """*SECTION_BEAM's second card depends on ELFORM (all its fields, fixed or free format, in one block with a
    second section): each gives its area."""

    def fixed(line: str) -> str:
        return "".join(f"{v:>10}" for v in line.split(","))

    for c1, c2 in ((card1, card2), (fixed(card1), fixed(card2))):
        deck = (
            f"*KEYWORD\n*PART\nbar\n         1         1         1\n*SECTION_BEAM\n{c1}\n{c2}\n2,3\n60.0\n"
            "*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n*NODE\n1,0,0,0\n2,100,0,0\n"
            "*ELEMENT_BEAM\n       1       1       1       2\n"
        )
        m = _read(_write(tmp_path, deck))
        np.testing.assert_allclose(m.beam_area, [area_mm2 * 1e-6], rtol=1e-12)


@pytest.mark.parametrize(
    ("section", "line"),
    [
        ("*SECTION_BEAM_AISC\n         1W14X90\n         2       1.0       0.0\n", 6),  # a standard shape's name
        ("*SECTION_BEAM_AISC_TITLE\nbeam\n1,W14X90\n2,1.0,0.0\n", 7),
        ("*SECTION_DISCRETE\n         1         0\n       0.0       0.0\n", 6),  # a spring's section
    ],
)
def test_a_beam_section_the_reader_does_not_read_is_named_not_called_undefined(tmp_path, section, line):
    """Beams whose *PART names a *SECTION_BEAM_AISC (or a *SECTION_DISCRETE) were refused with 'refers to undefined
    section 1', though the deck defines it: the reader skips those cards (it has no AISC shape table)."""
    deck = (
        "*KEYWORD\n*PART\nbar\n         1         1         1\n" + section
        + "*MAT_ELASTIC\n         1  7.85e-09  210000.0       0.3\n*NODE\n1,0,0,0\n2,100,0,0\n"
        + "*ELEMENT_BEAM\n       1       1       1       2\n"
    )  # fmt: skip
    pattern = (rf"deck\.k line 4: \*PART 1 refers to section 1, a \*SECTION_\w+ \(deck\.k line {line}\) that the "
               r"reader does not read; its shell, solid or beam elements need a \*SECTION_SHELL, \*SECTION_SOLID or "
               r"\*SECTION_BEAM$")  # fmt: skip
    with pytest.raises(DeckError, match=pattern):
        _read(_write(tmp_path, deck))
    with pytest.raises(DeckError, match=r"deck\.k line 4: \*PART 1 refers to undefined section 1$"):
        _read(_write(tmp_path, deck.replace(section, section.replace("1", "7", 1))))  # section 7: none is 1


def test_element_beam_section_reads_its_section_type_card(tmp_path):
    """*ELEMENT_BEAM_SECTION's card is STYPE D1 .. D6 (a name such as SECTION_08, then 10-column fields); it was read
    as *ELEMENT_BEAM_THICKNESS's 16-column PARM1..PARM4, so every such deck was refused."""
    deck = """*KEYWORD
*PART
bar
         1         1         1
*SECTION_BEAM
         1         2
      50.0
*MAT_ELASTIC
         1  7.85e-09  210000.0       0.3
*NODE
1,0,0,0
2,100,0,0
*ELEMENT_BEAM_SECTION
       1       1       1       2
SECTION_08      10.0
       2       1       1       2
SECTION_09      20.0      10.0
       3       1       1       2
SECTION_11      10.0       5.0
       4       1       1       2
SECTION_01      10.0       5.0       1.0       1.0
5,1,1,2
SECTION_09,20.0,10.0
"""
    m = _read(_write(tmp_path, deck))
    hand = [math.pi / 4 * 10.0**2, math.pi / 4 * (20.0**2 - 10.0**2), 10.0 * 5.0, 50.0, math.pi / 4 * 300.0]  # mm^2
    np.testing.assert_allclose(m.beam_area, np.array(hand) * 1e-6, rtol=1e-12)
    assert m.total_mass() == pytest.approx(sum(hand) * 100.0 * 7.85e-9 * 1e3, rel=1e-12)  # mm^3 x t/mm^3 -> kg
    assert any("SECTION_01 x1" in w and "their part's *SECTION_BEAM area" in w for w in m.warnings)


def test_blank_lines_before_the_first_solid_are_skipped_as_for_shells_and_nodes(tmp_path):
    """A blank line opening an *ELEMENT_SOLID block was taken for the element's card ('expects element id in columns
    1-8, got blank'); *NODE and *ELEMENT_SHELL skip such lines."""
    head = HEAD.replace("*SECTION_SHELL\n         1         2\n       2.0       2.0       2.0       2.0\n",
                        "*SECTION_SOLID\n         1         1\n")  # fmt: skip
    nodes = "*NODE\n1,0,0,0\n2,10,0,0\n3,10,20,0\n4,0,20,0\n5,0,0,30\n6,10,0,30\n7,10,20,30\n8,0,20,30\n"
    one = "       1       1       1       2       3       4       5       6       7       8\n"
    two = "       1       1\n       1       2       3       4       5       6       7       8\n"
    for body in (one, two):
        ref = _read(_write(tmp_path, head + nodes + "*ELEMENT_SOLID\n" + body))
        m = _read(_write(tmp_path, head + nodes + "*ELEMENT_SOLID\n\n$ a comment\n   \n" + body, "blank.k"))
        np.testing.assert_allclose(m.solid_volumes(), [10 * 20 * 30 * 1e-9], rtol=1e-12)
        assert m.total_mass() == ref.total_mass() and np.array_equal(m.solid_nodes, ref.solid_nodes)


@pytest.mark.parametrize("option", ["TET4TOTET10", "H8TOH20", "H8TOH27"])
def test_solids_lsdyna_gives_mid_side_nodes_read_as_plain_solids(tmp_path, option):
    """*ELEMENT_SOLID_TET4TOTET10 (H8TOH20, H8TOH27) holds plain 4- and 8-node cards to which LS-DYNA adds mid-side
    nodes; it was skipped as an unknown option, so a part meshed that way stayed in the model with no mass."""
    head = HEAD.replace("*SECTION_SHELL\n         1         2\n       2.0       2.0       2.0       2.0\n",
                        "*SECTION_SOLID\n         1         1\n")  # fmt: skip
    nodes = "*NODE\n1,0,0,0\n2,10,0,0\n3,10,20,0\n4,0,20,0\n5,0,0,30\n6,10,0,30\n7,10,20,30\n8,0,20,30\n"
    card = (
        "       1       1       1       2       4       5       5       5       5       5\n"
        if option == "TET4TOTET10"
        else "       1       1       1       2       3       4       5       6       7       8\n"
    )
    ref = _read(_write(tmp_path, head + nodes + "*ELEMENT_SOLID\n" + card))
    m = _read(_write(tmp_path, head + nodes + f"*ELEMENT_SOLID_{option}\n" + card, "opt.k"))
    volume = 10 * 20 * 30 / (6 if option == "TET4TOTET10" else 1) * 1e-9
    np.testing.assert_allclose(m.solid_volumes(), [volume], rtol=1e-12)
    assert m.total_mass() == ref.total_mass() > 0 and np.array_equal(m.solid_nodes, ref.solid_nodes)
    assert not any("skipped" in w for w in m.warnings), m.warnings


@pytest.mark.parametrize(
    ("card", "pattern"),
    [
        (
            "*SET_PART_LIST\n         1\n         1       abc\n",
            r"\*SET_PART_LIST expects an integer PID2 in columns 11-20",
        ),
        (
            "*SET_NODE_LIST_TITLE\nx\n         1\n         1         2       2.5\n",
            r"\*SET_NODE_LIST_TITLE expects an integer NID3 in columns 21-30",
        ),
        (
            "*SET_PART_LIST_GENERATE\n         1\n         1         x\n",
            r"\*SET_PART_LIST_GENERATE expects an integer B1END in columns 11-20, got 'x'",
        ),
    ],
)
def test_set_card_errors_name_the_field_as_the_manual_does(tmp_path, card, pattern):
    """The id fields of sets were named P0..P7 in errors: 'P1' for the second id, PID2 in the manual."""
    with pytest.raises(DeckError, match=r"deck.k line \d+: " + pattern):
        _read(_write(tmp_path, HEAD + NODES + SHELL + card))


def test_a_set_id_defined_twice_is_refused(tmp_path):
    """Two part sets (or two node sets) of one SID: the last silently replaced the first, so a sub-assembly map's
    set:<id>, an *INITIAL_VELOCITY_GENERATION or a *CONSTRAINED_NODAL_RIGID_BODY could take another set than the one
    meant. Refused naming both, as other duplicate ids are; a part set and a node set may share an id."""
    parts = "*SET_PART_LIST\n        10\n         1\n"
    parts += "*SET_PART_LIST_GENERATE_TITLE\nagain\n        10\n         1         1\n"
    with pytest.raises(DeckError, match=r"line 24: \*SET_PART_LIST_GENERATE_TITLE SID 10 is defined twice "
                       r"\(first in deck.k line 20\)"):  # fmt: skip
        _read(_write(tmp_path, HEAD + NODES + SHELL + parts))
    nodes = "*SET_NODE_LIST\n        10\n         1         2\n*SET_NODE\n        10\n         3\n"
    with pytest.raises(DeckError, match=r"line 23: \*SET_NODE SID 10 is defined twice \(first in deck.k line 20\)"):
        _read(_write(tmp_path, HEAD + NODES + SHELL + nodes))
    m = _read(
        _write(
            tmp_path,
            HEAD
            + NODES
            + SHELL
            + parts[: parts.index("*SET_PART_LIST_GENERATE")]
            + nodes[: nodes.index("*SET_NODE\n")],
        )
    )
    assert m.n_shells == 1


@pytest.mark.parametrize(
    ("card", "pattern"),
    [
        (
            "*SET_NODE_LIST_GENERATE\n         6\n        14        11\n",
            r"line 21: \*SET_NODE_LIST_GENERATE expects B1BEG <= B1END \(a range from first to last id\), got 14 > 11",
        ),
        (
            "*SET_PART_LIST_GENERATE\n         7\n         1         1\n         1         1         9         3\n",
            r"line 22: \*SET_PART_LIST_GENERATE expects B2BEG <= B2END \(a range from first to last id\), got 9 > 3",
        ),
        (
            "*SET_PART_LIST_GENERATE\n         7\n         0         1\n",
            r"line 21: \*SET_PART_LIST_GENERATE expects positive ids B1BEG and B1END, got 0 and 1",
        ),
        (
            "*SET_NODE_LIST_GENERATE\n         6\n         1         4         2\n",
            r"line 21: \*SET_NODE_LIST_GENERATE expects positive ids B2BEG and B2END, got 2 and 0",
        ),
    ],
    ids=["swapped", "swapped-second-line", "zero-begin", "blank-end"],
)
def test_a_generated_set_range_must_run_from_first_to_last_id(tmp_path, card, pattern):
    """A *SET_..._GENERATE range with its ends swapped (14 11) or one end blank or zero gave no ids, or id 0, without
    a word: a set that then names nothing (an initial velocity that moves no node); now an error names the range."""
    with pytest.raises(DeckError, match=r"deck\.k " + pattern):
        _read(_write(tmp_path, HEAD + NODES + SHELL + card))
    good = "*SET_NODE_LIST_GENERATE\n         6\n         1         2         4         4\n"
    assert _read(_write(tmp_path, HEAD + NODES + SHELL + good)).n_nodes == 4  # a one-id range (4 4) is fine


def _generated_sets_deck(node_range: str, part_range: str) -> str:
    """The plate deck with a node set 6 and a part set 7 generated from the given ranges (``BEG END`` fields): 2 kg
    shared by set 6's nodes (*ELEMENT_MASS_NODE_SET) and 1 kg added to set 7's parts (*ELEMENT_MASS_PART_SET)."""
    return (
        HEAD
        + NODES
        + SHELL
        + f"*SET_NODE_LIST_GENERATE\n         6\n{node_range}\n*SET_PART_LIST_GENERATE\n         7\n{part_range}\n"
        + "*ELEMENT_MASS_NODE_SET\n       9       6       2.000e-03\n*ELEMENT_MASS_PART_SET\n       7       1.000e-03\n"
    )


@pytest.mark.parametrize(
    ("node_range", "part_range"),
    [
        ("         11000000000", "         1         1"),  # a billion node ids over a deck of 4 nodes
        ("         2         3         3 999999999         1         1", "         1 999999999"),  # overlapping
        ("   9999996  99999999         1         4", "        99       100         1         1"),  # empty, then all
        ("         1       100", "         1        50"),  # a small range over ids the deck lacks
    ],
    ids=["billion", "overlapping", "gap-first", "beyond-the-deck"],
)
def test_a_generated_set_holds_the_defined_ids_of_its_ranges_whatever_their_size(tmp_path, node_range, part_range):
    """A *SET_..._GENERATE set holds every id the deck defines between BnBEG and BnEND (LS-DYNA: the ranges are
    limits on the ids, resolved after all input is read, so gaps in the numbering are no problem). The reader
    expanded each range into a Python list of every id in it: ten million ids (its cap then) cost about 0.4 GB,
    ``1 1000000000`` was refused as a typo, and a range over ids the deck lacks (``1 100`` over nodes 1-4) was
    refused by *ELEMENT_MASS_NODE_SET ('lists undefined node 5') and by a sub-assembly map. Ranges are now held as
    their ends and resolved against the deck's ids: the billion-id set is the deck's 4 nodes, at a cost in memory
    that does not grow with the range."""
    import tracemalloc

    ref = _read(_write(tmp_path, _generated_sets_deck("         1         4", "         1         1"), "ref.k"))
    deck = _write(tmp_path, _generated_sets_deck(node_range, part_range))
    tracemalloc.start()
    try:
        m = _read(deck, subassemblies={"front": ["set:7"]})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"reading a 4-node deck took {peak / 1e6:.0f} MB at its peak"
    assert m.subassemblies == {"front": [1]}
    assert np.array_equal(m.point_mass_nodes, ref.point_mass_nodes) and m.point_mass.tolist() == [0.5] * 4
    assert m.part_added_mass == ref.part_added_mass == pytest.approx({1: 1.0})
    assert m.total_mass() == pytest.approx(ref.total_mass(), rel=1e-12)


def test_a_generated_set_range_just_under_the_former_cap_costs_no_memory_of_its_size(tmp_path):
    """Ten million ids less four (just under the cap the reader had, MAX_GENERATED_IDS) in the node set an
    *INITIAL_VELOCITY sets moving, over a 4-node deck: the reader built a list of every id in the range (hundreds of
    MB at its peak); now it holds the range's ends and resolves them against the deck's nodes."""
    import tracemalloc

    sets = "*SET_NODE_LIST_GENERATE\n         6\n         1   9999996\n*INITIAL_VELOCITY\n         6\n  -15640.0\n"
    deck = _write(tmp_path, HEAD + NODES + SHELL + sets)
    tracemalloc.start()
    try:
        m = _read(deck)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"reading a 4-node deck took {peak / 1e6:.0f} MB at its peak"
    assert m.n_nodes == 4 and m.left_out == {} and not any("initial velocit" in w for w in m.warnings)


def test_resolving_sets_sorts_the_node_ids_it_needs_and_does_not_hash_them(tmp_path, monkeypatch):
    """The ranges of generated sets are resolved against the deck's node ids, which were passed through
    ``np.unique`` in every deck, with or without a generated set: numpy 2's hash-based ``unique`` takes about 0.4 s
    per 160,000 int64 ids (2.6 s per million, 70 times a sort), and reading a 160,000-node deck took nearly 40 %
    longer than before the ranges were resolved. The ids are unique already (a node defined twice is refused): they
    are sorted, and only where a node set has ranges."""
    from marlcrash.vehicle.keyword import _IdSet, _resolve_sets, _Tables

    def refused(*args, **kwargs):
        raise AssertionError("np.unique over the deck's node ids")

    ids = np.random.default_rng(0).permutation(np.arange(1, 2001, dtype=np.int64))  # in file order, unsorted
    none = np.zeros(0, dtype=np.int64)
    listed = _IdSet("listed", np.array([7, 3], dtype=np.int64), np.zeros((0, 2), dtype=np.int64))
    generated = _IdSet("generated", none, np.array([[5, 8], [1990, 10**9], [6, 9]], dtype=np.int64))
    monkeypatch.setattr(np, "unique", refused)
    t = _Tables(node_set_cards={5: listed, 6: generated})
    _resolve_sets(t, ids)
    assert t.node_sets[5][1].tolist() == [7, 3] and t.node_sets[6][1].tolist() == [5, 6, 7, 8, *range(1990, 2001), 9]
    monkeypatch.setattr(np, "sort", refused)  # no ranges: the ids are not even sorted
    t = _Tables(node_set_cards={5: listed})
    _resolve_sets(t, ids)
    assert t.node_sets[5][1].tolist() == [7, 3]
    monkeypatch.undo()
    nodes = "*NODE\n" + "".join(NODES.splitlines(keepends=True)[:0:-1])  # defined last to first
    deck = _generated_sets_deck("         3         4         2         3", "         1         1")
    m = _read(_write(tmp_path, deck.replace(NODES, nodes)))
    assert sorted(m.node_ids[m.point_mass_nodes].tolist()) == [2, 3, 4]
    assert m.point_mass.tolist() == pytest.approx([2 / 3] * 3)


def test_a_generated_set_that_holds_no_defined_id_is_named(tmp_path):
    """A generated node set whose ranges hold none of the deck's nodes is empty: what refers to it says so."""
    with pytest.raises(DeckError, match=r"\*ELEMENT_MASS_NODE_SET 9 refers to empty node set 6"):
        _read(_write(tmp_path, _generated_sets_deck("       100       200", "         1         1")))


def test_a_utf8_byte_order_mark_is_no_data(tmp_path):
    """A deck saved by a Windows editor starts with a byte-order mark; it was refused ('expected a keyword line
    starting with '*', got data '\\ufeff*KEYWORD'), in an included file too."""
    ref = _read(_write(tmp_path, HEAD + NODES + SHELL))
    (tmp_path / "nodes.k").write_bytes(b"\xef\xbb\xbf" + NODES.encode())
    p = tmp_path / "bom.k"
    p.write_bytes(b"\xef\xbb\xbf" + (HEAD + "*INCLUDE\nnodes.k\n" + SHELL).encode())
    m = _read(p)
    assert np.array_equal(m.coords, ref.coords) and m.total_mass() == ref.total_mass()
    p.write_bytes(b"\xef\xbb\xbf" + (HEAD + NODES + SHELL.replace("       4\n", "       9\n")).encode())
    with pytest.raises(DeckError, match=r"bom\.k line 18: shell element 1 refers to undefined node 9"):
        _read(p)  # line numbers as the editor shows them


def test_a_fixed_format_parameter_expression_may_hold_commas(tmp_path):
    """'R t3      max(t1,t2)' (fixed format: name in columns 1-10, expression after) was split at its comma as free
    format, so any expression calling max, min or atan2 was refused."""
    params = "*PARAMETER\nR t1      1.0\nR t2      2.0\n*PARAMETER_EXPRESSION\n"
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    for line, t3 in (
        ("R t3      max(t1,t2)", 2.0),
        ("Rt3       min(t1, t2)+atan2(0.0,1.0)", 1.0),
        ("R t3,max(t1,t2)+1", 3.0),  # free format: a comma right after the name
        ("I t3,  2*t2", 4.0),
    ):
        m = _read(_write(tmp_path, params + line + "\n" + head.replace("*KEYWORD\n", "") + NODES + SHELL))
        assert m.shell_thickness[0] == pytest.approx(t3 * 1e-3), line


@pytest.mark.parametrize("line", ["R thk", "R thk     ", "I n  "])
def test_a_parameter_expression_without_an_expression_is_named(tmp_path, line):
    """A line with a type and a name only crashed the reader with Python's 'not enough values to unpack': with no
    comma in it, the whole line looked like the head of a free-format line."""
    p = _write(tmp_path, f"*KEYWORD\n*PARAMETER_EXPRESSION\n{line}\n" + HEAD.replace("*KEYWORD\n", "") + NODES + SHELL)
    with pytest.raises(DeckError, match=r"deck\.k line 3: \*PARAMETER_EXPRESSION expects an arithmetic expression"):
        _read(p)


@pytest.mark.parametrize(
    ("expr", "value"),
    [
        ("mod(7.5,2)+mod(-7,3)", 1.5 - 1.0),  # Fortran's MOD takes the sign of its first argument: -1, not 2
        ("sign(3,-1)+sign(-2,5)*2", -3.0 + 4.0),  # |a| with the sign of b
        ("sinh(1)+cosh(1)-tanh(0.5)", math.sinh(1) + math.cosh(1) - math.tanh(0.5)),
        ("MOD(10, 4)", 2.0),  # names of functions in any case
    ],
)
def test_a_parameter_expression_calls_mod_sign_and_the_hyperbolic_functions(tmp_path, expr, value):
    """*PARAMETER_EXPRESSION takes Fortran's intrinsic functions; MOD, SIGN, SINH, COSH and TANH were refused ('expects
    an arithmetic expression')."""
    params = f"*PARAMETER_EXPRESSION\nR t3,10+{expr}\n"
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    m = _read(_write(tmp_path, params + head.replace("*KEYWORD\n", "") + NODES + SHELL))
    assert m.shell_thickness[0] == pytest.approx((10 + value) * 1e-3, rel=1e-12)


def test_a_parameter_expression_may_use_parameters_named_as_python_keywords(tmp_path):
    """Expressions were parsed as Python: a parameter named ``in`` (an inch), ``lambda`` or ``as`` made the expression
    a syntax error ('expects an arithmetic expression'), and one named ``True`` read as 1."""
    params = (
        "*PARAMETER\nR in      25.4\nR lambda  0.5\nR True    3.0\n*PARAMETER_EXPRESSION\nR t3,in*0.1*lambda+True\n"
    )
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    m = _read(_write(tmp_path, params + head.replace("*KEYWORD\n", "") + NODES + SHELL))
    assert m.shell_thickness[0] == pytest.approx((25.4 * 0.1 * 0.5 + 3.0) * 1e-3, rel=1e-12)


def test_an_expression_using_a_later_expression_says_so(tmp_path):
    """Expressions are evaluated in deck order; one using a parameter that a later expression defines was refused as
    'used but not defined in the deck; define it with *PARAMETER', though the deck defines it. The message now names
    the later definition."""
    params = "*PARAMETER_EXPRESSION\nR t3,2*t4\n$ t4 is defined below\nR t4,1.5\n"
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    with pytest.raises(DeckError, match=r"deck\.k line 2: parameter 't4' is used before it is defined: its "
                       r"\*PARAMETER_EXPRESSION \(deck\.k line 4\) comes later"):  # fmt: skip
        _read(_write(tmp_path, params + head.replace("*KEYWORD\n", "") + NODES + SHELL))
    with pytest.raises(DeckError, match=r"deck\.k line 2: \*PARAMETER_EXPRESSION 't3' uses itself"):
        _read(_write(tmp_path, "*PARAMETER_EXPRESSION\nR t3,t3+1\n" + head.replace("*KEYWORD\n", "") + NODES + SHELL))


def test_mod_by_zero_in_a_parameter_expression_is_named(tmp_path):
    params = "*PARAMETER_EXPRESSION\nR t3,mod(1,0)\n"
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    with pytest.raises(DeckError, match=r"deck\.k line 2: \*PARAMETER_EXPRESSION expects an arithmetic expression, "
                       r"got 'mod\(1,0\)'"):  # fmt: skip
        _read(_write(tmp_path, params + head.replace("*KEYWORD\n", "") + NODES + SHELL))


def test_nint_in_a_parameter_expression_rounds_halves_away_from_zero_as_fortran(tmp_path):
    """NINT(2.5) is 3 in Fortran (and LS-DYNA); it was Python's round, which gives 2 (halves to even)."""
    params = "*PARAMETER_EXPRESSION\nR t3,nint(2.5)-nint(-0.5)-nint(-1.5)+nint(0.4)\n"  # 3 - (-1) - (-2) + 0 = 6
    head = HEAD.replace("       2.0       2.0       2.0       2.0\n", "       &t3\n")
    m = _read(_write(tmp_path, params + head.replace("*KEYWORD\n", "") + NODES + SHELL))
    assert m.shell_thickness[0] == pytest.approx(6e-3)


def test_keywords_joining_nodes_are_named_where_they_stand(tmp_path):
    """*NODE_MERGE, *CONSTRAINED_NODE_SET, *CONSTRAINED_SPOTWELD ... join nodes; the reader does not follow them,
    and they were only counted in the skipped-cards summary (no file, no line, no word of what they change). Each
    such keyword now gets one warning naming its first file and line and how many blocks there are."""
    joins = "*NODE_MERGE\n0.01\n*CONSTRAINED_NODE_SET\n1,123\n*CONSTRAINED_SPOTWELD\n1,2\n*CONSTRAINED_SPOTWELD\n3,4\n"
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = read_deck(_write(tmp_path, HEAD + NODES + SHELL + joins))
    msgs = [str(r.message) for r in rec if issubclass(r.category, UserWarning)]
    for kw, line, more in (("NODE_MERGE", 19, ""), ("CONSTRAINED_NODE_SET", 21, ""), ("CONSTRAINED_SPOTWELD", 23, 2)):
        hits = [w for w in msgs if f"*{kw} " in w and "not followed" in w]
        assert len(hits) == 1, (kw, msgs)
        assert f"deck.k line {line}" in hits[0] and (not more or f"{more} blocks" in hits[0])
        assert any(w in hits[0] for w in m.warnings)
    assert m.skipped_cards["CONSTRAINED_SPOTWELD"] == 2  # still counted among the skipped cards


def test_include_names_written_with_backslashes_resolve(tmp_path):
    """A deck written on Windows names its includes ``sub\\mesh.k``: on Linux that is one file name with a
    backslash in it, which did not exist, and the deck was refused. Where the name as written is not found, its
    backslashes are read as folder separators; a file whose name really holds a backslash still wins."""
    sub = tmp_path / "sub"
    (sub / "deeper").mkdir(parents=True)
    _write(sub / "deeper", "*KEYWORD\n" + SHELL + "*END\n", "elems.k")
    _write(sub, "*KEYWORD\n" + NODES + "*INCLUDE\ndeeper\\elems.k\n*END\n", "mesh.k")
    m = _read(_write(tmp_path, HEAD + "*INCLUDE\n.\\sub\\mesh.k\n*END\n"))
    assert m.n_nodes == 4 and m.n_shells == 1
    m = _read(_write(tmp_path, HEAD + "*INCLUDE_PATH\nsub\\deeper\n*INCLUDE\nelems.k\n" + NODES + "*END\n", "p.k"))
    assert m.n_nodes == 4 and m.n_shells == 1  # an *INCLUDE_PATH folder too
    _write(tmp_path, "*KEYWORD\n" + NODES + SHELL + "*END\n", "lit\\x.k")  # a name holding a backslash
    (tmp_path / "lit").mkdir()
    _write(tmp_path / "lit", "*KEYWORD\n*END\n", "x.k")
    m = _read(_write(tmp_path, HEAD + "*INCLUDE\nlit\\x.k\n*END\n", "lit.k"))
    assert m.n_nodes == 4 and m.n_shells == 1
    with pytest.raises(DeckError, match=r"bad.k line 13: \*INCLUDE file 'sub\\\\none.k' not found"):
        _read(_write(tmp_path, HEAD + "*INCLUDE\nsub\\none.k\n*END\n", "bad.k"))


def test_shells_without_any_thickness_are_named_with_their_part_and_line(tmp_path):
    """A shell whose element card and part section both give no thickness gets no mass: only the summary's notes
    said so, and the mass was gone from every later figure without a word on the screen."""
    body = HEAD + NODES + SHELL + _part_with_shell(2, "0.0") + "*END\n"
    with pytest.warns(UserWarning, match=r"deck\.k: 1 shells in parts \[2\] have neither element nor section "
                      r"thickness .* the first deck\.k line 31: they get no mass"):  # fmt: skip
        m = read_deck(_write(tmp_path, body))
    assert m.element_masses()["shell"][1] == 0.0
    assert any("shells in parts [2]" in w for w in m.warnings)
    with warnings.catch_warnings():  # a deck whose shells all have a thickness says nothing of it
        warnings.simplefilter("error", UserWarning)
        read_deck(_write(tmp_path, HEAD + NODES + SHELL + _part_with_shell(2, "1.0") + "*END\n", "ok.k"))


def test_a_rigid_body_merge_of_an_undefined_or_deformable_part_is_named_where_it_stands(tmp_path):
    """LS-DYNA refuses a *CONSTRAINED_RIGID_BODIES pair whose parts are not both rigid; the reader dropped it without
    a word (a rigid part merged into a fixed barrier then stayed vehicle structure)."""
    body = HEAD + NODES + SHELL + "*CONSTRAINED_RIGID_BODIES\n         1        99\n*END\n"
    with pytest.warns(
        UserWarning,
        match=r"deck\.k: \*CONSTRAINED_RIGID_BODIES \(deck\.k line 20\): PIDM 1 is not rigid \(no \*MAT_RIGID\) and "
        r"PIDS 99 is not a part of the deck; the pair is not merged",
    ):
        m = read_deck(_write(tmp_path, body))
    assert any("PIDS 99 is not a part" in w for w in m.warnings)
    assert m.n_shells == 1  # the deck is read on
