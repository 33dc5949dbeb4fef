"""The closed-loop simulator: plant, thrusters and allocation, sensors, Kalman filter and LQG
controller in one compiled loop (SPEC sections 4, 5, 7).

Timing, at control sample k (t_k = k h, h the filter's sample time, 0.1 s for uDrone):

1. sensors sample the true state at t_k (each at its own rate, with its noise and lever arm;
   none during a drop-out window),
2. the filter corrects with the samples that arrived and reports x_k,
3. the controller computes tau_k = P r_k - K x_k - b_k (heading error wrapped), which is
   allocated to the thrusters (saturation-aware), turned into PWM commands (quantised) and
   back into the thrust the thrusters really give,
4. the filter predicts with the wrench the allocation achieved, and the plant is integrated
   from t_k to t_k+1 with the thrust held (zero-order hold): RK4 at ``plant_step_s`` for the
   process model, the exact discrete solution for the observer model.

Row k of the log holds t_k, the truth at t_k, the samples y_k, the corrected estimate x_k, the
reference and the commands of step k. All random numbers are drawn beforehand from the run's
seed (numpy Generator), so a run is reproducible from its seed alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from numba import njit

from rovlab.allocation.solvers import Allocator, allocate_kernel, matvec
from rovlab.control.lqg import lqg_tau
from rovlab.control.lqr import design_lqr_from_config
from rovlab.estimation.discretise import discretise
from rovlab.estimation.fusion import CH_STATUS, N_REP, REP_EVENT, REP_INNOV, REP_S, EVENT_USED, new_channel_state
from rovlab.estimation.kalman import correct_arrays, pack_model, predict_arrays, unpack_model, work_size
from rovlab.estimation.model import FilterModel, build_filter_model
from rovlab.models import kinetics as kin
from rovlab.models.noise import gauss_markov_coefficients, psd_factor
from rovlab.models.thrusters import ThrusterBank, bank_force, bank_pwm
from rovlab.params.design import DesignConfig, load_design_config
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle, load_vehicle
from rovlab.sim import metrics as mx
from rovlab.sim.plant import linear_advance, process_advance
from rovlab.sim.scenario import Scenario, scenario_from_dict

PLANT_PROCESS, PLANT_OBSERVER = 0, 1
_Z, _PSI = 0, 1  # truth quantities a channel can measure (index into [z, psi, w, r])
_QUANTITY_INDEX = {"z": 0, "psi": 1, "w": 2, "r": 3}


# --------------------------------------------------------------------------------------------
# The compiled loop
# --------------------------------------------------------------------------------------------

@njit(cache=True)
def _wrap(a: float) -> float:
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


@njit(cache=True)
def _nees(e, P, n, L):
    """e^T P^-1 e over the first n states by Cholesky (NaN if P is not positive definite)."""
    for j in range(n):
        acc = P[j, j]
        for k in range(j):
            acc -= L[j, k] * L[j, k]
        if not acc > 0.0:
            return np.nan
        L[j, j] = math.sqrt(acc)
        for i in range(j + 1, n):
            acc = P[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    total = 0.0
    for i in range(n):  # forward substitution L z = e, accumulating z^T z
        acc = e[i]
        for k in range(i):
            acc -= L[i, k] * e[k]
        e[i] = acc / L[i, i]
        total += e[i] * e[i]
    return total


@njit(cache=True)
def closed_loop(
    k0, k1, h, n_sub, h_plant, plant_kind,
    # process plant
    p_truth, xp, noise_std, plant_normals, bias, bias_phi, bias_std, bias_normals,
    # observer plant
    Phi_p, Delta_p, L_p, xo, obs_normals,
    # sensors (one per filter channel)
    ch_quantity, ch_offset, ch_std, ch_period, dropout, sensor_normals,
    # filter
    fmodel, xf, Pf, chs,
    # controller
    K, Pref, refs,
    # allocation and thrusters
    B, T, s_alloc, f_min, f_max, level, n_levels, rows, grid_pwm, grid_force, pwm_res,
    # logs (row k - k0)
    log_true, log_y, log_x, log_P, log_u, log_pwm, log_status, log_cons, log_bias,
):
    """Run control steps k0 .. k1-1 (t_k = k h). State arrays (xp, bias, xo, xf, Pf, chs) are
    advanced in place; per-step inputs (noise draws, references, drop-out mask) and the logs are
    indexed by row = k - k0, so a long run can be done in chunks (the live HMI does)."""
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(fmodel)
    n = xf.shape[0]
    m = H.shape[0]
    nt = rows.shape[0]
    rep = np.empty((m, N_REP))
    work = np.empty(work_size(n, m))
    y = np.empty(m)
    present = np.empty(m, dtype=np.bool_)
    kwork = np.empty((4, 8))
    fwork = np.empty(4)
    tmp6 = np.empty(Phi_p.shape[0])
    tau6 = np.zeros(6)
    tau_b = np.empty(4)
    truth = np.empty(4)
    err = np.empty(6)
    chol = np.empty((6, 6))
    u = np.empty(2)
    for k in range(k0, k1):
        row = k - k0
        t = k * h
        # -- truth at t_k ------------------------------------------------------------------
        if plant_kind == PLANT_PROCESS:
            truth[0] = xp[2]
            truth[1] = _wrap(xp[3])
            truth[2] = xp[6]
            truth[3] = xp[7]
        else:
            truth[0] = xo[0]
            truth[1] = _wrap(xo[1])
            truth[2] = xo[2]
            truth[3] = xo[3]
        for i in range(4):
            log_true[row, i] = truth[i]
        # -- sensors ----------------------------------------------------------------------
        for j in range(m):
            if ch_period[j] > 0 and k % ch_period[j] == 0 and not dropout[row, j]:
                v = truth[ch_quantity[j]] + ch_offset[j] + ch_std[j] * sensor_normals[row, j]
                if ch_quantity[j] == _PSI:
                    v = _wrap(v)
                y[j] = v
                present[j] = True
            else:
                y[j] = np.nan
                present[j] = False
            log_y[row, j] = y[j]
        # -- filter: correct --------------------------------------------------------------
        correct_arrays(xf, Pf, chs, H, cfg, wrap, t, y, present, rep, work)
        for i in range(n):
            log_x[row, i] = xf[i]
            for jj in range(n):
                log_P[row, i, jj] = Pf[i, jj]
        nis = 0.0
        used = 0
        for j in range(m):
            log_status[row, j] = chs[j, CH_STATUS]
            if rep[j, REP_EVENT] == EVENT_USED:
                nis += rep[j, REP_INNOV] ** 2 / rep[j, REP_S]
                used += 1
        log_cons[row, 0] = nis
        log_cons[row, 1] = used
        # NEES of the corrected estimate: z, psi, w, r (and the biases when the plant has them)
        nn = 6 if plant_kind == PLANT_OBSERVER else 4
        for i in range(4):
            err[i] = xf[i] - truth[i]
        err[1] = _wrap(err[1])
        if nn == 6:
            err[4] = xf[4] - xo[4]
            err[5] = xf[5] - xo[5]
        log_cons[row, 2] = _nees(err, Pf, nn, chol)
        # -- controller: tau = P r - K x - b (heading error wrapped) ----------------------
        lqg_tau(K, Pref, xf, refs[row], u)
        # -- allocation, PWM, real thrust --------------------------------------------------
        tau6[:] = 0.0
        tau6[2] = u[0]
        tau6[5] = u[1]
        f, frac = allocate_kernel(B, T, s_alloc, f_min, f_max, tau6, level, n_levels, True)
        pwm = bank_pwm(rows, grid_pwm, grid_force, f)
        if pwm_res > 0.0:
            for i in range(nt):
                pwm[i] = pwm_res * np.round(pwm[i] / pwm_res)
        f_real = bank_force(rows, grid_pwm, grid_force, pwm)
        for i in range(nt):
            log_pwm[row, i] = pwm[i]
        achieved = matvec(B, f)
        log_u[row, 0] = achieved[2]
        log_u[row, 1] = achieved[5]
        log_u[row, 2] = u[0]
        log_u[row, 3] = u[1]
        u[0] = achieved[2]
        u[1] = achieved[5]
        # -- filter: predict with what the thrusters were asked to give --------------------
        predict_arrays(xf, Pf, Delta, Q, wrap, sp, u, work)
        # -- plant from t_k to t_k+1 --------------------------------------------------------
        if plant_kind == PLANT_PROCESS:
            real = matvec(B, f_real)
            for i in range(4):
                log_bias[row, i] = bias[i]
            tau_b[0] = real[0] + bias[0]
            tau_b[1] = real[1] + bias[1]
            tau_b[2] = real[2] + bias[2]
            tau_b[3] = real[5] + bias[3]
            process_advance(p_truth, xp, tau_b, h_plant, noise_std, plant_normals[row * n_sub:(row + 1) * n_sub],
                            kwork, fwork)
            for i in range(4):
                bias[i] = bias_phi[i] * bias[i] + bias_std[i] * bias_normals[row, i]
        else:
            log_bias[row, 2] = xo[4]
            log_bias[row, 3] = xo[5]
            linear_advance(Phi_p, Delta_p, L_p, xo, u, obs_normals[row * n_sub:(row + 1) * n_sub], tmp6)


# --------------------------------------------------------------------------------------------
# Preparing a run
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Prepared:
    """A scenario with everything the compiled loop needs (models, gains, noise draws)."""

    scenario: Scenario
    vehicle: Vehicle  # the vehicle as the filter/controller know it
    truth: Vehicle  # the plant's true vehicle
    config: DesignConfig
    filter_model: FilterModel
    K: np.ndarray  # LQR gain (2 x 4)
    Pref: np.ndarray  # reference feed-forward (2 x 2)
    allocator: Allocator
    arrays: dict[str, Any] = field(repr=False)


def lqr_gains(vehicle: Vehicle, config: DesignConfig) -> tuple[np.ndarray, np.ndarray]:
    """Discrete LQR gain K and reference gain P of the configuration (SPEC section 6)."""
    design = design_lqr_from_config(vehicle, config)
    return np.ascontiguousarray(design.K), np.ascontiguousarray(design.P)


def prepare(data: Mapping[str, Any] | Scenario, *, file: str = "<dict>", seed: int | None = None,
            vehicle: Vehicle | None = None, truth: Vehicle | None = None,
            config: DesignConfig | None = None) -> Prepared:
    """Resolve a scenario (a dict from its TOML, or a Scenario) into a runnable Prepared.

    ``vehicle`` / ``config`` replace the scenario's vehicle (the model the filter and the
    controller use) and filter/controller configuration; ``truth`` replaces the plant's vehicle
    (by default the model vehicle with the scenario's [truth] parameters).
    """
    sc = data if isinstance(data, Scenario) else scenario_from_dict(data, file=file, seed=seed)
    vehicle = vehicle if vehicle is not None else _load_ref(sc, "vehicle", load_vehicle)
    config = config if config is not None else _load_ref(sc, "design", load_design_config)
    design = _design(vehicle, config, sc.plant, sc.plant_step_s)
    fm, K, Pref, allocator = design.fm, design.K, design.Pref, design.allocator
    h = fm.h
    n_sub = int(round(h / sc.plant_step_s))
    if n_sub < 1 or abs(n_sub * sc.plant_step_s - h) > 1e-9 * h:
        raise ConfigError([Problem(sc.file, "plant_step_s", sc.plant_step_s,
                                   f"a step that divides the filter's sample time {h:g} s")], "scenario file")
    n_ctrl = int(math.floor(sc.duration_s / h + 1e-9)) + 1
    truth = truth if truth is not None else _truth_vehicle(vehicle, sc)
    bank = allocator.bank if truth.thrusters is vehicle.thrusters else ThrusterBank.from_vehicle(truth)
    rng = np.random.default_rng(sc.seed)

    # channels: which true quantity, lever arm, noise (the vehicle's true sensor variance), period
    m = len(fm.channels)
    ch_quantity = np.array([_QUANTITY_INDEX[c.quantity] for c in fm.channels], dtype=np.int64)
    ch_offset = np.array([c.offset for c in fm.channels])
    ch_std = np.array([math.sqrt(truth.sensor(c.sensor).variance.get(c.quantity, c.variance)) for c in fm.channels])
    ch_period = np.array([max(1, int(round(1.0 / (truth.sensor(c.sensor).rate_hz * h)))) for c in fm.channels],
                         dtype=np.int64)
    times = np.arange(n_ctrl) * h
    dropout = np.zeros((n_ctrl, m), dtype=np.bool_)
    known = {c.sensor for c in fm.channels}
    problems = []
    for i, d in enumerate(sc.dropouts):
        if d.sensor not in known:
            problems.append(Problem(sc.file, f"dropout[{i}].sensor", d.sensor,
                                    "a sensor the filter uses: " + ", ".join(sorted(known))))
            continue
        cols = [j for j, c in enumerate(fm.channels) if c.sensor == d.sensor and d.channel in (None, c.quantity)]
        if not cols:
            problems.append(Problem(sc.file, f"dropout[{i}].sensor", f"{d.sensor}.{d.channel}",
                                    "a channel the filter uses: " + ", ".join(c.name for c in fm.channels)))
        window = (times >= d.start_s) & (times < d.end_s)
        for j in cols:
            dropout[window, j] = True
    if problems:
        raise ConfigError(problems, "scenario file")
    idx = np.maximum(np.searchsorted(sc.reference_times, times, side="right") - 1, 0)
    refs = np.column_stack([sc.reference_z[idx], sc.reference_psi[idx]])

    # plant
    p_truth = kin.pack(truth)
    p_truth[kin.P_GZ] -= sc.buoyancy_offset
    xp = sc.initial.copy()
    noise_std = np.sqrt(sc.process_noise_psd / sc.plant_step_s)
    bias_phi, bias_std = gauss_markov_coefficients(sc.bias_std**2, 1.0 / sc.bias_time_constant_s, h)
    bias = sc.bias_std * rng.standard_normal(4)  # start in the stationary distribution
    Phi_p, Delta_p, L_p = design.Phi_p, design.Delta_p, design.L_p
    if sc.plant == "observer":
        plant_normals = np.zeros((0, 4), dtype=np.float32)
        obs_normals = rng.standard_normal((n_ctrl * n_sub, 6), dtype=np.float32)
    else:
        plant_normals = rng.standard_normal((n_ctrl * n_sub, 4), dtype=np.float32)
        obs_normals = np.zeros((0, 6), dtype=np.float32)
    xo = np.array([sc.initial[2], sc.initial[3], sc.initial[6], sc.initial[7], 0.0, 0.0])
    bias_normals = rng.standard_normal((n_ctrl, 4))
    sensor_normals = rng.standard_normal((n_ctrl, m))

    fmodel = design.fmodel
    arrays = dict(
        n_ctrl=n_ctrl, h=h, n_sub=n_sub, h_plant=sc.plant_step_s,
        plant_kind=PLANT_PROCESS if sc.plant == "process" else PLANT_OBSERVER,
        p_truth=p_truth, xp=xp, noise_std=noise_std, plant_normals=plant_normals, bias=bias,
        bias_phi=np.asarray(bias_phi, float), bias_std=np.asarray(bias_std, float), bias_normals=bias_normals,
        Phi_p=np.ascontiguousarray(Phi_p), Delta_p=np.ascontiguousarray(Delta_p), L_p=np.ascontiguousarray(L_p),
        xo=xo, obs_normals=obs_normals,
        ch_quantity=ch_quantity, ch_offset=ch_offset, ch_std=ch_std, ch_period=ch_period, dropout=dropout,
        sensor_normals=sensor_normals, fmodel=fmodel, xf=fm.x0.astype(float).copy(), Pf=fm.P0.astype(float).copy(),
        chs=new_channel_state(m), K=K, Pref=Pref, refs=refs,
        B=allocator.B, T=allocator.T, s_alloc=allocator._s, f_min=allocator.f_min, f_max=allocator.f_max,
        level=allocator.level, n_levels=allocator.n_levels, rows=bank.rows, grid_pwm=bank.grid_pwm,
        grid_force=bank.grid_force, pwm_res=sc.pwm_resolution_us,
    )
    return Prepared(sc, vehicle, truth, config, fm, K, Pref, allocator, arrays)


@dataclass(frozen=True, eq=False)
class _Design:
    """What depends only on the vehicle, the configuration and the plant step (shared by runs)."""

    vehicle: Vehicle
    config: DesignConfig
    fm: FilterModel
    K: np.ndarray
    Pref: np.ndarray
    allocator: Allocator
    fmodel: np.ndarray
    Phi_p: np.ndarray
    Delta_p: np.ndarray
    L_p: np.ndarray


_DESIGNS: dict[tuple, _Design] = {}


def _design(vehicle: Vehicle, config: DesignConfig, plant: str, plant_step: float) -> _Design:
    """Filter model, LQR gains, allocator and the observer plant's discretisation, cached per
    (vehicle, configuration, plant) objects: Monte Carlo runs share them (they are immutable)."""
    key = (id(vehicle), id(config), plant, plant_step)
    hit = _DESIGNS.get(key)
    if hit is not None and hit.vehicle is vehicle and hit.config is config:
        return hit
    fm = build_filter_model(vehicle, config)
    K, Pref = lqr_gains(vehicle, config)
    if plant == "observer":
        disc = discretise(fm.A, fm.B, fm.E, fm.W, plant_step)
        Phi_p, Delta_p, L_p = disc.Phi, disc.Delta, psd_factor(disc.Q)
    else:
        Phi_p, Delta_p, L_p = np.eye(6), np.zeros((6, 2)), np.zeros((6, 6))
    fmodel = pack_model(fm.Phi, fm.Delta, fm.Q, fm.H, fm.channel_config(), fm.wrap_states())
    d = _Design(vehicle, config, fm, K, Pref, Allocator(vehicle), fmodel, np.ascontiguousarray(Phi_p),
                np.ascontiguousarray(Delta_p), np.ascontiguousarray(L_p))
    if len(_DESIGNS) > 32:
        _DESIGNS.clear()
    _DESIGNS[key] = d
    return d


_FILES: dict[tuple, Any] = {}


def _load_cached(loader, ref: str):
    """Load a vehicle/configuration once per (file, modification time)."""
    from pathlib import Path

    path = Path(ref)
    stamp = path.stat().st_mtime_ns if path.exists() else None
    key = (loader.__name__, ref, stamp)
    if key not in _FILES:
        if len(_FILES) > 64:
            _FILES.clear()
        _FILES[key] = loader(ref)
    return _FILES[key]


def _load_ref(sc: Scenario, key: str, loader):
    ref = getattr(sc, key)
    try:
        return _load_cached(loader, ref)
    except ConfigError as exc:
        # say which scenario key pointed there
        raise ConfigError([Problem(sc.file, key, ref, f"a loadable {key}: {p}") for p in exc.problems],
                          "scenario file") from None


def _truth_vehicle(vehicle: Vehicle, sc: Scenario) -> Vehicle:
    tp = dict(sc.truth_parameters)
    if not tp:
        return vehicle
    changes: dict[str, Any] = {}
    if "mass" in tp:
        changes["mass"] = tp["mass"]
    if "I_zz" in tp:
        changes["I_zz"] = tp["I_zz"]
    if "displaced_volume" in tp:
        changes["displaced_volume"] = tp["displaced_volume"]
    added = vehicle.added_mass.copy()
    for i, key in enumerate(("X_udot", "Y_vdot", "Z_wdot", "N_rdot")):
        if key in tp:
            added[i] = tp[key]
    changes["added_mass"] = added
    return vehicle.with_updates(**changes)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SimResult:
    """Logs of one run (rows at the control rate) and what is needed to read them."""

    scenario: Scenario
    columns: dict[str, np.ndarray]  # the time-series contract (timeseries.csv)
    P: np.ndarray  # (K, 6, 6) corrected covariances
    nees: np.ndarray  # (K,) NEES of the states in nees_states
    nees_states: tuple[str, ...]
    nis: np.ndarray  # (K,) NIS per used measurement (NaN when none was used)
    channels: tuple[str, ...]
    thrusters: tuple[str, ...]
    meta: dict[str, Any]


def run_prepared(prep: Prepared) -> SimResult:
    a = prep.arrays
    n_ctrl = a["n_ctrl"]
    m = len(prep.filter_model.channels)
    nt = a["rows"].shape[0]
    logs = dict(
        log_true=np.empty((n_ctrl, 4)), log_y=np.empty((n_ctrl, m)), log_x=np.empty((n_ctrl, 6)),
        log_P=np.empty((n_ctrl, 6, 6)), log_u=np.empty((n_ctrl, 4)), log_pwm=np.empty((n_ctrl, nt)),
        log_status=np.empty((n_ctrl, m)), log_cons=np.empty((n_ctrl, 3)), log_bias=np.zeros((n_ctrl, 4)),
    )
    st = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in a.items()}
    closed_loop(
        0, n_ctrl, st["h"], st["n_sub"], st["h_plant"], st["plant_kind"],
        st["p_truth"], st["xp"], st["noise_std"], st["plant_normals"], st["bias"], st["bias_phi"], st["bias_std"],
        st["bias_normals"], st["Phi_p"], st["Delta_p"], st["L_p"], st["xo"], st["obs_normals"],
        st["ch_quantity"], st["ch_offset"], st["ch_std"], st["ch_period"], st["dropout"], st["sensor_normals"],
        st["fmodel"], st["xf"], st["Pf"], st["chs"], st["K"], st["Pref"], st["refs"],
        st["B"], st["T"], st["s_alloc"], st["f_min"], st["f_max"], st["level"], st["n_levels"], st["rows"],
        st["grid_pwm"], st["grid_force"], st["pwm_res"],
        logs["log_true"], logs["log_y"], logs["log_x"], logs["log_P"], logs["log_u"], logs["log_pwm"],
        logs["log_status"], logs["log_cons"], logs["log_bias"],
    )
    return _result(prep, logs)


def _result(prep: Prepared, logs: Mapping[str, np.ndarray]) -> SimResult:
    sc = prep.scenario
    fm = prep.filter_model
    a = prep.arrays
    n_ctrl = a["n_ctrl"]
    t = np.arange(n_ctrl) * a["h"]
    cols: dict[str, np.ndarray] = {"time_s": t}
    for i, s in enumerate(("z", "psi", "w", "r")):
        cols[f"true_{s}"] = logs["log_true"][:, i]
    for i, s in enumerate(fm.states):
        cols[f"est_{s}"] = logs["log_x"][:, i]
    for j, c in enumerate(fm.channels):
        cols[f"meas_{c.column}"] = logs["log_y"][:, j]
    cols["ref_z"] = a["refs"][:, 0]
    cols["ref_psi"] = a["refs"][:, 1]
    cols["tau_Z"] = logs["log_u"][:, 0]
    cols["tau_N"] = logs["log_u"][:, 1]
    for i, name in enumerate(prep.allocator.bank.names):
        cols[f"pwm_{name}"] = logs["log_pwm"][:, i]
    # extras beyond the contract
    for i, s in enumerate(fm.states):
        cols[f"var_{s}"] = logs["log_P"][:, i, i]
    for j, c in enumerate(fm.channels):
        cols[f"status_{c.column}"] = logs["log_status"][:, j]
    cols["tau_Z_demanded"] = logs["log_u"][:, 2]
    cols["tau_N_demanded"] = logs["log_u"][:, 3]
    if sc.plant == "observer":
        cols["true_b_w"] = logs["log_bias"][:, 2]
        cols["true_b_r"] = logs["log_bias"][:, 3]
        idx = [0, 1, 2, 3, 4, 5]
    else:
        # the force the filter's bias should absorb: Gauss-Markov bias + net buoyancy
        cols["true_bias_heave"] = logs["log_bias"][:, 2] - a["p_truth"][kin.P_GZ]
        cols["true_bias_yaw"] = logs["log_bias"][:, 3]
        idx = [0, 1, 2, 3]
    nees = logs["log_cons"][:, 2]
    nis_sum, used = logs["log_cons"][:, 0], logs["log_cons"][:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        nis = np.where(used > 0, nis_sum / np.maximum(used, 1), np.nan)
    meta = {
        "scenario": sc.name, "seed": sc.seed, "plant": sc.plant, "vehicle": prep.vehicle.name,
        "design": prep.config.name, "title": f"{sc.name} (seed {sc.seed})",
        "dropouts": [{"sensor": d.sensor + (f".{d.channel}" if d.channel else ""), "start_s": d.start_s,
                      "end_s": d.end_s} for d in sc.dropouts],
        "channels": [c.name for c in fm.channels], "thrusters": list(prep.allocator.bank.names),
        "measurement_offsets": {f"meas_{c.column}": c.offset for c in fm.channels},
        "sample_time_s": a["h"], "plant_step_s": a["h_plant"],
    }
    return SimResult(sc, cols, logs["log_P"], nees, tuple(fm.states[i] for i in idx), nis,
                     tuple(c.name for c in fm.channels), tuple(prep.allocator.bank.names), meta)


def simulate(name_or_path: str, *, seed: int | None = None) -> SimResult:
    """Load a scenario (packaged name or TOML path), run it and return the logs."""
    from rovlab.sim.scenario import load_scenario

    return run_prepared(prepare(load_scenario(name_or_path, seed=seed)))


def summarise(result: SimResult) -> dict[str, Any]:
    """metrics.json of one run (SPEC section 7): RMS error per state, step response per axis,
    drop-out drift and NEES/NIS consistency."""
    c = result.columns
    sc = result.scenario
    t = c["time_s"]
    out: dict[str, Any] = {"scenario": sc.name, "seed": sc.seed, "plant": sc.plant}
    states = ["z", "psi", "w", "r"]
    est = np.column_stack([c[f"est_{s}"] for s in states])
    true = np.column_stack([c[f"true_{s}"] for s in states])
    err = mx.estimation_error(est, true)
    out["rms_error"] = dict(zip(states, map(float, mx.rms(err))))
    if sc.plant == "observer":
        eb = np.column_stack([c["est_b_w"] - c["true_b_w"], c["est_b_r"] - c["true_b_r"]])
        out["rms_error"].update(dict(zip(("b_w", "b_r"), map(float, mx.rms(eb)))))
    # steps of the reference schedule, per axis, judged on the true state
    steps = []
    prev_z, prev_psi = sc.initial[2], sc.initial[3]
    times = list(sc.reference_times) + [sc.duration_s + 1.0]
    for i, t0 in enumerate(sc.reference_times):
        t1 = times[i + 1]
        z1, psi1 = float(sc.reference_z[i]), float(sc.reference_psi[i])
        if abs(z1 - prev_z) > 1e-12:
            r = mx.step_response(t, c["true_z"], t0, prev_z, z1, t1, band=0.02, min_band=0.005)
            steps.append({"axis": "z", **r})
        if abs(mx.wrap(psi1 - prev_psi)) > 1e-12:
            r = mx.step_response(t, c["true_psi"], t0, prev_psi, psi1, t1, band=0.02, min_band=math.radians(0.5),
                                 angle=True)
            steps.append({"axis": "psi", **r})
        prev_z, prev_psi = z1, psi1
    out["steps"] = steps
    out["settling_time_s"] = {}
    out["overshoot"] = {}
    for axis in ("z", "psi"):
        mine = [s for s in steps if s["axis"] == axis]
        if mine:
            st = [s["settling_time_s"] for s in mine]
            out["settling_time_s"][axis] = None if any(v is None for v in st) else max(st)
            out["overshoot"][axis] = max(s["overshoot"] or 0.0 for s in mine)
    # drop-outs: what dead reckoning costs
    drops = []
    for d in sc.dropouts:
        w = (t >= d.start_s) & (t < d.end_s)
        before = (t >= max(0.0, d.start_s - (d.end_s - d.start_s))) & (t < d.start_s)
        after = (t >= d.end_s) & (t < d.end_s + 10.0)
        if not w.any():
            continue
        e_psi = err[:, 1]
        i0 = int(np.argmax(w))
        i1 = int(len(w) - 1 - np.argmax(w[::-1]))
        drops.append({
            "sensor": d.sensor + (f".{d.channel}" if d.channel else ""), "start_s": d.start_s, "end_s": d.end_s,
            "heading_drift_rad": float(e_psi[i1] - e_psi[i0]),
            "heading_error_max_rad": float(np.max(np.abs(e_psi[w]))),
            "heading_error_rms_before": float(mx.rms(e_psi[before])) if before.any() else None,
            "heading_error_rms_after_10s": float(mx.rms(e_psi[after])) if after.any() else None,
            "depth_error_rms_during": float(mx.rms(err[w, 0])),
            "depth_error_rms_before": float(mx.rms(err[before, 0])) if before.any() else None,
            "heave_velocity_jump_on_return": float(np.max(np.abs(np.diff(c["est_w"][i1:i1 + 20])))) if i1 + 2 < len(t) else None,
        })
    out["dropouts"] = drops
    # consistency: NEES of the corrected estimate, NIS per used measurement
    out["nees"] = {"states": list(result.nees_states), **mx.consistency(result.nees, len(result.nees_states))}
    out["nis"] = mx.consistency(result.nis, 1)
    return out
