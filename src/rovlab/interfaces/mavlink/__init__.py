"""MAVLink for stock BlueROV2s (ArduSub): a vehicle simulator, a bridge to rovlab's node core and
log conversion. See docs/mavlink.md.

pymavlink is an optional dependency (``pip install 'rovlab[mavlink]'``) imported only through
:func:`mavutil`, so importing this package (and ``rovlab`` itself) stays fast without it. Every
MAVLink unit (centidegrees, hPa, millivolts, microseconds, the normalised joystick ranges) is
converted to SI at this edge by :mod:`rovlab.interfaces.mavlink.units`.

pymavlink chooses its wire protocol and dialect from two environment variables (``MAVLINK20``,
``MAVLINK_DIALECT``; its import sets the second when it is missing) and a module-wide dialect
(``mavutil.set_dialect``). rovlab speaks MAVLink 2 with ArduSub's dialect (ardupilotmega) on every
connection it opens (:func:`connection`) and leaves both as it found them: the environment
variables and pymavlink's dialect are what they were before, for the user's own pymavlink code.
"""

from __future__ import annotations

import os
import threading
from typing import Any

_ENV = ("MAVLINK20", "MAVLINK_DIALECT")
_LOCK = threading.RLock()  # the environment and pymavlink's dialect are process-wide


class MavlinkMissing(RuntimeError):
    """pymavlink is not installed."""


def _restore(before: dict[str, str | None]) -> None:
    for key, value in before.items():
        if value is None:
            os.environ.pop(key, None)
        elif os.environ.get(key) != value:
            os.environ[key] = value


def mavutil() -> Any:
    """pymavlink's ``mavutil`` module, imported with the environment left as it was. Open
    connections with :func:`connection` (MAVLink 2, ardupilotmega), not its mavlink_connection."""
    with _LOCK:
        before = {k: os.environ.get(k) for k in _ENV}
        try:
            from pymavlink import mavutil as mu
        except ImportError:
            raise MavlinkMissing("MAVLink needs pymavlink: pip install 'rovlab[mavlink]'") from None
        finally:
            _restore(before)
    return mu


def connection(url: str, **kwargs: Any) -> Any:
    """``mavutil.mavlink_connection(url, **kwargs)`` speaking MAVLink 2 with the ardupilotmega
    dialect (ArduSub's), whatever the process's pymavlink settings; those are restored after.

    A connection keeps the message module it was made with, so it stays MAVLink 2 / ardupilotmega
    afterwards (and never switches itself: pymavlink switches, and sets ``MAVLINK20``, only on a
    connection that started at MAVLink 1)."""
    mu = mavutil()
    with _LOCK:
        before = {k: os.environ.get(k) for k in _ENV}
        previous = mu.current_dialect
        os.environ["MAVLINK20"] = "1"
        try:
            mu.set_dialect("ardupilotmega")
            return mu.mavlink_connection(url, **kwargs)
        finally:
            _restore(before)
            mu.set_dialect(previous)  # with the user's environment: the module they had


def dialect() -> Any:
    """The ardupilotmega MAVLink 2 message module (constants, message classes)."""
    mavutil()
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega
