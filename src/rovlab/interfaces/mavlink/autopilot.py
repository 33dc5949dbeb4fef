"""The vehicle as its ArduSub autopilot describes it: frame, thruster directions, PWM range.

ArduSub does not know thrust directions: it *mixes* pilot and attitude-controller inputs with a
factor table per frame (FRAME_CONFIG) and then multiplies each motor's output by its
MOT_n_DIRECTION (+1 or -1) before turning it into a PWM pulse, 1500 + 400 output, limited to
MOT_PWM_MIN .. MOT_PWM_MAX (ArduPilot, libraries/AP_Motors/AP_Motors6DOF.cpp: setup_motors'
add_motor_raw_6dof tables, output_armed_stabilizing, calc_thrust_to_pwm). An owner sets the
directions so that the vehicle moves as commanded (the Blue Robotics set-up procedure tests each
motor). So the physical thrust direction of motor n for a PWM above neutral is

    e_n = MOT_n_DIRECTION * a_n

where a_n is the frame's *nominal* axis of motor n: the direction whose thrust the factor table
assumes for a positive output (forward, lateral and throttle factors give its sign per axis; the
roll, pitch and yaw factors its moments). rovlab's vehicle file gives each thruster's line of
action (position and ``direction`` for a PWM above neutral); the nominal axis is that line
oriented as the factor table says, and the file *implies* MOT_n_DIRECTION = sign(e_n . a_n).

* :func:`read_parameters` reads the parameters a log carries (.tlog PARAM_VALUE, DataFlash .BIN
  PARM) through pymavlink;
* :func:`check_vehicle` compares a vehicle file with an autopilot's parameters: frame and
  motor count, each MOT_n_DIRECTION against the one the file implies, the PWM range; every
  disagreement named (parameter, its value, the vehicle file's). A frame whose mixing rovlab
  does not know (FRAME_CONFIG 0 BlueROV1, 3-7) is not checked;
* :func:`vehicle_edits` gives the edits that make a vehicle file agree with the parameters
  (``rovlab vehicle from-ardusub``).

The factor tables below are facts of ArduSub's source (frames 1 VECTORED, the BlueROV2, and 2
VECTORED_6DOF, the BlueROV2 Heavy), the same in ArduSub 4.1 and 4.7.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.params.validate import Problem
from rovlab.params.vehicle import Vehicle

# FRAME_CONFIG -> (name, per motor: roll, pitch, yaw, throttle, forward, lateral factors)
# (AP_Motors6DOF.cpp, AP_Motors6DOF::setup_motors; throttle +1 = up, forward +1 = ahead, lateral +1 = right)
FRAMES: dict[int, tuple[str, tuple[tuple[float, ...], ...]]] = {
    1: ("VECTORED", (
        (0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
        (1, 0, 0, -1, 0, 0), (-1, 0, 0, -1, 0, 0))),
    2: ("VECTORED_6DOF", (
        (0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
        (1, -1, 0, -1, 0, 0), (-1, -1, 0, -1, 0, 0), (1, 1, 0, -1, 0, 0), (-1, 1, 0, -1, 0, 0))),
}
PWM_NEUTRAL_US = 1500.0  # AP_Motors6DOF::calc_thrust_to_pwm: 1500 + 400 thrust
TRUST_HINT = "--trust-vehicle-file uses the vehicle file as it is"
LOG_SUFFIXES = (".tlog", ".bin")


class ParameterError(ValueError):
    """A log or link whose parameters cannot be read (the message names the file)."""


def nominal_axes(frame: int) -> np.ndarray:
    """(n, 3) sign pattern of each motor's nominal thrust axis in the body frame (FRD): the
    forward, lateral and throttle factors, throttle up being -z."""
    _name, table = FRAMES[frame]
    return np.array([[f[4], f[5], -f[3]] for f in table], dtype=float)


def moment_signs(frame: int) -> np.ndarray:
    """(n, 3) the roll, pitch and yaw factors of each motor."""
    _name, table = FRAMES[frame]
    return np.array([[f[0], f[1], f[2]] for f in table], dtype=float)


@dataclass(frozen=True)
class Implied:
    """What a vehicle file implies for an ArduSub frame."""

    frame: int
    directions: tuple[int, ...]  # the MOT_n_DIRECTION the file's thrust directions imply
    problems: tuple[Problem, ...]  # thrusters whose line of action is not the frame's motor n


def implied_directions(vehicle: Vehicle, frame: int, *, file: str | None = None) -> Implied:
    """The MOT_n_DIRECTION a vehicle file implies for a frame, with a problem for each thruster
    whose line of action cannot be the frame's motor n (no component along its nominal axis, or
    a moment of the opposite sign to the frame's roll, pitch or yaw factor)."""
    where = file or vehicle.file or vehicle.name
    axes, moments = nominal_axes(frame), moment_signs(frame)
    name = FRAMES[frame][0]
    out, problems = [], []
    for n, th in enumerate(vehicle.thrusters[: len(axes)]):
        e = np.asarray(th.direction, dtype=float)
        along = float(e @ axes[n])
        if abs(along) < 1e-6:
            problems.append(Problem(where, f"thrusters[name={th.name}].direction", [float(v) for v in e],
                                    f"a line of action along ArduSub {name} motor {n + 1}'s axis "
                                    f"(forward, lateral, down signs {axes[n].tolist()})"))
            out.append(0)
            continue
        sign = 1 if along > 0 else -1
        a = sign * e  # the nominal axis on the file's line of action
        moment = np.cross(np.asarray(th.position, dtype=float), a)  # roll, pitch, yaw of a unit thrust
        for k, axis in enumerate(("roll", "pitch", "yaw")):
            f = moments[n, k]
            if f != 0 and abs(moment[k]) > 1e-6 and np.sign(moment[k]) != np.sign(f):
                problems.append(Problem(where, f"thrusters[name={th.name}].position", [float(v) for v in th.position],
                                        f"ArduSub {name} motor {n + 1}: its {axis} factor is {f:+g}, this thruster's "
                                        f"{axis} moment along that motor's axis is {moment[k]:+.3g} N m/N (is the "
                                        "file's thruster order ArduSub's motor order?)"))
        out.append(sign)
    return Implied(frame, tuple(out), tuple(problems))


