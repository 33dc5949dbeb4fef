"""A dive plan flown by the vehicle node, with the guards that abort it (issue 29, "Flying it").

A plan (rovlab.ident.plan.DivePlan, written by ``rovlab lab plan-dive``) is flown by the node core
(rovlab.interfaces.node.core.NodeCore.fly) instead of its controller: each control step the wrench
comes from the plan's :class:`~rovlab.ident.plan.Flyer` (excitation + trim + the weak depth law,
whose guard pauses the excitation outside the depth band), with the latest depth sample as the
depth law's input (as ``rovlab lab dive`` flies it), and goes through the node's allocation and PWM
path (rovlab.control.open_loop), so the filter predicts with the thrust actually commanded and the
adapters send and record the PWM that ``rovlab identify dive`` reads.

The flight **aborts** (the node goes neutral and holds nothing; the reason is said and kept) on:

* depth: the estimate or the latest depth sample shallower than ``depth_min - depth_margin_m`` or
  deeper than ``depth_max + depth_margin_m`` (the plan's own guard acts inside the margin), or the
  filter's pressure channel not 'ok'/'recovering' (lost, timed out: the depth would be a prediction);
* heading: the heading turned more than ``turns`` full turns either way from where the flight
  started (the yaw excitation spins the vehicle; a tether winds up), or a yaw rate beyond
  ``yaw_rate_rad_s`` (default twice the plan's ``yaw_rate`` setting, at least 1 rad/s);
* anything the adapter reports (:meth:`PlanFlight.abort`): lost telemetry or link, a mode change
  or disarm by someone else, another ground station's stick input, a set-point or an abort message.

**Unwinding.** The plan's yaw moment is open loop, so the heading wanders (measured on
``rovlab mavlink sim``: two of three 300 s flights reached two turns and were aborted). Once the
heading has turned more than half the turns guard from the start, a yaw moment that would turn it
further is commanded with the opposite sign (same magnitude and hold): the excitation stays as
rich, the identification reads the PWM actually commanded, and the model is symmetric in N. The
steps so flipped are counted (``unwound_s`` in the report).

States: ``waiting`` (loaded; the adapter starts it once the vehicle obeys at the start depth),
``flying``, then ``complete`` or ``aborted``. :meth:`PlanFlight.report` says what was flown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

STATES = ("waiting", "flying", "complete", "aborted")
START_SETTLE_S = 2.0  # an adapter starts the plan once the depth has been within the start tolerance this long
END_NEUTRAL_S = 1.0  # neutral commands this long after the flight ended, before an adapter stops
# accepted ranges of the guards (CLI options --fly-guard-*; ValueError outside)
GUARD_RANGES: dict[str, tuple[float, float, str]] = {
    "depth_margin_m": (0.1, 5.0, "m"),
    "turns": (0.25, 20.0, "turns"),
    "yaw_rate_rad_s": (0.1, 10.0, "rad/s"),
    "start_tolerance_m": (0.05, 2.0, "m"),
}


@dataclass(frozen=True)
class FlightGuards:
    """What aborts a plan's flight (module docstring). ``yaw_rate_rad_s`` None: twice the plan's."""

    depth_margin_m: float = 0.5
    turns: float = 2.0
    yaw_rate_rad_s: float | None = None
    start_tolerance_m: float = 0.3  # how close to the plan's start depth the flight may start

    def validated(self) -> FlightGuards:
        """Itself, or ValueError naming the guard, its value and the accepted range."""
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name == "yaw_rate_rad_s":
                continue
            lo, hi, unit = GUARD_RANGES[f.name]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"flight guard {f.name} must be within {lo:g} .. {hi:g} {unit}, got {v!r}")
        return self

    def for_plan(self, plan: Any) -> FlightGuards:
        """With the yaw-rate limit filled in from the plan (twice its yaw_rate, at least 1 rad/s)."""
        if self.yaw_rate_rad_s is not None:
            return self
        planned = plan.settings.get("yaw_rate", 1.0) if isinstance(plan.settings, dict) else 1.0
        try:
            planned = float(planned)
        except (TypeError, ValueError):
            planned = 1.0
        if not (math.isfinite(planned) and planned > 0):
            planned = 1.0
        return replace(self, yaw_rate_rad_s=min(max(2.0 * planned, 1.0), GUARD_RANGES["yaw_rate_rad_s"][1]))


class PlanFlight:
    """One flight of a plan (module docstring); stepped by the node core under its lock."""

    def __init__(self, plan: Any, guards: FlightGuards | None = None, *, h: float) -> None:
        self.plan = plan
        self.guards = (guards or FlightGuards()).validated().for_plan(plan)
        ratio = float(plan.dt) / float(h)
        if not (ratio >= 1.0 - 1e-9 and abs(ratio - round(ratio)) < 1e-6):
            raise ValueError(f"the plan's command step {plan.dt:g} s must be a whole multiple of the node's control "
                             f"period {h:g} s")
        self.per_command = int(round(ratio))  # control steps per plan command
        self.h = float(h)
        self.flyer = plan.flyer()
        self.state = "waiting"
        self.reason = ""  # why it aborted
        self.steps = 0  # control steps flown
        self.guard_steps = 0  # of which with the plan's depth guard on (excitation paused)
        self.unwound_steps = 0  # of which with the yaw moment's sign flipped to unwind the heading
        self.start_stamp: float | None = None
        self.end_stamp: float | None = None
        self.start_k: int | None = None
        self._psi0: float | None = None
        self._psi_last: float | None = None
        self.turned = 0.0  # heading change since the start [rad], unwrapped
        self.depth_range = (math.inf, -math.inf)
        self.max_yaw_rate = 0.0

    # -- what it is doing ---------------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        return len(self.plan.Z) * self.per_command

    @property
    def active(self) -> bool:
        return self.state == "flying"

    @property
    def ended(self) -> bool:
        return self.state in ("complete", "aborted")

    @property
    def duration_s(self) -> float:
        return self.steps * self.h

    def depth_limits(self) -> tuple[float, float]:
        m = self.guards.depth_margin_m
        return self.plan.depth_min - m, self.plan.depth_max + m

    # -- the node core's side -----------------------------------------------------------------
    def start(self, k: int, stamp: float) -> None:
        if self.state != "waiting":
            raise ValueError(f"the flight is {self.state}, it cannot start")
        self.state = "flying"
        self.start_k = k
        self.start_stamp = stamp

    def wrench(self, depth: float, **horizontal: Any) -> list[float]:
        """The wrench [X, Y, Z, N] of the current step for the measured depth [m] (and, for a surge
        and sway plan, the estimated heading, rate and position: rovlab.ident.plan.Flyer.step)."""
        i = min(self.steps // self.per_command, len(self.plan.Z) - 1)
        tau, guarded = self.flyer.step(i, depth, **horizontal)
        self.guard_steps += int(guarded)
        out = [float(v) for v in tau]
        if abs(self.turned) > math.pi * self.guards.turns and out[3] * self.turned > 0.0:
            out[3] = -out[3]  # turning further: the same moment the other way (module docstring)
            self.unwound_steps += 1
        return out

    def after_step(self, stamp: float, *, z: float, z_sample: float | None, psi: float | None, r: float | None,
                   depth_status: str) -> None:
        """Count the step and check the guards on the corrected estimate (and the latest depth
        sample); complete at the plan's end."""
        self.steps += 1
        lo, hi = self.depth_limits()
        zs = [v for v in (z, z_sample) if v is not None and math.isfinite(v)]
        if zs:
            self.depth_range = (min(self.depth_range[0], *zs), max(self.depth_range[1], *zs))
        if depth_status not in ("ok", "recovering"):
            return self.abort(f"depth sensor: the filter's pressure channel is {depth_status} (its depth would be a "
                              "prediction)", stamp)
        if not zs:
            return self.abort("depth sensor: no depth", stamp)
        for what, v in (("estimated", z), ("measured", z_sample)):
            if v is not None and math.isfinite(v) and not lo <= v <= hi:
                return self.abort(f"depth guard: {what} depth {v:.2f} m is outside {lo:.2f} .. {hi:.2f} m (the plan's "
                                  f"band {self.plan.depth_min:g} .. {self.plan.depth_max:g} m with a margin of "
                                  f"{self.guards.depth_margin_m:g} m)", stamp)
        if psi is not None and math.isfinite(psi):
            if self._psi0 is None:
                self._psi0 = self._psi_last = psi
            else:
                assert self._psi_last is not None
                self.turned += math.remainder(psi - self._psi_last, 2.0 * math.pi)
                self._psi_last = psi
            if abs(self.turned) > 2.0 * math.pi * self.guards.turns:
                return self.abort(f"heading guard: turned {self.turned / (2 * math.pi):+.2f} turns since the start, "
                                  f"beyond +-{self.guards.turns:g} (the tether winds up)", stamp)
        if r is not None and math.isfinite(r):
            self.max_yaw_rate = max(self.max_yaw_rate, abs(r))
            limit = float(self.guards.yaw_rate_rad_s or math.inf)
            if abs(r) > limit:
                return self.abort(f"yaw-rate guard: {math.degrees(r):+.0f} deg/s, beyond +-{math.degrees(limit):.0f} "
                                  "deg/s", stamp)
        if self.steps >= self.n_steps:
            self.state = "complete"
            self.end_stamp = stamp
        return None

    def abort(self, reason: str, stamp: float | None = None) -> None:
        """Abort (a no-op once ended); the reason is kept for the report."""
        if self.ended:
            return
        self.state = "aborted"
        self.reason = reason
        self.end_stamp = stamp

    # -- what it did --------------------------------------------------------------------------
    def report(self) -> dict[str, Any]:
        return {"state": self.state, "reason": self.reason, "flown_s": round(self.duration_s, 3),
                "plan_s": round(self.n_steps * self.h, 3), "guard_s": round(self.guard_steps * self.h, 3),
                "unwound_s": round(self.unwound_steps * self.h, 3),
                "turns": round(self.turned / (2 * math.pi), 3),
                "depth_range_m": [round(v, 3) for v in self.depth_range] if self.steps else [],
                "max_yaw_rate_deg_s": round(math.degrees(self.max_yaw_rate), 1),
                "start_stamp": self.start_stamp, "end_stamp": self.end_stamp}

    def summary(self) -> str:
        r = self.report()
        head = {"waiting": "flight not started", "flying": "flying", "complete": "flight complete",
                "aborted": "FLIGHT ABORTED"}[self.state]
        text = (f"{head}: {r['flown_s']:.1f} of {r['plan_s']:.1f} s of the plan flown, {r['guard_s']:.1f} s with its "
                f"depth guard on (excitation paused), {r['unwound_s']:.1f} s with the yaw moment flipped to unwind")
        if self.steps:
            text += (f", depth {r['depth_range_m'][0]:.2f} .. {r['depth_range_m'][1]:.2f} m, turned {r['turns']:+.2f} "
                     f"turns, yaw rate up to {r['max_yaw_rate_deg_s']:.0f} deg/s")
        if self.reason:
            text += f"; {self.reason}"
        return text


__all__ = ["END_NEUTRAL_S", "GUARD_RANGES", "START_SETTLE_S", "STATES", "FlightGuards", "PlanFlight"]
