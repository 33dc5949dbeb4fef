"""Recording a vehicle node's inputs and outputs to MCAP, for ROS 2 tools, Foxglove and replay.

Two files of the same run (rovlab.io.timeseries.series_path names the second):

* ``RUN.mcap``, a ROS 2 bag (MCAP profile ``ros2``, every channel CDR with its ``ros2msg``
  definition): the node's own topics as they are on the wire (ENU/FLU, REP 103/105):
  ``pressure`` (sensor_msgs/FluidPressure, frame the pressure sensor), ``mocap/pose``
  (geometry_msgs/PoseStamped), ``odometry`` (nav_msgs/Odometry with the filter's covariance),
  ``wrench`` (geometry_msgs/WrenchStamped) and ``thrusters/pwm_us`` (std_msgs/Float64MultiArray),
  plus what a viewer needs to place the vehicle: ``/tf`` (tf2_msgs/TFMessage, map -> base_link
  from the estimate) and ``/tf_static`` (base_link -> each sensor of the vehicle file at its lever
  arm). The node itself does not broadcast tf; the recording adds it;
* ``RUN.rovlab.mcap``, rovlab's JSON topics (rovlab.io.messages: /rovlab/estimate,
  /rovlab/measurement, /rovlab/reference, /rovlab/command), the layout of the simulator's logs,
  which ``rovlab filter`` replays and the HMI reads (sensor status, innovations, controller state:
  what no standard ROS message holds).

Messages are written as they come (chunked, so a crash loses at most the last chunk); :meth:`close`
finishes both files and is called on SIGINT / SIGTERM by the adapters.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore, NodeOutput
from rovlab.io import ros2msg

_ROS2 = {"pressure": ros2msg.FLUID_PRESSURE, "mocap/pose": ros2msg.POSE_STAMPED, "odometry": ros2msg.ODOMETRY,
         "wrench": ros2msg.WRENCH_STAMPED, "thrusters/pwm_us": ros2msg.FLOAT64_MULTI_ARRAY}
_TF = {"/tf": ros2msg.TF_MESSAGE, "/tf_static": ros2msg.TF_MESSAGE}  # global, as tf2 uses them


def _ns(t_s: float) -> int:
    return int(round(t_s * 1e9))


class NodeRecorder:
    """The node's ROS 2 bag and its rovlab series file (thread-safe; see the module)."""

    def __init__(self, path: str | Path, core: NodeCore, *, namespace: str = "") -> None:
        try:
            from mcap.writer import CompressionType
            from mcap_ros2.writer import Writer
        except ImportError as exc:
            raise RuntimeError("recording needs mcap and mcap-ros2-support: pip install 'rovlab[log]'") from exc
        from rovlab.io.timeseries import McapStream, series_path

        self.path = Path(path)
        self.series_path = series_path(self.path)
        self.core = core
        self._lock = threading.Lock()
        v = core.vehicle
        meta = {"vehicle": v.name, "config": core.config.name, "sample_time_s": str(core.h),
                "channels": ",".join(c.name for c in core.channels), "thrusters": ",".join(core.thrusters),
                "world_frame": rc.WORLD_FRAME, "body_frame": rc.BODY_FRAME}
        self._fh = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._bag = Writer(self._fh, chunk_size=64 * 1024, compression=CompressionType.NONE)
        self._bag.add_metadata("rovlab", {**meta, "series": self.series_path.name})
        self._series = McapStream(self.series_path, metadata={**meta, "ros2_bag": self.path.name},
                                  chunk_size=64 * 1024)
        prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
        schemas = {t: self._bag.register_msgdef(t, ros2msg.DEFINITIONS[t]) for t in {*_ROS2.values(), *_TF.values()}}
        self._topics = {topic: (f"{prefix}/{topic}", schemas[datatype]) for topic, datatype in _ROS2.items()}
        self._topics.update({topic: (topic, schemas[datatype]) for topic, datatype in _TF.items()})
        self._pressure_frame = core.sensor_of_kind("pressure") or "pressure"
        self._sensors = [(s.name, s.position) for s in v.sensors]
        self._seq = 0
        self.closed = False

    def _add(self, topic: str, t_s: float, msg: dict[str, Any]) -> None:
        """One ROS 2 message (under the lock)."""
        ns = _ns(t_s)
        if self._seq == 0:  # the sensors' fixed frames, once, with the first message's time
            name, schema = self._topics["/tf_static"]
            self._bag.write_message(name, schema, ros2msg.tf_message(ros2msg.sensor_transforms(ns, self._sensors)),
                                    log_time=ns, publish_time=ns, sequence=0)
            self._seq = 1
        name, schema = self._topics[topic]
        self._bag.write_message(name, schema, msg, log_time=ns, publish_time=ns, sequence=self._seq)
        self._seq += 1

    def sample(self, topic: str, stamp: float, samples: dict[str, float]) -> None:
        """An input as the node understood it (NED samples of a sensor topic), re-encoded as the
        ROS 2 message of that topic (pressure, mocap/pose; other inputs are not recorded)."""
        if topic == "pressure" and "z" in samples:
            v = self.core.vehicle
            msg: dict[str, Any] = {
                "header": {"stamp": ros2msg.stamp_s(stamp), "frame_id": self._pressure_frame},
                "fluid_pressure": rc.pressure_from_depth(samples["z"], rho=v.water_density, g=v.gravity),
                "variance": 0.0}  # 0: unknown (sensor_msgs/FluidPressure); the node does not read it
        elif topic == "mocap/pose" and "z" in samples and "psi" in samples:
            c = ros2msg.odometry_content(samples)
            msg = {"header": {"stamp": ros2msg.stamp_s(stamp), "frame_id": rc.WORLD_FRAME},
                   "pose": {"position": dict(zip("xyz", c["position"])),
                            "orientation": dict(zip("xyzw", c["orientation"]))}}
        else:
            return
        with self._lock:
            if not self.closed:
                self._add(topic, stamp, msg)

    def output(self, out: NodeOutput) -> None:
        """One control step: odometry, /tf, wrench, PWM (ROS 2) and rovlab's JSON messages."""
        ns = _ns(out.stamp)
        c = rc.odometry_content(out)
        tf = ros2msg.body_transform(ns, c)  # None for a non-finite pose (tf refuses NaN)
        messages = [("odometry", ros2msg.odometry(ns, c, frame=rc.WORLD_FRAME, child=rc.BODY_FRAME)),
                    *([("/tf", ros2msg.tf_message([tf]))] if tf is not None else []),
                    ("wrench", ros2msg.wrench_stamped(ns, out.tau, frame=rc.BODY_FRAME)),
                    ("thrusters/pwm_us", ros2msg.pwm_array(out.thrusters, out.pwm_us))]
        with self._lock:
            if self.closed:
                return
            for topic, msg in messages:
                self._add(topic, out.stamp, msg)
            for topic, _t, jmsg in out.messages():
                self._series.write(topic, out.stamp, jmsg)

    def close(self) -> None:
        """Finish both files (summary, index); safe to call twice."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._bag.finish()
            finally:
                self._fh.close()
                self._series.close()
