"""LS-DYNA keyword deck reader (DESIGN 3): a deck file to a :class:`VehicleModel` in SI.

Coverage:

- formats: fixed (8/10/16-character fields), long (20-character fields; a keyword
  suffix ``+`` or ``*KEYWORD LONG=Y``), I10 (fields under 10 characters widened to
  10; suffix ``%`` or ``*KEYWORD I10=Y``) and free format (comma-separated lines,
  which may stand between fixed-format lines of one block); an include file is read in its includer's format, or
  in the one its ``*INCLUDE`` suffix (``+``, ``%``, ``-``) names; ``$`` comments; reals as Fortran reads them
  (``1.0D+03``, and ``7.85-9``: a signed exponent needs no E);
- structure: ``*KEYWORD``, ``*TITLE``, ``*END`` (ends the current file),
  ``*INCLUDE`` (paths relative to the including file, nested), ``*INCLUDE_PATH``
  and ``*INCLUDE_PATH_RELATIVE`` (a name not found as written is looked up with its backslashes as folder
  separators: a deck written on Windows);
- ``*PARAMETER`` (``R``/``I``/``C`` typed), ``*PARAMETER_EXPRESSION`` and their ``_LOCAL`` forms (values of
  the defining file and the files it includes, before the deck's of the same name: component files may each
  define their own; expressions of arithmetic, ``pi`` and Fortran's intrinsic functions ``abs``, ``aint``, ``int``,
  ``nint``, ``mod``, ``sign``, ``min``, ``max``, ``sqrt``, ``exp``, ``log``, ``log10``, the trigonometric,
  inverse trigonometric and hyperbolic ones); ``&name`` and ``-&name`` in any numeric field. A name defined
  twice keeps its first definition with a note where the value may differ, as LS-DYNA's default
  ``*PARAMETER_DUPLICATION`` (DFLAG 1) does; the deck's own ``*PARAMETER_DUPLICATION`` DFLAG 2-5
  applies to the definitions after it.
  ``params=`` supplies values for parameters the deck uses but does not define,
  and overrides deck values (each override is recorded in ``model.warnings``);
- geometry: ``*NODE`` (blank fields read as 0), ``*ELEMENT_SHELL`` with options
  ``THICKNESS``/``BETA``/``MCID``/``OFFSET`` (element thickness 0 means the
  section's), ``*ELEMENT_SOLID`` (one line of 8 nodes, or the two-line form with 8
  or 10 nodes, 10-node tets kept as their 4 corner nodes; options ``ORTHO``, and ``TET4TOTET10``, ``H8TOH20``,
  ``H8TOH27``, whose cards are plain ones),
  ``*ELEMENT_BEAM`` (options ``THICKNESS`` and ``SECTION`` give element areas, the latter for the circular,
  tubular and solid-box section types ``SECTION_08``, ``_09``, ``_11``, other types taking the part's section area;
  ``PID``/``OFFSET``/``ORIENTATION``/``SCALAR``/``SCALR``/``WARPAGE`` are read past);
- properties: ``*PART`` (title line + card; ``CONTACT``, ``PRINT``,
  ``ATTACHMENT_NODES``, ``AVERAGED`` cards read past, ``INERTIA`` below),
  ``*SECTION_SHELL`` (mean of T1..T4), ``*SECTION_SOLID``, ``*SECTION_BEAM`` (area A
  of resultant/truss beams, or from TS1/TS2/TT1/TT2 for rectangular and tubular
  integrated beams), all with ``_TITLE``;
- materials: ``*MAT_ELASTIC``/``*MAT_001``, ``*MAT_PLASTIC_KINEMATIC``/``*MAT_003``,
  ``*MAT_RIGID``/``*MAT_020``, ``*MAT_PIECEWISE_LINEAR_PLASTICITY``/``*MAT_024``
  (eight-point curves, an LCSS ``*DEFINE_CURVE``, or an LCSS ``*DEFINE_TABLE``/``_2D`` of strain rates, whose
  lowest rate's curve is taken: the cells' crush efficiency carries rate effects), with ``_TITLE``; any other
  ``*MAT_...`` is read for RO, E, PR from its first card where those fields are
  numbers: ``MID RO E PR`` unless :data:`_MAT_LAYOUTS` knows its layout (``*MAT_NULL``, Johnson-Cook,
  foams, rubbers, orthotropic and discrete-beam materials); a card whose PR field is no Poisson's ratio
  has a layout the reader does not know, and its E and PR are defaulted with a note. Springs, dampers and
  seatbelts have no density. Only the materials of the parts kept decide the unit system and must be
  complete. The hardening modulus from ETAN is
  ``E ETAN / (E - ETAN)``; the ultimate strength is the yield stress at the failure
  strain (FS, FAIL) or the curve maximum; the fracture strength the curve value at
  FAIL. Everything else is completed by :func:`complete_material`;
- masses beyond density times volume (:attr:`VehicleModel.point_mass`, ``part_added_mass``,
  ``part_mass``): ``*ELEMENT_MASS`` (a lumped mass on a node) and ``_NODE_SET`` (one mass shared
  equally by the set's nodes), ``*ELEMENT_INERTIA`` (``_OFFSET``; its MASS on its node: cells translate,
  so the inertia tensor and the offset are not needed), ``*ELEMENT_MASS_PART`` and ``_SET`` (ADDMASS
  spread over the part's elements by area, volume or length; FINMASS the part's, or the set's, final
  mass), ``*SECTION_SHELL`` MAREA (mass per area), ``*PART_INERTIA`` TM (a rigid part's whole mass; its
  VTX..VTZ set it moving; a rigid part without elements shares it among its ``*CONSTRAINED_EXTRA_NODES``),
  and ``*CONSTRAINED_NODAL_RIGID_BODY_INERTIA`` (``_SPC``, ``_TITLE``) TM, the body's whole mass, shared
  equally by its node set (lumped masses on those nodes are replaced by it, a note says so; its VTX..VTZ
  set the set moving), ``*SECTION_BEAM`` NSM (mass per length; not for discrete beams, ELFORM 6, as in
  LS-DYNA); ``*ELEMENT_MASS_PART`` LCID and MWD are not read; ``*ELEMENT_MASS_MATRIX`` is not read (skipped and
  counted like any card);
- ``*SET_PART``, ``*SET_PART_LIST`` and ``*SET_PART_LIST_GENERATE`` (usable as
  ``"set:<id>"`` in sub-assembly maps); a ``_GENERATE`` set holds the ids the deck defines in its ranges, as in
  LS-DYNA (the ranges are limits on the ids: ``1 1000000000`` over a deck of a million nodes is those nodes, held
  as the range's two ends);
- ``*CONSTRAINED_RIGID_BODIES`` (which rigid parts move as one body), ``*SET_NODE``/
  ``*SET_NODE_LIST`` (``_TITLE``, ``_GENERATE``) and ``*INITIAL_VELOCITY``,
  ``_NODE``, ``_GENERATION`` (part, part set or node set) and ``_RIGID_BODY``, for which
  parts the deck sets moving (a velocity in a local coordinate system, ICID, is not turned into the deck's
  axes: the direction of travel is then not checked, a note says so);
- parts that are not vehicle: a ``*MAT_RIGID`` part whose constraints (``CMO``, ``CON1``,
  ``CON2``) hold it along the direction of travel, and, where the deck sets nodes moving, a
  part none of whose nodes moves, are a barrier or fixture: they are left out of the model
  (``VehicleModel.left_out`` says why; a warning too).

Every other card (``*CONTROL_*``, ``*DATABASE_*``, ``*CONTACT_*``, ``*HOURGLASS``,
other ``*INITIAL_*``, ``*RIGIDWALL_*``, ``*BOUNDARY_*``, other sets, unknown ones) is
skipped, counted per keyword in ``VehicleModel.skipped_cards`` and summarised in one
:class:`UserWarning`. So are other element and section kinds (``*ELEMENT_DISCRETE``, ``_SEATBELT``,
``_TSHELL``, ...): a part with none of the elements read whose section or material the reader does not
read is left out with a note. Keywords that join nodes (``*NODE_MERGE``, ``*CONSTRAINED_NODE_SET``,
``*CONSTRAINED_SPOTWELD``, ... :data:`_JOINING`) are not followed either: one warning per keyword names its file
and line (the cells are built from the elements' geometry, which they do not change). A blank line is a card
of defaults, also as the last card of a section or
of an element with several lines.

Big blocks (``*NODE``, ``*ELEMENT_*``) are parsed vectorised: the block's lines are
laid out as a ``[n, width]`` byte array, columns are sliced and converted with
numpy; lines in free format, with parameter references or with unusual characters,
and any chunk the fast conversion rejects, go through the per-line parser, which
is the authority on values and produces the error messages.

Errors:
    DeckError: every problem in the deck -- a file or include that cannot be read,
        a line that is not a keyword where one is needed, a non-numeric or blank
        required field, an undefined parameter, duplicate node/element/part/section/
        material/curve ids, elements or parts referring to unknown nodes, parts, sections or
        materials, non-finite coordinates, undetectable units. The message names the
        file and 1-based line and says what was expected and what was found, e.g.
        ``car.k line 812: *NODE expects a numeric x coordinate in columns 9-24, got 'abc'``.
    ConfigError: a bad ``units=`` name, ``axis_map`` or sub-assembly map.
"""

from __future__ import annotations

import ast
import bisect
import math
import operator
import re
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from keyword import iskeyword
from pathlib import Path
from typing import Any

import numpy as np

from marlcrash.errors import DeckError, ModelError, file_label
from marlcrash.units import (
    CARD_WAVE_SPEED_WINDOW,
    DENSITY_WINDOW,
    UNIT_SYSTEM_NAMES,
    UNIT_SYSTEMS,
    UnitSystem,
    density_fits,
    detect_unit_system,
    get_unit_system,
    wave_speed,
)
from marlcrash.vehicle.materials import Material, complete_material
from marlcrash.vehicle.model import AxisMap, Part, VehicleModel

__all__ = ["read_deck"]

_CHUNK = 65536  # rows converted per numpy call when a fast conversion needs a fallback
MAX_VEHICLE_EXTENT = 50.0  # m: the kept structure spans more only by a coordinate typo or wrong units
OUTLIER_SIZE_RATIO = 100.0  # an element this many times its part's median size is noted ...
OUTLIER_MIN_SIZE = 0.5  # m: ... when it is also at least this large
THICK_SHELL = 0.05  # m: a shell thicker than this and than its own size is noted (a thickness typo: 2000. for 2.)
_NO_FAILURE = 1e20  # LS-DYNA's conventional "never fails" strain

# --------------------------------------------------------------------------- layouts


@dataclass(frozen=True)
class _Field:
    """One field of a fixed-format card: its name, standard width, kind and label."""

    name: str
    width: int
    kind: str  # "i" integer, "f" real, "s" text (read as written)
    label: str


def _layout(*specs: tuple[str, int, str, str]) -> tuple[_Field, ...]:
    return tuple(_Field(*s) for s in specs)


def _ids(prefix: str, count: int, width: int, label: str) -> list[tuple[str, int, str, str]]:
    return [(f"{prefix}{i}", width, "i", f"{label} {prefix}{i}") for i in range(1, count + 1)]


_NODE = _layout(
    ("nid", 8, "i", "node id"),
    ("x", 16, "f", "x coordinate"),
    ("y", 16, "f", "y coordinate"),
    ("z", 16, "f", "z coordinate"),
)
_ELEM_HEAD = [("eid", 8, "i", "element id"), ("pid", 8, "i", "part id")]
_SHELL = _layout(*_ELEM_HEAD, *_ids("n", 8, 8, "node id"))
_SHELL_T = _layout(*[(f"t{i}", 16, "f", f"thickness THIC{i}") for i in range(1, 5)])
_SOLID = _layout(*_ELEM_HEAD, *_ids("n", 8, 8, "node id"))
_SOLID_HEAD = _layout(*_ELEM_HEAD)
_SOLID_NODES = _layout(*_ids("n", 10, 8, "node id"))
_BEAM = _layout(*_ELEM_HEAD, *_ids("n", 3, 8, "node id"))
_BEAM_T = _layout(*[(f"p{i}", 16, "f", f"PARM{i}") for i in range(1, 5)])
_BEAM_SEC = _layout(("stype", 10, "s", "section type STYPE"), *[(f"d{i}", 10, "f", f"D{i}") for i in range(1, 7)])


def _card(*names: str, kinds: str | None = None) -> tuple[_Field, ...]:
    """A card of 10-character fields; ``kinds`` gives 'i'/'f' per field (default 'f')."""
    kinds = kinds or "f" * len(names)
    return tuple(_Field(n, 10, k, n.upper()) for n, k in zip(names, kinds, strict=True))


_PART = _card("pid", "secid", "mid", kinds="iii")
_SEC_SHELL_1 = _card("secid", "elform", "shrf", "nip", "propt", "qr", "icomp", kinds="iifffff")
_SEC_SHELL_2 = _card("t1", "t2", "t3", "t4", "nloc", "marea")
_SEC_SOLID = _card("secid", "elform", kinds="if")
_SEC_ID = _card("secid", kinds="i")  # the first field of every *SECTION card
_SEC_BEAM_1 = _card("secid", "elform", "shrf", "qr", "cst", "scoor", "nsm", kinds="iffffff")
_SEC_BEAM_2 = _card("a1", "a2", "a3", "a4")
_MAT_1 = _card("mid", "c1", "c2", "c3", "c4", "c5", "c6", "c7", kinds="ifffffff")
_MAT_8 = _card(*(f"c{i}" for i in range(8)))
_MAT_CARDS: dict[str, tuple[tuple[_Field, ...], ...]] = {
    "elastic": (_card("mid", "ro", "e", "pr", "da", "db", "k", kinds="iffffff"),),
    "plastic_kinematic": (
        _card("mid", "ro", "e", "pr", "sigy", "etan", "beta", kinds="iffffff"),
        _card("src", "srp", "fs", "vp"),
    ),
    "piecewise_linear": (
        _card("mid", "ro", "e", "pr", "sigy", "etan", "fail", "tdel", kinds="ifffffff"),
        _card("c", "p", "lcss", "lcsr", "vp", "lcf"),
        _card(*(f"eps{i}" for i in range(1, 9))),
        _card(*(f"es{i}" for i in range(1, 9))),
    ),
    # the eighth field, ALIAS, is a name (a VDA surface), not read
    "rigid": (_card("mid", "ro", "e", "pr", "n", "couple", "m", kinds="iffffff"), _card("cmo", "con1", "con2")),
}
"""The cards the reader reads of the material kinds it knows, with their fields named as in the LS-DYNA manual
(other kinds: :data:`_MAT_1`, read leniently)."""
_SET_HEAD = _card("sid", kinds="i")
_SET_PIDS = _card(*(f"pid{i}" for i in range(1, 9)), kinds="i" * 8)
_SET_NIDS = _card(*(f"nid{i}" for i in range(1, 9)), kinds="i" * 8)
_SET_RANGES = _card(*(f"b{i}{end}" for i in range(1, 5) for end in ("beg", "end")), kinds="i" * 8)  # _GENERATE
_CURVE_HEAD = _card("lcid", "sidr", "sfa", "sfo", "offa", "offo", kinds="iiffff")
# NID (_RIGID_BODY: PID) VX VY VZ VXR VYR VZR ICID: ICID > 0, the velocities are in that local system
_VEL_NODE = _card("nid", "vx", "vy", "vz", "vxr", "vyr", "vzr", "icid", kinds="iffffffi")
_MERGE = _card("pidm", "pids", kinds="ii")
_VEL_HEAD = _card("nsid", "nsidex", "boxid", "irigid", "icid", kinds="iiiff")
_VEL_6 = _card("vx", "vy", "vz", "vxr", "vyr", "vzr")
_VEL_GEN = _card("id", "styp", "omega", "vx", "vy", "vz", "ivatn", "icid", kinds="iifffffi")
_CURVE_PT = (_Field("a", 20, "f", "abscissa"), _Field("o", 20, "f", "ordinate"))
_TABLE_HEAD = _card("tbid", "sfa", "offa", kinds="iff")
_TABLE_2D_ROW = (_Field("value", 20, "f", "VALUE"), _Field("lcid", 20, "i", "CURVEID"))
_ELEM_MASS = _layout(
    ("eid", 8, "i", "element id"), ("nid", 8, "i", "node id"), ("mass", 16, "f", "mass"), ("pid", 8, "i", "part id")
)
_ELEM_MASS_SET = _layout(
    ("eid", 8, "i", "element id"), ("nid", 8, "i", "node set id"), ("mass", 16, "f", "mass"), ("pid", 8, "i", "part id")
)
_MASS_PART = _layout(("id", 8, "i", "PID"), ("addmass", 16, "f", "ADDMASS"), ("finmass", 16, "f", "FINMASS"))
_INERTIA = _card("xc", "yc", "zc", "tm", "ircs", "nodeid", kinds="ffffii")
_ELEM_INERTIA = _layout(("eid", 8, "i", "element id"), ("nid", 8, "i", "node id"), ("csid", 8, "i", "CSID"))
_ELEM_INERTIA_2 = _card("ixx", "ixy", "ixz", "iyy", "iyz", "izz", "mass")
_NODAL_BODY = _card("pid", "cid", "nsid", "pnode", "iprt", "drflag", "rrflag", kinds="iiiiiii")
_EXTRA_NODES = _card("pid", "nid", "iflag", kinds="iii")
_DUPLICATION = _card("dflag", kinds="i")


def _widths(layout: tuple[_Field, ...], fmt: str) -> list[int]:
    if fmt == "long":
        return [20] * len(layout)
    if fmt == "i10":
        return [max(f.width, 10) for f in layout]
    return [f.width for f in layout]


_INT_OK = np.zeros(256, dtype=bool)
_INT_OK[np.frombuffer(b"0123456789+- ", dtype=np.uint8)] = True
_FLOAT_OK = _INT_OK.copy()
_FLOAT_OK[np.frombuffer(b".eE", dtype=np.uint8)] = True

# --------------------------------------------------------------------------- sources


class _Source:
    """One deck file: its bytes and line table (``[L]`` arrays of line starts and ends)."""

    def __init__(self, path: Path, data: bytes):
        data = data.removeprefix(b"\xef\xbb\xbf")  # a UTF-8 byte-order mark (Windows editors write one): no data
        if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):  # lone CRs: classic Mac line endings
            data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        if not data.endswith(b"\n"):
            data += b"\n"
        self.path = path
        self.data = data
        self.parent: _Source | None = None  # the file that includes this one (this inclusion of it)
        self.buf = np.frombuffer(data, dtype=np.uint8)
        nl = np.flatnonzero(self.buf == 10)
        self.starts = np.concatenate([[0], nl[:-1] + 1]).astype(np.int64)
        ends = nl.astype(np.int64)
        cr = (ends > self.starts) & (self.buf[np.maximum(ends - 1, 0)] == 13)
        self.ends = ends - cr
        nonempty = self.ends > self.starts
        self.first = np.where(nonempty, self.buf[np.minimum(self.starts, len(self.buf) - 1)], 0)
        self.special = np.zeros(len(self.starts), dtype=bool)
        for ch in (b",", b"&", b"\t"):
            pos = np.flatnonzero(self.buf == ch[0])
            if pos.size:
                self.special[np.searchsorted(self.starts, pos, side="right") - 1] = True

    @classmethod
    def load(cls, path: Path, including: tuple[Path, int] | None = None) -> _Source:
        try:
            data = path.read_bytes()
        except OSError as e:
            if including is not None:
                raise DeckError(f"*INCLUDE cannot read {str(path)!r} ({e.strerror})", *including) from None
            raise DeckError(f"cannot read the deck ({e.strerror})", path) from None
        return cls(path, data)

    @property
    def n_lines(self) -> int:
        return len(self.starts)

    def text(self, i: int) -> str:
        """Line ``i`` as text: UTF-8 (titles such as "Stoßfänger" written by current pre-processors), else Latin-1
        (older decks; every byte decodes)."""
        raw = self.data[self.starts[i] : self.ends[i]]
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            return raw.decode("latin-1")

    def padded(self, rows: np.ndarray, width: int) -> np.ndarray:
        """``[n, width]`` uint8 array of the given lines, cut or padded with spaces."""
        n = len(rows)
        out = np.full((n, width), 32, dtype=np.uint8)
        if n == 0:
            return out
        s = self.starts[rows]
        lengths = self.ends[rows] - s
        if (lengths == lengths[0]).all() and (n == 1 or (np.diff(s) == s[1] - s[0]).all()):
            stride = int(s[1] - s[0]) if n > 1 else int(lengths[0]) + 1
            m = min(int(lengths[0]), width)
            if m:
                view = np.lib.stride_tricks.as_strided(
                    self.buf[int(s[0]) :], shape=(n, m), strides=(stride, 1), writeable=False
                )
                out[:, :m] = view
            return out
        cols = np.arange(width)
        for a in range(0, n, _CHUNK):
            ss, ll = s[a : a + _CHUNK], lengths[a : a + _CHUNK]
            mask = cols[None, :] < ll[:, None]
            pos = ss[:, None] + cols[None, :]
            block = out[a : a + _CHUNK]
            block[mask] = self.buf[pos[mask]]
        return out


