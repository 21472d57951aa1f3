"""Key figures, CSV export and plots of a simulated crash (``marlcrash simulate``).

The figures are the ones crash engineers read off a full-vehicle pulse: peak
compartment deceleration (CFC60), time to zero velocity, maximum dynamic crush,
rebound velocity; plus the energy balance error of the simulation and the energy
absorbed per sub-assembly. Sign convention as everywhere in marlcrash: velocity is
the forward (travel) speed, so a frontal crash pulse is negative.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from marlcrash.cells.model import N_PARAMS, PARAM_NAMES, CellModel
from marlcrash.errors import ModelError
from marlcrash.outputs import atomic_output, save_figure
from marlcrash.pulse.cfc import f_n
from marlcrash.pulse.signal import filtered_acceleration, sampled_acceleration
from marlcrash.sim.energy import max_balance_error
from marlcrash.sim.scenario import KMH, CrashScenario
from marlcrash.sim.surrogate import SimResult
from marlcrash.units import G0


def _first_crossing_ms(t: np.ndarray, v: np.ndarray) -> float | None:
    """First time [ms] at which ``v`` reaches zero, interpolated; ``None`` if it never does."""
    idx = np.flatnonzero(v <= 0.0)
    if idx.size == 0:
        return None
    i = int(idx[0])
    if i == 0:
        return float(t[0] * 1e3)
    f = v[i - 1] / (v[i - 1] - v[i])
    return float((t[i - 1] + f * (t[i] - t[i - 1])) * 1e3)


def compartment_sensor(result: SimResult, cells: CellModel) -> int | None:
    """Index into ``result.sensor_names`` of a sensor on the rigid compartment, if any (the signals of a result of
    ``probe_cells``, named ``cell<i>``, are no sensors of the model)."""
    names = list(cells.sensor_names)
    for k, name in enumerate(result.sensor_names):
        if name in names and int(cells.sensor_cell[names.index(name)]) == cells.compartment:
            return k
    return None


def energy_budget(cells: CellModel, scenario: CrashScenario, params: np.ndarray | None = None) -> dict[str, float]:
    """What the impact brings against the plastic work the cells can take.

    Returns:
        ``impact_energy_kj``: the kinetic energy of the vehicle's mass at the impact speed (elements,
        and the masses a deck adds by ``*ELEMENT_MASS``, ``*ELEMENT_MASS_PART``, MAREA, ``*PART_INERTIA``);
        ``crush_capacity_kj``: the sum of the crushing cells' ``E_s`` under ``params`` (default
        ``cells.params``), the plastic work they can take before they bottom out. Damping and the
        densified cells take energy beyond it, so the absorbed energy can exceed it.

    Raises:
        ModelError: ``params`` that are not one parameter set ``[n_cells, 7]`` (or ``[1, n_cells, 7]``).
    """
    p = np.asarray(cells.params if params is None else params, dtype=float)
    if p.shape not in ((cells.n_cells, N_PARAMS), (1, cells.n_cells, N_PARAMS)):  # [2, n, 7] was read as [n, 14]
        raise ModelError(f"params must be [{cells.n_cells}, {N_PARAMS}] (one parameter set), got {list(p.shape)}")
    p = p.reshape(cells.n_cells, N_PARAMS)
    crushing = ~cells.is_null & ~cells.is_rigid
    return {
        "impact_energy_kj": 0.5 * cells.total_mass * scenario.speed**2 / 1e3,
        "crush_capacity_kj": float(p[crushing, PARAM_NAMES.index("E_s")].sum() / 1e3),
    }


def bottoming_note(budget: dict[str, float]) -> str | None:
    """A note when the impact brings more than the cells can take as plastic work, else ``None``.

    A sufficient sign that the front bottoms out, not a necessary one: where the load paths
    crush unevenly, some lanes bottom out with capacity left in others.
    """
    e_in, e_cap = budget["impact_energy_kj"], budget["crush_capacity_kj"]
    if e_in <= e_cap:
        return None
    return (
        f"note: the impact brings {e_in:.1f} kJ and the cells can take {e_cap:.1f} kJ as plastic work, so the "
        "front must bottom out: the rest comes back through the densified cells as a stiff stop and rebound. "
        "A deeper region of interest (roi_depth in the discretization config, --config) gives the surrogate "
        "more structure to crush."
    )


def short_record(duration: float, cfc: int) -> str | None:
    """Why a record of ``duration`` [s] is too short for figures filtered at CFC ``cfc``, ``None`` where it is not.

    As :func:`marlcrash.pulse.signal.filter_pulse` and the calibration window ask: at least one period of the
    filter's -3 dB frequency (10 ms at CFC 60). A shorter record is mostly the filter's end handling: the default
    car's up-front sensors peaked at 1596 g over 1 ms and 137 g over 2 ms, at 315 g over 150 ms.
    """
    if duration >= 1.0 / f_n(cfc) - 1e-12:
        return None
    return (
        f"a record of {duration * 1e3:g} ms is too short for the CFC {cfc} figures; expected at least "
        f"{1e3 / f_n(cfc):g} ms (one period of the filter's {f_n(cfc):.0f} Hz -3 dB frequency: a shorter record "
        "is mostly its end handling)"
    )


def checked_row(result: SimResult, row: int) -> int:
    """``row`` as an index ``0..B-1`` into ``result``'s batch (:meth:`SimResult.batch_row`), errors keyed ``row``.

    Raises:
        IndexError: not an integer, or outside the batch (it failed inside torch, naming no argument).
    """
    try:
        return result.batch_row(row)
    except IndexError as e:
        raise IndexError(f"row: {e}") from None


def crash_summary(result: SimResult, cells: CellModel, scenario: CrashScenario, cfc: int = 60, row: int = 0) -> dict:
    """Key figures of one simulated crash (batch row ``row``).

    Returns:
        A JSON-ready dict: ``scenario`` (its name; ``None`` where the row's overlap or side is not the
        scenario's), ``speed_kmh``, ``overlap``, ``side`` (the row's load case: a run's per-row ``speed``,
        ``overlap`` and ``side`` override the scenario's), ``duration_ms`` (the simulated
        time after first contact: a run's ``duration`` overrides the scenario's), ``n_cells``,
        ``peak_decel_g`` (largest CFC-filtered compartment deceleration, g), ``t_peak_ms``,
        ``time_to_zero_velocity_ms`` (compartment; ``None`` if it never stops in the window),
        ``max_crush_m``, ``rebound_velocity_ms`` (largest rearward compartment speed after the
        stop, m/s, >= 0), ``rebound_fraction`` (of the row's impact speed),
        ``energy_balance_max_rel_error``, ``absorbed_energy_kj`` (sub-assembly -> kJ at the end;
        present when per-cell energies were recorded), and ``sensors`` (name -> ``peak_g``,
        ``t_peak_ms``, ``delta_v_ms``).

    Raises:
        IndexError: ``row`` is not a batch row of ``result`` (negative rows count from the end).
        ModelError: a record too short for CFC ``cfc`` (:func:`short_record`).
    """
    row = checked_row(result, row)
    t = result.time.detach().cpu().numpy()
    dt = float(t[1] - t[0])
    why = short_record(float(t[-1] - t[0]), cfc)
    if why is not None:
        raise ModelError(f"duration: {why}")
    v_comp = result.compartment_velocity[row].detach().cpu().numpy()
    acc = filtered_acceleration(result.acceleration[row].detach().cpu().numpy(), dt, cfc)  # [K, T], all at once
    sensors = {}
    for k, name in enumerate(result.sensor_names):
        a = acc[k]
        v = result.velocity[row, k].detach().cpu().numpy()
        i = int(np.argmin(a))
        sensors[name] = {
            "peak_g": float(-a[i] / G0) + 0.0,  # + 0.0: a resting record printed -0.0
            "t_peak_ms": float(t[i] * 1e3),
            "delta_v_ms": float(v[0] - v[-1]),
        }
    k_comp = compartment_sensor(result, cells)
    if k_comp is not None:
        a_comp = acc[k_comp]
    else:
        a_comp = sampled_acceleration(result.compartment_velocity[row].detach(), dt).cpu().numpy()
        a_comp = filtered_acceleration(a_comp, dt, cfc)
    i_peak = int(np.argmin(a_comp))
    t_stop = _first_crossing_ms(t, v_comp)
    rebound = float(max(0.0, -v_comp.min())) if t_stop is not None else 0.0

    # the row's own load case: a run's per-row tensors override the scenario's (the 56 km/h row of a batch at 40
    # and 56 km/h was reported at 40 km/h, an offset row of a full-width scenario as full width, a run's own
    # duration as the scenario's); the scenario's nominal values where they are the row's (a float32 run holds
    # 40 km/h as 40.0000005)
    def nominal(value: float, of_scenario: float) -> float:
        return of_scenario if math.isclose(value, of_scenario, rel_tol=1e-6) else value

    speed = nominal(float(result.speed[row]), scenario.speed)
    overlap = nominal(float(result.overlap[row]), scenario.overlap)
    side = "left" if float(result.side[row]) > 0 else "right"
    if overlap == 1.0 == scenario.overlap:  # the side is irrelevant at full width
        side = scenario.side
    own = overlap == scenario.overlap and side == scenario.side
    out: dict[str, Any] = {
        "scenario": scenario.name if own else None,
        "speed_kmh": scenario.speed_kmh if speed == scenario.speed else speed / KMH,
        "overlap": overlap,
        "side": side,
        "duration_ms": nominal(float(t[-1]), scenario.duration) * 1e3,
        "n_cells": cells.n_cells,
        "peak_decel_g": float(-a_comp[i_peak] / G0) + 0.0,
        "t_peak_ms": float(t[i_peak] * 1e3),
        "time_to_zero_velocity_ms": t_stop,
        "max_crush_m": float(result.crush[row].max()),
        "rebound_velocity_ms": rebound,
        "rebound_fraction": rebound / speed,
        "energy_balance_max_rel_error": max_balance_error(result[row]),
        "sensors": sensors,
    }
    absorbed = subassembly_absorbed(result, cells, row)
    if absorbed is not None:
        out["absorbed_energy_kj"] = {k: float(v[-1] / 1e3) for k, v in absorbed.items()}
    return out


def subassembly_absorbed(result: SimResult, cells: CellModel, row: int = 0) -> dict[str, np.ndarray] | None:
    """Energy [J] absorbed per sub-assembly, ``name -> [T']``; ``None`` without per-cell records.

    Raises:
        ModelError: ``cells`` is not the model ``result`` was simulated on (another number of cells).
    """
    row = checked_row(result, row)
    n = result.cell_plastic.shape[1]
    if n != cells.n_cells:  # failed inside numpy ("boolean index did not match indexed array")
        raise ModelError(f"cells: the result is of a model of {n} cells, this one ({cells.name!r}) has {cells.n_cells}")
    e = result.cell_absorbed[row].detach().cpu().numpy()  # [n, T']
    if e.shape[-1] == 0:
        return None
    sub = np.where(cells.is_null, -1, cells.subassembly)
    n_sub = len(cells.subassembly_names)
    sums = np.zeros((n_sub, e.shape[-1]))
    np.add.at(sums, sub[sub >= 0], e[sub >= 0])
    return {name: sums[i] for i, name in enumerate(cells.subassembly_names)}


def write_crash_csv(result: SimResult, path: str | Path, row: int = 0) -> Path:
    """Write time [s], per-sensor acceleration [g] and velocity [m/s], crush [m] as CSV (atomically).

    The accelerations are the simulator's output, unfiltered (as a test's raw channels are): the crash summary's peaks
    are CFC 60, and ``marlcrash pulse FILE.csv`` filters them the same way."""
    row = checked_row(result, row)
    path = Path(path)
    t = result.time.detach().cpu().numpy()
    cols = {"time_s": t}
    acc = result.acceleration[row].detach().cpu().numpy()
    for k, name in enumerate(result.sensor_names):
        cols[f"{name}_acc_g"] = acc[k] / G0
        cols[f"{name}_vel_ms"] = result.velocity[row, k].detach().cpu().numpy()
    cols["crush_m"] = result.crush[row].detach().cpu().numpy()
    with atomic_output(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(list(cols))
        w.writerows(np.stack(list(cols.values()), axis=1).tolist())
    return path


def plot_crash(result: SimResult, cells: CellModel, path: str | Path, title: str = "", cfc: int = 60, row: int = 0):
    """PNG: CFC-filtered acceleration and velocity per sensor, energy absorbed per sub-assembly.

    With per-cell energy series (``record_cells='series'``) the third panel stacks each sub-assembly's absorbed
    energy over time under the vehicle's kinetic energy; with a single per-cell record (``'final'``, at the end or
    at ``cells_at``) it is a bar per sub-assembly at that record; without per-cell records (``'none'``) it is left
    out. ``row``: the batch row drawn (:func:`checked_row`: an :class:`IndexError` naming it outside the batch).
    """
    import matplotlib

    matplotlib.use("Agg")

    fig = crash_figure(result, cells, title=title, cfc=cfc, row=row)
    return save_figure(fig, path)


def crash_figure(result: SimResult, cells: CellModel, title: str = "", cfc: int = 60, row: int = 0):
    """The matplotlib figure :func:`plot_crash` saves (the caller closes it)."""
    import matplotlib.pyplot as plt

    row = checked_row(result, row)

    t = result.time.detach().cpu().numpy()
    dt = float(t[1] - t[0])
    absorbed = subassembly_absorbed(result, cells, row)
    series = absorbed is not None and next(iter(absorbed.values())).shape[0] == t.shape[0]
    n_panels = 3 if absorbed is not None else 2
    fig, axes = plt.subplots(n_panels, 1, figsize=(8, 3.0 * n_panels))
    axes[1].sharex(axes[0])
    if series:
        axes[2].sharex(axes[0])
    acc = filtered_acceleration(result.acceleration[row].detach().cpu().numpy(), dt, cfc) / G0
    for k, name in enumerate(result.sensor_names):
        a = acc[k]
        axes[0].plot(t * 1e3, a, label=f"{name} CFC{cfc}")
        axes[1].plot(t * 1e3, result.velocity[row, k].detach().cpu().numpy(), label=name)
    axes[0].set_ylabel("acceleration [g]")
    axes[1].set_ylabel("velocity [m/s]")
    for ax in axes[:2]:
        ax.axhline(0.0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if absorbed is not None:
        floor = 1e-3 * max(1.0, result.initial[row].item())
        names = [n for n, v in absorbed.items() if v[-1] > floor]
        if series:  # each sub-assembly in its own colour, as plot_cells draws it (the 10-colour cycle repeated)
            from marlcrash.cells.plot import subassembly_colours

            colours = dict(zip(absorbed, subassembly_colours(len(absorbed)), strict=True))
            axes[2].stackplot(t * 1e3, *[absorbed[n] / 1e3 for n in names], labels=names,
                              colors=[colours[n] for n in names])  # fmt: skip
            axes[2].plot(t * 1e3, result.kinetic[row].detach().cpu().numpy() / 1e3, "k--", lw=1, label="kinetic")
            axes[2].set_ylabel("absorbed energy [kJ]")
            # beside the axes: inside, at the upper right, it covered the top bands once the crash was over
            axes[2].legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        else:  # one per-cell record: the split at that record, not a curve at t = 0
            axes[2].barh(names, [absorbed[n][-1] / 1e3 for n in names])
            axes[2].invert_yaxis()
            axes[2].set_xlabel("absorbed energy at the per-cell record (end, or cells_at) [kJ]")
        axes[2].grid(alpha=0.3)
    axes[2 if series else 1].set_xlabel("time [ms]")
    fig.suptitle(title)
    fig.tight_layout()
    return fig
