"""The peer of bench_node.py (run by it, inside a loopback-only network namespace, with the ROS
environment's Python): starts ``rovlab rosN node``, publishes pressure and motion capture at
10 Hz and times each step from its last sensor message to its Odometry. Prints 'RESULT {json}'."""

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

ROVLAB = os.path.join(os.path.dirname(sys.executable), "rovlab")
WARM = 'from rovlab.interfaces.node.runtime import load_node\nload_node("udrone", "thesis")\n'


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("ros", choices=("ros1", "ros2"))
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--logdir", default=".")
    a = ap.parse_args()
    subprocess.run([sys.executable, "-c", WARM], check=True, timeout=1200, capture_output=True)
    procs = []
    if a.ros == "ros1":
        os.environ.update(ROS_MASTER_URI="http://127.0.0.1:11331", ROS_IP="127.0.0.1", ROS_HOSTNAME="127.0.0.1")
        procs.append(subprocess.Popen(["rosmaster", "--core", "-p", "11331"], stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        time.sleep(1.0)
    log = open(os.path.join(a.logdir, "node.log"), "w")  # noqa: SIM115
    procs.append(subprocess.Popen([ROVLAB, a.ros, "node", "--vehicle", "udrone", "--config", "thesis"],
                                  stdout=log, stderr=subprocess.STDOUT))
    sent: dict[int, float] = {}
    lat: list[float] = []
    try:
        if a.ros == "ros2":
            import rclpy
            from geometry_msgs.msg import PoseStamped
            from nav_msgs.msg import Odometry
            from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
            from sensor_msgs.msg import FluidPressure

            rclpy.init()
            node = rclpy.create_node("latency_peer")
            pub_p = node.create_publisher(FluidPressure, "/pressure", qos_profile_sensor_data)
            pub_m = node.create_publisher(PoseStamped, "/mocap/pose", qos_profile_sensor_data)
            t_base: list[float] = []

            def on_odom(m) -> None:
                t = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                k = int(round((t - t_base[0]) / 0.1)) if t_base else -1
                if k in sent:
                    lat.append(time.time() - sent.pop(k))

            node.create_subscription(Odometry, "/odometry", on_odom, QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))

            def stamp(msg, t: float) -> None:
                msg.header.stamp.sec = int(math.floor(t))
                msg.header.stamp.nanosec = int(round((t - math.floor(t)) * 1e9)) % 1_000_000_000

            def spin(until: float) -> None:
                while time.time() < until:
                    rclpy.spin_once(node, timeout_sec=max(0.0, min(0.005, until - time.time())))

            discover = time.time() + 30
            while node.count_subscribers("/mocap/pose") == 0 and time.time() < discover:
                spin(time.time() + 0.1)
            spin(time.time() + 2.0)
        else:
            import rospy
            from geometry_msgs.msg import PoseStamped
            from nav_msgs.msg import Odometry
            from sensor_msgs.msg import FluidPressure

            rospy.init_node("latency_peer", disable_signals=True)
            pub_p = rospy.Publisher("/pressure", FluidPressure, queue_size=10, tcp_nodelay=True)
            pub_m = rospy.Publisher("/mocap/pose", PoseStamped, queue_size=10, tcp_nodelay=True)
            t_base = []

            def on_odom(m) -> None:
                k = int(round((m.header.stamp.to_sec() - t_base[0]) / 0.1)) if t_base else -1
                if k in sent:
                    lat.append(time.time() - sent.pop(k))

            rospy.Subscriber("/odometry", Odometry, on_odom, queue_size=50, tcp_nodelay=True)

            def stamp(msg, t: float) -> None:
                msg.header.stamp = rospy.Time.from_sec(t)

            def spin(until: float) -> None:
                time.sleep(max(0.0, until - time.time()))

            discover = time.time() + 30
            while pub_m.get_num_connections() == 0 and time.time() < discover:
                time.sleep(0.1)
            time.sleep(2.0)
        rng = random.Random(0)
        t0 = math.floor(time.time()) + 1.0
        t_base.append(t0)
        n = int(a.seconds / 0.1)
        for k in range(n):
            t = t0 + 0.1 * k
            spin(t)
            p = FluidPressure()
            stamp(p, t)
            p.fluid_pressure = 101325.0 + 9810.0 * (1.0 - 0.0465 + rng.gauss(0, 0.01))
            pub_p.publish(p)
            m = PoseStamped()
            stamp(m, t)
            m.pose.position.z = -1.0 + rng.gauss(0, 4e-5)
            yaw = 0.3 + rng.gauss(0, 1e-3)
            m.pose.orientation.z, m.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            sent[k] = time.time()
            pub_m.publish(m)
        spin(time.time() + 1.0)
    finally:
        for p in reversed(procs):
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
    print("RESULT " + json.dumps({"latency_s": lat[10:], "sent": n, "replies": len(lat)}))


if __name__ == "__main__":
    main()
