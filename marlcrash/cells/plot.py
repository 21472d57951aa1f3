"""3D picture of a cell model: voxels of the non-null cells coloured by sub-assembly."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from marlcrash.cells.model import CellModel
from marlcrash.outputs import save_figure


def draw_vehicle_frame(ax) -> None:
    """Draw 3D ``ax``'s data in marlcrash's vehicle frame as it is (x rearward, y left, z up; call after plotting).

    That frame is left-handed and matplotlib draws its 3D axes right-handed, so the plain points showed the vehicle
    mirrored, its left (+y) on its right side. The y axis is drawn reversed, which makes the drawn frame the
    vehicle's: seen from the front, the vehicle's left is on the viewer's right.
    """
    ax.invert_yaxis()


def subassembly_colours(n: int) -> list[tuple[float, float, float, float]]:
    """One colour per sub-assembly ``0..n-1``, no two alike: ``tab20``'s for up to 20, else ``n`` evenly spaced along
    ``turbo`` (a cycle of fewer colours drew two sub-assemblies in one colour). The picture of the cells and the
    energy panel of :func:`marlcrash.pulse.simulation.crash_figure` colour a sub-assembly alike."""
    import matplotlib.pyplot as plt

    if n <= 20:
        cmap = plt.get_cmap("tab20")
        return [cmap(k) for k in range(n)]
    cmap = plt.get_cmap("turbo")
    return [cmap(k / (n - 1)) for k in range(n)]


def plot_cells(cells: CellModel, path: str | Path, max_points: int = 60000) -> Path:
    """Write a 3D scatter PNG of the cells' voxels coloured by sub-assembly (null cells omitted).

    Args:
        cells: the cell model (its ``grid_labels`` give the voxels).
        path: output ``.png`` path.
        max_points: at most this many voxels are drawn (an even subsample beyond it); a whole number >= 1.

    Returns:
        The path written. Sensor cells are drawn in black, larger.

    Raises:
        ValueError: ``max_points`` is not a whole number >= 1 (0 drew no voxel at all).
    """
    if isinstance(max_points, bool) or not isinstance(max_points, int | np.integer) or max_points < 1:
        raise ValueError(f"max_points: expected a whole number of voxels >= 1, got {max_points!r}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = cells.grid_labels
    ex, ey, ez = (np.asarray(e) for e in cells.grid_edges)
    flat = labels.ravel()
    show = (flat >= 0) & ~cells.is_null[np.maximum(flat, 0)] & ~cells.is_rigid[np.maximum(flat, 0)]
    idx = np.flatnonzero(show)
    if idx.size > max_points:
        idx = idx[np.linspace(0, idx.size - 1, max_points).astype(np.int64)]
    ix, iy, iz = np.unravel_index(idx, labels.shape)
    cx, cy, cz = 0.5 * (ex[1:] + ex[:-1]), 0.5 * (ey[1:] + ey[:-1]), 0.5 * (ez[1:] + ez[:-1])
    sub = cells.subassembly[flat[idx]]
    sensor = cells.is_sensor[flat[idx]]
    fig = plt.figure(figsize=(10, 7))
    ax = fig.add_subplot(projection="3d")
    colours = subassembly_colours(len(cells.subassembly_names))
    for k, name in enumerate(cells.subassembly_names):
        m = (sub == k) & ~sensor
        if m.any():
            ax.scatter(cx[ix[m]], cy[iy[m]], cz[iz[m]], s=2, color=colours[k], label=name, depthshade=False)
    if sensor.any():
        ax.scatter(cx[ix[sensor]], cy[iy[sensor]], cz[iz[sensor]], s=8, color="k", label="sensor cells")
    ax.set_xlabel("x [m] (rearward)")
    ax.set_ylabel("y [m] (left)")
    ax.set_zlabel("z [m]")
    draw_vehicle_frame(ax)
    ax.set_title(f"{cells.name}: {cells.method}, {cells.n_cells} cells ({cells.n_null} null)")
    ax.legend(loc="upper left", fontsize=6, markerscale=3, ncol=2)
    ax.view_init(elev=25, azim=-130)
    return save_figure(fig, path)  # whole or not at all: a failed write leaves an earlier picture as it was
