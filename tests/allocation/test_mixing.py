"""ArduSub-style mixing derived from the vehicle's geometry (rovlab.allocation.mixing)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.allocation.geometry import configuration_matrix
from rovlab.allocation.mixing import AXES, Mixer
from rovlab.params.vehicle import load_vehicle


@pytest.fixture(scope="module")
def heavy() -> Mixer:
    return Mixer.from_vehicle(load_vehicle("bluerov2_heavy"))


def test_heavy_factors_are_the_vectored_6dof_pattern(heavy):
    """ArduSub's SUB_FRAME_VECTORED_6DOF table (AP_Motors6DOF.cpp) has +-1 forward, lateral and yaw
    factors on the four horizontal motors and +-1 throttle on the four vertical ones; the geometry
    of bluerov2_heavy.toml gives the same magnitudes. Unlike the table, the vertical motors also
    get small forward/lateral factors: they cancel the roll and pitch moments of the horizontal
    thrusters (8.5 cm below the CG), which ArduSub leaves to its attitude controller."""
    f = heavy.factors
    horizontal, vertical = slice(0, 4), slice(4, 8)
    for j, axis in enumerate(AXES):
        if axis == "throttle":
            np.testing.assert_allclose(np.abs(f[vertical, j]), 1.0, atol=1e-9)
            np.testing.assert_allclose(f[horizontal, j], 0.0, atol=1e-9)
        else:
            np.testing.assert_allclose(np.abs(f[horizontal, j]), 1.0, atol=1e-9)
            assert np.max(np.abs(f[vertical, j])) < 0.6
    np.testing.assert_allclose(f[vertical, AXES.index("yaw")], 0.0, atol=1e-9)


@pytest.mark.parametrize("name", ["bluerov2_heavy", "udrone"])
def test_each_axis_moves_the_vehicle_along_that_axis_only(name):
    v = load_vehicle(name)
    mixer = Mixer.from_vehicle(v)
    B = configuration_matrix(v)
    rows = {"forward": (0, 1.0), "lateral": (1, 1.0), "throttle": (2, -1.0), "yaw": (5, 1.0)}
    for j, axis in enumerate(AXES):
        wrench = B @ mixer.factors[:, j]  # factor pattern read as forces
        row, sign = rows[axis]
        assert sign * wrench[row] > 0
        others = np.delete(wrench, row)
        np.testing.assert_allclose(others, 0.0, atol=1e-9)
        assert np.max(np.abs(mixer.factors[:, j])) == pytest.approx(1.0)


def test_outputs_keep_their_direction_when_scaled(heavy):
    out = heavy.outputs(np.array([1.0, 1.0, 0.0, 1.0]))
    assert np.max(np.abs(out)) == pytest.approx(1.0)
    raw = heavy.factors @ np.array([1.0, 1.0, 0.0, 1.0])
    np.testing.assert_allclose(out, raw / np.max(np.abs(raw)))
    np.testing.assert_allclose(heavy.outputs(np.array([5.0, 0, 0, 0])), heavy.outputs(np.array([1.0, 0, 0, 0])))


def test_pwm_is_linear_around_neutral_and_inverts(heavy):
    pwm = heavy.pwm_us(np.array([-1.0, -0.5, 0.0, 0.25, 0.5, 1.0, 2.0, -3.0]))
    np.testing.assert_allclose(pwm, [1100, 1300, 1500, 1600, 1700, 1900, 1900, 1100])
    np.testing.assert_allclose(heavy.outputs_from_pwm(pwm), [-1, -0.5, 0, 0.25, 0.5, 1, 1, -1])


def test_inputs_for_outputs_recovers_the_mix(heavy):
    u = np.array([0.3, -0.2, 0.5, 0.1])
    np.testing.assert_allclose(heavy.inputs_for_outputs(heavy.outputs(u)), u, atol=1e-12)
