"""The benchmark library function: keys, consistency of its ratios, and the float32 fast path."""

from __future__ import annotations

import time

import pytest
import torch

from marlcrash.calibrate.baselines import MAX_BATCH
from marlcrash.errors import ConfigError
from marlcrash.sim.bench import (
    PARTIAL,
    device_study,
    dtype_study,
    format_device_study,
    format_dtype_study,
    format_implicit_study,
    format_lane_study,
    format_noalias_study,
    format_substep_study,
    implicit_study,
    lane_study,
    noalias_study,
    plausibility_checks,
    run_benchmark,
    substep_study,
)
from marlcrash.sim.scenario import get_scenario


@pytest.mark.slow
def test_run_benchmark_small_batches_reports_consistent_ratios():
    res = run_benchmark(batch_sizes=(1, 4), repeats=1, include_uniform=False)
    for key in ("sims_per_s_optimized", "link_updates_per_s", "overhead_share", "roofline_sims_per_s"):
        assert key in res, key
    assert set(res["sims_per_s_optimized"]) == {"1", "4"}
    assert res["steps_per_sim"] == 300 * res["substeps"]
    for b, rate in res["sims_per_s_optimized"].items():
        assert rate > 0
        # link updates are rate x steps x links, measured from the same timing
        assert res["link_updates_per_s"][b] == pytest.approx(rate * res["steps_per_sim"] * res["n_links_live"])
        assert 0.0 <= res["overhead_share"][b] < 1.0
    assert res["roofline_ratio"] == pytest.approx(res["sims_per_s_optimized"]["4"] / res["roofline_sims_per_s"])
    assert res["sims_per_s_uniform_b64"] is None
    assert 0 < res["n_links_live"] < res["n_links_optimized"]  # the default car has zero-share links


@pytest.mark.parametrize(
    ("batch_sizes", "key"), [((1, MAX_BATCH + 1), "batch_sizes[1]"), ((0,), "batch_sizes[0]"),
                             ((True,), "batch_sizes[0]"), ((2.5,), "batch_sizes[0]"), ((), "batch_sizes")]
)  # fmt: skip
def test_run_benchmark_refuses_batch_sizes_it_cannot_run_naming_them(batch_sizes, key, monkeypatch):
    # 10**9 ran on into torch's "can't allocate memory"; () into max() of an empty sequence after the timing
    def reached(*args, **kwargs):
        raise AssertionError("the batch sizes were not checked before the car was built")

    monkeypatch.setattr("marlcrash.cells.discretize", reached)
    with pytest.raises(ConfigError) as e:
        run_benchmark(batch_sizes=batch_sizes, repeats=1, include_uniform=False)
    assert e.value.key == key
    if key != "batch_sizes":
        assert f"expected a batch size in [1, {MAX_BATCH}]" in str(e.value)


@pytest.mark.slow
def test_substep_study_grades_variants_and_names_the_fewest_passing_steps():
    res = substep_study(variants=((1, False), (2, False, 2.0), (7, False), (8, False)), batch=4, vehicle_seeds=(2,))
    one, two_scaled, seven, eight = res["rows"]
    assert [r["steps_per_sim"] for r in res["rows"]] == [300, 600, 2100, 2400]
    # the mass floor of a variant is applied and its cost booked: cells of 0.03-0.2 kg raised to 2 kg
    assert two_scaled["mass_floor"] == 2.0 and seven["mass_floor"] == eight["mass_floor"] < 2.0
    assert two_scaled["mass_added_kg"] > 3 * eight["mass_added_kg"] > 0
    # mass scaling does not buy the larger step: 0.25 ms steps with ~900 kg moved into the crush zone
    # still fail (rebound from the capped links, crush and the up-front spikes)
    assert not two_scaled["passed"] and "full_width_40 rebound in [0.05, 0.2]" in two_scaled["failed"]
    # the configured 8 substeps pass every DESIGN 4 check (tests/test_sim_default_car.py grades the same cases)
    assert eight["passed"] and eight["failed"] == []
    # one 0.5 ms step per output sample: the stability cap softens the links, the stored elastic energy
    # comes back as rebound far above the 5-20 % of rigid-wall tests
    assert not one["passed"] and "full_width_40 rebound in [0.05, 0.2]" in one["failed"]
    assert one["figures"]["rebound"] > 0.2
    # 7 substeps pass on the default car too, with more rebound; the fewest passing steps are named
    assert seven["passed"] and seven["figures"]["rebound"] > eight["figures"]["rebound"]
    assert res["needed"] is seven
    assert res["vehicle_seeds"] == [2] and eight["variants_passed"] >= seven["variants_passed"]
    for r in res["rows"]:
        assert r["sims_per_s"] > 0 and r["roofline_sims_per_s"] > 0
    text = format_substep_study(res)
    assert "fewest steps that pass every check on the default car: 2100 (7 substeps" in text
    assert f"mass scaling up to 2 kg per cell ({two_scaled['mass_added_kg']:.0f} kg moved" in text
    assert "springback relief" not in text  # no variant here used it
    assert f"floors up to {res['mass_floor_limit_kg']:.2f} kg" in text


