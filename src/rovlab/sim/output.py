"""Writing a run's results into a folder: timeseries.csv, timeseries.mcap (a ROS 2 bag) and
timeseries.rovlab.mcap (rovlab's series), metrics.json, the PNG
figures and report.html. Whatever was computed is written even if a later step fails (a missing
optional extra such as matplotlib only skips the figures, with a note)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.io.logwriter import write_csv
from rovlab.io.messages import order_columns
from rovlab.io.report import write_figures, write_nees_figure, write_report_html
from rovlab.io.timeseries import series_path, write_mcap
from rovlab.sim.metrics import with_units
from rovlab.sim.results import SimResult


def ordered_columns(result: SimResult) -> dict[str, np.ndarray]:
    """timeseries.csv's columns in the order every rovlab log uses (rovlab.io.messages)."""
    return order_columns(result.columns)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def _clean(o: Any) -> Any:
    """NaN/inf -> None so that metrics.json is strict JSON."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    return o


def write_json(path: Path, data: Mapping[str, Any]) -> Path:
    """``data`` as JSON, atomically (a full disk leaves no partial file, and an earlier one as it was)."""
    from rovlab.core.files import atomic_write_text

    atomic_write_text(path, json.dumps(_clean(json.loads(json.dumps(data, default=_json_default))), indent=2) + "\n")
    return path


def write_run(out_dir: str | Path, result: SimResult, metrics: Mapping[str, Any], *, figures: bool = True,
              mcap: bool = True, report: bool = True, notes: list[str] | None = None) -> dict[str, Path]:
    """Write one run's files; returns name -> path of what was written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    notes = notes if notes is not None else []
    cols = ordered_columns(result)
    words = result.status_words()  # sensor status as the words `rovlab filter` writes
    write_csv(out / "timeseries.csv", {k: words.get(k, v) for k, v in cols.items()}, exact=("time_s",))
    written["timeseries.csv"] = out / "timeseries.csv"
    written["metrics.json"] = write_json(out / "metrics.json", with_units(metrics))
    if mcap:
        try:
            written["timeseries.mcap"] = write_mcap(out / "timeseries.mcap", cols, metadata={
                "scenario": result.scenario.name, "seed": str(result.scenario.seed)},
                start_time_s=result.meta.get("start_time_unix_s"))
            written["timeseries.rovlab.mcap"] = series_path(out / "timeseries.mcap")
        except RuntimeError as exc:
            notes.append(str(exc))
    figs: list[Path] = []
    if figures:
        try:
            figs = write_figures(out, cols, result.meta)
            for f in figs:
                written[f.name] = f
        except RuntimeError as exc:
            notes.append(str(exc))
    if report:
        written["report.html"] = write_report_html(out / "report.html", f"rovlab: {result.scenario.name}", [
            {"title": result.scenario.name, "description": result.scenario.description + " — " + result.scenario.source,
             "metrics": metrics, "figures": figs,
             "extra": f"seed {result.scenario.seed}; plant: {result.scenario.plant}; vehicle {result.meta['vehicle']}; "
                      f"filter/controller configuration {result.meta['design']}"}])
    return written


def write_monte_carlo(out_dir: str | Path, scenario_name: str, summary: Mapping[str, Any],
                      runs: Sequence[Mapping[str, Any]], t: np.ndarray, description: str = "",
                      notes: list[str] | None = None, *, figures: bool = True) -> dict[str, Path]:
    """monte_carlo/metrics.json, and with ``figures`` the NEES over the runs (nees.png)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = {"metrics.json": write_json(out / "metrics.json", with_units({"monte_carlo": summary}))}
    notes = notes if notes is not None else []
    figs = []
    if not figures:
        return written
    try:
        nees = np.array([r["nees"] for r in runs], dtype=float)
        if "nees" in summary:
            dof = summary["nees"]["dof"]
            asked = int(summary.get("runs_requested", len(runs)))
            count = f"{len(runs)} runs" if asked == len(runs) else f"the {len(runs)} finished of {asked} runs (interrupted)"
            figs.append(write_nees_figure(out / "nees.png", t, nees, summary["nees"]["bounds_per_step"], dof,
                                          f"{scenario_name}: filter consistency over {count}",
                                          note=summary.get("consistency_note")))
    except RuntimeError as exc:
        notes.append(str(exc))
    written.update({f.name: f for f in figs})
    return written
