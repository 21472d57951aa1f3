"""The surrogate on the embedded default car: plausible pulses (DESIGN 4), energy, locality, gradients, batching.

The cell parameters come from the car's geometry and materials (``discretize(default_vehicle())``);
nothing here is fitted to the target ranges, which are those of DESIGN section 4 for a B-segment car
against a rigid wall: at 40 km/h full width, CFC60 peak 20-45 g at the tunnel, maximum dynamic crush
0.35-0.7 m, time to zero velocity 50-110 ms, rebound 5-20 % of the impact speed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import fields

import numpy as np
import pytest
import torch

from marlcrash.cells.parameterization import apply_increments
from marlcrash.envs.core import load_env_config
from marlcrash.metrics import rmse
from marlcrash.pulse.signal import filtered_acceleration
from marlcrash.sim import Surrogate, get_scenario, max_balance_error
from marlcrash.units import G0

KMH40 = {"speed_kmh": 40.0}
PARTIAL = (
    "offset40_left",
    "offset40_right",
    "small_overlap_left",
    "small_overlap_right",
)


@pytest.fixture(scope="module")
def car(default_cells):
    return default_cells


@pytest.fixture(scope="module")
def sim(default_sim):
    return default_sim


@pytest.fixture(scope="module")
def base(car):
    return torch.as_tensor(car.params)[None]


def _random_params(cells, batch, seed):
    """E_x, E_s scaled 0.5x-2x per cell (log-uniform); feasible factors perturbed 0.5x-1.5x and renormalised."""
    g = torch.Generator().manual_seed(seed)
    p = torch.as_tensor(cells.params)[None].repeat(batch, 1, 1)
    p[..., :2] *= torch.exp(
        torch.empty(p[..., :2].shape, dtype=p.dtype).uniform_(np.log(0.5), np.log(2.0), generator=g)
    )
    f = p[..., 2:] * torch.empty(p[..., 2:].shape, dtype=p.dtype).uniform_(0.5, 1.5, generator=g)
    f = f * torch.as_tensor(cells.feasible)[None]
    p[..., 2:] = f / f.sum(-1, keepdim=True).clamp_min(1e-12)
    return p


def _pulse(out, row=0, sensor="tunnel"):
    """CFC60 peak deceleration [g] and its time [s], time to zero velocity [s], rebound [-], max crush [m]."""
    k = out.sensor_names.index(sensor)
    a = filtered_acceleration(out.acceleration[row, k].numpy(), 5e-4, 60)
    v = out.compartment_velocity[row].numpy()
    below = np.flatnonzero(v <= 0.0)
    t0v = float(out.time[below[0]]) if below.size else float("inf")
    return {
        "peak": float(-a.min() / G0),
        "t_peak": float(out.time[int(np.argmin(a))]),
        "t0v": t0v,
        "rebound": float(-v.min() / v[0]),
        "crush": float(out.crush[row].max()),
    }


@pytest.fixture(scope="module")
def fw40(sim, base):
    return sim.run(base, get_scenario("full_width_40"), record_cells="final")


# ------------------------------------------------------------------ plausibility
def test_full_width_40_pulse_in_published_ranges(fw40):
    s = _pulse(fw40)
    assert 20.0 <= s["peak"] <= 45.0, s
    assert 0.35 <= s["crush"] <= 0.70, s
    assert 0.050 <= s["t0v"] <= 0.110, s
    assert 0.05 <= s["rebound"] <= 0.20, s


def test_load_paths_absorb_the_energy(car, fw40):
    """The rails and crash boxes take a large share; nothing ends on the rigid wall contact of the compartment."""
    ab = fw40.cell_absorbed[0, :, -1].numpy()
    e0 = float(fw40.initial[0])
    share = {name: ab[car.cells_of(name)].sum() / e0 for name in car.subassembly_names}
    assert share["front_rail_left"] + share["front_rail_right"] > 0.2, share
    assert share["compartment"] < 0.01, share  # the compartment never reaches the wall at 40 km/h
    assert float(fw40.crush[0].max()) < float(car.lo[car.compartment, 0])


@pytest.mark.parametrize("name", PARTIAL)
def test_partial_overlap_softer_and_longer_at_equal_speed(sim, base, fw40, name):
    off = sim.run(base, get_scenario(name, KMH40), record_cells="none")
    f, o = _pulse(fw40), _pulse(off)
    assert o["peak"] < f["peak"], (name, o, f)
    assert o["t0v"] > 1.1 * f["t0v"], (name, o, f)


def test_56_kmh_crushes_more_than_40(sim, base, fw40):
    fast = sim.run(base, get_scenario("full_width_56"), record_cells="none")
    assert _pulse(fast)["crush"] > 1.2 * _pulse(fw40)["crush"]


@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_crush_is_continuous_in_overlap_where_the_barrier_edge_clips_a_cell(sim, base, backend):
    """A barrier 0.01 % wider than offset40's 0.40 (or than 0.25) reported 12-16 % less crush at 56 km/h: the cell
    its edge clips meets a wall as stiff as the covered fraction of its front, sinks centimetres into it, and crush
    subtracted that penetration whole. Weighted by the coverage, crush follows the compartment's travel, which
    barely moves."""
    for edge in (0.25, 0.40):
        ov = torch.tensor([edge, edge + 1e-4], dtype=torch.float64)
        scenario = get_scenario("offset40_left", {"duration": 0.1})
        out = sim.run(base.repeat(2, 1, 1), scenario, overlap=ov, backend=backend, record_cells="none")
        crush = out.crush.amax(dim=1)
        travel = out.compartment_displacement.amax(dim=1)
        assert abs(float(travel[1] - travel[0])) < 0.01, (edge, travel)
        assert abs(float(crush[1] - crush[0])) < 0.01, (edge, crush)
        assert float((travel - crush).max()) < 0.03, (edge, travel, crush)  # a penalty's millimetres, not decimetres


def test_the_wall_meets_each_cell_where_its_exposed_material_begins(car, sim):
    # reference: walk every voxel column from the front to its first voxel of a non-null cell
    lab, edges = car.grid_labels, car.grid_edges[0]
    ref = {}
    for j in range(lab.shape[1]):
        for k in range(lab.shape[2]):
            for i in range(lab.shape[0]):
                c = int(lab[i, j, k])
                if c >= 0 and not car.is_null[c]:
                    ref[c] = min(ref.get(c, np.inf), float(edges[i]))
                    break
    exposed = np.flatnonzero((car.front_area > 0) & ~car.is_rigid)
    assert sorted(ref.keys() - {car.compartment}) == exposed.tolist()
    want = np.array([ref[c] for c in exposed])
    np.testing.assert_allclose(car.front_x[exposed], want, rtol=0, atol=1e-12)
    # the sloping hood's cells reach forward of their exposed faces: their boxes met the wall 8 cm early
    ahead = want - car.lo[exposed, 0]
    assert ahead.max() > 0.05 and set(car.subassembly[exposed[ahead > 1e-9]]) == {car.subassembly_names.index("hood")}
    wall = sim.scenario_tensors(1, get_scenario("full_width_40"))
    gap = wall.gap[0, exposed].numpy()
    np.testing.assert_allclose(gap, want - want.min(), rtol=0, atol=1e-12)


@pytest.mark.parametrize("sensor", ["upfront_left", "upfront_right"])
def test_upfront_sensor_peaks_before_the_tunnel(fw40, sensor):
    up, tunnel = _pulse(fw40, sensor=sensor), _pulse(fw40)
    assert up["t_peak"] < tunnel["t_peak"], (up, tunnel)


@pytest.mark.xfail(
    strict=True,
    reason="known physics shortfall: the up-front sensor cells stop within 1-2 ms at the wall (about 315 g "
    "CFC60); this passed before only because the acceleration output was aliased (marlcrash.sim.bench."
    "plausibility_checks, known_failures)",
)
@pytest.mark.parametrize("sensor", ["upfront_left", "upfront_right"])
def test_upfront_sensor_peak_in_10_to_150_g(fw40, sensor):
    up = _pulse(fw40, sensor=sensor)
    assert 10.0 <= up["peak"] <= 150.0, up


def test_acceleration_output_integrates_to_the_velocity_change(fw40):
    """The output is a sample of the velocity's derivative, not an aliased point value (up-front: 8.9 of 12 m/s)."""
    dt = float(fw40.time[1] - fw40.time[0])
    acc, vel = fw40.acceleration[0].numpy(), fw40.velocity[0].numpy()
    led = np.concatenate([np.zeros((acc.shape[0], 1)), acc], axis=1)  # zero acceleration before the contact
    dv = (led.sum(axis=1) - 0.5 * (led[:, 0] + led[:, -1])) * dt  # trapezoid, an independent integration
    np.testing.assert_allclose(dv, vel[:, -1] - vel[:, 0], rtol=0.0, atol=1e-9)


