"""SAE J211 channel frequency class (CFC) filtering.

SAE J211-1 (and ISO 6487) specify the CFC filter as a 4-pole phase-less
Butterworth low-pass: a 2-pole Butterworth section run forward, then backward
over the data. For a CFC class ``C`` the section's design frequency is
``wd = 2*pi*C*2.0775`` [rad/s]; prewarped with ``wa = tan(wd*T/2)`` it gives the
recursion

    y[n] = a0*x[n] + a1*x[n-1] + a2*x[n-2] + b1*y[n-1] + b2*y[n-2]

with ``a0 = wa^2/(1+sqrt(2)*wa+wa^2)``, ``a1 = 2*a0``, ``a2 = a0``,
``b1 = -2*(wa^2-1)/(1+sqrt(2)*wa+wa^2)``, ``b2 = (-1+sqrt(2)*wa-wa^2)/(1+sqrt(2)*wa+wa^2)``.
Run twice, the magnitude is squared: the -3 dB point lies at
``2.0775*C*(sqrt(2)-1)^(1/4) = 5/3*C`` (100 Hz for CFC 60; J211's ``F_N``, whose table rounds
CFC 1000's to 1650 Hz) and the phase is zero. J211's ``F_H`` is the passband's upper edge, the class
itself (60 Hz for CFC 60), where the gain stays within +0.5 / -1 dB.

End handling (a documented choice; J211 asks that start-up transients be kept
out of the data): before filtering, each end is padded with ``pad_time``
(default 10 ms) of its point-symmetric ("odd") reflection about the end value,
and the recursion starts in the steady state of the first padded value
(``scipy.signal.filtfilt(..., padtype="odd")``). Constants and straight lines
pass through unchanged, so a pulse that ends at a non-zero level keeps it.

Two front ends share these coefficients: :func:`cfc_filter` (numpy, any axis,
for file IO) and :func:`cfc_filter_torch` (batched, for surrogate outputs). The
torch front end runs the same recursion over each record when no gradient is
needed, so a record's filtered values do not depend on the other records of its
batch (bit for bit); where a gradient is needed it multiplies by a cached
``[T, T]`` matrix, the filter applied to the identity. A matrix product's
rounding depends on the batch layout (the BLAS kernel handles the rows of a
partial tile differently), about 1e-15 relative, so the two paths agree to
rounding, not bitwise.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
import scipy.signal
import torch

from marlcrash.errors import ConfigError, PulseError
from marlcrash.metrics import _as_signal, check_step

CFC_CLASSES: tuple[int, ...] = (60, 180, 600, 1000)
"""The channel frequency classes of SAE J211 / ISO 6487."""
DESIGN_FACTOR = 2.0775
"""Design frequency of the 2-pole section per CFC unit (J211: ``wd = 2*pi*CFC*2.0775``)."""
DEFAULT_PAD_TIME = 0.010
"""Length [s] of the odd reflection added at both ends before filtering."""


def check_cfc(cfc: int) -> int:
    """Return ``cfc`` if it is a J211 class, else raise :class:`ConfigError` listing them."""
    if isinstance(cfc, bool) or not isinstance(cfc, int | np.integer) or int(cfc) not in CFC_CLASSES:
        raise ConfigError(f"expected a CFC class in {list(CFC_CLASSES)}, got {cfc!r}", key="cfc")
    return int(cfc)


def f_h(cfc: int) -> float:
    """J211's ``F_H`` [Hz], the upper edge of the passband (gain within +0.5 / -1 dB): the class itself (60 Hz for
    CFC 60). The -3 dB frequency is :func:`f_n`."""
    return float(check_cfc(cfc))


def f_n(cfc: int) -> float:
    """J211's ``F_N`` [Hz], the -3 dB frequency of the CFC filter: ``5/3 * CFC`` (100 Hz for CFC 60; J211's table
    rounds CFC 1000's 1667 Hz to 1650)."""
    return 5.0 / 3.0 * check_cfc(cfc)


