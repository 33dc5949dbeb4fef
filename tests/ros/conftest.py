"""Running ROS processes for the tests: each test's processes live in a private network namespace
with only loopback (DDS and rosmaster traffic never leave the machine), inside one process group
that is killed when the test ends or times out.

The middleware comes from the project's own files: `make ros2-env` (rclpy wheels in .venv-ros2)
and `make ros1-env` (Debian's rospy, .venv-ros1); `make test` runs both first. Without them, or
without root for the namespace, the tests skip with the reason -- and fail when CI is set.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
ROS2_PY = ROOT / ".venv-ros2" / "bin" / "python"
ROS1_PY = ROOT / ".venv-ros1" / "bin" / "python"
_NETNS = "ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo; exec \"$@\""


def require(ok: bool, reason: str) -> None:
    if ok:
        return
    if os.environ.get("CI"):
        pytest.fail(f"{reason} (CI is set: the ROS tests must run; `make test` prepares them)")
    pytest.skip(reason)


def require_netns() -> None:
    require(os.geteuid() == 0 and shutil.which("unshare") is not None and shutil.which("ip") is not None,
            "a private network namespace (unshare -n, as root) keeps DDS / rosmaster on loopback")


def run_isolated(argv: list[str], *, timeout: float, tmp: Path) -> dict:
    """Run argv in a loopback-only network namespace; returns the JSON after 'RESULT ' on its
    stdout. Kills the whole process group on timeout."""
    env = dict(os.environ, ROS_LOG_DIR=str(tmp / "roslog"), ROS_HOME=str(tmp / "roshome"), PYTHONUNBUFFERED="1")
    env.pop("ROS_MASTER_URI", None)
    proc = subprocess.Popen(["unshare", "-n", "bash", "-c", _NETNS, "_", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate(timeout=10)
        logs = "".join(f"\n--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(tmp.glob("*.log")))
        pytest.fail(f"{argv[1:]} did not finish within {timeout:g} s:\n{out[-3000:]}{logs}")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # anything left behind in the group
        except ProcessLookupError:
            pass
    for line in out.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    logs = "".join(f"\n--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(tmp.glob("*.log")))
    raise AssertionError(f"no result from {argv[1:]} (exit {proc.returncode}):\n{out[-5000:]}{logs}")


def tracking_rms(result: dict, duration: float) -> dict[str, float]:
    """RMS of the true depth and heading errors over the first ``duration`` seconds of a run
    observed over ROS (truth rows and set-points as (stamp, depth, ENU yaw)), next to the
    compiled simulator's on the same scenario (step-process-model)."""
    import math

    import numpy as np

    from rovlab.sim.runner import simulate

    def wrap(a):
        return np.remainder(np.asarray(a) + np.pi, 2 * np.pi) - np.pi

    def rms(a):
        return float(math.sqrt(np.mean(np.square(a))))

    from rovlab.sim.scenario import load_scenario

    sc = load_scenario("step-process-model")
    truth = np.array(result["truth"])
    t0 = truth[0, 0]  # the simulated vehicle stamps step k at t0 + k h
    assert abs(truth[0, 1] - sc.initial[2]) < 1e-9, "the first step (the initial state) was not received"
    truth = truth[truth[:, 0] <= t0 + duration + 1e-6]
    refs = np.array([sc.reference_at(t - t0) for t in truth[:, 0]])  # the schedule it published
    ez = truth[:, 1] - refs[:, 0]
    epsi = wrap(truth[:, 2] - (0.5 * np.pi - refs[:, 1]))  # ENU yaw error = -(heading error): the same RMS
    c = simulate("step-process-model").columns
    bz, bpsi = c["true_z"] - c["ref_z"], wrap(c["true_psi"] - c["ref_psi"])
    return {"rows": len(truth), "z": rms(ez), "psi": rms(epsi), "z_sim": rms(bz), "psi_sim": rms(bpsi),
            "z_last10": rms(ez[-100:]), "psi_last10": rms(epsi[-100:]), "z_sim_last10": rms(bz[-100:]),
            "psi_sim_last10": rms(bpsi[-100:])}
