"""Priority allocation is the exact lexicographic optimum (issue 11, item 3).

The reference is an independent formulation solved by scipy's HiGHS LP solver, level by level:
variables [f (n thrusters), alpha_l (one per demanded level)], equalities B f = sum_l alpha_l tau_l
(so every DOF demanded zero, K and M included, is kept at zero), bounds f_min <= f <= f_max and
0 <= alpha_l <= 1; maximise alpha_0, fix it, maximise alpha_1, ... (the definition of a
lexicographic optimum; prioritised allocation as surveyed by Johansen & Fossen 2013, "Control
allocation - a survey", Automatica 49(5), 1087-1103). The kernel's fractions must equal the LP's on
thousands of random saturating demands
(fixed seed) for both packaged vehicles.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from rovlab.allocation import DEFAULT_PRIORITY, SCALE_ALL, Allocator
from rovlab.params.vehicle import WRENCH6

SEED = 11_3  # issue 11, item 3
FRACTION_TOL = 1e-6  # HiGHS's own primal/dual feasibility tolerance is 1e-7
LIMIT_TOL = 1e-9  # [N]


def lexicographic_lp(alloc: Allocator, tau6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(alpha per level, forces) of the lexicographic LP, computed with scipy.optimize.linprog."""
    B, n = alloc.B, alloc.B.shape[1]
    levels = [lv for lv in range(alloc.n_levels) if np.any(tau6[alloc.level == lv] != 0.0)]
    if not levels:
        return np.ones(alloc.n_levels), np.zeros(n)
    cols = []
    for lv in levels:
        t = np.where(alloc.level == lv, tau6, 0.0)
        cols.append(-t)
    A_eq = np.hstack([B, np.array(cols).T])
    bounds = list(zip(alloc.f_min, alloc.f_max)) + [(0.0, 1.0)] * len(levels)
    x = None
    for k in range(len(levels)):
        c = np.zeros(n + len(levels))
        c[n + k] = -1.0
        res = linprog(c, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs")
        assert res.status == 0, res.message
        x = res.x
        a = float(np.clip(x[n + k], 0.0, 1.0))
        bounds[n + k] = (a, a)  # fix this level at its optimum for the levels below
    alpha = np.ones(alloc.n_levels)
    for k, lv in enumerate(levels):
        alpha[lv] = bounds[n + k][0]
    return alpha, (x[:n] if x is not None else np.zeros(n))


def _random_demands(rng, count, scale, with_km):
    """4-DOF demands [X, Y, Z, N] (K = M = 0), some with roll/pitch moments too; heavy-tailed
    sizes so most saturate and some levels are feasible on their own."""
    tau = rng.normal(size=(count, 6)) * scale * rng.uniform(0.3, 2.0, size=(count, 1))
    if not with_km:
        tau[:, 3:5] = 0.0
    else:
        tau[rng.uniform(size=count) < 0.6, 3:5] = 0.0
    # sometimes drop a DOF entirely (a level with nothing demanded, or a partly demanded level)
    tau[rng.uniform(size=(count, 6)) < 0.1] = 0.0
    return tau


CASES = {
    # (vehicle fixture, demand scale per DOF [N, N, N, N m, N m, N m])
    "udrone": np.array([60.0, 60.0, 80.0, 3.0, 3.0, 6.0]),
    "heavy": np.array([200.0, 200.0, 250.0, 20.0, 20.0, 30.0]),
}


def _check_against_lp(alloc, demands):
    checked = 0
    worst = 0.0
    for tau in demands:
        f, frac = alloc.forces(tau)
        alpha_lp, f_lp = lexicographic_lp(alloc, tau)
        if np.all(alpha_lp >= 1.0 - 1e-9):
            continue  # feasible demand: covered by test_feasible_demand_is_met_exactly
        checked += 1
        expected = np.where(tau != 0.0, alpha_lp[alloc.level], 1.0)
        worst = max(worst, float(np.max(np.abs(frac - expected))))
        np.testing.assert_allclose(frac, expected, atol=FRACTION_TOL,
                                   err_msg=f"demand {tau.tolist()}: fractions differ from the LP's")
        assert np.all(f <= alloc.f_max + LIMIT_TOL) and np.all(f >= alloc.f_min - LIMIT_TOL)
        # the wrench is exactly the demanded one scaled per level: zero rows stay zero (K = M = 0),
        # nothing bends
        np.testing.assert_allclose(alloc.B @ f, frac * tau, atol=1e-9, rtol=0)
        # the least weighted effort among optimal force vectors (weights are 1 here): no more
        # than the LP's (arbitrary) optimal vertex
        assert f @ f <= f_lp @ f_lp + 1e-6
    return checked, worst


@pytest.mark.parametrize("vehicle_name", ["udrone", "heavy"])
def test_priority_is_the_lexicographic_lp_optimum(vehicle_name, request):
    alloc = Allocator(request.getfixturevalue(vehicle_name))
    rng = np.random.default_rng(SEED)
    demands = _random_demands(rng, 2000, CASES[vehicle_name], with_km=True)
    checked, worst = _check_against_lp(alloc, demands)
    assert checked > 1000, f"only {checked} of the random demands saturated"


@pytest.mark.parametrize("vehicle_name", ["udrone", "heavy"])
@pytest.mark.parametrize("priority", [SCALE_ALL, (("X", "Y"), ("N",), ("Z",)), (("N",), ("Z",), ("Y",), ("X",))],
                         ids=["scale", "xy-n-z", "n-z-y-x"])
def test_other_priorities_are_lexicographic_too(vehicle_name, priority, request):
    alloc = Allocator(request.getfixturevalue(vehicle_name), priority=priority)
    rng = np.random.default_rng(SEED + 1)
    checked, _ = _check_against_lp(alloc, _random_demands(rng, 300, CASES[vehicle_name], with_km=False))
    assert checked > 150


def test_default_priority_is_documented_order():
    # the order the README and the CLI help state
    assert DEFAULT_PRIORITY == (("K", "M"), ("Z",), ("N",), ("X", "Y"))
    assert set(sum(DEFAULT_PRIORITY, ())) == set(WRENCH6)


def _is_least_effort(alloc, f, weights, tol=1e-7):
    """KKT certificate that f minimises f^T W f over {B f = B f, f_min <= f <= f_max}: a
    multiplier nu exists with (W f - B^T nu)_i = 0 for thrusters inside their limits, >= 0 at
    the lower limit and <= 0 at the upper one (found, or shown not to exist, by an LP)."""
    B = alloc.B
    g = weights * f
    at_lo = f <= alloc.f_min + 1e-9
    at_hi = f >= alloc.f_max - 1e-9
    free = ~(at_lo | at_hi)
    scale = 1.0 + np.max(np.abs(g))
    A_ub = np.vstack([B.T[free], -B.T[free], B.T[at_lo], -B.T[at_hi]])
    b_ub = np.concatenate([g[free] + tol * scale, -g[free] + tol * scale, g[at_lo] + tol * scale,
                           -g[at_hi] + tol * scale])
    res = linprog(np.zeros(6), A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * 6, method="highs")
    return res.status == 0


def test_redundant_vehicle_uses_least_weighted_effort(heavy):
    """BlueROV2 Heavy (8 thrusters, 2-dimensional null space): whether the demand is met or
    scaled, the forces are the least weighted effort giving the allocated wrench within the
    limits - also when the plain weighted pseudo-inverse would exceed a limit."""
    rng = np.random.default_rng(SEED + 2)
    weights = rng.uniform(0.5, 3.0, 8)
    alloc = Allocator(heavy, weights=weights)
    counts = {"met, pseudo-inverse outside limits": 0, "saturated": 0}
    for tau in _random_demands(rng, 600, 0.4 * CASES["heavy"], with_km=False):
        f, frac = alloc.forces(tau)
        assert np.all(f <= alloc.f_max + LIMIT_TOL) and np.all(f >= alloc.f_min - LIMIT_TOL)
        np.testing.assert_allclose(alloc.B @ f, frac * tau, atol=1e-9, rtol=0)
        plain = alloc.T @ tau
        if np.all(frac == 1.0):
            if np.all(plain <= alloc.f_max) and np.all(plain >= alloc.f_min):
                np.testing.assert_allclose(f, plain, atol=1e-12)  # as before: the pseudo-inverse
                continue
            counts["met, pseudo-inverse outside limits"] += 1
        else:
            counts["saturated"] += 1
        assert _is_least_effort(alloc, f, weights), f"demand {tau.tolist()}: not the least effort"
    assert min(counts.values()) > 20, counts


def test_least_effort_certificate_can_fail(heavy):
    # the check above rejects a feasible but wasteful force vector (a null-space step added)
    alloc = Allocator(heavy)
    tau = np.array([20.0, 0, 10.0, 0, 0, 0])
    f, _ = alloc.forces(tau)
    _, _, Vt = np.linalg.svd(alloc.B)
    assert _is_least_effort(alloc, f, np.ones(8))
    assert not _is_least_effort(alloc, f + 2.0 * Vt[6], np.ones(8))


def test_rank_deficient_thruster_set_scales_the_least_squares_wrench(heavy):
    """Five of the Heavy's thrusters (B of rank 4, so not every wrench can be made): each level's
    pseudo-inverse (least-squares) wrench P tau_l, P = B T, is scaled lexicographically, as the
    same LP with P tau_l in place of tau_l says."""
    from rovlab.allocation import weighted_pinv
    from rovlab.allocation.solvers import allocate_kernel

    full = Allocator(heavy)
    cols = [0, 1, 2, 3, 4]
    B = np.ascontiguousarray(full.B[:, cols])
    T = np.ascontiguousarray(weighted_pinv(B))
    f_min, f_max = full.f_min[cols].copy(), full.f_max[cols].copy()
    assert np.linalg.matrix_rank(B) == 4
    P = B @ T
    rng = np.random.default_rng(SEED + 3)
    checked = 0
    for tau in _random_demands(rng, 300, CASES["heavy"], with_km=False):
        f, frac = allocate_kernel(B, T, np.ones(5), f_min, f_max, tau, full.level, full.n_levels, True)
        assert np.all(f <= f_max + LIMIT_TOL) and np.all(f >= f_min - LIMIT_TOL)
        levels = [lv for lv in range(full.n_levels) if np.any(tau[full.level == lv] != 0.0)]
        A_eq = np.hstack([B, -np.array([P @ np.where(full.level == lv, tau, 0.0) for lv in levels]).T])
        bounds = list(zip(f_min, f_max)) + [(0.0, 1.0)] * len(levels)
        for k, lv in enumerate(levels):
            c = np.zeros(5 + len(levels))
            c[5 + k] = -1.0
            a = float(np.clip(linprog(c, A_eq=A_eq, b_eq=np.zeros(6), bounds=bounds, method="highs").x[5 + k], 0, 1))
            bounds[5 + k] = (a, a)
            assert frac[full.level == lv][tau[full.level == lv] != 0] == pytest.approx(a, abs=FRACTION_TOL)
        checked += any(b[0] < 1.0 - 1e-9 for b in bounds[5:])
    assert checked > 100
