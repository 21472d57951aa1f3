"""The results table of issue 5: MAPPO, IPPO, single-agent PPO, random search, CMA-ES, gradient descent, LM.

    python train/compare.py                                       # 7 methods x seeds 0, 1, 2, budget 2000
    python train/compare.py methods=[cmaes,mappo] seeds=[0] budget=500 name=try1
    python train/compare.py name=try1 resume=true                 # after a kill: skip finished method/seed pairs

Writes ``<out_dir>/compare/<name>/``: compare.json, compare.csv, compare.md (rewritten after every run),
and the PPO runs' training logs under ppo/<method>/seed<s>/.
"""

from __future__ import annotations

import json
import shlex
import sys

import hydra
from omegaconf import DictConfig

from marlcrash.calibrate.compare import load_compare_config, run_comparison
from marlcrash.calibrate.entry import (
    config_mapping,
    exit_on_bad_overrides,
    fixed_run_folder,
    name_default_run,
    run_script,
)
from marlcrash.errors import MarlcrashError


@hydra.main(version_base=None, config_path="../configs/train", config_name="compare")
def main(cfg: DictConfig) -> None:
    command = ("python train/compare.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])).strip()
    try:
        data = config_mapping(cfg)
        config = load_compare_config(data, source="configs/train/compare.yaml")
        name_default_run(cfg, config, lambda c: c.run_dir)  # multirun jobs started in one second: one folder each
        run_dir, rows = run_comparison(config, command=command, progress=lambda msg: print(msg, flush=True))
    except MarlcrashError as e:  # bad config or input: a message, not a traceback
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print((run_dir / "compare.md").read_text())
    print(json.dumps({"run": str(run_dir), "rows": len(rows)}))


def check_job(cfg, data, given):
    """A multirun job's values and run folder, checked before the sweep's first job runs (entry.check_sweep)."""
    config = load_compare_config(data, source="configs/train/compare.yaml")
    return fixed_run_folder(cfg, config, lambda c: c.run_dir, given)


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "compare", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
