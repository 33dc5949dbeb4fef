"""The DP integral state stays within the thrust capacity (issue 28, item 5).

Under a current the thrusters cannot hold the position error grows without end, and with it the
integral of the back-calculation (Astrom & Hagglund 2006, Advanced PID Control, sec. 3.5), which
settles at e (k_t K_p / K_i - 1) / k_t only for a constant error: the reproducer's integral was
-154 m s after 60 s and falling. The DP law now clamps it so that its force K_i int stays within
what the thrusters give along the axis (rovlab.allocation.capacity.thrust_capacity).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rovlab.control import dp
from rovlab.params.vehicle import load_vehicle

_ROWS = (0, 1, 2, 5)  # X, Y, Z, N in the 6-DOF wrench


@pytest.mark.parametrize("name", ["udrone_dvl", "bluerov2_heavy"])
def test_thrust_capacity_is_what_the_allocation_gives(name):
    """The capacity per DOF is the saturation-aware allocation's answer to a pure demand far beyond
    the thrusters (rovlab.allocation: K = M = 0 first, then Z, N, then X and Y)."""
    from rovlab.allocation.solvers import Allocator

    vehicle = load_vehicle(name)
    lo, hi = dp.thrust_capacity(vehicle)
    alloc = Allocator(vehicle)
    for k, row in enumerate(_ROWS):
        demand = np.zeros(4)
        demand[k] = 1e6
        assert hi[k] == pytest.approx(alloc.allocate(demand).achieved[row], rel=1e-9, abs=1e-9), (name, k)
        assert lo[k] == pytest.approx(alloc.allocate(-demand).achieved[row], rel=1e-9, abs=1e-9), (name, k)
    assert np.all(lo < 0.0) and np.all(hi > 0.0)


def test_integral_limit_maps_the_capacity_through_K_i(udrone_dvl, udrone_dp):
    """-K_i int within [tau_min, tau_max] in z and psi; x and y (NED) within the largest surge or
    sway force either way."""
    d = dp.design(udrone_dvl, udrone_dp)
    lo, hi = d.integral_limit
    np.testing.assert_allclose(-d.Ki[2:] * hi[2:], d.tau_min[2:], rtol=1e-12)
    np.testing.assert_allclose(-d.Ki[2:] * lo[2:], d.tau_max[2:], rtol=1e-12)
    horizontal = max(abs(d.tau_min[0]), abs(d.tau_min[1]), d.tau_max[0], d.tau_max[1])
    np.testing.assert_allclose(d.Ki[:2] * hi[:2], horizontal, rtol=1e-12)
    np.testing.assert_allclose(-d.Ki[:2] * lo[:2], horizontal, rtol=1e-12)
    # no integral action: no bound
    d0 = dp.design(udrone_dvl, udrone_dp.with_table("dp", replace(udrone_dp.table("dp"), integral_ratio=0.0)))
    assert np.all(np.isinf(d0.integral_limit[0])) and np.all(np.isinf(d0.integral_limit[1]))


@pytest.mark.parametrize("anti_windup", [1.0, 0.0])
def test_integral_stays_within_the_capacity_while_the_error_grows(udrone_dvl, udrone_dp, anti_windup):
    """The vehicle pushed off its set-point at 5 cm/s while the thrusters give nothing (a current
    too strong to hold): without the clamp the integral grows with the error (back-calculation: to
    ~15 e, 450 m s at e = 30 m; plain integral: 9000 m s); with it the integral stops where K_i int
    equals uDrone's largest horizontal thrust (40 N forward, so 145 m s) and stays there."""
    ctrl = dp.build(udrone_dvl, udrone_dp.with_table("dp", replace(udrone_dp.table("dp"), anti_windup=anti_windup))).kernel
    unclamped = ctrl._replace(int_lo=np.full(4, -np.inf), int_hi=np.full(4, np.inf), state=ctrl.state.copy())
    nav = np.zeros(12)
    nav[2] = 1.0
    ref = np.array([0.0, 0.0, 1.0, 0.0])
    tau = np.empty(4)
    largest = {}
    for c in (ctrl, unclamped):
        largest[id(c)] = 0.0
        for k in range(6000):  # 600 s
            nav[0] = 0.05 * k * 0.1
            dp._dp_step(c, k * 0.1, nav, ref, tau)
            dp._dp_actuated(c, k * 0.1, tau.copy(), np.zeros(4))
            largest[id(c)] = max(largest[id(c)], abs(c.state[12]))
    # (back-calculation drives the integral negative, toward what was achieved; the plain one positive)
    hi = ctrl.int_hi[0]
    assert hi == -ctrl.int_lo[0] == pytest.approx(40.03 / ctrl.Ki[0], rel=1e-3)
    assert largest[id(ctrl)] == pytest.approx(hi, rel=1e-12)  # at the bound, never beyond
    assert abs(ctrl.state[12]) == pytest.approx(hi, rel=1e-12)
    assert abs(unclamped.state[12]) > 3.0 * hi  # the test can fail: without the clamp it winds up
