"""Metrics against plain, independent references (python loops / numpy), batched torch, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import similaritymeasures
import torch

from marlcrash.errors import PulseError
from marlcrash.metrics import (
    MetricsConfig,
    area_between,
    compute_metrics,
    curve_points,
    discrete_frechet,
    discrete_frechet_points,
    discrete_frechet_ragged,
    discrete_frechet_uniform_numba,
    rmse,
)

N_PAIRS = 100


def ref_frechet(P: np.ndarray, Q: np.ndarray) -> float:
    """Eiter and Mannila's discrete Frechet distance, the classic table filled with python loops."""
    n, m = len(P), len(Q)
    ca = np.full((n, m), -1.0)
    for i in range(n):
        for j in range(m):
            d = math.dist(P[i], Q[j])
            if i == 0 and j == 0:
                ca[i, j] = d
            elif i == 0:
                ca[i, j] = max(ca[i, j - 1], d)
            elif j == 0:
                ca[i, j] = max(ca[i - 1, j], d)
            else:
                ca[i, j] = max(min(ca[i - 1, j], ca[i - 1, j - 1], ca[i, j - 1]), d)
    return float(ca[n - 1, m - 1])


def ref_area_exact(t: np.ndarray, q: np.ndarray, p: np.ndarray) -> float:
    """Integral of |q - p| for piecewise-linear curves, splitting sign-changing intervals at the root."""
    total = 0.0
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        d0, d1 = q[k] - p[k], q[k + 1] - p[k + 1]
        if d0 * d1 >= 0:
            total += h * (abs(d0) + abs(d1)) / 2
        else:
            tc = h * d0 / (d0 - d1)  # root of the linear difference
            total += abs(d0) * tc / 2 + abs(d1) * (h - tc) / 2
    return total


