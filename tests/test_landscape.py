"""The landscape study around the twin truth: its bookkeeping on a linear toy, the real problem, the script."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from conftest import REPO, SHORT_DURATION

from marlcrash.calibrate import ProblemConfig, build_problem
from marlcrash.calibrate.landscape import (
    cluster_sensor_study,
    local_fit,
    loglog_slopes,
    neighbourhood_points,
    sensitivity_spectrum,
    sensor_clusters,
    truth_neighbourhood,
)
from marlcrash.errors import ConfigError, ModelError
from marlcrash.metrics import Metrics
from marlcrash.reward import TerminationConfig


class LinearToy:
    """A problem whose metrics are exactly ``gain * rms(x - truth)`` on one sensor: slope 1 everywhere."""

    def __init__(self, gain: float = 10.0, truth: bool = True):
        self.n_agents, self.sensors, self.gain = 3, ["only"], gain
        self.free = torch.ones(3, 7, dtype=torch.bool)
        self.free[2, 4:] = False
        self.true_x = torch.full((3, 7), 0.1, dtype=torch.float64) * self.free if truth else None
        self.success_cfg = TerminationConfig(success_area=0.05, success_dfd=None, success_rmse=None)
        self.sim = SimpleNamespace(config=SimpleNamespace(dtype="float64"))  # what the radius check reads

    def clip(self, x):
        return torch.where(self.free, x.clamp(-1.0, 1.0), 0.0)

    def evaluate(self, x):
        d = (x - self.true_x)[:, self.free]
        a = self.gain * d.pow(2).mean(-1).sqrt()[:, None]
        return Metrics(a, a, a)

    def success(self, m):
        return (m.area < self.success_cfg.success_area).all(-1)


def test_slopes_of_power_laws():
    radii = [1e-4, 1e-3, 1e-2, 0.1]
    for p in (0.0, 1.0, 2.5):
        got = loglog_slopes(radii, [3.0 * r**p for r in radii])
        assert got == pytest.approx([p] * 3, abs=1e-12)
    assert loglog_slopes([1.0, 2.0, 4.0], [0.0, 1.0, 2.0]) == [None, pytest.approx(1.0)]


def test_points_move_only_the_group_and_keep_their_directions():
    toy = LinearToy()
    radii = [1e-3, 1e-2]
    x = neighbourhood_points(toy, radii, "E_s", draws=4, seed=1)
    d = (x - toy.true_x).reshape(2, 4, 3, 7)
    assert (d[..., [0, 2, 3, 4, 5, 6]] == 0).all() and (d[..., 1] != 0).all()
    torch.testing.assert_close(d[0] / radii[0], d[1] / radii[1], rtol=1e-9, atol=0)
    t = neighbourhood_points(toy, radii, "transmission", draws=4, seed=1).reshape(2, 4, 3, 7) - toy.true_x
    assert (t[..., :2] == 0).all() and (t[:, :, 2, 4:] == 0).all()  # fixed coordinates never move


def test_linear_toy_gives_slope_one_and_the_radius_it_needs():
    toy = LinearToy(gain=10.0)
    radii = [1e-4, 1e-3, 1e-2, 1e-1]
    res = truth_neighbourhood(toy, radii, groups=["all"], draws=64, seed=0)
    g = res["groups"]["all"]
    assert res["at_truth"]["area"] == [0.0]
    assert g["slope"] == pytest.approx([1.0] * 3, abs=1e-9)
    # the rms of 64 x 18 standard normals is close to 1: the median area is gain * r within a few %
    for r, a in zip(radii, g["area"], strict=True):
        assert a == pytest.approx(10.0 * r, rel=0.1)
    assert g["radius_needed"] == 1e-3  # about 0.01 passes the 0.05 threshold, about 0.1 does not
    assert g["pass_share"][0] == 1.0 and g["pass_share"][-1] == 0.0


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [({"radii": [1e-3, 1e-4]}, "radii"), ({"radii": [0.0, 1e-3]}, "radii"), ({"draws": 0}, "draws"),
     ({"groups": ["stiffness"]}, "groups"),
     # these raised ValueError/TypeError from float()/int(), or (2.5) ran 2 draws silently
     ({"radii": [1e-3, "x"]}, "radii"), ({"radii": 1e-3}, "radii"), ({"draws": 2.5}, "draws"),
     ({"draws": None}, "draws"), ({"draws": float("nan")}, "draws"), ({"draws": True}, "draws"),
     ({"groups": "all"}, "groups")],
)  # fmt: skip
def test_bad_arguments_name_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        truth_neighbourhood(LinearToy(), **kwargs)


def test_no_ground_truth_is_refused():
    with pytest.raises(ConfigError, match="twin"):
        truth_neighbourhood(LinearToy(truth=False), [1e-3])


def test_real_problem_is_exact_at_the_truth_and_worsens_away_from_it():
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    before = problem.n_simulations
    res = truth_neighbourhood(problem, [1e-6, 1e-1], groups=["all"], draws=2)
    assert problem.n_simulations - before == 1 + 2 * 2
    assert max(max(v) for v in res["at_truth"].values()) < 1e-12
    area = res["groups"]["all"]["area"]
    assert 0 < area[0] < 1e-4 < area[1]


def test_radii_of_a_float32_problem_must_rise_above_its_rounding():
    """A float32 simulation's rounding swamps the pulse change of a parameter change below
    :data:`~marlcrash.calibrate.leastsq.FLOAT32_FD_STEP`, as it swamps a finite difference. On the full-width twin
    (150 ms) moving E_x by r = 1e-6 and 1e-5 gave float32 areas 23x and 5x float64's, and the slope 0.3-0.4 where
    float64's is 1.00: the module's sign that "the pulse jumps", read off rounding. ``truth_neighbourhood`` and
    ``cluster_sensor_study`` ran such radii (the defaults) without a word; they now refuse them on a float32
    problem (key ``radii``) before any simulation, as ``local_fit`` refuses such an ``fd_step``."""
    radii = [1e-6, 1e-5, 1e-3]
    area = {}
    for dtype in ("float64", "float32"):
        p = build_problem(ProblemConfig(env_overrides={"sim_dtype": dtype}))
        m = p.evaluate(neighbourhood_points(p, radii, "E_x", draws=2, seed=0))
        area[dtype] = m.area.amax(-1).reshape(len(radii), 2).median(dim=1).values.tolist()
    assert loglog_slopes(radii[:2], area["float64"][:2])[0] == pytest.approx(1.0, abs=0.05)
    assert loglog_slopes(radii[:2], area["float32"][:2])[0] < 0.7  # rounding, not the landscape
    assert area["float32"][0] > 3 * area["float64"][0]
    assert area["float32"][2] == pytest.approx(area["float64"][2], rel=0.05)  # at the floor: the landscape again

    problem = build_problem(ProblemConfig(duration=SHORT_DURATION, env_overrides={"sim_dtype": "float32"}))
    for run in (
        lambda **kw: truth_neighbourhood(problem, **kw),
        lambda **kw: cluster_sensor_study(problem, cluster_radii=[0.0], **kw),
    ):
        for kw in ({}, {"radii": [5e-4, 1e-2]}):
            with pytest.raises(ConfigError, match=r"float32 .* radii of at least 0\.001") as e:
                run(**kw)
            assert e.value.key == "radii"
    assert problem.n_simulations == 0
    res = truth_neighbourhood(problem, [1e-3, 1e-2], groups=["E_x"], draws=1)
    assert len(res["groups"]["E_x"]["slope"]) == 1


def test_script_prints_json():
    cmd = [sys.executable, str(REPO / "benchmarks" / "bench_landscape.py"), "--draws", "1",
           "--duration", str(SHORT_DURATION), "--json"]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert set(res["groups"]) == {"E_x", "E_s", "transmission", "all"}
    assert res["simulations"] == 1 + 4 * len(res["radii"])
    assert all(math.isfinite(a) for g in res["groups"].values() for a in g["area"])


def test_script_spectrum_reads_a_baseline_result(tmp_path):
    problem = build_problem(ProblemConfig(duration=0.01))
    best = problem.clip(problem.true_x[None] + 0.01)[0]
    torch.save({"best_x": best, "best_params": torch.zeros(1)}, tmp_path / "best.pt")
    script = str(REPO / "benchmarks" / "bench_landscape.py")
    cmd = [
        sys.executable,
        script,
        "--duration",
        "0.01",
        "--spectrum",
        "--candidate",
        str(tmp_path / "best.pt"),
        "--json",
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["n_free"] == problem.n_free and res["simulations"] == problem.n_free + 2
    assert sum(res["candidate"]["error_share"].values()) == pytest.approx(1.0)
    torch.save(torch.zeros(3, 7), tmp_path / "wrong.pt")
    bad = subprocess.run([*cmd[:5], "--candidate", str(tmp_path / "wrong.pt")], capture_output=True, text=True,
                         timeout=600, cwd=REPO)  # fmt: skip
    assert bad.returncode != 0 and "wrong.pt" in bad.stderr and "Traceback" not in bad.stderr


# ------------------------------------------------------------------ sensors read as clusters
def test_sensor_clusters_hold_the_massive_cells_within_the_radius():
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    cells = problem.cells
    names = list(cells.sensor_names)
    for s in problem.sensors:
        c = int(cells.sensor_cell[names.index(s)])
        assert sensor_clusters(cells, [s], 0.0)[0].tolist() == [c]
        members = sensor_clusters(cells, [s], 0.2)[0]
        d = np.linalg.norm(cells.centroid[members] - cells.centroid[c], axis=1)
        assert c in members and (d <= 0.2).all()
        others = np.setdiff1d(np.arange(cells.n_cells), members)
        far = np.linalg.norm(cells.centroid[others] - cells.centroid[c], axis=1) > 0.2
        assert (far | cells.is_null[others] | (cells.mass[others] <= 0)).all()


def test_probe_cells_record_what_the_named_sensors_record():
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    cells = problem.cells
    names = list(cells.sensor_names)
    idx = [int(cells.sensor_cell[names.index(s)]) for s in problem.sensors]
    x = problem.zeros(2)
    named = problem.simulate(x)
    probed = problem.simulate(x, probe_cells=idx)
    assert probed.sensor_names == [f"cell{i}" for i in idx]
    assert torch.equal(named.velocity, probed.velocity) and torch.equal(named.acceleration, probed.acceleration)
    with pytest.raises(ModelError, match="probe_cells"):
        problem.simulate(x, probe_cells=[cells.n_cells])
    for bad in ([idx[0] + 0.7], [float("nan")], np.array([True])):  # 2.7 was truncated to cell 2
        with pytest.raises(ModelError, match="probe_cells must be whole cell indices"):
            problem.simulate(x, probe_cells=bad)
    assert torch.equal(problem.simulate(x, probe_cells=[float(i) for i in idx]).velocity, named.velocity)


def test_cluster_study_at_radius_zero_is_the_landscape_of_the_sensors():
    """Radius 0 reads the sensor cells alone: the same medians as the landscape study's, by another path."""
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    radii = [1e-3, 1e-1]
    ref = truth_neighbourhood(problem, radii, groups=["all"], draws=3, seed=4)["groups"]["all"]["area_per_sensor"]
    before = problem.n_simulations
    res = cluster_sensor_study(problem, cluster_radii=[0.0, 0.15], radii=radii, draws=3, seed=4)
    assert problem.n_simulations - before == 1 + 2 * 3
    single, wide = res["clusters"]
    assert single["cells"] == [1] * len(problem.sensors)
    np.testing.assert_allclose(single["area_per_sensor"], ref, rtol=1e-9, atol=1e-15)
    assert wide["cells"][0] > 1 and wide["mass_kg"][0] > single["mass_kg"][0]
    assert all(a > 0 for row in wide["area_per_sensor"] for a in row)
    with pytest.raises(ConfigError, match="cluster_radii"):
        cluster_sensor_study(problem, cluster_radii=[-0.1])
    with pytest.raises(ConfigError, match="cluster_radii"):  # raised TypeError from np.isfinite
        cluster_sensor_study(problem, cluster_radii=["0.1"])


