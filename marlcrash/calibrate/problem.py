"""The calibration problem that optimizers and agents share (DESIGN 6).

A :class:`CalibrationProblem` fixes one cell model, one agent layout, one scenario and
one reference pulse, and exposes the search space the environments act in:
``x [N, n_agents, 7]`` log-scale factors per agent (sub-assembly granularity), mapped to
feasible cell parameters by :func:`marlcrash.cells.parameterization.apply_increments` applied once to
the initial parameters: ``E <- clip(E0 * exp(x_E), lo * E0, hi * E0)``; transmission factors
``((f0 + floor) * exp(x_f) - floor)^+`` on feasible entries, ``f_x`` no lower than a lateral factor where x is
feasible (DESIGN 1.3 boundary condition 3), renormalised to sum one. An
agent at ``x`` is exactly (bit for bit) where the environment's agent stands after one step of
increments ``x``. After several steps whose increments sum to ``x`` its ``E_x``, ``E_s`` are there too
(to rounding) where no step hit a bound, but its transmission factors only near: each step renormalises,
and the ``floor`` shift does not commute with that (of the order of ``floor * |x|``: 4.5e-4 after three
steps of increments up to 0.05 each at the default floor 0.01).

What it offers:

- :meth:`CalibrationProblem.evaluate`: per-sensor metrics ``[N, K]`` of ``N`` candidates from
  ONE batched no-grad simulation (numba path); every candidate counts one simulation
  (:attr:`CalibrationProblem.n_simulations`).
- :meth:`CalibrationProblem.loss`: a differentiable smooth fit loss through the torch
  simulator (forward plus backward count one simulation per candidate).
- :meth:`CalibrationProblem.score` (higher is better, the reward form's score of the
  sensor-reduced metrics) ranks candidates; :meth:`CalibrationProblem.success` is the
  termination test of DESIGN 1.5 (every sensor below every threshold).
- :meth:`CalibrationProblem.param_error`: relative error of the recovered per-sub-assembly
  parameters against a twin's hidden truth; :attr:`CalibrationProblem.true_x` is the
  search-space point that represents that truth.

The twin truth (:func:`marlcrash.references.perturb_twin`) is one increment per sub-assembly
through the same mapping, so when every agent owns cells of a single sub-assembly (the default
layout: sub-assemblies, some split left/right) ``true_x`` is the twin's own increments
(:attr:`marlcrash.references.ReferenceBatch.true_increments`) and its parameters equal the
truth bit for bit: zero metrics, zero parameter error. Agents that merge sub-assemblies
cannot follow per-sub-assembly increments; then ``true_x`` is a least-squares fit in
parameter space and the truth is representable only approximately (the fit can leave the search box where the twin's
draws do not: it is clipped to the box, with a warning naming the coordinates). With ``masking`` on, the
coordinates of agents the impact-region rule leaves inactive stay at zero in ``true_x`` too, so
the twin's perturbation of their cells is out of reach by design (all agents are active at full
width); with ``masking.cells: region`` so is that of an active agent's cells outside the impact region, and
the least-squares ``true_x`` is fitted over the cells each agent reaches.

The search box: ``|x| <= box_radius`` per coordinate, and for ``E_x``, ``E_s`` also within
the environment's behaviour bounds (``log lo <= x <= log hi``). Coordinates that cannot
change anything are fixed at zero (:attr:`CalibrationProblem.free`): agents inactive in the
scenario (impact-region rule, when ``masking`` is on), transmission directions
no increment can change in any cell an agent reaches (infeasible there, or the cell's only feasible one), and
``E_x``, ``E_s`` where the environment's behaviour bounds are ``[1, 1]`` (a box of no width). The twin's log
factors are normal (``reference.twin`` spreads, unbounded; only ``E`` is clipped to the behaviour bounds), so a wide
spread can draw a truth outside the box: ``true_x`` is clipped to it, and building the problem warns, naming each
agent, sub-assembly and parameter outside (the default spreads, 0.2, put the box 5 sigma out).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Literal, TypedDict, cast

import numpy as np
import torch

from marlcrash.cells.model import PARAM_NAMES, CellModel
from marlcrash.cells.parameterization import apply_increments, movable_factors, moved_factors
from marlcrash.config import flatten_overrides, require
from marlcrash.envs.agents import AgentLayout, build_agents
from marlcrash.envs.core import (
    EnvConfig,
    build_cells,
    env_config_of,
    overridden,
    require_env,
    require_env_keys_unset,
)
from marlcrash.envs.masking import ImpactRegions
from marlcrash.errors import ConfigError, ModelError
from marlcrash.metrics import Metrics, area_between, compute_metrics, rmse
from marlcrash.pulse.cfc import f_n
from marlcrash.pulse.signal import DEFAULT_COMPARE_MARGIN, compared_velocity, compared_window, margin_samples
from marlcrash.references import ReferenceBatch, ReferenceSampler, require_file_scenario
from marlcrash.reward import (
    Reward,
    TerminationConfig,
    load_reward_config,
    require_reward,
    require_scales,
    require_weights,
    termination,
)
from marlcrash.sim.scenario import CrashScenario, get_scenario, list_scenarios
from marlcrash.sim.surrogate import SimResult, Surrogate, load_sim_config


@dataclass
class SuccessConfig:
    """Success thresholds per sensor (DESIGN 1.5); ``None`` skips a metric. The defaults are the paper's best
    Table 3 row (iteration I5): :meth:`is_paper`.

    Attributes:
        area: area between the velocity curves [m].
        dfd: discrete Frechet distance [m/s] (time in s, as in the paper).
        rmse: velocity RMSE [m/s].
    """

    area: float | None = 0.0015
    dfd: float | None = 0.335
    rmse: float | None = 0.1511

    def validate(self) -> None:
        for k in ("area", "dfd", "rmse"):
            v = getattr(self, k)
            require(v is None or (np.isfinite(v) and v > 0), k, f"expected a threshold > 0 or null, got {v}")
        require(any(getattr(self, k) is not None for k in ("area", "dfd", "rmse")), "area",
                "at least one of area, dfd, rmse needs a threshold")  # fmt: skip

    def describe(self) -> str:
        """The test for a results table, thresholds with units: ``A < 0.0015 m, DFD < 0.335 m/s, RMSE < 0.1511 m/s``;
        a skipped metric (``None``) is left out."""
        parts = [("A", self.area, "m"), ("DFD", self.dfd, "m/s"), ("RMSE", self.rmse, "m/s")]
        return ", ".join(f"{name} < {v} {unit}" for name, v, unit in parts if v is not None)

    def is_paper(self) -> bool:
        """Whether these are the paper's thresholds (the defaults, its best Table 3 row), every metric set."""
        return self == SuccessConfig()

    def termination_config(self) -> TerminationConfig:
        """The episode-end config whose success test is this one (no failure limits)."""
        return TerminationConfig(success_area=self.area, success_dfd=self.dfd, success_rmse=self.rmse, max_iterations=1)

    def passes(self, metrics: Metrics) -> torch.Tensor:
        """``[*batch]`` bool: every sensor of per-sensor metrics ``[*batch, K]`` below every threshold set (a NaN
        metric fails), the environments' success test (:func:`marlcrash.reward.termination`)."""
        return termination(metrics, self.termination_config(), 0).success


