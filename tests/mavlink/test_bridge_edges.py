"""The bridge at its edges: a misbehaving vehicle (garbage, NaN and infinite fields, a mismatched
SYSID_MYGCS) does not stop it; RC overrides instead of MANUAL_CONTROL; the command-line bridge
stops cleanly on SIGTERM with its recording complete. All on 127.0.0.1, bounded waits."""

from __future__ import annotations

import importlib.util
import math
import os
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port, start_rovlab, stop, wait_until  # noqa: E402


def _bridge(port: int, lines: list[str], **kw):
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    return MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                         connect=f"udpin:127.0.0.1:{port}", log=lines.append, **kw)


def test_a_misbehaving_vehicle_does_not_stop_the_bridge():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    port = free_udp_port()
    lines: list[str] = []
    bridge = _bridge(port, lines)
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    fake = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega")
    try:
        def burst(p_hpa: float, yaw: float, rate: float) -> None:
            fake.mav.heartbeat_send(12, 3, 81, 19, 4)
            fake.mav.scaled_pressure2_send(0, p_hpa, 0.0, 1500)
            fake.mav.attitude_send(0, 0.0, 0.0, yaw, 0.0, 0.0, rate)

        for _ in range(10):
            burst(math.nan, math.inf, -math.inf)
            fake.mav.param_value_send(b"SYSID_MYGCS", 42.0, 6, 11, 1)
            fake.write(b"\xfd\xff\x00garbage, not MAVLink at all" * 10)  # may swallow what follows: fine
            time.sleep(0.05)
        assert wait_until(lambda: bridge.counts["bad_data"] > 0 and bridge.vehicle_seen, 10.0)
        assert thread.is_alive()
        assert bridge.core.counters["accepted"] == 0  # nothing non-finite reached the filter
        assert any("SYSID_MYGCS is 42" in line for line in lines)
        # and good telemetry afterwards is used
        for _ in range(20):
            burst(1013.25 + 1.0 * 1000 * 9.82 / 100, 0.3, 0.0)
            time.sleep(0.05)
        assert wait_until(lambda: bridge.core.counters["accepted"] > 10, 10.0)
        assert thread.is_alive()
    finally:
        bridge.stop()
        thread.join(10.0)
        fake.close()
    assert not thread.is_alive()


def test_rc_overrides_move_the_thrusters_and_a_disarmed_vehicle_stays_disarmed():
    port = free_udp_port()
    lines: list[str] = []
    bridge = _bridge(port, lines, arm=True, command="rc_override")
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1", "--duration", "120")
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: bridge.armed, 120.0), lines
        bridge.set_reference(z=3.0, psi=0.0)  # 2 m deeper: the vertical thrusters push down
        assert wait_until(lambda: bridge.servo_pwm is not None and all(p < 1480 for p in bridge.servo_pwm[4:8]), 15.0), \
            f"vertical thrusters did not push down: {bridge.servo_pwm}"
        last = bridge.sent[-1][1]
        assert len(last) == 8 and last[2] < 1500 and last[0] == 65535  # channel 3 (throttle) down; 1 untouched
        # a pilot disarms the vehicle: the bridge (armed once) must not arm it again
        bridge.conn.mav.command_long_send(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0)
        assert wait_until(lambda: not bridge.armed, 5.0)
        time.sleep(2.5)
        assert not bridge.armed and any("disarmed" in line for line in lines)
    finally:
        bridge.stop()
        thread.join(10.0)
        stop(sim)


def test_command_line_bridge_stops_cleanly_and_keeps_its_recording(tmp_path):
    from mcap.reader import make_reader

    port = free_udp_port()
    record = tmp_path / "dive.mcap"
    bridge = start_rovlab("mavlink", "bridge", "--connect", f"udpin:127.0.0.1:{port}", "--arm", "--depth", "1.5",
                          "--record", str(record), "--status-every", "0.5")
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1", "--duration", "120")
    try:
        assert bridge.stdout is not None
        deadline = time.monotonic() + 120.0
        armed = False
        while not armed and time.monotonic() < deadline and bridge.poll() is None:
            line = bridge.stdout.readline()
            armed = " armed" in line and "t=" in line
        assert armed, "the command-line bridge did not arm the simulated vehicle"
    finally:
        out = stop(bridge)  # SIGTERM
        stop(sim)
    assert bridge.returncode == 0, out
    assert "stopped" in out
    with open(record, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()  # present only if the file was finished properly
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
    assert {"/mavlink/HEARTBEAT", "/mavlink/SCALED_PRESSURE2", "/rovlab/estimate", "/rovlab/command"} <= topics


def test_a_vehicle_file_that_disagrees_with_the_vehicles_parameters_stops_the_bridge_before_it_commands(tmp_path):
    """Issue 27: the bridge reads FRAME_CONFIG, MOT_n_DIRECTION and the PWM range from the vehicle
    (the simulator reports what its own vehicle file implies) and compares them with its vehicle
    file: thruster T3 reversed in the bridge's file -> MOT_3_DIRECTION disagrees -> nothing armed,
    nothing commanded, exit code 2, the parameter named. --trust-vehicle-file overrides."""
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.edit import edit_vehicle_file
    from rovlab.params.vehicle import load_vehicle, packaged_vehicle_path

    mine = tmp_path / "reversed_t3.toml"
    heavy = load_vehicle("bluerov2_heavy")
    t3 = next(t for t in heavy.thrusters if t.name == "T3")
    edit_vehicle_file(packaged_vehicle_path("bluerov2_heavy"),
                      {"thrusters[name=T3].direction": [-float(v) + 0.0 for v in t3.direction]}, output=mine)
    port = free_udp_port()
    lines: list[str] = []
    bridge = MavlinkBridge(load_vehicle(mine), load_design_config("bluerov2_heavy"), connect=f"udpin:127.0.0.1:{port}",
                           log=lines.append, arm=True)
    bridge.set_reference(z=1.5, psi=0.0)
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--duration", "120")
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        thread.join(120.0)
        assert not thread.is_alive(), lines  # it stopped by itself
        assert bridge.exit_code == 2 and bridge.vehicle_problems
        text = "\n".join(lines)
        assert "MOT_3_DIRECTION = -1: expected +1" in text and "MOT_1_DIRECTION" not in text, text
        assert all(neutral for _t, _v, neutral in bridge.sent)  # only the neutral inputs of its exit
        assert not bridge.armed and not bridge._armed_by_us
    finally:
        bridge.stop()
        thread.join(10.0)
        stop(sim)


def test_the_status_line_says_no_telemetry_instead_of_a_predicted_depth(capsys):
    """Issue 28: with no telemetry at all the status line printed z = 2.000 m, the filter's own
    prediction; it now says that nothing came (and the bridge controls nothing)."""
    from rovlab.interfaces.cli import main

    port = free_udp_port()
    assert main(["mavlink", "bridge", "--connect", f"udpin:127.0.0.1:{port}", "--duration", "2.5",
                 "--status-every", "0.5"]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "no telemetry from the vehicle (none received yet): no estimate, no control" in out
    assert "z=" not in out
    # nor a lost depth sensor: the filter's pressure channel times out, but nothing ever came (it said
    # "DEPTH SENSOR: the filter has lost the pressure channel (lost-timeout)" with no vehicle there)
    assert "DEPTH SENSOR" not in captured.err, captured.err