def test_coarser_cells_do_not_buy_a_larger_step():
    """Merging the light sheet-metal cells into heavier ones (a target cell volume 10x ``cells.yaml``'s) gives no
    plausible pulse at a larger step: at 2 substeps the rebound stays far above 20 %, and at the configured 8 the
    coarse front no longer gives partial overlaps their softer, longer pulses (README, Simulator speed)."""
    res = substep_study(variants=((2, False), (8, False)), batch=2, vehicle_seeds=(), target_cell_volume=3e-3)
    assert 60 < res["n_cells"] < 300 and res["target_cell_volume"] == 3e-3  # the default car: 501 cells
    two, eight = res["rows"]
    assert not two["passed"] and two["figures"]["rebound"] > 0.2
    assert not eight["passed"] and any("softer and longer" in f for f in eight["failed"])
    assert res["needed"] is None
    text = format_substep_study(res)
    assert text.startswith(f"cells of 0.003 m^3: {res['n_cells']} cells") and "no step count passes" in text


def test_mass_floor_limit_is_where_the_compartment_runs_out_of_mass(default_cells):
    from marlcrash.errors import ModelError
    from marlcrash.sim import Surrogate
    from marlcrash.sim.bench import load_sim_config, mass_floor_limit

    limit = mass_floor_limit(default_cells)
    sim = Surrogate(default_cells, load_sim_config(overrides={"mass_floor": limit * (1 - 1e-6)}))
    comp = float(default_cells.mass[default_cells.compartment])
    assert sim.mass_added == pytest.approx(comp, rel=1e-4)  # nearly all of it moved to the light cells
    with pytest.raises(ModelError, match=r"more than the compartment.s .* kg can pay for"):
        Surrogate(default_cells, load_sim_config(overrides={"mass_floor": limit * (1 + 1e-6)}))


def test_default_lanes_balances_vector_width_and_cores():
    from marlcrash.sim.kernels import default_lanes

    # large batches: the fastest width per simulation (16 lanes); 32 measured slower per simulation (0.85)
    assert default_lanes(1024, 2) == default_lanes(128, 2) == 16
    # the main job's 48 episodes: 6 chunks of 8 (3 rounds per core, no padding) beat 3 chunks of 16 (one core
    # idle for a round) and 2 of 32 (measured on the default car, interleaved: 126-133 vs 96-98 vs 81 sims/s)
    assert default_lanes(48, 2) == 8
    # 24 simulations on 2 cores: 2 chunks of 16 (one padded by 8) keep both cores busy in one round; 3 chunks
    # of 8 leave one idle for a round, 6 of 4 run at 0.73
    assert default_lanes(24, 2) == 16
    # one simulation: one lane, never padding to a vector
    assert default_lanes(1, 2) == 1
    # a large model: chunks beyond the cache budget are left out (the uniform model, 6891 cells and 11462
    # links, ran 1.49x as fast at 8 lanes as at 32, and 1.09x as fast as at 4)
    from marlcrash.sim.kernels import CHUNK_BYTES, chunk_bytes_per_lane

    uniform = chunk_bytes_per_lane(11462, 6891)
    assert 8 * uniform <= CHUNK_BYTES < 16 * uniform
    assert default_lanes(64, 2, uniform) == 8
    assert default_lanes(64, 2, chunk_bytes_per_lane(2138, 501)) == 16  # the default car is not capped
    assert default_lanes(64, 2, chunk_bytes_per_lane(2138, 501), "float64") * chunk_bytes_per_lane(2138, 501) * 4 < (
        CHUNK_BYTES
    )  # ... by far
    assert default_lanes(64, 2, 10 * CHUNK_BYTES) == 1  # nothing fits: one lane, never an empty choice


