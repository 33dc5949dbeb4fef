"""Damping from towing-carriage runs (Sandøy 2016, sec. 4.3.1).

Each run tows the vehicle at one constant speed (five positive and five negative speeds in
[-0.5, 0.5] m/s per DOF in the thesis). Per run, the steady window is found on the speed trace,
the load cell is tared with the mean force at rest before the run starts and after it ends
(removes the cell's offset and, in heave, the net buoyancy), and the mean force over the window is the steady force.
Runs of the rig alone (same file format) give the rig's own drag, fitted with the same terms
and subtracted. Then, with SNAME signs (Fossen 2011; Sandøy 2016, sec. 3.1),

    force_n = -(X_u u + X_|u|u |u| u + X_uuu u^3)        (force the rig applies to the vehicle)

is fitted by linear least squares for the chosen terms. Because the rig drag is fitted with the
same regressors, the vehicle's coefficients are the total fit minus the rig fit, and their
covariances add.

Columns: ``run, time_s, speed_mps, force_n`` for the vehicle runs and the rig runs alike.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.ident.fitting import (
    DAMPING_TERMS,
    IdentificationError,
    LinearFit,
    check_terms,
    damping_regressors,
    fit_damping,
    linear_lsq,
    significant,
)
from rovlab.ident.steady import mean_with_stderr, plateau_window, rest_samples
from rovlab.io.tables import DataTable, read_table, require_increasing, split_runs

COLUMNS = ("run", "time_s", "speed_mps", "force_n")
DOFS = ("surge", "sway", "heave")


@dataclass(frozen=True, eq=False)
class RunSeries:
    """One run as logged, for plots."""

    run: int
    time_s: np.ndarray
    speed: np.ndarray
    force: np.ndarray


@dataclass(frozen=True, eq=False)
class SteadyPoint:
    """The steady speed and force of one run."""

    run: int
    speed: float  # mean over the steady window
    force: float  # mean force over the window, tare removed [N or N m]
    force_stderr: float
    tare: float  # force at rest before the run, subtracted (0 if none) [N]
    start_s: float
    end_s: float
    series: RunSeries | None = field(default=None, repr=False)


def steady_points(runs: Sequence[tuple[int, np.ndarray, np.ndarray, np.ndarray]], *, what: str = "run",
                  min_s: float = 2.0, trim_s: float = 1.0, tare: bool = True) -> list[SteadyPoint]:
    """Steady (speed, force) of each run given as (run id, time, speed, force)."""
    out = []
    for rid, t, v, f in runs:
        label = f"{what} {rid}"
        if t.size < 5:
            raise IdentificationError(f"{label}: {t.size} sample(s); a run needs a time series")
        win = plateau_window(t, v, what=label, min_s=min_s, trim_s=trim_s)
        rest = rest_samples(t, v, win) if tare else np.zeros(0, dtype=int)
        offset = float(np.mean(f[rest])) if rest.size else 0.0
        sl = slice(win.start, win.stop)
        force, se = mean_with_stderr(f[sl] - offset)
        out.append(SteadyPoint(rid, float(np.mean(v[sl])), force, se, offset, float(t[win.start]),
                               float(t[win.stop - 1]), RunSeries(rid, t, v, f)))
    return out


@dataclass(frozen=True, eq=False)
class DampingFit:
    """SNAME damping coefficients (<= 0 for a dissipative body) from steady runs."""

    linear: float
    quadratic: float
    cubic: float
    terms: tuple[str, ...]
    stderr: Mapping[str, float]  # 0 for terms not fitted
    points: tuple[SteadyPoint, ...]
    rig_points: tuple[SteadyPoint, ...]
    rig: Mapping[str, float]  # the rig's own damping coefficients (same terms; empty without rig)
    speed: np.ndarray  # steady speed per vehicle run
    damping: np.ndarray  # vehicle-only damping force per run, D = -(force - rig force) [N]
    residual: np.ndarray  # damping - fitted
    rms: float
    dof: str = ""
    unit: str = "N"  # "N m" for yaw
    speed_unit: str = "m/s"
    pinned: Mapping[str, tuple[float, float]] = field(default_factory=dict)  # term -> (estimate, stderr) set to 0

    def coefficients(self) -> dict[str, float]:
        return {"linear": self.linear, "quadratic": self.quadratic, "cubic": self.cubic}

    def damping_force(self, speed: np.ndarray | float) -> np.ndarray:
        """Fitted SNAME damping force D(v) = X_u v + X_|u|u |v| v + X_uuu v^3 (negative for v > 0)."""
        v = np.asarray(speed, dtype=float)
        return self.linear * v + self.quadratic * np.abs(v) * v + self.cubic * v**3

    def as_dict(self) -> dict[str, Any]:
        return {"linear": self.linear, "quadratic": self.quadratic, "cubic": self.cubic,
                "stderr": dict(self.stderr), "terms": list(self.terms), "rms": self.rms,
                "runs": len(self.points), "rig_runs": len(self.rig_points), "rig": dict(self.rig),
                "dof": self.dof, "pinned_at_zero": {k: list(v) for k, v in self.pinned.items()}}


def _combine(total: LinearFit, rig: LinearFit | None, terms: tuple[str, ...]) -> tuple[dict, dict]:
    coef = dict(zip(terms, total.coef - (rig.coef if rig is not None else 0.0)))
    var = total.stderr**2 + (rig.stderr**2 if rig is not None else 0.0)
    se = dict(zip(terms, np.sqrt(var)))
    for t in DAMPING_TERMS:
        coef.setdefault(t, 0.0)
        se.setdefault(t, 0.0)
    return {k: float(v) for k, v in coef.items()}, {k: float(v) for k, v in se.items()}


PIN_SIGMAS = 3.0  # a positive coefficient within this many standard errors of 0 is taken as 0


def _pin_insignificant_positive(v: np.ndarray, damping: np.ndarray, terms: tuple[str, ...], coef: dict, se: dict,
                                rig: LinearFit | None, *, what: str) -> dict[str, tuple[float, float]]:
    """Set to 0 the terms whose estimate is positive but not significantly so, and refit the rest.

    SNAME damping is <= 0 (a vehicle file refuses anything else). A term the vehicle does not
    have (bluerov2_heavy's Y_v = 0, N_r = 0) comes out at +-noise, half the time positive; such
    a term is fixed at 0 and the other terms refitted without it (``coef``, ``se`` updated in
    place). A significantly positive term is kept: it points at the data (a flipped force sign),
    and writing it is refused downstream.
    """
    pinned: dict[str, tuple[float, float]] = {}
    while True:
        free = [t for t in terms if t not in pinned]
        bad = [t for t in free if 0.0 < coef[t] <= PIN_SIGMAS * se[t]]
        if not bad:
            return pinned
        for t in bad:
            pinned[t] = (coef[t], se[t])
            coef[t] = 0.0
        free = [t for t in terms if t not in pinned]
        if not free:
            return pinned
        sub = linear_lsq(damping_regressors(v, free), damping, free, what=f"{what} fit")
        rig_var = dict(zip(terms, rig.stderr**2)) if rig is not None else {}
        for t, c, s_ in zip(free, sub.coef, sub.stderr):
            coef[t] = float(c)
            se[t] = float(np.sqrt(s_**2 + rig_var.get(t, 0.0)))


def fit_steady_damping(points: Sequence[SteadyPoint], rig_points: Sequence[SteadyPoint] = (), *,
                       terms: Sequence[str] = DAMPING_TERMS, dof: str = "", what: str = "towing",
                       unit: str = "N", speed_unit: str = "m/s") -> DampingFit:
    """Fit the damping coefficients to steady points, subtracting the rig's own fitted drag."""
    terms = check_terms(terms)
    if len(points) < len(terms) + 1:
        raise IdentificationError(
            f"{what} fit with terms {', '.join(terms)} needs at least {len(terms) + 1} runs at distinct "
            f"speeds; got {len(points)}" + (f" (runs {', '.join(str(p.run) for p in points)})" if points else ""))
    v = np.array([p.speed for p in points])
    f = np.array([p.force for p in points])
    total = fit_damping(v, f, terms, what=f"{what} fit")
    rig = None
    if rig_points:
        if len(rig_points) < len(terms) + 1:
            raise IdentificationError(f"rig-only fit with terms {', '.join(terms)} needs at least "
                                      f"{len(terms) + 1} rig runs; got {len(rig_points)}")
        vr = np.array([p.speed for p in rig_points])
        lo, hi = vr.min(), vr.max()
        outside = [p.run for p in points if not (lo - 0.05 * abs(lo) - 1e-3 <= p.speed <= hi + 0.05 * abs(hi) + 1e-3)]
        if outside:
            raise IdentificationError(
                f"rig runs cover speeds {lo:.3g}..{hi:.3g} {speed_unit}; vehicle run(s) {', '.join(map(str, outside))} "
                "lie outside it, so the rig drag there would be extrapolated; add rig runs at those speeds")
        rig = fit_damping(vr, np.array([p.force for p in rig_points]), terms, what="rig-only fit")
    coef, se = _combine(total, rig, terms)
    rig_force = -(damping_regressors(v, terms) @ rig.coef) if rig is not None else np.zeros_like(v)
    damping = -(f - rig_force)  # vehicle-only damping force D(v)
    pinned = _pin_insignificant_positive(v, damping, terms, coef, se, rig, what=what)
    fitted = damping_regressors(v, terms) @ np.array([coef[t] for t in terms])
    res = damping - fitted
    return DampingFit(
        linear=coef["linear"], quadratic=coef["quadratic"], cubic=coef["cubic"], terms=terms, stderr=se,
        points=tuple(points), rig_points=tuple(rig_points),
        rig=dict(zip(terms, map(float, rig.coef))) if rig is not None else {},
        speed=v, damping=damping, residual=res, rms=float(np.sqrt(np.mean(res**2))), dof=dof, unit=unit,
        speed_unit=speed_unit, pinned=pinned)


def towing_runs(table: DataTable) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """(run, time, speed, force) per run of a towing file, time checked to increase within each run."""
    table.require(*COLUMNS)
    out = []
    for rid, rows in split_runs(table, "run"):
        require_increasing(rows, "time_s")
        out.append((rid, rows["time_s"], rows["speed_mps"], rows["force_n"]))
    return out


def identify_towing(table: DataTable, rig: DataTable | None = None, *, terms: Sequence[str] = DAMPING_TERMS,
                    dof: str = "", min_s: float = 2.0, trim_s: float = 1.0, tare: bool = True) -> DampingFit:
    """Towing runs (and optional rig-only runs) -> SNAME damping coefficients."""
    pts = steady_points(towing_runs(table), what=f"{table.file}: run", min_s=min_s, trim_s=trim_s, tare=tare)
    rig_pts = (steady_points(towing_runs(rig), what=f"{rig.file}: rig run", min_s=min_s, trim_s=trim_s, tare=tare)
               if rig is not None else [])
    return fit_steady_damping(pts, rig_pts, terms=terms, dof=dof, what="towing")


SPEED_COLUMNS = {"u_mps": "surge", "v_mps": "sway", "w_mps": "heave"}


def read_towing(path: str | Path) -> DataTable:
    """A towing log. The speed column is ``speed_mps``, or ``u_mps`` / ``v_mps`` / ``w_mps``, which
    also say the DOF (read back by :func:`dof_of_log`)."""
    table = read_table(path, what="towing log")
    named = [c for c in SPEED_COLUMNS if table.has(c)]
    if len(named) == 1 and not table.has("speed_mps"):
        col = named[0]
        data = {("speed_mps" if k == col else k): v for k, v in table.data.items()}
        columns = tuple("speed_mps" if c == col else c for c in table.columns)
        table = DataTable(table.file, columns, data, table.lines,
                          table.comments + (f"dof = {SPEED_COLUMNS[col]}",))
    table.require(*COLUMNS)
    return table


def dof_of_log(table: DataTable) -> str | None:
    """The DOF a towing log says it is (a u/v/w_mps speed column, or the virtual lab's
    ``# setting.dof = ...`` line), None if it does not say."""
    meta = table.meta()
    for key in ("dof", "setting.dof"):
        if meta.get(key) in DOFS:
            return meta[key]
    return None


def damping_edits(fit: DampingFit, dof: str, *, digits: int = 4) -> dict[str, float]:
    """Vehicle-file edits ``damping.<dof>.{linear, quadratic, cubic}`` (only the fitted terms;
    the others are set to 0, since the fit assumed them absent)."""
    return {f"damping.{dof}.{t}": significant(getattr(fit, t), digits) for t in DAMPING_TERMS}
