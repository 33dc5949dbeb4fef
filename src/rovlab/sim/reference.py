"""The closed loop of :mod:`rovlab.sim.runner`, written as a plain Python/numpy loop.

Slow (tens of milliseconds per simulated second) but short and readable: it is the oracle the
tests compare the compiled loop against (noise-free, so both see the same inputs), and the
"plain-Python loop" baseline of ``benchmarks/bench_closed_loop.py``. It supports the process
and the observer plant, sensors at the control rate, the Kalman filter without sensor
management (every present sample is used: a standard stacked Joseph update), the LQG law,
the saturation-aware allocation and the PWM commands with the dead band's hysteresis.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rovlab.core.angles import wrap_angle as _wrap
from rovlab.models import kinetics as kin
from rovlab.models import thruster_kernels as tk
from rovlab.sim.plant import ObserverPlant
from rovlab.sim.prepare import Prepared


def run_python(prep: Prepared, *, noise: bool = True, steps: int | None = None) -> dict[str, np.ndarray]:
    """Run the prepared scenario; returns logs {'true', 'x', 'P', 'u', 'pwm', 'y'} per control step."""
    fm = prep.filter_model
    alloc = prep.allocator
    bank = alloc.bank
    plant, drive, sensors = prep.plant, prep.drive, prep.sensors
    ctl = prep.design.controller.model
    n_sub = plant.n_sub
    n = prep.n_ctrl if steps is None else steps
    observer = isinstance(plant, ObserverPlant)
    obs: Any = plant  # one of the two plants; the branches below read only that one's fields
    xo = plant.x.copy()
    xp = plant.x.copy()
    bias = np.zeros(4) if observer or not noise else obs.bias.copy()
    x = fm.x0.astype(float).copy()
    P = fm.P0.astype(float).copy()
    quantity = {2: 0, 3: 1, 6: 2, 7: 3}  # TRUTH index -> index in [z, psi, w, r]
    ch_quantity = np.array([quantity[int(q)] for q in sensors.quantity])
    H, R = fm.H, fm.R
    offsets = np.array([c.offset for c in fm.channels])
    angle = np.array([c.angle for c in fm.channels])
    logs: dict[str, list[np.ndarray]] = {k: [] for k in ("true", "x", "P", "u", "pwm", "y")}
    side, sum_f = np.zeros(len(bank.names)), np.zeros(len(bank.names))  # the thrusters' dead-band state
    for k in range(n):
        truth = np.array([xo[0], _wrap(xo[1]), xo[2], xo[3]]) if observer else \
            np.array([xp[2], _wrap(xp[3]), xp[6], xp[7]])
        # sensors
        present = np.array([k % sensors.period[j] == 0 and not drive.dropout[k, j] for j in range(len(offsets))])
        y = truth[ch_quantity] + offsets
        if noise:
            y = y + sensors.std * drive.sensor_normals[k]
        y = np.where(angle, [_wrap(v) for v in y], y)
        # filter: stacked Joseph update with the present samples (offsets removed)
        if present.any():
            Hk, Rk = H[present], R[np.ix_(present, present)]
            nu = (y[present] - offsets[present]) - Hk @ x
            nu = np.where(angle[present], [_wrap(v) for v in nu], nu)
            S = Hk @ P @ Hk.T + Rk
            K = P @ Hk.T @ np.linalg.inv(S)
            x = x + K @ nu
            x[1] = _wrap(x[1])
            IKH = np.eye(6) - K @ Hk
            P = IKH @ P @ IKH.T + K @ Rk @ K.T
        logs["true"].append(truth)
        logs["x"].append(x.copy())
        logs["P"].append(P.copy())
        logs["y"].append(np.where(present, y, np.nan))
        # LQG law with the heading error wrapped
        z_ref, psi_ref = drive.refs[k, 2], drive.refs[k, 3]
        psi_hat = psi_ref - _wrap(psi_ref - x[1])
        u = ctl.P @ np.array([z_ref, psi_ref]) - ctl.K @ np.array([x[0], psi_hat, x[2], x[3]]) - x[4:6]
        # allocation, PWM (quantised), real thrust
        f, _ = alloc.forces(np.array([0.0, 0.0, u[0], 0.0, 0.0, u[1]]))
        pwm = np.empty(len(bank.names))
        tk.bank_pwm_hold_into(bank.rows, bank.grid_pwm, bank.grid_force, f, side, sum_f, prep.actuators.hold_us, pwm)
        res = prep.actuators.pwm_res
        if res > 0:
            pwm = res * np.round(pwm / res)
        achieved = alloc.B @ f
        u = np.array([achieved[2], achieved[5]])
        logs["u"].append(u)
        logs["pwm"].append(pwm)
        # filter prediction
        x = fm.Phi @ x + fm.Delta @ u
        x[1] = _wrap(x[1])
        P = fm.Phi @ P @ fm.Phi.T + fm.Q
        # plant
        if observer:
            for s in range(n_sub):
                w = obs.L @ drive.plant_normals[k * n_sub + s] if noise else 0.0
                xo = obs.Phi @ xo + obs.Delta @ u + w
        else:
            real = alloc.B @ bank.force(pwm)
            tau = np.array([real[0], real[1], real[2], real[5]]) + bias
            for s in range(n_sub):
                w = obs.noise_std * drive.plant_normals[k * n_sub + s] if noise else 0.0
                xp = kin.rk4_step(obs.p, xp, tau + w, np.zeros(4), obs.h)
            if noise:
                bias = obs.bias_phi * bias + obs.bias_std * drive.bias_normals[k]
    return {k: np.array(v) for k, v in logs.items()}
