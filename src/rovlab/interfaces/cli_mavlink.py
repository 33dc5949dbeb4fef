"""Sub-command ``mavlink``: a simulated ArduSub vehicle (``sim``), the bridge from an ArduSub
vehicle to rovlab's estimator and controller (``bridge``) and the conversion of MAVLink logs
(``convert``). pymavlink is imported only when one of them runs (docs/mavlink.md)."""

from __future__ import annotations

import argparse
import math
import signal
import sys
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("mavlink", help="MAVLink for ArduSub vehicles (BlueROV2): simulator, bridge, log conversion")
    cmds = p.add_subparsers(dest="mavlink_command", metavar="ACTION")
    cmds.required = True

    s = cmds.add_parser("sim", help="a simulated ArduSub vehicle speaking MAVLink: a scenario's plant and sensors "
                                    "in real time")
    s.add_argument("--scenario", default="bluerov2-heavy-step",
                   help="packaged scenario name or TOML file whose plant, sensors, noise, biases and drop-outs "
                        "are simulated (default bluerov2-heavy-step; its set-points are not used)")
    s.add_argument("--vehicle", default=None,
                   help="vehicle name or TOML file replacing the scenario's (default: the scenario's)")
    s.add_argument("--connect", default="udpout:127.0.0.1:14550",
                   help="pymavlink connection string (default udpout:127.0.0.1:14550: sends to a ground "
                        "station listening with udpin on 14550, as a vehicle does)")
    s.add_argument("--depth", type=float, default=None, help="initial depth [m] (default: the scenario's)")
    s.add_argument("--heading-deg", type=float, default=None, help="initial heading [deg] (default: the scenario's)")
    s.add_argument("--seed", type=int, default=None, help="seed of the plant and sensor noise (default: the "
                                                           "scenario's)")
    s.add_argument("--local-position", action="store_true",
                   help="also send LOCAL_POSITION_NED (as a vehicle with a positioning system does)")
    s.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: run "
                                                                "until Ctrl-C)")
    s.add_argument("--firmware", choices=("4.7", "4.1"), default="4.7",
                   help="which generation of ArduSub parameter names to emulate: 4.7 (MAV_SYSID, MAV_GCS_SYSID; "
                        "the default) or 4.1 (SYSID_THISMAV, SYSID_MYGCS)")
    s.add_argument("--home", default="63.44,10.40,0",
                   help="LAT,LON[,ALT] of the home position and EKF origin [deg, deg, m] (default 63.44,10.40,0), "
                        "or 'none' for a vehicle without one (MAV_CMD_GET_HOME_POSITION then fails, as on ArduSub)")
    s.set_defaults(func=_cmd_sim)

    b = cmds.add_parser("bridge", help="run rovlab's estimator (and controller) on an ArduSub vehicle over MAVLink")
    add_bridge_arguments(b)
    b.add_argument("--depth", type=float, default=None,
                   help="depth set-point [m]: engages the controller (default: estimate only, command nothing)")
    b.add_argument("--heading-deg", type=float, default=None, help="heading set-point [deg] (with --depth; default: "
                                                                  "the estimated heading when engaged)")
    b.add_argument("--north", type=float, default=None,
                   help="north set-point x [m] of the vehicle's EKF origin (LOCAL_POSITION_NED), with --depth; a DP "
                        "configuration only, e.g. --config ardusub_sitl_heavy_dp (default: the estimated position)")
    b.add_argument("--east", type=float, default=None, help="east set-point y [m], as --north")
    b.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    b.add_argument("--status-every", type=float, default=2.0, help="print the estimate every N s (0: never)")
    add_fly_arguments(b)
    b.set_defaults(func=_cmd_bridge)

    r = cmds.add_parser("record", help="record a vehicle's MAVLink telemetry to MCAP (a listener: sends nothing)")
    r.add_argument("--connect", default="udpin:127.0.0.1:14550",
                   help="pymavlink connection string (default udpin:127.0.0.1:14550, where a vehicle sends)")
    r.add_argument("--out", required=True, help="MCAP file to write (replay it with rovlab filter FILE.mcap)")
    r.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    r.set_defaults(func=_cmd_record)

    c = cmds.add_parser("convert", help="a .tlog or recorded .mcap as the CSV log rovlab filter reads")
    c.add_argument("log", help=".tlog (QGroundControl, MAVProxy, BlueOS) or .mcap recorded by rovlab mavlink")
    c.add_argument("--vehicle", default="bluerov2_heavy", help="vehicle name or TOML file (default bluerov2_heavy)")
    c.add_argument("--config", default="bluerov2_heavy", help="filter configuration (default bluerov2_heavy): "
                                                              "its channels and sample time shape the CSV")
    c.add_argument("--surface-hpa", type=float, default=None,
                   help="surface pressure [hPa] (default: BARO2_GND_PRESS from the log, else 1013.25)")
    c.add_argument("--out", required=True, help="CSV file to write")
    c.set_defaults(func=_cmd_convert)


