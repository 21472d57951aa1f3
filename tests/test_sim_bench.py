"""The benchmark library function: keys, consistency of its ratios, and the float32 fast path."""

from __future__ import annotations

import pytest

from marlcrash.sim.bench import run_benchmark


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
        assert res["link_updates_per_s"][b] == pytest.approx(rate * res["steps_per_sim"] * res["n_links_optimized"])
        assert 0.0 <= res["overhead_share"][b] < 1.0
    assert res["roofline_ratio"] == pytest.approx(res["sims_per_s_optimized"]["4"] / res["roofline_sims_per_s"])
    assert res["sims_per_s_uniform_b64"] is None
