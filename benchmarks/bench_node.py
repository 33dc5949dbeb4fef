"""Vehicle node latency: from a sensor sample to the published estimate (median, p99).

1. In process (NodeCore, no middleware): the time from offering the last sample of a control
   step (``push``) to the step's output being ready (``tick`` returns) -- the node's own cost.
2. Over ROS 2 (when .venv-ros2 exists and we may make a network namespace): an rclpy peer
   publishes FluidPressure and PoseStamped at 10 Hz to ``rovlab ros2 node``; the latency is the
   time from publishing the step's last sensor message to receiving its nav_msgs/Odometry
   (both in the peer, one clock), for 30 s. Loopback only (a private network namespace).
3. Over ROS 1 the same with rospy (when .venv-ros1 exists).

Prints numbers only. Run: ``python benchmarks/bench_node.py [--seconds 30]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _timing  # noqa: F401  (thread settings)

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
NETNS = "ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo; exec \"$@\""


def _pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))]


def report(what: str, lat_s: list[float]) -> None:
    ms = [1e3 * x for x in lat_s]
    print(f"{what:46s} n={len(ms):5d}  median {statistics.median(ms):8.3f} ms  p99 {_pct(ms, 0.99):8.3f} ms  "
          f"max {max(ms):8.3f} ms")


def in_process(n: int = 3000) -> None:
    from rovlab.interfaces.node.core import NodeCore
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    core = NodeCore(load_vehicle("udrone"), load_design_config("thesis"), log=lambda m: None)
    core.set_reference(z=1.0, psi=0.0)
    lat = []
    h = core.h
    for k in range(n):
        chans = core.channels
        for c in chans[:-1]:
            core.push(c.sensor, c.quantity, 1.0 + c.offset if c.quantity == "z" else 0.1, k * h)
        last = chans[-1]
        t0 = time.perf_counter()
        core.push(last.sensor, last.quantity, 1.0 + last.offset if last.quantity == "z" else 0.1, k * h)
        outs = core.tick(k * h)
        lat.append(time.perf_counter() - t0)
        assert len(outs) == 1
    report("NodeCore: last sample -> estimate (in process)", lat[100:])


def over_ros(kind: str, seconds: float) -> None:
    py = ROOT / f".venv-ros{kind}" / "bin" / "python"
    if not py.exists():
        print(f"ROS {kind}: skipped (.venv-ros{kind} missing: make ros{kind}-env)")
        return
    if os.geteuid() != 0 or not shutil.which("unshare"):
        print(f"ROS {kind}: skipped (needs root for a loopback-only network namespace)")
        return
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, ROS_LOG_DIR=tmp, ROS_HOME=tmp)
        p = subprocess.run(["unshare", "-n", "bash", "-c", NETNS, "_", str(py), str(HERE / "node_latency_peer.py"),
                            f"ros{kind}", "--seconds", str(seconds), "--logdir", tmp],
                           capture_output=True, text=True, env=env, timeout=seconds + 1500, start_new_session=True)
        line = next((x for x in p.stdout.splitlines() if x.startswith("RESULT ")), None)
        if line is None:
            print(f"ROS {kind}: no result\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
            return
        r = json.loads(line[7:])
        report(f"ROS {kind}: sensor message -> Odometry (rovlab ros{kind} node)", r["latency_s"])
        print(f"{'':46s} steps with a reply {r['replies']}/{r['sent']}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=30.0)
    a = ap.parse_args()
    in_process()
    over_ros("2", a.seconds)
    over_ros("1", a.seconds)


if __name__ == "__main__":
    sys.exit(main())
