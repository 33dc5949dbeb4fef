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
import sys
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


MSGS = rc.Messages(FluidPressure=FluidPressure, PoseStamped=PoseStamped, Imu=Imu, Odometry=Odometry,
                   WrenchStamped=WrenchStamped, Float64MultiArray=Float64MultiArray,
                   MultiArrayDimension=MultiArrayDimension, DiagnosticArray=DiagnosticArray,
                   DiagnosticStatus=DiagnosticStatus, KeyValue=KeyValue)


class _Ros2:
    """Stamps and the clock on ROS 2 (rovlab.interfaces.node.ros_common.RosAdapter)."""

    msgs = MSGS
    node: Node

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def set_stamp(self, header: Any, seconds: float) -> None:
        _stamp(header.stamp, seconds)

    def stamp_seconds(self, stamp: Any, now: float) -> float:
        return _seconds(stamp, now)


class VehicleNode(_Ros2, rc.VehicleAdapter):
    """NodeCore on ROS 2 topics (see the module)."""

    def __init__(self, core: NodeCore, table: rc.ParameterTable, *, namespace: str = "", mocap_covariance: bool = False,
                 recorder: Any = None, node_name: str = "rovlab_node") -> None:
        self.setup(core, table, recorder)
        self.node = node = Node(node_name, namespace=namespace)
        log = node.get_logger()
        self.warn = rc.Throttle(log.warning)
        self.info = log.info
        node.create_subscription(FluidPressure, rc.TOPICS["pressure"], self.guard("pressure", self.on_pressure),
                                 qos_profile_sensor_data)
        node.create_subscription(PoseWithCovarianceStamped if mocap_covariance else PoseStamped, rc.TOPICS["mocap"],
                                 self.guard("mocap/pose", self.on_mocap), qos_profile_sensor_data)
        node.create_subscription(Imu, rc.TOPICS["imu"], self.guard("imu", self.on_imu), qos_profile_sensor_data)
        node.create_subscription(PoseStamped, rc.TOPICS["setpoint"], self.guard("setpoint", self.on_setpoint), RELIABLE)
        node.create_subscription(String, rc.TOPICS["abort"], self.guard("abort", lambda m: self.on_abort(m.data)),
                                 RELIABLE)
        self.pub_odom = node.create_publisher(Odometry, rc.TOPICS["odometry"], RELIABLE)
        self.pub_wrench = node.create_publisher(WrenchStamped, rc.TOPICS["wrench"], RELIABLE)
        self.pub_pwm = node.create_publisher(Float64MultiArray, rc.TOPICS["pwm"], RELIABLE)
        self.pub_diag = node.create_publisher(DiagnosticArray, rc.TOPICS["diagnostics"], RELIABLE)
        self.pub_msgs = node.create_publisher(String, rc.TOPICS["messages"], RELIABLE)
        self._declare_parameters()
        node.add_on_set_parameters_callback(self._on_set_parameters)
        node.create_timer(core.h / 5.0, self.guard("timer", lambda: self.run(self.now())))

    def request_stop(self) -> None:
        signal.raise_signal(signal.SIGTERM)  # _spin stops (a flight ended)

    def publish_more(self, out: NodeOutput) -> None:
        if self.pub_msgs.get_subscription_count() > 0:  # the HMI (rovlab hmi --source ros2) listens
            self.pub_msgs.publish(String(data=json.dumps(out.messages())))

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
             record: str | None = None, remaps: list[str] | None = None, fly: tuple[Any, Any] | None = None) -> int:
    """``rovlab ros2 node`` (``fly``: a dive plan and its guards, flown then the node stops; 1 if
    the flight aborted)."""
    from rovlab.interfaces.node.runtime import load_node

    core, table = load_node(vehicle, config, wait_for_samples_s=10.0)
    recorder = None
    if record:
        from rovlab.interfaces.node.record import NodeRecorder

        recorder = NodeRecorder(record, core, namespace=namespace)
    rclpy.init(args=_ros_args(remaps), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    vn = VehicleNode(core, table, namespace=namespace, mocap_covariance=mocap_covariance, recorder=recorder)
    if fly is not None:
        vn.fly(*fly)
    vn.info(f"rovlab node up: vehicle {core.vehicle.name}, configuration {core.config.name}, h = {core.h:g} s, "
            f"estimator {core.estimator_name}, controller {core.controller_name}; fusing "
            + ", ".join(c.name for c in core.channels) + ("; flying a dive plan" if fly is not None else ""))
    _spin(vn.node, recorder.close if recorder is not None else None)
    if vn.flight is not None and not vn.flight.ended:
        vn.flight.abort("the node was stopped before the plan's end")
        print(f"rovlab ros2 node: {vn.flight.summary()}", file=sys.stderr, flush=True)
        vn.exit_code = 1
    return vn.exit_code


class SimNode(_Ros2, rc.SimAdapter):
    """A SimulatedVehicle on ROS 2 topics, paced by a wall-clock timer."""

    def __init__(self, sim: Any, *, namespace: str = "", setpoints: bool = True, wait: bool = True,
                 node_name: str = "rovlab_sim", duration_s: float | None = None, wait_limit_s: float = 900.0) -> None:
        self.setup(sim, duration_s=duration_s, wait_limit_s=wait_limit_s)
        self.waiting = wait
        self.node = node = Node(node_name, namespace=namespace)
        self.warn = rc.Throttle(node.get_logger().warning)
        self.info = node.get_logger().info
        self.pub_p = node.create_publisher(FluidPressure, rc.TOPICS["pressure"], qos_profile_sensor_data)
        self.pub_m = node.create_publisher(PoseStamped, rc.TOPICS["mocap"], qos_profile_sensor_data)
        self.pub_i = node.create_publisher(Imu, rc.TOPICS["imu"], qos_profile_sensor_data)
        self.pub_t = node.create_publisher(Odometry, rc.TOPICS["truth"], RECORDED)
        self.pub_s = node.create_publisher(PoseStamped, rc.TOPICS["setpoint"], RECORDED) if setpoints else None
        node.create_subscription(Float64MultiArray, rc.TOPICS["pwm"], self.set_pwm, RELIABLE)
        self.t0: float | None = None
        self.ready_at: float | None = None
        node.create_timer(sim.h / 2.0, self._on_timer)

    def _on_timer(self) -> None:
        now = self.node.get_clock().now().nanoseconds * 1e-9
        if self.waiting:  # hold the vehicle at its initial state until a node listens and commands
            n = self.node
            if n.count_subscribers(rc.TOPICS["pressure"]) + n.count_subscribers(rc.TOPICS["mocap"]) == 0 \
                    or n.count_publishers(rc.TOPICS["pwm"]) == 0 \
                    or (self.pub_s is not None and n.count_subscribers(rc.TOPICS["setpoint"]) == 0):
                if self.note_waiting(now):  # no node came: give up (run_sim says so and exits 1)
                    signal.raise_signal(signal.SIGTERM)
                return
            if self.ready_at is None:  # discovered: give the connections a moment to match
                self.ready_at = now
            if now - self.ready_at < 1.0:
                return
            self.waiting = False
            n.get_logger().info("a node is listening and commanding: the simulated vehicle starts")
        if self.started(now):  # --duration counts from the start, not while waiting for a node
            signal.raise_signal(signal.SIGTERM)
            return
        if self.t0 is None:
            self.t0 = now
        # the simulated time follows the clock: steps missed while the process was held up are
        # made up at once (stamped with their own times), at most CATCH_UP at a time
        due = int((now - self.t0) / self.sim.h + 1e-9) + 1 - self.sim.k
        for _ in range(min(max(due, 0), CATCH_UP)):
            s = self.sim.step()
            self.publish_step(s, self.t0 + s.t)
        if due > CATCH_UP:
            self.t0 = now - (self.sim.k - 1) * self.sim.h


def run_sim(*, vehicle: str | None, scenario: str, namespace: str = "", setpoints: bool = True,
            duration_s: float | None = None, wait: bool = True, remaps: list[str] | None = None,
            wait_limit_s: float = 900.0) -> int:
    """``rovlab ros2 sim`` (1 when no node came within ``wait_limit_s``)."""
    from rovlab._jit import with_progress
    from rovlab.interfaces.node.runtime import load_sim

    sim = load_sim(scenario, vehicle)
    # the plant compiled before the vehicle is announced (a first step would otherwise stall its clock)
    with_progress(sim.compile, lambda msg: print(f"rovlab sim: {msg}", file=sys.stderr, flush=True),
                  "the simulated vehicle's plant", hint="; `rovlab compile --realtime` prepares it ahead")
    rclpy.init(args=_ros_args(remaps), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    sn = SimNode(sim, namespace=namespace, setpoints=setpoints, wait=wait, duration_s=duration_s,
                 wait_limit_s=wait_limit_s)
    sn.node.get_logger().info(f"rovlab sim up: scenario {sim.scenario.name}, vehicle {sim.prep.truth.name}, "
                              f"h = {sim.h:g} s; publishing " + ", ".join(c.name for c in sim.channels))

    def on_exit() -> None:
        note = sn.exit_note()
        if note:
            sn.node.get_logger().warning(note)

    _spin(sn.node, on_exit)
    return 0 if sn.started_at is not None else 1
