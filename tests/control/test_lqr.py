"""Discrete LQR, Bryson's rule, reference feed-forward, the LQG law and its thruster mapping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.control.lqg import LQGController, lqg_tau, tau_to_wrench
from rovlab.control.lqr import (
    bryson,
    design_lqr,
    design_lqr_from_config,
    dlqr,
    reference_gain_continuous,
    reference_gain_discrete,
)
from rovlab.models.linear import HeaveYawParams
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle
from rovlab.sim.autopilot import ThrusterMapping

# K and P of the thesis design: Sandøy 2016, appendix A.4 run in MATLAB (the thesis does not print them)
K_THESIS = np.array([[17.7318, 0.0, 54.0771, 0.0], [0.0, 0.148116, 0.0, 2.41781]])
P_THESIS = np.diag([17.7318, 0.148116])


@pytest.fixture(scope="module")
def thesis_design():
    return design_lqr_from_config(load_vehicle("udrone"), load_design_config("thesis"))


def test_thesis_K_and_P_reproduced(thesis_design):
    np.testing.assert_allclose(thesis_design.K, K_THESIS, rtol=5e-6, atol=1e-12)
    np.testing.assert_allclose(thesis_design.P, P_THESIS, rtol=5e-6, atol=1e-12)
    assert thesis_design.reference == "continuous"
    assert np.all(np.abs(thesis_design.poles) < 1.0)


def test_discrete_and_continuous_reference_gains_agree_for_integrating_plants(thesis_design):
    d = thesis_design
    P_d = reference_gain_discrete(d.K, d.C, d.Phi, d.Delta)
    P_c = reference_gain_continuous(d.K, d.C, d.A, d.B)
    np.testing.assert_allclose(P_d, P_c, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P_d, d.K[:, :2], rtol=1e-9, atol=1e-12)  # = the position gains
    # and the closed loop settles on the reference: x = Phi x + Delta (P r - K x)
    r = np.array([0.7, math.radians(30)])
    x_ss = np.linalg.solve(np.eye(4) - d.Phi + d.Delta @ d.K, d.Delta @ P_d @ r)
    np.testing.assert_allclose(d.C @ x_ss, r, rtol=1e-12)


def test_bryson_rule_matches_the_thesis_weights():
    # thesis appendix A.4 lines 35-36
    Q = bryson([1.5, math.pi / 6, 0.5, math.pi / 100])
    R = bryson([10.0, math.pi / 100], [0.1, 0.01])
    c = load_design_config("thesis")
    np.testing.assert_allclose(np.diag(Q), c.lqr_Q, rtol=1e-14)
    np.testing.assert_allclose(np.diag(R), c.lqr_R, rtol=1e-14)
    with pytest.raises(ValueError):
        bryson([1.0, 0.0])


def test_dlqr_equals_python_control(thesis_design):
    control = pytest.importorskip("control")
    d = thesis_design
    K_ref, S_ref, E_ref = control.dlqr(d.Phi, d.Delta, d.Q, d.R)
    K, S, E = dlqr(d.Phi, d.Delta, d.Q, d.R)
    np.testing.assert_allclose(K, K_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(S, S_ref, rtol=1e-9, atol=1e-12)


def test_design_lqr_rejects_bad_input():
    p = HeaveYawParams.from_values(m=7.31, I_zz=0.16, Z_wdot=-11.13, N_rdot=-0.1, Z_w=-5.18, N_r=-0.06656)
    with pytest.raises(ValueError, match="positive definite"):
        design_lqr(p, 0.1, np.ones(4), np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="reference"):
        design_lqr(p, 0.1, np.ones(4), np.ones(2), reference="magic")


def test_lqg_law_cancels_the_bias_and_wraps_the_heading(thesis_design):
    ctl = LQGController.from_design(thesis_design)
    # at the reference and at rest, the law only cancels the estimated bias (tau = P r - K x - b_hat;
    # the thesis's eq. 5.29 has + b_hat, an erratum: the bias enters its model like a force, eq. 5.10)
    x = np.array([0.7, 0.3, 0.0, 0.0, -6.7, 0.02])
    np.testing.assert_allclose(ctl.tau(x, [0.7, 0.3]), [6.7, -0.02], atol=1e-12)
    # heading 179 deg, reference -179 deg: turn +2 deg, not -358 deg
    x = np.array([0.7, math.radians(179), 0, 0, 0, 0])
    tau = ctl.tau(x, [0.7, math.radians(-179)])
    assert tau[1] == pytest.approx(thesis_design.K[1, 1] * math.radians(2), rel=1e-9)
    assert tau[0] == pytest.approx(0.0, abs=1e-12)
    # depth error: more depth wanted -> push down (positive Z)
    assert ctl.tau(np.array([0.5, 0, 0, 0, 0, 0.0]), [0.7, 0.0])[0] == pytest.approx(17.7318 * 0.2, rel=1e-5)
    out = np.empty(2)
    lqg_tau(ctl.K, ctl.P, np.ascontiguousarray(x), np.array([0.7, math.radians(-179)]), out)
    np.testing.assert_array_equal(out, tau)
    with pytest.raises(ValueError):
        ctl.tau(np.zeros(4), [0.0, 0.0])


def test_thruster_mapping_allocates_heave_and_yaw():
    mapping = ThrusterMapping(load_vehicle("udrone"))
    np.testing.assert_array_equal(tau_to_wrench([10.0, 0.5]), [0.0, 0.0, 10.0, 0.5])
    res = mapping.allocate([10.0, 0.0])
    # Z = +10 N (down) gives f = [-2.83, -2.83, -4.35, 0, 0, 0] N, K = M = 0 (worked out here from B f = tau,
    # Sandøy 2016, eq. 2.3 and table 2.1)
    np.testing.assert_allclose(res.forces, [-2.83, -2.83, -4.35, 0, 0, 0], atol=5e-3)
    np.testing.assert_allclose(res.achieved, [0, 0, 10, 0, 0, 0], atol=1e-9)
    pwm = mapping.pwm_us([0.0, 0.5])
    assert pwm.shape == (6,) and np.all((pwm >= 1300) & (pwm <= 1700))
    assert mapping.allocate([0.0, 0.5]).achieved[5] == pytest.approx(0.5)


def test_weights_without_a_stabilising_lqr_are_a_config_error():
    # z and psi are pure integrators: with no weight on them the Riccati equation has no
    # stabilising solution; that used to surface as numpy's "Singular matrix" traceback
    from rovlab.params.design import design_config_from_dict, packaged_config_path
    from rovlab.params.validate import ConfigError, read_toml

    data = read_toml(packaged_config_path("thesis"))
    data["lqr"] = {"source": "test", "Q_diag": [0.0, 0.0, 1.0, 1.0], "R_diag": [1.0, 1.0]}
    config = design_config_from_dict(data, file="zero.toml")
    with pytest.raises(ConfigError, match=r"zero.toml: lqr: got 'Q = diag\(0, 0, 1, 1\), R = diag\(1, 1\)'.*"
                                          "stabilising discrete LQR"):
        design_lqr_from_config(load_vehicle("udrone"), config)
