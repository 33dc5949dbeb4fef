"""The MAVLink bridge as the HMI's source (rovlab.interfaces.hmi.source.Source): the HMI shows and
tunes an ArduSub vehicle the way it shows a simulation (``rovlab hmi --source mavlink``).

The bridge runs on its own thread and clock (``paced = False``); :meth:`MavlinkSource.advance`
returns the messages its node core produced since the last call. There is no truth and no
schedule: ``follow_schedule`` hands the vehicle back to the pilot (the controller disengages).
"""

from __future__ import annotations

import threading
from typing import Any

from rovlab.interfaces.mavlink.bridge import MavlinkBridge
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle


class MavlinkSource:
    kind = "vehicle"
    paced = False

    def __init__(self, bridge: MavlinkBridge, *, start: bool = True) -> None:
        self.bridge = bridge
        self._thread = threading.Thread(target=bridge.run, name="rovlab-mavlink-bridge", daemon=True)
        if start:
            self._thread.start()

    def close(self, timeout: float = 5.0) -> None:
        """Stop the bridge (neutral commands, disarm what it armed, close the recording)."""
        self.bridge.stop()
        if self._thread.is_alive():
            self._thread.join(timeout)

    @property
    def h(self) -> float:
        return self.bridge.core.h

    @property
    def time(self) -> float:
        return self.bridge.core.time

    def describe(self) -> dict[str, Any]:
        core = self.bridge.core
        return {
            "kind": self.kind,
            "scenario": {"name": f"MAVLink vehicle on {self.bridge.connect}", "plant": "vehicle",
                         "description": "an ArduSub vehicle through rovlab mavlink bridge", "seed": None, "file": None},
            "vehicle": core.vehicle.name,
            "config": core.config.name,
            "h": self.h,
            "has_truth": False,
            "states": list(core.states),
            "channels": [{"name": c.name, "column": c.column, "sensor": c.sensor, "quantity": c.quantity,
                          "offset": c.offset} for c in core.channels],
            "sensors": list(core.sensor_enabled),
            "thrusters": list(core.thrusters),
            "controller": core.controller_name,
            "controller_states": list(core.design.controller.state_names),
        }

    def status(self) -> dict[str, Any]:
        core, br = self.bridge.core, self.bridge
        return {
            "time_s": core.time,
            "reference": {"z": float(core.reference[2]), "psi": float(core.reference[3]), "x": float(core.reference[0]),
                          "y": float(core.reference[1]), "schedule": False},  # x, y: held with a DP configuration
            "engaged": bool(br.engaged),  # a set-point is wanted (held while the vehicle obeys: vehicle.holding)
            "sensors": dict(core.sensor_enabled),
            "filter_modes": core.filter_modes(),
            "vehicle": {"seen": br.vehicle_seen, "armed": br.armed, "mode": br.mode, "failsafe": br.failsafe,
                        "holding": bool(core.engaged), "hold_blocked": br.hold_blocked, "depth_problem": br.depth_problem,
                        "pilot_gain": br.pilot_gain(), "parameter_names": br.firmware_names,
                        "rates_hz": dict(br.rates), "rates_short": sorted(br.rate_short)},
        }

    def advance(self, n: int) -> list[tuple[str, float, dict[str, Any]]]:
        return self.bridge.drain()

    def reset(self) -> None:
        raise ValueError("a real vehicle cannot be reset from the HMI")

    def set_reference(self, z: float | None = None, psi: float | None = None, *, x: float | None = None,
                      y: float | None = None) -> None:
        self.bridge.set_reference(z=z, psi=psi, x=x, y=y)  # north/east: DP configurations only (ValueError)

    def follow_schedule(self) -> None:
        """No schedule on a vehicle: stop commanding and leave it to the pilot."""
        self.bridge.disengage()

    def set_sensor_available(self, sensor: str, available: bool) -> None:
        self.bridge.core.set_sensor_enabled(sensor, available)

    def set_filter_mode(self, channel: str, mode: str) -> None:
        self.bridge.core.set_filter_mode(channel, mode)

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        if truth is not None:
            raise ValueError("a real vehicle has no plant truth to change")
        self.bridge.core.apply(vehicle=vehicle, config=config)

    def loop_summary(self) -> dict[str, Any]:
        from rovlab.interfaces.hmi.source import design_summary

        core, br = self.bridge.core, self.bridge
        out = design_summary(core.design, truth=core.vehicle, controller=core.controller_name)
        out["bridge"] = {"connect": br.connect, "command": br.command, "command_hz": 1.0 / br.command_period,
                         "telemetry_timeout_s": br.telemetry_timeout_s, **br.counts}
        return out
