"""Training logs: one CSV file per run by default, TensorBoard on request (DESIGN 6).

A logger receives one row of scalars per training iteration (:meth:`RunLogger.log`).
The CSV file is the source of truth (learning curves are plotted from it); its
:attr:`CSVLogger.position` (rows written) is stored in checkpoints so that a resumed
run first cuts the rows written after the checkpoint (:meth:`CSVLogger.truncate`) and
its log reads exactly like an uninterrupted run's.

TensorBoard (``logger: tensorboard``) writes event files *in addition* to the CSV; it
needs the ``tensorboard`` extra (``pip install -e ".[tensorboard]"``) and is imported
only when asked for.
"""

from __future__ import annotations

import csv
import math
import numbers
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from marlcrash.errors import ConfigError
from marlcrash.outputs import atomic_output

if TYPE_CHECKING:  # imported where a TensorBoard log is asked for: it needs the tensorboard extra
    from torch.utils.tensorboard import SummaryWriter

LOG_FILE = "log.csv"
"""Name of the CSV log inside a run folder."""

LOGGERS: tuple[str, ...] = ("csv", "tensorboard")
"""Logger names accepted by :func:`make_logger`."""


class CSVLogger:
    """Appends one row of scalars per iteration to ``<run_dir>/log.csv``.

    The columns are fixed by the first row written (later rows must have the same keys);
    integers (the counts) are written as integers and other values with ``repr``, so a float read back is the
    float written.

    Args:
        run_dir: the run folder (created if missing).
    """

    def __init__(self, run_dir: str | Path):
        self.path = Path(run_dir) / LOG_FILE
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns: list[str] | None = None
        self.position = 0
        if self.path.is_file():  # counted, not parsed: a resume cuts the rows after its checkpoint (a torn one too)
            lines = _lines(self.path)
            self.position = max(0, len(lines) - 1)
            if lines:
                self.columns = _header(self.path, *lines[0])

    def log(self, row: dict[str, float]) -> None:
        """Append one row ``{column: value}``; the first row fixes the columns.

        Raises:
            ValueError: the row's keys differ from the columns of the file.
        """
        if self.columns is None:
            self.columns = list(row)
            with open(self.path, "w", newline="", encoding="utf-8") as fh:
                csv.writer(fh).writerow(self.columns)
        if list(row) != self.columns:
            raise ValueError(f"log row keys {sorted(row)} differ from the columns of {self.path}: {self.columns}")
        with open(self.path, "a", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerow([_fmt(row[c]) for c in self.columns])
            fh.flush()
            os.fsync(fh.fileno())
        self.position += 1

    def require_columns(self, columns: Sequence[str], key: str) -> None:
        """Refuse a log whose columns are not ``columns``, the ones the rows to come have (a run started by a version
        that logged others): no row could be appended to it. A log not yet written passes.

        Raises:
            ConfigError: (``key``) naming the file and the columns that differ.
        """
        if self.columns is None or self.columns == list(columns):
            return
        extra = [c for c in self.columns if c not in columns]
        missing = [c for c in columns if c not in self.columns]
        differ = [f"{what}: {', '.join(map(repr, cs))}" for what, cs in (("columns not written now", extra),
                  ("columns missing", missing)) if cs] or ["the same columns in another order"]  # fmt: skip
        raise ConfigError(
            f"the columns of {self.path} differ from the ones this version of marlcrash writes ({'; '.join(differ)}), "
            "so no row can be appended: the run was started by another version. Resume it with that version, or start "
            "a new run",
            key=key,
            path=self.path,
        )

    def truncate(self, position: int) -> None:
        """Keep only the first ``position`` rows (rows written after a checkpoint are cut on resume).

        The rows after ``position`` are dropped unread: a row torn by a kill during its write is one of them. A log
        with fewer rows (deleted or cut short since the checkpoint) is kept as it is, with a warning: the rows it
        lacks are lost, and the learning curves will miss those iterations.

        Raises:
            ConfigError: a row kept is not one number per column (naming the file and line).
        """
        lines = _lines(self.path)[: position + 1] if self.path.is_file() else []
        if max(len(lines) - 1, 0) < position:
            held = "is missing" if not lines else f"holds {len(lines) - 1} rows"
            warnings.warn(
                f"{self.path} {held}, the checkpoint counts {position}: the log of iterations "
                f"{max(len(lines), 1)}-{position} is lost (the run goes on; its learning curves will lack them)",
                stacklevel=2,
            )
        if not lines:
            self.position = 0
            return
        columns = _header(self.path, *lines[0])
        keep = [columns] + [_values(self.path, n, text, columns) for n, text in lines[1:]]
        with atomic_output(self.path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows(keep)
        self.position = len(keep) - 1
        self.columns = keep[0]

    def close(self) -> None:
        """Nothing to release (every row is flushed as written)."""


class TensorBoardLogger(CSVLogger):
    """The CSV log plus TensorBoard event files in ``<run_dir>/tensorboard/``.

    Raises:
        ConfigError: the ``tensorboard`` package is not installed.
    """

    def __init__(self, run_dir: str | Path):
        super().__init__(run_dir)
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            raise ConfigError(
                "TensorBoard logging needs the 'tensorboard' extra: pip install -e \".[tensorboard]\" "
                "(or choose logger: csv)",
                key="logger",
            ) from None
        self._writer_class = SummaryWriter
        self._log_dir = str(Path(run_dir) / "tensorboard")
        self._purge_step: int | None = None
        # opened by the first row, after a resume's truncate has set the purge step
        self.writer: SummaryWriter | None = None

    def truncate(self, position: int) -> None:
        """Cut the CSV rows after ``position`` and drop TensorBoard events from step ``position + 1`` on (steps are
        iterations, 1-based) once the next row opens the event file."""
        super().truncate(position)
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        self._purge_step = self.position + 1

    def log(self, row: dict[str, float]) -> None:
        """Append the CSV row and write each value as a scalar at step ``iteration``."""
        step = int(row.get("iteration", self.position + 1))
        super().log(row)
        if self.writer is None:
            self.writer = self._writer_class(log_dir=self._log_dir, purge_step=self._purge_step)
        for k, v in row.items():
            if k != "iteration":
                self.writer.add_scalar(k, float(v), step)
        self.writer.flush()

    def close(self) -> None:
        """Close the event file."""
        if self.writer is not None:
            self.writer.close()
            self.writer = None


RunLogger = CSVLogger
"""The logger interface (:class:`TensorBoardLogger` extends it)."""


def make_logger(kind: str, run_dir: str | Path) -> CSVLogger:
    """A logger by name: ``csv`` or ``tensorboard`` (CSV plus event files).

    Raises:
        ConfigError: unknown name, or TensorBoard asked for but not installed.
    """
    if kind == "csv":
        return CSVLogger(run_dir)
    if kind == "tensorboard":
        return TensorBoardLogger(run_dir)
    raise ConfigError(f"unknown logger {kind!r}; expected one of {list(LOGGERS)}", key="logger")


def read_log(path: str | Path, rows: int | None = None, columns: Sequence[str] = ()) -> list[dict[str, float]]:
    """Rows of a CSV log as ``{column: float}`` dicts (empty if the file has no rows).

    Args:
        path: the log file.
        rows: read only the first ``rows`` rows (a checkpoint's ``log_position``); the rows after them, which a
            resume would cut, are not parsed (a row torn by a kill during its write is one).
        columns: columns the caller needs; a log without one of them is refused.

    Raises:
        ConfigError: a row read is not one number per column, or a column in ``columns`` is missing, naming the
            file and line.
    """
    path = Path(path)
    lines = _lines(path)
    if not lines:
        return []
    header = _header(path, *lines[0])
    missing = [c for c in columns if c not in header]
    if missing:
        raise ConfigError(f"line 1: no column {missing[0]!r}; expected a log written by train/train.py", path=path)
    body = lines[1:] if rows is None else lines[1 : rows + 1]
    return [dict(zip(header, map(float, _values(path, n, text, header)), strict=True)) for n, text in body]


def _lines(path: Path) -> list[tuple[int, str]]:
    """The non-blank lines of a log as ``(1-based line number, text)``, undecoded bytes kept as escapes: a line is
    decoded (and refused) only where it is parsed, so junk after the rows read costs nothing."""
    raw = path.read_bytes().split(b"\n")
    out = []
    for i, line in enumerate(raw, 1):
        text = line.rstrip(b"\r").decode("utf-8", errors="backslashreplace")
        if text.strip():
            out.append((i, text))
    return out


def _header(path: Path, line: int, text: str) -> list[str]:
    columns = next(csv.reader([text]))
    if any(not c.strip() for c in columns) or len(set(columns)) != len(columns):
        raise ConfigError(f"line {line}: expected the column names of a log (distinct, none empty), got {text!r}",
                          path=path)  # fmt: skip
    return columns


def _values(path: Path, line: int, text: str, columns: list[str]) -> list[str]:
    """The fields of one row, checked to be one number per column."""
    values = next(csv.reader([text]))
    for c, v in zip(columns, values, strict=False):
        try:
            float(v)
        except ValueError:
            raise ConfigError(f"line {line}: expected a number in column {c!r}, got {v!r}", path=path) from None
    if len(values) != len(columns):  # numbers, too few of them: the row a kill cut short
        cut = " (a row cut short: was the run killed while writing it?)" if len(values) < len(columns) else ""
        raise ConfigError(
            f"line {line}: expected {len(columns)} values, one per column of line 1, got {len(values)}{cut}", path=path
        )
    return values


def _fmt(value: Any) -> str:
    if isinstance(value, numbers.Integral):  # counts (iteration, env_steps) stay integers for pandas and the eye
        return str(int(value))
    v = float(value)
    return repr(v) if math.isfinite(v) else str(v)
