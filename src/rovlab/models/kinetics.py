"""The 4-DOF process model of Sandøy 2016, ch. 3 (Fossen 2011, ch. 6-7; SNAME notation).

    eta_dot = J(psi) nu
    (M_RB + M_A) nu_dot + C_RB(nu) nu + C_A(nu) nu + D_L nu + D_NL(nu) nu + g = tau + b

eta = [x, y, z, psi] (NED), nu = [u, v, w, r] (body), tau = [X, Y, Z, N]. Roll and pitch are
assumed zero.

Ocean current: a constant, irrotational current V_c = [V_N, V_E, V_D] (NED, packed at ``P_VC``,
0 by default) enters through the relative velocity nu_r = nu - nu_c, nu_c = [R(psi)^T V_c; 0]. For
such a current the rigid-body terms may be written in nu_r as well (Fossen 2011, Handbook of
Marine Craft Hydrodynamics and Motion Control, sec. 8.3, Property 8.1), so

    M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r + g = tau + b,   nu_dot = nu_r_dot + nu_c_dot,
    nu_c_dot = [r v_c, -r u_c, 0, 0],   eta_dot = J(psi) nu

with nu (over ground, what a bottom-locked DVL measures) kept as the state. With V_c = 0 every
expression reduces to the one without current, bit for bit.

Free surface: where the surface cuts the hull (|z| < h/2, h the hull's height) buoyancy and heave
added mass scale with the submerged fraction s(z) (0 above the band, 1 below it, linear in
between): net heave force W - s(z) B and heave mass m_w(z) = m - s(z) Z_wdot. A mass that depends
on the position needs its own term in the equation of motion. With roll = pitch = 0 heave is
w = z_dot, and Lagrange's equation (Goldstein, Poole & Safko 2002, Classical Mechanics, 3rd ed.,
sec. 1.4) for T = 1/2 m_w(z) w^2 and V(z) = -W z + B int s dz (z down) reads

    d/dt (m_w w) - 1/2 m_w'(z) w^2 + dV/dz = Z    =>    m_w w_dot + 1/2 m_w'(z) w^2 = W - s(z) B + Z

(d/dt (m_w w) = m_w w_dot + m_w' w^2), so that d(T + V)/dt = Z w: without damping and thrust the
energy is conserved through the breach (tests/models/test_free_surface_energy.py). m_w' = -Z_wdot / h
> 0 in the band: a rising hull sheds added mass and is pushed up by 1/2 m_w' w^2 (without the
term uDrone released from 1 m lost 1.9 J at the breach and stopped ~4 cm short). w is the
relative heave velocity, like every hydrodynamic term (a vertical current at the surface is not
physical; the packaged scenarios have none).

The matrix builders below are plain numpy for reading and testing; the per-step
paths (``nu_dot``, ``plant_rhs``, ``rk4_step``) run on a packed parameter vector (see
:func:`pack`) in numba-compiled code.
"""

from __future__ import annotations

import math

import numpy as np

from rovlab._jit import njit
from rovlab.core.angles import cos_sin_small
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
P_GZ = 33  # restoring force in the heave row when submerged, B - W (left-hand side)
P_ZWDOT = 34  # Z_wdot
P_BUOY = 35  # buoyancy B when fully submerged [N]
P_WEIGHT = 36  # weight W [N]
P_HALF_H = 37  # half the hull's height [m]: the free surface cuts the hull when |z| < this
P_VC = 38  # 3 entries: constant, irrotational ocean current in NED [m/s] (0 unless a scenario sets it)
P_SIZE = 41


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
    p[P_ZWDOT] = vehicle.added_mass[2]
    p[P_BUOY] = vehicle.buoyancy
    p[P_WEIGHT] = vehicle.weight
    p[P_HALF_H] = 0.5 * hull_height(vehicle)
    return p


def hull_height(vehicle: Vehicle) -> float:
    """The hull's height [m] for the free surface: the vehicle file's geometry, else the cube root
    of the displaced volume (a box of that volume)."""
    if vehicle.geometry is not None:
        return float(vehicle.geometry.height)
    return float(vehicle.displaced_volume) ** (1.0 / 3.0)


