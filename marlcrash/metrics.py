"""Similarity of an estimated and a reference signal (paper Eq. 8 to 11), batched in torch.

All metrics take ``q`` (the estimate, the paper's Q) and ``p`` (the reference, P)
as ``[..., T]`` tensors, typically ``[B, n_sensors, T]`` velocities [m/s], and
return ``[...]`` (``[B, n_sensors]``). They run on any device, support float64,
and are differentiable (the Frechet distance is only sub-differentiable: its
gradient flows through the pair of points that sets the leash length).

- :func:`area_between`: ``A = integral |Q - P| dt`` [m for velocities]. The
  default ``method="exact"`` integrates the piecewise-linear interpolants
  exactly: an interval where ``Q - P`` changes sign is split at its crossing
  into two triangles. ``method="trapezoid"`` applies the trapezoid rule to
  ``|Q - P|`` (it over-estimates intervals with a crossing).
- :func:`discrete_frechet`: the discrete Frechet distance of the polylines
  ``(t_i, q_i)`` and ``(s_j, p_j)`` (Eiter and Mannila's coupling distance,
  Eq. 9, 10): the shortest leash that lets two walkers traverse both point
  sequences forward only. Points are Euclidean in ``(time_scale * t,
  value_scale * v)``; the default scales of 1 use unscaled SI (s, m/s), as in
  the paper's Table 3. Q may have ``n`` and P ``m`` points.
- :func:`rmse`: root mean square of ``Q - P`` over the common time samples (Eq. 11).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numba
import numpy as np
import torch

from marlcrash.config import require
from marlcrash.errors import PulseError


class Metrics(NamedTuple):
    """The three similarity metrics, each ``[...]`` (e.g. ``[B, n_sensors]``), SI units."""

    area: torch.Tensor
    dfd: torch.Tensor
    rmse: torch.Tensor

    def per_sensor(self, names: list[str]) -> dict[str, dict[str, float]]:
        """``{sensor: {"area", "dfd", "rmse"}}`` of per-sensor metrics ``[K]`` (the summary.json form)."""
        if self.area.dim() != 1 or self.area.shape[0] != len(names):
            raise ValueError(f"expected metrics of {len(names)} sensors [K], got shape {tuple(self.area.shape)}")
        return {
            s: {"area": float(self.area[k]), "dfd": float(self.dfd[k]), "rmse": float(self.rmse[k])}
            for k, s in enumerate(names)
        }


MAX_DFD_SCALE = 1e6
"""Largest factor on time or velocity before Frechet distances [-]: ``dfd_value_scale: 1e308`` made every distance
NaN (1e160: inf, its square overflowing) and the reward with it. At this bound a 100 m/s difference is 1e8 and its
square finite in float32."""


@dataclass
class MetricsConfig:
    """How the similarity metrics are computed (part of a reward config).

    Attributes:
        area_method: ``exact`` (piecewise-linear, split at crossings) or ``trapezoid``.
        dfd_time_scale: factor on time [s] before Frechet distances (1: unscaled SI).
        dfd_value_scale: factor on the signal [m/s] before Frechet distances (1: unscaled SI).
    """

    area_method: Literal["exact", "trapezoid"] = "exact"
    dfd_time_scale: float = 1.0
    dfd_value_scale: float = 1.0

    def validate(self) -> None:
        """Raise :class:`~marlcrash.errors.ConfigError` for scales outside ``(0, MAX_DFD_SCALE]``."""
        for k in ("dfd_time_scale", "dfd_value_scale"):
            v = getattr(self, k)
            require(v > 0, f"metrics.{k}", f"must be > 0, got {v}")
            require(v <= MAX_DFD_SCALE, f"metrics.{k}",
                    f"must be at most {MAX_DFD_SCALE:g} (MAX_DFD_SCALE: a larger factor overflows the distance), "
                    f"got {v}")  # fmt: skip


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(x)`` for ``x >= 0`` whose gradient at 0 is 0 instead of NaN; NaN stays NaN (an RMSE of a NaN curve
    came out 0, a perfect fit)."""
    pos = x > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.where(x.isnan(), x, 0.0))


