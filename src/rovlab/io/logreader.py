"""Reading time-stamped CSV logs through pyarrow's CSV reader, every problem named with its line.

Log format (what ``rovlab filter`` reads and what the simulator writes): UTF-8 text (a
byte-order mark is ignored), optional ``#`` comment lines, one header line of comma-separated
column names, then one row per sample. One column is the time (``time_s`` by default): finite
and strictly increasing. Every other cell is a number, ``nan``, ``inf``/``-inf``, or empty;
empty and ``nan`` both mean "no value at this time" (a sensor that did not deliver a sample),
``inf`` is kept (a faulty sample). Extra columns are allowed and kept. Blank lines are skipped,
CRLF line endings are accepted, cells may be quoted (``"a,b"``) but not span lines.

pyarrow splits and parses the rows (:mod:`rovlab.io.csvfile`); what it read is then checked
column by column, and every problem is a :class:`rovlab.params.validate.ConfigError` naming the
file, the line and the column, e.g. ``log.csv: line 7, column 'z_pressure': got 'abc'; expected
a number``.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.io.csvfile import DATA, Rows, bools, comments, float_array, header_cells, read_rows, split_lines, strings
from rovlab.params.validate import ConfigError, Problem

_MAX_PROBLEMS = 20
MISSING = ("", "nan", "NaN", "NAN", "na", "NA")  # no value at this time
# A number as C, CSV readers and spreadsheets write one (RE2, as pyarrow's compute functions take
# it): ASCII digits, optional sign, point and exponent, or inf/infinity. Python's float() also
# takes '1_000' and non-ASCII digits ('１２'), which no other tool reads as numbers: refused.
NUMBER = r"^[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:inf|infinity))$"
NUMBER_EXPECTED = "a number (ASCII digits, e.g. 1.5e-3; or empty / nan for no value)"
RANGE_EXPECTED = "a number within +-1.8e308 (inf is written inf)"
_BOM = "\ufeff".encode()


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
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError([Problem(file, "", "no such file", "an existing CSV log")], "log") from None
    except IsADirectoryError:
        raise ConfigError([Problem(file, "", "a directory", "a CSV log file")], "log") from None
    try:
        data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError([Problem(file, "", "undecodable bytes",
                                   f"UTF-8 text ({exc.reason} at byte {exc.start})")], "log") from None
    return _parse(data, file, required, time_column)


def parse_log(text: str, *, file: str = "<text>", required: Sequence[str] = (),
              time_column: str = "time_s") -> Log:
    """Parse the text of a log (see :func:`read_log`).

    The time and the ``required`` columns must hold numbers (or no value); any other column is
    read as numbers when every cell is one, and kept as text otherwise (``Log.text``).
    """
    return _parse(text.encode("utf-8", errors="surrogatepass"), file, required, time_column)


def _parse(data: bytes, file: str, required: Sequence[str], time_column: str) -> Log:
    data = data.removeprefix(_BOM)
    lines = split_lines(data)
    found = np.flatnonzero(lines.kind == DATA)
    need = [time_column] + [c for c in required if c != time_column]
    header = None
    if found.size:
        h = int(found[0])
        header = [c.strip() for c in header_cells(data[lines.start[h]:lines.end[h]])]
    header_line = int(found[0]) + 1 if found.size else 0
    _check_header(file, header, header_line, need)
    assert header is not None  # _check_header refuses a file without one
    rest = data[lines.start[header_line]:] if header_line < len(lines) else b""
    rows = read_rows(rest, header, file=file, first_line=header_line)
    if not len(rows) and not rows.problems:
        raise ConfigError([Problem(file, "", "no data rows", "at least one row after the header")], "log")
    problems = list(rows.problems)
    values: dict[str, np.ndarray] = {}
    texts: dict[str, list[str]] = {}
    for j, name in enumerate(header):
        column = _Column(rows, name, j, file)
        if name in need:
            values[name] = column.strict(problems, is_time=name == time_column)
        elif column.bad.any():
            texts[name] = column.text.to_pylist()
        else:
            values[name] = column.value
    if len(problems) < _MAX_PROBLEMS:
        t = values[time_column]  # NaN where the time itself was bad (already reported)
        for r in (np.flatnonzero(np.diff(t) <= 0) + 1)[:_MAX_PROBLEMS + 1].tolist():
            what = "repeats" if t[r] == t[r - 1] else "goes back from"
            line = int(rows.lines[r])
            problems.append((line, header.index(time_column), Problem(
                file, f"line {line}, column {time_column!r}", float(t[r]),
                f"strictly increasing times (it {what} {float(t[r - 1])!r} on line {int(rows.lines[r - 1])})")))
    _raise(problems)
    return Log(file=file, columns=tuple(header), data=values, lines=rows.lines, comments=tuple(comments(data, lines)),
               time_column=time_column, text=texts)


class _Column:
    """The cells of one column read as strings: the text (stripped), which are missing values,
    which are numbers (and their value, NaN otherwise), which are out of range (1e400)."""

    def __init__(self, rows: Rows, name: str, index: int, file: str) -> None:
        import pyarrow as pa
        import pyarrow.compute as pc

        self.rows, self.name, self.index, self.file = rows, name, index, file
        self.text = pc.utf8_trim_whitespace(rows.cells[name])
        self.missing = bools(pc.is_in(self.text, value_set=strings(MISSING)))
        number = pc.match_substring_regex(self.text, NUMBER)
        self.number = bools(number)
        self.value = np.full(self.number.size, np.nan)
        self.overflow = np.zeros(self.number.size, dtype=bool)
        if self.number.any():
            self.value[self.number] = float_array(pc.cast(pc.filter(self.text, number), pa.float64()))
            inf = np.isinf(self.value)
            if inf.any():  # 1e400 is out of range, not 'inf'
                self.overflow = inf & ~bools(pc.match_substring(self.text, "n", ignore_case=True))
                self.value[self.overflow] = np.nan
                self.number &= ~self.overflow
        self.bad = ~self.missing & ~self.number

    def cell(self, r: int) -> str:
        return str(self.text[r].as_py())

    def strict(self, problems: list[tuple[int, int, Problem]], *, is_time: bool = False) -> np.ndarray:
        """The values; a problem for each cell that is not a number (up to the limit), and for a
        time: no value or not finite."""
        value = self.value
        bad = self.bad | (self.missing if is_time else False)
        if is_time:
            bad = bad | (self.number & ~np.isfinite(value))
            value = np.where(np.isfinite(value), value, np.nan)
        for r in np.flatnonzero(bad)[:_MAX_PROBLEMS + 1].tolist():
            text = self.cell(r)
            if self.missing[r]:
                expected = "a time in seconds"
                text = text or "(empty)"
            elif self.number[r]:
                expected = "a finite time in seconds"
            else:
                expected = RANGE_EXPECTED if self.overflow[r] else NUMBER_EXPECTED
            line = int(self.rows.lines[r])
            problems.append((line, self.index, Problem(self.file, f"line {line}, column {self.name!r}", text, expected)))
        return value


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


def _raise(problems: list[tuple[int, int, Problem]]) -> None:
    """Raise the problems in the order of the file (line, then column), the first 20."""
    if not problems:
        return
    ordered = [p for _, _, p in sorted(problems, key=lambda item: item[:2])]
    if len(ordered) > _MAX_PROBLEMS:
        ordered = ordered[:_MAX_PROBLEMS] + [Problem(ordered[0].file, "", "more problems",
                                                     f"(stopped after the first {_MAX_PROBLEMS})")]
    raise ConfigError(ordered, "log")


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
    is read in blocks of whole lines (about 64 bytes a row), each parsed on its own by pyarrow,
    so memory does not grow with the log. pyarrow first parses a block straight into numbers
    (``fast``); a block it cannot read so, or with a comment or blank line, a cell it reads as
    inf or NaN, or times out of order, is read again as text and checked cell by cell like
    :func:`read_log` (up to 20 problems a block, each with its line and column). ``fast=False``
    checks every block so. A row's file line is found only when a message needs one (:meth:`where`).

    The blocks are parsed on a reader thread, at most ``PREFETCH`` chunks ahead of the consumer
    (pyarrow parses without the GIL); iterating raises :class:`ConfigError` at the first chunk
    with a problem. The chunks before it have been yielded already, so a consumer writes its
    output somewhere temporary first.
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
        self._last_t = (math.nan, 0)

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
                header = [c.strip() for c in header_cells(line.encode("utf-8"))]
                break
            self._data_start = f.tell()
        self._header_line = number
        _check_header(self.file, header, number, self.need)
        assert header is not None
        return header

    # -- line numbers (error path only) --------------------------------------------------------
    def _blocks(self) -> Iterator[tuple[bytes, int, int]]:
        """Blocks of whole lines after the header: (bytes, lines before it, lines in it)."""
        block_bytes = max(1 << 12, 64 * self.chunk_rows)
        with open(self.path, "rb") as f:
            f.seek(self._data_start)
            line = self._header_line
            rest = b""
            while True:
                block = f.read(block_bytes)
                data = rest + block
                if block:  # up to the last line break (a \r at the end may be half a \r\n)
                    cut = max(data.rfind(b"\n"), data.rfind(b"\r", 0, len(data) - 1)) + 1
                    if cut == 0:
                        rest = data
                        continue
                    data, rest = data[:cut], data[cut:]
                else:
                    rest = b""
                if data:
                    count = len(split_lines(data)) if b"\r" in data else data.count(b"\n") + (not data.endswith(b"\n"))
                    yield data, line, count
                    line += count
                if not block:
                    break

    def line_of(self, row: int) -> int | None:
        """File line of a data row (counted on demand: for messages)."""
        seen = 0
        for data, line, _ in self._blocks():
            rows = np.flatnonzero(split_lines(data).kind == DATA)
            if row < seen + rows.size:
                return line + int(rows[row - seen]) + 1
            seen += rows.size
        return None

    def where(self, row: int, column: str | None = None) -> str:
        number = self.line_of(row)
        text = f"line {number}" if number is not None else "end of file"
        return f"{text}, column {column!r}" if column else text

    def problem(self, row: int, column: str | None, value: object, expected: str) -> ConfigError:
        return ConfigError([Problem(self.file, self.where(row, column), value, expected)], "log")

    # -- chunks -------------------------------------------------------------------------------
    def __iter__(self) -> Iterator[LogChunk]:
        """Blocks of whole lines (~``chunk_rows`` rows) parsed one at a time on a reader thread;
        call ``close()`` on the iterator to stop it early."""
        return _Prefetch(self._chunks(), PREFETCH)

    def _chunks(self) -> Iterator[LogChunk]:
        self.rows = 0
        self._last_t = (math.nan, 0)  # (time, line or 0 if unknown) of the last row yielded
        for data, line, count in self._blocks():
            chunk = self._parse_block(data, line, count)
            if chunk is not None:
                yield chunk
        if self.rows == 0:
            raise ConfigError([Problem(self.file, "", "no data rows", "at least one row after the header")], "log")

    def _parse_block(self, data: bytes, line: int, count: int) -> LogChunk | None:
        """The rows of one block of ``count`` whole lines (the first is line ``line + 1``)."""
        values = self._numbers(data, count) if self._fast else None
        if values is not None:
            return self._chunk(values, None)
        return self._checked_block(data, line)

    def _numbers(self, data: bytes, count: int) -> dict[str, np.ndarray] | None:
        """The block parsed straight into numbers, or None if it needs the checked reading: pyarrow
        could not, a row is not one line, or a value or the time order needs a closer look."""
        import pyarrow as pa
        import pyarrow.csv as pcsv

        if b"#" in data and (data.startswith(b"#") or b"\n#" in data or b"\r#" in data):
            return None  # comment lines
        try:
            table = pcsv.read_csv(
                pa.BufferReader(data), memory_pool=pa.system_memory_pool(),  # mimalloc keeps ~10 MiB more
                read_options=pcsv.ReadOptions(column_names=self.header, use_threads=False),
                convert_options=pcsv.ConvertOptions(
                    include_columns=self.need, column_types={c: pa.float64() for c in self.need},
                    null_values=list(MISSING), strings_can_be_null=False, quoted_strings_can_be_null=True))
        except pa.ArrowInvalid:
            return None
        if table.num_rows != count:
            return None  # blank lines or a quoted line break
        values = {}
        suspicious = False
        for c in self.need:
            col = table.column(c)
            arr = float_array(col)
            values[c] = arr
            finite = np.isfinite(arr)
            if c == self.time_column:
                suspicious |= not finite.all()
            elif not finite.all():  # inf, or NaN spelt other than as a missing value
                suspicious |= bool(np.isinf(arr).any()) or col.null_count != np.count_nonzero(np.isnan(arr))
        t = values[self.time_column]
        if suspicious or np.any(np.diff(t) <= 0) or (self.rows and t.size and not t[0] > self._last_t[0]):
            return None  # time order checked with line numbers
        return values if t.size else None

    def _checked_block(self, data: bytes, line: int) -> LogChunk | None:
        """The block read as text and checked cell by cell: every problem with its line and column."""
        rows = read_rows(data, self.header, file=self.file, first_line=line, include=self.need)
        problems = list(rows.problems)
        values = {c: _Column(rows, c, self.header.index(c), self.file).strict(problems, is_time=c == self.time_column)
                  for c in self.need}
        _raise(problems)
        if not len(rows):
            return None
        return self._chunk(values, rows.lines.tolist())

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
        for b in np.flatnonzero(np.diff(full) <= 0)[:_MAX_PROBLEMS + 1]:
            r = int(b) + 1 - offset  # index in this block
            before = lines[r - 1] if r >= 1 else (prev_line or self.line_of(self.rows - 1))
            what = "repeats" if full[b + 1] == full[b] else "goes back from"
            problems.append((lines[r], 0, Problem(
                self.file, f"line {lines[r]}, column {self.time_column!r}", float(full[b + 1]),
                f"strictly increasing times (it {what} {float(full[b])!r} on line {before})")))
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
