"""Reading and writing crash pulses: CSV and ISO-MME, a summary and a plot.

Every reader returns a :class:`~marlcrash.pulse.signal.Pulse` in marlcrash's
convention (SI, forward speed, frontal crash pulse negative; see
:mod:`marlcrash.pulse.signal`). ``sign`` multiplies the acceleration on read:
``+1`` for data in the SAE J211 / ISO 6487 vehicle frame (x forward), ``-1`` for
data that records deceleration as positive.

CSV: an optional block of ``#`` comment lines, one header row, then one row per sample. Time in seconds
(``time_unit="ms"`` for milliseconds), acceleration in g (``unit="m/s2"`` for SI). Columns are chosen by name;
the delimiter (``,``, ``;`` or tab) is the one that splits the header and the first rows alike, or the one a first
line ``sep=;`` (Excel's) names; with ``;`` a decimal comma (``-2,5``) is read as a decimal point, and with tabs where
no comma can group thousands (``-0,25``, not only ``-1,005``). A delimiter ending the lines (``time;acc;``) adds no
column: a trailing column with no name in the header must be empty in every row. UTF-8, Windows-1252, or UTF-16/32
with its byte-order mark. A gap in the time column (``max_gap``) is reported as a warning: resampling bridges it with
a straight line. A table of breakpoints (a pulse given by its corners, e.g. a
trapezoid from a specification) is read with ``breakpoints=True``: at least two rows, no gap warning, and sampled
at :data:`BREAKPOINT_RATE_HZ` by linear interpolation, so it is filtered and integrated like a record.

ISO-MME (ISO/TS 13499): a test folder with ``<test>.mme`` and a ``Channel``
folder holding ``<test>.chn`` (the channel list) and one file per channel,
``<test>.001``, ``<test>.002``, ... (``<test>.1000`` follows ``<test>.999``, and a number written with fewer digits,
``<test>.01``, is read as the same channel; two files for one number, ``<test>.001`` and ``<test>.0001`` or
``<test>.01``, are refused as ambiguous; channels are numbered from 001, and a ``<test>.000`` is named in a warning,
not read). The channel list, where the test has one, is
checked against the channel files (one it does not list is refused, one it lists that is missing is named in a
warning), and its ``Name of channel 001 :<code> / <name>`` names a channel whose file gives no code or no name. The
``.mme`` file's ``Number of channels`` must agree with the list; without a list, the channel files are checked against
it as against a list of channels 001 to that count.
Each channel file starts with ``Name  :value`` header lines; the samples follow, one value per line. Latin-1 text
(written so), or UTF-8 as some tools write it: a line is read as UTF-8 where its bytes are UTF-8, else as Latin-1;
UTF-16 or UTF-32 with its byte-order mark (UTF-16 without one is refused, naming the file).
Time is ``Time of first sample + i * Sampling interval`` [s]; ``Unit`` gives the
acceleration unit (``g`` or ``m/s**2``). ``Channel frequency class`` is
information only: samples read from ISO-MME count as unfiltered.

Every malformed input raises :class:`~marlcrash.errors.PulseError` naming the
file, the line (and column) and what was expected.
"""

from __future__ import annotations

import codecs
import csv
import io
import math
import os
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from marlcrash.errors import PulseError, file_label
from marlcrash.outputs import atomic_output, save_figure
from marlcrash.pulse.signal import (
    DEFAULT_THRESHOLD_G,
    MIN_SAMPLES,
    PRE_IMPACT_TIME,
    Pulse,
    filtered_from_time_zero,
    on_record,
    without_zero_offset,
)
from marlcrash.units import G0


def _spellings(length: str, time: str) -> list[str]:
    """The spellings of ``length/time²`` a header or a channel file gives, spaces removed and in lower case (as
    :func:`acc_unit_key` makes them): ``m/s2``, ``m/s^2``, ``m s-2``, ``m·s⁻²``, ``m/sec2`` ..."""
    out = []
    for t in (time, "sec") if time == "s" else (time,):
        out += [f"{length}/{t}{sq}" for sq in ("2", "^2", "**2", "²")] + [f"{length}/({t}*{t})", f"{length}/{t}/{t}"]
        out += [f"{length}{dot}{t}{neg}" for dot in ("", ".", "·", "*") for neg in ("-2", "^-2", "⁻²")]
    return out


ACC_UNITS = {
    "g": G0,
    **dict.fromkeys([*_spellings("m", "s"), "mps2"], 1.0),
    **dict.fromkeys(_spellings("mm", "s"), 1e-3),
    **dict.fromkeys(_spellings("mm", "ms"), 1e3),  # the acceleration of the mm-ms-kg and mm-g-ms unit systems
}
"""SI factor of each acceleration unit spelling (normalized: :func:`acc_unit_key`); a factor's first spelling is the
one ``pulse --unit`` takes (:data:`ACC_UNIT_NAMES`)."""
ACC_UNIT_NAMES = list(dict.fromkeys(next(k for k, f in ACC_UNITS.items() if f == v) for v in ACC_UNITS.values()))
"""The first spelling of each acceleration unit: what messages list and ``pulse --unit`` takes."""
_OTHER_SPELLINGS = "; other spellings such as m/s^2, m s-2 or m/sec2 are read too"
_TIME_UNITS = {"s": 1.0, "ms": 1e-3}
_TIME_NAMES = ("time", "t", "zeit", "time_s", "time [s]", "time (s)")
MIN_GAP_S = 2.5e-3
"""Shortest time step :func:`read_csv` warns about as a gap [s] (when it is also ``max_gap`` median steps long): a
quarter period of CFC 60's 100 Hz -3 dB frequency. Jittered time stamps bridge shorter steps harmlessly; a data
logger's dropout of tens of ms is bridged by a straight line (a table of breakpoints wants exactly that)."""
MIN_RECORD_RATE_HZ = 500.0
"""Lowest sampling rate :func:`check_record_rate` accepts [Hz]. Crash accelerometers record at 10 kHz or more, and
CFC 60 itself needs about 600 Hz; a record at a few Hz is almost always a time column in ms read as seconds
(10 kHz in ms: 10 Hz), which would make every velocity change 1000x too large."""
MIN_RECORD_S = 1e-3
"""Shortest record :func:`check_record_rate` accepts [s]. A crash pulse lasts tens to hundreds of ms (a record
too short for its filter is accepted with a note); a record in seconds read as ms lasts 1000x less (150 ms: 0.15
ms)."""
MAX_RECORD_S = 10.0
"""Longest sampled record :func:`check_record_rate` accepts [s], as :data:`MAX_BREAKPOINT_SPAN_S` for tables: a
crash record with its pre-trigger part lasts well under a second; one in ms read as seconds lasts 1000x longer (an
LS-DYNA run in mm-ms-kg written every 2 us reads as 160 s at 500 Hz, its 150 ms window then 0.1 % of the pulse)."""
MAX_RECORD_RATE_HZ = 1e6
"""Highest sampling rate :func:`check_record_rate` accepts [Hz]: crash data loggers sample at 10-100 kHz; a record
in seconds read as ms samples 1000x faster (2 kHz: 2 MHz)."""
BREAKPOINT_RATE_HZ = 10_000.0
"""Rate a table of breakpoints (``read_csv(breakpoints=True)``) is sampled at [Hz]: a crash accelerometer's."""
MAX_BREAKPOINT_SPAN_S = 10.0
"""Longest table of breakpoints accepted [s]. A crash pulse lasts well under a second; a table in ms read as
seconds spans tens of seconds (and would give 1000x the velocity change)."""
_UNIT_HINT = "is the time column in ms (--time-unit ms; time_unit: ms)?"


def _number(text: str) -> float:
    """``text`` as a number the way a data file writes one: Python's ``float`` also reads digit groups with ``_``
    (``1_000``) and non-ASCII digits, which no spreadsheet or test system writes (a ``ValueError`` here)."""
    if "_" in text or not text.isascii():
        raise ValueError(f"not a number as a data file writes one: {text!r}")
    return float(text)


def _is_number(text: str) -> bool:
    try:
        _number(text.replace(",", "."))
    except ValueError:
        return False
    return True


def _located(reason: str, path: str | Path, line: int | None = None, column: str | None = None) -> str:
    """``<file> line <n>, column '<name>': <reason>``, the form of every message about an input file."""
    where = file_label(path) if line is None else f"{file_label(path)} line {line}"
    if column is not None:
        where += f", column {column!r}"
    return f"{where}: {reason}"


def _err(reason: str, path: str | Path, line: int | None = None, column: str | None = None) -> PulseError:
    return PulseError(_located(reason, path, line, column))


def acc_unit_key(unit: str) -> str:
    """The normalized spelling of an acceleration unit name, as :data:`ACC_UNITS` holds it (case and spaces)."""
    return unit.strip().lower().replace(" ", "")


_UNIT_AT_END = re.compile(r"([\[(])\s*([^\[\]()]+?)\s*([\])])\s*$")
"""A unit in brackets or parentheses at the end of a column name (``'a_x [m/s2]'``, ``'time (ms)'``)."""


_ACC_SUFFIXES = {"g": "g", "ms2": "m/s2", "m_s2": "m/s2", "mm_s2": "mm/s2"}
"""The unit each acceleration suffix of :data:`_UNIT_SUFFIX` stands for, in the spelling ``--unit`` takes."""
_TIME_SUFFIXES = {"s": "s", "ms": "ms"}
"""The unit each time suffix of :data:`_UNIT_SUFFIX` stands for."""
_UNIT_SUFFIX = re.compile(r"(?:(?:^|.*_)acc_(g|ms2|m_s2|mm_s2)|time_(s|ms))$", re.IGNORECASE)
"""A unit as the library writes it, an underscore suffix (``marlcrash simulate --csv``: ``time_s``,
``<sensor>_acc_g``): ``time_<s|ms>`` for a whole name, ``acc_<g|ms2|m_s2|mm_s2>`` for a whole name or the end of
one after an underscore. No other name ending in ``_g``, ``_s`` or ``_ms2`` is read as giving a unit (``fuel_g``,
``mass_s``, ``radsup_ms2``, ``runtime_ms``), nor ``<sensor>_vel_ms`` (m/s, no acceleration)."""


def _header_unit(name: str) -> str | None:
    """The unit a column name gives at its end: in brackets (:data:`_UNIT_AT_END`) as written, else as an underscore
    suffix of the library's own (:data:`_UNIT_SUFFIX`) in the spelling ``pulse --unit``/``--time-unit`` take,
    else ``None``."""
    m = _UNIT_AT_END.search(name)
    if m:
        return m.group(2)
    m = _UNIT_SUFFIX.fullmatch(name.strip())
    if m is None:
        return None
    return _ACC_SUFFIXES[m.group(1).lower()] if m.group(1) else _TIME_SUFFIXES[m.group(2).lower()]


_NOT_ACC_NAME = re.compile(r"(?:.*_)?vel_ms|crush_m", re.IGNORECASE)
"""The columns ``marlcrash simulate --csv`` writes beside the accelerations: ``<sensor>_vel_ms`` (m/s) and
``crush_m`` (m)."""
_NOT_ACC_UNITS = frozenset({"m/s", "km/h", "kph", "mph", "m", "cm", "mm", "s", "ms"})
"""Header units (lower case) of columns that hold no acceleration: velocities, lengths and times."""


def _not_acceleration(name: str) -> bool:
    """Column ``name`` holds no acceleration by its header: one of the library's velocity or crush columns
    (:data:`_NOT_ACC_NAME`), or a bracketed unit of velocity, length or time (``v_x [m/s]``, ``s (mm)``)."""
    if _NOT_ACC_NAME.fullmatch(name.strip()):
        return True
    said = _header_unit(name)
    return said is not None and said.strip().lower().replace(" ", "") in _NOT_ACC_UNITS


_UNIT_LIKE = re.compile(r"[^\W\d_]{2,3}|.*[/^²*].*")
"""What a bracketed header suffix must look like to be taken for a unit the reader does not know (``mg``, ``km/h``,
``ft/s2``, ``us``), not a remark (``(filtered)``, ``[CH1]``, ``(x)``)."""


