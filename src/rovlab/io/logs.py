"""Time-stamped CSV logs: reading with line-numbered errors, and a generic CSV writer.

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
import io
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterable, Mapping, Sequence

import numpy as np

from rovlab.io.tables import scan_csv
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
    comments, header, header_line, rows, row_lines = scan_csv(
        text, split=lambda line: next(csv.reader([line])) if '"' in line else line.split(","))
    header = [c.strip() for c in header] if header is not None else None

    need = [time_column] + [c for c in required if c != time_column]
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
    if not rows:
        raise ConfigError([Problem(file, "", "no data rows", "at least one row after the header")], "log")

    n = len(header)
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
                try:
                    x = float(text_cell)
                except ValueError:
                    if c in strict:
                        problems.append(Problem(file, f"line {number}, column {header[c]!r}", text_cell,
                                                "a number (or empty / nan for no value)"))
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
        for r in np.flatnonzero(np.diff(t) <= 0) + 1:
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


def write_csv(target: str | Path | IO[str], columns: Mapping[str, Sequence | np.ndarray], *,
              float_format: str | None = None, comments: Iterable[str] = (),
              exact: Iterable[str] = ()) -> None:
    """Write equally long columns (numbers or strings) as CSV; ``-`` means standard output.

    Numbers are written exactly (shortest round-trip form) unless ``float_format`` (e.g.
    ``"%.6g"``) is given; the ``exact`` columns (e.g. ``("time_s",)``) are always written exactly, so
    that ``%.10g`` does not turn epoch time stamps (1.7e9 s) into whole seconds. NaN is written as an empty cell ("no value"), so what this writes
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
        target.write(text)  # type: ignore[union-attr]
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


def _unquote(cell: str) -> str:
    return cell.strip()


def _quote(text: str) -> str:
    if any(ch in text for ch in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text