def check_vehicle(vehicle: Vehicle, params: Mapping[str, float], *, source: str,
                  file: str | None = None) -> list[Problem]:
    """Every disagreement between a vehicle file and an ArduSub autopilot's parameters, each naming
    the parameter, its value (from ``source``) and what the vehicle file says; [] if they agree.
    A parameter the autopilot did not report is not checked."""
    where = file or vehicle.file or vehicle.name
    out: list[Problem] = []
    frame_raw = params.get("FRAME_CONFIG")
    n = len(vehicle.thrusters)
    if frame_raw is not None:
        frame = int(frame_raw)
        if frame not in FRAMES:
            pass  # a frame whose mixing rovlab does not know (e.g. 7 CUSTOM): nothing to check it against
        elif len(FRAMES[frame][1]) != n:
            k = len(FRAMES[frame][1])
            out.append(Problem(source, "FRAME_CONFIG", frame,
                               f"a frame of {n} motors, as vehicle file {where} has {n} thrusters; {frame} is "
                               f"{FRAMES[frame][0]}, {k} motors (start from a vehicle file with {k}; {TRUST_HINT})"))
        else:
            implied = implied_directions(vehicle, frame, file=where)
            out.extend(implied.problems)
            for k, want in enumerate(implied.directions):
                key = f"MOT_{k + 1}_DIRECTION"
                got = params.get(key)
                if got is None or want == 0:
                    continue
                if int(round(float(got))) != want:
                    th = vehicle.thrusters[k]
                    out.append(Problem(source, key, int(round(float(got))),
                                       f"{want:+d} as vehicle file {where} implies (thruster {th.name} pushes along "
                                       f"{_vec(th.direction)} above neutral PWM; ArduSub {FRAMES[frame][0]} mixes "
                                       f"motor {k + 1} along {_vec(nominal_axes(frame)[k] * want)})"))
    for key, attr, pick in (("MOT_PWM_MIN", "pwm_min_us", min), ("MOT_PWM_MAX", "pwm_max_us", max)):
        got = params.get(key)
        if got is None or not math.isfinite(float(got)) or float(got) <= 0:
            continue  # 0: the SERVOn range is used (ArduPilot's default)
        mine = pick(getattr(t, attr) for t in vehicle.thrusters)
        if abs(float(got) - mine) > 0.5:
            out.append(Problem(source, key, float(got), f"{mine:g} us as vehicle file {where} says ({attr})"))
    return out