def test_default_lanes_in_float32_fills_the_same_row_bytes():
    """float32 has its own table: its fastest chunk is 16 lanes, as in float64 (since the noalias kernel)."""
    from marlcrash.sim.kernels import CHUNK_BYTES, chunk_bytes_per_lane, default_lanes

    car32 = chunk_bytes_per_lane(2138, 501, itemsize=4)
    assert default_lanes(1024, 2, car32, "float32") == default_lanes(128, 2, car32, "float32") == 16
    assert default_lanes(1024, 2, chunk_bytes_per_lane(2138, 501), "float64") == 16
    # the main job's 48 episodes: 6 chunks of 8 at 0.86 of 16's rate still beat 3 of 16 (a core idle for a round)
    assert default_lanes(48, 2, car32, "float32") == 8
    assert default_lanes(1, 2, car32, "float32") == 1
    # the cache cap still applies: the uniform model in float32 gets 16 lanes (8 in float64)
    uniform32 = chunk_bytes_per_lane(11462, 6891, itemsize=4)
    assert 16 * uniform32 <= CHUNK_BYTES < 32 * uniform32
    assert default_lanes(64, 2, uniform32, "float32") == 16
    with pytest.raises(ValueError, match="dtype must be one of"):
        default_lanes(64, 2, car32, "float16")


def test_dtype_study_times_both_precisions_at_their_own_width():
    """The interleaved float64 / float32 comparison: each precision at its default width, the speed ratio of
    the same run, and how far float32 moves the sensor velocities and the crush (float64 ledgers keep it close)."""
    res = dtype_study(batch=128, repeats=1)
    assert res["lanes"] == {"float64": 16, "float32": 16}
    assert all(r > 0 for r in res["sims_per_s"].values())
    assert res["float32_over_float64"] == pytest.approx(res["sims_per_s"]["float32"] / res["sims_per_s"]["float64"])
    assert 0 < res["max_velocity_diff_ms"] < 0.01  # of a 15.6 m/s impact
    assert 0 < res["max_crush_diff_m"] < 1e-3
    text = format_dtype_study(res)
    assert "float32 / float64" in text and text.count("\n") == 4
    with pytest.raises(ValueError, match="batch and repeats must be >= 1"):
        dtype_study(batch=0)


@pytest.mark.slow
def test_lane_study_times_each_width_without_padding_and_names_the_fastest():
    res = lane_study(widths=(1, 4), batch=2, repeats=1)
    one, four = res["rows"]
    # each width runs at least one full chunk per thread: no padded lanes, no idle core
    assert (one["batch"], four["batch"]) == (max(2, res["threads"]), max(2, res["threads"] * 4))
    assert max(r["efficiency"] for r in res["rows"]) == 1.0
    assert res["best_width"] in (1, 4)
    for r in res["rows"]:
        assert r["sims_per_s"] > 0 and 0 < r["efficiency"] <= 1.0
    text = format_lane_study(res)
    assert "fastest width" in text and text.count("\n") == 4
    with pytest.raises(ValueError, match="chunk widths must be >= 1"):
        lane_study(widths=(0,), batch=1, repeats=1)


