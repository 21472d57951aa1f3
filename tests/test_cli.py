"""The console script, run as a user would: a subprocess, JSON parsed back."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from marlcrash.errors import ConfigError


def run_cli(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "marlcrash.cli", *args], capture_output=True, text=True, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"marlcrash {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr}")
    return proc


def test_inspect_lsopt_json(lsopt_deck):
    out = json.loads(run_cli("inspect", str(lsopt_deck), "--param", "tbumper=3", "--param", "thood=1", "--json").stdout)
    assert (out["n_nodes"], out["n_shells"], out["n_solids"], out["n_beams"], out["n_parts"]) == (1236, 584, 0, 0, 5)
    assert set(out["parts"]) == {"1", "2", "3", "4", "5"} and set(out["left_out"]) == {"6"}  # 6: the fixed block
    assert out["total_mass_kg"] == pytest.approx(sum(out["parts"].values()))
    assert out["skipped_cards"]  # the deck has contacts, rigid walls, database cards


def test_inspect_undefined_parameter_is_a_clear_error(lsopt_deck):
    proc = run_cli("inspect", str(lsopt_deck), check=False)
    assert proc.returncode == 2
    assert "tbumper" in proc.stderr and "line" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_inspect_table_and_bad_param(lsopt_deck):
    proc = run_cli("inspect", str(lsopt_deck), "--param", "tbumper=3", "--param", "thood=1")
    assert "584 shells" in proc.stdout and "skipped cards" in proc.stdout
    assert "left out of the vehicle (1 part(s)):\n  part 6 " in proc.stdout
    proc = run_cli("inspect", str(lsopt_deck), "--param", "tbumper", check=False)
    assert proc.returncode == 2 and "--param" in proc.stderr


def test_a_malformed_axis_map_is_said_as_the_option_typed(tmp_path):
    """``--axis-map x=+x,y=+z`` (z left out) said ``key 'axis_map.z': deck axis 'z' is used twice in AxisMap(x='+x',
    y='+z', z='+z', ...)``: a key the user never typed, and a z=+z nobody wrote (an axis left out keeps the identity).
    The message now names ``--axis-map`` and says that z was not given and kept as +z."""
    deck = tmp_path / "car.k"  # the map is read before the deck
    proc = run_cli("inspect", str(deck), "--axis-map", "x=+x,y=+z", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: key '--axis-map")
    assert "z not given" in proc.stderr and "+z" in proc.stderr
    proc = run_cli("inspect", str(deck), "--axis-map", "x=+q,y=+z,z=+y", check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: key '--axis-map") and "'+q'" in proc.stderr


def test_an_empty_axis_map_is_refused_not_read_as_none(tmp_path):
    """``--axis-map ""`` (a shell variable left unset, a quoting slip) was read as no map at all, without a word: the
    deck was read with its own axes. Now an error names ``--axis-map`` and the form expected, for a deck and for a
    synthetic car (where it does not apply)."""
    deck = tmp_path / "car.k"  # the map is read before the deck
    for text in ("", " ", ","):
        for target in ((str(deck),), ()):
            proc = run_cli("discretize", *target, "--axis-map", text, check=False)
            assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
            if target:
                assert proc.stderr.startswith("error: key '--axis-map': no axis given"), proc.stderr
                assert "expected items like 'x=+x,y=+z,z=+y'" in proc.stderr
            else:
                assert proc.stderr.startswith("error: --axis-map only applies to keyword decks"), proc.stderr


def test_a_param_value_that_is_not_finite_is_said_as_the_option_typed(tmp_path):
    """``--param tbumper=nan`` (or inf, or 1e400) was taken: the deck then failed at whatever card used the value
    ('*SECTION_SHELL expects thicknesses T1..T4 >= 0, got [nan, nan, nan, nan]'), naming a deck line the user did not
    write and not the option. It is refused as the option typed, before the deck is read, as vehicle_options.params
    of a config is."""
    for value in ("nan", "inf", "-inf", "1e400"):
        proc = run_cli("inspect", str(tmp_path / "car.k"), "--param", f"tbumper={value}", check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.startswith(f"error: key '--param': value of 'tbumper' must be a finite number, got "
                                      f"'{value}'"), proc.stderr  # fmt: skip


def test_a_param_given_twice_is_refused_not_the_last_one_taken(tmp_path):
    """``--param tbumper=3 --param tbumper=5`` read the deck with 5 and said nothing of the 3; nor of ``TBUMPER=3``,
    the same parameter as the deck reads names (LS-DYNA's are case-insensitive). Which one was meant is the user's
    to say: refused as the option typed, naming both values, before the deck is read."""
    for first, second in (("tbumper=3", "tbumper=5"), ("tbumper=3", " TBUMPER =5")):
        proc = run_cli("inspect", str(tmp_path / "car.k"), "--param", first, "--param", second, check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.startswith("error: key '--param': parameter 'tbumper' given twice"), proc.stderr
        assert f"{first!r} and {second!r}" in proc.stderr, proc.stderr
    proc = run_cli("inspect", str(tmp_path / "car.k"), "--param", "tbumper=3", "--param", "TBUMPER=3.0", check=False)
    assert proc.stderr.startswith("error: car.k: cannot read the deck"), proc.stderr  # one value, said twice: taken


def test_an_unknown_unit_system_is_said_as_the_option_typed(tmp_path):
    """``--units furlong`` said ``key 'units'``, the library's argument, not the option typed (and only once the deck
    had been read): now ``key '--units'``, before the deck is read."""
    proc = run_cli("inspect", str(tmp_path / "car.k"), "--units", "furlong", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: key '--units': unknown unit system 'furlong'; expected one of"), proc.stderr


def test_discretize_default_car_json(tmp_path):
    plot, save = tmp_path / "cells.png", tmp_path / "cells.npz"
    out = json.loads(run_cli("discretize", "--json", "--plot", str(plot), "--save", str(save)).stdout)
    # the files written, as simulate's JSON gives its csv and plot (the table says them; the JSON did not)
    assert (out["plot"], out["save"]) == (str(plot), str(save)) and save.stat().st_size > 10_000
    for key in (
        "roi_volume_mm3",
        "target_cell_volume_mm3",
        "n_cells_uniform",
        "n_cells_optimized",
        "n_null_cells",
        "roi_mass_kg",
        "cell_mass_kg",
        "n_subassemblies",
    ):
        assert key in out, key
    assert out["n_cells_optimized"] * 8 <= out["n_cells_uniform"]
    assert out["cell_mass_kg"] == pytest.approx(out["roi_mass_kg"], rel=5e-3)
    assert plot.stat().st_size > 10_000
    # the saved model says what made it (it said nothing: a cell model kept for later could not be traced)
    from marlcrash.cells import CellModel

    origin = out["provenance"]
    assert CellModel.load(save).meta["provenance"] == origin
    assert origin["command"] == f"marlcrash discretize --json --plot {plot} --save {save}"
    cells_yaml = Path(origin["configs_folder"]) / "cells.yaml"
    assert origin["configs"]["configs/cells.yaml"] == hashlib.sha256(cells_yaml.read_bytes()).hexdigest()


def test_discretize_says_which_cells_config_key_does_not_fit_the_vehicle(tmp_path):
    """A roi_depth longer than the car (12 for 1.2) warns naming the key, its value and the car's length; a target
    cell volume for the compartment, which is rigid and not discretized, is refused naming the key (both were taken
    without a word)."""
    text = (Path(__file__).parents[1] / "configs" / "cells.yaml").read_text()
    deep, comp = tmp_path / "deep.yaml", tmp_path / "comp.yaml"
    deep.write_text(re.sub(r"^roi_depth: 1\.2 ", "roi_depth: 12 ", text, count=1, flags=re.M))
    comp.write_text(text.replace("  wheel_right: 0.01", "  wheel_right: 0.01\n  compartment: 0.05", 1))
    proc = run_cli("discretize", "--config", str(deep), "--json")
    assert "warning: b_segment: roi_depth = 12 m is longer than the vehicle (4.000 m" in proc.stderr, proc.stderr
    assert json.loads(proc.stdout)["n_cells_optimized"] > 0
    proc = run_cli("discretize", "--config", str(comp), "--json", check=False)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr and not proc.stdout
    assert proc.stderr.startswith("error: comp.yaml key 'subassembly_target_cell_volume.compartment': the compartment "
                                  "is one rigid cell and is not discretized"), proc.stderr  # fmt: skip


def _refused_by_the_parser(capsys, args: tuple[str, ...], message: str) -> None:
    """``marlcrash args`` ends with argparse's exit status 2 and ``message`` on standard error."""
    from marlcrash.cli import main

    with pytest.raises(SystemExit) as e:
        main(list(args))
    err = capsys.readouterr().err
    assert e.value.code == 2, (args, err)
    assert message in err, (args, err)


