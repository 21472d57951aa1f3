"""Initial behaviour parameters ``E_x, E_s`` of each cell from its material and geometry (DESIGN 1.3).

For a cell with x length ``L_x`` [m] (its extent along x, :attr:`CellModel.crush_length`)
and aggregate material (mass-weighted 8-vector):

- mean axial material section ``A_x = sum_s V_s a_s / L_x`` [m^2], summed over the
  cell's material samples ``s`` with volume ``V_s`` and axial factor ``a_s``
  (``sqrt(1 - n_x^2)`` for shells with unit normal ``n``, ``|d_x|`` for beams along
  ``d``, 1 for solids). By the coarea formula this is exactly the plane-cut
  section averaged over x: a tube along x gives perimeter x thickness, a plate
  facing x gives 0;
- effective section ``A = max(A_x, min_section_fraction * V / L_x)`` with ``V`` the
  cell's material volume: a cell with no material along x (a plate facing the
  load, a cooling-module core) still crushes, as its material smeared over
  ``L_x`` times the fraction. So every cell with mass has ``A > 0``;
- flow stress ``sigma_flow = (sigma_y + sigma_u) / 2`` [Pa];
- mean crush force ``F_c = eta * sigma_flow * A`` [N], ``eta`` the volume-weighted
  mean of the sample kinds' efficiencies (thin walls and beams ``eta_shell``,
  0.22 in ``configs/cells.yaml``: superfolding theory gives 0.11 to 0.23 for car
  sections, times a strain-rate factor; solids ``eta_solid``);
- stroke ``s = (1 - c) * L_x`` [m], ``c`` the volume-weighted compaction
  (fraction of the length left as compacted material): a fixed geometric property of the
  cell, kept in :attr:`CellModel.stroke`, from which the simulator recovers the crush force
  ``F_c = E_s / s`` of whatever ``E_s`` it is given (a solid cell's short stroke makes it strong);
- saturation energy ``E_s = F_c * s`` [J];
- elastic stiffness ``k = Y * A / L_x`` [N/m] and elastic energy at crush onset
  ``E_x = F_c^2 / (2 k)`` [J].

Null cells, massless cells and the compartment get zeros.
"""

from __future__ import annotations

import numpy as np

from marlcrash.cells.grid import KIND_SOLID, Samples


def behaviour_params(
    samples: Samples,
    cell_of_sample: np.ndarray,
    n: int,
    material: np.ndarray,
    crush_length: np.ndarray,
    active: np.ndarray,
    eta_shell: float,
    eta_solid: float,
    compaction_shell: float,
    compaction_solid: float,
    min_section_fraction: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``E_x``, ``E_s`` [J], the effective section ``A`` [m^2] and the stroke ``s`` [m] of each cell (formulas above).

    Args:
        samples: material samples ``[P]``.
        cell_of_sample: ``[P]`` cell index of each sample.
        n: number of cells.
        material: ``[n, 8]`` aggregate material vectors (SI).
        crush_length: ``[n]`` x length of each cell [m].
        active: ``[n]`` bool, cells that get parameters (non-null, non-rigid).
        eta_shell, eta_solid: crush efficiencies of thin-walled and solid material [-].
        compaction_shell, compaction_solid: compacted length fractions [-].
        min_section_fraction: least section as a fraction of ``V / L_x`` [-].

    Returns:
        ``(E_x [n], E_s [n], A [n], s [n])``; zeros where no parameters are given.
    """
    solid = samples.kind == KIND_SOLID
    vol = np.bincount(cell_of_sample, weights=samples.volume, minlength=n)
    axvol = np.bincount(cell_of_sample, weights=samples.axial_volume, minlength=n)
    vol_solid = np.bincount(cell_of_sample, weights=np.where(solid, samples.volume, 0.0), minlength=n)
    frac_solid = np.divide(vol_solid, vol, out=np.zeros(n), where=vol > 0)
    eta = eta_shell + (eta_solid - eta_shell) * frac_solid
    comp = compaction_shell + (compaction_solid - compaction_shell) * frac_solid
    ok = active & (vol > 0) & (crush_length > 0)
    length = np.where(ok, crush_length, 1.0)
    area = np.maximum(axvol / length, min_section_fraction * vol / length)
    sigma_flow = 0.5 * (material[:, 4] + material[:, 5])
    youngs = material[:, 1]
    force = eta * sigma_flow * area
    stroke = (1.0 - comp) * length
    e_s = force * stroke
    k = youngs * area / length
    e_x = np.divide(force**2, 2.0 * k, out=np.zeros(n), where=k > 0)
    zero = np.zeros(n)
    return np.where(ok, e_x, zero), np.where(ok, e_s, zero), np.where(ok, area, zero), np.where(ok, stroke, zero)
