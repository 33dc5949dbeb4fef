"""Drop-out, recovery and sensor-loss metrics (issue 10): the pure functions on synthetic columns,
then the closed-loop checks that run fast (a few runs of the packaged case studies, Sandøy 2016, sec. 5.3.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.estimation.fusion import (
    REASON_GATE,
    REASON_STUCK,
    REASON_TIMEOUT,
    STATUS_LOST,
    STATUS_OK,
    STATUS_RECOVERING,
    code_label,
    status_code,
)
from rovlab.params.design import design_config_from_dict, packaged_config_path
from rovlab.params.validate import read_toml
from rovlab.sim import metrics as mx
from rovlab.sim.prepare import prepare
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import load_scenario

H = 0.1


def columns(n=600):
    t = np.arange(n) * H
    zero = np.zeros(n)
    return {"time_s": t, "true_z": zero + 0.7, "est_z": zero + 0.7, "true_psi": zero.copy(), "est_psi": zero.copy(),
            "true_r": zero.copy(), "est_r": zero.copy(), "tau_N": zero.copy(), "var_psi": zero + 1e-6}


# --------------------------------------------------------------------------------------------
# pure functions
# --------------------------------------------------------------------------------------------

def test_error_before_the_dropout_leaves_out_the_start_up_transient():
    c = columns()
    t = c["time_s"]
    c["est_z"] = c["est_z"] + np.where(t < 5.0, 0.05, 0.001)  # 5 cm while the bias converges, then 1 mm
    before = mx.error_before_dropout(c, 20.0, settle_s=10.0)
    assert before["z"] == pytest.approx(0.001)
    assert before["from_s"] == 10.0 and before["to_s"] == 20.0 and before["window_s"] == 10.0
    assert mx.error_before_dropout(c, 5.0, settle_s=10.0)["z"] is None  # empty window


def test_drift_during_the_dropout_is_wrapped():
    c = columns()
    t = c["time_s"]
    window = (t >= 20.0) & (t < 40.0)
    c["true_psi"] = np.full(t.size, math.pi - 0.05)
    c["est_psi"] = mx.wrap(c["true_psi"] + np.where(window, 0.01 * (t - 20.0), 0.0))  # crosses +-pi
    d = mx.drift_during_dropout(c, 20.0, 40.0)["psi"]
    assert d["drift"] == pytest.approx(0.199, abs=1e-9)
    assert d["max_abs_error"] == pytest.approx(0.199, abs=1e-9)


def test_recovery_kick_measures_psi_r_and_tau_n_after_the_return():
    c = columns()
    ret = 40.0
    k = int(round(ret / H))
    c["true_psi"][:] = 0.3
    c["est_psi"][:] = 0.3
    c["est_psi"][:k] = 0.3 - 0.2  # 0.2 rad off during the drop-out, jumps back at the return
    c["est_r"][k] = 0.05
    c["tau_N"][k + 3] = -0.03
    c["tau_N"][k + 80] = 0.5  # outside the 5 s window
    c["var_psi"][:k] = 1.0  # dead reckoning: the filter's own sigma is huge
    out = mx.recovery_kick(c, ret, window_s=5.0)
    assert out["max_step_psi"] == pytest.approx(0.2)
    assert out["max_step_r"] == pytest.approx(0.05)
    assert out["peak_abs_tau_N"] == pytest.approx(0.03)
    assert out["psi_error_at_return"] == pytest.approx(-0.2)
    assert out["psi_back_within_2sigma_s"] == pytest.approx(0.0)
    c["est_psi"][k:k + 20] = 0.3 - 0.2 * np.linspace(1.0, 0.05, 20)  # spread over 2 s
    assert mx.recovery_kick(c, ret)["psi_back_within_2sigma_s"] == pytest.approx(2.0)
    assert mx.recovery_kick(c, 100.0)["max_step_psi"] is None  # after the end of the log


def test_sensor_loss_events_with_reasons_and_expected_dropouts():
    c = columns(400)
    n = c["time_s"].size
    q = np.zeros(n)
    q[205:400] = status_code(STATUS_LOST, REASON_TIMEOUT)  # the scheduled drop-out
    q[100:103] = status_code(STATUS_LOST, REASON_GATE)  # a false alarm
    q[103:150] = status_code(STATUS_RECOVERING, 0)
    p = np.zeros(n)
    p[300:] = status_code(STATUS_LOST, REASON_STUCK)
    plain = np.zeros(n)
    plain[50:60] = STATUS_LOST  # a log with plain STATUS_* codes: reason unknown
    c.update(status_z_qualisys=q, status_z_pressure=p, status_psi_qualisys=plain)
    events = mx.sensor_loss_events(c, dropouts=[{"sensor": "qualisys.z", "start_s": 20.0, "end_s": 40.0}])
    assert [(e["channel"], e["t_s"], e["reason"], e["expected"]) for e in events] == [
        ("psi_qualisys", 5.0, "unknown", False), ("z_qualisys", 10.0, "gate", False),
        ("z_qualisys", 20.5, "timeout", True), ("z_pressure", 30.0, "stuck", False)]
    assert mx.loss_event_counts(events) == {"total": 4, "unexpected": 3,
                                            "by_reason": {"gate": 1, "stuck": 1, "timeout": 1, "unknown": 1}}
    assert code_label(status_code(STATUS_OK, 0)) == "ok" and code_label(8) == "lost-stuck"
    with pytest.raises(ValueError, match="status code"):
        code_label(42)


def test_dropout_metrics_composes_the_three():
    c = columns()
    out = mx.dropout_metrics(c, [("qualisys", 20.0, 40.0)])
    assert len(out) == 1 and set(out[0]) == {"sensor", "start_s", "end_s", "before", "during", "recovery"}


# --------------------------------------------------------------------------------------------
# closed loop (Sandøy 2016, sec. 5.3.1, case studies 2 and 3, figs. 5.3 and 5.4; thesis configuration)
# --------------------------------------------------------------------------------------------

def thesis_with(**fusion):
    data = read_toml(packaged_config_path("thesis"))
    data["fusion"] = dict(data["fusion"], **fusion)
    return design_config_from_dict(data, file="thesis (modified)")


@pytest.fixture(scope="module")
def gate_off():
    return thesis_with(gate_probability=1.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_process_model_runs_lose_no_sensor_and_keep_the_gate_off_depth_error(seed, gate_off):
    # issue 10: P0 = 0 and the 6.7 N net buoyancy used to cost Qualisys z at t = 0.3 s in every run
    runs = {}
    for label, cfg in (("on", None), ("off", gate_off)):
        res = run_prepared(prepare(load_scenario("step-process-model", seed=seed), config=cfg))
        runs[label] = res.columns
    events = mx.sensor_loss_events(runs["on"])
    assert events == []
    rms = {k: float(mx.rms(c["est_z"] - c["true_z"])) for k, c in runs.items()}
    assert rms["on"] <= 2.0 * rms["off"]


def test_dropout_recovery_spreads_the_correction(gate_off):
    scenario = load_scenario("dropout")  # seed 3: Qualisys lost from 20 s to 40 s
    rec = {}
    for label, cfg in (("ramp", None), ("abrupt", thesis_with(recovery_time_s=0.0))):
        res = run_prepared(prepare(scenario, config=cfg))
        (m,) = mx.dropout_metrics(res.columns, res.meta["dropouts"])
        rec[label] = m["recovery"]
        events = mx.sensor_loss_events(res.columns, dropouts=res.meta["dropouts"])
        assert mx.loss_event_counts(events)["unexpected"] == 0
    ramp, abrupt = rec["ramp"], rec["abrupt"]
    assert abs(abrupt["psi_error_at_return"]) > 0.1  # a real heading drift to correct
    assert ramp["max_step_psi"] <= 0.25 * abrupt["max_step_psi"]
    assert ramp["max_step_r"] <= abrupt["max_step_r"] / 3.0
    assert ramp["peak_abs_tau_N"] <= 0.5 * abrupt["peak_abs_tau_N"]
    assert ramp["psi_back_within_2sigma_s"] is not None and ramp["psi_back_within_2sigma_s"] < 5.0


@pytest.mark.parametrize("name", ["heave-buoyancy-step", "heave-payload"])
def test_a_change_the_model_missed_costs_no_sensor(name, gate_off):
    # A float floods (-5 N at 40 s) or a payload is picked up: the truth accelerates away from the
    # prediction, and Qualisys z (0.045 mm) fails the gate at once. It is the model that is wrong,
    # so the sensor must stay in and teach the bias estimate (issue 10: "never discard a healthy
    # sensor because the filter is the one that is wrong"). Before the maneuver rule of
    # rovlab.estimation.fusion, heave-buoyancy-step lost Qualisys z at 40.3 s, the estimate trailed
    # the sinking vehicle for 5 s, and it sank 0.37 m below its set-point (2.5 cm with the gate off).
    runs = {}
    for label, cfg in (("on", None), ("off", gate_off)):
        res = run_prepared(prepare(load_scenario(name), config=cfg))
        runs[label] = res.columns
    assert mx.sensor_loss_events(runs["on"]) == []
    c = runs["on"]
    after = c["time_s"] >= 30.0
    excursion = {k: float(np.max(np.abs(v["true_z"] - v["ref_z"])[after])) for k, v in runs.items()}
    assert excursion["on"] <= 1.5 * excursion["off"] + 0.005
    rms = {k: float(mx.rms(v["est_z"] - v["true_z"])) for k, v in runs.items()}
    assert rms["on"] <= 2.0 * rms["off"]