@dataclass
class _Block:
    """One keyword and its data lines (0-based indices; comments removed)."""

    keyword: str
    fmt: str
    src: _Source
    line: int
    rows: np.ndarray
    tail: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Blank lines after the last data line (not in ``rows``): a stray blank line, or a last card of defaults, which
    readers of multi-line entries take where an entry would otherwise be cut short (:meth:`complete`)."""

    def complete(self, rows: np.ndarray, per: int) -> np.ndarray:
        """``rows`` (ending with the block's last data line) plus the trailing blank lines that complete the last
        entry of ``per`` lines, where the blank lines after it suffice; ``rows`` unchanged otherwise."""
        short = -rows.size % per
        if short and self.tail.size >= short:
            return np.concatenate([rows, self.tail[:short]])
        return rows

    def lineno(self, row: int) -> int:
        return int(row) + 1

    def err(self, reason: str, row: int | None = None) -> DeckError:
        return DeckError(reason, self.src.path, self.lineno(self.line if row is None else row))


@dataclass
class _Locs:
    """Where rows of a concatenated table came from, for messages."""

    offsets: list[int] = field(default_factory=list)
    chunks: list[tuple[_Source, np.ndarray]] = field(default_factory=list)
    total: int = 0

    def add(self, src: _Source, rows: np.ndarray) -> None:
        self.offsets.append(self.total)
        self.chunks.append((src, rows))
        self.total += len(rows)

    def where(self, i: int) -> tuple[Path, int]:
        k = bisect.bisect_right(self.offsets, i) - 1
        src, rows = self.chunks[k]
        return src.path, int(rows[i - self.offsets[k]]) + 1


# --------------------------------------------------------------------------- values


@dataclass
class _Scope:
    """The parameters of one scope: the deck's (``*PARAMETER``), or one included file's (``*PARAMETER_LOCAL``)."""

    values: dict[str, float | int | str] = field(default_factory=dict)
    where: dict[str, tuple[Path, int]] = field(default_factory=dict)  # the definition in effect of each name


class _Params:
    """Deck parameters: name -> value, with where each was defined.

    ``*PARAMETER`` values hold for the whole deck. ``*PARAMETER_LOCAL`` (and ``*PARAMETER_EXPRESSION_LOCAL``) values
    hold in the file that defines them and the files it includes, where they take precedence over the deck's of the
    same name; so component files may each define their own ``&t1``, as LS-DYNA allows. A file included twice has a
    scope per inclusion.
    """

    def __init__(self, user: dict[str, float] | None):
        self.glob = _Scope()
        self.values = self.glob.values
        self.where = self.glob.where
        self.local: dict[int, tuple[_Source, _Scope]] = {}  # id of a file's inclusion -> its local parameters
        self.user = {str(k).strip().lower(): v for k, v in (user or {}).items()}
        # (scope key, name) -> (kind, name, expression, path, line, the file it is written in, local), in deck order
        self.exprs: dict[tuple[int | None, str], tuple[str, str, str, Path, int, _Source | None, bool]] = {}
        self.notes: list[str] = []
        self.deck_names: set[str] = set()  # defined by the deck (*PARAMETER, *PARAMETER_EXPRESSION, _LOCAL)
        self.used: set[str] = set()  # referenced by a field or an expression
        self.duplication = 1  # *PARAMETER_DUPLICATION DFLAG; LS-DYNA's default: warn and keep the first

    def _scope(self, src: _Source | None) -> tuple[int | None, _Scope]:
        """The scope key and table of the deck (``src`` ``None``) or of the file ``src``'s local parameters."""
        if src is None:
            return None, self.glob
        if id(src) not in self.local:
            self.local[id(src)] = (src, _Scope())
        return id(src), self.local[id(src)][1]

    def _claim(self, name: str, path: Path, line: int, differs: bool, scope: _Scope) -> bool:
        """Whether a definition of ``name`` at ``path`` line ``line`` takes effect in ``scope``
        (``*PARAMETER_DUPLICATION``).

        A first definition always does. A later one is ignored (DFLAG 1 and 3, 1 being LS-DYNA's default) or
        replaces the one before (2 and 4); 1 and 2 add a note where the value may differ (``differs``), 5 refuses.
        """
        if name not in scope.where:
            scope.where[name] = (path, line)
            return True
        first, at = scope.where[name]
        d = self.duplication
        if d == 5:
            raise DeckError(
                f"parameter {name!r} is defined twice (first in {first.name} line {at}), which "
                "*PARAMETER_DUPLICATION DFLAG 5 makes an error",
                path,
                line,
            )
        if d in (1, 2) and differs:
            what = "the first definition is kept" if d == 1 else "the new definition replaces it"
            self.notes.append(
                f"{path.name} line {line}: parameter {name!r} is defined again with another value (first in "
                f"{first.name} line {at}); {what}, as LS-DYNA's *PARAMETER_DUPLICATION DFLAG {d} does"
            )
        if d in (2, 4):
            scope.where[name] = (path, line)
            return True
        return False

    def define(self, name: str, value: float | int | str, path: Path, line: int, src: _Source | None = None) -> None:
        """A ``*PARAMETER`` value (``*PARAMETER_LOCAL`` of the file ``src``), subject to the duplicate rule of its
        scope (:meth:`_claim`)."""
        key = name.lower()
        skey, scope = self._scope(src)
        differs = (skey, key) in self.exprs or (key in scope.values and scope.values[key] != value)
        if self._claim(key, path, line, differs, scope):
            self.exprs.pop((skey, key), None)
            scope.values[key] = value

    def define_expr(
        self, kind: str, name: str, expr: str, path: Path, line: int, at: _Source | None = None, local: bool = False
    ) -> None:
        """A ``*PARAMETER_EXPRESSION`` written in the file ``at`` (``local``: ``_LOCAL``, a value of that file's),
        evaluated by :meth:`finish` with the values seen there, subject to the duplicate rule of its scope."""
        key = name.lower()
        skey, scope = self._scope(at if local else None)
        if self._claim(key, path, line, True, scope):
            self.exprs.pop((skey, key), None)  # re-inserted: evaluated in the order of the definitions in effect
            scope.values.pop(key, None)
            self.exprs[(skey, key)] = (kind, key, expr, path, line, at, local)

    def finish(self) -> None:
        """Apply ``params=`` overrides, then evaluate expressions in deck order."""
        local_names = {k for _, scope in self.local.values() for k in scope.values}
        self.deck_names = set(self.values) | local_names | {name for _, name, *_ in self.exprs.values()}
        for k, v in self.user.items():
            if k in self.values and self.values[k] != v:
                self.notes.append(f"parameter {k!r}: deck value {self.values[k]!r} overridden by params= {v!r}")
            self.values[k] = v
            for src, scope in self.local.values():
                if k in scope.values and scope.values[k] != v:
                    self.notes.append(f"parameter {k!r}: local value {scope.values[k]!r} of {src.path.name} "
                                      f"overridden by params= {v!r}")  # fmt: skip
        for kind, name, expr, path, line, at, local in self.exprs.values():
            if name in self.user:
                self.notes.append(f"parameter {name!r}: deck expression overridden by params= {self.user[name]!r}")
                continue
            val = _eval_expr(expr, self, path, line, at)
            if kind == "I" and not (math.isfinite(val) and abs(val) < 2**62):
                raise DeckError(f"*PARAMETER_EXPRESSION expects an integer value for {name!r}, got {val}", path, line)
            self._scope(at if local else None)[1].values[name] = round(val) if kind == "I" else val

    def get(self, name: str, path: Path, line: int, src: _Source | None = None) -> float | int | str:
        """The value of ``&name`` used at ``path`` line ``line`` of the file ``src``: a ``params=`` value, else the
        nearest local one (that file's, then its includers'), else the deck's."""
        key = name.strip().lower()
        self.used.add(key)
        if key in self.user:
            return self.user[key]
        f = src
        seen: list[int | None] = [None]  # None: the global expressions; then file ids from ``src`` up its includers
        while f is not None:
            local = self.local.get(id(f))
            if local is not None and key in local[1].values:
                return local[1].values[key]
            seen.append(id(f))
            f = f.parent
        if key in self.values:
            return self.values[key]
        for skey in seen:  # an expression not yet evaluated: it comes later in the deck
            if (skey, key) in self.exprs:
                p, at = self.exprs[(skey, key)][3:5]
                if (p, at) == (path, line):
                    raise DeckError(f"*PARAMETER_EXPRESSION {key!r} uses itself", path, line)
                raise DeckError(
                    f"parameter {key!r} is used before it is defined: its *PARAMETER_EXPRESSION ({p.name} line {at}) "
                    "comes later; expressions are evaluated in deck order",
                    path,
                    line,
                )
        raise DeckError(
            f"parameter {key!r} is used but not defined in the deck; define it with *PARAMETER, or give its value in "
            f"the deck's units: --param {key}=VALUE on the command line, params={{{key!r}: value}} in Python",
            path,
            line,
        )


_FUNCS: dict[str, Callable[..., float]] = {
    "sin": math.sin,
    "cos": math.cos,
    "tan": math.tan,
    "asin": math.asin,
    "acos": math.acos,
    "atan": math.atan,
    "atan2": math.atan2,
    "sinh": math.sinh,
    "cosh": math.cosh,
    "tanh": math.tanh,
    "sqrt": math.sqrt,
    "exp": math.exp,
    "log": math.log,
    "log10": math.log10,
    "abs": abs,
    "min": min,
    "max": max,
    "int": int,
    "aint": math.trunc,
    "nint": lambda x: math.copysign(math.floor(abs(x) + 0.5), x),  # Fortran's NINT: halves away from zero
    "mod": math.fmod,  # Fortran's MOD: a - int(a / b) * b, the sign of a (Python's % takes the sign of b)
    "sign": lambda a, b: abs(a) if b >= 0 else -abs(a),  # Fortran's SIGN: |a| with the sign of b
}
"""The functions a ``*PARAMETER_EXPRESSION`` may call (Fortran's intrinsics, as LS-DYNA evaluates them), by
lower-case name."""
_BINOPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.Mod: operator.mod,
}


_NAME = re.compile(r"[A-Za-z_]\w*")
_KEYWORD_NAME = "_kw_"
"""Prefix given to a parameter name that is a Python keyword (``in``, ``lambda``, ``True``) before an expression is
parsed as Python, and taken off again when it is looked up."""


def _eval_expr(text: str, params: _Params, path: Path, line: int, at: _Source | None = None) -> float:
    """Evaluate a ``*PARAMETER_EXPRESSION`` right-hand side (arithmetic only) written in the file ``at``."""
    src = text.strip().replace("^", "**").replace("&", "")
    src = _NAME.sub(lambda m: _KEYWORD_NAME + m[0] if iskeyword(m[0]) else m[0], src)

    def ev(node: ast.AST) -> float:
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
            return float(node.value)
        if isinstance(node, ast.Name):
            name = node.id
            if name.startswith(_KEYWORD_NAME) and iskeyword(name[len(_KEYWORD_NAME) :]):
                name = name[len(_KEYWORD_NAME) :]
            if name.lower() == "pi":
                return math.pi
            v = params.get(name, path, line, at)
            if isinstance(v, str):
                raise DeckError(f"*PARAMETER_EXPRESSION uses character parameter {name!r} as a number", path, line)
            return float(v)
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            return _BINOPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
            v = ev(node.operand)
            return -v if isinstance(node.op, ast.USub) else v
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id.lower() in _FUNCS:
            return float(_FUNCS[node.func.id.lower()](*[ev(a) for a in node.args]))
        raise ValueError("unsupported expression")

    try:
        return float(ev(ast.parse(src, mode="eval")))
    except DeckError:
        raise
    except (SyntaxError, ValueError, TypeError, ZeroDivisionError, OverflowError, RecursionError, MemoryError):
        raise DeckError(
            f"*PARAMETER_EXPRESSION expects an arithmetic expression, got {text.strip()!r}", path, line
        ) from None


_FORTRAN_REAL = re.compile(r"([+-]?(?:\d+\.?\d*|\.\d+))(?:[dDeE]([+-]?\d+)|([+-]\d+))")
"""A real as Fortran's formatted input reads it beyond what ``float`` takes: a ``D`` exponent (``1.0D+03``), or a
signed exponent without its letter (``7.85-9``, ``2.1+5``: E is optional before a sign)."""


class _NonFinite(ValueError):
    """A real field that reads as NaN or infinity (``nan``, ``inf``, ``1e999``): no value a deck can mean (the reader
    marks fields not given with NaN)."""


def _to_number(tok: str, kind: str) -> float | int:
    """Convert a stripped token; raises ValueError when it is not a number of that kind (:class:`_NonFinite` where
    it reads as NaN or infinity)."""
    if kind == "i":
        try:
            return int(tok)
        except ValueError:
            v = float(tok)  # integral reals such as "2." are accepted in integer fields
            if not v.is_integer():
                raise
            return int(v)
    try:
        v = float(tok)
    except ValueError:
        m = _FORTRAN_REAL.fullmatch(tok)
        if m is None:
            raise
        v = float(f"{m.group(1)}e{m.group(2) or m.group(3)}")
    if not math.isfinite(v):
        raise _NonFinite(tok)
    return v


def _columns(widths: list[int]) -> list[tuple[int, int]]:
    cols, c = [], 0
    for w in widths:
        cols.append((c, c + w))
        c += w
    return cols


def _read_line(
    block: _Block, row: int, layout: tuple[_Field, ...], params: _Params, lenient: bool = False
) -> list[Any]:
    """Slow path: parse one line against ``layout``; blanks are ``None``, numbers ``int`` (kind ``i``) or ``float``,
    text ``str`` (kind ``s``).

    With ``lenient``, non-numeric fields become ``None`` instead of raising.
    """
    text = block.src.text(row)
    widths = _widths(layout, block.fmt)
    if "," in text:
        toks = [t.strip() for t in text.split(",")]
        toks += [""] * (len(layout) - len(toks))
        where = [f"in free-format field {i + 1}" for i in range(len(layout))]
    else:
        cols = _columns(widths)
        toks = [text[a:b].strip() for a, b in cols]
        where = [f"in columns {a + 1}-{b}" for a, b in cols]
    out: list = []
    lineno = block.lineno(row)
    for f, tok, wh in zip(layout, toks, where, strict=False):
        if not tok:
            out.append(None)
            continue
        if f.kind == "s":
            out.append(tok)
            continue
        neg = tok.startswith("-&")
        if neg or tok.startswith("&"):
            v = params.get(tok[2:] if neg else tok[1:], block.src.path, lineno, block.src)
            if isinstance(v, str):
                try:
                    v = _to_number(v.strip(), f.kind)
                except ValueError:
                    if lenient:
                        out.append(None)
                        continue
                    raise block.err(
                        f"*{block.keyword} expects a numeric {f.label} {wh}, but parameter {tok!r} is {v!r}", row
                    ) from None
            if f.kind == "i":
                if not float(v).is_integer() or abs(v) >= 2**62:
                    raise block.err(
                        f"*{block.keyword} expects an integer {f.label} {wh}, parameter {tok!r} is {v}", row
                    )
                v = int(v)
            out.append(-v if neg else v)
            continue
        try:
            val = _to_number(tok, f.kind)
            if f.kind == "i" and abs(val) >= 2**62:
                raise OverflowError
            out.append(val)
        except (ValueError, OverflowError) as e:
            if lenient:
                out.append(None)
                continue
            what = "an integer" if f.kind == "i" else "a finite" if isinstance(e, _NonFinite) else "a numeric"
            raise block.err(f"*{block.keyword} expects {what} {f.label} {wh}, got {tok!r}", row) from None
    return out


def _field_where(block: _Block, row: int, layout: tuple[_Field, ...], k: int) -> str:
    text = block.src.text(row)
    if "," in text:
        toks = text.split(",")
        tok = toks[k].strip() if k < len(toks) else ""
        return f"in free-format field {k + 1}, got {tok!r}" if tok else f"in free-format field {k + 1}, got blank"
    a, b = _columns(_widths(layout, block.fmt))[k]
    tok = text[a:b].strip()
    return f"in columns {a + 1}-{b}, got {tok!r}" if tok else f"in columns {a + 1}-{b}, got blank"


def _convert(sub: np.ndarray, dtype: type) -> tuple[np.ndarray, np.ndarray]:
    """Convert ``[n, w]`` space-padded digits to numbers; returns values and a ``[n]`` failure mask."""
    n, w = sub.shape
    vals: np.ndarray = np.zeros(n, dtype=dtype)
    bad = np.zeros(n, dtype=bool)
    strs = np.ascontiguousarray(sub).view(f"S{w}").ravel()
    for a in range(0, n, _CHUNK):
        part = strs[a : a + _CHUNK]
        try:
            vals[a : a + _CHUNK] = part.astype(dtype)
        except (ValueError, OverflowError, TypeError, UnicodeError):
            for j, s in enumerate(part.tolist()):
                try:
                    vals[a + j] = dtype(s) if dtype is np.float64 else int(s)
                except (ValueError, OverflowError, TypeError, UnicodeError):
                    bad[a + j] = True
    return vals, bad


def _table(
    block: _Block,
    rows: np.ndarray,
    layout: tuple[_Field, ...],
    params: _Params,
    required: tuple[str, ...] = (),
    positive: tuple[str, ...] = (),
) -> dict[str, np.ndarray]:
    """Parse lines ``rows`` of ``block`` against ``layout``, vectorised.

    Returns one ``[n]`` array per field (int64 or float64, blanks as 0). Fields in
    ``required`` must not be blank; fields in ``positive`` must be > 0.
    """
    n = len(rows)
    widths = _widths(layout, block.fmt)
    cols = _columns(widths)
    src = block.src
    arr = src.padded(rows, cols[-1][1])
    slow = src.special[rows].copy()
    subs = []
    for f, (a, b) in zip(layout, cols, strict=True):
        sub = arr[:, a:b]
        table = _INT_OK if f.kind == "i" else _FLOAT_OK
        slow |= ~table[sub].all(axis=1)
        blank = (sub == 32).all(axis=1)
        if f.name in required:
            slow |= blank
        subs.append((sub, blank))
    out: dict[str, np.ndarray] = {}
    fast = np.flatnonzero(~slow)
    for f, (sub, blank) in zip(layout, subs, strict=True):
        dtype = np.int64 if f.kind == "i" else np.float64
        col = np.zeros(n, dtype=dtype)
        if fast.size:
            s = sub[fast]
            b = blank[fast]
            s[b, -1] = ord("0")
            vals, bad = _convert(s, dtype)
            if dtype is np.float64:
                bad |= ~np.isfinite(vals)  # "1e999": the per-line parser refuses it, naming the columns
            col[fast] = vals
            slow[fast[bad]] = True
        out[f.name] = col
    for i in np.flatnonzero(slow).tolist():
        line_vals = _read_line(block, int(rows[i]), layout, params)
        for k, (f, v) in enumerate(zip(layout, line_vals, strict=True)):
            if v is None and f.name in required:
                raise block.err(
                    f"*{block.keyword} expects {f.label} {_field_where(block, int(rows[i]), layout, k)}", int(rows[i])
                )
            out[f.name][i] = 0 if v is None else v
    for name in positive:
        bad = np.flatnonzero(out[name] <= 0)
        if bad.size:
            i = int(bad[0])
            k = [f.name for f in layout].index(name)
            raise block.err(
                f"*{block.keyword} expects a positive {layout[k].label} {_field_where(block, int(rows[i]), layout, k)}",
                int(rows[i]),
            )
    return out


