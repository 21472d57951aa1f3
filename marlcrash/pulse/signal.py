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

Time zero of a record whose clock is not aligned to the contact (``time_zero:
threshold``; a documented choice, :func:`find_onset`): where the pulse of the
earliest channel starts. Each channel's zero level and noise are measured on its
samples before that time zero (its pre-trigger data, whatever the clock; after the
contact no channel is at rest, also one whose own pulse starts later); the pulse
is detected on the CFC-filtered channel where it leaves ``threshold_g`` (0.5 g)
or 5x its pre-trigger noise after that filter, where higher; and the onset is
the start of a straight line fitted with the zero level to the record's samples
up to where the pulse reaches 40 % of its peak. A level crossing is no time
zero: the zero-phase CFC 60 filter spreads a sharp onset backwards (its output
crosses 0.5 g 5-13 ms before the pulse starts), and a slow onset reaches a
level above the noise milliseconds after it starts. A channel with too little
pre-trigger data for its zero level is named in a warning.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from marlcrash.errors import PulseError
from marlcrash.metrics import check_step
from marlcrash.pulse.cfc import (
    CFC_CLASSES,
    DEFAULT_PAD_TIME,
    cfc_filter,
    cfc_filter_torch,
    check_cfc,
    f_n,
    min_rate_hz,
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
        drawn: a table of breakpoints sampled (``read_csv(breakpoints=True)``, a pulse drawn by its corners): it has
            neither noise nor offset, so its zero level is 0 exactly; :func:`find_onset` and the offset removal
            (:func:`without_zero_offset`, :func:`remove_zero_offset`) measure none.
    """

    time: np.ndarray
    acc: np.ndarray
    channels: tuple[str, ...]
    source: str = ""
    cfc: int | None = None
    drawn: bool = False

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
        if not np.all(np.isfinite(time)):
            i = int(np.argmin(np.isfinite(time)))
            raise PulseError(f"{where}non-finite sample time ({time[i]}) at sample {i}; expected finite times [s]")
        if not np.all(np.isfinite(acc)):
            k, i = (int(v) for v in np.argwhere(~np.isfinite(acc))[0])
            name = repr(str(self.channels[k])) if len(self.channels) == acc.shape[0] else str(k)
            raise PulseError(f"{where}channel {name} has a non-finite acceleration ({acc[k, i]}) at sample {i} "
                             f"(t = {float(time[i]):.6g} s); expected finite numbers")  # fmt: skip
        steps = np.diff(time)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise PulseError(
                f"{where}time must strictly increase; sample {i + 1} has t={float(time[i + 1])!r} "
                f"after t={float(time[i])!r}"
            )
        if isinstance(self.channels, str):  # 'xy' was two channels 'x' and 'y'
            raise PulseError(f"{where}channels: expected a sequence of channel names, got the text {self.channels!r}")
        channels = tuple(str(c) for c in self.channels)
        if acc.shape[0] == 0:
            raise PulseError(f"{where}expected at least one channel, got acc of shape {acc.shape}")
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
        items = [channels] if isinstance(channels, str | int | np.integer) else list(channels)
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

    def velocity(self, v0: float | np.ndarray = 0.0) -> np.ndarray:
        """``[K, T]`` forward velocity [m/s]: ``v0`` (or ``[K]``, one per channel) plus the trapezoid integral of
        ``acc``."""
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

    Raises:
        PulseError: ``time`` not of the length of ``acc``'s last axis, or a ``v0`` of another shape than ``[...]``
            that does not broadcast to it without growing it (3 speeds for 1 channel gave 3 velocities).
    """
    acc = np.asarray(acc, dtype=np.float64)
    time = np.asarray(time, dtype=np.float64)
    speed = np.asarray(v0, dtype=np.float64)
    if time.ndim != 1 or acc.ndim < 1 or time.shape[0] != acc.shape[-1]:
        raise PulseError(f"time: expected [T] sample times for accelerations of shape {list(acc.shape)}, got shape "
                         f"{list(time.shape)}")  # fmt: skip
    try:
        grows = np.broadcast_shapes(speed.shape, acc.shape[:-1]) != acc.shape[:-1]
    except ValueError:
        grows = True
    if grows:
        raise PulseError(f"v0: expected one speed or one per trace (shape {list(acc.shape[:-1])}), got shape "
                         f"{list(speed.shape)}")  # fmt: skip
    h = np.diff(time)
    inc = 0.5 * (acc[..., 1:] + acc[..., :-1]) * h
    out = np.concatenate([np.zeros((*acc.shape[:-1], 1)), np.cumsum(inc, axis=-1)], axis=-1)
    return out + speed[..., None]


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


def _check_velocity(velocity: object) -> torch.Tensor:
    """``velocity`` as it may be differentiated: a real tensor with a time axis ``[..., T]``."""
    if not isinstance(velocity, torch.Tensor):
        raise PulseError(
            f"expected velocity as a [..., T] tensor [m/s] (e.g. SimResult.velocity), got {type(velocity).__name__}; "
            "convert it with torch.as_tensor"
        )
    if velocity.dim() == 0:
        raise PulseError("expected velocity as a [..., T] tensor [m/s] (e.g. SimResult.velocity), got a scalar")
    if velocity.is_complex():
        raise PulseError(f"expected real velocity samples [m/s], got {velocity.dtype}")
    return velocity


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
        cfc: channel frequency class; ``None`` integrates the sampled acceleration unfiltered (the velocity
            averaged ``[1, 2, 1] / 4`` over neighbouring samples, the lead-in's sample before the first taken at the
            initial velocity): what a record of that acceleration (``marlcrash simulate --csv``) read with
            ``cfc: null`` integrates to. The raw velocity itself is not what a file can give back: compared with
            the file, it missed the model's own simulation by a DFD of 2.4 m/s on an up-front sensor.
        pre_time: constant-velocity lead-in [s] (:data:`PRE_IMPACT_TIME`; 0 filters the record as it is).

    Returns:
        ``[..., T]`` velocity [m/s].

    Raises:
        PulseError: ``velocity`` is not a real ``[..., T]`` tensor, ``dt`` is not a finite step > 0 s, or
            ``pre_time`` is not a duration >= 0 s.
    """
    velocity = _check_velocity(velocity)
    dt = check_step(dt)
    if not (_is_real(pre_time) and math.isfinite(pre_time) and pre_time >= 0):  # text was math's TypeError
        raise PulseError(f"pre_time must be a duration >= 0 s, got {pre_time!r}")
    n = round(pre_time / dt)
    acc = sampled_acceleration(velocity, dt)
    acc = torch.cat([acc.new_zeros((*acc.shape[:-1], n)), acc], dim=-1)
    if cfc is not None:
        acc = cfc_filter_torch(acc, dt, cfc)
    return integrate_torch(acc, dt, v0=velocity[..., 0])[..., n:]


def margin_samples(seconds: float, rate_hz: float, cfc: int | None = 60) -> int:
    """Whole samples at ``rate_hz`` in a compare margin of ``seconds`` (:func:`compared_window`): the one rounding
    the reference loader and the calibration problem share.

    Compared unfiltered (``cfc=None``) at most one sample counts: nothing is filtered, and only the central
    difference of the acceleration at the window's last sample reaches past it (a backward difference there missed
    the model's own 30 ms record by a DFD of 0.62 m/s).
    """
    most = math.floor(float(seconds) * float(rate_hz) + 1e-6)
    return most if cfc is not None else min(most, 1)


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
        cfc: channel frequency class; ``None``: the unfiltered integral (:func:`compared_velocity`).
        n: samples of the window.
        margin: samples past the window each row is filtered over: an int, or ``[B]`` integers.

    Returns:
        ``[B, ..., n]`` velocity [m/s].

    Raises:
        PulseError: a window ``n`` or margins that are not whole numbers of samples, a negative margin, ``[B]``
            margins for a batch of another size, or ``velocity`` shorter than the window and a row's margin.
    """
    velocity = _check_velocity(velocity)
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise PulseError(f"expected the window n as a whole number of samples >= 1, got {n!r}")
    n = int(n)
    try:
        m = torch.as_tensor(margin)
    except (TypeError, ValueError, RuntimeError):
        m = torch.tensor(math.nan)
    if m.numel() == 0:  # no rows: an empty list reads as floats
        m = m.to(torch.int64)
    if m.dtype == torch.bool or m.is_floating_point() or m.is_complex():  # 2.5 was cut to 2, True taken as 1
        raise PulseError(f"expected margins as whole numbers of samples (an int or [B] integers), got {margin!r}")
    m = m.to(torch.int64)
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
    simulate --csv``) and read back (``marlcrash pulse``) gives the velocity change of the simulation
    (the trapezoid rule gives it with the zero acceleration before the contact as a sample at ``-dt``,
    as the lead-in of :func:`compared_velocity` has; from the first sample on, its half weight falls short
    by ``a[0] dt / 2``).
    The simulator's instantaneous acceleration at the output instants is not a usable sample: the
    light front cells ring far above the 1 kHz Nyquist frequency of a 2 kHz record, and on the
    default car at 40 km/h those point values integrate to 8.9 of an up-front sensor's 12.0 m/s.

    Args:
        velocity: ``[..., T]`` velocities [m/s] on a uniform grid from the first contact, ``T >= 2``.
        dt: sampling interval [s].

    Returns:
        ``[..., T]`` acceleration [m/s^2] (differentiable).

    Raises:
        PulseError: ``velocity`` is not a real ``[..., T]`` tensor of at least 2 samples, or ``dt`` is not a finite
            step > 0 s.
    """
    velocity = _check_velocity(velocity)
    dt = check_step(dt)
    if velocity.shape[-1] < 2:
        raise PulseError(f"need at least 2 velocity samples for an acceleration, got {velocity.shape[-1]}")
    v = torch.cat([velocity[..., :1], velocity], dim=-1)
    return torch.gradient(v, spacing=dt, dim=-1)[0][..., 1:]


def filter_pulse(pulse: Pulse, cfc: int = 60, pad_time: float = DEFAULT_PAD_TIME) -> Pulse:
    """CFC-filter every channel of a uniformly sampled pulse (see :mod:`marlcrash.pulse.cfc`).

    A pulse already filtered with ``cfc`` (``pulse.cfc``) is returned as it is.

    Raises:
        PulseError: the pulse is not uniformly sampled (resample it first), already filtered
            with a lower (stricter) class, or shorter than one period of the -3 dB frequency (10 ms at
            CFC 60): the end reflections then dominate, and a 5 ms, 20 g half-sine came out at 14 g,
            a 2 ms one with its integral's sign reversed.
    """
    cfc = check_cfc(cfc)
    span = pulse.n_samples * pulse.dt
    if span < 1.0 / f_n(cfc):
        raise PulseError(
            f"{pulse.source or 'pulse'}: a record of {span * 1e3:.3g} ms is too short for CFC {cfc}; expected at "
            f"least {1e3 / f_n(cfc):.3g} ms (one period of its {f_n(cfc):.0f} Hz -3 dB frequency)"
        )
    if not pulse.is_uniform:
        raise PulseError(
            f"{pulse.source or 'pulse'}: CFC filtering needs uniform sampling; resample first "
            f"(marlcrash.pulse.resample)"
        )
    if pulse.cfc is not None and pulse.cfc < cfc:
        raise PulseError(f"{pulse.source or 'pulse'}: already filtered with CFC {pulse.cfc}, cannot apply CFC {cfc}")
    if pulse.cfc == cfc:  # filtered twice, a 10 ms, 50 g half-sine's 47.5 g CFC 60 peak came out at 45.0 g
        return pulse
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
    if not (_is_real(rate_hz) and np.isfinite(rate_hz) and rate_hz > 0):
        raise PulseError(f"resampling rate must be a positive number of Hz, got {rate_hz!r}")
    for name, t in (("t_start", t_start), ("t_end", t_end)):
        if t is not None and not (_is_real(t) and np.isfinite(t)):
            raise PulseError(f"{name}: expected a time [s] or None, got {t!r}")
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
    """The first crossing [s] of ``|acc| = threshold_g`` by any channel (interpolated): a plain level crossing.

    A record's time zero is its onset (:func:`find_onset`), which a crossing lies off: after a slow onset, and on a
    CFC-filtered record before a sharp one. Pass a filtered pulse (:func:`filter_pulse`); noise on raw data would
    trigger early.

    Raises:
        PulseError: no channel reaches the threshold, or it is already exceeded at the first sample.
    """
    if not (_is_real(threshold_g) and threshold_g > 0):  # text was "'>' not supported"
        raise PulseError(f"threshold_g: time-zero threshold must be > 0 g, got {threshold_g!r}")
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
"""Onset detection level as a multiple of a channel's pre-trigger noise as the detection filter passes it, where that
is above ``threshold_g`` (:func:`find_onset`)."""
MIN_PRE_TRIGGER = 0.0025
"""[s] Fewest seconds of samples before a channel's onset for :func:`find_onset` to measure its zero level and noise
on them (those up to :data:`ONSET_GAP` before it: 2 ms, 20 samples at 10 kHz; and at least :data:`MIN_SAMPLES`). A
lab export's 5-20 ms of pre-trigger data are enough; the zero level's own uncertainty is the noise over the root
of their number (3 g rms over 5 ms at 10 kHz: 0.4 g)."""
ONSET_GAP = 0.0005
"""[s] A channel's zero level and noise are measured on its samples up to this long before the record's time zero
(:func:`find_onset`)."""
ONSET_FIT_FRACTION = 0.4
"""The onset line is fitted up to where the pulse reaches this fraction of its peak (or 3x the onset level of the
band it is found on, where higher; at most half the peak): long enough to average the noise, short enough that a
half-sine's start is nearly straight (fitted to 40-50 % of its peak, the line starts 0.05-0.15 ms before a 60-100 ms
half-sine's onset)."""
ONSET_SEARCH = 0.02
"""[s] How far before the filtered record's first crossing of its onset level the onset is searched: a zero-phase
filter spreads a sharp onset backwards by up to about 13 ms (CFC 60)."""
_FIT_STEPS = 8
"""Candidate onsets per sampling interval in :func:`_hinge_fit`."""
_ONSET_PASSES = 4
"""Most passes of :func:`find_onset` (zero level and noise measured before the onset of the previous pass)."""
PRE_PULSE_NOTE = 0.2
"""[m/s] :func:`find_onset` names a channel in a warning when its samples before time zero step to another level (its
pulse starting before the onset found: a pre-pulse below the onset level) and their mean, taken as its zero level,
puts its velocity change this far off to the record's end. Four times the calibration's success DFD (0.05 m/s); the
simulated tunnel read alone is 1.9 m/s off from a record that starts at the contact, 0.45 m/s after 20 ms of rest."""


