"""An unplanned dive: a pilot flying a BlueROV2 by joystick in ArduSub's MANUAL mode (issue 29,
"Measured here": what ``rovlab identify dive`` gives on a dive nobody planned for it).

Nothing here is an excitation design. The pilot strings together what pilots do in a pool: descend
to a depth, look around holding it by eye, turn towards something, run forward, ascend a little,
and pause. In MANUAL mode the autopilot holds nothing: each stick maps to a share of the thrust in
its DOF times the joystick gain (ArduSub's JS_GAIN_DEFAULT, 0.5 by default per ArduSub's parameter
documentation), so the slightly heavy vehicle sinks unless the pilot corrects. The pilot's hand is
a first-order lag (0.3 s, an assumption) on the intended stick position, quantised to the 1/1000
steps of MAVLink's MANUAL_CONTROL, with a 5 % dead zone around the centre (an assumption: the
ground station sets it); the pilot reads the depth off the screen (the logged 2 Hz depth) and corrects
by eye: only once it is off by more than 15-25 cm, with a gentle 10-25 % stick, until back within
10 cm. Surge runs are flown too (the 4-DOF plant moves), although identify dive models heave and
yaw only.

:func:`pilot_dive` returns a plan-like object that :func:`rovlab.ident.dive.fly_plan` flies with
the same hidden vehicle, thrusters and sensors as a planned dive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rovlab.params.vehicle import Vehicle

GAIN = 0.5  # ArduSub's joystick gain JS_GAIN_DEFAULT (default 0.5): full stick = 50 % of the thrust in that DOF
HAND_TAU_S = 0.3  # the pilot's hand on the stick: first-order lag [s]
DEAD_ZONE = 0.05  # stick share zeroed around the centre
TASKS = ("descend", "hold", "turn", "forward", "ascend", "pause")


@dataclass(frozen=True, eq=False)
class PilotDive:
    """What :func:`rovlab.ident.dive.fly_plan` needs of a plan: the command step, the number of
    steps (``Z``: zeros, one per step), the start depth and a flyer (the pilot)."""

    vehicle: str
    dt: float
    Z: np.ndarray
    start_depth: float
    depth_min: float
    depth_max: float
    capacity: dict[str, tuple[float, float]]
    seed: int
    gain: float = GAIN
    forward_runs: bool = True  # False: the pilot never uses the forward stick (heave and yaw only)
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(len(self.Z) * self.dt)

    def flyer(self) -> Pilot:
        return Pilot(self)


class Pilot:
    """A pilot's stick inputs at each command step, from the depth on the screen (module docstring)."""

    def __init__(self, dive: PilotDive) -> None:
        self.d = dive
        self.rng = np.random.default_rng([dive.seed, 29])
        self.stick = np.zeros(4)  # X, Y, Z, N shares in [-1, 1] as the hand holds them
        self.target_depth = dive.start_depth
        self.task = "hold"
        self.until = 0.0
        self.intent = np.zeros(4)
        self.correcting = 0.0  # heave stick of a depth correction in progress
        self.tasks: list[tuple[float, str]] = []

    def _next_task(self, t: float, depth: float) -> None:
        rng, d = self.rng, self.d
        weights = np.array([1.0, 2.0, 2.0, 1.5 if d.forward_runs else 0.0, 1.0, 0.7])
        task = str(rng.choice(TASKS, p=weights / weights.sum()))
        self.intent = np.zeros(4)
        if task in ("descend", "ascend"):
            lo, hi = d.depth_min + 0.2, d.depth_max - 0.2
            new = float(rng.uniform(lo, hi))
            if abs(new - depth) < 0.4:  # not worth it: look around instead
                task = "hold"
            else:
                self.target_depth = new
                task = "descend" if new > depth else "ascend"
                # descend = throttle down: a positive (down, NED) heave force
                self.intent[2] = math.copysign(float(rng.uniform(0.2, 0.5)), new - depth)
                self.until = t + 30.0  # at most; ends on reaching the depth
        if task == "hold":
            self.until = t + float(rng.uniform(5.0, 25.0))
        elif task == "turn":
            self.intent[3] = float(rng.choice((-1.0, 1.0)) * rng.uniform(0.15, 0.5))
            self.until = t + float(rng.uniform(0.5, 2.5))
        elif task == "forward":
            self.intent[0] = float(rng.uniform(0.3, 0.8))
            self.until = t + float(rng.uniform(4.0, 15.0))
        elif task == "pause":  # hands off the sticks
            self.until = t + float(rng.uniform(2.0, 8.0))
        self.task = task
        self.tasks.append((t, task))

    def step(self, k: int, depth: float) -> tuple[list[float], bool]:
        d = self.d
        t = k * d.dt
        if k == 0:
            self._next_task(t, depth)
        elif t >= self.until or (self.task == "descend" and depth >= self.target_depth) or (
                self.task == "ascend" and depth <= self.target_depth):
            self._next_task(t, depth)
        intent = self.intent.copy()
        if self.task in ("hold", "turn", "forward"):  # keep the depth by eye, with a gentle hand
            err = depth - self.target_depth
            if self.correcting == 0.0 and abs(err) > float(self.rng.uniform(0.15, 0.25)):
                self.correcting = -math.copysign(float(self.rng.uniform(0.1, 0.25)), err)
            elif self.correcting != 0.0 and abs(err) < 0.1:
                self.correcting = 0.0
            intent[2] = self.correcting
            if self.task == "forward" and self.rng.uniform() < 0.01:  # a small heading correction now and then
                intent[3] = float(self.rng.uniform(-0.15, 0.15))
        else:
            self.correcting = 0.0
        if depth < d.depth_min - 0.3 or depth > d.depth_max + 0.3:  # too far: back towards the middle, firmly
            intent[2] = 0.4 if depth < d.depth_min else -0.4
        a = d.dt / (HAND_TAU_S + d.dt)
        self.stick += a * (intent - self.stick)
        cmd = np.round(self.stick * 1000.0) / 1000.0  # MANUAL_CONTROL's -1000..1000
        cmd[np.abs(cmd) < DEAD_ZONE] = 0.0
        tau = []
        for i, dof in enumerate(("surge", "sway", "heave", "yaw")):
            lo, hi = d.capacity.get(dof, (0.0, 0.0))  # (surge and sway: where dof_capacity gives them)
            s = float(cmd[i]) * d.gain
            tau.append(s * (hi if s > 0 else -lo))
        return tau, False


