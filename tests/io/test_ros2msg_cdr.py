"""The ROS 2 messages of rovlab's files (rovlab.io.ros2msg), checked against an independent
implementation of ROS 2's interfaces and CDR: rosbags' type store of ROS 2 Kilted. The definitions
rovlab writes as MCAP schemas are the standard ones field for field, and what mcap-ros2-support's
public writer encodes from rovlab's message contents is what rosbags decodes, for arbitrary values,
missing entries, NaN and any time stamp a builtin_interfaces/Time holds, in REP 103's axes."""

from __future__ import annotations

import io
import math
import random

import numpy as np
import pytest

from rovlab.io import ros2msg
from rovlab.io.messages import row_messages, rows_to_messages

typesys = pytest.importorskip("rosbags.typesys", reason="rosbags (the dev extra) checks the ROS 2 messages")
mcap_reader = pytest.importorskip("mcap.reader")
ros2_writer = pytest.importorskip("mcap_ros2.writer")


@pytest.fixture(scope="module")
def kilted():
    return typesys.get_typestore(typesys.Stores.ROS2_KILTED)


def test_definitions_are_the_standard_interfaces(kilted):
    """Each schema parses to the same fields, types and defaults as the interface of ROS 2 Kilted,
    nested messages included, and names every message it uses."""
    for datatype, text in ros2msg.DEFINITIONS.items():
        ours = typesys.get_types_from_msg(text, datatype)
        standard = typesys.get_types_from_msg(kilted.generate_msgdef(datatype, ros_version=2)[0], datatype)
        assert ours == standard, datatype
        for name in ours:
            assert ours[name] == kilted.fielddefs[name], (datatype, name)


def _random_cases(seed: int, n: int):
    rng = random.Random(seed)
    for i in range(n):
        nav = {k: rng.uniform(-50.0, 50.0) for k in ("x", "y", "z", "psi", "u", "v", "w", "r") if rng.random() < 0.8}
        if i % 5 == 0 and nav:
            nav[next(iter(nav))] = math.nan  # a diverged estimate stays NaN (no made-up number)
        states = tuple(k for k in nav if rng.random() < 0.7) + ("b_Z",) * (i % 2)
        A = np.array([[rng.uniform(-1.0, 1.0) for _ in states] for _ in states])
        P = A @ A.T if i % 3 else None
        tau = [rng.uniform(-80.0, 80.0) for _ in "XYZN"]
        t_ns = rng.choice([0, 999_999_999, 1_000_000_000, rng.randrange(0, 2**31 * 10**9)])
        yield t_ns, nav, P, states, tau


