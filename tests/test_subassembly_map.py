"""Sub-assembly maps: every part the map names ends up in exactly the group the map puts it in."""

from __future__ import annotations

import pytest

from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.subassembly_map import resolve_subassemblies
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