def add_bridge_arguments(p: argparse.ArgumentParser, *, connect_default: str = "udpin:127.0.0.1:14550") -> None:
    """Options of the bridge, shared with ``rovlab hmi --source mavlink``."""
    p.add_argument("--connect", default=connect_default,
                   help=f"pymavlink connection string to the vehicle (default {connect_default}: where ArduSub / "
                        "BlueOS sends telemetry to a topside)")
    p.add_argument("--vehicle", default="bluerov2_heavy", help="vehicle name or TOML file (default bluerov2_heavy)")
    p.add_argument("--config", default="bluerov2_heavy",
                   help="filter/controller configuration name or TOML file (default bluerov2_heavy)")
    p.add_argument("--target-system", type=int, default=1, help="the vehicle's MAVLink system id (default 1)")
    p.add_argument("--sysid", type=int, default=255,
                   help="the bridge's MAVLink system id; must be the vehicle's ground station id, MAV_GCS_SYSID "
                        "(SYSID_MYGCS before ArduSub 4.7; default 255)")
    p.add_argument("--command", choices=("manual_control", "rc_override"), default="manual_control",
                   dest="command_mode",  # not args.command: the sub-command's name, which errors are prefixed with
                   help="how to command ArduSub: MANUAL_CONTROL (default) or RC_CHANNELS_OVERRIDE")
    p.add_argument("--command-hz", type=float, default=None, help="command rate [Hz] (default: the control rate)")
    p.add_argument("--telemetry-timeout", type=float, default=0.5,
                   help="seconds without telemetry before neutral commands are sent (default 0.5)")
    p.add_argument("--arm", action="store_true", help="set MANUAL mode and arm the vehicle (disarm on exit)")
    p.add_argument("--record", default=None, help="record telemetry and rovlab's messages to this MCAP file")
    p.add_argument("--trust-vehicle-file", action="store_true",
                   help="command even when the vehicle's own parameters (frame, MOT_n_DIRECTION, PWM range) disagree "
                        "with the vehicle file (default: stop before commanding anything, exit 2)")


