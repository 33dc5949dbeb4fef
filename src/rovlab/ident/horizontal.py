"""Surge and sway from a dive whose log carries position or velocity (issue 29; the heave / yaw
part, the refusals and the covariances are rovlab.ident.dive's, reused here).

The model is rovlab.models.kinetics's horizontal rows with roll = pitch = 0, r_g = 0 and no
current (SNAME signs; M_u = m - X_udot, M_v = m - Y_vdot):

    M_u u_dot = s_X tau_X + M_v v r + (X_u + X_|u|u |u| + X_uuu u^2) u
    M_v v_dot = s_Y tau_Y - M_u u r + (Y_v + Y_|v|v |v| + Y_vvv v^2) v
    x_dot = cos(psi) u - sin(psi) v,   y_dot = sin(psi) u + cos(psi) v

The two rows are coupled only through the yaw rate r (Coriolis and the added mass's Munk-free
part of C_A, Fossen 2011 sec. 6.3-6.4), and the body velocities reach the NED position through
the heading. Neither is estimated here: the heading and yaw rate the AHRS logged are taken as
known inputs (interpolated on the model's grid), so the rotation is modelled but costs no
parameters. rovlab lab plan-dive excites surge and sway in segments where the yaw excitation is
off and a weak heading law holds the heading (rovlab.ident.plan), so r stays small there and the
surge and sway parameters do not trade against the Coriolis terms; the model still carries them
for the yaw segments and whatever the heading law lets through.

Outputs: a DVL's bottom-track body velocity u, v (a ``dvl`` sensor's ``u_<name>``, ``v_<name>``
columns) and / or a positioning system's NED x, y (``motion_capture`` sensor: USBL, motion
capture, or ArduSub's LOCAL_POSITION_NED in a MAVLink log). Each 15 s window starts from its own
fitted u0, v0 (and x0, y0 with a position output): multiple shooting, as for heave and yaw. The
windows are simulated together (numpy over windows and over the Jacobian's perturbations), RK4
on the 0.05 s grid with the thrust held over a step and the heading and yaw rate at each stage's
time.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rovlab.ident import dive as _d
from rovlab.ident.fitting import IdentificationError

HORIZONTAL = ("surge", "sway")
OUTPUT_DOFS = ("surge", "sway", "north", "east")  # Channel.dof of u, v (DVL) and x, y (position)
_STATE = {("surge", "velocity"): 2, ("sway", "velocity"): 3, ("north", "position"): 0, ("east", "position"): 1}
SPEED_FLOOR = 0.03  # m/s: below this largest speed a DOF is not excited
# m/s: below this RMS speed neither. A pilot's dive moves sway at 0.3-1.5 cm/s RMS, mostly the
# Coriolis drift of turns made while moving forward (-M_u u r): on 19 such dives with a DVL, Y_vdot
# came out up to 23 % off and within +-2 sigma in 58 % only; a plan's sway runs at ~6 cm/s RMS
SPEED_RMS_FLOOR = 0.02
HOPELESS = 1.0 / _d.MAX_REL  # a parameter whose sigma exceeds this many refusal thresholds is refused at once


def has_horizontal(data: _d.DiveData) -> bool:
    """Whether the log carries position or velocity (surge/sway can be identified)."""
    return any(c.dof in OUTPUT_DOFS and c.t.size for c in data.channels)


def no_horizontal_reason(data: _d.DiveData, vehicle: Any) -> str:
    sens = _d.sensor_channels(vehicle)
    have = [sens[k][0] for k in ("x", "y", "u", "v") if k in sens]
    cols = (f"its columns {', '.join(have)} are missing or empty" if have else
            f"the vehicle file {vehicle.name} declares no position sensor (a [[sensors]] of kind motion_capture with "
            "x, y: USBL, motion capture, or ArduSub's LOCAL_POSITION_NED) and no DVL (kind dvl with u, v)")
    return (f"{data.file}: surge and sway need position or velocity in the log (a DVL's u, v or a position's x, y); "
            f"{cols}")


class HorizontalProblem:
    """Output error of surge and sway together on [t0, t1]: global parameters (dof, key) and per
    window the initial (u0, v0), with (x0, y0) first when the log has a position output."""

    def __init__(self, data: _d.DiveData, base: Mapping[str, _d.DofModel], free: Sequence[tuple[str, str]],
                 t0: float, t1: float, *, grid_s: float = _d.GRID_S, window_s: float = _d.WINDOW_S) -> None:
        self.base = dict(base)
        self.keys = list(free)
        self.free = [f"{d}.{k}" for d, k in self.keys]  # len(free) = number of global parameters
        self.h = grid_s
        h = grid_s
        n = int(math.floor((t1 - t0) / h + 1e-9))
        if n < 4:
            raise IdentificationError(f"{data.file}: the surge/sway segment {t0:g}-{t1:g} s is too short")
        tg = t0 + h * np.arange(n + 1)
        self.channels = [c for c in data.channels if c.dof in OUTPUT_DOFS and c.t.size]
        if not self.channels:
            raise IdentificationError(no_horizontal_reason(data, _VehicleName(data.file)))
        self.sigma = np.array([c.sigma for c in self.channels], dtype=float)
        self.has_pos = any(c.kind == "position" for c in self.channels)
        self.nuisance = 4 if self.has_pos else 2
        head = data.channel("yaw", "position")
        rate = data.channel("yaw", "velocity")
        if head is None or head.t.size < 2:
            raise IdentificationError(f"{data.file}: surge and sway need the heading (an AHRS's psi) to turn the body "
                                      "forces and velocities; the log has no heading samples")
        th = np.arange(2 * n + 1) * 0.5 * h + t0  # nodes and midpoints
        psi = np.interp(th, head.t, head.y)
        if rate is not None and rate.t.size >= 2:
            r = np.interp(th, rate.t, rate.y)
        else:
            r = np.gradient(psi, th) if th.size > 1 else np.zeros_like(th)
        X = _d._held(data, tg[:-1], 0)
        Y = _d._held(data, tg[:-1], 1)
        nw = max(1, int(round((t1 - t0) / window_s)))
        edges = np.linspace(0, n, nw + 1).round().astype(int)
        L = int(np.max(np.diff(edges)))
        W = len(edges) - 1
        self.L, self.W = L, W
        self.X = np.zeros((W, L))
        self.Y = np.zeros((W, L))
        self.cos = np.zeros((W, 2 * L + 1))
        self.sin = np.zeros((W, 2 * L + 1))
        self.r = np.zeros((W, 2 * L + 1))
        self.windows: list[_d._Window] = []
        self.count = 0
        keep: list[int] = []
        sw, sj, sa, ss, sy, sc = [], [], [], [], [], []
        for wi, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            m = b - a
            self.X[wi, :m], self.Y[wi, :m] = X[a:b], Y[a:b]
            seg = slice(2 * a, 2 * b + 1)
            p = psi[seg]
            self.cos[wi, :2 * m + 1], self.sin[wi, :2 * m + 1] = np.cos(p), np.sin(p)
            self.r[wi, :2 * m + 1] = r[seg]
            samples = []
            for ci, c in enumerate(self.channels):
                lo, hi = tg[a], tg[b]
                msk = (c.t >= lo) & (c.t < hi) if b < n else (c.t >= lo) & (c.t <= hi)
                if not msk.any():
                    continue
                x = (c.t[msk] - lo) / h
                j = np.minimum(np.floor(x).astype(int), m - 1)
                k = int(msk.sum())
                idx = np.arange(self.count, self.count + k)
                samples.append((ci, j, x - j, c.y[msk], idx))
                sw.append(np.full(k, len(self.windows)))
                sj.append(j)
                sa.append(x - j)
                ss.append(np.full(k, _STATE[(c.dof, c.kind)]))
                sy.append(c.y[msk])
                sc.append(np.full(k, ci))
                self.count += k
            if samples:
                self.windows.append(_d._Window(int(a), int(m), samples))
                keep.append(wi)
        if not self.windows:
            raise IdentificationError(f"{data.file}: no position or velocity samples between {t0:g} and {t1:g} s")
        self.X, self.Y, self.cos, self.sin, self.r = (a[keep] for a in (self.X, self.Y, self.cos, self.sin, self.r))
        self.W = len(self.windows)
        self.s_w = np.concatenate(sw)
        self.s_j = np.concatenate(sj)
        self.s_a = np.concatenate(sa)
        self.s_state = np.concatenate(ss)
        self.y = np.concatenate(sy)
        self.channel_of = np.concatenate(sc)

    # ---- parameters ----------------------------------------------------------------------
    def models(self, theta: np.ndarray) -> dict[str, _d.DofModel]:
        g = len(self.keys)
        vals: dict[str, dict[str, float]] = {d: {} for d in HORIZONTAL}
        for (d, k), x in zip(self.keys, theta[:g]):
            vals[d][k] = float(x)
        return {d: self.base[d].with_values(vals[d]) for d in HORIZONTAL}

    def _coeffs(self, theta_rows: np.ndarray) -> np.ndarray:
        """(P, 10): M_u, M_v, s_X, s_Y, X_u, X_|u|u, X_uuu, Y_v, Y_|v|v, Y_vvv per parameter row."""
        out = np.empty((theta_rows.shape[0], 10))
        for i, th in enumerate(theta_rows):
            m = self.models(th)
            s, w = m["surge"], m["sway"]
            out[i] = (s.rigid - s.added_mass, w.rigid - w.added_mass, s.thrust_scale, w.thrust_scale,
                      s.linear, s.quadratic, s.cubic, w.linear, w.quadratic, w.cubic)
        return out

    def initial(self) -> np.ndarray:
        """The base's globals and each window's start from its first samples."""
        th = [getattr(self.base[d], k) for d, k in self.keys]
        for wi, w in enumerate(self.windows):
            st = np.zeros(4)
            got = np.zeros(4, dtype=bool)
            for ci, _j, _a, y, _ in w.samples:
                c = self.channels[ci]
                s = _STATE[(c.dof, c.kind)]
                if c.kind == "velocity":
                    st[s], got[s] = float(np.mean(y[:3])), True
                else:
                    st[s], got[s] = float(y[0]), True
            if not (got[2] and got[3]):  # velocity from the first positions, turned into the body frame
                pos = {self.channels[ci].dof: (j, a, y) for ci, j, a, y, _ in w.samples
                       if self.channels[ci].kind == "position"}
                if "north" in pos and "east" in pos and pos["north"][2].size >= 3 and pos["east"][2].size >= 3:
                    vel = []
                    for key in ("north", "east"):
                        j, a, y = pos[key]
                        k = min(y.size, 5)
                        tt = (j[:k] + a[:k]) * self.h
                        fit = np.polyfit(tt, y[:k], 1)
                        vel.append(float(fit[0]))
                        st[_STATE[(key, "position")]] = float(np.polyval(fit, 0.0))
                    c, s = self.cos[wi, 0], self.sin[wi, 0]
                    st[2], st[3] = c * vel[0] + s * vel[1], -s * vel[0] + c * vel[1]
            th += list(st[:4] if self.has_pos else st[2:])
        return np.array(th, dtype=float)

    # ---- simulation ------------------------------------------------------------------------
    def simulate(self, theta_rows: np.ndarray, init: np.ndarray) -> np.ndarray:
        """States (P, W, L + 1, 4) [x, y, u, v] from init (P, W, 4) for each parameter row."""
        c = self._coeffs(theta_rows)
        P = c.shape[0]
        Mu, Mv, sx, sy = (c[:, i:i + 1] for i in range(4))
        xu, xuu, xuuu, yv, yvv, yvvv = (c[:, i:i + 1] for i in range(4, 10))
        iMu, iMv = 1.0 / Mu, 1.0 / Mv
        h = self.h
        out = np.empty((P, self.W, self.L + 1, 4))
        x, y, u, v = (init[:, :, i].copy() for i in range(4))
        out[:, :, 0] = init

        def f(u: np.ndarray, v: np.ndarray, k2: int, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, ...]:
            co, si, r = self.cos[:, k2], self.sin[:, k2], self.r[:, k2]
            du = (sx * X + Mv * v * r + (xu + xuu * np.abs(u) + xuuu * u * u) * u) * iMu
            dv = (sy * Y - Mu * u * r + (yv + yvv * np.abs(v) + yvvv * v * v) * v) * iMv
            return co * u - si * v, si * u + co * v, du, dv

        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(self.L):
                X, Y = self.X[:, k], self.Y[:, k]
                a1 = f(u, v, 2 * k, X, Y)
                a2 = f(u + 0.5 * h * a1[2], v + 0.5 * h * a1[3], 2 * k + 1, X, Y)
                a3 = f(u + 0.5 * h * a2[2], v + 0.5 * h * a2[3], 2 * k + 1, X, Y)
                a4 = f(u + h * a3[2], v + h * a3[3], 2 * k + 2, X, Y)
                x = x + h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
                y = y + h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
                u = u + h / 6 * (a1[2] + 2 * a2[2] + 2 * a3[2] + a4[2])
                v = v + h / 6 * (a1[3] + 2 * a2[3] + 2 * a3[3] + a4[3])
                out[:, :, k + 1, 0], out[:, :, k + 1, 1], out[:, :, k + 1, 2], out[:, :, k + 1, 3] = x, y, u, v
        return out

    def _init(self, theta: np.ndarray) -> np.ndarray:
        g = len(self.keys)
        nu = theta[g:].reshape(self.W, self.nuisance)
        init = np.zeros((self.W, 4))
        if self.has_pos:
            init[:] = nu
        else:
            init[:, 2:] = nu
        return init

    def _outputs(self, states: np.ndarray) -> np.ndarray:
        """(P, count) model outputs at the samples from states (P, W, L + 1, 4)."""
        a = states[:, self.s_w, self.s_j, self.s_state]
        b = states[:, self.s_w, self.s_j + 1, self.s_state]
        return (1.0 - self.s_a) * a + self.s_a * b

    def predictions(self, theta: np.ndarray) -> np.ndarray:
        st = self.simulate(theta[None, :], self._init(theta)[None])
        return self._outputs(st)[0]

    def residuals(self, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
        out = (self.y - self.predictions(theta)) / weights[self.channel_of]
        return np.nan_to_num(out, nan=1e6, posinf=1e6, neginf=-1e6)

    def jacobian(self, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Forward differences for the globals and u0, v0 (every window's at once: the windows are
        independent), exact -1 for x0, y0 on the position outputs; all perturbations in one run."""
        g = len(self.keys)
        rows = [theta]
        steps = []
        for i, (d, k) in enumerate(self.keys):
            step = 1e-6 * max(abs(theta[i]), _d._SCALE[k](self.base[d]))
            th = theta.copy()
            th[i] += step
            rows.append(th)
            steps.append(step)
        init0 = self._init(theta)
        inits = [init0] * (g + 1)
        dv = 1e-6 * np.maximum(np.abs(init0[:, 2:]), 0.1)
        for s in (2, 3):
            moved = init0.copy()
            moved[:, s] += dv[:, s - 2]
            inits.append(moved)
            rows.append(theta)
        out = self._outputs(self.simulate(np.array(rows), np.array(inits)))
        wt = weights[self.channel_of]
        J = np.zeros((self.count, theta.size))
        for i in range(g):
            J[:, i] = -(out[i + 1] - out[0]) / steps[i] / wt
        off = 2 if self.has_pos else 0  # u0, v0 after x0, y0 in a window's block
        for n, s in enumerate((2, 3)):
            d = -(out[g + 1 + n] - out[0]) / dv[self.s_w, s - 2] / wt
            J[np.arange(self.count), g + self.nuisance * self.s_w + off + n] = d
        if self.has_pos:
            for s in (0, 1):
                m = self.s_state == s
                J[np.flatnonzero(m), g + self.nuisance * self.s_w[m] + s] = -1.0 / wt[m]
        return np.nan_to_num(J)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for d, k in self.keys:
            rigid = self.base[d].rigid
            lo.append({"added_mass": -50.0 * rigid, "linear": -np.inf, "quadratic": -np.inf,
                       "thrust_scale": 0.05}[k])
            hi.append({"added_mass": 0.0, "linear": 0.0, "quadratic": 0.0, "thrust_scale": 20.0}[k])
        n = self.nuisance * self.W
        return np.array(lo + [-np.inf] * n), np.array(hi + [np.inf] * n)


