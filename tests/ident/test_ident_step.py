"""Step/relay response (Sandøy 2016, sec. 4.2.2): relay test -> output-error fit of k/(s + a) -> added mass, linear damping."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.ident import IdentificationError, lab, step
from rovlab.params.vehicle import DOF4


def _fit(table, mass, **kw):
    if table.has("heading_rad"):
        return step.fit_step_response(table["time_s"], table["moment_nm"], np.unwrap(table["heading_rad"]),
                                      mass=mass, **kw)
    return step.fit_step_response(table["time_s"], table["force_n"], table["position_m"], mass=mass, **kw)


@pytest.mark.parametrize("vehicle_name, dof, seed", [
    ("udrone_vehicle", "surge", 1), ("udrone_vehicle", "sway", 2), ("udrone_vehicle", "yaw", 3),
    ("modified_udrone", "surge", 4), ("modified_udrone", "heave", 5), ("heavy_vehicle", "surge", 6),
])
def test_linear_truth_within_5_percent(request, lab_table, vehicle_name, dof, seed):
    vehicle = request.getfixturevalue(vehicle_name)
    kw = dict(force=0.3, amplitude=1.0) if dof == "yaw" else {}
    data = lab.relay_test(vehicle, dof, seed=seed, linear=True, **kw)
    i = DOF4.index(dof)
    mass = vehicle.I_zz if dof == "yaw" else vehicle.mass
    fit = _fit(lab_table(data), mass, bias=(dof == "heave"))
    assert fit.added_mass == pytest.approx(vehicle.added_mass[i], rel=0.05)
    assert fit.linear_damping == pytest.approx(vehicle.damping_linear[i], rel=0.05)
    M = mass - vehicle.added_mass[i]
    assert fit.gain == pytest.approx(1 / M, rel=0.05)
    assert fit.pole == pytest.approx(-vehicle.damping_linear[i] / M, rel=0.05)
    assert fit.fit_percent > 99.0
    assert fit.added_mass < 0 and fit.linear_damping < 0  # SNAME signs


def test_heave_bias_is_the_unlogged_buoyancy(lab_table, udrone_vehicle):
    data = lab.relay_test(udrone_vehicle, "heave", seed=7, linear=True, force=3.0, buoyancy_error_n=1.5)
    fit = _fit(lab_table(data), udrone_vehicle.mass, bias=True)
    assert fit.bias == pytest.approx(data.truth["bias"], abs=0.05)
    assert fit.bias == pytest.approx(udrone_vehicle.weight - udrone_vehicle.buoyancy - 1.5, abs=0.05)
    assert fit.added_mass == pytest.approx(-14.57, rel=0.05)
    blind = _fit(lab_table(data), udrone_vehicle.mass, bias=False)
    assert blind.rms > 10 * fit.rms


def test_nonlinear_truth_biases_the_linear_model(lab_table, udrone_vehicle):
    # With uDrone's full surge damping (X_|u|u = -18.18, X_uuu = -24.24) the first-order model is an
    # equivalent linearisation: the identified "linear damping" is far above X_u = -4.03 and the
    # added mass is about 10 % low at 2 N (the thesis's own SI gave k = 0.07769, a = 1.197, i.e.
    # -a/k = -15.4: the same effect). Smaller forces (lower speeds) shrink the bias.
    low = _fit(lab_table(lab.relay_test(udrone_vehicle, "surge", seed=8, force=0.5)), 7.31)
    high = _fit(lab_table(lab.relay_test(udrone_vehicle, "surge", seed=8, force=2.0)), 7.31)
    for fit in (low, high):
        assert fit.added_mass == pytest.approx(-5.50, rel=0.15)
        assert fit.linear_damping < -4.03
    assert abs(low.added_mass + 5.5) < abs(high.added_mass + 5.5)
    assert abs(low.linear_damping + 4.03) < abs(high.linear_damping + 4.03)
    assert high.fit_percent < 99.5  # the model error is visible in the fit


def test_thesis_numbers_convert_with_the_errata_corrected():
    # Sandøy 2016, sec. 4.2.4: k = 0.07769 gives 1/k - m = 5.56 kg (the thesis printed 5.517 in eq. 4.14, an arithmetic slip)
    t = np.arange(0, 40, 0.1)
    k, a, m = 0.07769, 1.197, 7.31
    force = np.where((t // 5) % 2 == 0, 2.0, -2.0)
    _, xu, _, _ = step.responses(a, 0.1, force)
    fit = step.fit_step_response(t, force, k * xu, mass=m)
    assert fit.gain == pytest.approx(k, rel=1e-6)
    assert fit.pole == pytest.approx(a, rel=1e-6)
    assert -fit.added_mass == pytest.approx(5.56, abs=0.005)
    assert fit.linear_damping == pytest.approx(-a / k, rel=1e-6)


def test_standard_errors_are_consistent_with_the_scatter(udrone_vehicle):
    # 20 relay tests with 100x the Qualisys variance: the spread of the estimates matches the
    # reported standard errors within a factor of 2
    est, se = [], []
    for seed in range(20):
        d = lab.relay_test(udrone_vehicle, "surge", seed=100 + seed, linear=True, duration_s=30.0,
                           position_variance=1e-4)
        c = d.columns
        f = step.fit_step_response(c["time_s"], c["force_n"], c["position_m"], mass=7.31)
        est.append(f.added_mass)
        se.append(f.stderr["added_mass"])
    ratio = np.std(est, ddof=1) / np.mean(se)
    assert 0.5 < ratio < 2.0


def test_no_switch_is_refused():
    t = np.arange(0, 10, 0.1)
    with pytest.raises(IdentificationError, match="force never changes"):
        step.fit_step_response(t, np.ones_like(t), 0.1 * t, mass=7.31)


def test_wrong_sign_is_explained():
    t = np.arange(0, 40, 0.1)
    force = np.where((t // 5) % 2 == 0, 2.0, -2.0)
    _, xu, _, _ = step.responses(1.0, 0.1, force)
    with pytest.raises(IdentificationError, match="check the sign convention"):
        step.fit_step_response(t, force, -0.08 * xu, mass=7.31)


def test_irregular_sampling_is_refused():
    t = np.cumsum(np.r_[0.0, np.full(50, 0.1), [0.5], np.full(50, 0.1)])
    with pytest.raises(IdentificationError, match="uniform sampling"):
        step.fit_step_response(t, np.sign(np.sin(t)), np.sin(t), mass=7.31)


def test_vehicle_edits_name_the_dof():
    t = np.arange(0, 40, 0.1)
    force = np.where((t // 5) % 2 == 0, 2.0, -2.0)
    _, xu, _, _ = step.responses(0.5, 0.1, force)
    fit = step.fit_step_response(t, force, 0.05 * xu, mass=7.31)
    assert step.step_edits(fit, "sway") == {"added_mass.Y_vdot": pytest.approx(7.31 - 20.0, rel=1e-3),
                                            "damping.sway.linear": pytest.approx(-10.0, rel=1e-3)}


def test_undamped_dof_gives_zero_not_positive_damping(lab_table, heavy_vehicle):
    # bluerov2_heavy has N_r = 0 (linear truth: a = 0). Unconstrained, the fitted pole came out
    # about -1e-6, i.e. a positive ("energy-creating") linear damping that the vehicle file
    # refuses; a passive body has a >= 0.
    data = lab.relay_test(heavy_vehicle, "yaw", seed=1, linear=True, force=0.3, amplitude=1.0)
    fit = _fit(lab_table(data), heavy_vehicle.I_zz, bias=True)
    assert fit.pole >= 0.0 and fit.linear_damping <= 0.0
    assert fit.linear_damping == pytest.approx(0.0, abs=1e-4)
    assert fit.added_mass == pytest.approx(heavy_vehicle.added_mass[3], rel=0.01)
    assert np.all(np.isfinite(fit.velocity_fit))


@pytest.mark.parametrize("dof, seed", [("surge", 21), ("sway", 22), ("heave", 23), ("yaw", 24)])
def test_known_nonlinear_damping_held_fixed_removes_the_added_mass_bias(lab_table, udrone_vehicle, dof, seed):
    # Issue 10, item 5: on the virtual lab's default vehicle (uDrone with its full quadratic and
    # cubic damping, Sandøy 2016, table 4.6) and default relay, the linear first-order model biases the added mass
    # (8-17 %); with the vehicle's nonlinear damping held fixed it is recovered within 3 %.
    v = udrone_vehicle
    i = DOF4.index(dof)
    table = lab_table(lab.relay_test(v, dof, seed=seed))
    mass = v.I_zz if dof == "yaw" else v.mass
    fixed = (v.damping_quadratic[i], v.damping_cubic[i])
    fit = _fit(table, mass, bias=(dof == "heave"), damping=fixed)
    assert fit.added_mass == pytest.approx(v.added_mass[i], rel=0.03)
    assert fit.linear_damping == pytest.approx(v.damping_linear[i], rel=0.05)
    assert fit.fixed_damping == fixed
    assert fit.fit_percent > 99.0
    if dof != "heave":  # heave's relay stays slow enough for the linear model (< 3 % off)
        linear = _fit(table, mass, bias=False)
        assert abs(linear.added_mass / v.added_mass[i] - 1) > 0.05  # the bias this removes


def test_fixed_damping_of_zero_is_the_linear_fit(lab_table, udrone_vehicle):
    table = lab_table(lab.relay_test(udrone_vehicle, "surge", seed=25, linear=True))
    a = _fit(table, 7.31)
    b = _fit(table, 7.31, damping=(0.0, 0.0))
    assert a.added_mass == b.added_mass and b.fixed_damping == (0.0, 0.0)


def test_positive_fixed_damping_is_refused():
    t = np.arange(0, 40, 0.1)
    force = np.where((t // 5) % 2 == 0, 2.0, -2.0)
    _, xu, _, _ = step.responses(1.0, 0.1, force)
    with pytest.raises(IdentificationError, match="SNAME signs"):
        step.fit_step_response(t, force, 0.08 * xu, mass=7.31, damping=(18.0, 0.0))


def test_nonlinear_simulation_matches_the_linear_responses_without_nonlinear_terms():
    # with Q = C = 0 the RK4 integration reproduces the exact zero-order-hold responses
    t = np.arange(0, 20, 0.1)
    force = np.where((t // 4) % 2 == 0, 1.5, -1.5)
    k, a = 0.08, 0.6
    _, xu, _, vu = step.responses(a, 0.1, force)
    x, v = step.simulate_nonlinear(k, a, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1, force)
    np.testing.assert_allclose(x, k * xu, atol=1e-7)
