"""Thrust curves from a load-cell staircase or a static table (Sandøy 2016, ch. 2, sec. 2.3).

The rig steps the PWM set-point (1300 -> 1700 us in 10 us steps, 30 s each in the thesis). The
force log is low-pass filtered (zero-phase 2nd-order Butterworth), the mean of the last
``window_s`` = 5 s of every step is taken as the thrust for that command, and the dead-band
curve of Sandøy 2016, ch. 2 is fitted by least squares, forward and reverse:

    s = u - d (u > d),  s = u + d (u < -d),  u = pwm_us - neutral
    f = K_L s + K_NL s |s|    (K_L, K_NL from the forward or the reverse set; f = 0 for |u| <= d)

with the dead band d fixed (default 25 us) or fitted (one d for both directions). All four
coefficients are constrained to be >= 0 (thrust grows with the command), as the vehicle file
requires. Symmetric pairs run together (T1 + T2) give ``pair = 2``: the force is divided by 2.

Log columns: ``time_s, pwm_us, force_n``; pwm_us is the staircase set-point (constant over each
step), force_n the thrust the thruster produces (positive for a forward command).
Static tables: ``pwm_us, force_n``, or the maker's CSV (``PWM (µs)``, ``Force (Kg f)``; kgf).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.ident.fitting import IdentificationError, covariance_from_jacobian, lowpass, sample_rate
from rovlab.io.tables import DataTable, read_table, require_increasing
from rovlab.params.vehicle import QuadraticCurve

KGF = 9.80665  # N per kilogram-force
NEUTRAL_US = 1500.0
DEFAULT_DEADBAND_US = 25.0
COEFFICIENTS = ("K_L_pos", "K_NL_pos", "K_L_neg", "K_NL_neg")
MIN_POINTS_PER_SIDE = 3  # two coefficients per direction + one degree of freedom


@dataclass(frozen=True, eq=False)
class StepMeans:
    """The steady thrust of each step of a staircase log."""

    pwm_us: np.ndarray  # set-point of each step [us]
    force_n: np.ndarray  # mean filtered force over the last window_s of the step [N]
    spread_n: np.ndarray  # standard deviation of the raw force in that window [N]
    start_s: np.ndarray  # start of each step [s]
    end_s: np.ndarray  # end of each step [s]
    window_s: float
    cutoff_hz: float
    pair: int
    time_s: np.ndarray  # the log (force already divided by pair), for plots
    force_raw_n: np.ndarray
    force_filtered_n: np.ndarray
    pwm_trace_us: np.ndarray
    skipped_us: tuple[float, ...] = ()  # set-points of steps shorter than the window


@dataclass(frozen=True, eq=False)
class ThrustFit:
    """Dead-band quadratic thrust curve with standard errors and residuals (Sandøy 2016, ch. 2)."""

    K_L_pos: float  # [N/us]
    K_NL_pos: float  # [N/us^2]
    K_L_neg: float
    K_NL_neg: float
    deadband_us: float
    deadband_fitted: bool
    neutral_us: float
    stderr: Mapping[str, float]  # same keys as the estimates (deadband_us: 0 when fixed)
    pwm_us: np.ndarray  # points used [us]
    force_n: np.ndarray  # measured thrust at those points [N]
    residual_n: np.ndarray  # measured - fitted [N]
    rms_n: float
    n_pos: int
    n_neg: int
    pair: int = 1
    steps: StepMeans | None = field(default=None, repr=False)

    def curve(self) -> QuadraticCurve:
        return QuadraticCurve(self.K_L_pos, self.K_NL_pos, self.K_L_neg, self.K_NL_neg)

    def force(self, pwm_us: np.ndarray | float) -> np.ndarray:
        """Thrust [N] of the fitted curve for PWM commands [us] (no saturation)."""
        return curve_force(np.asarray(pwm_us, dtype=float) - self.neutral_us, self.deadband_us,
                           self.K_L_pos, self.K_NL_pos, self.K_L_neg, self.K_NL_neg)

    def as_dict(self) -> dict[str, Any]:
        return {
            "K_L_pos": self.K_L_pos, "K_NL_pos": self.K_NL_pos,
            "K_L_neg": self.K_L_neg, "K_NL_neg": self.K_NL_neg,
            "deadband_us": self.deadband_us, "rms_n": self.rms_n,
            "stderr": dict(self.stderr), "deadband_fitted": self.deadband_fitted,
            "neutral_us": self.neutral_us, "points": int(self.pwm_us.size),
            "points_forward": self.n_pos, "points_reverse": self.n_neg, "pair": self.pair,
        }


def curve_force(u: np.ndarray, d: float, klp: float, knlp: float, kln: float, knln: float) -> np.ndarray:
    """f(u) of Sandøy 2016, ch. 2 for PWM offsets u = pwm - neutral [us]."""
    u = np.asarray(u, dtype=float)
    sp = np.maximum(u - d, 0.0)
    sn = np.minimum(u + d, 0.0)
    return klp * sp + knlp * sp * sp + kln * sn - knln * sn * sn


# --------------------------------------------------------------------------------------------
# Staircase -> steady points
# --------------------------------------------------------------------------------------------

def step_means(time_s: np.ndarray, pwm_us: np.ndarray, force_n: np.ndarray, *, window_s: float = 5.0,
               cutoff_hz: float = 1.0, pair: int = 1, tol_us: float = 0.5) -> StepMeans:
    """Mean filtered force over the last ``window_s`` of each PWM step (Sandøy 2016, sec. 2.3).

    A step is a run of consecutive samples whose set-point stays within ``tol_us``. Steps shorter
    than the window are skipped (listed in ``skipped_us``).
    """
    t = np.asarray(time_s, dtype=float)
    pwm = np.asarray(pwm_us, dtype=float)
    if pair < 1:
        raise IdentificationError(f"pair must be a positive number of thrusters, got {pair}")
    if window_s <= 0:
        raise IdentificationError(f"averaging window must be positive, got {window_s} s")
    f = np.asarray(force_n, dtype=float) / pair
    fs = sample_rate(t)
    if window_s * fs < 3:
        raise IdentificationError(f"averaging window {window_s:g} s holds fewer than 3 samples at {fs:g} Hz")
    filt = lowpass(f, fs, cutoff_hz, order=2)
    starts_list = [0]
    ref = pwm[0]
    for i in range(1, pwm.size):  # a new step whenever the set-point leaves the current one
        if abs(pwm[i] - ref) > tol_us:
            starts_list.append(i)
            ref = pwm[i]
    starts = np.array(starts_list)
    stops = np.concatenate([starts[1:], [t.size]])
    h = 1.0 / fs
    sel_pwm, sel_f, sel_sd, sel_t0, sel_t1, skipped = [], [], [], [], [], []
    for a, b in zip(starts, stops):
        t0, t1 = t[a], t[b - 1] + h
        if t1 - t0 < window_s - 0.5 * h:
            skipped.append(float(np.median(pwm[a:b])))
            continue
        m = (t[a:b] >= t1 - window_s - 0.5 * h)
        sel_pwm.append(float(np.median(pwm[a:b])))
        sel_f.append(float(np.mean(filt[a:b][m])))
        sel_sd.append(float(np.std(f[a:b][m], ddof=1)) if m.sum() > 1 else 0.0)
        sel_t0.append(t0)
        sel_t1.append(t1)
    if not sel_pwm:
        raise IdentificationError(
            f"no PWM step lasts {window_s:g} s: pwm_us must be the staircase set-point, held constant "
            f"over each step (found {len(starts)} step(s), the longest {_longest(t, starts, stops, h):.3g} s); "
            "use a shorter averaging window for a shorter staircase")
    return StepMeans(np.array(sel_pwm), np.array(sel_f), np.array(sel_sd), np.array(sel_t0), np.array(sel_t1),
                     window_s, cutoff_hz, pair, t, f, filt, pwm, tuple(skipped))


def _longest(t: np.ndarray, starts: np.ndarray, stops: np.ndarray, h: float) -> float:
    return float(max(t[b - 1] + h - t[a] for a, b in zip(starts, stops)))


# --------------------------------------------------------------------------------------------
# Curve fit
# --------------------------------------------------------------------------------------------

def fit_thrust_curve(pwm_us: np.ndarray, force_n: np.ndarray, *, neutral_us: float = NEUTRAL_US,
                     deadband_us: float | None = DEFAULT_DEADBAND_US,
                     pwm_range: tuple[float, float] | None = None, max_force_n: float | None = None,
                     pair: int = 1, steps: StepMeans | None = None) -> ThrustFit:
    """Least-squares fit of the dead-band curve to static (pwm, thrust) points.

    ``deadband_us=None`` fits the dead band too. ``pwm_range`` keeps only points inside it;
    ``max_force_n`` drops points whose |thrust| exceeds it (the thesis's rig bent above ~10 N).
    """
    from scipy.optimize import least_squares

    pwm = np.asarray(pwm_us, dtype=float)
    f = np.asarray(force_n, dtype=float)
    if pwm.shape != f.shape or pwm.ndim != 1:
        raise IdentificationError("pwm_us and force_n must be equally long 1-D series")
    keep = np.ones(pwm.size, dtype=bool)
    if pwm_range is not None:
        lo, hi = pwm_range
        if not lo < hi:
            raise IdentificationError(f"PWM range must be increasing, got {lo:g}..{hi:g}")
        keep &= (pwm >= lo) & (pwm <= hi)
    if max_force_n is not None:
        keep &= np.abs(f) <= max_force_n
    pwm, f = pwm[keep], f[keep]
    u = pwm - neutral_us
    fit_d = deadband_us is None
    d0 = DEFAULT_DEADBAND_US if fit_d else float(deadband_us)  # type: ignore[arg-type]
    if d0 < 0:
        raise IdentificationError(f"dead band must be >= 0, got {d0:g} us")
    n_pos = int(np.sum(u > d0))
    n_neg = int(np.sum(u < -d0))
    for n, side, rel in ((n_pos, "forward", ">"), (n_neg, "reverse", "<")):
        if n < MIN_POINTS_PER_SIDE:
            bound = neutral_us + d0 if side == "forward" else neutral_us - d0
            raise IdentificationError(
                f"the {side} curve needs at least {MIN_POINTS_PER_SIDE} steady points with PWM {rel} "
                f"{bound:g} us (outside the dead band); found {n}")

    for mask, side, want in ((u > d0, "forward", 1.0), (u < -d0, "reverse", -1.0)):
        if want * float(np.mean(f[mask])) <= 0:
            raise IdentificationError(
                f"the {side} steps produce {'negative' if want > 0 else 'positive'} thrust on average: force_n must "
                "be the thrust the thruster produces, positive for a forward command (check the load cell's sign "
                "or the thruster's mounting)")

    def model(p: np.ndarray) -> np.ndarray:
        d = p[4] if fit_d else d0
        return curve_force(u, d, p[0], p[1], p[2], p[3])

    def jac(p: np.ndarray) -> np.ndarray:
        d = p[4] if fit_d else d0
        sp = np.maximum(u - d, 0.0)
        sn = np.minimum(u + d, 0.0)
        cols = [sp, sp * sp, sn, -sn * sn]
        if fit_d:
            cols.append(-(p[0] + 2 * p[1] * sp) * (u > d) + (p[2] - 2 * p[3] * sn) * (u < -d))
        return np.column_stack(cols)

    # Start from the separate linear fits with the dead band fixed at its initial value.
    p0 = []
    for mask, s in ((u > d0, u - d0), (u < -d0, u + d0)):
        A = np.column_stack([s[mask], s[mask] * np.abs(s[mask])])
        c, *_ = np.linalg.lstsq(A, f[mask], rcond=None)
        p0 += [max(c[0], 1e-6), max(c[1], 1e-9)]
    lower = [0.0] * 4
    upper = [np.inf] * 4
    if fit_d:
        span = float(np.min(np.abs(u[np.abs(f) > 0]))) if np.any(np.abs(f) > 0) else 100.0
        umax = float(np.max(np.abs(u)))
        p0.append(min(d0, 0.9 * umax))
        lower.append(0.0)
        upper.append(max(umax - 1.0, span))
    p0 = np.clip(np.array(p0), np.array(lower), np.array(upper))
    sol = least_squares(lambda p: model(p) - f, p0, jac=jac, bounds=(lower, upper), x_scale="jac",
                        method="trf")
    p = sol.x
    res = f - model(p)
    J = jac(p)
    cov = covariance_from_jacobian(J, res)
    se = np.sqrt(np.abs(np.diag(cov)))
    names = COEFFICIENTS + (("deadband_us",) if fit_d else ())
    stderr = {n: float(s) for n, s in zip(names, se)}
    if not fit_d:
        stderr["deadband_us"] = 0.0
    d = float(p[4]) if fit_d else d0
    return ThrustFit(
        K_L_pos=float(p[0]), K_NL_pos=float(p[1]), K_L_neg=float(p[2]), K_NL_neg=float(p[3]),
        deadband_us=d, deadband_fitted=fit_d, neutral_us=neutral_us, stderr=stderr,
        pwm_us=pwm, force_n=f, residual_n=res, rms_n=float(np.sqrt(np.mean(res**2))),
        n_pos=int(np.sum(u > d)), n_neg=int(np.sum(u < -d)), pair=pair, steps=steps)


def fit_thrust_log(time_s: np.ndarray, pwm_us: np.ndarray, force_n: np.ndarray, *, pair: int = 1,
                   window_s: float = 5.0, cutoff_hz: float = 1.0, neutral_us: float = NEUTRAL_US,
                   deadband_us: float | None = DEFAULT_DEADBAND_US,
                   pwm_range: tuple[float, float] | None = None,
                   max_force_n: float | None = None) -> ThrustFit:
    """Load-cell staircase log -> steady points -> curve fit (Sandøy 2016, sec. 2.3)."""
    steps = step_means(time_s, pwm_us, force_n, window_s=window_s, cutoff_hz=cutoff_hz, pair=pair)
    return fit_thrust_curve(steps.pwm_us, steps.force_n, neutral_us=neutral_us, deadband_us=deadband_us,
                            pwm_range=pwm_range, max_force_n=max_force_n, pair=pair, steps=steps)


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------

LOG_COLUMNS = ("time_s", "pwm_us", "force_n")


def read_thrust_log(path: str | Path) -> DataTable:
    """A load-cell log with columns time_s, pwm_us, force_n (clear errors otherwise)."""
    table = read_table(path, required=LOG_COLUMNS, what="thrust log")
    require_increasing(table, "time_s")
    return table


def read_thrust_table(path: str | Path) -> tuple[np.ndarray, np.ndarray, str]:
    """(pwm_us, force_n, format) of a static table: ``pwm_us, force_n`` [N], ``pwm_us, force_kgf``,
    or the maker's T200 CSV (``PWM (µs)``, ``Force (Kg f)``), converted to newtons."""
    table = read_table(path, what="thrust table")
    cols = {c.lower().replace(" ", ""): c for c in table.columns}
    pwm_col = cols.get("pwm_us") or next((c for k, c in cols.items() if k.startswith("pwm")), None)
    force_col: str | None
    if "force_n" in cols:
        force_col, scale, fmt = cols["force_n"], 1.0, "pwm_us, force_n"
    elif "force_kgf" in cols:
        force_col, scale, fmt = cols["force_kgf"], KGF, "pwm_us, force_kgf"
    else:
        kgf = next((c for k, c in cols.items() if k.startswith("force") and "kg" in k), None)
        force_col, scale, fmt = kgf, KGF, "maker's T200 table (kgf)"
    if pwm_col is None or force_col is None:
        table.require("pwm_us", "force_n")
    return table[pwm_col], table[force_col] * scale, fmt  # type: ignore[index]


def thrust_edits(fit: ThrustFit, thrusters: Sequence[str], *, digits: int = 4) -> dict[str, Any]:
    """Vehicle-file edits (key path -> value) that make each named thruster use the fitted curve."""
    from rovlab.ident.fitting import significant
    from rovlab.params.edit import DELETE

    curve = {k: significant(getattr(fit, k), digits) for k in COEFFICIENTS}
    edits: dict[str, Any] = {}
    for name in thrusters:
        block = f"thrusters[name={name}]"
        edits[f"{block}.model"] = "quadratic"
        edits[f"{block}.quadratic"] = curve
        edits[f"{block}.table"] = DELETE
        edits[f"{block}.deadband_us"] = significant(fit.deadband_us, 4)
        edits[f"{block}.deadband_kind"] = DELETE  # the fit's dead band shifts the curve (the default)
        if fit.neutral_us != NEUTRAL_US:
            edits[f"{block}.pwm_neutral_us"] = fit.neutral_us
    return edits