def _nonblank(block: _Block, rows: np.ndarray) -> np.ndarray:
    """The rows that are not entirely blank (blank lines are skipped in one-line tables)."""
    if rows.size == 0:
        return rows
    src = block.src
    lengths = src.ends[rows] - src.starts[rows]
    keep = lengths > 0
    cand = np.flatnonzero(keep)
    if cand.size:
        w = int(lengths.max())
        if w <= 256:
            arr = src.padded(rows[cand], w)
            keep[cand] = ~((arr == 32) | (arr == 9)).all(axis=1)  # spaces and tabs
        else:
            keep[cand] = [bool(src.text(int(r)).strip()) for r in rows[cand]]
    return rows[keep]


# --------------------------------------------------------------------------- scanning


@dataclass
class _Deck:
    """Everything read from the deck, in deck units, before assembly."""

    params: _Params
    title: str | None = None
    blocks: list[_Block] = field(default_factory=list)
    skipped: Counter = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    include_paths: list[Path] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    """Every file read, the main deck first, then the ``*INCLUDE`` files in the order they were met."""
    early_end: list[tuple[Path, int]] = field(default_factory=list)
    """``*END`` lines with more than comments after them (LS-DYNA, like the reader, stops reading the file there)."""
    unread_includes: list[str] = field(default_factory=list)
    """One note per ``*INCLUDE_<option>`` card the reader does not follow (``_TRANSFORM``, ``_AUTO_OFFSET``, ...)."""


def _keyword_line(text: str) -> tuple[str, str | None, list[str]]:
    """``*NAME[+|%|-] rest`` -> (NAME, format suffix, rest tokens)."""
    toks = text[1:].split()
    if not toks:
        return "", None, []
    name = toks[0].upper()
    suffix = None
    if name[-1:] in ("+", "%", "-"):
        suffix, name = name[-1], name[:-1]
    rest = toks[1:]
    if rest and rest[0] in ("+", "%", "-"):
        suffix, rest = rest[0], rest[1:]
    return name, suffix, rest


def _scan(
    path: Path, deck: _Deck, fmt: str, stack: tuple[Path, ...], including: tuple[Path, int] | None,
    parent: _Source | None = None,
) -> None:  # fmt: skip
    """Split one file into keyword blocks, following includes; read parameters now. ``parent``: the including
    file (its ``*PARAMETER_LOCAL`` values hold here too)."""
    src = _Source.load(path, including)
    src.parent = parent
    deck.files.append(path.resolve())
    kw = np.flatnonzero(src.first == ord("*"))
    head_end = int(kw[0]) if kw.size else src.n_lines
    for i in np.flatnonzero(src.first[:head_end] != ord("$")).tolist():
        if src.text(i).strip():
            raise DeckError(f"expected a keyword line starting with '*', got data {src.text(i)[:40]!r}", path, i + 1)
    bounds = [*kw.tolist(), src.n_lines]
    for j in range(len(kw)):
        k, end = bounds[j], bounds[j + 1]
        name, suffix, rest = _keyword_line(src.text(k))
        if not name:
            raise DeckError("expected a keyword name after '*', got nothing", path, k + 1)
        rows = np.arange(k + 1, end, dtype=np.int64)
        rows = rows[src.first[rows] != ord("$")]
        n_data = rows.size
        while n_data and not src.text(int(rows[n_data - 1])).strip():
            n_data -= 1
        bfmt = {"+": "long", "%": "i10", "-": "std"}.get(suffix or "", fmt)
        block = _Block(name, bfmt, src, k, rows[:n_data], rows[n_data:])
        if name == "END":
            if any(src.text(i).strip() and src.first[i] != ord("$") for i in range(k + 1, src.n_lines)):
                deck.early_end.append((path, k + 1))
            return
        if name == "KEYWORD":
            opts = {t.upper().partition("=")[0]: t.upper().partition("=")[2] for t in rest if "=" in t}
            if opts.get("LONG") in ("Y", "YES"):
                fmt = "long"
            elif opts.get("I10") in ("Y", "YES"):
                fmt = "i10"
            elif opts.get("LONG") == "S":
                fmt = "std"
        elif name == "TITLE":
            if rows.size and deck.title is None:
                deck.title = src.text(int(rows[0])).strip()
        elif name in ("INCLUDE_PATH", "INCLUDE_PATH_RELATIVE"):
            for r in rows.tolist():
                folder = src.text(r).strip()
                p = Path(folder)
                if not (p if p.is_absolute() else path.parent / p).is_dir():  # a folder written on Windows
                    p = Path(folder.replace("\\", "/"))
                deck.include_paths.append(p if p.is_absolute() else path.parent / p)
        elif name == "INCLUDE":
            for r, fname in _include_names(src, rows, k):
                target = _resolve_include(fname, path, deck, r)
                if target in stack:
                    chain = " -> ".join(p.name for p in (*stack, target))  # from the main deck
                    raise DeckError(f"*INCLUDE {fname!r} makes a cycle: {chain}", path, r + 1)
                _scan(target, deck, bfmt, (*stack, target), (path, r + 1), src)  # "*INCLUDE +": a long file
        elif name.startswith("INCLUDE_"):  # _TRANSFORM, _AUTO_OFFSET, _STAMPED_PART, _NASTRAN, ...
            names = _include_names(src, rows, k, first=True)
            for r, fname in names[:1]:  # the file name is the first card; the rest are options
                deck.unread_includes.append(
                    f"*{name} {fname!r} ({path.name} line {r + 1}) is not read: the nodes, elements and masses of "
                    "that file are missing from the vehicle (merge it into the deck, or include it with *INCLUDE)"
                )
            deck.skipped[name] += 1
        elif name in ("PARAMETER", "PARAMETER_LOCAL"):
            _read_parameters(block, deck.params, local=name.endswith("_LOCAL"))
        elif name in ("PARAMETER_EXPRESSION", "PARAMETER_EXPRESSION_LOCAL"):
            _read_parameter_expressions(block, deck.params, local=name.endswith("_LOCAL"))
        elif name == "PARAMETER_DUPLICATION":
            _read_duplication(block, deck.params)
        else:
            deck.blocks.append(block)


def _include_names(src: _Source, rows: np.ndarray, k: int, first: bool = False) -> list[tuple[int, str]]:
    """The file names of the ``*INCLUDE`` keyword at line ``k`` (0-based): ``(line, name)`` per name, a name
    continued on the next line where it ends in `` +``. A block without a name (``first``: whose first card is no
    name, as an ``*INCLUDE_<option>``'s must be) is refused at its first blank card, or at the keyword where it has
    no card."""
    out: list[tuple[int, str]] = []
    pending: tuple[int, str] | None = None
    for r in rows.tolist():
        t = src.text(r).strip()
        if pending is not None:
            t = pending[1] + t
        start = pending[0] if pending is not None else r
        if t.endswith(" +"):
            pending = (start, t[:-2].rstrip())
            continue
        pending = None
        if t:
            out.append((start, t))
    if pending is not None:
        out.append(pending)
    if not out or (first and out[0][0] != rows[0]):
        at, got = (int(rows[0]), "a blank card") if rows.size else (k, "no card")
        raise DeckError(f"*{_keyword_line(src.text(k))[0]} expects a file name, got {got}", src.path, at + 1)
    return out


def _resolve_include(fname: str, including: Path, deck: _Deck, row: int) -> Path:
    # the including file's folder, then the main deck's (LS-DYNA resolves a relative name against the main file's
    # folder, so nested includes are often written relative to it), then the *INCLUDE_PATH folders; a name as
    # written first, then with its backslashes read as folder separators (a deck written on Windows)
    folders = [including.parent, deck.files[0].parent, *deck.include_paths]
    candidates: list[Path] = []
    for p in dict.fromkeys([Path(fname), Path(fname.replace("\\", "/"))]):
        candidates += [p] if p.is_absolute() else [d.resolve() / p for d in folders]
    candidates = list(dict.fromkeys(candidates))
    for c in candidates:
        if c.is_file():
            return c.resolve()
    dirs = [c for c in candidates if c.is_dir()]
    if dirs:
        raise DeckError(f"*INCLUDE {fname!r} is a folder ({dirs[0]}); expected a keyword file", including, row + 1)
    looked = ", ".join(dict.fromkeys(str(c.parent) for c in candidates))
    raise DeckError(f"*INCLUDE file {fname!r} not found (looked in {looked})", including, row + 1)


def _param_pairs(block: _Block, row: int) -> list[tuple[str, str]]:
    text = block.src.text(row)
    if "," in text:
        toks = [t.strip() for t in text.split(",")]
        return [(toks[i], toks[i + 1] if i + 1 < len(toks) else "") for i in range(0, len(toks), 2) if toks[i]]
    w = 20 if block.fmt == "long" else 10
    pairs = []
    for a in range(0, len(text), 2 * w):
        name, val = text[a : a + w].strip(), text[a + w : a + 2 * w].strip()
        if name:
            pairs.append((name, val))
    ok = all(p[0][:1].upper() in "RIC" and p[0][1:].strip() and " " not in p[0][1:].strip() for p in pairs)
    if ok and all(p[1] for p in pairs):
        return pairs
    toks = text.split()  # whitespace-separated fallback: "R name value" or "Rname value"
    out, i = [], 0
    while i < len(toks):
        t = toks[i]
        if len(t) == 1 and t.upper() in "RIC" and i + 2 < len(toks) + 1:
            out.append((f"{t} {toks[i + 1]}" if i + 1 < len(toks) else t, toks[i + 2] if i + 2 < len(toks) else ""))
            i += 3
        else:
            out.append((t, toks[i + 1] if i + 1 < len(toks) else ""))
            i += 2
    return out


def _read_parameters(block: _Block, params: _Params, local: bool = False) -> None:
    """``*PARAMETER`` (``local``: ``*PARAMETER_LOCAL``, the values of the block's file and the files it includes)."""
    src = block.src if local else None
    for r in block.rows.tolist():
        if not block.src.text(r).strip():
            continue
        for head, val in _param_pairs(block, r):
            kind, name = head[:1].upper(), head[1:].strip()
            if kind not in ("R", "I", "C") or not name:
                raise block.err(f"*PARAMETER expects a type R, I or C followed by a name, got {head!r}", r)
            if kind == "C":
                params.define(name, val, block.src.path, r + 1, src)
                continue
            try:
                v = _to_number(val, "i" if kind == "I" else "f")
            except (ValueError, OverflowError):
                raise block.err(f"*PARAMETER expects a {kind} value for {name!r}, got {val!r}", r) from None
            params.define(name, v, block.src.path, r + 1, src)


def _read_duplication(block: _Block, params: _Params) -> None:
    """``*PARAMETER_DUPLICATION``: DFLAG, how later definitions of a parameter name are treated from here on."""
    rows = _nonblank(block, block.rows)
    (dflag,) = _read_line(block, int(rows[0]), _DUPLICATION, params) if rows.size else (None,)
    if dflag is not None and dflag not in (0, 1, 2, 3, 4, 5):  # 0 (or blank): the default, 1
        at = _field_where(block, int(rows[0]), _DUPLICATION, 0)
        raise block.err(f"*PARAMETER_DUPLICATION expects DFLAG 0 to 5 (0: the default, 1) {at}", int(rows[0]))
    params.duplication = int(dflag) if dflag else 1


_EXPR_HEAD = re.compile(r"\s*[RrIi]\s*[A-Za-z_]\w*\s*")
"""What stands before the first comma of a free-format ``*PARAMETER_EXPRESSION`` line: a type and a name."""


def _read_parameter_expressions(block: _Block, params: _Params, local: bool = False) -> None:
    """``*PARAMETER_EXPRESSION`` (``local``: ``_LOCAL``, as :func:`_read_parameters`)."""
    w = 20 if block.fmt == "long" else 10
    for r in block.rows.tolist():
        text = block.src.text(r)
        if not text.strip():
            continue
        # free format: a comma right after the name, not in max(a, b); a line without any is fixed format (one
        # that ended after its name, 'R thk', matched the head whole and was split at the comma it lacked)
        free = "," in text and _EXPR_HEAD.fullmatch(text.split(",", 1)[0]) is not None
        head, expr = text.split(",", 1) if free else (text[:w], text[w:])
        head = head.strip()
        kind, name = head[:1].upper(), head[1:].strip()
        if kind not in ("R", "I") or not name:
            raise block.err(f"*PARAMETER_EXPRESSION expects a type R or I followed by a name, got {head!r}", r)
        params.define_expr(kind, name, expr, block.src.path, r + 1, block.src, local)


# --------------------------------------------------------------------------- cards


@dataclass
class _Elements:
    """Elements of one kind, in deck units; node columns hold node ids."""

    width: int
    ids: list[np.ndarray] = field(default_factory=list)
    part: list[np.ndarray] = field(default_factory=list)
    nodes: list[np.ndarray] = field(default_factory=list)
    extra: list[np.ndarray] = field(default_factory=list)  # shells: [n, 4] thickness, beams: [n] area or nan
    locs: _Locs = field(default_factory=_Locs)

    def add(self, src, rows, ids, part, nodes, extra) -> None:
        self.ids.append(ids)
        self.part.append(part)
        self.nodes.append(nodes)
        self.extra.append(extra)
        self.locs.add(src, rows)

    def cat(self, extra_shape: tuple[int, ...]):
        if not self.ids:
            z = np.zeros(0, dtype=np.int64)
            return z, z, np.zeros((0, self.width), np.int64), np.zeros((0, *extra_shape))
        return (
            np.concatenate(self.ids),
            np.concatenate(self.part),
            np.concatenate(self.nodes),
            np.concatenate(self.extra),
        )


@dataclass
class _Section:
    kind: str  # shell, solid, beam
    value: float | None  # shell thickness or beam area (deck units); None where unknown
    elform: int
    cst: int
    where: tuple[Path, int]
    marea: float = 0.0  # non-structural mass (deck units): per area for shells (MAREA), per length for beams (NSM)


@dataclass
class _RawMaterial:
    mid: int
    name: str
    kind: str
    values: dict[str, float]
    where: tuple[Path, int]
    keyword: str = ""
    note: str | None = None  # what the reader could not take from the card (e.g. a layout it does not know)
    densityless: bool = False  # a spring, damper or seatbelt material: its card has no density at all
    ro_at: str = ""  # where RO is on the first card and what is there ("in columns 11-20, got blank"), for messages


@dataclass
class _Velocity:
    """One initial-velocity assignment: what it moves and whether its velocity is non-zero.

    ``target``: ``"nodes"`` (``ids`` node ids), ``"node_set"``, ``"part"``, ``"part_set"`` (``ids``: the one
    set or part id) or ``"all"``; ``except_set`` a node set exempted (``*INITIAL_VELOCITY`` NSIDEX).
    """

    target: str
    ids: np.ndarray
    moving: np.ndarray  # [len(ids)] bool (one entry for sets, parts and "all")
    where: tuple[Path, int]
    except_set: int = 0
    except_moving: bool = False
    vel: np.ndarray | None = None  # [k, 3] translational velocities given (deck axes); None: in a local system
    local: tuple[int, int] | None = None  # (ICID, line) of a velocity given in a local system, which is not read


@dataclass
class _CurveTable:
    """A ``*DEFINE_TABLE`` or ``*DEFINE_TABLE_2D``: one curve per value (a strain rate where a ``*MAT_024`` LCSS
    names it), the values scaled and offset as the card says, and where the card is."""

    values: np.ndarray
    curve_ids: list[int]
    where: tuple[Path, int]


@dataclass
class _Tables:
    node_ids: list[np.ndarray] = field(default_factory=list)
    coords: list[np.ndarray] = field(default_factory=list)
    node_locs: _Locs = field(default_factory=_Locs)
    shells: _Elements = field(default_factory=lambda: _Elements(4))
    solids: _Elements = field(default_factory=lambda: _Elements(8))
    beams: _Elements = field(default_factory=lambda: _Elements(2))
    parts: dict[int, tuple[str, int, int, tuple[Path, int]]] = field(default_factory=dict)
    dropped: dict[int, str] = field(default_factory=dict)  # parts left out by _drop_unread_parts -> why
    sections: dict[int, _Section] = field(default_factory=dict)
    materials: dict[int, _RawMaterial] = field(default_factory=dict)
    set_cards: dict[int, _IdSet] = field(default_factory=dict)  # *SET_PART cards, as read
    node_set_cards: dict[int, _IdSet] = field(default_factory=dict)  # *SET_NODE cards, as read
    sets: dict[int, tuple[str, list[int]]] = field(default_factory=dict)  # part sets, resolved (_resolve_sets)
    node_sets: dict[int, tuple[str, np.ndarray]] = field(default_factory=dict)  # node sets, resolved
    curves: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    curve_at: dict[int, tuple[Path, int]] = field(default_factory=dict)  # LCID -> where its *DEFINE_CURVE is
    tables: dict[int, _CurveTable] = field(default_factory=dict)  # TBID -> *DEFINE_TABLE (_2D)
    table_open: int | None = None  # the *DEFINE_TABLE whose curves are being read (they follow it, in its order)
    velocities: list[_Velocity] = field(default_factory=list)
    rigid_merges: list[tuple[int, int, tuple[Path, int]]] = field(default_factory=list)  # (PIDM, PIDS, where)
    point_masses: list[_PointMasses] = field(default_factory=list)
    part_masses: list[_PartMass] = field(default_factory=list)
    inertia: dict[int, tuple[float, tuple[Path, int]]] = field(default_factory=dict)  # pid -> (TM, where)
    nodal_bodies: list[_NodalBody] = field(default_factory=list)
    extra_nodes: dict[int, list[tuple[int, bool, tuple[Path, int]]]] = field(default_factory=dict)  # pid -> (id, set)
    unread_stypes: Counter = field(default_factory=Counter)  # *ELEMENT_BEAM_SECTION types without an area -> count
    unread_sections: dict[int, tuple[str, Path, int]] = field(default_factory=dict)  # SECID -> (keyword, file, line)
    unread_parts: dict[int, tuple[str, Path, int]] = field(default_factory=dict)  # PID -> (keyword, file, line)

    def section_of(self, part: Part) -> _Section:
        """The section card of a part that :func:`_assemble` made (it refuses a part whose section is not read)."""
        assert part.section_id is not None, f"part {part.id} has no section id"  # set for every part of the deck
        return self.sections[part.section_id]


@dataclass
class _IdSet:
    """A ``*SET_PART``/``*SET_NODE`` card as read: the ids it lists, or the ``[k, 2]`` first and last ids of its
    ``_GENERATE`` ranges. A range holds the ids the deck defines in it (LS-DYNA resolves the ranges after all input
    is read, so gaps in the numbering do not matter); it is kept as its two ends, so a range of a billion ids over
    a small deck costs what the deck does (:meth:`members`)."""

    title: str
    ids: np.ndarray
    ranges: np.ndarray
    where: tuple[Path, int] | None = None  # the SID card

    def members(self, defined: np.ndarray) -> np.ndarray:
        """The set's ids: those listed, as listed, then each range's ids among ``defined`` (sorted, unique), each
        once, in the order of the ranges."""
        if not self.ranges.size:
            return self.ids
        lo = np.searchsorted(defined, self.ranges[:, 0], side="left")
        hi = np.searchsorted(defined, self.ranges[:, 1], side="right")
        taken = np.zeros(defined.size, dtype=bool)
        parts = [self.ids]
        for a, b in zip(lo.tolist(), hi.tolist(), strict=True):
            new = a + np.flatnonzero(~taken[a:b])
            taken[a:b] = True
            parts.append(defined[new])
        return np.concatenate(parts)


def _resolve_sets(t: _Tables, node_ids: np.ndarray) -> None:
    """Fill ``t.sets`` (part ids as a list) and ``t.node_sets`` (node ids as an array) from the set cards read:
    the ranges of ``_GENERATE`` sets hold the deck's nodes (``node_ids``) and the parts its ``*PART`` cards define
    (those left out too). ``node_ids`` are unique (:func:`_check_duplicates`): they are sorted, not passed through
    ``np.unique`` (numpy 2's hash-based one takes seconds per million ids), and only where a node set has ranges."""
    parts = np.array(sorted({*t.parts, *t.dropped}), dtype=np.int64)
    t.sets = {sid: (s.title, s.members(parts).tolist()) for sid, s in t.set_cards.items()}
    ranged = any(s.ranges.size for s in t.node_set_cards.values())
    nodes = np.sort(node_ids) if ranged else node_ids  # members() reads them for ranges only
    t.node_sets = {sid: (s.title, s.members(nodes)) for sid, s in t.node_set_cards.items()}