def add_fly_arguments(p: argparse.ArgumentParser) -> None:
    """Options of flying a dive plan (``--fly``), shared with ``rovlab ros2 node``."""
    from rovlab.interfaces.node.flight import GUARD_RANGES, FlightGuards

    d = FlightGuards()
    r = GUARD_RANGES
    p.add_argument("--fly", metavar="PLAN", default=None,
                   help="fly this dive plan (rovlab lab plan-dive) at its start depth (the bridge: armed in MANUAL), "
                        "with depth and heading guards; abort to neutral on a guard, lost telemetry or pilot input; "
                        "then stop (exit 1 if aborted). Record it with --record; docs/identification.md 'Flying a plan'")
    p.add_argument("--fly-guard-depth-margin", type=float, default=d.depth_margin_m, metavar="M",
                   help=f"abort when the depth leaves the plan's band by more than this [m] (default "
                        f"{d.depth_margin_m:g}, {r['depth_margin_m'][0]:g} .. {r['depth_margin_m'][1]:g})")
    p.add_argument("--fly-guard-turns", type=float, default=d.turns, metavar="N",
                   help=f"abort beyond this many turns either way from the start heading (default {d.turns:g}, "
                        f"{r['turns'][0]:g} .. {r['turns'][1]:g}; a tether winds up)")
    p.add_argument("--fly-guard-yaw-rate-deg", type=float, default=None, metavar="DEG_S",
                   help="abort beyond this yaw rate [deg/s] (default twice the plan's yaw rate, at least 57.3; "
                        f"{math.degrees(r['yaw_rate_rad_s'][0]):.1f} .. {math.degrees(r['yaw_rate_rad_s'][1]):.0f})")
    p.add_argument("--fly-start-tolerance", type=float, default=d.start_tolerance_m, metavar="M",
                   help=f"start the plan within this distance of its start depth [m] (default {d.start_tolerance_m:g}, "
                        f"{r['start_tolerance_m'][0]:g} .. {r['start_tolerance_m'][1]:g})")


def load_flight(args: argparse.Namespace, vehicle_name: str) -> tuple[Any, Any] | None:
    """(plan, guards) of the --fly options (None without --fly); UserError / ConfigError (exit 2)
    for a bad plan file or guard, each named with its value and what was expected."""
    from rovlab.ident.plan import read_plan
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.node.flight import GUARD_RANGES, FlightGuards

    if args.fly is None:
        return None
    for name in ("fly_guard_depth_margin", "fly_guard_turns", "fly_guard_yaw_rate_deg", "fly_start_tolerance"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise UserError(f"--{name.replace('_', '-')} must be a finite number, got {v}")
    rate = args.fly_guard_yaw_rate_deg
    lo, hi, _ = GUARD_RANGES["yaw_rate_rad_s"]
    if rate is not None and not lo <= math.radians(rate) <= hi:
        raise UserError(f"--fly-guard-yaw-rate-deg must be within {math.degrees(lo):.1f} .. {math.degrees(hi):.0f} "
                        f"deg/s, got {rate:g}")
    try:
        guards = FlightGuards(depth_margin_m=args.fly_guard_depth_margin, turns=args.fly_guard_turns,
                              yaw_rate_rad_s=None if rate is None else math.radians(rate),
                              start_tolerance_m=args.fly_start_tolerance).validated()
    except ValueError as exc:
        option = {"depth_margin_m": "--fly-guard-depth-margin", "turns": "--fly-guard-turns",
                  "start_tolerance_m": "--fly-start-tolerance"}
        text = str(exc)
        for key, opt in option.items():
            text = text.replace(f"flight guard {key}", opt)
        raise UserError(text) from None
    try:
        plan = read_plan(args.fly)
    except OSError as exc:
        raise UserError(f"--fly {args.fly}: cannot read it: {exc.strerror or exc}") from None
    if plan.vehicle != vehicle_name:
        raise UserError(f"--fly {args.fly}: the plan is for vehicle {plan.vehicle!r}, this is {vehicle_name!r}: its trim "
                        f"and thrust limits are another vehicle's (rovlab lab plan-dive --vehicle {vehicle_name} plans "
                        "one for it)")
    return plan, guards


def make_bridge(args: argparse.Namespace, log: Any) -> Any:
    """A MavlinkBridge from the shared options (UserError for bad ones)."""
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    _check_connect(args.connect)
    for name in ("target_system", "sysid"):
        if not 1 <= getattr(args, name) <= 255:
            raise UserError(f"--{name.replace('_', '-')} must be 1 .. 255, got {getattr(args, name)}")
    vehicle = load_vehicle(args.vehicle)
    config = load_design_config(args.config)
    try:
        from rovlab.interfaces.mavlink.bridge import MavlinkBridge

        return MavlinkBridge(vehicle, config, connect=args.connect, target_system=args.target_system,
                             sysid=args.sysid, command=args.command_mode, command_hz=args.command_hz,
                             telemetry_timeout_s=args.telemetry_timeout, arm=args.arm, record=args.record, log=log,
                             trust_vehicle_file=getattr(args, "trust_vehicle_file", False))
    except MavlinkMissing as exc:
        raise UserError(str(exc)) from None
    except ValueError as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot open {args.connect} or {args.record}: {exc.strerror or exc}") from None


def _check_connect(url: str) -> None:
    from rovlab.interfaces.cli import UserError

    kind, _, rest = url.partition(":")
    if kind in ("udpin", "udpout", "udp", "tcp", "tcpin"):
        port = rest.rsplit(":", 1)[-1]
        if not port.isdigit() or not 0 < int(port) < 65536:
            raise UserError(f"--connect {url!r}: expected e.g. udpin:127.0.0.1:14550 (a port 1 .. 65535)")
    elif not kind:
        raise UserError(f"--connect {url!r}: expected a pymavlink connection string such as udpin:127.0.0.1:14550")


def _stop_on_signals(stop: Any) -> None:
    def handler(signum: int, frame: Any) -> None:
        stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, handler)
        except ValueError:  # pragma: no cover - not in the main thread
            pass


