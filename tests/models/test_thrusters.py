"""Thruster curves (Sandøy 2016, eq. 2.5 and table 2.2): dead band, exact inverse, saturation, T200 tables
(Blue Robotics T200 data)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.models.thrusters import (
    KGF,
    ThrusterBank,
    force_from_pwm,
    pwm_from_force,
    t200_force_table,
    t200_raw_table,
    thrust_limits,
)


def test_dead_band_gives_no_thrust(udrone):
    t = udrone.thruster("T1")
    for pwm in np.linspace(1475, 1525, 51):
        assert force_from_pwm(t, pwm) == 0.0
    assert force_from_pwm(t, 1526) > 0 and force_from_pwm(t, 1474) < 0


def test_curve_values_from_the_thesis_formula(udrone):
    # Sandøy 2016, eq. 2.5 and table 2.2, T1: f = K_L+ (u-d) + K_NL+ (u-d)^2 for u > d
    t = udrone.thruster("T1")
    s = 1650 - 1500 - 25
    assert force_from_pwm(t, 1650) == pytest.approx(6.07e-2 * s + 3.33e-4 * s**2, rel=1e-15)
    s = 1350 - 1500 + 25
    assert force_from_pwm(t, 1350) == pytest.approx(3.28e-2 * s - 3.68e-4 * s**2, rel=1e-15)
    assert pwm_from_force(t, 0.0) == 1500.0


def test_round_trip_force_pwm_force_over_whole_range(udrone):
    """Exact inverse of eq. 2.5 (the thesis's eq. 2.6 is garbled, an erratum): force -> PWM -> force within 1e-9 N
    everywhere in the range."""
    for t in udrone.thrusters:
        lo, hi = thrust_limits(t)
        for f in np.linspace(lo, hi, 2001):
            assert abs(force_from_pwm(t, pwm_from_force(t, f)) - f) < 1e-9


def test_round_trip_pwm_force_pwm_outside_dead_band(udrone):
    t = udrone.thruster("T4")
    for pwm in np.concatenate([np.linspace(1300, 1474.9, 300), np.linspace(1525.1, 1700, 300)]):
        assert pwm_from_force(t, force_from_pwm(t, pwm)) == pytest.approx(pwm, abs=1e-9)


def test_commands_saturate_to_pwm_range(udrone):
    t = udrone.thruster("T3")  # uDrone: 1300-1700 us as in the thesis
    lo, hi = thrust_limits(t)
    assert pwm_from_force(t, 1e3) == 1700.0 and pwm_from_force(t, -1e3) == 1300.0
    assert force_from_pwm(t, 1900) == hi and force_from_pwm(t, 1100) == lo
    assert lo < 0 < hi and abs(lo) < hi  # reverse is weaker


def test_t200_table_matches_maker_data():
    # Blue Robotics T200 public data (Sept 2019), 16 V: 5.25 kgf at 1900 us, -4.07 kgf at 1100 us
    pwm, force = t200_raw_table(16)
    assert force[-1] == pytest.approx(5.25 * KGF) and force[0] == pytest.approx(-4.07 * KGF)
    table = t200_force_table(16.0)
    assert table[-1] == pytest.approx(5.25 * KGF)
    # monotone outwards from neutral, zero in the dead band
    mid = np.searchsorted(pwm, 1500)
    assert np.all(np.diff(table[mid:]) >= 0) and np.all(np.diff(table[: mid + 1]) >= 0)
    assert table[mid] == 0.0


def test_t200_interpolates_in_voltage():
    # away from the ends (where the maker's data is made monotone) it is the mean of 14 V and 16 V
    f15 = t200_force_table(15.0)[25:-25]
    np.testing.assert_allclose(f15, 0.5 * (t200_force_table(14.0) + t200_force_table(16.0))[25:-25], atol=1e-12)
    with pytest.raises(ValueError, match="10-20 V"):
        t200_force_table(24.0)


def test_tabulated_thruster_round_trip(heavy):
    bank = ThrusterBank.from_vehicle(heavy)
    assert bank.f_max[0] == pytest.approx(5.25 * KGF)  # 16 V, 1900 us
    forces = np.linspace(bank.f_min[0], bank.f_max[0], 8)
    back = bank.force(bank.pwm(forces))
    np.testing.assert_allclose(back, forces, atol=1e-9)


def test_bank_rejects_wrong_shapes_and_nan(udrone):
    bank = ThrusterBank.from_vehicle(udrone)
    with pytest.raises(ValueError, match="6 values"):
        bank.pwm(np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        bank.force(np.array([1500, 1500, np.nan, 1500, 1500, 1500]))


# --------------------------------------------------------------------------------------------
# A cut dead band (deadband_kind = "cut"): ArduSub SITL's thruster model
# --------------------------------------------------------------------------------------------

def _cut(thruster, **curve):
    """A thruster as given, its dead band cut (and its curve replaced by ``curve``'s coefficients if given)."""
    from dataclasses import replace

    from rovlab.params.vehicle import QuadraticCurve

    if curve:
        thruster = replace(thruster, curve=QuadraticCurve(**curve))
    return replace(thruster, deadband_kind="cut")


def test_cut_dead_band_is_sitls_thruster():
    """ArduPilot libraries/SITL/SIM_Submarine.cpp (calculate_forces, V4.7.0-dev): an integer pulse within
    1475..1525 us gives no thrust; outside it thrust = 51.48 N x o|o| with o = (pwm - 1500) / 400 -- the whole
    offset, not the offset beyond the band's edge."""
    from rovlab.params.vehicle import load_vehicle

    t = load_vehicle("ardusub_sitl_heavy").thruster("T5")  # a vertical: 51.48 N / (400 us)^2 along its axis
    assert t.deadband_kind == "cut" and t.deadband_us == 25.0
    for pwm in range(1475, 1526):
        assert force_from_pwm(t, pwm) == 0.0
    for pwm in (1100, 1300, 1474, 1526, 1530, 1540, 1700, 1900):
        o = (pwm - 1500) / 400
        assert force_from_pwm(t, pwm) == pytest.approx(51.48 * o * abs(o), rel=1e-12), pwm
    assert force_from_pwm(t, 1526) == pytest.approx(0.2175, abs=1e-4)  # the header's jump at 26 us
    # the shifted band with the same coefficients is 0.2175 N short at 1550 us instead (what rovlab had)
    from dataclasses import replace

    assert force_from_pwm(t, 1550) - force_from_pwm(replace(t, deadband_kind="shift"), 1550) == pytest.approx(
        51.48 * ((50 / 400) ** 2 - (25 / 400) ** 2), rel=1e-12)


@pytest.mark.parametrize("curve", [None, {"K_L_pos": 6.07e-2, "K_NL_pos": 3.33e-4, "K_L_neg": 3.28e-2,
                                          "K_NL_neg": 3.68e-4}])  # SITL's pure square law; uDrone T1's asymmetric fit
def test_cut_round_trips_outside_the_gap(curve):
    from rovlab.params.vehicle import load_vehicle

    t = load_vehicle("ardusub_sitl_heavy").thruster("T1")
    t = _cut(t, **curve) if curve else t
    lo, hi = thrust_limits(t)
    least_pos, least_neg = force_from_pwm(t, 1526.0), -force_from_pwm(t, 1474.0)
    for f in np.concatenate([np.linspace(lo, -least_neg, 1001), np.linspace(least_pos, hi, 1001)]):
        assert abs(force_from_pwm(t, pwm_from_force(t, f)) - f) < 1e-9 * max(1.0, abs(f))
    for pwm in np.concatenate([np.linspace(1100, 1474, 300), np.linspace(1526, 1900, 300)]):
        assert pwm_from_force(t, force_from_pwm(t, pwm)) == pytest.approx(pwm, abs=1e-9)
    assert pwm_from_force(t, 0.0) == 1500.0


@pytest.mark.parametrize("curve", [None, {"K_L_pos": 6.07e-2, "K_NL_pos": 3.33e-4, "K_L_neg": 3.28e-2,
                                          "K_NL_neg": 3.68e-4}])
def test_cut_rounds_a_demand_in_the_gap_to_the_nearer_force(curve):
    """A demand smaller than the least thrust outside the band (at its edge + 1 us) is commanded as whichever
    of neutral (0 N) and the edge + 1 us is nearer in force: neutral below half the least thrust, the edge + 1 us
    from half on; the same on the reverse side with its own coefficients."""
    from rovlab.params.vehicle import load_vehicle

    t = load_vehicle("ardusub_sitl_heavy").thruster("T5")
    t = _cut(t, **curve) if curve else t
    for sign, edge in ((1.0, 1526.0), (-1.0, 1474.0)):
        least = abs(force_from_pwm(t, edge))
        assert least > 0.0
        for frac in (1e-6, 0.1, 0.3, 0.4999):
            assert pwm_from_force(t, sign * frac * least) == 1500.0, (sign, frac)
        for frac in (0.5, 0.6, 0.9, 0.999999):
            assert pwm_from_force(t, sign * frac * least) == edge, (sign, frac)
            # the error in force is never more than half the least thrust
            assert abs(force_from_pwm(t, edge) - sign * frac * least) <= 0.5 * least
        assert pwm_from_force(t, sign * least) == pytest.approx(edge, abs=1e-9)  # from here on the exact root


def test_compiled_and_plain_kernels_agree_on_every_kind():
    """The cut next to the shifted quadratic and the T200 table, plain kernels against numba's, forward, inverse
    and the inverse with the dead band's hysteresis (rovlab.models.thruster_kernels)."""
    from rovlab.models import thruster_kernels as tk
    from rovlab.models import thrusters as th
    from rovlab.params.vehicle import load_vehicle

    sitl, udrone, heavy = (load_vehicle(n) for n in ("ardusub_sitl_heavy", "udrone", "bluerov2_heavy"))
    thrusters = [sitl.thruster("T1"), sitl.thruster("T5"), udrone.thruster("T1"), heavy.thruster("T1"),
                 _cut(udrone.thruster("T4"))]
    bank = ThrusterBank.from_thrusters(thrusters)
    assert bank.rows[:, tk.K_KIND].tolist() == [tk.KIND_CUT, tk.KIND_CUT, tk.KIND_QUADRATIC, tk.KIND_TABLE,
                                                tk.KIND_CUT]
    rng = np.random.default_rng(30)
    n = len(thrusters)
    pwm = np.concatenate([rng.uniform(1100, 1900, (300, n)), rng.integers(1470, 1531, (300, n)).astype(float)])
    force = np.concatenate([rng.normal(0.0, 5.0, (300, n)), rng.normal(0.0, 0.3, (300, n))])
    for p in pwm:
        np.testing.assert_array_equal(bank.force(p), bank.force(p, compiled=False))
    for f in force:
        np.testing.assert_array_equal(bank.pwm(f), bank.pwm(f, compiled=False))
    hold = th.bank_pwm_hold_into  # compiled
    state = [(np.zeros(n), np.zeros(n)), (np.zeros(n), np.zeros(n))]
    for f in force:
        outs = []
        for kernel, (side, sum_f) in zip((hold, tk.bank_pwm_hold_into), state):
            ff, out = f.copy(), np.empty(n)
            kernel(bank.rows, bank.grid_pwm, bank.grid_force, ff, side, sum_f, 20.0, out)
            outs.append((out, ff))
        np.testing.assert_array_equal(outs[0][0], outs[1][0])
        np.testing.assert_array_equal(outs[0][1], outs[1][1])
    np.testing.assert_array_equal(state[0][0], state[1][0])


def test_cut_hysteresis_waits_at_its_own_edge_then_crosses():
    """bank_pwm_hold_into on a cut band: a thruster pushing forward that gets a small reverse demand (its inverse:
    1474 us, 1 us beyond the reverse edge) waits at 1525 us (its own edge: no thrust, force reported 0) until the
    summed reverse demand needs 20 us beyond 1475 us; a demand in the gap below half the least thrust is short
    of the edge and waits too."""
    from rovlab.models import thruster_kernels as tk
    from rovlab.params.vehicle import load_vehicle

    bank = ThrusterBank.from_thrusters([load_vehicle("ardusub_sitl_heavy").thruster("T5")])
    side, sum_f, out = np.zeros(1), np.zeros(1), np.empty(1)
    least = -float(bank.force(np.array([1474.0]), compiled=False)[0])

    def step(f: float) -> tuple[float, float]:
        ff = np.array([f])
        tk.bank_pwm_hold_into(bank.rows, bank.grid_pwm, bank.grid_force, ff, side, sum_f, 20.0, out)
        return float(out[0]), float(ff[0])

    assert step(1.0)[0] > 1526.0 and side[0] == 1.0
    assert step(-0.3 * least) == (1525.0, 0.0)  # rounds to neutral: short of the reverse edge
    pwm_cross = float(bank.pwm(np.array([-1.0]), compiled=False)[0])
    crossed_after = None
    for k in range(1, 200):
        pwm, given = step(-1.05 * least)
        if pwm < 1475.0:
            crossed_after = k
            break
        assert (pwm, given) == (1525.0, 0.0)
    # crosses once the sum needs >= 20 us beyond 1475 us: a sum of f(1455 us) = 51.48 (45/400)^2 = 0.65 N
    need = 51.48 * (45 / 400) ** 2
    assert crossed_after is not None and crossed_after == int(np.ceil((need - 0.3 * least) / (1.05 * least)))
    assert side[0] == -1.0 and pwm_cross < 1475.0
    # without the hysteresis the same demand is the plain inverse at once
    side[:] = 1.0
    sum_f[:] = 0.0
    ff = np.array([-1.05 * least])
    tk.bank_pwm_hold_into(bank.rows, bank.grid_pwm, bank.grid_force, ff, side, sum_f, 0.0, out)
    assert out[0] == float(bank.pwm(np.array([-1.05 * least]), compiled=False)[0]) < 1475.0


def test_every_other_packaged_vehicle_keeps_its_shifted_dead_band():
    """deadband_kind defaults to "shift": no packaged vehicle but SITL's changes kind or numbers (uDrone's curve
    values are held to the thesis above)."""
    from rovlab.models import thruster_kernels as tk
    from rovlab.params import load_vehicle, packaged_vehicle_names

    for name in packaged_vehicle_names():
        v = load_vehicle(name)
        kinds = {t.deadband_kind for t in v.thrusters}
        rows = ThrusterBank.from_vehicle(v).rows[:, tk.K_KIND]
        if name in ("ardusub_sitl_heavy", "ardusub_sitl_heavy_gps"):  # SITL's sub (and with EKF3's position, for DP)
            assert kinds == {"cut"} and np.all(rows == tk.KIND_CUT)
        else:
            assert kinds == {"shift"}, name
            assert np.all((rows == tk.KIND_QUADRATIC) | (rows == tk.KIND_TABLE)), name


def test_a_fitted_curve_written_onto_a_cut_thruster_makes_it_shifted(tmp_path):
    """rovlab identify thrust --update writes the shifted fit (rovlab.ident.thrust): its dead band shifts the
    curve, so a thruster that had a cut one loses deadband_kind rather than keeping a cut with a shifted fit."""
    import shutil

    from rovlab.ident.thrust import fit_thrust_curve, thrust_edits
    from rovlab.params.edit import edit_vehicle_file
    from rovlab.params.vehicle import load_vehicle, packaged_vehicle_path

    path = tmp_path / "sitl.toml"
    shutil.copy(packaged_vehicle_path("ardusub_sitl_heavy"), path)
    t = load_vehicle(path).thruster("T5")
    pwm = np.concatenate([np.arange(1100.0, 1470.0, 10.0), np.arange(1540.0, 1901.0, 10.0)])
    fit = fit_thrust_curve(pwm, np.array([force_from_pwm(t, p) for p in pwm]))
    v = edit_vehicle_file(path, thrust_edits(fit, ["T5"]))
    assert v.thruster("T5").deadband_kind == "shift" and v.thruster("T6").deadband_kind == "cut"
    assert "deadband_kind" in path.read_text().split('name = "T6"')[1].split("[[")[0]
