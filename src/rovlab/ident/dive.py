"""Identification from a dive: heave and yaw from the vehicle's own log (issue 29).

A BlueROV2 owner has no towing carriage and no motion capture, only the vehicle and its log:
commanded PWM, the pressure sensor's depth (ArduSub's SCALED_PRESSURE2, ~2 Hz) and the AHRS
heading and yaw rate (ATTITUDE, ~20 Hz). This module turns such a log into the heave and yaw
parameters of the vehicle file, with standard deviations, correlations and a validation.

The model (rovlab.models.kinetics with roll = pitch = 0, fully submerged, and no surge or sway:
heave and yaw are then decoupled; SNAME signs):

    (m - Z_wdot) w_dot = s_Z tau_Z - (B - W) + Z_w w + Z_|w|w |w| w + Z_www w^3,   z_dot = w
    (I_zz - N_rdot) r_dot = s_N tau_N + N_r r + N_|r|r |r| r + N_rrr r^3,          psi_dot = r

tau_Z, tau_N: the wrench of the logged PWM through the vehicle file's thrust curves and
configuration matrix (held between commands); s_Z, s_N: thrust scales (1 = the curves are right);
the cubic terms are held at the file's values. Outputs: depth (pressure sensor), heading and yaw
rate (AHRS), at the times they were logged.

**What no dive can tell.** The equations are unchanged when M, s, B - W and the damping of a DOF
are all multiplied by one constant: the motion responds to force / mass only. So the added mass
and the thrust scale of a DOF cannot both be estimated from any manoeuvre; one must be known (a
bollard/load-cell test of the thrusters, ``rovlab identify thrust``, fixes s; a known added mass
fixes M). By default s = 1 (the vehicle file's thrust curves) and the added mass is estimated;
``free=`` may choose the thrust scale instead (then the added mass is held).

**Method.** Output error, i.e. maximum likelihood for white measurement noise (Ljung 1999,
sec. 7.4; Jategaonkar 2015, Flight Vehicle System Identification, ch. 4): the model is simulated
with the logged input (RK4 on a fixed grid) and its outputs are fitted to the measured ones by
``scipy.optimize.least_squares`` (trust-region reflective, bounds: M > 0 with added mass <= 0,
damping <= 0). To keep slow unmodelled forces (process noise, a tether) from accumulating in the
integrated depth over minutes, the identification segment is cut into windows (15 s) that each
start from their own fitted position and velocity (multiple shooting; Bock 1981). The start is a
constrained linear least-squares fit of the equation of motion (equation error) on velocities and
accelerations from a smoothing spline of the measurements (``scipy.optimize.lsq_linear`` with the
same bounds), or the vehicle file's guess where that fits the outputs better. Each channel's
weight is its residual variance (estimated: ML with unknown noise levels; the vehicle file's
variance is the first guess).

**Uncertainty.** Each window's initial state is profiled out, and the covariance of the global
parameters is the largest (per parameter) of three estimates from the weighted Jacobian J and the
residuals at the optimum: the white-noise s^2 (J^T J)^-1 (s^2 the residual variance), a Newey-West
sandwich (Bartlett weights, per channel; Newey & West 1987) for a smoothed AHRS heading whose
errors are correlated from sample to sample, and a window-clustered sandwich (Liang & Zeger 1986)
for correlation within a window across channels, such as the drift a random force leaves in the
integrated depth and heading.

**Refusals.** A parameter whose standard deviation is large against what it does (added mass:
30 % of it; a damping term: 30 % of the damping force at the log's RMS speed; a thrust scale: 0.1)
is not reported: it is held at the vehicle file's value, the fit repeated, and the report names it
with the manoeuvre that would determine it. A DOF the log does not move at all is refused whole.

**Validation.** The log is split in time: identification (the first 70 %) and validation (the
rest). On the validation segment, the depth and heading are predicted 1, 10 and 100 steps of
0.1 s ahead from states taken from the data alone (the latest heading and yaw rate samples; depth
and heave velocity from a causal quadratic fit of the last 3 s of depth), for the identified
model and for the vehicle file it started from: the same initial states for both.

**Surge and sway** (section "Surge and sway" below): where the log carries a DVL's u, v or a
position's x, y, X_udot, X_u, X_|u|u, Y_vdot, Y_v, Y_|v|v by the same output error, surge and sway
together with the logged heading and yaw rate as inputs; and the yaw model then takes the Munk
moment -(X_udot - Y_vdot) u v as a known input.

The virtual dive (:func:`fly_plan`) flies a plan (rovlab.ident.plan) on a hidden vehicle with the
process model of rovlab.models.kinetics (4-DOF, RK4 at 0.01 s), its thrusters (allocation of the
model vehicle, PWM quantised to 1 us, the true vehicle's thrust curves with their dead band) and a
BlueROV2's sensors: depth at 2 Hz with the file's variance and resolution, AHRS heading at 20 Hz
with a smoothed (first-order Gauss-Markov, 0.5 s) error of the file's variance, yaw rate at 20 Hz.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.ident.fitting import IdentificationError, significant
from rovlab.params.vehicle import Vehicle

DOFS = ("heave", "yaw")
HORIZONTAL_DOFS = ("surge", "sway")  # when the log carries position or velocity (section "Surge and sway")
ALL_DOFS = DOFS + HORIZONTAL_DOFS
_DOF_INDEX = {"surge": 0, "sway": 1, "heave": 2, "yaw": 3}
# parameter keys per DOF (the fit's internal names) and how the report and the vehicle file call them
KEYS = ("added_mass", "linear", "quadratic", "net_buoyancy", "thrust_scale")
NAMES = {"heave": {"added_mass": "Z_wdot", "linear": "Z_w", "quadratic": "Z_|w|w", "net_buoyancy": "B-W",
                   "thrust_scale": "s_Z"},
         "yaw": {"added_mass": "N_rdot", "linear": "N_r", "quadratic": "N_|r|r", "thrust_scale": "s_N"},
         "surge": {"added_mass": "X_udot", "linear": "X_u", "quadratic": "X_|u|u", "thrust_scale": "s_X"},
         "sway": {"added_mass": "Y_vdot", "linear": "Y_v", "quadratic": "Y_|v|v", "thrust_scale": "s_Y"}}
UNITS = {"heave": {"added_mass": "kg", "linear": "N s/m", "quadratic": "N s^2/m^2", "net_buoyancy": "N",
                   "thrust_scale": ""},
         "yaw": {"added_mass": "kg m^2", "linear": "N m s/rad", "quadratic": "N m s^2/rad^2", "thrust_scale": ""},
         "surge": {"added_mass": "kg", "linear": "N s/m", "quadratic": "N s^2/m^2", "thrust_scale": ""},
         "sway": {"added_mass": "kg", "linear": "N s/m", "quadratic": "N s^2/m^2", "thrust_scale": ""}}
DEFAULT_FREE = ("added_mass", "linear", "quadratic", "net_buoyancy")
GRID_S = 0.05  # model integration step [s]
WINDOW_S = 15.0  # multiple-shooting window [s]
PREDICTION_STEP_S = 0.1
HORIZONS = (1, 10, 100)
MAX_REL = 0.3  # refusal threshold (module docstring)
MAX_SCALE_SIGMA = 0.1
AHRS_TAU_S = 0.5  # correlation time of the virtual AHRS heading error [s]
_DEG = math.pi / 180.0


# --------------------------------------------------------------------------------------------
# The heave / yaw model
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DofModel:
    """One DOF's parameters (SNAME signs, SI)."""

    dof: str
    rigid: float  # m [kg] or I_zz [kg m^2] (known: weigh the vehicle)
    added_mass: float
    linear: float
    quadratic: float
    cubic: float  # held fixed
    net_buoyancy: float = 0.0  # B - W [N] (heave)
    thrust_scale: float = 1.0

    def values(self) -> dict[str, float]:
        out = {k: float(getattr(self, k)) for k in KEYS}
        if self.dof != "heave":
            out.pop("net_buoyancy")
        return out

    def with_values(self, values: Mapping[str, float]) -> DofModel:
        from dataclasses import replace

        changes: dict[str, Any] = {k: float(v) for k, v in values.items()}
        return replace(self, **changes)


def dof_model(vehicle: Vehicle, dof: str) -> DofModel:
    i = _DOF_INDEX[dof]
    return DofModel(dof, float(vehicle.I_zz if dof == "yaw" else vehicle.mass), float(vehicle.added_mass[i]),
                    float(vehicle.damping_linear[i]), float(vehicle.damping_quadratic[i]),
                    float(vehicle.damping_cubic[i]),
                    float(vehicle.buoyancy - vehicle.weight) if dof == "heave" else 0.0, 1.0)


def simulate(model: DofModel, tau: Sequence[float], h: float, p0: float, v0: float) -> tuple[list[float], list[float]]:
    """Position and velocity on the grid 0, h, ... len(tau) h (RK4, tau[k] held over step k)."""
    inv = 1.0 / (model.rigid - model.added_mass)
    s, nb, lin, quad, cub = model.thrust_scale, model.net_buoyancy, model.linear, model.quadratic, model.cubic
    p, v = float(p0), float(v0)
    ps, vs = [p], [v]
    hh, h6 = 0.5 * h, h / 6.0
    for f in tau:
        g = s * f - nb
        k1 = (g + (lin + quad * abs(v) + cub * v * v) * v) * inv
        v2 = v + hh * k1
        k2 = (g + (lin + quad * abs(v2) + cub * v2 * v2) * v2) * inv
        v3 = v + hh * k2
        k3 = (g + (lin + quad * abs(v3) + cub * v3 * v3) * v3) * inv
        v4 = v + h * k3
        k4 = (g + (lin + quad * abs(v4) + cub * v4 * v4) * v4) * inv
        p += h6 * (v + 2.0 * v2 + 2.0 * v3 + v4)
        v += h6 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if not (abs(v) < 1e6):  # diverged (a bad parameter trial): stop, the residuals say so
            ps.extend([math.nan] * (len(tau) + 1 - len(ps)))
            vs.extend([math.nan] * (len(tau) + 1 - len(vs)))
            return ps, vs
        ps.append(p)
        vs.append(v)
    return ps, vs


# --------------------------------------------------------------------------------------------
# Dive data: input and output samples
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Channel:
    """Samples of one output: ``kind`` 'position' (depth, heading) or 'velocity' (yaw rate)."""

    name: str
    dof: str
    kind: str
    t: np.ndarray
    y: np.ndarray
    sigma: float  # from the vehicle file (the fit re-estimates it)


