"""Front door two: a native batched TorchRL ``EnvBase`` over the calibration core.

Batch ``[B]``; all agents in one group ``"agents"`` (``[*batch, n_agents, features]``,
as ``MultiAgentMLP`` expects). Keys:

- ``("agents", "observation")``: ``[B, n_agents, obs_dim]`` float32;
- ``("agents", "action")``: ``[B, n_agents, act_dim]`` float32 in ``[-1, 1]``: a value outside is clipped to the
  bound (an unsquashed policy's sample acts as the bound), a NaN or inf entry that acts (``"action_mask"``) is refused
  (:class:`~marlcrash.envs.core.ActionError` naming its index; one that does not act is ignored);
- ``("agents", "mask")``: ``[B, n_agents]`` bool, the agent is active this episode
  (set a loss's ``loss_mask_key`` to it: inactive agents' actions are ignored);
- ``("agents", "action_mask")``: ``[B, n_agents, act_dim]`` bool, entries that act
  (:meth:`~marlcrash.envs.core.CalibrationCore.action_mask`: valid cell slots and feasible factors of active
  agents, a sub-assembly's factors some of its cells take; with ``masking.cells: region`` its in-region cells);
- ``"state"``: ``[B, state_dim]`` float32 global state for centralized critics;
- ``("metrics", "area" | "dfd" | "rmse")``: ``[B, n_sensors]`` float64 per-sensor metrics;
- ``"reward"``: ``[B, 1]`` float32 team reward; ``"done"``, ``"terminated"``,
  ``"truncated"``: ``[B, 1]`` bool at the root.

Device: ``CalibrationTorchEnv(..., device="cuda")`` puts the specs and every returned tensor on that device and takes
actions and the ``"_reset"``/``"_step"`` masks from it (TorchRL's ``EnvBase(device=...)``); the simulation and the
core's state stay on the CPU, so each step moves its actions there and its outputs back. A training run builds its env
on its ``device`` (``configs/train/train.yaml``).

Partial resets (``"_reset"`` ``[B, 1]``) restart only the flagged rows; ``reset(seed=s)``
re-seeds the core first, exactly as the PettingZoo door's ``reset(seed=s)``. Partial steps (``"_step"`` ``[B]``, which
``rollout(..., break_when_all_done=True)`` sets to the rows whose episodes go on) step only the flagged rows; the others
keep their state (observation and end flags as they stood, reward 0) and are not simulated. A row whose episode ended
(``"done"``) is reset before it is stepped again (``step_and_maybe_reset``, a rollout, a ``"_reset"`` entry): stepping
it is refused (:class:`~marlcrash.envs.core.ActionError` naming the rows), as the PettingZoo door refuses.

Seeding copies: every env starts from its config's ``seed`` (reproducible by default), so copies run side by side
(``SerialEnv``, ``ParallelEnv``) draw the same episodes until seeded: call ``set_seed(s)`` on the batched env (TorchRL
gives each worker its own seed from ``s``), or give each copy its own ``seed``. One env with ``batch_size=B`` needs
neither: its rows draw from one generator, all rows of a reset in one draw
(:meth:`~marlcrash.references.ReferenceSampler.sample`), so a row's references depend on ``B`` and on which rows reset
together: the same seed reproduces a run of the same ``B``, and ``reference.pin_seed`` gives every row one reference.

Worker processes: a ``ParallelEnv`` needs the ``spawn`` start method (TorchRL's default). With
``mp_start_method="fork"`` in a process that has already simulated, the workers die at start ("fork() called from
a process already using GNU OpenMP"): the compiled simulator runs on numba's OpenMP threading layer, whose GNU
runtime is not fork safe. One env with ``batch_size=B`` already runs its rows on every core.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from marlcrash.cells.model import CellModel
from marlcrash.config import require_device
from marlcrash.envs.core import CalibrationCore, EnvConfig, check_env_args, load_env_config
from marlcrash.sim.surrogate import SimConfig

GROUP = "agents"
"""Name of the single agent group."""


class CalibrationTorchEnv(EnvBase):
    """Batched calibration environment (module docstring).

    Args:
        config: env config; ``None`` loads ``configs/env/default.yaml``.
        batch_size: number ``B`` of parallel episodes.
        cells: the model to calibrate (``None``: discretize ``config.vehicle``).
        sim_config: simulator settings (``None``: ``configs/sim.yaml``).
        device: the torch device of the specs and of every tensor the env returns (``"cpu"``, ``"cuda:0"``);
            actions and ``"_reset"``/``"_step"`` masks are taken from it. The simulation runs on the CPU whatever
            the device: each step's actions move to the CPU and its outputs to the device.

    Raises:
        ConfigError: a bad argument, named (``config``, ``batch_size``, ``cells``, ``device``), or an invalid config.
    """

    batch_locked = True

    def __init__(
        self,
        config: EnvConfig | None = None,
        batch_size: int = 1,
        cells: CellModel | None = None,
        sim_config: SimConfig | None = None,
        device: torch.device | str = "cpu",
    ):
        config = config if config is not None else load_env_config()
        batch_size = check_env_args(config, batch_size)
        require_device(device, "device")
        super().__init__(device=device, batch_size=torch.Size([batch_size]))
        self.core = CalibrationCore(config, batch_size, cells, sim_config)
        self._make_specs()

    @property
    def agent_names(self) -> list[str]:
        return list(self.core.layout.names)

    def _make_specs(self) -> None:
        c = self.core
        B, A = c.B, c.A
        bool_spec = lambda *shape: Categorical(n=2, shape=torch.Size(shape), dtype=torch.bool)  # noqa: E731
        self.observation_spec = Composite(
            {
                GROUP: Composite(
                    {
                        "observation": Unbounded(shape=(B, A, c.obs_dim), dtype=torch.float32),
                        "mask": bool_spec(B, A),
                        "action_mask": bool_spec(B, A, c.act_dim),
                    },
                    shape=(B, A),
                ),
                "state": Unbounded(shape=(B, c.state_dim), dtype=torch.float32),
                "metrics": Composite(
                    {k: Unbounded(shape=(B, c.K), dtype=torch.float64) for k in ("area", "dfd", "rmse")}, shape=(B,)
                ),
            },
            shape=(B,),
        )
        self.action_spec = Composite(
            {
                GROUP: Composite(
                    {"action": Bounded(low=-1.0, high=1.0, shape=(B, A, c.act_dim), dtype=torch.float32)},
                    shape=(B, A),
                )
            },
            shape=(B,),
        )
        self.reward_spec = Composite({"reward": Unbounded(shape=(B, 1), dtype=torch.float32)}, shape=(B,))
        self.done_spec = Composite({k: bool_spec(B, 1) for k in ("done", "terminated", "truncated")}, shape=(B,))

    def _observation_td(self) -> TensorDict:
        c = self.core
        obs, state = c.observations()
        m = c.metrics
        return TensorDict(
            {
                GROUP: TensorDict(
                    {"observation": obs, "mask": c.active.clone(), "action_mask": c.action_mask()},
                    batch_size=(c.B, c.A),
                ),
                "state": state,
                "metrics": TensorDict(
                    {"area": m.area.clone(), "dfd": m.dfd.clone(), "rmse": m.rmse.clone()}, batch_size=(c.B,)
                ),
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict:
            mask = tensordict.get("_reset").reshape(self.core.B)
        self.core.reset(seed=kwargs.get("seed"), mask=mask)
        out = self._observation_td()
        c = self.core
        for k, v in (("done", c.done), ("terminated", c.terminated), ("truncated", c.truncated)):
            out.set(k, v[:, None].clone())
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        c = self.core
        rows = tensordict.get("_step", None)  # TorchRL's partial step: only these rows go on
        c.step(tensordict.get((GROUP, "action")), mask=None if rows is None else rows.reshape(c.B))
        out = self._observation_td()
        out.set("reward", c.reward.to(torch.float32)[:, None])
        out.set("done", c.done[:, None].clone())
        out.set("terminated", c.terminated[:, None].clone())
        out.set("truncated", c.truncated[:, None].clone())
        return out

    def _set_seed(self, seed: int | None) -> None:
        self.core.seed(seed)
