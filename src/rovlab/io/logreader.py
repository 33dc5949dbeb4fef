"""Reading time-stamped CSV logs, every problem named with its line (the writers: rovlab.io.logwriter).

Log format (what ``rovlab filter`` reads and what the simulator writes): UTF-8 text (a
byte-order mark is ignored), optional ``#`` comment lines, one header line of comma-separated
column names, then one row per sample. One column is the time (``time_s`` by default): finite
and strictly increasing. Every other cell is a number, ``nan``, ``inf``/``-inf``, or empty;
empty and ``nan`` both mean "no value at this time" (a sensor that did not deliver a sample),
``inf`` is kept (a faulty sample). Extra columns are allowed and kept. Blank lines are skipped,
CRLF line endings are accepted.

Every problem is a :class:`rovlab.params.validate.ConfigError` naming the file, the line and
the column, e.g. ``log.csv: line 7, column 'z_pressure': got 'abc'; expected a number``.
"""

from __future__ import annotations

import csv
import math
import queue
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.io.tables import NUMBER_EXPECTED, RANGE_EXPECTED, number_problem, parse_number, scan_csv  # noqa: F401
from rovlab.params.validate import ConfigError, Problem

_MAX_PROBLEMS = 20
_MISSING = {"", "nan", "NaN", "NAN", "na", "NA"}
@dataclass(frozen=True, eq=False)
class Log:
    """The columns of one log as float arrays (NaN = no value), with the file line of each row."""

    file: str
    columns: tuple[str, ...]
    data: Mapping[str, np.ndarray]
    lines: np.ndarray  # 1-based line number of each row
    comments: tuple[str, ...] = ()
    time_column: str = "time_s"
    text: Mapping[str, list[str]] = field(default_factory=dict)  # columns that are not numbers

    def __len__(self) -> int:
        return int(self.lines.size)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    @property
    def time(self) -> np.ndarray:
        return self.data[self.time_column]

    def where(self, row: int, column: str | None = None) -> str:
        """'line N' (and the column) of a row index, for error messages."""
        text = f"line {int(self.lines[row])}" if 0 <= row < len(self) else "end of file"
        return f"{text}, column {column!r}" if column else text

    def problem(self, row: int, column: str | None, value: object, expected: str) -> ConfigError:
        return ConfigError([Problem(self.file, self.where(row, column), value, expected)], "log")


