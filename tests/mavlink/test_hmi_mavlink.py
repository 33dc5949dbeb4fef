"""The HMI on an ArduSub vehicle through the MAVLink bridge (`rovlab hmi --source mavlink`), the
vehicle being `rovlab mavlink sim` in another process: the server streams the bridge's messages
(no truth), takes a reference from a client, and the command stops cleanly on SIGTERM."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import re
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None
                                or importlib.util.find_spec("aiohttp") is None,
                                reason="needs pymavlink and aiohttp: pip install 'rovlab[mavlink,hmi]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port, start_rovlab, stop  # noqa: E402


async def _next(ws, kind, *, timeout=20.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = await ws.receive(timeout=end - time.monotonic())
        frame = json.loads(msg.data)
        if frame["type"] == kind:
            return frame
    raise AssertionError(f"no {kind} frame within {timeout} s")


def test_hmi_server_on_the_bridge(tmp_path):
    from aiohttp.test_utils import TestClient, TestServer

    from rovlab.interfaces.hmi.server import HmiServer
    from rovlab.interfaces.hmi.session import Session
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.interfaces.mavlink.source import MavlinkSource
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    port = free_udp_port()
    bridge = MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                           connect=f"udpin:127.0.0.1:{port}", log=lambda text: None)
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1", "--duration", "120")
    source = MavlinkSource(bridge)
    session = Session.for_vehicle(source, vehicle="bluerov2_heavy", config="bluerov2_heavy", out_dir=tmp_path)

    async def main():
        server = HmiServer(session)
        client = TestClient(TestServer(server.app, host="127.0.0.1"))
        await client.start_server()
        try:
            ws = await client.ws_connect("/ws")
            hello = await _next(ws, "hello")
            assert hello["source"]["kind"] == "vehicle" and hello["source"]["has_truth"] is False
            assert hello["documents"]["loop"]["K"] and hello["documents"]["loop"]["bridge"]["command"] == "manual_control"
            # the page shows "live" and no Start/Step/Reset/speed for it (it showed "paused" and a Start button)
            assert hello["state"]["live"] is True and hello["state"]["running"] is False
            assert hello["state"]["engaged"] is False  # "no set-point held: the pilot has the vehicle"
            frame = await _next(ws, "data", timeout=60.0)
            topics = {m[0] for m in frame["messages"]}
            assert "/rovlab/estimate" in topics and "/rovlab/truth" not in topics
            await ws.send_str(json.dumps({"cmd": "reference", "id": 3, "depth_m": 1.5}))
            reply = await _next(ws, "reply")
            assert reply["id"] == 3 and reply["ok"]
            assert bridge.engaged and bridge.core.reference[2] == 1.5  # held once the vehicle is armed in MANUAL
            state = await _next(ws, "state")  # what the page says of the set-point: wanted, and why not held
            while not state["vehicle"]["seen"]:
                state = await _next(ws, "state", timeout=30.0)
            assert state["engaged"] is True
            assert state["vehicle"]["holding"] or state["vehicle"]["hold_blocked"], state["vehicle"]
            await ws.send_str(json.dumps({"cmd": "start", "id": 4}))  # a vehicle has its own clock
            err = await _next(ws, "error")
            assert err["id"] == 4 and "own clock" in err["message"]
            await ws.send_str(json.dumps({"cmd": "step", "id": 5, "n": 1}))  # nor single steps
            err = await _next(ws, "error")
            assert err["id"] == 5 and "own clock" in err["message"]
            await ws.close()
        finally:
            await client.close()

    try:
        asyncio.run(asyncio.wait_for(main(), 120.0))
    finally:
        source.close()
        stop(sim)
    assert not source._thread.is_alive()  # close() stopped the bridge


def test_rovlab_hmi_source_mavlink_command(tmp_path):
    port = free_udp_port()
    hmi = start_rovlab("hmi", "--source", "mavlink", "--connect", f"udpin:127.0.0.1:{port}", "--port", "0",
                       "--out", str(tmp_path / "hmi"))
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1", "--duration", "120")
    try:
        deadline = time.monotonic() + 120.0
        url = None
        assert hmi.stdout is not None
        while url is None and time.monotonic() < deadline and hmi.poll() is None:
            line = hmi.stdout.readline()
            found = re.search(r"open (http://127\.0\.0\.1:\d+/)", line)
            url = found.group(1) if found else None
        assert url, "rovlab hmi --source mavlink did not start"
        import urllib.request

        state: dict = {}
        while "/rovlab/estimate" not in state.get("latest", {}) and time.monotonic() < deadline:
            time.sleep(0.5)
            with urllib.request.urlopen(url + "api/state", timeout=10) as r:
                state = json.loads(r.read())
        assert "bridge" in state["loop"] and "/rovlab/truth" not in state["latest"]
        assert state["latest"]["/rovlab/estimate"]["sensors"]  # the bridge's estimates reach the HMI
    finally:
        out = stop(hmi)
        stop(sim)
    assert hmi.returncode == 0, out
