"""The virtual lab: realistic data for every experiment of Sandøy 2016, sec. 2.3 and ch. 4, from any vehicle file.

No lab data from the thesis survives, so each identification tool is proven on data generated
here from a vehicle whose true parameters are known (rovlab's own addition), and users can
rehearse an experiment before booking the basin. Every rig is seeded (numpy ``Generator``); the
seed, the settings and the true parameters go into the file's ``#`` comment lines.

Rigs (defaults follow the thesis; every duration is configurable so tests run short versions):

* ``thrust_rig``: load-cell staircase (Sandøy 2016, sec. 2.3): PWM set-point 1300 -> 1700 us in 10 us steps,
  30 s each; the ESC sees a first-order low-pass of the set-point; true thrust from
  ``rovlab.models.thrusters`` (quadratic or tabulated T200 alike); the load cell is a first-order
  low-pass plus white noise. Several thrusters on the rig at once give their summed force.
* ``towing_runs``: carriage runs (Sandøy 2016, sec. 4.3.1) ramping to five positive and five negative speeds,
  force = vehicle damping + rig drag + inertia during ramps + a per-run load-cell offset (+ net
  buoyancy in heave) through the load cell; plus rig-only runs.
* ``yaw_runs``: constant moments (0.25, 0.5, 0.75, 1, 2 N m) integrating
  (I_zz - N_rdot) r_dot = N_r r + N_|r|r |r| r + N_rrr r^3 + N, heading wrapped to (-pi, pi] with
  motion-capture noise.
* ``relay_test``: a relay on position switches a constant force back and forth (Sandøy 2016, sec. 4.2.2); the
  4-DOF model of ``rovlab.models.kinetics`` (full nonlinear damping, or linear-only on request)
  is integrated with RK4 and the position is observed by motion capture with the vehicle file's
  variance.
* ``resting_log``: every sensor channel of the vehicle file at rest, white noise with the file's
  variance plus a slow linear drift.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.angles import wrap as wrap_angle
from rovlab.params.vehicle import DOF4, Vehicle

# Fallbacks when a vehicle file lacks a sensor: uDrone's Qualisys (thesis table 4.8).
QUALISYS_VARIANCE = {"x": 2.727425e-08, "y": 2.584928e-08, "z": 1.987803e-09, "psi": 1.641552e-06}
DOF_POSITION_CHANNEL = {"surge": "x", "sway": "y", "heave": "z", "yaw": "psi"}


@dataclass(frozen=True, eq=False)
class LabData:
    """One generated data file: columns, the truth it came from, and how it was made."""

    experiment: str
    columns: Mapping[str, np.ndarray]
    truth: Mapping[str, float]
    settings: Mapping[str, Any]
    seed: int
    vehicle: str
    formats: Mapping[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def comments(self) -> list[str]:
        lines = [f"rovlab virtual lab: {self.experiment}", f"vehicle = {self.vehicle}", f"seed = {self.seed}"]
        lines += [f"setting.{k} = {_show(v)}" for k, v in self.settings.items()]
        lines += [f"truth.{k} = {_show(v)}" for k, v in self.truth.items()]
        lines += [f"note: {n}" for n in self.notes]
        return lines


def _show(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.9g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_show(x) for x in v) + "]"
    return str(v)


def write_lab_data(path: str | Path, data: LabData) -> Path:
    from rovlab.io.tables import write_table

    return write_table(path, data.columns, comments=data.comments(), formats=data.formats)


def new_seed() -> int:
    """A fresh seed to record (so the run can be replayed)."""
    entropy = np.random.SeedSequence().entropy
    return int(entropy) % (2**32)  # type: ignore[arg-type]  # an int for a fresh SeedSequence


MAX_ROWS = 2_000_000  # more rows than this is a typo (and a long wait), not an experiment


def _number(name: str, value: float, *, positive: bool = False, nonnegative: bool = False,
            nonzero: bool = False) -> float:
    """``value`` as a float, or ValueError naming the parameter and what it must be."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    ok = math.isfinite(x) and (not positive or x > 0) and (not nonnegative or x >= 0) and (not nonzero or x != 0)
    if not ok:
        kind = "positive" if positive else "non-negative" if nonnegative else "non-zero" if nonzero else "finite"
        raise ValueError(f"{name} must be a {kind} finite number, got {x:g}")
    return x


