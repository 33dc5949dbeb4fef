"""The depth-and-heading law and the thrusters behind it, composed (Sandøy 2016, ch. 2 and sec. 5.2).

:class:`ThrusterMapping` turns the LQG demand tau = [Z, N] into the 4-DOF wrench
[0, 0, Z, N] (rovlab.control.lqg.tau_to_wrench; K = M = 0 demanded) and allocates it to thruster
forces and PWM commands with the saturation-aware :class:`rovlab.allocation.Allocator`. It lives
here, above control and allocation, because those sibling layers do not import each other.
"""

from __future__ import annotations

import numpy as np

from rovlab.allocation import AllocationResult, Allocator
from rovlab.control.lqg import tau_to_wrench
from rovlab.params.vehicle import Vehicle


class ThrusterMapping:
    """tau = [Z, N] -> thruster forces and PWM through the vehicle's allocation."""

    def __init__(self, vehicle: Vehicle, allocator: Allocator | None = None) -> None:
        self.vehicle = vehicle
        self.allocator = allocator if allocator is not None else Allocator(vehicle)

    def allocate(self, tau: np.ndarray) -> AllocationResult:
        """Forces, PWM, achieved wrench and saturation report for the demand [Z, N]."""
        return self.allocator.allocate(tau_to_wrench(tau))

    def pwm_us(self, tau: np.ndarray) -> np.ndarray:
        return self.allocate(tau).pwm_us
