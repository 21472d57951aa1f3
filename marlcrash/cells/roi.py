"""Region of interest, section planes and the rigid compartment (DESIGN 1.2).

In marlcrash axes (x rearward from the front at x = 0, y lateral with +y left,
z up) the ROI is the box ``x in [0, roi_depth]``, ``y`` across the vehicle's width ``W``
(``[y0 - W/2, y0 + W/2]``, ``y0`` the middle of its bounding box: its centre line) and ``z``
spanning the deformable material in front of ``roi_depth``. The sub-assembly
:data:`~marlcrash.vehicle.model.COMPARTMENT` (or, if the model has none, every part of
rigid material) is not discretized: it and every element whose centroid lies behind
``roi_depth`` form one rigid compartment cell.

One lateral reference: a barrier covering the fraction ``o`` of the width covers ``o W`` from the
struck side's outer edge ``y0 +- W/2`` (:func:`barrier_edge`), as a crash test measures it. The
section planes, the simulated barrier (:func:`marlcrash.sim.scenario.barrier_fraction`) and the
impact regions all take their edges from it, so a vehicle not centred on ``y = 0`` (an
:class:`~marlcrash.vehicle.model.AxisMap` with ``y_center``) is struck where it is cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlcrash.errors import ConfigError, ModelError
from marlcrash.vehicle.model import COMPARTMENT, VehicleModel

FRONT_TOL = 1e-3
"""How far [m] the model's front-most node may lie from x = 0 (rounding of a hand-built model)."""


@dataclass
class Roi:
    """The region of interest of a vehicle.

    Attributes:
        lo, hi: ``[3]`` ROI box corners [m].
        width: vehicle width ``W`` [m] from the model bounds.
        planes_y: sorted y positions of the section planes [m] (``y0``, ``y0 +- y1``, ``y0 +- y2``).
        compartment_parts: sorted part ids of the compartment.
        shell_in, solid_in, beam_in: ``[S]``, ``[V]``, ``[B]`` bool, elements that are discretized
            (not compartment, centroid in front of ``roi_depth``).
        roi_mass: mass of the discretized elements [kg], their added mass included.
        total_mass: vehicle mass [kg] (:meth:`VehicleModel.total_mass`: added and point masses included).
        masses: the model's structural element masses (``VehicleModel.element_masses``), reused downstream.
        added: the model's non-structural element masses (``VehicleModel.element_added_masses``).
        frame_y: how far along y this ROI's frame lies from the model's own [m] (``discretize`` works in the frame
            centred on the vehicle; messages give positions in the model's frame: add it).
    """

    lo: np.ndarray
    hi: np.ndarray
    width: float
    planes_y: np.ndarray
    compartment_parts: np.ndarray
    shell_in: np.ndarray
    solid_in: np.ndarray
    beam_in: np.ndarray
    roi_mass: float
    total_mass: float
    masses: dict[str, np.ndarray]
    added: dict[str, np.ndarray]
    frame_y: float = 0.0

    @property
    def volume(self) -> float:
        """ROI box volume [m^3]."""
        return float(np.prod(self.hi - self.lo))

    @property
    def centre_y(self) -> float:
        """The vehicle's centre line ``y0`` [m]: the middle of its width (of the ROI box, which spans it)."""
        return float(0.5 * (self.lo[1] + self.hi[1]))


def barrier_edge(centre_y, width, overlap, side):
    """Lateral position [m] of the inner edge of a barrier covering the fraction ``overlap`` of the width.

    The barrier covers ``overlap * width`` measured from the vehicle's outer edge on the struck side,
    ``centre_y + side * width / 2``: its inner edge is at ``centre_y + side * (width / 2 - overlap * width)``
    (a 40 % offset on the left of a 1.7 m car centred on 0: ``y = +0.17 m``). The one lateral reference of the
    section planes, the simulated barrier and the impact regions; floats, numpy arrays and tensors alike.

    Args:
        centre_y: the vehicle's centre line [m] (:attr:`Roi.centre_y`, ``CellModel.centre_y``).
        width: vehicle width ``W`` [m].
        overlap: covered fraction(s) of the width.
        side: +1 (left, +y) or -1 (right, -y).
    """
    return centre_y + side * (0.5 * width - overlap * width)


