"""Write a :class:`VehicleModel` as a fixed-format LS-DYNA keyword deck (DESIGN 3).

The deck holds ``*NODE`` (16-character coordinates, 10 significant digits),
``*ELEMENT_SHELL_THICKNESS`` (element thickness on every shell), ``*ELEMENT_SOLID``,
``*ELEMENT_BEAM_THICKNESS`` (element area as PARM1 of a resultant beam),
``*PART``, ``*SECTION_SHELL/SOLID/BEAM`` (one card per section id: parts that share an id and whose section values
agree share its card, as LS-DYNA lets them; a part whose values differ from those of the first part with its id gets
a fresh id, with a warning, and a part with no section id a fresh one), and materials by kind:
``elastic`` -> ``*MAT_ELASTIC``, ``plastic_kinematic`` -> ``*MAT_PLASTIC_KINEMATIC``,
``piecewise_linear`` -> ``*MAT_PIECEWISE_LINEAR_PLASTICITY``, ``rigid`` ->
``*MAT_RIGID`` (``other`` is written as ``*MAT_ELASTIC``). Sections and materials use
per-keyword long format (``+``, 20-character fields) so their values survive a round
trip to 13 significant digits; ``*PART`` does where an id needs more than its 10 columns, and
``*NODE``, ``*ELEMENT_*`` and ``*ELEMENT_MASS`` where one needs more than 8 or a value a
3-digit exponent (1e100 or more in the deck's units). A
``<stem>.subassemblies.yaml`` beside the deck holds the sub-assemblies.
:func:`marlcrash.vehicle.keyword.read_deck` reads the pair back to the same model. Added
masses go as the reader takes them: a rigid part's set structural mass as ``*PART_INERTIA``
(its inertia tensor that of its elements as lumped masses), non-structural mass as
``*ELEMENT_MASS_PART`` ADDMASS, point masses as ``*ELEMENT_MASS`` (renumbered from 1 where
ids repeat, as a node set's share does, or one is not positive). Every other id must be positive, as LS-DYNA
wants: :func:`write_deck` refuses a model with one that is not.

What the cards cannot carry: strengths of elastic and rigid materials (the reader
re-derives them with :func:`complete_material`), a fracture strength different from
the ultimate one for ``plastic_kinematic``, shear and bulk moduli inconsistent with
E and nu, a set mass (:attr:`VehicleModel.part_mass`) of a deformable part or a zero one
(``*PART_INERTIA`` TM is read for rigid parts only, and must be positive), and names that do not fit their title
line: ``*TITLE`` and a material's title are one line of 80 columns, a part's heading one of 70 (LS-DYNA reads
no more; the deck is UTF-8, and a column is a byte), so a longer name is cut to its field and a line break in one
becomes a space, and an element thickness or beam area of 0 in a part whose section value is not 0 (LS-DYNA gives
such an element its section's). The writer warns
(:class:`UserWarning`) when a model holds such values, naming each and what it reads back as.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np

from marlcrash.errors import ModelError
from marlcrash.outputs import atomic_output
from marlcrash.units import get_unit_system
from marlcrash.vehicle.materials import MATERIAL_FIELDS, Material, complete_material
from marlcrash.vehicle.model import VehicleModel
from marlcrash.vehicle.subassembly_map import dump_subassembly_map

__all__ = ["write_deck"]

# Plastic strain at which MAT_003/MAT_024 cards place the ultimate strength, and at
# which MAT_024 places the fracture strength: the model's 8-vector has strengths,
# not strains, so the writer picks typical values for car-body steels.
STRAIN_AT_ULTIMATE = 0.2
STRAIN_AT_FRACTURE = 0.3
_ROWS = 100_000  # rows formatted per write call


def _f20(x: float) -> str:
    return f"{x:20.12e}"


def _title(name: str, what: str, cannot: list[str], width: int = 80) -> str:
    """A title line: one line of ``width`` columns, bytes of its UTF-8 (80 for ``*TITLE`` and a material's title,
    70 for a part's heading: LS-DYNA reads no more). One that would begin with ``$`` (a comment) or ``*`` (a keyword)
    is indented by a space: readers strip titles, so it reads back as written. A name that does not read back whole
    (longer than the field, with a line break, or with blanks around it) is noted in ``cannot`` as ``what``, with
    what it reads back as."""
    text = name.replace("\r", " ").replace("\n", " ")
    line = " " + text if text.startswith(("$", "*")) else text
    cut = line.encode("utf-8")[:width].decode("utf-8", "ignore")  # columns are bytes; no character split
    back = cut.strip()
    if back != name:
        how = [f"is cut to its {width} columns"] if len(line.rstrip().encode("utf-8")) > width else []
        if text != name:
            how.insert(0, "is written on one line")
        cannot.append(f"{what} {name!r} {' and '.join(how) or 'loses the blanks around it'}: it reads back as {back!r}")
    return cut


def _card(values: Iterable[float | int]) -> str:
    """One long-format card: integers (Python or numpy) as integer fields, everything else as a float."""
    out = []
    for v in values:
        out.append(f"{int(v):20d}" if isinstance(v, int | np.integer) else _f20(float(v)))
    return "".join(out) + "\n"


def _write_rows(f, fmt: str, *cols: np.ndarray) -> None:
    n = len(cols[0]) if cols else 0
    for a in range(0, n, _ROWS):
        rows = zip(*(c[a : a + _ROWS].tolist() for c in cols), strict=True)
        f.write("".join(fmt % r for r in rows))


def _id_format(max_id: int, *values: np.ndarray) -> tuple[str, int]:
    """Keyword suffix and id width for ids up to ``max_id``: long format (``+``, 20 columns) where an id needs more
    than 8 columns or one of ``values`` more than the 16 of a fixed-format real (a 3-digit exponent,
    ``-1.000000000e+100``: :func:`_tidy` leaves none below 1e-99)."""
    wide = any(v.size and float(np.abs(v).max()) >= 1e100 for v in values)
    return ("", 8) if max_id < 10**8 and not wide else ("+", 20)


def _material_cards(m: Material, u, cannot: list[str]) -> tuple[str, list[str]]:
    """Keyword text of one material and the 8-vector entries it cannot carry (a title it cannot carry whole goes
    to ``cannot``)."""
    ro, e, nu = m.density / u.density, m.youngs_modulus / u.stress, m.poisson_ratio
    sy, su, sf = (m.yield_strength / u.stress, m.ultimate_strength / u.stress, m.fracture_strength / u.stress)
    title = _title(m.name, f"material {m.id}: its title", cannot)
    kind = m.kind
    rebuilt = Material(m.id, m.name, kind, m.density, m.youngs_modulus, poisson_ratio=nu)
    if kind in ("elastic", "other"):
        text = f"*MAT_ELASTIC_TITLE+\n{title}\n" + _card([m.id, ro, e, nu])
    elif kind == "rigid":
        text = f"*MAT_RIGID_TITLE+\n{title}\n" + _card([m.id, ro, e, nu]) + _card([1.0, 0, 0]) + "\n"
    elif kind == "plastic_kinematic":
        eh = (su - sy) / STRAIN_AT_ULTIMATE
        etan = e * eh / (e + eh)
        text = (
            f"*MAT_PLASTIC_KINEMATIC_TITLE+\n{title}\n"
            + _card([m.id, ro, e, nu, sy, etan, 0.0])
            + _card([0.0, 0.0, STRAIN_AT_ULTIMATE, 0.0])
        )
        rebuilt = Material(
            m.id,
            m.name,
            kind,
            m.density,
            m.youngs_modulus,
            yield_strength=m.yield_strength,
            ultimate_strength=sy * u.stress + etan * e / (e - etan) * STRAIN_AT_ULTIMATE * u.stress,
            fracture_strength=math.nan,
            poisson_ratio=nu,
        )
        rebuilt = replace(rebuilt, fracture_strength=rebuilt.ultimate_strength)
    elif kind == "piecewise_linear":
        eps, es = [0.0, STRAIN_AT_ULTIMATE], [sy, su]
        fail = 0.0
        if sf != su:
            eps.append(STRAIN_AT_FRACTURE)
            es.append(sf)
            fail = STRAIN_AT_FRACTURE
        text = (
            f"*MAT_PIECEWISE_LINEAR_PLASTICITY_TITLE+\n{title}\n"
            + _card([m.id, ro, e, nu, sy, 0.0, fail, 0.0])
            + _card([0.0, 0.0, 0, 0, 0.0])
            + _card(eps + [0.0] * (8 - len(eps)))
            + _card(es + [0.0] * (8 - len(es)))
        )
        rebuilt = Material(
            m.id,
            m.name,
            kind,
            m.density,
            m.youngs_modulus,
            yield_strength=m.yield_strength,
            ultimate_strength=max(m.ultimate_strength, m.fracture_strength),
            fracture_strength=m.fracture_strength,
            poisson_ratio=nu,
        )
    else:
        raise ModelError(f"material {m.id}: unknown kind {kind!r}")
    if not np.isfinite(m.vector()).all():
        raise ModelError(
            f"material {m.id} ({m.name}): incomplete 8-vector {m.vector().tolist()}; use complete_material"
        )
    back = complete_material(rebuilt).vector()
    lost = [
        name
        for name, a, b in zip(MATERIAL_FIELDS, m.vector(), back, strict=True)
        if not math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)
    ]
    if kind == "other":
        lost.append("kind (written as elastic)")
    return text, lost


def _part_kinds(model: VehicleModel) -> dict[int, str]:
    kinds: dict[int, str] = {}
    for kind, parts in (("shell", model.shell_part), ("solid", model.solid_part), ("beam", model.beam_part)):
        for pid in np.unique(parts).tolist():
            if pid in kinds and kinds[pid] != kind:
                raise ModelError(f"{model.name}: part {pid} holds both {kinds[pid]} and {kind} elements")
            kinds[int(pid)] = kind
    return kinds


def _check_ids(model: VehicleModel, kinds: dict[int, str]) -> None:
    """Refuse an id LS-DYNA does not take (every id of a keyword deck is a positive integer), and a part's section
    value it cannot read (a shell part's thickness, a beam part's area: finite and >= 0)."""
    for what, keyword, ids in (
        ("node", "*NODE", model.node_ids),
        ("shell", "*ELEMENT_SHELL_THICKNESS", model.shell_ids),
        ("solid", "*ELEMENT_SOLID", model.solid_ids),
        ("beam", "*ELEMENT_BEAM_THICKNESS", model.beam_ids),
        ("part", "*PART", list(model.parts)),
        ("material", "*MAT", list(model.materials)),
    ):
        a = np.asarray(ids, dtype=np.int64)
        if a.size and a.min() <= 0:
            bad = int(a[a <= 0][0])
            raise ModelError(f"{model.name}: {what} id {bad} is not positive ({keyword} takes ids from 1)")
    for pid, p in model.parts.items():
        kind = kinds.get(pid, "shell")
        if p.section_id is not None and p.section_id <= 0:
            raise ModelError(
                f"{model.name}: part {pid}'s section id {p.section_id} is not positive "
                f"(*SECTION_{kind.upper()} takes ids from 1)"
            )
        checks = {"shell": ("thickness", p.thickness, "m", "T1..T4"), "beam": ("beam area", p.beam_area, "m^2", "A")}
        if kind in checks:
            what, value, unit, field = checks[kind]
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ModelError(
                    f"{model.name}: part {pid}'s {what} {value} {unit} is not finite and >= 0 "
                    f"(*SECTION_{kind.upper()} {field})"
                )


def write_deck(model: VehicleModel, path: str | Path, *, units: str = "mm-t-s", subassembly_yaml: bool = True) -> Path:
    """Write ``model`` as a fixed-format keyword deck in ``units``.

    Args:
        model: a valid model (SI units).
        path: the deck file to write (written atomically, :func:`marlcrash.outputs.atomic_output`).
        units: unit system of the deck, a name of :data:`marlcrash.units.UNIT_SYSTEMS`.
        subassembly_yaml: also write ``<stem>.subassemblies.yaml`` beside the deck.

    Returns:
        The deck path.

    Raises:
        ModelError: the model is invalid, a part mixes element kinds, a material is
            incomplete, a node, element, part, section or material id is not positive, or a part's
            thickness or beam area is not finite and >= 0.
        ConfigError: unknown ``units``, or ``path`` cannot be written (its folder is missing or not writable).
    """
    u = get_unit_system(units)
    model.validate()
    path = Path(path)
    kinds = _part_kinds(model)
    _check_ids(model, kinds)
    lost: dict[int, list[str]] = {}
    cannot: list[str] = []  # what else the cards cannot carry
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as f:
        f.write(f"$ written by marlcrash from model {model.name!r}, units {u.name}\n*KEYWORD\n*TITLE\n")
        f.write((_title(model.name, "*TITLE", cannot) if model.name else "vehicle") + "\n")
        for mid in sorted(model.materials):
            text, miss = _material_cards(model.materials[mid], u, cannot)
            f.write(text)
            if miss:
                lost[mid] = miss
        written: dict[int, tuple[int, str]] = {}  # section id -> (first part, its section cards less the id)
        fresh = max([p.section_id or 0 for p in model.parts.values()] + list(model.parts) + [0]) + 1
        for pid in sorted(model.parts):
            p = model.parts[pid]
            kind = kinds.get(pid, "shell")
            section = _section_cards(model, pid, kind, u, cannot)
            secid = p.section_id
            if secid is not None and secid in written and written[secid][1] != section(0):
                cannot.append(f"part {pid}: its section {secid} (shared with part {written[secid][0]}, whose section "
                              f"values differ) is written as section {fresh}")  # fmt: skip
                secid = None
            if secid is None:
                secid, fresh = fresh, fresh + 1
            heading = _title(p.name, f"part {pid}: its heading", cannot, width=70)
            inertia = pid in model.part_mass and _inertia_carries(model, pid, cannot)
            if inertia:
                f.write(f"*PART_INERTIA+\n{heading}\n" + _card([pid, secid, p.material_id]))
                f.write(_inertia_cards(model, pid, u))
            elif max(pid, secid, p.material_id) < 10**10:
                f.write(f"*PART\n{heading}\n{pid:10d}{secid:10d}{p.material_id:10d}\n")
            else:  # an id too wide for the card's 10 columns
                f.write(f"*PART+\n{heading}\n" + _card([pid, secid, p.material_id]))
            if secid not in written:  # parts whose section values agree share the card, as LS-DYNA lets them
                written[secid] = (pid, section(0))
                f.write(section(secid))
        _write_geometry(f, model, u)
        _write_masses(f, model, u)
        f.write("*END\n")
    if subassembly_yaml:
        dump_subassembly_map(model.subassemblies, path.with_name(path.stem + ".subassemblies.yaml"))
    if lost or cannot:
        listing = "; ".join([f"material {mid}: {', '.join(v)}" for mid, v in sorted(lost.items())] + cannot)
        warnings.warn(f"{path.name}: the keyword cards cannot carry {listing}", UserWarning, stacklevel=2)
    return path


def _section_cards(model: VehicleModel, pid: int, kind: str, u, cannot: list[str]):
    """``secid -> text`` of part ``pid``'s ``*SECTION_SHELL/SOLID/BEAM`` (long format) with section id ``secid``.

    An element thickness or area of 0 reads back as its section's value (LS-DYNA's rule), so a part whose elements
    include such ones is noted in ``cannot`` where its section value is not 0; a beam part without an area of its own
    gets section area 0 then (else the median of its elements', a section LS-DYNA can run)."""
    p = model.parts[pid]
    if kind == "shell":
        t = (p.thickness or 0.0) / u.length
        _note_zero_elements(model.shell_thickness[model.shell_part == pid], t, pid, "shells", "thickness", cannot)
        return lambda secid: "*SECTION_SHELL+\n" + _card([secid, 2, 1.0, 2, 0.0]) + _card([t, t, t, t])
    if kind == "solid":
        return lambda secid: "*SECTION_SOLID+\n" + _card([secid, 1])
    areas = model.beam_area[model.beam_part == pid]
    a = p.beam_area if p.beam_area else 0.0 if (areas <= 0).any() or not areas.size else float(np.median(areas))
    a /= u.area
    _note_zero_elements(areas, a, pid, "beams", "area", cannot)
    i = a * a / (4 * math.pi)  # solid circular section of that area
    return lambda secid: "*SECTION_BEAM+\n" + _card([secid, 2, 1.0, 2.0, 0.0]) + _card([a, i, i, 2 * i])


def _note_zero_elements(values: np.ndarray, section: float, pid: int, what: str, name: str, cannot: list[str]) -> None:
    """Note in ``cannot`` the elements of part ``pid`` whose ``name`` is 0 under a section value that is not."""
    zero = int((values <= 0).sum())
    if zero and section > 0:
        cannot.append(f"part {pid}: {zero} {what} of {name} 0 (read back, they take the section's {section:.4g} in the "
                      "deck's units, as LS-DYNA gives an element without its own)")  # fmt: skip


def _write_geometry(f, model: VehicleModel, u) -> None:
    ids = model.node_ids
    c = _tidy(model.coords / u.length)
    sfx, w = _id_format(int(ids.max()) if ids.size else 0, c)
    cw = 20 if sfx else 16
    f.write(f"*NODE{sfx}\n")
    _write_rows(f, f"%{w}d%{cw}.9e%{cw}.9e%{cw}.9e\n", ids, c[:, 0], c[:, 1], c[:, 2])
    nid = model.node_ids
    if model.n_shells:
        n = nid[model.shell_nodes]
        t = _tidy(model.shell_thickness / u.length)
        sfx, w = _id_format(max(int(n.max()), int(model.shell_ids.max()), int(model.shell_part.max())), t)
        tw = 20 if sfx else 16
        f.write(f"*ELEMENT_SHELL_THICKNESS{sfx}\n")
        fmt = f"%{w}d" * 6 + "\n" + f"%{tw}.9e" * 4 + "\n"
        _write_rows(f, fmt, model.shell_ids, model.shell_part, n[:, 0], n[:, 1], n[:, 2], n[:, 3], t, t, t, t)
    if model.n_solids:
        n = nid[model.solid_nodes]
        sfx, w = _id_format(max(int(n.max()), int(model.solid_ids.max()), int(model.solid_part.max())))
        f.write(f"*ELEMENT_SOLID{sfx}\n")
        _write_rows(f, f"%{w}d" * 10 + "\n", model.solid_ids, model.solid_part, *(n[:, k] for k in range(8)))
    if model.n_beams:
        n = nid[model.beam_nodes]
        a = _tidy(model.beam_area / u.area)
        i = _tidy(a * a / (4 * math.pi))
        sfx, w = _id_format(max(int(n.max()), int(model.beam_ids.max()), int(model.beam_part.max())), a, 2 * i)
        tw = 20 if sfx else 16
        f.write(f"*ELEMENT_BEAM_THICKNESS{sfx}\n")
        fmt = f"%{w}d" * 4 + "\n" + f"%{tw}.9e" * 4 + "\n"
        _write_rows(f, fmt, model.beam_ids, model.beam_part, n[:, 0], n[:, 1], a, i, i, 2 * i)


def _inertia_carries(model: VehicleModel, pid: int, cannot: list[str]) -> bool:
    """Whether ``*PART_INERTIA`` carries part ``pid``'s set mass: LS-DYNA (and the reader) take its TM for rigid parts
    only, and only a positive one. Otherwise the part is written as ``*PART`` and the mass noted in ``cannot``."""
    mass = model.part_mass[pid]
    rigid = model.materials[model.parts[pid].material_id].is_rigid
    if rigid and mass > 0:
        return True
    why = "*PART_INERTIA sets the mass of rigid parts only" if not rigid else "*PART_INERTIA needs a mass TM > 0"
    cannot.append(f"part {pid}: its set mass {mass:.4g} kg ({why}; read back, the part weighs density x volume)")
    return False


def _inertia_cards(model: VehicleModel, pid: int, u) -> str:
    """The three ``*PART_INERTIA`` cards of part ``pid`` (long format): its mass centre and set mass, the
    inertia tensor of its elements as lumped masses about that centre, zero initial velocity."""
    em = model.element_masses()
    pts, ms = [], []
    for kind in ("shell", "solid", "beam"):
        sel = getattr(model, f"{kind}_part") == pid
        pts.append(model.coords[getattr(model, f"{kind}_nodes")[sel]].mean(axis=1))
        ms.append(em[kind][sel])
    p, m = np.concatenate(pts), np.concatenate(ms)
    c = (m[:, None] * p).sum(axis=0) / m.sum()
    d = p - c
    r2 = (d**2).sum(axis=1)
    j = (m[:, None, None] * (r2[:, None, None] * np.eye(3) - d[:, :, None] * d[:, None, :])).sum(axis=0)
    j /= u.mass * u.length**2
    c = c / u.length
    return (
        _card([c[0], c[1], c[2], model.part_mass[pid] / u.mass, 0, 0])
        + _card([j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]])
        + _card([0.0] * 6)
    )


def _write_masses(f, model: VehicleModel, u) -> None:
    if model.part_added_mass:
        f.write("*ELEMENT_MASS_PART+\n")
        for pid, mass in sorted(model.part_added_mass.items()):
            f.write(_card([pid, mass / u.mass, 0.0]))
    if model.point_mass.size:
        ids = model.point_mass_ids
        if np.unique(ids).size < ids.size or ids.min() <= 0:
            ids = np.arange(1, ids.size + 1)
        nid = model.node_ids[model.point_mass_nodes]
        pm = _tidy(model.point_mass / u.mass)
        sfx, w = _id_format(max(int(ids.max()), int(nid.max())), pm)
        f.write(f"*ELEMENT_MASS{sfx}\n")
        mw = 20 if sfx else 16
        _write_rows(f, f"%{w}d%{w}d%{mw}.9e%{w}d\n", ids, nid, pm, np.zeros_like(ids))


def _tidy(x: np.ndarray) -> np.ndarray:
    """Flush magnitudes below 1e-99 to 0 so every value fits its field with a 2-digit exponent."""
    return np.where(np.abs(x) < 1e-99, 0.0, x)
