"""Ablations (DESIGN 6): the factor product, runs under the results table's protocol, paired effects, resume, script.

Runs on a shortened copy of configs/ (every scenario simulated for 30 ms instead of 150 ms).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import marlcrash.calibrate.ablate as ablate
from marlcrash.calibrate.ablate import (
    CSV_COLUMNS,
    FACTORS,
    best_so_far_curve,
    cell_compare_config,
    cell_name,
    load_ablation_config,
    paired_effects,
    reference_problem,
    run_ablation,
)
from marlcrash.calibrate.compare import outcome_row, ppo_train_config, problem_config, run_ppo
from marlcrash.calibrate.problem import build_problem
from marlcrash.envs.core import CalibrationCore, load_env_config
from marlcrash.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def tiny_data(tmp_path: Path, **kw) -> dict:
    """configs/train/ablate.yaml as a mapping, shrunk to seconds: budget 24, 2 envs x 3 steps, small networks."""
    data = yaml.safe_load((REPO / "configs" / "train" / "ablate.yaml").read_text())
    for k in ("defaults", "hydra", "name"):
        data.pop(k)
    for m in ("mappo", "ippo", "ppo_single"):
        algo = yaml.safe_load((REPO / "configs" / "train" / "algorithm" / f"{m}.yaml").read_text())
        data[m] = {**algo, "hidden": [16, 16], "minibatch_size": 3, "epochs": 2}
    data.update(budget=24, seeds=[0], out_dir=str(tmp_path / "runs"), name="t", max_wall_s=None,
                masking=["none", "primary_secondary"], scenarios=["offset40_left"])  # fmt: skip
    data["ppo"].update(n_envs=2, episode_length=3)
    data.update(kw)
    return data


def tiny(tmp_path: Path, **kw) -> ablate.AblationConfig:
    return load_ablation_config(tiny_data(tmp_path, **kw), source="test")


# ------------------------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "override, key, words",
    [
        ({"masking": ["none", "sideways"]}, "masking[1]", "sideways"),
        ({"masking": ["none", "none"]}, "masking", "distinct"),
        ({"rewards": ["log_ratio", "nope"]}, "rewards[1]", "nope"),
        ({"granularity": ["agent"]}, "granularity[0]", "agent"),
        ({"scenarios": ["head_on"]}, "scenarios[0]", "unknown scenario"),
        ({"algorithms": ["sgd"]}, "algorithms[0]", "unknown algorithm"),
        ({"algorithms": []}, "algorithms", "at least one"),
        ({"seeds": [0, -1]}, "seeds[1]", "[0, 2**64 - 1]"),
        ({"seeds": [0, 2**64]}, "seeds[1]", "[0, 2**64 - 1]"),  # the PPO runs' torch seed: failed mid-ablation
        ({"env_overrides": {"masking.mode": "none"}}, "env_overrides.masking.mode", "list its levels"),
        ({"env_overrides": {"reference.pin_seed": 3}}, "env_overrides.reference.pin_seed", "protocol"),
        ({"env_overrides": {"reference": {"pin_seed": 3}}}, "env_overrides.reference.pin_seed", "protocol"),
        (
            {"env_overrides": {"termination": {"max_iterations": 4}}},
            "env_overrides.termination.max_iterations",
            "ppo.episode_length",
        ),
        ({"env_overrides": {"max_stepp": 0.1}}, "env_overrides.max_stepp", ""),
        ({"env_overrides": {"reference.kind": "cross_fidelity"}}, "env_overrides.reference.kind", "protocol"),
        (
            {
                "ppo": {
                    "n_envs": 2,
                    "episode_length": 3,
                    "threads": 0,
                    "env_overrides": {"reference.twin.e_x_spread": 0.4},
                }
            },
            "ppo.env_overrides.reference.twin.e_x_spread",
            "top-level env_overrides",
        ),
        ({"score": "nope"}, "score", "nope"),
        ({"masking": ["none", "a-b"]}, "masking[1]", "without"),
        ({"rewards": ["configs/reward/log_ratio.yaml"]}, "rewards[0]", "without"),
        (
            {"ppo": {"n_envs": 2, "episode_length": 3, "threads": 0, "env_overrides": {"masking.mode": "none"}}},
            "ppo.env_overrides.masking.mode",
            "list its levels",
        ),
        ({"masking": ["none", "primary+regoin"]}, "masking[1]", "unknown modifier 'regoin'"),
        ({"masking": ["primary", "primary+region+agent"]}, "masking[1]", "masking.cells twice"),
        ({"masking": ["none", "none+region"]}, "masking[1]", "changes nothing"),
        ({"masking": ["primary+region+nosat", "primary+nosat+region"]}, "masking[1]", "as masking[0]"),
        ({"masking": ["none", "primary", "primary+agent"]}, "masking[2]", "as masking[1]"),  # the env's cells: agent
        ({"masking": ["primary_secondary", "primary_secondary+sat"]}, "masking[1]", "as masking[0]"),
        ({"masking": ["none+nosat", "primary", "none+agent+nosat"]}, "masking[2]", "as masking[0]"),
        ({"env_overrides": {"masking.cells": "region"}}, "env_overrides.masking.cells", "primary+region"),
        (
            {"env_overrides": {"masking": {"saturation_preference": False}}},
            "env_overrides.masking.saturation_preference",
            "sat, nosat",
        ),
        ({"budget": 7}, "budget", "at least one PPO iteration"),
        ({"max_wall_s": -1.0}, "max_wall_s", "> 0"),
    ],
)
def test_bad_config_fails_naming_the_key(short, tmp_path, override, key, words):
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, **override)
    assert e.value.key == key, str(e.value)
    assert words in str(e.value)


def test_a_masking_level_that_activates_no_agent_on_a_scenario_is_refused(short, tmp_path, monkeypatch):
    """With a 5 cm primary region and min_fraction 1, no agent of the default deck has all its cells in the region:
    ``primary`` trained with every action masked and reported a gain of exactly 0 as its result (the env only
    warned, inside the run). It is refused before any run, naming the level and the scenario."""
    monkeypatch.setattr(ablate, "run_cell", lambda *a, **kw: pytest.fail("ran a cell"))
    over = {"masking.min_fraction": 1.0, "masking.primary_depth": 0.05}
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, env_overrides=over, masking=["none", "primary"])
    assert e.value.key == "masking[1]", str(e.value)
    assert "'offset40_left' activates no agent" in str(e.value) and "'primary'" in str(e.value)
    tiny(tmp_path, env_overrides={"masking.min_fraction": 1.0})  # every scenario keeps an agent: accepted


def test_masking_levels_that_let_the_same_agents_act_on_the_same_cells_are_refused_or_flagged(short, tmp_path):
    """On a full-width scenario ``none`` and ``primary`` both activate every agent on every cell, and
    ``secondary_hops: 0`` makes ``primary_secondary`` ``primary``: their runs were bit-identical and the tables read
    "+0.0000, 1 tie" as a measured effect. Levels that coincide on every scenario are refused; on some, warned."""
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, masking=["none", "primary"], scenarios=["full_width_40"])
    assert e.value.key == "masking[1]", str(e.value)
    assert "'primary' lets the same agents act on the same cells as masking[0] 'none' on every scenario" in str(e.value)
    assert "full_width_40 (21 of 21 agents, 488 cells acting)" in str(e.value)
    with pytest.raises(ConfigError) as e:
        tiny(tmp_path, masking=["primary", "primary_secondary"], env_overrides={"masking.secondary_hops": 0})
    assert e.value.key == "masking[1]" and "as masking[0] 'primary' on every scenario" in str(e.value)
    with pytest.warns(UserWarning, match=r"'primary' lets the same agents act .* on full_width_40 \(21 of 21"):
        tiny(tmp_path, masking=["none", "primary"], scenarios=["full_width_40", "offset40_left"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tiny(tmp_path, masking=["none", "primary"], scenarios=["offset40_left"])  # they differ: no word
        tiny(tmp_path, masking=["none+nosat", "primary+sat"], scenarios=["offset40_left"])
        tiny(tmp_path, masking=["primary+sat", "primary+nosat"], scenarios=["full_width_40"])  # preference differs


def test_reward_forms_must_measure_as_the_score_form_does(short, tmp_path):
    path = short / "reward" / "paper_factor.yaml"  # an edited registered form: another scaling of the Frechet points
    text = path.read_text()
    form = yaml.safe_load(text)
    form["metrics"]["dfd_time_scale"] = 10.0
    path.write_text(yaml.safe_dump(form))
    try:
        with pytest.raises(ConfigError) as e:
            tiny(tmp_path, rewards=["log_ratio", "paper_factor"])
        assert e.value.key == "rewards[1]" and "measures A, DFD and RMSE differently" in str(e.value)
    finally:
        path.write_text(text)
    tiny(tmp_path, rewards=["log_ratio", "paper_factor"])  # as shipped: the same measurement


def test_minibatch_must_divide_the_frames_of_each_algorithm_run(short, tmp_path):
    data = tiny_data(tmp_path, algorithms=["mappo", "ippo"])
    data["ippo"]["minibatch_size"] = 4  # 2 envs x 3 steps = 6 frames
    with pytest.raises(ConfigError) as e:
        load_ablation_config(data, source="test")
    assert e.value.key == "ippo.minibatch_size" and "6 env steps" in str(e.value)


def test_config_file_defaults_and_the_full_factor_product(short, tmp_path):
    data = yaml.safe_load((REPO / "configs" / "train" / "ablate.yaml").read_text())
    assert data["masking"] == ["none", "primary", "primary_secondary"] and data["seeds"] == [0, 1, 2]
    cfg = tiny(tmp_path, masking=["none", "primary"], rewards=["log_ratio", "paper_factor", "neg_weighted_sum"],
               granularity=["subassembly", "cell"], scenarios=["offset40_left", "full_width_40"])  # fmt: skip
    cells = cfg.cells()
    assert len(cells) == 1 * 2 * 2 * 2 * 3
    assert len({cell_name(c) for c in cells}) == len(cells)
    rewards = ["log_ratio", "paper_factor", "neg_weighted_sum"]
    want = set(itertools.product(["mappo"], ["none", "primary"], ["offset40_left", "full_width_40"],
                                 ["subassembly", "cell"], rewards))  # fmt: skip
    assert {tuple(c[f] for f in FACTORS) for c in cells} == want
    assert cfg.varied() == ["masking", "scenario", "granularity", "reward"]


def test_a_cell_trains_with_its_factors_and_the_fixed_settings(short, tmp_path):
    cfg = tiny(tmp_path, env_overrides={"behaviour_bounds": [0.5, 2.0]})
    cell = {"algorithm": "mappo", "masking": "primary", "scenario": "small_overlap_right", "granularity": "cell",
            "reward": "paper_factor"}  # fmt: skip
    tc = ppo_train_config(cell_compare_config(cfg, cell, 3), "mappo", 3, tmp_path)
    env = load_env_config(tc.env, tc.env_overrides)
    assert env.masking.mode == "primary" and env.granularity == "cell" and env.reward == "paper_factor"
    assert env.scenarios == {"small_overlap_right": 1.0} and env.reference.pin_seed == 3
    assert list(env.behaviour_bounds) == [0.5, 2.0] and env.max_step == 0.1  # shared and PPO overrides
    assert tc.seed == 3 and tc.n_envs == 2 and tc.episode_length == 3


def test_shared_and_ppo_overrides_of_one_section_both_reach_the_runs(short, tmp_path):
    """``+env_overrides.masking.min_fraction=0.5 +ppo.env_overrides.masking.primary_depth=1.0``: two mappings for
    the masking section; the PPO one replaced the shared one whole, so the runs trained with min_fraction 0.1."""
    data = tiny_data(tmp_path, env_overrides={"masking": {"min_fraction": 0.5}})
    data["ppo"]["env_overrides"]["masking"] = {"primary_depth": 1.0}
    cfg = load_ablation_config(data, source="test")
    cell = {"algorithm": "mappo", "masking": "primary", "scenario": "offset40_left", "granularity": "subassembly",
            "reward": "log_ratio"}  # fmt: skip
    tc = ppo_train_config(cell_compare_config(cfg, cell, 0), "mappo", 0, tmp_path)
    m = load_env_config(tc.env, tc.env_overrides).masking
    assert (m.mode, m.min_fraction, m.primary_depth) == ("primary", 0.5, 1.0)
    flat = {**cfg.ppo.env_overrides, "masking.min_fraction": 0.5, "masking.primary_depth": 1.0}
    flat.pop("masking")
    same = load_ablation_config({**data, "env_overrides": {}, "ppo": {**data["ppo"], "env_overrides": flat}})
    problem = reference_problem(cfg, "offset40_left", 0)
    assert ablate.masking_reach(cfg, problem, "primary") == ablate.masking_reach(same, problem, "primary")


def test_active_agents_are_counted_over_the_training_envs_agents(short, tmp_path):
    """``ppo.env_overrides`` may set the agents (``agents.split_lr``): the runs train with that layout, so the active
    and total agent counts of a row are its; they were the yardstick problem's (12 of 21 instead of 11 of 16)."""
    data = tiny_data(tmp_path)
    data["ppo"]["env_overrides"]["agents.split_lr"] = []
    cfg = load_ablation_config(data, source="test")
    problem = reference_problem(cfg, "offset40_left", 0)
    cell = {"algorithm": "mappo", "masking": "primary_secondary", "scenario": "offset40_left",
            "granularity": "subassembly", "reward": "log_ratio"}  # fmt: skip
    tc = ppo_train_config(cell_compare_config(cfg, cell, 0), "mappo", 0, tmp_path)
    core = CalibrationCore(load_env_config(tc.env, tc.env_overrides), batch_size=1)
    core.reset()
    reach = ablate.masking_reach(cfg, problem, "primary_secondary")
    assert (reach["active_agents"], reach["n_agents"]) == (int(core.active[0].sum()), core.A) == (11, 16)


