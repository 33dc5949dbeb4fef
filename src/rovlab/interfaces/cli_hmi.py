"""Sub-command ``hmi``: the local web app to tune and watch a live simulation (see
rovlab.interfaces.hmi). Interfaces hold no maths."""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("hmi", help="local web app: tune the model, observer and controller, watch the estimates live")
    p.add_argument("--port", type=int, default=8765, help="TCP port on 127.0.0.1 (0 = pick a free one; default 8765)")
    p.add_argument("--scenario", default="step-process-model",
                   help="packaged scenario name or TOML file (default step-process-model; rovlab scenarios lists them)")
    p.add_argument("--vehicle", default=None, help="vehicle name or TOML file (default: the scenario's)")
    p.add_argument("--config", default=None, help="filter/controller configuration name or TOML file "
                                                  "(default: the scenario's)")
    p.add_argument("--seed", type=int, default=None, help="seed of the simulation (default: the scenario's)")
    p.add_argument("--speed", type=float, default=1.0, help="times real time (0.1 to 50, default 1)")
    p.add_argument("--paused", action="store_true", help="start paused (press Start in the page)")
    p.add_argument("--out", default="out/hmi", help="folder for saved parameters and the session log (default out/hmi)")
    p.add_argument("--source", choices=("simulation", "ros2", "mavlink"), default="simulation",
                   help="simulation (default); ros2: a running `rovlab ros2 node` (give it the node's --vehicle "
                        "and --config; needs rclpy, e.g. in .venv-ros2); mavlink: an ArduSub vehicle through "
                        "rovlab's MAVLink bridge (--connect; --vehicle/--config default to bluerov2_heavy)")
    p.add_argument("--namespace", default="", help="with --source ros2: the node's namespace")
    p.add_argument("--connect", default="udpin:127.0.0.1:14550",
                   help="with --source mavlink: pymavlink connection string (default udpin:127.0.0.1:14550)")
    p.add_argument("--arm", action="store_true", help="with --source mavlink: set MANUAL and arm the vehicle")
    p.add_argument("--record", default=None, help="with --source mavlink: record the telemetry to this MCAP file")
    p.set_defaults(func=_cmd_hmi)


def _cmd_hmi(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError

    try:
        import aiohttp  # noqa: F401
    except ImportError:
        raise UserError("the HMI needs aiohttp: pip install 'rovlab[hmi]'") from None
    if args.source == "simulation":
        from rovlab.interfaces.compiling import announce_compile, loop_of
        from rovlab.params.validate import ConfigError
        from rovlab.sim.scenario import load_scenario_data

        try:
            data, file = load_scenario_data(args.scenario)
        except (ConfigError, OSError):
            pass  # the session reports a bad scenario, with file and key
        else:
            announce_compile([loop_of(data, file, design=args.config)])
    from rovlab.interfaces.hmi.session import SPEED_RANGE, Session

    if not 0 <= args.port <= 65535:
        raise UserError(f"--port must be 0 .. 65535, got {args.port}")
    if not SPEED_RANGE[0] <= args.speed <= SPEED_RANGE[1]:
        raise UserError(f"--speed must be {SPEED_RANGE[0]:g} .. {SPEED_RANGE[1]:g}, got {args.speed:g}")
    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    closing = None
    if args.source == "ros2":
        session, closing = _ros2_session(args)
    elif args.source == "mavlink":
        session, source = _mavlink_session(args)
        closing = source.close  # neutral commands, disarm what it armed, close the recording
    else:
        session = Session.simulation(args.scenario, vehicle=args.vehicle, config=args.config, seed=args.seed,
                                     out_dir=Path(args.out), speed=args.speed, running=not args.paused)
    served: list[bool] = []  # set once the server listens: before that nobody could log anything
    try:
        return asyncio.run(_serve(session, args.port, served))
    finally:
        if served:
            _write_log(session)
        if closing is not None:
            closing()


def _ros2_session(args: argparse.Namespace):
    """A session on a running ROS 2 vehicle node: the same page and messages as a simulation."""
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.hmi.session import Session

    try:
        from rovlab.interfaces.node.ros2_source import Ros2Source, hmi_documents
    except ImportError as exc:
        raise UserError(f"--source ros2 needs rclpy ({exc}): run the HMI from .venv-ros2 (make ros2-env) or a "
                        "sourced ROS 2 installation") from None
    docs, stash = hmi_documents(args.vehicle or "udrone", args.config or "default")
    source = Ros2Source(vehicle=docs["vehicle"].value, config=docs["config"].value, config_data=docs["config"].data,
                        stash=stash, namespace=args.namespace)
    return Session(source, docs, out_dir=Path(args.out), running=not args.paused), source.close


def _mavlink_session(args: argparse.Namespace):
    """A session on an ArduSub vehicle through the MAVLink bridge (rovlab.interfaces.mavlink)."""
    from rovlab.interfaces.cli_mavlink import add_bridge_arguments, make_bridge
    from rovlab.interfaces.hmi.session import Session

    vehicle = args.vehicle or "bluerov2_heavy"
    config = args.config or "bluerov2_heavy"
    # the bridge's own options and defaults (rovlab mavlink bridge), with what this command was given
    bridge_parser = argparse.ArgumentParser(add_help=False)
    add_bridge_arguments(bridge_parser)
    bridge_args = bridge_parser.parse_args(["--connect", args.connect, "--vehicle", vehicle, "--config", config])
    bridge_args.arm, bridge_args.record = args.arm, args.record
    bridge = make_bridge(bridge_args, lambda text: print(f"rovlab hmi: mavlink: {text}", file=sys.stderr, flush=True))
    from rovlab.interfaces.mavlink.source import MavlinkSource

    source = MavlinkSource(bridge)
    try:
        return Session.for_vehicle(source, vehicle=vehicle, config=config, out_dir=Path(args.out)), source
    except Exception:
        source.close()
        raise


async def _serve(session, port: int, served: list[bool]) -> int:
    from rovlab.interfaces.cli import UserError
    from rovlab.interfaces.hmi.server import HmiServer

    server = HmiServer(session, port=port)
    try:
        url = await server.start()
    except OSError as exc:
        await server.stop()
        raise UserError(f"cannot listen on 127.0.0.1:{port}: {exc.strerror or exc} "
                        "(use --port 0 for a free port)") from None
    served.append(True)
    src = session.source.describe()
    if session.source.paced:
        print(f"rovlab hmi: {src['scenario']['name']} with {src['vehicle']} / {src['config']} "
              f"({'running' if session.running else 'paused'}, {session.speed:g}x real time)")
    else:
        print(f"rovlab hmi: {src['scenario']['name']} with {src['vehicle']} / {src['config']} (its own clock)")
    print(f"rovlab hmi: open {url} in a browser (Ctrl-C stops; the session log goes to {session.log.folder}/)",
          flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - not on this platform/thread
            pass
    try:
        await stop.wait()
    finally:
        await server.stop()
    return 0


def _write_log(session) -> None:
    """Nothing the user logged is lost: write the session log whatever way we stop."""
    if not session.log.rows and not session.log.events:
        print("rovlab hmi: stopped (nothing was logged)", file=sys.stderr)
        return
    try:
        paths = session.export()
    except OSError as exc:
        print(f"rovlab hmi: could not write the session log to {session.log.folder}: {exc}", file=sys.stderr)
        return
    print(f"rovlab hmi: stopped; session log ({session.log.rows} rows): "
          + ", ".join(str(p) for p in paths), file=sys.stderr)
