"""Multi-agent calibration environments (DESIGN 1.4, 1.5, 5).

One batched core (:class:`CalibrationCore`) and two front doors: a PettingZoo
``ParallelEnv`` (:class:`CalibrationParallelEnv`) and a native batched TorchRL
``EnvBase`` (:class:`CalibrationTorchEnv`); agents (:func:`build_agents`) and the
impact-region rule (:class:`ImpactRegions`). The front doors are imported lazily so
that ``marlcrash.envs.core`` does not pull in PettingZoo or TorchRL.
"""

from marlcrash.envs.agents import AgentLayout, AgentsConfig, AgentSpec, build_agents
from marlcrash.envs.core import (
    ActionError,
    CalibrationCore,
    EnvConfig,
    ObservationConfig,
    apply_increments,
    load_env_config,
)
from marlcrash.envs.masking import ImpactRegions, MaskingConfig

__all__ = [
    "ActionError",
    "AgentLayout",
    "AgentSpec",
    "AgentsConfig",
    "CalibrationCore",
    "CalibrationParallelEnv",
    "CalibrationTorchEnv",
    "EnvConfig",
    "ImpactRegions",
    "MaskingConfig",
    "ObservationConfig",
    "apply_increments",
    "build_agents",
    "load_env_config",
]


def __getattr__(name: str):
    if name == "CalibrationParallelEnv":
        from marlcrash.envs.pettingzoo_env import CalibrationParallelEnv

        return CalibrationParallelEnv
    if name == "CalibrationTorchEnv":
        from marlcrash.envs.torchrl_env import CalibrationTorchEnv

        return CalibrationTorchEnv
    raise AttributeError(f"module 'marlcrash.envs' has no attribute {name!r}")
