"""Does a local least-squares method pass the success test? Levenberg-Marquardt on the twin problem.

Runs :func:`marlcrash.calibrate.landscape.local_fit` (finite-difference Jacobians in one batch of
``n_free`` simulations, six damping values per step) on the calibration problem of the landscape
study (twin reference of ``full_width_40``, seed 0 by default), from the initial parameters or from a
random point ``--start-radius`` (log-scale, uniform per coordinate) away from the twin's truth, and
prints per iteration the simulations used, the residual cost, the per-sensor areas and whether every
threshold passes. About 133 simulations (2 s on 2 cores) per iteration.

Usage: python benchmarks/bench_local_fit.py [--start-radius R] [--iterations 10] [--duration S]
       [--scenario full_width_40] [--reference-seed 0] [--seed 0] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.calibrate.landscape import local_fit
from marlcrash.calibrate.problem import ProblemConfig, build_problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start-radius", type=float, default=None,
                    help="start this log-scale distance from the truth (default: the initial parameters)")  # fmt: skip
    ap.add_argument("--iterations", type=int, default=10, help="Levenberg-Marquardt iterations")
    ap.add_argument("--duration", type=float, default=None, help="simulated window [s] (default: the scenario's)")
    ap.add_argument("--scenario", default="full_width_40", help="registered scenario of the twin reference")
    ap.add_argument("--reference-seed", type=int, default=0, help="seed of the twin's hidden perturbation")
    ap.add_argument("--seed", type=int, default=0, help="seed of the start point's draw")
    ap.add_argument("--json", action="store_true", help="print the iterate records as JSON only")
    args = ap.parse_args()
    problem = build_problem(
        ProblemConfig(scenario=args.scenario, reference_seed=args.reference_seed, duration=args.duration)
    )
    hist = local_fit(problem, start_radius=args.start_radius, iterations=args.iterations, seed=args.seed)
    if args.json:
        print(json.dumps(hist, indent=1))
        return
    start = "initial parameters" if args.start_radius is None else f"truth + {args.start_radius:g} (uniform)"
    print(f"Levenberg-Marquardt from the {start}; {problem.n_free} free coordinates, window {problem.duration} s")
    names = problem.sensors
    print(f"{'iter':>4} {'sims':>6} {'cost':>10} {'max |log err|':>13}  " + " ".join(f"{'A ' + s:>16}" for s in names)
          + "  passed")  # fmt: skip
    for i, h in enumerate(hist):
        areas = " ".join(f"{h['sensors'][s]['area']:16.5f}" for s in names)
        print(f"{i:4d} {h['simulations']:6d} {h['cost']:10.3e} {h['distance']:13.2e}  {areas}  {h['passed']}")


if __name__ == "__main__":
    main()
