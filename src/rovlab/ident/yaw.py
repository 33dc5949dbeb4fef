"""Yaw damping from constant-moment runs (Sandøy 2016, sec. 4.3.2).

The allocation applies a constant yaw moment (0.25, 0.5, 0.75, 1 and 2 N m in the thesis) and the
vehicle spins up to a steady yaw rate, where

    moment_nm = -(N_r r + N_|r|r |r| r)        (SNAME signs; cubic optional)

The steady rate is read from the heading without differentiating it: the heading is unwrapped
(so wrap-around at +-pi is harmless), the steady window is found on a smoothed rate, and the
rate is the slope of a straight line fitted to the heading over that window (its standard
error follows from the line fit; noise on the heading averages out instead of being amplified).

Columns: ``run, time_s, moment_nm, heading_rad`` (heading may be wrapped to (-pi, pi]).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rovlab.ident.fitting import IdentificationError
from rovlab.ident.steady import Window, mean_with_stderr, noise_level, smooth
from rovlab.ident.towing import DampingFit, RunSeries, SteadyPoint, fit_steady_damping
from rovlab.io.tables import DataTable, read_table, require_increasing, split_runs

COLUMNS = ("run", "time_s", "moment_nm", "heading_rad")
YAW_TERMS = ("linear", "quadratic")


def unwrap_heading(heading_rad: np.ndarray) -> np.ndarray:
    """Continuous heading from a wrapped one (jumps larger than pi are taken as wraps)."""
    return np.unwrap(np.asarray(heading_rad, dtype=float))


def line_slope(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope of a least-squares line and its standard error."""
    t = np.asarray(t, dtype=float)
    tc = t - t.mean()
    sxx = float(tc @ tc)
    slope = float(tc @ (y - y.mean())) / sxx
    res = y - y.mean() - slope * tc
    n = t.size
    se = float(np.sqrt((res @ res) / max(n - 2, 1) / sxx))
    return slope, se


def steady_rate(t: np.ndarray, heading: np.ndarray, moment: np.ndarray, *, what: str, min_s: float = 2.0,
                rel_tol: float = 0.02) -> tuple[Window, float, float]:
    """(window, rate, its standard error) of one constant-moment run."""
    psi = unwrap_heading(heading)
    h = float(np.median(np.diff(t)))
    on = np.abs(moment) >= 0.5 * np.max(np.abs(moment))
    if not np.any(on) or np.max(np.abs(moment)) == 0:
        raise IdentificationError(f"{what}: moment_nm is zero throughout; a run needs a constant moment")
    idx = np.flatnonzero(on)
    a0, b0 = int(idx[0]), int(idx[-1]) + 1
    n_on = b0 - a0
    if n_on * h < 2 * min_s:
        raise IdentificationError(f"{what}: the moment is applied for {n_on * h:.3g} s; need at least "
                                  f"{2 * min_s:g} s to reach and hold a steady rate")
    # smoothed local rate: slope of the heading over ~1 s (central difference of smoothed heading)
    k = max(2, int(round(1.0 / h)))
    ps = smooth(psi, k)
    rate = np.gradient(ps, t)
    tail = slice(b0 - max(n_on // 4, 3), b0)
    final, _ = line_slope(t[tail], psi[tail])
    sigma_rate = noise_level(psi) * np.sqrt(2.0) / (k * h)  # roughly the noise of a k-sample slope
    tol = max(rel_tol * abs(final), 4 * sigma_rate, 1e-6)
    ok = np.abs(rate[a0:b0] - final) <= tol
    bad = np.flatnonzero(~ok[: n_on - k])  # ignore the last k samples (smoothing edge)
    start = a0 + (int(bad[-1]) + 1 if bad.size else 0) + k
    stop = b0 - k // 2
    if (stop - start) * h < min_s:
        raise IdentificationError(
            f"{what}: the yaw rate is steady for only {max(0, stop - start) * h:.3g} s (rate {final:.3g} rad/s); "
            f"need at least {min_s:g} s; run longer or check that the moment is constant")
    r, se = line_slope(t[start:stop], psi[start:stop])
    return Window(start, stop, final, tol), r, se


def yaw_points(table: DataTable, *, min_s: float = 2.0) -> list[SteadyPoint]:
    table.require(*COLUMNS)
    out = []
    for rid, rows in split_runs(table, "run"):
        require_increasing(rows, "time_s")
        t, m, psi = rows["time_s"], rows["moment_nm"], rows["heading_rad"]
        if t.size < 10:
            raise IdentificationError(f"{table.file}: run {rid}: {t.size} sample(s); a run needs a time series")
        win, r, _ = steady_rate(t, psi, m, what=f"{table.file}: run {rid}", min_s=min_s)
        moment, mse = mean_with_stderr(m[win.start:win.stop])
        out.append(SteadyPoint(rid, r, moment, mse, 0.0, float(t[win.start]), float(t[win.stop - 1]),
                               RunSeries(rid, t, unwrap_heading(psi), m)))
    return out


def identify_yaw(table: DataTable, *, terms: Sequence[str] = YAW_TERMS, min_s: float = 2.0) -> DampingFit:
    """Constant-moment runs -> SNAME yaw damping N_r, N_|r|r (and N_rrr if asked)."""
    pts = yaw_points(table, min_s=min_s)
    return fit_steady_damping(pts, (), terms=terms, dof="yaw", what="yaw", unit="N m", speed_unit="rad/s")


def read_yaw(path: str | Path) -> DataTable:
    return read_table(path, required=COLUMNS, what="yaw log")