# ------------------------------------------------------------------ energy
def test_energy_balance_default_car(fw40):
    assert max_balance_error(fw40) < 5e-3
    torch.testing.assert_close(fw40.cell_absorbed[..., -1].sum(1), fw40.absorbed[:, -1], rtol=1e-9, atol=1e-6)


def _action_bound_params(cells, batch, seed):
    """Parameter sets anywhere inside the calibration's action bounds, through the env's own update.

    Per-cell log increments from the initial parameters: ``E_x``, ``E_s`` uniform over the whole
    ``behaviour_bounds`` box (every fifth row at its corners, 0.25x or 4x), transmission increments in
    [-3, 3] with the env's floor (factors may drop to zero, down to one surviving direction), renormalised.
    """
    env = load_env_config()
    lo, hi = env.behaviour_bounds
    g = torch.Generator().manual_seed(seed)
    init = torch.as_tensor(cells.params)
    inc = torch.empty(batch, cells.n_cells, 7, dtype=init.dtype)
    inc[..., :2].uniform_(np.log(lo), np.log(hi), generator=g)
    heads = torch.rand(batch, cells.n_cells, 2, generator=g, dtype=init.dtype) < 0.5
    corner = torch.where(heads, np.log(lo), np.log(hi))
    inc[::5, :, :2] = corner[::5]
    inc[..., 2:].uniform_(-3.0, 3.0, generator=g)
    feasible = torch.as_tensor(cells.feasible)
    return apply_increments(init[None].repeat(batch, 1, 1), inc, init, feasible, (lo, hi), env.transmission_floor)


