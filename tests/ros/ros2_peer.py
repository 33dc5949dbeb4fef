"""An independent rclpy peer for the ROS 2 node tests; run with the ROS 2 environment's Python,
inside a network namespace with only loopback (tests/ros/conftest.py). It starts ``rovlab ros2``
processes, talks to them with plain rclpy (standard messages and parameter services only, no
rovlab import) and prints one JSON object with what it saw.

    ros2_peer.py peer   [--ns NS]      # node alone: sensor data in, odometry/PWM out, parameters, bad input
    ros2_peer.py e2e    [--duration S] # `rovlab ros2 sim` + `rovlab ros2 node`: truth and set-points
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

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64MultiArray

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# the end-to-end observer keeps every message until its executor takes it (on a loaded machine
# this Python process can fall behind the 100 Hz truth and its catch-up bursts) and asks for the
# simulated vehicle's recent history (transient local): on a loaded machine (CI) discovery can
# match it to the simulated vehicle a few seconds after the first step, which was then lost
EVERYTHING = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
ALL_NEW = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)  # the node's (volatile) topics
HERE = os.path.dirname(os.path.abspath(__file__))
ROVLAB = os.path.join(os.path.dirname(sys.executable), "rovlab")


def start(args: list[str], log: str) -> subprocess.Popen:
    fh = open(log, "w")  # noqa: SIM115
    return subprocess.Popen([ROVLAB, *args], stdout=fh, stderr=subprocess.STDOUT)


def stop(p: subprocess.Popen, timeout: float = 10.0) -> int | None:
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
    return p.returncode


def stamp(msg, t: float) -> None:
    msg.header.stamp.sec = int(math.floor(t))
    msg.header.stamp.nanosec = int((t - math.floor(t)) * 1e9)


def spin_until(node, cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.02)
        if cond():
            return True
    return False


def set_param(node, client, name: str, value, kind: int) -> tuple[bool, str]:
    pv = ParameterValue(type=kind)
    if kind == ParameterType.PARAMETER_DOUBLE:
        pv.double_value = float(value)
    elif kind == ParameterType.PARAMETER_BOOL:
        pv.bool_value = bool(value)
    elif kind == ParameterType.PARAMETER_STRING:
        pv.string_value = str(value)
    req = SetParameters.Request(parameters=[Parameter(name=name, value=pv)])
    fut = client.call_async(req)
    spin_until(node, fut.done, 20.0)
    if not fut.done():
        return False, "timeout"
    r = fut.result().results[0]
    return bool(r.successful), r.reason


WARM = """
from rovlab.interfaces.node.runtime import load_node, load_sim
core, _ = load_node("udrone", "thesis")
sim = load_sim("step-process-model")
sim.step(); sim.step()
"""


def warm_up() -> None:
    """Compile (or load from the cache) the node's and the simulated vehicle's kernels before any
    clock starts: after a change of rovlab's sources the first process compiles for minutes."""
    subprocess.run([sys.executable, "-c", WARM], check=True, timeout=1200, capture_output=True)


