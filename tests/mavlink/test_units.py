"""MAVLink units <-> SI at the edge (rovlab.interfaces.mavlink.units) and ArduSub's parameter table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.interfaces.mavlink.ardusub import Parameters
from rovlab.interfaces.mavlink.units import (
    depth_from_pressure,
    heading_deg,
    input_from_rc_pulse,
    inputs_from_manual_control,
    manual_control_from_inputs,
    pressure_hpa,
    rc_pulse_from_input,
)


def test_pressure_and_depth_round_trip():
    # 1 m of fresh water (rho 1000, g 9.81) is 9810 Pa = 98.1 hPa
    assert pressure_hpa(1.0, water_density=1000.0, gravity=9.81) == pytest.approx(1013.25 + 98.1)
    assert pressure_hpa(-0.3, water_density=1000.0, gravity=9.81) == pytest.approx(1013.25)  # in the air
    for z in (0.0, 0.5, 12.3):
        p = pressure_hpa(z, water_density=1025.0, gravity=9.81, surface_hpa=1000.0)
        assert depth_from_pressure(p, water_density=1025.0, gravity=9.81, surface_hpa=1000.0) == pytest.approx(z)
    for bad in (math.nan, math.inf, 0.0, -5.0):
        assert math.isnan(depth_from_pressure(bad, water_density=1000.0, gravity=9.81))


def test_heading_degrees():
    assert heading_deg(0.0) == 0
    assert heading_deg(math.pi / 2) == 90
    assert heading_deg(-math.pi / 2) == 270


def test_manual_control_follows_ardusubs_joystick_scaling():
    # ArduSub joystick.cpp: x -> 1500 + 0.4 gain x, read as (pulse - 1500) / 400 = gain x / 1000
    np.testing.assert_allclose(inputs_from_manual_control(1000, -500, 500, 0, gain=0.5), [0.5, -0.25, 0.0, 0.0])
    np.testing.assert_allclose(inputs_from_manual_control(0, 0, 1000, -1000, gain=1.0), [0.0, 0.0, 1.0, -1.0])
    np.testing.assert_allclose(inputs_from_manual_control(0, 0, 0, 0, gain=0.5, throttle_gain=2.0),
                               [0.0, 0.0, -1.0, 0.0])


@pytest.mark.parametrize("gain, thr", [(1.0, 1.0), (0.5, 1.0), (0.8, 1.5)])
def test_manual_control_inverse(gain, thr):
    u = np.array([0.2, -0.3, 0.4, -0.1]) * gain
    x, y, z, r = manual_control_from_inputs(u, gain=gain, throttle_gain=thr)
    np.testing.assert_allclose(inputs_from_manual_control(x, y, z, r, gain=gain, throttle_gain=thr), u, atol=2e-3)


def test_manual_control_saturates_to_the_message_ranges():
    assert manual_control_from_inputs(np.array([1.0, -1.0, 1.0, 1.0]), gain=0.5) == (1000, -1000, 1000, 1000)
    assert manual_control_from_inputs(np.zeros(4), gain=0.5) == (0, 0, 500, 0)
    with pytest.raises(ValueError, match="finite"):
        manual_control_from_inputs(np.array([math.nan, 0, 0, 0]), gain=1.0)


def test_rc_pulses():
    assert input_from_rc_pulse(1900) == 1.0
    assert input_from_rc_pulse(1300) == -0.5
    assert input_from_rc_pulse(2500) == 1.0
    assert rc_pulse_from_input(-0.25) == 1400


def test_parameters_refuse_bad_values_and_change_nothing():
    p = Parameters()
    assert p.set("JS_GAIN_DEFAULT", 0.8) is None and p["JS_GAIN_DEFAULT"] == 0.8
    assert "outside" in p.set("JS_GAIN_DEFAULT", 7.0)
    assert "finite" in p.set("JS_GAIN_DEFAULT", math.nan)
    assert "read-only" in p.set("MOT_PWM_MIN", 1000)
    assert "unknown" in p.set("NOPE", 1)
    assert p["JS_GAIN_DEFAULT"] == 0.8
    assert p.set("SYSID_MYGCS", 254.6) is None and p["SYSID_MYGCS"] == 255.0  # integers are rounded
    assert all(len(s.name) <= 16 for s in p.specs)
