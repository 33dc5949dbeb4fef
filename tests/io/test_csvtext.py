"""The compiled CSV formatter of `rovlab filter` (issue 16 part 3): the same bytes as pyarrow's CSV
writer wrote before it (shortest round-trip digits, pyarrow's layout), rounding exactly as
round_significant, with or without pyarrow installed."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.io.csvtext import csv_rows, format_float
from rovlab.io.logwriter import round_significant


def _values() -> np.ndarray:
    rng = np.random.default_rng(16)
    n = 20_000
    wide = rng.choice([-1.0, 1.0], n) * rng.uniform(1.0, 10.0, n) * 10.0 ** rng.integers(-30, 40, n)
    powers = 10.0 ** np.arange(-25, 30)
    near = np.concatenate([powers, np.nextafter(powers, 0.0), np.nextafter(powers, np.inf),
                           9.9999999995 * 10.0 ** np.arange(-20, 20), 1.00000000005 * 10.0 ** np.arange(-20, 20)])
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, 1.7976931348623157e308, 1e-13, 9.9e-14,
                        123456789012.5, 1e9, 1e10, 1e-6, 9.99e-7, 35999.9, 1.7e9 + 0.1, 1.0 / 3.0])
    return np.concatenate([wide, rng.standard_normal(n), rng.standard_normal(n) * 1e-9, near, special])


def _lines(data) -> list[str]:
    return bytes(data).decode("ascii").split("\n")[:-1]


@pytest.mark.parametrize("digits", [None, 10, 6, 15, 1])
def test_kernel_writes_what_python_lays_out(digits):
    x = _values()
    expected = round_significant(x, digits) if digits else x
    assert _lines(csv_rows([x], [digits])) == [format_float(float(v)) for v in expected]


@pytest.mark.parametrize("digits", [None, 10])
def test_kernel_writes_the_bytes_pyarrow_wrote(digits):
    pa = pytest.importorskip("pyarrow")
    import pyarrow.csv

    x = _values()
    expected = round_significant(x, digits) if digits else x
    sink = pa.BufferOutputStream()
    pyarrow.csv.write_csv(pa.table({"x": pa.array(expected, from_pandas=True)}), sink,
                          write_options=pyarrow.csv.WriteOptions(include_header=False, quoting_style="none"))
    assert _lines(csv_rows([x], [digits])) == _lines(sink.getvalue().to_pybytes())


def test_layout_and_values_left_to_python():
    # 17 digits and 1e-200 need Python's repr; 9.999999999999999e-14 sits where round_significant
    # stops rounding (k = 22): it rounds to 1e-13 there, and so must the writer
    x = np.array([0.1, 1e-6, 9.99e-7, 1e9, 1e10, -0.0, 2.0 / 3.0, 1.2345678901234567e-200, 9.999999999999999e-14])
    assert _lines(csv_rows([x], [None])) == ["0.1", "0.000001", "9.99e-7", "1000000000", "1e+10", "-0",
                                              "0.6666666666666666", "1.2345678901234567e-200",
                                              "9.999999999999999e-14"]
    # (round_significant leaves 1e-200 as it is: beyond the scale of exact powers of ten)
    assert _lines(csv_rows([x], [10]))[6:] == ["0.6666666667", "1.2345678901234567e-200", "1e-13"]
    many = np.full(500, 1.2345678901234567e-200)  # more values left to Python than the first list holds
    assert set(_lines(csv_rows([many], [None]))) == {"1.2345678901234567e-200"}


def test_rows_with_labels_and_empty_cells():
    x = np.array([1.5, np.nan, -2.0])
    text = bytes(csv_rows([x, (np.array([0, 2, 1]), ["ok", "lost-gate", "off"]), x * 10], [None, None, 10]))
    assert text == b"1.5,ok,15\n,off,\n-2,lost-gate,-20\n"


@pytest.mark.parametrize("columns, needle", [
    ([(np.array([0]), ["a,b"])], "needs quoting"),
    ([(np.array([3]), ["ok"])], "label codes"),
    ([np.ones(2), np.ones(3)], "has 3 values"),
    ([], "no columns"),
])
def test_refusals(columns, needle):
    with pytest.raises(ValueError, match=needle):
        csv_rows(columns)


def test_chunk_writer_writes_the_same_bytes_without_pyarrow(tmp_path, monkeypatch):
    import sys

    from rovlab.io.logwriter import ChunkWriter

    def write(path):
        with ChunkWriter(path, ["time_s", "x", "s"], significant=10, exact=["time_s"]) as w:
            for k in range(3):
                w.write({"time_s": 1.7e9 + np.arange(k * 5, k * 5 + 5) * 0.1, "x": _values()[k * 5:k * 5 + 5],
                         "s": (np.array([0, 1, 0, 1, 1]), ["ok", "lost-timeout"])})

    write(tmp_path / "a.csv")
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    write(tmp_path / "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