class _VehicleName:
    def __init__(self, file: str) -> None:
        self.name = f"the vehicle of {file}"


def body_speeds(data: _d.DiveData, t0: float, t1: float) -> dict[str, np.ndarray]:
    """Surge and sway speeds on [t0, t1]: the DVL's, else the position's smoothed derivative
    turned into the body frame by the logged heading."""
    out: dict[str, np.ndarray] = {}
    for dof in HORIZONTAL:
        c = data.channel(dof, "velocity")
        if c is not None:
            m = (c.t >= t0) & (c.t <= t1)
            out[dof] = c.y[m]
    if len(out) == 2:
        return out
    xn, ye, head = data.channel("north", "position"), data.channel("east", "position"), data.channel("yaw", "position")
    if xn is None or ye is None or head is None:
        return {d: out.get(d, np.zeros(0)) for d in HORIZONTAL}
    m = (xn.t >= t0) & (xn.t <= t1)
    if m.sum() < 8:
        return {d: out.get(d, np.zeros(0)) for d in HORIZONTAL}
    from scipy.interpolate import make_smoothing_spline

    t = xn.t[m]
    vn = make_smoothing_spline(t, xn.y[m]).derivative()(t)
    me = (ye.t >= t0) & (ye.t <= t1)
    ve = make_smoothing_spline(ye.t[me], ye.y[me]).derivative()(t)
    psi = np.interp(t, head.t, head.y)
    c, s = np.cos(psi), np.sin(psi)
    out.setdefault("surge", c * vn + s * ve)
    out.setdefault("sway", -s * vn + c * ve)
    return out