def vehicle_edits(vehicle: Vehicle, params: Mapping[str, float], *,
                  source: str) -> tuple[dict[str, Any], dict[str, str], list[str]]:
    """(values, source notes, report lines) that make a vehicle file agree with the parameters:
    each thruster's direction = MOT_n_DIRECTION times the frame's nominal axis on the file's line
    of action, and the PWM range from MOT_PWM_MIN/MAX. Raises ValueError naming what is missing
    or cannot be matched (frame, motor count, a thruster that is not the frame's motor n)."""
    frame_raw = params.get("FRAME_CONFIG")
    if frame_raw is None:
        raise ValueError(f"{source}: no FRAME_CONFIG among its parameters: the frame decides the mixing")
    frame = int(frame_raw)
    if frame not in FRAMES:
        known = ", ".join(f"{k} ({v[0]})" for k, v in FRAMES.items())
        raise ValueError(f"{source}: FRAME_CONFIG = {frame}; rovlab knows the mixing of {known}")
    name, table = FRAMES[frame]
    if len(table) != len(vehicle.thrusters):
        raise ValueError(f"{source}: FRAME_CONFIG = {frame} ({name}) drives {len(table)} motors; the base vehicle "
                         f"{vehicle.name} has {len(vehicle.thrusters)} thrusters: choose a base vehicle with {len(table)}")
    implied = implied_directions(vehicle, frame)
    if implied.problems:
        raise ValueError("; ".join(f"{p.key}: {p.expected}" for p in implied.problems))
    values: dict[str, Any] = {}
    notes: dict[str, str] = {}
    lines = [f"frame: FRAME_CONFIG = {frame} ({name}, {len(table)} motors) from {source}"]
    axes = nominal_axes(frame)
    for k, th in enumerate(vehicle.thrusters):
        key = f"MOT_{k + 1}_DIRECTION"
        got = params.get(key)
        mot = 1 if got is None else int(round(float(got)))
        if mot not in (-1, 1):
            raise ValueError(f"{source}: {key} = {got}; expected -1 or 1")
        e = np.asarray(th.direction, dtype=float) * implied.directions[k] * mot  # = MOT * nominal on the line
        changed = implied.directions[k] != mot
        values[f"thrusters[name={th.name}].direction"] = [float(v) + 0.0 for v in e]  # no -0.0 in the file
        notes[f"thrusters[name={th.name}]"] = (f"direction = {key} ({mot:+d}, {source}) x ArduSub {name} motor "
                                               f"{k + 1}'s nominal axis {_vec(axes[k])} on the base file's line")
        what = "reversed" if changed else "kept"
        lines.append(f"thruster {th.name}: {key} = {mot:+d}{'' if got is not None else ' (not reported: +1)'} -> "
                     f"direction {_vec(e)} ({what})")
    for key, attr in (("MOT_PWM_MIN", "pwm_min_us"), ("MOT_PWM_MAX", "pwm_max_us")):
        got = params.get(key)
        if got is not None and math.isfinite(float(got)) and float(got) > 0:
            for th in vehicle.thrusters:
                values[f"thrusters[name={th.name}].{attr}"] = int(round(float(got)))
            lines.append(f"{attr} = {int(round(float(got)))} us for every thruster ({key})")
    for th in vehicle.thrusters:
        if abs(th.pwm_neutral_us - PWM_NEUTRAL_US) > 0.5:
            values[f"thrusters[name={th.name}].pwm_neutral_us"] = int(PWM_NEUTRAL_US)
    lines.append("pwm_neutral_us = 1500 us (ArduSub's fixed neutral: 1500 + 400 output)")
    return values, notes, lines


