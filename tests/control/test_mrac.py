"""Model-reference adaptive heave control (rovlab.control.mrac; the tentative task 7 of Sandøy 2016's thesis
description, not done there; issue 12).

The kernels are plain compiled functions, so most checks drive them directly: the reference model
against its transfer function, the Lyapunov derivative of the continuous law (Slotine & Li 1991,
sec. 8.5), exact tracking with the true parameters on the continuous model, the projection under
a persistent disturbance, and the configuration's errors.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rovlab.control import mrac
from rovlab.core.components import fresh
from rovlab.models.discretise import zoh
from rovlab.params.design import design_config_from_dict, load_design_config, packaged_config_path
from rovlab.params.validate import ConfigError, read_toml

# the continuous heave plant used below: M w_dot = Z - D_l w - D_q |w| w + F (uDrone, Sandøy 2016, table 4.6,
# with the thesis's design mass M = m - Z_wdot = 7.31 + 11.13 of appendix A.3 and uDrone's ~6.7 N of buoyancy,
# B - W from table 4.1)
THETA = np.array([18.44, 5.18, 36.99, -6.67])


@pytest.fixture(scope="module")
def thesis():
    return load_design_config("thesis")


@pytest.fixture(scope="module")
def spec(udrone, thesis):
    return mrac.build(udrone, thesis)


def _config(changes: dict) -> object:
    data = read_toml(packaged_config_path("thesis"))
    data["mrac"] = {**data["mrac"], **changes}
    return design_config_from_dict(data, file="cfg.toml")


# --------------------------------------------------------------------------------------------
# Reference model
# --------------------------------------------------------------------------------------------

def _tf_step(t, omega, zeta):
    """Unit step response of omega^2 / (s^2 + 2 zeta omega s + omega^2) (textbook closed forms)."""
    if zeta == 1.0:
        return 1.0 - (1.0 + omega * t) * np.exp(-omega * t)
    wd = omega * math.sqrt(1.0 - zeta**2)
    return 1.0 - np.exp(-zeta * omega * t) * (np.cos(wd * t) + zeta / math.sqrt(1.0 - zeta**2) * np.sin(wd * t))


@pytest.mark.parametrize(("omega", "zeta"), [(0.6, 1.0), (1.2, 0.5), (0.3, 0.8)])
def test_reference_model_matches_its_transfer_function(udrone, omega, zeta):
    """The component's reference model, stepped through its own kernels with hedging off, gives
    the sampled step response of omega^2 / (s^2 + 2 zeta omega s + omega^2) (ZOH is exact for a
    step)."""
    cfg = _config({"bandwidth": omega, "damping": zeta, "hedge": False, "max_step": 0.1})
    ctrl = fresh(mrac.build(udrone, cfg).kernel)
    nav = np.zeros(12)
    tau = np.zeros(4)
    ref = np.array([0.0, 0.0, 0.3, 0.0])  # a 0.3 m step from z = 0
    zm = []
    for k in range(400):
        mrac._mrac_step(ctrl, k * 0.1, nav, ref, tau)
        zm.append(ctrl.state[4])
        mrac._mrac_actuated(ctrl, k * 0.1, tau, tau)
    t = 0.1 * np.arange(400)
    np.testing.assert_allclose(np.array(zm), 0.3 * _tf_step(t, omega, zeta), atol=1e-12)


def test_hedging_slows_the_reference_model(udrone, thesis):
    """With a heave force shortfall the reference model accelerates less (pseudo-control hedging)."""
    base = fresh(mrac.build(udrone, thesis).kernel)
    hedged = fresh(base)
    nav = np.zeros(12)
    ref = np.array([0.0, 0.0, 0.5, 0.0])
    tau = np.zeros(4)
    for _ in range(20):
        mrac._mrac_step(base, 0.0, nav, ref, tau)
        mrac._mrac_actuated(base, 0.0, tau, tau)
        mrac._mrac_step(hedged, 0.0, nav, ref, tau)
        achieved = tau.copy()
        achieved[2] = 0.5 * tau[2]  # the thrusters gave half the demanded heave force
        mrac._mrac_actuated(hedged, 0.0, tau, achieved)
    assert 0.0 < hedged.state[4] < base.state[4]


# --------------------------------------------------------------------------------------------
# The law: Lyapunov derivative and exact tracking on the continuous model
# --------------------------------------------------------------------------------------------

def _closed_loop(theta_true, gamma, lam, k_s, omega, zeta, r):
    """Vector field of [z, w, z_m, w_m, theta_hat (4)] under the continuous law (sigma = 0)."""
    Y = np.zeros(4)

    def f(t, x):
        z, w, zm, wm = x[:4]
        th = x[4:]
        am = mrac.reference_accel(zm, wm, r, omega**2, 2 * zeta * omega)
        tau, s = mrac.heave_law(th, z, w, zm, wm, am, lam, k_s, Y)
        M, Dl, Dq, F = theta_true
        wdot = (tau - Dl * w - Dq * abs(w) * w + F) / M
        return np.concatenate([[w, wdot, wm, am], -gamma * Y * s])
    return f


def test_lyapunov_derivative_is_minus_k_s_s_squared(rng):
    """V = M s^2 / 2 + theta_tilde^T Gamma^-1 theta_tilde / 2 decreases at exactly -k_s s^2 along the
    closed loop (checked by central differences of V along the vector field at random states)."""
    gamma = np.array([50.0, 50.0, 50.0, 300.0])
    lam, k_s, omega, zeta, r = 2.0, 80.0, 0.6, 1.0, 0.7
    f = _closed_loop(THETA, gamma, lam, k_s, omega, zeta, r)

    def V(x):
        s = (x[1] - x[3]) + lam * (x[0] - x[2])
        tt = x[4:] - THETA
        return 0.5 * THETA[0] * s**2 + 0.5 * np.sum(tt**2 / gamma)

    for _ in range(50):
        x = np.concatenate([rng.normal(0.7, 0.3, 4) * [1, 0.3, 1, 0.3],
                            THETA * rng.uniform(0.5, 1.5, 4)])
        x[[1, 3]] = rng.normal(0.0, 0.2, 2)
        dx = f(0.0, x)
        eps = 1e-6
        vdot = (V(x + eps * dx) - V(x - eps * dx)) / (2 * eps)
        s = (x[1] - x[3]) + lam * (x[0] - x[2])
        assert vdot == pytest.approx(-k_s * s**2, rel=1e-5, abs=1e-8)
        assert vdot <= 1e-8


def test_true_parameters_track_the_reference_model_exactly():
    """With theta_hat = theta and no disturbance the continuous closed loop follows the reference
    model exactly (M s_dot = -k_s s with s(0) = 0): |z - z_m| stays at integrator precision, and
    the estimates do not move."""
    gamma = np.array([50.0, 50.0, 50.0, 300.0])
    x = np.concatenate([[1.05, 0.0, 1.05, 0.0], THETA])
    worst = 0.0
    for r, t0, t1 in ((0.70, 0.0, 20.0), (1.20, 20.0, 40.0)):  # the set-point steps at 20 s
        sol = solve_ivp(_closed_loop(THETA, gamma, 2.0, 80.0, 0.6, 1.0, r), (t0, t1), x, method="DOP853",
                        rtol=1e-12, atol=1e-13, dense_output=False, max_step=0.05)
        worst = max(worst, float(np.max(np.abs(sol.y[0] - sol.y[2]))))
        x = sol.y[:, -1]
        np.testing.assert_allclose(sol.y[4:, -1], THETA, rtol=1e-10)
    assert abs(x[0] - 1.20) < 1e-4  # it did move: the reference model reached 1.2 m
    assert worst < 1e-9


def test_sampled_law_error_is_a_sampling_error(udrone, thesis):
    """The component at h samples the continuous law and holds it: with the true parameters its
    tracking error against the reference model on the exactly discretised linear heave model is
    small and shrinks with h (first order): it is a sampling error, not a modelling one."""
    theta = np.array([18.44, 5.18, 0.0, 0.0])  # the linear design model: no quadratic damping, no buoyancy
    errors = []
    for h in (0.1, 0.01):
        cfg = dataclasses.replace(_config({"initial": {"M": 18.44, "D_l": 5.18, "D_q": 0.0, "F": 0.0},
                                           "hedge": False}), sample_time=h)
        ctrl = fresh(mrac.build(udrone, cfg).kernel)
        A = np.array([[0.0, 1.0], [0.0, -theta[1] / theta[0]]])
        Phi, Delta = zoh(A, np.array([[0.0], [1.0 / theta[0]]]), h)
        x = np.array([1.05, 0.0])
        nav = np.zeros(12)
        tau = np.zeros(4)
        ref = np.array([0.0, 0.0, 0.70, 0.0])
        worst = 0.0
        for k in range(int(round(20.0 / h))):
            nav[2], nav[6] = x
            mrac._mrac_step(ctrl, k * h, nav, ref, tau)
            worst = max(worst, abs(x[0] - ctrl.state[4]))
            mrac._mrac_actuated(ctrl, k * h, tau, tau)
            x = Phi @ x + Delta[:, 0] * tau[2]
        errors.append(worst)
        np.testing.assert_allclose(ctrl.state[:2], theta[:2], rtol=0.05)
    assert errors[0] < 0.01  # 1 cm on a 0.35 m step at 10 Hz
    assert errors[1] < errors[0] / 5.0


# --------------------------------------------------------------------------------------------
# Projection
# --------------------------------------------------------------------------------------------

def test_projection_keeps_the_estimates_in_their_set_under_persistent_disturbance(udrone, thesis):
    """A heave plant pulled down by 100 N (far beyond what the box allows F to be) driven through
    the component's own kernels for 10 min: every estimate stays in [lo, hi] at every step, and F
    sits on its bound."""
    ctrl = fresh(mrac.build(udrone, thesis).kernel)
    lo, hi = ctrl.lo.copy(), ctrl.hi.copy()
    theta = np.array([21.88, 5.18, 36.99, 100.0])
    h = 0.1
    nav = np.zeros(12)
    tau = np.zeros(4)
    ref = np.array([0.0, 0.0, 0.7, 0.0])
    x = np.array([0.7, 0.0])
    rng = np.random.default_rng(12)
    for k in range(6000):
        nav[2], nav[6] = x[0] + 1e-3 * rng.standard_normal(), x[1] + 1e-2 * rng.standard_normal()
        ref[2] = 0.7 + 0.3 * math.sin(0.05 * k)  # persistent excitation as well
        mrac._mrac_step(ctrl, k * h, nav, ref, tau)
        achieved = tau.copy()
        achieved[2] = min(max(tau[2], -49.0), 29.9)  # uDrone's heave thrust (allocation with K = M = 0)
        mrac._mrac_actuated(ctrl, k * h, tau, achieved)
        assert np.all(ctrl.state[:4] >= lo) and np.all(ctrl.state[:4] <= hi)
        for _ in range(10):  # Euler at h/10
            M, Dl, Dq, F = theta
            wdot = (achieved[2] - Dl * x[1] - Dq * abs(x[1]) * x[1] + F) / M
            x = x + 0.01 * np.array([x[1], wdot])
    assert ctrl.state[3] == pytest.approx(hi[3])


def test_projection_never_moves_away_from_a_point_of_the_set(rng):
    """Clipping to the box is the Gamma^-1-weighted projection (Gamma diagonal): the distance to any
    theta inside the box never grows (Ioannou & Sun 1996, ch. 4 and 8, the projection property)."""
    lo = np.array([5.0, 0.0, 0.0, -30.0])
    hi = np.array([60.0, 30.0, 200.0, 30.0])
    gamma = np.array([50.0, 50.0, 50.0, 300.0])
    for _ in range(2000):
        inside = rng.uniform(lo, hi)
        th = rng.uniform(lo, hi)
        Y = rng.normal(0.0, 5.0, 4)
        s = rng.normal(0.0, 1.0)
        raw = th - 0.1 * gamma * Y * s
        mrac.adapt(th, Y, s, gamma, 0.0, th.copy(), lo, hi, 0.1)
        assert np.all(th >= lo) and np.all(th <= hi)
        assert np.sum((th - inside) ** 2 / gamma) <= np.sum((raw - inside) ** 2 / gamma) + 1e-12


def test_sigma_modification_leaks_towards_the_initial_estimate():
    th = np.array([30.0, 10.0, 50.0, 5.0])
    th0 = np.array([20.0, 5.0, 37.0, -6.7])
    for _ in range(500):
        mrac.adapt(th, np.zeros(4), 0.0, np.ones(4), 0.5, th0, np.full(4, -1e3), np.full(4, 1e3), 0.1)
    np.testing.assert_allclose(th, th0, atol=1e-9 + 1e-9 * 100)


# --------------------------------------------------------------------------------------------
# Design and configuration
# --------------------------------------------------------------------------------------------

def test_build_declares_its_needs_and_logged_state(spec, udrone, thesis):
    assert spec.needs == ("z", "psi", "w", "r", "b_N")  # no b_Z: MRAC adapts its own net force
    assert spec.state_names == mrac.STATE_NAMES
    d = spec.model
    np.testing.assert_allclose(d.theta0, [7.31 + 11.13, 5.18, 36.99, udrone.weight - udrone.buoyancy])
    assert np.all(d.lo < d.theta0) and np.all(d.theta0 < d.hi)
    assert d.sampled_radius < 1.0
    np.testing.assert_allclose(d.K, spec.kernel.K)  # the heading LQR is the thesis's
    assert d.K[1, 1] == pytest.approx(0.148116, rel=1e-5)


def test_heading_row_is_the_lqg_law(spec):
    from rovlab.control.lqg import LQGController

    ctrl = fresh(spec.kernel)
    nav = np.zeros(12)
    nav[[2, 3, 6, 7, 10, 11]] = [0.8, 0.9, 0.05, 0.01, 1.0, 0.02]
    tau = np.zeros(4)
    mrac._mrac_step(ctrl, 0.0, nav, np.array([0.0, 0.0, 0.7, 0.5]), tau)
    lqg = LQGController(K=spec.model.K, P=spec.model.P)
    assert tau[3] == pytest.approx(lqg.tau(nav[[2, 3, 6, 7, 10, 11]], np.array([0.7, 0.5]))[1], rel=1e-12)
    assert tau[0] == tau[1] == 0.0


@pytest.mark.parametrize(("changes", "key", "expected"), [
    ({"bandwith": 0.5}, "mrac.bandwith", "unknown keys are errors"),
    ({"bandwidth": -1.0}, "mrac.bandwidth", "a positive number"),
    ({"gain": {"M": -1.0}}, "mrac.gain.M", "a number >= 0"),
    ({"gain": {"mass": 1.0}}, "mrac.gain.mass", "unknown keys are errors"),
    ({"bounds": {"F": [5.0, -5.0]}}, "mrac.bounds.F", "lowest < highest"),
    ({"bounds": {"M": [0.0, 30.0]}}, "mrac.bounds.M", "positive lower bound"),
    ({"bounds": {"D_l": [1.0]}}, "mrac.bounds.D_l", "a list of 2 finite numbers"),
    ({"hedge": "yes"}, "mrac.hedge", "true or false"),
])
def test_bad_mrac_tables_are_refused_with_the_key(changes, key, expected):
    data = read_toml(packaged_config_path("thesis"))
    data["mrac"] = {**data["mrac"], **changes}
    with pytest.raises(ConfigError) as info:
        design_config_from_dict(data, file="cfg.toml")
    hits = [p for p in info.value.problems if p.key == key]
    assert hits and expected in hits[0].expected and hits[0].file == "cfg.toml"


def test_mrac_table_needs_its_source():
    data = read_toml(packaged_config_path("thesis"))
    del data["mrac"]["source"]
    with pytest.raises(ConfigError) as info:
        design_config_from_dict(data, file="cfg.toml")
    assert [p.key for p in info.value.problems] == ["mrac.source"]


def test_a_configuration_without_mrac_table_gets_the_defaults(udrone):
    data = read_toml(packaged_config_path("thesis"))
    del data["mrac"]
    cfg = design_config_from_dict(data, file="cfg.toml")
    assert not cfg.table("mrac").given and cfg.table("mrac").k_s == 80.0
    assert mrac.build(udrone, cfg).model.sampled_radius < 1.0


@pytest.mark.parametrize(("changes", "key", "expected"), [
    ({"initial": {"F": 50.0}}, "mrac.initial.F", "inside the projection bounds"),
    ({"bounds": {"M": [30.0, 60.0]}}, "mrac.bounds.M", "inside the projection bounds"),
    ({"k_s": 400.0}, "mrac.k_s", "stable"),
    ({"sigma": 20.0}, "mrac.sigma", "sigma * sample_time < 1"),
])
def test_designs_that_cannot_work_are_refused(udrone, changes, key, expected):
    with pytest.raises(ConfigError) as info:
        mrac.build(udrone, _config(changes))
    hits = [p for p in info.value.problems if p.key == key]
    assert hits and expected in hits[0].expected


def test_reference_model_is_checked_against_the_thrusters(udrone):
    """A 2 rad/s reference model for a 1 m step would need far more than uDrone's ~30 N down. The
    check is MRAC's own declaration (ComponentInfo.check), and making a design runs it."""
    from rovlab.allocation.solvers import Allocator
    from rovlab.core.components import component
    from rovlab.sim.designs import make_design

    check_heave_capacity = component("controller", "mrac").check
    assert check_heave_capacity is mrac.check_heave_capacity
    ok = mrac.build(udrone, _config({}))
    check_heave_capacity(ok, Allocator(udrone), "cfg.toml")  # the packaged design fits
    fast = mrac.build(udrone, _config({"bandwidth": 2.0, "max_step": 1.0}))
    down, up = fast.model.heave_force_needed
    assert down > 60.0 and up < -50.0
    with pytest.raises(ConfigError) as info:
        check_heave_capacity(fast, Allocator(udrone), "cfg.toml")
    p = info.value.problems[0]
    assert p.key == "mrac.bandwidth" and "the thrusters give" in p.expected and p.file == "cfg.toml"
    with pytest.raises(ConfigError, match="mrac.bandwidth"):
        make_design(udrone, _config({"bandwidth": 2.0, "max_step": 1.0}), plant="process", plant_step=0.01,
                    controller="mrac")


def test_heave_force_needed_for_a_slow_step_is_the_buoyancy():
    down, up = mrac.heave_force_needed(THETA, 0.01, 1.0, 0.1)
    assert down == pytest.approx(6.67, abs=0.01) and up == pytest.approx(6.67, abs=0.01)
