"""MCAP logs open in Foxglove and ROS 2 tools as they are (issue 15, item 2): every message is
decoded with the schema its channel declares, times are wall-clock, schema names are clean."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

mcap_reader = pytest.importorskip("mcap.reader")
jsonschema = pytest.importorskip("jsonschema")
decoder = pytest.importorskip("mcap_ros2.decoder")


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory):
    from rovlab.sim.output import write_run
    from rovlab.sim.runner import simulate, summarise

    res = simulate("dropout")
    out = tmp_path_factory.mktemp("run")
    before = time.time()
    write_run(out, res, summarise(res), figures=False, report=False)
    return out / "timeseries.mcap", res, before


def _messages(path):
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh)
        summary = reader.get_summary()
        yield from reader.iter_messages()
    del summary


def test_every_message_decodes_with_its_declared_schema(run_mcap):
    path, res, _ = run_mcap
    ros2 = decoder.DecoderFactory()
    counts: dict[str, int] = {}
    names = set()
    for schema, channel, message in _messages(path):
        names.add(schema.name)
        if schema.encoding == "jsonschema":
            assert channel.message_encoding == "json"
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
        else:
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            decode = ros2.decoder_for("cdr", schema)
            decode(message.data)
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    n = len(res.columns["time_s"])
    for topic in ("/rovlab/truth", "/rovlab/estimate", "/rovlab/odometry/truth", "/rovlab/odometry/estimate",
                  "/rovlab/wrench", "/rovlab/command", "/rovlab/reference"):
        assert counts[topic] == n, topic
    assert not any(name.count("rovlab") > 1 for name in names)  # no 'rovlab.rovlab.truth'
    assert {"nav_msgs/msg/Odometry", "geometry_msgs/msg/WrenchStamped", "rovlab.truth"} <= names


def test_odometry_carries_the_estimate_its_covariance_and_wall_clock_times(run_mcap):
    path, res, before = run_mcap
    ros2 = decoder.DecoderFactory()
    c = res.columns
    k = 250  # 25 s: inside the drop-out, heading dead-reckoned
    seen = 0
    for schema, channel, message in _messages(path):
        if channel.topic != "/rovlab/odometry/estimate":
            continue
        if seen == k:
            odo = ros2.decoder_for("cdr", schema)(message.data)
            assert odo.header.frame_id == "map_ned" and odo.child_frame_id == "base_link_frd"
            assert odo.pose.pose.position.z == pytest.approx(c["est_z"][k])
            q = odo.pose.pose.orientation
            assert 2 * math.atan2(q.z, q.w) == pytest.approx(c["est_psi"][k])
            assert odo.pose.covariance[14] == pytest.approx(c["var_z"][k])  # (z, z)
            assert odo.pose.covariance[35] == pytest.approx(c["var_psi"][k])  # (yaw, yaw)
            assert odo.twist.twist.angular.z == pytest.approx(c["est_r"][k])
            t = odo.header.stamp.sec + odo.header.stamp.nanosec * 1e-9
            start = res.meta["start_time_unix_s"]
            assert t == pytest.approx(start + c["time_s"][k], abs=1e-6)
            assert before - 600 < start <= before  # wall clock of this run, not 1970
            assert message.log_time == odo.header.stamp.sec * 1_000_000_000 + odo.header.stamp.nanosec
            break
        seen += 1
    else:
        pytest.fail("no estimate odometry at the row looked for")
    assert np.isfinite(c["est_z"][k])