@pytest.mark.parametrize("scenario", ["offset40_left", "small_overlap_left"])
def test_acting_cells_are_the_cells_a_full_action_moves(short, tmp_path, scenario):
    """``acting_cells`` counts the cells the active agents' actions reach in the runs' env: an action of +1 on every
    entry changes exactly that many cells' parameters, and ``+region`` keeps the agents but reaches fewer cells
    (``active`` alone read the same for both levels)."""
    cfg = tiny(tmp_path, masking=["primary_secondary", "primary_secondary+region"], scenarios=[scenario])
    problem = reference_problem(cfg, scenario, 0)
    reach = {}
    for level in cfg.masking:
        cell = {"algorithm": "mappo", "masking": level, "scenario": scenario, "granularity": "cell",
                "reward": "log_ratio"}  # fmt: skip
        tc = ppo_train_config(cell_compare_config(cfg, cell, 0), "mappo", 0, tmp_path)
        core = CalibrationCore(load_env_config(tc.env, tc.env_overrides), batch_size=1)
        core.reset()
        before = core.params.clone()
        core.apply_actions(torch.ones(1, core.A, core.act_dim, dtype=torch.float64))
        moved = int((core.params != before).any(-1).sum())
        reach[level] = ablate.masking_reach(cfg, problem, level)
        assert reach[level]["acting_cells"] == moved, level
        assert reach[level]["active_agents"] == int(core.active[0].sum()), level
    agent, region = reach.values()
    assert agent["active_agents"] == region["active_agents"] and region["acting_cells"] < agent["acting_cells"]


