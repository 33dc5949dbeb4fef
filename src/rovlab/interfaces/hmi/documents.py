"""The parameter documents the HMI edits: the model vehicle, the plant's true vehicle and the
filter/controller configuration, each held as the plain dict of its TOML file.

An edit sets key paths (``rigid_body.mass``, ``damping.heave.linear``,
``thrusters[name=T1].quadratic.K_L_pos``, ``measurements[1].variance``; the syntax of
:mod:`rovlab.params.edit`) in a deep copy, which the file's own loader validates; only a document
that loads (and that the running loop accepts) replaces the current one. Saving writes the
document into the original file's text, so its comments and layout survive, and checks that the
written file loads back to the same values.
"""

from __future__ import annotations

import copy
import datetime as _dt
import math
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import tomlkit

from rovlab.core.files import atomic_write_text
from rovlab.params.edit import DELETE, apply_edits, parse_path
from rovlab.params.validate import ConfigError, Problem

Validator = Callable[[Mapping[str, Any], str], Any]


def coerce_text(value: Any) -> Any:
    """Read a value typed into the page as a TOML value: ``"7.5"`` -> 7.5, ``"[1, 2]"`` -> [1, 2],
    ``"nan"`` -> nan (which the loaders refuse); text that is not a TOML value stays text."""
    if not isinstance(value, str):
        return value
    text = value.strip()
    if not text:
        return value
    try:
        parsed = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return value
    if isinstance(parsed, (_dt.date, _dt.time, _dt.datetime)):
        return value
    return parsed


def set_path(data: dict[str, Any], path: str, value: Any, *, file: str = "<document>") -> None:
    """Set (value None: delete) one key path in nested plain dicts/lists, creating tables on the way.

    Raises ConfigError naming the path when it does not fit the document's structure.
    """
    try:
        steps = parse_path(path)
    except ValueError as exc:
        raise ConfigError([Problem(file, path, path, str(exc))], "edit") from None
    node: Any = data
    done = ""
    for i, step in enumerate(steps):
        last = i == len(steps) - 1
        here = f"{done}.{step.label()}" if done else step.label()
        if not isinstance(node, dict):
            raise ConfigError([Problem(file, done or "(top level)", node, f"a table to hold {step.key}")], "edit")
        if step.index is None and step.match is None:
            if last:
                if value is None:
                    node.pop(step.key, None)
                else:
                    node[step.key] = value
                return
            node = node.setdefault(step.key, {})
            done = here
            continue
        entries = node.get(step.key)
        if not isinstance(entries, list):
            raise ConfigError([Problem(file, here, "missing", f"an array of tables [[{step.key}]]")], "edit")
        if step.index is not None:
            if not -len(entries) <= step.index < len(entries):
                raise ConfigError([Problem(file, here, f"{len(entries)} entries",
                                           f"an index below {len(entries)}")], "edit")
            hits = [step.index]
        else:
            field, want = step.match  # type: ignore[misc]
            hits = [j for j, e in enumerate(entries) if isinstance(e, dict) and str(e.get(field)) == want]
            if len(hits) != 1:
                have = ", ".join(str(e.get(field)) for e in entries if isinstance(e, dict)) or "none"
                raise ConfigError([Problem(file, here, want, f"exactly one entry of [[{step.key}]] with "
                                           f"{field} = {want!r} (there are: {have})")], "edit")
        if last:
            if value is None:
                del entries[hits[0]]
            elif isinstance(value, dict):
                entries[hits[0]] = value
            else:
                raise ConfigError([Problem(file, here, value, "a table for an array-of-tables entry")], "edit")
            return
        node = entries[hits[0]]
        done = here


def get_path(data: Mapping[str, Any], path: str) -> Any:
    """The value at a key path, or None when absent."""
    node: Any = data
    for step in parse_path(path):
        if not isinstance(node, Mapping) or step.key not in node:
            return None
        node = node[step.key]
        if step.index is not None or step.match is not None:
            if not isinstance(node, list):
                return None
            if step.index is not None:
                if not -len(node) <= step.index < len(node):
                    return None
                node = node[step.index]
            else:
                field, want = step.match  # type: ignore[misc]
                hits = [e for e in node if isinstance(e, dict) and str(e.get(field)) == want]
                if len(hits) != 1:
                    return None
                node = hits[0]
    return node


