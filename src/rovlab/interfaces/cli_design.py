"""Sub-commands ``design`` (observer and LQR design) and ``filter`` (offline estimation of a log).

Interfaces hold no maths: these load the files, call rovlab.estimation / rovlab.control and
format the answer.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np

from rovlab.params.validate import ConfigError, Problem

INPUT_COLUMNS = ("tau_Z", "tau_N")


def register(sub: argparse._SubParsersAction) -> None:
    des = sub.add_parser("design", help="discretise the depth-and-heading model, check observability, design the LQR")
    _common(des)
    des.add_argument("--json", action="store_true", help="machine-readable output (SI units)")
    des.add_argument("--allow-unobservable", action="store_true",
                     help="report an unobservable sensor set instead of refusing it")
    des.set_defaults(func=_cmd_design)

    fil = sub.add_parser("filter", help="estimate depth, heading, velocities and biases from a recorded log")
    fil.add_argument("log", help="CSV log: time_s, tau_Z, tau_N and one column per fused sensor channel "
                                 "(e.g. z_qualisys, z_pressure, psi_qualisys); empty or nan = no sample")
    fil.add_argument("--out", required=True, help="output CSV (- for standard output)")
    _common(fil)
    fil.set_defaults(func=_cmd_filter)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", default="udrone", help="packaged vehicle name or TOML file (default: udrone)")
    p.add_argument("--config", default="default",
                   help="filter/controller configuration: packaged name (default, thesis) or TOML file "
                        "(default: default)")


def _load(args: argparse.Namespace, *, require_observable: bool = True):
    from rovlab.estimation.model import build_filter_model
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    config = load_design_config(args.config)
    return vehicle, config, build_filter_model(vehicle, config, require_observable=require_observable)


# --------------------------------------------------------------------------------------------
# design
# --------------------------------------------------------------------------------------------

def _cmd_design(args: argparse.Namespace) -> int:
    from rovlab.control.lqr import design_lqr_from_config
    from rovlab.estimation.model import describe_direction

    vehicle, config, model = _load(args, require_observable=not args.allow_unobservable)
    lqr = design_lqr_from_config(vehicle, config)
    p = model.params
    info: dict[str, Any] = {
        "vehicle": vehicle.name,
        "config": config.name,
        "sample_time": model.h,
        "states": list(model.states),
        "inputs": list(model.inputs),
        "measurements": [c.name for c in model.channels],
        "Phi": model.Phi.tolist(),
        "Delta": model.Delta.tolist(),
        "Gamma": model.Gamma.tolist(),
        "Q": model.Q.tolist(),
        "H": model.H.tolist(),
        "R": model.R.tolist(),
        "K": lqr.K.tolist(),
        "P": lqr.P.tolist(),
        "observable": bool(model.observable),
        "unobservable": list(model.unobservable),
        "unobservable_directions": [describe_direction(model.unobservable_directions[:, k])
                                    for k in range(model.unobservable_directions.shape[1])],
        "model": {"M_w": p.M_w, "M_r": p.M_r, "Z_w": p.Z_w, "N_r": p.N_r, "T_w": model.T_w, "T_r": model.T_r},
        "W": np.diag(model.W).tolist(),
        "lqr": {"states": ["z", "psi", "w", "r"], "Q": np.diag(lqr.Q).tolist(), "R": np.diag(lqr.R).tolist(),
                "reference_gain": lqr.reference, "closed_loop_poles_abs": np.abs(lqr.poles).tolist()},
    }
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    print(f"vehicle {vehicle.name}, configuration {config.name} ({config.file}); sample time {model.h:g} s")
    print(f"  model: M_w = {p.M_w:.6g} kg, M_r = {p.M_r:.6g} kg m^2, Z_w = {p.Z_w:.6g}, N_r = {p.N_r:.6g}, "
          f"T_w = {model.T_w:.6g} s, T_r = {model.T_r:.6g} s")
    print("  measurements:")
    for c in model.channels:
        gate = "off" if not np.isfinite(c.gate_threshold) else f"chi2 {c.gate_threshold:.3g}"
        print(f"    {c.name:16s} column {c.column:14s} variance {c.variance:.6g}  l_z {c.offset:+.4g} m  "
              f"timeout {c.timeout_s:g} s  gate {gate}")
    if model.observable:
        print("  observable: yes")
    else:
        print(f"  observable: NO -- cannot estimate {', '.join(model.unobservable)} "
              f"({'; '.join(info['unobservable_directions'])})")
    for name in ("Phi", "Delta", "Q"):
        _print_matrix(name, getattr(model, name))
    _print_matrix("K (LQR)", lqr.K)
    _print_matrix(f"P (reference gain, {lqr.reference})", lqr.P)
    print(f"  |closed-loop poles| = {', '.join(f'{a:.4f}' for a in np.abs(lqr.poles))}")
    return 0


def _print_matrix(name: str, M: np.ndarray) -> None:
    print(f"  {name} =")
    for row in np.atleast_2d(M):
        print("    [" + "  ".join(f"{v: .6g}" for v in row) + "]")


# --------------------------------------------------------------------------------------------
# filter
# --------------------------------------------------------------------------------------------

def _cmd_filter(args: argparse.Namespace) -> int:
    from rovlab.estimation.fusion import EVENT_NONFINITE, EVENT_REJECTED, EVENT_USED, STATUS_LOST
    from rovlab.estimation.kalman import DepthHeadingFilter, steps_between
    from rovlab.interfaces.cli import UserError
    from rovlab.io.logs import read_log, write_csv

    vehicle, config, model = _load(args)
    filt = DepthHeadingFilter(model)
    columns = [c.column for c in model.channels]
    log = read_log(args.log, required=("time_s",) + INPUT_COLUMNS + tuple(columns))
    t = log.time
    n_predict, bad = steps_between(t, model.h)
    if bad is not None:
        dt = float(t[bad] - t[bad - 1])
        raise ConfigError([Problem(log.file, log.where(bad, "time_s"),
                                   f"a step of {dt:.6g} s after line {int(log.lines[bad - 1])}",
                                   f"a whole number of filter sample times h = {model.h:g} s (within 25%)")],
                          "log")
    u = np.column_stack([log[c] for c in INPUT_COLUMNS])
    y = np.column_stack([log[c] for c in columns])
    run = filt.run(t, u, y, n_predict=n_predict)

    out: dict[str, Any] = {"time_s": t}
    for i, s in enumerate(model.states):
        out[s] = run.x[:, i]
    for i, s in enumerate(model.states):
        out[f"var_{s}"] = run.variance[:, i]
    for j, c in enumerate(model.channels):
        out[f"status_{c.column}"] = run.status_labels(j)
    comments = [f"rovlab filter {args.log}: vehicle {vehicle.name}, configuration {config.name}, "
                f"h = {model.h:g} s", "units: SI (m, rad, m/s, rad/s, N, N m); var_* are the variances"]
    try:
        write_csv(args.out, out, comments=comments, float_format="%.10g", exact=("time_s",))
    except OSError as exc:
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None

    report = sys.stderr if args.out == "-" else sys.stdout
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    print(f"filtered {len(t)} samples ({span:g} s) of {args.log} with {vehicle.name}/{config.name}"
          + ("" if args.out == "-" else f" -> {args.out}"), file=report)
    gaps = int(np.sum(n_predict[:-1] > 1))
    if gaps:
        print(f"  {gaps} gap(s) in the log bridged by prediction", file=report)
    for j, c in enumerate(model.channels):
        lost = run.status[:, j] >= STATUS_LOST
        samples = int(np.sum(~np.isnan(y[:, j])))
        used = int(np.sum(run.event[:, j] == EVENT_USED))
        rejected = int(np.sum(run.event[:, j] == EVENT_REJECTED))
        faulty = int(np.sum(run.event[:, j] == EVENT_NONFINITE))
        print(f"  {c.name:16s} {samples} samples, {used} used, {rejected} rejected by the gate"
              + (f", {faulty} not finite" if faulty else "")
              + f"; lost {100.0 * lost.mean():.1f}% of the time", file=report)
    return 0
