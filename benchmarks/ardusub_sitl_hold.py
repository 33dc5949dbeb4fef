"""The bridge's depth and heading hold on ArduSub SITL (../shared/tools/ardusub-sitl; issue 30): the numbers of
docs/mavlink.md, "ArduSub SITL".

Per run: a fresh SITL (sea-level home, MANUAL) with the bridge on its first link and an independent observer on
its second (tests/mavlink/test_ardusub_sitl.py's fixture parts: SITL's true state from SIM_STATE); the bridge
dives to 1 m, 25 s to settle, then the hold over ``--hold-s``; then 1.5 m and 45 deg to starboard at once, 40 s.
Reported (one JSON line per run): the true depth's RMS about its mean over the hold, the heading's RMS about
the set-point (ATTITUDE, EKF3's yaw: what the bridge holds), the 0.5 m and 45 deg steps' time to 90 % and the
peak of their 2-s mean, and how the bridge's pulses sit against SITL's dead zone (1475-1525 us).
``--bar2-rnd`` sets SITL's SIM_BAR2_RND (its depth noise: 0.2 m default, uniform +-; a Bar30 is about 0.003);
give it a vehicle file whose pressure variance says so. SITL runs in real time: about 2.5 min a run. Not part
of ``make bench`` (it needs the SITL binary and its time).

Run: .venv/bin/python benchmarks/ardusub_sitl_hold.py [--vehicle V] [--config C] [--bar2-rnd M] [--runs N]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "mavlink"))


def one_run(vehicle: str, config: str, bar2_rnd: float, hold_s: float) -> dict:
    import test_ardusub_sitl as sitl

    work = Path(tempfile.mkdtemp(prefix="rovlab-sitl-"))
    res: dict = {"vehicle": vehicle, "config": config, "bar2_rnd_m": bar2_rnd}
    try:
        with sitl.running_sitl(work) as (bridge_port, _relay, obs):
            _fly(bridge_port, obs, vehicle, config, bar2_rnd, hold_s, res)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return res


def _fly(bridge_port: int, obs: Any, vehicle: str, config: str, bar2_rnd: float, hold_s: float, res: dict) -> None:
    from mavclient import wait_until

    from rovlab.interfaces.mavlink.bridge import MavlinkBridge
    from rovlab.params.design import load_design_config
    from rovlab.params.vehicle import load_vehicle

    if bar2_rnd != 0.2:
        time.sleep(2.0)
        obs.set_param("SIM_BAR2_RND", bar2_rnd)
    bridge = MavlinkBridge(load_vehicle(vehicle), load_design_config(config),
                           connect=f"udpin:127.0.0.1:{bridge_port}", log=lambda text: None, arm=True)
    bridge.set_reference(z=1.0)
    thread = threading.Thread(target=bridge.run, daemon=True)
    thread.start()
    try:
        assert wait_until(obs.armed_in_manual, 60.0), "SITL not armed in MANUAL"
        assert wait_until(lambda: bridge.core.last is not None and abs(bridge.core.last.x[0] - 1.0) < 0.1, 40.0)
        psi0 = float(bridge.core.reference[3])
        time.sleep(25.0)
        t0 = time.monotonic()
        time.sleep(hold_s)
        t1 = time.monotonic()
        hold, yaw, servos = obs.window("truth", t0, t1), obs.window("yaw", t0, t1), obs.window("servos", t0, t1)
        off = float(np.mean(hold[:, 1])) - 1.0  # BARO2_GND_PRESS was taken floating below the surface
        res["hold_rms_cm"] = 100 * float(np.std(hold[:, 1]))
        res["heading_rms_deg"] = float(np.sqrt(np.mean(np.degrees(np.angle(np.exp(1j * (yaw[:, 1] - psi0)))) ** 2)))
        pulses = servos[:, 1:9]
        res["pulses_inside_dead_zone"] = int(np.sum((pulses > 1475) & (pulses < 1525) & (pulses != 1500)))
        res["pulses"] = int(pulses.size)
        res["verticals_at_1526us"] = float(np.mean(pulses[:, 4:8] == 1526))
        bridge.set_reference(z=1.5, psi=math.remainder(psi0 + math.radians(45.0), 2 * math.pi))
        t2 = time.monotonic()
        time.sleep(40.0)
        t3 = time.monotonic()
        after, yaw2 = obs.window("truth", t2, t3), obs.window("yaw", t2, t3)
    finally:
        bridge.stop()
        thread.join(15.0)
    z = after[:, 1] - off
    res["step_peak_2s_pct"] = float((np.convolve(z, np.ones(20) / 20, "valid").max() - 1.5) / 0.5 * 100)
    k = np.nonzero(z >= 1.45)[0]
    res["step_t90_s"] = float(after[k[0], 0] - t2) if len(k) else None
    turned = np.degrees(np.unwrap(yaw2[:, 1]) - psi0)
    turned -= 360.0 * np.round(turned[0] / 360.0)
    res["yaw_peak_2s_pct"] = float((np.convolve(turned, np.ones(20) / 20, "valid").max() - 45.0) / 45.0 * 100)
    k = np.nonzero(turned >= 40.5)[0]
    res["yaw_t90_s"] = float(yaw2[k[0], 0] - t2) if len(k) else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="ardusub_sitl_heavy", help="vehicle name or file")
    ap.add_argument("--config", default="ardusub_sitl_heavy", help="configuration name or file")
    ap.add_argument("--bar2-rnd", type=float, default=0.2, help="SITL's SIM_BAR2_RND [m] (0.2: SITL's default)")
    ap.add_argument("--hold-s", type=float, default=60.0)
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()
    import test_ardusub_sitl as sitl

    if not sitl.SITL_BIN.exists():
        print(f"no ArduSub SITL at {sitl.SITL_DIR}", file=sys.stderr)
        return 2
    for _ in range(args.runs):
        print(json.dumps(one_run(args.vehicle, args.config, args.bar2_rnd, args.hold_s)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
