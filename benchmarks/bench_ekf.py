"""The 4-DOF EKF step (rovlab.estimation.ekf) against the same EKF written plainly in numpy/scipy.

One step = correct with the 9 channels of design udrone_dp (motion capture x, y, z, psi; pressure;
IMU yaw rate; DVL u, v, w) and predict over 0.1 s (RK4 in 10 substeps on the plant's right-hand
side, the analytic Jacobian, Van Loan's Phi and Q). rovlab's compiled step also runs its sensor
management (timeouts, chi-square gate, recovery), which the plain step does not. The plain step is
what a user would write with scipy: scipy.linalg.expm for Van Loan, numpy for the rest, the
right-hand side and Jacobian through rovlab.models.kinetics from Python.

Run: ``.venv/bin/python benchmarks/bench_ekf.py``. Times are best-of-5 means per step.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import _timing  # noqa: E402, I001  (pins the BLAS/numba threads to 1 before numpy is imported)
import numpy as np  # noqa: E402
from scipy.linalg import expm  # noqa: E402

from rovlab.estimation import ekf  # noqa: E402
from rovlab.estimation.fusion import N_REP  # noqa: E402
from rovlab.models import kinetics as kin  # noqa: E402
from rovlab.params.design import load_design_config  # noqa: E402
from rovlab.params.vehicle import load_vehicle  # noqa: E402


def plain_step(p, inv_T, W, H, R, x, P, y, tau, h, n_sub):
    """One EKF step with numpy/scipy: stacked Joseph update, RK4 state, Van Loan covariance."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    nu = y - H @ x
    nu[3] = (nu[3] + np.pi) % (2 * np.pi) - np.pi
    x = x + K @ nu
    IKH = np.eye(12) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    A = ekf.continuous_model(p, inv_T, x, tau)
    Bf = A[:, 8:12]
    EWE = np.zeros((12, 12))
    EWE[4:8, 4:8] = (Bf[4:8] * W[:4]) @ Bf[4:8].T
    EWE[8:, 8:] = np.diag(W[4:])
    G = expm(np.block([[-A * h, EWE * h], [np.zeros((12, 12)), A.T * h]]))
    Phi = G[12:, 12:].T
    Q = Phi @ G[:12, 12:]

    def f(z):
        d = kin.plant_rhs(p, z[:8], tau + z[8:], np.zeros(4))
        return np.concatenate([d, -inv_T * z[8:]])

    dt = h / n_sub
    for _ in range(n_sub):
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x, Phi @ P @ Phi.T + Q


def main() -> None:
    vehicle = load_vehicle("udrone_dvl")
    cfg = load_design_config("udrone_dp")
    spec = ekf.build(vehicle, cfg)
    est, mdl = spec.kernel, spec.model
    m = est.H.shape[0]
    y = np.array([0.01, -0.02, 1.0, 0.05, 1.0 + mdl.channels[4].offset, 0.001, 0.01, 0.0, 0.0])
    present = np.ones(m, dtype=np.bool_)
    rep = np.empty((m, N_REP))
    tau = np.array([0.5, -0.3, 6.5, 0.02])
    est.x[:] = [0, 0, 1.0, 0.05, 0, 0, 0, 0, 0, 0, -6.5, 0]
    est.P[:] = np.eye(12) * 1e-3

    def ours():
        ekf._correct(est, 0.0, y, present, rep)
        ekf._predict(est, 0.0, tau)

    x0, P0 = est.x.copy(), est.P.copy()
    state = {"x": x0.copy(), "P": P0.copy()}

    def plain():
        state["x"], state["P"] = plain_step(mdl.p, mdl.inv_T, mdl.W, mdl.H, mdl.R, state["x"], state["P"],
                                            y - np.array([c.offset for c in mdl.channels]), tau, mdl.h, est.n_sub)

    t_ours = _timing.per_call(ours)
    t_plain = _timing.per_call(plain)
    print("4-DOF EKF, one step (correct with 9 channels + predict over 0.1 s), design udrone_dp")
    print(f"  numpy/scipy EKF step          {t_plain * 1e6:9.1f} us")
    print(f"  rovlab compiled EKF step      {t_ours * 1e6:9.1f} us   {t_plain / t_ours:6.1f}x "
          "(with sensor management)")
    print(f"  real-time margin at 10 Hz     {0.1 / t_ours:9.0f}x")


if __name__ == "__main__":
    main()