@pytest.mark.slow
def test_implicit_study_counts_link_passes_and_grades_the_linear_scheme():
    """One step count: Newton statistics over a short window, the linearly implicit scheme graded over 150 ms,
    and the roofline scaled from the explicit one by the link passes per simulation."""
    explicit = {"steps_per_sim": 2100, "roofline_sims_per_s": 300.0}
    res = implicit_study((1,), window_s=0.002, explicit=explicit)
    (row,) = res["rows"]
    nw, li = row["newton"], row["linear"]
    assert row["steps_per_sim"] == 300 and nw["steps"] == 4
    # every force evaluation and CG iteration is one link pass; every Newton iteration at least one of each
    assert nw["link_passes_per_step"] >= nw["force_evals_per_step"] >= nw["newton_mean"] + 1.0
    assert row["roofline_sims_per_s"] == pytest.approx(300.0 * 2100 / 300 / nw["link_passes_per_step"])
    assert li["link_passes_per_step"] > 2.0  # one force evaluation plus the CG iterations of its solve
    assert not li["passed"] and "energy balance < 0.5 %" in li["failed"] and li["balance"] > 5e-3
    text = format_implicit_study(res)
    assert "backward Euler" in text and "linearly implicit" in text and "at 2100 steps (300.0 sims/s)" in text


@pytest.mark.slow
def test_noalias_study_times_both_compilations_and_finds_the_same_numbers():
    """The kernel and the roofline pass recompiled without ``noalias`` from their own source: the same outputs to
    rounding, ratios of the same run."""
    res = noalias_study(batch=4, repeats=1)
    r = res["sims_per_s"]
    assert set(r) == {"kernel_noalias", "kernel_plain", "roofline_noalias", "roofline_plain"}
    assert all(v > 0 for v in r.values())
    assert res["kernel_ratio"] == pytest.approx(r["kernel_noalias"] / r["kernel_plain"])
    assert res["roofline_ratio"] == pytest.approx(r["roofline_noalias"] / r["roofline_plain"])
    assert res["max_rel_diff"] < 1e-12 and res["noalias_active"]  # rounding only (bit for bit on most builds)
    assert "kernel   noalias" in format_noalias_study(res)
    with pytest.raises(ValueError, match="dtype must be one of"):
        noalias_study(batch=1, dtype="float16")


def test_plausibility_checks_simulate_the_scenarios_exact_speed_and_overlap(default_sim):
    """The cases were handed to the simulator as float32 tensors: 40 km/h ran (and was graded) at 39.9999986 km/h,
    overlap 0.4 at 0.40000001. The simulated rows now start at the scenarios' speeds exactly (SI, float64)."""
    seen = {}

    def run(sim, p, **kw):
        seen.update(kw)
        seen["result"] = sim.run(p, backend="numba", **kw)
        return seen["result"]

    plausibility_checks(default_sim, run=run)
    scs = [get_scenario("full_width_40")] + [get_scenario(n, {"speed_kmh": 40.0}) for n in PARTIAL]
    scs.append(get_scenario("full_width_56"))
    for key, want in (("speed", [s.speed for s in scs]), ("overlap", [s.overlap for s in scs]),
                      ("side", [s.side_sign for s in scs])):  # fmt: skip
        assert seen[key].dtype == torch.float64, key
        assert seen[key].tolist() == want, key
    res = seen["result"]
    assert res.compartment_velocity[:, 0].tolist() == [s.speed for s in scs]  # the speed simulated, to the bit
    assert res.compartment_velocity[0, 0].item() * 3.6 == 40.0


