"""What the ROS adapters share, tested without ROS: NED/FRD <-> ENU/FLU both ways (REP-103/105),
the odometry and wrench contents, message parsing with clear refusals, the run-time parameter
table and the MCAP recording."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from rovlab.core import frames
from rovlab.interfaces.node import ros_common as rc
from rovlab.interfaces.node.core import NodeCore
from rovlab.io import ros2msg
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


def _rotate(q, v):
    """Rotate v by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    return R @ np.asarray(v, dtype=float)


def test_world_and_body_axes_both_ways():
    assert frames.ned_to_enu([1, 0, 0]).tolist() == [0, 1, 0]  # north is ENU y
    assert frames.ned_to_enu([0, 1, 0]).tolist() == [1, 0, 0]  # east is ENU x
    assert frames.ned_to_enu([0, 0, 2]).tolist() == [0, 0, -2]  # 2 m deep is ENU z = -2
    assert frames.frd_to_flu([1, 1, 1]).tolist() == [1, -1, -1]  # starboard is -left, down is -up
    rng = np.random.default_rng(0)
    for _ in range(20):
        v = rng.normal(size=3)
        np.testing.assert_array_equal(frames.enu_to_ned(frames.ned_to_enu(v)), v)
        np.testing.assert_array_equal(frames.flu_to_frd(frames.frd_to_flu(v)), v)


@pytest.mark.parametrize("psi", [0.0, 0.5 * math.pi, math.pi, -0.5 * math.pi, 0.3, -2.9])
def test_heading_quaternion_points_the_body_where_the_heading_says(psi):
    """Forward (base_link x) of the quaternion for heading psi points, in ENU, along the NED
    direction (cos psi, sin psi, 0) -- and the heading read back is psi."""
    q = frames.heading_quaternion(psi)
    forward_enu = _rotate(q, [1, 0, 0])
    np.testing.assert_allclose(forward_enu, frames.ned_to_enu([math.cos(psi), math.sin(psi), 0.0]), atol=1e-12)
    # base_link's left (y) points to port: NED starboard is (-sin psi, cos psi, 0), port is its negative
    np.testing.assert_allclose(_rotate(q, [0, 1, 0]), frames.ned_to_enu([math.sin(psi), -math.cos(psi), 0.0]),
                               atol=1e-12)
    assert frames.quaternion_heading(q) == pytest.approx(math.remainder(psi, 2 * math.pi), abs=1e-12) or \
        abs(abs(frames.quaternion_heading(q)) - math.pi) < 1e-12
    assert frames.heading_to_yaw(frames.yaw_to_heading(0.7)) == pytest.approx(0.7)


def test_quaternion_refusals():
    with pytest.raises(ValueError, match="not a valid quaternion"):
        frames.quaternion_yaw(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="not a valid quaternion"):
        frames.quaternion_yaw(float("nan"), 0.0, 0.0, 1.0)
    assert frames.quaternion_yaw(0.0, 0.0, 0.0, 2.0) == 0.0  # not normalised: still a rotation


def test_covariances_rotate_with_the_axes_and_back():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(6, 6))
    C = A @ A.T
    np.testing.assert_allclose(frames.pose_covariance_to_ned(frames.pose_covariance_to_enu(C)), C)
    np.testing.assert_allclose(frames.twist_covariance_to_frd(frames.twist_covariance_to_flu(C)), C)
    # a covariance is the second moment of the transformed samples: check against samples mapped one by one
    X = rng.multivariate_normal(np.zeros(6), C, size=20000)
    Y = np.array([np.concatenate([frames.ned_to_enu(x[:3]), frames.ned_to_enu(x[3:])]) for x in X])
    np.testing.assert_allclose(np.cov(Y.T), frames.pose_covariance_to_enu(np.cov(X.T)), atol=1e-12)


