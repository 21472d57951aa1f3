"""Hand-built CellModels for the surrogate's tests and benchmark.

:func:`grid_model` builds a regular block of ``nx * ny * nz`` cells in front of a
rigid compartment: +x links to the next cell rearward (the last layer to the
compartment), lateral +-y/+-z links between neighbours (each owned by its source
cell), optional null cells (with gap links jumping over them along x) and
optional random dropping of lateral links. Parameters follow a simple physical
sizing: crush force per column from a target deceleration, so pulses are of
realistic magnitude.
"""

from __future__ import annotations

import numpy as np

from marlcrash.cells.model import CellModel

STEEL = np.array([7850.0, 2.1e11, 8.08e10, 1.75e11, 3.0e8, 4.5e8, 4.0e8, 0.3])  # rho, Y, G, K, sy, su, sf, nu (SI)


def grid_model(
    nx: int,
    ny: int,
    nz: int,
    *,
    length: float = 1.2,
    width: float = 1.7,
    height: float = 0.6,
    roi_mass: float = 400.0,
    compartment_mass: float = 1200.0,
    column_force: float | None = None,
    ex_ratio: float = 0.05,
    f_x: float = 0.7,
    null_cells: tuple[tuple[int, int, int], ...] = (),
    lateral_keep: float = 1.0,
    sensors: tuple[tuple[str, tuple[int, int, int] | None], ...] = (("tunnel", None),),
    seed: int = 0,
    name: str = "grid",
) -> CellModel:
    """A block of cells ``[nx, ny, nz]`` (x rearward, y left, z up) plus the compartment.

    Args:
        nx, ny, nz: cells along x, y, z.
        length, width, height: block extent [m]; x from 0, y centred on 0, z from 0.
        roi_mass: total mass of the block cells [kg], split evenly.
        compartment_mass: rigid compartment mass [kg].
        column_force: crush force per (y, z) column [N]; default sizes the block so that the
            whole front crushes at about 25 g for the total mass.
        ex_ratio: ``E_x / E_s`` [-].
        f_x: share of the +x transmission factor where lateral neighbours exist [-].
        null_cells: grid positions ``(i, j, k)`` that are null (empty space).
        lateral_keep: probability of keeping each lateral neighbour pair [-].
        sensors: ``(name, (i, j, k))`` pairs; ``None`` puts the sensor on the compartment.
        seed: RNG seed for ``lateral_keep``.
        name: model name.
    """
    rng = np.random.default_rng(seed)
    n_grid = nx * ny * nz
    n = n_grid + 1
    comp = n_grid
    dx, dy, dz = length / nx, width / ny, height / nz
    gid = lambda i, j, k: (i * ny + j) * nz + k  # noqa: E731
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    ii, jj, kk = ii.ravel(), jj.ravel(), kk.ravel()
    lo = np.zeros((n, 3))
    hi = np.zeros((n, 3))
    lo[:n_grid] = np.stack([ii * dx, -width / 2 + jj * dy, kk * dz], axis=1)
    hi[:n_grid] = lo[:n_grid] + np.array([dx, dy, dz])
    lo[comp] = [length, -width / 2, 0.0]
    hi[comp] = [length + 2.0, width / 2, height]
    is_null = np.zeros(n, dtype=bool)
    for i, j, k in null_cells:
        is_null[gid(i, j, k)] = True
    is_rigid = np.zeros(n, dtype=bool)
    is_rigid[comp] = True
    n_mass = int((~is_null[:n_grid]).sum())
    mass = np.zeros(n)
    mass[:n_grid] = np.where(is_null[:n_grid], 0.0, roi_mass / n_mass)
    mass[comp] = compartment_mass
    total = roi_mass + compartment_mass
    if column_force is None:
        column_force = 25.0 * 9.80665 * total / (ny * nz)

    src, dst, ldir, gap, carea = [], [], [], [], []
    # +x links (and gap links over null cells); the last layer links to the compartment.
    for j in range(ny):
        for k in range(nz):
            i = 0
            while i < nx:
                a = gid(i, j, k)
                if is_null[a]:
                    i += 1
                    continue
                b_i = i + 1
                while b_i < nx and is_null[gid(b_i, j, k)]:
                    b_i += 1
                b = gid(b_i, j, k) if b_i < nx else comp
                src.append(a)
                dst.append(b)
                ldir.append(0)
                gap.append((b_i - i - 1) * dx)
                carea.append(dy * dz)
                i = b_i
    # lateral links, one per direction and neighbour pair
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                a = gid(i, j, k)
                if is_null[a]:
                    continue
                for d, (oj, ok) in ((1, (1, 0)), (3, (0, 1))):
                    j2, k2 = j + oj, k + ok
                    if j2 >= ny or k2 >= nz:
                        continue
                    b = gid(i, j2, k2)
                    if is_null[b] or rng.random() > lateral_keep:
                        continue
                    area = dx * (dz if d == 1 else dy)
                    src += [a, b]
                    dst += [b, a]
                    ldir += [d, d + 1]
                    gap += [0.0, 0.0]
                    carea += [area, area]
    src, dst, ldir = np.array(src, np.int64), np.array(dst, np.int64), np.array(ldir, np.int64)
    gap, carea = np.array(gap), np.array(carea)
    share = np.ones(len(src))  # one link per (src, direction) on a regular grid

    feasible = np.zeros((n, 5), dtype=bool)
    feasible[src, ldir] = True
    params = np.zeros((n, 7))
    lateral_total = feasible[:, 1:].sum(axis=1)
    fx = np.where(lateral_total > 0, f_x, 1.0) * feasible[:, 0]
    rest = 1.0 - fx
    params[:, 2] = fx
    params[:, 3:7] = np.where(
        lateral_total[:, None] > 0, rest[:, None] * feasible[:, 1:] / np.maximum(lateral_total, 1)[:, None], 0.0
    )
    crush_length = np.full(n, dx)
    crush_length[comp] = 0.0
    stroke = np.where(is_null | is_rigid, 0.0, 0.7 * crush_length)  # thin-walled cells: compaction 0.3
    e_s = column_force * 0.7 * dx / np.maximum(fx, 0.3)  # axial link then crushes at about column_force
    params[:, 0] = ex_ratio * e_s
    params[:, 1] = e_s
    params[is_null | is_rigid] = 0.0
    front = (ii == 0) & ~is_null[:n_grid]
    front_area = np.zeros(n)
    front_area[:n_grid] = np.where(front, dy * dz, 0.0)

    sub_names = ["right", "centre", "left"]
    subassembly = np.full(n, -1, dtype=np.int64)
    third = np.clip((jj * 3) // ny, 0, 2)
    subassembly[:n_grid] = np.where(is_null[:n_grid], -1, third)
    subassembly[comp] = 3
    sub_names.append("compartment")

    sensor_names, sensor_cell = [], []
    for s_name, pos in sensors:
        sensor_names.append(s_name)
        sensor_cell.append(comp if pos is None else gid(*pos))
    sensor_cell = np.array(sensor_cell, dtype=np.int64)
    is_sensor = np.zeros(n, dtype=bool)
    is_sensor[sensor_cell] = True
    centroid = 0.5 * (lo + hi)
    volume = np.prod(hi - lo, axis=1)
    material = np.where(is_null[:, None], 0.0, STEEL[None, :])
    edges = (
        np.linspace(0, length, nx + 1),
        np.linspace(-width / 2, width / 2, ny + 1),
        np.linspace(0, height, nz + 1),
    )
    labels = np.arange(n_grid).reshape(nx, ny, nz)
    labels = np.where(is_null[:n_grid].reshape(nx, ny, nz), -1, labels)
    cells = CellModel(
        lo=lo,
        hi=hi,
        centroid=centroid,
        volume=volume,
        mass=mass,
        material=material,
        params=params,
        feasible=feasible,
        subassembly=subassembly,
        is_null=is_null,
        is_sensor=is_sensor,
        is_rigid=is_rigid,
        front_area=front_area,
        crush_length=crush_length,
        stroke=stroke,
        link_src=src,
        link_dst=dst,
        link_dir=ldir,
        link_contact_area=carea,
        link_material_area=0.05 * carea,
        link_gap=gap,
        link_share=share,
        sensor_names=sensor_names,
        sensor_cell=sensor_cell,
        sensor_position=centroid[sensor_cell],
        subassembly_names=sub_names,
        method="uniform",
        target_cell_volume=dx * dy * dz,
        roi_depth=length,
        roi_lo=np.array([0.0, -width / 2, 0.0]),
        roi_hi=np.array([length, width / 2, height]),
        planes_y=np.array([0.0]),
        vehicle_width=width,
        roi_mass=roi_mass,
        total_mass=total,
        grid_edges=edges,
        grid_labels=labels,
        name=name,
    )
    cells.validate()
    return cells


def single_cell(
    mass: float = 10.0,
    compartment_mass: float = 1000.0,
    crush_force: float = 1e5,
    crush_length: float = 1.0,
    e_x: float = 1.0,
) -> CellModel:
    """One crushable cell in front of the compartment (the analytic case).

    The cell touches the wall; its +x link to the compartment crushes at ``crush_force``
    (``E_s = crush_force * stroke``, the stroke ``0.7 * crush_length`` of a thin-walled cell).
    """
    m = grid_model(
        1,
        1,
        1,
        length=crush_length,
        width=1.0,
        height=1.0,
        roi_mass=mass,
        compartment_mass=compartment_mass,
        column_force=crush_force,
        ex_ratio=1.0,
        name="single",
    )
    m.params[0, 0] = e_x
    m.params[0, 1] = crush_force * m.stroke[0]
    return m


def chain(n: int = 5) -> CellModel:
    """A 1D chain of ``n`` cells in front of the compartment, sensors front and rear."""
    return grid_model(
        n,
        1,
        1,
        width=0.3,
        height=0.3,
        roi_mass=60.0,
        compartment_mass=1000.0,
        sensors=(("front", (0, 0, 0)), ("tunnel", None)),
        name="chain",
    )


def block(f_x: float = 0.7) -> CellModel:
    """A 4 x 5 x 2 block with lateral links, one null cell (bridged by a gap link), three sensors.

    Width 1.0 m and 5 columns put the 40 % offset edge (y = 0.1 m) on a cell boundary.
    """
    return grid_model(
        4,
        5,
        2,
        length=0.8,
        width=1.0,
        height=0.4,
        roi_mass=120.0,
        compartment_mass=1100.0,
        null_cells=((1, 2, 0),),
        f_x=f_x,
        sensors=(("front_left", (0, 4, 1)), ("front_right", (0, 0, 1)), ("tunnel", None)),
        name="block",
    )


def vehicle_block(seed: int = 0) -> CellModel:
    """A synthetic ~531-cell, ~1600-link model for benchmarks (9 x 20 x 3 block, random lateral links).

    20 columns of 85 mm over 1.7 m put the 40 % and 25 % overlap edges on cell boundaries.
    """
    rng = np.random.default_rng(seed)
    nulls = set()
    while len(nulls) < 9:
        nulls.add((int(rng.integers(1, 8)), int(rng.integers(0, 20)), int(rng.integers(0, 3))))
    return grid_model(
        9,
        20,
        3,
        null_cells=tuple(sorted(nulls)),
        lateral_keep=0.65,
        seed=seed,
        sensors=(("tunnel", None), ("upfront_left", (0, 15, 1)), ("upfront_right", (0, 4, 1))),
        name="vehicle_block",
    )
