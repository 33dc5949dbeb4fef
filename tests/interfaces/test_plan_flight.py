"""A dive plan flown by the vehicle node (issue 29, "Flying it"; rovlab.interfaces.node.flight):
the node commands the plan's Flyer wrench through its allocation and PWM, and every guard aborts
the flight to neutral. Samples are pushed by hand here (no middleware); the bridge's end-to-end
flight against `rovlab mavlink sim` is tests/mavlink/test_bridge_fly.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.ident.plan import plan_dive
from rovlab.interfaces.node.core import NodeCore
from rovlab.interfaces.node.flight import FlightGuards, PlanFlight
from rovlab.params.design import load_design_config


@pytest.fixture(scope="module")
def plan(heavy):
    return plan_dive(heavy, ("heave", "yaw"), 30.0, seed=3)


@pytest.fixture()
def core(heavy):
    return NodeCore(heavy, load_design_config("bluerov2_heavy"), log=lambda msg: None)


class Feeder:
    """Depth, heading and yaw-rate samples at every control step, with a little noise (a channel that
    repeats one value exactly is 'stuck' to the filter's sensor management)."""

    def __init__(self, core: NodeCore) -> None:
        self.core = core
        self.k = 0
        self.rng = np.random.default_rng(0)
        self.noise = 1e-3

    def step(self, z: float | None = 2.0, psi: float = 0.3, r: float = 0.0):
        c = self.core
        values = {"z": z, "psi": math.remainder(psi, 2 * math.pi), "r": r}
        for ch in c.channels:
            v = values.get(ch.quantity, 0.0)  # x, y, u, v, w of a DVL vehicle: at rest
            if v is not None:
                c.push(ch.sensor, ch.quantity, v + ch.offset + self.noise * self.rng.standard_normal(), self.k * c.h)
        outs = c.tick(self.k * c.h + c.collect_s + 1e-9)
        self.k += 1
        assert len(outs) == 1
        return outs[0]


def _neutral(out) -> bool:
    return not out.engaged and np.allclose(out.tau, 0.0) and np.allclose(out.pwm_us, 1500.0, atol=1.0)


def test_the_node_flies_the_plans_wrench_then_goes_neutral(core, plan):
    """Each step's demanded wrench is the plan's Flyer's for the latest depth sample (computed here
    independently), the PWM is what the allocation gives for it, and at the plan's end the flight
    is complete and the thrusters neutral."""
    feed = Feeder(core)
    flight = core.fly(plan)
    assert flight.state == "waiting"
    for _ in range(5):
        assert _neutral(feed.step())
    core.start_flight()
    flyer = plan.flyer()
    depths = 2.0 + 1.2 * np.sin(np.arange(len(plan.Z)) * 0.02)  # out of the band (1-3 m), inside the margin
    differed = 0
    for i in range(len(plan.Z)):
        out = feed.step(z=float(depths[i]))
        expected, _ = flyer.step(i, out.y[core.depth_channel()])  # the sample of this step, as the node used it
        assert out.flight in ("flying", "complete") and out.engaged
        assert out.tau == pytest.approx(expected, abs=1e-9)
        differed += int(not np.allclose(out.pwm_us, 1500.0, atol=1.0))
    assert flight.state == "complete" and flight.duration_s == pytest.approx(plan.duration_s)
    assert differed > 0.9 * len(plan.Z)  # the thrusters did fly it
    assert 0 < flight.guard_steps < len(plan.Z)  # the plan's own guard paused the excitation outside the band
    after = feed.step()
    assert _neutral(after) and after.flight == "complete"
    assert "flight complete" in flight.summary()


@pytest.mark.parametrize("case", ["deep", "shallow", "turns", "yaw_rate", "pressure_lost", "adapter"])
def test_each_guard_aborts_the_flight_to_neutral(core, plan, case):
    guards = FlightGuards(turns=0.5, yaw_rate_rad_s=2.0)
    feed = Feeder(core)
    flight = core.fly(plan, guards)
    for _ in range(3):
        feed.step()
    core.start_flight()
    for _ in range(10):
        assert feed.step().engaged
    lo, hi = flight.depth_limits()
    assert (lo, hi) == pytest.approx((plan.depth_min - 0.5, plan.depth_max + 0.5))
    psi = 0.3
    for _ in range(200):
        if case == "deep":
            feed.step(z=hi + 0.3)
        elif case == "shallow":
            feed.step(z=lo - 0.3)
        elif case in ("turns", "yaw_rate"):
            rate = 1.5 if case == "turns" else 3.0  # below / above the 2 rad/s guard
            psi += rate * core.h
            feed.step(psi=psi, r=rate)
        elif case == "pressure_lost":
            feed.step(z=None)
        else:
            core.abort_flight("pilot input: a test")
            feed.step()
        if flight.ended:
            break
    assert flight.state == "aborted", flight.summary()
    reason = {"deep": "depth guard", "shallow": "depth guard", "turns": "heading guard", "yaw_rate": "yaw-rate guard",
              "pressure_lost": "depth sensor", "adapter": "pilot input"}[case]
    assert flight.reason.startswith(reason), flight.reason
    if case == "turns":
        assert abs(flight.turned) > 2 * math.pi * 0.5 and flight.max_yaw_rate < 2.0
    assert _neutral(feed.step()) and _neutral(feed.step())
    assert "FLIGHT ABORTED" in flight.summary() and reason in flight.summary()


def test_the_depth_guard_reads_the_sample_not_only_the_estimate(core, plan):
    """One depth sample beyond the margin aborts at once (the filter's estimate lags behind it)."""
    feed = Feeder(core)
    flight = core.fly(plan)
    feed.step()
    core.start_flight()
    feed.step()
    feed.step(z=plan.depth_max + 0.6)
    assert flight.state == "aborted" and "measured depth" in flight.reason


def test_guards_and_plans_the_node_cannot_fly_are_refused(core, plan):
    for bad in (FlightGuards(turns=0.0), FlightGuards(depth_margin_m=math.nan), FlightGuards(yaw_rate_rad_s=50.0),
                FlightGuards(start_tolerance_m=-1.0)):
        with pytest.raises(ValueError, match="flight guard"):
            core.fly(plan, bad)
    assert core.flight is None
    from dataclasses import replace

    with pytest.raises(ValueError, match="whole multiple"):
        PlanFlight(replace(plan, dt=0.15), h=core.h)
    with pytest.raises(ValueError, match="no plan loaded"):
        core.start_flight()
    assert FlightGuards().for_plan(plan).yaw_rate_rad_s == pytest.approx(2.0 * plan.settings["yaw_rate"])


def test_a_surge_and_sway_plan_flies_on_the_estimated_position_or_is_refused(udrone_dvl, udrone_dp):
    """A horizontal plan's Flyer needs the heading and the position (its heading law and box guard):
    the node gives it the filter's estimate, and refuses the plan where the filter has no x, y."""
    from rovlab.params.vehicle import load_vehicle

    heavy_dvl = load_vehicle("bluerov2_heavy_dvl")
    depth_only = NodeCore(heavy_dvl, load_design_config("bluerov2_heavy"), log=lambda msg: None)
    with pytest.raises(ValueError, match="estimated position and heading"):
        depth_only.fly(plan_dive(heavy_dvl, ("heave", "yaw", "surge"), 60.0, seed=1))
    assert depth_only.flight is None
    core = NodeCore(udrone_dvl, udrone_dp, log=lambda msg: None)
    flight = core.fly(plan_dive(udrone_dvl, ("heave", "surge"), 30.0, seed=1))
    feed = Feeder(core)
    feed.noise = 1e-2
    for _ in range(5):
        feed.step(z=2.0)
    core.start_flight()
    surge = [feed.step(z=2.0).tau[0] for _ in range(100)]
    assert flight.state == "flying" and np.ptp(surge) > 1.0  # the surge excitation is flown


def test_past_half_the_turns_guard_the_yaw_moment_unwinds(core, plan):
    """Beyond half the turns guard (here 1 turn: half a turn) a yaw moment that would turn the
    heading further is flown with the opposite sign, the same magnitude; one that unwinds is kept."""
    feed = Feeder(core)
    feed.noise = 1e-2  # 30 s of one depth: 1 mm of noise looks stuck to the filter
    flight = core.fly(plan, FlightGuards(turns=1.0, yaw_rate_rad_s=5.0))
    feed.step()
    core.start_flight()
    flyer = plan.flyer()
    psi, flipped, kept = 0.3, 0, 0
    for i in range(len(plan.Z) - 1):
        psi += 0.25 * core.h  # turning positive, 0.25 rad/s: half a turn after 12.6 s
        out = feed.step(psi=psi, r=0.25)
        expected, _ = flyer.step(i, out.y[core.depth_channel()])
        beyond = abs(flight.turned) > math.pi  # as the flight saw it before this step's command (lags a step)
        if beyond and expected[3] > 0:
            flipped += int(out.tau[3] == pytest.approx(-expected[3]))
        elif beyond and expected[3] < 0:
            kept += int(out.tau[3] == pytest.approx(expected[3]))
        if flight.ended:
            break
    assert flipped > 10 and kept > 10 and flight.unwound_steps >= flipped - 1
    assert flight.report()["unwound_s"] > 1.0 and "flipped to unwind" in flight.summary()
