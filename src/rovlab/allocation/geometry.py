"""Thrust configuration matrix from thruster positions and directions (Sandøy 2016, ch. 2).

Thruster i at r_i with unit thrust direction e_i contributes the wrench column
[e_i; r_i x e_i]; stacking the columns gives B (6 x n, rows X, Y, Z, K, M, N) with
tau_6 = B f for thruster forces f (Fossen 2011, sec. 12.3).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rovlab.params.vehicle import Vehicle


def configuration_matrix_from(positions: Sequence[np.ndarray], directions: Sequence[np.ndarray]) -> np.ndarray:
    r = np.asarray(positions, dtype=float).reshape(-1, 3)
    e = np.asarray(directions, dtype=float).reshape(-1, 3)
    if r.shape != e.shape:
        raise ValueError(f"{len(r)} positions but {len(e)} directions")
    return np.vstack([e.T, np.cross(r, e).T])


def configuration_matrix(vehicle: Vehicle) -> np.ndarray:
    """The 6 x n configuration matrix of a vehicle's thrusters."""
    return configuration_matrix_from([t.position for t in vehicle.thrusters],
                                     [t.direction for t in vehicle.thrusters])
