"""Front door one: a PettingZoo ``ParallelEnv`` over the calibration core with ``B = 1``.

- ``possible_agents``: every agent of the layout; ``agents``: the agents active in the
  episode (impact-region rule), fixed at reset and emptied when the episode ends.
- :meth:`CalibrationParallelEnv.reset` returns observations and infos for EVERY possible
  agent by default (TorchRL's ``PettingZooWrapper`` indexes all of them at reset);
  ``reset_agents="live"`` returns them for the live agents only, as PettingZoo's own
  ``parallel_to_aec`` expects (it replaces infos whose keys are not ``agents`` by the whole
  dict copied under every agent). ``step`` returns entries for the live agents only, so an agent that is
  not active in the episode never gets a termination or truncation flag (PettingZoo's ``parallel_api_test``
  warns "not all possible_agents are terminated or truncated" about exactly these agents).
- Spaces are fixed per agent (``gymnasium.spaces.Box``, float32): observations
  ``[obs_dim]``, actions ``[act_dim]`` in ``[-1, 1]``; the same objects on every call.
- Actions of agents not in ``agents`` (inactive or finished) are ignored; missing actions
  of live agents count as zero (no change). A live agent's action values outside ``[-1, 1]`` are clipped to the
  bound; a NaN or inf entry that acts (``action_entries``) is refused (:class:`~marlcrash.envs.core.ActionError`).
- Every live agent receives the team reward. An agent inactive in the episode is not in ``agents``, so
  ``step`` returns no entry for it at all (PettingZoo's API has no "present but idle" agent; DESIGN 5's
  "inactive agents receive it too" holds in the native TorchRL env, whose team reward sits at the root for
  every agent). Infos carry the per-sensor metrics ``area``, ``dfd``, ``rmse`` (``[n_sensors]`` arrays, the
  same for every agent) and ``action_entries`` (``[act_dim]`` bool: the entries of the agent's action that act,
  its row of the native env's ``("agents", "action_mask")``, :meth:`~marlcrash.envs.core.CalibrationCore.action_mask`:
  per cell a valid slot and a feasible factor, with ``masking.cells: region`` only the agent's cells in the impact
  region; all ``False`` for an agent inactive in the episode). Not named ``action_mask``: PettingZoo's API test
  samples each agent's space with an info of that name as the mask, which a ``Box`` refuses. TorchRL's
  ``PettingZooWrapper`` gives it as ``(group, "info", "action_entries")``.
- Wrap it as ``PettingZooWrapper(env, use_mask=True, done_on_any=False)``. The wrapper counts an agent that is not in
  ``agents`` as done, and for a parallel env its default ``done_on_any=True`` ends the episode when any agent is
  done: every episode with an agent outside the impact region (4 of the 5 default scenarios: the offset and small
  overlap ones) ended after its first step without a word. ``use_mask=True`` gives the live agents' mask.
- TorchRL's ``PettingZooWrapper`` hands every info entry on as float32: it builds the info spec without a dtype
  (TorchRL 0.14: no option sets one, and it writes the values into float32 buffers), so the float64 metrics come out
  rounded to float32 (relative error at most 6e-8, 2**-24) and ``action_entries`` as 1.0 / 0.0 (``.bool()`` gives
  the mask back). The float64 metrics are this env's infos, or the native env's ``("metrics", ...)``.
- Seeding: ``reset(seed=...)`` re-seeds the core's own generator only.
- ``reset(options=...)`` is accepted and ignored: the env has no per-episode options (the scenario mix, references
  and masking are env config). It is not refused: PettingZoo's ``parallel_api_test`` calls
  ``reset(seed=0, options={"options": 1})`` to check that ``reset`` takes the argument.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch
from gymnasium import spaces
from pettingzoo import ParallelEnv

from marlcrash.cells.model import CellModel
from marlcrash.envs.core import ActionError, CalibrationCore, EnvConfig, load_env_config
from marlcrash.sim.surrogate import SimConfig


class CalibrationParallelEnv(ParallelEnv):
    """Calibration of one cell model against one reference per episode (module docstring).

    Args:
        config: env config; ``None`` loads ``configs/env/default.yaml``.
        cells: the model to calibrate (``None``: discretize ``config.vehicle``).
        sim_config: simulator settings (``None``: ``configs/sim.yaml``).
        render_mode: only ``None`` (no rendering).
        reset_agents: ``possible`` (default; for TorchRL's ``PettingZooWrapper``) or ``live``: the agents
            whose observations and infos :meth:`reset` returns (for ``pettingzoo.utils.parallel_to_aec``).
    """

    metadata: ClassVar[dict] = {"name": "marlcrash_calibration_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self,
        config: EnvConfig | None = None,
        cells: CellModel | None = None,
        sim_config: SimConfig | None = None,
        render_mode: str | None = None,
        reset_agents: str = "possible",
    ):
        if render_mode is not None:
            raise ActionError(f"render_mode must be None (no rendering), got {render_mode!r}")
        if reset_agents not in ("possible", "live"):
            raise ActionError(f"reset_agents must be 'possible' or 'live', got {reset_agents!r}")
        self.reset_agents = reset_agents
        self.render_mode = None
        self.core = CalibrationCore(config if config is not None else load_env_config(), 1, cells, sim_config)
        c = self.core
        self.possible_agents: list[str] = list(c.layout.names)
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._obs_spaces = {
            a: spaces.Box(-np.inf, np.inf, shape=(c.obs_dim,), dtype=np.float32) for a in self.possible_agents
        }
        self._act_spaces = {
            a: spaces.Box(-1.0, 1.0, shape=(c.act_dim,), dtype=np.float32) for a in self.possible_agents
        }
        self.observation_spaces = self._obs_spaces
        self.action_spaces = self._act_spaces
        self.state_space = spaces.Box(-np.inf, np.inf, shape=(c.state_dim,), dtype=np.float32)
        self._started = False

    def observation_space(self, agent: str) -> spaces.Box:
        """The agent's observation space; :class:`ActionError` naming the agent if it is not a possible agent."""
        return self._space(self._obs_spaces, agent, "observation_space")

    def action_space(self, agent: str) -> spaces.Box:
        """The agent's action space; :class:`ActionError` naming the agent if it is not a possible agent."""
        return self._space(self._act_spaces, agent, "action_space")

    def _space(self, table: Mapping[str, spaces.Box], agent: str, what: str) -> spaces.Box:
        try:
            return table[agent]
        except (KeyError, TypeError):  # TypeError: an unhashable name
            raise ActionError(f"{what}: unknown agent {agent!r}; possible agents are {self.possible_agents}") from None

    # -------------------------------------------------------------------------------- helpers
    def _observations(self, agents: list[str]) -> dict[str, np.ndarray]:
        obs, self._state = self.core.observations()
        o = obs[0].numpy()
        return {a: o[self._index[a]].copy() for a in agents}

    def _infos(self, agents: list[str]) -> dict[str, dict[str, Any]]:
        m = self.core.metrics
        base = {"area": m.area[0].numpy(), "dfd": m.dfd[0].numpy(), "rmse": m.rmse[0].numpy()}
        mask = self.core.action_mask()[0].numpy()
        return {a: {**{k: v.copy() for k, v in base.items()}, "action_entries": mask[self._index[a]].copy()}
                for a in agents}  # fmt: skip

    def state(self) -> np.ndarray:
        """Global state ``[state_dim]`` float32 (for centralized critics)."""
        if getattr(self, "_state", None) is None:
            raise ActionError("call reset() before state()")
        return self._state[0].numpy().copy()

    # ---------------------------------------------------------------------------------- API
    def reset(self, seed: int | None = None, options: dict | None = None):
        """New episode; observations and infos for every possible agent, or the live ones (module docstring).

        ``options`` is ignored (no per-episode options; module docstring)."""
        self.core.reset(seed=seed)
        active = self.core.active[0].tolist()
        self.agents = [a for a, on in zip(self.possible_agents, active, strict=True) if on]
        self._started = True
        who = self.possible_agents if self.reset_agents == "possible" else self.agents
        return self._observations(who), self._infos(who)

    def step(self, actions: dict[str, np.ndarray]):
        """One calibration iteration; returns dicts for the agents live at its start."""
        if not self._started:
            raise ActionError("call reset() before step()")
        if not isinstance(actions, dict):
            raise ActionError(f"actions must be a dict agent name -> array [{self.core.act_dim}], got {type(actions)}")
        live = list(self.agents)
        if not live and not bool(self.core.active[0].any()):  # at reset, not at the episode's end
            raise ActionError(
                f"no agent is active in this episode ({self.core.scenario[0]}: the impact-region rule, masking.mode "
                f"{self.core.config.masking.mode!r}, leaves none); call reset() for another, or loosen masking"
            )
        if not live:
            raise ActionError("the episode is over (no live agents); call reset()")
        arr = np.zeros((1, self.core.A, self.core.act_dim), dtype=np.float64)
        for name, act in actions.items():  # dict of agents -> array: an I/O edge
            if name not in self._index:
                raise ActionError(f"unknown agent {name!r}; possible agents are {self.possible_agents}")
            if name not in live:
                continue
            if isinstance(act, torch.Tensor):  # a policy's output too
                act = act.detach().cpu()
                act = act.double() if act.is_floating_point() else act  # bfloat16 has no numpy dtype
            try:
                a = np.asarray(act)
            except (ValueError, TypeError) as e:  # a ragged list: numpy's "inhomogeneous shape"
                raise ActionError(f"action of agent {name!r} must be an array of shape [{self.core.act_dim}], got "
                                  f"{type(act).__name__} numpy cannot read as one ({e})") from None  # fmt: skip
            if a.shape != (self.core.act_dim,):
                raise ActionError(
                    f"action of agent {name!r} must have shape [{self.core.act_dim}], got {list(a.shape)}"
                )
            if not np.issubdtype(a.dtype, np.floating):
                raise ActionError(f"action of agent {name!r} must be floating point, got {a.dtype}")
            arr[0, self._index[name]] = a
        self.core.step(torch.from_numpy(arr))
        c = self.core
        r = float(c.reward[0])
        term, trunc = bool(c.terminated[0]), bool(c.truncated[0])
        obs = self._observations(live)
        rewards = dict.fromkeys(live, r)
        terminations = dict.fromkeys(live, term)
        truncations = dict.fromkeys(live, trunc)
        infos = self._infos(live)
        if term or trunc:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def render(self) -> None:
        return None

    def close(self) -> None:
        return None