@dataclass
class ProblemConfig:
    """What is calibrated against what; values in ``configs/train/baseline.yaml`` (``problem:``).

    Attributes:
        env: env config (``configs/env/<name>.yaml``) supplying vehicle, agents, bounds, floor,
            masking and reference settings, so baselines search the environments' space.
        env_overrides: dotted-key overrides of that env config.
        scenario: registered scenario name.
        reference: ``twin``, ``cross_fidelity`` or ``file`` (a measured test of ``reference.files`` in the env
            config or ``env_overrides``, for this scenario); replaces the env's ``reference.kind``.
        reference_seed: seed of the reference draw (the twin's hidden perturbation).
        duration: simulated window [s]; ``None`` uses the scenario's.
        box_radius: half-width of the search box in log-scale [-].
        masking: fix agents inactive in the scenario (impact-region rule) at zero.
        fit: reward config (``configs/reward/<name>.yaml``) whose score ranks candidates.
        success: thresholds of the success test.
        sim_backend: no-grad simulator of :meth:`CalibrationProblem.evaluate`.
        metrics_backend: ``numba`` (compiled Frechet kernel) or ``torch`` (reference).
    """

    env: str = "default"
    env_overrides: dict[str, Any] = field(default_factory=dict)
    scenario: str = "full_width_40"
    reference: Literal["twin", "cross_fidelity", "file"] = "twin"
    reference_seed: int = 0
    duration: float | None = None
    box_radius: float = 1.0
    masking: bool = True
    fit: str = "log_ratio"
    success: SuccessConfig = field(default_factory=SuccessConfig)
    sim_backend: Literal["numba", "torch"] = "numba"
    metrics_backend: Literal["numba", "torch"] = "numba"

    def validate(self) -> None:
        require(self.scenario in list_scenarios(), "scenario",
                f"unknown scenario {self.scenario!r}; registered: {list_scenarios()}")  # fmt: skip
        require(self.reference_seed >= 0, "reference_seed", f"expected a seed >= 0, got {self.reference_seed}")
        require(self.duration is None or (np.isfinite(self.duration) and self.duration > 0), "duration",
                f"expected a window > 0 s or null, got {self.duration}")  # fmt: skip
        require(np.isfinite(self.box_radius) and 0 < self.box_radius <= 5.0, "box_radius",
                f"expected a log-scale half-width in (0, 5], got {self.box_radius}")  # fmt: skip
        require_env(self.env, "env")
        require_env_keys_unset(
            self.env_overrides,
            {
                "scenarios": "scenario",
                "reference.file_scenario": "scenario (a file reference is the test of the problem's scenario)",
            },
        )
        require_reward(self.fit, "fit")


@dataclass
class SmoothLoss:
    """The differentiable fit loss ``mean_k(w_area A_k / area_scale + w_rmse RMSE_k / rmse_scale)``.

    The discrete Frechet distance is left out: it is only sub-differentiable (one
    bottleneck pair carries its gradient) and needs the ``[N, T, T]`` table.
    """

    w_area: float = 1.0
    w_rmse: float = 1.0
    area_scale: float = 0.02
    rmse_scale: float = 0.25

    def validate(self) -> None:
        require_weights(self, ("w_area", "w_rmse"), prefix="")
        require(self.w_area + self.w_rmse > 0, "w_area", "at least one of w_area, w_rmse must be > 0")
        require_scales(self, ("area_scale", "rmse_scale"), prefix="")


