"""Masses a deck adds beyond density times volume: *ELEMENT_MASS, *ELEMENT_INERTIA, *ELEMENT_MASS_PART, MAREA,
*SECTION_BEAM NSM, *PART_INERTIA (also of a body of extra nodes) and *CONSTRAINED_NODAL_RIGID_BODY_INERTIA.

References are hand computations on a two-shell plate in mm-t-s units (1 t = 1000 kg, 1 mm = 1e-3 m).
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from marlcrash.cells.discretize import discretize
from marlcrash.errors import DeckError
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.keyword_writer import write_deck
from marlcrash.vehicle.registry import load_vehicle
from marlcrash.vehicle.summary import format_vehicle_summary, vehicle_summary

RHO, T = 7850.0, 2e-3  # kg/m^3, m
A1, A2, A3 = 0.01, 0.005, 0.01  # shell areas [m^2]: 100 x 100, 100 x 50 (part 1), 100 x 100 (part 2)
M1, M2, M3 = (a * T * RHO for a in (A1, A2, A3))


def _deck(section_card2: str = "       2.0       2.0       2.0       2.0", part2: str = "*PART", mat2: str = "") -> str:
    mat2 = mat2 or "*MAT_ELASTIC\n         2  7.85e-09  210000.0       0.3\n"
    return f"""*KEYWORD
*PART
plate
         1         1         1
{part2}
second plate
         2         1         2
{{inertia}}*SECTION_SHELL
         1         2
{section_card2}
*MAT_ELASTIC
         1  7.85e-09  210000.0       0.3
{mat2}*NODE
       1
       2           100.0
       3           100.0           100.0
       4                           100.0
       5           100.0           150.0
       6                           150.0
       7           200.0
       8           200.0           100.0
*ELEMENT_SHELL
       1       1       1       2       3       4
       2       1       4       3       5       6
       3       2       2       7       8       3
