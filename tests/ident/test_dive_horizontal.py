"""Surge and sway from dives (issue 29): the planner's horizontal segments and box guard, the
virtual dive's DVL / positioning system, and ``rovlab identify dive`` on surge and sway.

Truths come from the virtual lab (rovlab.ident.dive.hidden_vehicle: the packaged
bluerov2_heavy_dvl with its surge and sway added mass and damping changed by up to 25 %, and the
linear sway damping vB22 leaves at 0 set to 20 % of the quadratic one at 1 m/s first), so every
number checked here is one the test itself made. The 5-minute, many-seed numbers are in
docs/identification.md ("Surge and sway"); the slow test below repeats them.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from rovlab.ident import dive, plan
from rovlab.ident.fitting import IdentificationError
from rovlab.interfaces.cli import main
from rovlab.params import load_vehicle
from rovlab.params.vehicle import packaged_vehicle_path

HORIZ = ("X_udot", "X_u", "X_|u|u", "Y_vdot", "Y_v", "Y_|v|v")


@pytest.fixture(scope="module")
def dvl():
    return load_vehicle("bluerov2_heavy_dvl")


@pytest.fixture(scope="module")
def usbl(tmp_path_factory):
    """bluerov2_heavy with a positioning system (x, y at 4 Hz, 5 cm: a USBL-like fix in a pool) and
    no DVL."""
    path = tmp_path_factory.mktemp("usbl") / "heavy_usbl.toml"
    path.write_text(packaged_vehicle_path("bluerov2_heavy").read_text(encoding="utf-8") + """
