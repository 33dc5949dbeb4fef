"""Recordings open in Foxglove (issue 27, item 8): every MCAP rovlab writes is read whole by the
libraries Foxglove opens MCAP files with (tests/peers/foxglove/read_mcap.mjs: @mcap/core's indexed
reader, @foxglove/rosmsg's ROS 2 .msg parser and @foxglove/rosmsg2-serialization's CDR reader,
JSON with jsonschema): a simulation's ROS 2 bag and its JSON series, a node recording and a MAVLink
bridge recording, every message decoded, none refused."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

PEER = Path(__file__).resolve().parents[1] / "peers" / "foxglove"


@pytest.fixture(scope="module")
def foxglove():
    node = shutil.which("node")
    reason = None
    if node is None:
        reason = "Node.js is missing (make test installs Debian's nodejs through scripts/ensure-node-peers.sh)"
    elif not (PEER / "node_modules" / "@mcap" / "core").is_dir():
        reason = "Foxglove's readers are not installed: run scripts/ensure-node-peers.sh (make test does)"
    if reason:
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)

    def read(path: Path) -> dict:
        out = subprocess.run([node, str(PEER / "read_mcap.mjs"), str(path)], capture_output=True, text=True,
                             timeout=300, cwd=PEER)
        assert out.returncode == 0, out.stderr
        result = json.loads(out.stdout)
        assert result["errors"] == [], result["errors"]
        for topic, t in result["topics"].items():
            assert t["errors"] == 0, f"{path.name} {topic}: {t['firstError']}"
        return result
    return read


def _counts(result: dict) -> dict[str, int]:
    return {topic: t["count"] for topic, t in result["topics"].items()}


def test_a_simulation_bag_and_its_series(foxglove, tmp_path):
    from rovlab.sim.output import write_run
    from rovlab.sim.runner import simulate

    res = simulate("dropout")
    write_run(tmp_path, res, {}, figures=False, report=False)
    n = len(res.columns["time_s"])
    bag = foxglove(tmp_path / "timeseries.mcap")
    assert bag["profile"] == "ros2"
    assert _counts(bag) == {"/rovlab/odometry/truth": n, "/rovlab/odometry/estimate": n, "/rovlab/wrench": n, "/tf": n}
    assert {t["messageEncoding"] for t in bag["topics"].values()} == {"cdr"}
    first = bag["topics"]["/rovlab/odometry/estimate"]["first"]
    assert (first["header"]["frame_id"], first["child_frame_id"]) == ("map", "base_link")
    assert first["pose"]["pose"]["position"]["z"] == pytest.approx(-float(res.columns["est_z"][0]))  # REP 103: z up
    tf = bag["topics"]["/tf"]["first"]["transforms"][0]
    assert tf["transform"]["translation"]["z"] == pytest.approx(-float(res.columns["true_z"][0]))
    series = foxglove(tmp_path / "timeseries.rovlab.mcap")
    assert series["profile"] == "" and {t["messageEncoding"] for t in series["topics"].values()} == {"json"}
    assert series["topics"]["/rovlab/truth"]["count"] == n
    assert series["topics"]["/rovlab/truth"]["first"]["state"]["z"] == pytest.approx(float(res.columns["true_z"][0]))


def test_a_node_recording(foxglove, tmp_path):
    from rovlab.interfaces.node.core import NodeCore
    from rovlab.interfaces.node.record import NodeRecorder
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    core = NodeCore(load_vehicle("udrone"), load_design_config("default"), log=lambda m: None)
    rec = NodeRecorder(tmp_path / "n.mcap", core, namespace="rov")
    core.set_reference(z=1.0, psi=0.0)
    t0 = 1.7e9
    for k in range(30):
        t = t0 + k * 0.1
        for c in core.channels:
            core.push(c.sensor, c.quantity, 1.0 + c.offset if c.quantity == "z" else 0.1, t)
        rec.sample("pressure", t, {"z": 1.0})
        for out in core.tick(t):
            rec.output(out)
    rec.close()
    bag = foxglove(tmp_path / "n.mcap")
    assert bag["profile"] == "ros2"
    counts = _counts(bag)
    assert counts["/rov/odometry"] == counts["/tf"] == counts["/rov/wrench"] == 30 and counts["/tf_static"] == 1
    assert bag["topics"]["/rov/odometry"]["schema"] == "nav_msgs/msg/Odometry"
    series = foxglove(tmp_path / "n.rovlab.mcap")
    assert series["topics"] and all(t["messageEncoding"] == "json" for t in series["topics"].values())


def test_a_mavlink_bridge_recording(foxglove, tmp_path):
    """What `rovlab mavlink bridge --record` writes (rovlab.interfaces.mavlink.logs.TelemetryRecorder:
    MAVLink's messages and rovlab's as JSON, no ROS 2 profile claimed): Foxglove decodes every one."""
    pytest.importorskip("pymavlink")
    from rovlab.interfaces.mavlink import dialect
    from rovlab.interfaces.mavlink.logs import TelemetryRecorder, read_records

    mavlink = dialect()

    path = tmp_path / "dive.mcap"
    rec = TelemetryRecorder(path, metadata={"connect": "udpin:127.0.0.1:14550"})
    t0 = 1.7e9
    for k in range(20):
        rec.mavlink(mavlink.MAVLink_attitude_message(100 * k, 0.0, 0.0, 0.1, 0.0, 0.0, 0.01), t0 + 0.05 * k)
        rec.mavlink(mavlink.MAVLink_scaled_pressure2_message(100 * k, 1113.25, 0.0, 1500), t0 + 0.05 * k)
        rec.rovlab("/rovlab/estimate", t0 + 0.05 * k, {"z": 1.0, "psi": 0.1, "status": "ok"})
    rec.close()
    assert len(read_records(path)) == 40
    result = foxglove(path)
    assert _counts(result) == {"/mavlink/ATTITUDE": 20, "/mavlink/SCALED_PRESSURE2": 20, "/rovlab/estimate": 20}
    assert result["profile"] != "ros2"
    assert result["topics"]["/mavlink/ATTITUDE"]["first"]["yaw"] == pytest.approx(0.1)
    assert result["topics"]["/mavlink/SCALED_PRESSURE2"]["first"]["press_abs"] == pytest.approx(1113.25)
