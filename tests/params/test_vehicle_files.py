"""Vehicle files: every packaged vehicle loads; each kind of malformed file gets its message."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rovlab.params import ConfigError, check_vehicle_file, load_vehicle, packaged_vehicle_names
from rovlab.params.vehicle import packaged_vehicle_path

UDRONE_TEXT = packaged_vehicle_path("udrone").read_text(encoding="utf-8")


def test_packaged_vehicles_are_listed_and_load():
    names = packaged_vehicle_names()
    assert {"udrone", "bluerov2_heavy"} <= set(names)
    for name in names:
        v = load_vehicle(name)
        assert v.name == name
        assert v.sources["vehicle"], f"{name} must say where its numbers come from"
        assert all(v.sources[block] for block in ("rigid_body", "restoring", "added_mass", "damping"))


def test_udrone_values_match_the_thesis_tables(udrone):
    # Sandøy 2016, tables 2.1-2.2 and 4.1-4.8 (W = m g and B = rho g Delta from table 4.1)
    assert udrone.mass == 7.31 and udrone.I_zz == 0.16
    assert udrone.weight == pytest.approx(71.7, abs=0.05)
    assert udrone.buoyancy == pytest.approx(78.4, abs=0.05)
    np.testing.assert_array_equal(udrone.added_mass, [-5.50, -12.70, -14.57, -0.12])
    np.testing.assert_array_equal(udrone.damping_linear, [-4.03, -6.22, -5.18, -0.07])
    np.testing.assert_array_equal(udrone.damping_quadratic, [-18.18, -21.66, -36.99, -1.55])
    np.testing.assert_array_equal(udrone.damping_cubic, [-24.24, -128.52, -123.15, 0.0])
    assert udrone.thruster_names == ("T1", "T2", "T3", "T4", "T5", "T6")
    t3 = udrone.thruster("T3")
    np.testing.assert_allclose(t3.position, [-0.199, 0.0, 0.085])
    assert (t3.curve.K_L_neg, t3.curve.K_NL_neg, t3.curve.K_L_pos, t3.curve.K_NL_pos) == (
        3.46e-2, 2.27e-4, 8.24e-2, 2.24e-4)
    assert udrone.sensor("pressure").variance == {"z": 1.189622e-04}
    np.testing.assert_allclose(udrone.sensor("pressure").position, [0.12315, 0, -0.0465])
    assert udrone.sensor("qualisys").variance["psi"] == 1.641552e-06
    assert udrone.geometry.area_top == pytest.approx(0.117375)


def test_vehicle_is_immutable(udrone):
    with pytest.raises(AttributeError):
        udrone.mass = 8.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        udrone.added_mass[0] = 1.0
    heavier = udrone.with_updates(mass=8.0)
    assert heavier.mass == 8.0 and udrone.mass == 7.31


def _problems(tmp_path: Path, text: str) -> list[str]:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    msgs = [str(p) for p in info.value.problems]
    assert all(str(path) in m for m in msgs), "every message names the file"
    assert check_vehicle_file(path), "check_vehicle_file reports the same problems"
    return msgs


@pytest.mark.parametrize(
    ("old", "new", "key", "expected"),
    [
        ("mass = 7.31", "", "rigid_body.mass", "missing"),
        ("mass = 7.31", "mass = 7.31\nmass_kg = 7.31", "rigid_body.mass_kg", "unknown keys are errors"),
        ("mass = 7.31", 'mass = "heavy"', "rigid_body.mass", "a number"),
        ("mass = 7.31", "mass = -7.31", "rigid_body.mass", "a positive number"),
        ("mass = 7.31", "mass = 0", "rigid_body.mass", "a positive number"),
        ("mass = 7.31", "mass = nan", "rigid_body.mass", "a finite number"),
        ("X_udot = -5.50", "X_udot = 5.50", "added_mass.X_udot", "added mass is <= 0"),
        ("surge = { linear = -4.03,", "surge = { linear = 4.03,", "damping.surge.linear", "damping is <= 0"),
        ("yaw   = { linear = -0.07, quadratic = -1.55, cubic = 0.0 }",
         "yaw   = { linear = -0.07, quadratic = 1.55, cubic = 0.0 }", "damping.yaw.quadratic", "damping is <= 0"),
        ("r_b = [0.0, 0.0, 0.00019]", "r_b = [0.0, 0.00019]", "restoring.r_b", "a list of 3 finite numbers"),
        ("position = [0.153, -0.111, -0.004]", "position = [0.153, -0.111, inf]", "thrusters[0].position",
         "a list of 3 finite numbers"),
        ("rate_hz = 10.0\nvariance = { z = 1.189622e-04 }", "rate_hz = 10.0\nvariance = { z = -1.0 }",
         "sensors[1].variance.z", "a positive number"),
        ('kind = "pressure"', 'kind = "sonar"', "sensors[1].kind", "one of"),
        ('model = "quadratic"\nquadratic = { K_L_pos = 6.07e-2',
         'model = "spline"\nquadratic = { K_L_pos = 6.07e-2', "thrusters[0].model", "one of"),
    ],
)
def test_each_bad_value_gets_its_message(tmp_path, old, new, key, expected):
    assert old in UDRONE_TEXT
    msgs = _problems(tmp_path, UDRONE_TEXT.replace(old, new, 1))
    hits = [m for m in msgs if f": {key}:" in m]
    assert hits, f"no message for {key}: {msgs}"
    assert expected in hits[0]


def test_direction_not_unit_vector(tmp_path):
    text = UDRONE_TEXT.replace("direction = [1.0, 0.0, 0.0]", "direction = [2.0, 0.0, 0.0]", 1)
    msgs = _problems(tmp_path, text)
    assert any("thrusters[3].direction" in m and "unit vector" in m and "norm is 2" in m for m in msgs)


def test_all_problems_reported_at_once(tmp_path):
    text = (UDRONE_TEXT.replace("mass = 7.31", "mass = -1")
            .replace("X_udot = -5.50", "X_udot = 5.5")
            .replace('name = "T2"', 'name = "T2"\ncolour = "blue"'))
    msgs = _problems(tmp_path, text)
    assert len(msgs) == 3
    assert any("rigid_body.mass" in m for m in msgs)
    assert any("added_mass.X_udot" in m for m in msgs)
    assert any("thrusters[1].colour" in m for m in msgs)


def test_configuration_that_cannot_produce_a_dof(tmp_path):
    # turn the sway thruster T6 into a second surge thruster: nothing can push sideways
    text = UDRONE_TEXT.replace("direction = [0.0, 1.0, 0.0]", "direction = [1.0, 0.0, 0.0]")
    msgs = _problems(tmp_path, text)
    assert any("Y (sway)" in m for m in msgs), msgs


def test_duplicate_thruster_names(tmp_path):
    msgs = _problems(tmp_path, UDRONE_TEXT.replace('name = "T2"', 'name = "T1"'))
    assert any("unique thruster names" in m for m in msgs)


def test_syntax_error_and_missing_file(tmp_path):
    msgs = _problems(tmp_path, UDRONE_TEXT.replace("mass = 7.31", "mass = = 7.31"))
    assert len(msgs) == 1 and "valid TOML" in msgs[0]
    with pytest.raises(ConfigError, match="an existing TOML file"):
        load_vehicle(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="packaged vehicle name"):
        load_vehicle("no_such_vehicle")


def test_thrusters_must_be_an_array_of_tables(tmp_path):
    text = re.sub(r"\[\[thrusters\]\].*?(?=\[\[sensors\]\])", "thrusters = 6\n", UDRONE_TEXT, count=0, flags=re.S)
    # 'thrusters = 6' placed after a table header belongs to that table; put it at the top instead
    text = 'thrusters = 6\n' + re.sub(r"thrusters = 6\n", "", text)
    msgs = _problems(tmp_path, text)
    assert any(": thrusters:" in m and "array of tables" in m for m in msgs)


# --------------------------------------------------------------------------------------------
# Issue 15 item 12: physical plausibility (docs/vehicle-file.md, "Plausible ranges"). Each of these
# was accepted by `vehicle check` and then turned the plant NaN (or broke an output file).
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize(
    ("old", "new", "key", "expected"),
    [
        ("surge = { linear = -4.03,", "surge = { linear = -9e18,", "damping.surge.linear", "-10000 .. 0"),
        ("gravity = 9.81", "gravity = 1.8e19", "restoring.gravity", "9.7 .. 9.9"),
        ("rate_hz = 10.0\nvariance = { z = 1.189622e-04 }", "rate_hz = 1e308\nvariance = { z = 1.189622e-04 }",
         "sensors[1].rate_hz", "0.01 .. 10000"),
        ("rate_hz = 10.0\nvariance = { z = 1.189622e-04 }", "rate_hz = 1e-29\nvariance = { z = 1.189622e-04 }",
         "sensors[1].rate_hz", "0.01 .. 10000"),
        ("position = [0.153, -0.111, -0.004]", "position = [1.5e11, -0.111, -0.004]", "thrusters[0].position",
         "-5 .. 5"),
        ("mass = 7.31", "mass = 7.31e6", "rigid_body.mass", "0.1 .. 1000"),
        ("mass = 7.31", "mass = 1.0", "restoring.displaced_volume", "B/W is 7.99"),
        ('name = "T2"', 'name = "T2\\u0000"', "thrusters[1].name", "control characters"),
        ('name = "pressure"', 'name = "pres\\nsure"', "sensors[1].name", "a name"),
        ("variance = { z = 1.189622e-04 }", "variance = { z = 5e-324 }", "sensors[1].variance.z", "1e-15 .. 10000"),
    ],
)
def test_implausible_values_are_refused(tmp_path, old, new, key, expected):
    assert old in UDRONE_TEXT
    msgs = _problems(tmp_path, UDRONE_TEXT.replace(old, new, 1))
    hits = [m for m in msgs if f": {key}:" in m]
    assert hits, f"no message for {key}: {msgs}"
    assert expected in hits[0]
    assert "docs/vehicle-file.md" in hits[0] or "name" in key


def test_vehicle_name_with_nul_and_no_sensors_are_refused(tmp_path):
    text = UDRONE_TEXT.replace('name = "udrone"', 'name = "ud\\u0000rone"', 1)
    text = text[:text.index("[[sensors]]")]
    msgs = _problems(tmp_path, text)
    assert any(": name:" in m and "\\x00" in m for m in msgs), msgs
    assert any(": sensors:" in m and "missing" in m for m in msgs), msgs


def test_vehicle_check_exit_status_and_show_json_is_strict_json(tmp_path, capsys):
    import json

    from rovlab.interfaces.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text(UDRONE_TEXT.replace("gravity = 9.81", "gravity = 1.8e19"), encoding="utf-8")
    assert main(["vehicle", "check", str(bad)]) == 2
    out = capsys.readouterr().out
    assert str(bad) in out and "restoring.gravity" in out and "1.8e+19" in out
    assert main(["vehicle", "show", "udrone", "--json"]) == 0
    out = capsys.readouterr().out
    json.loads(out, parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ('deadband_kind = "cut"      #', 'deadband_kind = "cutt"      #', "one of 'shift', 'cut'"),
        ("deadband_us = 25           # SITL's ESC dead zone", "deadband_us = 0  #", "deadband_us > 0"),
        ("pwm_max_us = 1900", "pwm_max_us = 1525.5", "pwm_neutral_us + deadband_us + 1 <= pwm_max_us"),
    ],
)
def test_a_bad_cut_dead_band_is_named(tmp_path, old, new, expected):
    """deadband_kind = "cut" (ArduSub SITL's thrusters): a misspelt kind, a cut without a band, a band whose
    least pulse (edge + 1 us) lies outside the PWM range: each named by file and key, all at once."""
    text = packaged_vehicle_path("ardusub_sitl_heavy").read_text()
    assert old in text
    msgs = _problems(tmp_path, text.replace(old, new, 1))
    hits = [m for m in msgs if ": thrusters[0].deadband_kind:" in m]
    assert hits and expected in hits[0], msgs


def test_a_cut_dead_band_on_a_table_is_refused(tmp_path):
    text = packaged_vehicle_path("bluerov2_heavy").read_text()
    assert text.count('model = "table"') >= 1
    msgs = _problems(tmp_path, text.replace('model = "table"', 'model = "table"\ndeadband_kind = "cut"', 1))
    hits = [m for m in msgs if ": thrusters[0].deadband_kind:" in m]
    assert hits and "applies to the quadratic model" in hits[0], msgs
