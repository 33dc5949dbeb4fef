"""Figures (PNG) and an HTML report for a closed-loop run, laid out like the thesis's figures 5.2-5.4:
per state the truth, the measurements and the estimate; the bias estimates; the velocities; the
control forces and thruster commands; drop-out windows shaded.

matplotlib is an optional extra (``pip install 'rovlab[plot]'``) imported only here. The HTML
report embeds the PNGs as data URIs, so it is one self-contained file that works offline.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.angles import wrap

_DEG = 180.0 / math.pi


def _plt():
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("figures need matplotlib: pip install 'rovlab[plot]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shade(ax, windows: Sequence[tuple[float, float, str]]) -> None:
    for start, end, label in windows:
        ax.axvspan(start, end, color="0.85", zorder=0, label=f"{label} lost" if label else None)


def _col(columns: Mapping[str, np.ndarray], name: str) -> np.ndarray | None:
    return np.asarray(columns[name], dtype=float) if name in columns else None


def _has(columns: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """A column known to be there (float)."""
    return np.asarray(columns[name], dtype=float)


def write_figures(out_dir: str | Path, columns: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> list[Path]:
    """Write the run's figures into out_dir; returns their paths."""
    plt = _plt()
    out = Path(out_dir)
    t = np.asarray(columns["time_s"], dtype=float)
    windows = [(d["start_s"], d["end_s"], d["sensor"]) for d in meta.get("dropouts", [])]
    title = meta.get("title", "")
    paths = []

    # 1. states: truth, measurements, estimate (+-2 sigma)
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    specs = [("z", "depth z [m]", 1.0), ("psi", "heading psi [deg]", _DEG), ("w", "heave velocity w [m/s]", 1.0),
             ("r", "yaw rate r [deg/s]", _DEG)]
    offsets = meta.get("measurement_offsets", {})
    for ax, (s, label, k) in zip(axes.ravel(), specs):
        _shade(ax, windows)
        lines = []
        true = _col(columns, f"true_{s}")
        if true is not None:
            ax.plot(t, true * k, color="k", lw=1.2, label="truth")
            lines.append(true * k)
        for name in columns:
            if name.startswith(f"meas_{s}_"):
                m = _has(columns, name)
                off = float(offsets.get(name, 0.0))
                ok = np.isfinite(m)
                sensor = name[len(f"meas_{s}_"):]
                note = " moved to VO" if off else ""
                ax.plot(t[ok], (m[ok] - off) * k, ".", ms=2, alpha=0.5, label=f"measured ({sensor}{note})")
        est = _col(columns, f"est_{s}")
        var = _col(columns, f"var_{s}")
        if est is not None:
            ax.plot(t, est * k, color="tab:red", lw=1.0, label="estimate")
            lines.append(est * k)
            if var is not None:
                sd = 2 * np.sqrt(np.maximum(var, 0))
                ax.fill_between(t, (est - sd) * k, (est + sd) * k, color="tab:red", alpha=0.15, lw=0,
                                label="estimate +-2 sigma")
        ref = _col(columns, f"ref_{s}")
        if ref is not None:
            ax.plot(t, ref * k, "--", color="tab:green", lw=1.0, label="reference")
            lines.append(ref * k)
        _limit_to(ax, lines)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"{title}: states".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "states.png", plt))

    # 2. estimation errors with the filter's own +-2 sigma
    fig, axes = plt.subplots(2, 2, figsize=(12, 6), sharex=True)
    for ax, (s, label, k) in zip(axes.ravel(), specs):
        _shade(ax, windows)
        true, est, var = _col(columns, f"true_{s}"), _col(columns, f"est_{s}"), _col(columns, f"var_{s}")
        if true is None or est is None:
            ax.set_visible(False)
            continue
        err = est - true
        if s == "psi":
            err = wrap(err)
        ax.plot(t, err * k, color="tab:red", lw=1.0, label="estimate - truth")
        if var is not None:
            sd = 2 * np.sqrt(np.maximum(var, 0)) * k
            ax.plot(t, sd, color="0.4", lw=0.8, ls="--", label="+-2 sigma (filter)")
            ax.plot(t, -sd, color="0.4", lw=0.8, ls="--")
            big = np.max(np.abs(err * k)[np.isfinite(err)]) if np.isfinite(err).any() else 1.0
            _limit_to(ax, [err * k, np.clip(sd, 0, 3 * big), -np.clip(sd, 0, 3 * big)])
        ax.set_ylabel(f"error in {label}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"{title}: estimation error".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "errors.png", plt))

    # 3. biases
    bias_specs = [("b_w", "heave bias b_w [N]"), ("b_r", "yaw bias b_r [N m]")]
    if _col(columns, "est_b_w") is None and _col(columns, "est_b_X") is not None:  # a 4-DOF estimate
        bias_specs = [("b_X", "surge bias b_X [N]"), ("b_Y", "sway bias b_Y [N]"), ("b_Z", "heave bias b_Z [N]"),
                      ("b_N", "yaw bias b_N [N m]")]
    fig, axes = plt.subplots(1, len(bias_specs), figsize=(12, 3.5), sharex=True)
    for ax, (s, label) in zip(axes, bias_specs):
        _shade(ax, windows)
        true = _col(columns, f"true_{s}")
        if true is not None:
            ax.plot(t, true, color="k", lw=1.2, label="truth")
        est, var = _col(columns, f"est_{s}"), _col(columns, f"var_{s}")
        if est is not None:
            ax.plot(t, est, color="tab:red", lw=1.0, label="estimate")
            if var is not None:
                sd = 2 * np.sqrt(np.maximum(var, 0))
                ax.fill_between(t, est - sd, est + sd, color="tab:red", alpha=0.15, lw=0,
                                label="estimate +-2 sigma")
        ax.set_ylabel(label)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{title}: bias estimates".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "biases.png", plt))

    # 4. control forces (one axis per unit) and thruster commands
    wrench = [(s, unit) for s, unit in (("X", "N"), ("Y", "N"), ("Z", "N"), ("N", "N m"))
              if _col(columns, f"tau_{s}") is not None]
    fig, axes = plt.subplots(len(wrench) + 1, 1, figsize=(12, 2.4 * (len(wrench) + 1) + 0.6), sharex=True)
    axes = np.atleast_1d(axes)
    for ax, (s, unit) in zip(axes, wrench):
        _shade(ax, windows)
        ax.plot(t, _col(columns, f"tau_{s}"), lw=1.0, label=f"tau_{s} achieved")
        demanded = _col(columns, f"tau_{s}_demanded")
        if demanded is not None and not np.allclose(demanded, _has(columns, f"tau_{s}"), equal_nan=True):
            ax.plot(t, demanded, lw=0.8, ls="--", label=f"tau_{s} demanded (saturated)")
        ax.set_ylabel(f"tau_{s} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    ax = axes[-1]
    _shade(ax, windows)
    # PWM commands as points (a thruster that crosses the ESC's dead band often would be a solid
    # block as a line); the band is shaded, and each thruster's legend says how often it changed
    # sides of the band per second: the chatter a design's pwm_hysteresis_us holds down (a square
    # wave into a real ESC; docs/simulation.md, "PWM across the dead band")
    ax.axhspan(1500 - 25, 1500 + 25, color="tab:olive", alpha=0.15, lw=0, label="dead band (no thrust)")
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    for name in columns:
        if name.startswith("pwm_"):
            pwm = np.asarray(_col(columns, name), dtype=float)
            side = np.sign(pwm[np.isfinite(pwm) & (np.abs(pwm - 1500.0) >= 24.5)] - 1500.0)  # at or beyond the band
            flips = int(np.count_nonzero(np.diff(side))) if side.size > 1 else 0
            rate = f", {flips / span:.2f} side changes/s" if span > 0 else ""
            ax.plot(t, pwm, ".", ms=2.0, label=f"{name[4:]}{rate}")
    ax.set_ylabel("thruster command [us]")
    ax.set_xlabel("time [s]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="upper right", markerscale=3)
    fig.suptitle(f"{title}: control".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "control.png", plt))
    if _col(columns, "est_x") is not None and _col(columns, "est_y") is not None:
        paths.extend(_planar_figures(out, columns, t, windows, title, plt))
    return paths


def _planar_figures(out: Path, columns: Mapping[str, np.ndarray], t: np.ndarray,
                    windows: Sequence[tuple[float, float, str]], title: str, plt) -> list[Path]:
    """A 4-DOF estimate (dynamic positioning): the xy track with the reference, and the planar
    states x, y, u, v with the filter's +-2 sigma."""
    paths = []
    fig, ax = plt.subplots(figsize=(7, 7))
    # NED seen from above: east to the right, north up
    true_x, true_y = _col(columns, "true_x"), _col(columns, "true_y")
    if true_x is not None and true_y is not None:
        ax.plot(true_y, true_x, color="k", lw=1.2, label="truth")
    ax.plot(_has(columns, "est_y"), _has(columns, "est_x"), color="tab:red", lw=0.8, label="estimate")
    if _col(columns, "ctrl_x_d") is not None and _col(columns, "ctrl_y_d") is not None:
        ax.plot(_has(columns, "ctrl_y_d"), _has(columns, "ctrl_x_d"), color="tab:blue", lw=1.0, ls=":",
                label="reference model")
    if _col(columns, "ref_x") is not None and _col(columns, "ref_y") is not None:
        ax.plot(_has(columns, "ref_y"), _has(columns, "ref_x"), "s--", color="tab:green", lw=0.8, ms=5,
                label="set-points")
    for start, end, sensor in windows:
        w = (t >= start) & (t < end)
        if w.any() and true_x is not None and true_y is not None:
            ax.plot(true_y[w], true_x[w], color="tab:orange", lw=2.0, alpha=0.6, label=f"{sensor} lost")
    ax.set_xlabel("east y [m]")
    ax.set_ylabel("north x [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}: xy track".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "track.png", plt))

    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    specs = [("x", "north x [m]"), ("y", "east y [m]"), ("u", "surge velocity u [m/s]"), ("v", "sway velocity v [m/s]")]
    for ax, (s, label) in zip(axes.ravel(), specs):
        _shade(ax, windows)
        lines = []
        true = _col(columns, f"true_{s}")
        if true is not None:
            ax.plot(t, true, color="k", lw=1.2, label="truth")
            lines.append(true)
        est, var = _col(columns, f"est_{s}"), _col(columns, f"var_{s}")
        if est is not None:
            ax.plot(t, est, color="tab:red", lw=1.0, label="estimate")
            lines.append(est)
            if var is not None:
                sd = 2 * np.sqrt(np.maximum(var, 0))
                ax.fill_between(t, est - sd, est + sd, color="tab:red", alpha=0.15, lw=0, label="estimate +-2 sigma")
        ref = _col(columns, f"ctrl_{s}_d")
        if ref is not None:
            ax.plot(t, ref, ":", color="tab:blue", lw=1.0, label="reference model")
            lines.append(ref)
        _limit_to(ax, lines)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"{title}: planar states".strip(": "))
    fig.tight_layout()
    paths.append(_save(fig, out / "planar.png", plt))
    return paths


