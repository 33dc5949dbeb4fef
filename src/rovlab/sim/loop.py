"""The closed loop, compiled once per choice of components (Sandøy 2016, ch. 3 and sec. 5.1, 5.3.1).

At control sample k (t_k = k h, h the estimator's sample time, 0.1 s for uDrone):

1. the plant reports its true state at t_k,
2. the sensors sample it (each at its own rate, with its noise and lever arm; none during a
   drop-out window),
3. the estimator corrects with the samples that arrived and reports x_k, P_k,
4. the controller computes the demanded wrench from the estimate and the reference,
5. the allocation turns it into thruster forces and PWM commands (quantised), and those into
   the thrust the thrusters really give,
6. the estimator predicts with the wrench the allocation achieved; the controller learns what
   was achieved (anti-windup, adaptation),
7. the plant is integrated from t_k to t_k+1 with the thrust held (zero-order hold).

Row k - k0 of the logs holds t_k, the truth at t_k, the samples y_k, the corrected estimate,
the reference and the commands of step k. The estimator, the controller and the plant are
components (rovlab.core.components): :func:`run_loop` calls them only through their slots, so a
new estimator or controller is one module plus its registration, and the loop is specialised
(and cached on disk) per combination. Everything random comes in through :class:`Drive`, drawn
beforehand from the run's seed by :func:`draw`, so a run is reproducible from its seed alone
and a long run can be done in chunks (the live HMI does) with the same result.
"""

from __future__ import annotations

import math
import os
import re
from typing import NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.angles import wrap_angle
from rovlab.core.components import N_TRUTH, TRUTH_INDEX, plant_advance
from rovlab.estimation.fusion import CH_REASON, CH_STATUS, EVENT_USED, N_REP, REP_EVENT, REP_INNOV, REP_S
from rovlab.sim.step import command, estimate, plant_sample

N_WRENCH_LOG = 8  # allocated X, Y, Z, N, then demanded X, Y, Z, N
_PSI = TRUTH_INDEX["psi"]


class Drive(NamedTuple):
    """Everything exogenous to the loop for rows 0 .. n-1 of a chunk."""

    plant_normals: np.ndarray  # (n * n_sub, the plant's draws per step) float32: plant noise per integration step
    bias_normals: np.ndarray  # (n, 4): Gauss-Markov bias drivers
    sensor_normals: np.ndarray  # (n, m): measurement noise
    dropout: np.ndarray  # (n, m) bool: no sample from channel j at row i
    refs: np.ndarray  # (n, 4): reference [x, y, z, psi]
    heave_force: np.ndarray  # (n,): extra downward heave force on the plant [N] (tether pull ...)
    pset: np.ndarray  # (n,) int64: which of the plant's parameter sets holds (truth events)


class Work(NamedTuple):
    """The loop's scratch arrays (allocated by the caller: the loop itself allocates nothing)."""

    rep: np.ndarray  # (m, N_REP) what the estimator did with each sample
    y: np.ndarray  # (m) samples
    present: np.ndarray  # (m) bool
    truth: np.ndarray  # (N_TRUTH)
    nav: np.ndarray  # (N_TRUTH) the estimate in the truth layout, for the controller
    err: np.ndarray  # (NEES states)
    chol: np.ndarray  # (NEES states, NEES states)
    tau: np.ndarray  # (4) demanded wrench
    tau_cmd: np.ndarray  # (4) achieved wrench
    tau_real: np.ndarray  # (4) real wrench
    pwm: np.ndarray  # (thrusters)


def new_work(m: int, n_nees: int, n_thrusters: int) -> Work:
    return Work(np.empty((m, N_REP)), np.empty(m), np.empty(m, dtype=np.bool_), np.empty(N_TRUTH), np.zeros(N_TRUTH),
                np.empty(n_nees), np.empty((n_nees, n_nees)), np.zeros(4), np.zeros(4), np.zeros(4),
                np.empty(n_thrusters))


class Logs(NamedTuple):
    """What the loop records per row (named into columns by rovlab.sim.results)."""

    truth: np.ndarray  # (n, N_TRUTH)
    y: np.ndarray  # (n, m) samples (NaN = none)
    status: np.ndarray  # (n, m) channel status codes (rovlab.estimation.fusion STATUS_*)
    reason: np.ndarray  # (n, m) why a channel is lost or off (REASON_*)
    x: np.ndarray  # (n, n_x) corrected estimate
    P: np.ndarray  # (n, n_x, n_x) its covariance
    wrench: np.ndarray  # (n, N_WRENCH_LOG)
    pwm: np.ndarray  # (n, thrusters)
    cons: np.ndarray  # (n, 3): NIS sum, number of samples used, NEES
    ctrl: np.ndarray  # (n, len(controller state))