_SI_LETTERS = frozenset({"N", "V", "W", "J", "K"})
"""One-letter SI unit symbols a header may give (force, voltage, ...), none an acceleration's; other single letters
in brackets are remarks (``acc (x)``)."""


def _gives_other_unit(said: str) -> bool:
    """A header unit ``said`` is a unit (:data:`_UNIT_LIKE`, not a remark such as ``(filtered)``) but none of the
    acceleration units the reader knows: ``deg``, ``kN``, ``mg``, or an SI symbol of one letter (``N``, ``V``)."""
    u = said.strip()
    return acc_unit_key(u) not in ACC_UNITS and (_UNIT_LIKE.fullmatch(u) is not None or u in _SI_LETTERS)


def _unknown_unit_warning(name: str, said: str, known: list[str], read_in: str, path: Path, line: int) -> None:
    """Warn that column ``name`` gives a unit ``said`` in its header that is none of ``known``, and is read in
    ``read_in``: a column of ``mg`` or ``km/h`` read as g or m/s is off by a factor the results do not show."""
    if _UNIT_LIKE.fullmatch(said.strip()) is not None:
        warnings.warn(
            _located(
                f"column {name!r} gives the unit {said!r} in its header, none of {known}; it is read in {read_in}: "
                "convert the column, or rename its header if that is no unit",
                path,
                line,
            ),
            stacklevel=3,
        )


def _with_unit(name: str, unit: str) -> str:
    """``name`` with the unit at its end replaced by ``unit``; unchanged without one. A bracketed end that is no unit
    (``[CH1]``, ``(filtered)``, which :func:`read_csv` reads as none) is a remark, and kept. A unit suffix of the
    library's own (:data:`_UNIT_SUFFIX`, ``tunnel_acc_g``, ``time_ms``) is replaced by the suffix of ``unit``."""
    m = _UNIT_AT_END.search(name)
    if m is None:
        m = _UNIT_SUFFIX.fullmatch(name)
        if m is None:
            return name
        at, kind = (m.start(1), _ACC_SUFFIXES) if m.group(1) else (m.start(2), _TIME_SUFFIXES)
        suffix_of = {u: k for k, u in reversed(kind.items())}  # a unit's first suffix
        if kind is _ACC_SUFFIXES:  # as --unit spells it: the first spelling of its factor
            unit = next(k for k, v in ACC_UNITS.items() if v == acc_unit_factor(unit))
        return f"{name[:at]}{suffix_of[unit]}" if unit in suffix_of else name
    said = m.group(2).strip()
    is_unit = acc_unit_key(said) in ACC_UNITS or said.lower() in _TIME_UNITS or _UNIT_LIKE.fullmatch(said)
    return f"{name[: m.start()]}{m.group(1)}{unit}{m.group(3)}" if is_unit else name


def acc_unit_factor(unit: str, path: str | Path | None = None, line: int | None = None) -> float:
    """SI factor [m/s^2 per unit] of an acceleration unit name (``g``, ``m/s2``, ``m/s**2`` ...)."""
    key = acc_unit_key(unit)
    if key in ACC_UNITS:
        return ACC_UNITS[key]
    reason = f"expected an acceleration unit in {ACC_UNIT_NAMES}{_OTHER_SPELLINGS}, got {unit!r}"
    raise _err(reason, path, line) if path is not None else PulseError(reason)


# ----------------------------------------------------------------------------------------------- CSV


def read_csv(
    path: str | Path,
    *,
    time_col: str | None = None,
    acc_col: str | Sequence[str] | None = None,
    unit: str = "g",
    time_unit: str = "s",
    sign: float = 1.0,
    max_gap: float | None = 4.0,
    breakpoints: bool = False,
    first_only: bool = False,
) -> Pulse:
    """Read a pulse from a CSV file with a header row.

    Args:
        path: the file.
        time_col: name of the time column (default: the first column named like ``time``/``t``/``zeit``, a unit at
            its end aside (``Zeit [s]``), else the first column).
        acc_col: name (or names) of the acceleration column(s) (default: every other column, but those whose header
            says they hold no acceleration: ``marlcrash simulate --csv``'s ``<sensor>_vel_ms`` and ``crush_m``, or a
            bracketed unit of velocity, length or time, ``v [m/s]``, ``crush (mm)``).
        unit: acceleration unit of the file, ``g`` or ``m/s2``.
        time_unit: time unit of the file, ``s`` or ``ms``.

            A unit at the end of a column's header must be the one the column is read in (else a
            :class:`PulseError` names the column and both units); one the reader does not know (``acc [mg]``,
            ``time [us]``) is warned about, naming the column. A header gives a unit in brackets or parentheses
            (``a_x [m/s2]``, ``time (ms)``), or as the library writes it (``marlcrash simulate --csv``), in an
            underscore suffix: ``time_s``/``time_ms`` as the whole name, ``acc_<unit>`` as the whole name or its end
            after an underscore (``tunnel_acc_g``), ``<unit>`` one of ``g``, ``ms2``/``m_s2`` (m/s^2), ``mm_s2``.
            No other name ending in ``_g``, ``_s``, ``_ms2`` ... gives a unit (``fuel_g``, ``radsup_ms2``,
            ``runtime_ms``; ``<sensor>_vel_ms`` is m/s).
        sign: ``+1`` or ``-1``, multiplies the acceleration (module docstring).
        max_gap: largest sampling interval, as a multiple of the median one, before a warning names the gap (a
            longer one that also exceeds :data:`MIN_GAP_S`); ``None``: no check.
        breakpoints: the rows are the corners of a piecewise linear pulse, not samples: two rows or more, no gap
            check, and the result is sampled at :data:`BREAKPOINT_RATE_HZ` from the first to the last row.
        first_only: without ``acc_col``, read the first acceleration column only (the first column that is not the
            time column nor marked as no acceleration, and whose header gives an acceleration unit or none where
            such a column exists: not ``pitch [deg]`` or ``F [kN]`` before ``a_x [g]``), as ``marlcrash pulse``
            does: the others are neither parsed nor checked.

    Returns:
        A :class:`Pulse` with one channel per acceleration column, named by its header.

    Raises:
        PulseError: unreadable file, missing column, ragged row, non-numeric or non-finite
            cell, time not strictly increasing, too few samples, or a table of breakpoints longer
            than :data:`MAX_BREAKPOINT_SPAN_S`.
    """
    path = Path(path)
    factor = acc_unit_factor(unit)
    if time_unit not in _TIME_UNITS:
        raise PulseError(f"time_unit: expected one of {sorted(_TIME_UNITS)}, got {time_unit!r}")
    _check_sign(sign)
    if max_gap is not None and not (math.isfinite(max_gap) and max_gap > 1):
        raise PulseError(f"max_gap: expected a multiple of the median sampling interval > 1 or None, got {max_gap!r}")
    if time_col is not None and not isinstance(time_col, str):  # was an AttributeError from inside the reader
        raise PulseError(f"time_col: expected a column name (columns are chosen by name), got {time_col!r}")
    _names(acc_col, "acc_col", "column")
    lines = _read_text_lines(path)
    first, delim, header, ti, width = _csv_header(path, lines, time_col)
    if acc_col is None:  # a simulation's own CSV: its velocities and crush were read as accelerations in g
        ai = [j for j in range(len(header)) if j != ti and not _not_acceleration(header[j])]
        if not ai:
            others = [header[j] for j in range(len(header)) if j != ti]
            raise _err(
                f"no acceleration column: the columns besides the time, {others}, hold velocities, lengths or times "
                "by their headers; name the acceleration column (--acc-col; acc_col)",
                path,
                first + 1,
            )
        if first_only:  # the first whose header gives an acceleration unit or none: not 'pitch [deg]', 'F [kN]'
            units = [_header_unit(header[j]) for j in ai]
            plain = [j for j, u in zip(ai, units, strict=True) if u is None or not _gives_other_unit(u)]
            acc_col = header[(plain or ai)[0]]
    # '0,5;-2,25': European spreadsheets separate by ';' because the comma is their decimal mark. With tabs only
    # where no comma can group thousands: a tab export of an English spreadsheet may ('-1,005' is -1005 there).
    decimal_comma = delim == ";"

    def find(name: str) -> int:
        return _csv_column(header, name, path, first + 1)

    if acc_col is not None:
        names = [acc_col] if isinstance(acc_col, str) else list(acc_col)
        ai = [find(n) for n in names]
        if ti in ai:
            raise _err(f"column {header[ti]!r} is chosen as both time and acceleration", path, first + 1)
        for j in ai:  # named, such a column was read as accelerations (11 m/s of velocity as an 11 g pulse)
            if _not_acceleration(header[j]):
                raise _err(
                    f"column {header[j]!r} holds no acceleration by its header (a velocity, length or time); "
                    "name an acceleration column (--acc-col; acc_col)",
                    path,
                    first + 1,
                )
    for j in ai:  # a unit written in the header ('a_x [m/s2]', 'ACC (g)') must be the unit the column is read in
        said = _header_unit(header[j])
        if said is not None and acc_unit_key(said) not in ACC_UNITS:
            _unknown_unit_warning(header[j], said, ACC_UNIT_NAMES, unit, path, first + 1)
        elif said is not None and ACC_UNITS[acc_unit_key(said)] != factor:
            typed = next(k for k, v in ACC_UNITS.items() if v == ACC_UNITS[acc_unit_key(said)])  # as --unit takes it
            raise _err(
                f"column {header[j]!r} is in {said} by its header, but is read in {unit}: give that unit "
                f"(--unit {typed}; unit: {typed})",
                path,
                first + 1,
            )
    said = _header_unit(header[ti])
    if said is not None:
        said = {"sec": "s", "secs": "s", "msec": "ms"}.get(said.strip().lower(), said)
    if said is not None and said.strip().lower() not in _TIME_UNITS:
        _unknown_unit_warning(header[ti], said, sorted(_TIME_UNITS), time_unit, path, first + 1)
    elif said is not None and said.strip().lower() != time_unit:
        raise _err(
            f"column {header[ti]!r} is in {said} by its header, but is read in {time_unit}: give that unit "
            f"(--time-unit {said.strip().lower()}; time_unit: {said.strip().lower()})",
            path,
            first + 1,
        )
    rows: list[list[float]] = []
    line_of: list[int] = []
    wanted = [ti, *ai]
    if delim == "\t":
        decimal_comma = _decimal_commas(lines[first + 1 :], wanted)
    for lineno, line in enumerate(lines[first + 1 :], start=first + 2):
        row = _row(line, delim, path, lineno)  # line by line: a quoted line break shifted every later line number
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        if len(row) not in (len(header), width):
            raise _err(f"expected {len(header)} fields as in the header, got {len(row)}", path, lineno)
        for j in range(len(header), len(row)):  # under the header's trailing empty names
            if row[j].strip():
                raise _err(f"column {j + 1} has no name in the header but holds {row[j].strip()!r}; every column "
                           "with data needs a name", path, lineno)  # fmt: skip
        vals = []
        for j in wanted:
            cell = row[j].strip()
            try:
                v = _number(cell.replace(",", ".") if decimal_comma else cell)
            except ValueError:
                raise _err(f"expected a number, got {cell!r}", path, lineno, header[j]) from None
            if not math.isfinite(v):
                raise _err(f"expected a finite number, got {cell!r}", path, lineno, header[j])
            vals.append(v)
        rows.append(vals)
        line_of.append(lineno)
    fewest = 2 if breakpoints else MIN_SAMPLES
    if len(rows) < fewest:
        what = "breakpoints" if breakpoints else "samples"
        raise _err(f"expected at least {fewest} {what}, got {len(rows)}", path)
    data = np.asarray(rows, dtype=np.float64)
    time = data[:, 0] * _TIME_UNITS[time_unit]
    steps = np.diff(time)
    # a table of breakpoints may draw a vertical edge (a rectangular pulse) with two rows of the same time
    bad = (steps < 0) | ((steps == 0) & np.r_[False, steps[:-1] == 0]) if breakpoints else steps <= 0
    if np.any(bad):
        i = int(np.argmax(bad))
        if steps[i] < 0:
            what = "time goes backwards"
        else:
            what = "a third row at one time" if breakpoints else "duplicated time"
        expected = ("time to increase (two rows of one time draw a vertical edge)" if breakpoints
                    else "time to strictly increase")  # fmt: skip
        raise _err(
            f"{what}: expected {expected}, got {float(data[i + 1, 0])!r} after {float(data[i, 0])!r}",
            path,
            line_of[i + 1],
            header[ti],
        )
    acc = data[:, 1:].T * (factor * float(sign))
    channels = tuple(header[j] for j in ai)
    if breakpoints:
        span = float(time[-1] - time[0])
        if span > MAX_BREAKPOINT_SPAN_S:
            raise _err(
                f"the breakpoints span {span:.4g} s; a crash pulse lasts well under {MAX_BREAKPOINT_SPAN_S:g} s: "
                + _UNIT_HINT,
                path,
                line_of[-1],
                header[ti],
            )
        n = int(np.ceil(span * BREAKPOINT_RATE_HZ - 1e-6)) + 1  # to the last corner (beyond it: its value)
        if n < MIN_SAMPLES:
            hint = " (is the time column in s? time_unit: s)" if time_unit == "ms" else ""
            raise _err(f"the breakpoints span {span:.4g} s, less than {MIN_SAMPLES} samples at "
                       f"{BREAKPOINT_RATE_HZ:g} Hz{hint}", path, line_of[-1], header[ti])  # fmt: skip
        rows_apart = float(np.median(steps[steps > 0]))
        if rows_apart < 0.5 / BREAKPOINT_RATE_HZ:
            reason = (f"rows {rows_apart:g} s apart (median) are a sampled record, not a table of breakpoints; "
                      f"sampling them at {BREAKPOINT_RATE_HZ:g} Hz drops samples (read the file without --breakpoints "
                      "/ breakpoints: true)")  # fmt: skip
            warnings.warn(_located(reason, path), stacklevel=2)
        grid = time[0] + np.arange(n) / BREAKPOINT_RATE_HZ
        dense = np.stack([np.interp(grid, time, a) for a in acc])
        return Pulse(time=grid, acc=dense, channels=channels, source=str(path), drawn=True)
    median = float(np.median(steps))
    n_gaps = 0 if max_gap is None else int(np.count_nonzero(steps > max(max_gap * median, MIN_GAP_S)))
    if n_gaps:
        i = int(np.argmax(steps))
        reason = (
            f"{n_gaps} gap(s) in the record, the longest from t = {float(data[i, 0])!r} to {float(data[i + 1, 0])!r} "
            f"({float(steps[i]) / median:.1f} times the median sampling interval of {median:g} s); resampling "
            "bridges a gap with a straight line, right for a table of breakpoints (read it as one: --breakpoints, "
            "breakpoints: true), wrong for a recorder's dropout"
        )
        warnings.warn(_located(reason, path, line_of[i + 1], header[ti]), stacklevel=2)
    return Pulse(time=time, acc=acc, channels=channels, source=str(path))


