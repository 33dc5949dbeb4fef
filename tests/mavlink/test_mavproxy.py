"""A real ground station against rovlab's MAVLink peers (issue 27): MAVProxy (PyPI `MAVProxy`, the dev
extra) connected to `rovlab mavlink sim`, alone and with `rovlab mavlink bridge` behind its --out.
MAVProxy runs headless (--non-interactive, its own state directory and HOME), all on 127.0.0.1
with free ports; every wait is bounded and every process started here is stopped here.

Skipped with the reason when MAVProxy is not installed, except under CI (the CI variable set),
where `make test` installs it and its absence is a failure."""

from __future__ import annotations

import collections
import importlib.util
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import free_udp_port, start_rovlab  # noqa: E402

START_TIMEOUT = 120.0  # a first run compiles the simulated plant
BANNER = "AP: ArduSub 4.7 parameters: rovlab mavlink sim of bluerov2_heavy, 8 thrusters"  # 74 characters: 2 chunks


@pytest.fixture(scope="module", autouse=True)
def mavproxy_installed() -> None:
    if importlib.util.find_spec("MAVProxy") is None:
        if os.environ.get("CI"):
            pytest.fail("MAVProxy is not installed, but CI is set: make test installs the peers extra, which has it")
        pytest.skip("needs MAVProxy: pip install -e '.[peers]' (make test installs it)")


