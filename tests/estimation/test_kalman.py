"""The depth-and-heading Kalman filter: equivalence with filterpy, fusion, dead reckoning, robustness."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from rovlab.estimation.filtering import Belief, DepthHeadingFilter
from rovlab.estimation.fusion import CFG_R, N_CH, REP_R
from rovlab.estimation.kalman import FLAG_INPUT, FLAG_TIME, kf_step, kf_workspace
from rovlab.estimation.model import build_filter_model
from rovlab.estimation.streaming import steps_between
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


@pytest.fixture(scope="module")
def thesis_model():
    return build_filter_model(load_vehicle("udrone"), load_design_config("thesis"))


@pytest.fixture(scope="module")
def filt(thesis_model):
    return DepthHeadingFilter(thesis_model)


def plain(model, **changes):
    """The same model with every channel's sensor management changed (default: no gate, no ramp,
    no stuck check)."""
    changes = changes or {"gate_threshold": np.inf, "recovery_samples": 0, "stuck_samples": 0}
    return DepthHeadingFilter(replace(model, channels=tuple(replace(c, **changes) for c in model.channels)))


def simulate(model, n, seed, *, u_amp=(5.0, 0.002)):
    """Truth and raw sensor samples from the observer model itself (the plant of Sandøy 2016, fig. 5.2)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * model.h
    u = np.column_stack([u_amp[0] * np.sin(2 * np.pi * t / 20.0), u_amp[1] * np.cos(2 * np.pi * t / 15.0)])
    L = np.linalg.cholesky(model.Q)
    x = model.x0.copy()
    X = np.empty((n, 6))
    for k in range(n):
        X[k] = x
        x = model.Phi @ x + model.Delta @ u[k] + L @ rng.standard_normal(6)
    y = X @ model.H.T + rng.standard_normal((n, len(model.channels))) * np.sqrt(np.diag(model.R))
    y += np.array([c.offset for c in model.channels])  # raw readings: the lever arm is undone by the filter
    return t, u, y, X


def filterpy_reference(model, t, u, y, P0):
    """An independent implementation: filterpy's KalmanFilter, stacked update over the samples present."""
    from filterpy.kalman import KalmanFilter

    m = len(model.channels)
    kf = KalmanFilter(dim_x=6, dim_z=m, dim_u=2)
    kf.F, kf.B, kf.Q = model.Phi.copy(), model.Delta.copy(), model.Q.copy()
    kf.x = model.x0.reshape(6, 1).copy()
    kf.P = P0.copy()
    offsets = np.array([c.offset for c in model.channels])
    X, P = [], []
    for k in range(len(t)):
        present = ~np.isnan(y[k])
        if present.any():
            kf.update((y[k] - offsets)[present].reshape(-1, 1), R=model.R[np.ix_(present, present)],
                      H=model.H[present])
        X.append(kf.x[:, 0].copy())
        P.append(kf.P.copy())
        kf.predict(u=u[k].reshape(2, 1))
    return np.array(X), np.array(P)


# --------------------------------------------------------------------------------------------
# equivalence
# --------------------------------------------------------------------------------------------

