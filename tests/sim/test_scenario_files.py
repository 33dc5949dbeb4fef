"""Scenario files (issue 4): packaged ones load; bad ones get clear messages; distributions draw per seed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rovlab.params import ConfigError
from rovlab.sim.scenario import load_scenario, packaged_scenario_names, resolve_scenario_path

DROPOUT_TEXT = resolve_scenario_path("dropout").read_text(encoding="utf-8")


def test_packaged_scenarios_reproduce_the_thesis_case_studies():
    assert {"step-observer-model", "step-process-model", "dropout"} <= set(packaged_scenario_names())
    sc = load_scenario("dropout")
    # Sandøy 2016, sec. 5.3.1: start at z = 1.05 m, psi = 52 deg; z_ref = 0.70 m, psi_ref = 30 deg, then 0 deg at 22 s
    assert sc.initial[2] == 1.05 and sc.initial[3] == pytest.approx(math.radians(52))
    np.testing.assert_allclose(sc.reference_times, [0.0, 22.0])
    np.testing.assert_allclose(sc.reference_z, [0.70, 0.70])
    np.testing.assert_allclose(sc.reference_psi, [math.radians(30), 0.0])
    assert sc.dropouts[0].sensor == "qualisys" and (sc.dropouts[0].start_s, sc.dropouts[0].end_s) == (20.0, 40.0)
    assert load_scenario("step-observer-model").plant == "observer"
    assert load_scenario("step-process-model").plant == "process"
    for name in packaged_scenario_names():
        assert load_scenario(name).source


def _problems(tmp_path: Path, text: str) -> list[str]:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    msgs = [str(p) for p in info.value.problems]
    assert all(str(path) in m for m in msgs)
    return msgs


@pytest.mark.parametrize(("old", "new", "key", "expected"), [
    ('plant = "process"', 'plant = "submarine"', "plant", "one of"),
    ("duration_s = 60.0", "duration_s = -1.0", "duration_s", "a positive number"),
    ("duration_s = 60.0", "duration_s = 60.0\nspeed = 2", "speed", "unknown keys are errors"),
    ("z = 1.05", 'z = "deep"', "initial.z", "a number"),
    ("t_s = 22.0", "t_s = 0.0", "reference[1].t_s", "a time after the previous reference"),
    ("end_s = 40.0", "end_s = 10.0", "dropout[0].end_s", "a time after start_s"),
    ("heave = 0.3", "heave = -0.3", "truth.bias_std.heave", "a number >= 0"),
    ("z = 1.05", 'z = { dist = "gamma", shape = 2 }', "initial.z.dist", "one of"),
    ("z = 1.05", 'z = { dist = "uniform", low = 2.0, high = 1.0 }', "initial.z.high", "a number >= low"),
    ("seed = 3", "seed = -3", "seed", "a non-negative integer"),
])
def test_each_bad_value_gets_its_message(tmp_path, old, new, key, expected):
    assert old in DROPOUT_TEXT
    msgs = _problems(tmp_path, DROPOUT_TEXT.replace(old, new, 1))
    hits = [m for m in msgs if f": {key}:" in m]
    assert hits, msgs
    assert expected in hits[0]


def test_distributions_draw_from_the_seed(tmp_path):
    text = DROPOUT_TEXT.replace("z = 1.05", 'z = { dist = "normal", mean = 1.05, std = 0.05 }').replace(
        "heading_deg = 52.0", 'heading_deg = { dist = "uniform", low = 40.0, high = 60.0 }')
    path = tmp_path / "mc.toml"
    path.write_text(text)
    a, b, c = load_scenario(path, seed=11), load_scenario(path, seed=11), load_scenario(path, seed=12)
    np.testing.assert_array_equal(a.initial, b.initial)
    assert a.initial[2] != c.initial[2]
    assert math.radians(40) <= a.initial[3] <= math.radians(60)
    zs = [load_scenario(path, seed=s).initial[2] for s in range(200)]
    assert np.mean(zs) == pytest.approx(1.05, abs=0.01) and np.std(zs) == pytest.approx(0.05, rel=0.2)


def test_unknown_scenario_name():
    with pytest.raises(ConfigError, match="packaged scenario name"):
        load_scenario("no-such-scenario")


# --------------------------------------------------------------------------------------------
# Issue 15 items 9 and 12: every problem at once, including those that need the referenced files;
# implausible values refused before anything runs.
# --------------------------------------------------------------------------------------------

def test_all_problems_of_a_scenario_at_once(tmp_path):
    text = (DROPOUT_TEXT.replace("seed = 3", "seed = -3")
            .replace("z = 1.05", 'z = { dist = "gamma" }')
            .replace('plant = "process"', 'plant = "submarine"')
            .replace("plant_step_s = 0.01", "plant_step_s = 0.03")
            .replace('sensor = "qualisys"', 'sensor = "sonar"')
            .replace('design = "thesis"', 'design = "no_such_config"'))
    msgs = _problems(tmp_path, text)
    keys = {m.split(": ")[1] for m in msgs}
    assert {"seed", "initial.z.dist", "plant", "design", "dropout[0].sensor"} <= keys, msgs
    text = DROPOUT_TEXT.replace("plant_step_s = 0.01", "plant_step_s = 0.03").replace(
        'sensor = "qualisys"', 'sensor = "qualisys.u"')
    msgs = _problems(tmp_path, text)
    assert any(": plant_step_s:" in m and "divides the filter's sample time 0.1 s" in m for m in msgs), msgs
    assert any(": dropout[0].sensor:" in m and "qualisys.psi" in m for m in msgs), msgs


@pytest.mark.parametrize(("old", "new", "key", "expected"), [
    ("plant_step_s = 0.01", "plant_step_s = 1e-308", "plant_step_s", "0.0001 .. 1"),
    ("plant_step_s = 0.01", "plant_step_s = 5e-324", "plant_step_s", "0.0001 .. 1"),
    ("plant_step_s = 0.01", "plant_step_s = 1e-9", "plant_step_s", "0.0001 .. 1"),
    ("duration_s = 60.0", "duration_s = 900000.0", "plant_step_s", "at most 1e+07 plant steps"),
    ("heave = 0.3", "heave = 1e15", "truth.bias_std.heave", "0 .. 1000"),
    ("z = 1.05", "z = 1e308", "initial.z", "-10000 .. 10000"),
    ("z = 0.70", "z = -1e308", "reference[0].z", "free surface"),  # above the surface: refused first
    ('name = "dropout"', 'name = "evil\\nname"', "name", "a name"),
])
def test_implausible_scenarios_are_refused(tmp_path, old, new, key, expected):
    assert old in DROPOUT_TEXT
    msgs = _problems(tmp_path, DROPOUT_TEXT.replace(old, new, 1))
    hits = [m for m in msgs if f": {key}:" in m]
    assert hits, msgs
    assert expected in hits[0]


def test_simulate_refuses_a_subnormal_plant_step_with_exit_2(tmp_path, capsys):
    from rovlab.interfaces.cli import main

    path = tmp_path / "tiny.toml"
    path.write_text(DROPOUT_TEXT.replace("plant_step_s = 0.01", "plant_step_s = 5e-324"), encoding="utf-8")
    assert main(["simulate", str(path), "--out", str(tmp_path / "out"), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert f"{path}: plant_step_s: got 5e-324" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
