"""Crash pulses: the signal type, integration, resampling and time-zero alignment.

Sign and unit convention (one for all of marlcrash):

- Inside, a pulse is SI: time [s], acceleration [m/s^2], velocity [m/s].
- *Velocity is the vehicle's forward speed* and acceleration its time
  derivative. A vehicle running into a barrier slows down, so a frontal crash
  pulse is **negative** and the velocity change over the crash is negative.
  This is the SAE J211 / ISO 6487 vehicle frame (x forward), so test data in
  that frame is read with ``sign=+1`` (the default); data recorded with
  deceleration positive is read with ``sign=-1``.
- The cell model's x axis points rearward (DESIGN 1.3), so a surrogate's
  x-acceleration ``a_x`` of a sensor maps to a pulse as ``acc = -a_x``
  (:func:`from_rearward_x`).

The processing chain for a reference (DESIGN 1.4, 1.5) is: CFC-filter at the
recording rate -> find time zero -> resample to the surrogate's 2 kHz output
grid -> integrate to velocity (:func:`prepare_velocity`).

Time zero (a documented choice): the first instant at which the magnitude of
the acceleration of any channel reaches ``threshold_g`` (default 0.5 g),
linearly interpolated between samples, found in two steps
(:func:`filtered_from_time_zero`): the CFC-filtered record's crossing, which
noise cannot trigger, then the crossing from there on of the record at CFC 1000
(unfiltered below 4.2 kHz). The CFC 60 filter is zero-phase (non-causal): its
output rises before the raw signal does, by 5-13 ms for a sharp onset, so its
own crossing only starts the search.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from marlcrash.errors import PulseError
from marlcrash.pulse.cfc import (
    CFC_CLASSES,
    DEFAULT_PAD_TIME,
    DESIGN_FACTOR,
    cfc_filter,
    cfc_filter_torch,
    check_cfc,
    f_h,
)
from marlcrash.units import G0

SURROGATE_RATE_HZ = 2000.0
"""Output rate of the surrogate's sensors (DESIGN 1.4): one step is 0.5 ms."""
DEFAULT_THRESHOLD_G = 0.5
"""Acceleration magnitude [g] whose first crossing defines time zero."""
MIN_SAMPLES = 8
"""Fewest samples a pulse may have."""
UNIFORM_RTOL = 1e-3
"""Largest relative deviation of a time step from the mean step for a 'uniform' record."""
PRE_IMPACT_TIME = 2.0 * DEFAULT_PAD_TIME
"""Constant-velocity (zero-acceleration) lead-in [s] put before a record for filtering, simulated
(:func:`compared_velocity`) or measured (:func:`filtered_from_time_zero`): twice the CFC filter's end padding
(20 ms), longer than the CFC 60 filter's impulse response (about 10 ms)."""
DEFAULT_COMPARE_MARGIN = 0.01
"""[s] How much longer than the compared window a candidate is simulated when its reference is a measured record
that goes on past the window (:func:`compared_window`, ``ReferenceConfig.compare_margin``)."""


