"""FE vehicle models: the data model, the LS-DYNA keyword reader and writer, and
the synthetic B-segment generator (the embedded default vehicle)."""

from marlcrash.vehicle.materials import MATERIAL_FIELDS, Material, complete_material
from marlcrash.vehicle.model import COMPARTMENT, AxisMap, Part, VehicleModel

__all__ = [
    "COMPARTMENT",
    "MATERIAL_FIELDS",
    "AxisMap",
    "Material",
    "Part",
    "VehicleModel",
    "complete_material",
]
