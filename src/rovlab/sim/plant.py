"""Plants for the closed-loop simulator: components of the plant slot (rovlab.core.components).

* :class:`ProcessPlant` (Sandøy 2016, ch. 3): x = [x, y, z, psi, u, v, w, r] integrated with
  fixed-step RK4 on the one right-hand side of the model (rovlab.models.kinetics.rk4_scalars); the
  force on the body is tau (from the thrusters) + b (Gauss-Markov biases, advanced with their
  exact discrete form) + w_nu (white noise of power spectral density W, held over each RK4 step
  as N(0, W / h), the zero-order-hold equivalent of white noise). The restoring force is in the
  packed parameters (rovlab.models.kinetics.pack). Truth events (a payload picked up, floats
  soaking up water: rovlab.sim.scenario) switch between the packed parameter sets ``p_sets``
  (row 0 is ``p``), chosen per control step by the drive (``drive.pset``), and a per-step extra
  downward heave force (``drive.heave_force``, e.g. a tether pull) adds to the thrust.
* :class:`ObserverPlant` ("perfect model"): the linear depth-and-heading model with its bias
  states, advanced exactly: x_{k+1} = Phi_h x_k + Delta_h u + L_h n_k, L_h L_h^T = Q_h (Van Loan
  at the plant step), so the filter's assumptions hold exactly. Its input is the wrench the
  allocation asked for (Z, N), the same the filter predicts with.

A Monte Carlo advances LANES runs of the process plant together (:func:`process_advance_lanes`,
the lanes of rovlab.sim.loop.run_loop_lanes): the lanes' states sit side by side in one array
and each RK4 step is one loop over the lanes, which the compiler turns into vector
instructions (16 lanes: ~4x the throughput of one run's RK4 here), with exactly the numbers of
each run alone (tested).

The standard normal draws are made beforehand with numpy's Generator from the run's seed and
handed in through the loop's drive (rovlab.sim.loop.Drive), so a run is reproducible from its
seed whatever compiles the loop.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rovlab._jit import njit
from rovlab.core.angles import wrap_angle
from rovlab.core.components import LANE_SCRATCH_ROWS, LANES, register_plant
from rovlab.models.kinetics import P_BUOY, P_SIZE, P_WEIGHT, rk4_scalars, rk4_stages, submerged


class ProcessPlant(NamedTuple):
    """The nonlinear 4-DOF process model with Gauss-Markov biases and white force noise."""

    p: np.ndarray  # packed parameters of the true vehicle (rovlab.models.kinetics.pack)
    x: np.ndarray  # state [x, y, z, psi, u, v, w, r]
    bias: np.ndarray  # Gauss-Markov bias force per DOF (4)
    bias_phi: np.ndarray  # exact discrete Gauss-Markov coefficients per control step (4)
    bias_std: np.ndarray  # (4)
    noise_std: np.ndarray  # sqrt(W / h_plant) of the white force noise (4)
    h: float  # RK4 step [s]
    n_sub: int  # RK4 steps per control step
    tb: np.ndarray  # (4) work
    p_sets: np.ndarray  # (n_sets, P_SIZE): the parameters after each truth event (row 0 = p)
    dist: np.ndarray  # (2): parameter set and extra heave force [N] of the last step



class ObserverPlant(NamedTuple):
    """The linear depth-and-heading model [z, psi, w, r, b_w, b_r], advanced exactly."""

    Phi: np.ndarray  # (6, 6) at the plant step
    Delta: np.ndarray  # (6, 2)
    L: np.ndarray  # (6, 6), L L^T = Q at the plant step
    x: np.ndarray  # (6)
    n_sub: int
    tmp: np.ndarray  # (6) work
    u: np.ndarray  # (2) work
    dist: np.ndarray  # (1): extra heave force [N] of the last step (events, tether)



@njit(cache=True, inline="always")
def _process_truth(plant, truth):
    x = plant.x
    for i in range(8):
        truth[i] = x[i]
    truth[3] = wrap_angle(x[3])
    # the force the estimator's bias states should absorb: Gauss-Markov bias + net buoyancy
    # (+ the extra heave force of the last step)
    truth[8] = plant.bias[0]
    truth[9] = plant.bias[1]
    ps = plant.p_sets[int(plant.dist[0])]
    net_up = submerged(ps, x[2]) * ps[P_BUOY] - ps[P_WEIGHT]
    truth[10] = plant.bias[2] + plant.dist[1] - net_up
    truth[11] = plant.bias[3]


@njit(cache=True)
def process_advance(p, x, tau_b, h, noise_std, normals):
    """Advance the process plant over len(normals) RK4 steps of length h (in place).

    tau_b (4) is the thruster force plus the bias, held over the control period (ZOH);
    normals (n_sub, 4) are standard normal draws and noise_std (4) = sqrt(W / h) scales them
    into the white force noise of each step. The state, and the cosine and sine of its heading,
    stay in registers between the steps (rovlab.models.kinetics.rk4_scalars); x is read and the
    heading's sine and cosine evaluated once per call (once per control period in the loop).
    """
    x0, x1, x2, x3, x4, x5, x6, x7 = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
    t0, t1, t2, t3 = tau_b[0], tau_b[1], tau_b[2], tau_b[3]
    s0, s1, s2, s3 = noise_std[0], noise_std[1], noise_std[2], noise_std[3]
    c, s = math.cos(x3), math.sin(x3)
    for j in range(normals.shape[0]):
        x0, x1, x2, x3, x4, x5, x6, x7, c, s = rk4_scalars(
            p, c, s, x0, x1, x2, x3, x4, x5, x6, x7, t0 + s0 * normals[j, 0], t1 + s1 * normals[j, 1],
            t2 + s2 * normals[j, 2], t3 + s3 * normals[j, 3], h)
    x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7] = x0, x1, x2, x3, x4, x5, x6, x7


@njit(cache=True, inline="always")
def _process_step(plant, drive, row, tau_cmd, tau_real):
    n = plant.n_sub
    tau_b = plant.tb
    for i in range(4):
        tau_b[i] = tau_real[i] + plant.bias[i]
    extra = drive.heave_force[row]
    tau_b[2] += extra
    j = drive.pset[row]
    process_advance(plant.p_sets[j], plant.x, tau_b, plant.h, plant.noise_std,
                    drive.plant_normals[row * n:(row + 1) * n])
    plant.dist[0] = j
    plant.dist[1] = extra
    for i in range(4):
        plant.bias[i] = plant.bias_phi[i] * plant.bias[i] + plant.bias_std[i] * drive.bias_normals[row, i]


# --------------------------------------------------------------------------------------------
# The process plant's lanes (a Monte Carlo's runs advanced together)
# --------------------------------------------------------------------------------------------
#
# The lanes' scratch (Lanes.scratch) holds rows of LANES values, lane l at row * LANES + l:
# the state x0..x7 and cos/sin of the heading (rows 0-9), the force held over the control
# period (10-13), the noise's standard deviations (14-17), this RK4 step's standard normals
# (18-21), and the step's result with its in-range flag (22-32). One flat array with a constant
# row stride lets the compiler prove that the rows do not overlap, so it vectorises the loop
# over the lanes without run-time alias checks.
_X, _F, _SD, _NRM, _OUT = 0, 10, 14, 18, 22
if _OUT + 11 > LANE_SCRATCH_ROWS or P_SIZE != 41:  # pragma: no cover - a reminder for whoever changes the packing
    raise ImportError("rovlab.sim.plant: the lanes' scratch is too small, or _params does not list every packed "
                      "parameter (it lists 41 one by one): update them")


@njit(cache=True, inline="always")
def _params(p):
    """The packed parameters as a tuple (kept in registers across the lanes' loop)."""
    return (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13], p[14],
            p[15], p[16], p[17], p[18], p[19], p[20], p[21], p[22], p[23], p[24], p[25], p[26], p[27], p[28],
            p[29], p[30], p[31], p[32], p[33], p[34], p[35], p[36], p[37], p[38], p[39], p[40])


