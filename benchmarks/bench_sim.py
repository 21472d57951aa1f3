"""Surrogate throughput on the default car: a thin wrapper printing :func:`marlcrash.sim.bench.run_benchmark`.

Usage: python benchmarks/bench_sim.py [--batches 1 64 1024] [--repeat 2] [--skip-uniform] [--float32] [--json]
       python benchmarks/bench_sim.py --dtypes [--batches 1024] [--repeat 3] [--json]  (float64 vs float32 in turn)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.cli import _batch_size, _positive_int
from marlcrash.sim.bench import dtype_study, format_benchmark, format_dtype_study, run_benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=_batch_size, nargs="+", default=[1, 64, 1024])
    ap.add_argument("--repeat", type=_positive_int, default=2)
    ap.add_argument("--skip-uniform", action="store_true", help="do not time the uniform (fine) model")
    ap.add_argument("--float32", action="store_true", help="simulate in float32 (config dtype)")
    ap.add_argument("--dtypes", action="store_true", help="time float64 against float32 in turn at the largest batch")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    if args.dtypes:
        res = dtype_study(max(args.batches), repeats=args.repeat)
        print(json.dumps(res, indent=1) if args.json else format_dtype_study(res))
        return
    res = run_benchmark(
        tuple(args.batches),
        repeats=args.repeat,
        include_uniform=not args.skip_uniform,
        sim_overrides={"dtype": "float32"} if args.float32 else None,
    )
    if args.json:
        print(json.dumps(res, indent=1))
        return
    print(format_benchmark(res))


if __name__ == "__main__":
    main()
