"""``rovlab mavlink bridge``: an ArduSub vehicle driven by rovlab's estimator and controller.

The bridge is a thin adapter around the node core (rovlab.interfaces.node.NodeCore), which does
all the estimation and control; this module only translates:

* in: the vehicle's telemetry, by rovlab.interfaces.mavlink.logs.SampleMap (SCALED_PRESSURE2 ->
  Bar30 depth with the vehicle file's water density and the vehicle's BARO2_GND_PRESS; ATTITUDE ->
  heading and yaw rate; VISION_POSITION_ESTIMATE / LOCAL_POSITION_NED -> position channels), each
  sample stamped with its arrival time and pushed into the node core;
* out: the node core's thruster PWM commands, read back as ArduSub motor outputs and turned into
  the pilot inputs whose ArduSub mix comes closest (rovlab.allocation.mixing.Mixer), sent as
  MANUAL_CONTROL in ArduSub's ranges (scaled by the vehicle's live pilot gain, NAMED_VALUE_FLOAT
  "PilotGain", and its JS_THR_GAIN) or as RC_CHANNELS_OVERRIDE pulses on channels 3-6.

On a shared link (QGroundControl or MAVProxy on the same vehicle) a ground station's
REQUEST_DATA_STREAM resets the rates the bridge set with MAV_CMD_SET_MESSAGE_INTERVAL (ArduPilot
applies the group rate to every message of the group). So the bridge measures the rate at which
each message it needs arrives, asks again when it falls below what it asked for, and says so --
once per episode -- when it cannot get it. It reads the parameters it needs under either
generation of names (ArduSub 4.7's MAV_GCS_SYSID, 4.1's SYSID_MYGCS), asking a bounded number of
times.

Safety, as the issue asks: the bridge sends its own HEARTBEAT (1 Hz, as a ground station);
it sends MANUAL_CONTROL only once the vehicle reported its joystick gains (or 5 s passed);
commands go out at a fixed rate (``command_hz``) and their change per second is limited
(``max_input_rate``); with no telemetry for ``telemetry_timeout_s`` (default 0.5 s) it sends
neutral commands (no slew limit on the way to neutral); with ``arm`` it puts the vehicle in
MANUAL and arms it -- once: a vehicle disarmed afterwards (by a pilot or a failsafe) stays
disarmed -- sending neutral inputs until it is armed (ArduSub refuses to arm on a stick that is
not neutral: "Arm: Yaw (RC4) is not neutral"), and on close it sends neutral and disarms what it
armed. Nothing is commanded before a reference is set (CLI ``--depth``/``--heading-deg`` or the
HMI): a pilot can fly the vehicle as usual.

A reference is *held* (the node core's controller engaged) only while the vehicle obeys the
bridge's inputs -- armed, in MANUAL -- and the bridge can see it: with telemetry and a plausible
depth sensor. Otherwise the controller is disengaged, so the filter does not predict the motion
of thrust that is not applied (and the controller does not wind up on it), and neutral inputs
are sent. The reference waits for the vehicle to be armed in MANUAL; it is dropped (said) when the
vehicle is disarmed or leaves MANUAL while held (a pilot or a failsafe took over; set it again to
resume). A depth sensor that reads an implausible value (SCALED_PRESSURE2 outside
PLAUSIBLE_DEPTH_M, e.g. ArduSub SITL started at a home 584 m above sea level reports about
-57 600 hPa) or whose channel the filter has lost stops the control loudly -- the value is named,
and no depth is ever flown on the filter's prediction: neutral inputs, as ArduSub's own
failsafes do -- until it reads plausibly again.

With a dynamic-positioning configuration (a controller whose references include x and y) the
bridge also holds north and east (``set_reference(x=, y=)``) on the position channels its filter
fuses, fed by LOCAL_POSITION_NED (asked for at the control rate). It holds them only on a measured
position: not before a step of the filter has used a position sample, not on an implausible one
(PLAUSIBLE_POSITION_M) and not while the channel is lost or recovering -- said, neutral inputs,
the set-point kept (docs/mavlink.md, "Dynamic positioning on ArduSub SITL").
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rovlab.allocation.mixing import Mixer
from rovlab.interfaces.mavlink import connection, dialect
from rovlab.interfaces.mavlink.ardusub import DATA_STREAM_NAMES, MODE_NAMES, MODES, MY_GCS, MY_GCS_HIGH, STREAM_OF_MESSAGE
from rovlab.interfaces.mavlink.logs import SampleMap, TelemetryRecorder
from rovlab.interfaces.mavlink.units import (
    RC_CHANNEL,
    depth_from_pressure,
    drain,
    manual_control_from_inputs,
    rc_pulse_from_input,
)
from rovlab.interfaces.node.core import NodeCore
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle

TELEMETRY = frozenset({"ATTITUDE", "SCALED_PRESSURE2", "LOCAL_POSITION_NED", "VISION_POSITION_ESTIMATE",
                       "SERVO_OUTPUT_RAW", "VFR_HUD", "SYS_STATUS"})
# what the bridge reads -> the names ArduSub has given it, newest first (4.7 renamed SYSID_MYGCS)
_PARAMS_WANTED: dict[str, tuple[str, ...]] = {
    "JS_GAIN_DEFAULT": ("JS_GAIN_DEFAULT",), "JS_THR_GAIN": ("JS_THR_GAIN",),
    "BARO2_GND_PRESS": ("BARO2_GND_PRESS",), "GCS_SYSID": (MY_GCS["4.7"], MY_GCS["4.1"]),
}
_PARAM_TRIES = 10  # requests (one a second) before the bridge says what the vehicle did not report
# ArduSub's ranges of the joystick gains (ArduSub/Parameters.cpp @Range; the simulator's ParamSpecs
# in rovlab.interfaces.mavlink.ardusub): the gain ArduSub applies is constrained to 0.1 .. 1.0
# (ArduSub/joystick.cpp), JS_THR_GAIN is used as it is (throttle scale 0.8 gain JS_THR_GAIN)
GAIN_RANGE = (0.1, 1.0)
THROTTLE_GAIN_RANGE = (0.5, 4.0)
_STREAMS = {"ATTITUDE": 30, "SCALED_PRESSURE2": 137, "SERVO_OUTPUT_RAW": 36}  # MAVLink message ids
POSITION_STREAM = ("LOCAL_POSITION_NED", 32)  # asked for too when the filter fuses a position (DP)
RATE_WINDOW_S = 2.0  # a stream's rate is measured over this long, from this long after asking
RATE_TOLERANCE = 0.75  # below this share of the rate asked for, the bridge asks again
RATE_ASKS = 3  # requests in a row without the rate before the bridge says it cannot get it
RATE_BACKOFF_S = 5.0  # then it keeps asking at this interval
RATE_RESETS_SAID = 3  # resets of one stream said in the log; later ones only counted
COMMAND_MODES = ("manual_control", "rc_override")
# a depth the pressure sensor can read: 2 m above the surface is 200 hPa below the surface pressure
# (more than any weather change); 1100 m is deeper than any Blue Robotics sensor reads (Bar100: 1000 m)
PLAUSIBLE_DEPTH_M = (-2.0, 1100.0)
# a horizontal position (LOCAL_POSITION_NED x, y: north/east of the EKF origin, set where the vehicle's
# position was first known) a small ROV on a tether can be at: 10 km from it either way
PLAUSIBLE_POSITION_M = 10_000.0
DEPTH_LOST_REPEAT_S = 10.0  # a repeating message (depth sensor lost, back, hold resumed) is said at most this often


class MavlinkBridge:
    """The node core on one MAVLink connection to an ArduSub vehicle (see the module).

    Drive it with :meth:`run` (blocking; :meth:`stop` from another thread or a signal handler) or
    call :meth:`step` from your own loop. :meth:`drain` hands out the rovlab messages produced
    since the last call (for the HMI)."""

    def __init__(self, vehicle: Vehicle, config: DesignConfig, *, connect: str = "udpin:127.0.0.1:14550",
                 target_system: int = 1, sysid: int = 255, compid: int = 191, command: str = "manual_control",
                 command_hz: float | None = None, max_input_rate: float = 4.0, telemetry_timeout_s: float = 0.5,
                 arm: bool = False, record: str | None = None, log: Callable[[str], None] | None = None,
                 core: NodeCore | None = None, trust_vehicle_file: bool = False) -> None:
        if command not in COMMAND_MODES:
            raise ValueError(f"command must be one of {', '.join(COMMAND_MODES)}, got {command!r}")
        for name, v, lo, hi in (("telemetry_timeout_s", telemetry_timeout_s, 0.05, 10.0),
                                ("max_input_rate", max_input_rate, 0.1, 100.0)):
            if not (math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"{name} must be within {lo:g} .. {hi:g}, got {v!r}")
        self.log = log or (lambda text: None)
        self.vehicle = vehicle
        self.core = core if core is not None else NodeCore(vehicle, config, log=self.log)
        rate = 1.0 / self.core.h if command_hz is None else float(command_hz)
        if not (math.isfinite(rate) and 1.0 <= rate <= 50.0):
            raise ValueError(f"command_hz must be within 1 .. 50 Hz, got {command_hz!r}")
        self.command_period = 1.0 / rate
        self.max_input_rate = float(max_input_rate)
        self.telemetry_timeout_s = float(telemetry_timeout_s)
        self.command = command
        self.target_system = int(target_system)
        self.sysid = int(sysid)
        self.want_arm = bool(arm)
        self.mixer = Mixer.from_vehicle(vehicle)
        self.smap = SampleMap(vehicle, tuple(self.core.design.estimator.channels))
        self._sample_of = {c.column: (c.sensor, c.quantity) for c in self.core.channels}
        self.mav = dialect()
        self.conn = connection(connect, source_system=self.sysid, source_component=compid)
        self.connect = connect
        self.recorder = TelemetryRecorder(record, metadata={"connect": connect, "vehicle": vehicle.name,
                                                            "config": config.name}) if record else None
        # what we know of the vehicle
        self.params: dict[str, float] = {"JS_GAIN_DEFAULT": 0.5, "JS_THR_GAIN": 1.0}  # ArduSub's defaults
        self.confirmed: set[str] = set()  # what the vehicle has reported (the keys of _PARAMS_WANTED, PilotGain)
        self.param_names: dict[str, str] = {}  # key of _PARAMS_WANTED -> the name the vehicle has
        # the vehicle as its autopilot describes it (frame, thruster directions, PWM range), checked
        # against the vehicle file before anything is commanded (rovlab.interfaces.mavlink.autopilot)
        self.trust_vehicle_file = bool(trust_vehicle_file)
        self._vehicle_keys = ("FRAME_CONFIG", "MOT_PWM_MIN", "MOT_PWM_MAX",
                              *(f"MOT_{k + 1}_DIRECTION" for k in range(len(vehicle.thrusters))))
        self.vehicle_problems: list[Any] | None = None  # None until checked; [] when the file agrees
        self.exit_code = 0
        self._wanted = {**_PARAMS_WANTED, **{k: (k,) for k in self._vehicle_keys}}
        self._param_asks: dict[str, int] = dict.fromkeys(self._wanted, 0)
        self.live_gain: float | None = None  # NAMED_VALUE_FLOAT PilotGain
        self.gain_problem: str | None = None  # JS_THR_GAIN outside ArduSub's range: neutral MANUAL_CONTROL only
        self.vehicle_seen = False
        self._first_seen: float | None = None
        self.armed = False
        self.mode: int | None = None
        self.last_telemetry: float | None = None
        self.servo_pwm: np.ndarray | None = None
        # what we send
        self.inputs = np.zeros(4)  # normalised [forward, lateral, throttle, yaw] last sent
        self.failsafe = False
        self.sent: collections.deque[tuple[float, tuple[int, ...], bool]] = collections.deque(maxlen=2000)
        self.sent_gains: tuple[float, float] | None = None  # (pilot gain, JS_THR_GAIN) of the last MANUAL_CONTROL
        self.counts: dict[str, int] = {"received": 0, "bad_data": 0, "errors": 0, "commands": 0, "neutral": 0,
                                       "failsafes": 0, "rate_requests": 0, "rate_resets": 0, "rate_failures": 0,
                                       "implausible_depth": 0, "depth_lost": 0}
        # the telemetry rates we need: arrivals, when we last asked, requests in a row without the rate
        # dynamic positioning: the controller holds x and y, on the position channels the filter fuses
        # (a vehicle-file sensor of kind motion_capture, fed by LOCAL_POSITION_NED / VISION_POSITION_ESTIMATE)
        self.dp = "x" in self.core.references
        self._position_channels = [j for j, c in enumerate(self.core.channels) if c.quantity in ("x", "y")]
        self._streams = dict(_STREAMS)
        if self._position_channels:
            self._streams[POSITION_STREAM[0]] = POSITION_STREAM[1]
        self.position_problem: str | None = None  # the position's problem now (None: none needed, or fused)
        self._last_bad_position: str | None = None
        self._position_fused = False  # a step of the filter has used a position sample
        self.counts["implausible_position"] = 0
        self.rate_wanted = {name: 1.0 / self.core.h for name in self._streams}
        self.rates: dict[str, float | None] = dict.fromkeys(self._streams)  # measured [Hz]; None before a full window
        self.rate_short: set[str] = set()  # streams arriving below RATE_TOLERANCE of the rate wanted
        self._arrivals: dict[str, collections.deque[float]] = {n: collections.deque(maxlen=1000) for n in self._streams}
        self._asked_at: dict[str, float] = {}
        self._rate_asks = dict.fromkeys(self._streams, 0)
        self._said_cannot: set[str] = set()  # streams said to be out of reach in their current episode
        self._resets = dict.fromkeys(self._streams, 0)
        self._armed_by_us = False
        self._due: dict[str, float] = {"heartbeat": 0.0, "command": 0.0, "params": 0.0, "arm": 0.0, "rates": 0.0}
        self._queue: collections.deque[tuple[str, float, dict[str, Any]]] = collections.deque(maxlen=20000)
        self._stop = threading.Event()
        self._last_command_time: float | None = None
        self._warned: set[str] = set()
        # the set-point asked for (None: none); held only while the vehicle obeys (see the module)
        self._ref_lock = threading.Lock()
        self._wanted_ref: dict[str, float | None] | None = None
        self.hold_blocked: str | None = None  # why a wanted reference is not held now (None: held or none)
        self.depth_problem: str | None = None  # the depth sensor's problem now (None: plausible and fused)
        self._said: dict[str, tuple[float, str]] = {}  # what a repeating message last said, and when
        self._last_implausible: str | None = None
        self.flight: Any = None  # a dive plan being flown (fly; rovlab.interfaces.mavlink.flight.BridgeFlight)

    # -- control from outside ------------------------------------------------------------------
    def set_reference(self, *, z: float | None = None, psi: float | None = None, x: float | None = None,
                      y: float | None = None) -> None:
        """Depth [m] / heading [rad] set-point, and with a DP configuration north x / east y [m] of
        the vehicle's EKF origin (LOCAL_POSITION_NED's frame). ValueError on bad values, or on x / y
        when the controller holds no position; nothing changes then. Held while the vehicle is armed
        in MANUAL and seen (see the module); until then it waits. A value left None is the
        estimate's when the hold starts."""
        if (x is not None or y is not None) and not self.dp:
            raise ValueError(f"north/east set-points need a controller that holds x and y (dynamic positioning, e.g. "
                             f"--config ardusub_sitl_heavy_dp); the configuration {self.core.config.name}'s "
                             f"{self.core.controller_name} holds {', '.join(self.core.references)}")
        with self._ref_lock:
            obeying = self.core.engaged
            self.core.set_reference(z=z, psi=psi, x=x, y=y)  # validates; engages
            old: dict[str, float | None] = self._wanted_ref or dict.fromkeys(("x", "y", "z", "psi"))
            if obeying:  # held already: the values left None stay what they were
                old = {k: float(self.core.reference[i]) for i, k in enumerate(("x", "y", "z", "psi"))}
            new = {"x": x, "y": y, "z": z, "psi": psi}
            self._wanted_ref = {k: old.get(k) if v is None else float(v) for k, v in new.items()}
            if not obeying:
                self.core.disengage()  # until the vehicle obeys (the next step decides)

    def fly(self, plan: Any, guards: Any = None) -> Any:
        """Fly a dive plan (rovlab.ident.plan.DivePlan) once the vehicle is armed in MANUAL at its
        start depth, with guards (rovlab.interfaces.node.flight.FlightGuards); the bridge stops when
        the flight ends (rovlab.interfaces.mavlink.flight). ValueError: a plan it cannot fly."""
        from rovlab.interfaces.mavlink.flight import BridgeFlight

        self.flight = BridgeFlight(self, plan, guards)
        return self.flight

    def disengage(self) -> None:
        """Stop holding (the vehicle goes back to the pilot); the filter keeps running."""
        with self._ref_lock:
            self._wanted_ref = None
            self.core.disengage()

    @property
    def engaged(self) -> bool:
        """A set-point is wanted (held now, or waiting for the vehicle: ``hold_blocked`` says why)."""
        return self._wanted_ref is not None

    def stop(self) -> None:
        self._stop.set()

    def drain(self) -> list[tuple[str, float, dict[str, Any]]]:
        """The rovlab messages (estimate, measurement, reference, command) since the last call."""
        out = []
        while self._queue:
            out.append(self._queue.popleft())
        return out

    # -- running -------------------------------------------------------------------------------
    def run(self, *, duration_s: float | None = None, tick_s: float = 0.005) -> None:
        start = time.monotonic()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if duration_s is not None and now - start >= duration_s:
                    break
                self.step(now)
                self._stop.wait(tick_s)
        finally:
            self.close()

    def close(self) -> None:
        """Neutral commands, disarm what we armed, release RC overrides, finish the recording."""
        try:
            if self.vehicle_seen:
                for _ in range(3):
                    self._send_inputs(np.zeros(4), time.monotonic(), neutral=True)
                if self.command == "rc_override":
                    self.conn.mav.rc_channels_override_send(self.target_system, 1, *([0] * 8))
                if self._armed_by_us:
                    self.conn.mav.command_long_send(self.target_system, 1, self.mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                    0, 0, 0, 0, 0, 0, 0)
        except OSError:  # pragma: no cover - the link is gone; nothing more to say to the vehicle
            pass
        finally:
            if self.flight is not None:
                self.flight.closing()  # stopped mid-flight: the abort said and recorded before the recording ends
            if self.recorder is not None:
                self.recorder.close()
            try:
                self.conn.close()
            except OSError:  # pragma: no cover
                pass

    def step(self, now: float) -> None:
        """Read what arrived, step the node core, send what is due."""
        wall = time.time()
        drain(self.conn, lambda msg: self._handle(msg, now, wall), self.counts, self._warn_once)  # bounded per call
        for out in self.core.tick(now):
            if not self._position_fused and any(math.isfinite(out.y[j]) for j in self._position_channels):
                self._position_fused = True  # x, y are the position's from here on, not the initial state's
            msgs = out.messages(outputs=("X", "Y", "Z", "N") if self.dp else ("Z", "N"))
            self._queue.extend(msgs)
            if self.recorder is not None:
                for topic, _t, m in msgs:
                    self.recorder.rovlab(topic, wall, m)
        self._housekeeping(now)
        if self.vehicle_problems is None and self.vehicle_seen:
            self._check_vehicle_file(now)
        self._check_depth(now)
        self._check_position(now)
        self._update_hold(now)
        if self.flight is not None:
            self.flight.step(now)
        arming = self.want_arm and not self.armed
        if (self.engaged or arming or self.flight is not None) and self.vehicle_seen and self.vehicle_problems == [] \
                and now >= self._due["command"] and self._gains_known(now):
            self._due["command"] = max(self._due["command"] + self.command_period, now)
            self._command(now)

    def _update_hold(self, now: float) -> None:
        """Engage the node core's controller while the vehicle obeys and is seen, disengage it
        otherwise; drop the reference when a pilot or a failsafe took the vehicle (see the module)."""
        with self._ref_lock:
            wanted = self._wanted_ref
            if wanted is None:
                self.hold_blocked = None
                return
            held = self.core.engaged
            in_manual = self.mode == MODES["MANUAL"]
            if held and not (self.armed and in_manual):
                mode = self.mode if self.mode is not None else -1
                what = "disarmed" if not self.armed else f"switched to mode {MODE_NAMES.get(mode, mode)}"
                self.log(f"the vehicle was {what} while the bridge held its set-point: control stops and the set-point "
                         "is dropped (a pilot or a failsafe has the vehicle; set a set-point again to resume)")
                self._wanted_ref = None
                self.core.disengage()
                self.hold_blocked = None
                return
            if self.vehicle_problems != []:
                blocked: str | None = "the vehicle file is not checked against the vehicle yet"
            elif not self.armed:
                blocked = "waiting for the vehicle to be armed in MANUAL"
            elif not in_manual:
                blocked = "waiting for the vehicle to be in MANUAL"
            elif self.telemetry_lost(now):
                blocked = "no telemetry"
            elif self.depth_problem is not None:
                blocked = "depth sensor: " + self.depth_problem
            elif self.position_problem is not None:
                blocked = "position: " + self.position_problem
            else:
                blocked = None
            if blocked is None and not held:
                self.core.set_reference(z=wanted["z"], psi=wanted["psi"], x=wanted.get("x"), y=wanted.get("y"))
                # a hold that stops and resumes (telemetry, depth sensor, position) keeps the set-point it started with
                ref = self.core.reference
                self._wanted_ref = {k: float(ref[i]) for i, k in enumerate(("x", "y", "z", "psi"))}
                where = f"north {ref[0]:.2f} m, east {ref[1]:.2f} m, " if self.dp else ""
                self._say_limited("hold", f"holding {where}depth {ref[2]:.2f} m, heading "
                                          f"{math.degrees(ref[3]):.1f} deg", now)
            elif blocked is not None and held:
                self.core.disengage()
            self.hold_blocked = blocked

    def _check_depth(self, now: float) -> None:
        """The depth sensor's state: an implausible reading (found by _plausible_pressure) or a
        pressure channel the filter has lost. Said loudly, with the value (again when its kind
        changes, else every DEPTH_LOST_REPEAT_S while it lasts); the hold stops (_update_hold)
        until it is back."""
        problem = self._last_implausible
        kind = "implausible"
        last = self.core.last
        if problem is None and last is not None and self.last_telemetry is not None:  # before any: "no telemetry"
            labels = [lab for c, lab in zip(self.core.channels, last.channel_status)
                      if c.quantity == "z" and self.core.sensor_of_kind("pressure") == c.sensor]
            bad = [lab for lab in labels if lab not in ("ok", "recovering")]
            if bad:
                problem = kind = f"the filter has lost the pressure channel ({bad[0]}): its depth is a prediction"
        if problem is not None:
            if self.depth_problem is None:
                self.counts["depth_lost"] += 1
            n = self.counts["depth_lost"]
            self._say_limited("depth", f"DEPTH SENSOR: {problem}; no depth control on a predicted depth: neutral "
                                       f"commands" + (f" (episode {n})" if n > 1 else ""), now, key_text=kind)
        elif self.depth_problem is not None:
            self._say_limited("depth-back", "depth sensor plausible and fused again", now)
        self.depth_problem = problem

    def _check_position(self, now: float) -> None:
        """DP only: the position the controller holds x and y on. No sample yet (ArduSub sends
        LOCAL_POSITION_NED only while its EKF has a position: SITL about 40 s after boot, a real
        vehicle with a DVL or USBL once EKF3 fuses it), an implausible one (found in _handle) or a
        position channel the filter has lost (stopped arriving: timeout; jumped: gate; frozen: stuck)
        stops the hold as the depth sensor does: said, with the value, and neutral commands -- x and
        y are never held on a dead-reckoned prediction -- until it is fused again."""
        if not (self.dp and self._position_channels):
            return
        problem = kind = self._last_bad_position
        last = self.core.last
        if problem is None:
            for j in self._position_channels:
                label = "none" if last is None else last.channel_status[j]
                c = self.core.channels[j]
                if not self._position_fused:  # x, y are still the initial state (the channel says 'ok' at first)
                    problem = kind = (f"no {c.name} sample yet (LOCAL_POSITION_NED: the vehicle's EKF has no position; "
                                      "ArduSub SITL: about 40 s after boot, when EKF3 uses its GPS)")
                elif label == "ok":
                    continue
                elif label == "recovering":  # a hold (re)starting now would take a half-corrected estimate as x, y
                    problem = kind = (f"{c.name} is back and the filter takes it in over its recovery time "
                                      "(x and y are not yet the position's)")
                else:
                    problem = kind = f"the filter has lost {c.name} ({label}): x and y would be a prediction"
                break
        if problem is not None:
            self._say_limited("position", f"POSITION: {problem}; no position control on a predicted position: "
                                          "neutral commands", now, key_text=kind)
        elif self.position_problem is not None:
            self._say_limited("position-back", "position plausible and fused: x and y can be held", now)
        self.position_problem = problem

    def _plausible_position(self, kind: str, fields: dict[str, Any]) -> bool:
        """Whether a position message reads a finite x, y within PLAUSIBLE_POSITION_M of the origin;
        an implausible one is counted, named (by _check_position) and not fused."""
        xy = [fields.get(k) for k in ("x", "y")]
        values = [float(v) if isinstance(v, (int, float)) else math.nan for v in xy]
        if all(math.isfinite(v) and abs(v) <= PLAUSIBLE_POSITION_M for v in values):
            self._last_bad_position = None
            return True
        self.counts["implausible_position"] += 1
        self._last_bad_position = (f"{kind} x = {xy[0]!r}, y = {xy[1]!r} m is implausible: expected finite values "
                                   f"within +-{PLAUSIBLE_POSITION_M:g} m of the EKF origin; its samples are rejected")
        return False

    def _say_limited(self, key: str, text: str, now: float, *, key_text: str | None = None) -> None:
        """Log a message that may repeat: when its text (or ``key_text``) changed, else at most every
        DEPTH_LOST_REPEAT_S (a sensor that comes and goes at the control rate does not flood the log)."""
        what = text if key_text is None else key_text
        last = self._said.get(key)
        if last is None or last[1] != what or now - last[0] >= DEPTH_LOST_REPEAT_S:
            self._said[key] = (now, what)
            self.log(text)

    # -- incoming ------------------------------------------------------------------------------
    def _handle(self, msg: Any, now: float, wall: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counts["bad_data"] += 1
            return
        self.counts["received"] += 1
        if self.recorder is not None:
            self.recorder.mavlink(msg, wall)
        if self.flight is not None and kind in ("MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE") \
                and msg.get_srcSystem() != self.sysid:
            self.flight.pilot_input(msg)  # another ground station's sticks: a pilot takes over
        if msg.get_srcSystem() != self.target_system:
            return
        if kind == "HEARTBEAT":
            if msg.type != self.mav.MAV_TYPE_SUBMARINE:
                return
            if not self.vehicle_seen:
                self.log(f"vehicle {self.target_system} seen (ArduSub mode {msg.custom_mode})")
                self._first_seen = now
            self.vehicle_seen = True
            armed = bool(msg.base_mode & self.mav.MAV_MODE_FLAG_SAFETY_ARMED)
            if armed and self.want_arm:
                self.want_arm = False  # armed once: never re-arm a vehicle that a pilot or a failsafe disarmed
            if self.armed and not armed:
                self.log("the vehicle is disarmed")
            self.armed = armed
            self.mode = int(msg.custom_mode)
            self.last_telemetry = now
            return
        if kind == "PARAM_VALUE":
            self._on_param(msg)
            return
        if kind == "STATUSTEXT":
            self.log(f"vehicle says: {msg.text}")
            return
        if kind == "NAMED_VALUE_FLOAT":
            self._on_named_float(msg)
            return
        if kind == "COMMAND_ACK":
            if msg.command == self.mav.MAV_CMD_SET_MESSAGE_INTERVAL and msg.result != self.mav.MAV_RESULT_ACCEPTED:
                self._warn_once(f"interval-{msg.result}", f"the vehicle refused MAV_CMD_SET_MESSAGE_INTERVAL (MAV_RESULT "
                                                          f"{msg.result}): the telemetry rates stay as its stream "
                                                          "rates (SRn_*) give them")
            return
        if kind not in TELEMETRY:
            return
        self.last_telemetry = now
        if kind in self._arrivals:
            self._arrivals[kind].append(now)
        fields = msg.to_dict()
        if kind == "SERVO_OUTPUT_RAW":
            n = len(self.mixer.thruster_names)
            self.servo_pwm = np.array([float(fields.get(f"servo{i + 1}_raw", 0)) for i in range(n)])
            return
        if kind == "SCALED_PRESSURE2" and not self._plausible_pressure(fields):
            return
        if kind in ("LOCAL_POSITION_NED", "VISION_POSITION_ESTIMATE") and self._position_channels:
            if not self._plausible_position(kind, fields):
                return
        for column, value in self.smap.samples(kind, fields).items():
            sensor, quantity = self._sample_of[column]
            self.core.push(sensor, quantity, value, now)

    def _plausible_pressure(self, fields: dict[str, Any]) -> bool:
        """Whether a SCALED_PRESSURE2 reads a depth within PLAUSIBLE_DEPTH_M; an implausible one is
        counted, named (by _check_depth) and not fused."""
        press = fields.get("press_abs")
        v = self.vehicle
        depth = depth_from_pressure(float(press) if isinstance(press, (int, float)) else math.nan,
                                    water_density=v.water_density, gravity=v.gravity, surface_hpa=self.smap.surface_hpa)
        lo, hi = PLAUSIBLE_DEPTH_M
        if math.isfinite(depth) and lo <= depth <= hi:
            self._last_implausible = None
            return True
        self.counts["implausible_depth"] += 1
        hint = " (ArduSub SITL: start it with --home at altitude 0)" if isinstance(press, (int, float)) and press < 0 \
            else ""
        if isinstance(press, (int, float)) and math.isfinite(press):  # the depth it would mean, for the message
            depth = (press - self.smap.surface_hpa) * 100.0 / (v.water_density * v.gravity)
        self._last_implausible = (f"SCALED_PRESSURE2 press_abs = {press!r} hPa is implausible: depth "
                                  f"{depth:.1f} m with surface {self.smap.surface_hpa:.2f} hPa, expected {lo:g} .. "
                                  f"{hi:g} m{hint}; its samples are rejected")
        return False

    def _on_param(self, msg: Any) -> None:
        name = str(msg.param_id).split("\x00", 1)[0]
        key = next((k for k, names in self._wanted.items() if name in names), None)
        if key is None or not math.isfinite(msg.param_value):
            return
        self.params[name] = float(msg.param_value)
        self.confirmed.add(key)
        self.param_names[key] = name
        if name == "JS_THR_GAIN":
            self._check_throttle_gain()
        if name == "BARO2_GND_PRESS" and msg.param_value > 0:
            self.smap.surface_hpa = float(msg.param_value) / 100.0
        if name == MY_GCS["4.7"] and "GCS_SYSID_HI" not in self._wanted:  # 4.7: a range of ids may count as the GCS
            self._wanted["GCS_SYSID_HI"] = (MY_GCS_HIGH,)
            self._param_asks["GCS_SYSID_HI"] = 0
        if key in ("GCS_SYSID", "GCS_SYSID_HI"):
            self._check_gcs_sysid()

    @property
    def firmware_names(self) -> str | None:
        """Which generation of parameter names the vehicle has: "4.7" (MAV_GCS_SYSID), "4.1"
        (SYSID_MYGCS), None before it said."""
        name = self.param_names.get("GCS_SYSID")
        return None if name is None else ("4.7" if name == MY_GCS["4.7"] else "4.1")

    def _check_gcs_sysid(self) -> None:
        """ArduSub obeys MANUAL_CONTROL and RC overrides from its ground station's system id only
        (4.7: or from MAV_GCS_SYSID to MAV_GCS_SYSID_HI when that is higher)."""
        name = self.param_names.get("GCS_SYSID")
        if name is None:
            return
        low = int(self.params[name])
        high = int(self.params.get(MY_GCS_HIGH, 0)) if name == MY_GCS["4.7"] else 0
        if self.sysid == low or low <= self.sysid <= high:
            return
        where = f"{name} is {low}" + (f" ({MY_GCS_HIGH} {high})" if high else "")
        self._warn_once(f"mygcs-{low}-{high}", f"the vehicle's {where}, the bridge is system {self.sysid}: ArduSub "
                                               f"ignores its commands (use --sysid {low} or set {name})")

    def _check_throttle_gain(self) -> None:
        """JS_THR_GAIN outside ArduSub's range: MANUAL_CONTROL cannot be scaled to it, so the bridge
        sends neutral inputs (1500 us whatever the gains) and says so, until it is back in range."""
        lo, hi = THROTTLE_GAIN_RANGE
        value = self.params["JS_THR_GAIN"]
        bad = not lo <= value <= hi
        if bad and self.gain_problem is None:
            self.gain_problem = (f"the vehicle reports JS_THR_GAIN = {value!r}, outside ArduSub's range {lo:g} .. "
                                 f"{hi:g}: MANUAL_CONTROL cannot be scaled to it, so the bridge sends neutral inputs "
                                 "until it is back in range (set it on the vehicle, or use --command rc_override)")
            self.log(self.gain_problem)
        elif not bad and self.gain_problem is not None:
            self.gain_problem = None
            self.log(f"JS_THR_GAIN = {value:g} is back in ArduSub's range: MANUAL_CONTROL resumes")

    def _on_named_float(self, msg: Any) -> None:
        """NAMED_VALUE_FLOAT "PilotGain": the joystick gain ArduSub applies to MANUAL_CONTROL now
        (JS_GAIN_DEFAULT at boot, then whatever the pilot's gain buttons made of it)."""
        name = msg.name.decode("ascii", "replace") if isinstance(msg.name, bytes) else str(msg.name)
        if name.split("\x00", 1)[0] != "PilotGain":
            return
        gain = float(msg.value)
        if not (math.isfinite(gain) and GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]):
            self._warn_once("gain-range", f"ignoring PilotGain {gain!r} from the vehicle: expected "
                                          f"{GAIN_RANGE[0]:g} .. {GAIN_RANGE[1]:g} (ArduSub constrains the gain it "
                                          "applies to that)")
            return
        old = self.live_gain
        self.live_gain = gain
        self.confirmed.add("PilotGain")
        if old is not None and abs(gain - old) > 1e-4:
            self.log(f"the vehicle's pilot gain changed from {old:g} to {gain:g}: MANUAL_CONTROL is scaled to it")

    def pilot_gain(self) -> float:
        """The gain ArduSub applies to MANUAL_CONTROL: the live PilotGain, else JS_GAIN_DEFAULT (the
        gain at boot, constrained to 0.1 .. 1.0 as ArduSub constrains it), else ArduSub's default 0.5."""
        if self.live_gain is not None:
            return self.live_gain
        boot = self.params.get("JS_GAIN_DEFAULT", 0.5)
        return min(max(boot, GAIN_RANGE[0]), GAIN_RANGE[1]) if math.isfinite(boot) else 0.5

    # -- outgoing ------------------------------------------------------------------------------
    def _housekeeping(self, now: float) -> None:
        mav, out = self.mav, self.conn.mav
        if now >= self._due["heartbeat"]:
            self._due["heartbeat"] = now + 1.0
            out.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        if not self.vehicle_seen:
            return
        if now >= self._due["params"]:
            self._due["params"] = now + 1.0
            self._ask_params()
        if not self._asked_at:  # first sight: ask for the telemetry at the control rate
            for name in self._streams:
                self._ask_rate(name, now)
        elif now >= self._due["rates"]:
            self._due["rates"] = now + 0.5
            self._check_rates(now)
        if self.want_arm and not self.armed and self.vehicle_problems == [] and now >= self._due["arm"]:
            self._due["arm"] = now + 1.0
            if self.mode != MODES["MANUAL"]:
                out.command_long_send(self.target_system, 1, mav.MAV_CMD_DO_SET_MODE, 0,
                                      mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MODES["MANUAL"], 0, 0, 0, 0, 0)
            else:
                out.command_long_send(self.target_system, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0,
                                      0, 0)
                self._armed_by_us = True

    def _ask_params(self) -> None:
        """PARAM_REQUEST_READ, under every name it has had, for each parameter not reported yet; after
        _PARAM_TRIES requests say once what is missing and stop asking."""
        for key, names in self._wanted.items():
            if key in self.confirmed:
                continue
            if self._param_asks[key] >= _PARAM_TRIES:
                self._warn_once(f"param-{key}", f"the vehicle did not report {' or '.join(names)} after "
                                                f"{_PARAM_TRIES} requests: "
                                                f"{_MISSING.get(key, 'this thruster direction cannot be checked')}")
                continue
            self._param_asks[key] += 1
            for name in names:
                self.conn.mav.param_request_read_send(self.target_system, 1, name.encode(), -1)

    def _ask_rate(self, name: str, now: float) -> None:
        self._asked_at[name] = now
        self.counts["rate_requests"] += 1
        self.conn.mav.command_long_send(self.target_system, 1, self.mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                        self._streams[name], int(round(1e6 / self.rate_wanted[name])), 0, 0, 0, 0,
                                        0)

    def _check_rates(self, now: float) -> None:
        """Measure each needed stream over the last RATE_WINDOW_S; ask again when it falls short
        (a ground station's REQUEST_DATA_STREAM resets it), say so once per episode, and say when
        it is back."""
        for name, wanted in self.rate_wanted.items():
            if now - self._asked_at[name] < RATE_WINDOW_S:
                continue  # a full window after the last request
            if name == POSITION_STREAM[0] and not self._position_fused:
                continue  # ArduSub sends it once its EKF has a position (the interval asked for stands): said there
            arrivals = self._arrivals[name]
            rate = sum(1 for t in arrivals if t > now - RATE_WINDOW_S) / RATE_WINDOW_S
            self.rates[name] = rate
            if rate >= RATE_TOLERANCE * wanted:
                if name in self.rate_short:
                    self.rate_short.discard(name)
                    if name in self._said_cannot:
                        self.log(f"{name} arrives at {rate:.1f} Hz again (asked for {wanted:g} Hz)")
                    self._said_cannot.discard(name)
                self._rate_asks[name] = 0
                continue
            group = DATA_STREAM_NAMES.get(STREAM_OF_MESSAGE.get(name, -1), "?")
            asks = self._rate_asks[name]
            if name not in self.rate_short:  # a new episode: the rate was reset (or never came)
                self.rate_short.add(name)
                self.counts["rate_resets"] += 1
                self._resets[name] += 1
                if self._resets[name] <= RATE_RESETS_SAID:
                    self.log(f"{name} arrives at {rate:.1f} Hz, not the {wanted:g} Hz asked for (a ground station on "
                             f"the link may have reset its stream group {group}): asking again"
                             + (" (further resets are counted, not said)" if self._resets[name] == RATE_RESETS_SAID
                                else ""))
            if asks >= RATE_ASKS:
                if name not in self._said_cannot:
                    self._said_cannot.add(name)
                    self.counts["rate_failures"] += 1
                    self.log(f"cannot get {name} at {wanted:g} Hz: it arrives at {rate:.1f} Hz after {asks} requests "
                             f"(the estimator works with fewer samples; set the vehicle's SRn_{group} rate or the "
                             "other ground station's stream rates)")
                if now - self._asked_at[name] < RATE_BACKOFF_S:
                    continue
            self._rate_asks[name] = asks + 1
            self._ask_rate(name, now)

    def _check_vehicle_file(self, now: float) -> None:
        """Once the vehicle reported its frame and thruster parameters (or did not within
        _PARAM_TRIES requests): compare them with the vehicle file. A disagreement stops the bridge
        before it commands anything (exit_code 2, each parameter named), unless trust_vehicle_file."""
        from rovlab.interfaces.mavlink.autopilot import TRUST_HINT, check_vehicle

        pending = [k for k in self._vehicle_keys if k not in self.confirmed and self._param_asks[k] < _PARAM_TRIES]
        if pending:
            return
        params = {k: self.params[k] for k in self._vehicle_keys if k in self.confirmed}
        problems = check_vehicle(self.vehicle, params, source=f"{self.connect} (system {self.target_system})")
        missing = [k for k in self._vehicle_keys if k not in self.confirmed]
        if missing:
            self.log(f"the vehicle did not report {', '.join(missing)}: the vehicle file's thrusters are not checked "
                     "against them")
        if problems and not self.trust_vehicle_file:
            self.vehicle_problems = problems
            self.log(f"the vehicle file {self.vehicle.name} disagrees with the vehicle's autopilot; nothing is commanded "
                     f"(rovlab vehicle from-ardusub --connect URL --base {self.vehicle.name} --out V.toml writes one "
                     f"that agrees; {TRUST_HINT}):")
            for pr in problems:
                self.log(f"  {pr.key} = {pr.value}: expected {pr.expected}")
            self.exit_code = 2
            self.stop()
            return
        if problems:
            self.log(f"--trust-vehicle-file: {len(problems)} disagreement(s) with the vehicle's parameters ignored")
        self.vehicle_problems = []

    def _gains_known(self, now: float) -> bool:
        """MANUAL_CONTROL is scaled by the live pilot gain and JS_THR_GAIN: wait for them (5 s at
        most, then what is known: JS_GAIN_DEFAULT, ArduSub's defaults, said once). RC overrides do
        not depend on them."""
        if self.command != "manual_control" or {"PilotGain", "JS_THR_GAIN"} <= self.confirmed:
            return True
        if self._first_seen is not None and now - self._first_seen > 5.0:
            missing = [what for key, what in (("PilotGain", "the live pilot gain (NAMED_VALUE_FLOAT PilotGain)"),
                                              ("JS_THR_GAIN", "JS_THR_GAIN")) if key not in self.confirmed]
            self._warn_once("gains", f"the vehicle did not report {' and '.join(missing)}: assuming pilot gain "
                                     f"{self.pilot_gain():g}, JS_THR_GAIN {self.params['JS_THR_GAIN']:g}")
            return True
        return False

    def telemetry_lost(self, now: float) -> bool:
        return self.last_telemetry is None or now - self.last_telemetry > self.telemetry_timeout_s

    def _command(self, now: float) -> None:
        lost = self.telemetry_lost(now)
        if lost:
            if not self.failsafe:
                self.failsafe = True
                self.counts["failsafes"] += 1
                self.log(f"no telemetry for {self.telemetry_timeout_s:g} s: sending neutral commands")
            self._send_inputs(np.zeros(4), now, neutral=True)
            return
        if self.failsafe:
            self.failsafe = False
            self.log("telemetry back: control resumes")
        last = self.core.last
        if not (self.core.engaged or self.core.flying) or last is None or not last.engaged:
            # arming, a set-point waiting for the vehicle, or a hold stopped: neutral (no slew limit), which
            # also keeps ArduSub's pilot-input failsafe (FS_PILOT_INPUT) from disarming a vehicle we armed
            self._send_inputs(np.zeros(4), now, neutral=True)
            return
        wanted = self.mixer.inputs_for_outputs(self.mixer.outputs_from_pwm(last.pwm_us))
        dt = self.command_period if self._last_command_time is None else max(now - self._last_command_time, 0.0)
        step = self.max_input_rate * dt
        self._send_inputs(self.inputs + np.clip(wanted - self.inputs, -step, step), now, neutral=False)

    def _send_inputs(self, inputs: np.ndarray, now: float, *, neutral: bool) -> None:
        self.inputs = np.asarray(inputs, dtype=float).copy()
        self._last_command_time = now
        if self.command == "manual_control" and self.gain_problem is not None:
            self.inputs, neutral = np.zeros(4), True  # a throttle gain it cannot scale to (said when it came)
        if self.command == "manual_control":
            gain = self.pilot_gain()
            thr = self.params.get("JS_THR_GAIN", 1.0) if self.gain_problem is None else 1.0  # neutral: any gain
            self.sent_gains = (gain, thr)
            x, y, z, r = manual_control_from_inputs(self.inputs, gain=gain, throttle_gain=thr)
            self.conn.mav.manual_control_send(self.target_system, x, y, z, r, 0)
            sent: tuple[int, ...] = (x, y, z, r)
        else:
            pulses = [65535] * 8  # UINT16_MAX: leave the channel as it is
            for j, axis in enumerate(("forward", "lateral", "throttle", "yaw")):
                pulses[RC_CHANNEL[axis] - 1] = rc_pulse_from_input(self.inputs[j])
            self.conn.mav.rc_channels_override_send(self.target_system, 1, *pulses)
            sent = tuple(pulses)
        self.sent.append((now, sent, neutral))
        self.counts["commands"] += 1
        if neutral:
            self.counts["neutral"] += 1

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.log(text)


# what the bridge does without a parameter the vehicle never reported
_MISSING = {
    "JS_GAIN_DEFAULT": "the pilot gain is the live PilotGain if reported, else ArduSub's default 0.5",
    "JS_THR_GAIN": "assuming ArduSub's default 1",
    "BARO2_GND_PRESS": "depth is measured from 1013.25 hPa",
    "GCS_SYSID": "cannot check that the vehicle obeys the bridge's system id",
    "GCS_SYSID_HI": "assuming no range of ground station ids",
    "FRAME_CONFIG": "the frame (and so the thruster directions) cannot be checked",
    "MOT_PWM_MIN": "the PWM range cannot be checked",
    "MOT_PWM_MAX": "the PWM range cannot be checked",
}
