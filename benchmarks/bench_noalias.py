"""The fast path and the roofline pass compiled ``noalias`` against the same code without, timed in one run.

Prints :func:`marlcrash.sim.bench.noalias_study`: simulations per second of the kernel and of the roofline's link
pass, each with its arrays marked ``noalias`` (:mod:`marlcrash.sim.noalias`) and recompiled without, their ratios,
and the largest difference between the two kernels' outputs, relative to each output's magnitude (rounding only).

Usage: python benchmarks/bench_noalias.py [--batch 1024] [--repeat 3] [--float32] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.sim.bench import format_noalias_study, noalias_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1024, help="simulations per timed run")
    ap.add_argument("--repeat", type=int, default=3, help="timing rounds; each variant keeps its best")
    ap.add_argument("--float32", action="store_true", help="simulate in float32 (config dtype)")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    if args.batch < 1 or args.repeat < 1:
        ap.error("--batch and --repeat must be >= 1")
    res = noalias_study(args.batch, args.repeat, "float32" if args.float32 else "float64")
    print(json.dumps(res, indent=1) if args.json else format_noalias_study(res))


if __name__ == "__main__":
    main()