def _level_step(y: np.ndarray) -> tuple[int, float, float, float]:
    """The least-squares split of samples ``y`` into two levels: ``(samples before the split, level before, level
    after, rms deviation from the two levels)``; at least two samples on either side (``len(y) >= 4``)."""
    n = y.size
    c = np.cumsum(y)
    s = np.arange(2, n - 1)
    m1 = c[s - 1] / s
    m2 = (c[-1] - c[s - 1]) / (n - s)
    gain = s * (n - s) / n * (m1 - m2) ** 2  # the squared deviation the split removes
    j = int(np.argmax(gain))
    rest = float(np.sum((y - y.mean()) ** 2) - gain[j])
    return int(s[j]), float(m1[j]), float(m2[j]), math.sqrt(max(rest, 0.0) / n)


@dataclass(frozen=True)
class Onset:
    """Where a record's pulse starts (:func:`find_onset`), per channel and for the record.

    Attributes:
        time: time zero [s] on the record's clock: the earliest channel onset, not before the first sample.
        onsets: ``[K]`` each channel's onset [s] (``inf``: the channel never leaves its noise).
        zero_level: ``[K]`` each channel's zero level [m/s^2]: the mean of its samples up to :data:`ONSET_GAP`
            before the record's time zero; 0 where not measured.
        noise: ``[K]`` rms deviation of those samples [m/s^2]; 0 where not measured.
        level: ``[K]`` the detection level [m/s^2]: ``threshold_g``, or :data:`NOISE_LEVELS` times the noise as the
            detection filter passes it, where that is higher.
        pre_trigger: ``[K]`` seconds of samples before the record's time zero, which each zero level is measured on
            (the same for every channel).
        measured: ``[K]`` whether the zero level and noise were measured (at least :data:`MIN_PRE_TRIGGER` of
            samples before time zero, and :data:`MIN_SAMPLES` samples).
    """

    time: float
    onsets: np.ndarray
    zero_level: np.ndarray
    noise: np.ndarray
    level: np.ndarray
    pre_trigger: np.ndarray
    measured: np.ndarray


