"""Fuzzing the HMI's set-point and parameter fields (issue 28): every field the page offers gets
NaN, infinities, huge and tiny numbers, text, true/false, arrays and integers beyond a float, as a
page (or anything else that speaks the WebSocket) would send them.

Each command must either be refused with a CommandError that names the field (and then nothing
changed: documents, design, reference) or be accepted, and then the loop's next steps publish
finite numbers only and the design in the loop has no non-finite number it did not have before.
The set-point commands all run; of the parameter commands the normal suite runs a seeded sample,
``make test-slow`` all (``ROVLAB_FUZZ_BUDGET`` overrides both).
"""

from __future__ import annotations

import math
import os
import random
from typing import Any

import pytest

from rovlab.interfaces.hmi.session import CommandError, Session

BUDGET = int(os.environ.get("ROVLAB_FUZZ_BUDGET", "0")) or None
SMALL = 120  # parameter commands per scenario in the normal suite (and every set-point command)
VALUES: list[Any] = ["nan", "inf", "-inf", math.nan, math.inf, "1e308", "-1e308", 1e300, 1e154, 1e-308, 5e-324,
                     "abc", "", " ", True, [1.0, 2.0], {"a": 1}, 10**400, -(10**400), "1e400", 0, -1]
REFERENCE_KEYS = ("depth_m", "heading_deg", "north_m", "east_m")
TEXT_FIELDS = (("config", "controller"), ("config", "estimator"), ("vehicle", "name"), ("truth", "name"))


def _numeric_leaves(node: Any, prefix: str = "") -> list[str]:
    """Key paths (rovlab.params.edit syntax) of every number in a document: the page's fields."""
    out: list[str] = []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _numeric_leaves(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(node, list):
        if node and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in node):
            out.append(prefix)  # a list of numbers is one field (e.g. lqr.Q_diag)
        for i, v in enumerate(node):
            if isinstance(v, dict):
                out += _numeric_leaves(v, f"{prefix}[name={v['name']}]" if "name" in v else f"{prefix}[{i}]")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        out.append(prefix)
    return out


def _nonfinite(x: Any, path: str = "") -> set[str]:
    if isinstance(x, float):
        return set() if math.isfinite(x) else {path}
    if isinstance(x, dict):
        return set().union(*(_nonfinite(v, f"{path}.{k}") for k, v in x.items())) if x else set()
    if isinstance(x, (list, tuple)):
        return set().union(*(_nonfinite(v, f"{path}[{i}]") for i, v in enumerate(x))) if x else set()
    return set()


def _commands(session: Session, budget: int | None) -> list[dict[str, Any]]:
    """Every set-point command, and (a seeded sample of ``budget`` of) the parameter commands: each
    number of the three documents and the names (controller, estimator, vehicle)."""
    sets = [{"cmd": "set", "target": target, "key": key, "value": v} for target in ("vehicle", "truth", "config")
            for key in _numeric_leaves(session.documents[target].data) for v in VALUES]
    sets += [{"cmd": "set", "target": target, "key": key, "value": v} for target, key in TEXT_FIELDS
             for v in VALUES + ["dp", "mrac", "../dp", "x" * 300]]
    if budget is not None and budget < len(sets):
        sets = random.Random(28).sample(sets, budget)
    return [{"cmd": "reference", key: v} for key in REFERENCE_KEYS for v in VALUES + [-5, 721, 9000, -1e4 - 1]] + sets


def _loop_nonfinite(session: Session) -> set[str]:
    """Non-finite numbers of the design in the loop. The configuration's LQR weights (lqr_Q, lqr_R)
    are an echo of the file: they reach the loop only through K and P, which are checked (a DP
    scenario does not use them)."""
    return {p for p in _nonfinite(session.source.loop_summary()) if not p.startswith((".lqr_Q", ".lqr_R"))}


def _snapshot(session: Session) -> tuple:
    return ({t: d.data for t, d in session.documents.items()}, session.source.loop_summary(),
            session.state()["reference"])


def _campaign(tmp_path, scenario: str, budget: int | None) -> None:
    session = Session.simulation(scenario, out_dir=tmp_path / "out", running=False)
    session.advance(5)
    baseline = _loop_nonfinite(session)
    commands = _commands(session, budget)
    refused = 0
    for command in commands:
        key = command.get("key") or next(k for k in REFERENCE_KEYS if k in command)
        before = _snapshot(session)
        try:
            session.handle(command)
        except CommandError as exc:
            assert exc.message and exc.key == key, (command, exc.message, exc.key)
            assert _snapshot(session) == before, command  # nothing changed
            refused += 1
            continue
        messages = session.advance(3)
        bad = sorted({topic for topic, _, m in messages if _nonfinite(m)})
        assert not bad, (command, bad)
        assert _loop_nonfinite(session) <= baseline, command
        ref = session.state()["reference"]
        assert abs(ref["heading_deg"]) <= 180 + 1e-9 and 0 <= ref["depth_m"] <= 1000, (command, ref)
        if command["cmd"] == "reference":  # the loop holds what was accepted (1e308 deg became -95.7 deg)
            value = float(command[key])
            if key == "heading_deg":
                assert abs(math.remainder(ref["heading_deg"] - value, 360.0)) < 1e-9, (command, ref)
            else:
                assert ref[key] == value, (command, ref)
        if command["cmd"] == "set":
            session.handle({"cmd": "revert", "target": command["target"]})
    assert refused > len(commands) // 2  # it ran, and most of the garbage was refused


@pytest.mark.parametrize("scenario", ["step-process-model", "dp-square"])
def test_every_field_refuses_garbage_or_keeps_the_loop_finite(tmp_path, scenario):
    _campaign(tmp_path, scenario, BUDGET or SMALL)


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["step-process-model", "dp-square", "heave-payload"])
def test_every_field_with_every_value(tmp_path, scenario):
    _campaign(tmp_path, scenario, BUDGET)
