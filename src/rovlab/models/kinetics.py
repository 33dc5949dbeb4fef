"""The 4-DOF process model of SPEC section 4 (Fossen 2011, ch. 6-7; SNAME notation).

    eta_dot = J(psi) nu
    (M_RB + M_A) nu_dot + C_RB(nu) nu + C_A(nu) nu + D_L nu + D_NL(nu) nu + g = tau + b

eta = [x, y, z, psi] (NED), nu = [u, v, w, r] (body), tau = [X, Y, Z, N]. Roll and pitch are
assumed zero. The matrix builders below are plain numpy for reading and testing; the per-step
paths (``nu_dot``, ``plant_rhs``, ``rk4_step``) run on a packed parameter vector (see
:func:`pack`) in numba-compiled code.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rovlab.params.vehicle import Vehicle

# Layout of the packed parameter vector used by the compiled kernels.
P_MINV = 0  # 16 entries, (M_RB + M_A)^-1 row-major
P_M = 16  # m
P_XG = 17  # x_g
P_YG = 18  # y_g
P_XUDOT = 19  # X_udot
P_YVDOT = 20  # Y_vdot
P_LIN = 21  # 4 entries: X_u, Y_v, Z_w, N_r
P_QUAD = 25  # 4 entries: X_|u|u, ...
P_CUB = 29  # 4 entries: X_uuu, ...
P_GZ = 33  # restoring force in the heave row, B - W (left-hand side)
P_SIZE = 34


def J(psi: float) -> np.ndarray:
    """4-DOF kinematic transform J(psi) = blockdiag(R_z(psi), 1) mapping nu to eta_dot."""
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def M_RB(vehicle: Vehicle) -> np.ndarray:
    """Rigid-body inertia matrix (4-DOF, about VO)."""
    m = vehicle.mass
    x_g, y_g = vehicle.r_g[0], vehicle.r_g[1]
    return np.array([
        [m, 0.0, 0.0, -m * y_g],
        [0.0, m, 0.0, m * x_g],
        [0.0, 0.0, m, 0.0],
        [-m * y_g, m * x_g, 0.0, vehicle.I_zz],
    ])


def M_A(vehicle: Vehicle) -> np.ndarray:
    """Added-mass matrix -diag(X_udot, Y_vdot, Z_wdot, N_rdot) (positive definite)."""
    return -np.diag(vehicle.added_mass)


def mass_matrix(vehicle: Vehicle) -> np.ndarray:
    return M_RB(vehicle) + M_A(vehicle)


def C_RB(vehicle: Vehicle, nu: np.ndarray) -> np.ndarray:
    """Rigid-body Coriolis-centripetal matrix (skew-symmetric)."""
    m = vehicle.mass
    x_g, y_g = vehicle.r_g[0], vehicle.r_g[1]
    u, v, _, r = nu
    a = m * (v + x_g * r)
    c = m * (u - y_g * r)
    return np.array([[0.0, 0.0, 0.0, -a], [0.0, 0.0, 0.0, c], [0.0, 0.0, 0.0, 0.0], [a, -c, 0.0, 0.0]])


def C_A(vehicle: Vehicle, nu: np.ndarray) -> np.ndarray:
    """Hydrodynamic Coriolis-centripetal matrix (skew-symmetric)."""
    X_udot, Y_vdot = vehicle.added_mass[0], vehicle.added_mass[1]
    u, v = nu[0], nu[1]
    return np.array([
        [0.0, 0.0, 0.0, Y_vdot * v],
        [0.0, 0.0, 0.0, -X_udot * u],
        [0.0, 0.0, 0.0, 0.0],
        [-Y_vdot * v, X_udot * u, 0.0, 0.0],
    ])


def D_L(vehicle: Vehicle) -> np.ndarray:
    """Linear damping -diag(X_u, Y_v, Z_w, N_r) (positive semi-definite)."""
    return -np.diag(vehicle.damping_linear)


def D_NL(vehicle: Vehicle, nu: np.ndarray) -> np.ndarray:
    """Nonlinear damping -diag(X_|u|u |u| + X_uuu u^2, ...)."""
    nu = np.asarray(nu, dtype=float)
    return -np.diag(vehicle.damping_quadratic * np.abs(nu) + vehicle.damping_cubic * nu**2)


def restoring(vehicle: Vehicle) -> np.ndarray:
    """g for roll = pitch = 0: only heave, B - W (a positively buoyant vehicle rises)."""
    return np.array([0.0, 0.0, vehicle.buoyancy - vehicle.weight, 0.0])


def pack(vehicle: Vehicle) -> np.ndarray:
    """The packed parameter vector the compiled kernels take (layout: the P_* constants)."""
    p = np.zeros(P_SIZE)
    p[P_MINV:P_MINV + 16] = np.linalg.inv(mass_matrix(vehicle)).ravel()
    p[P_M] = vehicle.mass
    p[P_XG] = vehicle.r_g[0]
    p[P_YG] = vehicle.r_g[1]
    p[P_XUDOT] = vehicle.added_mass[0]
    p[P_YVDOT] = vehicle.added_mass[1]
    p[P_LIN:P_LIN + 4] = vehicle.damping_linear
    p[P_QUAD:P_QUAD + 4] = vehicle.damping_quadratic
    p[P_CUB:P_CUB + 4] = vehicle.damping_cubic
    p[P_GZ] = vehicle.buoyancy - vehicle.weight
    return p


@njit(cache=True, fastmath=False)
def nu_dot_packed(p: np.ndarray, nu: np.ndarray, tau: np.ndarray, b: np.ndarray) -> np.ndarray:
    """nu_dot = M^-1 (tau + b - C(nu) nu - D(nu) nu - g) on a packed parameter vector."""
    u, v, r = nu[0], nu[1], nu[3]
    m = p[P_M]
    a = m * (v + p[P_XG] * r)
    c = m * (u - p[P_YG] * r)
    # C(nu) nu = (C_RB + C_A) nu
    cx = (-a + p[P_YVDOT] * v) * r
    cy = (c - p[P_XUDOT] * u) * r
    cn = (a - p[P_YVDOT] * v) * u + (-c + p[P_XUDOT] * u) * v
    f = np.empty(4)
    f[0] = tau[0] + b[0] - cx
    f[1] = tau[1] + b[1] - cy
    f[2] = tau[2] + b[2] - p[P_GZ]
    f[3] = tau[3] + b[3] - cn
    for i in range(4):
        x = nu[i]
        f[i] += (p[P_LIN + i] + p[P_QUAD + i] * abs(x) + p[P_CUB + i] * x * x) * x
    out = np.empty(4)
    for i in range(4):
        out[i] = (p[P_MINV + 4 * i] * f[0] + p[P_MINV + 4 * i + 1] * f[1]
                  + p[P_MINV + 4 * i + 2] * f[2] + p[P_MINV + 4 * i + 3] * f[3])
    return out


@njit(cache=True)
def plant_rhs(p: np.ndarray, x: np.ndarray, tau: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Time derivative of the 8-state x = [eta; nu] with force tau and bias b held fixed."""
    out = np.empty(8)
    psi = x[3]
    c, s = np.cos(psi), np.sin(psi)
    out[0] = c * x[4] - s * x[5]
    out[1] = s * x[4] + c * x[5]
    out[2] = x[6]
    out[3] = x[7]
    out[4:] = nu_dot_packed(p, x[4:], tau, b)
    return out