def fit_horizontal(data: _d.DiveData, start: Mapping[str, _d.DofModel], dofs: Sequence[str], t0: float, t1: float, *,
                   free: Mapping[str, Sequence[str]], max_rel: float = _d.MAX_REL) -> dict[str, _d.DofFit]:
    """Output-error fit of surge and sway on [t0, t1] (module docstring), with rovlab.ident.dive's
    refusals: a DOF the log does not move is refused whole; a parameter whose sigma is large
    against what it does is held at the file's value and named with the manoeuvre that would
    determine it."""
    from scipy.optimize import least_squares

    speeds = body_speeds(data, t0, t1)
    stats = {d: (float(np.sqrt(np.mean(speeds[d] ** 2))) if speeds[d].size else 0.0,
                 float(np.max(np.abs(speeds[d]))) if speeds[d].size else 0.0) for d in HORIZONTAL}
    out: dict[str, _d.DofFit] = {}
    keys: list[tuple[str, str]] = []
    weak: dict[str, str] = {}
    for dof in dofs:
        chosen = [k for k in _d.KEYS if k in free.get(dof, _d.DEFAULT_FREE) and k != "net_buoyancy"]
        if "added_mass" in chosen and "thrust_scale" in chosen:
            raise IdentificationError(f"{_d.NAMES[dof]['added_mass']} and {_d.NAMES[dof]['thrust_scale']} cannot both "
                                      "be estimated: the motion responds to force / mass only, so no manoeuvre tells "
                                      "a larger added mass from weaker thrust; hold one (measure the thrust with "
                                      "rovlab identify thrust, or keep the file's added mass)")
        s_rms, s_max = stats[dof]
        why = (f"the log does not excite {dof}: its {dof} speed is {s_rms:.3g} m/s RMS, at most {s_max:.3g} m/s "
               f"(need > {SPEED_RMS_FLOOR:g} RMS and {SPEED_FLOOR:g} at most); fly rovlab lab plan-dive --dofs {dof}")
        if s_max < SPEED_FLOOR:
            out[dof] = _d._refused_dof(dof, start[dof], why, s_rms, s_max)
            continue
        if s_rms < SPEED_RMS_FLOOR:  # fitted with the other DOF (it moves, and couples), not reported
            weak[dof] = why + " (its parameters were fitted alongside the other DOF's, not reported)"
        keys += [(dof, k) for k in chosen]
    if not keys:
        return out
    held: dict[tuple[str, str], str] = {}
    while True:
        cur = [k for k in keys if k not in held]
        if not cur:
            for dof in {d for d, _ in keys}:
                why = "no parameter is determined by this log: " + "; ".join(
                    f"{_d.NAMES[d][k]}: {v}" for (d, k), v in held.items() if d == dof)
                out[dof] = _d._refused_dof(dof, start[dof], why, *stats[dof],
                                           refused={k: v for (d, k), v in held.items() if d == dof})
            return out
        prob = HorizontalProblem(data, start, cur, t0, t1)
        weights = prob.sigma.copy()
        th0 = prob.initial()
        lo, hi = prob.bounds()
        th0 = _d._inside(th0, lo, hi, [_d._SCALE[k](start[d]) for d, k in cur])
        cost_start = 0.5 * float(np.sum(prob.residuals(th0, weights) ** 2))
        for _ in range(2):  # ML with unknown noise levels: fit, re-weight by the residuals, fit again
            sol = least_squares(lambda th, w=weights: prob.residuals(th, w), th0,
                                jac=lambda th, w=weights: prob.jacobian(th, w), bounds=(lo, hi), x_scale="jac",
                                method="trf", max_nfev=60)
            th0 = sol.x
            raw = prob.residuals(th0, np.ones(len(prob.channels)))
            weights = np.array([max(float(np.sqrt(np.mean(raw[prob.channel_of == ci] ** 2))), 1e-9)
                                if np.any(prob.channel_of == ci) else prob.sigma[ci]
                                for ci in range(len(prob.channels))])
        theta = th0
        r = prob.residuals(theta, weights)
        J = prob.jacobian(theta, weights)
        covs = _d._covariances(prob, J, r)  # type: ignore[arg-type]
        var = np.max([np.diag(c) for c in covs], axis=0)
        sig = np.sqrt(var)
        cov_hac = max(covs, key=lambda c: float(np.trace(c / np.maximum(var, 1e-300))))
        models = prob.models(theta)
        # refuse the worst-determined parameter and fit again without it; those hopeless (sigma
        # above HOPELESS times the threshold: more than what they do) go at once, which saves the
        # refits of a log that determines nothing (the real surface log: 40 s -> a few)
        ratios = [_d._determination(k, models[d], sig[i], stats[d][0], max_rel) for i, (d, k) in enumerate(cur)]
        worst_i = int(np.argmax(ratios))
        if not ratios[worst_i] > 1.0:
            break
        for i, ratio in enumerate(ratios):
            if i == worst_i or ratio > HOPELESS:
                d, k = cur[i]
                held[(d, k)] = (f"not determined by this log (sigma {sig[i]:.3g}, {ratio * max_rel * 100:.0f} % of what "
                                f"it does); held at the file's value; to determine it: {_d._manoeuvre(d, k, stats[d][0])}")
    raw = prob.residuals(theta, np.ones(len(prob.channels)))
    for dof in sorted({d for d, _ in keys}, key=HORIZONTAL.index):
        if dof in weak:  # refused, but its fitted model kept (the yaw fit's Munk moment uses its added mass)
            from dataclasses import replace

            ref = _d._refused_dof(dof, start[dof], weak[dof], *stats[dof])
            prs = tuple(replace(p, sigma=float(sig[cur.index((dof, p.key))])) if (dof, p.key) in cur else p
                        for p in ref.params)
            out[dof] = replace(ref, params=prs, model=models[dof])
            continue
        idx = [i for i, (d, _) in enumerate(cur) if d == dof]
        est = tuple(cur[i][1] for i in idx)
        dd = np.sqrt(np.maximum(np.diag(cov_hac)[idx], 1e-300))
        corr = cov_hac[np.ix_(idx, idx)] / np.outer(dd, dd) if idx else np.zeros((0, 0))
        params = []
        st = start[dof]
        for k in st.values():
            name, unit = _d.NAMES[dof][k], _d.UNITS[dof][k]
            if (dof, k) in cur:
                i = cur.index((dof, k))
                params.append(_d.ParamResult(k, name, unit, float(getattr(st, k)), float(theta[i]), float(sig[i]),
                                             "estimated", _d._at_bound(k, theta[i], lo[i], hi[i])))
            elif (dof, k) in held:
                params.append(_d.ParamResult(k, name, unit, float(getattr(st, k)), float(getattr(st, k)), math.nan,
                                             "refused", held[(dof, k)]))
            else:
                params.append(_d.ParamResult(k, name, unit, float(getattr(st, k)), float(getattr(st, k)), math.nan,
                                             "held", "held at the file's value (not asked for)"))
        mine = [ci for ci, c in enumerate(prob.channels) if c.dof == dof or c.kind == "position"]
        rms = {prob.channels[ci].name: float(np.sqrt(np.mean(raw[prob.channel_of == ci] ** 2)))
               for ci in mine if np.any(prob.channel_of == ci)}
        counts = {prob.channels[ci].name: int(np.sum(prob.channel_of == ci)) for ci in mine}
        if not est:
            why = "no parameter is determined by this log: " + "; ".join(
                f"{_d.NAMES[d][k]}: {v}" for (d, k), v in held.items() if d == dof)
            out[dof] = _d._refused_dof(dof, st, why, *stats[dof], refused={k: v for (d, k), v in held.items() if d == dof})
            continue
        out[dof] = _d.DofFit(dof, tuple(params), corr, est, models[dof], rms, counts, *stats[dof],
                             windows=len(prob.windows), cost_start=cost_start, cost=0.5 * float(r @ r))
    return {d: out[d] for d in dofs if d in out}


