"""Vehicle registry: every config in configs/vehicle/ is registered and builds; names, paths and errors."""

from __future__ import annotations

import numpy as np
import pytest

from marlcrash import cli
from marlcrash.errors import ConfigError
from marlcrash.vehicle.keyword import read_deck
from marlcrash.vehicle.model import COMPARTMENT, AxisMap, VehicleModel
from marlcrash.vehicle.registry import (
    DECK_SUFFIXES,
    DEFAULT_VEHICLE,
    VEHICLES,
    VehicleOptions,
    list_vehicles,
    load_configured_vehicle,
    load_vehicle,
    vehicle_config_path,
    vehicle_dir,
)
from marlcrash.vehicle.synthetic import build_vehicle, load_synthetic_config


def test_every_vehicle_file_is_registered():
    files = {p.name for p in vehicle_dir().glob("*.y*ml")}
    assert files, f"no vehicle configs in {vehicle_dir()}"
    assert files == set(VEHICLES.values())
    assert DEFAULT_VEHICLE in list_vehicles()
    assert list_vehicles() == sorted(list_vehicles())


@pytest.mark.parametrize("name", list_vehicles())
def test_registered_vehicle_builds(name):
    model = load_vehicle(name)
    assert isinstance(model, VehicleModel)
    model.validate()
    cfg = load_synthetic_config(vehicle_config_path(name))
    assert model.total_mass() == pytest.approx(cfg.total_mass, rel=1e-9)
    assert COMPARTMENT in model.subassemblies
    assert model.bounds()[0, 0] == 0.0


def test_unknown_name_lists_known_vehicles():
    with pytest.raises(ConfigError) as err:
        load_vehicle("zz_not_a_car")
    msg = str(err.value)
    assert "zz_not_a_car" in msg
    for name in list_vehicles():
        assert name in msg


def test_yaml_path_and_seed_pass_through():
    path = vehicle_config_path(DEFAULT_VEHICLE)
    by_path = load_vehicle(str(path), seed=5)
    by_name = load_vehicle(DEFAULT_VEHICLE, seed=5)
    direct = build_vehicle(load_synthetic_config(path), seed=5)
    np.testing.assert_array_equal(by_path.coords, direct.coords)
    np.testing.assert_array_equal(by_name.shell_thickness, direct.shell_thickness)


def test_missing_files_and_deck_seed_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_vehicle(str(tmp_path / "nope.yaml"))
    with pytest.raises(ConfigError, match="not found"):
        load_vehicle(str(tmp_path / "nope.k"))
    deck = tmp_path / "car.key"
    deck.write_text("*KEYWORD\n*END\n")
    with pytest.raises(ConfigError) as err:
        load_vehicle(str(deck), seed=3)
    assert err.value.key == "seed"


def test_a_vehicle_file_missing_a_key_names_the_key(tmp_path):
    """A key left out of a vehicle YAML (or of a section) is named as the user writes it, not as a Python TypeError."""
    text = (
        vehicle_config_path(DEFAULT_VEHICLE)
        .read_text()
        .replace("materials: materials.yaml", f"materials: {vehicle_dir().parent / 'materials.yaml'}")
    )
    lines = text.splitlines(keepends=True)
    beam = lines.index(next(line for line in lines if line.startswith("bumper_beam:")))
    thickness = next(i for i in range(beam, len(lines)) if lines[i].startswith("  thickness:"))
    top = next(i for i, line in enumerate(lines) if line.startswith("total_mass:"))
    for drop, key in ((top, "total_mass"), (thickness, "bumper_beam.thickness")):
        path = tmp_path / f"{key}.yaml"
        path.write_text("".join(lines[:drop] + lines[drop + 1 :]))
        with pytest.raises(ConfigError) as err:
            load_vehicle(str(path))
        assert err.value.key == key and err.value.path == str(path), str(err.value)
        assert "missing" in str(err.value) and "__init__" not in str(err.value)


def test_deck_options_for_a_synthetic_car_are_a_config_error():
    with pytest.raises(ConfigError, match="units"):
        load_vehicle(DEFAULT_VEHICLE, units="mm-t-s")


