"""Ablations (DESIGN 6): masking level x scenario x action granularity x reward form x algorithm x seeds.

    python train/ablate.py                                        # masking levels x 2 scenarios x seeds 0, 1, 2
    python train/ablate.py masking=[none,primary_secondary] scenarios=[full_width_40] rewards=[log_ratio,paper_factor]
    python train/ablate.py granularity=[subassembly,cell] budget=2000 name=gran
    python train/ablate.py 'masking=[primary_secondary,primary_secondary+region,primary_secondary+nosat]' name=rules
    python train/ablate.py name=gran resume=true                  # after a kill: skip finished runs

Writes ``<out_dir>/ablate/<name>/``: ablate.json, ablate.csv, ablate.md (rewritten after every run),
ablate.png, and every run's training log under runs/<cell>/ppo/<algorithm>/seed<s>/.
"""

from __future__ import annotations

import json
import shlex
import sys

import hydra
from omegaconf import DictConfig

from marlcrash.calibrate.ablate import load_ablation_config, run_ablation
from marlcrash.calibrate.entry import (
    config_mapping,
    exit_on_bad_overrides,
    fixed_run_folder,
    name_default_run,
    run_script,
)
from marlcrash.errors import MarlcrashError


@hydra.main(version_base=None, config_path="../configs/train", config_name="ablate")
def main(cfg: DictConfig) -> None:
    command = ("python train/ablate.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])).strip()
    try:
        data = config_mapping(cfg)
        config = load_ablation_config(data, source="configs/train/ablate.yaml")
        name_default_run(cfg, config, lambda c: c.run_dir)  # multirun jobs started in one second: one folder each
        run_dir, rows = run_ablation(config, command=command, progress=lambda msg: print(msg, flush=True))
    except MarlcrashError as e:  # bad config or input: a message, not a traceback
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print((run_dir / "ablate.md").read_text())
    print(json.dumps({"run": str(run_dir), "rows": len(rows)}))


def check_job(cfg, data, given):
    """A multirun job's values and run folder, checked before the sweep's first job runs (entry.check_sweep)."""
    config = load_ablation_config(data, source="configs/train/ablate.yaml")
    return fixed_run_folder(cfg, config, lambda c: c.run_dir, given)


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "ablate", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
