"""The bridge on a link it shares with a ground station (issue 27): it reads ArduSub 4.7's parameter
names without asking for the old ones forever, scales MANUAL_CONTROL by the live pilot gain
(NAMED_VALUE_FLOAT "PilotGain"), measures the telemetry rates that arrive, asks again when they
fall short and says when it cannot get one. The vehicle here is a scripted pymavlink peer, so each
behaviour is provoked on purpose; tests/mavlink/test_mavproxy.py has the same against MAVProxy and
the simulator. 127.0.0.1, free ports, bounded waits."""

from __future__ import annotations

import collections
import importlib.util
import os
import random
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port  # noqa: E402

# a vehicle with ArduSub 4.7's names: (value, MAV_PARAM_TYPE)
PARAMS_4_7 = {"MAV_GCS_SYSID": (255, 4), "MAV_GCS_SYSID_HI": (0, 4), "JS_GAIN_DEFAULT": (0.5, 9),
              "JS_THR_GAIN": (1.0, 9), "BARO2_GND_PRESS": (101325.0, 9)}


def test_4_7_names_live_gain_and_a_rate_the_bridge_cannot_get():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    port = free_udp_port()
    lines: list[str] = []
    bridge = MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                           connect=f"udpin:127.0.0.1:{port}", log=lines.append)
    thread = threading.Thread(target=bridge.run, daemon=True)
    fake = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega")
    reads: collections.Counter[str] = collections.Counter()  # PARAM_REQUEST_READ by name
    intervals: collections.Counter[int] = collections.Counter()  # SET_MESSAGE_INTERVAL by message id
    manual = []
    thread.start()
    try:
        start = time.monotonic()
        due = collections.defaultdict(float)
        engaged = False
        while time.monotonic() - start < 12.0:
            now = time.monotonic()
            # the vehicle: HEARTBEAT and PilotGain at 1 Hz, the Bar30 and servos at the 10 Hz the bridge
            # asks for, ATTITUDE stuck at 2 Hz whatever it asks (another ground station keeps resetting it)
            for what, period in (("hb", 1.0), ("att", 0.5), ("fast", 0.1)):
                if now < due[what]:
                    continue
                due[what] = now + period
                if what == "hb":
                    fake.mav.heartbeat_send(12, 3, 209, 19, 4)
                    fake.mav.named_value_float_send(int((now - start) * 1000), b"PilotGain", 0.8)
                elif what == "att":
                    fake.mav.attitude_send(int((now - start) * 1000), 0.0, 0.0, 0.2, 0.0, 0.0, 0.0)
                else:
                    # with a live sensor's noise: a frozen value is a stuck sensor, and the bridge does not
                    # hold depth on one
                    fake.mav.scaled_pressure2_send(int((now - start) * 1000), 1013.25 + 98.2 + random.gauss(0.0, 0.2),
                                                   98.2, 1500)
                    fake.mav.servo_output_raw_send(int((now - start) * 1e6), 0, *([1500] * 16))
            while (msg := fake.recv_match(blocking=False)) is not None:
                kind = msg.get_type()
                if kind == "PARAM_REQUEST_READ":
                    name = msg.param_id
                    reads[name] += 1
                    if name in PARAMS_4_7:  # SYSID_MYGCS does not exist on 4.7: no answer, as from ArduSub
                        value, ptype = PARAMS_4_7[name]
                        fake.mav.param_value_send(name.encode(), value, ptype, 400, 0)
                elif kind == "COMMAND_LONG" and msg.command == 511:
                    intervals[int(msg.param1)] += 1
                    fake.mav.command_ack_send(511, 0)
                elif kind == "MANUAL_CONTROL":
                    manual.append((msg.x, msg.y, msg.z, msg.r))
            if not engaged and now - start > 1.0:
                bridge.set_reference(z=2.0, psi=0.2)  # 1 m deeper than it is: the controller commands heave
                engaged = True
            time.sleep(0.005)
    finally:
        bridge.stop()
        thread.join(10.0)
        fake.close()
    assert not thread.is_alive()
    text = "\n".join(lines)
    # both generations asked once, then only the name the vehicle has (4.7); never the old one forever
    assert bridge.firmware_names == "4.7" and reads["MAV_GCS_SYSID"] >= 1 and 1 <= reads["SYSID_MYGCS"] <= 2, reads
    assert reads["MAV_GCS_SYSID_HI"] >= 1 and "ignores its commands" not in text
    # the live gain scales what is sent
    assert bridge.live_gain == pytest.approx(0.8) and bridge.pilot_gain() == pytest.approx(0.8)
    assert manual, "no MANUAL_CONTROL from the engaged bridge"
    assert bridge.sent_gains == (pytest.approx(0.8), 1.0)
    assert any(z != 500 for _x, _y, z, _r in manual)  # heave commanded
    # ATTITUDE: asked again, then said it cannot get it; bounded requests; the Bar30 left alone at 10 Hz
    assert "cannot get ATTITUDE at 10 Hz" in text, text
    assert "SCALED_PRESSURE2" not in text and intervals[137] == 1
    assert 4 <= intervals[30] <= 6, intervals
    assert bridge.rates["ATTITUDE"] == pytest.approx(2.0, abs=0.6)
    assert bridge.rates["SCALED_PRESSURE2"] == pytest.approx(10.0, abs=2.0)
    assert bridge.counts["rate_failures"] == 1