def min_rate_hz(cfc: int) -> float:
    """[Hz] The sampling rate a class needs to exceed: twice its design frequency (``2 * 2.0775 * CFC``), which must
    lie below Nyquist."""
    return 2.0 * DESIGN_FACTOR * cfc


def _check_dt(dt: float, cfc: int) -> float:
    if not (isinstance(dt, int | float | np.floating) and math.isfinite(dt) and dt > 0):
        raise PulseError(f"sampling interval must be a positive number of seconds, got {dt!r}")
    fd = DESIGN_FACTOR * cfc
    if dt * fd >= 0.5:
        raise PulseError(
            f"CFC {cfc} needs a sampling rate above {min_rate_hz(cfc):.0f} Hz (its design frequency {fd:.1f} Hz "
            f"must lie below Nyquist); got {1 / dt:.1f} Hz"
        )
    if 1.0 / dt < 10.0 * f_h(cfc):  # the customary minimum: 10 kHz for CFC 1000
        warnings.warn(
            f"sampling rate {1 / dt:.0f} Hz is below 10 x F_H = {10 * f_h(cfc):.0f} Hz for CFC {cfc}; the filter's "
            f"response departs from the analog J211 corridor as its -3 dB frequency nears Nyquist",
            stacklevel=3,
        )
    return float(dt)


