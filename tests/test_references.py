"""Reference pulses: twin, cross-fidelity and measured files (marlcrash.references)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from marlcrash.cells.parameterization import apply_increments
from marlcrash.config import from_dict
from marlcrash.envs.core import build_cells
from marlcrash.errors import ConfigError, PulseError
from marlcrash.pulse.cfc import cfc_filter
from marlcrash.pulse.signal import (
    PRE_IMPACT_TIME,
    SHORT_PRE_TRIGGER,
    compared_velocity,
    compared_window,
    margin_samples,
)
from marlcrash.references import (
    CrossFidelityConfig,
    FileReference,
    ReferenceConfig,
    ReferenceSampler,
    TwinConfig,
    perturb_twin,
    twin_increments,
)
from marlcrash.sim import Surrogate, get_scenario

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="session")
def cells():
    return build_cells("b_segment", None, "optimized")


@pytest.fixture(scope="session")
def sim(cells):
    return Surrogate(cells)


def sampler(cells, sim, kind="twin", scenarios=None, **kw):
    cfg = ReferenceConfig(kind=kind, **kw)
    return ReferenceSampler(cells, sim, list(cells.sensor_names), scenarios or {"full_width_40": 1.0}, cfg)


def test_twin_without_spread_is_the_model_itself(cells, sim):
    s = sampler(cells, sim, twin=TwinConfig(0.0, 0.0, 0.0))
    ref = s.sample(np.random.default_rng(0), 2)
    direct = sim.run(torch.as_tensor(cells.params)[None], get_scenario("full_width_40"), record_cells="none")
    compared = compared_velocity(direct.velocity.double(), 5e-4, 60)  # integral of the CFC60 acceleration
    torch.testing.assert_close(ref.velocity, compared.expand(2, -1, -1), rtol=0, atol=1e-12)
    torch.testing.assert_close(ref.true_params, torch.as_tensor(cells.params)[None].expand(2, -1, -1))
    assert torch.equal(ref.raw_velocity[:, :, 0], torch.full_like(ref.raw_velocity[:, :, 0], 40 / 3.6))
    # the filtered signal starts a little below the impact speed (the zero-phase filter reaches back), the tunnel least
    v0 = ref.velocity[:, :, 0] - 40 / 3.6
    assert float(v0[:, :2].max()) < -1.0 and float(v0[:, 2].abs().max()) < 0.01  # up-front sensors, tunnel


@pytest.mark.parametrize("cfc", [600, 1000])
def test_a_compare_cfc_the_output_rate_cannot_carry_is_refused_by_name(cells, sim, cfc):
    """The simulation is filtered at the scenarios' 2 kHz: CFC 600 and 1000 passed the config's check and failed at
    the first comparison with the filter's PulseError, naming no key."""
    with pytest.raises(ConfigError, match=rf"CFC {cfc} needs an output rate above .* 2000 Hz: expected one of "
                                          r"\[60, 180\] or null") as e:  # fmt: skip
        sampler(cells, sim, compare_cfc=cfc)
    assert e.value.key == "reference.compare_cfc"
    assert sampler(cells, sim, compare_cfc=180).config.compare_cfc == 180


def test_a_reference_batch_holds_the_compared_velocity_and_no_acceleration_that_disagrees_with_it():
    """``ReferenceBatch.acceleration`` was read by nothing (the env, the problems and the plots differentiate the
    compared velocity), and it was not that velocity's derivative: a simulated reference stored the simulator's
    unfiltered acceleration beside its CFC-filtered velocity, a file reference the derivative of its filtered one. A
    batch holds the velocity as compared (and a simulated one its raw velocity) only."""
    from dataclasses import fields

    from marlcrash.references import ReferenceBatch

    names = {f.name for f in fields(ReferenceBatch)}
    assert "velocity" in names and "raw_velocity" in names
    assert "acceleration" not in names


def test_compared_signal_is_the_integral_of_the_cfc60_acceleration(cells, sim):
    """DESIGN 1.5: the compared velocity integrates the CFC-filtered acceleration of the record led in by
    PRE_IMPACT_TIME at the impact speed (zero acceleration before contact); with ``compare_cfc: null`` the same
    integral unfiltered (what a record of that acceleration read with ``cfc: null`` integrates to)."""
    raw = sampler(cells, sim, twin=TwinConfig(0.0, 0.0, 0.0), compare_cfc=None).sample(np.random.default_rng(0), 1)
    cfc = sampler(cells, sim, twin=TwinConfig(0.0, 0.0, 0.0)).sample(np.random.default_rng(0), 1)
    dt = 5e-4
    n = round(PRE_IMPACT_TIME / dt)
    v = raw.raw_velocity
    led = torch.cat([v[..., :1].expand(-1, -1, n), v], -1)
    acc = torch.gradient(led, spacing=dt, dim=-1)[0]

    def integral(a):  # trapezoid from the impact speed at the lead-in's first sample
        inc = 0.5 * (a[..., 1:] + a[..., :-1]) * dt
        return v[..., :1] + torch.cat([torch.zeros_like(a[..., :1]), torch.cumsum(inc, -1)], -1)

    filtered = torch.as_tensor(cfc_filter(acc.numpy(), dt, 60).copy())
    torch.testing.assert_close(cfc.velocity, integral(filtered)[..., n:], rtol=0, atol=1e-9)
    torch.testing.assert_close(raw.velocity, integral(acc)[..., n:], rtol=0, atol=1e-9)
    # unfiltered, the integral of the central differences is the velocity averaged [1, 2, 1] / 4
    pad = torch.cat([v[..., :1], v, v[..., -1:]], -1)
    smooth = (pad[..., :-2] + 2 * pad[..., 1:-1] + pad[..., 2:]) / 4
    torch.testing.assert_close(raw.velocity[..., :-1], smooth[..., :-1], rtol=0, atol=1e-9)
    assert not torch.allclose(cfc.velocity, raw.velocity, atol=1e-3)  # the filter does act on the up-front sensors


def test_compared_signal_has_no_offset_from_the_first_contact(cells, sim):
    """A bumper-region sensor stops within 1-2 ms of contact. Filtered without a lead-in, the filter's odd
    reflection about that huge first deceleration left a constant velocity offset (1.1 m/s on the up-front
    sensor of the default car while it sat at the wall); with it, the compared signal follows the raw
    velocity once the filter's few-millisecond spread is over."""
    raw = sampler(cells, sim, twin=TwinConfig(0.0, 0.0, 0.0), compare_cfc=None).sample(np.random.default_rng(0), 1)
    v = raw.raw_velocity[0]
    window = slice(60, 120)  # 30-60 ms: the up-front cells rest against the barrier, the tunnel decelerates
    assert float(v[0, :10].min()) < 1.0  # the up-front sensor stops within 5 ms
    now = compared_velocity(v, 5e-4, 60)
    before = compared_velocity(v, 5e-4, 60, pre_time=0.0)
    offset_now = (now[:, window] - v[:, window]).mean(-1).abs()
    offset_before = (before[:, window] - v[:, window]).mean(-1).abs()
    assert float(offset_now.max()) < 0.01
    assert float(offset_before[0]) > 0.1  # what the lead-in removes (up-front left: 0.26 m/s here)
    with pytest.raises(PulseError, match="pre_time"):
        compared_velocity(v, 5e-4, 60, pre_time=-1.0)


def test_twin_truth_is_reachable_in_the_calibration_parameter_space(cells):
    """The hidden truth is apply_increments of per-sub-assembly log increments (the agents' own space)."""
    p0 = torch.as_tensor(cells.params)
    sub = torch.as_tensor(np.where(cells.is_null | cells.is_rigid, -1, cells.subassembly))
    feasible = torch.as_tensor(cells.feasible)
    noise = torch.randn(2, len(cells.subassembly_names), 7, generator=torch.Generator().manual_seed(0)).double()
    cfg = TwinConfig(0.3, 0.2, 0.25)
    truth = perturb_twin(p0, sub, feasible, noise, cfg, (0.25, 4.0), floor=0.01)
    sig = torch.tensor([0.3, 0.2] + [0.25] * 5, dtype=torch.float64)
    inc = torch.where((sub >= 0)[None, :, None], (noise * sig)[:, sub.clamp_min(0)], torch.zeros(()).double())
    again = apply_increments(p0[None].expand(2, -1, -1), inc, p0, feasible, (0.25, 4.0), 0.01)
    torch.testing.assert_close(truth, again, rtol=0, atol=0)


def test_twin_perturbation_is_per_subassembly_feasible_and_seeded(cells, sim):
    s = sampler(cells, sim, scenarios={"offset40_left": 1.0, "small_overlap_right": 2.0})
    a = s.sample(np.random.default_rng(5), 3)
    b = s.sample(np.random.default_rng(5), 3)
    torch.testing.assert_close(a.true_params, b.true_params, rtol=0, atol=0)
    torch.testing.assert_close(a.velocity, b.velocity, rtol=0, atol=0)
    c = s.sample(np.random.default_rng(6), 3)
    assert not torch.equal(a.true_params, c.true_params)
    p0 = torch.as_tensor(cells.params)
    truth = a.true_params
    deform = torch.as_tensor(~cells.is_null & ~cells.is_rigid)
    ratio = truth[:, :, :2] / torch.where(p0[:, :2] > 0, p0[:, :2], 1.0)
    for k, _name in enumerate(cells.subassembly_names[:-1]):  # one factor per sub-assembly and env
        idx = torch.as_tensor(np.flatnonzero((cells.subassembly == k) & ~cells.is_null))
        r = ratio[:, idx]
        torch.testing.assert_close(r, r[:, :1].expand_as(r), rtol=1e-10, atol=0)
    assert not torch.allclose(ratio[:, deform], torch.ones(()).double())
    f = truth[:, deform][..., 2:]
    torch.testing.assert_close(f.sum(-1), torch.ones(f.shape[:-1], dtype=torch.float64))
    assert (f[:, ~torch.as_tensor(cells.feasible)[deform]] == 0).all()
    torch.testing.assert_close(truth[:, ~deform], p0[~deform].expand(3, -1, -1))
    # the reference is the simulation of the ground truth under the drawn scenarios
    sc = [get_scenario(n) for n in a.scenario]
    f64 = torch.float64
    again = sim.run(truth, speed=torch.tensor([x.speed for x in sc], dtype=f64), record_cells="none",
                    overlap=torch.tensor([x.overlap for x in sc], dtype=f64),
                    side=torch.tensor([x.side_sign for x in sc], dtype=f64))  # fmt: skip
    torch.testing.assert_close(a.velocity, s.compared(again.velocity), rtol=0, atol=1e-12)


