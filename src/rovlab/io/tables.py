"""Small numeric CSV tables: the data files of the lab experiments (and the maker's T200 tables).

Format: UTF-8 text (a byte-order mark is ignored), one header line of comma-separated column
names, then one row of numbers per line. Lines starting with ``#`` are comments (the virtual lab
writes its seed and true parameters there); blank lines are skipped; CRLF line endings and
trailing empty fields (``1100,-2.90,``) are accepted. Every value must be a finite number. Cells
are not quoted (a quote is a character like any other).

pyarrow reads the rows (:mod:`rovlab.io.csvfile`); every problem is reported as a
:class:`rovlab.params.validate.ConfigError` naming the file, the line and the column, so that
command-line tools print it without a traceback::

    runs.csv: line 7, column 'force_n': got 'abc'; expected a number
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.files import atomic_write_bytes, atomic_write_text
from rovlab.io.csvfile import DATA, bools, comments, csv_rows, float_array, head, header_cells, read_rows, split_lines, strings
from rovlab.params.validate import ConfigError, Problem

_MAX_PROBLEMS = 20  # stop collecting after this many bad cells (the rest are likely the same)

# A number as a lab instrument writes it (RE2, as pyarrow's compute functions take it): ASCII
# digits, optional sign, decimal point and exponent. Python's float() also takes '1_000' and '１２'
# (other scripts' digits); those are refused, as is anything that is not finite.
_NUMBER = r"^(?i:[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:e[+-]?[0-9]+)?|[+-]?(?:inf|infinity|nan))$"

# Plausible magnitudes of a lab log's values, by the unit suffix of the column name (SI; see
# docs/identification.md). A fuzzer's times or positions scaled by 1e154 or 1e-300 used to end in
# overflows, a ZeroDivisionError or an SVD failure deep in the fits.
COLUMN_LIMITS: dict[str, float] = {
    "_s": 1e8,  # time [s]: about three years
    "_us": 1e4,  # PWM [us]
    "_n": 1e5,  # force [N]
    "_kgf": 1e4,  # force [kgf]
    "_nm": 1e4,  # moment [N m]
    "_m": 1e4,  # position [m]
    "_mps": 100.0,  # speed [m/s]
    "_rad": 1e6,  # angle, unwrapped [rad]
}
DEFAULT_LIMIT = 1e9  # other columns (sensor channels of a resting log, run numbers)
TINY = 1e-30  # a non-zero value smaller than this is no instrument's reading: scaled data
MIN_SAMPLE_INTERVAL_S = 1e-6  # time steps below 1 us: not a lab log (or time in the wrong unit)


def column_limit(name: str) -> float:
    """The largest plausible magnitude of a column's values (by its unit suffix)."""
    for suffix, limit in COLUMN_LIMITS.items():
        if name.endswith(suffix):
            return limit
    return DEFAULT_LIMIT


@dataclass(frozen=True, eq=False)
class DataTable:
    """Columns of one CSV file as float arrays, with the file line of every row."""

    file: str
    columns: tuple[str, ...]
    data: Mapping[str, np.ndarray]
    lines: np.ndarray  # 1-based line number in the file of each row
    comments: tuple[str, ...] = ()  # comment lines (without the leading '#')

    def __len__(self) -> int:
        return int(self.lines.size)

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.data:
            raise ConfigError([Problem(self.file, "columns", list(self.columns),
                                       f"a column named {name!r}")], "data file")
        return self.data[name]

    def has(self, name: str) -> bool:
        return name in self.data

    def require(self, *names: str) -> None:
        """Raise a :class:`ConfigError` naming every missing column."""
        missing = [n for n in names if n not in self.data]
        if missing:
            raise ConfigError([Problem(
                self.file, "header", ", ".join(self.columns) or "(no columns)",
                "columns " + ", ".join(names) + " (missing: " + ", ".join(missing) + ")")], "data file")

    def problem(self, row: int | None, column: str | None, value: object, expected: str) -> ConfigError:
        """A :class:`ConfigError` pointing at one row (index into the arrays) and column."""
        return ConfigError([Problem(self.file, _where(self, row, column), value, expected)], "data file")

    def select(self, mask: np.ndarray) -> DataTable:
        """The rows where ``mask`` is true (same columns, same file)."""
        mask = np.asarray(mask, dtype=bool)
        return DataTable(self.file, self.columns, {k: v[mask] for k, v in self.data.items()},
                         self.lines[mask], self.comments)

    def meta(self) -> dict[str, str]:
        """``key = value`` pairs found in the comment lines (e.g. ``seed = 7``)."""
        out: dict[str, str] = {}
        for line in self.comments:
            if "=" in line:
                key, _, value = line.partition("=")
                if key.strip() and " " not in key.strip():
                    out[key.strip()] = value.strip()
        return out


