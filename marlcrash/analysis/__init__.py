"""Analysis of calibrations (DESIGN 7): per-agent contributions (Shapley values, leave-one-out), per-agent
parameter changes, and their pictures. The notebooks in ``notebooks/`` are thin layers over this package."""

from marlcrash.analysis.contributions import (
    Contributions,
    RunCalibration,
    agent_changes,
    agent_contributions,
    coalition_params,
    quantity_names,
    run_calibration,
    step_directions,
)
from marlcrash.analysis.plots import plot_cells_by_contribution, plot_contributions
from marlcrash.analysis.shapley import Attribution, exact_shapley, one_at_a_time, sampled_shapley

__all__ = [
    "Attribution",
    "Contributions",
    "RunCalibration",
    "agent_changes",
    "agent_contributions",
    "coalition_params",
    "exact_shapley",
    "one_at_a_time",
    "plot_cells_by_contribution",
    "plot_contributions",
    "quantity_names",
    "run_calibration",
    "sampled_shapley",
    "step_directions",
]
