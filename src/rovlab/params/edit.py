"""Edit a TOML parameter file in place, keeping its comments and layout (tomlkit).

Used by the identification tools (``rovlab identify ... --update``) and by anything else that
saves parameters back to a file (e.g. the HMI saving a tuned vehicle). Values are set by key
path; a path is dot-separated keys, where an element of an array of tables is chosen by a key
value or an index::

    added_mass.X_udot
    damping.surge.linear
    thrusters[name=T1].quadratic          (a dict value is merged key by key)
    sensors[name=pressure].variance.z
    thrusters[0].deadband_us
    thrusters[name=T1].table              (value DELETE removes the key)

Each edited block can get a ``source`` note (appended to the existing one, or replacing it) so
the file keeps saying where its numbers came from. The edited document is validated *before*
anything is written (for vehicles with :func:`rovlab.params.vehicle.vehicle_from_dict`), then
written atomically (temporary file + rename), so a failed edit never leaves a broken file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomlkit
from tomlkit import items
from tomlkit.container import Container

from rovlab.core.files import atomic_write_text
from rovlab.params.validate import ConfigError, Problem


class _Delete:
    def __repr__(self) -> str:
        return "DELETE"


DELETE: Any = _Delete()
"""Value that removes a key."""

_COMPONENT = re.compile(r"^(?P<key>[A-Za-z0-9_\-]+)(?:\[(?P<sel>[^\]]*)\])?$")


@dataclass(frozen=True)
class _Step:
    key: str
    index: int | None = None  # thrusters[2]
    match: tuple[str, str] | None = None  # thrusters[name=T1]

    def label(self) -> str:
        if self.index is not None:
            return f"{self.key}[{self.index}]"
        if self.match is not None:
            return f"{self.key}[{self.match[0]}={self.match[1]}]"
        return self.key


def parse_path(path: str) -> list[_Step]:
    """Split ``thrusters[name=T1].quadratic`` into its steps (ValueError if malformed)."""
    steps: list[_Step] = []
    if not path:
        raise ValueError("empty key path")
    for part in path.split("."):
        m = _COMPONENT.match(part.strip())
        if not m:
            raise ValueError(f"malformed key path {path!r} at {part!r}; expected key, key[index] or key[field=value]")
        sel = m.group("sel")
        if sel is None:
            steps.append(_Step(m.group("key")))
        elif "=" in sel:
            field, _, value = sel.partition("=")
            steps.append(_Step(m.group("key"), match=(field.strip(), value.strip().strip("'\""))))
        elif sel.strip().lstrip("-").isdigit():
            steps.append(_Step(m.group("key"), index=int(sel)))
        else:
            raise ValueError(f"malformed selector [{sel}] in key path {path!r}")
    return steps


# --------------------------------------------------------------------------------------------
# Items
# --------------------------------------------------------------------------------------------

def format_float(x: float) -> str:
    """Shortest round-tripping TOML spelling, in exponent form for small/large magnitudes."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"TOML files here hold finite numbers only, got {x}")
    text = repr(x)
    if x != 0 and (abs(x) < 1e-2 or abs(x) >= 1e6):
        for digits in range(0, 17):
            candidate = f"{x:.{digits}e}"
            if float(candidate) == x:
                mant, _, exp = candidate.partition("e")
                text = f"{mant}e{int(exp)}"
                break
    if "e" not in text and "." not in text and "inf" not in text and "nan" not in text:
        text += ".0"
    return text


def _item(value: Any, old: Any = None) -> Any:
    """A tomlkit item for a plain value, keeping the old item's trailing comment."""
    trivia = old.trivia if isinstance(old, items.Item) and not isinstance(old, (items.Table, items.AoT)) else None
    new: Any
    if isinstance(value, bool):
        new = tomlkit.item(value)
    elif isinstance(value, int):
        new = tomlkit.item(value)
    elif isinstance(value, float):
        new = items.Float(value, items.Trivia(), format_float(value))
    elif isinstance(value, Mapping):
        new = tomlkit.inline_table()
        for k, v in value.items():
            new[k] = _item(v)
        keys = list(value)
        if keys:  # "{ a = 1, b = 2 }", the spacing the packaged files use
            new[keys[0]].trivia.indent = " "
            new[keys[-1]].trivia.trail = " "
    elif isinstance(value, (list, tuple)):
        new = tomlkit.array()
        for v in value:
            new.append(_item(v))
    elif hasattr(value, "tolist"):  # numpy scalars and arrays
        return _item(value.tolist(), old)
    else:
        new = tomlkit.item(value)
    if trivia is not None and hasattr(new, "trivia"):
        new.trivia.comment_ws = trivia.comment_ws
        new.trivia.comment = trivia.comment
        new.trivia.trail = trivia.trail
        new.trivia.indent = trivia.indent
    return new


