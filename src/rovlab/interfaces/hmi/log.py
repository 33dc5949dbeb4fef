"""The session log: every message the HMI received, kept as the columns of a time-series log
(:mod:`rovlab.io.timeseries`) so it can be written as CSV and MCAP at any time.

Messages are turned back into columns with the naming of :mod:`rovlab.io.messages`
(``true_*``, ``est_*``, ``var_*``, ``status_*``, ``meas_*``, ``ref_*``, ``tau_*``, ``pwm_*``);
messages with the same time stamp form one row. A reset of the simulation starts a new *run*
(time starts again at 0), written to its own files. The user's actions (parameter changes,
sensor switches ...) are kept as events with the time they happened at.
"""

from __future__ import annotations

import json
import math
import time
from array import array
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.files import atomic_write_text
from rovlab.io.logwriter import write_csv
from rovlab.io.messages import SENSOR_STATUS, order_columns, status_words
from rovlab.io.timeseries import series_path, write_mcap

_STATUS_CODE = {name: float(code) for code, name in SENSOR_STATUS.items()}
# topic -> (field of the message, column prefix)
_FIELDS = {
    "/rovlab/truth": (("state", "true_"),),
    "/rovlab/estimate": (("state", "est_"), ("variance", "var_"), ("sensors", "status_")),
    "/rovlab/measurement": (("values", "meas_"),),
    "/rovlab/reference": (("state", "ref_"),),
    "/rovlab/command": (("tau", "tau_"), ("pwm_us", "pwm_"), ("controller", "ctrl_")),
}


class Run:
    """The rows of one run: columns of float64 (NaN: no value), ``time_s`` first."""

    def __init__(self) -> None:
        self.columns: dict[str, array] = {"time_s": array("d")}
        self.started = time.time()  # wall-clock start of the run (MCAP log times)
        self.rows = 0
        self._row: dict[str, float] | None = None
        self._t: float | None = None

    def add(self, topic: str, t: float, message: dict[str, Any]) -> None:
        fields = _FIELDS.get(topic)
        if fields is None:
            return  # a topic this log does not know (future bridges may publish more)
        if self._row is None or self._t != t:
            self._flush()
            self._row = {"time_s": float(t)}
            self._t = t
        for field, prefix in fields:
            values = message.get(field)
            if not isinstance(values, dict):
                continue
            for name, v in values.items():
                self._row[prefix + str(name)] = _number(v, prefix == "status_")

    def _flush(self) -> None:
        row = self._row
        if row is None:
            return
        for name in row:
            if name not in self.columns:
                self.columns[name] = array("d", [math.nan]) * self.rows
        for name, col in self.columns.items():
            col.append(row.get(name, math.nan))
        self.rows += 1
        self._row = None

    def finish(self) -> None:
        self._flush()
        self._t = None

    def arrays(self) -> dict[str, np.ndarray]:
        """The columns as numpy arrays, the row still being assembled included."""
        pending = self._row or {}
        names = list(self.columns) + [n for n in pending if n not in self.columns]
        out: dict[str, np.ndarray] = {}
        for name in names:
            col = self.columns.get(name)
            base = np.array(col, dtype=float) if col is not None else np.full(self.rows, math.nan)
            out[name] = np.append(base, pending.get(name, math.nan)) if self._row is not None else base
        return out

    def __len__(self) -> int:
        return self.rows + (1 if self._row is not None else 0)


def _number(v: Any, status: bool) -> float:
    if status:
        return _STATUS_CODE.get(v, math.nan) if isinstance(v, str) else math.nan
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return math.nan
    return float(v)


class SessionLog:
    """All runs of one HMI session plus the user's actions, written under ``folder/stem*``."""

    def __init__(self, folder: str | Path, stem: str | None = None) -> None:
        self.folder = Path(folder)
        self.stem = stem or time.strftime("session-%Y%m%d-%H%M%S")
        self.runs: list[Run] = [Run()]
        self.events: list[dict[str, Any]] = []

    @property
    def run(self) -> Run:
        return self.runs[-1]

    def add(self, messages: Iterable[tuple[str, float, dict[str, Any]]]) -> None:
        run = self.run
        for topic, t, msg in messages:
            run.add(topic, t, msg)

    def new_run(self) -> None:
        """After a reset: time starts again, so the rows go to a new run."""
        self.run.finish()
        if len(self.run):
            self.runs.append(Run())

    def event(self, t: float, what: str, **details: Any) -> None:
        self.events.append({"run": len(self.runs), "t": float(t), "wall_time": time.time(), "what": what,
                            **details})

    @property
    def rows(self) -> int:
        return sum(len(r) for r in self.runs)

    def paths(self, formats: Iterable[str] = ("csv", "mcap")) -> list[Path]:
        """Files :meth:`write` would write now."""
        runs = [i for i, r in enumerate(self.runs, 1) if len(r)]
        out: list[Path] = []
        for i in runs:
            name = self.stem if len(runs) == 1 and i == 1 else f"{self.stem}-run{i}"
            for fmt in formats:
                out.append(self.folder / f"{name}.{fmt}")
                if fmt == "mcap":  # a ROS 2 bag and rovlab's series beside it
                    out.append(series_path(out[-1]))
        return out

    def write(self, formats: Iterable[str] = ("csv", "mcap"), *, metadata: dict[str, str] | None = None
              ) -> list[Path]:
        """Write every run with rows (one file per run and format) and the events; returns the paths.

        MCAP needs the ``mcap`` package; without it only CSV is written (and said so by the caller).
        """
        formats = tuple(formats)
        self.folder.mkdir(parents=True, exist_ok=True)
        written: list[Path] = []
        nonempty = [(i, r) for i, r in enumerate(self.runs, 1) if len(r)]
        for i, run in nonempty:
            name = self.stem if len(nonempty) == 1 and i == 1 else f"{self.stem}-run{i}"
            cols = order_columns(run.arrays())  # the order and words of timeseries.csv
            for fmt in formats:
                path = self.folder / f"{name}.{fmt}"
                if fmt == "csv":
                    write_csv(path, status_words(cols), exact=("time_s",))
                    written.append(path)
                elif fmt == "mcap":
                    meta = {"run": str(i), **(metadata or {})}
                    written.append(write_mcap(path, cols, metadata=meta, start_time_s=run.started))
                    written.append(series_path(path))
                else:
                    raise ValueError(f"unknown log format {fmt!r}; expected csv or mcap")
        if self.events or written:
            events = self.folder / f"{self.stem}-events.json"
            atomic_write_text(events, json.dumps(self.events, indent=1, default=str) + "\n")
            written.append(events)
        return written


def mcap_available() -> bool:
    try:
        import mcap.writer  # noqa: F401
    except ImportError:
        return False
    return True
