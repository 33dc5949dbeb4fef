"""rovlab's MAVLink edge leaves the process as it found it (DEVELOPERS.md: a library does not own the
process): pymavlink reads its wire protocol and dialect from the environment variables MAVLINK20
and MAVLINK_DIALECT and keeps a module-wide dialect; rovlab opened its connections by setting the
variables (os.environ.setdefault) and left them set for the rest of the user's process. Each case
runs in a fresh interpreter, with and without a user's own settings."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

SMALL_TLOG = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ardusub" / "small.tlog"

PROBE = r"""
import json, os, sys
keys = ("MAVLINK20", "MAVLINK_DIALECT")
before = {k: os.environ.get(k) for k in keys}
from rovlab.interfaces.mavlink import connection, mavutil
mu = mavutil()
after_import = {k: os.environ.get(k) for k in keys}
user_dialect = (mu.current_dialect, mu.mavlink.__name__)
# a link as the bridge and the simulator open it, and a log as rovlab filter reads it
conn = connection("udpin:127.0.0.1:0", source_system=255, source_component=191)
link = (type(conn.mav).__module__, conn.WIRE_PROTOCOL_VERSION)
conn.close()
tlog = sys.argv[1]
read = 0
if tlog:
    from rovlab.interfaces.mavlink.logs import read_records
    read = len(read_records(tlog))
print(json.dumps({"before": before, "after_import": after_import, "after": {k: os.environ.get(k) for k in keys},
                  "user_dialect": user_dialect, "dialect_after": [mu.current_dialect, mu.mavlink.__name__],
                  "link": link, "read": read}))
"""


def _probe(env_extra: dict[str, str], tlog: str = "") -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MAVLINK20", "MAVLINK_DIALECT")}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", PROBE, tlog], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_no_settings_of_the_user_stay_none_and_links_speak_mavlink2_ardupilotmega():
    tlog = str(SMALL_TLOG) if SMALL_TLOG.is_file() else ""
    r = _probe({}, tlog)
    assert r["before"] == {"MAVLINK20": None, "MAVLINK_DIALECT": None}
    assert r["after_import"] == r["before"] and r["after"] == r["before"], r  # was MAVLINK20=1, ardupilotmega
    assert r["dialect_after"] == list(r["user_dialect"]), r  # pymavlink's own default (v1, "all") kept
    assert r["link"] == ["pymavlink.dialects.v20.ardupilotmega", "2.0"], r
    if tlog:
        assert r["read"] > 1000  # the real ArduSub log (MAVLink 2) still reads through the kept dialect


def test_a_users_own_pymavlink_settings_are_kept():
    r = _probe({"MAVLINK_DIALECT": "common"})
    assert r["after"] == {"MAVLINK20": None, "MAVLINK_DIALECT": "common"}, r
    assert r["user_dialect"] == ["common", "pymavlink.dialects.v10.common"]
    assert r["dialect_after"] == r["user_dialect"], r
    assert r["link"] == ["pymavlink.dialects.v20.ardupilotmega", "2.0"], r
