"""A corrupted time stamp in a MAVLink log (issue 28, fuzzing campaign): one message of a .tlog
whose 8-byte time stamp says 12 days or 3 years later (or 1970, or the largest uint64) made
`rovlab filter` lay a 0.1 s grid over the whole span (minutes; MemoryError of 7.45 GiB). The
converter now writes a row per message time (e2ac106), so the work is bounded; what is left: the
message is named and left out (its time is unknown, the messages around it agree), the dive is
filtered as if it were not there, and a real jump of the clock is a gap the filter restarts after,
reported at its time in the log (not at a line of the converted file, which the user never sees)."""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path

import numpy as np
import pytest

from rovlab.estimation.model import build_filter_model
from rovlab.interfaces.cli import main
from rovlab.interfaces.mavlink.logs import filter_columns, stamp_outliers, write_filter_log
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "ardusub"
TLOG = DATA / "small.tlog"
real_log = pytest.mark.skipif(importlib.util.find_spec("pymavlink") is None or not TLOG.is_file(),
                              reason=f"needs pymavlink (pip install 'rovlab[mavlink]') and the real log {TLOG}")

DAY, YEAR = 86400.0, 365 * 86400.0


@pytest.fixture(scope="module")
def heavy():
    v = load_vehicle("bluerov2_heavy")
    return v, build_filter_model(v, load_design_config("bluerov2_heavy"))


def _dive(n: int = 200, t0: float = 1.7e9) -> list:
    """20 Hz ATTITUDE and 2 Hz SCALED_PRESSURE2 of one vehicle, in the order a ground station writes them."""
    recs = [(t0, "HEARTBEAT", {"type": 12, "_sysid": 1})]
    for i in range(n):
        t = t0 + 0.05 * i
        recs.append((t, "ATTITUDE", {"yaw": 0.01 * i, "yawspeed": 0.2, "roll": 0.0, "pitch": 0.0, "_sysid": 1}))
        if i % 10 == 0:
            recs.append((t + 0.001, "SCALED_PRESSURE2", {"press_abs": 1013.25 + 9.82, "_sysid": 1}))
    return recs


def test_stamp_outliers_finds_the_stamps_that_leave_the_file_order_and_come_back():
    t = [0.0, 0.1, 0.2, 5e6, 0.3, 0.4]
    assert stamp_outliers(t, 1000.0) == [3]
    assert stamp_outliers([9e9, 0.0, 0.1, 0.2], 1000.0) == [0]  # the first message, judged by the ones after it
    assert stamp_outliers([0.0, 0.1, -3e7, float("nan"), 0.2, 0.3], 1000.0) == [2, 3]  # a short run
    # a jump that the later messages keep is a gap, not a corrupted stamp
    assert stamp_outliers([0.0, 0.1, 5000.0, 5000.1, 5000.2], 1000.0) == []
    assert stamp_outliers([0.0, 0.1, 0.2], 1000.0) == []


@pytest.mark.parametrize("stamp", [12 * DAY, 3 * YEAR, -1.7e9, 1.8446744073709552e13 - 1.7e9],
                         ids=["12 days later", "3 years later", "1970", "largest uint64 us"])
def test_one_corrupted_stamp_is_named_and_left_out(heavy, tmp_path, stamp):
    v, model = heavy
    recs = _dive()
    clean = filter_columns(recs, v, tuple(model.channels), model.h)
    t, kind, fields = recs[58]
    assert kind == "ATTITUDE"
    recs[58] = (t + stamp, kind, fields)
    summary = write_filter_log("dive.tlog", v, model, tmp_path / "in.csv", records=recs)
    assert summary["rows"] == clean["time_s"].size - 1  # its sample alone is left out
    assert [(n, k) for n, k, *_ in summary["left_out"]] == [(59, "ATTITUDE")]  # message 59 of the log, 1-based
    assert summary["left_out"][0][2] == t + stamp
    from rovlab.io.logreader import read_log

    got = read_log(tmp_path / "in.csv")
    assert got.time[-1] == pytest.approx(clean["time_s"][-1])  # the span of the dive, not of the stamp