"""


def _read(text: str, tmp_path, name: str = "deck.k", **kw):
    path = tmp_path / name
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return read_deck(path, **kw)


def _mass_line(eid: int, nid: int, tonnes: float, pid: int = 0) -> str:
    return f"{eid:8d}{nid:8d}{tonnes:16.6e}{pid:8d}\n"


def _part_line(pid: int, addmass: float = 0.0, finmass: float = 0.0) -> str:
    """An *ELEMENT_MASS_PART(_SET) card: PID I8, ADDMASS E16, FINMASS E16 (then LCID, not read)."""
    return f"{pid:8d}{addmass:16.6e}{finmass:16.6e}{0:8d}\n"


def test_plain_deck_has_no_added_mass(tmp_path):
    m = _read(_deck().format(inertia=""), tmp_path)
    assert m.point_mass.size == 0 and m.part_added_mass == {} and m.part_mass == {}
    assert m.part_masses() == pytest.approx({1: M1 + M2, 2: M3}, rel=1e-12)


def test_element_mass_on_nodes_and_node_sets(tmp_path):
    cards = (
        "*ELEMENT_MASS\n"
        + _mass_line(1, 3, 0.001)  # 1 kg on node 3
        + "*ELEMENT_MASS_NODE_SET\n"
        + _mass_line(2, 5, 0.002)  # 2 kg shared by the two nodes of set 5
        + "*SET_NODE_LIST\n         5\n         7         8\n"
    )
    m = _read(_deck().format(inertia="") + cards, tmp_path)
    got = dict(zip(m.node_ids[m.point_mass_nodes].tolist(), m.point_mass.tolist(), strict=True))
    assert got == pytest.approx({3: 1.0, 7: 1.0, 8: 1.0}, rel=1e-12)
    assert m.point_mass_ids.tolist() == [1, 2, 2]
    assert m.total_mass() == pytest.approx(M1 + M2 + M3 + 3.0, rel=1e-12)
    assert m.part_masses() == pytest.approx({1: M1 + M2, 2: M3}, rel=1e-12)  # point masses are on nodes
    s = vehicle_summary(m)
    assert s["point_mass_kg"] == pytest.approx(3.0) and s["n_point_masses"] == 3
    assert s["total_mass_kg"] == pytest.approx(m.total_mass())
    assert "3.000 kg in 3 point mass(es) on nodes" in format_vehicle_summary(s)


def test_element_mass_part_spreads_by_area_and_finmass_sets_the_total(tmp_path):
    base = _deck().format(inertia="")
    m = _read(base + "*ELEMENT_MASS_PART\n" + _part_line(1, 0.0003), tmp_path)  # ADDMASS 0.3 kg
    assert m.part_added_mass == pytest.approx({1: 0.3})
    np.testing.assert_allclose(m.element_added_masses()["shell"], [0.2, 0.1, 0.0], rtol=1e-12)  # 2:1 by area
    np.testing.assert_allclose(m.element_masses()["shell"], [M1, M2, M3], rtol=1e-12)  # structure unchanged
    assert m.part_masses()[1] == pytest.approx(M1 + M2 + 0.3, rel=1e-12)
    m = _read(base + "*ELEMENT_MASS_PART\n" + _part_line(1, 0.0003, 0.001), tmp_path)  # FINMASS 1 kg wins
    assert m.part_masses()[1] == pytest.approx(1.0, rel=1e-12)
    # a part set: the 0.3 kg over both parts by area (0.015 and 0.01 m^2)
    m = _read(
        base
        + "*ELEMENT_MASS_PART_SET\n"
        + _part_line(9, 0.0003)
        + "*SET_PART_LIST\n         9\n         1         2\n",
        tmp_path,
    )
    assert m.part_added_mass == pytest.approx({1: 0.18, 2: 0.12}, rel=1e-12)
    # FINMASS on the set: the set's total
    m = _read(
        base
        + "*ELEMENT_MASS_PART_SET\n"
        + _part_line(9, 0.0, 0.002)
        + "*SET_PART_LIST\n         9\n         1         2\n",
        tmp_path,
    )
    assert sum(m.part_masses().values()) == pytest.approx(2.0, rel=1e-12)
    add = 2.0 - (M1 + M2 + M3)  # spread by area, 0.015 : 0.01
    assert m.part_added_mass == pytest.approx({1: 0.6 * add, 2: 0.4 * add}, rel=1e-12)
    # the same card in the I10 form (PID I10, ADDMASS E16, FINMASS E16) and in long format (20 each)
    i10 = f"*ELEMENT_MASS_PART %\n{1:10d}{0.0003:16.6e}{0.0:16.6e}\n"
    assert _read(base + i10, tmp_path).part_added_mass == pytest.approx({1: 0.3})
    long = f"*ELEMENT_MASS_PART +\n{1:20d}{0.0003:20.6e}{0.0:20.6e}\n"
    assert _read(base + long, tmp_path).part_added_mass == pytest.approx({1: 0.3})
    # a blank MASS is LS-DYNA's default, 0
    m = _read(base + "*ELEMENT_MASS\n       1       3\n", tmp_path)
    assert m.point_mass.tolist() == [0.0] and m.total_mass() == pytest.approx(M1 + M2 + M3, rel=1e-12)


def test_marea_adds_mass_per_area(tmp_path):
    # MAREA 2e-9 t/mm^2 = 2 kg/m^2 on every shell of section 1 (both parts)
    m = _read(_deck("       2.0       2.0       2.0       2.0         0   2.0e-09").format(inertia=""), tmp_path)
    assert m.part_added_mass == pytest.approx({1: 2.0 * (A1 + A2), 2: 2.0 * A3}, rel=1e-9)
    assert m.total_mass() == pytest.approx(M1 + M2 + M3 + 2.0 * (A1 + A2 + A3), rel=1e-9)


RIGID = "*MAT_RIGID\n         2  7.85e-09  210000.0       0.3\n       0.0         0         0\n"
# XC YC ZC TM (5 kg) IRCS NODEID / IXX IXY IXZ IYY IYZ IZZ / VTX VTY VTZ VRX VRY VRZ
INERTIA = (
    "     150.0      50.0       0.0     0.005\n       1.0       0.0       0.0       1.0       0.0       1.0\n{vel}\n"
)


def test_part_inertia_sets_a_rigid_part_mass_and_its_velocity_counts(tmp_path):
    text = _deck(part2="*PART_INERTIA", mat2=RIGID).replace("{inertia}", INERTIA.format(vel=""))
    m = _read(text, tmp_path)
    assert m.part_mass == {2: pytest.approx(5.0)} and m.part_masses()[2] == pytest.approx(5.0, rel=1e-12)
    assert m.total_mass() == pytest.approx(M1 + M2 + 5.0, rel=1e-12)
    # on a deformable part LS-DYNA ignores it: so does the reader, with a note
    m = _read(_deck(part2="*PART_INERTIA").replace("{inertia}", INERTIA.format(vel="")), tmp_path)
    assert m.part_mass == {} and m.part_masses()[2] == pytest.approx(M3)
    assert any("*PART_INERTIA of part 2 ignored" in w for w in m.warnings)
    # nodes of part 1 alone move; the rigid part's only velocity is its *PART_INERTIA VTX: it moves, it stays
    moving = "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{-15640.0:10.1f}\n" for n in (1, 4, 5, 6))
    for vel, stays in ((f"{-15640.0:10.1f}", True), ("", False)):
        text = _deck(part2="*PART_INERTIA", mat2=RIGID).replace("{inertia}", INERTIA.format(vel=vel)) + moving
        m = _read(text, tmp_path)
        assert (2 in m.parts) == stays and (2 in m.left_out) != stays


def test_left_out_parts_take_their_masses_along(tmp_path):
    """A barrier at rest leaves with its point masses and added mass; the vehicle's stay."""
    moving = "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{-15640.0:10.1f}\n" for n in (1, 4, 5, 6))
    cards = "*ELEMENT_MASS\n" + _mass_line(1, 7, 0.001) + _mass_line(2, 6, 0.002)  # node 7: part 2 only
    cards += "*ELEMENT_MASS_PART\n" + _part_line(2, 0.0003) + ""
    m = _read(_deck().format(inertia="") + moving + cards, tmp_path)
    assert sorted(m.left_out) == [2]
    assert m.point_mass_ids.tolist() == [2] and m.part_added_mass == {}
    assert m.total_mass() == pytest.approx(M1 + M2 + 2.0, rel=1e-12)


