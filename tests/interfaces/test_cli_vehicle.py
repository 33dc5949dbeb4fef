"""Command-line contract of issue 2: vehicle show/check, thruster, allocate."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rovlab.interfaces.cli import main
from rovlab.params.vehicle import packaged_vehicle_path


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_vehicle_show_json(capsys):
    code, out, _ = run(capsys, "vehicle", "show", "udrone", "--json")
    data = json.loads(out)
    assert code == 0
    assert data["name"] == "udrone" and data["mass"] == 7.31
    assert data["thrusters"] == ["T1", "T2", "T3", "T4", "T5", "T6"]
    B = np.array(data["configuration_matrix"])
    assert B.shape == (6, 6) and B[4, 2] == pytest.approx(-0.199)


def test_vehicle_show_default_and_human(capsys):
    code, out, _ = run(capsys, "vehicle", "show")
    assert code == 0 and "udrone" in out and "configuration matrix" in out


def test_vehicle_check_ok_and_bad(capsys, tmp_path):
    code, out, _ = run(capsys, "vehicle", "check", str(packaged_vehicle_path("bluerov2_heavy")))
    assert code == 0 and "ok" in out
    bad = tmp_path / "bad.toml"
    bad.write_text(packaged_vehicle_path("udrone").read_text().replace("mass = 7.31", "mass = -7.31")
                   .replace("X_udot = -5.50", "X_udot = 5.50"))
    code, out, _ = run(capsys, "vehicle", "check", str(bad))
    assert code == 2
    assert "2 problems" in out and "rigid_body.mass" in out and "added_mass.X_udot" in out


def test_vehicle_show_bad_file_is_a_clean_error(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 3\n")
    code, _, err = run(capsys, "vehicle", "show", str(bad))
    assert code == 2 and "Traceback" not in err and "name" in err


def test_thruster_round_trip(capsys):
    code, out, _ = run(capsys, "thruster", "--thruster", "T1", "--force", "5", "--json")
    pwm = json.loads(out)["pwm_us"]
    code, out, _ = run(capsys, "thruster", "--thruster", "T1", "--pwm", str(pwm), "--json")
    assert json.loads(out)["force"] == pytest.approx(5.0, abs=1e-9)


def test_thruster_voltage_for_table_model(capsys):
    code, out12, _ = run(capsys, "thruster", "--vehicle", "bluerov2_heavy", "--thruster", "T1", "--pwm", "1800",
                         "--voltage", "12", "--json")
    code, out20, _ = run(capsys, "thruster", "--vehicle", "bluerov2_heavy", "--thruster", "T1", "--pwm", "1800",
                         "--voltage", "20", "--json")
    assert json.loads(out20)["force"] > json.loads(out12)["force"] > 0
    code, _, err = run(capsys, "thruster", "--thruster", "T1", "--pwm", "1600", "--voltage", "12")
    assert code == 2 and "tabulated" in err
    code, _, err = run(capsys, "thruster", "--thruster", "T9", "--pwm", "1600")
    assert code == 2 and "no thruster 'T9'" in err


def test_allocate_json_contract(capsys):
    code, out, _ = run(capsys, "allocate", "--wrench", "0", "0", "10", "0", "--json")
    data = json.loads(out)
    assert set(data) >= {"forces", "pwm_us", "achieved", "saturated"}
    np.testing.assert_allclose(data["forces"], [-2.83, -2.83, -4.35, 0, 0, 0], atol=5e-3)
    assert data["saturated"] is False
    code, out, _ = run(capsys, "allocate", "--wrench", "0", "0", "200", "0", "--json")
    assert json.loads(out)["saturated"] is True


def test_allocate_unconstrained_reports_forces_beyond_limits(capsys):
    # 200 N down on uDrone: the plain inverse asks T3 for far more than its -13.0 N reverse limit
    code, out, _ = run(capsys, "allocate", "--wrench", "0", "0", "200", "0", "--mode", "unconstrained", "--json")
    data = json.loads(out)
    assert code == 0 and data["saturated"] is True
    assert "T3" in data["over_limit"]
    assert data["forces"][2] < -13.0  # not clipped: the pseudo-inverse as it is
    np.testing.assert_allclose(data["achieved"], [0, 0, 200, 0, 0, 0], atol=1e-9)
    code, out, _ = run(capsys, "allocate", "--wrench", "0", "0", "200", "0", "--mode", "unconstrained")
    assert "beyond the thrust limits: T1, T2, T3" in out
    code, out, _ = run(capsys, "allocate", "--wrench", "0", "0", "10", "0", "--mode", "unconstrained", "--json")
    assert json.loads(out)["over_limit"] == [] and json.loads(out)["saturated"] is False


def test_allocate_bad_input(capsys):
    code, _, err = run(capsys, "allocate", "--wrench", "1", "2", "3")
    assert code == 2 and "4 values" in err
    code, _, err = run(capsys, "allocate", "--wrench", "1", "2", "nan", "4")
    assert code == 2 and "finite" in err