def test_script_cluster_radii_prints_json():
    cmd = [sys.executable, str(REPO / "benchmarks" / "bench_landscape.py"), "--draws", "1",
           "--duration", str(SHORT_DURATION), "--cluster-radii", "0", "0.1", "--json"]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert [c["radius_m"] for c in res["clusters"]] == [0.0, 0.1]
    assert res["simulations"] == 1 + len(res["radii"])


def test_local_fit_converges_near_the_truth_and_counts_its_simulations():
    """1 % from the truth over the full 150 ms the landscape is smooth enough for Levenberg-Marquardt to pass
    within three iterations (worst sensor area 0.0114, 0.0032, 0.0016, 0.0014 m against the 0.0015 mark).

    Before damping acted on elastic deformation only and bottoming out happened within the step, the first
    step from here was rejected at every damping value and the fit stalled at 2-5x the area mark.
    """
    problem = build_problem(ProblemConfig())
    hist = local_fit(problem, start_radius=1e-2, iterations=3, seed=0)
    assert len(hist) == 4
    assert [h["simulations"] for h in hist] == [1 + i * (problem.n_free + 6) for i in range(4)]
    costs = [h["cost"] for h in hist]
    assert costs[3] <= costs[2] <= costs[1] < 0.5 * costs[0], costs
    assert not hist[0]["passed"] and hist[-1]["passed"]
    assert set(hist[0]["sensors"]) == set(problem.sensors)


