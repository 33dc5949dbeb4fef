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
