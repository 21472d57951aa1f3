"""Levenberg-Marquardt steps on residuals (shared by the ``lm`` baseline and ``local_fit``), on linear toys."""

from __future__ import annotations

import torch

from marlcrash.calibrate.leastsq import damped_steps, fd_points, jacobian, lm_iteration


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


def test_finite_difference_points_stay_in_a_box_narrower_than_the_step():
    """Where the box is narrower than ``fd_step`` along a coordinate (``problem.box_radius`` below it), the backward
    point left the box on the other side (``-1e-5`` in a box of ``+-2e-6``): lm simulated candidates outside its
    search box. A step that fits neither way goes to the farther bound (a shorter one-sided step); a box of zero
    width gives no step and a zero Jacobian column."""
    f64 = torch.float64
    lo, hi = torch.tensor([-2e-6, -2e-6, -2e-6, -2e-6, 0.0], dtype=f64), torch.tensor([2e-6] * 4 + [0.0], dtype=f64)
    z = torch.tensor([0.0, 1.5e-6, -2e-6, 2e-6, 0.0], dtype=f64)
    points, h = fd_points(z, lo, hi, 1e-5)
    assert bool(((points >= lo) & (points <= hi)).all()), points
    torch.testing.assert_close(h, torch.tensor([2e-6, -3.5e-6, 4e-6, -4e-6, 0.0], dtype=f64), rtol=0, atol=1e-20)
    torch.testing.assert_close(points, z + torch.diag(h), rtol=0, atol=1e-20)
    a = torch.arange(15, dtype=f64).reshape(3, 5)
    jac = jacobian(points @ a.T, z @ a.T, h)
    assert bool(torch.isfinite(jac).all()) and bool((jac[:, 4] == 0).all())
    torch.testing.assert_close(jac[:, :4], a[:, :4])
    # a box wider than twice the step: forward, or backward at the upper bound, exactly as before
    lo, hi = -torch.ones(3, dtype=f64), torch.ones(3, dtype=f64)
    z = torch.tensor([0.3, 1.0 - 1e-6, -1.0], dtype=f64)
    points, h = fd_points(z, lo, hi, 1e-5)
    assert torch.equal(h, torch.tensor([1e-5, -1e-5, 1e-5], dtype=f64)) and torch.equal(points, z + torch.diag(h))


def test_an_iteration_in_a_narrow_box_simulates_only_points_inside_it():
    a, truth, _ = _linear()
    lo, hi = torch.full((4,), -3e-6, dtype=torch.float64), torch.full((4,), 3e-6, dtype=torch.float64)
    simulated = []

    def run(zs):
        simulated.append(zs.clone())
        return (zs - truth) @ a.T, None

    z = torch.tensor([0.0, 3e-6, -3e-6, 1e-6], dtype=torch.float64)
    lm_iteration(run, z, run(z[None])[0][0], 1e-6, lo, hi, 1e-5)
    zs = torch.cat(simulated)
    assert bool(((zs >= lo) & (zs <= hi)).all()), zs