def test_local_fit_rejects_bad_settings():
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    for key, kw in (("iterations", {"iterations": 0}), ("fd_step", {"fd_step": -1e-5}), ("damping", {"damping": 0.0}),
                    ("iterations", {"iterations": 2.5}), ("iterations", {"iterations": "3"}),
                    ("fd_step", {"fd_step": None}), ("start_radius", {"start_radius": float("nan")})):  # fmt: skip
        with pytest.raises(ConfigError, match=key):
            local_fit(problem, **kw)
    assert problem.n_simulations == 0


def test_finite_differences_of_a_float32_problem_need_a_step_above_its_rounding():
    """At the default step (1e-5) a float32 simulation's finite differences are rounding noise (the Jacobian's
    columns came out 4.5x off float64's, test_calibrate_baselines): the ``lm`` baseline refuses such a step, but
    ``local_fit`` and ``sensitivity_spectrum`` fitted and reported singular values of that noise without a word.
    They refuse it by the same rule (key ``fd_step``), before any simulation."""
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION, env_overrides={"sim_dtype": "float32"}))
    for run in (
        lambda **kw: local_fit(problem, start_radius=1e-2, **kw),
        lambda **kw: sensitivity_spectrum(problem, **kw),
    ):
        for kw in ({}, {"fd_step": 5e-4}):
            with pytest.raises(ConfigError, match=r"float32 .* at least 0\.001") as e:
                run(**kw)
            assert e.value.key == "fd_step"
    assert problem.n_simulations == 0
    assert len(local_fit(problem, start_radius=1e-2, iterations=1, fd_step=1e-3)) == 2
    assert sensitivity_spectrum(problem, fd_step=1e-3)["n_free"] == problem.n_free