def read_log(path: str | Path, *, required: Sequence[str] = (), time_column: str = "time_s") -> Log:
    """Read a log; raise :class:`ConfigError` listing every problem (up to 20) with its line."""
    path = Path(path)
    file = str(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise ConfigError([Problem(file, "", "no such file", "an existing CSV log")], "log") from None
    except IsADirectoryError:
        raise ConfigError([Problem(file, "", "a directory", "a CSV log file")], "log") from None
    except UnicodeDecodeError as exc:
        raise ConfigError([Problem(file, "", "undecodable bytes",
                                   f"UTF-8 text ({exc.reason} at byte {exc.start})")], "log") from None
    return parse_log(text, file=file, required=required, time_column=time_column)


def parse_log(text: str, *, file: str = "<text>", required: Sequence[str] = (),
              time_column: str = "time_s") -> Log:
    """Parse the text of a log (see :func:`read_log`).

    The time and the ``required`` columns must hold numbers (or no value); any other column is
    read as numbers when every cell is one, and kept as text otherwise (``Log.text``).
    """
    text = text.removeprefix("\ufeff")
    comments, header, header_line, rows, row_lines = scan_csv(text, split=_split)
    header = [c.strip() for c in header] if header is not None else None

    need = [time_column] + [c for c in required if c != time_column]
    _check_header(file, header, header_line, need)
    assert header is not None  # _check_header refuses a file without one
    if not rows:
        raise ConfigError([Problem(file, "", "no data rows", "at least one row after the header")], "log")

    n = len(header)
    problems: list[Problem] = []
    values = np.full((len(rows), n), np.nan)
    it = header.index(time_column)
    strict = {header.index(c) for c in need}
    text_cols: dict[int, list[str]] = {}
    for r, (cells, number) in enumerate(zip(rows, row_lines)):
        if len(cells) > n and not any(c.strip() for c in cells[n:]):
            cells = cells[:n]
        if len(cells) != n:
            problems.append(Problem(file, f"line {number}", f"{len(cells)} fields",
                                    f"{n} fields, one per column ({', '.join(header)})"))
        else:
            for c, cell in enumerate(cells):
                text_cell = cell.strip()
                if c in text_cols:
                    continue
                if text_cell in _MISSING:
                    if c == it:
                        problems.append(Problem(file, f"line {number}, column {time_column!r}",
                                                text_cell or "(empty)", "a time in seconds"))
                    continue
                x = parse_number(text_cell)
                if x is None:
                    if c in strict:
                        problems.append(Problem(file, f"line {number}, column {header[c]!r}", text_cell,
                                                number_problem(text_cell)))
                    else:
                        text_cols[c] = []
                    continue
                if c == it and not math.isfinite(x):
                    problems.append(Problem(file, f"line {number}, column {time_column!r}", text_cell,
                                            "a finite time in seconds"))
                values[r, c] = x
        if len(problems) >= _MAX_PROBLEMS:
            break
    if len(problems) < _MAX_PROBLEMS:
        t = values[:, it]  # NaN where the time itself was bad (already reported)
        for r in (np.flatnonzero(np.diff(t) <= 0) + 1).tolist():
            what = "repeats" if t[r] == t[r - 1] else "goes back from"
            problems.append(Problem(file, f"line {row_lines[r]}, column {time_column!r}", float(t[r]),
                                    f"strictly increasing times (it {what} {float(t[r - 1])!r} on line "
                                    f"{row_lines[r - 1]})"))
            if len(problems) >= _MAX_PROBLEMS:
                break
    if len(problems) >= _MAX_PROBLEMS:
        problems.append(Problem(file, "", "more problems", f"(stopped after the first {_MAX_PROBLEMS})"))
    if problems:
        raise ConfigError(problems, "log")
    data = {name: values[:, i].copy() for i, name in enumerate(header) if i not in text_cols}
    texts = {header[c]: [_unquote(cells[c]) for cells in rows] for c in text_cols}
    return Log(file=file, columns=tuple(header), data=data, lines=np.asarray(row_lines, dtype=np.int64),
               comments=tuple(comments), time_column=time_column, text=texts)


def _split(line: str) -> list[str]:
    return next(csv.reader([line])) if '"' in line else line.split(",")


def _check_header(file: str, header: list[str] | None, header_line: int, need: Sequence[str]) -> None:
    if header is None:
        raise ConfigError([Problem(file, "", "an empty file",
                                   "a header line of column names: " + ", ".join(need))], "log")
    where_header = f"line {header_line} (header)"
    problems: list[Problem] = []
    for i, name in enumerate(header):
        if not name:
            problems.append(Problem(file, where_header, f"column {i + 1} has no name", "a name for every column"))
    dups = sorted({n for n in header if n and header.count(n) > 1})
    if dups:
        problems.append(Problem(file, where_header, ", ".join(dups), "unique column names"))
    missing = [n for n in need if n not in header]
    if missing:
        sep = next((s for s in (";", "\t") if len(header) == 1 and s in header[0]), None)
        hint = f" (the header looks {sep!r}-separated; use commas)" if sep else ""
        problems.append(Problem(file, where_header, ", ".join(header) or "(no columns)",
                                f"columns {', '.join(need)} (missing: {', '.join(missing)}){hint}"))
    if problems:
        raise ConfigError(problems, "log")


# --------------------------------------------------------------------------------------------
# Streaming: long logs in chunks, memory flat
# --------------------------------------------------------------------------------------------

CHUNK_ROWS = 1 << 12  # ~256 KiB blocks: peak memory grows with the block (1 << 14: +13 MiB), speed does not
PREFETCH = 4  # chunks parsed ahead by the reader thread (~0.2 MiB each with six columns)


@dataclass(frozen=True, eq=False)
class LogChunk:
    """Consecutive rows of a log: the wanted columns as float arrays (NaN = no value)."""

    start: int  # index in the log of the first row
    data: Mapping[str, np.ndarray]

    def __len__(self) -> int:
        return int(next(iter(self.data.values())).size)


class LogStream:
    """The time and ``required`` columns of a log, read in chunks of about ``chunk_rows`` rows.

    Same format and the same refusals as :func:`read_log` (other columns are not read). The file
    is read in blocks of whole lines (about 64 bytes a row), each parsed on its own, so memory
    does not grow with the log. The fast path parses a block with pyarrow's CSV reader (the
    ``arrow`` extra): numbers in C++. A block it cannot read, or with a cell it reads as inf or
    NaN, or with times out of order, goes to the careful line scanner, which names the line and
    column of each problem (up to 20 a block); without pyarrow the careful scanner reads every
    block. Lines are counted only when a message needs one (:meth:`where`).

    Iterating raises :class:`ConfigError` at the first chunk with a problem; the chunks before
    it have been yielded already, so a consumer writes its output somewhere temporary first.
    """

    def __init__(self, path: str | Path, *, required: Sequence[str] = (), time_column: str = "time_s",
                 chunk_rows: int = CHUNK_ROWS, fast: bool = True) -> None:
        self.path = Path(path)
        self.file = str(path)
        self.time_column = time_column
        self.need = [time_column] + [c for c in required if c != time_column]
        self.chunk_rows = max(1, int(chunk_rows))
        self.comments: list[str] = []
        self._fast = fast
        self._data_start = 0  # byte offset of the first line after the header
        self._header_line = 0
        self.header = self._read_header()
        self.rows = 0  # rows yielded so far

    # -- header -------------------------------------------------------------------------------
    def _open_error(self, exc: OSError) -> ConfigError:
        if isinstance(exc, FileNotFoundError):
            return ConfigError([Problem(self.file, "", "no such file", "an existing CSV log")], "log")
        if isinstance(exc, IsADirectoryError):
            return ConfigError([Problem(self.file, "", "a directory", "a CSV log file")], "log")
        return ConfigError([Problem(self.file, "", exc.strerror or str(exc), "a readable CSV log")], "log")

    def _read_header(self) -> list[str]:
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise self._open_error(exc) from None
        header = None
        with f:
            number = 0
            while True:
                raw = f.readline()
                if not raw:
                    break
                number += 1
                try:
                    line = raw.decode("utf-8")
                except UnicodeDecodeError as exc:
                    raise ConfigError([Problem(self.file, f"line {number}", "undecodable bytes",
                                               f"UTF-8 text ({exc.reason})")], "log") from None
                if number == 1:
                    line = line.removeprefix("\ufeff")
                line = line.strip()
                if not line:
                    continue
                if line.startswith("#"):
                    self.comments.append(line[1:].strip())
                    continue
                header = [c.strip() for c in _split(line)]
                break
            self._data_start = f.tell()
        self._header_line = number
        _check_header(self.file, header, number, self.need)
        assert header is not None
        return header

    # -- line numbers (error path only) --------------------------------------------------------
    def _data_lines(self, start_row: int = 0) -> Iterator[tuple[int, int, str]]:
        """(row index, line number, text) of the data lines from ``start_row`` on."""
        row = 0
        number = self._header_line
        with open(self.path, "rb") as f:
            f.seek(self._data_start)
            for raw in f:
                number += 1
                if row < start_row:  # counting only: bytes, no decoding
                    stripped = raw.strip()
                    if stripped and not stripped.startswith(b"#"):
                        row += 1
                    continue
                try:
                    line = raw.decode("utf-8").strip()
                except UnicodeDecodeError as exc:
                    raise ConfigError([Problem(self.file, f"line {number}", "undecodable bytes",
                                               f"UTF-8 text ({exc.reason})")], "log") from None
                if not line or line.startswith("#"):
                    continue
                yield row, number, line
                row += 1

    def line_of(self, row: int) -> int | None:
        """File line of a data row (counted on demand: for messages)."""
        for r, number, _ in self._data_lines(row):
            if r == row:
                return number
            break
        return None

    def where(self, row: int, column: str | None = None) -> str:
        number = self.line_of(row)
        text = f"line {number}" if number is not None else "end of file"
        return f"{text}, column {column!r}" if column else text

    def problem(self, row: int, column: str | None, value: object, expected: str) -> ConfigError:
        return ConfigError([Problem(self.file, self.where(row, column), value, expected)], "log")

    # -- chunks -------------------------------------------------------------------------------
    def __iter__(self) -> Iterator[LogChunk]:
        """Blocks of whole lines (~``chunk_rows`` rows) parsed one at a time: memory stays flat.

        With pyarrow the blocks are parsed on a reader thread, at most ``PREFETCH`` chunks ahead
        of the consumer (pyarrow parses without the GIL, so this overlaps the consumer's work);
        call ``close()`` on the iterator to stop it early. The careful scanner needs the GIL
        throughout and runs in the consumer's thread."""
        pa = None
        if self._fast:
            try:
                import pyarrow
                import pyarrow.csv  # noqa: F401
                pa = pyarrow
            except ImportError:
                pa = None
        chunks = self._chunks(pa)
        return chunks if pa is None else _Prefetch(chunks, PREFETCH)

    def _chunks(self, pa) -> Iterator[LogChunk]:
        self.rows = 0
        self._last_t = (math.nan, 0)  # (time, line or 0 if unknown) of the last row yielded
        block_bytes = max(1 << 12, 64 * self.chunk_rows)
        with open(self.path, "rb") as f:
            f.seek(self._data_start)
            line = self._header_line  # lines before this block
            rest = b""
            while True:
                block = f.read(block_bytes)
                data = rest + block
                if block:
                    cut = data.rfind(b"\n") + 1
                    if cut == 0:
                        rest = data
                        continue
                    data, rest = data[:cut], data[cut:]
                else:
                    rest = b""
                if data:
                    chunk = self._parse_block(pa, data, line)
                    if chunk is not None:
                        yield chunk
                    line += data.count(b"\n")
                if not block:
                    break
        if self.rows == 0:
            raise ConfigError([Problem(self.file, "", "no data rows", "at least one row after the header")], "log")

    def _parse_block(self, pa, data: bytes, line: int) -> LogChunk | None:
        """The rows of one block of whole lines (the first is line ``line + 1``)."""
        if pa is not None:
            csv_mod = pa.csv
            try:
                table = csv_mod.read_csv(
                    pa.BufferReader(data), memory_pool=pa.system_memory_pool(),  # mimalloc keeps ~10 MiB more
                    read_options=csv_mod.ReadOptions(column_names=self.header, use_threads=False),
                    convert_options=csv_mod.ConvertOptions(
                        include_columns=self.need, column_types={c: pa.float64() for c in self.need},
                        null_values=sorted(_MISSING), strings_can_be_null=False, quoted_strings_can_be_null=True))
            except pa.ArrowInvalid:
                return self._careful_block(data, line)  # names the line and column of each problem
            if table.num_rows == 0:
                return None
            values = {}
            suspicious = np.zeros(table.num_rows, dtype=bool)
            for c in self.need:
                col = table.column(c)
                parts = [_float_array(chunk) for chunk in col.chunks]
                arr = parts[0] if len(parts) == 1 else np.concatenate(parts)
                values[c] = arr
                if c == self.time_column:
                    suspicious |= ~np.isfinite(arr)
                else:
                    # inf, or NaN spelt other than as a missing value: the careful scanner decides
                    if col.null_count != np.count_nonzero(np.isnan(arr)):
                        suspicious |= np.isnan(arr)  # some NaN spelt otherwise than as a missing value
                    suspicious |= np.isinf(arr)
            if suspicious.any():
                return self._careful_block(data, line)
            t = values[self.time_column]
            if np.any(np.diff(t) <= 0) or (self.rows and not t[0] > self._last_t[0]):
                return self._careful_block(data, line)  # time order checked with line numbers
            return self._chunk(values, None)
        return self._careful_block(data, line)

    def _careful_block(self, data: bytes, line: int) -> LogChunk | None:
        """The careful scanner on one block: every problem with its line and column (up to 20)."""
        idx = [self.header.index(c) for c in self.need]
        n = len(self.header)
        problems: list[Problem] = []
        rows: list[list[float]] = []
        lines: list[int] = []
        number = line
        for raw in data.split(b"\n")[:-1] if data.endswith(b"\n") else data.split(b"\n"):
            number += 1
            try:
                text = raw.decode("utf-8").strip()
            except UnicodeDecodeError as exc:
                problems.append(Problem(self.file, f"line {number}", "undecodable bytes", f"UTF-8 text ({exc.reason})"))
                continue
            if not text or text.startswith("#"):
                continue
            cells = _split(text)
            if len(cells) > n and not any(c.strip() for c in cells[n:]):
                cells = cells[:n]
            if len(cells) != n:
                problems.append(Problem(self.file, f"line {number}", f"{len(cells)} fields",
                                        f"{n} fields, one per column ({', '.join(self.header)})"))
            else:
                row = []
                for c, i in zip(self.need, idx):
                    x = _cell_value(self.file, number, c, cells[i].strip(), c == self.time_column, problems)
                    row.append(math.nan if x is None else x)
                rows.append(row)
                lines.append(number)
            if len(problems) >= _MAX_PROBLEMS:
                break
        _raise(problems)
        if not rows:
            return None
        values = np.array(rows, dtype=float)
        return self._chunk({c: values[:, j].copy() for j, c in enumerate(self.need)}, lines)

    def _chunk(self, data: dict[str, np.ndarray], lines: list[int] | None) -> LogChunk:
        t = data[self.time_column]
        if lines is not None:
            self._check_times(t, lines)
        chunk = LogChunk(self.rows, data)
        self.rows += t.size
        self._last_t = (float(t[-1]), lines[-1] if lines is not None else 0)
        return chunk

    def _check_times(self, t: np.ndarray, lines: Sequence[int]) -> None:
        prev_t, prev_line = self._last_t
        full = np.concatenate([[prev_t], t]) if self.rows > 0 else t
        offset = 1 if self.rows > 0 else 0
        problems = []
        for b in np.flatnonzero(np.diff(full) <= 0)[:_MAX_PROBLEMS]:
            r = int(b) + 1 - offset  # index in this block
            before = lines[r - 1] if r >= 1 else (prev_line or self.line_of(self.rows - 1))
            what = "repeats" if full[b + 1] == full[b] else "goes back from"
            problems.append(Problem(self.file, f"line {lines[r]}, column {self.time_column!r}", float(full[b + 1]),
                                    f"strictly increasing times (it {what} {float(full[b])!r} on line {before})"))
        _raise(problems)


class _Prefetch(Iterator[LogChunk]):
    """The items of ``items`` produced on a worker thread, at most ``depth`` ahead of the
    consumer; an exception is raised to the consumer where it occurred in the sequence. The
    thread stops when the items end, on :meth:`close`, or when this iterator is dropped (it holds
    no reference to it)."""

    def __init__(self, items: Iterator[LogChunk], depth: int) -> None:
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=_produce, args=(items, self._queue, self._stop),
                                        name="rovlab-log-reader", daemon=True)
        self._thread.start()

    def __next__(self) -> LogChunk:
        if self._done:
            raise StopIteration
        more, item = self._queue.get()
        if more:
            return item
        self._done = True
        self._thread.join()
        if item is not None:
            raise item
        raise StopIteration

    def close(self) -> None:
        """Stop the reader thread (the chunks not consumed are dropped)."""
        self._done = True
        self._stop.set()
        self._thread.join()

    def __del__(self) -> None:
        self._stop.set()


