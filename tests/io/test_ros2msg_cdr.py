"""rovlab's own CDR encoding of the simulation log's ROS 2 messages (rovlab.io.ros2msg) is byte for
byte what mcap-ros2-support's general encoder makes of the same message (the encoder ROS 2 tools'
MCAP writer uses), for arbitrary values, missing entries, NaN and any time stamp a ROS 2
builtin_interfaces/Time holds."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from rovlab.io import ros2msg
from rovlab.io.messages import row_messages, rows_to_messages


def _random_cases(seed: int, n: int):
    rng = random.Random(seed)
    for i in range(n):
        state = {k: rng.uniform(-50.0, 50.0) for k in ("x", "y", "z", "psi", "u", "v", "w", "r") if rng.random() < 0.8}
        if i % 5 == 0 and state:
            state[next(iter(state))] = math.nan  # a NaN estimate is written as 0, as odometry() does
        variance = {k: rng.uniform(-1e-3, 2.0) for k in state} if i % 2 else None
        tau = {k: rng.uniform(-80.0, 80.0) for k in "XYZN" if rng.random() < 0.8}
        t_ns = rng.choice([0, 999_999_999, 1_000_000_000, rng.randrange(0, 2**31 * 10**9)])
        yield t_ns, state, variance, tau


def test_odometry_and_wrench_bytes_equal_the_general_encoder():
    dynamic = pytest.importorskip("mcap_ros2._dynamic")
    odo = dynamic.serialize_dynamic(ros2msg.ODOMETRY, ros2msg.ODOMETRY_DEF)[ros2msg.ODOMETRY]
    wre = dynamic.serialize_dynamic(ros2msg.WRENCH_STAMPED, ros2msg.WRENCH_STAMPED_DEF)[ros2msg.WRENCH_STAMPED]
    for t_ns, state, variance, tau in _random_cases(7, 300):
        assert ros2msg.odometry_cdr(t_ns, state, variance) == odo(ros2msg.odometry(t_ns, state, variance))
        assert ros2msg.wrench_stamped_cdr(t_ns, tau) == wre(ros2msg.wrench_stamped(t_ns, tau))


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