def prediction_errors(data: _d.DiveData, identified: Mapping[str, _d.DofModel], start: Mapping[str, _d.DofModel],
                      t0: float, t1: float, *, step_s: float = _d.PREDICTION_STEP_S,
                      horizons: Sequence[int] = _d.HORIZONS, every_s: float = 1.0) -> dict[str, dict[str, list[float]]]:
    """k-step prediction RMSE on [t0, t1] of the DVL's surge and sway velocity (``u_mps``,
    ``v_mps``) or, without a DVL, of the horizontal position (``position_m``: the distance between
    predicted and measured x, y), for the identified model and the vehicle file's, from the same
    initial states: the latest DVL sample, the latest position sample (moved on by the latest
    velocity), or without a DVL the velocity of a line through the last 2 s of positions."""
    u, v = data.channel("surge", "velocity"), data.channel("sway", "velocity")
    xn, ye = data.channel("north", "position"), data.channel("east", "position")
    head, rate = data.channel("yaw", "position"), data.channel("yaw", "velocity")
    if head is None:
        return {}
    use_vel = u is not None and v is not None
    ref = u if use_vel else xn
    if ref is None or (not use_vel and ye is None):
        return {}
    m = (ref.t >= t0) & (ref.t <= t1)
    if m.sum() < 10:
        return {}
    tm = ref.t[m]
    step = float(np.median(np.diff(tm)))
    stride = max(1, int(round(every_s / max(step, 1e-3))))
    labels = ("u_mps", "v_mps") if use_vel else ("position_m",)
    out: dict[str, dict[str, list[float]]] = {lab: {"identified": [], "file": [], "n": []} for lab in labels}
    models = (identified, start)
    for k in horizons:
        horizon = k * step_s
        targets = tm[(tm >= t0 + horizon + 2.0) & (tm <= tm[-1] - 1.0)][::stride]
        n = max(1, int(round(horizon / _d.GRID_S)))
        hh = horizon / n
        errs: dict[str, list[list[float]]] = {lab: [[], []] for lab in labels}
        for tt in targets:
            ts = tt - horizon
            if use_vel:
                assert u is not None and v is not None
                i = int(np.searchsorted(u.t, ts + 1e-9)) - 1
                j = int(np.searchsorted(v.t, ts + 1e-9)) - 1
                if i < 0 or j < 0:
                    continue
                st = [0.0, 0.0, float(u.y[i]), float(v.y[j])]
            else:
                assert xn is not None and ye is not None
                sel = (xn.t <= ts + 1e-9) & (xn.t >= ts - 2.0)
                sele = (ye.t <= ts + 1e-9) & (ye.t >= ts - 2.0)
                if sel.sum() < 3 or sele.sum() < 3:
                    continue
                fn = np.polyfit(xn.t[sel] - ts, xn.y[sel], 1)
                fe = np.polyfit(ye.t[sele] - ts, ye.y[sele], 1)
                psi0 = float(np.interp(ts, head.t, head.y))
                c, s = math.cos(psi0), math.sin(psi0)
                st = [float(fn[1]), float(fe[1]), c * fn[0] + s * fe[0], -s * fn[0] + c * fe[0]]
            tg = ts + hh * np.arange(n)
            th = ts + 0.5 * hh * np.arange(2 * n + 1)
            psi = np.interp(th, head.t, head.y)
            r = np.interp(th, rate.t, rate.y) if rate is not None else np.gradient(psi, th)
            X, Y = _d._held(data, tg, 0), _d._held(data, tg, 1)
            for mi, mdl in enumerate(models):
                xs = _simulate_one(mdl["surge"], mdl["sway"], X, Y, np.cos(psi), np.sin(psi), r, hh, st)
                if use_vel:
                    assert u is not None and v is not None
                    errs["u_mps"][mi].append(xs[2] - float(u.y[np.searchsorted(u.t, tt - 1e-9)]))
                    errs["v_mps"][mi].append(xs[3] - float(v.y[np.searchsorted(v.t, tt - 1e-9)]))
                else:
                    assert xn is not None and ye is not None
                    ex = xs[0] - float(xn.y[np.searchsorted(xn.t, tt - 1e-9)])
                    ey = xs[1] - float(np.interp(tt, ye.t, ye.y))
                    errs["position_m"][mi].append(math.hypot(ex, ey))
        for lab in labels:
            for mi, key in enumerate(("identified", "file")):
                e = np.asarray(errs[lab][mi])
                out[lab][key].append(float(np.sqrt(np.mean(e**2))) if e.size else math.nan)
            out[lab]["n"].append(len(errs[lab][0]))
    return out