def _where(table: DataTable, row: int | None, column: str | None) -> str:
    parts = []
    if row is not None and 0 <= row < len(table):
        parts.append(f"line {int(table.lines[row])}")
    if column is not None:
        parts.append(f"column {column!r}")
    return ", ".join(parts)


def read_table(path: str | Path, *, required: Sequence[str] = (), what: str = "data file") -> DataTable:
    """Read a numeric CSV file; raise :class:`ConfigError` naming file, line and column on any problem.

    ``required`` columns are checked before the values, so a file with the wrong header gets
    one clear message instead of a list of bad cells.
    """
    path = Path(path)
    file = str(path)
    try:
        data = path.read_bytes()
        data.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError([Problem(file, "", "no such file", "an existing CSV file")], what) from None
    except IsADirectoryError:
        raise ConfigError([Problem(file, "", "a directory", "a CSV file")], what) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([Problem(file, "", "undecodable bytes", f"UTF-8 text ({exc.reason} at byte "
                                   f"{exc.start})")], what) from None
    data = data.removeprefix("\ufeff".encode())
    lines = split_lines(data)
    found = np.flatnonzero(lines.kind == DATA)
    if not found.size:
        raise ConfigError([Problem(file, "", "an empty file", "a header line of column names, e.g. "
                                   + (", ".join(required) if required else "time_s, ..."))], what)
    header_line = int(found[0]) + 1
    header = _trim([c.strip() for c in header_cells(data[lines.start[header_line - 1]:lines.end[header_line - 1]],
                                                    quoted=False)])
    problems: list[Problem] = []
    where_header = f"line {header_line} (header)"
    sep = next((s for s in (";", "\t") if s in header[0]), None) if len(header) == 1 else None
    if len(header) == 1 and (sep or (required and len(required) > 1)):
        hint = f" (found {sep!r}-separated names)" if sep else ""
        names = ", ".join(required) if required else "time_s, ..."
        problems.append(Problem(file, where_header, header[0], f"comma-separated column names {names}{hint}"))
        raise ConfigError(problems, what)
    for i, name in enumerate(header):
        if not name:
            problems.append(Problem(file, where_header, f"column {i + 1} has no name", "a name for every column"))
        elif _is_number(name):
            problems.append(Problem(file, where_header, name, "column names (the header line is missing)"))
            break
    dups = sorted({n for n in header if n and header.count(n) > 1})
    if dups:
        problems.append(Problem(file, where_header, ", ".join(dups), "unique column names"))
    if problems:
        raise ConfigError(problems, what)
    missing = [n for n in required if n not in header]
    if missing:
        raise ConfigError([Problem(file, where_header, ", ".join(header),
                                   "columns " + ", ".join(required) + " (missing: " + ", ".join(missing) + ")")],
                          what)
    rest = data[lines.start[header_line]:] if header_line < len(lines) else b""
    rows = read_rows(rest, header, file=file, first_line=header_line, quoted=False, unit="values",
                     max_problems=_MAX_PROBLEMS)
    if not len(rows) and not rows.problems:
        raise ConfigError([Problem(file, "", "no data rows", "at least one row of numbers after the header")], what)

    found_problems = list(rows.problems)
    data_columns = {name: _numbers(rows, name, c, file, found_problems) for c, name in enumerate(header)}
    if found_problems:
        ordered = [p for _, _, p in sorted(found_problems, key=lambda item: item[:2])]
        if len(ordered) > _MAX_PROBLEMS:
            ordered = ordered[:_MAX_PROBLEMS] + [Problem(file, "", "more bad rows",
                                                         f"(stopped after the first {_MAX_PROBLEMS} problems)")]
        raise ConfigError(ordered, what)
    for arr in data_columns.values():
        arr.setflags(write=False)
    lines_of_rows = rows.lines.astype(int)
    lines_of_rows.setflags(write=False)
    notes = comments(data, lines)
    if not notes:  # metadata of files rovlab writes lives in a JSON sidecar (older files: '#' lines)
        side = read_sidecar(path).get("comments")
        if isinstance(side, list):
            notes = [str(c) for c in side]
    return DataTable(file, tuple(header), data_columns, lines_of_rows, tuple(notes))


