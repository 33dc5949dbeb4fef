"""Closed-schema reading of TOML tables, collecting every problem with its key path.

All of rovlab's files (vehicles, filter/controller configurations, scenarios) are read
through :class:`TableReader`: each accessor checks one key, records a :class:`Problem`
(file, key path, value, expectation) instead of raising, and returns a placeholder so that
reading continues and *all* problems of a file are reported at once. ``finish()`` adds an
error for every key that was never asked for (unknown keys are errors).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Problem:
    """One thing wrong in a file: where, what was found, what was expected."""

    file: str
    key: str
    value: Any
    expected: str

    def __str__(self) -> str:
        where = f"{self.file}: {self.key}" if self.key else self.file
        if self.value is _MISSING:
            return f"{where}: missing; expected {self.expected}"
        return f"{where}: got {_show(self.value)}; expected {self.expected}"


class ConfigError(ValueError):
    """A file (or table) failed validation; ``problems`` lists every problem found."""

    def __init__(self, problems: Sequence[Problem], what: str = "file") -> None:
        self.problems = list(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        n = len(self.problems)
        super().__init__(f"invalid {what} ({n} problem{'s' if n != 1 else ''}):\n{lines}")


class _Missing:
    def __repr__(self) -> str:  # pragma: no cover - debugging aid
        return "<missing>"


_MISSING: Any = _Missing()


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class PackagedFiles:
    """TOML files shipped in a package folder, addressed by name (``udrone``) or by path."""

    def __init__(self, package: str, folder: str, what: str) -> None:
        self.package, self.folder, self.what = package, folder, what

    def names(self) -> list[str]:
        base = resources.files(self.package) / self.folder
        return sorted(p.name[:-5] for p in base.iterdir() if p.name.endswith(".toml"))

    def path(self, name: str) -> Path:
        return Path(str(resources.files(self.package) / self.folder / f"{name}.toml"))

    def resolve(self, name_or_path: str | Path) -> Path:
        """A path (anything ending in .toml, containing a slash or existing) or a packaged name."""
        text = str(name_or_path)
        path = Path(text)
        if path.suffix == ".toml" or path.exists() or "/" in text:
            return path
        if text in self.names():
            return self.path(text)
        raise ConfigError([Problem(text, "", text, f"a {self.what} file path or a packaged {self.what} name: "
                                   + ", ".join(self.names()))], self.what)


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax errors into a :class:`ConfigError`."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError([Problem(str(path), "", _MISSING, "an existing TOML file")]) from None
    except IsADirectoryError:
        raise ConfigError([Problem(str(path), "", "a directory", "a TOML file")]) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([Problem(str(path), "", "undecodable bytes", f"UTF-8 text ({exc})")]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([Problem(str(path), "", "a TOML syntax error", f"valid TOML ({exc})")]) from None


class Collector:
    """Shared sink for the problems of one file."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.problems: list[Problem] = []

    def add(self, key: str, value: Any, expected: str) -> None:
        self.problems.append(Problem(self.file, key, value, expected))

    def raise_if_any(self, what: str = "file") -> None:
        if self.problems:
            raise ConfigError(self.problems, what)


def control_characters(text: str, *, allow_newlines: bool) -> str:
    """The control characters in ``text`` as escapes (e.g. ``'\\x00, \\n'``), '' if none.

    NUL and other C0/C1 controls are never meaningful in rovlab's text; newlines and tabs are
    allowed in free text (descriptions, sources) when ``allow_newlines``.
    """
    ok = "\n\r\t" if allow_newlines else ""
    found = sorted({c for c in text if (ord(c) < 32 or 127 <= ord(c) < 160 or c in "\u2028\u2029")
                    and c not in ok})
    return ", ".join(repr(c)[1:-1] for c in found)