def _check_rows(rows: float, what: str) -> None:
    if rows > MAX_ROWS:
        raise ValueError(f"the {what} would have {rows:.3g} rows, more than the {MAX_ROWS} a lab file may have; "
                         "shorten the experiment or lower the sampling rate")


def _rng(seed: int | None) -> tuple[np.random.Generator, int]:
    s = new_seed() if seed is None else int(seed)
    return np.random.default_rng(s), s


def _first_order(x: np.ndarray, h: float, tau: float, y0: float | None = None) -> np.ndarray:
    """Exact discrete first-order low-pass of a piecewise-constant input (ZOH), time constant tau."""
    from scipy.signal import lfilter

    if tau <= 0:
        return np.asarray(x, dtype=float).copy()
    e = math.exp(-h / tau)
    y0 = float(x[0]) if y0 is None else y0
    # direct form II transposed with b0 = 0: the state is the output, so zi = [y0] gives y[0] = y0
    y, _ = lfilter([0.0, 1 - e], [1.0, -e], np.asarray(x, dtype=float), zi=np.array([y0]))
    return y


# --------------------------------------------------------------------------------------------
# Thrust rig
# --------------------------------------------------------------------------------------------

def thrust_curve_of(vehicle: Vehicle, name: str, pwm_us: np.ndarray) -> np.ndarray:
    """True thrust [N] of one thruster of the vehicle for PWM commands (its own model)."""
    from rovlab.models.thrusters import ThrusterBank, bank_force

    thr = vehicle.thruster(name)
    bank = ThrusterBank.from_thrusters([thr])
    grid = np.arange(thr.pwm_min_us, thr.pwm_max_us + 0.05, 0.1)
    out = np.empty(grid.size)
    one = np.empty(1)
    for i, p in enumerate(grid):
        one[0] = p
        out[i] = bank_force(bank.rows, bank.grid_pwm, bank.grid_force, one)[0]
    return np.interp(pwm_us, grid, out)


