"""The crash surrogate: scenarios, batched explicit dynamics over the cell graph, energy accounting."""

from marlcrash.sim.energy import balance_error, behaviour_curve, cell_energies, max_balance_error
from marlcrash.sim.scenario import (
    CrashScenario,
    barrier_fraction,
    barrier_mask,
    get_scenario,
    list_scenarios,
)
from marlcrash.sim.surrogate import SimConfig, SimResult, Surrogate, load_sim_config

__all__ = [
    "CrashScenario",
    "SimConfig",
    "SimResult",
    "Surrogate",
    "balance_error",
    "barrier_fraction",
    "barrier_mask",
    "behaviour_curve",
    "cell_energies",
    "get_scenario",
    "list_scenarios",
    "load_sim_config",
    "max_balance_error",
]
