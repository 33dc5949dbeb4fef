"""The virtual lab: seeded, reproducible, and shaped like the thesis's experiments (Sandøy 2016, sec. 2.3 and ch. 4)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.ident import lab
from rovlab.io.tables import read_table


def test_same_seed_same_data_different_seed_different_data(udrone_vehicle):
    a = lab.thrust_rig(udrone_vehicle, "T1", seed=5, step_s=4.0)
    b = lab.thrust_rig(udrone_vehicle, "T1", seed=5, step_s=4.0)
    c = lab.thrust_rig(udrone_vehicle, "T1", seed=6, step_s=4.0)
    np.testing.assert_array_equal(a.columns["force_n"], b.columns["force_n"])
    assert not np.array_equal(a.columns["force_n"], c.columns["force_n"])
    d = lab.thrust_rig(udrone_vehicle, "T1", step_s=4.0)  # no seed: a fresh one, recorded
    assert isinstance(d.seed, int)
    e = lab.thrust_rig(udrone_vehicle, "T1", seed=d.seed, step_s=4.0)
    np.testing.assert_array_equal(d.columns["force_n"], e.columns["force_n"])


def test_file_records_seed_settings_and_truth(tmp_path, udrone_vehicle):
    data = lab.towing_runs(udrone_vehicle, "sway", seed=77, hold_s=5.0)[0]
    path = tmp_path / "sway.csv"
    lab.write_lab_data(path, data)
    table = read_table(path)
    meta = table.meta()
    assert meta["seed"] == "77"
    assert meta["vehicle"] == "udrone"
    assert meta["setting.dof"] == "sway"
    assert float(meta["truth.linear"]) == -6.22  # Sandøy 2016, table 4.6: Y_v
    assert table.columns == ("run", "time_s", "speed_mps", "force_n")


def test_staircase_follows_the_thesis_rig(udrone_vehicle):
    data = lab.thrust_rig(udrone_vehicle, "T2", seed=1)  # the full thesis staircase
    pwm, t = data.columns["pwm_us"], data.columns["time_s"]
    levels = np.unique(pwm)
    np.testing.assert_array_equal(levels, np.arange(1300, 1701, 10))  # 1300 -> 1700 us in 10 us steps
    assert t[-1] + t[1] == pytest.approx(41 * 30.0)  # 30 s each
    assert np.all(np.diff(pwm) >= 0)
    # the ESC sees a low-pass-filtered command: no force spike at a step (Sandøy 2016, sec. 2.3.2). Noise-free
    # rig, step 1650 -> 1660 us: one sample after the step the force has moved < 5 % of the way.
    quiet = lab.thrust_rig(udrone_vehicle, "T2", seed=1, noise_std_n=0.0)
    f = quiet.columns["force_n"]
    k = int(np.flatnonzero(pwm == 1660)[0])
    total = f[k + 29 * 50] - f[k - 1]  # 29 s later
    assert total > 0.5
    assert 0 <= f[k + 1] - f[k - 1] < 0.05 * total


def test_towing_runs_ramp_hold_and_rig_drag(udrone_vehicle):
    veh, rig = lab.towing_runs(udrone_vehicle, "surge", seed=2, speeds=(0.3, -0.3), noise_std_n=0.0,
                               offset_std_n=0.0, speed_noise_mps=0.0)
    run1 = veh.columns["run"] == 1
    v = veh.columns["speed_mps"][run1]
    assert v.max() == pytest.approx(0.3) and v[0] == 0.0 and v[-1] == 0.0
    hold = v == 0.3
    f_total = veh.columns["force_n"][run1][hold][-1]
    f_rig = rig.columns["force_n"][rig.columns["run"] == 1][hold][-1]
    # force_n = -(X_u u + X_|u|u u|u| + X_uuu u^3) + rig drag (surge values of Sandøy 2016, table 4.6)
    expected = 4.03 * 0.3 + 18.18 * 0.09 + 24.24 * 0.027
    assert f_total - f_rig == pytest.approx(expected, rel=1e-3)
    assert f_rig == pytest.approx(1.0 * 0.3 + 6.0 * 0.09, rel=1e-3)


def test_yaw_heading_is_wrapped_to_half_open_interval():
    x = np.array([np.pi, -np.pi, 3 * np.pi, 0.5, -3.5])
    w = lab.wrap_angle(x)
    assert np.all((w > -np.pi) & (w <= np.pi))
    np.testing.assert_allclose(w[:3], np.pi)
    np.testing.assert_allclose(np.exp(1j * w), np.exp(1j * x))


def test_relay_uses_the_vehicles_motion_capture_variance(udrone_vehicle):
    d = lab.relay_test(udrone_vehicle, "surge", seed=3, linear=True, duration_s=20.0)
    assert d.settings["position_variance"] == pytest.approx(2.727425e-08)  # thesis table 4.8, Qualisys x
    assert d.settings["rate_hz"] == 10.0
    assert set(np.unique(np.abs(d.columns["force_n"]))) == {2.0}


def test_relay_without_motion_capture_falls_back_and_says_so(heavy_vehicle):
    d = lab.relay_test(heavy_vehicle, "surge", seed=3, duration_s=20.0)
    assert any("no motion-capture sensor" in n for n in d.notes)


def test_relay_that_never_switches_is_refused(udrone_vehicle):
    with pytest.raises(ValueError, match="the relay switched 0 time"):
        lab.relay_test(udrone_vehicle, "heave", seed=1, force=0.5, buoyancy_error_n=1.0)


def test_resting_log_has_every_sensor_channel(udrone_vehicle):
    d = lab.resting_log(udrone_vehicle, seed=1, samples=100)
    names = [c for c in d.columns if c != "time_s"]
    expected = [f"{ch}_{s.name}" for s in udrone_vehicle.sensors for ch in s.variance]
    assert names == expected
    assert d.columns["time_s"][1] == pytest.approx(0.1)  # 10 Hz as in the vehicle file


def test_settings_are_checked_by_the_python_api_too(udrone_vehicle):
    # the CLI checks its options; the functions check theirs, naming the parameter
    with pytest.raises(ValueError, match="noise_std_n must be a non-negative finite number, got -1"):
        lab.thrust_rig(udrone_vehicle, "T1", seed=1, noise_std_n=-1.0)
    with pytest.raises(ValueError, match="towing speeds must be a non-zero finite number, got nan"):
        lab.towing_runs(udrone_vehicle, "surge", seed=1, speeds=(0.1, float("nan")))
    with pytest.raises(ValueError, match="moments must be a non-zero finite number, got 0"):
        lab.yaw_runs(udrone_vehicle, seed=1, moments=(0.0, 1.0))
    with pytest.raises(ValueError, match="relay force must be a positive finite number, got nan"):
        lab.relay_test(udrone_vehicle, "surge", seed=1, force=float("nan"))
    with pytest.raises(ValueError, match="rate_hz must be a positive finite number, got 0"):
        lab.resting_log(udrone_vehicle, seed=1, rate_hz=0.0)
    with pytest.raises(ValueError, match="relay log would have 1e\\+08 rows"):
        lab.relay_test(udrone_vehicle, "surge", seed=1, duration_s=1e7)


def test_thrusters_with_different_curves_on_one_rig_are_flagged(udrone_vehicle):
    same = lab.thrust_rig(udrone_vehicle, ["T1", "T2"], seed=1, step_s=2.0)
    mixed = lab.thrust_rig(udrone_vehicle, ["T1", "T3"], seed=1, step_s=2.0)  # Sandøy 2016, table 2.2: T3 has its own curve
    assert not any("do not share one thrust curve" in n for n in same.notes)
    assert any("do not share one thrust curve" in n for n in mixed.notes)


def test_long_resting_log_keeps_increasing_times(tmp_path, udrone_vehicle):
    # time_s was written with 6 significant digits: past 100 000 s (1e6 samples at 10 Hz) rows
    # got equal times and the file could not be read back
    d = lab.resting_log(udrone_vehicle, seed=1, samples=2, rate_hz=1e-5)  # t = 0, 100 000 s ...
    d = lab.LabData(d.experiment, {k: v + (123456.7 if k == "time_s" else 0.0) for k, v in d.columns.items()},
                    d.truth, d.settings, d.seed, d.vehicle, d.formats, d.notes)
    lab.write_lab_data(tmp_path / "rest.csv", d)
    np.testing.assert_allclose(read_table(tmp_path / "rest.csv")["time_s"], [123456.7, 223456.7], rtol=1e-12)
