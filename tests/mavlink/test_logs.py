"""MAVLink logs: a dive of `rovlab mavlink sim` recorded as a .tlog (by an independent pymavlink
ground station) and as MCAP (`rovlab mavlink record`), replayed through `rovlab filter`; the
conversion on synthetic telemetry; bad logs refused with a clear message."""

from __future__ import annotations

import csv
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from rovlab.estimation.model import build_filter_model
from rovlab.interfaces.cli import main
from rovlab.interfaces.mavlink.logs import LogError, filter_columns, read_records
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle

HAVE_PYMAVLINK = importlib.util.find_spec("pymavlink") is not None
needs_pymavlink = pytest.mark.skipif(not HAVE_PYMAVLINK, reason="needs pymavlink: pip install 'rovlab[mavlink]'")

sys.path.insert(0, str(Path(__file__).parent))
from mavclient import GroundStation, free_udp_port, start_rovlab, stop  # noqa: E402


@pytest.fixture(scope="module")
def heavy():
    v = load_vehicle("bluerov2_heavy")
    return v, build_filter_model(v, load_design_config("bluerov2_heavy"))


def _pressure(z: float) -> float:
    return 1013.25 + z * 1000.0 * 9.82 / 100.0


def test_filter_columns_on_synthetic_telemetry(heavy):
    v, model = heavy
    t0 = 1.7e9
    recs = [(t0 - 5.0, "HEARTBEAT", {"type": 6, "_sysid": 255}),  # the ground station's: ignored
            (t0, "HEARTBEAT", {"type": 12, "_sysid": 1}),
            (t0 + 0.00, "SCALED_PRESSURE2", {"press_abs": _pressure(1.0), "_sysid": 1}),
            (t0 + 0.04, "SCALED_PRESSURE2", {"press_abs": _pressure(1.1), "_sysid": 1}),  # same period: kept too
            (t0 + 0.10, "ATTITUDE", {"yaw": 0.5, "yawspeed": 0.01, "roll": 0.0, "pitch": 0.0, "_sysid": 1}),
            (t0 + 0.20, "SERVO_OUTPUT_RAW", {**{f"servo{i}_raw": 1500 for i in range(1, 5)},
                                             **{f"servo{i}_raw": 1700 for i in range(5, 9)}, "_sysid": 1}),
            (t0 + 0.30, "SCALED_PRESSURE2", {"press_abs": float("nan"), "_sysid": 1}),  # no sample: no row
            (t0 + 0.50, "SCALED_PRESSURE2", {"press_abs": _pressure(0.9), "_sysid": 1})]
    cols = filter_columns(recs, v, tuple(model.channels), 0.1)
    # a row at each time the vehicle sent something the filter uses: every sample, at its own time
    np.testing.assert_allclose(cols["time_s"], [0.0, 0.04, 0.10, 0.20, 0.50])
    z = cols["z_bar30"]
    assert z[0] == pytest.approx(1.0) and z[1] == pytest.approx(1.1) and z[4] == pytest.approx(0.9)
    assert np.isnan(z[2:4]).all()
    assert cols["psi_imu"][2] == pytest.approx(0.5) and cols["r_imu"][2] == pytest.approx(0.01)
    # vertical thrusters at 1700 us push up: Z < 0 from the SERVO_OUTPUT_RAW on, held; zero before it
    assert np.all(cols["tau_Z"][:3] == 0.0)
    assert cols["tau_Z"][3] < -10.0 and cols["tau_Z"][4] == cols["tau_Z"][3]
    assert np.all(np.abs(cols["tau_N"]) < 1e-9) and np.all(np.abs(cols["tau_X"]) < 1e-9)
    assert "tau_Y" in cols  # the whole wrench: the 4-DOF EKF replays a dive too


def test_bad_logs_are_refused_clearly(heavy, tmp_path):
    v, model = heavy
    with pytest.raises(LogError, match="no such file"):
        read_records(tmp_path / "missing.tlog")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(LogError, match="expected a .tlog"):
        read_records(tmp_path / "notes.txt")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(LogError, match="junk.mcap"):
        read_records(tmp_path / "junk.mcap")
    with pytest.raises(LogError, match="no telemetry"):
        filter_columns([(1.0, "HEARTBEAT", {"type": 12, "_sysid": 1})], v, tuple(model.channels), 0.1)


