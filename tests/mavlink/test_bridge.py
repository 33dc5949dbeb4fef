"""`rovlab mavlink bridge` against `rovlab mavlink sim` (another process) on 127.0.0.1: it arms
the vehicle, holds a depth set-point, serves the HMI as a Source, and sends neutral commands
within one second of losing telemetry. Every wait is bounded."""

from __future__ import annotations

import importlib.util
import math
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port, start_rovlab, stop  # noqa: E402

COMPILE_TIMEOUT = 300.0  # the first run on a machine compiles the node's control step
SETPOINT = 2.0


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    port = free_udp_port()
    record = tmp_path_factory.mktemp("bridge") / "dive.mcap"
    lines: list[str] = []
    bridge = MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                           connect=f"udpin:127.0.0.1:{port}", arm=True, record=str(record), log=lines.append)
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1.2", "--duration",
                       "600")
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + COMPILE_TIMEOUT
        while not bridge.armed and time.monotonic() < deadline and sim.poll() is None:
            time.sleep(0.1)
        assert bridge.armed, f"the bridge did not arm the simulated vehicle: {lines}"
        yield {"bridge": bridge, "sim": sim, "thread": thread, "record": record, "lines": lines}
    finally:
        bridge.stop()
        thread.join(10.0)
        stop(sim)


def _measured_depth(bridge) -> float:
    out = bridge.core.last
    j = out.channel_columns.index("z_bar30")
    return float(out.y[j])


def test_bridge_holds_a_depth_set_point(rig):
    """From 1.2 m to a 2 m set-point: within 10 cm, then, from 10 s later, 10 s of the depths the
    vehicle reports (SCALED_PRESSURE2) within a few centimetres of the set-point on average."""
    bridge = rig["bridge"]
    bridge.set_reference(z=SETPOINT, psi=0.0)
    t0 = time.monotonic()
    settled_at = None
    while time.monotonic() - t0 < 120.0 and settled_at is None:
        time.sleep(0.1)
        if abs(_measured_depth(bridge) - SETPOINT) < 0.1:
            settled_at = time.monotonic() - t0
    assert settled_at is not None, f"depth did not reach {SETPOINT} m: last {_measured_depth(bridge):.3f} m"
    time.sleep(10.0)
    held = []
    t1 = time.monotonic()
    while time.monotonic() - t1 < 10.0:
        time.sleep(0.1)
        z = _measured_depth(bridge)
        if not math.isnan(z):
            held.append(z)
    err = np.array(held) - SETPOINT
    print(f"\ndepth hold: within 10 cm after {settled_at:.1f} s; 10 s later, over 10 s, the Bar30 depth error was "
          f"mean {err.mean() * 100:+.1f} cm, RMS {np.sqrt(np.mean(err**2)) * 100:.1f} cm, max {np.abs(err).max() * 100:.1f} cm")
    assert len(held) > 50
    assert abs(err.mean()) < 0.05
    assert np.sqrt(np.mean(err**2)) < 0.08
    assert bridge.core.last.x[0] == pytest.approx(SETPOINT, abs=0.05)  # the estimate agrees
    assert bridge.counts["failsafes"] == 0
    last_sent = bridge.sent[-1][1]
    assert 0 <= last_sent[2] <= 1000 and all(-1000 <= v <= 1000 for v in (last_sent[0], last_sent[1], last_sent[3]))


def test_bridge_is_an_hmi_source(rig):
    from rovlab.interfaces.hmi.source import Source
    from rovlab.interfaces.mavlink.source import MavlinkSource

    src = MavlinkSource(rig["bridge"], start=False)  # the rig's bridge already runs
    assert isinstance(src, Source)
    assert src.kind == "vehicle" and src.paced is False
    d = src.describe()
    assert d["has_truth"] is False and d["vehicle"] == "bluerov2_heavy"
    assert {c["column"] for c in d["channels"]} == {"z_bar30", "psi_imu", "r_imu"}
    src.advance(1)
    time.sleep(0.5)
    topics = {t for t, _, _ in src.advance(1)}
    assert {"/rovlab/estimate", "/rovlab/measurement", "/rovlab/command"} <= topics
    assert "/rovlab/truth" not in topics
    st = src.status()
    assert st["vehicle"]["armed"] and st["reference"]["z"] == pytest.approx(SETPOINT)
    with pytest.raises(ValueError, match="truth"):
        src.apply(truth=rig["bridge"].core.vehicle)
    with pytest.raises(ValueError):
        src.set_sensor_available("no-such-sensor", False)


def test_telemetry_loss_sends_neutral_within_one_second(rig):
    """The vehicle's process is killed (no goodbye): the bridge must send neutral commands
    (MANUAL_CONTROL x = y = r = 0, z = 500) within one second of the last telemetry."""
    bridge, sim = rig["bridge"], rig["sim"]
    assert not bridge.failsafe
    sim.kill()
    t_kill = time.monotonic()
    deadline = t_kill + 5.0
    first = None
    while time.monotonic() < deadline and first is None:
        time.sleep(0.02)
        first = next((s for s in list(bridge.sent) if s[2] and s[0] >= t_kill), None)
    assert first is not None, "no neutral command within 5 s of losing telemetry"
    t_sent, values, _ = first
    delay = t_sent - bridge.last_telemetry
    print(f"\ntelemetry failsafe: neutral MANUAL_CONTROL {values} sent {delay * 1000:.0f} ms after the last "
          f"telemetry ({(t_sent - t_kill) * 1000:.0f} ms after the vehicle process was killed)")
    assert values == (0, 0, 500, 0)
    assert delay < 1.0
    # and it keeps sending neutral while the link stays down
    time.sleep(0.5)
    assert all(s[2] for s in list(bridge.sent) if s[0] > t_sent)


def test_recording_holds_telemetry_and_estimates(rig):
    from rovlab.interfaces.mavlink.logs import read_records
    from rovlab.io.timeseries import read_mcap_json

    bridge = rig["bridge"]
    bridge.stop()
    rig["thread"].join(10.0)
    assert not rig["thread"].is_alive()
    kinds = {k for _, k, _ in read_records(rig["record"])}
    assert {"HEARTBEAT", "SCALED_PRESSURE2", "ATTITUDE", "SERVO_OUTPUT_RAW"} <= kinds
    topics = {t for t, _, _ in read_mcap_json(rig["record"], prefix="/rovlab/")}
    assert {"/rovlab/estimate", "/rovlab/command"} <= topics