_DECIMAL_COMMA = re.compile(r"[+-]?\d*,\d+(?:[eE][+-]?\d+)?")
"""A number written with a decimal comma (``-0,25``, ``1,5E-03``)."""
_THOUSANDS = re.compile(r"[+-]?[1-9]\d{0,2}(?:,\d{3})+")
"""A whole number whose commas group thousands (``-1,005``, ``12,500``): read with a decimal comma, another number."""


def _decimal_commas(lines: list[str], columns: list[int]) -> bool:
    """Whether the tab-separated data ``lines`` write numbers in ``columns`` with a decimal comma: every cell there that
    holds a comma is a number with one decimal comma, and one at least (``-0,025``, ``1,5``) can group no thousands
    (``-1,005``, which an English spreadsheet writes for -1005)."""
    unambiguous = False
    for row in (_fields(line, "\t") or [] for line in lines):  # a line that is no CSV: read_csv names it
        if not row or row[0].lstrip().startswith("#"):
            continue
        for cell in (row[j].strip() for j in columns if j < len(row) and "," in row[j]):
            if _DECIMAL_COMMA.fullmatch(cell) is None:
                return False
            unambiguous = unambiguous or _THOUSANDS.fullmatch(cell) is None
    return unambiguous


def is_sign(sign: Any) -> bool:
    """Whether ``sign`` is +1 or -1, a bool not (``True == 1``: a flag is not a sign)."""
    return not isinstance(sign, (bool, np.bool_)) and sign in (1, -1)


def _check_sign(sign: Any) -> None:
    """Refuse a ``sign`` that is not +1 or -1 (:func:`is_sign`)."""
    if not is_sign(sign):
        raise PulseError(f"sign: expected +1 or -1, got {sign!r}")


def _names(value: Any, key: str, what: str) -> None:
    """Refuse, naming ``key``, a choice of columns or channels that is not ``None``, a name or a list of names (a
    number, ``acc_col=1``, raised a TypeError or an AttributeError from inside the reader), or an empty list (a CSV
    read as a pulse of no channels, an ISO-MME test as an IndexError after reading it)."""
    if value is None or isinstance(value, str):
        return
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        if not value:
            raise PulseError(f"{key}: expected at least one {what} name, got {value!r}")
        return
    raise PulseError(f"{key}: expected a {what} name or a list of {what} names ({what}s are chosen by name), "
                     f"got {value!r}")  # fmt: skip


