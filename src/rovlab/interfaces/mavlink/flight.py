"""``rovlab mavlink bridge --fly PLAN``: a dive plan flown on an ArduSub vehicle in MANUAL.

The node core flies the plan (rovlab.interfaces.node.flight: the plan's wrench through the
allocation and PWM, its depth and heading guards); this adapter decides when it may start and
what else aborts it, on what the bridge sees of the vehicle:

* **start**: the vehicle armed in MANUAL (``--arm`` does both), the vehicle file checked, telemetry
  and a plausible depth, and the estimated depth within ``start_tolerance_m`` of the plan's
  ``start_depth``. Away from it, the configuration's depth controller holds the start depth first
  (the bridge's own set-point, with its safety rules) until the depth has been within the tolerance
  for START_SETTLE_S; a configuration without a depth controller says what the pilot must do.
* **abort** (neutral from the next command, the hold dropped, said loudly, exit status 1): any
  guard of the node core's flight; no telemetry for the bridge's ``telemetry_timeout_s``; the
  depth sensor implausible or lost; the vehicle disarmed or switched out of MANUAL (a pilot or a
  failsafe took it); MANUAL_CONTROL or RC_CHANNELS_OVERRIDE from another system on the link (a
  pilot's joystick on a shared link). Before the start the same events abort a flight that was
  ready once (a vehicle disarmed after arming is never re-armed by the bridge).
* **recording**: SERVO_OUTPUT_RAW (the PWM the vehicle applies, which identify dive takes as the
  input) is asked at SERVO_HZ instead of the control rate, so the input it holds lags less.
* **end**: the report (flown, guard time, aborted or complete) is logged and recorded as a
  ``/rovlab/flight`` message in the MCAP; neutral commands for END_NEUTRAL_S, then the bridge
  stops (its close() sends neutral and disarms what it armed).
"""

from __future__ import annotations

import math
import time
from typing import Any

from rovlab.core.components import TRUTH_INDEX
from rovlab.interfaces.mavlink.ardusub import MODE_NAMES, MODES
from rovlab.interfaces.node.flight import END_NEUTRAL_S, START_SETTLE_S

# SERVO_OUTPUT_RAW asked at this rate for a flight: rovlab identify dive holds each PWM until the next
# one, so at the control rate (10 Hz) the input it sees lags the thrust applied by up to a period
SERVO_HZ = 50.0
PILOT_MESSAGES = ("MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE")


