"""The vehicle node and the simulated vehicle as ROS 1 nodes (rospy, from Debian's packages), on
the same topics and messages as the ROS 2 ones (rovlab.interfaces.node.ros_common). Imported only
by ``rovlab ros1 ...``: it imports rospy.

Parameters live on the parameter server under the node's private namespace, with ``/`` for the
dots of the ROS 2 names (``~process_noise/psd/w``, ``~sensors/qualisys/enabled``). The node
polls them (1 Hz): a change is validated by the configuration loader and the design like the ROS 2
parameter services; a refused one is logged with its reason and the server's value put back to
the one that runs, so ``rosparam get`` always shows the running configuration.

rospy runs each subscription and timer in its own thread; NodeCore is thread-safe.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import FluidPressure, Imu
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore


def _stamp(seconds: float) -> Any:
    sec = math.floor(seconds)
    return rospy.Time(int(sec), min(int(round((seconds - sec) * 1e9)), 999_999_999))


def _seconds(stamp: Any, now: float) -> float:
    if stamp.secs == 0 and stamp.nsecs == 0:
        return now
    return rc.stamp_seconds(stamp.secs, stamp.nsecs)


def _now() -> float:
    return rospy.get_rostime().to_sec()


MSGS = rc.Messages(FluidPressure=FluidPressure, PoseStamped=PoseStamped, Imu=Imu, Odometry=Odometry,
                   WrenchStamped=WrenchStamped, Float64MultiArray=Float64MultiArray,
                   MultiArrayDimension=MultiArrayDimension, DiagnosticArray=DiagnosticArray,
                   DiagnosticStatus=DiagnosticStatus, KeyValue=KeyValue)


class _Ros1:
    """Stamps and the clock on ROS 1 (rovlab.interfaces.node.ros_common.RosAdapter)."""

    msgs = MSGS

    def now(self) -> float:
        return _now()

    def set_stamp(self, header: Any, seconds: float) -> None:
        header.stamp = _stamp(seconds)

    def stamp_seconds(self, stamp: Any, now: float) -> float:
        return _seconds(stamp, now)


class VehicleNode1(_Ros1, rc.VehicleAdapter):
    """NodeCore on ROS 1 topics."""

    def __init__(self, core: NodeCore, table: rc.ParameterTable, *, mocap_covariance: bool = False,
                 recorder: Any = None) -> None:
        self.setup(core, table, recorder)
        self.warn = rc.Throttle(rospy.logwarn)
        self.info = rospy.loginfo
        self.pub_odom = rospy.Publisher(rc.TOPICS["odometry"], Odometry, queue_size=10)
        self.pub_wrench = rospy.Publisher(rc.TOPICS["wrench"], WrenchStamped, queue_size=10)
        self.pub_pwm = rospy.Publisher(rc.TOPICS["pwm"], Float64MultiArray, queue_size=10)
        self.pub_diag = rospy.Publisher(rc.TOPICS["diagnostics"], DiagnosticArray, queue_size=10)
        rospy.Subscriber(rc.TOPICS["pressure"], FluidPressure, self.guard("pressure", self.on_pressure),
                         queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["mocap"], PoseWithCovarianceStamped if mocap_covariance else PoseStamped,
                         self.guard("mocap/pose", self.on_mocap), queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["imu"], Imu, self.guard("imu", self.on_imu), queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["setpoint"], PoseStamped, self.guard("setpoint", self.on_setpoint), queue_size=10)
        self._server: dict[str, Any] = {}
        for name, value in {"surface_pressure_pa": self.surface_pa, **table.values}.items():
            rospy.set_param("~" + name.replace(".", "/"), value)
            self._server[name] = value
        rospy.Timer(rospy.Duration(core.h / 5.0), self.guard("timer", lambda event: self.run(_now())))
        rospy.Timer(rospy.Duration(1.0), self.guard("parameters", lambda event: self.poll_parameters()))

    def poll_parameters(self) -> None:
        """Apply what changed on the parameter server (see the module)."""
        changes: dict[str, Any] = {}
        for name, old in self._server.items():
            value = rospy.get_param("~" + name.replace(".", "/"), old)
            if value != old:
                changes[name] = value
        if not changes:
            return
        reason = None
        surface = changes.pop("surface_pressure_pa", None)
        if surface is not None and not (isinstance(surface, (int, float)) and not isinstance(surface, bool)
                                        and 0.0 < float(surface) < 1e8):
            reason = f"surface_pressure_pa = {surface!r}: expected a pressure in Pa"
        if reason is None and changes:
            try:
                reason = self.table.set(changes)
            except Exception as exc:  # noqa: BLE001 - a bad parameter must not stop the node
                reason = f"{type(exc).__name__}: {exc}"
        if reason is not None:
            rospy.logerr(f"parameters refused: {reason}")
            for name in [*changes, *(["surface_pressure_pa"] if surface is not None else [])]:
                rospy.set_param("~" + name.replace(".", "/"), self._server[name])
            return
        if surface is not None:
            self.surface_pa = float(surface)
            self._server["surface_pressure_pa"] = surface
        self._server.update(changes)
        rospy.loginfo(f"parameters set: {', '.join(changes) or 'surface_pressure_pa'}")


def _init(name: str, namespace: str, remaps: list[str] | None = None) -> None:
    # rospy takes its namespace from ROS_NAMESPACE when it is imported (the command line sets it
    # before importing this module); a namespace given here later cannot take effect
    ns = "/" + namespace.strip("/") if namespace.strip("/") else "/"
    if rospy.get_namespace() != ns + ("" if ns.endswith("/") else "/"):
        raise RuntimeError(f"rospy was imported with namespace {rospy.get_namespace()!r}, not {ns!r}: set "
                           "ROS_NAMESPACE before importing rovlab.interfaces.node.ros1")
    argv = ["rovlab", *(remaps or [])]
    rospy.init_node(name, argv=argv, disable_signals=True)


def _spin(on_exit: Callable[[], None] | None = None) -> int:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda s, f: stop.set())
    signal.signal(signal.SIGINT, lambda s, f: stop.set())
    try:
        while not stop.is_set() and not rospy.is_shutdown():
            stop.wait(0.1)
    finally:
        rospy.signal_shutdown("rovlab: stopped")
        if on_exit is not None:
            on_exit()
    return 0


def run_node(*, vehicle: str, config: str, namespace: str = "", mocap_covariance: bool = False,
             record: str | None = None, remaps: list[str] | None = None) -> int:
    """``rovlab ros1 node``."""
    from rovlab.interfaces.node.runtime import load_node

    core, table = load_node(vehicle, config, wait_for_samples_s=10.0)
    recorder = None
    if record:
        from rovlab.interfaces.node.record import NodeRecorder

        recorder = NodeRecorder(record, core, namespace=namespace)
    _init("rovlab_node", namespace, remaps)
    VehicleNode1(core, table, mocap_covariance=mocap_covariance, recorder=recorder)
    rospy.loginfo(f"rovlab node up (ROS 1): vehicle {core.vehicle.name}, configuration {core.config.name}, "
                  f"h = {core.h:g} s; fusing " + ", ".join(c.name for c in core.channels))
    return _spin(recorder.close if recorder is not None else None)


class SimNode1(_Ros1, rc.SimAdapter):
    """A SimulatedVehicle on ROS 1 topics, paced by a rospy timer."""

    def __init__(self, sim: Any, *, setpoints: bool = True, wait: bool = True, duration_s: float | None = None,
                 wait_limit_s: float = 900.0) -> None:
        self.setup(sim, duration_s=duration_s, wait_limit_s=wait_limit_s)
        self.waiting = wait
        self.warn = rc.Throttle(rospy.logwarn)
        self.info = rospy.loginfo
        self.pub_p = rospy.Publisher(rc.TOPICS["pressure"], FluidPressure, queue_size=10, tcp_nodelay=True)
        self.pub_m = rospy.Publisher(rc.TOPICS["mocap"], PoseStamped, queue_size=10, tcp_nodelay=True)
        self.pub_i = rospy.Publisher(rc.TOPICS["imu"], Imu, queue_size=10, tcp_nodelay=True)
        self.pub_t = rospy.Publisher(rc.TOPICS["truth"], Odometry, queue_size=10)
        self.pub_s = rospy.Publisher(rc.TOPICS["setpoint"], PoseStamped, queue_size=10) if setpoints else None
        self.sub = rospy.Subscriber(rc.TOPICS["pwm"], Float64MultiArray, self.set_pwm, queue_size=10, tcp_nodelay=True)
        self.lock = threading.Lock()
        self.t0: float | None = None
        self.ready_at: float | None = None
        rospy.Timer(rospy.Duration(sim.h / 2.0), self._on_timer)

    def _on_timer(self, event: Any) -> None:
        with self.lock:
            try:
                self._tick()
            except Exception as exc:  # noqa: BLE001
                self.warn("sim", f"simulated vehicle: {type(exc).__name__}: {exc}")

    def _tick(self) -> None:
        now = _now()
        if self.waiting:
            if self.pub_p.get_num_connections() + self.pub_m.get_num_connections() == 0 \
                    or self.sub.get_num_connections() == 0 \
                    or (self.pub_s is not None and self.pub_s.get_num_connections() == 0):
                if self.note_waiting(now):  # no node came: give up (run_sim says so and exits 1)
                    signal.raise_signal(signal.SIGTERM)
                return
            if self.ready_at is None:
                self.ready_at = now
            if now - self.ready_at < 1.0:
                return
            self.waiting = False
            rospy.loginfo("a node is listening and commanding: the simulated vehicle starts")
        if self.started(now):  # --duration counts from the start, not while waiting for a node
            signal.raise_signal(signal.SIGTERM)
            return
        if self.t0 is None:
            self.t0 = now
        due = int((now - self.t0) / self.sim.h + 1e-9) + 1 - self.sim.k  # made up when held up (see ros2.py)
        for _ in range(min(max(due, 0), 50)):
            s = self.sim.step()
            self.publish_step(s, self.t0 + s.t)
        if due > 50:
            self.t0 = now - (self.sim.k - 1) * self.sim.h


def run_sim(*, vehicle: str | None, scenario: str, namespace: str = "", setpoints: bool = True,
            duration_s: float | None = None, wait: bool = True, remaps: list[str] | None = None,
            wait_limit_s: float = 900.0) -> int:
    """``rovlab ros1 sim`` (1 when no node came within ``wait_limit_s``)."""
    from rovlab._jit import with_progress
    from rovlab.interfaces.node.runtime import load_sim

    sim = load_sim(scenario, vehicle)
    # the plant compiled before the vehicle is announced (a first step would otherwise stall its clock)
    with_progress(sim.compile, lambda msg: print(f"rovlab sim: {msg}", file=sys.stderr, flush=True),
                  "the simulated vehicle's plant", hint="; `rovlab compile --realtime` prepares it ahead")
    _init("rovlab_sim", namespace, remaps)
    sn = SimNode1(sim, setpoints=setpoints, wait=wait, duration_s=duration_s, wait_limit_s=wait_limit_s)
    rospy.loginfo(f"rovlab sim up (ROS 1): scenario {sim.scenario.name}, h = {sim.h:g} s")

    def on_exit() -> None:
        note = sn.exit_note()
        if note:  # rospy has shut down: straight to stderr
            print(f"rovlab sim: {note}", file=sys.stderr, flush=True)

    _spin(on_exit)
    return 0 if sn.started_at is not None else 1
