"""Cells: ROI, section planes, uniform/optimized discretization, cross-sections and
transmission initialisation (VehicleModel -> CellModel, DESIGN 1.2, 1.3)."""

from marlcrash.cells.discretize import DiscretizationConfig, SensorSpec, discretize, load_discretization_config
from marlcrash.cells.model import DIRECTIONS, PARAM_NAMES, CellModel
from marlcrash.cells.summary import discretization_summary, format_discretization_summary, summarize_cells

__all__ = [
    "DIRECTIONS",
    "PARAM_NAMES",
    "CellModel",
    "DiscretizationConfig",
    "SensorSpec",
    "discretization_summary",
    "discretize",
    "format_discretization_summary",
    "load_discretization_config",
    "summarize_cells",
]
