"""A PD depth-and-heading law with the net buoyancy fed forward: the controller of rovlab's plugin
example.

Z = kp_z (z_ref - z) - kd_z w + (B - W),  N = kp_psi wrap(psi_ref - psi) - kd_psi r

with the vehicle's net buoyancy B - W (positive: it floats, so the law pushes down) from its
vehicle file. The gains are the [pd] table of the design file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

# the estimate the loop hands a controller is in rovlab's TRUTH layout, the reference in REFERENCE's:
# their entries by name
from rovlab.core.components import (
    NAV_PSI,
    NAV_R,
    NAV_W,
    NAV_Z,
    REF_PSI,
    REF_Z,
    ComponentInfo,
    ControllerSpec,
    register_component,
    register_controller,
)


@dataclass(frozen=True)
class PDConfig:
    """The [pd] table of a design file (SI units, radians)."""

    kp_z: float = 40.0  # N/m
    kd_z: float = 40.0  # N s/m
    kp_psi: float = 1.0  # N m/rad
    kd_psi: float = 0.8  # N m s/rad
    source: str = "rovlab_example_plugin defaults, for uDrone (about 1.5 rad/s in heave, 2 rad/s in yaw)"


class PD(NamedTuple):
    kp_z: float
    kd_z: float
    kp_psi: float
    kd_psi: float
    net_buoyancy: float  # B - W [N]
    state: np.ndarray  # (0) a PD law keeps no state


@njit(cache=False)
def _step(ctrl, t, nav, ref, tau):
    e_psi = ref[REF_PSI] - nav[NAV_PSI]
    e_psi = e_psi - 2.0 * math.pi * math.floor((e_psi + math.pi) / (2.0 * math.pi))
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = ctrl.kp_z * (ref[REF_Z] - nav[NAV_Z]) - ctrl.kd_z * nav[NAV_W] + ctrl.net_buoyancy
    tau[3] = ctrl.kp_psi * e_psi - ctrl.kd_psi * nav[NAV_R]


register_controller(PD, state=("state",), step=_step)


def build(vehicle, config) -> ControllerSpec:
    c: PDConfig = config.table("pd")
    kernel = PD(c.kp_z, c.kd_z, c.kp_psi, c.kd_psi, float(vehicle.buoyancy - vehicle.weight), np.zeros(0))
    return ControllerSpec(kernel=kernel, needs=("z", "psi", "w", "r"), references=("z", "psi"), outputs=("Z", "N"))


def read_table(t) -> PDConfig:
    """The [pd] table, read with rovlab's TableReader (its checks and messages)."""
    base = PDConfig()
    source = t.string("source")
    values = [t.number(k, getattr(base, k), nonnegative=True, hi=1e4, what=unit)
              for k, unit in (("kp_z", "N/m"), ("kd_z", "N s/m"), ("kp_psi", "N m/rad"), ("kd_psi", "N m s/rad"))]
    t.finish()
    return PDConfig(*values, source=source)


register_component(ComponentInfo(
    "pd", "controller", build, description="PD depth and heading with net buoyancy fed forward (plugin example)",
    parse_table=read_table, default_table=PDConfig))
