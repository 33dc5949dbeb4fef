"""Vehicle parameters: the closed TOML schema, its loader and the packaged vehicles."""

from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import (
    DOF4,
    WRENCH6,
    Geometry,
    QuadraticCurve,
    Sensor,
    Thruster,
    Vehicle,
    check_vehicle_file,
    load_vehicle,
    packaged_vehicle_names,
    vehicle_from_dict,
)

__all__ = [
    "DOF4", "WRENCH6", "ConfigError", "Geometry", "Problem", "QuadraticCurve", "Sensor", "Thruster",
    "Vehicle", "check_vehicle_file", "load_vehicle", "packaged_vehicle_names", "vehicle_from_dict",
]
