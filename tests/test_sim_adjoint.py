"""The compiled adjoint (``backend="adjoint"``): gradients of the sensor velocities against torch autograd
and against finite differences of the fast kernel, its forward pass, and what it refuses."""

from __future__ import annotations

import pytest
import torch

from marlcrash.errors import ModelError
from marlcrash.sim import Surrogate, get_scenario, load_sim_config
from marlcrash.sim.adjoint import _statics, forward_velocity

SC = get_scenario("full_width_40")


def _params(car, batch, seed, spread=0.3):
    """Every parameter of every cell scaled by a log-normal factor (transmission factors too)."""
    g = torch.Generator().manual_seed(seed)
    base = torch.as_tensor(car.params, dtype=torch.float64)
    return base[None] * torch.exp(spread * torch.randn(batch, *base.shape, generator=g, dtype=torch.float64))


def _velocity_grad(sim, p0, duration, backend, weights, **rows):
    p = p0.clone().requires_grad_(True)
    res = sim.run(p, SC, duration=duration, record_cells="none", backend=backend, **rows)
    (res.velocity * weights).sum().backward()
    return res, p.grad


def _assert_same_gradient(ga, gt, rtol):
    """Per parameter column (E_x, E_s, five transmission factors): relative error of the whole column."""
    for j in range(gt.shape[-1]):
        ref = float(gt[..., j].norm())
        assert ref > 0, f"column {j}: no gradient at all, the test would not see a wrong one"
        assert float((ga[..., j] - gt[..., j]).norm()) <= rtol * ref, f"column {j}"


@pytest.mark.parametrize("duration", [0.03, pytest.param(0.15, marks=pytest.mark.slow)])
def test_adjoint_gradient_equals_torch_autograd(default_sim, default_cells, duration):
    """Two rows, two load cases (full width, 40 % offset at 56 km/h): crush, contact across gaps, wall
    contact and cells bottoming out within the window are all differentiated."""
    sim, car = default_sim, default_cells
    p0 = _params(car, 2, seed=1)
    rows = {"speed": torch.tensor([11.11, 15.56]), "overlap": torch.tensor([1.0, 0.4]), "side": torch.ones(2)}
    g = torch.Generator().manual_seed(2)
    w = torch.randn(2, len(car.sensor_names), round(duration / SC.output_dt) + 1, generator=g, dtype=torch.float64)
    rt, gt = _velocity_grad(sim, p0, duration, "torch", w, **rows)
    ra, ga = _velocity_grad(sim, p0, duration, "adjoint", w, **rows)
    assert bool(rt.saturated.any(dim=1).all()), "no cell bottomed out in some row: the switch is not exercised"
    torch.testing.assert_close(ra.velocity.detach(), rt.velocity.detach(), rtol=0, atol=1e-5)
    _assert_same_gradient(ga, gt, rtol=1e-9)


def test_adjoint_gradient_matches_finite_differences_of_the_fast_kernel(default_sim, default_cells):
    """Independent of torch: central differences of the numba kernel along random directions."""
    sim, car = default_sim, default_cells
    duration = 0.02
    p0 = _params(car, 1, seed=3, spread=0.2)
    g = torch.Generator().manual_seed(4)
    w = torch.randn(1, len(car.sensor_names), round(duration / SC.output_dt) + 1, generator=g, dtype=torch.float64)
    _, grad = _velocity_grad(sim, p0, duration, "adjoint", w)
    for k in range(3):
        d = torch.randn(p0.shape, generator=g, dtype=torch.float64) * p0  # relative direction
        h = 1e-7  # 1e-6 crosses kinks of the yield switches (rel. error 2e-3); 1e-7 agrees to 1e-8
        pair = torch.cat([p0 + h * d, p0 - h * d])
        v = sim.run(pair, SC, duration=duration, record_cells="none", backend="numba").velocity
        fd = float(((v[0] - v[1]) * w[0]).sum()) / (2 * h)
        ad = float((grad * d).sum())
        assert abs(fd - ad) <= 1e-4 * abs(ad) + 1e-9, (k, fd, ad)


