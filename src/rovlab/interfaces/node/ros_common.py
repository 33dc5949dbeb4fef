"""What the ROS 2 and ROS 1 adapters share: topics, message contents, parameters. No ROS import.

ROS 1 and ROS 2 messages of the same name have the same fields, so the adapters fill and read
them through the functions below and differ only in how they create publishers, stamps and
parameter services.

Topics (relative to the namespace NS; remappable), REP-103/REP-105 frames (ENU ``map``/``odom``,
FLU ``base_link``; rovlab.interfaces.node.frames converts):

=====================  ==========================================  ===========================
topic                  type                                        direction (node)
=====================  ==========================================  ===========================
pressure               sensor_msgs/FluidPressure [Pa]              in  (best effort)
mocap/pose             geometry_msgs/PoseStamped (or ...WithCovar.) in  (best effort)
imu                    sensor_msgs/Imu                             in  (best effort)
setpoint               geometry_msgs/PoseStamped (depth, heading)  in  (reliable; x, y too for DP)
odometry               nav_msgs/Odometry, covariance of the filter out (reliable)
wrench                 geometry_msgs/WrenchStamped (demanded)      out (reliable)
thrusters/pwm_us       std_msgs/Float64MultiArray (vehicle order)  out (reliable)
diagnostics            diagnostic_msgs/DiagnosticArray             out (reliable)
truth/odometry         nav_msgs/Odometry (simulated vehicle only)  sim out
rovlab/messages        std_msgs/String: rovlab.io.messages, JSON   out (ROS 2, when the HMI listens)
=====================  ==========================================  ===========================

Pressure is turned into the sensor's depth as (p - p_surface) / (rho g), with rho and g from the
vehicle file and p_surface the node parameter ``surface_pressure_pa`` (101325 Pa by default).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from rovlab.core import frames
from rovlab.core.components import TRUTH_INDEX
from rovlab.interfaces.node.core import NodeCore, NodeOutput
from rovlab.io import ros2msg

TOPICS = {"pressure": "pressure", "mocap": "mocap/pose", "imu": "imu", "setpoint": "setpoint",
          "odometry": "odometry", "wrench": "wrench", "pwm": "thrusters/pwm_us", "diagnostics": "diagnostics",
          "truth": "truth/odometry", "messages": "rovlab/messages", "abort": "fly/abort"}
WORLD_FRAME = ros2msg.WORLD_FRAME
BODY_FRAME = ros2msg.BODY_FRAME
SURFACE_PRESSURE_PA = 101325.0
# diagnostic_msgs/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3


class MessageError(ValueError):
    """A message that cannot be used; the text names the topic and the field."""


# --------------------------------------------------------------------------------------------
# Outgoing
# --------------------------------------------------------------------------------------------

def odometry_content(out: NodeOutput | None = None, *, nav: Mapping[str, float] | None = None,
                     P: np.ndarray | None = None, states: tuple[str, ...] = ()) -> dict[str, Any]:
    """Position (ENU), orientation quaternion (base_link in ENU), linear and angular velocity
    (FLU) and the two 6x6 covariances (row-major lists of 36) of an estimate -- from a node output,
    or from ``nav`` (TRUTH names -> values) with an optional covariance P over ``states``; the
    covariance convention is rovlab.io.ros2msg's (UNESTIMATED_VARIANCE for what is not estimated,
    zeros for an exact state)."""
    if out is not None:
        nav = {q: float(out.nav[i]) for i, q in enumerate(("x", "y", "z", "psi", "u", "v", "w", "r"))}
        estimated = dict(zip(out.states, out.estimated))
        P, states = out.P, tuple(estimated[s] for s in out.states)
    assert nav is not None
    return ros2msg.odometry_content(nav, P, states)


def fill_odometry(msg: Any, content: Mapping[str, Any], *, frame: str = WORLD_FRAME, child: str = BODY_FRAME) -> Any:
    """Fill a nav_msgs/Odometry (ROS 1 or 2) except its header stamp."""
    msg.header.frame_id = frame
    msg.child_frame_id = child
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = content["position"]
    q.x, q.y, q.z, q.w = content["orientation"]
    msg.pose.covariance = [float(v) for v in content["pose_covariance"]]
    lin, ang = msg.twist.twist.linear, msg.twist.twist.angular
    lin.x, lin.y, lin.z = content["linear"]
    ang.x, ang.y, ang.z = content["angular"]
    msg.twist.covariance = [float(v) for v in content["twist_covariance"]]
    return msg


wrench_flu = ros2msg.wrench_flu


def fill_wrench(msg: Any, tau: np.ndarray, *, frame: str = BODY_FRAME) -> Any:
    msg.header.frame_id = frame
    (fx, fy, fz), (tx, ty, tz) = wrench_flu(tau)
    f, t = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z = fx, fy, fz
    t.x, t.y, t.z = tx, ty, tz
    return msg


def fill_pwm(msg: Any, dim_cls: Any, out: NodeOutput) -> Any:
    """std_msgs/Float64MultiArray: one PWM [us] per thruster, labelled by the thrusters' names."""
    dim = dim_cls()
    dim.label = ",".join(out.thrusters)
    dim.size = len(out.thrusters)
    dim.stride = len(out.thrusters)
    msg.layout.dim = [dim]
    msg.data = [float(v) for v in out.pwm_us]
    return msg


