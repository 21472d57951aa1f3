"""Optimizer baselines on a simulation budget (DESIGN 6).

    python train/baseline.py method=cmaes budget=2000 seed=1
    python train/baseline.py method=gradient problem.duration=0.05 gradient.lr=0.01 name=try1
    python train/baseline.py method=lm budget=20000 lm.restart_radius=0.1

Writes ``<out_dir>/<method>/<name>/``: summary.json, history.csv, config.json, provenance.json, best.pt, velocity.png.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from marlcrash.calibrate import build_problem, load_run_config, run_baseline, write_run
from marlcrash.calibrate.baselines import run_folder, run_path, run_record
from marlcrash.calibrate.entry import (
    config_mapping,
    exit_on_bad_overrides,
    fixed_run_folder,
    name_default_run,
    run_script,
)
from marlcrash.errors import MarlcrashError
from marlcrash.outputs import json_text


@hydra.main(version_base=None, config_path="../configs/train", config_name="baseline")
def main(cfg: DictConfig) -> None:
    try:
        data = config_mapping(cfg)
        config = load_run_config(data, source="configs/train/baseline.yaml")
        name_default_run(cfg, config, run_path)  # multirun jobs started in one second: one folder each
        run_folder(config)  # an existing run name fails now, not after the budget is spent
        record = run_record(config)  # the inputs as the run starts (provenance.json)
        problem = build_problem(config.problem)
        result = run_baseline(config, problem)
        folder = write_run(config, problem, result, record)
    except MarlcrashError as e:  # bad config or input: a message, not a traceback
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    s = result.summary()
    print(json_text({"run": str(folder), "simulations": s["simulations"], "stop": s["stop"],
                      "stop_reason": s["stop_reason"], "sims_to_success": s["sims_to_success"],
                      "initial_score": s["initial_score"], "best_score": s["best_score"],
                      "wall_time_s": round(s["wall_time_s"], 2)}, indent=None))  # fmt: skip


def check_job(cfg, data, given):
    """A multirun job's values and run folder, checked before the sweep's first job runs (entry.check_sweep)."""
    config = load_run_config(data, source="configs/train/baseline.yaml")
    folder = fixed_run_folder(cfg, config, run_path, given)
    return None if folder is None else run_folder(config)  # an existing one refused, as a single run does


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "baseline", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
