"""Pulse IO: CSV and ISO-MME round trips, delta-v of analytic pulses, summary, plot, bad input."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from marlcrash.errors import PulseError
from marlcrash.pulse import (
    Pulse,
    filter_pulse,
    find_time_zero,
    from_rearward_x,
    integrate,
    plot_pulse,
    prepare_velocity,
    pulse_summary,
    read_csv,
    read_mme,
    read_pulse,
    resample,
    write_csv,
    write_mme,
)
from marlcrash.pulse.io import MAX_CRASH_DELTA_V
from marlcrash.units import G0

DATA = Path(__file__).parent / "data"
DV = 40 / 3.6  # [m/s] velocity change of the analytic pulses


def half_sine(t: np.ndarray, tau: float, dv: float = DV) -> np.ndarray:
    """Frontal pulse (negative) of duration tau [s] whose integral is -dv (exactly 2 A tau / pi = dv)."""
    amp = dv * math.pi / (2 * tau)
    return np.where((t >= 0) & (t <= tau), -amp * np.sin(math.pi * np.clip(t, 0, tau) / tau), 0.0)


@pytest.fixture
def analytic() -> Pulse:
    t = np.arange(-0.02, 0.2, 1e-4)
    return Pulse(t, np.stack([half_sine(t, 0.080), half_sine(t, 0.060)]), ("tunnel", "radsup"))


def test_integration_of_a_half_sine_is_exact_to_discretization():
    t = np.arange(0, 0.1 + 1e-12, 1e-5)
    v = integrate(t, half_sine(t, 0.1), v0=DV)
    exact = DV - DV * (1 - np.cos(math.pi * t / 0.1)) / 2
    np.testing.assert_allclose(v, exact, atol=1e-6)


@pytest.mark.parametrize("unit", ["g", "m/s2"])
def test_csv_round_trip_delta_v_within_one_percent(tmp_path, analytic, unit):
    path = write_csv(analytic, tmp_path / "pulse.csv", unit=unit)
    back = read_csv(path, unit=unit)
    assert back.channels == ("tunnel", "radsup")
    np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)
    filtered = filter_pulse(back, 60)
    dv_end = filtered.velocity()[:, -1]
    np.testing.assert_allclose(dv_end, -DV, rtol=0.01)
    # the convention: a frontal crash pulse is negative, the velocity change too
    assert (filtered.acc.min(axis=1) < -10 * G0).all() and (dv_end < 0).all()


def test_mme_round_trip_delta_v_within_one_percent(tmp_path, analytic):
    mme = write_mme(analytic, tmp_path / "T1", "T1")
    assert mme.name == "T1.mme" and (tmp_path / "T1" / "Channel" / "T1.002").is_file()
    back = read_mme(tmp_path / "T1")
    assert back.channels == ("tunnel", "radsup")
    np.testing.assert_allclose(back.time, analytic.time, atol=1e-12)
    np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(filter_pulse(back, 60).velocity()[:, -1], -DV, rtol=0.01)
    one = read_mme(mme, channels="RADSUP")  # by the .mme file, channel matched case-insensitively
    assert one.channels == ("radsup",)


def test_mme_header_text_outside_latin_1_is_refused_naming_the_field(tmp_path, analytic):
    """ISO-MME files are written and read in Latin-1 (ISO 8859-1). A channel name read from a UTF-8 CSV header
    ('a_x Σ') crashed ``write_mme`` with a bare UnicodeEncodeError, after the .mme file was written; a name holding a
    line break wrote a file whose header ended there. Both are refused, naming the channel and the character, before
    anything is written; a Latin-1 name ('Beschl. m/s²') is written and read back."""
    greek = Pulse(analytic.time, analytic.acc, ("tunnel", "a_x \u03a3"))
    with pytest.raises(PulseError, match=r"channel 2 name 'a_x Σ': 'Σ' \(U\+03A3\) is not a Latin-1 character"):
        write_mme(greek, tmp_path / "G", "G")
    assert not (tmp_path / "G").exists()
    with pytest.raises(PulseError, match=r"test name 'T\u2013 1': '\u2013' \(U\+2013\) is not a Latin-1"):
        write_mme(analytic, tmp_path / "D", "T\u2013 1")
    broken = Pulse(analytic.time, analytic.acc, ("tunnel", "rad\nsup"))
    with pytest.raises(PulseError, match=r"channel 2 name 'rad\\nsup': '\\n' \(U\+000A\) is a line break"):
        write_mme(broken, tmp_path / "B", "B")
    latin = Pulse(analytic.time, analytic.acc, ("tunnel", "Beschl. m/s²"))
    write_mme(latin, tmp_path / "L", "Prüfung")
    assert read_mme(tmp_path / "L").channels == ("tunnel", "Beschl. m/s²")


@pytest.mark.parametrize(
    ("test", "says"),
    [
        ("", r"test name '' is empty"),
        ("run/2", r"test name 'run/2': '/' \(U\+002F\) is a path separator"),
        ("run\x002", r"test name 'run\\x002': '\\x00' \(U\+0000\) cannot stand in a file name"),
    ],
    ids=["empty", "slash", "nul"],
)
def test_a_test_name_that_cannot_name_the_files_is_refused_before_anything_is_written(tmp_path, analytic, test, says):
    """The test name is the stem of every file of the test (``<test>.mme``, ``Channel/<test>.001``). An empty one
    wrote ``.mme`` and ``Channel/.001``, a test ``read_mme`` then refused ('found 0' .mme files); one holding ``/``
    raised a bare FileNotFoundError after the Channel folder was made, and one holding a NUL a bare ValueError
    ('embedded null byte'). Each is refused naming the name, before anything is written."""
    with pytest.raises(PulseError, match=r"write_mme: " + says):
        write_mme(analytic, tmp_path / "T", test)
    assert not (tmp_path / "T").exists()
    write_mme(analytic, tmp_path / "ok", "run 2.v1")  # spaces and dots are fine
    assert read_mme(tmp_path / "ok").channels == analytic.channels


def test_mme_channel_files_past_999_are_read_in_numeric_order(tmp_path):
    """Channel files are numbered with at least three digits: the 1000th is ``<test>.1000`` (as pyisomme writes it).
    ``read_mme`` found only three-digit suffixes, so a pulse of 1000 channels came back with 999 without a word; the
    files are read in numeric order (a name sort puts ``.1000`` before ``.101``)."""
    t = np.arange(8) * 1e-4  # the fewest samples a pulse may have
    many = Pulse(t, np.arange(1000.0)[:, None] * np.ones((1000, t.size)), tuple(f"c{i}" for i in range(1000)))
    write_mme(many, tmp_path / "M", "M")
    assert (tmp_path / "M" / "Channel" / "M.1000").is_file()
    back = read_mme(tmp_path / "M")
    assert back.channels == many.channels
    np.testing.assert_allclose(back.acc, many.acc, rtol=1e-6, atol=1e-6)


def test_committed_csv_and_mme_examples_agree_and_give_40_kmh():
    csv = read_pulse(DATA / "halfsine_40kmh.csv")
    mme = read_pulse(DATA / "HS40")
    assert csv.channels == ("tunnel_acx", "radsup_acx")
    assert mme.channels == ("10TUNN0000ACXP", "10RADS0000ACXP")
    assert csv.n_samples == mme.n_samples == 1101 and csv.sample_rate_hz == pytest.approx(5000.0)
    np.testing.assert_allclose(csv.acc, mme.acc, rtol=1e-4, atol=1e-3)  # g vs m/s**2 channel, 5 digits
    for p in (csv, mme):
        np.testing.assert_allclose(filter_pulse(p, 60).velocity()[:, -1], -DV, rtol=0.01)


def test_sign_and_time_unit_options(tmp_path, analytic):
    path = tmp_path / "ms.csv"
    data = np.column_stack([analytic.time * 1e3, -analytic.acc[0] / G0])  # ms, deceleration positive
    np.savetxt(path, data, delimiter=";", header="Time [ms];x", comments="")
    p = read_csv(path, acc_col="x", time_unit="ms", sign=-1)
    np.testing.assert_allclose(p.time, analytic.time, atol=1e-12)
    np.testing.assert_allclose(p.acc[0], analytic.acc[0], atol=1e-9)
    assert float(from_rearward_x(np.array(2.0))) == -2.0


def test_pulse_summary_csv_and_mme(tmp_path, analytic):
    amp_g = DV * math.pi / (2 * 0.080) / G0  # 22.25 g
    for path in (write_csv(analytic, tmp_path / "a.csv"), write_mme(analytic, tmp_path / "M", "M").parent):
        s = pulse_summary(path, acc_col="tunnel")
        assert s["channel"] == "tunnel" and s["n_samples"] == analytic.n_samples
        assert s["sample_rate_hz"] == pytest.approx(1e4)
        assert s["peak_g"] == pytest.approx(amp_g, rel=0.01)
        # time zero is the onset (t = 0), not the 0.5 g crossing, asin(0.5 g / A) * tau / pi = 0.57 ms after it
        assert s["t0_ms"] == pytest.approx(0.0, abs=0.1)
        assert s["t_peak_ms"] == pytest.approx(40.0 - s["t0_ms"], abs=0.2)
        assert s["delta_v_ms"] == pytest.approx(DV, rel=0.01)
        assert s["delta_v_150ms_ms"] == pytest.approx(DV, rel=0.01)
        assert s["delta_v_kmh"] == pytest.approx(40.0, rel=0.01)
    short = Pulse(analytic.time[:1000], analytic.acc[:, :1000], analytic.channels)  # ends at 80 ms
    s = pulse_summary(write_csv(short, tmp_path / "short.csv"), time_zero="file")
    assert s["delta_v_150ms_ms"] is None and s["t0_ms"] == 0.0


def test_prepare_velocity_gives_2_khz_from_time_zero(analytic):
    t, v = prepare_velocity(analytic, duration=0.15, v0=DV)
    assert t[0] == 0.0 and len(t) == 301
    np.testing.assert_allclose(np.diff(t), 5e-4, atol=1e-12)
    np.testing.assert_allclose(v[:, 0], DV, atol=0.005)  # v0 at the onset, but for what the filter spreads before it
    np.testing.assert_allclose(v[:, -1], 0.0, atol=0.01 * DV)
    t0 = find_time_zero(filter_pulse(analytic, 60))
    assert -0.001 < t0 < 0.001


@pytest.mark.parametrize("duration", [0.0, -0.01, float("nan"), float("inf"), "0.15"])
def test_prepare_velocity_refuses_a_window_that_is_not_a_duration(analytic, duration):
    """A window of -10 ms returned no samples without a word (a metric over it compares nothing) and NaN raised
    "cannot convert float NaN to integer" from inside; each now names the duration and what was expected."""
    with pytest.raises(PulseError, match=r"duration: expected a window > 0 s after time zero"):
        prepare_velocity(analytic, duration=duration, time_zero="file")


@pytest.mark.parametrize("rate", [0.0, -2000.0, float("nan"), "2000"])
def test_prepare_velocity_refuses_a_rate_that_is_not_a_number_of_hz(analytic, rate):
    """A rate of 0 raised ZeroDivisionError, one given as text "can't multiply sequence by non-int"."""
    with pytest.raises(PulseError, match=r"rate_hz: expected a finite output rate > 0 Hz"):
        prepare_velocity(analytic, rate_hz=rate, duration=0.15, time_zero="file")


@pytest.mark.parametrize(
    ("key", "value"),
    [("beyond", "0.01"), ("beyond", None), ("v0", float("nan")), ("v0", "11"), ("v0", [11.0, 11.0, 11.0]),
     ("threshold_g", "0.5"), ("threshold_g", None)],
)  # fmt: skip
def test_prepare_velocity_names_a_setting_that_is_not_a_number(analytic, key, value):
    """``beyond`` or ``threshold_g`` as text or None raised TypeErrors naming nothing ('must be real number', "'>' not
    supported"); ``v0`` NaN gave a NaN reference, text was read as a number, and three speeds for the two channels
    raised numpy's broadcast error (two speeds for one channel made the reference two channels without a word)."""
    with pytest.raises(PulseError, match=key):
        prepare_velocity(analytic, duration=0.15, **{key: value})


def test_prepare_velocity_takes_one_speed_or_one_per_channel(analytic):
    _, v = prepare_velocity(analytic, duration=0.15, v0=DV)
    _, each = prepare_velocity(analytic, duration=0.15, v0=np.array([DV, DV + 1.0]))
    np.testing.assert_allclose(each, v + np.array([[0.0], [1.0]]), atol=1e-12)
    with pytest.raises(PulseError, match="v0"):
        prepare_velocity(analytic.select("tunnel"), duration=0.15, v0=[DV, DV])


def test_resample_is_linear_interpolation(analytic):
    r = resample(analytic, 2000.0, 0.0, 0.1)
    assert r.n_samples == 201 and r.time[-1] == pytest.approx(0.1)
    np.testing.assert_allclose(r.acc[0], np.interp(r.time, analytic.time, analytic.acc[0]))
    with pytest.raises(PulseError, match="inside the record"):
        resample(analytic, 2000.0, -1.0, 0.1)


def test_plot_pulse_writes_png(tmp_path, analytic):
    out = plot_pulse(filter_pulse(analytic, 60), tmp_path / "p.png", reference=analytic)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


# ------------------------------------------------------------------------------------- bad input


def _csv(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    return path


GOOD_ROWS = "".join(f"{i * 1e-4:.4f},{-float(i)}\n" for i in range(20))
BAD_CELL_ROWS = "".join(f"{i * 1e-4:.4f},{'abc' if i == 5 else -float(i)}\n" for i in range(20))


@pytest.mark.parametrize(
    ("text", "kwargs", "pattern"),
    [
        ("time,acc\n" + GOOD_ROWS, {"acc_col": "accel"}, r"bad\.csv line 1: column 'accel' not found"),
        (
            "time,acc\n" + BAD_CELL_ROWS,
            {},
            r"bad\.csv line 7, column 'acc': "
            r"expected a number, got 'abc'",
        ),
        ("time,acc\n0.0000,1\n0.0001,nan\n" + GOOD_ROWS, {}, r"bad\.csv line 3, column 'acc': expected a finite"),
        (
            "time,acc\n0.0000,1\n0.0002,1\n0.0001,1\n" + "".join(f"{1 + i},0\n" for i in range(10)),
            {},
            r"bad\.csv line 4, column 'time': time goes backwards",
        ),
        (
            "time,acc\n0.0000,1\n0.0001,1\n0.0001,1\n" + "".join(f"{1 + i},0\n" for i in range(10)),
            {},
            r"bad\.csv line 4, column 'time': duplicated time",
        ),
        ("time,acc\n0.0000,1\n0.0001,1\n", {}, r"bad\.csv: expected at least 8 samples, got 2"),
        ("time,acc\n0.0000,1,3\n" + GOOD_ROWS, {}, r"bad\.csv line 2: expected 2 fields as in the header, got 3"),
        ("# only a comment\n", {}, r"bad\.csv: expected a header row"),
        ("time,acc\n" + GOOD_ROWS, {"unit": "furlong"}, r"expected an acceleration unit"),
        (GOOD_ROWS, {}, r"bad\.csv line 1: expected a header row naming the columns"),
        ("# time,acc\n" + GOOD_ROWS, {}, r"bad\.csv line 2: expected a header row naming .*comments=''"),
        # Python's float reads digit groups: '1_000' was 1000 g
        (
            "time,acc\n" + GOOD_ROWS + "0.0020,1_000\n",
            {},
            r"bad\.csv line 22, column 'acc': expected a number, got '1_0",
        ),
        # a quoted line break joined two lines, and every later line number was one short
        (
            "time,acc\n" + GOOD_ROWS[:24] + '0.0002,"1\n",x\n' + GOOD_ROWS[24:],
            {},
            r"bad\.csv line 4: cannot split the line into fields at ',': expected every quoted field to close on",
        ),
        (
            "time,acc\n" + GOOD_ROWS + "0.0020," + "1" * 200_000 + "\n",
            {},  # csv's own error, of no file or line
            r"bad\.csv line 22: cannot split .* at most 131072 characters in a field",
        ),
    ],
    ids=[
        "missing-column",
        "non-numeric",
        "nan",
        "backwards",
        "duplicate",
        "too-few",
        "ragged",
        "empty",
        "unit",
        "no-header",
        "commented-header",
        "digit-groups",
        "quoted-line-break",
        "huge-field",
    ],
)
def test_bad_csv_raises_pulse_error_with_file_and_line(tmp_path, text, kwargs, pattern):
    with pytest.raises(PulseError, match=pattern):
        read_csv(_csv(tmp_path, text), **kwargs)


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(PulseError, match=r"nope\.csv: cannot read"):
        read_csv(tmp_path / "nope.csv")
    (tmp_path / "x.bin").write_bytes(b"\0")
    with pytest.raises(PulseError, match=r"x\.bin: expected a \.csv"):
        read_pulse(tmp_path / "x.bin")


def _mme(tmp_path: Path, analytic: Pulse) -> Path:
    write_mme(analytic, tmp_path / "B", "B")
    return tmp_path / "B" / "Channel" / "B.001"


def _edit(path: Path, old: str, new: str) -> None:
    path.write_text(path.read_text(encoding="latin-1").replace(old, new, 1), encoding="latin-1")


def test_bad_mme_sample_line(tmp_path, analytic):
    ch = _mme(tmp_path, analytic)
    lines = ch.read_text(encoding="latin-1").splitlines()
    lines[20] = "1.0e0x"
    ch.write_text("\n".join(lines) + "\n", encoding="latin-1")
    with pytest.raises(PulseError, match=r"B\.001 line 21: expected one sample value per line, got '1.0e0x'"):
        read_mme(tmp_path / "B")
    lines[20] = "1_000"  # Python's float reads digit groups: 1000 g
    ch.write_text("\n".join(lines) + "\n", encoding="latin-1")
    with pytest.raises(PulseError, match=r"B\.001 line 21: expected one sample value per line, got '1_000'"):
        read_mme(tmp_path / "B")


def test_of_three_mme_channels_the_one_recorded_apart_is_named(tmp_path, analytic):
    """The channel sharing no time with the others is named, whichever it is (the latest starting one was, and with
    the first channel moved earlier than the rest it was another)."""
    three = Pulse(analytic.time, np.stack([*analytic.acc, analytic.acc[0]]), ("a", "b", "c"))
    write_mme(three, tmp_path / "T", "T")
    _edit(tmp_path / "T" / "Channel" / "T.001", "Time of first sample        :-0.02", "Time of first sample        :-5")
    with pytest.raises(PulseError, match=r"T\.001: the channels read \(T\.001 -5 to .*; T\.001 lies apart from the"):
        read_mme(tmp_path / "T")


def test_a_blank_line_inside_an_mme_channel_header_does_not_end_it(tmp_path, analytic):
    ch = _mme(tmp_path, analytic)
    _edit(ch, "Unit                        :g\n", "\nUnit                        :g\n\n")  # the Unit line was 'missing'
    plain = read_mme(_mme(tmp_path / "c", analytic).parent.parent)
    np.testing.assert_array_equal(read_mme(tmp_path / "B").acc, plain.acc)


def test_bad_mme_headers(tmp_path, analytic):
    ch = _mme(tmp_path, analytic)
    _edit(ch, "Unit                        :g", "Unit                        :N")
    with pytest.warns(UserWarning, match=r"B\.mme: read the acceleration channels only; skipped B\.001 \(N\)"):
        assert read_mme(tmp_path / "B").channels == ("radsup",)  # by default only acceleration channels are read
    with pytest.raises(PulseError, match=r"B\.001 line 4: expected an acceleration unit"):
        read_mme(tmp_path / "B", channels="B.001")  # named, it must be one
    _edit(ch.with_suffix(".002"), "Unit                        :g", "Unit                        :kN")
    with pytest.raises(PulseError, match=r"B\.mme: no acceleration channel in the test \(channel units: \['N', 'kN'\]"):
        read_mme(tmp_path / "B")
    _edit(ch.with_suffix(".002"), "Unit                        :kN", "Unit                        :g")
    _edit(ch, "Unit                        :N\n", "")
    with pytest.raises(PulseError, match=r"B\.001: missing header line 'Unit'"):  # never skipped as "not acceleration"
        read_mme(tmp_path / "B")
    assert read_mme(tmp_path / "B", channels="radsup").channels == ("radsup",)  # not needed when not read
    _edit(ch, "Reference system", "Unit                        :g\nReference system")
    _edit(ch, "Unit                        :N", "Unit                        :g")
    _edit(ch, "Number of samples           :2200", "Number of samples           :2201")
    with pytest.raises(PulseError, match=r"B\.001 line 8: 'Number of samples' says 2201, found 2200"):
        read_mme(tmp_path / "B")
    _edit(ch, "Number of samples           :2201", "Number of samples           :2200.7")  # was read as 2200
    with pytest.raises(PulseError, match=r"B\.001 line 8: 'Number of samples': expected a whole number, got '2200\.7'"):
        read_mme(tmp_path / "B")
    _edit(ch, "Number of samples           :2200.7", "Number of samples           :2200")
    _edit(ch, "Sampling interval           :", "Sampling interval           :x")
    with pytest.raises(PulseError, match=r"B\.001 line 7: 'Sampling interval': expected a number"):
        read_mme(tmp_path / "B")
    with pytest.raises(PulseError, match=r"channel 'HEAD' not found"):
        read_mme(tmp_path / "B", channels="HEAD")


def test_mme_without_channel_folder(tmp_path):
    (tmp_path / "E").mkdir()
    (tmp_path / "E" / "E.mme").write_text("Data format edition number  :1.6\n")
    with pytest.raises(PulseError, match=r"E\.mme: expected a 'Channel' folder"):
        read_mme(tmp_path / "E")


def test_time_zero_outside_the_record_names_the_record_as_written(tmp_path):
    from marlcrash.pulse.io import processed_pulse

    early = tmp_path / "early.csv"  # ends 50 ms before the file's time zero
    early.write_text("time,acc\n" + "".join(f"{-0.2 + k * 5e-4:.4f},-1.0\n" for k in range(301)))
    with pytest.raises(PulseError, match=r"early\.csv: time zero 0 s \(the file's t = 0, --time-zero file; "
                       r"time_zero='file'\) lies outside the record \[-0\.2, -0\.05\] s"):  # fmt: skip
        processed_pulse(early, time_zero="file")
    # the file's t = 0 of a record on a clock from 1 s: the option that reads it is named (the error named none)
    late = tmp_path / "late.csv"
    late.write_text("time,acc\n" + "".join(f"{1 + k * 5e-4:.4f},-1.0\n" for k in range(301)))
    with pytest.raises(PulseError, match=r"late\.csv: time zero 0 s \(the file's t = 0, --time-zero file; "
                       r"time_zero='file'\) lies outside the record \[1, 1\.15\] s: its clock does not start at the "
                       r"contact; read it with --time-zero threshold \(time_zero='threshold'\)"):  # fmt: skip
        processed_pulse(late, time_zero="file")


@pytest.mark.parametrize("start", [0.0, 1e-4, 0.015])
def test_a_record_starting_after_its_t0_is_refused_not_led_in_by_made_up_data(tmp_path, start):
    """The zero-acceleration lead-in before a record is an assumption for the filter, not data: a record whose first
    sample lies 15 ms after the file's t = 0 had those 15 ms of its window made up (accepted, 0.84 m/s short of the
    20 g half-sine's velocity change). One sample interval late is a clock whose first sample closes an interval."""
    from marlcrash.pulse.io import processed_pulse

    t = start + np.arange(2000) * 1e-4
    pulse = Pulse(t, half_sine(t, 0.080)[None], ("x",), source="rec.csv")
    path = write_csv(pulse, tmp_path / "rec.csv")
    if start > 1e-4:
        with pytest.raises(PulseError, match=r"rec\.csv: time zero t = 0 ms .* lies outside the record \[15, 214\.9\]"):
            prepare_velocity(pulse, time_zero="file", duration=0.1)
        with pytest.raises(PulseError, match=r"rec\.csv: time zero 0 s \(the file's t = 0.* the record \[0\.015,"):
            processed_pulse(path, time_zero="file")
        return
    _, v = prepare_velocity(pulse, time_zero="file", duration=0.1)
    assert v[0, -1] == pytest.approx(-DV, rel=2e-3)  # -DV - v0 = -DV from a record that holds the whole pulse
    assert processed_pulse(path, time_zero="file")[2] == 0.0


def test_filtering_a_pulse_again_with_its_own_class_leaves_it_as_it_is(analytic):
    once = filter_pulse(analytic, 60)
    assert filter_pulse(once, 60) is once  # filtered twice, a 10 ms, 50 g half-sine's 47.5 g peak came out at 45 g
    # the compared signal of a filtered pulse is that of the pulse read as filtered (cfc=None), not filtered again
    as_read = prepare_velocity(once, cfc=None, duration=0.1)[1]
    np.testing.assert_array_equal(prepare_velocity(once, duration=0.1)[1], as_read)
    assert filter_pulse(filter_pulse(analytic, 180), 60).cfc == 60  # a stricter class still filters
    with pytest.raises(PulseError, match="already filtered with CFC 60, cannot apply CFC 180"):
        filter_pulse(once, 180)


def test_bad_arguments_to_the_signal_helpers_are_pulse_errors_that_say_what_was_expected(analytic):
    from marlcrash.pulse.cfc import cfc_filter_torch, cfc_matrix
    from marlcrash.pulse.signal import filtered_acceleration

    with pytest.raises(PulseError, match=r"v0: expected one speed or one per trace \(shape \[2\]\), got shape \[3\]"):
        analytic.velocity(np.zeros(3))  # 3 speeds for 2 channels: a [3, T] broadcast for 1 channel
    with pytest.raises(PulseError, match=r"v0: .*shape \[1\]\), got shape \[3\]"):
        analytic.select(0).velocity(np.zeros(3))
    assert analytic.velocity(np.array([1.0, 2.0]))[:, 0].tolist() == [1.0, 2.0]
    with pytest.raises(PulseError, match=r"time: expected \[T\] sample times for accelerations of shape \[2200\]"):
        integrate(analytic.time[:10], analytic.acc[0])
    with pytest.raises(PulseError, match="expected a finite sampling interval dt > 0"):
        filtered_acceleration(analytic.acc, 0.0)
    for bad in ("1e-4", 0.0):
        with pytest.raises(PulseError, match="expected a finite sampling interval dt > 0"):
            cfc_matrix(10, bad)
        with pytest.raises(PulseError, match="expected a finite sampling interval dt > 0"):
            cfc_filter_torch(torch.zeros(1, 300), bad)
    with pytest.raises(PulseError, match="resampling rate must be a positive number of Hz, got '2000'"):
        resample(analytic, "2000")
    with pytest.raises(PulseError, match="t_start: expected a time"):
        resample(analytic, 2000.0, "a")
    assert analytic.select(np.int64(1)).channels == ("radsup",)  # numpy's index was 'not iterable'
    with pytest.raises(PulseError, match="channels: expected a sequence of channel names, got the text 'x'"):
        Pulse(analytic.time, analytic.acc[0], "x")
    with pytest.raises(PulseError, match=r"expected at least one channel, got acc of shape \(0, 2200\)"):
        Pulse(analytic.time, np.zeros((0, analytic.n_samples)), ())


def test_pulse_rejects_non_increasing_time_and_nan():
    t = np.arange(10) * 1e-3
    with pytest.raises(
        PulseError, match=r"strictly increase; sample 1 has t=0\.008 after t=0\.009\d*$"
    ):  # plain numbers
        Pulse(t[::-1], np.zeros(10), ("a",))
    with pytest.raises(PulseError, match="finite"):
        Pulse(t, np.full(10, np.nan), ("a",))


def test_a_pulse_with_nan_names_the_channel_and_the_sample():
    """A pulse built in memory (the Python API, a simulation's record) with NaN in one channel said 'time and
    acceleration must be finite; found NaN or inf', naming neither the channel nor where: it names both, as the
    readers name a file's line and column."""
    t = np.arange(10) * 1e-3
    acc = np.zeros((2, 10))
    acc[1, 7] = np.nan
    with pytest.raises(PulseError, match=r"^x\.csv: channel 'tunnel' has a non-finite acceleration \(nan\) at "
                       r"sample 7 \(t = 0\.007 s\); expected finite numbers$"):  # fmt: skip
        Pulse(t, acc, ("front", "tunnel"), source="x.csv")
    t[3] = np.inf
    with pytest.raises(PulseError, match=r"^non-finite sample time \(inf\) at sample 3; expected finite times \[s\]$"):
        Pulse(t, np.zeros((2, 10)), ("front", "tunnel"))
    with pytest.raises(PulseError, match=r"channel 1 has a non-finite acceleration \(-inf\) at sample 0"):
        Pulse(np.arange(10) * 1e-3, np.r_[np.zeros(10), -np.inf, np.zeros(9)].reshape(2, 10), ("a",))


def test_a_time_column_in_ms_gets_a_hint_and_numbers_print_plainly(tmp_path):
    from marlcrash.pulse.io import processed_pulse

    t = np.arange(0.0, 200.0, 0.1)  # 200 ms of 10 kHz samples, written in ms: read as s it is 10 Hz
    acc = np.where((t > 10) & (t < 90), -20 * np.sin(np.pi * (t - 10) / 80), 0.0)
    ms = tmp_path / "ms.csv"
    ms.write_text("time,acc\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(t, acc, strict=True)))
    for cfc in (60, None):  # unfiltered too: its delta-v would be 1000x too large, silently
        with pytest.raises(PulseError, match=r"ms\.csv: sampling rate 10 Hz .*time column in ms \(--time-unit ms"):
            processed_pulse(ms, cfc=cfc)
    work = processed_pulse(ms, time_unit="ms")[1]
    assert work.sample_rate_hz == pytest.approx(1e4)
    # the other way round: a record in seconds read as ms lasts 0.2 ms
    s = tmp_path / "s.csv"
    s.write_text("time,acc\n" + "".join(f"{a / 1e3:.7f},{b:.6f}\n" for a, b in zip(t, acc, strict=True)))
    for cfc in (60, None):
        with pytest.raises(PulseError, match=r"s\.csv: record of 0\.1999 ms at 1e\+07 Hz.*in seconds \(--time-unit s"):
            processed_pulse(s, cfc=cfc, time_unit="ms")
    s2 = tmp_path / "s2.csv"  # 2 s at 2 kHz in seconds, read as ms: 2 ms long, but at 2 MHz
    s2.write_text("time,acc\n" + "".join(f"{k / 2e3:.4f},{-1.0 if 200 < k < 360 else 0.0}\n" for k in range(4001)))
    with pytest.raises(PulseError, match=r"s2\.csv: record of 2 ms at 2e\+06 Hz"):
        processed_pulse(s2, time_unit="ms")
    assert processed_pulse(s)[1].sample_rate_hz == pytest.approx(1e4)
    back = tmp_path / "back.csv"
    back.write_text("time,acc\n" + "".join(f"{x},1\n" for x in (0, 0.0004, 0.0001, 0.0005, 0.0006, 0.0007, 0.0008, 9)))
    with pytest.raises(PulseError, match=r"got 0\.0001 after 0\.0004") as info:
        processed_pulse(back)
    assert "np.float64" not in str(info.value)


def test_csv_only_options_on_an_iso_mme_test_are_reported_not_silently_dropped():
    from marlcrash.pulse.io import processed_pulse

    mme = Path(__file__).parent / "data" / "HS40"
    with pytest.warns(UserWarning, match="HS40: ISO-MME channels carry their own time base and unit"):
        _, work, _ = processed_pulse(mme, unit="m/s2")
    # named as typed, on the command line and in Python, those given alone (it said 'time_col/unit/time_unit')
    given = r"--time-col zeit \(time_col='zeit'\), --time-unit ms \(time_unit='ms'\) apply to CSV files only and are"
    with pytest.warns(UserWarning, match=r"channels carry their own time base and unit; " + given + " ignored$"):
        processed_pulse(mme, time_col="zeit", time_unit="ms")
    plain = processed_pulse(mme)[1]
    np.testing.assert_array_equal(work.acc, plain.acc)  # ignored, as the warning says


@pytest.mark.parametrize("pre_ms", [0, 2, 20])
def test_a_record_that_starts_at_the_impact_filters_like_one_with_pre_trigger_samples(tmp_path, pre_ms):
    """A short hard pulse (3 ms, 20 g) at the first sample: the CFC 60 figures equal those of the same pulse
    recorded with 20 ms of quiet pre-trigger data; the filter's end reflection used to take 35 % of delta-v."""
    from marlcrash.pulse.io import pulse_summary

    def write(pre):
        t = np.arange(-pre, 50.0 + 1e-9, 0.1) / 1e3
        a = np.where((t >= 0) & (t < 0.003), -20.0 * np.sin(np.pi * t / 0.003), 0.0)
        path = tmp_path / f"pre{pre}.csv"
        path.write_text("time,acc\n" + "".join(f"{x:.6f},{y:.9f}\n" for x, y in zip(t, a, strict=True)))
        return pulse_summary(path, cfc=60)

    ref = write(20)
    if pre_ms < 2.5:  # too little pre-trigger data to measure a zero level: taken as 0, and said so
        with pytest.warns(
            UserWarning,
            match=rf"pre{pre_ms}\.csv: channel 'acc' has {pre_ms}\.0 ms of samples before "
            r"its onset at t = 0\.00 ms, too few to measure its zero level",
        ):
            got = write(pre_ms)
    else:
        got = write(pre_ms)
    for key in ("peak_g", "t_peak_ms", "delta_v_ms", "t0_ms"):
        assert got[key] == pytest.approx(ref[key], rel=1e-6, abs=1e-6), key
    exact = 2 * 20 * G0 * 0.003 / np.pi  # unfiltered delta-v of the half-sine; the filter keeps the integral
    assert got["delta_v_ms"] == pytest.approx(exact, rel=0.03)


@pytest.mark.parametrize("rate_hz", [2e3, 1e4, 2e4])
@pytest.mark.parametrize("peak_g", [30.0, 300.0, 3000.0])
def test_time_zero_is_the_onset_not_where_the_zero_phase_filter_spreads_it(rate_hz, peak_g):
    """A 3 ms half-sine starting at t = 0 (without pre-trigger data, and with 5 or 20 ms of it; clean, and with 0.3 or
    3 g rms noise at test-record rates): time zero lies at its onset, within a sample or 0.25 ms; the CFC 60 record
    itself crosses 0.5 g 5-13 ms earlier. (The 0.5 g crossing of the CFC 1000 record after it, time zero before,
    lay up to 1.1 ms early with 0.3 g of noise, and with 3 g on noise up to 20 ms before the pulse.)"""
    from marlcrash.pulse.signal import filtered_from_time_zero

    rng = np.random.default_rng(int(peak_g))
    for start in (0.0, -0.005, -0.02):
        t = np.arange(round(start * rate_hz), round(0.2 * rate_hz)) / rate_hz
        a = np.where((t >= 0) & (t <= 0.003), -peak_g * G0 * np.sin(np.pi * t / 0.003), 0.0)
        for noise in (0.0, 0.3 * G0, 3 * G0) if rate_hz > 5e3 else (0.0,):  # slower records (simulated) are not
            p = Pulse(time=t, acc=(a + rng.normal(0.0, noise, t.size))[None], channels=["a"])  # filtered
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                work, t0 = filtered_from_time_zero(p, 60)
            assert abs(t0) <= max(1.0 / rate_hz, 0.25e-3), (start, noise, t0)
            assert bool(caught) == (start == 0.0)  # no pre-trigger data to measure the zero level on: said so
            spread = find_time_zero(work)  # the filtered record's own crossing, well ahead of the pulse
            assert spread < -2e-3 if peak_g >= 300 and noise == 0 else spread < t0 + 1e-3


def test_find_onset_measures_each_channel_before_time_zero():
    """Two channels of one record at 10 kHz: a ramp of 1 g/ms from 30 ms on a 0.8 g offset with 1 g rms noise, and a
    later one (a tunnel) from 33 ms with 0.2 g rms. Each zero level and noise is measured on the channel's own
    samples before the record's time zero (the earliest onset, the contact), the detection level is 5x that noise as
    CFC 60 passes it (0.5 g where higher), each onset lies at its ramp's start, and time zero is the earliest."""
    from marlcrash.pulse.signal import NOISE_LEVELS, find_onset

    t = np.arange(2000) / 1e4  # no negative times: the clock is not the contact's
    rng = np.random.default_rng(3)
    front = -np.clip(t - 0.030, 0.0, 0.020) * 1000.0 * G0 + 0.8 * G0 + rng.normal(0.0, G0, t.size)
    tunnel = -np.clip(t - 0.033, 0.0, 0.020) * 500.0 * G0 + rng.normal(0.0, 0.2 * G0, t.size)
    onset = find_onset(Pulse(t, np.stack([front, tunnel]), ("front", "tunnel"), source="two.csv"), 60)
    np.testing.assert_allclose(onset.onsets, [0.030, 0.033], atol=0.6e-3)  # 0.6 ms per g of noise at 1 g/ms
    assert onset.time == onset.onsets[0] and onset.measured.all()
    np.testing.assert_allclose(onset.pre_trigger, [onset.time, onset.time])
    n = np.round((onset.time - 0.0005) * 1e4)  # samples measured, up to 0.5 ms before time zero
    assert np.all(np.abs(onset.zero_level / G0 - [0.8, 0.0]) <= 4 * np.array([1.0, 0.2]) / np.sqrt(n))  # 4 sigma
    np.testing.assert_allclose(onset.noise / G0, [1.0, 0.2], rtol=0.15)
    gain = 0.144  # rms of unit white noise at 10 kHz after CFC 60
    np.testing.assert_allclose(onset.level / G0, [NOISE_LEVELS * gain * onset.noise[0] / G0, 0.5], rtol=0.02)
    with pytest.raises(PulseError, match="threshold must be > 0 g"):
        find_onset(Pulse(t, front[None], ("front",)), 60, threshold_g=0.0)


_LAB_CONTACT = 0.020
"""[s] The contact's time in :func:`_lab_front_and_tunnel`'s record."""


def _lab_front_and_tunnel() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lab record's time [s] and two channels [g] at 10 kHz, the contact at :data:`_LAB_CONTACT`: the front
    decelerates at up to 30 g over 80 ms from the contact; the tunnel at 1.5 g from the contact and its main pulse
    (20 g, 60 ms) 6 ms later."""
    rate = 1e4
    t = np.arange(round(0.2 * rate)) / rate
    s = t - _LAB_CONTACT
    front = np.where((s >= 0) & (s <= 0.08), -30.0 * np.sin(np.pi * np.clip(s, 0, 0.08) / 0.08), 0.0)
    main = np.where((s >= 0.006) & (s <= 0.066), -20.0 * np.sin(np.pi * np.clip(s - 0.006, 0, 0.06) / 0.06), 0.0)
    return t, front, main - 1.5 * np.interp(s, [0.0, 0.001, 0.1, 0.1001], [0.0, 1.0, 1.0, 0.0], left=0.0, right=0.0)


def test_a_channel_that_decelerates_before_its_onset_takes_its_zero_level_before_time_zero():
    """A lab export at 10 kHz (clock not the contact's, ``time_zero: threshold``) with a 0.3 g offset on both
    channels: the front stops in a 30 g, 80 ms half-sine from 20 ms on; the tunnel decelerates at 1.5 g from the
    contact on (reached in 1 ms), and its main pulse, a 20 g, 60 ms half-sine, starts 6 ms later (a simulated
    tunnel's first milliseconds: 2.6 g on the default car). The tunnel is not at rest between the contact and the
    onset found for it (its main pulse), so its zero level is the mean of its samples before the record's time zero:
    the offset alone. It was measured up to that onset: 0.12 g taken for the 0.3 g offset, and the 0.18 g left
    integrated into a drift of 0.3 m/s over 150 ms."""
    from marlcrash.pulse.signal import find_onset, shift_time, without_zero_offset

    t, front, tunnel = _lab_front_and_tunnel()
    acc = (np.stack([front, tunnel]) + 0.3) * G0
    pulse = Pulse(t, acc, ("front", "tunnel"), source="lab.csv")
    onset = find_onset(pulse, 60)
    assert abs(onset.time - _LAB_CONTACT) < 0.2e-3 and onset.measured.all()
    np.testing.assert_allclose(onset.zero_level / G0, [0.3, 0.3], atol=1e-9)  # before time zero, not the 1.5 g
    np.testing.assert_allclose(onset.pre_trigger, onset.time)  # what was measured: the samples before time zero
    clean = Pulse(t, acc - 0.3 * G0, pulse.channels)
    _, got = prepare_velocity(without_zero_offset(pulse, "threshold"), duration=0.15, v0=DV)
    _, ref = prepare_velocity(shift_time(clean, onset.time), duration=0.15, time_zero="file", v0=DV)
    np.testing.assert_allclose(got, ref, atol=1e-6)  # the record less its offset, from the same time zero
    dv = 2 * 20 * G0 * 0.06 / math.pi + 1.5 * G0 * (0.1 - 0.0005 + 0.00005)  # the main pulse and the 1.5 g
    assert DV - got[1, -1] == pytest.approx(dv, rel=2e-3)


@pytest.mark.parametrize("cfc", [60, 180, 600, 1000])
@pytest.mark.parametrize("rate_hz", [2e3, 1e4, 2e4])
def test_the_onset_search_passes_no_more_noise_at_the_records_end_than_inside(cfc, rate_hz):
    """White noise of unit rms leaves a linear filter with a gain per output sample: the norm of that sample's row
    of the filter matrix. The J211 filter (odd end reflection) lifts it over the record's last samples (at the last,
    2.4-10x the interior's); the onset search's filter, with a resting lead-out, stays within 2 % of the interior's
    everywhere after the record's middle (the level :func:`find_onset` sets is 5x the interior's)."""
    from marlcrash.pulse.cfc import DESIGN_FACTOR
    from marlcrash.pulse.signal import _detection_filter, _quiet_filter

    dt = 1.0 / rate_hz
    if 2.0 * DESIGN_FACTOR * cfc >= rate_hz:  # the rate cannot carry this class (as find_onset's bands)
        pytest.skip("class above the rate's band")
    n = round(0.2 * rate_hz)
    eye = np.eye(n)  # row j: the impulse at j; filtered, column i holds row i of the filter matrix
    plain = np.sqrt(np.sum(_quiet_filter(eye, dt, cfc) ** 2, axis=0))
    searched = np.sqrt(np.sum(_detection_filter(eye, dt, cfc) ** 2, axis=0))
    interior = plain[n // 2]
    assert searched[n // 2] == pytest.approx(interior, rel=1e-6)
    assert searched[n // 2 :].max() <= 1.02 * interior
    assert plain[-1] >= 1.5 * interior  # what the lead-out takes away


def test_a_short_pulse_under_noise_is_found_not_the_noise_the_end_reflection_lifts():
    """A 3 ms, 10 g half-sine at 20 ms under 3 g rms noise (10 kHz, 200 ms): CFC 60 leaves it at 4.8 g, and its last
    sample's noise at up to 4.7 g (the odd reflection passes it 7x less attenuated). Time zero lies within 2 ms of
    the onset for every seed; the search of the J211-filtered record put it at 180-200 ms for seeds 2, 10 and 31."""
    from marlcrash.pulse.signal import find_onset

    t = np.arange(2000) / 1e4
    pulse = np.where((t >= 0.02) & (t < 0.023), -10 * G0 * np.sin(np.pi * (t - 0.02) / 0.003), 0.0)
    for seed in range(40):
        noisy = pulse + 3 * G0 * np.random.default_rng(seed).standard_normal(t.size)
        onset = find_onset(Pulse(t, noisy[None], ("x",), source="short.csv"), 60)
        assert abs(onset.time - 0.02) <= 2e-3, (seed, onset.time)


def test_a_record_without_a_pulse_above_its_noise_is_refused_naming_the_file_and_channels(tmp_path):
    """Noise alone (1 g rms, a 0.8 g offset) has no onset: refused, naming the file, each channel, its peak and its
    level, not a time zero on a noise sample."""
    t = np.arange(2000) / 1e4
    a = 0.8 + np.random.default_rng(0).normal(0.0, 1.0, t.size)
    path = tmp_path / "quiet.csv"
    path.write_text("time,x_acc\n" + "".join(f"{x:.4f},{y:.6f}\n" for x, y in zip(t, a, strict=True)))
    refused = (
        r"quiet\.csv: no channel leaves its pre-trigger noise \(0\.5 g, or 5 x its noise where higher\): "
        r"'x_acc' peaks at 0\.\d+ g after CFC 60, its onset level is 0\.7\d+ g"
    )
    with pytest.raises(PulseError, match=refused):
        pulse_summary(path)


def test_a_refused_records_onset_level_is_the_one_its_hum_set():
    """1 g rms white noise with a 0.4 g, 50 Hz hum and no pulse: CFC 60 passes the hum whole, so the detection level
    is 5x the filtered pre-trigger samples' rms, and the refusal states that level, above the record's peak. It
    stated the white-noise level instead (0.74 g), below the peak it named (0.78 g)."""
    from marlcrash.pulse.signal import find_onset

    t = np.arange(2000) / 1e4
    a = (np.random.default_rng(0).normal(0.0, 1.0, t.size) + 0.4 * np.sin(2 * np.pi * 50 * t)) * G0
    with pytest.raises(PulseError, match=r"hum\.csv: no channel leaves its pre-trigger noise") as refused:
        find_onset(Pulse(t, a[None], ("x_acc",), source="hum.csv"), 60)
    stated = re.search(r"peaks at ([\d.]+) g.*level is ([\d.]+) g", str(refused.value))
    peak, level = float(stated.group(1)), float(stated.group(2))
    assert level > peak


def test_sampled_acceleration_is_the_derivative_with_a_resting_lead_in():
    """Central differences: second order against the analytic derivative, zero-acceleration lead-in at t = 0."""
    from marlcrash.pulse.signal import sampled_acceleration

    dt = 5e-4
    t = torch.arange(301, dtype=torch.float64) * dt
    w = 2 * np.pi * 40.0
    v = 11.0 + 2.0 * torch.sin(w * t)  # [T]
    a = sampled_acceleration(v[None, None], dt)[0, 0]
    exact = 2.0 * w * torch.cos(w * t)
    inner = slice(1, -1)
    err = (a[inner] - exact[inner]).abs().max()
    assert err < 2.0 * w**3 * dt**2 / 6 * 1.01  # the central difference's truncation bound
    assert float(a[0]) == pytest.approx(float(v[1] - v[0]) / (2 * dt), rel=1e-12)  # v[-1] = v[0]
    with pytest.raises(PulseError, match="at least 2"):
        sampled_acceleration(v[:1], dt)


def test_csv_dialects_of_spreadsheets_and_lab_tools(tmp_path, analytic):
    """Semicolons with decimal commas, a quoted header whose names hold the other delimiter, Windows-1252 text."""
    ref = read_csv(_write_plain(tmp_path / "plain.csv", analytic))
    rows = [(f"{t:.9f}".replace(".", ","), f"{a / 9.80665:.9f}".replace(".", ",")) for t, a in zip(
        analytic.time, analytic.acc[0], strict=True)]  # fmt: skip
    euro = tmp_path / "euro.csv"
    euro.write_bytes(('"Zeit (s)";"Beschl., g in m/s²"\n' + "".join(f"{a};{b}\n" for a, b in rows)).encode("cp1252"))
    p = read_csv(euro, unit="g")
    assert p.channels == ("Beschl., g in m/s²",)  # not a replacement character, not split at the comma
    np.testing.assert_allclose(p.acc, ref.acc, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(p.time, ref.time, atol=1e-9)
    tab = tmp_path / "tab.csv"
    tab.write_text("time\tacc\n" + "".join(f"{a.replace(',', '.')}\t{b.replace(',', '.')}\n" for a, b in rows))
    np.testing.assert_allclose(read_csv(tab).acc, ref.acc, rtol=1e-8, atol=1e-6)
    tab_text = "time\tacc m/s²\n" + "".join(f"{a.replace(',', '.')}\t{b.replace(',', '.')}\n" for a, b in rows)
    for codec in ("utf-16", "utf-16-be"):  # Excel's "Unicode Text": UTF-16 with a byte-order mark, either order
        wide = tmp_path / f"{codec}.txt"
        wide.write_bytes(tab_text.encode(codec) if codec == "utf-16" else b"\xfe\xff" + tab_text.encode(codec))
        p = read_csv(wide)
        assert p.channels == ("acc m/s²",)
        np.testing.assert_allclose(p.acc, ref.acc, rtol=1e-8, atol=1e-6)
    wide32 = tmp_path / "utf32.txt"
    wide32.write_bytes(tab_text.encode("utf-32"))  # starts with FF FE 00 00, which begins like UTF-16's mark
    assert read_csv(wide32).channels == ("acc m/s²",)
    broken = tmp_path / "broken.txt"
    broken.write_bytes(b"\xff\xfe" + b"t\x00\x00\xd8")  # a lone surrogate
    with pytest.raises(PulseError, match=r"broken\.txt: starts with a UTF-16 byte-order mark but is not UTF-16"):
        read_csv(broken)
    thousands = tmp_path / "thousands.csv"  # tab export of an English spreadsheet: '-1,005' is not -1.005
    thousands.write_text("time\tacc\n" + "".join(f"{i * 1e-4:.4f}\t-1,{i:03d}\n" for i in range(20)))
    with pytest.raises(PulseError, match=r"thousands\.csv line 2, column 'acc': expected a number, got '-1,000'"):
        read_csv(thousands, unit="m/s2")
    stray = tmp_path / "stray.csv"  # one Latin-1 comment line in a UTF-8 file: the header stays UTF-8
    stray.write_bytes("# Prüfung\n".encode("latin-1") + "time,acc [m/s²]\n".encode() + _plain_rows(analytic).encode())
    assert read_csv(stray, acc_col="acc [m/s²]", unit="m/s2").channels == ("acc [m/s²]",)
    with pytest.raises(PulseError, match=r"stray\.csv line 2: column 'acc \[m/s²\]' is in m/s² by its header, but"):
        read_csv(stray, acc_col="acc [m/s²]")  # read in g, the default: 9.8x too large
    names = tmp_path / "names.csv"  # commas in the names and the numbers of a ';' file split evenly at ',' too
    names.write_text("Zeit, s;Beschl., g\n" + "".join(f"0,{i:04d};-1,50\n" for i in range(20)))
    assert read_csv(names).channels == ("Beschl., g",)
    tie = tmp_path / "tie.csv"  # one comma per row in a ';' file with integer times: ';' wins the tie
    tie.write_text('"time (ms)";"acc, g"\n' + "".join(f"{i};-0,25\n" for i in range(20)))
    assert read_csv(tie, time_unit="ms").acc[0, 0] == pytest.approx(-0.25 * 9.80665)
    mixed = tmp_path / "mixed.csv"  # the header says ',', the rows ';': the first disagreeing row is named
    mixed.write_text("time,acc\n0;1\n0.001;2\n" + "".join(f"{i * 1e-3};0\n" for i in range(2, 10)))
    with pytest.raises(PulseError, match=r"mixed\.csv line 2: expected 2 fields as in the header, got 1"):
        read_csv(mixed)


def test_an_excel_sep_line_names_the_delimiter_and_one_named_column_is_no_header(tmp_path, analytic):
    """Excel reads (and some exports write) a first line ``sep=;`` naming the delimiter. It was taken for the
    header: ``marlcrash pulse`` stopped with a bare ``StopIteration`` traceback, ``read_csv`` said the header line's
    names held 'acc' under no name. The line now sets the delimiter (``;``: decimal commas, as in any ``;`` file)
    and the header is the line after it; a header of one named column (``time;``) is refused, naming the line."""
    from marlcrash.pulse.io import pulse_summary

    ref = read_csv(_write_plain(tmp_path / "plain.csv", analytic))
    rows = "".join(f"{t:.9f};{a / G0:.9f}\n".replace(".", ",") for t, a in zip(analytic.time, analytic.acc[0],
                                                                              strict=True))  # fmt: skip
    path = tmp_path / "excel.csv"
    path.write_text("sep=;\n" + "time;acc\n" + rows)
    p = read_csv(path)
    assert p.channels == ("acc",)
    np.testing.assert_allclose(p.acc, ref.acc, rtol=1e-8, atol=1e-6)
    assert pulse_summary(path)["delta_v_ms"] == pytest.approx(DV, rel=0.01)
    path.write_text("sep=\t\n" + "time\tacc\n" + rows.replace(",", ".").replace(";", "\t"))
    np.testing.assert_allclose(read_csv(path).acc, ref.acc, rtol=1e-8, atol=1e-6)
    path.write_text("time;\n" + "".join(f"{i},{i:04d};\n" for i in range(20)))  # no acceleration column
    for read in (read_csv, pulse_summary):
        with pytest.raises(PulseError, match=r"excel\.csv line 1: expected a header with at least two columns"):
            read(path)


def test_a_time_column_named_with_its_unit_is_found_wherever_it_stands(tmp_path, analytic):
    """The time column is found by name (``time``, ``t``, ``zeit`` ...), but only ``time ...`` was found with a unit
    after it: a German export's ``a_x [g];Zeit [s]`` read ``a_x [g]`` as the time ("column 'a_x [g]': duplicated
    time"), and ``acc,t (ms)`` likewise. The name is now matched without the unit at its end."""
    ref = read_csv(_write_plain(tmp_path / "plain.csv", analytic))
    pairs = list(zip(analytic.time, analytic.acc[0] / G0, strict=True))
    path = tmp_path / "lab.csv"
    path.write_text("a_x [g];Zeit [s]\n" + "".join(f"{a:.9f};{t:.9f}\n".replace(".", ",") for t, a in pairs))
    p = read_csv(path)
    assert p.channels == ("a_x [g]",)
    np.testing.assert_allclose(p.acc, ref.acc, rtol=1e-8, atol=1e-6)
    path.write_text("acc,t (ms)\n" + "".join(f"{a:.9f},{t * 1e3:.9f}\n" for t, a in pairs))
    p = read_csv(path, time_unit="ms")
    assert p.channels == ("acc",)
    np.testing.assert_allclose(p.time, ref.time, atol=1e-9)


def test_a_file_time_zero_long_before_the_pulse_is_named_in_a_warning(tmp_path):
    """``time_zero: file`` (a file reference's default) takes the file's t = 0 as the contact. A lab record on a
    clock from 0, its 30 ms of pre-trigger data at positive times, was compared as if the car hit the barrier 30 ms
    before its pulse starts, and its 0.4 g offset stayed, without a word (only a clock starting after 0 was
    refused). Now the pulse's onset that late after t = 0 is named in a warning, with the option that reads such a
    record; a record whose t = 0 is the contact gets none, nor does a channel starting some ms after it. Only a file
    reference warns (its channels are the vehicle's): ``marlcrash pulse --time-zero file`` may read a dummy's head,
    at rest until its restraint engages."""
    from marlcrash.pulse.io import pulse_summary

    t = np.arange(0.0, 0.25, 1e-4)
    acc_g = half_sine(t - 0.030, 0.080) / G0 + 0.4
    path = tmp_path / "clock0.csv"
    path.write_text("time,acc\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(t, acc_g, strict=True)))
    late = r"clock0\.csv: the pulse starts at t = (29\.[5-9]|30\.[0-4])\d ms .*time_zero: threshold"
    with pytest.warns(UserWarning, match=late):
        prepare_velocity(read_pulse(path), time_zero="file", duration=0.15)  # as a file reference reads it
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pulse_summary(path, time_zero="file")
        assert pulse_summary(path)["delta_v_ms"] == pytest.approx(DV, rel=0.01)  # read so, it is the pulse
        for start in (0.0, 0.006):  # the pulse at the file's t = 0, or a channel some ms after the contact
            path.write_text("time,acc\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(
                t - 0.03, half_sine(t - 0.03 - start, 0.080) / G0, strict=True)))  # fmt: skip
            prepare_velocity(read_pulse(path), time_zero="file", duration=0.15)


def test_a_tab_separated_export_with_decimal_commas_is_read_where_no_comma_can_group_thousands(tmp_path, analytic):
    """A German spreadsheet saved as tab-separated text writes decimal commas ('-0,025'); it was refused ("column
    'Zeit [s]': expected a number, got '-0,02000'") with no option to read it, as a tab export of an English one
    may group thousands ('-1,005'). A comma that cannot group thousands (after a leading 0, or not before exactly
    three digits) is a decimal comma, and the file is read so; one of only ambiguous cells is still refused."""
    ref = read_csv(_write_plain(tmp_path / "plain.csv", analytic))
    rows = "".join(f"{t:.9f}\t{a / G0:.9f}\n".replace(".", ",") for t, a in zip(analytic.time, analytic.acc[0],
                                                                               strict=True))  # fmt: skip
    path = tmp_path / "excel.txt"
    path.write_text("Zeit [s]\tBeschleunigung [g]\n" + rows)
    p = read_csv(path)
    np.testing.assert_allclose(p.acc, ref.acc, rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(p.time, ref.time, atol=1e-9)
    path.write_text("time\tacc\n" + "".join(f"{i * 1e-4:.4f}\t{'-1,005' if i == 3 else '-1.5'}\n" for i in range(20)))
    with pytest.raises(PulseError, match=r"excel\.txt line 5, column 'acc': expected a number, got '-1,005'"):
        read_csv(path)  # points elsewhere: the comma groups thousands


def test_a_csv_line_ends_at_line_feeds_and_carriage_returns_only(tmp_path, analytic):
    """The CSV reader split its lines with ``str.splitlines``, which also breaks at form feeds, U+0085, U+2028 and
    other separators: a comment holding one ('# rig 2<U+2028>second take') went on as a line without '#', which was
    taken for the header ('expected a header with at least two columns'); a form feed in a row split it into two
    ragged rows. Lines end at line feeds, carriage returns and CR LF, as an ISO-MME file's do."""
    ref = read_csv(_write_plain(tmp_path / "plain.csv", analytic))
    rows = _plain_rows(analytic).splitlines(keepends=True)
    for sep in ("\x0c", "\x85", "\u2028", "\u2029", "\x1c", "\x0b"):
        text = (
            f"# rig 2{sep}second take\r\ntime,acc\n"
            + "".join(rows[:5])
            + rows[5].replace(",", f",{sep}")
            + "".join(rows[6:])
        )
        for codec in ("utf-8", "utf-16"):
            f = tmp_path / f"sep-{ord(sep)}-{codec}.csv"
            f.write_bytes(text.encode(codec))
            p = read_csv(f)
            assert p.channels == ("acc",)
            np.testing.assert_array_equal(p.acc, ref.acc)
            np.testing.assert_array_equal(p.time, ref.time)


def _plain_rows(pulse: Pulse) -> str:
    return "".join(f"{t:.9f},{a / 9.80665:.9f}\n" for t, a in zip(pulse.time, pulse.acc[0], strict=True))


def _write_plain(path: Path, pulse: Pulse) -> Path:
    path.write_text("time,acc\n" + _plain_rows(pulse))
    return path


def test_a_gap_in_the_time_column_is_named_in_a_warning_and_bridged(tmp_path):
    t = np.r_[np.arange(0, 0.05, 1e-4), np.arange(0.08, 0.15, 1e-4)]  # 30 ms missing
    path = tmp_path / "gap.csv"
    path.write_text("time,acc\n" + "".join(f"{x:.6f},-1\n" for x in t))
    with pytest.warns(UserWarning, match=r"gap\.csv line 502, column 'time': 1 gap\(s\) in the record, the longest "
                                         r"from t = 0\.0499 to 0\.08 \(301\.0 times"):  # fmt: skip
        assert read_csv(path).n_samples == t.size
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv(path, max_gap=None)  # no check
        jitter = tmp_path / "jitter.csv"  # steps up to 5x the median but under 2.5 ms: not a gap
        tj = np.cumsum(np.r_[0.0, np.tile([1e-4, 1e-4, 1e-4, 5e-4], 100)])
        jitter.write_text("time,acc\n" + "".join(f"{x:.6f},-1\n" for x in tj))
        read_csv(jitter)
    with pytest.raises(PulseError, match="max_gap"):
        read_csv(path, max_gap=0.5)


def test_mme_reads_acceleration_channels_and_the_summary_takes_the_first(tmp_path, analytic):
    """A real test holds forces and other time bases too: by default only accelerations are read, and the pulse
    summary reads the first acceleration channel alone."""
    from marlcrash.pulse import mme_channels
    from marlcrash.pulse.io import pulse_summary
    from marlcrash.pulse.signal import resample

    slow = resample(analytic, 5000.0)  # another time base
    write_mme(Pulse(analytic.time, np.stack([analytic.acc[0] / 9.80665 * 1e3, analytic.acc[0]]),
                    ("11SEBE0000B3FO0D", "10VEHC000000ACXP")), tmp_path / "T", "T")  # fmt: skip
    _edit(tmp_path / "T" / "Channel" / "T.001", "Unit                        :g", "Unit                        :N")
    write_mme(slow, tmp_path / "S", "S")
    for f in (tmp_path / "S" / "Channel").glob("S.001"):
        f.rename(tmp_path / "T" / "Channel" / "T.003")
    _edit(tmp_path / "T" / "Channel" / "T.chn", "channels          :2", "channels          :3")  # and listed
    _edit(tmp_path / "T" / "T.mme", "channels          :2", "channels          :3")  # and counted
    with (tmp_path / "T" / "Channel" / "T.chn").open("a", encoding="latin-1") as f:
        f.write("Name of channel 003         :NOVALUE\n")
    info = mme_channels(tmp_path / "T")
    assert [(c["code"], c["unit"], c["acceleration"]) for c in info] == [
        ("11SEBE0000B3FO0D", "N", False), ("10VEHC000000ACXP", "g", True), ("", "g", True)]  # fmt: skip
    # the two accelerations differ in time base (5 and 10 kHz): the 5 kHz one is interpolated onto the 10 kHz
    # instants (refused before, "read them separately", which a file reference of both channels cannot)
    resampled = (
        r"T\.mme: the channels read have other time bases \(T\.002 \(10000 Hz from -0\.02 s\), T\.003 "
        r"\(5000 Hz from -0\.02 s\)\); each is interpolated linearly onto 10000 Hz"
    )
    with pytest.warns(UserWarning, match=resampled):
        both = read_mme(tmp_path / "T")
    span = (analytic.time >= slow.time[0] - 1e-12) & (analytic.time <= slow.time[-1] + 1e-12)
    np.testing.assert_allclose(both.time, analytic.time[span], rtol=0, atol=1e-12)
    np.testing.assert_allclose(both.acc[0], analytic.acc[0][span], rtol=0, atol=1e-9)
    # linear interpolation of the 5 kHz samples: within h^2 / 8 max|a''| of the half-sine (A (pi / T)^2)
    bound = (2e-4) ** 2 / 8 * np.abs(analytic.acc[0]).max() * (math.pi / 0.080) ** 2
    assert 0 < np.abs(both.acc[1] - analytic.acc[0][span]).max() <= bound
    _edit(tmp_path / "T" / "Channel" / "T.003", "Time of first sample        :-0.02", "Time of first sample        :5")
    # of two channels either may be the one off: both are named, with their spans, on the test's file
    apart = r"T\.mme: the channels read \(T\.002 -0\.02 to 0\.1.* s, T\.003 5 to 5\.2.* s\) share 0 sampling instants"
    with pytest.raises(PulseError, match=apart), pytest.warns(UserWarning, match="skipped T.001"):
        read_mme(tmp_path / "T")
    assert read_mme(tmp_path / "T", channels="10VEHC000000ACXP").channels == ("10VEHC000000ACXP",)
    s = pulse_summary(tmp_path / "T")
    assert s["channel"] == "10VEHC000000ACXP"
    assert s["delta_v_ms"] == pytest.approx(pulse_summary(_write_plain(tmp_path / "p.csv", analytic))["delta_v_ms"])


def test_filtering_a_record_shorter_than_the_filter_period_is_refused():
    from marlcrash.pulse import filter_pulse

    t = np.arange(50) * 1e-4  # 5 ms
    short = Pulse(t, -20 * 9.80665 * np.sin(np.pi * t / 5e-3), ("a",))
    with pytest.raises(PulseError, match=r"record of 5 ms is too short for CFC 60; expected at least 10 ms"):
        filter_pulse(short, 60)
    assert filter_pulse(short, 600).cfc == 600  # 1 ms is enough for CFC 600


def _trapezoid_corners(scale: float = 1.0) -> str:
    # 20 g plateau from 10 to 60 ms, ramps of 10 and 20 ms, quiet to 200 ms: delta-v 20 g * 65 ms
    corners = [(0.0, 0.0), (0.010, -20.0), (0.060, -20.0), (0.080, 0.0), (0.200, 0.0)]
    return "time,acc\n" + "".join(f"{t * scale:g},{a:g}\n" for t, a in corners)


def test_a_table_of_breakpoints_is_sampled_between_its_corners(tmp_path):
    from marlcrash.pulse.io import BREAKPOINT_RATE_HZ, processed_pulse

    path = tmp_path / "corners.csv"
    path.write_text(_trapezoid_corners())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # corners 120 ms apart are no recorder dropout
        p = read_csv(path, breakpoints=True)
    assert p.sample_rate_hz == pytest.approx(BREAKPOINT_RATE_HZ) and p.n_samples == 2001 and p.is_uniform
    t = p.time
    expected = -20 * G0 * np.clip(np.minimum(t / 0.010, (0.080 - t) / 0.020), 0.0, 1.0)  # independent of np.interp
    np.testing.assert_allclose(p.acc[0], expected, rtol=0, atol=1e-9)
    dv = 20 * G0 * (0.050 + 0.010 / 2 + 0.020 / 2)
    work = processed_pulse(path, breakpoints=True, cfc=None, time_zero="file")[1]  # corners from the contact
    assert abs(work.velocity()[0, -1]) == pytest.approx(dv, rel=1e-6)
    _, filt, _ = processed_pulse(path, breakpoints=True, time_zero="file")  # CFC 60 keeps a 65 ms pulse's area
    assert abs(filt.velocity()[0, -1]) == pytest.approx(dv, rel=2e-3)
    in_ms = tmp_path / "corners_ms.csv"
    in_ms.write_text(_trapezoid_corners(1e3))
    np.testing.assert_allclose(read_csv(in_ms, breakpoints=True, time_unit="ms").acc, p.acc, rtol=0, atol=1e-9)
    with pytest.raises(PulseError, match=r"corners_ms\.csv line 6, column 'time': the breakpoints span 200 s.*"
                                         r"--time-unit ms"):  # fmt: skip
        read_csv(in_ms, breakpoints=True)
    one = tmp_path / "one.csv"
    one.write_text("time,acc\n0,-1\n")
    with pytest.raises(PulseError, match=r"one\.csv: expected at least 2 breakpoints, got 1"):
        read_csv(one, breakpoints=True)
    with pytest.raises(PulseError, match=r"HS40: --breakpoints \(breakpoints=True\) applies to CSV files only: an "
                       "ISO-MME channel is sampled, not a table of breakpoints"):  # fmt: skip
        processed_pulse(Path(__file__).parent / "data" / "HS40", breakpoints=True)
    with pytest.raises(PulseError, match=r"HS40: breakpoints=True applies to CSV files only"):
        read_pulse(Path(__file__).parent / "data" / "HS40", breakpoints=True)
    square = tmp_path / "square.csv"  # vertical edges: two rows of one time; the last corner off the 0.1 ms grid
    square.write_text("time,acc\n0,0\n0.01,0\n0.01,-20\n0.05,-20\n0.05,0\n0.08005,-4\n")
    q = read_csv(square, breakpoints=True)
    assert q.time[-1] == pytest.approx(0.0801) and q.acc[0, -1] == pytest.approx(-4 * G0)  # kept, held after it
    inside = (q.time > 0.0100001) & (q.time < 0.0499999)
    assert np.all(q.acc[0, inside] == -20 * G0)
    k = int(np.argmin(np.abs(q.time - 0.065)))  # on the ramp from 0 at 50 ms (after the edge) to -4 g at 80.05 ms
    assert q.acc[0, k] == pytest.approx(-4 * G0 * (q.time[k] - 0.05) / 0.03005, rel=1e-9)
    third = tmp_path / "third.csv"
    third.write_text("time,acc\n0,0\n0.01,0\n0.01,-20\n0.01,-5\n0.05,0\n")
    with pytest.raises(PulseError, match=r"third\.csv line 5, column 'time': a third row at one time"):
        read_csv(third, breakpoints=True)
    with pytest.raises(PulseError, match=r"the breakpoints span 0\.0002 s.*is the time column in s"):
        read_csv(path, breakpoints=True, time_unit="ms")  # a table in s read as ms
    dense = tmp_path / "dense.csv"  # a 20 kHz record read as breakpoints: decimated, so warned about
    dense.write_text("time,acc\n" + "".join(f"{i * 5e-5:.5f},-1\n" for i in range(400)))
    with pytest.warns(UserWarning, match=r"dense\.csv: rows 5e-05 s apart \(median\) are a sampled record"):
        read_csv(dense, breakpoints=True)


def test_a_table_of_breakpoints_drawn_from_its_first_row_starts_there_with_a_zero_level_of_0(tmp_path):
    # a specification's rectangle, 20 g for 50 ms from the first row: no rest before it, nothing to measure. The
    # median of its first 2 ms was taken as its level at rest: its falling edge became the onset (49.9 ms) and the
    # -20 g plateau its "offset", doubling the velocity change (19.6 m/s) with two warnings pointing elsewhere
    from marlcrash.pulse.io import processed_pulse
    from marlcrash.pulse.signal import find_onset

    path = tmp_path / "rect.csv"
    path.write_text("time,acc\n0,-20\n50,-20\n50,0\n150,0\n")
    dv = 20 * G0 * 0.050
    for cfc, tol in ((None, 1e-6), (60, 2e-3)):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a drawn pulse: nothing to say about rest, offset or pre-trigger data
            raw, work, t0 = processed_pulse(path, breakpoints=True, time_unit="ms", cfc=cfc, time_zero="threshold")
        assert raw.drawn and t0 == 0.0
        assert abs(work.velocity()[0, -1]) == pytest.approx(dv, rel=tol)
    onset = find_onset(raw)
    assert onset.zero_level.tolist() == [0.0] and not onset.measured.any()
    # drawn with a rest first: the onset is the rise's corner, found as for a record
    late = tmp_path / "late.csv"
    late.write_text("time,acc\n0,0\n20,0\n25,-20\n60,-20\n70,0\n150,0\n")
    _, work, t0 = processed_pulse(late, breakpoints=True, time_unit="ms", cfc=None, time_zero="threshold")
    assert t0 == pytest.approx(0.020, abs=2e-4)
    assert abs(work.velocity()[0, -1]) == pytest.approx(20 * G0 * (0.035 + 0.005 / 2 + 0.010 / 2), rel=1e-6)


def test_a_table_of_breakpoints_read_as_samples_is_refused_with_the_option_to_use(tmp_path):
    from marlcrash.pulse.io import processed_pulse

    t = np.array([0.0, 0.005, 0.010, 0.030, 0.050, 0.060, 0.070, 0.080, 0.150])  # 9 corners: 60 Hz mean rate
    path = tmp_path / "table.csv"
    path.write_text("time,acc\n" + "".join(f"{x:g},{-20 * math.sin(math.pi * min(x, 0.08) / 0.08):.6f}\n" for x in t))
    refused = r"table\.csv: sampling rate .* Hz .*--breakpoints \(breakpoints: true\)"
    with pytest.warns(UserWarning, match=r"read it as one: --breakpoints"), pytest.raises(PulseError, match=refused):
        processed_pulse(path)
    assert processed_pulse(path, breakpoints=True, time_zero="file")[1].sample_rate_hz == pytest.approx(1e4)
    slow = Pulse(np.arange(40) * 0.01, -np.ones((1, 40)) * G0, ("10VEHC0000ACXP",))  # 100 Hz: seconds in ms?
    mme = write_mme(slow, tmp_path / "slow")
    with pytest.raises(PulseError, match="'Sampling interval' in seconds") as info:
        processed_pulse(mme)
    assert "--breakpoints" not in str(info.value)  # an ISO-MME channel is never a table of breakpoints


def _onset_csv(path: Path, *, offset_g: float = 0.0, noise_g: float = 0.0, pre_s: float = 0.02, shift_s: float = 0.0):
    """A 10 kHz record of an 80 ms, 30 g half-sine from t = 0 with ``pre_s`` of pre-trigger samples, a transducer
    offset and white noise; its clock shifted by ``shift_s``. The true velocity change is 2 A tau / pi."""
    t = np.arange(-round(pre_s * 1e4), 2500) / 1e4
    a = half_sine(t, 0.08, 30 * G0 * 2 * 0.08 / math.pi) / G0 + offset_g
    a = a + np.random.default_rng(1).normal(0.0, noise_g, t.size) if noise_g else a
    path.write_text("time,acc\n" + "".join(f"{x + shift_s:.6f},{y:.9g}\n" for x, y in zip(t, a, strict=True)))
    return path


def test_unfiltered_summary_integrates_from_before_the_first_sample(tmp_path):
    """``--cfc 0`` (``cfc=None``) leads the record in with zero acceleration as the filtered path does: a record that
    starts at the impact counted only half its first interval, and a rectangle given by its corners (10 g for
    100 ms, 9.80665 m/s) came out 0.05 % short; unfiltered at 10 kHz it is exact to the trapezoid rule."""
    corners = tmp_path / "rect.csv"
    corners.write_text("time,acc\n0,0\n0,-10\n100,-10\n100,0\n200,0\n")
    s = pulse_summary(corners, breakpoints=True, time_unit="ms", time_zero="file", cfc=None)
    assert s["delta_v_ms"] == pytest.approx(10 * G0 * 0.1, rel=1e-12)
    start = _onset_csv(tmp_path / "start.csv", pre_s=0.0)  # starts at the impact, with a 0 g first sample
    t = np.arange(2500) / 1e4
    expected = -np.trapezoid(half_sine(t, 0.08, 30 * G0 * 2 * 0.08 / math.pi), t)
    assert pulse_summary(start, time_zero="file", cfc=None)["delta_v_ms"] == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("time_zero", ["file", "threshold"])
@pytest.mark.parametrize("offset_g", [0.2, 0.6, 1.5])
def test_a_transducer_offset_is_removed_from_the_pre_trigger_samples(tmp_path, time_zero, offset_g):
    """A constant offset integrates into a drift (0.2 g: -3.5 % of the velocity change) and, above the 0.5 g
    threshold, set time zero at the first sample: its pre-trigger mean is subtracted, with either time-zero rule,
    in ``marlcrash pulse`` as in a file reference. With ``threshold`` the record's clock does not matter: the same
    record 37 ms later (no negative times), also with an offset above the threshold and 5 ms of pre-trigger data,
    gives the same figures. (Such an offset was not recognised there: time zero at the first sample, and the
    offset integrated, 0.6 g: -5.9 %, 1.5 g: -14.7 % of the velocity change at 150 ms.)"""
    clean = pulse_summary(_onset_csv(tmp_path / "clean.csv"), time_zero=time_zero)
    assert clean["delta_v_ms"] == pytest.approx(30 * G0 * 2 * 0.08 / math.pi, rel=1e-4)
    biased = pulse_summary(_onset_csv(tmp_path / "bias.csv", offset_g=offset_g), time_zero=time_zero)
    for key in ("delta_v_ms", "delta_v_150ms_ms", "t0_ms", "peak_g"):
        assert biased[key] == pytest.approx(clean[key], rel=1e-9, abs=1e-9), key
    if time_zero == "threshold":
        assert abs(clean["t0_ms"]) < 0.1  # the onset, not the 0.5 g crossing 0.42 ms after it
        for pre_s in (0.005, 0.02):
            ref = pulse_summary(_onset_csv(tmp_path / f"ref{pre_s}.csv", pre_s=pre_s), time_zero=time_zero)
            late = _onset_csv(tmp_path / f"late{pre_s}.csv", offset_g=offset_g, pre_s=pre_s, shift_s=0.037)
            got = pulse_summary(late, time_zero=time_zero)
            for key in ("delta_v_ms", "delta_v_150ms_ms", "peak_g"):
                assert got[key] == pytest.approx(ref[key], rel=1e-9), (pre_s, key)
            assert got["t0_ms"] - 37.0 == pytest.approx(ref["t0_ms"], abs=1e-6)
            assert got["delta_v_150ms_ms"] == pytest.approx(clean["delta_v_150ms_ms"], rel=1e-6)
    with pytest.warns(UserWarning, match=r"averages 5 g before t = -1 ms, more than a transducer offset"):
        pulse_summary(_onset_csv(tmp_path / "fault.csv", offset_g=5.0), time_zero="file")


def test_a_threshold_zero_level_above_a_transducer_offset_is_subtracted_and_named(tmp_path):
    """With ``time_zero: threshold`` the samples averaged precede the onset found, so a mean of 5 g there is
    subtracted all the same (the figures are those of the clean record), and a warning names file and channel."""
    clean = pulse_summary(_onset_csv(tmp_path / "clean.csv", shift_s=0.02))
    with pytest.warns(
        UserWarning,
        match=r"fault\.csv: channel 'acc' averages 5 g before its onset at t = 19\.9\d ms, "
        r"more than a transducer offset \(2 g\): subtracted as its zero level",
    ):
        got = pulse_summary(_onset_csv(tmp_path / "fault.csv", offset_g=5.0, shift_s=0.02))
    for key in ("delta_v_ms", "delta_v_150ms_ms", "t0_ms", "peak_g"):
        assert got[key] == pytest.approx(clean[key], rel=1e-9, abs=1e-9), key


def _lab_record(path: Path, shape: str, *, noise_g: float, pre_s: float, seed: int, offset_g: float = 0.8):
    """A 10 kHz lab export whose clock is not the contact's: it starts at 0, ``pre_s`` before a known pulse (a 30 g,
    80 ms half-sine, or a 20 g, 60 ms trapezoid with 5 ms ramps), on a transducer offset, with seeded white noise.
    Returns the file, the pulse's onset [s] and its velocity change [m/s] (analytic: its integral)."""
    t = np.arange(round((pre_s + 0.2) * 1e4)) / 1e4
    s = t - pre_s
    if shape == "halfsine":
        a = np.where((s >= 0) & (s <= 0.08), -30.0 * np.sin(np.pi * np.clip(s, 0.0, 0.08) / 0.08), 0.0)
        dv = 2 * 30 * G0 * 0.08 / math.pi
    else:
        a = -20.0 * np.interp(s, [0.0, 0.005, 0.055, 0.060], [0.0, 1.0, 1.0, 0.0], left=0.0, right=0.0)
        dv = 20 * G0 * 0.055
    a = a + offset_g + np.random.default_rng(seed).normal(0.0, noise_g, t.size)
    path.write_text("time,acc\n" + "".join(f"{x:.4f},{y:.6f}\n" for x, y in zip(t, a, strict=True)))
    return path, pre_s, dv


@pytest.mark.parametrize("shape", ["halfsine", "trapezoid"])
@pytest.mark.parametrize("noise_g", [0.3, 1.0, 2.0, 3.0])
def test_time_zero_of_a_noisy_record_is_its_onset_with_5_to_50_ms_of_pre_trigger(tmp_path, shape, noise_g):
    """Lab exports keep 5-50 ms of pre-trigger data, and raw channels carry noise. Time zero (``time_zero:
    threshold``) lies within 0.7 ms per g of rms noise of the known onset (0.2 ms at 0.3 g, 2.1 ms at 3 g), over five
    seeds, with a 0.8 g offset, on a clock without negative times. That is about three standard deviations of the
    best any estimate can do from such a record (the Cramer-Rao bound of the onset of a line from the zero level:
    0.15-0.25 ms per g for the half-sine's 1.2 g/ms at 10 kHz, with 5-50 ms before it).

    Before, the 0.5 g crossing of the CFC 60 record started the search, and noise crossed it: with 2-3 g rms time
    zero lay up to 47 ms early (at the record's start) with 5-50 ms of pre-trigger data, and up to 2.9 ms late with
    1 g (the crossing of 5x the noise)."""
    for pre_s in (0.005, 0.010, 0.020, 0.050):
        for seed in range(5):
            path, onset, _ = _lab_record(tmp_path / "lab.csv", shape, noise_g=noise_g, pre_s=pre_s, seed=seed)
            t0 = pulse_summary(path)["t0_ms"] / 1e3
            assert abs(t0 - onset) <= 0.7e-3 * noise_g, (pre_s, seed, (t0 - onset) * 1e3)


@pytest.mark.parametrize("shape", ["halfsine", "trapezoid"])
def test_delta_v_of_a_noisy_record_with_an_offset_is_the_pulse_integral(tmp_path, shape):
    """The velocity change 150 ms after time zero of the records above (0.8 g offset, 20 ms of pre-trigger data, no
    negative times) against the pulse's integral: clean within 0.1 %, with 1 g rms noise within 0.4 m/s over five
    seeds (3.3x the zero level's own uncertainty: 1 g over the root of its 195 samples, integrated over the
    170 ms from 20 ms before time zero, 0.12 m/s). Before: time zero at the first sample and the offset
    integrated, 1.2 m/s (8 %) short."""
    path, _, dv = _lab_record(tmp_path / "clean.csv", shape, noise_g=0.0, pre_s=0.02, seed=0)
    assert pulse_summary(path)["delta_v_150ms_ms"] == pytest.approx(dv, rel=1e-3)
    for seed in range(5):
        path, _, dv = _lab_record(tmp_path / "noisy.csv", shape, noise_g=1.0, pre_s=0.02, seed=seed)
        assert abs(pulse_summary(path)["delta_v_150ms_ms"] - dv) <= 0.4, seed


def test_too_little_pre_trigger_data_for_a_zero_level_is_named_not_silent(tmp_path):
    """1 ms of samples before the pulse cannot measure a zero level or noise: time zero is found with a zero level of
    0 and the 0.5 g threshold, and a warning names the file, the channel and what it has."""
    path, onset, dv = _lab_record(tmp_path / "short.csv", "halfsine", noise_g=0.0, pre_s=0.001, seed=0, offset_g=0.0)
    with pytest.warns(
        UserWarning,
        match=r"short\.csv: channel 'acc' has 0\.9 ms of samples before its onset at "
        r"t = 0\.9\d ms, too few to measure its zero level and noise \(time_zero "
        r"threshold needs 2\.5 ms of pre-trigger data\).*--time-zero file",
    ):
        s = pulse_summary(path)
    assert s["t0_ms"] == pytest.approx(onset * 1e3, abs=0.1) and s["delta_v_150ms_ms"] == pytest.approx(dv, rel=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the file's clock: nothing to measure, nothing said
        pulse_summary(path, time_zero="file")


def test_iso_mme_default_channel_is_not_chosen_past_a_channel_without_unit(tmp_path, analytic):
    folder = tmp_path / "T1"
    write_mme(analytic, folder, "T1")
    chan = folder / "Channel" / "T1.001"
    chan.write_text("".join(line for line in chan.read_text(encoding="latin-1").splitlines(True)
                            if not line.startswith("Unit")), encoding="latin-1")  # fmt: skip
    with pytest.raises(PulseError, match=r"T1: channel file T1.001 has no 'Unit' header line.*--acc-col"):
        pulse_summary(folder)


def test_a_table_of_breakpoints_from_the_contact_needs_no_pre_trigger_data(tmp_path):
    """Corners drawn from t = 0 have neither noise nor offset: time_zero threshold takes their zero level as 0 without
    the warning a sampled record that starts at the contact gets (the same samples written out as such)."""
    from marlcrash.pulse.io import processed_pulse
    from marlcrash.pulse.signal import SHORT_PRE_TRIGGER

    path = tmp_path / "corners.csv"
    path.write_text(_trapezoid_corners())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, work, t0 = processed_pulse(path, breakpoints=True, time_zero="threshold")
    assert t0 == pytest.approx(0.0, abs=1e-4)
    p = read_csv(path, breakpoints=True)
    sampled = tmp_path / "sampled.csv"
    sampled.write_text("time,acc\n" + "".join(f"{t:.6f},{a / G0:.9f}\n" for t, a in zip(p.time, p.acc[0], strict=True)))
    with pytest.warns(UserWarning, match=SHORT_PRE_TRIGGER):
        _, work2, _ = processed_pulse(sampled, time_zero="threshold")
    np.testing.assert_allclose(work2.acc, work.acc, rtol=0, atol=1e-6 * float(np.abs(work.acc).max()))
    early = tmp_path / "early.csv"  # corners from t = -2 ms on the file's clock: no offset to leave in either
    early.write_text("time,acc\n-0.002,0\n" + "".join(_trapezoid_corners().splitlines(keepends=True)[1:]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        processed_pulse(early, breakpoints=True, time_zero="file")


def test_a_file_clock_record_with_short_pre_trigger_says_its_offset_stays():
    """time_zero file: the zero level is the mean before t = -1 ms. Under 5 ms of such samples it is not measured;
    that used to be silent, with a 0.8 g offset left to drift into the velocity."""
    from marlcrash.pulse.signal import remove_zero_offset

    def record(pre_ms: float) -> Pulse:
        t = np.arange(-round(pre_ms * 10), 1500) / 1e4
        acc = np.where((t >= 0) & (t < 0.08), -30 * G0 * np.sin(np.pi * np.clip(t, 0, 0.08) / 0.08), 0.0) + 0.8 * G0
        return Pulse(time=t, acc=acc[None], channels=["acc"], source="lab.csv")

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        long = remove_zero_offset(record(10.0))
        np.testing.assert_allclose(long.acc[0, long.time < 0], 0.0, atol=1e-9)  # offset measured and removed
        start = record(0.0)
        assert remove_zero_offset(start) is start  # starts at the contact: nothing to measure, nothing to say
    short = record(3.0)
    said = r"lab\.csv: 3 ms of pre-trigger samples \(negative times\), 1\.9 ms of them before t = -1 ms, fewer"
    with pytest.warns(UserWarning, match=said):
        assert remove_zero_offset(short) is short
    tiny = record(0.5)  # no sample before t = -1 ms at all: said all the same (it was silent)
    with pytest.warns(UserWarning, match=r"lab\.csv: 0\.5 ms of pre-trigger samples \(negative times\), 0 ms of them"):
        assert remove_zero_offset(tiny) is tiny


def test_noise_near_the_start_of_a_record_does_not_discard_its_pre_trigger_data():
    """The first guess of where the pulse starts rises above the noise of the record's first 2 ms: with 3 g of noise
    on a 3 ms, 10 g pulse (seed 22), noise crossed the guess's level near the start, the channel's 10 ms of
    pre-trigger data were given up as too short, and time zero came out 10 ms early with the 0.5 g offset left in."""
    from marlcrash.pulse.signal import find_onset

    t = 0.29 + np.arange(1600) / 1e4  # the clock is not the contact's: contact at t = 0.3 s, 10 ms of pre-trigger
    pulse = np.where((t >= 0.3) & (t < 0.303), -10 * G0 * np.sin(np.pi * (t - 0.3) / 0.003), 0.0)
    acc = pulse + 0.5 * G0 + np.random.default_rng(22).normal(0, 3 * G0, t.size)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        onset = find_onset(Pulse(time=t, acc=acc[None], channels=["acc"], source="lab.csv"), 60)
    assert onset.measured[0] and abs(onset.time - 0.3) < 2e-3
    assert onset.zero_level[0] == pytest.approx(0.5 * G0, abs=3 * G0 / np.sqrt(80))  # the offset, to 3 std errors


def test_a_folder_given_as_dot_is_named_in_the_message(tmp_path, monkeypatch):
    """Messages name a file by its name; ``.`` (the working folder) has none, so ``marlcrash pulse .`` printed
    ``error: : expected exactly one <test>.mme file``. Such a path is named by its resolved path."""
    from marlcrash.errors import ConfigError, DeckError

    monkeypatch.chdir(tmp_path)
    with pytest.raises(PulseError) as e:
        read_mme(".")
    assert str(e.value).startswith(f"{tmp_path.resolve()}: expected exactly one <test>.mme file"), str(e.value)
    assert str(DeckError("bad card", ".", line=3)).startswith(f"{tmp_path.resolve()} line 3: bad card")
    assert str(ConfigError("bad", key="k", path=".")) == f"{tmp_path.resolve()} key 'k': bad"
    assert str(ConfigError("bad", key="k", path=tmp_path / "a.yaml")) == "a.yaml key 'k': bad"  # a name stays a name


def test_an_iso_mme_test_folder_finds_its_mme_file_whatever_the_case_of_its_suffix(tmp_path, analytic, monkeypatch):
    """``read_pulse`` takes a ``T1.Mme`` file by its suffix in any case; the test folder holding it must be read
    alike. The folder was searched with two globs, ``*.mme`` and ``*.MME``: a ``.Mme`` file was not found, and
    where globs ignore case (Windows) both found the one ``.mme`` file, counted twice."""
    mme = write_mme(analytic, tmp_path / "T1", "T1")
    mixed = mme.rename(mme.with_name("T1.Mme"))
    assert read_mme(tmp_path / "T1").channels == read_mme(mixed).channels == ("tunnel", "radsup")
    assert read_pulse(tmp_path / "T1").channels == ("tunnel", "radsup")
    mixed.rename(mme)  # a file system whose globs ignore case: '*.MME' also matches 'T1.mme'
    plain_glob = Path.glob

    def case_blind_glob(self, pattern):
        return plain_glob(self, pattern.lower())

    monkeypatch.setattr(Path, "glob", case_blind_glob)
    assert read_mme(tmp_path / "T1").channels == ("tunnel", "radsup")
    monkeypatch.undo()
    (tmp_path / "T1" / "T2.MME").write_text("Data format edition number  :1.6\n")
    with pytest.raises(PulseError, match=r"T1: expected exactly one <test>\.mme file in the test folder, found 2"):
        read_mme(tmp_path / "T1")


def test_write_csv_quotes_channel_names_that_hold_a_comma_or_a_quote(tmp_path):
    """``write_csv`` writes "the format read_csv reads"; an ISO-MME channel read by its name (``Vehicle CG, x``) or
    a name with a quote made a header of more fields than the rows, which read_csv refused (line 2: expected 4
    fields as in the header, got 3)."""
    t = np.arange(0.0, 0.05, 1e-4)
    acc = np.stack([-9.80665 * np.sin(40 * t), 2 * 9.80665 * np.cos(40 * t)])
    p = Pulse(t, acc, ("Vehicle CG, x", 'B-pillar "left"'))
    back = read_csv(write_csv(p, tmp_path / "names.csv"))
    assert back.channels == p.channels
    np.testing.assert_allclose(back.acc, acc, rtol=1e-12)
    back = read_csv(write_csv(p, tmp_path / "si.csv", unit="m/s2", time_col="t, s"), unit="m/s2", time_col="t, s")
    assert back.channels == p.channels


def test_write_csv_keeps_a_remark_at_the_end_of_a_name_and_writes_the_unit_over_a_unit(tmp_path):
    """``write_csv`` wrote its unit over any bracketed end of a name, a remark too: channels ``acc [CH1]`` and ``acc
    [CH2]`` became two columns ``acc [g]``, a header read_csv refused ('duplicate column name'), and ``tunnel
    (filtered)`` came back as ``tunnel (g)``. A remark is kept (read_csv reads it as no unit); a unit, known or not,
    is replaced by the one written."""
    t = np.arange(0.0, 0.05, 1e-4)
    acc = np.stack([-9.80665 * np.sin(40 * t), 2 * 9.80665 * np.cos(40 * t), np.ones_like(t), -np.ones_like(t)])
    p = Pulse(t, acc, ("acc [CH1]", "acc [CH2]", "tunnel (filtered)", "a_x [m/s2]"))
    back = read_csv(write_csv(p, tmp_path / "remarks.csv", time_col="t (ms)"))
    assert back.channels == ("acc [CH1]", "acc [CH2]", "tunnel (filtered)", "a_x [g]")
    np.testing.assert_allclose(back.acc, acc, rtol=1e-12)
    np.testing.assert_allclose(back.time, t, rtol=0, atol=1e-15)
    path = write_csv(Pulse(t, acc[:2], ("acc [mg]", "b (x)")), tmp_path / "si.csv", unit="m/s2", time_col="t [run 2]")
    assert path.read_text().splitlines()[0] == "t [run 2],acc [m/s2],b (x)"


def test_the_pulse_summary_reads_only_the_first_acceleration_column_of_a_csv(tmp_path):
    """``marlcrash pulse FILE`` summarizes the first acceleration column (as it reads only the first acceleration
    channel of an ISO-MME test); a lab export's other columns, a remark column left empty or a channel that ends
    earlier, made the file unreadable (``column 'remark': expected a number, got ''``)."""
    from marlcrash.pulse.io import processed_pulse, pulse_summary

    t = np.arange(-0.02, 0.2, 1e-4)
    acc_g = half_sine(t, 0.080) / G0
    rows = [
        f"{x:.4f};{a:.6f};;{'' if k > 1500 else '0,0'}".replace(".", ",")
        for k, (x, a) in enumerate(zip(t, acc_g, strict=True))
    ]
    path = tmp_path / "lab.csv"
    path.write_text('"Zeit [s]";"a_x [g]";"remark";"v [m/s2]"\n' + "\n".join(rows) + "\n")
    s = pulse_summary(path)
    assert s["channel"] == "a_x [g]" and s["delta_v_ms"] == pytest.approx(DV, rel=0.01)
    assert processed_pulse(path)[0].channels == ("a_x [g]",)
    # the column named is read, and an unused column's unit is no concern of the first one
    with pytest.raises(PulseError, match=r"lab\.csv line 1503, column 'v \[m/s2\]': expected a number, got ''"):
        pulse_summary(path, acc_col="v [m/s2]", unit="m/s2")
    with pytest.raises(PulseError, match=r"lab\.csv line 1: column 'nope' not found"):
        pulse_summary(path, acc_col="nope")
    bad = tmp_path / "bad.csv"
    bad.write_text("time,,acc\n" + GOOD_ROWS)  # the header is checked as before
    with pytest.raises(PulseError, match=r"bad\.csv line 1: header column 2 is empty"):
        pulse_summary(bad)


def test_a_channel_file_key_with_doubled_spaces_is_read_as_the_mme_and_chn_keys_are(tmp_path, analytic):
    """The .mme and .chn readers take ``Number  of channels`` as ``Number of channels``; a channel file's keys were
    only stripped, so ``Sampling  interval`` failed with "missing header line 'Sampling interval'" though it was
    there."""
    ch = _mme(tmp_path, analytic)
    _edit(ch, "Sampling interval           :", "Sampling  interval          :")
    _edit(ch, "Number of samples           :", "Number  of samples          :")
    p = read_mme(tmp_path / "B")
    assert p.n_samples == analytic.n_samples and p.sample_rate_hz == pytest.approx(analytic.sample_rate_hz)


def test_an_iso_mme_number_of_samples_given_as_novalue_is_not_a_count(tmp_path, analytic):
    """ISO-MME writes ``NOVALUE`` for a value not given (as the reader takes for ``Channel code``); the optional
    ``Number of samples`` said so was refused as "expected a number, got 'NOVALUE'". It is checked when given."""
    ch = _mme(tmp_path, analytic)
    _edit(ch, "Number of samples           :2200", "Number of samples           :NOVALUE")
    p = read_mme(tmp_path / "B")
    assert p.n_samples == analytic.n_samples and p.channels == ("tunnel", "radsup")
    _edit(ch, "Number of samples           :NOVALUE", "Number of samples           :many")
    with pytest.raises(PulseError, match=r"B\.001 line 8: 'Number of samples': expected a number, got 'many'"):
        read_mme(tmp_path / "B")


@pytest.mark.parametrize(
    ("unit", "factor"),
    [("m s-2", 1.0), ("m.s-2", 1.0), ("m·s⁻²", 1.0), ("ms-2", 1.0), ("mps2", 1.0), ("m/sec^2", 1.0),
     ("mm/s^2", 1e-3), ("mm s-2", 1e-3), ("mm/ms2", 1e3), ("mm/ms^2", 1e3)],
)  # fmt: skip
def test_si_spellings_of_an_acceleration_unit_in_a_header_are_read_in_that_unit(tmp_path, unit, factor):
    """``a_x [m s-2]`` (the SI spelling of many data loggers), ``[m.s-2]``, ``[ms-2]``, ``[mps2]`` were taken for
    remarks: the column was read as g without a word, 9.8x every figure (a 6.5 g pulse printed 63.7 g). They, mm/s^2
    (a known unit that was called unknown) and LS-DYNA's mm/ms^2 (mm-ms-kg runs: 1000 m/s^2) are read as what they
    say: in that unit when it is given, and a clear refusal naming it when another is."""
    from marlcrash.pulse.io import ACC_UNIT_NAMES, acc_unit_factor

    path = tmp_path / "p.csv"
    m_s2 = -np.sin(np.linspace(0.0, np.pi, 200)) * 60.0  # m/s^2
    path.write_text(
        f"time [s],a_x [{unit}]\n" + "".join(f"{k * 1e-4:.4f},{float(a / factor)!r}\n" for k, a in enumerate(m_s2))
    )
    typed = next(u for u in ACC_UNIT_NAMES if acc_unit_factor(u) == factor)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pulse = read_csv(path, unit=typed)
    np.testing.assert_allclose(pulse.acc[0], m_s2, rtol=1e-12)
    with pytest.raises(
        PulseError,
        match=rf"p\.csv line 1: column 'a_x \[{re.escape(unit)}\]' is in {re.escape(unit)} "
        rf"by its header, but is read in g: give that unit \(--unit {re.escape(typed)}",
    ):
        read_csv(path)  # unit g, the default


def test_a_sampled_record_of_minutes_is_refused_as_a_time_column_in_ms(tmp_path):
    """An LS-DYNA run in mm-ms-kg written every 2 us has its time in ms: read as seconds it is 160 s at 500 Hz,
    which passed the rate check (500 Hz is accepted), and the 150 ms window of a reference held 0.1 % of the pulse
    (velocity change 0.09 of 11.1 m/s, no error). A sampled record longer than 10 s is refused with the hint."""
    from marlcrash.pulse.io import check_record_rate, read_pulse

    path = tmp_path / "dyna_ms.csv"
    t_ms = np.arange(0.0, 160.0, 0.002)
    acc = -20.0 * np.sin(np.pi * np.clip(t_ms / 80.0, 0.0, 1.0))
    path.write_text("time,acc\n" + "".join(f"{a:.4f},{b:.6g}\n" for a, b in zip(t_ms, acc, strict=True)))
    with pytest.raises(PulseError, match=r"dyna_ms\.csv: record of 160 s at 500 Hz: .*at most 10 s\); is the time "
                                         r"column in ms \(--time-unit ms; time_unit: ms\)\?"):  # fmt: skip
        check_record_rate(read_pulse(path), path)  # as a file reference and `marlcrash pulse` check a record
    in_ms = read_pulse(path, time_unit="ms")
    check_record_rate(in_ms, path, time_unit="ms")
    assert float(in_ms.time[-1] - in_ms.time[0]) == pytest.approx(0.16, abs=1e-4)


@pytest.mark.parametrize(
    ("header", "named"),
    [
        ("time [s],acc [mg]", "acc [mg]"),  # milli-g: 1000x off when read as g
        ("time [s],acc [cm/s2]", "acc [cm/s2]"),  # gal
        ("time [s],acc [ft/s^2]", "acc [ft/s^2]"),
        ("time [us],acc [g]", "time [us]"),  # microseconds read as seconds
    ],
)
def test_a_header_unit_the_reader_does_not_know_is_warned_about_naming_the_column(tmp_path, header, named):
    """A unit written in the header that is not the one read used to be refused only when it was a known unit:
    ``acc [mg]`` was read as g, ``time [us]`` as seconds, without a word."""
    path = tmp_path / "p.csv"
    path.write_text(header + "\n" + "\n".join(f"{k * 1e-4:.4f},{-20.0 * (k % 7)}" for k in range(60)) + "\n")
    with pytest.warns(UserWarning, match=rf"p\.csv line 1: column '{re.escape(named)}' gives the unit"):
        read_csv(path)


def test_the_first_acceleration_column_skips_columns_whose_header_gives_another_unit(tmp_path):
    # a lab's CSV with a pitch angle and a barrier force before the acceleration: the angle was read as g (3 g,
    # 1.5 m/s, plausible), and only a generic unknown-unit warning said anything
    from marlcrash.pulse.io import processed_pulse

    t = np.arange(-0.02, 0.2, 1e-4)
    a = np.where((t >= 0) & (t < 0.08), -30 * np.sin(np.pi * np.clip(t, 0, 0.08) / 0.08), 0.0)
    rows = "".join(f"{x:.5f},{0.1 * y:.4f},{2 * y:.4f},{y:.4f},{y:.6f}\n" for x, y in zip(t, a, strict=True))
    path = tmp_path / "lab.csv"
    path.write_text("time,pitch [deg],F_barrier [kN],F [N],a_x [g]\n" + rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the other columns are not read, so nothing is said of their units
        raw, work, _ = processed_pulse(path, cfc=None, time_zero="file")
    assert raw.channels == ("a_x [g]",)
    assert work.velocity()[0, -1] == pytest.approx(-30 * G0 * 0.08 * 2 / np.pi, rel=1e-3)
    # a file whose columns all give other units: the first is read, as before, and its unit warned about
    alone = tmp_path / "alone.csv"
    alone.write_text("time,pitch [deg]\n" + "".join(f"{x:.5f},{0.1 * y:.4f}\n" for x, y in zip(t, a, strict=True)))
    with pytest.warns(UserWarning, match=r"column 'pitch \[deg\]' gives the unit 'deg'"):
        assert read_csv(alone, first_only=True).channels == ("pitch [deg]",)
    # named, a column is read whatever its header (with the warning)
    with pytest.warns(UserWarning, match=r"column 'F_barrier \[kN\]' gives the unit 'kN'"):
        assert read_csv(path, acc_col="F_barrier [kN]").channels == ("F_barrier [kN]",)


@pytest.mark.parametrize(
    "header", ["time [s],acc [g]", "Time (sec),a_x [m/s2] (filtered)", "t (ms),ACC [CH1]", "time,acc (x)"]
)
def test_known_units_and_remarks_in_a_header_read_without_a_unit_warning(tmp_path, header):
    path = tmp_path / "p.csv"
    path.write_text(header + "\n" + "\n".join(f"{k * 1e-4:.4f},{-20.0 * (k % 7)}" for k in range(60)) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv(path, time_unit="ms" if header.startswith("t (ms)") else "s")


def test_a_frontal_pulse_read_with_the_other_sign_is_named_in_a_warning(tmp_path, analytic):
    """A frontal record whose file gives deceleration as positive, read with the default (SAE J211) sign: its velocity
    change speeds the vehicle up by 40 km/h, and ``marlcrash pulse`` said nothing, its figures being magnitudes. A
    warning now names the file, the channel and the option that flips the sign; the figures keep their meaning (the
    same magnitudes), and read with that sign nothing is said."""
    path = write_csv(Pulse(analytic.time, -analytic.acc, analytic.channels), tmp_path / "decel_positive.csv")
    with pytest.warns(UserWarning) as caught:
        s = pulse_summary(path)
    said = [str(w.message) for w in caught if "speeds up" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in caught]
    gain = re.escape(f"{DV:.3g}")  # the analytic pulse's whole velocity change, gained
    assert re.search(rf"decel_positive\.csv: channel 'tunnel' speeds up by {gain} m/s .*negative.*"
                     r"--deceleration-positive.*sign=-1", said[0]), said[0]  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        right = pulse_summary(path, sign=-1)
        pulse_summary(write_csv(analytic, tmp_path / "j211.csv"))
    for key in ("t0_ms", "peak_g", "t_peak_ms", "delta_v_ms", "delta_v_max_ms", "delta_v_150ms_ms"):
        assert s[key] == pytest.approx(right[key], rel=1e-12, abs=1e-12), key
    assert right["delta_v_ms"] == pytest.approx(DV, rel=0.01)


def test_a_pulse_in_m_s2_read_as_g_is_named_in_a_warning(tmp_path, analytic):
    """A record in m/s^2 read with the CSV default unit g integrates to 9.8x its velocity change (a 300 m/s^2 half
    sine over 100 ms: 674 km/h) and ``marlcrash pulse`` printed it without a word; a warning now names the file, the
    channel, the figure and the option. Read in its own unit, or a real pulse in g, nothing is said."""
    in_ms2 = Pulse(analytic.time, analytic.acc, analytic.channels)
    path = write_csv(in_ms2, tmp_path / "ms2.csv", unit="m/s2")  # the numbers of m/s^2 under a header...
    text = path.read_text().replace("[m/s2]", "").replace("_ms2", "")  # ...that does not say so
    path.write_text(text)
    with pytest.warns(UserWarning) as caught:
        s = pulse_summary(path)  # read as g
    said = [str(w.message) for w in caught if "more than any vehicle crash" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in caught]
    assert s["delta_v_max_ms"] == pytest.approx(G0 * DV, rel=0.01) and s["delta_v_max_ms"] > MAX_CRASH_DELTA_V
    assert re.search(rf"ms2\.csv: channel '.*' changes velocity by {re.escape(f'{G0 * DV:.3g}')}.* km/h\).*"
                     r"--unit m/s2 \(unit: m/s2\)", said[0]), said[0]  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pulse_summary(path, unit="m/s2")["delta_v_max_ms"] == pytest.approx(DV, rel=0.01)
        pulse_summary(write_csv(analytic, tmp_path / "g.csv"))
    assert DV < MAX_CRASH_DELTA_V


def test_an_iso_mme_test_reads_each_channel_file_once(tmp_path, analytic, monkeypatch):
    """``read_mme`` and ``marlcrash pulse`` read each file of an ISO-MME test once, its header and its samples
    together: the channel list was read (every file, whole) and then each chosen channel file again, and ``marlcrash
    pulse`` listed the channels twice more (three readings of a file that may hold 100 000 samples). Same results."""
    import pathlib

    write_mme(Pulse(analytic.time, np.stack([analytic.acc[0] * 1e3, *analytic.acc]), ("11BELT0000FOXA", "tunnel",
                    "radsup")), tmp_path / "T", "T")  # fmt: skip
    _edit(tmp_path / "T" / "Channel" / "T.001", "Unit                        :g", "Unit                        :N")
    expected_all = read_mme(tmp_path / "T", channels=["tunnel", "radsup"])
    expected_summary = pulse_summary(_write_plain(tmp_path / "p.csv", analytic))
    reads: list[str] = []  # the files opened, however they are read
    path_open = pathlib.Path.open

    def counted(self, *args, **kwargs):
        reads.append(self.name)
        return path_open(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "open", counted)
    with pytest.warns(UserWarning, match=r"skipped T\.001 \(N\)"):
        got = read_mme(tmp_path / "T")
    assert got.channels == ("tunnel", "radsup") and np.array_equal(got.acc, expected_all.acc)
    assert sorted(reads) == ["T.001", "T.002", "T.003", "T.chn", "T.mme"]
    reads.clear()
    assert read_mme(tmp_path / "T", channels="radsup").channels == ("radsup",)
    assert sorted(reads) == ["T.001", "T.002", "T.003", "T.chn", "T.mme"]
    reads.clear()
    s = pulse_summary(tmp_path / "T")  # the first acceleration channel: the files after it are not needed
    assert s["channel"] == "tunnel" and s["delta_v_ms"] == pytest.approx(expected_summary["delta_v_ms"])
    assert sorted(reads) == ["T.001", "T.002", "T.chn", "T.mme"]


def test_listing_the_channels_of_an_iso_mme_test_reads_their_headers_not_their_samples(tmp_path, analytic, monkeypatch):
    """``mme_channels`` parses the first 200 lines of each channel file as its header, but read every file whole
    first: listing a test whose channel holds three million samples (18 MB) read all of it (and held it, as text and
    as a list of lines). It now reads a channel file only up to the end of its header; the channels it lists are the
    same, and ``read_mme`` still reads each file once, header and samples together."""
    import pathlib
    import tracemalloc

    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    expected = mme_channels(tmp_path / "T")
    big = tmp_path / "T" / "Channel" / "T.002"
    head = big.read_text(encoding="latin-1").split("\n")[:8]  # the header lines write_mme writes
    head[-1] = "Number of samples           :3000000"
    with big.open("wb") as f:
        f.write(("\n".join(head) + "\n").encode("latin-1"))
        for _ in range(30):
            f.write(b"-1.25\n" * 100_000)
    assert big.stat().st_size > 18_000_000
    read_bytes: dict[str, int] = {}  # bytes read per file, however it is read
    path_open = pathlib.Path.open

    class Counted:
        def __init__(self, f, name):
            self._f, self._name = f, name

        def _count(self, data):
            read_bytes[self._name] = read_bytes.get(self._name, 0) + len(data)
            return data

        def read(self, *args):
            return self._count(self._f.read(*args))

        def readline(self, *args):
            return self._count(self._f.readline(*args))

        def __iter__(self):
            return (self._count(line) for line in self._f)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self._f.__exit__(*exc)

        def __getattr__(self, name):
            return getattr(self._f, name)

    monkeypatch.setattr(pathlib.Path, "open", lambda self, *a, **k: Counted(path_open(self, *a, **k), self.name))
    tracemalloc.start()
    try:
        got = mme_channels(tmp_path / "T")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert got == expected
    assert read_bytes["T.002"] < 100_000, f"read {read_bytes['T.002']} bytes of T.002 to list its header"
    assert peak < 2_000_000, f"listing the channels took {peak / 1e6:.1f} MB at its peak"
    read_bytes.clear()
    samples = read_mme(tmp_path / "T", channels="radsup")  # header and samples: the file read once, whole
    assert samples.n_samples == 3_000_000 and np.all(samples.acc == -1.25 * G0)
    assert read_bytes["T.002"] == big.stat().st_size


def test_an_iso_mme_header_may_hold_a_windows_1252_ellipsis(tmp_path, analytic):
    """ISO-MME files are read as Latin-1, and their lines were split by ``str.splitlines``, which also breaks at
    U+0085 (byte 0x85, the ellipsis of Windows-1252), form feeds and other control characters: a comment 'run 2 ...'
    written by a Windows tool ended the header there, and the channel lost the header lines after it ('missing
    header line 'Unit''). Lines end at line feeds and carriage returns only."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    ref = read_mme(tmp_path / "T")
    for f in sorted((tmp_path / "T" / "Channel").glob("T.00?")):
        data = f.read_bytes()
        f.write_bytes(data.replace(b"\n", b"\nComments                    :run 2\x85 again\x0c\n", 1))
    got = read_mme(tmp_path / "T")
    assert got.channels == ref.channels and np.array_equal(got.acc, ref.acc)
    assert [c["unit"] for c in mme_channels(tmp_path / "T")] == ["g", "g"]


def test_a_channel_whose_pulse_starts_before_its_onset_is_named_with_the_velocity_change_it_loses(tmp_path):
    """The tunnel of a lab export (10 kHz, 20 ms of rest, a 0.3 g offset, 0.1 g rms noise) decelerates at 1.5 g from
    the contact, its main pulse (20 g, 60 ms) 6 ms later. Read alone (``marlcrash pulse --acc-col``, a file of that
    channel only), time zero is its main pulse's onset and the mean of its samples before it, 1.5 g over its last
    4 ms, is taken as its zero level: its velocity change comes out 0.37 m/s short, silently before. A warning now
    names the file, the channel, where the samples step and about how much is lost, within 0.05 m/s of the known
    loss, and suggests ``--time-zero file``. Read with the front channel (a file reference) the earliest onset is
    the contact, nothing is lost, and nothing is said; nor of records whose samples before the pulse rest on a
    constant offset with white noise of up to 3 g."""
    from marlcrash.pulse.signal import find_onset, without_zero_offset

    t, front, tunnel = _lab_front_and_tunnel()
    acc = (np.stack([front, tunnel]) + 0.3 + np.random.default_rng(0).normal(0.0, 0.1, (2, t.size))) * G0
    dv = 2 * 20 * G0 * 0.06 / math.pi + 1.5 * G0 * (0.1 - 0.0005)  # the main pulse and the 1.5 g
    alone = write_csv(Pulse(t, acc[1:], ("tunnel",)), tmp_path / "alone.csv")
    with pytest.warns(UserWarning, match=r"alone\.csv: channel 'tunnel' is not at rest before the record's time zero "
                      r"at t = 2\d\.\d\d ms: its samples there step by -1\.\d+ g at t = 20\.\d\d ms.*about "
                      r"(\d\.\d+) m/s short .*--time-zero file") as said:  # fmt: skip
        s_alone = pulse_summary(alone)
    lost = dv - s_alone["delta_v_ms"]
    assert 0.3 < lost < 0.45 and s_alone["t0_ms"] > 22.0  # time zero at the main pulse, after the contact
    named = [re.search(r"about (\d\.\d+) m/s short", str(w.message)) for w in said]
    assert [float(m.group(1)) for m in named if m] == [pytest.approx(lost, abs=0.05)]
    both = Pulse(t, acc, ("front", "tunnel"), source="both.csv")
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*is not at rest")
        _, v = prepare_velocity(without_zero_offset(both, "threshold"))
        assert abs(find_onset(both, 60).time - _LAB_CONTACT) < 0.3e-3
        for noise_g in (1.0, 3.0):
            for pre_s in (0.005, 0.02, 0.05):
                for seed in range(3):
                    pulse_summary(_lab_record(tmp_path / "lab.csv", "halfsine", noise_g=noise_g, pre_s=pre_s,
                                              seed=seed)[0])  # fmt: skip
    assert v[1, 0] - v[1, -1] == pytest.approx(dv, abs=0.05)  # all of it, from the contact


def test_an_iso_mme_test_written_as_utf8_is_read_as_utf8(tmp_path, analytic):
    """ISO-MME files were read as Latin-1 only: a channel file a tool wrote as UTF-8 with ``Unit :m/s²`` read as
    ``m/sÂ²`` and was refused as an unknown unit. A line is decoded as UTF-8 where its bytes are UTF-8, else as Latin-1
    (line by line, as the CSV reader does; a UTF-8 byte-order mark is dropped), and ``mme_channels``, which reads a
    header in 16 KiB chunks, decodes alike where a chunk ends inside a UTF-8 character. Latin-1 files read as
    before."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "L", "T", unit="m/s**2")
    write_mme(analytic, tmp_path / "U", "T", unit="m/s**2")
    ref = read_mme(tmp_path / "L")
    files = sorted((tmp_path / "U" / "Channel").glob("T.00?"))
    for k, f in enumerate(files):
        head, _, body = f.read_text(encoding="latin-1").partition("Reference system")
        head = head.replace(":m/s**2", ":m/s²").replace(f":{ref.channels[k]}\n", f":Beschl. Σ {k}\n", 1)
        if k == 0:  # a Latin-1 comment in a UTF-8 file stays Latin-1; the UTF-8 lines after it stay UTF-8
            data = b"Comments                    :Pr\xfcfung\n" + (head + "Reference system" + body).encode()
        else:  # a byte-order mark, and a comment that puts a chunk's end between the two bytes of '²'
            data = ("\ufeff" + head).encode()
            split = 16384 - 1 - data.index("²".encode())
            comment = "Comments                    :" + "x" * (split - 30) + "\n"
            data = ("\ufeff" + comment + head + "Reference system" + body).encode()
            assert data[16383:16385] == "²".encode()
        f.write_bytes(data)
    got = read_mme(tmp_path / "U")
    assert got.channels == ("Beschl. Σ 0", "Beschl. Σ 1") and np.array_equal(got.acc, ref.acc)
    listed = mme_channels(tmp_path / "U")
    assert [(c["name"], c["unit"], c["acceleration"]) for c in listed] == [
        ("Beschl. Σ 0", "m/s²", True), ("Beschl. Σ 1", "m/s²", True)]  # fmt: skip
    assert read_mme(tmp_path / "U", channels="Beschl. Σ 1").channels == ("Beschl. Σ 1",)
    assert [c["unit"] for c in mme_channels(tmp_path / "L")] == ["m/s**2", "m/s**2"]  # Latin-1, as before


def test_mme_header_text_whose_latin_1_bytes_read_as_utf8_is_refused(tmp_path, analytic):
    """ISO-MME lines are read as UTF-8 where their bytes are UTF-8: ``write_mme`` writes Latin-1, and a name whose
    Latin-1 bytes happen to be UTF-8 ('Maß²': DF B2, one UTF-8 character) would read back as another name. Refused
    before anything is written, naming what it would read as; the Latin-1 names of real tests are not UTF-8 and are
    written as before."""
    with pytest.raises(PulseError, match=r"channel 2 name 'Maß²': .* read it back as 'Ma\u07f2'"):
        write_mme(Pulse(analytic.time, analytic.acc, ("tunnel", "Maß²")), tmp_path / "M", "M")
    assert not (tmp_path / "M").exists()
    write_mme(Pulse(analytic.time, analytic.acc, ("Fläche m²", "Größe µ")), tmp_path / "L", "Prüfung")
    assert read_mme(tmp_path / "L").channels == ("Fläche m²", "Größe µ")


@pytest.mark.parametrize(("existing", "added"), [("T.001", "T.0001"), ("T.001", "T.01"), ("T.002", "t.002")])
def test_two_files_for_one_iso_mme_channel_number_are_refused_naming_both(tmp_path, analytic, existing, added):
    """A channel file is ``<test>.<number>``, the number of at least three digits. ``T.001`` and ``T.0001`` (both
    channel 1) were both read, the channel twice; ``T.01`` beside ``T.001`` was passed over without a word; and
    ``t.002`` (the stem matched in any case) was read beside ``T.002``. Two files for one channel number are
    ambiguous: refused, naming both, by ``read_mme`` and ``mme_channels`` alike."""

    write_mme(analytic, tmp_path / "T", "T")
    chan = tmp_path / "T" / "Channel"
    (chan / added).write_bytes((chan / existing).read_bytes())
    a, b = sorted((existing, added))
    said = rf"Channel: channel {int(existing[2:])} has two files, {re.escape(a)} and {re.escape(b)}; a channel is one"
    _reading_and_listing_refuse(tmp_path / "T", said)
    (chan / added).unlink()
    assert read_mme(tmp_path / "T").channels == analytic.channels


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-be", "utf-32"])
def test_an_iso_mme_test_written_as_utf16_with_its_byte_order_mark_is_read(tmp_path, analytic, codec):
    """ISO-MME files are Latin-1, or UTF-8 as some tools write them; a Windows tool may write UTF-16 (or UTF-32) with
    a byte-order mark, as the CSV reader takes it. Such a channel file was read byte by byte as Latin-1 ('ÿþN\\x00a'),
    its header names were not found and the test was refused as "missing header line 'Unit'", and ``mme_channels``
    listed its channels with no name and no unit. The byte-order mark is read and the text decoded by it; the header
    listing, read in 16 KiB chunks, alike where a chunk ends inside a UTF-16 surrogate pair or a CR LF. The samples
    are those of the Latin-1 test."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "L", "T", unit="m/s**2")
    write_mme(analytic, tmp_path / "U", "T", unit="m/s**2")
    ref, listed = read_mme(tmp_path / "L"), mme_channels(tmp_path / "L")
    bom, encoding = {"utf-16": (b"\xff\xfe", "utf-16-le"), "utf-16-be": (b"\xfe\xff", "utf-16-be"),
                     "utf-32": (b"\xff\xfe\x00\x00", "utf-32-le")}[codec]  # fmt: skip
    unit = len("x".encode(encoding))  # bytes per character: 2 or 4
    for f in [tmp_path / "U" / "T.mme", *sorted((tmp_path / "U" / "Channel").glob("T.*"))]:
        first, _, text = f.read_text(encoding="latin-1").replace(":m/s**2", ":m/s²").partition("\n")
        data = bom + (first + "\r\n").encode(encoding)
        for end, at in (("\U0001d6f4 (Σ)\n", 16384), ("\r\n", 32768)):  # where the 16 KiB chunks end
            comment = "Comments                    :Prüfung "
            fill = (at - unit - len(data) - len(comment.encode(encoding))) // unit
            data += (comment + "Σ" * fill + end).encode(encoding)
            assert data[at - unit : at + unit].decode(encoding) in ("\U0001d6f4", "\U0001d6f4 ", "\r\n")
        f.write_bytes(data + text.encode(encoding))
    got = read_mme(tmp_path / "U")
    assert got.channels == ref.channels and np.array_equal(got.acc, ref.acc) and np.array_equal(got.time, ref.time)
    assert [(c["name"], c["unit"]) for c in mme_channels(tmp_path / "U")] == [(c["name"], "m/s²") for c in listed]


def test_an_iso_mme_file_in_utf16_without_byte_order_mark_or_broken_is_refused_naming_it(tmp_path, analytic):
    """UTF-16 without a byte-order mark cannot be told from other text by its bytes alone; ISO-MME headers start with
    a Latin letter, so a NUL byte after it is UTF-16's. Refused naming the file and the encodings read, where it was
    "missing header line 'Unit'"; a file whose byte-order mark says UTF-16 but whose bytes are not is refused alike."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    ch = tmp_path / "T" / "Channel" / "T.002"
    text = ch.read_text(encoding="latin-1")
    for codec in ("utf-16-le", "utf-16-be"):
        ch.write_bytes(text.encode(codec))
        said = r"T\.002: looks like UTF-16 text without a byte-order mark .*expected Latin-1 or UTF-8"
        with pytest.raises(PulseError, match=said):
            read_mme(tmp_path / "T")
        with pytest.raises(PulseError, match=said):
            mme_channels(tmp_path / "T")
    ch.write_bytes(text.encode("utf-16") + b"\x00")  # an odd number of bytes
    said = r"T\.002: starts with a UTF-16 byte-order mark but is not UTF-16 text \(truncated data\)"
    with pytest.raises(PulseError, match=said):
        read_mme(tmp_path / "T")
    ch.write_bytes(text.encode("utf-16")[:60] + b"\x00\xd8" + text.encode("utf-16")[60:])  # a lone surrogate
    with pytest.raises(PulseError, match=r"T\.002: starts with a UTF-16 byte-order mark but is not UTF-16 text"):
        mme_channels(tmp_path / "T")


def test_write_mme_writes_a_channel_code_only_where_the_name_is_one(tmp_path, analytic):
    """An ISO-MME channel code is 16 characters (test object, position, main and fine locations, physical dimension,
    direction, filter class: ``11HEAD0000H3ACXP``). ``write_mme`` wrote every channel's name as its 'Channel code'
    ('tunnel', '10VEHC0000ACXP'), an invalid code in a file that claims to be ISO-MME, which a reader of codes takes
    apart by position. A name that is a code (16 capital letters and digits, as a pulse read from a test is named) is
    written as such, any other name only as 'Name of the channel', the code as NOVALUE (ISO-MME's "not given": where
    the sensor sat is not known to write_mme). ``read_mme`` names the channels as before."""
    from marlcrash.pulse import mme_channels

    names = ("tunnel", "10VEHC0000ACXP", "11HEAD0000H3ACXP")  # a name, a 14-character near-code, a code
    write_mme(Pulse(analytic.time, np.stack([analytic.acc[0]] * 3), names), tmp_path / "T", "T")
    codes = []
    for k in (1, 2, 3):
        head = (tmp_path / "T" / "Channel" / f"T.00{k}").read_text(encoding="latin-1").splitlines()
        codes += [line.partition(":")[2] for line in head if line.startswith("Channel code ")]
    assert codes == ["NOVALUE", "NOVALUE", "11HEAD0000H3ACXP"]
    assert all(len(c) == 16 for c in codes if c != "NOVALUE")
    assert read_mme(tmp_path / "T").channels == names
    assert [(c["code"], c["name"]) for c in mme_channels(tmp_path / "T")] == [
        ("", "tunnel"), ("", "10VEHC0000ACXP"), ("11HEAD0000H3ACXP", "11HEAD0000H3ACXP")]  # fmt: skip
    assert read_mme(tmp_path / "T", channels="10vehc0000acxp").channels == ("10VEHC0000ACXP",)  # by its name


@pytest.mark.parametrize("left", ["T.003", "T.0002", "t.001"])  # T.000: ..._numbered_zero_is_no_channel
def test_write_mme_refuses_a_folder_whose_other_channel_files_would_be_read_as_this_test(tmp_path, analytic, left):
    """``write_mme`` over a test of the same name wrote its channel files and left the others: a 2-channel pulse
    written where a 3-channel test was read back with 3 channels, the third the old test's, without a word; a
    ``T.0002`` (or ``t.001`` beside ``T.001``) left there made the test unreadable (two files for one channel). Such a
    file is refused, named, before anything is written; a test written over one of the same channels is fine. The
    test's channel folder is the one ``read_mme`` reads, in whatever case it is spelled."""
    three = Pulse(analytic.time, np.stack([*analytic.acc, analytic.acc[0]]), ("a", "b", "c"))
    write_mme(three, tmp_path / "T", "T")
    write_mme(three, tmp_path / "T", "T")  # over the same channels: fine
    chan = tmp_path / "T" / "Channel"
    if left == "t.001" and (chan / left).exists():
        pytest.skip("a file system that ignores case: t.001 is T.001")
    (chan / "T.003").rename(chan / left)
    before = {p.name: p.read_bytes() for p in (tmp_path / "T").rglob("*") if p.is_file()}
    with pytest.raises(PulseError, match=rf"write_mme: the Channel folder holds {re.escape(left)}, which read_mme "
                       r"would read as a channel of test 'T' \(the pulse has 2 channels\); remove it"):  # fmt: skip
        write_mme(analytic, tmp_path / "T", "T")
    assert {p.name: p.read_bytes() for p in (tmp_path / "T").rglob("*") if p.is_file()} == before
    (chan / left).unlink()
    write_mme(analytic, tmp_path / "T", "T")
    assert read_mme(tmp_path / "T").channels == analytic.channels
    chan.rename(tmp_path / "T" / "CHANNEL")  # the folder as another tool spells it
    write_mme(analytic, tmp_path / "T", "T")
    assert [p.name for p in (tmp_path / "T").iterdir() if p.is_dir()] == ["CHANNEL"]
    assert read_mme(tmp_path / "T").channels == analytic.channels


@pytest.mark.parametrize("other", ["A.mme", "t.MME"])
def test_write_mme_refuses_a_folder_holding_the_mme_file_of_another_test(tmp_path, analytic, other):
    """A test folder holds one test: ``read_mme`` of the folder takes its one ``.mme`` file. ``write_mme`` of test
    ``T`` into a folder holding ``A.mme`` (or ``t.MME``, test T as another tool spells it) wrote ``T.mme`` beside
    it, a folder that ``read_mme`` refused ("expected exactly one <test>.mme file"). It is refused before anything is
    written, naming the file; a test written over its own ``.mme`` file is fine."""
    write_mme(analytic, tmp_path / "T", "T")
    mme = tmp_path / "T" / "T.mme"
    if other == "t.MME" and mme.with_name(other).exists():
        pytest.skip("a file system that ignores case: t.MME is T.mme")
    mme.rename(mme.with_name(other))
    before = {p.name: p.read_bytes() for p in (tmp_path / "T").rglob("*") if p.is_file()}
    with pytest.raises(PulseError, match=rf"write_mme: the test folder holds {re.escape(other)}, the \.mme file of "
                       r"a test beside the T\.mme it writes; read_mme reads a test folder of one test: remove it or "
                       "write the test to another folder"):  # fmt: skip
        write_mme(analytic, tmp_path / "T", "T")
    assert {p.name: p.read_bytes() for p in (tmp_path / "T").rglob("*") if p.is_file()} == before
    mme.with_name(other).rename(mme)
    write_mme(analytic, tmp_path / "T", "T")
    assert read_mme(tmp_path / "T").channels == analytic.channels


def test_an_iso_mme_test_folder_with_two_channel_folders_is_refused_naming_both(tmp_path, analytic):
    """The channel folder is found in any case ('Channel', 'CHANNEL'). A test folder holding two ('Channel' and
    'channel', as another tool wrote it beside) was read from whichever the file system listed first, the other
    passed over without a word. Refused naming both, by ``read_mme`` and ``write_mme`` (before writing anything)."""
    import shutil

    write_mme(analytic, tmp_path / "T", "T")
    if (tmp_path / "T" / "channel").exists():
        pytest.skip("a file system that ignores case: 'channel' is 'Channel'")
    shutil.copytree(tmp_path / "T" / "Channel", tmp_path / "T" / "channel")
    said = r"T\.mme: the test folder holds two channel folders, 'Channel' and 'channel'; keep one"
    with pytest.raises(PulseError, match=said):
        read_mme(tmp_path / "T")
    with pytest.raises(PulseError, match=said):
        read_mme(tmp_path / "T" / "T.mme")
    with pytest.raises(PulseError, match=r"write_mme: T: the test folder holds two channel folders, 'Channel' and"):
        write_mme(analytic, tmp_path / "T", "T")


def test_an_iso_mme_channel_header_longer_than_200_lines_is_listed_as_read(tmp_path, analytic):
    """A channel header is every ``Name :value`` line before the first sample, however many comment lines it holds.
    ``mme_channels`` parsed the first 200 lines only, so a channel with 250 comment lines before its 'Unit' was
    listed with no unit and no name (not an acceleration), while ``read_mme`` read it whole as one."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    expected = mme_channels(tmp_path / "T")
    chan = tmp_path / "T" / "Channel" / "T.001"
    comments = "".join(f"Comments                    :rig note {i}\n" for i in range(250))
    chan.write_text(comments + chan.read_text(encoding="latin-1"), encoding="latin-1")
    assert mme_channels(tmp_path / "T") == expected
    assert read_mme(tmp_path / "T").channels == analytic.channels


@pytest.mark.parametrize("zero", ["T.000", "T.0000", "T.00"])
def test_an_iso_mme_file_numbered_zero_is_no_channel(tmp_path, analytic, zero):
    """ISO-MME numbers channel files from 001. A ``<test>.000`` beside them was read as channel 0, before channel 1:
    listed first, read by default as an acceleration (a time base differing from the others' refused the whole test)
    and taken by ``marlcrash pulse`` as the first acceleration channel. It is no channel, and is named in a warning;
    ``write_mme`` refuses a folder holding one saying so, not that it would be read as a channel."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    chan = tmp_path / "T" / "Channel"
    other = Pulse(analytic.time[:1000], analytic.acc[:1, :1000] * 2, ("stray",))
    write_mme(other, tmp_path / "S", "T")
    (tmp_path / "S" / "Channel" / "T.001").rename(chan / zero)
    said = rf"T\.mme: {re.escape(zero)} is no channel file \(ISO-MME numbers them from 001\); not read"
    with pytest.warns(UserWarning, match=said):
        assert [c["file"].name for c in mme_channels(tmp_path / "T")] == ["T.001", "T.002"]
    with pytest.warns(UserWarning, match=said):
        back = read_mme(tmp_path / "T")
    assert back.channels == analytic.channels
    np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)
    with pytest.warns(UserWarning, match=said):
        assert pulse_summary(tmp_path / "T")["channel"] == "tunnel"
    no_channel = r"which is no channel file \(ISO-MME numbers them from 001\) and read_mme would warn about; remove it"
    with pytest.raises(PulseError, match=rf"write_mme: the Channel folder holds {re.escape(zero)}, {no_channel}"):
        write_mme(analytic, tmp_path / "T", "T")


def test_write_mme_that_fails_midway_leaves_the_folder_as_it_was(tmp_path, analytic, monkeypatch):
    """``write_mme`` wrote the ``.mme`` file, the channel list and the channel files one by one into the folder: a
    disk that filled up at the second channel left a test whose ``.mme`` and first channel were there, which
    ``read_mme`` read as a one-channel test. The test is written beside the folder and moved into place whole: a
    failure leaves a new folder absent, an existing one as it was, and no temporary file or folder behind."""
    import errno
    import pathlib

    def tree(root: Path) -> dict[str, bytes | None]:
        return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in sorted(root.rglob("*"))}

    old = Pulse(analytic.time[:500], analytic.acc[:, :500] * 0.5, ("old a", "old b"))
    write_mme(old, tmp_path / "same", "T")  # an earlier run of the test, written over
    (tmp_path / "other").mkdir()  # a test folder holding a report only, no channel folder yet
    (tmp_path / "other" / "report.txt").write_text("kept\n")
    before = tree(tmp_path)
    path_open = pathlib.Path.open

    def full_disk(self, mode="r", *args, **kwargs):
        if "002" in self.name and "w" in mode:
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return path_open(self, mode, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "open", full_disk)
    for folder in ("new", "same", "other"):
        with pytest.raises(OSError, match="No space left on device"):
            write_mme(analytic, tmp_path / folder, "T")
        assert tree(tmp_path) == before, folder
    monkeypatch.undo()
    for folder in ("new", "same", "other"):
        write_mme(analytic, tmp_path / folder, "T")
        back = read_mme(tmp_path / folder)
        assert back.channels == analytic.channels
        np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)
    assert (tmp_path / "other" / "report.txt").read_text() == "kept\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new", "other", "same"]
    assert sorted(p.name for p in (tmp_path / "same").iterdir()) == ["Channel", "T.mme"]


@pytest.mark.parametrize("failing", [1, 2, 3, 4])
def test_write_mme_whose_renames_fail_midway_puts_back_the_files_it_replaced(tmp_path, analytic, monkeypatch, failing):
    """Into an existing test folder, ``write_mme`` moved its files into place one by one (the channel list, each
    channel file, then the ``.mme`` file): a rename that failed midway (``os.replace`` refused, the disk went away)
    left the new channel list and first channels beside the old others and the old ``.mme`` file, a test of mixed
    runs that ``read_mme`` read without a word. The files replaced are put back: the folder is as it was, and no
    temporary file or folder is left behind."""
    import errno
    import os

    def tree(root: Path) -> dict[str, bytes | None]:
        return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in sorted(root.rglob("*"))}

    old = Pulse(analytic.time[:500], analytic.acc[:, :500] * 0.5, ("old a", "old b"))
    write_mme(old, tmp_path / "same", "T")  # an earlier run of the test, written over: 4 files replaced
    (tmp_path / "other").mkdir()  # a test folder without a channel folder: the folder moved, then the .mme file
    (tmp_path / "other" / "report.txt").write_text("kept\n")
    before = tree(tmp_path)
    os_replace, calls = os.replace, []

    def fails(src, dst, *args, **kwargs):
        calls.append(dst)
        if len(calls) == failing:
            raise OSError(errno.EIO, "Input/output error", str(dst))
        return os_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", fails)
    for folder in ("same", "other") if failing == 1 else ("same",):
        calls.clear()
        with pytest.raises(OSError, match="Input/output error"):
            write_mme(analytic, tmp_path / folder, "T")
        assert tree(tmp_path) == before, folder
    monkeypatch.undo()
    back = read_mme(tmp_path / "same")
    assert back.channels == old.channels
    np.testing.assert_allclose(back.acc, old.acc, rtol=1e-12, atol=1e-9)
    write_mme(analytic, tmp_path / "same", "T")
    assert read_mme(tmp_path / "same").channels == analytic.channels


def _reading_and_listing_refuse(test, match):
    """Both ways into an ISO-MME test, reading it and listing its channels, refuse it with the same message."""
    from marlcrash.pulse import mme_channels

    with pytest.raises(PulseError, match=match):
        read_mme(test)
    with pytest.raises(PulseError, match=match):
        mme_channels(test)


def _three_channel_test(tmp_path: Path, analytic: Pulse) -> Path:
    three = Pulse(analytic.time, np.stack([*analytic.acc, analytic.acc[0]]), ("tunnel", "radsup", "11HEADCG0000ACXP"))
    write_mme(three, tmp_path / "T", "T")
    return tmp_path / "T" / "Channel"


def test_an_iso_mme_channel_list_names_what_its_channel_files_do_not(tmp_path, analytic):
    """``<test>.chn`` lists the channels of the test, ``Name of channel 001 :<code> / <name>`` as labs write it. It was
    never read: a channel file without 'Name of the channel' and 'Channel code' was named by its file, ``T.001``, and
    could not be chosen by the name its test gives it. The list names it now; a channel file's own names come first."""
    from marlcrash.pulse import mme_channels

    chan = _three_channel_test(tmp_path, analytic)
    _edit(chan / "T.001", "Name of the channel         :tunnel\n", "")
    _edit(chan / "T.chn", "channel 001         :tunnel", "channel 001         :10TUNNCG0000ACXP / Tunnel X")
    _edit(chan / "T.chn", "channel 003         :11HEADCG0000ACXP", "channel 003         :11CHSTCG0000ACXP / C")
    listed = mme_channels(tmp_path / "T")
    assert [(c["code"], c["name"]) for c in listed] == [("10TUNNCG0000ACXP", "Tunnel X"), ("", "radsup"),
                                                        ("11HEADCG0000ACXP", "11HEADCG0000ACXP")]  # fmt: skip
    assert read_mme(tmp_path / "T").channels == ("10TUNNCG0000ACXP", "radsup", "11HEADCG0000ACXP")
    one = read_mme(tmp_path / "T", channels="tunnel x")
    assert one.channels == ("10TUNNCG0000ACXP",)
    np.testing.assert_allclose(one.acc[0], analytic.acc[0], rtol=1e-12, atol=1e-9)
    (chan / "T.chn").unlink()  # a test without a channel list is read as before, without a word
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_mme(tmp_path / "T").channels == ("T.001", "radsup", "11HEADCG0000ACXP")


def test_an_iso_mme_channel_list_and_its_channel_files_must_agree(tmp_path, analytic):
    """A channel file the list does not hold (``T.003`` left from an earlier test, beside a list of two) was read as
    a channel of the test; it is refused now, naming the list, its line and the file. A channel listed whose file is
    missing is named in a warning, and the test read without it. A list that says one count and lists another, or
    no number, is refused naming its line."""
    from marlcrash.pulse import mme_channels

    chan = _three_channel_test(tmp_path, analytic)
    listing = (chan / "T.chn").read_text(encoding="latin-1")
    _edit(chan / "T.chn", "Number of channels          :3", "Number of channels          :2")
    _edit(chan / "T.chn", "Name of channel 003         :11HEADCG0000ACXP\n", "")
    unlisted = (r"T\.chn line 2: the Channel folder holds T\.003, a channel file the channel list does not hold "
                r"\(it lists 2 channels\); remove it, or list it in T\.chn")  # fmt: skip
    _reading_and_listing_refuse(tmp_path / "T", unlisted)
    (chan / "T.chn").write_text(listing, encoding="latin-1")
    (chan / "T.002").unlink()
    missing = r"T\.chn line 4: lists channel 002 \('radsup'\), but the Channel folder holds no T\.002; read without it"
    with pytest.warns(UserWarning, match=missing):
        assert read_mme(tmp_path / "T").channels == ("tunnel", "11HEADCG0000ACXP")
    with pytest.warns(UserWarning, match=missing):
        assert [c["file"].name for c in mme_channels(tmp_path / "T")] == ["T.001", "T.003"]
    for old, new, said in (
        (":3", ":two", r"2: 'Number of channels': expected a whole number, got 'two'"),
        (":3", ":\u00b3", r"2: 'Number of channels': expected a whole number, got '\u00b3'"),  # isdigit, no int
        (":3", ":4", r"2: 'Number of channels' says 4, the list names 3 channels"),
        ("channel 002", "channel 001", r"4: channel 001 is listed twice, on lines 3 and 4"),
    ):
        (chan / "T.chn").write_text(listing.replace(old, new), encoding="latin-1")
        with pytest.raises(PulseError, match=r"T\.chn line " + said):
            read_mme(tmp_path / "T")


def test_an_iso_mme_channel_folder_with_two_channel_lists_is_refused(tmp_path, analytic):
    """``T.chn`` and ``t.CHN`` (another tool's spelling) beside it: which lists the channels is not known. Refused
    naming both by ``read_mme``, and by ``write_mme`` before it writes ``T.chn`` beside the other."""
    write_mme(analytic, tmp_path / "T", "T")
    chan = tmp_path / "T" / "Channel"
    if (chan / "t.CHN").exists():
        pytest.skip("a file system that ignores case: t.CHN is T.chn")
    (chan / "T.chn").rename(chan / "t.CHN")
    assert read_mme(tmp_path / "T").channels == analytic.channels  # found in any case
    with pytest.raises(PulseError, match=r"write_mme: the Channel folder holds t\.CHN, a channel list of test 'T' "
                       r"beside the T\.chn it writes; remove it"):  # fmt: skip
        write_mme(analytic, tmp_path / "T", "T")
    (chan / "T.chn").write_bytes((chan / "t.CHN").read_bytes())
    with pytest.raises(PulseError, match=r"Channel: the folder holds two channel lists of test 'T', T\.chn and t\.CHN"):
        read_mme(tmp_path / "T")


@pytest.mark.parametrize("where", ["afile", "afile/T"])
def test_write_mme_to_a_file_is_refused_naming_it(tmp_path, analytic, where):
    """A test folder that is a file, or inside one, was an OSError naming a temporary folder beside it
    (``.afile.<hex>.tmp -> afile: Not a directory``) or the file without saying what was expected; now a
    :class:`PulseError` naming the file, before anything is written."""
    (tmp_path / "afile").write_text("x")
    with pytest.raises(PulseError, match=r"write_mme: .*afile is a file; expected a test folder"):
        write_mme(analytic, tmp_path / where, "T")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_read_pulse_refuses_csv_time_options_for_an_iso_mme_test():
    """``read_pulse`` (a ``kind: file`` reference's reader) dropped ``time_unit`` and ``time_col`` for an ISO-MME test
    without a word, where it refuses ``unit``: a reference given ``time_unit: ms`` for a test was read in seconds
    as if nothing had been said. Refused, naming the option; the defaults pass."""
    with pytest.raises(PulseError, match=r"HS40: ISO-MME channels carry their own time base .*; do not pass "
                       r"time_unit='ms'"):  # fmt: skip
        read_pulse(DATA / "HS40", time_unit="ms")
    with pytest.raises(PulseError, match=r"HS40: ISO-MME channels carry their own time base .*; do not pass "
                       r"time_col='zeit'"):  # fmt: skip
        read_pulse(DATA / "HS40", time_col="zeit")
    assert read_pulse(DATA / "HS40", time_unit="s", time_col=None, unit="g").n_channels == 2


def test_read_mme_of_no_channels_is_a_clear_error():
    """``channels=[]`` (an empty selection, as a list built from a filter that matched nothing) was an IndexError
    from inside ``read_mme``; now a PulseError saying what was expected."""
    with pytest.raises(PulseError, match=r"channels: expected at least one channel name, got \[\]"):
        read_mme(DATA / "HS40", channels=[])
    with pytest.raises(PulseError, match=r"acc_col: expected at least one channel name, got \(\)"):  # as typed
        read_pulse(DATA / "HS40", acc_col=())


def test_read_csv_of_no_acceleration_columns_is_a_clear_error(tmp_path, analytic):
    """``acc_col=[]`` (an empty selection) returned a pulse of no channels, which failed later far from the option;
    now a PulseError naming the option and what was expected, as ``read_mme`` does for ``channels=[]``."""
    path = write_csv(analytic, tmp_path / "p.csv")
    with pytest.raises(PulseError, match=r"acc_col: expected at least one column name, got \[\]"):
        read_csv(path, acc_col=[])
    with pytest.raises(PulseError, match=r"acc_col: expected at least one column name, got \(\)"):
        read_pulse(path, acc_col=())
    assert read_csv(path, acc_col=["radsup"]).channels == ("radsup",)


def test_a_trailing_delimiter_on_every_line_is_an_empty_column_that_is_ignored(tmp_path, analytic):
    """Some lab exports end every line with the delimiter (``time;acc;`` / ``0,001;2,3;``): the file was refused with
    "header column 3 is empty". A trailing column empty in the header and in every row is no column; an empty header
    column with data under it is still refused, naming the line and the column."""
    rows = [f"{t:.4f};{a / G0:.6f};".replace(".", ",") for t, a in zip(analytic.time, analytic.acc[0], strict=True)]
    path = tmp_path / "lab.csv"
    path.write_text("time;acc;\n" + "\n".join(rows) + "\n")
    p = read_csv(path)
    assert p.channels == ("acc",) and p.n_samples == analytic.n_samples
    np.testing.assert_allclose(p.acc[0], analytic.acc[0], atol=1e-5 * G0)
    assert read_pulse(path, acc_col="acc").channels == ("acc",)
    # two trailing delimiters, and rows that end without it, alike
    path.write_text("time,acc,,\n" + "".join(f"{i * 1e-4:.4f},{-float(i)}{',,' if i % 2 else ''}\n"
                                             for i in range(20)))  # fmt: skip
    assert read_csv(path).channels == ("acc",)
    # data under the empty name is refused, naming where
    rows[40] = rows[40] + "7"
    path.write_text("time;acc;\n" + "\n".join(rows) + "\n")
    with pytest.raises(PulseError, match=r"lab\.csv line 42: column 3 has no name in the header but holds '7'"):
        read_csv(path)
    path.write_text("time;;acc\n" + "\n".join(rows) + "\n")  # an empty name before the last is refused as before
    with pytest.raises(PulseError, match=r"lab\.csv line 1: header column 2 is empty"):
        read_csv(path)
    path.write_text("0;1;\n" + "\n".join(rows) + "\n")  # a header of numbers is no header, trailing ';' or not
    with pytest.raises(PulseError, match=r"lab\.csv line 1: expected a header row naming the columns"):
        read_csv(path)


@pytest.mark.parametrize(("kwargs", "key"), [({"acc_col": 1}, "acc_col"), ({"acc_col": ["acc", 2]}, "acc_col"),
                                             ({"time_col": 0}, "time_col")])  # fmt: skip
def test_a_column_given_by_number_is_refused_naming_the_option(tmp_path, kwargs, key):
    """Columns are chosen by name: ``read_csv(acc_col=1)`` raised ``TypeError: object of type 'int' has no len()``
    (and ``time_col=0`` an AttributeError from inside the reader)."""
    with pytest.raises(PulseError, match=rf"^{key}: expected a column name"):
        read_csv(_csv(tmp_path, "time,acc\n" + GOOD_ROWS), **kwargs)


def test_an_iso_mme_channel_given_by_number_is_refused_naming_the_option(tmp_path, analytic):
    write_mme(analytic, tmp_path / "B", "B")
    with pytest.raises(PulseError, match=r"^channels: expected a channel name"):
        read_mme(tmp_path / "B", channels=1)
    with pytest.raises(PulseError, match=r"^acc_col: expected a channel name"):
        read_pulse(tmp_path / "B", acc_col=[1])


@pytest.mark.parametrize("sign", [True, False, "1", 2])
def test_a_sign_that_is_not_plus_or_minus_one_is_refused(tmp_path, analytic, sign):
    """``sign=True`` was read as +1 (``True == 1``): a bool is not a sign (a flag like ``deceleration_positive``
    passed in its place would read every such file the wrong way round)."""
    path = write_csv(analytic, tmp_path / "a.csv")
    write_mme(analytic, tmp_path / "B", "B")
    for read in (read_csv, read_pulse):
        with pytest.raises(PulseError, match=r"^sign: expected \+1 or -1"):
            read(path, sign=sign)
    with pytest.raises(PulseError, match=r"^sign: expected \+1 or -1"):
        read_mme(tmp_path / "B", sign=sign)
    np.testing.assert_array_equal(read_csv(path, sign=np.float64(-1.0)).acc, -read_csv(path).acc)  # a numpy -1 is


@pytest.mark.parametrize("acc_col", [["tunnel", "radsup"], ("radsup",), 1])
def test_processed_pulse_takes_one_channel_by_name(tmp_path, analytic, acc_col):
    """:func:`processed_pulse` prepares one channel (``acc_col``: the channel); a list of two was read and all but its
    first silently dropped (and 1 raised a TypeError from inside the reader)."""
    from marlcrash.pulse.io import processed_pulse

    for path in (write_csv(analytic, tmp_path / "a.csv"), write_mme(analytic, tmp_path / "M", "M").parent):
        with pytest.raises(PulseError, match=r"^acc_col: expected one channel name .*got "):
            processed_pulse(path, acc_col=acc_col)
        with pytest.raises(PulseError, match=r"^acc_col: expected one channel name"):
            pulse_summary(path, acc_col=acc_col)
    assert processed_pulse(tmp_path / "a.csv", acc_col="radsup")[0].channels == ("radsup",)


def test_an_iso_mme_number_of_channels_must_agree_with_its_channel_files(tmp_path, analytic):
    """The test's ``<test>.mme`` says how many channels it has (``Number of channels``). It was read for nothing: a
    ``T.003`` left from an earlier test beside a test of two channels without a channel list was read as its third
    channel. The count is checked as the channel list is: a channel file it does not count is refused, naming the
    ``.mme`` file and line; a channel it counts whose file is missing is named in a warning; a count that is no whole
    number, or that differs from the channel list's, is refused naming its line."""

    chan = _three_channel_test(tmp_path, analytic)
    mme = tmp_path / "T" / "T.mme"
    (chan / "T.chn").unlink()  # the count of the .mme file is all the test says of its channels
    _edit(mme, "Number of channels          :3", "Number of channels          :2")
    unlisted = (r"T\.mme line 4: the Channel folder holds T\.003, a channel file the test does not count \('Number "
                r"of channels' says 2\); remove it, or count it in T\.mme")  # fmt: skip
    _reading_and_listing_refuse(tmp_path / "T", unlisted)
    _edit(mme, "Number of channels          :2", "Number of channels          :4")
    missing = r"T\.mme line 4: counts channel 004, but the Channel folder holds no T\.004; read without it"
    with pytest.warns(UserWarning, match=missing):
        assert read_mme(tmp_path / "T").channels == ("tunnel", "radsup", "11HEADCG0000ACXP")
    for value, said in (
        ("two", "expected a whole number, got 'two'"),
        ("\u00b3", "expected a whole number, got '\u00b3'"),
    ):
        _edit(mme, "Number of channels          :4", f"Number of channels          :{value}")
        with pytest.raises(PulseError, match=rf"T\.mme line 4: 'Number of channels': {said}"):
            read_mme(tmp_path / "T")
        _edit(mme, f"Number of channels          :{value}", "Number of channels          :4")
    _edit(mme, "Number of channels          :4", "Number of channels          :NOVALUE")  # not given
    assert read_mme(tmp_path / "T").channels == ("tunnel", "radsup", "11HEADCG0000ACXP")
    _three_channel_test(tmp_path, analytic)  # with the channel list, the two counts must agree
    _edit(mme, "Number of channels          :3", "Number of channels          :2")
    with pytest.raises(
        PulseError, match=r"T\.mme line 4: 'Number of channels' says 2, the channel list T\.chn lists 3"
    ):
        read_mme(tmp_path / "T")


@pytest.mark.parametrize("short", ["T.01", "T.1"])
def test_an_iso_mme_channel_file_numbered_with_fewer_than_three_digits_is_read(tmp_path, analytic, short):
    """A channel file ``T.01`` (or ``T.1``), as a tool that does not pad the number to three digits writes it, was
    passed over (without a word where the test gives no channel list or count): the test was read without its first
    channel. It is channel 1, read as ``T.001`` is (two files for one number, ``T.01`` beside ``T.001``, are refused as
    before)."""
    from marlcrash.pulse import mme_channels

    write_mme(analytic, tmp_path / "T", "T")
    chan = tmp_path / "T" / "Channel"
    (chan / "T.001").rename(chan / short)
    (chan / "T.chn").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert [c["file"].name for c in mme_channels(tmp_path / "T")] == [short, "T.002"]
        back = read_mme(tmp_path / "T")
    assert back.channels == analytic.channels
    np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)
    assert read_mme(tmp_path / "T", channels=short).channels == ("tunnel",)


def test_the_unit_suffix_simulate_writes_is_read_as_the_header_unit(tmp_path):
    """``marlcrash simulate --csv`` names its columns ``time_s``, ``<sensor>_acc_g``, ``<sensor>_vel_ms``; the reader
    knew only bracketed units (``acc [g]``), so reading that file with ``unit='m/s2'`` (``--unit m/s2``) took its g
    for m/s^2 without a word (9.81x too small). The library's own suffixes are now the header's unit: read without a
    unit the file gives the simulated acceleration in SI, and a unit that contradicts the suffix is refused, naming
    the column and both units, as for a bracketed one."""
    from sim_fixtures import chain

    from marlcrash.pulse.simulation import write_crash_csv
    from marlcrash.sim import Surrogate, get_scenario

    cells = chain(3)
    params = torch.as_tensor(cells.params, dtype=torch.float64)[None]
    result = Surrogate(cells).run(
        params, get_scenario("full_width_40", {"duration": 0.02}), backend="torch", record_cells="none"
    )
    path = write_crash_csv(result, tmp_path / "out.csv")
    sensor = result.sensor_names[0]
    back = read_csv(path, acc_col=f"{sensor}_acc_g")
    np.testing.assert_allclose(back.time, result.time.numpy(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.acc[0], result.acceleration[0, 0].numpy(), rtol=1e-12, atol=1e-9)
    with pytest.raises(PulseError, match=rf"out\.csv line 1: column '{sensor}_acc_g' is in g by its header, but is "
                                         r"read in m/s2: give that unit \(--unit g; unit: g\)"):  # fmt: skip
        read_csv(path, acc_col=f"{sensor}_acc_g", unit="m/s2")
    with pytest.raises(PulseError, match=r"column 'time_s' is in s by its header, but is read in ms"):
        read_csv(path, acc_col=f"{sensor}_acc_g", time_unit="ms")


@pytest.mark.parametrize(
    ("header", "kwargs", "message"),
    [
        ("time_ms,acc_g", {}, r"column 'time_ms' is in ms by its header, but is read in s"),
        ("time,tunnel_acc_ms2", {}, r"column 'tunnel_acc_ms2' is in m/s2 by its header, but is read in g"),
        ("time,tunnel_acc_m_s2", {}, r"column 'tunnel_acc_m_s2' is in m/s2 by its header, but is read in g"),
        ("Time_S,Tunnel_Acc_G", {"unit": "m/s2"}, r"column 'Tunnel_Acc_G' is in g by its header, but is read in m/s2"),
    ],
)
def test_a_unit_suffix_that_contradicts_the_unit_read_is_refused(tmp_path, header, kwargs, message):
    path = tmp_path / "p.csv"
    path.write_text(header + "\n" + "\n".join(f"{k * 1e-4:.4f},{-20.0 * (k % 7)}" for k in range(60)) + "\n")
    with pytest.raises(PulseError, match=message):
        read_csv(path, **kwargs)


@pytest.mark.parametrize(
    "header", ["time,fuel_g", "time,radsup_ms2", "time,mass_s", "runtime_ms,acc", "t,acceleration_g", "time,acc_ms"]
)
def test_a_name_that_merely_ends_like_a_unit_is_no_header_unit(tmp_path, header):
    """Only the library's own patterns (``time_<s|ms>``, ``[<sensor>_]acc_<g|ms2|m_s2|mm_s2>``) give a unit: other
    names ending in ``_g``, ``_s``, ``_ms2`` ... read in the unit asked for, refused or warned about by nothing."""
    path = tmp_path / "p.csv"
    path.write_text(header + "\n" + "\n".join(f"{k * 1e-4:.4f},{-20.0 * (k % 7)}" for k in range(60)) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_csv(path, unit="m/s2")
        read_csv(path, unit="g")


def test_write_csv_rewrites_a_unit_suffix_to_the_unit_it_writes(tmp_path, analytic):
    """A channel read from a simulate CSV keeps its name (``tunnel_acc_g``); written in m/s^2 under that name, the
    header would say g of m/s^2 values. The suffix is written as the unit written, and the file reads back."""
    named = Pulse(analytic.time, analytic.acc, ("tunnel_acc_g", "radsup_acc_g"))
    path = write_csv(named, tmp_path / "p.csv", unit="m/s2", time_col="time_ms")
    assert path.read_text().splitlines()[0] == "time_s,tunnel_acc_ms2,radsup_acc_ms2"
    back = read_csv(path, unit="m/s2")
    np.testing.assert_allclose(back.acc, analytic.acc, rtol=1e-12, atol=1e-9)


def test_read_csv_leaves_out_the_columns_whose_header_says_they_hold_no_acceleration(tmp_path):
    """``read_csv`` of a ``marlcrash simulate --csv`` file read its ``<sensor>_vel_ms`` velocities and ``crush_m``
    as accelerations in g (six channels for three sensors, a "pulse" of 11 m/s = 11 g). Without ``acc_col`` the
    columns a header marks as velocity, length or time are left out, also for ``marlcrash pulse`` (the first
    acceleration column); named, such a column is refused (it was read as accelerations), and a file of none is a
    clear error."""
    t = np.arange(0, 0.02, 5e-4)
    acc = -20.0 * np.sin(np.pi * t / 0.02)
    rows = "".join(f"{x},{a},{11.1 + a * x},{0.4 * x}\n" for x, a in zip(t, acc, strict=True))
    sim = tmp_path / "sim.csv"
    sim.write_text("time_s,tunnel_acc_g,tunnel_vel_ms,crush_m\n" + rows)
    p = read_csv(sim)
    assert p.channels == ("tunnel_acc_g",)
    np.testing.assert_allclose(p.acc[0], acc * G0)
    with pytest.raises(PulseError, match=r"sim\.csv line 1: column 'tunnel_vel_ms' holds no acceleration"):
        read_csv(sim, acc_col="tunnel_vel_ms", unit="m/s2")
    lab = tmp_path / "lab.csv"
    lab.write_text("time [s],v_x [m/s],s_x (mm),a_x [g],remark\n" + rows.replace("\n", ",0\n"))
    assert read_csv(lab).channels == ("a_x [g]", "remark")
    for named in ("v_x [m/s]", "s_x (mm)"):
        with pytest.raises(PulseError, match=rf"lab\.csv line 1: column '{re.escape(named)}' holds no acceleration"):
            read_csv(lab, acc_col=["a_x [g]", named])
    assert read_csv(lab, first_only=True).channels == ("a_x [g]",)
    only = tmp_path / "only.csv"
    only.write_text("time_s,tunnel_vel_ms,crush_m\n" + "".join(f"{x},1,{x}\n" for x in t))
    with pytest.raises(PulseError, match=r"only\.csv line 1: no acceleration column: .*'tunnel_vel_ms', 'crush_m'"):
        read_csv(only)


@pytest.mark.parametrize("time_zero", ["file", "threshold"])
def test_a_record_uniform_within_its_tolerance_stays_uniform_when_led_in(tmp_path, time_zero):
    """Times written to 7 decimals at 12.8 kHz jitter by up to 0.96e-3 of the step: uniform within UNIFORM_RTOL, so
    not resampled. The 20 ms lead-in was spaced by the first step, which moved the mean step, and the led-in record
    was refused by the filter ("CFC filtering needs uniform sampling; resample first")."""
    fs, span = 12800.0, 0.06
    t = np.arange(int(0.1 * fs) + 1) / fs - 0.02
    acc_g = -20.0 * np.sin(np.pi * t / span) * ((t > 0) & (t < span))
    path = tmp_path / "jitter.csv"
    path.write_text("time,acc\n" + "".join(f"{a:.7f},{b:.6f}\n" for a, b in zip(t, acc_g, strict=True)))
    assert read_csv(path).is_uniform
    dv = 20.0 * G0 * 2 * span / np.pi  # the half-sine's velocity change
    s = pulse_summary(path, time_zero=time_zero)
    assert abs(s["delta_v_ms"]) == pytest.approx(dv, rel=2e-3)
    _, v = prepare_velocity(read_csv(path), cfc=60, time_zero=time_zero)
    assert float(v[0, 0] - v[0].min()) == pytest.approx(dv, rel=2e-3)