_LEVEL = {"ok": OK, "recovering": WARN, "off": WARN, "disabled": STALE}


def diagnostics_content(out: NodeOutput, counters: Mapping[str, int], *, name: str = "rovlab",
                        gains: Any = None) -> list[dict[str, Any]]:
    """One DiagnosticStatus per sensor (level from its worst channel: ok -> OK, recovering or off
    -> WARN, lost -> ERROR, switched off -> STALE), then one for the node: the sample counters and
    the controller's gain matrix K (row-major, when it has one) so a tuning can be checked."""
    statuses = []
    for sensor, label in out.sensor_status.items():
        values = {ch: st for ch, st in zip(out.channels, out.channel_status) if ch.split(".")[0] == sensor}
        statuses.append({"level": _LEVEL.get(label, ERROR), "name": f"{name}/sensors/{sensor}", "message": label,
                         "hardware_id": sensor, "values": values})
    values = {k: str(v) for k, v in counters.items()}
    if gains is not None:
        values["K"] = " ".join(f"{v:.9g}" for v in np.asarray(gains, dtype=float).ravel())
    statuses.append({"level": OK, "name": f"{name}/node", "message": "engaged" if out.engaged else "no set-point yet",
                     "hardware_id": "", "values": values})
    return statuses


def fill_diagnostics(msg: Any, status_cls: Any, kv_cls: Any, content: list[dict[str, Any]]) -> Any:
    out = []
    for c in content:
        s = status_cls()
        s.level = bytes([c["level"]]) if isinstance(getattr(s, "level", b""), bytes) else c["level"]
        s.name, s.message, s.hardware_id = c["name"], c["message"], c["hardware_id"]
        vals = []
        for k, v in c["values"].items():
            kv = kv_cls()
            kv.key, kv.value = str(k), str(v)
            vals.append(kv)
        s.values = vals
        out.append(s)
    msg.status = out
    return msg


# --------------------------------------------------------------------------------------------
# Incoming (ValueError / MessageError naming the field for anything unusable)
# --------------------------------------------------------------------------------------------

