"""One control step and one plant step, compiled: the closed loop of rovlab.sim.loop cut in two
halves for a vehicle that runs in real time (the node on the vehicle, a simulated vehicle on the
same topics).

:func:`control_step` is what the loop does between sampling the sensors and advancing the plant
(estimator correct -> controller -> allocation and PWM -> estimator predict -> controller
actuated), for one sample and through the same slot functions (rovlab.core.components), so a
node fed the samples of a simulation computes exactly the simulation's estimates and commands.
:func:`plant_push` and :func:`plant_sample` are the other half: the thrust the PWM commands give and
the plant advanced one control period with it; the truth and the sensor samples at a step.

Nothing here is new maths: both are sequences of existing kernels. They are compiled once per
combination of component types and cached on disk like the loop (:func:`control_step_for`
picks the uncached copy for components defined outside rovlab, as rovlab.sim.loop.loop_for).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.components import (
    controller_actuated,
    controller_step,
    estimator_correct,
    estimator_predict,
    plant_advance,
    plant_truth,
)
from rovlab.estimation.layout import EVENT_NONE, REP_EVENT
from rovlab.models.sensors import sample_sensors
from rovlab.models.thrusters import bank_force_into
from rovlab.sim.actuators import actuate

_DOF6 = (0, 1, 2, 5)  # X, Y, Z, N in the 6-DOF wrench [X, Y, Z, K, M, N]


class StepOut(NamedTuple):
    """What :func:`control_step` fills (arrays the caller owns and reads after each step)."""

    rep: np.ndarray  # (m, N_REP) the estimator's report per channel
    nav: np.ndarray  # (N_TRUTH) the estimate in the TRUTH layout
    tau: np.ndarray  # (4) demanded wrench [X, Y, Z, N]
    tau_cmd: np.ndarray  # (4) the wrench the allocation achieved
    tau_real: np.ndarray  # (4) what the PWM commands give on the model vehicle
    pwm: np.ndarray  # (thrusters) PWM commands [us]
    x: np.ndarray  # (n) corrected estimate
    P: np.ndarray  # (n, n) its covariance
    ctrl: np.ndarray  # (len(controller state)) the controller's state after its command (what the loop logs)


# The two halves of a control step, shared by the simulator's loop (rovlab.sim.loop, which logs
# between them) and the vehicle's control step below: one body for both.

@njit(cache=True, inline="always")
def estimate(t, est, nav_of, y, present, rep, nav, x_out, P_out):
    """Correct the estimator with the samples y (NaN where ``present`` is False); the corrected
    estimate and covariance into x_out / P_out, and into ``nav`` in the TRUTH layout."""
    for j in range(rep.shape[0]):  # what an estimator does not report on a channel: no event
        rep[j, REP_EVENT] = EVENT_NONE
        for col in range(1, rep.shape[1]):
            rep[j, col] = math.nan
    estimator_correct(est, t, y, present, rep)
    n = est.x.shape[0]
    for i in range(n):
        x_out[i] = est.x[i]
        for j in range(n):
            P_out[i, j] = est.P[i, j]
        nav[nav_of[i]] = est.x[i]


@njit(cache=True, inline="always")
def command(t, est, ctrl, act, ref, engaged, nav, tau, tau_cmd, tau_real, pwm, ctrl_out):
    """The controller's demand from ``nav`` and ``ref`` (zero when not ``engaged``: neutral
    thrusters), the allocation and PWM commands, the controller's state into ``ctrl_out``, then the
    estimator's prediction with the achieved wrench and the controller told what was achieved."""
    if engaged:
        controller_step(ctrl, t, nav, ref, tau)
    else:
        for i in range(4):
            tau[i] = 0.0
    actuate(act, tau, tau_cmd, tau_real, pwm)
    state = ctrl.state
    for i in range(state.shape[0]):
        ctrl_out[i] = state[i]
    estimator_predict(est, t, tau_cmd)
    if engaged:
        controller_actuated(ctrl, t, tau, tau_cmd)


