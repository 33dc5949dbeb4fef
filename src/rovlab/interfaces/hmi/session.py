"""The HMI's state: a source of messages, the parameter documents being tuned, the session log,
and the commands a client may send. No web code here (see server.py), so all of it is testable
without a browser.

Commands are JSON objects ``{"cmd": NAME, ...}`` (an optional ``id`` is echoed in the reply):

=================  =============================================================================
``start``          run (paced by the server at ``speed`` times real time)
``pause``          stop advancing
``step``           ``n`` (default 1, at most 100) control steps while paused
``reset``          back to the scenario's start (tuned parameters are kept; a new log run begins)
``speed``          ``value``: 0.1 .. 50 times real time
``reference``      ``depth_m`` (0 .. 1000), ``heading_deg`` (degrees at the edge, -720 .. 720, wrapped
                   to -180 .. 180), ``north_m`` and/or ``east_m`` (position set-point, only for a
                   controller that follows x and y, e.g. "dp"); ``schedule: true`` goes back to the
                   scenario's reference schedule
``sensor``         ``sensor``: name, ``available``: true/false (simulated drop-out)
``filter_mode``    ``channel``: e.g. ``qualisys.z``, ``mode``: auto | off | on
``set``            ``target``: vehicle | truth | config, and ``key`` + ``value`` or ``changes``
                   (``{key path: value}``, applied together; value null deletes the key). Values
                   typed as text are read as TOML values ("7.5", "[1, 2]", "nan").
``revert``         ``target``: back to the document as loaded
``save``           ``target``: vehicle | truth | config | all; optional ``name`` (a file name in
                   the output folder) or ``in_place: true`` (write back to a user's own file)
``export``         ``formats``: ["csv", "mcap"] (default both): write the session log now
``state``          the full state again (to this client only)
=================  =============================================================================

A bad command raises :class:`CommandError` with a message for the user (and, for a refused
parameter value, the loader's problems: file, key, value, expectation); nothing changes then.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.interfaces.hmi.documents import ParameterDocument
from rovlab.interfaces.hmi.log import SessionLog, mcap_available
from rovlab.interfaces.hmi.source import Message, SimulationSource, Source
from rovlab.params.design import design_config_from_dict, resolve_config_path
from rovlab.params.validate import ConfigError, Problem, read_toml
from rovlab.params.vehicle import resolve_vehicle_path, vehicle_from_dict

TARGETS = ("vehicle", "truth", "config")
SPEED_RANGE = (0.1, 50.0)
MAX_STEPS_PER_COMMAND = 100  # 10 s of a 0.1 s loop: one client's "step" must not stall the others
MAX_COMMAND_DEPTH = 16  # nesting of a command's JSON (a key path's value is at most a table of lists)
DEPTH_RANGE_M = (0.0, 1000.0)  # a depth set-point: the free surface down to beyond any small vehicle's rating
MAX_POSITION_M = 1e4  # |north|, |east| set-point: 10 km, far beyond a tethered vehicle's reach
# |heading| set-point [deg]: two turns either way. Every way of writing a heading fits (-180 .. 180,
# 0 .. 360, a value just past a turn such as 370, which wraps to 10); a larger one is a slip or a
# unit mix-up that wrapping would hide: MAVLink's centidegrees (9000 for 90 deg) would wrap to 0 deg.
MAX_HEADING_DEG = 720.0
_DEG = math.pi / 180.0
_FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,100}\.toml$")
_SCENARIO_TRUTH_KEYS = {  # scenario [truth.parameters] key -> vehicle-file key path
    "mass": "rigid_body.mass", "I_zz": "rigid_body.I_zz", "displaced_volume": "restoring.displaced_volume",
    "X_udot": "added_mass.X_udot", "Y_vdot": "added_mass.Y_vdot", "Z_wdot": "added_mass.Z_wdot",
    "N_rdot": "added_mass.N_rdot",
}


class CommandError(Exception):
    """A command the session refused; ``message`` is for the user, ``problems`` name the fields."""

    def __init__(self, message: str, *, problems: list[Problem] | None = None, key: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.problems = problems or []
        self.key = key

    def payload(self) -> dict[str, Any]:
        out: dict[str, Any] = {"message": self.message}
        if self.key is not None:
            out["key"] = self.key
        if self.problems:
            out["problems"] = [{"file": p.file, "key": p.key, "value": _problem_value(p), "expected": p.expected,
                                "text": str(p)} for p in self.problems]
        return out


@dataclass
class Outcome:
    """What a command did: a reply for the sender and what the other clients must hear about."""

    result: dict[str, Any] = field(default_factory=dict)
    state_changed: bool = False  # broadcast the new state
    documents_changed: bool = False  # broadcast the documents (and the loop summary)
    reset: bool = False  # clients clear their plots
    messages: list[Message] = field(default_factory=list)  # produced by a "step" (broadcast as data)
    pacing_changed: bool = False  # the pacer re-anchors its clock


class Session:
    """A source, the three parameter documents, the log and the run state (running, speed)."""

    def __init__(self, source: Source, documents: Mapping[str, ParameterDocument], *, out_dir: str | Path,
                 speed: float = 1.0, running: bool = True, log: SessionLog | None = None) -> None:
        self.source = source
        self.documents = dict(documents)
        self.out_dir = Path(out_dir)
        self.log = log or SessionLog(self.out_dir)
        self.running = running and source.paced
        self.speed = _check_speed(speed)
        self.latest: dict[str, dict[str, Any]] = {}  # last message per topic
        self.files: dict[str, Path] = {}  # files this session wrote, by name (served for download)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def simulation(cls, scenario: str = "step-process-model", *, vehicle: str | None = None,
                   config: str | None = None, seed: int | None = None, out_dir: str | Path = "out/hmi",
                   speed: float = 1.0, running: bool = True) -> Session:
        """A session on a packaged or user scenario, optionally with another vehicle/configuration.

        Raises ConfigError (file, key, value, expectation) if any file is invalid.
        """
        from rovlab.sim.live import LiveSimulation
        from rovlab.sim.scenario import load_scenario

        sc = load_scenario(scenario, seed=seed)
        vdoc = _vehicle_document("vehicle", vehicle or sc.vehicle)
        tdoc = _vehicle_document("truth", vehicle or sc.vehicle, truth_parameters=sc.truth_parameters)
        cdoc = _config_document(config or sc.design)
        sim = LiveSimulation(sc, vehicle=vdoc.value, truth=tdoc.value, config=cdoc.value)
        sim.advance(1)  # compile (or load the cached) loop now, not on the first paced step
        sim.reset()
        return cls(SimulationSource(sim), {"vehicle": vdoc, "truth": tdoc, "config": cdoc}, out_dir=out_dir,
                   speed=speed, running=running)

    @classmethod
    def for_vehicle(cls, source: Source, *, vehicle: str, config: str, out_dir: str | Path = "out/hmi") -> Session:
        """A session on a vehicle bridge's source (its own clock, no truth): the model vehicle and
        configuration documents the bridge runs (the truth document mirrors the vehicle file; a
        vehicle refuses changes to it)."""
        vdoc = _vehicle_document("vehicle", vehicle)
        tdoc = _vehicle_document("truth", vehicle)
        cdoc = _config_document(config)
        return cls(source, {"vehicle": vdoc, "truth": tdoc, "config": cdoc}, out_dir=out_dir, running=False)

    # -- running -------------------------------------------------------------------------------
    def advance(self, n: int) -> list[Message]:
        """Run n steps of the source, log their messages and remember the latest of each topic."""
        messages = self.source.advance(n)
        self.log.add(messages)
        for topic, _, msg in messages[-8:]:
            self.latest[topic] = msg
        return messages

    def info(self) -> dict[str, Any]:
        """Fixed facts for a client that connects (plus the state and the documents)."""
        return {"source": self.source.describe(), "state": self.state(), "documents": self.documents_payload(),
                "speed_range": list(SPEED_RANGE), "targets": list(TARGETS)}

    def state(self) -> dict[str, Any]:
        st = self.source.status()
        ref = st["reference"]
        return {
            "running": self.running, "live": not self.source.paced, "speed": self.speed, "time_s": st["time_s"],
            "reference": {"depth_m": ref["z"], "heading_deg": ref["psi"] / _DEG, "north_m": ref.get("x", 0.0),
                          "east_m": ref.get("y", 0.0), "schedule": ref["schedule"]},
            "sensors": st["sensors"], "filter_modes": st["filter_modes"],
            # a vehicle bridge says whether a set-point is wanted and why it is not held (MAVLink)
            "engaged": st.get("engaged"), "vehicle": st.get("vehicle"),
            "sensor_status": dict(self.latest.get("/rovlab/estimate", {}).get("sensors", {})),
            "log": {"rows": self.log.rows, "runs": len(self.log.runs), "folder": str(self.log.folder),
                    "stem": self.log.stem},
            "saved": {t: str(d.saved_to) for t, d in self.documents.items() if d.saved_to is not None},
            "files": sorted(self.files),
        }

    def documents_payload(self) -> dict[str, Any]:
        return {
            "documents": {t: d.data for t, d in self.documents.items()},
            "origins": {t: {"file": str(d.origin) if d.origin else None, "label": d.label,
                            "packaged": d.packaged} for t, d in self.documents.items()},
            "loop": self.source.loop_summary(),
            "source": self.source.describe(),
        }

    # -- commands ------------------------------------------------------------------------------
    def handle(self, command: Any) -> Outcome:
        """Carry out one command (a dict parsed from JSON). Raises CommandError; then nothing changed."""
        if not isinstance(command, dict):
            raise CommandError(f"a command is a JSON object with a 'cmd' key, got {_kind(command)}")
        if _depth_exceeds(command, MAX_COMMAND_DEPTH):
            raise CommandError(f"a command nested deeper than {MAX_COMMAND_DEPTH} levels; expected a flat object "
                               "whose values are numbers, text, or small tables and lists")
        name = command.get("cmd")
        if not isinstance(name, str):
            raise CommandError("a command needs 'cmd': one of " + ", ".join(sorted(_COMMANDS)))
        handler = _COMMANDS.get(name)
        if handler is None:
            raise CommandError(f"unknown command {name!r}; known: " + ", ".join(sorted(_COMMANDS)))
        return handler(self, command)

    def _start(self, c: dict) -> Outcome:
        if not self.source.paced:
            raise CommandError("this source runs on its own clock; it cannot be started or paused here")
        if not self.running:
            self.running = True
            self.log.event(self.source.time, "start")
        return Outcome(state_changed=True, pacing_changed=True)

    def _pause(self, c: dict) -> Outcome:
        if not self.source.paced:
            raise CommandError("this source runs on its own clock; it cannot be started or paused here")
        if self.running:
            self.running = False
            self.log.event(self.source.time, "pause")
        return Outcome(state_changed=True, pacing_changed=True)

    def _step(self, c: dict) -> Outcome:
        n = _integer(c, "n", 1, lo=1, hi=MAX_STEPS_PER_COMMAND)
        if not self.source.paced:
            raise CommandError("this source runs on its own clock; it cannot be stepped here")
        if self.running:
            raise CommandError("pause first: single steps are for a paused run")
        return Outcome(messages=self.advance(n), state_changed=True)

    def _reset(self, c: dict) -> Outcome:
        if not self.source.paced:
            raise CommandError("this source runs on its own clock; it cannot be reset from here")
        self.log.event(self.source.time, "reset")
        self.source.reset()
        self.log.new_run()
        self.latest.clear()
        return Outcome(state_changed=True, reset=True, pacing_changed=True)

    def _speed(self, c: dict) -> Outcome:
        value = c.get("value")
        try:
            speed = _check_speed(value)
        except ValueError as exc:
            raise CommandError(str(exc), key="speed") from None
        self.speed = speed
        self.log.event(self.source.time, "speed", value=speed)
        return Outcome(state_changed=True, pacing_changed=True)

    def _reference(self, c: dict) -> Outcome:
        if c.get("schedule") is True:
            self.source.follow_schedule()
            self.log.event(self.source.time, "reference", schedule=True)
            return Outcome(state_changed=True)
        z = _optional_number(c, "depth_m")
        heading = _optional_number(c, "heading_deg")
        north = _optional_number(c, "north_m")
        east = _optional_number(c, "east_m")
        if z is None and heading is None and north is None and east is None:
            raise CommandError("a reference needs depth_m, heading_deg, north_m and/or east_m (or schedule: true)")
        lo, hi = DEPTH_RANGE_M
        if z is not None and not lo <= z <= hi:
            raise CommandError(f"depth_m must be within {lo:g} .. {hi:g} m (NED: 0 is the free surface, positive "
                               f"down), got {z:g}", key="depth_m")
        if heading is not None and not -MAX_HEADING_DEG <= heading <= MAX_HEADING_DEG:
            raise CommandError(f"heading_deg must be within -{MAX_HEADING_DEG:g} .. {MAX_HEADING_DEG:g} deg (it is "
                               f"wrapped to -180 .. 180; a larger value is a slip or another unit, e.g. "
                               f"centidegrees), got {heading:g}", key="heading_deg")
        for key, v in (("north_m", north), ("east_m", east)):
            if v is not None and not -MAX_POSITION_M <= v <= MAX_POSITION_M:
                raise CommandError(f"{key} must be within -{MAX_POSITION_M:g} .. {MAX_POSITION_M:g} m, got {v:g}",
                                   key=key)
        if north is not None or east is not None:
            described = self.source.describe()
            follows = described.get("references")  # what the running controller follows (None: not said)
            if follows is not None and not {"x", "y"} <= set(follows):
                key = "north_m" if north is not None else "east_m"
                raise CommandError(f"{key}: the running controller {described.get('controller', '?')!r} holds "
                                   f"{', '.join(follows) or 'nothing'} only, not a north/east position; choose a "
                                   "position controller (e.g. dp, with an estimator of x and y) in the Control "
                                   "tab first", key=key)
        psi = None
        if heading is not None:
            psi = math.remainder(heading * _DEG, 2.0 * math.pi)  # (-pi, pi]
        try:
            if north is None and east is None:  # sources without position set-points keep their two-argument call
                self.source.set_reference(z=z, psi=psi)
            else:
                self.source.set_reference(z=z, psi=psi, x=north, y=east)
        except ValueError as exc:  # the source's own check (a vehicle bridge: no DP there, no depth yet)
            given = (("north_m", north), ("east_m", east), ("depth_m", z), ("heading_deg", heading))
            key = next(k for k, v in given if v is not None)  # one was given (checked above)
            raise CommandError(f"reference refused: {exc}", key=key) from None
        position = {k: v for k, v in (("north_m", north), ("east_m", east)) if v is not None}
        self.log.event(self.source.time, "reference", depth_m=z, heading_deg=heading, **position)
        return Outcome(state_changed=True)

    def _sensor(self, c: dict) -> Outcome:
        sensor = _string(c, "sensor")
        available = c.get("available")
        if not isinstance(available, bool):
            raise CommandError(f"'available' must be true or false, got {_kind(available)}", key="available")
        try:
            self.source.set_sensor_available(sensor, available)
        except ValueError as exc:
            raise CommandError(str(exc), key="sensor") from None
        self.log.event(self.source.time, "sensor", sensor=sensor, available=available)
        return Outcome(state_changed=True)

    def _filter_mode(self, c: dict) -> Outcome:
        channel = _string(c, "channel")
        mode = _string(c, "mode")
        try:
            self.source.set_filter_mode(channel, mode)
        except ValueError as exc:
            raise CommandError(str(exc), key="mode") from None
        self.log.event(self.source.time, "filter_mode", channel=channel, mode=mode)
        return Outcome(state_changed=True)

    def _set(self, c: dict) -> Outcome:
        target = _target(c)
        if "changes" in c:
            changes = c["changes"]
            if not isinstance(changes, dict) or not changes:
                raise CommandError("'changes' must be an object {key path: value} with at least one entry")
        elif isinstance(c.get("key"), str):
            if "value" not in c:
                raise CommandError("'set' needs a 'value' (null deletes the key)", key=c["key"])
            changes = {c["key"]: c["value"]}
        else:
            raise CommandError("'set' needs 'key' and 'value', or 'changes'")
        doc = self.documents[target]
        try:
            # a value the loader passes but the design cannot use (a variance of 1e-320, whose inverse
            # overflows) raises FloatingPointError here instead of putting inf/NaN into the loop
            with np.errstate(over="raise", invalid="raise", divide="raise"):
                data, value = doc.candidate(changes)
                self.source.apply(**{target: value})  # designs first; raises before anything changes
        except ConfigError as exc:
            raise CommandError(_refusal(target, exc), problems=exc.problems,
                               key=next(iter(changes))) from None
        except (ValueError, TypeError, ArithmeticError, KeyError) as exc:
            given = ", ".join(f"{k} = {_kind(v)}" for k, v in changes.items())
            raise CommandError(f"{_WHAT[target]} unchanged: the design failed with {given} ({exc}); expected a "
                               "value of a physically sensible size", key=next(iter(changes))) from None
        doc.commit(data, value)
        applied = {k: doc.get(k) for k in changes}
        self.log.event(self.source.time, "set", target=target, changes=_jsonable(applied))
        return Outcome(result={"target": target, "applied": applied},
                       documents_changed=True, state_changed=True)

    def _revert(self, c: dict) -> Outcome:
        target = _target(c)
        doc = self.documents[target]
        try:
            value = doc.validate(doc.loaded)
            self.source.apply(**{target: value})
        except ConfigError as exc:
            raise CommandError(_refusal(target, exc), problems=exc.problems) from None
        doc.commit(dict(doc.loaded), value)
        self.log.event(self.source.time, "revert", target=target)
        return Outcome(documents_changed=True, state_changed=True)

    def _save(self, c: dict) -> Outcome:
        target = c.get("target", "all")
        targets = TARGETS if target == "all" else (_target(c),)
        name = c.get("name")
        in_place = c.get("in_place", False)
        if name is not None and (not isinstance(name, str) or not _FILE_NAME.fullmatch(name)):
            raise CommandError("name must be a plain file name ending in .toml (letters, digits, . _ -), "
                               f"got {name!r}", key="name")
        if name is not None and len(targets) != 1:
            raise CommandError("a file name can only be given when saving one target", key="name")
        if not isinstance(in_place, bool):
            raise CommandError(f"'in_place' must be true or false, got {_kind(in_place)}", key="in_place")
        saved = {}
        for t in targets:
            doc = self.documents[t]
            if in_place:
                if doc.origin is None or doc.packaged or t == "truth":
                    raise CommandError(f"{t}: only a user's own file can be saved in place; its origin is "
                                       f"{doc.label}", key="in_place")
                path = doc.origin
            else:
                path = self.out_dir / (name or _default_name(t, doc))
            try:
                written, kept = doc.save(path)
            except ConfigError as exc:
                raise CommandError(f"{t}: saving failed: {exc}", problems=exc.problems) from None
            except OSError as exc:
                raise CommandError(f"{t}: could not write {path}: {exc.strerror or exc}") from None
            self.files[written.name] = written
            saved[t] = {"path": str(written), "comments_kept": kept, "url": f"/files/{written.name}"}
            self.log.event(self.source.time, "save", target=t, path=str(written))
        return Outcome(result={"saved": saved}, state_changed=True)

    def _export(self, c: dict) -> Outcome:
        formats = c.get("formats", ["csv", "mcap"])
        if not isinstance(formats, list) or not formats or not all(f in ("csv", "mcap") for f in formats):
            raise CommandError(f"'formats' must be a list of 'csv' and/or 'mcap', got {formats!r}", key="formats")
        notes = []
        if "mcap" in formats and not mcap_available():
            formats = [f for f in formats if f != "mcap"]
            notes.append("MCAP needs the 'mcap' package (pip install 'rovlab[log]'); wrote CSV only")
            if not formats:
                formats = ["csv"]
        if not self.log.rows:
            raise CommandError("nothing to export yet: the log is empty (start the run first)")
        try:
            paths = self.export(formats)
        except OSError as exc:
            raise CommandError(f"could not write the log: {exc}") from None
        return Outcome(result={"files": [{"path": str(p), "url": f"/files/{p.name}"} for p in paths],
                               "notes": notes}, state_changed=True)

    def _state(self, c: dict) -> Outcome:
        return Outcome(result=self.info())

    # -- shutdown --------------------------------------------------------------------------------
    def export(self, formats: list[str] | tuple[str, ...] | None = None) -> list[Path]:
        """Write the session log (and events) now; returns the files."""
        if formats is None:
            formats = ["csv", "mcap"] if mcap_available() else ["csv"]
        meta = {"source": self.source.kind, **{t: d.label for t, d in self.documents.items()}}
        paths = self.log.write(formats, metadata=meta)
        for p in paths:
            self.files[p.name] = p
        return paths


_COMMANDS = {
    "start": Session._start, "pause": Session._pause, "step": Session._step, "reset": Session._reset,
    "speed": Session._speed, "reference": Session._reference, "sensor": Session._sensor,
    "filter_mode": Session._filter_mode, "set": Session._set, "revert": Session._revert, "save": Session._save,
    "export": Session._export, "state": Session._state,
}


# --------------------------------------------------------------------------------------------
# Documents from files
# --------------------------------------------------------------------------------------------

def _is_packaged(path: Path) -> bool:
    import rovlab

    root = Path(rovlab.__file__).resolve().parent
    try:
        path.resolve().relative_to(root)
    except ValueError:
        return False
    return True


def _vehicle_document(target: str, ref: str, *, truth_parameters: Mapping[str, float] | None = None
                      ) -> ParameterDocument:
    path = resolve_vehicle_path(ref)
    data = read_toml(path)
    for key, value in (truth_parameters or {}).items():  # the scenario's plant differs from the file
        section, _, name = _SCENARIO_TRUTH_KEYS[key].partition(".")
        data.setdefault(section, {})[name] = float(value)
    label = f"{path.name} ({'plant truth' if target == 'truth' else 'model vehicle'})"
    return ParameterDocument(target, data, origin=path, label=label, packaged=_is_packaged(path),
                             validate=lambda d, f: vehicle_from_dict(d, file=f))


def _config_document(ref: str) -> ParameterDocument:
    path = resolve_config_path(ref)
    data = read_toml(path)
    return ParameterDocument("config", data, origin=path, label=f"{path.name} (filter/controller)",
                             packaged=_is_packaged(path), validate=lambda d, f: design_config_from_dict(d, file=f))


def _default_name(target: str, doc: ParameterDocument) -> str:
    base = str(doc.data.get("name") or target)
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", base)[:60] or target
    return f"{target}-{base}.toml"


# --------------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------------

def _depth_exceeds(value: Any, limit: int) -> bool:
    """Whether nested dicts/lists go deeper than ``limit`` (iterative: no recursion to exhaust)."""
    stack = [(value, 1)]
    while stack:
        node, depth = stack.pop()
        children: Any
        if isinstance(node, dict):
            children = node.values()
        elif isinstance(node, list):
            children = node
        else:
            continue
        if depth > limit:
            return True
        stack.extend((child, depth + 1) for child in children)
    return False


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int) and abs(value) >= 10**40:
        return f"an integer of {len(str(abs(value)))} digits"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return repr(value[:40] + ("..." if len(value) > 40 else ""))
    return f"a JSON {type(value).__name__}".replace("dict", "object").replace("list", "array")


def _finite_float(value: Any) -> float | None:
    """value as a finite float, or None (text, true/false, NaN, infinities, an integer beyond a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        x = float(value)
    except OverflowError:  # a JSON integer of 400 digits
        return None
    return x if math.isfinite(x) else None


def _check_speed(value: Any) -> float:
    lo, hi = SPEED_RANGE
    x = _finite_float(value)
    if x is None or not lo <= x <= hi:
        raise ValueError(f"speed must be a number from {lo:g} to {hi:g} (times real time), got {_kind(value)}")
    return x


def _optional_number(c: dict, key: str) -> float | None:
    value = c.get(key)
    if value is None:
        return None
    x = _finite_float(value)
    if x is None:
        raise CommandError(f"{key} must be a finite number, got {_kind(value)}", key=key)
    return x


def _integer(c: dict, key: str, default: int, *, lo: int, hi: int) -> int:
    value = c.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise CommandError(f"{key} must be an integer from {lo} to {hi}, got {_kind(value)}", key=key)
    return value


def _string(c: dict, key: str) -> str:
    value = c.get(key)
    if not isinstance(value, str) or not value:
        raise CommandError(f"{key} must be a non-empty string, got {_kind(value)}", key=key)
    return value


def _target(c: dict) -> str:
    target = c.get("target")
    if target not in TARGETS:
        raise CommandError("target must be one of " + ", ".join(TARGETS) + f", got {_kind(target)}", key="target")
    return target


_WHAT = {"vehicle": "model vehicle", "truth": "plant truth", "config": "filter/controller configuration"}


def _refusal(target: str, exc: ConfigError) -> str:
    return f"{_WHAT[target]} unchanged: " + ("; ".join(str(p) for p in exc.problems) or str(exc))


def _problem_value(p: Problem) -> Any:
    return None if type(p.value).__name__ == "_Missing" else _jsonable(p.value)


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return _jsonable(value.tolist())
    return repr(value)
