"""MAVLink units <-> SI, in one place (docs/conventions.md: SI inside, other units only at the edge).

* Pressure: SCALED_PRESSURE* carry press_abs in hPa (1 hPa = 100 Pa) and temperature in cdegC.
  Depth of the sensor z = (p_abs - p_surface) / (rho g), positive down.
* Angles: ATTITUDE is already in rad and rad/s; VFR_HUD.heading is whole degrees 0..359.
* Joystick: MANUAL_CONTROL x, y, r in -1000..1000 and z in 0..1000 (500 = neutral). ArduSub turns
  them into RC channel pulses with its live pilot gain (JS_GAIN_DEFAULT at boot, then as the gain
  buttons set it; reported as NAMED_VALUE_FLOAT "PilotGain") and throttle gain
  (JS_THR_GAIN): 1500 + 0.4 gain x for forward, lateral and yaw, 1500 + 0.8 gain thr_gain (z - 500)
  for throttle, each clipped to 1100..1900, and reads a channel as (pulse - 1500) / 400 in [-1, 1]
  (ArduPilot ArduSub/joystick.cpp, transform_manual_control_to_rc_override). So a normalised
  pilot input is u = gain x / 1000 (x, y, r) and u = gain thr_gain (z - 500) / 500 (z).
* RC overrides: ArduSub's channel map is 1 pitch, 2 roll, 3 throttle, 4 yaw, 5 forward,
  6 lateral; a pulse p in us reads as (p - 1500) / 400.
* Battery: SYS_STATUS voltage in mV, current in cA.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

STANDARD_ATMOSPHERE_HPA = 1013.25
PA_PER_HPA = 100.0

# ArduSub's RC input map (1-based channel numbers) for the four axes rovlab commands
RC_CHANNEL = {"throttle": 3, "yaw": 4, "forward": 5, "lateral": 6}
RC_NEUTRAL_US = 1500.0
RC_HALF_RANGE_US = 400.0


def pressure_hpa(depth_m: float, *, water_density: float, gravity: float,
                 surface_hpa: float = STANDARD_ATMOSPHERE_HPA) -> float:
    """Absolute pressure [hPa] at a sensor depth [m]; at or above the surface the air's pressure."""
    return surface_hpa + max(depth_m, 0.0) * water_density * gravity / PA_PER_HPA


def depth_from_pressure(press_abs_hpa: float, *, water_density: float, gravity: float,
                        surface_hpa: float = STANDARD_ATMOSPHERE_HPA) -> float:
    """Sensor depth [m] (positive down) from absolute pressure [hPa]; NaN for a non-finite or
    non-positive reading."""
    if not (math.isfinite(press_abs_hpa) and press_abs_hpa > 0.0):
        return math.nan
    return (press_abs_hpa - surface_hpa) * PA_PER_HPA / (water_density * gravity)


def cdeg_c(temperature_c: float) -> int:
    """Temperature in centidegrees Celsius (int16 of SCALED_PRESSURE*)."""
    return int(round(temperature_c * 100.0))


def heading_deg(psi_rad: float) -> int:
    """VFR_HUD heading: whole degrees 0..359 from a heading in rad."""
    return int(round(math.degrees(psi_rad))) % 360


def inputs_from_manual_control(x: float, y: float, z: float, r: float, *, gain: float,
                               throttle_gain: float = 1.0) -> np.ndarray:
    """Normalised pilot inputs [forward, lateral, throttle, yaw] in [-1, 1] that ArduSub makes of a
    MANUAL_CONTROL (x, y, r in -1000..1000, z in 0..1000 with 500 neutral)."""
    u = np.array([gain * x / 1000.0, gain * y / 1000.0, gain * throttle_gain * (z - 500.0) / 500.0,
                  gain * r / 1000.0])
    return np.clip(u, -1.0, 1.0)


def manual_control_from_inputs(inputs: np.ndarray, *, gain: float, throttle_gain: float = 1.0
                               ) -> tuple[int, int, int, int]:
    """The MANUAL_CONTROL (x, y, z, r) that ArduSub reads as the normalised inputs
    [forward, lateral, throttle, yaw] (the inverse of inputs_from_manual_control), saturated to the
    message's ranges: with a gain below 1 the vehicle cannot be given full thrust this way."""
    u = np.asarray(inputs, dtype=float)
    if u.shape != (4,) or not np.all(np.isfinite(u)):
        raise ValueError(f"expected 4 finite inputs [forward, lateral, throttle, yaw], got {u!r}")
    if not (gain > 0.0 and throttle_gain > 0.0):
        raise ValueError(f"joystick gains must be positive, got gain={gain!r}, throttle_gain={throttle_gain!r}")
    x = int(round(np.clip(u[0] * 1000.0 / gain, -1000, 1000)))
    y = int(round(np.clip(u[1] * 1000.0 / gain, -1000, 1000)))
    z = int(round(np.clip(500.0 + u[2] * 500.0 / (gain * throttle_gain), 0, 1000)))
    r = int(round(np.clip(u[3] * 1000.0 / gain, -1000, 1000)))
    return x, y, z, r


def input_from_rc_pulse(pulse_us: float) -> float:
    """A pilot input in [-1, 1] from an RC pulse [us] (ArduSub's reading of a channel)."""
    return float(np.clip((pulse_us - RC_NEUTRAL_US) / RC_HALF_RANGE_US, -1.0, 1.0))


def rc_pulse_from_input(u: float) -> int:
    return int(round(RC_NEUTRAL_US + RC_HALF_RANGE_US * float(np.clip(u, -1.0, 1.0))))


def drain(conn: Any, handle: Callable[[Any], None], counts: dict[str, int],
          warn_once: Callable[[str, str], None], limit: int = 1000) -> None:
    """Read what arrived on a pymavlink connection and hand each message to ``handle``, at most
    ``limit`` per call (a flood cannot starve the caller's loop). A broken packet or a handler
    tripping on odd values is counted in ``counts["errors"]`` and reported once per kind; the
    caller keeps running."""
    for _ in range(limit):
        try:
            msg = conn.recv_msg()
        except Exception as exc:  # noqa: BLE001 - a broken packet must not stop the endpoint
            counts["errors"] += 1
            warn_once("recv", f"receive error: {exc}")
            return
        if msg is None:
            return
        try:
            handle(msg)
        except Exception as exc:  # noqa: BLE001 - nor a message with odd values
            counts["errors"] += 1
            warn_once(f"handle-{msg.get_type()}", f"could not handle {msg.get_type()}: {exc}")