def test_no_reachable_parameters_drive_the_sensors_through_the_wall(car, sim):
    """Transmission increments keep x the principal direction where it is feasible (DESIGN 1.3 boundary condition
    3). An increment of -5 on f_x (E_s at its lower bound) left the lateral links principal and the axial ones with a
    share near 0: the up-front sensors drove on at the impact speed (15.56 m/s at 150 ms, 56 km/h) through the cells
    ahead of them and the wall, as cells interact only through their links."""
    env = load_env_config()
    lo, hi = env.behaviour_bounds
    init, feasible = torch.as_tensor(car.params), torch.as_tensor(car.feasible)
    p = _action_bound_params(car, 6, seed=3)
    inc = torch.zeros_like(p)
    inc[..., 2] = -5.0
    inc[::2, :, 1] = -5.0  # every other row with E_s at its lower bound too
    p = apply_increments(p, inc, init, feasible, (lo, hi), env.transmission_floor)
    deform = torch.as_tensor(~car.is_null & ~car.is_rigid)
    f, x = p[:, deform, 2:], feasible[deform, 0]
    assert bool((f[:, x, 0] >= f[:, x, 1:].amax(-1)).all())
    sc = get_scenario("full_width_56")
    out = sim.run(p, sc, backend="numba", record_cells="none")
    slowest = out.velocity.amin(dim=-1)  # [B, sensors]
    assert bool((slowest < 0.25 * sc.speed).all()), slowest