@dataclass(frozen=True)
class Pulse:
    """Acceleration histories of one crash, in marlcrash's convention (module docstring).

    Attributes:
        time: ``[T]`` strictly increasing sample times [s].
        acc: ``[K, T]`` accelerations [m/s^2] of ``K`` channels (sensors), forward positive.
        channels: ``K`` channel names.
        source: the file the pulse came from ('' if built in memory).
        cfc: the CFC class already applied, ``None`` for unfiltered data.
    """

    time: np.ndarray
    acc: np.ndarray
    channels: tuple[str, ...]
    source: str = ""
    cfc: int | None = None

    def __post_init__(self):
        where = f"{self.source}: " if self.source else ""
        time = np.asarray(self.time, dtype=np.float64)
        acc = np.asarray(self.acc, dtype=np.float64)
        if acc.ndim == 1:
            acc = acc[None, :]
        if time.ndim != 1 or acc.ndim != 2 or acc.shape[1] != time.shape[0]:
            raise PulseError(f"{where}expected time [T] and acc [K, T], got shapes {time.shape} and {acc.shape}")
        if time.shape[0] < MIN_SAMPLES:
            raise PulseError(f"{where}expected at least {MIN_SAMPLES} samples, got {time.shape[0]}")
        if not (np.all(np.isfinite(time)) and np.all(np.isfinite(acc))):
            raise PulseError(f"{where}time and acceleration must be finite; found NaN or inf")
        steps = np.diff(time)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise PulseError(
                f"{where}time must strictly increase; sample {i + 1} has t={float(time[i + 1])!r} "
                f"after t={float(time[i])!r}"
            )
        channels = tuple(str(c) for c in self.channels)
        if len(channels) != acc.shape[0]:
            raise PulseError(f"{where}expected {acc.shape[0]} channel names, got {len(channels)}")
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "acc", acc)
        object.__setattr__(self, "channels", channels)

    @property
    def n_samples(self) -> int:
        """Number of samples ``T``."""
        return int(self.time.shape[0])

    @property
    def n_channels(self) -> int:
        """Number of channels ``K``."""
        return int(self.acc.shape[0])

    @property
    def dt(self) -> float:
        """Mean sampling interval [s]."""
        return float((self.time[-1] - self.time[0]) / (self.n_samples - 1))

    @property
    def sample_rate_hz(self) -> float:
        """Mean sampling rate [Hz]."""
        return 1.0 / self.dt

    @property
    def is_uniform(self) -> bool:
        """Whether every time step is within :data:`UNIFORM_RTOL` of the mean step."""
        return bool(np.max(np.abs(np.diff(self.time) - self.dt)) <= UNIFORM_RTOL * self.dt)

    def select(self, channels: str | int | Sequence[str | int]) -> Pulse:
        """The pulse restricted to some channels, by name or index (order kept as given)."""
        items = [channels] if isinstance(channels, str | int) else list(channels)
        idx = []
        for c in items:
            if isinstance(c, str):
                if c not in self.channels:
                    raise PulseError(f"channel {c!r} not found; the pulse has {list(self.channels)}")
                idx.append(self.channels.index(c))
            else:
                if not -self.n_channels <= c < self.n_channels:
                    raise PulseError(f"channel index {c} out of range for {self.n_channels} channels")
                idx.append(c % self.n_channels)
        return replace(self, acc=self.acc[idx], channels=tuple(self.channels[i] for i in idx))

    def velocity(self, v0: float = 0.0) -> np.ndarray:
        """``[K, T]`` forward velocity [m/s]: ``v0`` plus the trapezoid integral of ``acc``."""
        return integrate(self.time, self.acc, v0=v0)