@njit(cache=True)
def rk4_step(p: np.ndarray, x: np.ndarray, tau: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
    """One classical Runge-Kutta step of length h (tau and b constant over the step)."""
    k1 = plant_rhs(p, x, tau, b)
    k2 = plant_rhs(p, x + 0.5 * h * k1, tau, b)
    k3 = plant_rhs(p, x + 0.5 * h * k2, tau, b)
    k4 = plant_rhs(p, x + h * k3, tau, b)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def nu_dot(vehicle: Vehicle, eta: np.ndarray, nu: np.ndarray, tau: np.ndarray,
           b: np.ndarray | None = None) -> np.ndarray:
    """Body acceleration nu_dot for state (eta, nu), force tau and bias b (SPEC section 4).

    eta is accepted for the signature's sake: with roll = pitch = 0 the restoring term does
    not depend on the pose.
    """
    del eta
    bias = np.zeros(4) if b is None else np.asarray(b, dtype=float)
    return nu_dot_packed(_packed(vehicle), np.asarray(nu, dtype=float), np.asarray(tau, dtype=float), bias)


def eta_dot(eta: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """eta_dot = J(psi) nu."""
    return J(float(eta[3])) @ np.asarray(nu, dtype=float)


def nu_dot_reference(vehicle: Vehicle, nu: np.ndarray, tau: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """Same as :func:`nu_dot`, written with the matrices (used to test the kernel)."""
    nu = np.asarray(nu, dtype=float)
    bias = np.zeros(4) if b is None else np.asarray(b, dtype=float)
    lhs = (C_RB(vehicle, nu) + C_A(vehicle, nu) + D_L(vehicle) + D_NL(vehicle, nu)) @ nu + restoring(vehicle)
    return np.linalg.solve(mass_matrix(vehicle), np.asarray(tau, dtype=float) + bias - lhs)


def linearise(vehicle: Vehicle, eta0: np.ndarray, nu0: np.ndarray,
              tau0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Analytic Jacobians A = df/dx, B = df/dtau of x_dot = f(x, tau), x = [eta; nu].

    The operating force tau0 does not enter the Jacobians (the model is affine in tau); it is
    accepted so a call names the full operating point.
    """
    del tau0
    eta0 = np.asarray(eta0, dtype=float)
    u, v, w, r = np.asarray(nu0, dtype=float)
    nu = np.array([u, v, w, r])
    m = vehicle.mass
    x_g, y_g = vehicle.r_g[0], vehicle.r_g[1]
    Xu, Yv = vehicle.added_mass[0], vehicle.added_mass[1]
    # d(C(nu) nu)/d nu, rows X, Y, Z, N
    dC = np.array([
        [0.0, (-m + Yv) * r, 0.0, -m * (v + 2 * x_g * r) + Yv * v],
        [(m - Xu) * r, 0.0, 0.0, m * (u - 2 * y_g * r) - Xu * u],
        [0.0, 0.0, 0.0, 0.0],
        [m * x_g * r + (Xu - Yv) * v, (Xu - Yv) * u + m * y_g * r, 0.0, m * (x_g * u + y_g * v)],
    ])
    dD = np.diag(vehicle.damping_linear + 2 * vehicle.damping_quadratic * np.abs(nu)
                 + 3 * vehicle.damping_cubic * nu**2)
    Minv = np.linalg.inv(mass_matrix(vehicle))
    psi = float(eta0[3])
    c, s = np.cos(psi), np.sin(psi)
    A = np.zeros((8, 8))
    A[0, 3] = -s * u - c * v
    A[1, 3] = c * u - s * v
    A[:4, 4:] = J(psi)
    A[4:, 4:] = Minv @ (dD - dC)
    B = np.vstack([np.zeros((4, 4)), Minv])
    return A, B


_PACK_CACHE: dict[int, tuple[Vehicle, np.ndarray]] = {}


def _packed(vehicle: Vehicle) -> np.ndarray:
    hit = _PACK_CACHE.get(id(vehicle))
    if hit is not None and hit[0] is vehicle:
        return hit[1]
    p = pack(vehicle)
    if len(_PACK_CACHE) > 64:
        _PACK_CACHE.clear()
    _PACK_CACHE[id(vehicle)] = (vehicle, p)
    return p