_DEEP = 1e6  # a depth at which the hull is fully submerged whatever its size


@njit(cache=True, inline="always")
def submerged(p, z):
    """Submerged fraction of the hull with its centre at depth z (z down, surface at 0): 1 below
    z = h/2, 0 above z = -h/2, linear in between (a box-shaped hull breaching the surface)."""
    hh = p[P_HALF_H]
    # deep (almost always): exactly what the clamped formula gives (finite z), without its division. Written
    # as one conditional expression over min/max rather than with early returns: inlined four
    # times per RK4 step, the branchy form cost the plant ~12 % (timed on 6010 RK4 steps)
    return 1.0 if z >= hh else min(max((z + hh) / (2.0 * hh), 0.0), 1.0)  # (NaN stays NaN)


@njit(cache=True, inline="always")
def heave_mass_slope(p, s_sub):
    """dm_w/dz [kg/m] of the heave mass m_w(z) = m - s(z) Z_wdot at submerged fraction s_sub:
    -Z_wdot / h inside the breach band (0 < s < 1, where s rises linearly over the hull's height
    h), 0 outside it (fully submerged or clear of the water). Positive: deeper is heavier."""
    return -p[P_ZWDOT] / (2.0 * p[P_HALF_H]) if 0.0 < s_sub < 1.0 else 0.0


@njit(cache=True, inline="always")
def rhs(p, x0, x1, x2, x3, x4, x5, x6, x7, f0, f1, f2, f3):
    """Time derivative of x = [eta; nu] (8, a tuple) for the total force f = tau + b (+ noise).

    The one right-hand side of the process model: :func:`rhs_into`, :func:`nu_dot_packed`,
    :func:`plant_rhs` and the model API evaluate this function; the simulator's RK4
    (:func:`rk4_scalars`) evaluates its body, :func:`rhs_cs`, with the heading's cosine and sine.
    Scalars in and out, so compiled callers need no arrays (nor their reference counting).
    """
    return rhs_cs(p, math.cos(x3), math.sin(x3), x2, x4, x5, x6, x7, f0, f1, f2, f3)


@njit(cache=True, inline="always")
def rhs_cs(p, c, s, x2, x4, x5, x6, x7, f0, f1, f2, f3):
    """:func:`rhs` with the heading given as c = cos(psi), s = sin(psi) (the rest of the pose,
    x and y, does not enter): for callers that know them more cheaply than by sin and cos
    (:func:`rk4_scalars`)."""
    d0 = c * x4 - s * x5
    d1 = s * x4 + c * x5
    # relative velocity nu_r = nu - nu_c (the current in body axes); the hydrodynamics below see nu_r
    d2 = x6
    u_c = v_c = 0.0
    if p[P_VC] != 0.0 or p[P_VC + 1] != 0.0:  # (without current nu_r = nu exactly: skip the rotation)
        u_c = c * p[P_VC] + s * p[P_VC + 1]
        v_c = -s * p[P_VC] + c * p[P_VC + 1]
        x4 = x4 - u_c
        x5 = x5 - v_c
    x6 = x6 - p[P_VC + 2]
    m = p[P_M]
    a = m * (x5 + p[P_XG] * x7)
    cc = m * (x4 - p[P_YG] * x7)
    # f - C(nu) nu - D(nu) nu - g (damping coefficients carry their negative SNAME sign)
    g0 = f0 - (-a + p[P_YVDOT] * x5) * x7 + (p[P_LIN] + p[P_QUAD] * abs(x4) + p[P_CUB] * x4 * x4) * x4
    g1 = f1 - (cc - p[P_XUDOT] * x4) * x7 + (p[P_LIN + 1] + p[P_QUAD + 1] * abs(x5) + p[P_CUB + 1] * x5 * x5) * x5
    # free surface: buoyancy and heave added mass scale with the submerged fraction s
    s_sub = submerged(p, x2)
    g2 = (f2 - (s_sub * p[P_BUOY] - p[P_WEIGHT])
          + (p[P_LIN + 2] + p[P_QUAD + 2] * abs(x6) + p[P_CUB + 2] * x6 * x6) * x6)
    g3 = (f3 - ((a - p[P_YVDOT] * x5) * x4 + (-cc + p[P_XUDOT] * x4) * x5)
          + (p[P_LIN + 3] + p[P_QUAD + 3] * abs(x7) + p[P_CUB + 3] * x7 * x7) * x7)
    # heave is decoupled in M (M_RB row z = [0, 0, m, 0], M_A diagonal)
    d4 = p[P_MINV] * g0 + p[P_MINV + 1] * g1 + p[P_MINV + 3] * g3
    d5 = p[P_MINV + 4] * g0 + p[P_MINV + 5] * g1 + p[P_MINV + 7] * g3
    d7 = p[P_MINV + 12] * g0 + p[P_MINV + 13] * g1 + p[P_MINV + 15] * g3
    if s_sub >= 1.0:  # submerged (almost always): 1 / (m - Z_wdot) is entry (2, 2) of M^-1, no division
        d6 = p[P_MINV + 10] * g2
    else:
        # breaching: the heave mass m_w(z) = m - s(z) Z_wdot depends on the depth, and Lagrange's
        # equation of T = 1/2 m_w(z) w^2 gives m_w w_dot + 1/2 m_w'(z) w^2 = Z (module docstring)
        d6 = (g2 - 0.5 * heave_mass_slope(p, s_sub) * x6 * x6) / (p[P_M] - s_sub * p[P_ZWDOT])
    if u_c != 0.0 or v_c != 0.0:  # nu_c_dot = d/dt R(psi)^T V_c = [r v_c, -r u_c, 0, 0]
        d4 += x7 * v_c
        d5 -= x7 * u_c
    return d0, d1, d2, x7, d4, d5, d6, d7