def thrust_rig(vehicle: Vehicle, thrusters: Sequence[str] | str | None = None, *, seed: int | None = None,
               pwm_start: float = 1300.0, pwm_stop: float = 1700.0, pwm_step: float = 10.0, step_s: float = 30.0,
               rate_hz: float = 50.0, command_tau_s: float = 1.0, cell_tau_s: float = 0.1,
               noise_std_n: float = 0.3) -> LabData:
    """Load-cell log ``time_s, pwm_us, force_n`` of a PWM staircase (Sandøy 2016, sec. 2.3).

    ``thrusters``: one name or several mounted together (their forces add: identify with --pair).
    """
    rng, seed = _rng(seed)
    names = [thrusters] if isinstance(thrusters, str) else list(thrusters or [vehicle.thrusters[0].name])
    for n in names:
        vehicle.thruster(n)  # KeyError with the list of names
    pwm_start = _number("pwm_start", pwm_start, positive=True)
    pwm_stop = _number("pwm_stop", pwm_stop, positive=True)
    pwm_step = _number("pwm_step", pwm_step, positive=True)
    step_s = _number("step_s", step_s, positive=True)
    rate_hz = _number("rate_hz", rate_hz, positive=True)
    command_tau_s = _number("command_tau_s", command_tau_s, nonnegative=True)
    cell_tau_s = _number("cell_tau_s", cell_tau_s, nonnegative=True)
    noise_std_n = _number("noise_std_n", noise_std_n, nonnegative=True)
    for n in names:
        thr = vehicle.thruster(n)
        lo, hi = min(pwm_start, pwm_stop), max(pwm_start, pwm_stop)
        if lo < thr.pwm_min_us or hi > thr.pwm_max_us:
            raise ValueError(f"the staircase {pwm_start:g} -> {pwm_stop:g} us leaves thruster {n}'s PWM range "
                             f"{thr.pwm_min_us:g}..{thr.pwm_max_us:g} us")
    _check_rows((abs(pwm_stop - pwm_start) / pwm_step + 1) * step_s * rate_hz, "thrust log")
    sign = 1.0 if pwm_stop >= pwm_start else -1.0
    levels = np.arange(pwm_start, pwm_stop + sign * 1e-9, sign * pwm_step)
    h = 1.0 / rate_hz
    per = int(round(step_s * rate_hz))
    setpoint = np.repeat(levels, per)
    t = h * np.arange(setpoint.size)
    neutral = vehicle.thruster(names[0]).pwm_neutral_us
    command = _first_order(setpoint, h, command_tau_s, y0=neutral)
    force: np.ndarray = np.sum([thrust_curve_of(vehicle, n, command) for n in names], axis=0)
    cell = _first_order(force, h, cell_tau_s, y0=0.0) + noise_std_n * rng.standard_normal(t.size)
    truth: dict[str, float] = {}
    thr = vehicle.thruster(names[0])
    if thr.model == "quadratic" and thr.curve is not None:
        truth = {"K_L_pos": thr.curve.K_L_pos, "K_NL_pos": thr.curve.K_NL_pos, "K_L_neg": thr.curve.K_L_neg,
                 "K_NL_neg": thr.curve.K_NL_neg, "deadband_us": thr.deadband_us}
    notes: tuple[str, ...] = () if truth else (f"{thr.name} is tabulated ({thr.table} at {thr.voltage:g} V): "
                                               "the truth is the table, "
                              "not a quadratic curve",)
    if truth and thr.deadband_kind == "cut":
        notes += (f"{thr.name}'s dead band is cut (its curve is of the whole offset from neutral), the fit's is "
                  "shifted: the fit does not reproduce it",)
    if len(names) > 1:
        notes += (f"{len(names)} thrusters on the rig together ({', '.join(names)}): identify with --pair {len(names)}",)
        def curve_of(t: Any) -> tuple:
            c = t.curve
            coefs = (c.K_L_pos, c.K_NL_pos, c.K_L_neg, c.K_NL_neg) if c is not None else None
            return (t.model, coefs, t.table, t.voltage, t.deadband_us, t.deadband_kind, t.pwm_neutral_us)

        if any(curve_of(vehicle.thruster(n)) != curve_of(thr) for n in names[1:]):
            notes += (f"{', '.join(names)} do not share one thrust curve: --pair fits their average, and the truth "
                      f"above is {names[0]}'s",)
    return LabData("thrust", {"time_s": t, "pwm_us": setpoint, "force_n": cell}, truth,
                   {"thrusters": ",".join(names), "pwm_start": pwm_start, "pwm_stop": pwm_stop, "pwm_step": pwm_step,
                    "step_s": step_s, "rate_hz": rate_hz, "command_tau_s": command_tau_s, "cell_tau_s": cell_tau_s,
                    "noise_std_n": noise_std_n},
                   seed, vehicle.name, {"pwm_us": ".6g"}, notes)


# --------------------------------------------------------------------------------------------
# Towing carriage
# --------------------------------------------------------------------------------------------

DEFAULT_SPEEDS = (0.1, -0.1, 0.2, -0.2, 0.3, -0.3, 0.4, -0.4, 0.5, -0.5)


