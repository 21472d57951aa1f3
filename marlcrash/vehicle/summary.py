"""A readable and a JSON summary of a vehicle model (what ``marlcrash inspect`` prints)."""

from __future__ import annotations

import numpy as np

from marlcrash.vehicle.model import VehicleModel


def vehicle_summary(model: VehicleModel) -> dict:
    """Counts, per-part data, sub-assemblies and skipped cards of a model.

    Returns:
        A JSON-serialisable dict with ``n_nodes`` (every node of the source), ``n_nodes_used`` (those the
        vehicle's elements use: a left-out barrier's nodes stay in the model unused), ``n_shells``, ``n_solids``,
        ``n_beams``, ``n_parts``, ``parts`` (part id as string -> mass [kg]), ``part_details`` (id -> name,
        material, thickness [mm], element counts, mass), ``subassemblies`` (name -> part ids),
        ``total_mass_kg`` (point masses included), ``added_mass_kg`` (non-structural mass on parts),
        ``point_mass_kg`` and ``n_point_masses`` (lumped masses on nodes), ``skipped_cards``, ``units``,
        ``bounds_m``, ``warnings``, ``left_out`` (part id as string -> why it is not vehicle structure, e.g. a
        fixed barrier in the deck).
    """
    masses = model.part_masses()
    details = {}
    for pid, part in sorted(model.parts.items()):
        mat = model.materials[part.material_id]
        thick = model.shell_thickness[model.shell_part == pid]
        details[str(pid)] = {
            "name": part.name,
            "material_id": part.material_id,
            "material": mat.name,
            "material_kind": mat.kind,
            "density_kg_m3": mat.density,
            "thickness_mm": float(np.mean(thick) * 1e3) if thick.size else None,
            "n_shells": int((model.shell_part == pid).sum()),
            "n_solids": int((model.solid_part == pid).sum()),
            "n_beams": int((model.beam_part == pid).sum()),
            "mass_kg": masses.get(pid, 0.0),
            "added_mass_kg": model.part_added_mass.get(pid, 0.0),
        }
    try:
        bounds = model.bounds().tolist()
    except ValueError:
        bounds = None
    return {
        "name": model.name,
        "units": model.units,
        "n_nodes": model.n_nodes,
        "n_nodes_used": int(model.used_nodes().size),
        "n_shells": model.n_shells,
        "n_solids": model.n_solids,
        "n_beams": model.n_beams,
        "n_parts": len(model.parts),
        "parts": {str(pid): masses.get(pid, 0.0) for pid in sorted(model.parts)},
        "part_details": details,
        "subassemblies": {k: list(v) for k, v in model.subassemblies.items()},
        "total_mass_kg": float(sum(masses.values())) + float(model.point_mass.sum()),
        "added_mass_kg": float(sum(model.part_added_mass.values())),
        "point_mass_kg": float(model.point_mass.sum()),
        "n_point_masses": int(model.point_mass.size),
        "skipped_cards": dict(sorted(model.skipped_cards.items())),
        "bounds_m": bounds,
        "warnings": list(model.warnings),
        "left_out": {str(pid): why for pid, why in sorted(model.left_out.items())},
    }


def format_vehicle_summary(s: dict) -> str:
    """Render :func:`vehicle_summary` as a plain-text report."""
    lines = [
        f"model      {s['name']}  (deck units {s['units']}, shown in SI)",
        f"nodes      {s['n_nodes']}"
        + (f" ({s['n_nodes_used']} used by the vehicle's elements)" if s["n_nodes_used"] != s["n_nodes"] else ""),
        f"elements   {s['n_shells']} shells, {s['n_solids']} solids, {s['n_beams']} beams",
        f"total mass {s['total_mass_kg']:.3f} kg",
    ]
    if s["added_mass_kg"] or s["n_point_masses"]:
        lines.append(
            f"           of which {s['added_mass_kg']:.3f} kg non-structural on parts, "
            f"{s['point_mass_kg']:.3f} kg in {s['n_point_masses']} point mass(es) on nodes"
        )
    if s["bounds_m"] is not None:
        lo, hi = s["bounds_m"]
        ext = [h - l for l, h in zip(lo, hi, strict=True)]
        lines.append(f"extent     x {ext[0]:.3f} m, y {ext[1]:.3f} m, z {ext[2]:.3f} m")
    lines.append("")
    # names in full (two titles may differ only at their end), each column as wide as its longest entry
    details = s["part_details"]
    materials = {pid: f"{d['material']} ({d['material_kind']})" for pid, d in details.items()}
    wp = max([6, *(len(pid) for pid in details)])
    wn = max([28, *(len(d["name"]) for d in details.values())])
    wm = max([24, *(len(m) for m in materials.values())])
    lines.append(f"{'part':>{wp}}  {'name':<{wn}} {'material':<{wm}} {'t [mm]':>7} {'elements':>9} {'mass [kg]':>11}")
    for pid, d in details.items():
        t = "-" if d["thickness_mm"] is None else f"{d['thickness_mm']:.3g}"
        n = d["n_shells"] + d["n_solids"] + d["n_beams"]
        lines.append(f"{pid:>{wp}}  {d['name']:<{wn}} {materials[pid]:<{wm}} {t:>7} {n:>9} {d['mass_kg']:>11.3f}")
    lines.append("")
    lines.append("sub-assemblies")
    for name, pids in s["subassemblies"].items():
        lines.append(f"  {name:<28} parts {', '.join(str(p) for p in pids)}")
    if s["left_out"]:
        lines.append("")
        lines.append(f"left out of the vehicle ({len(s['left_out'])} part(s)):")
        lines.extend(f"  {why}" for why in s["left_out"].values())
    if s["skipped_cards"]:
        lines.append("")
        total = sum(s["skipped_cards"].values())
        lines.append(f"skipped cards ({total}): " + ", ".join(f"{k} x{v}" for k, v in s["skipped_cards"].items()))
    if s["warnings"]:
        lines.append("")
        lines.append(f"warnings ({len(s['warnings'])}):")
        lines.extend(f"  {w}" for w in s["warnings"][:20])
        if len(s["warnings"]) > 20:
            lines.append(f"  ... and {len(s['warnings']) - 20} more")
    return "\n".join(lines)
