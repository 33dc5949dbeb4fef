"""Filter/controller configurations and the observer model built from them (Sandøy 2016, sec. 5.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.estimation.model import build_filter_model, observability
from rovlab.params.design import (
    check_design_config_file,
    design_config_from_dict,
    load_design_config,
    packaged_config_names,
    packaged_config_path,
)
from rovlab.params.validate import ConfigError, read_toml
from rovlab.params.vehicle import load_vehicle


def _config(**changes):
    """The thesis configuration as a dict, with top-level tables replaced."""
    data = read_toml(packaged_config_path("thesis"))
    data.update(changes)
    return data


def test_packaged_configs_load_and_build_for_udrone():
    assert {"default", "thesis"} <= set(packaged_config_names())
    udrone = load_vehicle("udrone")
    for name in ("default", "thesis"):  # bluerov2_heavy is for its own vehicle (tests/params)
        assert check_design_config_file(name) == []
        model = build_filter_model(udrone, load_design_config(name))
        assert model.observable
        assert [c.name for c in model.channels] == ["qualisys.z", "pressure.z", "qualisys.psi"]


def test_thesis_config_values():
    # Sandøy 2016, appendix A.3
    c = load_design_config("thesis")
    assert c.sample_time == 0.1
    assert c.model_values(load_vehicle("udrone")) == {
        "m": 7.31, "I_zz": 0.16, "Z_wdot": -11.13, "N_rdot": -0.1, "Z_w": -5.18, "N_r": -0.06656}
    np.testing.assert_array_equal(np.diag(c.W), [0, 0, 1e-2, 1e-8, 2e-1, 1e-3])
    np.testing.assert_allclose(c.initial_state, [1.05, math.radians(52), 0, 0, 0, 0], rtol=1e-15)
    np.testing.assert_array_equal(c.P0, np.zeros((6, 6)))
    model = build_filter_model(load_vehicle("udrone"), c)
    np.testing.assert_array_equal(np.diag(model.R), [1.987803e-09, 1.189622e-04, 1.641552e-06])
    np.testing.assert_array_equal(model.H, [[1, 0, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0]])


def test_default_config_takes_the_vehicle_values():
    udrone = load_vehicle("udrone")
    model = build_filter_model(udrone, load_design_config("default"))
    assert model.params.M_w == pytest.approx(7.31 + 14.57) and model.params.N_r == -0.07
    assert model.R[1, 1] == udrone.sensor("pressure").variance["z"]
    # lever arm of the pressure sensor (Sandøy 2016, table 4.7: [0.12315, 0, -0.0465] m): z_VO = z_p - l_z (eq. 5.23)
    assert model.channels[1].offset == -0.0465
    assert model.channels[0].timeout_s == pytest.approx(0.5)  # 5 periods at 10 Hz


def test_default_config_needs_the_sensor_kinds():
    with pytest.raises(ConfigError, match="motion_capture"):
        build_filter_model(load_vehicle("bluerov2_heavy"), load_design_config("default"))


def test_unobservable_sensor_sets_are_refused_naming_the_states():
    udrone = load_vehicle("udrone")
    only_pressure = design_config_from_dict(_config(measurements=[{"sensor": "pressure", "quantity": "z"}]))
    with pytest.raises(ConfigError) as err:
        build_filter_model(udrone, only_pressure)
    text = str(err.value)
    assert "psi, r, b_r" in text and "Add a measurement of psi" in text
    model = build_filter_model(udrone, only_pressure, require_observable=False)
    assert not model.observable and model.unobservable == ("psi", "r", "b_r")
    only_heading = design_config_from_dict(_config(measurements=[{"sensor": "qualisys", "quantity": "psi"}]))
    with pytest.raises(ConfigError, match="z, w, b_w"):
        build_filter_model(udrone, only_heading)


def test_observability_check_on_textbook_cases():
    A = build_filter_model(load_vehicle("udrone"), load_design_config("thesis")).A
    # velocities alone never give the positions (pure integrators)
    ok, touched, V = observability(A, np.eye(6)[[2, 3]])
    assert not ok and touched == ("z", "psi") and V.shape[1] == 2
    # depth and heading observe everything, biases included (thesis eq. 5.16)
    assert observability(A, np.eye(6)[[0, 1]])[0]


def test_measurement_variance_falls_back_to_the_vehicle_and_must_exist():
    udrone = load_vehicle("udrone")
    cfg = design_config_from_dict(_config(measurements=[
        {"sensor": "qualisys", "quantity": "z"}, {"sensor": "qualisys", "quantity": "psi"}]))
    model = build_filter_model(udrone, cfg)
    assert model.R[0, 0] == udrone.sensor("qualisys").variance["z"]
    cfg = design_config_from_dict(_config(measurements=[
        {"sensor": "qualisys", "quantity": "z"}, {"sensor": "imu", "quantity": "psi"}]), file="my.toml")
    with pytest.raises(ConfigError, match=r"my.toml: measurements\[1\].variance.*imu.psi"):
        build_filter_model(udrone, cfg)
    cfg = design_config_from_dict(_config(measurements=[{"sensor": "sonar", "quantity": "z"}]), file="my.toml")
    with pytest.raises(ConfigError, match="sensor of vehicle 'udrone'"):
        build_filter_model(udrone, cfg)


def test_bad_configuration_lists_every_problem():
    data = _config()
    data["sample_time"] = -0.1
    data["colour"] = "blue"
    data["process_noise"] = dict(data["process_noise"], bias_time_constant={"w": 10.0, "r": 5.0})
    data["fusion"] = dict(data["fusion"], gate_probability=0.2)
    data["measurements"] = [{"sensor": "qualisys", "quantity": "x"}, {"quantity": "z"}]
    del data["lqr"]["source"]
    with pytest.raises(ConfigError) as err:
        design_config_from_dict(data, file="bad.toml")
    text = str(err.value)
    for needle in ("bad.toml: sample_time", "bad.toml: colour", "unknown keys are errors",
                   "process_noise.bias_time_per_mass", "fusion.gate_probability",
                   "measurements[0].quantity", "measurements[1].sensor", "lqr.source"):
        assert needle in text, needle
    assert len(err.value.problems) == 7


def test_lqr_weights_forms():
    data = _config()
    data["lqr"] = {"source": "test", "Q_diag": [1.0, 2.0, 3.0, 4.0], "R_diag": [0.5, 0.25]}
    c = design_config_from_dict(data)
    np.testing.assert_array_equal(c.lqr_Q, [1, 2, 3, 4])
    data["lqr"] = {"source": "test", "Q_diag": [1.0, 2.0, 3.0, 4.0], "R_diag": [0.5, 0.0]}
    with pytest.raises(ConfigError, match="positive input weights"):
        design_config_from_dict(data)
    data["lqr"] = {"source": "test"}
    with pytest.raises(ConfigError, match="either Bryson"):
        design_config_from_dict(data)


def test_values_that_overflow_are_refused_naming_the_file():
    # used to end in NaN matrices (psd 1e300) or a ValueError traceback from the filter (std 1e300)
    udrone = load_vehicle("udrone")
    data = _config()
    data["process_noise"] = dict(data["process_noise"], psd={"w": 1e300, "r": 1e300, "b_w": 1e300, "b_r": 1e300})
    # since issue 15 the loader refuses implausible values before the design overflows
    with pytest.raises(ConfigError, match=r"my.toml: process_noise.psd.w: got 1e\+300.*0 \.\. 1e\+06"):
        build_filter_model(udrone, design_config_from_dict(data, file="my.toml"))
    data = _config(sample_time=1e9)
    with pytest.raises(ConfigError, match=r"my.toml: sample_time: got 1000000000.0.*0.001 \.\. 10"):
        build_filter_model(udrone, design_config_from_dict(data, file="my.toml"))
    data = _config()
    data["initial"] = dict(data["initial"], std={"z": 1e300, "psi_deg": 10.0})
    with pytest.raises(ConfigError, match=r"my.toml: initial.std.z: got 1e\+300"):
        design_config_from_dict(data, file="my.toml")


def test_sensor_management_settings_that_destabilise_the_loop_are_refused():
    # issue 10: recovery_variance_factor = 1 let the closed loop diverge (it is gone; the key is
    # refused with the reason), and a start-up phase shorter than the design needs let the gate
    # discard healthy sensors while the filter was still wrong (startup_s = 0 with P0 = 0: the
    # closed loop left its depth by a metre).
    udrone = load_vehicle("udrone")
    data = _config()
    data["fusion"] = dict(data["fusion"], recovery_variance_factor=1.0)
    with pytest.raises(ConfigError, match=r"my.toml: fusion.recovery_variance_factor: got 1.0; .*recovery_time_s"):
        design_config_from_dict(data, file="my.toml")
    data = _config()
    data["fusion"] = dict(data["fusion"], startup_s=0.0)
    with pytest.raises(ConfigError, match=r"my.toml: fusion.startup_s \(measurements\[0\]\): got 0.0; expected at least"):
        build_filter_model(udrone, design_config_from_dict(data, file="my.toml"))
    data["fusion"] = dict(data["fusion"], startup_s=0.0, gate_probability=1.0)  # no gate: nothing to wait for
    build_filter_model(udrone, design_config_from_dict(data, file="my.toml"))
    data = _config()
    data["fusion"] = dict(data["fusion"], stuck_window_s=0.2)  # 2 samples cannot show a variance
    with pytest.raises(ConfigError, match=r"stuck_window_s: got 0.2; expected a window of at least 5 samples"):
        build_filter_model(udrone, design_config_from_dict(data, file="my.toml"))


def test_start_up_phase_from_the_design():
    # the Riccati recursion from P0 converges in about a second for the thesis design (P0 = 0), and
    # the steady-state error dynamics have a time constant of 0.3 s: 1.1 s + 5 x 0.3 s
    from scipy.linalg import solve_discrete_are

    from rovlab.estimation.model import startup_time

    m = build_filter_model(load_vehicle("udrone"), load_design_config("thesis"))
    assert all(c.startup_s == pytest.approx(2.59, abs=0.01) for c in m.channels)
    # the error time constant, independently: steady-state prior covariance from scipy's DARE
    P = solve_discrete_are(m.Phi.T, m.H.T, m.Q, m.R)
    K = P @ m.H.T @ np.linalg.inv(m.H @ P @ m.H.T + m.R)
    rho = max(abs(np.linalg.eigvals(m.Phi @ (np.eye(6) - K @ m.H))))
    tau = -m.h / math.log(rho)
    assert tau == pytest.approx(0.30, abs=0.01)
    converge = startup_time(m.Phi, m.Q, m.H, m.R, m.P0, m.h, time_constants=0.0)
    assert m.channels[0].startup_s == pytest.approx(converge + 5 * tau, rel=1e-6)
    assert 0.5 < converge < 2.0
    data = _config()
    data["fusion"] = dict(data["fusion"], startup_s=10.0)
    c = build_filter_model(load_vehicle("udrone"), design_config_from_dict(data))
    assert all(ch.startup_s == 10.0 for ch in c.channels)
