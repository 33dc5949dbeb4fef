"""What rovlab needs to know about ArduSub: its flight modes and the parameters that matter to a
companion computer, with their documented ranges (ArduSub parameter list,
ardupilot.org/sub/docs/parameters.html). Plain data; no pymavlink.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# ArduSub flight modes (HEARTBEAT.custom_mode; ArduSub/mode.h, Mode::Number)
MODES = {"STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "CIRCLE": 7, "SURFACE": 9,
         "POSHOLD": 16, "MANUAL": 19, "MOTOR_DETECT": 20}
MODE_NAMES = {v: k for k, v in MODES.items()}

# FS_PILOT_INPUT actions
FS_PILOT_DISABLED, FS_PILOT_WARN, FS_PILOT_DISARM = 0, 1, 2

# MAV_PARAM_TYPE
PARAM_INT32 = 6
PARAM_REAL32 = 9


@dataclass(frozen=True)
class ParamSpec:
    name: str  # at most 16 characters (PARAM_VALUE.param_id)
    default: float
    low: float
    high: float
    integer: bool = False
    read_only: bool = False
    doc: str = ""

    @property
    def mav_type(self) -> int:
        return PARAM_INT32 if self.integer else PARAM_REAL32


# The parameters the simulated vehicle has, in PARAM_VALUE index order. Ranges as ArduSub documents them.
SIM_PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("SYSID_THISMAV", 1, 1, 255, integer=True, doc="MAVLink system id of the vehicle"),
    ParamSpec("SYSID_MYGCS", 255, 1, 255, integer=True,
              doc="system id whose MANUAL_CONTROL and RC overrides the vehicle obeys"),
    ParamSpec("FS_PILOT_INPUT", 1, 0, 2, integer=True,
              doc="pilot input failsafe: 0 disabled, 1 warn (and neutral inputs), 2 disarm"),
    ParamSpec("FS_PILOT_TIMEOUT", 3.0, 0.1, 10.0, doc="pilot input failsafe timeout [s] (older ArduSub: up to 3)"),
    ParamSpec("JS_GAIN_DEFAULT", 0.5, 0.1, 1.0, doc="joystick gain at start-up"),
    ParamSpec("JS_THR_GAIN", 1.0, 0.5, 4.0, doc="extra gain on the throttle (heave) input"),
    ParamSpec("BARO_SPEC_GRAV", 1.0, 0.98, 1.05, doc="specific gravity of the water for depth (1.0 fresh, 1.024 sea)"),
    ParamSpec("BARO2_GND_PRESS", 101325.0, 0.0, 200000.0, read_only=True,
              doc="surface pressure of the external (Bar30) sensor [Pa]"),
    ParamSpec("MOT_PWM_MIN", 1100, 0, 2000, integer=True, read_only=True, doc="thruster PWM minimum [us]"),
    ParamSpec("MOT_PWM_MAX", 1900, 0, 2000, integer=True, read_only=True, doc="thruster PWM maximum [us]"),
    ParamSpec("FRAME_CONFIG", 1, 0, 7, integer=True, read_only=True,
              doc="frame: 1 vectored (BlueROV2), 2 vectored 6DOF (Heavy), 7 custom"),
)


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
