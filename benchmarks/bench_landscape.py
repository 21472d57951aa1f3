"""How precisely a calibration must recover the twin truth to pass the success thresholds.

Prints, for the calibration problem of ``configs/train/baseline.yaml`` (twin reference of
``full_width_40``, seed 0 by default), the median worst-sensor metrics at random points a
log-scale distance ``r`` from the twin's hidden truth, per parameter group, with the log-log
slope of the area (1: smooth, near 0: the pulse jumps) and the largest radius that still passes
(:mod:`marlcrash.calibrate.landscape`). About 300 simulations, well under a minute on 2 cores.

Usage: python benchmarks/bench_landscape.py [--scenario full_width_40] [--reference-seed 0] [--draws 8] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.calibrate.landscape import format_landscape, truth_neighbourhood
from marlcrash.calibrate.problem import ProblemConfig, build_problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="full_width_40", help="registered scenario of the twin reference")
    ap.add_argument("--reference-seed", type=int, default=0, help="seed of the twin's hidden perturbation")
    ap.add_argument("--draws", type=int, default=8, help="random directions per radius")
    ap.add_argument("--duration", type=float, default=None, help="simulated window [s] (default: the scenario's)")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    problem = build_problem(
        ProblemConfig(scenario=args.scenario, reference_seed=args.reference_seed, duration=args.duration)
    )
    res = truth_neighbourhood(problem, draws=args.draws)
    res["simulations"] = problem.n_simulations
    print(json.dumps(res, indent=1) if args.json else format_landscape(res))


if __name__ == "__main__":
    main()
