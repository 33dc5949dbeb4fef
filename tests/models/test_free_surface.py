"""The free surface (issue 15, item 5): the hull's buoyancy and heave added mass fall as it
breaches, so a positively buoyant vehicle floats at the surface instead of rising into the air."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.models import kinetics as k


@pytest.fixture(scope="module")
def udrone():
    from rovlab.params import load_vehicle

    return load_vehicle("udrone")


def test_deep_below_the_surface_the_model_is_unchanged(udrone):
    p = k.pack(udrone)
    nu = np.array([0.2, -0.1, 0.05, 0.1])
    deep = k.plant_rhs(p, np.array([0.0, 0.0, 2.0, 0.3, *nu]), np.zeros(4), np.zeros(4))
    np.testing.assert_allclose(deep[4:], k.nu_dot_reference(udrone, nu, np.zeros(4)), rtol=1e-12, atol=1e-14)


def test_buoyancy_and_added_mass_scale_with_the_submerged_fraction(udrone):
    p = k.pack(udrone)
    h = udrone.geometry.height  # 0.287 m (Sandøy 2016, table 4.2)
    W, B, m, Zw = udrone.weight, udrone.buoyancy, udrone.mass, udrone.added_mass[2]
    for z, s in ((h / 2, 1.0), (0.0, 0.5), (-h / 4, 0.25), (-h / 2, 0.0), (-1.0, 0.0)):
        acc = k.plant_rhs(p, np.array([0, 0, z, 0, 0, 0, 0, 0.0]), np.zeros(4), np.zeros(4))[6]
        assert acc == pytest.approx((W - s * B) / (m - s * Zw), rel=1e-12), z


def test_a_buoyant_vehicle_floats_at_the_surface(udrone):
    """uDrone is 6.7 N positively buoyant (B - W from Sandøy 2016, table 4.1): left alone at 1 m it rises and settles
    where buoyancy equals weight, s = W / B = 0.915 of the hull under water."""
    p = k.pack(udrone)
    x = np.array([0, 0, 1.0, 0, 0, 0, 0, 0.0])
    for _ in range(6000):  # 60 s
        x = k.rk4_step(p, x, np.zeros(4), np.zeros(4), 0.01)
    h = udrone.geometry.height
    z_float = h * (udrone.weight / udrone.buoyancy) - h / 2
    assert x[2] == pytest.approx(z_float, abs=1e-3)
    assert abs(x[6]) < 1e-3


def test_jacobian_in_the_breach_band_matches_finite_differences(udrone):
    p = k.pack(udrone)
    x0 = np.array([0.0, 0.0, -0.05, 0.2, 0.1, 0.0, 0.05, 0.0])
    f = np.array([1.0, 0.0, 3.0, 0.1])
    A, B = k.linearise(udrone, x0[:4], x0[4:], f)
    zero = np.zeros(4)
    for j in range(8):
        dx = np.zeros(8)
        dx[j] = 1e-7
        col = (k.plant_rhs(p, x0 + dx, f, zero) - k.plant_rhs(p, x0 - dx, f, zero)) / 2e-7
        np.testing.assert_allclose(A[:, j], col, rtol=1e-5, atol=1e-7)
    du = np.array([0.0, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(B[:, 2], k.plant_rhs(p, x0, f + du, zero) - k.plant_rhs(p, x0, f, zero), atol=1e-12)


def test_references_and_starts_above_the_surface_are_refused():
    from rovlab.params.validate import ConfigError
    from rovlab.sim.scenario import load_scenario_data, scenario_from_dict

    data, file = load_scenario_data("step-process-model")
    data["reference"][0]["z"] = -3.0
    with pytest.raises(ConfigError, match="free surface"):
        scenario_from_dict(data, file=file)
    data, file = load_scenario_data("step-process-model")
    data["initial"]["z"] = -0.5
    with pytest.raises(ConfigError, match="free surface"):
        scenario_from_dict(data, file=file)
