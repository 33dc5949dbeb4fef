"""rovlab: model, identify, estimate, control and simulate small underwater vehicles.

Units are SI and radians inside; NED world frame, FRD body frame; SNAME names and signs.
See docs/conventions.md.
"""

__version__ = "0.1.0"
