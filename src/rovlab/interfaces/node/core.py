"""The vehicle node without middleware: samples in, estimate and thruster commands out.

:class:`NodeCore` runs the configured estimator and controller (rovlab.sim.components: ``kf``,
``lqg``, ``mrac`` ...) on the vehicle, one control step every ``h`` seconds (the
configuration's sample time), through the same compiled slots as the simulator
(rovlab.sim.step.control_step), so fed the samples of a simulation it computes the
simulation's estimates and commands exactly. The ROS 2, ROS 1 and MAVLink adapters and the HMI
all sit on it; it imports no middleware and does no maths of its own.

API (stable; additions only)::

    core = NodeCore(vehicle, config)            # designs and compiles once (says so on stderr)
    core.push(sensor, quantity, value, stamp)   # -> "accepted" | "late" | "out-of-order" | ...
    core.set_reference(z=2.0, psi=0.5)          # engages the controller (until then: neutral PWM)
    for out in core.tick(now):                  # runs the steps that are due; never blocks
        publish(out.x, out.P, out.channel_status, out.tau, out.pwm_us)
    core.apply(config=new_config)               # redesign, keep the state; ConfigError: no change
    core.set_sensor_enabled("qualisys", False)  # its samples are dropped (the filter times it out)
    core.set_filter_mode("qualisys.z", "off")   # force a channel off / on / back to "auto"
    flight = core.fly(plan)                     # a dive plan instead of the controller (loaded, waiting)
    core.start_flight(); core.abort_flight(why) # fly it from the next step; abort to neutral

Units and frames are rovlab's (SI, radians, NED world, FRD body): adapters convert at their edge.

**Clock.** Times (``stamp``, ``now``) are seconds on the adapter's clock (ROS time, Unix time,
a test's counter). Step k is due at T_k = t0 + k h; t0 is the stamp of the first sample pushed
(or ``now`` of the first :meth:`tick` if none came), so the steps line up with a sensor that
samples at the control rate. The filter sees the time k h. With ``wait_for_samples_s`` > 0
(the ROS nodes use 10 s) ticks before the first sample run nothing for that long, so a node started
before its sensors does not dead-reckon (and time its sensors out) before they ever spoke.

**Samples.** A sample belongs to the step nearest its stamp, and every sample is used, at any
rate: a step corrects the filter with the newest sample of each channel that belongs to it (or to
an earlier step), and, before that, with the older ones of a channel that sent several in the
same period (a 20 Hz heading at h = 0.1 s), one after another in the order of their stamps
(several channels in one correction as long as none repeats) -- as the offline filter fuses
several rows of one period (rovlab.estimation.streaming), so a live node and ``rovlab filter`` on
its recording use the same samples. A sample of an earlier period that arrived after its step
ran is used at the next step only if no newer sample of its channel came (else ``replaced``: it
would be fused a period late). What can happen to a sample is returned by :meth:`push` and
counted in :attr:`counters`:

* ``accepted``: stored for its step (at most ``max_queue`` samples of a channel wait for one
  step; beyond that the oldest is dropped and ``replaced`` is counted);
* ``late``: its step is more than ``max_lag`` steps before the next one (default 1: a sample that
  arrived just after its step ran is still used at the next step);
* ``out-of-order``: not newer than a sample of the same channel already stored or used;
* ``unused``: no filter channel fuses this sensor quantity (e.g. motion capture x); not an error;
* ``disabled``: the sensor is switched off (:meth:`set_sensor_enabled`);
* ``future``: stamped more than ``max_ahead_s`` after the step being collected (clock mismatch);
  dropped;
* ``invalid``: not a finite number or timestamp (``last_problem`` says what and where).

A step runs as soon as every enabled channel has a sample for it (low latency), and at the latest at
T_k + ``collect_s`` (default h / 2) with whatever arrived: a channel without a sample is a missing
sample, which the filter's sensor management handles (dead reckoning, timeout -> lost). A step
due while earlier ones were not run (the adapter stalled) is preceded by those, each without
samples (dead reckoning), up to ``max_catch_up`` steps; after a longer gap the clock is
re-based on ``now`` (counted as ``rebased``) and the filter keeps its state.

**Reference.** Until :meth:`set_reference` is first called the controller is not engaged: the
demanded wrench is zero and the PWM commands are neutral, while the filter runs.

**Flying a dive plan** (issue 29; rovlab.interfaces.node.flight). :meth:`fly` loads a plan
(rovlab.ident.plan.DivePlan) with its guards; :meth:`start_flight` flies it from the next step on
instead of the controller (which is disengaged): each step the wrench is the plan's Flyer's for
the latest depth sample, allocated and turned into PWM by the same compiled step (an open-loop
controller component, rovlab.control.open_loop), so the filter predicts with the wrench the
allocation achieved and the outputs carry the PWM flown (``engaged`` True, ``flight`` 'flying').
After each step the flight's guards are checked on the corrected estimate; a guard, the plan's
end or :meth:`abort_flight` ends it, and from the next step on the thrusters are neutral.
"""