def test_equals_filterpy_stacked_update_to_1e9(thesis_model):
    # Sequential scalar Joseph updates (rovlab) against filterpy's stacked update and Joseph form:
    # mathematically identical for diagonal R (Bierman 1977). Random drop-outs of every channel,
    # gate and ramp off so both use exactly the same samples with the same R.
    t, u, y, _ = simulate(thesis_model, 400, seed=3)
    rng = np.random.default_rng(4)
    y[rng.random(y.shape) < 0.15] = np.nan
    y[100:130, :] = np.nan  # a stretch of pure dead reckoning
    P0 = np.diag([1e-2, (5 * np.pi / 180) ** 2, 1e-2, 1e-3, 1.0, 1e-2])
    f = plain(thesis_model)
    b = f.initial_belief(P0=P0)
    X_ref, P_ref = filterpy_reference(thesis_model, t, u, y, P0)
    X, P = [], []
    for k in range(len(t)):
        b, rep = f.step(b, t[k], u[k], y[k])
        X.append(rep.x.copy())
        P.append(rep.P.copy())
    X, P = np.array(X), np.array(P)
    # rovlab keeps psi in (-pi, pi] and wraps innovations; filterpy's psi runs on continuously
    # (the simulated measurement is not wrapped): the two agree modulo 2 pi.
    X_ref[:, 1] = X[:, 1] + np.remainder(X_ref[:, 1] - X[:, 1] + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(X, X_ref, rtol=1e-9, atol=1e-9)
    for k in range(len(t)):
        np.testing.assert_allclose(P[k], P_ref[k], rtol=1e-9, atol=1e-9 * np.max(np.abs(P_ref[k])))


def test_offline_run_equals_online_steps(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 300, seed=5)
    y[50:80, 0] = np.nan
    run = filt.run(t, u, y)
    b = filt.initial_belief()
    for k in range(len(t)):
        b, rep = filt.step(b, t[k], u[k], y[k])
        np.testing.assert_array_equal(rep.x, run.x[k])
        np.testing.assert_array_equal(np.diag(rep.P), run.variance[k])
    np.testing.assert_array_equal(b.x, run.belief.x)
    np.testing.assert_array_equal(b.channels, run.belief.channels)


def test_timing_correct_then_report_then_project(filt, thesis_model):
    # correct, then project (Sandøy 2016, table 5.1); decided here: row k is corrected with y_k, reported,
    # then projected with u_k.
    b0 = filt.initial_belief()
    u = np.array([3.0, 0.01])
    b1, rep = filt.step(b0, 0.0, u, [np.nan, np.nan, np.nan])  # no sample: x_0 reported unchanged
    np.testing.assert_array_equal(rep.x, thesis_model.x0)
    expected = thesis_model.Phi @ thesis_model.x0 + thesis_model.Delta @ u
    expected[1] = math.remainder(expected[1], 2 * math.pi)
    np.testing.assert_allclose(b1.x, expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(b1.P, thesis_model.Q, rtol=1e-14, atol=0)  # P0 = 0 in the thesis


# --------------------------------------------------------------------------------------------
# beliefs are values
# --------------------------------------------------------------------------------------------

def test_belief_is_an_immutable_value_and_round_trips(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 60, seed=6)
    b = filt.initial_belief()
    for k in range(30):
        b, _ = filt.step(b, t[k], u[k], y[k])
    before = b.data.copy()
    b_next, _ = filt.step(b, t[30], u[30], y[30])
    np.testing.assert_array_equal(b.data, before)  # the input belief is untouched
    with pytest.raises(ValueError):
        b.x[0] = 1.0  # views are read-only
    with pytest.raises(AttributeError):
        b.data = before  # frozen
    saved = json.loads(json.dumps(b.to_dict()))
    restored = Belief.from_dict(saved)
    again, _ = filt.step(restored, t[30], u[30], y[30])
    np.testing.assert_array_equal(again.x, b_next.x)
    np.testing.assert_array_equal(again.P, b_next.P)
    assert restored.t == b.t == t[29]


def test_step_rejects_mismatched_input(filt):
    b = filt.initial_belief()
    with pytest.raises(ValueError):
        filt.step(b, 0.0, [1.0, 2.0], [1.0, 2.0])  # 2 samples for 3 channels
    with pytest.raises(ValueError):
        filt.step(b, 0.0, [1.0], [1.0, 2.0, 3.0])
    other = Belief.make(np.zeros(6), np.eye(6), np.zeros((2, N_CH)))
    with pytest.raises(ValueError):
        filt.step(other, 0.0, [0.0, 0.0], [1.0, 1.0, 1.0])
    with pytest.raises(KeyError, match="no channel"):
        filt.step(b, 0.0, [0.0, 0.0], {"dvl.w": 0.1})


def test_mapping_input_and_lever_arm(filt, thesis_model):
    # pressure sensor at l_z = -0.0465 m (above VO): it reads 0.0465 m less depth than VO
    b = filt.initial_belief(P0=np.eye(6))
    depth = 1.2
    _, rep = filt.step(b, 0.0, [0.0, 0.0], {"pressure.z": depth - 0.0465})
    # one precise-ish measurement with a huge prior variance: the estimate lands near the VO depth
    assert rep.x[0] == pytest.approx(depth, abs=1e-3)
    assert rep.events == ("none", "used", "none")


# --------------------------------------------------------------------------------------------
# dead reckoning
# --------------------------------------------------------------------------------------------

def test_dropout_detected_by_timeout_and_recovered_with_transitional_variance(filt, thesis_model):
    t, u, y, X = simulate(thesis_model, 700, seed=7)
    y[200:400, [0, 2]] = np.nan  # Qualisys z and psi lost from t = 20 s to 40 s (Sandøy 2016, fig. 5.4)
    run = filt.run(t, u, y)
    timeout = thesis_model.channels[0].timeout_s  # 0.5 s
    first_lost = 200 + int(round(timeout / thesis_model.h))  # strictly later than the timeout
    labels = run.status_labels(0)
    assert labels[first_lost - 1] == "ok" and labels[first_lost + 1] == "lost-timeout"
    assert all(s == "lost-timeout" for s in labels[first_lost + 1:400])
    assert set(run.status_labels(1)) == {"ok"}  # pressure carries on
    # return at sample 400: recovering for recovery_time_s (5 s = 50 samples), then ok
    assert labels[400] == "recovering" and labels[449] == "recovering" and labels[451] == "ok"
    # heading dead-reckons: its variance grows during the drop-out, the depth's stays bounded
    assert run.variance[399, 1] > 100 * run.variance[199, 1]
    assert run.variance[399, 0] < 2 * thesis_model.channels[1].variance
    # the estimate stays close to the truth throughout
    assert np.max(np.abs(run.x[:, 0] - X[:, 0])) < 0.05


def test_recovery_spreads_the_correction_evenly_over_the_recovery_samples(thesis_model):
    # After 20 s without Qualisys, sample k = 1..N after its return is used with
    # R_eff = R + (N - k) h P^- h^T (under-weighting, rovlab.estimation.fusion), so each applies
    # about 1/N of the heading correction instead of all of it at once.
    t, u, y, X = simulate(thesis_model, 520, seed=8)
    y[200:400, [0, 2]] = np.nan
    ramp = plain(thesis_model, gate_threshold=np.inf, stuck_samples=0)  # recovery on, gate off
    hard = plain(thesis_model, gate_threshold=np.inf, stuck_samples=0, recovery_samples=0)
    c = thesis_model.channels[2]  # qualisys.psi
    N = c.recovery_samples
    assert N == round(c.recovery_time_s / thesis_model.h) == 50
    b_r = b_h = ramp.initial_belief()
    for k in range(400):
        b_r, _ = ramp.step(b_r, t[k], u[k], y[k])
        b_h, _ = hard.step(b_h, t[k], u[k], y[k])
    np.testing.assert_array_equal(b_r.x, b_h.x)  # identical until the sensor returns
    assert b_r.P[1, 1] > 1e3 * c.variance  # dead reckoning: the prior dwarfs R
    steps_r, steps_h, status = [], [], []
    for k in range(400, 460):
        prior_r, prior_h = b_r, b_h
        b_r, rep_r = ramp.step(b_r, t[k], u[k], y[k])
        b_h, rep_h = hard.step(b_h, t[k], u[k], y[k])
        n_used = k - 400 + 1
        expected = c.variance + max(N - n_used, 0) * prior_r.P[1, 1]
        assert rep_r.variance_used[2] == pytest.approx(expected, rel=1e-9)
        assert rep_h.variance_used[2] == c.variance
        steps_r.append(abs(math.remainder(rep_r.x[1] - prior_r.x[1], 2 * math.pi)))
        steps_h.append(abs(math.remainder(rep_h.x[1] - prior_h.x[1], 2 * math.pi)))
        status.append(rep_r.status[2])
        # P stays the honest covariance of the under-weighted estimate: never below the optimal one
        assert rep_r.P[1, 1] >= rep_h.P[1, 1] * (1 - 1e-9) or k > 450
    assert max(steps_r) < 0.1 * max(steps_h)  # the heading estimate does not jump
    assert status[0] == "recovering" and status[N - 1] == "recovering" and status[N] == "ok"
    # by the end of the recovery the two estimates agree
    assert abs(math.remainder(b_r.x[1] - b_h.x[1], 2 * math.pi)) < 3 * math.sqrt(b_h.P[1, 1])


def test_chi2_gate_rejects_an_outlier_like_a_missing_sample(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 200, seed=9)
    spiked = y.copy()
    spiked[100, 0] += 0.05  # 5 cm on a 45 um sensor
    missing = y.copy()
    missing[100, 0] = np.nan
    run_s = filt.run(t, u, spiked)
    run_m = filt.run(t, u, missing)
    assert run_s.event[100, 0] == 2  # rejected
    assert run_s.status_labels(0)[100] == "ok"  # one outlier does not declare the sensor lost
    np.testing.assert_array_equal(run_s.x, run_m.x)
    assert run_s.innovation[100, 0] ** 2 / run_s.innovation_variance[100, 0] > thesis_model.channels[0].gate_threshold


def test_chi2_gate_declares_a_sensor_lost_and_it_returns(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 400, seed=10)
    y[100:103, 0] += 0.05  # three consecutive outliers, the pressure sensor disagreeing: lost
    run = filt.run(t, u, y)
    labels = run.status_labels(0)
    assert labels[101] == "ok" and labels[102] == "lost-gate"
    assert labels[103] == "recovering"  # the next good sample passes the gate


def test_a_persistent_deviation_without_a_witness_is_followed(filt, thesis_model):
    # Heading sensor re-zeroed by 0.5 rad: with no other heading sensor nothing can tell an offset
    # from a change the model missed. The first sample is rejected as an outlier; the next one
    # repeats the deviation (persistence): the heading variance is widened to cover it and the
    # sample used. No loss, the filter is on the sensor at once, and the yaw-rate estimate is not
    # kicked (a plain update of this 0.5 rad innovation through the psi-r correlation sent r_hat
    # to 7 rad/s).
    t, u, y, X = simulate(thesis_model, 400, seed=10)
    y[200:, 2] += 0.5
    run = filt.run(t, u, y)
    assert run.event[200, 2] == 2 and np.all(run.event[201:, 2] == 1)
    assert set(run.status_labels(2)) == {"ok"}
    assert abs(math.remainder(run.x[201, 1] - (y[201, 2]), 2 * math.pi)) < 0.01
    assert np.max(np.abs(run.x[195:, 3] - X[195:, 3])) < 0.05


def test_sensors_that_agree_with_each_other_overrule_a_wrong_prediction(filt, thesis_model):
    """Consensus rule: the thesis design starts from P0 = 0 and knows nothing of uDrone's 6.7 N net
    buoyancy (B - W from Sandøy 2016, table 4.1). Both depth sensors then disagree with the overconfident prediction
    but agree with each other: they must be used, not gated out into dead reckoning."""
    n = 100
    t = np.arange(n) * thesis_model.h
    u = np.zeros((n, 2))
    rng = np.random.default_rng(5)
    disturbed = np.array([0.0, 0.0, 0.0, 0.0, -6.7, 0.0])  # an unmodelled upward force, as a bias state
    x = thesis_model.x0 + disturbed
    X = np.empty((n, 6))
    for k in range(n):
        X[k] = x
        x = thesis_model.Phi @ x + thesis_model.Delta @ u[k]
    y = X @ thesis_model.H.T + rng.standard_normal((n, 3)) * np.sqrt(np.diag(thesis_model.R))
    y += np.array([c.offset for c in thesis_model.channels])
    run = filt.run(t, u, y)
    # the pressure channel (1) is never rejected, and depth is tracked to within a few cm while
    # the bias converges (dead reckoning on the wrong model would drift by decimetres)
    assert not np.any(run.event[:, 1] == 2)
    assert np.max(np.abs(run.x[:, 0] - X[:, 0])) < 0.05
    assert abs(run.x[-1, 4] - (-6.7)) < 1.5


def test_an_offset_sensor_stays_out_while_a_redundant_sensor_confirms_the_prediction(filt, thesis_model):
    # Qualisys z re-zeroed by 20 cm at t = 20 s while the pressure sensor keeps agreeing with the
    # prediction: Qualisys is lost by the gate and never re-admitted (the pressure sensor is the
    # independent witness that the model, not the offset sensor, is right).
    t, u, y, X = simulate(thesis_model, 400, seed=17)
    y[200:, 0] += 0.2
    run = filt.run(t, u, y)
    labels = run.status_labels(0)
    assert labels[199] == "ok" and labels[202] == "lost-gate"
    assert set(labels[202:]) == {"lost-gate"}
    assert np.all(run.event[200:, 0] == 2)  # every offset sample rejected
    assert set(run.status_labels(1)) == {"ok"}
    assert np.max(np.abs(run.x[200:, 0] - X[200:, 0])) < 0.03  # depth follows the pressure sensor


def test_reacquire_after_erratic_disagreement_without_a_witness(filt, thesis_model):
    # Qualisys z off by 20 cm +- 5 cm at random (not a persistent deviation) and no pressure
    # sensor: every sample fails the gate, so it is lost; after disagreeing for reacquire_after_s
    # with no witness it is re-admitted (or comes back earlier through the growing depth variance).
    t, u, y, _ = simulate(thesis_model, 400, seed=17)
    rng = np.random.default_rng(3)
    y[200:, 0] += 0.2 + rng.uniform(-0.05, 0.05, 200)
    y[:, 1] = np.nan  # no pressure sensor at all (lost by timeout at the start)
    run = filt.run(t, u, y)
    labels = run.status_labels(0)
    k_back = 200 + int(round(thesis_model.channels[0].reacquire_after_s / thesis_model.h))
    assert labels[202] == "lost-gate"
    back = labels.index("recovering", 202)
    assert 202 < back <= k_back
    assert np.all(run.event[203:back, 0] == 2)


def test_non_finite_inputs_never_poison_the_state(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 300, seed=11)
    y[50, 0] = np.inf  # a faulty sample
    y[60:70, 1] = -np.inf
    y[80, :] = 1e308  # finite but absurd: rejected by the gate
    u[90] = [np.nan, np.inf]  # a broken input
    t = t.copy()
    t[95] = np.nan  # a broken time stamp
    run = filt.run(t, u, y, hold_input=False)
    assert np.all(np.isfinite(run.x)) and np.all(np.isfinite(run.variance))
    assert run.status_labels(0)[50] == "lost-nonfinite" and run.status_labels(0)[51] == "recovering"
    assert run.event[80].tolist() == [2, 2, 2]
    assert run.flags[90] & FLAG_INPUT and run.flags[95] & FLAG_TIME
    b = run.belief
    assert np.all(np.linalg.eigvalsh(b.P) > 0)
    # the same through the online API, with an explicit present mask: NaN marked present is a fault
    b0 = filt.initial_belief()
    b1, rep = filt.step(b0, 0.0, [0.0, 0.0], [np.nan, 1.0, 0.9], present=[True, True, True])
    assert rep.status[0] == "lost-nonfinite" and rep.events[0] == "nonfinite"
    assert np.all(np.isfinite(b1.x)) and np.all(np.isfinite(b1.P))


def test_manual_override(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 120, seed=12)
    b = filt.initial_belief()
    for k in range(50):  # past the start-up phase (the gate is armed)
        b, _ = filt.step(b, t[k], u[k], y[k])
    b = filt.with_mode(b, "qualisys.z", "off")
    b, rep = filt.step(b, t[50], u[50], y[50])
    assert rep.status[0] == "off" and rep.events[0] == "ignored"
    b = filt.with_mode(b, "qualisys.z", "auto")
    b, rep = filt.step(b, t[51], u[51], y[51])
    assert rep.status[0] == "recovering" and rep.events[0] == "used"
    # forced on: an outlier the gate would reject is used
    b_on = filt.with_mode(b, "qualisys.z", "on")
    bad = y[52].copy()
    bad[0] += 0.05
    _, rep_auto = filt.step(b, t[52], u[52], bad)
    _, rep_on = filt.step(b_on, t[52], u[52], bad)
    assert rep_auto.events[0] == "rejected" and rep_on.events[0] == "used"
    with pytest.raises(ValueError, match="mode"):
        filt.with_mode(b, "qualisys.z", "sometimes")
    assert filt.status(b_on)["qualisys.z"] == "recovering"


def test_heading_innovation_and_state_are_wrapped(filt):
    b = filt.initial_belief(x0=np.array([1.0, math.pi - 0.01, 0, 0, 0, 0]), P0=np.eye(6) * 1e-4)
    b, rep = filt.step(b, 0.0, [0.0, 0.0], [np.nan, np.nan, -math.pi + 0.01])
    assert rep.innovation[2] == pytest.approx(0.02, abs=1e-12)  # not -2 pi + 0.02
    assert rep.events[2] == "used"
    assert -math.pi < rep.x[1] <= math.pi
    assert abs(math.remainder(rep.x[1] - math.pi, 2 * math.pi)) < 0.011


def test_gap_in_a_log_is_bridged_by_prediction(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 100, seed=13)
    keep = np.ones(100, dtype=bool)
    keep[40] = False  # the logger skipped a row
    n_pred, bad = steps_between(t[keep], thesis_model.h)
    assert bad is None and n_pred[39] == 2 and n_pred.sum() == 100
    with_gap = filt.run(t[keep], u[keep], y[keep], n_predict=n_pred)
    y_nan = y.copy()
    y_nan[40] = np.nan
    u_held = u.copy()
    u_held[40] = u[39]  # the input is held through the gap
    full = filt.run(t, u_held, y_nan)
    np.testing.assert_allclose(with_gap.x, full.x[keep], rtol=1e-12, atol=1e-14)
    t_bad = t.copy()
    t_bad[50:] += 0.04
    assert steps_between(t_bad, thesis_model.h)[1] == 50


def test_input_hold_for_missing_log_values(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 50, seed=14)
    u_nan = u.copy()
    u_nan[10:13, 0] = np.nan
    u_held = u.copy()
    u_held[10:13, 0] = u[9, 0]
    np.testing.assert_array_equal(filt.run(t, u_nan, y).x, filt.run(t, u_held, y).x)


# --------------------------------------------------------------------------------------------
# numerics
# --------------------------------------------------------------------------------------------

def test_covariance_stays_symmetric_positive_definite_over_two_million_steps(thesis_model):
    # precise Qualisys (45 um) against metre-scale prior uncertainty and long dead-reckoning
    # stretches: the regime where the short form P - K H P goes indefinite.
    f = DepthHeadingFilter(thesis_model)
    n = 500_000
    rng = np.random.default_rng(15)
    t0 = np.arange(n) * thesis_model.h
    u = np.zeros((n, 2))
    # raw pressure reading at the board, 4.65 cm above VO: 1.0 - 0.0465 (consistent with Qualisys)
    y = np.column_stack([1.0 + 1e-4 * rng.standard_normal(n), 0.9535 + 0.01 * rng.standard_normal(n),
                         0.5 + 1e-3 * rng.standard_normal(n)])
    phase = (t0 % 3000.0)
    y[(phase > 1000.0) & (phase < 1600.0), 0] = np.nan  # 10-minute Qualisys drop-outs
    y[(phase > 1000.0) & (phase < 1600.0), 2] = np.nan
    y[(phase > 2000.0) & (phase < 2030.0), :] = np.nan  # total dead reckoning
    b = f.initial_belief(P0=np.diag([1.0, 3.0, 1.0, 1.0, 100.0, 1.0]))
    for chunk in range(4):  # 2 million steps
        run = f.run(t0 + chunk * n * thesis_model.h, u, y, belief=b)
        b = run.belief
        P = b.P
        assert np.array_equal(P, P.T)
        assert np.min(np.linalg.eigvalsh(P)) > 0
        assert np.all(run.variance > 0) and np.all(np.isfinite(run.x))
    assert run.variance[-1, 0] < 1e-8  # back on Qualisys at the end


def test_kernel_api_for_compiled_callers(filt, thesis_model):
    # what a closed-loop simulator does from its own njit loop: in-place kf_step on plain arrays
    t, u, y, _ = simulate(thesis_model, 20, seed=16)
    b = filt.initial_belief()
    x, P, ch = b.x.copy(), b.P.copy(), b.channels.copy()
    xc, Pc = np.empty(6), np.empty((6, 6))
    rep = np.empty((3, 4))
    work = kf_workspace(6, 3)
    run = filt.run(t, u, y)
    for k in range(20):
        kf_step(filt.packed, x, P, ch, t[k], u[k], y[k], ~np.isnan(y[k]), xc, Pc, rep, work)
        np.testing.assert_array_equal(xc, run.x[k])
    assert rep[0, REP_R] == filt.cfg[0, CFG_R]


def test_correct_and_predict_separately_equal_step(filt, thesis_model):
    t, u, y, _ = simulate(thesis_model, 10, seed=18)
    b = filt.initial_belief(P0=np.eye(6) * 1e-3)
    for k in range(10):
        nxt, rep = filt.step(b, t[k], u[k], y[k])
        corrected, rep_c = filt.correct(b, t[k], y[k])
        np.testing.assert_array_equal(corrected.x, rep.x)
        np.testing.assert_array_equal(rep_c.P, rep.P)
        assert rep_c.status == rep.status
        np.testing.assert_array_equal(filt.predict(corrected, u[k]).x, nxt.x)
        b = nxt


def test_scalar_joseph_update_kernel_against_numpy():
    from rovlab.estimation.kalman import kf_update_scalar

    rng = np.random.default_rng(19)
    A = rng.standard_normal((6, 6))
    P = A @ A.T + np.eye(6)
    x = rng.standard_normal(6)
    h = np.array([0.5, 0.0, 1.0, 0.0, 0.0, -0.2])  # a general row
    r, value = 0.3, 1.7
    k = P @ h / (h @ P @ h + r)
    I_kh = np.eye(6) - np.outer(k, h)
    P_ref = I_kh @ P @ I_kh.T + r * np.outer(k, k)
    x_ref = x + k * (value - h @ x)
    x1, P1 = x.copy(), P.copy()
    kf_update_scalar(x1, P1, h, value, r, False, np.zeros(6), kf_workspace(6, 1))
    np.testing.assert_allclose(x1, x_ref, rtol=1e-12)
    np.testing.assert_allclose(P1, P_ref, rtol=1e-11, atol=1e-14)


def test_consensus_does_not_let_two_sensors_with_the_same_garbage_overrule_the_model(filt, thesis_model):
    # The consensus rule's guard: both depth sensors jump by the same metre (a shared fault, e.g. a
    # logging offset). They agree with each other, but the jump fails even the widened gate, so
    # both samples are rejected exactly as if they were missing.
    t, u, y, _ = simulate(thesis_model, 200, seed=20)
    jumped = y.copy()
    jumped[100, :2] += 1.0
    missing = y.copy()
    missing[100, :2] = np.nan
    run_j = filt.run(t, u, jumped)
    run_m = filt.run(t, u, missing)
    assert run_j.event[100, :2].tolist() == [2, 2]  # rejected
    np.testing.assert_array_equal(run_j.x, run_m.x)
