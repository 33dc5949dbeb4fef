"""CSV through pyarrow's CSV reader and writer: what rovlab's log and table readers and writers share.

pyarrow splits the lines into cells, unquotes them and parses numbers; this module does what it
has no option for, on the bytes and vectorised, so that every message can name a file line:
which lines are blank or ``#`` comments (dropped before pyarrow reads), the file line of each
row, the rows pyarrow could not take (undecodable bytes, a wrong number of fields, a quoted
cell running past the end of its line) and rows whose fields beyond the header's are all empty
(``1100,-2.90,``: taken). A line ends at ``\\n``, ``\\r\\n`` or a lone ``\\r``, where pyarrow ends a row.

Arrays are built from numpy's buffers and pyarrow's compute functions get no Python scalars:
``pa.array``, ``pa.scalar`` and ``Array.to_numpy`` import pandas when it is installed (0.3-0.7 s).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rovlab.params.validate import Problem

BLANK, COMMENT, DATA = 0, 1, 2
_SPACE = np.array([9, 11, 12, 32], dtype=np.uint8)  # tab, vertical tab, form feed, space


@dataclass(frozen=True, eq=False)
class Lines:
    """The physical lines of a block of bytes: byte offsets of each line's text (without its
    line break) and its kind (BLANK, COMMENT or DATA)."""

    start: np.ndarray
    end: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return int(self.start.size)


def split_lines(data: bytes) -> Lines:
    """The lines of ``data``: blank (ASCII white space only), comment (``#`` after white space) or data."""
    a = np.frombuffer(data, dtype=np.uint8)
    if a.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Lines(empty, empty, empty)
    lf, cr = a == 10, a == 13
    breaks = lf.copy()
    breaks[:-1] |= cr[:-1] & ~lf[1:]  # a lone \r
    breaks[-1] |= cr[-1]
    last = np.flatnonzero(breaks)  # the last byte of each line break
    crlf = np.zeros(last.size, dtype=bool)
    inner = last > 0
    crlf[inner] = lf[last[inner]] & cr[last[inner] - 1]
    start = np.concatenate(([0], last + 1))
    end = last - crlf
    if start[-1] < a.size:
        end = np.concatenate((end, [a.size]))
    else:
        start = start[:-1]
    text = np.flatnonzero(~(lf | cr | np.isin(a, _SPACE)))
    i = np.searchsorted(text, start)
    first = text[np.minimum(i, text.size - 1)] if text.size else np.zeros(start.size, dtype=np.int64)
    has_text = (i < text.size) & (first < end)
    kind = np.where(has_text, np.where(a[first] == 35, COMMENT, DATA), BLANK)  # 35: '#'
    return Lines(start, end, kind)


def line_text(data: bytes, lines: Lines, i: int) -> str:
    """The text of line i (undecodable bytes replaced)."""
    return data[lines.start[i]:lines.end[i]].decode("utf-8", errors="replace")


def comments(data: bytes, lines: Lines) -> list[str]:
    """The text of the comment lines after their '#', stripped."""
    return [line_text(data, lines, int(i)).strip()[1:].strip() for i in np.flatnonzero(lines.kind == COMMENT)]


def header_cells(line: bytes, *, quoted: bool = True) -> list[str]:
    """The cells of one header line as pyarrow splits them (unquoted, not stripped); a quote left
    open runs to the end of the line."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    count = line.count(b",") + 1
    for text in (line, line + b'"'):
        try:
            table = pcsv.read_csv(
                pa.BufferReader(text + b"\n"),
                read_options=pcsv.ReadOptions(autogenerate_column_names=True, use_threads=False),
                parse_options=pcsv.ParseOptions(quote_char='"' if quoted else False),
                convert_options=pcsv.ConvertOptions(column_types={f"f{i}": pa.string() for i in range(count)},
                                                    strings_can_be_null=False, quoted_strings_can_be_null=False))
        except pa.ArrowInvalid:
            continue  # a quote left open: closed at the end of the line
        return [str(table.column(i)[0].as_py()) for i in range(table.num_columns)]
    return [line.decode("utf-8", errors="replace")]


@dataclass(frozen=True, eq=False)
class Rows:
    """Data rows read by pyarrow: the cells of the columns read (string arrays), the file line of
    each row, and a problem for each line that is no row: (line, -1, problem), which sorts with
    problems of cells, (line, column, problem)."""

    cells: dict[str, Any]
    lines: np.ndarray
    problems: list[tuple[int, int, Problem]]

    def __len__(self) -> int:
        return int(self.lines.size)


def read_rows(data: bytes, names: Sequence[str], *, file: str, first_line: int = 0,
              include: Sequence[str] | None = None, quoted: bool = True, unit: str = "fields",
              max_problems: int = 20) -> Rows:
    """The data rows of ``data`` (whole lines, the first of them line ``first_line + 1`` of the
    file) under the header ``names``, the columns ``include`` (default: all) as strings.

    ``quoted``: cells may be quoted (``"a,b"``), else a quote is a character like any other.
    ``unit`` names the fields in messages (``3 fields``; lab tables say ``values``).
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    lines = split_lines(data)
    keep = lines.kind == DATA
    problems = _undecodable(data, lines, keep, file, first_line, max_problems)
    if not keep.all():
        data = _drop(data, lines, ~keep)
    numbers = first_line + 1 + np.flatnonzero(keep)  # the file line of each row pyarrow sees
    names = list(names)
    include = names if include is None else list(include)
    if numbers.size == 0:
        return Rows({c: strings([]) for c in include}, np.zeros(0, dtype=np.int64), problems)
    table, invalid = _parse(data, names, include, quoted)
    end = table.num_rows + len(invalid) + 1  # pyarrow's row numbers below this are rows of their own line
    if end - 1 != numbers.size:  # a quoted cell runs past the end of its line
        table, invalid, end, problem = _line_break_in_cell(data, names, include, quoted, numbers, file)
        problems.append(problem)
    order = _row_numbers(table.num_rows, invalid)
    cells = {c: table.column(c).combine_chunks() for c in include}

    # rows with more fields than the header, all of them empty beyond it: taken
    n = len(names)
    wider = [row for row in invalid if row[1] > n and row[0] < end]
    taken: set[int] = set()
    for count in sorted({k for _, k, _ in wider}):
        group = [(number, text) for number, k, text in wider if k == count]
        wide = [f"f{i}" for i in range(count)]
        sub, _ = _parse("\n".join(text for _, text in group).encode("utf-8") + b"\n", wide, wide, quoted)
        if sub.num_rows != len(group):
            continue  # not one row each: refused below
        extra = np.zeros(len(group), dtype=bool)
        for name in wide[n:]:
            extra |= bools(pc.match_substring_regex(pc.utf8_trim_whitespace(sub.column(name).combine_chunks()), "(?s)."))
        fine = np.flatnonzero(~extra)
        if fine.size:
            index = ints(fine)
            order = np.concatenate([order, np.array([group[i][0] for i in fine.tolist()], dtype=np.int64)])
            cells = {c: pa.concat_arrays([cells[c], sub.column(wide[names.index(c)]).combine_chunks().take(index)])
                     for c in include}
            taken.update(group[i][0] for i in fine.tolist())
    refused = [(number, count) for number, count, _ in sorted(invalid) if number < end and number not in taken]
    for number, count in refused[:max_problems + 1]:
        line = int(numbers[number - 1])
        problems.append((line, -1, Problem(file, f"line {line}", f"{count} {unit}",
                                           f"{n} {unit}, one per column ({', '.join(names)})")))
    if taken or not (order < end).all():
        pick = np.argsort(order, kind="stable")
        pick = pick[order[pick] < end]
        order = order[pick]
        cells = {c: arr.take(ints(pick)) for c, arr in cells.items()}
    return Rows(cells, numbers[order - 1].astype(np.int64), problems)


def _undecodable(data: bytes, lines: Lines, keep: np.ndarray, file: str, first_line: int,
                 max_problems: int) -> list[tuple[int, int, Problem]]:
    """A problem for each line that is not UTF-8 (up to ``max_problems``; those lines and, at the
    limit, the rest are taken out of ``keep``)."""
    problems: list[tuple[int, int, Problem]] = []
    pos = 0
    while pos < len(data):
        try:
            data[pos:].decode("utf-8")
            break
        except UnicodeDecodeError as exc:
            i = int(np.searchsorted(lines.start, pos + exc.start, side="right")) - 1
            line = first_line + i + 1
            problems.append((line, -1, Problem(file, f"line {line}", "undecodable bytes", f"UTF-8 text ({exc.reason})")))
            keep[i] = False
            if len(problems) > max_problems:
                keep[i:] = False
                break
            pos = int(lines.start[i + 1]) if i + 1 < len(lines) else len(data)
    return problems


def _row_numbers(num_rows: int, invalid: list[tuple[int, int, str]]) -> np.ndarray:
    """pyarrow's row numbers (from 1) of the rows of its table: those not among the invalid ones."""
    skipped = np.array(sorted(number for number, _, _ in invalid), dtype=np.int64)
    total = num_rows + skipped.size
    taken = np.ones(total + 1, dtype=bool)
    taken[0] = False
    taken[skipped] = False
    return np.flatnonzero(taken)


def _parse(data: bytes, names: list[str], include: list[str], quoted: bool) -> tuple[Any, list[tuple[int, int, str]]]:
    """pyarrow's table of ``data`` (string columns ``include``) and the rows it could not take:
    (row number from 1, number of fields, text)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    invalid: list[tuple[int, int, str]] = []

    def skip(row: Any) -> str:
        invalid.append((int(row.number), int(row.actual_columns), str(row.text)))
        return "skip"

    table = pcsv.read_csv(
        pa.BufferReader(data),
        read_options=pcsv.ReadOptions(column_names=names, use_threads=False, block_size=max(1 << 20, len(data) + 1)),
        parse_options=pcsv.ParseOptions(quote_char='"' if quoted else False, invalid_row_handler=skip),
        convert_options=pcsv.ConvertOptions(include_columns=include, column_types={c: pa.string() for c in include},
                                            strings_can_be_null=False, quoted_strings_can_be_null=False))
    return table, invalid


def _line_break_in_cell(data: bytes, names: list[str], include: list[str], quoted: bool, numbers: np.ndarray,
                        file: str) -> tuple[Any, list[tuple[int, int, str]], int, tuple[int, int, Problem]]:
    """The table and invalid rows of ``data``, pyarrow's row number of the first row with a line
    break in a cell (the rows before it are one line each) and the problem at its first line."""
    import pyarrow.compute as pc

    table, invalid = _parse(data, names, names, quoted)
    broken = np.zeros(table.num_rows, dtype=bool)
    for name in names:
        broken |= bools(pc.match_substring_regex(table.column(name).combine_chunks(), "[\r\n]"))
    found = [(int(_row_numbers(table.num_rows, invalid)[r]), next(
        text for text in (str(table.column(c)[r].as_py()) for c in names) if "\n" in text or "\r" in text))
        for r in np.flatnonzero(broken)[:1].tolist()]
    found += [(number, text) for number, _, text in invalid if "\n" in text or "\r" in text][:1]
    if found:
        end, cell = min(found)
        value = cell.splitlines()[0] if cell.splitlines() else cell
        expected = "a closing quote on the same line (a quoted cell may not span lines)"
    else:  # not seen with pyarrow's reader: named rather than guessed
        end, value, expected = 1, "rows that are not lines", "one row per line"
    line = int(numbers[min(end, numbers.size) - 1])
    return table.select(include), invalid, end, (line, -1, Problem(file, f"line {line}", value, expected))


def _drop(data: bytes, lines: Lines, mask: np.ndarray) -> bytes:
    """``data`` without the text of the lines in ``mask`` (their line breaks stay: empty lines)."""
    a = np.frombuffer(data, dtype=np.uint8)
    edge = np.zeros(a.size + 1, dtype=np.int64)
    edge[lines.start[mask]] += 1
    edge[lines.end[mask]] -= 1
    return a[np.cumsum(edge[:-1]) == 0].tobytes()


# --------------------------------------------------------------------------------------------
# arrays from numpy and back, without pandas
# --------------------------------------------------------------------------------------------

def bools(arr: Any) -> np.ndarray:
    """A pyarrow boolean array as numpy (null = False)."""
    n = len(arr)
    validity, values = arr.buffers()[:2]
    bits = np.unpackbits(np.frombuffer(values, dtype=np.uint8), bitorder="little")
    out = bits[arr.offset:arr.offset + n].astype(bool)
    if arr.null_count:
        valid = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
        out &= valid[arr.offset:arr.offset + n].astype(bool)
    return out


def float_array(arr: Any) -> np.ndarray:
    """A pyarrow float64 array (or chunked array) as numpy, nulls as NaN."""
    chunks = arr.chunks if hasattr(arr, "chunks") else [arr]
    parts = []
    for chunk in chunks:
        n = len(chunk)
        validity, data = chunk.buffers()[:2]
        values = np.frombuffer(data, dtype=np.float64, count=chunk.offset + n)[chunk.offset:]
        if chunk.null_count:
            bits = np.unpackbits(np.frombuffer(validity, dtype=np.uint8), bitorder="little")
            values = np.where(bits[chunk.offset:chunk.offset + n].astype(bool), values, np.nan)
        parts.append(values)
    if not parts:
        return np.zeros(0)
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def floats(x: np.ndarray) -> Any:
    """A float64 array for pyarrow, NaN as null (empty cells); shares x's memory."""
    import pyarrow as pa

    x = np.ascontiguousarray(x, dtype=np.float64)
    nan = np.isnan(x)
    validity = pa.py_buffer(np.packbits(~nan, bitorder="little")) if nan.any() else None
    return pa.Array.from_buffers(pa.float64(), x.size, [validity, pa.py_buffer(x)])


def ints(x: np.ndarray) -> Any:
    import pyarrow as pa

    x = np.ascontiguousarray(x, dtype=np.int64)
    return pa.Array.from_buffers(pa.int64(), x.size, [None, pa.py_buffer(x)])


def strings(items: Sequence[str | None]) -> Any:
    """A pyarrow string array (None = null)."""
    import pyarrow as pa

    encoded = [b"" if s is None else s.encode("utf-8") for s in items]
    offsets = np.zeros(len(encoded) + 1, dtype=np.int64)
    np.cumsum([len(e) for e in encoded], out=offsets[1:])
    small = offsets[-1] < 2**31  # 32-bit offsets (Arrow's string), else large_string
    missing = np.fromiter((s is None for s in items), dtype=bool, count=len(encoded))
    validity = pa.py_buffer(np.packbits(~missing, bitorder="little")) if missing.any() else None
    return pa.Array.from_buffers(pa.string() if small else pa.large_string(), len(encoded),
                                 [validity, pa.py_buffer(offsets.astype(np.int32) if small else offsets),
                                  pa.py_buffer(b"".join(encoded))])


def labels(codes: np.ndarray, names: Sequence[str]) -> Any:
    """The label of each integer code, as a pyarrow dictionary array (written as the labels; no
    string per row is built)."""
    import pyarrow as pa

    codes = np.ascontiguousarray(codes, dtype=np.int64)
    if codes.size and (codes.min() < 0 or codes.max() >= len(names)):
        raise ValueError(f"label codes must be in 0..{len(names) - 1}, got {codes.min()}..{codes.max()}")
    return pa.DictionaryArray.from_arrays(ints(codes), strings([str(s) for s in names]))


def csv_rows(arrays: Sequence[Any], names: Sequence[str], *, quoting: str = "none") -> Any:
    """Equally long pyarrow arrays as CSV rows (no header), a pyarrow buffer. ``quoting``:
    'none' (a cell needing quotes is refused) or 'needed' (every text cell quoted)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    sizes = {len(a) for a in arrays}
    if len(sizes) > 1:
        raise ValueError(f"columns of different lengths: {dict(zip(names, (len(a) for a in arrays)))}")
    table = pa.Table.from_arrays(list(arrays), names=[f"c{i}" for i in range(len(arrays))])
    pool = pa.system_memory_pool()  # the default pool (mimalloc) kept ~12 MiB more at the peak of rovlab filter on 360 000 rows
    sink = pa.BufferOutputStream(memory_pool=pool)
    try:
        options = pcsv.WriteOptions(include_header=False, quoting_style=quoting,
                                    batch_size=max(1024, min(table.num_rows, 1 << 16)))  # a chunk at once: ~10 % faster
        pcsv.write_csv(table, sink, write_options=options, memory_pool=pool)
    except pa.ArrowInvalid as exc:
        raise ValueError(f"{exc} (a cell that needs quoting: text columns are plain words)") from None
    return sink.getvalue()


def quote(text: str) -> str:
    """A header cell as RFC 4180 writes it."""
    if any(ch in text for ch in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def head(names: Sequence[str], comments: Sequence[str] = ()) -> bytes:
    """Comment lines and the header line."""
    return ("".join(f"# {line}\n" for line in comments) + ",".join(quote(n) for n in names) + "\n").encode("utf-8")
