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
import threading
import time
from collections.abc import Callable
from typing import Any

import rospy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import FluidPressure, Imu
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore, NodeOutput


def _stamp(seconds: float) -> Any:
    sec = math.floor(seconds)
    return rospy.Time(int(sec), min(int(round((seconds - sec) * 1e9)), 999_999_999))


def _seconds(stamp: Any, now: float) -> float:
    if stamp.secs == 0 and stamp.nsecs == 0:
        return now
    return rc.stamp_seconds(stamp.secs, stamp.nsecs)


class _Throttle:
    def __init__(self, log: Callable[[str], None], period: float = 2.0) -> None:
        self.log, self.period = log, period
        self.last: dict[str, float] = {}
        self.lock = threading.Lock()

    def __call__(self, key: str, message: str) -> None:
        now = time.monotonic()
        with self.lock:
            if now - self.last.get(key, -1e9) < self.period:
                return
            self.last[key] = now
        self.log(message)


def _now() -> float:
    return rospy.get_rostime().to_sec()


class VehicleNode1:
    """NodeCore on ROS 1 topics."""

    def __init__(self, core: NodeCore, table: rc.ParameterTable, *, mocap_covariance: bool = False,
                 recorder: Any = None) -> None:
        self.core, self.table, self.recorder = core, table, recorder
        self.warn = _Throttle(rospy.logwarn)
        v = core.vehicle
        self.rho, self.g = v.water_density, v.gravity
        self.surface_pa = rc.SURFACE_PRESSURE_PA
        self.sensor = {k: core.sensor_of_kind(k) for k in ("pressure", "motion_capture", "imu")}
        self.pub_odom = rospy.Publisher(rc.TOPICS["odometry"], Odometry, queue_size=10)
        self.pub_wrench = rospy.Publisher(rc.TOPICS["wrench"], WrenchStamped, queue_size=10)
        self.pub_pwm = rospy.Publisher(rc.TOPICS["pwm"], Float64MultiArray, queue_size=10)
        self.pub_diag = rospy.Publisher(rc.TOPICS["diagnostics"], DiagnosticArray, queue_size=10)
        rospy.Subscriber(rc.TOPICS["pressure"], FluidPressure, self._guard("pressure", self._on_pressure),
                         queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["mocap"], PoseWithCovarianceStamped if mocap_covariance else PoseStamped,
                         self._guard("mocap/pose", self._on_mocap), queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["imu"], Imu, self._guard("imu", self._on_imu), queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(rc.TOPICS["setpoint"], PoseStamped, self._guard("setpoint", self._on_setpoint), queue_size=10)
        self._server: dict[str, Any] = {}
        for name, value in {"surface_pressure_pa": self.surface_pa, **table.values}.items():
            rospy.set_param("~" + name.replace(".", "/"), value)
            self._server[name] = value
        rospy.Timer(rospy.Duration(core.h / 5.0), self._guard("timer", lambda event: self._run(_now())))
        rospy.Timer(rospy.Duration(1.0), self._guard("parameters", lambda event: self.poll_parameters()))

    def _guard(self, where: str, fn: Callable[[Any], None]) -> Callable[[Any], None]:
        def call(arg: Any) -> None:
            try:
                fn(arg)
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
        self._run(_now())

    def _on_pressure(self, msg: Any) -> None:
        depth = rc.depth_from_pressure(msg.fluid_pressure, rho=self.rho, g=self.g, surface_pa=self.surface_pa)
        self._push("pressure", {"z": depth}, _seconds(msg.header.stamp, _now()), "pressure")

    def _on_mocap(self, msg: Any) -> None:
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        self._push("motion_capture", rc.pose_samples(pose, "mocap/pose.pose"), _seconds(msg.header.stamp, _now()),
                   "mocap/pose")

    def _on_imu(self, msg: Any) -> None:
        self._push("imu", rc.imu_samples(msg), _seconds(msg.header.stamp, _now()), "imu")

    def _on_setpoint(self, msg: Any) -> None:
        s = rc.pose_samples(msg.pose, "setpoint.pose")
        if s["z"] < 0.0:
            raise rc.MessageError(f"setpoint depth {s['z']:g} m (ENU z = {-s['z']:g}) is above the surface")
        self.core.set_reference(z=s["z"], psi=s["psi"])

    def _run(self, now: float) -> None:
        outs = self.core.tick(now)
        if outs:
            self.publish(outs[-1])

    def publish(self, out: NodeOutput) -> None:
        odom = rc.fill_odometry(Odometry(), rc.odometry_content(out))
        odom.header.stamp = _stamp(out.stamp)
        self.pub_odom.publish(odom)
        w = rc.fill_wrench(WrenchStamped(), out.tau)
        w.header.stamp = _stamp(out.stamp)
        self.pub_wrench.publish(w)
        self.pub_pwm.publish(rc.fill_pwm(Float64MultiArray(), MultiArrayDimension, out))
        if out.k % max(1, int(round(1.0 / self.core.h))) == 0:
            d = rc.fill_diagnostics(DiagnosticArray(), DiagnosticStatus, KeyValue, rc.diagnostics_content(
                out, self.core.counters, gains=getattr(self.core.design.controller.model, "K", None)))
            d.header.stamp = _stamp(out.stamp)
            self.pub_diag.publish(d)
        if self.recorder is not None:
            self.recorder.output(out)

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

    core, table = load_node(vehicle, config)
    recorder = None
    if record:
        from rovlab.interfaces.node.record import NodeRecorder

        recorder = NodeRecorder(record, core, namespace=namespace)
    _init("rovlab_node", namespace, remaps)
    VehicleNode1(core, table, mocap_covariance=mocap_covariance, recorder=recorder)
    rospy.loginfo(f"rovlab node up (ROS 1): vehicle {core.vehicle.name}, configuration {core.config.name}, "
                  f"h = {core.h:g} s; fusing " + ", ".join(c.name for c in core.channels))
    return _spin(recorder.close if recorder is not None else None)


class SimNode1:
    """A SimulatedVehicle on ROS 1 topics, paced by a rospy timer."""

    def __init__(self, sim: Any, *, setpoints: bool = True, wait: bool = True) -> None:
        self.sim = sim
        self.waiting = wait
        self.warn = _Throttle(rospy.logwarn)
        truth = sim.prep.truth
        self.rho, self.g = truth.water_density, truth.gravity
        self.pub_p = rospy.Publisher(rc.TOPICS["pressure"], FluidPressure, queue_size=10, tcp_nodelay=True)
        self.pub_m = rospy.Publisher(rc.TOPICS["mocap"], PoseStamped, queue_size=10, tcp_nodelay=True)
        self.pub_i = rospy.Publisher(rc.TOPICS["imu"], Imu, queue_size=10, tcp_nodelay=True)
        self.pub_t = rospy.Publisher(rc.TOPICS["truth"], Odometry, queue_size=10)
        self.pub_s = rospy.Publisher(rc.TOPICS["setpoint"], PoseStamped, queue_size=10) if setpoints else None
        self.sub = rospy.Subscriber(rc.TOPICS["pwm"], Float64MultiArray, self._on_pwm, queue_size=10, tcp_nodelay=True)
        self.last_ref: tuple[float, float] | None = None
        self.last_ref_time = -1e9
        self.lock = threading.Lock()
        self.t0: float | None = None
        rospy.Timer(rospy.Duration(sim.h / 2.0), self._on_timer)

    def _on_pwm(self, msg: Any) -> None:
        try:
            self.sim.set_pwm(list(msg.data))
        except ValueError as exc:
            self.warn("pwm", f"thrusters/pwm_us ignored: {exc}")

    def _on_timer(self, event: Any) -> None:
        with self.lock:
            try:
                self._tick()
            except Exception as exc:  # noqa: BLE001
                self.warn("sim", f"simulated vehicle: {type(exc).__name__}: {exc}")

    def _tick(self) -> None:
        if self.waiting:
            if self.pub_p.get_num_connections() + self.pub_m.get_num_connections() == 0 \
                    or self.sub.get_num_connections() == 0:
                return
            self.waiting = False
            rospy.loginfo("a node is listening and commanding: the simulated vehicle starts")
        now = _now()
        if self.t0 is None:
            self.t0 = now
        due = int((now - self.t0) / self.sim.h + 1e-9) + 1 - self.sim.k  # made up when held up (see ros2.py)
        for _ in range(min(max(due, 0), 50)):
            s = self.sim.step()
            self._publish_step(s, self.t0 + s.t)
        if due > 50:
            self.t0 = now - (self.sim.k - 1) * self.sim.h

    def _publish_step(self, s: Any, now: float) -> None:
        by_sensor: dict[str, dict[str, float]] = {}
        for sensor, quantity, value in s.samples:
            by_sensor.setdefault(sensor, {})[quantity] = value
        for sensor, values in by_sensor.items():
            kind = self.sim.sensor_kind(sensor)
            if kind == "pressure" and "z" in values:
                m = FluidPressure()
                m.header.stamp = _stamp(now)
                m.header.frame_id = sensor
                m.fluid_pressure = rc.pressure_from_depth(values["z"], rho=self.rho, g=self.g)
                self.pub_p.publish(m)
            elif kind == "motion_capture":
                pm = PoseStamped()
                pm.header.stamp = _stamp(now)
                pm.header.frame_id = rc.WORLD_FRAME
                c = rc.odometry_content(nav={"x": s.truth["x"], "y": s.truth["y"], "z": values.get("z", s.truth["z"]),
                                             "psi": values.get("psi", s.truth["psi"])})
                p, q = pm.pose.position, pm.pose.orientation
                p.x, p.y, p.z = c["position"]
                q.x, q.y, q.z, q.w = c["orientation"]
                self.pub_m.publish(pm)
            elif kind == "imu":
                im = Imu()
                im.header.stamp = _stamp(now)
                im.header.frame_id = rc.BODY_FRAME
                c = rc.odometry_content(nav={"psi": values.get("psi", 0.0), "r": values.get("r", 0.0)})
                if "psi" in values:
                    q = im.orientation
                    q.x, q.y, q.z, q.w = c["orientation"]
                else:
                    im.orientation_covariance = [-1.0] + [0.0] * 8
                im.angular_velocity.z = c["angular"][2]
                self.pub_i.publish(im)
        t = rc.fill_odometry(Odometry(), rc.odometry_content(nav=s.truth))
        t.header.stamp = _stamp(now)
        self.pub_t.publish(t)
        if self.pub_s is not None and (s.reference != self.last_ref or now - self.last_ref_time > 1.0):
            sp = PoseStamped()
            sp.header.stamp = _stamp(now)
            sp.header.frame_id = rc.WORLD_FRAME
            c = rc.odometry_content(nav={"z": s.reference[0], "psi": s.reference[1]})
            sp.pose.position.z = c["position"][2]
            q = sp.pose.orientation
            q.x, q.y, q.z, q.w = c["orientation"]
            self.pub_s.publish(sp)
            self.last_ref, self.last_ref_time = s.reference, now


def run_sim(*, vehicle: str | None, scenario: str, namespace: str = "", setpoints: bool = True,
            duration_s: float | None = None, wait: bool = True, remaps: list[str] | None = None) -> int:
    """``rovlab ros1 sim``."""
    from rovlab.interfaces.node.runtime import load_sim

    sim = load_sim(scenario, vehicle)
    _init("rovlab_sim", namespace, remaps)
    SimNode1(sim, setpoints=setpoints, wait=wait)
    rospy.loginfo(f"rovlab sim up (ROS 1): scenario {sim.scenario.name}, h = {sim.h:g} s")
    if duration_s is not None:
        threading.Timer(duration_s, lambda: signal.raise_signal(signal.SIGTERM)).start()
    return _spin()