def test_part_inertia_is_the_whole_mass_and_its_cards_come_before_contact(tmp_path):
    """TM is a rigid part's whole mass: MAREA and *ELEMENT_MASS_PART do not add to it. The inertia cards (and
    the IRCS card) come right after the part card; CONTACT cards follow; a block may hold several parts."""
    marea = "       2.0       2.0       2.0       2.0         0   2.0e-09"
    contact = "       0.3       0.2\n"  # FS FD: not a velocity
    ircs = INERTIA.format(vel="").replace("     0.005\n", "     0.005         1\n") + "       1.0       0.0       0.0\n"
    third = "third, no elements\n         3         1         2\n" + INERTIA.format(vel="")
    text = _deck(marea, "*PART_INERTIA_CONTACT", RIGID).replace("{inertia}", ircs + contact + third + contact)
    moving = "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{-15640.0:10.1f}\n" for n in (1, 4, 5, 6))
    m = _read(text + "*ELEMENT_MASS_PART\n" + _part_line(2, 0.0003), tmp_path)
    assert m.part_mass == {2: pytest.approx(5.0)} and m.part_masses()[2] == pytest.approx(5.0, rel=1e-12)
    assert m.part_added_mass == pytest.approx({1: 2.0 * (A1 + A2)}, rel=1e-9)  # part 1's MAREA only
    assert 3 in m.parts and 3 not in m.part_mass  # read from the same block; nothing to place its mass on
    said = "\n".join(m.warnings)
    assert "MAREA of section 1 not added" in said and "adds nothing to part(s) [2]" in said
    assert "*PART_INERTIA part 3 has neither elements nor *CONSTRAINED_EXTRA_NODES to place its 5 kg" in said
    # the friction card is not an initial velocity: the rigid part at rest is left out
    assert sorted(_read(text + moving, tmp_path).left_out) == [2]  # part 3 has no elements to leave out
    # a rotation alone does not move a body toward the barrier
    rot = _deck(part2="*PART_INERTIA", mat2=RIGID).replace("{inertia}", INERTIA.format(vel=f"{'':30}{1.0:10.1f}"))
    assert 2 in _read(rot + moving, tmp_path).left_out