@pytest.mark.slow
def test_energy_balance_1000_random_parameter_sets_one_numba_batch(car, sim):
    p = _action_bound_params(car, 1000, seed=11)
    e0 = torch.as_tensor(car.params)[None, :, :2]
    assert bool((p[..., :2] >= 0.25 * e0 - 1e-12).all()) and bool((p[..., :2] <= 4.0 * e0 + 1e-12).all())
    assert bool((p[::5, :, :2] / e0 < 0.26).any()) and bool((p[::5, :, :2] / e0 > 3.9).any())
    out = sim.run(p, get_scenario("full_width_40"), backend="numba", record_cells="final")
    assert out.acceleration.shape[0] == 1000
    for f in fields(out):
        x = getattr(out, f.name)
        if isinstance(x, torch.Tensor) and x.is_floating_point():
            assert torch.isfinite(x).all(), f.name
    assert max_balance_error(out) < 5e-3


def test_kinetic_energy_equals_the_cell_velocities(car, sim):
    """The reported kinetic energy against 1/2 sum m v^2 of every cell's own recorded velocity.

    Recorded velocities are mid-step averages, the reported energy the leapfrog product ``m v v'``: they
    differ by ``m (v - v')^2 / 8``, far below the 0.5 % checked, at every output step.
    """
    sc = get_scenario("full_width_40")
    cells = np.flatnonzero(~car.is_null)
    p = _action_bound_params(car, 2, seed=4)
    out = sim.run(p, sc, backend="numba", probe_cells=cells, record_cells="none")
    m = sim.mass_ke[cells].to(torch.float64)
    ke = 0.5 * (m[None, :, None] * out.velocity.square()).sum(1)
    assert bool((out.kinetic[:, -1] < 0.2 * out.initial).all())  # most of the energy was absorbed
    rel = (ke - out.kinetic).abs() / out.initial[:, None]
    assert float(rel.max()) < 5e-3


def test_corner_of_the_accepted_stability_ranges_stays_stable_and_beyond_is_refused(car):
    """Damping is explicit on top of stability-capped stiffness: the accepted ranges must not diverge together."""
    from marlcrash.errors import ConfigError
    from marlcrash.sim import load_sim_config
    from marlcrash.sim.surrogate import MAX_LINK_DAMPING_RATIO, MAX_STIFFNESS_CAP

    p = _random_params(car, 16, seed=12)
    corner = {"stiffness_cap": MAX_STIFFNESS_CAP, "link_damping_ratio": MAX_LINK_DAMPING_RATIO,
              "contact_damping_ratio": 1.0, "wall_damping_ratio": 1.0}  # fmt: skip
    peak = {}
    for name, over in (("default", {}), ("corner", corner)):
        out = Surrogate(car, load_sim_config(overrides=over)).run(p, get_scenario("full_width_56"), backend="numba",
                                                                  record_cells="none")  # fmt: skip
        assert torch.isfinite(out.acceleration).all() and max_balance_error(out) < 5e-3, name
        peak[name] = float(out.acceleration.abs().max()) / G0
    # stable: the spikes of light cells grow a little, they do not run away (cap 1.5 with link damping 0.15: 1e30 g)
    assert peak["corner"] < 2.0 * peak["default"], peak
    for key, value in (
        ("link_damping_ratio", MAX_LINK_DAMPING_RATIO + 0.01),
        ("stiffness_cap", MAX_STIFFNESS_CAP + 0.01),
    ):
        with pytest.raises(ConfigError, match=key):
            load_sim_config(overrides={key: value})


# ------------------------------------------------------------------ locality
def _hops_from_first_contact(car, sim, scenario):
    """Link-graph distance (undirected) of every cell from the cells that touch the wall at t = 0."""
    wall = sim.scenario_tensors(1, scenario)
    start = np.flatnonzero((wall.covered[0] & (wall.gap[0] == 0)).numpy())
    adj = [[] for _ in range(car.n_cells)]
    for a, b in zip(car.link_src.tolist(), car.link_dst.tolist(), strict=True):
        adj[a].append(b)
        adj[b].append(a)
    hops = np.full(car.n_cells, np.iinfo(np.int64).max)
    hops[start] = 0
    queue = deque(start.tolist())
    while queue:
        i = queue.popleft()
        for j in adj[i]:
            if hops[j] > hops[i] + 1:
                hops[j] = hops[i] + 1
                queue.append(j)
    return hops


