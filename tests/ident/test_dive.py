"""Identification from dives (issue 29): the planner, the virtual dive and ``rovlab identify dive``.

Truths come from the virtual lab (rovlab.ident.dive.hidden_vehicle: the packaged bluerov2_heavy
with its heave and yaw added mass and damping changed by up to 25 % and its net buoyancy by up to
2 N), so every number checked here is one the test itself made; the tolerances are issue 29's
(damping 5 %, added mass 10 %) in the slow 50-dive check, twice those on the short plans of the
quick tests.
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

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ardusub"
TLOG = DATA / "small.tlog"


@pytest.fixture(scope="module")
def heavy():
    return load_vehicle("bluerov2_heavy")


@pytest.fixture(scope="module")
def short_plan(heavy):
    return plan.plan_dive(heavy, ("heave", "yaw"), 150.0, seed=2)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def _fit(vehicle, truth, p, seed, *, noise=True, **kw):
    flight = dive.fly_plan(p, vehicle, truth, seed=seed, noise=noise)
    return flight, dive.identify_dive(dive.dive_from_columns(flight.columns, vehicle), vehicle, **kw)


def test_the_plan_keeps_within_the_thrust_limits_the_band_and_rests(heavy, short_plan):
    p = short_plan
    cap = plan.dof_capacity(heavy)
    # bluerov2_heavy's four vertical T200s at 16 V: ~4 x 40 N down, ~4 x 51 N up (the table's asymmetry)
    assert 140 < cap["heave"][1] < 180 and -230 < cap["heave"][0] < -180
    assert np.max(np.abs(p.Z)) <= 0.8 * min(-cap["heave"][0], cap["heave"][1]) + 1e-9
    assert np.max(np.abs(p.N)) <= 0.8 * cap["yaw"][1] + 1e-9
    t = p.dt * np.arange(len(p.Z))
    rest = (t % 45.0) >= 40.0  # 5 s rests every 40 s
    assert np.all(p.Z[rest] == 0) and np.all(p.N[rest] == 0) and np.any(p.Z[~rest] != 0)
    assert len(set(np.round(np.abs(p.Z[p.Z != 0]), 6))) > 10  # many levels: linear and quadratic apart
    flight = dive.fly_plan(p, heavy, heavy, noise=False)  # the vehicle file's own model
    assert flight.guard_s == 0.0
    assert p.depth_min <= flight.depth_range[0] and flight.depth_range[1] <= p.depth_max


def test_a_plan_that_would_breach_the_surface_or_has_no_dof_is_refused(heavy):
    with pytest.raises(ValueError, match="submerged"):
        plan.plan_dive(heavy, ("heave",), 60.0, depth_min=0.1, depth_max=2.0)
    with pytest.raises(ValueError, match="surge and sway"):
        plan.plan_dive(heavy, ("surge",), 60.0)


def test_the_model_is_rovlabs_process_model_without_noise(heavy):
    """Noise-free dive of a hidden vehicle: the output-error fit lands on the truth within 1 % (the
    dive model and rovlab.models.kinetics agree; what differs: the 0.05 s grid against the plant's
    0.01 s, and the small surge and sway the 4-DOF plant has from 1 us PWM steps; measured 0.4 %)."""
    truth = dive.hidden_vehicle(heavy, 11)
    p = plan.plan_dive(heavy, ("heave", "yaw"), 120.0, seed=4)
    flight, fit = _fit(heavy, truth, p, 0, noise=False)
    for f in fit.fits.values():
        for prm in f.params:
            if prm.status == "estimated":
                assert prm.estimate == pytest.approx(flight.truth[prm.name], rel=1e-2, abs=1e-4), prm.name


@pytest.mark.parametrize("seed", [1, 2])
def test_a_short_planned_dive_recovers_the_hidden_vehicle_within_its_sigmas(heavy, short_plan, seed):
    truth = dive.hidden_vehicle(heavy, 100 + seed)
    flight, fit = _fit(heavy, truth, short_plan, seed)
    for f in fit.fits.values():
        assert not f.refused_dof
        for prm in f.params:
            if prm.status == "held":
                continue
            assert prm.status == "estimated", (prm.name, prm.note)
            true = flight.truth[prm.name]
            assert abs(prm.estimate - true) <= 3.0 * prm.sigma, (prm.name, prm.estimate, true, prm.sigma)
            # issue 29's 5 % damping / 10 % added mass are for a 5-minute plan (the slow test); this one
            # is half as long, its sigmas ~1.4 times wider (Z_w: 0.86 against 0.57 N s/m)
            tol = 0.15 if prm.key == "added_mass" else 0.10
            if prm.key != "net_buoyancy":
                assert abs(prm.estimate / true - 1) < tol, (prm.name, prm.estimate, true)
    # the identified model predicts the validation segment better than the vehicle file it started from
    for rows in fit.prediction.values():
        assert rows["identified"][-1] < rows["file"][-1]


def test_expected_sigmas_are_those_of_the_fit_in_size(heavy, short_plan):
    """The planner's Cramér-Rao sigmas and the sigmas the fit reports on a dive of the same plan
    agree within a factor of 3 for the heave parameters (the fit's include the process noise)."""
    expected = {e.name: e.sigma for e in plan.expected_sigmas(heavy, short_plan)}
    _, fit = _fit(heavy, heavy, short_plan, 5)
    for prm in fit.fits["heave"].params:
        if prm.status == "estimated":
            assert expected[prm.name] / 3 < prm.sigma < 3 * expected[prm.name], prm.name


def test_a_dof_the_log_does_not_excite_is_refused_with_the_manoeuvre_that_would(heavy):
    p = plan.plan_dive(heavy, ("yaw",), 90.0, seed=1)
    _, fit = _fit(heavy, heavy, p, 1)
    heave = fit.fits["heave"]
    assert heave.refused_dof and "plan-dive --dofs heave" in heave.refused_dof
    assert all(prm.status == "refused" for prm in heave.params)
    assert "depth_m" not in fit.prediction
    assert not any(k.startswith(("added_mass.Z", "damping.heave", "restoring")) for k in dive.dive_edits(fit, heavy))
    assert fit.fits["yaw"].param("quadratic").status == "estimated"


def test_added_mass_and_thrust_scale_are_not_both_estimated(heavy, short_plan):
    flight = dive.fly_plan(short_plan, heavy, heavy, seed=0)
    data = dive.dive_from_columns(flight.columns, heavy)
    with pytest.raises(IdentificationError, match="force / mass"):
        dive.identify_dive(data, heavy, free=("added_mass", "thrust_scale"))
    # the thrust scale with the added mass held. A vehicle whose heave mass, damping and net buoyancy
    # are all 1/0.85 of the file's moves exactly as the file's would with a thrust 0.85 of the curves'
    # (the equations divided by 1/0.85): the fit, holding the file's added mass, finds s_Z = 0.85
    c = 1 / 0.85
    am, lin, quad = (np.array(a, dtype=float) for a in (heavy.added_mass, heavy.damping_linear,
                                                         heavy.damping_quadratic))
    am[2] = heavy.mass - c * (heavy.mass - am[2])
    lin[2] *= c
    quad[2] *= c
    nb = c * (heavy.buoyancy - heavy.weight)
    heavier = heavy.with_updates(added_mass=am, damping_linear=lin, damping_quadratic=quad,
                                 displaced_volume=(heavy.weight + nb) / (heavy.water_density * heavy.gravity))
    flight = dive.fly_plan(short_plan, heavy, heavier, seed=0, noise=False)
    fit = dive.identify_dive(dive.dive_from_columns(flight.columns, heavy), heavy, dofs=("heave",),
                             free=("thrust_scale", "linear", "quadratic", "net_buoyancy"))
    f = fit.fits["heave"]
    assert f.param("thrust_scale").estimate == pytest.approx(0.85, rel=5e-3)
    assert f.param("added_mass").status == "held"
    assert f.param("quadratic").estimate == pytest.approx(heavy.damping_quadratic[2], rel=5e-3)


def test_cli_plan_fly_identify_update(capsys, tmp_path):
    planned = tmp_path / "plan.toml"
    code, out, err = run(capsys, "lab", "plan-dive", "--vehicle", "bluerov2_heavy", "--dofs", "heave,yaw",
                         "--duration", 120, "--seed", 3, "--out", planned)
    assert code == 0, err
    assert "Z_|w|w" in out and "expected standard deviations" in out and planned.is_file()
    log = tmp_path / "dive.csv"
    code, out, err = run(capsys, "lab", "dive", "--plan", planned, "--vehicle", "bluerov2_heavy", "--seed", 4,
                         "--out", log, "--json")
    assert code == 0, err
    made = json.loads(out)
    truth = made["written"][0]["truth"]
    target = tmp_path / "my_heavy.toml"
    target.write_text(packaged_vehicle_path("bluerov2_heavy").read_text(encoding="utf-8"), encoding="utf-8")
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--update", target, "--json")
    assert code == 0, err
    res = json.loads(out)
    z = res["heave"]["parameters"]["Z_|w|w"]
    assert z["status"] == "estimated" and abs(z["estimate"] - truth["Z_|w|w"]) < 3 * z["sigma"]
    assert res["prediction_rmse"]["heading_rad"]["identified"][2] < res["prediction_rmse"]["heading_rad"]["file"][2]
    v = load_vehicle(target)
    assert v.damping_quadratic[2] == pytest.approx(z["estimate"], rel=1e-3)
    text = target.read_text(encoding="utf-8")
    assert f"rovlab identify dive {log.name} (t 0.0-" in text and "Z_|w|w sigma" in text
    # the text report names the table's columns and the prediction horizons
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy")
    assert code == 0 and "100 steps" in out and "N_|r|r" in out


@pytest.mark.parametrize("argv, expected", [
    (["--dofs", "surge"], "surge and sway"),
    (["--free", "added_mass,thrust_scale"], "force / mass"),
    (["--split", "0.99"], "--split"),
])
def test_cli_bad_input_exits_2_with_a_message(capsys, tmp_path, heavy, argv, expected):
    p = plan.plan_dive(heavy, ("heave", "yaw"), 60.0, seed=1)
    flight = dive.fly_plan(p, heavy, heavy, seed=1)
    from rovlab.io.logwriter import write_csv

    log = tmp_path / "d.csv"
    write_csv(log, flight.columns)
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", *argv)
    assert code == 2 and expected in err and "Traceback" not in err


def test_a_plan_file_with_an_unknown_key_is_refused(capsys, tmp_path, heavy):
    p = plan.plan_dive(heavy, ("heave",), 60.0, seed=1)
    path = plan.write_plan(tmp_path / "p.toml", p)
    assert plan.read_plan(path).Z == pytest.approx(p.Z)
    path.write_text(path.read_text(encoding="utf-8").replace("depth_gain", "depth_gainz"), encoding="utf-8")
    code, out, err = run(capsys, "lab", "dive", "--plan", path, "--vehicle", "bluerov2_heavy", "--seed", 1,
                         "--out", tmp_path / "d.csv")
    assert code == 2 and "depth_gainz" in err


@pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None or not TLOG.is_file(),
                    reason="needs pymavlink and ../shared/data/ardusub/small.tlog")
