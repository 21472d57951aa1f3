"""Amortized calibration, measured (DESIGN 6): a trained policy vs optimizers from scratch on held-out twins.

    python train/amortized.py run=runs/mappo/<name>
    python train/amortized.py run=runs/mappo/<name> reference_seeds=[101,102,103,104] iterations=24
    python train/amortized.py run=runs/mappo/<name> 'budgets.cmaes=[1,10,100]' '~budgets.gradient' out_dir=cmp

Hydra merges a mapping given on the command line into the file's ``budgets`` (``budgets='{cmaes: [1]}'`` keeps
the other optimizers' budgets): change one with ``budgets.<optimizer>=[...]``, drop one with ``~budgets.<optimizer>``.

Writes ``amortized.csv``, ``amortized.md`` and ``amortized.json`` into the run folder (or ``out_dir``), after every
finished piece (marked incomplete) and at the end. ``resume=true`` continues an interrupted comparison there:

    python train/amortized.py run=runs/mappo/<name> resume=true
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from marlcrash.calibrate.amortized import (
    amortized_comparison,
    check_comparison_dir,
    hold_comparison_dir,
    load_amortized_config,
    read_comparison,
    write_comparison,
)
from marlcrash.calibrate.entry import config_mapping, exit_on_bad_overrides, run_script
from marlcrash.errors import ConfigError, MarlcrashError
from marlcrash.outputs import check_output_dir


@hydra.main(version_base=None, config_path="../configs/train", config_name="amortized")
def main(cfg: DictConfig) -> None:
    command = "python train/amortized.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    try:
        data = config_mapping(cfg)
        config = load_amortized_config(data, source="configs/train/amortized.yaml")
        if config.run is None:  # a resume looked for its comparison in the launch folder and named key 'resume'
            raise ConfigError("expected a training run folder, e.g. run=runs/mappo/<name>", key="run")
        where = check_output_dir(config.out_dir or config.run, "out_dir" if config.out_dir else "run")
        # one comparison per folder; the run folder (out_dir null) or a resumed one must exist: a missing one is said
        with hold_comparison_dir(where, create=config.out_dir is not None and not config.resume):
            # before the work, not after it: a new comparison needs a folder without one, a resumed one its record
            done = read_comparison(where) if config.resume else None
            out = where if config.resume else check_comparison_dir(where)

            def keep(partial):  # the tables so far after every finished piece: a failure or kill keeps them
                write_comparison(partial, out, command=command.strip(), replace=True)

            try:
                comparison = amortized_comparison(config, progress=lambda msg: print(msg, flush=True), partial=keep,
                                                  done=done)  # fmt: skip
            except KeyboardInterrupt as e:
                if (out / "amortized.json").is_file():  # a new comparison's folder holds none (checked above)
                    e.add_note(f"{out} keeps the finished pieces (amortized.json); the same command with resume=true "
                               "continues it")  # fmt: skip
                raise
            paths = write_comparison(comparison, out, command=command.strip(), replace=True)
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    print(Path(paths["amortized.md"]).read_text())
    print(json.dumps({k: str(v) for k, v in paths.items()}))


def check_job(cfg, data, given):
    """A multirun job's values, checked before the sweep's first job runs (entry.check_sweep)."""
    load_amortized_config(data, source="configs/train/amortized.yaml")


if __name__ == "__main__":
    exit_on_bad_overrides(__file__, "amortized", check_job=check_job)  # Hydra errors as ours; a sweep checked first
    run_script(main)  # Ctrl-C: 'interrupted' and what the run kept, no traceback