def _write_and_read(messages):
    """Write (datatype, message dict) with mcap_ros2's public writer; the raw CDR back."""
    buf = io.BytesIO()
    w = ros2_writer.Writer(buf)
    schemas = {t: w.register_msgdef(t, ros2msg.DEFINITIONS[t]) for t in {t for t, _ in messages}}
    for k, (datatype, msg) in enumerate(messages):
        w.write_message("/" + datatype.replace("/", "_"), schemas[datatype], msg, log_time=k)
    w.finish()
    buf.seek(0)
    reader = mcap_reader.make_reader(buf)
    assert reader.get_header().profile == "ros2"
    return [(schema.name, message.data) for schema, _, message in reader.iter_messages(log_time_order=True)]


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def test_contents_encode_to_what_rosbags_decodes(kilted):
    cases = list(_random_cases(7, 200))
    messages = []
    for t_ns, nav, P, states, tau in cases:
        content = ros2msg.odometry_content(nav, P, states)
        messages += [(ros2msg.ODOMETRY, ros2msg.odometry(t_ns, content)),
                     (ros2msg.WRENCH_STAMPED, ros2msg.wrench_stamped(t_ns, tau)),
                     (ros2msg.TF_MESSAGE, ros2msg.tf_message([ros2msg.body_transform(t_ns, content)]))]
    raw = _write_and_read(messages)
    assert len(raw) == 3 * len(cases)
    for k, (t_ns, nav, P, states, tau) in enumerate(cases):
        odo = kilted.deserialize_cdr(raw[3 * k][1], raw[3 * k][0])
        assert odo.header.stamp.sec * 1_000_000_000 + odo.header.stamp.nanosec == t_ns
        assert (odo.header.frame_id, odo.child_frame_id) == ("map", "base_link")
        p = odo.pose.pose.position
        # REP 103: ENU (x east = NED y, y north = NED x, z up = -depth), FLU (heave and yaw rate negated)
        for got, want in ((p.x, nav.get("y", 0.0)), (p.y, nav.get("x", 0.0)), (p.z, -nav.get("z", 0.0)),
                          (odo.twist.twist.linear.x, nav.get("u", 0.0)), (odo.twist.twist.linear.y, -nav.get("v", 0.0)),
                          (odo.twist.twist.linear.z, -nav.get("w", 0.0)), (odo.twist.twist.angular.z, -nav.get("r", 0.0))):
            assert _same(got, want), (k, got, want)
        q = odo.pose.pose.orientation
        if math.isfinite(nav.get("psi", 0.0)):
            yaw = 2.0 * math.atan2(q.z, q.w)
            assert math.remainder(yaw - (0.5 * math.pi - nav.get("psi", 0.0)), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        content = ros2msg.odometry_content(nav, P, states)
        np.testing.assert_array_equal(odo.pose.covariance, content["pose_covariance"])
        np.testing.assert_array_equal(odo.twist.covariance, content["twist_covariance"])
        wre = kilted.deserialize_cdr(raw[3 * k + 1][1], raw[3 * k + 1][0])
        assert [wre.wrench.force.x, wre.wrench.force.y, wre.wrench.force.z] == [tau[0], -tau[1], -tau[2]]
        assert [wre.wrench.torque.x, wre.wrench.torque.y, wre.wrench.torque.z] == [0.0, 0.0, -tau[3]]
        tf = kilted.deserialize_cdr(raw[3 * k + 2][1], raw[3 * k + 2][0])
        finite = all(math.isfinite(nav.get(q, 0.0)) for q in ("x", "y", "z", "psi"))
        assert len(tf.transforms) == (1 if finite else 0)  # tf refuses NaN: no transform rather than a NaN one
        if finite:
            tr = tf.transforms[0]
            assert (tr.header.frame_id, tr.child_frame_id) == ("map", "base_link")
            assert [tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z] == \
                [p.x, p.y, p.z]


def test_unestimated_variance_convention():
    """REP 103/105 give the axes, REP 145 and sensor_msgs the meaning of a covariance: 0 is
    "unknown" (for the whole matrix), -1 marks an absent 3x3 block of an Imu. For one axis of an
    estimate's 6x6 pose or twist, rovlab writes a large variance (no information) on the diagonal
    of every quantity the estimator does not estimate, zeros off it; the truth is exact (zeros)."""
    big = ros2msg.UNESTIMATED_VARIANCE
    assert big >= 1e6  # (1 km)^2, (1000 rad)^2: nothing an ROV's estimate could mean
    P = np.array([[0.01, 0.002, 0.0], [0.002, 0.04, 0.0], [0.0, 0.0, 0.09]])
    pose, twist = (np.array(c).reshape(6, 6) for c in ros2msg.odometry_covariances(P, ("z", "psi", "w")))
    # ENU z = -z and yaw = pi/2 - psi: both signs flip, so their cross term keeps its sign
    assert pose[2, 2] == 0.01 and pose[5, 5] == 0.04 and pose[2, 5] == pose[5, 2] == 0.002
    assert np.diag(pose)[[0, 1, 3, 4]].tolist() == [big] * 4  # x, y (not estimated), roll, pitch (not modelled)
    assert twist[2, 2] == 0.09 and np.diag(twist)[[0, 1, 3, 4, 5]].tolist() == [big] * 5
    off = ~np.eye(6, dtype=bool)
    off[2, 5] = off[5, 2] = False
    assert not pose[off].any() and not twist[~np.eye(6, dtype=bool)].any()
    assert ros2msg.odometry_covariances(None, ()) == ([0.0] * 36, [0.0] * 36)  # the truth
    # a bias (not in Odometry) does not count as an estimated pose or twist quantity
    pose_b, _ = ros2msg.odometry_covariances(np.eye(1), ("b_Z",))
    assert pose_b[14] == big


def test_all_rows_at_once_equal_row_by_row():
    rng = np.random.default_rng(3)
    n = 40
    cols = {"time_s": np.arange(n) * 0.1, "true_z": rng.normal(size=n), "est_z": rng.normal(size=n),
            "var_z": rng.random(n), "status_z_bar30": rng.integers(0, 4, n).astype(float),
            "meas_z_bar30": np.where(rng.random(n) < 0.3, np.nan, rng.normal(size=n)),
            "ref_z": np.ones(n), "tau_Z": rng.normal(size=n), "pwm_t1": 1500 + rng.normal(size=n),
            "ctrl_theta": rng.normal(size=n)}
    cols["status_z_bar30"][5] = np.nan
    whole = list(rows_to_messages(cols))
    by_row = [m for k in range(n) for m in row_messages(cols, k)]
    assert whole == by_row
    assert len(whole) == 5 * n


def test_one_row_as_written_out():
    cols = {"time_s": np.array([0.0, 0.1]), "true_z": np.array([1.0, 1.5]), "est_z": np.array([0.9, np.nan]),
            "var_z": np.array([0.01, 0.02]), "status_z_bar30": np.array([0.0, 2.0]),
            "meas_z_bar30": np.array([np.nan, 1.4]), "ref_z": np.array([2.0, 2.0]), "tau_Z": np.array([3.0, 4.0]),
            "pwm_t1": np.array([1500.0, 1520.0])}
    assert list(row_messages(cols, -1)) == [
        ("/rovlab/truth", 0.1, {"t": 0.1, "state": {"z": 1.5}}),
        ("/rovlab/estimate", 0.1, {"t": 0.1, "state": {"z": None}, "variance": {"z": 0.02},
                                   "sensors": {"z_bar30": "lost"}}),
        ("/rovlab/measurement", 0.1, {"t": 0.1, "values": {"z_bar30": 1.4}}),
        ("/rovlab/reference", 0.1, {"t": 0.1, "state": {"z": 2.0}}),
        ("/rovlab/command", 0.1, {"t": 0.1, "tau": {"Z": 4.0}, "pwm_us": {"t1": 1520.0}}),
    ]
    for _, _, msg in rows_to_messages(cols):  # plain Python numbers (JSON), not numpy scalars
        for group in msg.values():
            values = group.values() if isinstance(group, dict) else [group]
            assert all(v is None or type(v) in (float, str) for v in values), msg