@pytest.mark.parametrize(
    ("cards", "message"),
    [
        (
            "*ELEMENT_MASS_PART_SET\n" + _part_line(9, 0.0003) + "*SET_PART_LIST\n         9\n         1         8\n",
            r"line 29: \*SET_PART 9 of \*ELEMENT_MASS_PART_SET lists undefined part 8",
        ),
        ("*ELEMENT_MASS\n" + _mass_line(1, 99, 0.001), r"deck.k line 29: \*ELEMENT_MASS 1 refers to undefined node 99"),
        ("*ELEMENT_MASS\n" + _mass_line(1, 3, -0.001), r"line 29: \*ELEMENT_MASS expects a mass >= 0 in columns 17-32"),
        (
            "*ELEMENT_MASS_NODE_SET\n" + _mass_line(4, 8, 0.001),
            r"line 29: \*ELEMENT_MASS_NODE_SET 4 refers to undefined",
        ),
        ("*ELEMENT_MASS_PART\n" + _part_line(7, 0.0003), r"line 29: \*ELEMENT_MASS_PART refers to undefined part 7"),
        (
            "*ELEMENT_MASS_PART_SET\n" + _part_line(7, 0.0003),
            r"line 29: \*ELEMENT_MASS_PART_SET refers to undefined part",
        ),
        (
            "*ELEMENT_MASS_PART\n" + _part_line(1, -0.0003),
            r"line 29: \*ELEMENT_MASS_PART expects ADDMASS >= 0 in columns 9-24",
        ),
        ("*ELEMENT_MASS_PART\n" + _part_line(1, 0.0, 0.0001), r"line 29: .*FINMASS of 0.1 kg, below the 0.2355 kg"),
    ],
)
def test_bad_mass_cards_name_the_line(tmp_path, cards, message):
    with pytest.raises(DeckError, match=message):
        _read(_deck().format(inertia="") + cards, tmp_path)


def test_bad_part_inertia_names_the_line(tmp_path):
    text = _deck(part2="*PART_INERTIA", mat2=RIGID).replace(
        "{inertia}", INERTIA.format(vel="").replace("0.005", "0.0  ")
    )
    with pytest.raises(DeckError, match=r"line 8: \*PART_INERTIA expects a positive mass TM in columns 31-40"):
        _read(text, tmp_path)


def test_written_deck_reads_back_with_every_mass(tmp_path):
    cards = "*ELEMENT_MASS\n" + _mass_line(1, 3, 0.001) + "*ELEMENT_MASS_NODE_SET\n" + _mass_line(2, 5, 0.002)
    cards += "*SET_NODE_LIST\n         5\n         1         2\n*ELEMENT_MASS_PART\n" + _part_line(1, 0.0003)
    text = _deck("       2.0       2.0       2.0       2.0         0   2.0e-09", "*PART_INERTIA", RIGID)
    m = _read(text.replace("{inertia}", INERTIA.format(vel="")) + cards, tmp_path)
    for units in ("mm-t-s", "m-kg-s"):
        out = write_deck(m, tmp_path / f"out_{units}.k", units=units, subassembly_yaml=False)
        back = _read(out.read_text(), tmp_path, name=f"back_{units}.k")
        assert back.total_mass() == pytest.approx(m.total_mass(), rel=1e-9)
        assert back.part_masses() == pytest.approx(m.part_masses(), rel=1e-9)
        assert back.part_mass == pytest.approx(m.part_mass, rel=1e-9)
        np.testing.assert_allclose(back.point_mass, m.point_mass, rtol=1e-9)
        np.testing.assert_array_equal(back.node_ids[back.point_mass_nodes], m.node_ids[m.point_mass_nodes])
        for kind in ("shell", "solid", "beam"):
            np.testing.assert_allclose(back.element_masses()[kind], m.element_masses()[kind], rtol=1e-9)
            np.testing.assert_allclose(back.element_added_masses()[kind], m.element_added_masses()[kind], rtol=1e-9)