def test_the_twin_spreads_are_an_env_override_of_every_run(short, tmp_path):
    """The protocol sets the reference's kind and seed, not its twin spreads: ``env_overrides.reference.twin.*``
    reaches the yardstick's reference and the PPO runs' (it was refused as set by the protocol)."""
    cfg = tiny(tmp_path, env_overrides={"reference": {"twin": {"e_x_spread": 0.4}}})
    cell = {"algorithm": "mappo", "masking": "none", "scenario": "offset40_left", "granularity": "subassembly",
            "reward": "log_ratio"}  # fmt: skip
    tc = ppo_train_config(cell_compare_config(cfg, cell, 0), "mappo", 0, tmp_path)
    ref = load_env_config(tc.env, tc.env_overrides).reference
    assert ref.twin.e_x_spread == 0.4 and ref.twin.e_s_spread == 0.2 and ref.pin_seed == 0 and ref.kind == "twin"
    wider, default = reference_problem(cfg, "offset40_left", 0), reference_problem(tiny(tmp_path), "offset40_left", 0)
    assert not torch.equal(wider.ref_velocity, default.ref_velocity)


def test_a_masking_level_sets_the_mode_and_what_active_agents_act_on(short, tmp_path):
    """``primary+region+nosat``: DESIGN 1.4's per-cell rule and the saturation preference as masking levels."""
    cfg = tiny(tmp_path, masking=["primary", "primary+region", "primary_secondary+region+nosat", "none+nosat"])
    got = {}
    for level in cfg.masking:
        cell = {"algorithm": "mappo", "masking": level, "scenario": "small_overlap_left", "granularity": "subassembly",
                "reward": "log_ratio"}  # fmt: skip
        tc = ppo_train_config(cell_compare_config(cfg, cell, 0), "mappo", 0, tmp_path)
        m = load_env_config(tc.env, tc.env_overrides).masking
        got[level] = (m.mode, m.cells, m.saturation_preference)
    assert got == {
        "primary": ("primary", "agent", True),  # no modifier: the env config's values (configs/env/default.yaml)
        "primary+region": ("primary", "region", True),
        "primary_secondary+region+nosat": ("primary_secondary", "region", False),
        "none+nosat": ("none", "agent", False),
    }
    names = {cell_name(c) for c in cfg.cells()}
    assert "mappo-primary+region-offset40_left-subassembly-log_ratio" in names and len(names) == 4
    # the env honours it: in the driver-side small overlap the region leaves part of an active agent's cells out
    env = load_env_config("default", {"scenarios": {"small_overlap_left": 1.0}, "reference.pin_seed": 0,
                                      **ablate.masking_overrides("primary+region")})  # fmt: skip
    core = CalibrationCore(env, batch_size=1)
    core.reset()
    owned = core.layout.cells[core.active[0]]
    owned = owned[owned >= 0]
    acting = core.acting[0, owned]
    assert acting.any() and not acting.all()


# ------------------------------------------------------------------------------------- statistics
def test_best_so_far_curve_is_the_step_function_of_the_record():
    hist = [[2, -3.0], [5, -2.0], [9, -1.5]]
    grid = np.array([0.0, 1.9, 2.0, 4.0, 5.0, 8.99, 9.0, 20.0])
    got = best_so_far_curve(hist, grid)
    assert np.isnan(got[:2]).all()
    np.testing.assert_array_equal(got[2:], [-3.0, -3.0, -2.0, -2.0, -1.5, -1.5])
    assert np.isnan(best_so_far_curve([], grid)).all()


def _row(seed, gain, area, **cell):
    base = {"algorithm": "mappo", "masking": "none", "scenario": "s1", "granularity": "subassembly",
            "reward": "log_ratio"}  # fmt: skip
    c = {**base, **cell}
    return {"cell": cell_name(c), **c, "seed": seed, "gain": gain, "area_worst": area}