@njit(cache=True, inline="always")
def rhs_into(p, x0, x1, x2, x3, x4, x5, x6, x7, f0, f1, f2, f3, out):
    """:func:`rhs` into the array ``out`` (8)."""
    d = rhs(p, x0, x1, x2, x3, x4, x5, x6, x7, f0, f1, f2, f3)
    for i in range(8):
        out[i] = d[i]


@njit(cache=True)
def jacobian_into(p, x, f, A):
    """Analytic Jacobian A = df/dx (8 x 8) of :func:`rhs_into` at x with the total force f (4)
    (with the packed ocean current, if any); the force enters affinely (df/dtau = [0; M^-1]) and
    matters only where the free surface cuts the hull. Compiled, for an EKF's prediction inside the simulator loop."""
    c, s = math.cos(x[3]), math.sin(x[3])
    u_c = c * p[P_VC] + s * p[P_VC + 1]
    v_c = -s * p[P_VC] + c * p[P_VC + 1]
    u, v, r = x[4] - u_c, x[5] - v_c, x[7]  # relative velocities (module docstring)
    m = p[P_M]
    x_g, y_g = p[P_XG], p[P_YG]
    Xu, Yv = p[P_XUDOT], p[P_YVDOT]
    for i in range(8):
        for j in range(8):
            A[i, j] = 0.0
    A[0, 3] = -s * x[4] - c * x[5]
    A[1, 3] = c * x[4] - s * x[5]
    A[0, 4] = c
    A[0, 5] = -s
    A[1, 4] = s
    A[1, 5] = c
    A[2, 6] = 1.0
    A[3, 7] = 1.0
    # G = d(-C(nu) nu - D(nu) nu)/d nu, rows X, Y, Z, N
    G = np.zeros((4, 4))
    G[0, 1] = -(-m + Yv) * r
    G[0, 3] = -(-m * (v + 2 * x_g * r) + Yv * v)
    G[1, 0] = -(m - Xu) * r
    G[1, 3] = -(m * (u - 2 * y_g * r) - Xu * u)
    G[3, 0] = -(m * x_g * r + (Xu - Yv) * v)
    G[3, 1] = -((Xu - Yv) * u + m * y_g * r)
    G[3, 3] = -(m * (x_g * u + y_g * v))
    for i in range(4):
        nu_i = (u, v, x[6] - p[P_VC + 2], r)[i]
        G[i, i] += p[P_LIN + i] + 2.0 * p[P_QUAD + i] * abs(nu_i) + 3.0 * p[P_CUB + i] * nu_i * nu_i
    s_sub = submerged(p, x[2])
    m_w = p[P_M] - s_sub * p[P_ZWDOT]
    for i in (0, 1, 3):
        for j in range(4):
            acc = 0.0
            for k in (0, 1, 3):
                acc += p[P_MINV + 4 * i + k] * G[k, j]
            A[4 + i, 4 + j] = acc
    for j in range(4):
        A[6, 4 + j] = G[2, j] / m_w
    if u_c != 0.0 or v_c != 0.0:
        # psi turns the current in body axes: d nu_r / d psi = -d nu_c / d psi = [-v_c, u_c, 0, 0],
        # and nu_c_dot = [r v_c, -r u_c] adds d/d psi = [-r u_c, -r v_c] and d/d r = [v_c, -u_c]
        for i in (0, 1, 3):
            A[4 + i, 3] = A[4 + i, 4] * (-v_c) + A[4 + i, 5] * u_c
        A[6, 3] = A[6, 4] * (-v_c) + A[6, 5] * u_c
        A[4, 3] += -r * u_c
        A[5, 3] += -r * v_c
        A[4, 7] += v_c
        A[5, 7] += -u_c
    if 0.0 < s_sub < 1.0:  # inside the breach band the heave force and mass depend on z
        ds = 1.0 / (2.0 * p[P_HALF_H])
        w = x[6] - p[P_VC + 2]
        g2 = -(s_sub * p[P_BUOY] - p[P_WEIGHT]) + (p[P_LIN + 2] + p[P_QUAD + 2] * abs(w)
                                                      + p[P_CUB + 2] * w * w) * w
        k_m = heave_mass_slope(p, s_sub)  # dm_w/dz = -ds Z_wdot
        # d/dz [(f_z + g2(z) - 1/2 k_m w^2) / m_w(z)], dg2/dz = -ds B
        A[6, 2] = (-ds * p[P_BUOY]) / m_w - (f[2] + g2 - 0.5 * k_m * w * w) * k_m / (m_w * m_w)
        A[6, 6] -= k_m * w / m_w  # d/dw of -1/2 k_m w^2 / m_w


