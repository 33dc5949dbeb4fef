"""`rovlab mavlink sim` behaves like ArduSub where a ground station notices (issue 27): stream rates
set by REQUEST_DATA_STREAM over SET_MESSAGE_INTERVAL, GET_HOME_POSITION, SYS_STATUS health bits,
chunked STATUSTEXT, the live pilot gain, both generations of parameter names. The simulator is
stepped in-process on a synthetic clock and watched by an independent pymavlink ground station
(tests/mavlink/mavclient.py), so nothing here depends on the machine's speed."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import GroundStation, free_udp_port  # noqa: E402

T0 = 1000.0  # the synthetic clock's start [s]
# MAV_SYS_STATUS bits (MAVLink common.xml)
GYRO, PRESSURE, GEOFENCE, AHRS = 1, 8, 1 << 20, 1 << 21


class Stepped:
    """An ArduSubSim on a synthetic clock and a ground station that records what arrives, with the
    simulated time of arrival."""

    def __init__(self, *, scenario_extra: dict[str, Any] | None = None, **kw: Any) -> None:
        from rovlab.interfaces.mavlink.vehicle_sim import ArduSubSim
        from rovlab.sim.realtime import SimulatedVehicle
        from rovlab.sim.scenario import load_scenario_data, scenario_from_dict

        data, file = load_scenario_data("bluerov2-heavy-step")
        sc = scenario_from_dict({**data, **(scenario_extra or {})}, file=file)
        port = free_udp_port()
        self.gcs = GroundStation(port)
        self.sim = ArduSubSim(SimulatedVehicle(sc), connect=f"udpout:127.0.0.1:{port}", **kw)
        self.t = 0.0
        self.got: list[tuple[float, Any]] = []
        self.run(0.1)  # the ground station learns the vehicle's address from its first messages

    def close(self) -> None:
        self.sim.close()
        self.gcs.close()

    def run(self, seconds: float, *, dt: float = 0.02, every: Callable[[], None] | None = None) -> list[Any]:
        """Step for `seconds`; the messages that arrived meanwhile."""
        start = len(self.got)
        for _ in range(int(round(seconds / dt))):
            if every is not None:
                every()
            self.sim.step(T0 + self.t)
            self.gcs.seen.clear()
            self.gcs.pump()
            self.got.extend((self.t, m) for m in self.gcs.seen)
            self.t += dt
        return [m for _, m in self.got[start:]]

    @property
    def mav(self) -> Any:
        return self.gcs.conn.mav


@pytest.fixture
def rig():
    r = Stepped()
    yield r
    r.close()


def count(msgs: list[Any], kind: str) -> int:
    return sum(1 for m in msgs if m.get_type() == kind)


def test_request_data_stream_overwrites_the_interval_set_for_a_message(rig):
    """ArduPilot's handle_request_data_stream sets the rate of every message of the group and so
    undoes an earlier MAV_CMD_SET_MESSAGE_INTERVAL: what a ground station's request does to a
    companion's rates on a shared link."""
    rig.mav.command_long_send(1, 1, 511, 0, 30, 100_000, 0, 0, 0, 0, 0)  # ATTITUDE at 10 Hz
    rig.run(0.5)
    msgs = rig.run(2.0)
    assert 18 <= count(msgs, "ATTITUDE") <= 22
    rig.mav.request_data_stream_send(1, 1, 10, 4, 1)  # EXTRA1 (ATTITUDE's group) at 4 Hz
    rig.run(0.5)
    msgs = rig.run(2.0)
    assert 7 <= count(msgs, "ATTITUDE") <= 9, count(msgs, "ATTITUDE")
    assert count(msgs, "SCALED_PRESSURE2") >= 15  # RAW_SENSORS untouched (the Bar30 at 10 Hz)
    rig.mav.request_data_stream_send(1, 1, 0, 2, 1)  # MAV_DATA_STREAM_ALL at 2 Hz: every group
    rig.run(0.5)
    msgs = rig.run(3.0)
    for kind in ("ATTITUDE", "SCALED_PRESSURE2", "SERVO_OUTPUT_RAW", "VFR_HUD", "SYS_STATUS", "NAMED_VALUE_FLOAT"):
        assert 5 <= count(msgs, kind) <= 7, (kind, count(msgs, kind))
    rig.mav.request_data_stream_send(1, 1, 10, 0, 0)  # stop EXTRA1
    rig.run(0.5)
    msgs = rig.run(2.0)
    assert count(msgs, "ATTITUDE") == 0 and count(msgs, "HEARTBEAT") == 2  # HEARTBEAT is in no group
    assert rig.sim.counts["stream_requests"] == 3