class Running:
    """A process started here, its output read as it comes (so a test can wait for a line)."""

    def __init__(self, proc: subprocess.Popen, *, interrupt: bool = False) -> None:
        self.proc = proc
        self.interrupt = interrupt  # stop with SIGINT (MAVProxy closes its logs on it)
        self.lines: list[tuple[float, str]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    @property
    def text(self) -> str:
        return "\n".join(line for _, line in self.lines)

    def when(self, pattern: str) -> float | None:
        """When the first line matching the regular expression arrived (time.monotonic())."""
        return next((t for t, line in list(self.lines) if re.search(pattern, line)), None)

    def wait_for(self, pattern: str, timeout: float) -> float | None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and self.proc.poll() is None:
            t = self.when(pattern)
            if t is not None:
                return t
            time.sleep(0.1)
        return self.when(pattern)

    def stop(self, timeout: float = 10.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT if self.interrupt else signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                if self.interrupt:  # MAVProxy runs in a process group of its own: it and what it started
                    os.killpg(self.proc.pid, signal.SIGKILL)
                else:
                    self.proc.kill()
                self.proc.wait(timeout)
        self._reader.join(timeout)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        print(self.text)


def start_mavproxy(master_port: int, state: Path, *, out_port: int | None = None) -> Running:
    """MAVProxy as a user runs it, headless: listening where the vehicle sends, optionally forwarding
    to another port (where the bridge listens)."""
    args = [sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpin:127.0.0.1:{master_port}",
            "--non-interactive", f"--state-basedir={state}"]
    if out_port is not None:
        args.append(f"--out=udpout:127.0.0.1:{out_port}")
    env = dict(os.environ, HOME=str(state), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            text=True, cwd=state, env=env, start_new_session=True)
    return Running(proc, interrupt=True)


def tlog_messages(path: Path) -> list[Any]:
    """Everything in MAVProxy's telemetry log (what it received and what it sent)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append(msg)
    log.close()
    return out


def test_mavproxy_connects_cleanly_to_the_simulator(tmp_path):
    """No false fence breach, GET_HOME_POSITION answered (MAVProxy asks every 2 s until it has a
    HOME_POSITION), the parameters listed over the parameter protocol (FTP refused at once), a
    long STATUSTEXT shown whole."""
    port = free_udp_port()
    mp = start_mavproxy(port, tmp_path)
    sim = Running(start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--duration", "300"))
    try:
        got = mp.wait_for(r"Received \d+ parameters", START_TIMEOUT)
        assert got is not None, mp.text
        time.sleep(5.0)  # long enough for MAVProxy to ask for home twice more if it had none
    finally:
        mp.stop()
        sim.stop()
    out = mp.text
    assert "fence breach" not in out and "FTP: request timed out" not in out and "no link" not in out, out
    assert BANNER in out.splitlines()
    count = int(re.search(r"Received (\d+) parameters", out).group(1))
    parm = dict(line.split()[:2] for line in (tmp_path / "mav.parm").read_text().splitlines() if line.strip())
    assert count == len(parm) == 23  # 15 of ArduSub's and MOT_1..8_DIRECTION of the Heavy's vehicle file
    assert [int(float(parm[f"MOT_{k}_DIRECTION"])) for k in range(1, 9)] == [-1] * 8
    assert float(parm["FS_PILOT_INPUT"]) == 2 and float(parm["MAV_GCS_SYSID"]) == 255 and "SYSID_MYGCS" not in parm
    msgs = tlog_messages(tmp_path / "mav.tlog")
    asked = [m for m in msgs if m.get_type() == "COMMAND_LONG" and m.command == 410]
    acks = [m.result for m in msgs if m.get_type() == "COMMAND_ACK" and m.command == 410]
    homes = [m for m in msgs if m.get_type() == "HOME_POSITION"]
    print(f"\nMAVProxy: GET_HOME_POSITION asked {len(asked)} time(s), answered {acks}; {len(homes)} HOME_POSITION; "
          f"{count} parameters")
    assert len(asked) == 1 and acks == [0] and homes  # asked once: ACCEPTED with the home
    status = [m for m in msgs if m.get_type() == "SYS_STATUS"]
    assert status and all(m.onboard_control_sensors_health & (1 << 20) for m in status)  # fence healthy


def test_bridge_keeps_its_rates_while_mavproxy_resets_them(tmp_path):
    """Vehicle -> MAVProxy -> bridge: MAVProxy sends REQUEST_DATA_STREAM(ALL, 4 Hz) 15 s after it
    finds the vehicle (and every 15 s after), which on ArduSub resets the 10 Hz the bridge asked for.
    The bridge notices, asks again and has its rates back within seconds; it also reads the 4.7
    parameter names and the live pilot gain through MAVProxy."""
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    vehicle_port, bridge_port = free_udp_port(), free_udp_port()
    lines: list[str] = []
    bridge = MavlinkBridge(load_vehicle("bluerov2_heavy"), load_design_config("bluerov2_heavy"),
                           connect=f"udpin:127.0.0.1:{bridge_port}", log=lines.append)
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    mp = start_mavproxy(vehicle_port, tmp_path, out_port=bridge_port)
    sim = Running(start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{vehicle_port}",
                               "--duration", "300"))
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while not bridge.vehicle_seen and time.monotonic() < deadline and sim.proc.poll() is None:
            time.sleep(0.1)
        assert bridge.vehicle_seen, sim.text + mp.text
        t_reset = sim.wait_for(r"asked for stream group 0 at 4 Hz", 40.0)  # MAVProxy's request, seen by the vehicle
        assert t_reset is not None, "MAVProxy sent no REQUEST_DATA_STREAM within 40 s:\n" + sim.text
        time.sleep(max(0.0, t_reset + 10.0 - time.monotonic()))
        rates_after = dict(bridge.rates)
    finally:
        bridge.stop()
        thread.join(10.0)
        mp.stop()
        sim.stop()
    assert not thread.is_alive()
    # arrivals of ATTITUDE per second around the reset, as the bridge received them
    arrivals = list(bridge._arrivals["ATTITUDE"])
    per_second = collections.Counter(math.floor(t - t_reset) for t in arrivals if t_reset - 3 <= t < t_reset + 10)
    bins = [per_second.get(k, 0) for k in range(-3, 10)]
    slow = [k for k in range(0, 10) if per_second.get(k, 0) < 8]
    print(f"\nATTITUDE arrivals per second from 3 s before to 10 s after MAVProxy's REQUEST_DATA_STREAM: {bins}; "
          f"bridge rates 10 s after: {rates_after}; requests {bridge.counts['rate_requests']}, resets noticed "
          f"{bridge.counts['rate_resets']}\n" + "\n".join(lines))
    assert bridge.counts["rate_resets"] >= 1 and any("asking again" in line for line in lines)
    assert bridge.counts["rate_requests"] > len(bridge.rate_wanted)  # asked again after the first request
    assert len(slow) <= 4, bins  # back at 10 Hz within a few seconds
    for name in ("ATTITUDE", "SCALED_PRESSURE2", "SERVO_OUTPUT_RAW"):
        assert rates_after[name] is not None and rates_after[name] >= 7.5, rates_after
    assert not any("cannot get" in line for line in lines)
    assert bridge.firmware_names == "4.7" and bridge.live_gain == pytest.approx(0.5)
    assert "fence breach" not in mp.text
