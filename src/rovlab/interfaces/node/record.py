"""Recording a vehicle node's inputs and outputs to MCAP, for Foxglove, ROS 2 tools and replay.

Two views of the same run in one file:

* ROS 2 messages (CDR, ``ros2msg`` schemas) on the node's own topics, as they are on the wire
  (ENU/FLU, REP-103/105): ``pressure`` (sensor_msgs/FluidPressure), ``mocap/pose``
  (geometry_msgs/PoseStamped), ``odometry`` (nav_msgs/Odometry with the filter's covariance),
  ``wrench`` (geometry_msgs/WrenchStamped) and ``thrusters/pwm_us`` (std_msgs/Float64MultiArray);
* rovlab's JSON topics (rovlab.io.messages: /rovlab/estimate, /rovlab/measurement,
  /rovlab/reference, /rovlab/command), the layout of the simulator's logs, which
  ``rovlab filter`` replays and the HMI reads.

Messages are written as they come (chunked, so a crash loses at most the last chunk); :meth:`close`
finishes the file and is called on SIGINT / SIGTERM by the adapters.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore, NodeOutput
from rovlab.io import ros2msg
from rovlab.io.messages import TOPICS

_ROS2 = {"pressure": ros2msg.FLUID_PRESSURE, "mocap/pose": ros2msg.POSE_STAMPED, "odometry": ros2msg.ODOMETRY,
         "wrench": ros2msg.WRENCH_STAMPED, "thrusters/pwm_us": ros2msg.FLOAT64_MULTI_ARRAY}


def _stamp(seconds: float) -> dict[str, int]:
    ns = int(round(seconds * 1e9))
    return ros2msg.stamp(ns)


class NodeRecorder:
    """An MCAP file the node writes its inputs and outputs to (thread-safe; see the module)."""

    def __init__(self, path: str | Path, core: NodeCore, *, namespace: str = "") -> None:
        try:
            from mcap.writer import Writer
            from mcap_ros2._dynamic import serialize_dynamic
        except ImportError as exc:
            raise RuntimeError("recording needs mcap and mcap-ros2-support: pip install 'rovlab[log]'") from exc
        self.path = Path(path)
        self.core = core
        self._lock = threading.Lock()
        self._fh = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._w = Writer(self._fh, chunk_size=64 * 1024)
        self._w.start(profile="ros2", library="rovlab node")
        self._seq = 0
        self._ch: dict[str, int] = {}
        self._enc: dict[str, Any] = {}
        ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        for topic, datatype in _ROS2.items():
            text = ros2msg.DEFINITIONS[datatype]
            sid = self._w.register_schema(name=datatype, encoding="ros2msg", data=text.encode())
            self._ch[topic] = self._w.register_channel(topic=f"{ns}/{topic}", message_encoding="cdr", schema_id=sid)
            self._enc[topic] = serialize_dynamic(datatype, text)[datatype]
        for topic, schema in TOPICS.items():
            sid = self._w.register_schema(name="rovlab." + topic.rsplit("/", 1)[-1], encoding="jsonschema",
                                          data=json.dumps(schema).encode())
            self._ch[topic] = self._w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        v = core.vehicle
        self._w.add_metadata("rovlab", {"vehicle": v.name, "config": core.config.name, "sample_time_s": str(core.h),
                                        "channels": ",".join(c.name for c in core.channels),
                                        "thrusters": ",".join(core.thrusters), "world_frame": rc.WORLD_FRAME,
                                        "body_frame": rc.BODY_FRAME})
        self.closed = False

    def _add(self, topic: str, t_s: float, data: bytes) -> None:
        ns = int(round(t_s * 1e9))
        with self._lock:
            if self.closed:
                return
            self._w.add_message(self._ch[topic], log_time=ns, publish_time=ns, data=data, sequence=self._seq)
            self._seq += 1

    def sample(self, topic: str, stamp: float, samples: dict[str, float]) -> None:
        """An input as the node understood it (NED samples of a sensor topic), re-encoded as the
        ROS 2 message of that topic (pressure, mocap/pose; other inputs are not recorded)."""
        if topic == "pressure" and "z" in samples:
            v = self.core.vehicle
            msg = {"header": {"stamp": _stamp(stamp), "frame_id": "pressure"},
                   "fluid_pressure": rc.pressure_from_depth(samples["z"], rho=v.water_density, g=v.gravity),
                   "variance": 0.0}
        elif topic == "mocap/pose" and "z" in samples and "psi" in samples:
            c = rc.odometry_content(nav=samples)
            p, q = c["position"], c["orientation"]
            msg = {"header": {"stamp": _stamp(stamp), "frame_id": rc.WORLD_FRAME},
                   "pose": {"position": {"x": p[0], "y": p[1], "z": p[2]},
                            "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}}}
        else:
            return
        self._add(topic, stamp, self._enc[topic](msg))

    def output(self, out: NodeOutput) -> None:
        """One control step: odometry, wrench, PWM (ROS 2) and rovlab's JSON messages."""
        c = rc.odometry_content(out)
        p, q, lin, ang = c["position"], c["orientation"], c["linear"], c["angular"]
        hdr = {"stamp": _stamp(out.stamp), "frame_id": rc.WORLD_FRAME}
        odom = {"header": hdr, "child_frame_id": rc.BODY_FRAME,
                "pose": {"pose": {"position": dict(zip("xyz", p)), "orientation": dict(zip("xyzw", q))},
                         "covariance": c["pose_covariance"]},
                "twist": {"twist": {"linear": dict(zip("xyz", lin)), "angular": dict(zip("xyz", ang))},
                          "covariance": c["twist_covariance"]}}
        self._add("odometry", out.stamp, self._enc["odometry"](odom))
        force, torque = rc.wrench_flu(out.tau)
        wrench = {"header": {"stamp": _stamp(out.stamp), "frame_id": rc.BODY_FRAME},
                  "wrench": {"force": dict(zip("xyz", force)), "torque": dict(zip("xyz", torque))}}
        self._add("wrench", out.stamp, self._enc["wrench"](wrench))
        n = len(out.thrusters)
        pwm = {"layout": {"dim": [{"label": ",".join(out.thrusters), "size": n, "stride": n}], "data_offset": 0},
               "data": [float(v) for v in out.pwm_us]}
        self._add("thrusters/pwm_us", out.stamp, self._enc["thrusters/pwm_us"](pwm))
        for topic, _t, msg in out.messages():
            self._add(topic, out.stamp, json.dumps(msg).encode())

    def close(self) -> None:
        """Finish the file (summary, index); safe to call twice."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._w.finish()
            finally:
                self._fh.close()