@dataclass
class _PointMasses:
    """One ``*ELEMENT_MASS`` (or ``*ELEMENT_INERTIA``) block (deck units): ``nids`` node ids, or node set ids
    (``on_sets``)."""

    ids: np.ndarray
    nids: np.ndarray
    mass: np.ndarray
    pid: np.ndarray
    on_sets: bool
    src: _Source
    rows: np.ndarray
    keyword: str = "ELEMENT_MASS"


@dataclass
class _MassBody:
    """A mass [kg] shared equally by a body's nodes (SI, resolved from the deck's cards)."""

    id: int
    members: list[tuple[int, bool, tuple[Path, int]]]  # (node id or node set id, is a set, where)
    mass: float
    what: str  # the card, for messages
    replaces: bool  # the body's whole mass: lumped masses on its nodes are replaced by it


@dataclass
class _NodalBody:
    """One ``*CONSTRAINED_NODAL_RIGID_BODY_INERTIA`` body (deck units): its node set and total mass TM."""

    pid: int
    nsid: int
    tm: float
    where: tuple[Path, int]


@dataclass
class _PartMass:
    """One ``*ELEMENT_MASS_PART`` (``_SET``) card (deck units)."""

    target: int  # part id, or part set id where ``on_set``
    on_set: bool
    addmass: float
    finmass: float
    where: tuple[Path, int]


def _split_options(name: str, base: str) -> set[str]:
    rest = name[len(base) :]
    return {o for o in rest.split("_") if o}


def _read_node(block: _Block, t: _Tables, params: _Params) -> None:
    rows = _nonblank(block, block.rows)
    if rows.size == 0:
        return
    v = _table(block, rows, _NODE, params, required=("nid",), positive=("nid",))
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        i = int(bad[0])
        raise block.err(f"*NODE expects finite coordinates for node {int(v['nid'][i])}, got {xyz[i].tolist()}", rows[i])
    t.node_ids.append(v["nid"])
    t.coords.append(xyz)
    t.node_locs.add(block.src, rows)


def _grouped(block: _Block, per: int, rows: np.ndarray | None = None) -> list[np.ndarray]:
    rows = block.complete(block.rows if rows is None else rows, per)
    if rows.size % per:
        last = int(rows[-1])
        raise block.err(
            f"*{block.keyword} expects {per} lines per element, but the block ends after "
            f"{rows.size % per} line(s) of the last element",
            last,
        )
    return [rows[i::per] for i in range(per)]


_SHELL_OPTS = {"THICKNESS", "BETA", "MCID", "OFFSET"}
_SOLID_OPTS = {"ORTHO", "TET10", "TET4TOTET10", "H8TOH20", "H8TOH27"}
"""``*ELEMENT_SOLID`` options read; ``TET4TOTET10``, ``H8TOH20`` and ``H8TOH27`` ask LS-DYNA to add mid-side nodes to
plain 4- and 8-node cards, so they read as ``*ELEMENT_SOLID`` (they were skipped: a part meshed so weighed nothing)."""
_BEAM_OPTS = {"THICKNESS", "SECTION", "PID", "OFFSET", "ORIENTATION", "SCALAR", "SCALR", "WARPAGE"}


