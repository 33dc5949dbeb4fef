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
