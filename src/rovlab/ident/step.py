"""First-order model from a step or relay response, any DOF (Sandøy 2016, sec. 4.2.2).

Decoupled, linearised 1-DOF dynamics (surge shown; SNAME signs):

    (m - X_udot) u_dot = X_u u + tau        <=>   u(s)/tau(s) = k / (s + a),
    k = 1 / (m - X_udot),   a = -X_u / (m - X_udot)

so, for a given rigid-body mass m (or inertia I_zz for yaw),

    X_udot = m - 1/k  (added mass, negative)   and   X_u = -a / k  (linear damping, negative).

The thesis got k = 0.07769, a = 1.197 (X_udot ~ -5.56; its printed -5.517 is a slip, corrected here).

Output-error fit: the model's *position* response to the logged force (held constant between
samples, i.e. exact zero-order-hold discretisation) is simulated and (k, a, initial position and
velocity, optionally a constant force bias b: tau -> tau + b, e.g. net buoyancy in heave) are
fitted to the measured position by least squares. The problem is separable: for a given pole a
the response is linear in (x0, v0, k, k b), so a is found by a 1-D search with the rest solved
exactly (variable projection, Golub & Pereyra 1973), then all parameters are refined jointly for
the standard errors. Velocity is never differentiated into the fit; a Savitzky-Golay derivative
(smoothing and differentiating in one step, so noise is not amplified) is only used for the plot.

The model is linear: with quadratic/cubic damping in the truth the fitted a is an equivalent
linearisation at the speeds the test reached, and the added mass is biased (8-17 % on uDrone at
the virtual lab's default relay force). When the nonlinear damping is known (towing tests, the
vehicle file), pass it as ``damping = (quadratic, cubic)``: the model becomes

    (m - X_udot) u_dot = X_u u + X_|u|u |u| u + X_uuu u^3 + tau (+ b)

with the quadratic and cubic terms held fixed, so only the added mass, the linear damping, the
initial state (and the bias) are fitted, and the added mass is no longer biased. This model is
not linear in its parameters: it is integrated by fourth-order Runge-Kutta (four sub-steps per
sample, force held) and fitted by nonlinear least squares started from the linear fit.

Columns: ``time_s, force_n, position_m`` (or, for yaw, ``time_s, moment_nm, heading_rad``;
the heading is unwrapped).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.ident.fitting import IdentificationError, covariance_from_jacobian, significant
from rovlab.io.tables import DataTable, read_table, require_increasing

COLUMNS = ("time_s", "force_n", "position_m")
YAW_COLUMNS = ("time_s", "moment_nm", "heading_rad")
DOF_KEYS = {"surge": ("X_udot", "surge"), "sway": ("Y_vdot", "sway"), "heave": ("Z_wdot", "heave"),
            "yaw": ("N_rdot", "yaw")}


@dataclass(frozen=True, eq=False)
class StepFit:
    """k, a of u(s)/tau(s) = k/(s + a) with the added mass and linear damping they imply."""

    gain: float  # k [1/kg] (or 1/(kg m^2) for yaw)
    pole: float  # a [1/s]
    x0: float  # initial position [m or rad]
    v0: float  # initial velocity
    bias: float  # constant force added to the logged one [N] (0 unless fitted)
    mass: float  # rigid-body mass (inertia) given by the user
    added_mass: float  # SNAME: m - 1/k (negative)
    linear_damping: float  # SNAME: -a/k (negative)
    stderr: Mapping[str, float]  # of gain, pole, x0, v0, bias, added_mass, linear_damping
    time_s: np.ndarray
    force: np.ndarray
    position: np.ndarray
    position_fit: np.ndarray
    velocity_smoothed: np.ndarray  # Savitzky-Golay derivative of the measured position
    velocity_fit: np.ndarray
    residual: np.ndarray  # measured - fitted position
    rms: float
    fit_percent: float  # 100 (1 - |y - y_fit| / |y - mean y|), as MATLAB's compare
    bias_fitted: bool = False
    fixed_damping: tuple[float, float] = (0.0, 0.0)  # (quadratic, cubic) held fixed, SNAME signs

    def as_dict(self) -> dict[str, Any]:
        return {"gain": self.gain, "pole": self.pole, "added_mass": self.added_mass,
                "linear_damping": self.linear_damping, "mass": self.mass, "x0": self.x0, "v0": self.v0,
                "bias": self.bias, "bias_fitted": self.bias_fitted, "stderr": dict(self.stderr),
                "rms": self.rms, "fit_percent": self.fit_percent, "samples": int(self.time_s.size),
                "fixed_damping": {"quadratic": self.fixed_damping[0], "cubic": self.fixed_damping[1]}}


# --------------------------------------------------------------------------------------------
# Model responses (exact ZOH on a uniform grid)
# --------------------------------------------------------------------------------------------

def _phi(a: float, h: float) -> tuple[float, float, float]:
    """e = exp(-a h), g1 = (1 - e)/a, g2 = (h - g1)/a with their a -> 0 limits."""
    x = a * h
    e = float(np.exp(-x))
    if abs(x) < 1e-6:
        g1 = h * (1 - x / 2 + x * x / 6)
        g2 = h * h * (0.5 - x / 6 + x * x / 24)
    else:
        g1 = float(-np.expm1(-x) / a)
        g2 = (h - g1) / a
    return e, g1, g2


def responses(a: float, h: float, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position responses on samples k = 0..n-1 to: x0 (ones), v0, the input u (k = 1), a unit
    constant input; and the velocity response to u. Input u_k is held over [t_k, t_k+1)."""
    from scipy.signal import lfilter

    n = u.size
    e, g1, g2 = _phi(a, h)
    k = np.arange(n)
    if abs(a * h) < 1e-9:
        free_v0 = h * k.astype(float)
    else:
        free_v0 = -np.expm1(-a * h * k) / a
    # velocity driven by u: v_{k+1} = e v_k + g1 u_k, v_0 = 0
    v = lfilter([0.0, g1], [1.0, -e], u)
    # position: x_{k+1} = x_k + g1 v_k + g2 u_k, x_0 = 0
    dx = g1 * v + g2 * u
    x = np.concatenate([[0.0], np.cumsum(dx[:-1])])
    ones = np.ones(n)
    vb = lfilter([0.0, g1], [1.0, -e], ones)
    xb = np.concatenate([[0.0], np.cumsum((g1 * vb + g2 * ones)[:-1])])
    return free_v0, x, xb, v