def test_null_and_far_cells_change_nothing_impact_cell_changes_early_pulse(car, sim, base):
    sc = get_scenario("full_width_40", {"duration": 0.0005})  # far cells: more links away than steps taken
    steps = sim.config.substeps  # explicit steps in one output step: load travels at most one link per step
    hops = _hops_from_first_contact(car, sim, sc)
    active = ~car.is_null & ~car.is_rigid
    far = np.flatnonzero(active & (hops > steps + 1))
    assert far.size > 0
    null = int(np.flatnonzero(car.is_null)[0])
    front = int(np.flatnonzero(active & (hops == 0))[0])
    p = base.repeat(4, 1, 1)
    p[1, null] = torch.tensor([float("nan"), -1.0, 5.0, 0.0, 0.0, 0.0, 0.0])
    p[2, far, :2] *= 1.8
    # (their transmission factors cannot change: on the default car every far cell has one feasible direction)
    p[3, front, 1] *= 1.5
    fields_compared = ("acceleration", "velocity", "crush", "kinetic", "stored", "absorbed", "plastic", "cell_absorbed")
    for backend in ("torch", "numba"):
        out = sim.run(p, sc, backend=backend)
        for row in (1, 2):
            for name in fields_compared:
                x = getattr(out, name)
                assert torch.equal(x[0], x[row]), (backend, row, name)
    # a null cell changes nothing over the whole 150 ms either
    whole = get_scenario("full_width_40")
    for backend in ("torch", "numba"):
        out = sim.run(p[:2], whole, backend=backend, record_cells="final")
        for name in fields_compared:
            x = getattr(out, name)
            assert torch.equal(x[0], x[1]), (backend, "null, 150 ms", name)
    early = sim.run(p[[0, 3]], get_scenario("full_width_40", {"duration": 0.01}), record_cells="none")
    k = early.sensor_names.index("upfront_left")
    assert float((early.velocity[0, k] - early.velocity[1, k]).abs().max()) > 1e-3


# ------------------------------------------------------------------ gradients and batching
def test_gradients_of_rmse_wrt_impact_region_finite_nonzero(car, sim, base):
    sc = get_scenario("full_width_40", {"duration": 0.005})
    ref = sim.run(_random_params(car, 1, seed=3), sc, backend="torch", record_cells="none").velocity.detach()
    p = base.clone().requires_grad_(True)
    out = sim.run(p, sc, backend="torch", record_cells="none")
    loss = rmse(out.velocity, ref).mean()  # the library's metric, per sensor, averaged
    loss.backward()
    g = p.grad[0]
    assert torch.isfinite(p.grad).all()
    wall = sim.scenario_tensors(1, sc)
    impact = np.flatnonzero((wall.covered[0] & (wall.gap[0] == 0)).numpy())
    assert impact.size > 10
    assert bool((g[impact, 0] != 0).all()) and bool((g[impact, 1] != 0).all())  # every struck cell's E_x and E_s
    assert float(g[car.is_null | car.is_rigid].abs().sum()) == 0.0


def test_batch_of_one_equals_row_of_64(car, sim):
    """Bit for bit, on both backends: a candidate's pulse never depends on the batch it came in."""
    p = _random_params(car, 64, seed=5)
    for backend, rows, window in (("numba", (0, 31, 63), 0.06), ("torch", (17,), 0.02)):  # torch: slow, shorter
        sc = get_scenario("offset40_left", {"speed_kmh": 40.0, "duration": window})
        full = sim.run(p, sc, backend=backend, record_cells="none")
        for i in rows:
            one = sim.run(p[i : i + 1], sc, backend=backend, record_cells="none")
            for f in ("acceleration", "velocity", "crush"):
                assert torch.equal(getattr(one, f)[0], getattr(full, f)[i]), (backend, i, f)
            for f in ("kinetic", "absorbed"):  # sums over cells: torch may order a [1, n] reduction differently
                torch.testing.assert_close(getattr(one, f)[0], getattr(full, f)[i], rtol=1e-12, atol=1e-9)


