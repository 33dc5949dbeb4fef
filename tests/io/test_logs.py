"""CSV logs: round trip, and each kind of malformed log gives one clear, line-numbered error."""

from __future__ import annotations

import io

import numpy as np
import pytest

from rovlab.io.logreader import parse_log, read_log
from rovlab.io.logwriter import write_csv
from rovlab.params.validate import ConfigError

REQUIRED = ("tau_Z", "tau_N", "z_qualisys")


def test_round_trip_with_missing_values_and_text(tmp_path):
    path = tmp_path / "est.csv"
    t = np.arange(5) * 0.1
    z = np.array([1.0, np.nan, 1.2, np.inf, -3.5e-9])
    write_csv(path, {"time_s": t, "z": z, "n": np.arange(5), "status": ["ok", "lost-timeout", "a,b", "ok", "ok"]},
              comments=["seed = 7"])
    log = read_log(path, required=("z", "n"))
    np.testing.assert_array_equal(log.time, t)
    np.testing.assert_array_equal(log["z"], z)  # NaN written empty and read back as NaN, inf kept
    assert log.comments == ("seed = 7",)
    assert log.columns == ("time_s", "z", "n", "status")
    assert log.text["status"] == ["ok", "lost-timeout", "a,b", "ok", "ok"]
    assert log.lines.tolist() == [3, 4, 5, 6, 7]


def test_reader_accepts_nan_empty_crlf_bom_and_extra_columns():
    text = "\ufeff# a comment\r\ntime_s,tau_Z,tau_N,z_qualisys,extra\r\n0.0,1,0,nan,x\r\n\r\n0.1,,0,1.05,\r\n"
    log = parse_log(text, required=REQUIRED)
    assert np.isnan(log["z_qualisys"][0]) and np.isnan(log["tau_Z"][1]) and log["z_qualisys"][1] == 1.05
    assert log.text == {"extra": ["x", ""]}  # a column nobody asked for may hold text
    with pytest.raises(ConfigError, match="line 3, column 'extra'"):
        parse_log(text, required=REQUIRED + ("extra",))  # but not a required one


@pytest.mark.parametrize("text, needles", [
    ("", ["empty file", "time_s, tau_Z"]),
    ("time_s,tau_Z,tau_N\n0,1,2\n", ["line 1 (header)", "missing: z_qualisys"]),
    ("time_s;tau_Z;tau_N;z_qualisys\n", ["missing", "';'-separated"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n", ["no data rows"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n0,1,2,3\n0.1,1,2\n", ["line 3", "3 fields", "4 fields"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n0,1,2,3\n0.1,one,2,3\n", ["line 3, column 'tau_Z'", "'one'", "a number"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n0,1,2,3\n0.2,1,2,3\n0.1,1,2,3\n", ["line 4, column 'time_s'",
                                                                       "goes back from 0.2 on line 3"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n0,1,2,3\n0,1,2,3\n", ["line 3", "repeats 0.0 on line 2"]),
    ("time_s,tau_Z,tau_N,z_qualisys\n,1,2,3\n", ["line 2, column 'time_s'", "(empty)"]),
    ("time_s,tau_Z,tau_N,z_qualisys\ninf,1,2,3\n", ["line 2", "finite time"]),
    ("time_s,time_s,tau_Z,tau_N,z_qualisys\n", ["unique column names"]),
])
def test_malformed_logs(text, needles):
    with pytest.raises(ConfigError) as err:
        parse_log(text, file="log.csv", required=REQUIRED)
    message = str(err.value)
    assert message.startswith("invalid log")
    for needle in needles:
        assert needle in message, (needle, message)


def test_many_bad_rows_are_listed_up_to_a_limit():
    rows = "".join(f"{k},x,0,0\n" for k in range(50))
    with pytest.raises(ConfigError) as err:
        parse_log("time_s,tau_Z,tau_N,z_qualisys\n" + rows, required=REQUIRED)
    assert 20 <= len(err.value.problems) <= 21 and "stopped after" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        read_log(tmp_path / "nope.csv")


def test_writer_checks_columns_and_writes_to_a_stream():
    with pytest.raises(ValueError, match="has 2 values"):
        write_csv(io.StringIO(), {"a": [1.0, 2.0, 3.0], "b": [1.0, 2.0]})
    buf = io.StringIO()
    write_csv(buf, {"time_s": [0.0, 0.1], "x": [1.5, np.nan]}, float_format="%.3f")
    assert buf.getvalue() == "time_s,x\n0.000,1.500\n0.100,\n"
    buf = io.StringIO()
    write_csv(buf, {"time_s": [0.1 + 0.2], "n": np.array([3], dtype=np.int8), "s": ["ok"]})
    assert buf.getvalue() == 'time_s,n,s\n0.30000000000000004,3,ok\n'
    # a text cell that needs quotes: pyarrow's writer then quotes every text cell, the numbers' too
    buf = io.StringIO()
    write_csv(buf, {"time_s": [0.1 + 0.2], "n": np.array([3], dtype=np.int8), "s": ["a\"b"]})
    assert buf.getvalue() == 'time_s,n,s\n"0.30000000000000004",3,"a""b"\n'
    log = parse_log(buf.getvalue(), required=("n",))
    assert log.time.tolist() == [0.1 + 0.2] and log["n"].tolist() == [3.0] and log.text["s"] == ['a"b']


def test_exact_columns_keep_epoch_time_stamps():
    # '%.10g' turned 1700000000.1 into 1700000000: every row of a log stamped with epoch time
    # got the same time. Columns named in ``exact`` are written in round-trip form.
    buf = io.StringIO()
    write_csv(buf, {"time_s": [1700000000.0, 1700000000.1], "z": [1.0 / 3.0, 2.0]}, float_format="%.10g",
              exact=("time_s",))
    log = parse_log(buf.getvalue())
    np.testing.assert_array_equal(log.time, [1700000000.0, 1700000000.1])
    assert buf.getvalue().splitlines()[1] == "1700000000.0,0.3333333333"
