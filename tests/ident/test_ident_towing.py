"""Towing damping (Sandøy 2016, sec. 4.3.1): virtual carriage -> identify -> SNAME coefficients.

Tolerances, as measured over many seeds with the lab's default noise (0.15 N load cell, 10 runs):
the damping force D(v) is recovered within 5 % at every towed speed; the individual linear,
quadratic and cubic coefficients of a three-term fit are strongly correlated over 0.1-0.5 m/s, so
each is checked against its own reported standard error (within 3.5 sigma), and within 5 % when
the data are noise-free or when only two terms are fitted.
"""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.ident import IdentificationError, lab, towing
from rovlab.io.tables import DataTable
from rovlab.params.vehicle import DOF4

TERMS = ("linear", "quadratic", "cubic")
SPEEDS = np.concatenate([np.linspace(-0.5, -0.1, 5), np.linspace(0.1, 0.5, 5)])


def _truth_curve(vehicle, dof, v):
    i = DOF4.index(dof)
    return (vehicle.damping_linear[i] * v + vehicle.damping_quadratic[i] * np.abs(v) * v
            + vehicle.damping_cubic[i] * v**3)


def test_noise_free_runs_recover_every_coefficient(lab_table, udrone_vehicle):
    veh, rig = lab.towing_runs(udrone_vehicle, "surge", seed=1, noise_std_n=0.0, speed_noise_mps=0.0,
                               offset_std_n=0.5)  # offsets stay: the tare must remove them
    fit = towing.identify_towing(lab_table(veh), lab_table(rig), dof="surge")
    # Sandøy 2016, table 4.6: X_u = -4.03, X_|u|u = -18.18, X_uuu = -24.24
    assert fit.linear == pytest.approx(-4.03, rel=0.01)
    assert fit.quadratic == pytest.approx(-18.18, rel=0.01)
    assert fit.cubic == pytest.approx(-24.24, rel=0.01)
    assert all(p.tare != 0 for p in fit.points)


@pytest.mark.parametrize("vehicle_name, dof, seed", [
    ("udrone_vehicle", "surge", 101), ("udrone_vehicle", "sway", 102), ("udrone_vehicle", "heave", 103),
    ("modified_udrone", "surge", 104), ("modified_udrone", "heave", 105),
])
def test_round_trip_damping_within_5_percent(request, lab_table, vehicle_name, dof, seed):
    vehicle = request.getfixturevalue(vehicle_name)
    veh, rig = lab.towing_runs(vehicle, dof, seed=seed)
    fit = towing.identify_towing(lab_table(veh), lab_table(rig), dof=dof)
    truth = _truth_curve(vehicle, dof, SPEEDS)
    np.testing.assert_allclose(fit.damping_force(SPEEDS), truth, rtol=0.05)
    i = DOF4.index(dof)
    for term, arr in zip(TERMS, (vehicle.damping_linear, vehicle.damping_quadratic, vehicle.damping_cubic)):
        assert abs(getattr(fit, term) - arr[i]) < 3.5 * fit.stderr[term], term
        assert getattr(fit, term) < 0, "SNAME: damping derivatives are negative"
    assert len(fit.points) == 10 and len(fit.rig_points) == 10


def test_rig_drag_must_be_subtracted(lab_table, udrone_vehicle):
    veh, rig = lab.towing_runs(udrone_vehicle, "surge", seed=7, rig_quadratic=-15.0)
    with_rig = towing.identify_towing(lab_table(veh), lab_table(rig))
    without = towing.identify_towing(lab_table(veh))
    truth = _truth_curve(udrone_vehicle, "surge", SPEEDS)
    np.testing.assert_allclose(with_rig.damping_force(SPEEDS), truth, rtol=0.05)
    assert np.max(np.abs(without.damping_force(SPEEDS) / truth - 1)) > 0.2


def test_two_term_fit_for_a_vehicle_without_cubic_damping(lab_table, heavy_vehicle):
    # von Benzon et al. 2022 (bluerov2_heavy.toml): X_u = -13.7, X_|u|u = -141, no cubic term
    for seed in (201, 202):
        veh, rig = lab.towing_runs(heavy_vehicle, "surge", seed=seed)
        fit = towing.identify_towing(lab_table(veh), lab_table(rig), terms=("linear", "quadratic"))
        assert fit.terms == ("linear", "quadratic")
        assert fit.linear == pytest.approx(-13.7, rel=0.05)
        assert fit.quadratic == pytest.approx(-141.0, rel=0.05)
        assert fit.cubic == 0.0 and fit.stderr["cubic"] == 0.0


