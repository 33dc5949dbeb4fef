"""Rows of numbers as CSV text in one compiled loop (the writer of ``rovlab filter``).

Floats are written in their shortest form that reads back as the same double, laid out as
pyarrow's CSV writer and JavaScript lay them out (so files written before, with pyarrow, and
now are the same bytes): plain decimals for 1e-6 <= |x| < 1e10 (``0.000001``, ``35999.9``,
``1000000000``), scientific notation with a signed exponent otherwise (``9.99e-7``,
``1.2345678901e+10``); whole numbers without a point (``0``, ``-0``, ``100``); ``inf``, ``-inf``;
NaN as an empty cell.

How the kernel finds the digits, exactly: for d = 10, 11, ..., 15 significant digits it takes
m = round(|x| 10^k), k = d - 1 - floor(log10 |x|), and keeps the first m for which m / 10^k == |x|
(m * 10^-k for k < 0). m < 2^53 and 10^|k| (|k| <= 22) are exact doubles and IEEE division is
correctly rounded, so equality means the decimal m 10^-k reads back as x; with at most 15 digits
round(|x| 10^k) is the nearest d-digit decimal, so the first d that passes is the shortest length
above 9, and any shorter form is m without its trailing zeros (two decimals of at most 10 digits
are further apart than one unit in the last place of a double). A value needing 16 or 17 digits,
or too small or too large for exact powers of ten (|x| < 1e-13 or > 1e31), is left to Python's
``repr`` (the shortest digits, by David Gay's algorithm) and laid out the same way:
:func:`format_float`. Columns written to s significant digits are rounded in the same pass,
exactly as :func:`round_significant` rounds (see :func:`_rounded`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rovlab._jit import njit

_TENS0 = 330
_TENS = np.array([float(f"1e{j}") for j in range(-_TENS0, 310)])  # the double nearest 10^j (correctly rounded)
_FLOAT_WIDTH = 26  # "-0.000001" + 15 digits, or "-1.23456789012345e-308" (+ the comma)
_MARK = 1  # byte standing for a value formatted in Python afterwards


# --------------------------------------------------------------------------------------------
# the layout, in Python (values the kernel leaves, tests)
# --------------------------------------------------------------------------------------------

def layout(negative: bool, digits: str, exponent: int) -> str:
    """A number 0.d1d2... x 10^(exponent + 1) as pyarrow writes it (``digits`` without
    leading or trailing zeros; ``exponent`` of the first digit, as in d1.d2d3e+exponent)."""
    sign = "-" if negative else ""
    n = len(digits)
    if -6 <= exponent <= 9:
        if exponent < 0:
            return f"{sign}0.{'0' * (-exponent - 1)}{digits}"
        if n <= exponent + 1:
            return f"{sign}{digits}{'0' * (exponent + 1 - n)}"
        return f"{sign}{digits[:exponent + 1]}.{digits[exponent + 1:]}"
    mantissa = digits[0] + ("." + digits[1:] if n > 1 else "")
    return f"{sign}{mantissa}e{'+' if exponent >= 0 else '-'}{abs(exponent)}"


def format_float(v: float) -> str:
    """One float as the kernel writes it ('' for NaN), from the shortest digits of ``repr``."""
    if v != v:
        return ""
    negative = math.copysign(1.0, v) < 0
    if math.isinf(v):
        return "-inf" if negative else "inf"
    if v == 0.0:
        return "-0" if negative else "0"
    text = repr(abs(v))
    mantissa, _, power = text.partition("e")
    whole, _, fraction = mantissa.partition(".")
    digits = whole + fraction
    exponent = len(whole) - 1 + (int(power) if power else 0)
    stripped = digits.lstrip("0")
    exponent -= len(digits) - len(stripped)
    return layout(negative, stripped.rstrip("0"), exponent)


# --------------------------------------------------------------------------------------------
# the kernel
# --------------------------------------------------------------------------------------------

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


@njit(cache=True, nogil=True, inline="always")
def _fill(m, nd, pairs, dig):
    """The nd digits of the whole number m (< 1e16) into dig without the trailing zeros: their count."""
    q = np.int64(m)
    if nd > 8:  # two 32-bit halves, two digits at a time
        hi = np.uint32(q // 100_000_000)
        lo = np.uint32(q - np.int64(hi) * 100_000_000)
        i = nd
        for _ in range(4):
            r = lo % np.uint32(100)
            lo //= np.uint32(100)
            dig[i - 1] = pairs[2 * r + 1]
            dig[i - 2] = pairs[2 * r]
            i -= 2
        while i > 0:
            dig[i - 1] = np.uint8(48 + hi % np.uint32(10))
            hi //= np.uint32(10)
            i -= 1
    else:
        u = np.uint32(q)
        for i in range(nd - 1, -1, -1):
            dig[i] = np.uint8(48 + u % np.uint32(10))
            u //= np.uint32(10)
    n = nd
    while n > 1 and dig[n - 1] == 48:
        n -= 1
    return n


@njit(cache=True, nogil=True)
def _digits(a, p10, pairs, dig):
    """Shortest digits of a finite a > 0 into dig: (count, exponent of the first digit), or
    (0, 0) when the value is left to Python (see the module docstring)."""
    e = int(math.floor(math.log10(a)))
    for d in range(10, 16):
        m = 0.0
        k = 0
        settled = False
        for _ in range(3):  # log10 may be one off near powers of ten: m tells
            k = d - 1 - e
            if k > 22 or k < -22:
                return 0, 0
            m = math.floor(a * p10[k] + 0.5) if k >= 0 else math.floor(a / p10[-k] + 0.5)
            if m >= p10[d]:
                e += 1
            elif m < p10[d - 1]:
                e -= 1
            else:
                settled = True
                break
        if not settled:
            return 0, 0
        back = m / p10[k] if k >= 0 else m * p10[-k]
        if back == a:
            return _fill(m, d, pairs, dig), e
    return 0, 0


@njit(cache=True, nogil=True, inline="always")
def _rounded(a, bits, s, p10, tens, pairs, dig):
    """Digits of a finite a > 0 (``bits``: its IEEE bits) rounded to s significant digits as
    round_significant rounds (m = rint(a 10^k), k = s - 1 - floor(log10 a)), whose
    shortest form they are (the double nearest m 10^-k; two decimals of at most 11 digits are
    further apart than a unit in the last place): (count, exponent); (0, 0) when |k| > 23, where
    round_significant leaves the value as it is; (-1, 0) when |k| is 22 or 23: left to Python.

    floor(log10 a) from the binary exponent b: floor(b log10 2) or one more, decided against the
    double nearest the power of ten (``tens``). It can differ from numpy's rounded log10 only
    within an ulp of a power of ten, where either k gives the same digits, unless one of them
    crosses |k| = 22, where round_significant stops rounding: those few go to Python."""
    b = np.int64((bits >> 52) & 0x7FF) - 1023
    if b < -1022:
        return 0, 0  # subnormal: |k| > 23
    e = (b * 78913) >> 18  # floor(b log10 2), exact for |b| < 1650
    if a >= tens[e + 1 + _TENS0]:
        e += 1
    k = s - 1 - e
    if k > 23 or k < -23:
        return 0, 0
    if k > 21 or k < -21:
        return -1, 0
    m = np.rint(a * p10[k]) if k >= 0 else np.rint(a / p10[-k])
    nd = max(1, s - 1)
    while m >= p10[nd]:
        nd += 1
    return _fill(m, nd, pairs, dig), nd - 1 - k


@njit(cache=True, nogil=True, inline="always")
def _put_float(v, bits, s, out, pos, p10, tens, pairs, dig):
    """Write the finite or infinite v (rounded to s significant digits unless s == 0) at
    out[pos:]: the new position, or -1 if left to Python."""
    if v < 0.0 or (v == 0.0 and math.copysign(1.0, v) < 0.0):
        out[pos] = 45  # '-'
        pos += 1
    a = abs(v)
    if a == 0.0:
        out[pos] = 48
        return pos + 1
    if math.isinf(a):
        out[pos] = 105  # inf
        out[pos + 1] = 110
        out[pos + 2] = 102
        return pos + 3
    n, e = _rounded(a, bits, s, p10, tens, pairs, dig) if s > 0 else (0, 0)
    if n < 0:
        return -1
    if n == 0:
        n, e = _digits(a, p10, pairs, dig)
    if n == 0:
        return -1
    if -6 <= e <= 9:
        if e < 0:
            out[pos] = 48
            out[pos + 1] = 46
            pos += 2
            for _ in range(-e - 1):
                out[pos] = 48
                pos += 1
            for i in range(n):
                out[pos] = dig[i]
                pos += 1
        else:
            for i in range(max(n, e + 1)):
                if i == e + 1:
                    out[pos] = 46
                    pos += 1
                out[pos] = dig[i] if i < n else 48
                pos += 1
        return pos
    out[pos] = dig[0]
    pos += 1
    if n > 1:
        out[pos] = 46
        pos += 1
        for i in range(1, n):
            out[pos] = dig[i]
            pos += 1
    out[pos] = 101  # e
    out[pos + 1] = 43 if e >= 0 else 45
    pos += 2
    x = abs(e)
    width = 1 if x < 10 else (2 if x < 100 else 3)
    for i in range(width - 1, -1, -1):
        out[pos + i] = np.uint8(48 + x % 10)
        x //= 10
    return pos + width


@njit(cache=True, nogil=True)
def _rows(F, Fbits, sig, codes, kinds, index, lab, lab_off, out, left):
    """The CSV rows: column c is float column index[c] of F (kinds[c] == 0; rounded to sig[c]
    significant digits unless 0) or label column
    index[c] of codes (kinds[c] == 1, text lab[lab_off[code]:lab_off[code + 1]]). Returns the
    bytes written and the number of values left to Python (a _MARK byte where each goes; the F
    index of the first len(left) in left[:, 0..1])."""
    p10 = np.empty(23)
    p = 1.0
    for i in range(23):
        p10[i] = p
        p *= 10.0
    tens = _TENS
    pairs = np.empty(200, dtype=np.uint8)  # "00", "01", ..., "99"
    for i in range(100):
        pairs[2 * i] = 48 + i // 10
        pairs[2 * i + 1] = 48 + i % 10
    dig = np.empty(20, dtype=np.uint8)
    pos = 0
    n_left = 0
    for r in range(F.shape[0]):
        for c in range(kinds.size):
            if c:
                out[pos] = 44  # ','
                pos += 1
            j = index[c]
            if kinds[c] == 0:
                v = F[r, j]
                if v != v:
                    continue
                end = _put_float(v, Fbits[r, j], sig[c], out, pos, p10, tens, pairs, dig)
                if end < 0:
                    out[pos] = _MARK
                    pos += 1
                    if n_left < left.shape[0]:
                        left[n_left, 0] = r
                        left[n_left, 1] = j
                    n_left += 1
                else:
                    pos = end
            else:
                code = codes[r, j]
                for b in range(lab_off[code], lab_off[code + 1]):
                    out[pos] = lab[b]
                    pos += 1
        out[pos] = 10  # '\n'
        pos += 1
    return pos, n_left


def csv_rows(columns: Sequence[np.ndarray | tuple[np.ndarray, Sequence[str]]],
             significant: Sequence[int | None] | None = None) -> bytes | memoryview:
    """Equally long columns as CSV rows (no header, no quoting), UTF-8: each column a float array
    or (integer codes, labels), the label of each code. ``significant[c]``: write float column c
    rounded to that many significant digits, as ``round_significant`` rounds
    (None: exactly)."""
    if not columns:
        raise ValueError("no columns to write")
    if significant is None:
        significant = [None] * len(columns)
    if len(significant) != len(columns) or any(d is not None and not 1 <= d <= 15 for d in significant):
        raise ValueError("significant: one entry per column, None or 1..15 digits")
    sig = np.array([d or 0 for d in significant], dtype=np.int64)
    floats: list[np.ndarray] = []
    label_cols: list[np.ndarray] = []
    texts: list[list[bytes]] = []
    kinds = np.empty(len(columns), dtype=np.int64)
    index = np.empty(len(columns), dtype=np.int64)
    width = 1
    n = None
    for c, col in enumerate(columns):
        if isinstance(col, tuple):
            codes, labels = col
            encoded = [str(s).encode("utf-8") for s in labels]
            bad = [s for s in encoded if any(ch in s for ch in b',"\n\r\x01')]
            if bad:
                raise ValueError(f"label {bad[0]!r} needs quoting; labels are plain words")
            codes = np.asarray(codes)
            if codes.size and (codes.min() < 0 or codes.max() >= len(encoded)):
                raise ValueError(f"label codes must be in 0..{len(encoded) - 1}, got {codes.min()}..{codes.max()}")
            kinds[c], index[c] = 1, len(label_cols)
            label_cols.append(codes + sum(len(t) for t in texts))  # codes into one table of all labels
            texts.append(encoded)
            width += max((len(s) for s in encoded), default=0) + 1
            size = codes.size
        else:
            arr = np.asarray(col, dtype=np.float64)
            kinds[c], index[c] = 0, len(floats)
            floats.append(arr)
            width += _FLOAT_WIDTH
            size = arr.size
        if n is None:
            n = size
        elif size != n:
            raise ValueError(f"column {c} has {size} values, the others {n}")
    assert n is not None
    F = np.empty((n, len(floats)))
    for j, arr in enumerate(floats):
        F[:, j] = arr
    codes2 = np.empty((n, len(label_cols)), dtype=np.int64)
    for j, arr in enumerate(label_cols):
        codes2[:, j] = arr
    all_labels = [s for group in texts for s in group]
    lab = np.frombuffer(b"".join(all_labels), dtype=np.uint8) if all_labels else np.zeros(0, dtype=np.uint8)
    lab.flags.writeable = False  # one type either way (read-only)
    lab_off = np.zeros(len(all_labels) + 1, dtype=np.int64)
    np.cumsum([len(s) for s in all_labels], out=lab_off[1:])
    out = np.empty(n * width, dtype=np.uint8)
    left = np.empty((64, 2), dtype=np.int64)  # values left to Python are rare
    size, n_left = _rows(F, F.view(np.uint64), sig, codes2, kinds, index, lab, lab_off, out, left)
    if n_left > left.shape[0]:
        left = np.empty((n_left, 2), dtype=np.int64)
        size, n_left = _rows(F, F.view(np.uint64), sig, codes2, kinds, index, lab, lab_off, out, left)
    if not n_left:
        return out.data[:size]  # no copy: pages past size were never touched
    float_digits = [d for d, kind in zip(significant, kinds) if kind == 0]
    parts = out[:size].tobytes().split(bytes([_MARK]))
    pieces = [parts[0]]
    for i in range(n_left):
        value = F[left[i, 0], left[i, 1]:left[i, 1] + 1]
        digits = float_digits[left[i, 1]]
        if digits:
            value = round_significant(value, digits)
        pieces.append(format_float(float(value[0])).encode("ascii"))
        pieces.append(parts[i + 1])
    return b"".join(pieces)
