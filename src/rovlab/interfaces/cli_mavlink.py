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

    s = cmds.add_parser("sim", help="a simulated ArduSub vehicle speaking MAVLink, on rovlab's plant model")
    s.add_argument("--vehicle", default="bluerov2_heavy",
                   help="vehicle name or TOML file (default bluerov2_heavy)")
    s.add_argument("--connect", default="udpout:127.0.0.1:14550",
                   help="pymavlink connection string (default udpout:127.0.0.1:14550: sends to a ground "
                        "station listening with udpin on 14550, as a vehicle does)")
    s.add_argument("--depth", type=float, default=0.0, help="initial depth [m] (default 0)")
    s.add_argument("--heading-deg", type=float, default=0.0, help="initial heading [deg] (default 0)")
    s.add_argument("--seed", type=int, default=0, help="seed of the plant and sensor noise (default 0)")
    s.add_argument("--local-position", action="store_true",
                   help="also send LOCAL_POSITION_NED (as a vehicle with a positioning system does)")
    s.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: run "
                                                                "until Ctrl-C)")
    s.set_defaults(func=_cmd_sim)

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

    for name in ("depth", "heading_deg"):
        if not math.isfinite(getattr(args, name)):
            raise UserError(f"--{name.replace('_', '-')} must be a finite number")
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    _check_connect(args.connect)
    vehicle = load_vehicle(args.vehicle)
    try:
        from rovlab.interfaces.mavlink.vehicle_sim import ArduSubSim

        sim = ArduSubSim(vehicle, connect=args.connect, seed=args.seed, depth_m=args.depth,
                         heading_rad=math.radians(args.heading_deg), local_position=args.local_position,
                         log=lambda text: print(f"rovlab mavlink sim: {text}", file=sys.stderr, flush=True))
    except MavlinkMissing as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"cannot open {args.connect}: {exc.strerror or exc}") from None
    _stop_on_signals(sim.stop)
    print(f"rovlab mavlink sim: {vehicle.name} as ArduSub system {sim.sysid} on {args.connect} "
          f"({len(vehicle.thrusters)} thrusters; Ctrl-C stops)", flush=True)
    try:
        sim.run(duration_s=args.duration)
    finally:
        sim.close()
        print(f"rovlab mavlink sim: stopped ({sim.counts['received']} messages received, "
              f"{sim.counts['bad_data']} malformed, {sim.counts['refused']} refused)", file=sys.stderr, flush=True)
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    import threading
    import time

    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.mavlink import MavlinkMissing, mavutil
    from rovlab.interfaces.mavlink.logs import TelemetryRecorder

    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    _check_connect(args.connect)
    try:
        conn = mavutil().mavlink_connection(args.connect, source_system=255, source_component=191,
                                            dialect="ardupilotmega")
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
    from rovlab.interfaces.mavlink.logs import LogError, write_filter_log
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
    counts = ", ".join(f"{k} {v}" for k, v in summary["samples"].items())
    print(f"{args.log}: {summary['messages']} MAVLink messages -> {args.out}: {summary['rows']} rows ({counts})")
    return 0
