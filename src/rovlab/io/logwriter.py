"""Writing CSV logs through pyarrow's CSV writer: a whole table (:func:`write_csv`: the
simulator's timeseries.csv, the HMI's session log, a converted dive) or a chunk of rows at a
time (:class:`ChunkWriter`: the estimates of ``rovlab filter``). Both write NaN as an empty cell
("no value"), so what they write :func:`rovlab.io.logreader.read_log` reads back unchanged, and
both write atomically through rovlab.core.files (a temporary file renamed over the target), so a
crash, a full disk, Ctrl-C or a refused run never leaves half a log, a temporary file or a
metadata sidecar without its log, and the files of an earlier run stay as they were.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from rovlab.core.files import atomic_open, atomic_write_bytes
from rovlab.io.csvfile import csv_rows, floats, head, ints, labels, strings


def round_significant(values: np.ndarray, digits: int) -> np.ndarray:
    """``values`` rounded to ``digits`` significant digits (vectorised ``float('%.{digits}g' % x)``).

    x * 10^k is rounded to an integer m and divided by the exact power of ten, which gives the
    double nearest to m 10^-k: its shortest round-trip form has at most ``digits`` digits. Values
    beyond 1e+-22 from the scale that powers of ten stay exact, inf and NaN are returned as they are.
    """
    a = np.asarray(values, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k = (digits - 1) - np.floor(np.log10(np.abs(a)))
        ok = np.isfinite(k) & (np.abs(k) <= 22)
        k = np.where(ok, k, 0.0)
        scale = 10.0 ** np.abs(k)
        up = k >= 0
        r = np.where(up, np.round(a * scale) / scale, np.round(a / scale) * scale)
    return np.where(ok, r, a)


def write_csv(target: str | Path | IO[str], columns: Mapping[str, Sequence | np.ndarray], *,
              float_format: str | None = None, comments: Iterable[str] = (),
              exact: Iterable[str] = ()) -> None:
    """Write equally long columns (numbers or strings) as CSV; ``-`` means standard output.

    Numbers are written exactly, as Python's ``repr`` writes them (``0.1``, ``1550.0``,
    ``1e-05``), unless ``float_format`` (e.g. ``"%.6g"``) is given; the ``exact`` columns (e.g.
    ``("time_s",)``) are always written exactly, so that ``%.10g`` does not turn epoch time stamps
    (1.7e9 s) into whole seconds. Integers are written as integers, text as it is; when a text
    cell needs quotes (a comma, a quote, a line break), every text cell is quoted (RFC 4180).
    """
    names = list(columns)
    if not names:
        raise ValueError("no columns to write")
    arrays = []
    length = None
    exact = set(exact)
    quoted = False
    for name in names:
        arr = np.asarray(columns[name])
        if arr.ndim != 1:
            raise ValueError(f"column {name!r} must be one-dimensional, got shape {arr.shape}")
        if length is None:
            length = arr.size
        elif arr.size != length:
            raise ValueError(f"column {name!r} has {arr.size} values, the others {length}")
        if arr.dtype.kind == "f":
            fmt = repr if float_format is None or name in exact else (lambda v: float_format % v)
            arrays.append(strings([None if v != v else fmt(v) for v in arr.astype(float).tolist()]))
        elif arr.dtype.kind == "i" or arr.dtype.kind == "u" and arr.dtype.itemsize < 8:
            arrays.append(ints(arr))
        else:
            texts = [str(v) for v in arr.tolist()]
            arrays.append(strings(texts))
            quoted = quoted or any(ch in text for text in set(texts) for ch in ',"\r\n')
    data = head(names, list(comments)) + csv_rows(arrays, names, quoting="needed" if quoted else "none").to_pybytes()
    if hasattr(target, "write"):
        target.write(data.decode("utf-8"))
        return
    if str(target) == "-":
        sys.stdout.write(data.decode("utf-8"))
        return
    atomic_write_bytes(target, data)


class ChunkWriter:
    """A CSV file written a chunk of rows at a time by pyarrow's CSV writer: floats in their
    shortest round-trip form as pyarrow lays them out (``0.000001``, ``9.99e-7``, ``1e+10``,
    ``100``), rounded to ``significant`` digits except the ``exact`` columns; NaN as an empty
    cell; text columns as given (not quoted: labels such as 'lost-timeout' only).

    Atomic like :func:`write_csv` (rovlab.core.files.atomic_open): rows go to a temporary file
    renamed over ``target`` by :meth:`close`; :meth:`abort` (or an exception inside ``with``:
    a refusal, Ctrl-C) removes it, and so does a write that fails (a full disk, in the worker
    thread or at the end), whose OSError :meth:`write` or :meth:`close` raises in the caller's
    thread. ``sidecar``: metadata written as JSON beside the file (rovlab.io.tables.write_sidecar)
    once every row is on disk, just before the file is renamed into place, so the two appear
    together or not at all. ``-`` writes to standard output (no sidecar). Chunks are rounded,
    formatted and written, in order, by a worker thread (pyarrow formats without the GIL, so
    this overlaps the caller's next chunk), at most two chunks in flight.
    """

    _IN_FLIGHT = 2

    def __init__(self, target: str | Path, names: Sequence[str], *, comments: Iterable[str] = (),
                 significant: int | None = None, exact: Iterable[str] = (),
                 sidecar: Mapping[str, Any] | None = None) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.names = list(names)
        if not self.names:
            raise ValueError("no columns to write")
        self.target = str(target)
        self.significant = significant
        self.exact = set(exact)
        self.sidecar = None if sidecar is None else dict(sidecar)
        self._pending: list = []
        self._file: Any = None  # the atomic_open context of a file target
        if self.target == "-":
            self._f = sys.stdout.buffer
        else:
            self._file = atomic_open(self.target, "wb")
            self._f = self._file.__enter__()
        try:
            self._f.write(head(self.names, list(comments)))
        except BaseException:
            self._discard()
            raise
        self._pool: Any = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rovlab-csv")

    def _format(self, columns: Mapping[str, Any]) -> Any:
        """One chunk as CSV rows (a pyarrow buffer), on the worker thread. The columns to round are
        rounded together, as one array (a few numpy calls a chunk: this thread holds the GIL
        between them, and the filter's thread waits for it)."""
        digits = self.significant
        rounded = [name for name in self.names if digits is not None and name not in self.exact
                   and isinstance(columns[name], np.ndarray) and columns[name].dtype.kind == "f"]
        if rounded and digits is not None:
            block = np.empty((len(columns[rounded[0]]), len(rounded)), order="F")
            for j, name in enumerate(rounded):
                block[:, j] = columns[name]
            block = np.asfortranarray(round_significant(block, digits))  # each column contiguous
        arrays: list[Any] = []
        for name in self.names:
            col = columns[name]
            if isinstance(col, tuple):
                arrays.append(labels(*col))
            elif name in rounded:
                arrays.append(floats(block[:, rounded.index(name)]))
            elif isinstance(col, np.ndarray) and col.dtype.kind == "f":
                arrays.append(floats(col))
            else:  # text (or integers, written exactly)
                arrays.append(strings([str(v) for v in (col.tolist() if hasattr(col, "tolist") else col)]))
        return csv_rows(arrays, self.names)

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
        self._f.write(memoryview(self._format(columns)))

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
        """Finish: every chunk written, the sidecar, then the file renamed into place; if any of it
        fails (e.g. OSError: the disk is full) nothing is left and the error is raised."""
        try:
            self._drain(keep=True)
            if self._file is None:
                self._f.flush()
                return
            self._f.flush()  # the rows on disk (a full disk says so here) before the sidecar
            os.fsync(self._f.fileno())
            if self.sidecar is not None:
                from rovlab.io.tables import write_sidecar

                write_sidecar(self.target, self.sidecar)
        except BaseException:
            self.abort()  # a chunk, the sidecar or the last rows could not be written: no output
            raise
        file, self._file = self._file, None
        file.__exit__(None, None, None)  # fsync and rename; on failure it removes the temporary file

    def abort(self) -> None:
        """Stop: chunks not yet written are dropped and the temporary file is removed."""
        try:
            self._drain(keep=False)
        finally:
            self._discard()

    def _discard(self) -> None:
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.__exit__(OSError, OSError("aborted"), None)  # removes the temporary file
        except OSError:
            pass  # closing it flushed into a full disk: it is removed all the same

    def __enter__(self) -> ChunkWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
