"""How far the cross-fidelity reference lies from the calibrated model, and how settled its integration is.

The cross-fidelity reference (``reference.kind: cross_fidelity``) is the same vehicle discretized on the uniform
grid (8939 cells for the default car, 2910 of them active, against 501 optimized), simulated as the "real test".
Its cells are light, so the mass scaling and step that suit the calibrated model (``configs/sim.yaml``: every active
cell raised to 0.5 kg, 8 steps per 0.5 ms) move most of the compartment's mass into its crush zone. The reference
therefore has its own ``mass_floor`` and ``substeps`` (``reference.cross_fidelity`` of the env config). This prints,
per scenario and for the reference simulated with sim.yaml's settings, with the env config's, and with a finer pair
(``--fine``):

- the mass the floor adds [kg] and the tunnel's CFC60 peak [g] and stop time [ms];
- ``gap``: the compared-velocity RMSE per sensor [m/s] between the optimized model at its initial parameters
  (sim.yaml) and the reference: where a calibration starts;
- ``to fine``: the largest RMSE per sensor [m/s] between that reference and the finer one: how much the
  reference still moves when its mass scaling is halved again and its step shortened.

Usage: python benchmarks/bench_cross_fidelity.py [--scenarios full_width_40 ...] [--fine 0.02 40] [--json]
About 10 s per scenario on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from marlcrash.envs.core import build_cells, load_env_config
from marlcrash.metrics import rmse
from marlcrash.pulse.simulation import crash_summary
from marlcrash.references import ReferenceSampler
from marlcrash.sim import Surrogate, get_scenario
from marlcrash.sim.surrogate import load_sim_config


def main() -> None:
    env = load_env_config()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(env.scenarios), help="registered scenarios")
    ap.add_argument("--fine", nargs=2, type=float, default=[0.02, 40], metavar=("FLOOR_KG", "SUBSTEPS"),
                    help="the finer mass floor [kg] and substeps the reference is compared with")  # fmt: skip
    ap.add_argument("--json", action="store_true", help="print the rows as JSON only")
    args = ap.parse_args()

    cells = build_cells(env.vehicle, env.vehicle_seed, env.discretization, env.vehicle_options)
    sensors = list(env.sensors or cells.sensor_names)
    sim = Surrogate(cells, load_sim_config())
    base = env.reference
    own = replace(base.cross_fidelity, vehicle_seeds=[None])  # the calibrated car (env.vehicle_seed)
    variants = {
        "sim.yaml": replace(own, mass_floor=None, substeps=None),
        "env config": own,
        "fine": replace(own, mass_floor=args.fine[0], substeps=int(args.fine[1])),
    }
    labels = {k: f"{k} ({v.sim_config(sim.config).mass_floor:g} kg, {v.sim_config(sim.config).substeps} sub)"
              for k, v in variants.items()}  # fmt: skip
    rows = []
    for name in args.scenarios:
        sc = get_scenario(name)
        samplers = {
            k: ReferenceSampler(cells, sim, sensors, {name: 1.0}, replace(base, kind="cross_fidelity",
                                                                              cross_fidelity=v),
                                vehicle=env.vehicle, vehicle_options=env.vehicle_options, vehicle_seed=env.vehicle_seed)
            for k, v in variants.items()
        }  # fmt: skip
        with torch.no_grad():
            own_run = sim.run(torch.as_tensor(cells.params)[None], sc, sensors=sensors, record_cells="none")
        start = samplers["env config"].compared(own_run.velocity)
        runs, refs = {}, {}
        for k, s in samplers.items():  # each reference simulated once: its summary and compared velocity
            fine, fsim = s.fine_model(None)
            with torch.no_grad():
                res = fsim.run(torch.as_tensor(fine.params)[None], sc, duration=s.duration, sensors=sensors,
                               record_cells="none", backend=s.backend)  # fmt: skip
            runs[k], refs[k] = (res, fine, fsim), s.compared(res.velocity)
        for k, (res, fine, fsim) in runs.items():
            summ = crash_summary(res, fine, sc)
            stop = summ["time_to_zero_velocity_ms"]
            rows.append({
                "scenario": name, "reference": labels[k], "added_kg": round(fsim.mass_added, 1),
                "tunnel_peak_g": round(summ["peak_decel_g"], 1), "stop_ms": None if stop is None else round(stop, 1),
                "gap_rmse": [round(float(x), 2) for x in rmse(start, refs[k])[0]],
                "to_fine_rmse": round(float(rmse(refs[k], refs["fine"]).max()), 3),
            })  # fmt: skip
            if not args.json:
                r = rows[-1]
                print(f"{name:20s} {r['reference']:30s} added {r['added_kg']:7.1f} kg  tunnel "
                      f"{r['tunnel_peak_g']:6.1f} g  stop {r['stop_ms']} ms  gap {r['gap_rmse']} m/s  "
                      f"to fine {r['to_fine_rmse']:.3f} m/s", flush=True)  # fmt: skip
    if args.json:
        print(json.dumps({"sensors": sensors, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
