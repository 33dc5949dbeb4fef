"""Simulated sensors: each channel samples one true quantity at its own rate, with its lever-arm
offset and white noise (Sandøy 2016, sec. 4.4 and 5.1).

Channel j measures ``truth[quantity[j]] + offset[j] + std[j] * n`` (n ~ N(0, 1), drawn beforehand
from the run's seed) every ``period[j]`` control steps, wrapped to (-pi, pi] for angles; no
sample while the channel is in a drop-out window. The truth layout is
rovlab.core.components.TRUTH ([x, y, z, psi, u, v, w, r, biases]).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rovlab._jit import njit
from rovlab.core.angles import wrap_angle


class SensorBank(NamedTuple):
    quantity: np.ndarray  # int64 (m): index into the truth vector
    offset: np.ndarray  # (m): added to the truth (lever arm: z_sensor = z_VO + l_z)
    std: np.ndarray  # (m): noise standard deviation
    period: np.ndarray  # int64 (m): sample every period control steps (0 = never)
    angle: np.ndarray  # bool (m): wrap to (-pi, pi]


@njit(cache=True, inline="always")
def sample_sensors(bank, truth, k, normals, dropout, row, y, present):
    """Samples of control step k into y (NaN when none) and present; normals and dropout
    (rows x channels) are read at ``row``."""
    for j in range(y.shape[0]):
        p = bank.period[j]
        if p > 0 and k % p == 0 and not dropout[row, j]:
            v = truth[bank.quantity[j]] + bank.offset[j] + bank.std[j] * normals[row, j]
            if bank.angle[j]:
                v = wrap_angle(v)
            y[j] = v
            present[j] = True
        else:
            y[j] = np.nan
            present[j] = False
