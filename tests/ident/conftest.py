"""Fixtures of the identification tests: vehicles with known truth and a lab-file round trip."""

from __future__ import annotations

import dataclasses

import pytest

from rovlab.ident.lab import LabData, write_lab_data
from rovlab.io.tables import DataTable, read_table
from rovlab.params import load_vehicle
from rovlab.params.vehicle import QuadraticCurve, packaged_vehicle_names


@pytest.fixture(scope="session")
def udrone_vehicle():
    return load_vehicle("udrone")


@pytest.fixture(scope="session")
def heavy_vehicle():
    if "bluerov2_heavy" not in packaged_vehicle_names():  # pragma: no cover - added by another change
        pytest.skip("bluerov2_heavy is not packaged")
    return load_vehicle("bluerov2_heavy")


@pytest.fixture(scope="session")
def modified_udrone(udrone_vehicle):
    """uDrone with every identifiable parameter changed (different mass, hydrodynamics, curves)."""
    v = udrone_vehicle
    curve = QuadraticCurve(K_L_pos=4.5e-2, K_NL_pos=2.9e-4, K_L_neg=2.6e-2, K_NL_neg=3.1e-4)
    thrusters = tuple(dataclasses.replace(t, curve=curve, deadband_us=32.0) for t in v.thrusters)
    return v.with_updates(
        name="udrone_modified", mass=9.2, I_zz=0.21,
        added_mass=[-7.1, -10.4, -17.9, -0.16],
        damping_linear=[-6.5, -8.0, -4.1, -0.11],
        damping_quadratic=[-25.0, -30.0, -44.0, -1.1],
        damping_cubic=[-12.0, -60.0, -80.0, -0.3],
        thrusters=thrusters)


@pytest.fixture
def lab_table(tmp_path):
    """Write a LabData to CSV and read it back as the tools would (exercises the file format)."""
    counter = {"n": 0}

    def make(data: LabData) -> DataTable:
        counter["n"] += 1
        path = tmp_path / f"{data.experiment.split()[0]}-{counter['n']}.csv"
        write_lab_data(path, data)
        return read_table(path)

    return make



@pytest.fixture(autouse=True)
def _work_in_tmp(tmp_path, monkeypatch):
    """`identify` writes its figure into the working directory (issue 15): keep it out of the repo."""
    monkeypatch.chdir(tmp_path)
