"""Discrete LQR for depth and heading, Bryson's rule and the reference feed-forward (Sandøy 2016, sec. 5.2).

Control model (the observer model without bias states): x = [z, psi, w, r], u = [Z, N],

    A_c = [[0, I], [0, -M^-1 D_L]],  B_c = [[0], [M^-1]],  C_c = [I, 0]

discretised exactly at h (zero-order hold), then the discrete LQR minimising
sum x^T Q x + u^T R u: with S the stabilising solution of the discrete algebraic Riccati
equation (scipy.linalg.solve_discrete_are),

    K = (R + Delta^T S Delta)^-1 Delta^T S Phi,      u = -K x.

Reference feed-forward P so that the output settles on the reference r (u = P r - K x):

* ``"discrete"`` (default): P = [C (I - Phi + Delta K)^-1 Delta]^-1, the steady state of the
  discrete closed loop x = Phi x + Delta (P r - K x);
* ``"continuous"``: P = [-C (A_c - B_c K)^-1 B_c]^-1, what the thesis computed (appendix A.4
  line 44) with the discrete K in the continuous model.

For this model both give the same P (= the position block of K, since z and psi are pure
integrators: at rest the thrust must vanish, so P r = K x); they differ for plants without
integrators. The thesis's reported K and P (Sandøy 2016, sec. 5.2) are reproduced either way.
Bryson's rule (Bryson & Ho 1975, sec. 5.4): Q_ii = w_i / x_max,i^2, R_jj = w_j / u_max,j^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovlab.core.weights import bryson_diagonal
from rovlab.models.discretise import zoh
from rovlab.models.linear import HeaveYawParams, control_model
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle

CONTROL_STATES = ("z", "psi", "w", "r")
INPUTS = ("Z", "N")


def bryson(maxima: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Diagonal weight matrix diag(w_i / max_i^2) (w_i = 1 when not given)."""
    mx = np.asarray(maxima, dtype=float)
    if np.any(~np.isfinite(mx)):
        raise ValueError("Bryson's rule needs positive maxima and non-negative weights of the same length")
    return np.diag(bryson_diagonal(mx, weights))


def dlqr(Phi: np.ndarray, Delta: np.ndarray, Q: np.ndarray, R: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, S, closed-loop eigenvalues) of the discrete LQR (like MATLAB's dlqr)."""
    Phi = np.asarray(Phi, dtype=float)
    Delta = np.asarray(Delta, dtype=float)
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    if np.any(np.linalg.eigvalsh(0.5 * (R + R.T)) <= 0):
        raise ValueError("the input weight R must be positive definite")
    from scipy.linalg import solve_discrete_are  # here: a run whose design is stored never imports it

    S = solve_discrete_are(Phi, Delta, Q, R)
    K = np.linalg.solve(R + Delta.T @ S @ Delta, Delta.T @ S @ Phi)
    return K, S, np.linalg.eigvals(Phi - Delta @ K)


def reference_gain_discrete(K: np.ndarray, C: np.ndarray, Phi: np.ndarray, Delta: np.ndarray) -> np.ndarray:
    """P = [C (I - Phi + Delta K)^-1 Delta]^-1."""
    n = Phi.shape[0]
    return np.linalg.inv(C @ np.linalg.solve(np.eye(n) - Phi + Delta @ K, Delta))


def reference_gain_continuous(K: np.ndarray, C: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """P = [-C (A - B K)^-1 B]^-1 (the thesis's formula, appendix A.4 line 44)."""
    return np.linalg.inv(-C @ np.linalg.solve(A - B @ K, B))


@dataclass(frozen=True, eq=False)
class LQRDesign:
    """A discrete LQR with reference feed-forward for the depth-and-heading control model."""

    h: float
    A: np.ndarray  # continuous control model
    B: np.ndarray
    C: np.ndarray
    Phi: np.ndarray  # its exact discretisation
    Delta: np.ndarray
    Q: np.ndarray  # weights
    R: np.ndarray
    K: np.ndarray  # 2 x 4 state feedback
    S: np.ndarray  # Riccati solution
    P: np.ndarray  # 2 x 2 reference feed-forward
    poles: np.ndarray  # discrete closed-loop eigenvalues
    reference: str  # how P was computed: "discrete" | "continuous"


def design_lqr(params: HeaveYawParams, h: float, Q: np.ndarray, R: np.ndarray, *,
               reference: str = "discrete") -> LQRDesign:
    """Discretise the control model at h and design K and P."""
    if not h > 0:
        raise ValueError(f"sample time must be positive, got {h}")
    A, B, C = control_model(params)
    Phi, Delta = zoh(A, B, h)
    Q = np.asarray(Q, dtype=float)
    R = np.asarray(R, dtype=float)
    Q = np.diag(Q) if Q.ndim == 1 else Q
    R = np.diag(R) if R.ndim == 1 else R
    K, S, poles = dlqr(Phi, Delta, Q, R)
    if reference == "discrete":
        P = reference_gain_discrete(K, C, Phi, Delta)
    elif reference == "continuous":
        P = reference_gain_continuous(K, C, A, B)
    else:
        raise ValueError(f"reference must be 'discrete' or 'continuous', got {reference!r}")
    return LQRDesign(h=float(h), A=A, B=B, C=C, Phi=Phi, Delta=Delta, Q=Q, R=R, K=K, S=S, P=P, poles=poles,
                     reference=reference)


def design_lqr_from_config(vehicle: Vehicle, config: DesignConfig) -> LQRDesign:
    """The LQR of a filter/controller configuration (model values from the vehicle or the file).

    Weights for which no stabilising LQR exists (e.g. a zero weight on z or psi, which are pure
    integrators: the Riccati equation then has no stabilising solution) raise a ConfigError that
    names the file's [lqr] table, not a LinAlgError from deep inside scipy.
    """
    params = HeaveYawParams.from_values(**config.model_values(vehicle))
    try:
        with np.errstate(all="ignore"):
            design = design_lqr(params, config.sample_time, config.lqr_Q, config.lqr_R,
                                reference=config.reference_gain)
        ok = (np.all(np.isfinite(design.K)) and np.all(np.isfinite(design.P))
              and bool(np.all(np.abs(design.poles) < 1.0)))
        reason = "the closed loop it gives is not stable" if not ok else ""
    except (np.linalg.LinAlgError, ValueError) as exc:
        ok, reason = False, f"the Riccati equation failed: {exc}"
    if not ok:
        weights = ("Q = diag(" + ", ".join(f"{q:.4g}" for q in np.asarray(config.lqr_Q)) + "), R = diag("
                   + ", ".join(f"{r:.4g}" for r in np.asarray(config.lqr_R)) + ")")
        raise ConfigError([Problem(config.file or config.name, "lqr", weights,
                                   "weights for which a stabilising discrete LQR exists: z and psi are pure "
                                   "integrators and need positive weights (" + reason + ")")],
                          "filter configuration")
    return design
