"""Numbers that summarise a closed-loop run: estimation error, step response, drop-out drift and
filter consistency (normalised estimation error squared, NEES, and normalised innovation squared,
NIS, against chi-square bounds; Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4).

Pure functions of logged arrays; angles are wrapped before differences are taken.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rovlab.core.angles import wrap
from rovlab.core.units import unit as quantity_unit
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
    step = float(step)
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


# --------------------------------------------------------------------------------------------
# Drop-outs, recovery and sensor-loss events (issue 10): pure functions of the time-series
# columns (``time_s``, ``est_<state>``, ``true_<state>``, ``var_<state>``, ``tau_N``,
# ``status_<quantity>_<sensor>`` with the numeric codes of rovlab.estimation.fusion.status_code)
# --------------------------------------------------------------------------------------------

_ANGLE_STATES = ("psi",)


def dropout_windows(dropouts: Sequence[Any]) -> list[tuple[str, float, float]]:
    """(sensor or 'sensor.quantity', start_s, end_s) from the scenario's drop-outs, given as
    mappings {"sensor", "start_s", "end_s"} (SimResult.meta["dropouts"]) or as tuples."""
    out = []
    for d in dropouts:
        if isinstance(d, dict):
            out.append((str(d["sensor"]), float(d["start_s"]), float(d["end_s"])))
        else:
            sensor, start, end = d
            out.append((str(sensor), float(start), float(end)))
    return out


def _error(columns: dict[str, np.ndarray], state: str) -> np.ndarray:
    e = np.asarray(columns[f"est_{state}"], dtype=float) - np.asarray(columns[f"true_{state}"], dtype=float)
    return wrap(e) if state in _ANGLE_STATES else e


def _states(columns: dict[str, np.ndarray], wanted: Sequence[str]) -> list[str]:
    return [s for s in wanted if f"est_{s}" in columns and f"true_{s}" in columns]


def error_before_dropout(columns: dict[str, np.ndarray], start_s: float, *, settle_s: float = 10.0,
                         states: Sequence[str] = ("z", "psi", "w", "r")) -> dict[str, Any]:
    """RMS estimation error per state on [settle_s, start_s): before the drop-out, but after the
    start-up transient (the bias estimates converging, the first reference step) has settled.

    ``window_s`` in the result is the length of the window used (None values when it is empty,
    e.g. a drop-out that starts before ``settle_s``)."""
    t = np.asarray(columns["time_s"], dtype=float)
    sel = (t >= settle_s) & (t < start_s)
    out: dict[str, Any] = {"from_s": float(settle_s), "to_s": float(start_s),
                           "window_s": float(max(0.0, start_s - settle_s)) if sel.any() else 0.0}
    for s in _states(columns, states):
        out[s] = float(rms(_error(columns, s)[sel])) if sel.any() else None
    return out


def drift_during_dropout(columns: dict[str, np.ndarray], start_s: float, end_s: float, *,
                         states: Sequence[str] = ("z", "psi")) -> dict[str, Any]:
    """Per state, over the rows with start_s <= t < end_s: the drift (error at the last row minus
    error at the first), the largest |error| and the RMS error."""
    t = np.asarray(columns["time_s"], dtype=float)
    sel = np.flatnonzero((t >= start_s) & (t < end_s))
    out: dict[str, Any] = {}
    for s in _states(columns, states):
        if sel.size == 0:
            out[s] = {"drift": None, "max_abs_error": None, "rms_error": None}
            continue
        e = _error(columns, s)[sel]
        drift = e[-1] - e[0]
        out[s] = {"drift": float(wrap(drift) if s in _ANGLE_STATES else drift),
                  "max_abs_error": float(np.max(np.abs(e))), "rms_error": float(rms(e))}
    return out


def recovery_kick(columns: dict[str, np.ndarray], return_s: float, *, window_s: float = 5.0) -> dict[str, Any]:
    """What a sensor's return at ``return_s`` does to the estimate and the commands, over the rows
    with return_s <= t < return_s + window_s:

    * ``max_step_psi`` / ``max_step_r``: the largest one-step change |x_k - x_{k-1}| of psi_hat
      (wrapped) and r_hat, the first step being the one into the first row after the return;
    * ``peak_abs_tau_N``: the largest |tau_N|;
    * ``psi_error_at_return``: psi_hat - psi at the last row before the return;
    * ``psi_back_within_2sigma_s``: how long after the return psi_hat first comes within
      2 sigma of the truth, sigma being the filter's smallest heading standard deviation in the
      window (sqrt(var_psi) once the sensor is fully back: during the drop-out the filter's own
      sigma grows to radians and would make the test empty); None if it never does in the
      window or var_psi is not logged.
    """
    t = np.asarray(columns["time_s"], dtype=float)
    rows = np.flatnonzero((t >= return_s) & (t < return_s + window_s))
    out: dict[str, Any] = {"return_s": float(return_s), "window_s": float(window_s), "max_step_psi": None,
                           "max_step_r": None, "peak_abs_tau_N": None, "psi_error_at_return": None,
                           "psi_back_within_2sigma_s": None}
    if rows.size == 0 or rows[0] == 0:
        return out
    prev = np.concatenate([[rows[0] - 1], rows])
    if "est_psi" in columns:
        out["max_step_psi"] = float(np.max(np.abs(wrap(np.diff(np.asarray(columns["est_psi"], float)[prev])))))
    if "est_r" in columns:
        out["max_step_r"] = float(np.max(np.abs(np.diff(np.asarray(columns["est_r"], float)[prev]))))
    if "tau_N" in columns:
        out["peak_abs_tau_N"] = float(np.max(np.abs(np.asarray(columns["tau_N"], float)[rows])))
    if "true_psi" in columns and "est_psi" in columns:
        e = _error(columns, "psi")
        out["psi_error_at_return"] = float(e[rows[0] - 1])
        if "var_psi" in columns:
            sigma = float(np.sqrt(np.min(np.asarray(columns["var_psi"], float)[rows])))
            inside = np.flatnonzero(np.abs(e[rows]) <= 2.0 * sigma)
            if inside.size:
                out["psi_back_within_2sigma_s"] = float(t[rows[inside[0]]] - return_s)
    return out


def _status_channel(column: str) -> tuple[str, str]:
    """('qualisys', 'z') from 'status_z_qualisys'."""
    quantity, _, sensor = column[len("status_"):].partition("_")
    return sensor, quantity


def sensor_loss_events(columns: dict[str, np.ndarray], *, dropouts: Sequence[Any] = ()) -> list[dict[str, Any]]:
    """Every transition of a channel into a lost state, from the ``status_<quantity>_<sensor>``
    columns (codes of rovlab.estimation.fusion.status_code; plain STATUS_* codes read as
    'lost' with reason 'unknown').

    Each event: ``channel`` (the column's suffix, e.g. 'z_qualisys'), ``t_s``, ``reason``
    ('timeout', 'gate', 'nonfinite', 'stuck', 'manual' or 'unknown') and ``expected``: True
    when the channel's sensor was in a scheduled drop-out window (start_s <= t <= end_s) -- a
    loss the scenario asked for, not a false alarm.
    """
    from rovlab.estimation.fusion import code_label

    t = np.asarray(columns["time_s"], dtype=float)
    windows = dropout_windows(dropouts)
    events = []
    for name in sorted(k for k in columns if k.startswith("status_")):
        codes = np.asarray(columns[name], dtype=float)
        if ((codes >= 0.0) & (codes < 2.0)).all():
            continue  # only ok/recovering (the usual case, once per Monte Carlo run): no loss to find
        sensor, quantity = _status_channel(name)
        labels = {c: code_label(c) for c in np.unique(codes[np.isfinite(codes)])}
        lost_codes = [c for c, label in labels.items() if label.startswith("lost")]
        lost = np.isin(codes, lost_codes)  # vectorised: this runs once per Monte Carlo run
        starts = np.flatnonzero(lost & ~np.concatenate([[False], lost[:-1]]))
        for k in starts:
            label = labels[codes[k]]
            reason = label[len("lost-"):] if label.startswith("lost-") else "unknown"
            expected = any(s in (sensor, f"{sensor}.{quantity}") and a <= t[k] <= b for s, a, b in windows)
            events.append({"channel": name[len("status_"):], "t_s": float(t[k]), "reason": reason,
                           "expected": bool(expected)})
    events.sort(key=lambda e: (e["t_s"], e["channel"]))
    return events


def loss_event_counts(events: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Summary of :func:`sensor_loss_events`: total, unexpected (false alarms) and per reason."""
    by_reason: dict[str, int] = {}
    for e in events:
        by_reason[e["reason"]] = by_reason.get(e["reason"], 0) + 1
    return {"total": len(events), "unexpected": sum(1 for e in events if not e["expected"]),
            "by_reason": dict(sorted(by_reason.items()))}


def dropout_metrics(columns: dict[str, np.ndarray], dropouts: Sequence[Any], *, settle_s: float = 10.0,
                    recovery_window_s: float = 5.0) -> list[dict[str, Any]]:
    """One record per drop-out window: error before (after ``settle_s``), drift during, and the
    recovery kick in ``recovery_window_s`` after the return (see the functions above)."""
    out = []
    for sensor, start, end in dropout_windows(dropouts):
        out.append({"sensor": sensor, "start_s": start, "end_s": end,
                    "before": error_before_dropout(columns, start, settle_s=settle_s),
                    "during": drift_during_dropout(columns, start, end),
                    "recovery": recovery_kick(columns, end, window_s=recovery_window_s)})
    return out


# --------------------------------------------------------------------------------------------
# Dynamic positioning (4-DOF estimate, x/y/z/psi references)
# --------------------------------------------------------------------------------------------

_POSE = ("x", "y", "z", "psi")
_FOUR_DOF = ("x", "y", "z", "psi", "u", "v", "w", "r")


def _err(columns: dict[str, np.ndarray], a: str, b: str, angle: bool) -> np.ndarray:
    e = np.asarray(columns[a], dtype=float) - np.asarray(columns[b], dtype=float)
    return wrap(e) if angle else e


def positioning_metrics(columns: dict[str, np.ndarray], dropouts: Sequence[Any] = (), *,
                        observer: bool = False, saturation_tol: float = 1e-6) -> dict[str, Any]:
    """metrics.json entries of a run with a 4-DOF estimate (time-series columns only):

    * ``rms_error``: RMS of estimate - truth per state (x ... r; biases too on the observer plant);
    * ``tracking_rms``: RMS of truth - reference per axis (x, y, z in m, psi in rad), against the
      controller's smooth reference (``ctrl_<axis>_d``, its reference model) where it logs one,
      else against the set-point ``ref_<axis>``; ``tracking_max``: the largest |truth - reference|
      per axis and ``tracking_horizontal_max_m`` the largest horizontal distance (the excursion of a
      vehicle holding station); ``setpoint_error_final``: truth - set-point at the end;
    * ``thrusters``: mean and largest |PWM - 1500| per thruster [us];
    * ``saturation``: time [s] and share of the run in which the allocation could not give the
      demanded wrench (achieved != demanded in any DOF);
    * ``position_dropouts``: per drop-out window, how far the x/y estimate drifted from the truth
      (dead reckoning) and the largest horizontal error.
    """
    c = columns
    t = np.asarray(c["time_s"], dtype=float)
    h = float(t[1] - t[0]) if len(t) > 1 else 0.0
    out: dict[str, Any] = {}
    states = [s for s in _FOUR_DOF if f"est_{s}" in c and f"true_{s}" in c]
    if observer:
        states += [s for s in ("b_X", "b_Y", "b_Z", "b_N") if f"est_{s}" in c and f"true_{s}" in c]
    out["rms_error"] = {s: float(rms(_err(c, f"est_{s}", f"true_{s}", s == "psi"))) for s in states}
    tracking: dict[str, float] = {}
    final: dict[str, float] = {}
    against: dict[str, str] = {}
    for a in _POSE:
        if f"true_{a}" not in c:
            continue
        ref = f"ctrl_{a}_d" if f"ctrl_{a}_d" in c else f"ref_{a}"
        if ref in c:
            tracking[a] = float(rms(_err(c, f"true_{a}", ref, a == "psi")))
            against[a] = ref
        if f"ref_{a}" in c:
            final[a] = float(_err(c, f"true_{a}", f"ref_{a}", a == "psi")[-1])
    out["tracking_rms"] = tracking
    out["tracking_max"] = {a: float(np.nanmax(np.abs(_err(c, f"true_{a}", ref, a == "psi"))))
                           for a, ref in against.items()}
    if "x" in against and "y" in against:
        out["tracking_horizontal_max_m"] = float(np.nanmax(np.hypot(_err(c, "true_x", against["x"], False),
                                                                    _err(c, "true_y", against["y"], False))))
    out["tracking_reference"] = against
    out["setpoint_error_final"] = final
    usage = {}
    for name in c:
        if name.startswith("pwm_"):
            off = np.abs(np.asarray(c[name], dtype=float) - 1500.0)
            usage[name[4:]] = {"mean_abs_pwm_offset_us": float(np.mean(off)), "max_abs_pwm_offset_us": float(np.max(off))}
    out["thrusters"] = usage
    sat = np.zeros(len(t), dtype=bool)
    for d in "XYZN":
        if f"tau_{d}" in c and f"tau_{d}_demanded" in c:
            sat |= np.abs(np.asarray(c[f"tau_{d}_demanded"], dtype=float) - np.asarray(c[f"tau_{d}"], dtype=float)) \
                > saturation_tol * np.maximum(1.0, np.abs(np.asarray(c[f"tau_{d}_demanded"], dtype=float)))
    out["saturation"] = {"time_s": float(np.count_nonzero(sat) * h), "share": float(np.mean(sat)) if len(t) else 0.0}
    drops = []
    if "est_x" in c and "true_x" in c and "est_y" in c and "true_y" in c:
        ex = _err(c, "est_x", "true_x", False)
        ey = _err(c, "est_y", "true_y", False)
        for sensor, start, end in dropout_windows(dropouts):
            w = (t >= start) & (t < end)
            if not w.any():
                continue
            i0 = int(np.argmax(w))
            i1 = int(len(w) - 1 - np.argmax(w[::-1]))
            horiz = np.hypot(ex[w], ey[w])
            drops.append({"sensor": sensor, "start_s": start, "end_s": end,
                          "x_drift_m": float(ex[i1] - ex[i0]), "y_drift_m": float(ey[i1] - ey[i0]),
                          "horizontal_drift_m": float(math.hypot(ex[i1] - ex[i0], ey[i1] - ey[i0])),
                          "horizontal_error_max_m": float(np.max(horiz)),
                          "tracking_rms_during": {a: float(rms(_err(c, f"true_{a}", against[a], a == "psi")[w]))
                                                  for a in against}})
    out["position_dropouts"] = drops
    return out


def holds_station(columns: Mapping[str, Any]) -> bool:
    """Whether a run is station keeping: its controller follows north and east set-points
    (``ref_x`` and ``ref_y`` logged) and none of its set-points changes during the run (a vehicle
    that starts off the set-point and is brought to it counts). Settling time and overshoot do not
    describe such a run; its error against the controller's reference and its largest excursion do."""
    if "ref_x" not in columns or "ref_y" not in columns:
        return False
    for name in columns:
        if name.startswith("ref_"):
            v = np.asarray(columns[name], dtype=float)
            v = v[np.isfinite(v)]
            if v.size and float(v.max() - v.min()) > 0.0:
                return False
    return True


# --------------------------------------------------------------------------------------------
# The units of metrics.json (issue 28: its keys said no unit)
# --------------------------------------------------------------------------------------------

_FRACTION = "1 (fraction)"
_CHI2 = "1 (chi-square statistic)"
_COUNT = "count"


def _unit_of(path: Sequence[str]) -> str | None:
    """The unit of the number at ``path`` (keys, with "[]" for a list item) of a run's metrics or
    of a Monte Carlo summary; None for what is a label rather than a quantity (seed, seeds)."""
    last = path[-1] if path else ""
    parent = path[-2] if len(path) > 1 else ""
    keys = [k for k in path if k != "[]"]
    top = keys[0] if keys else ""
    if last == "[]":  # a list of numbers: the unit of what it lists
        last, parent = parent, (path[-3] if len(path) > 2 else "")
    if top in ("seed", "seeds"):
        return None
    if top in ("nees", "nis") or (top == "monte_carlo" and len(keys) > 1 and keys[1] in ("nees", "nis")):
        return {"dof": _COUNT, "runs": _COUNT, "share_inside": "1 (fraction of time steps)",
                "mean_inside": "1 (1: inside; over runs, the fraction inside)"}.get(last, _CHI2)
    if top == "sensor_losses" or (top == "monte_carlo" and len(keys) > 1 and keys[1] == "sensor_losses"):
        return "s" if last == "t_s" else _COUNT
    if top == "monte_carlo":
        return {"runs": _COUNT, "runs_requested": _COUNT, "wall_time_s": "s",
                "vehicle_steps_per_s": "1/s (plant steps per second of wall time)"}.get(last)
    if parent in ("rms_error", "tracking_rms", "tracking_max", "setpoint_error_final", "before",
                  "tracking_rms_during") and quantity_unit(last):
        return quantity_unit(last)
    if top == "dropouts" and len(keys) == 4 and keys[1] == "during" and quantity_unit(keys[2]):
        return quantity_unit(keys[2])  # dropouts[].during.<state>.drift, .max_abs_error, .rms_error
    if parent == "settling_time_s":
        return "s"
    if last == "overshoot" or parent == "overshoot":
        return "1 (fraction of the step size)"
    if top == "steps" and last in ("from", "to"):
        return "m for axis z, rad for axis psi"
    special = {"max_step_psi": "rad", "max_step_r": "rad/s", "peak_abs_tau_N": "N m", "psi_error_at_return": "rad",
               "heading_error_rms_before": "rad", "depth_error_rms_before": "m", "depth_error_rms_during": "m",
               "share": _FRACTION}
    if last in special:
        return special[last]
    for suffix, u in (("_per_s", "1/s"), ("_s", "s"), ("_m", "m"), ("_rad", "rad"), ("_us", "us")):
        if last.endswith(suffix):
            return u
    return None


def _key_path(dotted: str) -> list[str]:
    """["steps", "[]", "overshoot"] from a flattened Monte Carlo key "steps[0].overshoot"."""
    out: list[str] = []
    for part in dotted.split("."):
        name, bracket, _ = part.partition("[")
        out.append(name)
        if bracket:
            out.append("[]")
    return out


def units_table(metrics: Mapping[str, Any]) -> dict[str, str]:
    """The unit of every number in a metrics.json (a run's, with or without its Monte Carlo block,
    or monte_carlo/metrics.json): key path (dots between keys, "[]" for a list's items) -> unit.
    SI throughout (docs/conventions.md); "1 (...)" is a dimensionless number, "count" a count.
    Each statistic of ``monte_carlo.metrics.<key>`` (mean, std, min, p5, median, p95, max) is in
    the unit of ``<key>`` (its ``count`` in runs)."""
    table: dict[str, str] = {}

    def walk(value: Any, path: list[str]) -> None:
        if isinstance(value, Mapping):
            if path == ["monte_carlo", "metrics"]:
                for key in value:
                    u = _unit_of(_key_path(key))
                    if u is not None:
                        table[f"monte_carlo.metrics.{key}"] = u
                return
            for k, v in value.items():
                walk(v, [*path, str(k)])
        elif isinstance(value, (list, tuple)):
            for item in value:
                walk(item, [*path, "[]"])
        elif value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):  # None: not reached
            u = _unit_of(path)
            if u is not None:
                table[".".join(path).replace(".[]", "[]")] = u

    walk(metrics, [])
    return table


def with_units(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """``metrics`` with its units table as ``units`` (what metrics.json holds)."""
    out = {k: v for k, v in metrics.items() if k != "units"}
    out["units"] = units_table(out)
    return out


def consistency_note(plant: str) -> str | None:
    """Why NEES/NIS outside their chi-square bounds may be no fault: they are exact only for a
    filter whose model and noise are the plant's (the observer plant is the estimator's own linear
    model and noise). None for that plant."""
    if plant == "observer":
        return None
    return (f"the {plant} plant is outside the filter's model (its nonlinear dynamics, thrusters and noise are "
            "not what the filter assumes): the chi-square bounds hold only for a filter whose model and noise "
            "are the plant's (plant = \"observer\"); here they measure how far the filter's tuning is from "
            "consistent on this plant")
