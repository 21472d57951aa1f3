"""How many explicit steps the surrogate's physics needs, and the roofline at each step count.

Prints, per ``(substeps, springback relief)`` variant, the default car's full-width 40 km/h figures,
whether every DESIGN 4 plausibility check passes (:func:`marlcrash.sim.bench.plausibility_checks`),
the fast path's simulations per second and the roofline measured in the same run. The fewest steps
that pass every check bound what any kernel of this explicit scheme can reach on this machine.

Usage: python benchmarks/bench_substeps.py [--batch 256] [--json] [--cell-volume 1e-3 --substeps 1 2 4 8]

``--cell-volume`` discretizes the car with coarser (or finer) cells than ``configs/cells.yaml``; ``--substeps``
grades only those step counts, without springback relief and with the configured mass floor.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.cli import _batch_size
from marlcrash.sim.bench import format_substep_study, substep_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=_batch_size, default=256, help="simulations per timed batch")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    ap.add_argument("--cell-volume", type=float, default=None, help="target cell volume [m^3] (default: cells.yaml)")
    ap.add_argument("--substeps", type=int, nargs="+", default=None, help="only these substep counts (no relief)")
    args = ap.parse_args()
    if args.cell_volume is not None and not args.cell_volume > 0:
        ap.error(f"--cell-volume: expected a volume > 0 m^3, got {args.cell_volume}")
    if args.substeps is not None and min(args.substeps) < 1:
        ap.error(f"--substeps: expected counts >= 1, got {args.substeps}")
    kw: dict[str, Any] = {} if args.substeps is None else {"variants": tuple((s, False) for s in args.substeps)}
    res = substep_study(batch=args.batch, target_cell_volume=args.cell_volume, **kw)
    print(json.dumps(res, indent=1) if args.json else format_substep_study(res))


if __name__ == "__main__":
    main()
