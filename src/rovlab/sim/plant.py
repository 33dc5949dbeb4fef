"""Plants for the closed-loop simulator, as compiled kernels that advance one control period.

* Process plant (SPEC section 4): x = [x, y, z, psi, u, v, w, r] integrated with fixed-step RK4;
  the force on the body is tau (from the thrusters) + b (Gauss-Markov biases, advanced by the
  runner with their exact discrete form) + w_nu (white noise of power spectral density W, held
  over each RK4 step as N(0, W / h), the zero-order-hold equivalent of white noise). The
  restoring force is in the packed parameters (rovlab.models.kinetics.pack).
* Observer plant ("perfect model"): the linear depth-and-heading model with its bias states,
  advanced exactly: x_{k+1} = Phi_h x_k + Delta_h u + L_h n_k, L_h L_h^T = Q_h (Van Loan at the
  plant step), so the filter's assumptions hold exactly.

The standard normal draws are made beforehand with numpy's Generator from the run's seed and
passed in, so a run is reproducible from its seed whatever compiles the loop.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rovlab.models.kinetics import P_CUB, P_GZ, P_LIN, P_M, P_MINV, P_QUAD, P_XG, P_XUDOT, P_YG, P_YVDOT


@njit(cache=True, inline="always")
def _rhs(p, x0, x1, x2, x3, x4, x5, x6, x7, f0, f1, f2, f3, out):
    """Time derivative of the 8-state process model into ``out`` (force f = tau + b + w)."""
    c, s = np.cos(x3), np.sin(x3)
    out[0] = c * x4 - s * x5
    out[1] = s * x4 + c * x5
    out[2] = x6
    out[3] = x7
    m = p[P_M]
    a = m * (x5 + p[P_XG] * x7)
    cc = m * (x4 - p[P_YG] * x7)
    g0 = f0 - (-a + p[P_YVDOT] * x5) * x7 + (p[P_LIN] + p[P_QUAD] * abs(x4) + p[P_CUB] * x4 * x4) * x4
    g1 = f1 - (cc - p[P_XUDOT] * x4) * x7 + (p[P_LIN + 1] + p[P_QUAD + 1] * abs(x5) + p[P_CUB + 1] * x5 * x5) * x5
    g2 = f2 - p[P_GZ] + (p[P_LIN + 2] + p[P_QUAD + 2] * abs(x6) + p[P_CUB + 2] * x6 * x6) * x6
    g3 = (f3 - ((a - p[P_YVDOT] * x5) * x4 + (-cc + p[P_XUDOT] * x4) * x5)
          + (p[P_LIN + 3] + p[P_QUAD + 3] * abs(x7) + p[P_CUB + 3] * x7 * x7) * x7)
    for i in range(4):
        out[4 + i] = (p[P_MINV + 4 * i] * g0 + p[P_MINV + 4 * i + 1] * g1
                      + p[P_MINV + 4 * i + 2] * g2 + p[P_MINV + 4 * i + 3] * g3)


@njit(cache=True)
def rk4_inplace(p: np.ndarray, x: np.ndarray, f: np.ndarray, h: float, k: np.ndarray) -> None:
    """One RK4 step of the process model on x (in place); k is an (4, 8) work array."""
    f0, f1, f2, f3 = f[0], f[1], f[2], f[3]
    _rhs(p, x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], f0, f1, f2, f3, k[0])
    hh = 0.5 * h
    _rhs(p, x[0] + hh * k[0, 0], x[1] + hh * k[0, 1], x[2] + hh * k[0, 2], x[3] + hh * k[0, 3],
         x[4] + hh * k[0, 4], x[5] + hh * k[0, 5], x[6] + hh * k[0, 6], x[7] + hh * k[0, 7], f0, f1, f2, f3, k[1])
    _rhs(p, x[0] + hh * k[1, 0], x[1] + hh * k[1, 1], x[2] + hh * k[1, 2], x[3] + hh * k[1, 3],
         x[4] + hh * k[1, 4], x[5] + hh * k[1, 5], x[6] + hh * k[1, 6], x[7] + hh * k[1, 7], f0, f1, f2, f3, k[2])
    _rhs(p, x[0] + h * k[2, 0], x[1] + h * k[2, 1], x[2] + h * k[2, 2], x[3] + h * k[2, 3],
         x[4] + h * k[2, 4], x[5] + h * k[2, 5], x[6] + h * k[2, 6], x[7] + h * k[2, 7], f0, f1, f2, f3, k[3])
    h6 = h / 6.0
    for i in range(8):
        x[i] += h6 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])


@njit(cache=True)
def process_advance(p: np.ndarray, x: np.ndarray, tau_b: np.ndarray, h: float, noise_std: np.ndarray,
                    normals: np.ndarray, k: np.ndarray, f: np.ndarray) -> None:
    """Advance the process plant over len(normals) RK4 steps of length h (in place).

    tau_b (4) is the thruster force plus the bias, held over the control period (ZOH);
    normals (n_sub, 4) are standard normal draws and noise_std (4) = sqrt(W / h) scales them
    into the white force noise of each step. k (4, 8) and f (4) are work arrays.
    """
    for j in range(normals.shape[0]):
        for i in range(4):
            f[i] = tau_b[i] + noise_std[i] * normals[j, i]
        rk4_inplace(p, x, f, h, k)


@njit(cache=True)
def linear_advance(Phi: np.ndarray, Delta: np.ndarray, L: np.ndarray, x: np.ndarray, u: np.ndarray,
                   normals: np.ndarray, tmp: np.ndarray) -> None:
    """Advance x <- Phi x + Delta u + L n over len(normals) exact steps (in place)."""
    m = x.shape[0]
    for s in range(normals.shape[0]):
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += Phi[i, j] * x[j] + L[i, j] * normals[s, j]
            for j in range(u.shape[0]):
                acc += Delta[i, j] * u[j]
            tmp[i] = acc
        for i in range(m):
            x[i] = tmp[i]
