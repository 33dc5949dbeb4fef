"""An independent rospy peer for the ROS 1 node tests; run with .venv-ros1's Python inside a
loopback-only network namespace (tests/ros/conftest.py). It starts a rosmaster on 127.0.0.1,
``rovlab ros1`` processes, talks to them with plain rospy (standard messages and the parameter
server, no rovlab import) and prints one JSON object with what it saw.

    ros1_peer.py peer   [--ns NS]
    ros1_peer.py e2e    [--duration S]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import signal
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROVLAB = os.path.join(os.path.dirname(sys.executable), "rovlab")
PORT = 11321
os.environ.update(ROS_MASTER_URI=f"http://127.0.0.1:{PORT}", ROS_IP="127.0.0.1", ROS_HOSTNAME="127.0.0.1")

import rospy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from sensor_msgs.msg import FluidPressure  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

WARM = """
from rovlab.interfaces.node.runtime import load_node, load_sim
core, _ = load_node("udrone", "thesis")
sim = load_sim("step-process-model")
sim.step(); sim.step()
"""


def start(args: list[str], log: str) -> subprocess.Popen:
    fh = open(log, "w")  # noqa: SIM115
    return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT)


def stop(p: subprocess.Popen, timeout: float = 10.0) -> int | None:
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
    return p.returncode


def master(logdir: str) -> subprocess.Popen:
    m = start(["rosmaster", "--core", "-p", str(PORT)], os.path.join(logdir, "rosmaster.log"))
    import xmlrpc.client

    end = time.monotonic() + 30
    while time.monotonic() < end:
        try:
            xmlrpc.client.ServerProxy(os.environ["ROS_MASTER_URI"]).getSystemState("/probe")
            return m
        except OSError:
            time.sleep(0.1)
    raise RuntimeError("rosmaster did not come up")


def wait_for(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


def peer(ns: str, logdir: str) -> dict:
    out: dict = {}
    subprocess.run([sys.executable, "-c", WARM], check=True, timeout=1200, capture_output=True)
    m = master(logdir)
    proc = start([ROVLAB, "ros1", "node", "--vehicle", "udrone", "--config", "thesis", "--namespace", ns,
                  "--remap", f"pressure:=/{ns}/depth/pressure"], os.path.join(logdir, "node.log"))
    try:
        rospy.init_node("rovlab_test_peer", disable_signals=True)
        pub_p = rospy.Publisher(f"/{ns}/depth/pressure", FluidPressure, queue_size=10)  # remapped
        pub_m = rospy.Publisher(f"/{ns}/mocap/pose", PoseStamped, queue_size=10)
        pub_s = rospy.Publisher(f"/{ns}/setpoint", PoseStamped, queue_size=10, latch=True)
        got: dict[str, list] = {"odom": [], "pwm": [], "wrench": [], "diag": []}
        rospy.Subscriber(f"/{ns}/odometry", Odometry, lambda msg: got["odom"].append(msg))
        rospy.Subscriber(f"/{ns}/thrusters/pwm_us", Float64MultiArray, lambda msg: got["pwm"].append(msg))
        rospy.Subscriber(f"/{ns}/wrench", WrenchStamped, lambda msg: got["wrench"].append(msg))
        rospy.Subscriber(f"/{ns}/diagnostics", DiagnosticArray, lambda msg: got["diag"].append(msg))
        prm = f"/{ns}/rovlab_node/"
        out["node_up"] = wait_for(lambda: rospy.has_param(prm + "lqr/input_weight/Z") and pub_p.get_num_connections() > 0,
                                  60.0)
        state = {"z": 1.0, "yaw": 0.3, "bad": None}
        rng = random.Random(1)

        def run(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                t = rospy.get_rostime()
                p = FluidPressure()
                p.header.stamp = t
                depth = state["z"] - 0.0465 + rng.gauss(0.0, 0.01)
                p.fluid_pressure = float("nan") if state["bad"] == "pressure" else 101325.0 + 1000.0 * 9.81 * depth
                pub_p.publish(p)
                pm = PoseStamped()
                pm.header.stamp = t
                pm.header.frame_id = "map"
                pm.pose.position.z = -state["z"] + rng.gauss(0.0, 4e-5)
                if state["bad"] != "quaternion":
                    yaw = state["yaw"] + rng.gauss(0.0, 1e-3)
                    pm.pose.orientation.z, pm.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
                pub_m.publish(pm)
                time.sleep(0.1)

        run(3.0)
        sp = PoseStamped()
        sp.pose.position.z = -1.5
        sp.pose.orientation.w = 1.0
        pub_s.publish(sp)
        run(5.0)
        out["odometry_count"] = len(got["odom"])
        if got["odom"]:
            o = got["odom"][-1]
            out["odometry"] = {"frame": o.header.frame_id, "child": o.child_frame_id, "z": o.pose.pose.position.z,
                               "pose_cov": list(o.pose.covariance), "twist_cov": list(o.twist.covariance)}
        if got["pwm"]:
            out["pwm"] = list(got["pwm"][-1].data)
            out["pwm_label"] = got["pwm"][-1].layout.dim[0].label
        out["wrench_count"] = len(got["wrench"])
        if got["diag"]:
            out["diagnostics"] = {s.name: [s.level, s.message, {kv.key: kv.value for kv in s.values}]
                                  for s in got["diag"][-1].status}
        n_before = len(got["odom"])
        state["bad"] = "pressure"
        run(1.0)
        state["bad"] = "quaternion"
        run(1.0)
        state["bad"] = None
        run(1.0)
        out["odometry_during_bad_input"] = len(got["odom"]) - n_before
        out["node_alive_after_bad_input"] = proc.poll() is None
        out["gain_before"] = out.get("diagnostics", {}).get("rovlab/node", [0, "", {}])[2].get("K")
        rospy.set_param(prm + "process_noise/psd/w", -1.0)  # refused: put back
        run(2.5)
        out["bad_param_after"] = rospy.get_param(prm + "process_noise/psd/w")
        rospy.set_param(prm + "lqr/input_weight/Z", 10.0)
        got["diag"].clear()
        run(3.0)
        out["good_param_after"] = rospy.get_param(prm + "lqr/input_weight/Z")
        if got["diag"]:
            d = {s.name: {kv.key: kv.value for kv in s.values} for s in got["diag"][-1].status}
            out["gain_after"] = d.get("rovlab/node", {}).get("K")
        out["node_alive_at_end"] = proc.poll() is None
    finally:
        rospy.signal_shutdown("done")
        out["node_exit"] = stop(proc)
        stop(m)
    return out


def e2e(duration: float, logdir: str, scenario: str) -> dict:
    out: dict = {}
    subprocess.run([sys.executable, "-c", WARM], check=True, timeout=1200, capture_output=True)
    m = master(logdir)
    sim = nodep = None
    rows: list = []
    refs: list = []
    est: list = []
    try:
        rospy.init_node("rovlab_test_observer", disable_signals=True)
        rospy.Subscriber("/truth/odometry", Odometry, lambda msg: rows.append(
            (msg.header.stamp.to_sec(), -msg.pose.pose.position.z,
             2 * math.atan2(msg.pose.pose.orientation.z, msg.pose.pose.orientation.w))), queue_size=100)
        rospy.Subscriber("/setpoint", PoseStamped, lambda msg: refs.append(
            (msg.header.stamp.to_sec(), -msg.pose.position.z,
             2 * math.atan2(msg.pose.orientation.z, msg.pose.orientation.w))), queue_size=100)
        rospy.Subscriber("/odometry", Odometry, lambda msg: est.append(msg.header.stamp.to_sec()), queue_size=100)
        time.sleep(0.5)  # subscribed before the simulated vehicle publishes its first step
        sim = start([ROVLAB, "ros1", "sim", "--scenario", scenario], os.path.join(logdir, "sim.log"))
        nodep = start([ROVLAB, "ros1", "node", "--vehicle", "udrone", "--config", "thesis"],
                      os.path.join(logdir, "node.log"))
        out["node_started"] = wait_for(lambda: len(est) > 0, 60.0)
        time.sleep(duration)
    finally:
        rospy.signal_shutdown("done")
        out["node_exit"] = stop(nodep) if nodep else None
        out["sim_exit"] = stop(sim) if sim else None
        stop(m)
    out["truth"] = rows
    out["setpoints"] = refs
    out["estimates"] = len(est)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("peer", "e2e"))
    ap.add_argument("--ns", default="rov")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--scenario", default="step-process-model")
    ap.add_argument("--logdir", default=".")
    a = ap.parse_args()
    os.environ["ROS_HOME"] = os.environ.get("ROS_HOME", a.logdir)
    res = peer(a.ns, a.logdir) if a.mode == "peer" else e2e(a.duration, a.logdir, a.scenario)
    print("RESULT " + json.dumps(res))


if __name__ == "__main__":
    main()
