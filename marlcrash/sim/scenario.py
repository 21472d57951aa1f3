"""Crash scenarios (DESIGN 1.2, 4): impact speed, barrier overlap and side, output timing.

A :class:`CrashScenario` is a validated schema whose values live in
``configs/scenarios/<name>.yaml`` (or ``.yml``; km/h there, m/s inside). The registry maps
file names to scenarios: :func:`list_scenarios`, :func:`get_scenario`.

Barrier geometry: x points rearward, +y is the vehicle's left. A rigid wall
perpendicular to x covers ``o*W`` of the vehicle width ``W`` from the outer edge of
the struck side, ``o`` the overlap fraction: the lateral band ``y >= y0 + W/2 - o*W``
(side ``left``) or ``y <= y0 - W/2 + o*W`` (side ``right``), ``y0`` the vehicle's centre
line (``CellModel.centre_y``, the reference of the section planes too:
:func:`marlcrash.cells.roi.barrier_edge`); the band extends beyond the vehicle's edge,
as a real barrier face does. :func:`barrier_mask` gives each cell's covered front-area fraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from marlcrash.cells.model import CellModel
from marlcrash.cells.roi import barrier_edge
from marlcrash.config import checked, config_dir, load_config, require
from marlcrash.errors import ConfigError, ModelError

KMH = 1.0 / 3.6
"""One km/h in m/s."""

SIDES: tuple[str, ...] = ("left", "right")
"""Struck sides; ``SIDE_SIGN[side]`` is +1 for left (+y) and -1 for right (-y)."""
SIDE_SIGN: dict[str, float] = {"left": 1.0, "right": -1.0}
_PLANE_TOL = 1e-6  # lateral distance [m] below which a cell face counts as lying on a barrier edge
BASE_OUTPUT_DT = 5e-4
"""[s] The output step ``substeps`` (configs/sim.yaml) divides: the integration step is ``BASE_OUTPUT_DT / substeps``
at any output rate (the 2 kHz sensor rate of DESIGN 1.4 the caps were tuned at)."""
MAX_SUBSTEPS = 1000
"""Most integration steps per ``BASE_OUTPUT_DT`` a sim config may ask for (``substeps``) [-]."""
MIN_SPEED_KMH = 1.0
"""Smallest impact speed [km/h], below any crash test (low-speed bumper tests are 4 km/h): a scenario's
``speed_kmh`` and each row's ``speed`` of a run are at least this. Any speed above zero was taken: 1e-170 km/h ran
with an initial kinetic energy of 0 J and a NaN energy balance."""
MAX_SPEED_KMH = 200.0
"""Largest impact speed [km/h]: a scenario's ``speed_kmh`` and each row's ``speed`` of a run are at most this."""
MAX_DURATION_S = 1.0
"""Longest crash window [s]: a scenario's ``duration`` is in (0, this]."""
MAX_RUN_DURATION_S = 2.0
"""Longest simulation of one run [s] (``Surrogate.run``'s ``duration``): a scenario's longest window with room for a
compared record's filter margin (``ReferenceConfig.compare_margin``, at most 0.1 s)."""


def steps_per_output(output_dt: float, substeps: int) -> int | None:
    """Integration steps (``BASE_OUTPUT_DT / substeps`` each) in one output step ``output_dt`` [s]; ``None`` where
    that is no whole number >= 1 (or ``output_dt`` is not finite)."""
    per = output_dt * substeps / BASE_OUTPUT_DT if math.isfinite(output_dt) else math.nan
    if not (per >= 1 - 1e-9 and abs(per - round(per)) <= 1e-6 * per):
        return None
    return round(per)


