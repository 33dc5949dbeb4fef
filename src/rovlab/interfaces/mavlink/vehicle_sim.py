"""``rovlab mavlink sim``: a MAVLink endpoint that behaves like an ArduSub vehicle, on the simulated
vehicle of a scenario (rovlab.sim.realtime.SimulatedVehicle: the same plant, thrusters, sensors,
noise, biases, drop-out windows and truth events as the scenario's batch run and the ROS simulators).

What it does, as a stock BlueROV2 running ArduSub would (docs/mavlink.md has the details):

* sends HEARTBEAT (MAV_TYPE_SUBMARINE, ArduPilot autopilot, armed flag, custom_mode = the
  ArduSub mode number), ATTITUDE (the IMU's latest heading and yaw-rate samples, rad and rad/s),
  SCALED_PRESSURE2 (the external Bar30: press_abs in hPa from the pressure sensor's latest depth
  sample and the true water density), VFR_HUD (heading in degrees, alt = -depth), SYS_STATUS,
  SERVO_OUTPUT_RAW (one servo per thruster in the vehicle file's order, in us) and, with
  ``local_position``, LOCAL_POSITION_NED (the true position, as with a positioning system). A
  sensor's message stops while the sensor sends nothing (a drop-out window of the scenario, or
  none at all): it resumes with its next sample;
  SYS_STATUS carries the health bits as ArduSub sets them (subsystems it does not have, such as
  the fence, marked healthy; the pressure sensor healthy while it reports) and NAMED_VALUE_FLOAT
  "PilotGain" the live pilot gain;
* streams at the rates ArduSub would: MAV_CMD_SET_MESSAGE_INTERVAL sets one message's rate and
  REQUEST_DATA_STREAM sets the rate of every message of a stream group, overwriting what
  SET_MESSAGE_INTERVAL set (ArduPilot's GCS_MAVLINK::handle_request_data_stream; the groups in
  rovlab.interfaces.mavlink.ardusub.STREAM_OF_MESSAGE), as a ground station's request does on a
  real link;
* arms and disarms on COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM and changes mode on
  MAV_CMD_DO_SET_MODE or SET_MODE, each answered by COMMAND_ACK; MANUAL and STABILIZE are
  simulated (identical here: roll and pitch are not modelled), other modes are refused;
  MAV_CMD_GET_HOME_POSITION is answered with HOME_POSITION and GPS_GLOBAL_ORIGIN (or FAILED
  without a home, as ArduPilot does); AUTOPILOT_VERSION is sent on request, a mission list
  request gets an empty list and MAVLink FTP requests are refused at once (no files), so a ground
  station reads the parameters with the parameter protocol (what ground stations ask at connect);
* answers the parameter protocol (PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET ->
  PARAM_VALUE, with ArduSub's types) for rovlab.interfaces.mavlink.ardusub.sim_parameters of one
  generation of names: 4.7 (MAV_SYSID, MAV_GCS_SYSID, MAV_GCS_SYSID_HI; the default) or 4.1
  (SYSID_THISMAV, SYSID_MYGCS);
* obeys MANUAL_CONTROL and RC_CHANNELS_OVERRIDE only from the ground station's system id (as
  ArduSub does), turns them into normalised inputs with the live pilot gain and JS_THR_GAIN
  (rovlab.interfaces.mavlink.units) and mixes them onto the thrusters
  (rovlab.allocation.mixing.Mixer: ArduSub-style factors derived from the vehicle's geometry,
  linear output -> PWM), while armed; the pilot gain starts from JS_GAIN_DEFAULT and moves with
  the gain buttons of ArduSub's default button map (MANUAL_CONTROL.buttons 11 up, 12 down);
* STATUSTEXT longer than 50 characters is sent in chunks (id, chunk_seq), as MAVLink 2 does;
* pilot-input failsafe: armed and no pilot input for FS_PILOT_TIMEOUT s -> neutral inputs (and
  with FS_PILOT_INPUT = 2, disarm).

Anything malformed (bad CRC, unknown message, out-of-range joystick values, a bad PARAM_SET) is
counted and answered where MAVLink has an answer; the endpoint keeps running.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rovlab.allocation.mixing import Mixer
from rovlab.interfaces.mavlink import connection, dialect
from rovlab.interfaces.mavlink.ardusub import (
    BUTTON_GAIN_DEC,
    BUTTON_GAIN_INC,
    BUTTON_SHIFT,
    DEFAULT_FIRMWARE,
    FS_PILOT_DISABLED,
    FS_PILOT_DISARM,
    MODE_NAMES,
    MODES,
    MY_GCS,
    MY_GCS_HIGH,
    STREAM_OF_MESSAGE,
    THIS_MAV,
    Parameters,
    boot_gain,
    motor_directions,
    sim_parameters,
    stepped_gain,
)
from rovlab.interfaces.mavlink.units import (
    RC_CHANNEL,
    cdeg_c,
    drain,
    heading_deg,
    input_from_rc_pulse,
    inputs_from_manual_control,
    pressure_hpa,
)
from rovlab.sim.realtime import SimulatedVehicle, VehicleSample

SIMULATED_MODES = (MODES["MANUAL"], MODES["STABILIZE"])
_AXES = ("forward", "lateral", "throttle", "yaw")
_ARM_FORCE_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 that forces arming/disarming
_MAX_CATCH_UP_S = 1.0  # real time the simulation catches up in one call; beyond it, it falls behind
# telemetry stream -> (sensor kind, quantities) of the samples it carries
_SOURCES = {"attitude": ("imu", ("psi", "r")), "pressure": ("pressure", ("z",))}
DEFAULT_HOME = (63.44, 10.40, 0.0)  # latitude, longitude [deg], altitude [m]: an arbitrary point in Trondheimsfjord
_TEXT_LEN = 50  # STATUSTEXT.text
_MAX_CHUNKS = 8  # a longer STATUSTEXT is cut after this many chunks


class ArduSubSim:
    """A simulated ArduSub vehicle on one MAVLink connection. Drive it with :meth:`run` (or call
    :meth:`step` from your own loop); not thread-safe apart from :meth:`stop`."""

    def __init__(self, sim: SimulatedVehicle, *, connect: str = "udpout:127.0.0.1:14550",
                 local_position: bool = False, attitude_hz: float = 25.0, firmware: str = DEFAULT_FIRMWARE,
                 home: tuple[float, float, float] | None = DEFAULT_HOME,
                 log: Callable[[str], None] | None = None) -> None:
        """``sim``: the simulated vehicle (its model vehicle is what the autopilot knows: frame, PWM
        range, mixing; its truth is the water and the thrust). Compile its plant (``sim.compile()``)
        before: the first step otherwise waits for numba while a ground station waits for us.
        ``firmware``: the generation of parameter names ("4.7" or "4.1"); ``home``: latitude,
        longitude [deg] and altitude [m] of the home position and EKF origin (at the NED origin), or
        None for a vehicle without one."""
        self.mav = dialect()
        self.sim = sim
        self.vehicle = vehicle = sim.prep.vehicle
        self.mixer = Mixer.from_vehicle(vehicle)
        n = len(vehicle.thrusters)
        if n > 16:
            raise ValueError(f"SERVO_OUTPUT_RAW carries 16 outputs; vehicle {vehicle.name!r} has {n} thrusters")
        pwm_min = min(t.pwm_min_us for t in vehicle.thrusters)
        pwm_max = max(t.pwm_max_us for t in vehicle.thrusters)
        self.firmware = firmware
        frame = 2 if n == 8 else 7  # VECTORED_6DOF (the Heavy), else CUSTOM
        self.params = Parameters(sim_parameters(firmware) + motor_directions(vehicle, frame),
                                 BARO_SPEC_GRAV=vehicle.water_density / 1000.0, MOT_PWM_MIN=pwm_min,
                                 MOT_PWM_MAX=pwm_max, FRAME_CONFIG=frame)
        self.my_gcs = MY_GCS[firmware]  # the parameter naming the ground station
        self.sysid = int(self.params[THIS_MAV[firmware]])
        p = self.params
        self.gain = boot_gain(p["JS_GAIN_DEFAULT"], p["JS_GAIN_MIN"], p["JS_GAIN_MAX"], int(p["JS_GAIN_STEPS"]))
        if home is not None and not (all(math.isfinite(v) for v in home) and -90 <= home[0] <= 90
                                     and -180 <= home[1] <= 180):
            raise ValueError(f"home must be latitude -90 .. 90, longitude -180 .. 180 [deg] and a finite altitude, "
                             f"got {home!r}")
        self.home = home
        self.conn = connection(connect, source_system=self.sysid, source_component=1)
        self.connect = connect
        self.local_position = local_position
        self.log = log or (lambda text: None)
        self.armed = False
        self.mode = MODES["MANUAL"]
        self.inputs = np.zeros(4)  # normalised pilot inputs [forward, lateral, throttle, yaw]
        self.last_pilot: float | None = None
        self.failsafe = False
        self.counts: dict[str, int] = {"received": 0, "bad_data": 0, "ignored_sysid": 0, "clipped": 0,
                                       "refused": 0, "errors": 0, "stream_requests": 0}
        self._buttons = 0  # MANUAL_CONTROL.buttons last received
        self._text_id = 0
        self._stop = threading.Event()
        self._t0: float | None = None
        self.state: VehicleSample = sim.step()  # step 0: the initial state and its samples
        self.latest: dict[str, tuple[float, float]] = {}  # stream -> (sample, time of the sample [s])
        self._silent_after = {key: _silence(sim, kind) for key, (kind, _q) in _SOURCES.items()}
        self._take(self.state)
        pressure = next((s for s in vehicle.sensors if s.kind == "pressure"), None)
        rate = pressure.rate_hz if pressure is not None else 10.0
        self._periods = {"heartbeat": 1.0, "attitude": 1.0 / attitude_hz, "pressure": 1.0 / rate,
                         "sys_status": 1.0, "named_float": 1.0, "servo": 0.1, "vfr_hud": 0.2, "local_position": 0.1}
        self._default_periods = dict(self._periods)
        self._due = dict.fromkeys(self._periods, 0.0)
        self._warned: set[str] = set()

    # -- lifecycle ---------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe; also from a signal handler)."""
        self._stop.set()

    def close(self) -> None:
        try:
            self.conn.close()
        except OSError:  # pragma: no cover - already closed
            pass

    def run(self, *, duration_s: float | None = None, tick_s: float = 0.005) -> None:
        """Serve until :meth:`stop` (or for duration_s of wall-clock time)."""
        start = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if duration_s is not None and now - start >= duration_s:
                break
            self.step(now)
            self._stop.wait(tick_s)

    def step(self, now: float) -> None:
        """Read what arrived, apply the failsafe, advance the plant to ``now`` and send what is due."""
        if self._t0 is None:
            self._t0 = now
        drain(self.conn, lambda msg: self._handle(msg, now), self.counts, self._warn_once)  # bounded per call
        self._failsafe(now)
        self._actuate(now - self._t0)
        self._advance(now - self._t0)
        self._telemetry(now)

    def _advance(self, elapsed: float) -> None:
        """Step the simulated vehicle to ``elapsed`` s of real time (whole control periods)."""
        sim = self.sim
        behind = elapsed - sim.k * sim.h
        if behind > _MAX_CATCH_UP_S:  # the process was held up (a debugger, a suspended laptop)
            skip = behind - _MAX_CATCH_UP_S
            self._t0 = (self._t0 or 0.0) + skip
            elapsed -= skip
            self._warn_once("behind", f"the simulation fell {skip:.1f} s behind real time; it continues from "
                                      "where it was")
        while sim.k * sim.h <= elapsed + 1e-9:
            try:
                self.state = sim.step()
            except RuntimeError as exc:  # the plant diverged: say so, hold the last state
                self._warn_once("diverged", str(exc))
                self.stop()
                return
            self._take(self.state)

    def _take(self, s: VehicleSample) -> None:
        for sensor, quantity, value in s.samples:
            kind = self.sim.sensor_kind(sensor)
            for key, (k, quantities) in _SOURCES.items():
                if k == kind and quantity in quantities:
                    self.latest[key + "." + quantity] = (value, s.t)

    def _sample(self, key: str, quantity: str) -> float | None:
        """The latest sample a stream carries, None while its sensor is silent."""
        got = self.latest.get(key + "." + quantity)
        if got is None or self.state.t - got[1] > self._silent_after[key]:
            return None
        return got[0]

    # -- incoming ----------------------------------------------------------------------------
    def _handle(self, msg: Any, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counts["bad_data"] += 1
            return
        self.counts["received"] += 1
        handler = _HANDLERS.get(kind)
        if handler is not None:
            handler(self, msg, now)

    def _from_my_gcs(self, msg: Any) -> bool:
        """Whether a pilot input comes from the ground station: its system id is the one the
        parameters name (4.7: or within MAV_GCS_SYSID .. MAV_GCS_SYSID_HI when that is higher)."""
        src = msg.get_srcSystem()
        low = int(self.params[self.my_gcs])
        high = int(self.params[MY_GCS_HIGH]) if MY_GCS_HIGH in self.params else 0
        if src == low or low <= src <= high:
            return True
        self.counts["ignored_sysid"] += 1
        self._warn_once(f"sysid-{src}", f"ignoring {msg.get_type()} from system {src}: {self.my_gcs} is {low}")
        return False

    def _on_manual_control(self, msg: Any, now: float) -> None:
        if msg.target != self.sysid or not self._from_my_gcs(msg):
            return
        raw = (msg.x, msg.y, msg.z, msg.r)
        x, y, r = (float(np.clip(v, -1000, 1000)) for v in (msg.x, msg.y, msg.r))
        z = float(np.clip(msg.z, 0, 1000))
        if (x, y, z, r) != tuple(float(v) for v in raw):
            self.counts["clipped"] += 1
            self._warn_once("mc-range", f"MANUAL_CONTROL out of range {raw}: clipped to x, y, r in -1000..1000, "
                                        "z in 0..1000")
        self._on_buttons(int(msg.buttons))
        self.inputs = inputs_from_manual_control(x, y, z, r, gain=self.gain, throttle_gain=self.params["JS_THR_GAIN"])
        self._pilot_input(now)

    def _on_buttons(self, buttons: int) -> None:
        """The gain buttons of ArduSub's default button map, acted on when pressed (not held)."""
        pressed = buttons & ~self._buttons
        self._buttons = buttons
        if buttons & (1 << BUTTON_SHIFT):
            return  # shifted, these buttons trim pitch: not simulated
        for button, up in ((BUTTON_GAIN_INC, True), (BUTTON_GAIN_DEC, False)):
            if pressed & (1 << button):
                p = self.params
                self.gain = stepped_gain(self.gain, up, gain_default=p["JS_GAIN_DEFAULT"], gain_min=p["JS_GAIN_MIN"],
                                         gain_max=p["JS_GAIN_MAX"], steps=int(p["JS_GAIN_STEPS"]))
                self._status(f"#Gain is {self.gain * 100:2.0f}%", severity=self.mav.MAV_SEVERITY_INFO)

    def _on_rc_override(self, msg: Any, now: float) -> None:
        if msg.target_system != self.sysid or not self._from_my_gcs(msg):
            return
        touched = False
        for j, axis in enumerate(_AXES):
            pulse = getattr(msg, f"chan{RC_CHANNEL[axis]}_raw")
            if pulse in (0, 65535):  # 0 = release, UINT16_MAX = leave as it is
                continue
            self.inputs[j] = input_from_rc_pulse(pulse)
            touched = True
        if touched:
            self._pilot_input(now)

    def _pilot_input(self, now: float) -> None:
        self.last_pilot = now
        if self.failsafe:
            self.failsafe = False
            self._status("pilot input back", severity=self.mav.MAV_SEVERITY_INFO)

    def _on_command_long(self, msg: Any, now: float) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        mav = self.mav
        result = mav.MAV_RESULT_UNSUPPORTED
        send_version = send_home = False
        wanted = msg.param1 if msg.command == mav.MAV_CMD_REQUEST_MESSAGE else None
        if msg.command == mav.MAV_CMD_GET_HOME_POSITION or wanted in (mav.MAVLINK_MSG_ID_HOME_POSITION,
                                                                       mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN):
            send_home = self.home is not None  # ArduPilot: FAILED while no home is set
            result = mav.MAV_RESULT_ACCEPTED if send_home else mav.MAV_RESULT_FAILED
        elif msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._arm(msg.param1, now)
        elif msg.command == mav.MAV_CMD_DO_SET_MODE:
            result = self._set_mode(msg.param2)
        elif msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(msg.param1, msg.param2)
        elif msg.command in (mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            send_version = msg.command != mav.MAV_CMD_REQUEST_MESSAGE or wanted == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            result = mav.MAV_RESULT_ACCEPTED if send_version else mav.MAV_RESULT_UNSUPPORTED
        self.conn.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        if send_version:
            caps = mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            self.conn.mav.autopilot_version_send(caps, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)
        if send_home:
            self._send_home(now)

    def _send_home(self, now: float) -> None:
        """HOME_POSITION and GPS_GLOBAL_ORIGIN, as ArduPilot sends them together (the home at the
        NED origin, which is also the EKF origin here)."""
        assert self.home is not None
        lat, lon, alt = self.home
        t_us = int((now - (self._t0 or now)) * 1e6)
        e7, mm = int(round(lat * 1e7)), int(round(alt * 1000.0))
        f7 = int(round(lon * 1e7))
        self.conn.mav.home_position_send(e7, f7, mm, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, t_us)
        self.conn.mav.gps_global_origin_send(e7, f7, mm, t_us)

    def _set_interval(self, msg_id: float, interval_us: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL for the streamed messages: interval in us, 0 = default,
        -1 = off (limited to 1 .. 100 Hz)."""
        key = _STREAM_KEYS.get(int(msg_id)) if math.isfinite(msg_id) else None
        if key is None or not math.isfinite(interval_us):
            self.counts["refused"] += 1
            return self.mav.MAV_RESULT_DENIED
        if interval_us < 0:
            self._periods[key] = math.inf
        elif interval_us == 0:
            self._periods[key] = self._default_periods[key]
        else:
            self._periods[key] = min(max(interval_us * 1e-6, 0.01), 1.0)
        self._due[key] = 0.0
        return self.mav.MAV_RESULT_ACCEPTED

    def _on_request_data_stream(self, msg: Any, now: float) -> None:
        """REQUEST_DATA_STREAM: the rate [Hz] of every message of a stream group (all groups for
        MAV_DATA_STREAM_ALL), overwriting intervals set one by one; 0 or start_stop = 0 stops them
        (ArduPilot's GCS_MAVLINK::handle_request_data_stream)."""
        if msg.target_system not in (0, self.sysid) or msg.start_stop not in (0, 1):
            return
        rate = int(msg.req_message_rate) if msg.start_stop == 1 else 0
        group = int(msg.req_stream_id)
        keys = [k for k, name in _STREAM_MESSAGE.items()
                if STREAM_OF_MESSAGE.get(name) is not None and group in (0, STREAM_OF_MESSAGE[name])]
        self.counts["stream_requests"] += 1
        for key in keys:
            self._periods[key] = math.inf if rate <= 0 else min(max(1.0 / rate, 0.01), 60.0)
            self._due[key] = now
        if keys:
            what = ", ".join(_STREAM_MESSAGE[k] for k in keys)
            self._warn_once(f"rds-{msg.get_srcSystem()}-{group}-{rate}",
                            f"system {msg.get_srcSystem()} asked for stream group {group} at {rate} Hz: {what}",
                            send=False)

    def _on_file_transfer(self, msg: Any, now: float) -> None:
        """MAVLink FTP: the simulator has no files. Ending a session is acknowledged, a file or
        directory request refused at once (NAK FileNotFound), anything else NAK Fail, so a ground
        station that tries FTP for the parameters falls back to the parameter protocol without
        waiting for timeouts."""
        if msg.target_system not in (0, self.sysid):
            return
        payload = bytes(msg.payload)
        if len(payload) < _FTP_HEADER.size:
            self.counts["refused"] += 1
            return
        seq, session, opcode = _FTP_HEADER.unpack_from(payload)[:3]
        if opcode in (_FTP_TERMINATE_SESSION, _FTP_RESET_SESSIONS):
            reply, size, error = _FTP_ACK, 0, b""
        else:
            reply, size = _FTP_NAK, 1
            error = bytes([_FTP_ERR_FILE_NOT_FOUND if opcode in _FTP_FILE_OPS else _FTP_ERR_FAIL])
        header = _FTP_HEADER.pack((seq + 1) & 0xFFFF, session, reply, size, opcode, 0, 0, 0)
        data = (header + error).ljust(251, b"\x00")
        self.conn.mav.file_transfer_protocol_send(0, msg.get_srcSystem(), msg.get_srcComponent(), list(data))

    def _on_mission_request_list(self, msg: Any, now: float) -> None:
        if msg.target_system in (0, self.sysid):  # no missions in the simulator: an empty list
            self.conn.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(), 0,
                                             getattr(msg, "mission_type", 0))

    def _arm(self, param1: float, now: float) -> int:
        mav = self.mav
        if param1 == 1.0:
            if self.mode not in SIMULATED_MODES:
                self._status(f"arming refused: mode {MODE_NAMES.get(self.mode, self.mode)} is not simulated")
                return mav.MAV_RESULT_DENIED
            if not self.armed:
                self.armed = True
                self.last_pilot = now  # the failsafe counts from arming
                self.inputs[:] = 0.0
                self._status("Arming motors", severity=mav.MAV_SEVERITY_INFO)
            return mav.MAV_RESULT_ACCEPTED
        if param1 == 0.0:
            if self.armed:
                self.armed = False
                self._status("Disarming motors", severity=mav.MAV_SEVERITY_INFO)
            return mav.MAV_RESULT_ACCEPTED
        self.counts["refused"] += 1
        return mav.MAV_RESULT_DENIED

    def _set_mode(self, custom_mode: float) -> int:
        mode = int(custom_mode) if math.isfinite(custom_mode) else -1
        if mode not in SIMULATED_MODES:
            self.counts["refused"] += 1
            self._status(f"mode {MODE_NAMES.get(mode, mode)} not simulated (MANUAL, STABILIZE are)")
            return self.mav.MAV_RESULT_DENIED
        self.mode = mode
        return self.mav.MAV_RESULT_ACCEPTED

    def _on_set_mode(self, msg: Any, now: float) -> None:
        if msg.target_system == self.sysid:
            self._set_mode(float(msg.custom_mode))

    def _on_param_request_list(self, msg: Any, now: float) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        # ArduPilot answers a parameter list request with its banner first
        info = self.mav.MAV_SEVERITY_INFO
        self._status(f"ArduSub {self.firmware} parameters: rovlab mavlink sim of {self.vehicle.name}, "
                     f"{len(self.vehicle.thrusters)} thrusters", severity=info, log=False)
        frame = {2: "VECTORED_6DOF", 1: "VECTORED"}.get(int(self.params["FRAME_CONFIG"]), "CUSTOM")
        self._status(f"Frame: {frame}", severity=info, log=False)
        for spec in self.params.specs:
            self._send_param(spec.name)

    def _on_param_request_read(self, msg: Any, now: float) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        if msg.param_index >= 0:
            if msg.param_index < len(self.params):
                self._send_param(self.params.specs[msg.param_index].name)
            return
        name = _param_name(msg.param_id)
        if self.params.spec(name) is not None:
            self._send_param(name)  # an unknown name gets no answer, as from ArduSub 4.1

    def _on_param_set(self, msg: Any, now: float) -> None:
        if msg.target_system not in (0, self.sysid):
            return
        name = _param_name(msg.param_id)
        why = self.params.set(name, msg.param_value)
        if why is not None:
            self.counts["refused"] += 1
            self._status(f"PARAM_SET refused: {why}")
        if self.params.spec(name) is not None:
            self._send_param(name)  # the value now in force (unchanged if refused), as ArduPilot does

    # -- outgoing ----------------------------------------------------------------------------
    def _send_param(self, name: str) -> None:
        spec = self.params.spec(name)
        assert spec is not None
        self.conn.mav.param_value_send(name.encode("ascii"), float(self.params[name]), spec.mav_type,
                                       len(self.params), self.params.index(name))

    def _status(self, text: str, *, severity: int | None = None, log: bool = True) -> None:
        """A STATUSTEXT; longer than 50 characters, in chunks of 50 with one id (1 .. 65535) and
        chunk_seq 0, 1, ..., the last one shorter than 50 (empty if need be), as MAVLink 2 defines."""
        sev = self.mav.MAV_SEVERITY_WARNING if severity is None else severity
        if log:
            self.log(text)
        data = text.encode("ascii", "replace")
        if len(data) <= _TEXT_LEN:
            self.conn.mav.statustext_send(sev, data)
            return
        self._text_id = self._text_id % 0xFFFF + 1
        chunks = [data[i:i + _TEXT_LEN] for i in range(0, len(data), _TEXT_LEN)][:_MAX_CHUNKS]
        if len(chunks[-1]) == _TEXT_LEN:
            chunks.append(b"")
        for seq, chunk in enumerate(chunks):
            self.conn.mav.statustext_send(sev, chunk, self._text_id, seq)

    def _warn_once(self, key: str, text: str, *, send: bool = True) -> None:
        if key not in self._warned:
            self._warned.add(key)
            if send:
                self._status(text)
            else:
                self.log(text)

    def _failsafe(self, now: float) -> None:
        action = int(self.params["FS_PILOT_INPUT"])
        if not self.armed or action == FS_PILOT_DISABLED or self.last_pilot is None or self.failsafe:
            return
        if now - self.last_pilot > self.params["FS_PILOT_TIMEOUT"]:
            self.failsafe = True
            self.inputs[:] = 0.0
            self._status("Lost manual control", severity=self.mav.MAV_SEVERITY_CRITICAL)
            if action == FS_PILOT_DISARM:
                self.armed = False
                self._status("Disarming motors (pilot input failsafe)")

    def _actuate(self, elapsed: float) -> None:
        """The motors' PWM from the pilot inputs now, acting from ``elapsed`` s of simulated time."""
        if self.armed and self.mode in SIMULATED_MODES:
            self.sim.set_pwm(self.mixer.pwm_us(self.mixer.outputs(self.inputs)), at=elapsed)
        else:
            self.sim.set_pwm(self.sim.neutral_pwm, at=elapsed)

    def _telemetry(self, now: float) -> None:
        due = [k for k, t in self._due.items() if now >= t]
        for key in due:
            self._due[key] = max(self._due[key] + self._periods[key], now)  # inf: the stream is off
        if not due:
            return
        mav, out = self.mav, self.conn.mav
        boot_ms = int((now - (self._t0 or now)) * 1000) & 0xFFFFFFFF
        x = self.state.truth
        if "heartbeat" in due:
            base = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
                    | mav.MAV_MODE_FLAG_STABILIZE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0))
            state = (mav.MAV_STATE_CRITICAL if self.failsafe
                     else mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY)
            out.heartbeat_send(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode, state)
        psi = self._sample("attitude", "psi")
        if "attitude" in due and psi is not None:
            r = self._sample("attitude", "r")
            out.attitude_send(boot_ms, 0.0, 0.0, psi, 0.0, 0.0, 0.0 if r is None else r)
        depth = self._sample("pressure", "z")
        if "pressure" in due and depth is not None:
            w = self.sim.prep.truth
            p = pressure_hpa(depth, water_density=w.water_density, gravity=w.gravity,
                             surface_hpa=self.params["BARO2_GND_PRESS"] / 100.0)
            out.scaled_pressure2_send(boot_ms, p, p - self.params["BARO2_GND_PRESS"] / 100.0, cdeg_c(15.0))
        if "vfr_hud" in due:
            throttle = int(round(50.0 + 50.0 * self.inputs[2]))
            out.vfr_hud_send(0.0, math.hypot(x["u"], x["v"]), heading_deg(x["psi"] if psi is None else psi), throttle,
                             -x["z"], -x["w"])
        if "sys_status" in due:
            present, enabled, health = self._sensor_bits(imu=psi is not None, depth=depth is not None)
            out.sys_status_send(present, enabled, health, 100, 16000, -1, -1, 0, 0, 0, 0, 0, 0)
        if "named_float" in due:
            out.named_value_float_send(boot_ms, b"PilotGain", self.gain)
        if "servo" in due:
            pwm = [int(round(p)) for p in self.sim.pwm] + [0] * (16 - self.sim.pwm.size)
            out.servo_output_raw_send(int((now - (self._t0 or now)) * 1e6) & 0xFFFFFFFF, 0, *pwm)
        if "local_position" in due and self.local_position:
            c, s = math.cos(x["psi"]), math.sin(x["psi"])
            vn = c * x["u"] - s * x["v"]
            ve = s * x["u"] + c * x["v"]
            out.local_position_ned_send(boot_ms, x["x"], x["y"], x["z"], vn, ve, x["w"])


    def _sensor_bits(self, *, imu: bool, depth: bool) -> tuple[int, int, int]:
        """SYS_STATUS present, enabled and health bits as ArduSub sets them (a BlueROV2 Heavy on
        ArduSub 4.1 in MANUAL, ../shared/data/ardusub/small.tlog, without its GPS): subsystems that
        are absent or off, such as the fence, count as healthy, so a ground station sees no fault;
        depth and position control are enabled only in the modes that use them (none is simulated).
        The pressure sensor is present when the vehicle has one and healthy while it reports; the
        IMU and AHRS are healthy while the IMU reports."""
        mav = self.mav
        present = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | mav.MAV_SYS_STATUS_SENSOR_3D_MAG | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
                   | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mav.MAV_SYS_STATUS_SENSOR_YAW_POSITION
                   | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
                   | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_GEOFENCE | mav.MAV_SYS_STATUS_AHRS
                   | mav.MAV_SYS_STATUS_LOGGING | mav.MAV_SYS_STATUS_SENSOR_BATTERY | mav.MAV_SYS_STATUS_PREARM_CHECK)
        if any(s.kind == "pressure" for s in self.vehicle.sensors):
            present |= mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        off = (mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
               | mav.MAV_SYS_STATUS_GEOFENCE | mav.MAV_SYS_STATUS_LOGGING)
        enabled = present & ~off
        health = present & ~(mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL)
        if not depth:
            health &= ~mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        if not imu:
            health &= ~(mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav.MAV_SYS_STATUS_AHRS)
        return present, enabled, health


