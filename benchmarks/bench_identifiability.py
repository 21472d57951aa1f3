"""Would more tests, or a low-frequency start, lead a local fit to the twin's truth? Two identifiability studies.

The local fit of ``bench_local_fit.py`` (Levenberg-Marquardt on the velocity residuals, finite-difference
Jacobians, six damping values per step; :func:`marlcrash.calibrate.leastsq.lm_iteration`) from the initial
parameters stalls in a valley far from the truth. This runs the same iteration with two changes, each optional:

- ``--scenarios``: the residuals of the twin's pulses in several load cases at once (the same hidden
  perturbation, reference seed ``--reference-seed``; every agent free, so each case searches the same
  coordinates), as a vehicle programme has several tests of one car;
- ``--cutoffs``: frequency continuation, as in full-waveform inversion: the residuals low-passed (a
  second-order Butterworth run forward and backward, cutoff in Hz) and fitted stage by stage from the lowest
  cutoff up, ``full`` for the unfiltered residuals.

Every stage runs ``--iterations`` iterations (fewer where the damping grows past 1e6: every step rejected).
After each stage it prints the simulations used, the fitted cost, the first scenario's per-sensor area, DFD
and RMSE (the graded case: ``full_width_40`` by default, the main job's), whether every threshold passes,
the mean relative sub-assembly parameter error and the rms log-scale distance to the truth. A
``full_width_40`` iteration costs ``n_free + 6`` = 133 simulations, about 1 s on 2 cores; every scenario adds
as many.

Usage: python benchmarks/bench_identifiability.py [--scenarios full_width_40 full_width_56 ...]
       [--cutoffs 6 25 full] [--iterations 15] [--reference-seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from scipy.signal import butter, sosfiltfilt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from marlcrash.calibrate.leastsq import lm_iteration
from marlcrash.calibrate.problem import ProblemConfig, build_problem

MAX_DAMPING = 1e6
"""A damping this large means every recent step was rejected: the stage ends."""


def _cutoff(text: str) -> float | None:
    if text == "full":
        return None
    value = float(text)
    if not 0 < value < 1000:
        raise argparse.ArgumentTypeError(f"expected a cutoff in (0, 1000) Hz or 'full', got {text!r}")
    return value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["full_width_40"],
                    help="load cases fitted at once; the first one is graded")  # fmt: skip
    ap.add_argument("--cutoffs", nargs="+", type=_cutoff, default=[None],
                    help="low-pass cutoffs [Hz] of the stages, lowest first; 'full' for none")  # fmt: skip
    ap.add_argument("--iterations", type=int, default=15, help="Levenberg-Marquardt iterations per stage")
    ap.add_argument("--reference-seed", type=int, default=0, help="seed of the twin's hidden perturbation")
    args = ap.parse_args()
    problems = [build_problem(ProblemConfig(scenario=s, masking=False, reference_seed=args.reference_seed))
                for s in args.scenarios]  # fmt: skip
    graded = problems[0]
    true_x = graded.true_x
    assert true_x is not None  # a twin reference (ProblemConfig's default) carries its hidden truth
    for p in problems[1:]:
        if not (torch.equal(p.free, graded.free) and p.true_x is not None and torch.equal(p.true_x, true_x)):
            raise SystemExit(f"error: {p.scenario.name} searches other coordinates or another truth")
    lo, hi = graded.flat_box()
    truth = graded.flat(true_x[None])[0]
    z = torch.zeros_like(truth)
    fs = 1.0 / graded.dt
    cutoff: float | None = None

    def run(zs: torch.Tensor):
        out = []
        for p in problems:
            r = p.residuals(p.unflat(zs))[0].reshape(zs.shape[0], len(p.sensors), -1)
            if cutoff is not None:
                r = torch.from_numpy(sosfiltfilt(butter(2, cutoff, fs=fs, output="sos"), r.numpy(), axis=-1).copy())
            out.append(r.reshape(zs.shape[0], -1))
        return torch.cat(out, 1), None

    def report(stage: str, cost: float) -> None:
        sims = sum(p.n_simulations for p in problems)  # the fit's, not the grading's below
        x = graded.unflat(z[None])
        m = graded.evaluate(x)
        fit = " ".join(f"{s} {float(m.area[0, k]):.4f}/{float(m.dfd[0, k]):.3f}/{float(m.rmse[0, k]):.3f}"
                       for k, s in enumerate(graded.sensors))  # fmt: skip
        print(f"{stage:>14} {sims:7d} {cost:10.3e}  {fit}  {bool(graded.success(m)[0])!s:>6} "
              f"{float(graded.param_error(x).mean()):8.3f} {float((z - truth).pow(2).mean().sqrt()):9.3f} "
              f"{time.perf_counter() - t0:7.0f}", flush=True)  # fmt: skip

    print(f"twin seed {args.reference_seed}; fitted: {', '.join(args.scenarios)}; graded: {args.scenarios[0]} "
          f"(area [m] / DFD [m/s] / RMSE [m/s] per sensor); {graded.n_free} free coordinates")  # fmt: skip
    print(f"{'stage':>14} {'sims':>7} {'cost':>10}  fit of the graded case  passed param err rms dist  wall s")
    t0 = time.perf_counter()
    report("start", float(run(z[None])[0].pow(2).sum()))
    for cutoff in args.cutoffs:
        r = run(z[None])[0][0]
        lam, done = 1e-2, 0
        while done < args.iterations and lam <= MAX_DAMPING:
            step = lm_iteration(run, z, r, lam, lo, hi, 1e-5)
            z, r, lam = step.z, step.r, step.lam
            done += 1
        report(f"{'full' if cutoff is None else f'{cutoff:g} Hz'} x{done}", float(r.pow(2).sum()))


if __name__ == "__main__":
    main()
