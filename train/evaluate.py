"""Evaluate a training run's latest checkpoint (DESIGN 6): deterministic policy on the twin reference.

    python train/evaluate.py run=runs/mappo/<name> [iterations=30]

Rewrites summary.json, eval_metrics.csv/.md, calibrated.npz, pulses.png, learning_curves.png in the run folder.
"""

from __future__ import annotations

import json
import sys

from marlcrash.calibrate.evaluate import evaluate_run
from marlcrash.errors import MarlcrashError

USAGE = "usage: python train/evaluate.py run=<run folder> [iterations=<calibration steps>]"


def parse(argv: list[str]) -> dict[str, str]:
    """``key=value`` arguments; only ``run`` and ``iterations`` are known."""
    args = {}
    for a in argv:
        key, sep, value = a.partition("=")
        if not sep or key not in ("run", "iterations"):
            raise SystemExit(f"error: unexpected argument {a!r}\n{USAGE}")
        args[key] = value
    if "run" not in args:
        raise SystemExit(f"error: missing run=<run folder>\n{USAGE}")
    return args


def main() -> None:
    args = parse(sys.argv[1:])
    try:
        iterations = int(args["iterations"]) if "iterations" in args else None
    except ValueError:
        raise SystemExit(f"error: iterations must be an integer, got {args['iterations']!r}") from None
    try:
        s = evaluate_run(args["run"], iterations=iterations)
    except MarlcrashError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    keys = ("selected_iteration", "all_passed", "final_metrics", "initial_metrics")
    print(json.dumps({k: s[k] for k in keys}, indent=1))


if __name__ == "__main__":
    main()