def _ms(seconds: float) -> str:
    """``seconds`` in ms with two decimals, for a message (``0.00``, not ``-0.00``)."""
    return f"{float(seconds) * 1e3 + 0.0:.2f}".replace("-0.00", "0.00")


def _quiet_filter(x: np.ndarray, dt: float, cfc: int | None) -> np.ndarray:
    """``x`` CFC-filtered at ``cfc`` (``None``: as it is), without the J211 10 F_H note (finding an onset, not a
    corridor)."""
    if cfc is None:
        return np.asarray(x, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return cfc_filter(x, dt, cfc, axis=-1)


def _detection_filter(x: np.ndarray, dt: float, cfc: int | None) -> np.ndarray:
    """``x`` (a channel less its zero level) filtered for onset detection (:func:`_quiet_filter`) with a resting
    lead-out of :data:`PRE_IMPACT_TIME` after it, as the lead-in before it: the J211 odd reflection at the record's
    own end pins the output to the last samples and passes their noise up to 7x less attenuated (CFC 60 at 10 kHz),
    so 3 g of noise crossed a 5-sigma level there; with the lead-out no output sample passes more noise than the
    record's interior."""
    if cfc is None:
        return np.asarray(x, dtype=np.float64)
    pad = np.zeros((*np.shape(x)[:-1], round(PRE_IMPACT_TIME / dt)))
    return _quiet_filter(np.concatenate([x, pad], axis=-1), dt, cfc)[..., : np.shape(x)[-1]]


@functools.lru_cache(maxsize=64)
def _white_gain(cfc: int | None, dt: float) -> float:
    """Rms of white noise of unit rms after the CFC filter at interval ``dt`` (its impulse response's 2-norm)."""
    if cfc is None:
        return 1.0
    n = 2 * round(2.0 * PRE_IMPACT_TIME / dt) + 1
    impulse = np.zeros(n)
    impulse[n // 2] = 1.0
    return float(np.sqrt(np.sum(_quiet_filter(impulse, dt, cfc) ** 2)))


def _onset_bands(cfc: int | None, rate_hz: float) -> list[int | None]:
    """The detection class, then every wider one the rate can filter, then the record as it is (``None``)."""
    if cfc is None:
        return [None]
    wider = [c for c in CFC_CLASSES if c > cfc and min_rate_hz(c) < rate_hz]
    return [cfc, *wider, None]


def _first_crossing(t: np.ndarray, y: np.ndarray, level: float, i0: int = 0) -> tuple[int, float] | None:
    """The first index ``i >= i0`` with ``y[i] >= level`` and the crossing time, interpolated; ``None`` without."""
    above = np.flatnonzero(y[i0:] >= level)
    if above.size == 0:
        return None
    i = i0 + int(above[0])
    if i == 0 or y[i - 1] >= level:
        return i, float(t[i])
    return i, float(t[i - 1] + (level - y[i - 1]) / (y[i] - y[i - 1]) * (t[i] - t[i - 1]))


def _hinge_fit(t: np.ndarray, y: np.ndarray, candidates: np.ndarray, free_level: bool) -> int:
    """The index of the ``t0`` of ``candidates`` whose least-squares fit ``y ~ b + s (t - t0)+`` leaves the least
    squared error (``b = 0`` unless ``free_level``): a level, then a straight line from the onset ``t0``."""

    def suffix(v: np.ndarray) -> np.ndarray:  # sums over samples k.. (k = 0..n)
        return np.concatenate([np.cumsum(v[::-1])[::-1], [0.0]])

    n1, s_t, s_tt, s_y, s_ty = suffix(np.ones_like(t)), suffix(t), suffix(t * t), suffix(y), suffix(t * y)
    k = np.searchsorted(t, candidates, side="right")  # the samples after each candidate: k..
    c = candidates
    a1 = s_t[k] - c * n1[k]  # sum of (t - t0)+
    a2 = s_tt[k] - 2.0 * c * s_t[k] + c * c * n1[k]  # sum of (t - t0)+^2
    ay = s_ty[k] - c * s_y[k]  # sum of y (t - t0)+
    yy, ysum, n = float(y @ y), float(y.sum()), float(y.size)
    if free_level:
        det = n * a2 - a1 * a1
        ok = (n1[k] >= 2) & (det > 1e-12 * n * a2)
        safe = np.where(ok, det, 1.0)
        b = (a2 * ysum - a1 * ay) / safe
        s = (n * ay - a1 * ysum) / safe
        sse = yy - 2.0 * b * ysum - 2.0 * s * ay + b * b * n + 2.0 * b * s * a1 + s * s * a2
    else:
        ok = a2 > 0
        s = ay / np.where(ok, a2, 1.0)
        sse = yy - s * ay
    return int(np.argmin(np.where(ok, sse, np.inf)))


def _channel_onset(
    t: np.ndarray, x: np.ndarray, n_lead: int, bands: list[int | None], level0: float, noise: float,
    quiet: np.ndarray | None, need: float,
) -> tuple[float, float, bool]:  # fmt: skip
    """One channel's onset [s] (``inf`` if it never reaches its level), detection level [m/s^2] (:func:`find_onset`),
    and whether its pre-trigger data are too short after all (the onset fitted at ``need`` after the first sample,
    the earliest it may be with a measured zero level).

    Args:
        t: times of the led-in record (``n_lead`` samples of lead-in, then the record).
        x: the channel less its zero level, zero over the lead-in.
        n_lead: samples of lead-in.
        bands: :func:`_onset_bands`.
        level0: ``threshold_g`` [m/s^2].
        noise: rms of the pre-trigger samples [m/s^2] (0 if not measured).
        quiet: mask of the pre-trigger samples, or ``None`` where too few (the zero level is then 0, known, and the
            lead-in stands for the pre-trigger data).
        need: seconds of samples a measured zero level needs before the onset (:data:`MIN_PRE_TRIGGER`).
    """
    dt = float(t[1] - t[0])

    def band_level(c: int | None) -> tuple[np.ndarray, float]:
        d = _detection_filter(x, dt, c)
        sigma = noise * _white_gain(c, dt)
        if quiet is not None and c is not None:  # coloured noise (hum, vibration) passes the filter as it is
            sigma = max(sigma, float(np.sqrt(np.mean(_quiet_filter(np.where(quiet, x, 0.0), dt, c)[quiet] ** 2))))
        return d, max(level0, NOISE_LEVELS * sigma)

    d0, level = band_level(bands[0])
    sign = 1.0 if d0.max() >= -d0.min() else -1.0  # the pulse's direction (a zero-phase filter rings the other way)
    hit = _first_crossing(t, sign * d0, level)
    if hit is None:
        return math.inf, level, False
    t_cross = hit[1]
    i_from = int(np.searchsorted(t, t_cross - ONSET_SEARCH))
    # the line is fitted up to where the pulse reaches a fraction of its peak, found on the widest band whose noise
    # is well below that level (a sharp onset: close to the record itself; a slow one under noise: the detection
    # band), and a quarter period of the band's -3 dB frequency on (its zero-phase filter moves a sharp rise earlier)
    t_end = t_cross
    for c in reversed(bands):
        d, lev = (d0, level) if c == bands[0] else band_level(c)
        y = sign * d
        peak = float(y[i_from:].max())
        top = min(max(3.0 * lev, ONSET_FIT_FRACTION * peak), 0.5 * peak)
        if c != bands[0] and top < 2.0 * lev:
            continue
        end = _first_crossing(t, y, top, i_from)
        if end is not None:
            t_end = max(end[1] + (0.0 if c is None else 0.25 / f_n(c)), t_cross)
            break
    j = min(t.size, int(np.searchsorted(t, t_end, side="right")) + 2)  # and two samples on
    i = n_lead if quiet is not None else 0  # a measured zero level is fitted along; else 0, the lead-in known
    # a measured zero level needs samples before the onset: the fit's start at that bound (the record supports no
    # later one) means too few
    floor = float(t[i]) + (need if quiet is not None else 0.0)
    lo = max(floor, t_cross - ONSET_SEARCH)
    step = dt / _FIT_STEPS  # candidates on a fixed grid of the record's clock, wherever the search starts
    first_step = math.ceil((lo - float(t[0])) / step - 1e-6)
    candidates = float(t[0]) + step * np.arange(first_step, math.floor((float(t[j - 1]) - float(t[0])) / step) + 1)
    if candidates.size == 0:
        return (t_cross, level, False) if quiet is None else (lo, level, True)
    best = _hinge_fit(t[i:j], x[i:j], candidates, free_level=quiet is not None)
    return float(candidates[best]), level, quiet is not None and best == 0 and lo == floor


def find_onset(pulse: Pulse, cfc: int | None = 60, threshold_g: float = DEFAULT_THRESHOLD_G) -> Onset:
    """Where the pulse of each channel starts, its zero level and noise, and the record's time zero.

    SAE J211 / ISO 6487 practice, for records whose clock is not aligned to the contact (``time_zero: threshold``):

    1. A channel's zero level and noise are the mean and rms deviation of its samples from the first one to
       :data:`ONSET_GAP` before the record's time zero (its pre-trigger data), whatever the record's clock: no
       negative times are needed, and a transducer offset above ``threshold_g`` is measured like any other. Not
       up to the channel's own onset where that comes later: after the contact no channel is at rest (a simulated
       tunnel decelerates at 2.6 g while its main pulse is 6 ms away), and those samples counted as offset left a
       1.5 g decelerating one 0.18 g off, a drift of 0.3 m/s over 150 ms.
    2. The pulse is detected where the channel less its zero level, CFC-filtered at ``cfc``, first leaves
       ``threshold_g`` or :data:`NOISE_LEVELS` times its pre-trigger noise after that filter (where higher), in the
       pulse's direction (its largest excursion); filtered with a resting lead-out after the record, so that the
       filter's end reflection does not lift the noise of its last samples.
    3. The onset is the start of a straight line fitted by least squares, with the zero level, to the samples of
       the record (not filtered: the zero-phase filter spreads an onset backwards) up to where the pulse reaches
       :data:`ONSET_FIT_FRACTION` of its peak: a level crossing lies after the onset by the level over the slope
       (5 g over a 1.2 g/ms half-sine: 4 ms), the fitted line's start at it.

    Steps 1 and 3 depend on each other: the first pass measures up to a rough start (the filtered channel at a
    fifth of its peak), each further one before the time zero of the last, until it stays within a sample (at most
    :data:`_ONSET_PASSES` passes; two, usually).

    A channel with less than :data:`MIN_PRE_TRIGGER` of samples before time zero has no pre-trigger data to measure:
    its zero level is taken as 0, the threshold is its level, and a warning names the file and channel (a record
    that starts at the contact is read with ``time_zero: file``). The record's time zero is the earliest channel
    onset, not before its first sample. A table of breakpoints (:attr:`Pulse.drawn`) has a zero level of 0 and no
    noise by construction: none is measured (the median of its first 2 ms, the rough start's reference, took a
    rectangle drawn from its first row as the level at rest, and its falling edge as the onset) and nothing is said.

    Limits of the method (README, "Calibrating against a measured test"): an onset is placed to about a sample (a
    2 kHz simulated up-front sensor, 480 g in its first sample: 0.56 ms before the contact); and a channel read alone
    whose pulse starts with a pre-pulse below 5x the noise measured with it takes that as its zero level (the
    simulated tunnel's 2.6 g over the 6 ms before its main pulse: 1.9 m/s of its velocity change lost). A record
    whose t = 0 is the contact is read with ``time_zero: file``; the channels of a test are read together. Such a loss
    is named in a warning (the channel, where its samples before time zero step, and about how much its velocity
    change loses to the record's end, where that is :data:`PRE_PULSE_NOTE` or more).

    Args:
        pulse: the record (resampled at its mean rate here if non-uniform).
        cfc: the detection filter class (the class the record is filtered with), ``None`` for data filtered
            already.
        threshold_g: the lowest detection level [g].

    Returns:
        The :class:`Onset`.

    Raises:
        PulseError: a threshold <= 0, or no channel leaves its noise (naming the file and each channel's level).
    """
    if not (_is_real(threshold_g) and threshold_g > 0):  # text was "'>' not supported"
        raise PulseError(f"threshold_g: time-zero threshold must be > 0 g, got {threshold_g!r}")
    where = pulse.source or "pulse"
    u = pulse if pulse.is_uniform else resample(pulse, pulse.sample_rate_hz)
    dt = u.dt
    led = lead_in(u, PRE_IMPACT_TIME)
    t, n_lead, first = led.time, led.n_samples - u.n_samples, float(u.time[0])
    bands = _onset_bands(cfc, 1.0 / dt)
    k_n = u.n_channels
    level0 = threshold_g * G0
    need = max(MIN_PRE_TRIGGER, ONSET_GAP + MIN_SAMPLES * dt)  # seconds before an onset that measure its zero level
    # a rough start: the channel (less the median of its first 2 ms) filtered, at a fifth of its peak, or above
    # the noise of those 2 ms (median absolute deviation; without it, 3 g of noise on a 10 g pulse crossed first
    # near the record's start, and the pre-trigger data were given up as too short)
    head = u.acc[:, : max(1, round(0.002 / dt))]
    centre = np.zeros((k_n, 1)) if u.drawn else np.median(head, axis=1, keepdims=True)  # drawn: its level is 0
    head_noise = 1.4826 * np.median(np.abs(head - centre), axis=1) * _white_gain(bands[0], dt)
    rough = led.acc - centre
    rough[:, :n_lead] = 0.0
    filtered = _detection_filter(rough, dt, bands[0])
    ends = np.empty(k_n)
    for k in range(k_n):
        mag = np.abs(filtered[k])
        peak = float(mag.max())
        rough_level = max(0.2 * peak, level0, min(NOISE_LEVELS * head_noise[k], 0.5 * peak))
        ends[k] = float(t[int(np.argmax(mag >= rough_level))])
    zero, noise, level = np.zeros(k_n), np.zeros(k_n), np.full(k_n, level0)
    measured = np.zeros(k_n, dtype=bool)
    onsets = np.full(k_n, math.inf)
    quiet_of = [np.zeros(t.size, dtype=bool)] * k_n  # the samples each zero level is the mean of
    for n_pass in range(_ONSET_PASSES):
        before = ends.copy()
        for k in range(k_n):
            quiet = quiet_of[k] = (t >= first) & (t < ends[k])
            measured[k] = (not u.drawn and quiet.sum() >= MIN_SAMPLES
                           and ends[k] - first >= need - ONSET_GAP - 0.5 * dt)  # fmt: skip
            zero[k] = float(led.acc[k, quiet].mean()) if measured[k] else 0.0
            noise[k] = float(led.acc[k, quiet].std()) if measured[k] else 0.0
            x = led.acc[k] - zero[k]
            x[:n_lead] = 0.0
            found = _channel_onset(t, x, n_lead, bands, level0, noise[k], quiet if measured[k] else None, need)
            if found[2]:  # too few samples before the onset after all: the zero level is 0
                measured[k], zero[k], noise[k] = False, 0.0, 0.0
                x = led.acc[k].copy()
                x[:n_lead] = 0.0
                found = _channel_onset(t, x, n_lead, bands, level0, 0.0, None, need)
            onsets[k], level[k] = found[:2]
            if math.isfinite(onsets[k]):
                ends[k] = onsets[k] - ONSET_GAP
        if np.all(np.isinf(onsets)):
            filtered = _detection_filter(led.acc - zero[:, None], dt, bands[0])
            filtered[:, :n_lead] = 0.0
            by = "" if bands[0] is None else f" after CFC {bands[0]}"
            peaks = np.abs(filtered).max(axis=1) / G0
            each = "; ".join(f"{name!r} peaks at {peaks[k]:.3g} g{by}, its onset level is {level[k] / G0:.3g} g"
                             for k, name in enumerate(u.channels))  # fmt: skip
            raise PulseError(
                f"{where}: no channel leaves its pre-trigger noise ({threshold_g:g} g, or {NOISE_LEVELS:g} x its "
                f"noise where higher): {each}"
            )
        # every channel is at rest before the record's time zero (the contact), none after it: a channel whose own
        # onset comes later (a tunnel) already decelerates in between, and its mean there is no transducer offset
        t_zero = float(onsets.min())
        ends = np.minimum(ends, t_zero - ONSET_GAP)
        ends[np.isinf(onsets)] = t_zero - ONSET_GAP
        if n_pass > 0 and np.all(np.abs(ends - before) < dt):  # measured before the time zero found with it
            break
    pre = np.full(k_n, t_zero - first)  # the samples each zero level is measured on: those before time zero
    for k in [] if u.drawn else np.flatnonzero(~measured).tolist():  # drawn: its zero level is 0, not a fallback
        at = f"its onset at t = {_ms(onsets[k])} ms" if onsets[k] == t_zero else (
            f"the record's time zero at t = {_ms(t_zero)} ms")  # fmt: skip
        warnings.warn(
            f"{where}: channel {u.channels[k]!r} has {max(pre[k], 0.0) * 1e3:.1f} ms of samples before {at}, "
            f"{SHORT_PRE_TRIGGER} (time_zero threshold needs {need * 1e3:.3g} ms of "
            f"pre-trigger data): its zero level is taken as 0 and its onset level as {threshold_g:g} g. A record that "
            "starts at the contact is read with time_zero file (--time-zero file)",
            UserWarning,
            stacklevel=2,
        )
    _warn_pre_pulse(where, u.channels, t, led.acc, quiet_of, measured, zero, max(t_zero, first), first, level0)
    return Onset(
        time=max(t_zero, first), onsets=onsets, zero_level=zero, noise=noise, level=level,
        pre_trigger=np.maximum(pre, 0.0), measured=measured.copy(),
    )  # fmt: skip


def _warn_pre_pulse(
    where: str, channels: Sequence[str], t: np.ndarray, acc: np.ndarray, quiet_of: list[np.ndarray],
    measured: np.ndarray, zero: np.ndarray, t_zero: float, first: float, level0: float,
) -> None:  # fmt: skip
    """Name in a warning each channel whose samples before time zero (``quiet_of``, the zero level's) are not at rest:
    they step to another level, by more than ``level0`` and :data:`NOISE_LEVELS` times their deviation from the two
    levels, and their mean, its zero level, puts the velocity change at least :data:`PRE_PULSE_NOTE` off to the
    record's end against the level before the step. A pre-pulse below the onset level (the simulated tunnel read
    alone: 2.6 g from 1.5 ms, its main pulse at 6 ms) was taken as a transducer offset without a word."""
    span = float(t[-1]) - max(t_zero - PRE_IMPACT_TIME, first)  # the zero level is subtracted from the integral over it
    for k in np.flatnonzero(measured).tolist():
        y, ty = acc[k, quiet_of[k]], t[quiet_of[k]]
        if y.size < 4:
            continue
        split, rest, later, dev = _level_step(y)
        if not abs(later - rest) > max(level0, NOISE_LEVELS * dev):
            continue
        off = (zero[k] - rest) * span  # the integral of the zero level less the level at rest
        if abs(off) < PRE_PULSE_NOTE:
            continue
        change = float(np.sum(acc[k, t >= t_zero] - zero[k]))  # the velocity change's direction
        side = "short" if off * change > 0 else "too large"
        warnings.warn(
            f"{where}: channel {channels[k]!r} is not at rest before the record's time zero at t = {_ms(t_zero)} ms: "
            f"its samples there step by {(later - rest) / G0:.3g} g at t = {_ms(ty[split])} ms (its pulse starts "
            "before the onset found, a pre-pulse below its onset level) and their mean is taken as its zero level: "
            f"its velocity change comes out about {abs(off):.2g} m/s {side} over the {span * 1e3:.0f} ms to the "
            "record's end. A record whose t = 0 is the contact is read with time_zero file (--time-zero file); a "
            "test's channels are read together (a file reference: the earliest onset is the contact)",
            UserWarning,
            stacklevel=3,
        )


SHORT_PRE_TRIGGER = "too few to measure its zero level and noise"
"""Part of :func:`find_onset`'s warning about a channel without pre-trigger data (never said of a drawn pulse)."""
OFFSET_LEFT_IN = "any transducer offset is left in the record"
"""Part of :func:`remove_zero_offset`'s warning about a record with too little pre-trigger data."""


ZERO_LEVEL_MARGIN = 0.001
"""[s] The zero level of a record is the mean of its samples up to this long before its t = 0 (pre-trigger data)."""
MAX_ZERO_OFFSET_G = 2.0
"""[g] A pre-trigger mean above this is not a transducer offset (the record's clock puts part of the crash, or a
fault, before t = 0): :func:`remove_zero_offset` then leaves the channel as it is and warns. Measured before the
onset found (``time_zero: threshold``, :func:`without_zero_offset`) it is subtracted all the same, with a warning."""


def remove_zero_offset(
    pulse: Pulse, before: float = -ZERO_LEVEL_MARGIN, min_time: float = 0.005, max_offset_g: float = MAX_ZERO_OFFSET_G
) -> Pulse:
    """Subtract each channel's zero level: the mean of its raw samples before ``before`` [s] (ISO 6487 / SAE J211
    practice: the pre-trigger samples of a test are at rest, so their mean is the transducer's offset).

    A DC offset integrates into a velocity drift: 0.3 g over 150 ms is 0.44 m/s. This is the zero level of a record
    whose t = 0 is the contact (``time_zero: file``); :func:`find_onset` measures it before the onset found
    otherwise. A record without samples before ``before`` (one that starts at the impact) is returned unchanged (the
    same object); so is one with less than ``min_time`` of them, with a warning naming the file (its offset, if any,
    stays: 0.8 g drifts about 8 % into a 40 km/h velocity change over 150 ms); and so is a channel whose pre-trigger
    mean exceeds ``max_offset_g`` (with a warning): those samples are not at rest. A table of breakpoints
    (:attr:`Pulse.drawn`) has no offset: it is returned unchanged.
    """
    if pulse.drawn or float(pulse.time[0]) >= 0.0:  # drawn, or starts at the contact: nothing to measure or say
        return pulse
    pre = pulse.time < before
    span = float(pulse.time[pre][-1] - pulse.time[0]) if pre.any() else 0.0  # 0-1 ms of negative times: none
    if span < min_time:
        warnings.warn(
            f"{pulse.source or 'pulse'}: {-float(pulse.time[0]) * 1e3:.3g} ms of pre-trigger samples (negative times), "
            f"{span * 1e3:.3g} ms of them before t = {before * 1e3:g} ms, fewer than the {min_time * 1e3:g} ms that "
            f"measure a channel's zero level: {OFFSET_LEFT_IN} (it integrates into a velocity drift); keep more of "
            "the test's pre-trigger data",
            UserWarning,
            stacklevel=2,
        )
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
    times (:func:`remove_zero_offset`). With ``"threshold"`` the file's clock is not trusted: each channel's offset
    is the mean of its samples before the pulse's onset, the record's time zero (:func:`find_onset`), whatever the
    record's clock, also where it is above the threshold. A channel with too few samples before it (less than
    :data:`MIN_PRE_TRIGGER`) is left as recorded; :func:`filtered_from_time_zero`, which finds time zero on the
    result, warns about it, naming the channel. A threshold-mode offset above :data:`MAX_ZERO_OFFSET_G` (by more than
    three standard errors of the mean) is subtracted all the same (those samples precede the onset), with a warning
    naming the channel. A table of breakpoints (:attr:`Pulse.drawn`) has no offset: it is returned unchanged.
    """
    if pulse.drawn:  # zero level 0 by construction: its first rows may be the pulse itself (a rectangle)
        return pulse
    if time_zero != "threshold":
        return remove_zero_offset(pulse)
    with warnings.catch_warnings():  # said once, by filtered_from_time_zero, which runs on the result
        warnings.simplefilter("ignore")
        onset = find_onset(pulse, cfc, threshold_g)
    level = np.where(onset.measured, onset.zero_level, 0.0)
    # beyond the offset by more than three standard errors of the mean (noise over 5 ms of 3 g: 0.4 g)
    n = np.maximum((onset.pre_trigger - ONSET_GAP) / pulse.dt, 1.0)
    for k in np.flatnonzero(np.abs(level) - 3.0 * onset.noise / np.sqrt(n) > MAX_ZERO_OFFSET_G * G0).tolist():
        warnings.warn(
            f"{pulse.source or 'pulse'}: channel {pulse.channels[k]!r} averages {level[k] / G0:.3g} g before "
            f"{'its onset' if onset.onsets[k] == onset.time else 'the pulse onset'} at t = {_ms(onset.time)} ms, "
            f"more than a transducer offset ({MAX_ZERO_OFFSET_G:g} g): "
            "subtracted as its zero level all the same; check the channel",
            UserWarning,
            stacklevel=2,
        )
    return replace(pulse, acc=pulse.acc - level[:, None])


def shift_time(pulse: Pulse, t0: float) -> Pulse:
    """The pulse with its clock shifted so that ``t0`` becomes time 0."""
    return replace(pulse, time=pulse.time - float(t0))


def lead_in(pulse: Pulse, pre_time: float) -> Pulse:
    """A uniform pulse with ``pre_time`` [s] of zero acceleration put before its first sample (same rate).

    The lead-in is spaced by the record's mean step, which it leaves unchanged: spaced by the first step, a record
    uniform within :data:`UNIFORM_RTOL` (times written to 7 decimals at 12.8 kHz) came out non-uniform, and the
    filter refused it ("CFC filtering needs uniform sampling")."""
    dt = pulse.dt
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
    n = round(pre_time / check_step(dt))
    a = np.asarray(acc, dtype=np.float64)
    led = np.concatenate([np.zeros((*a.shape[:-1], n)), a], axis=-1)
    return cfc_filter(led, dt, cfc, axis=-1)[..., n:]


def filtered_from_time_zero(
    pulse: Pulse,
    cfc: int | None = 60,
    time_zero: str = "threshold",
    threshold_g: float = DEFAULT_THRESHOLD_G,
    *,
    warn_late: bool = False,
) -> tuple[Pulse, float]:
    """A record made uniform (resampled at its mean rate if needed), CFC-filtered at that rate, and its time zero.

    Args:
        pulse: the raw (or already filtered) pulse.
        cfc: CFC class, or ``None`` to skip filtering.
        time_zero: ``"threshold"`` (the earliest channel onset, :func:`find_onset`) or ``"file"`` (the file's t = 0).
        threshold_g: the lowest onset detection level [g] (:func:`find_onset`).
        warn_late: with ``"file"``, name in a warning a pulse that starts more than :data:`LATE_ONSET_S` after t = 0
            on a record at rest before it (a clock that does not start at the contact), as :func:`prepare_velocity`
            does for a file reference, whose channels are the vehicle's (an occupant's start later, at rest).

    With ``"threshold"``, time zero is where the pulse starts (:func:`find_onset`): detected on the record filtered
    at ``cfc`` against its pre-trigger noise, and placed by a straight line fitted to the unfiltered record's onset.
    A level crossing of the filtered record lay milliseconds off: the zero-phase filter spreads a sharp onset
    (a bumper-region sensor stopping within 1-2 ms, a 3 ms half-sine) backwards, so it crosses 0.5 g 5-13 ms
    before it starts, and a noise level above 0.5 g is reached milliseconds after a slow onset. A channel with too
    little pre-trigger data to measure its zero level and noise is named in a warning (:func:`find_onset`).

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
        return p, find_onset(u, cfc, threshold_g).time
    if time_zero == "file":
        if warn_late:
            _warn_late_onset(u, cfc, threshold_g)
        return p, 0.0
    raise PulseError(f"time_zero must be 'threshold' or 'file', got {time_zero!r}")


LATE_ONSET_S = 0.010
"""[s] A pulse that starts this long after the file's t = 0, read with ``time_zero: file`` (t = 0 the contact), is
named in a warning by :func:`prepare_velocity` (a file reference) where every channel is at rest before it: a record
on a clock from 0 with its pre-trigger data at positive times. In the model's own simulations the onset of a record
read with its up-front channels lies within 1 ms of the contact, and the tunnel's read alone at most 5.8 ms after it
(full width, 40 km/h), or later after a pre-pulse that is no rest (small overlap, unfiltered: 21 ms, averaging 7.7
g)."""


def _warn_late_onset(pulse: Pulse, cfc: int | None, threshold_g: float) -> None:
    """Warn where ``pulse``'s onset (:func:`find_onset`) lies more than :data:`LATE_ONSET_S` after its t = 0, which
    ``time_zero: file`` takes as the contact: it is compared as if the impact came that much before the pulse."""
    if pulse.time[0] > 0.0:  # a t = 0 off the record is refused, naming it
        return
    with warnings.catch_warnings():  # its own warnings are those of time_zero threshold, not this reading's
        warnings.simplefilter("ignore")
        try:
            onset = find_onset(pulse, cfc, threshold_g)
        except PulseError:  # no pulse above the noise: nothing to place
            return
    if onset.time <= LATE_ONSET_S:
        return
    k = int(np.argmin(onset.onsets))
    before = (pulse.time >= 0.0) & (pulse.time <= onset.time)
    # every channel at rest up to the onset, averaging no more than a transducer offset, as pre-trigger data do; a
    # record from the contact whose onset is misplaced is not (a channel read alone or unfiltered: the simulated
    # tunnel's 7.7 g over the 21 ms before its small-overlap onset; a rectangle sampled from its first row: its
    # onset at its end)
    if np.all(np.abs(pulse.acc[:, before].mean(axis=1)) <= MAX_ZERO_OFFSET_G * G0):
        warnings.warn(
            f"{pulse.source or 'pulse'}: the pulse starts at t = {_ms(onset.time)} ms (channel "
            f"{pulse.channels[k]!r}), but time_zero file takes the file's t = 0 as the contact: it is compared as if "
            "the impact came that much earlier. If the record's clock does not start at the contact (pre-trigger "
            "data at positive times), read it with time_zero: threshold (--time-zero threshold)",
            UserWarning,
            stacklevel=3,
        )


def on_record(pulse: Pulse, t0: float) -> bool:
    """Whether time zero ``t0`` [s] lies on ``pulse`` as read: from one sample interval before its first sample
    (a clock whose first sample closes the first interval) to before its last.

    Not on the lead-in :func:`filtered_from_time_zero` puts before the record: that is zero acceleration assumed,
    not data, and a record starting 15 ms after its t = 0 read with ``time_zero: file`` had those 15 ms of its
    window made up (a 20 g, 80 ms half-sine's velocity change came out 0.84 m/s short, silently).
    """
    return bool(pulse.time[0] - pulse.dt * (1.0 + 1e-6) <= t0 < pulse.time[-1])


def _is_real(x: object) -> bool:
    """Whether ``x`` is a real number (a Python or numpy number; not a bool or text)."""
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


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
        time_zero: ``"threshold"`` (the pulse's onset, :func:`find_onset`) or ``"file"`` (the file's t = 0).
        threshold_g: the lowest onset detection level [g] (:func:`find_onset`).
        v0: forward speed [m/s] before the impact (0 gives the velocity change), or ``[K]`` one per channel.
        beyond: with a ``duration``, also return up to this long [s] past the window, as far as the record
            reaches (the filter ran over the whole record either way; :func:`compared_window`).

    The filtered record is integrated from :data:`PRE_IMPACT_TIME` before time zero (or its first sample, if
    later), where it is ``v0``, as :func:`compared_velocity` integrates a simulation from before its contact:
    the zero-phase filter spreads the onset's deceleration before time zero, so the returned velocity at time
    zero is slightly below ``v0`` (a sharp onset: a few tenths of a m/s), as a simulation's compared one is.

    Returns:
        ``time [T]`` from 0 at ``rate_hz`` and ``velocity [K, T]`` [m/s].

    Raises:
        PulseError: a ``duration`` that is not a window > 0 s, a ``rate_hz`` that is not a rate > 0 Hz, a
            ``beyond`` < 0 s, a ``v0`` that is not a finite speed (or one per channel), a ``threshold_g`` <= 0,
            time zero outside the record (the file's t = 0 of a record on another clock), or a record that ends
            before the window does (naming the file).
    """
    if not (_is_real(beyond) and math.isfinite(beyond) and beyond >= 0):  # text was math's TypeError
        raise PulseError(f"beyond must be a duration >= 0 s, got {beyond!r}")
    try:  # NaN gave a NaN reference, text was read as a number, a speed per channel of another count broadcast
        speed = None if isinstance(v0, str | bool) else np.asarray(v0, dtype=np.float64)
    except (TypeError, ValueError):
        speed = None
    if speed is not None and (speed.ndim > 1 or (speed.ndim == 1 and speed.shape[0] != pulse.n_channels)):
        speed = None
    if speed is None or not np.all(np.isfinite(speed)):
        raise PulseError(f"v0: expected the forward speed before the impact [m/s], a finite number or one per "
                         f"channel ({pulse.n_channels}), got {v0!r}")  # fmt: skip
    if duration is not None and not (_is_real(duration) and math.isfinite(duration) and duration > 0):
        raise PulseError(f"duration: expected a window > 0 s after time zero (or None: to the record's end), "
                         f"got {duration!r}")  # fmt: skip
    if not (_is_real(rate_hz) and math.isfinite(rate_hz) and rate_hz > 0):
        raise PulseError(f"rate_hz: expected a finite output rate > 0 Hz, got {rate_hz!r}")
    p, t0 = filtered_from_time_zero(pulse, cfc, time_zero, threshold_g, warn_late=True)
    if not on_record(pulse, t0):  # the file's t = 0 off a record on another clock
        what, hint = ("its onset", "")
        if time_zero == "file":
            what = "the file's t = 0, time_zero: file"
            hint = ": its clock does not start at the contact; read it with time_zero: threshold (the pulse's onset)"
        raise PulseError(f"{pulse.source or 'pulse'}: time zero t = {t0 * 1e3:.4g} ms ({what}) lies outside the record "
                         f"[{pulse.time[0] * 1e3:.6g}, {pulse.time[-1] * 1e3:.6g}] ms{hint}")  # fmt: skip
    t_end = p.time[-1] if duration is None else t0 + float(duration)
    if duration is not None and t_end > p.time[-1] + 1e-9:
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
    v = q.velocity(speed)[:, n_pre:]
    return np.arange(v.shape[1]) / rate_hz, v
