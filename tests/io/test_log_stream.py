"""Streaming log reader and chunk writer (issue 16 part 3, issue 15's log numbers): the same
values and the same line-numbered refusals as read_log, a chunk at a time, whether pyarrow parses
a block straight into numbers ("typed") or every block is read as text and checked cell by cell
("checked", the reading of a block with a problem)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.io.logreader import LogStream, parse_log, read_log
from rovlab.io.logwriter import ChunkWriter, round_significant, write_csv
from rovlab.params.validate import ConfigError

REQUIRED = ("tau_Z", "tau_N", "z_qualisys")
HEADER = "time_s,tau_Z,tau_N,z_qualisys"


def _stream(path, *, fast=True, chunk_rows=7):
    s = LogStream(path, required=REQUIRED, chunk_rows=chunk_rows, fast=fast)
    chunks = list(s)
    return s, {c: np.concatenate([ch.data[c] for ch in chunks]) for c in s.need}, chunks


@pytest.mark.parametrize("fast", [True, False], ids=["typed", "checked"])
def test_stream_equals_read_log(tmp_path, fast):
    rng = np.random.default_rng(3)
    n = 500
    cols = {"time_s": np.arange(n) * 0.1, "tau_Z": rng.normal(size=n), "tau_N": rng.normal(size=n),
            "z_qualisys": rng.normal(size=n), "note": ["a"] * n}
    cols["z_qualisys"][::7] = np.nan
    cols["z_qualisys"][5] = np.inf
    cols["tau_Z"][9] = -np.inf
    path = tmp_path / "log.csv"
    write_csv(path, cols, comments=["made by a test"])
    whole = read_log(path, required=REQUIRED)
    stream, data, chunks = _stream(path, fast=fast, chunk_rows=64)
    assert len(chunks) > 3 and stream.comments == ["made by a test"]
    for c in ("time_s",) + REQUIRED:
        np.testing.assert_array_equal(data[c], whole[c])
    assert [ch.start for ch in chunks] == np.cumsum([0] + [len(ch) for ch in chunks[:-1]]).tolist()
    assert stream.where(10, "tau_N") == f"line {int(whole.lines[10])}, column 'tau_N'"


NUMBERS = [("1_000", "a number (ASCII digits"), ("\uff11\uff12", "a number (ASCII digits"),
           ("1e400", "within +-1.8e308"), ("-1e400", "within +-1.8e308"), ("0x10", "a number"),
           ("1,5", "fields"), ("Nan", "a number"), ("1e", "a number")]


@pytest.mark.parametrize("fast", [True, False], ids=["typed", "checked"])
@pytest.mark.parametrize("cell, needle", NUMBERS, ids=[c for c, _ in NUMBERS])
def test_numbers_other_tools_do_not_read_are_refused_with_line_and_column(tmp_path, fast, cell, needle):
    rows = [f"{k * 0.1:.1f},0,0,1" for k in range(30)]
    rows[20] = f"2.0,0,0,{cell}"
    path = tmp_path / "n.csv"
    path.write_text(HEADER + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        _stream(path, fast=fast)
    msg = str(err.value)
    assert str(path) in msg and "line 22" in msg and needle in msg, msg
    if "fields" not in needle:
        assert "column 'z_qualisys'" in msg and repr(cell) in msg
    with pytest.raises(ConfigError, match="line 22"):
        read_log(path, required=REQUIRED)  # the whole-file reader says the same


@pytest.mark.parametrize("fast", [True, False], ids=["typed", "checked"])
def test_time_order_is_checked_across_chunks(tmp_path, fast):
    rows = [f"{k * 0.1:.1f},0,0,1" for k in range(30)]
    rows[14] = "0.5,0,0,1"  # line 16: goes back
    path = tmp_path / "t.csv"
    path.write_text("# c\n" + HEADER + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(ConfigError) as err:
        _stream(path, fast=fast, chunk_rows=5)
    assert "line 17, column 'time_s'" in str(err.value) and "goes back from 1.3 on line 16" in str(err.value)


def test_inf_and_words_kept_and_blank_and_comment_lines_inside(tmp_path):
    path = tmp_path / "w.csv"
    path.write_text(HEADER + "\n0,0,0,inf\n\n# a note\n0.1, 1 ,0,-Infinity\r\n0.2,NA,0,nan\n")
    _, data, _ = _stream(path)
    assert data["z_qualisys"][0] == np.inf and data["z_qualisys"][1] == -np.inf
    assert data["tau_Z"][1] == 1.0 and np.isnan(data["tau_Z"][2]) and np.isnan(data["z_qualisys"][2])


@pytest.mark.parametrize("text, needle", [
    ("", "empty file"),
    (HEADER + "\n", "no data rows"),
    ("time_s;tau_Z\n", "';'-separated"),
    (HEADER + "\n0,0,0,1\n,0,0,1\n", "line 3, column 'time_s'"),
    (HEADER + "\n0,0,0,1\ninf,0,0,1\n", "finite time"),
])
def test_stream_refusals(tmp_path, text, needle):
    path = tmp_path / "r.csv"
    path.write_text(text)
    with pytest.raises(ConfigError, match=needle):
        _stream(path)


def test_undecodable_bytes_name_the_line(tmp_path):
    path = tmp_path / "b.csv"
    path.write_bytes(HEADER.encode() + b"\n0,0,0,1\n0.1,0,0,\xff\n")
    with pytest.raises(ConfigError, match="line 3.*undecodable|undecodable.*line 3"):
        _stream(path)


def test_parse_log_refuses_the_same_numbers():
    with pytest.raises(ConfigError, match="line 3, column 'tau_Z'"):
        parse_log(HEADER + "\n0,0,0,1\n0.1,1_000,0,1\n", required=REQUIRED)


def test_chunk_writer_round_trip_atomic_and_abort(tmp_path):
    path = tmp_path / "out.csv"
    t = 1.7e9 + np.arange(6) * 0.1
    x = np.array([1.0 / 3.0, np.nan, -2.5e-9, 1e300, 0.0, 123456789012.5])
    with ChunkWriter(path, ["time_s", "x", "s"], comments=["hello"], significant=10, exact=["time_s"]) as w:
        w.write({"time_s": t[:3], "x": x[:3], "s": (np.array([0, 1, 0]), ["ok", "lost-timeout"])})
        assert not path.exists()  # written to a temporary file first
        w.write({"time_s": t[3:], "x": x[3:], "s": ["ok", "ok", "off"]})
    log = read_log(path)
    np.testing.assert_array_equal(log.time, t)
    np.testing.assert_array_equal(log["x"], round_significant(x, 10))
    assert log.text["s"] == ["ok", "lost-timeout", "ok", "ok", "ok", "off"] and log.comments == ("hello",)
    with pytest.raises(RuntimeError):
        with ChunkWriter(tmp_path / "never.csv", ["a"]) as w:
            w.write({"a": np.ones(3)})
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == [path]  # no output and no temporary left


def test_round_significant_matches_printf():
    rng = np.random.default_rng(5)
    x = rng.choice([-1.0, 1.0], 5000) * rng.uniform(1.0, 10.0, 5000) * 10.0 ** rng.integers(-12, 12, 5000)
    expect = np.array([float(f"{v:.10g}") for v in x])
    np.testing.assert_array_equal(round_significant(x, 10), expect)
    tiny = np.array([1.2345678901234e-20, np.inf, -np.inf, 0.0])  # beyond 1e+-22 scale: kept as they are
    np.testing.assert_array_equal(round_significant(tiny, 10), tiny)


@pytest.mark.parametrize("cell, expected", [("1_000", "a number"), ("\uff11\uff12", "a number"),
                                            ("1e400", "a finite number")])
def test_lab_tables_refuse_the_same_numbers(tmp_path, cell, expected):
    from rovlab.io.tables import read_table

    path = tmp_path / "lab.csv"
    path.write_text(f"time_s,force_n\n0,1\n0.1,{cell}\n", encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        read_table(path)
    assert f"line 3, column 'force_n': got '{cell}'; expected {expected}" in str(err.value)