class CalibrationProblem:
    """One calibration task in the agents' search space (module docstring).

    Args:
        cells: the cell model calibrated.
        layout: its agents (each owns cells; ``x`` has one 7-vector per agent).
        surrogate: the simulator of ``cells``.
        scenario: the load case.
        reference: a :class:`ReferenceBatch` with one row (``[1, K, T0]``, ``T0 >= T``).
        sensors: ``[K]`` sensor names in the reference's order.
        bounds: ``(lo, hi)`` factors of the initial ``E_x``, ``E_s``.
        floor: transmission update shift (``EnvConfig.transmission_floor``).
        fit: the reward whose score ranks candidates (its metric settings are used).
        success: success thresholds.
        duration: window [s] (``None``: the scenario's); the reference is cut to it.
        active: ``[n_agents]`` bool agents that may act (``None``: all).
        acting: ``[n_cells]`` bool cells an agent's factors reach (``None``: all its cells; the impact region
            where ``masking.cells`` is ``region``).
        box_radius: search box half-width [-].
        sim_backend, metrics_backend: engines of :meth:`evaluate`.
        compare_cfc: CFC class of the compared signal (the integral of the filtered acceleration;
            ``ReferenceConfig.compare_cfc``), ``None`` for the integral of the unfiltered acceleration.
        compare_margin: [s] a measured reference's record goes on past the window and was filtered over
            it, so candidates are simulated up to this much longer, as far as the record reaches
            (:attr:`margin`; ``ReferenceConfig.compare_margin``; one sample at most with ``compare_cfc=None``, for
            the acceleration's central difference at the window's end); simulated references are cut at the window
            as the candidates are, and get none.

    Raises:
        ConfigError: reference with more than one row or shorter than the window.
    """

    def __init__(
        self,
        cells: CellModel,
        layout: AgentLayout,
        surrogate: Surrogate,
        scenario: CrashScenario,
        reference: ReferenceBatch,
        sensors: list[str],
        *,
        bounds: tuple[float, float],
        floor: float,
        fit: Reward,
        success: SuccessConfig,
        duration: float | None = None,
        active: torch.Tensor | None = None,
        acting: torch.Tensor | None = None,
        box_radius: float = 1.0,
        sim_backend: Literal["numba", "torch"] = "numba",
        metrics_backend: Literal["numba", "torch"] = "numba",
        compare_cfc: int | None = 60,
        compare_margin: float = DEFAULT_COMPARE_MARGIN,
    ):
        self.cells, self.layout, self.sim, self.scenario = cells, layout, surrogate, scenario
        self.sensors = list(sensors)
        self.bounds, self.floor, self.fit = (float(bounds[0]), float(bounds[1])), float(floor), fit
        self.sim_backend, self.metrics_backend = sim_backend, metrics_backend
        self.duration = float(duration if duration is not None else scenario.duration)
        self.dt = scenario.output_dt
        self.T = round(self.duration / self.dt) + 1
        if reference.velocity.shape[0] != 1:
            raise ConfigError(f"expected a reference batch of one row, got {reference.velocity.shape[0]}", "reference")
        if reference.velocity.shape[-1] < self.T:
            raise ConfigError(
                f"the reference has {reference.velocity.shape[-1]} samples, "
                f"the window {self.duration} s needs {self.T}",
                key="duration",
            )
        self.reference = reference
        self.compare_cfc = compare_cfc
        # samples the candidates are simulated past the window and filtered over before the cut: a measured record's
        # samples past the window (past the scenario's, and past a shorter duration's), at most compare_margin
        self.margin = 0
        if reference.raw_velocity is not None:  # filter the simulated reference over this window, as the estimates
            self.ref_velocity = compared_velocity(reference.raw_velocity[0, :, : self.T].to(torch.float64), self.dt,
                                                  compare_cfc)  # [K, T]  # fmt: skip
        else:  # a measured pulse, filtered when read over its whole record
            self.ref_velocity = reference.velocity[0, :, : self.T].to(torch.float64)
            past = reference.velocity.shape[-1] - self.T + (0 if reference.margin is None else int(reference.margin[0]))
            self.margin = min(past, margin_samples(compare_margin, 1.0 / self.dt, compare_cfc))
        self.speed, self.overlap, self.side = (
            t[:1].to(torch.float64) for t in (reference.speed, reference.overlap, reference.side)
        )
        self.success_cfg = success.termination_config()
        self.n_simulations = 0

        f64 = torch.float64
        self.init = torch.as_tensor(cells.params, dtype=f64)  # [n, 7]
        self.feasible = torch.as_tensor(cells.feasible)  # [n, 5]
        self._agent_of = layout.agent_of_cell.clamp_min(0)
        owned = layout.owned if acting is None else layout.owned & torch.as_tensor(acting, dtype=torch.bool)
        self._owned = owned[:, None].to(f64)  # [n, 1]
        A = layout.n_agents
        self.active = torch.ones(A, dtype=torch.bool) if active is None else torch.as_tensor(active, dtype=torch.bool)
        # a transmission direction is free for an agent if an increment along it changes some cell it reaches (a
        # feasible factor of a cell with another feasible one; a lone one stays one)
        feas_agent = torch.zeros(A, 5, dtype=f64).index_add_(
            0, self._agent_of, (movable_factors(self.feasible) & owned[:, None]).to(f64)
        )
        free = torch.cat([torch.ones(A, 2, dtype=torch.bool), feas_agent > 0], dim=1) & self.active[:, None]
        self.box_radius = r = float(box_radius)
        lo_e, hi_e = max(-r, float(np.log(self.bounds[0]))), min(r, float(np.log(self.bounds[1])))
        lower = torch.tensor([lo_e, lo_e] + [-r] * 5, dtype=f64).expand(A, 7)
        upper = torch.tensor([hi_e, hi_e] + [r] * 5, dtype=f64).expand(A, 7)
        # E_x, E_s whose behaviour bounds are [1, 1] have a box of no width: no increment changes them either (cma
        # refused such a box, lm simulated a finite-difference point per coordinate that moved nothing)
        self.free = free & (upper > lower)
        self.lower = torch.where(self.free, lower, 0.0)  # [A, 7]
        self.upper = torch.where(self.free, upper, 0.0)  # [A, 7]

        deform = ~cells.is_null & ~cells.is_rigid & (cells.subassembly >= 0)
        subs = np.unique(cells.subassembly[deform])
        self.subassembly_names = [cells.subassembly_names[s] for s in subs]
        sub_index = np.full(cells.n_cells, -1, dtype=np.int64)
        sub_index[deform] = np.searchsorted(subs, cells.subassembly[deform])
        self._sub_index = torch.as_tensor(sub_index)
        self._deform = torch.as_tensor(deform)
        self.true_params = None if reference.true_params is None else reference.true_params[0].to(f64)
        self.true_x = None if self.true_params is None else self._true_x(reference)

    # ------------------------------------------------------------------------------- search space
    @property
    def n_agents(self) -> int:
        return self.layout.n_agents

    @property
    def agent_names(self) -> list[str]:
        return list(self.layout.names)

    @property
    def n_free(self) -> int:
        """Number of free coordinates of ``x``."""
        return int(self.free.sum())

    def zeros(self, n: int = 1) -> torch.Tensor:
        """``[n, n_agents, 7]`` the initial parameters' point (all factors one)."""
        return torch.zeros(n, self.n_agents, 7, dtype=torch.float64)

    def check_x(self, x: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Validate candidates; return ``[N, n_agents, 7]`` float64 (a single ``[n_agents, 7]`` gets ``N = 1``).

        A candidate that requires grad keeps its graph (the result is ``x`` itself, or a view or cast of it).

        Raises:
            ModelError: wrong shape or non-finite entries (named by index).
        """
        x = torch.as_tensor(x)
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or tuple(x.shape[1:]) != (self.n_agents, 7) or not x.is_floating_point():
            raise ModelError(
                f"candidates must be float [N, n_agents={self.n_agents}, 7] log-scale factors, got "
                f"{list(x.shape)} {x.dtype}"
            )
        bad = ~torch.isfinite(x)
        if bool(bad.any()):
            n, a, j = (int(i) for i in torch.nonzero(bad)[0])
            raise ModelError(
                f"candidate {n}: x[{a}, {j}] (agent {self.agent_names[a]!r}, {PARAM_NAMES[j]}) is not finite"
            )
        return x.to(torch.float64)

    def clip(self, x: torch.Tensor) -> torch.Tensor:
        """Project ``[N, n_agents, 7]`` onto the search box (non-free coordinates to zero)."""
        return torch.minimum(torch.maximum(x, self.lower), self.upper)

    def flat(self, x: torch.Tensor) -> torch.Tensor:
        """Free coordinates ``[N, n_free]`` of ``x [N, n_agents, 7]``."""
        return x[:, self.free]

    def flat_box(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper bounds ``[n_free]`` of the free coordinates (the search box of :meth:`clip`)."""
        return self.flat(self.lower[None])[0], self.flat(self.upper[None])[0]

    def unflat(self, z: torch.Tensor) -> torch.Tensor:
        """``[N, n_agents, 7]`` from free coordinates ``z [N, n_free]`` (others zero)."""
        z = torch.as_tensor(z, dtype=torch.float64)
        x = self.zeros(z.shape[0])
        x[:, self.free] = z
        return x

    def params(self, x: torch.Tensor) -> torch.Tensor:
        """Cell parameters ``[N, n_cells, 7]`` of candidates ``x [N, n_agents, 7]`` (differentiable).

        Values are exactly :func:`~marlcrash.cells.parameterization.apply_increments` of the initial parameters.
        That function keeps a cell's transmission factors bit-identical where the increment is zero
        (a ``where`` with no gradient), so the gradient is taken from its renormalised branch,
        which equals it in value: ``x = 0`` gets a non-zero gradient too.
        """
        x = x * self.free  # fixed coordinates never act
        inc = x[:, self._agent_of] * self._owned  # [N, n, 7]
        init = self.init.expand(x.shape[0], -1, -1)
        p = apply_increments(init, inc, self.init, self.feasible, self.bounds, self.floor)
        if not x.requires_grad:
            return p
        g = moved_factors(init[..., 2:], inc[..., 2:], self.feasible, self.floor)
        total = g.sum(-1, keepdim=True)
        smooth = torch.where(total > 0, g / torch.where(total > 0, total, torch.ones_like(total)), init[..., 2:])
        f = smooth + (p[..., 2:] - smooth).detach()
        return torch.cat([p[..., :2], f], dim=-1)

    # -------------------------------------------------------------------------------- simulation
    @property
    def sim_duration(self) -> float:
        """[s] What a candidate is simulated over: the window and the :attr:`margin`."""
        return self.duration + self.margin * self.dt

    def simulate(
        self,
        x: torch.Tensor,
        *,
        count: bool = True,
        backend: Literal["torch", "numba", "adjoint", "auto"] | None = None,
        probe_cells=None,
    ) -> SimResult:
        """Simulate candidates ``x [N, n_agents, 7]`` over the window and the margin (:attr:`sim_duration`, ``T +
        margin`` samples: :meth:`compared` cuts them); ``count`` charges ``N`` simulations.

        Without gradients (``x`` not requiring grad) it uses :attr:`sim_backend`; ``count=False`` is
        for reporting (re-simulating a known candidate for plots), never for search. ``probe_cells``
        records those cells instead of the sensors (:meth:`~marlcrash.sim.surrogate.Surrogate.run`).
        ``x`` is checked (:meth:`check_x`) with or without gradients; the check keeps its graph.
        """
        x = self.check_x(x)
        p = self.params(x)
        n = p.shape[0]
        res = self.sim.run(
            p,
            speed=self.speed.expand(n),
            overlap=self.overlap.expand(n),
            side=self.side.expand(n),
            duration=self.sim_duration,
            sensors=self.sensors if probe_cells is None else None,  # the probes are recorded instead
            probe_cells=probe_cells,
            record_cells="none",
            backend=backend or ("torch" if x.requires_grad else self.sim_backend),
        )
        if count:
            self.n_simulations += n
        return res

    def compared(self, velocity: torch.Tensor) -> torch.Tensor:
        """Simulated velocities ``[..., K, T + margin]`` as compared over the window, ``[..., K, T]``
        (:func:`~marlcrash.pulse.signal.compared_window`)."""
        return compared_window(velocity.to(torch.float64), self.dt, self.compare_cfc, self.T, self.margin)

    def metrics(self, velocity: torch.Tensor) -> Metrics:
        """Per-sensor metrics ``[N, K]`` of simulated velocities ``[N, K, T + margin]`` (:meth:`simulate`'s,
        over :attr:`sim_duration`) against the reference (no grad)."""
        return self._compared_metrics(self.compared(velocity.detach()))

    def _compared_metrics(self, v: torch.Tensor) -> Metrics:
        return compute_metrics(
            v, self.ref_velocity, dt=self.dt, config=self.fit.cfg.metrics, backend=self.metrics_backend
        )

    def residuals(self, x: torch.Tensor | np.ndarray) -> tuple[torch.Tensor, Metrics]:
        """Velocity residuals and metrics of ``N`` candidates from one batched no-grad simulation (counts ``N``).

        Returns:
            ``r [N, K, T]``: compared minus reference velocity times ``sqrt(dt)`` [m/s^0.5], so that
            ``(r**2).sum((1, 2))`` is the summed ``integral (v - v_ref)^2 dt`` over the sensors [m^2/s],
            the least-squares cost of :mod:`~marlcrash.calibrate.leastsq`; and the metrics ``[N, K]``.
        """
        x = self.check_x(x)
        with torch.no_grad():
            res = self.simulate(x)
        v = self.compared(res.velocity)
        return (v - self.ref_velocity) * float(np.sqrt(self.dt)), self._compared_metrics(v)

    def evaluate(self, x: torch.Tensor | np.ndarray) -> Metrics:
        """Metrics ``[N, K]`` of ``N`` candidates ``[N, n_agents, 7]`` from one batched no-grad simulation."""
        x = self.check_x(x)
        with torch.no_grad():
            res = self.simulate(x)
        return self.metrics(res.velocity)

    def score(self, metrics: Metrics) -> torch.Tensor:
        """``[N]`` fit score of per-sensor metrics ``[N, K]``: the reward form's score, higher is better."""
        return self.fit.score(metrics).to(torch.float64)

    def success(self, metrics: Metrics) -> torch.Tensor:
        """``[N]`` bool: every sensor below every success threshold."""
        return termination(metrics, self.success_cfg, 0).success

    def loss(self, x: torch.Tensor, weights: SmoothLoss, backend: str = "adjoint") -> tuple[torch.Tensor, Metrics]:
        """Differentiable loss ``[N]`` through the simulator, and the candidates' metrics ``[N, K]``.

        Counts ``N`` simulations (forward and backward of a candidate together count one).

        Args:
            x: ``[N, n_agents, 7]`` candidates, or one ``[n_agents, 7]`` (usually ``requires_grad``; checked as
                :meth:`check_x` checks).
            weights: the loss weights and scales.
            backend: ``adjoint`` (compiled forward and reverse pass, :mod:`marlcrash.sim.adjoint`) or
                ``torch`` (the autograd reference); the same gradients to rounding.
        """
        if backend not in ("adjoint", "torch"):
            raise ConfigError(f"expected adjoint or torch, got {backend!r}", key="backend")
        res = self.simulate(x, backend=cast(Literal["adjoint", "torch"], backend))  # checks x, keeping its graph
        v = self.compared(res.velocity)
        ref = self.ref_velocity.expand_as(v)
        area = area_between(v, ref, dt=self.dt, method=self.fit.cfg.metrics.area_method)
        loss = (weights.w_area * area / weights.area_scale + weights.w_rmse * rmse(v, ref) / weights.rmse_scale).mean(
            -1
        )
        return loss, self.metrics(res.velocity)

    # ------------------------------------------------------------------------------- ground truth
    def subassembly_params(self, params: torch.Tensor) -> torch.Tensor:
        """Per-sub-assembly aggregates ``[N, S, 7]`` of cell parameters ``[N, n_cells, 7]``.

        ``E_x``, ``E_s``: sums over the sub-assembly's deformable cells [J]; transmission
        factors: means over its cells [-].
        """
        w = self._deform.to(params.dtype)[None, :, None]
        S = len(self.subassembly_names)
        idx = self._sub_index.clamp_min(0)
        tot = params.new_zeros(params.shape[0], S, 7).index_add_(1, idx, params * w)
        count = params.new_zeros(S).index_add_(0, idx, self._deform.to(params.dtype))
        return torch.cat([tot[..., :2], tot[..., 2:] / count[None, :, None]], dim=-1)

    def param_error(self, x: torch.Tensor) -> torch.Tensor:
        """Relative error ``[N, S, 3]`` of the recovered sub-assembly parameters against the twin truth.

        Columns: ``E_x`` and ``E_s``: ``|sum_rec - sum_true| / sum_true``; transmission:
        ``sum_d |mean f_rec - mean f_true| / sum_d mean f_true`` (relative L1 of the mean factors).

        Raises:
            ConfigError: the reference has no ground truth (not a twin).
        """
        if self.true_params is None:
            raise ConfigError("param_error needs a twin reference with ground truth", key="problem.reference")
        return self.params_error(self.params(self.check_x(x)).detach(), self.true_params)

    def params_error(self, params: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
        """Relative error ``[N, S, 3]`` of cell parameters ``[N, n_cells, 7]`` against ``truth`` ``[n_cells, 7]``.

        The definition behind :meth:`param_error`, for parameters reached by any calibrator.
        """
        rec = self.subassembly_params(params.to(torch.float64))
        true = self.subassembly_params(truth.to(torch.float64)[None])
        e = (rec[..., :2] - true[..., :2]).abs() / true[..., :2]
        t = (rec[..., 2:] - true[..., 2:]).abs().sum(-1) / true[..., 2:].sum(-1)
        return torch.cat([e, t[..., None]], dim=-1)

    def param_error_table(self, x: torch.Tensor) -> dict[str, dict[str, float]]:
        """``{sub-assembly: {E_x, E_s, transmission}}`` relative errors of one candidate ``[n_agents, 7]``."""
        err = self.param_error(x)[0]
        keys = ("E_x", "E_s", "transmission")
        return {s: {k: float(err[i, j]) for j, k in enumerate(keys)} for i, s in enumerate(self.subassembly_names)}

    def _true_x(self, reference: ReferenceBatch) -> torch.Tensor:
        """The point ``[n_agents, 7]`` representing the twin truth (module docstring)."""
        inc = reference.true_increments
        names = list(self.cells.subassembly_names)
        merged = any(len(subs) != 1 for subs in self.layout.subassemblies)
        if inc is None or merged:
            assert self.true_params is not None  # __init__ asks for true_x only of a reference with a truth
            x = self._fit_true_x(self.true_params)
        else:
            sub = torch.tensor([names.index(subs[0]) for subs in self.layout.subassemblies], dtype=torch.int64)
            x = inc[0, sub].to(torch.float64) * self.free
        self._warn_outside_box(inc, x)
        if inc is not None and merged:  # the twin's draw may lie inside the box while the fit to it does not
            self._warn_outside_box(None, x, fitted=True)
        return x.clamp(min=self.lower, max=self.upper)

    def _warn_outside_box(self, inc: torch.Tensor | None, x: torch.Tensor, fitted: bool = False) -> None:
        """Warn, naming agents, sub-assemblies and parameters, where the twin's hidden truth lies outside the search
        box: its log factors are normal (unbounded), so a wide spread draws truths no candidate reaches, and
        ``true_x`` is clipped to the box. Checked on the twin's own increments ``inc [1, S, 7]`` per sub-assembly
        an agent owns (``None``: on the point ``x [n_agents, 7]``; a merged agent's least-squares point is only an
        approximation of them). ``fitted``: ``x`` is merged agents' least-squares point for increments that all lie
        in the box; it can still leave it (a shared transmission factor for two sub-assemblies' cells moved past
        +1 in log scale with the default spreads), and clipping it doubled those parameters' error: said as such."""
        names = list(self.cells.subassembly_names)
        where: list[str] = []
        keys: dict[str, None] = {}  # the spreads behind the coordinates outside
        count = 0
        for a, subs in enumerate(self.layout.subassemblies):
            drawn = ([(f"sub-assembly {s}", inc[0, names.index(s)]) for s in subs] if inc is not None
                     else [(f"sub-assemblies {', '.join(subs)}", x[a])])  # fmt: skip
            for j in range(7):
                lo, hi = float(self.lower[a, j]), float(self.upper[a, j])
                tol = 1e-9 * (1.0 + max(abs(lo), abs(hi)))
                out = [(s, float(v[j])) for s, v in drawn if not lo - tol <= float(v[j]) <= hi + tol]
                if not bool(self.free[a, j]) or not out:
                    continue
                count += 1
                keys.setdefault(("e_x_spread", "e_s_spread", *["transmission_spread"] * 5)[j])
                if len(where) < 5:
                    owner, v = out[0]
                    where.append(f"agent {self.agent_names[a]!r} ({owner}) {PARAM_NAMES[j]} at log factor {v:.3g} "
                                 f"(box [{lo:.3g}, {hi:.3g}])")  # fmt: skip
        if not count:
            return
        more = f", and {count - len(where)} more" if count > len(where) else ""
        b_lo, b_hi = self.bounds
        if fitted:
            warnings.warn(
                f"the least-squares point that represents the twin's truth for the merged agents lies outside the "
                f"search box (box_radius = {self.box_radius:g}) at {count} of the {self.n_free} free coordinates: "
                f"{'; '.join(where)}{more}. The twin's draws lie inside it, but one factor of a merged agent stands "
                f"for several sub-assemblies' truths and the fit leaves the box; true_x is clipped to it, so "
                f"param_error at true_x is larger than the fit's own. Raise box_radius, or split the merged agents "
                f"(agents.merge)",
                stacklevel=4,
            )
            return
        warnings.warn(
            f"the twin's hidden truth lies outside the search box (box_radius = {self.box_radius:g}; E_x, E_s also "
            f"within behaviour_bounds [{b_lo:g}, {b_hi:g}]) at {count} of the {self.n_free} free coordinates: "
            f"{'; '.join(where)}{more}. true_x is clipped to the box, so no candidate reaches the truth: param_error "
            f"and success cannot get to those of the truth. The twin's log factors are normal (unbounded): lower "
            f"{', '.join('reference.twin.' + k for k in keys)} or raise box_radius",
            stacklevel=4,
        )

    def _fit_true_x(self, truth: torch.Tensor, sweeps: int = 200, refine_iters: int = 200) -> torch.Tensor:
        """The point ``[n_agents, 7]`` representing the twin truth ``[n_cells, 7]`` (module docstring).

        Fitted over the cells ``x`` reaches (all an agent's, or its in-region ones with ``masking.cells: region``).
        ``E``: mean log ratio over the agent's cells (exact: the twin scales a sub-assembly
        uniformly). Transmission: the twin's ``log(f/f0) = log(phi_d) - log(Z_cell)`` is fitted
        as ``x[a, d] - z[c]`` by alternating least squares, each agent's ``x`` centred, then refined
        by L-BFGS on the squared mismatch of the mapped factors (no simulation involved).
        """
        f64 = torch.float64
        # the cells x reaches (masking.cells region: an agent's in-region ones); the others stay initial whatever x is
        A, agent, owned = self.n_agents, self._agent_of, self._owned[:, 0] > 0
        cnt = torch.zeros(A, dtype=f64).index_add_(0, agent, owned.to(f64)).clamp_min(1.0)
        le = torch.where(owned[:, None], torch.log(truth[:, :2] / self.init[:, :2]), 0.0)
        x_e = torch.zeros(A, 2, dtype=f64).index_add_(0, agent, le) / cnt[:, None]
        f0, ft = self.init[:, 2:], truth[:, 2:]
        w = (self.feasible & (f0 > 0) & (ft > 0) & owned[:, None]).to(f64)  # [n, 5]
        L = torch.where(w > 0, torch.log(torch.where(w > 0, ft / torch.where(w > 0, f0, 1.0), 1.0)), 0.0)
        wa = torch.zeros(A, 5, dtype=f64).index_add_(0, agent, w).clamp_min(1e-300)
        x_t = torch.zeros(A, 5, dtype=f64)
        wc = w.sum(1).clamp_min(1e-300)
        for _ in range(sweeps):  # alternating least squares, vectorized over cells and agents
            z = ((x_t[agent] - L) * w).sum(1) / wc  # [n]
            x_t = torch.zeros(A, 5, dtype=f64).index_add_(0, agent, (L + z[:, None]) * w) / wa
        used = (wa >= 1).to(f64)
        x_t = (x_t - (x_t * used).sum(1, keepdim=True) / used.sum(1, keepdim=True).clamp_min(1.0)) * used
        x = (torch.cat([x_e, x_t], dim=1) * self.free)[None].requires_grad_(True)
        # refine in parameter space: the floor makes the twin's factors representable only approximately
        opt = torch.optim.LBFGS([x], max_iter=refine_iters, line_search_fn="strong_wolfe")

        def mismatch() -> torch.Tensor:
            opt.zero_grad()
            loss = ((self.params(x)[0, owned, 2:] - truth[owned, 2:]) ** 2).sum()
            loss.backward()
            return loss

        if float(w.sum()) > 0 and float((self.params(x.detach())[0, owned, 2:] - truth[owned, 2:]).abs().max()) > 0:
            opt.step(mismatch)
        return x.detach()[0] * self.free  # clipped to the box by _true_x


class Backends(TypedDict):
    """The engines of a :class:`ProblemConfig` (:func:`env_backends`)."""

    sim_backend: Literal["numba", "torch"]
    metrics_backend: Literal["numba", "torch"]


def env_backends(env: Any) -> Backends:
    """The :class:`ProblemConfig` engines of an env config: its ``sim_backend`` (``auto``: the no-grad ``numba``,
    what ``auto`` runs without gradients) and ``metrics_backend``, so a problem built for an env's reference scores
    its candidates as that env does."""
    sim: Literal["numba", "torch"] = "numba" if env.sim_backend == "auto" else env.sim_backend
    return {"sim_backend": sim, "metrics_backend": env.metrics_backend}


def problem_env_config(config: ProblemConfig):
    """The env config a problem is built from: ``config.env`` with its overrides, reference kind and scenario.

    A file reference is a test of ``config.scenario`` (``reference.file_scenario``), so a set of tests of several
    load cases in ``reference.files`` gives each problem the test of its own scenario.

    Raises:
        ConfigError: ``env_overrides`` set another ``reference.kind`` than ``reference`` (the problem's wins, so
            asking for a file reference there alone silently calibrated against the twin), no test of
            ``reference.files`` is of ``config.scenario``, or a bad env or override (keyed within the problem:
            ``env``, ``env_overrides.<key>``; :func:`~marlcrash.envs.core.env_config_of`).
    """
    kind = flatten_overrides(EnvConfig, config.env_overrides).get("reference.kind", config.reference)
    if kind != config.reference:
        raise ConfigError(f"the problem's reference is {config.reference!r}; set reference={kind} instead "
                          "(problem.reference picks the kind)", key="env_overrides.reference.kind")  # fmt: skip
    env = env_config_of(config.env, config.env_overrides, {"reference.kind": config.reference,
                                                          "reference.file_scenario": None,  # set below for a file
                                                          "scenarios": {config.scenario: 1.0}})  # fmt: skip
    if config.reference == "file":  # the test of this scenario (a set of tests may hold several load cases)
        require_file_scenario(env.reference, config.scenario, "problem.scenario")
        env.reference.file_scenario = config.scenario
    return env


@contextmanager
def _env_errors(config: ProblemConfig, env: EnvConfig) -> Iterator[None]:
    """Name a :class:`ConfigError` of the env's values raised while building (a sensor the model lacks, an agent
    layout that leaves cells unowned: bare env keys such as ``sensors``, which the problem config does not have) as
    the user set them: ``env_overrides.<key>`` where an override set it, else the env file's key (as
    :class:`~marlcrash.envs.core.CalibrationCore` names it). An error naming a file of its own is kept."""
    try:
        yield
    except ConfigError as e:
        if e.path is not None:
            raise
        if e.key is not None and overridden(e.key, list(flatten_overrides(EnvConfig, config.env_overrides))):
            raise ConfigError(e.reason, key=f"env_overrides.{e.key}") from None
        raise ConfigError(e.reason, key=e.key, path=getattr(env, "_source", None)) from None


def build_problem(config: ProblemConfig, cells: CellModel | None = None) -> CalibrationProblem:
    """Build the calibration problem of a config: cells, agents, simulator, reference.

    Args:
        config: the problem settings.
        cells: the cell model (``None``: the env config's vehicle, discretized once per process).

    Raises:
        ConfigError: invalid env, scenario, window, reward or reference settings (key named).
    """
    env = problem_env_config(config)
    scenario = get_scenario(config.scenario)
    if config.duration is not None:
        steps = config.duration * scenario.output_rate
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps) or config.duration > scenario.duration + 1e-12:
            raise ConfigError(
                f"expected a whole number of {scenario.output_dt} s output steps, at most the scenario's "
                f"{scenario.duration} s, got {config.duration}",
                key="problem.duration",
            )
        cfc = env.reference.compare_cfc
        if cfc is not None and config.duration < 1.0 / f_n(cfc) - 1e-12:  # as filter_pulse asks of a record
            raise ConfigError(
                f"expected a window of at least {1.0 / f_n(cfc)} s, one period of the {f_n(cfc):.0f} Hz -3 dB "
                f"frequency of the compared signal's CFC {cfc} (reference.compare_cfc), got {config.duration}",
                key="problem.duration",
            )
    bounds = (env.behaviour_bounds[0], env.behaviour_bounds[1])
    active = acting = None
    with _env_errors(config, env):  # values of the env that only building refuses, named as the user set them
        if cells is None:
            cells = build_cells(env.vehicle, env.vehicle_seed, env.discretization, env.vehicle_options)
        sensors = list(env.sensors) or list(cells.sensor_names)
        layout = build_agents(cells, env.agents)
        sim = Surrogate(cells, load_sim_config(overrides={"dtype": env.sim_dtype}), output_dt=scenario.output_dt)
        sampler = ReferenceSampler(cells, sim, sensors, env.scenarios, env.reference, vehicle=env.vehicle,
                                   vehicle_options=env.vehicle_options, bounds=bounds, floor=env.transmission_floor,
                                   backend=config.sim_backend, vehicle_seed=env.vehicle_seed)  # fmt: skip
        reference = sampler.sample(np.random.default_rng(config.reference_seed), 1)
        if config.masking:
            regions = ImpactRegions(cells, layout, env.masking)
            region = regions.region(reference.overlap, reference.side, reference.speed)
            active = regions.active(reference.overlap, reference.side, reference.speed, region)[0]
            acting = region[0] if env.masking.cells == "region" else None
    fit_cfg = load_reward_config(config.fit)
    return CalibrationProblem(
        cells, layout, sim, scenario, reference, sensors, bounds=bounds, floor=env.transmission_floor,
        fit=Reward(fit_cfg), success=config.success, duration=config.duration, active=active, acting=acting,
        box_radius=config.box_radius, sim_backend=config.sim_backend, metrics_backend=config.metrics_backend,
        compare_cfc=env.reference.compare_cfc, compare_margin=env.reference.compare_margin,
    )  # fmt: skip
