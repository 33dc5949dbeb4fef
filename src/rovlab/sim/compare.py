"""Controllers compared on one scenario, from the same seeds (issue 12: MRAC against LQG).

For each seed the scenario is drawn once (rovlab.sim.scenario: distributions and noise come
from the seed alone) and run once per controller, so every controller meets exactly the same
plant, noise, sensors and disturbances. Judged on the **true** depth against the **reference
model** z_m of the configuration's [mrac] table (second order, omega_m, zeta_m, started at the
true initial depth, at rest), the same yardstick for every controller, adaptive or not:

``depth_error_rms`` / ``depth_error_peak``
    RMS / largest |z - z_m| from the change (the first truth event; without one, ``t_change``
    below) to the end [m].
``settling_time_s``
    time after the change until |z - z_m| stays within ``band`` (1 cm) to the end (None: never).
``last10s_rms``
    RMS of z - z_m over the last 10 s [m].
``effort_rms``
    RMS of the achieved heave force from the change to the end [N].
``saturation_s``
    time during which the allocation could not give the demanded heave force or yaw moment
    (more than 1 mN / 1 mN m short) [s].
``parameter_bounds_held``
    adaptive controllers: every adapted parameter stayed within its projection bounds.
``diverged``
    a non-finite value or |z - z_m| above 1 m.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from rovlab.control.mrac import PARAMETERS, reference_model
from rovlab.models.discretise import zoh
from rovlab.sim.designs import DesignBook
from rovlab.sim.prepare import prepare
from rovlab.sim.results import SimResult
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import Scenario, scenario_from_dict

BAND_M = 0.01
LAST_S = 10.0
DIVERGED_M = 1.0
METRICS = ("depth_error_rms", "depth_error_peak", "settling_time_s", "last10s_rms", "effort_rms", "saturation_s")


def reference_model_response(sc: Scenario, times: np.ndarray, omega: float, zeta: float) -> np.ndarray:
    """z_m at the given (equally spaced) times for the scenario's depth schedule, exact with the
    set-point held between samples, from the true initial depth at rest."""
    h = float(times[1] - times[0]) if len(times) > 1 else 0.1
    A, B = reference_model(omega, zeta)
    Phi, G = zoh(A, B, h)
    idx = np.maximum(np.searchsorted(sc.reference_times, times, side="right") - 1, 0)
    r = sc.reference_z[idx]
    x = np.array([sc.initial[2], 0.0])
    out = np.empty(len(times))
    for k in range(len(times)):
        out[k] = x[0]
        x = Phi @ x + G[:, 0] * r[k]
    return out


def change_time(sc: Scenario) -> float:
    """When the disturbance starts: the first truth event, else a quarter of the run (a tether
    pull acts from the start; the first quarter holds the initial depth step)."""
    return float(sc.events[0].t_s) if sc.events else 0.25 * sc.duration_s


def run_metrics(result: SimResult, zm: np.ndarray, t_change: float, bounds: tuple[np.ndarray, np.ndarray] | None
                ) -> dict[str, Any]:
    """The numbers of one run (module docstring)."""
    c = result.columns
    t = c["time_s"]
    h = float(t[1] - t[0])
    err = c["true_z"] - zm
    win = t >= t_change - 1e-9
    last = t >= t[-1] - LAST_S + 1e-9
    out: dict[str, Any] = {
        "depth_error_rms": _rms(err[win]), "depth_error_peak": float(np.max(np.abs(err[win]))),
        "settling_time_s": _settling(t[win], err[win], t_change), "last10s_rms": _rms(err[last]),
        "effort_rms": _rms(c["tau_Z"][win]),
    }
    short = np.zeros(len(t), dtype=bool)
    for o in ("Z", "N"):
        if f"tau_{o}" in c:
            short |= np.abs(c[f"tau_{o}_demanded"] - c[f"tau_{o}"]) > 1e-3
    out["saturation_s"] = float(short.sum() * h)
    finite = all(np.all(np.isfinite(v)) for k, v in c.items() if k.startswith(("true_", "tau_", "ctrl_")))
    out["diverged"] = bool(not finite or not np.all(np.abs(err) < DIVERGED_M))
    if bounds is not None:
        lo, hi = bounds
        held = True
        finals = {}
        for i, p in enumerate(PARAMETERS):
            col = c.get(f"ctrl_{_state_name(p)}")
            if col is None:
                continue
            tol = 1e-9 * max(1.0, abs(lo[i]), abs(hi[i]))
            held &= bool(np.all((col >= lo[i] - tol) & (col <= hi[i] + tol)))
            finals[p] = float(col[-1])
        out["parameter_bounds_held"] = held
        out["parameters_final"] = finals
    return out


def _state_name(p: str) -> str:
    return f"{p}_hat"


def _rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def _settling(t: np.ndarray, err: np.ndarray, t0: float) -> float | None:
    outside = np.nonzero(np.abs(err) > BAND_M)[0]
    if outside.size == 0:
        return 0.0
    if outside[-1] >= len(t) - 1:
        return None
    return float(t[outside[-1] + 1] - t0)


def compare(data: Mapping[str, Any], file: str, controllers: Sequence[str], seeds: Sequence[int], *,
            keep: int = 1, progress: Any = None) -> tuple[dict[str, Any], dict[str, list[SimResult]]]:
    """Run the scenario for every seed with every controller (same seeds, same draws).

    Returns (comparison, results): the comparison.json content, and the full results of the first
    ``keep`` seeds per controller (for figures)."""
    book = DesignBook()
    per: dict[str, list[dict[str, Any]]] = {c: [] for c in controllers}
    kept: dict[str, list[SimResult]] = {c: [] for c in controllers}
    first: Scenario | None = None
    refmodel: tuple[float, float] | None = None
    bounds_of: dict[str, Any] = {}
    done = 0
    for i, seed in enumerate(seeds):
        sc = scenario_from_dict(data, file=file, seed=seed)
        first = first or sc
        for ctl in controllers:
            prep = prepare(replace(sc, controller=ctl), book=book)
            if refmodel is None:
                mc = prep.config.table("mrac")
                refmodel = (mc.bandwidth, mc.damping)
            model = prep.design.controller.model
            bounds = (model.lo, model.hi) if hasattr(model, "lo") and hasattr(model, "hi") else None
            if bounds is not None and ctl not in bounds_of:
                bounds_of[ctl] = model
            res = run_prepared(prep)
            t = res.columns["time_s"]
            zm = reference_model_response(sc, t, *refmodel)
            m = run_metrics(res, zm, change_time(sc), bounds)
            m["seed"] = seed
            per[ctl].append(m)
            if i < keep:
                res.columns["refmodel_z"] = zm
                kept[ctl].append(res)
            done += 1
            if progress:
                progress(done, len(seeds) * len(controllers))
    assert first is not None and refmodel is not None
    out: dict[str, Any] = {
        "scenario": first.name, "description": first.description, "source": first.source,
        "controllers": list(controllers), "runs": len(seeds), "seeds": [int(s) for s in seeds],
        "reference_model": {"bandwidth_rad_s": refmodel[0], "damping": refmodel[1]},
        "change_s": change_time(first), "band_m": BAND_M, "last_s": LAST_S,
        "definitions": {
            "depth_error": "true depth - reference model output z_m (same reference model for every controller)",
            "depth_error_rms": "RMS of the depth error from change_s to the end [m]",
            "depth_error_peak": "largest |depth error| from change_s to the end [m]",
            "settling_time_s": "time after change_s until |depth error| stays within band_m (null: never) [s]",
            "last10s_rms": "RMS of the depth error over the last 10 s [m]",
            "effort_rms": "RMS of the achieved heave force from change_s to the end [N]",
            "saturation_s": "time the allocation fell short of the demanded Z or N [s]",
            "parameter_bounds_held": "every adapted parameter stayed within its projection bounds in every run",
            "values": "with several runs: the mean over runs; 'spread' gives p95 and max",
        },
    }
    for ctl in controllers:
        runs = per[ctl]
        entry: dict[str, Any] = {}
        spread: dict[str, Any] = {}
        for key in METRICS:
            vals = [r[key] for r in runs]
            fin = np.array([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
            if key == "settling_time_s" and len(fin) < len(vals):
                entry[key] = None  # some run never settled
                spread[key] = {"never_settled": len(vals) - len(fin),
                               **({"p95": float(np.percentile(fin, 95)), "max": float(fin.max())} if fin.size else {})}
                continue
            entry[key] = float(fin.mean()) if fin.size else None
            if fin.size:
                spread[key] = {"p95": float(np.percentile(fin, 95)), "max": float(fin.max()),
                               "min": float(fin.min())}
        entry["diverged"] = int(sum(r["diverged"] for r in runs))
        if ctl in bounds_of:
            model = bounds_of[ctl]
            entry["parameter_bounds_held"] = bool(all(r.get("parameter_bounds_held", False) for r in runs))
            entry["parameters"] = {
                p: {"initial": float(model.theta0[i]), "lower": float(model.lo[i]), "upper": float(model.hi[i]),
                    "final_mean": float(np.mean([r["parameters_final"][p] for r in runs]))}
                for i, p in enumerate(PARAMETERS)}
        entry["spread"] = spread
        entry["per_run"] = runs
        out[ctl] = entry
    return out, kept


def table(comparison: Mapping[str, Any]) -> str:
    """The comparison as a text table (one row per controller)."""
    ctls = comparison["controllers"]
    n = comparison["runs"]
    head = (f"{comparison['scenario']}: {n} run{'s' if n != 1 else ''} per controller, seeds "
            f"{comparison['seeds'][0]}..{comparison['seeds'][-1]}; error = true depth - reference model "
            f"(omega {comparison['reference_model']['bandwidth_rad_s']:g} rad/s, zeta "
            f"{comparison['reference_model']['damping']:g}); change at {comparison['change_s']:g} s"
            + ("; values are means over runs (max in brackets)" if n > 1 else ""))
    cols = [("RMS err [cm]", "depth_error_rms", 100.0), ("peak [cm]", "depth_error_peak", 100.0),
            ("settle [s]", "settling_time_s", 1.0), ("last 10 s [cm]", "last10s_rms", 100.0),
            ("effort [N]", "effort_rms", 1.0), ("saturated [s]", "saturation_s", 1.0)]
    header = f"{'controller':10s} " + " ".join(f"{c[0]:>16s}" for c in cols) + f" {'bounds':>7s} {'diverged':>8s}"
    lines = [head, header]
    for ctl in ctls:
        e = comparison[ctl]
        cells = []
        for _, key, k in cols:
            v = e.get(key)
            mx = e["spread"].get(key, {}).get("max")
            text = "-" if v is None else f"{v * k:.3g}"
            if n > 1 and mx is not None:
                text += f" ({mx * k:.3g})"
            if key == "settling_time_s" and e["spread"].get(key, {}).get("never_settled"):
                text += f" [{e['spread'][key]['never_settled']} never]"
            cells.append(f"{text:>16s}")
        held = e.get("parameter_bounds_held")
        lines.append(f"{ctl:10s} " + " ".join(cells) + f" {('-' if held is None else 'held' if held else 'LEFT'):>7s} "
                     f"{e['diverged']:>8d}")
    lines.append("('-': not applicable or never settled to 1 cm; bounds: adapted parameters within their "
                 "projection set)")
    return "\n".join(lines)


def figure(path: Any, comparison: Mapping[str, Any], kept: Mapping[str, list[SimResult]]) -> Any:
    """Overlay of the first seed's runs: depth, error against the reference model, heave force,
    and the adapted net force against the true one (matplotlib, imported here only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    colours = {"lqg": "tab:blue", "mrac": "tab:red"}
    drawn_ref = False
    for ctl, results in kept.items():
        if not results:
            continue
        c = results[0].columns
        t = c["time_s"]
        col = colours.get(ctl)
        if not drawn_ref:
            ax[0].plot(t, c["ref_z"], "k:", lw=1, label="set-point")
            ax[0].plot(t, c["refmodel_z"], "k--", lw=1, label="reference model")
            if "true_b_w" in c:
                ax[3].plot(t, c["true_b_w"], "k--", lw=1, label="true net down force (weight - buoyancy + bias + pull)")
            drawn_ref = True
        ax[0].plot(t, c["true_z"], color=col, lw=1.2, label=f"{ctl}: true depth")
        ax[1].plot(t, 100.0 * (c["true_z"] - c["refmodel_z"]), color=col, lw=1.0, label=ctl)
        ax[2].plot(t, c["tau_Z"], color=col, lw=1.0, label=ctl)
        if "ctrl_F_hat" in c:
            ax[3].plot(t, c["ctrl_F_hat"], color=col, lw=1.2, label=f"{ctl}: adapted F")
        elif "est_b_w" in c:
            ax[3].plot(t, c["est_b_w"], color=col, lw=1.0, label=f"{ctl}: bias estimate b_w")
    t0 = comparison["change_s"]
    for a in ax:
        a.axvline(t0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
        a.legend(fontsize=7, loc="best")
    ax[0].invert_yaxis()
    ax[0].set_ylabel("depth z [m] (down)")
    ax[1].set_ylabel("z - z_m [cm]")
    ax[1].axhspan(-100 * BAND_M, 100 * BAND_M, color="0.9")
    ax[2].set_ylabel("heave force Z [N]")
    ax[3].set_ylabel("net down force [N]")
    ax[3].set_xlabel("time [s]")
    ax[0].set_title(f"{comparison['scenario']} (seed {comparison['seeds'][0]}): " + " vs ".join(kept))
    fig.tight_layout()
    from rovlab.core.files import write_figure

    try:
        write_figure(fig, path, dpi=110)  # atomic: a full disk leaves no partial figure
    finally:
        plt.close(fig)
    return path
