"""The bridge on ArduSub itself: ArduPilot's ArduSub firmware built for SITL (../shared/tools/ardusub-sitl,
its README), with its own simulated submarine, sensors and EKF3 -- the closest a test gets to a BlueROV2.

SITL sends its first MAVLink link to the bridge through a relay this test can cut (telemetry loss) and
its second link (``--serial1``) to an independent observer: pymavlink only, no rovlab code, which reads
SITL's true state (SIM_STATE), the vehicle's mode, arming and motor outputs, and sets SITL's parameters
(SIM_BAR2_GLITCH: the water-pressure sensor's altitude glitch; 584 m reproduces what a SITL home 584 m
above sea level gives, SCALED_PRESSURE2 = -57 600 hPa, issue 30). The bridge flies the vehicle file and
configuration ardusub_sitl_heavy (SITL's own physics). Skipped, with the reason, when the SITL binary is
not there (a user's clone). SITL runs in real time: each test takes tens of seconds.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

SITL_DIR = Path(os.environ.get("ROVLAB_ARDUSUB_SITL", Path(__file__).resolve().parents[2].parent / "shared" / "tools"
                               / "ardusub-sitl"))
SITL_BIN = SITL_DIR / "ardusub"
SITL_PARAMS = SITL_DIR / "sub-6dof.parm"

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                       reason="needs pymavlink: pip install 'rovlab[mavlink]'"),
    pytest.mark.skipif(not (os.access(SITL_BIN, os.X_OK) and SITL_PARAMS.is_file()),
                       reason=f"no ArduSub SITL at {SITL_DIR} (ArduPilot's ArduSub built for SITL and sub-6dof.parm; "
                              "set ROVLAB_ARDUSUB_SITL to its folder)"),
]

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import wait_until  # noqa: E402

MANUAL = 19  # ArduSub's mode number
ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _free_instance() -> int:
    """A SITL instance number (-I) whose fixed ports (UDP 5501 + 10 I: its physics input, TCP 5763 + 10 I:
    SERIAL2) nobody holds."""
    for inst in range(40, 90):
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u, socket.socket() as t:
                u.bind(("0.0.0.0", 5501 + 10 * inst))
                t.bind(("0.0.0.0", 5763 + 10 * inst))
            return inst
        except OSError:
            continue
    raise RuntimeError("no free ArduSub SITL instance number in 40 .. 89")


class Relay:
    """SITL's first link to the bridge, on loopback, which the test can cut one way or both."""

    def __init__(self, bridge_port: int) -> None:
        self.vehicle_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # SITL's udpclient sends here
        self.vehicle_side.bind(("127.0.0.1", 0))
        self.port = self.vehicle_side.getsockname()[1]
        self.bridge_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # to the bridge's udpin
        self.bridge_side.bind(("127.0.0.1", 0))
        self.bridge = ("127.0.0.1", bridge_port)
        self.vehicle: tuple[str, int] | None = None
        self.up = True  # telemetry: vehicle -> bridge
        self.down = True  # commands: bridge -> vehicle
        self.dropped = 0
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._pump, args=(self.vehicle_side, True), daemon=True),
                         threading.Thread(target=self._pump, args=(self.bridge_side, False), daemon=True)]
        for s in (self.vehicle_side, self.bridge_side):
            s.settimeout(0.1)
        for t in self._threads:
            t.start()

    def _pump(self, sock: socket.socket, upwards: bool) -> None:
        while not self._stop.is_set():
            try:
                data, addr = sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            if upwards:
                self.vehicle = addr
                if self.up:
                    self.bridge_side.sendto(data, self.bridge)
                else:
                    self.dropped += 1
            elif self.down and self.vehicle is not None:
                self.vehicle_side.sendto(data, self.vehicle)

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2.0)
        self.vehicle_side.close()
        self.bridge_side.close()


