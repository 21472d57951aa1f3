"""The surrogate on a GPU: the eager torch backend and its CUDA-graph replay against a launch floor, a bandwidth
roofline and the compiled CPU kernel, all measured in one run.

Prints, per precision, simulations per second of the default car's complete 150 ms ``full_width_56`` crash at each
batch size with the surrogate moved to the device (``Surrogate.to``) for the ``torch`` and ``cuda_graph`` backends,
the eager time per integration step at the smallest batch (its launch floor), a roofline from the device's copy
bandwidth, and the compiled CPU kernel (numba, the host's cores) at B = 1024 in the same run
(:func:`marlcrash.sim.bench.device_study`).

Usage: python benchmarks/bench_gpu.py [--device cuda] [--batch-sizes 1 64 1024 8192] [--dtypes float64 float32]
[--json]

Needs a CUDA device; ``--device cpu`` times the torch reference path on this machine instead (slow: use small
batches).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.cli import _batch_size, _positive_int
from marlcrash.errors import ConfigError
from marlcrash.sim.bench import device_study, format_device_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", help="torch device (default cuda)")
    ap.add_argument("--batch-sizes", type=_batch_size, nargs="+", default=[1, 64, 1024, 8192], help="B timed")
    ap.add_argument("--dtypes", nargs="+", choices=("float64", "float32"), default=["float64", "float32"])
    ap.add_argument("--repeats", type=_positive_int, default=2, help="timed runs per rate (best kept)")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    try:
        res = device_study(args.device, tuple(args.batch_sizes), tuple(args.dtypes), repeats=args.repeats)
    except ConfigError as e:
        ap.exit(2, f"error: {e}\n")
    print(json.dumps(res, indent=1) if args.json else format_device_study(res))


if __name__ == "__main__":
    main()