@dataclass(frozen=True, eq=False)
class DiveData:
    """A dive log in SI: the thrust wrench (held from each command time) and the output samples."""

    file: str
    t_cmd: np.ndarray  # command times [s]
    tau: np.ndarray  # (n, 4) [X, Y, Z, N] from each command time on
    channels: tuple[Channel, ...]
    notes: tuple[str, ...] = ()

    def channel(self, dof: str, kind: str) -> Channel | None:
        return next((c for c in self.channels if c.dof == dof and c.kind == kind), None)

    @property
    def span(self) -> tuple[float, float]:
        ts = [c.t for c in self.channels if c.t.size] + [self.t_cmd]
        return float(min(t[0] for t in ts)), float(max(t[-1] for t in ts))


def sensor_channels(vehicle: Vehicle) -> dict[str, tuple[str, str, str, float, float]]:
    """Which sensor gives depth, heading and yaw rate: key -> (column, sensor, channel, variance,
    resolution). Depth: a pressure sensor; heading and yaw rate: an IMU/AHRS, else motion capture;
    north / east position x, y: a positioning system (kind motion_capture: USBL, motion capture,
    ArduSub's LOCAL_POSITION_NED); surge / sway velocity u, v: a DVL (bottom track)."""
    out: dict[str, tuple[str, str, str, float, float]] = {}
    wanted = {"depth": (("pressure", "z"),), "heading": (("imu", "psi"), ("motion_capture", "psi")),
              "rate": (("imu", "r"),), "x": (("motion_capture", "x"),), "y": (("motion_capture", "y"),),
              "u": (("dvl", "u"),), "v": (("dvl", "v"),)}
    for key, options in wanted.items():
        for kind, ch in options:
            s = next((s for s in vehicle.sensors if s.kind == kind and ch in s.variance), None)
            if s is not None:
                out[key] = (f"{ch}_{s.name}", s.name, ch, float(s.variance[ch]), float(s.resolution.get(ch, 0.0)))
                break
    return out


def dive_from_columns(cols: Mapping[str, np.ndarray], vehicle: Vehicle, *, file: str = "<log>") -> DiveData:
    """A dive from log columns: ``time_s``; the input as ``pwm_<thruster>`` per thruster (converted
    through the vehicle's thrust curves and configuration matrix) or as ``tau_Z``, ``tau_N`` (what
    ``rovlab mavlink convert`` writes); outputs ``<channel>_<sensor>`` of the vehicle's sensors
    (depth, heading, yaw rate); NaN = no sample at that row."""
    from rovlab.allocation.geometry import configuration_matrix
    from rovlab.models.thrusters import ThrusterBank

    if "time_s" not in cols:
        raise IdentificationError(f"{file}: no time_s column; expected a dive log (time_s, pwm_<thruster> or "
                                  "tau_Z/tau_N, and the sensors' columns)")
    t = np.asarray(cols["time_s"], dtype=float)
    pwm_names = [f"pwm_{n}" for n in vehicle.thruster_names]
    notes: list[str] = []
    if all(n in cols for n in pwm_names):
        pwm = np.column_stack([np.asarray(cols[n], dtype=float) for n in pwm_names])
        ok = np.all(np.isfinite(pwm), axis=1)
        bank = ThrusterBank.from_vehicle(vehicle)
        B = configuration_matrix(vehicle)
        t_cmd = t[ok]
        forces = np.array([bank.force(row, compiled=False) for row in pwm[ok]]) if ok.any() else np.zeros((0, len(pwm_names)))
        tau6 = forces @ B.T if forces.size else np.zeros((0, 6))
        tau = tau6[:, [0, 1, 2, 5]] if tau6.size else np.zeros((0, 4))
        notes.append(f"input: PWM of {', '.join(vehicle.thruster_names)} through {vehicle.name}'s thrust curves")
    elif "tau_Z" in cols and "tau_N" in cols:
        z, n = np.asarray(cols["tau_Z"], dtype=float), np.asarray(cols["tau_N"], dtype=float)
        x = np.asarray(cols.get("tau_X", np.zeros_like(z)), dtype=float)
        y = np.asarray(cols.get("tau_Y", np.zeros_like(z)), dtype=float)
        ok = np.isfinite(z) & np.isfinite(n)
        t_cmd = t[ok]
        tau = np.column_stack([x[ok], y[ok], z[ok], n[ok]])
        notes.append("input: the log's tau_Z, tau_N (thrust wrench from PWM through the vehicle's thrust curves)")
    else:
        missing = [n for n in pwm_names if n not in cols]
        raise IdentificationError(f"{file}: no thruster input: expected a column pwm_<thruster> for each thruster of "
                                  f"{vehicle.name} (missing {', '.join(missing)}) or the columns tau_Z and tau_N")
    if t_cmd.size == 0:
        raise IdentificationError(f"{file}: no row with the thruster input; expected PWM or tau_Z/tau_N values")
    sens = sensor_channels(vehicle)
    chans: list[Channel] = []
    for key, dof, kind in (("depth", "heave", "position"), ("heading", "yaw", "position"), ("rate", "yaw", "velocity"),
                           ("x", "north", "position"), ("y", "east", "position"), ("u", "surge", "velocity"),
                           ("v", "sway", "velocity")):
        if key not in sens:
            continue
        col, _, _, var, _ = sens[key]
        if col not in cols:
            continue
        y = np.asarray(cols[col], dtype=float)
        m = np.isfinite(y)
        ty, yy = t[m], y[m]
        if key == "heading" and yy.size:
            yy = np.unwrap(yy)
        chans.append(Channel(col, dof, kind, ty, yy, math.sqrt(var)))
    if not chans:
        want = ", ".join(v[0] for v in sens.values()) or "none (the vehicle file has no pressure or heading sensor)"
        raise IdentificationError(f"{file}: no output column of {vehicle.name}'s sensors; expected {want}")
    return DiveData(file, t_cmd, tau, tuple(chans), tuple(notes))


def read_dive(path: str | Path, vehicle: Vehicle) -> DiveData:
    """A dive from a CSV log (:func:`dive_from_columns`). A .tlog / .BIN / .mcap MAVLink log is read
    at the interface layer (rovlab.interfaces.cli_ident.read_dive_log: the MAVLink log readers
    give the same columns)."""
    from rovlab.io.logreader import read_log

    log = read_log(Path(path))
    return dive_from_columns(dict(log.data), vehicle, file=str(path))


# --------------------------------------------------------------------------------------------
# Output-error problem of one DOF
# --------------------------------------------------------------------------------------------

@dataclass(eq=False)
class _Window:
    i0: int  # first grid index
    n: int  # grid steps in the window
    samples: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]  # (channel index, j, alpha, y, idx)