def _read_shell(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    per = 1 + bool(opts & {"THICKNESS", "BETA", "MCID"}) + ("OFFSET" in opts)
    rows = _nonblank(block, block.rows) if per == 1 else block.rows
    if rows.size == 0:
        return
    groups = _grouped(block, per, rows)
    main = groups[0]
    v = _table(block, main, _SHELL[:6], params, ("eid", "pid", "n1", "n2", "n3"), ("eid", "pid", "n1", "n2", "n3"))
    nodes = np.stack([v["n1"], v["n2"], v["n3"], v["n4"]], axis=1)
    neg = np.flatnonzero(nodes[:, 3] < 0)
    if neg.size:
        i = int(neg[0])
        raise block.err(
            f"*{block.keyword} element {v['eid'][i]}: N4 {nodes[i, 3]} is no node id (a positive id, or blank or 0 "
            "for a triangle)",
            int(main[i]),
        )
    nodes[:, 3] = np.where(nodes[:, 3] == 0, nodes[:, 2], nodes[:, 3])
    thick = np.zeros((main.size, 4))
    if per > 1 and opts & {"THICKNESS", "BETA", "MCID"}:
        th = _table(block, groups[1], _SHELL_T, params)
        thick = np.stack([th[f"t{i}"] for i in range(1, 5)], axis=1)
        bad = np.flatnonzero(~np.isfinite(thick).all(axis=1) | (thick < 0).any(axis=1))
        if bad.size:
            i = int(bad[0])
            raise block.err(f"*{block.keyword} expects thicknesses >= 0, got {thick[i].tolist()}", groups[1][i])
    t.shells.add(block.src, main, v["eid"], v["pid"], nodes, thick)


def _read_solid(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    filled = _nonblank(block, block.rows)
    if filled.size == 0:
        return
    rows = block.rows[block.rows >= filled[0]]  # blank lines before the first element are no card of it
    two_line = "TET10" in opts
    if not two_line:
        first = _read_line(block, int(rows[0]), _SOLID, params)
        two_line = all(x is None for x in first[2:])
    per = (2 if two_line else 1) + 2 * ("ORTHO" in opts)
    if per == 1:
        rows = _nonblank(block, rows)
    groups = _grouped(block, per, rows)
    main = groups[0]
    req = ("eid", "pid") if two_line else ("eid", "pid", "n1", "n2", "n3", "n4")
    head = _table(block, main, _SOLID_HEAD if two_line else _SOLID, params, req, req)
    if two_line:
        nd = _table(block, groups[1], _SOLID_NODES, params, ("n1", "n2", "n3", "n4"), ("n1", "n2", "n3", "n4"))
        nodes = np.stack([nd[f"n{i}"] for i in range(1, 9)], axis=1)
        is_tet10 = (nd["n9"] > 0) | (nd["n10"] > 0) | ("TET10" in opts)
        nodes[is_tet10, 4:] = nodes[is_tet10, 3:4]
        node_rows = groups[1]
    else:
        nodes = np.stack([head[f"n{i}"] for i in range(1, 9)], axis=1)
        node_rows = main
    tail = nodes[:, 4:]
    tet = (tail <= 0).all(axis=1)
    nodes[tet, 4:] = nodes[tet, 3:4]
    bad = np.flatnonzero((nodes <= 0).any(axis=1))
    if bad.size:
        i = int(bad[0])
        raise block.err(
            f"*{block.keyword} expects 4 (tetrahedron) or 8 positive node ids, got {nodes[i].tolist()}", node_rows[i]
        )
    t.solids.add(block.src, main, head["eid"], head["pid"], nodes, np.zeros(main.size))


def _read_beam(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    extra_opts = ["THICKNESS", "SECTION", "PID", "OFFSET", "ORIENTATION", "SCALAR", "SCALR", "WARPAGE"]
    order = [o for o in extra_opts if o in opts]
    if "THICKNESS" in order and "SECTION" in order:
        order.remove("SECTION")
    per = 1 + len(order)
    rows = _nonblank(block, block.rows) if per == 1 else block.rows
    if rows.size == 0:
        return
    groups = _grouped(block, per, rows)
    main = groups[0]
    req = ("eid", "pid", "n1", "n2")
    v = _table(block, main, _BEAM, params, req, req)
    parm = np.full((main.size, 5), np.nan)  # PARM1..PARM4 (THICKNESS), the area of a section type (SECTION)
    if "THICKNESS" in order:
        p = _table(block, groups[1 + order.index("THICKNESS")], _BEAM_T, params)
        parm[:, :4] = np.stack([p[f"p{i}"] for i in range(1, 5)], axis=1)
        parm[(parm[:, :4] == 0).all(axis=1), :4] = np.nan
    elif "SECTION" in order:  # STYPE D1 .. D6: a standard section type and its dimensions
        for k, r in enumerate(groups[1 + order.index("SECTION")].tolist()):
            stype, *d = _read_line(block, r, _BEAM_SEC, params)
            stype = str(stype or "").upper()
            parm[k, 4] = _stype_area(stype, [x or 0.0 for x in d])
            if math.isnan(parm[k, 4]):
                t.unread_stypes[stype or "blank"] += 1
    t.beams.add(block.src, main, v["eid"], v["pid"], np.stack([v["n1"], v["n2"]], axis=1), parm)


def _stype_area(stype: str, d: list[float]) -> float:
    """Area (deck units) of a standard beam section type of ``*ELEMENT_BEAM_SECTION``: ``SECTION_08`` (circular, D1
    the diameter), ``_09`` (tubular, D1 and D2 the outer and inner diameters), ``_11`` (solid box, D1 x D2); ``nan``
    for the other types (I, channel, hat, ... shapes) and for dimensions that give no area."""
    if stype == "SECTION_08":
        a = 0.25 * math.pi * d[0] ** 2
    elif stype == "SECTION_09":
        a = 0.25 * math.pi * (d[0] ** 2 - d[1] ** 2) if d[0] > d[1] >= 0 else math.nan
    elif stype == "SECTION_11":
        a = d[0] * d[1]
    else:
        return math.nan
    return a if a > 0 else math.nan


def _read_part(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    rows = block.rows.tolist()
    i = 0
    while i < len(rows):
        title = block.src.text(rows[i]).strip()
        if i + 1 >= len(rows):
            raise block.err("*PART expects a card with PID, SECID, MID after the title line, got end of block", rows[i])
        r = rows[i + 1]
        pid, secid, mid = _read_line(block, r, _PART, params)
        for val, label in ((pid, "PID"), (secid, "SECID"), (mid, "MID")):
            if val is None or val <= 0:
                k = ["PID", "SECID", "MID"].index(label)
                raise block.err(f"*PART expects a positive {label} {_field_where(block, r, _PART, k)}", r)
        if pid in t.parts:
            prev = t.parts[pid][3]
            raise block.err(f"*PART id {pid} is defined twice (first in {prev[0].name} line {prev[1]})", r)
        t.parts[int(pid)] = (title, int(secid), int(mid), (block.src.path, r + 1))
        i += 2
        if "INERTIA" in opts:  # its cards come first, the CONTACT, PRINT, ... cards after them
            if i >= len(rows):
                raise block.err("*PART_INERTIA expects a card XC, YC, ZC, TM after the part card, got end of block", r)
            _xc, _yc, _zc, tm, ircs, _nodeid = _read_line(block, rows[i], _INERTIA, params)
            if tm is None or not (math.isfinite(tm) and tm > 0):
                raise block.err(
                    f"*PART_INERTIA expects a positive mass TM {_field_where(block, rows[i], _INERTIA, 3)}",
                    rows[i],
                )
            t.inertia[int(pid)] = (float(tm), (block.src.path, rows[i] + 1))
            vel = _read_line(block, rows[i + 2], _VEL_6, params) if i + 2 < len(rows) else []  # blank at the end
            if any(x not in (None, 0.0) for x in vel[:3]):  # a rigid body set moving; at rest it says nothing
                where = (block.src.path, rows[i + 2] + 1)
                t.velocities.append(_Velocity("part", np.array([pid]), np.array([True]), where, vel=_vec(vel[:3])))
            i += 3 + (ircs == 1)
        i += sum(o in opts for o in ("CONTACT", "PRINT", "ATTACHMENT", "AVERAGED"))


def _note_unread_part(block: _Block, t: _Tables) -> None:
    """Where the PID of a ``*PART_COMPOSITE`` (a title line, then PID first) is, for the error of an element that
    refers to it."""
    _note_unread_id(block, block.rows[1:], _PART, t.unread_parts)


def _note_unread_id(
    block: _Block, rows: np.ndarray, layout: tuple[_Field, ...], table: dict[int, tuple[str, Path, int]]
) -> None:
    """Note in ``table`` the id in the first field (of ``layout``) of the first of ``rows`` of a card the reader skips:
    its keyword, file and line (an id given as a label, or unreadable, is not noted)."""
    if rows.size:
        text = block.src.text(int(rows[0]))
        tok = text.split(",")[0] if "," in text else text[: _widths(layout, block.fmt)[0]]
        try:  # read as written: a parameter here is not resolved (nor marked used) for a card that is skipped
            key = int(tok.strip())
        except ValueError:
            return
        if key > 0:
            table.setdefault(key, (block.keyword, block.src.path, block.lineno(int(rows[0]))))


def _add_section(block: _Block, t: _Tables, secid: int | None, sec: _Section, row: int) -> None:
    if secid is None or secid <= 0:
        raise block.err(f"*{block.keyword} expects a positive SECID in columns 1-10, got {secid!r}", row)
    if secid in t.sections:
        prev = t.sections[secid].where
        raise block.err(f"section id {secid} is defined twice (first in {prev[0].name} line {prev[1]})", row)
    t.sections[secid] = sec


def _read_section(block: _Block, kind: str, opts: set[str], t: _Tables, params: _Params) -> None:
    rows = block.rows.tolist()
    title = "TITLE" in opts
    i = 0
    while i < len(rows):
        i += title
        if i >= len(rows):
            raise block.err(f"*{block.keyword} expects a section card after the title, got end of block", rows[-1])
        r = rows[i]
        where = (block.src.path, r + 1)
        if kind == "solid":
            secid, elform = _read_line(block, r, _SEC_SOLID, params)
            _add_section(block, t, secid, _Section("solid", None, int(elform or 1), 0, where), r)
            i += 1
            if (elform or 0) >= 101 or (opts - {"TITLE"}):
                break  # user-element or option cards follow: only the first section of this block is read
            continue
        if i + 1 >= len(rows):
            rows = block.complete(np.asarray(rows, dtype=np.int64), i + 2).tolist()  # a blank last card: defaults
        if i + 1 >= len(rows):
            raise block.err(f"*{block.keyword} expects a second card after the section card, got end of block", r)
        if kind == "shell":
            secid, elform, _shrf, nip, _propt, _qr, icomp = _read_line(block, r, _SEC_SHELL_1, params)
            *ts, _nloc, marea = (x or 0.0 for x in _read_line(block, rows[i + 1], _SEC_SHELL_2, params))
            if any(x < 0 for x in ts) or not all(math.isfinite(x) for x in ts):  # as written: before T1 fills in
                raise block.err(f"*{block.keyword} expects thicknesses T1..T4 >= 0, got {ts}", rows[i + 1])
            t1 = ts[0]
            ts = [x if x > 0 else t1 for x in ts]  # a blank or zero T2..T4 is T1, as in LS-DYNA
            if not (math.isfinite(marea) and marea >= 0):
                at = _field_where(block, rows[i + 1], _SEC_SHELL_2, 5)
                raise block.err(f"*{block.keyword} expects a mass per area MAREA >= 0 {at}", rows[i + 1])
            sec = _Section("shell", float(np.mean(ts)), int(elform or 0), 0, where, float(marea))
            _add_section(block, t, secid, sec, r)
            i += 2
            if icomp == 1:
                i += math.ceil((nip or 2) / 8)
            if (elform or 0) >= 101 or (opts - {"TITLE"}):
                break  # user-element or option cards follow: only the first section of this block is read
        else:
            secid, elform, _shrf, qr, cst, _scoor, nsm = _read_line(block, r, _SEC_BEAM_1, params)
            a1, a2, a3, a4 = (x or 0.0 for x in _read_line(block, rows[i + 1], _SEC_BEAM_2, params))
            elform, cst, nsm = int(elform or 1), int(cst or 0), nsm or 0.0
            if not (math.isfinite(nsm) and nsm >= 0):
                at = _field_where(block, r, _SEC_BEAM_1, 6)
                raise block.err(f"*{block.keyword} expects a mass per length NSM >= 0 {at}", r)
            area = _beam_area(elform, cst, a1, a2, a3, a4, qr or 0.0)
            _add_section(block, t, secid, _Section("beam", area, elform, cst, where, float(nsm)), r)
            i += 2
            if elform >= 101 or (opts - {"TITLE"}):
                break  # user-element or option cards follow: only the first section of this block is read


def _note_unread_section(block: _Block, t: _Tables) -> None:
    """Where the first SECID of a ``*SECTION_...`` card the reader does not read is, for the error of a part that
    uses it."""
    rows = _nonblank(block, block.rows)
    _note_unread_id(block, rows[1:] if "TITLE" in block.keyword.split("_") else rows, _SEC_ID, t.unread_sections)


def _beam_area(elform: int, cst: int, a1: float, a2: float, a3: float, a4: float, qr: float = 0.0) -> float | None:
    """Beam cross-section area (deck units) from section or element parameters, ``None`` if unknown."""
    if elform in (2, 3, 12, 13):
        return a1 if a1 > 0 else None
    if elform in (1, 4, 5, 7, 8, 9, 11, 14) and qr >= 0:
        s = 0.5 * (a1 + (a2 or a1))
        tt = 0.5 * (a3 + (a4 or a3))
        if cst == 0:
            return s * tt if s > 0 and tt > 0 else None
        if cst == 1:
            return 0.25 * math.pi * (s**2 - tt**2) if s > tt >= 0 and s > 0 else None
    return None


_MAT_KINDS = {
    "ELASTIC": "elastic",
    "001": "elastic",
    "PLASTIC_KINEMATIC": "plastic_kinematic",
    "003": "plastic_kinematic",
    "RIGID": "rigid",
    "020": "rigid",
    "PIECEWISE_LINEAR_PLASTICITY": "piecewise_linear",
    "024": "piecewise_linear",
}
_MAT_024_VARIANTS = ("LOG_INTERPOLATION", "STOCHASTIC", "MIDFAIL", "2D")
_NOT_MATERIALS = ("ADD_", "THERMAL_", "NONLOCAL")


def _material_kind(keyword: str) -> tuple[str, bool] | None:
    """(kind, has_title) for a ``MAT_...`` keyword, ``None`` for cards that are no material."""
    name = keyword[4:]
    if name.startswith(_NOT_MATERIALS) or not name:
        return None
    title = name.endswith("_TITLE")
    if title:
        name = name[: -len("_TITLE")]
    if name in _MAT_KINDS:
        return _MAT_KINDS[name], title
    for base in ("PIECEWISE_LINEAR_PLASTICITY", "024"):
        if name.startswith(base + "_") and name[len(base) + 1 :] in _MAT_024_VARIANTS:
            return "piecewise_linear", title
    return ("null" if name in ("NULL", "009") else "other"), title


_STANDARD_LAYOUT = (0, 1, 2)
_MAT_LAYOUT_GROUPS: tuple[tuple[tuple[int | None, int | None, int | None], tuple[str, ...]], ...] = (
    ((0, 2, 3), ("JOHNSON_COOK", "015")),  # MID RO G E PR
    ((0, None, None), ("ISOTROPIC_ELASTIC_PLASTIC", "012", "SOIL_AND_FOAM", "005")),  # MID RO G ...
    ((0, None, None), ("VISCOELASTIC", "006", "SIMPLIFIED_RUBBER/FOAM", "SIMPLIFIED_RUBBER", "181")),  # RO BULK/KM
    ((0, None, 1), ("MOONEY-RIVLIN_RUBBER", "027", "HYPERELASTIC_RUBBER", "077_H", "OGDEN_RUBBER", "077_O")),
    ((0, 1, None), ("LOW_DENSITY_FOAM", "057", "FU_CHANG_FOAM", "083")),  # MID RO E LCID / KCON
    # orthotropic, MID RO EA EB EC PRBA: EA (the material's first axis) is taken as E
    ((0, 1, None), ("ORTHOTROPIC_ELASTIC", "002", "COMPOSITE_DAMAGE", "022", "FABRIC", "034")),
    ((0, 1, None), ("ENHANCED_COMPOSITE_DAMAGE", "054", "055", "LAMINATED_COMPOSITE_FABRIC", "058")),
    # discrete beams: MID RO, then stiffnesses
    ((0, None, None), ("LINEAR_ELASTIC_DISCRETE_BEAM", "066", "NONLINEAR_ELASTIC_DISCRETE_BEAM", "067")),
    ((0, None, None), ("NONLINEAR_PLASTIC_DISCRETE_BEAM", "068", "ELASTIC_SPRING_DISCRETE_BEAM", "074")),
    ((0, None, None), ("GENERAL_NONLINEAR_6DOF_DISCRETE_BEAM", "119", "GENERAL_NONLINEAR_1DOF_DISCRETE_BEAM", "121")),
    ((0, None, None), ("1DOF_GENERALIZED_SPRING", "146")),
)
_MAT_LAYOUTS = {name: layout for layout, names in _MAT_LAYOUT_GROUPS for name in names}
"""Where RO, E and PR sit among the fields after MID on the first card of ``*MAT`` types read as "other", where
that differs from LS-DYNA's usual ``MID RO E PR`` (:data:`_STANDARD_LAYOUT`); ``None``: not on that card."""


def _mat_layout(keyword: str) -> tuple[int | None, int | None, int | None] | None:
    """The first-card layout of a ``*MAT_...`` keyword read as "other"; ``None`` for materials without a density
    (springs, dampers, seatbelts: ``*MAT_SPRING_...``, ``*MAT_DAMPER_...``, ``*MAT_S01`` .. ``*MAT_S15``,
    ``*MAT_SEATBELT``/``*MAT_B01``), which only elements the reader skips use."""
    name = keyword[4:].removesuffix("_TITLE")
    if name.startswith(("SPRING_", "DAMPER_", "SEATBELT", "B01")) or (
        len(name) >= 3 and name[0] == "S" and name[1:3].isdigit()
    ):
        return None
    return _MAT_LAYOUTS.get(name, _STANDARD_LAYOUT)


def _read_material(block: _Block, kind: str, title: bool, t: _Tables, params: _Params) -> None:
    rows = block.rows.tolist()
    name = block.keyword
    if title:
        if not rows:
            raise block.err(f"*{block.keyword} expects a title line, got end of block")
        name = block.src.text(rows[0]).strip() or name
        rows = rows[1:]
    if not rows:
        raise block.err(f"*{block.keyword} expects a card with MID, RO, ...; got end of block")
    r = rows[0]
    lenient = kind in ("other", "null")
    cards = _MAT_CARDS.get(kind, (_MAT_1,))
    c = _read_line(block, r, cards[0], params, lenient=lenient)
    mid = c[0]
    if mid is None or mid <= 0:
        raise block.err(f"*{block.keyword} expects a positive MID {_field_where(block, r, _MAT_1, 0)}", r)
    if mid in t.materials:
        prev = t.materials[mid].where
        raise block.err(f"material id {mid} is defined twice (first in {prev[0].name} line {prev[1]})", r)

    def card(k: int) -> list[float]:
        layout = cards[k] if k < len(cards) else _MAT_8
        if k >= len(rows):
            return [0.0] * len(layout)
        return [x or 0.0 for x in _read_line(block, rows[k], layout, params, lenient=lenient)]

    f = [x if x is not None else math.nan for x in c[1:]]
    vals: dict[str, float] = {"ro": f[0], "e": f[1], "pr": f[2]}
    note = None
    if kind == "null":
        vals = {"ro": f[0], "e": f[5], "pr": f[6]}
        kind = "other"
    elif kind == "other":
        layout = _mat_layout(block.keyword)
        ro_i, e_i, pr_i = layout if layout is not None else (None, None, None)
        vals = {k: f[i] if i is not None else math.nan for k, i in (("ro", ro_i), ("e", e_i), ("pr", pr_i))}
        if layout is None:
            note = "a spring, damper or seatbelt material: no density"
        elif layout is _STANDARD_LAYOUT and math.isfinite(vals["pr"]) and not -1.0 < vals["pr"] < 0.5:
            note = (
                f"its first card does not read as MID RO E PR (PR field {vals['pr']:g}): the reader does not know "
                "this material's layout, so its Young's modulus and Poisson's ratio are defaulted"
            )
            vals.update(e=math.nan, pr=math.nan)
        elif e_i is None:
            note = "its first card gives no Young's modulus"
    elif kind == "plastic_kinematic":
        vals.update(sigy=f[3], etan=f[4], fail=card(1)[2])
    elif kind == "piecewise_linear":
        c2 = card(1)
        vals.update(sigy=f[3], etan=f[4], fail=f[5], lcss=c2[2])
        vals["eps"], vals["es"] = card(2), card(3)  # type: ignore[assignment]
    elif kind == "rigid":
        cmo, con1, con2 = card(1)[:3]
        vals.update(cmo=cmo, con1=con1, con2=con2)
    where = (block.src.path, r + 1)
    t.materials[int(mid)] = _RawMaterial(int(mid), name, kind, vals, where, block.keyword, note, kind == "other"
                                         and _mat_layout(block.keyword) is None)  # fmt: skip
    if not math.isfinite(vals["ro"]):
        t.materials[int(mid)].ro_at = _field_where(block, r, cards[0], 1)


def _read_id_set(block: _Block, opts: set[str], out: dict[int, _IdSet], params: _Params) -> None:
    """A ``*SET_PART``/``*SET_NODE`` ``[_LIST][_TITLE][_GENERATE]`` block into ``out[sid]``."""
    rows = block.rows.tolist()
    title = ""
    if "TITLE" in opts:
        title = block.src.text(rows[0]).strip() if rows else ""
        rows = rows[1:]
    if not rows:
        raise block.err(f"*{block.keyword} expects a card with SID, got end of block")
    (sid,) = _read_line(block, rows[0], _SET_HEAD, params)
    if sid is None or sid <= 0:
        raise block.err(
            f"*{block.keyword} expects a positive SID {_field_where(block, rows[0], _SET_HEAD, 0)}", rows[0]
        )
    ids = np.zeros(0, dtype=np.int64)
    ranges = np.zeros((0, 2), dtype=np.int64)
    body = _nonblank(block, np.asarray(rows[1:], dtype=np.int64))
    if body.size:
        layout = _SET_RANGES if "GENERATE" in opts else _SET_NIDS if block.keyword.startswith("SET_NODE") else _SET_PIDS
        v = _table(block, body, layout, params)
        vals = np.stack([v[f.name] for f in layout], axis=1)  # [lines, 8], blanks 0
        if "GENERATE" in opts:
            ends: list[tuple[int, int]] = []
            for row, line in zip(body.tolist(), vals.tolist(), strict=True):
                for k in range(4):
                    a, b = line[2 * k], line[2 * k + 1]
                    if not (a or b):
                        continue
                    beg, end = f"B{k + 1}BEG", f"B{k + 1}END"
                    if a <= 0 or b <= 0:
                        raise block.err(f"*{block.keyword} expects positive ids {beg} and {end}, got {a} and {b}", row)
                    if a > b:
                        raise block.err(
                            f"*{block.keyword} expects {beg} <= {end} (a range from first to last id), got {a} > {b}",
                            row,
                        )
                    ends.append((a, b))
            ranges = np.array(ends, dtype=np.int64).reshape(-1, 2)
        else:
            ids = vals.ravel()
            ids = ids[ids != 0]
    where = (block.src.path, rows[0] + 1)
    prev = out[int(sid)].where if int(sid) in out else None
    if prev is not None:
        raise block.err(
            f"*{block.keyword} SID {sid} is defined twice (first in {prev[0].name} line {prev[1]})", rows[0]
        )
    out[int(sid)] = _IdSet(title, ids, ranges, where)


def _vec(v: list[float | None]) -> np.ndarray:
    """``[1, 3]`` translational velocity from read fields (blanks: 0)."""
    return np.array([[x or 0.0 for x in v]], dtype=float)


def _read_velocity(block: _Block, opts: set[str], t: _Tables, params: _Params) -> bool:
    """``*INITIAL_VELOCITY``, ``_NODE``, ``_GENERATION`` and ``_RIGID_BODY``; ``False`` for other options.

    Only which nodes, parts or sets are set moving is kept (any non-zero translational
    velocity): that tells the vehicle from a barrier at rest (:func:`_stationary_parts`).
    """
    # one-line tables skip blank lines; in card pairs a blank line is a card of defaults
    rows = _nonblank(block, block.rows) if opts in ({"NODE"}, {"RIGID", "BODY"}) else block.rows
    if rows.size == 0:
        return True
    where = (block.src.path, block.lineno(int(rows[0])))

    def moving(*v: float | None) -> bool:
        return any(x not in (None, 0.0) for x in v)

    if opts == {"NODE"}:
        v = _table(block, rows, _VEL_NODE, params, required=("nid",), positive=("nid",))
        mv = (v["vx"] != 0) | (v["vy"] != 0) | (v["vz"] != 0)
        loc = np.flatnonzero(mv & (v["icid"] != 0))
        local = (int(v["icid"][loc[0]]), block.lineno(int(rows[loc[0]]))) if loc.size else None
        given = None if local else np.stack([v["vx"], v["vy"], v["vz"]], 1)
        t.velocities.append(_Velocity("nodes", v["nid"], mv, where, vel=given, local=local))
    elif opts == {"RIGID", "BODY"}:
        for r in rows.tolist():
            pid, *vel, icid = _read_line(block, r, _VEL_NODE, params)
            local = (int(icid), block.lineno(r)) if icid else None
            t.velocities.append(
                _Velocity(
                    "part",
                    np.array([pid or 0]),
                    np.array([moving(*vel[:3])]),
                    where,
                    vel=None if local else _vec(vel[:3]),
                    local=local,
                )
            )
    elif not opts:  # NSID NSIDEX BOXID ..., then VX VY VZ ..., then VXE VYE VZE ... where NSIDEX > 0
        r = rows.tolist()
        nsid, nsidex, boxid, _, icid = _read_line(block, r[0], _VEL_HEAD, params)
        vel = _read_line(block, r[1], _VEL_6, params) if len(r) > 1 else []
        target = "box" if boxid else "node_set" if nsid else "all"
        exempt_moving = bool(nsidex) and len(r) > 2 and moving(*_read_line(block, r[2], _VEL_6, params)[:3])
        t.velocities.append(
            _Velocity(
                target,
                np.array([nsid or 0]),
                np.array([moving(*vel[:3])]),
                where,
                nsidex or 0,
                exempt_moving,
                vel=None if icid else _vec(vel[:3]),
                local=(int(icid), where[1]) if icid else None,
            )
        )
    elif opts == {"GENERATION"}:
        for k in range(0, rows.size, 2):  # ID STYP OMEGA VX VY VZ ..., then XC YC ZC NX NY NZ PHASE IRIGID
            gid, styp, omega, vx, vy, vz, _, icid = _read_line(block, int(rows[k]), _VEL_GEN, params)
            target = {1: "part_set", 2: "part", 3: "node_set"}.get(styp or 0, "unknown") if gid else "all"
            t.velocities.append(
                _Velocity(
                    target,
                    np.array([gid or 0]),
                    np.array([moving(vx, vy, vz, omega)]),
                    where,
                    vel=None if icid else _vec([vx, vy, vz]),
                    local=(int(icid), block.lineno(int(rows[k]))) if icid else None,
                )
            )
    else:
        return False
    return True


def _read_element_mass(block: _Block, opts: set[str], t: _Tables, params: _Params) -> bool:
    """``*ELEMENT_MASS`` (``_NODE_SET``) and ``*ELEMENT_MASS_PART`` (``_SET``); ``False`` for other options."""
    rows = _nonblank(block, block.rows)
    if opts <= {"NODE", "SET"} and opts != {"NODE"}:
        if rows.size:
            on_sets = bool(opts)
            layout = _ELEM_MASS_SET if on_sets else _ELEM_MASS
            v = _table(block, rows, layout, params, required=("eid", "nid"), positive=("eid", "nid"))  # MASS: 0
            bad = np.flatnonzero(~(np.isfinite(v["mass"]) & (v["mass"] >= 0)))
            if bad.size:
                i = int(bad[0])
                raise block.err(
                    f"*{block.keyword} expects a mass >= 0 {_field_where(block, int(rows[i]), layout, 2)}", int(rows[i])
                )
            masses = _PointMasses(v["eid"], v["nid"], v["mass"], v["pid"], on_sets, block.src, rows, block.keyword)
            t.point_masses.append(masses)
        return True
    if opts in ({"PART"}, {"PART", "SET"}):
        for r in rows.tolist():
            pid, addmass, finmass = _read_line(block, r, _MASS_PART, params)
            what = "PSID" if "SET" in opts else "PID"
            if pid is None or pid <= 0:
                at = _field_where(block, r, _MASS_PART, 0)
                raise block.err(f"*{block.keyword} expects a positive {what} {at}", r)
            for k, val in ((1, addmass), (2, finmass)):
                if val is not None and not (math.isfinite(val) and val >= 0):
                    label = _MASS_PART[k].label
                    raise block.err(f"*{block.keyword} expects {label} >= 0 {_field_where(block, r, _MASS_PART, k)}", r)
            t.part_masses.append(
                _PartMass(int(pid), "SET" in opts, addmass or 0.0, finmass or 0.0, (block.src.path, r + 1))
            )
        return True
    return False


def _read_element_inertia(block: _Block, opts: set[str], t: _Tables, params: _Params) -> bool:
    """``*ELEMENT_INERTIA`` (``_OFFSET``): EID, NID, CSID, then IXX .. IZZ, MASS (then the offset); the mass is
    kept as a point mass on the node (the surrogate moves cells, it does not rotate them: the inertia tensor and
    the offset are not needed). ``False`` for other options."""
    if not opts <= {"OFFSET"}:
        return False
    rows = block.rows
    if rows.size == 0:
        return True
    groups = _grouped(block, 2 + ("OFFSET" in opts), rows)
    head = _table(block, groups[0], _ELEM_INERTIA, params, required=("eid", "nid"), positive=("eid", "nid"))
    mass = _table(block, groups[1], _ELEM_INERTIA_2, params)["mass"]
    bad = np.flatnonzero(~(np.isfinite(mass) & (mass >= 0)))
    if bad.size:
        r = int(groups[1][int(bad[0])])
        raise block.err(f"*{block.keyword} expects a mass >= 0 {_field_where(block, r, _ELEM_INERTIA_2, 6)}", r)
    pid = np.zeros(mass.size, dtype=np.int64)
    t.point_masses.append(_PointMasses(head["eid"], head["nid"], mass, pid, False, block.src, groups[0], block.keyword))
    return True


def _read_nodal_body(block: _Block, opts: set[str], t: _Tables, params: _Params) -> bool:
    """``*CONSTRAINED_NODAL_RIGID_BODY_INERTIA`` (``_SPC``, ``_TITLE``): per body the card PID .. NSID, the SPC
    card, XC YC ZC TM IRCS NODEID, the inertia tensor, VTX .. VRZ and, where IRCS = 1, the local axes. Keeps the
    node set and TM, and a non-zero VTX .. VTZ as an initial velocity of the set. ``False`` without ``INERTIA``
    (a nodal rigid body without inertia adds no mass)."""
    if "INERTIA" not in opts or not opts <= {"INERTIA", "SPC", "TITLE"}:
        return False
    rows = block.rows.tolist()
    i = 0
    while i < len(rows):
        i += "TITLE" in opts
        if i >= len(rows):
            raise block.err(
                f"*{block.keyword} expects a card PID, CID, NSID after the title, got end of block", rows[-1]
            )
        r = rows[i]
        pid, _cid, nsid, *_ = _read_line(block, r, _NODAL_BODY, params)
        if pid is None or pid <= 0:
            raise block.err(f"*{block.keyword} expects a positive PID {_field_where(block, r, _NODAL_BODY, 0)}", r)
        if nsid is not None and nsid < 0:
            raise block.err(
                f"*{block.keyword} expects a node set NSID >= 0 {_field_where(block, r, _NODAL_BODY, 2)}", r
            )
        i += 1 + ("SPC" in opts)
        if i >= len(rows):
            raise block.err(f"*{block.keyword} expects a card XC, YC, ZC, TM for body {pid}, got end of block", r)
        _xc, _yc, _zc, tm, ircs, _nodeid = _read_line(block, rows[i], _INERTIA, params)
        if tm is not None and not (math.isfinite(tm) and tm >= 0):
            raise block.err(
                f"*{block.keyword} expects a mass TM >= 0 {_field_where(block, rows[i], _INERTIA, 3)}", rows[i]
            )
        where = (block.src.path, r + 1)  # the card that names the node set
        sid = int(nsid or pid)  # NSID 0: the node set numbered as the body
        t.nodal_bodies.append(_NodalBody(int(pid), sid, float(tm or 0.0), where))
        vel = _read_line(block, rows[i + 2], _VEL_6, params) if i + 2 < len(rows) else []
        if any(x not in (None, 0.0) for x in vel[:3]):
            where = (block.src.path, rows[i + 2] + 1)
            t.velocities.append(_Velocity("node_set", np.array([sid]), np.array([True]), where, vel=_vec(vel[:3])))
        i += 3 + (ircs == 1)
    return True


def _read_extra_nodes(block: _Block, opts: set[str], t: _Tables, params: _Params) -> bool:
    """``*CONSTRAINED_EXTRA_NODES_NODE`` / ``_SET``: PID, NID (NSID), IFLAG per card; ``False`` otherwise."""
    if opts not in ({"NODE"}, {"SET"}):
        return False
    for r in _nonblank(block, block.rows).tolist():
        pid, nid, _iflag = _read_line(block, r, _EXTRA_NODES, params)
        for k, (val, label) in enumerate(((pid, "PID"), (nid, "NSID" if "SET" in opts else "NID"))):
            if val is None or val <= 0:
                raise block.err(
                    f"*{block.keyword} expects a positive {label} {_field_where(block, r, _EXTRA_NODES, k)}", r
                )
        t.extra_nodes.setdefault(int(pid), []).append((int(nid), "SET" in opts, (block.src.path, r + 1)))
    return True


def _claim_curve_id(block: _Block, t: _Tables, label: str, ident: int | None, row: int) -> int:
    """A ``*DEFINE_CURVE``'s LCID or a ``*DEFINE_TABLE``'s TBID (``label``), checked positive and not yet defined
    (curves and tables share one id space in LS-DYNA), and recorded as defined at ``row``."""
    if ident is None or ident <= 0:
        raise block.err(f"*{block.keyword} expects a positive {label} in columns 1-10, got {ident!r}", row)
    prev = t.curve_at.get(int(ident))
    if prev is not None:
        raise block.err(
            f"*{block.keyword} {label} {ident} is defined twice (first in {prev[0].name} line {prev[1]})", row
        )
    t.curve_at[int(ident)] = (block.src.path, block.lineno(row))
    return int(ident)


def _read_curve(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    rows = block.rows.tolist()
    if "TITLE" in opts:
        rows = rows[1:]
    if not rows:
        raise block.err(f"*{block.keyword} expects a card with LCID, got end of block")
    lcid, _sidr, sfa, sfo, offa, offo = _read_line(block, rows[0], _CURVE_HEAD, params)
    lcid = _claim_curve_id(block, t, "LCID", lcid, rows[0])
    pts = np.array([[x or 0.0 for x in _read_line(block, r, _CURVE_PT, params)] for r in rows[1:]]).reshape(-1, 2)
    # scaled after the offsets are applied (LS-DYNA manual, *DEFINE_CURVE); SFA, SFO 0 (or blank) mean 1
    x = (pts[:, 0] + (offa or 0.0)) * (sfa or 1.0)
    y = (pts[:, 1] + (offo or 0.0)) * (sfo or 1.0)
    back = np.flatnonzero(np.diff(x) < 0)
    if back.size:  # LS-DYNA refuses such a curve; interpolating it would give a silently wrong value
        i = int(back[0]) + 1
        raise block.err(
            f"*{block.keyword} LCID {lcid}: the abscissae must not decrease, point {i + 1} has {pts[i, 0]:g} after "
            f"{pts[i - 1, 0]:g}",
            rows[1 + i],
        )
    t.curves[int(lcid)] = (x, y)
    if t.table_open is not None:  # one of the curves of the *DEFINE_TABLE before it
        table = t.tables[t.table_open]
        table.curve_ids.append(int(lcid))
        if len(table.curve_ids) == len(table.values):
            t.table_open = None


def _read_table(block: _Block, opts: set[str], t: _Tables, params: _Params) -> None:
    """``*DEFINE_TABLE`` (values; its curves are the ``*DEFINE_CURVE`` keywords right after it, in the values'
    order, as LS-DYNA reads them) or ``*DEFINE_TABLE_2D`` (value and curve id on each card), with ``_TITLE``."""
    rows = _nonblank(block, block.rows).tolist()
    if "TITLE" in opts:
        rows = rows[1:]
    if not rows:
        raise block.err(f"*{block.keyword} expects a card with TBID, got end of block")
    tbid, sfa, offa = _read_line(block, rows[0], _TABLE_HEAD, params)
    tbid = _claim_curve_id(block, t, "TBID", tbid, rows[0])
    two_d = "2D" in opts
    layout = _TABLE_2D_ROW if two_d else _TABLE_2D_ROW[:1]
    cards = [_read_line(block, r, layout, params) for r in rows[1:]]
    for r, card in zip(rows[1:], cards, strict=True):
        if card[0] is None or (two_d and (card[1] is None or card[1] <= 0)):
            what = "a VALUE and a positive CURVEID" if two_d else "a VALUE"
            raise block.err(f"*{block.keyword} TBID {tbid} expects {what} on each card, got {card!r}", r)
    if not cards:
        raise block.err(f"*{block.keyword} TBID {tbid} lists no value", rows[0])
    values = (np.array([c[0] for c in cards], dtype=float) + (offa or 0.0)) * (sfa or 1.0)
    back = np.flatnonzero(np.diff(values) <= 0)
    if back.size:  # LS-DYNA interpolates between the curves of increasing values
        i = int(back[0]) + 1
        raise block.err(
            f"*{block.keyword} TBID {tbid}: the values must increase, value {i + 1} is {cards[i][0]:g} after "
            f"{cards[i - 1][0]:g}",
            rows[1 + i],
        )
    t.tables[tbid] = _CurveTable(values, [int(c[1]) for c in cards] if two_d else [], t.curve_at[tbid])
    if not two_d:
        t.table_open = tbid


def _table_unfinished(t: _Tables, tbid: int, before: str) -> DeckError:
    """The error of *DEFINE_TABLE ``tbid`` whose curves do not all follow it (``before``: what came instead)."""
    table = t.tables[tbid]
    return DeckError(
        f"*DEFINE_TABLE {tbid} lists {len(table.values)} values but {len(table.curve_ids)} *DEFINE_CURVE "
        f"follow it before {before}; LS-DYNA reads a table's curves from the keywords right after it, one per value",
        *table.where,
    )


def _dispatch(block: _Block, t: _Tables, deck: _Deck) -> None:
    kw = block.keyword
    params = deck.params
    if t.table_open is not None and kw not in ("DEFINE_CURVE", "DEFINE_CURVE_TITLE"):
        raise _table_unfinished(
            t, t.table_open, f"*{kw} ({file_label(block.src.path)} line {block.lineno(block.line)})"
        )
    if kw == "NODE":
        _read_node(block, t, params)
        return
    for base, opts_ok, reader in (
        ("ELEMENT_SHELL", _SHELL_OPTS, _read_shell),
        ("ELEMENT_SOLID", _SOLID_OPTS, _read_solid),
        ("ELEMENT_BEAM", _BEAM_OPTS, _read_beam),
    ):
        if kw == base or kw.startswith(base + "_"):
            opts = _split_options(kw, base)
            if opts <= opts_ok:
                reader(block, opts, t, params)
                return
            deck.skipped[kw] += 1
            return
    for base, read_or_refuse in (
        ("ELEMENT_MASS", _read_element_mass),
        ("ELEMENT_INERTIA", _read_element_inertia),
        ("CONSTRAINED_NODAL_RIGID_BODY", _read_nodal_body),
        ("CONSTRAINED_EXTRA_NODES", _read_extra_nodes),
    ):
        if kw == base or kw.startswith(base + "_"):
            if not read_or_refuse(block, _split_options(kw, base), t, params):
                deck.skipped[kw] += 1
            return
    if kw == "PART" or kw.startswith("PART_"):
        opts = _split_options(kw, "PART")
        opts = {"ATTACHMENT" if o == "NODES" else o for o in opts} - {"NODES"}
        if opts <= {"CONTACT", "PRINT", "ATTACHMENT", "AVERAGED", "INERTIA"}:
            _read_part(block, opts, t, params)
        else:
            if "COMPOSITE" in opts:  # a title line and PID first, as *PART's: named if its elements refer to it
                _note_unread_part(block, t)
            deck.skipped[kw] += 1
        return
    for base, kind in (("SECTION_SHELL", "shell"), ("SECTION_SOLID", "solid"), ("SECTION_BEAM", "beam")):
        if kw == base or kw.startswith(base + "_"):
            opts = _split_options(kw, base)
            if opts <= {"TITLE"} or (kind == "shell" and opts <= {"TITLE", "ALE", "MISC", "EFG", "XFEM"}):
                _read_section(block, kind, opts, t, params)
            else:
                _note_unread_section(block, t)
                deck.skipped[kw] += 1
            return
    if kw.startswith("SECTION_"):  # *SECTION_DISCRETE, _SEATBELT, _TSHELL, ...
        _note_unread_section(block, t)
        deck.skipped[kw] += 1
        return
    if kw.startswith("MAT_"):
        mk = _material_kind(kw)
        if mk is None:
            deck.skipped[kw] += 1
        else:
            _read_material(block, mk[0], mk[1], t, params)
        return
    for base, sets in (("SET_PART", t.set_cards), ("SET_NODE", t.node_set_cards)):
        if kw == base or kw.startswith(base + "_"):
            opts = _split_options(kw, base)
            if opts <= {"LIST", "TITLE", "GENERATE"}:
                _read_id_set(block, opts, sets, params)
            else:
                deck.skipped[kw] += 1
            return
    if (kw == "INITIAL_VELOCITY" or kw.startswith("INITIAL_VELOCITY_")) and _read_velocity(
        block, _split_options(kw, "INITIAL_VELOCITY"), t, params
    ):
        return
    if kw == "CONSTRAINED_RIGID_BODIES":
        for r in _nonblank(block, block.rows).tolist():
            pidm, pids = _read_line(block, r, _MERGE, params)
            if pidm and pids:
                t.rigid_merges.append((int(pidm), int(pids), (block.src.path, block.lineno(r))))
        return
    if kw in ("DEFINE_CURVE", "DEFINE_CURVE_TITLE"):
        _read_curve(block, _split_options(kw, "DEFINE_CURVE"), t, params)
        return
    if kw == "DEFINE_TABLE" or kw.startswith("DEFINE_TABLE_"):
        opts = _split_options(kw, "DEFINE_TABLE")
        if opts <= {"TITLE", "2D"}:
            _read_table(block, opts, t, params)
            return
    deck.skipped[kw] += 1


# --------------------------------------------------------------------------- assembly


def _table_curve(raw: _RawMaterial, lcss: int, t: _Tables, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The stress-strain curve of a ``*MAT_024`` whose LCSS is a ``*DEFINE_TABLE``: that of its lowest strain rate
    (the quasi-static one; the cells' crush efficiency ``eta_shell`` carries the rate effects), with a note."""
    table = t.tables[lcss]
    absent = [c for c in table.curve_ids if c not in t.curves]
    if absent:
        raise DeckError(f"*DEFINE_TABLE_2D {lcss} (LCSS of material {raw.mid}) names curve {absent[0]}, which the "
                        "deck does not define", *table.where)  # fmt: skip
    lowest = float(table.values[0])
    rate = math.exp(lowest) if lowest < 0 else lowest  # a first value < 0: the values are ln(strain rate)
    notes.append(
        f"material {raw.mid} ({raw.name}): LCSS {lcss} is a *DEFINE_TABLE of {len(table.values)} strain rates; the "
        f"curve of the lowest ({rate:.4g}/s, LCID {table.curve_ids[0]}) is used (eta_shell carries rate effects)"
    )
    return t.curves[table.curve_ids[0]]


def _material_si(raw: _RawMaterial, u: UnitSystem, t: _Tables, notes: list[str]) -> Material:
    curves = t.curves
    v = raw.values
    ro, e, pr = v["ro"] * u.density, v["e"] * u.stress, v["pr"]
    sy = su = sf = math.nan
    if raw.kind in ("plastic_kinematic", "piecewise_linear"):
        sy = v["sigy"] * u.stress
        etan = v["etan"] * u.stress
        fail = v["fail"]
        eh = e * etan / (e - etan) if 0 < etan < e else 0.0
        has_fail = 0 < fail < _NO_FAILURE
        pts = None
        if raw.kind == "piecewise_linear":
            lcss = int(v["lcss"])
            if lcss > 0 and (lcss in curves or lcss in t.tables):
                x, y = curves[lcss] if lcss in curves else _table_curve(raw, lcss, t, notes)
                pts = (x, y * u.stress)
            elif lcss > 0:
                notes.append(f"material {raw.mid} ({raw.name}): LCSS {lcss} is neither a *DEFINE_CURVE nor a "
                             "*DEFINE_TABLE, ETAN used")  # fmt: skip
            else:
                es = np.asarray(v["es"], dtype=float)
                keep = es > 0
                if keep.any():
                    pts = (np.asarray(v["eps"], dtype=float)[keep], es[keep] * u.stress)
        if pts is not None and len(pts[1]):
            x, y = pts
            sy = float(y[0])  # LS-DYNA ignores SIGY where LCSS or the EPS/ES points give the curve
            su = float(np.max(y))
            sf = float(np.interp(fail, x, y)) if has_fail else su
        elif has_fail and sy > 0:
            su = sf = sy + eh * fail
    return Material(
        id=raw.mid,
        name=raw.name,
        kind=raw.kind,
        density=ro,
        youngs_modulus=e,
        yield_strength=sy,
        ultimate_strength=su,
        fracture_strength=sf,
        poisson_ratio=pr,
    )


def _mat_label(raw: _RawMaterial) -> str:
    """``name, *KEYWORD`` of a read material (the keyword alone where the card has no title)."""
    return f"*{raw.keyword}" if raw.name == raw.keyword else f"{raw.name}, *{raw.keyword}"


def _drop_unread_parts(t: _Tables, carried: set[int], notes: list[str]) -> None:
    """Leave out the parts that carry nothing the reader reads and refer to what it does not read.

    A part with no shell, solid or beam elements (and no rigid-body mass on extra nodes: ``carried``) whose
    section is not a ``*SECTION_SHELL``/``_SOLID``/``_BEAM`` (``*SECTION_DISCRETE``, ``_SEATBELT``, ``_TSHELL``,
    ...), whose material is missing, or whose material has no density (springs, dampers, seatbelts) holds the
    skipped elements of a full-vehicle deck (springs, belts, thick shells): one note lists them. Parts with
    elements the reader reads still have to refer to a section and a material it reads.
    """
    why: dict[str, list[int]] = {}
    for pid, (title, secid, mid, _where) in list(t.parts.items()):
        if pid in carried:
            continue
        if secid not in t.sections:
            reason = "a section the reader does not read"
        elif mid not in t.materials:
            reason = "no material the deck defines"
        elif t.materials[mid].densityless:
            reason = f"a material without a density (*{t.materials[mid].keyword})"
        else:
            continue
        why.setdefault(reason, []).append(pid)
        t.dropped[pid] = f"part {pid} ({title!r}) has no shell, solid or beam elements and {reason}: not modelled"
        del t.parts[pid]
    for reason, pids in why.items():
        notes.append(f"{len(pids)} part(s) without shell, solid or beam elements and with {reason} left out: "
                     f"{sorted(pids)[:10]}{' ...' if len(pids) > 10 else ''}")  # fmt: skip


def _complete_raw(
    raw: _RawMaterial, u: UnitSystem, t: _Tables, es_known: list[float], notes: list[str], user: int | None
) -> Material:
    """A read material in SI with its 8-vector completed (:func:`complete_material`); ``notes`` gets its defaults;
    ``user``: a part that uses it, named in the error about a material without a density.

    Raises:
        DeckError: no density, or a value :func:`complete_material` refuses, at the card.
    """
    mid = raw.mid
    if raw.densityless:
        raise DeckError(f"material {mid} ({_mat_label(raw)}) is {raw.note}, yet part {user} uses it", *raw.where)
    if raw.note is not None:
        notes.append(f"material {mid} ({_mat_label(raw)}): {raw.note}")
    m = _material_si(raw, u, t, notes)
    if not (math.isfinite(m.youngs_modulus) and m.youngs_modulus > 0) and raw.kind == "other":
        e_def = float(np.median(es_known)) if es_known else 2.1e11
        notes.append(f"material {mid} ({raw.name}): Young's modulus not given, defaulted to {e_def:.4g} Pa")
        m = Material(mid, m.name, m.kind, m.density, e_def, poisson_ratio=m.poisson_ratio)
    if not math.isfinite(m.density) and raw.kind == "other":
        raise DeckError(f"*MAT card {mid} expects a numeric density RO {raw.ro_at}", *raw.where)
    try:
        m = complete_material(m)
    except ModelError as err:
        raise DeckError(str(err), *raw.where) from None
    notes.extend(m.warnings)
    return m


def _lookup(keys: np.ndarray, values: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised dict lookup: ``(values[pos], found)`` for sorted ``keys``."""
    if keys.size == 0:
        return np.zeros(query.shape, values.dtype), np.zeros(query.shape, bool)
    pos = np.searchsorted(keys, query)
    pos_c = np.minimum(pos, keys.size - 1)
    found = keys[pos_c] == query
    return values[pos_c], found


def _check_duplicates(ids: np.ndarray, locs: _Locs, what: str) -> None:
    if ids.size < 2:
        return
    order = np.argsort(ids, kind="stable")
    s = ids[order]
    dup = np.flatnonzero(s[1:] == s[:-1])
    if dup.size:
        k = int(dup[0])
        first, second = int(order[k]), int(order[k + 1])
        p1, l1 = locs.where(first)
        p2, l2 = locs.where(second)
        raise DeckError(f"{what} id {int(s[k])} is defined twice (first in {p1.name} line {l1})", p2, l2)


_WAVE_SPEED_KINDS = ("elastic", "plastic_kinematic", "piecewise_linear")
"""The material kinds whose wave speed is checked card by card: the metals and structural polymers of a body in
white (foams, honeycombs and rubbers lie outside :data:`marlcrash.units.CARD_WAVE_SPEED_WINDOW`, and a rigid body's E
is a contact stiffness)."""


def _assemble(deck: _Deck, t: _Tables, units: str | None, main: Path) -> tuple[VehicleModel, list[str]]:
    notes: list[str] = list(deck.params.notes)
    stopped = "".join(f" (reading stopped at the *END in {p.name} line {n}, before the rest of that file)"
                      for p, n in deck.early_end[:1])  # fmt: skip
    if not t.node_ids:  # checked first: an empty or wrong file has no materials either, and says so more plainly
        raise DeckError(f"the deck has no *NODE data{stopped}", main)
    node_ids = np.concatenate(t.node_ids)
    _check_duplicates(node_ids, t.node_locs, "node")
    elem_parts = {int(p) for a in (*t.shells.part, *t.solids.part, *t.beams.part) for p in np.unique(a).tolist()}
    if not elem_parts:
        raise DeckError(f"the deck has no *ELEMENT_SHELL, *ELEMENT_SOLID or *ELEMENT_BEAM data{stopped}", main)
    _drop_unread_parts(t, elem_parts | (set(t.inertia) & set(t.extra_nodes)), notes)
    used: dict[int, int] = {}  # material id -> the first part (one with elements or mass) that uses it
    for pid, (_, _, mid, _) in t.parts.items():
        used.setdefault(mid, pid)
    for mid, pid in used.items():  # before the units: a blank density would read as "no unit system fits"
        raw = t.materials.get(mid)
        if raw is not None and not raw.densityless and not math.isfinite(raw.values["ro"]):
            raise DeckError(
                f"*MAT card {mid} expects a numeric density RO {raw.ro_at} ({_mat_label(raw)}, used by part {pid})",
                *raw.where,
            )
    # ---- units, from the materials of the parts kept (the deck's others may be of any kind: foams, belts, springs)
    judged = [m for mid, m in t.materials.items() if mid in used] or list(t.materials.values())
    rho = np.array([m.values["ro"] for m in judged], dtype=float)
    e = np.array([m.values["e"] for m in judged], dtype=float)
    whole = False  # the deck as a whole reads in other units than those given (one warning says so)
    if units is not None:
        u = get_unit_system(units)
        seen = detect_unit_system(rho, e)
        if seen is not None and seen.name != u.name:  # the user may know better: a warning, not an error
            whole = True
            msg = (
                f"units {u.name} given, but the material densities (median {np.nanmedian(rho):.4g}) and moduli read "
                f"as {seen.name}: lengths, masses and strengths will be off by orders of magnitude"
            )
            notes.append(msg)
            warnings.warn(f"{main.name}: {msg}", UserWarning, stacklevel=3)
        pos = rho[np.isfinite(rho) & (rho > 0)]
        ro_med = float(np.median(pos)) if pos.size else 0.0
        if seen is None and ro_med > 0 and not density_fits(ro_med, u):  # a system the reader does not know
            whole = True
            msg = (
                f"units {u.name} given, but the material densities (median {ro_med:.4g}) read as "
                f"{ro_med * u.density:.4g} kg/m^3 in it, outside the structural materials' {DENSITY_WINDOW[0]:g} "
                f"to {DENSITY_WINDOW[1]:g} kg/m^3: masses will be off by orders of magnitude (the reader knows "
                f"{UNIT_SYSTEM_NAMES} only; a deck in another system must be converted)"
            )
            notes.append(msg)
            warnings.warn(f"{main.name}: {msg}", UserWarning, stacklevel=3)
    else:
        detected = detect_unit_system(rho, e)
        if detected is None:
            med = f"{np.nanmedian(rho):.4g}" if rho.size else "n/a"
            raise DeckError(
                f"cannot tell the unit system from material densities (median {med}) and moduli{stopped}; "
                f"give it: --units on the command line, units= in Python, one of {UNIT_SYSTEM_NAMES}",
                main,
            )
        u = detected
    for mid, pid in used.items() if not whole else ():  # one card in other units than the rest: mass or E off 1e3x+
        raw = t.materials.get(mid)
        if raw is None or raw.densityless or pid in t.inertia:  # undefined (refused below), or its mass set
            continue
        ro = raw.values["ro"]
        if ro > 0 and not density_fits(ro, u):
            fits = [s.name for s in UNIT_SYSTEMS.values() if density_fits(ro, s)]
            if fits:
                msg = (
                    f"material {mid} ({_mat_label(raw)}) density RO {ro:g} ({raw.where[0].name} line {raw.where[1]}) "
                    f"as {u.name} is {ro * u.density:.4g} kg/m^3, outside the structural materials' "
                    f"{DENSITY_WINDOW[0]:g} to {DENSITY_WINDOW[1]:g} kg/m^3; as {fits[0]} it is "
                    f"{ro * get_unit_system(fits[0]).density:.4g} kg/m^3: a card in another unit system? "
                    f"(part {pid}'s mass follows it)"
                )
                notes.append(msg)
                warnings.warn(f"{main.name}: {msg}", UserWarning, stacklevel=3)
            continue
        e_raw = raw.values["e"]
        if raw.kind not in _WAVE_SPEED_KINDS or not (ro > 0 and e_raw > 0):
            continue
        c = float(wave_speed(ro, e_raw, u))
        lo, hi = CARD_WAVE_SPEED_WINDOW
        if not lo <= c <= hi:  # E in another unit system than the deck's
            msg = (
                f"material {mid} ({_mat_label(raw)}) ({raw.where[0].name} line {raw.where[1]}): RO {ro:g} and E "
                f"{e_raw:g} as {u.name} give a wave speed sqrt(E/RO) of {c:.4g} m/s, outside the {lo:g} to {hi:g} "
                "m/s of metals and structural polymers: "
                f"E in another unit system than the deck's {u.name}? (part {pid}'s stiffness follows it; a soft "
                "foam or rubber may lie below)"
            )
            notes.append(msg)
            warnings.warn(f"{main.name}: {msg}", UserWarning, stacklevel=3)
    # ---- nodes
    coords = np.concatenate(t.coords) * u.length
    order = np.argsort(node_ids, kind="stable")
    sorted_ids = node_ids[order]

    def node_index(ids: np.ndarray, locs: _Locs, kind: str, eids: np.ndarray) -> np.ndarray:
        idx, found = _lookup(sorted_ids, order, ids)
        if not found.all():
            row = int(np.flatnonzero(~found.all(axis=1))[0])
            missing = int(ids[row][~found[row]][0])
            raise DeckError(f"{kind} element {int(eids[row])} refers to undefined node {missing}", *locs.where(row))
        return idx

    # ---- parts, sections, materials
    materials: dict[int, Material] = {}
    es_known = [m.values["e"] * u.stress for m in judged if m.values["e"] > 0]
    for mid, raw in t.materials.items():
        try:
            materials[mid] = _complete_raw(raw, u, t, es_known, notes if mid in used else [], used.get(mid))
        except DeckError as err:
            if mid in used:
                raise
            why = raw.note if raw.densityless else err.reason
            notes.append(f"material {mid} ({_mat_label(raw)}) left out: no part the reader keeps uses it, and it "
                         f"cannot be read ({why})")  # fmt: skip
    parts: dict[int, Part] = {}
    for pid, (title, secid, mid, where) in t.parts.items():
        if secid not in t.sections and secid in t.unread_sections:
            kw, path, line = t.unread_sections[secid]
            raise DeckError(f"*PART {pid} refers to section {secid}, a *{kw} ({path.name} line {line}) that the reader "
                            "does not read; its shell, solid or beam elements need a *SECTION_SHELL, *SECTION_SOLID "
                            "or *SECTION_BEAM", *where)  # fmt: skip
        if secid not in t.sections:
            raise DeckError(f"*PART {pid} refers to undefined section {secid}", *where)
        if mid not in materials:
            raise DeckError(f"*PART {pid} refers to undefined material {mid}", *where)
        sec = t.sections[secid]
        thick = sec.value * u.length if sec.kind == "shell" and sec.value is not None else None
        area = sec.value * u.area if sec.kind == "beam" and sec.value is not None else None
        parts[pid] = Part(pid, title, mid, secid, thick, area)
    part_keys = np.array(sorted(parts), dtype=np.int64)
    sec_kind = np.array([t.section_of(parts[p]).kind for p in part_keys.tolist()], dtype=object)

    def part_checks(kind: str, elems: _Elements, ids: np.ndarray, pid: np.ndarray) -> np.ndarray:
        _check_duplicates(ids, elems.locs, f"{kind} element")
        pos, found = _lookup(part_keys, np.arange(part_keys.size), pid)
        if not found.all():
            row = int(np.flatnonzero(~found)[0])
            p = int(pid[row])
            if p in t.unread_parts:  # defined by a card the reader skips: "undefined" would send the user looking
                kw, path, line = t.unread_parts[p]
                why = f"a *{kw} ({path.name} line {line}) that the reader does not read; expected a *PART"
                raise DeckError(f"{kind} element {int(ids[row])} refers to part {p}, {why}", *elems.locs.where(row))
            raise DeckError(f"{kind} element {int(ids[row])} refers to undefined part {p}", *elems.locs.where(row))
        wrong = np.flatnonzero(sec_kind[pos] != kind) if pos.size else np.zeros(0, int)
        if wrong.size:
            row = int(wrong[0])
            part = parts[int(pid[row])]
            raise DeckError(
                f"{kind} element {int(ids[row])} is in part {part.id} whose section {part.section_id} is a "
                f"*SECTION_{sec_kind[pos[row]].upper()}, expected a *SECTION_{kind.upper()}",
                *elems.locs.where(row),
            )
        return pos

    # shells
    s_ids, s_part, s_nid, s_t = t.shells.cat((4,))
    pos = part_checks("shell", t.shells, s_ids, s_part)
    s_nodes = node_index(s_nid, t.shells.locs, "shell", s_ids)
    sec_t = np.array([(parts[p].thickness or 0.0) / u.length for p in part_keys.tolist()])
    tsec = sec_t[pos] if pos.size else np.zeros(0)
    tt = np.where(s_t > 0, s_t, tsec[:, None])
    tri = s_nid[:, 3] == s_nid[:, 2]
    s_thick = np.where(tri, tt[:, :3].mean(axis=1), tt.mean(axis=1)) * u.length
    zero = np.flatnonzero(s_thick <= 0)
    if zero.size:  # mass and section lost without a word to the screen (only the summary's notes said it)
        zp = np.unique(s_part[zero]).tolist()
        at, line = t.shells.locs.where(int(zero[0]))
        msg = (
            f"{zero.size} shells in parts {zp[:10]}{' ...' if len(zp) > 10 else ''} have neither element nor section "
            f"thickness (*SECTION_SHELL T1 of their part, or thickness on the element card), the first {at.name} "
            f"line {line}: they get no mass and no section"
        )
        notes.append(msg)
        warnings.warn(f"{main.name}: {msg}", UserWarning, stacklevel=3)
    # solids
    v_ids, v_part, v_nid, _ = t.solids.cat(())
    part_checks("solid", t.solids, v_ids, v_part)
    v_nodes = node_index(v_nid, t.solids.locs, "solid", v_ids)
    # beams
    b_ids, b_part, b_nid, b_parm = t.beams.cat((5,))
    pos = part_checks("beam", t.beams, b_ids, b_part)
    b_nodes = node_index(b_nid, t.beams.locs, "beam", b_ids)
    b_area = np.zeros(b_ids.size)
    if b_ids.size:
        sec_area = np.array([(parts[p].beam_area or np.nan) / u.area for p in part_keys.tolist()])
        b_area = sec_area[pos]
        has = ~np.isnan(b_parm[:, :4]).any(axis=1)
        for row in np.flatnonzero(has).tolist():  # element-level sections are rare: a loop is fine
            sec = t.section_of(parts[int(b_part[row])])
            a = _beam_area(sec.elform, sec.cst, *b_parm[row, :4].tolist())
            if a is not None:
                b_area[row] = a
        typed = ~np.isnan(b_parm[:, 4])
        b_area[typed] = b_parm[typed, 4]
        if t.unread_stypes:
            listing = ", ".join(f"{k} x{n}" for k, n in sorted(t.unread_stypes.items()))
            notes.append(f"*ELEMENT_BEAM_SECTION types the reader computes no area for ({listing}; it does SECTION_08, "
                         "_09, _11): those beams take their part's *SECTION_BEAM area")  # fmt: skip
        missing = np.isnan(b_area)
        if missing.any():
            notes.append(f"{int(missing.sum())} beams have no cross-section area the reader can compute: area 0")
            b_area[missing] = 0.0
        b_area = b_area * u.area
    if s_ids.size + v_ids.size + b_ids.size == 0:
        raise DeckError("the deck has no *ELEMENT_SHELL, *ELEMENT_SOLID or *ELEMENT_BEAM data", main)
    model = VehicleModel(
        node_ids=node_ids,
        coords=coords,
        shell_ids=s_ids,
        shell_part=s_part,
        shell_nodes=s_nodes,
        shell_thickness=s_thick,
        solid_ids=v_ids,
        solid_part=v_part,
        solid_nodes=v_nodes,
        beam_ids=b_ids,
        beam_part=b_part,
        beam_nodes=b_nodes,
        beam_area=b_area,
        parts=parts,
        materials=materials,
        subassemblies={},
        name=deck.title or main.stem,
        units=u.name,
        skipped_cards=dict(sorted(deck.skipped.items())),
        warnings=notes,
        left_out=dict(t.dropped),
    )
    return model, notes


def _element_sizes(coords: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Largest bounding-box side of each element ``nodes [E, k]`` [m], in chunks (full-vehicle decks)."""
    out = np.empty(len(nodes))
    for a in range(0, len(nodes), _CHUNK):
        c = coords[nodes[a : a + _CHUNK]]
        out[a : a + _CHUNK] = (c.max(axis=1) - c.min(axis=1)).max(axis=1)
    return out


def _check_extent(model: VehicleModel, t: _Tables) -> list[str]:
    """Refuse a structure larger than a vehicle; note elements far larger than the rest of their part, and shells
    thicker than :data:`THICK_SHELL` and than they are wide.

    A coordinate typo (``1.5e12`` for ``1500.``) makes the elements on that node huge, and their mass with
    them: the car weighed 8e10 kg without a word. Runs on the parts kept (a ground plane may be large).
    """
    used = np.unique(np.concatenate([model.used_nodes(), model.point_mass_nodes]))
    xyz = model.coords[used]
    where = t.node_locs.where  # node index = row of the deck's node table (without_parts keeps the nodes)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        i = int(used[bad[0]])
        raise DeckError(
            f"node {int(model.node_ids[i])} has a non-finite coordinate {model.coords[i].tolist()}", *where(i)
        )
    centre = np.median(xyz, axis=0)
    span = xyz.max(axis=0) - xyz.min(axis=0)
    if span.max() > MAX_VEHICLE_EXTENT:
        k = int(np.argmax(np.abs(xyz - centre).max(axis=1)))
        i = int(used[k])
        x, y, z = model.coords[i].tolist()
        raise DeckError(
            f"the structure spans {span.max():.4g} m, more than any vehicle ({MAX_VEHICLE_EXTENT:g} m); node "
            f"{int(model.node_ids[i])} at ({x:.4g}, {y:.4g}, {z:.4g}) m lies {np.linalg.norm(xyz[k] - centre):.4g} m "
            f"from the median node: a coordinate typo, or the wrong unit system (read as {model.units}; --units)",
            *where(i),
        )
    notes = []
    sizes: dict[str, np.ndarray] = {}
    for kind, nodes in (("shell", model.shell_nodes), ("solid", model.solid_nodes), ("beam", model.beam_nodes)):
        if not len(nodes):
            continue
        part = getattr(model, f"{kind}_part")
        size = sizes[kind] = _element_sizes(model.coords, nodes)
        order = np.lexsort((size, part))
        pids, first, count = np.unique(part[order], return_index=True, return_counts=True)
        median = size[order][first + (count - 1) // 2]  # lower median per part
        ref = median[np.searchsorted(pids, part)]
        out = np.flatnonzero((size > OUTLIER_MIN_SIZE) & (size > OUTLIER_SIZE_RATIO * ref))
        if not out.size:
            continue
        e = int(out[np.argmax(size[out] / np.maximum(ref[out], 1e-12))])
        own = nodes[e]
        i = int(own[np.argmax(np.linalg.norm(model.coords[own] - centre, axis=1))])
        path, line = where(i)
        notes.append(
            f"{out.size} {kind} element(s) are over {OUTLIER_SIZE_RATIO:g}x their part's median size: {kind} "
            f"{int(getattr(model, f'{kind}_ids')[e])} of part {int(part[e])} spans {size[e]:.3g} m (the part's "
            f"median {ref[e]:.3g} m); its node {int(model.node_ids[i])} ({path.name} line {line}) may have a "
            f"coordinate typo, which also inflates the elements' mass"
        )
    if "shell" in sizes:  # the same mass error from a thickness typo: a 2 m thick shell on a 0.1 m plate
        thick = model.shell_thickness
        out = np.flatnonzero((thick > THICK_SHELL) & (thick > sizes["shell"]))
        if out.size:
            e = int(out[np.argmax(thick[out])])
            pids = np.unique(model.shell_part[out])
            notes.append(
                f"{out.size} shell element(s) of part(s) {pids[:8].tolist()}{' ...' if pids.size > 8 else ''} are "
                f"thicker than {THICK_SHELL * 1e3:g} mm and than they are wide: shell {int(model.shell_ids[e])} of "
                f"part {int(model.shell_part[e])} is {thick[e] * 1e3:.4g} mm thick; a thickness typo (its section's "
                f"T1-T4 or the element's card), which inflates the part's mass in proportion"
            )
    return notes


def _deck_masses(model: VehicleModel, t: _Tables) -> VehicleModel:
    """The model with the masses the deck adds to its elements and nodes (SI), each checked against the model.

    ``*PART_INERTIA`` TM sets a rigid part's whole mass (:attr:`VehicleModel.part_mass`; MAREA, NSM and
    ``*ELEMENT_MASS_PART`` do not add to it, a note says so); ``*SECTION_SHELL`` MAREA, ``*SECTION_BEAM`` NSM
    (per length; not for discrete beams) and ``*ELEMENT_MASS_PART``
    (``_SET``) add non-structural mass, FINMASS what brings the part (the set) to that total
    (:attr:`VehicleModel.part_added_mass`); ``*ELEMENT_MASS`` puts masses on nodes, ``_NODE_SET`` shares one
    equally among the set's nodes (:attr:`VehicleModel.point_mass`).
    """
    if not (
        t.point_masses or t.part_masses or t.inertia or t.nodal_bodies or any(s.marea for s in t.sections.values())
    ):
        return model
    u = get_unit_system(model.units)
    notes: list[str] = []
    part_mass: dict[int, float] = {}
    bodies: list[_MassBody] = []  # masses on extra nodes and nodal rigid bodies
    counts = _element_counts(model) if t.inertia else {}
    for pid, (tm, where) in t.inertia.items():
        if pid not in model.parts:
            continue
        at = f"{where[0].name} line {where[1]}"
        if not model.materials[model.parts[pid].material_id].is_rigid:
            notes.append(f"{at}: *PART_INERTIA of part {pid} ignored: LS-DYNA reads it for rigid parts only")
            continue
        if not counts.get(pid):
            if pid in t.extra_nodes:  # a rigid body of extra nodes only: TM shared by them
                what = f"*CONSTRAINED_EXTRA_NODES of part {pid}"
                bodies.append(_MassBody(pid, t.extra_nodes[pid], tm * u.mass, what, replaces=False))
            else:
                notes.append(
                    f"{at}: *PART_INERTIA part {pid} has neither elements nor *CONSTRAINED_EXTRA_NODES to place its "
                    f"{tm * u.mass:.4g} kg: not counted"
                )
            continue
        part_mass[pid] = tm * u.mass
    model = replace(model, part_mass=part_mass)
    measures = model.element_measures()
    part_measure = {k: model.sum_by_part({k: measures[k]}) for k in ("shell", "beam")}  # area, length per part
    added: dict[int, float] = {}
    for pid, part in model.parts.items():
        sec = None if part.section_id is None else t.sections.get(part.section_id)
        if sec is None or sec.marea <= 0 or sec.kind == "solid":
            continue
        field = "MAREA" if sec.kind == "shell" else "NSM"
        if pid in part_mass:
            notes.append(f"part {pid}: {field} of section {part.section_id} not added: *PART_INERTIA sets its whole "
                         "mass")  # fmt: skip
        elif sec.kind == "beam" and sec.elform == 6:
            notes.append(f"part {pid}: NSM of section {part.section_id} not added: LS-DYNA ignores it for discrete "
                         "beams (ELFORM 6)")  # fmt: skip
        elif part_measure[sec.kind][pid] > 0:
            per = u.area if sec.kind == "shell" else u.length
            added[pid] = sec.marea * u.mass / per * part_measure[sec.kind][pid]
    if t.part_masses:
        own = replace(model, part_added_mass=dict(added)).part_masses()  # structural + MAREA so far
        measure = model.sum_by_part(model.element_measures())
        for pm in t.part_masses:
            card = f"*ELEMENT_MASS_PART{'_SET' if pm.on_set else ''} {pm.target}"
            if pm.on_set:
                if pm.target not in t.sets:
                    raise DeckError(f"*ELEMENT_MASS_PART_SET refers to undefined part set {pm.target}", *pm.where)
                pids = list(dict.fromkeys(t.sets[pm.target][1]))
                undefined = [p for p in pids if p not in t.parts and p not in t.dropped]
                if undefined:
                    raise DeckError(
                        f"*SET_PART {pm.target} of *ELEMENT_MASS_PART_SET lists undefined part {undefined[0]}",
                        *pm.where,
                    )
            else:
                if pm.target not in t.parts and pm.target not in t.dropped:
                    raise DeckError(f"*ELEMENT_MASS_PART refers to undefined part {pm.target}", *pm.where)
                pids = [pm.target]
            gone = [p for p in pids if p in t.dropped]
            if gone:  # springs, belts: not modelled, and their mass with them
                notes.append(f"{pm.where[0].name} line {pm.where[1]}: {card} adds nothing to part(s) {gone}: "
                             "left out (no elements the reader reads)")  # fmt: skip
                pids = [p for p in pids if p not in t.dropped]
                if not pids:
                    continue
            inertia = [p for p in pids if p in part_mass]
            if inertia:
                notes.append(
                    f"{pm.where[0].name} line {pm.where[1]}: {card} adds nothing to part(s) {inertia}: "
                    "*PART_INERTIA sets their whole mass"
                )
                pids = [p for p in pids if p not in part_mass]
                if not pids:
                    continue
            pids = [p for p in pids if measure.get(p, 0.0) > 0]
            if not pids:
                raise DeckError(f"{card} has no element to carry its mass", *pm.where)
            current = sum(own[p] for p in pids)
            add = pm.addmass * u.mass
            if pm.finmass > 0:  # FINMASS wins over ADDMASS
                add = pm.finmass * u.mass - current
                if add < -1e-9 * current:
                    raise DeckError(
                        f"{card} asks for a final mass FINMASS of {pm.finmass * u.mass:.4g} kg, below the "
                        f"{current:.4g} kg its part(s) have already",
                        *pm.where,
                    )
                add = max(add, 0.0)
            # by area (volume, length) as LS-DYNA spreads it; by mass across parts of different element kinds
            kinds = {t.section_of(model.parts[p]).kind for p in pids}  # a part's elements are its section's
            by_measure = len(kinds) == 1 or current <= 0
            weight = {p: measure[p] if by_measure else own[p] for p in pids}
            wsum = sum(weight.values())
            for p in pids:
                added[p] = added.get(p, 0.0) + add * weight[p] / wsum
                own[p] += add * weight[p] / wsum
    model = replace(model, part_added_mass={p: m for p, m in added.items() if m > 0})
    for nb in t.nodal_bodies:
        if nb.tm > 0:
            what = f"*CONSTRAINED_NODAL_RIGID_BODY {nb.pid}"
            bodies.append(_MassBody(nb.pid, [(nb.nsid, True, nb.where)], nb.tm * u.mass, what, replaces=True))
        else:
            notes.append(
                f"{nb.where[0].name} line {nb.where[1]}: *CONSTRAINED_NODAL_RIGID_BODY_INERTIA {nb.pid} gives no mass "
                "TM: its nodes keep their own"
            )
    if t.point_masses or bodies:
        model = _point_masses(model, t, bodies, u.mass, notes)
    model.warnings.extend(notes)
    return model


def _point_masses(
    model: VehicleModel,
    t: _Tables,
    bodies: list[_MassBody],
    to_kg: float,
    notes: list[str],
) -> VehicleModel:
    """The model with its point masses: ``*ELEMENT_MASS`` (``_NODE_SET``: one mass shared equally by the set's
    nodes) and ``*ELEMENT_INERTIA`` on nodes; each of ``bodies`` shares its mass equally among its nodes. A nodal
    rigid body's TM is its whole mass (``replaces``): lumped masses on its nodes are replaced by it (a note names
    them)."""
    order = np.argsort(model.node_ids, kind="stable")
    sorted_ids = model.node_ids[order]

    def nodes_of(nids: np.ndarray, what: str, where: tuple[Path, int]) -> np.ndarray:
        idx, found = _lookup(sorted_ids, order, nids)
        if not found.all():
            raise DeckError(f"{what} undefined node {int(nids[~found][0])}", *where)
        return idx

    def set_nodes(sid: int, what: str, where: tuple[Path, int]) -> np.ndarray:
        if sid not in t.node_sets or not len(t.node_sets[sid][1]):
            kind = "undefined" if sid not in t.node_sets else "empty"
            raise DeckError(f"{what} refers to {kind} node set {sid}", *where)
        members = np.unique(np.asarray(t.node_sets[sid][1], dtype=np.int64))
        return nodes_of(members, f"node set {sid} of {what} lists", where)

    ids, nodes, mass = [], [], []
    for pm in t.point_masses:
        if pm.on_sets:
            cards = zip(pm.ids.tolist(), pm.nids.tolist(), pm.mass.tolist(), strict=True)
            for k, (eid, sid, m) in enumerate(cards):
                idx = set_nodes(sid, f"*{pm.keyword} {eid}", (pm.src.path, int(pm.rows[k]) + 1))
                ids.append(np.full(idx.size, eid, dtype=np.int64))
                nodes.append(idx)
                mass.append(np.full(idx.size, m * to_kg / idx.size))
        else:
            idx, found = _lookup(sorted_ids, order, pm.nids)
            if not found.all():
                k = int(np.flatnonzero(~found)[0])
                raise DeckError(
                    f"*{pm.keyword} {int(pm.ids[k])} refers to undefined node {int(pm.nids[k])}",
                    pm.src.path,
                    int(pm.rows[k]) + 1,
                )
            ids.append(pm.ids)
            nodes.append(idx)
            mass.append(pm.mass * to_kg)
    n_lumped = sum(a.size for a in ids)
    replaced = np.zeros(model.n_nodes, dtype=bool)
    for body in bodies:
        idx = np.unique(
            np.concatenate(
                [
                    set_nodes(i, body.what, where)
                    if is_set
                    else nodes_of(np.array([i]), f"{body.what} refers to", where)
                    for i, is_set, where in body.members
                ]
            )
        )
        ids.append(np.full(idx.size, body.id, dtype=np.int64))
        nodes.append(idx)
        mass.append(np.full(idx.size, body.mass / idx.size))
        replaced[idx] |= body.replaces
    ids_a, nodes_a, mass_a = (np.concatenate(x) for x in (ids, nodes, mass))
    drop = np.zeros(ids_a.size, dtype=bool)
    drop[:n_lumped] = replaced[nodes_a[:n_lumped]]
    if drop.any():
        notes.append(
            f"{int(drop.sum())} lumped mass(es) ({mass_a[drop].sum():.4g} kg; element(s) "
            f"{sorted(set(ids_a[drop].astype(np.int64).tolist()))[:5]}) sit on nodes of a "
            "*CONSTRAINED_NODAL_RIGID_BODY_INERTIA: replaced by its TM, as LS-DYNA does"
        )
    keep = ~drop
    return replace(
        model,
        point_mass_ids=ids_a[keep].astype(np.int64),
        point_mass_nodes=nodes_a[keep].astype(np.int64),
        point_mass=mass_a[keep].astype(np.float64),
    )


# *MAT_RIGID CMO = +1: CON1 is the global translational constraint code
_CON1_AXES = {0: "", 1: "x", 2: "y", 3: "z", 4: "xy", 5: "yz", 6: "zx", 7: "xyz"}


def _refuse_weightless_parts(model: VehicleModel, t: _Tables) -> None:
    """Refuse, at its *MAT card, a material of density RO 0 that a kept part with elements uses when no
    ``*PART_INERTIA`` TM sets that part's mass (:meth:`VehicleModel.weightless_parts`; ``validate`` says the same of
    a model made in Python, without the card)."""
    for pid, n in model.weightless_parts()[:1]:
        part = model.parts[pid]
        raw = t.materials[part.material_id]
        raise DeckError(
            f"material {raw.mid} ({_mat_label(raw)}) has density RO 0, yet part {pid} ({part.name!r}, "
            f"{n} elements) uses it: its elements would weigh nothing; expected RO > 0 (a rigid part's "
            "mass may come from *PART_INERTIA TM)",
            *raw.where,
        )


def _element_counts(model: VehicleModel) -> dict[int, int]:
    """Part id -> number of elements (shells, solids and beams)."""
    pids, n = np.unique(np.concatenate([model.shell_part, model.solid_part, model.beam_part]), return_counts=True)
    return dict(zip(pids.tolist(), n.tolist(), strict=True))


def _fixed_parts(model: VehicleModel, t: _Tables, axis_map: AxisMap) -> tuple[dict[int, str], list[str]]:
    """Parts a ``*MAT_RIGID`` holds in place along the direction of travel: part id -> why; and notes.

    A rigid body whose translation along the deck axis that becomes marlcrash's x (the
    direction of travel) is constrained cannot move with the vehicle: it is a barrier, an
    impactor's backing or a fixture, not vehicle structure (the LS-OPT small car's rigid block
    in front of its bumper is one). ``CMO = +1`` reads ``CON1`` as global translational
    constraints; ``CMO = -1`` reads the first three digits of the local SPC code ``CON2``, which
    decides only when all three translations are held (the local system is not read). Rigid
    parts merged by ``*CONSTRAINED_RIGID_BODIES`` move as one body under the master's constraints.
    """
    travel = "xyz"[int(np.abs(axis_map.matrix()[0]).argmax())]
    rigid = {pid for pid, p in model.parts.items() if t.materials[p.material_id].kind == "rigid"}
    notes: list[str] = []
    for pm, ps, (path, line) in t.rigid_merges:  # LS-DYNA refuses these; the pair was dropped without a word
        bad = [
            f"{role} {pid} is {'not a part of the deck' if pid not in t.parts else 'not rigid (no *MAT_RIGID)'}"
            for role, pid in (("PIDM", pm), ("PIDS", ps))
            if pid not in rigid and pid not in t.dropped
        ]
        if bad:
            msg = f"*CONSTRAINED_RIGID_BODIES ({path.name} line {line}): {' and '.join(bad)}; the pair is not merged"
            notes.append(msg)
            warnings.warn(f"{path.name}: {msg}", UserWarning, stacklevel=4)
    if not rigid:
        return {}, notes

    def held(pid: int) -> tuple[str, str]:
        """(deck axes held, how) of a rigid part's own material."""
        raw = t.materials[model.parts[pid].material_id]
        cmo, con1, con2 = (raw.values.get(k, 0.0) for k in ("cmo", "con1", "con2"))
        at = f"*MAT_RIGID {raw.mid} ({raw.where[0].name} line {raw.where[1]})"
        if cmo == 1.0:
            if con1 in _CON1_AXES:
                axes = _CON1_AXES[int(con1)]
                return axes, f"{at}, CMO=1, CON1={int(con1)}: held in deck {axes or 'no axis'}"
            notes.append(f"part {pid}: {at} has CON1 = {con1:g}, expected 0-7 with CMO = 1; read as unconstrained")
        elif cmo == -1.0:
            if not (0 <= con2 < 1e6 and con2 == int(con2)):
                notes.append(
                    f"part {pid}: {at} has CON2 = {con2:g}, expected a 6-digit SPC code with CMO = -1; "
                    "read as unconstrained"
                )
                return "", ""
            code = f"{int(con2):06d}"
            if code[:3] == "111":
                return "xyz", f"{at}, CMO=-1, CON2={code}: held in every translation"
            if code[:3].strip("0"):
                notes.append(
                    f"part {pid}: {at} is held in local system {con1:g} (CMO=-1, CON2={code}); the reader does "
                    "not follow local systems, so it stays vehicle structure"
                )
        elif cmo != 0.0:
            notes.append(f"part {pid}: {at} has CMO = {cmo:g}, expected -1, 0 or 1; read as unconstrained")
        return "", ""

    master = {s: m for m, s, _ in t.rigid_merges if m in rigid and s in rigid and m != s}

    def root(pid: int) -> int:
        seen = {pid}
        while pid in master and master[pid] not in seen:
            pid = master[pid]
            seen.add(pid)
        return pid

    own = {pid: held(pid) for pid in sorted({root(p) for p in rigid})}
    masses: dict[int, float] | None = None  # computed once a part is fixed
    counts: dict[int, int] = {}
    fixed: dict[int, str] = {}
    for pid in sorted(rigid):
        top = root(pid)
        axes, how = own[top]
        if travel not in axes:
            continue
        if masses is None:
            masses, counts = model.part_masses(), _element_counts(model)
        via = "" if top == pid else f"merged into rigid part {top} by *CONSTRAINED_RIGID_BODIES, whose "
        fixed[pid] = (
            f"part {pid} ({model.parts[pid].name!r}): {via}{how} does not move along deck {travel}, the direction "
            f"of travel: a barrier or fixture, not vehicle structure; left out of the vehicle "
            f"({counts.get(pid, 0)} elements, {masses.get(pid, 0.0):.1f} kg)"
        )
    return fixed, notes


def _stationary_parts(model: VehicleModel, t: _Tables, skip: set[int]) -> tuple[dict[int, str], list[str]]:
    """Parts none of whose nodes the deck's initial-velocity cards set moving, while others move.

    A part at rest when the rest of the model starts at the impact speed is a barrier (a
    deformable honeycomb, its backing) or a fixture, not vehicle structure. Nothing is
    decided when the deck sets nothing moving, or when a card refers to something the
    reader cannot resolve (a box, an undefined or unread set): a note says so.
    """
    if not t.velocities:
        return {}, []
    order = np.argsort(model.node_ids, kind="stable")
    sorted_ids = model.node_ids[order]

    def node_index(ids) -> np.ndarray:
        idx, found = _lookup(sorted_ids, order, np.asarray(ids, dtype=np.int64))
        return idx[found]

    elems = [
        (model.shell_part, model.shell_nodes),
        (model.solid_part, model.solid_nodes),
        (model.beam_part, model.beam_nodes),
    ]

    def part_nodes(pids) -> np.ndarray:
        return np.concatenate([nodes[np.isin(part, pids)].ravel() for part, nodes in elems])

    moving = np.zeros(model.n_nodes, dtype=bool)
    for v in t.velocities:
        if v.target == "nodes":
            moving[node_index(v.ids[v.moving])] = True
            continue
        if not v.moving[0] and not v.except_moving:
            continue
        sid = int(v.ids[0])
        unresolved = (
            v.target in ("box", "unknown")
            or (v.target == "node_set" and sid not in t.node_sets)
            or (v.target == "part_set" and sid not in t.sets)
            or (v.except_set and v.except_set not in t.node_sets)
        )
        if unresolved:
            what = {"box": "a *DEFINE_BOX", "unknown": "an unknown set type"}.get(v.target, "a set the reader lacks")
            return {}, [
                f"{v.where[0].name} line {v.where[1]}: an initial velocity refers to {what}; parts at rest "
                "(a barrier) are not detected from initial velocities"
            ]
        if v.target == "all":
            sel = np.arange(model.n_nodes)
        elif v.target == "node_set":
            sel = node_index(t.node_sets[sid][1])
        else:
            sel = part_nodes(t.sets[sid][1] if v.target == "part_set" else [sid])
        if v.except_set:
            exempt = np.zeros(model.n_nodes, dtype=bool)
            exempt[node_index(t.node_sets[v.except_set][1])] = True
            moving[sel[exempt[sel]]] |= v.except_moving
            sel = sel[~exempt[sel]]
        moving[sel] |= bool(v.moving[0])
    if not moving.any():
        return {}, []
    moved = set()
    for elem_part, nodes in elems:
        moved.update(np.unique(elem_part[moving[nodes].any(axis=1)]).tolist())
    counts = _element_counts(model)
    rest = [pid for pid in sorted(model.parts) if pid not in moved and pid not in skip and counts.get(pid)]
    if not rest:
        return {}, []
    masses = model.part_masses()
    out = {}
    for pid in rest:
        part = model.parts[pid]
        out[pid] = (
            f"part {pid} ({part.name!r}): the deck's initial velocities set none of its nodes moving while "
            f"{int(moving.sum())} nodes move: a barrier or fixture at rest, not vehicle structure; left out of the "
            f"vehicle ({counts[pid]} elements, {masses.get(pid, 0.0):.1f} kg)"
        )
    return out, []


def _travel_note(t: _Tables, axis_map: AxisMap) -> list[str]:
    """A note where every initial velocity the deck gives moves along one axis and direction other than
    marlcrash's -x (the vehicle travels front first towards -x; its front is taken at the smallest x).

    Nothing is said where the deck sets nothing moving, or moves things along several axes or directions (two
    vehicles, a moving barrier). Where it sets something moving in a local coordinate system (ICID), which the
    reader does not evaluate, a note says that the direction is not checked.
    """
    given = [v for v in t.velocities if v.target != "nodes" or v.moving.any()]
    local = [(v.local, v.where[0]) for v in given if v.local is not None and (v.moving.any() or v.except_moving)]
    if local:
        (icid, line), path = local[0]
        return [
            f"{path.name} line {line}: an initial velocity is given in the local coordinate system ICID {icid}; "
            "the reader takes initial velocities in the deck's global axes only, so the direction of travel is not "
            "checked against the axis map: make sure the vehicle moves front first along marlcrash -x (x rearward)"
        ]
    if not given or any(v.vel is None for v in given):
        return []
    vel = np.concatenate([v.vel[v.moving] if v.target == "nodes" else v.vel for v in given if v.vel is not None])
    vel = vel[np.abs(vel).max(axis=1) > 0]
    if vel.size == 0:
        return []
    axis = np.abs(vel).argmax(axis=1)
    sign = np.sign(vel[np.arange(len(vel)), axis])
    if np.unique(axis).size > 1 or np.unique(sign).size > 1:
        return []
    a, s = int(axis[0]), float(sign[0])
    r = axis_map.matrix()
    mapped = r @ (s * np.eye(3)[a])
    if mapped[0] < 0:
        return []
    deck_dir = f"{'+' if s > 0 else '-'}{'xyz'[a]}"
    m_axis = int(np.abs(mapped).argmax())
    m_dir = f"{'+' if mapped[m_axis] > 0 else '-'}{'xyz'[m_axis]}"
    # a map with x the deck's -travel, of the given map's handedness
    spec = {k: (int(np.abs(row).argmax()), float(row[np.abs(row).argmax()])) for k, row in zip("xyz", r, strict=True)}
    new = dict(spec, x=(a, -s))
    if spec["x"][0] == a:  # x held the travel's axis, the wrong way round: turn half about z (y flips with x)
        new["y"] = (spec["y"][0], -spec["y"][1])
    else:  # the axis that held the travel's takes x's old one, signed to keep the map's handedness
        other = "y" if spec["y"][0] == a else "z"
        new[other] = (spec["x"][0], 1.0)
        if np.linalg.det(np.array([np.eye(3)[ax] * sg for ax, sg in new.values()])) * np.linalg.det(r) < 0:
            new[other] = (spec["x"][0], -1.0)
    text = ",".join(f"{k}={'+' if sg > 0 else '-'}{'xyz'[ax]}" for k, (ax, sg) in new.items())
    path, line = given[0].where
    return [
        f"{path.name} line {line}: the deck's initial velocities move the vehicle along deck {deck_dir}, marlcrash "
        f"{m_dir} under the axis map x={axis_map.x},y={axis_map.y},z={axis_map.z}; marlcrash's vehicle travels "
        "front first along -x (x rearward) and its front is taken at the smallest x, so its region of interest would "
        f"lie at the far end from the impact: give --axis-map {text} (axis_map= in Python), and check that the "
        "driver's left lands at +y"
    ]


# keywords that join nodes (merge them, tie them, weld them), which the reader does not follow
_JOINING = (
    "NODE_MERGE",
    "CONSTRAINED_NODE_SET",
    "CONSTRAINED_SPOTWELD",
    "CONSTRAINED_GENERALIZED_WELD",
    "CONSTRAINED_RIVET",
    "CONSTRAINED_TIED_NODES_FAILURE",
    "CONSTRAINED_LINEAR",
    "CONSTRAINED_INTERPOLATION",
    "CONSTRAINED_SHELL_TO_SOLID",
)


def _unfollowed_joints(deck: _Deck) -> list[str]:
    """One note per keyword of :data:`_JOINING` in the deck, naming its first file and line and its count."""
    first: dict[str, tuple[_Block, int]] = {}
    for b in deck.blocks:
        if any(b.keyword == j or b.keyword.startswith(j + "_") for j in _JOINING):
            at, n = first.get(b.keyword, (b, 0))
            first[b.keyword] = (at, n + 1)
    return [
        f"*{kw} ({b.src.path.name} line {b.lineno(b.line)}{f', {n} blocks in all' if n > 1 else ''}) is not "
        "followed: the nodes it joins stay separate in the model (the cells, built from the elements' geometry, do "
        "not depend on it; a part tied to the moving structure only by these joints is judged on its own nodes "
        "where parts at rest are left out)"
        for kw, (b, n) in first.items()
    ]


def deck_files(path: str | Path, params: dict[str, float] | None = None) -> list[Path]:
    """The files a deck consists of: ``path`` and every file it pulls in with ``*INCLUDE`` (nested), resolved.

    What a run's record hashes (:mod:`marlcrash.provenance`): real vehicle models are mostly includes.

    Raises:
        DeckError: the deck or an included file cannot be read or split into keyword blocks.
    """
    return list(dict.fromkeys(_scanned(Path(path), params).files))


def _scanned(main: Path, params: dict[str, float] | None) -> _Deck:
    """The deck's keyword blocks, parameters and files, ``*INCLUDE``s followed (standard format to start)."""
    deck = _Deck(params=_Params(params))
    _scan(main, deck, "std", (main.resolve(),), None)
    return deck


def read_deck(
    path: str | Path,
    *,
    params: dict[str, float] | None = None,
    units: str | None = None,
    axis_map: AxisMap | None = None,
    subassemblies: str | Path | dict[str, list[int]] | None = None,
    name: str | None = None,
) -> VehicleModel:
    """Read an LS-DYNA keyword deck into a validated :class:`VehicleModel` in SI units.

    Args:
        path: the main deck file; ``*INCLUDE`` paths are relative to the including file.
        params: values of parameters the deck uses (``&name``); they also override
            the deck's own ``*PARAMETER`` values.
        units: the deck's unit system, a name of :data:`marlcrash.units.UNIT_SYSTEMS` (``mm-t-s``,
            ``mm-kg-ms``, ``m-kg-s``, ``mm-g-ms``, ``cm-g-us``, ``in-lbf-s``); detected from material
            densities and moduli when ``None``.
        axis_map: how the deck's axes map onto marlcrash's (x rearward, y left, z up);
            identity when ``None``. The model is always shifted so its front is at
            x = 0 and its lateral centre at y = 0 (:meth:`VehicleModel.transformed`).
        subassemblies: a sub-assembly YAML file (see
            :mod:`marlcrash.vehicle.subassembly_map`) or a mapping name -> part ids or
            part-name globs; parts it leaves out become their own ``part_<id>``.
            ``None``: every part is its own sub-assembly.
        name: the model's name; default the deck's ``*TITLE`` or the file stem.

    Returns:
        The model: ``coords [N, 3]`` in metres, ``shell_nodes [S, 4]``, ``solid_nodes
        [V, 8]``, ``beam_nodes [B, 2]`` as node indices, thicknesses [m], areas [m^2],
        complete materials; ``skipped_cards`` counts the cards not interpreted.

    Raises:
        DeckError: the deck is malformed or inconsistent (file and line named).
        ConfigError: unknown ``units`` name, bad ``axis_map`` or sub-assembly map.
    """
    from marlcrash.vehicle.subassembly_map import load_subassembly_map, resolve_subassemblies

    main = Path(path)
    deck = _scanned(main, params)
    deck.params.finish()
    tables = _Tables()
    for block in deck.blocks:
        _dispatch(block, tables, deck)
    if tables.table_open is not None:
        raise _table_unfinished(tables, tables.table_open, "the end of the deck")
    stray = sorted(set(deck.params.user) - deck.params.deck_names - deck.params.used)
    if stray:  # most likely a misspelt name, whose intended parameter then keeps the deck's value
        known = sorted(deck.params.deck_names | deck.params.used)
        raise DeckError(
            f"parameter(s) {', '.join(map(repr, stray))} given (--param, params=) but the deck neither defines nor "
            f"uses them; its parameters: {', '.join(known) if known else 'none'}",
            main,
        )
    try:
        model, _ = _assemble(deck, tables, units, main)
    except DeckError as e:
        if deck.unread_includes and "undefined" in e.reason:  # the id may well be defined in the unread file
            raise DeckError(f"{e.reason}; note: {deck.unread_includes[0]}", e.path, e.line) from None
        raise
    _resolve_sets(tables, model.node_ids)
    model = _deck_masses(model, tables)
    if name is not None:
        model.name = name
    axis_map = axis_map if axis_map is not None else AxisMap()
    fixed, notes = _fixed_parts(model, tables, axis_map)
    at_rest, more = _stationary_parts(model, tables, skip=set(fixed))
    fixed.update(at_rest)
    model.warnings.extend(notes + more)
    if fixed:
        model = model.without_parts(fixed)
        if model.n_shells + model.n_solids + model.n_beams == 0:
            raise DeckError(f"no vehicle structure is left: {'; '.join(fixed.values())}", main)
        for why in fixed.values():
            warnings.warn(f"{main.name}: {why}", UserWarning, stacklevel=2)
    _refuse_weightless_parts(model, tables)  # the vehicle's: a barrier left out may weigh nothing
    try:
        model.validate()
    except ModelError as e:
        raise DeckError(str(e), main) from None
    for note in [
        *deck.unread_includes,
        *_unfollowed_joints(deck),
        *_check_extent(model, tables),
        *_travel_note(tables, axis_map),
    ]:
        model.warnings.append(note)
        warnings.warn(f"{main.name}: {note}", UserWarning, stacklevel=2)
    model = model.transformed(axis_map)
    sets = {sid: (title, ids) for sid, (title, ids) in tables.sets.items()}
    if subassemblies is not None:
        if isinstance(subassemblies, dict):
            mapping = resolve_subassemblies(subassemblies, model, part_sets=sets)
        else:
            mapping = load_subassembly_map(subassemblies, model, part_sets=sets)
        model = model.with_subassemblies(mapping)
    model = model.with_default_subassemblies()
    if deck.skipped:
        total = sum(deck.skipped.values())
        listing = ", ".join(f"*{k} x{n}" for k, n in sorted(deck.skipped.items()))
        msg = f"{main.name}: skipped {total} card(s) the reader does not interpret: {listing}"
        model.warnings.append(msg)
        warnings.warn(msg, UserWarning, stacklevel=2)
    return model
