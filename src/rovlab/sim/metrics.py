"""Numbers that summarise a closed-loop run: estimation error, step response, drop-out drift and
filter consistency (normalised estimation error squared, NEES, and normalised innovation squared,
NIS, against chi-square bounds; Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4).

Pure functions of logged arrays; angles are wrapped before differences are taken.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Sequence

import numpy as np
from scipy.stats import chi2


def wrap(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) wrapped to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def estimation_error(est: np.ndarray, truth: np.ndarray, angle_columns: Sequence[int] = (1,)) -> np.ndarray:
    err = np.asarray(est, dtype=float) - np.asarray(truth, dtype=float)
    for j in angle_columns:
        err[:, j] = wrap(err[:, j])
    return err


def rms(err: np.ndarray) -> np.ndarray:
    """Root mean square along the first axis, ignoring NaN (NaN where nothing is left)."""
    e = np.asarray(err, dtype=float)
    ok = np.isfinite(e)
    count = ok.sum(axis=0)
    with np.errstate(over="ignore"):
        total = np.where(ok, e, 0.0) ** 2
    return np.where(count > 0, np.sqrt(total.sum(axis=0) / np.maximum(count, 1)), np.nan)


def step_response(t: np.ndarray, y: np.ndarray, t_step: float, y0: float, y1: float, t_end: float,
                  *, band: float = 0.02, min_band: float = 0.0, angle: bool = False) -> dict[str, Any]:
    """Settling time (to within +-band of the step size, at least min_band) and overshoot (fraction
    of the step size beyond the set-point) of y after a step from y0 to y1 at t_step."""
    sel = (t >= t_step) & (t < t_end)
    tt, yy = t[sel], np.asarray(y, dtype=float)[sel]
    step = wrap(y1 - y0) if angle else y1 - y0
    out: dict[str, Any] = {"t_s": float(t_step), "from": float(y0), "to": float(y1),
                           "settling_time_s": None, "overshoot": None}
    if tt.size == 0 or step == 0:
        return out
    err = wrap(yy - y1) if angle else yy - y1
    tol = max(band * abs(step), min_band)
    outside = np.nonzero(np.abs(err) > tol)[0]
    if outside.size == 0:
        out["settling_time_s"] = 0.0
    elif outside[-1] < tt.size - 1:
        out["settling_time_s"] = float(tt[outside[-1] + 1] - t_step)
    beyond = -err * np.sign(-step)  # positive when past the set-point in the step's direction
    out["overshoot"] = float(max(0.0, np.max(beyond)) / abs(step))
    return out


def nees(err: np.ndarray, P: np.ndarray) -> np.ndarray:
    """e_k^T P_k^-1 e_k per row (P: (K, n, n)); NaN where P is singular (e.g. P0 = 0)."""
    err = np.asarray(err, dtype=float)
    P = np.asarray(P, dtype=float)
    out = np.full(err.shape[0], np.nan)
    # Cholesky of every covariance at once; rows that are not positive definite stay NaN
    diag = np.einsum("kii->ki", P)
    ok = np.all(diag > 0, axis=1) & np.all(np.isfinite(P), axis=(1, 2)) & np.all(np.isfinite(err), axis=1)
    idx = np.flatnonzero(ok)
    if idx.size:
        try:
            L = np.linalg.cholesky(P[idx])
            z = np.linalg.solve(L, err[idx][..., None])[..., 0]
            out[idx] = np.sum(z * z, axis=1)
        except np.linalg.LinAlgError:
            for k in idx:
                try:
                    out[k] = err[k] @ np.linalg.solve(P[k], err[k])
                except np.linalg.LinAlgError:
                    pass
    return out


@functools.lru_cache(maxsize=256)
def chi2_interval(dof: float, runs: int = 1, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided bounds of the average of `runs` independent chi-square(dof) variables."""
    a = (1 - probability) / 2
    return (float(chi2.ppf(a, dof * runs) / runs), float(chi2.ppf(1 - a, dof * runs) / runs))


def consistency(values: np.ndarray, dof: int, *, probability: float = 0.95) -> dict[str, Any]:
    """Consistency of a NEES/NIS series from one run (values: (K,)) or many (values: (N, K)).

    Returns the average, the share of time steps whose run-average lies inside the chi-square
    bounds, and the bounds themselves. A consistent filter keeps about `probability` inside.
    """
    v = np.atleast_2d(np.asarray(values, dtype=float))
    runs = v.shape[0]
    ok = np.isfinite(v)
    count = ok.sum(axis=0)
    per_step = np.where(count > 0, np.where(ok, v, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan)
    lo, hi = chi2_interval(dof, runs, probability)
    finite = np.isfinite(per_step)
    inside = float(np.mean((per_step[finite] >= lo) & (per_step[finite] <= hi))) if finite.any() else math.nan
    total = float(np.where(ok, v, 0.0).sum())
    n = int(ok.sum())
    avg_lo, avg_hi = chi2_interval(dof, max(n, 1), probability)
    return {
        "dof": dof, "runs": runs, "mean": float(total / max(n, 1)),
        "bounds_per_step": [lo, hi], "share_inside": inside,
        "mean_bounds": [avg_lo, avg_hi],
        "mean_inside": bool(avg_lo <= total / max(n, 1) <= avg_hi),
    }