def test_a_batch_draws_row_by_row_so_a_row_does_not_depend_on_the_batch_size(cells, sim):
    """sample()'s docstring: row i's scenario pick, then its [S, 7] twin normals, then row i + 1's; so the first
    rows of a larger batch are the smaller batch from the same seed, and one draw is the seed's own reference."""
    s = sampler(cells, sim, scenarios={"offset40_left": 1.0, "small_overlap_right": 2.0})
    eight, four = s.sample(np.random.default_rng(3), 8), s.sample(np.random.default_rng(3), 4)
    for n, ref in ((8, eight), (4, four)):  # the documented order, drawn here independently
        rng = np.random.default_rng(3)
        pick, noise = [], []
        for _ in range(n):
            pick.append(rng.choice(2, p=[1 / 3, 2 / 3]))
            noise.append(rng.standard_normal((s.n_subassemblies, 7)))
        assert ref.scenario == [["offset40_left", "small_overlap_right"][i] for i in pick]
        expected = twin_increments(torch.as_tensor(np.stack(noise)), s.config.twin)
        torch.testing.assert_close(ref.true_increments, expected, rtol=0, atol=0)
    assert len(set(eight.scenario)) == 2  # both scenarios drawn: the rows differ in more than their twins
    assert eight.scenario[:4] == four.scenario
    for name in ("true_increments", "true_params", "velocity", "speed", "overlap", "side"):
        torch.testing.assert_close(getattr(eight, name)[:4], getattr(four, name), rtol=0, atol=0, msg=name)
    one = s.sample(np.random.default_rng(3), 1)
    torch.testing.assert_close(one.true_params[0], four.true_params[0], rtol=0, atol=0)
    torch.testing.assert_close(s.pinned(3, 2).true_params, one.true_params.expand(2, -1, -1), rtol=0, atol=0)


def test_file_and_cross_fidelity_picks_do_not_depend_on_the_batch_size(cells, sim, tmp_path, monkeypatch):
    """Test picks (kind file) and vehicle-seed picks (cross_fidelity) are drawn row by row too."""
    from marlcrash.pulse.simulation import write_crash_csv

    files = []
    for k, name in enumerate(("full_width_40", "offset40_left", "small_overlap_right")):
        result = sim.run(torch.as_tensor(cells.params)[None], get_scenario(name), record_cells="none")
        path = write_crash_csv(result, tmp_path / f"{name}.csv")
        files.append(FileReference(path=str(path), scenario=name, weight=1.0 + k,
                                   channels={s: f"{s}_acc_g" for s in cells.sensor_names}))  # fmt: skip
    s = sampler(cells, sim, kind="file", files=files)
    eight, three = s.sample(np.random.default_rng(11), 8), s.sample(np.random.default_rng(11), 3)
    assert len(set(eight.source)) > 1 and eight.source[:3] == three.source
    torch.testing.assert_close(eight.velocity[:3], three.velocity, rtol=0, atol=0)
    rng = np.random.default_rng(11)
    assert eight.source == [files[rng.choice(3, p=[1 / 6, 2 / 6, 3 / 6])].path for _ in range(8)]

    seeds = [None, 1, 2]
    cross = sampler(cells, sim, kind="cross_fidelity", scenarios={"full_width_40": 1.0, "offset40_left": 1.0},
                    cross_fidelity=CrossFidelityConfig(vehicle_seeds=seeds))  # fmt: skip
    fake = np.zeros((len(cells.sensor_names), cross.n_outputs))  # the pick order only: no fine model is built
    monkeypatch.setattr(cross, "_fine_reference", lambda seed, scenario: fake + 11.0)
    drawn = {n: cross.sample(np.random.default_rng(4), n) for n in (1, 2, 6)}
    assert drawn[6].source[:2] == drawn[2].source and drawn[2].source[:1] == drawn[1].source
    assert drawn[6].scenario[:2] == drawn[2].scenario
    rng = np.random.default_rng(4)
    expected = []
    for _ in range(6):
        scenario = ("full_width_40", "offset40_left")[rng.choice(2, p=[0.5, 0.5])]
        expected.append((scenario, f"uniform:seed={seeds[rng.integers(0, 3)]}"))
    assert list(zip(drawn[6].scenario, drawn[6].source, strict=True)) == expected
    assert len({e[1] for e in expected}) > 1


def test_perturb_twin_bounds_clip_the_behaviour_factors(cells):
    p0 = torch.as_tensor(cells.params)
    sub = torch.as_tensor(np.where(cells.is_null | cells.is_rigid, -1, cells.subassembly))
    noise = torch.full((1, len(cells.subassembly_names), 7), 10.0, dtype=torch.float64)
    out = perturb_twin(p0, sub, torch.as_tensor(cells.feasible), noise, TwinConfig(1.0, 1.0, 0.0), bounds=(0.5, 2.0))
    active = p0[:, 0] > 0
    torch.testing.assert_close(out[0, active, :2], 2.0 * p0[active, :2])


def test_a_bounded_twins_increments_are_the_ones_its_truth_was_made_with(cells, sim):
    """With behaviour bounds the twin's E factors are clipped: its returned increments are the clipped ones, and
    apply_increments of them is its truth bit for bit (they were the raw draws, up to 3.0 past log 4)."""
    s = ReferenceSampler(cells, sim, list(cells.sensor_names), {"full_width_40": 1.0},
                         ReferenceConfig(twin=TwinConfig(1.5, 1.5, 0.2)), bounds=(0.25, 4.0))  # fmt: skip
    ref = s.sample(np.random.default_rng(0), 2)
    inc = ref.true_increments
    assert float(inc[..., :2].abs().max()) <= float(np.log(4.0))
    assert (inc[..., :2].abs() == float(np.log(4.0))).any()  # some factors clipped
    p0 = torch.as_tensor(cells.params)
    sub = torch.as_tensor(np.where(cells.is_null | cells.is_rigid, -1, cells.subassembly))
    per_cell = torch.where((sub >= 0)[None, :, None], inc[:, sub.clamp_min(0)], torch.zeros((), dtype=inc.dtype))
    again = apply_increments(p0[None].expand(2, -1, -1), per_cell, p0, torch.as_tensor(cells.feasible), (0.25, 4.0),
                             0.01)  # fmt: skip
    torch.testing.assert_close(again, ref.true_params, rtol=0, atol=0)
    deform = sub >= 0
    torch.testing.assert_close(torch.log(ref.true_params[:, deform, :2] / p0[deform, :2]), per_cell[:, deform, :2])


def test_file_reference_conventions_and_time_zero_alignment(cells, sim, tmp_path):
    """The same test written another way: decelerations positive, m/s^2, time in ms, recorded 37 ms later.

    With ``sign=-1, unit='m/s2', time_unit='ms'`` the reference must equal the default-convention one: the
    sign and unit conversions are right and, with ``time_zero: threshold``, time zero is found from the pulse,
    not from the file's clock. Read with the default sign, the positive decelerations are refused, naming it.
    """
    rows = [r for r in (DATA / "halfsine_40kmh.csv").read_text().splitlines() if not r.startswith("#")]
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    other = tmp_path / "late_decel_positive.csv"
    t_ms = (data[:, 0] + 0.037) * 1e3
    body = "".join(f"{t:.6f};{-a * 9.80665:.12g}\n" for t, a in zip(t_ms, data[:, 1], strict=True))
    other.write_text("time_ms;tunnel_decel\n" + body)
    refs = []
    for path, chan, conv in (
        (DATA / "halfsine_40kmh.csv", "tunnel_acx", {}),
        (other, "tunnel_decel", {"sign": -1.0, "unit": "m/s2", "time_unit": "ms"}),
    ):
        spec = FileReference(path=str(path), scenario="full_width_40", channels=dict.fromkeys(cells.sensor_names, chan),
                             time_zero="threshold", **conv)  # fmt: skip
        refs.append(sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity)
    torch.testing.assert_close(refs[1], refs[0], rtol=0, atol=1e-9)
    channels = dict.fromkeys(cells.sensor_names, "tunnel_decel")
    positive = FileReference(path=str(other), scenario="full_width_40", unit="m/s2", time_unit="ms",
                             channels=channels, time_zero="threshold")  # fmt: skip
    with pytest.raises(PulseError, match=r"above the impact speed.*set reference\.files\[0\]\.sign: -1"):
        sampler(cells, sim, kind="file", files=[positive])


