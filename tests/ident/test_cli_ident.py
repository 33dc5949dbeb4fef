"""Command-line contract of issue 5: ``rovlab lab ...`` -> ``rovlab identify ... --json`` round trips,
``added-mass``, ``--update`` into a vehicle file, and clean errors (exit status 2, no traceback)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rovlab.interfaces.cli import main
from rovlab.params import load_vehicle
from rovlab.params.vehicle import packaged_vehicle_path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def run_json(capsys, *argv):
    code, out, err = run(capsys, *argv, "--json")
    assert code == 0, err
    return json.loads(out)


@pytest.fixture
def vehicle_copy(tmp_path):
    path = tmp_path / "my_udrone.toml"
    path.write_text(packaged_vehicle_path("udrone").read_text(encoding="utf-8"), encoding="utf-8")
    return path


def test_thrust_round_trip_and_update(capsys, tmp_path, vehicle_copy):
    log = tmp_path / "t4t5.csv"
    made = run_json(capsys, "lab", "thrust", "--thruster", "T4,T5", "--seed", 3, "--step-s", 8, "--out", log)
    assert made["seed"] == 3 and "--pair 2" in made["next"]
    data = run_json(capsys, "identify", "thrust", log, "--pair", 2, "--window", 3, "--no-plot",
                    "--update", vehicle_copy, "--thruster", "T4,T5")
    assert set(data) >= {"K_L_pos", "K_NL_pos", "K_L_neg", "K_NL_neg", "deadband_us", "rms_n"}
    # Sandøy 2016, table 2.2, T4/T5: K_L+ 7.22e-2, K_NL+ 2.41e-4, K_L- 3.57e-2, K_NL- 1.75e-4
    for key, truth in (("K_L_pos", 7.22e-2), ("K_NL_pos", 2.41e-4), ("K_L_neg", 3.57e-2), ("K_NL_neg", 1.75e-4)):
        assert data[key] == pytest.approx(truth, rel=0.03), key
    v = load_vehicle(vehicle_copy)
    assert v.thruster("T5").curve.K_L_pos == pytest.approx(data["K_L_pos"], rel=1e-3)
    assert "curve: rovlab identify thrust t4t5.csv --pair 2" in v.thruster("T4").source


def test_thrust_table_of_the_maker(capsys, tmp_path):
    from importlib import resources

    src = resources.files("rovlab.models") / "data" / "t200" / "T200-Thrusters-16V.csv"
    data = run_json(capsys, "identify", "thrust", str(src), "--table", "--plot", tmp_path / "t200.png")
    assert 0.1 < data["rms_n"] < 0.6 and data["points"] == 201
    assert (tmp_path / "t200.png").stat().st_size > 10_000


def test_towing_round_trip_writes_plot_into_the_working_directory(capsys, tmp_path, vehicle_copy, monkeypatch):
    # issue 15: the figure used to go next to the input (inside the installed package for packaged data)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    runs = tmp_path / "heave.csv"
    made = run_json(capsys, "lab", "towing", "--dof", "heave", "--seed", 5, "--out", runs)
    rig = tmp_path / "heave-rig.csv"
    assert made["written"][1]["file"] == str(rig)
    data = run_json(capsys, "identify", "towing", runs, "--rig", rig, "--update", vehicle_copy)  # DOF from the log
    assert data["dof"] == "heave"
    assert set(data) >= {"linear", "quadratic", "cubic"}
    for key, truth in (("linear", -5.18), ("quadratic", -36.99), ("cubic", -123.15)):  # Sandøy 2016, table 4.6
        assert abs(data[key] - truth) < 3.5 * data["stderr"][key]
    assert data["plot"] == "heave-towing.png" and (work / "heave-towing.png").exists()
    assert not (tmp_path / "heave-towing.png").exists()
    v = load_vehicle(vehicle_copy)
    assert v.damping_linear[2] == pytest.approx(data["linear"], rel=1e-3)
    assert "heave: rovlab identify towing heave.csv --rig heave-rig.csv" in v.sources["damping"]


def test_yaw_round_trip(capsys, tmp_path):
    runs = tmp_path / "yaw.csv"
    run_json(capsys, "lab", "yaw", "--seed", 6, "--duration-s", 15, "--out", runs)
    data = run_json(capsys, "identify", "yaw", runs, "--no-plot")
    assert data["linear"] == pytest.approx(-0.07, rel=0.05)  # Sandøy 2016, table 4.6: N_r
    assert data["quadratic"] == pytest.approx(-1.55, rel=0.05)  # N_|r|r


def test_step_round_trip_and_update(capsys, tmp_path, vehicle_copy):
    log = tmp_path / "relay.csv"
    made = run_json(capsys, "lab", "step", "--seed", 7, "--linear", "--out", log)
    assert "--mass 7.31" in made["next"]
    data = run_json(capsys, "identify", "step", log, "--mass", 7.31, "--no-plot", "--update", vehicle_copy)
    assert set(data) >= {"gain", "pole", "added_mass", "linear_damping"}
    assert data["added_mass"] == pytest.approx(-5.50, rel=0.05)  # SNAME sign; Sandøy 2016, table 4.4
    assert data["linear_damping"] == pytest.approx(-4.03, rel=0.05)
    assert data["gain"] == pytest.approx(1 / (7.31 + 5.50), rel=0.05)
    v = load_vehicle(vehicle_copy)
    assert v.added_mass[0] == pytest.approx(data["added_mass"], rel=1e-3)


def test_step_with_the_vehicles_nonlinear_damping(capsys, tmp_path, vehicle_copy):
    # issue 10, item 5: --vehicle holds the file's quadratic/cubic damping fixed (and gives the mass)
    log = tmp_path / "relay.csv"
    made = run_json(capsys, "lab", "step", "--dof", "sway", "--seed", 5, "--out", log)
    assert "--vehicle udrone" in made["next"]
    data = run_json(capsys, "identify", "step", log, "--dof", "sway", "--vehicle", "udrone", "--no-plot",
                    "--update", vehicle_copy)
    assert data["mass"] == pytest.approx(7.31)
    assert data["fixed_damping"] == {"quadratic": pytest.approx(-21.66), "cubic": pytest.approx(-128.52)}
    assert data["added_mass"] == pytest.approx(-12.70, rel=0.03)  # Sandøy 2016, table 4.4: Y_vdot
    assert load_vehicle(vehicle_copy).added_mass[1] == pytest.approx(data["added_mass"], rel=1e-3)
    code, out, _ = run(capsys, "identify", "step", log, "--dof", "sway", "--vehicle", "udrone", "--no-plot")
    assert code == 0 and "held fixed (from udrone)" in out


def test_step_needs_a_mass_or_a_vehicle(capsys, tmp_path):
    log = tmp_path / "relay.csv"
    run(capsys, "lab", "step", "--seed", 5, "--linear", "--out", log)
    code, _, err = run(capsys, "identify", "step", log, "--no-plot")
    assert code == 2 and "--mass" in err and "--vehicle" in err and "Traceback" not in err
    code, _, err = run(capsys, "identify", "step", log, "--vehicle", "no_such_vehicle", "--no-plot")
    assert code == 2 and "no_such_vehicle" in err and "Traceback" not in err


def test_noise_round_trip_and_update(capsys, tmp_path, vehicle_copy):
    log = tmp_path / "rest.csv"
    run_json(capsys, "lab", "noise", "--seed", 8, "--out", log)
    data = run_json(capsys, "identify", "noise", log, "--no-plot", "--allan", "--update", vehicle_copy)
    assert data["variance"]["z_pressure"] == pytest.approx(1.189622e-04, rel=0.05)  # thesis table 4.8
    assert "allan" in data
    v = load_vehicle(vehicle_copy)
    assert v.sensor("qualisys").variance["psi"] == pytest.approx(data["variance"]["psi_qualisys"], rel=1e-3)
    assert "variance: rovlab identify noise rest.csv" in v.sensor("pressure").source


def test_added_mass_contract(capsys, tmp_path):
    data = run_json(capsys, "added-mass", "--length", 0.482, "--width", 0.333, "--height", 0.287,
                    "--area-front", 0.055915, "--area-side", 0.102378, "--area-top", 0.117375)
    # Sandøy 2016, table 4.4 (Eidsvik's method, sec. 4.2.1, on the geometry of table 4.2)
    assert data["X_udot"] == pytest.approx(-5.50, abs=0.01)
    assert data["Y_vdot"] == pytest.approx(-12.70, abs=0.01)
    assert data["Z_wdot"] == pytest.approx(-14.57, abs=0.01)
    assert data["N_rdot"] == pytest.approx(-0.12, abs=0.01)
    code, out, _ = run(capsys, "added-mass", "--vehicle", "udrone", "--plot", tmp_path / "am.png")
    assert code == 0 and "X_udot =   -5.4969 kg" in out and (tmp_path / "am.png").exists()


def test_human_readable_output(capsys, tmp_path):
    log = tmp_path / "relay.csv"
    code, out, _ = run(capsys, "lab", "step", "--seed", 9, "--out", log)
    assert code == 0 and "seed 9" in out and "next: rovlab identify step" in out
    code, out, _ = run(capsys, "identify", "step", log, "--mass", 7.31, "--no-plot")
    assert code == 0 and "added mass X_udot = m - 1/k" in out and "(SNAME)" in out


# -- errors ----------------------------------------------------------------------------------

def test_malformed_file_is_a_clean_error(capsys, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,pwm_us,force_n\n0,1500,0\n0.02,1500,oops\n", encoding="utf-8")
    code, out, err = run(capsys, "identify", "thrust", bad)
    assert code == 2 and out == ""
    assert "bad.csv: line 3, column 'force_n': got 'oops'; expected a number" in err
    assert "Traceback" not in err


def test_missing_columns_and_too_little_data(capsys, tmp_path):
    bad = tmp_path / "runs.csv"
    bad.write_text("run,time_s,speed,force_n\n1,0,0,0\n", encoding="utf-8")
    code, _, err = run(capsys, "identify", "towing", bad)
    assert code == 2 and "missing: speed_mps" in err
    few = tmp_path / "few.csv"
    run(capsys, "lab", "towing", "--speeds", "0.1,0.2,0.3", "--seed", 1, "--out", few)
    code, _, err = run(capsys, "identify", "towing", few, "--no-plot")
    assert code == 2 and "needs at least 4 runs" in err and str(few) in err


def test_update_needs_a_thruster_and_a_real_file(capsys, tmp_path):
    log = tmp_path / "t.csv"
    run(capsys, "lab", "thrust", "--seed", 1, "--step-s", 6, "--out", log)
    code, _, err = run(capsys, "identify", "thrust", log, "--window", 3, "--update", "x.toml")
    assert code == 2 and "--update needs --thruster" in err
    code, _, err = run(capsys, "identify", "thrust", log, "--window", 3, "--no-plot", "--update", "udrone",
                       "--thruster", "T1")
    assert code == 2 and "copy it first" in err
    code, _, err = run(capsys, "identify", "thrust", log, "--window", 3, "--no-plot", "--update",
                       packaged_vehicle_path("udrone"), "--thruster", "T1")
    assert code == 2 and "packaged vehicle file" in err


def test_update_that_would_break_the_file_writes_nothing(capsys, tmp_path, vehicle_copy):
    # towing data with the force sign flipped gives positive ("energy-creating") damping, which
    # the vehicle file refuses: the update must fail and leave the file as it was
    from rovlab.io.tables import read_table, write_table

    runs = tmp_path / "surge.csv"
    run(capsys, "lab", "towing", "--seed", 4, "--out", runs)
    t = read_table(runs)
    flipped = tmp_path / "flipped.csv"
    write_table(flipped, {c: (-t[c] if c == "force_n" else t[c]) for c in t.columns}, formats={"run": "d"})
    before = vehicle_copy.read_text(encoding="utf-8")
    code, _, err = run(capsys, "identify", "towing", flipped, "--no-plot", "--dof", "surge", "--update", vehicle_copy)
    assert code == 2 and "nothing was written" in err and "damping.surge.linear" in err
    assert vehicle_copy.read_text(encoding="utf-8") == before


def test_thrust_of_the_wrong_sign_is_explained(capsys, tmp_path):
    log = tmp_path / "odd.csv"
    rows = ["time_s,pwm_us,force_n"]
    t = 0.0
    for pwm in range(1300, 1710, 10):
        for _ in range(100):
            rows.append(f"{t:.2f},{pwm},{-0.05 * (pwm - 1500)}")
            t += 0.05
    log.write_text("\n".join(rows) + "\n", encoding="utf-8")
    code, _, err = run(capsys, "identify", "thrust", log, "--no-plot")
    assert code == 2 and "forward steps produce negative thrust" in err


def test_lab_bad_options(capsys, tmp_path):
    code, _, err = run(capsys, "lab", "thrust", "--thruster", "T9", "--out", tmp_path / "x.csv")
    assert code == 2 and "has no thruster 'T9'" in err
    code, _, err = run(capsys, "lab", "step", "--dof", "heave", "--force", "0.5", "--out", tmp_path / "x.csv")
    assert code == 2 and "relay switched 0 time" in err


def test_missing_matplotlib_only_warns(capsys, tmp_path, monkeypatch):
    from rovlab.ident import plots

    def unavailable(*a, **k):
        raise plots.PlotUnavailable(plots.INSTALL_HINT)

    monkeypatch.setattr(plots, "_figure", unavailable)
    log = tmp_path / "relay.csv"
    run(capsys, "lab", "step", "--seed", 2, "--linear", "--out", log)
    code, out, err = run(capsys, "identify", "step", log, "--mass", 7.31, "--json")
    assert code == 0 and json.loads(out)["plot"] is None
    assert "pip install 'rovlab[plot]'" in err


def test_step_update_can_keep_the_towing_damping(capsys, tmp_path, vehicle_copy):
    log = tmp_path / "relay.csv"
    run(capsys, "lab", "step", "--seed", 12, "--out", log)
    code, _, err = run(capsys, "identify", "step", log, "--mass", 7.31, "--no-plot", "--update", vehicle_copy,
                       "--added-mass-only")
    assert code == 0 and "equivalent linearisation" not in err
    v = load_vehicle(vehicle_copy)
    assert v.damping_linear[0] == -4.03 and v.added_mass[0] != -5.50  # X_u of Sandøy 2016, table 4.6 kept
    code, _, err = run(capsys, "identify", "step", log, "--mass", 7.31, "--no-plot", "--update", vehicle_copy)
    assert code == 0 and "equivalent linearisation" in err
    assert load_vehicle(vehicle_copy).damping_linear[0] < -4.03


def test_step_dof_must_match_the_log_columns(capsys, tmp_path, vehicle_copy):
    # A surge relay log (force_n, position_m) with --dof yaw would have written its added mass into
    # N_rdot, and a yaw log without --dof into X_udot: refused, and the file left alone.
    surge = tmp_path / "relay.csv"
    run(capsys, "lab", "step", "--seed", 3, "--linear", "--out", surge)
    before = vehicle_copy.read_text(encoding="utf-8")
    code, _, err = run(capsys, "identify", "step", surge, "--mass", 7.31, "--dof", "yaw", "--no-plot",
                       "--update", vehicle_copy)
    assert code == 2 and "--dof yaw needs the columns time_s, moment_nm, heading_rad" in err
    yaw_log = tmp_path / "yaw-relay.csv"
    run(capsys, "lab", "step", "--dof", "yaw", "--force", 0.3, "--amplitude", 1.0, "--seed", 4, "--linear",
        "--out", yaw_log)
    code, _, err = run(capsys, "identify", "step", yaw_log, "--mass", 0.16, "--dof", "surge", "--no-plot",
                       "--update", vehicle_copy)
    assert code == 2 and "use --dof yaw" in err and "Traceback" not in err
    assert vehicle_copy.read_text(encoding="utf-8") == before
    # without --dof the DOF follows the columns: a yaw log updates N_rdot (Sandøy 2016, table 4.4: -0.12 kg m^2)
    data = run_json(capsys, "identify", "step", yaw_log, "--mass", 0.16, "--no-plot", "--update", vehicle_copy,
                    "--added-mass-only")
    assert data["dof"] == "yaw"
    v = load_vehicle(vehicle_copy)
    assert v.added_mass[3] == pytest.approx(-0.12, rel=0.05) and v.added_mass[0] == -5.50


def test_plot_names_are_checked_and_written_exactly(capsys, tmp_path):
    # an unknown suffix used to end in a matplotlib traceback, and a name without one was written
    # as NAME.png while the output reported NAME
    log = tmp_path / "rest.csv"
    run(capsys, "lab", "noise", "--seed", 1, "--samples", 200, "--out", log)
    for bad in (tmp_path / "fig.txt", tmp_path / "fig"):
        code, _, err = run(capsys, "identify", "noise", log, "--plot", bad)
        assert code == 2 and "must end in .png, .svg, .pdf" in err and "Traceback" not in err
    (tmp_path / "dir.png").mkdir()
    code, _, err = run(capsys, "identify", "noise", log, "--plot", tmp_path / "dir.png")
    assert code == 2 and "is a directory" in err
    data = run_json(capsys, "identify", "noise", log, "--plot", tmp_path / "fig.svg")
    assert data["plot"] == str(tmp_path / "fig.svg")
    assert (tmp_path / "fig.svg").read_text(encoding="utf-8").lstrip().startswith("<?xml")


def test_run_errors_name_the_file_once_and_yaw_tables_say_rate_and_moment(capsys, tmp_path):
    few = tmp_path / "short.csv"
    run(capsys, "lab", "towing", "--seed", 1, "--hold-s", 3, "--out", few)
    code, _, err = run(capsys, "identify", "towing", few, "--no-plot")
    assert code == 2 and err.count("short.csv") == 1 and "run 1: the steady part" in err
    runs = tmp_path / "yaw.csv"
    run(capsys, "lab", "yaw", "--seed", 6, "--duration-s", 15, "--out", runs)
    code, out, _ = run(capsys, "identify", "yaw", runs, "--no-plot")
    assert code == 0 and "rate       moment" in out and "(rad/s, N m)" in out


@pytest.mark.parametrize("argv, needle", [
    # values that used to be accepted silently (negative noise, NaN moments, a negative trim) or
    # to end in a traceback (--rate-hz inf) or to run for hours (--duration-s 1e7)
    (["lab", "thrust", "--noise-n", "-1"], "argument --noise-n: expected a non-negative number"),
    (["lab", "thrust", "--rate-hz", "inf"], "argument --rate-hz: expected a finite number"),
    (["lab", "thrust", "--pwm-step", "nan"], "argument --pwm-step: expected a finite number"),
    (["lab", "thrust", "--pwm-start", "500"], "leaves thruster T1's PWM range 1300..1700 us"),
    (["lab", "thrust", "--seed", "-1"], "argument --seed: expected a seed of 0 or more"),
    (["lab", "towing", "--speeds", "nan,0.1"], "--speeds: expected comma-separated finite numbers"),
    (["lab", "towing", "--hold-s", "0"], "argument --hold-s: expected a positive number"),
    (["lab", "yaw", "--moments", "0,1"], "moments must be a non-zero finite number"),
    (["lab", "yaw", "--moment-error", "nan"], "argument --moment-error: expected a finite number"),
    (["lab", "step", "--force", "nan"], "argument --force: expected a finite number"),
    (["lab", "step", "--duration-s", "1e7"], "more than the 2000000 a lab file may have"),
    (["lab", "noise", "--rate-hz", "0"], "argument --rate-hz: expected a positive number"),
    (["lab", "noise", "--samples", "100000000"], "more than the 2000000 a lab file may have"),
])
def test_lab_refuses_bad_settings(capsys, tmp_path, argv, needle):
    out = tmp_path / "x.csv"
    try:
        code = main([str(a) for a in argv] + ["--out", str(out)])
    except SystemExit as exc:  # argparse: usage and the message
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err, err
    assert not out.exists()


@pytest.mark.parametrize("argv, needle", [
    (["identify", "towing", "{towing}", "--trim", "-1"], "argument --trim: expected a non-negative number"),
    (["identify", "towing", "{towing}", "--min-steady", "nan"], "argument --min-steady: expected a finite number"),
    (["identify", "thrust", "{towing}", "--max-force", "0"], "argument --max-force: expected a positive number"),
    (["identify", "thrust", "{towing}", "--deadband", "nan"], "argument --deadband: expected a finite number"),
    (["identify", "step", "{towing}", "--mass", "-7"], "argument --mass: expected a positive number"),
    (["added-mass", "--vehicle", "udrone", "--rho", "abc"], "argument --rho: expected a number, got 'abc'"),
])
def test_identify_refuses_bad_options(capsys, tmp_path, argv, needle):
    towing = tmp_path / "t.csv"
    towing.write_text("run,time_s,speed_mps,force_n\n1,0,0,0\n", encoding="utf-8")
    with pytest.raises(SystemExit) as exc:  # argparse: exit status 2, usage and the message
        main([a.format(towing=towing) for a in argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and needle in err


def test_added_mass_in_millimetres_gets_a_note(capsys):
    code, _, err = run(capsys, "added-mass", "--length", 482, "--width", 333, "--height", 287,
                       "--area-front", 55915, "--area-side", 102378, "--area-top", 117375, "--json")
    assert code == 0 and "were they given in millimetres?" in err


def test_static_table_without_table_flag_gets_a_hint(capsys):
    from importlib import resources

    src = resources.files("rovlab.models") / "data" / "t200" / "T200-Thrusters-16V.csv"
    code, _, err = run(capsys, "identify", "thrust", str(src), "--no-plot")
    assert code == 2 and "missing: time_s" in err and "for a static table add --table" in err


def test_positive_added_mass_points_at_the_mass_option(capsys, tmp_path):
    # a yaw relay identified with the vehicle's mass instead of I_zz: m - 1/k > 0
    log = tmp_path / "yaw-relay.csv"
    run(capsys, "lab", "step", "--dof", "yaw", "--force", 0.3, "--amplitude", 1.0, "--seed", 4, "--linear",
        "--out", log)
    code, _, err = run(capsys, "identify", "step", log, "--mass", 7.31, "--no-plot")
    assert code == 0 and "added mass comes out positive" in err and "inertia I_zz" in err


def test_towing_dof_is_inferred_or_required(capsys, tmp_path):
    # issue 15: heave data used to be reported (and written with --update) as "surge"
    from rovlab.io.tables import read_table, write_table

    runs = tmp_path / "heave.csv"
    run(capsys, "lab", "towing", "--dof", "heave", "--seed", 4, "--out", runs)
    t = read_table(runs)
    bare = tmp_path / "bare.csv"  # no '# setting.dof' line
    write_table(bare, {c: t[c] for c in t.columns}, formats={"run": "d"})
    code, _, err = run(capsys, "identify", "towing", bare, "--no-plot")
    assert code == 2 and str(bare) in err and "expected --dof surge, --dof sway or --dof heave" in err
    assert run_json(capsys, "identify", "towing", bare, "--no-plot", "--dof", "heave")["dof"] == "heave"
    named = tmp_path / "named.csv"  # the speed column says the DOF
    write_table(named, {("w_mps" if c == "speed_mps" else c): t[c] for c in t.columns}, formats={"run": "d"})
    assert run_json(capsys, "identify", "towing", named, "--no-plot")["dof"] == "heave"
    code, _, err = run(capsys, "identify", "towing", runs, "--no-plot", "--dof", "surge")
    assert code == 2 and "the log says it is a heave towing log" in err


def test_noise_refuses_a_staircase_as_a_resting_log(capsys, tmp_path):
    # issue 15: a PWM staircase was accepted as sensor noise at rest
    staircase = tmp_path / "staircase.csv"
    run(capsys, "lab", "thrust", "--seed", 2, "--pwm-step", "50", "--step-s", "5", "--out", staircase)
    code, _, err = run(capsys, "identify", "noise", staircase, "--no-plot")
    assert code == 2 and str(staircase) in err and "not a resting log" in err and "'pwm_us'" in err
    code, _, _ = run(capsys, "identify", "noise", staircase, "--no-plot", "--no-stationarity-check")
    assert code == 0
    resting = tmp_path / "rest.csv"
    run(capsys, "lab", "noise", "--seed", 2, "--samples", "500", "--out", resting)
    data = run_json(capsys, "identify", "noise", resting, "--no-plot")
    assert all(1.5 < r < 2.5 for r in data["von_neumann_ratio"].values())  # white noise: 2


def test_plot_of_packaged_data_goes_to_the_working_directory(capsys, tmp_path, monkeypatch):
    from importlib import resources

    monkeypatch.chdir(tmp_path)
    table = resources.files("rovlab.models") / "data" / "t200" / "T200-Thrusters-16V.csv"
    before = {p.name for p in Path(str(table)).parent.iterdir()}
    data = run_json(capsys, "identify", "thrust", str(table), "--table")
    assert data["plot"] == "T200-Thrusters-16V-thrust.png" and (tmp_path / data["plot"]).exists()
    assert {p.name for p in Path(str(table)).parent.iterdir()} == before


def test_update_on_a_read_only_or_full_disk_fails_cleanly(capsys, tmp_path, vehicle_copy, monkeypatch):
    # issue 15: an OSError traceback, and a temporary file left behind
    import errno
    import os

    import rovlab.core.files as files  # the one atomic writer (params.edit writes through it)

    log = tmp_path / "rest.csv"
    run(capsys, "lab", "noise", "--seed", 3, "--samples", "300", "--out", log)
    before = vehicle_copy.read_text(encoding="utf-8")
    folder_before = sorted(p.name for p in vehicle_copy.parent.iterdir())

    def full_disk(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(files.os, "fsync", full_disk)
    code, _, err = run(capsys, "identify", "noise", log, "--no-plot", "--update", vehicle_copy)
    assert code == 2 and str(vehicle_copy) in err and "No space left on device" in err and "Traceback" not in err
    assert vehicle_copy.read_text(encoding="utf-8") == before
    assert sorted(p.name for p in vehicle_copy.parent.iterdir()) == folder_before  # no temporary file left
    monkeypatch.undo()

    vehicle_copy.chmod(0o444)
    try:
        code, _, err = run(capsys, "identify", "noise", log, "--no-plot", "--update", vehicle_copy)
    finally:
        vehicle_copy.chmod(0o644)
    if os.geteuid() != 0:  # root may write anything: os.access says so
        assert code == 2 and "read-only" in err
    assert vehicle_copy.read_text(encoding="utf-8") == before or code == 0