def _numbers(rows: Any, name: str, c: int, file: str, problems: list[tuple[int, int, Problem]]) -> np.ndarray:
    """One column's values; a problem for each cell that is no finite, plausible number (the
    first 20)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    text = pc.utf8_trim_whitespace(rows.cells[name])
    matched = pc.match_substring_regex(text, _NUMBER)
    number = bools(matched)
    values = np.full(number.size, np.nan)
    if number.any():
        values[number] = float_array(pc.cast(pc.filter(text, matched), pa.float64()))
    limit = column_limit(name)
    with np.errstate(invalid="ignore"):
        magnitude = np.abs(values)
        bad = ~number | ~np.isfinite(values) | (magnitude > limit) | ((values != 0) & (magnitude < TINY))
    for r in np.flatnonzero(bad)[:_MAX_PROBLEMS + 1].tolist():
        line = int(rows.lines[r])
        where = f"line {line}, column {name!r}"
        cell = str(text[r].as_py())
        if not number[r]:
            problem = Problem(file, where, cell or "(empty)", "a number (ASCII digits, e.g. 1000 or 1.5e-3)")
        elif not np.isfinite(values[r]):
            problem = Problem(file, where, cell, "a finite number")
        elif magnitude[r] > limit:
            problem = Problem(file, where, cell, f"a magnitude of at most {limit:g} (the plausible range of this "
                              "column's unit, docs/identification.md)")
        else:
            problem = Problem(file, where, cell, f"0 or a magnitude of at least {TINY:g} (smaller is below any "
                              "instrument's resolution: were the values scaled?)")
        problems.append((line, c, problem))
    return values


def _trim(cells: list[str]) -> list[str]:
    while cells and not cells[-1]:
        cells.pop()
    return cells


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def sidecar_path(path: str | Path) -> Path:
    """The JSON file that holds a CSV file's metadata: ``<name>.json`` beside it."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def write_sidecar(path: str | Path, meta: Mapping[str, Any]) -> Path:
    """Write a CSV file's metadata as JSON beside it (CSV files stay plain RFC 4180, no comment
    lines, so pandas and spreadsheets read them with their defaults)."""
    target = sidecar_path(path)
    atomic_write_text(target, json.dumps(dict(meta), indent=1, default=str) + "\n")
    return target


def read_sidecar(path: str | Path) -> dict[str, Any]:
    """The metadata written by :func:`write_sidecar` ({} when there is none or it is unreadable)."""
    try:
        data = json.loads(sidecar_path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def write_table(path: str | Path, columns: Mapping[str, Iterable[float]], *,
                comments: Sequence[str] = (), formats: Mapping[str, str] | None = None) -> Path:
    """Write columns (all the same length) as plain CSV (atomic replace); ``comments`` (lines
    such as ``seed = 7``) go to the JSON sidecar (:func:`write_sidecar`, key ``comments``), where
    :func:`read_table` finds them again.

    ``formats`` maps a column to a ``format()`` spec (default ``.9g``; ``d`` for integers).
    """
    path = Path(path)
    names = list(columns)
    arrays = [np.asarray(list(v) if not isinstance(v, np.ndarray) else v) for v in columns.values()]
    sizes = {a.shape[0] for a in arrays}
    if len(sizes) > 1:
        raise ValueError(f"columns differ in length: {dict(zip(names, (a.shape[0] for a in arrays)))}")
    cells = []
    for name, arr in zip(names, arrays):
        spec = (formats or {}).get(name, ".9g")
        cells.append(strings([format(int(x) if spec == "d" else float(x), spec) for x in arr.tolist()]))
    atomic_write_bytes(path, head(names) + csv_rows(cells, names).to_pybytes())
    if comments:
        write_sidecar(path, {"comments": list(comments)})
    return path


def split_runs(table: DataTable, column: str = "run") -> list[tuple[int, DataTable]]:
    """The rows of each run (integer ``column``), in order of first appearance.

    A run's rows need not be contiguous in the file, but each run's time must increase.
    """
    ids = table[column]
    bad = np.flatnonzero((ids != np.round(ids)) | (np.abs(ids) > 1e9))
    if bad.size:
        raise table.problem(int(bad[0]), column, float(ids[bad[0]]), "an integer run number (|run| <= 1e9)")
    order: list[int] = []
    seen: set[int] = set()
    for x in ids.astype(int):
        if int(x) not in seen:
            seen.add(int(x))
            order.append(int(x))
    return [(rid, table.select(ids.astype(int) == rid)) for rid in order]


def require_increasing(table: DataTable, column: str = "time_s") -> None:
    """Raise naming the first row where ``column`` does not strictly increase."""
    x = table[column]
    bad = np.flatnonzero(np.diff(x) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise table.problem(i, column, float(x[i]), f"a value greater than the previous row's {float(x[i - 1]):g} "
                            "(time must increase)")
    bad = np.flatnonzero(np.diff(x) < MIN_SAMPLE_INTERVAL_S)
    if bad.size:
        i = int(bad[0]) + 1
        raise table.problem(i, column, float(x[i]), f"a time at least {MIN_SAMPLE_INTERVAL_S:g} s after the previous "
                            f"row's {float(x[i - 1]):.17g} (samples closer than that: time in seconds?)")