class BridgeFlight:
    """A plan's flight on a MavlinkBridge (module docstring); :meth:`step` runs in bridge.step."""

    def __init__(self, bridge: Any, plan: Any, guards: Any = None, *, stop_when_done: bool = True) -> None:
        self.bridge = bridge
        self.plan = plan
        self.flight = bridge.core.fly(plan, guards)  # ValueError: a plan this node cannot fly
        if "SERVO_OUTPUT_RAW" in bridge.rate_wanted:
            bridge.rate_wanted["SERVO_OUTPUT_RAW"] = max(bridge.rate_wanted["SERVO_OUTPUT_RAW"], SERVO_HZ)
        self.stop_when_done = bool(stop_when_done)
        self.phase = "waiting"  # waiting -> (descending) -> flying -> ended
        self._ready_once = False
        self._near_since: float | None = None
        self._ended_at: float | None = None
        self._pilot: str | None = None  # another system's stick input seen on the link

    @property
    def guards(self) -> Any:
        return self.flight.guards

    def pilot_input(self, msg: Any) -> None:
        """A MANUAL_CONTROL / RC_CHANNELS_OVERRIDE seen from another system (bridge._handle)."""
        if self._pilot is None:
            self._pilot = (f"pilot input: {msg.get_type()} from system {msg.get_srcSystem()} on the link (another "
                           "ground station's joystick)")

    def closing(self) -> None:
        """The bridge closes (Ctrl-C, --duration, an error) before the flight ended: abort it, say so
        and record it, so the recording says why it stops where it does."""
        f = self.flight
        if f.ended:
            return
        f.abort("the bridge was stopped before the plan's end" if f.active
                else "the bridge was stopped before the flight started")
        self.phase = "ended"
        self.bridge.log(("ABORTED TO NEUTRAL: " if f.steps else "") + f.summary())
        self._record(f.state, time.time())
        if self.bridge.exit_code == 0:
            self.bridge.exit_code = 1

    def _record(self, event: str, wall: float) -> None:
        rec = self.bridge.recorder
        if rec is not None:
            rec.rovlab("/rovlab/flight", wall, {"event": event, "plan": {
                "vehicle": self.plan.vehicle, "duration_s": self.plan.duration_s, "start_depth": self.plan.start_depth,
                "depth_band": [self.plan.depth_min, self.plan.depth_max], "seed": self.plan.seed},
                **self.flight.report()})

    def _why_not(self, now: float) -> str | None:
        """Why the bridge cannot fly now (None: it can)."""
        b = self.bridge
        if self._pilot is not None:
            return self._pilot
        if not b.vehicle_seen:
            return f"no vehicle seen yet on {b.connect} (no HEARTBEAT of system {b.target_system})"
        if b.vehicle_problems != []:
            return "the vehicle file is not checked against the vehicle yet"
        if b.telemetry_lost(now):
            return f"no telemetry for {b.telemetry_timeout_s:g} s (lost link)"
        if b.depth_problem is not None:
            return "depth sensor: " + b.depth_problem
        if not b.armed:
            return "the vehicle is disarmed"
        if b.mode != MODES["MANUAL"]:
            mode = b.mode if b.mode is not None else -1
            return f"the vehicle is in mode {MODE_NAMES.get(mode, mode)}, not MANUAL"
        return None

    def step(self, now: float) -> None:
        b = self.bridge
        f = self.flight
        if self.phase == "flying" and not f.ended:
            why = self._why_not(now)
            if why is None and b.engaged:  # a set-point (the HMI, a script) during the flight: someone else commands
                why = "pilot input: a set-point was given to the bridge (the HMI or a script); it is dropped"
            if why is not None:
                b.core.abort_flight(why)
        if f.ended and self.phase != "ended":
            self.phase = "ended"
            self._ended_at = now
            b.disengage()
            loud = "" if f.state == "complete" else "ABORTED TO NEUTRAL: "
            b.log(f"{loud}{f.summary()}")
            self._record(f.state, time.time())
            if f.state == "aborted" and b.exit_code == 0:
                b.exit_code = 1
        if self.phase == "ended":
            if self.stop_when_done and self._ended_at is not None and now - self._ended_at >= END_NEUTRAL_S:
                b.stop()
            return
        if self.phase == "flying":
            return
        why = self._why_not(now)
        if why is None:
            self._ready_once = True
        elif self._ready_once or self._pilot is not None:
            b.core.abort_flight("before the start: " + why)
            return self.step(now)
        else:
            b._say_limited("fly-wait", f"flight of the plan waits: {why}", now)
            return
        last = b.core.last
        if last is None:
            return
        z = float(last.nav[TRUTH_INDEX["z"]])
        start, tol = self.plan.start_depth, self.guards.start_tolerance_m
        near = abs(z - start) <= tol
        if near and (self.phase == "waiting" or (self._near_since is not None and now - self._near_since >= START_SETTLE_S)):
            if b.engaged:
                b.disengage()
            b.core.start_flight()
            self.phase = "flying"
            b.log(f"flying the plan: {self.plan.duration_s:.0f} s of {', '.join(self.plan.dofs)} excitation from "
                  f"{z:.2f} m, depth band {self.plan.depth_min:g} .. {self.plan.depth_max:g} m (abort outside "
                  f"{f.depth_limits()[0]:.2f} .. {f.depth_limits()[1]:.2f} m, beyond +-{self.guards.turns:g} turns or "
                  f"{math.degrees(self.guards.yaw_rate_rad_s):.0f} deg/s, on lost telemetry or pilot input)")
            self._record("start", time.time())
            return
        if near:
            self._near_since = self._near_since if self._near_since is not None else now
            return
        self._near_since = None
        if "z" in b.core.references:
            if self.phase != "descending":
                self.phase = "descending"
                b.log(f"going to the plan's start depth {start:g} m (now {z:.2f} m) with the depth controller of "
                      f"{b.core.config.name}; the flight starts {START_SETTLE_S:g} s after the depth is within "
                      f"{tol:g} m of it")
                b.set_reference(z=start)
        else:
            b._say_limited("fly-wait", f"bring the vehicle to the plan's start depth {start:g} m (now {z:.2f} m; "
                                       f"{b.core.config.name} has no depth controller): the flight starts within "
                                       f"{tol:g} m of it", now)


__all__ = ["BridgeFlight", "END_NEUTRAL_S", "PILOT_MESSAGES", "SERVO_HZ", "START_SETTLE_S"]