def peer(ns: str, logdir: str) -> dict:
    out: dict = {}
    warm_up()
    proc = start(["ros2", "node", "--vehicle", "udrone", "--config", "thesis", "--namespace", ns,
                  "--record", os.path.join(logdir, "node.mcap"), "--remap", f"pressure:=/{ns}/depth/pressure"],
                 os.path.join(logdir, "node.log"))
    rclpy.init()
    node = rclpy.create_node("rovlab_test_peer")
    try:
        pub_p = node.create_publisher(FluidPressure, f"/{ns}/depth/pressure", qos_profile_sensor_data)  # remapped
        pub_m = node.create_publisher(PoseStamped, f"/{ns}/mocap/pose", qos_profile_sensor_data)
        pub_s = node.create_publisher(PoseStamped, f"/{ns}/setpoint", RELIABLE)
        got: dict[str, list] = {"odom": [], "pwm": [], "wrench": [], "diag": []}
        node.create_subscription(Odometry, f"/{ns}/odometry", lambda m: got["odom"].append(m), RELIABLE)
        node.create_subscription(Float64MultiArray, f"/{ns}/thrusters/pwm_us", lambda m: got["pwm"].append(m), RELIABLE)
        node.create_subscription(WrenchStamped, f"/{ns}/wrench", lambda m: got["wrench"].append(m), RELIABLE)
        node.create_subscription(DiagnosticArray, f"/{ns}/diagnostics", lambda m: got["diag"].append(m), RELIABLE)
        setc = node.create_client(SetParameters, f"/{ns}/rovlab_node/set_parameters")
        getc = node.create_client(GetParameters, f"/{ns}/rovlab_node/get_parameters")
        out["service_up"] = setc.wait_for_service(timeout_sec=60.0)
        state = {"z": 1.0, "yaw": 0.3, "bad": None}
        rng = random.Random(1)  # sensor noise: a sensor repeating one value is declared stuck

        def send(t: float) -> None:
            p = FluidPressure()
            stamp(p, t)
            # the pressure sensor sits 0.0465 m above VO on uDrone: its depth is z - 0.0465
            depth = state["z"] - 0.0465 + rng.gauss(0.0, 0.01)
            p.fluid_pressure = float("nan") if state["bad"] == "pressure" else 101325.0 + 1000.0 * 9.81 * depth
            pub_p.publish(p)
            m = PoseStamped()
            stamp(m, t)
            m.header.frame_id = "map"
            m.pose.position.z = -state["z"] + rng.gauss(0.0, 4e-5)
            if state["bad"] == "quaternion":
                m.pose.orientation.w = 0.0
            else:
                yaw = state["yaw"] + rng.gauss(0.0, 1e-3)
                m.pose.orientation.z, m.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            pub_m.publish(m)

        def run(seconds: float) -> None:
            end = time.monotonic() + seconds
            nxt = time.monotonic()
            while time.monotonic() < end:
                if time.monotonic() >= nxt:
                    send(node.get_clock().now().nanoseconds * 1e-9)
                    nxt += 0.1
                rclpy.spin_once(node, timeout_sec=0.01)

        sp = PoseStamped()
        sp.pose.position.z = -1.5  # 1.5 m deep (ENU z up)
        sp.pose.orientation.w = 1.0  # ENU yaw 0: heading east, psi = pi/2
        run(5.0)
        pub_s.publish(sp)
        run(5.0)
        out["odometry_count"] = len(got["odom"])
        if got["odom"]:
            o = got["odom"][-1]
            out["odometry"] = {"frame": o.header.frame_id, "child": o.child_frame_id, "z": o.pose.pose.position.z,
                               "qz": o.pose.pose.orientation.z, "qw": o.pose.pose.orientation.w,
                               "pose_cov": list(o.pose.covariance), "twist_cov": list(o.twist.covariance)}
        out["pwm_count"] = len(got["pwm"])
        if got["pwm"]:
            out["pwm"] = list(got["pwm"][-1].data)
            out["pwm_label"] = got["pwm"][-1].layout.dim[0].label if got["pwm"][-1].layout.dim else ""
        if got["wrench"]:
            w = got["wrench"][-1].wrench
            out["wrench"] = [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z]
        if got["diag"]:
            out["diagnostics"] = {s.name: [int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else s.level,
                                           s.message, {kv.key: kv.value for kv in s.values}]
                                  for s in got["diag"][-1].status}
        # bad input: NaN pressure, a zero quaternion; the node must keep publishing
        n_before = len(got["odom"])
        state["bad"] = "pressure"
        run(1.0)
        state["bad"] = "quaternion"
        run(1.0)
        state["bad"] = None
        run(1.0)
        out["odometry_during_bad_input"] = len(got["odom"]) - n_before
        out["node_alive_after_bad_input"] = proc.poll() is None
        # parameters: a bad value is refused with a reason, a good one redesigns the gains
        out["bad_param"] = set_param(node, setc, "process_noise.psd.w", -1.0, ParameterType.PARAMETER_DOUBLE)
        out["bad_param_type"] = set_param(node, setc, "lqr.input_weight.Z", "much", ParameterType.PARAMETER_STRING)
        out["unknown_sensor_switch"] = set_param(node, setc, "sensors.sonar.enabled", True,
                                                 ParameterType.PARAMETER_BOOL)
        out["gain_before"] = out.get("diagnostics", {}).get("rovlab/node", [0, "", {}])[2].get("K")
        out["good_param"] = set_param(node, setc, "lqr.input_weight.Z", 10.0, ParameterType.PARAMETER_DOUBLE)
        got["diag"].clear()
        run(2.0)
        if got["diag"]:
            d = {s.name: {kv.key: kv.value for kv in s.values} for s in got["diag"][-1].status}
            out["gain_after"] = d.get("rovlab/node", {}).get("K")
        req = GetParameters.Request(names=["lqr.input_weight.Z"])
        fut = getc.call_async(req)
        spin_until(node, fut.done, 20.0)
        out["param_read_back"] = fut.result().values[0].double_value if fut.done() else None
        out["sensor_off"] = set_param(node, setc, "sensors.qualisys.enabled", False, ParameterType.PARAMETER_BOOL)
        got["diag"].clear()
        run(2.5)
        if got["diag"]:
            out["diag_after_sensor_off"] = {s.name: s.message for s in got["diag"][-1].status}
        out["node_alive_at_end"] = proc.poll() is None
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        out["node_exit"] = stop(proc)
    return out


