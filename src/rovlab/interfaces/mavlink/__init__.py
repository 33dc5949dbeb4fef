"""MAVLink for stock BlueROV2s (ArduSub): a vehicle simulator, a bridge to rovlab's node core and
log conversion. See docs/mavlink.md.

pymavlink is an optional dependency (``pip install 'rovlab[mavlink]'``) imported only through
:func:`mavutil`, so importing this package (and ``rovlab`` itself) stays fast without it. Every
MAVLink unit (centidegrees, hPa, millivolts, microseconds, the normalised joystick ranges) is
converted to SI at this edge by :mod:`rovlab.interfaces.mavlink.units`.
"""

from __future__ import annotations

import os
from typing import Any


class MavlinkMissing(RuntimeError):
    """pymavlink is not installed."""


def mavutil() -> Any:
    """pymavlink's ``mavutil`` set up for MAVLink 2 and the ardupilotmega dialect (ArduSub's)."""
    os.environ.setdefault("MAVLINK20", "1")
    os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")
    try:
        from pymavlink import mavutil as mu
    except ImportError:
        raise MavlinkMissing("MAVLink needs pymavlink: pip install 'rovlab[mavlink]'") from None
    return mu


def dialect() -> Any:
    """The ardupilotmega MAVLink 2 message module (constants, message classes)."""
    mavutil()
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega
