"""Lab data files (rovlab.io.tables): every malformed file gets a message naming file, line and column."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.io.tables import read_table, split_runs, write_table
from rovlab.params import ConfigError


def _write(tmp_path, text, name="log.csv", raw=False):
    path = tmp_path / name
    if raw:
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


def test_round_trip_with_comments(tmp_path):
    path = tmp_path / "x.csv"
    write_table(path, {"run": [1, 1, 2], "time_s": [0.0, 0.1, 0.0]}, comments=["seed = 4", "hello"],
                formats={"run": "d"})
    t = read_table(path, required=("run", "time_s"))
    assert t.columns == ("run", "time_s")
    np.testing.assert_array_equal(t["run"], [1, 1, 2])
    assert t.meta() == {"seed": "4"}
    # issue 15: plain CSV that pandas reads with its defaults; the comments live in x.csv.json
    assert "#" not in path.read_text(encoding="utf-8") and (tmp_path / "x.csv.json").exists()
    assert list(t.lines) == [2, 3, 4]
    pd = pytest.importorskip("pandas")
    assert list(pd.read_csv(path).columns) == ["run", "time_s"]
    assert [rid for rid, _ in split_runs(t)] == [1, 2]


def test_bom_crlf_and_trailing_commas_are_accepted(tmp_path):
    path = _write(tmp_path, "\ufeff PWM (µs), Force (Kg f),\r\n1100,-2.90,\r\n1104,-2.92,\r\n".encode("utf-8"), raw=True)
    t = read_table(path)
    assert t.columns == ("PWM (µs)", "Force (Kg f)")
    np.testing.assert_array_equal(t["Force (Kg f)"], [-2.90, -2.92])


@pytest.mark.parametrize("text, message", [
    ("time_s,pwm_us,force_n\n0,1500,abc\n", "log.csv: line 2, column 'force_n': got 'abc'; expected a number"),
    ("time_s,pwm_us,force_n\n0,1500\n", "log.csv: line 2: got '2 values'; expected 3 values"),
    ("time_s,pwm_us,force_n\n0,1500,nan\n", "line 2, column 'force_n': got 'nan'; expected a finite number"),
    ("time_s,pwm_us\n0,1500\n", "missing: force_n"),
    ("time_s;pwm_us;force_n\n0;1500;1\n", "found ';'-separated names"),
    ("# only a comment\n", "an empty file"),
    ("time_s,pwm_us,force_n\n", "no data rows"),
    ("0,1500,1\n1,1500,1\n", "the header line is missing"),
    ("time_s,time_s,force_n\n0,1,2\n", "unique column names"),
])
def test_malformed_files(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        read_table(path, required=("time_s", "pwm_us", "force_n"))
    assert message in str(err.value)


def test_missing_and_undecodable_files(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        read_table(tmp_path / "nope.csv")
    path = _write(tmp_path, b"time_s\n\xff\xfe\n", raw=True)
    with pytest.raises(ConfigError, match="UTF-8"):
        read_table(path)


def test_many_bad_cells_are_capped(tmp_path):
    path = _write(tmp_path, "a\n" + "x\n" * 50)
    with pytest.raises(ConfigError) as err:
        read_table(path)
    assert len(err.value.problems) == 21
    assert "stopped after the first 20" in str(err.value)


def test_non_integer_run_and_backwards_time_are_named(tmp_path):
    from rovlab.io.tables import require_increasing

    t = read_table(_write(tmp_path, "run,time_s\n1,0\n1.5,0.1\n"))
    with pytest.raises(ConfigError, match="line 3, column 'run': got 1.5; expected an integer run number"):
        split_runs(t)
    t = read_table(_write(tmp_path, "time_s\n0\n0.2\n0.1\n", name="b.csv"))
    with pytest.raises(ConfigError, match="b.csv: line 4, column 'time_s': got 0.1"):
        require_increasing(t)


def test_semicolon_file_is_explained_without_required_columns(tmp_path):
    path = _write(tmp_path, "time_s;force_n;position_m\n0;1;0\n")
    with pytest.raises(ConfigError, match="found ';'-separated names"):
        read_table(path)


# Issue 15 item 12: numbers Python reads but no instrument writes, and implausible magnitudes.
@pytest.mark.parametrize(("cell", "expected"), [
    ("1_000", "a number (ASCII digits"),
    ("１２", "a number (ASCII digits"),
    ("0x10", "a number (ASCII digits"),
    ("1e400", "a finite number"),
    ("1e154", "a magnitude of at most 100000"),
    ("1e-300", "0 or a magnitude of at least 1e-30"),
])
def test_odd_numbers_and_magnitudes_are_refused(tmp_path, cell, expected):
    path = _write(tmp_path, f"time_s,force_n\n0.0,1.0\n0.1,{cell}\n")
    with pytest.raises(ConfigError) as info:
        read_table(path)
    msg = str(info.value.problems[0])
    assert str(path) in msg and "line 3, column 'force_n'" in msg and expected in msg


def test_time_steps_below_a_microsecond_and_huge_run_numbers_are_refused(tmp_path):
    from rovlab.io.tables import require_increasing

    t = read_table(_write(tmp_path, "time_s,x\n0.0,1\n1e-9,2\n"))
    with pytest.raises(ConfigError, match=r"line 3, column 'time_s'.*at least 1e-06 s after"):
        require_increasing(t)
    with pytest.raises(ConfigError, match=r"line 2, column 'run'.*at most 1e\+09"):
        read_table(_write(tmp_path, "run,time_s\n1e12,0.0\n", name="runs.csv"))
    ok = read_table(_write(tmp_path, "time_s,force_n\n-0.0,0\n0.5,-1.5e-3\n", name="ok.csv"))
    np.testing.assert_array_equal(ok["force_n"], [0.0, -1.5e-3])
