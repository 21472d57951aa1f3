"""Calibration: the shared problem, simulation budgets and optimizer baselines (DESIGN 6)."""

from marlcrash.calibrate.baselines import (
    BASELINES,
    BaselineRunConfig,
    CalibrationResult,
    CMAESConfig,
    GradientConfig,
    LMConfig,
    RandomSearchConfig,
    cmaes,
    gradient_descent,
    levenberg_marquardt,
    load_run_config,
    random_search,
    run_baseline,
    write_run,
)
from marlcrash.calibrate.budget import HistoryRow, Progress
from marlcrash.calibrate.landscape import truth_neighbourhood
from marlcrash.calibrate.problem import (
    CalibrationProblem,
    ProblemConfig,
    SmoothLoss,
    SuccessConfig,
    build_problem,
)

__all__ = [
    "BASELINES",
    "BaselineRunConfig",
    "CMAESConfig",
    "CalibrationProblem",
    "CalibrationResult",
    "GradientConfig",
    "HistoryRow",
    "LMConfig",
    "ProblemConfig",
    "Progress",
    "RandomSearchConfig",
    "SmoothLoss",
    "SuccessConfig",
    "build_problem",
    "cmaes",
    "gradient_descent",
    "levenberg_marquardt",
    "load_run_config",
    "random_search",
    "run_baseline",
    "truth_neighbourhood",
    "write_run",
]