def _point_masses(m) -> dict[int, float]:
    """Node id -> point mass [kg], summed."""
    out: dict[int, float] = {}
    for nid, kg in zip(m.node_ids[m.point_mass_nodes].tolist(), m.point_mass.tolist(), strict=True):
        out[nid] = out.get(nid, 0.0) + kg
    return out


def _inertia_card(eid: int, nid: int, tonnes: float) -> str:
    """*ELEMENT_INERTIA: EID NID CSID (I8), then IXX IXY IXZ IYY IYZ IZZ MASS (10 columns each)."""
    return (
        f"{eid:8d}{nid:8d}{0:8d}\n"
        + f"{1.0:10.1f}{0.0:10.1f}{0.0:10.1f}{1.0:10.1f}{0.0:10.1f}{1.0:10.1f}{tonnes:10.4g}\n"
    )


def _body(pid: int, nsid: int, tonnes: float, vtx: float = 0.0, spc: bool = False, title: str = "") -> str:
    """One *CONSTRAINED_NODAL_RIGID_BODY_INERTIA body: PID CID NSID ..., [CMO CON1 CON2], XC YC ZC TM IRCS NODEID,
    IXX .. IZZ, VTX .. VRZ (10 columns each)."""
    text = f"{title}\n" if title else ""
    text += f"{pid:10d}{0:10d}{nsid:10d}\n" + (f"{1.0:10.1f}{7:10d}{7:10d}\n" if spc else "")
    text += f"{150.0:10.1f}{50.0:10.1f}{0.0:10.1f}{tonnes:10.4g}\n"
    return text + f"{1.0:10.1f}{0.0:10.1f}{0.0:10.1f}{1.0:10.1f}{0.0:10.1f}{1.0:10.1f}\n" + f"{vtx:10.1f}\n"


def test_element_inertia_puts_its_mass_on_its_node(tmp_path):
    """The mass (card 2, columns 61-70) on the node; the inertia tensor and an _OFFSET card move no mass."""
    cards = "*ELEMENT_INERTIA\n" + _inertia_card(1, 3, 0.001) + _inertia_card(2, 7, 0.0025)
    cards += "*ELEMENT_INERTIA_OFFSET\n" + _inertia_card(3, 8, 0.0005) + f"{10.0:10.1f}{0.0:10.1f}{0.0:10.1f}\n"
    m = _read(_deck().format(inertia="") + cards, tmp_path)
    assert _point_masses(m) == pytest.approx({3: 1.0, 7: 2.5, 8: 0.5}, rel=1e-12)
    assert sorted(m.point_mass_ids.tolist()) == [1, 2, 3]
    assert m.total_mass() == pytest.approx(M1 + M2 + M3 + 4.0, rel=1e-12)
    assert "ELEMENT_INERTIA" not in m.skipped_cards and "ELEMENT_INERTIA_OFFSET" not in m.skipped_cards
    # the same numbers in long format (+: every field 20 columns)
    long = "*ELEMENT_INERTIA+\n" + f"{1:20d}{3:20d}{0:20d}\n" + f"{1.0:20.1f}" * 6 + f"{0.001:20.4g}\n"
    assert _point_masses(_read(_deck().format(inertia="") + long, tmp_path)) == pytest.approx({3: 1.0})
    with pytest.raises(DeckError, match=r"line 29: \*ELEMENT_INERTIA 4 refers to undefined node 99"):
        _read(_deck().format(inertia="") + "*ELEMENT_INERTIA\n" + _inertia_card(4, 99, 0.001), tmp_path)
    with pytest.raises(DeckError, match=r"line 30: \*ELEMENT_INERTIA expects a mass >= 0 in columns 61-70"):
        _read(_deck().format(inertia="") + "*ELEMENT_INERTIA\n" + _inertia_card(4, 3, -0.001), tmp_path)
    with pytest.raises(DeckError, match=r"expects 2 lines per element"):
        _read(_deck().format(inertia="") + "*ELEMENT_INERTIA\n" + _inertia_card(4, 3, 0.001)[:25], tmp_path)