def test_a_file_reference_read_with_sign_minus_one_that_climbs_names_the_sign_given_not_the_same_remedy(cells, sim):
    """A test that records decelerations negative (SAE J211), read with ``sign: -1``, climbs above the impact speed
    too: the refusal says that the sign given turned it over and to leave it at +1, not "set sign: -1" again (the
    remedy the user has already applied)."""
    channels = dict.fromkeys(cells.sensor_names, "tunnel_acx")
    spec = FileReference(path=str(DATA / "halfsine_40kmh.csv"), scenario="full_width_40", channels=channels, sign=-1.0)
    with pytest.raises(PulseError, match=r"above the impact speed") as e:
        sampler(cells, sim, kind="file", files=[spec])
    assert "set reference.files[0].sign: -1" not in str(e.value)
    assert re.search(r"reference\.files\[0\]\.sign: -1 is given.*leave reference\.files\[0\]\.sign at 1", str(e.value))


def test_a_file_reference_whose_velocity_change_no_crash_can_have_is_refused_naming_the_unit(cells, sim, tmp_path):
    """A test in m/s^2 whose header gives no unit, read in g (the default), changes the velocity 9.8x as much: the
    40 km/h half-sine's 11 m/s became 109 m/s, down to -98 m/s, and the surrogate was calibrated against it without a
    word (only a velocity climbing above the impact speed was refused). A crash changes the velocity by at most about
    twice the impact speed (a full rebound): more is refused, naming the channel and the unit; read in m/s2 it is
    the test."""
    rows = [r for r in (DATA / "halfsine_40kmh.csv").read_text().splitlines() if not r.startswith("#")]
    data = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    path = tmp_path / "si.csv"
    path.write_text("time,ax\n" + "".join(f"{t:.6f},{a * 9.80665:.12g}\n" for t, a in data[:, :2]))
    spec = {"path": str(path), "scenario": "full_width_40", "channels": dict.fromkeys(cells.sensor_names, "ax")}
    with pytest.raises(PulseError, match=r"si\.csv: channel 'ax' changes the velocity by 1\d\d m/s, from the impact "
                       r"speed 11\.1 m/s.*unit g.*reference\.files\[0\]\.unit"):  # fmt: skip
        sampler(cells, sim, kind="file", files=[FileReference(**spec)])
    v = sampler(cells, sim, kind="file", files=[FileReference(**spec, unit="m/s2")]).sample(
        np.random.default_rng(0), 1).velocity  # fmt: skip
    assert float(v[0, 0, 0] - v[0, 0, -1]) == pytest.approx(40 / 3.6, rel=0.02)


def test_a_simulation_written_as_csv_and_read_as_a_file_reference_is_the_simulation(cells, sim, tmp_path):
    """``marlcrash simulate --csv`` read back as a measured test: the reference equals the simulation's own
    compared signal. A record that starts at the impact (a bumper-region sensor at 485 g in its first sample)
    sets time zero at its first sample, and the deceleration the filter spreads before time zero is counted:
    integrating from time zero instead left the up-front sensors 4.6 m/s short (area 0.48 m)."""
    from marlcrash.pulse.simulation import write_crash_csv

    sc = get_scenario("full_width_40")
    result = sim.run(torch.as_tensor(cells.params)[None], sc, record_cells="none")
    path = write_crash_csv(result, tmp_path / "sim.csv")
    spec = FileReference(path=str(path), scenario=sc.name, channels={s: f"{s}_acc_g" for s in cells.sensor_names})
    ref = sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity
    model = compared_velocity(result.velocity.double(), sc.output_dt, 60)
    assert float(ref[0, 0, 0]) < sc.speed - 3.0  # the up-front sensors' first millisecond, as the model's
    torch.testing.assert_close(ref, model, rtol=0, atol=1e-6)  # the CSV's 17 significant digits, filtered


def test_an_unfiltered_comparison_of_a_simulation_read_back_as_a_file_is_exact(cells, sim, tmp_path):
    """``compare_cfc: null`` with the model's own simulation as the test (``cfc: null``): the candidate at the test's
    parameters meets it exactly. The file holds the sampled acceleration (central differences), and its integral is
    the velocity averaged [1, 2, 1] / 4 over neighbouring samples; the candidate was compared as its raw velocity,
    which missed the up-front sensors by a DFD of 2.4 m/s (they stop within 2 ms)."""
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.pulse.simulation import write_crash_csv

    sc = get_scenario("full_width_40")
    result = sim.run(torch.as_tensor(cells.params)[None], sc, record_cells="none")
    path = write_crash_csv(result, tmp_path / "sim.csv")
    channels = {s: f"{s}_acc_g" for s in cells.sensor_names}
    spec = FileReference(path=str(path), scenario=sc.name, channels=channels, cfc=None)
    s = sampler(cells, sim, kind="file", files=[spec], compare_cfc=None)
    ref = s.sample(np.random.default_rng(0), 1).velocity
    torch.testing.assert_close(ref, s.compared(result.velocity), rtol=0, atol=1e-9)
    files = [{"path": str(path), "scenario": sc.name, "channels": channels, "cfc": None}]
    over = {"reference.files": files, "reference.compare_cfc": None}
    problem = build_problem(ProblemConfig(reference="file", env_overrides=over), cells)
    m = problem.evaluate(problem.zeros(1))
    assert float(m.dfd.max()) < 1e-6 and float(m.area.max()) < 1e-9


def test_the_limits_of_a_threshold_time_zero_on_a_simulated_2khz_record(cells, sim, tmp_path):
    """The two limits of ``time_zero: threshold`` the README names, on the model's own simulation at 2 kHz; neither
    is a fault of the record, and ``time_zero: file`` reads both records exactly.

    1. An onset is placed to about a sample: the up-front sensors' first sample (the central difference at the
       contact) already holds 480 g, and the line through the first samples starts 0.56 ms before the contact. The
       velocity change is the same, but sensors that stop within 2 ms then miss their simulation by a DFD of 1.5 m/s.
    2. Zero levels are measured before the earliest onset: the tunnel, read alone, decelerates at 2.6 g from 1.5 ms,
       6 ms before its main pulse and below 5x the noise measured with it, which is taken as its zero level (1.9 m/s of
       its velocity change lost from a record that starts at the contact, 0.45 m/s after 20 ms of rest); read with
       the up-front channels, whose onset is the contact, it keeps all of it.
    """
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.pulse.io import pulse_summary, read_pulse, write_csv
    from marlcrash.pulse.signal import Pulse, find_onset, prepare_velocity

    sc = get_scenario("full_width_40")
    result = sim.run(torch.as_tensor(cells.params)[None], sc, record_cells="none")
    t, acc, names = result.time.double().numpy(), result.acceleration[0].double().numpy(), result.sensor_names
    n = round(0.02 / sc.output_dt)  # 20 ms of rest before the contact
    rest = write_csv(Pulse(np.r_[np.arange(-n, 0) * sc.output_dt, t], np.c_[np.zeros((3, n)), acc], names),
                     tmp_path / "rest.csv")  # fmt: skip
    contact = write_csv(Pulse(t, acc, names), tmp_path / "contact.csv")
    assert -0.75e-3 < find_onset(read_pulse(rest), 60).time < -0.4e-3
    channels = {s: s for s in names}

    def worst_dfd(time_zero):
        files = [{"path": str(rest), "scenario": sc.name, "channels": channels, "time_zero": time_zero}]
        p = build_problem(ProblemConfig(reference="file", env_overrides={"reference.files": files}), cells)
        return float(p.evaluate(p.zeros(1)).dfd.max())

    assert worst_dfd("file") < 1e-6 and worst_dfd("threshold") > 1.0
    for path, lost in ((contact, (1.5, 2.3)), (rest, (0.3, 0.7))):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")  # the up-front sensors' record from the contact: no pre-trigger data
            alone = pulse_summary(path, acc_col="tunnel")
            whole = pulse_summary(path, acc_col="tunnel", time_zero="file")["delta_v_ms"]
            assert lost[0] < whole - alone["delta_v_ms"] < lost[1] and 5.5 < alone["t0_ms"] < 6.5
            # the loss is no longer silent: a warning names the channel and about how much it loses
            named = [re.search(r"channel 'tunnel' is not at rest .* about (\d\.\d+) m/s short", str(w.message))
                     for w in said]  # fmt: skip
            assert [float(m.group(1)) for m in named if m] == [pytest.approx(whole - alone["delta_v_ms"], abs=0.3)]
            said.clear()
            for time_zero in ("threshold", "file"):  # with every channel: the earliest onset is the contact's
                _, v = prepare_velocity(read_pulse(path), time_zero=time_zero)
                assert float(v[2, 0] - v[2, -1]) == pytest.approx(whole, abs=0.01)
            assert not [w for w in said if "is not at rest" in str(w.message)]