def new_logs(n: int, m: int, n_x: int, n_thrusters: int, n_ctrl_state: int) -> Logs:
    return Logs(np.empty((n, N_TRUTH)), np.empty((n, m)), np.empty((n, m)), np.empty((n, m)), np.empty((n, n_x)),
                np.empty((n, n_x, n_x)), np.empty((n, N_WRENCH_LOG)), np.empty((n, n_thrusters)),
                np.empty((n, 3)), np.empty((n, n_ctrl_state)))


def draw(rng: np.random.Generator, n: int, n_sub: int, plant_draws: int,
         m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The random inputs of n control steps, in a fixed order: plant noise (single precision),
    bias drivers, sensor noise (so a run drawn in one chunk is reproduced from its seed alone)."""
    plant = rng.standard_normal((n * n_sub, plant_draws), dtype=np.float32)
    bias = rng.standard_normal((n, 4))
    sensors = rng.standard_normal((n, m))
    return plant, bias, sensors


@njit(cache=True)
def _nees(err, P, idx, L):
    """err^T P^-1 err over the states idx, by Cholesky (NaN if that block is not positive definite)."""
    n = idx.shape[0]
    for j in range(n):
        acc = P[idx[j], idx[j]]
        for k in range(j):
            acc -= L[j, k] * L[j, k]
        if not acc > 0.0:
            return np.nan
        L[j, j] = math.sqrt(acc)
        for i in range(j + 1, n):
            acc = P[idx[i], idx[j]]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    total = 0.0
    for i in range(n):  # forward substitution L z = e, accumulating z^T z
        acc = err[i]
        for k in range(i):
            acc -= L[i, k] * err[k]
        err[i] = acc / L[i, i]
        total += err[i] * err[i]
    return total


@njit(cache=True, inline="always")
def _to_plant(k, row, t, plant, sensors, est, ctrl, act, nav_of, nees_idx, drive, logs, work):
    """Steps 1-6 of control step k (module docstring), up to the plant's advance: the truth and
    the samples (rovlab.sim.step.plant_sample), the estimator's correction
    (rovlab.sim.step.estimate), the controller, the allocation and the estimator's prediction
    (rovlab.sim.step.command: the vehicle node's control step is the same two halves), each
    logged at ``row``. The wrench the plant is to feel is left in work.tau_cmd / work.tau_real.
    Returns False, logging nothing, when the plant's true state is no longer finite (or beyond
    1e9)."""
    m = sensors.quantity.shape[0]
    nt = act.rows.shape[0]
    n_nees = nees_idx.shape[0]
    rep, y, present, truth, nav, err, chol = work.rep, work.y, work.present, work.truth, work.nav, work.err, work.chol
    tau, tau_cmd, tau_real, pwm = work.tau, work.tau_cmd, work.tau_real, work.pwm
    log_truth, log_y, log_status, log_reason = logs.truth, logs.y, logs.status, logs.reason
    log_x, log_P = logs.x, logs.P
    log_wrench, log_pwm, log_cons, log_ctrl = logs.wrench, logs.pwm, logs.cons, logs.ctrl
    # -- truth and sensors at t_k ---------------------------------------------------------
    if not plant_sample(k, plant, sensors, drive, row, truth, y, present):
        return False  # the plant diverged (absurd parameters or forces): stop, rows 0..row-1 hold
    for i in range(N_TRUTH):
        log_truth[row, i] = truth[i]
    for j in range(m):
        log_y[row, j] = y[j]
    # -- estimator: correct -----------------------------------------------------------------
    x_row = log_x[row]
    estimate(t, est, nav_of, y, present, rep, nav, x_row, log_P[row])
    ch = est.ch
    nis = 0.0
    used = 0
    for j in range(m):
        log_status[row, j] = ch[j, CH_STATUS]
        log_reason[row, j] = ch[j, CH_REASON]
        if rep[j, REP_EVENT] == EVENT_USED:
            nis += rep[j, REP_INNOV] ** 2 / rep[j, REP_S]
            used += 1
    log_cons[row, 0] = nis
    log_cons[row, 1] = used
    for a in range(n_nees):
        i = nees_idx[a]
        e = x_row[i] - truth[nav_of[i]]
        err[a] = wrap_angle(e) if nav_of[i] == _PSI else e
    log_cons[row, 2] = _nees(err, log_P[row], nees_idx, chol)
    # -- controller, allocation and thrusters; estimator: predict ----------------------------
    command(t, est, ctrl, act, drive.refs[row], True, nav, tau, tau_cmd, tau_real, pwm, log_ctrl[row])
    for i in range(nt):
        log_pwm[row, i] = pwm[i]
    for i in range(4):
        log_wrench[row, i] = tau_cmd[i]
        log_wrench[row, 4 + i] = tau[i]
    return True


@njit(cache=True, **WITHOUT_NRT)
def run_loop(k0, k1, h, plant, sensors, est, ctrl, act, nav_of, nees_idx, drive, logs, work):
    """Run control steps k0 .. k1-1 (t_k = k h). The components' state arrays are advanced in
    place; ``drive`` and ``logs`` are indexed by row = k - k0. Returns the number of rows done:
    k1 - k0, or fewer if the plant's true state stopped being finite (or beyond 1e9), in which
    case the run stops there rather than log garbage. ``work`` holds its scratch arrays
    (:func:`new_work`).

    nav_of (int64, n_x): the TRUTH index each estimator state estimates; nees_idx (int64): the
    estimator states whose error enters the NEES (those the plant has a truth for); angle states
    (psi) have their errors wrapped.
    """
    work.nav[:] = 0.0
    for k in range(k0, k1):
        row = k - k0
        if not _to_plant(k, row, k * h, plant, sensors, est, ctrl, act, nav_of, nees_idx, drive, logs, work):
            return row
        # -- the plant to t_k+1 (step 7) ---------------------------------------------------
        plant_advance(plant, drive, row, work.tau_cmd, work.tau_real)
    return k1 - k0


# What numba says when code compiled without reference counting (the loop, and what it inlines or
# compiles for it) needs the runtime's memory: a new array, list or string, or an exception built
# from a value known only at run time.
_ALLOCATION_MARKS = ("Only accept returning of array passed into the function as argument",
                     "NRT required but not enabled")


def allocation_error(exc: BaseException, components: tuple[object, ...]) -> TypeError | None:
    """A clear error for a compile failure of the loop (or the node's step) caused by a component
    kernel that allocates (np.empty, an array expression, a list, a string, an exception with a
    run-time message), naming the components and the line numba points at; None for any other
    exception."""
    text = str(exc)
    if not type(exc).__module__.startswith("numba") or not any(m in text for m in _ALLOCATION_MARKS):
        return None
    where = re.search(r'File "([^"]+)", line (\d+)', text)
    line = f" (numba points at {os.path.abspath(where.group(1))}, line {where.group(2)})" if where else ""
    names = ", ".join(type(c).__name__ for c in components)
    return TypeError(
        f"a kernel of the components {names} allocates memory (an array, a list, a string or an exception "
        f"message built at run time) inside the closed loop{line}. The loop is compiled without numba's "
        "reference counting, so its kernels must not allocate: keep scratch arrays as fields of the component "
        "(see docs/architecture.md), or move the work into a separate njit function decorated with "
        "**rovlab._jit.WITH_NRT (numba's reference counting on) "
        "that allocates inside and returns no array (an array it returned would never be freed)")


class explain_allocation:
    """``with explain_allocation(components): loop(...)``: a compile failure caused by a kernel
    that allocates leaves as :func:`allocation_error`'s TypeError (the simulator and the node use
    it around their first compiled call); anything else passes unchanged."""

    def __init__(self, components: tuple[object, ...]) -> None:
        self.components = components

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if exc is not None and isinstance(exc, Exception):
            clear = allocation_error(exc, self.components)
            if clear is not None:
                raise clear from exc


# numba keeps one cache index per function, listing every signature compiled for it. A component
# class defined outside rovlab (a user's script, a test module) in that index would make the
# index unreadable in any process that cannot import that module, so loops with such components
# are compiled by this uncached copy instead (per process).
run_loop_uncached = njit(cache=False, **WITHOUT_NRT)(getattr(run_loop, "py_func", run_loop))


def loop_for(*components: object):
    """The loop to call for these components: the disk-cached one when every component class is
    rovlab's own, else the per-process copy."""
    if all(type(c).__module__.startswith("rovlab.") for c in components):
        return run_loop
    return run_loop_uncached
