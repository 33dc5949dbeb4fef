"""Published heave and yaw parameter sets, scored beside an identified model (issue 29).

``rovlab identify dive --compare NAME|FILE`` predicts the validation segment of a dive with a
published parameter set as well as with the identified model and the vehicle file it started from.
The packaged sets are in ``published_sets.toml`` next to this module, each with its citation; a set
is the default comparison of the vehicle files it lists under ``vehicles`` (by their ``name``).
A parameter a set does not publish (or publishes for another vehicle's ballast, such as B - W) is
taken from the vehicle file, and :meth:`PublishedSet.taken_from_file` names it.

A set file (the packaged one or a user's) holds one table per set::

    [myset]
    title = "..."
    citation = "author, title, table, page"
    vehicles = ["bluerov2_heavy"]          # optional: default comparison for these vehicle names
    [myset.values]                         # SI, SNAME signs; any of the keys below
    mass = 11.5                            # the rigid-body mass and I_zz the set was identified with
    Z_wdot = -14.57
    [myset.from_file]                      # optional: published values not used, and why
    "B-W" = "ballast of that vehicle"
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rovlab.ident.dive import NAMES, DofModel, dof_model
from rovlab.ident.fitting import IdentificationError
from rovlab.params.vehicle import Vehicle

PACKAGED = "published_sets.toml"
_RIGID = {"mass": ("heave", "surge", "sway"), "I_zz": ("yaw",)}
# report name -> (dof, DofModel field)
_PARAMS = {name: (dof, key) for dof, names in NAMES.items() for key, name in names.items() if key != "thrust_scale"}
VALUE_KEYS = tuple(_RIGID) + tuple(_PARAMS)
_TABLE_KEYS = {"title", "citation", "source", "vehicles", "values", "from_file"}


@dataclass(frozen=True, eq=False)
class PublishedSet:
    """One published parameter set (SI, SNAME signs) with its citation."""

    name: str
    title: str
    citation: str
    values: Mapping[str, float]
    vehicles: tuple[str, ...] = ()
    source: str = ""
    from_file: Mapping[str, str] = field(default_factory=dict)  # published but not used: why
    file: str = ""

    def models(self, vehicle: Vehicle, dofs: tuple[str, ...] = ("heave", "yaw")) -> dict[str, DofModel]:
        """The heave and yaw models of this set: its values where it gives them, the vehicle
        file's elsewhere (thrust curves always the file's: thrust scale 1)."""
        out = {}
        for dof in dofs:
            base = dof_model(vehicle, dof)
            changes = {key: self.values[name] for name, (d, key) in _PARAMS.items() if d == dof and name in self.values}
            rigid = next((k for k, d in _RIGID.items() if dof in d), None)
            if rigid is not None and rigid in self.values:
                changes["rigid"] = self.values[rigid]
            out[dof] = base.with_values(changes)
        return out

    def taken_from_file(self, dofs: tuple[str, ...] = ("heave", "yaw")) -> list[str]:
        """Report names of the parameters this set does not give (the vehicle file's are used)."""
        names = [k for k, d in _RIGID.items() if set(d) & set(dofs)] + [n for n, (d, _) in _PARAMS.items() if d in dofs]
        return [n for n in names if n not in self.values]

    def note(self) -> str:
        """One line for a report: which set, where from, what is the file's."""
        names = [f"{k} ({self.from_file[k]})" if k in self.from_file else k for k in self.taken_from_file()]
        return (f"published set {self.name}: {self.title}"
                + (f"; from the vehicle file: {', '.join(names)}" if names else "")
                + "; the full citation is in --json (published_set)")

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "title": self.title, "citation": self.citation, "source": self.source,
                "values": dict(self.values), "taken_from_file": self.taken_from_file(),
                "published_not_used": dict(self.from_file), "file": self.file}


