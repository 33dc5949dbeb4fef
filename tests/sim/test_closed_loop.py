"""The closed-loop simulator and the thesis case studies (Sandøy 2016, sec. 5.3.1, figs. 5.2-5.4).

The case-study tests check numerically what the thesis observed: the references are reached, the
estimates stay within a few of the filter's own standard deviations, the bias absorbs what the
model leaves out, and a motion-capture drop-out raises the heading error until Qualisys returns.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rovlab.models import kinetics as kin
from rovlab.params.design import design_config_from_dict, packaged_config_path
from rovlab.params.validate import read_toml
from rovlab.sim.prepare import prepare
from rovlab.sim.reference import run_python
from rovlab.sim.results import summarise
from rovlab.sim.runner import run_prepared, simulate
from rovlab.sim.scenario import load_scenario, packaged_scenario_names


@pytest.fixture(scope="module")
def runs():
    return {name: simulate(name) for name in ("step-observer-model", "step-process-model", "dropout")}


def _err(c, s):
    e = c[f"est_{s}"] - c[f"true_{s}"]
    return np.pi - np.mod(np.pi - e, 2 * np.pi) if s == "psi" else e


def test_every_packaged_scenario_runs(runs):
    for name in packaged_scenario_names():
        res = runs.get(name) or simulate(name)
        assert np.all(np.isfinite(res.columns["est_z"])) and np.all(np.isfinite(res.columns["true_z"]))
        # 10 Hz, both ends (601 rows for the 60 s case studies)
        assert len(res.columns["time_s"]) == int(round(res.scenario.duration_s / 0.1)) + 1
        m = summarise(res)
        assert set(m) >= {"rms_error", "task", "nees", "nis"}
        # a step response where the set-points change; station keeping has none (issue 28)
        assert ({"settling_time_s", "overshoot"} <= set(m)) == (m["task"] != "station keeping"), name


def test_observer_model_plant_tracks_and_is_consistent(runs):
    """Case 1 (thesis fig. 5.2): perfect model -- the filter's assumptions hold exactly."""
    c = runs["step-observer-model"].columns
    t = c["time_s"]
    assert abs(c["true_z"][-1] - 0.70) < 0.01  # depth reference reached
    # first heading step (52 -> 30 deg) mostly done by 21 s: the thesis's LQR is slow (tau ~ 17 s)
    assert abs(math.degrees(c["true_psi"][t == 21.0][0]) - 30.0) < 0.4 * 22.0
    assert abs(math.degrees(c["true_psi"][-1])) < 5.0  # heading on its way to 0 deg (slow LQR, tau ~ 17 s)
    for s in ("z", "psi", "w", "r"):
        inside = np.abs(_err(c, s))[1:] <= 3 * np.sqrt(c[f"var_{s}"][1:])
        assert inside.mean() > 0.97, s
    m = summarise(runs["step-observer-model"])
    assert m["rms_error"]["z"] < 1e-3  # Qualisys depth noise is 4.5e-5 m
    lo, hi = m["nees"]["mean_bounds"]
    assert 0.5 * lo < m["nees"]["mean"] < 2 * hi


def test_process_model_bias_absorbs_what_the_model_leaves_out(runs):
    """Case 2 (thesis fig. 5.3): uDrone is 6.7 N buoyant and the damping is nonlinear; the bias
    estimate converges to that force and the heave velocity estimate overshoots meanwhile."""
    res = runs["step-process-model"]
    c = res.columns
    t = c["time_s"]
    assert abs(c["true_z"][-1] - 0.70) < 0.02
    late = t > 40
    # the heave bias settles on the net buoyancy plus the Gauss-Markov disturbance (Sandøy 2016, eq. 3.11 and 3.18)
    assert np.mean(np.abs(c["est_b_w"][late] - c["true_b_w"][late])) < 1.0
    assert c["est_b_w"][late].mean() < -5.0
    w_err = np.abs(_err(c, "w"))
    # (2x, not 3x: since issue 10 Qualisys z is no longer gated out during the start-up, which
    # made the overshoot larger than the bias convergence alone does)
    assert w_err[t < 8].max() > 2 * w_err[t > 30].max()


