"""Core data model: units, materials, VehicleModel geometry and validation, axis maps, config plumbing."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pytest

from marlcrash.config import from_dict, load_config, load_yaml, require
from marlcrash.errors import ConfigError, ModelError
from marlcrash.units import UNIT_SYSTEMS, detect_unit_system, get_unit_system
from marlcrash.vehicle.materials import Material, complete_material, mass_weighted
from marlcrash.vehicle.model import AxisMap, Part, VehicleModel


def _steel(mid: int = 1) -> Material:
    return complete_material(Material(mid, "steel", "plastic_kinematic", 7850.0, 2.1e11, yield_strength=3.5e8))


def _box_model() -> VehicleModel:
    """A unit cube solid, a tetrahedron solid, one quad shell and one triangle shell, one beam."""
    coords = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float
    )
    return VehicleModel(
        node_ids=np.arange(1, 9),
        coords=coords,
        shell_ids=np.array([10, 11]),
        shell_part=np.array([2, 2]),
        shell_nodes=np.array([[0, 1, 2, 3], [0, 1, 5, 5]]),
        shell_thickness=np.array([0.002, 0.001]),
        solid_ids=np.array([20, 21]),
        solid_part=np.array([1, 1]),
        solid_nodes=np.array([[0, 1, 2, 3, 4, 5, 6, 7], [0, 1, 3, 4, 4, 4, 4, 4]]),
        beam_ids=np.array([30]),
        beam_part=np.array([3]),
        beam_nodes=np.array([[0, 6]]),
        beam_area=np.array([1e-4]),
        parts={1: Part(1, "block", 1), 2: Part(2, "skin", 1, thickness=0.002), 3: Part(3, "rod", 1, beam_area=1e-4)},
        materials={1: _steel()},
        subassemblies={"front": [1, 2]},
    )


def test_unit_system_conversions():
    mm_t_s = get_unit_system("mm-t-s")
    assert mm_t_s.density == pytest.approx(1e12)  # t/mm^3 -> kg/m^3
    assert mm_t_s.stress == pytest.approx(1e6)  # MPa -> Pa
    assert mm_t_s.force == pytest.approx(1.0)  # N
    mm_kg_ms = get_unit_system("mm-kg-ms")
    assert mm_kg_ms.stress == pytest.approx(1e9)  # GPa
    assert mm_kg_ms.force == pytest.approx(1e3)  # kN
    assert mm_kg_ms.velocity == pytest.approx(1.0)  # mm/ms = m/s
    mm_g_ms = get_unit_system("mm-g-ms")
    assert (mm_g_ms.density, mm_g_ms.stress, mm_g_ms.force) == pytest.approx((1e6, 1e6, 1.0))  # g/mm^3, MPa, N
    cm_g_us = get_unit_system("cm-g-us")
    assert (cm_g_us.density, cm_g_us.stress, cm_g_us.force) == pytest.approx((1e3, 1e11, 1e7))  # g/cm^3, Mbar
    in_lbf_s = get_unit_system("in-lbf-s")
    assert in_lbf_s.force == pytest.approx(4.4482216152605)  # lbf
    assert in_lbf_s.stress == pytest.approx(6894.757293168)  # psi
    assert in_lbf_s.mass == pytest.approx(175.126835246)  # lbf s^2/in
    assert in_lbf_s.velocity == pytest.approx(0.0254)  # in/s
    with pytest.raises(ConfigError, match="unknown unit system 'furlong-firkin-fortnight'"):
        get_unit_system("furlong-firkin-fortnight")


@pytest.mark.parametrize("name", sorted(UNIT_SYSTEMS))
def test_detect_unit_system_steel(name):
    u = UNIT_SYSTEMS[name]
    rho = np.array([7850.0, 2700.0, 7850.0]) / u.density
    e = np.array([2.1e11, 7e10, 2.1e11]) / u.stress
    assert detect_unit_system(rho, e) == u


@pytest.mark.parametrize("name", sorted(UNIT_SYSTEMS))
@pytest.mark.parametrize(
    "materials",
    [
        [(7850.0, 2.1e11)],  # steel
        [(2700.0, 7e10)],  # aluminium
        [(1200.0, 2e9)],  # a polymer
        [(78500.0, 2.1e11)],  # steel mass-scaled 10x
        [(7850.0, 2.1e11), (50.0, 2e6), (1000.0, 5e9), (7850.0, 2.1e11)],  # with a foam and a fabric
    ],
    ids=["steel", "aluminium", "polymer", "mass-scaled", "mixed"],
)
def test_detect_unit_system_is_unique_for_every_system_and_material(name, materials):
    # mm-g-ms and in-lbf-s densities differ by 10.7x only: a steel deck in one must not also fit the other
    u = UNIT_SYSTEMS[name]
    rho, e = (np.array(v) for v in zip(*materials, strict=True))
    assert detect_unit_system(rho / u.density, e / u.stress) == u


def test_detect_unit_system_wants_one_modulus_per_density():
    with pytest.raises(ValueError, match="one modulus per density"):
        detect_unit_system(np.array([7.85e-9, 2.7e-9]), np.array([2.1e5]))


def test_detect_unit_system_ambiguous_or_empty():
    assert detect_unit_system(np.array([]), np.array([])) is None
    assert detect_unit_system(np.array([1e-30]), np.array([1.0])) is None


def test_complete_material_derives_and_warns():
    m = complete_material(Material(7, "alu", "elastic", 2700.0, 7e10, poisson_ratio=0.33))
    assert m.shear_modulus == pytest.approx(7e10 / (2 * 1.33))
    assert m.bulk_modulus == pytest.approx(7e10 / (3 * (1 - 0.66)))
    assert m.yield_strength > 0 and m.ultimate_strength >= m.yield_strength
    assert any("yield strength missing" in w for w in m.warnings)
    assert np.isfinite(m.vector()).all() and m.vector().shape == (8,)


def test_an_ultimate_strength_below_yield_is_raised_with_a_warning():
    """The ultimate strength was silently raised to the yield strength: a value the source gave, changed unsaid."""
    m = complete_material(Material(4, "odd", "plastic_kinematic", 7850.0, 2.1e11, yield_strength=4e8,
                                   ultimate_strength=3e8, fracture_strength=3e8))  # fmt: skip
    assert m.ultimate_strength == 4e8
    assert any("ultimate strength 3e+08 Pa is below the yield strength 4e+08 Pa" in w for w in m.warnings)
    ok = complete_material(Material(5, "dp600", "plastic_kinematic", 7850.0, 2.1e11, yield_strength=3.8e8,
                                    ultimate_strength=6.2e8, fracture_strength=5.6e8))  # fmt: skip
    assert ok.ultimate_strength == 6.2e8 and not any("ultimate" in w for w in ok.warnings)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"density": math.nan, "youngs_modulus": 2e11}, "density"),
        ({"density": 7850.0, "youngs_modulus": 0.0}, "Young"),
        ({"density": 7850.0, "youngs_modulus": 2e11, "poisson_ratio": 0.6}, "Poisson"),
        ({"density": 7850.0, "youngs_modulus": 2e11, "yield_strength": -4e8}, "yield strength must be > 0 .* -4e"),
        ({"density": 7850.0, "youngs_modulus": 2e11, "ultimate_strength": -1.0}, "ultimate strength must be > 0"),
    ],
)
def test_complete_material_rejects(kwargs, match):
    with pytest.raises(ModelError, match=match):
        complete_material(Material(3, "bad", "elastic", **kwargs))


def test_mass_weighted_aggregate():
    v = np.array([[1.0] * 8, [3.0] * 8])
    np.testing.assert_allclose(mass_weighted(v, np.array([1.0, 3.0])), [2.5] * 8)
    np.testing.assert_allclose(mass_weighted(v, np.zeros(2)), np.zeros(8))


def test_geometry_against_closed_forms():
    m = _box_model()
    np.testing.assert_allclose(m.solid_volumes(), [1.0, 1.0 / 6.0], rtol=1e-12)
    np.testing.assert_allclose(m.shell_areas(), [1.0, 0.5], rtol=1e-12)
    np.testing.assert_allclose(m.beam_lengths(), [math.sqrt(3.0)], rtol=1e-12)
    masses = m.part_masses()
    assert masses[1] == pytest.approx(7850.0 * (1 + 1 / 6))
    assert masses[2] == pytest.approx(7850.0 * (0.002 + 0.5 * 0.001))
    assert masses[3] == pytest.approx(7850.0 * math.sqrt(3.0) * 1e-4)
    assert m.total_mass() == pytest.approx(sum(masses.values()))


def test_boundary_faces_of_two_bricks_drop_the_shared_face():
    coords = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1, 2)], dtype=float)

    # node index = x + 3*y + 6*z
    def n(x, y, z):
        return x + 3 * y + 6 * z

    bricks = [
        [n(i, 0, 0), n(i + 1, 0, 0), n(i + 1, 1, 0), n(i, 1, 0), n(i, 0, 1), n(i + 1, 0, 1), n(i + 1, 1, 1), n(i, 1, 1)]
        for i in (0, 1)
    ]
    m = _box_model()
    m.coords, m.node_ids = coords, np.arange(1, 13)
    m.solid_nodes, m.solid_ids, m.solid_part = np.array(bricks), np.array([1, 2]), np.array([1, 1])
    m.shell_nodes, m.shell_ids, m.shell_part, m.shell_thickness = (
        np.zeros((0, 4), int),
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros(0),
    )
    m.beam_nodes, m.beam_ids, m.beam_part, m.beam_area = (
        np.zeros((0, 2), int),
        np.zeros(0, int),
        np.zeros(0, int),
        np.zeros(0),
    )
    tri, _ = m.solid_boundary_triangles()
    assert tri.shape[0] == 20  # 10 outer quads, 2 triangles each
    mesh = m.part_mesh(1)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(2.0)


def test_validate_names_the_problem():
    m = _box_model()
    m.validate()
    bad = _box_model()
    bad.coords[3, 1] = np.nan
    with pytest.raises(ModelError, match="node 4 has a non-finite"):
        bad.validate()
    bad = _box_model()
    bad.shell_part[1] = 99
    with pytest.raises(ModelError, match="shell 11 refers to unknown part 99"):
        bad.validate()
    bad = _box_model()
    bad.solid_nodes[0, 0] = 50
    with pytest.raises(ModelError, match="solid 20 refers to a node index"):
        bad.validate()
    with pytest.raises(ModelError, match="part 1 is in two sub-assemblies"):
        _box_model().with_subassemblies({"a": [1], "b": [1, 2]})


@pytest.mark.parametrize("area", [-1e-4, math.nan, math.inf])
def test_validate_refuses_a_negative_or_non_finite_beam_area(area):
    """Shell thickness was checked, beam area not: a negative area gave the beam a negative mass without a word."""
    bad = _box_model()
    bad.beam_area[0] = area
    with pytest.raises(ModelError, match=r"beam 30's cross-sectional area must be finite and >= 0 m\^2"):
        bad.validate()


@pytest.mark.parametrize("thickness", [-1e-3, math.nan, -math.inf])
def test_validate_names_the_shell_whose_thickness_is_negative_or_not_finite(thickness):
    """The message said 'shell thickness must be finite and >= 0' and no more: which of a million shells, and what
    value, was left to find. It names the shell and its value now, as the beam area's does."""
    bad = _box_model()
    bad.shell_thickness[1] = thickness
    with pytest.raises(ModelError, match=rf"shell 11's thickness must be finite and >= 0 m, got {thickness}$"):
        bad.validate()


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("density", -7850.0, r"density must be finite and >= 0 kg/m\^3, got -7850.0"),
        ("density", math.nan, r"density must be finite and >= 0 kg/m\^3, got nan \(missing: complete_material"),
        ("youngs_modulus", 0.0, r"Young's modulus must be finite and > 0 Pa, got 0.0"),
        ("shear_modulus", -1.0, r"shear modulus must be finite and > 0 Pa, got -1.0"),
        ("bulk_modulus", math.inf, r"bulk modulus must be finite and > 0 Pa, got inf"),
        ("yield_strength", -3.5e8, r"yield strength must be finite and > 0 Pa, got -350000000.0"),
        ("ultimate_strength", math.nan, r"ultimate strength must be finite and > 0 Pa, got nan \(missing"),
        ("fracture_strength", 0.0, r"fracture strength must be finite and > 0 Pa, got 0.0"),
        ("poisson_ratio", 0.5, r"Poisson's ratio must lie in \(-1, 0.5\), got 0.5"),
    ],
)
def test_validate_refuses_a_material_value_that_is_not_physical(field, value, message):
    """Materials were not checked: one made in Python with a negative yield strength or a zero Young's modulus
    passed, and the default car discretized with it without a word; a NaN strength stopped the discretizer with
    'CellModel.params contains non-finite values' and a negative density with 'their density or thickness is 0',
    neither naming the material. validate names the material, the value and what was expected, as
    complete_material does for a read one."""
    bad = _box_model()
    bad.materials = {1: dataclasses.replace(bad.materials[1], **{field: value})}
    with pytest.raises(ModelError, match=r"vehicle: material 1 \(steel\)'s " + message):
        bad.validate()