def test_paired_effects_match_a_hand_computation():
    rows = [
        _row(0, -1.0, 0.04), _row(1, -2.0, 0.02),  # baseline masking none, scenario s1
        _row(0, -0.5, 0.01, masking="primary"), _row(1, -2.5, 0.04, masking="primary"),
        _row(0, -3.0, 0.08, scenario="s2"), _row(0, -2.0, 0.02, scenario="s2", masking="primary"),
        _row(2, 9.0, 1.0, masking="primary"),  # no baseline run with seed 2: unpaired, left out
        _row(3, 0.0, 0.0), _row(3, 0.5, 0.01, masking="primary"),  # a zero area: paired, but no area ratio
    ]  # fmt: skip
    levels = {"algorithm": ["mappo"], "masking": ["none", "primary"], "scenario": ["s1", "s2"],
              "granularity": ["subassembly"], "reward": ["log_ratio"]}  # fmt: skip
    eff = {(e["factor"], e["level"]): e for e in paired_effects(rows, levels)}
    assert set(eff) == {("masking", "primary"), ("scenario", "s2")}
    m = eff["masking", "primary"]
    d = np.array([0.5, -0.5, 1.0, 0.5])  # (s1, 0), (s1, 1), (s2, 0), (s1, 3)
    assert m["pairs"] == 4 and m["baseline"] == "none" and m["wins"] == 3 and m["ratio_pairs"] == 3
    assert m["gain_diff_mean"] == pytest.approx(d.mean(), abs=1e-15)
    assert m["gain_diff_se"] == pytest.approx(d.std(ddof=1) / math.sqrt(4), abs=1e-15)
    assert m["area_worst_ratio"] == pytest.approx((0.25 * 2.0 * 0.25) ** (1 / 3), rel=1e-12)
    assert m["gain_mean"] == pytest.approx(np.mean([-0.5, -2.5, -2.0, 0.5]))
    assert m["baseline_gain_mean"] == pytest.approx(np.mean([-1.0, -2.0, -3.0, 0.0]))
    s = eff["scenario", "s2"]  # pairs: (none, 0) and (primary, 0)
    assert s["pairs"] == 2 and s["gain_diff_mean"] == pytest.approx(np.mean([-2.0, -1.5])) and s["wins"] == 0


def _table_row(seed, gain, area, **cell):
    """A finished row with every key ``ablate.md`` reads."""
    r = _row(seed, gain, area, **cell)
    r.update(active_agents=21, n_agents=21, acting_cells=300, simulations=24, stop="budget",
             score=None if gain is None else gain - 2.0,
             initial_score=-2.0, dfd_worst=0.5, rmse_worst=0.4, passed=False, sims_to_success=None,
             param_error=0.1, wall_time_s=1.0)  # fmt: skip
    return r


def test_ablate_md_gives_every_tables_units_and_the_pairs_of_the_area_ratio():
    """The per-run table gave the worst area, DFD and RMSE without units (the per-cell table has them), and the
    worst-area ratio of the paired effects, taken over the pairs whose areas are both > 0, read as over every pair
    where fewer had one (a zero area: 1 of 2 pairs)."""
    rows = [_table_row(0, -1.0, 0.04), _table_row(1, -2.0, 0.0), _table_row(2, -1.0, 0.02),
            _table_row(0, -0.5, 0.01, masking="primary"), _table_row(1, -2.5, 0.04, masking="primary"),
            _table_row(0, -1.5, 0.01, scenario="s2"), _table_row(2, -0.5, 0.01, scenario="s2")]  # fmt: skip
    cfg = ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1", "s2"])
    md = ablate.markdown(cfg, rows, None, "today")
    per_run = md.split("## Per run")[1]
    assert "| area worst [m] | DFD worst [m/s] | RMSE worst [m/s] |" in per_run
    assert "| masking | primary vs none | 2 | +0.0000 ± 0.5000 | 1/2 | 0.250 (1 of 2 pairs) |" in md
    assert "| scenario | s2 vs s1 | 2 | +0.0000 ± 0.5000 | 1/2 | 0.354 |" in md  # every pair: no count


