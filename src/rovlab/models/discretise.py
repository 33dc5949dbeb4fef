"""Exact discretisation of linear models: zero-order hold and Van Loan's process-noise covariance.

For x_dot = A x + B u + E w with u held constant over [t_k, t_k + h) and w white noise of
power spectral density W (E[w(t) w(s)^T] = W delta(t - s)):

    x_{k+1} = Phi x_k + Delta u_k + w_k,       w_k ~ N(0, Q)
    Phi   = e^{A h}
    Delta = int_0^h e^{A s} ds B               (zero-order hold; Chen 2013, eq. 4.17)
    Q     = int_0^h e^{A s} E W E^T e^{A^T s} ds

Phi and Delta come from one matrix exponential of the augmented matrix [[A, B], [0, 0]] h.
Q comes from Van Loan's method (Van Loan 1978, IEEE TAC 23(3); Brown & Hwang 2012, sec. 3.9):

    F = [[-A h, E W E^T h], [0, A^T h]],   G = e^F,   Phi = (G_22)^T,   Q = Phi G_12

Gamma = int_0^h e^{A s} ds E is what MATLAB's ``c2d(A, E, h)`` returns (the thesis reports it);
the filter does not need it: Q above is already the covariance of the discrete state noise
(rovlab's correction of the thesis, whose eq. in sec. 5.1.2 writes Gamma Q Gamma^T: predict with
Phi P Phi^T + Q, not Gamma Q Gamma^T).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _square(name: str, M: np.ndarray) -> np.ndarray:
    M = np.asarray(M, dtype=float)
    if M.ndim != 2 or M.shape[0] != M.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} has non-finite entries")
    return M


def _check_h(h: float) -> float:
    h = float(h)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"sample time must be a positive number, got {h}")
    return h


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Delta) of x_dot = A x + B u with u held over each step of length h."""
    A = _square("A", A)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    h = _check_h(h)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    from scipy.linalg import expm  # here: a run whose design is stored never imports scipy.linalg

    G = expm(M * h)
    return G[:n, :n].copy(), G[:n, n:].copy()


def van_loan(A: np.ndarray, E: np.ndarray, W: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Q): transition matrix and discrete process-noise covariance by Van Loan's method.

    Q is returned exactly symmetric (the average of Q and Q^T; the two differ by round-off).
    """
    A = _square("A", A)
    n = A.shape[0]
    E = np.asarray(E, dtype=float).reshape(n, -1)
    W = _square("W", W)
    if W.shape[0] != E.shape[1]:
        raise ValueError(f"W is {W.shape[0]}x{W.shape[0]} but E has {E.shape[1]} columns")
    if not np.allclose(W, W.T, rtol=1e-12, atol=0.0):
        raise ValueError("the power spectral density W must be symmetric")
    h = _check_h(h)
    F = np.zeros((2 * n, 2 * n))
    F[:n, :n] = -A * h
    F[:n, n:] = E @ W @ E.T * h
    F[n:, n:] = A.T * h
    from scipy.linalg import expm

    G = expm(F)
    Phi = G[n:, n:].T.copy()
    Q = Phi @ G[:n, n:]
    return Phi, 0.5 * (Q + Q.T)


@dataclass(frozen=True, eq=False)
class DiscreteModel:
    """x_{k+1} = Phi x_k + Delta u_k + w_k with w_k ~ N(0, Q); Gamma = int e^{As} ds E."""

    Phi: np.ndarray
    Delta: np.ndarray
    Gamma: np.ndarray
    Q: np.ndarray
    h: float


def discretise(A: np.ndarray, B: np.ndarray, E: np.ndarray, W: np.ndarray, h: float) -> DiscreteModel:
    """Exact (zero-order-hold) discretisation of A, B and Van Loan's Q for the noise E w."""
    Phi, Delta = zoh(A, B, h)
    _, Gamma = zoh(A, E, h)
    _, Q = van_loan(A, E, W, h)  # its Phi equals zoh's to round-off (checked in the tests)
    return DiscreteModel(Phi=Phi, Delta=Delta, Gamma=Gamma, Q=Q, h=float(h))