@njit(cache=True)
def nu_dot_packed(p: np.ndarray, nu: np.ndarray, tau: np.ndarray, b: np.ndarray) -> np.ndarray:
    """nu_dot = M^-1 (tau + b - C(nu) nu - D(nu) nu - g) on a packed parameter vector, fully
    submerged (for the free surface use :func:`plant_rhs` with the depth)."""
    out = np.empty(8)
    rhs_into(p, 0.0, 0.0, _DEEP, 0.0, nu[0], nu[1], nu[2], nu[3],
             tau[0] + b[0], tau[1] + b[1], tau[2] + b[2], tau[3] + b[3], out)
    return out[4:].copy()


@njit(cache=True)
def plant_rhs(p: np.ndarray, x: np.ndarray, tau: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Time derivative of the 8-state x = [eta; nu] with force tau and bias b held fixed."""
    out = np.empty(8)
    rhs_into(p, x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7],
             tau[0] + b[0], tau[1] + b[1], tau[2] + b[2], tau[3] + b[3], out)
    return out


@njit(cache=True, inline="always")
def rk4_scalars(p, c, s, x0, x1, x2, x3, x4, x5, x6, x7, f0, f1, f2, f3, h):
    """One classical Runge-Kutta step of length h from the state (x0 .. x7), whose heading x3 has
    c = cos(x3) and s = sin(x3), with the force (f0 .. f3) held. Returns the new state and the
    cosine and sine of its heading (10 scalars), so a caller stepping many times keeps all of it
    in registers (rovlab.sim.plant.process_advance).

    The stages' headings x3 + d (|d| = h |r| / 2 or h |r|, small) are turned into cosines and
    sines by the angle-addition formulas (rovlab.core.angles.cos_sin_small) instead of four
    sin/cos pairs per step: the same values to rounding (60 s at 100 Hz of a spiralling vehicle
    end within ~1e-14 m of evaluating sin and cos at every stage, with or without a current;
    tests/models/test_kinetics.py checks 1e-12) in ~35 % less time.
    """
    k1 = rhs_cs(p, c, s, x2, x4, x5, x6, x7, f0, f1, f2, f3)
    hh = 0.5 * h
    d = hh * k1[3]
    cd, sd = cos_sin_small(d)
    k2 = rhs_cs(p, c * cd - s * sd, s * cd + c * sd, x2 + hh * k1[2],
                x4 + hh * k1[4], x5 + hh * k1[5], x6 + hh * k1[6], x7 + hh * k1[7], f0, f1, f2, f3)
    d = hh * k2[3]
    cd, sd = cos_sin_small(d)
    k3 = rhs_cs(p, c * cd - s * sd, s * cd + c * sd, x2 + hh * k2[2],
                x4 + hh * k2[4], x5 + hh * k2[5], x6 + hh * k2[6], x7 + hh * k2[7], f0, f1, f2, f3)
    d = h * k3[3]
    cd, sd = cos_sin_small(d)
    k4 = rhs_cs(p, c * cd - s * sd, s * cd + c * sd, x2 + h * k3[2],
                x4 + h * k3[4], x5 + h * k3[5], x6 + h * k3[6], x7 + h * k3[7], f0, f1, f2, f3)
    h6 = h / 6.0
    turn = h6 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3])
    cd, sd = cos_sin_small(turn)
    return (x0 + h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            x1 + h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            x2 + h6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
            x3 + turn,
            x4 + h6 * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4]),
            x5 + h6 * (k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5]),
            x6 + h6 * (k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6]),
            x7 + h6 * (k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7]),
            c * cd - s * sd, s * cd + c * sd)


@njit(cache=True)
def rk4_inplace(p: np.ndarray, x: np.ndarray, f: np.ndarray, h: float) -> None:
    """One classical Runge-Kutta step of x (in place) with the force f held."""
    d = rk4_scalars(p, math.cos(x[3]), math.sin(x[3]), x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7],
                    f[0], f[1], f[2], f[3], h)
    for i in range(8):
        x[i] = d[i]


@njit(cache=True)
def rk4_step(p: np.ndarray, x: np.ndarray, tau: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
    """One classical Runge-Kutta step of length h (tau and b constant over the step)."""
    out = x.copy()
    f = np.empty(4)
    for i in range(4):
        f[i] = tau[i] + b[i]
    rk4_inplace(p, out, f, h)
    return out


def nu_dot(vehicle: Vehicle, eta: np.ndarray, nu: np.ndarray, tau: np.ndarray,
           b: np.ndarray | None = None) -> np.ndarray:
    """Body acceleration nu_dot for state (eta, nu), force tau and bias b (Sandøy 2016, ch. 3).

    Packs the vehicle on every call (about 20 us); a loop should pack once (:func:`pack`) and
    call :func:`plant_rhs` or the compiled kernels.

    With roll = pitch = 0 the pose enters only through the depth: near the free surface
    (|z| < half the hull's height) buoyancy and heave added mass fall with the submerged fraction.
    """
    bias = np.zeros(4) if b is None else np.asarray(b, dtype=float)
    x = np.concatenate([np.asarray(eta, dtype=float).ravel(), np.asarray(nu, dtype=float).ravel()])
    return plant_rhs(pack(vehicle), x, np.asarray(tau, dtype=float), bias)[4:]


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

    The operating force tau0 enters only where the free surface cuts the hull (the heave mass
    depends on the depth there). Evaluated by the compiled :func:`jacobian_into`, the same code
    an EKF runs inside the simulator; B = M^-1 with the submerged heave added mass.
    """
    x = np.concatenate([np.asarray(eta0, dtype=float).ravel(), np.asarray(nu0, dtype=float).ravel()])
    f = np.zeros(4) if tau0 is None else np.asarray(tau0, dtype=float).ravel()
    p = pack(vehicle)
    A = np.empty((8, 8))
    jacobian_into(p, x, f, A)
    Minv = np.linalg.inv(mass_matrix(vehicle))
    Minv[2, 2] = 1.0 / (p[P_M] - submerged(p, x[2]) * p[P_ZWDOT])
    B = np.vstack([np.zeros((4, 4)), Minv])
    return A, B