def _simulate_one(su: _d.DofModel, sw: _d.DofModel, X: np.ndarray, Y: np.ndarray, co: np.ndarray, si: np.ndarray,
                  r: np.ndarray, h: float, st: Sequence[float]) -> list[float]:
    """One horizontal trajectory (plain Python; the model of HorizontalProblem.simulate)."""
    Mu, Mv = su.rigid - su.added_mass, sw.rigid - sw.added_mass
    x, y, u, v = (float(a) for a in st)

    def f(u: float, v: float, k2: int, Xk: float, Yk: float) -> tuple[float, float, float, float]:
        du = (su.thrust_scale * Xk + Mv * v * r[k2] + (su.linear + su.quadratic * abs(u) + su.cubic * u * u) * u) / Mu
        dv = (sw.thrust_scale * Yk - Mu * u * r[k2] + (sw.linear + sw.quadratic * abs(v) + sw.cubic * v * v) * v) / Mv
        return co[k2] * u - si[k2] * v, si[k2] * u + co[k2] * v, du, dv

    for k in range(len(X)):
        a1 = f(u, v, 2 * k, X[k], Y[k])
        a2 = f(u + 0.5 * h * a1[2], v + 0.5 * h * a1[3], 2 * k + 1, X[k], Y[k])
        a3 = f(u + 0.5 * h * a2[2], v + 0.5 * h * a2[3], 2 * k + 1, X[k], Y[k])
        a4 = f(u + h * a3[2], v + h * a3[3], 2 * k + 2, X[k], Y[k])
        x += h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
        y += h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
        u += h / 6 * (a1[2] + 2 * a2[2] + 2 * a3[2] + a4[2])
        v += h / 6 * (a1[3] + 2 * a2[3] + 2 * a3[3] + a4[3])
    return [x, y, u, v]


