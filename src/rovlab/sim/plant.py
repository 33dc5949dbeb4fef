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

The standard normal draws are made beforehand with numpy's Generator from the run's seed and
handed in through the loop's drive (rovlab.sim.loop.Drive), so a run is reproducible from its
seed whatever compiles the loop.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.angles import wrap_angle
from rovlab.core.components import NAV_BN, NAV_BX, NAV_BY, NAV_BZ, NAV_PSI, NAV_R, NAV_W, NAV_Z, register_plant
from rovlab.models.kinetics import P_BUOY, P_WEIGHT, rk4_scalars, submerged


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
    truth[NAV_PSI] = wrap_angle(x[3])
    # the force the estimator's bias states should absorb: Gauss-Markov bias + net buoyancy
    # (+ the extra heave force of the last step)
    truth[NAV_BX] = plant.bias[0]
    truth[NAV_BY] = plant.bias[1]
    ps = plant.p_sets[int(plant.dist[0])]
    net_up = submerged(ps, x[2]) * ps[P_BUOY] - ps[P_WEIGHT]
    truth[NAV_BZ] = plant.bias[2] + plant.dist[1] - net_up
    truth[NAV_BN] = plant.bias[3]


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
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


@njit(cache=True, inline="always")
def _observer_truth(plant, truth):
    x = plant.x
    for i in range(truth.shape[0]):
        truth[i] = 0.0
    truth[NAV_Z] = x[0]
    truth[NAV_PSI] = wrap_angle(x[1])
    truth[NAV_W] = x[2]
    truth[NAV_R] = x[3]
    truth[NAV_BZ] = x[4] + plant.dist[0]
    truth[NAV_BN] = x[5]


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


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def linear_advance(Phi, Delta, L, x, u, normals, tmp):
    """Advance x <- Phi x + Delta u + L n over len(normals) exact steps (in place).

    The depth-and-heading model's sizes (6 states, 2 inputs) are passed as constants, which
    lets the compiler unroll the sums (~30 % faster, the same sums in the same order)."""
    if x.shape[0] == 6 and u.shape[0] == 2:
        _linear_steps(Phi, Delta, L, x, u, normals, tmp, 6, 2)
    else:
        _linear_steps(Phi, Delta, L, x, u, normals, tmp, x.shape[0], u.shape[0])


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _observer_step(plant, drive, row, tau_cmd, tau_real):
    n = plant.n_sub
    u = plant.u
    u[0] = tau_cmd[2] + drive.heave_force[row]
    u[1] = tau_cmd[3]
    plant.dist[0] = drive.heave_force[row]
    linear_advance(plant.Phi, plant.Delta, plant.L, plant.x, u,
                   drive.plant_normals[row * n:(row + 1) * n], plant.tmp)


register_plant(ProcessPlant, state=("x", "bias", "dist"), draws=4, truth=_process_truth, advance=_process_step)
register_plant(ObserverPlant, state=("x", "dist"), draws=6, truth=_observer_truth, advance=_observer_step)
