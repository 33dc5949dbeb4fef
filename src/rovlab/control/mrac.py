"""Model-reference adaptive heave control (MRAC); heading stays on its LQR (Sandøy 2016, sec. 5.2).

Plant (heave row of the process model (Sandøy 2016, ch. 3); z down, SNAME signs; Fossen 2011, ch. 6)::

    M w_dot = Z - D_l w - D_q |w| w + F,      z_dot = w

with M = m - Z_wdot, D_l = -Z_w, D_q = -Z_|w|w and F the net downward force (weight - buoyancy
+ tether pull + slowly varying disturbances). All four are unknown to the controller: theta =
[M, D_l, D_q, F].

**Reference model** (second order, bandwidth omega_m, damping zeta_m) filters the operator's
depth set-point r::

    z_m_ddot = omega_m^2 (r - z_m) - 2 zeta_m omega_m z_m_dot         (- nu_h, see hedging)

i.e. z_m / r = omega_m^2 / (s^2 + 2 zeta_m omega_m s + omega_m^2); it is propagated exactly
between control samples (zero-order hold on r, rovlab.models.discretise.zoh).

**Law** (the direct adaptive tracking controller of Slotine & Li 1991, sec. 8.5, "adaptive
control of nonlinear systems", with the reference model's state as the desired trajectory).
With the tracking error e = z - z_m,
the composite error s = e_dot + lambda e and the reference acceleration a_r = z_m_ddot - lambda
e_dot::

    Z     = Y^T theta_hat - k_s s,          Y = [a_r, w, |w| w, -1]
    theta_hat_dot = -Gamma Y s - sigma (theta_hat - theta_0)          then projection onto the box

Closed loop: M s_dot = -k_s s + Y^T theta_tilde (theta_tilde = theta_hat - theta). With the
Lyapunov function V = M s^2 / 2 + theta_tilde^T Gamma^-1 theta_tilde / 2 and sigma = 0,
V_dot = -k_s s^2 <= 0 for constant theta (Slotine & Li 1991, sec. 8.5, in their notation):
s -> 0, hence e -> 0 (e is s filtered by 1/(p + lambda)), and the estimates stay bounded.

Robustness (Ioannou & Sun 1996, ch. 8, "robust adaptive laws"; Lavretsky & Wise 2013, ch. 11):

* **projection**: after each update the estimates are clipped to the box [lo, hi]. Clipping is
  the Gamma^-1-weighted projection onto the box (Gamma diagonal), so it never increases the
  distance to a true theta inside the box, and V_dot <= -k_s s^2 still holds; the estimates can
  never leave the box whatever the disturbance (tested).
* **sigma-modification** (optional): leakage towards theta_0 (Ioannou & Kokotovic 1983).
* **hedging** (Johnson & Calise 2002, pseudo-control hedging): when the allocation cannot give
  the demanded heave force, the reference model is slowed by what was missing, nu_h =
  (Z_demanded - Z_achieved) / M_hat, so the adaptation does not learn from the saturation.

Sampled implementation: the loop calls :func:`_mrac_step` at t_k with the *estimate* (z, w from
the Kalman filter, not the truth) and :func:`_mrac_actuated` after the allocation; the law is
evaluated at t_k and held (zero-order hold), the adaptation is integrated with one Euler step of
h, the reference model exactly. On a continuous-time plant the sampled law is therefore exact
only as h -> 0 (O(h) sampling error); the continuous law itself tracks the reference model
exactly when theta_hat = theta (tested on the model to integrator precision).

Kernels: @njit(cache=True, inline="always"), nothing allocated per step (work arrays live in
the component).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.control.lqg import (  # the reference model is shared with the LQG's optional one
    lqg_tau,
    lqr_lines,
    lqr_summary,
    reference_accel,
    reference_model,
)
from rovlab.control.lqr import LQRDesign, design_lqr_from_config
from rovlab.core.components import (
    NAV_BN,
    NAV_BZ,
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
from rovlab.core.summary import render
from rovlab.models.discretise import zoh
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem, TableReader
from rovlab.params.vehicle import Vehicle

MRAC_PARAMETERS = ("M", "D_l", "D_q", "F")  # heave mass, linear and quadratic damping, net down force


@dataclass(frozen=True)
class MRACConfig:
    """The [mrac] table: reference model, adaptation gains and the projection set (SI units).

    ``initial`` and ``bounds`` hold only what the file gives; the rest is filled from the model
    by rovlab.control.mrac (which also checks that the initial estimates lie in the bounds).
    """

    bandwidth: float = 0.6  # omega_m [rad/s]
    damping: float = 1.0  # zeta_m
    max_step: float = 0.5  # [m]
    lam: float = 2.0  # lambda [1/s]
    k_s: float = 80.0  # [N s/m]
    sigma: float = 0.0  # [1/s]
    hedge: bool = True
    gain: Mapping[str, float] = field(default_factory=lambda: {"M": 50.0, "D_l": 50.0, "D_q": 50.0, "F": 300.0})
    initial: Mapping[str, float] = field(default_factory=dict)
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    source: str = "rovlab defaults, tuned in simulation on the heave-* scenarios (rovlab.control.mrac)"
    given: bool = False  # the file had an [mrac] table


STATE_NAMES = ("M_hat", "D_l_hat", "D_q_hat", "F_hat", "z_m", "w_m")  # log columns ctrl_<name>
PARAMETERS = MRAC_PARAMETERS  # theta = [M, D_l, D_q, F]
UNITS = {"M": "kg", "D_l": "N s/m", "D_q": "N s^2/m^2", "F": "N"}
_IZM, _IWM = 4, 5  # z_m, w_m in the state array


# --------------------------------------------------------------------------------------------
# The law and the adaptation (compiled; also callable from Python for tests)
# --------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def heave_law(theta, z, w, zm, wm, am, lam, k_s, Y):
    """Z = Y^T theta - k_s s for the reference state (zm, wm, am); fills the regressor Y (4).
    Returns (Z, s)."""
    ed = w - wm
    s = ed + lam * (z - zm)
    Y[0] = am - lam * ed  # a_r
    Y[1] = w
    Y[2] = abs(w) * w
    Y[3] = -1.0
    tau = theta[0] * Y[0] + theta[1] * Y[1] + theta[2] * Y[2] + theta[3] * Y[3] - k_s * s
    return tau, s


@njit(cache=True, inline="always")
def adapt(theta, Y, s, gamma, sigma, theta0, lo, hi, h):
    """One Euler step of theta_dot = -Gamma Y s - sigma (theta - theta0), then projection onto
    the box [lo, hi] (in place)."""
    for i in range(gamma.shape[0]):  # theta may be longer (the component's state array)
        v = theta[i] - h * (gamma[i] * Y[i] * s + sigma * (theta[i] - theta0[i]))
        if v < lo[i]:
            v = lo[i]
        elif v > hi[i]:
            v = hi[i]
        theta[i] = v


# --------------------------------------------------------------------------------------------
# The component
# --------------------------------------------------------------------------------------------

class MRAC(NamedTuple):
    """MRAC in heave + LQR in heading (controller slot). state = [theta_hat (4), z_m, w_m]."""

    K: np.ndarray  # 2 x 4 LQR (only the heading row is used)
    P: np.ndarray  # 2 x 2
    Phi_m: np.ndarray  # (2, 2) reference model over one sample
    G_m: np.ndarray  # (2, 2) its inputs [r, nu_h]
    gamma: np.ndarray  # (4) adaptation gains (Gamma diagonal)
    theta0: np.ndarray  # (4) initial estimates (and the sigma-modification's anchor)
    lo: np.ndarray  # (4) projection box
    hi: np.ndarray  # (4)
    om2: float  # omega_m^2
    c1: float  # 2 zeta_m omega_m
    lam: float
    k_s: float
    sigma: float
    hedge: float  # 1.0: hedge the reference model, 0.0: do not
    h: float  # sample time [s]
    x6: np.ndarray  # (6) work: [z, psi, w, r, b_Z, b_N]
    r2: np.ndarray  # (2) work: references
    u2: np.ndarray  # (2) work: LQG [Z, N]
    Y: np.ndarray  # (4) work: regressor of this sample
    mem: np.ndarray  # (2) work: [depth reference, s] of this sample
    state: np.ndarray  # (6): M_hat, D_l_hat, D_q_hat, F_hat, z_m, w_m
    started: np.ndarray  # (1): 0 until the reference model has been set to the first estimate


_FROM_NAV = (NAV_Z, NAV_PSI, NAV_W, NAV_R, NAV_BZ, NAV_BN)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _mrac_step(ctrl, t, nav, ref, tau):
    st = ctrl.state
    z = nav[NAV_Z]
    w = nav[NAV_W]
    if ctrl.started[0] == 0.0:  # the reference model starts where the vehicle is
        st[_IZM] = z
        st[_IWM] = w
        ctrl.started[0] = 1.0
    r = ref[REF_Z]
    am = reference_accel(st[_IZM], st[_IWM], r, ctrl.om2, ctrl.c1)
    Z, s = heave_law(st, z, w, st[_IZM], st[_IWM], am, ctrl.lam, ctrl.k_s, ctrl.Y)
    ctrl.mem[0] = r
    ctrl.mem[1] = s
    # heading: the LQG law's heading row (its heave row is not used)
    for i in range(6):
        ctrl.x6[i] = nav[_FROM_NAV[i]]
    ctrl.r2[0] = r
    ctrl.r2[1] = ref[REF_PSI]
    lqg_tau(ctrl.K, ctrl.P, ctrl.x6, ctrl.r2, ctrl.u2)
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = Z
    tau[3] = ctrl.u2[1]


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _mrac_actuated(ctrl, t, tau_demanded, tau_achieved):
    st = ctrl.state
    adapt(st, ctrl.Y, ctrl.mem[1], ctrl.gamma, ctrl.sigma, ctrl.theta0, ctrl.lo, ctrl.hi, ctrl.h)
    nu_h = ctrl.hedge * (tau_demanded[2] - tau_achieved[2]) / st[0]
    zm, wm = st[_IZM], st[_IWM]
    r = ctrl.mem[0]
    st[_IZM] = ctrl.Phi_m[0, 0] * zm + ctrl.Phi_m[0, 1] * wm + ctrl.G_m[0, 0] * r + ctrl.G_m[0, 1] * nu_h
    st[_IWM] = ctrl.Phi_m[1, 0] * zm + ctrl.Phi_m[1, 1] * wm + ctrl.G_m[1, 0] * r + ctrl.G_m[1, 1] * nu_h


register_controller(MRAC, state=("state", "started"), step=_mrac_step, actuated=_mrac_actuated)


# --------------------------------------------------------------------------------------------
# Design
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class MRACDesign:
    """What build() decided: the heading LQR, the reference model and the adaptation set-up."""

    lqr: LQRDesign
    config: MRACConfig
    h: float
    theta0: np.ndarray  # [M, D_l, D_q, F]
    lo: np.ndarray
    hi: np.ndarray
    gamma: np.ndarray
    Phi_m: np.ndarray
    G_m: np.ndarray
    sampled_radius: float  # spectral radius of the nominal sampled error loop (< 1)
    heave_force_needed: tuple[float, float]  # (down, up) [N] for a max_step step each way, holding F
    file: str = ""

    @property
    def K(self) -> np.ndarray:
        return self.lqr.K

    @property
    def P(self) -> np.ndarray:
        return self.lqr.P

    def summary(self) -> dict:
        c = self.config
        return {
            "bandwidth": c.bandwidth, "damping": c.damping, "max_step": c.max_step, "lambda": c.lam, "k_s": c.k_s,
            "sigma": c.sigma, "hedge": c.hedge, "sampled_radius": self.sampled_radius,
            "parameters": list(PARAMETERS), "units": [UNITS[p] for p in PARAMETERS],
            "initial": self.theta0.tolist(), "lower": self.lo.tolist(), "upper": self.hi.tolist(),
            "gain": self.gamma.tolist(),
            "heave_force_needed": [float(f) for f in self.heave_force_needed],
        }


def model_parameters(vehicle: Vehicle, config: DesignConfig) -> np.ndarray:
    """theta of the model: [m - Z_wdot, -Z_w, -Z_|w|w, W - B] (configuration overrides first)."""
    mv = config.model_values(vehicle)
    return np.array([mv["m"] - mv["Z_wdot"], -mv["Z_w"], -float(vehicle.damping_quadratic[2]),
                     vehicle.weight - vehicle.buoyancy])


def default_bounds(theta0: np.ndarray, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """The projection box when the file gives none (assumption, wide on purpose: it must hold every
    plausible truth): M in [M0/4, 4 M0]; D_l, D_q in [0, 5 D + 10]; F in F0 +- W/2 (half the
    vehicle's weight of payload or buoyancy change)."""
    M0, Dl0, Dq0, F0 = theta0
    lo = np.array([0.25 * M0, 0.0, 0.0, F0 - 0.5 * weight])
    hi = np.array([4.0 * M0, 5.0 * Dl0 + 10.0, 5.0 * Dq0 + 10.0, F0 + 0.5 * weight])
    return lo, hi


def design_mrac(vehicle: Vehicle, config: DesignConfig) -> MRACDesign:
    """Check the [mrac] table against the model and design the reference model (ConfigError)."""
    c = config.table("mrac")
    where = config.file or config.name
    h = float(config.sample_time)
    problems: list[Problem] = []
    model = model_parameters(vehicle, config)
    theta0 = np.array([c.initial.get(p, model[i]) for i, p in enumerate(PARAMETERS)], dtype=float)
    lo, hi = default_bounds(model, vehicle.weight)
    for i, p in enumerate(PARAMETERS):
        if p in c.bounds:
            lo[i], hi[i] = c.bounds[p]
    for i, p in enumerate(PARAMETERS):
        if not lo[i] <= theta0[i] <= hi[i]:
            key = f"mrac.initial.{p}" if p in c.initial else f"mrac.bounds.{p}"
            problems.append(Problem(where, key, float(theta0[i]) if p in c.initial else [lo[i], hi[i]],
                                    f"an initial {p} inside the projection bounds [{lo[i]:g}, {hi[i]:g}] "
                                    f"(initial {theta0[i]:g} {UNITS[p]})"))
    gamma = np.array([c.gain[p] for p in PARAMETERS], dtype=float)
    if c.sigma * h >= 1.0:
        problems.append(Problem(where, "mrac.sigma", c.sigma, f"sigma * sample_time < 1 (h = {h:g} s)"))
    # the sampled error loop (Z = -k_s (e_dot + lambda e) with the true model, zero-order hold at h)
    # must be stable for the nominal mass and the smallest mass the projection allows
    radius = 0.0
    for M in (theta0[0], lo[0]):
        A = np.array([[0.0, 1.0], [0.0, -theta0[1] / M]])
        B = np.array([[0.0], [1.0 / M]])
        Phi, Delta = zoh(A, B, h)
        rho = float(np.max(np.abs(np.linalg.eigvals(Phi - Delta @ np.array([[c.k_s * c.lam, c.k_s]])))))
        radius = max(radius, rho)
    if not radius < 1.0:
        problems.append(Problem(where, "mrac.k_s", c.k_s,
                                f"a feedback gain for which the loop sampled at h = {h:g} s is stable for M "
                                f"from {lo[0]:g} to {theta0[0]:g} kg (spectral radius {radius:.3f} >= 1); "
                                "lower k_s or lambda, or raise the lower bound of M"))
    if problems:
        raise ConfigError(problems, "filter configuration")
    A_m, B_m = reference_model(c.bandwidth, c.damping)
    Phi_m, G_m = zoh(A_m, B_m, h)
    need = heave_force_needed(theta0, c.bandwidth, c.damping, c.max_step)
    lqr = design_lqr_from_config(vehicle, config)
    return MRACDesign(lqr, c, h, theta0, lo, hi, gamma, np.ascontiguousarray(Phi_m), np.ascontiguousarray(G_m),
                      radius, need, where)


def equivalent_gains(design: MRACDesign) -> dict[str, Any]:
    """The heave law as a PID on e = z - z_m, linearised at rest (reference model still, w = 0,
    theta_hat = theta_0): what a fixed-gain controller must match to be as stiff (rovlab compare).

    With a_r = -lambda w and F_hat = Gamma_F * integral of s (the F row of the adaptation,
    Y_F = -1), Z = -(lambda k_s + Gamma_F) e - (k_s + lambda M_0 - D_l0) w - lambda Gamma_F * integral of e:

    * ``K_z`` = lambda k_s, ``K_w`` = k_s + lambda M_0 - D_l0: the state feedback without the
      adaptation (an LQR's K on [z, w]); the closed loop's damping is K_w + D_l = k_s + lambda M;
    * ``K_p`` = K_z + Gamma_F, ``K_i`` = lambda Gamma_F: with the adapted net force, which acts as
      a PI on s. On the true model (theta_hat = theta) the closed loop is
      (s + lambda)(M s^2 + k_s s + Gamma_F): the poles of ``poles``.
    """
    c = design.config
    M0, Dl0 = float(design.theta0[0]), float(design.theta0[1])
    gF = float(design.gamma[3])
    Kz = c.lam * c.k_s
    Kw = c.k_s + c.lam * M0 - Dl0
    roots = np.roots([M0, c.k_s, gF]) if gF > 0 else np.array([-c.k_s / M0, 0.0])
    return {"K_z": Kz, "K_w": Kw, "K_p": Kz + gF, "K_d": Kw, "K_i": c.lam * gF, "M_0": M0, "D_l0": Dl0,
            "Gamma_F": gF, "poles": sorted([complex(-c.lam), *(complex(r) for r in roots)], key=lambda z: -z.real)}


def heave_force_needed(theta: np.ndarray, omega: float, zeta: float, step: float) -> tuple[float, float]:
    """(largest downward, largest upward) heave force [N] that following the reference model's
    response to a depth step of +-step takes on the model theta = [M, D_l, D_q, F], holding F."""
    A_m, B_m = reference_model(omega, zeta)
    dt = min(0.01, 0.05 / omega)
    Phi, G = zoh(A_m, B_m, dt)
    n = int(math.ceil(12.0 / (zeta * omega) / dt)) if zeta < 1 else int(math.ceil(12.0 * zeta / omega / dt))
    M, Dl, Dq, F = theta
    out = []
    for sign in (1.0, -1.0):
        x = np.zeros(2)
        extreme = 0.0
        for _ in range(min(n, 200000)):
            a = omega**2 * (sign * step - x[0]) - 2.0 * zeta * omega * x[1]
            f = M * a + Dl * x[1] + Dq * abs(x[1]) * x[1]
            extreme = max(extreme, sign * f)
            x = Phi @ x + G[:, 0] * sign * step
        out.append(float(sign * extreme - F))
    return out[0], out[1]


def build(vehicle: Vehicle, config: DesignConfig) -> ControllerSpec:
    """MRAC in heave with the configuration's [mrac] table, LQR in heading (raises ConfigError)."""
    d = design_mrac(vehicle, config)
    c = d.config
    state = np.concatenate([d.theta0, [0.0, 0.0]])
    kernel = MRAC(np.ascontiguousarray(d.lqr.K, dtype=float), np.ascontiguousarray(d.lqr.P, dtype=float),
                  d.Phi_m, d.G_m, d.gamma, d.theta0.copy(), d.lo, d.hi, float(c.bandwidth**2),
                  float(2.0 * c.damping * c.bandwidth), float(c.lam), float(c.k_s), float(c.sigma),
                  1.0 if c.hedge else 0.0, d.h, np.zeros(6), np.zeros(2), np.zeros(2), np.zeros(4), np.zeros(2),
                  state, np.zeros(1))
    return ControllerSpec(kernel=kernel, needs=("z", "psi", "w", "r", "b_N"), references=("z", "psi"),
                          outputs=("Z", "N"), state_names=STATE_NAMES, model=d)


def read_mrac_table(t: TableReader) -> MRACConfig:
    """Read the [mrac] table of a design file with the loader's reader (closed schema; every problem collected)."""
    base = MRACConfig()
    source = t.string("source")
    omega = t.number("bandwidth", base.bandwidth, positive=True, hi=100.0, what="omega_m of the reference model in rad/s")
    zeta = t.number("damping", base.damping, positive=True, hi=10.0, what="zeta_m of the reference model")
    step = t.number("max_step", base.max_step, positive=True, what="depth step in m the thrusters must manage")
    lam = t.number("lambda", base.lam, positive=True, what="1/s, in s = e_dot + lambda e")
    k_s = t.number("k_s", base.k_s, positive=True, what="N s/m, feedback on s")
    sigma = t.number("sigma", base.sigma, nonnegative=True, what="1/s, sigma-modification; 0 = off")
    hedge = t.boolean("hedge", base.hedge)
    gain = dict(base.gain)
    g = t.table("gain", required=False)
    for key in MRAC_PARAMETERS:
        if g.has(key):
            gain[key] = g.number(key, nonnegative=True, what="adaptation gain; 0 freezes the parameter")
    g.finish()
    initial: dict[str, float] = {}
    it = t.table("initial", required=False)
    for key in MRAC_PARAMETERS:
        if it.has(key):
            initial[key] = it.number(key, positive=key == "M", nonnegative=key in ("D_l", "D_q"),
                                     what={"M": "kg", "D_l": "N s/m", "D_q": "N s^2/m^2", "F": "N, down"}[key])
    it.finish()
    bounds: dict[str, tuple[float, float]] = {}
    bt = t.table("bounds", required=False)
    for key in MRAC_PARAMETERS:
        if bt.has(key):
            lo, hi = bt.vector(key, 2, what="[lowest, highest]")
            if np.all(np.isfinite([lo, hi])):
                floor = 0.0 if key != "F" else -math.inf
                if not lo < hi:
                    bt.problem(key, [lo, hi], "[lowest, highest] with lowest < highest")
                elif lo < floor or (key == "M" and lo <= 0.0):
                    bt.problem(key, [lo, hi], "a positive lower bound for M, >= 0 for D_l and D_q")
                else:
                    bounds[key] = (float(lo), float(hi))
    bt.finish()
    t.finish()
    return MRACConfig(bandwidth=omega, damping=zeta, max_step=step, lam=lam, k_s=k_s, sigma=sigma, hedge=hedge,
                      gain=gain, initial=initial, bounds=bounds, source=source, given=True)


def check_heave_capacity(spec: ControllerSpec, alloc: Any, where: str) -> None:
    """The heave force the reference model takes (``heave_force_needed`` = (down, up) [N]) must come
    from the thrusters (allocation with K = M = 0); ConfigError naming the [mrac] keys otherwise."""
    down, up = (float(f) for f in spec.model.heave_force_needed)
    down_cap = float(alloc.allocate(np.array([0.0, 0.0, 1e6, 0.0])).achieved[2])
    up_cap = float(alloc.allocate(np.array([0.0, 0.0, -1e6, 0.0])).achieved[2])
    if down > down_cap or up < up_cap:
        cfg = spec.model.config
        raise ConfigError([Problem(where, "mrac.bandwidth", cfg.bandwidth,
                                   f"a reference model the thrusters can follow: a {cfg.max_step:g} m depth step "
                                   f"(mrac.max_step) with bandwidth {cfg.bandwidth:g} rad/s and damping "
                                   f"{cfg.damping:g} takes {down:.1f} N down / {up:.1f} N on the model (holding its "
                                   f"net weight), the thrusters give {down_cap:.1f} N down / {up_cap:.1f} N; lower "
                                   "the bandwidth or max_step")], "filter configuration")


register_component(ComponentInfo(
    "mrac", "controller", build,
    description="model-reference adaptive heave control with LQR heading (Sandøy 2016, thesis description, task 7)",
    parse_table=read_mrac_table, default_table=MRACConfig, check=check_heave_capacity,
    summary=lambda spec: {**lqr_summary(spec.model.lqr), "mrac": spec.model.summary()},
    describe=lambda spec: ["  heave: MRAC (the heading on the LQR's row N)", *render({"mrac": spec.model.summary()}),
                           *lqr_lines(spec.model.lqr)]))
