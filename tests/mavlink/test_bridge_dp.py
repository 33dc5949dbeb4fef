"""The bridge with a dynamic-positioning configuration, without ArduSub SITL (issue 30): north/east
set-points only where the controller holds x and y (the CLI refuses them otherwise, exit 2); against a
scripted vehicle, x and y are never held before the vehicle reports a position, on an implausible one, or
after the position stops arriving (neutral inputs, each said). SITL itself: test_ardusub_sitl_dp.py."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port, start_rovlab, stop, wait_until  # noqa: E402


def _bridge(port: int, lines: list[str], vehicle: str, config: str, **kw):
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    return MavlinkBridge(load_vehicle(vehicle), load_design_config(config), connect=f"udpin:127.0.0.1:{port}",
                         log=lines.append, **kw)


def test_north_east_need_a_controller_that_holds_them():
    lines: list[str] = []
    bridge = _bridge(free_udp_port(), lines, "ardusub_sitl_heavy", "ardusub_sitl_heavy")
    try:
        assert not bridge.dp
        with pytest.raises(ValueError, match="north/east set-points need a controller that holds x and y"):
            bridge.set_reference(z=1.0, x=2.0)
        assert not bridge.engaged  # nothing changed
        from rovlab.interfaces.mavlink.source import MavlinkSource

        source = MavlinkSource(bridge, start=False)  # the HMI's north/east set-points go the same way
        with pytest.raises(ValueError, match="north/east set-points need a controller"):
            source.set_reference(z=1.0, y=2.0)
    finally:
        bridge.close()
    for extra, said in ((["--depth", "1", "--north", "2"], "holds z, psi, no north/east set-point"),
                        (["--east", "2"], "--north/--east need --depth")):
        proc = start_rovlab("mavlink", "bridge", "--connect", f"udpin:127.0.0.1:{free_udp_port()}", "--vehicle",
                            "ardusub_sitl_heavy", "--config", "ardusub_sitl_heavy", "--duration", "5", *extra)
        try:
            proc.wait(60.0)  # refused at once, after loading the vehicle and designing (no vehicle needed)
        except subprocess.TimeoutExpired:
            pass
        out = stop(proc)
        assert proc.returncode == 2, out
        assert said in out and "Traceback" not in out, out


def test_a_dp_hold_waits_for_a_plausible_position_and_stops_when_it_is_lost():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    port = free_udp_port()
    lines: list[str] = []
    bridge = _bridge(port, lines, "ardusub_sitl_heavy_gps", "ardusub_sitl_heavy_dp", command="rc_override")
    assert bridge.dp and "LOCAL_POSITION_NED" in bridge.rate_wanted
    bridge.set_reference(z=1.0)
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    fake = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1,
                                      dialect="ardupilotmega")
    position: list[tuple[float, float] | None] = [None]
    stop_event = threading.Event()

    def vehicle() -> None:  # an ArduSub armed in MANUAL at 1 m, agreeing with the vehicle file, at 10 Hz
        params = {"FRAME_CONFIG": 2.0, "MOT_PWM_MIN": 1100.0, "MOT_PWM_MAX": 1900.0,
                  **{f"MOT_{k}_DIRECTION": 1.0 for k in range(1, 9)}}
        rng = np.random.default_rng(30)  # sensors that scatter (a value repeated exactly is a stuck sensor)
        n = 0
        while not stop_event.is_set():
            if n % 10 == 0:
                fake.mav.heartbeat_send(12, 3, 81 | 128, 19, 4)
                for name, value in params.items():
                    fake.mav.param_value_send(name.encode(), value, 9, len(params), 0)
            dz, dpsi, dx, dy = rng.normal(0.0, [0.1, 1e-3, 0.01, 0.01])  # SITL's depth scatters 11.7 cm
            fake.mav.scaled_pressure2_send(n * 100, 1013.25 + (1.0 + dz) * 1023.6 * 9.80665 / 100.0, 0.0, 1500)
            fake.mav.attitude_send(n * 100, 0.0, 0.0, 0.5 + dpsi, 0.0, 0.0, 0.0)
            if position[0] is not None:
                fake.mav.local_position_ned_send(n * 100, position[0][0] + dx, position[0][1] + dy, 1.0, 0.0, 0.0, 0.0)
            n += 1
            stop_event.wait(0.1)

    feeder = threading.Thread(target=vehicle, daemon=True)
    feeder.start()
    try:
        # no position reported yet (ArduSub's EKF3 without one): not held, said, neutral
        assert wait_until(lambda: bridge.position_problem is not None and bridge.vehicle_problems == [], 20.0), lines
        time.sleep(1.0)
        assert not bridge.core.engaged and "position: no ekf3_position.x sample yet" in (bridge.hold_blocked or "")
        assert any("POSITION: no ekf3_position.x sample yet" in line for line in lines), lines
        assert bridge.sent and all(neutral for _t, _v, neutral in list(bridge.sent)[-5:])

        # an implausible one: rejected, named with its value, still not held
        position[0] = (3.0e7, 2.0)
        assert wait_until(lambda: bridge.counts["implausible_position"] > 5, 5.0)
        assert not bridge.core.engaged and "x = 30000000.0" in (bridge.position_problem or ""), bridge.position_problem
        assert bridge.core.counters["accepted"] > 0 and not bridge._position_fused

        # plausible: held, on the position the filter estimates (the set-point gave depth only)
        position[0] = (1.0, 2.0)
        assert wait_until(lambda: bridge.core.engaged, 10.0), lines[-5:]
        assert bridge.core.reference[0] == pytest.approx(1.0, abs=0.2)
        assert bridge.core.reference[1] == pytest.approx(2.0, abs=0.2)
        assert any("holding north" in line for line in lines), lines[-5:]
        from rovlab.interfaces.mavlink.source import MavlinkSource

        ref = MavlinkSource(bridge, start=False).status()["reference"]  # what the HMI shows as north/east
        assert (ref["x"], ref["y"]) == (bridge.core.reference[0], bridge.core.reference[1])

        # the position stops (EKF3 lost it): the filter times the channel out and the hold stops
        position[0] = None
        assert wait_until(lambda: not bridge.core.engaged, 5.0), lines[-5:]
        assert "has lost ekf3_position" in (bridge.position_problem or ""), bridge.position_problem
        time.sleep(0.5)
        assert all(neutral for _t, _v, neutral in list(bridge.sent)[-3:])
        assert bridge.engaged  # the set-point is kept: held again on the same north/east once it is back
        ref = dict(bridge._wanted_ref or {})
        position[0] = (1.5, 2.5)
        assert wait_until(lambda: bridge.core.engaged, 15.0), lines[-5:]
        assert bridge.core.reference[0] == pytest.approx(ref["x"]) and bridge.core.reference[1] == pytest.approx(ref["y"])
    finally:
        stop_event.set()
        feeder.join(2.0)
        bridge.stop()
        thread.join(10.0)
        fake.close()
    assert not thread.is_alive()
