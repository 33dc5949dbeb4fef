"""Sub-commands ``ros2`` and ``ros1``: the vehicle node and a simulated vehicle on ROS topics
(rovlab.interfaces.node). The middleware is imported only when one of them runs."""

from __future__ import annotations

import argparse
import math


def register(sub: argparse._SubParsersAction) -> None:
    for ros, needs in (("ros2", "pip install 'rovlab[ros2]' (or a ROS 2 installation's rclpy)"),
                       ("ros1", "Debian's python3-rospy and message packages (scripts/ensure-ros1.sh)")):
        p = sub.add_parser(ros, help=f"run the vehicle node or a simulated vehicle on {ros.upper()} ({needs})")
        what = p.add_subparsers(dest="what", metavar="{node,sim}")
        what.required = True
        n = what.add_parser("node", help="estimator and controller as a node: sensor topics in, odometry, "
                                         "wrench, PWM and diagnostics out")
        n.add_argument("--vehicle", default="udrone", help="vehicle name or TOML file (default udrone)")
        n.add_argument("--config", default="default", help="filter/controller configuration name or TOML file")
        n.add_argument("--namespace", default="", help="namespace of the topics (default: none)")
        n.add_argument("--mocap-covariance", action="store_true",
                       help="mocap/pose is geometry_msgs/PoseWithCovarianceStamped (default PoseStamped)")
        n.add_argument("--record", default=None, metavar="FILE.mcap",
                       help="record the node's inputs and outputs: a ROS 2 bag (MCAP) in FILE.mcap and "
                            "rovlab's series (JSON) in FILE.rovlab.mcap beside it")
        n.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                       help="remap a topic, e.g. mocap/pose:=/qualisys/rov/pose (repeatable)")
        if ros == "ros2":
            from rovlab.interfaces.cli_mavlink import add_fly_arguments

            add_fly_arguments(n)  # the plan flown at its start depth; a set-point or NS/fly/abort aborts it
        n.set_defaults(func=_cmd_node, ros=ros)
        s = what.add_parser("sim", help="a simulated vehicle in real time on the same topics")
        s.add_argument("--vehicle", default=None, help="vehicle name or TOML file (default: the scenario's)")
        s.add_argument("--scenario", default="step-process-model", help="packaged scenario name or TOML file")
        s.add_argument("--namespace", default="", help="namespace of the topics (default: none)")
        s.add_argument("--no-setpoints", action="store_true",
                       help="do not publish the scenario's reference schedule on NS/setpoint")
        s.add_argument("--duration", type=float, default=None,
                       help="stop after the vehicle has run this many seconds (counted from its start: the time "
                            "spent waiting for a node is not counted)")
        s.add_argument("--wait-limit", type=float, default=900.0, metavar="S",
                       help="give up (exit status 1) when no node has listened and commanded for this many seconds "
                            "(default 900: a node's first start on a slow machine compiles for minutes)")
        s.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                       help="remap a topic (repeatable)")
        s.add_argument("--no-wait", action="store_true",
                       help="start at once (default: hold the initial state until a node subscribes and commands)")
        s.set_defaults(func=_cmd_sim, ros=ros)


def _adapter(ros: str, namespace: str = ""):
    import os

    from rovlab.interfaces.cli import UserError

    if ros == "ros1" and namespace.strip("/"):  # rospy reads its namespace from the environment when imported
        os.environ["ROS_NAMESPACE"] = "/" + namespace.strip("/")
    try:
        if ros == "ros2":
            from rovlab.interfaces.node import ros2 as mod
        else:
            from rovlab.interfaces.node import ros1 as mod  # type: ignore[no-redef]
    except ImportError as exc:
        hint = ("pip install 'rovlab[ros2]' in its own environment (make ros2-env), or source a ROS 2 installation"
                if ros == "ros2" else "apt-get install python3-rospy python3-rosmaster python3-geometry-msgs "
                "python3-sensor-msgs python3-nav-msgs python3-diagnostic-msgs (scripts/ensure-ros1.sh)")
        raise UserError(f"{ros} is not available here ({exc}); {hint}") from None
    return mod


def _remaps(args: argparse.Namespace) -> list[str]:
    from rovlab.interfaces.cli import UserError

    for r in args.remap:
        a, sep, b = r.partition(":=")
        if not sep or not a or not b or " " in r:
            raise UserError(f"--remap {r!r}: expected FROM:=TO, e.g. mocap/pose:=/qualisys/rov/pose")
    return list(args.remap)


def _cmd_node(args: argparse.Namespace) -> int:
    remaps = _remaps(args)
    fly = None
    if getattr(args, "fly", None) is not None:
        from rovlab.interfaces.cli_mavlink import load_flight
        from rovlab.params.vehicle import load_vehicle

        fly = load_flight(args, load_vehicle(args.vehicle).name)
    mod = _adapter(args.ros, args.namespace)
    extra = {"fly": fly} if fly is not None else {}
    return int(mod.run_node(vehicle=args.vehicle, config=args.config, namespace=args.namespace,
                            mocap_covariance=args.mocap_covariance, record=args.record, remaps=remaps, **extra))


def _cmd_sim(args: argparse.Namespace) -> int:
    from rovlab.interfaces.cli import UserError

    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration must be > 0 s, got {args.duration}")
    if not args.wait_limit > 0 or not math.isfinite(args.wait_limit):
        raise UserError(f"--wait-limit must be a positive number of seconds, got {args.wait_limit}")
    remaps = _remaps(args)
    mod = _adapter(args.ros, args.namespace)
    return int(mod.run_sim(vehicle=args.vehicle, scenario=args.scenario, namespace=args.namespace,
                           setpoints=not args.no_setpoints, duration_s=args.duration, wait=not args.no_wait,
                           wait_limit_s=args.wait_limit,
                           remaps=remaps))
