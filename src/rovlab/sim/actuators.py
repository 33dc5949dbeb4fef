"""Allocation and thrusters inside the closed loop: demanded wrench -> PWM -> real thrust.

The demanded 4-DOF wrench [X, Y, Z, N] is allocated on the full 6-DOF wrench with K = M = 0
(saturation-aware, rovlab.allocation), the thruster forces are turned into PWM commands,
quantised to the ESC's resolution, and back into the thrust the thrusters really give
(rovlab.models.thrusters). The estimator predicts with the wrench the allocation achieved; the
plant feels the real one.

Across the dead band the PWM mapping may have a hysteresis (``hold_us``, the design file's
``pwm_hysteresis_us``; rovlab.models.thruster_kernels.bank_pwm_hold_into): a thruster changes
direction only when the demand for the other direction, summed while it waits, needs at least
``hold_us`` beyond the dead band; it waits at the edge of its own side (no thrust). Without it,
noise on a demand near zero (the thesis's heading loop holding still) made uDrone's surge pair
alternate ~1475/1525 us every 0.1 s: a square wave into the ESCs (issue 28; the measurements
and why DP designs keep none are in docs/simulation.md, "PWM across the dead band").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rovlab._jit import njit
from rovlab.allocation.solvers import Allocator, allocate_into
from rovlab.models.thrusters import ThrusterBank, bank_force_into, bank_pwm_hold_into, bank_pwm_into

_DOF6 = (0, 1, 2, 5)  # X, Y, Z, N in the 6-DOF wrench [X, Y, Z, K, M, N]


class Actuators(NamedTuple):
    B: np.ndarray  # 6 x n configuration matrix (the model vehicle's, used to allocate)
    T: np.ndarray  # allocator's pseudo-inverse
    s: np.ndarray
    f_min: np.ndarray
    f_max: np.ndarray
    level: np.ndarray  # priority level per DOF
    n_levels: int
    B_true: np.ndarray  # 6 x n of the true vehicle (what the thrust really does)
    rows: np.ndarray  # thruster bank of the true vehicle
    grid_pwm: np.ndarray
    grid_force: np.ndarray
    pwm_res: float  # ESC resolution [us]; 0 = continuous
    tau6: np.ndarray  # (6) work
    f: np.ndarray  # (n) work: allocated forces
    frac: np.ndarray  # (6) work: achieved share per DOF
    cmd: np.ndarray  # (n) work: PWM commands
    f_real: np.ndarray  # (n) work: the thrust they give
    real: bool  # compute the real thrust (tau_real); False when nothing feels it (the observer plant)
    hold_us: float  # the dead band's hysteresis [us]; 0 = none
    side: np.ndarray  # (n) state: the side of the dead band each thruster is on (+1, -1; 0 at neutral)
    sum_f: np.ndarray  # (n) state: the other side's demand summed while waiting [N]


def make_actuators(allocator: Allocator, bank: ThrusterBank, B_true: np.ndarray, pwm_res: float, *,
                   real: bool = True, hold_us: float | None = None) -> Actuators:
    """The actuators of a run. ``real=False`` skips the thrust the PWM commands really give
    (tau_real is then the achieved wrench) where nothing feels it: the observer plant takes the
    achieved wrench (rovlab.sim.runner). The vehicle node keeps the default: it reports tau_real
    (rovlab.sim.step.control_step). ``hold_us``: the dead band's hysteresis (0: the plain inverse;
    default: the design's, ``allocator.pwm_hysteresis_us``, so a vehicle node commands what the
    simulator does). Every thruster starts at neutral; :func:`fresh_actuators` gives a run its own copy."""
    n = bank.rows.shape[0]
    if hold_us is None:
        hold_us = allocator.pwm_hysteresis_us
    return Actuators(allocator.B, allocator.T, allocator._s, allocator.f_min, allocator.f_max, allocator.level,
                     int(allocator.n_levels), np.ascontiguousarray(B_true, dtype=float), bank.rows, bank.grid_pwm,
                     bank.grid_force, float(pwm_res), np.zeros(6),
                     np.zeros(allocator.B.shape[1]), np.ones(6), np.zeros(n),
                     np.zeros(n), bool(real), float(hold_us), np.zeros(n), np.zeros(n))


def fresh_actuators(act: Actuators) -> Actuators:
    """The same actuators with their own work arrays and every thruster at neutral (the state of a
    new run: a Monte Carlo shares one Actuators between its runs)."""
    return act._replace(tau6=np.zeros(6), f=np.zeros_like(act.f), frac=np.ones(6), cmd=np.zeros_like(act.cmd),
                        f_real=np.zeros_like(act.f_real), side=np.zeros_like(act.side), sum_f=np.zeros_like(act.sum_f))


@njit(cache=True, inline="always")
def actuate(act, tau, tau_cmd, tau_real, pwm):
    """Allocate the demanded wrench tau (4); fill the achieved wrench tau_cmd (4), the real one
    tau_real (4; the achieved one when act.real is False) and the PWM commands pwm (n thrusters)."""
    tau6 = act.tau6
    tau6[:] = 0.0
    tau6[0] = tau[0]
    tau6[1] = tau[1]
    tau6[2] = tau[2]
    tau6[5] = tau[3]
    f = act.f
    allocate_into(act.B, act.T, act.s, act.f_min, act.f_max, tau6, act.level, act.n_levels, True, f, act.frac)
    cmd = act.cmd
    if act.hold_us > 0.0:  # f becomes what the thrusters give (0 for one that waits at its edge)
        bank_pwm_hold_into(act.rows, act.grid_pwm, act.grid_force, f, act.side, act.sum_f, act.hold_us, cmd)
    else:
        bank_pwm_into(act.rows, act.grid_pwm, act.grid_force, f, cmd)
    nt = cmd.shape[0]
    if act.pwm_res > 0.0:
        for i in range(nt):
            cmd[i] = act.pwm_res * np.round(cmd[i] / act.pwm_res)
    for i in range(nt):
        pwm[i] = cmd[i]
    if act.real:  # the achieved and the real wrench in one pass (measured faster than two)
        f_real = act.f_real
        bank_force_into(act.rows, act.grid_pwm, act.grid_force, cmd, f_real)
        for a in range(4):
            r = _DOF6[a]
            acc = 0.0
            acc_real = 0.0
            for i in range(nt):
                acc += act.B[r, i] * f[i]
                acc_real += act.B_true[r, i] * f_real[i]
            tau_cmd[a] = acc
            tau_real[a] = acc_real
    else:
        for a in range(4):
            r = _DOF6[a]
            acc = 0.0
            for i in range(nt):
                acc += act.B[r, i] * f[i]
            tau_cmd[a] = acc
            tau_real[a] = acc
