"""`rovlab mavlink sim` seen by an independent pymavlink ground station (tests/mavlink/mavclient.py):
connect, list and set parameters, arm, fly with MANUAL_CONTROL and watch the depth change in
SCALED_PRESSURE2, survive garbage. All on 127.0.0.1 with a free port; every wait is bounded."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import GroundStation, free_udp_port, start_rovlab, stop  # noqa: E402

RHO, G = 1000.0, 9.82  # bluerov2_heavy.toml
SURFACE_HPA = 1013.25
START_TIMEOUT = 90.0  # first run compiles the plant kernels


def depth_of(msg) -> float:
    return (msg.press_abs - SURFACE_HPA) * 100.0 / (RHO * G)


@pytest.fixture(scope="module")
def vehicle():
    port = free_udp_port()
    gcs = GroundStation(port)
    proc = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "3",
                        "--duration", "300")
    try:
        gcs.wait_for(lambda: "HEARTBEAT" in gcs.latest or proc.poll() is not None, START_TIMEOUT,
                     what="first HEARTBEAT")
        assert proc.poll() is None, stop(proc)
        yield gcs, proc
    finally:
        gcs.close()
        out = stop(proc)
        print(out)


def param_set(gcs: GroundStation, name: str, value: float) -> None:
    gcs.conn.mav.param_set_send(1, 1, name.encode(), value, 9)


def test_heartbeat_is_an_ardusub_submarine(vehicle):
    gcs, _ = vehicle
    hb = gcs.latest["HEARTBEAT"]
    assert hb.type == 12  # MAV_TYPE_SUBMARINE
    assert hb.autopilot == 3  # MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == 19  # MANUAL
    gcs.wait_for(lambda: {"ATTITUDE", "SCALED_PRESSURE2", "SYS_STATUS", "SERVO_OUTPUT_RAW"} <= set(gcs.latest),
                 10.0, what="telemetry")
    assert depth_of(gcs.latest["SCALED_PRESSURE2"]) == pytest.approx(3.0, abs=0.3)
    assert all(1100 <= getattr(gcs.latest["SERVO_OUTPUT_RAW"], f"servo{i}_raw") <= 1900 for i in range(1, 9))


def test_parameter_list_and_set(vehicle):
    gcs, proc = vehicle
    gcs.seen.clear()
    gcs.conn.mav.param_request_list_send(1, 1)
    gcs.wait_for(lambda: gcs.messages("PARAM_VALUE") and len({m.param_id for m in gcs.messages("PARAM_VALUE")})
                 == gcs.messages("PARAM_VALUE")[0].param_count, 10.0, what="all parameters")
    values = {m.param_id: m for m in gcs.messages("PARAM_VALUE")}
    assert values["MAV_GCS_SYSID"].param_value == 255 and "SYSID_MYGCS" not in values  # ArduSub 4.7 names
    assert values["FS_PILOT_INPUT"].param_value == 2 and values["FS_PILOT_INPUT"].param_type == 2  # INT8, as ArduSub
    assert values["JS_GAIN_DEFAULT"].param_type == 9 and values["MOT_PWM_MIN"].param_type == 4  # REAL32, INT16
    assert values["JS_GAIN_DEFAULT"].param_count == len(values)
    assert sorted(m.param_index for m in values.values()) == list(range(len(values)))

    gcs.seen.clear()
    param_set(gcs, "JS_GAIN_DEFAULT", 1.0)
    gcs.wait_for(lambda: any(m.param_id == "JS_GAIN_DEFAULT" and m.param_value == 1.0
                             for m in gcs.messages("PARAM_VALUE")), 5.0, what="PARAM_VALUE after PARAM_SET")
    # refused: out of range, NaN, read-only, unknown -> a STATUSTEXT, the value unchanged, still running
    gcs.seen.clear()
    for name, value in (("JS_GAIN_DEFAULT", 9.0), ("JS_GAIN_DEFAULT", math.nan), ("MOT_PWM_MIN", 900.0),
                        ("NO_SUCH_PARAM", 1.0)):
        param_set(gcs, name, value)
    gcs.wait_for(lambda: len(gcs.messages("STATUSTEXT")) >= 4, 5.0, what="refusals")
    assert all(m.param_value == 1.0 for m in gcs.messages("PARAM_VALUE") if m.param_id == "JS_GAIN_DEFAULT")
    assert any("outside" in m.text for m in gcs.messages("STATUSTEXT"))
    assert proc.poll() is None


def test_garbage_and_strangers_do_not_move_it(vehicle):
    gcs, proc = vehicle
    gcs.conn.write(b"\xfd\x09\x00\x00\x00garbage that is not MAVLink" * 20)
    # MANUAL_CONTROL from a system other than SYSID_MYGCS is ignored (ArduSub does the same)
    gcs.conn.mav.srcSystem = 42
    try:
        for _ in range(5):
            gcs.conn.mav.manual_control_send(1, 1000, 0, 1000, 0, 0)
    finally:
        gcs.conn.mav.srcSystem = 255
    gcs.pump(0.5)
    assert proc.poll() is None
    servo = gcs.latest["SERVO_OUTPUT_RAW"]
    assert all(getattr(servo, f"servo{i}_raw") == 1500 for i in range(1, 9))  # disarmed: neutral


def test_arm_fly_up_and_pilot_failsafe(vehicle):
    gcs, proc = vehicle
    param_set(gcs, "FS_PILOT_TIMEOUT", 0.5)

    def neutral() -> None:  # a pilot at neutral: pilot input keeps flowing, as from a joystick
        gcs.conn.mav.manual_control_send(1, 0, 0, 500, 0, 0)

    def climb() -> None:
        gcs.conn.mav.manual_control_send(1, 0, 0, 1000, 0, 0)  # full throttle up (z: 500 neutral)

    gcs.seen.clear()
    gcs.conn.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # MAV_CMD_COMPONENT_ARM_DISARM
    gcs.wait_for(lambda: any(m.command == 400 and m.result == 0 for m in gcs.messages("COMMAND_ACK")), 5.0,
                 every=neutral, what="arming ACK")
    gcs.wait_for(lambda: gcs.latest["HEARTBEAT"].base_mode & 128, 3.0, every=neutral, what="armed HEARTBEAT")
    start = depth_of(gcs.latest["SCALED_PRESSURE2"])
    gcs.wait_for(lambda: depth_of(gcs.latest["SCALED_PRESSURE2"]) < start - 0.3, 20.0, every=climb,
                 what="depth decreasing under throttle up")
    servo = gcs.latest["SERVO_OUTPUT_RAW"]
    assert all(getattr(servo, f"servo{i}_raw") > 1550 for i in range(5, 9))  # vertical thrusters pushing up

    # stop sending: after FS_PILOT_TIMEOUT the vehicle goes neutral and, with ArduSub's default
    # FS_PILOT_INPUT = 2, disarms on its own
    gcs.wait_for(lambda: all(getattr(gcs.latest["SERVO_OUTPUT_RAW"], f"servo{i}_raw") == 1500 for i in range(1, 9)),
                 5.0, what="neutral outputs after the pilot-input failsafe")
    gcs.wait_for(lambda: not gcs.latest["HEARTBEAT"].base_mode & 128, 3.0, what="disarmed by the failsafe")
    assert any("manual control" in m.text for m in gcs.messages("STATUSTEXT"))
    assert proc.poll() is None


def test_unsupported_mode_is_refused(vehicle):
    gcs, _ = vehicle
    gcs.seen.clear()
    gcs.conn.mav.command_long_send(1, 1, 176, 0, 1, 3, 0, 0, 0, 0, 0)  # DO_SET_MODE AUTO
    gcs.wait_for(lambda: any(m.command == 176 for m in gcs.messages("COMMAND_ACK")), 5.0, what="mode ACK")
    assert next(m for m in gcs.messages("COMMAND_ACK") if m.command == 176).result == 2  # DENIED
    gcs.conn.mav.command_long_send(1, 1, 176, 0, 1, 0, 0, 0, 0, 0, 0)  # STABILIZE
    gcs.wait_for(lambda: gcs.latest["HEARTBEAT"].custom_mode == 0, 3.0, what="STABILIZE in HEARTBEAT")


def test_what_ground_stations_ask_at_connect(vehicle):
    gcs, _ = vehicle
    gcs.seen.clear()
    gcs.conn.mav.command_long_send(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0)  # REQUEST_MESSAGE AUTOPILOT_VERSION
    gcs.conn.mav.mission_request_list_send(1, 1)
    gcs.wait_for(lambda: gcs.messages("AUTOPILOT_VERSION") and gcs.messages("MISSION_COUNT"), 5.0,
                 what="AUTOPILOT_VERSION and MISSION_COUNT")
    assert gcs.messages("AUTOPILOT_VERSION")[0].capabilities & 8192  # MAVLink 2
    assert gcs.messages("MISSION_COUNT")[0].count == 0
    # message rates: ATTITUDE at 5 Hz, then back to the default; an unknown stream is refused
    gcs.conn.mav.command_long_send(1, 1, 511, 0, 30, 200_000, 0, 0, 0, 0, 0)
    gcs.conn.mav.command_long_send(1, 1, 511, 0, 9999, 200_000, 0, 0, 0, 0, 0)
    gcs.wait_for(lambda: len([m for m in gcs.messages("COMMAND_ACK") if m.command == 511]) >= 2, 5.0,
                 what="SET_MESSAGE_INTERVAL ACKs")
    assert [m.result for m in gcs.messages("COMMAND_ACK") if m.command == 511] == [0, 2]
    gcs.pump(0.5)
    gcs.seen.clear()
    gcs.pump(2.0)
    n = len(gcs.messages("ATTITUDE"))
    assert 6 <= n <= 14, f"{n} ATTITUDE messages in 2 s at 5 Hz"
    gcs.conn.mav.command_long_send(1, 1, 511, 0, 30, 0, 0, 0, 0, 0, 0)  # default again
