"""Sub-commands on vehicles: ``vehicle show``, ``vehicle check``, ``thruster``, ``allocate``.

Interfaces hold no maths: these only load, call the core and format the answer.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from typing import Any

import numpy as np

from rovlab.params.validate import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    veh = sub.add_parser("vehicle", help="show or check a vehicle description")
    vsub = veh.add_subparsers(dest="vehicle_command", metavar="ACTION")
    vsub.required = True
    show = vsub.add_parser("show", help="print a vehicle's parameters and configuration matrix")
    show.add_argument("vehicle", nargs="?", default="udrone", help="packaged name or TOML file (default: udrone)")
    show.add_argument("--json", action="store_true", help="machine-readable output")
    show.set_defaults(func=_cmd_show)
    check = vsub.add_parser("check", help="validate a vehicle file, listing every problem (exit 2 if any)")
    check.add_argument("file", help="packaged name or TOML file")
    check.set_defaults(func=_cmd_check)
    lst = vsub.add_parser("list", help="list the packaged vehicles")
    lst.set_defaults(func=_cmd_list)
    fa = vsub.add_parser("from-ardusub", help="a vehicle file whose thrusters are as an ArduSub autopilot describes "
                                              "them (frame, MOT_n_DIRECTION, PWM range), on a base vehicle's "
                                              "geometry and hydrodynamics")
    fa.add_argument("log", nargs="?", help="a .tlog or DataFlash .BIN log carrying the autopilot's parameters")
    fa.add_argument("--connect", default=None, metavar="URL",
                    help="read them from a live autopilot instead (pymavlink URL, e.g. udpin:0.0.0.0:14550)")
    fa.add_argument("--base", default="bluerov2_heavy", help="vehicle name or TOML file to start from "
                                                             "(default bluerov2_heavy)")
    fa.add_argument("--out", required=True, help="the vehicle file to write")
    fa.add_argument("--name", default=None, help="the new vehicle's name (default: the --out file's stem)")
    fa.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for a live autopilot's "
                                                                 "parameters (default 30)")
    fa.set_defaults(func=_cmd_from_ardusub)

    thr = sub.add_parser("thruster", help="convert between PWM command and thrust for one thruster")
    thr.add_argument("--vehicle", default="udrone", help="packaged name or TOML file (default: udrone)")
    thr.add_argument("--thruster", required=True, help="thruster name, e.g. T1")
    group = thr.add_mutually_exclusive_group(required=True)
    group.add_argument("--force", type=float, help="thrust [N] -> PWM")
    group.add_argument("--pwm", type=float, help="PWM pulse width [us] -> thrust")
    thr.add_argument("--voltage", type=float, help="supply voltage [V] for a tabulated (T200) thruster")
    thr.add_argument("--json", action="store_true", help="machine-readable output")
    thr.set_defaults(func=_cmd_thruster)

    alloc = sub.add_parser("allocate", help="allocate a wrench to thruster forces and PWM commands")
    alloc.add_argument("--vehicle", default="udrone", help="packaged name or TOML file (default: udrone)")
    alloc.add_argument("--wrench", type=float, nargs="+", required=True, metavar="V",
                       help="X Y Z N [N, N m] (K = M = 0 demanded) or X Y Z K M N")
    alloc.add_argument("--mode", choices=("priority", "scale", "unconstrained"), default="priority",
                       help="priority: the largest share of each DOF group in turn, K,M > Z > N > X,Y, "
                            "each scaled along its own direction; scale: the largest share of the whole "
                            "wrench, direction kept; unconstrained: plain pseudo-inverse, forces may exceed "
                            "the thrusters' limits (reported; their PWM then saturates)")
    alloc.add_argument("--json", action="store_true", help="machine-readable output")
    alloc.set_defaults(func=_cmd_allocate)


def _load(name: str):
    from rovlab.params.vehicle import load_vehicle

    return load_vehicle(name)


def _cmd_from_ardusub(args: argparse.Namespace) -> int:
    """Read the autopilot's parameters, edit a copy of the base vehicle file, say what came from where."""
    from pathlib import Path

    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing
    from rovlab.interfaces.mavlink.autopilot import ParameterError, fetch_parameters, read_parameters, vehicle_edits
    from rovlab.params.edit import edit_vehicle_file
    from rovlab.params.vehicle import load_vehicle, resolve_vehicle_path

    if bool(args.log) == bool(args.connect):
        raise UserError("give either a log (.tlog or .BIN) or --connect URL")
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UserError(f"--timeout must be > 0 s, got {args.timeout}")
    base_path = resolve_vehicle_path(args.base)
    base = load_vehicle(base_path)
    out = Path(args.out)
    if out.suffix.lower() != ".toml":
        raise UserError(f"--out {out}: a vehicle file is TOML: give a name ending in .toml")
    if out.exists() and out.resolve() == base_path.resolve():
        raise UserError(f"--out {out} is the base vehicle file: write the new vehicle to another file")
    try:
        if args.log:
            params = read_parameters(args.log)
            source = Path(args.log).name
        else:
            params, source = fetch_parameters(args.connect, timeout_s=args.timeout)
        values, notes, lines = vehicle_edits(base, params, source=source)
    except (ParameterError, ValueError, MavlinkMissing) as exc:
        raise UserError(str(exc)) from None
    name = args.name or out.stem
    values["name"] = name
    values["description"] = f"{base.description}; thrusters as its ArduSub autopilot describes them ({source})"
    try:
        edit_vehicle_file(base_path, values, sources={**notes}, output=out)
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"rovlab vehicle from-ardusub: {name} from {base.name} ({base_path.name}) and the {len(params)} "
          f"parameters of {source}")
    for line in lines:
        print(f"  {line}")
    kept = [k for k in ("JS_GAIN_DEFAULT", "JS_THR_GAIN", "FS_PILOT_INPUT", "BARO2_GND_PRESS") if k in params]
    if kept:
        print("  not a vehicle property, read live by the bridge (and from the log by rovlab filter): "
              + ", ".join(f"{k} = {params[k]:g}" for k in kept))
    print(f"  hydrodynamics, masses, thruster positions and curves, sensors: {base.name}'s, unchanged")
    print(f"wrote {out}")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from rovlab.params.vehicle import load_vehicle, packaged_vehicle_names

    for name in packaged_vehicle_names():
        v = load_vehicle(name)
        print(f"{name:16s} {v.description}")
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from rovlab.allocation import Allocator, configuration_matrix

    v = _load(args.vehicle)
    B = configuration_matrix(v)
    alloc = Allocator(v, compiled=False)  # only its thrust limits: no numba
    info: dict[str, Any] = {
        "name": v.name,
        "description": v.description,
        "file": v.file,
        "mass": v.mass,
        "I_zz": v.I_zz,
        "weight": v.weight,
        "buoyancy": v.buoyancy,
        "net_buoyancy": v.buoyancy - v.weight,  # B - W [N]: > 0 floats up, < 0 sinks
        "r_g": v.r_g.tolist(),
        "r_b": v.r_b.tolist(),
        "added_mass": dict(zip(("X_udot", "Y_vdot", "Z_wdot", "N_rdot"), v.added_mass.tolist())),
        "damping": {
            dof: {"linear": float(v.damping_linear[i]), "quadratic": float(v.damping_quadratic[i]),
                  "cubic": float(v.damping_cubic[i])}
            for i, dof in enumerate(("surge", "sway", "heave", "yaw"))
        },
        "thrusters": list(v.thruster_names),
        "thruster_details": [
            {
                "name": t.name, "position": t.position.tolist(), "direction": t.direction.tolist(),
                "model": t.model,
                "curve": dataclasses.asdict(t.curve) if t.curve else {"table": t.table, "voltage": t.voltage},
                "pwm_range_us": [t.pwm_min_us, t.pwm_max_us], "deadband_us": t.deadband_us,
                "deadband_kind": t.deadband_kind,
                "thrust_limits": [float(alloc.f_min[i]), float(alloc.f_max[i])],
            }
            for i, t in enumerate(v.thrusters)
        ],
        "sensors": [
            {"name": s.name, "kind": s.kind, "position": s.position.tolist(), "rate_hz": s.rate_hz,
             "variance": dict(s.variance)}
            for s in v.sensors
        ],
        "configuration_matrix": B.tolist(),
        "configuration_rank": int(np.linalg.matrix_rank(B)),
        "sources": dict(v.sources),
    }
    if args.json:
        print(_json(info, indent=2))
        return 0
    print(f"{v.name}: {v.description}")
    print(f"  file        {v.file}")
    print(f"  mass        {v.mass:g} kg   I_zz {v.I_zz:g} kg m^2")
    print(f"  weight      {v.weight:.2f} N   buoyancy {v.buoyancy:.2f} N   {_net_buoyancy(v.weight, v.buoyancy)}")
    print("  added mass  " + "  ".join(f"{k} {val:g}" for k, val in info["added_mass"].items()))
    print("  damping     DOF      linear   |x|x      x^3")
    for dof, d in info["damping"].items():
        print(f"              {dof:6s} {d['linear']:8.3f} {d['quadratic']:8.3f} {d['cubic']:8.2f}")
    print("  thrusters   name  position [m]               direction        model      limits [N]     dead band")
    for td in info["thruster_details"]:
        pos = " ".join(f"{x:+.3f}" for x in td["position"])
        dirn = " ".join(f"{x:+.2f}" for x in td["direction"])
        lo, hi = td["thrust_limits"]
        dead = ("the table's" if td["model"] == "table" else "none" if td["deadband_us"] == 0
                else f"+-{td['deadband_us']:g} us {td['deadband_kind']}")
        print(f"              {td['name']:5s} [{pos}]  [{dirn}]  {td['model']:9s}  {lo:+.1f} .. {hi:+.1f}"
              f"  {dead}")
    print("  sensors     " + ", ".join(f"{s['name']} ({s['kind']}, {s['rate_hz']:g} Hz)" for s in info["sensors"]))
    print(f"  configuration matrix B (rows X Y Z K M N; rank {info['configuration_rank']}):")
    print("              " + "".join(f"{n:>9s}" for n in v.thruster_names))
    for label, row in zip("XYZKMN", B):
        print(f"            {label} " + "".join(f"{x:9.4f}" for x in row))
    return 0


