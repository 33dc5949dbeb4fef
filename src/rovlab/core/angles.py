"""Angle conventions: every angle inside rovlab is in radians, wrapped to (-pi, pi].

:func:`wrap_angle` is the one scalar wrap (a numba kernel, callable from Python and from other
compiled code); :func:`wrap` is its vectorised numpy counterpart for arrays.
"""

from __future__ import annotations

import math

import numpy as np

from rovlab._jit import njit  # numba's, or plain in `rovlab filter` with built kernels

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def wrap_angle(a: float) -> float:
    """a wrapped to (-pi, pi]."""
    return a - TWO_PI * math.ceil((a - math.pi) / TWO_PI)


def wrap(a: np.ndarray | float) -> np.ndarray:
    """Element-wise wrap to (-pi, pi] (numpy; NaN stays NaN)."""
    a = np.asarray(a, dtype=float)
    return a - TWO_PI * np.ceil((a - np.pi) / TWO_PI)