class Observer:
    """SITL's second link: true state, mode, arming, motor outputs and messages, on its own thread."""

    def __init__(self, port: int) -> None:
        os.environ.setdefault("MAVLINK20", "1")
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=250, source_component=190,
                                               dialect="ardupilotmega")
        self.lock = threading.Lock()
        self.truth: list[tuple[float, float, float]] = []  # (time, true depth [m], true yaw [rad])
        self.position: list[tuple[float, int, int]] = []  # (time, true latitude, longitude [1e-7 deg]): SIM_STATE
        self.yaw: list[tuple[float, float]] = []  # ATTITUDE: the autopilot's heading, which the bridge holds
        self.servos: list[tuple[float, tuple[int, ...]]] = []
        self.heartbeat: tuple[float, int, int] | None = None  # (time, base_mode, custom_mode)
        self.texts: list[str] = []
        self.params: dict[str, float] = {}
        self.sysid: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        asked = 0.0
        beat = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if self.sysid is not None and now > beat:
                beat = now + 1.0
                self.conn.mav.heartbeat_send(6, 8, 0, 0, 4)  # a ground station, not the vehicle's (MAV_GCS_SYSID)
                if now > asked:  # SIM_STATE, ATTITUDE, SERVO_OUTPUT_RAW on this link; again now and then
                    asked = now + 5.0
                    for msg_id, hz in ((108, 10), (30, 10), (36, 10)):
                        self.conn.mav.command_long_send(self.sysid, 1, 511, 0, msg_id, int(1e6 / hz), 0, 0, 0, 0, 0)
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            kind = msg.get_type()
            t = time.monotonic()
            with self.lock:
                if kind == "HEARTBEAT" and msg.type == 12:
                    self.sysid = msg.get_srcSystem()
                    self.heartbeat = (t, msg.base_mode, msg.custom_mode)
                elif kind == "SIM_STATE":
                    self.truth.append((t, -msg.alt, msg.yaw))  # home at sea level: depth = -altitude
                    self.position.append((t, msg.lat_int, msg.lon_int))
                elif kind == "ATTITUDE":
                    self.yaw.append((t, msg.yaw))
                elif kind == "SERVO_OUTPUT_RAW":
                    self.servos.append((t, tuple(getattr(msg, f"servo{i}_raw") for i in range(1, 9))))
                elif kind == "STATUSTEXT":
                    self.texts.append(str(msg.text))
                elif kind == "PARAM_VALUE":
                    self.params[str(msg.param_id).split("\x00", 1)[0]] = float(msg.param_value)

    def set_param(self, name: str, value: float, timeout: float = 10.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.conn.mav.param_set_send(self.sysid or 1, 1, name.encode(), value, 9)
            if wait_until(lambda: self.params.get(name) == pytest.approx(value), 1.0):
                return
        raise AssertionError(f"SITL did not take {name} = {value}")

    def armed_in_manual(self) -> bool:
        hb = self.heartbeat
        return hb is not None and time.monotonic() - hb[0] < 3.0 and bool(hb[1] & ARMED) and hb[2] == MANUAL

    def disarmed(self) -> bool:
        hb = self.heartbeat
        return hb is not None and not hb[1] & ARMED

    def window(self, series: str, t0: float, t1: float) -> np.ndarray:
        with self.lock:
            rows = list(getattr(self, series))
        if series == "servos":
            return np.array([[t, *s] for t, s in rows if t0 <= t < t1])
        return np.array([r for r in rows if t0 <= r[0] < t1])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


@contextlib.contextmanager
def running_sitl(work: Path) -> Iterator[tuple[int, Relay, Observer]]:
    """ArduSub SITL at sea level running in ``work`` (it writes eeprom.bin and logs/ there), its first
    link through a relay to a free port for the bridge, its second to an observer: (bridge port,
    relay, observer). Stopped, and its logs/ removed, on leaving. Also benchmarks/ardusub_sitl_hold.py's."""
    bridge_port = _free_udp_port()
    relay = Relay(bridge_port)
    obs_port = _free_udp_port()
    observer = Observer(obs_port)
    log = open(work / "sitl.log", "w")  # noqa: SIM115 - closed below
    proc = subprocess.Popen([str(SITL_BIN), "-w", "--model", "vectored_6dof", "--speedup", "1",
                             "--home=-35.363261,149.165230,0,0", "--defaults", str(SITL_PARAMS),
                             f"-I{_free_instance()}", "--serial0", f"udpclient:127.0.0.1:{relay.port}",
                             "--serial1", f"udpclient:127.0.0.1:{obs_port}"],
                            cwd=work, stdout=log, stderr=subprocess.STDOUT)
    try:
        assert wait_until(lambda: observer.heartbeat is not None, 60.0), f"ArduSub SITL sent nothing ({work / 'sitl.log'})"
        yield bridge_port, relay, observer
    finally:
        proc.terminate()
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)
        observer.close()
        relay.close()
        log.close()
        shutil.rmtree(work / "logs", ignore_errors=True)