def _without_upfront_left(tmp_path: Path) -> Path:
    """A copy of configs/cells.yaml without the up-front left sensor: the LS-OPT car read with x=+x,y=+z,z=+y has no
    material within 0.75 m of its default position on its side of the centre line."""
    import yaml

    data = yaml.safe_load((Path(__file__).parents[1] / "configs" / "cells.yaml").read_text())
    data["sensors"] = [s for s in data["sensors"] if s["name"] != "upfront_left"]
    path = tmp_path / "cells_no_upfront_left.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_discretize_lsopt_with_axis_map(lsopt_deck, tmp_path):
    args = ("discretize", str(lsopt_deck), "--param", "tbumper=3", "--param", "thood=1", "--axis-map", "x=+x,y=+z,z=+y")
    proc = run_cli(*args, "--json", check=False)
    assert (
        proc.returncode == 2 and "error: sensor 'upfront_left': no material within sensor_snap_distance" in proc.stderr
    )
    assert "Traceback" not in proc.stderr
    out = json.loads(run_cli(*args, "--config", str(_without_upfront_left(tmp_path)), "--json").stdout)
    assert out["n_cells_optimized"] > 0 and out["n_subassemblies"] >= 5
    assert out["cell_mass_kg"] == pytest.approx(out["roi_mass_kg"], rel=5e-3)


DATA = Path(__file__).parent / "data"


def test_pulse_json_and_plot(tmp_path):
    plot = tmp_path / "pulse.png"
    out = json.loads(run_cli("pulse", str(DATA / "halfsine_40kmh.csv"), "--json", "--plot", str(plot)).stdout)
    for key in ("n_samples", "sample_rate_hz", "peak_g", "t_peak_ms", "delta_v_ms", "delta_v_150ms_ms"):
        assert key in out, key
    # the file is a 40 km/h half-sine (tests/data/README.md): delta-v 11.11 m/s
    assert out["delta_v_ms"] == pytest.approx(40 / 3.6, rel=0.01)
    assert out["sample_rate_hz"] == pytest.approx(5000.0)
    assert plot.stat().st_size > 10_000
    mme = json.loads(run_cli("pulse", str(DATA / "HS40"), "--json").stdout)
    assert mme["delta_v_ms"] == pytest.approx(40 / 3.6, rel=0.01)
    # CSV options on an ISO-MME test are named as typed, those given alone (it said 'time_col/unit/time_unit')
    proc = run_cli("pulse", str(DATA / "HS40"), "--unit", "m/s2", "--json")
    assert json.loads(proc.stdout) == mme
    assert ("warning: HS40: ISO-MME channels carry their own time base and unit; --unit m/s2 (unit='m/s2') applies "
            "to CSV files only and is ignored") in proc.stderr, proc.stderr  # fmt: skip
    # the plot never replaces the record it reads, and is a PNG by name
    record = tmp_path / "record.csv"
    record.write_bytes((DATA / "halfsine_40kmh.csv").read_bytes())
    for target, why in ((record, "is also"), (tmp_path / "pulse.pdf", "expected a .png")):
        proc = run_cli("pulse", str(record), "--plot", str(target), check=False)
        assert proc.returncode == 2 and "'--plot'" in proc.stderr and why in proc.stderr, proc.stderr
    assert record.read_bytes() == (DATA / "halfsine_40kmh.csv").read_bytes()