def test_adjoint_forward_is_the_fast_path_and_its_replay_is_the_torch_path(default_sim, default_cells):
    sim, car = default_sim, default_cells
    p0 = _params(car, 2, seed=5)
    duration = 0.03
    a = sim.run(p0, SC, duration=duration, record_cells="none", backend="adjoint")
    b = sim.run(p0, SC, duration=duration, record_cells="none", backend="numba")
    assert torch.equal(a.velocity, b.velocity)  # no gradient asked: exactly the fast path
    # the replay the reverse pass differentiates performs the torch path's operations in its order
    props = sim.link_props(sim.check_params(p0))
    wall = sim.scenario_tensors(2, SC)
    _, idx = sim._sensor_index(list(SC.sensors))
    n_out = round(duration / SC.output_dt) + 1
    replay = forward_velocity((props.yield_c, props.yield_t, props.k, props.k_dense, props.damping, props.e_s),
                              _statics(sim, wall, n_out, idx))  # fmt: skip
    ref = sim.run(p0, SC, duration=duration, record_cells="none", backend="torch").velocity
    torch.testing.assert_close(replay, ref, rtol=0, atol=1e-11)


def test_adjoint_refuses_what_it_does_not_cover(default_cells):
    car = default_cells
    p = torch.as_tensor(car.params)[None].clone().requires_grad_(True)
    relief = Surrogate(car, load_sim_config(overrides={"springback_relief": True}))
    with pytest.raises(ModelError, match="springback_relief"):
        relief.run(p, SC, duration=0.001, backend="adjoint")
    single = Surrogate(car, load_sim_config(overrides={"dtype": "float32"}))
    with pytest.raises(ModelError, match="float64"):
        single.run(p, SC, duration=0.001, backend="adjoint")
    with pytest.raises(ModelError, match="backend must be one of"):
        relief.run(p, SC, duration=0.001, backend="jax")


def test_adjoint_refuses_a_second_derivative_instead_of_dropping_its_curvature(default_sim, default_cells):
    """The reverse pass is not differentiable itself: ``create_graph`` gradients must not give second derivatives
    that leave out the simulation's curvature (on a 10 ms window 3e5 against torch autograd's 4e17)."""
    sim, car = default_sim, default_cells
    p = _params(car, 1, seed=6).requires_grad_(True)
    res = sim.run(p, SC, duration=0.002, record_cells="none", backend="adjoint")
    (g,) = torch.autograd.grad(res.velocity.sum(), p, create_graph=True)
    (plain,) = torch.autograd.grad(
        sim.run(p, SC, duration=0.002, record_cells="none", backend="adjoint").velocity.sum(), p
    )
    assert torch.equal(g.detach(), plain)  # the first derivatives are the same with or without a graph
    with pytest.raises(ModelError, match=r"first derivatives only.*backend .torch."):
        torch.autograd.grad(g.sum(), p)


@pytest.mark.parametrize("name", ["speed", "overlap"])
def test_adjoint_refuses_scenario_tensors_that_require_grad(default_sim, default_cells, name):
    """The adjoint differentiates the cell parameters only: a speed or overlap that requires grad got none (its
    ``.grad`` stayed None, so an optimizer silently never moved it); torch autograd differentiates it."""
    sim, car = default_sim, default_cells
    p = _params(car, 2, seed=7).requires_grad_(True)
    value = {"speed": torch.tensor([15.0, 12.0]), "overlap": torch.tensor([1.0, 0.6])}[name].requires_grad_(True)
    with pytest.raises(ModelError, match=rf"{name}.*backend .torch."):
        sim.run(p, SC, duration=0.002, record_cells="none", backend="adjoint", **{name: value})
    res = sim.run(p, SC, duration=0.002, record_cells="none", backend="torch", **{name: value})
    res.velocity.sum().backward()
    assert value.grad is not None  # reached by torch autograd
    with torch.no_grad():  # no gradient asked: the fast result, as for parameters that require grad
        sim.run(p, SC, duration=0.002, record_cells="none", backend="adjoint", **{name: value})


