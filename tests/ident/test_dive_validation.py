"""Validation of identify dive (issue 29, "Validation built in" and "Measured here"): the published
parameter set scored beside the identified model and the vehicle file, the validation figure, and
what a pilot-driven (unplanned) dive gives.

Truths come from the virtual lab (rovlab.ident.dive.hidden_vehicle), so every number checked here
is one the test itself made; the published set's values are checked against the citation they
carry (Wu 2018, Tables 5.1-5.3, as restated in public code that cites it).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rovlab.ident import dive, plan, published
from rovlab.ident.fitting import IdentificationError
from rovlab.interfaces.cli import main
from rovlab.params import load_vehicle
from rovlab.params.vehicle import packaged_vehicle_path


@pytest.fixture(scope="module")
def heavy():
    return load_vehicle("bluerov2_heavy")


@pytest.fixture(scope="module")
def short_dive(heavy, tmp_path_factory):
    """A 120 s planned dive of a hidden bluerov2_heavy, written as the CSV that rovlab lab dive writes."""
    from rovlab.ident import lab

    p = plan.plan_dive(heavy, ("heave", "yaw"), 120.0, seed=3)
    truth = dive.hidden_vehicle(heavy, 7)
    flight = dive.fly_plan(p, heavy, truth, seed=7)
    path = tmp_path_factory.mktemp("dive") / "dive.csv"
    lab.write_lab_data(path, lab.LabData("dive", flight.columns, flight.truth, {}, 7, heavy.name,
                                         {k: ".6g" for k in flight.columns if k.startswith("pwm_")}, ()))
    return path, flight


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_the_packaged_published_set_is_wu_2018_with_its_citation(heavy):
    s = published.default_set(heavy)
    assert s is not None and s.name == "wu2018"
    assert "Flinders" in s.citation and "Table" in s.citation
    # Wu 2018 Tables 5.1-5.3 (printed positive; SNAME signs here)
    assert s.values == {"mass": 11.5, "I_zz": 0.16, "Z_wdot": -14.57, "N_rdot": -0.12, "Z_w": -5.18,
                        "Z_|w|w": -36.99, "N_r": -0.07, "N_|r|r": -1.55, "X_udot": -5.5, "Y_vdot": -12.7,
                        "X_u": -4.03, "X_|u|u": -18.18, "Y_v": -6.22, "Y_|v|v": -21.66}
    m = s.models(heavy, ("heave", "yaw", "surge", "sway"))
    assert (m["surge"].rigid, m["surge"].added_mass, m["surge"].linear, m["surge"].quadratic) == (11.5, -5.5, -4.03,
                                                                                                  -18.18)
    assert (m["sway"].rigid, m["sway"].added_mass, m["sway"].linear, m["sway"].quadratic) == (11.5, -12.7, -6.22,
                                                                                                -21.66)
    assert (m["heave"].rigid, m["heave"].added_mass, m["heave"].linear, m["heave"].quadratic) == (11.5, -14.57, -5.18,
                                                                                                  -36.99)
    assert (m["yaw"].rigid, m["yaw"].added_mass, m["yaw"].linear, m["yaw"].quadratic) == (0.16, -0.12, -0.07, -1.55)
    # the set's B - W is its own vehicle's ballast: the file's trim is used, and the report says so
    assert m["heave"].net_buoyancy == pytest.approx(heavy.buoyancy - heavy.weight)
    assert s.taken_from_file() == ["B-W"] and "ballast" in s.note()
    assert published.default_set(load_vehicle("udrone")) is None


@pytest.mark.parametrize("text, expected", [
    ("[a]\ntitle = 't'\ncitation = 'c'\n[a.values]\nZ_w = 5.18\n", "Z_w = 5.18: expected a value <= 0"),
    ("[a]\ntitle = 't'\ncitation = 'c'\n[a.values]\nZ_x = -1.0\n", "unknown parameter 'Z_x'"),
    ("[a]\ntitle = 't'\n[a.values]\nZ_w = -1.0\n", "no 'citation'"),
    ("[a]\ntitle = 't'\ncitation = 'c'\ncolour = 1\n[a.values]\nZ_w = -1.0\n", "unknown key(s) colour"),
    ("[a]\ntitle = 't'\ncitation = 'c'\n[a.values]\nmass = -2\n", "mass = -2: expected a positive"),
])
def test_a_bad_set_file_is_refused_naming_file_key_and_value(tmp_path, text, expected):
    f = tmp_path / "sets.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(IdentificationError, match=None) as exc:
        published.load_set(f)
    assert str(f) in str(exc.value) and expected in str(exc.value)


def test_identify_dive_scores_the_published_set_and_draws_the_figure(capsys, tmp_path, short_dive):
    log, flight = short_dive
    png = tmp_path / "validation.png"
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--plot", png, "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["published_set"]["name"] == "wu2018" and res["plot"] == str(png)
    assert png.stat().st_size > 50_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = res["prediction_rmse"]
    for out_name in ("depth_m", "heading_rad"):
        r = rows[out_name]
        assert len(r["published"]) == 3
        # Wu's heave damping is ~6x below the hidden vehicle's (Z_w -5.18 against ~-33): 10 s ahead its
        # depth and heading are worse than the identified model's (measured 2026-11-27 on this dive:
        # depth 1.53 m against 0.017 m, heading 19 deg against 0.41 deg)
        assert r["identified"][2] < r["published"][2]
    text_code, text, _ = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--no-plot")
    assert text_code == 0 and "identified / file / published wu2018" in text and "Tables 5.1-5.3" in text
    assert "from the vehicle file: B-W" in text


def test_a_vehicle_without_a_published_set_has_no_such_column_and_says_so(capsys, tmp_path, short_dive):
    log, _ = short_dive
    mine = tmp_path / "my_rov.toml"
    mine.write_text(packaged_vehicle_path("bluerov2_heavy").read_text(encoding="utf-8")
                    .replace('name = "bluerov2_heavy"', 'name = "my_rov"', 1), encoding="utf-8")
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", mine, "--no-plot", "--json")
    assert code == 0, err
    res = json.loads(out)
    assert res["published_set"] is None
    assert all("published" not in r for r in res["prediction_rmse"].values())
    code, text, _ = run(capsys, "identify", "dive", log, "--vehicle", mine, "--no-plot")
    assert "no published parameter set compared: none is listed for my_rov" in text
    # and it can be asked for by name
    code, out, err = run(capsys, "identify", "dive", log, "--vehicle", mine, "--no-plot", "--compare", "wu2018", "--json")
    assert code == 0 and json.loads(out)["published_set"]["name"] == "wu2018"


def test_compare_with_an_unknown_set_exits_2(capsys, short_dive):
    log, _ = short_dive
    code, _, err = run(capsys, "identify", "dive", log, "--vehicle", "bluerov2_heavy", "--compare", "nosuch")
    assert code == 2 and "--compare nosuch: no such packaged set or file" in err and "wu2018" in err


def test_validation_traces_put_the_identified_model_on_the_measurements(heavy, short_dive):
    """The figure's 10-step predictions: the identified model's are closer to the measured depth and
    heading than the vehicle file's, and its free run stays closer too (the hidden vehicle differs
    from the file by up to 25 %)."""
    log, _ = short_dive
    data = dive.read_dive(log, heavy)
    fit = dive.identify_dive(data, heavy)
    models = {"identified": {d: f.model for d, f in fit.fits.items()},
              "file": {d: dive.dof_model(heavy, d) for d in fit.fits}}
    traces = dive.validation_traces(data, models, *fit.valid_span)
    assert [t.output for t in traces] == ["depth_m", "heading_rad"]
    for tr in traces:
        def rmse(series, model):
            t, p = series[model]
            return float(np.sqrt(np.mean((p - np.interp(t, tr.t, tr.y)) ** 2)))
        assert tr.k == 10 and len(tr.k_step["identified"][0]) > 20
        assert rmse(tr.k_step, "identified") < rmse(tr.k_step, "file")
        assert rmse(tr.free, "identified") < rmse(tr.free, "file")
        assert tr.free["identified"][0][0] == pytest.approx(tr.free_start)


# --------------------------------------------------------------------------------------------
# An unplanned dive: a pilot with a joystick (rovlab.ident.pilot)
# --------------------------------------------------------------------------------------------

def _pilot_fit(heavy, seed, *, forward_runs=True):
    from rovlab.ident import pilot

    p = pilot.pilot_dive(heavy, 300.0, seed=seed, forward_runs=forward_runs)
    truth = dive.hidden_vehicle(heavy, 1000 + seed)
    flight = dive.fly_plan(p, heavy, truth, seed=seed)
    return p, flight, dive.identify_dive(dive.dive_from_columns(flight.columns, heavy), heavy)


def test_a_pilot_flies_like_a_pilot(heavy):
    """No excitation plan: descents and ascents to depths the pilot picks, holds corrected by eye,
    turns, forward runs, hands off; the stick in MANUAL_CONTROL's 1/1000 steps with a dead zone."""
    from rovlab.ident import pilot

    p = pilot.pilot_dive(heavy, 300.0, seed=11)
    flyer = p.flyer()
    taus = [flyer.step(k, 1.5 if k < 1500 else 2.5)[0] for k in range(len(p.Z))]
    kinds = {task for _, task in flyer.tasks}
    assert {"hold", "turn", "forward"} <= kinds and ({"descend", "ascend"} & kinds)
    tau = np.array(taus)
    lo, hi = p.capacity["yaw"]
    assert np.max(np.abs(tau[:, 3])) <= 0.5 * hi + 1e-9  # 50 % pilot gain
    assert np.all(tau[:, 1] == 0.0)  # no lateral stick
    assert np.any(tau[:, 2] > 0) and np.any(tau[:, 2] < 0)  # heave stick both ways (down: positive Z, NED)
    with pytest.raises(ValueError, match="submerged"):
        pilot.pilot_dive(heavy, 300.0, depth_min=0.1)