def _carriage_profile(speed: float, h: float, rest_s: float, accel: float,
                      hold_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, speed and acceleration of one run: rest, ramp, hold, ramp down, rest."""
    ramp_s = abs(speed) / accel
    total = rest_s + ramp_s + hold_s + ramp_s + rest_s
    t = h * np.arange(int(round(total / h)) + 1)
    t1, t2, t3 = rest_s, rest_s + ramp_s, rest_s + ramp_s + hold_s
    s = np.sign(speed)
    v = np.select([t < t1, t < t2, t < t3, t < t3 + ramp_s],
                  [0.0, s * accel * (t - t1), speed, speed - s * accel * (t - t3)], 0.0)
    a = np.select([t < t1, t < t2, t < t3, t < t3 + ramp_s], [0.0, s * accel, 0.0, -s * accel], 0.0)
    return t, v, a


def towing_runs(vehicle: Vehicle, dof: str = "surge", *, seed: int | None = None,
                speeds: Sequence[float] = DEFAULT_SPEEDS, rate_hz: float = 50.0, rest_s: float = 3.0,
                accel_mps2: float = 0.2, hold_s: float = 15.0, rig_linear: float = -1.0,
                rig_quadratic: float = -6.0, cell_tau_s: float = 0.1, noise_std_n: float = 0.15,
                speed_noise_mps: float = 0.002, offset_std_n: float = 0.3) -> tuple[LabData, LabData]:
    """(vehicle runs, rig-only runs), each ``run, time_s, speed_mps, force_n`` (Sandøy 2016, sec. 4.3.1).

    force_n is the force the carriage applies along the DOF's positive axis: it balances the
    vehicle's SNAME damping, the rig's drag (``rig_linear`` v + ``rig_quadratic`` |v| v), and
    accelerates the vehicle with its added mass on the ramps; each run has a random load-cell
    offset (and, in heave, the net buoyancy B - W), which the tool tares away at rest.
    """
    if dof not in ("surge", "sway", "heave"):
        raise ValueError(f"towing DOF must be surge, sway or heave, got {dof!r}")
    if len(speeds) == 0:
        raise ValueError("towing needs at least one speed")
    speeds = [_number("towing speeds", s, nonzero=True) for s in speeds]
    rate_hz = _number("rate_hz", rate_hz, positive=True)
    rest_s = _number("rest_s", rest_s, nonnegative=True)
    accel_mps2 = _number("accel_mps2", accel_mps2, positive=True)
    hold_s = _number("hold_s", hold_s, positive=True)
    for name, value in (("rig_linear", rig_linear), ("rig_quadratic", rig_quadratic)):
        _number(name, value)
    for name, value in (("cell_tau_s", cell_tau_s), ("noise_std_n", noise_std_n),
                        ("speed_noise_mps", speed_noise_mps), ("offset_std_n", offset_std_n)):
        _number(name, value, nonnegative=True)
    _check_rows(sum(2 * rest_s + 2 * abs(v) / accel_mps2 + hold_s for v in speeds) * rate_hz, "towing log")
    rng, seed = _rng(seed)
    i = DOF4.index(dof)
    lin, quad, cub = (float(vehicle.damping_linear[i]), float(vehicle.damping_quadratic[i]),
                      float(vehicle.damping_cubic[i]))
    inertia = vehicle.mass - float(vehicle.added_mass[i])
    static = (vehicle.buoyancy - vehicle.weight) if dof == "heave" else 0.0
    h = 1.0 / rate_hz

    def runs(with_vehicle: bool) -> dict[str, np.ndarray]:
        cols: dict[str, list[np.ndarray]] = {"run": [], "time_s": [], "speed_mps": [], "force_n": []}
        for k, v_set in enumerate(speeds, start=1):
            t, v, a = _carriage_profile(float(v_set), h, rest_s, accel_mps2, hold_s)
            f = -(rig_linear * v + rig_quadratic * np.abs(v) * v)
            if with_vehicle:
                f = f + inertia * a - (lin * v + quad * np.abs(v) * v + cub * v**3) + static
            f = f + offset_std_n * rng.standard_normal()
            meas = _first_order(f, h, cell_tau_s) + noise_std_n * rng.standard_normal(t.size)
            cols["run"].append(np.full(t.size, k))
            cols["time_s"].append(t)
            cols["speed_mps"].append(v + speed_noise_mps * rng.standard_normal(t.size))
            cols["force_n"].append(meas)
        return {k: np.concatenate(v) for k, v in cols.items()}

    settings = {"dof": dof, "speeds": list(speeds), "rate_hz": rate_hz, "rest_s": rest_s, "accel_mps2": accel_mps2,
                "hold_s": hold_s, "rig_linear": rig_linear, "rig_quadratic": rig_quadratic, "cell_tau_s": cell_tau_s,
                "noise_std_n": noise_std_n, "speed_noise_mps": speed_noise_mps, "offset_std_n": offset_std_n}
    truth = {"linear": lin, "quadratic": quad, "cubic": cub}
    fmt = {"run": "d", "speed_mps": ".6g"}
    veh = LabData("towing", runs(True), truth, settings, seed, vehicle.name, fmt)
    rig = LabData("towing (rig only)", runs(False), {"rig_linear": rig_linear, "rig_quadratic": rig_quadratic},
                  settings, seed, vehicle.name, fmt)
    return veh, rig


# --------------------------------------------------------------------------------------------
# 1-DOF integration on the 4-DOF model
# --------------------------------------------------------------------------------------------

def _integration_vehicle(vehicle: Vehicle, dof: str, linear: bool) -> Vehicle:
    if not linear:
        return vehicle
    i = DOF4.index(dof)
    quad = np.array(vehicle.damping_quadratic)
    cub = np.array(vehicle.damping_cubic)
    quad[i] = 0.0
    cub[i] = 0.0
    return vehicle.with_updates(damping_quadratic=quad, damping_cubic=cub)


_TEST_DEPTH = 5.0  # [m] centre depth in the virtual tank tests: deep enough that the free surface never cuts the hull


def _simulate_1dof(vehicle: Vehicle, dof: str, force_fn, duration_s: float, rate_hz: float,
                   substeps: int = 10, extra_force: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Integrate the 4-DOF model with a force on one DOF (net buoyancy cancelled unless heave).

    ``extra_force`` is an unlogged constant force on the DOF (e.g. a buoyancy error).
    ``force_fn(k, position, velocity) -> force`` is evaluated at each sample and held (ZOH).
    Returns time, force per sample, true position and velocity of that DOF at the samples.
    """
    from rovlab.models.kinetics import pack, rk4_step

    p = pack(vehicle)
    i = DOF4.index(dof)
    bias = np.zeros(4)
    if dof != "heave":
        bias[2] = vehicle.buoyancy - vehicle.weight  # hold depth: only the tested DOF moves
    bias[i] += extra_force
    n = int(round(duration_s * rate_hz)) + 1
    h = 1.0 / rate_hz / substeps
    x = np.zeros(8)
    x[2] = _TEST_DEPTH  # in the basin, well below the free surface
    x0 = x.copy()
    t = np.arange(n) / rate_hz
    pos, vel, frc = np.empty(n), np.empty(n), np.empty(n)
    tau = np.zeros(4)
    for k in range(n):
        pos[k], vel[k] = x[i] - x0[i], x[4 + i]  # position relative to the start
        frc[k] = force_fn(k, pos[k], vel[k])
        tau[i] = frc[k]
        for _ in range(substeps):
            x = rk4_step(p, x, tau, bias, h)
    return t, frc, pos, vel


def _position_variance(vehicle: Vehicle, dof: str) -> tuple[float, float, str]:
    """(variance, rate_hz, note) of the motion-capture channel observing the DOF."""
    ch = DOF_POSITION_CHANNEL[dof]
    for s in vehicle.sensors:
        if s.kind == "motion_capture" and ch in s.variance:
            return (float(s.variance[ch]), float(s.rate_hz),
                    f"observed by motion capture {s.name!r}: {ch} variance {float(s.variance[ch]):.4g} at {s.rate_hz:g} Hz")
    return QUALISYS_VARIANCE[ch], 10.0, (f"{vehicle.name} has no motion-capture sensor with {ch}: uDrone's Qualisys "
                                         "variance at 10 Hz (thesis table 4.8) is used")


# --------------------------------------------------------------------------------------------
# Yaw runs
# --------------------------------------------------------------------------------------------

DEFAULT_MOMENTS = (0.25, 0.5, 0.75, 1.0, 2.0)


def yaw_runs(vehicle: Vehicle, *, seed: int | None = None, moments: Sequence[float] = DEFAULT_MOMENTS,
             rest_s: float = 2.0, duration_s: float = 30.0, rate_hz: float | None = None,
             heading_variance: float | None = None, moment_error: float = 0.0) -> LabData:
    """Constant-moment runs ``run, time_s, moment_nm, heading_rad`` (Sandøy 2016, sec. 4.3.2).

    ``moment_nm`` logs the commanded moment; the moment the thrusters really apply differs from
    it by a random factor per run (relative standard deviation ``moment_error``: open-loop
    allocation and thrust-curve errors, which the thesis names as the main limit of this test).
    """
    if len(moments) == 0:
        raise ValueError("yaw runs need at least one moment")
    moments = [_number("moments", m, nonzero=True) for m in moments]
    rest_s = _number("rest_s", rest_s, nonnegative=True)
    duration_s = _number("duration_s", duration_s, positive=True)
    moment_error = _number("moment_error", moment_error, nonnegative=True)
    rng, seed = _rng(seed)
    var, rate, note = _position_variance(vehicle, "yaw")
    var = var if heading_variance is None else _number("heading_variance", heading_variance, nonnegative=True)
    rate = rate if rate_hz is None else _number("rate_hz", rate_hz, positive=True)
    _check_rows(len(moments) * (rest_s + duration_s) * rate, "yaw log")
    cols: dict[str, list[np.ndarray]] = {"run": [], "time_s": [], "moment_nm": [], "heading_rad": []}
    k_on = int(round(rest_s * rate))
    for run, m in enumerate(moments, start=1):
        applied = m * (1.0 + moment_error * rng.standard_normal())
        t, frc, pos, _ = _simulate_1dof(vehicle, "yaw", lambda k, x, v, a=applied: a if k >= k_on else 0.0,
                                        rest_s + duration_s, rate)
        psi0 = rng.uniform(-np.pi, np.pi)
        cols["run"].append(np.full(t.size, run))
        cols["time_s"].append(t)
        cols["moment_nm"].append(np.where(t >= t[k_on], m, 0.0))
        cols["heading_rad"].append(wrap_angle(psi0 + pos + math.sqrt(var) * rng.standard_normal(t.size)))
    i = DOF4.index("yaw")
    truth = {"linear": float(vehicle.damping_linear[i]), "quadratic": float(vehicle.damping_quadratic[i]),
             "cubic": float(vehicle.damping_cubic[i])}
    return LabData("yaw", {k: np.concatenate(v) for k, v in cols.items()}, truth,
                   {"moments": list(moments), "rest_s": rest_s, "duration_s": duration_s, "rate_hz": rate,
                    "heading_variance": var, "moment_error": moment_error}, seed, vehicle.name, {"run": "d"}, (note,))


# --------------------------------------------------------------------------------------------
# Relay / step test
# --------------------------------------------------------------------------------------------

def relay_test(vehicle: Vehicle, dof: str = "surge", *, seed: int | None = None, force: float = 2.0,
               amplitude: float = 0.3, duration_s: float = 60.0, rate_hz: float | None = None,
               linear: bool = False, position_variance: float | None = None,
               buoyancy_error_n: float = 1.0) -> LabData:
    """Relay test: a constant force switched on position at +-amplitude (Sandøy 2016, sec. 4.2.2).

    In heave the relay switches around a trim force B - W taken from the vehicle file, while the
    simulated vehicle is ``buoyancy_error_n`` more buoyant than the file says (the thesis found
    its buoyancy a few hundred grams off); identify with ``--fit-bias``. The truth ``bias`` is the
    constant force on the DOF that the log does not show: W - B - buoyancy_error_n in heave.

    Columns ``time_s, force_n, position_m`` (``time_s, moment_nm, heading_rad`` for yaw, heading
    wrapped). ``linear=True`` drops the quadratic and cubic damping of the DOF from the truth.
    Truth: ``gain`` k = 1/(m - X_udot), ``pole`` a = -X_u/(m - X_udot), ``added_mass``,
    ``linear_damping`` and the ``mass`` (I_zz for yaw) to pass to ``identify step``.
    """
    if dof not in DOF4:
        raise ValueError(f"DOF must be one of {', '.join(DOF4)}, got {dof!r}")
    force = _number("relay force", force, positive=True)
    amplitude = _number("relay amplitude", amplitude, positive=True)
    duration_s = _number("duration_s", duration_s, positive=True)
    buoyancy_error_n = _number("buoyancy_error_n", buoyancy_error_n)
    rng, seed = _rng(seed)
    var, rate, note = _position_variance(vehicle, dof)
    var = var if position_variance is None else _number("position_variance", position_variance, nonnegative=True)
    rate = rate if rate_hz is None else _number("rate_hz", rate_hz, positive=True)
    _check_rows(duration_s * rate, "relay log")
    truth_vehicle = _integration_vehicle(vehicle, dof, linear)
    trim = (vehicle.buoyancy - vehicle.weight) if dof == "heave" else 0.0
    extra = -buoyancy_error_n if dof == "heave" else 0.0
    state = {"sign": 1.0}

    def relay(k: int, x: float, v: float) -> float:
        if x >= amplitude:
            state["sign"] = -1.0
        elif x <= -amplitude:
            state["sign"] = 1.0
        return trim + state["sign"] * force

    t, frc, pos, _ = _simulate_1dof(truth_vehicle, dof, relay, duration_s, rate, extra_force=extra)
    switches = int(np.sum(np.diff(frc) != 0))
    if switches < 2:
        raise ValueError(f"the relay switched {switches} time(s) in {duration_s:g} s: a force of {force:g} does not "
                         f"drive the {dof} position to +-{amplitude:g} and back (a larger force, a smaller "
                         "amplitude or a longer test; in heave the force must beat the buoyancy error)")
    i = DOF4.index(dof)
    m = vehicle.I_zz if dof == "yaw" else vehicle.mass
    M = m - float(vehicle.added_mass[i])
    truth = {"gain": 1.0 / M, "pole": -float(vehicle.damping_linear[i]) / M, "added_mass": float(vehicle.added_mass[i]),
             "linear_damping": float(vehicle.damping_linear[i]), "mass": m,
             "quadratic": 0.0 if linear else float(vehicle.damping_quadratic[i]),
             "cubic": 0.0 if linear else float(vehicle.damping_cubic[i]),
             "bias": (vehicle.weight - vehicle.buoyancy + extra) if dof == "heave" else 0.0}
    meas = pos + math.sqrt(var) * rng.standard_normal(t.size)
    if dof == "yaw":
        cols = {"time_s": t, "moment_nm": frc, "heading_rad": wrap_angle(meas)}
    else:
        cols = {"time_s": t, "force_n": frc, "position_m": meas}
    notes = (note,) + (() if linear else ("nonlinear damping in the truth: the first-order model is an "
                                          "equivalent linearisation (biased added mass and damping)",))
    return LabData("step", cols, truth, {"dof": dof, "force": force, "amplitude": amplitude,
                                         "duration_s": duration_s, "rate_hz": rate, "linear": linear,
                                         "position_variance": var, "trim": trim, "buoyancy_error_n": buoyancy_error_n},
                   seed, vehicle.name, {}, notes)


# --------------------------------------------------------------------------------------------
# Resting sensor log
# --------------------------------------------------------------------------------------------

REST_LEVEL = {"x": 2.0, "y": -1.0, "z": 1.2, "phi": 0.01, "theta": -0.02, "psi": 0.9, "u": 0.0, "v": 0.0,
              "w": 0.0, "r": 0.0}


def resting_log(vehicle: Vehicle, *, seed: int | None = None, samples: int = 6796, rate_hz: float | None = None,
                drift_sigmas: float = 3.0) -> LabData:
    """``time_s`` and ``<channel>_<sensor>`` columns of the vehicle at rest (Sandøy 2016, sec. 4.4.1).

    Each channel: its rest value + white noise with the vehicle file's variance + a linear drift
    of ``drift_sigmas`` standard deviations over the log (random sign).
    """
    if not vehicle.sensors:
        raise ValueError(f"vehicle {vehicle.name!r} has no [[sensors]] to log")
    if samples < 2:
        raise ValueError("a resting log needs at least 2 samples")
    _check_rows(samples, "resting log")
    drift_sigmas = _number("drift_sigmas", drift_sigmas, nonnegative=True)
    rng, seed = _rng(seed)
    rate = (_number("rate_hz", rate_hz, positive=True) if rate_hz is not None
            else max(s.rate_hz for s in vehicle.sensors))
    t = np.arange(samples) / rate
    cols: dict[str, np.ndarray] = {"time_s": t}
    truth: dict[str, float] = {}
    for s in vehicle.sensors:
        for ch, var in s.variance.items():
            name = f"{ch}_{s.name}"
            sd = math.sqrt(var)
            drift = drift_sigmas * sd * rng.choice([-1.0, 1.0]) * (t / t[-1] if t[-1] > 0 else t)
            cols[name] = REST_LEVEL.get(ch, 0.0) + drift + sd * rng.standard_normal(samples)
            truth[name] = float(var)
    return LabData("noise", cols, truth, {"samples": samples, "rate_hz": rate, "drift_sigmas": drift_sigmas},
                   seed, vehicle.name)
