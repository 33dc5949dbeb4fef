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

from rovlab.core.angles import wrap
from rovlab.estimation import consistency as cons


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


# chi-square intervals are asked for the same (dof, runs) over and over in Monte Carlo
_interval = functools.lru_cache(maxsize=256)(cons.chi2_interval)


def consistency(values: np.ndarray, dof: int, *, probability: float = 0.95) -> dict[str, Any]:
    """Consistency of a NEES/NIS series from one run (values: (K,)) or many (values: (N, K)).

    Returns the overall average and its chi-square interval, and the share of time steps whose
    run-average lies inside the per-step interval (rovlab.estimation.consistency.check; a
    consistent filter keeps about `probability` inside).
    """
    v = np.atleast_2d(np.asarray(values, dtype=float))
    runs = v.shape[0]
    ok = np.isfinite(v)
    n = int(ok.sum())
    mean = float(np.where(ok, v, 0.0).sum() / max(n, 1))
    lo, hi = _interval(dof, runs, probability)
    if runs > 1:
        share = cons.check(np.where(ok, v, np.nan), dof, probability).fraction_inside
    else:
        row = v[0][ok[0]]
        share = float(np.mean((row >= lo) & (row <= hi))) if row.size else math.nan
    avg_lo, avg_hi = _interval(dof, max(n, 1), probability)
    return {
        "dof": dof, "runs": runs, "mean": mean,
        "bounds_per_step": [lo, hi], "share_inside": share,
        "mean_bounds": [avg_lo, avg_hi],
        "mean_inside": bool(avg_lo <= mean <= avg_hi),
    }