@njit(cache=True, inline="always")
def _lane_step(p, w, lane, h, series):
    """rovlab.models.kinetics.rk4_stages of one lane of the scratch ``w`` (layout above)."""
    return rk4_stages(p, w[(_X + 8) * LANES + lane], w[(_X + 9) * LANES + lane],
                      w[_X * LANES + lane], w[(_X + 1) * LANES + lane], w[(_X + 2) * LANES + lane],
                      w[(_X + 3) * LANES + lane], w[(_X + 4) * LANES + lane], w[(_X + 5) * LANES + lane],
                      w[(_X + 6) * LANES + lane], w[(_X + 7) * LANES + lane],
                      w[_F * LANES + lane] + w[_SD * LANES + lane] * w[_NRM * LANES + lane],
                      w[(_F + 1) * LANES + lane] + w[(_SD + 1) * LANES + lane] * w[(_NRM + 1) * LANES + lane],
                      w[(_F + 2) * LANES + lane] + w[(_SD + 2) * LANES + lane] * w[(_NRM + 2) * LANES + lane],
                      w[(_F + 3) * LANES + lane] + w[(_SD + 3) * LANES + lane] * w[(_NRM + 3) * LANES + lane],
                      h, series)


@njit(cache=True, inline="always")
def _lane_store(w, lane, r):
    """The new state and heading cosine and sine (r[0:10], a tuple) into the lane's result rows."""
    w[_OUT * LANES + lane] = r[0]
    w[(_OUT + 1) * LANES + lane] = r[1]
    w[(_OUT + 2) * LANES + lane] = r[2]
    w[(_OUT + 3) * LANES + lane] = r[3]
    w[(_OUT + 4) * LANES + lane] = r[4]
    w[(_OUT + 5) * LANES + lane] = r[5]
    w[(_OUT + 6) * LANES + lane] = r[6]
    w[(_OUT + 7) * LANES + lane] = r[7]
    w[(_OUT + 8) * LANES + lane] = r[8]
    w[(_OUT + 9) * LANES + lane] = r[9]