def _net_buoyancy(weight: float, buoyancy: float) -> str:
    """B - W in words. z is down (NED): the net force of gravity and buoyancy on the hull is
    W - B along +z, so W > B sinks the vehicle and B > W floats it up (docs/conventions.md)."""
    net = buoyancy - weight
    if abs(net) < 0.005:  # what the two-decimal figures above cannot tell apart
        return "net buoyancy B - W 0.00 N: neutral"
    what = "floats up when unpowered" if net > 0 else "sinks when unpowered"
    return f"net buoyancy B - W {net:+.2f} N: {what}"


def _cmd_check(args: argparse.Namespace) -> int:
    from rovlab.params.vehicle import check_vehicle_file

    problems = check_vehicle_file(args.file)
    if not problems:
        print(f"{args.file}: ok")
        return 0
    print(f"{args.file}: {len(problems)} problem{'s' if len(problems) != 1 else ''}")
    for p in problems:
        print(f"  - {p}")
    return 2


def _cmd_thruster(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError
    from rovlab.models.thrusters import force_from_pwm, pwm_from_force, thrust_limits

    v = _load(args.vehicle)
    try:
        t = v.thruster(args.thruster)
    except KeyError as exc:
        raise UserError(exc.args[0]) from None
    if args.voltage is not None:
        if t.model != "table":
            raise UserError(f"--voltage applies to tabulated thrusters; {t.name} uses the {t.model} model")
        if not 10.0 <= args.voltage <= 20.0:
            raise UserError(f"--voltage {args.voltage:g}: the T200 tables cover 10-20 V")
        t = dataclasses.replace(t, voltage=args.voltage)
    value = args.force if args.force is not None else args.pwm
    if not math.isfinite(value):
        raise UserError(f"{'--force' if args.force is not None else '--pwm'} must be a finite number")
    f_lo, f_hi = thrust_limits(t)
    if args.force is not None:
        pwm = pwm_from_force(t, args.force)
        saturated = not f_lo <= args.force <= f_hi
        out = {"thruster": t.name, "force": args.force, "pwm_us": pwm, "saturated": saturated,
               "achieved_force": force_from_pwm(t, pwm)}
    else:
        saturated = not t.pwm_min_us <= args.pwm <= t.pwm_max_us
        out = {"thruster": t.name, "pwm_us": args.pwm, "force": force_from_pwm(t, args.pwm),
               "saturated": saturated}
    if args.json:
        print(_json(out))
        return 0
    if args.force is not None:
        print(f"{t.name}: {args.force:g} N -> {out['pwm_us']:.2f} us")
    else:
        print(f"{t.name}: {args.pwm:g} us -> {out['force']:.4f} N")
    if saturated:
        print(f"  saturated: range {t.pwm_min_us:g}-{t.pwm_max_us:g} us, thrust {f_lo:.2f} .. {f_hi:.2f} N"
              + (f"; gives {out['achieved_force']:.3f} N" if args.force is not None else ""))
    return 0


def _cmd_allocate(args: argparse.Namespace) -> int:
    from rovlab.allocation import SCALE_ALL, Allocator
    from rovlab.interfaces.cli import UserError

    if len(args.wrench) not in (4, 6):
        raise UserError(f"--wrench takes 4 values (X Y Z N) or 6 (X Y Z K M N), got {len(args.wrench)}")
    if not all(math.isfinite(x) for x in args.wrench):
        raise UserError(f"--wrench values must be finite, got {args.wrench}")
    v = _load(args.vehicle)
    # one allocation: the plain-Python kernels (same numbers) beat importing numba and compiling
    if args.mode == "unconstrained":
        alloc = Allocator(v, saturation=False, compiled=False)
    elif args.mode == "scale":
        alloc = Allocator(v, priority=SCALE_ALL, compiled=False)
    else:
        alloc = Allocator(v, compiled=False)
    res = alloc.allocate(np.array(args.wrench))
    if args.json:
        print(_json(res.as_dict()))
        return 0
    print(f"{v.name}: allocation ({args.mode})")
    print("  DOF   demanded   achieved")
    for label, d, a in zip(("X", "Y", "Z", "K", "M", "N"), res.demanded, res.achieved):
        print(f"  {label}   {d:9.3f}  {a:9.3f}")
    print("  thruster   force [N]   pwm [us]   limits [N]")
    for i, name in enumerate(res.thruster_names):
        print(f"  {name:8s} {res.forces[i]:10.3f} {res.pwm_us[i]:10.1f}   {alloc.f_min[i]:+.1f} .. {alloc.f_max[i]:+.1f}")
    if res.over_limit:
        print("  beyond the thrust limits: " + ", ".join(res.over_limit)
              + " (unconstrained pseudo-inverse: their PWM commands saturate, so the real wrench differs)")
    elif res.saturated:
        print("  saturated: " + ", ".join(f"{d} at {f:.0%}" for d, f in
                                          zip(("X", "Y", "Z", "K", "M", "N"), res.fraction) if f < 1 - 1e-6))
    else:
        print("  not saturated")
    return 0


__all__ = ["register", "ConfigError"]


def _finite(obj: Any) -> Any:
    """JSON has no Infinity or NaN: non-finite numbers become null (e.g. an unbounded limit)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj


def _json(obj: Any, **kw: Any) -> str:
    """Strict JSON (RFC 8259): never prints Infinity or NaN."""
    return json.dumps(_finite(obj), allow_nan=False, **kw)