def test_validate_refuses_a_part_whose_elements_weigh_nothing():
    """A density of 0 passed validate: the part's elements weighed nothing and own no cell, and the discretizer said
    so only as 'sub-assembly ... has no mass' (or, for a part grouped with heavier ones, not at all: its strength
    dropped out of the cells). validate names the part and its material now; a material of density 0 that no part
    with elements uses, or whose part's mass is set (``part_mass``, a rigid part's *PART_INERTIA), stays valid."""
    bad = _box_model()
    bad.materials = {1: bad.materials[1], 2: dataclasses.replace(bad.materials[1], id=2, name="foam", density=0.0)}
    bad.validate()  # used by no part
    bad.parts[2] = Part(2, "skin", 2, thickness=0.002)
    with pytest.raises(ModelError, match=r"vehicle: part 2 \('skin', 2 elements\) is of material 2 \(foam\), whose "
                       r"density is 0, and no part mass sets its own: its elements would weigh nothing; expected a "
                       r"density > 0 kg/m\^3"):  # fmt: skip
        bad.validate()
    bad.part_mass = {2: 1.5}
    bad.validate()
    assert bad.part_masses()[2] == pytest.approx(1.5)


def test_validate_refuses_a_part_or_material_filed_under_another_id(tmp_path):
    """``parts`` and ``materials`` map an id to the part or material of that id, and nothing checked it: a material
    filed under 1 with id 7 passed, and write_deck (which writes the card's own id) gave a deck its reader refused
    ('*PART 1 refers to undefined material 1'); a part filed under 3 with id 9 read back as part 3 without a word."""
    from marlcrash.vehicle.keyword_writer import write_deck

    bad = _box_model()
    bad.materials = {1: dataclasses.replace(bad.materials[1], id=7)}
    with pytest.raises(ModelError, match=r"vehicle: materials\[1\] is material 7 \('steel'\); expected material 1"):
        bad.validate()
    with pytest.raises(ModelError, match=r"materials\[1\] is material 7"):
        write_deck(bad, tmp_path / "car.k")
    assert list(tmp_path.iterdir()) == []
    bad = _box_model()
    bad.parts = {**bad.parts, 3: dataclasses.replace(bad.parts[3], id=9)}
    with pytest.raises(ModelError, match=r"vehicle: parts\[3\] is part 9 \('rod'\); expected part 3"):
        bad.validate()