def test_auto_backend_differentiates_a_speed_that_requires_grad(default_sim, default_cells):
    """``auto`` is numba "unless gradients are required": a speed that requires grad (parameters that do not) got
    the no-grad fast result, so ``backward`` failed or the speed silently kept no gradient."""
    sim, car = default_sim, default_cells
    speed = torch.tensor([15.0], dtype=torch.float64, requires_grad=True)
    res = sim.run(_params(car, 1, seed=8), SC, speed=speed, duration=0.005, record_cells="none", backend="auto")
    res.velocity.sum().backward()
    assert speed.grad is not None and float(speed.grad.abs()) > 0


def test_adjoint_gradient_equals_torch_in_partial_overlaps_at_kinks_and_row_by_row(default_sim, default_cells):
    """Right offset and small overlaps (per row), rows with zero transmission factors (absent links: the return
    mapping's ``min``/``max`` at ties): every parameter column agrees with torch autograd, each row run alone gets
    its gradient in the batch exactly, and ``record_cells`` does not change it."""
    sim, car = default_sim, default_cells
    p0 = _params(car, 3, seed=9)
    p0[0, :, 3] = 0.0  # f_y = 0 in every cell
    p0[1, ::3, 3:] = 0.0  # every third cell transmits along x only (lateral links of share 0)
    rows = {"speed": torch.tensor([15.56, 11.11, 13.0]), "overlap": torch.tensor([0.4, 0.25, 0.25]),
            "side": torch.tensor([-1.0, 1.0, -1.0])}  # fmt: skip
    duration = 0.015
    g = torch.Generator().manual_seed(10)
    w = torch.randn(3, len(car.sensor_names), round(duration / SC.output_dt) + 1, generator=g, dtype=torch.float64)
    rt, gt = _velocity_grad(sim, p0, duration, "torch", w, **rows)
    _, ga = _velocity_grad(sim, p0, duration, "adjoint", w, **rows)
    assert bool(rt.saturated.any(dim=1).all()), "no cell bottomed out in some row: the switch is not exercised"
    for b in range(3):
        _assert_same_gradient(ga[b], gt[b], rtol=1e-9)
        one = {k: v[b : b + 1] for k, v in rows.items()}
        _, g1 = _velocity_grad(sim, p0[b : b + 1], duration, "adjoint", w[b : b + 1], **one)
        assert torch.equal(g1[0], ga[b]), f"row {b} depends on its batch"
    p = p0.clone().requires_grad_(True)
    res = sim.run(p, SC, duration=duration, record_cells="series", backend="adjoint", **rows)
    (res.velocity * w).sum().backward()
    assert torch.equal(p.grad, ga)


def test_adjoint_gradient_of_each_parameter_kind_matches_finite_differences(default_sim, default_cells):
    """Central differences of the fast kernel along a random direction in one parameter column at a time
    (E_x, E_s and each transmission factor), in a 40 % offset to the right."""
    sim, car = default_sim, default_cells
    duration = 0.02
    rows = {"speed": torch.tensor([15.56]), "overlap": torch.tensor([0.4]), "side": torch.tensor([-1.0])}
    p0 = _params(car, 1, seed=11, spread=0.2)
    g = torch.Generator().manual_seed(12)
    w = torch.randn(1, len(car.sensor_names), round(duration / SC.output_dt) + 1, generator=g, dtype=torch.float64)
    _, grad = _velocity_grad(sim, p0, duration, "adjoint", w, **rows)
    h = 1e-7  # relative; see the test above
    for j in range(7):
        d = torch.zeros_like(p0)
        d[..., j] = torch.randn(p0.shape[:-1], generator=g, dtype=torch.float64) * p0[..., j]
        pair = torch.cat([p0 + h * d, p0 - h * d])
        two = {k: v.expand(2) for k, v in rows.items()}
        v = sim.run(pair, SC, duration=duration, record_cells="none", backend="numba", **two).velocity
        fd = float(((v[0] - v[1]) * w[0]).sum()) / (2 * h)
        ad = float((grad * d).sum())
        assert abs(fd - ad) <= 1e-4 * abs(ad), (j, fd, ad)
