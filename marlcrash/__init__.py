"""marlcrash: cell surrogates of vehicle frontal crash structures, calibrated
against reference crash pulses with multi-agent reinforcement learning.

Data flows one way: vehicle -> cells -> sim -> pulse/metrics -> envs ->
calibrate -> analysis.
"""

import os

# Idle OpenMP threads sleep instead of spinning, unless the user chose otherwise. A marlcrash process holds two OpenMP
# runtimes, each with its own thread pool: the system's libgomp runs numba's parallel kernels, torch bundles another.
# Spinning threads of one pool (libgomp's default) hold the cores while the other's work waits: on this 2-core
# machine, while other work ran, the torch work around the simulator's kernel took 0.26-1.6 s per 48 simulations
# with spinning threads against 0.04-0.08 s with sleeping ones (benchmarks/bench_wait_policy.py, 2026-11-24). Read
# when a runtime loads: numba's at its first parallel kernel, torch's at ``import torch`` (so a torch imported
# before marlcrash keeps its own setting).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