def output_step_rule(substeps: int) -> str:
    """The end of a message refusing an output step that is no whole number of the integration steps of
    ``substeps``: what those steps are and which output rates fit them."""
    dt = BASE_OUTPUT_DT / substeps
    fits = ", ".join(f"{1 / (k * dt):.6g}" for k in (max(substeps // 2, 1), substeps, 2 * substeps))
    return (
        f"must be a whole number >= 1 of the {dt * 1e6:.6g} us integration steps (configs/sim.yaml substeps: "
        f"{substeps} per {BASE_OUTPUT_DT * 1e3:g} ms); e.g. output rates of {fits} Hz"
    )


@dataclass
class CrashScenario:
    """One frontal crash load case against a rigid barrier.

    Attributes:
        name: registry name (the YAML file stem).
        description: one line for humans.
        speed_kmh: impact speed [km/h] (use :attr:`speed` for m/s).
        overlap: covered fraction of the vehicle width, in (0, 1].
        side: ``left`` (+y, driver side) or ``right`` (-y); irrelevant at overlap 1.
        barrier: barrier type; only ``rigid`` exists.
        duration: simulated window [s].
        output_rate: sensor sampling rate [Hz].
        sensors: names of the sensors to record (empty: all sensors of the model).
    """

    name: str = "scenario"
    description: str = ""
    speed_kmh: float = 56.0
    overlap: float = 1.0
    side: Literal["left", "right"] = "left"
    barrier: Literal["rigid"] = "rigid"
    duration: float = 0.150
    output_rate: float = 2000.0
    sensors: list[str] = field(default_factory=list)

    def validate(self) -> None:
        """Check value ranges; raise :class:`ConfigError` naming the key."""
        require(
            np.isfinite(self.speed_kmh) and MIN_SPEED_KMH <= self.speed_kmh <= MAX_SPEED_KMH,
            "speed_kmh",
            f"impact speed must be in [{MIN_SPEED_KMH:g}, {MAX_SPEED_KMH:g}] km/h, got {self.speed_kmh}",
        )
        require(
            np.isfinite(self.overlap) and 0.0 < self.overlap <= 1.0,
            "overlap",
            f"overlap must be a width fraction in (0, 1], got {self.overlap}",
        )
        require(self.side in SIDES, "side", f"side must be one of {list(SIDES)}, got {self.side!r}")
        require(self.barrier == "rigid", "barrier", f"only a 'rigid' barrier is modelled, got {self.barrier!r}")
        require(
            np.isfinite(self.duration) and 0.0 < self.duration <= MAX_DURATION_S,
            "duration",
            f"duration must be in (0, {MAX_DURATION_S:g}] s, got {self.duration}",
        )
        require(
            np.isfinite(self.output_rate) and 100.0 <= self.output_rate <= 1e5,
            "output_rate",
            f"output_rate must be in [100, 1e5] Hz, got {self.output_rate}",
        )
        # the closest fraction of BASE_OUTPUT_DT with at most MAX_SUBSTEPS in the denominator is the one that fits,
        # if any does: 2000.5 Hz was refused as a duration that is not a whole number of its output steps
        near = Fraction(self.output_dt / BASE_OUTPUT_DT).limit_denominator(MAX_SUBSTEPS)
        require(
            steps_per_output(self.output_dt, near.denominator) is not None,
            "output_rate",
            f"output_rate {self.output_rate:g} Hz: the output step {self.output_dt:.6g} s must be a whole number of "
            f"integration steps ({BASE_OUTPUT_DT * 1e3:g} ms / substeps, configs/sim.yaml), which no substeps in "
            f"[1, {MAX_SUBSTEPS}] gives; e.g. output rates of 500, 1000, 2000, 4000 Hz",
        )
        steps = self.duration * self.output_rate
        require(
            abs(steps - round(steps)) < 1e-6 * max(1.0, steps),
            "duration",
            f"duration {self.duration} s is not a whole number of {self.output_dt} s output steps",
        )
        for i, s in enumerate(self.sensors):  # '' passed here and failed at the run as an unknown sensor
            require(bool(s.strip()), f"sensors[{i}]", f"expected a sensor name, got {s!r}")
        require(len(set(self.sensors)) == len(self.sensors), "sensors", f"duplicate sensor names in {self.sensors}")

    @property
    def speed(self) -> float:
        """Impact speed [m/s]."""
        return self.speed_kmh * KMH

    @property
    def output_dt(self) -> float:
        """Output step [s]."""
        return 1.0 / self.output_rate

    @property
    def n_outputs(self) -> int:
        """Output samples including t = 0 (301 for 150 ms at 2 kHz)."""
        return round(self.duration * self.output_rate) + 1

    @property
    def side_sign(self) -> float:
        """+1 for the left (+y) side, -1 for the right (-y) side."""
        return SIDE_SIGN[self.side]


def _not_a_scenario(value, what: str) -> ModelError:
    return ModelError(
        f"{what} must be a CrashScenario (marlcrash.sim.get_scenario(name)), got {type(value).__name__} {value!r}"
    )


def checked_scenario(scenario: CrashScenario | None) -> CrashScenario | None:
    """``scenario`` checked as a registered file's values are (a :class:`CrashScenario` built in Python skipped that:
    a side of ``up`` failed with a ``KeyError``, a sensor list given as one name was split into letters).

    Raises:
        ModelError: not a :class:`CrashScenario`.
        ConfigError: a wrong type or value, naming the key.
    """
    if scenario is None:
        return None
    if not isinstance(scenario, CrashScenario):
        raise _not_a_scenario(scenario, "scenario")
    return checked(scenario)


def scenario_tensors(scenarios: list[CrashScenario]) -> dict[str, torch.Tensor]:
    """The per-row ``speed`` [m/s], ``overlap`` [-] and ``side`` [-] ``[B]`` float64 tensors of ``scenarios``, the
    per-row arguments of :meth:`~marlcrash.sim.surrogate.Surrogate.run` (float64: torch's default float32 ran 40 km/h
    at 39.9999986 km/h; the simulator casts to its own precision).

    Raises:
        ModelError: ``scenarios`` is no list or tuple, or holds something that is no :class:`CrashScenario`.
        ConfigError: a scenario value of the wrong type or out of range (one made in Python), naming the key.
    """
    if not isinstance(scenarios, list | tuple):  # one scenario: "'CrashScenario' object is not iterable"
        raise ModelError(f"scenarios must be a list of CrashScenario, got {type(scenarios).__name__} {scenarios!r}")
    for i, sc in enumerate(scenarios):
        if not isinstance(sc, CrashScenario):
            raise _not_a_scenario(sc, f"scenarios[{i}]")
    for sc in {id(sc): sc for sc in scenarios}.values():  # each once: a sampled batch repeats a few scenarios
        checked(sc)
    f64 = torch.float64
    return {
        "speed": torch.tensor([s.speed for s in scenarios], dtype=f64),
        "overlap": torch.tensor([s.overlap for s in scenarios], dtype=f64),
        "side": torch.tensor([s.side_sign for s in scenarios], dtype=f64),
    }


def scenario_dir() -> Path:
    """The folder of scenario YAML files."""
    return config_dir() / "scenarios"


def _scenario_files() -> dict[str, list[Path]]:
    """The files of each scenario name (file stem): ``<name>.yaml`` or ``<name>.yml`` (a ``.yml`` file was left out
    of the registry without a word)."""
    found: dict[str, list[Path]] = {}
    for suffix in (".yaml", ".yml"):
        for p in sorted(scenario_dir().glob(f"*{suffix}")):
            if p.is_file():
                found.setdefault(p.stem, []).append(p)
    return found


def list_scenarios() -> list[str]:
    """Names of all registered scenarios (the stems of the ``.yaml`` or ``.yml`` files), sorted."""
    return sorted(_scenario_files())


def get_scenario(name: str, overrides: dict | None = None) -> CrashScenario:
    """Load a registered scenario by name, with optional dotted-key overrides.

    Raises:
        ConfigError: unknown name (the message lists the known ones), an invalid file, or an ``output_rate`` whose
            output step is no whole number of the integration steps of ``configs/sim.yaml``.
    """
    files = _scenario_files()
    if not isinstance(name, str) or name not in files:
        # checked against the registry, not the file system: "" and "../other/x" named files outside it
        raise ConfigError(f"unknown scenario {name!r}; registered: {sorted(files)}", key="scenario")
    if len(files[name]) > 1:
        raise ConfigError(
            f"scenario {name!r} is given by two files, {' and '.join(p.name for p in files[name])}; keep one",
            key="scenario",
        )
    path = files[name][0]
    sc = load_config(CrashScenario, path, overrides, complete=True)
    if sc.name != name:
        raise ConfigError(
            f"scenario file {path.name} declares name {sc.name!r}; expected {name!r}", key="name", path=path
        )
    from marlcrash.sim.surrogate import load_sim_config  # the simulator builds on this module

    # now, not where a Surrogate is built for it (after the deck was read and cut into cells)
    substeps = load_sim_config().substeps
    if steps_per_output(sc.output_dt, substeps) is None:
        raise ConfigError(
            f"output_rate {sc.output_rate:g} Hz: the output step {sc.output_dt:.6g} s {output_step_rule(substeps)}",
            key="output_rate",
            path=path,
        )
    return sc


def barrier_fraction(
    lo_y: torch.Tensor,
    hi_y: torch.Tensor,
    width: float,
    overlap: torch.Tensor,
    side: torch.Tensor,
    *,
    centre_y: float,
) -> torch.Tensor:
    """Covered fraction of each cell's lateral extent, batched over scenarios.

    Args:
        lo_y, hi_y: ``[n]`` lateral bounds of the cells [m].
        width: vehicle width ``W`` [m].
        overlap: ``[B]`` overlap fractions in (0, 1].
        side: ``[B]`` +1 (left, +y) or -1 (right, -y).
        centre_y: the vehicle's centre line [m] (``CellModel.centre_y``): the overlap is measured from the struck
            side's outer edge ``centre_y +- W/2``, not from ``y = 0``.

    Returns:
        ``[B, n]`` fraction in [0, 1] of each cell's y-extent inside the barrier band.
    """
    sgn = side.to(lo_y.dtype)[:, None]
    edge = barrier_edge(centre_y, width, overlap.to(lo_y.dtype)[:, None], sgn)  # [B, 1]: inner barrier edge
    # Mirror the right-side case onto the left: band is y' >= sgn * edge with y' = sgn * y.
    a = torch.minimum(sgn * lo_y[None, :], sgn * hi_y[None, :])
    b = torch.maximum(sgn * lo_y[None, :], sgn * hi_y[None, :])
    extent = (b - a).clamp_min(1e-12)
    covered = (b - torch.maximum(a, sgn * edge)).clamp(min=0.0)
    # Snap round-off slivers: cells never straddle the section planes, so a micrometre is "on the plane".
    covered = torch.where(covered < _PLANE_TOL, torch.zeros_like(covered), covered)
    covered = torch.where(extent - covered < _PLANE_TOL, extent, covered)
    frac = (covered / extent).clamp(max=1.0)
    full = (overlap >= 1.0)[:, None]
    return torch.where(full, torch.ones_like(frac), frac)


def barrier_mask(cells: CellModel, scenario: CrashScenario) -> np.ndarray:
    """Fraction of each cell's front area covered by the scenario's barrier.

    Args:
        cells: the cell model (uses ``lo``, ``hi``, ``front_area``, ``vehicle_width``, ``centre_y``).
        scenario: the load case.

    Returns:
        ``[n_cells]`` float in [0, 1]; zero for cells with no front area, null and rigid cells.

    Raises:
        ModelError: ``scenario`` is no :class:`CrashScenario`.
        ConfigError: a scenario value of the wrong type or out of range (one made in Python), naming the key.
    """
    if not isinstance(scenario, CrashScenario):
        raise _not_a_scenario(scenario, "scenario")
    scenario = checked(scenario)
    frac = barrier_fraction(
        torch.as_tensor(cells.lo[:, 1], dtype=torch.float64),
        torch.as_tensor(cells.hi[:, 1], dtype=torch.float64),
        float(cells.vehicle_width),
        torch.tensor([scenario.overlap], dtype=torch.float64),
        torch.tensor([scenario.side_sign], dtype=torch.float64),
        centre_y=cells.centre_y,
    )[0].numpy()
    exposed = (cells.front_area > 0) & ~cells.is_null & ~cells.is_rigid
    return np.where(exposed, frac, 0.0)
