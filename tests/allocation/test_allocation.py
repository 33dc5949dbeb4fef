"""Thrust allocation (Sandøy 2016, sec. 2.2; Fossen 2011): configuration matrix, exact, weighted and saturation-aware."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from rovlab.allocation import SCALE_ALL, Allocator, configuration_matrix, weighted_pinv

# B from the cross products of Sandøy 2016, eq. 2.2-2.3 with table 2.1; agrees with its appendix B.3 (the worked
# example after eq. 2.2 has sign slips, an erratum)
B_UDRONE = np.array([
    [0, 0, 0, 1, 1, 0],
    [0, 0, 0, 0, 0, 1],
    [-1, -1, -1, 0, 0, 0],
    [0.111, -0.111, 0, 0, 0, -0.095],
    [0.153, 0.153, -0.199, -0.014, -0.014, 0],
    [0, 0, 0, -0.111, 0.111, 0.008],
])


def test_udrone_configuration_matrix_equals_the_thesis_geometry(udrone):
    B = configuration_matrix(udrone)
    np.testing.assert_allclose(B, B_UDRONE, atol=1e-15)
    assert np.linalg.det(B) == pytest.approx(0.0173, abs=5e-5)


def test_heave_example_worked_out_from_B(udrone):
    # Z = +10 N (down) with K = M = 0 -> f = [-2.83, -2.83, -4.35, 0, 0, 0] N (worked out here from B above)
    res = Allocator(udrone).allocate([0, 0, 10, 0])
    np.testing.assert_allclose(res.forces, [-2.83, -2.83, -4.35, 0, 0, 0], atol=5e-3)
    np.testing.assert_allclose(res.achieved, [0, 0, 10, 0, 0, 0], atol=1e-12)
    assert not res.saturated
    assert np.all(res.pwm_us[:3] < 1475) and np.all(res.pwm_us[3:] == 1500)


def _feasible_wrenches(alloc, rng, n=300, margin=0.95):
    f = rng.uniform(alloc.f_min * margin, alloc.f_max * margin, size=(n, alloc.B.shape[1]))
    return f @ alloc.B.T


@pytest.mark.parametrize("vehicle_name", ["udrone", "heavy"])
def test_feasible_demand_is_met_exactly(vehicle_name, request, rng):
    v = request.getfixturevalue(vehicle_name)
    alloc = Allocator(v)
    for tau in _feasible_wrenches(alloc, rng):
        res = alloc.allocate(tau)
        np.testing.assert_allclose(res.achieved, tau, atol=1e-9)
        assert not res.saturated
        assert np.all(res.forces <= alloc.f_max + 1e-9) and np.all(res.forces >= alloc.f_min - 1e-9)


def test_square_unconstrained_is_the_inverse(udrone, rng):
    alloc = Allocator(udrone, saturation=False)
    tau = rng.normal(size=6)
    np.testing.assert_allclose(alloc.forces(tau)[0], np.linalg.solve(B_UDRONE, tau), atol=1e-12)


def test_unconstrained_is_the_plain_pseudo_inverse_and_says_so(heavy):
    alloc = Allocator(heavy, saturation=False)
    tau = np.array([150.0, 0, 0, 0, 0, 0])  # beyond the four horizontal T200s (51.5 N at 16 V)
    res = alloc.allocate(tau)
    np.testing.assert_allclose(res.forces, alloc.T @ tau, atol=1e-12)  # not clipped
    np.testing.assert_allclose(res.achieved, tau, atol=1e-9)
    assert res.saturated and res.over_limit == ("T1", "T2", "T3", "T4")
    assert np.all(res.pwm_us[:4] >= 1100) and np.all(res.pwm_us[:4] <= 1900)  # commands saturate
    assert Allocator(heavy).allocate(tau).over_limit == ()


def test_weighted_pinv_minimises_weighted_effort(heavy, rng):
    B = configuration_matrix(heavy)
    w = rng.uniform(0.5, 3.0, 8)
    T = weighted_pinv(B, w)
    tau = rng.normal(size=6)
    f = T @ tau
    np.testing.assert_allclose(B @ f, tau, atol=1e-12)
    # any other solution f + null-space step costs more
    _, _, Vt = np.linalg.svd(B)
    for z in Vt[6:]:
        assert (f + 0.1 * z) @ (w * (f + 0.1 * z)) > f @ (w * f)
    with pytest.raises(ValueError, match="positive"):
        weighted_pinv(B, -w)


def _parallel(a, b):
    """a is a non-negative multiple of b."""
    nb = np.linalg.norm(b)
    if nb == 0:
        return np.linalg.norm(a) < 1e-9
    return np.linalg.norm(a - (a @ b) / nb**2 * b) < 1e-7 * max(1.0, np.linalg.norm(a)) and a @ b >= -1e-12


def test_saturation_scales_never_bends_and_respects_limits(udrone, rng):
    alloc = Allocator(udrone, priority=SCALE_ALL)
    clipped_bent = 0
    for _ in range(300):
        tau = rng.normal(size=4) * np.array([60, 60, 60, 6])
        res = alloc.allocate(tau)
        assert np.all(res.forces <= alloc.f_max + 1e-9) and np.all(res.forces >= alloc.f_min - 1e-9)
        assert _parallel(res.achieved, res.demanded)
        if res.saturated:
            # the scale is the largest feasible one: some thruster sits at a limit
            at_limit = np.isclose(res.forces, alloc.f_max) | np.isclose(res.forces, alloc.f_min)
            assert at_limit.any()
            # naive per-thruster clipping would have bent the wrench (the defect we avoid)
            naive = udrone_clip(alloc, res.demanded)
            clipped_bent += not _parallel(naive, res.demanded)
    assert clipped_bent > 50


def udrone_clip(alloc, tau6):
    return alloc.B @ np.clip(np.linalg.solve(alloc.B, tau6), alloc.f_min, alloc.f_max)


def test_priority_gives_up_lower_dofs_first(udrone):
    alloc = Allocator(udrone)  # default priority: (K, M) > Z > N > (X, Y)
    # depth near the reverse limit of T3 (-13.0 N) plus surge, whose pitch moment (T4, T5 sit
    # 14 mm above VO) needs heave-thruster capacity that depth already uses
    res = alloc.allocate([15.0, 0.0, 29.0, 0.5])
    assert res.saturated
    # Z is kept exactly (feasible on its own), N too; X (lowest) is scaled along its own axis
    assert res.fraction[2] == pytest.approx(1.0) and res.fraction[5] == pytest.approx(1.0)
    assert 0 <= res.fraction[0] < 1
    np.testing.assert_allclose(res.achieved[[1, 3, 4]], 0.0, atol=1e-9)  # no bending into Y, K, M
    assert res.limited_dofs() == ["X"]
    # a depth demand the vehicle cannot meet at all: scaled, and the rest gets what is left
    res = alloc.allocate([0.0, 0.0, 200.0, 0.0])
    assert res.saturated and 0 < res.fraction[2] < 1
    # the largest depth force with K = M = 0: the rear thruster T3 is at its reverse limit
    assert res.forces[2] == pytest.approx(alloc.f_min[2])
    np.testing.assert_allclose(res.achieved[[0, 1, 3, 4, 5]], 0.0, atol=1e-9)


def test_priority_result_is_best_possible_for_top_level(udrone, rng):
    """The top demanded level gets the largest feasible fraction (checked by linear programming)."""
    alloc = Allocator(udrone, priority=[("Z",), ("X", "Y", "N")])
    B = alloc.B
    for _ in range(30):
        z = rng.uniform(-120, 120)
        res = alloc.allocate([rng.normal() * 20, rng.normal() * 20, z, rng.normal()])
        # max alpha s.t. B f = alpha * [0,0,z,0,0,0], f in bounds
        tau = np.array([0, 0, z, 0, 0, 0.0])
        c = np.zeros(7)
        c[-1] = -1
        A_eq = np.hstack([B, -tau[:, None]])
        bounds = list(zip(alloc.f_min, alloc.f_max)) + [(0, 1)]
        lp = linprog(c, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs")
        # never less than the isolated optimum (lower levels may free capacity, never take it)
        assert res.fraction[2] >= lp.x[-1] - 1e-7


def test_redundant_vehicle_redistributes_before_scaling(heavy, rng):
    """BlueROV2 Heavy (8 thrusters): when the pseudo-inverse saturates a thruster, the rest of the
    demand is redistributed over the free ones, so more of the wrench is met than by scaling."""
    alloc = Allocator(heavy, priority=SCALE_ALL)
    better = 0
    for _ in range(200):
        tau = rng.normal(size=6) * np.array([120, 120, 150, 0, 0, 15])
        tau[3:5] = 0
        res = alloc.allocate(tau)
        assert np.all(res.forces <= alloc.f_max + 1e-9) and np.all(res.forces >= alloc.f_min - 1e-9)
        assert _parallel(res.achieved, res.demanded)
        d = alloc.T @ tau
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.where(d > 0, alloc.f_max / d, np.where(d < 0, alloc.f_min / d, np.inf))
        plain = min(1.0, ratios.min())
        assert res.fraction[0] >= plain - 1e-9
        better += res.fraction[0] > plain + 1e-6
    assert better > 10


def test_bad_wrench_and_priority(udrone):
    alloc = Allocator(udrone)
    with pytest.raises(ValueError, match="4 .* or 6"):
        alloc.allocate([1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        alloc.allocate([0, 0, np.nan, 0])
    with pytest.raises(ValueError, match="unknown DOF"):
        Allocator(udrone, priority=[("Q",)])
    with pytest.raises(ValueError, match="twice"):
        Allocator(udrone, priority=[("X",), ("X", "Y")])