def test_roofline_counts_the_simulations_asked_for_not_the_padded_lanes(default_sim):
    """17 simulations run as 2 chunks of 16 lanes: the roofline pass streams 32 lanes, but the rate it stands for
    (next to the kernel's ``B / t``, which pads the same way) is 17 per pass, not 32."""
    from marlcrash.sim import kernels
    from marlcrash.sim.bench import measure_roofline

    batch, seconds = 17, 0.05
    lanes = kernels.lanes_for(batch, default_sim.L, default_sim.n, "float64")
    padded = -(-batch // lanes) * lanes
    seen = []

    def link_pass(lp, src, dst, n, n_steps, cst):  # a pass of known duration over the arrays it is given
        seen.append(lp.shape[0] * lp.shape[-1])
        if n_steps > 2:  # not the warm-up call
            time.sleep(seconds)
        return 0.0

    rate = measure_roofline(default_sim, batch, 10, link_pass=link_pass)
    assert padded > batch and seen[-1] == padded  # the pass does stream the padded chunks
    assert rate == pytest.approx(batch / seconds, rel=0.2)


@pytest.mark.parametrize("batch", [0, -3])
def test_roofline_refuses_a_batch_it_cannot_time(default_sim, batch):
    """A batch of 0 streamed no chunk and reported 0 sims/s (benchmarks/bench_implicit.py --batch 0 then scaled it
    into every implicit row)."""
    from marlcrash.sim.bench import measure_roofline

    with pytest.raises(ConfigError, match=r"expected a batch size in \[1, ") as e:
        measure_roofline(default_sim, batch, 10)
    assert e.value.key == "batch"


@pytest.mark.parametrize(
    ("script", "args", "option"),
    [("bench_sim.py", ["--batches", "0"], "--batches"), ("bench_sim.py", ["--dtypes", "--batches", "0"], "--batches"),
     ("bench_sim.py", ["--repeat", "0"], "--repeat"), ("bench_adjoint.py", ["--batch", "0"], "--batch"),
     ("bench_env.py", ["--batch", "0"], "--batch"), ("bench_env.py", ["--repeat", "0"], "--repeat"),
     ("bench_env.py", ["--pz-steps", "0"], "--pz-steps"), ("bench_implicit.py", ["--batch", "0"], "--batch"),
     ("bench_implicit.py", ["--explicit-substeps", "0"], "--explicit-substeps"),
     ("bench_implicit.py", ["--substeps", "0"], "--substeps"),
     ("bench_substeps.py", ["--batch", "0", "--substeps", "1"], "--batch"),
     ("bench_wait_policy.py", ["--rounds", "0"], "--rounds"), ("bench_wait_policy.py", ["--busy", "-1"], "--busy"),
     ("bench_gpu.py", ["--device", "cpu", "--repeats", "0"], "--repeats"),
     ("bench_gpu.py", ["--device", "cpu", "--batch-sizes", "0"], "--batch-sizes")],
)  # fmt: skip
def test_benchmark_scripts_refuse_counts_below_one_as_usage_errors(script, args, option):
    """A count of 0 ran into a traceback (ConfigError, ModelError, or bench_env's min() of no timings after the whole
    TorchRL run); the scripts now refuse it before any work, as a usage error naming the option."""
    import subprocess
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / script
    out = subprocess.run([sys.executable, str(path), *args], capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr
    assert f"error: argument {option}: expected " in out.stderr and "Traceback" not in out.stderr


def test_run_benchmark_keeps_the_best_of_repeats_for_every_rate_it_compares(monkeypatch):
    """The optimized rates were the best of ``repeats`` runs, the roofline and the uniform model's rate one run each:
    on a shared machine the ratios to them (``roofline_ratio``, ``optimized_over_uniform_b64``) read high. And the
    roofline was timed after every kernel run, so a change of load between the two phases went into their ratio (0.32
    to 0.70 in four runs of one command): now it is timed in turn with the kernel at the largest batch, round by
    round."""
    import marlcrash.cells
    from marlcrash.sim import Surrogate, bench

    discretize = marlcrash.cells.discretize
    monkeypatch.setattr(  # the default car stands in for the uniform model (its 8939 cells take minutes here)
        marlcrash.cells, "discretize", lambda vehicle, method="optimized": discretize(vehicle)
    )
    calls: list[str] = []
    run = Surrogate.run

    def kernel(self, *args, **kwargs):
        calls.append(f"kernel B={args[0].shape[0]}")
        return run(self, *args, **kwargs)

    monkeypatch.setattr(Surrogate, "run", kernel)
    monkeypatch.setattr(bench, "roofline_pass", lambda *a, **k: lambda: calls.append("roofline"))
    seen = {}
    best = bench._best

    def recorded(fn, repeats):
        seen["best"] = repeats
        return best(fn, repeats)

    monkeypatch.setattr(bench, "_best", recorded)
    res = bench.run_benchmark(batch_sizes=(2, 1), repeats=3)
    timed = [c for c in calls if c in ("kernel B=2", "roofline")]
    assert timed[-6:] == ["kernel B=2", "roofline"] * 3 and calls.count("roofline") == 3
    assert seen == {"best": 3} and res["sims_per_s_uniform_b64"] > 0
    assert len(res["roofline_ratio_rounds"]) == 3
    assert res["roofline_ratio"] == pytest.approx(res["sims_per_s_optimized"]["2"] / res["roofline_sims_per_s"])
    assert min(res["roofline_ratio_rounds"]) > 0


def test_import_makes_idle_openmp_threads_sleep_unless_the_user_chose():
    """Two OpenMP runtimes share the cores (numba's system libgomp, torch's bundled one): ``import marlcrash`` sets
    ``OMP_WAIT_POLICY=PASSIVE`` so that neither pool's idle threads spin while the other works; a value the user set
    is kept (benchmarks/bench_wait_policy.py measures both)."""
    import os
    import subprocess
    import sys

    code = "import marlcrash, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    for given, expected in ((None, "PASSIVE"), ("ACTIVE", "ACTIVE")):
        run_env = env if given is None else {**env, "OMP_WAIT_POLICY": given}
        out = subprocess.run([sys.executable, "-c", code], env=run_env, capture_output=True, text=True, timeout=120)
        assert out.stdout.strip() == expected, out.stderr


@pytest.mark.slow
def test_the_wait_policy_benchmark_runs_both_policies():
    import json
    import subprocess
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_wait_policy.py"
    args = ["--batch", "2", "--repeat", "1", "--rounds", "1", "--json"]
    out = subprocess.run([sys.executable, str(path), *args], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    row = json.loads(out.stdout)["rounds"][0]
    for policy in ("ACTIVE", "PASSIVE"):
        assert 0 < row[policy]["outside_kernel_s"] < row[policy]["wall_s"]
    assert row["wall_ratio_active_over_passive"] == pytest.approx(row["ACTIVE"]["wall_s"] / row["PASSIVE"]["wall_s"])


def test_device_study_times_the_torch_backend_and_its_limits_on_the_cpu():
    """The GPU study runs anywhere: on the CPU it times the eager torch path (no graph replay there) and the numba
    kernel in one run; its floor is the smallest batch's time per step and its roofline the copy bandwidth over the
    bytes of the live link-steps, so both follow from the reported figures."""
    res = device_study("cpu", batch_sizes=(1, 2), dtypes=("float32",), repeats=1, duration=0.005)
    assert res["backends"] == ["torch"] and res["device"] == "cpu"
    r = res["float32"]
    steps, live = res["steps_per_sim"], res["n_links_live"]
    assert steps == 10 * 8 and live > 0
    assert set(r["sims_per_s"]["torch"]) == {"1", "2"} and all(x > 0 for x in r["sims_per_s"]["torch"].values())
    assert r["step_floor_s"] == pytest.approx(1.0 / r["sims_per_s"]["torch"]["1"] / steps)
    assert r["roofline_sims_per_s"] == pytest.approx(r["copy_bandwidth_bytes_per_s"] / ((4 + 2) * 4 * live * steps))
    assert r["roofline_ratio"]["torch"] == pytest.approx(r["sims_per_s"]["torch"]["2"] / r["roofline_sims_per_s"])
    assert r["cpu_numba_batch"] == 2 and r["cpu_numba_sims_per_s"] > 0
    text = format_device_study(res)
    assert "float32: eager launch floor" in text and "torch: B=1:" in text and "compiled CPU kernel" in text
    with pytest.raises(ConfigError, match="key 'device'"):
        device_study("tpu")
