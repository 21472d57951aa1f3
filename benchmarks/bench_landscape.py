"""How precisely a calibration must recover the twin truth to pass the success thresholds.

Prints, for the calibration problem of ``configs/train/baseline.yaml`` (twin reference of
``full_width_40``, seed 0 by default), the median worst-sensor metrics at random points a
log-scale distance ``r`` from the twin's hidden truth, per parameter group, with the log-log
slope of the area (1: smooth, near 0: the pulse jumps) and the largest radius that still passes
(:mod:`marlcrash.calibrate.landscape`). About 300 simulations, well under a minute on 2 cores.

With ``--cluster-radii 0 0.08 0.15 0.25`` it instead reads every sensor as the mass-weighted mean
velocity of the cells within each radius (a sensor bracket rather than one light cell) and prints the
median area per sensor at radii 1e-4, 1e-3 and 1e-2 (:func:`marlcrash.calibrate.landscape.cluster_sensor_study`).

With ``--spectrum`` it instead prints the singular values of the residual Jacobian at the truth
(:func:`marlcrash.calibrate.landscape.sensitivity_spectrum`, 128 simulations): how many parameter
directions the sensors see; ``--candidate runs/lm/<name>/best.pt`` adds how that calibration's
parameter error splits over those directions.

Usage: python benchmarks/bench_landscape.py [--scenario full_width_40] [--reference-seed 0] [--draws 8]
       [--duration S] [--cluster-radii M [M ...] | --spectrum [--candidate FILE.pt]] [--json]
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from marlcrash.calibrate.landscape import (
    cluster_sensor_study,
    format_cluster_study,
    format_landscape,
    format_spectrum,
    sensitivity_spectrum,
    truth_neighbourhood,
)
from marlcrash.calibrate.problem import ProblemConfig, build_problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="full_width_40", help="registered scenario of the twin reference")
    ap.add_argument("--reference-seed", type=int, default=0, help="seed of the twin's hidden perturbation")
    ap.add_argument("--draws", type=int, default=8, help="random directions per radius")
    ap.add_argument("--duration", type=float, default=None, help="simulated window [s] (default: the scenario's)")
    ap.add_argument(
        "--cluster-radii",
        type=float,
        nargs="+",
        default=None,
        metavar="M",
        help="instead: read each sensor as the mass-weighted mean of the cells within these radii [m] "
        "(0 = the sensor cell alone) and report the area at radii 1e-4, 1e-3, 1e-2",
    )
    ap.add_argument("--spectrum", action="store_true", help="instead: singular values of the residual Jacobian")
    ap.add_argument("--candidate", type=Path, default=None,
                    help="with --spectrum: a baseline run's best.pt (or a saved [n_agents, 7] tensor)")  # fmt: skip
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    if args.candidate is not None and not args.spectrum:
        ap.error("--candidate needs --spectrum")
    if args.spectrum and args.cluster_radii is not None:
        ap.error("--spectrum and --cluster-radii are separate studies; give one")
    problem = build_problem(
        ProblemConfig(scenario=args.scenario, reference_seed=args.reference_seed, duration=args.duration)
    )
    if args.spectrum:
        cand = None
        if args.candidate is not None:
            try:
                data = torch.load(args.candidate, weights_only=True)
            except (OSError, RuntimeError, pickle.UnpicklingError) as e:
                sys.exit(f"error: {args.candidate}: cannot read a saved tensor ({e})")
            cand = data["best_x"] if isinstance(data, dict) and "best_x" in data else data
            if not isinstance(cand, torch.Tensor) or tuple(cand.shape) != (problem.n_agents, 7):
                sys.exit(f"error: {args.candidate}: expected best_x or a tensor of shape [{problem.n_agents}, 7]")
            cand = cand.to(torch.float64)
        res, text = sensitivity_spectrum(problem, candidate=cand), format_spectrum
    elif args.cluster_radii is not None:
        res = cluster_sensor_study(problem, cluster_radii=args.cluster_radii, draws=args.draws)
        text = format_cluster_study
    else:
        res = truth_neighbourhood(problem, draws=args.draws)
        text = format_landscape
    res["simulations"] = problem.n_simulations
    print(json.dumps(res, indent=1) if args.json else text(res))


if __name__ == "__main__":
    main()