@pytest.mark.slow
def test_float32_fast_path_closes_balance_and_matches_float64(car, sim):
    """config dtype float32: the fused kernel in single precision (float64 ledgers) keeps the physics.

    Elastic-plastic trajectories amplify rounding (yield and saturation switch a step earlier or later),
    so rows agree to 1 % of the impact speed and 5 mm of crush, not to float64 rounding.
    """
    from marlcrash.sim import load_sim_config

    sim32 = Surrogate(car, load_sim_config(overrides={"dtype": "float32"}))
    p = _random_params(car, 8, seed=7)
    sc = get_scenario("full_width_40", {"duration": 0.08})
    a = sim.run(p, sc, backend="numba", record_cells="final")
    b = sim32.run(p.to(torch.float32), sc, backend="numba", record_cells="final")
    assert b.velocity.dtype == torch.float32
    assert max_balance_error(b) < 5e-3
    scale = float(a.compartment_velocity.abs().max())
    assert float((a.compartment_velocity - b.compartment_velocity.double()).abs().max()) < 1e-2 * scale
    assert float((a.crush - b.crush.double()).abs().max()) < 5e-3


def test_sensor_velocities_respond_linearly_to_small_parameter_changes(car, sim, base):
    """No step-quantized force jumps: 1e-5 and 1e-4 relative changes of the energies move the pulses linearly.

    The changes scale each sub-assembly's energies uniformly, as the twin reference and the agents do; the
    reference slope comes from 1e-8 changes. With damping switched on or off in full at the step that detects a
    contact or a yield, the 1e-5 response was up to 46x the linear one; with elastic-part damping but bottoming
    out at the step after the crossing, up to 4.6x at 1e-5 and 12x at 1e-4 (now at most 1.0001x at 1e-5). A 1e-4
    change may cross a real knee of the element laws (a link that starts to yield a step earlier): 1.72x on one
    direction's up-front sensor, the others at most 1.4x.
    """
    g = torch.Generator().manual_seed(11)
    sub = torch.as_tensor(car.subassembly).clamp_min(0)
    dirs = torch.randn((4, len(car.subassembly_names), 2), generator=g, dtype=torch.float64)[:, sub]
    eps = (1e-8, 1e-5, 1e-4)
    p = base.repeat(1 + len(eps) * 4, 1, 1).clone()
    for i, (d, e) in enumerate((d, e) for d in dirs for e in eps):
        p[1 + i, :, :2] *= torch.exp(e * d)
    v = sim.run(p, get_scenario("full_width_40"), backend="numba", record_cells="none").velocity
    slope = (v[1:] - v[:1]).abs().amax(-1) / torch.tensor(eps * 4, dtype=v.dtype)[:, None]
    slope = slope.reshape(4, len(eps), -1)  # [directions, eps, sensors]
    ratio = slope[:, 1:] / slope[:, :1]
    assert bool((slope[:, 0] > 0).all())
    assert float(ratio.median()) < 1.1, ratio
    assert float(ratio[:, 0].max()) < 1.5, ratio  # 1e-5
    assert float(ratio[:, 1].max()) < 3.0, ratio  # 1e-4: a knee crossed, not the 12x of step-quantized jumps


@pytest.mark.parametrize("case", ["offset40", "small_overlap"])
def test_left_and_right_impacts_on_the_symmetric_car_are_mirror_images(car, sim, base, case):
    """The nominal car is mirror-symmetric, so a left impact's pulses are a right impact's, sensors swapped.

    Before its cells were exact mirrors (grid edges symmetric only to rounding, ties on them decided by that
    rounding, plane-cut pieces binned by midpoints), offset40's far-side up-front sensor peaked at 153.7 g on one
    side and 166.6 g on the other.
    """
    names = list(car.sensor_names)
    swap = [names.index(n.replace("left", "@").replace("right", "left").replace("@", "right")) for n in names]
    left = sim.run(base, get_scenario(f"{case}_left"), record_cells="none")
    right = sim.run(base, get_scenario(f"{case}_right"), record_cells="none")
    assert swap != list(range(len(names)))  # there are left and right sensors to swap
    torch.testing.assert_close(left.velocity[:, swap], right.velocity, rtol=0, atol=1e-9)
    torch.testing.assert_close(left.crush, right.crush, rtol=0, atol=1e-12)
