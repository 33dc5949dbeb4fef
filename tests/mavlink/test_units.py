"""MAVLink units <-> SI at the edge (rovlab.interfaces.mavlink.units) and ArduSub's parameter table."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.interfaces.mavlink.ardusub import (
    PARAM_INT8,
    PARAM_INT16,
    PARAM_REAL32,
    Parameters,
    boot_gain,
    sim_parameters,
    stepped_gain,
)
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
    assert p.set("MAV_GCS_SYSID", 254.6) is None and p["MAV_GCS_SYSID"] == 255.0  # integers are rounded
    assert all(len(s.name) <= 16 for s in p.specs)


def test_two_generations_of_parameter_names_with_ardusubs_defaults_and_types():
    """Defaults and MAV_PARAM_TYPEs as a BlueROV2 Heavy on ArduSub 4.1.1 reports them in its PARAM_VALUE
    stream (../shared/data/ardusub/small.tlog: FS_PILOT_INPUT 2 INT8, FS_PILOT_TIMEOUT 3.0 REAL32,
    JS_GAIN_DEFAULT 0.5 / MIN 0.25 / MAX 1.0 REAL32, JS_GAIN_STEPS 4 INT8, MOT_PWM_* INT16,
    SYSID_THISMAV 1 / SYSID_MYGCS 255 INT16); ArduPilot 4.7 renamed the system ids (GCS.cpp var_info)."""
    old = {s.name: s for s in sim_parameters("4.1")}
    new = {s.name: s for s in sim_parameters("4.7")}
    assert {"SYSID_THISMAV", "SYSID_MYGCS"} <= set(old) and not {"MAV_SYSID", "MAV_GCS_SYSID"} & set(old)
    assert {"MAV_SYSID", "MAV_GCS_SYSID", "MAV_GCS_SYSID_HI"} <= set(new) and not {"SYSID_THISMAV", "SYSID_MYGCS"} & set(new)
    for table in (old, new):
        assert table["FS_PILOT_INPUT"].default == 2 and table["FS_PILOT_INPUT"].mav_type == PARAM_INT8
        assert (table["FS_PILOT_TIMEOUT"].default, table["FS_PILOT_TIMEOUT"].high) == (3.0, 3.0)
        assert table["JS_GAIN_STEPS"].mav_type == PARAM_INT8 and table["FRAME_CONFIG"].mav_type == PARAM_INT8
        assert table["MOT_PWM_MIN"].mav_type == PARAM_INT16 and table["JS_THR_GAIN"].mav_type == PARAM_REAL32
        assert (table["JS_GAIN_DEFAULT"].default, table["JS_GAIN_MIN"].default, table["JS_GAIN_MAX"].default) == \
            (0.5, 0.25, 1.0)
    assert old["SYSID_MYGCS"].mav_type == new["MAV_GCS_SYSID"].mav_type == PARAM_INT16
    with pytest.raises(ValueError, match="firmware"):
        sim_parameters("4.5")


def test_pilot_gain_as_ardusub_keeps_it():
    """ArduSub joystick.cpp: the boot gain is JS_GAIN_DEFAULT within JS_GAIN_MIN .. MAX, else the step
    nearest the middle; each gain button press moves it by (MAX - MIN) / (STEPS - 1) within MIN .. MAX."""
    assert boot_gain(0.5, 0.25, 1.0, 4) == 0.5
    assert boot_gain(0.1, 0.25, 1.0, 4) == pytest.approx(0.5)  # outside: 0.25 + (4 // 2 - 1) * 0.75 / 3
    assert boot_gain(0.1, 0.25, 1.0, 1) == 0.25  # one step: JS_GAIN_DEFAULT clamped
    g = stepped_gain(0.5, True, gain_default=0.5, gain_min=0.25, gain_max=1.0, steps=4)
    assert g == pytest.approx(0.75)
    assert stepped_gain(g, True, gain_default=0.5, gain_min=0.25, gain_max=1.0, steps=4) == pytest.approx(1.0)
    assert stepped_gain(1.0, True, gain_default=0.5, gain_min=0.25, gain_max=1.0, steps=4) == 1.0
    assert stepped_gain(0.25, False, gain_default=0.5, gain_min=0.25, gain_max=1.0, steps=4) == 0.25
    assert stepped_gain(0.8, True, gain_default=0.5, gain_min=0.25, gain_max=1.0, steps=1) == 0.5