def _produce(items: Iterator[LogChunk], out: queue.Queue, stop: threading.Event) -> None:
    """The reader thread of :class:`_Prefetch`: (True, item) per item, then (False, None) or
    (False, exception)."""

    def put(entry: tuple[bool, Any]) -> bool:
        while not stop.is_set():
            try:
                out.put(entry, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    try:
        for item in items:
            if not put((True, item)):
                return  # closed by the consumer
        put((False, None))
    except BaseException as exc:  # noqa: B036 -- handed to the consumer, raised there
        put((False, exc))
    finally:
        close = getattr(items, "close", None)
        if close is not None:
            close()


def _float_array(chunk) -> np.ndarray:
    """A pyarrow float64 array as numpy, nulls as NaN, read from its buffers (pyarrow's own
    to_numpy imports pandas for arrays with nulls: 0.4 s)."""
    n = len(chunk)
    validity, data = chunk.buffers()[:2]
    arr = np.frombuffer(data, dtype=np.float64, count=chunk.offset + n)[chunk.offset:]
    if chunk.null_count:
        bits = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
        arr = np.where(bits[chunk.offset:chunk.offset + n].astype(bool), arr, np.nan)
    return arr


def _cell_value(file: str, number: int, column: str, text: str, is_time: bool,
                problems: list[Problem]) -> float | None:
    """One cell of a wanted column (None = no value), or a problem appended."""
    if text in _MISSING:
        if is_time:
            problems.append(Problem(file, f"line {number}, column {column!r}", text or "(empty)",
                                    "a time in seconds"))
        return None
    x = parse_number(text)
    if x is None:
        problems.append(Problem(file, f"line {number}, column {column!r}", text, number_problem(text)))
        return None
    if is_time and not math.isfinite(x):
        problems.append(Problem(file, f"line {number}, column {column!r}", text, "a finite time in seconds"))
        return None
    return x


def _raise(problems: list[Problem]) -> None:
    if not problems:
        return
    if len(problems) >= _MAX_PROBLEMS:
        problems = problems[:_MAX_PROBLEMS] + [Problem(problems[0].file, "", "more problems",
                                                       f"(stopped after the first {_MAX_PROBLEMS})")]
    raise ConfigError(problems, "log")


def _unquote(cell: str) -> str:
    return cell.strip()