def test_odometry_content_from_an_estimate():
    """z, psi, w, r and their covariance (including the z-psi and w-r cross terms) land where
    REP-103 puts them: ENU z = -z, yaw = pi/2 - psi, FLU vz = -w, wz = -r; unknowns marked."""
    states = ("z", "psi", "w", "r", "b_Z", "b_N")
    P = np.diag([0.01, 0.02, 0.03, 0.04, 5.0, 6.0])
    P[0, 1] = P[1, 0] = 0.005  # z-psi
    P[2, 3] = P[3, 2] = 0.007  # w-r
    P[0, 2] = P[2, 0] = 0.009  # z-w: across pose and twist, Odometry has no place for it
    nav = {"x": 0.0, "y": 0.0, "z": 2.0, "psi": 0.25, "u": 0.0, "v": 0.0, "w": 0.1, "r": 0.05}
    c = rc.odometry_content(nav=nav, P=P, states=states)
    assert c["position"] == [0.0, 0.0, -2.0]
    assert frames.quaternion_yaw(*c["orientation"]) == pytest.approx(0.5 * math.pi - 0.25)
    assert c["linear"] == pytest.approx([0.0, 0.0, -0.1]) and c["angular"] == pytest.approx([0.0, 0.0, -0.05])
    pc, tc = np.array(c["pose_covariance"]).reshape(6, 6), np.array(c["twist_covariance"]).reshape(6, 6)
    assert pc[2, 2] == 0.01 and pc[5, 5] == 0.02 and pc[2, 5] == pc[5, 2] == 0.005  # (-1)(-1): sign kept
    assert tc[2, 2] == 0.03 and tc[5, 5] == 0.04 and tc[2, 5] == 0.007
    assert pc[0, 0] == pc[1, 1] == pc[3, 3] == pc[4, 4] == ros2msg.UNESTIMATED_VARIANCE
    assert tc[0, 0] == tc[1, 1] == tc[3, 3] == tc[4, 4] == ros2msg.UNESTIMATED_VARIANCE


def test_wrench_to_flu():
    force, torque = rc.wrench_flu(np.array([1.0, 2.0, 3.0, 0.5]))
    assert force == [1.0, -2.0, -3.0] and torque == [0.0, 0.0, -0.5]


def _pose(x=0.0, y=0.0, z=-1.0, q=(0.0, 0.0, 0.0, 1.0)):
    return SimpleNamespace(position=SimpleNamespace(x=x, y=y, z=z),
                           orientation=SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3]))


def test_incoming_messages_and_their_refusals():
    s = rc.pose_samples(_pose(x=1.0, y=2.0, z=-1.5, q=frames.heading_quaternion(0.4)))
    assert s == pytest.approx({"x": 2.0, "y": 1.0, "z": 1.5, "psi": 0.4})
    with pytest.raises(rc.MessageError, match=r"pose\.position\.z = nan"):
        rc.pose_samples(_pose(z=float("nan")))
    with pytest.raises(rc.MessageError, match="orientation"):
        rc.pose_samples(_pose(q=(0.0, 0.0, 0.0, 0.0)))
    d = rc.depth_from_pressure(rc.pressure_from_depth(1.25, rho=1000.0, g=9.81), rho=1000.0, g=9.81)
    assert d == pytest.approx(1.25)
    with pytest.raises(rc.MessageError, match="fluid_pressure"):
        rc.depth_from_pressure(-5.0, rho=1000.0, g=9.81)
    with pytest.raises(rc.MessageError, match="not a number"):
        rc.depth_from_pressure("high", rho=1000.0, g=9.81)
    imu = SimpleNamespace(orientation=SimpleNamespace(x=0.0, y=0.0, z=0.0, w=0.0), orientation_covariance=[-1.0] + [0] * 8,
                          angular_velocity=SimpleNamespace(x=0.0, y=0.0, z=0.2))
    assert rc.imu_samples(imu) == {"r": pytest.approx(-0.2)}  # no orientation (REP-145), FLU wz -> FRD r
    # rclpy hands the covariance as a numpy array: `cov or []` raised "truth value of an array is ambiguous",
    # so the ROS 2 node dropped every IMU message of a vehicle with an IMU (found flying bluerov2_heavy, issue 29)
    imu = SimpleNamespace(orientation=SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
                          angular_velocity=SimpleNamespace(x=0.0, y=0.0, z=0.2))
    got = rc.imu_samples(imu)
    assert got["r"] == pytest.approx(-0.2) and got["psi"] == pytest.approx(math.pi / 2)  # ENU yaw 0 = heading east
    with pytest.raises(rc.MessageError, match="stamp"):
        rc.stamp_seconds(float("nan"), 0)


@pytest.fixture(scope="module")
def table_core():
    core = NodeCore(load_vehicle("udrone"), load_design_config("default"), log=lambda m: None)
    from rovlab.params.design import resolve_config_path
    from rovlab.params.validate import read_toml

    path = resolve_config_path("default")
    return core, rc.ParameterTable(core, path, read_toml(path))


def test_parameter_table_names_validates_and_saves(table_core, tmp_path):
    core, table = table_core
    names = set(table.values)
    assert {"process_noise.psd.w", "process_noise.bias_time_per_mass", "lqr.state_max.z", "lqr.input_weight.Z",
            "fusion.gate_probability", "measurements.pressure.z.variance", "measurements.qualisys.psi.variance",
            "sensors.qualisys.enabled", "sensors.pressure.enabled"} <= names
    K = core.design.controller.model.K.copy()
    assert table.set({"lqr.input_weight.Z": 1.0}) is None
    assert not np.allclose(core.design.controller.model.K, K)
    reason = table.set({"process_noise.psd.w": -1.0})
    assert reason is not None and "process_noise.psd.w" in reason and ">= 0" in reason
    assert table.values["process_noise.psd.w"] == 1e-2  # unchanged
    assert "finite" in table.set({"lqr.state_max.z": float("nan")})
    assert "not a parameter" in table.set({"lqr.nonsense": 1.0})
    assert "true or false" in table.set({"sensors.qualisys.enabled": 1.0})
    assert table.set({"measurements.pressure.z.variance": 2e-4}) is None
    assert core.design.estimator.model.R[1, 1] == 2e-4
    assert table.set({"sensors.pressure.enabled": False}) is None and not core.sensor_enabled["pressure"]
    assert table.set({"filter.qualisys.psi.mode": "off"}) is None and core.filter_modes()["qualisys.psi"] == "off"
    assert "'auto', 'off' or 'on'" in table.set({"filter.qualisys.psi.mode": "sometimes"})
    # saving: the packaged file with the tuned values, loadable and equal to what runs
    saved = table.save(tmp_path / "tuned.toml")
    tuned = load_design_config(saved)
    assert tuned.lqr_R[0] == core.config.lqr_R[0]
    assert tuned.measurements[1].variance == 2e-4


def test_recording_is_readable_as_ros2_and_replayable(tmp_path):
    from mcap.reader import make_reader

    from rovlab.interfaces.node.record import NodeRecorder
    from rovlab.io.timeseries import read_mcap_columns

    core = NodeCore(load_vehicle("udrone"), load_design_config("default"), log=lambda m: None)
    rec = NodeRecorder(tmp_path / "n.mcap", core, namespace="rov")
    core.set_reference(z=1.0, psi=0.0)
    for k in range(30):
        for c in core.channels:
            core.push(c.sensor, c.quantity, 1.0 + 0.01 * math.sin(k) + c.offset if c.quantity == "z" else 0.1, k * 0.1)
        rec.sample("pressure", k * 0.1, {"z": 1.0})
        rec.sample("mocap/pose", k * 0.1, {"x": 0.0, "y": 0.0, "z": 1.0, "psi": 0.1})
        for out in core.tick(k * 0.1):
            rec.output(out)
    rec.close()
    rec.close()
    with open(tmp_path / "n.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert topics["/rov/odometry"] == "nav_msgs/msg/Odometry" and topics["/rov/pressure"] == "sensor_msgs/msg/FluidPressure"
    from mcap_ros2.decoder import DecoderFactory

    with open(tmp_path / "n.mcap", "rb") as fh:
        msgs = [m for _, _, _, m in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=["/rov/odometry"])]
    assert len(msgs) == 30 and msgs[-1].child_frame_id == "base_link"
    assert msgs[-1].pose.pose.position.z == pytest.approx(-1.0, abs=0.05)
    cols = read_mcap_columns(tmp_path / "n.mcap")  # the series beside the bag: n.rovlab.mcap
    assert len(cols["time_s"]) == 30 and np.all(np.isfinite(cols["tau_Z"]))
    assert read_mcap_columns(tmp_path / "n.rovlab.mcap").keys() == cols.keys()