from __future__ import annotations

import math
import sys
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rovlab.core.components import N_TRUTH, TRUTH, TRUTH_INDEX, fresh, restore, state_of
from rovlab.estimation.fusion import (
    CH_MODE,
    CH_REASON,
    CH_STATUS,
    MODE_AUTO,
    MODE_NAMES,
    MODE_OFF,
    MODE_ON,
    N_REP,
    new_channel_state,
    status_label,
)
from rovlab.io.messages import command_message, estimate_message, measurement_message, reference_message
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle
from rovlab.sim.actuators import make_actuators
from rovlab.sim.designs import Design, make_design

MAX_HEADING_RAD = 4.0 * math.pi  # |psi| of a set-point: two turns either way (the HMI's +-720 deg)
SAMPLE_RESULTS = ("accepted", "late", "out-of-order", "unused", "disabled", "future", "invalid")
_MODES = {"auto": MODE_AUTO, "off": MODE_OFF, "on": MODE_ON}
_COMPILED: set[tuple[type, ...]] = set()  # component types whose step this process has compiled


@dataclass(frozen=True)
class ChannelInfo:
    """A measurement the filter fuses (names as in the simulator's logs)."""

    name: str  # "<sensor>.<quantity>", e.g. "qualisys.z"
    sensor: str
    quantity: str  # z, psi, w or r (rovlab.core.components.TRUTH)
    column: str  # "<quantity>_<sensor>"
    offset: float  # lever-arm offset the filter subtracts from the raw sample [m]


@dataclass(frozen=True, eq=False)
class NodeOutput:
    """What one control step hands out (SI units, radians, NED/FRD). Arrays are copies."""

    k: int  # step index
    t: float  # filter time k h [s]
    stamp: float  # T_k on the adapter's clock [s] (the time the estimate refers to)
    states: tuple[str, ...]  # names of x's entries (e.g. z, psi, w, r, b_w, b_r)
    x: np.ndarray  # corrected estimate at T_k
    P: np.ndarray  # its covariance (n x n)
    nav: np.ndarray  # the estimate in the TRUTH layout (x, y, z, psi, u, v, w, r, b_X, b_Y, b_Z, b_N; 0 = not estimated)
    estimated: tuple[str, ...]  # the TRUTH quantities the estimator estimates
    channels: tuple[str, ...]
    channel_status: tuple[str, ...]  # per channel: 'ok', 'recovering', 'off', 'lost-timeout', ...
    sensor_status: dict[str, str]  # per sensor: its worst channel's status
    y: np.ndarray  # the samples used at this step (NaN: none)
    innovation: np.ndarray  # per channel: the prior innovation (NaN without a usable sample)
    reference: np.ndarray  # [x, y, z, psi]
    engaged: bool  # False: no reference yet, neutral thrusters
    tau: np.ndarray  # demanded wrench [X, Y, Z, N]
    tau_achieved: np.ndarray  # what the allocation achieved [X, Y, Z, N] (the filter's input)
    thrusters: tuple[str, ...]
    pwm_us: np.ndarray  # PWM command per thruster, the vehicle file's order [us]
    controller_state: dict[str, float] = field(default_factory=dict)
    channel_columns: tuple[str, ...] = ()  # per channel, its log column ('z_qualisys' ...)
    flight: str = ""  # a dive plan's flight: '' (none), 'waiting', 'flying', 'complete', 'aborted'

    def variance(self) -> dict[str, float]:
        return {s: float(self.P[i, i]) for i, s in enumerate(self.states)}

    def messages(self, *, outputs: tuple[str, ...] = ("X", "Y", "Z", "N")) -> list[tuple[str, float, dict[str, Any]]]:
        """The step as rovlab.io.messages (the topics the simulator publishes, without truth):
        estimate, measurement, reference, command; channels named by their log columns and the
        command's ``tau`` holding the achieved wrench (X ...) and the demanded one (X_demanded ...),
        as in the simulator's messages. ``outputs``: the wrench entries the controller commands."""
        t = self.t
        cols = self.channel_columns or self.channels
        status = dict(zip(cols, self.channel_status))
        out = [("/rovlab/estimate", t, estimate_message(t, dict(zip(self.states, self.x)), self.variance(), status)),
               ("/rovlab/measurement", t, measurement_message(t, dict(zip(cols, self.y)))),
               ("/rovlab/reference", t, reference_message(t, {"z": self.reference[2], "psi": self.reference[3]})),
               ("/rovlab/command", t, command_message(
                   t, {**{o: self.tau_achieved["XYZN".index(o)] for o in outputs},
                       **{f"{o}_demanded": self.tau["XYZN".index(o)] for o in outputs}},
                   dict(zip(self.thrusters, self.pwm_us)), self.controller_state))]
        return out


