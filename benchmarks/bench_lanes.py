"""Fast-path throughput per simulation at each chunk width (simulations per vectorised chunk).

Prints :func:`marlcrash.sim.bench.lane_study`: simulations per second at each width, their ratio to
the fastest width measured in the same run, and the efficiencies the kernel uses to choose its width
(``marlcrash.sim.kernels.LANE_EFFICIENCY``).

Usage: python benchmarks/bench_lanes.py [--widths 1 2 4 8 16 32 64 128] [--batch 128] [--repeat 3]
       [--float32] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.sim.bench import format_lane_study, lane_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--widths", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128])
    ap.add_argument("--batch", type=int, default=128, help="simulations per timed run (at least threads x width)")
    ap.add_argument("--repeat", type=int, default=3, help="timing rounds; each width keeps its best")
    ap.add_argument("--float32", action="store_true", help="simulate in float32 (config dtype)")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    if min(args.widths) < 1 or args.batch < 1 or args.repeat < 1:
        ap.error("--widths, --batch and --repeat must be >= 1")
    res = lane_study(
        tuple(args.widths),
        batch=args.batch,
        repeats=args.repeat,
        sim_overrides={"dtype": "float32"} if args.float32 else None,
    )
    print(json.dumps(res, indent=1) if args.json else format_lane_study(res))


if __name__ == "__main__":
    main()