def _cmd_sim(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing
    from rovlab.params.vehicle import load_vehicle
    from rovlab.sim.scenario import load_scenario

    initial = {}
    for name, key, scale in (("depth", "z", 1.0), ("heading_deg", "psi", math.pi / 180.0)):
        value = getattr(args, name)
        if value is None:
            continue
        if not math.isfinite(value):
            raise UserError(f"--{name.replace('_', '-')} must be a finite number")
        initial[key] = value * scale
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    _check_connect(args.connect)
    home = _parse_home(args.home)
    scenario = load_scenario(args.scenario, seed=args.seed)
    vehicle = load_vehicle(args.vehicle) if args.vehicle else None

    def log(text: str) -> None:
        print(f"rovlab mavlink sim: {text}", file=sys.stderr, flush=True)

    try:
        from rovlab.interfaces.mavlink.vehicle_sim import ArduSubSim
        from rovlab.sim.realtime import SimulatedVehicle

        try:
            vsim = SimulatedVehicle(scenario, vehicle=vehicle, initial=initial)
        except ValueError as exc:
            raise UserError(f"scenario {args.scenario}: {exc}") from None
        _compile_announced(vsim, log)
        sim = ArduSubSim(vsim, connect=args.connect, local_position=args.local_position, firmware=args.firmware,
                         home=home, log=log)
    except MavlinkMissing as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot open {args.connect}: {exc.strerror or exc}") from None
    _stop_on_signals(sim.stop)
    print(f"rovlab mavlink sim: {sim.vehicle.name} ({scenario.name}, seed {scenario.seed}) as ArduSub system "
          f"{sim.sysid} on {args.connect} ({len(sim.vehicle.thrusters)} thrusters, ArduSub {args.firmware} parameter "
          "names; Ctrl-C stops)", flush=True)
    try:
        sim.run(duration_s=args.duration)
    finally:
        sim.close()
        print(f"rovlab mavlink sim: stopped ({sim.counts['received']} messages received, "
              f"{sim.counts['bad_data']} malformed, {sim.counts['refused']} refused)", file=sys.stderr, flush=True)
    return 0


def _parse_home(text: str) -> tuple[float, float, float] | None:
    from rovlab.interfaces.cli import UserError

    if text.strip().lower() == "none":
        return None
    parts = text.split(",")
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values) \
            or not (-90 <= values[0] <= 90 and -180 <= values[1] <= 180):
        raise UserError(f"--home {text!r}: expected LAT,LON[,ALT] (latitude -90 .. 90, longitude -180 .. 180 deg, "
                        "altitude m) or none")
    lat, lon = values[0], values[1]
    return lat, lon, values[2] if len(values) == 3 else 0.0


