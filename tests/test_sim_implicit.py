"""The implicit study integrator (issue 3's semi-implicit route) against closed forms and its own tangent."""

from __future__ import annotations

import pytest
import torch
from sim_fixtures import single_cell, vehicle_block

from marlcrash.errors import ModelError
from marlcrash.sim import Surrogate, get_scenario, load_sim_config
from marlcrash.sim.implicit import run_implicit


def _uncapped(cells, **over):
    cfg = load_sim_config(overrides={"mass_floor": 0.0, **over})
    return Surrogate(cells, cfg, stability_caps=False)


def _stop_time(t, v):
    i = int(torch.nonzero(v <= 0)[0])
    return float(t[i - 1] + (t[i] - t[i - 1]) * v[i - 1] / (v[i - 1] - v[i]))


def _single(speed_kmh, force, substeps, **kw):
    cells = single_cell(mass=10.0, compartment_mass=1000.0, crush_force=force, crush_length=1.5, e_x=1.0)
    sim = _uncapped(cells, link_damping_ratio=0.0, substeps=substeps)
    sc = get_scenario("full_width_40", {"speed_kmh": speed_kmh, "duration": 0.2})
    out, stats = run_implicit(sim, torch.as_tensor(cells.params)[None], sc, **kw)
    return out, stats, sc.speed


@pytest.mark.parametrize("substeps", [1, 2])
@pytest.mark.parametrize("speed_kmh,force", [(40.0, 1e5), (56.0, 2e5)])
def test_backward_euler_matches_rigid_plastic_closed_form_at_half_millisecond_steps(speed_kmh, force, substeps):
    """Raw stiffness (5e9 N/m on a 10 kg cell: 125x the explicit stability limit at 0.5 ms), Newton-solved:
    crush = M v^2 / 2F and stop time = M v / F within 1 %, every step solved."""
    out, stats, v = _single(speed_kmh, force, substeps)
    assert stats["unconverged_steps"] == 0
    assert float(out.crush.max()) == pytest.approx(1000.0 * v**2 / (2 * force), rel=0.01)
    assert _stop_time(out.time, out.compartment_velocity[0]) == pytest.approx(1000.0 * v / force, rel=0.01)


def test_linearly_implicit_step_misses_the_closed_form():
    """One solve with the predictor's (elastic) tangent treats the yielding link as elastic: the crush falls far
    short of the closed form. The study reports this scheme; this pins why it is not usable."""
    out, stats, v = _single(40.0, 1e5, 1, linear=True)
    assert stats["solves_per_step"] == pytest.approx(1.0)
    assert float(out.crush.max()) < 0.5 * 1000.0 * v**2 / (2 * 1e5)


def test_element_tangent_matches_finite_differences():
    """The tangent the Newton solve uses is the derivative of the element forces by the node increments."""
    cells = vehicle_block()
    sim = _uncapped(cells, substeps=1)
    p = torch.as_tensor(cells.params)[None]
    _, props, wall, _, _ = sim.prepare(p, get_scenario("full_width_40"))
    n, L, dt = sim.n, sim.L, sim.dt
    v = wall.speed[:, None].expand(1, n).clone()
    z = lambda *shape: torch.zeros(shape, dtype=torch.float64)  # noqa: E731
    state = (z(1, L), sim.gap.expand(1, -1).clone(), z(1, n), torch.zeros(1, L, dtype=torch.bool))
    g = torch.Generator().manual_seed(0)
    ds0 = dt * v * (1.0 + 0.2 * torch.randn(1, n, generator=g, dtype=torch.float64))

    def force(ds):
        st = sim._step(props, wall, *state, ds, ds, ds / dt, tangent=True)
        return sim._node_force(st), st

    f0, st = force(ds0)
    assert int((st.k_t > 0).sum()) > 0 and int((st.kw_t > 0).sum()) > 0  # elastic links and wall contact
    e = torch.randn(1, n, generator=g, dtype=torch.float64)
    eps = 1e-10
    fd = (force(ds0 + eps * e)[0] - f0) / eps
    d = st.k_t[0] * (e[0, sim.dst] - e[0, sim.src])
    jx = (st.kw_t[0] * e[0]).index_add(0, sim.dst, d).index_add(0, sim.src, -d)  # J e; dF = -J ds
    assert torch.allclose(fd[0], -jx, rtol=1e-4, atol=1e-6 * float(jx.abs().max()))


def test_uncapped_surrogate_refuses_the_explicit_paths_and_bad_arguments_are_named():
    cells = single_cell(mass=10.0, compartment_mass=1000.0, crush_force=1e5, crush_length=1.5, e_x=1.0)
    sim = _uncapped(cells)
    p = torch.as_tensor(cells.params)[None]
    with pytest.raises(ModelError, match="stability_caps=False"):
        sim.run(p, get_scenario("full_width_40"))
    # None and text failed inside '<=' or int() (a TypeError, "x" a ValueError); linear="no" ran the linear scheme
    for kw, key in (({"theta": 0.3}, "theta"), ({"max_newton": 0}, "max_newton"), ({"cg_rtol": 0.0}, "cg_rtol"),
                    ({"newton_rtol": -1.0}, "newton_rtol"), ({"theta": None}, "theta"), ({"max_newton": "x"},
                    "max_newton"), ({"max_newton": None}, "max_newton"), ({"max_newton": True}, "max_newton"),
                    ({"newton_rtol": "1e-10"}, "newton_rtol"), ({"cg_rtol": None}, "cg_rtol"),
                    ({"linear": "no"}, "linear must be True or False, got 'no'")):  # fmt: skip
        with pytest.raises(ModelError, match=key):
            run_implicit(sim, p, get_scenario("full_width_40"), **kw)
    # as Surrogate.run: an unknown mode is refused, not run as "none" (no per-cell energies, without a word)
    with pytest.raises(ModelError, match="record_cells must be one of series, final, none; got 'all'"):
        run_implicit(sim, p, get_scenario("full_width_40", {"duration": 0.001}), record_cells="all")