[[sensors]]
name = "usbl"
kind = "motion_capture"
source = "test: a USBL-like positioning system, 5 cm at 4 Hz (assumed)"
position = [0.0, 0.0, 0.0]
rate_hz = 4.0
variance = { x = 2.5e-3, y = 2.5e-3 }
""", encoding="utf-8")
    return load_vehicle(path)


@pytest.fixture(scope="module")
def short_plan(dvl):
    return plan.plan_dive(dvl, ("heave", "yaw", "surge", "sway"), 150.0, seed=2)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_plan_time_shares_yaw_and_surge_sway_within_limits_and_keeps_heave(dvl, short_plan):
    p = short_plan
    assert p.horizontal and p.X is not None and p.Y is not None and p.hold is not None
    cap = plan.dof_capacity(dvl)
    for arr, dof in ((p.X, "surge"), (p.Y, "sway")):
        assert np.max(np.abs(arr)) <= 0.8 * min(-cap[dof][0], cap[dof][1]) + 1e-9
        assert len(set(np.round(np.abs(arr[arr != 0]), 6))) > 10  # many levels
    t = p.dt * np.arange(len(p.Z))
    rest = (t % 45.0) >= 40.0
    assert np.all(p.X[rest] == 0) and np.all(p.Y[rest] == 0)
    # the yaw excitation is off while the heading law holds, and surge / sway only then
    assert np.all(p.N[p.hold] == 0) and np.any(p.N[~p.hold] != 0)
    assert np.all(p.X[~p.hold] == 0) and np.any(p.X[p.hold] != 0)
    # heave's sequence is the one a heave and yaw plan of the same seed has
    assert np.array_equal(p.Z, plan.plan_dive(dvl, ("heave", "yaw"), 150.0, seed=2).Z)
    flight = dive.fly_plan(p, dvl, dvl, noise=False)  # the vehicle file's own model
    xy = flight.states[:, 1:3]
    assert np.max(np.abs(xy - xy[0])) < 0.5 * p.box_m
    assert p.depth_min <= flight.depth_range[0] and flight.depth_range[1] <= p.depth_max
    # the weak heading law holds the heading within a few degrees over a held period (measured 6.6 deg
    # peak to peak in the first: the Munk moment (X_udot - Y_vdot) u v and the thrusters' PWM steps
    # against 0.59 N m/rad), where a yaw period turns the vehicle by tens of degrees
    psi, ts = flight.states[:, 4], flight.states[:, 0]
    first = (ts >= 46.0) & (ts < 85.0)
    assert np.all(p.hold[450:850]) and np.ptp(psi[first]) < math.radians(10.0)
    assert np.ptp(psi[(ts >= 1.0) & (ts < 40.0)]) > math.radians(30.0)


def test_a_vehicle_without_position_or_velocity_gets_no_surge_sway_plan(capsys, tmp_path):
    heavy = load_vehicle("bluerov2_heavy")
    with pytest.raises(ValueError, match="bluerov2_heavy: surge and sway need"):
        plan.plan_dive(heavy, ("heave", "surge"), 60.0)
    code, out, err = run(capsys, "lab", "plan-dive", "--vehicle", "bluerov2_heavy", "--dofs", "surge,sway",
                         "--out", tmp_path / "p.toml")
    assert code == 2 and "kind dvl" in err and "motion_capture" in err and "Traceback" not in err


def test_the_box_guard_pauses_the_excitation_and_pulls_the_vehicle_back(dvl, short_plan):
    p = short_plan
    assert p.X is not None and p.hold is not None
    k = int(np.flatnonzero((p.X != 0) & p.hold)[0])
    mid = 0.5 * (p.depth_min + p.depth_max)
    fly = p.flyer()
    tau, guarded = fly.step(k, mid, heading=0.0, rate=0.0, position=(10.0, -3.0))  # the start: the box's centre
    assert not guarded and tau[0] == pytest.approx(p.X[k])
    # 0.6 box north of the start, heading east: excitation paused, 4 x the position law, pointing south
    # (the body's y axis, starboard of east)
    out = 10.0 + 0.6 * p.box_m
    tau, guarded = fly.step(k, mid, heading=math.pi / 2, rate=0.0, position=(out, -3.0))
    assert guarded and tau[0] == pytest.approx(0.0, abs=1e-9)
    assert tau[1] == pytest.approx(4 * p.position_gain * 0.6 * p.box_m)
    tau, guarded = fly.step(k, mid, heading=math.pi / 2, rate=0.0, position=(10.0 + 0.3 * p.box_m, -3.0))
    assert guarded  # not yet back in the middle half
    tau, guarded = fly.step(k, mid, heading=0.0, rate=0.0, position=(10.0 + 0.2 * p.box_m, -3.0))
    assert not guarded and tau[0] == pytest.approx(p.X[k] - p.position_gain * 0.2 * p.box_m)
    with pytest.raises(ValueError, match="heading and position"):
        p.flyer().step(k, mid)


def test_the_horizontal_model_is_rovlabs_process_model_without_noise(dvl, short_plan):
    """Noise-free dive of a hidden vehicle: the surge / sway fit lands on the truth within 1 % (the
    model and rovlab.models.kinetics agree, Coriolis coupling included)."""
    truth = dive.hidden_vehicle(dvl, 11)
    flight = dive.fly_plan(short_plan, dvl, truth, seed=0, noise=False)
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, dvl), dvl, dofs=("surge", "sway"))
    for dof in ("surge", "sway"):
        for prm in fit.fits[dof].params:
            if prm.key != "thrust_scale":
                assert prm.status == "estimated", (prm.name, prm.note)
                assert prm.estimate == pytest.approx(flight.truth[prm.name], rel=1e-2), prm.name


@pytest.mark.parametrize("seed", [1, 3])
def test_a_short_dvl_dive_recovers_surge_and_sway_within_their_sigmas(dvl, short_plan, seed):
    """A 150 s plan (105 s identified, half of it surge / sway periods, 7 windows). Over seeds 1-8
    the worst z-score was X_udot's 4.5 sigma at seed 2 (3.1 % off; seed 6: 2.4 sigma): few windows
    make the clustered sigma rough, so the honesty claim is the 5-minute slow test's."""
    truth = dive.hidden_vehicle(dvl, 100 + seed)
    flight = dive.fly_plan(short_plan, dvl, truth, seed=seed)
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, dvl), dvl)
    assert set(fit.fits) == {"heave", "yaw", "surge", "sway"}  # surge and sway by default: the log has a DVL
    for dof in ("surge", "sway"):
        for prm in fit.fits[dof].params:
            if prm.key == "thrust_scale":
                continue
            assert prm.status == "estimated", (prm.name, prm.note)
            true = flight.truth[prm.name]
            assert abs(prm.estimate - true) <= 3.0 * prm.sigma, (prm.name, prm.estimate, true, prm.sigma)
            assert abs(prm.estimate / true - 1) < (0.15 if prm.key == "added_mass" else 0.10), prm.name
    for out in ("u_mps", "v_mps"):
        rows = fit.prediction[out]
        assert rows["identified"][-1] < rows["file"][-1], out


