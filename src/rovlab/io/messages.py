"""The messages rovlab's loop publishes, the same for the simulator and a real vehicle's bridge.

Each message is a JSON-able dict on a topic. The simulator's logs (MCAP), the HMI's live stream
and a middleware bridge all use these builders, so a consumer cannot tell a simulated vehicle from
a real one (a real vehicle simply has no ``/rovlab/truth``).

Column naming of a time-series log (rovlab.io.timeseries) maps onto the topics:
``true_*`` -> truth, ``est_*`` and ``var_*`` and ``status_*`` -> estimate, ``meas_*`` ->
measurement, ``ref_*`` -> reference, ``tau_*`` and ``pwm_*`` -> command; a controller's own state (``ctrl_*``,
e.g. MRAC's adapted parameters) travels with the command as ``controller``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

# status codes of rovlab.estimation.fusion (STATUS_OK, STATUS_RECOVERING, STATUS_LOST, STATUS_OFF)
SENSOR_STATUS = {0: "ok", 1: "recovering", 2: "lost", 3: "off"}

_NUM = {"type": "number"}
_MAP = {"type": "object", "additionalProperties": {"type": ["number", "null"]}}
TOPICS: dict[str, dict[str, Any]] = {
    "/rovlab/truth": {"type": "object", "properties": {"t": _NUM, "state": _MAP}},
    "/rovlab/estimate": {"type": "object", "properties": {
        "t": _NUM, "state": _MAP, "variance": _MAP,
        "sensors": {"type": "object", "additionalProperties": {"type": "string"}}}},
    "/rovlab/measurement": {"type": "object", "properties": {"t": _NUM, "values": _MAP}},
    "/rovlab/reference": {"type": "object", "properties": {"t": _NUM, "state": _MAP}},
    "/rovlab/command": {"type": "object", "properties": {"t": _NUM, "tau": _MAP, "pwm_us": _MAP,
                                                         "controller": _MAP}},
}


def _rank(name: str) -> int:
    """Group of a column in a log's order: time, truth, estimate, samples, references, commands,
    PWM, variances, sensor status, demanded wrench, true biases, controller state, the rest."""
    if name == "time_s":
        return 0
    if name.startswith("true_b_"):
        return 10
    if name.startswith("tau_") and name.endswith("_demanded"):
        return 9
    for i, prefix in enumerate(("true_", "est_", "meas_", "ref_", "tau_", "pwm_", "var_", "status_"), start=1):
        if name.startswith(prefix):
            return i
    return 11 if name.startswith("ctrl_") else 12


def order_columns(columns: Mapping[str, Any]) -> dict[str, Any]:
    """The columns in the one order every rovlab log uses (timeseries.csv, the HMI session log),
    stable within each group."""
    return {k: columns[k] for k in sorted(columns, key=_rank)}


def status_words(columns: Mapping[str, Any]) -> dict[str, Any]:
    """The columns with ``status_*`` codes (0 ok, 1 recovering, 2 lost, 3 off) as words."""
    out = dict(columns)
    for k, v in columns.items():
        if k.startswith("status_"):
            out[k] = [SENSOR_STATUS.get(int(c), "unknown") if c == c else "" for c in np.asarray(v, dtype=float).tolist()]
    return out


def _clean(value: float) -> float | None:
    v = float(value)
    return None if math.isnan(v) else v


def truth_message(t: float, state: Mapping[str, float]) -> dict[str, Any]:
    return {"t": float(t), "state": {k: _clean(v) for k, v in state.items()}}


def estimate_message(t: float, state: Mapping[str, float], variance: Mapping[str, float],
                     sensors: Mapping[str, str]) -> dict[str, Any]:
    return {"t": float(t), "state": {k: _clean(v) for k, v in state.items()},
            "variance": {k: _clean(v) for k, v in variance.items()}, "sensors": dict(sensors)}


def measurement_message(t: float, values: Mapping[str, float]) -> dict[str, Any]:
    """Measurements present at time t (channel -> value); absent channels are left out."""
    return {"t": float(t), "values": {k: float(v) for k, v in values.items() if not math.isnan(float(v))}}


def reference_message(t: float, state: Mapping[str, float]) -> dict[str, Any]:
    return {"t": float(t), "state": {k: _clean(v) for k, v in state.items()}}


def command_message(t: float, tau: Mapping[str, float], pwm_us: Mapping[str, float],
                    controller: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Commands of time t; ``controller``: the controller's own state (left out when it has none)."""
    out = {"t": float(t), "tau": {k: _clean(v) for k, v in tau.items()},
           "pwm_us": {k: _clean(v) for k, v in pwm_us.items()}}
    if controller:
        out["controller"] = {k: _clean(v) for k, v in controller.items()}
    return out


_PREFIXES = ("true_", "est_", "var_", "status_", "meas_", "ref_", "tau_", "pwm_", "ctrl_")


def _groups(columns: Mapping[str, Any]) -> dict[str, dict[str, list[float]]]:
    """The columns by message group (prefix -> {name without prefix: values as Python floats})."""
    out: dict[str, dict[str, list[float]]] = {p: {} for p in _PREFIXES}
    for name, col in columns.items():
        for p in _PREFIXES:
            if name.startswith(p):
                out[p][name[len(p):]] = np.asarray(col, dtype=float).tolist()
                break
    return out


def _messages(groups: Mapping[str, Mapping[str, list[float]]], t: float,
              k: int) -> Iterator[tuple[str, float, dict[str, Any]]]:
    if groups["true_"]:
        yield "/rovlab/truth", t, truth_message(t, {n: c[k] for n, c in groups["true_"].items()})
    if groups["est_"]:
        status = {n: SENSOR_STATUS.get(int(c[k]), "unknown") for n, c in groups["status_"].items()
                  if not math.isnan(c[k])}
        yield "/rovlab/estimate", t, estimate_message(
            t, {n: c[k] for n, c in groups["est_"].items()}, {n: c[k] for n, c in groups["var_"].items()}, status)
    if groups["meas_"]:
        yield "/rovlab/measurement", t, measurement_message(t, {n: c[k] for n, c in groups["meas_"].items()})
    if groups["ref_"]:
        yield "/rovlab/reference", t, reference_message(t, {n: c[k] for n, c in groups["ref_"].items()})
    if groups["tau_"] or groups["pwm_"]:
        yield "/rovlab/command", t, command_message(t, {n: c[k] for n, c in groups["tau_"].items()},
                                                    {n: c[k] for n, c in groups["pwm_"].items()},
                                                    {n: c[k] for n, c in groups["ctrl_"].items()})


def row_messages(columns: Mapping[str, np.ndarray], k: int) -> Iterator[tuple[str, float, dict[str, Any]]]:
    """The messages of row k of a time-series log."""
    k = range(len(columns["time_s"]))[k]  # a negative k counts from the end, as indexing does
    yield from _messages(_groups({n: np.asarray(c)[k:k + 1] for n, c in columns.items()}),
                         float(columns["time_s"][k]), 0)


def rows_to_messages(columns: Mapping[str, np.ndarray]) -> Iterator[tuple[str, float, dict[str, Any]]]:
    """The messages of every row, in row order (the columns are grouped once)."""
    groups = _groups(columns)
    for k, t in enumerate(np.asarray(columns["time_s"], dtype=float).tolist()):
        yield from _messages(groups, t, k)