def test_nodal_rigid_body_inertia_shares_its_mass_and_replaces_lumped_masses(tmp_path):
    """TM is the body's whole mass, shared by its node set; a lumped mass on one of its nodes is replaced by it."""
    base = _deck().format(inertia="") + "*SET_NODE_LIST\n         5\n         7         8\n"
    lumped = "*ELEMENT_MASS\n" + _mass_line(1, 7, 0.001) + _mass_line(2, 3, 0.002)
    m = _read(base + lumped + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n" + _body(9, 5, 0.004), tmp_path)
    assert _point_masses(m) == pytest.approx({7: 2.0, 8: 2.0, 3: 2.0}, rel=1e-12)  # node 7's 1 kg is replaced
    assert m.total_mass() == pytest.approx(M1 + M2 + M3 + 6.0, rel=1e-12)
    assert any("1 lumped mass(es) (1 kg; element(s) [1])" in w and "replaced by its TM" in w for w in m.warnings)
    # _SPC_INERTIA (an SPC card after the first) and _TITLE, two bodies in one block; NSID 0: the set numbered as
    # the body
    two = _body(5, 0, 0.004, spc=True, title="engine") + _body(6, 6, 0.001, spc=True, title="battery")
    sets = "*SET_NODE_LIST\n         6\n         1\n"
    m = _read(_deck().format(inertia="") + "*SET_NODE_LIST\n         5\n         7         8\n" + sets
              + "*CONSTRAINED_NODAL_RIGID_BODY_SPC_INERTIA_TITLE\n" + two, tmp_path)  # fmt: skip
    assert _point_masses(m) == pytest.approx({7: 2.0, 8: 2.0, 1: 1.0}, rel=1e-12)
    # no TM: nothing added, a note; without INERTIA: skipped like any card
    m = _read(base + lumped + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n" + _body(9, 5, 0.0), tmp_path)
    assert _point_masses(m) == pytest.approx({7: 1.0, 3: 2.0})
    assert any("gives no mass TM: its nodes keep their own" in w for w in m.warnings)
    m = _read(base + "*CONSTRAINED_NODAL_RIGID_BODY\n         9         0         5\n", tmp_path)
    assert m.point_mass.size == 0 and m.skipped_cards.get("CONSTRAINED_NODAL_RIGID_BODY") == 1
    with pytest.raises(DeckError, match=r"line 29: \*CONSTRAINED_NODAL_RIGID_BODY 9 refers to undefined node set 4"):
        _read(_deck().format(inertia="") + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n" + _body(9, 4, 0.004), tmp_path)
    with pytest.raises(DeckError, match=r"line 30: .*expects a mass TM >= 0 in columns 31-40, got '-0.004'"):
        _read(_deck().format(inertia="") + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n" + _body(9, 5, -0.004), tmp_path)
    with pytest.raises(DeckError, match=r"line 29: .*expects a card XC, YC, ZC, TM for body 9, got end of block"):
        _read(_deck().format(inertia="") + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n         9         0         5\n",
              tmp_path)  # fmt: skip


def test_nodal_rigid_body_velocity_sets_its_nodes_moving(tmp_path):
    """VTX of a nodal rigid body moves its node set: part 2, whose nodes only it moves, stays vehicle."""
    moving = "*INITIAL_VELOCITY_NODE\n" + "".join(f"{n:10d}{-15640.0:10.1f}\n" for n in (1, 4, 5, 6))
    base = _deck().format(inertia="") + moving + "*SET_NODE_LIST\n         5\n         2         7         8\n"
    for vtx, stays in ((-15640.0, True), (0.0, False)):
        m = _read(base + "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA\n" + _body(9, 5, 0.003, vtx=vtx), tmp_path)
        assert (2 in m.parts) == stays
        # at rest, the body's nodes 7 and 8 are used only by the left-out part 2: their masses leave with it
        assert _point_masses(m) == pytest.approx({2: 1.0, 7: 1.0, 8: 1.0} if stays else {2: 1.0})


def test_part_inertia_of_a_body_of_extra_nodes_sits_on_them(tmp_path):
    """A rigid part without elements whose *CONSTRAINED_EXTRA_NODES are its body: TM shared by those nodes."""
    third = "third, no elements\n         3         1         2\n" + INERTIA.format(vel="")
    text = _deck(part2="*PART_INERTIA", mat2=RIGID).replace("{inertia}", INERTIA.format(vel="") + third)
    extra = "*CONSTRAINED_EXTRA_NODES_SET\n         3         5\n*SET_NODE_LIST\n         5\n         7         8\n"
    extra += "*CONSTRAINED_EXTRA_NODES_NODE\n         3         1\n"
    m = _read(text + extra, tmp_path)
    assert _point_masses(m) == pytest.approx({1: 5 / 3, 7: 5 / 3, 8: 5 / 3}, rel=1e-12)
    assert m.point_mass_ids.tolist() == [3, 3, 3] and 3 not in m.part_mass
    assert m.total_mass() == pytest.approx(M1 + M2 + 5.0 + 5.0, rel=1e-12)
    with pytest.raises(DeckError, match=r"line 38: \*CONSTRAINED_EXTRA_NODES of part 3 refers to undefined node 99"):
        _read(text + "*CONSTRAINED_EXTRA_NODES_NODE\n         3        99\n", tmp_path)
    with pytest.raises(DeckError, match=r"line 38: \*CONSTRAINED_EXTRA_NODES_NODE expects a positive NID"):
        _read(text + "*CONSTRAINED_EXTRA_NODES_NODE\n         3\n", tmp_path)


@pytest.fixture(scope="module")
def car_cells():
    car = load_vehicle("b_segment")
    return car, discretize(car)


def test_point_and_added_masses_add_inertia_where_they_sit_and_no_strength(car_cells):
    car, base = car_cells
    front = int(np.argmin(car.coords[car.used_nodes(), 0]))
    front = int(car.used_nodes()[front])
    rear = int(car.used_nodes()[np.argmax(car.coords[car.used_nodes(), 0])])
    bumper = int(car.shell_part[np.argmin(car.coords[car.shell_nodes[:, 0], 0])])
    heavy = replace(
        car,
        point_mass_ids=np.array([1, 2]),
        point_mass_nodes=np.array([front, rear]),
        point_mass=np.array([3.0, 40.0]),
        part_added_mass={bumper: 2.5},
    )
    cells = discretize(heavy)
    comp = cells.n_cells - 1
    # the same cells, the same strength: added mass carries no material
    np.testing.assert_array_equal(cells.params, base.params)
    np.testing.assert_array_equal(cells.material, base.material)
    assert cells.total_mass == pytest.approx(base.total_mass + 45.5, rel=1e-12)
    dm = cells.mass - base.mass
    # the front node's 3 kg in the cell of its voxel; the rear one's 40 kg with the compartment
    vox, inside = _locate(cells, car.coords[front])
    assert inside and dm[cells.grid_labels.ravel()[vox]] >= 3.0 - 1e-9
    assert dm[comp] == pytest.approx(40.0, abs=1e-9)
    # the bumper's 2.5 kg over the bumper's cells (all in the ROI), nothing anywhere else
    assert dm[:comp].sum() == pytest.approx(3.0 + 2.5, rel=1e-9)
    gained = {cells.subassembly_names[i] for i in np.unique(cells.subassembly[:comp][dm[:comp] > 1e-12])}
    front_sub = cells.subassembly_names[cells.subassembly[cells.grid_labels.ravel()[vox]]]
    assert car.subassembly_of_part()[bumper] in gained and gained <= {car.subassembly_of_part()[bumper], front_sub}


def test_a_point_mass_on_a_node_of_the_front_structure_stays_with_the_front(car_cells):
    """A node of a discretized element can lie in a voxel no cell of structure owns (null space beside a wall whose
    samples sit in the next voxel, a compartment voxel, behind roi_depth at the rear of an element straddling it):
    its lumped mass went to the rigid compartment, 1.71 kg of 0.01 kg on each of the default car's 27689 front
    nodes. It now goes to the cell of the nearest material sample."""
    car, base = car_cells
    comp = list(car.subassemblies["compartment"])
    shells, solids = car.shell_nodes[~np.isin(car.shell_part, comp)], car.solid_nodes[~np.isin(car.solid_part, comp)]
    nodes = np.unique(np.concatenate([shells.ravel(), solids.ravel()]))
    nodes = nodes[car.coords[nodes, 0] < 1.0]
    heavy = replace(
        car, point_mass_ids=np.arange(1, nodes.size + 1), point_mass_nodes=nodes, point_mass=np.full(nodes.size, 0.01)
    )
    cells = discretize(heavy)
    dm = cells.mass - base.mass
    assert dm[cells.compartment] == pytest.approx(0.0, abs=1e-9)
    assert dm.sum() == pytest.approx(0.01 * nodes.size, rel=1e-12)
    assert (dm[cells.is_null] == 0).all()


def _locate(cells, point):
    edges = cells.grid_edges
    idx = [int(np.clip(np.searchsorted(edges[a], point[a], side="right") - 1, 0, len(edges[a]) - 2)) for a in range(3)]
    inside = all(edges[a][0] <= point[a] <= edges[a][-1] for a in range(3))
    return np.ravel_multi_index(tuple(idx), cells.grid_labels.shape), inside


def _beam_deck(elform: int, nsm: str) -> str:
    """Part 1: shells as in :func:`_deck`; part 3: two truss beams (section 3, 50 mm^2) of 100 mm each."""
    card2 = "      50.0" if elform != 6 else "       1.0       0.0         0       1.0"
    return _deck().format(inertia="") + (
        "*PART\nbar\n         3         3         1\n"
        f"*SECTION_BEAM\n         3{elform:10d}       1.0         0       0.0       0.0{nsm}\n{card2}\n"
        "*ELEMENT_BEAM\n       9       3       1       2       4\n      10       3       2       7       3\n"
    )


def test_section_beam_nsm_adds_mass_per_length(tmp_path):
    # NSM 1e-6 t/mm = 1 kg/m on the truss beams of 100 mm (nodes 1-2) and 100 mm (2-7): 0.2 kg
    m = _read(_beam_deck(3, "   1.0e-06"), tmp_path)
    assert m.part_added_mass == pytest.approx({3: 0.2}, rel=1e-9)
    np.testing.assert_allclose(m.element_added_masses()["beam"], [0.1, 0.1], rtol=1e-9)
    no_nsm = _read(_beam_deck(3, ""), tmp_path)
    assert no_nsm.part_added_mass == {} and m.total_mass() == pytest.approx(no_nsm.total_mass() + 0.2, rel=1e-12)
    # discrete beams take no NSM in LS-DYNA: a note, no mass
    m = _read(_beam_deck(6, "   1.0e-06"), tmp_path)
    assert m.part_added_mass == {} and any("NSM of section 3 not added" in w for w in m.warnings)
    with pytest.raises(
        DeckError, match=r"line 32: \*SECTION_BEAM expects a mass per length NSM >= 0 in columns 61-70, got '-1.0e-06'"
    ):
        _read(_beam_deck(3, "  -1.0e-06"), tmp_path)
