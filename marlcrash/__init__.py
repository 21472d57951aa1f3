"""marlcrash: cell surrogates of vehicle frontal crash structures, calibrated
against reference crash pulses with multi-agent reinforcement learning.

Data flows one way: vehicle -> cells -> sim -> pulse/metrics -> envs ->
calibrate -> analysis.
"""

__version__ = "0.1.0"
