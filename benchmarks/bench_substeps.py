"""How many explicit steps the surrogate's physics needs, and the roofline at each step count.

Prints, per ``(substeps, springback relief)`` variant, the default car's full-width 40 km/h figures,
whether every DESIGN 4 plausibility check passes (:func:`marlcrash.sim.bench.plausibility_checks`),
the fast path's simulations per second and the roofline measured in the same run. The fewest steps
that pass every check bound what any kernel of this explicit scheme can reach on this machine.

Usage: python benchmarks/bench_substeps.py [--batch 256] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.sim.bench import format_substep_study, substep_study


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=256, help="simulations per timed batch")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    res = substep_study(batch=args.batch)
    print(json.dumps(res, indent=1) if args.json else format_substep_study(res))


if __name__ == "__main__":
    main()