def _compile_announced(vsim: Any, log: Any) -> None:
    """Compile the simulated vehicle's plant before anything is sent (a ground station that sees a
    HEARTBEAT and then nothing declares the link lost); say so, with the elapsed time, when it
    takes a while."""
    from rovlab._jit import with_progress

    _, seconds = with_progress(vsim.compile, log, "the simulated vehicle's plant",
                               hint="; `rovlab compile --realtime` prepares it ahead")
    if seconds > 1.0:
        log(f"compiled the simulated vehicle's plant in {seconds:.1f} s")


def _cmd_record(args: argparse.Namespace) -> int:
    import threading
    import time

    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing, connection
    from rovlab.interfaces.mavlink.logs import TelemetryRecorder

    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    _check_connect(args.connect)
    try:
        conn = connection(args.connect, source_system=255, source_component=191)
    except MavlinkMissing as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot open {args.connect}: {exc.strerror or exc}") from None
    try:
        recorder = TelemetryRecorder(args.out, metadata={"connect": args.connect})
    except OSError as exc:
        conn.close()
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    stop = threading.Event()
    _stop_on_signals(stop.set)
    print(f"rovlab mavlink record: {args.connect} -> {args.out} (Ctrl-C stops)", flush=True)
    start = time.monotonic()
    bad = 0
    try:
        while not stop.is_set() and (args.duration is None or time.monotonic() - start < args.duration):
            try:
                msg = conn.recv_match(blocking=True, timeout=0.1)
            except Exception:  # noqa: BLE001 - a broken packet must not end the recording
                bad += 1
                continue
            if msg is None:
                continue
            if msg.get_type() == "BAD_DATA":
                bad += 1
                continue
            recorder.mavlink(msg, time.time())
    finally:
        recorder.close()  # nothing recorded is lost, whatever ended the loop
        conn.close()
        print(f"rovlab mavlink record: {recorder.stream.count} messages -> {args.out}"
              + (f" ({bad} malformed skipped)" if bad else ""), file=sys.stderr, flush=True)
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from rovlab.estimation.model import build_filter_model
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing
    from rovlab.interfaces.mavlink.logs import LogError, left_out_lines, write_filter_log
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    if args.surface_hpa is not None and not (math.isfinite(args.surface_hpa) and 500 <= args.surface_hpa <= 1100):
        raise UserError(f"--surface-hpa must be 500 .. 1100 hPa, got {args.surface_hpa}")
    vehicle = load_vehicle(args.vehicle)
    model = build_filter_model(vehicle, load_design_config(args.config))
    try:
        summary = write_filter_log(args.log, vehicle, model, args.out, surface_hpa=args.surface_hpa)
    except (LogError, MavlinkMissing, RuntimeError) as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    for line in left_out_lines(args.log, summary):
        print(f"rovlab mavlink convert: {line}", file=sys.stderr)
    counts = ", ".join(f"{k} {v}" for k, v in summary["samples"].items())
    print(f"{args.log}: {summary['messages']} MAVLink messages -> {args.out}: {summary['rows']} rows ({counts})")
    return 0


