"""Error types raised for bad user input.

Every error that a user can cause (a malformed deck, an impossible config value,
a pulse file with non-monotonic time) is raised as one of these types, with a
message that says where (file, line, key), what was expected and what was found.
They subclass :class:`ValueError` so generic callers can catch them too.
"""

from __future__ import annotations

from pathlib import Path


def file_label(path: str | Path) -> str:
    """How a message names a file: its name; the whole resolved path where the name is empty (``.``, ``/``)."""
    p = Path(path)
    return p.name or str(p.resolve())


class MarlcrashError(ValueError):
    """Base class of all user-input errors raised by marlcrash."""


class DeckError(MarlcrashError):
    """A finite-element input deck is malformed or inconsistent.

    Attributes:
        path: the file in which the problem was found (``None`` if not file-based).
        line: 1-based line number in that file (``None`` if not line-based).
        reason: what was expected and what was found.
    """

    def __init__(self, reason: str, path: str | Path | None = None, line: int | None = None):
        self.path = None if path is None else str(path)
        self.line = line
        self.reason = reason
        where = ""
        if self.path is not None:
            where = file_label(self.path) if line is None else f"{file_label(self.path)} line {line}"
            where += ": "
        super().__init__(f"{where}{reason}")


class ModelError(MarlcrashError):
    """A vehicle or cell model is inconsistent (NaN coordinates, dangling ids, ...)."""


class ConfigError(MarlcrashError):
    """A configuration value is missing, of the wrong type, or out of range.

    The message always names the key (dotted path) and, where known, the file.
    """

    def __init__(self, reason: str, key: str | None = None, path: str | Path | None = None):
        self.key = key
        self.path = None if path is None else str(path)
        self.reason = reason
        where = []
        if self.path is not None:
            where.append(file_label(self.path))
        if key is not None:
            where.append(f"key '{key}'")
        prefix = (" ".join(where) + ": ") if where else ""
        super().__init__(f"{prefix}{reason}")


class PulseError(MarlcrashError):
    """A crash pulse (measured or simulated signal) is malformed."""


def report_interrupt(e: KeyboardInterrupt) -> None:
    """Print a Ctrl-C as a command reports it: ``interrupted`` on standard error, then each note the work added to
    the interrupt (:meth:`BaseException.add_note`: what it kept, how to continue), instead of a traceback."""
    import sys

    print("interrupted", file=sys.stderr)
    for note in getattr(e, "__notes__", ()):
        print(note, file=sys.stderr)


def end_by_sigint() -> None:
    """End this process by SIGINT, as an uncaught KeyboardInterrupt does: a shell running it in a loop stops at the
    interrupt, where an exit status (130) would go on to the next command. Returns only where the system has no
    such signal (the caller then exits with 130)."""
    import os
    import signal
    import sys

    if hasattr(signal, "SIGINT") and hasattr(os, "kill"):
        sys.stdout.flush()
        sys.stderr.flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