class LinearResidualToy:
    """Residuals exactly ``A (z - z_true)`` over 14 free coordinates; ``A`` has known singular values."""

    def __init__(self, singular: np.ndarray, blind: int | None = None, seed: int = 0):
        rng = np.random.default_rng(seed)
        u, _ = np.linalg.qr(rng.standard_normal((40, 14)))
        v, _ = np.linalg.qr(rng.standard_normal((14, 14)))
        self.A = torch.as_tensor(u @ np.diag(singular) @ v.T)
        if blind is not None:
            self.A[:, blind] = 0.0
        self.v = torch.as_tensor(v)
        self.n_agents, self.free = 2, torch.ones(2, 7, dtype=torch.bool)
        self.true_x = torch.full((2, 7), 0.05, dtype=torch.float64)
        self.n_simulations = 0
        self.sim = SimpleNamespace(config=SimpleNamespace(dtype="float64"))  # what the step check reads

    def check_x(self, x):
        x = torch.as_tensor(x, dtype=torch.float64)
        return x[None] if x.dim() == 2 else x

    def clip(self, x):
        return x.clamp(-1.0, 1.0)

    def flat_box(self):
        return -torch.ones(14, dtype=torch.float64), torch.ones(14, dtype=torch.float64)

    def flat(self, x):
        return x[:, self.free]

    def unflat(self, z):
        return z.reshape(-1, 2, 7)

    def residuals(self, x):
        z = self.flat(x) - self.true_x.reshape(1, -1)
        self.n_simulations += z.shape[0]
        return (z @ self.A.T)[:, None, :], None