def test_the_real_surface_log_determines_nothing_and_says_why(heavy):
    """small.tlog (ArduSub 4.1, BlueROV2 Heavy at the surface or on deck, 263 s): no heave or yaw
    manoeuvre, so both DOFs are refused, naming the plan that would determine them."""
    from rovlab.interfaces.cli_ident import read_dive_log

    data = read_dive_log(TLOG, heavy)
    fit = dive.identify_dive(data, heavy)
    for dof in ("heave", "yaw"):
        assert fit.fits[dof].refused_dof and f"--dofs {dof}" in fit.fits[dof].refused_dof
    assert dive.dive_edits(fit, heavy) == {}


@pytest.mark.slow
def test_reported_sigmas_are_honest_over_many_seeds(heavy):
    """Issue 29: from a 5-minute planned manoeuvre, the truth inside +-2 sigma in >= 90 % of the
    seeds for every parameter, damping within 5 % and added mass within 10 % in every seed."""
    p = plan.plan_dive(heavy, ("heave", "yaw"), 300.0, seed=1)
    inside: dict[str, list[bool]] = {}
    for seed in range(50):
        truth = dive.hidden_vehicle(heavy, 1000 + seed)
        flight, fit = _fit(heavy, truth, p, seed)
        for f in fit.fits.values():
            for prm in f.params:
                if prm.status != "estimated":
                    continue
                true = flight.truth[prm.name]
                inside.setdefault(prm.name, []).append(abs(prm.estimate - true) <= 2 * prm.sigma)
                if prm.key in ("linear", "quadratic"):
                    assert abs(prm.estimate / true - 1) < 0.05, (seed, prm.name)
                elif prm.key == "added_mass":
                    assert abs(prm.estimate / true - 1) < 0.10, (seed, prm.name)
    for name, hits in inside.items():
        assert len(hits) == 50 and np.mean(hits) >= 0.9, (name, np.mean(hits))
    assert math.isfinite(p.duration_s)
