"""A running ROS 2 vehicle node as the HMI's source (``rovlab hmi --source ros2``).

The node publishes, with every control step, rovlab's own messages (rovlab.io.messages: estimate,
measurement, reference, command) as JSON on ``NS/rovlab/messages`` (std_msgs/String); this source
collects them on a background rclpy thread and hands them to the HMI, which shows them exactly as it
shows a simulation. Commands go back the standard way: a set-point on ``NS/setpoint``, sensor
switches, filter modes and configuration changes as ROS 2 parameters of the node (validated there
by the same loader; a refusal comes back with its reason and nothing changes). Imports rclpy.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Mapping
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from rovlab.core import frames
from rovlab.interfaces.node import ros_common as rc
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def _value(v: Any) -> ParameterValue:
    pv = ParameterValue()
    if isinstance(v, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, v
    elif isinstance(v, (int, float)):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, float(v)
    elif isinstance(v, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, v
    else:
        pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, [float(x) for x in v]
    return pv


class Ros2Source:
    """The HMI's Source protocol over a running ``rovlab ros2 node`` (see the module)."""

    kind = "vehicle"
    paced = True  # the HMI's pacer collects what arrived; the node keeps its own clock

    def __init__(self, *, vehicle: Vehicle, config: DesignConfig, config_data: Mapping[str, Any],
                 stash: Mapping[int, Mapping[str, Any]], namespace: str = "", node_name: str = "rovlab_node",
                 timeout_s: float = 10.0) -> None:
        from rovlab.sim.designs import make_design

        self.vehicle, self.config = vehicle, config
        self.design = make_design(vehicle, config, plant="process", plant_step=config.sample_time)
        self._stash = stash  # DesignConfig id -> the dict it was validated from (the HMI's documents)
        self.sent = rc.parameter_values(config_data, self.design)
        self.timeout_s = timeout_s
        ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("rovlab_hmi", context=self.ctx)
        self.pub_sp = self.node.create_publisher(PoseStamped, f"{ns}/setpoint", RELIABLE)
        self.node.create_subscription(String, f"{ns}/rovlab/messages", self._on_messages, RELIABLE)
        self.cli = self.node.create_client(SetParametersAtomically, f"{ns}/{node_name}/set_parameters_atomically")
        self._lock = threading.Lock()
        self._inbox: list[tuple[str, float, dict[str, Any]]] = []
        self._t = 0.0
        self.reference = (math.nan, math.nan)
        self.sensors = {c.sensor: True for c in self.design.estimator.channels}
        self.modes = {c.name: "auto" for c in self.design.estimator.channels}
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="rovlab-hmi-ros2", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shut down from close()
            pass

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        self._thread.join(3.0)

    def _on_messages(self, msg: Any) -> None:
        try:
            items = json.loads(msg.data)
            out = [(str(topic), float(t), dict(m)) for topic, t, m in items]
        except (ValueError, TypeError):
            return
        with self._lock:
            self._inbox.extend(out)
            if out:
                self._t = max(self._t, out[-1][1])
            for topic, _t, m in out:
                if topic == "/rovlab/reference":
                    self.reference = (m["state"].get("z"), m["state"].get("psi"))

    # -- Source protocol -----------------------------------------------------------------------
    @property
    def h(self) -> float:
        return float(self.config.sample_time)

    @property
    def time(self) -> float:
        return self._t + self.h

    def describe(self) -> dict[str, Any]:
        est = self.design.estimator
        return {
            "kind": self.kind,
            "scenario": {"name": "ROS 2 vehicle node", "description": "a running rovlab ros2 node", "plant": "vehicle",
                         "seed": None, "file": None},
            "vehicle": self.vehicle.name, "config": self.config.name, "h": self.h, "has_truth": False,
            "states": list(est.states),
            "channels": [{"name": c.name, "column": c.column, "sensor": c.sensor, "quantity": c.quantity,
                          "offset": c.offset} for c in est.channels],
            "sensors": list(self.sensors), "thrusters": list(self.design.allocator.bank.names),
            "controller": self.config.controller, "controller_states": list(self.design.controller.state_names),
            "references": ["z", "psi"],  # this source sends depth and heading set-points only
        }

    def status(self) -> dict[str, Any]:
        z, psi = self.reference
        return {"time_s": self._t, "reference": {"z": z, "psi": psi, "schedule": False},
                "sensors": dict(self.sensors), "filter_modes": dict(self.modes)}

    def advance(self, n: int) -> list[tuple[str, float, dict[str, Any]]]:
        with self._lock:
            out, self._inbox = self._inbox, []
        return out

    def reset(self) -> None:
        raise ValueError("a running vehicle cannot be reset from the HMI (restart its node)")

    def set_reference(self, z: float | None = None, psi: float | None = None, *, x: float | None = None,
                      y: float | None = None) -> None:
        if x is not None or y is not None:
            raise ValueError("this node holds depth and heading: north/east set-points need the DP controller, "
                             "which the ROS nodes do not run yet")
        zr, pr = self.reference
        z = z if z is not None else zr
        psi = psi if psi is not None else pr
        for name, v in (("z", z), ("psi", psi)):
            if v is None or not math.isfinite(v):
                raise ValueError(f"reference {name} must be a finite number (the node has no set-point yet)")
        assert z is not None and psi is not None
        if z < 0:
            raise ValueError(f"reference depth z must be >= 0 m, got {z!r}")
        m = PoseStamped()
        m.header.frame_id = rc.WORLD_FRAME
        m.pose.position.z = float(frames.ned_to_enu([0.0, 0.0, z])[2])
        q = frames.heading_quaternion(psi)
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = q
        self.pub_sp.publish(m)
        self.reference = (z, psi)

    def follow_schedule(self) -> None:
        raise ValueError("a vehicle has no reference schedule: set a depth and heading")

    def set_sensor_available(self, sensor: str, available: bool) -> None:
        if sensor not in self.sensors:
            raise ValueError(f"unknown sensor {sensor!r}; the filter fuses {', '.join(self.sensors)}")
        self._set({f"sensors.{sensor}.enabled": bool(available)}, "sensors")
        self.sensors[sensor] = bool(available)

    def set_filter_mode(self, channel: str, mode: str) -> None:
        if channel not in self.modes:
            raise ValueError(f"unknown channel {channel!r}; the filter has {', '.join(self.modes)}")
        self._set({f"filter.{channel}.mode": mode}, "filter")
        self.modes[channel] = mode

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        if truth is not None:
            raise ValueError("a real vehicle has no plant truth to change")
        if vehicle is not None:
            raise ValueError("the model vehicle of a running node changes by restarting it with the edited file")
        if config is None:
            return
        data = self._stash.get(id(config))
        if data is None:
            raise ValueError("the configuration to apply is not one of the HMI's documents")
        from rovlab.sim.designs import make_design

        design = make_design(self.vehicle, config, plant="process", plant_step=config.sample_time)
        new = rc.parameter_values(data, design)
        changes = {k: v for k, v in new.items() if k in self.sent and v != self.sent[k]}
        unsupported = sorted(set(new) ^ set(self.sent))
        if unsupported:
            raise ConfigError([Problem(config.file or config.name, unsupported[0], "added or removed",
                                       "the same keys as the running node's configuration (restart the node to "
                                       "change its structure)")], "filter configuration")
        if changes:
            self._set(changes, config.file or config.name)
        self.sent.update(changes)
        self.config, self.design = config, design

    def loop_summary(self) -> dict[str, Any]:
        fm = self.design.estimator.model
        ctl = self.design.controller.model
        out: dict[str, Any] = {"controller": self.config.controller, "vehicle": {"name": self.vehicle.name}}
        if fm is not None:
            out["R"] = {c.name: c.variance for c in fm.channels}
            out["W"] = [float(x) for x in fm.W.diagonal()[2:]]
        if ctl is not None and hasattr(ctl, "K"):
            out["K"] = [[float(x) for x in row] for row in ctl.K]
        return out

    # -- parameters ----------------------------------------------------------------------------
    def _set(self, changes: Mapping[str, Any], where: str) -> None:
        """Set parameters on the node, all or none; ConfigError with the node's reason if refused."""
        if not self.cli.wait_for_service(timeout_sec=self.timeout_s):
            raise ValueError("the vehicle node does not answer (is `rovlab ros2 node` running in this namespace?)")
        req = SetParametersAtomically.Request(parameters=[Parameter(name=k, value=_value(v)) for k, v in changes.items()])
        done = threading.Event()
        fut = self.cli.call_async(req)
        fut.add_done_callback(lambda f: done.set())
        if not done.wait(self.timeout_s):
            raise ValueError("the vehicle node did not answer the parameter change in time")
        r = fut.result().result
        if not r.successful:
            key = next(iter(changes))
            raise ConfigError([Problem(where, key, changes[key], f"a value the node accepts: {r.reason}")],
                              "parameters")


def hmi_documents(vehicle: str, config: str) -> tuple[dict[str, Any], dict[int, Any]]:
    """The HMI's three parameter documents for a vehicle node, and the stash through which the
    source sees the dict behind each validated configuration."""
    from rovlab.interfaces.hmi.documents import ParameterDocument
    from rovlab.interfaces.hmi.session import _config_document, _vehicle_document
    from rovlab.params.design import design_config_from_dict

    stash: dict[int, Any] = {}

    def validate(d: Mapping[str, Any], f: str) -> DesignConfig:
        cfg = design_config_from_dict(d, file=f)
        stash[id(cfg)] = dict(d)
        return cfg

    base = _config_document(config)
    cdoc = ParameterDocument("config", base.data, origin=base.origin, label=base.label, validate=validate,
                             packaged=base.packaged)
    return {"vehicle": _vehicle_document("vehicle", vehicle), "truth": _vehicle_document("truth", vehicle),
            "config": cdoc}, stash


