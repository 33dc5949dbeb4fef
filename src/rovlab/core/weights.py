"""Bryson's rule for quadratic weights (Bryson & Ho 1975, sec. 5.4): weight_i / max_i^2.

The one implementation of the rule: the configuration loader (rovlab.params.design) turns the
file's maxima into LQR weights with it, and rovlab.control.lqr offers it as a matrix.
"""

from __future__ import annotations

import numpy as np


def bryson_diagonal(maxima: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The diagonal w_i / max_i^2 (w_i = 1 when not given); NaN where a maximum is NaN."""
    mx = np.asarray(maxima, dtype=float).ravel()
    w = np.ones_like(mx) if weights is None else np.asarray(weights, dtype=float).ravel()
    if mx.shape != w.shape or np.any(mx <= 0) or np.any(np.isinf(mx)) or np.any(w < 0):
        raise ValueError("Bryson's rule needs positive maxima and non-negative weights of the same length")
    return w / mx**2