def default_dofs(data: _d.DiveData) -> tuple[str, ...]:
    """heave and yaw, and surge and sway when the log carries position or velocity."""
    return _d.DOFS + (HORIZONTAL if has_horizontal(data) else ())


def fit(data: _d.DiveData, vehicle: Any, dofs: Sequence[str], free: Mapping[str, Sequence[str]] | Sequence[str] | None,
        t0: float, t_split: float, *, max_rel: float = _d.MAX_REL) -> dict[str, _d.DofFit]:
    """rovlab.ident.dive.identify_dive's surge / sway fits; IdentificationError naming what is
    missing when the log has no position or velocity."""
    want = [d for d in dofs if d in HORIZONTAL]
    if not has_horizontal(data):
        raise IdentificationError(no_horizontal_reason(data, vehicle))
    chosen = {d: (free.get(d, _d.DEFAULT_FREE) if isinstance(free, Mapping) else (free or _d.DEFAULT_FREE))
              for d in want}
    start = {d: _d.dof_model(vehicle, d) for d in HORIZONTAL}
    return fit_horizontal(data, start, want, t0, t_split, free=chosen, max_rel=max_rel)


def merge(data: _d.DiveData, vehicle: Any, dofs: Sequence[str], hfits: Mapping[str, _d.DofFit],
          fits: Mapping[str, _d.DofFit], pred: Mapping[str, Any], t_split: float,
          t_end: float) -> tuple[dict[str, _d.DofFit], dict[str, Any]]:
    """The fits in the order of ``dofs``, and the prediction errors with surge and sway's added."""
    start = {d: _d.dof_model(vehicle, d) for d in HORIZONTAL}
    out = dict(pred)
    if any(not f.refused_dof for f in hfits.values()):
        ident = dict(start)
        for d, f in hfits.items():
            if not f.refused_dof:
                ident[d] = f.model
        mine = prediction_errors(data, ident, start, t_split, t_end)
        if any("published" in rows for rows in pred.values()):  # a published set scored for heave / yaw only
            for rows in mine.values():
                rows["published"] = [math.nan] * len(rows["n"])
        out.update(mine)
    merged = dict(fits) | dict(hfits)
    return {d: merged[d] for d in dofs if d in merged}, out