def test_a_tied_pair_is_not_counted_as_a_loss():
    """A level that changes nothing on a reference (``+nosat`` where no cell saturates, ``+region`` where every
    acting cell is in the region) gains exactly what the baseline gains; ``wins`` counted that pair with the losses, so
    '1/3' read as two losses where one pair was a tie. So was a pair where neither run has a gain (both diverged)."""
    rows = [_table_row(0, -1.0, 0.04), _table_row(1, -2.0, 0.02), _table_row(2, None, 0.02),
            _table_row(0, -0.5, 0.01, masking="primary"), _table_row(1, -2.0, 0.02, masking="primary"),
            _table_row(2, None, 0.02, masking="primary")]  # fmt: skip
    levels = {"algorithm": ["mappo"], "masking": ["none", "primary"], "scenario": ["s1"],
              "granularity": ["subassembly"], "reward": ["log_ratio"]}  # fmt: skip
    [e] = paired_effects(rows, levels)
    assert (e["pairs"], e["wins"], e["ties"]) == (3, 1, 2)
    md = ablate.markdown(ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1"]), rows, None, "today")
    assert "| masking | primary vs none | 3 | - | 1/3 (2 ties) |" in md
    e1 = paired_effects(rows[:2] + rows[3:5], levels)[0]  # one tie
    assert (e1["wins"], e1["ties"]) == (1, 1)


def test_ablate_md_says_how_many_runs_are_planned_and_done():
    """ablate.md is written before the first run finishes and after each run: it read 'varied: nothing; fixed:
    nothing; reference seeds []' until a run finished, and never said how many runs the ablation has."""
    cfg = ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1", "s2"])  # 4 cells x 3 seeds
    md = ablate.markdown(cfg, [], None, "today")
    assert "- runs finished: 0 of 12 (4 cells x 3 reference seeds)\n" in md
    assert "- varied: masking (none, primary); scenario (s1, s2); fixed: algorithm `mappo`," in md
    assert "reference seeds [0, 1, 2]" in md and "nothing" not in md
    md = ablate.markdown(cfg, [_table_row(0, -1.0, 0.04), _table_row(0, -0.5, 0.01, masking="primary")], None, "x")
    assert "- runs finished: 2 of 12 (4 cells x 3 reference seeds)\n" in md
    done = [_table_row(s, -1.0, 0.04, scenario=sc, masking=m) for s in (0, 1, 2) for sc in ("s1", "s2")
            for m in ("none", "primary")]  # fmt: skip
    extra = _table_row(5, -1.0, 0.04)  # a resumed run's row of a seed no longer in the config: counted too
    assert "- runs finished: 13 of 13 (4 cells x 3 reference seeds" in ablate.markdown(cfg, [*done, extra], None, "x")


# ------------------------------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def finished(short, tmp_path_factory):
    """A finished tiny ablation: masking none / primary_secondary on offset40_left, reference seed 0."""
    tmp = tmp_path_factory.mktemp("abl")
    cfg = tiny(tmp)
    run_dir, rows = run_ablation(cfg, command="test")
    return cfg, run_dir, rows


def test_ablation_runs_every_cell_and_writes_its_tables(finished):
    cfg, run_dir, rows = finished
    assert sorted(p.name for p in run_dir.iterdir()) == sorted([*ablate.FILES, "runs", "provenance.json"])
    assert [(r["masking"], r["seed"]) for r in rows] == [("none", 0), ("primary_secondary", 0)]
    with open(run_dir / "ablate.csv") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == list(CSV_COLUMNS) and len(table) == 2
    for r, t in zip(rows, table, strict=True):
        assert 1 <= r["simulations"] <= cfg.budget and r["stop"] == "budget"
        assert r["score"] >= r["initial_score"] - 1e-12 and r["gain"] == r["score"] - r["initial_score"]
        assert float(t["score"]) == pytest.approx(r["score"], rel=1e-12) and t["cell"] == r["cell"]
        assert set(r["metrics"]) == {"upfront_left", "upfront_right", "tunnel"}
        assert (run_dir / "runs" / r["cell"] / "ppo" / "mappo" / "seed0" / "log.csv").is_file()
    data = json.loads((run_dir / "ablate.json").read_text())
    assert len(data["rows"]) == 2 and len(data["cells"]) == 2
    [eff] = data["effects"]
    assert eff["factor"] == "masking" and eff["pairs"] == 1
    assert eff["gain_diff_mean"] == pytest.approx(rows[1]["gain"] - rows[0]["gain"], abs=1e-12)
    assert rows[0]["initial_score"] == rows[1]["initial_score"]  # one reference: gains differ as scores do
    md = (run_dir / "ablate.md").read_text()
    assert "## Paired effects" in md and "| masking | primary_secondary vs none | 1 |" in md
    assert "- command: `test`" in md


def test_active_agents_are_those_the_env_masks_in_training(finished):
    _, _, rows = finished
    for r in rows:
        env = load_env_config("default", {"scenarios": {r["scenario"]: 1.0}, "reference.pin_seed": r["seed"],
                                          "masking.mode": r["masking"]})  # fmt: skip
        core = CalibrationCore(env, batch_size=1)
        core.reset()
        assert r["active_agents"] == int(core.active[0].sum()) and r["n_agents"] == core.A
    none, ps = rows
    assert none["active_agents"] == none["n_agents"] > ps["active_agents"] > 0  # offset: part of the front masked


def test_a_row_is_the_results_table_run_of_its_cell(finished, tmp_path):
    """Rerun one cell through the results table's own functions: the same numbers (same seeds, same reference)."""
    cfg, _, rows = finished
    r = rows[1]
    cell = {f: r[f] for f in FACTORS}
    cc = cell_compare_config(cfg, cell, 0)
    assert cc.env_overrides["masking.mode"] == "primary_secondary" and cfg.score == cell["reward"]
    problem = build_problem(problem_config(cc, 0))  # the results table's own problem (it ranks by the env's reward)
    direct = outcome_row(cc, problem, run_ppo(cc, "mappo", 0, problem, tmp_path))
    for k in ("score", "initial_score", "simulations", "area_worst", "dfd_worst", "rmse_worst", "param_error"):
        assert direct[k] == pytest.approx(r[k], rel=1e-12, abs=1e-15), k
    assert direct["history"] == r["history"]


def test_the_yardstick_is_the_score_form_whatever_the_cell_trained_on(short, tmp_path):
    cfg = tiny(tmp_path, score="paper_factor")
    problem = reference_problem(cfg, "offset40_left", 0)
    m = problem.evaluate(problem.zeros(1))
    from marlcrash.reward import Reward, load_reward_config

    torch.testing.assert_close(problem.score(m), Reward(load_reward_config("paper_factor")).score(m))
    assert not torch.allclose(problem.score(m), Reward(load_reward_config("log_ratio")).score(m))


def test_resume_skips_finished_runs_and_refuses_a_changed_protocol(finished, tmp_path, monkeypatch):
    _, run_dir, rows = finished
    shutil.copytree(run_dir, tmp_path / "runs" / "ablate" / "t")  # the finished run, seed 0 only
    data = tiny_data(tmp_path, seeds=[0, 1], resume=True, plots=False)
    calls = []
    real = ablate.run_cell

    def counting(config, cell, seed, *a, **kw):
        calls.append((cell_name(cell), seed))
        return real(config, cell, seed, *a, **kw)

    monkeypatch.setattr(ablate, "run_cell", counting)
    _, more = run_ablation(load_ablation_config(data, source="test"))
    assert sorted(s for _, s in calls) == [1, 1] and len(more) == 4
    assert more[:2] == json.loads(json.dumps(rows))  # the finished rows, as saved
    with pytest.raises(ConfigError) as e:
        run_ablation(load_ablation_config({**data, "budget": 32}, source="test"))
    assert e.value.key == "budget" and "would not compare" in str(e.value)
    with pytest.raises(ConfigError) as e:
        run_ablation(load_ablation_config({**data, "resume": False}, source="test"))
    assert e.value.key == "name"


def test_resume_refuses_a_level_spelling_the_setting_of_finished_rows(finished, tmp_path, monkeypatch):
    """``primary_secondary+sat`` is the finished ``primary_secondary`` (the env's saturation preference is on)."""
    _, run_dir, _ = finished
    shutil.copytree(run_dir, tmp_path / "runs" / "ablate" / "t")
    monkeypatch.setattr(ablate, "run_cell", lambda *a, **kw: pytest.fail("ran a cell"))
    data = tiny_data(tmp_path, masking=["none", "primary_secondary+sat"], resume=True, plots=False)
    with pytest.raises(ConfigError) as e:
        run_ablation(load_ablation_config(data, source="test"))
    assert e.value.key == "masking[1]" and "'primary_secondary'" in str(e.value), str(e.value)


def test_resume_reads_rows_written_before_acting_cells_were_counted(finished, tmp_path, monkeypatch):
    """An ablation started before the ``acting_cells`` column resumes: its rows show ``-`` there, the new ones the
    count."""
    _, run_dir, rows = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)
    record = json.loads((dst / "ablate.json").read_text())
    for r in record["rows"]:
        del r["acting_cells"]
    (dst / "ablate.json").write_text(json.dumps(record))
    data = tiny_data(tmp_path, seeds=[0, 1], resume=True, plots=False)
    _, more = run_ablation(load_ablation_config(data, source="test"))
    assert [r["acting_cells"] for r in more[:2]] == [None, None]
    assert [r["acting_cells"] for r in more[2:]] == [r["acting_cells"] for r in rows] and None not in more[2:]
    with open(dst / "ablate.csv") as fh:
        assert [t["acting_cells"] for t in csv.DictReader(fh)] == ["", "", *(str(r["acting_cells"]) for r in rows)]
    cells = json.loads((dst / "ablate.json").read_text())["cells"]  # per cell: the count its newer rows give
    assert [c["acting_cells"] for c in cells] == [r["acting_cells"] for r in rows]
    assert "| active | acting cells |" in (dst / "ablate.md").read_text()


