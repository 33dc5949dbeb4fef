"""The 4-DOF EKF (rovlab.estimation.ekf): equal to the linear Kalman filter on a linear model,
its compiled Van Loan against scipy, the ocean current's Jacobian, observability refusals."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm

from rovlab.estimation import ekf, kf
from rovlab.estimation.ekf import EKFConfig
from rovlab.estimation.fusion import N_REP
from rovlab.models import kinetics as kin
from rovlab.params.design import MeasurementConfig, load_design_config
from rovlab.params.validate import ConfigError
from rovlab.params.vehicle import load_vehicle

SEED = 20261123


def _linear_vehicle():
    """uDrone with only linear damping: with X = Y = 0 and u = v = 0 its heave and yaw are the
    linear depth-and-heading model of Sandøy 2016, sec. 5.1 (CG = VO, so no coupling)."""
    v = load_vehicle("udrone")
    return v.with_updates(damping_quadratic=np.zeros(4), damping_cubic=np.zeros(4))


def _pair():
    vehicle = _linear_vehicle()
    base = load_design_config("default")
    x0 = np.array(base.initial_state, dtype=float)
    x0[0] = 5.0  # 5 m deep: away from the free surface (the model is linear only fully submerged)
    x0[1] = 0.3
    cfg = replace(base, initial_state=x0)
    kspec = kf.build(vehicle, cfg)
    fm = kspec.model
    T_w, T_r = fm.T_w, fm.T_r
    std12 = np.zeros(12)
    std12[[2, 3, 6, 7, 10, 11]] = cfg.initial_std
    std12[[0, 1, 4, 5, 8, 9]] = [1.0, 1.0, 0.5, 0.5, 10.0, 10.0]
    x12 = np.zeros(12)
    x12[[2, 3, 6, 7, 10, 11]] = x0
    ec = EKFConfig(force_psd=np.array([1e-2, 1e-2, cfg.psd[2], cfg.psd[3]]),
                   bias_psd=np.array([1e-3, 1e-3, cfg.psd[4], cfg.psd[5]]),
                   bias_time_constant_s=np.array([60.0, 60.0, T_w, T_r]), substeps=10,
                   initial_state=x12, initial_std=std12, dead_reckoning=("x", "y", "u", "v", "b_X", "b_Y"))
    espec = ekf.build(vehicle, cfg.with_table("ekf", ec))
    return kspec, espec


def test_ekf_equals_linear_kf_on_the_linear_model():
    """Stone Soup's check (KF = EKF on a linear model): same data, same channels and sensor
    management, the estimates and covariances of the shared states agree to 1e-9."""
    kspec, espec = _pair()
    fm = kspec.model
    kest, eest = kspec.kernel, espec.kernel
    rng = np.random.default_rng(SEED)
    n = 600
    t = np.arange(n) * fm.h
    u = np.column_stack([5.0 * np.sin(2 * np.pi * t / 20.0), 0.02 * np.cos(2 * np.pi * t / 15.0)])
    L = np.linalg.cholesky(fm.Q + 1e-30 * np.eye(6))
    x = np.array([5.0, 0.5, 0.0, 0.0, 1.0, 0.01])
    m = len(fm.channels)
    offsets = np.array([c.offset for c in fm.channels])
    shared = [2, 3, 6, 7, 10, 11]
    rep_k, rep_e = np.empty((m, N_REP)), np.empty((m, N_REP))
    worst_x = worst_P = 0.0
    for k in range(n):
        y = fm.H @ x + offsets + rng.standard_normal(m) * np.sqrt(np.diag(fm.R))
        present = np.ones(m, dtype=np.bool_)
        if 200 <= k < 300:
            present[[0, 2]] = False  # motion capture lost: depth on pressure alone, heading dead-reckoned
            y[[0, 2]] = np.nan
        kf._correct(kest, t[k], y, present, rep_k)
        ekf._correct(eest, t[k], y, present, rep_e)
        dx = np.abs(eest.x[shared] - kest.x)
        dx[1] = abs(math.remainder(eest.x[3] - kest.x[1], 2 * math.pi))
        worst_x = max(worst_x, float(np.max(dx)))
        worst_P = max(worst_P, float(np.max(np.abs(eest.P[np.ix_(shared, shared)] - kest.P))))
        np.testing.assert_array_equal(rep_e[:, 0], rep_k[:, 0])  # the same channel events
        tau = np.array([0.0, 0.0, u[k, 0], u[k, 1]])
        kf._predict(kest, t[k], tau)
        ekf._predict(eest, t[k], tau)
        x = fm.Phi @ x + fm.Delta @ u[k] + L @ rng.standard_normal(6)
        assert x[0] > 0.5 and eest.x[2] > 0.5, "the test's truth must stay clear of the free surface"
    assert worst_x < 1e-9, worst_x
    assert worst_P < 1e-9, worst_P
    # u and v were never excited: the EKF's planar states stayed exactly at rest
    assert np.all(eest.x[[0, 1, 4, 5]] == 0.0)


def test_ekf_differs_from_kf_when_the_model_is_not_linear():
    """The equality above is not a tautology: with uDrone's quadratic damping (Sandøy 2016 table
    4.5) the EKF's heave prediction differs from the linear filter's."""
    vehicle = load_vehicle("udrone_dvl")
    _, espec = _pair()
    cfg = load_design_config("udrone_dp")
    est = ekf.build(vehicle, cfg).kernel
    lin = espec.kernel
    for e in (est, lin):
        e.x[:] = 0.0
        e.x[2] = 1.0
        e.x[6] = 0.4
    ekf._predict(est, 0.0, np.zeros(4))
    ekf._predict(lin, 0.0, np.zeros(4))
    assert abs(est.x[6] - lin.x[6]) > 1e-3


def test_compiled_van_loan_matches_scipy():
    vehicle = load_vehicle("udrone_dvl")
    cfg = load_design_config("udrone_dp")
    spec = ekf.build(vehicle, cfg)
    mdl = spec.model
    x = np.array([0.5, -0.3, 1.2, 0.7, 0.3, -0.1, 0.05, 0.2, 0.1, -0.2, -6.0, 0.01])
    A = ekf.continuous_model(mdl.p, mdl.inv_T, x)
    Phi, Q = ekf.van_loan(A, mdl.W, mdl.h, np.empty((24, 24)))
    Phi_s, Q_s = ekf.discrete_model(mdl.p, mdl.inv_T, mdl.W, x, mdl.h)
    np.testing.assert_allclose(Phi, Phi_s, rtol=0, atol=1e-13)
    np.testing.assert_allclose(Q, Q_s, rtol=1e-10, atol=1e-16)
    np.testing.assert_allclose(Phi, expm(A * mdl.h), rtol=0, atol=1e-13)


def test_expm_pade_on_a_large_norm_matrix():
    rng = np.random.default_rng(SEED)
    A = rng.standard_normal((12, 12)) * 3.0
    np.testing.assert_allclose(ekf.expm_pade(A), expm(A), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("current", [(0.0, 0.0, 0.0), (0.3, -0.2, 0.05)])
def test_jacobian_with_current_matches_finite_differences(current):
    """The analytic Jacobian of the model with an ocean current (Fossen 2011 sec. 8.3) against
    central differences of the one right-hand side."""
    p = kin.pack(load_vehicle("udrone"))
    p[kin.P_VC:kin.P_VC + 3] = current
    x = np.array([0.4, -0.7, 1.3, 2.1, 0.25, -0.15, 0.08, 0.3])
    f = np.array([3.0, -2.0, 1.0, 0.2])
    A = np.empty((8, 8))
    kin.jacobian_into(p, x, f, A)
    num = np.empty((8, 8))
    for j in range(8):
        d = np.zeros(8)
        d[j] = 1e-6
        num[:, j] = (kin.plant_rhs(p, x + d, f, np.zeros(4)) - kin.plant_rhs(p, x - d, f, np.zeros(4))) / 2e-6
    np.testing.assert_allclose(A, num, rtol=1e-6, atol=1e-7)


def test_current_pushes_a_resting_vehicle_downstream():
    """A vehicle at rest in a 0.2 m/s current heading north is pushed north (drag on the relative
    velocity), and a current of 0 leaves the right-hand side exactly as before."""
    p = kin.pack(load_vehicle("udrone"))
    x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    base = kin.plant_rhs(p, x, np.zeros(4), np.zeros(4))
    p2 = p.copy()
    p2[kin.P_VC] = 0.2
    pushed = kin.plant_rhs(p2, x, np.zeros(4), np.zeros(4))
    assert pushed[4] > 0.01
    p2[kin.P_VC] = 0.0
    np.testing.assert_array_equal(kin.plant_rhs(p2, x, np.zeros(4), np.zeros(4)), base)


def test_unobservable_sensor_set_is_refused_with_the_states_named():
    vehicle = load_vehicle("udrone_dvl")
    cfg = load_design_config("udrone_dp")
    keep = tuple(m for m in cfg.measurements if m.kind != "motion_capture")  # no position fix
    with pytest.raises(ConfigError) as err:
        ekf.build(vehicle, replace(cfg, measurements=keep))
    text = str(err.value)
    assert "measurements" in text and "x" in text and "dead_reckoning" in text


def test_dead_reckoning_accepts_what_the_user_names():
    vehicle = load_vehicle("udrone_dvl")
    cfg = load_design_config("udrone_dp")
    keep = tuple(m for m in cfg.measurements if m.kind != "motion_capture")
    # without motion capture neither the position nor the heading is seen (yaw rate only)
    dead = ("x", "y", "psi")
    spec = ekf.build(vehicle, replace(cfg, measurements=keep).with_table("ekf", replace(cfg.table("ekf"), dead_reckoning=dead)))
    assert set(spec.model.dead_reckoned) == set(dead)
    with pytest.raises(ConfigError, match="psi"):
        ekf.build(vehicle, replace(cfg, measurements=keep).with_table(
            "ekf", replace(cfg.table("ekf"), dead_reckoning=("x", "y"))))


def test_kf_refuses_a_planar_measurement_clearly():
    vehicle = load_vehicle("udrone")
    cfg = load_design_config("default")
    extra = MeasurementConfig(quantity="x", sensor=None, kind="motion_capture", variance=None,
                              fusion=cfg.measurements[0].fusion, key="measurements[9]")
    with pytest.raises(ConfigError) as err:
        kf.build(vehicle, replace(cfg, measurements=(*cfg.measurements, extra)))
    assert "measurements[9].quantity" in str(err.value) and "ekf" in str(err.value)


def test_nan_measurement_and_input_do_not_break_the_filter():
    vehicle = load_vehicle("udrone_dvl")
    est = ekf.build(vehicle, load_design_config("udrone_dp")).kernel
    m = est.H.shape[0]
    rep = np.empty((m, N_REP))
    y = np.full(m, np.nan)
    present = np.ones(m, dtype=np.bool_)
    ekf._correct(est, 0.0, y, present, rep)
    ekf._predict(est, 0.0, np.array([np.nan, 1.0, np.inf, 0.0]))
    assert np.all(np.isfinite(est.x)) and np.all(np.isfinite(est.P))


def test_udrone_dp_on_the_thesis_vehicle_is_refused_for_its_missing_dvl():
    """The thesis's uDrone had no DVL: udrone_dp names the vehicle, the key and what is there."""
    with pytest.raises(ConfigError) as err:
        ekf.build(load_vehicle("udrone"), load_design_config("udrone_dp"))
    text = str(err.value)
    assert "udrone_dp.toml" in text and ".kind" in text and "dvl" in text and "'udrone'" in text