def _silence(sim: SimulatedVehicle, kind: str) -> float:
    """How long after its last sample a sensor of this kind counts as silent [s]: two of its sample
    periods and one control period (at least 0.25 s)."""
    rates = [s.rate_hz for s in sim.prep.truth.sensors if s.kind == kind and s.rate_hz]
    return max(2.0 / max(rates) if rates else 0.0, 0.25) + sim.h


def _param_name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0].strip()


_HANDLERS: dict[str, Callable[[ArduSubSim, Any, float], None]] = {
    "MANUAL_CONTROL": ArduSubSim._on_manual_control,
    "RC_CHANNELS_OVERRIDE": ArduSubSim._on_rc_override,
    "COMMAND_LONG": ArduSubSim._on_command_long,
    "SET_MODE": ArduSubSim._on_set_mode,
    "PARAM_REQUEST_LIST": ArduSubSim._on_param_request_list,
    "PARAM_REQUEST_READ": ArduSubSim._on_param_request_read,
    "PARAM_SET": ArduSubSim._on_param_set,
    "MISSION_REQUEST_LIST": ArduSubSim._on_mission_request_list,
    "REQUEST_DATA_STREAM": ArduSubSim._on_request_data_stream,
    "FILE_TRANSFER_PROTOCOL": ArduSubSim._on_file_transfer,
}