def test_heave_buoyancy_offset_is_tared(lab_table, udrone_vehicle):
    # uDrone is 6.7 N buoyant (B - W from Sandøy 2016, table 4.1): the rig holds that at rest; the tare removes it
    veh, rig = lab.towing_runs(udrone_vehicle, "heave", seed=9, offset_std_n=0.0)
    fit = towing.identify_towing(lab_table(veh), lab_table(rig), dof="heave")
    net = udrone_vehicle.buoyancy - udrone_vehicle.weight
    assert np.mean([p.tare for p in fit.points]) == pytest.approx(net, abs=0.05)
    untared = towing.identify_towing(lab_table(veh), lab_table(rig), tare=False)
    assert untared.rms > 10 * fit.rms


def test_sign_convention_positive_force_at_positive_speed_is_negative_damping():
    t = np.arange(0, 30, 0.05)
    runs = []
    for k, v in enumerate((0.1, 0.2, 0.3, 0.4, -0.2), start=1):
        speed = np.where((t > 5) & (t < 25), v, 0.0)
        runs.append((k, t, speed, 10.0 * speed))  # the rig pushes forward to tow forward
    pts = towing.steady_points(runs)
    fit = towing.fit_steady_damping(pts, terms=("linear",))
    assert fit.linear == pytest.approx(-10.0, rel=1e-6)


def _table(rows: dict[str, list[float]]) -> DataTable:
    data = {k: np.asarray(v, float) for k, v in rows.items()}
    n = len(next(iter(data.values())))
    return DataTable("runs.csv", tuple(data), data, np.arange(2, n + 2))


def test_too_few_runs_is_a_clear_error(udrone_vehicle):
    veh, _ = lab.towing_runs(udrone_vehicle, "surge", seed=3, speeds=(0.1, 0.2, 0.3))
    cols = {k: list(v) for k, v in veh.columns.items()}
    with pytest.raises(IdentificationError, match=r"needs at least 4 runs.*got 3 \(runs 1, 2, 3\)"):
        towing.identify_towing(_table(cols))


def test_a_run_that_never_moves_is_named():
    t = np.arange(0, 20, 0.05).tolist()
    table = _table({"run": [4] * len(t), "time_s": t, "speed_mps": [0.0] * len(t), "force_n": [0.0] * len(t)})
    with pytest.raises(IdentificationError, match="run 4: the run never leaves rest"):
        towing.identify_towing(table)


def test_rig_runs_must_cover_the_vehicle_speeds(lab_table, udrone_vehicle):
    veh, _ = lab.towing_runs(udrone_vehicle, "surge", seed=4)
    _, rig = lab.towing_runs(udrone_vehicle, "surge", seed=4, speeds=(0.1, -0.1, 0.2, -0.2, 0.3))
    with pytest.raises(IdentificationError, match="outside it"):
        towing.identify_towing(lab_table(veh), lab_table(rig))


def test_missing_column_names_the_file():
    from rovlab.params import ConfigError

    table = _table({"run": [1.0], "time_s": [0.0], "speed": [0.0], "force_n": [0.0]})
    with pytest.raises(ConfigError, match=r"runs.csv: header.*missing: speed_mps"):
        towing.identify_towing(table)


def test_absent_term_that_comes_out_positive_is_pinned_at_zero(lab_table, heavy_vehicle):
    # bluerov2_heavy has Y_v = 0 (von Benzon 2022): with this seed the linear term comes out at
    # +0.06 +- 0.05, which the vehicle file would refuse (SNAME damping <= 0). It is fixed at 0,
    # the quadratic term refitted, and the fit says so.
    veh, rig = lab.towing_runs(heavy_vehicle, "sway", seed=2)
    fit = towing.identify_towing(lab_table(veh), lab_table(rig), terms=("linear", "quadratic"), dof="sway")
    assert fit.linear == 0.0 and set(fit.pinned) == {"linear"}
    estimate, se = fit.pinned["linear"]
    assert 0.0 < estimate <= 3.0 * se
    assert fit.quadratic == pytest.approx(heavy_vehicle.damping_quadratic[1], rel=0.01)
    assert fit.as_dict()["pinned_at_zero"] == {"linear": [estimate, se]}
    edits = towing.damping_edits(fit, "sway")
    assert all(value <= 0.0 for value in edits.values())
