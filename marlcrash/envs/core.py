"""The calibration core: ``B`` batched calibration environments in torch (DESIGN 1.4, 1.5, 5).

One :class:`CalibrationCore` holds ``B`` independent episodes of calibrating one
:class:`~marlcrash.cells.model.CellModel` against references. Both front doors (the
PettingZoo ``ParallelEnv`` with ``B = 1`` and the batched TorchRL ``EnvBase``) are thin
layers over it, so they give the same numbers for the same seed and actions (the TorchRL door with ``B = 1``;
with a larger ``B`` the first reset's rows are the first episodes of a smaller one, :meth:`CalibrationCore.reset`).

Episode (per environment row):

- :meth:`CalibrationCore.reset` draws a scenario and a reference
  (:class:`~marlcrash.references.ReferenceSampler`), resets the parameters to the
  model's initial ones, fixes the active agents by the impact-region rule
  (:mod:`marlcrash.envs.masking`) and simulates once for the first observation.
  With ``reference.pin_seed`` set, every episode gets the same reference
  (:meth:`~marlcrash.references.ReferenceSampler.pinned`: the one
  :func:`~marlcrash.calibrate.problem.build_problem` builds for ``reference_seed = pin_seed``
  when ``scenarios`` is that problem's single scenario); the core's generator is not used for it.
- :meth:`CalibrationCore.step` maps actions ``[B, n_agents, act_dim]`` in ``[-1, 1]`` to
  per-cell log increments (``* max_step``; zero for inactive agents; behaviour changes
  of saturated cells damped when the saturation preference is on), applies them
  (:func:`apply_increments`), runs ONE batched no-grad simulation for all ``B`` rows
  (``record_cells="final"``; only the rows of its ``mask`` where one is given, TorchRL's partial
  step), and computes metrics, team reward and end flags.

Actions: ``subassembly`` granularity, ``act_dim = 7`` log-scale increments applied to
all the agent's cells; ``cell`` granularity, ``act_dim = 7 * max_cells``: per cell (in
the agent's slot order) 7 increments, padded, with :meth:`CalibrationCore.action_mask`.

Parameter update: :func:`marlcrash.cells.parameterization.apply_increments`, the one
mapping from log-scale increments to feasible parameters that agents, baselines and the
twin reference share.

Observation per agent, ``[B, n_agents, obs_dim]`` float32, concatenated:

1. the state vector of DESIGN 1.4: ``(v_ref - v_est) * velocity_scale`` for every
   sensor and output step, ``K * T`` values (same for all agents);
2. own parameters relative to initial, ``* param_scale``: ``log(E / E0)`` for ``E_x``, ``E_s``
   and ``log((f + floor) / (f0 + floor))`` for a feasible transmission factor (``floor`` =
   ``transmission_floor``, the coordinate the update moves: a factor that starts at or falls to 0 is
   seen, not a 0 like an untouched one); ``subassembly``: the mean over the agent's cells (7 values;
   transmission means over feasible entries), ``cell``: per cell padded (``7 * max_cells``);
3. its cells' absorbed-energy fractions ``absorbed / E_s`` from the last simulation,
   ``* energy_scale``, padded (``max_cells``);
4. its identity, one-hot (``n_agents``).

Global state ``[B, state_dim]``: the state vector, every agent's 7 mean log-ratios and
its mean absorbed-energy fraction.

Observers (:attr:`CalibrationCore.simulation_hooks`): callables ``hook(params, metrics)`` told
about every simulated candidate right after its simulation, in simulation order -- ``params
[n, n_cells, 7]`` and its per-sensor ``metrics [n, K]`` (e.g. best-so-far bookkeeping of a
calibration run, :class:`marlcrash.calibrate.marl.ProgressHook`). They get copies and change nothing.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from marlcrash.cells.model import CellModel
from marlcrash.cells.parameterization import apply_increments, log_ratios, movable_factors
from marlcrash.config import checked, config_dir, flatten_overrides, load_config, require
from marlcrash.envs.agents import AgentsConfig, build_agents
from marlcrash.envs.masking import ImpactRegions, MaskingConfig
from marlcrash.errors import ConfigError, MarlcrashError
from marlcrash.metrics import Metrics, compute_metrics
from marlcrash.references import ReferenceConfig, ReferenceSampler
from marlcrash.reward import Reward, TerminationConfig, load_reward_config, require_reward, shipped_termination
from marlcrash.sim.scenario import BASE_OUTPUT_DT, get_scenario, list_scenarios, steps_per_output
from marlcrash.sim.surrogate import SimConfig, Surrogate, load_sim_config
from marlcrash.vehicle.registry import VehicleOptions, is_deck, vehicle_config_path


class ActionError(MarlcrashError):
    """Bad use of an environment's API: actions of the wrong shape, dtype, or with non-finite values, a call out of
    order (step() before reset()), a bad seed or argument."""


DEFAULT_SCENARIOS = ("full_width_40", "offset40_left", "offset40_right", "small_overlap_left", "small_overlap_right")
"""The scenario distribution of ``configs/env/default.yaml`` (equal weights): the default of an :class:`EnvConfig` made
in Python, as every default there (``tests/test_config_defaults.py`` keeps them equal to the file)."""

DEFAULT_SPLIT_LR = ("bumper_beam", "subframe", "cooling_module", "dash_firewall", "hood")
"""Sub-assemblies ``configs/env/default.yaml`` splits into left and right agents."""


MAX_OBSERVATION_SCALE = 1e6
"""Largest factor on an observation part [its inverse unit]: the observations are float32, and ``velocity_scale:
1e308`` made every one inf or NaN, fed to the policy without a word. At this bound a 100 m/s velocity difference
observes as 1e8, finite (and far past where a tanh network saturates)."""

MAX_BEHAVIOUR_FACTOR = 1e3
"""Widest ``behaviour_bounds``: ``[1 / MAX_BEHAVIOUR_FACTOR, MAX_BEHAVIOUR_FACTOR]`` times the initial ``E_x``,
``E_s``. Wider bounds are no calibration of the car's structure, and in a float32 simulation (``sim_dtype``) an
upper bound of 1e300 let ``E_s`` grow to inf after 37 steps: the run ended mid-training with an error naming a cell,
not the setting."""


@dataclass
class ObservationConfig:
    """Scales of the observation parts (values in ``configs/env``)."""

    velocity_scale: float = 1.0
    param_scale: float = 1.0
    energy_scale: float = 1.0

    def validate(self) -> None:
        for k in ("velocity_scale", "param_scale", "energy_scale"):
            v = getattr(self, k)
            require(math.isfinite(v) and 0 < v <= MAX_OBSERVATION_SCALE, k,
                    f"expected a finite scale in (0, {MAX_OBSERVATION_SCALE:g}] (MAX_OBSERVATION_SCALE: the "
                    f"observations are float32), got {v}")  # fmt: skip


@dataclass
class EnvConfig:
    """Calibration environment settings; values and their meaning in ``configs/env/default.yaml``."""

    vehicle: str = "b_segment"
    vehicle_seed: int | None = None
    vehicle_options: VehicleOptions = field(default_factory=VehicleOptions)
    discretization: Literal["optimized", "uniform"] = "optimized"
    sensors: list[str] = field(default_factory=list)
    scenarios: dict[str, float] = field(default_factory=lambda: dict.fromkeys(DEFAULT_SCENARIOS, 1.0))
    granularity: Literal["subassembly", "cell"] = "subassembly"
    max_step: float = 0.1
    behaviour_bounds: list[float] = field(default_factory=lambda: [0.25, 4.0])
    transmission_floor: float = 0.01
    agents: AgentsConfig = field(default_factory=lambda: AgentsConfig(split_lr=list(DEFAULT_SPLIT_LR)))
    masking: MaskingConfig = field(default_factory=MaskingConfig)
    reward: str = "log_ratio"
    termination: TerminationConfig = field(default_factory=shipped_termination)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    metrics_backend: Literal["numba", "torch"] = "numba"
    sim_backend: Literal["numba", "torch", "auto"] = "auto"
    sim_dtype: Literal["float64", "float32"] = "float64"
    seed: int = 0

    def validate(self) -> None:
        try:
            self.vehicle_options.require_fits(self.vehicle)
        except ConfigError as e:
            raise ConfigError(e.reason, key=f"vehicle_options.{e.key}") from None
        if not is_deck(self.vehicle) and Path(self.vehicle).suffix.lower() not in (".yaml", ".yml"):
            vehicle_config_path(self.vehicle)  # a registered name: an unknown one now, not when the env is built
        require(self.vehicle_seed is None or _is_int_at_least(self.vehicle_seed, 0), "vehicle_seed",
                f"expected a seed >= 0 or null (the nominal car), got {self.vehicle_seed!r}")  # fmt: skip
        if is_deck(self.vehicle):  # now, not when the env is built (or a cross-fidelity seed is first drawn)
            variants = {"vehicle_seed": self.vehicle_seed}
            if self.reference.kind == "cross_fidelity":
                seeds = self.reference.cross_fidelity.vehicle_seeds
                variants.update({f"reference.cross_fidelity.vehicle_seeds[{i}]": v for i, v in enumerate(seeds)})
            for key, seed in variants.items():
                require(seed is None, key, f"the vehicle {self.vehicle!r} is a keyword deck, which has no variants; "
                                           f"expected null (the deck as read), got {seed!r}")  # fmt: skip
        require(_is_int_at_least(self.seed, 0), "seed", f"expected a seed >= 0, got {self.seed!r}")
        twice = sorted({s for s in self.sensors if self.sensors.count(s) > 1})
        require(not twice, "sensors", f"names {twice} more than once; each sensor is compared once (an empty list: "
                                      "every sensor of the cell model)")  # fmt: skip
        require(bool(self.scenarios), "scenarios", "expected at least one scenario name with a weight")
        known = list_scenarios()
        for k, w in self.scenarios.items():
            require(k in known, f"scenarios.{k}", f"unknown scenario {k!r}; registered (configs/scenarios/): {known}")
            require(math.isfinite(w) and w > 0, f"scenarios.{k}", f"expected a weight > 0, got {w}")
        fine = self.reference.cross_fidelity.substeps
        if self.reference.kind == "cross_fidelity" and fine is not None:  # now, not in the fine model's simulator
            for k in self.scenarios:
                sc = get_scenario(k)
                require(steps_per_output(sc.output_dt, fine) is not None, "reference.cross_fidelity.substeps",
                        f"the fine model's {fine} steps per {BASE_OUTPUT_DT * 1e3:g} ms do not fit a whole number "
                        f"in the {sc.output_dt * 1e3:.6g} ms output step of scenario {k!r} ({sc.output_rate:g} Hz); "
                        f"expected substeps that make it one, or null (configs/sim.yaml's)")  # fmt: skip
        require(0.0 < self.max_step <= 2.0, "max_step", f"expected a log increment in (0, 2], got {self.max_step}")
        b = self.behaviour_bounds
        m = MAX_BEHAVIOUR_FACTOR
        require(len(b) == 2 and 1.0 / m <= b[0] <= 1.0 <= b[1] <= m, "behaviour_bounds",
                f"expected [lo, hi] with {1.0 / m:g} <= lo <= 1 <= hi <= {m:g} (factors of the initial E_x, E_s; "
                f"MAX_BEHAVIOUR_FACTOR), got {b}")  # fmt: skip
        require(0.0 < self.transmission_floor <= 1.0, "transmission_floor",
                f"expected a value in (0, 1], got {self.transmission_floor}")  # fmt: skip
        require_reward(self.reward, "reward")  # now, not when an env is built from it


def env_config_path(name: str) -> Path:
    """``configs/env/<name>.yaml``."""
    return config_dir() / "env" / f"{name}.yaml"


def require_env(name: str | Path, key: str = "env") -> None:
    """Refuse, naming ``key`` (the setting that names the env, for a schema's ``validate()``), an env config that
    is neither registered (``configs/env/<name>.yaml``) nor a ``.yaml`` file path."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml"):
        require(path.is_file(), key, f"no env config file {str(name)!r}; expected a registered name or a YAML file")
    elif not env_config_path(str(name)).is_file():
        known = sorted(p.stem for p in (config_dir() / "env").glob("*.yaml"))
        raise ConfigError(f"unknown env config {str(name)!r}; registered: {known}", key=key)