@pytest.mark.parametrize(
    ("kind", "ids", "message"),
    [
        ("node", np.array([1, 2, 3, 4, 5, 6, 7, 1]), r"node id 1 is given twice \(node indices 0 and 7\)"),
        ("shell", np.array([10, 10]), r"shell id 10 is given twice \(shell indices 0 and 1\)"),
        ("solid", np.array([21, 21]), r"solid id 21 is given twice \(solid indices 0 and 1\)"),
    ],
)
def test_validate_refuses_a_repeated_node_or_element_id(tmp_path, kind, ids, message):
    """Node and element ids were not checked: a model made in Python with one id on two nodes (or two shells)
    passed, and the writer wrote a deck its own reader refused ('node id 1 is defined twice'). Ids of different
    element kinds may coincide, as the reader allows."""
    from marlcrash.vehicle.keyword_writer import write_deck

    bad = _box_model()
    setattr(bad, f"{kind}_ids", ids)
    with pytest.raises(ModelError, match=message + r"; expected each \w+ id once"):
        bad.validate()
    with pytest.raises(ModelError, match=message):
        write_deck(bad, tmp_path / "car.k")
    assert list(tmp_path.iterdir()) == []
    shared = _box_model()
    shared.solid_ids = shared.shell_ids.copy()  # a shell and a solid with one id: both LS-DYNA and the reader take it
    shared.validate()


