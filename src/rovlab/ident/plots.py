"""PNG figures of every identification: data, fit, residuals, with units on every axis.

matplotlib is an optional extra (``pip install 'rovlab[plot]'``) and is imported inside the
functions only; figures are drawn on the Agg canvas directly (no pyplot, no global backend
switch), so plotting works headless and never disturbs an interactive session.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


class PlotUnavailable(ImportError):
    """matplotlib is not installed."""


INSTALL_HINT = "plots need matplotlib: pip install 'rovlab[plot]' (or pip install matplotlib)"


def _figure(rows: int, cols: int = 1, *, height: float = 2.6, width: float = 8.0, **kw: Any):
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise PlotUnavailable(INSTALL_HINT) from exc
    fig = Figure(figsize=(width, height * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axes


FORMATS = (".png", ".svg", ".pdf")


def _save(fig: Any, path: str | Path) -> Path:
    """Write exactly ``path`` in the format its suffix names (.png, .svg or .pdf), atomically
    (rovlab.core.files): a full disk leaves no empty or partial figure and an earlier one as it was."""
    from rovlab.core.files import write_figure

    path = Path(path)
    if path.suffix.lower() not in FORMATS:
        raise ValueError(f"a figure file must end in {', '.join(FORMATS)}; got {str(path)!r}")
    return write_figure(fig, path, dpi=110)


def _pm(x: float, se: float) -> str:
    return f"{x:.4g} ± {se:.2g}" if np.isfinite(se) and se > 0 else f"{x:.4g}"


# --------------------------------------------------------------------------------------------

def plot_thrust(fit, path: str | Path, *, title: str = "") -> Path:
    """Staircase log (if any), thrust points with the fitted curve, residuals."""
    rows = 3 if fit.steps is not None else 2
    fig, ax = _figure(rows, height=2.8)
    k = 0
    if fit.steps is not None:
        s = fit.steps
        a = ax[0, 0]
        a.plot(s.time_s, s.force_raw_n, color="0.75", lw=0.5, label="load cell" + (f" / {s.pair}" if s.pair > 1 else ""))
        a.plot(s.time_s, s.force_filtered_n, color="C0", lw=1.0, label=f"Butterworth {s.cutoff_hz:g} Hz, zero phase")
        for t1, f in zip(s.end_s, s.force_n):
            a.plot([t1 - s.window_s, t1], [f, f], color="C3", lw=2.0)
        a.plot([], [], color="C3", lw=2.0, label=f"mean of last {s.window_s:g} s")
        a.set_xlabel("time [s]")
        a.set_ylabel("thrust [N]")
        b = a.twinx()
        b.plot(s.time_s, s.pwm_trace_us, color="C2", lw=0.8, alpha=0.6)
        b.set_ylabel("PWM set-point [µs]", color="C2")
        a.legend(loc="upper left", fontsize=8)
        a.set_title(title or "Thrust staircase")
        k = 1
    a = ax[k, 0]
    grid = np.linspace(min(fit.pwm_us.min(), fit.neutral_us - fit.deadband_us - 1),
                       max(fit.pwm_us.max(), fit.neutral_us + fit.deadband_us + 1), 800)
    a.axvspan(fit.neutral_us - fit.deadband_us, fit.neutral_us + fit.deadband_us, color="0.9",
              label=f"dead band ±{fit.deadband_us:.3g} µs" + (" (fitted)" if fit.deadband_fitted else ""))
    a.plot(fit.pwm_us, fit.force_n, "o", ms=3.5, color="C0", label="steady thrust" if fit.steps else "table points")
    a.plot(grid, fit.force(grid), color="C3", lw=1.5, label="fit f = K_L s + K_NL s|s|")
    se = fit.stderr
    text = (f"forward: K_L = {_pm(fit.K_L_pos, se['K_L_pos'])} N/µs, K_NL = {_pm(fit.K_NL_pos, se['K_NL_pos'])} N/µs²\n"
            f"reverse: K_L = {_pm(fit.K_L_neg, se['K_L_neg'])} N/µs, K_NL = {_pm(fit.K_NL_neg, se['K_NL_neg'])} N/µs²\n"
            f"RMS residual {fit.rms_n:.3g} N over {fit.pwm_us.size} points")
    a.text(0.01, 0.98, text, transform=a.transAxes, va="top", fontsize=8, family="monospace",
           bbox=dict(facecolor="white", alpha=0.8, edgecolor="0.8"))
    a.set_xlabel("PWM [µs]")
    a.set_ylabel("thrust [N]")
    a.legend(loc="lower right", fontsize=8)
    if k == 0:
        a.set_title(title or "Thrust curve fit")
    r = ax[k + 1, 0]
    r.axhline(0, color="0.5", lw=0.8)
    r.plot(fit.pwm_us, fit.residual_n, "o", ms=3.5, color="C0")
    r.set_xlabel("PWM [µs]")
    r.set_ylabel("residual [N]")
    r.set_title("residuals (measured − fitted)", fontsize=9)
    return _save(fig, path)


def plot_damping(fit, path: str | Path, *, title: str = "") -> Path:
    """Runs with their steady windows, damping points with the fitted curve, residuals."""
    fig, ax = _figure(3, height=2.8)
    yaw = fit.dof == "yaw"
    a = ax[0, 0]
    offset = 0.0
    for p in fit.points:
        s = p.series
        if s is None:
            continue
        if yaw:
            rate = np.gradient(s.speed, s.time_s)
            a.plot(s.time_s + offset, rate, lw=0.6, color="0.6")
            m = (s.time_s >= p.start_s) & (s.time_s <= p.end_s)
            a.plot(s.time_s[m] + offset, np.full(m.sum(), p.speed), color="C3", lw=2)
        else:
            a.plot(s.time_s + offset, s.speed, lw=0.6, color="0.6")
            m = (s.time_s >= p.start_s) & (s.time_s <= p.end_s)
            a.plot(s.time_s[m] + offset, s.speed[m], color="C3", lw=1.5)
        offset += float(s.time_s[-1] - s.time_s[0]) + 2.0
    a.plot([], [], color="C3", lw=2, label="steady window (used)")
    a.set_xlabel("time, runs end to end [s]")
    a.set_ylabel("yaw rate [rad/s]" if yaw else f"{fit.dof or 'carriage'} speed [m/s]")
    a.legend(loc="best", fontsize=8)
    a.set_title(title or (f"{fit.dof} damping" if fit.dof else "damping"))

    b = ax[1, 0]
    v = fit.speed
    lim = max(float(np.max(np.abs(v))) * 1.1, 1e-6)
    grid = np.linspace(-lim if np.any(v < 0) else 0.0, lim, 400)
    if fit.rig_points:
        vr = np.array([p.speed for p in fit.rig_points])
        fr = np.array([p.force for p in fit.rig_points])
        b.plot(vr, fr, "s", ms=4, mfc="none", color="C2", label="rig only (measured)")
        b.plot(v, [p.force for p in fit.points], "^", ms=4, mfc="none", color="0.5", label="vehicle + rig (measured)")
    se = [p.force_stderr for p in fit.points]
    b.errorbar(v, -fit.damping, yerr=se, fmt="o", ms=4, color="C0",
               label="vehicle: applied moment = −D(r)" if yaw else "vehicle: applied force = −D(v)")
    b.plot(grid, -fit.damping_force(grid), color="C3", lw=1.5, label="fit")
    unit, vu = fit.unit, fit.speed_unit
    lines = [f"{t}: {_pm(getattr(fit, t), fit.stderr[t])}" for t in fit.terms]
    b.text(0.01, 0.98, "SNAME coefficients\n" + "\n".join(lines) + f"\nRMS residual {fit.rms:.3g} {unit}",
           transform=b.transAxes, va="top", fontsize=8, family="monospace",
           bbox=dict(facecolor="white", alpha=0.8, edgecolor="0.8"))
    b.set_xlabel(f"{'yaw rate' if yaw else 'speed'} [{vu}]")
    b.set_ylabel(f"{'moment' if yaw else 'force'} [{unit}]")
    b.legend(loc="lower right", fontsize=8)
    r = ax[2, 0]
    r.axhline(0, color="0.5", lw=0.8)
    r.plot(v, fit.residual, "o", ms=4, color="C0")
    r.set_xlabel(f"{'yaw rate' if yaw else 'speed'} [{vu}]")
    r.set_ylabel(f"residual [{unit}]")
    r.set_title("residuals of the damping (measured − fitted)", fontsize=9)
    return _save(fig, path)


def plot_step(fit, path: str | Path, *, title: str = "", position_unit: str = "m", force_unit: str = "N",
              position_label: str = "position", force_label: str = "force") -> Path:
    """Force, position (measured vs simulated model), velocity, residuals."""
    fig, ax = _figure(4, height=2.3, sharex=True)
    t = fit.time_s
    ax[0, 0].step(t, fit.force, where="post", color="C2")
    ax[0, 0].set_ylabel(f"{force_label} [{force_unit}]")
    ax[0, 0].set_title(title or "Step/relay response: output-error fit of k/(s + a)")
    a = ax[1, 0]
    a.plot(t, fit.position, ".", ms=2.5, color="C0", label="measured")
    a.plot(t, fit.position_fit, color="C3", lw=1.2, label="model (simulated)")
    se = fit.stderr
    a.set_title(f"k = {_pm(fit.gain, se['gain'])}, a = {_pm(fit.pole, se['pole'])} 1/s\n"
                f"added mass (SNAME) = {_pm(fit.added_mass, se['added_mass'])}, "
                f"linear damping = {_pm(fit.linear_damping, se['linear_damping'])}\n"
                f"fit {fit.fit_percent:.2f} %, RMS {fit.rms:.3g} {position_unit}"
                + (f", bias {_pm(fit.bias, se['bias'])} {force_unit}" if fit.bias_fitted else ""),
                fontsize=8, family="monospace", loc="left")
    a.set_ylabel(f"{position_label} [{position_unit}]")
    a.legend(loc="best", fontsize=8)
    v = ax[2, 0]
    v.plot(t, fit.velocity_smoothed, color="C0", lw=0.8, label="Savitzky-Golay derivative of measured")
    v.plot(t, fit.velocity_fit, color="C3", lw=1.2, label="model")
    v.set_ylabel(f"{'rate' if position_label == 'heading' else 'velocity'} [{position_unit}/s]")
    v.legend(loc="best", fontsize=8)
    r = ax[3, 0]
    r.axhline(0, color="0.5", lw=0.8)
    r.plot(t, fit.residual, color="C0", lw=0.8)
    r.set_ylabel(f"residual [{position_unit}]")
    r.set_xlabel("time [s]")
    return _save(fig, path)


def plot_noise(estimate, path: str | Path, *, title: str = "", units: dict[str, str] | None = None) -> Path:
    """Per channel: detrended residual with ±1 sigma, and the Allan deviation (or a histogram)."""
    from rovlab.core.units import squared

    names = list(estimate.channels)
    fig, ax = _figure(len(names), 2, height=1.9, width=10.0)
    units = units or {}
    for i, name in enumerate(names):
        c = estimate.channels[name]
        u = units.get(name, _guess_unit(name))
        a = ax[i, 0]
        a.plot(estimate.time_s, c.residual, lw=0.4, color="C0", label="residual (drift removed)")
        for k, s in enumerate((-c.std, c.std)):
            a.axhline(s, color="C3", lw=0.8, label="±1σ (sample std)" if k == 0 else None)
        a.legend(loc="lower right", fontsize=7)
        a.set_ylabel(f"{name}\n[{u}]", fontsize=8)
        u2 = squared(u) if u != "unit" else "unit²"  # rad/s: rad^2/s^2
        a.text(0.01, 0.95, f"σ² = {c.variance:.4g} {u2}  (95 % CI {c.ci95[0]:.3g}..{c.ci95[1]:.3g}); "
               f"drift removed {c.drift_per_s:.3g} {u}/s", transform=a.transAxes, va="top", fontsize=7,
               bbox=dict(facecolor="white", alpha=0.8, edgecolor="0.8"))
        if i == len(names) - 1:
            a.set_xlabel("time [s]")
        if i == 0:
            a.set_title(title or f"Resting log, drift (degree {estimate.detrend_degree}) removed; ±1σ in red",
                        fontsize=9)
        b = ax[i, 1]
        if c.allan_dev is not None and c.allan_dev.size:
            b.loglog(c.allan_tau_s, c.allan_dev, "o-", ms=3, color="C0", label="overlapping ADEV")
            b.loglog(c.allan_tau_s, c.std * np.sqrt(c.allan_tau_s[0] / c.allan_tau_s), "--", color="C3", lw=0.8,
                     label="white noise (slope −½)")
            b.set_ylabel(f"ADEV [{u}]", fontsize=8)
            if i == len(names) - 1:
                b.set_xlabel("averaging time τ [s]")
            if i == 0:
                b.legend(fontsize=7)
        else:
            b.hist(c.residual, bins=40, density=True, color="C0", alpha=0.6)
            x = np.linspace(c.residual.min(), c.residual.max(), 200)
            b.plot(x, np.exp(-0.5 * (x / c.std) ** 2) / (c.std * np.sqrt(2 * np.pi)), color="C3", lw=1)
            b.set_ylabel("density", fontsize=8)
            if i == len(names) - 1:
                b.set_xlabel(f"residual [{u}]")
    return _save(fig, path)


def _guess_unit(name: str) -> str:
    from rovlab.core.units import unit

    ch = name.split(".", 1)[1] if "." in name else name.split("_", 1)[0]
    return unit(ch, "unit")


def plot_added_mass(estimate, path: str | Path, *, title: str = "") -> Path:
    """The DNV-RP-H103 tables with their splines and the points this vehicle used."""
    from rovlab.ident.added_mass import _spline, dnv_tables

    t = dnv_tables()
    fig, ax = _figure(1, 3, height=3.6, width=12.0)
    panels = [
        (t.rect_a_over_b, t.rect_CA, "table A-1 rectangle: C_A", "a/b",
         [("W/L (surge strip)", estimate.ratios["rect_W_over_L"]), ("L/W (sway, heave)", estimate.ratios["rect_L_over_W"])]),
        (t.rect_a_over_b, t.rect_beta, "table A-1 rectangle: β (yaw)", "a/b",
         [("W/L (yaw)", estimate.ratios["rect_W_over_L"])]),
        (t.prism_b_over_a, t.prism_CA, "table A-2 square prism: C_A", "b/a",
         [("L/a (surge 3-D)", estimate.ratios["prism_L_over_a"])]),
    ]
    for a, (x, y, name, xl, marks) in zip(ax[0], panels):
        s = _spline(x, y)
        xs = np.linspace(min(x.min(), *(m[1] for m in marks)) * 0.9, max(x.max(), *(m[1] for m in marks)) * 1.05, 400)
        a.plot(x, y, "o", color="C0", label="DNV-RP-H103")
        a.plot(xs, s(xs), color="C0", lw=1, label="not-a-knot spline")
        for j, (lab, r) in enumerate(marks):
            a.plot([r], [float(s(r))], "D", ms=7, color=f"C{3 + j}", label=f"{lab} = {r:.3g}")
        a.set_xscale("log")
        a.set_xlabel(f"{xl} [-]")
        a.set_ylabel("coefficient [-]")
        a.set_title(name, fontsize=9)
        a.legend(fontsize=7)
    fig.suptitle(title or (f"Added mass (SNAME): X_udot {estimate.X_udot:.3f} kg, Y_vdot {estimate.Y_vdot:.3f} kg, "
                           f"Z_wdot {estimate.Z_wdot:.3f} kg, N_rdot {estimate.N_rdot:.4f} kg m²; λ = {estimate.scale:.3f}"),
                 fontsize=9)
    return _save(fig, path)


_DIVE_STYLE = {"identified": ("C3", "identified"), "file": ("C0", "vehicle file"), "published": ("C2", "published")}


def plot_dive(fit, traces, path: str | Path, *, title: str = "") -> Path:
    """Validation of a dive identification (rovlab.ident.dive): on the validation segment, the
    measured depth against each model's k-step-ahead predictions and free runs, the heading
    prediction errors (a heading that turns through hundreds of degrees hides errors of a few), and
    the 1/10/100-step prediction RMSE per model as bars. ``traces``: rovlab.ident.dive.validation_traces."""
    from rovlab.ident.dive import HORIZONS, PREDICTION_STEP_S

    rows = 2 * len(traces) + 1
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise PlotUnavailable(INSTALL_HINT) from exc
    fig = Figure(figsize=(10.0, 2.2 * rows + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    gs = fig.add_gridspec(rows, 2, height_ratios=[1.0] * (rows - 1) + [1.15])
    pub = getattr(fit, "compare", None)
    labels = {k: v[1] for k, v in _DIVE_STYLE.items()}
    if pub is not None:
        labels["published"] = f"published set {pub.name}"
    first = None
    handles: dict[str, Any] = {}
    for i, tr in enumerate(traces):
        depth = tr.output == "depth_m"
        for j, (kind, series) in enumerate((("k", tr.k_step), ("free", tr.free))):
            a = fig.add_subplot(gs[2 * i + j, :], sharex=first)
            first = first or a
            how = (f"{tr.k}-step-ahead prediction ({tr.k * PREDICTION_STEP_S:g} s ahead of the data's state)"
                   if kind == "k" else f"free run from t = {tr.free_start:.1f} s (the logged input only)")
            if depth:
                span = max(float(np.ptp(tr.y)), 0.05)
                h = a.plot(tr.t, tr.y, ".", ms=2.5, color="0.3", zorder=1)[0]
                handles.setdefault("measured", (h, "measured (depth, heading)"))
                for model, (t, p) in series.items():
                    color = _DIVE_STYLE.get(model, ("C4", model))[0]
                    h = a.plot(t, p, color=color, lw=1.2, zorder=3 if model == "identified" else 2)[0]
                    handles.setdefault(model, (h, labels.get(model, model)))
                a.set_ylim(float(np.max(tr.y)) + 0.25 * span, float(np.min(tr.y)) - 0.25 * span)  # down is down
                a.set_ylabel("depth [m]\n(positive down)")
                a.set_title(f"depth: {how}; lines leaving the plot are clipped", fontsize=9, loc="left")
            else:
                a.axhline(0.0, color="0.3", lw=0.8)
                worst = 1.0
                for model, (t, p) in series.items():
                    color = _DIVE_STYLE.get(model, ("C4", model))[0]
                    err = np.degrees(p - np.interp(t, tr.t, tr.y))
                    h = a.plot(t, err, color=color, lw=1.1, zorder=3 if model == "identified" else 2)[0]
                    handles.setdefault(model, (h, labels.get(model, model)))
                    if model == "identified" and err.size:
                        worst = max(worst, float(np.max(np.abs(err))))
                if kind == "k":
                    a.set_ylim(-4.0 * worst, 4.0 * worst)
                else:  # free runs drift by tens of degrees: linear within +-1 deg, logarithmic beyond
                    a.set_yscale("symlog", linthresh=1.0)
                    a.set_ylim(-360.0, 360.0)
                a.set_ylabel("heading error [deg]\n(model - measured)")
                a.set_title(f"heading: {how}; measured heading turns {np.degrees(np.ptp(tr.y)):.0f} deg "
                            "in this segment; clipped", fontsize=9, loc="left")
            if 2 * i + j == 2 * len(traces) - 1:
                a.set_xlabel("time [s] (validation segment)")
    for col, out in enumerate(("depth_m", "heading_rad")):
        a = fig.add_subplot(gs[rows - 1, col])
        rmse = fit.prediction.get(out)
        scale, unit, what = (1.0, "m", "depth") if out == "depth_m" else (180.0 / np.pi, "deg", "heading")
        if not rmse:
            a.text(0.5, 0.5, f"no {what} prediction (DOF not identified)", ha="center", va="center",
                   transform=a.transAxes, fontsize=8)
            a.set_axis_off()
            continue
        models = [m for m in ("identified", "file", "published") if m in rmse]
        x = np.arange(len(HORIZONS))
        w = 0.8 / len(models)
        for k, m in enumerate(models):
            vals = np.asarray(rmse[m], dtype=float) * scale
            bars = a.bar(x + (k - (len(models) - 1) / 2) * w, vals, w, color=_DIVE_STYLE[m][0])
            handles.setdefault(m, (bars, labels[m]))
            for b, v in zip(bars, vals):
                if np.isfinite(v):
                    a.annotate(f"{v:.2g}", (b.get_x() + b.get_width() / 2, v), ha="center", va="bottom", fontsize=7,
                               xytext=(0, 1), textcoords="offset points")
        a.set_yscale("log")
        a.margins(y=0.15)
        a.set_xticks(x, [f"{h} step{'s' if h > 1 else ''} ({h * PREDICTION_STEP_S:g} s)" for h in HORIZONS])
        a.set_ylabel(f"{what} RMSE [{unit}]")
        a.set_title(f"{what}: prediction RMSE, validation segment", fontsize=9, loc="left")
    a0, a1 = fit.ident_span
    head = title or (f"Dive validation: identified on {a0:.0f}-{a1:.0f} s, validated on "
                     f"{fit.valid_span[0]:.0f}-{fit.valid_span[1]:.0f} s")
    order = [k for k in ("measured", "identified", "file", "published") if k in handles]
    fig.legend([handles[k][0] for k in order], [handles[k][1] for k in order], loc="outside upper center",
               ncol=len(order), fontsize=8, title=head, title_fontsize=10, frameon=False)
    return _save(fig, path)
