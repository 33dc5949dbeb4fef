"""The joystick gains the vehicle reports, checked against ArduSub's own ranges (issue 28, fuzzing
campaign: the bridge took any gain). ArduSub/Parameters.cpp: JS_GAIN_DEFAULT 0.1 .. 1.0,
JS_GAIN_MIN 0.1 .. 0.8, JS_GAIN_MAX 0.2 .. 1.0, JS_THR_GAIN 0.5 .. 4.0; ArduSub/joystick.cpp
constrains the gain it applies (the one it reports as NAMED_VALUE_FLOAT "PilotGain") to 0.1 .. 1.0
and uses JS_THR_GAIN as it is (throttleScale = 0.8 gain JS_THR_GAIN). So a PilotGain outside
0.1 .. 1.0 is not a gain ArduSub applies (ignored), a JS_GAIN_DEFAULT outside it is clamped as
ArduSub clamps it, and a JS_THR_GAIN outside its range -- one the bridge cannot scale MANUAL_CONTROL
to without guessing -- makes the bridge send neutral inputs, saying why, until it is back in range.
Before: PilotGain 0.01 was taken (every input scaled 100 times up), JS_THR_GAIN -1 raised
ValueError in the command loop."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port  # noqa: E402


class _Link:
    """Stands in for the pymavlink connection: records MANUAL_CONTROL."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, int, int, int]] = []
        self.mav = self

    def manual_control_send(self, target, x, y, z, r, buttons) -> None:
        self.sent.append((x, y, z, r))


@pytest.fixture
def bridge():
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    lines: list[str] = []
    b = MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                      connect=f"udpin:127.0.0.1:{free_udp_port()}", log=lines.append)
    real, b.conn = b.conn, _Link()
    b.lines = lines
    yield b
    real.close()


def _param(name: str, value: float) -> SimpleNamespace:
    return SimpleNamespace(param_id=name, param_value=value)


def _gain(value: float) -> SimpleNamespace:
    return SimpleNamespace(name=b"PilotGain", value=value)


UP = np.array([0.0, 0.0, 0.2, 0.0])  # a fifth of full throttle


@pytest.mark.parametrize("value", [40.0, 0.2, -1.0, 0.0, 1e30])
def test_a_throttle_gain_outside_ardusubs_range_stops_manual_control_with_the_reason(bridge, value):
    bridge._on_param(_param("JS_THR_GAIN", value))
    bridge._send_inputs(UP, 1.0, neutral=False)  # before: ValueError for -1, an exact guess for 40
    assert bridge.conn.sent[-1] == (0, 0, 500, 0)  # neutral: 1500 us whatever the gains
    said = [line for line in bridge.lines if "JS_THR_GAIN" in line]
    assert len(said) == 1 and f"JS_THR_GAIN = {value!r}" in said[0] and "0.5 .. 4" in said[0], bridge.lines
    assert "neutral" in said[0]
    bridge._on_param(_param("JS_THR_GAIN", 2.0))  # back in range: commands again, scaled to it
    bridge._send_inputs(UP, 1.1, neutral=False)
    x, y, z, r = bridge.conn.sent[-1]
    assert z == round(500 + 0.2 * 500 / (0.5 * 2.0)) and bridge.sent_gains == (0.5, 2.0)
    assert any("JS_THR_GAIN" in line and "back" in line for line in bridge.lines), bridge.lines


@pytest.mark.parametrize("value", [0.01, 0.0999, 1.5, -0.5])
def test_a_pilot_gain_ardusub_cannot_apply_is_ignored(bridge, value):
    bridge._on_named_float(_gain(0.8))
    bridge._on_named_float(_gain(value))
    assert bridge.pilot_gain() == 0.8
    assert any(f"PilotGain {value!r}" in line and "0.1 .. 1" in line for line in bridge.lines), bridge.lines


@pytest.mark.parametrize("value,applied", [(5.0, 1.0), (0.01, 0.1), (0.3, 0.3)])
def test_the_boot_gain_is_clamped_as_ardusub_clamps_it(bridge, value, applied):
    bridge._on_param(_param("JS_GAIN_DEFAULT", value))
    assert bridge.pilot_gain() == applied
    bridge._send_inputs(UP, 1.0, neutral=False)
    assert bridge.conn.sent[-1][2] == min(1000, round(500 + 0.2 * 500 / applied))
