"""``rovlab mavlink bridge``: an ArduSub vehicle driven by rovlab's estimator and controller.

The bridge is a thin adapter around the node core (rovlab.interfaces.node.NodeCore), which does
all the estimation and control; this module only translates:

* in: the vehicle's telemetry, by rovlab.interfaces.mavlink.logs.SampleMap (SCALED_PRESSURE2 ->
  Bar30 depth with the vehicle file's water density and the vehicle's BARO2_GND_PRESS; ATTITUDE ->
  heading and yaw rate; VISION_POSITION_ESTIMATE / LOCAL_POSITION_NED -> position channels), each
  sample stamped with its arrival time and pushed into the node core;
* out: the node core's thruster PWM commands, read back as ArduSub motor outputs and turned into
  the pilot inputs whose ArduSub mix comes closest (rovlab.allocation.mixing.Mixer), sent as
  MANUAL_CONTROL in ArduSub's ranges (scaled by the vehicle's JS_GAIN_DEFAULT and JS_THR_GAIN)
  or as RC_CHANNELS_OVERRIDE pulses on channels 3-6.

Safety, as the issue asks: the bridge sends its own HEARTBEAT (1 Hz, as a ground station);
it sends MANUAL_CONTROL only once the vehicle reported its joystick gains (or 5 s passed);
commands go out at a fixed rate (``command_hz``) and their change per second is limited
(``max_input_rate``); with no telemetry for ``telemetry_timeout_s`` (default 0.5 s) it sends
neutral commands (no slew limit on the way to neutral); with ``arm`` it puts the vehicle in
MANUAL and arms it -- once: a vehicle disarmed afterwards (by a pilot or a failsafe) stays
disarmed -- and on close it sends neutral and disarms what it armed. The controller is
engaged only once a reference is set (CLI ``--depth``/``--heading-deg`` or the HMI); before that
nothing is commanded and a pilot can fly the vehicle as usual.
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
from rovlab.interfaces.mavlink import dialect, mavutil
from rovlab.interfaces.mavlink.ardusub import MODES
from rovlab.interfaces.mavlink.logs import SampleMap, TelemetryRecorder
from rovlab.interfaces.mavlink.units import RC_CHANNEL, drain, manual_control_from_inputs, rc_pulse_from_input
from rovlab.interfaces.node.core import NodeCore
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle

TELEMETRY = frozenset({"ATTITUDE", "SCALED_PRESSURE2", "LOCAL_POSITION_NED", "VISION_POSITION_ESTIMATE",
                       "SERVO_OUTPUT_RAW", "VFR_HUD", "SYS_STATUS"})
_PARAMS_WANTED = ("JS_GAIN_DEFAULT", "JS_THR_GAIN", "BARO2_GND_PRESS", "SYSID_MYGCS")
_STREAMS = {"ATTITUDE": 30, "SCALED_PRESSURE2": 137, "SERVO_OUTPUT_RAW": 36}  # MAVLink message ids
COMMAND_MODES = ("manual_control", "rc_override")


class MavlinkBridge:
    """The node core on one MAVLink connection to an ArduSub vehicle (see the module).

    Drive it with :meth:`run` (blocking; :meth:`stop` from another thread or a signal handler) or
    call :meth:`step` from your own loop. :meth:`drain` hands out the rovlab messages produced
    since the last call (for the HMI)."""

    def __init__(self, vehicle: Vehicle, config: DesignConfig, *, connect: str = "udpin:127.0.0.1:14550",
                 target_system: int = 1, sysid: int = 255, compid: int = 191, command: str = "manual_control",
                 command_hz: float | None = None, max_input_rate: float = 4.0, telemetry_timeout_s: float = 0.5,
                 arm: bool = False, record: str | None = None, log: Callable[[str], None] | None = None,
                 core: NodeCore | None = None) -> None:
        if command not in COMMAND_MODES:
            raise ValueError(f"command must be one of {', '.join(COMMAND_MODES)}, got {command!r}")
        for name, v, lo, hi in (("telemetry_timeout_s", telemetry_timeout_s, 0.05, 10.0),
                                ("max_input_rate", max_input_rate, 0.1, 100.0)):
            if not (math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"{name} must be within {lo:g} .. {hi:g}, got {v!r}")
        self.log = log or (lambda text: None)
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
        self.conn = mavutil().mavlink_connection(connect, source_system=self.sysid, source_component=compid,
                                                 dialect="ardupilotmega")
        self.connect = connect
        self.recorder = TelemetryRecorder(record, metadata={"connect": connect, "vehicle": vehicle.name,
                                                            "config": config.name}) if record else None
        # what we know of the vehicle
        self.params: dict[str, float] = {"JS_GAIN_DEFAULT": 0.5, "JS_THR_GAIN": 1.0}  # ArduSub's defaults
        self.confirmed: set[str] = set()  # parameters the vehicle has reported
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
        self.counts: dict[str, int] = {"received": 0, "bad_data": 0, "errors": 0, "commands": 0, "neutral": 0,
                                       "failsafes": 0}
        self._armed_by_us = False
        self._due: dict[str, float] = {"heartbeat": 0.0, "command": 0.0, "params": 0.0, "arm": 0.0}
        self._streams_asked = False
        self._queue: collections.deque[tuple[str, float, dict[str, Any]]] = collections.deque(maxlen=20000)
        self._stop = threading.Event()
        self._last_command_time: float | None = None
        self._warned: set[str] = set()

    # -- control from outside ------------------------------------------------------------------
    def set_reference(self, *, z: float | None = None, psi: float | None = None) -> None:
        """Depth [m] / heading [rad] set-point; engages the controller (ValueError on bad values)."""
        self.core.set_reference(z=z, psi=psi)

    def disengage(self) -> None:
        self.core.disengage()

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
            msgs = out.messages(outputs=("Z", "N"))
            self._queue.extend(msgs)
            if self.recorder is not None:
                for topic, _t, m in msgs:
                    self.recorder.rovlab(topic, wall, m)
        self._housekeeping(now)
        if self.core.engaged and self.vehicle_seen and now >= self._due["command"] and self._gains_known(now):
            self._due["command"] = max(self._due["command"] + self.command_period, now)
            self._command(now)

    # -- incoming ------------------------------------------------------------------------------
    def _handle(self, msg: Any, now: float, wall: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counts["bad_data"] += 1
            return
        self.counts["received"] += 1
        if self.recorder is not None:
            self.recorder.mavlink(msg, wall)
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
        if kind not in TELEMETRY:
            return
        self.last_telemetry = now
        fields = msg.to_dict()
        if kind == "SERVO_OUTPUT_RAW":
            n = len(self.mixer.thruster_names)
            self.servo_pwm = np.array([float(fields.get(f"servo{i + 1}_raw", 0)) for i in range(n)])
            return
        for column, value in self.smap.samples(kind, fields).items():
            sensor, quantity = self._sample_of[column]
            self.core.push(sensor, quantity, value, now)

    def _on_param(self, msg: Any) -> None:
        name = str(msg.param_id).split("\x00", 1)[0]
        if name not in _PARAMS_WANTED or not math.isfinite(msg.param_value):
            return
        self.params[name] = float(msg.param_value)
        self.confirmed.add(name)
        if name == "BARO2_GND_PRESS" and msg.param_value > 0:
            self.smap.surface_hpa = float(msg.param_value) / 100.0
        if name == "SYSID_MYGCS" and int(msg.param_value) != self.sysid:
            self._warn_once("mygcs", f"the vehicle's SYSID_MYGCS is {int(msg.param_value)}, the bridge is system "
                                     f"{self.sysid}: ArduSub ignores its commands (use --sysid "
                                     f"{int(msg.param_value)} or set SYSID_MYGCS)")

    # -- outgoing ------------------------------------------------------------------------------
    def _housekeeping(self, now: float) -> None:
        mav, out = self.mav, self.conn.mav
        if now >= self._due["heartbeat"]:
            self._due["heartbeat"] = now + 1.0
            out.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        if not self.vehicle_seen:
            return
        if now >= self._due["params"] and any(p not in self.confirmed for p in _PARAMS_WANTED):
            self._due["params"] = now + 1.0
            for name in _PARAMS_WANTED:
                if name not in self.confirmed:
                    out.param_request_read_send(self.target_system, 1, name.encode(), -1)
        if not self._streams_asked:
            self._streams_asked = True  # ask once for the telemetry at the control rate (ArduSub honours it)
            for msg_id in _STREAMS.values():
                out.command_long_send(self.target_system, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                      int(self.core.h * 1e6), 0, 0, 0, 0, 0)
        if self.want_arm and not self.armed and now >= self._due["arm"]:
            self._due["arm"] = now + 1.0
            if self.mode != MODES["MANUAL"]:
                out.command_long_send(self.target_system, 1, mav.MAV_CMD_DO_SET_MODE, 0,
                                      mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MODES["MANUAL"], 0, 0, 0, 0, 0)
            else:
                out.command_long_send(self.target_system, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0,
                                      0, 0)
                self._armed_by_us = True

    def _gains_known(self, now: float) -> bool:
        """MANUAL_CONTROL is scaled by the vehicle's joystick gains: wait for them (5 s at most, then
        ArduSub's defaults, said once). RC overrides do not depend on them."""
        if self.command != "manual_control" or {"JS_GAIN_DEFAULT", "JS_THR_GAIN"} <= self.confirmed:
            return True
        if self._first_seen is not None and now - self._first_seen > 5.0:
            self._warn_once("gains", "the vehicle did not report JS_GAIN_DEFAULT / JS_THR_GAIN: assuming "
                                     f"{self.params['JS_GAIN_DEFAULT']:g} / {self.params['JS_THR_GAIN']:g}")
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
        if last is None or not last.engaged:
            return
        wanted = self.mixer.inputs_for_outputs(self.mixer.outputs_from_pwm(last.pwm_us))
        dt = self.command_period if self._last_command_time is None else max(now - self._last_command_time, 0.0)
        step = self.max_input_rate * dt
        self._send_inputs(self.inputs + np.clip(wanted - self.inputs, -step, step), now, neutral=False)

    def _send_inputs(self, inputs: np.ndarray, now: float, *, neutral: bool) -> None:
        self.inputs = np.asarray(inputs, dtype=float).copy()
        self._last_command_time = now
        if self.command == "manual_control":
            gain = self.params.get("JS_GAIN_DEFAULT", 0.5) or 0.5
            thr = self.params.get("JS_THR_GAIN", 1.0) or 1.0
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