def load_env_config(name_or_path: str | Path = "default", overrides: dict | None = None) -> EnvConfig:
    """Load an env config by registered name (``configs/env/<name>.yaml``) or path, with dotted overrides."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        require_env(name_or_path)
        path = env_config_path(str(name_or_path))
    config = load_config(EnvConfig, path, overrides, complete=True)  # values live in the file, not the schema
    vars(config)["_source"] = str(path)  # no schema field: for errors found later, when the environment is built
    return config


def require_env_keys_unset(
    env_overrides: dict[str, Any], owners: dict[str, str], overrides_key: str = "env_overrides"
) -> None:
    """Refuse an env override of a key that another setting decides (``owners``: env key -> that setting).

    The caller's code sets those keys after the overrides, so an override of one (or of a key within it) would be
    replaced without a word; the error names ``<overrides_key>.<key>`` and the setting to use instead.
    """
    for k in flatten_overrides(EnvConfig, env_overrides):
        for p, owner in owners.items():
            if k == p or k.startswith(p + "."):
                raise ConfigError(f"{p} is set by {owner}, which would replace this value; set that instead",
                                  key=f"{overrides_key}.{k}")  # fmt: skip


def env_config_of(
    env: str,
    env_overrides: dict[str, Any],
    extra: dict[str, Any] | None = None,
    *,
    env_key: str = "env",
    overrides_key: str = "env_overrides",
) -> EnvConfig:
    """:func:`load_env_config` for a config that names an env (``env_key``) and overrides of it (``overrides_key``),
    then ``extra``, the settings its code adds; an error is keyed as the user set it.

    A bad or misplaced override is named ``<overrides_key>.<key>`` without the env file (it is not in that file;
    the caller adds its own with :func:`~marlcrash.config.nested_error`), an unknown env ``env_key``; an error of
    the env file's own keys names that file and key.
    """
    given = list(flatten_overrides(EnvConfig, env_overrides))
    try:
        return load_env_config(env, {**env_overrides, **(extra or {})})
    except ConfigError as e:
        k = e.key or ""
        if e.path is None and k == "env":
            raise ConfigError(e.reason, key=env_key) from None
        if overridden(k, given):
            raise ConfigError(e.reason, key=f"{overrides_key}.{k}") from None
        raise


def overridden(key: str, given: list[str]) -> bool:
    """An error's dotted ``key`` is about a value that one of the dotted override keys ``given`` set: that key, a key
    within an overridden section (``agents.split_lr`` where ``agents`` is given), or the section of an overridden key
    (``agents`` where ``agents.rest`` is given)."""
    return any(key == o or key.startswith((o + ".", o + "[")) or o.startswith(key + ".") for o in given)


def _is_int_at_least(value: Any, lo: int) -> bool:
    """``value`` is an integer (Python or numpy, not a bool) ``>= lo``."""
    return not isinstance(value, bool | np.bool_) and isinstance(value, int | np.integer) and bool(value >= lo)


def check_env_args(config: Any, batch_size: Any, cells: Any = None) -> int:
    """Refuse an env's constructor arguments that are not an :class:`EnvConfig`, a whole number of episodes
    >= 1 (a numpy integer too) and a :class:`~marlcrash.cells.model.CellModel` or ``None``; return ``batch_size`` as
    an ``int``. Arguments, not keys of the env's YAML file.

    Raises:
        ConfigError: named ``config``, ``batch_size`` or ``cells``, without a file.
    """
    if not isinstance(config, EnvConfig):
        hint = f" (load_env_config({config!r}))" if isinstance(config, str | Path) else ""
        raise ConfigError(f"expected an EnvConfig{hint}, got {type(config).__name__}", key="config")
    if not _is_int_at_least(batch_size, 1):
        raise ConfigError(f"batch_size must be a positive integer, got {batch_size!r}", key="batch_size")
    if cells is not None and not isinstance(cells, CellModel):  # a vehicle's name failed on '.sensor_names'
        hint = "; the vehicle to discretize is config.vehicle" if isinstance(cells, str | Path) else ""
        raise ConfigError(f"expected a CellModel or None (None: discretize config.vehicle){hint}, got "
                          f"{type(cells).__name__}", key="cells")  # fmt: skip
    return int(batch_size)


def build_cells(vehicle: str, seed: int | None, method: str, options: VehicleOptions | None = None) -> CellModel:
    """Discretize a registered vehicle (or a vehicle file, read with ``options``) once per process and cache it
    (the :data:`_CELLS_KEPT` used last), keyed by the configs folder and ``cells.yaml``'s values too (a changed
    ``MARLCRASH_CONFIGS`` used to get the model built from the folder before), by a vehicle file's and a sub-assembly
    map's resolved paths (a relative path read after a change of folder names another file), and rebuilt when a file
    it was built from (under the configs folder, the deck and its ``*INCLUDE``s, the map) changed since: it was kept
    by the path as typed, so an edited deck read again in the same process gave the old deck's cells."""
    from marlcrash.cells.discretize import discretize, load_discretization_config
    from marlcrash.vehicle.registry import load_configured_vehicle

    options = options or VehicleOptions()
    cell_config = load_discretization_config()
    where = str(Path(vehicle).resolve()) if Path(vehicle).suffix else vehicle  # a registered name has no suffix
    sub = None if options.subassemblies is None else str(Path(options.subassemblies).resolve())
    key = (where, seed, method, options.key(), sub, str(config_dir().resolve()), repr(cell_config))
    kept = _CELLS.pop(key, None)  # put back last: the least recently used goes first
    if kept is not None and _files_state(kept[1]) == kept[2]:
        _CELLS[key] = kept
        return kept[0]
    files = _input_files(vehicle, options)
    state = _files_state(files)  # before reading: a file changed while it is read is read again next time
    cells = discretize(load_configured_vehicle(vehicle, seed, options), cell_config, method=method)
    _CELLS[key] = (cells, files, state)
    while len(_CELLS) > _CELLS_KEPT:
        _CELLS.pop(next(iter(_CELLS)))
    return cells


