"""The vehicle node and the simulated vehicle as ROS 2 nodes (rclpy), on the topics of
rovlab.interfaces.node.ros_common. Imported only by ``rovlab ros2 ...``: it imports rclpy.

* :func:`run_node`: ``rovlab ros2 node`` -- NodeCore behind subscriptions (sensor data best
  effort, set-points reliable), publishers (reliable), a timer, and ROS 2 parameters (the
  configuration's numbers and the sensor switches; ``ros2 param set`` semantics, refused with a
  reason when the configuration loader or the design refuses them).
* :func:`run_sim`: ``rovlab ros2 sim`` -- a SimulatedVehicle paced in real time, publishing the
  sensor topics and NS/truth/odometry, taking NS/thrusters/pwm_us.

Every callback catches what a bad message or parameter can raise, logs it (throttled) and
carries on: nothing from the outside stops the node.
"""

from __future__ import annotations

import json
import math
import signal
import time
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import FluidPressure, Imu
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore, NodeOutput

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# the simulated vehicle makes up at most CATCH_UP steps at once after a stall. Its truth and
# set-point topics are what a recorder evaluates: they keep the last 10 s (1000 steps at 100 Hz)
# for a reader that is slow (several bursts) or that discovery matched late (transient local: a
# recorder asking for it gets the run from its first step even if it matched a few seconds in;
# readers that ask for volatile data get only new samples, as before)
CATCH_UP = 50
RECORDED = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _stamp(msg_stamp: Any, seconds: float) -> Any:
    sec = math.floor(seconds)
    msg_stamp.sec = int(sec)
    msg_stamp.nanosec = min(int(round((seconds - sec) * 1e9)), 999_999_999)
    return msg_stamp


def _seconds(stamp: Any, now: float) -> float:
    if stamp.sec == 0 and stamp.nanosec == 0:
        return now  # an unstamped message: its arrival time
    return rc.stamp_seconds(stamp.sec, stamp.nanosec)


class _Throttle:
    """Log a repeated problem at most once per ``period`` seconds (with the count in between)."""

    def __init__(self, log: Callable[[str], None], period: float = 2.0) -> None:
        self.log, self.period = log, period
        self.last: dict[str, float] = {}
        self.count: dict[str, int] = {}

    def __call__(self, key: str, message: str) -> None:
        now = time.monotonic()
        self.count[key] = self.count.get(key, 0) + 1
        if now - self.last.get(key, -1e9) >= self.period:
            n = self.count.pop(key)
            self.last[key] = now
            self.log(message + (f" ({n} times since the last report)" if n > 1 else ""))