@pytest.fixture(scope="module")
def sitl(tmp_path_factory):
    """One ArduSub SITL at sea level for the module: (bridge port, relay, observer)."""
    with running_sitl(tmp_path_factory.mktemp("ardusub-sitl")) as running:
        yield running


def assert_stopped_and_disarmed(bridge: Any, thread: threading.Thread, observer: Observer) -> None:
    """After bridge.stop(): its thread ended, ArduSub disarmed, the last inputs it sent neutral."""
    thread.join(15.0)
    assert not thread.is_alive()
    assert wait_until(observer.disarmed, 10.0), observer.heartbeat
    assert bridge.sent and bridge.sent[-1][2]


def _bridge(port: int, lines: list[str], **kw: Any):
    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    def log(text: str) -> None:
        lines.append(f"{time.monotonic():.2f} {text}")

    return MavlinkBridge(load_vehicle("ardusub_sitl_heavy"), load_design_config("ardusub_sitl_heavy"),
                         connect=f"udpin:127.0.0.1:{port}", log=log, arm=True, **kw)


def _held(bridge) -> bool:
    return bool(bridge.core.engaged and bridge.core.last is not None and bridge.core.last.engaged)


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    return np.convolve(x, np.ones(n) / n, mode="valid")


def test_bridge_arms_holds_depth_and_heading_follows_a_step_and_disarms_on_exit(sitl, tmp_path):
    port, relay, observer = sitl
    lines: list[str] = []
    record = tmp_path / "dive.mcap"
    bridge = _bridge(port, lines, record=str(record))
    bridge.set_reference(z=1.0)  # waits for the vehicle: armed in MANUAL
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        assert wait_until(observer.armed_in_manual, 60.0), "\n".join(lines[-20:])
        assert wait_until(lambda: _held(bridge), 5.0), "\n".join(lines[-20:])
        psi0 = float(bridge.core.reference[3])
        # dive from the surface (SITL floats 0.13 m deep) and settle, then hold for 15 s
        assert wait_until(lambda: abs(bridge.core.last.x[0] - 1.0) < 0.1, 30.0), "did not reach 1 m"
        time.sleep(8.0)
        # the heading too: the dive swings it 6-10 deg off, back within 3 deg 30-40 s after reaching the depth
        # (measured, docs/mavlink.md: a yaw demand inside the thrusters' dead-zone gap waits for the filter's
        # yaw bias to carry it across)
        assert wait_until(lambda: abs(math.remainder(bridge.core.last.x[1] - psi0, 2 * math.pi)) < math.radians(1.5),
                          45.0), "heading not back within 1.5 deg"
        t0 = time.monotonic()
        time.sleep(15.0)
        hold = observer.window("truth", t0, time.monotonic())
        yaw = observer.window("yaw", t0, time.monotonic())
        servos = observer.window("servos", t0, time.monotonic())
        depth_rms = float(np.std(hold[:, 1]))
        heading_err = np.degrees(np.angle(np.exp(1j * (yaw[:, 1] - psi0))))
        # measured on this SITL (docs/mavlink.md): 2.9-3.1 cm and 0.9-1.5 deg RMS over 60 s in 4 runs (depth
        # z max 1.5 m in the configuration: 3.2-4.2 cm, 15-s windows of them 1.5-5.0 cm); SIM_Submarine as the
        # BlueROV2 Heavy (the model the bridge used to fly it on): 14 cm; SCALED_PRESSURE2 alone scatters 11.7 cm
        assert depth_rms < 0.06, f"true depth scatters {depth_rms * 100:.1f} cm RMS in 15 s"
        assert float(np.sqrt(np.mean(heading_err ** 2))) < 2.0, heading_err
        # SITL's thrusters give nothing within 1475-1525 us (SIM_Submarine's ESC dead zone) and the bridge
        # commands no pulse there but neutral: the cut dead band's inverse rounds a demand in the gap to 1500 or
        # to the least pulse outside it, 1526 / 1474 us (hovering takes 0.157 N per vertical, 1526 us gives
        # 0.2175 N). Measured: 0 of 4800 pulses inside in each of 10 runs, 1526 us on the verticals 13-38 % of
        # the time
        pulses = servos[:, 1:]
        assert len(pulses) > 50 and not np.any((pulses > 1475) & (pulses < 1525) & (pulses != 1500)), pulses
        assert np.any(pulses[:, 4:8] == 1526), pulses
        surface_offset = float(np.mean(hold[:, 1])) - 1.0  # BARO2_GND_PRESS was taken floating 0.13-0.16 m deep
        assert 0.05 < surface_offset < 0.25, surface_offset

        # a 0.5 m deeper, 45 deg to starboard
        bridge.set_reference(z=1.5, psi=math.remainder(psi0 + math.radians(45.0), 2 * math.pi))
        t1 = time.monotonic()
        time.sleep(22.0)
        after = observer.window("truth", t1, time.monotonic())
        yaw = observer.window("yaw", t1, time.monotonic())
        z = after[:, 1] - surface_offset
        turned = np.degrees(np.unwrap(yaw[:, 1]) - psi0)
        turned -= 360.0 * np.round(turned[0] / 360.0)
        last5 = after[:, 0] > after[-1, 0] - 5.0
        assert abs(float(np.mean(z[last5])) - 1.5) < 0.06, z[last5]
        assert abs(float(np.mean(turned[yaw[:, 0] > yaw[-1, 0] - 5.0])) - 45.0) < 3.0, turned[-20:]
        # overshoot of the 2-s mean, measured 7.1-7.4 % / below 1 % (z max 1.5 m: 8.5-11.5 % / 0.6-3.9 %): with
        # SITL's depth noise it is the hold's scatter (with a Bar30's, SIM_BAR2_RND 0.003: 0.4-1.6 %); docs/mavlink.md
        assert float(np.max(_smooth(z, 20))) < 1.5 + 0.5 * 0.20
        assert float(np.max(_smooth(turned, 20))) < 45.0 * 1.08
        assert observer.armed_in_manual()
    finally:
        bridge.stop()
    assert_stopped_and_disarmed(bridge, thread, observer)  # disarmed on exit, and the last inputs neutral
    assert bridge.counts["failsafes"] == 0 and bridge.counts["implausible_depth"] == 0

    # the recording replays through rovlab filter to the estimates the bridge made live
    est = tmp_path / "est.csv"
    out = subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", "filter", str(record), "--vehicle",
                          "ardusub_sitl_heavy", "--config", "ardusub_sitl_heavy", "--out", str(est)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    _replay_agrees(record, est)