def _input_files(vehicle: str, options: VehicleOptions) -> list[Path]:
    """The files a cell model of ``vehicle`` is built from: those under the configs folder (a registered car's YAML,
    the materials, ``cells.yaml``: the run's recorded inputs, :func:`marlcrash.provenance.config_files`), a vehicle
    file with its ``*INCLUDE``s and a sub-assembly map."""
    from marlcrash.provenance import config_files, with_includes

    files = config_files()
    if Path(vehicle).suffix:
        files += with_includes(Path(vehicle).resolve())
    if options.subassemblies is not None:
        files.append(Path(options.subassemblies).resolve())
    return files


def _files_state(files: list[Path]) -> tuple:
    """Modification time and size of every file (``None`` for one that is gone): what tells that it changed."""
    out: list[tuple[int, int] | None] = []
    for p in files:
        try:
            st = p.stat()
            out.append((st.st_mtime_ns, st.st_size))
        except OSError:
            out.append(None)
    return tuple(out)


_CELLS: dict[tuple, tuple[CellModel, list[Path], tuple]] = {}
_CELLS_KEPT = 4


# ------------------------------------------------------------------------------------------ the core
def _put(t: torch.Tensor, rows: torch.Tensor | slice, values: torch.Tensor) -> torch.Tensor:
    """A copy of ``t`` with ``values`` in ``rows`` (the state tensors are replaced, never written in place: a caller
    may hold the previous ones)."""
    out = t.clone()
    out[rows] = values
    return out


