"""Benchmark: discretize a 1e6-node / 1e6-shell front (dense grid of shell tubes).

The deck is built directly as a :class:`VehicleModel` in memory: square steel
tubes along x fill a 1.2 m deep, 1.6 m wide, 0.8 m high front in a regular
y-z lattice, grouped by lattice column into sub-assemblies, with a rigid
compartment box behind. Prints the times of the uniform and optimized
discretizations, their ratio and the cell counts, all measured in one run.

Usage: ``python benchmarks/bench_discretize.py [--shells 1000000]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from marlcrash.cells import discretize, load_discretization_config
from marlcrash.vehicle.materials import Material, complete_material
from marlcrash.vehicle.model import COMPARTMENT, Part, VehicleModel, empty_float, empty_int


def tube_lattice(
    n_shells: float = 1e6,
    depth: float = 1.3,
    width: float = 1.6,
    height: float = 0.8,
    pitch: float = 0.07,
    side: float = 0.05,
    n_groups: int = 12,
) -> VehicleModel:
    """A dense lattice of square shell tubes along x plus a rigid compartment box.

    Args:
        n_shells: approximate number of tube shells.
        depth: tube length along x [m] (tubes cross the ROI depth into the compartment).
        width, height: lattice extent in y and z [m].
        pitch: lattice spacing [m]; side: tube side [m].
        n_groups: number of sub-assemblies (lattice columns are dealt round-robin).

    Returns:
        The model (SI units, marlcrash axes).
    """
    ys = np.arange(-width / 2 + pitch / 2, width / 2, pitch)
    zs = np.arange(pitch / 2, height, pitch)
    yc, zc = (a.ravel() for a in np.meshgrid(ys, zs, indexing="ij"))
    n_tubes = yc.size
    per_tube = n_shells / n_tubes
    # per_tube = n_x * 4 m with element size s: n_x = depth / s, m = side / s
    s = np.sqrt(depth * 4 * side / per_tube)
    m = max(1, round(side / s))
    n_x = max(1, round(depth / s))
    t = np.arange(4 * m) / m  # perimeter parameter 0..4
    sidx, frac = np.floor(t).astype(int), t - np.floor(t)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * side / 2
    ring = corners[sidx] + frac[:, None] * (corners[sidx + 1] - corners[sidx])  # [4m, 2]
    xs = np.linspace(0.0, depth, n_x + 1)
    n_ring = 4 * m
    nodes = np.empty((n_tubes, n_x + 1, n_ring, 3))
    nodes[..., 0] = xs[None, :, None]
    nodes[..., 1] = yc[:, None, None] + ring[None, None, :, 0]
    nodes[..., 2] = zc[:, None, None] + ring[None, None, :, 1]
    base = (np.arange(n_tubes) * (n_x + 1) * n_ring)[:, None, None]
    i = np.arange(n_x)[None, :, None]
    j = np.arange(n_ring)[None, None, :]
    j1 = (j + 1) % n_ring
    quads = np.stack(
        [base + i * n_ring + j, base + (i + 1) * n_ring + j, base + (i + 1) * n_ring + j1, base + i * n_ring + j1],
        axis=-1,
    ).reshape(-1, 4)
    tube_of_shell = np.repeat(np.arange(n_tubes), n_x * n_ring)
    column = np.searchsorted(ys, yc - 1e-9)  # lattice column of each tube
    part_of_tube = 1 + column % n_groups
    coords = nodes.reshape(-1, 3)
    # rigid compartment: a closed box behind the ROI, 4 x 2 coarse quads per face pair
    lo, hi = np.array([depth, -width / 2, 0.0]), np.array([depth + 2.0, width / 2, height + 0.6])
    box = np.array([[lo[0], lo[1], lo[2]], [hi[0], lo[1], lo[2]], [hi[0], hi[1], lo[2]], [lo[0], hi[1], lo[2]]])
    box = np.concatenate([box, box + np.array([0, 0, hi[2] - lo[2]])])
    faces = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
    n0 = coords.shape[0]
    coords = np.concatenate([coords, box])
    quads = np.concatenate([quads, faces + n0])
    comp_part = n_groups + 1
    shell_part = np.concatenate([part_of_tube[tube_of_shell], np.full(6, comp_part)])
    steel = complete_material(Material(1, "dp600", "piecewise_linear", 7850.0, 210e9, yield_strength=4e8,
                                       ultimate_strength=6e8, poisson_ratio=0.3))  # fmt: skip
    rigid = complete_material(Material(2, "rigid", "rigid", 7850.0, 210e9, poisson_ratio=0.3))
    parts = {p: Part(p, f"tubes_{p}", 1, p, 1.5e-3) for p in range(1, n_groups + 1)}
    parts[comp_part] = Part(comp_part, COMPARTMENT, 2, comp_part, 0.08)
    thick = np.where(shell_part == comp_part, 0.08, 1.5e-3)
    subs = {f"tubes_{p}": [p] for p in range(1, n_groups + 1)}
    subs[COMPARTMENT] = [comp_part]
    n_sh = quads.shape[0]
    return VehicleModel(
        node_ids=np.arange(1, coords.shape[0] + 1),
        coords=coords,
        shell_ids=np.arange(1, n_sh + 1),
        shell_part=shell_part,
        shell_nodes=quads,
        shell_thickness=thick,
        solid_ids=empty_int(0),
        solid_part=empty_int(0),
        solid_nodes=empty_int(0, 8),
        beam_ids=empty_int(0),
        beam_part=empty_int(0),
        beam_nodes=empty_int(0, 2),
        beam_area=empty_float(0),
        parts=parts,
        materials={1: steel, 2: rigid},
        subassemblies=subs,
        name="tube_lattice",
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shells", type=float, default=1e6, help="approximate number of shells")
    args = ap.parse_args()
    t0 = time.perf_counter()
    model = tube_lattice(args.shells)
    t_build = time.perf_counter() - t0
    print(
        f"model: {model.n_nodes} nodes, {model.n_shells} shells, {model.total_mass():.1f} kg, built in {t_build:.2f} s"
    )
    cfg = load_discretization_config()
    for method in ("uniform", "optimized"):  # warm-up: the first call also paid for lazy imports (scipy, shapely)
        discretize(tube_lattice(2e4), cfg, method=method)
    times = {}
    cells = {}
    for method in ("uniform", "optimized"):
        t0 = time.perf_counter()
        cells[method] = discretize(model, cfg, method=method)
        times[method] = time.perf_counter() - t0
        c = cells[method]
        print(
            f"{method:9s}: {times[method]:6.2f} s, {c.n_cells} cells ({c.n_null} null), {c.n_links} links, "
            f"stages {c.meta['timings_s']}"
        )
    o, u = cells["optimized"], cells["uniform"]
    print(f"optimized / uniform time ratio: {times['optimized'] / times['uniform']:.2f}")
    print(f"optimized / uniform cell ratio: {o.n_cells / u.meta['n_cells_uniform']:.3f}")
    print(f"cell mass / ROI mass: {o.mass[:-1].sum() / o.roi_mass:.6f}")
    print(f"optimized discretization of {model.n_shells} shells: {times['optimized']:.2f} s (budget 60 s)")


if __name__ == "__main__":
    main()