class ParameterDocument:
    """One TOML document being tuned: its current dict, the file it came from and its loader.

    ``validate(data, file)`` turns a dict into the validated object (a Vehicle, a DesignConfig)
    or raises ConfigError. The document only changes through :meth:`commit` of a candidate that
    :meth:`candidate` produced, i.e. that validated.
    """

    def __init__(self, target: str, data: Mapping[str, Any], *, origin: Path | None, label: str,
                 validate: Validator, packaged: bool = False) -> None:
        self.target = target
        self.origin = origin  # the file whose text (comments, layout) saving starts from
        self.packaged = packaged  # origin is a file shipped inside rovlab (never written in place)
        self.label = label
        self._validate = validate
        self.data: dict[str, Any] = copy.deepcopy(dict(data))
        self.loaded: dict[str, Any] = copy.deepcopy(dict(data))  # as first loaded (for "revert")
        self.value = validate(self.data, label)
        self.saved_to: Path | None = None

    def candidate(self, changes: Mapping[str, Any]) -> tuple[dict[str, Any], Any]:
        """A validated edited copy: (new dict, validated object). Raises ConfigError; changes nothing."""
        if not changes:
            raise ConfigError([Problem(self.label, "", {}, "at least one key to change")], "edit")
        new = copy.deepcopy(self.data)
        for path, value in changes.items():
            if not isinstance(path, str):
                raise ConfigError([Problem(self.label, str(path), path, "a key path (text)")], "edit")
            set_path(new, path, _plain(coerce_text(value)), file=self.label)
        return new, self._validate(new, self.label)

    def validate(self, data: Mapping[str, Any]) -> Any:
        """The validated object of ``data`` (raises ConfigError naming this document)."""
        return self._validate(data, self.label)

    def commit(self, data: dict[str, Any], value: Any) -> None:
        self.data = data
        self.value = value

    def get(self, path: str) -> Any:
        return get_path(self.data, path)

    # -- saving --------------------------------------------------------------------------
    def render(self) -> tuple[str, bool]:
        """The document as TOML text: the origin's text with the changed values written into it
        (comments kept), and whether that worked (False: plain dump, comments lost)."""
        if self.origin is not None:
            try:
                text = self.origin.read_text(encoding="utf-8")
                doc = tomlkit.parse(text)
                original = tomllib.loads(text)
                edits: dict[str, Any] = {}
                replace: dict[str, list] = {}
                _diff(original, self.data, "", edits, replace)
                apply_edits(doc, edits, file=str(self.origin))
                for key, entries in replace.items():
                    doc[key] = _aot(entries)
                new_text = tomlkit.dumps(doc)
                if _same(tomllib.loads(new_text), self.data):
                    return new_text, True
            except Exception:  # noqa: BLE001, S110 - tomlkit has its own error types; the plain dump below
                pass  # still saves every value, only the comments are lost (and the caller says so)
        return tomlkit.dumps(self.data), False

    def save(self, path: str | Path) -> tuple[Path, bool]:
        """Write the document to ``path`` and check it loads back to the same values.

        Returns (path, comments kept). Raises ConfigError if the written file does not reload.
        """
        path = Path(path)
        text, kept = self.render()
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
        with path.open("rb") as fh:
            back = tomllib.load(fh)
        if not _same(back, self.data):
            raise ConfigError([Problem(str(path), "", "different values", "the saved file to reload to the "
                                       "values in the HMI (please report this)")], "saved file")
        self._validate(back, str(path))
        self.saved_to = path
        return path, kept


def _plain(value: Any) -> Any:
    """JSON values as TOML-able plain values (None only as 'delete')."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return float(a) == float(b) or (math.isnan(float(a)) and math.isnan(float(b)))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _diff(old: Any, new: Any, prefix: str, edits: dict[str, Any], replace: dict[str, list]) -> None:
    """Key-path edits turning ``old`` into ``new`` (arrays of tables that changed length: ``replace``)."""
    for key in old:
        if key not in new:
            edits[f"{prefix}{key}"] = DELETE
    for key, value in new.items():
        path = f"{prefix}{key}"
        if key not in old:
            if _is_aot(value) and not prefix:
                replace[key] = value
            else:
                edits[path] = value
            continue
        before = old[key]
        if isinstance(value, dict) and isinstance(before, dict):
            _diff(before, value, path + ".", edits, replace)
        elif _is_aot(value) and _is_aot(before) and len(value) == len(before):
            for i, (b, v) in enumerate(zip(before, value)):
                _diff(b, v, f"{path}[{i}].", edits, replace)
        elif _is_aot(value) and not prefix:
            replace[key] = value
        elif not _same(before, value):
            edits[path] = value


def _is_aot(x: Any) -> bool:
    return isinstance(x, list) and bool(x) and all(isinstance(e, dict) for e in x)


def _aot(entries: list[dict[str, Any]]) -> Any:
    aot = tomlkit.aot()
    for entry in entries:
        table = tomlkit.table()
        for k, v in entry.items():
            table[k] = _inline(v)
        aot.append(table)
    return aot


def _inline(value: Any) -> Any:
    if isinstance(value, dict):
        t = tomlkit.inline_table()
        for k, v in value.items():
            t[k] = _inline(v)
        return t
    return value
