"""The ROS 2 messages in rovlab's files and on its nodes' topics: definitions and contents.

Definitions: the standard interfaces rovlab writes (nav_msgs/msg/Odometry,
geometry_msgs/msg/WrenchStamped, tf2_msgs/msg/TFMessage ...) in the concatenated ``ros2msg`` text
that MCAP stores as a channel's schema (the form ``ros2 bag record`` writes), built from the field
lists below by :func:`definition`. Contents: plain dicts with the messages' fields, which
``mcap_ros2.writer.Writer`` encodes as CDR; the vehicle nodes copy the same contents into rclpy or
rospy message objects (rovlab.interfaces.node.ros_common).

Frames and units (REP 103, REP 105): the world frame ``map`` is east-north-up, the body frame
``base_link`` forward-left-up, SI units and radians; rovlab's NED/FRD values are converted here
(rovlab.core.frames) and nowhere else in the files.

Covariance of an estimate (:func:`odometry_covariances`, the one place it is filled): the
estimator's covariance where it estimates a quantity; every other entry of the diagonal -- a
quantity the estimator does not estimate (x and y for a depth-and-heading filter, roll and pitch,
which rovlab's 4-DOF model holds at 0) -- carries :data:`UNESTIMATED_VARIANCE`, with zeros off the
diagonal. A large variance is a valid covariance that says "no information" to whatever fuses or
draws it; 0 would claim the opposite (or, read as REP 145 and sensor_msgs read it, "covariance
unknown" for the whole matrix), and REP 145's -1 marks a whole 3x3 block of an Imu as absent, not
one axis of a 6x6 pose. The truth of a simulation is exact and carries a zero covariance.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from rovlab.core import frames

WORLD_FRAME = "map"
BODY_FRAME = "base_link"
UNESTIMATED_VARIANCE = 1e6  # [m^2, rad^2, (m/s)^2, (rad/s)^2] on the diagonal for what is not estimated
Vector = Sequence[float] | np.ndarray

# --------------------------------------------------------------------------------------------
# Definitions: each message's own fields, as in its .msg file (without comments); the nested
# messages' definitions are appended by definition(), as ROS 2's MCAP writer does
# --------------------------------------------------------------------------------------------

_FIELDS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
    "geometry_msgs/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
    "nav_msgs/Odometry": ("std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
                          "geometry_msgs/TwistWithCovariance twist\n"),
    "sensor_msgs/FluidPressure": "std_msgs/Header header\nfloat64 fluid_pressure\nfloat64 variance\n",
    "std_msgs/MultiArrayDimension": "string label\nuint32 size\nuint32 stride\n",
    "std_msgs/MultiArrayLayout": "MultiArrayDimension[] dim\nuint32 data_offset\n",
    "std_msgs/Float64MultiArray": "MultiArrayLayout layout\nfloat64[] data\n",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
}
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
               "int64", "uint64", "string", "wstring"}
_SEP = "=" * 80 + "\n"


def _nested(name: str) -> list[str]:
    """The message types a message's fields refer to, in the order of the fields (package-relative
    names resolved against the message's own package)."""
    package = name.split("/")[0]
    out = []
    for line in _FIELDS[name].splitlines():
        typ = line.split()[0].split("[")[0]
        if typ in _PRIMITIVES:
            continue
        out.append(typ if "/" in typ else f"{package}/{typ}")
    return out


def definition(datatype: str) -> str:
    """The ``ros2msg`` schema text of a message type ("nav_msgs/msg/Odometry"): its fields, then
    each message it uses once, depth first, after a line of 80 '=' and ``MSG: package/Name``."""
    name = datatype.replace("/msg/", "/")
    seen: list[str] = []

    def walk(n: str) -> None:
        for sub in _nested(n):
            if sub not in seen:
                seen.append(sub)
                walk(sub)

    walk(name)
    return _FIELDS[name] + "".join(f"{_SEP}MSG: {sub}\n{_FIELDS[sub]}" for sub in seen)


ODOMETRY = "nav_msgs/msg/Odometry"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
FLUID_PRESSURE = "sensor_msgs/msg/FluidPressure"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
DEFINITIONS = {t: definition(t) for t in (ODOMETRY, WRENCH_STAMPED, FLUID_PRESSURE, POSE_STAMPED,
                                          FLOAT64_MULTI_ARRAY, TF_MESSAGE)}

# --------------------------------------------------------------------------------------------
# Contents
# --------------------------------------------------------------------------------------------

# where each TRUTH quantity sits in Odometry: (block, index) with block 0 = pose (x y z rx ry rz, NED
# world axes before conversion), 1 = twist (vx vy vz wx wy wz, FRD body axes before conversion)
_ODOM_SLOT = {"x": (0, 0), "y": (0, 1), "z": (0, 2), "psi": (0, 5), "u": (1, 0), "v": (1, 1), "w": (1, 2),
              "r": (1, 5)}


def stamp(t_ns: int) -> dict[str, int]:
    """builtin_interfaces/Time of a time in integer nanoseconds."""
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    return {"sec": sec, "nanosec": nanosec}


def stamp_s(t_s: float) -> dict[str, int]:
    """builtin_interfaces/Time of a time in seconds (rounded to the nanosecond)."""
    return stamp(int(round(t_s * 1e9)))