def plausible_expectation(bounds: tuple[float, float], what: str = "") -> str:
    lo, hi = bounds
    unit = f"{what}; " if what else ""
    return (f"a number within {lo:g} .. {hi:g} ({unit}the plausible range for a BlueROV-class "
            "vehicle, docs/vehicle-file.md)")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class TableReader:
    """Typed accessors over one TOML table; remembers which keys were read."""

    def __init__(self, data: Any, collector: Collector, path: str = "") -> None:
        self.collector = collector
        self.path = path
        self._seen: set[str] = set()
        if not isinstance(data, dict):
            collector.add(path or "(top level)", data, "a table")
            data = {}
        self.data: dict[str, Any] = data

    # -- helpers --------------------------------------------------------------------------
    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def has(self, name: str) -> bool:
        return name in self.data

    def _get(self, name: str, required: bool) -> Any:
        self._seen.add(name)
        if name not in self.data:
            if required:
                self.collector.add(self.key(name), _MISSING, "a value")
            return _MISSING
        return self.data[name]

    def problem(self, name: str, value: Any, expected: str) -> None:
        self.collector.add(self.key(name), value, expected)

    # -- scalars --------------------------------------------------------------------------
    def number(
        self,
        name: str,
        default: float | None | Any = _MISSING,
        *,
        positive: bool = False,
        nonnegative: bool = False,
        nonpositive: bool = False,
        negative: bool = False,
        lo: float | None = None,
        hi: float | None = None,
        plausible: tuple[float, float] | None = None,
        what: str = "",
    ) -> float:
        """A finite real number with optional sign/range constraints (NaN on error).

        ``plausible = (lo, hi)`` is a physical plausibility range (both ends included): a value
        outside it is refused with the range in the message (e.g. a damping of -9e18).
        """
        required = default is _MISSING
        value = self._get(name, required)
        if value is _MISSING:
            return math.nan if required else default  # type: ignore[return-value]
        if not _is_number(value):
            self.problem(name, value, "a number" + (f" ({what})" if what else ""))
            return math.nan
        x = float(value)
        if not math.isfinite(x):
            self.problem(name, value, "a finite number")
            return math.nan
        rules = [
            (positive and not x > 0, "a positive number"),
            (nonnegative and not x >= 0, "a number >= 0"),
            (nonpositive and not x <= 0, "a number <= 0"),
            (negative and not x < 0, "a negative number"),
            (lo is not None and x < lo, f"a number >= {lo}"),
            (hi is not None and x > hi, f"a number <= {hi}"),
        ]
        for failed, expectation in rules:
            if failed:
                self.problem(name, value, expectation + (f" ({what})" if what else ""))
                return math.nan
        if plausible is not None and not plausible[0] <= x <= plausible[1]:
            self.problem(name, value, plausible_expectation(plausible, what))
            return math.nan
        return x

    def integer(self, name: str, default: int | Any = _MISSING, *, lo: int | None = None) -> int:
        required = default is _MISSING
        value = self._get(name, required)
        if value is _MISSING:
            return 0 if required else default
        if not isinstance(value, int) or isinstance(value, bool):
            self.problem(name, value, "an integer")
            return 0
        if lo is not None and value < lo:
            self.problem(name, value, f"an integer >= {lo}")
            return 0
        return int(value)

    def string(
        self, name: str, default: str | None | Any = _MISSING, *, choices: Iterable[str] | None = None
    ) -> str:
        required = default is _MISSING
        value = self._get(name, required)
        if value is _MISSING:
            return "" if required else default  # type: ignore[return-value]
        if not isinstance(value, str):
            self.problem(name, value, "a string")
            return ""
        bad = control_characters(value, allow_newlines=True)
        if bad:
            self.problem(name, value, f"text without control characters (found {bad})")
            return ""
        if choices is not None:
            options = list(choices)
            if value not in options:
                self.problem(name, value, "one of " + ", ".join(repr(c) for c in options))
                return ""
        return value

    def name(self, name: str = "name", default: str | Any = _MISSING) -> str:
        """A name: one line of printable text, 1-64 characters, no leading/trailing space.

        Names end up in file names, CSV headers and log lines, so a NUL, a newline or a tab in
        one is refused rather than carried into those files.
        """
        before = len(self.collector.problems)
        value = self.string(name, default)
        if len(self.collector.problems) > before or name not in self.data:
            return value  # already reported (wrong type, NUL, ...) or the default
        bad = control_characters(value, allow_newlines=False)
        if bad or not value or len(value) > 64 or value != value.strip():
            why = f" (found {bad})" if bad else ""
            self.problem(name, value, "a name: 1-64 printable characters on one line, no leading or "
                         f"trailing space{why}")
            return ""
        return value

    def boolean(self, name: str, default: bool | Any = _MISSING) -> bool:
        required = default is _MISSING
        value = self._get(name, required)
        if value is _MISSING:
            return False if required else default
        if not isinstance(value, bool):
            self.problem(name, value, "true or false")
            return False
        return value

    def vector(
        self, name: str, length: int | None = None, default: Any = _MISSING, *, what: str = ""
    ) -> np.ndarray:
        """A list of finite numbers (of a given length) as a float array (NaNs on error)."""
        required = default is _MISSING
        value = self._get(name, required)
        n = length if length is not None else 0
        if value is _MISSING:
            return np.full(n, np.nan) if required else np.asarray(default, dtype=float)
        exp = f"a list of {length} finite numbers" if length else "a list of finite numbers"
        if what:
            exp += f" ({what})"
        if (
            not isinstance(value, list)
            or (length is not None and len(value) != length)
            or not all(_is_number(v) and math.isfinite(float(v)) for v in value)
        ):
            self.problem(name, value, exp)
            return np.full(n, np.nan)
        return np.asarray(value, dtype=float)

    def numbers_table(self, name: str, keys: Sequence[str], *, required: Sequence[str] = (),
                      positive: bool = False, plausible: tuple[float, float] | None = None) -> dict[str, float]:
        """An inline table mapping some of ``keys`` to numbers, e.g. ``{ z = 1e-4 }``."""
        sub = self.table(name, required=False)
        out: dict[str, float] = {}
        for k in keys:
            if sub.has(k) or k in required:
                out[k] = sub.number(k, positive=positive, plausible=plausible)
        sub.finish()
        return out

    # -- structure ------------------------------------------------------------------------
    def table(self, name: str, *, required: bool = True) -> TableReader:
        value = self._get(name, required)
        if value is _MISSING:
            return TableReader({}, self.collector, self.key(name))
        if not isinstance(value, dict):
            self.problem(name, value, "a table")
            return TableReader({}, self.collector, self.key(name))
        return TableReader(value, self.collector, self.key(name))

    def tables(self, name: str, *, required: bool = True, min_count: int = 0) -> list[TableReader]:
        """An array of tables (``[[name]]``)."""
        value = self._get(name, required)
        if value is _MISSING:
            return []
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            self.problem(name, _show_kind(value), "an array of tables ([[" + name + "]])")
            return []
        if len(value) < min_count:
            self.problem(name, f"{len(value)} entries", f"at least {min_count}")
        return [TableReader(v, self.collector, f"{self.key(name)}[{i}]") for i, v in enumerate(value)]

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        """The value as parsed (for keys whose type varies, e.g. distributions)."""
        value = self._get(name, default is _MISSING)
        return default if value is _MISSING else value

    def finish(self) -> None:
        """Record an error for every key present in the table but never read."""
        for name in self.data:
            if name not in self._seen:
                self.collector.add(self.key(name), self.data[name], "no such key (unknown keys are errors)")


def _show_kind(value: Any) -> Any:
    if isinstance(value, list):
        return f"a list of {len(value)} item(s)"
    return value
