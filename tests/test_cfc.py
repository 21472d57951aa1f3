"""SAE J211 CFC filter: coefficients, frequency response, zero phase, step, half-sine, padding."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import scipy.signal
import torch

from marlcrash.errors import ConfigError, PulseError
from marlcrash.pulse.cfc import CFC_CLASSES, cfc_coefficients, cfc_filter, cfc_filter_torch, cfc_matrix, f_h, f_n


def j211_coefficients(cfc: float, T: float) -> tuple[float, float, float, float, float]:
    """The J211 formulas, written out independently of marlcrash."""
    wd = 2 * math.pi * cfc * 2.0775
    wa = math.sin(wd * T / 2) / math.cos(wd * T / 2)
    den = 1 + math.sqrt(2) * wa + wa**2
    a0 = wa**2 / den
    return a0, 2 * a0, a0, -2 * (wa**2 - 1) / den, (-1 + math.sqrt(2) * wa - wa**2) / den


def j211_recursion(x: np.ndarray, coef) -> np.ndarray:
    """One pass of y[n] = a0 x[n] + a1 x[n-1] + a2 x[n-2] + b1 y[n-1] + b2 y[n-2], zero initial state."""
    a0, a1, a2, b1, b2 = coef
    y = np.zeros_like(x)
    for n in range(len(x)):
        y[n] = a0 * x[n]
        if n >= 1:
            y[n] += a1 * x[n - 1] + b1 * y[n - 1]
        if n >= 2:
            y[n] += a2 * x[n - 2] + b2 * y[n - 2]
    return y


@pytest.mark.filterwarnings("ignore:sampling rate")  # CFC 1000 at 10 kHz is legal but warned about
@pytest.mark.parametrize("cfc", CFC_CLASSES)
@pytest.mark.parametrize("fs", [10_000.0, 20_000.0, 50_000.0])
def test_coefficients_match_j211_formulas_and_scipy_butterworth(cfc, fs):
    b, a = cfc_coefficients(cfc, 1 / fs)
    a0, a1, a2, b1, b2 = j211_coefficients(cfc, 1 / fs)
    np.testing.assert_allclose(b, [a0, a1, a2], rtol=1e-13, atol=0)
    np.testing.assert_allclose(a, [1.0, -b1, -b2], rtol=1e-13, atol=1e-15)
    # second, independent reference: scipy's prewarped bilinear Butterworth at 2.0775 * CFC
    bs, as_ = scipy.signal.butter(2, 2.0775 * cfc, fs=fs)
    np.testing.assert_allclose(b, bs, rtol=1e-10)
    np.testing.assert_allclose(a, as_, rtol=1e-10)
    # the library's section is a unity-gain low-pass: its DC gain sum(b) / sum(a) is one
    assert abs(sum(b) / sum(a) - 1.0) < 1e-12


def test_filter_equals_forward_backward_j211_recursion():
    """Without padding, cfc_filter is the J211 recursion run forward, then backward."""
    dt = 1e-4
    rng = np.random.default_rng(3)
    x = np.concatenate([np.zeros(200), rng.normal(size=600), np.zeros(3000)])
    coef = j211_coefficients(60, dt)
    ref = j211_recursion(j211_recursion(x, coef)[::-1], coef)[::-1]
    got = cfc_filter(x, dt, 60, pad_time=0.0)
    # scipy starts from the steady state of x[0] = 0: the same as a zero initial state here
    np.testing.assert_allclose(got, ref, atol=1e-12)


def _gain_db(cfc: int, fs: float, n: int = 2**16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.zeros(n)
    x[n // 2] = 1.0
    h = cfc_filter(x, 1 / fs, cfc)
    spec = np.fft.rfft(np.roll(h, -n // 2))
    f = np.fft.rfftfreq(n, 1 / fs)
    return f, 20 * np.log10(np.maximum(np.abs(spec), 1e-300)), h


@pytest.mark.parametrize("cfc", CFC_CLASSES)
def test_minus_3db_at_f_n_and_flat_passband_to_f_h(cfc):
    fs = 50_000.0
    f, g, h = _gain_db(cfc, fs)
    i = int(np.argmax(g < -3.0))
    f3 = f[i - 1] + (-3.0 - g[i - 1]) / (g[i] - g[i - 1]) * (f[i] - f[i - 1])
    # J211's table: F_H (passband edge) is the class; F_N (-3 dB) 100, 300, 1000, 1650 Hz (1667 rounded)
    assert f_h(cfc) == cfc
    assert f_n(cfc) == pytest.approx({60: 100, 180: 300, 600: 1000, 1000: 1650}[cfc], rel=0.011)
    assert f3 == pytest.approx(f_n(cfc), rel=5e-3)
    band = f <= f_h(cfc)
    assert g[band].max() <= 0.5 and g[band].min() >= -1.0  # J211 passband corridor +0.5 / -1 dB
    # 4 poles: -24 dB/octave far above F_N, about -48 dB two octaves above the design frequency
    assert g[np.searchsorted(f, 8 * 2.0775 * cfc)] < -45.0
    # zero phase: the impulse response is symmetric about the impulse
    n = len(h)
    np.testing.assert_allclose(h[n // 2 + 1 : n // 2 + 2000], h[n // 2 - 1 : n // 2 - 2000 : -1], atol=1e-13)


def test_cfc60_f_n_is_100_hz_at_10_khz():
    f, g, _ = _gain_db(60, 10_000.0)
    i = int(np.argmax(g < -3.0))
    f3 = f[i - 1] + (-3.0 - g[i - 1]) / (g[i] - g[i - 1]) * (f[i] - f[i - 1])
    assert abs(f3 - 100.0) < 0.5


def test_half_sine_matches_frequency_domain_reference_and_keeps_its_peak_time():
    """A 10 ms half-sine: equal to |H|^2 applied by FFT, peak time unchanged, small attenuation."""
    fs, dur = 10_000.0, 0.010
    dt = 1 / fs
    t = np.arange(-0.2, 0.2, dt)
    x = np.where((t >= 0) & (t <= dur), np.sin(np.pi * np.clip(t, 0, dur) / dur), 0.0)
    y = cfc_filter(x, dt, 60)
    a0, a1, a2, b1, b2 = j211_coefficients(60, dt)
    z = np.exp(-2j * np.pi * np.fft.fftfreq(len(t), dt) * dt)
    h = (a0 + a1 * z + a2 * z**2) / (1 - b1 * z - b2 * z**2)
    ref = np.real(np.fft.ifft(np.fft.fft(x) * np.abs(h) ** 2))
    np.testing.assert_allclose(y, ref, atol=1e-9)
    assert t[np.argmax(y)] == pytest.approx(t[np.argmax(x)], abs=dt / 2)
    assert 0.94 < y.max() < 1.0  # measured 0.951: a 10 ms pulse loses about 5 % at CFC 60
    assert y.sum() * dt == pytest.approx(x.sum() * dt, rel=1e-9)  # unit DC gain keeps the impulse (delta-v)


def test_step_response_midpoint_and_settling():
    dt = 1e-4
    n, k = 4001, 2000
    x = np.zeros(n)
    x[k + 1 :] = 1.0
    x[k] = 0.5  # the symmetric step
    y = cfc_filter(x, dt, 60)
    assert y[k] == pytest.approx(0.5, abs=1e-9)  # no lag: the midpoint stays at the step time
    np.testing.assert_allclose(y[k + 1 : k + 1000] + y[k - 1 : k - 1000 : -1], 1.0, atol=1e-9)
    settle = round(0.010 / dt)
    assert np.all(np.abs(y[k + settle :] - 1) < 0.01)
    assert np.all(np.abs(y[: k - settle]) < 0.01)
    assert y.max() < 1.05  # small overshoot of the 4-pole response


def test_padding_keeps_constants_and_ramps_at_the_ends():
    dt = 1e-4
    const = np.full(500, 3.0)
    np.testing.assert_allclose(cfc_filter(const, dt, 60), const, rtol=1e-12)
    ramp = 2.0 + 30.0 * np.arange(1000) * dt
    padded = np.abs(cfc_filter(ramp, dt, 60) - ramp).max()
    unpadded = np.abs(cfc_filter(ramp, dt, 60, pad_time=0.0) - ramp).max()
    assert padded < 1e-3
    assert unpadded > 20 * padded


def test_torch_filter_equals_numpy_and_is_differentiable():
    dt = 5e-4
    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 3, 300))
    ref = cfc_filter(x, dt, 60)
    xt = torch.tensor(x, requires_grad=True)
    y = cfc_filter_torch(xt, dt, 60)
    np.testing.assert_allclose(y.detach().numpy(), ref, atol=1e-12)
    y.sum().backward()
    assert torch.isfinite(xt.grad).all() and xt.grad.abs().sum() > 0
    assert cfc_matrix(300, dt, 60).shape == (300, 300)
    # a numpy count (an array's size) is a count: np.int64(300) was refused as "needs at least 3 samples"
    np.testing.assert_array_equal(cfc_matrix(np.int64(300), dt, 60), cfc_matrix(300, dt, 60))
    for bad in (2, 300.0, True):
        with pytest.raises(PulseError, match=r"an integer count of at least 3 samples, got n="):
            cfc_matrix(bad, dt, 60)


def test_torch_filter_without_grad_is_batch_independent_bit_for_bit():
    """A record filtered alone equals its row of any batch exactly; the matrix (grad) path agrees to rounding.

    A matrix product does not give that: here rows 0-2 of a 3-row product differ from the same rows of a
    64-row one by about 1e-14 (the BLAS kernel treats the rows of a partial tile differently).
    """
    dt = 5e-4
    x = torch.tensor(np.random.default_rng(2).normal(size=(64, 3, 301)) * 100.0)
    y = cfc_filter_torch(x, dt, 60)
    for i in (0, 1, 17, 63):
        assert torch.equal(cfc_filter_torch(x[i : i + 1], dt, 60)[0], y[i])
        assert torch.equal(cfc_filter_torch(x[i, 2], dt, 60), y[i, 2])
    np.testing.assert_array_equal(y.numpy(), cfc_filter(x.numpy(), dt, 60))
    with torch.enable_grad():
        yg = cfc_filter_torch(x.clone().requires_grad_(True), dt, 60)
    np.testing.assert_allclose(yg.detach().numpy(), y.numpy(), rtol=0, atol=1e-11)
    assert cfc_filter_torch(x.float(), dt, 60).dtype == torch.float32
    bad = x[:2].clone()
    bad[1, 0, 10] = float("nan")
    out = cfc_filter_torch(bad, dt, 60)  # a diverged candidate poisons only its own record
    assert torch.equal(out[0], y[0]) and bool(out[1, 0].isnan().all()) and bool(out[1, 1:].isfinite().all())


def test_filter_along_any_axis():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(500, 2))
    np.testing.assert_allclose(cfc_filter(x, 1e-4, 180, axis=0), cfc_filter(x.T, 1e-4, 180).T, atol=1e-14)


def test_bad_inputs():
    with pytest.raises(ConfigError, match=r"\[60, 180, 600, 1000\]"):
        cfc_coefficients(100, 1e-4)
    with pytest.raises(PulseError, match="sampling rate above"):
        cfc_coefficients(1000, 1e-3)
    with pytest.raises(PulseError, match="finite"):
        cfc_filter(np.array([0.0, np.nan, 1.0, 2.0]), 1e-4, 60)
    with pytest.raises(PulseError, match="positive"):
        cfc_filter(np.zeros(10), -1.0, 60)
    with pytest.warns(UserWarning, match="10 x F_H = 600 Hz"):
        cfc_coefficients(60, 1 / 500.0)


@pytest.mark.parametrize("cfc", CFC_CLASSES)
def test_sampling_at_ten_times_the_class_keeps_the_j211_corridor_and_does_not_warn(cfc):
    """The sampling-rate note fires below 10 x F_H = 10 x CFC (10 kHz for CFC 1000, the customary rate). It fired
    below 10 x 5/3 CFC (the -3 dB frequency mislabelled F_H): every CFC 1000 record at 10 kHz got it."""
    fs = 10.0 * cfc
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f, g, _ = _gain_db(cfc, fs)
    band = f <= f_h(cfc)
    assert g[band].max() <= 0.5 and g[band].min() >= -1.0  # J211 passband corridor +0.5 / -1 dB up to F_H
    assert -4.0 < np.interp(f_n(cfc), f, g) < -2.0  # -3 dB at F_N within 1 dB (-2.45 dB: the bilinear warp)


@pytest.mark.parametrize("pad_time", [float("nan"), float("inf"), -0.001, "10 ms"])
def test_a_bad_pad_time_is_a_pulse_error_on_every_front_end(pad_time):
    """``pad_time`` < 0 was refused, but NaN or inf reached ``round()`` (ValueError / OverflowError from Python, not
    a PulseError the command line reports) and a string a TypeError."""
    x = np.random.default_rng(0).normal(size=200)
    with pytest.raises(PulseError, match=r"pad_time must be a duration >= 0 s"):
        cfc_filter(x, 1e-4, 60, pad_time=pad_time)
    with pytest.raises(PulseError, match=r"pad_time must be a duration >= 0 s"):
        cfc_filter_torch(torch.as_tensor(x)[None], 1e-4, 60, pad_time=pad_time)
    with pytest.raises(PulseError, match=r"pad_time must be a duration >= 0 s"):
        cfc_matrix(200, 1e-4, 60, pad_time=pad_time)
    np.testing.assert_array_equal(cfc_filter(x, 1e-4, 60, pad_time=0), cfc_filter(x, 1e-4, 60, pad_time=0.0))


def test_the_torch_filter_reads_integer_and_half_precision_records_and_names_what_it_cannot_take():
    """An integer record came back filtered and truncated to integers (a ramp 0, 1, 2, ... as 0, 0, 1, 2, ...; the
    matrix path, on a GPU, by an integer matrix of zeros), bfloat16 was numpy's 'unsupported ScalarType', an array
    an AttributeError on ``.device`` and a scalar an IndexError."""
    ramp = np.arange(60.0) ** 2 / 60.0
    want = cfc_filter(ramp, 1e-4, 60)
    y = cfc_filter_torch(torch.tensor(np.round(ramp)).to(torch.int64), 1e-4, 60)
    assert y.dtype == torch.get_default_dtype()
    np.testing.assert_allclose(y.double().numpy(), cfc_filter(np.round(ramp), 1e-4, 60), rtol=1e-6, atol=1e-6)
    for dtype in (torch.bfloat16, torch.float16):
        for grad in (False, True):
            x = torch.tensor(ramp, dtype=dtype, requires_grad=grad)
            y = cfc_filter_torch(x, 1e-4, 60)
            assert y.dtype == dtype
            np.testing.assert_allclose(y.detach().double().numpy(), want, rtol=2e-2, atol=0.2)
    np.testing.assert_allclose(cfc_filter_torch(ramp, 1e-4, 60).numpy(), want, rtol=1e-12, atol=1e-12)
    with pytest.raises(PulseError, match="scalar"):
        cfc_filter_torch(torch.tensor(1.0), 1e-4)
    with pytest.raises(PulseError, match="real"):
        cfc_filter_torch(torch.zeros(60, dtype=torch.complex64), 1e-4)
    with pytest.raises(PulseError, match="x"):
        cfc_filter_torch("abc", 1e-4)


def test_the_numpy_filter_names_samples_it_cannot_read():
    """Complex samples lost their imaginary part with only numpy's ComplexWarning, text raised numpy's 'could not
    convert string to float', and an axis the record does not have an IndexError."""
    with pytest.raises(PulseError, match="real"):
        cfc_filter(np.zeros(50) + 1j, 1e-4)
    with pytest.raises(PulseError, match="numbers"):
        cfc_filter(["a"] * 50, 1e-4)
    with pytest.raises(PulseError, match="axis 5"):
        cfc_filter(np.zeros((3, 50)), 1e-4, axis=5)
    np.testing.assert_allclose(cfc_filter([[1] * 50], 1e-4), np.ones((1, 50)), rtol=1e-12)  # integers are numbers
