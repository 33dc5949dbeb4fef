"""Simulation scenarios: closed-schema TOML files, with any scalar replaceable by a distribution.

A scenario names the vehicle, the filter/controller configuration, the plant fidelity, the true
initial state, the reference schedule, drop-out windows, the true disturbances and the seed::

    name = "dropout"
    description = "..."
    source = "Sandøy 2016, fig. 5.4; SPEC section 7, case 3"
    vehicle = "udrone"              # packaged name, or a path relative to this file
    design = "thesis"               # filter/controller configuration (name or path)
    estimator = "kf"                # optional: override the configuration's estimator / controller
    controller = "lqg"
    plant = "process"               # "process": nonlinear 4-DOF model with thrusters, noise and
                                    # biases; "observer": the linear design model ("perfect model")
    duration_s = 60.0
    seed = 1
    plant_step_s = 0.01             # fixed-step RK4 (must divide the filter's sample time)

    [initial]                       # true initial state (missing entries are 0)
    z = 1.05
    heading_deg = 52.0              # also x, y, u, v, w, r_deg_s

    [[reference]]                   # piecewise-constant set-points; a missing entry keeps its value
    t_s = 0.0
    z = 0.70
    heading_deg = 30.0

    [[dropout]]                     # no samples from a sensor (or one channel) in [start_s, end_s)
    sensor = "qualisys"             # or "qualisys.z"
    start_s = 20.0
    end_s = 40.0

    [truth]                         # the process plant's disturbances (all optional)
    process_noise_psd = { surge = 1e-2, sway = 1e-2, heave = 1e-2, yaw = 1e-8 }
    bias_std = { heave = 0.5, yaw = 0.01 }          # stationary std of the true Gauss-Markov biases
    bias_time_constant_s = { heave = 60.0, yaw = 60.0 }
    buoyancy_offset = 0.0           # extra net buoyancy in N (positive = lighter), e.g. a payload
    pwm_resolution_us = 1.0         # ESC command quantisation (0 = none)
    parameters = { mass = 7.6 }     # plant truth differing from the vehicle file (any of
                                    # mass, I_zz, X_udot ... N_rdot, displaced_volume)

    [[truth.event]]                 # a sudden change of the plant from t_s on (cumulative)
    t_s = 40.0
    mass_change = 0.5               # kg of rigid-body mass picked up (< 0: dropped); its weight
                                    # comes with it (net buoyancy falls by mass_change * g)
    buoyancy_change = -4.0          # N of buoyancy gained (positive = lighter), e.g. floats
                                    # soaking up water (< 0) or a payload's displaced volume (> 0)

    [truth.tether]                  # a slowly varying vertical pull (positive = down, N):
    mean = 1.0                      # mean + amplitude * sin(2 pi t / period_s + phase)
    amplitude = 2.0
    period_s = 40.0
    phase_deg = 0.0

Distributions (for Monte Carlo): any number above may be written as
``{ dist = "normal", mean = 1.05, std = 0.02 }`` or ``{ dist = "uniform", low = 0.9, high = 1.2 }``.
Each run draws them from its own seed, so a run is replayed from its seed alone.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from rovlab.params.validate import Collector, PackagedFiles, TableReader, read_toml

_DEG = math.pi / 180.0
DOF_NAMES = ("surge", "sway", "heave", "yaw")
PLANTS = ("process", "observer")
INITIAL_KEYS = {"x": 1.0, "y": 1.0, "z": 1.0, "heading_deg": _DEG, "u": 1.0, "v": 1.0, "w": 1.0,
                "r_deg_s": _DEG}
TRUTH_PARAMETERS = ("mass", "I_zz", "X_udot", "Y_vdot", "Z_wdot", "N_rdot", "displaced_volume")


@dataclass(frozen=True)
class Dropout:
    sensor: str  # sensor name
    channel: str | None  # None = every channel of the sensor
    start_s: float
    end_s: float


@dataclass(frozen=True)
class TruthEvent:
    """A sudden change of the plant at t_s (SI): rigid-body mass added and buoyancy gained."""

    t_s: float
    mass_change: float = 0.0  # [kg]; its weight comes with it
    buoyancy_change: float = 0.0  # [N], positive = lighter


@dataclass(frozen=True)
class Tether:
    """A vertical pull [N, positive down]: mean + amplitude sin(2 pi t / period_s + phase)."""

    mean: float = 0.0
    amplitude: float = 0.0
    period_s: float = 60.0
    phase: float = 0.0  # [rad]

    def force(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return self.mean + self.amplitude * np.sin(2.0 * math.pi * t / self.period_s + self.phase)


@dataclass(frozen=True, eq=False)
class Scenario:
    """One concrete run (distributions already drawn). SI units, radians."""

    name: str
    description: str
    source: str
    vehicle: str  # name or resolved path
    design: str  # name or resolved path
    plant: str
    duration_s: float
    seed: int
    plant_step_s: float
    initial: np.ndarray  # [x, y, z, psi, u, v, w, r]
    reference_times: np.ndarray  # (k,) switch times [s]
    reference_z: np.ndarray  # (k,) depth set-point from that time
    reference_psi: np.ndarray  # (k,) heading set-point [rad]
    dropouts: tuple[Dropout, ...]
    process_noise_psd: np.ndarray  # (4,) surge, sway, heave, yaw
    bias_std: np.ndarray  # (4,)
    bias_time_constant_s: np.ndarray  # (4,)
    buoyancy_offset: float
    pwm_resolution_us: float
    truth_parameters: Mapping[str, float]
    file: str = ""
    estimator: str | None = None  # overrides the design configuration's choice
    controller: str | None = None
    events: tuple[TruthEvent, ...] = ()  # [[truth.event]], in time order
    tether: Tether = Tether()  # [truth.tether]

    def reference_at(self, t: float) -> tuple[float, float]:
        k = int(np.searchsorted(self.reference_times, t, side="right")) - 1
        k = max(k, 0)
        return float(self.reference_z[k]), float(self.reference_psi[k])


# --------------------------------------------------------------------------------------------

_PACKAGED = PackagedFiles("rovlab.sim", "scenarios", "scenario")


def packaged_scenario_names() -> list[str]:
    return _PACKAGED.names()


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A packaged scenario name (``dropout``) or a path to a TOML file."""
    return _PACKAGED.resolve(name_or_path)


