"""Absurd values in the [ekf] and [dp] tables of a design file (issue 28, fuzzing campaign): a bias
PSD of 2e298 passed `rovlab design` and crashed `rovlab simulate` with numpy's LinAlgError (a
traceback), and a DP bandwidth of 1e300 ran to exit 0 with NaN in the demanded wrench. Each is
refused where the table is read (rovlab.params.design.per_key, the helper both readers use),
naming file, key, value and the range expected; never inside the kernels.

Measured on dp-station-keeping shortened to 20 s (2026-11-27): force_psd and bias_psd 1e6 in all
axes, initial_std 1e4 m / 720 deg / 10 m/s / 1e4 N, bandwidth, reference_bandwidth and
max_speed 1e6: finite. Past the bound: bias_psd 2e298 and force_psd 1e300 LinAlgError,
initial_std 1e300 NaN variances, bandwidth 1e300 and reference_bandwidth 1e300 NaN.
Not covered by a bound on magnitude, so bounded by physical ranges in the EKF's reader
(rovlab/estimation/ekf.py, read_ekf_table): initial_std 1e6 (LinAlgError in the EKF kernel after a
few seconds) and a known current of 5 m/s (the same)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rovlab.interfaces.cli import main
from rovlab.params.design import design_config_from_dict, load_design_config
from rovlab.params.validate import ConfigError, read_toml

REFUSED = [
    ("ekf", "bias_psd", "X", 2e298),
    ("ekf", "force_psd", "N", 1e300),
    ("ekf", "initial_std", "x", 1e300),
    ("ekf", "initial_state", "u", -1e300),
    ("ekf", "current", "north", 1e300),
    ("ekf", "bias_time_constant_s", "Z", 1e300),
    ("dp", "bandwidth", "x", 1e300),
    ("dp", "reference_bandwidth", "psi", 1e300),
    ("dp", "max_speed", "x", 1e300),
    ("dp", "max_speed", "psi_deg_s", 1e300),
]


def _mutant(table: str, key: str, sub: str, value: float) -> dict:
    data = read_toml(load_design_config("udrone_dp").file)
    data[table] = dict(data[table])
    data[table][key] = dict(data[table].get(key, {}), **{sub: value})
    return data


@pytest.mark.parametrize("table,key,sub,value", REFUSED, ids=lambda v: str(v))
def test_an_absurd_value_is_refused_where_the_table_is_read(table, key, sub, value):
    with pytest.raises(ConfigError) as exc:
        design_config_from_dict(_mutant(table, key, sub, value), file="my_dp.toml")
    text = str(exc.value)
    assert f"my_dp.toml: {table}.{key}.{sub}: got {value!r}; expected" in text, text


@pytest.mark.parametrize("table,key,sub,value", [("ekf", "bias_psd", "X", 1e6), ("ekf", "force_psd", "X", 1e6),
                                                 ("ekf", "initial_std", "b_X", 1e4), ("ekf", "current", "east", -2.0),
                                                 ("dp", "bandwidth", "z", 1e6), ("dp", "max_speed", "x", 1e6)],
                         ids=lambda v: str(v))
def test_large_but_finite_values_are_accepted(table, key, sub, value):
    config = design_config_from_dict(_mutant(table, key, sub, value), file="my_dp.toml")
    assert config.table(table) is not None


def test_rovlab_design_and_simulate_refuse_the_fuzzers_bias_psd(tmp_path, capsys):
    """The reproducer: bias_psd X = 2e298 in udrone_dp (design passed, simulate: LinAlgError)."""
    import tomlkit

    path = tmp_path / "my_dp.toml"
    path.write_text(tomlkit.dumps(_mutant("ekf", "bias_psd", "X", 2e298)), encoding="utf-8")
    assert main(["design", "--vehicle", "udrone_dvl", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{path}: ekf.bias_psd.X: got 2e+298; expected" in err, err
    scenario = tmp_path / "dp.toml"
    from rovlab.sim.scenario import resolve_scenario_path

    text = resolve_scenario_path("dp-station-keeping").read_text(encoding="utf-8")
    scenario.write_text(text.replace('design = "udrone_dp"', f'design = "{path}"'), encoding="utf-8")
    out = tmp_path / "out"
    assert main(["simulate", str(scenario), "--out", str(out), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "ekf.bias_psd.X" in err and not out.exists(), err


@pytest.mark.parametrize("key,sub,value", [("initial_std", "x", 1e6), ("current", "north", 5.0)])
def test_values_that_break_the_ekf_kernel_are_refused_by_its_reader(key, sub, value):
    with pytest.raises(ConfigError, match=rf"ekf\.{key}\.{sub}: got"):
        design_config_from_dict(_mutant("ekf", key, sub, value), file="my_dp.toml")


def test_the_packaged_dp_designs_load():
    for name in ("udrone_dp", "bluerov2_heavy_dp"):
        assert Path(load_design_config(name).file).is_file()


@pytest.mark.parametrize("edit, key", [
    (lambda d: d["lqr"]["state_max"].__setitem__("psi_deg", 5e-324), r"lqr\.state_max\.psi_deg: got 5e-324"),
    (lambda d: d["measurements"][0].__setitem__("variance", 1e-310), r"measurements\[0\]\.variance: got 1e-310"),
])
def test_values_that_underflow_in_the_design_are_refused_by_the_loader(edit, key):
    """Found by the HMI's fuzzing (issue 28): a Bryson maximum of 5e-324 deg is 0 rad (a NaN weight,
    no problem reported), a measurement variance of 1e-310 passed the loader and overflowed the
    design's Riccati step."""
    from rovlab.params.design import resolve_config_path

    d = read_toml(resolve_config_path("thesis"))
    edit(d)
    with pytest.raises(ConfigError, match=key):
        design_config_from_dict(d, file="thesis.toml")
