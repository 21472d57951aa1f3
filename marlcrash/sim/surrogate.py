"""The crash surrogate: batched, differentiable explicit dynamics over the cell graph (DESIGN 4).

Realisation: a lumped-mass, elastic-plastic spring model (Kamal-type), 1D motion
along x per cell.

- Nodes: every cell is a node with one degree of freedom ``s`` (travel toward the
  barrier, i.e. along -x, from the initial position); null cells are inert nodes
  with no links and no contact. The whole vehicle starts at the impact speed.
- Links: each link ``src -> dst`` is an elastic-plastic element on the relative
  travel ``delta = s_dst - s_src`` (compression positive; for +x links the rear
  cell closing on the front one, for lateral links a shear-like coupling). From the
  source cell's parameters: crush force ``F_c = E_s / stroke`` (:attr:`CellModel.stroke`, the cell's length
  less its compacted material: a solid cell's short stroke makes it strong),
  elastic stiffness ``k = F_c^2 / (2 E_x)``; the link carries the share
  ``(f_dir / max_d f_d) * link_share`` of both. The transmission factors are
  relative shares (the paper's share of transmitted energy per direction): the
  principal direction (the largest factor: x, where the cell has +x links, in the parameter space,
  which keeps boundary condition 3, :mod:`marlcrash.cells.parameterization`) keeps
  the cell's full crush strength and every other direction ``f_d / f_max`` of it.
  (Scaling by ``f_x`` itself took 40 % of a rail's axial strength away into
  lateral links that carry little, and ``f_x = 0`` cut load paths.) Lateral links
  yield symmetrically, axial links in tension at ``tension_ratio * F``, gap links
  carry only compression after the gap has closed, at most the crush strength of
  the cell they land on (contact engages the softer partner: a rigid powertrain
  pushes into the dash at the dash's strength), with contact damping
  ``contact_damping_ratio`` (impacts across a gap are inelastic, as at the wall).
- Saturation: once the plastic work of a cell's links reaches ``E_s`` the cell has
  bottomed out: its links stop yielding and stiffen by ``densification_factor``,
  so all further load is transmitted. The switch happens within the step that crosses
  ``E_s``: if the fraction ``phi`` of the cell's plastic work in that step lies past ``E_s``,
  each out-link's force moves ``phi`` of the way from its update toward the dense update
  ``f_old + k_dense dd`` (``f_old`` its force at the step's start), its damping likewise, and the cell
  keeps exactly ``E_s`` as plastic work (the rest became elastic energy of the dense links).
  Switching at the next step instead made every later force depend on which step the
  crossing fell in: 1e-4 changes of the parameters moved the pulses 10x more than the
  linear response; now the response stays linear to about 1e-3.
- Wall: one-sided penalty contact (with damping while penetrating) on each cell's
  front area covered by the barrier (:func:`~marlcrash.sim.scenario.barrier_fraction`), from
  the x where the wall meets the cell's exposed material (:attr:`CellModel.front_x`).
- Damping (Kelvin-Voigt on the elastic part only): a link's viscous force is its damping
  coefficient times the rate of its *elastic* deformation in the step, ``(f_ret - f_old) / k / dt``
  (``f_ret`` the return-mapped force): the full relative velocity while elastic, nothing during
  plastic flow, and the elastic share of the step where it starts or stops yielding. Gap links
  and the wall damp the penetration made in the step the same way (``min(v, pen / dt)`` at the
  wall) and never pull (total contact force ``>= 0``). So no force jumps when a contact closes or
  a link starts or stops yielding between two steps: damping switched on or off in full at the
  step that detects the switch made the pulse depend on which step that was, and 1e-5 parameter
  changes moved sensor velocities 20-30x more than the linear response
  (``tests/test_sim_default_car.py``).
- Integrator: symplectic Euler with ``substeps`` steps per output step.

Stability choice (documented effect on the pulse): an explicit step ``dt`` is
stable when every node's summed stiffness is below ``2 m / dt^2``. Every element
stiffness ``k`` is therefore combined *in series* with a numerical compliance
``k_cap = c * min(m_i / deg_i, m_j / deg_j) / dt^2`` (``c = stiffness_cap``,
``deg`` = number of elements at the node): ``k_eff = k k_cap / (k + k_cap)``. This is
smooth (differentiable), never stiffer than the cap, so stable for any parameters
(Gershgorin bound, ``c < 2`` without damping; the explicit link, contact and wall damping use up part of
that budget, so the accepted ranges are ``c <= 1.2`` and ``link_damping_ratio <= 0.15``, measured
jointly on the default car: ``c = 1.9`` or ``link_damping_ratio = 0.25`` alone, or ``c = 1.5`` with
``link_damping_ratio = 0.15``, diverge). Effect: the elastic rise of the pulse is softer
(elastic energy at crush onset is ``F^2 / 2 k_eff >= E_x``) when ``k`` exceeds the
cap; crush forces (plateaus) and energies absorbed are not changed. Light cells are
mass-scaled up to ``mass_floor`` with the added mass taken from the compartment,
so the vehicle mass and the initial kinetic energy are unchanged (selective mass
scaling, as explicit FE codes do). On the default car (thin-walled cells of
0.03-0.2 kg) the cap binds for most links: the elastic energy they store at a given
force is ``F^2 / 2 k_eff``, which is released as rebound. ``substeps`` and
``mass_floor`` in ``configs/sim.yaml`` are chosen so the capped stiffness lets the
load paths reach their crush forces within a few mm and the rebound stays in the
5-20 % of real rigid-wall tests (tested in ``tests/test_sim_default_car.py``).

Springback relief (``springback_relief``, off by default): the excess elastic energy
``F^2 / 2 k_eff - F^2 / 2 k_raw`` of a capped link is a numerical artefact; the real element
would unload along its own stiff slope. Once a link has yielded, every step in which it
unloads (``|f|`` falls, same sign) scales its force by ``q = 1 - (1 - exp(-dt / tau)) x`` with
``x = k_raw / (k_raw + k_cap) = 1 - k_eff / k_raw`` the excess share of its force (0 where the
cap does not bind); ``tau = springback_tau``. This only ever reduces ``|f|`` and its derivative
by the displacement stays ``q k_eff <= k_eff``: no stiffness is added, the explicit step stays
stable and the map stays contractive (a stiff real unloading slope, tried first, made the
trajectories chaotic: 1e-12 parameter changes moved the stop time). The released elastic energy
``(f^2 - (q f)^2) / 2 k_eff`` is booked as plastic work of the source cell (it counts toward
``E_s``); the balance closes as before because the work is integrated with the forces applied.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal, NamedTuple

import numpy as np
import torch

from marlcrash.cells.model import N_PARAMS, PARAM_NAMES, CellModel
from marlcrash.config import checked, config_dir, load_config, require, require_device
from marlcrash.errors import ModelError
from marlcrash.sim.energy import cell_energies
from marlcrash.sim.scenario import (
    BASE_OUTPUT_DT,
    KMH,
    MAX_RUN_DURATION_S,
    MAX_SPEED_KMH,
    MAX_SUBSTEPS,
    MIN_SPEED_KMH,
    CrashScenario,
    barrier_fraction,
    checked_scenario,
    output_step_rule,
    steps_per_output,
)

_BIG = 1e30  # "infinite" yield force of a bottomed-out link [N]
_EPS_F = 1e-12  # floor of a cell's largest transmission factor [-] (all-zero rows stay zero)
_EPS_K = 1e-9  # floor of element stiffness relative to its cap, keeps f / k finite for idle links [-]
MAX_LINK_DAMPING_RATIO = 0.15
"""Largest accepted ``link_damping_ratio`` [-]. The damping force is explicit and each element's stiffness may sit
at its stability cap, so damping adds to a node's step-stability budget: on the default car with 0.5x-2x random
energies, 0.15 peaks at 7 500 g (0.05: 5 900 g), 0.2 at 15 000 g and 0.25 diverges (1e30 g)."""
MAX_STIFFNESS_CAP = 1.2
"""Largest accepted ``stiffness_cap`` [-]: stable together with the largest accepted damping ratios (link 0.15,
contact and wall 1.0: peaks of 6 600 g on the same test); 1.5 with link damping 0.15 diverges, and 1.9 with the
default damping. The undamped Gershgorin bound would be 2."""


@dataclass
class SimConfig:
    """Integrator and contact settings; values in ``configs/sim.yaml`` (see its comments).

    The defaults here are that file's shipped values (tested), so ``SimConfig()`` in a notebook simulates what the
    tools do; the tools themselves read the file and refuse one with a key missing.
    """

    substeps: int = 8
    stiffness_cap: float = 1.0
    mass_floor: float = 0.5
    densification_factor: float = 10.0
    tension_ratio: float = 0.3
    link_damping_ratio: float = 0.05
    contact_damping_ratio: float = 0.7
    wall_stiffness: float = 1e10
    wall_damping_ratio: float = 0.7
    springback_relief: bool = False
    springback_tau: float = 2e-3
    dtype: Literal["float64", "float32"] = "float64"
    backend: Literal["torch", "numba", "auto"] = "auto"

    # not a field: removed keys and what replaced them, for the error that names one (marlcrash.config)
    RETIRED_KEYS = MappingProxyType(
        {
            "stroke_fraction": "the crushable stroke is each cell's own now (CellModel.stroke, from compaction_shell "
            "and compaction_solid in configs/cells.yaml); one fraction for every cell gave solid cells 1/7 of their "
            "crush force"
        }
    )

    def validate(self) -> None:
        """Range checks; raise :class:`~marlcrash.errors.ConfigError` naming the key."""
        require(
            1 <= self.substeps <= MAX_SUBSTEPS,
            "substeps",
            f"substeps must be in [1, {MAX_SUBSTEPS}], got {self.substeps}",
        )
        require(
            0.0 < self.stiffness_cap <= MAX_STIFFNESS_CAP,
            "stiffness_cap",
            f"stiffness_cap must be in (0, {MAX_STIFFNESS_CAP}] for stability with the explicit damping, "
            f"got {self.stiffness_cap}",
        )
        require(self.mass_floor >= 0.0, "mass_floor", f"mass_floor must be >= 0 kg, got {self.mass_floor}")
        require(
            self.densification_factor >= 1.0,
            "densification_factor",
            f"densification_factor must be >= 1, got {self.densification_factor}",
        )
        require(
            0.0 <= self.tension_ratio <= 1.0,
            "tension_ratio",
            f"tension_ratio must be in [0, 1], got {self.tension_ratio}",
        )
        require(
            0.0 <= self.link_damping_ratio <= MAX_LINK_DAMPING_RATIO,
            "link_damping_ratio",
            f"link_damping_ratio must be in [0, {MAX_LINK_DAMPING_RATIO}] (the explicit step is stable for the "
            f"stability-capped stiffness, not for much damping on top of it), got {self.link_damping_ratio}",
        )
        require(
            0.0 <= self.contact_damping_ratio <= 1.0,
            "contact_damping_ratio",
            f"contact_damping_ratio must be in [0, 1], got {self.contact_damping_ratio}",
        )
        require(
            self.wall_stiffness > 0.0, "wall_stiffness", f"wall_stiffness must be > 0 N/m^3, got {self.wall_stiffness}"
        )
        require(
            0.0 <= self.wall_damping_ratio <= 1.0,
            "wall_damping_ratio",
            f"wall_damping_ratio must be in [0, 1], got {self.wall_damping_ratio}",
        )

        require(
            isinstance(self.springback_relief, bool),
            "springback_relief",
            f"springback_relief must be true or false, got {self.springback_relief!r}",
        )
        require(self.springback_tau > 0.0, "springback_tau", f"springback_tau must be > 0 s, got {self.springback_tau}")

    @property
    def torch_dtype(self) -> torch.dtype:
        return torch.float64 if self.dtype == "float64" else torch.float32


def load_sim_config(path: str | Path | None = None, overrides: dict | None = None) -> SimConfig:
    """Load ``configs/sim.yaml`` (or ``path``) with optional dotted-key overrides."""
    return load_config(SimConfig, path or config_dir() / "sim.yaml", overrides, complete=True)


@dataclass
class SimResult:
    """Output of one batched simulation; ``T`` output samples including t = 0.

    Signs: velocities and accelerations are along the direction of travel (toward
    the barrier): velocity starts at the impact speed, deceleration is negative.

    Attributes:
        time: ``[T]`` output times [s].
        sensor_names: ``[K]`` names of the recorded sensors.
        velocity: ``[B, K, T]`` sensor-cell velocity [m/s].
        acceleration: ``[B, K, T]`` sensor-cell acceleration [m/s^2] as an anti-aliased accelerometer
            records it at the output rate, derived from ``velocity``
            (:func:`~marlcrash.pulse.signal.sampled_acceleration`): its integral is the velocity change, by the
            trapezoid rule with the zero acceleration before the first contact as a sample at ``-dt`` (without it
            the first sample's half weight left an up-front sensor 9.5 % short: it loses 4.7 m/s in 0.5 ms).
        compartment_displacement: ``[B, T]`` compartment travel since first contact [m].
        compartment_velocity: ``[B, T]`` compartment velocity [m/s].
        crush: ``[B, T]`` dynamic crush [m]: compartment travel since the front touched
            the barrier, less the (numerical) penalty penetration of the front into the wall: the largest of the
            covered cell fronts' penetrations, each times the fraction of its front the barrier covers (a front the
            barrier's edge clips meets a wall as stiff as that fraction and sinks into it; unweighted, an overlap
            just past a cell's edge took centimetres off the crush).
        kinetic, stored, absorbed: ``[B, T]`` energy totals [J] (leapfrog kinetic energy;
            elastic energy in links and contact; work dissipated by plasticity,
            densification, damping).
        plastic: ``[B, T]`` return-mapping plastic work of all links [J] (independent check).
        initial: ``[B]`` initial kinetic energy [J].
        cell_input, cell_absorbed, cell_transmitted: ``[B, n_cells, T']`` cumulative
            per-cell energies [J] (``T' = T`` for ``record_cells='series'``, 1 for
            ``'final'``: at the end, or at ``Surrogate.run``'s ``cells_at``; 0 for ``'none'``).
        cell_plastic: ``[B, n_cells]`` plastic work per cell [J], at the end (or at ``cells_at``).
        saturated: ``[B, n_cells]`` bool, cell bottomed out (plastic work reached E_s), at the same time.
        speed, overlap, side: ``[B]`` each row's load case: impact speed [m/s], barrier overlap fraction, +1 left /
            -1 right (the scenario's, or the run's per-row tensors where given).
    """

    time: torch.Tensor
    sensor_names: list[str]
    velocity: torch.Tensor
    compartment_displacement: torch.Tensor
    compartment_velocity: torch.Tensor
    crush: torch.Tensor
    kinetic: torch.Tensor
    stored: torch.Tensor
    absorbed: torch.Tensor
    plastic: torch.Tensor
    initial: torch.Tensor
    cell_input: torch.Tensor
    cell_absorbed: torch.Tensor
    cell_transmitted: torch.Tensor
    cell_plastic: torch.Tensor
    saturated: torch.Tensor
    speed: torch.Tensor
    overlap: torch.Tensor
    side: torch.Tensor

    @property
    def acceleration(self) -> torch.Tensor:
        """``[B, K, T]`` sensor acceleration [m/s^2] (see the class doc)."""
        from marlcrash.pulse.signal import sampled_acceleration  # the pulse package builds on this module

        return sampled_acceleration(self.velocity, float(self.time[1] - self.time[0]))

    def batch_row(self, row: Any) -> int:
        """``row`` as an index ``0..B-1`` into the batch (a negative row counts from the end).

        Raises:
            IndexError: not an integer (an int or numpy integer; a bool is none), or outside the batch.
        """
        try:
            if isinstance(row, bool | np.bool_):  # True was row 1
                raise TypeError
            r = operator.index(row)
        except TypeError:
            raise IndexError(f"expected an integer batch row, got {row!r}") from None
        B = self.initial.shape[0]
        if not -B <= r < B:
            raise IndexError(f"batch row {r} out of range for a result of {B} rows")
        return r % B

    def __getitem__(self, idx) -> SimResult:
        """Select batch rows (``result[3]``, ``result[-1]``, ``result[2:5]``), keeping the batch dimension.

        Raises:
            IndexError: an integer row outside the batch, or a bool.
        """
        if isinstance(idx, bool | np.bool_):  # no row (batch_row raises): torch read x[True] as a new axis
            self.batch_row(idx)
        try:
            operator.index(idx)  # an int or numpy integer: one row (result[-1] was the empty slice -1:0)
        except TypeError:
            pass  # a slice, or an index tensor or list of rows
        else:
            row = self.batch_row(idx)
            idx = slice(row, row + 1)
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = v[idx] if isinstance(v, torch.Tensor) and f.name != "time" else v
        return SimResult(**out)


class _Step(NamedTuple):
    """One step's element forces and the link state after it (:meth:`Surrogate._step`), all ``[B, L]`` or ``[B, n]``."""

    dd: torch.Tensor  # link deformation increments [m]
    o: torch.Tensor  # gap openings [m]
    yielded: torch.Tensor  # link has yielded (springback relief)
    plastic: torch.Tensor  # cell plastic work [J]
    k: torch.Tensor  # current link stiffness [N/m]
    f_new: torch.Tensor  # elastic(-plastic) link force [N]
    f_tot: torch.Tensor  # link force with damping [N]
    pen: torch.Tensor  # wall penetration (negative: apart) [m]
    in_contact: torch.Tensor  # bool, cell pushing on the wall
    fw: torch.Tensor  # wall force [N]
    k_t: torch.Tensor | None  # link force derivative by its deformation increment [N/m] (tangent=True)
    kw_t: torch.Tensor | None  # wall force derivative by the cell's increment [N/m] (tangent=True)


@dataclass
class LinkProps:
    """Per-batch element properties derived from the parameters (all ``[B, L]`` or ``[B, n]``)."""

    yield_c: torch.Tensor  # [B, L] compressive yield (crush) force [N]
    yield_t: torch.Tensor  # [B, L] tensile yield force magnitude [N]
    k: torch.Tensor  # [B, L] effective elastic stiffness [N/m]
    k_dense: torch.Tensor  # [B, L] effective stiffness once the source cell bottomed out [N/m]
    damping: torch.Tensor  # [B, L] viscous coefficient on the elastic deformation rate [N s/m]
    relax: torch.Tensor  # [B, L] per-step force factor of a yielded link while unloading (springback relief) [-]
    relax_dense: torch.Tensor  # [B, L] ... once the source cell bottomed out [-]
    e_s: torch.Tensor  # [B, n] saturation energy per cell (inf for cells without links) [J]


@dataclass
class WallProps:
    """Per-batch contact properties (``[B, n]``) and scenario tensors (``[B]``)."""

    k: torch.Tensor  # [B, n] penalty stiffness [N/m] (0 where not covered)
    damping: torch.Tensor  # [B, n] contact damping [N s/m]
    gap: torch.Tensor  # [B, n] x distance from the first contact point to the cell front [m]
    covered: torch.Tensor  # [B, n] bool, cell front covered by the barrier
    coverage: torch.Tensor  # [B, n] the covered fraction of the cell front (0 where not covered)
    speed: torch.Tensor  # [B] impact speed [m/s]
    overlap: torch.Tensor  # [B] barrier overlap fraction of the vehicle width
    side: torch.Tensor  # [B] +1 left, -1 right


GRAPH_MAX_BATCH = 1024
"""The largest batch ``backend="auto"`` replays as a CUDA graph on a GPU; above it runs the eager ``torch`` backend.
On an H100 (``benchmarks/bench_gpu.py``, default car, 150 ms) the replay ran 3.3-5.6x the eager rate at B = 1 to
64, 0.93x (float64) and 1.5x (float32) at 1024, and 0.70x (float64) and 0.73x (float32) at 8192, where the kernels
are bandwidth-bound and the replay's branchless saturation step (:meth:`Surrogate._step`) adds traffic."""

Backend = Literal["torch", "numba", "adjoint", "cuda_graph", "auto"]
BACKENDS: tuple[Backend, ...] = ("torch", "numba", "adjoint", "cuda_graph", "auto")
"""The engines :meth:`Surrogate.run` takes (its ``backend``)."""


def load_case(wall: WallProps) -> dict[str, torch.Tensor]:
    """A run's per-row ``speed``, ``overlap`` and ``side`` for its :class:`SimResult` (detached copies)."""
    return {k: getattr(wall, k).detach().clone() for k in ("speed", "overlap", "side")}


def _short(x, limit: int = 80) -> str:
    """``repr(x)``, cut to ``limit`` characters for a message (a parameter list repeats thousands of numbers)."""
    r = repr(x)
    return r if len(r) <= limit else r[: limit - 3] + "..."


def _is_real(x) -> bool:
    """``x`` holds real numbers (ints or floats): not text, bools, complex numbers or objects; numpy's dtype for what is
    no tensor (torch's is float32 for Python floats, and casts a complex number to its real part)."""
    if isinstance(x, torch.Tensor):
        return not (x.dtype.is_complex or x.dtype == torch.bool)
    try:
        return np.asarray(x).dtype.kind in "iuf"
    except (TypeError, ValueError):  # a ragged list
        return False


def _tensor(x, **kw) -> torch.Tensor:
    """``torch.as_tensor(x, **kw)``; a numpy array with negative strides (``a[::-1]``, which torch cannot wrap:
    "At least one stride in the given numpy array is negative") is copied first."""
    if isinstance(x, np.ndarray) and any(st < 0 for st in x.strides):
        x = x.copy()
    return torch.as_tensor(x, **kw)


def _seconds(value, name: str) -> float:
    """``value`` [s] as a float: a real number (an int, float, numpy scalar, or 0-d real array or tensor).

    Raises:
        ModelError: text (``float("0.01")`` read it), a bool (ran as 1 s), a list or a complex number, naming ``name``.
    """
    if not (_is_real(value) and np.ndim(value) == 0):
        raise ModelError(f"{name} must be a time in s (a real number), got {_short(value)}")
    return float(value)


class Surrogate:
    """Batched cell-surrogate simulator of one :class:`CellModel`.

    ``Surrogate(cells, config)`` precomputes index tensors, scaled masses and
    stability caps once; :meth:`run` then simulates ``B`` parameter sets.

    Args:
        cells: the cell model (validated here).
        config: integrator settings; ``None`` loads ``configs/sim.yaml``.
        output_dt: output step [s] (2 kHz default): a whole number of integration steps ``dt``. The integration
            step is ``BASE_OUTPUT_DT / substeps`` whatever the output rate, so the stability caps, and with them the
            crash, do not depend on how it is sampled (at 500 Hz a crash of 0.5 ms output steps x 8 rebounded 59 %
            instead of 16 %); :attr:`substeps` steps per output sample.
        stability_caps: combine every element's stiffness in series with its explicit stability cap (the
            module doc). ``False`` keeps the raw stiffnesses: only the implicit study integrator
            (:mod:`marlcrash.sim.implicit`) can run such a surrogate; :meth:`run` refuses.

    Raises:
        ModelError: ``cells`` that is no :class:`CellModel`, a ``stability_caps`` that is no bool, links touching
            null cells or owned by the compartment, no mass, an output step that is not a positive whole number of
            integration steps (or not a number), or a ``config`` that is no :class:`SimConfig`.
    """

    def __init__(
        self, cells: CellModel, config: SimConfig | None = None, output_dt: float = 5e-4, stability_caps: bool = True
    ):
        if not isinstance(cells, CellModel):  # None or a deck path failed with "'NoneType' has no attribute 'validate'"
            raise ModelError(
                f"cells must be a CellModel (marlcrash.cells.discretize(model)), got {type(cells).__name__} "
                f"{_short(cells)}"
            )
        cells.validate()
        if config is not None and not isinstance(config, SimConfig):  # a path or overrides failed inside dataclasses
            raise ModelError(
                f"config must be a SimConfig (load_sim_config(path, overrides)), got {type(config).__name__} {config!r}"
            )
        if not isinstance(stability_caps, bool | np.bool_):  # bool("no") is True, bool(None) False
            raise ModelError(f"stability_caps must be True or False, got {stability_caps!r}")
        self.stability_caps = bool(stability_caps)
        self.cells = cells
        self.config = cfg = checked(config) if config is not None else load_sim_config()
        self.output_dt = _seconds(output_dt, "output_dt")
        self.dt = BASE_OUTPUT_DT / cfg.substeps
        per = steps_per_output(self.output_dt, cfg.substeps)
        if per is None:
            rate = f"{1.0 / self.output_dt:.6g}" if self.output_dt else "inf"
            raise ModelError(
                f"output step {output_dt!r} s (a scenario's output_rate {rate} Hz) {output_step_rule(cfg.substeps)}"
            )
        self.substeps = per
        """Integration steps per output sample."""
        # the step simulated, not the one given within the 1e-6 accepted (np.float32(5e-4)): the time axis was
        # labelled by the inexact step (0.150000007 s at the end of 0.150 s) and every 2 kHz scenario refused
        self.output_dt = BASE_OUTPUT_DT * (per / cfg.substeps)
        dtype = self.dtype = cfg.torch_dtype
        # Stiffnesses (links and wall) are clamped at sqrt(largest float), far above any stability cap (which then
        # binds fully), so that k_raw * cap stays finite: in float32 E_x = 1e-20 J, 1e11 x E_s or a wall_stiffness of
        # 1e39 N/m^3 overflowed to inf and gave NaN.
        self.k_max = math.sqrt(torch.finfo(dtype).max)
        n, L = cells.n_cells, cells.n_links
        self.n, self.L = n, L
        src, dst = cells.link_src.astype(np.int64), cells.link_dst.astype(np.int64)
        null, rigid = cells.is_null.astype(bool), cells.is_rigid.astype(bool)
        self.comp = cells.compartment
        if L and (null[src].any() or null[dst].any()):
            bad = int(np.flatnonzero(null[src] | null[dst])[0])
            raise ModelError(f"link {bad} ({src[bad]} -> {dst[bad]}) touches a null cell; null cells have no links")
        if L and rigid[src].any():
            bad = int(np.flatnonzero(rigid[src])[0])
            raise ModelError(f"link {bad} is owned by the rigid compartment cell {src[bad]}; energy never flows to -x")
        if (np.asarray(cells.link_dir) < 0).any() or (np.asarray(cells.link_dir) > 4).any():
            raise ModelError("CellModel.link_dir must index DIRECTIONS (0..4)")
        active = ~null & ~rigid
        if (cells.crush_length[active] <= 0).any():
            bad = int(np.flatnonzero(active & (cells.crush_length <= 0))[0])
            raise ModelError(f"cell {bad}: crush_length must be > 0 m, got {cells.crush_length[bad]}")
        if (cells.stroke[active] <= 0).any():
            bad = int(np.flatnonzero(active & (cells.stroke <= 0))[0])
            raise ModelError(f"cell {bad}: stroke must be > 0 m, got {cells.stroke[bad]}")

        # Mass scaling: light cells raised to the floor, the compartment pays for it.
        mass = np.where(null, 1.0, cells.mass.astype(np.float64))
        if (mass < 0).any():  # the floor lifted it without a word, paid by the compartment
            bad = int(np.flatnonzero(mass < 0)[0])
            raise ModelError(f"{cells.name}: cell {bad}: mass must be >= 0 kg, got {mass[bad]:g}")
        added = np.where(active, np.maximum(cfg.mass_floor - mass, 0.0), 0.0)
        mass = mass + added
        if (mass[active] <= 0).any():  # only with mass_floor 0; the message blamed the compartment
            bad = int(np.flatnonzero(active & (mass <= 0))[0])
            raise ModelError(
                f"{cells.name}: cell {bad} has no mass (0 kg) and mass_floor (sim config) is 0 kg: the explicit step "
                "needs a mass in every cell with material; give mass_floor > 0"
            )
        mass[self.comp] -= added.sum()
        if (mass[~null] <= 0).any():
            total = float(cells.mass[~null].sum())
            if cells.mass[self.comp] <= 0:  # not the units: the region of interest took the whole vehicle
                raise ModelError(
                    f"{cells.name}: the compartment has no mass (0 kg), so it cannot pay for the mass floor of "
                    f"{cfg.mass_floor:g} kg (mass_floor, sim config) on {int((added > 0).sum())} light cells: every "
                    "element lies in the region of interest; give a roi_depth (cells config) shorter than the vehicle"
                )
            raise ModelError(
                f"{cells.name}: the mass floor of {cfg.mass_floor:g} kg (mass_floor, sim config) adds "
                f"{added.sum():.4g} kg to {int((added > 0).sum())} light cells, more than the compartment's "
                f"{cells.mass[self.comp]:.4g} kg can pay for (vehicle {total:.4g} kg); a deck read in the wrong unit "
                "system is this light: check its units (--units)"
            )
        self.mass_added = float(added.sum())
        exposed = (cells.front_area > 0) & active
        deg = np.bincount(src, minlength=n) + np.bincount(dst, minlength=n) + exposed.astype(np.int64)
        deg = np.maximum(deg, 1)
        c = cfg.stiffness_cap / self.dt**2
        m_per = mass / deg
        cap_link = c * np.minimum(m_per[src], m_per[dst])
        m_pair = mass[src] * mass[dst] / (mass[src] + mass[dst])

        t = lambda a, dt=dtype: torch.as_tensor(np.asarray(a), dtype=dt)  # noqa: E731
        self.src, self.dst = t(src, torch.int64), t(dst, torch.int64)
        self.param_index = t(src * 5 + cells.link_dir.astype(np.int64), torch.int64)  # into f.reshape(B, n*5)
        self.share = t(cells.link_share)
        self.gap = t(cells.link_gap)
        self.is_gap = t(cells.link_gap > 0, torch.bool)
        self.is_axial = t(cells.link_dir == 0, torch.bool)
        self.dst_rigid = t(rigid[dst], torch.bool)
        self.cap_link = t(cap_link)
        self.m_pair = t(m_pair)
        self.mass = t(mass)
        self.mass_ke = t(np.where(null, 0.0, mass))  # null cells carry no energy
        self.cap_wall = t(c * m_per)
        self.exposed = t(exposed, torch.bool)
        self.front_area = t(np.where(exposed, cells.front_area, 0.0))
        self.active = t(active, torch.bool)
        link_dirs = np.zeros((n, 5), bool)
        link_dirs[src, cells.link_dir.astype(np.int64)] = True
        self.link_dirs = t(link_dirs, torch.bool)  # [n, 5] the directions each cell has links in
        self.has_links = self.link_dirs.any(dim=1)
        self.stroke = t(np.where(active, cells.stroke, 1.0))
        self.front_x = t(cells.front_x)  # where the wall meets each cell (not its bounding box front)
        self.lo_y, self.hi_y = t(cells.lo[:, 1]), t(cells.hi[:, 1])
        self.width = float(cells.vehicle_width)
        self.centre_y = cells.centre_y
        # Fast-path layout: plain links first, then gap links, each sorted by (src, dst).
        self.link_order = np.lexsort((dst, src, cells.link_gap > 0))
        self.tension_ratio_np = np.where(cells.link_dir == 0, cfg.tension_ratio, 1.0)

    # ------------------------------------------------------------------ device
    @property
    def device(self) -> torch.device:
        """Where the surrogate's tensors live and the ``torch`` backend runs (:meth:`to`); the CPU by default."""
        return self.mass.device

    def to(self, device: str | torch.device) -> Surrogate:
        """Move the surrogate's tensors to ``device`` (in place, as ``nn.Module.to``) and return it.

        On a CUDA device the differentiable ``torch`` backend and its graph replay ``cuda_graph`` run (``auto`` picks
        one, :meth:`run`; the compiled ``numba`` and ``adjoint`` backends are CPU code and are refused), results come
        back on that device, and parameters or scenario tensors given on the CPU (or as arrays) are moved there. Each
        integration step is about a hundred unfused kernels whatever ``B`` is: on an H100 the best rate was 1.3-1.45x
        the compiled kernel on the host's 16 cores (``benchmarks/bench_gpu.py``, README "On a GPU").

        Raises:
            ConfigError: a ``device`` that is not ``cpu`` or a CUDA device this machine has (key ``device``).
        """
        require_device(device, "device")
        dev = torch.device(device)
        if dev.type == "cuda" and dev.index is None:
            dev = torch.device("cuda", torch.cuda.current_device())
        for name, value in list(vars(self).items()):
            if isinstance(value, torch.Tensor):
                setattr(self, name, value.to(dev))
        return self

    def _on_device(self, x: torch.Tensor, name: str) -> torch.Tensor:
        """``x`` on the surrogate's device: from the CPU it is moved (autograd follows), from another device refused
        (torch's "Expected all tensors to be on the same device" came from deep inside a step)."""
        if x.device == self.device:
            return x
        if x.device.type != "cpu":
            raise ModelError(
                f"{name} must be on the surrogate's device {self.device} (Surrogate.to) or on the CPU, got device "
                f"{x.device}"
            )
        return x.to(self.device)

    # ------------------------------------------------------------------ inputs
    def check_params(self, params: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Validate ``params`` and return them as ``[B, n_cells, 7]`` in the simulation dtype.

        Null and rigid cells' rows are ignored (not checked, replaced by neutral values).

        Raises:
            ModelError: not numbers, wrong shape, on a device that is neither the CPU nor the surrogate's, non-finite
                values, ``E_x <= 0`` or ``E_s <= 0`` or
                negative transmission factors in an active cell (named by index and parameter), factors 0 in every
                direction an active cell has links in, also where only the
                simulation's dtype makes them so (float32: ``E_s = 1e39`` is inf, ``E_x = 1e-50`` is 0).
        """
        try:
            p = _tensor(params)
        except (TypeError, ValueError, RuntimeError):  # text, None, a ragged list: torch's "invalid data type 'str'"
            raise ModelError(
                f"params must be an array or tensor of numbers [B, {self.n}, {N_PARAMS}], got "
                f"{type(params).__name__} {_short(params)}"
            ) from None
        p = self._on_device(p, "params")
        if p.ndim == 2:
            p = p[None]
        if p.ndim != 3 or p.shape[1:] != (self.n, N_PARAMS):
            raise ModelError(
                f"params must be [B, {self.n}, {N_PARAMS}] (or [{self.n}, {N_PARAMS}]), got {list(p.shape)}"
            )
        if not p.is_floating_point():
            raise ModelError(f"params must be floating point, got {p.dtype}")
        given = p
        p = p.to(self.dtype)
        with torch.no_grad():
            # the values given first, then as the simulation's dtype holds them (1e39 is inf in float32)
            for q, cast in ((given, False), (p, True))[: 1 if p.dtype == given.dtype else 2]:  # once without a cast
                act = q[:, self.active]
                bad = ~torch.isfinite(act)
                bad[..., :2] |= act[..., :2] <= 0
                bad[..., 2:] |= act[..., 2:] < 0
                if bool(bad.any()):
                    b, i, j = (int(x) for x in torch.nonzero(bad)[0])
                    cell = int(torch.nonzero(self.active)[i])
                    where = f"params[{b}, {cell}, {j}] ({PARAM_NAMES[j]}) of active cell {cell}"
                    if cast:
                        raise ModelError(
                            f"{where}: got {float(given[b, cell, j]):g}, which {self.config.dtype} (the simulation's "
                            f"dtype, configs/sim.yaml) holds as {float(act[b, i, j])}; it must be finite and "
                            f"{'> 0' if j < 2 else '>= 0'} there"
                        )
                    raise ModelError(
                        f"{where} must be finite and {'> 0' if j < 2 else '>= 0'}, got {float(act[b, i, j])}"
                    )
                # a cell with links whose factors are 0 in every direction it has links in transmits nothing: the
                # cells behind it and the rigid compartment drove on through it (all factors 0: 2.3 m in 150 ms at
                # 56 km/h, the sensors never slowed)
                dirs = self.link_dirs[self.active]
                mute = ((act[..., 2:] == 0) | ~dirs).all(-1) & dirs.any(-1)
                if bool(mute.any()):
                    b, i = (int(x) for x in torch.nonzero(mute)[0])
                    cell = int(torch.nonzero(self.active)[i])
                    names = [PARAM_NAMES[2 + d] for d in torch.nonzero(dirs[i]).flatten().tolist()]
                    raise ModelError(
                        f"params[{b}, {cell}, 2:7] (the transmission factors {', '.join(PARAM_NAMES[2:])}) of active "
                        f"cell {cell}: {', '.join(names)}, the directions it has links in, are all 0"
                        f"{f' as {self.config.dtype} holds them' if cast else ''}, so it would transmit nothing and "
                        "let the cells behind it pass through it; give one of them a factor > 0 (the factors are "
                        "relative shares, summing to one in the parameter space)"
                    )
        neutral = torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=self.dtype, device=self.device)
        return torch.where(self.active[None, :, None], p, neutral)

    def link_props(self, params: torch.Tensor) -> LinkProps:
        """Element properties from checked ``params [B, n, 7]`` (differentiable)."""
        cfg = self.config
        B = params.shape[0]
        e_x, e_s = params[..., 0], params[..., 1]
        f_c = e_s / self.stroke  # [B, n] crush force [N]
        k_max = self.k_max
        k_c = (f_c * f_c / (2.0 * e_x)).clamp(max=k_max)  # [B, n] elastic stiffness [N/m]
        f = params[..., 2:]
        # Transmission factors are relative shares: the principal direction carries the full crush
        # strength, every other direction f_d / f_max of it (f_max > 0 wherever a cell has links).
        rel = f / f.amax(dim=-1, keepdim=True).clamp_min(_EPS_F)
        factor = rel.reshape(B, self.n * 5)[:, self.param_index] * self.share  # [B, L]
        yield_c = f_c[:, self.src] * factor
        # Contact across a gap engages the softer partner: a gap link pushes at most at the crush
        # strength of the cell it lands on (the rigid compartment never limits).
        f_dst = torch.where(self.dst_rigid, torch.full_like(f_c, float("inf"))[:, self.dst], f_c[:, self.dst])
        yield_c = torch.where(self.is_gap, torch.minimum(yield_c, f_dst), yield_c)
        k_raw = k_c[:, self.src] * factor
        kd_raw = (cfg.densification_factor * k_raw).clamp(max=k_max)
        cap = self.cap_link
        if self.stability_caps:
            k = k_raw * cap / (k_raw + cap) + _EPS_K * cap
            k_dense = kd_raw * cap / (kd_raw + cap) + _EPS_K * cap
        else:  # 1 N/m for idle links keeps f / k finite; they carry no force (yield force 0)
            k, k_dense = torch.where(k_raw > 0, k_raw, 1.0), torch.where(kd_raw > 0, kd_raw, 1.0)

        # the constants as tensors of the run's dtype: two Python floats make a tensor of torch's default dtype, so a
        # float64 run took them rounded to float32 (and changed with torch.set_default_dtype)
        def const(x: float) -> torch.Tensor:
            return torch.tensor(x, dtype=self.dtype, device=self.device)

        t_ratio = torch.where(self.is_axial, const(cfg.tension_ratio), const(1.0))
        yield_t = torch.where(self.is_gap, torch.zeros_like(yield_c), yield_c * t_ratio)
        zeta = torch.where(self.is_gap, const(cfg.contact_damping_ratio), const(cfg.link_damping_ratio))
        damping = 2.0 * zeta * torch.sqrt(k * self.m_pair)
        e_s_cell = torch.where(self.has_links, e_s, torch.full_like(e_s, float("inf")))
        # Springback relief (module doc): the excess share k_raw / (k_raw + cap) = 1 - k_eff / k_raw of a
        # yielded link's force decays by exp(-dt / tau) per unloading step.
        a = (1.0 - np.exp(-self.dt / cfg.springback_tau)) if cfg.springback_relief else 0.0
        relax = 1.0 - a * k_raw / (k_raw + cap)
        relax_dense = 1.0 - a * kd_raw / (kd_raw + cap)
        return LinkProps(yield_c, yield_t, k, k_dense, damping, relax, relax_dense, e_s_cell)

    def scenario_tensors(
        self,
        batch: int,
        scenario: CrashScenario | None = None,
        speed: torch.Tensor | None = None,
        overlap: torch.Tensor | None = None,
        side: torch.Tensor | None = None,
    ) -> WallProps:
        """Wall contact for ``batch`` rows from a scenario or per-row tensors.

        Args:
            batch: ``B``.
            scenario: defaults for any tensor not given.
            speed: ``[B]`` impact speed [m/s], a scenario's range (``MIN_SPEED_KMH`` to ``MAX_SPEED_KMH``);
            overlap: ``[B]`` in (0, 1]; side: ``[B]`` +1 left, -1 right.

        Raises:
            ModelError: a ``batch`` that is no integer >= 0, tensors of the wrong shape, out of range or not on the
                CPU, a scenario that is no :class:`CrashScenario`.
            ConfigError: a scenario value of the wrong type or out of range, naming the key.
        """
        try:  # -1 failed inside torch ("numel: integer multiplication overflow"), 2.5 in expand()
            rows = None if isinstance(batch, bool) else operator.index(batch)
        except TypeError:
            rows = None
        if rows is None or rows < 0:
            raise ModelError(f"batch must be a number of rows >= 0 (an integer), got {_short(batch)}")
        return self._wall(rows, checked_scenario(scenario), speed, overlap, side)

    def _wall(self, batch, scenario, speed, overlap, side) -> WallProps:
        """:meth:`scenario_tensors` of a checked scenario (:meth:`prepare` checks it once)."""
        unit = {"speed": "[m/s]", "overlap": "[-]", "side": "(+1 left, -1 right)"}

        def refuse(name, bad, x, what):  # names the tensor, the first bad row and its value
            if bool(bad.any()):
                row = int(torch.nonzero(bad)[0])
                raise ModelError(f"'{name}' {what}, got {float(x[row]):g} in row {row}")

        def vec(x, default, name):
            if x is None:
                if scenario is None:
                    raise ModelError(f"give a scenario or the per-batch tensor '{name}'")
                x = default
            try:  # real numbers: a complex one was cast to its real part (only torch warned), a bool taken as 1 or 0
                if not _is_real(x):
                    raise TypeError
                x = _tensor(x, dtype=self.dtype)
            except (TypeError, ValueError, RuntimeError):  # text, None in a list: torch's "invalid data type"
                raise ModelError(
                    f"'{name}' must be a number or a tensor of numbers {unit[name]}, got {_short(x)}"
                ) from None
            x = self._on_device(x, f"'{name}'")
            if x.ndim == 0:
                x = x.expand(batch)
            if x.shape != (batch,):
                raise ModelError(f"'{name}' must be of shape [{batch}] (one value per batch row), got {list(x.shape)}")
            refuse(name, ~torch.isfinite(x), x, "must be finite")
            return x

        sp = vec(speed, None if scenario is None else scenario.speed, "speed")
        ov = vec(overlap, None if scenario is None else scenario.overlap, "overlap")
        sd = vec(side, None if scenario is None else scenario.side_sign, "side")
        with torch.no_grad():
            low, top = MIN_SPEED_KMH * KMH, MAX_SPEED_KMH * KMH  # a scenario's range (CrashScenario.validate)
            refuse(
                "speed",
                (sp < low) | (sp > top),
                sp,
                f"must be in [{low:g}, {top:g}] m/s (a scenario's speed_kmh in [{MIN_SPEED_KMH:g}, "
                f"{MAX_SPEED_KMH:g}] km/h)",
            )
            refuse("overlap", (ov <= 0) | (ov > 1), ov, "must be in (0, 1]")
            refuse("side", sd.abs() != 1, sd, "must be +1 (left) or -1 (right)")
        frac = barrier_fraction(self.lo_y, self.hi_y, self.width, ov, sd, centre_y=self.centre_y) * self.exposed
        covered = frac > 0
        if not bool(covered.any(dim=1).all()):
            rows = torch.nonzero(~covered.any(dim=1)).flatten().tolist()
            raise ModelError(
                f"the barrier covers no cell front in batch rows {rows[:5]} (overlap {ov[rows[0]].item():g}, side "
                f"{'left' if sd[rows[0]].item() > 0 else 'right'}): the overlap is narrower than the vehicle's "
                "front cells; use a larger overlap"
            )
        first = torch.where(covered, self.front_x, torch.full_like(frac, float("inf"))).amin(dim=1, keepdim=True)
        gap = torch.where(covered, self.front_x - first, torch.zeros_like(frac))
        k_raw = (self.config.wall_stiffness * self.front_area * frac).clamp(max=self.k_max)
        capped = k_raw * self.cap_wall / (k_raw + self.cap_wall) if self.stability_caps else k_raw
        k = torch.where(covered, capped, torch.zeros_like(frac))
        damping = 2.0 * self.config.wall_damping_ratio * torch.sqrt(k * self.mass)
        return WallProps(k, damping, gap, covered, frac, sp, ov, sd)

    # ------------------------------------------------------------------ run
    def run(
        self,
        params: torch.Tensor | np.ndarray,
        scenario: CrashScenario | None = None,
        *,
        speed: torch.Tensor | None = None,
        overlap: torch.Tensor | None = None,
        side: torch.Tensor | None = None,
        duration: float | None = None,
        sensors: list[str] | None = None,
        probe_cells: list[int] | np.ndarray | torch.Tensor | None = None,
        record_cells: Literal["series", "final", "none"] = "series",
        backend: Backend | None = None,
        cells_at: float | None = None,
    ) -> SimResult:
        """Simulate ``B`` crashes.

        Args:
            params: ``[B, n_cells, 7]`` (or ``[n_cells, 7]``) cell parameters.
            scenario: load case (speed, overlap, side, duration, sensors); per-row tensors override it.
            speed, overlap, side: optional ``[B]`` tensors (m/s, fraction, +1 left / -1 right).
            duration: simulated window [s], a whole number of output steps; overrides the scenario's (default: the
                scenario's, without one 0.150).
            sensors: sensor names to record (default: the scenario's list, else all).
            probe_cells: record these cells' acceleration and velocity instead of the sensors (named
                ``cell<i>`` in the result), e.g. to study sensor placement; indices into the cell model, of cells
                with material (a null cell is refused). Not together with ``sensors`` (a scenario's list is
                replaced).
            record_cells: per-cell energy series (``series``), final values only, or none.
            backend: ``torch`` (differentiable reference), ``numba`` (fast no-grad), ``adjoint`` (the
                ``numba`` result with sensor velocities differentiable by a compiled reverse pass,
                :mod:`marlcrash.sim.adjoint`), ``cuda_graph`` (the ``torch`` steps replayed as a CUDA graph per
                output interval: a surrogate on a CUDA device, :meth:`to`, no gradient), ``auto`` (where gradients
                are required, of ``params`` or of a ``speed``, ``overlap`` or ``side`` that requires grad, ``torch``;
                else ``numba`` on the CPU, and on a GPU ``cuda_graph`` up to ``GRAPH_MAX_BATCH`` rows, ``torch``
                above); default from the config.
            cells_at: time [s] of the ``final`` per-cell energies, ``cell_plastic`` and ``saturated``, an
                output sample's (default: the end), e.g. a compared window's end when the simulation runs on
                past it to filter the pulse over a longer record.

        Returns:
            A :class:`SimResult`.

        Raises:
            ModelError: an unknown backend or ``record_cells``, ``numba`` or ``adjoint`` on a CUDA device,
                ``cuda_graph`` on the CPU or where gradients are required, ``cells_at`` outside the simulated time
                or between samples, ``sensors`` and ``probe_cells`` both given.
            ConfigError: a scenario value of the wrong type or out of range (one built in Python), naming the key.
        """
        if backend not in (None, *BACKENDS):
            raise ModelError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
        if record_cells not in ("series", "final", "none"):
            raise ModelError(f"record_cells must be one of series, final, none; got {record_cells!r}")
        if not self.stability_caps:
            raise ModelError(
                "this Surrogate was built with stability_caps=False: no explicit step is stable with the raw "
                "stiffnesses; run it with marlcrash.sim.implicit.run_implicit"
            )
        p, props, wall, n_out, sensor_idx = self.prepare(
            params, scenario, speed, overlap, side, duration, sensors, probe_cells
        )
        snap = n_out - 1
        if cells_at is not None:
            at = _seconds(cells_at, "cells_at") / self.output_dt
            if not (np.isfinite(at) and abs(at - round(at)) <= 1e-6 * max(1.0, at) and 0 <= round(at) < n_out):
                raise ModelError(
                    f"cells_at must be an output sample's time in [0, {(n_out - 1) * self.output_dt:.6g}] s "
                    f"(every {self.output_dt:.6g} s), got {cells_at}"
                )
            snap = round(at)
        backend = backend or self.config.backend
        # gradients are required by the parameters or by a scenario tensor (speed, overlap, side)
        graded = torch.is_grad_enabled() and (p.requires_grad or wall.speed.requires_grad or wall.k.requires_grad)
        on_cpu = self.device.type == "cpu"
        if backend == "auto":
            graph = p.shape[0] <= GRAPH_MAX_BATCH
            backend = "torch" if graded else ("numba" if on_cpu else ("cuda_graph" if graph else "torch"))
        if backend in ("numba", "adjoint") and not on_cpu:
            raise ModelError(
                f"backend {backend!r} runs on the CPU only; this surrogate is on {self.device} (Surrogate.to): use "
                "backend 'torch', 'cuda_graph' or 'auto' there, or move it back with .to('cpu')"
            )
        if backend == "cuda_graph":
            if on_cpu:
                raise ModelError(
                    "backend 'cuda_graph' runs on a CUDA device: move the surrogate there with .to('cuda'), or use "
                    "'numba' (or 'auto') on the CPU"
                )
            if graded:
                raise ModelError(
                    "backend 'cuda_graph' gives no gradients (a replayed graph records no autograd history) and "
                    "these inputs require grad: use backend 'torch', or run under torch.no_grad()"
                )
            return self._run_torch(props, wall, n_out, sensor_idx, record_cells, snap=snap, graphed=True)
        if backend == "adjoint":
            from marlcrash.sim.adjoint import run_adjoint

            return run_adjoint(self, props, wall, n_out, sensor_idx, record_cells, snap)
        if backend == "numba":
            from marlcrash.sim.kernels import run_numba

            return run_numba(self, props, wall, n_out, sensor_idx, record_cells, snap=snap)
        return self._run_torch(props, wall, n_out, sensor_idx, record_cells, snap=snap)

    def prepare(
        self,
        params: torch.Tensor | np.ndarray,
        scenario: CrashScenario | None = None,
        speed: torch.Tensor | None = None,
        overlap: torch.Tensor | None = None,
        side: torch.Tensor | None = None,
        duration: float | None = None,
        sensors: list[str] | None = None,
        probe_cells=None,
    ) -> tuple:
        """Checked inputs of one batched run (the arguments of :meth:`run`).

        Returns:
            ``(params [B, n, 7], LinkProps, WallProps, n_out, (sensor names, [K] cell indices))``.

        Raises:
            ModelError: ``params`` of no batch rows (``B = 0``), besides what :meth:`run` names.
        """
        p = self.check_params(params)
        if p.shape[0] == 0:  # an empty result, whose balance error failed inside torch ("max(): ... numel() == 0")
            raise ModelError(
                f"params has no batch rows (B = 0): give at least one parameter set [B >= 1, {self.n}, {N_PARAMS}]"
            )
        scenario = checked_scenario(scenario)
        if scenario is not None and steps_per_output(scenario.output_dt, self.config.substeps) != self.substeps:
            raise ModelError(
                f"scenario output step {scenario.output_dt} s differs from the surrogate's {self.output_dt} s; "
                "build the Surrogate with output_dt=scenario.output_dt"
            )
        dur = duration if duration is not None else (scenario.duration if scenario is not None else 0.150)
        seconds = _seconds(dur, "duration")
        steps = seconds / self.output_dt
        if not (np.isfinite(steps) and steps >= 0.5 and abs(steps - round(steps)) <= 1e-6 * steps):
            raise ModelError(
                f"duration must be > 0 s and a whole number of {self.output_dt:.6g} s output steps, got {dur}"
            )
        if seconds > MAX_RUN_DURATION_S:  # 150 (ms meant) asked 43.7 TiB of numpy
            raise ModelError(
                f"duration must be at most {MAX_RUN_DURATION_S:g} s (MAX_RUN_DURATION_S: a crash window with room for "
                f"a filter margin), got {seconds:g} s; durations are in seconds (0.15 for 150 ms)"
            )
        n_out = round(steps) + 1
        if sensors is not None and probe_cells is not None:  # the named sensors were dropped without a word
            raise ModelError(
                f"give sensors or probe_cells, not both: sensors {_short(sensors)} would not be recorded, the "
                f"probe_cells {_short(probe_cells)} are recorded instead of sensors"
            )
        names = sensors if sensors is not None else (list(scenario.sensors) if scenario is not None else [])
        # names from the scenario: the message says where they came from (a registered file's key)
        where = f" (scenario {scenario.name!r}, key 'sensors')" if sensors is None and scenario is not None else ""
        sensor_idx = self._sensor_index(names, where) if probe_cells is None else self._probe_index(probe_cells)
        return (
            p,
            self.link_props(p),
            self._wall(p.shape[0], scenario, speed, overlap, side),
            n_out,
            sensor_idx,
        )

    def _sensor_index(self, names: list[str], where: str = "") -> tuple[list[str], torch.Tensor]:
        # one name was split into letters ("unknown sensors ['t', 'u', ...]"); 3 or [["tunnel"]] failed inside set()
        if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
            raise ModelError(f"sensors must be a list of sensor names, got {_short(names)}")
        if len(set(names)) != len(names):  # as a scenario file's list: the same signal twice
            raise ModelError(f"duplicate sensor names in {list(names)}")
        all_names = list(self.cells.sensor_names)
        if not names:
            names = all_names
        missing = [s for s in names if s not in all_names]
        if missing:
            raise ModelError(f"unknown sensors {missing}{where}; the cell model has {all_names}")
        idx = [int(self.cells.sensor_cell[all_names.index(s)]) for s in names]
        return list(names), torch.tensor(idx, dtype=torch.int64, device=self.device)

    def _probe_index(self, cells) -> tuple[list[str], torch.Tensor]:
        try:  # [[0, 1], [2]] failed inside numpy ("inhomogeneous shape")
            raw = np.asarray(cells.detach().cpu() if isinstance(cells, torch.Tensor) else cells).reshape(-1)
        except (TypeError, ValueError):
            raise ModelError(f"probe_cells must be whole cell indices in [0, {self.n}), got {_short(cells)}") from None
        if raw.dtype.kind not in "iu" and not (
            raw.dtype.kind == "f" and np.isfinite(raw).all() and (raw == np.round(raw)).all()
        ):
            # 2.7 was truncated to cell 2
            raise ModelError(f"probe_cells must be whole cell indices in [0, {self.n}), got {raw.tolist()}")
        idx = torch.as_tensor(raw.astype(np.int64))
        if idx.numel() == 0 or int(idx.min()) < 0 or int(idx.max()) >= self.n:
            raise ModelError(f"probe_cells must be cell indices in [0, {self.n}), got {idx.tolist()}")
        null = [int(i) for i in idx if self.cells.is_null[int(i)]]
        if null:  # an inert node: it "recorded" the impact speed for the whole crash
            raise ModelError(
                f"probe_cells must be cells with material: cell {null[0]} is a null cell (empty space, no links or "
                f"contact, it keeps the impact speed); got {idx.tolist()}"
            )
        return [f"cell{int(i)}" for i in idx], idx.to(self.device)

    def _step(
        self, props, wall, f_el, o, plastic, yielded, s, ds, v_wall, tangent: bool = False, branchless: bool = False
    ) -> _Step:
        """One step's element forces for the node increments ``ds [B, n]`` (``s`` the travel after them).

        Pure: returns the updated link state instead of writing it. ``v_wall`` is the velocity the wall
        damping sees (the explicit step's start velocity, ``ds / dt`` in the implicit study). With ``tangent``
        it also returns each element's force derivative by its deformation increment (stiffness plus damping
        ``/ dt`` where elastic, 0 while yielding, open or not pushing), for the implicit study's linear solve.
        ``branchless`` applies the saturation crossing's correction to every link (zero where no cell crosses) instead
        of asking the device whether any crosses: the same numbers without a host synchronisation, as a captured CUDA
        graph needs.
        """
        dt, src, dst, is_gap, relief = self.dt, self.src, self.dst, self.is_gap, self.config.springback_relief
        zl = torch.zeros_like(f_el)
        dd = ds[:, dst] - ds[:, src]
        sat = (plastic >= props.e_s)[:, src]
        k = torch.where(sat, props.k_dense, props.k)
        # A link with a zero transmission share is absent: it stays at zero force after saturation too.
        dense = sat & (props.yield_c > 0)
        yc = torch.where(dense, torch.full_like(k, _BIG), props.yield_c)
        yt = torch.where(dense & ~is_gap, torch.full_like(k, _BIG), props.yield_t)
        z = f_el / k - o + dd
        f_tr = k * torch.where(is_gap, z.clamp_min(0.0), z)
        o = torch.where(is_gap, (-z).clamp_min(0.0), zl)
        f_ret = torch.minimum(torch.maximum(f_tr, -yt), yc)
        w_pl = f_ret * (f_tr - f_ret) / k
        if relief:
            yielded = yielded | (f_tr != f_ret)
            unload = yielded & (f_ret * f_el > 0.0) & (f_ret.abs() < f_el.abs())
            f_new = torch.where(unload, f_ret * torch.where(sat, props.relax_dense, props.relax), f_ret)
            w_pl = w_pl + 0.5 * (f_ret * f_ret - f_new * f_new) / k
        else:
            f_new = f_ret
        plastic_new = plastic.index_add(1, src, w_pl)
        # damping on the elastic part of this step's deformation (module doc: continuous at every switch)
        f_tot = f_new + props.damping * (f_ret - f_el) / (k * dt)
        k_t = None
        if tangent:
            elastic = (f_tr == f_ret) & (~is_gap | ((z > 0.0) & (f_tot > 0.0)))
            k_t = torch.where(elastic, k + props.damping / dt, zl)
        f_tot = torch.where(is_gap, f_tot.clamp_min(0.0), f_tot)
        # saturation within the step (module doc): the part of the step past E_s is densified
        cross = (plastic_new >= props.e_s) & (plastic < props.e_s)  # [B, n]
        if branchless or bool(cross.any()):
            gain = plastic_new - plastic
            phi = torch.where(cross, (plastic_new - props.e_s) / torch.where(cross, gain, 1.0), 0.0)[:, src]
            live = cross[:, src] & (props.yield_c > 0) & (~is_gap | (f_new > 0))
            # this step's force change: k dd while elastic, 0 while yielding throughout, and the elastic part where the
            # link started or stopped yielding within the step (0 was taken there: the force jumped by that part, with
            # the step the crossing fell in, up to 0.015 m/s in a sensor's velocity)
            el = f_new - f_el
            df = torch.where(live, phi * (props.k_dense * dd - el), zl)
            dv = torch.where(live, phi * props.damping * (dd - el / k) / dt, zl)
            f_new, f_tot = f_new + df, f_tot + df + dv
            plastic_new = torch.where(cross, props.e_s, plastic_new)
            k = torch.where(cross[:, src], props.k_dense, k)  # the dense elastic energy from now on
        pen = s - wall.gap
        in_contact = wall.covered & (pen > 0)
        fw_raw = wall.k * pen + wall.damping * torch.minimum(v_wall, pen / dt)
        fw = torch.where(in_contact, fw_raw.clamp_min(0.0), torch.zeros_like(pen))
        kw_t = torch.where(in_contact & (fw_raw > 0.0), wall.k + wall.damping / dt, 0.0) if tangent else None
        return _Step(dd, o, yielded, plastic_new, k, f_new, f_tot, pen, in_contact, fw, k_t, kw_t)

    def _node_force(self, st: _Step) -> torch.Tensor:
        """``[B, n]`` net force on each cell of a step [N]: link forces (``+`` at the source, ``-`` at the
        destination) less the wall force."""
        return torch.zeros_like(st.fw).index_add(1, self.src, st.f_tot).index_add(1, self.dst, -st.f_tot) - st.fw

    def _advance(self, props, wall, z: dict, step_in, increment=None, theta=1.0, branchless=False) -> dict:
        """One integration step of the state ``z`` (:meth:`_run_torch`): the changed entries, new tensors."""
        dt, m = self.dt, self.mass
        s, v = z["s"], z["v"]
        u = None
        if increment is None:
            ds, v_wall = dt * v, v
        else:
            ds, u = increment(props, wall, z["f_el"], z["o"], z["plastic"], z["yielded"], s, v, z["force"])
            v_wall = ds / dt
        s = s + ds
        st = self._step(
            props, wall, z["f_el"], z["o"], z["plastic"], z["yielded"], s, ds, v_wall, branchless=branchless
        )
        force = self._node_force(st)
        # explicit: symplectic Euler; the implicit study: theta of the end and 1 - theta of the start forces
        if increment is None:
            acc = force / m
        elif u is None:
            acc = ((1.0 - theta) * z["force"] + theta * force) / m
        else:  # linearly implicit: the velocity change of the linear solve
            acc = u / dt
        # Work with the same discrete forces (trapezoid): closes the leapfrog balance exactly.
        fbar = 0.5 * (z["f_prev"] + st.f_tot)
        fwbar = 0.5 * (z["fw_prev"] + st.fw)
        return {
            "s": s,
            "v": v + dt * acc,
            "v_start": v,
            "force": force,
            "f_el": st.f_new,
            "o": st.o,
            "yielded": st.yielded,
            "plastic": st.plastic,
            "f_prev": st.f_tot,
            "fw_prev": st.fw,
            "work": z["work"] + fbar * st.dd,
            "passed": z["passed"] + fbar * (step_in - ds[:, self.dst]),
            "w_work": z["w_work"] + fwbar * ds,
            "w_in": z["w_in"] + fwbar * step_in,
            "stored_l": 0.5 * st.f_new * st.f_new / st.k,
            "stored_w": torch.where(st.in_contact, 0.5 * wall.k * st.pen * st.pen, torch.zeros_like(st.pen)),
        }

    def _capture_interval(self, props, wall, z: dict, step_in):
        """A function that advances ``z`` in place by one output interval (``substeps`` explicit steps) by replaying a
        CUDA graph captured here; ``z``'s tensors are the graph's fixed inputs and outputs.

        The steps are :meth:`_advance`'s, branchless (no host synchronisation may fall inside a capture), so a replay
        gives the eager loop's numbers. Warmed up on a side stream first, as ``torch.cuda.graphs`` asks.
        """

        def interval():
            w = z
            for _ in range(self.substeps):
                w = {**w, **self._advance(props, wall, w, step_in, branchless=True)}
            for key, value in w.items():
                z[key].copy_(value)

        saved = {key: value.clone() for key, value in z.items()}
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            interval()  # warm-up: it advanced z, put back below
        torch.cuda.current_stream(self.device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            interval()
        for key, value in saved.items():
            z[key].copy_(value)
        return graph.replay

    def _run_torch(
        self,
        props: LinkProps,
        wall: WallProps,
        n_out: int,
        sensor_idx,
        record_cells,
        increment=None,
        theta=1.0,
        snap: int | None = None,
        graphed: bool = False,
    ) -> SimResult:
        """The explicit reference path (symplectic Euler); ``increment`` swaps in the implicit study's step.

        ``snap``: the output sample of the ``final`` per-cell energies and the plastic work per cell (default:
        the last).

        ``graphed`` (explicit, on a CUDA device, no gradient): the steps of one output interval are captured once as a
        CUDA graph and replayed (:meth:`_capture_interval`), the same kernels without the Python and launch cost of
        each (``backend="cuda_graph"``).

        ``increment(props, wall, f_el, o, plastic, yielded, s, v, force)`` returns a step's node increments
        ``ds``; the velocity update then applies ``(1 - theta)`` of the start and ``theta`` of the end forces
        (:func:`marlcrash.sim.implicit.run_implicit`).
        """
        names, sidx = sensor_idx
        B, n = props.k.shape[0], self.n
        sub = self.substeps
        src, dst = self.src, self.dst
        m_ke = self.mass_ke
        zl = props.k.new_zeros((B, self.L))
        zn = props.k.new_zeros((B, n))
        v = wall.speed[:, None].expand(B, n).clone()
        z = {  # the state a step advances (_advance)
            "s": zn.clone(),
            "v": v,
            "v_start": v.clone(),
            "force": zn.clone(),
            "f_el": zl.clone(),
            "o": self.gap.expand(B, -1).clone(),
            "yielded": torch.zeros((B, self.L), dtype=torch.bool, device=self.device),  # springback relief
            "plastic": zn.clone(),
            "f_prev": zl.clone(),
            "fw_prev": zn.clone(),
            "work": zl.clone(),
            "passed": zl.clone(),
            "w_work": zn.clone(),
            "w_in": zn.clone(),
            "stored_l": zl.clone(),
            "stored_w": zn.clone(),
        }
        e0 = 0.5 * (m_ke * v * v).sum(dim=1)
        step_in = wall.speed[:, None] * self.dt  # [B, 1] moving-frame drift per step

        rec: dict[str, list[torch.Tensor]] = {k: [] for k in ("vel", "s", "vc", "pen", "ke", "st", "ab", "pl")}
        cells_rec: dict[str, list[torch.Tensor]] = {"in": [], "ab": [], "tr": []}
        snap = n_out - 1 if snap is None else snap
        at_snap: dict[str, torch.Tensor] = {}  # plastic work at the snapshot
        cells_at_snap: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}  # record_cells="final"

        def record(vel, ke):  # copies only: a CUDA graph's replay overwrites the state tensors in place
            s, plastic, stored_l, stored_w = z["s"], z["plastic"], z["stored_l"], z["stored_w"]
            work, w_work = z["work"], z["w_work"]
            # weighted by coverage: a cell front the barrier edge clips is held by a wall as soft as that fraction
            pen = torch.where(wall.covered, wall.coverage * (s - wall.gap).clamp_min(0.0), zn).amax(dim=1)
            st = stored_l.sum(dim=1) + stored_w.sum(dim=1)
            rec["vel"].append(vel[:, sidx])
            rec["s"].append(s[:, self.comp].clone())
            rec["vc"].append(vel[:, self.comp].clone())
            rec["pen"].append(pen)
            rec["ke"].append(ke)
            rec["st"].append(st)
            rec["ab"].append(work.sum(dim=1) + w_work.sum(dim=1) - st)
            rec["pl"].append(plastic.sum(dim=1))
            ledgers = (work, z["passed"], stored_l, w_work, z["w_in"], stored_w, src, dst)
            if record_cells == "series":
                ci, ca, ct = cell_energies(*ledgers)
                cells_rec["in"].append(ci)
                cells_rec["ab"].append(ca)
                cells_rec["tr"].append(ct)
            if len(rec["vel"]) - 1 == snap:
                at_snap["plastic"] = plastic.clone()
                if record_cells == "final":
                    cells_at_snap["cells"] = cell_energies(*ledgers)

        def record_output():
            if increment is None:  # leapfrog: mid-step velocity, kinetic energy m v v_new / 2
                v0, v1 = z["v_start"], z["v"]
                record(0.5 * (v0 + v1), 0.5 * (m_ke * v0 * v1).sum(dim=1))
            else:  # implicit study: end-of-step velocity and kinetic energy
                record(z["v"], 0.5 * (m_ke * z["v"] * z["v"]).sum(dim=1))

        record(v, e0)
        if graphed:
            replay = self._capture_interval(props, wall, z, step_in)
            for _ in range(n_out - 1):
                replay()
                record_output()
        else:
            for step in range(1, (n_out - 1) * sub + 1):
                z.update(self._advance(props, wall, z, step_in, increment, theta))
                if step % sub == 0:
                    record_output()

        stack = lambda key: torch.stack(rec[key], dim=-1)  # noqa: E731
        if record_cells == "final":
            ci, ca, ct = cells_at_snap["cells"]
            cell_in, cell_ab, cell_tr = ci[..., None], ca[..., None], ct[..., None]
        elif record_cells == "series":
            cell_in, cell_ab, cell_tr = (torch.stack(cells_rec[k], dim=-1) for k in ("in", "ab", "tr"))
        else:
            cell_in = cell_ab = cell_tr = zn.new_zeros((B, n, 0))
        comp = stack("s")
        return SimResult(
            time=torch.arange(n_out, dtype=self.dtype, device=self.device) * self.output_dt,
            sensor_names=names,
            velocity=stack("vel"),
            compartment_displacement=comp,
            compartment_velocity=stack("vc"),
            crush=comp - stack("pen"),
            kinetic=stack("ke"),
            stored=stack("st"),
            absorbed=stack("ab"),
            plastic=stack("pl"),
            initial=e0,
            cell_input=cell_in,
            cell_absorbed=cell_ab,
            cell_transmitted=cell_tr,
            cell_plastic=at_snap["plastic"],
            saturated=at_snap["plastic"] >= props.e_s,
            **load_case(wall),
        )