def cfc_coefficients(cfc: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of the J211 2-pole section, in scipy's ``(b, a)`` form.

    Args:
        cfc: channel frequency class (60, 180, 600 or 1000).
        dt: sampling interval [s].

    Returns:
        ``b = [a0, a1, a2]`` and ``a = [1, -b1, -b2]`` (J211 writes the feedback
        terms with a plus sign; scipy's ``lfilter`` subtracts them).

    Raises:
        ConfigError: ``cfc`` is not a J211 class.
        PulseError: ``dt`` is not positive or too coarse for the class.
    """
    cfc = check_cfc(cfc)
    dt = _check_dt(dt, cfc)
    wd = 2.0 * math.pi * cfc * DESIGN_FACTOR
    wa = math.sin(wd * dt / 2.0) / math.cos(wd * dt / 2.0)
    den = 1.0 + math.sqrt(2.0) * wa + wa**2
    a0 = wa**2 / den
    b1 = -2.0 * (wa**2 - 1.0) / den
    b2 = (-1.0 + math.sqrt(2.0) * wa - wa**2) / den
    return np.array([a0, 2.0 * a0, a0]), np.array([1.0, -b1, -b2])


def cfc_filter(x: np.ndarray, dt: float, cfc: int = 60, *, axis: int = -1, pad_time: float = DEFAULT_PAD_TIME):
    """Filter uniformly sampled data with the J211 CFC filter (zero phase).

    Args:
        x: samples along ``axis``, e.g. ``[K, T]`` accelerations [any unit].
        dt: sampling interval [s].
        cfc: channel frequency class (60, 180, 600 or 1000).
        axis: the time axis.
        pad_time: length [s] of the odd reflection at each end (clipped to the record).

    Returns:
        The filtered array, same shape and dtype float64.

    Raises:
        PulseError: samples that are not real numbers, non-finite samples, an ``axis`` they lack, fewer than 3
            samples, a bad ``dt`` or ``pad_time``.
        ConfigError: ``cfc`` is not a J211 class.
    """
    try:
        a = np.asarray(x)
        real = not np.iscomplexobj(a)  # complex samples lost their imaginary part with a ComplexWarning
        x = a.astype(np.float64) if real else a
    except (TypeError, ValueError):  # text was numpy's 'could not convert string to float'
        raise PulseError(f"CFC filtering needs samples as an array of numbers, got {type(x).__name__}") from None
    if not real:
        raise PulseError(f"CFC filtering needs real samples, got {a.dtype}")
    if x.ndim and not -x.ndim <= axis < x.ndim:
        raise PulseError(f"CFC filtering along axis {axis}: the samples have shape {x.shape}, no such axis")
    if x.ndim == 0 or x.shape[axis] < 3:
        raise PulseError(f"CFC filtering needs at least 3 samples along axis {axis}, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise PulseError("CFC filtering needs finite samples; found NaN or inf")
    return _filtfilt(x, dt, cfc, axis, pad_time)


def _filtfilt(x: np.ndarray, dt: float, cfc: int, axis: int, pad_time: float) -> np.ndarray:
    """The filter of :func:`cfc_filter` on float64 ``x`` with at least 3 samples; NaN propagates per record."""
    b, a = cfc_coefficients(cfc, dt)
    padlen = min(round(_check_pad_time(pad_time) / dt), x.shape[axis] - 1)
    return scipy.signal.filtfilt(b, a, x, axis=axis, padtype="odd" if padlen > 0 else None, padlen=padlen)


def _check_pad_time(pad_time: float) -> float:
    """``pad_time`` as a float if it is a finite duration >= 0 s, else a :class:`PulseError`."""
    ok = isinstance(pad_time, int | float | np.integer | np.floating) and not isinstance(pad_time, bool)
    if not (ok and math.isfinite(pad_time) and pad_time >= 0):
        raise PulseError(f"pad_time must be a duration >= 0 s, got {pad_time!r}")
    return float(pad_time)


@functools.lru_cache(maxsize=32)
def _cfc_matrix_cached(n: int, dt: float, cfc: int, pad_time: float) -> np.ndarray:
    # The filter is linear in x, so filtering the identity gives its matrix: y = M @ x.
    return np.ascontiguousarray(cfc_filter(np.eye(n), dt, cfc, axis=0, pad_time=pad_time))


def cfc_matrix(n: int, dt: float, cfc: int = 60, pad_time: float = DEFAULT_PAD_TIME) -> np.ndarray:
    """The ``[n, n]`` matrix ``M`` with ``cfc_filter(x) == M @ x`` for records of ``n`` samples."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 3:  # numpy's integers are counts too
        raise PulseError(f"CFC filtering needs an integer count of at least 3 samples, got n={n!r}")
    return _cfc_matrix_cached(int(n), check_step(dt), check_cfc(cfc), _check_pad_time(pad_time))


def cfc_filter_torch(x: torch.Tensor, dt: float, cfc: int = 60, pad_time: float = DEFAULT_PAD_TIME) -> torch.Tensor:
    """Batched, differentiable CFC filter over the last axis (same result as :func:`cfc_filter`).

    Without a gradient to track (``x`` on the CPU, not requiring grad, or grad mode off) each record is
    filtered by the recursion itself, so its result does not depend on the batch it came in, bit for bit;
    NaN or inf in a record stays in that record. Otherwise ``x`` is multiplied by the filter's matrix
    (:func:`cfc_matrix`), which agrees to about 1e-15 relative (module docstring).

    Args:
        x: ``[..., T]`` uniformly sampled signals (e.g. ``[B, n_sensors, T]``); an array or an integer tensor is read
            as floating point numbers (float64, the default dtype).
        dt: sampling interval [s].
        cfc: channel frequency class.
        pad_time: end padding [s], as in :func:`cfc_filter`.

    Returns:
        ``[..., T]`` filtered signals, on ``x``'s device and floating dtype.
    """
    x = _as_signal(x, "x")  # an integer record came back truncated to integers, an array was an AttributeError
    n = int(x.shape[-1])
    if x.device.type == "cpu" and not (x.requires_grad and torch.is_grad_enabled()):
        if n < 3:
            raise PulseError(f"CFC filtering needs at least 3 samples, got n={n}")
        y = _filtfilt(  # through float64 in torch: numpy has no bfloat16
            x.detach().to(torch.float64).numpy(), check_step(dt), check_cfc(cfc), -1, _check_pad_time(pad_time)
        )
        return torch.from_numpy(np.ascontiguousarray(y)).to(x.dtype)
    m = torch.as_tensor(cfc_matrix(n, dt, cfc, pad_time), dtype=x.dtype, device=x.device)
    return x @ m.T