def test_a_pilot_dive_determines_heave_and_says_when_surge_runs_cloud_yaw(heavy):
    """What identify dive gives on a 5-minute pilot-driven dive (docs/identification.md, "An
    unplanned dive"): heave determined and within its sigmas; with forward runs in the log the
    report warns that the yaw model leaves out the surge coupling; without them, yaw too is
    determined within its sigmas."""
    _, flight, fit = _pilot_fit(heavy, 11)
    assert not any(f.refused_dof for f in fit.fits.values())
    for prm in fit.fits["heave"].params:
        if prm.status == "held":
            continue
        true = flight.truth[prm.name]
        assert prm.status == "estimated" and abs(prm.estimate - true) <= 3 * prm.sigma, (prm.name, prm.estimate, true)
        if prm.key in ("linear", "quadratic"):
            assert abs(prm.estimate / true - 1) < 0.05, prm.name
    assert any("surge/sway thrust" in n and "N_r" in n for n in fit.notes)
    _, flight, fit = _pilot_fit(heavy, 1, forward_runs=False)
    assert not any("surge/sway thrust" in n for n in fit.notes)
    for f in fit.fits.values():
        for prm in f.params:
            if prm.status == "held":
                continue
            true = flight.truth[prm.name]
            assert prm.status == "estimated" and abs(prm.estimate - true) <= 3 * prm.sigma, (prm.name, prm.estimate, true)