def test_pulse_plot_of_a_non_uniform_record_and_a_short_record_note(tmp_path):
    """--plot draws the pulse the summary describes (resampled, filtered, aligned), also for jittered time stamps;
    a record that ends before 150 ms after time zero gets a null delta_v_150ms_ms and a note saying why."""
    import numpy as np

    rng = np.random.default_rng(0)
    t = np.sort(np.concatenate([[0.0, 0.2], rng.uniform(0.0, 0.2, 998)]))
    acc_g = np.where((t > 0.01) & (t < 0.09), -20.0 * np.sin(np.pi * (t - 0.01) / 0.08), 0.0)
    nu = tmp_path / "nu.csv"
    nu.write_text("time,acc\n" + "".join(f"{a:.9g},{b:.9g}\n" for a, b in zip(t, acc_g, strict=True)))
    plot = tmp_path / "nu.png"
    proc = run_cli("pulse", str(nu), "--json", "--plot", str(plot))
    out = json.loads(proc.stdout)
    assert plot.stat().st_size > 10_000 and out["plot"] == str(plot)
    assert out["delta_v_150ms_ms"] is not None and "note" not in proc.stderr
    # 20 g half-sine of 80 ms: delta-v 2 A tau / pi
    assert out["delta_v_ms"] == pytest.approx(2 * 20 * 9.80665 * 0.08 / np.pi, rel=0.02)
    short = tmp_path / "short.csv"
    ts = np.append(t[t < 0.15], 0.15)  # 150 ms from the file's t = 0, like a simulated record
    acc_s = np.append(acc_g[t < 0.15], 0.0)
    short.write_text("time,acc\n" + "".join(f"{a:.9g},{b:.9g}\n" for a, b in zip(ts, acc_s, strict=True)))
    proc = run_cli("pulse", str(short), "--json")
    assert json.loads(proc.stdout)["delta_v_150ms_ms"] is None and "--time-zero file" in proc.stderr
    proc = run_cli("pulse", str(short), "--json", "--time-zero", "file")
    assert json.loads(proc.stdout)["delta_v_150ms_ms"] is not None and "note" not in proc.stderr
    shorter = tmp_path / "shorter.csv"  # 100 ms from the file's t = 0: read with --time-zero file, which it named
    keep = ts <= 0.1
    shorter.write_text("time,acc\n" + "".join(f"{a:.9g},{b:.9g}\n" for a, b in zip(ts[keep], acc_s[keep], strict=True)))
    proc = run_cli("pulse", str(shorter), "--json", "--time-zero", "file")
    assert json.loads(proc.stdout)["delta_v_150ms_ms"] is None
    said = "note: delta_v_150ms_ms is null: the record ends less than 150 ms after time zero (the file's t = 0)"
    assert said in proc.stderr and "use --time-zero file" not in proc.stderr, proc.stderr


def test_pulse_column_unit_and_filter_options(tmp_path):
    """--time-col/--acc-col pick columns by name, --unit m/s2 converts, --cfc changes the filter class."""
    import numpy as np

    g0 = 9.80665
    rows = [line for line in (DATA / "halfsine_40kmh.csv").read_text().splitlines() if not line.startswith("#")]
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    other = tmp_path / "ms2.csv"
    cols = zip(data[:, 0], data[:, 2] * g0, data[:, 1] * g0, strict=True)
    body = "".join(f"{t:.6f},{a:.9g},{b:.9g}\n" for t, a, b in cols)
    other.write_text("zeit,radsup_ms2,tunnel_ms2\n" + body)  # tunnel last, in m/s2

    def summary(path, *opts):
        return json.loads(run_cli("pulse", str(path), "--json", *opts).stdout)

    opts = ("--time-col", "zeit", "--acc-col", "tunnel_ms2", "--unit", "m/s2")
    ref = summary(DATA / "halfsine_40kmh.csv", "--acc-col", "tunnel_acx", "--cfc", "180")
    got = summary(other, *opts, "--cfc", "180")
    for key in ("peak_g", "t_peak_ms", "delta_v_ms", "delta_v_150ms_ms"):
        assert got[key] == pytest.approx(ref[key], rel=1e-6, abs=1e-9), key
    # 0.2 g of white noise: the wider filter class passes more of it, so its peak is higher
    assert summary(other, *opts, "--cfc", "1000")["peak_g"] > got["peak_g"]
    proc = run_cli("pulse", str(other), "--time-col", "zeit", "--acc-col", "nope", check=False)
    assert proc.returncode == 2 and "nope" in proc.stderr and "tunnel_ms2" in proc.stderr
    in_ms = tmp_path / "ms.csv"  # the same record with its time in ms
    cols = zip(data[:, 0] * 1e3, data[:, 2] * g0, data[:, 1] * g0, strict=True)
    in_ms.write_text("zeit,radsup_ms2,tunnel_ms2\n" + "".join(f"{t:.3f},{a:.9g},{b:.9g}\n" for t, a, b in cols))
    got_ms = summary(in_ms, *opts, "--cfc", "180", "--time-unit", "ms")
    for key in ("peak_g", "t_peak_ms", "delta_v_ms", "delta_v_150ms_ms"):
        assert got_ms[key] == pytest.approx(ref[key], rel=1e-6, abs=1e-9), key
    for cfc in ("60", "0"):  # read as seconds: refused, filtered or not, with the option to use
        proc = run_cli("pulse", str(in_ms), *opts, "--cfc", cfc, check=False)
        assert proc.returncode == 2 and "is the time column in ms (--time-unit ms" in proc.stderr


