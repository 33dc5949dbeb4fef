"""Dynamic positioning in x, y, z and psi: nonlinear PID with a third-order reference model,
acceleration feed-forward, bias feed-forward from the estimator and back-calculation anti-windup
(controller slot; the thesis's further work, Sandøy 2016 sec. 6).

The design is the textbook DP controller of Fossen (2011), Handbook of Marine Craft Hydrodynamics
and Motion Control, Wiley:

* **Reference model** (Fossen 2011, sec. 10.2): per axis a first-order low-pass filter in cascade
  with a mass-damper-spring, i.e. the third-order model

      eta_d''' + (2 zeta + 1) omega eta_d'' + (2 zeta + 1) omega^2 eta_d' + omega^3 eta_d = omega^3 r

  with the velocity saturated at ``max_speed`` (Fossen's saturating element), so that a set-point
  step becomes a smooth, feasible trajectory (position, velocity, acceleration). It is started at
  the first estimate the controller sees; the heading reference takes the short way round.
* **Nonlinear PID** (Fossen 2011, sec. 12.2, PID control for DP, with gains by pole
  placement on the decoupled mass-damper of each axis): with the NED error
  e = eta_hat - eta_d (heading wrapped) and the body velocity error nu_tilde = nu_hat - R(psi)^T eta_d',

      tau = M nu_r' + C(nu_hat_r) nu_hat_r + D(nu_r) nu_r       (model feed-forward)
            - R(psi)^T (K_p e + K_i int e) - K_d nu_tilde        (PID, the integral kept in NED)
            - b_hat                                              (bias feed-forward)

  nu_d = R(psi)^T eta_d' and nu_r = R(psi)^T (eta_d' - V_c) = nu_d - nu_c the reference's velocity
  through the water, V_c the current the estimator's model knows (``[ekf] current``; 0 when unknown:
  the biases carry its force then); nu_r' = R(psi)^T eta_d'' + r_d [v_r, -u_r] (the body turning at
  the reference's yaw rate r_d), with w_r = w_d - V_c,D and r_r = r_d in heave and yaw. D(nu_r) the
  model's linear, quadratic and cubic damping on the reference (at 20 deg/s of turn uDrone's
  quadratic yaw damping alone needs 0.19 N m, which the PID would otherwise meet with a heading
  error). C the rigid-body and added-mass Coriolis-centripetal terms of the plant's model
  (rovlab.models.kinetics; Fossen 2011, sec. 8.3, Property 8.1 for an irrotational current), among
  them the Munk moment (X_udot - Y_vdot) u_r v_r, at the *estimated* velocity through the water
  nu_hat_r = nu_hat - nu_c (and r_hat): C is skew-symmetric, so cancelling it with the estimate takes
  no damping from the loop (the damping stays on the reference, where K_d = 2 zeta omega_n M - D_L
  counts on it), and it cancels the Munk moment's change as the vehicle moves, which an unknown
  current's fast yaw bias did. An estimator told the current takes its drag and Munk moment out of
  its biases, so the controller must feed them forward: without it telling uDrone's EKF the
  current made DP station keeping three to six times worse (issue 28, item 2; docs/dp.md). On the
  reference (nu_hat = nu_d) the wrench is the model's inverse dynamics;
  K_p = M omega_n^2, K_d = 2 zeta omega_n M - D_L, K_i = (omega_n / 10) K_p (the rule of thumb
  K_i ~ omega_n / 10 K_p; ``integral_ratio``). M = diag(m - X_udot, m - Y_vdot, m - Z_wdot,
  I_zz - N_rdot), D_L = -diag(X_u, Y_v, Z_w, N_r). The bias is **subtracted**: it enters the model
  like a force (the thesis's eq. 5.29 has + b_hat, an erratum). Keeping the integral in NED means a
  constant current's force does not have to be re-learnt after every heading change.
* **Anti-windup** by back-calculation (Astrom & Hagglund 2006, Advanced PID Control, sec. 3.5):
  when the allocation achieves tau_a != tau_d (thrusters saturated), the integral moves so the PID
  output approaches what was achieved: int e' = e - (k_t / K_i) R(psi) (tau_a - tau_d),
  k_t = anti_windup * omega_n. Back-calculation holds the integral where the error is constant; a
  current the thrusters cannot hold makes the error grow, and the integral with it. So the
  integral is also clamped: its force K_i int stays within the thrust capacity of its axis
  (:func:`thrust_capacity`: what the allocation gives in that DOF alone; x and y, kept in NED,
  within the most of surge or sway either way), and the state always means a force the thrusters
  could give.

State (logged as ctrl_<name>): the reference model (eta_d, eta_d', eta_d''), the NED integral,
the last NED error and a started flag.

Its table in the design file (read by this module with rovlab.params.validate.TableReader)::

    [dp]                                   # optional: the DP controller (controller = "dp"; rovlab.control.dp)
    source = "..."
    bandwidth = { x = 0.6, y = 0.6, z = 0.6, psi = 1.5 }        # closed-loop omega_n [rad/s]
    damping = 1.0                          # zeta of the pole placement
    integral_ratio = 0.1                   # K_i = ratio * omega_n * K_p
    reference_bandwidth = { x = 0.4, y = 0.4, z = 0.4, psi = 0.5 }   # third-order reference model
    reference_damping = 1.0
    max_speed = { x = 0.15, y = 0.15, z = 0.15, psi_deg_s = 20.0 }  # reference-model speed limits
    anti_windup = 1.0                      # back-calculation gain k_t = anti_windup * omega_n (0 = off)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.allocation.capacity import thrust_capacity
from rovlab.core.angles import wrap_angle
from rovlab.core.components import (
    NAV_BN,
    NAV_BX,
    NAV_BY,
    NAV_BZ,
    NAV_PSI,
    NAV_R,
    NAV_U,
    NAV_V,
    NAV_W,
    NAV_X,
    NAV_Y,
    NAV_Z,
    REF_PSI,
    REFERENCE,
    ComponentInfo,
    ControllerSpec,
    register_component,
    register_controller,
)
from rovlab.models import kinetics as kin
from rovlab.params.design import DesignConfig, per_key
from rovlab.params.validate import ConfigError, Problem, TableReader
from rovlab.params.vehicle import Vehicle

_DEG = math.pi / 180.0
DP_AXES = REFERENCE  # x, y, z, psi: the axes the DP law holds (keys of the [dp] tables)


@dataclass(frozen=True, eq=False)
class DPConfig:
    """The [dp] table: the dynamic-positioning controller (rovlab.control.dp), SI and radians.

    Per axis (x, y, z, psi): closed-loop natural frequency ``bandwidth`` [rad/s] and relative
    damping of the PID pole placement; reference-model natural frequency and speed limit.
    """

    bandwidth: np.ndarray = field(default_factory=lambda: np.array([0.6, 0.6, 0.6, 0.8]))
    damping: float = 1.0
    integral_ratio: float = 0.1  # K_i = integral_ratio * omega_n * K_p (Fossen 2011, sec. 12.2)
    reference_bandwidth: np.ndarray = field(default_factory=lambda: np.array([0.4, 0.4, 0.4, 0.5]))
    reference_damping: float = 1.0
    max_speed: np.ndarray = field(default_factory=lambda: np.array([0.15, 0.15, 0.15, math.radians(20.0)]))
    anti_windup: float = 1.0  # back-calculation gain (times omega_n) when the thrusters saturate; 0 = off
    source: str = "rovlab defaults (rovlab.control.dp.DPConfig)"
    given: bool = False


STATE_NAMES = (
    *(f"{a}_d" for a in DP_AXES), *(f"{a}_d_dot" for a in DP_AXES), *(f"{a}_d_ddot" for a in DP_AXES),
    *(f"int_{a}" for a in DP_AXES), *(f"e_{a}" for a in DP_AXES), "started",
)
_ETA, _VEL, _ACC, _INT, _ERR, _STARTED = 0, 4, 8, 12, 16, 20
_REF_SUBSTEPS = 10  # Euler substeps of the reference model per sample


class DP(NamedTuple):
    """The DP law as a component: gains and model diagonals (4 each, axes x, y, z, psi)."""

    Kp: np.ndarray
    Ki: np.ndarray
    Kd: np.ndarray
    M: np.ndarray  # diagonal inertia (with added mass)
    D: np.ndarray  # diagonal linear damping (positive)
    Dq: np.ndarray  # diagonal quadratic damping (positive)
    Dc: np.ndarray  # diagonal cubic damping (positive)
    rb: np.ndarray  # (5) m, x_g, y_g, X_udot, Y_vdot: the Coriolis-centripetal terms (incl. the Munk moment)
    current: np.ndarray  # (3) the known current in NED [m/s] (the estimator's; 0 = unknown, in the biases)
    int_lo: np.ndarray  # (4) bounds of the integral state: K_i int stays within the thrust capacity
    int_hi: np.ndarray  # (4)
    omega_r: np.ndarray  # reference-model natural frequencies [rad/s]
    zeta_r: float
    v_max: np.ndarray  # reference-model speed limits (m/s, rad/s)
    k_t: np.ndarray  # back-calculation gains [1/s] (0 = off)
    h: float
    state: np.ndarray  # (21): see STATE_NAMES


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def reference_model_step(eta, vel, acc, r, omega, zeta, v_max, h, n_sub):
    """Advance one axis of the third-order reference model over h (n_sub Euler substeps, in place
    on the 1-element views eta, vel, acc) toward the set-point r, speed limited to v_max."""
    dt = h / n_sub
    k = 2.0 * zeta + 1.0
    for _ in range(n_sub):
        jerk = omega ** 3 * (r - eta[0]) - k * omega ** 2 * vel[0] - k * omega * acc[0]
        acc[0] += dt * jerk
        vel[0] += dt * acc[0]
        if vel[0] > v_max:
            vel[0] = v_max
            if acc[0] > 0.0:
                acc[0] = 0.0
        elif vel[0] < -v_max:
            vel[0] = -v_max
            if acc[0] < 0.0:
                acc[0] = 0.0
        eta[0] += dt * vel[0]


@njit(cache=True, inline="always")
def _damping(ctrl, i, v):
    """The model's damping force of axis i at the relative velocity v (feed-forward)."""
    return (ctrl.D[i] + ctrl.Dq[i] * abs(v) + ctrl.Dc[i] * v * v) * v


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _dp_step(ctrl, t, nav, ref, tau):
    s = ctrl.state
    psi = nav[NAV_PSI]
    c, sn = math.cos(psi), math.sin(psi)
    if s[_STARTED] == 0.0:  # start the reference model where the vehicle is
        for i in range(4):
            s[_ETA + i] = nav[i]
            s[_VEL + i] = 0.0
            s[_ACC + i] = 0.0
            s[_INT + i] = 0.0
        s[_STARTED] = 1.0
    # NED errors (heading wrapped) against the reference model's pose (scalars: the closed loop
    # allocates nothing, rovlab.sim.loop.run_loop)
    e0 = nav[NAV_X] - s[_ETA + 0]
    e1 = nav[NAV_Y] - s[_ETA + 1]
    e2 = nav[NAV_Z] - s[_ETA + 2]
    e3 = wrap_angle(nav[NAV_PSI] - s[_ETA + 3])
    s[_ERR + 0] = e0
    s[_ERR + 1] = e1
    s[_ERR + 2] = e2
    s[_ERR + 3] = e3
    # NED force of position and integral terms, and the reference's velocity/acceleration, in body axes
    fx = ctrl.Kp[0] * e0 + ctrl.Ki[0] * s[_INT + 0]
    fy = ctrl.Kp[1] * e1 + ctrl.Ki[1] * s[_INT + 1]
    vx, vy = s[_VEL + 0], s[_VEL + 1]
    ax, ay = s[_ACC + 0], s[_ACC + 1]
    u_d = c * vx + sn * vy
    v_d = -sn * vx + c * vy
    du_d = c * ax + sn * ay
    dv_d = -sn * ax + c * ay
    # the model along the reference, in the velocity relative to the known current (module docstring):
    # nu_r = R^T (eta_d' - V_c), its derivative with the body turning at r_d, Coriolis and damping
    r_d = s[_VEL + 3]
    cur = ctrl.current
    u_r = u_d - (c * cur[0] + sn * cur[1])
    v_r = v_d - (-sn * cur[0] + c * cur[1])
    w_r = s[_VEL + 2] - cur[2]
    # the Coriolis-centripetal terms (the Munk moment among them) at the estimated relative velocity:
    # they do no work (C skew-symmetric), so cancelling them removes no damping (module docstring)
    u_e = nav[NAV_U] - (u_d - u_r)
    v_e = nav[NAV_V] - (v_d - v_r)
    r_e = nav[NAV_R]
    rb = ctrl.rb
    m, x_g, y_g, X_udot, Y_vdot = rb[0], rb[1], rb[2], rb[3], rb[4]
    ff0 = ctrl.M[0] * (du_d + r_d * v_r) - (m * (v_e + x_g * r_e) - Y_vdot * v_e) * r_e + _damping(ctrl, 0, u_r)
    ff1 = ctrl.M[1] * (dv_d - r_d * u_r) + (m * (u_e - y_g * r_e) - X_udot * u_e) * r_e + _damping(ctrl, 1, v_r)
    ff2 = ctrl.M[2] * s[_ACC + 2] + _damping(ctrl, 2, w_r)
    ff3 = (ctrl.M[3] * s[_ACC + 3] + m * r_e * (x_g * u_e + y_g * v_e) + (X_udot - Y_vdot) * u_e * v_e
           + _damping(ctrl, 3, r_d))
    tau[0] = ff0 - (c * fx + sn * fy) - ctrl.Kd[0] * (nav[NAV_U] - u_d) - nav[NAV_BX]
    tau[1] = ff1 - (-sn * fx + c * fy) - ctrl.Kd[1] * (nav[NAV_V] - v_d) - nav[NAV_BY]
    tau[2] = ff2 - ctrl.Kp[2] * e2 - ctrl.Ki[2] * s[_INT + 2] - ctrl.Kd[2] * (nav[NAV_W] - s[_VEL + 2]) - nav[NAV_BZ]
    tau[3] = ff3 - ctrl.Kp[3] * e3 - ctrl.Ki[3] * s[_INT + 3] - ctrl.Kd[3] * (nav[NAV_R] - r_d) - nav[NAV_BN]
    # advance the reference model toward the set-point (heading: the short way round)
    for i in range(4):
        r = ref[i]
        if i == 3:
            r = s[_ETA + 3] + wrap_angle(ref[REF_PSI] - s[_ETA + 3])
        reference_model_step(s[_ETA + i:_ETA + i + 1], s[_VEL + i:_VEL + i + 1], s[_ACC + i:_ACC + i + 1], r,
                             ctrl.omega_r[i], ctrl.zeta_r, ctrl.v_max[i], ctrl.h, _REF_SUBSTEPS)
    s[_ETA + 3] = wrap_angle(s[_ETA + 3])


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _dp_actuated(ctrl, t, tau_demanded, tau_achieved):
    s = ctrl.state
    # the shortfall of the allocation (body) in NED, for the back-calculation
    psi = s[_ETA + 3] + s[_ERR + 3]  # the estimated heading (to one reference-model step)
    c, sn = math.cos(psi), math.sin(psi)
    dx = tau_achieved[0] - tau_demanded[0]
    dy = tau_achieved[1] - tau_demanded[1]
    d = (c * dx - sn * dy, sn * dx + c * dy, tau_achieved[2] - tau_demanded[2], tau_achieved[3] - tau_demanded[3])
    for i in range(4):
        if ctrl.Ki[i] > 0.0:
            # PID output u = -(K_p e + K_i xi): xi' = e - (k_t / K_i) d moves u toward what was achieved
            xi = s[_INT + i] + ctrl.h * (s[_ERR + i] - ctrl.k_t[i] / ctrl.Ki[i] * d[i])
            # and K_i xi no more than the thrusters can give along the axis (module docstring)
            s[_INT + i] = min(max(xi, ctrl.int_lo[i]), ctrl.int_hi[i])