def section_planes(width: float, overlaps: list[float] | tuple[float, ...], centre_y: float = 0.0) -> np.ndarray:
    """Section planes in y for the centre line and each barrier overlap.

    A barrier covering the fraction ``o`` of the width from one side has its edge at
    :func:`barrier_edge`: ``y0 +- (W/2 - o W)``; 40 % gives ``y0 +- 0.1 W``, 25 % gives ``y0 +- 0.25 W``.

    Args:
        width: vehicle width ``W`` [m].
        overlaps: overlap fractions in ``(0, 1)``.
        centre_y: the vehicle's centre line ``y0`` [m].

    Returns:
        Sorted unique plane positions [m], always including ``y0``.
    """
    ys = [0.0]
    for i, o in enumerate(overlaps):
        if not 0.0 < o < 1.0:
            raise ConfigError(f"overlap fractions must lie in (0, 1), got {o}", key=f"overlaps[{i}]")
        ys += [barrier_edge(0.0, width, o, side) for side in (1.0, -1.0)]
    # rounded about the centre line, then placed: a centred model's planes are exact negatives of each other
    return np.unique(np.round(np.array(ys), 12)) + centre_y


def compartment_parts(model: VehicleModel) -> np.ndarray:
    """Part ids of the rigid compartment: its sub-assembly, else all rigid-material parts."""
    if COMPARTMENT in model.subassemblies:
        return np.array(sorted(int(p) for p in model.subassemblies[COMPARTMENT]), dtype=np.int64)
    rigid = [pid for pid, p in model.parts.items() if model.materials[p.material_id].is_rigid]
    return np.array(sorted(rigid), dtype=np.int64)


def _centroid_x(model: VehicleModel, nodes: np.ndarray) -> np.ndarray:
    if nodes.shape[0] == 0:
        return np.zeros(0)
    return model.coords[nodes][:, :, 0].mean(axis=1)


def region_of_interest(model: VehicleModel, roi_depth: float, overlaps: list[float] | tuple[float, ...]) -> Roi:
    """Crop the vehicle: ROI box, section planes and which elements are discretized.

    Args:
        model: the vehicle in marlcrash axes.
        roi_depth: crop depth behind the front-most point [m].
        overlaps: barrier overlap fractions defining the y section planes.

    Returns:
        The :class:`Roi`.

    Raises:
        ModelError: the model's front is not at x = 0 (within :data:`FRONT_TOL`), or it has no deformable
            material in front of ``roi_depth``.
    """
    if not roi_depth > 0:
        raise ConfigError(f"expected a positive depth [m], got {roi_depth}", key="roi_depth")
    b = model.bounds()
    if abs(b[0, 0]) > FRONT_TOL:  # the box starts at x = 0: material ahead of it was clamped, a gap cropped short
        raise ModelError(
            f"{model.name}: the front-most node is at x = {b[0, 0]:.4g} m; the region of interest is cut from the "
            "model in marlcrash axes, front at x = 0 (x rearward, y left, z up): read decks with read_deck, or "
            "move a model built in Python with model.transformed(AxisMap())"
        )
    width = float(b[1, 1] - b[0, 1])
    if width <= 0:
        raise ModelError(f"{model.name}: vehicle has zero width (all nodes at y = {b[0, 1]} m)")
    comp = compartment_parts(model)
    masses = model.element_masses()
    added = model.element_added_masses()
    sel = {}
    for kind, parts, nodes in (
        ("shell", model.shell_part, model.shell_nodes),
        ("solid", model.solid_part, model.solid_nodes),
        ("beam", model.beam_part, model.beam_nodes),
    ):
        sel[kind] = (~np.isin(parts, comp)) & (_centroid_x(model, nodes) < roi_depth)
    used = np.concatenate(
        [
            model.shell_nodes[sel["shell"]].ravel(),
            model.solid_nodes[sel["solid"]].ravel(),
            model.beam_nodes[sel["beam"]].ravel(),
        ]
    )
    if used.size == 0:
        raise ModelError(
            f"{model.name}: no deformable element has its centroid in front of roi_depth = {roi_depth} m "
            f"(model x range {b[0, 0]:.3f} .. {b[1, 0]:.3f} m, compartment parts {comp.tolist()[:10]})"
        )
    z = model.coords[np.unique(used), 2]
    zlo, zhi = float(z.min()), float(z.max())
    if zhi - zlo < 1e-6:
        zlo, zhi = zlo - 0.5e-3, zhi + 0.5e-3
    centre = 0.5 * (b[0, 1] + b[1, 1])
    lo = np.array([0.0, -0.5 * width + centre, zlo])
    hi = np.array([roi_depth, 0.5 * width + centre, zhi])
    roi_mass = float(sum(masses[k][sel[k]].sum() + added[k][sel[k]].sum() for k in sel))
    # summed as before added masses existed, so a model without them keeps its mass to the last bit
    total = float(sum(m.sum() for m in masses.values()))
    total += float(sum(a.sum() for a in added.values())) + float(model.point_mass.sum())
    return Roi(
        lo=lo,
        hi=hi,
        width=width,
        planes_y=section_planes(width, overlaps, centre),
        compartment_parts=comp,
        shell_in=sel["shell"],
        solid_in=sel["solid"],
        beam_in=sel["beam"],
        roi_mass=roi_mass,
        total_mass=total,
        masses=masses,
        added=added,
    )