@pytest.mark.slow
def test_what_a_pilot_dive_gives_over_20_seeds(heavy):
    """docs/identification.md, "An unplanned dive" (measured 2026-11-27, seeds 0-19 of 30): on
    5-minute pilot dives with forward runs nothing is refused, the heave parameters' truths lie
    within +-2 sigma in >= 90 % of the dives and within 10 % in every one; the report warns of
    the surge thrust in every dive (N_r, which it biases, is within +-2 sigma in only 75 %)."""
    inside: dict[str, list[bool]] = {}
    for seed in range(20):
        _, flight, fit = _pilot_fit(heavy, seed)
        assert not any(f.refused_dof for f in fit.fits.values()), seed
        assert any("surge/sway thrust" in n for n in fit.notes), seed
        for prm in fit.fits["heave"].params:
            if prm.status == "held":
                continue
            assert prm.status == "estimated", (seed, prm.name, prm.note)
            true = flight.truth[prm.name]
            inside.setdefault(prm.name, []).append(abs(prm.estimate - true) <= 2 * prm.sigma)
            if prm.key != "net_buoyancy":
                assert abs(prm.estimate / true - 1) < 0.10, (seed, prm.name, prm.estimate, true)
    for name, hits in inside.items():
        assert len(hits) == 20 and np.mean(hits) >= 0.9, (name, np.mean(hits))