def random_curve(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Velocity-like curve: times over ~0.1 s, values of a few m/s."""
    t = np.cumsum(rng.uniform(1e-4, 2e-3, size=n))
    v = 10 * np.cos(np.linspace(0, 2, n)) + rng.normal(scale=0.5, size=n)
    return t, v


def test_frechet_equals_eiter_mannila_on_100_random_pairs_of_different_lengths():
    rng = np.random.default_rng(0)
    qs, ps, refs = [], [], []
    for _ in range(N_PAIRS):
        n, m = rng.integers(1, 60, size=2)
        tq, vq = random_curve(rng, n)
        tp, vp = random_curve(rng, m)
        ref = ref_frechet(np.c_[tq, vq], np.c_[tp, vp])
        got = discrete_frechet(torch.tensor(vq), torch.tensor(vp), torch.tensor(tq), torch.tensor(tp))
        assert got.dtype == torch.float64
        assert abs(got.item() - ref) <= 1e-9 * max(1.0, ref)
        # a second reference where conventions match (Euclidean points, same recursion)
        assert abs(similaritymeasures.frechet_dist(np.c_[tq, vq], np.c_[tp, vp]) - ref) <= 1e-9 * max(1.0, ref)
        qs.append(torch.tensor(np.c_[tq, vq]))
        ps.append(torch.tensor(np.c_[tp, vp]))
        refs.append(ref)
    # all 100 ragged pairs in one batch
    np.testing.assert_allclose(discrete_frechet_ragged(qs, ps).numpy(), refs, rtol=1e-12, atol=1e-12)


def test_frechet_batched_over_sensors_with_scaling():
    rng = np.random.default_rng(1)
    B, K, n, m = 3, 2, 25, 40
    q = torch.tensor(rng.normal(size=(B, K, n)))
    p = torch.tensor(rng.normal(size=(K, m)))  # reference broadcast over the batch
    tq, tp = torch.linspace(0, 0.1, n, dtype=torch.float64), torch.linspace(0, 0.1, m, dtype=torch.float64)
    got = discrete_frechet(q, p, tq, tp, time_scale=1000.0, value_scale=2.0)
    assert got.shape == (B, K)
    for b in range(B):
        for k in range(K):
            ref = ref_frechet(np.c_[tq * 1000, 2 * q[b, k]], np.c_[tp * 1000, 2 * p[k]])
            assert got[b, k].item() == pytest.approx(ref, abs=1e-12)


def test_frechet_properties():
    t = torch.linspace(0, 0.15, 301, dtype=torch.float64)
    v = 11.1 * torch.cos(t * 20)
    assert discrete_frechet(v, v, t).item() == 0.0
    w = v + 0.3
    assert discrete_frechet(v, w, t).item() == pytest.approx(0.3, abs=1e-12)  # a constant offset is the leash
    a, b = torch.randn(50, dtype=torch.float64), torch.randn(70, dtype=torch.float64)
    ta, tb = torch.linspace(0, 1, 50, dtype=torch.float64), torch.linspace(0, 1, 70, dtype=torch.float64)
    assert discrete_frechet(a, b, ta, tb).item() == pytest.approx(discrete_frechet(b, a, tb, ta).item(), abs=1e-15)
    pts = curve_points(a, ta)
    assert pts.shape == (50, 2)
    # duplicating points leaves the distance unchanged (the basis of the ragged padding)
    dup = torch.cat([pts[:10], pts[9:10], pts[10:]])
    pb = curve_points(b, tb)
    assert discrete_frechet_points(dup, pb).item() == discrete_frechet_points(pts, pb).item()


def test_area_equals_reference_on_100_random_pairs_of_different_lengths():
    rng = np.random.default_rng(2)
    for _ in range(N_PAIRS):
        n = int(rng.integers(2, 120))
        t, q = random_curve(rng, n)
        p = q + rng.normal(scale=0.3, size=n)  # crossings are frequent
        tt, qt, pt = (torch.tensor(x) for x in (t, q, p))
        exact = area_between(qt, pt, tt).item()
        assert abs(exact - ref_area_exact(t, q, p)) <= 1e-9 * max(1.0, exact)
        trap = area_between(qt, pt, tt, method="trapezoid").item()
        assert abs(trap - np.trapezoid(np.abs(q - p), t)) <= 1e-9 * max(1.0, trap)
        assert exact <= trap + 1e-15  # the trapezoid rule over-estimates crossing intervals
        assert rmse(qt, pt).item() == pytest.approx(np.sqrt(np.mean((q - p) ** 2)), abs=1e-12)


def test_area_uniform_dt_and_batch():
    rng = np.random.default_rng(3)
    q, p = rng.normal(size=(4, 3, 50)), rng.normal(size=(4, 3, 50))
    dt = 5e-4
    got = area_between(torch.tensor(q), torch.tensor(p), dt=dt)
    t = np.arange(50) * dt
    ref = np.array([[ref_area_exact(t, q[b, k], p[b, k]) for k in range(3)] for b in range(4)])
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-12)


def test_compute_metrics_shapes_and_config():
    rng = np.random.default_rng(4)
    q = torch.tensor(rng.normal(size=(5, 3, 30)))
    p = torch.tensor(rng.normal(size=(3, 30)))
    m = compute_metrics(q, p, dt=5e-4)
    assert all(x.shape == (5, 3) and x.dtype == torch.float64 for x in m)
    m2 = compute_metrics(q, p, dt=5e-4, config=MetricsConfig("trapezoid", 1000.0, 1.0))
    assert (m2.area >= m.area).all() and (m2.dfd >= m.dfd).all()
    t = torch.arange(30, dtype=torch.float64) * 5e-4
    m3 = compute_metrics(q, p, t)
    for a, b in zip(m, m3, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)


def test_gradients_area_rmse_and_frechet():
    rng = np.random.default_rng(5)
    p = torch.tensor(rng.normal(size=(2, 12)))
    t = torch.tensor(np.cumsum(rng.uniform(0.01, 0.02, size=12)))
    q = torch.tensor(rng.normal(size=(2, 12)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: area_between(x, p, t), (q,))
    assert torch.autograd.gradcheck(lambda x: rmse(x, p), (q,))
    assert torch.autograd.gradcheck(lambda x: discrete_frechet(x, p, t), (q,))
    # at a perfect fit the gradients are finite (zero), not NaN
    z = p.clone().requires_grad_(True)
    (area_between(z, p, t) + rmse(z, p) + discrete_frechet(z, p, t)).sum().backward()
    assert torch.isfinite(z.grad).all()


def test_frechet_gradient_matches_autograd_through_the_dynamic_program():
    """The bottleneck-pair gradient equals autograd through a differentiable max/min recursion."""
    rng = np.random.default_rng(6)
    q = torch.tensor(rng.normal(size=(9, 2)), requires_grad=True)
    p = torch.tensor(rng.normal(size=(7, 2)))
    d = torch.cdist(q, p, compute_mode="donot_use_mm_for_euclid_dist")
    ca = [[None] * 7 for _ in range(9)]
    for i in range(9):
        for j in range(7):
            prev = [ca[a][b] for a, b in ((i - 1, j), (i - 1, j - 1), (i, j - 1)) if a >= 0 and b >= 0]
            ca[i][j] = d[i, j] if not prev else torch.maximum(d[i, j], torch.stack(prev).min())
    (g_ref,) = torch.autograd.grad(ca[8][6], q)
    (g,) = torch.autograd.grad(discrete_frechet_points(q, p), q)
    torch.testing.assert_close(g, g_ref)


def test_metric_input_errors():
    with pytest.raises(PulseError, match="common time samples"):
        rmse(torch.zeros(3, 10), torch.zeros(3, 11))
    with pytest.raises(PulseError, match="exactly one of time"):
        area_between(torch.zeros(10), torch.zeros(10))
    with pytest.raises(PulseError, match="points"):
        discrete_frechet_points(torch.zeros(10), torch.zeros(10))
    # not torch's broadcasting error from inside: the shapes and what was expected
    with pytest.raises(PulseError, match=r"common time samples.*\(2, 3, 301\) and \(3, 300\)"):
        compute_metrics(torch.zeros(2, 3, 301), torch.zeros(3, 300), dt=5e-4)
    for f in (compute_metrics, area_between):
        with pytest.raises(PulseError, match=r"broadcastable batch dimensions.*\(2, 3, 301\) and \(2, 4, 301\)"):
            f(torch.zeros(2, 3, 301), torch.zeros(2, 4, 301), dt=5e-4)


@pytest.mark.parametrize("dt", [0.0, -5e-4, float("nan"), float("inf"), "fast", "5e-4", True, torch.ones(2)])
def test_a_step_that_is_not_a_positive_number_of_seconds_is_refused(dt):
    # a zero or negative step gave zero or negative areas without a word
    q, p = torch.rand(2, 30, dtype=torch.float64), torch.rand(2, 30, dtype=torch.float64)
    with pytest.raises(PulseError, match="dt"):
        compute_metrics(q, p, dt=dt)
    with pytest.raises(PulseError, match="dt"):
        discrete_frechet(q, p, dt=dt)


def test_sample_times_must_increase():
    q, p = torch.rand(2, 30, dtype=torch.float64), torch.rand(2, 30, dtype=torch.float64)
    t = torch.linspace(0.0, 0.015, 30, dtype=torch.float64)
    with pytest.raises(
        PulseError, match=r"strictly increasing sample times, got time\[1\] = 0.01448.* after time\[0\] = 0.015"
    ):
        compute_metrics(q, p, t.flip(0))
    repeated = t.clone()
    repeated[7] = repeated[6]
    with pytest.raises(PulseError, match=r"time\[7\]"):
        area_between(q, p, repeated)
    with pytest.raises(PulseError, match="non-finite"):
        compute_metrics(q, p, torch.where(t > 0.01, torch.nan, t))


def test_metrics_accept_arrays_and_name_what_they_cannot_read():
    q, p = np.random.default_rng(0).random((2, 3, 40))
    got = compute_metrics(q, p, dt=5e-4)
    ref = compute_metrics(torch.from_numpy(q), torch.from_numpy(p), dt=5e-4)
    for a, b in zip(got, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    # a string or a scalar was an AttributeError or IndexError from inside torch
    with pytest.raises(PulseError, match="expected q as a tensor or array of numbers, got str"):
        compute_metrics("velocity.csv", p, dt=5e-4)
    with pytest.raises(PulseError, match=r"expected p as .* got a scalar"):
        rmse(q, 1.0)


def test_numba_backend_equals_torch_backend():
    """The compiled row-by-row Frechet kernel gives the DP table's numbers (scaled time axis too)."""
    g = torch.Generator().manual_seed(0)
    q = torch.randn(4, 3, 60, generator=g, dtype=torch.float64).cumsum(-1)
    p = torch.randn(3, 60, generator=g, dtype=torch.float64).cumsum(-1)  # broadcast over the batch
    for cfg in (MetricsConfig(), MetricsConfig(dfd_time_scale=300.0, dfd_value_scale=0.5)):
        fast = compute_metrics(q, p, dt=5e-4, config=cfg, backend="numba")
        slow = compute_metrics(q, p, dt=5e-4, config=cfg)
        for a, b in zip(fast, slow, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    with pytest.raises(PulseError, match="uniform step"):
        compute_metrics(q, p, torch.linspace(0, 0.03, 60, dtype=torch.float64), backend="numba")
    with pytest.raises(PulseError, match="backend must be 'torch' or 'numba', got 'cuda'"):  # not torch silently
        compute_metrics(q, p, dt=5e-4, backend="cuda")


def test_a_nan_curve_gets_nan_metrics_in_both_backends_and_fails_the_episode():
    """A NaN estimate scored an RMSE of 0 (a perfect fit), the compiled Frechet kernel skipped the NaN (1.0 where
    torch gave NaN), and a NaN state never ended an episode."""
    from marlcrash.reward import TerminationConfig, termination

    t = torch.arange(40, dtype=torch.float64) * 5e-4
    q, p = torch.sin(60 * t)[None].repeat(2, 1), torch.cos(60 * t)[None].repeat(2, 1)
    q[1, 7] = float("nan")
    for backend in ("torch", "numba"):
        m = compute_metrics(q, p, dt=5e-4, backend=backend)
        for name, v in zip(("area", "dfd", "rmse"), m, strict=True):
            assert math.isfinite(float(v[0])) and math.isnan(float(v[1])), (backend, name)
    assert math.isnan(float(rmse(q[1], p[1])))
    cfg = TerminationConfig(max_iterations=10, success_area=1e-3, failure_area=None)
    m = compute_metrics(q, p, dt=5e-4)
    end = termination(type(m)(*(v[:, None] for v in m)), cfg, 1)
    assert end.failure.tolist() == [False, True] and end.success.tolist() == [False, False]


def test_numba_backend_returns_the_dtype_of_the_other_metrics():
    """A float32 estimate against a float64 reference: area and RMSE come out float64 (type promotion, as every
    metric of the torch backend), but the compiled Frechet distance was cast to the estimate's float32."""
    g = torch.Generator().manual_seed(1)
    q = torch.randn(2, 3, 30, generator=g).cumsum(-1)  # float32
    p = torch.randn(3, 30, generator=g, dtype=torch.float64).cumsum(-1)
    slow = compute_metrics(q, p, dt=5e-4)
    fast = compute_metrics(q, p, dt=5e-4, backend="numba")
    assert {t.dtype for t in slow} == {t.dtype for t in fast} == {torch.float64}
    torch.testing.assert_close(fast.dfd, slow.dfd, rtol=1e-6, atol=1e-6)


def test_signals_on_two_devices_are_refused_by_name():
    q = torch.zeros(2, 3, 10, device="meta", dtype=torch.float64)
    p = torch.zeros(3, 10, dtype=torch.float64)
    for f in (compute_metrics, area_between):
        with pytest.raises(PulseError, match=r"expected q and p on one device, got meta and cpu"):
            f(q, p, dt=5e-4)
    with pytest.raises(PulseError, match=r"one device"):
        rmse(q, p)
    with pytest.raises(PulseError, match=r"one device"):
        discrete_frechet_points(q[..., None], p[..., None])
    # an array given with a tensor goes where the tensor is
    assert area_between(q, p.numpy(), dt=5e-4).device.type == rmse(p.tolist(), q).device.type == "meta"


def test_sample_times_whose_batch_does_not_fit_the_signals_are_refused_by_name():
    """Times ``[B, T]`` for signals ``[B, K, T]`` (a batch axis in the wrong place) failed deep in torch."""
    q = torch.rand(2, 3, 5, dtype=torch.float64)
    p = torch.rand(3, 5, dtype=torch.float64)
    t = torch.arange(10, dtype=torch.float64).reshape(2, 5) * 1e-3
    for f in (area_between, compute_metrics, discrete_frechet):
        with pytest.raises(PulseError, match=r"expected time as \[T\] or with batch dimensions .* got shape \(2, 5\)"):
            f(q, p, t)
    assert area_between(q, p, t[:, None]).shape == (2, 3)  # [B, 1, T] broadcasts over the sensors


def test_frechet_refuses_both_sample_times_and_a_step():
    """``dt`` silently replaced given sample times (area_between and curve_points refuse the pair)."""
    q, p = torch.rand(5, dtype=torch.float64), torch.rand(5, dtype=torch.float64)
    t = torch.tensor([0.0, 0.1, 0.5, 0.6, 2.0], dtype=torch.float64)
    with pytest.raises(PulseError, match="exactly one of time"):
        discrete_frechet(q, p, t, dt=0.1)
    with pytest.raises(PulseError, match="exactly one of time"):
        discrete_frechet(q, p, time_p=t, dt=0.1)


def test_an_empty_curve_is_refused_by_name_and_a_one_point_curve_has_its_distance():
    """A curve of no samples raised torch's "cannot reshape tensor of 0 elements" from inside the time check; one
    sample is a curve of one point, whose Frechet distance is the longest distance to the other curve's points."""
    for q, p in ((torch.zeros(0), torch.zeros(3)), (torch.zeros(3), torch.zeros(2, 0))):
        with pytest.raises(PulseError, match=r"expected at least one sample per curve, got 0"):
            discrete_frechet(q, p, dt=1e-3)
    with pytest.raises(PulseError, match=r"expected at least one sample per curve, got 0"):
        discrete_frechet(torch.zeros(0), torch.zeros(0), torch.zeros(0))
    with pytest.raises(PulseError, match=r"expected at least one sample per curve, got 0"):
        curve_points(torch.zeros(4, 0), dt=1e-3)
    got = discrete_frechet(torch.tensor([3.0], dtype=torch.float64), torch.tensor([0.0, 1.0, 5.0]), dt=1.0)
    assert float(got) == pytest.approx(max(3.0, math.hypot(1.0, 2.0), math.hypot(2.0, 2.0)), abs=1e-12)


def test_the_compiled_frechet_kernel_names_what_it_cannot_take():
    """:func:`discrete_frechet_uniform_numba` took no input check: curves of two lengths and empty ones raised torch's
    broadcasting or reshaping errors, an array an AttributeError, and dt = 0 or nan gave a number (the distance of the
    values alone, or nan) where :func:`discrete_frechet` refuses the step."""
    from marlcrash.metrics import discrete_frechet_uniform_numba as dfd

    with pytest.raises(PulseError, match=r"common time samples.*\(50,\) and \(40,\)"):
        dfd(torch.zeros(50), torch.zeros(40), 1e-3)
    with pytest.raises(PulseError, match=r"at least one sample per curve, got 0"):
        dfd(torch.zeros(3, 0), torch.zeros(3, 0), 1e-3)
    for dt in (0.0, float("nan"), -1e-3):
        with pytest.raises(PulseError, match=r"sampling interval dt > 0"):
            dfd(torch.zeros(5), torch.ones(5), dt)
    q, p = np.random.default_rng(1).random((2, 3, 20))
    torch.testing.assert_close(dfd(q, p, 1e-3), discrete_frechet(q, p, dt=1e-3), rtol=1e-12, atol=1e-12)


def test_point_sequences_are_read_as_numbers_and_malformed_ones_refused_by_name():
    """:func:`discrete_frechet_points` raised torch's "result type Float can't be cast to ... Long" for integer points
    and a TypeError for numpy arrays; :func:`discrete_frechet_ragged` raised torch's cat/stack errors for a curve of
    values ``[n]`` or curves of other dimensions."""
    ints = discrete_frechet_points(torch.tensor([[0, 1], [1, 2]]), torch.tensor([[0, 1], [1, 5]]))
    assert float(ints) == 3.0
    arrays = discrete_frechet_points(np.array([[0.0, 1.0], [1.0, 2.0]]), np.array([[0.0, 1.0], [1.0, 5.0]]))
    assert float(arrays) == 3.0
    with pytest.raises(PulseError, match=r"expected qs\[0\] as \[n, D\] points, at least one, got shape \(3,\)"):
        discrete_frechet_ragged([torch.zeros(3)], [torch.zeros(4, 2)])
    with pytest.raises(PulseError, match=r"expected ps\[1\] as \[m, 2\] points .*got shape \(4, 3\)"):
        discrete_frechet_ragged([torch.zeros(3, 2), torch.zeros(2, 2)], [torch.zeros(4, 2), torch.zeros(4, 3)])
    got = discrete_frechet_ragged([np.zeros((3, 2)), [[0, 0]]], [np.zeros((4, 2)), [[0, 2], [0, 0]]])
    torch.testing.assert_close(got, torch.tensor([0.0, 2.0], dtype=torch.float64))


def test_curves_of_two_lengths_without_time_p_are_told_to_pass_it():
    """``time_p`` defaults to ``time_q``: for curves of two lengths the error was "time has 50 samples, the signals
    40", naming neither the curve nor the option."""
    t = torch.arange(50, dtype=torch.float64) * 1e-3
    with pytest.raises(PulseError, match=r"q has 50 samples, p 40: pass time_p"):
        discrete_frechet(torch.zeros(50), torch.zeros(40), t)
    tp = t[:40] * 50 / 40
    want = ref_frechet(np.stack([t.numpy(), np.zeros(50)], 1), np.stack([tp.numpy(), np.zeros(40)], 1))
    got = discrete_frechet(torch.zeros(50, dtype=torch.float64), torch.zeros(40, dtype=torch.float64), t, tp)
    assert float(got) == pytest.approx(want, rel=1e-12)


def test_area_of_float32_signals_takes_its_widths_from_float64_times_unrounded():
    """Float32 signals on a float64 clock (a 20 kHz record stamped from 1000 s): the times were rounded to float32
    before their steps were taken, so the widths were multiples of float32's 61 us there (0 or 61 us for 50 us steps)
    and the area was refused as of non-increasing times. The widths are the float64 steps, the area float32 as the
    signals."""
    time = 1000.0 + torch.arange(601, dtype=torch.float64) * 5e-5
    q = torch.sin(torch.linspace(0.0, 20.0, 601))  # float32
    p = torch.zeros(601)
    want = area_between(q.double(), p.double(), time)
    for t in (time, time.numpy(), time.tolist()):
        got = area_between(q, p, t)
        assert got.dtype == torch.float32
        torch.testing.assert_close(got.double(), want, rtol=1e-6, atol=0.0)
        trap = area_between(q, p, t, method="trapezoid")
        torch.testing.assert_close(trap.double(), area_between(q.double(), p.double(), time, method="trapezoid"),
                                   rtol=1e-6, atol=0.0)  # fmt: skip


def test_frechet_of_float32_signals_on_a_late_float64_clock_is_that_of_the_clock_from_its_start():
    """Float32 signals stamped on a float64 clock far from 0 (a 20 kHz record from 1000 s, p's samples 30 us after q's):
    the points were built in float32, whose times at 1000 s are multiples of 61 us, so the leash between samples 30 us
    apart came out 61 us (time_scale 1000: 0.061 ms for 0.03). The distance is invariant under a shift of both clocks;
    the points are built from the earliest sample time of both curves."""
    rng = np.random.default_rng(7)
    tq = np.arange(120) * 5e-5
    tp = 3e-5 + np.arange(90) * 6.7e-5
    q = np.cumsum(rng.normal(size=120)) * 1e-3
    p = np.cumsum(rng.normal(size=90)) * 1e-3
    want = ref_frechet(np.c_[tq * 1000, q.astype(np.float32)], np.c_[tp * 1000, p.astype(np.float32)])
    for t0 in (0.0, 1000.0, -1000.0):
        got = discrete_frechet(torch.tensor(q, dtype=torch.float32), torch.tensor(p, dtype=torch.float32),
                               torch.tensor(t0 + tq), torch.tensor(t0 + tp), time_scale=1000.0)  # fmt: skip
        assert got.dtype == torch.float32
        assert float(got) == pytest.approx(want, rel=1e-5), t0
    # one clock for both (compute_metrics): coupling neighbouring samples measures their 50 us, not 0 or 61 us
    t = 1000.0 + torch.arange(120, dtype=torch.float64) * 5e-5
    qs = torch.tensor(q, dtype=torch.float32)
    ps = torch.roll(qs, 3)
    want = ref_frechet(np.c_[tq * 1000, qs.numpy()], np.c_[tq * 1000, ps.numpy()])
    got = compute_metrics(qs, ps, t, config=MetricsConfig(dfd_time_scale=1000.0)).dfd
    assert float(got) == pytest.approx(want, rel=1e-5)


def test_a_non_finite_curve_gets_the_same_frechet_distance_with_and_without_a_gradient():
    """With a gradient to track (the gradient baseline's path) the dynamic program chose its predecessors by
    comparisons that skip NaN, and ties of infinite cells picked the padding's pair (0, 0): a NaN estimate got a
    distance of 0 (a perfect fit) and one with an infinite sample 0 instead of inf. Reference: the plain table of
    :func:`ref_frechet` with NaN propagated, and inf where a point is infinitely far."""
    nan, inf = math.nan, math.inf
    zero = [0.0, 0.0, 0.0, 0.0]
    cases = [
        ([0.0, nan, 0.0, 0.0], zero, nan),
        ([0.0, 0.0, 0.0, nan], zero, nan),
        ([5.0, 0.0, 0.0, nan], zero, nan),
        ([0.0, inf, 0.0, 0.0], zero, inf),
        ([0.0, 1e300, 0.0, 0.0], zero, inf),  # finite, but its squared distance overflows float64
        ([0.0, 3.0, 0.0, 0.0], zero, 3.0),
    ]
    for qv, pv, want in cases:
        q = torch.tensor(qv, dtype=torch.float64)
        p = torch.tensor(pv, dtype=torch.float64)
        plain = float(discrete_frechet(q, p, dt=1.0))
        tracked = discrete_frechet(q.clone().requires_grad_(), p, dt=1.0)
        for got in (plain, float(tracked.detach())):
            assert (math.isnan(got) and math.isnan(want)) or got == want, (qv, plain, float(tracked.detach()))
    q = torch.tensor([0.0, 3.0, 1.0, 0.0], dtype=torch.float64, requires_grad=True)
    discrete_frechet(q, torch.zeros(4, dtype=torch.float64), dt=1.0).backward()
    assert q.grad.tolist() == [0.0, 1.0, 0.0, 0.0]  # a finite distance keeps its gradient


def test_the_compiled_frechet_kernel_gives_nan_where_torch_does_for_infinite_samples():
    """Both curves infinite at the same time made the compiled kernel's squared distance ``inf - inf`` = NaN, which
    its ``max``/``min`` skip: a distance of 0 where the torch backend gives NaN (as for a NaN sample)."""
    inf = math.inf
    for qv, pv in (([0.0, inf, 0.0], [0.0, inf, 0.0]), ([0.0, -inf, 0.0], [-inf, 0.0, 0.0])):
        q = torch.tensor([qv], dtype=torch.float64)
        p = torch.tensor([pv], dtype=torch.float64)
        slow = compute_metrics(q, p, dt=1e-3)
        fast = compute_metrics(q, p, dt=1e-3, backend="numba")
        assert math.isnan(float(slow.dfd[0])) and math.isnan(float(fast.dfd[0])), (qv, pv, slow.dfd, fast.dfd)
    q = torch.tensor([[0.0, inf, 0.0]], dtype=torch.float64)
    p = torch.tensor([[0.0, -inf, 0.0]], dtype=torch.float64)  # opposite infinities: infinitely far, not NaN
    assert float(compute_metrics(q, p, dt=1e-3, backend="numba").dfd[0]) == inf
    assert float(compute_metrics(q, p, dt=1e-3).dfd[0]) == inf


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf, "2", None, True])
@pytest.mark.parametrize("key", ["time_scale", "value_scale"])
def test_a_frechet_scale_that_is_not_a_factor_above_zero_is_refused_by_name(key, scale):
    """Called directly (not through a checked MetricsConfig), a scale of 0 dropped time or values from the distance
    without a word, NaN gave NaN, text or None raised torch's 'only integer tensors of a single element can be
    converted to an index', True counted as 1; in both the torch and the compiled kernel."""
    q = torch.tensor([0.0, 1.0, 0.5], dtype=torch.float64)
    p = torch.tensor([0.2, 0.8, 0.4], dtype=torch.float64)
    for call in (
        lambda: discrete_frechet(q, p, dt=1e-3, **{key: scale}),
        lambda: discrete_frechet(q, p, torch.arange(3.0) * 1e-3, **{key: scale}),
        lambda: discrete_frechet_uniform_numba(q, p, 1e-3, **{key: scale}),
    ):
        with pytest.raises(PulseError, match=key):
            call()
