"""`rovlab ros2 node --fly PLAN` against `rovlab ros2 sim` (issue 29, "Flying it"), in a loopback-only
network namespace: the node takes the simulated BlueROV2 Heavy to the plan's start depth with its
depth controller, flies a 30 s plan and stops (exit 0); a message on fly/abort aborts the flight
to neutral (exit 1)."""

from __future__ import annotations

import pytest

from .conftest import HERE, ROS2_PY, require, require_netns, run_isolated


@pytest.fixture()
def ros2(tmp_path, heavy):
    require(ROS2_PY.exists(), "the ROS 2 environment .venv-ros2 is missing (make ros2-env)")
    require_netns()
    from rovlab.ident.plan import plan_dive, write_plan

    write_plan(tmp_path / "plan30.toml", plan_dive(heavy, ("heave", "yaw"), 30.0, seed=2))
    return tmp_path


def _run(tmp, *extra):
    return run_isolated([str(ROS2_PY), str(HERE / "ros2_fly_peer.py"), str(tmp / "plan30.toml"), "--logdir", str(tmp),
                         *extra], timeout=1500, tmp=tmp)


def test_the_ros2_node_flies_a_plan_against_the_ros2_sim(ros2):
    r = _run(ros2)
    log = r["node_log"]
    assert r["started"], log
    assert r["node_exit"] == 0, log
    assert "going to the plan's start depth 2 m" in log and "flight complete: 30.0 of 30.0 s" in log, log
    heave = [z for z, _ in r["wrench"]]
    assert max(heave) - min(heave) > 10.0  # the excitation was flown (published wrench, ENU/FLU signs)
    assert r["pwm_last"] is not None and all(abs(p - 1500.0) <= 1.0 for p in r["pwm_last"]), r["pwm_last"]
    from rovlab.io.timeseries import read_mcap_columns

    cols = read_mcap_columns(ros2 / "node.mcap")  # the node's own recording, node.rovlab.mcap
    assert {"tau_Z", "tau_N", "pwm_T1"} <= set(cols) and len(cols["time_s"]) >= 300
    # and identify dive reads it (the PWM commanded, the samples each step used): the scenario's vehicle
    # is the packaged bluerov2_heavy, so its damping is the file's (Z_w -33 N s/m, N_|r|r -1.5 N m s^2/rad^2)
    import json
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", "identify", "dive", str(ros2 / "node.mcap"),
                          "--vehicle", "bluerov2_heavy", "--json", "--no-plot"], capture_output=True, text=True,
                         timeout=300)  # --no-plot: the figure's default place is the working directory (the checkout)
    assert res.returncode == 0, res.stderr
    fit = json.loads(res.stdout)
    assert fit["heave"]["parameters"]["Z_w"]["estimate"] == pytest.approx(-33.0, rel=0.35)
    assert fit["yaw"]["parameters"]["N_|r|r"]["estimate"] == pytest.approx(-1.5, rel=0.35)


def test_an_abort_message_aborts_the_ros2_flight_to_neutral(ros2):
    r = _run(ros2, "--abort", "3")
    log = r["node_log"]
    assert r["started"], log
    assert r["pwm_before_abort"] is not None and any(abs(p - 1500.0) > 1.0 for p in r["pwm_before_abort"])
    assert r["node_exit"] == 1, log
    assert "ABORTED TO NEUTRAL" in log and "abort message on fly/abort: 'pilot takes over'" in log, log
    assert r["pwm_last"] is not None and all(abs(p - 1500.0) <= 1.0 for p in r["pwm_last"]), r["pwm_last"]
    assert r["ended_after_s"] < 10.0