class CalibrationCore:
    """``B`` batched calibration episodes (module docstring).

    Args:
        config: the env config (:func:`load_env_config`).
        batch_size: ``B``.
        cells: the model to calibrate; ``None`` discretizes ``config.vehicle`` (cached).
        sim_config: simulator settings; ``None`` loads ``configs/sim.yaml`` with the env config's ``sim_dtype``.

    Raises:
        ConfigError: an invalid value (a config made or changed in Python is checked as a file's values are), or
            invalid agents, scenarios, sensors or reference settings.
    """

    def __init__(
        self,
        config: EnvConfig,
        batch_size: int = 1,
        cells: CellModel | None = None,
        sim_config: SimConfig | None = None,
    ):
        batch_size = check_env_args(config, batch_size, cells)  # arguments: not keys of the env's YAML file
        source = getattr(config, "_source", None)
        try:
            # the loaders check a file's values; an EnvConfig made or changed in Python (EnvConfig() in a notebook)
            # skipped that: a misspelt masking.mode ran primary_secondary, a granularity 'cells' per-cell actions.
            # The env runs the checked copy: a section given as a mapping (EnvConfig(masking={"mode": "none"}))
            # passed the check as such and failed later with "'dict' object has no attribute ..."
            config = checked(config)
            if source is not None:
                vars(config)["_source"] = source
            self._build(config, batch_size, cells, sim_config)
        except ConfigError as e:  # name the YAML file the bad key came from
            if e.path is None and source is not None:
                raise ConfigError(e.reason, key=e.key, path=source) from None
            raise

    def _build(self, config: EnvConfig, batch_size: int, cells: CellModel | None, sim_config: SimConfig | None) -> None:
        self.config = cfg = config
        self.B = batch_size
        if cells is None:
            cells = build_cells(cfg.vehicle, cfg.vehicle_seed, cfg.discretization, cfg.vehicle_options)
        self.cells = cells
        self.sensors = list(cfg.sensors) or list(self.cells.sensor_names)
        rcfg = load_reward_config(cfg.reward)
        rcfg.termination = cfg.termination
        self.reward_fn = Reward(rcfg)
        self.layout = build_agents(self.cells, cfg.agents)
        self.regions = ImpactRegions(self.cells, self.layout, cfg.masking)
        from marlcrash.sim.scenario import get_scenario

        ref = cfg.reference  # the scenarios drawn: a file reference's are those of the tests it draws
        files = [f for f in ref.files if ref.file_scenario in (None, f.scenario)]
        drawn = cfg.scenarios if ref.kind != "file" else dict.fromkeys(f.scenario for f in files)
        idle = self.regions.idle_scenarios([get_scenario(name) for name in drawn])
        if idle:
            warnings.warn(f"{'; '.join(idle)}: such episodes calibrate nothing. On a deck, check that its axes map "
                          "onto marlcrash's (vehicle_options.axis_map: x rearward, y to the left, z up); else lower "
                          "masking.min_fraction or widen the depths", stacklevel=3)  # fmt: skip
        sim_cfg = sim_config if sim_config is not None else load_sim_config(overrides={"dtype": cfg.sim_dtype})
        rate = get_scenario(next(iter(drawn))).output_rate  # the sampler checks that all of them have it
        self.sim = Surrogate(self.cells, sim_cfg, output_dt=1.0 / rate)
        self.sampler = ReferenceSampler(
            self.cells, self.sim, self.sensors, cfg.scenarios, cfg.reference, vehicle=cfg.vehicle,
            vehicle_options=cfg.vehicle_options, bounds=(cfg.behaviour_bounds[0], cfg.behaviour_bounds[1]),
            floor=cfg.transmission_floor, backend=cfg.sim_backend, vehicle_seed=cfg.vehicle_seed,
        )  # fmt: skip
        self.duration, self.dt = self.sampler.duration, 1.0 / self.sampler.output_rate
        self.T, self.K = self.sampler.n_outputs, len(self.sensors)
        lay = self.layout
        self.A, self.M = lay.n_agents, lay.max_cells
        self.act_dim = 7 if cfg.granularity == "subassembly" else 7 * self.M
        own_dim = 7 if cfg.granularity == "subassembly" else 7 * self.M
        self.obs_dim = self.K * self.T + own_dim + self.M + self.A
        self.state_dim = self.K * self.T + 8 * self.A

        n = self.cells.n_cells
        f64 = torch.float64
        self.init = torch.as_tensor(self.cells.params, dtype=f64)
        self.feasible = torch.as_tensor(self.cells.feasible)
        # [n, 7] where an observed log-ratio is defined: E > 0, feasible transmission factors (shifted by the floor)
        self._observed = torch.cat([self.init[:, :2] > 0, self.feasible], dim=1)
        self._warned_failed = False  # episodes that start past the failure limits are warned about once
        self._owned = lay.owned[None, :, None]
        self._agent_of = lay.agent_of_cell.clamp_min(0)
        self._slot_of = lay.slot_of_cell.clamp_min(0)
        self._eye = torch.eye(self.A, dtype=torch.float32)
        valid = lay.valid[:, :, None].expand(self.A, self.M, 7)
        movable = movable_factors(self.feasible)  # a lone feasible factor stays one whatever the action
        feas = torch.cat([torch.ones(n, 2, dtype=torch.bool), movable], dim=1)[lay.cells]  # [A, M, 7]
        self._slot_action_mask = valid & feas  # [A, M, 7] the factors each cell slot takes
        self._static_action_mask = (  # a sub-assembly factor acts where one of the agent's cells takes it
            self._slot_action_mask.any(1)
            if cfg.granularity == "subassembly"
            else self._slot_action_mask.reshape(self.A, -1)
        )
        self._summary_w = (lay.valid[:, :, None] & self._observed[lay.cells]).to(f64)  # [A, M, 7]
        self._summary_n = self._summary_w.sum(1).clamp_min(1.0)  # [A, 7]

        B = self.B
        self.params = self.init[None].repeat(B, 1, 1)
        self.ref_velocity = torch.zeros(B, self.K, self.T, dtype=f64)
        self.est_velocity = torch.zeros(B, self.K, self.T, dtype=f64)
        self.speed = torch.zeros(B, dtype=f64)
        self.overlap = torch.ones(B, dtype=f64)
        self.side = torch.ones(B, dtype=f64)
        self.margin = torch.zeros(B, dtype=torch.int64)  # samples simulated past the window (ReferenceBatch.margin)
        self.active = torch.ones(B, self.A, dtype=torch.bool)
        self.acting = torch.ones(B, n, dtype=torch.bool)  # cells an active agent acts on (masking.cells)
        self.saturated = torch.zeros(B, n, dtype=torch.bool)
        self.energy_fraction = torch.zeros(B, n, dtype=f64)
        self.metrics = Metrics(*(torch.zeros(B, self.K, dtype=f64) for _ in range(3)))
        self.iteration = torch.zeros(B, dtype=torch.int64)
        self.started = torch.zeros(B, dtype=torch.bool)  # rows that had a reset (an episode to step)
        self.reward = torch.zeros(B, dtype=f64)
        self.terminated = torch.zeros(B, dtype=torch.bool)
        self.truncated = torch.zeros(B, dtype=torch.bool)
        self.success = torch.zeros(B, dtype=torch.bool)
        self.scenario: list[str] = [""] * B
        self.source: list[str] = [""] * B  # each row's reference origin (ReferenceBatch.source: twin, a file path)
        self.true_params: torch.Tensor | None = None
        self.rng = np.random.default_rng(cfg.seed)
        self.simulation_hooks: list[Callable[[torch.Tensor, Metrics], None]] = []

    # ------------------------------------------------------------------------------------ seeding
    def seed(self, seed: int | None) -> None:
        """Re-seed the core's own generator (the global RNGs are never touched).

        Raises:
            ActionError: ``seed`` is not ``None`` or an integer >= 0 (numpy's own message did not say which value).
        """
        if seed is not None and not _is_int_at_least(seed, 0):
            raise ActionError(f"seed must be an integer >= 0 or None, got {seed!r}")
        self.rng = np.random.default_rng(seed)

    # --------------------------------------------------------------------------------- simulation
    def _simulate(self, rows: torch.Tensor | slice) -> Metrics:
        # past the window by the rows' largest margin (a measured reference filtered over a longer record); the
        # energy fractions and saturation below are at the window's end whatever the margin
        margin = self.margin[rows]
        with torch.no_grad():
            res = self.sim.run(self.params[rows], speed=self.speed[rows], overlap=self.overlap[rows],
                               side=self.side[rows], duration=self.duration + int(margin.max()) * self.dt,
                               sensors=self.sensors, record_cells="final", backend=self.config.sim_backend,
                               cells_at=self.duration)  # fmt: skip
        est = self.sampler.compared(res.velocity, margin)
        self.est_velocity[rows] = est
        e_s = self.params[rows][..., 1]
        absorbed = res.cell_absorbed[..., -1].to(torch.float64)
        self.energy_fraction[rows] = torch.where(e_s > 0, absorbed / torch.where(e_s > 0, e_s, 1.0), 0.0)
        self.saturated[rows] = res.saturated
        ref = self.ref_velocity[rows]
        m = compute_metrics(
            est, ref, dt=self.dt, config=self.reward_fn.cfg.metrics, backend=self.config.metrics_backend
        )
        for hook in self.simulation_hooks:
            hook(self.params[rows].clone(), Metrics(*(t.clone() for t in m)))
        return m

    # -------------------------------------------------------------------------------------- reset
    def reset(self, seed: int | None = None, mask: torch.Tensor | None = None) -> None:
        """Start new episodes in the rows of ``mask`` (``[B]`` bool; all rows if ``None``).

        Draws scenario and reference per row with the core's generator (re-seeded first when
        ``seed`` is given; with ``reference.pin_seed`` every row gets the pinned reference instead),
        resets parameters, fixes the active agents and simulates once. The rows of ``mask`` are drawn in
        one :meth:`~marlcrash.references.ReferenceSampler.sample` call, row by row, so after ``reset(seed=s)``
        rows 0-3 of a batch of 8 have the references of a batch of 4; later resets go on from where the
        generator stands, so from then on which reference a row gets depends on ``B`` and on which rows reset
        together (pin the reference to keep it).

        Raises:
            ActionError: a bad ``seed`` or ``mask``; a refused call changes nothing (the generator included).
        """
        rows = torch.arange(self.B) if mask is None else torch.nonzero(self._row_mask(mask, "reset")).flatten()
        if seed is not None:
            self.seed(seed)
        if rows.numel() == 0:
            return
        pin = self.config.reference.pin_seed
        n = int(rows.numel())
        ref = self.sampler.sample(self.rng, n) if pin is None else self.sampler.pinned(pin, n)
        for i, r in enumerate(rows.tolist()):  # scenario names: per-row Python strings
            self.scenario[r] = ref.scenario[i]
            self.source[r] = ref.source[i]
        self.speed[rows], self.overlap[rows], self.side[rows] = ref.speed, ref.overlap, ref.side
        self.ref_velocity[rows] = ref.velocity
        self.margin[rows] = 0 if ref.margin is None else ref.margin
        if ref.true_params is not None:
            if self.true_params is None:
                self.true_params = self.init[None].repeat(self.B, 1, 1)
            self.true_params[rows] = ref.true_params
        self.params[rows] = self.init
        region = self.regions.region(ref.overlap, ref.side, ref.speed)
        self.active[rows] = self.regions.active(ref.overlap, ref.side, ref.speed, region)
        self.acting[rows] = region if self.config.masking.cells == "region" else True
        m = self._simulate(rows)
        for old, new in zip(self.metrics, m, strict=True):
            old[rows] = new
        self._warn_failed_at_reset(rows, m)
        self.iteration[rows] = 0
        self.started[rows] = True
        self.reward[rows] = 0.0
        self.terminated[rows] = False
        self.truncated[rows] = False
        self.success[rows] = False

    def _warn_failed_at_reset(self, rows: torch.Tensor, m: Metrics) -> None:
        """Warn (once per core) where an episode starts past a failure limit: it ends as a failure at its first
        step whatever the agents do, so its reward teaches nothing (a reference this model cannot come near)."""
        if self._warned_failed:
            return
        cfg = self.reward_fn.cfg.termination
        over = []
        for metric in ("area", "dfd", "rmse"):
            limit = getattr(cfg, f"failure_{metric}")
            worst = getattr(m, metric).amax(-1)  # [n]
            if limit is not None and bool((worst > limit).any()):
                i = int(worst.argmax())
                where = self.scenario[int(rows[i])]
                over.append(f"{metric} {float(worst[i]):.4g} > failure_{metric} {limit:g} ({where})")
        if over:
            self._warned_failed = True
            warnings.warn(f"episodes start past the failure limits: {'; '.join(over)}. They end as failures at the "
                          f"first step whatever the agents do (reference.kind {self.config.reference.kind}); raise "
                          "termination.failure_* or set them to null", stacklevel=3)  # fmt: skip

    # ------------------------------------------------------------------------------------ actions
    def check_actions(self, actions: torch.Tensor | np.ndarray, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Validate ``[B, n_agents, act_dim]`` float actions (on any device); return them clipped to [-1, 1] as
        float64 on the CPU.

        ``rows`` (``[B]`` bool; every row if ``None``): the rows that act; the others' actions are ignored as an
        inactive agent's are.

        The actions are detached from any autograd graph: the simulation is not differentiated through, and a
        policy's output taken with gradients (``env.rollout(n, policy)`` outside ``torch.no_grad()``) would
        otherwise tie the parameters, and every later observation, to that graph, which grew with every step.

        Raises:
            ActionError: wrong type, shape or dtype, or NaN/inf entries of active agents (named by index); such
                entries where :meth:`action_mask` is false are ignored, and returned as zero.
        """
        if isinstance(actions, np.ndarray):
            if actions.dtype.kind != "f":
                raise ActionError(f"actions must be floating point (float32 or float64), got numpy {actions.dtype}")
            actions = torch.from_numpy(np.array(actions, order="C"))  # a copy: flipped or read-only arrays are fine
        if not isinstance(actions, torch.Tensor):
            raise ActionError(f"actions must be a tensor [B, n_agents, act_dim], got {type(actions).__name__}")
        want = (self.B, self.A, self.act_dim)
        if tuple(actions.shape) != want:
            raise ActionError(
                f"actions must have shape [B={self.B}, n_agents={self.A}, act_dim={self.act_dim}] "
                f"({self.config.granularity} granularity), got {list(actions.shape)}"
            )
        if not actions.is_floating_point():
            raise ActionError(f"actions must be floating point (float32 or float64), got {actions.dtype}")
        actions = actions.detach().cpu()  # the simulation's device: a TorchRL env's actions may come from a GPU
        used = self.action_mask()  # inactive agents' and padded entries are ignored (as the PettingZoo door does)
        if rows is not None:
            used = used & rows[:, None, None]
        bad = ~torch.isfinite(actions) & used
        if bool(bad.any()):
            b, a, j = (int(x) for x in torch.nonzero(bad)[0])
            raise ActionError(
                f"actions must be finite; actions[{b}, {a}, {j}] (agent {self.layout.names[a]!r}) is "
                f"{float(actions[b, a, j])} ({int(bad.sum())} non-finite entries)"
            )
        actions = actions.to(torch.float64)
        return torch.where(used | torch.isfinite(actions), actions.clamp(-1.0, 1.0), 0.0)  # finite ones: as given

    def increments(self, actions: torch.Tensor) -> torch.Tensor:
        """Per-cell log increments ``[B, n_cells, 7]`` from checked actions ``[B, n_agents, act_dim]``.

        Inactive agents and unowned cells get zero; with the saturation preference, behaviour
        increments of cells saturated in the last simulation are damped.
        """
        a = actions * self.config.max_step * self.active[..., None]  # float64: not max_step * bool (float32)
        if self.config.granularity == "subassembly":
            inc = a[:, self._agent_of]  # [B, n, 7]
        else:
            inc = a.view(self.B, self.A, self.M, 7)[:, self._agent_of, self._slot_of]
        inc = inc * (self._owned & self.acting[..., None])
        m = self.config.masking
        if m.saturation_preference:
            damp = torch.where(self.saturated, torch.tensor(m.saturation_damping, dtype=inc.dtype), 1.0)
            inc = torch.cat([inc[..., :2] * damp[..., None], inc[..., 2:]], dim=-1)
        return inc

    def apply_actions(self, actions: torch.Tensor | np.ndarray, rows: torch.Tensor | None = None) -> None:
        """Check and apply actions to the parameters, without simulating (``rows``: ``[B]`` bool, the rows that
        act; the others keep their parameters bit for bit; every row if ``None``)."""
        inc = self.increments(self.check_actions(actions, rows))
        lo, hi = self.config.behaviour_bounds
        params = apply_increments(self.params, inc, self.init, self.feasible, (lo, hi),
                                  self.config.transmission_floor)  # fmt: skip
        self.params = params if rows is None else torch.where(rows[:, None, None], params, self.params)

    def action_mask(self) -> torch.Tensor:
        """``[B, n_agents, act_dim]`` bool: entries that act (active agent; per cell, a valid slot and a feasible
        factor; per sub-assembly, a factor some cell of the agent takes; where ``masking.cells`` is ``region``, of
        its cells in the region only)."""
        mask = self._static_action_mask[None] & self.active[..., None]
        if self.config.masking.cells == "region":
            lay = self.layout
            acting = self.acting[:, lay.cells.clamp_min(0)] & lay.valid  # [B, A, M]
            if self.config.granularity == "cell":
                mask = mask & acting[..., None].expand(-1, -1, -1, 7).reshape(self.B, self.A, -1)
            else:
                mask = mask & (self._slot_action_mask[None] & acting[..., None]).any(2)
        return mask

    # --------------------------------------------------------------------------------------- step
    def step(self, actions: torch.Tensor | np.ndarray, mask: torch.Tensor | None = None) -> None:
        """Apply actions, simulate the rows of ``mask`` once, update their metrics, reward and end flags.

        ``mask``: ``[B]`` bool, the rows to step (all rows if ``None``; TorchRL's ``"_step"`` entry, which a
        ``rollout(..., break_when_all_done=True)`` sets to the rows whose episodes go on). The other rows are
        not simulated and keep their parameters, metrics, iteration and end flags; their actions are ignored
        and their reward is 0.

        Raises:
            ActionError: bad actions (:meth:`check_actions`), a bad ``mask``, or a stepped row that was never reset
                (no reference yet) or whose episode has ended (:attr:`done`) and was not reset since.
        """
        rows = None if mask is None else self._row_mask(mask, "step")
        ready = self.started if rows is None else self.started | ~rows
        if not bool(ready.all()):
            bad = torch.nonzero(~ready).flatten().tolist()
            raise ActionError(f"call reset() before step(): rows {bad} of {self.B} have no episode yet")
        ended = self.done if rows is None else self.done & rows
        if bool(ended.any()):  # stepped on, an episode went past its end, its steps part of no episode
            bad = torch.nonzero(ended).flatten().tolist()
            raise ActionError(f"rows {bad} of {self.B} have ended (terminated or truncated); reset them before "
                              "stepping them again (TorchRL: a '_reset' entry, step_and_maybe_reset or a rollout reset "
                              "them) or leave them out of the step ('_step')")  # fmt: skip
        self.apply_actions(actions, rows)  # checked first: a refused step changes nothing
        self.reward = torch.zeros(self.B, dtype=torch.float64)
        idx: slice | torch.Tensor = slice(None)
        if rows is not None:
            idx = torch.nonzero(rows).flatten()
            if idx.numel() == 0:
                return
        prev = Metrics(*(t[idx] for t in self.metrics))
        m = self._simulate(idx)
        self.metrics = Metrics(*(_put(t, idx, v) for t, v in zip(self.metrics, m, strict=True)))
        self.iteration[idx] += 1
        self.reward[idx] = self.reward_fn(m, prev).to(torch.float64)
        term = self.reward_fn.termination(m, self.iteration[idx])
        self.success = _put(self.success, idx, term.success)
        self.terminated = _put(self.terminated, idx, term.success | term.failure)
        self.truncated = _put(self.truncated, idx, term.truncated & ~(term.success | term.failure))

    def _row_mask(self, mask: torch.Tensor, what: str) -> torch.Tensor:
        """``mask`` as ``[B]`` bool (a ``[B, 1]`` one too; integers only if all 0 or 1); :class:`ActionError` naming
        ``what`` otherwise. Cast to bool first, row indices ``[0, 2, 1, 3]`` read as ``[F, T, T, T]``, a float mask
        as non-zero, and any shape of ``B`` elements was taken: the wrong rows were reset or stepped."""
        try:
            m = torch.as_tensor(mask, device="cpu")
        except (TypeError, ValueError, RuntimeError) as e:
            raise ActionError(f"{what} mask must be [{self.B}] bool, got {type(mask).__name__} ({e})") from None
        if m.shape not in ((self.B,), (self.B, 1)) and not (self.B == 1 and m.dim() == 0):
            raise ActionError(
                f"{what} mask must be [{self.B}] bool, got shape {list(m.shape)} ([{self.B}, 1] is taken too)"
            )
        integer = not (m.is_floating_point() or m.is_complex() or m.dtype == torch.bool)
        if m.dtype != torch.bool and not (integer and bool(((m == 0) | (m == 1)).all())):
            raise ActionError(
                f"{what} mask must be [{self.B}] bool (one flag per row, not row indices), got dtype "
                f"{str(m.dtype).removeprefix('torch.')} with values {m.reshape(-1)[:8].tolist()}"
            )
        return m.reshape(-1).to(torch.bool)

    @property
    def done(self) -> torch.Tensor:
        """``[B]`` bool, episode over (terminated or truncated)."""
        return self.terminated | self.truncated

    # ------------------------------------------------------------------------------- observations
    def _log_ratio(self) -> torch.Tensor:
        return log_ratios(self.params, self.init, self._observed, self.config.transmission_floor)

    def state_vector(self) -> torch.Tensor:
        """``[B, K * T]`` scaled signed differences reference minus estimate (DESIGN 1.4)."""
        d = (self.ref_velocity - self.est_velocity) * self.config.observation.velocity_scale
        return d.reshape(self.B, -1)

    def observations(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-agent observations ``[B, n_agents, obs_dim]`` and global state ``[B, state_dim]`` (float32)."""
        o = self.config.observation
        lay = self.layout
        sv = self.state_vector().to(torch.float32)
        lr = self._log_ratio()[:, lay.cells]  # [B, A, M, 7]
        summary = (lr * self._summary_w).sum(2) / self._summary_n  # [B, A, 7]
        if self.config.granularity == "subassembly":
            own = summary * o.param_scale
        else:
            own = (lr * lay.valid[..., None]).reshape(self.B, self.A, -1) * o.param_scale
        energy = self.energy_fraction[:, lay.cells] * lay.valid  # [B, A, M]
        obs = torch.cat(
            [
                sv[:, None, :].expand(self.B, self.A, sv.shape[1]),
                own.to(torch.float32),
                (energy * o.energy_scale).to(torch.float32),
                self._eye.expand(self.B, self.A, self.A),
            ],
            dim=-1,
        )
        mean_energy = energy.sum(-1) / lay.count
        state = torch.cat(
            [sv, (summary * o.param_scale).reshape(self.B, -1).float(), (mean_energy * o.energy_scale).float()], dim=-1
        )
        return obs, state