@njit(cache=True, error_model="numpy")  # no Python division check: no early exit, so the lanes vectorise
def _rk4_lanes(p, w, n_lanes, h):
    """One RK4 step of lanes 0 .. n_lanes-1 of the scratch ``w`` (layout above), every heading
    increment by its series; returns how many lanes had an increment beyond the series' range
    (their results are then not those of rk4_scalars, and the caller redoes the step)."""
    pt = _params(p)
    for lane in range(n_lanes):
        r = _lane_step(pt, w, lane, h, True)
        _lane_store(w, lane, r)
        w[(_OUT + 10) * LANES + lane] = 1.0 if r[10] else 0.0
    outside = 0
    for lane in range(n_lanes):
        outside += w[(_OUT + 10) * LANES + lane] == 0.0
    return outside


@njit(cache=True)
def _rk4_lanes_exact(p, w, n_lanes, h):
    """The RK4 step of every lane as rk4_scalars does it (sin and cos where an increment is
    large): for a step where some lane left the series' range (a very fast turn, or a diverging
    plant)."""
    for lane in range(n_lanes):
        _lane_store(w, lane, _lane_step(p, w, lane, h, False))


@njit(cache=True)
def process_advance_lanes(plants, drives, row, lanes):
    """plant_advance_lanes of the process plant: every running lane over one control period,
    with exactly the numbers _process_step gives each run alone. ``plants`` are the lanes'
    plants stacked (rovlab.core.components.stacked: state x, bias, dist per lane; the
    parameters, steps and noise levels shared) and ``drives`` their drives
    (rovlab.sim.loop.stacked_drive)."""
    active = lanes.active
    n_lanes = active.shape[0]
    w = lanes.scratch
    n = plants.n_sub
    h = plants.h
    j = drives.pset[row]
    p = plants.p_sets[j]
    extra = drives.heave_force[row]
    xs = plants.x
    bias = plants.bias
    for lane in range(n_lanes):
        if active[lane]:
            for i in range(8):
                w[(_X + i) * LANES + lane] = xs[lane, i]
            w[(_X + 8) * LANES + lane] = math.cos(xs[lane, 3])
            w[(_X + 9) * LANES + lane] = math.sin(xs[lane, 3])
            for i in range(4):
                w[(_F + i) * LANES + lane] = lanes.tau_real[lane, i] + bias[lane, i]
                w[(_SD + i) * LANES + lane] = plants.noise_std[i]
            w[(_F + 2) * LANES + lane] += extra
        else:  # no run in this lane, or its plant diverged: a vehicle at rest, never read back
            for i in range(_NRM):
                w[i * LANES + lane] = 0.0
            w[(_X + 8) * LANES + lane] = 1.0
    normals = drives.plant_normals
    for step in range(n):
        k = row * n + step
        for lane in range(n_lanes):
            if active[lane]:
                for i in range(4):
                    w[(_NRM + i) * LANES + lane] = normals[lane, k, i]
            else:
                for i in range(4):
                    w[(_NRM + i) * LANES + lane] = 0.0
        if _rk4_lanes(p, w, n_lanes, h) > 0:  # some lane turned beyond the series' range: the exact step
            _rk4_lanes_exact(p, w, n_lanes, h)
        for i in range(10):
            for lane in range(n_lanes):
                w[(_X + i) * LANES + lane] = w[(_OUT + i) * LANES + lane]
    bias_normals = drives.bias_normals
    for lane in range(n_lanes):
        if active[lane]:
            for i in range(8):
                xs[lane, i] = w[(_X + i) * LANES + lane]
            plants.dist[lane, 0] = j
            plants.dist[lane, 1] = extra
            for i in range(4):
                bias[lane, i] = plants.bias_phi[i] * bias[lane, i] + plants.bias_std[i] * bias_normals[lane, row, i]