def test_a_test_record_with_pre_trigger_samples_and_an_offset_is_the_simulation(cells, sim, tmp_path):
    """A lab export: 20 ms of pre-trigger samples at negative times, t = 0 at the contact, and a 0.3 g transducer
    offset on every sample. With the default ``time_zero: file`` the offset is the pre-trigger mean and is removed
    (integrated, it drifted 0.44 m/s over 150 ms), and the reference is the simulation the record came from. A
    problem calibrating against it (``reference=file``) starts at zero error with the simulated parameters."""
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.pulse.simulation import write_crash_csv

    sc = get_scenario("full_width_40")
    result = sim.run(torch.as_tensor(cells.params)[None], sc, record_cells="none")
    sim_csv = write_crash_csv(result, tmp_path / "sim.csv")
    rows = np.genfromtxt(sim_csv, delimiter=",", names=True)
    t = np.concatenate([np.arange(-40, 0) * sc.output_dt, rows["time_s"]])
    cols = {s: np.concatenate([np.zeros(40), rows[f"{s}_acc_g"]]) + 0.3 for s in cells.sensor_names}
    path = tmp_path / "lab.csv"
    body = "".join(",".join(f"{v:.17g}" for v in (t[i], *(c[i] for c in cols.values()))) + "\n" for i in range(t.size))
    path.write_text("time_s," + ",".join(cols) + "\n" + body)
    channels = {s: s for s in cells.sensor_names}
    spec = FileReference(path=str(path), scenario=sc.name, channels=channels)
    ref = sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity
    torch.testing.assert_close(ref, compared_velocity(result.velocity.double(), sc.output_dt, 60), rtol=0, atol=1e-6)

    files = [{"path": str(path), "scenario": sc.name, "channels": channels}]
    problem = build_problem(ProblemConfig(reference="file", env_overrides={"reference.files": files}), cells)
    m = problem.evaluate(problem.zeros(1))
    assert float(m.area.max()) < 1e-6 and problem.success(m).tolist() == [True]
    with pytest.raises(ConfigError, match=r"set reference=file") as e:  # the kind is the problem's to set
        build_problem(ProblemConfig(env_overrides={"reference.kind": "file", "reference.files": files}), cells)
    assert e.value.key == "env_overrides.reference.kind"


def test_tests_of_several_load_cases_give_each_problem_the_test_of_its_scenario(cells, sim, tmp_path):
    """``reference.files`` with tests of two load cases: ``file_scenario`` draws only one case's tests, and a
    problem (``reference=file``) calibrates against the test of ``problem.scenario``; the seed drew any test by
    weight before, and the problem then simulated that test's load case under its own scenario's name."""
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.pulse.simulation import write_crash_csv

    files = []
    for name in ("full_width_40", "offset40_left"):
        result = sim.run(torch.as_tensor(cells.params)[None], get_scenario(name), record_cells="none")
        path = write_crash_csv(result, tmp_path / f"{name}.csv")
        files.append(FileReference(path=str(path), scenario=name, weight=1.0 + 8 * len(files),
                                   channels={s: f"{s}_acc_g" for s in cells.sensor_names}))  # fmt: skip
    one = sampler(cells, sim, kind="file", files=files, file_scenario="full_width_40")
    ref = one.sample(np.random.default_rng(0), 8)
    assert ref.scenario == ["full_width_40"] * 8 and ref.source == [files[0].path] * 8
    both = sampler(cells, sim, kind="file", files=files).sample(np.random.default_rng(0), 64).scenario
    assert set(both) == {"full_width_40", "offset40_left"}
    with pytest.raises(ConfigError, match=r"no test of reference\.files is of scenario 'full_width_56'") as e:
        from_dict(
            ReferenceConfig,
            {"kind": "file", "files": [vars(f) for f in files], "file_scenario": "full_width_56"},
        )
    assert e.value.key == "file_scenario"

    over = {"reference.files": [vars(f) for f in files]}
    for seed in range(3):  # the offset test is 9 in 10 of an unrestricted draw
        problem = build_problem(ProblemConfig(reference="file", reference_seed=seed, env_overrides=over), cells)
        assert problem.reference.source == [files[0].path]
        assert float(problem.evaluate(problem.zeros(1)).area.max()) < 1e-6
    with pytest.raises(ConfigError, match=r"no test of reference\.files is of scenario 'full_width_56'") as e:
        build_problem(ProblemConfig(reference="file", scenario="full_width_56", env_overrides=over), cells)
    assert e.value.key == "problem.scenario"


def test_an_env_on_the_tests_of_one_scenario_simulates_at_that_scenarios_rate(cells, tmp_path, monkeypatch):
    """The env built its simulator at the output rate of ``reference.files[0]``'s scenario, not of the tests
    ``file_scenario`` draws: an env on the tests of a 1 kHz load case, listed after a 2 kHz one, was refused (the
    simulator's output step is not the scenarios')."""
    import shutil

    import yaml

    from marlcrash.config import config_dir
    from marlcrash.envs import load_env_config
    from marlcrash.envs.core import CalibrationCore
    from marlcrash.pulse.simulation import write_crash_csv

    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    data = yaml.safe_load((configs / "scenarios" / "full_width_40.yaml").read_text())
    (configs / "scenarios" / "full_width_40_1khz.yaml").write_text(
        yaml.safe_dump({**data, "name": "full_width_40_1khz", "output_rate": 1000.0})
    )
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    files = []
    for name in ("full_width_40", "full_width_40_1khz"):
        sc = get_scenario(name)
        result = Surrogate(cells, output_dt=1.0 / sc.output_rate).run(torch.as_tensor(cells.params)[None], sc)
        path = write_crash_csv(result, tmp_path / f"{name}.csv")
        files.append({"path": str(path), "scenario": name, "channels": {s: f"{s}_acc_g" for s in cells.sensor_names}})
    for name, rate in (("full_width_40_1khz", 1000.0), ("full_width_40", 2000.0)):
        over = {"reference.kind": "file", "reference.files": files, "reference.file_scenario": name}
        core = CalibrationCore(load_env_config("default", over), batch_size=2, cells=cells)
        assert core.sim.output_dt == pytest.approx(1.0 / rate) and core.dt == pytest.approx(1.0 / rate)
        core.reset(seed=0)
        assert float(core.metrics[0].max()) < 1e-6  # the initial parameters are the tests' own simulation


def test_a_file_scenario_with_another_reference_kind_is_refused_naming_the_key():
    """``reference.file_scenario`` picks among the measured tests: with ``kind: twin`` it was read by nothing and
    loaded without a word, and a problem's ``env_overrides.reference.file_scenario`` was replaced by
    ``problem.scenario`` as silently. Both are refused, naming the key. A run that trained on one scenario's tests
    is still evaluated (and its problem built) on a twin: the evaluation drops the training's choice of test."""
    from marlcrash.calibrate.evaluate import evaluation_overrides
    from marlcrash.calibrate.marl import TrainConfig, make_env_config
    from marlcrash.calibrate.problem import ProblemConfig, problem_env_config
    from marlcrash.envs.core import load_env_config

    with pytest.raises(ConfigError, match=r"only with kind 'file'.*kind is 'twin'") as e:
        load_env_config("default", {"reference.file_scenario": "full_width_40"})
    assert e.value.key == "reference.file_scenario"
    files = [{"path": "test.csv", "scenario": "full_width_40", "channels": {"s": "c"}}]
    measured = {"reference.kind": "file", "reference.files": files, "reference.file_scenario": "full_width_40"}
    assert load_env_config("default", measured).reference.file_scenario == "full_width_40"
    chosen = {"reference.files": files, "reference.file_scenario": "full_width_40"}
    with pytest.raises(ConfigError, match=r"set by scenario") as e:
        ProblemConfig(reference="file", env_overrides=chosen).validate()
    assert e.value.key == "env_overrides.reference.file_scenario"
    run = TrainConfig(env_overrides=measured, name="r")
    run.eval.reference = "twin"
    env = make_env_config(run, evaluation_overrides(run))
    assert (env.reference.kind, env.reference.file_scenario) == ("twin", None)
    over = {k: v for k, v in measured.items() if k != "reference.file_scenario"}
    env = problem_env_config(ProblemConfig(reference="twin", env_overrides={**over, "reference.kind": "twin"}))
    assert env.reference.file_scenario is None
    assert problem_env_config(ProblemConfig(reference="file", env_overrides=over)).reference.file_scenario == (
        "full_width_40"
    )