def test_a_diverged_run_is_standard_json_loses_its_pairs_and_resumes(finished, tmp_path, monkeypatch):
    """ablate.json held ``-Infinity`` (score, gain) and ``NaN`` (areas) for a run whose every candidate diverged: jq
    and JavaScript refuse the whole file. They are null there, the run loses its pairs, and a resume reads them
    back and draws the plot."""
    import re

    from test_outputs import _strict

    _, run_dir, rows = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)
    record = json.loads((dst / "ablate.json").read_text())  # as written before: Python's -Infinity and NaN
    r = record["rows"][1]
    r["score"] = r["gain"] = float("-inf")
    r["area_worst"] = float("nan")
    r["history"] = [[h[0], float("-inf")] for h in r["history"]]
    (dst / "ablate.json").write_text(json.dumps(record))
    real = ablate.run_ppo

    def diverging(cc, algorithm, seed, problem, root):  # seed 1, masking primary_secondary: every candidate diverges
        out = real(cc, algorithm, seed, problem, root)
        if seed == 1 and cc.env_overrides["masking.mode"] == "primary_secondary":
            out.progress.best_score = float("-inf")
            out.progress.history = [dataclasses.replace(h, best=float("-inf")) for h in out.progress.history]
        return out

    monkeypatch.setattr(ablate, "run_ppo", diverging)
    said: list[str] = []
    data = tiny_data(tmp_path, seeds=[0, 1], resume=True, plots=True)
    _, more = run_ablation(load_ablation_config(data, source="test"), progress=said.append)
    assert [(m["masking"], m["seed"]) for m in more] == [("none", 0), ("primary_secondary", 0), ("none", 1),
                                                         ("primary_secondary", 1)]  # fmt: skip
    for m in (more[1], more[3]):
        assert m["score"] is None and m["gain"] is None and {h[1] for h in m["history"]} == {None}
    assert more[1]["area_worst"] is None and more[0] == json.loads(json.dumps(rows[0]))
    assert "primary_secondary" in said[1] and ": score - (initial " in said[1]
    saved = _strict((dst / "ablate.json").read_text())
    assert saved["rows"] == more
    [eff] = saved["effects"]
    assert eff["pairs"] == 2 and eff["wins"] == 0  # no gain: it loses to the baseline's
    assert eff["gain_diff_mean"] is None and eff["gain_mean"] is None and eff["baseline_gain_mean"] is not None
    cells = {c["masking"]: c for c in saved["cells"]}
    assert cells["primary_secondary"]["gain_mean"] is None and cells["none"]["gain_mean"] is not None
    with open(dst / "ablate.csv") as fh:
        table = list(csv.DictReader(fh))
    assert [(t["score"], t["gain"]) for t in table[1::2]] == [("", "")] * 2 and table[0]["score"] != ""
    md = (dst / "ablate.md").read_text()
    assert not re.search(r"\b(inf|nan)\b", md, re.IGNORECASE), md
    assert "| masking | primary_secondary vs none | 2 | - | 0/2 |" in md
    assert (dst / "ablate.png").stat().st_size > 0
    # the same again: nothing to run, every row read back with its nulls
    monkeypatch.setattr(ablate, "run_cell", lambda *a, **kw: pytest.fail("ran a cell"))
    _, again = run_ablation(load_ablation_config(data, source="test"))
    assert again == more and _strict((dst / "ablate.json").read_text())["effects"] == saved["effects"]


def test_resume_refuses_rows_of_another_reference_or_metric(finished, tmp_path):
    _, run_dir, _ = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)
    record = json.loads((dst / "ablate.json").read_text())
    for r in record["rows"]:  # as if configs/ had changed since: the same settings, another initial fit
        r["initial_score"] -= 0.5
    (dst / "ablate.json").write_text(json.dumps(record))
    data = tiny_data(tmp_path, masking=["none", "primary_secondary", "primary"], resume=True, plots=False)
    with pytest.raises(ConfigError) as e:
        run_ablation(load_ablation_config(data, source="test"))
    assert e.value.key == "resume" and "would not compare" in str(e.value)


def test_a_picture_of_an_earlier_run_does_not_survive_plots_false(finished, tmp_path):
    """``plots=false`` kept the ablate.png an earlier run drew in the folder, beside tables it no longer showed: it
    looked like this run's picture."""
    _, run_dir, _ = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)
    assert (dst / "ablate.png").is_file()  # the finished run's picture
    _, rows = run_ablation(load_ablation_config(tiny_data(tmp_path, resume=True, plots=False), source="test"))
    assert len(rows) == 2 and (dst / "ablate.md").is_file()
    assert not (dst / "ablate.png").exists()


def test_a_resume_removes_the_temporaries_of_the_results_a_kill_left(finished, tmp_path):
    """A kill while ablate.json (.csv, .md, .png, provenance.json) was rewritten left ``.ablate.<hex>.tmp.json``
    beside it, which nothing removed. The ablation, which holds its folder, removes those of its own files;
    other names (another process's outputs) stay."""
    _, run_dir, _ = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)
    stale = [dst / ".ablate.0badf00d.tmp.json", dst / ".ablate.deadbeef.tmp.png", dst / ".provenance.0badf00d.tmp.json"]
    kept = [dst / ".notes.0badf00d.tmp.json", dst / ".ablate.0badf00d.tmp.txt"]
    for p in [*stale, *kept]:
        p.write_text("half a file")
    _, rows = run_ablation(load_ablation_config(tiny_data(tmp_path, resume=True, plots=False), source="test"))
    assert len(rows) == 2
    assert sorted(p for p in dst.iterdir() if ".tmp" in p.name) == sorted(kept)