def test_dropout_heading_dead_reckons_and_recovers(runs):
    """Case 3 (thesis fig. 5.4): Qualisys lost 20-40 s; depth continues on the pressure sensor."""
    res = runs["dropout"]
    c = res.columns
    t = c["time_s"]
    before = (t >= 10) & (t < 20)
    during = (t >= 20) & (t < 40)
    after = (t >= 45) & (t < 60)
    psi_err = np.abs(_err(c, "psi"))
    assert psi_err[during].max() > 10 * psi_err[before].max()
    assert psi_err[after].max() < 5 * psi_err[before].max() + math.radians(0.2)
    z_err = np.abs(_err(c, "z"))
    assert np.sqrt(np.mean(z_err[during] ** 2)) > 3 * np.sqrt(np.mean(z_err[before] ** 2))
    assert np.all(np.isnan(c["meas_z_qualisys"][during])) and np.all(np.isfinite(c["meas_z_pressure"][during]))
    # the filter declared Qualisys lost during the window and brought it back afterwards
    assert np.all(c["status_z_qualisys"][(t > 21) & (t < 40)] == 2)  # STATUS_LOST
    assert c["status_z_qualisys"][-1] == 0  # ok again
    m = summarise(res)
    drop = m["dropouts"][0]
    assert drop["heading_error_max_rad"] > 10 * drop["heading_error_rms_before"]


def _gate_free_thesis_config():
    """The thesis design without rovlab's sensor management (the thesis had none): every sample
    is used, as in the plain-Python oracle."""
    data = read_toml(packaged_config_path("thesis"))
    data["fusion"].update(gate_probability=1.0, timeout_s=1e9, recovery_time_s=0.0)
    return design_config_from_dict(data, file="thesis (gate-free)")


def test_compiled_loop_equals_plain_python_loop_without_noise():
    prep = prepare(load_scenario("step-process-model"), config=_gate_free_thesis_config())
    for a in (prep.drive.plant_normals, prep.drive.bias_normals, prep.drive.sensor_normals, prep.plant.bias):
        a[...] = 0.0
    res = run_prepared(prep)
    ref = run_python(prep, noise=False, steps=200)
    c = res.columns
    for i, s in enumerate(("z", "psi", "w", "r")):
        np.testing.assert_allclose(c[f"true_{s}"][:200], ref["true"][:, i], atol=1e-9)
        np.testing.assert_allclose(c[f"est_{s}"][:200], ref["x"][:, i], atol=1e-9)
    np.testing.assert_allclose(c["tau_Z"][:200], ref["u"][:, 0], atol=1e-8)


def test_rk4_at_100_hz_matches_a_tight_reference_over_60_s():
    """Issue 4: RK4 at 100 Hz within 1e-6 m of a tight-tolerance solution over 60 s (same ZOH forces)."""
    prep = prepare(load_scenario("step-process-model"))
    for a in (prep.drive.plant_normals, prep.drive.bias_normals, prep.drive.sensor_normals, prep.plant.bias):
        a[...] = 0.0
    res = run_prepared(prep)
    c = res.columns
    p = prep.plant.p
    B = prep.allocator.B
    bank = prep.allocator.bank
    pwm = np.column_stack([c[f"pwm_{n}"] for n in prep.allocator.bank.names])
    x = prep.plant.x.copy()
    worst = 0.0
    for k in range(len(c["time_s"]) - 1):
        real = B @ bank.force(pwm[k])
        tau = np.array([real[0], real[1], real[2], real[5]])
        sol = solve_ivp(lambda _t, s: kin.plant_rhs(p, s, tau, np.zeros(4)), (0.0, prep.h), x,
                        method="DOP853", rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        worst = max(worst, abs(x[2] - c["true_z"][k + 1]))
    assert worst < 1e-6


def test_runs_are_reproducible_from_their_seed():
    a = simulate("dropout", seed=41)
    b = simulate("dropout", seed=41)
    c = simulate("dropout", seed=42)
    np.testing.assert_array_equal(a.columns["est_psi"], b.columns["est_psi"])
    assert not np.array_equal(a.columns["est_psi"], c.columns["est_psi"])


@pytest.mark.parametrize("name", ["step-observer-model", "dropout"])
def test_nees_of_the_compiled_loop_equals_the_metrics_module(runs, name):
    from rovlab.sim import metrics as mx

    res = runs[name]
    c = res.columns
    states = list(res.nees_states)
    truth = np.column_stack([c[f"true_{s}"] for s in states])
    est = np.column_stack([c[f"est_{s}"] for s in states])
    idx = [["z", "psi", "w", "r", "b_w", "b_r"].index(s) for s in states]
    from rovlab.estimation.consistency import nees

    P = res.P[:, idx][:, :, idx]
    pd = np.array([np.all(np.linalg.eigvalsh(Pk) > 0) for Pk in P])  # P0 = 0 at the start
    ref = np.full(len(P), np.nan)
    ref[pd] = nees(mx.estimation_error(est, truth)[pd], P[pd])
    ok = np.isfinite(ref)
    assert ok.sum() > 500
    np.testing.assert_allclose(res.nees[ok], ref[ok], rtol=1e-8)
    assert np.array_equal(np.isfinite(res.nees), ok)
