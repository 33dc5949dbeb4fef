"""Sensor faults on logs through ``rovlab filter`` (issue 10): outliers, a stuck sensor, an offset.

The logs come from the thesis's observer model itself (Sandøy 2016, sec. 5.1.1, the plant of its case
study 1, fig. 5.2: the filter's model is right), sampled at 10 Hz with the thesis's sensor variances
(table 4.8), so every reaction below is the sensor management's, not a model mismatch.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.estimation.model import build_filter_model
from rovlab.interfaces.cli import main
from rovlab.io.logreader import read_log
from rovlab.io.logwriter import write_csv
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle

N = 600  # 60 s at 10 Hz
COLUMNS = ("z_qualisys", "z_pressure", "psi_qualisys")


@pytest.fixture(scope="module")
def model():
    return build_filter_model(load_vehicle("udrone"), load_design_config("thesis"))


def make_log(model, seed):
    """Truth x_k (N x 6) and the log columns of a run of the observer model with sensor noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * model.h
    u = np.column_stack([4.0 * np.sin(2 * np.pi * t / 20.0), 0.004 * np.cos(2 * np.pi * t / 15.0)])
    L = np.linalg.cholesky(model.Q)
    x = model.x0.copy()
    X = np.empty((N, 6))
    for k in range(N):
        X[k] = x
        x = model.Phi @ x + model.Delta @ u[k] + L @ rng.standard_normal(6)
    cols = {"time_s": t, "tau_Z": u[:, 0], "tau_N": u[:, 1]}
    for c in model.channels:  # raw readings: the lever arm is undone by the filter
        cols[c.column] = X[:, c.state_index] + c.offset + math.sqrt(c.variance) * rng.standard_normal(N)
    cols["psi_qualisys"] = np.remainder(cols["psi_qualisys"] + np.pi, 2 * np.pi) - np.pi
    return X, cols


def rovlab_filter(tmp_path, capsys, cols, name):
    log = tmp_path / f"{name}.csv"
    out = tmp_path / f"{name}-est.csv"
    write_csv(log, cols)
    code = main(["filter", str(log), "--out", str(out), "--config", "thesis"])
    _, err = capsys.readouterr()
    assert code == 0, err
    return read_log(out)


def first(labels, label, start):
    return next(k for k in range(start, len(labels)) if labels[k] == label)


def test_100_sigma_outliers_are_rejected_without_a_trace(tmp_path, capsys, model):
    # (seed 1 would show something else: a 4.7-sigma process-noise event at t = 11.3 s that the
    # heading filter then follows through the recovery ramp, during which a 0.13 rad heading
    # outlier is no longer 100 sigma of the filter's honest uncertainty)
    X, cols = make_log(model, seed=4)
    spiked = {k: v.copy() for k, v in cols.items()}
    missing = {k: v.copy() for k, v in cols.items()}
    # isolated 100-sigma outliers on every channel, both signs, after the start-up phase
    hits = {"z_qualisys": (80, 230, 410), "z_pressure": (120, 300, 480), "psi_qualisys": (150, 350, 520)}
    for c in model.channels:
        sigma = math.sqrt(c.variance)
        for i, k in enumerate(hits[c.column]):
            spiked[c.column][k] += (100.0 if i % 2 == 0 else -100.0) * sigma
            missing[c.column][k] = np.nan
    est_s = rovlab_filter(tmp_path, capsys, spiked, "spiked")
    est_m = rovlab_filter(tmp_path, capsys, missing, "missing")
    # no visible effect: the estimate is exactly the one without those samples
    for s in ("z", "psi", "w", "r", "b_w", "b_r"):
        np.testing.assert_array_equal(est_s[f"est_{s}"], est_m[f"est_{s}"])
    for col in COLUMNS:  # one outlier never declares a sensor lost
        assert set(est_s.text[f"status_{col}"]) == {"ok"}
    assert np.max(np.abs(est_s["est_z"] - X[:, 0])) < 1e-3


def test_a_stuck_pressure_sensor_is_declared_lost_within_3_s(tmp_path, capsys, model):
    X, cols = make_log(model, seed=2)
    k0, k1 = 200, 400  # frozen at its last reading from t = 20 s to t = 40 s
    cols["z_pressure"][k0:k1] = cols["z_pressure"][k0 - 1]
    est = rovlab_filter(tmp_path, capsys, cols, "stuck")
    status = est.text["status_z_pressure"]
    assert set(status[:k0]) == {"ok"}
    k_lost = first(status, "lost-stuck", k0)
    assert est.time[k_lost] - est.time[k0] <= 3.0
    assert all(s == "lost-stuck" for s in status[k_lost:k1])
    # once it reports noise again it comes back through the recovery path
    assert "recovering" in status[k1:k1 + 25] and status[-1] == "ok"
    assert set(est.text["status_z_qualisys"]) == {"ok"}  # the other depth sensor is not blamed
    assert np.max(np.abs(est["est_z"] - X[:, 0])) < 1e-3


def test_an_offset_sensor_is_rejected_while_the_redundant_sensor_agrees_with_the_model(tmp_path, capsys, model):
    X, cols = make_log(model, seed=3)
    k0 = 200
    # One sensor at a time. A single pressure sample (sigma 11 mm) can only refute a Qualisys
    # offset beyond the pairwise gate, sqrt(15.1 (R_q + R_p)) = 4.2 cm, plus its own noise: 10 cm.
    for col, offset in (("z_qualisys", 0.10), ("z_pressure", 0.20)):
        faulty = {k: v.copy() for k, v in cols.items()}
        faulty[col][k0:] += offset  # re-zeroed at t = 20 s and never back
        missing = {k: v.copy() for k, v in cols.items()}
        missing[col][k0:] = np.nan
        est_f = rovlab_filter(tmp_path, capsys, faulty, f"offset-{col}")
        est_m = rovlab_filter(tmp_path, capsys, missing, f"missing-{col}")
        status = est_f.text[f"status_{col}"]
        other = "z_pressure" if col == "z_qualisys" else "z_qualisys"
        assert set(status[:k0]) == {"ok"} and status[k0 + 2] == "lost-gate"
        # rejected for good, well past reacquire_after_s: the redundant sensor confirms the model
        assert set(status[k0 + 2:]) == {"lost-gate"}
        assert set(est_f.text[f"status_{other}"]) == {"ok"}
        # every offset sample rejected: the estimate is the one without the faulty sensor
        np.testing.assert_array_equal(est_f["est_z"], est_m["est_z"])
        assert np.max(np.abs(est_f["est_z"][k0:] - X[k0:, 0])) < 0.03
