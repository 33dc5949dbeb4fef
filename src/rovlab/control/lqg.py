"""The LQG control law and the thruster mapping behind it (Sandøy 2016, ch. 2 and sec. 5.2).

With the Kalman estimate x_hat = [z, psi, w, r, b_w, b_r] and references r = [z_ref, psi_ref]:

    tau = P r - K [z, psi', w, r] - [b_w, b_r]

* the bias estimate is **subtracted**: in the model the bias enters like a force
  (M nu_dot = ... + tau + b), so tau = ... - b_hat cancels it (rovlab's correction of the thesis: its
  eq. 5.29 adds it);
* the heading error is wrapped: psi' = psi_ref - wrap(psi_ref - psi_hat) is the heading
  equivalent to psi_hat (modulo 2 pi) nearest to the reference, so a vehicle at 179 deg told to
  go to -179 deg turns 2 deg, not 358 deg. With P_psi = K_psi (true for this model, see
  rovlab.control.lqr) the heading term is K_psi wrap(psi_ref - psi_hat).

**Depth reference model** (optional, the ``[lqg]`` table; off in the thesis): the depth set-point
goes through the second-order reference model MRAC follows (rovlab.control.mrac; bandwidth
omega_m, damping zeta_m, started at the first estimate, propagated exactly between samples), and
the law follows its state with the model's force to do so (a two-degree-of-freedom LQ servo)::

    Z = P_z z_m - K [z, psi', w - w_m, r] - b_w  +  M z_m_ddot + D w_m       (M = m - Z_wdot, D = -Z_w)

At rest (z_m = r, w_m = 0) this is the law above; it only shapes how a set-point change is
followed, so that a stiff LQR is not asked to jump a step (rovlab compare's ``lqg-matched``).

:func:`lqg_tau` is a numba kernel for the simulator's compiled loop::

    lqg_tau(K (2 x 4), P (2 x 2), x_hat (6), ref (2), tau_out (2)) -> None

:func:`tau_to_wrench` turns tau = [Z, N] into the 4-DOF wrench [0, 0, Z, N] (X = Y = 0; the
allocation demands K = M = 0). The thruster mapping behind the law, which composes it with the
saturation-aware allocation, is :class:`rovlab.sim.autopilot.ThrusterMapping` (control and
allocation are sibling layers and do not import each other).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.control.lqr import LQRDesign, design_lqr_from_config
from rovlab.core.angles import wrap_angle
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
from rovlab.params.vehicle import Vehicle

if TYPE_CHECKING:
    from rovlab.params.validate import TableReader


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def lqg_tau(K, P, x_hat, ref, tau):
    psi_eq = ref[1] - wrap_angle(ref[1] - x_hat[1])
    for i in range(2):
        acc = P[i, 0] * ref[0] + P[i, 1] * ref[1]
        acc -= K[i, 0] * x_hat[0] + K[i, 1] * psi_eq + K[i, 2] * x_hat[2] + K[i, 3] * x_hat[3]
        tau[i] = acc - x_hat[4 + i]


@dataclass(frozen=True, eq=False)
class LQGController:
    """tau = P r - K [eta_hat; nu_hat] - b_hat for the depth-and-heading filter's estimate."""

    K: np.ndarray  # 2 x 4
    P: np.ndarray  # 2 x 2

    @classmethod
    def from_design(cls, design: LQRDesign) -> LQGController:
        return cls(K=np.ascontiguousarray(design.K), P=np.ascontiguousarray(design.P))

    def tau(self, x_hat: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """[Z, N] for an estimate x_hat (6) and references [z_ref, psi_ref] (SI, radians)."""
        x = np.ascontiguousarray(x_hat, dtype=float)
        r = np.ascontiguousarray(ref, dtype=float)
        if x.shape != (6,) or r.shape != (2,):
            raise ValueError(f"x_hat must have 6 entries and ref 2, got {x.shape} and {r.shape}")
        out = np.empty(2)
        lqg_tau(self.K, self.P, x, r, out)
        return out


@njit(cache=True, inline="always")
def reference_accel(zm, wm, r, om2, c1):
    """z_m_ddot = omega^2 (r - z_m) - 2 zeta omega w_m (c1 = 2 zeta omega) of the depth reference model."""
    return om2 * (r - zm) - c1 * wm


def reference_model(omega: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_m, B_m) of the depth reference model z_m / r = omega^2 / (s^2 + 2 zeta omega s + omega^2),
    state [z_m, w_m], inputs [r, nu_h] (nu_h: MRAC's hedging signal, rovlab.control.mrac)."""
    A = np.array([[0.0, 1.0], [-omega**2, -2.0 * zeta * omega]])
    B = np.array([[0.0, 0.0], [omega**2, -1.0]])
    return A, B


class LQG(NamedTuple):
    """The LQG law as a closed-loop component (controller slot). Its state is the depth
    reference model's [z_m, w_m] when the [lqg] table asks for one, else empty."""

    K: np.ndarray  # 2 x 4
    P: np.ndarray  # 2 x 2
    x6: np.ndarray  # (6) work: [z, psi, w, r, b_Z, b_N] gathered from the estimate
    r2: np.ndarray  # (2) work: [z_ref, psi_ref]
    u2: np.ndarray  # (2) work: [Z, N]
    Phi_m: np.ndarray  # (2, 2) reference model over one sample (identity without one)
    G_m: np.ndarray  # (2, 2) its inputs [r, nu_h] (only r is used here)
    ff: np.ndarray  # (2) feed-forward model [M, D]: Z_ff = M z_m_ddot + D w_m
    om2: float  # omega_m^2
    c1: float  # 2 zeta_m omega_m
    follow: float  # 1.0: the depth set-point goes through the reference model; 0.0: straight in (thesis)
    state: np.ndarray  # (2) [z_m, w_m] with a reference model, else (0)
    started: np.ndarray  # (1): 0 until the reference model has been set to the first estimate


_FROM_NAV = (NAV_Z, NAV_PSI, NAV_W, NAV_R, NAV_BZ, NAV_BN)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _lqg_step(ctrl, t, nav, ref, tau):
    for i in range(6):
        ctrl.x6[i] = nav[_FROM_NAV[i]]
    ctrl.r2[0] = ref[REF_Z]
    ctrl.r2[1] = ref[REF_PSI]
    ff = 0.0
    if ctrl.follow != 0.0:
        st = ctrl.state
        if ctrl.started[0] == 0.0:  # the reference model starts where the vehicle is
            st[0] = nav[NAV_Z]
            st[1] = nav[NAV_W]
            ctrl.started[0] = 1.0
        zm = st[0]
        wm = st[1]
        r = ref[REF_Z]
        ff = ctrl.ff[0] * reference_accel(zm, wm, r, ctrl.om2, ctrl.c1) + ctrl.ff[1] * wm
        ctrl.r2[0] = zm
        ctrl.x6[2] -= wm
        st[0] = ctrl.Phi_m[0, 0] * zm + ctrl.Phi_m[0, 1] * wm + ctrl.G_m[0, 0] * r
        st[1] = ctrl.Phi_m[1, 0] * zm + ctrl.Phi_m[1, 1] * wm + ctrl.G_m[1, 0] * r
    lqg_tau(ctrl.K, ctrl.P, ctrl.x6, ctrl.r2, ctrl.u2)
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = ctrl.u2[0] + ff
    tau[3] = ctrl.u2[1]


register_controller(LQG, state=("state", "started"), step=_lqg_step)


@dataclass(frozen=True)
class LQGConfig:
    """The [lqg] table (optional; without it the thesis law: the set-point goes straight in)."""

    reference_model: bool = False  # the depth set-point through a second-order reference model
    bandwidth: float = 0.6  # omega_m [rad/s] (MRAC's default, rovlab.control.mrac)
    damping: float = 1.0  # zeta_m
    source: str = "rovlab default: no reference model (Sandøy 2016, sec. 5.2)"
    given: bool = False


def read_lqg_table(t: TableReader) -> LQGConfig:
    """Read the [lqg] table of a design file with the loader's reader (closed schema)."""
    base = LQGConfig()
    source = t.string("source")
    on = t.boolean("reference_model", base.reference_model)
    omega = t.number("bandwidth", base.bandwidth, positive=True, hi=100.0, what="omega_m of the reference model in rad/s")
    zeta = t.number("damping", base.damping, positive=True, hi=10.0, what="zeta_m of the reference model")
    t.finish()
    return LQGConfig(reference_model=on, bandwidth=omega, damping=zeta, source=source, given=True)


def build(vehicle: Vehicle, config: DesignConfig) -> ControllerSpec:
    """Design the LQR of a configuration and wrap it as the LQG component (raises ConfigError)."""
    design = design_lqr_from_config(vehicle, config)
    c: LQGConfig = config.table("lqg")
    names: tuple[str, ...]
    if c.reference_model:
        A_m, B_m = reference_model(c.bandwidth, c.damping)
        Phi_m, G_m = zoh(A_m, B_m, float(config.sample_time))
        mv = config.model_values(vehicle)
        ff = np.array([mv["m"] - mv["Z_wdot"], -mv["Z_w"]])
        om2, c1, follow, state, names = c.bandwidth**2, 2.0 * c.damping * c.bandwidth, 1.0, np.zeros(2), ("z_m", "w_m")
    else:
        Phi_m, G_m, ff = np.eye(2), np.zeros((2, 2)), np.zeros(2)
        om2, c1, follow, state, names = 0.0, 0.0, 0.0, np.zeros(0), ()
    kernel = LQG(np.ascontiguousarray(design.K, dtype=float), np.ascontiguousarray(design.P, dtype=float),
                 np.zeros(6), np.zeros(2), np.zeros(2), np.ascontiguousarray(Phi_m), np.ascontiguousarray(G_m), ff,
                 float(om2), float(c1), follow, state, np.zeros(1))
    return ControllerSpec(kernel=kernel, needs=("z", "psi", "w", "r", "b_Z", "b_N"), references=("z", "psi"),
                          outputs=("Z", "N"), state_names=names, model=design)


def tau_to_wrench(tau: np.ndarray) -> np.ndarray:
    """The 4-DOF wrench [X, Y, Z, N] = [0, 0, Z, N] of a depth-and-heading demand [Z, N]."""
    Z, N = np.asarray(tau, dtype=float).ravel()
    return np.array([0.0, 0.0, Z, N])


def lqr_summary(design: LQRDesign) -> dict[str, Any]:
    """The LQR of a design (the keys K, P, lqr of ``rovlab design --json``)."""
    return {"K": design.K.tolist(), "P": design.P.tolist(),
            "lqr": {"states": ["z", "psi", "w", "r"], "Q": np.diag(design.Q).tolist(), "R": np.diag(design.R).tolist(),
                    "reference_gain": design.reference,
                    "closed_loop_poles_abs": np.abs(design.poles).tolist()}}


def lqr_lines(design: LQRDesign) -> list[str]:
    """The LQR for people (``rovlab design``)."""
    return [*render({"K (LQR) on [z, psi, w, r]": design.K}),
            *render({f"P (reference gain, {design.reference})": design.P}),
            f"  |closed-loop poles| = {', '.join(f'{a:.4f}' for a in np.abs(design.poles))}"]


def _reference_summary(kernel: LQG) -> dict[str, Any]:
    if kernel.follow == 0.0:
        return {}
    omega = float(np.sqrt(kernel.om2))
    return {"reference_model": {"bandwidth": omega, "damping": float(kernel.c1 / (2.0 * omega)),
                                "feedforward_M": float(kernel.ff[0]), "feedforward_D": float(kernel.ff[1])}}


register_component(ComponentInfo(
    "lqg", "controller", build,
    description="LQR depth and heading with the filter's bias estimate fed forward (Sandøy 2016, sec. 5.2)",
    parse_table=read_lqg_table, default_table=LQGConfig,
    summary=lambda spec: {**lqr_summary(spec.model), **_reference_summary(spec.kernel)},
    describe=lambda spec: [*lqr_lines(spec.model), *render(_reference_summary(spec.kernel))]))