@pytest.mark.parametrize("stamp", [12 * DAY, 3 * YEAR, -1.7e9], ids=["12 days later", "3 years later", "1970"])
@real_log
def test_rovlab_filter_on_small_tlog_with_one_corrupted_stamp(tmp_path, capsys, stamp, my_rov):
    """The real log (small.tlog, 35 912 messages) with message 5001 (an ATTITUDE at 1683220569.174)
    re-stamped: exit 0, the message named with its stamp and left out, every other sample filtered
    over the log's 263.4 s, no restart."""
    bad = tmp_path / "bad.tlog"
    _write_tlog(TLOG, bad, {5000: stamp})
    est = tmp_path / "est.csv"
    code = main(["filter", str(bad), "--vehicle", str(my_rov), "--config", "bluerov2_heavy", "--out", str(est)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "bad.tlog: message 5001 (ATTITUDE)" in err and "left out" in err and "expected" in err, err
    assert "restarted" not in out, out
    assert "filtered 6154 samples (263.406 s)" in out, out  # small.tlog: 6155 rows, one left out
    assert "imu.psi          5232 samples" in out


@real_log
def test_a_real_clock_jump_restarts_the_filter_at_its_time(tmp_path, capsys, my_rov):
    """Every message from 5001 on 2000 s later (the ground station's clock set forward): a gap longer
    than --max-gap-steps (1000 s at h = 0.1 s), so the filter restarts there; the report gives the
    time in the log (message 5001 was 28.119 s after the first message the filter uses), not a line of
    the converted file."""
    bad = tmp_path / "jump.tlog"
    _write_tlog(TLOG, bad, {i: 2000.0 for i in range(5000, 40000)})
    est = tmp_path / "est.csv"
    code = main(["filter", str(bad), "--vehicle", str(my_rov), "--config", "bluerov2_heavy", "--out", str(est)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "left out" not in err
    restart = [line for line in out.splitlines() if "restarted" in line]
    assert len(restart) == 1 and "t = 2028.12 s" in restart[0] and "line" not in restart[0], out


@pytest.fixture(scope="module")
def my_rov(tmp_path_factory):
    out = tmp_path_factory.mktemp("vehicle") / "my_rov.toml"
    assert main(["vehicle", "from-ardusub", str(TLOG), "--base", "bluerov2_heavy", "--out", str(out)]) == 0
    return out


def _write_tlog(src: Path, dst: Path, shift: dict[int, float]) -> None:
    """A copy of a .tlog (8-byte big-endian time stamp in microseconds, then the MAVLink packet, per
    message) with message i's stamp moved by shift[i] seconds, written through pymavlink's reader."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(src), dialect="ardupilotmega")
    i = 0
    with open(dst, "wb") as fh:
        while (msg := log.recv_match()) is not None:
            if msg.get_type() == "BAD_DATA":
                continue
            us = int(round((msg._timestamp + shift.get(i, 0.0)) * 1e6))
            fh.write(struct.pack(">Q", min(max(us, 0), 2**64 - 1)) + msg.get_msgbuf())
            i += 1
    log.close()
    assert i == 35912  # small.tlog's messages (../shared/data/ardusub/README.md)


@real_log
def test_the_helper_writes_the_log_unchanged_without_a_shift(tmp_path):
    from rovlab.interfaces.mavlink.logs import read_records

    _write_tlog(TLOG, tmp_path / "copy.tlog", {})
    a, b = read_records(TLOG), read_records(tmp_path / "copy.tlog")
    assert len(a) == len(b) and all(x[0] == y[0] and x[1] == y[1] for x, y in zip(a, b))
    assert np.all(np.diff([r[0] for r in b]) > -1.0)  # the log's own stamps never go back a second


def test_an_mcap_recording_is_read_in_the_order_it_was_written(heavy, tmp_path):
    """rovlab's own recording (rovlab mavlink record / bridge --record): the same check on an MCAP, whose
    messages the reader would otherwise sort by their log time (moving the corrupted one to the end)."""
    pytest.importorskip("mcap")
    from rovlab.interfaces.mavlink.logs import MAVLINK_PREFIX, TelemetryRecorder, read_records

    v, model = heavy
    recs = _dive()
    t, kind, fields = recs[58]
    recs[58] = (t + 3 * YEAR, kind, fields)
    rec = TelemetryRecorder(tmp_path / "dive.mcap")
    for stamp, k, f in recs:
        rec.stream.write(MAVLINK_PREFIX + k, stamp, f)
    rec.close()
    back = read_records(tmp_path / "dive.mcap")
    assert [k for _, k, _ in back] == [k for _, k, _ in recs]
    summary = write_filter_log(tmp_path / "dive.mcap", v, model, tmp_path / "in.csv", records=back)
    assert [(n, k) for n, k, *_ in summary["left_out"]] == [(59, "ATTITUDE")]


def test_a_broken_clock_is_refused_naming_the_first_message(heavy, tmp_path):
    """More than 100 corrupted stamps (MAX_LEFT_OUT) are not glitches: LogError (exit 2 from the CLI)."""
    from rovlab.interfaces.mavlink.logs import MAX_LEFT_OUT, LogError

    v, model = heavy
    recs = _dive(n=2000)
    bad = [i for i in range(5, len(recs), 15)][:MAX_LEFT_OUT + 1]
    for i in bad:
        recs[i] = (recs[i][0] + 1e7, recs[i][1], recs[i][2])
    with pytest.raises(LogError, match=rf"dive.tlog: {MAX_LEFT_OUT + 1} messages .* message 6 \(ATTITUDE\)"):
        write_filter_log("dive.tlog", v, model, tmp_path / "in.csv", records=recs)
    recs[bad[-1]] = (recs[bad[-1]][0] - 1e7, recs[bad[-1]][1], recs[bad[-1]][2])
    assert len(write_filter_log("dive.tlog", v, model, tmp_path / "in.csv", records=recs)["left_out"]) == MAX_LEFT_OUT