def pilot_dive(vehicle: Vehicle, duration_s: float = 300.0, *, seed: int = 0, depth_min: float = 1.0,
               depth_max: float = 3.0, start_depth: float = 1.5, dt: float = 0.1, gain: float = GAIN,
               forward_runs: bool = True) -> PilotDive:
    """A pilot-flown dive of ``duration_s`` for :func:`rovlab.ident.dive.fly_plan` (module docstring)."""
    if not duration_s > 0 or not math.isfinite(duration_s):
        raise ValueError(f"duration {duration_s!r} s: expected a positive number of seconds")
    if not 0.3 <= depth_min < depth_max:
        raise ValueError(f"depth band {depth_min:g} .. {depth_max:g} m: expected 0.3 m <= top < bottom (submerged)")
    if not 0 < gain <= 1:
        raise ValueError(f"pilot gain {gain!r}: expected a share of the thrust in 0 .. 1")
    from rovlab.ident.plan import dof_capacity

    n = int(round(duration_s / dt))
    return PilotDive(vehicle.name, dt, np.zeros(n), float(start_depth), float(depth_min), float(depth_max),
                     dict(dof_capacity(vehicle)), int(seed), float(gain), bool(forward_runs),
                     {"kind": "pilot", "gain": gain, "hand_tau_s": HAND_TAU_S, "dead_zone": DEAD_ZONE,
                      "forward_runs": forward_runs})
