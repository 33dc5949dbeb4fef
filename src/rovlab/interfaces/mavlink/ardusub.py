"""What rovlab needs to know about ArduSub: its flight modes, the parameters that matter to a
companion computer with their documented ranges and MAVLink types (ArduSub parameter list,
ardupilot.org/sub/docs/parameters.html; types and defaults as a BlueROV2 Heavy on ArduSub 4.1
reports them in ../shared/data/ardusub/small.tlog), the two generations of parameter names, and
which telemetry stream group carries which message. Plain data; no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

# ArduSub flight modes (HEARTBEAT.custom_mode; ArduSub/mode.h, Mode::Number)
MODES = {"STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "CIRCLE": 7, "SURFACE": 9,
         "POSHOLD": 16, "MANUAL": 19, "MOTOR_DETECT": 20}
MODE_NAMES = {v: k for k, v in MODES.items()}

# FS_PILOT_INPUT actions
FS_PILOT_DISABLED, FS_PILOT_WARN, FS_PILOT_DISARM = 0, 1, 2

# MAV_PARAM_TYPE of ArduPilot's AP_Int8, AP_Int16, AP_Int32 and AP_Float
PARAM_INT8 = 2
PARAM_INT16 = 4
PARAM_INT32 = 6
PARAM_REAL32 = 9

# Parameter generations. ArduPilot 4.7 moved the MAVLink system ids into the GCS library:
# SYSID_THISMAV -> MAV_SYSID, SYSID_MYGCS -> MAV_GCS_SYSID (plus MAV_GCS_SYSID_HI: with a value >=
# MAV_GCS_SYSID every system id from MAV_GCS_SYSID to it counts as the ground station). A vehicle
# has one generation or the other, never both.
FIRMWARES = ("4.1", "4.7")
DEFAULT_FIRMWARE = "4.7"
THIS_MAV = {"4.1": "SYSID_THISMAV", "4.7": "MAV_SYSID"}
MY_GCS = {"4.1": "SYSID_MYGCS", "4.7": "MAV_GCS_SYSID"}
MY_GCS_HIGH = "MAV_GCS_SYSID_HI"  # 4.7 only

# MAV_DATA_STREAM group (REQUEST_DATA_STREAM.req_stream_id, the SRn_* rate parameters) that carries
# each message a BlueROV2 companion cares about, as ArduSub groups them (GCS_Mavlink stream tables):
# a REQUEST_DATA_STREAM for a group sets the rate of every message in it, overwriting what
# MAV_CMD_SET_MESSAGE_INTERVAL set; MAV_DATA_STREAM_ALL (0) sets every group.
DATA_STREAM_NAMES = {1: "RAW_SENSORS", 2: "EXTENDED_STATUS", 3: "RC_CHANNELS", 4: "RAW_CONTROLLER",
                     6: "POSITION", 10: "EXTRA1", 11: "EXTRA2", 12: "EXTRA3"}
STREAM_OF_MESSAGE = {"SCALED_PRESSURE": 1, "SCALED_PRESSURE2": 1, "SYS_STATUS": 2, "NAMED_VALUE_FLOAT": 2,
                     "SERVO_OUTPUT_RAW": 3, "RC_CHANNELS": 3, "GLOBAL_POSITION_INT": 6, "LOCAL_POSITION_NED": 6,
                     "ATTITUDE": 10, "VFR_HUD": 11, "SYSTEM_TIME": 12, "BATTERY_STATUS": 12}

# ArduSub's default joystick buttons (MANUAL_CONTROL.buttons bit i = button i; ArduSub joystick.cpp,
# default_js_buttons): the ones that change the pilot gain, without the shift button (5) held
BUTTON_SHIFT, BUTTON_GAIN_INC, BUTTON_GAIN_DEC = 5, 11, 12


@dataclass(frozen=True)
class ParamSpec:
    name: str  # at most 16 characters (PARAM_VALUE.param_id)
    default: float
    low: float
    high: float
    mav_type: int = PARAM_REAL32
    read_only: bool = False
    doc: str = ""

    @property
    def integer(self) -> bool:
        return self.mav_type != PARAM_REAL32


def sim_parameters(firmware: str = DEFAULT_FIRMWARE) -> tuple[ParamSpec, ...]:
    """The parameters the simulated vehicle has, in PARAM_VALUE index order, for one generation of
    names ("4.1" or "4.7"). Defaults, ranges and types as ArduSub documents and reports them."""
    if firmware not in FIRMWARES:
        raise ValueError(f"firmware must be one of {', '.join(FIRMWARES)}, got {firmware!r}")
    ids: tuple[ParamSpec, ...] = (
        ParamSpec(THIS_MAV[firmware], 1, 1, 255, PARAM_INT16, doc="MAVLink system id of the vehicle"),
        ParamSpec(MY_GCS[firmware], 255, 1, 255, PARAM_INT16,
                  doc="system id whose MANUAL_CONTROL and RC overrides the vehicle obeys"),
    )
    if firmware == "4.7":
        ids += (ParamSpec(MY_GCS_HIGH, 0, 0, 255, PARAM_INT16,
                          doc=f"with a value >= {MY_GCS[firmware]}: the highest system id also obeyed"),)
    return ids + (
        ParamSpec("FS_PILOT_INPUT", FS_PILOT_DISARM, 0, 2, PARAM_INT8,
                  doc="pilot input failsafe: 0 disabled, 1 warn (and neutral inputs), 2 disarm"),
        ParamSpec("FS_PILOT_TIMEOUT", 3.0, 0.1, 3.0, doc="pilot input failsafe timeout [s]"),
        ParamSpec("JS_GAIN_DEFAULT", 0.5, 0.1, 1.0, doc="pilot gain at boot (the live gain: NAMED_VALUE_FLOAT PilotGain)"),
        ParamSpec("JS_GAIN_MAX", 1.0, 0.2, 1.0, doc="largest pilot gain the gain buttons reach"),
        ParamSpec("JS_GAIN_MIN", 0.25, 0.1, 0.8, doc="smallest pilot gain the gain buttons reach"),
        ParamSpec("JS_GAIN_STEPS", 4, 1, 10, PARAM_INT8, doc="pilot gain steps between JS_GAIN_MIN and JS_GAIN_MAX"),
        ParamSpec("JS_THR_GAIN", 1.0, 0.5, 4.0, doc="extra gain on the throttle (heave) input"),
        ParamSpec("BARO_SPEC_GRAV", 1.0, 0.98, 1.05, doc="specific gravity of the water for depth (1.0 fresh, 1.024 sea)"),
        ParamSpec("BARO2_GND_PRESS", 101325.0, 0.0, 200000.0, read_only=True,
                  doc="surface pressure of the external (Bar30) sensor [Pa]"),
        ParamSpec("MOT_PWM_MIN", 1100, 0, 2000, PARAM_INT16, read_only=True, doc="thruster PWM minimum [us]"),
        ParamSpec("MOT_PWM_MAX", 1900, 0, 2000, PARAM_INT16, read_only=True, doc="thruster PWM maximum [us]"),
        ParamSpec("FRAME_CONFIG", 1, 0, 7, PARAM_INT8, read_only=True,
                  doc="frame: 1 vectored (BlueROV2), 2 vectored 6DOF (Heavy), 7 custom"),
    )


SIM_PARAMETERS: tuple[ParamSpec, ...] = sim_parameters()


def boot_gain(gain_default: float, gain_min: float, gain_max: float, steps: int) -> float:
    """The pilot gain ArduSub starts with (joystick.cpp, init_joystick): JS_GAIN_DEFAULT when it lies
    within JS_GAIN_MIN .. JS_GAIN_MAX (or there is one step), else the step nearest the middle;
    always within 0.1 .. 1."""
    if steps <= 1 or gain_min - 0.01 < gain_default < gain_max + 0.01:
        gain = min(max(gain_default, gain_min), gain_max)
    else:
        gain = gain_min + (steps // 2 - 1) * (gain_max - gain_min) / (steps - 1)
    return min(max(gain, 0.1), 1.0)


def stepped_gain(gain: float, up: bool, *, gain_default: float, gain_min: float, gain_max: float,
                 steps: int) -> float:
    """The pilot gain after one press of the gain-up or gain-down button (joystick.cpp): one of
    JS_GAIN_STEPS steps between JS_GAIN_MIN and JS_GAIN_MAX, or JS_GAIN_DEFAULT with one step."""
    gain_min = min(max(gain_min, 0.1), 0.8)
    gain_max = min(max(gain_max, gain_min), 1.0)
    steps = min(max(int(steps), 1), 10)
    if steps == 1:
        return min(max(gain_default, gain_min), gain_max)
    delta = (gain_max - gain_min) / (steps - 1)
    return min(max(gain + (delta if up else -delta), gain_min), gain_max)


def motor_directions(vehicle: Any, frame: int) -> tuple[ParamSpec, ...]:
    """MOT_n_DIRECTION of a simulated vehicle: what its vehicle file implies for the frame
    (rovlab.interfaces.mavlink.autopilot), so a bridge that checks them finds them in agreement;
    none for a frame whose mixing rovlab does not know. Read-only: the simulated thrusters push as
    the vehicle file says."""
    from rovlab.interfaces.mavlink.autopilot import FRAMES, implied_directions

    if frame not in FRAMES or len(FRAMES[frame][1]) != len(vehicle.thrusters):
        return ()
    dirs = implied_directions(vehicle, frame).directions
    return tuple(ParamSpec(f"MOT_{k + 1}_DIRECTION", d if d else 1, -1, 1, PARAM_INT8, read_only=True,
                           doc=f"motor {k + 1} reversed (-1) or not (1), as the vehicle file implies")
                 for k, d in enumerate(dirs))


class Parameters:
    """A vehicle's parameter table: values by name, in a fixed index order."""

    def __init__(self, specs: tuple[ParamSpec, ...] = SIM_PARAMETERS, **values: float) -> None:
        self.specs = specs
        self._by_name = {s.name: s for s in specs}
        self.values = {s.name: float(s.default) for s in specs}
        for name, v in values.items():  # initial values (read-only ones included)
            if name not in self._by_name:
                raise KeyError(f"unknown parameter {name!r}")
            self.values[name] = float(v)

    def __len__(self) -> int:
        return len(self.specs)

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def index(self, name: str) -> int:
        return next(i for i, s in enumerate(self.specs) if s.name == name)

    def spec(self, name: str) -> ParamSpec | None:
        return self._by_name.get(name)

    def set(self, name: str, value: float) -> str | None:
        """Set a parameter; returns None when done, else why it was refused (nothing changes)."""
        spec = self._by_name.get(name)
        if spec is None:
            return f"unknown parameter {name!r}"
        if spec.read_only:
            return f"{name} is read-only"
        try:
            v = float(value)
        except (TypeError, ValueError):
            return f"{name}: not a number: {value!r}"
        if not math.isfinite(v):
            return f"{name}: value must be finite, got {v!r}"
        if spec.integer:
            v = float(round(v))
        if not spec.low <= v <= spec.high:
            return f"{name}: {v:g} is outside {spec.low:g} .. {spec.high:g}"
        self.values[name] = v
        return None