def read_parameters(path: str | Path) -> dict[str, float]:
    """The parameters a log carries: the last PARAM_VALUE of each name in a .tlog, the last PARM of
    each name in a DataFlash .BIN (pymavlink reads both). ParameterError naming the file when it
    cannot be read or carries no parameters."""
    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"{p}: no such file")
    if p.suffix.lower() not in LOG_SUFFIXES:
        raise ParameterError(f"{p}: not an ArduSub log (expected {' or '.join(LOG_SUFFIXES)})")
    from rovlab.interfaces.mavlink import connection

    try:
        conn = connection(os.fspath(p))
    except Exception as exc:  # noqa: BLE001 - pymavlink raises many kinds on a corrupt file
        raise ParameterError(f"{p}: cannot be read as a MAVLink log ({type(exc).__name__}: {exc})") from None
    params: dict[str, float] = {}
    try:
        while True:
            try:
                msg = conn.recv_match(type=["PARAM_VALUE", "PARM"])
            except Exception as exc:  # noqa: BLE001
                raise ParameterError(f"{p}: unreadable after {len(params)} parameters "
                                     f"({type(exc).__name__}: {exc})") from None
            if msg is None:
                break
            if msg.get_type() == "PARAM_VALUE":
                name, value = msg.param_id, msg.param_value
            else:
                name, value = msg.Name, msg.Value
            if isinstance(name, bytes):
                name = name.decode("ascii", "replace")
            name = str(name).split("\x00", 1)[0].strip()
            if name and isinstance(value, (int, float)) and math.isfinite(float(value)):
                params[name] = float(value)
    finally:
        try:
            conn.close()
        except Exception:  # noqa: BLE001 - closing a reader cannot fail usefully
            pass
    if not params:
        raise ParameterError(f"{p}: carries no parameters (no PARAM_VALUE / PARM messages)")
    return params


def fetch_parameters(url: str, *, timeout_s: float = 30.0, source_system: int = 255) -> tuple[dict[str, float], str]:
    """Every parameter of a live autopilot over MAVLink (PARAM_REQUEST_LIST, then PARAM_REQUEST_READ
    of each index still missing): (parameters, a description of where they came from).
    ParameterError naming the link when no autopilot answers or the list stays incomplete within
    ``timeout_s`` (the link is closed either way)."""
    import time

    from rovlab.interfaces.mavlink import connection

    try:
        conn = connection(url, source_system=source_system, source_component=190)
    except Exception as exc:  # noqa: BLE001 - pymavlink raises many kinds for a bad address
        raise ParameterError(f"{url}: cannot open the link ({type(exc).__name__}: {exc})") from None
    try:
        deadline = time.monotonic() + timeout_s
        hb = None
        while hb is None and time.monotonic() < deadline:
            m = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if m is not None and m.get_srcComponent() == 1 and m.type != 6:  # an autopilot, not a GCS
                hb = m
        if hb is None:
            raise ParameterError(f"{url}: no autopilot HEARTBEAT within {timeout_s:g} s")
        sysid = hb.get_srcSystem()
        conn.target_system, conn.target_component = sysid, 1
        values: dict[int, tuple[str, float]] = {}
        count: int | None = None
        asked = 0.0
        conn.mav.param_request_list_send(sysid, 1)
        while time.monotonic() < deadline:
            m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            now = time.monotonic()
            if m is not None and m.get_srcSystem() == sysid:
                count = int(m.param_count)
                name = m.param_id.decode("ascii", "replace") if isinstance(m.param_id, bytes) else str(m.param_id)
                values[int(m.param_index)] = (name.split("\x00", 1)[0].strip(), float(m.param_value))
            if count is not None and len(values) >= count:
                break
            if m is None and count is not None and now - asked > 1.0:  # the list paused: ask for what is missing
                for i in [i for i in range(count) if i not in values][:20]:
                    conn.mav.param_request_read_send(sysid, 1, b"", i)
                asked = now
        if count is None or len(values) < count:
            raise ParameterError(f"{url}: system {sysid} sent {len(values)} of {count if count is not None else '?'} "
                                 f"parameters within {timeout_s:g} s")
        params = {name: v for name, v in values.values() if name and math.isfinite(v)}
        return params, f"{url} (system {sysid}, {len(params)} parameters)"
    finally:
        try:
            conn.close()
        except Exception:  # noqa: BLE001
            pass


def _vec(v: Any) -> str:
    return "(" + ", ".join(f"{float(x) + 0.0:+.3g}" for x in np.asarray(v, dtype=float)) + ")"
