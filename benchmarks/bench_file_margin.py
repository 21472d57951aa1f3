"""How far a candidate at a test's own parameters misses the test, by compare margin and window.

A measured reference's record goes on past the compared window and is filtered over all of it; candidates
compared with it are simulated ``reference.compare_margin`` longer and cut after filtering
(:func:`marlcrash.pulse.signal.compared_window`). This writes the model's own simulation, continued to
``--record`` seconds, as a test CSV (``marlcrash simulate --csv``), calibrates against it
(``reference=file``) and prints the worst sensor's DFD [m/s] and area [m] at the model's parameters, which
the test came from, per scenario, window and margin. Margin 0 filters the candidate only up to the window's
end, as before the margin existed. About 1 s per cell of the table.

Usage: python benchmarks/bench_file_margin.py [--scenarios full_width_40 small_overlap_left ...]
       [--durations 0.15 0.03] [--margins 0 0.01 0.02] [--record 0.2] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from marlcrash.calibrate.problem import ProblemConfig, build_problem
from marlcrash.envs.core import build_cells, load_env_config
from marlcrash.pulse.simulation import write_crash_csv
from marlcrash.sim import Surrogate, get_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=["full_width_40", "offset40_left", "small_overlap_left",
                                                       "full_width_56"], help="registered scenarios")  # fmt: skip
    ap.add_argument("--durations", nargs="+", type=float, default=[0.15, 0.08, 0.03], help="compared windows [s]")
    ap.add_argument("--margins", nargs="+", type=float, default=[0.0, 0.01, 0.02], help="compare margins [s]")
    ap.add_argument("--record", type=float, default=0.2, help="length of the test record after contact [s]")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON only")
    args = ap.parse_args()
    for name in args.scenarios:  # before any work: a test record must cover its scenario's window
        if args.record < get_scenario(name).duration:
            ap.error(f"--record {args.record} s is shorter than {name}'s window {get_scenario(name).duration} s")
    env = load_env_config()
    cells = build_cells(env.vehicle, env.vehicle_seed, env.discretization)
    sim = Surrogate(cells)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenarios:
            sc = get_scenario(name)
            res = sim.run(torch.as_tensor(cells.params)[None], sc, duration=args.record, record_cells="none")
            path = write_crash_csv(res, Path(tmp) / f"{name}.csv")
            channels = {s: f"{s}_acc_g" for s in cells.sensor_names}
            for duration in args.durations:
                for margin in args.margins:
                    over = {"reference.files": [{"path": str(path), "scenario": name, "channels": channels}],
                            "reference.compare_margin": margin}  # fmt: skip
                    problem = build_problem(ProblemConfig(scenario=name, reference="file", duration=duration,
                                                          env_overrides=over), cells)  # fmt: skip
                    m = problem.evaluate(problem.zeros(1))
                    rows.append({"scenario": name, "window_s": problem.duration, "margin_s": margin,
                                 "margin_samples": problem.margin, "dfd": float(m.dfd.max()),
                                 "area": float(m.area.max())})  # fmt: skip
                    if not args.json:
                        r = rows[-1]
                        print(f"{name:20s} window {r['window_s'] * 1e3:5.0f} ms  margin {margin * 1e3:4.0f} ms "
                              f"({r['margin_samples']:2d} samples)  worst DFD {r['dfd']:.2g} m/s  "
                              f"area {r['area']:.2g} m", flush=True)  # fmt: skip
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
