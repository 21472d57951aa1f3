"""Multi-agent calibration training (DESIGN 6): MAPPO (default), IPPO, single-agent PPO on the joint action.

    python train/train.py                                  # MAPPO, configs/train/train.yaml
    python train/train.py algorithm=ippo seed=1 name=ippo1
    python train/train.py algorithm=ppo_single n_envs=32 algorithm.minibatch_size=64
    python train/train.py resume=true                      # continue the newest run (or resume=runs/mappo/<name>)
    python train/train.py resume=true name=ippo1 algorithm=ippo   # continue that run (an error if it has none)
    python train/train.py resume=true time_limit_s=1200    # ... with more time (its other settings may not change)
    MARLCRASH_CI=1 python train/train.py                   # the 1-2 minute smoke run of CI (the `ci:` overrides;
                                                           # keys given on the command line keep their values)

Writes ``<out_dir>/<algorithm>/<name>/``: config.yaml, log.csv, checkpoint.pt, then the evaluation:
summary.json, eval_metrics.csv/.md, calibrated.npz, pulses.png, learning_curves.png. This script adds
``process_wall_time_s`` to summary.json: the wall time of this process, imports, discretization and
evaluation included, for a run trained by one process; a resume adds none (``train_wall_time_s`` counts the
training of every process, from the checkpoint) and keeps the one a finished run has.
"""

from __future__ import annotations

import time

START = time.perf_counter()  # before the heavy imports: process_wall_time_s counts them too

import sys  # noqa: E402

import hydra  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

from marlcrash.calibrate.entry import (  # noqa: E402
    config_mapping,
    exit_on_bad_overrides,
    fixed_run_folder,
    name_default_run,
    run_script,
)
from marlcrash.calibrate.marl import load_train_config, run_dir_of, train, value_keys  # noqa: E402
from marlcrash.errors import ConfigError, MarlcrashError  # noqa: E402
from marlcrash.outputs import json_text  # noqa: E402

RESUME_KEYS = ("resume", "name", "out_dir", "algorithm")
"""Command-line keys a ``resume=true`` reads (they locate the run folder); a ``resume=<folder>`` reads only itself and
ignores them, with a warning naming them. Every other override goes to :func:`train`: the run's saved config.yaml
takes those of ``RESUME_FREE_KEYS`` (``time_limit_s=1200``) and refuses any other that is not the run's."""


_JOBS = [0]  # jobs this process ran: a multirun (-m seed=0,1,2) runs them all in one process


@hydra.main(version_base=None, config_path="../configs/train", config_name="train")
def main(cfg: DictConfig) -> None:
    start = START if _JOBS[0] == 0 else time.perf_counter()  # a later job's time is its own, not the sweep's
    _JOBS[0] += 1
    try:
        overrides = HydraConfig.get().overrides.task
        given = [o.split("=")[0].lstrip("+~") for o in overrides]
        data = config_mapping(cfg)
        config = load_train_config(  # command-line values win over the ci: block
            data, source="configs/train/train.yaml", explicit=value_keys(given)
        )
        locating = ("resume",) if isinstance(config.resume, str) else RESUME_KEYS  # a folder given: it alone
        if config.resume is True and "name" in given:  # a name given: that run or an error, never the newest instead
            config.resume = str(run_dir_of(config))
        name_default_run(cfg, config, run_dir_of)  # multirun jobs started in one second: one folder each
        if config.resume is not False:
            ignored = [o for o, k in zip(overrides, given, strict=True) if k in RESUME_KEYS and k not in locating]
            if ignored:
                print(f"warning: resume=<folder> continues the run in that folder; ignored: {' '.join(ignored)}",
                      file=sys.stderr)  # fmt: skip
        # the whole job, imports (first job) and discretization included; added while the run folder is held
        stamp = None if config.resume is not False else lambda: {"process_wall_time_s": time.perf_counter() - start}
        result = train(config, summary_extra=stamp, given=[k for k in value_keys(given) if k not in RESUME_KEYS])
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    s = result.summary or {}
    wall = s.get("process_wall_time_s")  # none after a resume (module doc): null, as in summary.json, not 0.0
    print(json_text({
        "run": str(result.run_dir), "iterations": result.iterations, "env_steps": result.env_steps,
        "simulations": result.simulations, "process_wall_time_s": None if wall is None else round(wall, 1),
        "selected_iteration": s.get("selected_iteration"), "all_passed": s.get("all_passed"),
        "final_metrics": s.get("final_metrics"),
    }, indent=1))  # fmt: skip


def check_job(cfg, data, given):
    """A multirun job's values and run folder, checked before the sweep's first job trains (entry.check_sweep)."""
    config = load_train_config(data, source="configs/train/train.yaml", explicit=value_keys(given))
    folder = fixed_run_folder(cfg, config, run_dir_of, given)
    if folder is not None and folder.exists():
        raise ConfigError(f"run folder {folder} exists already; choose another name or resume=true", key="name")
    return folder


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "train", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
