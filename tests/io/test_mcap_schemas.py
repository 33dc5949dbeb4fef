"""A simulation's MCAP files open in ROS 2 tools and Foxglove as they are (issue 15, item 2; issue 27,
item 8): timeseries.mcap is a ROS 2 bag (profile ros2, only CDR messages with their ros2msg
definitions) that rosbags reads whole and converts to a ROS 1 bag and to a sqlite3 ROS 2 bag;
rovlab's series beside it (timeseries.rovlab.mcap) carry every column as JSON with its schema.
Times are wall-clock, schema names clean, axes REP 103's."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

mcap_reader = pytest.importorskip("mcap.reader")
jsonschema = pytest.importorskip("jsonschema")
decoder = pytest.importorskip("mcap_ros2.decoder")


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory):
    from rovlab.sim.output import write_run
    from rovlab.sim.runner import simulate

    res = simulate("dropout")
    out = tmp_path_factory.mktemp("run")
    before = time.time()
    written = write_run(out, res, {}, figures=False, report=False)
    assert written["timeseries.mcap"] == out / "timeseries.mcap"
    assert written["timeseries.rovlab.mcap"] == out / "timeseries.rovlab.mcap"
    return out / "timeseries.mcap", res, before


def _messages(path):
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh)
        yield from reader.iter_messages(log_time_order=True)


def _profile(path) -> str:
    with open(path, "rb") as fh:
        return mcap_reader.make_reader(fh).get_header().profile


def test_the_bag_holds_only_ros2_messages_that_decode(run_mcap):
    path, res, _ = run_mcap
    assert _profile(path) == "ros2"
    ros2 = decoder.DecoderFactory()
    counts: dict[str, int] = {}
    names = set()
    for schema, channel, message in _messages(path):
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr", channel.topic
        names.add(schema.name)
        ros2.decoder_for("cdr", schema)(message.data)
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    n = len(res.columns["time_s"])
    assert counts == {"/rovlab/odometry/truth": n, "/rovlab/odometry/estimate": n, "/rovlab/wrench": n, "/tf": n}
    assert names == {"nav_msgs/msg/Odometry", "geometry_msgs/msg/WrenchStamped", "tf2_msgs/msg/TFMessage"}


def test_the_series_hold_every_column_as_json(run_mcap):
    path, res, _ = run_mcap
    series = path.with_name("timeseries.rovlab.mcap")
    assert _profile(series) == ""  # not a ROS 2 bag, and it does not say it is one
    counts: dict[str, int] = {}
    names = set()
    for schema, channel, message in _messages(series):
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
        jsonschema.validate(json.loads(message.data), json.loads(schema.data))
        names.add(schema.name)
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    n = len(res.columns["time_s"])
    for topic in ("/rovlab/truth", "/rovlab/estimate", "/rovlab/command", "/rovlab/reference"):
        assert counts[topic] == n, topic
    assert not any(name.count("rovlab") > 1 for name in names)  # no 'rovlab.rovlab.truth'
    assert "rovlab.truth" in names
    from rovlab.io.timeseries import read_mcap_columns

    # given the bag, the reader finds the series beside it
    back = read_mcap_columns(path)
    np.testing.assert_allclose(back["est_z"], res.columns["est_z"], equal_nan=True)


def test_odometry_carries_the_estimate_its_covariance_and_wall_clock_times(run_mcap):
    from rovlab.io.ros2msg import UNESTIMATED_VARIANCE

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
            assert odo.header.frame_id == "map" and odo.child_frame_id == "base_link"
            assert odo.pose.pose.position.z == pytest.approx(-c["est_z"][k])  # ENU: up
            q = odo.pose.pose.orientation
            yaw = 2 * math.atan2(q.z, q.w)
            assert math.remainder(yaw - (math.pi / 2 - c["est_psi"][k]), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
            assert odo.pose.covariance[14] == pytest.approx(c["var_z"][k])  # (z, z)
            assert odo.pose.covariance[35] == pytest.approx(c["var_psi"][k])  # (yaw, yaw)
            # x, y (not estimated by the depth-and-heading filter), roll, pitch (not modelled)
            assert [odo.pose.covariance[7 * i] for i in (0, 1, 3, 4)] == [UNESTIMATED_VARIANCE] * 4
            assert odo.twist.twist.angular.z == pytest.approx(-c["est_r"][k])  # FLU: counter-clockwise
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


def test_the_truth_is_exact_and_tf_places_the_estimate(run_mcap):
    path, res, _ = run_mcap
    ros2 = decoder.DecoderFactory()
    truth = [ros2.decoder_for("cdr", s)(m.data) for s, ch, m in _messages(path) if ch.topic == "/rovlab/odometry/truth"]
    tf = [ros2.decoder_for("cdr", s)(m.data) for s, ch, m in _messages(path) if ch.topic == "/tf"]
    assert all(not any(o.pose.covariance) and not any(o.twist.covariance) for o in truth)
    k = 100
    assert truth[k].pose.pose.position.z == pytest.approx(-res.columns["true_z"][k])
    (tr,) = tf[k].transforms
    assert (tr.header.frame_id, tr.child_frame_id) == ("map", "base_link")
    assert tr.transform.translation.z == pytest.approx(-res.columns["est_z"][k])


def test_rosbags_reads_and_converts_the_bag(run_mcap, tmp_path):
    """rosbags (an implementation independent of the writer) opens the bag, decodes every message
    and converts it to a ROS 1 bag and to a sqlite3 ROS 2 bag with every message."""
    highlevel = pytest.importorskip("rosbags.highlevel", reason="rosbags (the dev extra) is the independent reader")
    path, res, _ = run_mcap
    n = len(res.columns["time_s"])
    expected = {"/rovlab/odometry/truth": n, "/rovlab/odometry/estimate": n, "/rovlab/wrench": n, "/tf": n}
    assert _rosbags_counts(highlevel, path) == expected
    ros1, sqlite = tmp_path / "run.bag", tmp_path / "run_sqlite3"
    for dst, extra in ((ros1, []), (sqlite, ["--dst-storage", "sqlite3"])):
        subprocess.run([sys.executable, "-m", "rosbags.convert", "--src", str(path), "--dst", str(dst), *extra],
                       check=True, capture_output=True, timeout=300)
        assert _rosbags_counts(highlevel, dst) == expected, dst


def _rosbags_counts(highlevel, path: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    with highlevel.AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts
