"""The ROS 1 vehicle node (issue 13) under rospy from Debian's packages, with a rosmaster on
127.0.0.1 in a loopback-only network namespace: the same checks as the ROS 2 node (sensor data in,
odometry with covariance and PWM out, the parameter server, bad input) and `rovlab ros1 sim` +
`rovlab ros1 node` holding depth and heading like case study 2."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import HERE, ROS1_PY, require, require_netns, run_isolated, tracking_rms


@pytest.fixture()
def ros1(tmp_path):
    require(ROS1_PY.exists(), "the ROS 1 environment .venv-ros1 is missing (make ros1-env: Debian's rospy)")
    require_netns()
    return tmp_path


def test_ros1_node_with_an_independent_peer(ros1):
    r = run_isolated([str(ROS1_PY), str(HERE / "ros1_peer.py"), "peer", "--ns", "rov", "--logdir", str(ros1)],
                     timeout=1500, tmp=ros1)
    assert r["node_up"]
    assert r["odometry_count"] >= 30 and r["wrench_count"] >= 30
    odom = r["odometry"]
    assert (odom["frame"], odom["child"]) == ("map", "base_link")
    pose_cov = np.array(odom["pose_cov"]).reshape(6, 6)
    assert 0 < pose_cov[2, 2] < 1.0 and 0 < pose_cov[5, 5] < 1.0 and pose_cov[0, 0] == 1e6
    assert odom["z"] < 0
    assert len(r["pwm"]) == 6 and r["pwm_label"] == "T1,T2,T3,T4,T5,T6"
    assert r["diagnostics"]["rovlab/node"][1] == "engaged"
    assert r["diagnostics"]["rovlab/sensors/pressure"][1] in ("ok", "recovering")  # remapped topic (--remap)
    assert r["diagnostics"]["rovlab/sensors/qualisys"][1] in ("ok", "recovering")
    assert r["odometry_during_bad_input"] >= 15 and r["node_alive_after_bad_input"]
    assert r["bad_param_after"] == pytest.approx(1e-2)  # refused: the running value put back
    assert r["good_param_after"] == 10.0
    assert r["gain_before"] and r["gain_after"] and r["gain_before"] != r["gain_after"]
    assert r["node_alive_at_end"] and r["node_exit"] == 0


def test_ros1_sim_and_node_hold_depth_and_heading_like_the_case_study(ros1):
    duration = 60.0
    r = run_isolated([str(ROS1_PY), str(HERE / "ros1_peer.py"), "e2e", "--duration", str(duration + 1.5),
                      "--logdir", str(ros1)], timeout=duration + 1500, tmp=ros1)
    assert r["node_started"] and r["node_exit"] == 0 and r["sim_exit"] == 0
    m = tracking_rms(r, duration)
    print(f"\nROS 1 sim+node, 60 s: depth RMS {m['z']:.4f} m (simulator {m['z_sim']:.4f}), heading RMS "
          f"{m['psi']:.4f} rad (simulator {m['psi_sim']:.4f}); last 10 s {m['z_last10']:.4f} m, {m['psi_last10']:.4f} rad")
    assert m["rows"] >= 0.95 * duration / 0.1
    assert m["z"] == pytest.approx(m["z_sim"], rel=0.25) and m["psi"] == pytest.approx(m["psi_sim"], rel=0.25)
    assert m["z_last10"] < 0.02 and m["psi_last10"] < max(2 * m["psi_sim_last10"], 0.02)
