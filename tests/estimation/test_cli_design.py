"""Command-line contract of issue 3: ``rovlab design`` and ``rovlab filter``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rovlab.interfaces.cli import main
from rovlab.io.logreader import read_log
from rovlab.io.logwriter import write_csv
from rovlab.params.design import packaged_config_path


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_design_json_contract(capsys):
    code, out, _ = run(capsys, "design", "--config", "thesis", "--json")
    assert code == 0
    data = json.loads(out)
    assert {"Phi", "Delta", "Gamma", "Q", "H", "R", "K", "P", "observable"} <= set(data)
    assert data["observable"] is True
    assert np.array(data["Phi"]).shape == (6, 6) and np.array(data["Delta"]).shape == (6, 2)
    assert np.array(data["H"]).shape == (3, 6) and np.array(data["R"]).shape == (3, 3)
    np.testing.assert_allclose(data["K"], [[17.7318, 0, 54.0771, 0], [0, 0.148116, 0, 2.41781]], rtol=5e-6)
    assert data["Q"][4][4] == pytest.approx(0.02, abs=5e-3)  # thesis eq. 5.31


def test_design_default_and_human_output(capsys):
    code, out, _ = run(capsys, "design")
    assert code == 0 and "observable: yes" in out and "K (LQR)" in out and "pressure.z" in out


def test_design_refuses_an_unobservable_sensor_set(capsys, tmp_path):
    text = packaged_config_path("thesis").read_text()
    head = text[: text.index("[[measurements]]")]
    cfg = tmp_path / "pressure_only.toml"
    cfg.write_text(head + '[[measurements]]\nsensor = "pressure"\nquantity = "z"\n\n'
                   + text[text.index("[lqr]"):])
    code, _, err = run(capsys, "design", "--config", str(cfg), "--json")
    assert code == 2 and "Traceback" not in err
    assert "psi, r, b_r" in err
    code, out, _ = run(capsys, "design", "--config", str(cfg), "--json", "--allow-unobservable")
    data = json.loads(out)
    assert code == 0 and data["observable"] is False and data["unobservable"] == ["psi", "r", "b_r"]


def _log(n=300, h=0.1, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * h
    z = 1.0 + 0.2 * np.sin(2 * np.pi * t / 20.0)
    psi = np.radians(30.0) + 0.1 * np.sin(2 * np.pi * t / 25.0)
    cols = {
        "time_s": t,
        "tau_Z": np.zeros(n),
        "tau_N": np.zeros(n),
        "z_qualisys": z + 4e-5 * rng.standard_normal(n),
        "z_pressure": z - 0.0465 + 0.011 * rng.standard_normal(n),
        "psi_qualisys": psi + 1e-3 * rng.standard_normal(n),
    }
    cols["z_qualisys"][100:150] = np.nan  # Qualisys drop-out
    cols["psi_qualisys"][100:150] = np.nan
    return cols


def test_filter_a_log(capsys, tmp_path):
    log_path = tmp_path / "log.csv"
    write_csv(log_path, _log())
    out_path = tmp_path / "est.csv"
    code, out, err = run(capsys, "filter", str(log_path), "--out", str(out_path))
    assert code == 0, err
    assert "300 samples" in out and "qualisys.z" in out
    est = read_log(out_path)
    states = ("z", "psi", "w", "r", "b_w", "b_r")
    for col in [f"est_{s}" for s in states] + [f"var_{s}" for s in states]:
        assert col in est.data and np.all(np.isfinite(est[col])), col
    status = est.text["status_z_qualisys"]
    assert status[50] == "ok" and status[140] == "lost-timeout" and status[152] == "recovering"
    assert set(est.text["status_z_pressure"]) == {"ok"}
    truth = 1.0 + 0.2 * np.sin(2 * np.pi * est.time / 20.0)
    assert np.max(np.abs(est["est_z"][50:] - truth[50:])) < 0.03
    assert abs(math.degrees(est["est_psi"][-1]) - 30.0 - math.degrees(0.1 * np.sin(2 * np.pi * 29.9 / 25.0))) < 1.0


def test_filter_to_stdout_and_with_a_gap(capsys, tmp_path):
    cols = _log(n=60)
    keep = np.ones(60, dtype=bool)
    keep[30] = False
    log_path = tmp_path / "gap.csv"
    write_csv(log_path, {k: v[keep] for k, v in cols.items()})
    code, out, err = run(capsys, "filter", str(log_path), "--out", "-")
    # plain CSV: the header is the first line (no comment lines; the metadata goes to a sidecar)
    assert code == 0 and out.splitlines()[0].startswith("time_s,est_z,est_psi") and "bridged" in err


@pytest.mark.parametrize("body, needle", [
    ("time_s,tau_Z,tau_N,z_qualisys,z_pressure\n0,0,0,1,1\n", "missing: psi_qualisys"),
    ("time_s,tau_Z,tau_N,z_qualisys,z_pressure,psi_qualisys\n0,0,0,1,1,0\n0.1,0,zero,1,1,0\n",
     "line 3, column 'tau_N'"),
    ("time_s,tau_Z,tau_N,z_qualisys,z_pressure,psi_qualisys\n0,0,0,1,1,0\n0.1,0,0,1,1,0\n0.1,0,0,1,1,0\n",
     "line 4, column 'time_s'"),
])
def test_filter_malformed_logs_are_clean_errors(capsys, tmp_path, body, needle):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    code, _, err = run(capsys, "filter", str(path), "--out", str(tmp_path / "est.csv"))
    assert code == 2 and "Traceback" not in err and needle in err, err
    assert not (tmp_path / "est.csv").exists()


def test_filter_unwritable_output_is_a_clean_error(capsys, tmp_path):
    log_path = tmp_path / "log.csv"
    write_csv(log_path, _log(n=20))
    code, _, err = run(capsys, "filter", str(log_path), "--out", str(tmp_path / "no" / "such" / "est.csv"))
    assert code == 2 and "cannot write" in err


def test_design_with_impossible_lqr_weights_is_a_clean_error(capsys, tmp_path):
    text = packaged_config_path("default").read_text()
    cfg = tmp_path / "zero.toml"
    cfg.write_text(text.replace("input_weight = { Z = 0.1, N = 0.01 }",
                                "input_weight = { Z = 0.1, N = 0.01 }\nstate_weight = { z = 0, psi = 0 }"))
    code, _, err = run(capsys, "design", "--config", str(cfg))
    assert code == 2 and "Traceback" not in err and "zero.toml: lqr" in err


def test_filter_reports_faulty_samples(capsys, tmp_path):
    cols = _log(n=60)
    cols["z_pressure"][20] = np.inf  # a faulty sample (not a missing one)
    log_path = tmp_path / "faulty.csv"
    write_csv(log_path, cols)
    code, out, err = run(capsys, "filter", str(log_path), "--out", str(tmp_path / "est.csv"))
    assert code == 0, err
    assert "pressure.z       60 samples, 59 used, 0 rejected by the gate, 1 not finite" in out
    est = read_log(tmp_path / "est.csv")
    assert est.text["status_z_pressure"][20] == "lost-nonfinite"
    assert np.all(np.isfinite(est["est_z"]))


def test_filter_keeps_epoch_time_stamps(capsys, tmp_path):
    cols = _log(n=30)
    cols["time_s"] = 1.7e9 + cols["time_s"]  # a ROS-style log stamped with Unix time
    write_csv(tmp_path / "epoch.csv", cols)
    code, _, err = run(capsys, "filter", str(tmp_path / "epoch.csv"), "--out", str(tmp_path / "est.csv"))
    assert code == 0, err
    est = read_log(tmp_path / "est.csv")  # strictly increasing times, or this read would fail
    np.testing.assert_array_equal(est.time, cols["time_s"])


def test_design_text_names_the_bias_time_constants_and_prints_gamma_and_h(capsys):
    # issue 15 item 6: T_w, T_r are the bias model's, not the vehicle's; Gamma and H were missing
    code, out, _ = run(capsys, "design", "--config", "thesis")
    assert code == 0
    assert "bias model (Gauss-Markov): time constants T_w = 1844 s (b_w), T_r = 26 s (b_r)" in out
    assert "heave M_w/-Z_w = 3.55985 s" in out and "yaw M_r/-N_r = 3.90625 s" in out
    for name in ("Phi", "Delta", "Gamma", "Q", "H", "R"):
        assert f"  {name} =\n" in out, name
    assert "deg" not in out and "psi [rad]" in out and "rad^2" in out
    h = out.split("  H =\n")[1].splitlines()[:3]
    assert h == ["    [ 1   0   0   0   0   0]", "    [ 1   0   0   0   0   0]", "    [ 0   1   0   0   0   0]"]


def test_design_of_the_ekf_and_dp_is_their_own_summary(capsys):
    """`rovlab design` works from the components' declarations: with estimator ekf and controller dp
    it shows the EKF's noise model and the DP gains, which follow Fossen (2011, sec. 12.2)'s pole
    placement K_p = M omega_n^2, K_i = ratio omega_n K_p."""
    from rovlab.params.design import load_design_config

    code, out, _ = run(capsys, "design", "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy_dp", "--json")
    assert code == 0
    info = json.loads(out)
    assert info["estimator"] == "ekf" and info["controller"] == "dp"
    assert info["states"][:4] == ["x", "y", "z", "psi"] and "force_psd" in info["ekf"]
    dp = load_design_config("bluerov2_heavy_dp").table("dp")
    g = info["dp"]
    for i, axis in enumerate(g["axes"]):
        wn = dp.bandwidth[i]
        assert g["Kp"][i] == pytest.approx(g["M"][i] * wn ** 2, rel=1e-12), axis
        assert g["Ki"][i] == pytest.approx(dp.integral_ratio * wn * g["Kp"][i], rel=1e-12), axis
    code, out, _ = run(capsys, "design", "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy_dp")
    assert code == 0 and "controller dp:" in out and "Kp = [" in out and "force_psd: X" in out