def _same(old: Any, value: Any) -> bool:
    plain = old.unwrap() if hasattr(old, "unwrap") else old
    if isinstance(plain, bool) or isinstance(value, bool):
        return plain is value
    if isinstance(plain, (int, float)) and isinstance(value, (int, float)):
        return float(plain) == float(value)
    return isinstance(plain, str) and isinstance(value, str) and plain == value


def _is_table(x: Any) -> bool:
    return isinstance(x, (items.Table, items.InlineTable, Container, tomlkit.TOMLDocument)) or (
        isinstance(x, dict))


# --------------------------------------------------------------------------------------------
# Editing a parsed document
# --------------------------------------------------------------------------------------------

class _EditProblem(Exception):
    def __init__(self, key: str, value: Any, expected: str) -> None:
        super().__init__(expected)
        self.key, self.value, self.expected = key, value, expected


def _descend(node: Any, step: _Step, done: str, *, create: bool) -> Any:
    here = f"{done}.{step.label()}" if done else step.label()
    if not _is_table(node):
        raise _EditProblem(done or "(top level)", type(node).__name__, "a table to hold " + step.key)
    if step.key not in node:
        if step.index is not None or step.match is not None:
            raise _EditProblem(here, "missing", f"an array of tables [[{step.key}]]")
        if not create:
            raise _EditProblem(here, "missing", "an existing table")
        node[step.key] = tomlkit.table() if isinstance(node, tomlkit.TOMLDocument) else tomlkit.inline_table()
        return node[step.key]
    child = node[step.key]
    if step.index is None and step.match is None:
        return child
    if not isinstance(child, (items.AoT, list)):
        raise _EditProblem(here, type(child).__name__, f"an array of tables [[{step.key}]]")
    entries = list(child)
    if step.index is not None:
        if not -len(entries) <= step.index < len(entries):
            raise _EditProblem(here, f"{len(entries)} entries", f"an index below {len(entries)}")
        return entries[step.index]
    field, want = step.match  # type: ignore[misc]
    hits = [e for e in entries if _is_table(e) and field in e and str(e[field]) == want]
    if not hits:
        have = ", ".join(str(e[field]) for e in entries if _is_table(e) and field in e) or "none"
        raise _EditProblem(here, want, f"an entry of [[{step.key}]] with {field} = {want!r} (there are: {have})")
    if len(hits) > 1:
        raise _EditProblem(here, want, f"a unique {field} in [[{step.key}]] ({len(hits)} entries match)")
    return hits[0]


def _assign(node: Any, key: str, value: Any, where: str) -> None:
    if value is DELETE:
        if key in node:
            del node[key]
        return
    old = node[key] if key in node else None
    if old is not None and not _is_table(old) and _same(old, value):
        return  # unchanged: keep the file's own spelling (25 stays 25, 7.22e-2 stays 7.22e-2)
    if isinstance(value, Mapping) and old is not None and _is_table(old):
        for k, v in value.items():  # merge, keeping the layout and comments of the existing table
            _assign(old, k, v, f"{where}.{k}")
        return
    if isinstance(value, Mapping) and isinstance(node, tomlkit.TOMLDocument):
        table = tomlkit.table()
        for k, v in value.items():
            table[k] = _item(v)
        node[key] = table
        return
    try:
        node[key] = _item(value, old)
    except ValueError as exc:
        raise _EditProblem(where, value, str(exc)) from None


def set_value(doc: Any, path: str, value: Any) -> None:
    """Set (or with DELETE remove) one value by key path in a tomlkit document.

    Missing intermediate tables are created (inline tables below the top level); entries of
    arrays of tables must exist. Raises ``ConfigError``-friendly ``ValueError``s through
    :func:`apply_edits`.
    """
    steps = parse_path(path)
    node = doc
    done = ""
    for step in steps[:-1]:
        node = _descend(node, step, done, create=True)
        done = f"{done}.{step.label()}" if done else step.label()
    last = steps[-1]
    if last.index is not None or last.match is not None:
        node = _descend(node, last, done, create=False)
        if not isinstance(value, Mapping):
            raise _EditProblem(path, value, "a table of values for an array-of-tables entry")
        for k, v in value.items():
            _assign(node, k, v, f"{path}.{k}")
        return
    if not _is_table(node):
        raise _EditProblem(done, type(node).__name__, f"a table to hold {last.key}")
    _assign(node, last.key, value, path)


