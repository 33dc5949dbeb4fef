"""An rclpy peer for `rovlab ros2 node --fly PLAN` against `rovlab ros2 sim` (issue 29): run with the
ROS 2 environment's Python inside a loopback-only network namespace (tests/ros/conftest.py).

    ros2_fly_peer.py PLAN --logdir DIR              # the plan flown to its end: the node exits 0
    ros2_fly_peer.py PLAN --logdir DIR --abort 3    # a message on fly/abort 3 s into the flight: exit 1

Prints one JSON object: the node's exit status, its log, and the wrench and PWM it published.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import rclpy
from geometry_msgs.msg import WrenchStamped
from std_msgs.msg import Float64MultiArray, String

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros2_peer import ALL_NEW, RELIABLE, spin_until, start, stop  # noqa: E402

WARM = """
from rovlab.interfaces.node.runtime import load_node, load_sim
from rovlab.ident.plan import read_plan
core, _ = load_node("bluerov2_heavy", "bluerov2_heavy")
core.fly(read_plan({plan!r}))
sim = load_sim("bluerov2-heavy-step", "bluerov2_heavy")
sim.step(); sim.step()
"""


def fly(plan: str, logdir: str, abort_after: float | None) -> dict:
    out: dict = {}
    subprocess.run([sys.executable, "-c", WARM.format(plan=plan)], check=True, timeout=1200, capture_output=True)
    rclpy.init()
    node = rclpy.create_node("rovlab_fly_observer")
    wrench: list[tuple[float, float]] = []
    pwm: list[list[float]] = []
    sim = nodep = None
    log = os.path.join(logdir, "node.log")
    try:
        node.create_subscription(WrenchStamped, "/wrench", lambda m: wrench.append((m.wrench.force.z, m.wrench.torque.z)),
                                 ALL_NEW)
        node.create_subscription(Float64MultiArray, "/thrusters/pwm_us", lambda m: pwm.append(list(m.data)), ALL_NEW)
        pub_abort = node.create_publisher(String, "/fly/abort", RELIABLE)
        sim = start(["ros2", "sim", "--scenario", "bluerov2-heavy-step", "--vehicle", "bluerov2_heavy", "--no-setpoints",
                     "--duration", "400"], os.path.join(logdir, "sim.log"))
        nodep = start(["ros2", "node", "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy", "--fly", plan,
                       "--record", os.path.join(logdir, "node.mcap")], log)

        def flying() -> bool:
            with open(log, encoding="utf-8") as fh:
                return "flying the plan" in fh.read()

        out["started"] = spin_until(node, lambda: flying() or nodep.poll() is not None, 240.0) and flying()
        if abort_after is not None and out["started"]:
            spin_until(node, lambda: False, abort_after)
            out["pwm_before_abort"] = pwm[-1] if pwm else None
            pub_abort.publish(String(data="pilot takes over"))
        t0 = time.monotonic()
        spin_until(node, lambda: nodep.poll() is not None, 300.0)
        out["ended_after_s"] = time.monotonic() - t0
        out["pwm_last"] = pwm[-1] if pwm else None
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        out["node_exit"] = stop(nodep) if nodep else None
        out["sim_exit"] = stop(sim) if sim else None
    with open(log, encoding="utf-8") as fh:
        out["node_log"] = fh.read()[-6000:]
    out["wrench"] = wrench
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("plan")
    ap.add_argument("--logdir", default=".")
    ap.add_argument("--abort", type=float, default=None)
    a = ap.parse_args()
    print("RESULT " + json.dumps(fly(a.plan, a.logdir, a.abort)))


if __name__ == "__main__":
    main()