def e2e(duration: float, logdir: str, scenario: str) -> dict:
    out: dict = {}
    warm_up()
    rclpy.init()
    node = rclpy.create_node("rovlab_test_observer")
    rows: list[tuple[float, float, float]] = []
    refs: list[tuple[float, float, float]] = []
    est: list[tuple[float, float]] = []
    sim = nodep = None
    try:
        node.create_subscription(Odometry, "/truth/odometry", lambda m: rows.append(
            (m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, -m.pose.pose.position.z,
             2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w))), EVERYTHING)
        node.create_subscription(PoseStamped, "/setpoint", lambda m: refs.append(
            (m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, -m.pose.position.z,
             2 * math.atan2(m.pose.orientation.z, m.pose.orientation.w))), EVERYTHING)
        node.create_subscription(Odometry, "/odometry", lambda m: est.append(
            (m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, -m.pose.pose.position.z)), ALL_NEW)
        spin_until(node, lambda: False, 1.0)  # subscribed before the simulated vehicle publishes its first step
        sim = start(["ros2", "sim", "--scenario", scenario], os.path.join(logdir, "sim.log"))
        nodep = start(["ros2", "node", "--vehicle", "udrone", "--config", "thesis"], os.path.join(logdir, "node.log"))
        spin_until(node, lambda: len(est) > 0, 60.0)
        out["node_started"] = bool(est)
        spin_until(node, lambda: False, duration)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        out["node_exit"] = stop(nodep) if nodep else None
        out["sim_exit"] = stop(sim) if sim else None
    out["truth"] = rows
    out["setpoints"] = refs
    out["estimates"] = len(est)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("peer", "e2e", "hmi"))
    ap.add_argument("--ns", default="rov")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--scenario", default="step-process-model")
    ap.add_argument("--logdir", default=".")
    a = ap.parse_args()
    if a.mode == "peer":
        res = peer(a.ns, a.logdir)
    elif a.mode == "hmi":
        res = hmi(a.ns, a.logdir)
    else:
        res = e2e(a.duration, a.logdir, a.scenario)
    print("RESULT " + json.dumps(res))


def hmi(ns: str, logdir: str) -> dict:
    """The HMI's ROS 2 source against a running node: messages in, commands and tuning out."""
    from rovlab.interfaces.node.ros2_source import Ros2Source, hmi_documents
    from rovlab.params.validate import ConfigError

    out: dict = {}
    warm_up()
    proc = start(["ros2", "node", "--vehicle", "udrone", "--config", "thesis", "--namespace", ns],
                 os.path.join(logdir, "node.log"))
    docs, stash = hmi_documents("udrone", "thesis")
    src = Ros2Source(vehicle=docs["vehicle"].value, config=docs["config"].value, config_data=docs["config"].data,
                     stash=stash, namespace=ns)
    rclpy.init()
    node = rclpy.create_node("rovlab_test_sensors")
    try:
        pub_p = node.create_publisher(FluidPressure, f"/{ns}/pressure", qos_profile_sensor_data)
        pub_m = node.create_publisher(PoseStamped, f"/{ns}/mocap/pose", qos_profile_sensor_data)
        rng = random.Random(2)
        messages: list = []

        def run(seconds: float) -> None:
            end = time.monotonic() + seconds
            nxt = time.monotonic()
            while time.monotonic() < end:
                if time.monotonic() >= nxt:
                    t = node.get_clock().now().nanoseconds * 1e-9
                    p = FluidPressure()
                    stamp(p, t)
                    p.fluid_pressure = 101325.0 + 9810.0 * (1.0 - 0.0465 + rng.gauss(0, 0.01))
                    pub_p.publish(p)
                    m = PoseStamped()
                    stamp(m, t)
                    m.pose.position.z = -1.0 + rng.gauss(0, 4e-5)
                    m.pose.orientation.w = 1.0
                    m.pose.orientation.z = rng.gauss(0, 1e-3)
                    pub_m.publish(m)
                    nxt += 0.1
                rclpy.spin_once(node, timeout_sec=0.01)
                messages.extend(src.advance(1))

        run(4.0)
        src.set_reference(z=1.2, psi=0.0)
        run(2.0)
        out["describe"] = src.describe()
        out["topics"] = sorted({m[0] for m in messages})
        est = [m for m in messages if m[0] == "/rovlab/estimate"]
        out["estimate"] = est[-1][2] if est else None
        ref = [m for m in messages if m[0] == "/rovlab/reference"]
        out["reference"] = ref[-1][2] if ref else None
        cmd = [m for m in messages if m[0] == "/rovlab/command"]
        out["command"] = cmd[-1][2] if cmd else None
        k_before = src.design.controller.model.K.tolist()
        cdoc = docs["config"]
        data, value = cdoc.candidate({"lqr.input_weight.Z": 5.0})
        src.apply(config=value)
        cdoc.commit(data, value)
        out["applied"] = True
        out["gain_changed"] = src.design.controller.model.K.tolist() != k_before
        try:
            data, value = cdoc.candidate({"fusion.gate_probability": 0.5})  # valid file, then the node decides
            src.apply(config=value)
            out["second_apply"] = "accepted"
        except ConfigError as exc:
            out["second_apply"] = str(exc)
        src.set_sensor_available("pressure", False)
        src.set_filter_mode("qualisys.psi", "off")
        messages.clear()
        run(2.0)
        est = [m for m in messages if m[0] == "/rovlab/estimate"]
        out["sensors_after"] = est[-1][2]["sensors"] if est else None
        out["node_alive"] = proc.poll() is None
    finally:
        src.close()
        node.destroy_node()
        rclpy.try_shutdown()
        out["node_exit"] = stop(proc)
    return out


if __name__ == "__main__":
    main()