def load_scenario_data(name_or_path: str | Path) -> tuple[dict[str, Any], str]:
    """The raw TOML of a scenario (distributions not drawn yet) and its file name."""
    path = resolve_scenario_path(name_or_path)
    return read_toml(path), str(path)


def load_scenario(name_or_path: str | Path, *, seed: int | None = None) -> Scenario:
    """Load a scenario and draw its distributions with ``seed`` (default: the file's seed)."""
    data, file = load_scenario_data(name_or_path)
    return scenario_from_dict(data, file=file, seed=seed)


def scenario_from_dict(data: Mapping[str, Any], *, file: str = "<dict>", seed: int | None = None) -> Scenario:
    col = Collector(file)
    raw_seed = data.get("seed", 0)
    if seed is None:
        if not isinstance(raw_seed, int) or isinstance(raw_seed, bool) or raw_seed < 0:
            col.add("seed", raw_seed, "a non-negative integer")
            raw_seed = 0
        seed = int(raw_seed)
    elif seed < 0:
        col.add("seed", seed, "a non-negative integer")
    rng = np.random.default_rng(seed)
    concrete = _draw(copy.deepcopy(dict(data)), rng, col, "")
    col.raise_if_any("scenario file")
    return _read(concrete, col, file, seed)


def _draw(node: Any, rng: np.random.Generator, col: Collector, path: str) -> Any:
    """Replace every distribution table by a sample (depth-first, in file order)."""
    if isinstance(node, dict):
        if "dist" in node:
            return _sample(node, rng, col, path)
        return {k: _draw(v, rng, col, f"{path}.{k}" if path else k) for k, v in node.items()}
    if isinstance(node, list):
        return [_draw(v, rng, col, f"{path}[{i}]") for i, v in enumerate(node)]
    return node


def _sample(node: dict, rng: np.random.Generator, col: Collector, path: str) -> float:
    r = TableReader(node, col, path)
    kind = r.string("dist", choices=("normal", "uniform"))
    value = math.nan
    if kind == "normal":
        mean = r.number("mean")
        std = r.number("std", nonnegative=True)
        if math.isfinite(mean) and math.isfinite(std):
            value = float(rng.normal(mean, std))
    elif kind == "uniform":
        lo = r.number("low")
        hi = r.number("high")
        if math.isfinite(lo) and math.isfinite(hi):
            if hi < lo:
                r.problem("high", hi, f"a number >= low ({lo})")
            else:
                value = float(rng.uniform(lo, hi))
    r.finish()
    return value


def _resolve_relative(ref: str, file: str) -> str:
    """Names stay names; relative paths are taken relative to the scenario file."""
    if ref.endswith(".toml") or "/" in ref:
        p = Path(ref)
        if not p.is_absolute() and file and not file.startswith("<"):
            p = Path(file).parent / p
        return str(p)
    return ref