def test_the_node_recording_is_a_ros2_bag_rosbags_reads_and_converts(tmp_path):
    """issue 27, item 8: the recording says it is a ROS 2 bag and is one: only CDR messages with
    their definitions, read whole by rosbags and converted to a ROS 1 bag and a sqlite3 ROS 2 bag;
    /tf places the estimate, /tf_static the sensors at their lever arms (REP 105: base_link FLU)."""
    import subprocess
    import sys

    from mcap.reader import make_reader

    from rovlab.interfaces.node.record import NodeRecorder

    highlevel = pytest.importorskip("rosbags.highlevel", reason="rosbags (the dev extra) is the independent reader")
    vehicle = load_vehicle("udrone")
    core = NodeCore(vehicle, load_design_config("default"), log=lambda m: None)
    rec = NodeRecorder(tmp_path / "n.mcap", core, namespace="rov")
    core.set_reference(z=1.0, psi=0.0)
    t0 = 1.7e9  # ROS time, UNIX seconds
    for k in range(40):
        t = t0 + k * 0.1
        for c in core.channels:
            core.push(c.sensor, c.quantity, 1.0 + c.offset if c.quantity == "z" else 0.1, t)
        rec.sample("pressure", t, {"z": 1.0})
        rec.sample("mocap/pose", t, {"x": 0.0, "y": 0.0, "z": 1.0, "psi": 0.1})
        for out in core.tick(t):
            rec.output(out)
    rec.close()
    with open(tmp_path / "n.mcap", "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    expected = {"/rov/pressure": 40, "/rov/mocap/pose": 40, "/rov/odometry": 40, "/tf": 40, "/rov/wrench": 40,
                "/rov/thrusters/pwm_us": 40, "/tf_static": 1}

    def read(path):
        counts: dict[str, int] = {}
        msgs: dict[str, list] = {}
        with highlevel.AnyReader([path]) as r:
            for conn, _t, raw in r.messages():
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
                msgs.setdefault(conn.topic, []).append(r.deserialize(raw, conn.msgtype))
        return counts, msgs

    counts, msgs = read(tmp_path / "n.mcap")
    assert counts == expected
    odo, tf = msgs["/rov/odometry"][-1], msgs["/tf"][-1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "base_link")
    assert tf.transform.translation.z == odo.pose.pose.position.z == pytest.approx(-1.0, abs=0.05)
    static = {t.child_frame_id: t for t in msgs["/tf_static"][0].transforms}
    assert set(static) == {s.name for s in vehicle.sensors}
    for s in vehicle.sensors:  # FRD lever arm -> FLU translation
        tr = static[s.name].transform.translation
        assert static[s.name].header.frame_id == "base_link"
        assert [tr.x, tr.y, tr.z] == pytest.approx([s.position[0], -s.position[1], -s.position[2]])
    assert msgs["/rov/pressure"][0].header.frame_id == core.sensor_of_kind("pressure")
    for dst, extra in ((tmp_path / "n.bag", []), (tmp_path / "n_sqlite3", ["--dst-storage", "sqlite3"])):
        subprocess.run([sys.executable, "-m", "rosbags.convert", "--src", str(tmp_path / "n.mcap"), "--dst", str(dst),
                        *extra], check=True, capture_output=True, timeout=300)
        assert read(dst)[0] == expected, dst


def test_node_and_simulator_odometry_share_one_variance_convention():
    """The node's Odometry (full covariance of its filter) and the simulator's (the logged
    variances) of the same estimate: the same diagonal, UNESTIMATED_VARIANCE where nothing is
    estimated (rovlab.io.ros2msg.odometry_covariances is the one place it is filled)."""
    from rovlab.io.timeseries import _ros2_messages

    core = NodeCore(load_vehicle("udrone"), load_design_config("default"), log=lambda m: None)
    core.set_reference(z=1.0, psi=0.0)
    outs = []
    for k in range(5):
        for c in core.channels:
            core.push(c.sensor, c.quantity, 1.0 + c.offset if c.quantity == "z" else 0.1, k * 0.1)
        outs += core.tick(k * 0.1)
    out = outs[-1]
    node = rc.odometry_content(out)
    (topic, sim_msg), *_ = _ros2_messages("/rovlab/estimate", 0, out.messages()[0][2], tf=False)
    assert topic == "/rovlab/odometry/estimate"
    node_pose, sim_pose = np.array(node["pose_covariance"]).reshape(6, 6), np.array(sim_msg["pose"]["covariance"]).reshape(6, 6)
    node_twist = np.array(node["twist_covariance"]).reshape(6, 6)
    sim_twist = np.array(sim_msg["twist"]["covariance"]).reshape(6, 6)
    np.testing.assert_allclose(np.diag(node_pose), np.diag(sim_pose), rtol=1e-12)
    np.testing.assert_allclose(np.diag(node_twist), np.diag(sim_twist), rtol=1e-12)
    assert np.diag(node_pose)[[0, 1, 3, 4]].tolist() == [ros2msg.UNESTIMATED_VARIANCE] * 4
    assert 0 < node_pose[2, 2] < 1.0 and 0 < node_pose[5, 5] < 1.0


