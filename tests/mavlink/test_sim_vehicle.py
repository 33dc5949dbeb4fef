"""`rovlab mavlink sim` runs the one simulated vehicle of rovlab.sim.realtime (the scenario's plant,
sensors and drop-out windows), seen by an independent pymavlink ground station. The simulator is
stepped in-process with a synthetic clock, so nothing here depends on the machine's speed."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None,
                                reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import GroundStation, free_udp_port  # noqa: E402


def _scenario(**extra):
    from rovlab.sim.scenario import load_scenario_data, scenario_from_dict

    data, file = load_scenario_data("bluerov2-heavy-step")
    data = {**data, **extra}
    return scenario_from_dict(data, file=file)


def _fly(sim_vehicle, seconds: float, *, dt: float = 0.02):
    """Step an ArduSubSim on a synthetic clock; the ground station's messages with their sim time."""
    from rovlab.interfaces.mavlink.vehicle_sim import ArduSubSim

    port = free_udp_port()
    gcs = GroundStation(port)
    sim = ArduSubSim(sim_vehicle, connect=f"udpout:127.0.0.1:{port}")
    got = []
    try:
        for i in range(int(round(seconds / dt)) + 1):
            t = i * dt
            sim.step(1000.0 + t)
            gcs.seen.clear()
            gcs.pump()
            got.extend((t, m) for m in gcs.seen)
    finally:
        sim.close()
        gcs.close()
    return sim, got


def test_a_drop_out_window_of_the_scenario_silences_its_sensor_message():
    """The scenario's [[dropout]] of the Bar30 from 1 to 2 s: SCALED_PRESSURE2 stops within the
    silence allowance (two sample periods + one control period = 0.3 s) and resumes; ATTITUDE
    (the IMU, not dropped) goes on. The old MAVLink simulator had no drop-outs at all."""
    from rovlab.sim.realtime import SimulatedVehicle

    sv = SimulatedVehicle(_scenario(dropout=[{"sensor": "bar30", "start_s": 1.0, "end_s": 2.0}]))
    _, got = _fly(sv, 3.0)
    pressure = [t for t, m in got if m.get_type() == "SCALED_PRESSURE2"]
    attitude = [t for t, m in got if m.get_type() == "ATTITUDE"]
    assert any(t < 1.0 for t in pressure) and any(t > 2.1 for t in pressure)
    assert not [t for t in pressure if 1.35 <= t < 2.0], pressure
    assert len([t for t in attitude if 1.0 <= t < 2.0]) >= 20  # 25 Hz stream, IMU not dropped


def test_the_messages_carry_the_simulated_vehicles_own_samples():
    """Same seed, same scenario: the heading in ATTITUDE and the depth in SCALED_PRESSURE2 are samples
    that the SimulatedVehicle gives (its noise model), not a second noise model of the MAVLink
    simulator. A twin vehicle stepped alongside gives the values to compare with."""
    from rovlab.sim.realtime import SimulatedVehicle

    sc = _scenario()
    twin = SimulatedVehicle(sc)
    samples = {}
    for _ in range(16):
        s = twin.step()
        for _sensor, q, v in s.samples:
            samples.setdefault(q, []).append(np.float32(v))
    sim, got = _fly(SimulatedVehicle(sc), 1.5)
    rho, g = sim.sim.prep.truth.water_density, sim.sim.prep.truth.gravity
    yaws = {np.float32(m.yaw) for _, m in got if m.get_type() == "ATTITUDE"}
    depths = [(m.press_abs - 1013.25) * 100.0 / (rho * g) for _, m in got if m.get_type() == "SCALED_PRESSURE2"]
    assert yaws and yaws <= set(samples["psi"])
    assert depths and all(min(abs(d - z) for z in samples["z"]) < 1e-3 for d in depths)  # float32 hPa
    assert math.isclose(samples["z"][0], 1.0, abs_tol=0.05)  # the scenario's initial depth (1 m)


def test_initial_state_by_name_replaces_the_scenarios():
    from rovlab.sim.realtime import SimulatedVehicle

    sv = SimulatedVehicle(_scenario(), initial={"z": 3.0, "psi": math.radians(-30.0)})
    s = sv.step()
    assert s.truth["z"] == pytest.approx(3.0) and s.truth["psi"] == pytest.approx(math.radians(-30.0))
    with pytest.raises(ValueError, match="no initial state 'depth'"):
        SimulatedVehicle(_scenario(), initial={"depth": 3.0})
    with pytest.raises(ValueError, match="must be finite"):
        SimulatedVehicle(_scenario(), initial={"z": math.nan})