def _read(data: dict[str, Any], col: Collector, file: str, seed: int) -> Scenario:
    top = TableReader(data, col)
    top.raw("seed", 0)  # already handled
    name = top.string("name")
    description = top.string("description", "")
    source = top.string("source")
    vehicle = _resolve_relative(top.string("vehicle", "udrone"), file)
    design = _resolve_relative(top.string("design", "default"), file)
    plant = top.string("plant", "process", choices=PLANTS)
    estimator = top.string("estimator", "") or None  # checked against the registry at prepare
    controller = top.string("controller", "") or None
    duration = top.number("duration_s", positive=True, hi=1e6)
    step = top.number("plant_step_s", 0.01, positive=True, hi=1.0)

    ini = top.table("initial", required=False)
    initial = np.zeros(8)
    order = ("x", "y", "z", "heading_deg", "u", "v", "w", "r_deg_s")
    for i, key in enumerate(order):
        initial[i] = ini.number(key, 0.0) * INITIAL_KEYS[key]
    ini.finish()

    times: list[float] = []
    zs: list[float] = []
    psis: list[float] = []
    z_now = initial[2]
    psi_now = initial[3]
    for r in top.tables("reference", required=False):
        t = r.number("t_s", nonnegative=True)
        z_now = r.number("z", z_now)
        psi_now = r.number("heading_deg", psi_now / _DEG) * _DEG
        r.finish()
        if times and math.isfinite(t) and t <= times[-1]:
            r.problem("t_s", t, f"a time after the previous reference ({times[-1]:g} s)")
        times.append(t)
        zs.append(z_now)
        psis.append(psi_now)
    if not times:
        times, zs, psis = [0.0], [float(initial[2])], [float(initial[3])]

    dropouts = []
    for d in top.tables("dropout", required=False):
        target = d.string("sensor")
        start = d.number("start_s", nonnegative=True)
        end = d.number("end_s", nonnegative=True)
        if math.isfinite(start) and math.isfinite(end) and end <= start:
            d.problem("end_s", end, f"a time after start_s ({start:g})")
        d.finish()
        sensor, _, channel = target.partition(".")
        dropouts.append(Dropout(sensor, channel or None, start, end))

    tr = top.table("truth", required=False)
    psd = _dof_numbers(tr, "process_noise_psd", {"surge": 1e-2, "sway": 1e-2, "heave": 1e-2, "yaw": 1e-4})
    bias_std = _dof_numbers(tr, "bias_std", {"surge": 0.2, "sway": 0.2, "heave": 0.3, "yaw": 0.005})
    bias_T = _dof_numbers(tr, "bias_time_constant_s", {d: 60.0 for d in DOF_NAMES}, positive=True)
    buoy = tr.number("buoyancy_offset", 0.0)
    pwm_res = tr.number("pwm_resolution_us", 1.0, nonnegative=True)
    params = tr.table("parameters", required=False)
    truth_params: dict[str, float] = {}
    for key in TRUTH_PARAMETERS:
        if params.has(key):
            if key in ("mass", "I_zz", "displaced_volume"):
                truth_params[key] = params.number(key, positive=True)
            else:
                truth_params[key] = params.number(key, nonpositive=True, what="SNAME sign")
    params.finish()
    events = _events(tr)
    tether = _tether(tr)
    tr.finish()
    top.finish()
    col.raise_if_any("scenario file")
    return Scenario(
        name=name, description=description, source=source, vehicle=vehicle, design=design, plant=plant,
        duration_s=duration, seed=seed, plant_step_s=step, initial=initial,
        reference_times=np.array(times), reference_z=np.array(zs), reference_psi=np.array(psis),
        dropouts=tuple(dropouts), process_noise_psd=psd, bias_std=bias_std, bias_time_constant_s=bias_T,
        buoyancy_offset=buoy, pwm_resolution_us=pwm_res, truth_parameters=truth_params, file=file,
        estimator=estimator, controller=controller, events=events, tether=tether,
    )


def _dof_numbers(tr: TableReader, key: str, defaults: dict[str, float], positive: bool = False) -> np.ndarray:
    sub = tr.table(key, required=False)
    out = np.array([sub.number(d, defaults[d], nonnegative=not positive, positive=positive) for d in DOF_NAMES])
    sub.finish()
    return out


def _events(tr: TableReader) -> tuple[TruthEvent, ...]:
    """[[truth.event]]: sudden changes of the plant, in increasing time."""
    out: list[TruthEvent] = []
    for ev in tr.tables("event", required=False):
        t = ev.number("t_s", nonnegative=True)
        dm = ev.number("mass_change", 0.0, what="kg of rigid-body mass added (< 0: dropped)")
        db = ev.number("buoyancy_change", 0.0, what="N of buoyancy gained (positive = lighter)")
        if not ev.has("mass_change") and not ev.has("buoyancy_change"):
            ev.problem("mass_change", "neither mass_change nor buoyancy_change",
                       "at least one of mass_change [kg] and buoyancy_change [N]")
        ev.finish()
        if out and math.isfinite(t) and math.isfinite(out[-1].t_s) and t <= out[-1].t_s:
            ev.problem("t_s", t, f"a time after the previous event ({out[-1].t_s:g} s)")
        out.append(TruthEvent(t, dm, db))
    return tuple(out)


def _tether(tr: TableReader) -> Tether:
    """[truth.tether]: a slowly varying vertical pull."""
    te = tr.table("tether", required=False)
    tether = Tether(
        mean=te.number("mean", 0.0, what="N, positive down"),
        amplitude=te.number("amplitude", 0.0, nonnegative=True, what="N"),
        period_s=te.number("period_s", 60.0, positive=True, what="s"),
        phase=te.number("phase_deg", 0.0, what="degrees") * _DEG,
    )
    te.finish()
    return tether