@njit(cache=True, **WITHOUT_NRT)  # no reference counting, no allocation: as rovlab.sim.loop.run_loop
def control_step(t, est, ctrl, act, nav_of, y, present, ref, engaged, out, correct_only=False):
    """One control step at time t [s] with the samples y (NaN where ``present`` is False): the
    loop's step between sampling the sensors and advancing the plant (:func:`estimate`, then
    :func:`command`). With ``correct_only`` the estimator is only corrected (:func:`estimate`):
    how a vehicle that received several samples of a channel in one control period fuses the
    older ones before the step (rovlab.interfaces.node.core), as the offline filter fuses several
    rows of one period one after another (rovlab.estimation.streaming).

    Fills the arrays of ``out`` (:class:`StepOut`): the estimator's per-channel report, the
    corrected estimate and covariance at t, the estimate in the TRUTH layout the controller
    reads, the demanded wrench, the wrench the allocation achieved, what the PWM commands give on
    the model vehicle, the PWM commands and the controller's state. With ``engaged`` False the
    controller is not run and the demanded wrench is zero (neutral thrusters); the estimator
    still corrects and predicts with the zero wrench.
    """
    estimate(t, est, nav_of, y, present, out.rep, out.nav, out.x, out.P)
    if not correct_only:
        command(t, est, ctrl, act, ref, engaged, out.nav, out.tau, out.tau_cmd, out.tau_real, out.pwm, out.ctrl)


control_step_uncached = njit(cache=False, **WITHOUT_NRT)(getattr(control_step, "py_func", control_step))


def control_step_for(*components: object):
    """The compiled control step for these components (disk-cached when all are rovlab's own)."""
    if all(type(c).__module__.startswith("rovlab.") for c in components):
        return control_step
    return control_step_uncached


@njit(cache=True, **WITHOUT_NRT)
def plant_push(plant, act, drive, row, pwms, weights, tau_real):
    """Advance the plant one control period (noise of ``row`` of ``drive``) with the thrust of the
    PWM commands ``pwms`` (one row per command, each in force for its ``weights`` fraction of the
    period; weights summing to 1): the period's mean wrench, which ``tau_real`` (4) receives [X, Y,
    Z, N] on the plant's true vehicle (act.B_true, act.rows). One row of weight 1: the thrust of one
    command over the whole period. Several: a command that arrived within the period acts from when
    it arrived (rovlab.sim.realtime), its impulse over the period exact."""
    f = act.f_real
    for a in range(4):
        tau_real[a] = 0.0
    for j in range(pwms.shape[0]):
        bank_force_into(act.rows, act.grid_pwm, act.grid_force, pwms[j], f)
        for a in range(4):
            r = _DOF6[a]
            acc = 0.0
            for i in range(f.shape[0]):
                acc += act.B_true[r, i] * f[i]
            tau_real[a] += weights[j] * acc
    plant_advance(plant, drive, row, tau_real, tau_real)


DIVERGED = 1e9  # a true state beyond this (or not finite) means the plant has diverged


@njit(cache=True, inline="always", **WITHOUT_NRT)
def plant_sample(k, plant, sensors, drive, row, truth, y, present):
    """The plant's truth at t_k into ``truth`` (N_TRUTH) and the sensor samples of step k into y /
    present (noise and drop-outs of ``row`` of ``drive``). Returns False, sampling nothing, when
    the truth is no longer finite or beyond :data:`DIVERGED` (the plant diverged); the loop's
    step 1-2 and the real-time simulated vehicle's."""
    plant_truth(plant, truth)
    finite = True
    for i in range(truth.shape[0]):
        finite = finite and abs(truth[i]) < DIVERGED
    if finite:
        sample_sensors(sensors, truth, k, drive.sensor_normals, drive.dropout, row, y, present)
    return finite