def test_pulse_header_units_are_read_with_an_option_the_command_takes(tmp_path):
    """A column whose header gives its unit as m/s^2 or mm/s2 (both known to the reader) read in g was refused with
    the hint '--unit m/s^2' / '--unit mm/s2', which ``marlcrash pulse`` refused in turn (its --unit took g and m/s2
    only): a CSV of mm/s2 could not be read by the command at all. The hint now spells the unit as --unit takes it,
    and --unit takes mm/s2."""
    t = np.arange(0.0, 0.2, 1e-4)
    acc = np.where(t <= 0.08, -30 * 9.80665 * np.sin(np.pi * np.clip(t, 0, 0.08) / 0.08), 0.0)  # [m/s^2]
    files = {}
    for name, unit, scale in (("ms2", "m/s^2", 1.0), ("mm", "mm/s2", 1e3)):
        files[name] = tmp_path / f"{name}.csv"
        rows = "".join(f"{a:.5f},{b * scale:.6f}\n" for a, b in zip(t, acc, strict=True))
        files[name].write_text(f"time,acc [{unit}]\n" + rows)
    for name, said, typed in (("ms2", "m/s^2", "m/s2"), ("mm", "mm/s2", "mm/s2")):
        proc = run_cli("pulse", str(files[name]), check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        assert f"is in {said} by its header, but is read in g: give that unit (--unit {typed}; unit: {typed})" in (
            proc.stderr
        ), proc.stderr
        got = json.loads(run_cli("pulse", str(files[name]), "--unit", typed, "--time-zero", "file", "--json").stdout)
        assert got["delta_v_ms"] == pytest.approx(2 * 30 * 9.80665 * 0.08 / np.pi, rel=1e-3)  # half-sine: 2 A tau/pi


def test_pulse_reads_a_table_of_breakpoints(tmp_path):
    corners = tmp_path / "corners.csv"  # a 20 g trapezoid given by its corners, time in ms
    corners.write_text("time,acc\n0,0\n10,-20\n60,-20\n80,0\n200,0\n")
    got = json.loads(run_cli("pulse", str(corners), "--breakpoints", "--time-unit", "ms", "--json").stdout)
    assert got["sample_rate_hz"] == pytest.approx(1e4) and got["n_samples"] == 2001
    assert got["delta_v_ms"] == pytest.approx(20 * 9.80665 * 0.065, rel=2e-3)
    assert got["peak_g"] == pytest.approx(20.0, rel=0.02)
    proc = run_cli("pulse", str(corners), "--breakpoints", check=False)  # ms read as s: 200 s of 20 g
    assert proc.returncode == 2 and "the breakpoints span 200 s" in proc.stderr and "Traceback" not in proc.stderr
    proc = run_cli("pulse", str(DATA / "HS40"), "--breakpoints", check=False)  # named no option
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (
        "error: HS40: --breakpoints (breakpoints=True) applies to CSV files only: an ISO-MME channel is sampled, "
        "not a table of breakpoints"
    ) in proc.stderr


def test_pulse_notes_a_record_too_short_for_its_filter(tmp_path):
    import numpy as np

    t = np.arange(0.0, 3.05, 0.1) / 1e3  # the record ends with the 3 ms pulse
    acc = -20.0 * np.sin(np.pi * np.clip(t / 0.003, 0.0, 1.0))
    short = tmp_path / "s3.csv"
    short.write_text("time,acc\n" + "".join(f"{a:.6f},{b:.6f}\n" for a, b in zip(t, acc, strict=True)))
    assert "less than the 20 ms the CFC 60 filter spreads a pulse over" in run_cli("pulse", str(short)).stderr
    assert "note: the record ends" not in run_cli("pulse", str(short), "--cfc", "0").stderr
    assert "note: the record ends" not in run_cli("pulse", str(DATA / "halfsine_40kmh.csv")).stderr


def test_pulse_bad_file_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,a\n0,1\n0.001,abc\n")
    proc = run_cli("pulse", str(bad), check=False)
    assert proc.returncode == 2
    assert "bad.csv line 3" in proc.stderr and "Traceback" not in proc.stderr


def test_pulse_of_a_missing_test_folder_says_it_is_missing(tmp_path):
    """An ISO-MME test folder has no suffix, so a mistyped one (``marlcrash pulse tests/TEST01``) was told
    'expected a .csv/.txt file, a .mme file or an ISO-MME test folder', which is what the user meant to give. It now
    says there is no such file or folder, from the command and from read_pulse; an existing file of another kind is
    told the kinds expected, as before."""
    from marlcrash.errors import PulseError
    from marlcrash.pulse.io import read_pulse

    proc = run_cli("pulse", str(tmp_path / "TEST01"), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: TEST01: no such file or folder"), proc.stderr
    with pytest.raises(PulseError, match="TEST01: no such file or folder"):
        read_pulse(tmp_path / "TEST01")
    (tmp_path / "notes.dat").write_text("x")
    with pytest.raises(PulseError, match=r"notes.dat: expected a .csv/.txt file, a .mme file or an ISO-MME test"):
        read_pulse(tmp_path / "notes.dat")


def test_simulate_json_csv_plot(tmp_path):
    csv_path, plot = tmp_path / "sim.csv", tmp_path / "sim.png"
    out = json.loads(
        run_cli("simulate", "--scenario", "full_width_40", "--json", "--csv", str(csv_path), "--plot", str(plot)).stdout
    )
    for key in (
        "peak_decel_g",
        "time_to_zero_velocity_ms",
        "max_crush_m",
        "rebound_velocity_ms",
        "energy_balance_max_rel_error",
        "n_cells",
        "sensors",
    ):
        assert key in out, key
    assert out["energy_balance_max_rel_error"] < 5e-3
    assert set(out["sensors"]) == {"upfront_left", "upfront_right", "tunnel"}
    # the default car weighs 1600 kg (DESIGN 3); its front can take far more than 40 km/h brings
    assert out["impact_energy_kj"] == pytest.approx(0.5 * 1600 * (40 / 3.6) ** 2 / 1e3, rel=1e-9)
    assert out["crush_capacity_kj"] > out["impact_energy_kj"]
    lines = csv_path.read_text().splitlines()
    header = lines[0].split(",")
    assert header[0] == "time_s" and "tunnel_acc_g" in header and "crush_m" in header
    assert len(lines) == 1 + 301  # 150 ms at 2 kHz, t = 0 included
    # what made the record, beside it (the CSV stays plain data): the car and load case, the command, the code and
    # every config file with its SHA-256; a record kept for a test report could not be traced to its inputs
    record = json.loads((tmp_path / "sim.provenance.json").read_text())
    assert out["provenance_file"] == str(tmp_path / "sim.provenance.json") and record["csv"] == str(csv_path)
    assert (record["vehicle"], record["n_cells"], record["scenario"]["speed_kmh"]) == ("b_segment", out["n_cells"], 40)
    origin = record["provenance"]
    assert origin == out["provenance"]
    assert origin["command"] == f"marlcrash simulate --scenario full_width_40 --json --csv {csv_path} --plot {plot}"
    assert origin["code"]["marlcrash"] and len(origin["code"]["source_sha256"]) == 64 and origin["torch"]
    folder = Path(origin["configs_folder"])
    assert {"configs/sim.yaml", "configs/cells.yaml", "configs/scenarios/full_width_40.yaml"} <= set(origin["configs"])
    for name, digest in origin["configs"].items():
        assert hashlib.sha256((folder / name.removeprefix("configs/")).read_bytes()).hexdigest() == digest, name
    assert plot.stat().st_size > 10_000
    # Round trip: the written acceleration, read back and filtered, carries the simulated velocity change
    # (the up-front sensors stop within 1-2 ms; an aliased point acceleration gave 7.7 of their 12.0 m/s,
    # and counted from time zero the filter's spread before it was lost).
    for sensor in ("upfront_left", "tunnel"):
        back = json.loads(
            run_cli("pulse", str(csv_path), "--acc-col", f"{sensor}_acc_g", "--time-zero", "file", "--json").stdout
        )
        s = out["sensors"][sensor]
        assert back["delta_v_ms"] == pytest.approx(s["delta_v_ms"], rel=0.02), (sensor, back, s)
        assert back["peak_g"] == pytest.approx(s["peak_g"], rel=1e-3), (sensor, back, s)
    # its columns give their unit as a suffix (time_s, <sensor>_acc_g): a contradicting --unit read g as m/s^2
    proc = run_cli("pulse", str(csv_path), "--unit", "m/s2", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert re.search(r"column '\w+_acc_g' is in g by its header, but is read in m/s2: give that unit \(--unit g",
                     proc.stderr), proc.stderr  # fmt: skip


def test_simulate_a_keyword_deck(lsopt_deck, tmp_path):
    """The DECK argument: the public LS-OPT small car, its parts as the sub-assemblies of the energy split."""
    config = ("--config", str(_without_upfront_left(tmp_path)))
    args = ("--param", "tbumper=3", "--param", "thood=1", "--axis-map", "x=+x,y=+z,z=+y", "--json")
    out = json.loads(run_cli("simulate", str(lsopt_deck), *config, *args).stdout)
    assert out["n_cells"] > 100 and out["scenario"] == "full_width_40"
    # the deck and the cells config given by path are inputs of the record, with their SHA-256
    inputs = out["provenance"]["configs"]
    for path in (lsopt_deck, Path(config[1])):
        assert inputs[str(path.resolve())] == hashlib.sha256(path.read_bytes()).hexdigest(), path
    assert set(out["absorbed_energy_kj"]) == {"part_1", "part_2", "part_3", "part_4", "part_5", "compartment"}
    assert out["energy_balance_max_rel_error"] < 5e-3
    assert 0.0 < out["max_crush_m"] < 2.0 and out["peak_decel_g"] > 1.0
    mass = json.loads(run_cli("inspect", str(lsopt_deck), *args[:4], "--json").stdout)["total_mass_kg"]
    assert out["impact_energy_kj"] == pytest.approx(0.5 * mass * (40 / 3.6) ** 2 / 1e3, rel=1e-9)
    assert out["crush_capacity_kj"] > out["impact_energy_kj"]
    # at 56 km/h this heavy box (4.4 t) brings more than its first 1.2 m can take as plastic work: said, not hidden
    proc = run_cli("simulate", str(lsopt_deck), *config, *args[:-1], "--speed", "56")
    assert "note: the impact brings 537.6 kJ and the cells can take" in proc.stdout and "roi_depth" in proc.stdout


def test_output_paths_are_checked_before_the_work(tmp_path):
    """A folder given as --csv/--plot, or a missing folder, fails at once, naming the option; nothing is left."""
    (tmp_path / "adir").mkdir()
    proc = run_cli("simulate", "--csv", str(tmp_path / "adir"), check=False)
    assert proc.returncode == 2 and "'--csv'" in proc.stderr and "is a folder" in proc.stderr
    proc = run_cli("simulate", "--csv", str(tmp_path / "ok.csv"), "--plot", str(tmp_path / "no" / "a.png"), check=False)
    assert proc.returncode == 2 and "'--plot'" in proc.stderr and "does not exist" in proc.stderr
    assert not (tmp_path / "ok.csv").exists()  # the csv was not written before the plot path failed
    proc = run_cli("pulse", str(DATA / "halfsine_40kmh.csv"), "--plot", str(tmp_path / "adir"), check=False)
    assert proc.returncode == 2 and "'--plot'" in proc.stderr
    # the record beside the csv is an output too: checked with it (adir.provenance.json, a folder, for --csv adir.csv)
    (tmp_path / "adir.provenance.json").mkdir()
    proc = run_cli("simulate", "--csv", str(tmp_path / "adir.csv"), check=False)
    assert proc.returncode == 2 and "'--csv'" in proc.stderr and "adir.provenance.json is a folder" in proc.stderr
    (tmp_path / "adir.provenance.json").rmdir()
    proc = run_cli("simulate", "--seed", "-1", check=False)
    assert proc.returncode == 2 and "--seed" in proc.stderr and "integer >= 0" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir"] and not any((tmp_path / "adir").iterdir())


def test_simulate_keeps_a_file_beside_its_csv_that_is_no_record_of_it(tmp_path):
    """``--csv lab.csv`` writes ``lab.provenance.json`` beside it, a file the user did not name: one of theirs there
    was replaced without a word. Refused before the work; the command's own record of an earlier run is replaced."""
    (tmp_path / "lab.provenance.json").write_text('{"mine": 1}')
    proc = run_cli("simulate", "--csv", str(tmp_path / "lab.csv"), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "key '--csv'" in proc.stderr and "lab.provenance.json exists and is not the provenance record" in proc.stderr
    assert (tmp_path / "lab.provenance.json").read_text() == '{"mine": 1}' and not (tmp_path / "lab.csv").exists()
    (tmp_path / "lab.provenance.json").unlink()
    for _ in range(2):  # the second run replaces the first's csv and record
        run_cli("simulate", "--duration", "20", "--csv", str(tmp_path / "lab.csv"))
    assert json.loads((tmp_path / "lab.provenance.json").read_text())["csv"] == str(tmp_path / "lab.csv")


def test_a_configs_folder_that_is_missing_is_named_not_its_default_scenario(tmp_path):
    """``MARLCRASH_CONFIGS`` naming no folder read as "key '--scenario': unknown scenario 'full_width_40'; registered:
    []", though no --scenario was given."""
    env = {**os.environ, "MARLCRASH_CONFIGS": str(tmp_path / "nowhere")}
    proc = subprocess.run([sys.executable, "-m", "marlcrash.cli", "simulate"], capture_output=True, text=True,
                          timeout=600, env=env)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"error: key 'MARLCRASH_CONFIGS': {tmp_path / 'nowhere'} is no folder"), proc.stderr


def test_an_output_file_name_ending_in_a_slash_is_refused_not_written_as_a_file(tmp_path, monkeypatch):
    """``simulate --csv results/`` (a folder meant, not there yet) wrote the CSV as a file named ``results``, and
    ``discretize --save cells.npz/`` a file ``cells.npz``: the trailing '/' was dropped by Path. A file name ending in
    a path separator names a folder and is refused, naming the option, before the work (check_output_file)."""
    from marlcrash.outputs import check_output_file

    monkeypatch.chdir(tmp_path)
    proc = run_cli("simulate", "--csv", "results/", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith("error: key '--csv': results/ ends in '/', so names a folder; expected a file name")
    proc = run_cli("discretize", "--save", "cells.npz/", check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: key '--save': cells.npz/ ends in '/'")
    with pytest.raises(ConfigError, match=r"key 'out': .*/a\.csv/ ends in '/'"):
        check_output_file(str(tmp_path / "a.csv") + "/", "out")
    assert list(tmp_path.iterdir()) == []


def test_simulate_csv_takes_a_csv_file_name_as_pulse_reads_back(tmp_path):
    """``simulate --csv crash.dat`` (or ``--csv results``) was written, and ``marlcrash pulse`` then refused that very
    file ('expected a .csv/.txt file'); ``--csv crash.png`` wrote CSV text under a picture's name. As --plot and
    --save name their formats, --csv takes a .csv name (any case), checked before the work."""
    for name in ("crash.dat", "results", "crash.png"):
        proc = run_cli("simulate", "--csv", str(tmp_path / name), check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.startswith(f"error: key '--csv': {tmp_path / name}: expected a .csv file name"), proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_outputs_never_replace_the_command_inputs(tmp_path, lsopt_deck):
    """An output path that is the deck, the config or another output of the same command is refused before the work;
    the inputs are left as they were."""
    deck = tmp_path / "car.k"
    deck.write_text(lsopt_deck.read_text())
    config = tmp_path / "cells.yaml"
    config.write_text((Path(__file__).parents[1] / "configs" / "cells.yaml").read_text())
    params = ("--param", "tbumper=3", "--param", "thood=1")
    cases = [
        (("simulate", str(deck), *params, "--csv", str(deck)), "'--csv'"),
        (("simulate", str(deck), *params, "--config", str(config), "--csv", str(config)), "'--csv'"),
        (("discretize", str(deck), *params, "--config", str(config), "--save", str(config)), "'--save'"),
        (
            ("discretize", str(deck), *params, "--save", str(tmp_path / "c.npz"), "--plot", str(tmp_path / "c.npz")),
            "'--plot'",
        ),
    ]
    for args, key in cases:
        proc = run_cli(*args, check=False)
        assert proc.returncode == 2 and key in proc.stderr and "choose another file name" in proc.stderr, proc.stderr
    proc = run_cli("discretize", "--plot", str(tmp_path / "cells.txt"), check=False)
    assert proc.returncode == 2 and "'--plot'" in proc.stderr and "expected a .png file name" in proc.stderr
    assert deck.read_text() == lsopt_deck.read_text() and "upfront_sensor_x" in config.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["car.k", "cells.yaml"]


def test_simulate_messages_for_out_of_range_and_empty_input(tmp_path):
    proc = run_cli("simulate", "--speed", "200", "--json")
    assert "warning: 200 km/h lies outside" in proc.stderr and json.loads(proc.stdout)["speed_kmh"] == 200.0
    assert "warning" not in run_cli("simulate", "--speed", "56", "--json").stderr
    proc = run_cli("simulate", "--overlap", "1e-6", check=False)
    assert proc.returncode == 2 and "overlap 1e-06" in proc.stderr and "larger overlap" in proc.stderr
    empty = tmp_path / "empty.k"
    empty.write_text("*KEYWORD\n*END\n")
    proc = run_cli("simulate", str(empty), check=False)
    assert proc.returncode == 2 and "empty.k: the deck has no *NODE data" in proc.stderr
    for command in ("inspect", "discretize", "simulate"):  # a deck is one vehicle: a variant seed is not ignored
        proc = run_cli(command, str(empty), "--seed", "3", check=False)
        assert proc.returncode == 2 and "'--seed'" in proc.stderr and "only synthetic cars have variants" in proc.stderr


def test_simulate_overrides_and_errors():
    out = json.loads(run_cli("simulate", "--speed", "56", "--overlap", "0.4", "--side", "right", "--json").stdout)
    assert (out["speed_kmh"], out["overlap"], out["side"]) == (56.0, 0.4, "right")
    assert out["scenario"] == "custom_56kmh_overlap0.4_right"  # named after what it is, not full_width_40
    proc = run_cli("simulate", "--side", "right", "--json")
    assert "warning: --side right has no effect" in proc.stderr
    assert json.loads(proc.stdout)["scenario"] == "custom_40kmh_full_width"
    # an override that repeats the scenario's own value is the registered load case, named so
    same = run_cli("simulate", "--scenario", "offset40_left", "--speed", "56", "--side", "left", "--json").stdout
    assert json.loads(same)["scenario"] == "offset40_left"
    proc = run_cli("simulate", "--speed", "-3", check=False)
    assert proc.returncode == 2 and "key '--speed'" in proc.stderr and "speed_kmh" not in proc.stderr
    proc = run_cli("simulate", "--speed", "40", "--overlap", "1.5", check=False)
    assert proc.returncode == 2 and "key '--overlap'" in proc.stderr and "got 1.5" in proc.stderr
    proc = run_cli("simulate", "--scenario", "moon_landing", check=False)
    assert proc.returncode == 2 and "full_width_40" in proc.stderr  # lists the registered ones
    assert "key '--scenario': unknown scenario 'moon_landing'" in proc.stderr  # the option typed, as --speed's
    proc = run_cli("simulate", "--scenario", "", check=False)  # ran full_width_40
    assert proc.returncode == 2 and "unknown scenario ''" in proc.stderr
    for size in ("0", "-1"):  # argparse's own message, before any simulation
        proc = run_cli("bench", "--batch-sizes", size, check=False)
        assert proc.returncode == 2 and "expected an integer >= 1" in proc.stderr, proc.stderr


def test_simulate_duration_writes_a_longer_record_of_the_same_load_case(tmp_path):
    base = json.loads(run_cli("simulate", "--json").stdout)
    csv = tmp_path / "test.csv"
    out = json.loads(run_cli("simulate", "--duration", "200", "--csv", str(csv), "--json").stdout)
    assert (out["scenario"], out["duration_ms"], base["duration_ms"]) == ("full_width_40", 200.0, 150.0)
    rows = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert rows.shape[0] == 401 and rows[-1, 0] == pytest.approx(0.2)  # 2 kHz from t = 0
    assert out["peak_decel_g"] == pytest.approx(base["peak_decel_g"], rel=1e-4)  # long before 150 ms
    assert out["max_crush_m"] == pytest.approx(base["max_crush_m"], rel=1e-9)
    for bad, why in (("150.3", "not a whole number of 0.0005 s output steps"), ("0", "must be in (0, 1] s"),
                     ("2", "too short for the CFC 60 figures; expected at least 10 ms")):  # fmt: skip
        proc = run_cli("simulate", "--duration", bad, check=False)
        assert proc.returncode == 2 and f"key '--duration': {float(bad):g} ms: " in proc.stderr and why in proc.stderr
        assert "Traceback" not in proc.stderr


def test_bench_refuses_a_batch_size_beyond_max_batch_before_any_work():
    """``--batch-sizes 1000000000`` ran on into torch's "can't allocate memory" traceback; argparse refuses it."""
    from marlcrash.calibrate.baselines import MAX_BATCH

    for size in ("1000000000", str(MAX_BATCH + 1)):
        proc = run_cli("bench", "--batch-sizes", "1", size, check=False)
        assert proc.returncode == 2 and "argument --batch-sizes" in proc.stderr, proc.stderr
        assert f"expected a batch size in [1, {MAX_BATCH}]" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_bench_json_keys():
    args = ("--batch-sizes", "1", "4", "--skip-uniform", "--dtype", "float32", "--json")
    out = json.loads(run_cli("bench", *args).stdout)
    for key in ("sims_per_s_optimized", "n_cells_optimized", "overhead_share", "roofline_sims_per_s"):
        assert key in out, key
    assert out["dtype"] == "float32"
    assert set(out["sims_per_s_optimized"]) == {"1", "4"}
    assert out["smallest_b"] == 1 and out["speedup_vs_smallest_b"]["1"] == 1.0
    assert all(v > 0 for v in out["sims_per_s_optimized"].values())
    assert 0.0 <= out["overhead_share"]["4"] < 1.0


@pytest.mark.slow
def test_bench_json_keys_with_the_uniform_model():
    """The issue's keys with the uniform model at B = 64 (the full 1 / 64 / 1024 run is the README's benchmark)."""
    out = json.loads(run_cli("bench", "--batch-sizes", "1", "64", "--json").stdout)
    for key in (
        "sims_per_s_optimized",
        "sims_per_s_uniform_b64",
        "n_cells_optimized",
        "n_cells_uniform",
        "overhead_share",
        "roofline_sims_per_s",
    ):
        assert key in out, key
    assert set(out["sims_per_s_optimized"]) == {"1", "64"}
    assert out["sims_per_s_uniform_b64"] > 0 and out["n_cells_uniform"] > 8 * out["n_cells_optimized"]
    assert out["roofline_sims_per_s"] > 0


def test_the_bottoming_note_comes_only_when_the_impact_brings_more_than_the_plastic_capacity():
    from marlcrash.pulse.simulation import bottoming_note

    assert bottoming_note({"impact_energy_kj": 274.3, "crush_capacity_kj": 527.3}) is None
    assert bottoming_note({"impact_energy_kj": 527.3, "crush_capacity_kj": 527.3}) is None
    note = bottoming_note({"impact_energy_kj": 537.6, "crush_capacity_kj": 527.3})
    assert note.startswith("note: the impact brings 537.6 kJ and the cells can take 527.3 kJ as plastic work")


def test_json_output_is_standard_json(capsys):
    """``--json`` prints standard JSON: a value that could not be computed (NaN, inf) reads as null, also nested,
    instead of the ``NaN`` that strict parsers (JavaScript, jq) refuse."""
    from marlcrash.cli import _print_json

    _print_json({"a": float("nan"), "b": [1.0, float("inf"), {"c": -float("inf")}], "d": 2.5, "e": "x", "f": 3})

    def refuse(constant):
        raise AssertionError(f"non-standard JSON constant {constant}")

    out = json.loads(capsys.readouterr().out, parse_constant=refuse)
    assert out == {"a": None, "b": [1.0, None, {"c": None}], "d": 2.5, "e": "x", "f": 3}


def test_pulse_reads_a_csv_file_once(capsys, monkeypatch):
    """``marlcrash pulse`` on a CSV file without ``--acc-col`` read the whole file twice: once for the header's
    first acceleration column, once for the samples. Now once, with the same figures."""
    from marlcrash.cli import main

    path = DATA / "halfsine_40kmh.csv"
    assert main(["pulse", str(path), "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    reads = []
    read_bytes = Path.read_bytes

    def counted(self):
        reads.append(self)
        return read_bytes(self)

    monkeypatch.setattr(Path, "read_bytes", counted)
    assert main(["pulse", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == want
    assert reads == [path]


def test_pulse_warns_of_a_frontal_pulse_that_speeds_the_vehicle_up(tmp_path):
    """A record of the committed frontal half-sine with its deceleration positive: the JSON gives the same magnitudes,
    and stderr names the file, the channel and ``--deceleration-positive`` (it said nothing)."""
    rows = [line for line in (DATA / "halfsine_40kmh.csv").read_text().splitlines() if not line.startswith("#")]
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    flipped = tmp_path / "flipped.csv"
    flipped.write_text("time,tunnel_acx\n" + "".join(f"{t:.6f},{-a:.9g}\n" for t, a in data[:, :2]))
    proc = run_cli("pulse", str(flipped), "--json")
    ref = json.loads(run_cli("pulse", str(DATA / "halfsine_40kmh.csv"), "--json").stdout)
    assert json.loads(proc.stdout)["delta_v_ms"] == pytest.approx(ref["delta_v_ms"], rel=1e-6)
    assert "warning: " in proc.stderr and "flipped.csv: channel 'tunnel_acx' speeds up" in proc.stderr
    assert "--deceleration-positive" in proc.stderr
    again = run_cli("pulse", str(flipped), "--json", "--deceleration-positive")
    assert "speeds up" not in again.stderr


def test_an_empty_path_is_refused_not_read_as_the_default_or_this_folder(tmp_path, monkeypatch, capsys):
    """An empty path (a shell variable left unset: ``marlcrash inspect "$DECK"``) was taken as no path, or as the
    working folder: ``inspect ""`` and ``discretize ""`` summarised the embedded car, ``--config ""`` read
    configs/cells.yaml, ``contributions --out ""`` wrote into ./contributions and ``pulse ""`` read this folder as a
    test. Each is now refused by the parser, naming the argument, before any work."""
    monkeypatch.chdir(tmp_path)
    cases = [  # the trailing options fail fast where the empty path is taken (so the old behaviour is quick to see)
        (("inspect", ""), "deck"),
        (("discretize", "", "--save", "c.txt"), "deck"),
        (("simulate", "", "--csv", "missing/x.csv"), "deck"),
        (("discretize", "--config", "", "--save", "c.txt"), "--config"),
        (("inspect", "b_segment", "--subassemblies", ""), "--subassemblies"),
        (("discretize", "--save", ""), "--save"),
        (("simulate", "--plot", ""), "--plot"),
        (("simulate", "--csv", ""), "--csv"),
        (("pulse", ""), "file"),
        (("pulse", "x.csv", "--plot", ""), "--plot"),
        (("contributions", "", "--permutations", "3"), "run"),
        (("contributions", "--out", "", "--permutations", "3"), "--out"),
    ]
    for args, name in cases:
        _refused_by_the_parser(capsys, args, f"error: argument {name}: expected a path, got an empty one")
    assert list(tmp_path.iterdir()) == []


def test_a_config_or_map_that_is_a_folder_or_missing_is_refused_naming_its_option(tmp_path, capsys):
    """``--config FOLDER`` said only "<folder name>: cannot read config file (Is a directory)", after the deck was
    read; a folder or missing file given for ``--config`` or ``--subassemblies`` is now refused by the parser."""
    folder, missing = f"{tmp_path} is a folder; expected a YAML file", f"no such file '{tmp_path / 'm.yaml'}'"
    cases = [
        (("discretize", "--config", str(tmp_path)), "--config", folder),
        (("simulate", "--config", str(tmp_path / "m.yaml")), "--config", missing),
        (("inspect", "b_segment", "--subassemblies", str(tmp_path)), "--subassemblies", folder),
        (("inspect", "b_segment", "--subassemblies", str(tmp_path / "m.yaml")), "--subassemblies", missing),
    ]
    for args, name, what in cases:
        _refused_by_the_parser(capsys, args, f"error: argument {name}: {what}")


def test_the_package_runs_as_a_module():
    """``python -m marlcrash`` (where the console script is not on PATH: a checkout run in place, another venv's
    Python) said "'marlcrash' is a package and cannot be directly executed"; it is now the ``marlcrash`` command."""
    proc = subprocess.run([sys.executable, "-m", "marlcrash", "inspect", "--help"], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert proc.returncode == 0 and proc.stdout.startswith("usage: marlcrash inspect"), proc.stderr
    proc = subprocess.run([sys.executable, "-m", "marlcrash", "inspect", "b_segment", "--seed", "x"],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "argument --seed: expected an integer >= 0" in proc.stderr


def test_an_interrupt_ends_the_command_without_a_traceback(tmp_path):
    """Ctrl-C in a long command (contributions, simulate) printed a Python traceback from wherever the work was. It
    now prints one line and the process still ends by SIGINT, so a calling shell loop stops too (an exit status of
    130 would let ``for f in *.csv; do marlcrash pulse "$f"; done`` go on to the next file). An output being written
    is left as it was (atomic writes), and no temporary file stays beside it. ``main(argv)`` called in a process of
    the caller's (a notebook, a test) leaves the interrupt to that caller: a Jupyter kernel is not ended by it."""
    import signal

    target = tmp_path / "out.csv"
    target.write_text("old\n")
    common = (
        "import sys\nfrom pathlib import Path\nimport marlcrash.cli as cli\n"
        "from marlcrash.outputs import atomic_output\n"
        "def interrupted(args):\n"
        "    with atomic_output(Path(args.csv)) as tmp:\n"
        "        tmp.write_text('half of the new')\n"
        "        raise KeyboardInterrupt\n"
        "cli.cmd_simulate = interrupted\n"
    )
    argv = ["simulate", "--csv", str(target)]
    console = common + f"sys.argv = {['marlcrash', *argv]!r}\nsys.exit(cli.main())\n"  # as the console script
    proc = subprocess.run([sys.executable, "-c", console], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr and proc.stderr == "interrupted\n", proc.stderr
    assert proc.returncode == -signal.SIGINT
    assert target.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]
    in_process = (
        common + f"try:\n    cli.main({argv!r})\nexcept KeyboardInterrupt:\n    print('caught by the caller')\n"
    )
    proc = subprocess.run([sys.executable, "-c", in_process], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout == "caught by the caller\n" and proc.stderr == "interrupted\n"
    assert target.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_an_output_named_dash_is_refused_not_written_as_a_file_named_dash(tmp_path, monkeypatch, capsys):
    """``simulate --csv -`` (standard output, as many commands read '-') wrote a file named '-' into the working
    folder, and the summary went to standard output as ever; ``contributions --out -`` made a folder '-'. An output
    path '-' is refused by the parser, naming the option, before any work."""
    monkeypatch.chdir(tmp_path)
    for args, name in (
        (("simulate", "--csv", "-", "--plot", "x.txt"), "--csv"),
        (("discretize", "--plot", "-"), "--plot"),
        (("discretize", "--save", "-"), "--save"),
        (("pulse", "x.csv", "--plot", "-"), "--plot"),
        (("contributions", "--out", "-", "--permutations", "3"), "--out"),
    ):
        _refused_by_the_parser(capsys, args, f"error: argument {name}: expected a file or folder name, got '-'")
    assert list(tmp_path.iterdir()) == []


def test_a_file_name_that_is_not_utf8_is_printed_not_a_traceback(tmp_path):
    """A file named in another encoding than the system's (latin-1 'Prüfung.csv' from an old share or zip) is read,
    but printing its name in the table stopped with a UnicodeEncodeError traceback under a UTF-8 locale (standard
    output is strict there). Standard output now writes such a name back as the bytes it was given, as ``ls`` does."""
    import os
    import shutil

    name = os.fsdecode(b"Pr\xfcfung.csv")  # latin-1 bytes: not UTF-8, so a surrogate escape in Python
    shutil.copy(DATA / "halfsine_40kmh.csv", tmp_path / name)
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}  # a UTF-8 locale's strict standard output
    proc = subprocess.run([sys.executable, "-m", "marlcrash.cli", "pulse", str(tmp_path / name)], capture_output=True,
                          env=env, timeout=120)  # fmt: skip
    assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr.decode(errors="replace")
    assert proc.stdout.startswith(b"file              " + os.fsencode(tmp_path) + b"/Pr\xfcfung.csv\n")


def test_every_option_with_a_default_says_it_in_its_help():
    """``pulse --cfc`` said 'CFC class, 0 for none' without the class used when it is not given (60), and
    ``simulate --overlap/--side`` not that the scenario's apply: a user could not tell from --help what a run without
    them does. Every option with a default value names it in its help, and --overlap/--side say the scenario's."""
    from marlcrash.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.option_strings and action.nargs != 0 and action.default is not None:
                assert "default" in (action.help or ""), (name, action.option_strings, action.help)
            if name == "simulate" and action.dest in ("overlap", "side"):
                assert "(default: the scenario's)" in action.help, action.help


def test_version():
    """``marlcrash --version`` names the package's version, the one pyproject.toml declares (what a bug report and a
    run's provenance.json quote); it was refused as an unknown argument."""
    import tomllib

    import marlcrash

    declared = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]["version"]
    assert marlcrash.__version__ == declared
    proc = subprocess.run([sys.executable, "-m", "marlcrash", "--version"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"marlcrash {declared}"
