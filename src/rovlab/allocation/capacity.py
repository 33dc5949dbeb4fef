"""What the thrusters can give per DOF: the thrust capacity of a vehicle (a design quantity, plain
Python; used by the DP controller's integral bound and the dive planner's excitation levels)."""

from __future__ import annotations

import numpy as np

from rovlab.allocation.geometry import configuration_matrix
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.vehicle import Vehicle


def thrust_capacity(vehicle: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """(most negative, most positive) force or moment per DOF X, Y, Z, N [N, N m] that the
    thrusters give in that DOF alone, every other DOF (roll and pitch included) at zero: what the
    saturation-aware allocation (rovlab.allocation.Allocator) answers to a pure demand, as a small
    linear program per DOF and sign (tests/control/test_dp_integral_limit.py compares the two)."""
    from scipy.optimize import linprog

    B = configuration_matrix(vehicle)  # 6 x n, rows X, Y, Z, K, M, N (Fossen 2011, sec. 12.3)
    bank = ThrusterBank.from_vehicle(vehicle)
    n = B.shape[1]
    lo, hi = np.zeros(4), np.zeros(4)
    for k, row in enumerate((0, 1, 2, 5)):
        A = np.hstack([B, -np.eye(6)[:, [row]]])  # B f - t e_row = 0
        bounds = [(float(a), float(b)) for a, b in zip(bank.f_min, bank.f_max)] + [(None, None)]
        for sign, out in ((1.0, hi), (-1.0, lo)):
            cost = np.zeros(n + 1)
            cost[-1] = -sign  # maximise sign * t
            res = linprog(cost, A_eq=A, b_eq=np.zeros(6), bounds=bounds, method="highs")
            out[k] = float(res.x[-1]) if res.status == 0 else 0.0
    return lo, hi


__all__ = ["thrust_capacity"]