def test_rovlab_filter_replays_a_node_recording(tmp_path, capsys):
    """`rovlab filter` on a node's MCAP recording: the offline filter over the recorded samples and
    achieved wrench gives the node's own estimates (the same filter, the same inputs)."""
    from rovlab.interfaces.cli import main
    from rovlab.interfaces.node.record import NodeRecorder
    from rovlab.io.logreader import read_log
    from rovlab.io.timeseries import read_mcap_columns

    core = NodeCore(load_vehicle("udrone"), load_design_config("default"), log=lambda m: None)
    rec = NodeRecorder(tmp_path / "dive.mcap", core)
    core.set_reference(z=1.0, psi=0.2)
    rng = np.random.default_rng(3)
    for k in range(80):
        for c in core.channels:
            v = (0.8 + 0.002 * k if c.quantity == "z" else 0.1) + c.offset + 0.01 * rng.standard_normal()
            if not (c.sensor == "qualisys" and 30 <= k < 40):  # a drop-out
                core.push(c.sensor, c.quantity, v, k * 0.1)
        for out in core.tick(k * 0.1 + core.collect_s):
            rec.output(out)
    rec.close()
    assert main(["filter", str(tmp_path / "dive.mcap"), "--config", "default", "--out", str(tmp_path / "est.csv")]) == 0
    est = read_log(tmp_path / "est.csv")
    node = read_mcap_columns(tmp_path / "dive.mcap")
    assert len(est.data["time_s"]) == 80
    np.testing.assert_allclose(est.data["est_z"], node["est_z"], atol=1e-9)
    np.testing.assert_allclose(est.data["est_psi"], node["est_psi"], atol=1e-9)
    assert "filtered 80 samples" in capsys.readouterr().out


@pytest.mark.parametrize("vehicle, config, dp", [("udrone_dvl", "udrone_dp", True), ("udrone", "default", False)])
def test_a_setpoints_position_reaches_a_dp_controller_and_is_said_unused_otherwise(vehicle, config, dp):
    """Issue 28: the ROS nodes used the depth and heading of a set-point and dropped x/y without a
    word. A controller declares the set-points it acts on (ComponentInfo.references): DP gets the
    position too; depth-and-heading control says, at the first set-point, that x and y are not used.
    Engaged by depth and heading alone (the bridge, the HMI), DP holds the estimated position
    instead of driving to the origin."""
    core = NodeCore(load_vehicle(vehicle), load_design_config(config), log=lambda m: None)
    assert ("x" in core.references) is dp
    said: list[str] = []
    adapter = SimpleNamespace(core=core, info=said.append)
    rc.VehicleAdapter.on_setpoint(adapter, SimpleNamespace(pose=_pose(x=3.0, y=4.0, z=-1.5,
                                                                 q=frames.heading_quaternion(0.4))))
    ref = core.reference
    assert ref[2:] == pytest.approx([1.5, 0.4])
    if dp:
        assert ref[:2] == pytest.approx([4.0, 3.0])  # ENU (3, 4) -> NED north 4, east 3
        assert "north 4 m, east 3 m" in said[0]
    else:
        assert "x and y are not used" in said[0]
    held = NodeCore(load_vehicle(vehicle), load_design_config(config), log=lambda m: None)
    held._nav[:2] = (2.5, -1.0)  # what the filter estimates when the controller is engaged
    held.set_reference(z=1.0)
    assert held.reference[:2] == pytest.approx([2.5, -1.0] if dp else [0.0, 0.0])
