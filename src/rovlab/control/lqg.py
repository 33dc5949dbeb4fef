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

:func:`lqg_tau` is a numba kernel for the simulator's compiled loop::

    lqg_tau(K (2 x 4), P (2 x 2), x_hat (6), ref (2), tau_out (2)) -> None

:func:`tau_to_wrench` turns tau = [Z, N] into the 4-DOF wrench [0, 0, Z, N] (X = Y = 0; the
allocation demands K = M = 0). The thruster mapping behind the law, which composes it with the
saturation-aware allocation, is :class:`rovlab.sim.autopilot.ThrusterMapping` (control and
allocation are sibling layers and do not import each other).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

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
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle


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


class LQG(NamedTuple):
    """The LQG law as a closed-loop component (controller slot): no state of its own."""

    K: np.ndarray  # 2 x 4
    P: np.ndarray  # 2 x 2
    x6: np.ndarray  # (6) work: [z, psi, w, r, b_Z, b_N] gathered from the estimate
    r2: np.ndarray  # (2) work: [z_ref, psi_ref]
    u2: np.ndarray  # (2) work: [Z, N]
    state: np.ndarray  # (0)


_FROM_NAV = (NAV_Z, NAV_PSI, NAV_W, NAV_R, NAV_BZ, NAV_BN)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _lqg_step(ctrl, t, nav, ref, tau):
    for i in range(6):
        ctrl.x6[i] = nav[_FROM_NAV[i]]
    ctrl.r2[0] = ref[REF_Z]
    ctrl.r2[1] = ref[REF_PSI]
    lqg_tau(ctrl.K, ctrl.P, ctrl.x6, ctrl.r2, ctrl.u2)
    tau[0] = 0.0
    tau[1] = 0.0
    tau[2] = ctrl.u2[0]
    tau[3] = ctrl.u2[1]


register_controller(LQG, state=("state",), step=_lqg_step)


def build(vehicle: Vehicle, config: DesignConfig) -> ControllerSpec:
    """Design the LQR of a configuration and wrap it as the LQG component (raises ConfigError)."""
    design = design_lqr_from_config(vehicle, config)
    kernel = LQG(np.ascontiguousarray(design.K, dtype=float), np.ascontiguousarray(design.P, dtype=float),
                 np.zeros(6), np.zeros(2), np.zeros(2), np.zeros(0))
    return ControllerSpec(kernel=kernel, needs=("z", "psi", "w", "r", "b_Z", "b_N"), references=("z", "psi"),
                          outputs=("Z", "N"), model=design)


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


register_component(ComponentInfo(
    "lqg", "controller", build,
    description="LQR depth and heading with the filter's bias estimate fed forward (Sandøy 2016, sec. 5.2)",
    summary=lambda spec: lqr_summary(spec.model), describe=lambda spec: lqr_lines(spec.model)))
