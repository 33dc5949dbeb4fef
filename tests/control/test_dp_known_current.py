"""A DP controller told the current feeds it forward (issue 28, item 2).

An estimator that models the current (``[ekf] current``) takes its drag and Munk moment out of its
force biases; the DP law must then put them into its feed-forward: the model along the reference
in the velocity through the water, nu_r = R(psi)^T (eta_d' - V_c) (Fossen 2011, Handbook of Marine
Craft Hydrodynamics and Motion Control, sec. 8.3: for an irrotational current the rigid-body and
hydrodynamic terms may be written in nu_r). With the estimate on the reference and no bias the
demanded wrench is the plant's inverse dynamics: the plant's own model (rovlab.models.kinetics)
then accelerates exactly as the reference does. uDrone has its centre of gravity at VO (Sandøy 2016,
table 4.1), so the DP law's diagonal inertia is the model's.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rovlab.control import dp
from rovlab.models import kinetics as kin
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle

CURRENT = np.array([0.25, 0.15, 0.0])  # NED [m/s]: across the heading below, so u_r v_r != 0


@pytest.fixture(scope="module")
def udrone():
    return load_vehicle("udrone_dvl")


def _config(current):
    cfg = load_design_config("udrone_dp")
    return cfg.with_table("ekf", replace(cfg.table("ekf"), current=np.asarray(current, dtype=float)))


def _plant(vehicle, current):
    p = kin.pack(vehicle)
    p[kin.P_VC:kin.P_VC + 3] = current
    return p


def _demand(ctrl, vehicle, psi, vel, acc):
    """The DP's wrench with the estimate on its reference (pose psi at 1 m, NED velocity vel and
    acceleration acc of x, y, z, psi) and the estimated heave bias the net weight."""
    s = ctrl.state
    s[:] = 0.0
    s[0:4] = [0.0, 0.0, 1.0, psi]
    s[4:8] = vel
    s[8:12] = acc
    s[20] = 1.0  # started
    c, sn = math.cos(psi), math.sin(psi)
    nav = np.zeros(12)
    nav[0:4] = s[0:4]
    nav[4] = c * vel[0] + sn * vel[1]
    nav[5] = -sn * vel[0] + c * vel[1]
    nav[6], nav[7] = vel[2], vel[3]
    nav[10] = vehicle.weight - vehicle.buoyancy  # b_Z carries the net weight (rovlab.core.components.TRUTH)
    tau = np.empty(4)
    dp._dp_step(ctrl, 0.0, nav, s[0:4].copy(), tau)
    return nav, tau


def test_the_known_current_is_the_estimators(udrone):
    assert np.array_equal(dp.design(udrone, load_design_config("udrone_dp")).current, np.zeros(3))
    np.testing.assert_array_equal(dp.design(udrone, _config(CURRENT)).current, CURRENT)
    # the depth-and-heading KF models no current (it has no table): nothing to feed forward
    assert np.array_equal(dp.known_current(load_design_config("default")), np.zeros(3))


def test_station_keeping_in_a_known_current_needs_no_correction(udrone):
    """At rest on the set-point, heading 46 deg off the current: the wrench holds the vehicle still
    in the plant with that current (drag in surge and sway, the Munk moment (X_udot - Y_vdot) u_r v_r
    in yaw, 0.31 N m here), so the PID has nothing to learn."""
    ctrl = dp.build(udrone, _config(CURRENT)).kernel
    psi = math.radians(-15.0)
    nav, tau = _demand(ctrl, udrone, psi, np.zeros(4), np.zeros(4))
    x = np.concatenate([nav[:4], nav[4:8]])
    nu_dot = kin.plant_rhs(_plant(udrone, CURRENT), x, tau, np.zeros(4))[4:]
    np.testing.assert_allclose(nu_dot, 0.0, atol=1e-12)
    c, sn = math.cos(psi), math.sin(psi)
    u_r, v_r = -(c * CURRENT[0] + sn * CURRENT[1]), -(-sn * CURRENT[0] + c * CURRENT[1])
    munk = (udrone.added_mass[0] - udrone.added_mass[1]) * u_r * v_r
    assert abs(munk) > 0.3 and tau[3] == pytest.approx(munk, rel=1e-12)
    # told nothing, the controller leaves all of it to the biases (and the plant accelerates)
    blind = dp.build(udrone, load_design_config("udrone_dp")).kernel
    _, tau0 = _demand(blind, udrone, psi, np.zeros(4), np.zeros(4))
    assert np.allclose(tau0[[0, 1, 3]], 0.0, atol=1e-12)


@pytest.mark.parametrize("current", [np.zeros(3), CURRENT, np.array([-0.1, 0.2, 0.05])])
def test_along_a_turning_reference_the_plant_follows_it(udrone, current):
    """Moving at (0.12, -0.08, 0.05) m/s NED while turning at 15 deg/s and accelerating: the plant
    with the known current, driven by the DP's wrench, has the reference's acceleration in body
    axes, d/dt R^T eta_d' = R^T eta_d'' + r [v_d, -u_d] (the body frame turns), in every DOF."""
    ctrl = dp.build(udrone, _config(current)).kernel
    psi = math.radians(-40.0)
    vel = np.array([0.12, -0.08, 0.05, math.radians(15.0)])
    acc = np.array([0.02, 0.03, -0.01, math.radians(2.0)])
    nav, tau = _demand(ctrl, udrone, psi, vel, acc)
    x = np.concatenate([nav[:4], nav[4:8]])
    nu_dot = kin.plant_rhs(_plant(udrone, current), x, tau, np.zeros(4))[4:]
    c, sn = math.cos(psi), math.sin(psi)
    u_d, v_d, r = nav[4], nav[5], vel[3]
    expected = [c * acc[0] + sn * acc[1] + r * v_d, -sn * acc[0] + c * acc[1] - r * u_d, acc[2], acc[3]]
    np.testing.assert_allclose(nu_dot, expected, atol=1e-12)