class NodeCore:
    """The estimator and controller of a vehicle, stepped on their own clock (see the module)."""

    def __init__(self, vehicle: Vehicle, config: DesignConfig, *, estimator: str | None = None,
                 controller: str | None = None, pwm_resolution_us: float = 1.0, collect_s: float | None = None,
                 max_lag: int = 1, max_ahead_s: float = 1.0, max_catch_up: int = 600,
                 log: Callable[[str], None] | None = None, wait_for_samples_s: float = 0.0,
                 max_queue: int = 32) -> None:
        self._lock = threading.RLock()
        self._log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
        self._names = (estimator, controller)
        self.pwm_resolution_us = float(pwm_resolution_us)
        self.max_lag = int(max_lag)
        self.max_ahead_s = float(max_ahead_s)
        self.max_catch_up = int(max_catch_up)
        if int(max_queue) < 1:
            raise ValueError(f"max_queue must be at least 1 (samples of a channel waiting for a step), got {max_queue!r}")
        self.max_queue = int(max_queue)
        self._collect = collect_s
        self.counters: dict[str, int] = {r: 0 for r in SAMPLE_RESULTS} | {"replaced": 0, "steps": 0, "rebased": 0,
                                                                         "extra_corrections": 0}
        self.last_problem = ""
        self.last: NodeOutput | None = None
        self.sensor_enabled: dict[str, bool] = {}
        self.reference = np.zeros(4)
        self.engaged = False
        self.k = 0
        self.t0: float | None = None
        self.wait_for_samples_s = float(wait_for_samples_s)
        self._first_tick: float | None = None
        self.flight: Any = None  # rovlab.interfaces.node.flight.PlanFlight (fly)
        self._flight_parts: tuple[Any, Any, Any] | None = None  # (open-loop controller, its kernel, its StepOut)
        self._flew = False  # the last step flew the plan
        self._install(make_design(vehicle, config, plant="process", plant_step=config.sample_time,
                                  estimator=estimator, controller=controller), keep=None)

    # -- what is running -----------------------------------------------------------------------
    @property
    def h(self) -> float:
        return float(self.design.estimator.h)

    @property
    def vehicle(self) -> Vehicle:
        return self.design.vehicle

    @property
    def config(self) -> DesignConfig:
        return self.design.config

    @property
    def collect_s(self) -> float:
        return 0.5 * self.h if self._collect is None else float(self._collect)

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(self.design.estimator.states)

    @property
    def thrusters(self) -> tuple[str, ...]:
        return tuple(self.design.allocator.bank.names)

    @property
    def sensors(self) -> tuple[str, ...]:
        """The sensors the filter fuses, in channel order."""
        return tuple(dict.fromkeys(c.sensor for c in self.channels))

    def sensor_of_kind(self, kind: str) -> str | None:
        """The first fused sensor of a vehicle-file kind ('pressure', 'motion_capture', 'imu' ...)."""
        return next((c.sensor for c, k in zip(self.channels, self._kinds) if k == kind), None)

    @property
    def controller_name(self) -> str:
        return self._names[1] or self.config.controller

    @property
    def references(self) -> tuple[str, ...]:
        """The set-points the controller acts on (its ControllerSpec.references, of x, y, z, psi:
        z and psi for depth-and-heading control, all four for dynamic positioning)."""
        return tuple(self.design.controller.references)

    @property
    def estimator_name(self) -> str:
        return self._names[0] or self.config.estimator

    @property
    def time(self) -> float:
        """Filter time of the next step [s]."""
        return self.k * self.h

    def next_due(self) -> float | None:
        """Adapter time at which the next step runs at the latest (None before the first sample)."""
        return None if self.t0 is None else self.t0 + self.k * self.h + self.collect_s

    # -- inputs --------------------------------------------------------------------------------
    def push(self, sensor: str, quantity: str, value: float, stamp: float) -> str:
        """Offer one sample (rovlab units: z [m] of the sensor, psi [rad], w [m/s], r [rad/s]);
        returns what happened to it (see the module). Never raises on bad data."""
        with self._lock:
            j = self._channel_index.get((sensor, quantity))
            if j is None:
                return self._count("unused")
            if not self.sensor_enabled.get(sensor, True):
                return self._count("disabled")
            try:
                v, s = float(value), float(stamp)
            except (TypeError, ValueError):
                return self._problem(f"{sensor}.{quantity}: sample {value!r} at {stamp!r} is not a number")
            if not math.isfinite(s):
                return self._problem(f"{sensor}.{quantity}: timestamp {stamp!r} is not finite")
            if not math.isfinite(v):
                return self._problem(f"{sensor}.{quantity}: value {value!r} is not finite")
            if self.t0 is None:
                self.t0 = s
            if s <= self._stamp[j]:
                return self._count("out-of-order")
            step = int(math.floor((s - self.t0) / self.h + 0.5))
            if step < self.k - self.max_lag:
                return self._count("late")
            if s > self.t0 + self.k * self.h + self.max_ahead_s:
                return self._count("future")
            queue = self._queue[j]
            if len(queue) >= self.max_queue:
                queue.popleft()
                self.counters["replaced"] += 1
            queue.append((v, s, step))
            self._stamp[j] = s
            return self._count("accepted")

    def set_reference(self, *, z: float | None = None, psi: float | None = None, x: float | None = None,
                      y: float | None = None) -> None:
        """New set-point (NED: depth z [m] >= 0, heading psi [rad]); engages the controller.
        ValueError (nothing changes) for a value that is not finite, a negative depth or a heading
        beyond two turns (+-4 pi rad; within them it is wrapped to (-pi, pi])."""
        new = self.reference.copy()
        for i, (name, v) in enumerate((("x", x), ("y", y), ("z", z), ("psi", psi))):
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"reference {name} must be a finite number, got {v!r}")
            new[i] = float(v)
        if z is not None and new[2] < 0.0:
            raise ValueError(f"reference depth z must be >= 0 m (the free surface is z = 0), got {z!r}")
        if psi is not None and abs(new[3]) > MAX_HEADING_RAD:  # as the HMI: wrapping 1e308 would hide a slip
            raise ValueError(f"reference heading psi must be within +-{MAX_HEADING_RAD:.4g} rad (two turns; a "
                             f"larger value is a slip or another unit, e.g. degrees or centidegrees), got {psi!r}")
        if psi is not None:
            new[3] = math.remainder(new[3], 2.0 * math.pi)
        with self._lock:
            if not self.engaged and z is None:
                new[2] = max(0.0, float(self._nav[TRUTH_INDEX["z"]]))  # hold the estimated depth
            if not self.engaged and psi is None:
                new[3] = float(self._nav[TRUTH_INDEX["psi"]])
            if not self.engaged and x is None and "x" in self.references:  # DP engaged with depth and
                new[0] = float(self._nav[TRUTH_INDEX["x"]])  # heading only: hold the estimated position,
            if not self.engaged and y is None and "y" in self.references:  # not drive to the origin
                new[1] = float(self._nav[TRUTH_INDEX["y"]])
            self.reference = new
            self.engaged = True

    def disengage(self) -> None:
        """Stop commanding: zero wrench, neutral PWM (the filter keeps running)."""
        with self._lock:
            self.engaged = False

    def set_sensor_enabled(self, sensor: str, enabled: bool) -> None:
        """Switch a sensor off (its samples are dropped, so the filter times it out) or back on."""
        if sensor not in self.sensor_enabled:
            raise ValueError(f"unknown sensor {sensor!r}; the filter fuses {', '.join(self.sensor_enabled)}")
        with self._lock:
            self.sensor_enabled[sensor] = bool(enabled)
            if not enabled:
                for j, c in enumerate(self.channels):
                    if c.sensor == sensor:
                        self._queue[j].clear()

    def set_filter_mode(self, channel: str, mode: str) -> None:
        """Force a filter channel 'off' or 'on', or back to 'auto'."""
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
        names = [c.name for c in self.channels]
        if channel not in names:
            raise ValueError(f"unknown channel {channel!r}; the filter has {', '.join(names)}")
        with self._lock:
            self.estimator.ch[names.index(channel), CH_MODE] = _MODES[mode]

    def filter_modes(self) -> dict[str, str]:
        return {c.name: MODE_NAMES[int(self.estimator.ch[j, CH_MODE])] for j, c in enumerate(self.channels)}

    # -- flying a dive plan (module: "Flying a dive plan") ----------------------------------------
    @property
    def flying(self) -> bool:
        """A plan is being flown (the thrusters obey it, not the controller)."""
        return self.flight is not None and self.flight.active

    def depth_channel(self) -> int | None:
        """Index of the filter's pressure depth channel (None: the filter fuses no pressure depth)."""
        return next((j for j, (c, kind) in enumerate(zip(self.channels, self._kinds))
                     if kind == "pressure" and c.quantity == "z"), None)

    def fly(self, plan: Any, guards: Any = None) -> Any:
        """Load ``plan`` (rovlab.ident.plan.DivePlan) with ``guards`` (flight.FlightGuards; None:
        the defaults) and return its PlanFlight, waiting for :meth:`start_flight`. Compiles the
        open-loop step if this process has not yet. ValueError: a plan this node cannot fly (no
        pressure depth channel, a command step that is not a multiple of the control period, a
        flight already under way)."""
        from rovlab.interfaces.node.flight import PlanFlight

        if self.flying:
            raise ValueError("a plan is being flown already; abort it first")
        if self.depth_channel() is None:
            raise ValueError(f"the filter of {self.config.name} fuses no pressure depth: a dive plan's depth law and "
                             "guards need one")
        nav = set(self.design.estimator.nav)
        if getattr(plan, "horizontal", False) and not {"x", "y", "psi", "r"} <= nav:
            raise ValueError(f"a surge and sway plan ({', '.join(plan.dofs)}) is flown on the estimated position and "
                             f"heading; the filter of {self.config.name} estimates {', '.join(sorted(nav))} (a "
                             "configuration with a DVL or a positioning system and x, y states flies it)")
        flight = PlanFlight(plan, guards, h=self.h)
        with self._lock:
            self.prepare_flight()
            self.flight = flight
        return flight

    def start_flight(self) -> None:
        """Fly the loaded plan from the next step on (the controller is disengaged)."""
        with self._lock:
            if self.flight is None:
                raise ValueError("no plan loaded (fly)")
            stamp = (self.t0 if self.t0 is not None else 0.0) + self.k * self.h
            self.flight.start(self.k, stamp)
            self.engaged = False

    def abort_flight(self, reason: str) -> bool:
        """Abort the flight under way (neutral thrusters from the next step); True if it was flying."""
        with self._lock:
            if self.flight is None or self.flight.ended:
                return False
            flying = self.flight.active
            self.flight.abort(reason, None if self.t0 is None else self.t0 + self.k * self.h)
            return flying

    def prepare_flight(self) -> None:
        """The open-loop controller, its compiled step (warmed up on copies: compiled ahead by
        ``rovlab compile --node``) and its outputs; :meth:`fly` calls it."""
        from rovlab.control.open_loop import open_loop
        from rovlab.sim.step import StepOut, control_step_for

        if self._flight_parts is not None:
            return
        ctl = open_loop()
        kernel = control_step_for(self.estimator, ctl)
        key = (type(self.estimator), type(ctl))
        if key not in _COMPILED:
            from rovlab._jit import with_progress

            m, n = len(self.channels), self.estimator.x.shape[0]
            ew, cw = fresh(self.estimator), open_loop()
            act = make_actuators(self.design.allocator, self.design.allocator.bank, self.design.allocator.B,
                                 self.pwm_resolution_us)

            def warm_up() -> None:
                kernel(0.0, ew, cw, act, self._nav_of, np.full(m, np.nan), np.zeros(m, dtype=np.bool_), np.zeros(4),
                       True, StepOut(np.empty((m, N_REP)), np.zeros(N_TRUTH), np.zeros(4), np.zeros(4), np.zeros(4),
                                     np.empty(len(self.thrusters)), np.empty(n), np.empty((n, n)), np.empty(4)),
                       False)

            what = f"the plan-flight step ({type(self.estimator).__name__} + open loop)"
            _, seconds = with_progress(warm_up, self._log, what, hint="")
            _COMPILED.add(key)
            if seconds > 1.0:
                self._log(f"rovlab node: {what} ready ({seconds:.1f} s)")
        out = self._out._replace(ctrl=np.empty(4))  # the same arrays, but the open loop's state (4)
        self._flight_parts = (ctl, kernel, out)

    def _fly_step(self, t: float, y: np.ndarray, present: np.ndarray) -> None:
        """One step of the flight: the plan's wrench for the latest depth sample, through the open
        loop's compiled step; then the guards on the corrected estimate."""
        assert self._flight_parts is not None and self.flight is not None and self.t0 is not None
        ctl, kernel, out = self._flight_parts
        j = self.depth_channel()
        assert j is not None
        sample = float(self._latest[j] - self.channels[j].offset)
        depth = sample if math.isfinite(sample) else float(self._nav[TRUTH_INDEX["z"]])
        nav = self._nav  # the previous step's estimate (this step's wrench is needed before its correction)
        if getattr(self.flight.plan, "horizontal", False):  # surge / sway: the heading law and the box guard
            ctl.state[:] = self.flight.wrench(depth, heading=float(nav[TRUTH_INDEX["psi"]]),
                                              rate=float(nav[TRUTH_INDEX["r"]]),
                                              position=(float(nav[TRUTH_INDEX["x"]]), float(nav[TRUTH_INDEX["y"]])))
        else:
            ctl.state[:] = self.flight.wrench(depth)
        kernel(t, self.estimator, ctl, self.actuators, self._nav_of, y, present, self.reference, True, out, False)
        est = set(self.design.estimator.nav)
        status = status_label(int(self.estimator.ch[j, CH_STATUS]), int(self.estimator.ch[j, CH_REASON]))
        if not self.sensor_enabled.get(self.channels[j].sensor, True):
            status = "disabled"
        self.flight.after_step(self.t0 + t, z=float(nav[TRUTH_INDEX["z"]]),
                               z_sample=sample if math.isfinite(sample) else None,
                               psi=float(nav[TRUTH_INDEX["psi"]]) if "psi" in est else None,
                               r=float(nav[TRUTH_INDEX["r"]]) if "r" in est else None, depth_status=status)

    def apply(self, *, vehicle: Vehicle | None = None, config: DesignConfig | None = None) -> None:
        """Swap in a new model vehicle and/or configuration (designed first: ConfigError and no
        change on failure), keeping the estimate, covariance, controller state and, by channel
        name, the channels' modes. The sample time cannot change while the node runs."""
        from rovlab.params.validate import ConfigError, Problem

        v = vehicle if vehicle is not None else self.vehicle
        c = config if config is not None else self.config
        if abs(c.sample_time - self.config.sample_time) > 1e-12:
            raise ConfigError([Problem(c.file or c.name, "sample_time", c.sample_time,
                                       f"the running node's {self.config.sample_time:g} s (restart the node to change it)")],
                              "filter configuration")
        design = make_design(v, c, plant="process", plant_step=c.sample_time,
                             estimator=self._names[0], controller=self._names[1])
        with self._lock:
            self._install(design, keep=(self.estimator, self.controller, self.channels))

    # -- stepping ------------------------------------------------------------------------------
    def tick(self, now: float) -> list[NodeOutput]:
        """Run the steps due at adapter time ``now`` (none, one, or a few after a stall)."""
        with self._lock:
            if self.t0 is None:
                if self._first_tick is None:
                    self._first_tick = float(now)
                if now - self._first_tick < self.wait_for_samples_s:
                    return []  # no sample yet: the clock starts with the first one (see the module)
                self.t0 = float(now)
            out: list[NodeOutput] = []
            # steps whose deadline T_j + collect_s has passed: j <= (now - collect_s - t0) / h
            behind = int(math.floor((now - self.collect_s - self.t0) / self.h + 1e-9)) - self.k + 1
            if behind > self.max_catch_up:
                self.counters["rebased"] += 1
                self._log(f"rovlab node: {behind} control steps behind (the process stalled {behind * self.h:.1f} s): "
                          "re-basing the clock; the filter keeps its state")
                self.t0 = float(now) - self.collect_s - self.k * self.h  # the next step is due now
                behind = 1
            for _ in range(max(behind, 0)):
                out.append(self._step(now))
            if self._complete():  # every channel has its sample for the current step: run it now
                if now >= self.t0 + self.k * self.h - 0.5 * self.h:
                    out.append(self._step(now))
            return out

    # -- internals -----------------------------------------------------------------------------
    def _count(self, result: str) -> str:
        self.counters[result] += 1
        return result

    def _problem(self, message: str) -> str:
        self.last_problem = message
        return self._count("invalid")

    def _complete(self) -> bool:
        want = [j for j, c in enumerate(self.channels) if self.sensor_enabled.get(c.sensor, True)
                and self.estimator.ch[j, CH_MODE] != MODE_OFF and self._expected[j]]
        return bool(want) and all(any(step == self.k for _, _, step in self._queue[j]) for j in want)

    def _step(self, now: float) -> NodeOutput:
        k = self.k
        t = k * self.h
        y, present = self._y, self._present
        newest: list[float | None] = [None] * len(self.channels)
        older: list[tuple[float, int, float]] = []  # (stamp, channel, value) of the samples before the newest
        for j, queue in enumerate(self._queue):
            due = []
            while queue and queue[0][2] <= k:  # steps grow with the stamps: the due samples lead the queue
                due.append(queue.popleft())
            if due:
                newest[j] = due[-1][0]
                period = due[-1][2]
                for v, stamp, step in due[:-1]:
                    if step == period:  # several samples of one period: each is used
                        older.append((stamp, j, v))
                    else:  # a sample of an earlier period that came after its step ran: the newer one
                        self.counters["replaced"] += 1  # replaces it (fusing it now would date it h late)
        if older:  # several samples of a channel in this period: the older ones first, in stamp order
            older.sort()
            group: dict[int, float] = {}
            for _, j, v in older:
                if j in group:
                    self._correct(t, group)
                    group = {}
                group[j] = v
            self._correct(t, group)
        for j, last in enumerate(newest):
            present[j] = last is not None
            y[j] = math.nan if last is None else last
            if last is not None:
                self._latest[j] = last
        self._flew = self.flying  # this step's output says engaged: its wrench was flown (a guard may end it)
        if self._flew:
            self._fly_step(t, y, present)
        else:
            self._kernel(t, self.estimator, self.controller, self.actuators, self._nav_of, y, present, self.reference,
                         self.engaged, self._out, False)
        self.k = k + 1
        self.counters["steps"] += 1
        out = self._output(k, t)
        self.last = out
        return out

    def _correct(self, t: float, samples: dict[int, float]) -> None:
        """Correct the estimator only (no control step) with ``samples`` (channel -> value)."""
        y, present = self._y, self._present
        present[:] = False
        y[:] = math.nan
        for j, v in samples.items():
            present[j] = True
            y[j] = v
        self.counters["extra_corrections"] += 1
        self._kernel(t, self.estimator, self.controller, self.actuators, self._nav_of, y, present, self.reference,
                     self.engaged, self._out, True)

    def _output(self, k: int, t: float) -> NodeOutput:
        ch = self.estimator.ch
        labels = tuple(status_label(int(ch[j, CH_STATUS]), int(ch[j, CH_REASON])) for j in range(len(self.channels)))
        by_sensor: dict[str, str] = {}
        rank = {"ok": 0, "recovering": 1, "off": 2}
        for c, label in zip(self.channels, labels):
            old = by_sensor.get(c.sensor)
            if old is None or rank.get(label, 3) > rank.get(old, 3):
                by_sensor[c.sensor] = label
        for s, on in self.sensor_enabled.items():
            if not on:
                by_sensor[s] = "disabled"
        ctl = self.design.controller
        assert self.t0 is not None
        return NodeOutput(
            k=k, t=t, stamp=self.t0 + t, states=self.states, x=self._x.copy(), P=self._P.copy(), nav=self._nav.copy(),
            estimated=tuple(self.design.estimator.nav), channels=tuple(c.name for c in self.channels),
            channel_status=labels, sensor_status=by_sensor, y=self._y.copy(), innovation=self._rep[:, 1].copy(),
            reference=self.reference.copy(), engaged=self.engaged or self._flew, tau=self._tau.copy(),
            tau_achieved=self._tau_cmd.copy(), thrusters=self.thrusters, pwm_us=self._pwm.copy(),
            controller_state={n: float(v) for n, v in zip(ctl.state_names, self.controller.state)},
            channel_columns=tuple(c.column for c in self.channels),
            flight="" if self.flight is None else self.flight.state)

    def _install(self, design: Design, keep: tuple[Any, Any, tuple[ChannelInfo, ...]] | None) -> None:
        """Make ``design`` the running one (compiling its step if this process has not yet)."""
        from rovlab.sim.loop import explain_allocation
        from rovlab.sim.step import StepOut, control_step_for

        est = fresh(design.estimator.kernel)
        ctl = fresh(design.controller.kernel)
        alloc = design.allocator
        act = make_actuators(alloc, alloc.bank, alloc.B, self.pwm_resolution_us)
        channels = tuple(ChannelInfo(c.name, c.sensor, c.quantity, c.column, float(c.offset))
                         for c in design.estimator.channels)
        m, n = len(channels), est.x.shape[0]
        if keep is not None:
            old_est, old_ctl, old_channels = keep
            saved = state_of(old_est)
            saved.pop("ch", None)
            restore(est, saved)
            restore(ctl, state_of(old_ctl))
            old_names = [c.name for c in old_channels]
            new_names = [c.name for c in channels]
            if new_names == old_names:
                est.ch[...] = old_est.ch
            else:
                chs = new_channel_state(m)
                for j, name in enumerate(new_names):
                    if name in old_names:
                        chs[j, CH_MODE] = old_est.ch[old_names.index(name), CH_MODE]
                est.ch[...] = chs
        kernel = control_step_for(est, ctl)
        key = (type(est), type(ctl))
        if key not in _COMPILED:
            from rovlab._jit import with_progress

            # warm-up on copies, with no samples: the running state is not touched
            ew, cw = fresh(est), fresh(ctl)
            nav_of = np.array([TRUTH_INDEX[q] for q in design.estimator.nav], dtype=np.int64)

            def warm_up() -> None:
                with explain_allocation((est, ctl)):
                    kernel(0.0, ew, cw, act, nav_of, np.full(m, np.nan), np.zeros(m, dtype=np.bool_), np.zeros(4),
                           True, StepOut(np.empty((m, N_REP)), np.zeros(N_TRUTH), np.zeros(4), np.zeros(4),
                                         np.zeros(4), np.empty(len(alloc.bank.names)), np.empty(n), np.empty((n, n)),
                                         np.empty(cw.state.shape[0])),
                           False)

            what = f"the control step ({type(est).__name__} + {type(ctl).__name__})"
            _, seconds = with_progress(warm_up, self._log, what,
                                       hint="; `rovlab compile --node` prepares it ahead")
            _COMPILED.add(key)
            if seconds > 1.0:
                self._log(f"rovlab node: {what} ready ({seconds:.1f} s)")
        self.design = design
        self.estimator, self.controller, self.actuators = est, ctl, act
        self.channels = channels
        self._kinds = tuple(c.kind for c in design.estimator.channels)
        self._channel_index = {(c.sensor, c.quantity): j for j, c in enumerate(channels)}
        self._kernel = kernel
        self._nav_of = np.array([TRUTH_INDEX[q] for q in design.estimator.nav], dtype=np.int64)
        rates = {c.sensor: design.vehicle.sensor(c.sensor).rate_hz for c in design.estimator.channels}
        self._expected = [rates[c.sensor] * design.estimator.h >= 1.0 - 1e-9 for c in channels]  # a sample every step
        self.sensor_enabled = {s: self.sensor_enabled.get(s, True) for s in dict.fromkeys(c.sensor for c in channels)}
        old_queue = getattr(self, "_queue", None)
        if old_queue is None or len(old_queue) != m:
            self._queue: list[deque[tuple[float, float, int]]] = [deque() for _ in range(m)]  # (value, stamp, step)
            self._stamp = np.full(m, -np.inf)
        self._y = np.full(m, np.nan)
        latest: np.ndarray | None = getattr(self, "_latest", None)
        if latest is None or len(latest) != m:
            self._latest: np.ndarray = np.full(m, np.nan)  # the newest sample of each channel so far
        self._present = np.zeros(m, dtype=np.bool_)
        self._rep = np.full((m, N_REP), np.nan)
        if getattr(self, "_nav", None) is None:
            self._nav = np.zeros(N_TRUTH)
        self._tau = np.zeros(4)
        self._tau_cmd = np.zeros(4)
        self._tau_real = np.zeros(4)
        self._pwm = np.empty(len(alloc.bank.names))
        self._x = est.x.copy()
        self._P = est.P.copy()
        # the same arrays, as the compiled step fills them
        self._out = StepOut(self._rep, self._nav, self._tau, self._tau_cmd, self._tau_real, self._pwm, self._x, self._P,
                            np.empty(ctl.state.shape[0]))
        if getattr(self, "flight", None) is not None and self.flight.active:
            self.flight.abort("the node's configuration or vehicle changed during the flight")
        self._flight_parts = None  # rebuilt for this design's estimator and outputs by the next fly()


__all__ = ["TRUTH", "SAMPLE_RESULTS", "ChannelInfo", "NodeCore", "NodeOutput"]