def _parse(name: str, table: Any, file: str) -> PublishedSet:
    where = f"{file}: [{name}]"
    if not isinstance(table, Mapping):
        raise IdentificationError(f"{where}: expected a table of a parameter set, got {table!r}")
    unknown = sorted(set(table) - _TABLE_KEYS)
    if unknown:
        raise IdentificationError(f"{where}: unknown key(s) {', '.join(unknown)}; expected "
                                  f"{', '.join(sorted(_TABLE_KEYS))}")
    for key in ("title", "citation", "values"):
        if key not in table:
            raise IdentificationError(f"{where}: no {key!r}; a published set needs a title, a citation (author, "
                                      "title, table and page) and its values")
    vals = table["values"]
    if not isinstance(vals, Mapping) or not vals:
        raise IdentificationError(f"{where}.values: expected a table of parameter values, got {vals!r}")
    values: dict[str, float] = {}
    for k, v in vals.items():
        if k not in VALUE_KEYS:
            raise IdentificationError(f"{where}.values: unknown parameter {k!r}; expected one of "
                                      f"{', '.join(VALUE_KEYS)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise IdentificationError(f"{where}.values.{k} = {v!r}: expected a finite number")
        if k in _RIGID and not v > 0:
            raise IdentificationError(f"{where}.values.{k} = {v!r}: expected a positive mass or inertia")
        if k in _PARAMS and _PARAMS[k][1] != "net_buoyancy" and v > 0:
            raise IdentificationError(f"{where}.values.{k} = {v!r}: expected a value <= 0 (SNAME signs: added mass "
                                      "and damping derivatives are negative; a paper's positive magnitude is "
                                      "written with a minus sign)")
        values[k] = float(v)
    vehicles = table.get("vehicles", [])
    if not isinstance(vehicles, list) or not all(isinstance(x, str) for x in vehicles):
        raise IdentificationError(f"{where}.vehicles = {vehicles!r}: expected a list of vehicle names")
    from_file = table.get("from_file", {})
    if not isinstance(from_file, Mapping) or not all(isinstance(x, str) for x in from_file.values()):
        raise IdentificationError(f"{where}.from_file: expected a table of parameter = \"why\" strings")
    return PublishedSet(name, str(table["title"]), str(table["citation"]), values, tuple(vehicles),
                        str(table.get("source", "")), dict(from_file), file)


def _read(path: Path | None) -> dict[str, PublishedSet]:
    import tomllib

    if path is None:
        from importlib import resources

        text = (resources.files("rovlab.ident") / PACKAGED).read_text(encoding="utf-8")
        file = PACKAGED
    else:
        file = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise IdentificationError(f"{file}: cannot read the parameter set file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise IdentificationError(f"{file}: not a TOML file ({exc}); expected tables of published parameter "
                                  "sets") from None
    if not data:
        raise IdentificationError(f"{file}: no parameter set; expected a table such as [myset] with title, "
                                  "citation and values")
    return {name: _parse(name, table, file) for name, table in data.items()}


def packaged_sets() -> dict[str, PublishedSet]:
    return _read(None)


def load_set(name_or_path: str | Path) -> PublishedSet:
    """A packaged set by name, or the (only) set of a TOML file (``FILE:NAME`` picks one of several)."""
    text = str(name_or_path)
    packaged = packaged_sets()
    if text in packaged:
        return packaged[text]
    path, _, pick = text.partition(":") if not Path(text).exists() and ":" in text else (text, "", "")
    p = Path(path)
    if not p.exists():
        raise IdentificationError(f"--compare {text}: no such packaged set or file; packaged sets: "
                                  f"{', '.join(packaged)} (or a TOML file of sets, or 'none')")
    sets = _read(p)
    if pick:
        if pick not in sets:
            raise IdentificationError(f"{path}: no set [{pick}]; it holds {', '.join(sets)}")
        return sets[pick]
    if len(sets) > 1:
        raise IdentificationError(f"{path}: holds {len(sets)} sets ({', '.join(sets)}); choose one with "
                                  f"--compare {path}:NAME")
    return next(iter(sets.values()))


def default_set(vehicle: Vehicle) -> PublishedSet | None:
    """The packaged set that lists this vehicle's name, if any."""
    return next((s for s in packaged_sets().values() if vehicle.name in s.vehicles), None)
