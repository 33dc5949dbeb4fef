"""The plain-Python kernels (one-shot commands) give the numbers of the compiled ones."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.allocation import SCALE_ALL, Allocator
from rovlab.models.thrusters import ThrusterBank


@pytest.mark.parametrize("vehicle, priority", [("udrone", None), ("heavy", None), ("heavy", SCALE_ALL)])
def test_plain_allocation_equals_compiled(vehicle, priority, request, rng):
    v = request.getfixturevalue(vehicle)
    kw = {} if priority is None else {"priority": priority}
    fast, plain = Allocator(v, **kw), Allocator(v, compiled=False, **kw)
    assert plain.compiled is False and fast.compiled is True
    for _ in range(40):
        tau = rng.normal(0.0, [40, 40, 60, 0.5, 0.5, 6]) * rng.choice([0.1, 1.0, 3.0])
        a, b = fast.allocate(tau), plain.allocate(tau)
        np.testing.assert_allclose(b.forces, a.forces, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b.pwm_us, a.pwm_us, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(b.fraction, a.fraction, rtol=1e-12, atol=1e-12)
        assert a.saturated == b.saturated


@pytest.mark.parametrize("vehicle", ["udrone", "heavy"])
def test_plain_thruster_maps_equal_compiled(vehicle, request, rng):
    bank = ThrusterBank.from_vehicle(request.getfixturevalue(vehicle))
    n = len(bank.names)
    for _ in range(20):
        pwm = rng.uniform(1000.0, 2000.0, n)
        np.testing.assert_allclose(bank.force(pwm, compiled=False), bank.force(pwm), rtol=1e-13, atol=1e-13)
        f = rng.uniform(-60.0, 60.0, n)
        np.testing.assert_allclose(bank.pwm(f, compiled=False), bank.pwm(f), rtol=1e-13, atol=1e-9)
