"""A small, independent MAVLink ground station for the tests: only pymavlink and the standard
library, no rovlab code, so what it sees is what any other ground station would see."""

from __future__ import annotations

import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")


def wait_until(test: Callable[[], bool], timeout: float) -> bool:
    """Poll ``test`` every 50 ms until it is true (True) or ``timeout`` seconds pass (False)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if test():
            return True
        time.sleep(0.05)
    return False


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_rovlab(*args: str) -> subprocess.Popen:
    """`rovlab ARGS...` in its own process (output to a pipe read at the end)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "rovlab.interfaces.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> str:
    """Stop a process started here with SIGTERM (SIGKILL if it does not go); returns its output."""
    if proc.poll() is None:
        proc.terminate()
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate(timeout=timeout)
    return out or ""


class GroundStation:
    """udpin on 127.0.0.1:port (the vehicle udpout-s to it), keeping the latest message of each type."""

    def __init__(self, port: int, *, sysid: int = 255, compid: int = 190) -> None:
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=sysid,
                                               source_component=compid, dialect="ardupilotmega")
        self.latest: dict[str, Any] = {}
        self.seen: list[Any] = []  # every message since the last clear()

        self._tlog: Any = None

    def record_tlog(self, path: str) -> None:
        """Write what arrives as a .tlog (8-byte big-endian UNIX time in us, then the raw message),
        the format ground stations record (pymavlink's UDP reader does not log by itself)."""
        self._tlog = open(path, "wb")  # noqa: SIM115 - closed in close()

    def close(self) -> None:
        if self._tlog is not None:
            self._tlog.close()
        self.conn.close()

    def pump(self, seconds: float = 0.0) -> None:
        """Read everything that arrives for `seconds` (at least what is queued now)."""
        end = time.monotonic() + seconds
        while True:
            msg = self.conn.recv_match(blocking=True, timeout=0.02)
            if msg is not None and msg.get_type() != "BAD_DATA":
                self.latest[msg.get_type()] = msg
                self.seen.append(msg)
                if self._tlog is not None:
                    self._tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + msg.get_msgbuf())
            if msg is None and time.monotonic() >= end:
                return

    def wait_for(self, test: Callable[[], bool], timeout: float, *, every: Callable[[], None] | None = None,
                 what: str = "condition") -> float:
        """Pump until test() holds; returns the seconds it took; fails after timeout."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if every is not None:
                every()
            self.pump(0.05)
            if test():
                return time.monotonic() - t0
        raise AssertionError(f"{what} not seen within {timeout} s")

    def messages(self, kind: str) -> list[Any]:
        return [m for m in self.seen if m.get_type() == kind]