# MAVLink FTP (FILE_TRANSFER_PROTOCOL.payload): header seq, session, opcode, size, req_opcode,
# burst_complete, padding, offset; the opcodes and errors the simulator answers with
_FTP_HEADER = struct.Struct("<HBBBBBBI")
_FTP_TERMINATE_SESSION, _FTP_RESET_SESSIONS = 1, 2
_FTP_FILE_OPS = (3, 4, 14)  # ListDirectory, OpenFileRO, CalcFileCRC32
_FTP_ACK, _FTP_NAK = 128, 129
_FTP_ERR_FAIL, _FTP_ERR_FILE_NOT_FOUND = 1, 10

# telemetry stream -> the MAVLink message it sends
_STREAM_MESSAGE = {"heartbeat": "HEARTBEAT", "attitude": "ATTITUDE", "pressure": "SCALED_PRESSURE2",
                   "sys_status": "SYS_STATUS", "named_float": "NAMED_VALUE_FLOAT", "servo": "SERVO_OUTPUT_RAW",
                   "vfr_hud": "VFR_HUD", "local_position": "LOCAL_POSITION_NED"}
# MAVLink message id -> telemetry stream (for MAV_CMD_SET_MESSAGE_INTERVAL)
_STREAM_KEYS = {0: "heartbeat", 30: "attitude", 137: "pressure", 1: "sys_status", 251: "named_float", 36: "servo",
                74: "vfr_hud", 32: "local_position"}
