"""Evaluate a training run's checkpoint (DESIGN 6): deterministic policy on the run's reference.

    python train/evaluate.py run=runs/mappo/<name>                 # the latest checkpoint
    python train/evaluate.py run=runs/mappo/<name> checkpoint=40   # the snapshot kept after iteration 40
    python train/evaluate.py run=runs/mappo/<name> iterations=30

The latest checkpoint with the run's own settings and inputs redoes the run's evaluation (summary.json,
eval_metrics.csv/.md, calibrated.npz, pulses.png, learning_curves.png in the run folder). Anything else never
replaces those files: a kept snapshot, another checkpoint file, other ``iterations``, or configs or code changed
since the run started (provenance.json) write to ``<run>/eval/<checkpoint file stem>[_steps<n>]/`` (a file
outside the run's checkpoints gets 8 hex digits of its path after the stem); the printed ``eval_dir`` says where.
Settings: configs/train/evaluate.yaml.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from marlcrash.calibrate.entry import config_mapping, exit_on_bad_overrides, run_script
from marlcrash.calibrate.evaluate import evaluate_run, load_evaluate_config
from marlcrash.errors import MarlcrashError
from marlcrash.outputs import json_text


@hydra.main(version_base=None, config_path="../configs/train", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    try:
        data = config_mapping(cfg)
        config = load_evaluate_config(data, source="configs/train/evaluate.yaml")
        assert config.run is not None  # validate() requires a run folder
        s = evaluate_run(config.run, iterations=config.iterations, checkpoint=config.checkpoint)
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    keys: tuple[str, ...] = ("eval_dir", "checkpoint", "iterations_trained", "selected_iteration", "all_passed")
    keys += ("final_metrics", "initial_metrics")
    print(json_text({k: s[k] for k in keys}, indent=1))


def check_job(cfg, data, given):
    """A multirun job's values, checked before the sweep's first job runs (entry.check_sweep)."""
    load_evaluate_config(data, source="configs/train/evaluate.yaml")


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "evaluate", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