def test_the_yaw_fit_takes_the_munk_moment_where_the_log_has_surge_and_sway_velocity(dvl, short_plan):
    """Surge and sway motion turns the vehicle: -(X_udot - Y_vdot) u v in yaw. On the same dive
    (seed 2 of the short plan), yaw from the log with its DVL columns (the Munk moment a known
    input) lands within 5 % and 3 sigma; with the DVL columns dropped it cannot, and N_r is off by
    35 % (measured)."""
    truth = dive.hidden_vehicle(dvl, 102)
    flight = dive.fly_plan(short_plan, dvl, truth, seed=2)
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, dvl), dvl, dofs=("yaw",))
    assert any("Munk moment" in n for n in fit.notes)
    for prm in fit.fits["yaw"].params:
        if prm.status == "estimated":
            true = flight.truth[prm.name]
            assert abs(prm.estimate / true - 1) < 0.05 and abs(prm.estimate - true) <= 3 * prm.sigma, prm.name
    blind = {k: c for k, c in flight.columns.items() if k not in ("u_dvl", "v_dvl")}
    fit = dive.identify_dive(dive.dive_from_columns(blind, dvl), dvl, dofs=("yaw",))
    assert abs(fit.fits["yaw"].param("linear").estimate / flight.truth["N_r"] - 1) > 0.15


def test_a_dvl_log_without_heading_still_gives_heave(dvl):
    """Heave and yaw asked for, the log with a DVL but no heading: the surge/sway fit behind the Munk
    moment cannot run (it needs the heading), and must not stop heave (it raised)."""
    p = plan.plan_dive(dvl, ("heave", "yaw", "surge", "sway"), 90.0, seed=1)
    flight = dive.fly_plan(p, dvl, dvl, seed=1)
    cols = {k: c for k, c in flight.columns.items() if k != "psi_imu"}
    fit = dive.identify_dive(dive.dive_from_columns(cols, dvl), dvl, dofs=("heave", "yaw"))
    assert not fit.fits["heave"].refused_dof and fit.fits["yaw"].refused_dof
    with pytest.raises(IdentificationError, match="heading"):  # asked for: said why not
        dive.identify_dive(dive.dive_from_columns(cols, dvl), dvl, dofs=("surge",))


def test_a_position_only_dive_identifies_surge_and_sway(usbl):
    p = plan.plan_dive(usbl, ("heave", "yaw", "surge", "sway"), 300.0, seed=1)
    truth = dive.hidden_vehicle(usbl, 5)
    flight = dive.fly_plan(p, usbl, truth, seed=5)
    assert "x_usbl" in flight.columns and "u_dvl" not in flight.columns
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, usbl), usbl, dofs=("surge", "sway"))
    for dof in ("surge", "sway"):
        for prm in fit.fits[dof].params:
            if prm.status == "estimated":
                true = flight.truth[prm.name]
                assert abs(prm.estimate - true) <= 3.0 * prm.sigma, (prm.name, prm.estimate, true, prm.sigma)
    assert fit.fits["surge"].param("quadratic").status == "estimated"
    rows = fit.prediction["position_m"]
    assert rows["identified"][-1] < rows["file"][-1]


def test_a_log_without_position_or_velocity_refuses_surge_and_sway(capsys, tmp_path):
    heavy = load_vehicle("bluerov2_heavy")
    p = plan.plan_dive(heavy, ("heave", "yaw"), 60.0, seed=1)
    flight = dive.fly_plan(p, heavy, heavy, seed=1)
    data = dive.dive_from_columns(flight.columns, heavy)
    assert not dive.has_horizontal(data) and dive.default_dofs(data) == ("heave", "yaw")
    with pytest.raises(IdentificationError, match="surge and sway need position or velocity"):
        dive.identify_dive(data, heavy, dofs=("heave", "surge"))
    from rovlab.io.logwriter import write_csv

    log = tmp_path / "d.csv"
    write_csv(log, flight.columns)
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--dofs", "surge,sway")
    assert code == 2 and "declares no position sensor" in err and "Traceback" not in err
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--no-plot", "--json")
    assert code == 0 and "surge" not in json.loads(out)


