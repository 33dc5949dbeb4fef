"""LogStream's reader thread: chunks in order, a refusal raised where it occurs in
the sequence after the chunks before it, and a thread that stops when the consumer does."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from rovlab.io.logreader import LogStream
from rovlab.params.validate import ConfigError

HEADER = "time_s,tau_Z,tau_N,z_qualisys"


def _log(tmp_path, n=400, bad_line=None):
    rows = [f"{k * 0.1:.1f},{k},0,{np.sin(k):.6f}" for k in range(n)]
    if bad_line is not None:
        rows[bad_line - 2] = rows[bad_line - 2].rsplit(",", 1)[0] + ",abc"
    path = tmp_path / "log.csv"
    path.write_text(HEADER + "\n" + "\n".join(rows) + "\n")
    return path


def _readers() -> int:
    return sum(t.name == "rovlab-log-reader" and t.is_alive() for t in threading.enumerate())


def test_chunks_in_order_then_the_thread_ends(tmp_path):
    chunks = iter(LogStream(_log(tmp_path), required=("tau_Z",), chunk_rows=16))
    tau = np.concatenate([c.data["tau_Z"] for c in chunks])
    np.testing.assert_array_equal(tau, np.arange(400.0))
    assert _readers() == 0


def test_refusal_after_the_chunks_before_it(tmp_path):
    chunks = iter(LogStream(_log(tmp_path, bad_line=300), required=("tau_Z", "z_qualisys"), chunk_rows=16))
    seen = 0
    with pytest.raises(ConfigError, match="line 300, column 'z_qualisys'"):
        for c in chunks:
            seen += len(c)
    assert 0 < seen < 299 and _readers() == 0


def test_closing_early_stops_the_reader(tmp_path):
    chunks = iter(LogStream(_log(tmp_path, n=5000), required=("tau_Z",), chunk_rows=16))
    first = next(chunks)
    assert first.start == 0
    chunks.close()  # type: ignore[attr-defined]
    assert _readers() == 0
    with pytest.raises(StopIteration):
        next(chunks)
