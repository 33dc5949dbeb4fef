"""Noise processes: first-order Gauss-Markov biases and correlated Gaussian samples (Sandøy 2016, ch. 3).

A Gauss-Markov process with stationary variance sigma^2 and correlation time 1/beta,

    b_dot = -beta b + sqrt(2 sigma^2 beta) w(t),

is advanced with its exact discrete form (Brown & Hwang 2012, ch. 4)

    b_{k+1} = exp(-beta h) b_k + sqrt(sigma^2 (1 - exp(-2 beta h))) n_k,   n_k ~ N(0, 1),

so its statistics do not depend on the step h.
"""

from __future__ import annotations

import numpy as np


def gauss_markov_coefficients(sigma2: np.ndarray | float, beta: np.ndarray | float,
                              h: float) -> tuple[np.ndarray, np.ndarray]:
    """(phi, std) of the exact discretisation: b_{k+1} = phi b_k + std n_k."""
    sigma2 = np.asarray(sigma2, dtype=float)
    beta = np.asarray(beta, dtype=float)
    if np.any(sigma2 < 0) or np.any(beta <= 0) or not h > 0:
        raise ValueError("Gauss-Markov needs variance >= 0, beta > 0 and step h > 0")
    phi = np.exp(-beta * h)
    std = np.sqrt(sigma2 * (1.0 - phi**2))
    return phi, std


def gauss_markov_from_psd(psd: np.ndarray | float, time_constant: np.ndarray | float,
                          h: float) -> tuple[np.ndarray, np.ndarray]:
    """(phi, std) for b_dot = -b/T + w with white-noise power spectral density W.

    The stationary variance of that process is W T / 2 (beta = 1/T).
    """
    T = np.asarray(time_constant, dtype=float)
    return gauss_markov_coefficients(np.asarray(psd, dtype=float) * T / 2.0, 1.0 / T, h)


def gauss_markov_step(b: np.ndarray, phi: np.ndarray, std: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return phi * b + std * rng.standard_normal(np.shape(b))


def psd_factor(Q: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """L with L L^T = Q for a symmetric positive semi-definite Q.

    Cholesky when Q is positive definite; otherwise a symmetric eigen-factor with the
    (round-off) negative eigenvalues set to zero. Raises if Q is clearly indefinite.
    """
    Q = np.asarray(Q, dtype=float)
    if Q.ndim != 2 or Q.shape[0] != Q.shape[1]:
        raise ValueError(f"covariance must be square, got shape {Q.shape}")
    if not np.all(np.isfinite(Q)):
        raise ValueError("covariance has non-finite entries")
    if not np.allclose(Q, Q.T, rtol=1e-9, atol=1e-15):
        raise ValueError("covariance must be symmetric")
    try:
        return np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        pass
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    scale = max(float(np.max(np.abs(lam))), 1e-300)
    if np.min(lam) < -tol * scale:
        raise ValueError(f"covariance is not positive semi-definite (eigenvalue {np.min(lam):.3g})")
    return V * np.sqrt(np.clip(lam, 0.0, None))


def correlated_samples(Q: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n samples (rows) of N(0, Q), drawn as L z with L L^T = Q."""
    L = psd_factor(Q)
    return rng.standard_normal((n, Q.shape[0])) @ L.T