def test_a_test_record_that_goes_on_past_the_window_is_compared_as_filtered_over_it(cells, sim, tmp_path):
    """A test's record goes on past the compared window, and the filter ran over all of it; candidates are
    simulated ``compare_margin`` (10 ms) longer, filtered, and cut alike. The model's own 200 ms small-overlap
    simulation as the test: at its parameters the problem and the environment now fit it to a DFD of 0.002-0.015
    m/s over 150 and 30 ms windows; filtered only up to the window's end, the candidate missed it by 0.18 and
    3.3 m/s (the front is still crushing at 30 ms), the paper's DFD mark being 0.335."""
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.envs.core import CalibrationCore, load_env_config
    from marlcrash.pulse.simulation import write_crash_csv

    sc = get_scenario("small_overlap_left")
    channels = {s: f"{s}_acc_g" for s in cells.sensor_names}
    long = sim.run(torch.as_tensor(cells.params)[None], sc, duration=0.2, record_cells="none")
    files = [FileReference(path=str(write_crash_csv(long, tmp_path / "long.csv")), scenario=sc.name,
                           channels=channels)]  # fmt: skip
    at_window = sim.run(torch.as_tensor(cells.params)[None], sc, record_cells="none")
    files.append(FileReference(path=str(write_crash_csv(at_window, tmp_path / "window.csv")), scenario=sc.name,
                               channels=channels, weight=1e-9))  # fmt: skip
    s = sampler(cells, sim, kind="file", files=files)
    assert s.max_margin == 20  # 10 ms at 2 kHz; a record that ends at the window has none:
    assert sampler(cells, sim, kind="file", files=files[1:]).sample(np.random.default_rng(0), 1).margin.tolist() == [0]
    ref = s.sample(np.random.default_rng(0), 2)
    assert ref.margin.tolist() == [20, 20] and ref.velocity.shape[-1] == sc.n_outputs
    assert ref.repeat(3).margin.tolist() == [20] * 3
    # unfiltered, only the acceleration's central difference at the window's last sample needs the sample after it
    raw = [FileReference(**{**vars(files[0]), "cfc": None})]
    assert sampler(cells, sim, kind="file", files=raw, compare_cfc=None).max_margin == 1

    def problem(duration, margin, file=0):
        over = {"reference.files": [vars(files[file])], "reference.compare_margin": margin}
        return build_problem(ProblemConfig(scenario=sc.name, reference="file", duration=duration,
                                           env_overrides=over), cells)  # fmt: skip

    for duration, fits, misses in ((None, 0.003, 0.1), (0.03, 0.02, 3.0)):
        p = problem(duration, 0.01)
        assert p.margin == 20 and p.sim_duration == pytest.approx(p.duration + 0.01)
        assert float(p.evaluate(p.zeros(1)).dfd.max()) < fits
        assert float(problem(duration, 0.0).evaluate(p.zeros(1)).dfd.max()) > misses
    unfiltered = {"reference.files": [{**vars(files[0]), "cfc": None}], "reference.compare_cfc": None}
    for duration in (None, 0.03):  # the candidate's last sample was a backward difference: a DFD of 0.017 and 0.62
        p = build_problem(ProblemConfig(scenario=sc.name, reference="file", duration=duration,
                                        env_overrides=unfiltered), cells)  # fmt: skip
        assert p.margin == 1 and float(p.evaluate(p.zeros(1)).dfd.max()) < 1e-6
    unfiltered["reference.compare_margin"] = 0.0  # no margin asked: none
    assert build_problem(ProblemConfig(scenario=sc.name, reference="file", env_overrides=unfiltered), cells).margin == 0
    short = problem(0.03, 0.01, file=1)  # the window-length record still goes on past a 30 ms window
    assert short.margin == 20 and float(short.evaluate(short.zeros(1)).dfd.max()) < 0.02
    full = problem(None, 0.01, file=1)
    assert full.margin == 0 and float(full.evaluate(full.zeros(1)).area.max()) < 1e-6

    env = load_env_config(overrides={"reference.kind": "file", "reference.files": [vars(f) for f in files[:1]]})
    core = CalibrationCore(env, 2, cells)
    core.reset(seed=0)
    assert core.margin.tolist() == [20, 20] and float(core.metrics.dfd.max()) < 0.003
    fraction, saturated = core.energy_fraction.clone(), core.saturated.clone()
    env.reference.compare_margin = 0.0
    core = CalibrationCore(env, 2, cells)
    core.reset(seed=0)
    assert core.margin.tolist() == [0, 0] and float(core.metrics.dfd.max()) > 0.1
    # the observed energy fractions and saturation are the window's end, margin or not
    torch.testing.assert_close(core.energy_fraction, fraction, rtol=1e-9, atol=1e-12)
    assert torch.equal(core.saturated, saturated)
    with pytest.raises(ConfigError, match=r"expected a duration in \[0, 0.1\] s, got -0.01") as e:
        from_dict(ReferenceConfig, {"compare_margin": -0.01})
    assert e.value.key == "compare_margin"


def test_compared_window_filters_each_row_over_its_margin():
    v = 10.0 - torch.cumsum(torch.rand(3, 2, 60, dtype=torch.float64), -1) * 0.1
    got = compared_window(v, 5e-4, 60, 40, torch.tensor([0, 20, 5]))
    for row, m in enumerate((0, 20, 5)):
        torch.testing.assert_close(got[row], compared_velocity(v[row, :, : 40 + m], 5e-4, 60)[:, :40], rtol=0, atol=0)
    same = compared_window(v, 5e-4, 60, 40, torch.tensor([20, 20, 20]))
    torch.testing.assert_close(compared_window(v, 5e-4, 60, 40, 20), same, rtol=0, atol=0)
    assert not torch.equal(got[0], compared_window(v, 5e-4, 60, 40, 20)[0])  # the margin changes the window
    with pytest.raises(PulseError, match="a window of 40 samples and a margin of 30 need 70 samples, got 60"):
        compared_window(v, 5e-4, 60, 40, torch.tensor([0, 30, 0]))
    with pytest.raises(PulseError, match=r"margins are samples past the window, >= 0; got \[0, -1, 0\]"):
        compared_window(v, 5e-4, 60, 40, torch.tensor([0, -1, 0]))
    with pytest.raises(PulseError, match=r"per row of the \(3, 2, 60\) velocities, got margins of shape \(2,\)"):
        compared_window(v, 5e-4, 60, 40, torch.tensor([0, 1]))
    # the loader and the problem count a margin's samples alike, whatever the float rounding of the seconds
    assert [margin_samples(x, 2000.0) for x in (0.01, 0.0099999999, 0.03 - 0.02, 0.00049, 0.0)] == [20, 20, 20, 0, 0]
    # unfiltered (compare_cfc null), only the central difference at the window's last sample reaches past it
    assert [margin_samples(x, 2000.0, None) for x in (0.01, 0.0005, 0.00049)] == [1, 1, 0]


def test_file_reference_settings_that_cannot_line_up_are_refused(cells, sim, tmp_path):
    spec = {"path": "nope.csv", "scenario": "full_width_40", "channels": dict.fromkeys(cells.sensor_names, "a")}
    with pytest.raises(ConfigError, match=r"expected the compared signal's class, compare_cfc = 60") as e:
        from_dict(ReferenceConfig, {"kind": "file", "files": [{**spec, "cfc": 180}]})
    assert e.value.key == "files[0].cfc"
    from_dict(ReferenceConfig, {"kind": "file", "compare_cfc": 180, "files": [{**spec, "cfc": 180}]})
    for cfc in (100, 0):  # not a class: named as compare_cfc, not as the test's cfc that matches the default
        with pytest.raises(ConfigError, match=rf"expected a CFC class \(60, 180, 600, 1000\) or null, got {cfc}") as e:
            from_dict(ReferenceConfig, {"kind": "file", "compare_cfc": cfc, "files": [spec]})
        assert e.value.key == "compare_cfc"
    with pytest.raises(ConfigError, match=r"unknown scenario 'full_width_30'; registered: \[") as e:
        from_dict(ReferenceConfig, {"kind": "file", "files": [{**spec, "scenario": "full_width_30"}]})
    assert e.value.key == "files[0].scenario"  # was 'scenario', when the env was built
    with pytest.raises(ConfigError, match=r"no such file or ISO-MME folder: .*nope\.csv") as e:
        sampler(cells, sim, kind="file", files=[FileReference(**spec)])
    assert e.value.key == "reference.files[0].path"


