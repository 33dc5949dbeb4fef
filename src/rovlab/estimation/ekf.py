"""The 4-DOF extended Kalman filter (the thesis's further work, Sandøy 2016 sec. 6 and appendix)
as a closed-loop component (estimator slot).

State x = [x, y, z, psi, u, v, w, r, b_X, b_Y, b_Z, b_N] (the layout rovlab.core.components.TRUTH):
pose in NED, velocity over ground in the body frame, and per DOF the force/moment on the body
beyond the thrust, b, as the truth and the depth-and-heading filter define it (b_Z includes the
net weight, so a controller's bias feed-forward cancels b as it is). Its model: a known mean
g_0 = [0, 0, W - B, 0] (the vehicle file's net weight, fully submerged) plus a zero-mean first-order
Gauss-Markov residual r per DOF for what the model leaves out (a buoyancy error, the free surface,
a tether, an unknown current):

    eta_dot = J(psi) nu
    nu_dot  = f(eta, nu, tau + b + w_f)        (rovlab.models.kinetics.rhs_into, without its
                                                restoring force: b carries it)
    b = g_0 + r,  r_dot = -T^-1 r + w_r,  so  b_dot = -T^-1 (b - g_0) + w_r
                                                w_f, w_r white, power spectral densities W_f, W_b

Fully submerged this is the plant's own heave equation, restoring force B - W included, with a
zero-mean heave bias, written in the state b = (W - B) + r. Before issue 28 the EKF had g_0 = 0:
b_Z was a zero-mean Gauss-Markov state made to carry uDrone's constant -6.7 N, so every prediction
pulled it toward 0 by |W - B| / T (0.11 N/s) and the filter was over-confident in heave while
motion capture was lost (docs/dp.md). The free surface's loss of buoyancy (s(z) B - B, s the
submerged fraction) is left to the residual as before: on a real vehicle the box hull of the vehicle
file is a poor model of it (on ../shared/data/ardusub/small.tlog, a BlueROV2 Heavy at the surface or
on deck whose vehicle file says it sinks by 0.98 N, W - s(z) B as b_Z's mean put the estimate 4.5 cm
below the pressure sensor and 12 healthy pressure samples out of the gate, against 2 before).

Prediction over one sample h (the input tau held, zero-order hold):

* the state by classical RK4 on the 12-state model in ``substeps`` steps (the bias decays inside
  the integration, so a linear model is integrated to O(h^5) per substep);
* the covariance with the Jacobian A = df/dx at the corrected estimate (the compiled analytic
  :func:`rovlab.models.kinetics.jacobian_into`, extended by the bias rows and columns) and
  Van Loan's method for Phi = e^{A h} and the discrete process noise
  Q = int_0^h e^{A s} E W E^T e^{A^T s} ds (Van Loan 1978, IEEE TAC 23(3); the matrix exponential by
  Pade (6, 6) with scaling and squaring, Golub & Van Loan 2013, Matrix Computations, alg. 9.3.1):
  P = Phi P Phi^T + Q (not Phi P Phi^T + Gamma Q Gamma^T as Sandøy 2016, sec. 5.1.2 writes: an erratum);
* a wrench known only to a relative accuracy kappa (``[process_noise] thrust_uncertainty``, as the
  depth-and-heading filter reads it: the thrust a PWM gives on a real vehicle) adds the covariance of
  its error held over the sample, P += sum_l (kappa tau_l)^2 Gamma_l Gamma_l^T with
  Gamma = int_0^h e^{A s} ds B_tau the discrete input matrix at the same linearisation (B_tau = df/dtau,
  the force columns; one more matrix exponential, only when kappa tau != 0).

Correction: every sensor of the 4-DOF model is linear in this state (motion capture x, y, z, psi;
pressure depth with the lever arm z_VO = z_sensor - l_z at zero roll and pitch; IMU heading and
yaw rate; a bottom-locked DVL's u, v, w), so the correction is the depth-and-heading filter's
own: the shared kernel :func:`rovlab.estimation.kalman.correct_arrays` with its sensor management
(timeouts, innovation gating, gradual recovery, manual on/off) and Joseph-form updates, psi
innovations wrapped. On a linear model this filter is therefore the linear Kalman filter
(tests/estimation/test_ekf.py shows it to 1e-9).

:func:`build` refuses a sensor set that does not observe the state (local observability of the
linearisation at the initial state; ``[ekf] dead_reckoning`` lists states the user accepts to
dead-reckon, e.g. x and y without a position fix).

Its table in the design file (read by this module with rovlab.params.validate.TableReader)::

    [ekf]                                  # optional: the 4-DOF EKF (estimator = "ekf"; rovlab.estimation.ekf)
    source = "..."
    force_psd = { X = 1e-2, Y = 1e-2, Z = 1e-2, N = 1e-6 }      # white force noise W [N^2/Hz ...]
    bias_psd = { X = 2e-2, Y = 2e-2, Z = 3e-3, N = 1e-4 }       # PSD of the bias drivers
    bias_time_constant_s = { X = 60.0, Y = 60.0, Z = 60.0, N = 60.0 }
    current = { north = 0.0, east = 0.0, down = 0.0 }           # a known current [m/s] (default 0)
    substeps = 10                          # RK4 steps per sample
    initial_state = { x = 0.0, psi_deg = 0.0 }                  # keys x y z psi_deg u v w r_deg_s b_X b_Y b_Z b_N
                                                                # (0 if absent; b_Z: the vehicle file's W - B)
    initial_std = { x = 1.0, psi_deg = 180.0 }
    dead_reckoning = ["x", "y"]            # states accepted as unobservable (no position fix)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from rovlab._jit import WITH_NRT, njit, plain
from rovlab.core.angles import wrap_angle
from rovlab.core.components import WRENCH, ComponentInfo, EstimatorSpec, register_component, register_estimator
from rovlab.estimation.fusion import new_channel_state
from rovlab.estimation.kalman import correct_arrays, work_size
from rovlab.estimation.model import channel_config, make_channels, observability, startup_time, unobservable_problem
from rovlab.models import kinetics as kin
from rovlab.params.design import BIAS_TIME_RANGE, PSD_RANGE, STATE_KEY_RANGES, DesignConfig, per_key
from rovlab.params.validate import ConfigError, Problem, TableReader
from rovlab.params.vehicle import Vehicle

_DEG = math.pi / 180.0
_EKF_STATE_KEYS = {"x": (0, 1.0), "y": (1, 1.0), "z": (2, 1.0), "psi_deg": (3, _DEG), "u": (4, 1.0),
                   "v": (5, 1.0), "w": (6, 1.0), "r_deg_s": (7, _DEG), "b_X": (8, 1.0), "b_Y": (9, 1.0),
                   "b_Z": (10, 1.0), "b_N": (11, 1.0)}


@dataclass(frozen=True, eq=False)
class EKFConfig:
    """The [ekf] table: noise model and initial belief of the 4-DOF EKF (rovlab.estimation.ekf), SI.

    force_psd: white force/moment noise W on [X, Y, Z, N] (enters like tau); bias_psd and
    bias_time_constant_s: the Gauss-Markov residual of the bias per DOF about the nominal net weight
    (r_dot = -r/T + w_r, w_r of PSD bias_psd); current: a known constant current (NED, m/s; 0 =
    unknown, left to the biases); initial_b_Z_nominal: initial_state gives no b_Z, which then
    starts at its mean, the vehicle file's W - B (a zero residual).
    """

    force_psd: np.ndarray = field(default_factory=lambda: np.array([1e-2, 1e-2, 1e-2, 1e-4]))
    bias_psd: np.ndarray = field(default_factory=lambda: np.array([2e-3, 2e-3, 3e-3, 1e-6]))
    bias_time_constant_s: np.ndarray = field(default_factory=lambda: np.full(4, 60.0))
    current: np.ndarray = field(default_factory=lambda: np.zeros(3))
    substeps: int = 10  # RK4 steps per sample in the prediction
    dead_reckoning: tuple[str, ...] = ()  # states accepted as unobservable (e.g. x, y without a position fix)
    initial_state: np.ndarray = field(default_factory=lambda: np.zeros(12))
    initial_std: np.ndarray = field(default_factory=lambda: np.array(
        [1.0, 1.0, 1.0, math.pi, 0.5, 0.5, 0.5, math.radians(30.0), 10.0, 10.0, 10.0, 1.0]))
    source: str = "rovlab defaults (rovlab.estimation.ekf.EKFConfig)"
    given: bool = False
    initial_b_Z_nominal: bool = True  # b_Z starts at the vehicle file's W - B (initial_state has no b_Z)


N_X = 12
EKF_STATES = ("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N")
EKF_MEASURABLE = EKF_STATES[:8]  # quantities a measurement may give the EKF
DOFS = WRENCH  # X, Y, Z, N: the keys of the [ekf] force and bias tables
STATE_OF_QUANTITY = {q: i for i, q in enumerate(EKF_STATES[:8])}
_PSI = 3


class EKF(NamedTuple):
    """The 4-DOF EKF: constants (packed model, noise, channels) and state (x, P, ch)."""

    p: np.ndarray  # packed model (rovlab.models.kinetics.pack), with the known current if any, no restoring force
    inv_T: np.ndarray  # (4) 1 / bias time constants [1/s]
    W: np.ndarray  # (8) PSD of the force noise (X, Y, Z, N) and of the bias drivers
    net: np.ndarray  # (4) the biases' means g_0 = [0, 0, W - B, 0] [N, N m]: the vehicle file's net weight
    kappa: np.ndarray  # (4) relative uncertainty of the wrench X, Y, Z, N ([process_noise] thrust_uncertainty)
    h: float  # sample time [s]
    n_sub: int  # RK4 steps per sample
    H: np.ndarray  # (m, 12)
    cfg: np.ndarray  # channel configuration (rovlab.estimation.fusion CFG_*)
    wrap: np.ndarray  # bool (12): psi
    x: np.ndarray  # (12) estimate
    P: np.ndarray  # (12, 12) covariance
    ch: np.ndarray  # (m, N_CH) sensor-management state
    work: np.ndarray  # correction scratch (rovlab.estimation.kalman.work_size)
    A: np.ndarray  # (12, 12) work: the Jacobian
    A8: np.ndarray  # (8, 8) work
    F: np.ndarray  # (24, 24) work: Van Loan's matrix
    k: np.ndarray  # (4, 12) work: RK4 stages
    xs: np.ndarray  # (12) work
    f: np.ndarray  # (4) work: the force tau + b


# --------------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------------

@njit(cache=True)
def expm_pade(A):
    """e^A by the (6, 6) Pade approximant with scaling and squaring (Golub & Van Loan 2013,
    alg. 9.3.1): ||A / 2^j||_inf <= 1/2 makes the approximant accurate to about 1e-16 relative."""
    n = A.shape[0]
    norm = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += abs(A[i, j])
        norm = max(norm, s)
    j = 0
    if norm > 0.5:
        j = int(math.ceil(math.log2(norm / 0.5)))
    As = A / (2.0 ** j)
    q = 6
    c = 1.0
    X = np.eye(n)
    N = np.eye(n)
    D = np.eye(n)
    sign = 1.0
    for k in range(1, q + 1):
        c = c * (q - k + 1) / ((2 * q - k + 1) * k)
        X = As @ X
        sign = -sign
        N += c * X
        D += (sign * c) * X
    E = np.ascontiguousarray(np.linalg.solve(D, N))
    for _ in range(j):
        E = E @ E
    return E


@njit(cache=True, inline="always")
def _rhs12(p, inv_T, net, x, f, tau, out, w8):
    """Time derivative of the 12-state model (x: eta, nu, b) with the input tau into out; w8 (8) work."""
    for i in range(4):
        f[i] = tau[i] + x[8 + i]
    kin.rhs_into(p, x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], f[0], f[1], f[2], f[3], w8)
    for i in range(8):
        out[i] = w8[i]
    for i in range(4):
        out[8 + i] = -inv_T[i] * (x[8 + i] - net[i])  # the residual b - g_0 decays


@njit(cache=True)
def propagate_state(p, inv_T, net, x, tau, h, n_sub, k, xs, f):
    """x <- x(t + h) by n_sub classical RK4 steps of the 12-state model (in place); k (4, 12) and
    xs (12) are work, f (4) too."""
    dt = h / n_sub
    w8 = np.empty(8)
    for _ in range(n_sub):
        _rhs12(p, inv_T, net, x, f, tau, k[0], w8)
        for i in range(N_X):
            xs[i] = x[i] + 0.5 * dt * k[0, i]
        _rhs12(p, inv_T, net, xs, f, tau, k[1], w8)
        for i in range(N_X):
            xs[i] = x[i] + 0.5 * dt * k[1, i]
        _rhs12(p, inv_T, net, xs, f, tau, k[2], w8)
        for i in range(N_X):
            xs[i] = x[i] + dt * k[2, i]
        _rhs12(p, inv_T, net, xs, f, tau, k[3], w8)
        for i in range(N_X):
            x[i] += dt / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])


@njit(cache=True)
def jacobian12(p, inv_T, x, tau, A, A8, f):
    """A = df/dx (12 x 12) of the 12-state model at x with the input tau."""
    for i in range(4):
        f[i] = tau[i] + x[8 + i]
    kin.jacobian_into(p, x[:8], f, A8)
    for i in range(N_X):
        for j in range(N_X):
            A[i, j] = 0.0
    for i in range(8):
        for j in range(8):
            A[i, j] = A8[i, j]
    # the bias enters like the force: d nu_dot / d b = M^-1 (heave with the submerged added mass)
    m_w = p[kin.P_M] - kin.submerged(p, x[2]) * p[kin.P_ZWDOT]
    for i in (0, 1, 3):
        for j in (0, 1, 3):
            A[4 + i, 8 + j] = p[kin.P_MINV + 4 * i + j]
    A[6, 10] = 1.0 / m_w
    for i in range(4):
        A[8 + i, 8 + i] = -inv_T[i]


@njit(cache=True)
def input_matrix(A, h):
    """Gamma = int_0^h e^{A s} ds B_tau (12 x 4), the discrete input matrix of the wrench held over
    the sample, with B_tau = df/dtau: the force columns of A (the wrench enters like the bias, rows
    4..7), by the exponential of [[A, B_tau], [0, 0]] h (Van Loan 1978)."""
    n = N_X
    F = np.zeros((n + 4, n + 4))
    for i in range(n):
        for j in range(n):
            F[i, j] = A[i, j] * h
    for i in range(4, 8):
        for j in range(4):
            F[i, n + j] = A[i, 8 + j] * h
    G = expm_pade(F)
    return np.ascontiguousarray(G[:n, n:])


@njit(cache=True)
def add_input_uncertainty(A, h, kappa, u, P):
    """P += sum_l (kappa_l u_l)^2 Gamma_l Gamma_l^T (in place): the error of a wrench known to the
    relative standard deviation kappa_l, held over the sample (as the depth-and-heading filter's
    rovlab.estimation.kalman.predict_arrays). Nothing is computed, and P is left as it is, when
    every kappa_l u_l is 0."""
    any_ = False
    for l in range(4):
        if kappa[l] * u[l] != 0.0:
            any_ = True
    if not any_:
        return
    Gam = input_matrix(A, h)
    for l in range(4):
        g = kappa[l] * u[l]
        if g != 0.0:
            g2 = g * g
            for i in range(N_X):
                di = g2 * Gam[i, l]
                for j in range(N_X):
                    P[i, j] += di * Gam[j, l]


@njit(cache=True)
def van_loan(A, W, h, F):
    """(Phi, Q) of x_dot = A x + E w, E W E^T with E = [0; M^-1 (force noise); I (bias drivers)]
    read from A's bias columns (the force noise enters like the bias). F (24 x 24) is work."""
    n = N_X
    for i in range(2 * n):
        for j in range(2 * n):
            F[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            F[i, j] = -A[i, j] * h
            F[n + i, n + j] = A[j, i] * h
    # E W E^T: force noise through the bias columns of A (rows 4..7), bias drivers on rows 8..11
    for i in range(4, 8):
        for j in range(4, 8):
            acc = 0.0
            for d in range(4):
                acc += A[i, 8 + d] * W[d] * A[j, 8 + d]
            F[i, n + j] = acc * h
    for d in range(4):
        F[8 + d, n + 8 + d] = W[4 + d] * h
    G = expm_pade(F)
    Phi = np.ascontiguousarray(G[n:, n:].T)
    Q = Phi @ np.ascontiguousarray(G[:n, n:])
    for i in range(n):  # symmetric by construction; remove the round-off
        for j in range(i + 1, n):
            q = 0.5 * (Q[i, j] + Q[j, i])
            Q[i, j] = q
            Q[j, i] = q
    return Phi, Q


@njit(cache=True, **WITH_NRT)  # allocates: explicit, as the closed loop that calls it is compiled without NRT
def ekf_predict(p, inv_T, net, kappa, W, h, n_sub, x, P, tau, A, A8, F, k, xs, f):
    """Project (x, P) over one sample with the wrench tau (4) held (in place). A non-finite tau
    entry is taken as 0 (as the linear filter does)."""
    u = np.empty(4)
    for i in range(4):
        u[i] = tau[i] if math.isfinite(tau[i]) else 0.0
    jacobian12(p, inv_T, x, u, A, A8, f)
    Phi, Q = van_loan(A, W, h, F)
    propagate_state(p, inv_T, net, x, u, h, n_sub, k, xs, f)
    x[_PSI] = wrap_angle(x[_PSI])
    PP = Phi @ P @ Phi.T + Q
    add_input_uncertainty(A, h, kappa, u, PP)
    for i in range(N_X):
        for j in range(N_X):
            P[i, j] = 0.5 * (PP[i, j] + PP[j, i])


@njit(cache=True)
def _correct(est, t, y, present, rep):
    correct_arrays(est.x, est.P, est.ch, est.H, est.cfg, est.wrap, t, y, present, rep, est.work)


@njit(cache=True)
def _predict(est, t, tau):
    ekf_predict(est.p, est.inv_T, est.net, est.kappa, est.W, est.h, est.n_sub, est.x, est.P, tau, est.A, est.A8,
                est.F, est.k, est.xs, est.f)


register_estimator(EKF, state=("x", "P", "ch"), correct=_correct, predict=_predict)


# --------------------------------------------------------------------------------------------
# Design (plain Python)
# --------------------------------------------------------------------------------------------

def continuous_model(p: np.ndarray, inv_T: np.ndarray, x: np.ndarray, tau: np.ndarray | None = None) -> np.ndarray:
    """The 12 x 12 Jacobian at x (for design and tests)."""
    A = np.empty((N_X, N_X))
    plain(jacobian12)(p, inv_T, np.asarray(x, dtype=float), np.zeros(4) if tau is None else np.asarray(tau, dtype=float),
                      A, np.empty((8, 8)), np.empty(4))
    return A


def discrete_input_matrix(A: np.ndarray, h: float) -> np.ndarray:
    """Gamma = int_0^h e^{A s} ds B_tau (12 x 4) by scipy's expm (the design-time check of the
    compiled :func:`input_matrix`)."""
    from scipy.linalg import expm

    n = N_X
    Bt = np.zeros((n, 4))
    Bt[4:8] = A[4:8, 8:12]
    F = np.zeros((n + 4, n + 4))
    F[:n, :n] = A * h
    F[:n, n:] = Bt * h
    return expm(F)[:n, n:]


def discrete_model(p: np.ndarray, inv_T: np.ndarray, W: np.ndarray, x: np.ndarray, h: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Q) at x, by scipy's expm (the design-time check of the compiled Van Loan)."""
    A = continuous_model(p, inv_T, x)
    n = N_X
    EWE = np.zeros((n, n))
    Bf = A[:, 8:12]
    EWE[4:8, 4:8] = (Bf[4:8] * W[:4]) @ Bf[4:8].T
    EWE[8:, 8:] = np.diag(W[4:])
    F = np.block([[-A * h, EWE * h], [np.zeros((n, n)), A.T * h]])
    from scipy.linalg import expm

    G = expm(F)
    Phi = G[n:, n:].T
    return Phi, Phi @ G[:n, n:]


def packed_model(vehicle: Vehicle, config: DesignConfig) -> np.ndarray:
    """The EKF's packed model: the vehicle file's, with the configuration's known current, and
    without the restoring force in the right-hand side: b_Z holds the net weight (what
    rovlab.core.components.TRUTH calls b_Z, as the depth-and-heading filter's b_w does), so the
    controller's bias feed-forward cancels it; its nominal value W - B (:func:`nominal_net`) is
    b_Z's mean in the bias model, the rest a zero-mean residual."""
    p = kin.pack(vehicle)
    p[kin.P_VC:kin.P_VC + 3] = config.table("ekf").current
    p[kin.P_BUOY] = 0.0
    p[kin.P_WEIGHT] = 0.0
    p[kin.P_GZ] = 0.0
    return p


def nominal_net(vehicle: Vehicle) -> np.ndarray:
    """The biases' means g_0 = [0, 0, W - B, 0] [N, N m]: the vehicle file's net weight, fully
    submerged (down positive, as b_Z)."""
    return np.array([0.0, 0.0, vehicle.weight - vehicle.buoyancy, 0.0])


def build(vehicle: Vehicle, config: DesignConfig) -> EstimatorSpec:
    """Design the 4-DOF EKF of a configuration (raises ConfigError naming the file and key)."""
    file = config.file or config.name
    ec = config.table("ekf")
    channels, problems = make_channels(vehicle, config, STATE_OF_QUANTITY, estimator="ekf")
    if problems:
        raise ConfigError(problems, "filter configuration")
    bad_dr = [s for s in ec.dead_reckoning if s not in EKF_STATES]
    if bad_dr:
        raise ConfigError([Problem(file, "ekf.dead_reckoning", bad_dr, "states of the EKF: " + ", ".join(EKF_STATES))],
                          "filter configuration")
    h = config.sample_time
    p = packed_model(vehicle, config)
    net = nominal_net(vehicle)
    kappa = np.full(4, float(config.thrust_uncertainty))
    inv_T = 1.0 / np.asarray(ec.bias_time_constant_s, dtype=float)
    W = np.concatenate([ec.force_psd, ec.bias_psd]).astype(float)
    m = len(channels)
    H = np.zeros((m, N_X))
    for j, c in enumerate(channels):
        H[j, c.state_index] = 1.0
    R = np.diag([c.variance for c in channels]) if m else np.zeros((0, 0))
    start = np.array(ec.initial_state, dtype=float)
    if ec.initial_b_Z_nominal:  # b_Z: its mean, the nominal net weight (a zero residual)
        start[10] = net[2]
    x0 = start.copy()
    if x0[2] < 1.0:  # linearise fully submerged (the free surface only changes heave's mass)
        x0[2] = 1.0
    A = continuous_model(p, inv_T, x0)
    observable, touched, V = observability(A, H, EKF_STATES)
    accepted = set(ec.dead_reckoning)
    if not observable and not set(touched) <= accepted:
        problem = unobservable_problem(file, channels, touched, V, EKF_STATES)
        extra = [s for s in touched if s not in accepted]
        raise ConfigError([Problem(problem.file, problem.key, problem.value,
                                   problem.expected.replace("Add a measurement", "Add a measurement (a position fix: "
                                                            "motion capture x, y; velocity: a DVL)", 1)
                                   + f" Or accept dead reckoning of {', '.join(extra)} with "
                                   "[ekf] dead_reckoning = [...].")], "filter configuration")
    Phi, Q = discrete_model(p, inv_T, W, x0, h)
    P0 = np.diag(np.asarray(ec.initial_std, dtype=float) ** 2)
    keep = [i for i, s in enumerate(EKF_STATES) if s not in accepted]
    auto = startup_time(Phi[np.ix_(keep, keep)], Q[np.ix_(keep, keep)], H[:, keep], R, P0[np.ix_(keep, keep)], h,
                        max_steps=20_000) if m else 0.0
    late = [(c, mc) for c, mc in zip(channels, config.measurements)
            if not math.isnan(c.startup_s) and c.startup_s < auto and np.isfinite(c.gate_threshold)]
    if late:
        raise ConfigError([Problem(file, f"fusion.startup_s ({mc.key})", c.startup_s,
                                   f"at least {auto:.3g} s for {c.name}: the start-up this EKF design needs before "
                                   "its innovation gate is valid; leave it out to use that value") for c, mc in late],
                          "filter configuration")
    channels = [replace(c, startup_s=auto) if math.isnan(c.startup_s) else c for c in channels]
    cfg = channel_config(channels, H)
    kernel = EKF(p, inv_T, W, net, kappa, float(h), int(ec.substeps), H, cfg, np.array([s == "psi" for s in EKF_STATES]),
                 start, P0.copy(), plain(new_channel_state)(m),
                 np.empty(plain(work_size)(N_X, m)),
                 np.empty((N_X, N_X)), np.empty((8, 8)), np.empty((2 * N_X, 2 * N_X)), np.empty((4, N_X)),
                 np.empty(N_X), np.empty(4))
    model = EKFModel(h=h, p=p, inv_T=inv_T, W=W, channels=tuple(channels), H=H, R=R, x0=kernel.x.copy(), P0=P0,
                     Phi0=Phi, Q0=Q, observable=observable, dead_reckoned=tuple(s for s in touched), net=net,
                     kappa=kappa)
    return EstimatorSpec(kernel=kernel, states=EKF_STATES, nav=EKF_STATES, channels=tuple(channels), h=h, model=model)


class EKFModel(NamedTuple):
    """The design behind an EKF (for display and tests): model, noise and its linearisation at x0."""

    h: float
    p: np.ndarray
    inv_T: np.ndarray
    W: np.ndarray
    channels: tuple
    H: np.ndarray
    R: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    Phi0: np.ndarray
    Q0: np.ndarray
    observable: bool
    dead_reckoned: tuple[str, ...]
    net: np.ndarray  # (4) the biases' means [N, N m]: the nominal net weight W - B in heave
    kappa: np.ndarray  # relative uncertainty of the wrench ([process_noise] thrust_uncertainty)

    @property
    def states(self) -> tuple[str, ...]:
        return EKF_STATES


# A known current per NED component [m/s]: BlueROV-class vehicles make 0.9-0.95 m/s flat out (the
# packaged vehicles' thrust against their drag), so a 2 m/s current (~4 knots) is already beyond
# any station keeping; 5 m/s made the EKF kernel fail (issue 28, fuzzing)
KNOWN_CURRENT_RANGE = (-2.0, 2.0)


def read_ekf_table(t: TableReader) -> EKFConfig:
    """Read the [ekf] table of a design file with the loader's reader (closed schema; every problem collected)."""
    base = EKFConfig()
    source = t.string("source")
    fpsd = per_key(t, "force_psd", DOFS, base.force_psd, nonnegative=True, plausible=PSD_RANGE,
                   what="N^2/Hz or (N m)^2/Hz")
    bpsd = per_key(t, "bias_psd", DOFS, base.bias_psd, nonnegative=True, plausible=PSD_RANGE,
                   what="N^2/s per s (PSD of the bias driver)")
    bT = per_key(t, "bias_time_constant_s", DOFS, base.bias_time_constant_s, positive=True, what="s")
    for i, k in enumerate(DOFS):
        if np.isfinite(bT[i]) and not BIAS_TIME_RANGE[0] <= bT[i] <= BIAS_TIME_RANGE[1]:
            t.problem(f"bias_time_constant_s.{k}", float(bT[i]), f"a time in [{BIAS_TIME_RANGE[0]:g}, "
                      f"{BIAS_TIME_RANGE[1]:g}] s")
    cur = per_key(t, "current", ("north", "east", "down"), base.current, plausible=KNOWN_CURRENT_RANGE,
                  what="m/s, NED")
    substeps = t.integer("substeps", base.substeps, lo=1)
    dead: list[str] = []
    if t.has("dead_reckoning"):
        raw = t.raw("dead_reckoning")
        if not isinstance(raw, list) or not all(isinstance(v, str) and v in EKF_STATES for v in raw):
            t.problem("dead_reckoning", raw, "a list of EKF states (" + ", ".join(EKF_STATES) + ")")
        else:
            dead = list(raw)
    if substeps > 1000:
        t.problem("substeps", substeps, "at most 1000 RK4 steps per sample")
        substeps = base.substeps
    keys = tuple(_EKF_STATE_KEYS)
    factors = tuple(f for _, f in _EKF_STATE_KEYS.values())
    raw_x0 = t.data.get("initial_state")
    b_z_given = isinstance(raw_x0, dict) and "b_Z" in raw_x0
    x0 = per_key(t, "initial_state", keys, base.initial_state / np.array(factors), factors=factors,
                 plausible=STATE_KEY_RANGES)
    std = per_key(t, "initial_std", keys, base.initial_std / np.array(factors), factors=factors, nonnegative=True,
                  plausible=STATE_KEY_RANGES)
    t.finish()
    for arr in (fpsd, bpsd, bT, cur, x0, std):
        arr.setflags(write=False)
    return EKFConfig(force_psd=fpsd, bias_psd=bpsd, bias_time_constant_s=bT, current=cur, substeps=substeps,
                     initial_state=x0, initial_std=std, dead_reckoning=tuple(dead), source=source, given=True,
                     initial_b_Z_nominal=not b_z_given)


def summary(spec: EstimatorSpec) -> dict[str, Any]:
    """The EKF's design (``rovlab design --json``, the HMI): its states, channels, noise model and
    the linearisation at its initial estimate."""
    m = spec.model
    return {
        "sample_time": m.h,
        "states": list(EKF_STATES),
        "measurements": [c.name for c in m.channels],
        "observable": bool(m.observable),
        "dead_reckoned": list(m.dead_reckoned),
        # heave and yaw in the KF's terms (the HMI's bias line): the bias time constants of b_Z, b_N
        "model": {"T_w": float(1.0 / m.inv_T[2]), "T_r": float(1.0 / m.inv_T[3])},
        "ekf": {"force_psd": dict(zip(DOFS, map(float, m.W[:4]))), "bias_psd": dict(zip(DOFS, map(float, m.W[4:]))),
                "bias_time_constant_s": dict(zip(DOFS, (float(1.0 / v) for v in m.inv_T))),
                # b_Z's mean (the nominal W - B, fully submerged) and the wrench's relative uncertainty
                "b_Z_mean": float(m.net[2]), "thrust_uncertainty": float(m.kappa[2]),
                "initial_std": dict(zip(EKF_STATES, map(float, np.sqrt(np.diag(m.P0)))))},
        "H": m.H.tolist(),
        "R": m.R.tolist(),
        "Phi": m.Phi0.tolist(),
        "Q": m.Q0.tolist(),
    }


register_component(ComponentInfo(
    "ekf", "estimator", build,
    description="4-DOF extended Kalman filter on the nonlinear model (Sandøy 2016, further work)",
    parse_table=read_ekf_table, default_table=EKFConfig, measurable=EKF_MEASURABLE, summary=summary))
