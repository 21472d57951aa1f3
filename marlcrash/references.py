"""Reference pulses for calibration (DESIGN 1.4, 1.5, 4 "Reference signals").

A reference is the velocity per sensor that the surrogate is calibrated to, on the
surrogate's output grid (``T`` samples at the scenario's output rate, 2 kHz), in the
surrogate's sign convention (forward speed, starting at the impact speed). Three kinds:

- ``twin``: the same :class:`CellModel` with a hidden, seeded perturbation per
  sub-assembly, simulated as the "real test". Per environment and sub-assembly, ``E_x``
  and ``E_s`` are multiplied by ``exp(spread * N(0, 1))`` (log-normal) factors; the five
  transmission factors of its cells are multiplied by per-direction log-normal factors
  and renormalised to sum one (fixed zeros stay zero, x no lower than a lateral factor where
  feasible). Optional bounds clip the ``E`` factors so the ground truth stays reachable by the
  agents; the transmission factors are not clipped, and a baseline's search box (``box_radius``)
  is not a bound of the draw: :class:`~marlcrash.calibrate.problem.CalibrationProblem` warns when
  a truth lies outside it. The ground-truth parameters are returned for evaluation.
- ``cross_fidelity``: a uniform-discretization model of the same vehicle (the calibrated car's own variant, the env's
  ``vehicle_seed``, for a null entry of ``vehicle_seeds``; another seeded variant for a seed) is simulated as the
  reference for the optimized model, with its own mass floor and
  step (:class:`CrossFidelityConfig`: its cells are too light for the calibrated model's mass scaling); sensors
  are matched by name. Deterministic per (vehicle seed, scenario), so results are cached.
- ``file``: measured pulses read with :func:`marlcrash.pulse.io.read_pulse` (CSV or
  ISO-MME), CFC-filtered, time-zero aligned, resampled to the output rate and integrated
  to velocity (:func:`marlcrash.pulse.signal.prepare_velocity`), starting at the impact
  speed of the file's scenario. Loaded once, drawn per episode by weight. Time zero is the
  file's t = 0 by default (``time_zero: file``): the first contact, as the simulation's t = 0
  (ISO-MME's T0; lab exports put pre-trigger samples at negative times, and their mean is
  subtracted as the channel's zero level). ``time_zero: threshold`` finds the pulse's onset
  instead, for records whose clock is not aligned to contact
  (:func:`marlcrash.pulse.signal.find_onset`: each channel's zero level and noise measured on
  its samples before the record's time zero, whatever the clock; the pulse detected on the CFC-filtered
  channel against 0.5 g or 5x that noise; its onset the start of a line fitted to it); a
  channel far from the front (the tunnel) starts milliseconds after the contact, and one with
  too little pre-trigger data is named in a warning. The file must be filtered with the
  compared signal's class (``cfc`` = ``compare_cfc``, or null when filtered already), and a
  record whose velocity climbs above the impact speed (decelerations recorded positive)
  is refused, naming ``sign``. A record usually goes on past the window and is filtered over all of
  it, so the filter's end handling never reaches the window's last samples; candidates compared with
  it are simulated up to ``compare_margin`` (10 ms) longer, as far as the record reaches, filtered and
  cut at the window alike (:attr:`ReferenceBatch.margin`; without it a candidate at the test's own
  parameters missed it by a DFD of up to 0.24 m/s over 150 ms and 3.3 m/s over 30 ms). Compared unfiltered
  (``compare_cfc: null``) the margin is one sample, the one the acceleration's central difference at the window's
  last sample needs (a backward difference there missed by up to 0.62 m/s over 30 ms).

One :class:`ReferenceSampler` draws a reference per episode (:meth:`ReferenceSampler.sample`)
from a :class:`ReferenceConfig`; the scenario distribution (names and weights) is
passed in by the environment, except for ``file`` whose entries name their own scenario and
weight (``file_scenario``: only the tests of that scenario; the calibration problem and a run's
evaluation set it to their scenario, so a set of tests of several load cases gives each its own).

Pinned reference (``pin_seed``, :meth:`ReferenceSampler.pinned`): every episode gets the same
reference, the first draw of ``numpy.random.default_rng(pin_seed)`` -- exactly the draw that
:func:`marlcrash.calibrate.problem.build_problem` makes for ``reference_seed = pin_seed`` when
the scenario distribution is that problem's single scenario. Calibrating ONE reference, as the
paper does, is then RL training on that reference.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import torch

from marlcrash.cells.model import CellModel
from marlcrash.cells.parameterization import apply_increments
from marlcrash.config import checked, config_dir, require
from marlcrash.errors import ConfigError, PulseError
from marlcrash.pulse.cfc import CFC_CLASSES, min_rate_hz
from marlcrash.pulse.io import ACC_UNIT_NAMES, ACC_UNITS, acc_unit_key, check_record_rate, is_mme, is_sign, read_pulse
from marlcrash.pulse.signal import (
    DEFAULT_COMPARE_MARGIN,
    compared_window,
    margin_samples,
    prepare_velocity,
    without_zero_offset,
)
from marlcrash.sim.scenario import CrashScenario, get_scenario, list_scenarios, scenario_tensors
from marlcrash.sim.surrogate import SimConfig, Surrogate

if TYPE_CHECKING:
    from marlcrash.vehicle.registry import VehicleOptions


@dataclass
class TwinConfig:
    """Spreads of the hidden twin perturbation (log-normal sigmas, per sub-assembly)."""

    e_x_spread: float = 0.2
    e_s_spread: float = 0.2
    transmission_spread: float = 0.2

    def validate(self) -> None:
        for k in ("e_x_spread", "e_s_spread", "transmission_spread"):
            v = getattr(self, k)
            require(np.isfinite(v) and 0.0 <= v <= 2.0, k, f"expected a log-normal sigma in [0, 2], got {v}")


@dataclass
class CrossFidelityConfig:
    """The fine reference model: discretization method, vehicle variants, and its own integration settings.

    The fine model's cells are light (the uniform default car's: median 64 g), so the calibrated model's mass floor
    (``mass_floor`` of ``configs/sim.yaml``, 0.5 kg) would move 1179 of the compartment's 1324 kg into its crush zone
    and turn its 29 g full-width pulse into 99 g. ``mass_floor`` and ``substeps`` here replace the sim config's for
    the reference only (``None``: the sim config's); the defaults keep the added mass at 36 kg, and a finer pair
    moves the reference's peaks by 1-10 % (``benchmarks/bench_cross_fidelity.py``).
    """

    method: Literal["uniform", "optimized"] = "uniform"
    target_cell_volume: float | None = None
    vehicle_seeds: list[int | None] = field(default_factory=lambda: [None])
    mass_floor: float | None = 0.05
    substeps: int | None = 24

    def validate(self) -> None:
        require(self.target_cell_volume is None or self.target_cell_volume > 0, "target_cell_volume",
                f"expected > 0 m^3 or null, got {self.target_cell_volume}")  # fmt: skip
        if self.target_cell_volume is not None:  # now, not at the first fine reference (after the env was built)
            from marlcrash.cells.discretize import load_discretization_config

            load_discretization_config()  # cells.yaml's own error names its own key
            try:
                load_discretization_config(overrides={"target_cell_volume": self.target_cell_volume})
            except ConfigError as e:
                raise ConfigError(f"the fine model's discretization (configs/cells.yaml with this volume) is "
                                  f"refused: {e}", key="target_cell_volume") from None  # fmt: skip
        require(bool(self.vehicle_seeds), "vehicle_seeds", "expected at least one vehicle seed (null = the car's own)")
        for i, v in enumerate(self.vehicle_seeds):
            ok = v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)
            require(ok, f"vehicle_seeds[{i}]", f"expected a seed >= 0 or null (the car's own variant), got {v!r}")
        floor = self.mass_floor
        require(floor is None or (isinstance(floor, (int, float)) and not isinstance(floor, bool)
                                  and np.isfinite(floor) and floor >= 0), "mass_floor",
                f"expected a mass >= 0 kg or null (the sim config's), got {floor!r}")  # fmt: skip
        require(self.substeps is None or (isinstance(self.substeps, int) and not isinstance(self.substeps, bool)
                                          and 1 <= self.substeps <= 1000), "substeps",
                f"expected an integer in [1, 1000] or null (the sim config's), got {self.substeps!r}")  # fmt: skip

    def sim_config(self, base: SimConfig) -> SimConfig:
        """``base`` with this reference's own ``mass_floor`` and ``substeps`` where they are set."""
        own = {k: getattr(self, k) for k in ("mass_floor", "substeps") if getattr(self, k) is not None}
        return replace(base, **own)


@dataclass
class FileReference:
    """One measured test: file, its load case, and how its channels map to sensors."""

    path: str = ""
    scenario: str = ""
    channels: dict[str, str] = field(default_factory=dict)
    unit: str = "g"
    time_unit: str = "s"
    sign: float = 1.0
    cfc: int | None = 60
    time_zero: Literal["threshold", "file"] = "file"
    threshold_g: float = 0.5
    weight: float = 1.0
    breakpoints: bool = False

    def validate(self) -> None:
        require(bool(self.path), "path", "expected the path of a CSV file or ISO-MME test")
        require(bool(self.scenario), "scenario", "expected the registered scenario of the test")
        require(self.scenario in list_scenarios(), "scenario",  # named here, not as the env's 'scenario' at its build
                f"unknown scenario {self.scenario!r}; registered: {list_scenarios()}")  # fmt: skip
        require(bool(self.channels), "channels", "expected a mapping sensor name -> channel name")
        require(is_sign(self.sign), "sign", f"expected +1 or -1, got {self.sign!r}")
        require(acc_unit_key(self.unit) in ACC_UNITS, "unit", f"expected one of {ACC_UNIT_NAMES}, got {self.unit!r}")
        require(self.time_unit in ("s", "ms"), "time_unit", f"expected s or ms, got {self.time_unit!r}")
        for key, unit in (("weight", ""), ("threshold_g", " g")):
            v = getattr(self, key)
            real = float(v) if isinstance(v, numbers.Real) and not isinstance(v, bool) else math.nan
            ok = math.isfinite(real) and real > 0
            require(ok, key, f"expected a finite number > 0{unit}, got {v!r}")


@dataclass
class ReferenceConfig:
    """Which reference the environment calibrates against (module docstring)."""

    kind: Literal["twin", "cross_fidelity", "file"] = "twin"
    twin: TwinConfig = field(default_factory=TwinConfig)
    cross_fidelity: CrossFidelityConfig = field(default_factory=CrossFidelityConfig)
    files: list[FileReference] = field(default_factory=list)
    compare_cfc: int | None = 60
    pin_seed: int | None = None
    file_scenario: str | None = None
    compare_margin: float = DEFAULT_COMPARE_MARGIN

    def validate(self) -> None:
        require(self.kind != "file" or bool(self.files), "files", "kind 'file' needs at least one entry in files")
        if self.kind == "file" and self.file_scenario is not None:
            require_file_scenario(self, self.file_scenario, "file_scenario")
        require(self.kind == "file" or self.file_scenario is None, "file_scenario",  # else read by nothing
                f"picks among the measured tests, so it is read only with kind 'file' (kind is {self.kind!r}); "
                f"expected null, got {self.file_scenario!r}")  # fmt: skip
        require(  # before the tests' cfc, which names compare_cfc's value as the one expected
            self.compare_cfc in (None, 60, 180, 600, 1000),
            "compare_cfc",
            f"expected a CFC class (60, 180, 600, 1000) or null, got {self.compare_cfc!r}",
        )
        for i, f in enumerate(self.files):  # the file and the simulation must be compared as the same signal
            require(f.cfc is None or f.cfc == self.compare_cfc, f"files[{i}].cfc",
                    f"expected the compared signal's class, compare_cfc = {self.compare_cfc} (or null: the file is "
                    f"filtered already), got {f.cfc}: the simulation is filtered with compare_cfc")  # fmt: skip
        require(np.isfinite(self.compare_margin) and 0.0 <= self.compare_margin <= 0.1, "compare_margin",
                f"expected a duration in [0, 0.1] s, got {self.compare_margin}")  # fmt: skip
        require(self.pin_seed is None or self.pin_seed >= 0, "pin_seed",
                f"expected a reference seed >= 0 or null, got {self.pin_seed}")  # fmt: skip


def require_file_scenario(config: ReferenceConfig, scenario: str, key: str) -> None:
    """Refuse, naming ``key``, a scenario that no test of ``config.files`` is of."""
    have = sorted({f.scenario for f in config.files})
    require(scenario in have, key,
            f"no test of reference.files is of scenario {scenario!r}; their scenarios: {have}")  # fmt: skip


@dataclass
class ReferenceBatch:
    """References for ``B`` episodes on a common grid of ``T`` samples and ``K`` sensors.

    Attributes:
        scenario: ``[B]`` scenario names.
        speed, overlap, side: ``[B]`` float64 impact speed [m/s], overlap [-], side (+1 left, -1 right).
        velocity: ``[B, K, T]`` float64 reference velocity [m/s] (forward speed) as compared:
            the integral of the CFC-filtered acceleration (``ReferenceConfig.compare_cfc``); the acceleration as
            compared is its time derivative.
        true_params: ``[B, n_cells, 7]`` ground truth of a twin, else ``None``.
        true_increments: ``[B, S, 7]`` the twin's log-scale increments per sub-assembly (index of
            ``CellModel.subassembly_names``) that :func:`perturb_twin` applied, else ``None``: a
            calibrator whose agents each own cells of one sub-assembly reaches the truth exactly
            at these coordinates.
        source: ``[B]`` a readable origin (``twin``, ``uniform:seed=None``, a file path).
        raw_velocity: ``[B, K, T]`` unfiltered simulated velocity of simulated references (so a
            shorter comparison window can be filtered alike); ``None`` for measured files,
            which are filtered when read.
        margin: ``[B]`` int64 samples past the window that a measured record holds (at most
            ``ReferenceConfig.compare_margin``, one sample compared unfiltered): it was filtered (its acceleration
            differenced) over them, so a candidate compared with it
            is simulated that much longer and cut after filtering
            (:func:`~marlcrash.pulse.signal.compared_window`); 0 for simulated references, which end at the
            window as the candidates do. ``None``: all 0.
    """

    scenario: list[str]
    speed: torch.Tensor
    overlap: torch.Tensor
    side: torch.Tensor
    velocity: torch.Tensor
    true_params: torch.Tensor | None
    source: list[str]
    raw_velocity: torch.Tensor | None = None
    true_increments: torch.Tensor | None = None
    margin: torch.Tensor | None = None

    def repeat(self, n: int) -> ReferenceBatch:
        """The first row repeated ``n`` times (every tensor ``[n, ...]``; copies, not views)."""

        def rows(t: torch.Tensor) -> torch.Tensor:
            return t[:1].repeat(n, *([1] * (t.ndim - 1)))

        def some(t: torch.Tensor | None) -> torch.Tensor | None:
            return None if t is None else rows(t)

        return ReferenceBatch([self.scenario[0]] * n, rows(self.speed), rows(self.overlap), rows(self.side),
                              rows(self.velocity), some(self.true_params),
                              [self.source[0]] * n, some(self.raw_velocity), some(self.true_increments),
                              some(self.margin))  # fmt: skip


def twin_increments(noise: torch.Tensor, config: TwinConfig, bounds: tuple[float, float] | None = None) -> torch.Tensor:
    """The twin's log-scale increments ``[B, S, 7]``: standard normal ``noise`` times the spreads.

    With ``bounds`` ``(lo, hi)``, the ``E_x``, ``E_s`` increments are clipped to ``[log lo, log hi]``: the factors
    :func:`perturb_twin` applies, so that the increments returned as the truth are the ones it was made with.
    """
    sig = torch.tensor([config.e_x_spread, config.e_s_spread] + [config.transmission_spread] * 5, dtype=noise.dtype)
    inc = noise * sig
    if bounds is not None:
        inc = torch.cat([inc[..., :2].clamp(math.log(bounds[0]), math.log(bounds[1])), inc[..., 2:]], dim=-1)
    return inc


def perturb_twin(
    params: torch.Tensor,
    subassembly: torch.Tensor,
    feasible: torch.Tensor,
    noise: torch.Tensor,
    config: TwinConfig,
    bounds: tuple[float, float] | None = None,
    floor: float = 0.01,
) -> torch.Tensor:
    """Apply per-sub-assembly twin perturbations to initial parameters.

    The perturbation is a log-scale increment per sub-assembly and parameter,
    ``spread * noise`` (:func:`twin_increments`, ``E`` clipped to ``bounds``), mapped by
    :func:`~marlcrash.cells.parameterization.apply_increments` -- the calibrators' own parameter space -- so the
    hidden truth is exactly reachable.

    Args:
        params: ``[n_cells, 7]`` initial parameters.
        subassembly: ``[n_cells]`` int64 sub-assembly index (-1: untouched, e.g. null cells).
        feasible: ``[n_cells, 5]`` bool feasible transmission factors.
        noise: ``[B, S, 7]`` standard normal draws, ``S`` sub-assemblies.
        config: spreads (log-normal sigmas).
        bounds: optional ``(lo, hi)`` on the ``E_x``/``E_s`` factors (default: unbounded).
        floor: transmission shift of the parameter space (the environment's ``transmission_floor``).

    Returns:
        ``[B, n_cells, 7]`` perturbed parameters; transmission factors stay feasible.
    """
    touched = (subassembly >= 0)[None, :, None]
    inc = twin_increments(noise, config, bounds)[:, subassembly.clamp_min(0)]
    inc = torch.where(touched, inc, noise.new_zeros(()))
    p0 = params.to(noise.dtype)
    lo, hi = bounds if bounds is not None else (1e-12, 1e12)
    return apply_increments(p0[None].expand_as(inc), inc, p0, feasible, (lo, hi), floor)


def _require_count(value: object, name: str, least: int) -> None:
    """Refuse an argument that is no integer ``>= least``, naming it (0 references failed in the simulator, a seed
    of -1 in numpy's "expected non-negative integer")."""
    if not (isinstance(value, int | np.integer) and not isinstance(value, bool) and value >= least):
        raise ValueError(f"expected {name} as an integer >= {least}, got {value!r}")


def _check_grid(scenarios: dict[str, CrashScenario]) -> tuple[float, float]:
    first = next(iter(scenarios.values()))
    for name, sc in scenarios.items():
        if abs(sc.duration - first.duration) > 1e-12 or abs(sc.output_rate - first.output_rate) > 1e-9:
            raise ConfigError(
                f"scenario {name!r} has duration {sc.duration} s at {sc.output_rate} Hz, but {first.name!r} has "
                f"{first.duration} s at {first.output_rate} Hz; all scenarios of an environment need one output grid",
                key="scenarios",
            )
    return first.duration, first.output_rate


class ReferenceSampler:
    """Draws one reference per episode, batched.

    Args:
        cells: the model being calibrated.
        surrogate: its simulator (used for twins; its :class:`SimConfig`, with the fine model's own mass floor and
            substeps, for cross-fidelity).
        sensors: ``[K]`` sensor names, in the order of the reference's sensor axis.
        scenarios: scenario name -> weight (ignored for ``kind: file``).
        config: the reference settings.
        vehicle: the vehicle name or path (cross-fidelity builds its fine model from it).
        vehicle_options: how ``vehicle`` is read (``None``: the defaults).
        vehicle_seed: the variant of ``vehicle`` that ``cells`` is (``None``: the nominal car); a null entry of
            ``cross_fidelity.vehicle_seeds`` is this variant, so the fine model is the calibrated car's.
        bounds: optional ``(lo, hi)`` factor bounds of ``E_x``, ``E_s`` for twins.
        floor: transmission shift of the parameter space (:mod:`marlcrash.cells.parameterization`).
        backend: simulator backend for references.

    Raises:
        ConfigError: a bad ``config`` value (named as ``reference.<key>``), unknown scenarios, mixed output grids
            or one that is not ``surrogate``'s output step, unknown sensors or channels.
        PulseError: unreadable or too short reference files.
    """

    def __init__(
        self,
        cells: CellModel,
        surrogate: Surrogate,
        sensors: list[str],
        scenarios: dict[str, float],
        config: ReferenceConfig,
        vehicle: str = "b_segment",
        vehicle_options: VehicleOptions | None = None,
        bounds: tuple[float, float] | None = None,
        floor: float = 0.01,
        backend: Literal["torch", "numba", "adjoint", "auto"] = "auto",
        vehicle_seed: int | None = None,
    ):
        config = checked(config, "reference")  # one made in Python skipped the checks a file's values get
        self.cells, self.sim, self.sensors, self.config = cells, surrogate, list(sensors), config
        self.vehicle, self.bounds, self.floor, self.backend = vehicle, bounds, floor, backend
        self.vehicle_options, self.vehicle_seed = vehicle_options, vehicle_seed
        if not self.sensors:  # a calibration compares sensor pulses: nothing to compare is no calibration
            raise ConfigError(
                f"no sensors to compare: none named and the cell model of {cells.name!r} has none (its "
                "discretization config's sensors, configs/cells.yaml)",
                key="sensors",
            )
        unknown = [s for s in self.sensors if s not in cells.sensor_names]
        if unknown:
            raise ConfigError(f"unknown sensors {unknown}; the cell model has {cells.sensor_names}", key="sensors")
        self._file_index: list[int] = []
        if config.kind == "file":  # a choice is an index into config.files (only file_scenario's tests, if set)
            self._file_index = [i for i, f in enumerate(config.files)
                                if config.file_scenario in (None, f.scenario)]  # fmt: skip
            names = [config.files[i].scenario for i in self._file_index]
            weights = [config.files[i].weight for i in self._file_index]
        else:
            names, weights = list(scenarios), list(scenarios.values())
        if not names:
            raise ConfigError("expected at least one scenario name with a weight", key="scenarios")
        if any(not (np.isfinite(w) and w > 0) for w in weights):
            raise ConfigError(f"scenario weights must be finite and > 0, got {weights}", key="scenarios")
        self.scenarios = {n: get_scenario(n) for n in dict.fromkeys(names)}
        self.duration, self.output_rate = _check_grid(self.scenarios)
        if abs(surrogate.output_dt * self.output_rate - 1.0) > 1e-9:  # else the reference is read on the wrong clock
            raise ConfigError(
                f"the simulator's output step output_dt = {surrogate.output_dt:.6g} s is not the scenarios' "
                f"{1.0 / self.output_rate:.6g} s (output_rate {self.output_rate:g} Hz); expected a Surrogate built "
                "with output_dt = 1 / output_rate",
                key="scenarios",
            )
        cfc = config.compare_cfc
        if cfc is not None and min_rate_hz(cfc) >= self.output_rate:  # the simulation is filtered at it
            fits = [c for c in CFC_CLASSES if min_rate_hz(c) < self.output_rate]
            raise ConfigError(
                f"CFC {cfc} needs an output rate above {min_rate_hz(cfc):.0f} Hz (its design frequency below "
                f"Nyquist); the scenarios' output_rate is {self.output_rate:g} Hz: expected one of {fits} or null",
                key="reference.compare_cfc",
            )
        self.choices = names
        self.weights = np.asarray(weights, dtype=np.float64) / np.sum(weights)
        self.n_outputs = round(self.duration * self.output_rate) + 1
        self._sub = torch.as_tensor(np.where(cells.is_null | cells.is_rigid, -1, cells.subassembly).astype(np.int64))
        self._params = torch.as_tensor(cells.params, dtype=torch.float64)
        self._feasible = torch.as_tensor(cells.feasible)
        self._fine: dict[int | None, tuple[CellModel, Surrogate]] = {}
        self._cache: dict[tuple[int | None, str], np.ndarray] = {}
        self._files = [self._load_file(i, config.files[i]) for i in self._file_index]  # empty unless kind file
        self._pinned: dict[int, ReferenceBatch] = {}

    @property
    def n_subassemblies(self) -> int:
        return len(self.cells.subassembly_names)

    # ----------------------------------------------------------------------------------- sampling
    def sample(self, rng: np.random.Generator, n: int) -> ReferenceBatch:
        """Draw ``n`` references (scenario by weight, then the reference) with ``rng``.

        The draws come row by row: row ``i``'s scenario pick (``file``: test pick), then its ``[S, 7]`` standard
        normals of the twin perturbation (``twin``) or its vehicle-seed pick (``cross_fidelity``), then row
        ``i + 1``'s. So a row's reference does not depend on ``n``: from generators in the same state, the first
        four rows of ``sample(rng, 8)`` are ``sample(rng, 4)``, and a run with more parallel episodes sees the same
        references in its first rows.
        A reference that depends on a seed alone is ``sample(numpy.random.default_rng(seed), 1)``: the one
        :meth:`pinned` repeats and :func:`~marlcrash.calibrate.problem.build_problem` calibrates.
        """
        _require_count(n, "n", 1)
        kind = self.config.kind
        n_draws = (self.n_subassemblies, 7) if kind == "twin" else ()
        pick = np.empty(n, dtype=np.int64)
        draws: list[np.ndarray | np.integer] = []  # per row: twin normals [S, 7] or a vehicle-seed index
        for i in range(n):  # row by row, so that row i's draws do not depend on n
            pick[i] = rng.choice(len(self.choices), p=self.weights)
            if kind == "twin":
                draws.append(rng.standard_normal(n_draws))
            elif kind == "cross_fidelity":
                draws.append(rng.integers(0, len(self.config.cross_fidelity.vehicle_seeds)))
        names = [self.choices[i] for i in pick]
        scs = [self.scenarios[s] for s in names]
        rows = scenario_tensors(scs)
        speed, overlap, side = rows["speed"], rows["overlap"], rows["side"]
        truth = increments = None
        margin = torch.zeros(n, dtype=torch.int64)
        if kind == "twin":
            noise = torch.as_tensor(np.asarray(draws, dtype=np.float64).reshape(n, *n_draws))
            truth = perturb_twin(
                self._params, self._sub, self._feasible, noise, self.config.twin, self.bounds, self.floor
            )
            with torch.no_grad():
                res = self.sim.run(truth, speed=speed, overlap=overlap, side=side, duration=self.duration,
                                   sensors=self.sensors, record_cells="none", backend=self.backend)  # fmt: skip
            raw = res.velocity.to(torch.float64)
            source = ["twin"] * n
            increments = twin_increments(noise, self.config.twin, self.bounds)
        elif kind == "cross_fidelity":
            seeds = [self.variant(v) for v in self.config.cross_fidelity.vehicle_seeds]
            seed_pick = [int(k) for k in draws]
            raw = torch.as_tensor(np.stack([self._fine_reference(seeds[k], s)
                                            for k, s in zip(seed_pick, names, strict=True)]))  # fmt: skip
            source = [f"{self.config.cross_fidelity.method}:seed={seeds[k]}" for k in seed_pick]
        else:
            raw = None
            vel = torch.as_tensor(np.stack([self._files[i][0] for i in pick]))
            margin = torch.tensor([self._files[i][1] for i in pick], dtype=torch.int64)
            source = [self.config.files[self._file_index[i]].path for i in pick]
        if raw is not None:
            vel = self.compared(raw)
        return ReferenceBatch(names, speed, overlap, side, vel, truth, source, raw, increments, margin)

    def pinned(self, seed: int, n: int) -> ReferenceBatch:
        """The pinned reference of ``seed`` for ``n`` episodes (module docstring); drawn once, then cached.

        It is ``sample(numpy.random.default_rng(seed), 1)`` repeated ``n`` times; no other generator is used.
        """
        _require_count(seed, "seed", 0)
        _require_count(n, "n", 1)
        if seed not in self._pinned:
            self._pinned[seed] = self.sample(np.random.default_rng(seed), 1)
        return self._pinned[seed].repeat(n)

    @property
    def max_margin(self) -> int:
        """The most samples past the window that a reference of this sampler holds (:attr:`ReferenceBatch.margin`)."""
        return max((f[1] for f in self._files), default=0)

    def compared(self, velocity: torch.Tensor, margin: torch.Tensor | int = 0) -> torch.Tensor:
        """Simulated ``[B, K, T + max(margin)]`` velocity as it is compared over the ``T`` samples of the window.

        The integral of the CFC-filtered acceleration, each row filtered over its ``margin`` samples past the
        window (its reference's :attr:`ReferenceBatch.margin`) and cut to the window.
        """
        return compared_window(velocity.to(torch.float64), 1.0 / self.output_rate, self.config.compare_cfc,
                               self.n_outputs, margin)  # fmt: skip

    # ------------------------------------------------------------------------------ cross-fidelity
    def variant(self, seed: int | None) -> int | None:
        """The vehicle variant of an entry of ``cross_fidelity.vehicle_seeds``: ``None`` is the calibrated car's."""
        return self.vehicle_seed if seed is None else seed

    def fine_model(self, seed: int | None = None) -> tuple[CellModel, Surrogate]:
        """The cross-fidelity reference model of a vehicle variant (an entry of ``cross_fidelity.vehicle_seeds``:
        ``None`` is the calibrated car's, :meth:`variant`) and its simulator, built once per variant."""
        seed = self.variant(seed)
        if seed not in self._fine:
            from marlcrash.cells.discretize import discretize, load_discretization_config
            from marlcrash.vehicle.registry import load_configured_vehicle

            cfg = self.config.cross_fidelity
            over = {} if cfg.target_cell_volume is None else {"target_cell_volume": cfg.target_cell_volume}
            model = load_configured_vehicle(self.vehicle, seed, self.vehicle_options)
            fine = discretize(model, load_discretization_config(overrides=over), method=cfg.method)
            missing = [s for s in self.sensors if s not in fine.sensor_names]
            if missing:
                raise ConfigError(f"the {cfg.method} reference model lacks sensors {missing}", key="sensors")
            sim_cfg = cfg.sim_config(self.sim.config)
            self._fine[seed] = (fine, Surrogate(fine, sim_cfg, output_dt=1.0 / self.output_rate))
        return self._fine[seed]

    def _fine_reference(self, seed: int | None, scenario: str) -> np.ndarray:
        """The raw velocity ``[K, T]`` of the fine model of ``seed`` in ``scenario`` (simulated once per variant)."""
        key = (self.variant(seed), scenario)
        if key not in self._cache:
            fine, sim = self.fine_model(seed)
            with torch.no_grad():
                res = sim.run(torch.as_tensor(fine.params)[None], self.scenarios[scenario], duration=self.duration,
                              sensors=self.sensors, record_cells="none", backend=self.backend)  # fmt: skip
            self._cache[key] = res.velocity[0].double().numpy()
        return self._cache[key]

    # ------------------------------------------------------------------------------------- files
    def _load_file(self, i: int, spec: FileReference) -> tuple[np.ndarray, int]:
        """Velocity ``[K, T]`` of test ``i`` over the window, and its margin (samples past it)."""
        key = f"reference.files[{i}]"
        missing = [s for s in self.sensors if s not in spec.channels]
        if missing:
            raise ConfigError(f"no channel given for sensors {missing}; expected one per sensor {self.sensors}",
                              key=f"{key}.channels")  # fmt: skip
        path = Path(spec.path)
        if not path.is_absolute():
            path = config_dir() / path
        if not path.exists():
            raise ConfigError(f"no such file or ISO-MME folder: {path} (a relative path is read from configs/)",
                              key=f"{key}.path")  # fmt: skip
        if is_mme(path):  # named by key here, not as read_pulse's keyword
            if acc_unit_key(spec.unit) != "g":
                raise ConfigError(f"an ISO-MME test's channels carry their own 'Unit' and are read in it; leave unit "
                                  f"at g (the default), got {spec.unit!r}", key=f"{key}.unit")  # fmt: skip
            if spec.time_unit != "s":
                raise ConfigError("an ISO-MME test's channels carry their own time base (in s); leave time_unit at s "
                                  f"(the default), got {spec.time_unit!r}", key=f"{key}.time_unit")  # fmt: skip
            if spec.breakpoints:
                raise ConfigError("breakpoints: true applies to CSV files only: an ISO-MME channel is sampled, not a "
                                  "table of breakpoints", key=f"{key}.breakpoints")  # fmt: skip
        channels = [spec.channels[s] for s in self.sensors]
        unique = list(dict.fromkeys(channels))
        pulse = read_pulse(path, acc_col=unique, unit=spec.unit, time_unit=spec.time_unit, sign=spec.sign,
                           breakpoints=spec.breakpoints)  # fmt: skip
        check_record_rate(pulse, path, time_unit=spec.time_unit)
        if pulse.n_channels != len(unique):
            raise PulseError(f"{path.name}: asked for channels {unique}, read {list(pulse.channels)}")
        pulse = pulse.select([unique.index(c) for c in channels])
        sc = self.scenarios[spec.scenario]
        # the samples before the contact are at rest: their mean is the offset (as `marlcrash pulse` removes it)
        most = margin_samples(self.config.compare_margin, sc.output_rate, self.config.compare_cfc)
        pulse = without_zero_offset(pulse, spec.time_zero, spec.cfc, spec.threshold_g)
        _, vel = prepare_velocity(pulse, cfc=spec.cfc, rate_hz=sc.output_rate, duration=sc.duration,
                                  time_zero=spec.time_zero, threshold_g=spec.threshold_g, v0=sc.speed,
                                  beyond=most / sc.output_rate)  # fmt: skip
        margin = vel.shape[1] - self.n_outputs
        vel = vel[:, : self.n_outputs]
        rise = float(vel.max()) - sc.speed
        if rise > max(1.0, 0.1 * sc.speed):  # a frontal impact slows the vehicle; rebound never exceeds the speed
            k = int(vel.max(axis=1).argmax())
            remedy = (  # a sign of -1 given already turned the file's values over: the remedy is the other sign
                f"{key}.sign: -1 is given (decelerations recorded positive): if the file records them negative, "
                f"leave {key}.sign at 1 (the default)"
                if spec.sign < 0
                else f"if the file records them positive, set {key}.sign: -1"
            )
            raise PulseError(
                f"{path.name}: channel {channels[k]!r} integrates to {rise:.3g} m/s above the impact speed "
                f"{sc.speed:.4g} m/s; expected decelerations negative (SAE J211, x forward): {remedy}"
            )
        change = sc.speed - float(vel.min())
        if change > 2.0 * sc.speed + max(1.0, 0.1 * sc.speed):  # at most a full rebound: v >= -speed
            k = int(vel.min(axis=1).argmin())
            raise PulseError(
                f"{path.name}: channel {channels[k]!r} changes the velocity by {change:.3g} m/s, from the impact "
                f"speed {sc.speed:.3g} m/s to {sc.speed - change:.3g} m/s; a crash changes it by at most about twice "
                f"the impact speed (a full rebound): is the acceleration in another unit than unit {spec.unit} "
                f"(m/s^2 read as g: 9.8 times the velocity change)? Set {key}.unit"
            )
        slowest = vel.min(axis=1)  # [K]: each channel's lowest velocity in the window
        if float(slowest.max()) > 0.25 * sc.speed:  # a rigid barrier stops a frontal impact within the window
            k = int(slowest.argmax())
            warnings.warn(
                f"{path.name}: channel {channels[k]!r} is still at {float(slowest[k]):.3g} m/s of the impact speed "
                f"{sc.speed:.4g} m/s at its slowest in the {sc.duration * 1e3:g} ms of scenario {sc.name!r}: a rigid "
                f"barrier brings the vehicle to rest (but where it glances off a small overlap); is the test of "
                f"another scenario ({key}.scenario), its time in another unit ({key}.time_unit: "
                f"{spec.time_unit}) or its acceleration ({key}.unit: {spec.unit})?",
                stacklevel=2,
            )
        if vel.shape[1] != self.n_outputs:
            raise PulseError(
                f"{path.name}: expected {self.n_outputs} samples ({sc.duration} s at {sc.output_rate} Hz) after time "
                f"zero, got {vel.shape[1]}; the record is too short for scenario {sc.name!r}"
            )
        return vel, margin
