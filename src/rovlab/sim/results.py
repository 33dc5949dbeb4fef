"""What a run gives: :func:`columns` names what the loop logged (timeseries.csv, the HMI's stream),
once for every caller; :class:`SimResult` holds a whole run; :func:`summarise` judges it
(metrics.json: errors, steps, drop-outs, sensor losses, consistency) from the columns the
estimator and controller declare, whatever they are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rovlab.sim import metrics as mx
from rovlab.sim.loop import Logs
from rovlab.sim.prepare import Prepared
from rovlab.sim.scenario import Scenario


def columns(prep: Prepared, logs: Logs, times: np.ndarray, refs: np.ndarray) -> dict[str, np.ndarray]:
    """The named time-series columns of a chunk of logs (timeseries.csv, the HMI's stream)."""
    est, ctl = prep.design.estimator, prep.design.controller
    cols: dict[str, np.ndarray] = {"time_s": times}
    for s, i in zip(est.states, prep.nav_of):
        cols[f"true_{s}"] = logs.truth[:, i]
    for i, s in enumerate(est.states):
        cols[f"est_{s}"] = logs.x[:, i]
    for j, c in enumerate(est.channels):
        cols[f"meas_{c.column}"] = logs.y[:, j]
    for r in ctl.references:
        cols[f"ref_{r}"] = refs[:, ["x", "y", "z", "psi"].index(r)]
    for o in ctl.outputs:
        cols[f"tau_{o}"] = logs.wrench[:, "XYZN".index(o)]
    for i, name in enumerate(prep.allocator.bank.names):
        cols[f"pwm_{name}"] = logs.pwm[:, i]
    for i, s in enumerate(est.states):
        cols[f"var_{s}"] = logs.P[:, i, i]
    for j, c in enumerate(est.channels):
        cols[f"status_{c.column}"] = logs.status[:, j]
    for o in ctl.outputs:
        cols[f"tau_{o}_demanded"] = logs.wrench[:, 4 + "XYZN".index(o)]
    for i, s in enumerate(ctl.state_names):
        cols[f"ctrl_{s}"] = logs.ctrl[:, i]
    return cols



@dataclass(frozen=True, eq=False)
class SimResult:
    """Logs of one run (rows at the control rate) and what is needed to read them."""

    scenario: Scenario
    columns: dict[str, np.ndarray]  # the time-series contract (timeseries.csv)
    P: np.ndarray  # (K, n, n) corrected covariances
    nees: np.ndarray  # (K,) NEES of the states in nees_states
    nees_states: tuple[str, ...]
    nis: np.ndarray  # (K,) NIS per used measurement (NaN when none was used)
    channels: tuple[str, ...]
    thrusters: tuple[str, ...]
    meta: dict[str, Any]
    reason: np.ndarray | None = None  # (K, m) why each channel is lost/off (fusion REASON_*)

    def status_codes(self) -> dict[str, np.ndarray]:
        """status_<column> as one code per sample for status and reason
        (rovlab.estimation.fusion.status_code: 4 lost-timeout ... 8 lost-stuck)."""
        from rovlab.estimation.fusion import STATUS_LOST

        out = {}
        for j, name in enumerate(k for k in self.columns if k.startswith("status_")):
            s = np.asarray(self.columns[name], dtype=float)
            r = self.reason[:, j] if self.reason is not None else np.zeros(len(s))
            out[name] = np.where((s == STATUS_LOST) & (r >= 1) & (r <= 5), 3 + r, s)
        return out

    def status_words(self) -> dict[str, list[str]]:
        """status_<column> as words ('ok', 'recovering', 'lost-timeout', 'lost-gate', 'off' ...),
        the same words `rovlab filter` writes."""
        from rovlab.estimation.fusion import status_label

        out = {}
        for j, name in enumerate(k for k in self.columns if k.startswith("status_")):
            codes = self.columns[name]
            reasons = self.reason[:, j] if self.reason is not None else np.zeros(len(codes))
            cache: dict[tuple[int, int], str] = {}
            out[name] = [cache.setdefault((int(s), int(r)), status_label(int(s), int(r)))
                         for s, r in zip(codes.tolist(), reasons.tolist())]
        return out


def result_of(prep: Prepared, logs: Logs, started: float) -> SimResult:
    """The result of a whole run from its logs; ``started`` is the wall clock of its start [s]."""
    result = _result(prep, logs)
    result.meta["start_time_unix_s"] = started  # wall clock of the run's start (log times)
    return result


def _result(prep: Prepared, logs: Logs) -> SimResult:
    sc = prep.scenario
    est = prep.design.estimator
    t = np.arange(prep.n_ctrl) * prep.h
    cols = columns(prep, logs, t, prep.drive.refs)
    nees = logs.cons[:, 2]
    nis_sum, used = logs.cons[:, 0], logs.cons[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        nis = np.where(used > 0, nis_sum / np.maximum(used, 1), np.nan)
    meta = {
        "scenario": sc.name, "seed": sc.seed, "plant": sc.plant, "vehicle": prep.vehicle.name,
        "design": prep.config.name, "title": f"{sc.name} (seed {sc.seed})",
        "estimator": sc.estimator or prep.config.estimator, "controller": sc.controller or prep.config.controller,
        "dropouts": [{"sensor": d.sensor + (f".{d.channel}" if d.channel else ""), "start_s": d.start_s,
                      "end_s": d.end_s} for d in sc.dropouts],
        "channels": [c.name for c in est.channels], "thrusters": list(prep.allocator.bank.names),
        "measurement_offsets": {f"meas_{c.column}": c.offset for c in est.channels},
        "sample_time_s": prep.h, "plant_step_s": sc.plant_step_s,
    }
    return SimResult(sc, cols, logs.P, nees, tuple(est.states[i] for i in prep.nees_idx), nis,
                     tuple(c.name for c in est.channels), tuple(prep.allocator.bank.names), meta, logs.reason)


def summarise(result: SimResult) -> dict[str, Any]:
    """metrics.json of one run (Sandøy 2016, sec. 5.3.1): RMS estimation error per state (estimate -
    truth), step response per axis (not for station keeping: ``task``), drop-out drift and NEES/NIS
    consistency; with a 4-DOF estimate the positioning numbers (tracking error and excursion,
    thrusters, saturation). metrics.json adds the unit of every number (rovlab.sim.metrics.units_table)."""
    c = result.columns
    sc = result.scenario
    t = c["time_s"]
    out: dict[str, Any] = {"scenario": sc.name, "seed": sc.seed, "plant": sc.plant}
    # the depth-and-heading quantities the estimator estimates (every shipped one does; a plugin may not)
    n = len(t)
    states = [q for q in ("z", "psi", "w", "r") if f"est_{q}" in c and f"true_{q}" in c]
    error = {q: mx.estimation_error(np.column_stack([c[f"est_{q}"]]), np.column_stack([c[f"true_{q}"]]),
                                    angle_columns=(0,) if q == "psi" else ())[:, 0] for q in states}
    out["rms_error"] = {q: float(mx.rms(error[q])) for q in states}
    if sc.plant == "observer" and "est_b_w" in c and "est_b_r" in c:
        eb = np.column_stack([c["est_b_w"] - c["true_b_w"], c["est_b_r"] - c["true_b_r"]])
        out["rms_error"].update(dict(zip(("b_w", "b_r"), map(float, mx.rms(eb)))))
    # what the controller was asked: to hold a position (station keeping: judged by its error
    # against its reference and its largest excursion, positioning_metrics below) or to follow
    # set-point changes (steps of the reference schedule, per axis, judged on the true state)
    holding = mx.holds_station(c)
    out["task"] = "station keeping" if holding else "set-point changes"
    if not holding:
        # each step judged until the next change of any set-point (the thesis's cases: the depth
        # step until the heading step at 22 s)
        steps = []
        prev_z, prev_psi = sc.initial[2], sc.initial[3]
        times = list(sc.reference_times) + [sc.duration_s + 1.0]
        for i, t0 in enumerate(sc.reference_times):
            t1 = times[i + 1]
            z1, psi1 = float(sc.reference_z[i]), float(sc.reference_psi[i])
            if abs(z1 - prev_z) > 1e-12 and "true_z" in c:
                r = mx.step_response(t, c["true_z"], t0, prev_z, z1, t1, band=0.02, min_band=0.005)
                steps.append({"axis": "z", **r})
            if abs(mx.wrap(psi1 - prev_psi)) > 1e-12 and "true_psi" in c:
                r = mx.step_response(t, c["true_psi"], t0, prev_psi, psi1, t1, band=0.02,
                                     min_band=math.radians(0.5), angle=True)
                steps.append({"axis": "psi", **r})
            prev_z, prev_psi = z1, psi1
        out["steps"] = steps
        out["settling_time_s"] = {}
        out["overshoot"] = {}
        for axis in ("z", "psi"):
            mine = [s for s in steps if s["axis"] == axis]
            if mine:
                st = [s["settling_time_s"] for s in mine]
                out["settling_time_s"][axis] = None if any(v is None for v in st) else max(st)
                out["overshoot"][axis] = max(s["overshoot"] or 0.0 for s in mine)
    # drop-outs: what dead reckoning costs, measured honestly: the "before" window starts after
    # the start-up has settled, the recovery is judged on psi_hat, r_hat and tau_N
    coded = {**c, **result.status_codes()}
    drops = []
    for d, rec in zip(sc.dropouts, mx.dropout_metrics(coded, result.meta["dropouts"])):
        w = (t >= d.start_s) & (t < d.end_s)
        if not w.any():
            continue
        e_psi = error.get("psi", np.full(n, np.nan))
        i0 = int(np.argmax(w))
        i1 = int(len(w) - 1 - np.argmax(w[::-1]))
        drops.append({
            **rec,
            "heading_drift_rad": float(e_psi[i1] - e_psi[i0]),
            "heading_error_max_rad": float(np.max(np.abs(e_psi[w]))),
            "heading_error_rms_before": rec["before"].get("psi"),
            "depth_error_rms_before": rec["before"].get("z"),
            "depth_error_rms_during": float(mx.rms(error["z"][w])) if "z" in error else None,
        })
    out["dropouts"] = drops
    events = mx.sensor_loss_events(coded, dropouts=result.meta["dropouts"])
    out["sensor_losses"] = {**mx.loss_event_counts(events), "events": events}
    # consistency: NEES of the corrected estimate, NIS per used measurement
    out["nees"] = {"states": list(result.nees_states), **mx.consistency(result.nees, len(result.nees_states))}
    out["nis"] = mx.consistency(result.nis, 1)
    note = mx.consistency_note(sc.plant)
    if note:  # NEES/NIS outside their bounds here may be no fault of the filter: say why
        out["consistency_note"] = note
    if "est_x" in c:  # a 4-DOF estimate (e.g. estimator "ekf"): the planar and dynamic-positioning numbers
        out.update(mx.positioning_metrics(c, result.meta["dropouts"], observer=sc.plant == "observer"))
    return out
