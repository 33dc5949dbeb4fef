"""Angle conventions: every angle inside rovlab is in radians, wrapped to (-pi, pi].

:func:`wrap_angle` is the one scalar wrap (a numba kernel, callable from Python and from other
compiled code); :func:`wrap` is its vectorised numpy counterpart for arrays. :func:`cos_sin_small`
gives cos and sin of a small angle without calling them (for turning a known heading by a small
increment with the angle-addition formulas, as the plant's RK4 does).
"""

from __future__ import annotations

import math

import numpy as np

from rovlab._jit import njit

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def wrap_angle(a: float) -> float:
    """a wrapped to (-pi, pi]."""
    return a - TWO_PI * math.ceil((a - math.pi) / TWO_PI)


def wrap(a: np.ndarray | float) -> np.ndarray:
    """Element-wise wrap to (-pi, pi] (numpy; NaN stays NaN)."""
    a = np.asarray(a, dtype=float)
    return a - TWO_PI * np.ceil((a - np.pi) / TWO_PI)


SMALL_ANGLE = 0.1  # |d| up to which cos_sin_small uses its series: the first omitted terms are < 3e-17


@njit(cache=True, inline="always")
def cos_sin_series(d: float) -> tuple[float, float]:
    """(cos d, sin d) by their Taylor series to d^8 and d^9, whatever d: exact to rounding for
    |d| <= 0.1 only (:func:`cos_sin_small` checks the range)."""
    d2 = d * d
    c = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0 - d2 * (1.0 / 40320.0))))
    s = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0 - d2 * (1.0 / 362880.0)))))
    return c, s


@njit(cache=True, inline="always")
def cos_sin_small(d: float) -> tuple[float, float]:
    """(cos d, sin d) by their Taylor series to d^8 and d^9 when |d| <= 0.1 (truncation below
    3e-17, i.e. within rounding of math.cos/math.sin), else by math.cos and math.sin.

    With c = cos(psi), s = sin(psi) known, cos(psi + d) = c cos d - s sin d and
    sin(psi + d) = s cos d + c sin d then cost a few multiplications instead of a sine and a
    cosine (about 14 ns together here, and on the critical path of a Runge-Kutta step).
    """
    if not abs(d) <= SMALL_ANGLE:  # (NaN too)
        return math.cos(d), math.sin(d)
    return cos_sin_series(d)