def test_a_dof_the_dive_does_not_move_is_refused_naming_the_manoeuvre(dvl):
    p = plan.plan_dive(dvl, ("heave", "yaw"), 90.0, seed=1)
    flight = dive.fly_plan(p, dvl, dvl, seed=1)
    data = dive.dive_from_columns(flight.columns, dvl)
    assert dive.has_horizontal(data)  # a DVL, but no surge / sway excitation
    fit = dive.identify_dive(data, dvl, dofs=("surge", "sway"))
    for dof in ("surge", "sway"):
        assert fit.fits[dof].refused_dof and f"plan-dive --dofs {dof}" in fit.fits[dof].refused_dof
    assert dive.dive_edits(fit, dvl) == {}


def test_a_pilots_dive_gives_surge_and_refuses_the_sway_it_barely_moves(dvl):
    """A pilot's dive (rovlab.ident.pilot, forward runs and turns) with a DVL: surge is excited
    (over 20 dives X_|u|u within 4 %, X_udot within 3.8 %); sway moves at 0.3-1.5 cm/s RMS, mostly
    the drift of turns made while moving forward, and is refused (it was up to 23 % off with
    sigmas that covered the truth in 58 % of the dives) though fitted alongside surge."""
    from rovlab.ident.pilot import pilot_dive

    truth = dive.hidden_vehicle(dvl, 1000)
    flight = dive.fly_plan(pilot_dive(dvl, 300.0, seed=0), dvl, truth, seed=0)
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, dvl), dvl, dofs=("surge", "sway"))
    sway = fit.fits["sway"]
    assert sway.refused_dof and "RMS" in sway.refused_dof and "plan-dive --dofs sway" in sway.refused_dof
    assert all(p.status == "refused" for p in sway.params)
    q = fit.fits["surge"].param("quadratic")
    assert q.status == "estimated" and abs(q.estimate / flight.truth["X_|u|u"] - 1) < 0.10
    assert not any(k.startswith(("added_mass.Y", "damping.sway")) for k in dive.dive_edits(fit, dvl))


def test_cli_plan_fly_identify_update_surge_and_sway(capsys, tmp_path):
    planned = tmp_path / "plan.toml"
    code, out, err = run(capsys, "lab", "plan-dive", "--vehicle", "bluerov2_heavy_dvl", "--dofs",
                         "heave,yaw,surge,sway", "--duration", 150, "--box-m", 8, "--seed", 3, "--out", planned)
    assert code == 0, err
    assert "X_|u|u" in out and "Y_vdot" in out and "box 8 m" in out
    p = plan.read_plan(planned)
    assert p.box_m == 8.0 and p.hold is not None and p.X is not None and np.any(p.X != 0)
    log = tmp_path / "dive.csv"
    code, out, err = run(capsys, "lab", "dive", "--plan", planned, "--vehicle", "bluerov2_heavy_dvl", "--seed", 4,
                         "--out", log, "--json")
    assert code == 0, err
    truth = json.loads(out)["written"][0]["truth"]
    target = tmp_path / "mine.toml"
    target.write_text(packaged_vehicle_path("bluerov2_heavy_dvl").read_text(encoding="utf-8"), encoding="utf-8")
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy_dvl", "--update", target,
                         "--json", "--no-plot")
    assert code == 0, err
    res = json.loads(out)
    x = res["surge"]["parameters"]["X_|u|u"]
    assert x["status"] == "estimated" and abs(x["estimate"] - truth["X_|u|u"]) < 3 * x["sigma"]
    assert "u_mps" in res["prediction_rmse"] and "v_mps" in res["prediction_rmse"]
    # the published set (Wu 2018, bluerov2_heavy_dvl's default) is scored in surge and sway too (it was NaN)
    for lab in ("u_mps", "v_mps"):
        rows = res["prediction_rmse"][lab]
        assert all(math.isfinite(x) and x > 0 for x in rows["published"]), rows
        assert rows["identified"][-1] < rows["published"][-1], rows  # 100 steps: its 4x smaller damping shows
    v = load_vehicle(target)
    assert v.damping_quadratic[0] == pytest.approx(x["estimate"], rel=1e-3)
    assert v.added_mass[1] == pytest.approx(res["sway"]["parameters"]["Y_vdot"]["estimate"], rel=1e-3)
    assert "Y_|v|v sigma" in target.read_text(encoding="utf-8")
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy_dvl", "--no-plot")
    assert code == 0 and "u [m/s]" in out and "X_udot" in out