def test_filter_refuses_a_bad_mavlink_log(tmp_path, capsys):
    (tmp_path / "junk.tlog").write_bytes(b"\x00" * 64)
    code = main(["filter", str(tmp_path / "junk.tlog"), "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy",
                 "--out", str(tmp_path / "est.csv")])
    assert code == 2
    assert "junk.tlog" in capsys.readouterr().err


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(line for line in fh if not line.startswith("#"))]
    header, body = rows[0], rows[1:]
    return {h: np.array([float(r[i]) if r[i] else math.nan for r in body]) for i, h in enumerate(header)
            if not h.startswith("status_")}


@needs_pymavlink
def test_sim_dive_replays_through_rovlab_filter(tmp_path, capsys):
    """A .tlog recorded by an independent pymavlink ground station and an MCAP recorded by
    `rovlab mavlink record`, each replayed through `rovlab filter`: the depth estimate follows
    the depth the vehicle reported."""
    port = free_udp_port()
    tlog = tmp_path / "dive.tlog"
    gcs = GroundStation(port)
    gcs.record_tlog(str(tlog))
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "2", "--duration",
                       "120")
    try:
        gcs.wait_for(lambda: "HEARTBEAT" in gcs.latest or sim.poll() is not None, 90.0, what="first HEARTBEAT")
        gcs.wait_for(lambda: len(gcs.messages("SCALED_PRESSURE2")) >= 50, 60.0, what="5 s of telemetry")
    finally:
        gcs.close()
        stop(sim)
    depths = [(m.press_abs - 1013.25) * 100.0 / (1000.0 * 9.82) for m in gcs.messages("SCALED_PRESSURE2")]

    out = tmp_path / "est.csv"
    assert main(["filter", str(tlog), "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy",
                 "--out", str(out)]) == 0
    est = _read_csv(out)
    assert est["time_s"].size > 40
    # the last estimate sits within a few centimetres of the depths the vehicle reported last
    assert est["est_z"][-1] == pytest.approx(np.mean(depths[-5:]), abs=0.05)

    # the same telemetry through `rovlab mavlink record` (MCAP) in a second run
    port = free_udp_port()
    mcap = tmp_path / "dive.mcap"
    rec = start_rovlab("mavlink", "record", "--connect", f"udpin:127.0.0.1:{port}", "--out", str(mcap),
                       "--duration", "60")
    sim = start_rovlab("mavlink", "sim", "--connect", f"udpout:127.0.0.1:{port}", "--depth", "1.5",
                       "--duration", "60")
    try:
        import time

        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline and sim.poll() is None:  # until the sim has sent for a few seconds
            time.sleep(0.5)
            if mcap.exists() and mcap.stat().st_size > 20_000:
                break
        time.sleep(3.0)
    finally:
        stop(sim)
        rec_out = stop(rec)  # SIGTERM: the recorder closes the file properly
    assert "messages ->" in rec_out
    records = read_records(mcap)
    assert {"HEARTBEAT", "SCALED_PRESSURE2", "ATTITUDE", "SERVO_OUTPUT_RAW"} <= {k for _, k, _ in records}
    out2 = tmp_path / "est2.csv"
    assert main(["filter", str(mcap), "--vehicle", "bluerov2_heavy", "--config", "bluerov2_heavy",
                 "--out", str(out2)]) == 0
    est2 = _read_csv(out2)
    last = [(f["press_abs"] - 1013.25) * 100.0 / (1000.0 * 9.82) for _, k, f in records if k == "SCALED_PRESSURE2"][-5:]
    assert est2["est_z"][-1] == pytest.approx(np.mean(last), abs=0.05)


def test_filter_reads_an_mcap_with_rovlabs_topics(tmp_path):
    """An MCAP without MAVLink telemetry (a simulation's log, or a vehicle node's recording) is read
    from its rovlab topics (measurements and achieved wrench) instead."""
    pytest.importorskip("mcap")
    from rovlab.io.timeseries import write_mcap
    from rovlab.sim.runner import simulate

    res = simulate("step-process-model")
    n = 200  # 20 s
    cols = {k: np.asarray(v)[:n] for k, v in res.columns.items() if not k.startswith("status_")}
    write_mcap(tmp_path / "sim.mcap", cols, start_time_s=0.0)
    out = tmp_path / "est.csv"
    assert main(["filter", str(tmp_path / "sim.mcap"), "--config", "default", "--out", str(out)]) == 0
    est = _read_csv(out)
    assert est["time_s"].size == n
    assert est["est_z"][-1] == pytest.approx(cols["true_z"][-1], abs=0.05)
