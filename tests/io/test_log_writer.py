"""The CSV writer of `rovlab filter` (ChunkWriter, pyarrow's CSV writer; issue 16 part 3, issue
26): every float in its shortest round-trip form laid out as pyarrow lays it out, rounded exactly
as round_significant rounds, labels and empty cells, and the refusals."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rovlab.io.logwriter import ChunkWriter, round_significant


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


def _write(tmp_path, columns, names, **kw) -> list[str]:
    path = tmp_path / "out.csv"
    with ChunkWriter(path, names, **kw) as w:
        w.write(columns)
    return path.read_text(encoding="ascii").split("\n")[1:-1]


def _digits(text: str) -> str:
    """The significant digits of a number's text (its mantissa without point, sign and zeros)."""
    return text.lstrip("-").lower().split("e")[0].replace(".", "").strip("0")


@pytest.mark.parametrize("digits", [None, 10, 6, 15, 1])
def test_every_value_is_written_shortest_and_reads_back(tmp_path, digits):
    x = _values()
    expected = round_significant(x, digits) if digits else x
    cells = _write(tmp_path, {"x": x}, ["x"], significant=digits)
    back = np.array([float(c) if c else np.nan for c in cells])
    np.testing.assert_array_equal(back, expected)  # NaN as an empty cell, -0, inf, subnormals
    finite = [(c, float(v)) for c, v in zip(cells, expected) if np.isfinite(v)]
    assert all(_digits(c) == _digits(repr(v)) for c, v in finite)  # the shortest digits, as Python's repr


def test_layout(tmp_path):
    x = np.array([0.1, 1e-6, 9.99e-7, 1e9, 1e10, -0.0, 2.0 / 3.0, 1.2345678901234567e-200, 9.999999999999999e-14,
                  100.0])
    assert _write(tmp_path, {"x": x}, ["x"]) == [
        "0.1", "0.000001", "9.99e-7", "1000000000", "1e+10", "-0", "0.6666666666666666", "1.2345678901234567e-200",
        "9.999999999999999e-14", "100"]
    # rounded as round_significant rounds: 9.999999999999999e-14 to 1e-13 (k = 22), 1e-200 left as it is
    assert _write(tmp_path, {"x": x}, ["x"], significant=10)[6:9] == ["0.6666666667", "1.2345678901234567e-200",
                                                                     "1e-13"]


def test_rows_with_labels_and_empty_cells(tmp_path):
    x = np.array([1.5, np.nan, -2.0])
    rows = _write(tmp_path, {"a": x, "s": (np.array([0, 2, 1]), ["ok", "lost-gate", "off"]), "b": x * 10,
                             "n": np.array([1, 2, 3])}, ["a", "s", "b", "n"])
    assert rows == ["1.5,ok,15,1", ",off,,2", "-2,lost-gate,-20,3"]


@pytest.mark.parametrize("columns, needle", [
    ({"a": (np.array([0]), ["a,b"])}, "needs quoting"),
    ({"a": ["x\ny"]}, "needs quoting"),
    ({"a": (np.array([3]), ["ok"])}, "label codes"),
    ({"a": np.ones(2), "b": np.ones(3)}, "different lengths"),
])
def test_refusals(tmp_path, columns, needle):
    with pytest.raises(ValueError, match=needle):
        with ChunkWriter(tmp_path / "out.csv", list(columns)) as w:
            w.write(columns)
    assert not list(tmp_path.iterdir())  # nothing left behind
    with pytest.raises(ValueError, match="no columns"):
        ChunkWriter(tmp_path / "out.csv", [])


def test_reading_and_writing_do_not_import_pandas(tmp_path):
    """pyarrow imports pandas (0.3-0.7 s) for pa.array, pa.scalar and to_numpy when pandas is
    installed: rovlab's readers and writers use none of them."""
    code = f"""
import sys
import numpy as np
from pathlib import Path
from rovlab.io.logreader import LogStream, read_log
from rovlab.io.logwriter import ChunkWriter, write_csv
from rovlab.io.tables import read_table, write_table
folder = Path({str(tmp_path)!r})
t = np.arange(10) * 0.1
write_csv(folder / "a.csv", {{"time_s": t, "z": np.where(t > 0.5, np.nan, t), "s": ["ok"] * 10}})
with ChunkWriter(folder / "b.csv", ["time_s", "z", "s"], significant=10) as w:
    w.write({{"time_s": t, "z": t * 3, "s": (np.zeros(10, dtype=int), ["ok"])}})
read_log(folder / "a.csv")
list(LogStream(folder / "b.csv", required=("z",)))
(folder / "c.csv").write_text("time_s,z\\n0,1\\n0.1,inf\\n")  # a block that is checked cell by cell
list(LogStream(folder / "c.csv", required=("z",)))
write_table(folder / "d.csv", {{"time_s": t, "force_n": t}})
read_table(folder / "d.csv")
print("pandas" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr
