"""Numbers printed with the right unit and sign (issue 28, a new user): ``rovlab design`` gave
a yaw-rate sensor's variance in m^2, ``rovlab vehicle show`` printed "net -0.98 N (up)" for a
vehicle that sinks, and ``rovlab identify noise`` printed its table without units."""

from __future__ import annotations

import json

import pytest

from rovlab.core.units import squared, unit
from rovlab.interfaces.cli import main
from rovlab.params.vehicle import load_vehicle


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_squared_units():
    assert [squared(unit(q)) for q in ("z", "psi", "w", "r", "b_N")] == \
        ["m^2", "rad^2", "m^2/s^2", "rad^2/s^2", "N^2 m^2"]
    assert unit("nonsense", "?") == "?" and squared("") == ""


def test_design_gives_each_measurement_variance_in_its_own_unit(capsys):
    # bluerov2_heavy's configuration fuses the IMU's yaw rate (imu.r): its variance is in rad^2/s^2
    code, out, _ = run(capsys, "design", "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy")
    assert code == 0
    rows = {line.split()[0]: line for line in out.splitlines() if " column " in line and "variance" in line}
    assert "rad^2/s^2" in rows["imu.r"] and "m^2" not in rows["imu.r"]
    assert " rad^2 " in rows["imu.psi"] and " m^2 " in rows["bar30.z"]


@pytest.mark.parametrize("vehicle, words", [("udrone", "+6.67 N: floats up"), ("bluerov2_heavy", "-0.98 N: sinks")])
def test_vehicle_show_says_whether_it_sinks(capsys, vehicle, words):
    v = load_vehicle(vehicle)
    code, out, _ = run(capsys, "vehicle", "show", vehicle)
    assert code == 0
    line = next(line for line in out.splitlines() if "buoyancy" in line)
    assert "B - W" in line and words in line
    assert ("floats" in line) == (v.buoyancy > v.weight)  # SNAME/NED: W - B > 0 pulls it down (+z): it sinks
    code, out, _ = run(capsys, "vehicle", "show", vehicle, "--json")
    assert json.loads(out)["net_buoyancy"] == pytest.approx(v.buoyancy - v.weight)


def test_identify_noise_table_has_units(capsys, tmp_path):
    log = tmp_path / "rest.csv"
    assert main(["lab", "noise", "--vehicle", "bluerov2_heavy", "--seed", "5", "--out", str(log)]) == 0
    capsys.readouterr()
    code, out, _ = run(capsys, "identify", "noise", str(log), "--no-plot")
    assert code == 0
    rows = {line.split()[0]: line for line in out.splitlines()[2:] if line.startswith("  ")}
    assert rows, out
    for column, line in rows.items():
        quantity = column.split("_")[0]
        u = unit(quantity)
        assert u, column
        # variance and its interval in the unit squared, the standard deviation in the unit
        assert line.count(f" {squared(u)}") == 2 and f" {u} " in line, line
    code, out, _ = run(capsys, "identify", "noise", str(log), "--no-plot", "--json")
    units = json.loads(out)["units"]
    assert units == {c: unit(c.split("_")[0]) for c in rows}