def body_velocity(data: _d.DiveData, t: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Surge and sway velocity at times ``t``: the DVL's (interpolated), else the position's
    smoothed derivative turned into the body frame by the logged heading; None without either."""
    u, v = data.channel("surge", "velocity"), data.channel("sway", "velocity")
    if u is not None and v is not None and u.t.size >= 2 and v.t.size >= 2:
        return np.interp(t, u.t, u.y), np.interp(t, v.t, v.y)
    xn, ye, head = data.channel("north", "position"), data.channel("east", "position"), data.channel("yaw", "position")
    if xn is None or ye is None or head is None or xn.t.size < 8 or ye.t.size < 8:
        return None
    from scipy.interpolate import make_smoothing_spline

    vn = make_smoothing_spline(xn.t, xn.y).derivative()(t)
    ve = make_smoothing_spline(ye.t, ye.y).derivative()(t)
    psi = np.interp(t, head.t, head.y)
    c, s = np.cos(psi), np.sin(psi)
    return c * vn + s * ve, -s * vn + c * ve


def with_munk_moment(data: _d.DiveData, vehicle: Any, hfits: Mapping[str, _d.DofFit], *,
                     shift: float = 0.0) -> _d.DiveData:
    """The dive with the Munk moment -(X_udot - Y_vdot) u v added to the yaw input tau_N (the yaw row
    of rovlab.models.kinetics's C_A(nu) nu; C_RB's cancels for r_g = 0): a known input where the log
    carries surge and sway velocity, with X_udot and Y_vdot as identified from the same log (also
    when only heave and yaw are asked for; the file's where the log does not determine them). A
    vehicle moving sideways while it surges is turned by it -- 0.06 N m at u = 0.4, v = 0.2 m/s on
    a BlueROV2 Heavy, four times the yaw damping at 0.1 rad/s -- and a yaw fit that leaves it out
    was measured 10-90 % off in N_r on surge / sway plans."""
    from dataclasses import replace

    vel = body_velocity(data, data.t_cmd)
    if vel is None:
        return data
    am = {}
    for dof in HORIZONTAL:  # a DOF fitted but too weakly moved to report still gives its fitted model
        f = hfits.get(dof)
        am[dof] = f.model.added_mass if f is not None else float(vehicle.added_mass[_d._DOF_INDEX[dof]])
    tau = np.array(data.tau, dtype=float, copy=True)
    tau[:, 3] -= (am["surge"] - am["sway"] + shift) * vel[0] * vel[1]
    note = (f"yaw input: with the Munk moment -(X_udot - Y_vdot) u v, X_udot - Y_vdot = {am['surge'] - am['sway']:.4g} "
            "kg, u and v from the log")
    return replace(data, tau=tau, notes=data.notes + (note,))


def with_munk_uncertainty(yaw: _d.DofFit, data: _d.DiveData, vehicle: Any, hfits: Mapping[str, _d.DofFit],
                          refit: Any) -> _d.DofFit:
    """The yaw fit with the uncertainty of the Munk moment's X_udot - Y_vdot carried into its
    sigmas: yaw refitted (``refit(data)``) with X_udot - Y_vdot one standard deviation larger
    (sqrt(sigma_Xudot^2 + sigma_Yvdot^2), the two fits' estimates taken as independent), and each
    estimated parameter's sigma^2 increased by the square of its change (first order). Without
    an estimated X_udot or Y_vdot (the file's used) nothing is added: their error is unknown."""
    from dataclasses import replace

    var = 0.0
    for dof in HORIZONTAL:
        f = hfits.get(dof)
        if f is not None and math.isfinite(f.param("added_mass").sigma):  # estimated, or fitted unreported
            var += f.param("added_mass").sigma ** 2
    if yaw.refused_dof or not var > 0:
        return yaw
    sk = math.sqrt(var)
    other = refit(with_munk_moment(data, vehicle, hfits, shift=sk))
    if other.refused_dof:
        return yaw
    params = []
    for p in yaw.params:
        q = other.param(p.key)
        if p.status == "estimated" and q.status == "estimated":
            d = q.estimate - p.estimate
            p = replace(p, sigma=math.hypot(p.sigma, d))
        params.append(p)
    return replace(yaw, params=tuple(params))
