"""Dynamic positioning: the DP controller's parts (reference model, pole placement, bias
feed-forward, anti-windup, heading the short way), its configuration errors, and the EKF + DP
closed loop (NEES over 100 Monte Carlo runs with the model equal to the plant; station keeping;
the box; the motion-capture drop-out)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rovlab.control import dp
from rovlab.params.design import design_config_from_dict, load_design_config
from rovlab.params.validate import ConfigError, read_toml
from rovlab.params.vehicle import load_vehicle
from rovlab.sim.montecarlo import run_many, summarise_runs
from rovlab.sim.prepare import prepare
from rovlab.sim.results import summarise
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import load_scenario_data, resolve_scenario_path

SEED = 4242


@pytest.fixture(scope="module")
def udrone():
    return load_vehicle("udrone_dvl")


@pytest.fixture(scope="module")
def cfg():
    return load_design_config("udrone_dp")


def _fresh(udrone, cfg):
    return dp.build(udrone, cfg).kernel


# --------------------------------------------------------------------------------------------
# The controller's parts
# --------------------------------------------------------------------------------------------

def test_pole_placement_puts_each_axis_at_its_bandwidth(udrone, cfg):
    """K_p = M w^2, K_d = 2 zeta w M - D (Fossen 2011, sec. 12.2): the closed loop
    M s^2 + (D + K_d) s + K_p of each axis has its poles at -zeta w +- w sqrt(zeta^2 - 1)."""
    d = dp.design(udrone, cfg)
    for i, w in enumerate(cfg.table("dp").bandwidth):
        poles = np.roots([d.M[i], d.D[i] + d.Kd[i], d.Kp[i]])
        np.testing.assert_allclose(poles.real, -cfg.table("dp").damping * w, rtol=1e-6)
        assert d.Ki[i] == pytest.approx(cfg.table("dp").integral_ratio * w * d.Kp[i])


def test_reference_model_is_smooth_speed_limited_and_arrives():
    """Third-order reference model (Fossen 2011, sec. 10.2): a 2 m step becomes a trajectory whose
    speed never exceeds the limit, whose acceleration starts at zero and which settles on the
    set-point without overshoot (zeta = 1)."""
    eta, vel, acc = np.zeros(1), np.zeros(1), np.zeros(1)
    h, v_max = 0.1, 0.15
    path, speeds, accs = [], [], []
    for _ in range(600):
        dp.reference_model_step(eta, vel, acc, 2.0, 0.4, 1.0, v_max, h, 10)
        path.append(eta[0])
        speeds.append(vel[0])
        accs.append(acc[0])
    assert max(speeds) <= v_max + 1e-12
    assert abs(accs[0]) < 0.05  # the first sample: no acceleration step
    assert max(path) < 2.0 + 1e-3 and abs(path[-1] - 2.0) < 1e-3
    assert max(speeds) == pytest.approx(v_max)  # a 2 m step at 0.4 rad/s is speed limited


def test_bias_is_fed_forward_with_the_right_sign(udrone, cfg):
    """tau = ... - b_hat (the bias enters the model like a force; the thesis's eq. 5.29 adds + b_hat, an erratum)."""
    nav = np.zeros(12)
    nav[2] = 1.0
    ref = np.array([0.0, 0.0, 1.0, 0.0])
    a, b = _fresh(udrone, cfg), _fresh(udrone, cfg)
    ta, tb = np.empty(4), np.empty(4)
    dp._dp_step(a, 0.0, nav, ref, ta)
    nav_b = nav.copy()
    nav_b[8:] = [1.0, -2.0, -6.7, 0.05]
    dp._dp_step(b, 0.0, nav_b, ref, tb)
    np.testing.assert_allclose(tb - ta, -nav_b[8:], atol=1e-12)


def test_heading_error_takes_the_short_way(udrone, cfg):
    ctrl = _fresh(udrone, cfg)
    nav = np.zeros(12)
    nav[2] = 1.0
    nav[3] = math.radians(-179.0)
    tau = np.empty(4)
    for _ in range(30):  # let the reference model move toward +179 deg
        dp._dp_step(ctrl, 0.0, nav, np.array([0.0, 0.0, 1.0, math.radians(179.0)]), tau)
    # from -179 to +179 deg the short way is 2 deg clockwise-negative: a negative yaw moment,
    # and the reference model moved by about 2 deg, not 358
    assert tau[3] < 0.0
    assert abs(math.remainder(ctrl.state[3] - nav[3], 2 * math.pi)) <= math.radians(2.0) + 1e-9


def test_back_calculation_stops_integral_windup(udrone, cfg):
    """Astrom & Hagglund 2006, sec. 3.5: with the thrusters saturated (nothing achieved) and a
    persistent error the integral stays bounded with back-calculation and grows without it."""
    def integral_after(anti_windup):
        c = dp.build(udrone, cfg.with_table("dp", replace(cfg.table("dp"), anti_windup=anti_windup))).kernel
        # without the thrust-capacity clamp (tests/control/test_dp_integral_limit.py), which would stop
        # the plain integral at 145 m s: here the back-calculation alone
        c = c._replace(int_lo=np.full(4, -np.inf), int_hi=np.full(4, np.inf))
        nav = np.zeros(12)
        nav[2] = 1.0
        tau = np.empty(4)
        for k in range(3000):
            nav[0] = 3.0  # far off the set-point, and the thrusters give nothing
            dp._dp_step(c, k * 0.1, nav, np.array([0.0, 0.0, 1.0, 0.0]), tau)
            dp._dp_actuated(c, k * 0.1, tau.copy(), np.zeros(4))
        return abs(c.state[12])

    with_aw, without = integral_after(1.0), integral_after(0.0)
    # without: the integral of a 3 m error over 300 s; with: the equilibrium of
    # xi' = e - (k_t / K_i)(K_p e + K_i xi) = 0, |xi| = e (k_t K_p / K_i - 1) / k_t = 3 * 9 / 0.6 = 45
    assert without == pytest.approx(900.0, rel=0.05)  # less the reference model's first seconds
    assert with_aw == pytest.approx(3.0 * (10.0 - 1.0) / cfg.table("dp").bandwidth[0], rel=0.02)


def test_bad_dp_and_ekf_keys_are_refused_with_file_key_value(tmp_path):
    from rovlab.params.design import packaged_config_path

    data = read_toml(packaged_config_path("udrone_dp"))
    data["dp"]["bandwidth"]["x"] = -1.0
    data["dp"]["gain"] = 3.0
    data["ekf"]["dead_reckoning"] = ["q"]
    with pytest.raises(ConfigError) as err:
        design_config_from_dict(data, file="mine.toml")
    text = str(err.value)
    assert "mine.toml" in text and "dp.bandwidth.x" in text and "dp.gain" in text and "ekf.dead_reckoning" in text


def test_kf_cannot_drive_dp(udrone):
    from rovlab.sim.components import build_pair

    cfg = load_design_config("default")
    with pytest.raises(ConfigError, match="x, y"):
        build_pair(udrone, cfg, controller="dp")


# --------------------------------------------------------------------------------------------
# Closed loop
# --------------------------------------------------------------------------------------------

def _model_equals_plant(tmp_path, duration_s: float):
    """dp-station-keeping with the EKF's model equal to the plant: the EKF knows the current and its
    bias drivers are the truth's Gauss-Markov ones (PSD 2 sigma^2 / T); the heave bias's mean is the
    vehicle file's net weight W - B in both (rovlab.estimation.ekf, issue 28)."""
    data, file = load_scenario_data("dp-station-keeping")
    cfg = read_toml(resolve_design("udrone_dp"))
    cur = data["truth"]["current"]
    cfg["ekf"]["current"] = dict(cur)
    std = data["truth"]["bias_std"]
    T = data["truth"]["bias_time_constant_s"]
    cfg["ekf"]["bias_psd"] = {d: 2 * std[k] ** 2 / T[k] for d, k in zip("XYZN", ("surge", "sway", "heave", "yaw"))}
    cfg["ekf"]["bias_time_constant_s"] = {d: T[k] for d, k in zip("XYZN", ("surge", "sway", "heave", "yaw"))}
    psd = data["truth"]["process_noise_psd"]
    cfg["ekf"]["force_psd"] = {d: psd[k] for d, k in zip("XYZN", ("surge", "sway", "heave", "yaw"))}
    design = tmp_path / "model_equals_plant.toml"
    _write_toml(design, cfg)
    data = dict(data)
    data["design"] = str(design)
    data["duration_s"] = duration_s
    return data, file


def resolve_design(name):
    from rovlab.params.design import packaged_config_path

    return packaged_config_path(name)


def _write_toml(path, data):
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = []
    tables = []
    for k, v in data.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            tables.extend((f"[{k}]", item) for item in v)
        else:
            lines.append(f"{k} = {value(v)}")
    for k, v in tables:
        lines.append(f"\n[{k}]")
        lines.extend(f"{kk} = {value(vv)}" for kk, vv in v.items())
    path.write_text("\n".join(lines) + "\n")


def test_nees_over_100_runs_stays_in_its_chi_square_bounds(tmp_path):
    """Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4: with the model equal to the plant the average
    NEES of the 8 pose and velocity states over N = 100 runs lies in its 95 % chi-square interval
    [chi2(0.025, 800), chi2(0.975, 800)] / 100 at about 95 % of the steps (we require 90 %), and its
    time average inside its own interval."""
    data, file = _model_equals_plant(tmp_path, 60.0)
    runs = run_many(data, file, range(SEED, SEED + 100), workers=1)
    summary = summarise_runs(runs)
    nees = summary["nees"]
    assert nees["dof"] == 8 and nees["runs"] == 100
    assert nees["share_inside"] >= 0.90, nees
    assert 7.5 < nees["mean"] < 8.5, nees


def test_nees_test_can_fail(tmp_path):
    """The same check on a filter told the force noise is 100 times smaller than it is: the NEES
    leaves its bounds (so the test above can fail)."""
    data, file = _model_equals_plant(tmp_path, 30.0)
    design = read_toml(data["design"])
    design["ekf"]["force_psd"] = {k: v / 100.0 for k, v in design["ekf"]["force_psd"].items()}
    _write_toml(tmp_path / "overconfident.toml", design)
    data["design"] = str(tmp_path / "overconfident.toml")
    summary = summarise_runs(run_many(data, file, range(SEED, SEED + 20), workers=1))
    assert summary["nees"]["share_inside"] < 0.5


def _run(name, **changes):
    data, file = load_scenario_data(name)
    data = dict(data, **changes)
    return summarise(run_prepared(prepare(data, file=file)))


def test_station_keeping_holds_within_centimetres_and_a_degree():
    m = _run("dp-station-keeping")
    tr = m["tracking_rms"]
    assert tr["x"] < 0.03 and tr["y"] < 0.03 and tr["z"] < 0.03, tr
    assert tr["psi"] < math.radians(1.0), tr
    assert m["saturation"]["time_s"] == 0.0
    assert m["tracking_reference"]["x"] == "ctrl_x_d"


def test_square_tracks_the_box_and_turns():
    m = _run("dp-square")
    tr = m["tracking_rms"]
    assert tr["x"] < 0.1 and tr["y"] < 0.1 and tr["z"] < 0.03, tr
    assert tr["psi"] < math.radians(5.0), tr
    fin = m["setpoint_error_final"]
    assert abs(fin["x"]) < 0.05 and abs(fin["y"]) < 0.05 and abs(fin["psi"]) < math.radians(2.0)


def test_mocap_dropout_dead_reckons_with_bounded_drift():
    m = _run("dp-mocap-dropout")
    (d,) = m["position_dropouts"]
    assert d["sensor"] == "qualisys"
    assert d["horizontal_error_max_m"] < 0.15, d
    assert m["tracking_rms"]["x"] < 0.05 and m["tracking_rms"]["y"] < 0.05


def test_scenario_current_is_read_and_checked(tmp_path):
    from rovlab.sim.scenario import scenario_from_dict

    data, file = load_scenario_data("dp-station-keeping")
    sc = scenario_from_dict(data, file=file)
    np.testing.assert_allclose(np.hypot(*sc.current[:2]), 0.1, rtol=1e-5)
    bad = dict(data, truth=dict(data["truth"], current={"north": 50.0}))
    with pytest.raises(ConfigError, match="truth.current.north"):
        scenario_from_dict(bad, file=str(resolve_scenario_path("dp-station-keeping")))


def test_bluerov2_heavy_dp_designs_on_stock_sensors_and_runs():
    """The BlueROV2 Heavy's packaged DP design (pressure + IMU, no motion capture, no DVL) designs
    with x, y, u, v and the horizontal biases dead-reckoned, and runs: depth and heading are held on
    measurements."""
    from rovlab.sim.components import build_pair

    vehicle = load_vehicle("bluerov2_heavy")
    cfg = load_design_config("bluerov2_heavy_dp")
    est, ctl = build_pair(vehicle, cfg)
    assert set(est.model.dead_reckoned) == {"x", "y", "u", "v", "b_X", "b_Y"}
    # the packaged scenario has the DVL now (tests/sim/test_bluerov2_heavy_dvl.py): run it on the stock sensors
    m = _run("bluerov2-heavy-dp", vehicle="bluerov2_heavy", design="bluerov2_heavy_dp", dropout=[])
    assert m["tracking_rms"]["z"] < 0.1 and m["tracking_rms"]["psi"] < math.radians(3.0), m["tracking_rms"]
    assert abs(m["setpoint_error_final"]["z"]) < 0.05
    # without dead_reckoning the same sensors are refused, naming the horizontal states
    with pytest.raises(ConfigError, match="x, y"):
        build_pair(vehicle, cfg.with_table("ekf", replace(cfg.table("ekf"), dead_reckoning=())))
