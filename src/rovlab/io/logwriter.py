"""Writing CSV logs: a whole table (write_csv: the simulator's timeseries.csv, the HMI's session
log, a converted dive) or a chunk of rows at a time (ChunkWriter: rovlab filter's estimates).
What they write, :mod:`rovlab.io.logreader` reads back unchanged.
"""

from __future__ import annotations

import io
import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from rovlab.io.csvtext import round_significant  # noqa: F401 (part of this module's API)


class ChunkWriter:
    """A CSV file written a chunk of rows at a time: floats in shortest round-trip form (or rounded
    to ``significant`` digits, except the ``exact`` columns), NaN as an empty cell, text columns as
    given (no quoting: labels such as 'lost-timeout' only).

    Atomic like :func:`write_csv`: rows go to a temporary file renamed over ``target`` by
    :meth:`close`; :meth:`abort` (or an exception inside ``with``) removes it, so a refused or
    interrupted run leaves no half-written output. ``-`` writes to standard output. Chunks are
    rounded and formatted by the compiled loop of :mod:`rovlab.io.csvtext` and written, in order,
    by a worker thread (both release the GIL, so this overlaps the caller's next chunk), at most
    two chunks in flight. The numbers are laid out as pyarrow's CSV writer lays them out
    (``0.000001``, ``9.99e-7``, ``1e+10``), with or without pyarrow installed.
    """

    _IN_FLIGHT = 2

    def __init__(self, target: str | Path, names: Sequence[str], *, comments: Iterable[str] = (),
                 significant: int | None = None, exact: Iterable[str] = ()) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.names = list(names)
        self.target = str(target)
        self.significant = significant
        self.exact = set(exact)
        self._tmp: Path | None = None
        self._pending: list = []
        if self.target == "-":
            self._f = sys.stdout.buffer
        else:
            path = Path(target)
            self._tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            self._f = open(self._tmp, "wb")
        head = "".join(f"# {line}\n" for line in comments) + ",".join(_quote(n) for n in self.names) + "\n"
        self._f.write(head.encode("utf-8"))
        self._pool: Any = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rovlab-csv")

    def _format(self, columns: Mapping[str, Any]) -> bytes | memoryview:
        """One chunk as CSV bytes, on the worker thread."""
        from rovlab.io.csvtext import csv_rows

        cols: list[Any] = []
        digits: list[int | None] = []
        for name in self.names:
            col = columns[name]
            digits.append(None)
            if isinstance(col, tuple):
                cols.append(col)
            elif isinstance(col, np.ndarray) and col.dtype.kind == "f":
                cols.append(col)  # rounded by the kernel, exactly as round_significant rounds
                digits[-1] = None if name in self.exact else self.significant
            else:  # text (or integers, written exactly): as codes into its distinct values
                texts = [str(v) for v in (col.tolist() if hasattr(col, "tolist") else col)]
                labels = sorted(set(texts))
                code = {text: i for i, text in enumerate(labels)}
                cols.append((np.array([code[text] for text in texts], dtype=np.int64), labels))
        return csv_rows(cols, digits)

    def write(self, columns: Mapping[str, np.ndarray | Sequence[str] | tuple[np.ndarray, Sequence[str]]]) -> None:
        """Append rows: each column a float array, a sequence of strings, or (codes, labels): the
        label of each integer code (written without building one string per row). The arrays
        must not be modified afterwards (they may still be formatting)."""
        if self._pool is None:
            raise ValueError(f"{self.target}: the writer is closed")
        self._pending.append(self._pool.submit(self._write, dict(columns)))
        while len(self._pending) >= self._IN_FLIGHT:
            self._pending.pop(0).result()  # raises what formatting or writing raised

    def _write(self, columns: Mapping[str, Any]) -> None:
        """Format and write one chunk, on the worker thread (one worker: in order)."""
        self._f.write(self._format(columns))

    def _drain(self, keep: bool) -> None:
        pending, self._pending = self._pending, []
        try:
            for future in pending:
                if keep:
                    future.result()
                else:
                    future.cancel()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=not keep)
                self._pool = None

    def close(self) -> None:
        self._drain(keep=True)
        if self._tmp is None:
            self._f.flush()
            return
        self._f.close()
        os.replace(self._tmp, self.target)
        self._tmp = None

    def abort(self) -> None:
        self._drain(keep=False)
        if self._tmp is None:
            return
        self._f.close()
        self._tmp.unlink(missing_ok=True)
        self._tmp = None

    def __enter__(self) -> ChunkWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_csv(target: str | Path | IO[str], columns: Mapping[str, Sequence | np.ndarray], *,
              float_format: str | None = None, comments: Iterable[str] = (),
              exact: Iterable[str] = ()) -> None:
    """Write equally long columns (numbers or strings) as CSV; ``-`` means standard output.

    Numbers are written exactly (shortest round-trip form) unless ``float_format`` (e.g.
    ``"%.6g"``) is given; the ``exact`` columns (e.g. ``("time_s",)``) are always written exactly, so
    that ``%.10g`` does not turn epoch time stamps (1.7e9 s) into whole seconds. NaN is written as an
    empty cell ("no value"), so what this writes
    :func:`read_log` reads back unchanged. A file is written atomically (temporary file, then
    rename) so a crash never leaves half a log.
    """
    names = list(columns)
    if not names:
        raise ValueError("no columns to write")
    cols = []
    length = None
    exact = set(exact)
    for name in names:
        col = columns[name]
        arr = np.asarray(col)
        if arr.ndim != 1:
            raise ValueError(f"column {name!r} must be one-dimensional, got shape {arr.shape}")
        if length is None:
            length = arr.size
        elif arr.size != length:
            raise ValueError(f"column {name!r} has {arr.size} values, the others {length}")
        if arr.dtype.kind in "iub":
            cols.append([str(v) for v in arr.tolist()])
        elif arr.dtype.kind == "f":
            fmt = repr if float_format is None or name in exact else (lambda v: float_format % v)
            cols.append(["" if v != v else fmt(v) for v in arr.astype(float).tolist()])
        else:
            cols.append([_quote(str(v)) for v in arr.tolist()])
    buf = io.StringIO()
    for line in comments:
        buf.write(f"# {line}\n")
    buf.write(",".join(_quote(n) for n in names) + "\n")
    for row in zip(*cols):
        buf.write(",".join(row))
        buf.write("\n")
    text = buf.getvalue()
    if hasattr(target, "write"):
        target.write(text)
        return
    if str(target) == "-":
        sys.stdout.write(text)
        return
    path = Path(target)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _quote(text: str) -> str:
    if any(ch in text for ch in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text
