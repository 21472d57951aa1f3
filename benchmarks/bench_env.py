"""Environment overhead: batched env step vs the raw simulator, and the PettingZoo path.

1. Native TorchRL env (``CalibrationTorchEnv``) at ``B`` (default 256): the time of one
   ``env.step`` (action checks and application, ONE batched simulation, metrics, reward,
   observations) against one ``Surrogate.run`` with the same parameters and settings.
   Ratio of rates = t_sim / t_step (target >= 0.9).
2. PettingZoo ``ParallelEnv`` (B = 1): per-step wall time minus the simulation time of the
   same step (dict packing, metrics, observations), also through TorchRL's PettingZooWrapper.

Timings are CPU time of this process (``time.process_time``, all threads), so other jobs on a
shared machine disturb them little; the two timings of a pair are interleaved and the fastest
of ``--repeat`` runs is kept, all measured in this one process.
Failure limits are disabled and episodes never truncate, so every step simulates.

Usage: python benchmarks/bench_env.py [--batch 256] [--repeat 7] [--pz-steps 30]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path
from typing import Any
from unittest import mock

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, installed or not

import numpy as np
import torch

from marlcrash.cli import _positive_int
from marlcrash.envs.core import load_env_config
from marlcrash.envs.pettingzoo_env import CalibrationParallelEnv
from marlcrash.envs.torchrl_env import CalibrationTorchEnv


def _timed(fn) -> float:
    """CPU time of this process (all its threads) spent in ``fn``: robust to other jobs on a shared machine."""
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def _raw_sim(core, run=None):
    """One simulation of the whole batch as an env step runs it: past the window by the largest margin (a measured
    reference filtered over a longer record; 0 for twins), per-cell energies at the window's end."""
    run = run or core.sim.run
    duration = core.duration + int(core.margin.max()) * core.dt
    return lambda: run(core.params, speed=core.speed, overlap=core.overlap, side=core.side, duration=duration,
                       sensors=core.sensors, record_cells="final", backend=core.config.sim_backend,
                       cells_at=core.duration)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=_positive_int, default=256)
    ap.add_argument("--repeat", type=_positive_int, default=7)
    ap.add_argument("--pz-steps", type=_positive_int, default=30)
    ap.add_argument("--config", default="default", help="env config name in configs/env")
    args = ap.parse_args()
    over: dict[str, Any] = {"termination.max_iterations": 10**6}
    over.update({f"termination.failure_{m}": None for m in ("area", "dfd", "rmse")})
    cfg = load_env_config(args.config, overrides=over)
    torch.set_grad_enabled(False)

    env = CalibrationTorchEnv(cfg, batch_size=args.batch)
    core = env.core
    print(f"model: {core.cells.n_cells} cells, {core.A} agents, obs_dim {core.obs_dim}, act_dim {core.act_dim}; "
          f"B = {args.batch}; torch threads {torch.get_num_threads()}")  # fmt: skip
    td = env.reset(seed=0)
    g = torch.Generator().manual_seed(0)

    def env_step():
        td.set(("agents", "action"), torch.rand(args.batch, core.A, core.act_dim, generator=g) * 0.2 - 0.1)
        env.step(td)

    inner = {"t": 0.0}
    run = core.sim.run

    def timed_run(*a, **k):  # time spent inside the simulator during each env.step
        t0 = time.process_time()
        out = run(*a, **k)
        inner["t"] += time.process_time() - t0
        return out

    with mock.patch.object(core.sim, "run", timed_run):  # env.step's simulations, timed
        env_step()  # compile / warm caches
        _raw_sim(core)()
        t_sim, t_step, share = [], [], []
        for _ in range(args.repeat):  # interleave, so load changes hit both alike
            t_sim.append(_timed(_raw_sim(core, run)))
            inner["t"] = 0.0
            t = _timed(env_step)
            t_step.append(t)
            share.append((inner["t"], t))
    s, e = min(t_sim), min(t_step)
    print(f"raw Surrogate.run   B={args.batch}: {s * 1e3:9.1f} ms CPU  ({args.batch / s:8.1f} sims/s)")
    print(f"CalibrationTorchEnv B={args.batch}: {e * 1e3:9.1f} ms CPU  ({args.batch / e:8.1f} env steps/s)")
    print(f"ratio env rate / simulator rate: {s / e:.3f}  (target >= 0.90); overhead {(e - s) * 1e3:.1f} ms/step")
    sim_in, step_in = min(share, key=lambda x: x[1] - x[0])
    print(
        f"same-call attribution: {sim_in * 1e3:.1f} of {step_in * 1e3:.1f} ms inside Surrogate.run -> ratio "
        f"{sim_in / step_in:.3f}, overhead {(step_in - sim_in) * 1e3:.1f} ms/step (insensitive to machine load)"
    )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pz = CalibrationParallelEnv(cfg, cells=core.cells)
        pz.reset(seed=0)
        rng = np.random.default_rng(0)
        sim1 = _raw_sim(pz.core)
        sim1()
        pz_inner = {"t": 0.0}
        pz_run = pz.core.sim.run

        def pz_timed_run(*a, **k):
            t0 = time.process_time()
            out = pz_run(*a, **k)
            pz_inner["t"] += time.process_time() - t0
            return out

        t_pz, t_sim1, pz_share = [], [], []
        with mock.patch.object(pz.core.sim, "run", pz_timed_run):  # pz.step's simulation, timed
            for _ in range(args.pz_steps):
                act = {a: rng.uniform(-0.1, 0.1, pz.core.act_dim).astype(np.float32) for a in pz.agents}
                pz_inner["t"] = 0.0
                t_pz.append(_timed(lambda act=act: pz.step(act)))
                pz_share.append(t_pz[-1] - pz_inner["t"])
                t_sim1.append(_timed(sim1))
        from torchrl.envs import PettingZooWrapper

        w = PettingZooWrapper(CalibrationParallelEnv(cfg, cells=core.cells), use_mask=True, done_on_any=False)
        wtd = w.reset(seed=0)
        t_w = []
        for _ in range(args.pz_steps):
            t0 = time.process_time()
            wtd = w.rand_step(wtd)["next"]
            t_w.append(time.process_time() - t0)
    p, s1, ww = min(t_pz), min(t_sim1), min(t_w)
    print(f"raw Surrogate.run B=1: {s1 * 1e3:7.2f} ms")
    print(f"ParallelEnv.step   B=1: {p * 1e3:7.2f} ms; overhead (step - simulation) {(p - s1) * 1e3:6.2f} ms; "
          f"ratio {s1 / p:.3f}")  # fmt: skip
    print(f"ParallelEnv.step same-call attribution: overhead {statistics.median(pz_share) * 1e3:6.2f} ms (median)")
    print(f"PettingZooWrapper.step: {ww * 1e3:7.2f} ms; overhead (step - simulation) {(ww - s1) * 1e3:6.2f} ms; "
          f"ratio {s1 / ww:.3f}")  # fmt: skip


if __name__ == "__main__":
    main()