def _as_signal(x: object, name: str) -> torch.Tensor:
    """``x`` as a floating tensor (numpy arrays and nested lists of numbers are accepted)."""
    if isinstance(x, torch.Tensor):
        t = x
    else:
        try:
            t = torch.as_tensor(np.asarray(x, dtype=np.float64))
        except (TypeError, ValueError):
            raise PulseError(f"expected {name} as a tensor or array of numbers, got {type(x).__name__}") from None
    if not (t.is_floating_point() or t.is_complex()):
        t = t.to(torch.get_default_dtype())
    if t.is_complex():
        raise PulseError(f"expected real {name} signals, got {t.dtype}")
    if t.dim() == 0:
        raise PulseError(f"expected {name} as [..., T] samples, got a scalar")
    return t


def _check_pair(q: object, p: object, min_samples: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """``q`` and ``p`` as tensors on common time samples, at least ``min_samples`` of them, with broadcastable batch
    dimensions, or a :class:`PulseError` saying what was expected.

    An array or list is placed on the device of the other signal, when that one is a tensor."""
    q, p = _as_pair(q, p)
    if q.shape[-1] != p.shape[-1]:
        raise PulseError(
            f"expected q and p on common time samples (same last dimension), got shapes {tuple(q.shape)} "
            f"and {tuple(p.shape)}; resample first"
        )
    if q.shape[-1] < min_samples:
        least = "one sample per curve" if min_samples == 1 else f"{min_samples} time samples"
        raise PulseError(f"expected at least {least}, got {q.shape[-1]} (shape {tuple(q.shape)})")
    try:
        torch.broadcast_shapes(q.shape, p.shape)
    except RuntimeError:
        raise PulseError(
            f"expected q and p with broadcastable batch dimensions (e.g. [B, n_sensors, T] and [n_sensors, T]), "
            f"got shapes {tuple(q.shape)} and {tuple(p.shape)}"
        ) from None
    return q, p


def _as_pair(q: object, p: object) -> tuple[torch.Tensor, torch.Tensor]:
    """``q`` and ``p`` as floating tensors (:func:`_as_signal`) on one device: an array or list is placed on the
    device of the other, when that one is a tensor."""
    given_q, given_p = isinstance(q, torch.Tensor), isinstance(p, torch.Tensor)
    q, p = _as_signal(q, "q"), _as_signal(p, "p")
    if given_q and not given_p:
        p = p.to(q.device)
    elif given_p and not given_q:
        q = q.to(p.device)
    _check_device(q, p)
    return q, p


def _check_device(q: torch.Tensor, p: torch.Tensor) -> None:
    if q.device != p.device:  # torch's own message names neither argument
        raise PulseError(f"expected q and p on one device, got {q.device} and {p.device}; move one with .to()")


def check_step(dt: Any) -> float:
    """``dt`` as seconds: a finite number > 0 (a Python or numpy number, or a one-element tensor), else a
    :class:`PulseError`."""
    try:
        step = math.nan if isinstance(dt, bool | str) else float(dt)  # a bool or text is no step
    except (TypeError, ValueError, RuntimeError):
        step = math.nan
    if not (math.isfinite(step) and step > 0):
        raise PulseError(f"expected a finite sampling interval dt > 0 [s], got {dt!r}")
    return step


def _check_scale(value: object, name: str) -> float:
    """A factor on time or values before Frechet distances: a finite real number > 0, else a :class:`PulseError`
    naming ``name`` (0 dropped time or values from the distance, text was torch's index error)."""
    real = (
        float(value)
        if isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
        else math.nan
    )
    if not (math.isfinite(real) and real > 0):
        raise PulseError(f"{name}: expected a finite factor > 0 (1: unscaled SI), got {value!r}")
    return real


def _check_time(time: object, like: torch.Tensor) -> torch.Tensor:
    """Sample times ``[T]``/``[..., T]`` [s] as a tensor on the device of ``like``: finite and strictly increasing, of
    ``like``'s dtype or their own floating one where that is more precise (float64 times of float32 signals: rounded
    to float32 first, the 50 us steps of a clock at 1000 s became 0 or 61 us)."""
    try:
        t = time if isinstance(time, torch.Tensor) else torch.as_tensor(np.asarray(time))  # a list: float64
        t = t.to(like.device, torch.promote_types(t.dtype, like.dtype) if t.is_floating_point() else like.dtype)
    except (TypeError, ValueError, RuntimeError):
        raise PulseError(f"expected time as a tensor or array of sample times [s], got {type(time).__name__}") from None
    if t.dim() == 0:
        raise PulseError("expected time as [T] sample times [s], got a scalar")
    if t.shape[-1] != like.shape[-1]:
        raise PulseError(f"time has {t.shape[-1]} samples, the signals {like.shape[-1]}")
    try:
        fits = torch.broadcast_shapes(t.shape, like.shape) == like.shape
    except RuntimeError:
        fits = False
    if not fits:  # torch's own message names neither time nor the signals
        raise PulseError(
            f"expected time as [T] or with batch dimensions that broadcast to the signals' "
            f"{tuple(like.shape)}, got shape {tuple(t.shape)}"
        )
    if not bool(torch.isfinite(t).all()):
        raise PulseError("time has non-finite sample times")
    rows = t.reshape(-1, t.shape[-1])
    bad = (rows[:, 1:] <= rows[:, :-1]).nonzero()
    if bad.numel():
        r, i = (int(v) for v in bad[0])
        raise PulseError(
            f"expected strictly increasing sample times, got time[{i + 1}] = {float(rows[r, i + 1])!r} s "
            f"after time[{i}] = {float(rows[r, i])!r} s"
        )
    return t


def _steps(time: torch.Tensor | None, dt: float | None, like: torch.Tensor) -> torch.Tensor:
    """Interval lengths ``[..., T-1]`` from ``time [T]``/``[..., T]`` or a uniform ``dt``."""
    if (time is None) == (dt is None):
        raise PulseError("pass exactly one of time (sample times [s]) or dt (uniform step [s])")
    if time is None:
        return torch.full_like(like[..., 1:], check_step(dt))
    time = _check_time(time, like)
    return (time[..., 1:] - time[..., :-1]).to(like.dtype)  # the steps in the times' precision, then the signals'


def area_between(
    q: torch.Tensor,
    p: torch.Tensor,
    time: torch.Tensor | None = None,
    *,
    dt: float | None = None,
    method: Literal["exact", "trapezoid"] = "exact",
) -> torch.Tensor:
    """Area between two curves on common time samples (paper Eq. 8).

    Args:
        q: ``[..., T]`` estimate.
        p: ``[..., T]`` reference (broadcastable with ``q``).
        time: ``[T]`` or ``[..., T]`` sample times [s]; or give ``dt``.
        dt: uniform sampling interval [s].
        method: ``exact`` or ``trapezoid`` (module docstring).

    Returns:
        ``[...]`` area [signal unit * s].
    """
    q, p = _check_pair(q, p)
    d = q - p
    h = _steps(time, dt, d)
    d0, d1 = d[..., :-1], d[..., 1:]
    a0, a1 = d0.abs(), d1.abs()
    if method == "trapezoid":
        return (0.5 * (a0 + a1) * h).sum(-1)
    if method != "exact":
        raise PulseError(f"area method must be 'exact' or 'trapezoid', got {method!r}")
    cross = d0 * d1 < 0
    s = a0 + a1
    # a crossing splits the interval into triangles of bases h*a0/s and h*a1/s
    split = (d0 * d0 + d1 * d1) / torch.where(cross, s, torch.ones_like(s))
    return (0.5 * h * torch.where(cross, split, s)).sum(-1)


def rmse(q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Root mean square error over the common time samples (paper Eq. 11).

    Args:
        q: ``[..., T]`` estimate; p: ``[..., T]`` reference.

    Returns:
        ``[...]`` RMSE [signal unit].
    """
    q, p = _check_pair(q, p)
    return _safe_sqrt(((q - p) ** 2).mean(-1))


def _nonempty(values: torch.Tensor) -> torch.Tensor:
    """``values`` if it has a sample per curve, else a :class:`PulseError` (was torch's "cannot reshape tensor of 0
    elements" from the time check)."""
    if values.shape[-1] == 0:
        raise PulseError(f"expected at least one sample per curve, got 0 (values of shape {tuple(values.shape)})")
    return values


def curve_points(
    values: torch.Tensor,
    time: torch.Tensor | None = None,
    *,
    dt: float | None = None,
    time_scale: float = 1.0,
    value_scale: float = 1.0,
) -> torch.Tensor:
    """Points ``[..., T, 2]`` = ``(time_scale * t, value_scale * v)`` of a sampled curve ``values [..., T]``."""
    if (time is None) == (dt is None):
        raise PulseError("pass exactly one of time (sample times [s]) or dt (uniform step [s])")
    time_scale, value_scale = _check_scale(time_scale, "time_scale"), _check_scale(value_scale, "value_scale")
    values = _nonempty(_as_signal(values, "values"))
    if time is None:
        time = torch.arange(values.shape[-1], dtype=values.dtype, device=values.device) * check_step(dt)
    time = _check_time(time, values).to(values.dtype).expand(values.shape)
    return torch.stack([time * time_scale, values * value_scale], dim=-1)


def discrete_frechet_points(q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Discrete Frechet distance of point sequences, batched (paper Eq. 9, 10).

    The coupling distance ``c[i, j] = max(d(q_i, p_j), min(c[i-1, j], c[i-1, j-1], c[i, j-1]))``
    is evaluated iteratively one anti-diagonal ``i + j = k`` at a time: each diagonal depends
    only on the two before it, so the ``n + m - 1`` steps are vectorized over the batch and
    along the diagonal (``O(n m)`` work, no recursion, no loop over the batch).

    Args:
        q: ``[..., n, D]`` points of the estimate.
        p: ``[..., m, D]`` points of the reference; batch dimensions broadcast with ``q``'s.

    Returns:
        ``[...]`` distances (Euclidean, in the points' units).
    """
    q, p = _as_pair(q, p)  # integer points or arrays were torch's cast or type errors
    if q.ndim < 2 or p.ndim < 2 or q.shape[-1] != p.shape[-1]:
        raise PulseError(f"expected points [..., n, D] and [..., m, D], got {tuple(q.shape)} and {tuple(p.shape)}")
    n, m = q.shape[-2], p.shape[-2]
    if n < 1 or m < 1:
        raise PulseError(f"expected at least one point per curve, got n={n}, m={m}")
    batch = torch.broadcast_shapes(q.shape[:-2], p.shape[:-2])
    dtype = torch.promote_types(q.dtype, p.dtype)
    qb = q.to(dtype).expand(*batch, n, q.shape[-1]).reshape(-1, n, q.shape[-1])
    pb = p.to(dtype).expand(*batch, m, p.shape[-1]).reshape(-1, m, p.shape[-1])
    track = torch.is_grad_enabled() and (qb.requires_grad or pb.requires_grad)
    with torch.no_grad():
        value, arg = _frechet_dp(qb.detach(), pb.detach(), track)
    if not track:
        return value.reshape(batch)
    assert arg is not None  # _frechet_dp returns the bottleneck indices whenever track is set
    # The distance equals the length of one bottleneck pair (i*, j*); its gradient is the
    # (sub)gradient of the whole dynamic program, without keeping n + m graphs of it.
    rows = torch.arange(qb.shape[0], device=qb.device)
    gap = qb[rows, arg // m] - pb[rows, arg % m]
    # a NaN or infinite distance has no bottleneck pair (ties of infinite cells pick any, the padding's (0, 0) too):
    # it is the program's value, as without a gradient (a NaN curve came out 0, a perfect fit)
    return torch.where(value.isfinite(), _safe_sqrt((gap**2).sum(-1)), value).reshape(batch)


def _frechet_dp(q: torch.Tensor, p: torch.Tensor, track: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Anti-diagonal dynamic program on ``q [B, n, D]``, ``p [B, m, D]`` (no autograd).

    Memory: the ``[B, n, m]`` distance table plus ``O(B n)`` per diagonal. The table is
    read along anti-diagonals through a strided view (cell ``(i, k - i)`` sits at flat
    offset ``k + i (m - 1)``), and diagonals live in buffers padded with one leading
    ``+inf`` so that the three predecessors of every cell are plain slices.

    Returns the ``[B]`` distances and, if ``track``, the ``[B]`` flat index ``i * m + j``
    of the pair whose distance they equal.
    """
    bsz, n, dim = q.shape
    m = p.shape[1]
    dev, dtype = q.device, q.dtype
    sq = torch.zeros(bsz, n, m, dtype=dtype, device=dev)
    for c in range(dim):  # coordinate by coordinate: no [B, n, m, D] temporary
        sq += (q[:, :, c, None] - p[:, None, :, c]) ** 2
    dist = sq.sqrt_()
    n_diag = n + m - 1
    diag = dist.as_strided((bsz, n_diag, n), (n * m, 1, m - 1))  # diag[:, k, i] = dist[:, i, k - i] where valid
    k_idx = torch.arange(n_diag, device=dev)[:, None]
    i_idx = torch.arange(n, device=dev)[None, :]
    invalid = (k_idx - i_idx < 0) | (k_idx - i_idx >= m)  # [n + m - 1, n]
    own_arg = i_idx * m + (k_idx - i_idx).clamp(0, m - 1)
    prev2, prev1, cur = (torch.full((bsz, n + 1), math.inf, dtype=dtype, device=dev) for _ in range(3))
    prev1[:, 1] = dist[:, 0, 0]
    if track:
        arg2, arg1, argc = (torch.zeros(bsz, n + 1, dtype=torch.long, device=dev) for _ in range(3))
    for k in range(1, n_diag):
        up, left, corner = prev1[:, :-1], prev1[:, 1:], prev2[:, :-1]  # c[i-1, j], c[i, j-1], c[i-1, j-1]
        d = diag[:, k]
        best = torch.minimum(up, left)  # NaN propagates (the comparisons below skip it)
        torch.minimum(best, corner, out=best)
        if track:
            left_best = left <= corner
            best_arg = torch.where(left_best, arg1[:, 1:], arg2[:, :-1])
            up_best = up < torch.where(left_best, left, corner)
            best_arg = torch.where(up_best, arg1[:, :-1], best_arg)
            torch.where(d >= best, own_arg[k], best_arg, out=argc[:, 1:])
            arg2, arg1, argc = arg1, argc, arg2
        torch.maximum(d, best, out=cur[:, 1:])
        cur[:, 1:].masked_fill_(invalid[k], math.inf)
        prev2, prev1, cur = prev1, cur, prev2
    return prev1[:, n].clone(), (arg1[:, n].clone() if track else None)


def discrete_frechet(
    q: torch.Tensor,
    p: torch.Tensor,
    time_q: torch.Tensor | None = None,
    time_p: torch.Tensor | None = None,
    *,
    dt: float | None = None,
    time_scale: float = 1.0,
    value_scale: float = 1.0,
) -> torch.Tensor:
    """Discrete Frechet distance of sampled curves ``(t, q(t))`` and ``(s, p(s))``.

    Args:
        q: ``[..., n]`` estimate values.
        p: ``[..., m]`` reference values (batch dimensions broadcast).
        time_q: ``[n]``/``[..., n]`` times [s] of ``q``; time_p likewise (default: ``time_q``).
        dt: uniform step [s] for both curves instead of times.
        time_scale: factor on times before distances (1: seconds, as in the paper).
        value_scale: factor on values before distances.

    Returns:
        ``[...]`` distances.
    """
    if dt is not None:
        if time_q is not None or time_p is not None:
            raise PulseError("pass exactly one of time (time_q, time_p: sample times [s]) or dt (uniform step [s])")
        pq = curve_points(q, dt=dt, time_scale=time_scale, value_scale=value_scale)
        pp = curve_points(p, dt=dt, time_scale=time_scale, value_scale=value_scale)
    else:
        if time_q is None:
            raise PulseError("pass time_q (and time_p if it differs) or dt")
        if time_p is None:
            n_q, n_p = _as_signal(q, "q").shape[-1], _as_signal(p, "p").shape[-1]
            if n_p != n_q:  # was "time has n samples, the signals m", naming neither
                raise PulseError(f"q has {n_q} samples, p {n_p}: pass time_p (p's sample times [s]; it defaults to "
                                 "time_q) for curves of two lengths")  # fmt: skip
            time_p = time_q
        # the distance is that of the curves on a clock from their earliest sample: points are built in the signals'
        # dtype, and float32 times 1000 s on are multiples of 61 us (samples 30 us apart were 61 us apart)
        q, p = (_nonempty(c) for c in _as_pair(q, p))
        time_q, time_p = _check_time(time_q, q), _check_time(time_p, p)
        origin = torch.minimum(time_q.min(), time_p.min())
        pq = curve_points(q, time_q - origin, time_scale=time_scale, value_scale=value_scale)
        pp = curve_points(p, time_p - origin, time_scale=time_scale, value_scale=value_scale)
    return discrete_frechet_points(pq, pp)


def discrete_frechet_ragged(qs: Sequence[torch.Tensor], ps: Sequence[torch.Tensor]) -> torch.Tensor:
    """Discrete Frechet distances of pairs of point sequences of any lengths ``n_b``, ``m_b``.

    Each curve is padded to the longest by repeating its last point, which leaves its
    discrete Frechet distance unchanged (a repeated point can always be coupled with the
    partner's current point at no extra cost), and the batch is computed at once.

    Args:
        qs: ``B`` tensors ``[n_b, D]``; ps: ``B`` tensors ``[m_b, D]`` (arrays accepted, as by the other metrics).

    Returns:
        ``[B]`` distances.
    """
    if len(qs) != len(ps) or not qs:
        raise PulseError(f"expected two equally long, non-empty lists of curves, got {len(qs)} and {len(ps)}")
    dims: list[int] = []

    def curve(c: object, key: str, n: str) -> torch.Tensor:  # torch's cat and stack errors named no curve
        t = _as_signal(c, key)
        if t.dim() != 2 or t.shape[0] < 1 or (dims and t.shape[1] != dims[0]):
            d = f"{dims[0]}" if dims else "D"
            like = " (D as qs[0]'s)" if dims else ""
            raise PulseError(f"expected {key} as [{n}, {d}] points{like}, at least one, got shape {tuple(t.shape)}")
        dims.append(t.shape[1])
        return t

    qs = [curve(c, f"qs[{b}]", "n") for b, c in enumerate(qs)]
    ps = [curve(c, f"ps[{b}]", "m") for b, c in enumerate(ps)]

    def stack(curves: Sequence[torch.Tensor]) -> torch.Tensor:
        size = max(c.shape[0] for c in curves)
        return torch.stack([torch.cat([c, c[-1:].expand(size - c.shape[0], -1)]) for c in curves])

    return discrete_frechet_points(stack(qs), stack(ps))


# ------------------------------------------------------------------ compiled Frechet rows
_DFD_BLOCK = 32  # rows per kernel block: the inner loop runs across rows, so it vectorizes


@numba.njit(cache=True, parallel=True)
def _dfd_rows(q: np.ndarray, p: np.ndarray, dt: float, ts: float, vs: float) -> np.ndarray:  # pragma: no cover
    """Discrete Frechet distances of ``R`` pairs of curves ``(i dt ts, q[r, i] vs)``, ``(j dt ts, p[r, j] vs)``.

    Squared distances are propagated (max/min commute with the final square root); each block
    of rows keeps two ``[m, block]`` rows of the coupling table and loops innermost over rows.
    """
    n_rows, n = q.shape
    m = p.shape[1]
    out = np.empty(n_rows)
    n_blocks = (n_rows + _DFD_BLOCK - 1) // _DFD_BLOCK
    for b in numba.prange(n_blocks):
        r0 = b * _DFD_BLOCK
        w = min(n_rows, r0 + _DFD_BLOCK) - r0
        qt = np.ascontiguousarray(q[r0 : r0 + w].T * vs)  # [n, w]
        pt = np.ascontiguousarray(p[r0 : r0 + w].T * vs)  # [m, w]
        prev = np.empty((m, w))
        cur = np.empty((m, w))
        for i in range(n):
            for j in range(m):
                tt = ((i - j) * dt * ts) ** 2
                if i == 0 and j == 0:
                    for k in range(w):
                        dv = qt[i, k] - pt[j, k]
                        cur[j, k] = tt + dv * dv
                elif i == 0:
                    for k in range(w):
                        dv = qt[i, k] - pt[j, k]
                        cur[j, k] = max(cur[j - 1, k], tt + dv * dv)
                elif j == 0:
                    for k in range(w):
                        dv = qt[i, k] - pt[j, k]
                        cur[j, k] = max(prev[j, k], tt + dv * dv)
                else:
                    for k in range(w):
                        dv = qt[i, k] - pt[j, k]
                        cur[j, k] = max(min(min(prev[j, k], prev[j - 1, k]), cur[j - 1, k]), tt + dv * dv)
            prev, cur = cur, prev
        for k in range(w):
            out[r0 + k] = math.sqrt(prev[m - 1, k])
    return out


def discrete_frechet_uniform_numba(
    q: torch.Tensor, p: torch.Tensor, dt: float, time_scale: float = 1.0, value_scale: float = 1.0
) -> torch.Tensor:
    """:func:`discrete_frechet` of curves on the common grid ``i * dt``, no-grad, in a compiled kernel.

    The same recursion row by row with ``O(T)`` memory instead of the ``[..., T, T]`` table
    (at ``B = 256`` and 3 sensors: milliseconds and kilobytes instead of seconds and 0.5 GB).

    Args:
        q, p: ``[..., T]`` values (broadcast), float64 on the CPU.
        dt: sample step [s].
        time_scale, value_scale: as in :func:`discrete_frechet`.

    Returns:
        ``[...]`` float64 distances.
    """
    q, p = _check_pair(q, p, min_samples=1)  # were torch's broadcasting, reshaping and attribute errors
    q, p = torch.broadcast_tensors(q.detach().double().cpu(), p.detach().double().cpu())
    dt = check_step(dt)  # dt = 0 or nan gave a number
    time_scale, value_scale = _check_scale(time_scale, "time_scale"), _check_scale(value_scale, "value_scale")
    shape = q.shape[:-1]
    qa = np.ascontiguousarray(q.reshape(-1, q.shape[-1]).numpy())
    pa = np.ascontiguousarray(p.reshape(-1, p.shape[-1]).numpy())
    rows = _dfd_rows(qa, pa, float(dt), float(time_scale), float(value_scale))
    # the kernel's min/max skip NaN, torch's propagate it: NaN where a sample is NaN or the two curves are infinite
    # with one sign (their distance inf - inf; a distance of 0 came out), on the values as the kernel scales them
    with np.errstate(over="ignore", invalid="ignore"):
        qs, ps = qa * float(value_scale), pa * float(value_scale)
    nan = np.isnan(qs).any(axis=1) | np.isnan(ps).any(axis=1)
    for side in (np.isposinf, np.isneginf):
        nan |= side(qs).any(axis=1) & side(ps).any(axis=1)
    rows[nan] = np.nan
    return torch.from_numpy(rows).reshape(shape)


def compute_metrics(
    q: torch.Tensor,
    p: torch.Tensor,
    time: torch.Tensor | None = None,
    *,
    dt: float | None = None,
    config: MetricsConfig | None = None,
    backend: Literal["torch", "numba"] = "torch",
) -> Metrics:
    """All three metrics of ``q`` against ``p`` on common samples.

    Args:
        q: ``[..., T]`` estimate, e.g. ``[B, n_sensors, T]`` velocities [m/s].
        p: ``[..., T]`` reference (broadcastable, e.g. ``[n_sensors, T]``).
        time: ``[T]`` sample times [s]; or ``dt``.
        dt: uniform sampling interval [s].
        config: area method and Frechet scaling (default: exact area, unscaled SI).
        backend: ``torch`` (differentiable, any device) or ``numba`` (the Frechet distance in a
            compiled kernel: no gradient, CPU, uniform ``dt``; same numbers to round-off).

    Returns:
        :class:`Metrics` of ``[...]`` tensors.
    """
    if backend not in ("torch", "numba"):
        raise PulseError(f"metrics backend must be 'torch' or 'numba', got {backend!r}")
    cfg = config or MetricsConfig()
    q, p = _check_pair(q, p)  # before broadcasting: torch's own message would not say what was expected
    q, p = torch.broadcast_tensors(q, p)
    area = area_between(q, p, time, dt=dt, method=cfg.area_method)
    if backend == "numba":
        if dt is None:
            raise PulseError("the numba metrics backend needs a uniform step dt")
        dfd = discrete_frechet_uniform_numba(q, p, dt, cfg.dfd_time_scale, cfg.dfd_value_scale)
        dfd = dfd.to(dtype=area.dtype, device=area.device)  # the promoted dtype and the device of the other two
        return Metrics(area=area, dfd=dfd, rmse=rmse(q, p))
    if time is None:
        dfd = discrete_frechet(q, p, dt=dt, time_scale=cfg.dfd_time_scale, value_scale=cfg.dfd_value_scale)
    else:
        dfd = discrete_frechet(q, p, time, time_scale=cfg.dfd_time_scale, value_scale=cfg.dfd_value_scale)
    return Metrics(area=area, dfd=dfd, rmse=rmse(q, p))