def _cmd_bridge(args: argparse.Namespace) -> int:
    import threading
    import time

    from rovlab.interfaces.cli import UserError

    for name in ("depth", "heading_deg", "north", "east", "duration"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise UserError(f"--{name.replace('_', '-')} must be a finite number")
    if args.depth is not None and args.depth < 0:
        raise UserError(f"--depth must be >= 0 m (z is positive down), got {args.depth}")
    if args.heading_deg is not None and args.depth is None:
        raise UserError("--heading-deg needs --depth (the controller holds both)")
    if (args.north is not None or args.east is not None) and args.depth is None:
        raise UserError("--north/--east need --depth (the DP controller holds x, y, z and heading together)")
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    if args.fly is not None and args.depth is not None:
        raise UserError("--fly and --depth: the plan brings the vehicle to its own start depth (give one of them)")

    def log(text: str) -> None:
        print(f"rovlab mavlink bridge: {text}", file=sys.stderr, flush=True)

    from rovlab.params.vehicle import load_vehicle

    flight = load_flight(args, load_vehicle(args.vehicle).name) if args.fly is not None else None
    bridge = make_bridge(args, log)
    if (args.north is not None or args.east is not None) and not bridge.dp:
        bridge.close()
        raise UserError(f"--north/--east: the configuration {bridge.core.config.name} (controller "
                        f"{bridge.core.controller_name}) holds {', '.join(bridge.core.references)}, no north/east "
                        "set-point; use a DP configuration (controller = \"dp\", e.g. --vehicle ardusub_sitl_heavy_gps "
                        "--config ardusub_sitl_heavy_dp)")
    if args.depth is not None:
        bridge.set_reference(z=args.depth, psi=None if args.heading_deg is None else math.radians(args.heading_deg),
                             x=args.north, y=args.east)
    doing = "holding " + format(args.depth, "g") + " m" if args.depth is not None else "estimating only"
    if flight is not None:
        try:
            bridge.fly(*flight)
        except ValueError as exc:
            bridge.close()
            raise UserError(f"--fly {args.fly}: {exc}") from None
        doing = f"flying {args.fly} once armed in MANUAL at {flight[0].start_depth:g} m"
        if not args.record:
            log("--fly without --record: nothing of the flight is recorded here (rovlab identify dive needs a log)")
    _stop_on_signals(bridge.stop)
    print(f"rovlab mavlink bridge: {bridge.core.vehicle.name}/{bridge.core.config.name} on {args.connect} "
          f"({doing}; Ctrl-C stops)", flush=True)
    thread = threading.Thread(target=bridge.run, kwargs={"duration_s": args.duration}, daemon=True)
    thread.start()
    next_print = time.monotonic() + args.status_every if args.status_every > 0 else math.inf
    while thread.is_alive():
        thread.join(0.2)
        if time.monotonic() >= next_print:
            next_print += args.status_every
            o = bridge.core.last
            if o is None or bridge.telemetry_lost(time.monotonic()):  # no estimate to show, only a prediction
                seen = bridge.last_telemetry
                since = "none received yet" if seen is None else f"none for {time.monotonic() - seen:.0f} s"
                print(f"no telemetry from the vehicle ({since}): no estimate, no control, "
                      f"{'armed' if bridge.armed else 'disarmed'}", flush=True)
                continue
            predicted = " (PREDICTED: no depth sensor)" if bridge.depth_problem is not None else ""
            held = "holding" if bridge.core.engaged else (f"not holding ({bridge.hold_blocked})" if bridge.hold_blocked
                                                           else "not holding")
            where = f"x={o.nav[0]:.2f} m  y={o.nav[1]:.2f} m  " if bridge.dp else ""  # nav: x, y, z, psi, ...
            print(f"t={o.t:7.1f} s  {where}z={o.nav[2]:.3f} m{predicted}  psi={math.degrees(o.nav[3]):6.1f} deg  "
                  f"tau_Z={o.tau[2]:6.2f} N  sensors={o.sensor_status}  "
                  f"{'FAILSAFE ' if bridge.failsafe else ''}{'armed' if bridge.armed else 'disarmed'}, {held}"
                  + (f", flight {bridge.flight.flight.state} {bridge.flight.flight.duration_s:.0f} s"
                     if bridge.flight is not None else ""), flush=True)
    c = bridge.counts
    print(f"rovlab mavlink bridge: stopped ({c['received']} messages in, {c['commands']} commands out, "
          f"{c['failsafes']} telemetry failsafes)" + (f"; recording: {args.record}" if args.record else ""),
          file=sys.stderr, flush=True)
    # (a flight stopped before its end was aborted, said and recorded by the bridge's close)
    # 2: the vehicle file disagreed with the vehicle's parameters (said above); 1: a flight aborted
    return bridge.exit_code