def set_source(doc: Any, block: str, note: str, *, mode: str = "append") -> None:
    """Append ``note`` to (or replace) the ``source`` string of a block (a table or an entry)."""
    if mode not in ("append", "replace"):
        raise ValueError(f"source mode must be 'append' or 'replace', got {mode!r}")
    node = doc
    done = ""
    for step in parse_path(block):
        node = _descend(node, step, done, create=False)
        done = f"{done}.{step.label()}" if done else step.label()
    if not _is_table(node):
        raise _EditProblem(block, type(node).__name__, "a table with a source note")
    old = str(node["source"]) if "source" in node else ""
    text = note if mode == "replace" or not old else f"{old}; {note}"
    _assign(node, "source", text, f"{block}.source")


def apply_edits(doc: Any, values: Mapping[str, Any], *, sources: Mapping[str, str] | None = None,
                source_mode: str = "append", file: str = "<document>") -> Any:
    """Apply every edit to a tomlkit document; raise :class:`ConfigError` listing every bad path."""
    problems: list[Problem] = []
    for path, value in values.items():
        try:
            set_value(doc, path, value)
        except _EditProblem as exc:
            problems.append(Problem(file, exc.key, exc.value, exc.expected))
        except ValueError as exc:
            problems.append(Problem(file, path, value, str(exc)))
    for block, note in (sources or {}).items():
        try:
            set_source(doc, block, note, mode=source_mode)
        except _EditProblem as exc:
            problems.append(Problem(file, exc.key, exc.value, exc.expected))
    if problems:
        raise ConfigError(problems, "edit")
    return doc


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------

def edit_toml_text(text: str, values: Mapping[str, Any], *, sources: Mapping[str, str] | None = None,
                   source_mode: str = "append", file: str = "<text>",
                   validate: Callable[[dict[str, Any]], Any] | None = None) -> tuple[str, Any]:
    """Edited TOML text and the result of ``validate(plain_dict)`` (None without a validator)."""
    try:
        doc = tomlkit.parse(text)
    except Exception as exc:  # tomlkit raises its own ParseError subclasses
        raise ConfigError([Problem(file, "", "a TOML syntax error", f"valid TOML ({exc})")]) from None
    apply_edits(doc, values, sources=sources, source_mode=source_mode, file=file)
    checked = validate(doc.unwrap()) if validate is not None else None
    return tomlkit.dumps(doc), checked


def edit_toml_file(path: str | Path, values: Mapping[str, Any], *, sources: Mapping[str, str] | None = None,
                   source_mode: str = "append", output: str | Path | None = None,
                   validate: Callable[[dict[str, Any]], Any] | None = None) -> Any:
    """Edit a TOML file in place (or into ``output``): validate first, then write atomically."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError([Problem(str(path), "", "no such file", "an existing TOML file")]) from None
    except IsADirectoryError:
        raise ConfigError([Problem(str(path), "", "a directory", "a TOML file")]) from None
    except UnicodeDecodeError as exc:
        raise ConfigError([Problem(str(path), "", "undecodable bytes",
                                   f"a UTF-8 TOML file ({exc.reason} at byte {exc.start})")]) from None
    new_text, checked = edit_toml_text(text, values, sources=sources, source_mode=source_mode,
                                       file=str(path), validate=validate)
    atomic_write_text(Path(output) if output is not None else path, new_text)
    return checked


def edit_vehicle_file(path: str | Path, values: Mapping[str, Any], *, sources: Mapping[str, str] | None = None,
                      source_mode: str = "append", output: str | Path | None = None):
    """Edit a vehicle file, refusing (and writing nothing) if the result is not a valid vehicle.

    Returns the validated :class:`rovlab.params.vehicle.Vehicle` as written.
    """
    from rovlab.params.vehicle import vehicle_from_dict

    target = str(output if output is not None else path)

    def validate(data: dict[str, Any]):
        try:
            return vehicle_from_dict(data, file=target)
        except ConfigError as exc:
            raise ConfigError(exc.problems, "vehicle file after the update (nothing was written)") from None

    return edit_toml_file(path, values, sources=sources, source_mode=source_mode, output=output,
                          validate=validate)