def _design(a: float, h: float, u: np.ndarray, bias: bool) -> np.ndarray:
    g, xu, xb, _ = responses(a, h, u)
    cols = [np.ones(u.size), g, xu] + ([xb] if bias else [])
    return np.column_stack(cols)


def savgol_velocity(t: np.ndarray, x: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """Velocity from position by a Savitzky-Golay derivative (quadratic over ~window_s)."""
    from scipy.signal import savgol_filter

    h = float(np.median(np.diff(t)))
    n = max(5, int(round(window_s / h)) | 1)  # odd window length
    if n > x.size:
        n = x.size if x.size % 2 else x.size - 1
    if n < 3:
        return np.gradient(x, t)
    return savgol_filter(x, n, min(2, n - 1), deriv=1, delta=h, mode="interp")


# --------------------------------------------------------------------------------------------
# Fit
# --------------------------------------------------------------------------------------------

def fit_step_response(time_s: np.ndarray, force: np.ndarray, position: np.ndarray, *, mass: float,
                      bias: bool = False, pole_bounds: tuple[float, float] = (1e-4, 1e2),
                      damping: tuple[float, float] | None = None) -> StepFit:
    """Output-error fit of k/(s + a) to a position response; see the module docstring.

    ``damping = (quadratic, cubic)``: known nonlinear damping of this DOF (SNAME signs, <= 0,
    e.g. X_|u|u and X_uuu from the vehicle file), held fixed in the fit.
    """
    from scipy.optimize import least_squares, minimize_scalar

    t = np.asarray(time_s, dtype=float)
    u = np.asarray(force, dtype=float)
    y = np.asarray(position, dtype=float)
    if not (np.isfinite(mass) and mass > 0):
        raise IdentificationError(f"the rigid-body mass must be positive, got {mass}")
    if damping is not None:
        quad, cub = (float(d) for d in damping)
        if not (np.isfinite(quad) and np.isfinite(cub) and quad <= 0 and cub <= 0):
            raise IdentificationError(f"the fixed nonlinear damping (quadratic {quad:g}, cubic {cub:g}) must be finite "
                                      "and <= 0 (SNAME signs)")
        if quad != 0.0 or cub != 0.0:
            lin = fit_step_response(t, u, y, mass=mass, bias=bias, pole_bounds=pole_bounds)
            return _fit_nonlinear(lin, quad, cub)
    if t.size < 10:
        raise IdentificationError(f"{t.size} samples; a step response needs a time series (at least 10 samples)")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise IdentificationError(f"time does not increase at sample {i} ({t[i - 1]:g} -> {t[i]:g} s)")
    h = float(np.median(dt))
    if np.max(np.abs(dt - h)) > 0.05 * h:
        i = int(np.argmax(np.abs(dt - h)))
        raise IdentificationError(f"the step-response fit needs uniform sampling; step {dt[i]:g} s at t = {t[i]:g} s "
                                  f"differs from the median {h:g} s by more than 5 %")
    if np.ptp(u) == 0:
        raise IdentificationError("the force never changes: a step or relay test needs at least one switch")
    if np.ptp(y) == 0:
        raise IdentificationError("the position never changes: the vehicle did not move")
    n_switch = int(np.sum(np.abs(np.diff(u)) > 0.05 * np.ptp(u)))
    if bias and n_switch < 2:
        raise IdentificationError("fitting a force bias needs at least two switches of the force (a relay test); "
                                  f"found {n_switch}")

    def inner(a: float) -> tuple[np.ndarray, np.ndarray]:
        A = _design(a, h, u, bias)
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        return c, y - A @ c

    lo, hi = pole_bounds
    grid = np.concatenate([[0.0], np.geomspace(lo, hi, 61)])  # a = 0: no linear damping at all
    rss = np.array([float(r @ r) for r in (inner(a)[1] for a in grid)])
    i = int(np.argmin(rss))
    if i == grid.size - 1:
        raise IdentificationError(
            f"the fitted pole a sits on its upper search bound {hi:g} 1/s (time constant below {1 / hi:g} s): "
            "the data cannot separate added mass from damping (sample faster or move longer between switches)")
    a_lo, a_hi = grid[max(i - 1, 0)], grid[i + 1]
    best = minimize_scalar(lambda a: float(np.sum(inner(a)[1] ** 2)), bounds=(a_lo, a_hi), method="bounded",
                           options={"xatol": 1e-12 + 1e-9 * a_hi})
    a = float(best.x)
    c, _ = inner(a)
    if c[2] <= 0:
        raise IdentificationError(
            f"the fitted gain k = {c[2]:.3g} is not positive: the position does not follow the force "
            "(check the sign convention: force_n acts along the positive position axis)")

    # joint refinement in (k, a, x0, v0[, b]) for the covariance
    theta0 = np.array([c[2], a, c[0], c[1]] + ([c[3] / c[2]] if bias else []))

    def model(th: np.ndarray) -> np.ndarray:
        g, xu, xb, _ = responses(th[1], h, u)
        out = th[2] + th[3] * g + th[0] * xu
        if bias:
            out = out + th[0] * th[4] * xb
        return out

    # a >= 0: a passive body has no negative damping (SNAME: linear_damping = -a/k <= 0); an
    # undamped DOF (e.g. bluerov2_heavy's N_r = 0) would otherwise come out slightly "negative"
    lower = np.full(theta0.size, -np.inf)
    lower[1] = 0.0
    sol = least_squares(lambda th: model(th) - y, theta0, x_scale="jac", method="trf", bounds=(lower, np.inf),
                        xtol=1e-12, ftol=1e-12)
    th = sol.x
    res = y - model(th)
    cov = covariance_from_jacobian(sol.jac, -res)
    k, a = float(th[0]), float(th[1])
    names = ["gain", "pole", "x0", "v0"] + (["bias"] if bias else [])
    se = {n: float(np.sqrt(abs(cov[i, i]))) for i, n in enumerate(names)}
    # delta method for the derived quantities
    g_added = np.zeros(th.size)
    g_added[0] = 1.0 / k**2  # d(m - 1/k)/dk
    g_damp = np.zeros(th.size)
    g_damp[0], g_damp[1] = a / k**2, -1.0 / k  # d(-a/k)
    se["added_mass"] = float(np.sqrt(abs(g_added @ cov @ g_added)))
    se["linear_damping"] = float(np.sqrt(abs(g_damp @ cov @ g_damp)))
    if not bias:
        se["bias"] = 0.0
    vu = responses(a, h, u)[3]
    tk = h * np.arange(u.size)
    vel_fit = th[3] * np.exp(-a * tk) + k * vu
    if bias:
        ramp = tk if a * h < 1e-12 else -np.expm1(-a * tk) / a  # (1 - e^{-a t})/a, t when a = 0
        vel_fit = vel_fit + k * th[4] * ramp  # response to the constant bias
    denom = float(np.linalg.norm(y - y.mean()))
    return StepFit(
        gain=k, pole=a, x0=float(th[2]), v0=float(th[3]), bias=float(th[4]) if bias else 0.0, mass=float(mass),
        added_mass=float(mass - 1.0 / k), linear_damping=float(-a / k), stderr=se, time_s=t, force=u,
        position=y, position_fit=y - res, velocity_smoothed=savgol_velocity(t, y), velocity_fit=vel_fit,
        residual=res, rms=float(np.sqrt(np.mean(res**2))),
        fit_percent=float(100 * (1 - np.linalg.norm(res) / denom)) if denom > 0 else float("nan"),
        bias_fitted=bias)


# --------------------------------------------------------------------------------------------
# Fit with known nonlinear damping
# --------------------------------------------------------------------------------------------

_SUBSTEPS = 4  # RK4 sub-steps per sample (the time constants are seconds, samples 0.1 s)


def simulate_nonlinear(k: float, a: float, x0: float, v0: float, b: float, quadratic: float, cubic: float,
                       h: float, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity at the samples of v_dot = k (u + b + Q |v| v + C v^3) - a v,
    x_dot = v, with u_k held over [t_k, t_k+1) (classical fourth-order Runge-Kutta)."""
    n = u.size
    xs = np.empty(n)
    vs = np.empty(n)
    x, v = float(x0), float(v0)
    dt = h / _SUBSTEPS
    kq, kc = k * quadratic, k * cubic

    def acc(vel: float, f: float) -> float:
        return f - a * vel + (kq * abs(vel) + kc * vel * vel) * vel

    for i in range(n):
        xs[i] = x
        vs[i] = v
        f = k * (float(u[i]) + b)
        for _ in range(_SUBSTEPS):
            a1 = acc(v, f)
            v2 = v + 0.5 * dt * a1
            a2 = acc(v2, f)
            v3 = v + 0.5 * dt * a2
            a3 = acc(v3, f)
            v4 = v + dt * a3
            a4 = acc(v4, f)
            x += dt / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
            v += dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            if not math.isfinite(v):
                xs[i + 1:] = np.nan
                vs[i + 1:] = np.nan
                return xs, vs
    return xs, vs


def _fit_nonlinear(lin: StepFit, quad: float, cub: float) -> StepFit:
    """Refit (k, a, x0, v0[, b]) with the nonlinear damping held fixed, from the linear fit."""
    from scipy.optimize import least_squares

    t, u, y = lin.time_s, lin.force, lin.position
    h = float(np.median(np.diff(t)))
    bias = lin.bias_fitted
    # start: the linear fit's pole holds the equivalent linearisation of the known terms at the
    # test's speeds; remove it (never below 0) so the search starts near the answer
    speed = float(np.sqrt(np.mean(lin.velocity_fit ** 2)))
    a0 = max(lin.pole + lin.gain * (quad * speed + cub * speed ** 2), 0.0)
    theta0 = np.array([lin.gain, a0, lin.x0, lin.v0] + ([lin.bias] if bias else []))

    def model(th: np.ndarray) -> np.ndarray:
        return simulate_nonlinear(th[0], th[1], th[2], th[3], th[4] if bias else 0.0, quad, cub, h, u)[0]

    def residual(th: np.ndarray) -> np.ndarray:
        r = model(th) - y
        return np.where(np.isfinite(r), r, 1e6)

    lower = np.full(theta0.size, -np.inf)
    lower[0] = 1e-12  # k > 0
    lower[1] = 0.0  # a >= 0: no negative linear damping
    sol = least_squares(residual, theta0, x_scale="jac", method="trf", bounds=(lower, np.inf), xtol=1e-12,
                        ftol=1e-12)
    th = sol.x
    res = y - model(th)
    if not np.all(np.isfinite(res)):
        raise IdentificationError("the fit with the fixed nonlinear damping diverged (check the damping values)")
    cov = covariance_from_jacobian(sol.jac, -res)
    k, a = float(th[0]), float(th[1])
    names = ["gain", "pole", "x0", "v0"] + (["bias"] if bias else [])
    se = {n: float(np.sqrt(abs(cov[i, i]))) for i, n in enumerate(names)}
    g_added = np.zeros(th.size)
    g_added[0] = 1.0 / k**2
    g_damp = np.zeros(th.size)
    g_damp[0], g_damp[1] = a / k**2, -1.0 / k
    se["added_mass"] = float(np.sqrt(abs(g_added @ cov @ g_added)))
    se["linear_damping"] = float(np.sqrt(abs(g_damp @ cov @ g_damp)))
    if not bias:
        se["bias"] = 0.0
    vel_fit = simulate_nonlinear(k, a, th[2], th[3], th[4] if bias else 0.0, quad, cub, h, u)[1]
    denom = float(np.linalg.norm(y - y.mean()))
    return StepFit(
        gain=k, pole=a, x0=float(th[2]), v0=float(th[3]), bias=float(th[4]) if bias else 0.0, mass=lin.mass,
        added_mass=float(lin.mass - 1.0 / k), linear_damping=float(-a / k), stderr=se, time_s=t, force=u,
        position=y, position_fit=y - res, velocity_smoothed=lin.velocity_smoothed, velocity_fit=vel_fit,
        residual=res, rms=float(np.sqrt(np.mean(res**2))),
        fit_percent=float(100 * (1 - np.linalg.norm(res) / denom)) if denom > 0 else float("nan"),
        bias_fitted=bias, fixed_damping=(quad, cub))


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------

def read_step(path: str | Path) -> tuple[DataTable, np.ndarray, np.ndarray, np.ndarray]:
    """(table, time, force, position) from ``time_s, force_n, position_m`` or the yaw columns
    ``time_s, moment_nm, heading_rad`` (heading unwrapped)."""
    table = read_table(path, what="step-response log")
    if all(table.has(c) for c in YAW_COLUMNS) and not table.has("position_m"):
        require_increasing(table, "time_s")
        return table, table["time_s"], table["moment_nm"], np.unwrap(table["heading_rad"])
    table.require(*COLUMNS)
    require_increasing(table, "time_s")
    return table, table["time_s"], table["force_n"], table["position_m"]


def step_edits(fit: StepFit, dof: str, *, digits: int = 4) -> dict[str, float]:
    """Vehicle-file edits: the added mass of the DOF and its linear damping."""
    if dof not in DOF_KEYS:
        raise IdentificationError(f"DOF must be one of {', '.join(DOF_KEYS)}, got {dof!r}")
    key, block = DOF_KEYS[dof]
    return {f"added_mass.{key}": significant(fit.added_mass, digits),
            f"damping.{block}.linear": significant(fit.linear_damping, digits)}