def test_a_plan_file_with_a_bad_hold_flag_is_refused(capsys, tmp_path, dvl):
    p = plan.plan_dive(dvl, ("surge", "sway"), 60.0, seed=1)
    path = plan.write_plan(tmp_path / "p.toml", p)
    back = plan.read_plan(path)
    assert back.X == pytest.approx(p.X) and np.array_equal(back.hold, p.hold)
    text = path.read_text(encoding="utf-8")
    i = text.index("hold = [")
    path.write_text(text[:i] + "hold = [2" + text[i + len("hold = [1"):], encoding="utf-8")
    code, out, err = run(capsys, "lab", "dive", "--plan", path, "--vehicle", "bluerov2_heavy_dvl", "--seed", 1,
                         "--out", tmp_path / "d.csv")
    assert code == 2 and "excitation.hold" in err and "Traceback" not in err


@pytest.mark.slow
def test_surge_sway_sigmas_are_honest_over_many_seeds(dvl):
    """docs/identification.md, "Surge and sway": 30 dives of a 5-minute heave/yaw/surge/sway plan
    on bluerov2_heavy_dvl; the truth inside +-2 sigma in >= 90 % of the seeds for every surge /
    sway parameter, damping within 5 % and added mass within 10 % in every seed."""
    p = plan.plan_dive(dvl, ("heave", "yaw", "surge", "sway"), 300.0, seed=1)
    inside: dict[str, list[bool]] = {}
    for seed in range(30):
        truth = dive.hidden_vehicle(dvl, 1000 + seed)
        flight = dive.fly_plan(p, dvl, truth, seed=seed)
        fit = dive.identify_dive(dive.dive_from_columns(flight.columns, dvl), dvl, dofs=("surge", "sway"))
        for f in fit.fits.values():
            for prm in f.params:
                if prm.key == "thrust_scale":
                    continue
                assert prm.status == "estimated", (seed, prm.name, prm.note)
                true = flight.truth[prm.name]
                inside.setdefault(prm.name, []).append(abs(prm.estimate - true) <= 2 * prm.sigma)
                tol = 0.10 if prm.key == "added_mass" else 0.05
                assert abs(prm.estimate / true - 1) < tol, (seed, prm.name, prm.estimate, true)
    assert set(inside) == set(HORIZ)
    for name, hits in inside.items():
        assert np.mean(hits) >= 0.9, (name, np.mean(hits))


DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ardusub"


@pytest.mark.slow  # ~25 s: the refusals refit a log that determines nothing
@pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None or not (DATA / "small.tlog").is_file(),
                    reason="needs pymavlink and ../shared/data/ardusub/small.tlog")
def test_the_real_surface_log_gives_position_but_determines_no_surge_or_sway(tmp_path):
    """small.tlog (ArduSub 4.1, BlueROV2 Heavy at the surface) carries LOCAL_POSITION_NED: read as
    a position where the vehicle file declares one, and surge and sway are refused whole (one
    short forward command is no manoeuvre). (With the packaged file, which declares no such
    sensor, they are refused before any fit: test_a_log_without_position_or_velocity_...)"""
    from rovlab.interfaces.cli_ident import read_dive_log

    path = tmp_path / "heavy_pos.toml"
    path.write_text(packaged_vehicle_path("bluerov2_heavy").read_text(encoding="utf-8") + """
[[sensors]]
name = "ekf"
kind = "motion_capture"
source = "ArduSub's LOCAL_POSITION_NED; variance ASSUMED (0.1 m)^2"
position = [0.0, 0.0, 0.0]
rate_hz = 3.0
variance = { x = 1.0e-2, y = 1.0e-2 }
""", encoding="utf-8")
    vehicle = load_vehicle(path)
    data = read_dive_log(DATA / "small.tlog", vehicle)
    assert data.channel("north", "position") is not None and data.channel("north", "position").t.size > 500
    fit = dive.identify_dive(data, vehicle, dofs=("surge", "sway"))
    for dof in ("surge", "sway"):
        assert fit.fits[dof].refused_dof and f"plan-dive --dofs {dof}" in fit.fits[dof].refused_dof
