"""rovlab's NED world / FRD body against ROS's ENU world / FLU body (REP-103, REP-105).

The one place rovlab changes frames, for the vehicle nodes and for the ROS 2 messages of its
files (rovlab.io.ros2msg): inside rovlab everything is NED (x north, y east,
z down; heading psi from north towards east) and FRD (x forward, y starboard, z down); on ROS
topics and in ROS bags the world frames (``map``, ``odom``) are ENU (x east, y north, z up; yaw from east towards
north) and the body frame ``base_link`` is FLU (x forward, y left, z up).

Both changes are a fixed signed permutation, its own inverse:

* world NED <-> ENU: (x, y, z) -> (y, x, -z); a small rotation vector maps the same way; the
  heading becomes yaw_ENU = pi/2 - psi_NED (and back);
* body FRD <-> FLU: (x, y, z) -> (x, -y, -z) (velocities, rates, forces, moments).

The orientation of FRD in NED, the yaw psi, is the quaternion of FLU in ENU with yaw pi/2 - psi
(roll and pitch zero in rovlab's 4-DOF model). A covariance C transforms as J C J^T, J the
block-diagonal signed permutation above (applied by indexing, so a NaN stays where it is). Plain numpy; no ROS import.
"""

from __future__ import annotations

import math

import numpy as np

WORLD = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED <-> ENU (involution)
BODY = np.diag([1.0, -1.0, -1.0])  # FRD <-> FLU (involution)
POSE_J = np.block([[WORLD, np.zeros((3, 3))], [np.zeros((3, 3)), WORLD]])  # pose covariance (x y z, rot x y z)
TWIST_J = np.block([[BODY, np.zeros((3, 3))], [np.zeros((3, 3)), BODY]])  # twist covariance (v, omega) in the body


def _signed_permutation(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index, sign) with J @ v == sign * v[index]: applied by indexing, a NaN (a quantity without
    a value) stays in its own entry instead of spreading through a matrix product."""
    return np.argmax(np.abs(J), axis=1), J[np.arange(len(J)), np.argmax(np.abs(J), axis=1)]


_WORLD, _BODY, _POSE, _TWIST = (_signed_permutation(J) for J in (WORLD, BODY, POSE_J, TWIST_J))


def _vector(perm: tuple[np.ndarray, np.ndarray], v: np.ndarray | list[float] | tuple[float, ...]) -> np.ndarray:
    index, sign = perm
    return sign * np.asarray(v, dtype=float)[index]


def _matrix(perm: tuple[np.ndarray, np.ndarray], C: np.ndarray) -> np.ndarray:
    """J C J^T for the signed permutation J."""
    index, sign = perm
    return np.outer(sign, sign) * np.asarray(C, dtype=float)[np.ix_(index, index)]


def _wrap(a: float) -> float:
    return math.remainder(a, 2.0 * math.pi)


def ned_to_enu(p: np.ndarray | list[float] | tuple[float, ...]) -> np.ndarray:
    """A world vector (position, velocity, small rotation) from NED to ENU."""
    return _vector(_WORLD, p)


enu_to_ned = ned_to_enu  # the same permutation both ways


def frd_to_flu(v: np.ndarray | list[float] | tuple[float, ...]) -> np.ndarray:
    """A body vector (velocity, rate, force, moment) from FRD to FLU."""
    return _vector(_BODY, v)


flu_to_frd = frd_to_flu


def heading_to_yaw(psi: float) -> float:
    """NED heading psi (from north, towards east) -> ENU yaw (from east, towards north), in (-pi, pi]."""
    return _wrap(0.5 * math.pi - psi)


yaw_to_heading = heading_to_yaw  # psi = pi/2 - yaw as well


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by yaw about the z axis."""
    return (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


def quaternion_yaw(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rotation about z, ZYX Euler angles) of a quaternion; ValueError if it is not a
    finite, non-zero quaternion."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(n) and n > 1e-9):
        raise ValueError(f"orientation ({x}, {y}, {z}, {w}) is not a valid quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def heading_quaternion(psi: float) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of base_link (FLU) in an ENU world for the NED heading psi."""
    return yaw_quaternion(heading_to_yaw(psi))


def quaternion_heading(q: tuple[float, float, float, float] | list[float]) -> float:
    """NED heading psi of a base_link (FLU) orientation in an ENU world (x, y, z, w)."""
    return yaw_to_heading(quaternion_yaw(*q))


def pose_covariance_to_enu(C_ned: np.ndarray) -> np.ndarray:
    """6x6 pose covariance (x, y, z, rotation about x, y, z) from NED world axes to ENU."""
    return _matrix(_POSE, C_ned)


pose_covariance_to_ned = pose_covariance_to_enu


def twist_covariance_to_flu(C_frd: np.ndarray) -> np.ndarray:
    """6x6 twist covariance (linear, angular) from FRD body axes to FLU."""
    return _matrix(_TWIST, C_frd)


twist_covariance_to_frd = twist_covariance_to_flu
