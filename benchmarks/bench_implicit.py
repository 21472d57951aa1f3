"""Issue 3's third route to a 0.25-0.5 ms step, measured: implicit integration of the surrogate's physics.

Prints, per step count on the default car (raw element stiffnesses, no stability caps, no mass scaling):
how well a Newton-solved backward Euler step converges over the impact and what it costs in link passes,
and how the linearly implicit scheme (one linear solve per step) grades on DESIGN 4's plausibility cases.
The roofline column scales the explicit scheme's roofline, measured in the same run at its fewest passing
steps, by the link passes each simulation needs (:func:`marlcrash.sim.bench.implicit_study`).

Usage: python benchmarks/bench_implicit.py [--substeps 1 2 4] [--explicit-substeps 7] [--batch 256] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch

from marlcrash.cli import _batch_size, _positive_int
from marlcrash.sim.bench import (
    format_implicit_study,
    implicit_study,
    live_links,
    load_sim_cells,
    measure_roofline,
)
from marlcrash.sim.scenario import get_scenario
from marlcrash.sim.surrogate import Surrogate, load_sim_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--substeps", type=_positive_int, nargs="+", default=[1, 2, 4], help="implicit steps per 0.5 ms output"
    )
    ap.add_argument(
        "--explicit-substeps",
        type=_positive_int,
        default=7,
        help="the explicit scheme's fewest passing substeps, whose roofline is scaled (benchmarks/bench_substeps.py)",
    )
    ap.add_argument("--batch", type=_batch_size, default=256, help="simulations per timed roofline batch")
    ap.add_argument("--json", action="store_true", help="print the result dict as JSON only")
    args = ap.parse_args()
    sim = Surrogate(load_sim_cells(), load_sim_config(overrides={"substeps": args.explicit_substeps}))
    steps = (get_scenario("full_width_56").n_outputs - 1) * args.explicit_substeps
    p = torch.as_tensor(sim.cells.params)[None]
    roof = measure_roofline(sim, args.batch, steps, n_links=live_links(sim, p))
    res = implicit_study(tuple(args.substeps), explicit={"steps_per_sim": steps, "roofline_sims_per_s": roof})
    print(json.dumps(res, indent=1) if args.json else format_implicit_study(res))


if __name__ == "__main__":
    main()
