"""The 4-DOF process model (Sandøy 2016, sec. 3.3 and appendix B.2; Fossen 2011 ch. 6-7): properties and kernels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.models import kinetics as k
from rovlab.models.linear import HeaveYawParams, control_model


def _random_nu(rng, n=200):
    return rng.uniform(-1.0, 1.0, size=(n, 4)) * np.array([0.8, 0.5, 0.5, 1.5])


def test_mass_matrix_symmetric_positive_definite(udrone, heavy):
    for v in (udrone, heavy):
        M = k.mass_matrix(v)
        np.testing.assert_array_equal(M, M.T)
        assert np.all(np.linalg.eigvalsh(M) > 0)
    # Sandøy 2016, eq. B.1-B.3 (M = M_RB + M_A): M_w = m - Z_wdot, M_r = I_zz - N_rdot
    M = k.mass_matrix(udrone)
    assert M[2, 2] == pytest.approx(7.31 + 14.57) and M[3, 3] == pytest.approx(0.16 + 0.12)


def test_coriolis_is_skew_symmetric_so_it_does_no_work(udrone, rng):
    v = udrone.with_updates(r_g=[0.02, -0.01, 0.0])  # off-centre CG exercises every term
    for nu in _random_nu(rng):
        C = k.C_RB(v, nu) + k.C_A(v, nu)
        np.testing.assert_allclose(C, -C.T, atol=1e-14)
        assert abs(nu @ C @ nu) < 1e-12


def test_damping_always_dissipates(udrone, heavy, rng):
    for v in (udrone, heavy):
        for nu in _random_nu(rng):
            D = k.D_L(v) + k.D_NL(v, nu)
            assert nu @ D @ nu >= 0.0


def test_kernel_equals_matrix_form(udrone, rng):
    v = udrone.with_updates(r_g=[0.02, -0.01, 0.0])
    for nu in _random_nu(rng, 50):
        tau = rng.normal(size=4) * 5
        b = rng.normal(size=4)
        deep = np.array([0.0, 0.0, 1.0, 0.0])  # 1 m down: the matrix form has no free surface
        np.testing.assert_allclose(k.nu_dot(v, deep, nu, tau, b), k.nu_dot_reference(v, nu, tau, b),
                                   rtol=1e-12, atol=1e-12)


def test_restoring_makes_positively_buoyant_vehicle_rise(udrone):
    # B - W = 6.7 N (Sandøy 2016, table 4.1): at rest with no thrust the vehicle accelerates up (z decreases)
    acc = k.nu_dot(udrone, np.array([0.0, 0.0, 1.0, 0.0]), np.zeros(4), np.zeros(4))  # 1 m down
    assert acc[2] == pytest.approx(-(udrone.buoyancy - udrone.weight) / (7.31 + 14.57))
    assert acc[2] < 0


def test_unforced_undamped_energy_is_conserved(udrone, rng):
    v = udrone.with_updates(damping_linear=np.zeros(4), damping_quadratic=np.zeros(4), damping_cubic=np.zeros(4),
                            displaced_volume=udrone.mass / udrone.water_density, r_g=[0.03, 0.01, 0.0])
    p = k.pack(v)
    M = k.mass_matrix(v)
    x = np.array([0.0, 0.0, 1.0, 0.3, 0.4, -0.2, 0.1, 0.6])
    E0 = 0.5 * x[4:] @ M @ x[4:]
    zero = np.zeros(4)
    for _ in range(2000):  # 20 s at 100 Hz
        x = k.rk4_step(p, x, zero, zero, 0.01)
    E1 = 0.5 * x[4:] @ M @ x[4:]
    assert abs(E1 - E0) / E0 < 1e-8


def test_damping_removes_energy_monotonically(udrone):
    p = k.pack(udrone.with_updates(displaced_volume=udrone.mass / udrone.water_density))
    M = k.mass_matrix(udrone)
    x = np.array([0.0, 0.0, 1.0, 0.0, 0.5, 0.3, -0.2, 1.0])
    zero = np.zeros(4)
    energy = []
    for _ in range(500):
        x = k.rk4_step(p, x, zero, zero, 0.01)
        energy.append(0.5 * x[4:] @ M @ x[4:])
    assert np.all(np.diff(energy) <= 1e-15)


def test_kinematics_rotate_body_velocity_into_ned(udrone):
    np.testing.assert_allclose(k.eta_dot(np.array([0, 0, 0, np.pi / 2]), np.array([1.0, 0, 0, 0])),
                               [0, 1, 0, 0], atol=1e-15)
    J = k.J(0.7)
    np.testing.assert_allclose(J.T @ J, np.eye(4), atol=1e-15)


def test_rk4_converges_at_fourth_order(udrone):
    p = k.pack(udrone)
    x0 = np.array([0.0, 0.0, 1.0, 0.5, 0.4, 0.1, 0.0, 0.3])
    tau = np.array([5.0, 1.0, 3.0, 0.2])
    zero = np.zeros(4)

    def run(h):
        x = x0.copy()
        for _ in range(int(round(2.0 / h))):
            x = k.rk4_step(p, x, tau, zero, h)
        return x

    ref = run(0.001)
    e1 = np.linalg.norm(run(0.04) - ref)
    e2 = np.linalg.norm(run(0.02) - ref)
    assert 12 < e1 / e2 < 20  # 2^4 = 16


def test_linearisation_at_rest_is_the_depth_heading_model(udrone):
    A, B = k.linearise(udrone, np.array([0.0, 0.0, 1.0, 0.0]), np.zeros(4), np.zeros(4))  # 1 m deep
    Ac, Bc, _ = control_model(HeaveYawParams.from_vehicle(udrone))
    # states [x y z psi u v w r]: heave/yaw sub-block equals the control model (Sandøy 2016, eq. 5.27)
    idx = [2, 3, 6, 7]
    np.testing.assert_allclose(A[np.ix_(idx, idx)], Ac, atol=1e-15)
    np.testing.assert_allclose(B[np.ix_(idx, [2, 3])], Bc, atol=1e-15)


def test_linearisation_matches_finite_difference_of_trajectory(udrone):
    eta0, nu0, tau0 = np.array([0, 0, 1, 0.3]), np.array([0.3, 0.1, -0.1, 0.2]), np.array([10.0, 2, 5, 0.5])
    v = udrone.with_updates(r_g=[0.02, -0.01, 0.0])
    A, B = k.linearise(v, eta0, nu0, tau0)
    p = k.pack(v)
    x0 = np.concatenate([eta0, nu0])
    zero = np.zeros(4)
    for j in range(8):  # central differences column by column
        dx = np.zeros(8)
        dx[j] = 1e-6
        col = (k.plant_rhs(p, x0 + dx, tau0, zero) - k.plant_rhs(p, x0 - dx, tau0, zero)) / 2e-6
        np.testing.assert_allclose(A[:, j], col, rtol=1e-6, atol=1e-8)
    for j in range(4):
        du = np.zeros(4)
        du[j] = 1.0
        np.testing.assert_allclose(B[:, j], k.plant_rhs(p, x0, tau0 + du, zero) - k.plant_rhs(p, x0, tau0, zero),
                                   atol=1e-12)


def test_small_angle_cos_sin_is_math_cos_sin_to_rounding():
    from rovlab.core.angles import cos_sin_small

    for d in [*np.linspace(-0.1, 0.1, 2001), 1e-300, -0.0, 0.1, -0.1, np.nextafter(0.1, 1.0), 0.5, -3.0, 40.0]:
        c, s = cos_sin_small(float(d))
        assert abs(c - math.cos(d)) <= 2.3e-16 and abs(s - math.sin(d)) <= 2.3e-16 * max(1.0, abs(d)), d
    c, s = cos_sin_small(math.nan)
    assert math.isnan(c) and math.isnan(s)


@pytest.mark.parametrize("current", [(0.0, 0.0), (0.3, -0.2)])
def test_plant_rk4_by_angle_addition_equals_sin_cos_at_every_stage(udrone, current):
    """The simulator's RK4 turns the heading's cosine and sine by the stage increments instead of
    evaluating them (rovlab.models.kinetics.rk4_scalars): 60 s at 100 Hz while the vehicle turns
    more than 8 full circles ends where the textbook RK4 (sin and cos of every stage's heading) ends, to
    rounding, with or without a current (whose rotation into body axes uses the heading too)."""
    from rovlab.sim.plant import process_advance

    p = k.pack(udrone)
    p[k.P_VC:k.P_VC + 2] = current
    x0 = np.array([0.0, 0.0, 2.0, 3.0, 0.3, 0.0, 0.0, 0.0])
    tau = np.array([8.0, 0.0, 5.0, 1.5])  # forward, down and a yaw moment: a steady spiral
    rng = np.random.default_rng(3)
    normals = rng.standard_normal((6000, 4)).astype(np.float32)
    noise_std = np.array([1.0, 1.0, 1.0, 0.1])

    def reference(x, h=0.01):
        x = x.copy()
        for j in range(normals.shape[0]):
            f = tau + noise_std * normals[j].astype(float)

            def rhs(y):
                return np.array(k.rhs(p, *y, *f))

            k1 = rhs(x)
            k2 = rhs(x + 0.5 * h * k1)
            k3 = rhs(x + 0.5 * h * k2)
            k4 = rhs(x + h * k3)
            x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return x

    x = x0.copy()
    for row in range(600):  # one call per control period, as the loop does
        process_advance(p, x, tau, 0.01, noise_std, normals[row * 10:(row + 1) * 10])
    ref = reference(x0)
    assert ref[3] - x0[3] > 8 * 2 * math.pi  # it did turn
    np.testing.assert_allclose(x, ref, rtol=0.0, atol=1e-12)
    once = x0.copy()  # one call for the whole run: the same to rounding
    process_advance(p, once, tau, 0.01, noise_std, normals)
    np.testing.assert_allclose(once, ref, rtol=0.0, atol=1e-12)


def test_submerged_fraction_keeps_nan():
    p = np.zeros(k.P_SIZE)
    p[k.P_HALF_H] = 0.1
    assert k.submerged(p, 0.5) == 1.0 and k.submerged(p, -0.5) == 0.0 and k.submerged(p, 0.0) == 0.5
    assert math.isnan(k.submerged(p, math.nan))