# the writer warns that e.g. *MAT_RIGID has no strength fields; that is its documented limit
@pytest.mark.filterwarnings("ignore:.*keyword cards cannot carry:UserWarning")
def test_deck_path_is_read_with_the_keyword_reader(tmp_path):
    import marlcrash.vehicle.keyword_writer as writer

    car = load_vehicle(DEFAULT_VEHICLE)
    path = tmp_path / "car.k"
    writer.write_deck(car, path, units="mm-t-s", subassembly_yaml=False)
    model = load_vehicle(str(path), units="mm-t-s")
    assert isinstance(model, VehicleModel)
    assert model.n_nodes == car.n_nodes and model.n_shells == car.n_shells and model.n_solids == car.n_solids
    assert model.total_mass() == pytest.approx(car.total_mass(), rel=1e-6)
    # every suffix `marlcrash simulate DECK` reads as a deck is one in an env config's vehicle too
    assert set(cli.DECK_SUFFIXES) == set(DECK_SUFFIXES)
    from marlcrash.pulse.io import ACC_UNIT_NAMES  # `pulse --unit`'s choices, written out there for startup time

    assert list(cli.ACC_UNIT_CHOICES) == ACC_UNIT_NAMES
    kw = path.rename(tmp_path / "car.kw")
    assert load_vehicle(str(kw), units="mm-t-s").n_shells == car.n_shells


def test_vehicle_options_read_a_deck_as_read_deck_does(lsopt_deck, tmp_path):
    """Every option reaches the reader: parameters the deck needs, units, axes, a sub-assembly map."""
    amap = tmp_path / "map.yaml"
    amap.write_text("subassemblies:\n  front: [1, 2]\n")
    params = {"tbumper": 3.0, "thood": 1.0}
    opts = VehicleOptions(params=params, units="mm-t-s", axis_map="x=-x,y=-y,z=+z", subassemblies=str(amap))
    opts.validate()
    with pytest.warns(UserWarning):
        got = load_configured_vehicle(lsopt_deck, None, opts)
        want = read_deck(lsopt_deck, params=params, units="mm-t-s", subassemblies=amap,
                         axis_map=AxisMap.parse("x=-x,y=-y,z=+z"))  # fmt: skip
        plain = read_deck(lsopt_deck, params=params)
    np.testing.assert_array_equal(got.coords, want.coords)
    assert not np.allclose(got.coords, plain.coords)  # the axis map was applied
    assert list(got.subassemblies) == list(want.subassemblies) and "front" in got.subassemblies
    assert got.total_mass() == want.total_mass()


def test_vehicle_options_of_a_synthetic_car(tmp_path):
    """Deck-only options are refused naming the option; a sub-assembly map regroups the synthetic car's parts."""
    for key, value in (("params", {"t": 1.0}), ("units", "mm-t-s"), ("axis_map", "x=+x")):
        with pytest.raises(ConfigError, match="keyword decks only") as e:
            load_configured_vehicle(DEFAULT_VEHICLE, None, VehicleOptions(**{key: value}))
        assert e.value.key == key
    amap = tmp_path / "map.yaml"
    amap.write_text("subassemblies:\n  crash_boxes: ['crash_box_*']\n")
    model = load_configured_vehicle(DEFAULT_VEHICLE, 2, VehicleOptions(subassemblies=str(amap)))
    nominal = load_vehicle(DEFAULT_VEHICLE, seed=2)
    assert "crash_boxes" in model.subassemblies and "crash_box_left" not in model.subassemblies
    assert model.total_mass() == nominal.total_mass()
    np.testing.assert_array_equal(model.coords, nominal.coords)


@pytest.mark.parametrize(
    "options,key,match",
    [
        ({"units": "mm-s"}, "units", "unknown unit system"),
        ({"axis_map": "x=+q"}, "axis_map.x", "deck axis"),
        ({"subassemblies": "no/such/map.yaml"}, "subassemblies", "no sub-assembly map file"),
        ({"params": {"t": float("nan")}}, "params.t", "finite"),
    ],
)
def test_bad_vehicle_options_name_the_key(options, key, match):
    with pytest.raises(ConfigError, match=match) as e:
        VehicleOptions(**options).validate()
    assert e.value.key == key


@pytest.mark.parametrize(
    "options,key",
    [
        ({"params": {"tbumper": float("nan"), "thood": 1.0}}, "params.tbumper"),  # was "*SECTION_SHELL ... nan"
        ({"params": {"tbumper": 3.0, "thood": 1.0}, "units": "mm"}, "units"),
        ({"axis_map": 5}, "axis_map"),  # was "'int' object has no attribute 'split'"
    ],
)
def test_load_configured_vehicle_checks_options_made_in_python(lsopt_deck, options, key):
    """``load_configured_vehicle`` used the options as given: one made in Python skipped the checks a config file's
    ``vehicle_options`` get, and failed inside the reader, on whatever card came first."""
    with pytest.raises(ConfigError) as e:
        load_configured_vehicle(lsopt_deck, None, VehicleOptions(**options))
    assert e.value.key == key


@pytest.mark.parametrize("bad", ["units=mm", {"units": "mm"}])
def test_load_configured_vehicle_refuses_options_of_the_wrong_kind_in_words(bad):
    with pytest.raises(ConfigError, match="options must be a VehicleOptions"):
        load_configured_vehicle(DEFAULT_VEHICLE, None, bad)
