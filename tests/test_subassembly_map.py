"""Sub-assembly maps: every part the map names ends up in exactly the group the map puts it in."""

from __future__ import annotations

import pytest

from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.subassembly_map import load_subassembly_map, resolve_subassemblies
from marlcrash.vehicle.synthetic import default_vehicle


@pytest.fixture(scope="module")
def car():
    return default_vehicle()


def test_an_empty_part_set_is_an_error_not_an_empty_group(car):
    """An entry must name at least one part: an empty ``*SET_PART`` made a sub-assembly (an agent) of nothing."""
    with pytest.raises(ConfigError, match=r"\*SET_PART 10 holds no part") as err:
        resolve_subassemblies({"front": ["set:10"]}, car, part_sets={10: ("front", [])})
    assert err.value.key == "subassemblies.front[0]"
    with pytest.raises(ModelError, match="sub-assembly 'front' lists no part"):
        car.with_subassemblies({"front": []})


def test_a_group_named_like_another_parts_default_group_is_refused(car, tmp_path):
    """``part_<id>`` is the name a part left out of the map gets: a group of that name holding other parts had its
    parts silently replaced by part <id> when the map was completed, and part <id> looked up into the group."""
    y = tmp_path / "map.yaml"
    y.write_text("subassemblies:\n  part_2: [1]\n")
    with pytest.raises(ConfigError, match=r"'part_2' is the name of part 2's own sub-assembly") as err:
        load_subassembly_map(y, car)
    assert err.value.key == "subassemblies.part_2" and "map.yaml" in str(err.value)
    with pytest.raises(ModelError, match=r"'part_2' is the name of part 2's own sub-assembly"):
        car.with_subassemblies({"part_2": [1]})
    # the name is fine for a group that holds part 2 (a dumped map, edited), or where no part 99 exists
    ok = car.with_subassemblies({"part_2": [2, 1], "part_99": [3]}).with_default_subassemblies()
    assert ok.subassemblies["part_2"] == [2, 1] and ok.subassemblies["part_99"] == [3]
    assert ok.subassembly_of_part()[1] == "part_2" and ok.subassembly_of_part()[4] == "part_4"


def test_a_dumped_map_reads_back_whatever_the_group_names(car, tmp_path):
    """A long group name with spaces was folded over two lines by the YAML emitter (its 80-column default), so the
    map written beside a deck (write_deck) could not be read back: 'mapping values are not allowed here'."""
    from marlcrash.vehicle.subassembly_map import dump_subassembly_map

    pids = sorted(car.parts)
    names = ["front " * 16 + "rail", "a: b", "#x", "null", "- x", "é", "x" * 200]
    mapping = {n: [p] for n, p in zip(names, pids, strict=False)}
    path = dump_subassembly_map(mapping, tmp_path / "map.yaml")
    assert load_subassembly_map(path, car) == mapping


def test_a_dumped_map_reads_back_group_names_holding_line_breaks(car, tmp_path):
    """A group name holding a line break (a key quoted in the user's map, or a name given in Python) was dumped as a
    single-quoted scalar over several lines, so the map (the one written beside a deck too) could not be read back:
    'mapping values are not allowed here'. Such a name is written on one line, double-quoted with its escapes."""
    from marlcrash.vehicle.subassembly_map import dump_subassembly_map

    pids = sorted(car.parts)
    names = ["front\nrail", "a " * 60 + "\nb", "rear\r\nrail", "hood"]
    mapping = {n: [p] for n, p in zip(names, pids, strict=False)}
    path = dump_subassembly_map(mapping, tmp_path / "map.yaml")
    assert len(path.read_text().splitlines()) == 2 + len(names)  # two header lines, then a line per group
    assert load_subassembly_map(path, car) == mapping


def test_unknown_top_level_keys_of_mixed_types_are_named(car, tmp_path):
    """Two unknown top-level keys, one a number (``1:`` and ``groups:``), raised TypeError from sorting them."""
    y = tmp_path / "map.yaml"
    y.write_text("subassemblies:\n  front: [1]\n1: x\ngroups: y\n")
    with pytest.raises(ConfigError, match=r"map\.yaml key '1': unknown key; expected only 'subassemblies'") as err:
        load_subassembly_map(y, car)
    assert err.value.key == "1"
