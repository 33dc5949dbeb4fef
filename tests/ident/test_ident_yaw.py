"""Yaw damping (Sandøy 2016, sec. 4.3.2): constant-moment runs -> steady yaw rate from a wrapped, noisy heading -> N_r, N_|r|r."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.ident import IdentificationError, lab, yaw
from rovlab.io.tables import DataTable


@pytest.mark.parametrize("vehicle_name, seed", [("udrone_vehicle", 1), ("udrone_vehicle", 2),
                                                ("modified_udrone", 3), ("heavy_vehicle", 4)])
def test_round_trip_within_5_percent(request, lab_table, vehicle_name, seed):
    vehicle = request.getfixturevalue(vehicle_name)
    data = lab.yaw_runs(vehicle, seed=seed, duration_s=20.0)
    table = lab_table(data)
    assert np.all(np.abs(table["heading_rad"]) <= np.pi)  # the log is wrapped ...
    assert np.any(np.abs(np.diff(table["heading_rad"])) > np.pi)  # ... and does wrap around
    fit = yaw.identify_yaw(table, terms=("linear", "quadratic", "cubic") if vehicle_name == "modified_udrone"
                           else ("linear", "quadratic"))
    N_r, N_rr, N_rrr = vehicle.damping_linear[3], vehicle.damping_quadratic[3], vehicle.damping_cubic[3]
    assert fit.quadratic == pytest.approx(N_rr, rel=0.05)
    # N_r is 0 for bluerov2_heavy (von Benzon 2022): compare on the scale of the damping moment
    assert fit.linear == pytest.approx(N_r, rel=0.05, abs=0.005)
    if vehicle_name == "modified_udrone":
        assert fit.cubic == pytest.approx(N_rrr, rel=0.05)
    assert len(fit.points) == 5
    # the moments of Sandøy 2016, sec. 4.3.2 (0.25 ... 2 N m) recovered per run
    np.testing.assert_allclose([p.force for p in fit.points], lab.DEFAULT_MOMENTS, rtol=1e-9)


def test_steady_rate_is_a_line_fit_not_a_derivative():
    # heading noise of 0.05 rad (30x Qualisys) at 10 Hz: differentiating would give ~0.7 rad/s
    # of noise per sample; the slope of a line over the steady window is still accurate
    rng = np.random.default_rng(5)
    t = np.arange(0, 30, 0.1)
    rate = 0.8
    psi = np.where(t < 2, 0.0, rate * (t - 2))
    heading = np.angle(np.exp(1j * (psi + 0.05 * rng.standard_normal(t.size))))
    moment = np.where(t < 2, 0.0, 1.0)
    win, r, se = yaw.steady_rate(t, heading, moment, what="run 1")
    assert r == pytest.approx(rate, abs=3 * se)
    assert se < 2e-3
    assert np.std(np.diff(yaw.unwrap_heading(heading)) / 0.1) > 0.5  # what a derivative would see


def test_allocation_error_shows_in_the_fit(lab_table, udrone_vehicle):
    # 5 % random error of the applied moment per run (thesis sec. 4.5: open-loop allocation):
    # the fit degrades and its standard errors say so
    clean = yaw.identify_yaw(lab_table(lab.yaw_runs(udrone_vehicle, seed=8, duration_s=15.0)))
    noisy = yaw.identify_yaw(lab_table(lab.yaw_runs(udrone_vehicle, seed=8, duration_s=15.0, moment_error=0.05)))
    assert noisy.stderr["quadratic"] > 100 * clean.stderr["quadratic"]
    assert noisy.rms > 100 * clean.rms


def _table(t, m, psi, run=1):
    data = {"run": np.full(t.size, float(run)), "time_s": t, "moment_nm": m, "heading_rad": psi}
    return DataTable("yaw.csv", tuple(data), data, np.arange(2, t.size + 2))


def test_zero_moment_run_is_refused():
    t = np.arange(0, 10, 0.1)
    with pytest.raises(IdentificationError, match="run 1: moment_nm is zero"):
        yaw.identify_yaw(_table(t, 0 * t, 0 * t))


def test_too_short_a_run_is_refused():
    t = np.arange(0, 3, 0.1)
    with pytest.raises(IdentificationError, match="the moment is applied for"):
        yaw.identify_yaw(_table(t, np.ones_like(t), 0.5 * t))


def test_two_runs_cannot_give_two_terms_and_a_check(lab_table, udrone_vehicle):
    data = lab.yaw_runs(udrone_vehicle, seed=2, moments=(0.5, 1.0), duration_s=10.0)
    with pytest.raises(IdentificationError, match="needs at least 3 runs"):
        yaw.identify_yaw(lab_table(data))
