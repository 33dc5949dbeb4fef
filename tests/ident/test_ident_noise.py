"""Sensor noise (Sandøy 2016, sec. 4.4.1): resting logs -> variances (R) with drift removed (decided here; the thesis
took MATLAB's var of the raw series); mapping to [[sensors]]."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.ident import IdentificationError, lab, noise


@pytest.mark.parametrize("vehicle_name, seed", [("udrone_vehicle", 1), ("udrone_vehicle", 2), ("heavy_vehicle", 3)])
def test_round_trip_within_5_percent(request, lab_table, vehicle_name, seed):
    # 6796 samples as in the thesis (sec. 4.4.1): a variance's relative standard error is
    # sqrt(2/6796) = 1.7 %, so 5 % is about 3 sigma
    vehicle = request.getfixturevalue(vehicle_name)
    data = lab.resting_log(vehicle, seed=seed)
    table = lab_table(data)
    cols = {c: table[c] for c in table.columns if c != "time_s"}
    est = noise.noise_variances(table["time_s"], cols)
    assert set(est.variance) == set(data.truth)
    for name, truth in data.truth.items():
        assert est.variance[name] == pytest.approx(truth, rel=0.05), name
        lo, hi = est.channels[name].ci95
        assert lo < est.variance[name] < hi
    if vehicle_name == "udrone_vehicle":
        # thesis table 4.8: pressure-sensor z variance 1.189622e-04 m^2
        assert est.variance["z_pressure"] == pytest.approx(1.189622e-04, rel=0.05)


def test_drift_must_be_removed(udrone_vehicle):
    data = lab.resting_log(udrone_vehicle, seed=4, drift_sigmas=5.0)
    cols = {c: v for c, v in data.columns.items() if c != "time_s"}
    with_drift = noise.noise_variances(data.columns["time_s"], cols, detrend=0)
    removed = noise.noise_variances(data.columns["time_s"], cols, detrend=1)
    truth = data.truth["z_pressure"]
    assert with_drift.variance["z_pressure"] > 2 * truth  # a 5-sigma linear drift adds 25/12 sigma^2
    assert removed.variance["z_pressure"] == pytest.approx(truth, rel=0.05)
    sd = np.sqrt(truth)
    assert abs(removed.channels["z_pressure"].drift_per_s) * data.columns["time_s"][-1] == pytest.approx(5 * sd, rel=0.1)


def test_allan_deviation_of_white_noise_falls_as_one_over_root_tau():
    rng = np.random.default_rng(11)
    x = rng.standard_normal(2**14)
    taus, adev = noise.allan_deviation(x, 0.1)
    slope = np.polyfit(np.log(taus), np.log(adev), 1)[0]
    assert slope == pytest.approx(-0.5, abs=0.05)
    assert adev[0] == pytest.approx(1.0, rel=0.05)  # ADEV at tau0 of white noise = sigma


def test_columns_map_to_sensor_channels(udrone_vehicle):
    t = np.arange(100) / 10.0
    rng = np.random.default_rng(1)
    cols = {"z_pressure": rng.standard_normal(100), "qualisys.psi": rng.standard_normal(100)}
    est = noise.noise_variances(t, cols)
    edits = noise.noise_edits(est, udrone_vehicle)
    assert set(edits) == {"sensors[name=pressure].variance.z", "sensors[name=qualisys].variance.psi"}
    assert noise.parse_channel_column("psi_qualisys") == ("qualisys", "psi")
    assert noise.parse_channel_column("temperature") is None


def test_unmappable_columns_are_listed(udrone_vehicle):
    t = np.arange(100) / 10.0
    cols = {"z_sonar": np.sin(t), "pressure.psi": np.cos(t), "temperature": t}
    est = noise.noise_variances(t, cols, check_stationary=False)  # sines are not noise at rest
    with pytest.raises(IdentificationError) as err:
        noise.noise_edits(est, udrone_vehicle)
    msg = str(err.value)
    assert "no sensor named 'sonar'" in msg
    assert "a pressure sensor has channels z" in msg
    assert "'temperature' (expected <sensor>.<channel> or <channel>_<sensor>)" in msg


def test_too_short_a_log_is_refused():
    with pytest.raises(IdentificationError, match="at least 20"):
        noise.noise_variances(np.arange(5.0), {"z_pressure": np.zeros(5)})