def test_a_test_that_leaves_the_vehicle_moving_is_warned_about_naming_scenario_and_units(cells, sim, tmp_path):
    """A reference whose velocity change is far too small loaded without a word: accelerations in mm/ms^2 read as
    g (0.1 of 11.1 m/s), or a 40 km/h test under a 56 km/h scenario (still at 5.6 m/s after 150 ms against a rigid
    wall). A channel still above a quarter of the impact speed at its slowest is warned about, naming the keys to
    check; a test that stops the vehicle is not."""
    rate, width = 10_000.0, 0.08
    t = np.arange(0.0, 0.16, 1.0 / rate)

    def spec(name, dv):
        acc_g = -np.where(t <= width, np.sin(np.pi * t / width), 0.0) * dv * np.pi / (2 * width) / 9.80665
        path = tmp_path / f"{name}.csv"
        path.write_text("time_s,acc_g\n" + "".join(f"{a:.5f},{b:.9g}\n" for a, b in zip(t, acc_g, strict=True)))
        return FileReference(path=str(path), scenario="full_width_40", channels=dict.fromkeys(cells.sensor_names,
                                                                                              "acc_g"))  # fmt: skip

    with pytest.warns(UserWarning, match=r"slow\.csv: channel 'acc_g' is still at 9\.\d+ m/s of the impact speed "
                      r"11\.11 m/s at its slowest in the 150 ms of scenario 'full_width_40': a rigid barrier brings "
                      r"the vehicle to rest .*\(reference\.files\[0\]\.scenario\), its time in another unit "
                      r"\(reference\.files\[0\]\.time_unit: s\) or its acceleration \(reference\.files\[0\]\.unit: "
                      r"g\)\?"):  # fmt: skip
        sampler(cells, sim, kind="file", files=[spec("slow", 2.0)]).sample(np.random.default_rng(0), 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sampler(cells, sim, kind="file", files=[spec("stops", 12.5)]).sample(np.random.default_rng(0), 1)


@pytest.mark.parametrize("peak_g", [30.0, 300.0])
def test_a_sharp_file_pulse_after_pre_trigger_data_keeps_its_whole_velocity_change(cells, sim, tmp_path, peak_g):
    """A 3 ms half-sine after 20 ms of pre-trigger samples at 10 kHz: the reference loses none of its velocity
    change to the filter's spread before time zero (integrated from time zero: 84-88 % of it was left)."""
    rate, width = 10_000.0, 0.003
    t = np.arange(-0.02, 0.16, 1.0 / rate)
    acc_g = np.where((t >= 0) & (t <= width), -peak_g * np.sin(np.pi * np.clip(t, 0, width) / width), 0.0)
    path = tmp_path / "halfsine.csv"
    path.write_text("time_s,acc_g\n" + "".join(f"{a:.9f},{b:.12g}\n" for a, b in zip(t, acc_g, strict=True)))
    spec = FileReference(path=str(path), scenario="full_width_40", channels=dict.fromkeys(cells.sensor_names, "acc_g"))
    v = sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity[0, 0]
    dv = peak_g * 9.80665 * 2 * width / np.pi  # the half-sine's integral
    assert float(40 / 3.6 - v[-1]) == pytest.approx(dv, rel=0.01)  # from the impact speed before the pulse
    assert float(40 / 3.6 - v[0]) > 0.05 * dv  # part of it before time zero, where the filter spread it


def test_file_reference_csv_and_mme_match_the_analytic_half_sine(cells, sim):
    for path, chan in (("halfsine_40kmh.csv", "tunnel_acx"), ("HS40", "10TUNN0000ACXP")):
        spec = FileReference(
            path=str(DATA / path), scenario="full_width_40", channels=dict.fromkeys(cells.sensor_names, chan)
        )
        s = sampler(cells, sim, kind="file", files=[spec])
        ref = s.sample(np.random.default_rng(0), 2)
        v = ref.velocity
        assert v.shape == (2, 3, 301)
        v0 = 40 / 3.6
        assert float((v[:, :, 0] - v0).abs().max()) < 0.02  # the filter spread little of a gentle 80 ms pulse before t0
        # 80 ms half-sine of 40 km/h delta-v: after the pulse the velocity is v0 - 11.111 m/s
        assert abs(float(v[0, 0, 240]) - (v0 - 40 / 3.6)) < 0.1
        # mid-pulse against the analytic integral, allowing the time-zero shift of the 0.5 g trigger
        t = np.arange(301) / 2000.0
        amp = (40 / 3.6) * np.pi / (2 * 0.080)
        t_trig = np.arcsin(0.5 * 9.80665 / amp) * 0.080 / np.pi
        tt = np.clip(t + t_trig, 0, 0.080)
        analytic = (
            v0
            - (40 / 3.6) / 2 * (1 - np.cos(np.pi * tt / 0.080))
            + (40 / 3.6) / 2 * (1 - np.cos(np.pi * t_trig / 0.080))
        )
        assert np.max(np.abs(v[0, 0].numpy() - analytic)) < 0.15


@pytest.mark.parametrize("noise_g", [0.0, 1.0])
def test_a_threshold_reference_of_a_noisy_record_with_an_offset_is_its_pulse(cells, sim, tmp_path, noise_g):
    """A lab export read with ``time_zero: threshold``: 10 ms of pre-trigger samples on a clock without negative
    times, a 0.8 g transducer offset and 1 g rms of white noise on an 80 ms, 30 g half-sine at 10 kHz. The reference
    is the analytic velocity from the impact speed at the onset (clean within 0.03 m/s, noisy within 0.3 m/s over
    the 150 ms). Before, the offset hid the onset: time zero at the first sample, 10 ms early, and the offset
    integrated, 1.2 m/s over 150 ms."""
    rate, pre, tau, amp = 10_000.0, 0.010, 0.080, 30.0
    t = np.arange(round((pre + 0.2) * rate)) / rate
    s = t - pre
    acc_g = np.where((s >= 0) & (s <= tau), -amp * np.sin(np.pi * np.clip(s, 0, tau) / tau), 0.0) + 0.8
    acc_g = acc_g + np.random.default_rng(7).normal(0.0, noise_g, t.size)
    path = tmp_path / "lab.csv"
    path.write_text("time_s,acc_g\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(t, acc_g, strict=True)))
    spec = FileReference(path=str(path), scenario="full_width_40", time_zero="threshold",
                         channels=dict.fromkeys(cells.sensor_names, "acc_g"))  # fmt: skip
    v = sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity[0, 0].numpy()
    tt = np.clip(np.arange(v.size) / 2000.0, 0.0, tau)
    dv = 2 * amp * 9.80665 * tau / np.pi
    analytic = 40 / 3.6 - dv / 2 * (1 - np.cos(np.pi * tt / tau))
    assert np.max(np.abs(v - analytic)) < (0.03 if noise_g == 0 else 0.3)


@pytest.mark.parametrize("start", [1.0, 0.1])
def test_a_file_time_zero_outside_the_record_is_named_as_such(cells, sim, tmp_path, start):
    """A record on a clock that starts after its t = 0 (a logger's clock from 1 s), read with ``time_zero: file``,
    was refused for something else: 'resampling window [0.98, 0.16] s must lie inside the record', or, from 0.1 s,
    'expected 301 samples after time zero, got 160; the record is too short' of a record of 400 ms. Now the time
    zero outside the record is said, with the option that reads such a record; read so, it is the pulse."""
    t = np.arange(0.0, 0.4, 1e-4) + start
    acc_g = np.where((t > start + 0.01) & (t < start + 0.09), -20 * np.sin(np.pi * (t - start - 0.01) / 0.08), 0.0)
    path = tmp_path / "clock.csv"
    path.write_text("time,acc\n" + "".join(f"{a:.5f},{b:.6f}\n" for a, b in zip(t, acc_g, strict=True)))
    spec = {"path": str(path), "scenario": "full_width_40", "channels": dict.fromkeys(cells.sensor_names, "acc")}
    with pytest.raises(PulseError, match=rf"clock\.csv: time zero t = 0 ms \(the file's t = 0, time_zero: file\) "
                       rf"lies outside the record \[{start * 1e3:g}, .*\] ms.*time_zero: threshold"):  # fmt: skip
        sampler(cells, sim, kind="file", files=[FileReference(**spec)])
    v = sampler(cells, sim, kind="file", files=[FileReference(**spec, time_zero="threshold")]).sample(
        np.random.default_rng(0), 1).velocity[0, 0].numpy()  # fmt: skip
    assert v[-1] == pytest.approx(40 / 3.6 - 2 * 20 * 9.80665 * 0.08 / np.pi, abs=0.01)


def test_file_reference_errors(cells, sim, tmp_path):
    spec = FileReference(
        path=str(DATA / "halfsine_40kmh.csv"), scenario="full_width_40", channels={"tunnel": "tunnel_acx"}
    )
    with pytest.raises(ConfigError, match="no channel given for sensors"):
        sampler(cells, sim, kind="file", files=[spec])
    short = tmp_path / "short.csv"
    lines = (DATA / "halfsine_40kmh.csv").read_text().splitlines()
    short.write_text("\n".join(lines[:400]) + "\n")  # 40 ms of a 150 ms window
    spec = FileReference(
        path=str(short), scenario="full_width_40", channels=dict.fromkeys(cells.sensor_names, "tunnel_acx")
    )
    with pytest.raises(PulseError):
        sampler(cells, sim, kind="file", files=[spec])


def test_sampler_config_errors(cells, sim):
    with pytest.raises(ConfigError, match="unknown scenario"):
        sampler(cells, sim, scenarios={"no_such_crash": 1.0})
    with pytest.raises(ConfigError, match="weights"):
        sampler(cells, sim, scenarios={"full_width_40": 0.0})
    with pytest.raises(ConfigError, match="unknown sensors"):
        ReferenceSampler(cells, sim, ["nope"], {"full_width_40": 1.0}, ReferenceConfig())


@pytest.mark.parametrize("output_dt", [2.5e-4, 1e-3])
def test_a_simulator_on_another_output_step_than_the_scenarios_is_refused(cells, output_dt):
    """A 4 kHz simulator gave a 2 kHz scenario's twin 601 samples, filtered as 2 kHz and cut to its first 301 (the
    first 75 ms taken for 150 ms) without a word; a 1 kHz one failed in the filter's window check."""
    with pytest.raises(ConfigError, match=r"output_dt.*2000 Hz"):
        ReferenceSampler(cells, Surrogate(cells, output_dt=output_dt), list(cells.sensor_names),
                         {"full_width_40": 1.0}, ReferenceConfig())  # fmt: skip


@pytest.mark.parametrize(
    ("kw", "key"),
    [
        ({"kind": "bogus"}, "reference.kind"),  # was an IndexError at sample() (drawn as a file reference)
        ({"twin": TwinConfig(e_x_spread=-0.5)}, "reference.twin.e_x_spread"),  # was taken: a mirrored draw
        ({"twin": TwinConfig(e_s_spread=float("nan"))}, "reference.twin.e_s_spread"),
        ({"pin_seed": -1}, "reference.pin_seed"),
        ({"cross_fidelity": CrossFidelityConfig(vehicle_seeds=[-2])}, "reference.cross_fidelity.vehicle_seeds"),
    ],
)
def test_a_reference_config_made_in_python_is_checked_naming_the_key(cells, sim, kw, key):
    with pytest.raises(ConfigError, match=re.escape(key)):
        sampler(cells, sim, **kw)


@pytest.mark.parametrize(("volume", "words"), [(0.05, "'solid_target_cell_volume'"), (2.5, "exceeds roi_depth")])
def test_a_fine_cell_volume_cells_yaml_refuses_is_named_as_the_env_key_when_loaded(volume, words):
    """``reference.cross_fidelity.target_cell_volume`` was checked only as > 0: 0.05 m^3 loaded, and the first
    cross-fidelity reference (the env built, a run folder made) failed as cells.yaml's ``solid_target_cell_volume``,
    a key and a file the user had not touched."""
    from marlcrash.envs.core import load_env_config

    key = "reference.cross_fidelity.target_cell_volume"
    with pytest.raises(ConfigError, match=words) as e:
        load_env_config("default", {key: volume})
    assert e.value.key == key and Path(e.value.path).name == "default.yaml"
    assert load_env_config("default", {key: 1e-4}).reference.cross_fidelity.target_cell_volume == 1e-4


def test_fine_model_substeps_that_miss_a_scenarios_output_step_are_named_when_loaded(tmp_path, monkeypatch):
    """``reference.cross_fidelity.substeps`` was checked only as an integer in [1, 1000]: 25 steps per 0.5 ms with a
    4 kHz scenario loaded, and the first cross-fidelity reference (the env built) failed in the fine model's simulator,
    naming configs/sim.yaml's substeps, a value the user had not touched."""
    import shutil

    from marlcrash.config import config_dir
    from marlcrash.envs.core import load_env_config

    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    path = configs / "scenarios" / "full_width_40.yaml"
    path.write_text(path.read_text().replace("output_rate: 2000.0", "output_rate: 4000.0"))
    monkeypatch.setenv("MARLCRASH_CONFIGS", str(configs))
    over = {"scenarios": {"full_width_40": 1.0}, "reference.kind": "cross_fidelity"}
    with pytest.raises(ConfigError, match=r"full_width_40.*4000 Hz") as e:
        load_env_config("default", {**over, "reference.cross_fidelity.substeps": 25})
    assert e.value.key == "reference.cross_fidelity.substeps" and Path(e.value.path).name == "default.yaml"
    assert load_env_config("default", {**over, "reference.cross_fidelity.substeps": 24})  # 6 steps per output
    assert load_env_config("default", {**over, "reference.kind": "twin", "reference.cross_fidelity.substeps": 25})


def test_cross_fidelity_reference_uses_the_uniform_model(cells, sim):
    s = sampler(cells, sim, kind="cross_fidelity", scenarios={"full_width_40": 1.0, "offset40_left": 1.0})
    ref = s.sample(np.random.default_rng(1), 4)
    fine, _ = s.fine_model(None)
    assert fine.method == "uniform" and fine.n_cells > 5 * cells.n_cells
    assert ref.true_params is None and ref.velocity.shape == (4, 3, 301)
    assert torch.allclose(ref.raw_velocity[:, :, 0], ref.speed[:, None].expand(4, 3))
    own = sim.run(torch.as_tensor(cells.params)[None], get_scenario("full_width_40"), record_cells="none")
    row = ref.scenario.index("full_width_40")
    assert (ref.velocity[row] - own.velocity[0]).abs().max() > 0.1  # a genuinely different model
    # cached and deterministic per scenario
    again = s.sample(np.random.default_rng(1), 4)
    torch.testing.assert_close(ref.velocity, again.velocity, rtol=0, atol=0)


def test_the_cross_fidelity_reference_of_a_vehicle_variant_is_that_variant(monkeypatch):
    """With ``vehicle_seed: 1`` the calibrated model is variant 1, but its cross-fidelity reference (``vehicle_seeds:
    [null]``, the default) was the uniform model of the nominal car: another car (8939 cells against the variant's
    8927), so the calibration chased a vehicle it is not. A null entry is now the calibrated car's own variant, in the
    env and in a baseline's problem, and the fine model is built (and kept) once per variant."""
    from marlcrash.calibrate.problem import ProblemConfig, build_problem
    from marlcrash.envs.core import CalibrationCore, load_env_config

    seeded = build_cells("b_segment", 1, "optimized")
    variant = build_cells("b_segment", 1, "uniform")
    seen = []

    def simulated(self, seed, scenario):  # the fine model each reference is drawn from, without simulating it
        seen.append(self.fine_model(seed)[0])
        return np.full((len(self.sensors), self.n_outputs), self.scenarios[scenario].speed)

    monkeypatch.setattr(ReferenceSampler, "_fine_reference", simulated)
    over = {"vehicle_seed": 1, "reference.kind": "cross_fidelity", "scenarios": {"full_width_40": 1.0}}
    core = CalibrationCore(load_env_config(overrides=over), 1, seeded)
    ref = core.sampler.sample(np.random.default_rng(0), 1)
    problem = build_problem(ProblemConfig(reference="cross_fidelity", env_overrides={"vehicle_seed": 1}), seeded)
    assert ref.source == problem.reference.source == ["uniform:seed=1"]
    for fine in seen:
        assert fine.name == variant.name == seeded.name == "b_segment_seed1"
        assert fine.n_cells == variant.n_cells and np.array_equal(fine.centroid, variant.centroid)
        assert np.array_equal(fine.mass, variant.mass) and np.array_equal(fine.params, variant.params)
    assert len(seen) == 2
    both = ReferenceSampler(seeded, core.sim, list(seeded.sensor_names), {"full_width_40": 1.0},
                            ReferenceConfig(kind="cross_fidelity", cross_fidelity=CrossFidelityConfig(
                                vehicle_seeds=[None, 1, 2])), vehicle_seed=1)  # fmt: skip
    assert both.fine_model(None) is both.fine_model(1)  # one variant, one fine model
    assert both.fine_model(2)[0].name == "b_segment_seed2"


def test_the_fine_reference_has_its_own_mass_scaling_and_step(cells, sim):
    """The fine model's light cells under the calibrated model's mass floor (0.5 kg) would take 1102 kg of the
    1324 kg compartment into the crush zone and peak at 115 g; its own floor and step keep the added mass small and
    the full-width pulse near the one of a finer integration (independent of the pair chosen)."""
    from dataclasses import replace

    from marlcrash.pulse.simulation import crash_summary
    from marlcrash.references import CrossFidelityConfig

    own = CrossFidelityConfig()
    rigid = float(cells.mass[cells.is_rigid.astype(bool)].sum())
    peaks = {}
    for label, cf in (("sim", replace(own, mass_floor=None, substeps=None)), ("own", own),
                      ("finer", replace(own, mass_floor=0.02, substeps=40))):  # fmt: skip
        fine, fsim = sampler(cells, sim, kind="cross_fidelity", cross_fidelity=cf).fine_model(None)
        assert fsim.config.mass_floor == (sim.config.mass_floor if cf.mass_floor is None else cf.mass_floor)
        assert fsim.dt == pytest.approx(5e-4 / (sim.config.substeps if cf.substeps is None else cf.substeps))
        sc = get_scenario("full_width_40")
        res = fsim.run(torch.as_tensor(fine.params)[None], sc, record_cells="none")
        peaks[label] = (fsim.mass_added, crash_summary(res, fine, sc)["peak_decel_g"])
    assert peaks["sim"][0] > 0.5 * rigid and peaks["own"][0] < 0.05 * rigid
    assert peaks["sim"][1] > 1.5 * peaks["finer"][1]  # the scaled reference is a different pulse
    assert peaks["own"][1] == pytest.approx(peaks["finer"][1], rel=0.1)
    for key, value in (("mass_floor", -1.0), ("mass_floor", "light"), ("substeps", 0), ("substeps", 2.5)):
        with pytest.raises(ConfigError, match=key):
            replace(own, **{key: value}).validate()


def test_file_reference_checks_its_rate_and_reads_breakpoints(cells, sim, tmp_path):
    channels = dict.fromkeys(cells.sensor_names, "acc")
    corners = [(0.0, 0.0), (0.002, 0.0), (0.012, -20.0), (0.062, -20.0), (0.082, 0.0), (0.3, 0.0)]
    table = tmp_path / "corners.csv"
    table.write_text("time,acc\n" + "".join(f"{t:g},{a:g}\n" for t, a in corners))
    dense = tmp_path / "dense.csv"  # the same trapezoid written out at 10 kHz
    t = np.arange(3001) / 1e4
    acc = np.interp(t, *zip(*corners, strict=True))
    dense.write_text("time,acc\n" + "".join(f"{a:.4f},{b:.12g}\n" for a, b in zip(t, acc, strict=True)))
    refs, short = [], []
    for path, extra in ((dense, {}), (table, {"breakpoints": True})):
        spec = FileReference(
            path=str(path), scenario="full_width_40", channels=channels, time_zero="threshold", **extra
        )
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            refs.append(sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity)
        short.append(any(SHORT_PRE_TRIGGER in str(w.message) for w in said))
    torch.testing.assert_close(refs[1], refs[0], rtol=0, atol=1e-9)
    # 2 ms before the rise: too short to measure a record's zero level (said), exact for corners (nothing to say)
    assert short == [True, False]
    rect = tmp_path / "rect.csv"  # drawn from its first row: time zero there, its plateau no transducer offset
    rect.write_text("time,acc\n0,-20\n0.05,-20\n0.05,0\n0.3,0\n")
    got = []
    for time_zero in ("file", "threshold"):
        spec = FileReference(path=str(rect), scenario="full_width_40", channels=channels, time_zero=time_zero,
                             breakpoints=True)  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got.append(sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity)
    torch.testing.assert_close(got[1], got[0], rtol=0, atol=1e-9)
    in_ms = tmp_path / "in_ms.csv"  # a record in ms, configured as seconds: 1000x delta-v unless refused
    in_ms.write_text("time,acc\n" + "".join(f"{a * 1e3:.1f},{b:.12g}\n" for a, b in zip(t, acc, strict=True)))
    spec = FileReference(path=str(in_ms), scenario="full_width_40", channels=channels)
    with pytest.raises(PulseError, match=r"in_ms\.csv: sampling rate 10 Hz .*time_unit: ms"):
        sampler(cells, sim, kind="file", files=[spec])
    for key, value in (("unit", "km/h"), ("time_unit", "sec")):
        with pytest.raises(ConfigError) as e:
            FileReference(path="x.csv", scenario="full_width_40", channels=channels, **{key: value}).validate()
        assert e.value.key == key
    for unit in ("G", "mm/s2", "m/s^2"):  # every spelling the reader takes
        FileReference(path="x.csv", scenario="full_width_40", channels=channels, unit=unit).validate()


def test_file_margin_benchmark_prints_its_rows_as_json():
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_file_margin.py"
    cmd = [sys.executable, str(script), "--scenarios", "full_width_40", "--durations", "0.03",
           "--margins", "0", "0.01", "--record", "0.17", "--json"]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert [(r["margin_s"], r["margin_samples"]) for r in rows] == [(0.0, 0), (0.01, 20)]
    assert rows[1]["dfd"] < rows[0]["dfd"] / 10  # the margin is what closes the window-end gap
    cmd[cmd.index("--record") + 1] = "0.1"  # a test record must cover the scenario's window, 150 ms
    bad = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2 and "shorter than full_width_40's window 0.15 s" in bad.stderr


def test_cross_fidelity_benchmark_prints_its_rows_as_json():
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_cross_fidelity.py"
    cmd = [sys.executable, str(script), "--scenarios", "full_width_40", "--fine", "0.05", "24", "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["sensors"] == ["upfront_left", "upfront_right", "tunnel"]
    by = {r["reference"].split(" (")[0]: r for r in got["rows"]}
    assert by["env config"]["to_fine_rmse"] == 0.0  # the "finer" pair given is the env config's own
    assert by["sim.yaml"]["added_kg"] > 20 * by["env config"]["added_kg"] and by["sim.yaml"]["to_fine_rmse"] > 0.5
    assert all(len(r["gap_rmse"]) == 3 for r in got["rows"])


@pytest.mark.parametrize("dt", [0.0, -5e-4, float("nan"), float("inf"), "5e-4", None, True])
def test_the_compared_signal_refuses_a_step_that_is_not_a_positive_number_of_seconds(dt):
    """A step of 0 raised ZeroDivisionError, a negative one torch's 'negative dimension', NaN 'cannot convert float
    NaN to integer'; sampled_acceleration returned inf for 0. Each now names dt and what was expected."""
    from marlcrash.pulse.signal import sampled_acceleration

    v = 10.0 - torch.cumsum(torch.rand(2, 60, dtype=torch.float64), -1) * 0.1
    for call in (lambda: compared_velocity(v, dt, 60), lambda: sampled_acceleration(v, dt),
                 lambda: compared_window(v[None], dt, 60, 40, 5)):  # fmt: skip
        with pytest.raises(PulseError, match=r"dt > 0 \[s\]"):
            call()


def test_the_compared_signal_takes_a_step_given_as_a_tensor_or_numpy_number():
    """``result.time[1] - result.time[0]`` is a 0-d tensor: it raised "type Tensor doesn't define __round__"."""
    v = 10.0 - torch.cumsum(torch.rand(2, 60, dtype=torch.float64), -1) * 0.1
    want = compared_velocity(v, 5e-4, 60)
    torch.testing.assert_close(compared_velocity(v, torch.tensor(5e-4, dtype=torch.float64), 60), want, rtol=0, atol=0)
    torch.testing.assert_close(compared_velocity(v, np.float64(5e-4), 60), want, rtol=0, atol=0)


def test_the_compared_signal_names_the_velocity_it_expected():
    """A 0-d tensor raised IndexError from deep inside, a numpy array torch's "expected Tensor as element 0"."""
    from marlcrash.pulse.signal import sampled_acceleration

    for call in (compared_velocity, sampled_acceleration):
        with pytest.raises(PulseError, match=r"expected velocity as a \[\.\.\., T\] tensor.*got a scalar"):
            call(torch.tensor(11.0), 5e-4)
        with pytest.raises(PulseError, match=r"expected velocity as a \[\.\.\., T\] tensor.*got ndarray"):
            call(np.full(60, 11.0), 5e-4)
    with pytest.raises(PulseError, match=r"expected real velocity.*complex"):
        compared_velocity(torch.ones(60, dtype=torch.complex128), 5e-4)


@pytest.mark.parametrize("n", [0, -3, 2.5, True, "40"])
def test_compared_window_refuses_a_window_that_is_not_a_whole_number_of_samples(n):
    """``n = -3`` returned 24 of 30 samples (a slice from the end), ``n = 0`` named the acceleration's 2 samples."""
    v = 10.0 - torch.cumsum(torch.rand(2, 1, 30, dtype=torch.float64), -1) * 0.1
    with pytest.raises(PulseError, match=r"expected the window n as a whole number of samples >= 1"):
        compared_window(v, 5e-4, 60, n)


@pytest.mark.parametrize("margin", [2.5, True, torch.tensor([1.0, 2.0]), [0.5, 1]])
def test_compared_window_refuses_margins_that_are_not_whole_numbers_of_samples(margin):
    """A margin of 2.5 was cut to 2 samples (and True taken as 1) without a word."""
    v = 10.0 - torch.cumsum(torch.rand(2, 1, 30, dtype=torch.float64), -1) * 0.1
    with pytest.raises(PulseError, match=r"expected margins as whole numbers of samples"):
        compared_window(v, 5e-4, 60, 20, margin)
    torch.testing.assert_close(compared_window(v, 5e-4, 60, 20, np.int64(2)), compared_window(v, 5e-4, 60, 20, 2))


def test_an_iso_mme_file_reference_takes_the_units_its_config_check_takes(cells, sim):
    """``unit: G`` passed the config check (units in any case, as the CSV reader takes them) and was then refused
    reading an ISO-MME test ("do not pass unit='G'"); a unit an ISO-MME test cannot take (its channels carry their
    own ``Unit`` and time base) is refused naming the key, not as a PulseError of the reader."""
    channels = dict.fromkeys(cells.sensor_names, "10TUNN0000ACXP")
    ref = {}
    for unit in ("g", "G", " g"):
        spec = FileReference(path=str(DATA / "HS40"), scenario="full_width_40", channels=channels, unit=unit)
        spec.validate()
        ref[unit] = sampler(cells, sim, kind="file", files=[spec]).sample(np.random.default_rng(0), 1).velocity
    torch.testing.assert_close(ref["G"], ref["g"], rtol=0, atol=0)
    torch.testing.assert_close(ref[" g"], ref["g"], rtol=0, atol=0)
    for key, value in (("unit", "m/s2"), ("time_unit", "ms")):
        spec = FileReference(path=str(DATA / "HS40"), scenario="full_width_40", channels=channels, **{key: value})
        spec.validate()  # the check cannot tell a folder from a CSV file without looking: at the read
        with pytest.raises(ConfigError, match=r"ISO-MME .* carry their own") as e:
            sampler(cells, sim, kind="file", files=[spec])
        assert e.value.key == f"reference.files[0].{key}"
    spec = FileReference(path=str(DATA / "HS40"), scenario="full_width_40", channels=channels, breakpoints=True)
    with pytest.raises(ConfigError, match=r"applies to CSV files only") as e:
        sampler(cells, sim, kind="file", files=[spec])
    assert e.value.key == "reference.files[0].breakpoints"


@pytest.mark.parametrize("sign", [True, False, np.bool_(True), 0.5, "1"])
def test_a_file_reference_sign_that_is_no_plus_or_minus_one_is_refused_naming_the_key(sign):
    # True == 1.0 passed validate() and was refused only by the reader, in a message without the config key
    spec = FileReference(path="x.csv", scenario="full_width_40", channels={"tunnel": "acc"}, sign=sign)
    with pytest.raises(ConfigError, match=r"key 'sign': expected \+1 or -1") as e:
        spec.validate()
    assert e.value.key == "sign"
    for good in (1, -1, 1.0, -1.0, np.float64(-1.0)):
        FileReference(path="x.csv", scenario="full_width_40", channels={"tunnel": "acc"}, sign=good).validate()


@pytest.mark.parametrize("key", ["weight", "threshold_g"])
@pytest.mark.parametrize("bad", [float("inf"), float("nan"), True])
def test_a_file_references_weight_and_onset_threshold_are_finite_numbers(key, bad):
    """A test's ``weight`` and its onset ``threshold_g`` of ``.inf`` passed the check (> 0): the weight was refused
    later under the env's ``scenarios`` key, the threshold found no onset in any record; ``true`` passed as 1."""
    from marlcrash.errors import ConfigError

    f = FileReference(path="x.csv", scenario="full_width_40", channels={"tunnel": "a"}, **{key: bad})
    with pytest.raises(ConfigError, match=f"expected a finite number > 0.*got {bad!r}") as e:
        f.validate()
    assert e.value.key == key


@pytest.mark.parametrize("pre_time", ["0.02", None, True, float("nan")])
def test_a_lead_in_that_is_not_a_duration_is_refused_by_name(pre_time):
    """Text or None as ``pre_time`` raised math.isfinite's TypeError ('must be real number'), naming nothing, and
    True was taken as a lead-in of 1 s."""
    with pytest.raises(PulseError, match="pre_time"):
        compared_velocity(torch.linspace(11.0, 0.0, 60, dtype=torch.float64), 5e-4, 60, pre_time=pre_time)


def test_a_reference_count_or_seed_that_is_no_natural_number_is_named(cells, sim):
    """``sample(rng, 0)`` failed in the simulator's parameter check, ``pinned(-1, n)`` in numpy ("expected
    non-negative integer"): the arguments are named."""
    s = sampler(cells, sim)
    for call, name in (
        (lambda: s.sample(np.random.default_rng(0), 0), "n"),
        (lambda: s.sample(np.random.default_rng(0), 2.0), "n"),
        (lambda: s.pinned(-1, 2), "seed"),
        (lambda: s.pinned(0, 0), "n"),
    ):
        with pytest.raises(ValueError, match=rf"expected {name} as an integer >= [01], got"):
            call()
    assert s.pinned(np.int64(3), 2).velocity.shape[0] == 2