def _replay_agrees(record: Path, est: Path) -> None:
    import csv
    import json

    from mcap.reader import make_reader

    live = []
    with open(record, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/rovlab/estimate"]):
            d = json.loads(m.data)
            live.append((d["t"], d["state"]["z"], d["state"]["psi"]))
    lv = np.array(live)
    with open(est, newline="") as f:
        rows = list(csv.DictReader(f))
    rp = np.array([[float(r["time_s"]), float(r["est_z"]), float(r["est_psi"])] for r in rows])
    # the two clocks start at different samples (live: the first sample pushed, here while SITL boots; the
    # replay: the recording's first row): line them up first (measured: within 1 s)
    held = (lv[:, 0] > 20.0) & (lv[:, 0] < rp[-1, 0] - 2.0)

    def apart(shift: float) -> float:
        z = np.interp(lv[held, 0] + shift, rp[:, 0], rp[:, 1])
        return float(np.sqrt(np.mean((z - lv[held, 1]) ** 2)))

    shift = min(np.arange(-2.0, 2.0001, 0.05), key=apart)
    psi = np.interp(lv[held, 0] + shift, rp[:, 0], np.unwrap(rp[:, 2]))
    # measured: 1.2 cm and 0.2 deg RMS apart (the live filter stamps samples on arrival, the replay on the
    # recording's clock)
    assert apart(shift) < 0.03, (shift, apart(shift))
    assert float(np.degrees(np.sqrt(np.mean(np.angle(np.exp(1j * (psi - lv[held, 2]))) ** 2)))) < 1.0


def test_telemetry_loss_and_an_implausible_depth_sensor_give_neutral_never_a_predicted_depth(sitl):
    port, relay, observer = sitl
    lines: list[str] = []
    bridge = _bridge(port, lines)
    bridge.set_reference(z=1.0)
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: observer.armed_in_manual() and _held(bridge), 60.0), "\n".join(lines[-20:])
        assert wait_until(lambda: abs(bridge.core.last.x[0] - 1.0) < 0.15, 30.0)

        # telemetry lost for 2 s (commands still reach the vehicle): neutral, then the hold resumes
        relay.up = False
        t0 = time.monotonic()
        assert wait_until(lambda: bridge.failsafe, 2.0)
        time.sleep(2.0 - (time.monotonic() - t0))
        relay.up = True
        servos = observer.window("servos", t0 + 1.0, t0 + 2.0)  # the last second of the gap
        assert len(servos) and np.all(servos[:, 1:] == 1500), servos
        assert wait_until(lambda: not bridge.failsafe and _held(bridge), 5.0), "\n".join(lines[-10:])
        assert bridge.counts["failsafes"] == 1 and observer.armed_in_manual()  # ArduSub's own failsafe kept quiet

        # the water-pressure sensor reads as at a home 584 m above sea level: about -57 600 hPa
        observer.set_param("SIM_BAR2_GLITCH", 584.0)
        t1 = time.monotonic()
        assert wait_until(lambda: bridge.depth_problem is not None and not bridge.core.engaged, 3.0), "\n".join(lines[-10:])
        time.sleep(4.0)
        text = "\n".join(lines)
        said = re.search(r"DEPTH SENSOR: SCALED_PRESSURE2 press_abs = (-5\d{4}\.\d*) hPa is implausible: depth "
                         r"(-\d+)\.\d m", text)
        assert said and -600 < int(said.group(2)) < -550, text  # named, and the depth it would mean
        assert bridge.counts["implausible_depth"] > 20
        during = [s for s in bridge.sent if s[0] > t1 + 1.0]
        assert during and all(neutral for _t, _v, neutral in during)  # nothing flown on the predicted depth
        servos = observer.window("servos", t1 + 1.5, time.monotonic())
        assert len(servos) and np.all(servos[:, 1:] == 1500), servos
        assert observer.armed_in_manual()

        # back to plausible: the filter takes the sensor back and the hold resumes, on the same set-point
        observer.set_param("SIM_BAR2_GLITCH", 0.0)
        assert wait_until(lambda: bridge.depth_problem is None and _held(bridge), 20.0), "\n".join(lines[-10:])
        assert float(bridge.core.reference[2]) == 1.0
    finally:
        relay.up = True
        observer.set_param("SIM_BAR2_GLITCH", 0.0)
        bridge.stop()
        thread.join(15.0)
    assert not thread.is_alive()
    assert wait_until(observer.disarmed, 10.0)