def _limit_to(ax, lines: Sequence[np.ndarray], margin: float = 0.15) -> None:
    """Scale the y axis to the lines (truth, estimate, reference), not to a covariance band that
    can grow by orders of magnitude while dead reckoning (the band is then clipped)."""
    vals = np.concatenate([np.asarray(v, dtype=float).ravel() for v in lines]) if lines else np.array([])
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return
    lo, hi = float(vals.min()), float(vals.max())
    pad = margin * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.1
    ax.set_ylim(lo - pad, hi + pad)


def write_nees_figure(path: str | Path, t: np.ndarray, nees_runs: np.ndarray, bounds: Sequence[float],
                      dof: int, title: str = "", *, note: str | None = None) -> Path:
    """Average NEES over Monte Carlo runs against its chi-square bounds; ``note`` under the plot
    (e.g. that the plant is not the filter's model, so the band is not expected to hold)."""
    import textwrap

    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 3.5 + (0.6 if note else 0.0)))
    runs = np.asarray(nees_runs, dtype=float)
    ok = np.isfinite(runs)
    count = ok.sum(axis=0)
    mean = np.where(count > 0, np.where(ok, runs, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan)
    lo, hi = float(bounds[0]), float(bounds[1])
    ax.axhspan(lo, hi, color="tab:green", alpha=0.15, lw=0, label="95 % chi-square band of the average")
    ax.plot(t, mean, lw=1.0, label=f"average NEES over {nees_runs.shape[0]} runs")
    ax.axhline(dof, color="k", lw=0.8, label=f"expected ({dof})")
    finite = mean[np.isfinite(mean)]
    top = max(2.0 * hi, float(np.percentile(finite, 99)) * 1.1 if finite.size else 0.0)
    ax.set_ylim(0.0, top)  # linear: the band is what matters; start-up outliers may leave the top
    ax.set_xlabel("time [s]")
    ax.set_ylabel("NEES")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(title)
    if note:
        fig.text(0.01, 0.01, "Note: " + "\n".join(textwrap.wrap(note, 150)), fontsize=7, va="bottom")
        fig.tight_layout(rect=(0.0, 0.12, 1.0, 1.0))
    else:
        fig.tight_layout()
    return _save(fig, Path(path), plt)


def _save(fig, path: Path, plt) -> Path:
    from rovlab.core.files import write_figure

    try:
        write_figure(fig, path, dpi=110)  # atomic: a full disk leaves no partial figure
    finally:
        plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------
# HTML
# --------------------------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em;max-width:1300px;color:#222}
h1{font-size:1.5em} h2{font-size:1.2em;margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:1em 0;font-size:.9em} td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
img{max-width:100%;border:1px solid #eee;margin:.5em 0} .muted{color:#666;font-size:.9em}
pre{background:#f7f7f7;padding:1em;overflow:auto;font-size:.8em}
"""


def _img(path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return f'<img alt="{html.escape(path.stem)}" src="data:image/png;base64,{data}">'


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            return "–"
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def comparison_rows(comparison: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(label, value) rows of a controller comparison (rovlab.sim.compare): per controller, the
    depth error against the reference model and what it cost."""
    rows: list[tuple[str, str]] = []
    for ctl in comparison.get("controllers", []):
        e = comparison.get(ctl, {})
        for key, label, k in (("depth_error_rms", "RMS depth error vs reference model [cm]", 100.0),
                              ("depth_error_peak", "peak depth error [cm]", 100.0),
                              ("settling_time_s", "settling time to 1 cm [s]", 1.0),
                              ("last10s_rms", "last-10 s RMS depth error [cm]", 100.0),
                              ("effort_rms", "RMS heave force [N]", 1.0),
                              ("saturation_s", "time saturated [s]", 1.0)):
            v = e.get(key)
            rows.append((f"{ctl}: {label}", _fmt(None if v is None else v * k, 3)))
        if "parameter_bounds_held" in e:
            rows.append((f"{ctl}: adapted parameters within bounds", _fmt(bool(e["parameter_bounds_held"]))))
        rows.append((f"{ctl}: diverged runs", _fmt(e.get("diverged"))))
    return rows


def summary_rows(metrics: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(label, value) rows of the headline numbers of one run's metrics (or of a comparison): what
    fits the run (metrics ``task``): the step response where the set-points change, the error
    against the controller's reference and the largest excursion where it holds station."""
    if "controllers" in metrics:
        return comparison_rows(metrics)
    rows: list[tuple[str, str]] = []
    rms = metrics.get("rms_error", {})
    for s, unit, k in (("x", "m", 1.0), ("y", "m", 1.0), ("z", "m", 1.0), ("psi", "deg", _DEG), ("u", "m/s", 1.0),
                       ("v", "m/s", 1.0), ("w", "m/s", 1.0), ("r", "deg/s", _DEG)):
        if s in rms:
            rows.append((f"RMS estimation error (estimate - truth) {s} [{unit}]", _fmt(rms[s] * k)))
    for axis in ("z", "psi"):  # only the axes that had a set-point step
        if axis in metrics.get("settling_time_s", {}):
            rows.append((f"settling time {axis} [s] (2 %)", _fmt(metrics["settling_time_s"][axis])))
    for axis in ("z", "psi"):
        if axis in metrics.get("overshoot", {}):
            rows.append((f"overshoot {axis} [%]", _fmt(100 * metrics["overshoot"][axis], 3)))
    tracking, largest = metrics.get("tracking_rms") or {}, metrics.get("tracking_max") or {}
    holding = metrics.get("task") == "station keeping"
    what = "station keeping" if holding else "tracking"
    for a, unit, k in (("x", "m", 1.0), ("y", "m", 1.0), ("z", "m", 1.0), ("psi", "deg", _DEG)):
        if a in tracking:
            rows.append((f"{what}: RMS error {a} (truth - controller's reference) [{unit}]", _fmt(tracking[a] * k)))
    if holding:
        if metrics.get("tracking_horizontal_max_m") is not None:
            rows.append(("station keeping: largest horizontal excursion [m]", _fmt(metrics["tracking_horizontal_max_m"])))
        for a, label, unit, k in (("z", "depth", "m", 1.0), ("psi", "heading", "deg", _DEG)):
            if a in largest:
                rows.append((f"station keeping: largest {label} excursion [{unit}]", _fmt(largest[a] * k)))
    if tracking and "saturation" in metrics:
        rows.append(("thrusters saturated [s]", _fmt(metrics["saturation"].get("time_s"))))
    for d in metrics.get("dropouts", []):
        rows.append((f"heading drift during {d['sensor']} drop-out [deg]", _fmt(d["heading_drift_rad"] * _DEG)))
        rows.append(("max heading error during drop-out [deg]", _fmt(d["heading_error_max_rad"] * _DEG)))
        rows.append(("depth estimation error RMS during / before drop-out [m]",
                     f"{_fmt(d['depth_error_rms_during'])} / {_fmt(d['depth_error_rms_before'])}"))
    nees = metrics.get("nees")
    if nees:
        rows.append((f"average NEES ({nees['dof']} states; expected {nees['dof']})",
                     f"{_fmt(nees['mean'])} (95 % bounds {_fmt(nees['mean_bounds'][0])}–{_fmt(nees['mean_bounds'][1])})"))
    nis = metrics.get("nis")
    if nis:
        rows.append(("average NIS per measurement (expected 1)", _fmt(nis["mean"])))
    if metrics.get("consistency_note") and (nees or nis):
        rows.append(("note on NEES/NIS", html.escape(str(metrics["consistency_note"]))))
    return rows


def write_report_html(path: str | Path, title: str, sections: Sequence[Mapping[str, Any]],
                      intro: str = "") -> Path:
    """One self-contained page. Each section: title, description, metrics, figures (paths), extra."""
    parts = [f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"]
    if intro:
        parts.append(f"<p>{html.escape(intro)}</p>")
    if len(sections) > 1:
        # in order of first appearance: the first section's rows, then what later ones add
        labels = list(dict.fromkeys(lbl for s in sections for lbl, _ in summary_rows(s["metrics"])))
        table = {s["title"]: dict(summary_rows(s["metrics"])) for s in sections}
        parts.append("<h2>Summary</h2><table><tr><th></th>" + "".join(f"<th>{html.escape(s['title'])}</th>"
                                                                       for s in sections) + "</tr>")
        for lbl in labels:
            parts.append(f"<tr><td>{html.escape(lbl)}</td>" + "".join(
                f"<td>{table[s['title']].get(lbl, '–')}</td>" for s in sections) + "</tr>")
        parts.append("</table>")
    for s in sections:
        parts.append(f"<h2 id='{html.escape(s['title'])}'>{html.escape(s['title'])}</h2>")
        if s.get("description"):
            parts.append(f"<p>{html.escape(s['description'])}</p>")
        parts.append("<table><tr><th>metric</th><th>value</th></tr>" + "".join(
            f"<tr><td>{html.escape(lbl)}</td><td>{val}</td></tr>" for lbl, val in summary_rows(s["metrics"]))
            + "</table>")
        if s.get("extra"):
            parts.append(f"<p class='muted'>{html.escape(s['extra'])}</p>")
        if s.get("text"):
            parts.append("<pre>" + html.escape(s["text"]) + "</pre>")
        for fig in s.get("figures", []):
            parts.append(_img(Path(fig)))
        parts.append("<details><summary>all metrics (metrics.json)</summary><pre>"
                     + html.escape(json.dumps(s["metrics"], indent=2)) + "</pre></details>")
    parts.append("</body></html>")
    path = Path(path)
    path.write_text("".join(parts), encoding="utf-8")
    return path
