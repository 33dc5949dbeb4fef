"""ROS 2 message definitions and builders for logs that ROS 2 tools and Foxglove open as they are.

The definitions are the standard interfaces (nav_msgs/msg/Odometry, geometry_msgs/msg/WrenchStamped
with their dependencies) in the concatenated ``ros2msg`` text form MCAP stores as a schema; the
messages are plain dicts that mcap-ros2-support encodes as CDR.

Frames: rovlab logs stay in its own conventions, named as REP-105 allows for them: the world frame
``map_ned`` (north-east-down) and the body frame ``base_link_frd`` (forward-right-down). Nothing is
converted here; a ROS bridge that publishes ENU/FLU converts at its edge.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

WORLD_FRAME = "map_ned"
BODY_FRAME = "base_link_frd"

_SEP = "=" * 80 + "\n"
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
_VECTOR3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"

ODOMETRY = "nav_msgs/msg/Odometry"
ODOMETRY_DEF = (
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n"
    + _SEP + _HEADER + _SEP + _TIME
    + _SEP + "MSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n"
    + _SEP + "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n"
    + _SEP + "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
    + _SEP + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
    + _SEP + "MSG: geometry_msgs/TwistWithCovariance\nTwist twist\nfloat64[36] covariance\n"
    + _SEP + "MSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular\n"
    + _SEP + _VECTOR3
)

WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
WRENCH_STAMPED_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n"
    + _SEP + _HEADER + _SEP + _TIME
    + _SEP + "MSG: geometry_msgs/Wrench\nVector3 force\nVector3 torque\n"
    + _SEP + _VECTOR3
)

FLUID_PRESSURE = "sensor_msgs/msg/FluidPressure"
FLUID_PRESSURE_DEF = "std_msgs/Header header\nfloat64 fluid_pressure\nfloat64 variance\n" + _SEP + _HEADER + _SEP + _TIME

POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_STAMPED_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Pose pose\n"
    + _SEP + _HEADER + _SEP + _TIME
    + _SEP + "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n"
    + _SEP + "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
    + _SEP + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
)

FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
FLOAT64_MULTI_ARRAY_DEF = (
    "std_msgs/MultiArrayLayout layout\nfloat64[] data\n"
    + _SEP + "MSG: std_msgs/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\nuint32 data_offset\n"
    + _SEP + "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"
)

DEFINITIONS = {ODOMETRY: ODOMETRY_DEF, WRENCH_STAMPED: WRENCH_STAMPED_DEF, FLUID_PRESSURE: FLUID_PRESSURE_DEF,
               POSE_STAMPED: POSE_STAMPED_DEF, FLOAT64_MULTI_ARRAY: FLOAT64_MULTI_ARRAY_DEF}


def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def _num(v: Any, default: float = 0.0) -> float:
    v = float(v) if v is not None else math.nan
    return v if math.isfinite(v) else default


def odometry(t_ns: int, state: Mapping[str, float], variance: Mapping[str, float] | None = None) -> dict[str, Any]:
    """nav_msgs/Odometry of a rovlab state (any of x, y, z, psi in map_ned; u, v, w, r in
    base_link_frd); the covariance diagonal from ``variance`` (0 where not estimated)."""
    var = variance or {}
    psi = _num(state.get("psi"))
    pose_cov = [0.0] * 36
    twist_cov = [0.0] * 36
    for i, key in enumerate(("x", "y", "z", None, None, "psi")):
        if key is not None:
            pose_cov[7 * i] = max(_num(var.get(key)), 0.0)
    for i, key in enumerate(("u", "v", "w", None, None, "r")):
        if key is not None:
            twist_cov[7 * i] = max(_num(var.get(key)), 0.0)
    return {
        "header": {"stamp": stamp(t_ns), "frame_id": WORLD_FRAME},
        "child_frame_id": BODY_FRAME,
        "pose": {"pose": {"position": {"x": _num(state.get("x")), "y": _num(state.get("y")),
                                       "z": _num(state.get("z"))},
                          # yaw psi about the NED z axis (down), roll = pitch = 0
                          "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(psi / 2), "w": math.cos(psi / 2)}},
                 "covariance": pose_cov},
        "twist": {"twist": {"linear": {"x": _num(state.get("u")), "y": _num(state.get("v")), "z": _num(state.get("w"))},
                            "angular": {"x": 0.0, "y": 0.0, "z": _num(state.get("r"))}},
                  "covariance": twist_cov},
    }


def wrench_stamped(t_ns: int, tau: Mapping[str, float]) -> dict[str, Any]:
    """geometry_msgs/WrenchStamped of a body wrench {X, Y, Z, N} (missing entries 0)."""
    return {"header": {"stamp": stamp(t_ns), "frame_id": BODY_FRAME},
            "wrench": {"force": {"x": _num(tau.get("X")), "y": _num(tau.get("Y")), "z": _num(tau.get("Z"))},
                       "torque": {"x": 0.0, "y": 0.0, "z": _num(tau.get("N"))}}}