class VehicleNode:
    """NodeCore on ROS 2 topics (see the module)."""

    def __init__(self, core: NodeCore, table: rc.ParameterTable, *, namespace: str = "", mocap_covariance: bool = False,
                 recorder: Any = None, node_name: str = "rovlab_node") -> None:
        self.core, self.table, self.recorder = core, table, recorder
        self.node = node = Node(node_name, namespace=namespace)
        log = node.get_logger()
        self.warn = _Throttle(log.warning)
        self.info = log.info
        v = core.vehicle
        self.rho, self.g = v.water_density, v.gravity
        self.surface_pa = rc.SURFACE_PRESSURE_PA
        self.sensor = {k: core.sensor_of_kind(k) for k in ("pressure", "motion_capture", "imu")}
        node.create_subscription(FluidPressure, rc.TOPICS["pressure"], self._guard("pressure", self._on_pressure),
                                 qos_profile_sensor_data)
        node.create_subscription(PoseWithCovarianceStamped if mocap_covariance else PoseStamped, rc.TOPICS["mocap"],
                                 self._guard("mocap/pose", self._on_mocap), qos_profile_sensor_data)
        node.create_subscription(Imu, rc.TOPICS["imu"], self._guard("imu", self._on_imu), qos_profile_sensor_data)
        node.create_subscription(PoseStamped, rc.TOPICS["setpoint"], self._guard("setpoint", self._on_setpoint), RELIABLE)
        self.pub_odom = node.create_publisher(Odometry, rc.TOPICS["odometry"], RELIABLE)
        self.pub_wrench = node.create_publisher(WrenchStamped, rc.TOPICS["wrench"], RELIABLE)
        self.pub_pwm = node.create_publisher(Float64MultiArray, rc.TOPICS["pwm"], RELIABLE)
        self.pub_diag = node.create_publisher(DiagnosticArray, rc.TOPICS["diagnostics"], RELIABLE)
        self.pub_msgs = node.create_publisher(String, rc.TOPICS["messages"], RELIABLE)
        self._declare_parameters()
        node.add_on_set_parameters_callback(self._on_set_parameters)
        node.create_timer(core.h / 5.0, self._guard("timer", self._on_timer))

    # -- helpers -------------------------------------------------------------------------------
    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def _guard(self, where: str, fn: Callable[[Any], None] | Callable[[], None]) -> Callable[..., None]:
        def call(*args: Any) -> None:
            try:
                fn(*args)
            except rc.MessageError as exc:
                self.warn(where, f"{rc.TOPICS.get(where, where)}: message ignored: {exc}")
            except Exception as exc:  # noqa: BLE001 - nothing from outside may stop the node
                self.warn(where + "!", f"{where}: {type(exc).__name__}: {exc} (the node keeps running)")
        return call

    def _push(self, kind: str, samples: dict[str, float], stamp: float, topic: str) -> None:
        for result in rc.push_samples(self.core, self.sensor[kind], samples, stamp):
            if result == "invalid":
                self.warn(topic + result, f"{topic}: {self.core.last_problem}")
        if self.recorder is not None:
            self.recorder.sample(topic, stamp, samples)
        self._run(self.now())

    # -- callbacks -----------------------------------------------------------------------------
    def _on_pressure(self, msg: Any) -> None:
        stamp = _seconds(msg.header.stamp, self.now())
        depth = rc.depth_from_pressure(msg.fluid_pressure, rho=self.rho, g=self.g, surface_pa=self.surface_pa)
        self._push("pressure", {"z": depth}, stamp, "pressure")

    def _on_mocap(self, msg: Any) -> None:
        stamp = _seconds(msg.header.stamp, self.now())
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        self._push("motion_capture", rc.pose_samples(pose, "mocap/pose.pose"), stamp, "mocap/pose")

    def _on_imu(self, msg: Any) -> None:
        stamp = _seconds(msg.header.stamp, self.now())
        self._push("imu", rc.imu_samples(msg), stamp, "imu")

    def _on_setpoint(self, msg: Any) -> None:
        s = rc.pose_samples(msg.pose, "setpoint.pose")
        if s["z"] < 0.0:
            raise rc.MessageError(f"setpoint depth {s['z']:g} m (ENU z = {-s['z']:g}) is above the surface")
        engaged = self.core.engaged
        self.core.set_reference(z=s["z"], psi=s["psi"])
        if not engaged:
            self.info(f"first set-point: depth {s['z']:g} m, heading {s['psi']:g} rad; controller engaged")

    def _on_timer(self) -> None:
        self._run(self.now())

    def _run(self, now: float) -> None:
        outs = self.core.tick(now)
        if outs:
            self.publish(outs[-1])

    def publish(self, out: NodeOutput) -> None:
        odom = rc.fill_odometry(Odometry(), rc.odometry_content(out))
        _stamp(odom.header.stamp, out.stamp)
        self.pub_odom.publish(odom)
        w = rc.fill_wrench(WrenchStamped(), out.tau)
        _stamp(w.header.stamp, out.stamp)
        self.pub_wrench.publish(w)
        self.pub_pwm.publish(rc.fill_pwm(Float64MultiArray(), MultiArrayDimension, out))
        if out.k % max(1, int(round(1.0 / self.core.h))) == 0:  # about 1 Hz
            d = rc.fill_diagnostics(DiagnosticArray(), DiagnosticStatus, KeyValue,
                                    rc.diagnostics_content(out, self.core.counters,
                                                           gains=getattr(self.core.design.controller.model, "K", None)))
            _stamp(d.header.stamp, out.stamp)
            self.pub_diag.publish(d)
        if self.pub_msgs.get_subscription_count() > 0:  # the HMI (rovlab hmi --source ros2) listens
            self.pub_msgs.publish(String(data=json.dumps(out.messages())))
        if self.recorder is not None:
            self.recorder.output(out)

    # -- parameters ----------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        desc = ParameterDescriptor(dynamic_typing=True)
        self.node.declare_parameter("surface_pressure_pa", self.surface_pa, desc)
        for name, value in self.table.values.items():
            self.node.declare_parameter(name, value, desc)

    def _on_set_parameters(self, params: list[Any]) -> Any:
        changes: dict[str, Any] = {}
        try:
            for p in params:
                value = p.value
                if p.name == "surface_pressure_pa":
                    if not (isinstance(value, (int, float)) and not isinstance(value, bool)
                            and 0.0 < float(value) < 1e8):
                        return SetParametersResult(successful=False,
                                                   reason=f"surface_pressure_pa = {value!r}: expected a pressure in Pa")
                    continue
                changes[p.name] = list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value
            reason = self.table.set(changes) if changes else None
        except Exception as exc:  # noqa: BLE001 - a bad parameter must not stop the node
            reason = f"{type(exc).__name__}: {exc}"
        if reason is not None:
            self.warn("param", f"parameters refused: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        for p in params:
            if p.name == "surface_pressure_pa":
                self.surface_pa = float(p.value)
        if changes:
            redesigned = [n for n in changes if not n.startswith("sensors.")]
            self.info(f"parameters set: {', '.join(changes)}" + (" (redesigned)" if redesigned else ""))
        return SetParametersResult(successful=True)


def _spin(node: Node, on_exit: Callable[[], None] | None = None) -> int:
    """Spin until SIGINT / SIGTERM; always runs ``on_exit`` (flush logs) and shuts down."""
    stop = {"flag": False}

    def _term(signum: int, frame: Any) -> None:
        stop["flag"] = True

    signal.signal(signal.SIGTERM, _term)
    signal.signal(signal.SIGINT, _term)
    try:
        while rclpy.ok() and not stop["flag"]:
            rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        if on_exit is not None:
            on_exit()
        node.destroy_node()
        if rclpy.ok():
            rclpy.try_shutdown()
    return 0


def _ros_args(remaps: list[str] | None) -> list[str]:
    out = ["rovlab"]
    if remaps:
        out.append("--ros-args")
        for r in remaps:
            out += ["-r", r]
    return out


def run_node(*, vehicle: str, config: str, namespace: str = "", mocap_covariance: bool = False,
             record: str | None = None, remaps: list[str] | None = None) -> int:
    """``rovlab ros2 node``."""
    from rovlab.interfaces.node.runtime import load_node

    core, table = load_node(vehicle, config, wait_for_samples_s=10.0)
    recorder = None
    if record:
        from rovlab.interfaces.node.record import NodeRecorder

        recorder = NodeRecorder(record, core)
    rclpy.init(args=_ros_args(remaps), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    vn = VehicleNode(core, table, namespace=namespace, mocap_covariance=mocap_covariance, recorder=recorder)
    vn.info(f"rovlab node up: vehicle {core.vehicle.name}, configuration {core.config.name}, h = {core.h:g} s, "
            f"estimator {core.estimator_name}, controller {core.controller_name}; fusing "
            + ", ".join(c.name for c in core.channels))
    return _spin(vn.node, recorder.close if recorder is not None else None)


class SimNode:
    """A SimulatedVehicle on ROS 2 topics, paced by a wall-clock timer."""

    def __init__(self, sim: Any, *, namespace: str = "", setpoints: bool = True, wait: bool = True,
                 node_name: str = "rovlab_sim") -> None:
        self.sim = sim
        self.waiting = wait
        self.node = node = Node(node_name, namespace=namespace)
        self.warn = _Throttle(node.get_logger().warning)
        truth = sim.prep.truth
        self.rho, self.g = truth.water_density, truth.gravity
        self.pub_p = node.create_publisher(FluidPressure, rc.TOPICS["pressure"], qos_profile_sensor_data)
        self.pub_m = node.create_publisher(PoseStamped, rc.TOPICS["mocap"], qos_profile_sensor_data)
        self.pub_i = node.create_publisher(Imu, rc.TOPICS["imu"], qos_profile_sensor_data)
        self.pub_t = node.create_publisher(Odometry, rc.TOPICS["truth"], RECORDED)
        self.pub_s = node.create_publisher(PoseStamped, rc.TOPICS["setpoint"], RECORDED) if setpoints else None
        node.create_subscription(Float64MultiArray, rc.TOPICS["pwm"], self._on_pwm, RELIABLE)
        self.last_ref: tuple[float, float] | None = None
        self.last_ref_time = -1e9
        self.t0: float | None = None
        self.ready_at: float | None = None
        node.create_timer(sim.h / 2.0, self._on_timer)

    def _on_pwm(self, msg: Any) -> None:
        try:
            self.sim.set_pwm(list(msg.data))
        except ValueError as exc:
            self.warn("pwm", f"thrusters/pwm_us ignored: {exc}")

    def _on_timer(self) -> None:
        now = self.node.get_clock().now().nanoseconds * 1e-9
        if self.waiting:  # hold the vehicle at its initial state until a node listens and commands
            n = self.node
            if n.count_subscribers(rc.TOPICS["pressure"]) + n.count_subscribers(rc.TOPICS["mocap"]) == 0 \
                    or n.count_publishers(rc.TOPICS["pwm"]) == 0 \
                    or (self.pub_s is not None and n.count_subscribers(rc.TOPICS["setpoint"]) == 0):
                return
            if self.ready_at is None:  # discovered: give the connections a moment to match
                self.ready_at = now
            if now - self.ready_at < 1.0:
                return
            self.waiting = False
            n.get_logger().info("a node is listening and commanding: the simulated vehicle starts")
        if self.t0 is None:
            self.t0 = now
        # the simulated time follows the clock: steps missed while the process was held up are
        # made up at once (stamped with their own times), at most CATCH_UP at a time
        due = int((now - self.t0) / self.sim.h + 1e-9) + 1 - self.sim.k
        for _ in range(min(max(due, 0), CATCH_UP)):
            s = self.sim.step()
            self._publish_step(s, self.t0 + s.t)
        if due > CATCH_UP:
            self.t0 = now - (self.sim.k - 1) * self.sim.h

    def _publish_step(self, s: Any, now: float) -> None:
        by_sensor: dict[str, dict[str, float]] = {}
        for sensor, quantity, value in s.samples:
            by_sensor.setdefault(sensor, {})[quantity] = value
        for sensor, values in by_sensor.items():
            kind = self.sim.sensor_kind(sensor)
            if kind == "pressure" and "z" in values:
                m = FluidPressure()
                _stamp(m.header.stamp, now)
                m.header.frame_id = sensor
                m.fluid_pressure = rc.pressure_from_depth(values["z"], rho=self.rho, g=self.g)
                self.pub_p.publish(m)
            elif kind == "motion_capture":
                m = PoseStamped()
                _stamp(m.header.stamp, now)
                m.header.frame_id = rc.WORLD_FRAME
                c = rc.odometry_content(nav={"x": s.truth["x"], "y": s.truth["y"], "z": values.get("z", s.truth["z"]),
                                             "psi": values.get("psi", s.truth["psi"])})
                p, q = m.pose.position, m.pose.orientation
                p.x, p.y, p.z = c["position"]
                q.x, q.y, q.z, q.w = c["orientation"]
                self.pub_m.publish(m)
            elif kind == "imu":
                m = Imu()
                _stamp(m.header.stamp, now)
                m.header.frame_id = rc.BODY_FRAME
                c = rc.odometry_content(nav={"psi": values.get("psi", 0.0), "r": values.get("r", 0.0)})
                if "psi" in values:
                    q = m.orientation
                    q.x, q.y, q.z, q.w = c["orientation"]
                else:
                    m.orientation_covariance[0] = -1.0
                m.angular_velocity.z = c["angular"][2]
                self.pub_i.publish(m)
        t = rc.fill_odometry(Odometry(), rc.odometry_content(nav=s.truth))
        _stamp(t.header.stamp, now)
        self.pub_t.publish(t)
        if self.pub_s is not None and (s.reference != self.last_ref or now - self.last_ref_time > 1.0):
            m = PoseStamped()
            _stamp(m.header.stamp, now)
            m.header.frame_id = rc.WORLD_FRAME
            c = rc.odometry_content(nav={"z": s.reference[0], "psi": s.reference[1]})
            m.pose.position.z = c["position"][2]
            q = m.pose.orientation
            q.x, q.y, q.z, q.w = c["orientation"]
            self.pub_s.publish(m)
            self.last_ref, self.last_ref_time = s.reference, now


def run_sim(*, vehicle: str | None, scenario: str, namespace: str = "", setpoints: bool = True,
            duration_s: float | None = None, wait: bool = True, remaps: list[str] | None = None) -> int:
    """``rovlab ros2 sim``."""
    from rovlab.interfaces.node.runtime import load_sim

    sim = load_sim(scenario, vehicle)
    rclpy.init(args=_ros_args(remaps), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    sn = SimNode(sim, namespace=namespace, setpoints=setpoints, wait=wait)
    sn.node.get_logger().info(f"rovlab sim up: scenario {sim.scenario.name}, vehicle {sim.prep.truth.name}, "
                              f"h = {sim.h:g} s; publishing " + ", ".join(c.name for c in sim.channels))
    if duration_s is not None:
        sn.node.create_timer(duration_s, lambda: signal.raise_signal(signal.SIGTERM))
    return _spin(sn.node)