def test_a_plotting_failure_keeps_the_results_and_names_the_picture(finished, tmp_path, monkeypatch):
    """An error of matplotlib's (not of marlcrash) while drawing ablate.png came out as its raw traceback; the tables
    are written before it, and the failure is a warning that names the picture."""
    import matplotlib.figure

    _, run_dir, rows = finished
    dst = tmp_path / "runs" / "ablate" / "t"
    shutil.copytree(run_dir, dst)

    def broken(*a, **kw):
        raise RuntimeError("backend exploded")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", broken)
    with pytest.warns(UserWarning, match=r"ablate\.png was not drawn: RuntimeError: backend exploded") as w:
        _, again = run_ablation(load_ablation_config(tiny_data(tmp_path, resume=True), source="test"))
    assert "ablate.json" in str(w[0].message)
    assert again == json.loads(json.dumps(rows))
    assert json.loads((dst / "ablate.json").read_text())["rows"] == again
    assert not (dst / "ablate.png").exists()  # neither a partial picture nor the earlier run's
    assert not [p.name for p in dst.iterdir() if p.name.endswith(".tmp.png")]


def test_resume_of_an_unreadable_record_names_it(short, tmp_path):
    cfg = tiny(tmp_path, resume=True)
    cfg.run_dir.mkdir(parents=True)
    (cfg.run_dir / "ablate.json").write_text("{not json")
    with pytest.raises(ConfigError) as e:
        run_ablation(cfg)
    assert e.value.key == "resume" and "ablate.json" in str(e.value)