def odometry_covariances(P: np.ndarray | None, states: Sequence[str]) -> tuple[list[float], list[float]]:
    """The pose covariance (map, ENU) and twist covariance (base_link, FLU) of nav_msgs/Odometry,
    row-major lists of 36, from an estimate's covariance ``P`` over ``states`` (TRUTH names: x, y,
    z, psi, u, v, w, r; others, such as biases, are not in Odometry). Every diagonal entry of a
    quantity not in ``states`` is :data:`UNESTIMATED_VARIANCE`. ``P`` None: an exact state (a
    simulation's truth, a set-point): all zeros."""
    if P is None:
        return [0.0] * 36, [0.0] * 36
    blocks = [np.diag(np.full(6, UNESTIMATED_VARIANCE)), np.diag(np.full(6, UNESTIMATED_VARIANCE))]
    slots = [(_ODOM_SLOT.get(q), i) for i, q in enumerate(states)]
    for a, i in slots:
        for b, j in slots:
            if a is not None and b is not None and a[0] == b[0]:
                blocks[a[0]][a[1], b[1]] = P[i, j]
    pose = frames.pose_covariance_to_enu(blocks[0])
    twist = frames.twist_covariance_to_flu(blocks[1])
    return pose.ravel().tolist(), twist.ravel().tolist()


def odometry_content(nav: Mapping[str, float], P: np.ndarray | None = None,
                     states: Sequence[str] = ()) -> dict[str, Any]:
    """Position (ENU), orientation quaternion (base_link in ENU), linear and angular velocity
    (FLU) and the two covariances (:func:`odometry_covariances`) of a state in rovlab's NED/FRD
    (``nav``: TRUTH names -> values; a missing quantity is 0)."""
    pos = frames.ned_to_enu([nav.get("x", 0.0), nav.get("y", 0.0), nav.get("z", 0.0)])
    quat = frames.heading_quaternion(nav.get("psi", 0.0))
    lin = frames.frd_to_flu([nav.get("u", 0.0), nav.get("v", 0.0), nav.get("w", 0.0)])
    ang = frames.frd_to_flu([0.0, 0.0, nav.get("r", 0.0)])
    pose_cov, twist_cov = odometry_covariances(P, states)
    return {"position": pos.tolist(), "orientation": list(quat), "linear": lin.tolist(), "angular": ang.tolist(),
            "pose_covariance": pose_cov, "twist_covariance": twist_cov}


def odometry(t_ns: int, content: Mapping[str, Any], *, frame: str = WORLD_FRAME,
             child: str = BODY_FRAME) -> dict[str, Any]:
    """nav_msgs/Odometry of an :func:`odometry_content`."""
    return {
        "header": {"stamp": stamp(t_ns), "frame_id": frame},
        "child_frame_id": child,
        "pose": {"pose": {"position": dict(zip("xyz", content["position"])),
                          "orientation": dict(zip("xyzw", content["orientation"]))},
                 "covariance": list(content["pose_covariance"])},
        "twist": {"twist": {"linear": dict(zip("xyz", content["linear"])),
                            "angular": dict(zip("xyz", content["angular"]))},
                  "covariance": list(content["twist_covariance"])},
    }


def wrench_flu(tau: Vector) -> tuple[list[float], list[float]]:
    """Force and torque in base_link (FLU) of rovlab's wrench [X, Y, Z, N] (FRD)."""
    force = frames.frd_to_flu([tau[0], tau[1], tau[2]])
    torque = frames.frd_to_flu([0.0, 0.0, tau[3]])
    return force.tolist(), torque.tolist()


def wrench_stamped(t_ns: int, tau: Vector, *, frame: str = BODY_FRAME) -> dict[str, Any]:
    """geometry_msgs/WrenchStamped of rovlab's wrench [X, Y, Z, N] (FRD), in base_link (FLU)."""
    force, torque = wrench_flu(tau)
    return {"header": {"stamp": stamp(t_ns), "frame_id": frame},
            "wrench": {"force": dict(zip("xyz", force)), "torque": dict(zip("xyz", torque))}}


def transform(t_ns: int, parent: str, child: str, translation: Vector,
              rotation: Vector = (0.0, 0.0, 0.0, 1.0)) -> dict[str, Any]:
    """geometry_msgs/TransformStamped: the pose of ``child`` in ``parent`` (ROS axes; rotation
    as a quaternion x, y, z, w)."""
    return {"header": {"stamp": stamp(t_ns), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": dict(zip("xyz", (float(v) for v in translation))),
                          "rotation": dict(zip("xyzw", (float(v) for v in rotation)))}}


def body_transform(t_ns: int, content: Mapping[str, Any], *, frame: str = WORLD_FRAME,
                   child: str = BODY_FRAME) -> dict[str, Any] | None:
    """The transform ``frame`` -> ``child`` of an :func:`odometry_content` (what /tf carries for
    a viewer); None when the pose is not finite (tf refuses NaN)."""
    values = [*content["position"], *content["orientation"]]
    if not all(math.isfinite(v) for v in values):
        return None
    return transform(t_ns, frame, child, content["position"], content["orientation"])


def sensor_transforms(t_ns: int, sensors: Iterable[tuple[str, Vector]], *,
                      body: str = BODY_FRAME) -> list[dict[str, Any]]:
    """The fixed transforms base_link -> each sensor's frame (named after the sensor) from its
    lever arm in rovlab's body frame (FRD, from the vehicle file), for /tf_static."""
    return [transform(t_ns, body, name, frames.frd_to_flu(np.asarray(position, dtype=float))) for name, position in sensors]


def tf_message(transforms: Iterable[dict[str, Any] | None]) -> dict[str, Any]:
    """tf2_msgs/TFMessage of the transforms given (None entries left out)."""
    return {"transforms": [t for t in transforms if t is not None]}


def pwm_array(thrusters: Sequence[str], pwm_us: Vector) -> dict[str, Any]:
    """std_msgs/Float64MultiArray: one PWM [us] per thruster, labelled with the thrusters' names."""
    n = len(thrusters)
    return {"layout": {"dim": [{"label": ",".join(thrusters), "size": n, "stride": n}], "data_offset": 0},
            "data": [float(v) for v in pwm_us]}