def from_rearward_x(acc_x: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    """Convert an acceleration along the cell model's rearward x axis to marlcrash's pulse sign."""
    return -acc_x


def integrate(time: np.ndarray, acc: np.ndarray, v0: float | np.ndarray = 0.0) -> np.ndarray:
    """Cumulative trapezoid integral along the last axis.

    Args:
        time: ``[T]`` sample times [s].
        acc: ``[..., T]`` accelerations [m/s^2].
        v0: velocity at ``time[0]`` [m/s], scalar or ``[...]``.

    Returns:
        ``[..., T]`` velocity [m/s].
    """
    acc = np.asarray(acc, dtype=np.float64)
    h = np.diff(np.asarray(time, dtype=np.float64))
    inc = 0.5 * (acc[..., 1:] + acc[..., :-1]) * h
    out = np.concatenate([np.zeros((*acc.shape[:-1], 1)), np.cumsum(inc, axis=-1)], axis=-1)
    return out + np.asarray(v0, dtype=np.float64)[..., None]


def integrate_torch(acc: torch.Tensor, dt: float, v0: float | torch.Tensor = 0.0) -> torch.Tensor:
    """Batched cumulative trapezoid integral of ``[..., T]`` uniformly sampled accelerations.

    Args:
        acc: ``[..., T]`` accelerations [m/s^2] (e.g. ``[B, n_sensors, T]``).
        dt: sampling interval [s].
        v0: initial velocity [m/s], scalar or ``[...]``.

    Returns:
        ``[..., T]`` velocity [m/s], ``v[..., 0] == v0``; differentiable.
    """
    inc = 0.5 * (acc[..., 1:] + acc[..., :-1]) * dt
    zero = torch.zeros_like(acc[..., :1])
    v0 = torch.as_tensor(v0, dtype=acc.dtype, device=acc.device)
    return torch.cat([zero, torch.cumsum(inc, dim=-1)], dim=-1) + v0.unsqueeze(-1)


def compared_velocity(
    velocity: torch.Tensor, dt: float, cfc: int | None = 60, pre_time: float = PRE_IMPACT_TIME
) -> torch.Tensor:
    """The signal calibration compares (DESIGN 1.5): the integral of the CFC-filtered acceleration.

    The acceleration is the central-difference derivative of the sampled velocity (the mean
    deceleration around each sample, what an anti-aliased accelerometer records), filtered
    with the phase-less CFC filter and integrated. Batched and differentiable.

    A simulated record starts at the first contact, often with the largest acceleration of the whole
    pulse at its first samples (a bumper cell stops within 1-2 ms). Filtered as it is, the filter's end
    handling (an odd reflection about that first value) turns part of this step into a spurious
    constant velocity offset: up to 1.1 m/s on the default car's up-front sensors, which alone made
    0.1 m of their area. So the record is first extended back by ``pre_time`` at its initial velocity,
    zero acceleration, which is what the vehicle did before the contact and what a test record's
    pre-trigger samples hold; it is filtered and integrated from there, and the samples from t = 0 on
    are returned. The zero-phase filter spreads the first deceleration a few milliseconds both ways,
    so the returned velocity at t = 0 is already slightly below the initial velocity, as in a
    filtered test record.

    Args:
        velocity: ``[..., T]`` velocities [m/s] on a uniform grid from the first contact (e.g.
            ``SimResult.velocity``).
        dt: sampling interval [s].
        cfc: channel frequency class; ``None`` returns ``velocity`` unchanged.
        pre_time: constant-velocity lead-in [s] (:data:`PRE_IMPACT_TIME`; 0 filters the record as it is).

    Returns:
        ``[..., T]`` velocity [m/s].
    """
    if cfc is None:
        return velocity
    if not (math.isfinite(pre_time) and pre_time >= 0):
        raise PulseError(f"pre_time must be a duration >= 0 s, got {pre_time!r}")
    n = round(pre_time / dt)
    acc = sampled_acceleration(velocity, dt)
    acc = torch.cat([acc.new_zeros((*acc.shape[:-1], n)), acc], dim=-1)
    return integrate_torch(cfc_filter_torch(acc, dt, cfc), dt, v0=velocity[..., 0])[..., n:]


def margin_samples(seconds: float, rate_hz: float) -> int:
    """Whole samples at ``rate_hz`` in a compare margin of ``seconds`` (:func:`compared_window`): the one rounding
    the reference loader and the calibration problem share."""
    return math.floor(float(seconds) * float(rate_hz) + 1e-6)


def compared_window(
    velocity: torch.Tensor, dt: float, cfc: int | None, n: int, margin: torch.Tensor | int = 0
) -> torch.Tensor:
    """:func:`compared_velocity` of a record simulated ``margin`` samples past a window of ``n``, cut to the window.

    A measured reference is filtered over its whole record, which goes on past the compared window, so its
    last samples in the window carry none of the filter's end handling. A candidate filtered only up to the
    window's end does (:data:`DEFAULT_COMPARE_MARGIN`); simulated ``margin`` samples longer, filtered, then cut,
    it is compared as the test is. Rows of a batch may have different margins (tests of different lengths).

    Args:
        velocity: ``[B, ..., T]`` velocities [m/s], ``T >= n + max(margin)``.
        dt: sampling interval [s].
        cfc: channel frequency class; ``None`` cuts the raw velocity.
        n: samples of the window.
        margin: samples past the window each row is filtered over: an int, or ``[B]`` integers.

    Returns:
        ``[B, ..., n]`` velocity [m/s].

    Raises:
        PulseError: a negative margin, ``[B]`` margins for a batch of another size, or ``velocity`` shorter
            than the window and a row's margin.
    """
    m = torch.as_tensor(margin, dtype=torch.int64)
    if m.numel() and int(m.min()) < 0:
        raise PulseError(f"margins are samples past the window, >= 0; got {m.tolist()}")
    if m.ndim > 1 or (m.ndim == 1 and (velocity.ndim < 2 or m.shape[0] != velocity.shape[0])):
        raise PulseError(f"expected an int or one margin per row of the {tuple(velocity.shape)} velocities, "
                         f"got margins of shape {tuple(m.shape)}")  # fmt: skip
    longest = n + (int(m.max()) if m.numel() else 0)
    if velocity.shape[-1] < longest:
        raise PulseError(f"a window of {n} samples and a margin of {longest - n} need {longest} samples, "
                         f"got {velocity.shape[-1]}")  # fmt: skip
    if m.ndim == 0:
        return compared_velocity(velocity[..., : n + int(m)], dt, cfc)[..., :n]
    out = velocity.new_empty((*velocity.shape[:-1], n))
    for k in torch.unique(m).tolist():  # one filter call per distinct margin (a few: one per test length)
        rows = m == k
        out[rows] = compared_velocity(velocity[rows][..., : n + k], dt, cfc)[..., :n]
    return out


def sampled_acceleration(velocity: torch.Tensor, dt: float) -> torch.Tensor:
    """The acceleration an anti-aliased accelerometer records at the samples of ``velocity``.

    The central difference ``(v[k + 1] - v[k - 1]) / 2 dt``: the mean acceleration over the two
    intervals around sample ``k``, with ``v[-1] = v[0]`` (constant speed before the first sample,
    the first contact) and the backward difference at the last sample. This is the acceleration
    :func:`compared_velocity` filters and integrates, so a record written with it (``marlcrash
    simulate --csv``) and read back (``marlcrash pulse``) gives the velocity change of the simulation.
    The simulator's instantaneous acceleration at the output instants is not a usable sample: the
    light front cells ring far above the 1 kHz Nyquist frequency of a 2 kHz record, and on the
    default car at 40 km/h those point values integrate to 8.9 of an up-front sensor's 12.0 m/s.

    Args:
        velocity: ``[..., T]`` velocities [m/s] on a uniform grid from the first contact, ``T >= 2``.
        dt: sampling interval [s].

    Returns:
        ``[..., T]`` acceleration [m/s^2] (differentiable).
    """
    if velocity.shape[-1] < 2:
        raise PulseError(f"need at least 2 velocity samples for an acceleration, got {velocity.shape[-1]}")
    v = torch.cat([velocity[..., :1], velocity], dim=-1)
    return torch.gradient(v, spacing=dt, dim=-1)[0][..., 1:]


def filter_pulse(pulse: Pulse, cfc: int = 60, pad_time: float = DEFAULT_PAD_TIME) -> Pulse:
    """CFC-filter every channel of a uniformly sampled pulse (see :mod:`marlcrash.pulse.cfc`).

    Raises:
        PulseError: the pulse is not uniformly sampled (resample it first), already filtered
            with a lower (stricter) class, or shorter than one period of the -3 dB frequency (10 ms at
            CFC 60): the end reflections then dominate, and a 5 ms, 20 g half-sine came out at 14 g,
            a 2 ms one with its integral's sign reversed.
    """
    cfc = check_cfc(cfc)
    span = pulse.n_samples * pulse.dt
    if span < 1.0 / f_h(cfc):
        raise PulseError(
            f"{pulse.source or 'pulse'}: a record of {span * 1e3:.3g} ms is too short for CFC {cfc}; expected at "
            f"least {1e3 / f_h(cfc):.3g} ms (one period of its {f_h(cfc):.0f} Hz -3 dB frequency)"
        )
    if not pulse.is_uniform:
        raise PulseError(
            f"{pulse.source or 'pulse'}: CFC filtering needs uniform sampling; resample first "
            f"(marlcrash.pulse.resample)"
        )
    if pulse.cfc is not None and pulse.cfc < cfc:
        raise PulseError(f"{pulse.source or 'pulse'}: already filtered with CFC {pulse.cfc}, cannot apply CFC {cfc}")
    acc = cfc_filter(pulse.acc, pulse.dt, cfc, axis=-1, pad_time=pad_time)
    return replace(pulse, acc=acc, cfc=cfc)


def resample(
    pulse: Pulse, rate_hz: float = SURROGATE_RATE_HZ, t_start: float | None = None, t_end: float | None = None
) -> Pulse:
    """Linearly interpolate a pulse onto the uniform grid ``t_start + i / rate_hz``.

    Filter before downsampling: linear interpolation does not remove content above
    the new Nyquist frequency (CFC 60 leaves nothing above ~300 Hz, far below 1 kHz).

    Args:
        pulse: the pulse.
        rate_hz: new sampling rate [Hz].
        t_start: first sample time [s] (default: the pulse's first time).
        t_end: last time [s] to cover, inclusive within 1e-9 s (default: the pulse's last time).

    Raises:
        PulseError: a bad rate or a window outside the record.
    """
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise PulseError(f"resampling rate must be a positive number of Hz, got {rate_hz!r}")
    t0 = pulse.time[0] if t_start is None else float(t_start)
    t1 = pulse.time[-1] if t_end is None else float(t_end)
    eps = 1e-9
    if t0 < pulse.time[0] - eps or t1 > pulse.time[-1] + eps or t1 <= t0:
        raise PulseError(
            f"{pulse.source or 'pulse'}: resampling window [{t0:.6g}, {t1:.6g}] s must lie inside the record "
            f"[{pulse.time[0]:.6g}, {pulse.time[-1]:.6g}] s"
        )
    n = int(np.floor((t1 - t0) * rate_hz + 1e-6)) + 1
    grid = t0 + np.arange(n) / rate_hz
    acc = np.stack([np.interp(grid, pulse.time, a) for a in pulse.acc])
    return replace(pulse, time=grid, acc=acc)


def find_time_zero(pulse: Pulse, threshold_g: float = DEFAULT_THRESHOLD_G) -> float:
    """Time zero [s]: first crossing of ``|acc| = threshold_g`` by any channel (interpolated).

    Pass a filtered pulse (:func:`filter_pulse`); noise on raw data would trigger early.

    Raises:
        PulseError: no channel reaches the threshold, or it is already exceeded at the first sample.
    """
    if not threshold_g > 0:
        raise PulseError(f"time-zero threshold must be > 0 g, got {threshold_g!r}")
    level = threshold_g * G0
    mag = np.abs(pulse.acc)
    above = mag >= level
    if not above.any():
        raise PulseError(
            f"{pulse.source or 'pulse'}: no channel reaches the time-zero threshold {threshold_g} g "
            f"(peak {mag.max() / G0:.3g} g)"
        )
    first = np.where(above.any(axis=1), above.argmax(axis=1), pulse.n_samples)
    k = int(first.argmin())
    i = int(first[k])
    if i == 0:
        raise PulseError(
            f"{pulse.source or 'pulse'}: channel {pulse.channels[k]!r} already exceeds {threshold_g} g at the first "
            f"sample; the record needs pre-impact data to find time zero"
        )
    m0, m1 = mag[k, i - 1], mag[k, i]
    return float(pulse.time[i - 1] + (level - m0) / (m1 - m0) * (pulse.time[i] - pulse.time[i - 1]))


NOISE_LEVELS = 5.0
"""Onset level as a multiple of a channel's noise (rms of its samples before the filtered crossing) where that is
above the threshold: :func:`onset_after`."""
NOISE_WINDOW = (0.005, 0.002)
"""[s] Least record length, and gap before the filtered crossing, of the samples that measure a channel's noise."""


def onset_after(
    raw: Pulse, t_from: float, threshold_g: float = DEFAULT_THRESHOLD_G, t_first: float | None = None
) -> float:
    """The first crossing of ``|acc| = threshold_g`` by any channel of ``raw`` at or after ``t_from`` [s]
    (interpolated).

    ``t_from`` is the filtered record's crossing (:func:`find_time_zero`), which a zero-phase filter moves ahead of
    the pulse; the unfiltered record's own crossing after it is the onset. A channel already above the threshold at
    ``t_from`` (noise, or a pulse the filter did not move) gives ``t_from``; no crossing after it gives ``t_from`` too.

    A noisy channel crosses the threshold on noise right after ``t_from``, which put time zero 5 ms early on a
    2 ms, 30 g onset with 1 g rms of noise. Where a channel has at least ``NOISE_WINDOW[0]`` of samples from
    ``t_first`` (the record's first sample; its lead-in is noise-free) to ``NOISE_WINDOW[1]`` before ``t_from``,
    its level is ``NOISE_LEVELS`` times their rms deviation, if that is above the threshold.
    """
    mag = np.abs(raw.acc)
    levels = np.full(mag.shape[0], threshold_g * G0)
    if t_first is not None:
        quiet = (raw.time >= t_first) & (raw.time < t_from - NOISE_WINDOW[1])
        if quiet.any() and float(raw.time[quiet][-1] - raw.time[quiet][0]) >= NOISE_WINDOW[0]:
            levels = np.maximum(levels, NOISE_LEVELS * raw.acc[:, quiet].std(axis=1))
    i0 = int(np.searchsorted(raw.time, t_from))
    best = math.inf
    for k in range(mag.shape[0]):
        level = levels[k]
        above = np.nonzero(mag[k, i0:] >= level)[0]
        if above.size == 0:
            continue
        i = i0 + int(above[0])
        if i == 0 or mag[k, i - 1] >= level:
            t = t_from if i == i0 else float(raw.time[i])
        else:
            m0, m1 = mag[k, i - 1], mag[k, i]
            t = float(raw.time[i - 1] + (level - m0) / (m1 - m0) * (raw.time[i] - raw.time[i - 1]))
        best = min(best, max(t, t_from))
    return t_from if math.isinf(best) else best


ZERO_LEVEL_MARGIN = 0.001
"""[s] The zero level of a record is the mean of its samples up to this long before its t = 0 (pre-trigger data)."""
MAX_ZERO_OFFSET_G = 2.0
"""[g] A pre-trigger mean above this is not a transducer offset (the record's clock puts part of the crash, or a
fault, before t = 0): :func:`remove_zero_offset` then leaves the channel as it is and warns."""


def remove_zero_offset(
    pulse: Pulse, before: float = -ZERO_LEVEL_MARGIN, min_time: float = 0.005, max_offset_g: float = MAX_ZERO_OFFSET_G
) -> Pulse:
    """Subtract each channel's zero level: the mean of its raw samples before ``before`` [s] (ISO 6487 / SAE J211
    practice: the pre-trigger samples of a test are at rest, so their mean is the transducer's offset).

    A DC offset integrates into a velocity drift: 0.3 g over 150 ms is 0.44 m/s, and an offset above the 0.5 g
    time-zero threshold sets time zero at the record's first sample. Records with less than ``min_time`` of
    samples before ``before`` (a record that starts at the impact) are returned unchanged (the same object), and so
    is a channel whose pre-trigger mean exceeds ``max_offset_g`` (with a warning): those samples are not at rest.
    """
    pre = pulse.time < before
    if not pre.any() or float(pulse.time[pre][-1] - pulse.time[0]) < min_time:
        return pulse
    level = pulse.acc[:, pre].mean(axis=1, keepdims=True)
    big = np.abs(level[:, 0]) > max_offset_g * G0
    for k in np.flatnonzero(big).tolist():
        warnings.warn(
            f"{pulse.source or 'pulse'}: channel {pulse.channels[k]!r} averages {level[k, 0] / G0:.3g} g before "
            f"t = {before * 1e3:g} ms, more than a transducer offset ({max_offset_g:g} g): its zero level is left as "
            "recorded",
            UserWarning,
            stacklevel=2,
        )
    return replace(pulse, acc=pulse.acc - np.where(big[:, None], 0.0, level))


def without_zero_offset(
    pulse: Pulse, time_zero: str = "file", cfc: int | None = 60, threshold_g: float = DEFAULT_THRESHOLD_G
) -> Pulse:
    """``pulse`` less each channel's transducer offset, measured where the record is at rest.

    With ``time_zero="file"`` (the file's t = 0 is the contact) the pre-trigger samples are those at negative
    times (:func:`remove_zero_offset`). With ``"threshold"`` the file's clock is not trusted: the offset is the
    mean of the samples from the record's start to :data:`ZERO_LEVEL_MARGIN` before the onset found on the record
    less its negative-time offset (an offset above the 0.5 g threshold would otherwise set the onset at the first
    sample), where they span at least 5 ms; else the negative-time offset stands. Where that onset lies inside the
    negative times averaged (the file's clock puts the contact before -1 ms), the mean held part of the pulse: the
    onset is found on the record as read instead. So an offset below the threshold gives the same result whatever
    the record's clock; one above it is recognised only where the contact is at the file's t = 0.
    """
    first = remove_zero_offset(pulse)
    if time_zero != "threshold":
        return first
    _, t0 = filtered_from_time_zero(first, cfc, "threshold", threshold_g)
    if first is not pulse and t0 < -ZERO_LEVEL_MARGIN:  # the negative-time mean held the onset: part of the crash
        first = pulse
        _, t0 = filtered_from_time_zero(pulse, cfc, "threshold", threshold_g)
    second = remove_zero_offset(pulse, before=t0 - ZERO_LEVEL_MARGIN)
    return first if second is pulse else second  # too few samples before the onset: the negative-time offset


def shift_time(pulse: Pulse, t0: float) -> Pulse:
    """The pulse with its clock shifted so that ``t0`` becomes time 0."""
    return replace(pulse, time=pulse.time - float(t0))


def lead_in(pulse: Pulse, pre_time: float) -> Pulse:
    """A uniform pulse with ``pre_time`` [s] of zero acceleration put before its first sample (same rate)."""
    dt = float(pulse.time[1] - pulse.time[0])
    n = round(pre_time / dt)
    if n <= 0:
        return pulse
    time = np.concatenate([pulse.time[0] - dt * np.arange(n, 0, -1), pulse.time])
    acc = np.concatenate([np.zeros((pulse.acc.shape[0], n)), pulse.acc], axis=1)
    return replace(pulse, time=time, acc=acc)


def filtered_acceleration(acc: np.ndarray, dt: float, cfc: int = 60, pre_time: float = PRE_IMPACT_TIME) -> np.ndarray:
    """CFC-filter accelerations ``[..., T]`` that start at the first contact, led in by ``pre_time`` of zero.

    As in :func:`compared_velocity`: a simulated record begins with its hardest deceleration, and
    filtered as it is, the filter's end handling (an odd reflection about the first value) holds that
    value at the start; an up-front sensor of the default car at 40 km/h then peaked at 485 g instead
    of its 315 g. The lead-in (the vehicle at constant speed before the contact) is dropped again.
    """
    n = round(pre_time / dt)
    a = np.asarray(acc, dtype=np.float64)
    led = np.concatenate([np.zeros((*a.shape[:-1], n)), a], axis=-1)
    return cfc_filter(led, dt, cfc, axis=-1)[..., n:]


def filtered_from_time_zero(
    pulse: Pulse, cfc: int | None = 60, time_zero: str = "threshold", threshold_g: float = DEFAULT_THRESHOLD_G
) -> tuple[Pulse, float]:
    """A record made uniform (resampled at its mean rate if needed), CFC-filtered at that rate, and its time zero.

    Args:
        pulse: the raw (or already filtered) pulse.
        cfc: CFC class, or ``None`` to skip filtering.
        time_zero: ``"threshold"`` (:func:`find_time_zero` on the filtered record) or ``"file"`` (the file's t = 0).
        threshold_g: time-zero threshold [g].

    Time zero is searched in two steps: the first crossing of the threshold by the filtered record (noise on
    the raw record cannot trigger it), then the first crossing from there on by the record filtered at CFC 1000
    where its rate allows (above 4.2 kHz, as test records are sampled), or unfiltered (a slower record, e.g. a
    simulated one at 2 kHz; :func:`onset_after`). The zero-phase filter spreads a pulse backwards
    in time: a sharp onset (a bumper-region sensor stopping within 1-2 ms, a 3 ms half-sine) crosses 0.5 g
    after CFC 60 filtering 5-13 ms before it starts, which would shift every time of the record and its
    velocity change at 150 ms.

    Before filtering, the record is led in by :data:`PRE_IMPACT_TIME` of zero acceleration (the vehicle at
    constant speed before the record began), and the filtered lead-in is kept (its times precede the
    file's first sample): the zero-phase filter spreads the first milliseconds of the pulse backwards, and
    a record that starts at the impact (no pre-trigger samples, e.g. a ``marlcrash simulate --csv`` record)
    would otherwise lose that part to the filter's end reflection. A 3 ms, 20 g half-sine starting at the
    first sample lost 35 % of its CFC 60 velocity change that way. For records with quiet pre-trigger data
    the lead-in changes nothing material. Unfiltered (``cfc=None``) the record is led in the same way, so its
    integral starts from the constant speed before the first sample as the filtered one does (from the first
    sample itself, a record starting at the impact lost half of that sample's interval: the simulated
    up-front velocity change came out 10 % short).

    Returns:
        ``(uniform filtered pulse on the file's clock, time zero [s] on that clock)``.
    """
    u = pulse if pulse.is_uniform else resample(pulse, pulse.sample_rate_hz)
    led = lead_in(u, PRE_IMPACT_TIME)
    p = led if cfc is None else filter_pulse(led, cfc)
    if time_zero == "threshold":
        t_filtered = find_time_zero(p, threshold_g)
        if cfc is None:  # the record's own crossing, not before its first sample (one that starts above the level)
            return p, max(t_filtered, float(u.time[0]))
        # the onset on CFC 1000 where the rate can filter it (design frequency below Nyquist), else unfiltered:
        # a narrower band spreads a sharp onset by milliseconds again (CFC 180 at 2 kHz: 1.5-4.5 ms)
        rate = 1.0 / float(u.time[1] - u.time[0])
        widest = max(CFC_CLASSES)
        sharp = lead_in(u, PRE_IMPACT_TIME)
        if widest > cfc and 2.0 * DESIGN_FACTOR * widest < rate:
            with warnings.catch_warnings():  # J211's 10 F_H margin concerns the corridor, not finding an onset
                warnings.simplefilter("ignore")
                sharp = filter_pulse(sharp, widest)
        # not before the file's first sample: a record that starts above the threshold (no pre-trigger data, e.g.
        # a simulation's) would otherwise cross it inside the assumed lead-in, up to one sample early
        return p, max(onset_after(sharp, t_filtered, threshold_g, float(u.time[0])), float(u.time[0]))
    if time_zero == "file":
        return p, 0.0
    raise PulseError(f"time_zero must be 'threshold' or 'file', got {time_zero!r}")


def prepare_velocity(
    pulse: Pulse,
    *,
    cfc: int | None = 60,
    rate_hz: float = SURROGATE_RATE_HZ,
    duration: float | None = None,
    time_zero: str = "threshold",
    threshold_g: float = DEFAULT_THRESHOLD_G,
    v0: float = 0.0,
    beyond: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Turn a raw reference pulse into the velocity signal the metrics compare (DESIGN 1.5).

    Args:
        pulse: the raw (or already filtered) pulse.
        cfc: CFC class to apply at the recording rate; ``None`` to skip (data already filtered).
        rate_hz: output rate [Hz] (the surrogate's 2 kHz by default).
        duration: length [s] of the window after time zero (default: to the end of the record).
        time_zero: ``"threshold"`` (see :func:`find_time_zero`) or ``"file"`` (the file's t = 0).
        threshold_g: time-zero threshold [g].
        v0: forward speed [m/s] before the impact (0 gives the velocity change).
        beyond: with a ``duration``, also return up to this long [s] past the window, as far as the record
            reaches (the filter ran over the whole record either way; :func:`compared_window`).

    The filtered record is integrated from :data:`PRE_IMPACT_TIME` before time zero (or its first sample, if
    later), where it is ``v0``, as :func:`compared_velocity` integrates a simulation from before its contact:
    the zero-phase filter spreads the onset's deceleration before time zero, so the returned velocity at time
    zero is slightly below ``v0`` (a sharp onset: a few tenths of a m/s), as a simulation's compared one is.

    Returns:
        ``time [T]`` from 0 at ``rate_hz`` and ``velocity [K, T]`` [m/s].
    """
    if not (math.isfinite(beyond) and beyond >= 0):
        raise PulseError(f"beyond must be a duration >= 0 s, got {beyond!r}")
    p, t0 = filtered_from_time_zero(pulse, cfc, time_zero, threshold_g)
    t_end = p.time[-1] if duration is None else t0 + float(duration)
    if t_end > p.time[-1] + 1e-9:
        raise PulseError(
            f"{pulse.source or 'pulse'}: the record ends {(p.time[-1] - t0) * 1e3:.4g} ms after time zero "
            f"(t = {t0 * 1e3:.4g} ms); expected at least {float(duration) * 1e3:.4g} ms"
        )
    if duration is not None and beyond > 0:  # whole samples past the window that the record holds
        t_end += min(beyond, margin_samples(p.time[-1] - t_end, rate_hz) / rate_hz)
    # integrated from PRE_IMPACT_TIME before time zero, as compared_velocity integrates a simulation: the zero-phase
    # filter spreads the onset's deceleration before time zero, and integrating from time zero lost it (an up-front
    # sensor's velocity change came out 4.6 m/s short of the simulation's the file was written from)
    n_pre = int(np.floor((t0 - max(float(p.time[0]), t0 - PRE_IMPACT_TIME)) * rate_hz + 1e-9))
    q = resample(p, rate_hz, t0 - n_pre / rate_hz, t_end)
    v = q.velocity(v0)[:, n_pre:]
    return np.arange(v.shape[1]) / rate_hz, v