def test_default_subassemblies_and_lookup():
    m = _box_model().with_default_subassemblies()
    assert m.subassemblies == {"front": [1, 2], "part_3": [3]}
    assert m.subassembly_of_part() == {1: "front", 2: "front", 3: "part_3"}


def test_axis_map_parse_and_transform():
    am = AxisMap.parse("x=+x,y=+z,z=+y")
    np.testing.assert_array_equal(am.matrix(), [[1, 0, 0], [0, 0, 1], [0, 1, 0]])
    m = _box_model()
    m.coords = m.coords * np.array([1.0, 2.0, 3.0]) + np.array([5.0, 6.0, 7.0])
    t = m.transformed(am)
    lo, hi = t.bounds()
    assert lo[0] == pytest.approx(0.0)  # front at x = 0
    assert lo[1] == pytest.approx(-hi[1])  # centred laterally
    assert hi[1] - lo[1] == pytest.approx(3.0)  # deck z extent became lateral
    assert lo[2] == pytest.approx(6.0)  # deck y became z, origin kept
    flipped = m.transformed(AxisMap(x="-x"))
    assert flipped.bounds()[0][0] == pytest.approx(0.0)
    # the last: z=+y meant, y typed twice; the identity z must not be kept without a word
    cases = [("x=+q", "deck axis"), ("x=+x,y=+x", "used twice"), ("w=+x", "expected items"),
             ("x=-x,y=+z,y=+y", "axis 'y' is given twice"),
             ("", "no axis given"), (" , ", "no axis given")]  # fmt: skip
    for text, match in cases:
        with pytest.raises(ConfigError, match=match):
            AxisMap.parse(text)