def test_home_position_as_ardupilot_answers_it():
    """MAV_CMD_GET_HOME_POSITION: HOME_POSITION and GPS_GLOBAL_ORIGIN with ACCEPTED; without a home
    FAILED (ArduPilot's GCS_MAVLINK::handle_command_get_home_position), never UNSUPPORTED."""
    with_home = Stepped(home=(63.44, 10.40, 2.0))
    try:
        with_home.mav.command_long_send(1, 0, 410, 0, 0, 0, 0, 0, 0, 0, 0)
        msgs = with_home.run(0.2)
        ack = next(m for m in msgs if m.get_type() == "COMMAND_ACK")
        home = next(m for m in msgs if m.get_type() == "HOME_POSITION")
        origin = next(m for m in msgs if m.get_type() == "GPS_GLOBAL_ORIGIN")
        assert (ack.command, ack.result) == (410, 0)
        assert (home.latitude, home.longitude, home.altitude) == (634400000, 104000000, 2000)
        assert list(home.q) == [1.0, 0.0, 0.0, 0.0] and (origin.latitude, origin.longitude) == (634400000, 104000000)
        with_home.mav.command_long_send(1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)  # REQUEST_MESSAGE HOME_POSITION
        assert count(with_home.run(0.2), "HOME_POSITION") == 1
    finally:
        with_home.close()
    no_home = Stepped(home=None)
    try:
        no_home.mav.command_long_send(1, 0, 410, 0, 0, 0, 0, 0, 0, 0, 0)
        msgs = no_home.run(0.2)
        assert [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"] == [(410, 4)]  # FAILED
        assert count(msgs, "HOME_POSITION") == 0
    finally:
        no_home.close()


def test_long_statustext_is_sent_in_chunks(rig):
    """MAVLink 2 STATUSTEXT: 50 characters a message; a longer text shares one id (not 0) over
    chunk_seq 0, 1, ..., and ends with a chunk shorter than 50 (an empty one after an exact multiple)."""
    rig.mav.param_request_list_send(1, 1)  # ArduPilot sends its banner first
    texts = [m for m in rig.run(0.3) if m.get_type() == "STATUSTEXT"]
    banner = [m for m in texts if m.id == texts[0].id]
    assert texts[0].id != 0 and [m.chunk_seq for m in banner] == list(range(len(banner))) and len(banner) >= 2
    assert all(len(m.text) == 50 for m in banner[:-1]) and len(banner[-1].text) < 50
    assert "".join(m.text for m in banner) == ("ArduSub 4.7 parameters: rovlab mavlink sim of bluerov2_heavy, "
                                                "8 thrusters")
    short = next(m for m in texts if m.id == 0)
    assert short.text == "Frame: VECTORED_6DOF" and short.chunk_seq == 0
    rig.sim._status("x" * 100)
    exact = [m for m in rig.run(0.1) if m.get_type() == "STATUSTEXT"]
    assert [(len(m.text), m.chunk_seq) for m in exact] == [(50, 0), (50, 1), (0, 2)]
    assert len({m.id for m in exact}) == 1 and exact[0].id != texts[0].id


def test_sys_status_marks_absent_subsystems_healthy_and_the_pressure_sensor_as_it_reports():
    """As ArduSub (small.tlog): the fence is present, not enabled and healthy, so a ground station
    sees no breach; the Bar30 is healthy while it reports and unhealthy in the scenario's drop-out."""
    r = Stepped(scenario_extra={"dropout": [{"sensor": "bar30", "start_s": 1.0, "end_s": 2.5}]})
    try:
        r.run(3.5)
        status = [(t, m) for t, m in r.got if m.get_type() == "SYS_STATUS"]
        for _t, m in status:
            assert m.onboard_control_sensors_health & GEOFENCE and not m.onboard_control_sensors_enabled & GEOFENCE
            assert m.onboard_control_sensors_health & (GYRO | AHRS) == GYRO | AHRS
            assert m.onboard_control_sensors_present & PRESSURE
        healthy = {round(t): bool(m.onboard_control_sensors_health & PRESSURE) for t, m in status}
        assert healthy[0] and not healthy[2] and healthy[3], healthy
    finally:
        r.close()


def test_the_live_pilot_gain_moves_with_the_gain_buttons_not_with_js_gain_default(rig):
    """ArduSub reads JS_GAIN_DEFAULT at boot only; the gain buttons of its default map (11 up, 12
    down) step the live gain, which NAMED_VALUE_FLOAT "PilotGain" reports and MANUAL_CONTROL is
    scaled by."""

    def gain() -> float:
        return [m.value for m in rig.run(1.1) if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "PilotGain"][-1]

    assert gain() == pytest.approx(0.5)
    rig.mav.param_set_send(1, 1, b"JS_GAIN_DEFAULT", 0.9, 9)
    assert gain() == pytest.approx(0.5)  # the parameter is for the next boot
    for buttons in (1 << 11, 1 << 11, 0):  # pressed, held, released: one step
        rig.mav.manual_control_send(1, 0, 0, 500, 0, buttons)
        rig.run(0.1)
    assert gain() == pytest.approx(0.75)
    texts = [m.text for _, m in rig.got if m.get_type() == "STATUSTEXT"]
    assert "#Gain is 75%" in texts
    rig.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
    rig.run(0.2, every=lambda: rig.mav.manual_control_send(1, 1000, 0, 500, 0, 0))
    assert rig.sim.armed and rig.sim.inputs[0] == pytest.approx(0.75)  # full forward stick x gain
    rig.mav.manual_control_send(1, 0, 0, 500, 0, 1 << 12)  # gain down
    rig.run(0.1)
    assert rig.sim.gain == pytest.approx(0.5)


def test_parameter_generations_4_1_and_4_7():
    """--firmware 4.1: SYSID_THISMAV / SYSID_MYGCS; 4.7 (default): MAV_SYSID / MAV_GCS_SYSID, and a
    range of ground station ids up to MAV_GCS_SYSID_HI. Pilot input from others is ignored."""
    old = Stepped(firmware="4.1")
    try:
        old.mav.param_request_list_send(1, 1)
        names = {m.param_id: m for m in old.run(0.3) if m.get_type() == "PARAM_VALUE"}
        assert names["SYSID_MYGCS"].param_value == 255 and "MAV_GCS_SYSID" not in names
        old.mav.param_request_read_send(1, 1, b"MAV_GCS_SYSID", -1)  # the other generation's name: no answer
        assert count(old.run(0.3), "PARAM_VALUE") == 0
    finally:
        old.close()
    new = Stepped()
    try:
        new.mav.param_set_send(1, 1, b"MAV_GCS_SYSID", 250, 4)
        new.run(0.1)
        new.mav.manual_control_send(1, 0, 0, 500, 0, 1 << 11)  # from 255: not the ground station now
        new.run(0.1)
        assert new.sim.gain == pytest.approx(0.5) and new.sim.counts["ignored_sysid"] == 1
        new.mav.param_set_send(1, 1, b"MAV_GCS_SYSID_HI", 255, 4)  # 250 .. 255 are ground stations
        new.run(0.1)
        new.mav.manual_control_send(1, 0, 0, 500, 0, 0)
        new.run(0.1)
        new.mav.manual_control_send(1, 0, 0, 500, 0, 1 << 11)
        new.run(0.1)
        assert new.sim.gain == pytest.approx(0.75)
    finally:
        new.close()


def test_mavlink_ftp_is_refused_at_once(rig):
    """The simulator has no files: an FTP open is answered NAK FileNotFound (seq + 1, the request's
    opcode), ending a session ACK, so a ground station falls back to the parameter protocol at once
    instead of waiting for timeouts (MAVProxy tries @PARAM/param.pck first)."""
    import struct

    header = struct.Struct("<HBBBBBBI")
    name = b"@PARAM/param.pck"
    for seq, opcode, body in ((7, 4, name), (9, 1, b"")):  # OpenFileRO, TerminateSession
        payload = (header.pack(seq, 3, opcode, len(body), 0, 0, 0, 0) + body).ljust(251, b"\0")
        rig.mav.file_transfer_protocol_send(0, 1, 1, list(payload))
        reply = next(m for m in rig.run(0.1) if m.get_type() == "FILE_TRANSFER_PROTOCOL")
        got = bytes(reply.payload)
        r_seq, r_session, r_opcode, r_size, r_req = header.unpack_from(got)[:5]
        assert (r_seq, r_session, r_req) == (seq + 1, 3, opcode)
        if opcode == 4:
            assert (r_opcode, r_size, got[header.size]) == (129, 1, 10)  # NAK, ERR_FileNotFound
        else:
            assert (r_opcode, r_size) == (128, 0)  # ACK