def _csv_header(path: Path, lines: list[str], time_col: str | None) -> tuple[int, str, list[str], int, int]:
    """The header of a CSV file's ``lines``: its index, the delimiter, the column names, the time column's
    index (``time_col``, else the first column named like ``time``, else the first column), and the number of
    fields the header line holds: more than names where it ends in empty ones (a trailing delimiter, ``time;acc;``),
    which are no columns (:func:`read_csv` checks that the rows hold nothing under them)."""
    first = next((i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")), None)
    if first is None:
        raise _err("expected a header row and samples, found no data", path)
    sep = _EXCEL_SEP.fullmatch(lines[first].strip(" "))  # not a tab: "sep=\t"
    if sep is not None:  # Excel's 'sep=;' line names the delimiter; the header follows it
        first = next((i for i in range(first + 1, len(lines))
                      if lines[i].strip() and not lines[i].lstrip().startswith("#")), None)  # fmt: skip
        if first is None:
            raise _err("expected a header row and samples after the 'sep=' line, found no data", path)
    delim = sep.group(1) if sep is not None else _delimiter(lines, first, path)
    header = [h.strip() for h in _row(lines[first], delim, path, first + 1)]
    width = len(header)
    while len(header) > 1 and not header[-1]:  # 'time;acc;': a trailing delimiter (the rows' cells: read_csv)
        header.pop()
    if len(header) < 2:  # 'time;': no acceleration column (read as a pulse of no channels)
        raise _err(
            f"expected a header with at least two columns (time and acceleration) separated by {delim!r}, got "
            f"{lines[first]!r}",
            path,
            first + 1,
        )
    if all(_is_number(h) for h in header):  # reading it as names would silently drop the first sample
        raise _err(
            "expected a header row naming the columns (e.g. 'time,acc'), got only numbers; lines starting with "
            "'#' are comments (numpy.savetxt comments its header: write it with comments='')",
            path,
            first + 1,
        )
    for j, h in enumerate(header):
        if not h:
            raise _err(f"header column {j + 1} is empty; every column needs a name", path, first + 1)
        if header.index(h) != j:
            raise _err(f"duplicate column name {h!r} in the header", path, first + 1)
    if time_col is None:
        low = [_UNIT_AT_END.sub("", h).strip().lower() for h in header]  # 'Zeit [s]', 't (ms)': by the name
        ti = next((j for j, h in enumerate(low) if h in _TIME_NAMES or h.startswith("time")), 0)
    else:
        ti = _csv_column(header, time_col, path, first + 1)
    return first, delim, header, ti, width


_EXCEL_SEP = re.compile(r"sep=([,;\t])", re.IGNORECASE)
"""Excel's first line naming a CSV file's delimiter (``sep=;``), which some exports write."""


def _csv_column(header: list[str], name: str, path: Path, line: int) -> int:
    """The index of column ``name`` in ``header`` (exact, else ignoring case), else a :class:`PulseError`."""
    if name in header:
        return header.index(name)
    low = [h.lower() for h in header]
    if name.lower() in low:
        return low.index(name.lower())
    raise _err(f"column {name!r} not found; the header has {header}", path, line)


def _read_text_lines(path: Path) -> list[str]:
    """The lines of a text file: UTF-8 (with or without a byte-order mark) or UTF-16/32 with one; a line that is not
    UTF-8 is read as Windows-1252 / Latin-1, the encodings lab and spreadsheet exports use (``m/s²`` in a header
    must not turn into a replacement character). Lines end at line feeds, carriage returns and CR LF
    (:func:`_split_lines`), not at the form feeds, U+0085 or U+2028 that ``str.splitlines`` also breaks at."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise _err(f"cannot read pulse file ({e.strerror})", path) from None
    raw = raw.removeprefix(_UTF8_BOM)
    codec = _bom_codec(raw)  # Excel's "Unicode Text" is UTF-16 with its byte-order mark
    if codec is not None:
        try:
            return _split_lines(raw.decode(codec))
        except UnicodeDecodeError as e:
            raise _not_bom_text(codec, e, path) from None
    return _decode_lines(raw, ("cp1252",))


_UTF8_BOM = b"\xef\xbb\xbf"
_BOMS = (
    (b"\xff\xfe\x00\x00", "utf-32"),
    (b"\x00\x00\xfe\xff", "utf-32"),
    (b"\xff\xfe", "utf-16"),
    (b"\xfe\xff", "utf-16"),
)
"""The byte-order marks of UTF-32 and UTF-16 and the codec each names; UTF-32's first, as its little-endian mark
starts with UTF-16's."""


def _bom_codec(raw: bytes) -> str | None:
    """The codec (``utf-16``, ``utf-32``) whose byte-order mark ``raw`` starts with, else ``None``."""
    return next((codec for bom, codec in _BOMS if raw.startswith(bom)), None)


def _not_bom_text(codec: str, e: UnicodeDecodeError, path: Path) -> PulseError:
    return _err(f"starts with a {codec.upper()} byte-order mark but is not {codec.upper()} text ({e.reason})", path)


def _decode_lines(raw: bytes, legacy: tuple[str, ...]) -> list[str]:
    """The lines of ``raw`` (:func:`_split_lines`): UTF-8 where ``raw`` is UTF-8 text, else line by line (one Latin-1
    comment must not turn a UTF-8 header into mojibake), a line that is not UTF-8 in the first of ``legacy`` that
    decodes it, else Latin-1. Either way a line is read as UTF-8 exactly when its bytes are UTF-8; a line break is a
    byte no UTF-8 character holds, so whole lines decode alike read at once or in chunks (:func:`_read_header_lines`).
    The CSV reader takes Windows-1252 before Latin-1, ISO-MME Latin-1 alone (the encoding :func:`write_mme` writes)."""
    try:
        return _split_lines(raw.decode("utf-8"))
    except UnicodeDecodeError:
        return [_decode_line(b, legacy) for b in raw.splitlines()]


def _decode_line(raw: bytes, legacy: tuple[str, ...]) -> str:
    for codec in ("utf-8", *legacy):
        try:
            return raw.decode(codec)
        except UnicodeDecodeError:
            pass
    return raw.decode("latin-1")  # never fails: every byte is a character


def _fields(line: str, delim: str) -> list[str] | None:
    """``line`` split at ``delim`` as CSV, or ``None`` where it is none: a quoted field that does not close on the
    line, text after a closing quote, a field over csv's size limit."""
    try:
        return next(csv.reader([line], delimiter=delim, strict=True), [])
    except csv.Error:
        return None


def _row(line: str, delim: str, path: Path, lineno: int) -> list[str]:
    """``line`` split at ``delim`` (:func:`_fields`), else a :class:`PulseError` naming the file and line."""
    row = _fields(line, delim)
    if row is None:
        raise _err(
            f"cannot split the line into fields at {delim!r}: expected every quoted field to close on its line (no "
            f"line break inside a cell) with the delimiter right after it, and at most {csv.field_size_limit()} "
            "characters in a field",
            path,
            lineno,
        )
    return row


def _delimiter(lines: list[str], first: int, path: Path) -> str:
    """The delimiter (``,``, ``;`` or tab) that splits the header into at least two names and the first data rows
    into as many fields; the header alone is ambiguous (``"time (s)";"acc, g"`` holds one of each)."""
    data = [s for s in lines[first + 1 : first + 21] if s.strip() and not s.lstrip().startswith("#")]
    n_head = {d: len(_fields(lines[first], d) or ()) for d in (",", ";", "\t")}
    # ';' and tab first: a ';' file's decimal commas (and commas in its names) also split it evenly at ','
    for d in (";", "\t", ","):
        if n_head[d] >= 2 and all(len(_fields(s, d) or ()) == n_head[d] for s in data):
            return d
    if max(n_head.values()) < 2:
        raise _err(
            f"expected a header with at least two columns separated by ',', ';' or tab, got {lines[first]!r}",
            path,
            first + 1,
        )
    return max(n_head, key=lambda d: n_head[d])  # the header's; the first row that disagrees is reported with its line


def write_csv(pulse: Pulse, path: str | Path, *, unit: str = "g", time_col: str = "time") -> Path:
    """Write a pulse as CSV (time in s, acceleration in ``unit``), the format :func:`read_csv` reads.

    A channel name that ends in a unit (``'a_x [m/s2]'``, read as such) gets the unit written instead, and a time
    column name ending in one gets ``s``: :func:`read_csv` checks a header's units against the units it reads in.
    """
    path = Path(path)
    factor = acc_unit_factor(unit)
    data = np.column_stack([pulse.time, pulse.acc.T / factor])
    names = io.StringIO()  # quoted where a name holds the delimiter or a quote, as read_csv's csv.reader reads it
    csv.writer(names, lineterminator="").writerow(
        [_with_unit(time_col, "s"), *(_with_unit(c, unit) for c in pulse.channels)]
    )
    header = names.getvalue()
    with atomic_output(path) as tmp:
        np.savetxt(tmp, data, delimiter=",", header=header, comments="", fmt="%.17g")
    return path


# ------------------------------------------------------------------------------------------ ISO-MME


def _parse_header(path: Path, lines: list[str]) -> tuple[dict[str, tuple[str, int]], int]:
    """``Name :value`` lines -> {lower-case name: (value, line number)}; returns the first data line index."""
    header: dict[str, tuple[str, int]] = {}
    start = len(lines)
    for i, raw in enumerate(lines):
        if not raw.strip():  # a blank line inside the header ended it: its later lines were read as samples
            continue
        if ":" not in raw:
            start = i
            break
        name, _, value = raw.partition(":")
        if not name.strip():
            raise _err(f"expected 'Name :value', got {raw!r}", path, i + 1)
        header.setdefault(" ".join(name.split()).lower(), (value.strip(), i + 1))  # as .mme/.chn keys
    return header, start


def _split_lines(text: str) -> list[str]:
    """``text`` split at line feeds, carriage returns and CR LF pairs, as ``str.splitlines`` without its other breaks
    (form feed, U+0085, U+2028 ...): an ISO-MME file decoded as Latin-1 holds Windows-1252's ellipsis as U+0085, and
    a CSV comment or cell may hold any of them. CSV and ISO-MME lines alike."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines[-1] == "":
        lines.pop()
    return lines


def _read_lines(path: Path) -> list[str]:
    """The lines of an ISO-MME file: UTF-8 where a line is UTF-8 (a byte-order mark dropped), else Latin-1, the
    encoding of the standard (:func:`_decode_lines`); MME files come from many labs and tools, and Latin-1 never fails
    to decode. A file that starts with a UTF-16 or UTF-32 byte-order mark is decoded by it (:func:`_mme_codec`)."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise _err(f"cannot read ({e.strerror})", path) from None
    codec = _mme_codec(raw[:4], path)
    if codec is None:
        return _decode_lines(raw.removeprefix(_UTF8_BOM), ())
    try:
        return _split_lines(raw.decode(codec))
    except UnicodeDecodeError as e:
        raise _not_bom_text(codec, e, path) from None


def _mme_codec(head: bytes, path: Path) -> str | None:
    """The codec of an ISO-MME file whose first bytes are ``head``: UTF-16 or UTF-32 where they are its byte-order
    mark, else ``None`` (Latin-1 or UTF-8 lines, :func:`_decode_lines`). UTF-16 without one is refused: a header
    starts with a Latin letter, and a NUL byte after it (or before it) is UTF-16's, which read as Latin-1 gave header
    names no reader finds ("missing header line 'Unit'")."""
    codec = _bom_codec(head)
    nul = [b == 0 for b in head[:4]]
    if codec is None and nul in ([False, True, False, True], [True, False, True, False]):
        raise _err("looks like UTF-16 text without a byte-order mark (NUL bytes between its first characters); "
                   "expected Latin-1 or UTF-8 text, or UTF-16/32 with its byte-order mark", path)  # fmt: skip
    return codec


def _read_header_lines(path: Path) -> list[str]:
    """The first lines of a channel file up to the first that is no ``Name :value`` line (the first sample), however
    many there are, as :func:`_read_lines` splits and decodes them: what :func:`_parse_header` reads, without reading
    the samples after it (a channel may hold millions). Only whole lines are decoded, so a chunk ending inside a UTF-8
    character leaves it whole for the next; a UTF-16/32 file is decoded chunk by chunk by an incremental decoder,
    which keeps a character split between chunks for the next, and goes on as the UTF-8 of its text."""
    lines: list[str] = []
    checked = 0  # lines[:checked] are header lines
    rest = bytearray()  # the last line read so far, which may go on in the next chunk
    try:
        with path.open("rb") as f:
            chunk = f.read(16384)
            codec = _mme_codec(chunk[:4], path)
            if codec is None:
                chunk = chunk.removeprefix(_UTF8_BOM)
                decoder = None
            else:
                decoder = codecs.getincrementaldecoder(codec)()
            while True:
                text = chunk if decoder is None else decoder.decode(chunk, final=not chunk).encode("utf-8")
                if not chunk:
                    lines += _decode_lines(bytes(rest + text), ())
                    break
                new = max(len(rest) - 1, 0)  # rest holds no line break but a last "\r", which may go on with "\n"
                rest += text
                end = max(rest.rfind(b"\n", new), rest.rfind(b"\r", new, len(rest) - 1))
                if end >= 0:
                    lines += _decode_lines(bytes(rest[: end + 1]), ())
                    del rest[: end + 1]
                if not all(":" in s for s in lines[checked:]):  # the first sample: the header ends before it
                    break
                checked = len(lines)
                chunk = f.read(16384)
    except OSError as e:
        raise _err(f"cannot read ({e.strerror})", path) from None
    except UnicodeDecodeError as e:
        raise _not_bom_text(str(codec), e, path) from None
    return lines


def _header_float(path: Path, header: dict[str, tuple[str, int]], key: str) -> float:
    if key not in header:
        raise _err(f"missing header line {key.capitalize()!r} (expected 'Name :value')", path)
    value, line = header[key]
    try:
        v = _number(value)
    except ValueError:
        raise _err(f"{key.capitalize()!r}: expected a number, got {value!r}", path, line) from None
    if not math.isfinite(v):
        raise _err(f"{key.capitalize()!r}: expected a finite number, got {value!r}", path, line)
    return v


def _read_mme_channel(path: Path, lines: list[str], header: dict[str, tuple[str, int]], start: int) -> dict[str, Any]:
    """The samples of a channel file whose ``lines`` were read and whose ``header`` ends at line index ``start``
    (:func:`_parse_header`): the file is read once for its header and its samples."""
    t_first = _header_float(path, header, "time of first sample")
    dt = _header_float(path, header, "sampling interval")
    if dt <= 0:
        raise _err(f"'Sampling interval': expected > 0 s, got {dt!r}", path, header["sampling interval"][1])
    if "unit" not in header:
        raise _err("missing header line 'Unit' (expected 'Name :value')", path)
    unit, unit_line = header["unit"]
    factor = acc_unit_factor(unit, path, unit_line)
    values = []
    for lineno, raw in enumerate(lines[start:], start=start + 1):
        s = raw.strip()
        if not s:
            continue
        try:
            v = _number(s)
        except ValueError:
            raise _err(f"expected one sample value per line, got {s!r}", path, lineno) from None
        if not math.isfinite(v):
            raise _err(f"expected a finite sample value, got {s!r}", path, lineno)
        values.append(v)
    # optional; NOVALUE is ISO-MME's "not given" (as for 'Channel code')
    if "number of samples" in header and header["number of samples"][0].upper() != "NOVALUE":
        n_decl = _header_float(path, header, "number of samples")
        if n_decl != int(n_decl) or n_decl < 0:  # 2700.7 was read as 2700
            raise _err(
                f"'Number of samples': expected a whole number, got {header['number of samples'][0]!r}",
                path,
                header["number of samples"][1],
            )
        if int(n_decl) != len(values):
            raise _err(
                f"'Number of samples' says {int(n_decl)}, found {len(values)} values",
                path,
                header["number of samples"][1],
            )
    if len(values) < MIN_SAMPLES:
        raise _err(f"expected at least {MIN_SAMPLES} samples, got {len(values)}", path)
    name = header.get("name of the channel", ("", 0))[0]
    code = header.get("channel code", ("", 0))[0]
    return {
        "name": name,
        "code": code if code and code.upper() != "NOVALUE" else "",
        "t_first": t_first,
        "dt": dt,
        "n": len(values),
        "acc": np.asarray(values) * factor,
    }


def _mme_paths(path: Path) -> tuple[Path, Path]:
    """(test .mme file, Channel folder) for a test folder or its .mme file."""
    if path.is_dir():
        # by the suffix in any case, as read_pulse takes a .mme file (two globs missed '.Mme', and where globs
        # ignore case, Windows, both found the one file)
        mmes = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() == ".mme")
        if len(mmes) != 1:
            raise _err(f"expected exactly one <test>.mme file in the test folder, found {len(mmes)}", path)
        mme = mmes[0]
    elif path.is_file():
        mme = path
    else:
        raise _err("no such ISO-MME test folder or .mme file", path)
    folders = _channel_folders(mme.parent)
    if not folders:
        raise _err("expected a 'Channel' folder next to the .mme file", mme)
    if len(folders) > 1:
        raise _err(_two_channel_folders(folders), mme)
    return mme, folders[0]


def _channel_folders(folder: Path) -> list[Path]:
    """The folders of a test folder named ``Channel`` in any case (``CHANNEL`` as some tools write it), by name."""
    return sorted(d for d in folder.iterdir() if d.is_dir() and d.name.lower() == "channel")


def _two_channel_folders(folders: list[Path]) -> str:
    return f"the test folder holds {_counted('channel folders', [repr(d.name) for d in folders])}; keep one"


def _counted(noun: str, names: list[str]) -> str:
    """``"two <noun>, A and B"`` (the count in figures from three on), for a message naming what clashes."""
    return f"{'two' if len(names) == 2 else len(names)} {noun}, {', '.join(names[:-1])} and {names[-1]}"


def _numbered_files(folder: Path, test: str) -> list[Path]:
    """The files ``<test>.<digits>`` in a channel folder, the stem in any case: each is read as the channel of its
    number (``<test>.001``, or ``<test>.01`` or ``<test>.1`` unpadded), and two for one number are ambiguous."""
    return [p for p in folder.iterdir() if p.is_file() and p.stem.lower() == test.lower()
            and re.fullmatch(r"\d+", p.suffix[1:] or "")]  # fmt: skip


_NUMBERED_ZERO = "no channel file (ISO-MME numbers them from 001)"


def _mme_channel_files(path: Path) -> tuple[Path, list[Path], dict[Path, tuple[str, str]]]:
    """(test .mme file, its channel files ``<test>.001``, ``<test>.002``, ... in order, and the names the channel
    list gives them, :func:`_listed_names`) of a test or .mme file."""
    mme, folder = _mme_paths(path)
    test = mme.stem
    count = _mme_channel_count(mme, _read_lines(mme))  # the test description must at least be readable
    # in numeric order: .001 to .999, then .1000 (as pyisomme writes them); .01 or .1 (unpadded) is channel 1 too
    numbered = _numbered_files(folder, test)
    for p in sorted(p for p in numbered if int(p.suffix[1:]) == 0):  # was read as channel 0, before channel 1
        warnings.warn(f"{file_label(mme)}: {p.name} is {_NUMBERED_ZERO}; not read", stacklevel=3)
    numbered = [p for p in numbered if int(p.suffix[1:]) != 0]
    by_number: dict[int, list[Path]] = {}
    for p in numbered:
        by_number.setdefault(int(p.suffix[1:]), []).append(p)
    for number, same in sorted(by_number.items()):
        if len(same) > 1:  # T.001 and T.0001, T.01 and T.001, T.002 and t.002: which is the channel is not known
            raise _err(f"channel {number} has {_counted('files', sorted(p.name for p in same))}; a channel is one "
                       f"file {test}.{number:03d}: remove the others", folder)  # fmt: skip
    files = sorted(numbered, key=lambda p: int(p.suffix[1:]))
    if not files:
        raise _err(f"no channel files {test}.001, {test}.002, ... in the Channel folder", mme)
    return mme, files, _listed_names(folder, test, files, (mme, count))


def mme_files(path: str | Path) -> list[Path]:
    """The files an ISO-MME test (its folder or its ``.mme`` file) is read from: the ``.mme`` file, the channel list
    ``<test>.chn`` where there is one, and the channel files in order (what a run's record hashes,
    :mod:`marlcrash.provenance`).

    Raises:
        PulseError: a test that cannot be read (as :func:`read_mme` says).
    """
    with warnings.catch_warnings():  # reading the test itself warns of a channel file it skips
        warnings.simplefilter("ignore")
        mme, files, _ = _mme_channel_files(Path(path))
    chn = _mme_channel_list(files[0].parent, mme.stem)[0]
    return [mme, *([chn] if chn.is_file() else []), *files]


_LISTED_CHANNEL = re.compile(r"name of channel (\d+)")
"""A channel of the channel list ``<test>.chn``: ``Name of channel 001 :<code> / <name>`` (the key's case and
spaces as :func:`_mme_channel_list` normalizes them)."""


def _mme_channel_list(folder: Path, test: str) -> tuple[Path, dict[int, tuple[str, int]], tuple[int, int] | None]:
    """The channel list ``<test>.chn`` of a channel folder (its name in any case): its path, {channel number: (value
    of its ``Name of channel`` line, line number)} and its ``Number of channels`` (count, line number), ``None``
    where not given. ``(folder, {}, None)`` without one: a test may come without it.

    Raises:
        PulseError: two lists, a count that is no whole number or differs from the channels named, a channel named
            twice or numbered 000 (naming the file and line).
    """
    found = sorted(p for p in folder.iterdir() if p.is_file() and p.stem.lower() == test.lower()
                   and p.suffix.lower() == ".chn")  # fmt: skip
    if not found:
        return folder, {}, None
    if len(found) > 1:
        raise _err(f"the folder holds {_counted(f'channel lists of test {test!r}', [p.name for p in found])}; "
                   "keep one", folder)  # fmt: skip
    chn = found[0]
    names: dict[int, tuple[str, int]] = {}
    count = None
    for i, raw in enumerate(_read_lines(chn), start=1):
        key, colon, value = raw.partition(":")
        key, value = " ".join(key.split()).lower(), value.strip()
        listed = _LISTED_CHANNEL.fullmatch(key)
        if colon and listed:
            k = int(listed.group(1))
            if k == 0:
                raise _err(f"'Name of channel {listed.group(1)}': {_NUMBERED_ZERO}", chn, i)
            if k in names:
                raise _err(f"channel {k:03d} is listed twice, on lines {names[k][1]} and {i}", chn, i)
            names[k] = (value, i)
        elif colon and key == "number of channels" and count is None:
            count = _channel_count(value, chn, i)
    if count is not None and names and count[0] != len(names):
        raise _err(f"'Number of channels' says {count[0]}, the list names {len(names)} channels", chn, count[1])
    return chn, names, count


def _channel_count(value: str, path: Path, line: int) -> tuple[int, int] | None:
    """A ``Number of channels`` value of ``path`` at ``line``: (count, line), ``None`` for ISO-MME's ``NOVALUE``."""
    if value.upper() == "NOVALUE":
        return None
    if not value.isdecimal():  # isdigit takes '³', which int() refuses
        raise _err(f"'Number of channels': expected a whole number, got {value!r}", path, line)
    return int(value), line


def _mme_channel_count(mme: Path, lines: list[str]) -> tuple[int, int] | None:
    """The ``Number of channels`` of a test's ``.mme`` file (its ``lines``): (count, line number), ``None`` where not
    given (:func:`_channel_count`)."""
    for i, raw in enumerate(lines, start=1):
        key, colon, value = raw.partition(":")
        if colon and " ".join(key.split()).lower() == "number of channels":
            return _channel_count(value.strip(), mme, i)
    return None


def _listed_names(
    folder: Path, test: str, files: list[Path], counted: tuple[Path, tuple[int, int] | None]
) -> dict[Path, tuple[str, str]]:
    """{channel file: (channel code, channel name)} as the channel list ``<test>.chn`` names them
    (:func:`_mme_channel_list`), checked against the channel ``files`` found; empty without a list. ``counted`` is
    the test's ``.mme`` file and its ``Number of channels`` (:func:`_mme_channel_count`): it must agree with the
    list, and without one the files are checked against it as against a list of channels 001 to that count.

    Raises:
        PulseError: a channel file the list (or the count) does not hold (``<test>.003`` beside a list of two, as an
            earlier test left it), naming the list (or the ``.mme`` file) and its line, or a count that differs from
            the list's; a channel listed (counted) whose file is missing is named in a warning.
    """
    chn, names, count = _mme_channel_list(folder, test)
    mme, test_count = counted
    if not names and count is None:
        if test_count is None:
            return {}
        chn, count = mme, test_count  # the .mme file's count is all the test says of its channels
    if names:
        listed = set(names)
    else:
        assert count is not None  # set just above where neither the list nor the count held any channels
        listed = set(range(1, count[0] + 1))
    line = count[1] if count is not None else min(i for _, i in names.values())
    by_number = {int(p.suffix[1:]): p for p in files}
    unlisted = [by_number[k].name for k in sorted(set(by_number) - listed)]
    if unlisted:
        shown = ", ".join(unlisted[:5]) + (f" and {len(unlisted) - 5} more" if len(unlisted) > 5 else "")
        what = "a channel file" if len(unlisted) == 1 else "channel files"
        it = "it" if len(unlisted) == 1 else "them"
        if chn == mme:
            held = f"the test does not count ('Number of channels' says {len(listed)}); remove {it}, or count {it}"
        else:
            held = f"the channel list does not hold (it lists {len(listed)} channels); remove {it}, or list {it}"
        raise _err(f"the {folder.name} folder holds {shown}, {what} {held} in {chn.name}", chn, line)
    if test_count is not None and chn != mme and test_count[0] != len(listed):
        raise _err(f"'Number of channels' says {test_count[0]}, the channel list {chn.name} lists {len(listed)}",
                   mme, test_count[1])  # fmt: skip
    for k in sorted(listed - set(by_number)):
        value, at = names.get(k, ("", line))
        said = f" ({value!r})" if value else ""
        verb = "counts" if chn == mme else "lists"
        warnings.warn(_located(f"{verb} channel {k:03d}{said}, but the {folder.name} folder holds no {test}.{k:03d}; "
                               "read without it", chn, at), stacklevel=4)  # fmt: skip
    return {by_number[k]: _listed_channel(value) for k, (value, _) in names.items() if k in by_number}


def _listed_channel(value: str) -> tuple[str, str]:
    """(channel code, channel name) of a channel list's ``Name of channel`` value: ``<code> / <name>``, as labs write
    it, or a channel code alone, or a name alone; ``("", "")`` for ``NOVALUE``."""
    if value.upper() in ("", "NOVALUE"):
        return "", ""
    code, slash, name = value.partition("/")
    if slash and _is_channel_code(code.strip()):
        name = name.strip()
        return code.strip(), "" if name.upper() == "NOVALUE" else name
    return (value, "") if _is_channel_code(value) else ("", value)


def _mme_entry(path: Path, header: dict[str, tuple[str, int]], listed: tuple[str, str] = ("", "")) -> dict[str, Any]:
    """One channel of :func:`mme_channels`, from its file's parsed header, and where that gives no code or no name,
    those of the channel list (``listed``, :func:`_listed_names`)."""
    code = header.get("channel code", ("", 0))[0]
    unit = header["unit"][0] if "unit" in header else None
    return {
        "file": path,
        "code": ("" if code.upper() == "NOVALUE" else code) or listed[0],
        "name": header.get("name of the channel", ("", 0))[0] or listed[1],
        "unit": unit,
        "acceleration": unit is not None and acc_unit_key(unit) in ACC_UNITS,
    }


def mme_channels(path: str | Path) -> list[dict[str, Any]]:
    """The channels of an ISO-MME test from their headers alone (the samples are not read), in file order.

    Args:
        path: the test folder or its ``<test>.mme`` file.

    Returns:
        One dict per channel file: ``file`` (path), ``code`` (channel code, ``""`` if none), ``name`` (name of
        the channel), ``unit`` (as written; ``None`` without a ``Unit`` line) and ``acceleration`` (whether that
        unit is an acceleration unit).

    Raises:
        PulseError: no test, no ``Channel`` folder or no channel files (naming the path), or a channel list
            ``<test>.chn`` (or, without one, the ``.mme`` file's ``Number of channels``) that does not hold a channel
            file, or a ``Number of channels`` that differs from the list's (naming its line).
    """
    _, files, listed = _mme_channel_files(Path(path))
    return [_mme_entry(p, _parse_header(p, _read_header_lines(p))[0], listed.get(p, ("", ""))) for p in files]


def _matches(wanted: str, entry: dict[str, Any]) -> bool:
    """Whether channel name ``wanted`` is the channel code, the name or the file name of ``entry``, ignoring case."""
    return wanted.lower() in (entry["code"].lower(), entry["name"].lower(), entry["file"].name.lower())


def read_mme(path: str | Path, *, channels: str | Sequence[str] | None = None, sign: float = 1.0) -> Pulse:
    """Read acceleration channels of an ISO-MME test.

    Args:
        path: the test folder or its ``<test>.mme`` file.
        channels: channel(s) to read, each matched (case-insensitively) against the channel
            code (e.g. ``10VEHC000000ACXP``), the ``Name of the channel`` or the file name
            (``<test>.001``); default: every acceleration channel (a test also holds forces,
            displacements ...: :func:`mme_channels` lists them).
        sign: ``+1`` or ``-1``, multiplies the acceleration (module docstring).

    Returns:
        A :class:`Pulse`. Channels of other time bases (sampling interval, first sample, length) are interpolated
        linearly onto the finest interval over the span all of them cover, with a warning. Channel names are
        the channel codes where given, else the channel names.

    Raises:
        PulseError: missing files, two files for one channel number, a channel file the channel list
            ``<test>.chn`` (or the ``.mme`` file's ``Number of channels``) does not hold, malformed headers or
            samples, a non-acceleration unit, unknown channels, or channels that share too little time.

    Each file of the test is read once: a channel's header and samples together.
    """
    return _read_mme(Path(path), channels, sign)


def _read_mme(
    path: Path, channels: str | Sequence[str] | None, sign: float, *, first_acceleration: bool = False
) -> Pulse:
    """:func:`read_mme`; with ``first_acceleration`` (and no ``channels``) the first acceleration channel alone, as
    ``marlcrash pulse`` reads a test: the files after it are not read, and a channel file before it without a
    ``Unit`` line is refused (it may be the channel meant)."""
    _check_sign(sign)
    _names(channels, "channels", "channel")
    wanted = None if channels is None else ([channels] if isinstance(channels, str) else list(channels))
    mme, files, listed = _mme_channel_files(path)
    info: list[dict[str, Any]] = []
    read: dict[Path, dict[str, Any]] = {}  # the chosen channels' samples, parsed from the reading of their header
    for p in files:
        lines = _read_lines(p)
        header, start = _parse_header(p, lines)
        entry = _mme_entry(p, header, listed.get(p, ("", "")))
        info.append(entry)
        if wanted is not None:  # a file is read for the first name it matches (the first file that matches it)
            chosen = any(_matches(w, entry) and not any(_matches(w, c) for c in info[:-1]) for w in wanted)
        elif entry["unit"] is None:  # not known to be something else: never skipped silently
            if first_acceleration:
                raise _err(
                    f"channel file {p.name} has no 'Unit' header line, so the reader cannot tell whether it is the "
                    "first acceleration channel; give the channel with --acc-col (acc_col=)",
                    path,
                )
            raise _err("missing header line 'Unit' (expected 'Name :value')", p)
        else:
            chosen = entry["acceleration"]
        if chosen:
            read[p] = _read_mme_channel(p, lines, header, start)
            if first_acceleration and wanted is None:
                break
    if wanted is None:
        chosen_files = [c["file"] for c in info if c["acceleration"]]
        if not chosen_files:
            units = sorted({c["unit"] for c in info})
            known = ACC_UNIT_NAMES
            raise _err(
                f"no acceleration channel in the test (channel units: {units}; acceleration units: {known})", mme
            )
        skipped = [f"{c['file'].name} ({c['unit']})" for c in info if not c["acceleration"]]
        if skipped and not first_acceleration:
            warnings.warn(
                f"{mme.name}: read the acceleration channels only; skipped {', '.join(skipped)}", stacklevel=3
            )
    else:
        chosen_files = []
        for w in wanted:
            hit = [c["file"] for c in info if _matches(w, c)]
            if not hit:
                known = sorted({n for c in info for n in (c["code"], c["name"], c["file"].name) if n})
                raise _err(f"channel {w!r} not found; the test has {known}", mme)
            chosen_files.append(hit[0])
    time, acc = _common_time_base(mme, chosen_files, [read[p] for p in chosen_files])
    acc = acc * float(sign)
    entries = {c["file"]: c for c in info}  # the names of the channel file, else of the channel list
    names = tuple(entries[p]["code"] or entries[p]["name"] or p.name for p in chosen_files)
    # 'Channel frequency class' is not trusted as a record of filtering already applied (labs use it for
    # the class a channel *should* be filtered with), so the pulse counts as unfiltered (cfc=None).
    return Pulse(time=time, acc=acc, channels=names, source=str(mme))


def _common_time_base(mme: Path, files: list[Path], chans: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """The time ``[T]`` and samples ``[K, T]`` of channels read from ``files``: their own where they share one time
    base, else each linearly interpolated onto the finest sampling interval over the span all of them cover (a test's
    data acquisition may sample channels at other rates or start them at other times), with a warning naming them.

    Raises:
        PulseError: (naming the channel file) a channel that covers no time in common with the first.
    """

    def time_of(c: dict[str, Any]) -> np.ndarray:
        return c["t_first"] + np.arange(c["n"]) * c["dt"]

    def end(c: dict[str, Any]) -> float:
        return c["t_first"] + (c["n"] - 1) * c["dt"]

    ref = chans[0]
    same = all(
        c["n"] == ref["n"]
        and abs(c["dt"] - ref["dt"]) <= 1e-9 * ref["dt"]
        and abs(c["t_first"] - ref["t_first"]) <= 1e-12
        for c in chans[1:]
    )
    if same:
        return time_of(ref), np.stack([c["acc"] for c in chans])
    lo = max(c["t_first"] for c in chans)
    hi = min(end(c) for c in chans)
    dt = min(c["dt"] for c in chans)
    n = math.floor((hi - lo) / dt * (1 + 1e-12)) + 1 if hi >= lo else 0
    if n < MIN_SAMPLES:
        # the channel that shares MIN_SAMPLES instants with the fewest others is named, where one is (of two, neither:
        # the latest starting one was named, and with the first channel off it was the other)
        def shared(a: dict[str, Any], b: dict[str, Any]) -> bool:
            return min(end(a), end(b)) - max(a["t_first"], b["t_first"]) >= (MIN_SAMPLES - 1) * dt

        overlaps = [sum(shared(a, b) for b in chans) for a in chans]
        odd = [i for i, v in enumerate(overlaps) if v == min(overlaps)]
        spans = ", ".join(f"{p.name} {c['t_first']:g} to {end(c):g} s" for p, c in zip(files, chans, strict=True))
        raise _err(
            f"the channels read ({spans}) share {max(n, 0)} sampling instants of {dt:g} s, fewer than {MIN_SAMPLES}"
            f"{f'; {files[odd[0]].name} lies apart from the others' if len(odd) == 1 else ''}: choose channels "
            "recorded over the same time (channels=)",
            files[odd[0]] if len(odd) == 1 else mme,
        )
    time = lo + np.arange(n) * dt
    differ = [f"{p.name} ({1.0 / c['dt']:.6g} Hz from {c['t_first']:g} s)" for p, c in zip(files, chans, strict=True)]
    warnings.warn(
        f"{mme.name}: the channels read have other time bases ({', '.join(differ)}); each is interpolated linearly "
        f"onto {1.0 / dt:.6g} Hz from {lo:g} to {float(time[-1]):g} s, the span all of them cover",
        UserWarning,
        stacklevel=4,
    )
    return time, np.stack([np.interp(time, time_of(c), c["acc"]) for c in chans])


def _mme_text(text: str, what: str) -> None:
    """Refuse header text that an ISO-MME file, Latin-1 (ISO 8859-1) text of one ``Name :value`` per line, cannot
    hold: a character outside Latin-1, a line break (which would end the header line there), or text whose Latin-1
    bytes are also UTF-8 for other text (``Maß²``: DF B2), which :func:`read_mme` would read as UTF-8."""
    for ch in text:
        if ch in "\n\r":
            why = "is a line break, which would end the header line there"
        elif ord(ch) > 0xFF:
            why = "is not a Latin-1 character; ISO-MME files are Latin-1 (ISO 8859-1) text"
        else:
            continue
        raise PulseError(f"write_mme: {what} {text!r}: {ch!r} (U+{ord(ch):04X}) {why}; rename it")
    back = _decode_line(text.encode("latin-1"), ())
    if back != text:
        raise PulseError(f"write_mme: {what} {text!r}: its Latin-1 bytes are also UTF-8 text, so a reader (read_mme "
                         f"among them) would read it back as {back!r}; rename it")  # fmt: skip


def _mme_test_name(test: str) -> None:
    """Refuse a test name that cannot be the stem of the test's files (``<test>.mme``, ``Channel/<test>.001``):
    empty, or holding a path separator or a NUL; then as :func:`_mme_text`."""
    if not test:
        raise PulseError("write_mme: test name '' is empty; it is the stem of the test's files (<test>.mme)")
    for ch, why in (("/", "is a path separator"), ("\0", "cannot stand in a file name")):
        if ch in test:
            raise PulseError(f"write_mme: test name {test!r}: {ch!r} (U+{ord(ch):04X}) {why}, and the test name is "
                             "the stem of its files (<test>.mme, Channel/<test>.001); rename it")  # fmt: skip
    _mme_text(test, "test name")


_CHANNEL_CODE = re.compile(r"[0-9A-Z]{16}")
"""An ISO-MME channel code: 16 capital letters and digits (test object, position, main location [4], fine locations
1-3 [2 each], physical dimension [2], direction, filter class), e.g. ``11HEAD0000H3ACXP``."""


def _is_channel_code(name: str) -> bool:
    """Whether ``name`` has the form of an ISO-MME channel code (:data:`_CHANNEL_CODE`)."""
    return _CHANNEL_CODE.fullmatch(name) is not None


def write_mme(pulse: Pulse, folder: str | Path, test: str = "TEST", *, unit: str = "g") -> Path:
    """Write a uniformly sampled pulse as an ISO-MME test folder that :func:`read_mme` reads.

    Args:
        pulse: the pulse (uniform sampling required).
        folder: the test folder (created with its parents where missing; an existing one is written into). The
            test is written whole or not at all: a failure midway (a full disk) leaves the folder as it was.
        test: the test name (file stem).
        unit: acceleration unit of the channel files, ``g`` or ``m/s**2``.

    Each channel's name is written as its ``Name of the channel``, and as its ``Channel code`` where it is one (16
    capital letters and digits, ``11HEAD0000H3ACXP``, as the channels of a pulse read from a test are named); any other
    name gets the code ``NOVALUE``, ISO-MME's "not given". A code made up for it would claim a test object, a position
    and a location on the vehicle that ``write_mme`` does not know, and :func:`read_mme` names a channel by its code,
    where given, else by its name: the names read back as written either way.

    Returns:
        The path of ``<folder>/<test>.mme``.

    Raises:
        PulseError: non-uniform sampling, an unknown unit, or a test or channel name that an ISO-MME file cannot
            hold (a character outside Latin-1, or a line break), or a test name that cannot name its files (empty,
            holding ``/`` or a NUL), naming it and the character, or a channel folder that holds a file of the
            test that is not one of its channels (``<test>.003`` left from a 3-channel test where the pulse has two,
            ``<test>.0001`` beside the ``<test>.001`` it writes), which :func:`read_mme` would read as one of its
            channels, or a ``<test>.000``, which it would warn about, or a channel list of the test spelled
            otherwise (``<TEST>.CHN``), or a test folder holding two channel folders (``Channel`` and ``channel``),
            or the ``.mme`` file of another test (or of the test spelled otherwise),
            or a ``folder`` that is a file or inside one; nothing is written then.
    """
    if not pulse.is_uniform:
        raise PulseError("ISO-MME needs uniform sampling; resample the pulse first")
    factor = acc_unit_factor(unit)
    _mme_test_name(test)  # everything written is checked before anything is
    _mme_text(unit, "unit")
    for k, name in enumerate(pulse.channels, start=1):
        _mme_text(name, f"channel {k} name")
    folder = Path(folder)
    for q in (folder, *folder.parents):  # the nearest that exists must be a folder
        if q.exists():
            if not q.is_dir():
                raise PulseError(f"write_mme: {q} is a file; expected a test folder" + ("" if q == folder else
                                 f" or a folder to make {folder} in"))  # fmt: skip
            break
    folders = _channel_folders(folder) if folder.is_dir() else []
    if len(folders) > 1:
        raise PulseError(f"write_mme: {file_label(folder)}: {_two_channel_folders(folders)}")
    chan_dir = folders[0] if folders else folder / "Channel"  # as another tool may have spelled it ('CHANNEL')
    for p in sorted(_numbered_files(chan_dir, test)) if chan_dir.is_dir() else ():
        mine = chan_dir / f"{test}.{int(p.suffix[1:]):03d}"  # a file this test writes over is no other channel
        if int(p.suffix[1:]) == 0:
            raise PulseError(f"write_mme: the {chan_dir.name} folder holds {p.name}, which is {_NUMBERED_ZERO} and "
                             "read_mme would warn about; remove it or write the test to another folder")  # fmt: skip
        if not (1 <= int(p.suffix[1:]) <= pulse.n_channels and mine.is_file() and mine.samefile(p)):
            raise PulseError(f"write_mme: the {chan_dir.name} folder holds {p.name}, which read_mme would read as a "
                             f"channel of test {test!r} (the pulse has {pulse.n_channels} channels); remove it or "
                             "write the test to another folder")  # fmt: skip
    for p in sorted(chan_dir.iterdir()) if chan_dir.is_dir() else ():
        mine = chan_dir / f"{test}.chn"  # the list this test writes over is no other list
        if p.suffix.lower() == ".chn" and p.stem.lower() == test.lower() and not (mine.is_file() and mine.samefile(p)):
            raise PulseError(f"write_mme: the {chan_dir.name} folder holds {p.name}, a channel list of test "
                             f"{test!r} beside the {mine.name} it writes; remove it or write the test to another "
                             "folder")  # fmt: skip
    mme = folder / f"{test}.mme"
    for p in sorted(folder.iterdir()) if folder.is_dir() else ():  # read_mme of the folder takes its one .mme file
        if p.is_file() and p.suffix.lower() == ".mme" and not (mme.is_file() and mme.samefile(p)):
            raise PulseError(f"write_mme: the test folder holds {p.name}, the .mme file of a test beside the "
                             f"{mme.name} it writes; read_mme reads a test folder of one test: remove it or write the "
                             "test to another folder")  # fmt: skip
    files = {mme.name: "Data format edition number  :1.6\n"
                       f"Laboratory test ref. number :{test}\n"
                       "Title                       :written by marlcrash\n"
                       f"Number of channels          :{pulse.n_channels}\n"}  # fmt: skip
    lines = ["Instrumentation standard    :ISO 6487", f"Number of channels          :{pulse.n_channels}"]
    for k, name in enumerate(pulse.channels, start=1):
        lines.append(f"Name of channel {k:03d}         :{name}")
    channel_files = {f"{test}.chn": "\n".join(lines) + "\n"}
    for k, name in enumerate(pulse.channels, start=1):
        head = [
            f"Name of the channel         :{name}",
            f"Channel code                :{name if _is_channel_code(name) else 'NOVALUE'}",
            f"Channel frequency class     :{pulse.cfc if pulse.cfc is not None else 'NOVALUE'}",
            f"Unit                        :{unit}",
            "Reference system            :SAE",
            f"Time of first sample        :{float(pulse.time[0])!r}",
            f"Sampling interval           :{float(pulse.dt)!r}",
            f"Number of samples           :{pulse.n_samples}",
        ]
        body = "\n".join(f"{v!r}" for v in (pulse.acc[k - 1] / factor).tolist())
        channel_files[f"{test}.{k:03d}"] = "\n".join(head) + "\n" + body + "\n"
    _write_mme_files(folder, chan_dir.name, files, channel_files)
    return mme


def _write_mme_files(folder: Path, chan_name: str, files: dict[str, str], channel_files: dict[str, str]) -> None:
    """Write ``files`` into ``folder`` and ``channel_files`` into its channel folder ``chan_name``, whole or not at
    all: into a new hidden folder (beside ``folder`` where it is new, inside it where it exists, on the same file
    system either way), flushed to disk, then renamed into place: the new folder at once, into an existing one the
    channel folder at once where it is new, else the channel files, then the test's ``.mme`` file last. A failure
    while writing (a full disk) leaves a new folder absent and an existing one as it was; the hidden one is removed.
    A failure among the renames into an existing folder (:func:`_move_into`) puts back what they replaced.
    """
    import shutil

    from marlcrash.outputs import new_sibling, sync_folder

    def made(tmp: Path) -> bool:
        try:
            tmp.mkdir()
        except FileExistsError:
            return False
        return True

    existed = folder.is_dir()
    if existed:
        first = folder / next(iter(files))  # <test>.mme, named where no temporary name is free
        stage = new_sibling(first, lambda token: f".{first.stem}.{token}.tmp", made)
    else:
        folder.parent.mkdir(parents=True, exist_ok=True)
        stage = new_sibling(folder, lambda token: f".{folder.name}.{token}.tmp", made)
    try:
        (stage / chan_name).mkdir()
        for where, written in ((stage, files), (stage / chan_name, channel_files)):
            for name, text in written.items():
                (where / name).write_text(text, encoding="latin-1")
            sync_folder(where)  # on disk before a name points at them
        if not existed:
            stage.rename(folder)  # refused where a folder was made there meanwhile: nothing is replaced then
            sync_folder(folder.parent, files=False)
            return
        chan_dir = folder / chan_name
        new_chan = not chan_dir.exists()
        moves = [] if new_chan else [(stage / chan_name / name, chan_dir / name) for name in channel_files]
        moves += [(stage / name, folder / name) for name in files]  # the .mme file last
        _move_into(moves, stage / ".old", (stage / chan_name, chan_dir) if new_chan else None)
        if not new_chan:
            sync_folder(chan_dir, files=False)
        sync_folder(folder, files=False)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _move_into(moves: list[tuple[Path, Path]], old: Path, new_folder: tuple[Path, Path] | None) -> None:
    """Rename the files ``moves`` (source, target) into place, after the folder ``new_folder`` (source, target) where
    given, all or none: each target there is first linked (else copied) into the new folder ``old``, and where a rename
    fails, those done are undone, in reverse order, before the error goes on (one that cannot be undone is added to
    its notes). The renames are not atomic as a set for a reader that looks meanwhile, nor across a system crash."""
    import shutil

    old.mkdir()
    kept: dict[Path, Path] = {}
    for i, (_, target) in enumerate(moves):
        if target.exists() or target.is_symlink():
            try:
                os.link(target, old / str(i), follow_symlinks=False)  # no copy, on the file system of the target
            except (OSError, NotImplementedError):  # a file system (or platform) without hard links
                shutil.copy2(target, old / str(i), follow_symlinks=False)
            kept[target] = old / str(i)
    done: list[Path] = []
    try:
        if new_folder is not None:
            new_folder[0].rename(new_folder[1])
            done.append(new_folder[1])
        for source, target in moves:
            source.replace(target)
            done.append(target)
    except BaseException as e:
        for target in reversed(done):
            try:
                if new_folder is not None and target == new_folder[1]:
                    target.rename(new_folder[0])
                elif target in kept:
                    kept[target].replace(target)
                else:
                    target.unlink()
            except OSError as undo:
                e.add_note(f"write_mme: could not put back {target} as it was: {undo}")
        raise


def is_mme(path: Path) -> bool:
    """``path`` names an ISO-MME test (its folder or its ``.mme`` file), not a CSV file."""
    return path.is_dir() or path.suffix.lower() == ".mme"


def _not_a_pulse_file(path: Path) -> PulseError:
    """The error for a path that is neither a CSV file nor an ISO-MME test by its name: a missing one (a mistyped
    test folder has no suffix either) is said to be missing, not of the wrong kind."""
    if not path.exists():
        return _err("no such file or folder; expected a .csv/.txt file, a .mme file or an ISO-MME test folder", path)
    return _err("expected a .csv/.txt file, a .mme file or an ISO-MME test folder", path)


def read_pulse(path: str | Path, **kwargs: Any) -> Pulse:
    """Read a CSV file (``.csv``/``.txt``) or an ISO-MME test (folder or ``.mme``) by its path.

    ``kwargs`` go to :func:`read_csv` or :func:`read_mme`; ``acc_col`` is accepted for both
    (for ISO-MME it selects channels). For ISO-MME the CSV options ``unit``, ``time_unit`` and ``time_col`` are
    refused unless left at their defaults (a channel carries its unit and time base), as is ``breakpoints``.
    """
    path = Path(path)
    if is_mme(path):
        if "acc_col" in kwargs:
            _names(kwargs["acc_col"], "acc_col", "channel")  # named as given
            kwargs["channels"] = kwargs.pop("acc_col")
        unit = kwargs.pop("unit", None)
        if unit is not None and not (isinstance(unit, str) and acc_unit_key(unit) == "g"):  # 'G' as read_csv takes it
            raise PulseError(f"{path.name}: ISO-MME channels carry their own 'Unit'; do not pass unit={unit!r}")
        for key, default in (("time_unit", "s"), ("time_col", None)):  # were dropped without a word
            value = kwargs.pop(key, default)
            if value != default:
                raise PulseError(f"{path.name}: ISO-MME channels carry their own time base ('Time of first sample', "
                                 f"'Sampling interval', in s); do not pass {key}={value!r}")  # fmt: skip
        if kwargs.pop("breakpoints", False):
            raise PulseError(f"{path.name}: breakpoints=True applies to CSV files only: an ISO-MME channel is "
                             "sampled, not a table of breakpoints")  # fmt: skip
        return read_mme(path, **kwargs)
    if path.suffix.lower() in (".csv", ".txt"):
        return read_csv(path, **kwargs)
    raise _not_a_pulse_file(path)


# ------------------------------------------------------------------------------------- summary, plot


def pulse_summary(path: str | Path, **options: Any) -> dict[str, Any]:
    """Key figures of one acceleration channel of a pulse file (the ``marlcrash pulse`` command).

    The channel is prepared by :func:`processed_pulse` (resampled if non-uniform, CFC-filtered,
    time zero found; ``options`` are its keyword arguments) and summarized by :func:`pulse_figures`.
    """
    return pulse_figures(*processed_pulse(path, **options), path=path)


SPEED_UP_NOTE = 0.5
"""[m/s] A velocity gain above this (the channel speeding up) is named in a warning by :func:`pulse_figures`; a crash
changes the velocity by 10 m/s and more; the drift of a 0.3 g transducer offset over 150 ms stays below it."""


MAX_CRASH_DELTA_V = 50.0
"""[m/s] A velocity change above this (180 km/h: a full rebound from 90 km/h) is no vehicle crash test's and is named
in a warning by :func:`pulse_figures` as a likely unit mix-up: m/s^2 read as g gives 9.8x the velocity change (a
56 km/h test: 550 km/h)."""


def pulse_figures(pulse: Pulse, work: Pulse, t0: float, path: str | Path = "") -> dict[str, Any]:
    """Key figures of a channel prepared by :func:`processed_pulse` (filtered acceleration integrated from time zero).

    Args:
        pulse, work, t0: what :func:`processed_pulse` returns (the record as read, uniform and filtered,
            time zero on the file's clock [s]).
        path: the file, for the ``file`` entry.

    Returns:
        A JSON-ready dict: ``file``, ``channel``, ``n_samples``, ``sample_rate_hz``, ``duration_ms``,
        ``cfc``, ``t0_ms`` (time zero on the file's clock), ``peak_g`` (largest magnitude of the
        filtered acceleration), ``t_peak_ms`` (after time zero), ``delta_v_ms`` (magnitude of the
        velocity change from before the impact to the end of the record, m/s), ``delta_v_max_ms`` (largest
        magnitude reached), ``delta_v_150ms_ms`` (at 150 ms after time zero; ``None`` if the record
        ends before) and ``delta_v_kmh`` (``delta_v_ms`` in km/h).

    A channel whose largest velocity change is a gain of more than :data:`SPEED_UP_NOTE` is named in a warning: a
    frontal crash pulse is negative in the module's sign (SAE J211), and one read with the other sign convention
    gave the same figures without a word. So is one whose largest velocity change exceeds :data:`MAX_CRASH_DELTA_V`
    (an acceleration in m/s^2 read as g gave 674 km/h without a word).

    "Before the impact" is :data:`~marlcrash.pulse.signal.PRE_IMPACT_TIME` before time zero, or the
    start of the filtered record (which includes the lead-in of :func:`filtered_from_time_zero`): the
    zero-phase filter spreads the first deceleration before time zero, and a velocity change counted
    from time zero lost that part (an up-front sensor of a ``marlcrash simulate --csv`` record read with
    ``--time-zero file``: 7.7 of its 12.0 m/s; a 3 ms half-sine at the first sample: 17 %).
    """
    acc = work.acc[0]
    v = work.velocity()[0]
    v_rel = v - np.interp(max(t0 - PRE_IMPACT_TIME, float(work.time[0])), work.time, v)
    after = work.time >= t0
    largest = float(v_rel[after][np.argmax(np.abs(v_rel[after]))])
    if largest > SPEED_UP_NOTE:  # a frontal crash slows the vehicle: SAE J211's frame, the module's convention
        warnings.warn(
            f"{path or pulse.source or 'pulse'}: channel {pulse.channels[0]!r} speeds up by {largest:.3g} m/s (its "
            "largest velocity change is positive); in marlcrash's sign (SAE J211, x forward) a frontal crash pulse is "
            "negative. If this is one, the file records deceleration as positive: read it with the other sign "
            "(--deceleration-positive, sign=-1; or without it, if given). The figures are magnitudes either way",
            UserWarning,
            stacklevel=2,
        )
    if abs(largest) > MAX_CRASH_DELTA_V:
        warnings.warn(
            f"{path or pulse.source or 'pulse'}: channel {pulse.channels[0]!r} changes velocity by {abs(largest):.4g} "
            f"m/s ({abs(largest) * 3.6:.4g} km/h), more than any vehicle crash test (a full rebound from 90 km/h is "
            f"{MAX_CRASH_DELTA_V:g} m/s): is the acceleration in another unit than it was read in? An acceleration in "
            f"m/s2 read as g (the CSV default) is {G0:.4g}x too large: read it with --unit m/s2 (unit: m/s2)",
            UserWarning,
            stacklevel=2,
        )
    i_peak = int(np.argmax(np.abs(acc)))
    t150 = t0 + 0.150
    dv150 = float(abs(np.interp(t150, work.time, v_rel))) if t150 <= work.time[-1] + 1e-12 else None
    return {
        "file": str(path),
        "channel": pulse.channels[0],
        "n_samples": pulse.n_samples,
        "sample_rate_hz": float(pulse.sample_rate_hz),
        "duration_ms": float((pulse.time[-1] - pulse.time[0]) * 1e3),
        "cfc": work.cfc,
        "t0_ms": float(t0 * 1e3),
        "peak_g": float(abs(acc[i_peak]) / G0),
        "t_peak_ms": float((work.time[i_peak] - t0) * 1e3),
        "delta_v_ms": float(abs(v_rel[-1])),
        "delta_v_max_ms": float(np.max(np.abs(v_rel[after]))),
        "delta_v_150ms_ms": dv150,
        "delta_v_kmh": float(abs(v_rel[-1]) * 3.6),
    }


def processed_pulse(
    path: str | Path,
    *,
    time_col: str | None = None,
    acc_col: str | None = None,
    unit: str = "g",
    time_unit: str = "s",
    cfc: int | None = 60,
    sign: float = 1.0,
    time_zero: str = "threshold",
    threshold_g: float = DEFAULT_THRESHOLD_G,
    breakpoints: bool = False,
) -> tuple[Pulse, Pulse, float]:
    """Read one acceleration channel and prepare it as :func:`pulse_summary` and ``marlcrash pulse --plot`` use it.

    The channel's transducer offset, the mean of its samples before the contact, is subtracted first
    (:func:`~marlcrash.pulse.signal.without_zero_offset`, as a file reference does: with ``time_zero="threshold"``
    the samples before the pulse's onset, whatever the record's clock). A non-uniform record is resampled at its
    mean rate, then CFC-filtered at that rate; time zero is the pulse's onset
    (:func:`~marlcrash.pulse.signal.find_onset`), or the file's t = 0 with ``time_zero="file"``. A channel with
    too little pre-trigger data to measure its zero level is named in a warning.

    Args:
        path: CSV file, ``.mme`` file or ISO-MME test folder.
        time_col: CSV time column (see :func:`read_csv`).
        acc_col: the channel (CSV column or MME channel), one name; default the first acceleration channel.
        unit: CSV acceleration unit, ``g`` or ``m/s2``.
        time_unit: CSV time unit, ``s`` or ``ms``.
        cfc: CFC class, or ``None`` for no filtering.
        sign: ``+1`` or ``-1`` (see the module docstring).
        time_zero: ``"threshold"`` or ``"file"``.
        threshold_g: the lowest onset detection level [g] (:func:`~marlcrash.pulse.signal.find_onset`).
        breakpoints: the CSV rows are the corners of a piecewise linear pulse (:func:`read_csv`).

    Returns:
        ``(raw, work, t0)``: the channel as read (a table of breakpoints sampled at :data:`BREAKPOINT_RATE_HZ`),
        the uniform (filtered) one on the file's clock, and time zero [s] on that clock.

    Raises:
        PulseError: unreadable file, bad channel, a sampling rate below :data:`MIN_RECORD_RATE_HZ` (a time
            column in ms read as s, typically), or time zero outside the record (naming the file).
    """
    if acc_col is not None and not isinstance(acc_col, str):  # a list was read and all but its first dropped
        raise PulseError(f"acc_col: expected one channel name (a CSV column or an ISO-MME channel; one channel is "
                         f"prepared), got {acc_col!r}")  # fmt: skip
    kwargs: dict[str, Any] = {"sign": sign}
    p = Path(path)
    mme = is_mme(p)
    if not mme:
        kwargs.update(time_col=time_col, unit=unit, time_unit=time_unit, breakpoints=breakpoints)
    elif breakpoints:
        raise _err("--breakpoints (breakpoints=True) applies to CSV files only: an ISO-MME channel is sampled, not "
                   "a table of breakpoints", p)  # fmt: skip
    else:  # named as typed, on the command line (marlcrash pulse) and in Python
        given = [f"--{name.replace('_', '-')} {value} ({name}={value!r})"
                 for name, value, default in (("time_col", time_col, None), ("unit", unit, "g"),
                                              ("time_unit", time_unit, "s"))
                 if value != default and not (name == "unit" and acc_unit_key(str(value)) == "g")]  # fmt: skip
        if given:
            verb = "applies to CSV files only and is" if len(given) == 1 else "apply to CSV files only and are"
            warnings.warn(f"{p.name}: ISO-MME channels carry their own time base and unit; {', '.join(given)} {verb} "
                          "ignored", stacklevel=2)  # fmt: skip
    if acc_col is not None:
        kwargs["acc_col"] = acc_col
    elif not mme:  # the first acceleration column only, as of an ISO-MME test: the others are not read
        kwargs["first_only"] = True
    if mme:  # the first acceleration channel only (others may have their own time base), each file read once
        pulse = _read_mme(p, acc_col, sign, first_acceleration=acc_col is None).select(0)
    elif p.suffix.lower() in (".csv", ".txt"):  # the file read once, its first acceleration column found in it
        pulse = read_csv(p, **kwargs).select(0)
    else:
        raise _not_a_pulse_file(p)
    check_record_rate(pulse, p, time_unit=time_unit)
    try:
        # the transducer offset, from the samples before the contact, as a file reference removes it
        work, t0 = filtered_from_time_zero(without_zero_offset(pulse, time_zero, cfc, threshold_g), cfc, time_zero,
                                           threshold_g)  # fmt: skip
    except PulseError as e:  # e.g. a sampling rate too low for the filter class: say which file
        if p.name not in str(e):
            raise _err(str(e), p) from None
        raise
    if not on_record(pulse, t0):
        what = hint = ""
        if time_zero == "file":  # named as typed, on the command line and in Python
            what = " (the file's t = 0, --time-zero file; time_zero='file')"
            hint = (": its clock does not start at the contact; read it with --time-zero threshold "
                    "(time_zero='threshold')")  # fmt: skip
        raise _err(f"time zero {t0:.6g} s{what} lies outside the record [{pulse.time[0]:.6g}, "
                   f"{pulse.time[-1]:.6g}] s{hint}", p)  # fmt: skip
    return pulse, work, t0


def check_record_rate(pulse: Pulse, path: str | Path, *, time_unit: str = "s") -> None:
    """Refuse a record sampled below :data:`MIN_RECORD_RATE_HZ` or longer than :data:`MAX_RECORD_S` (a time column
    in ms read as s, typically) or shorter than :data:`MIN_RECORD_S` or sampled above :data:`MAX_RECORD_RATE_HZ`
    (one in s read as ms).

    Args:
        pulse: the record as read.
        path: its file or ISO-MME test, named in the error.
        time_unit: the CSV time unit it was read with (chooses the hint).

    Raises:
        PulseError: naming the file, the rate and the likely cause.
    """
    p = Path(path)
    span = float(pulse.time[-1] - pulse.time[0])
    if span < MIN_RECORD_S or pulse.sample_rate_hz > MAX_RECORD_RATE_HZ:
        cause = "is the time column in seconds (--time-unit s; time_unit: s)?" if time_unit == "ms" else (
            "is the record complete, and its time in the unit given?")  # fmt: skip
        raise _err(
            f"record of {span * 1e3:.4g} ms at {pulse.sample_rate_hz:.4g} Hz: crash pulse records last tens to "
            f"hundreds of ms at 10-100 kHz (accepted here: at least {MIN_RECORD_S * 1e3:g} ms, at most "
            f"{MAX_RECORD_RATE_HZ:.0e} Hz); {cause}",
            p,
        )
    if pulse.sample_rate_hz >= MIN_RECORD_RATE_HZ:
        if span > MAX_RECORD_S:
            cause = "is the record's time in the unit given?" if time_unit == "ms" or is_mme(p) else _UNIT_HINT
            raise _err(
                f"record of {span:.4g} s at {pulse.sample_rate_hz:.4g} Hz: crash pulse records last tens to hundreds "
                f"of ms (accepted here: at most {MAX_RECORD_S:g} s); {cause}",
                p,
            )
        return
    mme = is_mme(p)
    if mme:
        cause = "is the channel's 'Sampling interval' in seconds?"
    elif time_unit == "s":
        cause = _UNIT_HINT
    else:
        cause = "is the time column in the unit given?"
    table = ("" if mme else " A table of breakpoints (the corners of a piecewise linear pulse) is read as such with "
             "--breakpoints (breakpoints: true)")  # fmt: skip
    raise _err(
        f"sampling rate {pulse.sample_rate_hz:.4g} Hz (record of {pulse.time[-1] - pulse.time[0]:.4g} s): crash "
        f"accelerometer records are sampled at {MIN_RECORD_RATE_HZ:g} Hz or more; {cause}{table}",
        p,
    )


def plot_pulse(
    pulse: Pulse,
    path: str | Path,
    *,
    reference: Pulse | None = None,
    title: str | None = None,
) -> Path:
    """Write a PNG with acceleration [g] and velocity change [km/h] of every channel.

    Args:
        pulse: the pulse to draw (all channels).
        path: the PNG to write.
        reference: an optional second pulse drawn dashed (e.g. the reference of a calibration).
        title: figure title (default: the pulse's source file name).

    Returns:
        ``path``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(8, 6), dpi=100)
    FigureCanvasAgg(fig)
    ax_a, ax_v = fig.subplots(2, 1, sharex=True)
    for p, style, tag in ((pulse, "-", ""), (reference, "--", " (ref)")):
        if p is None:
            continue
        v = p.velocity()
        for k, name in enumerate(p.channels):
            label = f"{name}{tag}" + (f" CFC{p.cfc}" if p.cfc else "")
            ax_a.plot(p.time * 1e3, p.acc[k] / G0, style, lw=1.2, label=label)
            ax_v.plot(p.time * 1e3, v[k] * 3.6, style, lw=1.2, label=label)
    ax_a.set_ylabel("acceleration [g]")
    ax_v.set_ylabel("velocity change [km/h]")
    ax_v.set_xlabel("time [ms]")
    for ax in (ax_a, ax_v):
        ax.grid(True, alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.5)
    ax_a.legend(loc="best", fontsize=8)
    fig.suptitle(title if title is not None else (Path(pulse.source).name if pulse.source else "pulse"))
    fig.tight_layout()
    return save_figure(fig, path, dpi="figure")
