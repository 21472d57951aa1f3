"""Table-2-like summaries of a discretization (what ``marlcrash discretize`` prints)."""

from __future__ import annotations

import warnings

import numpy as np

from marlcrash.cells.discretize import DiscretizationConfig, discretize, load_discretization_config
from marlcrash.cells.model import CellModel
from marlcrash.vehicle.model import COMPARTMENT, VehicleModel


def summarize_cells(cells: CellModel, n_cells_optimized: int | None = None) -> dict:
    """Summary of one cell model.

    Args:
        cells: a discretized model (either method).
        n_cells_optimized: count of the optimized model, if ``cells`` is a uniform one.

    Returns:
        A JSON-serialisable dict: ``method``, ``n_cells`` (this model, all cells),
        ``roi_volume_mm3``, ``target_cell_volume_mm3``, ``n_cells_uniform`` (uniform grid
        blocks over the ROI, the paper's count; the uniform model splits a block shared by sub-assemblies, so its
        ``n_cells`` is larger with ``uniform_cells: per_subassembly``; ``None`` for a model the discretizer did not
        build, whose ``meta`` does not record it), ``n_cells_optimized`` (all cells of the
        optimized model: non-null, null, sensor and compartment), ``n_null_cells`` and ``n_sensor_cells``
        (this model), ``roi_mass_kg``, ``cell_mass_kg`` (cells without the compartment),
        ``compartment_mass_kg``, ``total_mass_kg``, ``n_subassemblies``, ``n_sensors``,
        ``n_links``, ``cells_per_subassembly`` (name -> count) and ``uniform_cells`` (a uniform model's
        ``uniform_cells`` setting, ``per_subassembly`` or ``per_block``; ``None`` for an optimized one).
    """
    comp = cells.compartment
    counts = {name: int((cells.subassembly == i).sum()) for i, name in enumerate(cells.subassembly_names)}
    non_comp = np.arange(cells.n_cells) != comp
    blocks = cells.meta.get("n_cells_uniform")  # the discretizer's grid: not in a model built by hand
    if cells.method == "optimized":
        n_cells_optimized = cells.n_cells
    return {
        "name": cells.name,
        "method": cells.method,
        "n_cells": cells.n_cells,
        "roi_volume_mm3": cells.roi_volume * 1e9,
        "target_cell_volume_mm3": cells.target_cell_volume * 1e9,
        "n_cells_uniform": None if blocks is None else int(blocks),
        "n_cells_optimized": n_cells_optimized,
        "n_null_cells": cells.n_null,
        "n_sensor_cells": int(cells.is_sensor.sum()),
        "roi_mass_kg": cells.roi_mass,
        "cell_mass_kg": float(cells.mass[non_comp].sum()),
        "compartment_mass_kg": float(cells.mass[comp]),
        "total_mass_kg": cells.total_mass,
        "n_subassemblies": len([n for n in cells.subassembly_names if n != COMPARTMENT]),
        "n_sensors": len(cells.sensor_names),
        "n_links": cells.n_links,
        "cells_per_subassembly": counts,
        "uniform_cells": None if cells.method == "optimized" else cells.meta.get("config", {}).get("uniform_cells"),
    }


def discretization_summary(
    model: VehicleModel, config: DiscretizationConfig | None = None, method: str | None = None
) -> tuple[dict, CellModel]:
    """Discretize ``model`` and summarise it.

    Args:
        model: vehicle in marlcrash axes.
        config: discretization config (default ``configs/cells.yaml``).
        method: ``uniform`` or ``optimized`` (default: the config's).

    Returns:
        ``(summary, cells)``: :func:`summarize_cells` of the chosen model (with the
        optimized count filled in for a uniform model too) and the cell model itself.
    """
    cfg = load_discretization_config() if config is None else config
    cells = discretize(model, cfg, method=method)
    n_opt = None
    if cells.method != "optimized":
        with warnings.catch_warnings():  # the model asked for has warned already; the other's count is all we need
            warnings.simplefilter("ignore")
            n_opt = discretize(model, cfg, method="optimized").n_cells
    return summarize_cells(cells, n_opt), cells


def format_discretization_summary(s: dict) -> str:
    """Render a summary as the paper's Table 2 plus cells per sub-assembly; a count not known is ``-``."""

    def count(n: int | None) -> str:
        return "-" if n is None else f"{n}"

    counts = [
        ("cells, uniform discretization (grid blocks)", count(s["n_cells_uniform"]), ""),
        ("cells, optimized discretization", count(s["n_cells_optimized"]), ""),
    ]
    if s["method"] != "optimized":
        counts.reverse()
        if s["n_cells"] != s["n_cells_uniform"]:  # this model's own count (the "of which" rows below are its)
            how = {  # per_block splits nothing: it differs from the blocks by the compartment alone
                "per_block": "one per block, plus the compartment",
                "per_subassembly": "blocks split by sub-assembly",
            }.get(s.get("uniform_cells", ""), "this model")
            counts.append((f"cells, uniform discretization ({how})", f"{s['n_cells']}", ""))
    rows = [
        ("model", s["name"], ""),
        ("method", s["method"], ""),
        ("ROI volume", f"{s['roi_volume_mm3']:.4g}", "mm^3"),
        ("threshold cell volume", f"{s['target_cell_volume_mm3']:.4g}", "mm^3"),
        *counts,  # the other discretization's count first: the "of which" rows below are this model's
        ("  of which null cells", f"{s['n_null_cells']}", ""),
        ("  of which sensor cells", f"{s['n_sensor_cells']}", ""),
        ("links", f"{s['n_links']}", ""),
        ("ROI element mass", f"{s['roi_mass_kg']:.3f}", "kg"),
        ("sum of cell masses", f"{s['cell_mass_kg']:.3f}", "kg"),
        ("rigid compartment mass", f"{s['compartment_mass_kg']:.3f}", "kg"),
        ("total mass", f"{s['total_mass_kg']:.3f}", "kg"),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"{name:<{width}}  {value:>12} {unit}".rstrip() for name, value, unit in rows]
    lines.append("")
    lines.append(f"cells per sub-assembly ({s['n_subassemblies']} sub-assemblies + compartment):")
    for name, n in s["cells_per_subassembly"].items():
        lines.append(f"  {name:<28} {n:>6}")
    return "\n".join(lines)
