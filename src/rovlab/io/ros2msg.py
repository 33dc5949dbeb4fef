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
import struct
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


def _odometry_values(state: Mapping[str, float], variance: Mapping[str, float] | None) -> list[float]:
    """The 85 float64 of nav_msgs/Odometry after its header, in message order: position (3),
    orientation (4), pose covariance (36), linear (3) and angular (3) velocity, twist covariance (36)."""
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
    # yaw psi about the NED z axis (down), roll = pitch = 0
    return [_num(state.get("x")), _num(state.get("y")), _num(state.get("z")),
            0.0, 0.0, math.sin(psi / 2), math.cos(psi / 2), *pose_cov,
            _num(state.get("u")), _num(state.get("v")), _num(state.get("w")), 0.0, 0.0, _num(state.get("r")),
            *twist_cov]


def odometry(t_ns: int, state: Mapping[str, float], variance: Mapping[str, float] | None = None) -> dict[str, Any]:
    """nav_msgs/Odometry of a rovlab state (any of x, y, z, psi in map_ned; u, v, w, r in
    base_link_frd); the covariance diagonal from ``variance`` (0 where not estimated)."""
    v = _odometry_values(state, variance)
    return {
        "header": {"stamp": stamp(t_ns), "frame_id": WORLD_FRAME},
        "child_frame_id": BODY_FRAME,
        "pose": {"pose": {"position": dict(zip("xyz", v[0:3])), "orientation": dict(zip("xyzw", v[3:7]))},
                 "covariance": v[7:43]},
        "twist": {"twist": {"linear": dict(zip("xyz", v[43:46])), "angular": dict(zip("xyz", v[46:49]))},
                  "covariance": v[49:85]},
    }


def _wrench_values(tau: Mapping[str, float]) -> list[float]:
    """force (3) and torque (3) of geometry_msgs/Wrench from a body wrench {X, Y, Z, N}."""
    return [_num(tau.get("X")), _num(tau.get("Y")), _num(tau.get("Z")), 0.0, 0.0, _num(tau.get("N"))]


def wrench_stamped(t_ns: int, tau: Mapping[str, float]) -> dict[str, Any]:
    """geometry_msgs/WrenchStamped of a body wrench {X, Y, Z, N} (missing entries 0)."""
    v = _wrench_values(tau)
    return {"header": {"stamp": stamp(t_ns), "frame_id": BODY_FRAME},
            "wrench": {"force": dict(zip("xyz", v[0:3])), "torque": dict(zip("xyz", v[3:6]))}}


# --------------------------------------------------------------------------------------------
# CDR: the two messages of a simulation log encoded directly (OMG XCDR1 little endian, what ROS 2
# puts on the wire and MCAP stores; DDS-XTypes 1.3, sec. 7.4.3.5), checked byte for byte against
# mcap-ros2-support's general encoder in the tests, at ~1/30 of its cost. Alignment of a
# primitive is its size, counted from the end of the 4-byte encapsulation header.
# --------------------------------------------------------------------------------------------

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, options 0


def _cdr_string(s: str, offset: int) -> bytes:
    """A CDR string at ``offset``: padding to 4, uint32 length with the terminating NUL, bytes, NUL."""
    raw = s.encode() + b"\x00"
    return b"\x00" * (-offset % 4) + struct.pack("<I", len(raw)) + raw


class _Stamped:
    """Encoder of a message [Header header, <strings>, <n float64>] with constant strings."""

    def __init__(self, strings: tuple[str, ...], n_doubles: int) -> None:
        body = b""
        offset = 8  # after the stamp (int32 sec, uint32 nanosec)
        for s in strings:
            part = _cdr_string(s, offset)
            body += part
            offset += len(part)
        self._strings = body + b"\x00" * (-offset % 8)
        self._doubles = struct.Struct(f"<{n_doubles}d")
        self._stamp = struct.Struct("<iI")

    def __call__(self, t_ns: int, values: list[float]) -> bytes:
        sec, nanosec = divmod(int(t_ns), 1_000_000_000)
        return _ENCAPSULATION + self._stamp.pack(sec, nanosec) + self._strings + self._doubles.pack(*values)


_ODOMETRY_CDR = _Stamped((WORLD_FRAME, BODY_FRAME), 85)
_WRENCH_CDR = _Stamped((BODY_FRAME,), 6)


def odometry_cdr(t_ns: int, state: Mapping[str, float], variance: Mapping[str, float] | None = None) -> bytes:
    """:func:`odometry` encoded as CDR (the bytes of a ROS 2 nav_msgs/Odometry message)."""
    return _ODOMETRY_CDR(t_ns, _odometry_values(state, variance))


def wrench_stamped_cdr(t_ns: int, tau: Mapping[str, float]) -> bytes:
    """:func:`wrench_stamped` encoded as CDR (geometry_msgs/WrenchStamped)."""
    return _WRENCH_CDR(t_ns, _wrench_values(tau))
