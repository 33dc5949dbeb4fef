"""Linear depth-and-heading models for the observer and the controller (Sandøy 2016, secs. 5.1-5.2).

Decoupled heave and yaw around low speed:

    z_dot = w,  psi_dot = r
    M_w w_dot = Z_w w + Z + b_w,   M_w = m - Z_wdot
    M_r r_dot = N_r r + N + b_r,   M_r = I_zz - N_rdot
    b_dot = -T^-1 b + w_b            (observer model only)

State order: observer x = [z, psi, w, r, b_w, b_r]; controller x = [z, psi, w, r];
input u = [Z, N].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovlab.params.vehicle import Vehicle


@dataclass(frozen=True)
class HeaveYawParams:
    """The four numbers the decoupled depth-and-heading model needs (SI, SNAME signs)."""

    M_w: float  # m - Z_wdot [kg]
    M_r: float  # I_zz - N_rdot [kg m^2]
    Z_w: float  # linear heave damping (<= 0) [N s/m]
    N_r: float  # linear yaw damping (<= 0) [N m s/rad]

    @classmethod
    def from_vehicle(cls, vehicle: Vehicle) -> HeaveYawParams:
        return cls(
            M_w=vehicle.mass - float(vehicle.added_mass[2]),
            M_r=vehicle.I_zz - float(vehicle.added_mass[3]),
            Z_w=float(vehicle.damping_linear[2]),
            N_r=float(vehicle.damping_linear[3]),
        )

    @classmethod
    def from_values(cls, *, m: float, I_zz: float, Z_wdot: float, N_rdot: float, Z_w: float,
                    N_r: float) -> HeaveYawParams:
        return cls(M_w=m - Z_wdot, M_r=I_zz - N_rdot, Z_w=Z_w, N_r=N_r)


def control_model(p: HeaveYawParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_c (4x4), B_c (4x2), C_c (2x4) of the depth-and-heading control model."""
    Minv = np.diag([1.0 / p.M_w, 1.0 / p.M_r])
    DL = -np.diag([p.Z_w, p.N_r])
    Z2, I2 = np.zeros((2, 2)), np.eye(2)
    A = np.block([[Z2, I2], [Z2, -Minv @ DL]])
    B = np.vstack([Z2, Minv])
    C = np.hstack([I2, Z2])
    return A, B, C


def observer_model(p: HeaveYawParams, T_w: float, T_r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A (6x6), B (6x2), E (6x6) of the observer model with Gauss-Markov bias states.

    E maps the noise vector [w_z, w_psi, w_w, w_r, w_bw, w_br]: process noise on the
    velocities enters through M^-1, bias noise directly (Sandøy 2016, sec. 5.1).
    """
    if not (T_w > 0 and T_r > 0):
        raise ValueError(f"bias time constants must be positive, got T_w={T_w}, T_r={T_r}")
    Minv = np.diag([1.0 / p.M_w, 1.0 / p.M_r])
    DL = -np.diag([p.Z_w, p.N_r])
    Z2, I2 = np.zeros((2, 2)), np.eye(2)
    A = np.block([
        [Z2, I2, Z2],
        [Z2, -Minv @ DL, Minv],
        [Z2, Z2, -np.diag([1.0 / T_w, 1.0 / T_r])],
    ])
    B = np.vstack([Z2, Minv, Z2])
    E = np.block([[Z2, Z2, Z2], [Z2, Minv, Z2], [Z2, Z2, I2]])
    return A, B, E