def test_spectrum_equals_the_svd_of_a_linear_toy():
    singular = np.array([3.0, 1.0, 0.5, 0.2, 0.05, 0.035, 0.012, 4e-3, 2e-3, 8e-4, 5e-4, 2e-4, 5e-5, 1e-5])
    toy = LinearResidualToy(singular)
    d = 0.01 * toy.v[:, 4] + 0.02 * toy.v[:, 9]  # relative singular values 0.05/3 and 8e-4/3
    cand = toy.true_x + toy.unflat(d[None])[0]
    res = sensitivity_spectrum(toy, candidate=cand)
    np.testing.assert_allclose(res["singular_values"], singular, rtol=1e-6)
    assert res["above"] == {"0.1": 3, "0.01": 6, "0.001": 8, "0.0001": 11} and res["blind_coordinates"] == 0
    assert res["simulations"] == 1 + 14 + 1 and res["n_residuals"] == 40
    c = res["candidate"]
    share = c["error_share"]
    assert list(share) == [">0.1", "0.01-0.1", "0.001-0.01", "0.0001-0.001", "<=0.0001"]
    assert share["0.01-0.1"] == pytest.approx(0.2, abs=1e-9) and share["0.0001-0.001"] == pytest.approx(0.8, abs=1e-9)
    assert c["residual"] == pytest.approx(c["linear_residual"], rel=1e-6) and c["residual_at_x"] == 0.0


def test_spectrum_with_fewer_residuals_than_coordinates_puts_null_space_errors_in_the_last_band():
    toy = LinearResidualToy(np.linspace(1.0, 0.1, 14))
    toy.A = toy.A[:10]  # 10 residuals, 14 coordinates: a 4-dimensional null space
    _, _, vt = np.linalg.svd(toy.A.numpy())
    d = torch.as_tensor(vt[-1])  # in the null space
    res = sensitivity_spectrum(toy, candidate=toy.true_x + toy.unflat(0.05 * d[None])[0])
    assert len(res["singular_values"]) == 14 and res["singular_values"][-4:] == [0.0] * 4
    assert res["candidate"]["error_share"]["<=0.0001"] == pytest.approx(1.0, abs=1e-6)


def test_spectrum_counts_blind_coordinates_and_checks_its_arguments():
    toy = LinearResidualToy(np.linspace(1.0, 0.1, 14), blind=3)
    res = sensitivity_spectrum(toy)
    assert res["blind_coordinates"] == 1 and res["relative"][-1] < 1e-12
    # a column of rounding size counts as blind (the compared signal's filter is a matrix product whose
    # rounding depends on the batch layout); a weak but real response does not
    scale = float(torch.linalg.vector_norm(toy.A, dim=0).max())
    toy.A[:, 5] *= 1e-11 * scale / float(torch.linalg.vector_norm(toy.A[:, 5]))
    toy.A[:, 6] *= 1e-6 * scale / float(torch.linalg.vector_norm(toy.A[:, 6]))
    assert sensitivity_spectrum(toy)["blind_coordinates"] == 2
    with pytest.raises(ConfigError) as e:
        sensitivity_spectrum(toy, bands=(1e-2, 1e-1))
    assert e.value.key == "bands"
    with pytest.raises(ConfigError) as e:
        sensitivity_spectrum(toy, fd_step=0.0)
    assert e.value.key == "fd_step"
    for kw, key in (({"fd_step": None}, "fd_step"), ({"bands": ("0.1",)}, "bands")):  # TypeError, ValueError
        with pytest.raises(ConfigError) as e:
            sensitivity_spectrum(toy, **kw)
        assert e.value.key == key


def test_spectrum_of_the_real_problem_sees_few_directions_in_a_short_window():
    """Over the first 10 ms the load has not reached the rear cells: their coordinates are blind."""
    problem = build_problem(ProblemConfig(duration=0.01))
    res = sensitivity_spectrum(problem)
    assert res["simulations"] == problem.n_free + 1
    assert 0 < res["blind_coordinates"] < problem.n_free
    assert res["above"]["0.0001"] <= problem.n_free - res["blind_coordinates"]
    assert res["relative"][0] == 1.0 and all(a >= b for a, b in zip(res["relative"], res["relative"][1:], strict=False))


def test_cluster_study_measures_the_area_as_the_problem_does():
    """A fit whose reward config integrates the area by the trapezoid rule: the cluster study compared with the
    exact area regardless, so at radius 0 its medians disagreed with the landscape study's (the problem's)."""
    problem = build_problem(ProblemConfig(duration=SHORT_DURATION))
    problem.fit.cfg.metrics.area_method = "trapezoid"
    radii = [1e-2, 1e-1]
    ref = truth_neighbourhood(problem, radii, groups=["all"], draws=3, seed=4)["groups"]["all"]["area_per_sensor"]
    res = cluster_sensor_study(problem, cluster_radii=[0.0], radii=radii, draws=3, seed=4)
    np.testing.assert_allclose(res["clusters"][0]["area_per_sensor"], ref, rtol=1e-9, atol=1e-15)
