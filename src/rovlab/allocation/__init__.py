"""Thrust allocation: configuration matrix and (saturation-aware) solvers."""

from rovlab.allocation.geometry import configuration_matrix, configuration_matrix_from
from rovlab.allocation.solvers import (
    DEFAULT_PRIORITY,
    SCALE_ALL,
    AllocationResult,
    Allocator,
    as_wrench6,
    weighted_pinv,
)

__all__ = ["DEFAULT_PRIORITY", "SCALE_ALL", "AllocationResult", "Allocator", "as_wrench6",
           "configuration_matrix", "configuration_matrix_from", "weighted_pinv"]