# --------------------------------------------------------------------------------------- script
def _script(args: list[str], configs: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MARLCRASH_CONFIGS": str(configs), "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, str(REPO / "train" / "ablate.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.mark.slow
def test_script_runs_the_factor_product(short_configs, tmp_path):
    args = ["budget=24", "seeds=[0]", "max_wall_s=null", "ppo.n_envs=2", "ppo.episode_length=3",
            "mappo.minibatch_size=3", "mappo.hidden=[16,16]", "ippo.minibatch_size=3", "ippo.hidden=[16,16]",
            "algorithms=[mappo,ippo]", "masking=[none,primary]", "scenarios=[small_overlap_left]",
            "name=smoke"]  # fmt: skip
    p = _script(args, short_configs, tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["runs"]  # Hydra wrote nothing else
    run_dir = tmp_path / "runs" / "ablate" / "smoke"
    with open(run_dir / "ablate.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted((r["algorithm"], r["masking"]) for r in rows) == sorted(
        itertools.product(["mappo", "ippo"], ["none", "primary"])
    )
    assert (run_dir / "ablate.png").stat().st_size > 0
    assert "| algorithm | ippo vs mappo | 2 (1 reference) | " in p.stdout and '"rows": 4' in p.stdout


@pytest.mark.slow
def test_script_rejects_bad_config_before_running(short_configs, tmp_path):
    p = _script(["masking=[none,sideways]", "name=bad"], short_configs, tmp_path)
    assert p.returncode == 2
    assert "masking[1]" in p.stderr and "sideways" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "runs").exists()


def test_the_standard_error_counts_references_not_pairs():
    """Pairs of one reference are not independent: the scenario factor's pairs at every masking level share the seed's
    references (and a masking level's pairs at every reward form share the scenario's), so the standard error over
    pairs treated them as independent samples and read 2-3x too small with three masking levels. The differences are
    now averaged per reference, and the error is taken over references (``references``; ``None`` below two)."""
    rows = [
        _row(0, 0.0, 0.01), _row(0, 0.0, 0.01, masking="primary"),
        _row(1, 0.0, 0.01), _row(1, 0.0, 0.01, masking="primary"),
        _row(0, 1.0, 0.01, scenario="s2"), _row(0, 1.2, 0.01, scenario="s2", masking="primary"),
        _row(1, -1.0, 0.01, scenario="s2"), _row(1, -0.8, 0.01, scenario="s2", masking="primary"),
    ]  # fmt: skip
    levels = {"algorithm": ["mappo"], "masking": ["none", "primary"], "scenario": ["s1", "s2"],
              "granularity": ["subassembly"], "reward": ["log_ratio"]}  # fmt: skip
    eff = {(e["factor"], e["level"]): e for e in paired_effects(rows, levels)}
    s = eff["scenario", "s2"]  # 4 pairs over 2 seeds: per seed 1.1 and -0.9
    assert (s["pairs"], s["references"]) == (4, 2)
    assert s["gain_diff_mean"] == pytest.approx(0.1, abs=1e-15)
    assert s["gain_diff_se"] == pytest.approx(np.std([1.1, -0.9], ddof=1) / math.sqrt(2), abs=1e-15)
    m = eff["masking", "primary"]  # 4 pairs on 4 references (s1 and s2, seeds 0 and 1)
    assert (m["pairs"], m["references"]) == (4, 4)
    assert m["gain_diff_se"] == pytest.approx(np.std([0.0, 0.0, 0.2, 0.2], ddof=1) / 2.0, abs=1e-15)
    one = {(e["factor"], e["level"]): e for e in paired_effects([r for r in rows if r["seed"] == 0], levels)}
    assert one["scenario", "s2"]["references"] == 1 and one["scenario", "s2"]["gain_diff_se"] is None
    md = ablate.markdown(ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1", "s2"]),
                         [_table_row(r["seed"], r["gain"], r["area_worst"], masking=r["masking"],
                                     scenario=r["scenario"]) for r in rows], None, "today")  # fmt: skip
    assert "| scenario | s2 vs s1 | 4 (2 references) | +0.1000 ± 1.0000 |" in md
    assert "| masking | primary vs none | 4 | +0.1000 ± 0.0577 |" in md


def test_the_mean_gain_difference_is_the_mean_the_standard_error_describes():
    """``gain_diff_mean`` averaged over pairs while ``gain_diff_se`` is the standard error of the per-reference
    averages: with unequal pair counts per reference (a partial or resumed ablation) the printed 'mean ± s.e.' were of
    two different estimators. The mean is now the mean of the per-reference averages; with equal counts it is the
    mean over pairs, as before."""
    rows = [
        _row(0, 0.0, 0.01), _row(0, 0.0, 0.01, masking="primary"),
        _row(1, 0.0, 0.01),  # masking primary on seed 1 not run yet
        _row(0, 1.0, 0.01, scenario="s2"), _row(0, 2.0, 0.01, scenario="s2", masking="primary"),
        _row(1, -1.0, 0.01, scenario="s2"),
    ]  # fmt: skip
    levels = {"algorithm": ["mappo"], "masking": ["none", "primary"], "scenario": ["s1", "s2"],
              "granularity": ["subassembly"], "reward": ["log_ratio"]}  # fmt: skip
    [s] = [e for e in paired_effects(rows, levels) if e["factor"] == "scenario"]
    per_ref = [np.mean([1.0, 2.0]), -1.0]  # seed 0: two pairs, seed 1: one
    assert (s["pairs"], s["references"]) == (3, 2)
    assert s["gain_diff_mean"] == pytest.approx(np.mean(per_ref), abs=1e-15)  # 0.25; over pairs it read 0.667
    assert s["gain_diff_se"] == pytest.approx(np.std(per_ref, ddof=1) / math.sqrt(2), abs=1e-15)
    done = [_row(1, 0.0, 0.01, masking="primary"), _row(1, 0.5, 0.01, scenario="s2", masking="primary")]
    even = paired_effects(rows + done, levels)
    [s2] = [e for e in even if e["factor"] == "scenario"]  # every reference two pairs: the mean over pairs
    assert s2["gain_diff_mean"] == pytest.approx(np.mean([1.0, 2.0, -1.0, 0.5]), abs=1e-15)


def test_the_success_test_in_ablate_md_leaves_out_a_skipped_metric():
    """``success.<metric>: null`` skips that metric (the yaml says so), yet ablate.md and compare.md stated the test as
    'every sensor A < None m, ...': a threshold of ``None`` that no run was held to. The test they state names the
    thresholds set, with their units, and only those."""
    from marlcrash.calibrate.compare import CompareConfig
    from marlcrash.calibrate.compare import markdown as compare_markdown
    from marlcrash.calibrate.problem import SuccessConfig

    success = SuccessConfig(area=None, dfd=0.3, rmse=None)
    md = ablate.markdown(ablate.AblationConfig(success=success), [], None, "today")
    assert "passed = every sensor DFD < 0.3 m/s;" in md and "None" not in md
    md = compare_markdown(CompareConfig(success=SuccessConfig(area=0.002, dfd=None, rmse=0.1)), [], None, "today")
    assert "success = every sensor A < 0.002 m, RMSE < 0.1 m/s " in md and "None" not in md
    default = ablate.markdown(ablate.AblationConfig(), [], None, "today")  # every metric: as before
    assert "passed = every sensor A < 0.0015 m, DFD < 0.335 m/s, RMSE < 0.1511 m/s;" in default


def test_the_mean_gain_curve_of_a_level_leaves_no_run_out(tmp_path, monkeypatch):
    """The lower panels of ablate.png averaged the gain-so-far curves with ``nanmean``: a run whose every candidate
    diverged (no gain) was dropped, so the level's curve, labelled '2 runs', was the other run's alone, where the
    tables and the upper panel give that level no mean. The curve is now the mean over every run of the level where
    each has a number, and the legend says how many runs have no gain."""
    figures = []
    monkeypatch.setattr(ablate, "save_figure", lambda fig, path, key=None: figures.append(fig) or path)

    def row(seed, history, masking="none"):
        r = _table_row(seed, None if history[-1][1] is None else history[-1][1] + 4.0, 0.01, masking=masking)
        return {**r, "initial_score": -4.0, "simulations": 6, "history": history}

    rows = [row(0, [[2, -3.0], [5, -2.0]]), row(1, [[2, -3.5], [5, -2.5]]),
            row(0, [[2, -3.0], [5, -1.0]], "primary"), row(1, [[2, None], [5, None]], "primary")]  # fmt: skip
    cfg = ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1"], budget=6)
    ablate.plot_ablation(cfg, rows, tmp_path / "ablate.png")
    [fig] = figures
    top, bottom = fig.axes[:2]
    lines = {ln.get_label(): ln for ln in bottom.get_lines()}
    assert set(lines) == {"none (2 runs)", "primary (2 runs, 1 without a gain: no mean)"}
    x, y = (np.asarray(v, dtype=np.float64) for v in lines["none (2 runs)"].get_data())
    np.testing.assert_allclose(y[x >= 5], 4.0 - 2.25)  # (-2 + -2.5) / 2 + 4
    assert np.isnan(y[x < 2]).all()
    assert np.isnan(np.asarray(lines["primary (2 runs, 1 without a gain: no mean)"].get_ydata(), float)).all()
    from matplotlib.collections import LineCollection

    assert sum(isinstance(c, LineCollection) for c in top.collections) == 1  # none's mean; primary has none


def test_a_cell_of_one_seed_has_no_spread_in_ablate_md():
    """With one seed per cell the per-cell table printed '± 0' (the population std of one value), which reads as a
    measured zero spread. Below two seeds it prints '± -' (no spread); two seeds or more keep the population std."""
    rows = [_table_row(0, -1.0, 0.04), _table_row(0, -0.5, 0.01, masking="primary"),
            _table_row(1, -1.5, 0.02, masking="primary")]  # fmt: skip
    md = ablate.markdown(ablate.AblationConfig(masking=["none", "primary"], scenarios=["s1"]), rows, None, "today")
    per_cell = md.split("## Per cell")[1].split("## Per run")[0]
    [one] = [line for line in per_cell.splitlines() if "| none |" in line]
    assert "± 0" not in one and "| 0/1 | -1 ± - | -3 ± - | 0.04 ± - |" in one
    [two] = [line for line in per_cell.splitlines() if "| primary |" in line]
    assert "| 0/2 | -1 ± 0.5 | -3 ± 0.5 | 0.015 ± 0.005 | 0.5 ± 0 |" in two
    assert "a single seed: no std (-)" in md


def test_ablate_md_says_the_median_sims_to_success_is_over_the_runs_that_passed():
    """The per-cell table's 'median sims to success' is the median over the runs in which a candidate met the success
    test only (:func:`~marlcrash.calibrate.compare.summarize`); compare.md said so, ablate.md did not, so a cell with
    1/3 passed read as a median over three runs. It now says so in compare.md's words."""
    from marlcrash.calibrate.compare import CompareConfig
    from marlcrash.calibrate.compare import markdown as compare_markdown

    said = "sims to success: simulations until the first candidate met it (median over the runs where one did)"
    assert said in compare_markdown(CompareConfig(), [], None, "today")
    assert said in ablate.markdown(ablate.AblationConfig(), [], None, "today")
