"""The SI unit of each named quantity rovlab estimates, measures or commands (docs/conventions.md):
one table for every place that prints or writes a number with its unit (``rovlab design``'s
measurement variances, ``rovlab identify noise``, metrics.json's units, figure labels).

Positions in m, angles in rad, velocities in m/s and rad/s, forces in N and moments in N m; the
world frame is NED and the body frame FRD, with SNAME's names (x, y, z, psi; u, v, w, r; X, Y, Z, N).
"""

from __future__ import annotations

UNITS: dict[str, str] = {
    # pose (world, NED) and body velocities
    "x": "m", "y": "m", "z": "m", "phi": "rad", "theta": "rad", "psi": "rad",
    "u": "m/s", "v": "m/s", "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s",
    # force/moment biases: 4-DOF (b_X ... b_N) and depth-and-heading (b_w, b_r) estimators
    "b_X": "N", "b_Y": "N", "b_Z": "N", "b_N": "N m", "b_w": "N", "b_r": "N m",
    # the wrench
    "X": "N", "Y": "N", "Z": "N", "K": "N m", "M": "N m", "N": "N m",
}


def unit(quantity: str, default: str = "") -> str:
    """The unit of a quantity by its name (``"r"`` -> ``"rad/s"``); ``default`` when unknown."""
    return UNITS.get(quantity, default)


def squared(u: str) -> str:
    """The unit of a variance of a quantity in ``u``: ``m`` -> ``m^2``, ``rad/s`` -> ``rad^2/s^2``,
    ``N m`` -> ``N^2 m^2``."""
    if not u:
        return ""
    num, _, den = u.partition("/")
    num = " ".join(f"{part}^2" for part in num.split())
    return f"{num}/{den}^2" if den else num