@njit(cache=True, inline="always")
def _observer_truth(plant, truth):
    x = plant.x
    for i in range(truth.shape[0]):
        truth[i] = 0.0
    truth[2] = x[0]
    truth[3] = wrap_angle(x[1])
    truth[6] = x[2]
    truth[7] = x[3]
    truth[10] = x[4] + plant.dist[0]
    truth[11] = x[5]


@njit(cache=True, inline="always")
def _linear_steps(Phi, Delta, L, x, u, normals, tmp, m, p):
    for s in range(normals.shape[0]):
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += Phi[i, j] * x[j] + L[i, j] * normals[s, j]
            for j in range(p):
                acc += Delta[i, j] * u[j]
            tmp[i] = acc
        for i in range(m):
            x[i] = tmp[i]


@njit(cache=True)
def linear_advance(Phi, Delta, L, x, u, normals, tmp):
    """Advance x <- Phi x + Delta u + L n over len(normals) exact steps (in place).

    The depth-and-heading model's sizes (6 states, 2 inputs) are passed as constants, which
    lets the compiler unroll the sums (~30 % faster, the same sums in the same order)."""
    if x.shape[0] == 6 and u.shape[0] == 2:
        _linear_steps(Phi, Delta, L, x, u, normals, tmp, 6, 2)
    else:
        _linear_steps(Phi, Delta, L, x, u, normals, tmp, x.shape[0], u.shape[0])


@njit(cache=True, inline="always")
def _observer_step(plant, drive, row, tau_cmd, tau_real):
    n = plant.n_sub
    u = plant.u
    u[0] = tau_cmd[2] + drive.heave_force[row]
    u[1] = tau_cmd[3]
    plant.dist[0] = drive.heave_force[row]
    linear_advance(plant.Phi, plant.Delta, plant.L, plant.x, u,
                   drive.plant_normals[row * n:(row + 1) * n], plant.tmp)


register_plant(ProcessPlant, state=("x", "bias", "dist"), draws=4, truth=_process_truth, advance=_process_step,
               advance_lanes=process_advance_lanes)
register_plant(ObserverPlant, state=("x", "dist"), draws=6, truth=_observer_truth, advance=_observer_step)