@dataclass
class _Inner:
    rate: float = 1.0

    def validate(self):
        require(self.rate > 0, "rate", f"must be > 0, got {self.rate}")


@dataclass
class _Outer:
    name: str = "x"
    count: int = 1
    inner: _Inner | None = None
    tags: list[str] | None = None


def test_from_dict_types_keys_and_validate(tmp_path):
    o = from_dict(_Outer, {"name": "a", "count": 3, "inner": {"rate": 2}, "tags": ["p"]})
    assert o.inner.rate == 2.0 and o.tags == ["p"]
    with pytest.raises(ConfigError, match="key 'colour': unknown key"):
        from_dict(_Outer, {"colour": 1})
    with pytest.raises(ConfigError, match="key 'count': expected an integer"):
        from_dict(_Outer, {"count": "3"})
    with pytest.raises(ConfigError, match=r"key 'inner\.rate': must be > 0"):
        from_dict(_Outer, {"inner": {"rate": -1.0}})
    f = tmp_path / "c.yaml"
    f.write_text("name: b\ninner:\n  rate: 0.5\n")
    assert load_config(_Outer, f, overrides={"inner.rate": 4.0}).inner.rate == 4.0
    f.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: invalid YAML at line"):
        load_config(_Outer, f)
    # a key given twice: PyYAML kept the last one without a word
    f.write_text("name: b\ninner:\n  rate: 0.5\n  rate: 2.0\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: invalid YAML at line 4: key 'rate' given twice \(first at line 3"):
        load_config(_Outer, f)
    f.write_text("name: b\ninner: {rate: 0.5, rate: 2.0}\n")  # one line: the check compared lines only
    with pytest.raises(ConfigError, match=r"line 2: key 'rate' given twice \(first at line 2, column 9\)"):
        load_config(_Outer, f)
    f.write_text("base: &b {rate: 1.0}\ninner:\n  <<: *b\n")  # a merge key is not a repeated key
    assert load_yaml(f)["inner"] == {"rate": 1.0}


def test_from_dict_takes_numpy_integers_where_it_takes_an_int():
    """A computed override (``np.int64`` from numpy arithmetic) was refused: "expected an integer, got np.int64(3)"."""
    o = from_dict(_Outer, {"count": np.int64(3), "inner": {"rate": np.int32(2)}})
    assert o.count == 3 and type(o.count) is int
    assert o.inner.rate == 2.0 and type(o.inner.rate) is float
    for flag in (True, np.True_):  # a bool is still no integer
        with pytest.raises(ConfigError, match="key 'count': expected an integer"):
            from_dict(_Outer, {"count": flag})
        with pytest.raises(ConfigError, match=r"key 'inner\.rate': expected a number"):
            from_dict(_Outer, {"inner": {"rate": flag}})


def test_a_poisson_ratio_of_zero_is_kept_and_only_a_missing_one_defaulted():
    """nu = 0 (cork, some foams and honeycombs) was read as missing and defaulted to 0.3 with a warning."""
    m = complete_material(Material(8, "cork", "elastic", 240.0, 3e7, poisson_ratio=0.0))
    assert m.poisson_ratio == 0.0 and not any("Poisson" in w for w in m.warnings)
    assert m.shear_modulus == pytest.approx(3e7 / 2) and m.bulk_modulus == pytest.approx(3e7 / 3)
    missing = complete_material(Material(9, "blank", "elastic", 240.0, 3e7))  # nan: not given
    assert missing.poisson_ratio == 0.3 and any("Poisson's ratio missing, defaulted to 0.3" in w
                                                 for w in missing.warnings)  # fmt: skip
