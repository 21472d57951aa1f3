"""Levenberg-Marquardt steps on residuals (shared by the ``lm`` baseline and ``local_fit``), on linear toys."""

from __future__ import annotations

import torch

from marlcrash.calibrate.leastsq import damped_steps, lm_iteration


def _linear(seed: int = 0, n: int = 4, m: int = 20):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(m, n, generator=g, dtype=torch.float64)
    truth = torch.linspace(-0.3, 0.3, n, dtype=torch.float64)
    box = (-torch.ones(n, dtype=torch.float64), torch.ones(n, dtype=torch.float64))
    return a, truth, box


def test_a_linear_problem_is_solved_in_one_step():
    a, truth, (lo, hi) = _linear()

    def run(zs):
        return (zs - truth) @ a.T, None

    z = torch.zeros(4, dtype=torch.float64)
    step = lm_iteration(run, z, run(z[None])[0][0], 1e-6, lo, hi, 1e-6)
    assert step.accepted is not None
    torch.testing.assert_close(step.z, truth, rtol=0, atol=1e-4)


def test_a_simulation_that_blows_up_at_a_finite_difference_point_does_not_poison_the_step():
    """One finite-difference point with a NaN residual (a candidate the simulator cannot run) made every entry
    of ``J^T J`` NaN, so every damped candidate was NaN and the next batch refused them ("x[...] is not finite"):
    the lm baseline and ``local_fit`` crashed. The coordinate is held for that iteration and the others move."""
    a, truth, (lo, hi) = _linear()
    simulated = []

    def run(zs):
        simulated.append(zs.clone())
        if not bool(torch.isfinite(zs).all()):
            raise ValueError("a non-finite candidate was simulated")
        r = (zs - truth) @ a.T
        r[zs[:, 0] > 0.5e-6] = float("nan")  # moving coordinate 0 up blows the simulation up
        return r, None

    z = torch.zeros(4, dtype=torch.float64)
    r0 = run(z[None])[0][0]
    step = lm_iteration(run, z, r0, 1e-6, lo, hi, 1e-6)
    assert step.accepted is not None and float((step.r**2).sum()) < float((r0**2).sum())
    assert float(step.z[0]) == 0.0 and float((step.z[1:] - z[1:]).abs().max()) > 0.01


def test_damped_steps_never_propose_a_non_finite_candidate():
    a, truth, (lo, hi) = _linear()
    z = torch.zeros(4, dtype=torch.float64)
    r = (z - truth) @ a.T
    for jac, res in ((a.clone().fill_(float("nan")), r), (a, torch.full_like(r, float("nan")))):
        cand = damped_steps(jac, res, z, 1e-2, lo, hi)
        assert bool(torch.isfinite(cand).all())
    # a Jacobian the pulses do not see at all, after the damping shrank far: no step (it raised a singular solve)
    torch.testing.assert_close(damped_steps(torch.zeros_like(a), r, z, 1e-12, lo, hi), z.expand(6, 4))