class _Problem:
    """Output error of one DOF on [t0, t1]: global parameters + (p0, v0) per window."""

    def __init__(self, data: DiveData, dof: str, base: DofModel, free: Sequence[str], t0: float, t1: float, *,
                 grid_s: float = GRID_S, window_s: float = WINDOW_S) -> None:
        self.dof, self.base, self.free, self.h = dof, base, tuple(free), grid_s
        self.t0 = t0
        n = int(math.floor((t1 - t0) / grid_s + 1e-9))
        if n < 4:
            raise IdentificationError(f"{data.file}: the {dof} segment {t0:g}-{t1:g} s is too short")
        tg = t0 + grid_s * np.arange(n + 1)
        self.tau = _held(data, tg[:-1], _DOF_INDEX[dof]).tolist()
        self.channels = [c for c in data.channels if c.dof == dof]
        self.sigma = np.array([c.sigma for c in self.channels], dtype=float)
        nw = max(1, int(round((t1 - t0) / window_s)))
        edges = np.linspace(0, n, nw + 1).round().astype(int)
        self.windows: list[_Window] = []
        self.count = 0
        for a, b in zip(edges[:-1], edges[1:]):
            samples = []
            for ci, c in enumerate(self.channels):
                lo, hi = tg[a], tg[b]
                m = (c.t >= lo) & (c.t < hi) if b < n else (c.t >= lo) & (c.t <= hi)
                if not m.any():
                    continue
                x = (c.t[m] - lo) / grid_s
                j = np.minimum(np.floor(x).astype(int), b - a - 1)
                samples.append((ci, j, x - j, c.y[m], np.arange(self.count, self.count + int(m.sum()))))
                self.count += int(m.sum())
            if samples:
                self.windows.append(_Window(int(a), int(b - a), samples))
        if not self.windows:
            raise IdentificationError(f"{data.file}: no {dof} output samples between {t0:g} and {t1:g} s")
        self.channel_of = np.empty(self.count, dtype=int)
        for w in self.windows:
            for ci, _, _, _, idx in w.samples:
                self.channel_of[idx] = ci

    # parameter vector: free globals, then (p0, v0) per window
    def model(self, theta: np.ndarray) -> DofModel:
        return self.base.with_values(dict(zip(self.free, theta[:len(self.free)])))

    def initial(self, base: DofModel) -> np.ndarray:
        """Globals of ``base`` and each window's start from the first samples."""
        th = [getattr(base, k) for k in self.free]
        for w in self.windows:
            pos = next(((j, a, y) for ci, j, a, y, _ in w.samples if self.channels[ci].kind == "position"), None)
            vel = next(((j, a, y) for ci, j, a, y, _ in w.samples if self.channels[ci].kind == "velocity"), None)
            p0 = float(pos[2][0]) if pos is not None else 0.0
            v0 = float(vel[2][0]) if vel is not None else 0.0
            if pos is not None and vel is None and pos[2].size >= 3:  # slope of the first samples
                k = min(pos[2].size, 4)
                tt = (pos[0][:k] + pos[1][:k]) * self.h
                v0 = float(np.polyfit(tt, pos[2][:k], 1)[0])
                p0 = float(np.polyval(np.polyfit(tt, pos[2][:k], 1), 0.0))
            th += [p0, v0]
        return np.array(th, dtype=float)

    def _window_pred(self, model: DofModel, w: _Window, p0: float, v0: float) -> tuple[np.ndarray, np.ndarray]:
        ps, vs = simulate(model, self.tau[w.i0:w.i0 + w.n], self.h, p0, v0)
        return np.asarray(ps), np.asarray(vs)

    def _fill(self, out: np.ndarray, w: _Window, ps: np.ndarray, vs: np.ndarray, weights: np.ndarray,
              subtract: bool) -> None:
        for ci, j, a, y, idx in w.samples:
            src = ps if self.channels[ci].kind == "position" else vs
            pred = (1.0 - a) * src[j] + a * src[j + 1]
            out[idx] = ((y - pred) if subtract else pred) / weights[ci]

    def residuals(self, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
        model = self.model(theta)
        out = np.empty(self.count)
        g = len(self.free)
        for k, w in enumerate(self.windows):
            ps, vs = self._window_pred(model, w, theta[g + 2 * k], theta[g + 2 * k + 1])
            self._fill(out, w, ps, vs, weights, True)
        return np.nan_to_num(out, nan=1e6, posinf=1e6, neginf=-1e6)

    def predictions(self, theta: np.ndarray) -> np.ndarray:
        """Model outputs at the samples (unweighted)."""
        model = self.model(theta)
        out = np.empty(self.count)
        g = len(self.free)
        ones = np.ones(len(self.channels))
        for k, w in enumerate(self.windows):
            ps, vs = self._window_pred(model, w, theta[g + 2 * k], theta[g + 2 * k + 1])
            self._fill(out, w, ps, vs, ones, False)
        return out

    def jacobian(self, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """d residuals / d theta: forward differences for the globals and v0; p0 exactly (-1 for
        the positions: the dynamics do not depend on the position)."""
        g = len(self.free)
        J = np.zeros((self.count, theta.size))
        base = self.predictions(theta) / weights[self.channel_of]
        for i in range(g):
            d = 1e-6 * max(abs(theta[i]), _SCALE[self.free[i]](self.base))
            th = theta.copy()
            th[i] += d
            J[:, i] = -(self.predictions(th) / weights[self.channel_of] - base) / d
        model = self.model(theta)
        for k, w in enumerate(self.windows):
            p0, v0 = theta[g + 2 * k], theta[g + 2 * k + 1]
            for ci, _, _, _, idx in w.samples:
                if self.channels[ci].kind == "position":
                    J[idx, g + 2 * k] = -1.0 / weights[ci]
            d = 1e-6 * max(abs(v0), 0.1)
            ps0, vs0 = self._window_pred(model, w, p0, v0)
            ps1, vs1 = self._window_pred(model, w, p0, v0 + d)
            tmp0, tmp1 = np.zeros(self.count), np.zeros(self.count)
            self._fill(tmp0, w, ps0, vs0, weights, False)
            self._fill(tmp1, w, ps1, vs1, weights, False)
            for _, _, _, _, idx in w.samples:
                J[idx, g + 2 * k + 1] = -(tmp1[idx] - tmp0[idx]) / d
        return J

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for k in self.free:
            lo.append({"added_mass": -50.0 * self.base.rigid, "linear": -np.inf, "quadratic": -np.inf,
                       "net_buoyancy": -np.inf, "thrust_scale": 0.05}[k])
            hi.append({"added_mass": 0.0, "linear": 0.0, "quadratic": 0.0, "net_buoyancy": np.inf,
                       "thrust_scale": 20.0}[k])
        n = 2 * len(self.windows)
        return np.array(lo + [-np.inf] * n), np.array(hi + [np.inf] * n)


_SCALE = {"added_mass": lambda b: 0.1 * b.rigid, "linear": lambda b: 1e-2 * b.rigid,
          "quadratic": lambda b: 1e-2 * b.rigid, "net_buoyancy": lambda b: 0.1, "thrust_scale": lambda b: 1.0}


def _held(data: DiveData, t: np.ndarray, col: int) -> np.ndarray:
    """The input column held from each command time (0 before the first)."""
    k = np.searchsorted(data.t_cmd, t + 1e-9, side="right") - 1
    out = np.where(k >= 0, data.tau[np.maximum(k, 0), col], 0.0)
    return out


def _covariances(prob: _Problem, J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(white-noise, Newey-West, window-clustered) covariances of the global parameters from the
    weighted Jacobian J and residuals r at the optimum.

    Each window's own initial state is profiled out first (Frisch-Waugh-Lovell: the global
    columns are projected onto the complement of the window's nuisance columns), so the scores
    are those of the global parameters alone. Newey-West (Bartlett weights up to twice the lag at
    which a channel's residual autocorrelation falls below 0.05) covers a smoothed AHRS; the
    window-clustered sandwich (the windows' score sums, G/(G-1) and t(G-1) small-sample factors;
    Liang & Zeger 1986) covers any correlation within a window, across channels too, e.g. the drift a random
    force leaves in the integrated depth and heading."""
    g = len(prob.free)
    nn = getattr(prob, "nuisance", 2)  # initial-state values per window (horizontal: 2 or 4)
    Jg = J[:, :g].copy()
    for k, w in enumerate(prob.windows):
        idx = np.concatenate([s[4] for s in w.samples])
        Jn = J[idx, g + nn * k:g + nn * (k + 1)]
        coef, *_ = np.linalg.lstsq(Jn, Jg[idx], rcond=None)
        Jg[idx] -= Jn @ coef
    n = r.size
    A = np.linalg.pinv(Jg.T @ Jg)
    white = float(r @ r) / max(n - J.shape[1], 1) * A
    S = np.zeros((g, g))
    for ci in range(len(prob.channels)):
        idx = np.flatnonzero(prob.channel_of == ci)  # in time order (windows in order)
        if idx.size < 3:
            continue
        sc = Jg[idx] * r[idx, None]
        e = r[idx]
        var = float(e @ e) / idx.size
        lag_max = 1
        for lag in range(1, min(idx.size // 4, 400)):
            rho = float(e[:-lag] @ e[lag:]) / (idx.size * var) if var > 0 else 0.0
            lag_max = lag
            if rho < 0.05:
                break
        L = 2 * lag_max
        S += sc.T @ sc
        for lag in range(1, min(L, idx.size - 1) + 1):
            G = sc[:-lag].T @ sc[lag:]
            S += (1.0 - lag / (L + 1.0)) * (G + G.T)
    hac = A @ S @ A
    C = np.zeros((g, g))
    for w in prob.windows:
        idx = np.concatenate([s[4] for s in w.samples])
        sw = Jg[idx].T @ r[idx]
        C += np.outer(sw, sw)
    G = len(prob.windows)
    # few clusters: G/(G-1), and the t(G-1) quantile's excess over the normal one folded into the
    # variance, so that +-2 sigma keeps its ~95 % (Cameron & Miller 2015, sec. VI)
    from scipy.stats import t as student

    widen = (float(student.ppf(0.975, G - 1)) / 1.959964) ** 2 if G > 1 else 1.0
    cluster = (G / (G - 1) if G > 1 else 1.0) * widen * (A @ C @ A)
    return white, hac, cluster


# --------------------------------------------------------------------------------------------
# Fit results
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ParamResult:
    key: str
    name: str
    unit: str
    start: float  # the vehicle file's value
    estimate: float
    sigma: float
    status: str  # "estimated", "held" (not free), "refused" (not determined: held at the file's value)
    note: str = ""


@dataclass(frozen=True, eq=False)
class DofFit:
    dof: str
    params: tuple[ParamResult, ...]
    correlation: np.ndarray  # among the estimated parameters, in the order of ``estimated``
    estimated: tuple[str, ...]
    model: DofModel  # with the estimates (refused / held: the file's values)
    rms: Mapping[str, float]  # per channel, residual RMS (identification segment)
    samples: Mapping[str, int]
    speed_rms: float
    speed_max: float
    refused_dof: str = ""  # non-empty: the whole DOF was not identified, and why
    windows: int = 0
    cost_start: float = math.nan
    cost: float = math.nan

    def param(self, key: str) -> ParamResult:
        return next(p for p in self.params if p.key == key)


@dataclass(frozen=True, eq=False)
class DiveFit:
    file: str
    fits: Mapping[str, DofFit]
    ident_span: tuple[float, float]
    valid_span: tuple[float, float]
    prediction: Mapping[str, Mapping[str, list[float]]]  # output -> {"identified": [..], "file": [..], "n": [..]}
    notes: tuple[str, ...] = ()
    compare: Any = None  # the published set scored as rows["published"] (rovlab.ident.published.PublishedSet)
    fitted: Any = None  # the DiveData heave and yaw were fitted on (yaw's input with the Munk moment where modelled)

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"file": self.file, "identification_s": list(self.ident_span),
                               "validation_s": list(self.valid_span), "notes": list(self.notes),
                               "prediction_rmse": {k: dict(v) for k, v in self.prediction.items()},
                               "prediction_step_s": PREDICTION_STEP_S, "horizons": list(HORIZONS),
                               "published_set": self.compare.as_dict() if self.compare is not None else None}
        for dof, f in self.fits.items():
            out[dof] = {"refused": f.refused_dof or None,
                        "parameters": {p.name: {"estimate": p.estimate, "sigma": p.sigma, "start": p.start,
                                                "status": p.status, "unit": p.unit, "note": p.note or None}
                                       for p in f.params},
                        "correlation": {"names": [NAMES[dof][k] for k in f.estimated],
                                        "matrix": f.correlation.tolist()},
                        "residual_rms": dict(f.rms), "samples": dict(f.samples),
                        "speed_rms": f.speed_rms, "speed_max": f.speed_max}
        return out


def _manoeuvre(dof: str, key: str, speed_rms: float) -> str:
    unit = "rad/s" if dof == "yaw" else "m/s"
    plan = f"rovlab lab plan-dive --dofs {dof}"
    return {"added_mass": f"quick reversals of the {dof} thrust (holds of 0.5-2 s: accelerations, {plan})",
            "linear": f"long holds at low {dof} speed (below {max(0.5 * speed_rms, 0.02):.2g} {unit}) as well as fast ones "
                      f"({plan})",
            "quadratic": f"{dof} speeds well above {max(2 * speed_rms, 0.1):.2g} {unit} ({plan})",
            "net_buoyancy": "rests with the vertical thrusters at neutral (the plan's rests)",
            "thrust_scale": "none from motion alone: a bollard/load-cell test of the thrusters (rovlab identify thrust)"}[key]


def _hold_text(dof: str) -> str:
    return {"heave": "heave (no depth change to speak of, or no depth column)",
            "yaw": "yaw (no turning to speak of, or no heading column)",
            "surge": "surge (no surge speed to speak of)", "sway": "sway (no sway speed to speak of)"}[dof]


def _reweighted_fit(prob: Any, th0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output error with unknown noise levels (heave/yaw's _Problem, surge/sway's
    HorizontalProblem): fit, re-weight each channel by its residual RMS, fit again. Returns the
    estimate, its weighted residuals, the standard deviations (the largest of _covariances') and
    the covariance the correlations are read from (the one that sets the most sigmas)."""
    from scipy.optimize import least_squares

    for _ in range(2):
        sol = least_squares(lambda th, w=weights: prob.residuals(th, w), th0,
                            jac=lambda th, w=weights: prob.jacobian(th, w), bounds=(lo, hi), x_scale="jac",
                            method="trf", max_nfev=60)
        th0 = sol.x
        raw = prob.residuals(th0, np.ones(len(prob.channels)))
        weights = np.array([max(float(np.sqrt(np.mean(raw[prob.channel_of == ci] ** 2))), 1e-9)
                            if np.any(prob.channel_of == ci) else prob.sigma[ci]
                            for ci in range(len(prob.channels))])
    r = prob.residuals(th0, weights)
    covs = _covariances(prob, prob.jacobian(th0, weights), r)
    var = np.max([np.diag(c) for c in covs], axis=0)
    cov_hac = max(covs, key=lambda c: float(np.trace(c / np.maximum(var, 1e-300))))
    return th0, r, np.sqrt(var), cov_hac


def fit_dof(data: DiveData, dof: str, start: DofModel, t0: float, t1: float, *,
            free: Sequence[str] = DEFAULT_FREE, max_rel: float = MAX_REL, grid_s: float = GRID_S,
            window_s: float | None = None) -> DofFit:
    """Output-error fit of one DOF on [t0, t1] (module docstring), with refusals."""
    window_s = WINDOW_S if window_s is None else window_s
    free = [k for k in KEYS if k in free and not (dof == "yaw" and k == "net_buoyancy")]
    if "added_mass" in free and "thrust_scale" in free:
        raise IdentificationError(f"{NAMES[dof]['added_mass']} and {NAMES[dof]['thrust_scale']} cannot both be "
                                  "estimated: the motion responds to force / mass only, so no manoeuvre tells a "
                                  "larger added mass from weaker thrust; hold one (measure the thrust with "
                                  "rovlab identify thrust, or keep the file's added mass)")
    pos = data.channel(dof, "position")
    vel = data.channel(dof, "velocity")
    speed = _speeds(pos, vel, t0, t1)
    s_rms = float(np.sqrt(np.mean(speed**2))) if speed.size else 0.0
    s_max = float(np.max(np.abs(speed))) if speed.size else 0.0
    floor = 0.03 if dof == "heave" else 0.05  # m/s, rad/s (3 cm/s: the 2 Hz depth's noise over 1 s)
    if pos is None or s_max < floor:
        why = (f"the log does not excite {_hold_text(dof)}: the largest {dof} speed is "
               f"{s_max:.3g} {'m/s' if dof == 'heave' else 'rad/s'} (need > {floor:g}); fly "
               f"rovlab lab plan-dive --dofs {dof}")
        return _refused_dof(dof, start, why, s_rms, s_max)
    held: dict[str, str] = {}
    prob = None
    theta = None
    while True:
        cur = [k for k in free if k not in held]
        prob = _Problem(data, dof, start, cur, t0, t1, grid_s=grid_s, window_s=window_s)
        weights = prob.sigma.copy()
        th0 = _start(prob, data, dof, start, weights, t0, t1)
        lo, hi = prob.bounds()
        th0 = _inside(th0, lo, hi, [_SCALE[k](start) for k in cur])
        cost_start = 0.5 * float(np.sum(prob.residuals(th0, weights) ** 2))
        theta, r, sig, cov_hac = _reweighted_fit(prob, th0, lo, hi, weights)
        g = len(cur)
        model = prob.model(theta)
        # refuse the worst-determined parameter, if any, and fit again without it
        worst, worst_ratio = None, 1.0
        for i, k in enumerate(cur):
            ratio = _determination(k, model, sig[i], s_rms, max_rel)
            if ratio > worst_ratio:
                worst, worst_ratio = k, ratio
        if worst is None:
            break
        held[worst] = (f"not determined by this log (sigma {sig[cur.index(worst)]:.3g}, "
                       f"{worst_ratio * max_rel * 100:.0f} % of what it does); held at the file's value; "
                       f"to determine it: {_manoeuvre(dof, worst, s_rms)}")
        if len(held) == len(free):
            return _refused_dof(dof, start, "no parameter is determined by this log: " +
                                "; ".join(f"{NAMES[dof][k]}: {v}" for k, v in held.items()), s_rms, s_max,
                                refused=held)
    d = np.sqrt(np.maximum(np.diag(cov_hac)[:g], 1e-300))
    corr = cov_hac[:g, :g] / np.outer(d, d)
    params = []
    for k in start.values():
        name, unit = NAMES[dof][k], UNITS[dof][k]
        if k in cur:
            i = cur.index(k)
            params.append(ParamResult(k, name, unit, float(getattr(start, k)), float(theta[i]), float(sig[i]),
                                      "estimated", _at_bound(k, theta[i], lo[i], hi[i])))
        elif k in held:
            params.append(ParamResult(k, name, unit, float(getattr(start, k)), float(getattr(start, k)), math.nan,
                                      "refused", held[k]))
        else:
            params.append(ParamResult(k, name, unit, float(getattr(start, k)), float(getattr(start, k)), math.nan,
                                      "held", "held at the file's value (not asked for)"))
    raw = prob.residuals(theta, np.ones(len(prob.channels)))
    rms = {c.name: float(np.sqrt(np.mean(raw[prob.channel_of == ci] ** 2)))
           for ci, c in enumerate(prob.channels) if np.any(prob.channel_of == ci)}
    counts = {c.name: int(np.sum(prob.channel_of == ci)) for ci, c in enumerate(prob.channels)}
    return DofFit(dof, tuple(params), corr, tuple(cur), model, rms, counts, s_rms, s_max, windows=len(prob.windows),
                  cost_start=cost_start, cost=0.5 * float(r @ r))


def _inside(th: np.ndarray, lo: np.ndarray, hi: np.ndarray, scale: Sequence[float]) -> np.ndarray:
    """th moved strictly inside finite bounds (a zero damping guess starts slightly negative)."""
    th = th.copy()
    for i, sc in enumerate(scale):
        if math.isfinite(hi[i]) and th[i] >= hi[i]:
            th[i] = hi[i] - 1e-2 * sc
        if math.isfinite(lo[i]) and th[i] <= lo[i]:
            th[i] = lo[i] + 1e-2 * sc
    return th


def _at_bound(key: str, x: float, lo: float, hi: float) -> str:
    if math.isfinite(hi) and key != "thrust_scale" and x >= hi - 1e-9 * max(1.0, abs(hi)):
        return "at its bound 0 (dissipative / positive added mass enforced): the sigma is not meaningful"
    return ""


def _determination(key: str, model: DofModel, sigma: float, speed_rms: float, max_rel: float) -> float:
    """sigma against what the parameter does, in units of max_rel (> 1: refuse)."""
    if not math.isfinite(sigma):
        return math.inf
    v = max(speed_rms, 1e-3)
    damp = abs(model.linear * v) + abs(model.quadratic * v * v) + abs(model.cubic * v**3)
    if key == "added_mass":
        return sigma / (max_rel * max(abs(model.added_mass), 1e-3 * model.rigid))
    if key == "linear":
        return sigma * v / (max_rel * max(damp, 1e-9))
    if key == "quadratic":
        return sigma * v * v / (max_rel * max(damp, 1e-9))
    if key == "thrust_scale":
        return sigma / MAX_SCALE_SIGMA
    return 0.0  # net buoyancy: always reported with its sigma


def _refused_dof(dof: str, start: DofModel, why: str, s_rms: float, s_max: float,
                 refused: Mapping[str, str] | None = None) -> DofFit:
    params = tuple(ParamResult(k, NAMES[dof][k], UNITS[dof][k], float(getattr(start, k)), float(getattr(start, k)),
                               math.nan, "refused", (refused or {}).get(k, why)) for k in start.values())
    return DofFit(dof, params, np.zeros((0, 0)), (), start, {}, {}, s_rms, s_max, refused_dof=why)


def _speeds(pos: Channel | None, vel: Channel | None, t0: float, t1: float) -> np.ndarray:
    if vel is not None:
        m = (vel.t >= t0) & (vel.t <= t1)
        return vel.y[m]
    if pos is None:
        return np.zeros(0)
    m = (pos.t >= t0) & (pos.t <= t1)
    if m.sum() < 8:
        return np.zeros(0)
    t, y = pos.t[m], pos.y[m]
    from scipy.interpolate import make_smoothing_spline

    spl = make_smoothing_spline(t, y)  # smoothing by generalised cross-validation
    return spl.derivative()(t)


def _start(prob: _Problem, data: DiveData, dof: str, start: DofModel, weights: np.ndarray, t0: float,
           t1: float) -> np.ndarray:
    """Equation-error start (constrained linear least squares), or the file's guess if that fits
    the outputs better."""
    cands = [prob.initial(start)]
    ee = equation_error(data, dof, start, t0, t1, prob.free)
    if ee is not None:
        cands.append(prob.initial(ee))
    costs = [float(np.sum(prob.residuals(c, weights) ** 2)) for c in cands]
    return cands[int(np.argmin(costs))]


def equation_error(data: DiveData, dof: str, start: DofModel, t0: float, t1: float,
                   free: Sequence[str]) -> DofModel | None:
    """Constrained least squares of the equation of motion on smoothed velocity and acceleration:
    s tau = M a + (B - W) - lin v - quad |v| v - cubic v^3, with M >= m (added mass <= 0) and
    damping <= 0; the parameters not in ``free`` held at ``start``. None when the data are too few."""
    from scipy.interpolate import make_smoothing_spline
    from scipy.optimize import lsq_linear

    pos, vel = data.channel(dof, "position"), data.channel(dof, "velocity")
    src = vel if vel is not None else pos
    if src is None:
        return None
    m = (src.t >= t0) & (src.t <= t1)
    if m.sum() < 20:
        return None
    t, y = src.t[m], src.y[m]
    tg = np.arange(t[0] + 1.0, t[-1] - 1.0, 0.1)
    if tg.size < 20:
        return None
    try:
        spl = make_smoothing_spline(t, y)  # smoothing by generalised cross-validation
    except ValueError:
        return None
    if vel is not None:
        v, a = spl(tg), spl.derivative()(tg)
    else:
        v, a = spl.derivative()(tg), spl.derivative(2)(tg)
    f = _held(data, tg, _DOF_INDEX[dof])
    cols = {"added_mass": -a, "linear": -v, "quadratic": -np.abs(v) * v, "net_buoyancy": np.ones_like(v),
            "thrust_scale": -f}
    # s f - M a - nb + lin v + quad |v| v + cub v^3 = 0 with M = rigid - added
    rhs = -(start.thrust_scale * f if "thrust_scale" not in free else 0.0) + start.rigid * a - start.cubic * v**3
    known = {k: getattr(start, k) for k in KEYS if k not in free and not (dof == "yaw" and k == "net_buoyancy")}
    for k, val in known.items():
        if k != "thrust_scale":
            rhs = rhs - cols[k] * val
    names = [k for k in free]
    A = np.column_stack([cols[k] for k in names])
    lo = [{"added_mass": -50.0 * start.rigid, "linear": -np.inf, "quadratic": -np.inf, "net_buoyancy": -np.inf,
           "thrust_scale": 0.05}[k] for k in names]
    hi = [{"added_mass": 0.0, "linear": 0.0, "quadratic": 0.0, "net_buoyancy": np.inf, "thrust_scale": 20.0}[k]
          for k in names]
    try:
        sol = lsq_linear(A, rhs, bounds=(lo, hi))
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(sol.x)):
        return None
    return start.with_values(dict(zip(names, sol.x)))


# --------------------------------------------------------------------------------------------
# The whole dive: split, fit, validate
# --------------------------------------------------------------------------------------------

def identify_dive(data: DiveData, vehicle: Vehicle, *, dofs: Sequence[str] | None = None,
                  free: Mapping[str, Sequence[str]] | Sequence[str] | None = None, split: float = 0.7,
                  max_rel: float = MAX_REL, compare: Any = None) -> DiveFit:
    """Identify heave and yaw from a dive (module docstring), and surge and sway
    (section "Surge and sway"); ``dofs`` None: heave and yaw, with surge and sway when the log
    carries position or velocity; ``split``: the share of the log used
    to identify (the rest validates); ``compare``: a published parameter set
    (rovlab.ident.published.PublishedSet) whose predictions are scored too."""
    if not 0.2 <= split <= 0.95:
        raise IdentificationError(f"split must be within 0.2 .. 0.95 (the share of the log used to identify), got {split}")
    a, b = data.span
    if b - a < 10.0:
        raise IdentificationError(f"{data.file}: {b - a:.3g} s of data; a dive log needs at least a minute")
    t_split = a + split * (b - a)
    if dofs is None:  # heave and yaw, and surge and sway when the log carries position or velocity
        dofs = default_dofs(data)
    fits = {}
    hfits: dict[str, DofFit] = {}
    munk: dict[str, DofFit] = {}  # the surge / sway fits whose X_udot - Y_vdot the yaw input uses
    fit_data = data
    if any(d in HORIZONTAL_DOFS for d in dofs):  # first: yaw takes its X_udot - Y_vdot
        hfits = fit_requested_horizontal(data, vehicle, dofs, free, a, t_split, max_rel=max_rel)
    if "yaw" in dofs and has_horizontal(data):  # the Munk moment as a known yaw input
        try:
            munk = hfits or fit_requested_horizontal(data, vehicle, HORIZONTAL_DOFS, free, a, t_split,
                                                     max_rel=max_rel)
        except IdentificationError:  # not asked for, and not possible (e.g. no heading): yaw without it
            munk = {}
        fit_data = with_munk_moment(data, vehicle, munk)
    for dof in dofs:
        if dof in HORIZONTAL_DOFS:  # above, together (fit_requested_horizontal)
            continue
        if dof not in DOFS:
            raise IdentificationError(f"DOF {dof!r}: identification from dives covers {', '.join(ALL_DOFS)} (surge and "
                                      "sway need position or velocity in the log)")
        chosen = free.get(dof, DEFAULT_FREE) if isinstance(free, Mapping) else (free or DEFAULT_FREE)
        fits[dof] = fit_dof(fit_data, dof, dof_model(vehicle, dof), a, t_split, free=chosen, max_rel=max_rel)
        if dof == "yaw" and munk:  # the Munk moment's X_udot - Y_vdot is uncertain too
            fits[dof] = with_munk_uncertainty(
                fits[dof], data, vehicle, munk,
                lambda d, c=chosen: fit_dof(d, "yaw", dof_model(vehicle, "yaw"), a, t_split, free=c, max_rel=max_rel))
    kept = tuple(d for d in fits if not fits[d].refused_dof)
    pred = prediction_errors(fit_data, {d: fits[d].model for d in kept}, {d: dof_model(vehicle, d) for d in kept},
                             t_split, b, published=compare.models(vehicle, kept) if compare is not None else None)
    if hfits:
        fits, pred = merge_horizontal(data, vehicle, dofs, hfits, fits, pred, t_split, b, compare)
    notes = fit_data.notes
    depth = data.channel("heave", "position")
    if depth is not None and depth.y.size and abs(float(np.median(depth.y))) < 0.3:
        from rovlab.models.kinetics import hull_height

        notes += (f"the depth stays near the surface (median {float(np.median(depth.y)):.3g} m; the free surface cuts "
                  f"the hull above {0.5 * hull_height(vehicle):.2f} m): a surface log; heave and yaw are identified "
                  "below 1 m (rovlab lab plan-dive keeps the vehicle there)",)
    if "yaw" in kept and fit_data is data:  # no surge/sway velocity in the log: the Munk moment left out
        notes += _horizontal_thrust_note(data, a, t_split)
    return DiveFit(data.file, fits, (a, t_split), (t_split, b), pred, notes, compare, fit_data)


def _horizontal_thrust_note(data: DiveData, t0: float, t1: float, *, force_n: float = 2.0,
                            busy_s: float = 5.0) -> tuple[str, ...]:
    """A note when the identification segment commands surge or sway thrust: the yaw model leaves
    out how surge and sway motion couple into yaw (docs/identification.md, "An unplanned dive")."""
    m = (data.t_cmd >= t0) & (data.t_cmd <= t1)
    if m.sum() < 2:
        return ()
    xy = np.hypot(data.tau[m, 0], data.tau[m, 1])
    dt = np.diff(np.append(data.t_cmd[m], t1))
    busy = float(np.sum(dt[xy > force_n]))
    if busy < busy_s:
        return ()
    return (f"the log commands surge/sway thrust for {busy:.0f} s of the identification segment (up to "
            f"{float(xy.max()):.3g} N): the yaw model leaves out how surge and sway motion couple into yaw, so N_r may "
            "be biased beyond its sigma (30 simulated pilot dives with forward runs: N_r from 64 % low to 22 % high, "
            "within +-2 sigma in 77 %); for yaw, fly turns on the spot (rovlab lab plan-dive --dofs heave,yaw)",)


def prediction_errors(data: DiveData, identified: Mapping[str, DofModel], start: Mapping[str, DofModel],
                      t0: float, t1: float, *, step_s: float = PREDICTION_STEP_S,
                      horizons: Sequence[int] = HORIZONS, every_s: float = 1.0,
                      published: Mapping[str, DofModel] | None = None) -> dict[str, dict[str, list[float]]]:
    """k-step prediction RMSE of depth and heading on [t0, t1] against the measurements, from the
    same initial states for every model (module docstring): heading and yaw rate from their latest
    samples; depth and heave velocity from a smoothing spline of the depth samples of the segment
    (the 2 Hz depth gives no velocity of its own: the spline's state is what motion capture's would
    be in a tank). ``published``: a third model per DOF (rovlab.ident.published), scored as
    ``rows["published"]``."""
    from scipy.interpolate import make_smoothing_spline

    out: dict[str, dict[str, list[float]]] = {}
    for dof in identified:
        keys = ("identified", "file") + (("published",) if published and dof in published else ())
        models = (identified[dof], start[dof]) + ((published[dof],) if published and dof in published else ())
        pos = data.channel(dof, "position")
        vel = data.channel(dof, "velocity")
        if pos is None:
            continue
        m = (pos.t >= t0) & (pos.t <= t1)
        if m.sum() < 10:
            continue
        tm, ym = pos.t[m], pos.y[m]
        # depth: the spline of every other sample gives the initial states, the others are the targets
        # (a spline through the target itself would predict it from itself)
        spl = make_smoothing_spline(tm[0::2], ym[0::2]) if vel is None else None
        tgt = tm[1::2] if vel is None else tm
        label = "depth_m" if dof == "heave" else "heading_rad"
        rows: dict[str, list[float]] = {k: [] for k in (*keys, "n")}
        step = float(np.median(np.diff(tgt)))
        stride = max(1, int(round(every_s / max(step, 1e-3))))
        for k in horizons:
            horizon = k * step_s
            errs: list[list[float]] = [[] for _ in models]
            targets = tgt[(tgt >= t0 + horizon + 2.0) & (tgt <= tm[-1] - 1.0)][::stride]
            for tt in targets:
                ts = tt - horizon
                init = _state_at(pos, vel, spl, ts)
                if init is None:
                    continue
                y = float(pos.y[np.searchsorted(pos.t, tt - 1e-9)])
                for i, mdl in enumerate(models):
                    errs[i].append(_predict(data, dof, mdl, init, ts, horizon)[1][-1] - y)
            for i, key in enumerate(keys):
                e = np.asarray(errs[i])
                rows[key].append(float(np.sqrt(np.mean(e**2))) if e.size else math.nan)
            rows["n"].append(len(errs[0]))
        out[label] = rows
    return out


def _state_at(pos: Channel, vel: Channel | None, spl: Any, ts: float) -> tuple[float, float] | None:
    """Initial (position, velocity) at ``ts`` from the data alone: a smoothing spline of the depth
    (``spl``), or the latest heading and yaw-rate samples."""
    if spl is not None:
        return float(spl(ts)), float(spl.derivative()(ts))
    assert vel is not None
    i = int(np.searchsorted(pos.t, ts + 1e-9)) - 1
    j = int(np.searchsorted(vel.t, ts + 1e-9)) - 1
    if i < 0 or j < 0:
        return None
    return float(pos.y[i] + vel.y[j] * (ts - pos.t[i])), float(vel.y[j])


def _predict(data: DiveData, dof: str, model: DofModel, init: tuple[float, float], ts: float,
             horizon: float) -> tuple[np.ndarray, np.ndarray]:
    """The model's position from ``init`` at ``ts`` over ``horizon`` seconds with the logged input:
    (times, positions) on a grid of at most GRID_S."""
    n = max(1, int(math.ceil(horizon / GRID_S - 1e-9)))
    h = horizon / n
    tau = _held(data, ts + h * np.arange(n), _DOF_INDEX[dof]).tolist()
    ps, _ = simulate(model, tau, h, init[0], init[1])
    return ts + h * np.arange(n + 1), np.asarray(ps)


@dataclass(frozen=True, eq=False)
class Trace:
    """One output on the validation segment: the measurements and each model's predictions."""

    output: str  # "depth_m" or "heading_rad"
    t: np.ndarray  # measurement times [s]
    y: np.ndarray  # measurements [m | rad, unwrapped]
    k_step: Mapping[str, tuple[np.ndarray, np.ndarray]]  # model -> (target times, k-step-ahead predictions)
    free: Mapping[str, tuple[np.ndarray, np.ndarray]]  # model -> (times, free-run simulation)
    k: int
    free_start: float


def validation_traces(data: DiveData, models: Mapping[str, Mapping[str, DofModel]], t0: float, t1: float, *,
                      k: int = 10, step_s: float = PREDICTION_STEP_S, every_s: float = 0.5) -> list[Trace]:
    """Depth and heading on [t0, t1] with each model's ``k``-step-ahead predictions (every
    ``every_s``, from the same data-only initial states as :func:`prediction_errors`) and its free
    run from the segment's start (2 s in: the spline's end) with the logged input only. ``models``:
    label -> {dof: DofModel} (e.g. identified, file, published)."""
    from scipy.interpolate import make_smoothing_spline

    out = []
    horizon = k * step_s
    for dof in ("heave", "yaw"):
        pos, vel = data.channel(dof, "position"), data.channel(dof, "velocity")
        use = {lab: m[dof] for lab, m in models.items() if dof in m}
        if pos is None or not use:
            continue
        m = (pos.t >= t0) & (pos.t <= t1)
        if m.sum() < 10:
            continue
        tm, ym = pos.t[m], pos.y[m]
        spl = make_smoothing_spline(tm[0::2], ym[0::2]) if vel is None else None  # as prediction_errors
        targets = np.arange(tm[0] + horizon + 2.0, tm[-1] - 1.0, every_s)
        k_step: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        free: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        ts0 = float(tm[0] + 2.0)
        init0 = _state_at(pos, vel, spl, ts0)
        for lab, mdl in use.items():
            tt, pp = [], []
            for target in targets:
                init = _state_at(pos, vel, spl, float(target - horizon))
                if init is None:
                    continue
                tt.append(float(target))
                pp.append(float(_predict(data, dof, mdl, init, float(target - horizon), horizon)[1][-1]))
            k_step[lab] = (np.asarray(tt), np.asarray(pp))
            if init0 is not None:
                free[lab] = _predict(data, dof, mdl, init0, ts0, float(tm[-1]) - ts0)
        out.append(Trace("depth_m" if dof == "heave" else "heading_rad", tm, ym, k_step, free, k, ts0))
    return out


# --------------------------------------------------------------------------------------------
# Surge and sway (when the log carries position or velocity)
# --------------------------------------------------------------------------------------------
#
# Surge and sway from a dive whose log carries position or velocity (issue 29; the heave / yaw
# part, the refusals and the covariances are rovlab.ident.dive's, reused here).
#
# The model is rovlab.models.kinetics's horizontal rows with roll = pitch = 0, r_g = 0 and no
# current (SNAME signs; M_u = m - X_udot, M_v = m - Y_vdot):
#
#     M_u u_dot = s_X tau_X + M_v v r + (X_u + X_|u|u |u| + X_uuu u^2) u
#     M_v v_dot = s_Y tau_Y - M_u u r + (Y_v + Y_|v|v |v| + Y_vvv v^2) v
#     x_dot = cos(psi) u - sin(psi) v,   y_dot = sin(psi) u + cos(psi) v
#
# The two rows are coupled only through the yaw rate r (Coriolis and the added mass's Munk-free
# part of C_A, Fossen 2011 sec. 6.3-6.4), and the body velocities reach the NED position through
# the heading. Neither is estimated here: the heading and yaw rate the AHRS logged are taken as
# known inputs (interpolated on the model's grid), so the rotation is modelled but costs no
# parameters. rovlab lab plan-dive excites surge and sway in segments where the yaw excitation is
# off and a weak heading law holds the heading (rovlab.ident.plan), so r stays small there and the
# surge and sway parameters do not trade against the Coriolis terms; the model still carries them
# for the yaw segments and whatever the heading law lets through.
#
# Outputs: a DVL's bottom-track body velocity u, v (a ``dvl`` sensor's ``u_<name>``, ``v_<name>``
# columns) and / or a positioning system's NED x, y (``motion_capture`` sensor: USBL, motion
# capture, or ArduSub's LOCAL_POSITION_NED in a MAVLink log). Each 15 s window starts from its own
# fitted u0, v0 (and x0, y0 with a position output): multiple shooting, as for heave and yaw. The
# windows are simulated together (numpy over windows and over the Jacobian's perturbations), RK4
# on the 0.05 s grid with the thrust held over a step and the heading and yaw rate at each stage's
# time.

HORIZONTAL = HORIZONTAL_DOFS
OUTPUT_DOFS = ("surge", "sway", "north", "east")  # Channel.dof of u, v (DVL) and x, y (position)
_STATE = {("surge", "velocity"): 2, ("sway", "velocity"): 3, ("north", "position"): 0, ("east", "position"): 1}
SPEED_FLOOR = 0.03  # m/s: below this largest speed a DOF is not excited
# m/s: below this RMS speed neither. A pilot's dive moves sway at 0.3-1.5 cm/s RMS, mostly the
# Coriolis drift of turns made while moving forward (-M_u u r): on 19 such dives with a DVL, Y_vdot
# came out up to 23 % off and within +-2 sigma in 58 % only; a plan's sway runs at ~6 cm/s RMS
SPEED_RMS_FLOOR = 0.02
HOPELESS = 1.0 / MAX_REL  # a parameter whose sigma exceeds this many refusal thresholds is refused at once


def has_horizontal(data: DiveData) -> bool:
    """Whether the log carries position or velocity (surge/sway can be identified)."""
    return any(c.dof in OUTPUT_DOFS and c.t.size for c in data.channels)


def no_horizontal_reason(data: DiveData, vehicle: Any) -> str:
    sens = sensor_channels(vehicle)
    have = [sens[k][0] for k in ("x", "y", "u", "v") if k in sens]
    cols = (f"its columns {', '.join(have)} are missing or empty" if have else
            f"the vehicle file {vehicle.name} declares no position sensor (a [[sensors]] of kind motion_capture with "
            "x, y: USBL, motion capture, or ArduSub's LOCAL_POSITION_NED) and no DVL (kind dvl with u, v)")
    return (f"{data.file}: surge and sway need position or velocity in the log (a DVL's u, v or a position's x, y); "
            f"{cols}")


class HorizontalProblem:
    """Output error of surge and sway together on [t0, t1]: global parameters (dof, key) and per
    window the initial (u0, v0), with (x0, y0) first when the log has a position output."""

    def __init__(self, data: DiveData, base: Mapping[str, DofModel], free: Sequence[tuple[str, str]],
                 t0: float, t1: float, *, grid_s: float = GRID_S, window_s: float = WINDOW_S) -> None:
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
            raise IdentificationError(f"{data.file}: surge and sway need position or velocity in the log (a DVL's u, v "
                                      "or a position's x, y); it has none")
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
        X = _held(data, tg[:-1], 0)
        Y = _held(data, tg[:-1], 1)
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
        self.windows: list[_Window] = []
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
                self.windows.append(_Window(int(a), int(m), samples))
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
    def models(self, theta: np.ndarray) -> dict[str, DofModel]:
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
            step = 1e-6 * max(abs(theta[i]), _SCALE[k](self.base[d]))
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


def body_speeds(data: DiveData, t0: float, t1: float) -> dict[str, np.ndarray]:
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


def fit_horizontal(data: DiveData, start: Mapping[str, DofModel], dofs: Sequence[str], t0: float, t1: float, *,
                   free: Mapping[str, Sequence[str]], max_rel: float = MAX_REL) -> dict[str, DofFit]:
    """Output-error fit of surge and sway on [t0, t1] (module docstring), with rovlab.ident.dive's
    refusals: a DOF the log does not move is refused whole; a parameter whose sigma is large
    against what it does is held at the file's value and named with the manoeuvre that would
    determine it."""
    speeds = body_speeds(data, t0, t1)
    stats = {d: (float(np.sqrt(np.mean(speeds[d] ** 2))) if speeds[d].size else 0.0,
                 float(np.max(np.abs(speeds[d]))) if speeds[d].size else 0.0) for d in HORIZONTAL}
    out: dict[str, DofFit] = {}
    keys: list[tuple[str, str]] = []
    weak: dict[str, str] = {}
    for dof in dofs:
        chosen = [k for k in KEYS if k in free.get(dof, DEFAULT_FREE) and k != "net_buoyancy"]
        if "added_mass" in chosen and "thrust_scale" in chosen:
            raise IdentificationError(f"{NAMES[dof]['added_mass']} and {NAMES[dof]['thrust_scale']} cannot both "
                                      "be estimated: the motion responds to force / mass only, so no manoeuvre tells "
                                      "a larger added mass from weaker thrust; hold one (measure the thrust with "
                                      "rovlab identify thrust, or keep the file's added mass)")
        s_rms, s_max = stats[dof]
        why = (f"the log does not excite {dof}: its {dof} speed is {s_rms:.3g} m/s RMS, at most {s_max:.3g} m/s "
               f"(need > {SPEED_RMS_FLOOR:g} RMS and {SPEED_FLOOR:g} at most); fly rovlab lab plan-dive --dofs {dof}")
        if s_max < SPEED_FLOOR:
            out[dof] = _refused_dof(dof, start[dof], why, s_rms, s_max)
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
                    f"{NAMES[d][k]}: {v}" for (d, k), v in held.items() if d == dof)
                out[dof] = _refused_dof(dof, start[dof], why, *stats[dof],
                                           refused={k: v for (d, k), v in held.items() if d == dof})
            return out
        prob = HorizontalProblem(data, start, cur, t0, t1)
        weights = prob.sigma.copy()
        th0 = prob.initial()
        lo, hi = prob.bounds()
        th0 = _inside(th0, lo, hi, [_SCALE[k](start[d]) for d, k in cur])
        cost_start = 0.5 * float(np.sum(prob.residuals(th0, weights) ** 2))
        theta, r, sig, cov_hac = _reweighted_fit(prob, th0, lo, hi, weights)
        models = prob.models(theta)
        # refuse the worst-determined parameter and fit again without it; those hopeless (sigma
        # above HOPELESS times the threshold: more than what they do) go at once, which saves the
        # refits of a log that determines nothing (the real surface log: 40 s -> a few)
        ratios = [_determination(k, models[d], sig[i], stats[d][0], max_rel) for i, (d, k) in enumerate(cur)]
        worst_i = int(np.argmax(ratios))
        if not ratios[worst_i] > 1.0:
            break
        for i, ratio in enumerate(ratios):
            if i == worst_i or ratio > HOPELESS:
                d, k = cur[i]
                held[(d, k)] = (f"not determined by this log (sigma {sig[i]:.3g}, {ratio * max_rel * 100:.0f} % of what "
                                f"it does); held at the file's value; to determine it: {_manoeuvre(d, k, stats[d][0])}")
    raw = prob.residuals(theta, np.ones(len(prob.channels)))
    for dof in sorted({d for d, _ in keys}, key=HORIZONTAL.index):
        if dof in weak:  # refused, but its fitted model kept (the yaw fit's Munk moment uses its added mass)
            from dataclasses import replace

            ref = _refused_dof(dof, start[dof], weak[dof], *stats[dof])
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
            name, unit = NAMES[dof][k], UNITS[dof][k]
            if (dof, k) in cur:
                i = cur.index((dof, k))
                params.append(ParamResult(k, name, unit, float(getattr(st, k)), float(theta[i]), float(sig[i]),
                                             "estimated", _at_bound(k, theta[i], lo[i], hi[i])))
            elif (dof, k) in held:
                params.append(ParamResult(k, name, unit, float(getattr(st, k)), float(getattr(st, k)), math.nan,
                                             "refused", held[(dof, k)]))
            else:
                params.append(ParamResult(k, name, unit, float(getattr(st, k)), float(getattr(st, k)), math.nan,
                                             "held", "held at the file's value (not asked for)"))
        mine = [ci for ci, c in enumerate(prob.channels) if c.dof == dof or c.kind == "position"]
        rms = {prob.channels[ci].name: float(np.sqrt(np.mean(raw[prob.channel_of == ci] ** 2)))
               for ci in mine if np.any(prob.channel_of == ci)}
        counts = {prob.channels[ci].name: int(np.sum(prob.channel_of == ci)) for ci in mine}
        if not est:
            why = "no parameter is determined by this log: " + "; ".join(
                f"{NAMES[d][k]}: {v}" for (d, k), v in held.items() if d == dof)
            out[dof] = _refused_dof(dof, st, why, *stats[dof], refused={k: v for (d, k), v in held.items() if d == dof})
            continue
        out[dof] = DofFit(dof, tuple(params), corr, est, models[dof], rms, counts, *stats[dof],
                             windows=len(prob.windows), cost_start=cost_start, cost=0.5 * float(r @ r))
    return {d: out[d] for d in dofs if d in out}


def horizontal_prediction_errors(data: DiveData, identified: Mapping[str, DofModel],
                                 start: Mapping[str, DofModel], t0: float, t1: float, *,
                                 step_s: float = PREDICTION_STEP_S, horizons: Sequence[int] = HORIZONS,
                                 every_s: float = 1.0, published: Mapping[str, DofModel] | None = None,
                                 ) -> dict[str, dict[str, list[float]]]:
    """k-step prediction RMSE on [t0, t1] of the DVL's surge and sway velocity (``u_mps``,
    ``v_mps``) or, without a DVL, of the horizontal position (``position_m``: the distance between
    predicted and measured x, y), for the identified model and the vehicle file's, from the same
    initial states: the latest DVL sample, the latest position sample (moved on by the latest
    velocity), or without a DVL the velocity of a line through the last 2 s of positions.
    ``published``: a third model (surge and sway of rovlab.ident.published), scored as
    ``rows["published"]``."""
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
    keys: tuple[str, ...] = ("identified", "file") + (("published",) if published else ())
    out: dict[str, dict[str, list[float]]] = {lab: {**{key: [] for key in keys}, "n": []} for lab in labels}
    models = (identified, start) + ((published,) if published else ())
    for k in horizons:
        horizon = k * step_s
        targets = tm[(tm >= t0 + horizon + 2.0) & (tm <= tm[-1] - 1.0)][::stride]
        n = max(1, int(round(horizon / GRID_S)))
        hh = horizon / n
        errs: dict[str, list[list[float]]] = {lab: [[] for _ in models] for lab in labels}
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
            X, Y = _held(data, tg, 0), _held(data, tg, 1)
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
            for mi, key in enumerate(keys):
                e = np.asarray(errs[lab][mi])
                out[lab][key].append(float(np.sqrt(np.mean(e**2))) if e.size else math.nan)
            out[lab]["n"].append(len(errs[lab][0]))
    return out


def _simulate_one(su: DofModel, sw: DofModel, X: np.ndarray, Y: np.ndarray, co: np.ndarray, si: np.ndarray,
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


def default_dofs(data: DiveData) -> tuple[str, ...]:
    """heave and yaw, and surge and sway when the log carries position or velocity."""
    return DOFS + (HORIZONTAL if has_horizontal(data) else ())


def fit_requested_horizontal(data: DiveData, vehicle: Any, dofs: Sequence[str],
                             free: Mapping[str, Sequence[str]] | Sequence[str] | None, t0: float, t_split: float, *,
                             max_rel: float = MAX_REL) -> dict[str, DofFit]:
    """identify_dive's surge / sway fits; IdentificationError naming what is
    missing when the log has no position or velocity."""
    want = [d for d in dofs if d in HORIZONTAL]
    if not has_horizontal(data):
        raise IdentificationError(no_horizontal_reason(data, vehicle))
    chosen = {d: (free.get(d, DEFAULT_FREE) if isinstance(free, Mapping) else (free or DEFAULT_FREE))
              for d in want}
    start = {d: dof_model(vehicle, d) for d in HORIZONTAL}
    return fit_horizontal(data, start, want, t0, t_split, free=chosen, max_rel=max_rel)


def merge_horizontal(data: DiveData, vehicle: Any, dofs: Sequence[str], hfits: Mapping[str, DofFit],
                     fits: Mapping[str, DofFit], pred: Mapping[str, Any], t_split: float,
                     t_end: float, compare: Any = None) -> tuple[dict[str, DofFit], dict[str, Any]]:
    """The fits in the order of ``dofs``, and the prediction errors with surge and sway's added
    (``compare``'s too: a rovlab.ident.published.PublishedSet, its values or the file's)."""
    start = {d: dof_model(vehicle, d) for d in HORIZONTAL}
    out = dict(pred)
    if any(not f.refused_dof for f in hfits.values()):
        ident = dict(start)
        for d, f in hfits.items():
            if not f.refused_dof:
                ident[d] = f.model
        published = compare.models(vehicle, tuple(HORIZONTAL)) if compare is not None else None
        out.update(horizontal_prediction_errors(data, ident, start, t_split, t_end, published=published))
    merged = dict(fits) | dict(hfits)
    return {d: merged[d] for d in dofs if d in merged}, out


def body_velocity(data: DiveData, t: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
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


def with_munk_moment(data: DiveData, vehicle: Any, hfits: Mapping[str, DofFit], *,
                     shift: float = 0.0) -> DiveData:
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
        am[dof] = f.model.added_mass if f is not None else float(vehicle.added_mass[_DOF_INDEX[dof]])
    tau = np.array(data.tau, dtype=float, copy=True)
    tau[:, 3] -= (am["surge"] - am["sway"] + shift) * vel[0] * vel[1]
    note = (f"yaw input: with the Munk moment -(X_udot - Y_vdot) u v, X_udot - Y_vdot = {am['surge'] - am['sway']:.4g} "
            "kg, u and v from the log")
    return replace(data, tau=tau, notes=data.notes + (note,))


def with_munk_uncertainty(yaw: DofFit, data: DiveData, vehicle: Any, hfits: Mapping[str, DofFit],
                          refit: Any) -> DofFit:
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


# --------------------------------------------------------------------------------------------
# Vehicle-file edits
# --------------------------------------------------------------------------------------------

def dive_edits(fit: DiveFit, vehicle: Vehicle, *, digits: int = 4) -> dict[str, float]:
    """Vehicle-file values of the estimated parameters (refused and held ones are not written;
    thrust scales have no place in a vehicle file and are reported only)."""
    edits: dict[str, float] = {}
    for dof, f in fit.fits.items():
        for p in f.params:
            if p.status != "estimated":
                continue
            if p.key == "added_mass":
                edits[f"added_mass.{p.name}"] = significant(p.estimate, digits)
            elif p.key in ("linear", "quadratic"):
                edits[f"damping.{dof}.{p.key}"] = significant(p.estimate, digits)
            elif p.key == "net_buoyancy":  # B - W = rho g V - m g
                vol = (p.estimate + vehicle.weight) / (vehicle.water_density * vehicle.gravity)
                edits["restoring.displaced_volume"] = significant(vol, 6)
    return edits


def provenance(fit: DiveFit, log_name: str) -> dict[str, str]:
    """Source notes per vehicle-file block: log, time span, method and standard deviations."""
    a, b = fit.ident_span
    blocks: dict[str, list[str]] = {}
    for f in fit.fits.values():
        for p in f.params:
            if p.status != "estimated":
                continue
            block = {"added_mass": "added_mass", "linear": "damping", "quadratic": "damping",
                     "net_buoyancy": "restoring"}.get(p.key)
            if block:
                blocks.setdefault(block, []).append(f"{p.name} sigma {p.sigma:.2g}")
    head = (f"rovlab identify dive {log_name} (t {a:.1f}-{b:.1f} s; output error, standard deviations robust to "
            "correlated errors)")
    return {blk: f"{head}: {', '.join(items)}" for blk, items in blocks.items()}


# --------------------------------------------------------------------------------------------
# The virtual dive: a plan flown on a hidden vehicle
# --------------------------------------------------------------------------------------------

def hidden_vehicle(vehicle: Vehicle, seed: int, *, spread: float = 0.25, buoyancy_n: float = 2.0) -> Vehicle:
    """A vehicle whose heave and yaw added mass and damping differ from ``vehicle``'s by up to
    +-``spread`` (uniform, each), whose net buoyancy is off by up to +-``buoyancy_n`` N, and whose
    zero linear damping (bluerov2_heavy's yaw: not published) becomes 20 % of the damping at
    1 m/s or rad/s, so that every coefficient has a truth to find. Surge and sway are perturbed
    the same way from a second stream of the seed (so heave and yaw are those of the seed as
    before surge and sway were added)."""
    rng = np.random.default_rng(seed)
    am = np.array(vehicle.added_mass, dtype=float)
    lin = np.array(vehicle.damping_linear, dtype=float)
    quad = np.array(vehicle.damping_quadratic, dtype=float)
    for i in (2, 3):
        am[i] *= rng.uniform(1 - spread, 1 + spread)
        if lin[i] == 0.0:
            lin[i] = 0.2 * quad[i]
        lin[i] *= rng.uniform(1 - spread, 1 + spread)
        quad[i] *= rng.uniform(1 - spread, 1 + spread)
    dv = rng.uniform(-buoyancy_n, buoyancy_n) / (vehicle.water_density * vehicle.gravity)
    rng_h = np.random.default_rng([seed, 1])
    for i in (0, 1):
        am[i] *= rng_h.uniform(1 - spread, 1 + spread)
        if lin[i] == 0.0:
            lin[i] = 0.2 * quad[i]
        lin[i] *= rng_h.uniform(1 - spread, 1 + spread)
        quad[i] *= rng_h.uniform(1 - spread, 1 + spread)
    return vehicle.with_updates(name=f"{vehicle.name} (hidden, seed {seed})", added_mass=am, damping_linear=lin,
                                damping_quadratic=quad, displaced_volume=vehicle.displaced_volume + dv)


def truth_values(vehicle: Vehicle) -> dict[str, float]:
    out = {}
    for dof in ALL_DOFS:
        for k, v in dof_model(vehicle, dof).values().items():
            if k != "thrust_scale":
                out[NAMES[dof][k]] = v
    return out


class _HorizontalSensors:
    """The virtual dive's DVL and / or positioning system and the surge / sway process noise
    (:func:`fly_plan`), drawn from their own random stream."""

    def __init__(self, model: Vehicle, sens: Mapping[str, tuple[str, str, str, float, float]], seed: int | None,
                 noise: bool, h: float, psd: float) -> None:
        self.rng = np.random.default_rng(None if seed is None else [seed, 2])
        self.h = h
        self.sens = {k: sens[k] for k in ("x", "y", "u", "v") if k in sens}
        self.every: dict[str, int] = {}
        for k, (_, name, _, _, _) in self.sens.items():
            self.every[k] = max(1, int(round(1.0 / (model.sensor(name).rate_hz * h))))
        self.sd = {k: (math.sqrt(v[3]) if noise else 0.0) for k, v in self.sens.items()}
        self.sd_force = math.sqrt(psd / h) if noise else 0.0
        self.rows: dict[str, list[float]] = {k: [] for k in self.sens}
        self.dr = [0.0, 0.0]  # dead-reckoned position from the DVL [m]
        self.fix: list[float] | None = None  # the latest positioning fix [m]
        self.dvl_every = self.every.get("u", 0)
        self.notes = [f"{v[0]} at {model.sensor(v[1]).rate_hz:g} Hz (variance {v[3]:.3g})" for v in self.sens.values()]

    def due(self, k: int) -> bool:
        return any(k % e == 0 for e in self.every.values())

    def position(self) -> tuple[float, float]:
        """What the guard knows of the position: the positioning system's latest fix, else the DVL's
        dead reckoning."""
        if self.fix is not None:
            return self.fix[0], self.fix[1]
        return self.dr[0], self.dr[1]

    def sample(self, k: int, x: np.ndarray, heading: float) -> None:
        """One log row at step k: each sensor's sample if it is due (NaN otherwise)."""
        got: dict[str, float] = {}
        for key, state in (("x", 0), ("y", 1), ("u", 4), ("v", 5)):
            if key not in self.sens:
                continue
            val = math.nan
            if k % self.every[key] == 0:
                val = float(x[state] + self.sd[key] * self.rng.standard_normal())
            got[key] = val
            self.rows[key].append(val)
        if "x" in got and "y" in got and math.isfinite(got["x"]) and math.isfinite(got["y"]):
            self.fix = [got["x"], got["y"]]
        if "u" in got and "v" in got and math.isfinite(got["u"]) and math.isfinite(got["v"]):
            dt = self.dvl_every * self.h
            c, s = math.cos(heading), math.sin(heading)
            self.dr[0] += dt * (c * got["u"] - s * got["v"])
            self.dr[1] += dt * (s * got["u"] + c * got["v"])

    def force_noise(self, fx: float, fy: float) -> tuple[float, float]:
        return (fx + self.sd_force * self.rng.standard_normal(), fy + self.sd_force * self.rng.standard_normal())

    def columns(self) -> dict[str, np.ndarray]:
        return {self.sens[k][0]: np.array(v) for k, v in self.rows.items()}

    def note(self) -> str:
        return ("; ".join(self.notes) + f"; surge/sway process noise PSD {self.sd_force**2 * self.h:g} N^2/Hz"
                + ("; the box guard's position dead-reckoned from the DVL" if "x" not in self.sens else ""))


@dataclass(frozen=True, eq=False)
class Flight:
    """What a flown plan logged: columns (time_s, pwm_<thruster>, sensor columns) and the truth."""

    columns: Mapping[str, np.ndarray]
    truth: Mapping[str, float]
    guard_s: float  # seconds the depth guard held the excitation
    depth_range: tuple[float, float]  # true depth reached
    notes: tuple[str, ...] = ()
    states: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))  # t, x(8): the true state per row


def fly_plan(plan: Any, model: Vehicle, truth: Vehicle, *, seed: int | None = 0, noise: bool = True,
             plant_step_s: float = 0.01, process_psd: Sequence[float] = (1e-2, 1e-6),
             depth_rate_hz: float = 2.0, heading_rate_hz: float = 20.0, pwm_resolution_us: float = 1.0,
             ahrs_tau_s: float = AHRS_TAU_S, process_psd_horizontal: float = 1e-2) -> Flight:
    """Fly ``plan`` (rovlab.ident.plan.DivePlan) on ``truth`` with the allocation and the thrust
    curves of ``model`` turning the wrench into PWM (module docstring). ``noise=False``: no sensor
    or process noise (the planner's nominal flight). ``process_psd``: white force noise on heave
    [N^2/Hz] and yaw [(N m)^2/Hz] (the packaged bluerov2-heavy-step scenario's values).

    A surge and sway plan is flown with the heading law and the box guard (rovlab.ident.plan), white
    force noise of ``process_psd_horizontal`` [N^2/Hz] on surge and sway, and the model vehicle's
    horizontal sensors at their files' rates and variances: a DVL's bottom-track u, v (the guard's
    position then dead-reckoned from them and the AHRS heading) and / or a positioning system's
    x, y (motion_capture kind). Those draws come from a second random stream of the seed, so the
    heave and yaw of a heave and yaw plan are what they were."""
    from rovlab.allocation.geometry import configuration_matrix
    from rovlab.allocation.solvers import Allocator
    from rovlab.core.angles import wrap as wrap_angle
    from rovlab.models.kinetics import pack, rk4_inplace
    from rovlab.models.thrusters import ThrusterBank

    rng = np.random.default_rng(seed)
    alloc = Allocator(model)
    bank_true = ThrusterBank.from_vehicle(truth)
    B_true = configuration_matrix(truth)
    p = pack(truth)
    sens = sensor_channels(model)
    if "depth" not in sens:
        raise ValueError(f"vehicle {model.name!r} has no pressure sensor: a dive needs depth")
    dt = float(plan.dt)
    sub = int(round(dt / plant_step_s))
    if sub < 1 or abs(sub * plant_step_s - dt) > 1e-9:
        raise ValueError(f"the plan's command step {dt:g} s must be a multiple of the plant step {plant_step_s:g} s")
    n_cmd = len(plan.Z)
    h = plant_step_s
    depth_every = int(round(1.0 / (depth_rate_hz * h)))
    head_every = int(round(1.0 / (heading_rate_hz * h)))
    x = np.zeros(8)
    x[2] = plan.start_depth
    x[3] = 0.3  # heading at the start [rad] (any)
    f = np.zeros(4)
    names = model.thruster_names
    rows_t: list[float] = []
    rows_pwm: list[np.ndarray] = []
    rows: dict[str, list[float]] = {k: [] for k in ("depth", "heading", "rate")}
    states: list[np.ndarray] = []
    var_z = sens["depth"][3] if noise else 0.0
    res_z = sens["depth"][4]
    lz = float(model.sensor(sens["depth"][1]).position[2])
    sd_psi = math.sqrt(sens["heading"][3]) if noise and "heading" in sens else 0.0
    sd_r = math.sqrt(sens["rate"][3]) if noise and "rate" in sens else 0.0
    phi = math.exp(-head_every * h / ahrs_tau_s)
    ahrs = sd_psi * rng.standard_normal()
    sd_proc = [math.sqrt(process_psd[0] / h), math.sqrt(process_psd[1] / h)] if noise else [0.0, 0.0]
    flyer = plan.flyer()
    z_meas = float(x[2] + lz)
    horiz = bool(getattr(plan, "horizontal", False))
    # the horizontal sensors log on any plan (a DVL does not stop for a heave and yaw plan); the
    # heading law and box guard fly only a surge / sway plan
    hs = (_HorizontalSensors(model, sens, seed, noise, h, process_psd_horizontal)
          if horiz or any(k in sens for k in ("x", "y", "u", "v")) else None)
    head_last, rate_last = float(wrap_angle(x[3] + ahrs)), 0.0
    guard_steps = 0
    zmin, zmax = x[2], x[2]
    pwm = np.full(len(names), 1500.0)
    for k in range(n_cmd * sub):
        if k % sub == 0:
            if hs is not None and horiz:
                tau, guarded = flyer.step(k // sub, z_meas - lz, heading=head_last, rate=rate_last,
                                          position=hs.position())
            else:
                tau, guarded = flyer.step(k // sub, z_meas - lz)
            guard_steps += int(guarded)
            res = alloc.allocate(np.asarray(tau, dtype=float))
            pwm = res.pwm_us
            if pwm_resolution_us > 0:
                pwm = pwm_resolution_us * np.round(pwm / pwm_resolution_us)
            f6 = B_true @ bank_true.force(pwm)
            real = f6[[0, 1, 2, 5]]
        t = k * h
        if k % depth_every == 0 or k % head_every == 0 or k % sub == 0 or (hs is not None and hs.due(k)):
            rows_t.append(t)
            rows_pwm.append(pwm.copy())
            states.append(np.concatenate([[t], x]))
            z_new = math.nan
            if k % depth_every == 0:
                z_new = x[2] + lz + math.sqrt(var_z) * rng.standard_normal()
                if res_z > 0:
                    z_new = res_z * round(z_new / res_z)
                z_meas = z_new
            rows["depth"].append(z_new)
            if k % head_every == 0 and "heading" in sens:
                ahrs = phi * ahrs + sd_psi * math.sqrt(1 - phi * phi) * rng.standard_normal()
                rows["heading"].append(float(wrap_angle(x[3] + ahrs)))
                rows["rate"].append(x[7] + sd_r * rng.standard_normal())
                head_last, rate_last = rows["heading"][-1], rows["rate"][-1]
            else:
                rows["heading"].append(math.nan)
                rows["rate"].append(math.nan)
            if hs is not None:
                hs.sample(k, x, head_last)
        f[0], f[1] = real[0], real[1]
        f[2] = real[2] + sd_proc[0] * rng.standard_normal()
        f[3] = real[3] + sd_proc[1] * rng.standard_normal()
        if hs is not None:
            f[0], f[1] = hs.force_noise(real[0], real[1])
        rk4_inplace(p, x, f, h)
        zmin, zmax = min(zmin, x[2]), max(zmax, x[2])
    cols: dict[str, np.ndarray] = {"time_s": np.array(rows_t)}
    P = np.array(rows_pwm)
    for i, n in enumerate(names):
        cols[f"pwm_{n}"] = P[:, i]
    for key in ("depth", "heading", "rate"):
        if key in sens:
            cols[sens[key][0]] = np.array(rows[key])
    if hs is not None:
        cols.update(hs.columns())
    notes = (f"depth {sens['depth'][0]} at {depth_rate_hz:g} Hz (variance {sens['depth'][3]:.3g} m^2, resolution "
             f"{res_z:g} m); AHRS heading at {heading_rate_hz:g} Hz with a Gauss-Markov error ({ahrs_tau_s:g} s); "
             f"PWM quantised to {pwm_resolution_us:g} us; process noise PSD heave {process_psd[0]:g} N^2/Hz, yaw "
             f"{process_psd[1]:g} (N m)^2/Hz" if noise else "no noise (nominal flight)",)
    extra: tuple[str, ...] = (hs.note(),) if hs is not None else ()
    return Flight(cols, truth_values(truth), guard_steps * dt, (float(zmin), float(zmax)), notes + extra,
                  np.array(states))