def _finite(value: Any, where: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise MessageError(f"{where} = {value!r} is not a number") from None
    if not math.isfinite(v):
        raise MessageError(f"{where} = {v} is not finite")
    return v


def depth_from_pressure(pressure_pa: Any, *, rho: float, g: float, surface_pa: float = SURFACE_PRESSURE_PA) -> float:
    """Depth of the pressure sensor [m] from its absolute pressure [Pa] (hydrostatics at the edge)."""
    p = _finite(pressure_pa, "fluid_pressure")
    if not 0.0 <= p < 1e8:
        raise MessageError(f"fluid_pressure = {p} Pa is not a plausible absolute pressure")
    return (p - surface_pa) / (rho * g)


def pressure_from_depth(depth: float, *, rho: float, g: float, surface_pa: float = SURFACE_PRESSURE_PA) -> float:
    return surface_pa + rho * g * depth


def pose_samples(pose: Any, where: str = "pose") -> dict[str, float]:
    """NED x, y, z and heading psi of a geometry_msgs/Pose of base_link in an ENU world."""
    p, q = pose.position, pose.orientation
    e = [_finite(p.x, f"{where}.position.x"), _finite(p.y, f"{where}.position.y"), _finite(p.z, f"{where}.position.z")]
    quat = [_finite(getattr(q, a), f"{where}.orientation.{a}") for a in "xyzw"]
    n = frames.enu_to_ned(e)
    try:
        psi = frames.quaternion_heading(quat)
    except ValueError as exc:
        raise MessageError(f"{where}.orientation: {exc}") from None
    return {"x": float(n[0]), "y": float(n[1]), "z": float(n[2]), "psi": psi}


def imu_samples(msg: Any) -> dict[str, float]:
    """Heading psi (when the orientation is given, REP-145: covariance[0] != -1) and yaw rate r
    (FRD) of a sensor_msgs/Imu in ENU / FLU."""
    out: dict[str, float] = {}
    raw = getattr(msg, "orientation_covariance", None)
    cov = [] if raw is None else list(raw)  # rclpy gives a numpy array: no `or []` (its truth value raises)
    if not cov or cov[0] != -1.0:
        q = msg.orientation
        quat = [_finite(getattr(q, a), f"imu.orientation.{a}") for a in "xyzw"]
        if any(quat):
            try:
                out["psi"] = frames.quaternion_heading(quat)
            except ValueError as exc:
                raise MessageError(f"imu.orientation: {exc}") from None
    av = msg.angular_velocity
    wz = _finite(av.z, "imu.angular_velocity.z")
    out["r"] = float(frames.flu_to_frd([0.0, 0.0, wz])[2])
    return out


def stamp_seconds(sec: Any, nanosec: Any) -> float:
    s = float(sec) + 1e-9 * float(nanosec)
    if not math.isfinite(s) or s <= 0.0:
        raise MessageError(f"header.stamp = {s} s is not a valid time")
    return s


def push_samples(core: NodeCore, sensor: str | None, samples: Mapping[str, float], stamp: float) -> list[str]:
    """Offer a sensor's samples to the node; returns the results (see NodeCore.push)."""
    if sensor is None:
        return []
    return [core.push(sensor, q, v, stamp) for q, v in samples.items()]


# --------------------------------------------------------------------------------------------
# Parameters: the configuration file's numbers, set through the file loader
# --------------------------------------------------------------------------------------------

# the tables of every design file whose numbers are run-time parameters; besides them, the tables
# of the components that the file has ([mrac], [ekf], [dp], a plugin's [pd]: DesignConfig.tables)
_TUNABLE_TABLES = ("process_noise", "fusion", "lqr", "model")


def _numeric(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def parameter_values(data: Mapping[str, Any], design: Any) -> dict[str, Any]:
    """The run-time parameters of a configuration file's dict (see :class:`ParameterTable`) and
    their values, for the vehicle node's design (rovlab.sim.runner.Design): name -> value."""
    return {name: value for name, (_path, value) in _parameters(data, design).items()}


def _parameters(data: Mapping[str, Any], design: Any) -> dict[str, tuple[str, Any]]:
    """name -> (key path in the file, value)."""
    out: dict[str, tuple[str, Any]] = {}

    def walk(node: Mapping[str, Any], prefix: str) -> None:
        for key, v in node.items():
            name = f"{prefix}.{key}"
            if isinstance(v, Mapping):
                walk(v, name)
            elif _numeric(v) or (isinstance(v, list) and v and all(_numeric(x) for x in v)):
                out[name] = (name, [float(x) for x in v] if isinstance(v, list) else float(v))

    for table in (*_TUNABLE_TABLES, *design.config.tables):
        if isinstance(data.get(table), Mapping):
            walk(data[table], table)
    channels = design.estimator.channels
    for i, (m, c) in enumerate(zip(data.get("measurements", []), design.config.measurements)):
        ch = next((x for x in channels if x.quantity == c.quantity and
                   (x.sensor == c.sensor or (c.sensor is None and x.kind == c.kind))), None)
        if ch is None:
            continue
        variance = m.get("variance") if isinstance(m, Mapping) else None
        out[f"measurements.{ch.sensor}.{ch.quantity}.variance"] = (
            f"measurements[{i}].variance", float(variance if variance is not None else ch.variance))
    for c in channels:
        out.setdefault(f"sensors.{c.sensor}.enabled", ("", True))
    for c in channels:
        out[f"filter.{c.name}.mode"] = ("", "auto")
    return out


class ParameterTable:
    """The node's run-time parameters: the configuration file's numbers (process noise W, bias
    time constants, measurement variances R, fusion settings, LQR weights, model overrides, and
    the numbers of every component table the file has: [mrac], [ekf], [dp], a plugin's),
    one on/off switch per sensor and one mode per filter channel.

    Names are the file's key paths (``process_noise.psd.w``, ``lqr.state_max.z``), a measurement's
    variance is ``measurements.<sensor>.<quantity>.variance``, a sensor switch
    ``sensors.<sensor>.enabled`` (true/false), a channel's mode ``filter.<sensor>.<quantity>.mode``
    ('auto', 'off', 'on'). :meth:`set` validates a batch with the configuration loader and
    redesigns (rovlab.params.design, NodeCore.apply): a refused batch changes nothing and the
    reason names the parameter and what was expected.
    """

    def __init__(self, core: NodeCore, config_file: str | Path | None, data: Mapping[str, Any]) -> None:
        self.core = core
        self.file = str(config_file) if config_file is not None else None
        self.base = copy.deepcopy(dict(data))
        self.data = copy.deepcopy(dict(data))
        self.edits: dict[str, Any] = {}  # key path (rovlab.params.edit syntax) -> value
        params = _parameters(self.data, core.design)
        self._path = {name: path for name, (path, _v) in params.items() if path}
        self.values: dict[str, Any] = {name: v for name, (_p, v) in params.items()}

    def set(self, changes: Mapping[str, Any]) -> str | None:
        """Apply a batch of parameter changes; None on success, else the reason (nothing changed)."""
        from rovlab.params.design import design_config_from_dict
        from rovlab.params.edit import apply_edits
        from rovlab.params.validate import ConfigError

        switches: dict[str, bool] = {}
        modes: dict[str, str] = {}
        edits: dict[str, Any] = {}
        for name, value in changes.items():
            if name.startswith("filter.") and name.endswith(".mode"):
                channel = name[len("filter."):-len(".mode")]
                if channel not in [c.name for c in self.core.channels]:
                    return f"{name}: unknown channel {channel!r}"
                if value not in ("auto", "off", "on"):
                    return f"{name} = {value!r}: expected 'auto', 'off' or 'on'"
                modes[channel] = value
                continue
            if name.startswith("sensors.") and name.endswith(".enabled"):
                sensor = name[len("sensors."):-len(".enabled")]
                if sensor not in self.core.sensors:
                    return f"{name}: unknown sensor {sensor!r} (the filter fuses {', '.join(self.core.sensors)})"
                if not isinstance(value, bool):
                    return f"{name} = {value!r}: expected true or false"
                switches[sensor] = value
                continue
            if name not in self._path:
                return f"{name}: not a parameter of this node"
            old = self.values[name]
            if isinstance(old, list):
                if not (isinstance(value, (list, tuple)) and len(value) == len(old) and all(_numeric(x) for x in value)):
                    return f"{name} = {value!r}: expected {len(old)} numbers"
                value = [float(x) for x in value]
                if not all(math.isfinite(x) for x in value):
                    return f"{name} = {value!r}: expected finite numbers"
            else:
                if not _numeric(value) or not math.isfinite(float(value)):
                    return f"{name} = {value!r}: expected a finite number"
                value = float(value)
            edits[self._path[name]] = value
        if edits:
            import tomlkit

            doc = tomlkit.document()
            for k, v in self.data.items():
                doc[k] = v
            try:
                apply_edits(doc, edits, file=self.file or "<parameters>")
                data = doc.unwrap()
                config = design_config_from_dict(data, file=self.file or self.core.config.file or "<parameters>")
                self.core.apply(config=config)
            except (ConfigError, ValueError) as exc:
                return str(exc)
            self.data = data
            self.edits.update(edits)
        for sensor, on in switches.items():
            self.core.set_sensor_enabled(sensor, on)
        for channel, mode in modes.items():
            self.core.set_filter_mode(channel, mode)
        for name, value in changes.items():
            self.values[name] = value if not isinstance(value, (int, float)) or isinstance(value, bool) else float(value)
        return None

    def save(self, path: str | Path) -> Path:
        """Write the tuned configuration: the original file with the changed values (comments
        kept), or the data as TOML when the node was started from a packaged name."""
        from rovlab.params.edit import edit_toml_file

        path = Path(path)
        if self.file and Path(self.file).exists():
            edit_toml_file(self.file, self.edits, output=path)
        else:
            import tomlkit

            from rovlab.core.files import atomic_write_text

            atomic_write_text(path, tomlkit.dumps(self.data))
        return path


# --------------------------------------------------------------------------------------------
# The message layer under both adapters (rovlab.interfaces.node.ros1 / ros2): what a vehicle node
# and a simulated vehicle do with ROS messages, whatever the middleware. An adapter gives it the
# message classes and how to stamp a header and read a stamp; it keeps the transport (publishers,
# subscriptions, timers, parameters, spinning).
# --------------------------------------------------------------------------------------------

class Throttle:
    """Log a repeated problem at most once per ``period`` seconds, with the count in between
    (thread-safe: rospy calls back from several threads)."""

    def __init__(self, log: Any, period: float = 2.0) -> None:
        import threading

        self.log, self.period = log, period
        self.last: dict[str, float] = {}
        self.count: dict[str, int] = {}
        self.lock = threading.Lock()

    def __call__(self, key: str, message: str) -> None:
        import time

        now = time.monotonic()
        with self.lock:
            self.count[key] = self.count.get(key, 0) + 1
            if now - self.last.get(key, -1e9) < self.period:
                return
            n = self.count.pop(key)
            self.last[key] = now
        self.log(message + (f" ({n} times since the last report)" if n > 1 else ""))


class Messages(NamedTuple):
    """The ROS message classes both adapters use (each adapter imports them from its middleware)."""

    FluidPressure: Any
    PoseStamped: Any
    Imu: Any
    Odometry: Any
    WrenchStamped: Any
    Float64MultiArray: Any
    MultiArrayDimension: Any
    DiagnosticArray: Any
    DiagnosticStatus: Any
    KeyValue: Any


class RosAdapter:
    """What a vehicle node and a simulated vehicle share on either middleware: stamping, guarding
    callbacks. A subclass sets ``msgs`` (:class:`Messages`), ``warn`` (:class:`Throttle`) and
    ``info``, and defines :meth:`now`, :meth:`set_stamp` and :meth:`stamp_seconds`."""

    msgs: Messages
    warn: Throttle
    info: Any

    def now(self) -> float:
        raise NotImplementedError

    def set_stamp(self, header: Any, seconds: float) -> None:
        """Stamp a message header with a time in seconds."""
        raise NotImplementedError

    def stamp_seconds(self, stamp: Any, now: float) -> float:
        """A header stamp in seconds; ``now`` (its arrival) for an unstamped message."""
        raise NotImplementedError

    def guard(self, where: str, fn: Any) -> Any:
        """``fn`` as a callback that logs (throttled) what a bad message raises and carries on:
        nothing from the outside stops the node."""
        def call(*args: Any) -> None:
            try:
                fn(*args)
            except MessageError as exc:
                self.warn(where, f"{TOPICS.get(where, where)}: message ignored: {exc}")
            except Exception as exc:  # noqa: BLE001 - nothing from outside may stop the node
                self.warn(where + "!", f"{where}: {type(exc).__name__}: {exc} (the node keeps running)")
        return call


class VehicleAdapter(RosAdapter):
    """The vehicle node's messages (NodeCore behind them): sensor samples in, set-points in,
    odometry, wrench, PWM and diagnostics out. A subclass creates the publishers ``pub_odom``,
    ``pub_wrench``, ``pub_pwm``, ``pub_diag`` and routes the sensor and set-point subscriptions to
    :meth:`on_pressure`, :meth:`on_mocap`, :meth:`on_imu`, :meth:`on_setpoint` (through
    :meth:`guard`), and ticks :meth:`run` from a timer."""

    pub_odom: Any
    pub_wrench: Any
    pub_pwm: Any
    pub_diag: Any
    flight: Any = None  # a dive plan being flown (fly; rovlab.interfaces.node.flight.PlanFlight)
    exit_code = 0  # 1: a flight aborted

    def setup(self, core: NodeCore, table: ParameterTable, recorder: Any = None) -> None:
        self.core, self.table, self.recorder = core, table, recorder
        v = core.vehicle
        self.rho, self.g = v.water_density, v.gravity
        self.surface_pa = SURFACE_PRESSURE_PA
        self.sensor = {k: core.sensor_of_kind(k) for k in ("pressure", "motion_capture", "imu")}

    def push(self, kind: str, samples: dict[str, float], stamp: float, topic: str) -> None:
        for result in push_samples(self.core, self.sensor[kind], samples, stamp):
            if result == "invalid":
                self.warn(topic + result, f"{topic}: {self.core.last_problem}")
        if self.recorder is not None:
            self.recorder.sample(topic, stamp, samples)
        self.run(self.now())

    def on_pressure(self, msg: Any) -> None:
        stamp = self.stamp_seconds(msg.header.stamp, self.now())
        depth = depth_from_pressure(msg.fluid_pressure, rho=self.rho, g=self.g, surface_pa=self.surface_pa)
        self.push("pressure", {"z": depth}, stamp, "pressure")

    def on_mocap(self, msg: Any) -> None:
        stamp = self.stamp_seconds(msg.header.stamp, self.now())
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        self.push("motion_capture", pose_samples(pose, "mocap/pose.pose"), stamp, "mocap/pose")

    def on_imu(self, msg: Any) -> None:
        self.push("imu", imu_samples(msg), self.stamp_seconds(msg.header.stamp, self.now()), "imu")

    def on_setpoint(self, msg: Any) -> None:
        flight = getattr(self, "flight", None)
        if flight is not None:  # someone else commands: a pilot takes over
            if not flight.ended:
                self.core.abort_flight(f"pilot input: a set-point on {TOPICS['setpoint']} (the set-point is not "
                                       "held: the node goes neutral)")
            return
        s = pose_samples(msg.pose, "setpoint.pose")
        if s["z"] < 0.0:
            raise MessageError(f"setpoint depth {s['z']:g} m (ENU z = {-s['z']:g}) is above the surface")
        engaged = self.core.engaged
        if "x" in self.core.references:  # dynamic positioning: the set-point's position too
            self.core.set_reference(x=s["x"], y=s["y"], z=s["z"], psi=s["psi"])
            if not engaged:
                self.info(f"first set-point: north {s['x']:g} m, east {s['y']:g} m, depth {s['z']:g} m, heading "
                          f"{s['psi']:g} rad; controller {self.core.controller_name} engaged")
            return
        self.core.set_reference(z=s["z"], psi=s["psi"])
        if not engaged:
            self.info(f"first set-point: depth {s['z']:g} m, heading {s['psi']:g} rad; controller "
                      f"{self.core.controller_name} engaged (it holds depth and heading: the set-point's x and y "
                      "are not used; a configuration with controller = \"dp\" holds a position)")

    def run(self, now: float) -> None:
        outs = self.core.tick(now)
        if outs:
            self.publish(outs[-1])
        if self.flight is not None:
            self._fly(now)

    # -- flying a dive plan (rovlab.interfaces.node.flight) ----------------------------------------
    def fly(self, plan: Any, guards: Any = None) -> Any:
        """Fly ``plan`` once the estimated depth is at its start depth (the depth controller takes
        the vehicle there first); abort to neutral on the core's guards, a set-point or a message on
        NS/fly/abort; stop the node END_NEUTRAL_S after the flight (:meth:`request_stop`)."""
        self.flight = self.core.fly(plan, guards)
        self._fly_phase = "waiting"
        self._near_since: float | None = None
        self._ended_at: float | None = None
        return self.flight

    def on_abort(self, text: str) -> None:
        """A message on NS/fly/abort (std_msgs/String): abort the flight."""
        if self.flight is not None:
            self.core.abort_flight(f"abort message on {TOPICS['abort']}: {str(text)[:80]!r}")

    def request_stop(self) -> None:
        """Stop the node (a middleware's own way); after a flight ended."""

    def _fly(self, now: float) -> None:
        from rovlab.interfaces.node.flight import END_NEUTRAL_S, START_SETTLE_S

        f, core = self.flight, self.core
        if f.ended:
            if self._fly_phase != "ended":
                self._fly_phase, self._ended_at = "ended", now
                core.disengage()
                (self.info if f.state == "complete" else self.warn_now)(
                    ("" if f.state == "complete" else "ABORTED TO NEUTRAL: ") + f.summary())
                if f.state == "aborted":
                    self.exit_code = 1
            elif self._ended_at is not None and now - self._ended_at >= END_NEUTRAL_S:
                self._ended_at = None
                self.request_stop()
            return
        last = core.last
        if f.active or last is None:
            return
        j = core.depth_channel()
        if j is None or last.channel_status[j] not in ("ok", "recovering"):
            return  # waiting for the depth sensor
        z = float(last.nav[TRUTH_INDEX["z"]])
        start, tol = f.plan.start_depth, f.guards.start_tolerance_m
        if abs(z - start) <= tol:
            if self._fly_phase == "waiting" or (self._near_since is not None and now - self._near_since >= START_SETTLE_S):
                core.start_flight()
                self._fly_phase = "flying"
                lo, hi = f.depth_limits()
                self.info(f"flying the plan: {f.plan.duration_s:.0f} s of {', '.join(f.plan.dofs)} excitation from "
                          f"{z:.2f} m (abort outside {lo:.2f} .. {hi:.2f} m, beyond +-{f.guards.turns:g} turns or "
                          f"{math.degrees(f.guards.yaw_rate_rad_s):.0f} deg/s, on a lost depth sensor, a set-point "
                          f"or a message on {TOPICS['abort']})")
            elif self._near_since is None:
                self._near_since = now
            return
        self._near_since = None
        if self._fly_phase == "waiting":
            if "z" in core.references:
                self._fly_phase = "descending"
                self.info(f"going to the plan's start depth {start:g} m (now {z:.2f} m) with the depth controller "
                          f"of {core.config.name}")
                core.set_reference(z=start)
            else:
                self._fly_phase = "told"
                self.info(f"bring the vehicle to the plan's start depth {start:g} m (now {z:.2f} m; "
                          f"{core.config.name} has no depth controller)")

    def warn_now(self, text: str) -> None:
        self.warn("flight", text)

    def publish(self, out: NodeOutput) -> None:
        m = self.msgs
        odom = fill_odometry(m.Odometry(), odometry_content(out))
        self.set_stamp(odom.header, out.stamp)
        self.pub_odom.publish(odom)
        w = fill_wrench(m.WrenchStamped(), out.tau)
        self.set_stamp(w.header, out.stamp)
        self.pub_wrench.publish(w)
        self.pub_pwm.publish(fill_pwm(m.Float64MultiArray(), m.MultiArrayDimension, out))
        if out.k % max(1, int(round(1.0 / self.core.h))) == 0:  # about 1 Hz
            d = fill_diagnostics(m.DiagnosticArray(), m.DiagnosticStatus, m.KeyValue, diagnostics_content(
                out, self.core.counters, gains=getattr(self.core.design.controller.model, "K", None)))
            self.set_stamp(d.header, out.stamp)
            self.pub_diag.publish(d)
        self.publish_more(out)
        if self.recorder is not None:
            self.recorder.output(out)

    def publish_more(self, out: NodeOutput) -> None:
        """What one middleware publishes beyond the common topics (nothing by default)."""


class SimAdapter(RosAdapter):
    """The simulated vehicle's messages: each step's sensor samples (pressure, motion capture, IMU),
    the truth as odometry and the scenario's set-points. A subclass creates the publishers
    ``pub_p``, ``pub_m``, ``pub_i``, ``pub_t`` and ``pub_s`` (None without set-points)."""

    pub_p: Any
    pub_m: Any
    pub_i: Any
    pub_t: Any
    pub_s: Any

    WAIT_NOTE_EVERY_S = 15.0

    def setup(self, sim: Any, *, duration_s: float | None = None, wait_limit_s: float = 900.0) -> None:
        self.sim = sim
        truth = sim.prep.truth
        self.rho, self.g = truth.water_density, truth.gravity
        self.last_ref: tuple[float, float] | None = None
        self.last_ref_time = -1e9
        self.duration_s = duration_s  # simulated seconds after the vehicle starts (None: until stopped)
        self.started_at: float | None = None
        self.wait_limit_s = wait_limit_s  # give up when no node came for this long
        self.wait_since: float | None = None
        self.last_wait_s = 0.0
        self._next_wait_note = 0.0

    def note_waiting(self, now: float) -> bool:
        """Say, every WAIT_NOTE_EVERY_S, that the vehicle waits for a node (so a node that is still
        compiling on its first start does not look like a broken link); True once it has waited
        ``wait_limit_s`` (time to give up)."""
        if self.wait_since is None:
            self.wait_since = now
            self._next_wait_note = now + self.WAIT_NOTE_EVERY_S
        self.last_wait_s = now - self.wait_since
        if now >= self._next_wait_note:
            self._next_wait_note = now + self.WAIT_NOTE_EVERY_S
            self.info(f"waiting for a node to listen to the sensors and command the thrusters "
                      f"({now - self.wait_since:.0f} s; a node's first start on a machine compiles its control "
                      "step: `rovlab compile --node` prepares it ahead)")
        return now - self.wait_since >= self.wait_limit_s

    def started(self, now: float) -> bool:
        """Mark the vehicle started (first call); whether its --duration has run out."""
        if self.started_at is None:
            self.started_at = now
        return self.duration_s is not None and now - self.started_at >= self.duration_s

    def exit_note(self) -> str | None:
        """What to say at exit when the vehicle never started (None when it did)."""
        if self.started_at is not None:
            return None
        waited = "" if self.wait_since is None else f" in {self.last_wait_s:.0f} s"
        return (f"the simulated vehicle never started: no node listened to its sensors and commanded its thrusters{waited} "
                "(is `rovlab ros2/ros1 node` running in the same namespace? its first start compiles: "
                "`rovlab compile --node` prepares it ahead)")

    def publish_step(self, s: Any, now: float) -> None:
        m = self.msgs
        by_sensor: dict[str, dict[str, float]] = {}
        for sensor, quantity, value in s.samples:
            by_sensor.setdefault(sensor, {})[quantity] = value
        for sensor, values in by_sensor.items():
            kind = self.sim.sensor_kind(sensor)
            if kind == "pressure" and "z" in values:
                p = m.FluidPressure()
                self.set_stamp(p.header, now)
                p.header.frame_id = sensor
                p.fluid_pressure = pressure_from_depth(values["z"], rho=self.rho, g=self.g)
                self.pub_p.publish(p)
            elif kind == "motion_capture":
                pm = m.PoseStamped()
                self.set_stamp(pm.header, now)
                pm.header.frame_id = WORLD_FRAME
                c = odometry_content(nav={"x": s.truth["x"], "y": s.truth["y"], "z": values.get("z", s.truth["z"]),
                                          "psi": values.get("psi", s.truth["psi"])})
                pos, q = pm.pose.position, pm.pose.orientation
                pos.x, pos.y, pos.z = c["position"]
                q.x, q.y, q.z, q.w = c["orientation"]
                self.pub_m.publish(pm)
            elif kind == "imu":
                im = m.Imu()
                self.set_stamp(im.header, now)
                im.header.frame_id = BODY_FRAME
                c = odometry_content(nav={"psi": values.get("psi", 0.0), "r": values.get("r", 0.0)})
                if "psi" in values:
                    q = im.orientation
                    q.x, q.y, q.z, q.w = c["orientation"]
                else:  # no orientation (REP 145): -1 in the first entry of its covariance
                    im.orientation_covariance = [-1.0] + [0.0] * 8
                im.angular_velocity.z = c["angular"][2]
                self.pub_i.publish(im)
        t = fill_odometry(m.Odometry(), odometry_content(nav=s.truth))
        self.set_stamp(t.header, now)
        self.pub_t.publish(t)
        if self.pub_s is not None and (s.reference != self.last_ref or now - self.last_ref_time > 1.0):
            sp = m.PoseStamped()
            self.set_stamp(sp.header, now)
            sp.header.frame_id = WORLD_FRAME
            c = odometry_content(nav={"z": s.reference[0], "psi": s.reference[1]})
            sp.pose.position.z = c["position"][2]
            q = sp.pose.orientation
            q.x, q.y, q.z, q.w = c["orientation"]
            self.pub_s.publish(sp)
            self.last_ref, self.last_ref_time = s.reference, now

    def set_pwm(self, msg: Any) -> None:
        """The thrusters' PWM commands of a message (a wrong one is logged and ignored), acting from
        when it arrived (before the vehicle started: from its first period)."""
        t0 = getattr(self, "t0", None)
        try:
            self.sim.set_pwm(list(msg.data), at=None if t0 is None else self.now() - t0)
        except ValueError as exc:
            self.warn("pwm", f"thrusters/pwm_us ignored: {exc}")