register_controller(DP, state=("state",), step=_dp_step, actuated=_dp_actuated)


@dataclass(frozen=True, eq=False)
class DPDesign:
    """The gains of a DP design and where they came from (for display and tests)."""

    Kp: np.ndarray
    Ki: np.ndarray
    Kd: np.ndarray
    M: np.ndarray
    D: np.ndarray
    config: DPConfig
    tau_min: np.ndarray = field(default_factory=lambda: np.full(4, -np.inf))  # thrust capacity per DOF X, Y, Z, N
    tau_max: np.ndarray = field(default_factory=lambda: np.full(4, np.inf))  # (thrust_capacity) [N, N m]
    current: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the known current (NED) [m/s]

    @property
    def integral_limit(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest, highest) integral state per axis x, y, z, psi [m s, rad s]: its force -K_i int
        within the thrust capacity; x and y (NED, turning with the heading) within the most the
        thrusters give in surge or sway either way, z and psi within their own capacity each way."""
        horizontal = float(np.max(np.abs(np.concatenate([self.tau_min[:2], self.tau_max[:2]]))))
        up = np.array([horizontal, horizontal, -self.tau_min[2], -self.tau_min[3]])  # most force against +int
        down = np.array([horizontal, horizontal, self.tau_max[2], self.tau_max[3]])
        with np.errstate(divide="ignore", invalid="ignore"):
            hi = np.where(self.Ki > 0.0, up / self.Ki, np.inf)
            lo = np.where(self.Ki > 0.0, -down / self.Ki, -np.inf)
        return lo, hi


def known_current(config: DesignConfig) -> np.ndarray:
    """The current the estimator's model knows (NED, m/s): its table's ``current`` (``[ekf]
    current``), else 0. An estimator that models a current takes its drag and Munk moment out of
    its force biases, so the controller has to feed them forward itself."""
    try:
        table = config.table(config.estimator)
    except KeyError:  # an estimator without a table (the depth-and-heading KF)
        return np.zeros(3)
    cur = getattr(table, "current", None)
    if cur is None:
        return np.zeros(3)
    cur = np.asarray(cur, dtype=float).ravel()
    return cur.copy() if cur.shape == (3,) and np.all(np.isfinite(cur)) else np.zeros(3)


def design(vehicle: Vehicle, config: DesignConfig) -> DPDesign:
    """Pole placement per axis (Fossen 2011, sec. 12.2): K_p = M omega_n^2,
    K_d = 2 zeta omega_n M - D, K_i = integral_ratio omega_n K_p. Raises ConfigError when an axis
    would need negative derivative gain (its own damping already exceeds the design's)."""
    dc = config.table("dp")
    M = np.diag(kin.mass_matrix(vehicle)).copy()
    D = -np.asarray(vehicle.damping_linear, dtype=float)
    wn = np.asarray(dc.bandwidth, dtype=float)
    Kp = M * wn ** 2
    Kd = 2.0 * dc.damping * wn * M - D
    Ki = dc.integral_ratio * wn * Kp
    bad = [a for a, k in zip(DP_AXES, Kd) if not k >= 0.0]
    if bad:
        raise ConfigError([Problem(config.file or config.name, "dp.bandwidth", {a: float(w) for a, w in zip(DP_AXES, wn)},
                                   f"a bandwidth for which 2 zeta omega_n M exceeds the vehicle's own damping on "
                                   f"{', '.join(bad)} (raise the bandwidth or the damping)")], "filter configuration")
    tau_min, tau_max = thrust_capacity(vehicle)
    return DPDesign(Kp, Ki, Kd, M, D, dc, tau_min, tau_max, known_current(config))


def build(vehicle: Vehicle, config: DesignConfig) -> ControllerSpec:
    """The DP component of a configuration (raises ConfigError)."""
    d = design(vehicle, config)
    dc = config.table("dp")
    int_lo, int_hi = d.integral_limit
    rb = np.array([vehicle.mass, vehicle.r_g[0], vehicle.r_g[1], vehicle.added_mass[0], vehicle.added_mass[1]],
                  dtype=float)
    kernel = DP(d.Kp, d.Ki, d.Kd, d.M, d.D, -np.asarray(vehicle.damping_quadratic, dtype=float),
                -np.asarray(vehicle.damping_cubic, dtype=float), rb, d.current.copy(), int_lo, int_hi,
                np.array(dc.reference_bandwidth, dtype=float),
                float(dc.reference_damping),
                np.array(dc.max_speed, dtype=float), dc.anti_windup * np.asarray(dc.bandwidth, dtype=float),
                float(config.sample_time), np.zeros(len(STATE_NAMES)))
    return ControllerSpec(kernel=kernel, needs=("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N"),
                          references=DP_AXES, outputs=("X", "Y", "Z", "N"), state_names=STATE_NAMES, model=d)


def summary(d: Any) -> dict[str, Any]:
    """The DP law's gains per axis x, y, z, psi (pole placement, Fossen 2011 sec. 12.2), the
    mass it is placed with, the thrust capacity per DOF X, Y, Z, N [N, N m], the bounds of the
    integral state [m s, rad s] and the known current (NED, m/s) it feeds forward (``rovlab design
    --json``, the HMI)."""
    lo, hi = d.integral_limit
    return {"dp": {"axes": list(DP_AXES), "Kp": np.asarray(d.Kp, dtype=float).tolist(),
                   "Ki": np.asarray(d.Ki, dtype=float).tolist(), "Kd": np.asarray(d.Kd, dtype=float).tolist(),
                   "M": np.asarray(d.M, dtype=float).tolist(),
                   "thrust_min": np.asarray(d.tau_min, dtype=float).tolist(),
                   "thrust_max": np.asarray(d.tau_max, dtype=float).tolist(),
                   "integral_min": [float(v) if np.isfinite(v) else None for v in lo],  # None: no integral
                   "integral_max": [float(v) if np.isfinite(v) else None for v in hi],
                   "known_current": np.asarray(d.current, dtype=float).tolist()}}


def read_dp_table(t: TableReader) -> DPConfig:
    """Read the [dp] table of a design file with the loader's reader (closed schema; every problem collected)."""
    base = DPConfig()
    source = t.string("source")
    axes = ("x", "y", "z", "psi")
    speed_keys = ("x", "y", "z", "psi_deg_s")
    bw = per_key(t, "bandwidth", axes, base.bandwidth, positive=True, what="rad/s")
    zeta = t.number("damping", base.damping, positive=True, hi=10.0, what="relative damping of the closed loop")
    ratio = t.number("integral_ratio", base.integral_ratio, nonnegative=True, hi=1.0,
                     what="K_i = ratio * omega_n * K_p; 0 = no integral action")
    rbw = per_key(t, "reference_bandwidth", axes, base.reference_bandwidth, positive=True, what="rad/s")
    rzeta = t.number("reference_damping", base.reference_damping, positive=True, hi=10.0)
    speed = per_key(t, "max_speed", speed_keys, base.max_speed / np.array([1, 1, 1, _DEG]),
                     factors=(1.0, 1.0, 1.0, _DEG), positive=True, what="m/s, or deg/s for psi_deg_s")
    aw = t.number("anti_windup", base.anti_windup, nonnegative=True, hi=100.0,
                  what="back-calculation gain relative to omega_n; 0 = off")
    t.finish()
    for arr in (bw, rbw, speed):
        arr.setflags(write=False)
    return DPConfig(bandwidth=bw, damping=zeta, integral_ratio=ratio, reference_bandwidth=rbw, reference_damping=rzeta,
                    max_speed=speed, anti_windup=aw, source=source, given=True)


register_component(ComponentInfo(
    "dp", "controller", build,
    description="dynamic positioning x, y, z, psi: reference model and nonlinear PID (Fossen 2011, ch. 12)",
    parse_table=read_dp_table, default_table=DPConfig, summary=lambda spec: summary(spec.model)))
