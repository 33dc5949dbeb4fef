"""Simulation scenarios: closed-schema TOML files, with any scalar replaceable by a distribution.

A scenario names the vehicle, the filter/controller configuration, the plant fidelity, the true
initial state, the reference schedule, drop-out windows, the true disturbances and the seed::

    name = "dropout"
    description = "..."
    source = "Sandøy 2016, sec. 5.3.1 and fig. 5.4 (case 3)"
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
    heading_deg = 30.0              # also x, y [m] (NED; followed by position controllers, "dp")

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
    current = { north = 0.1, east = 0.0, down = 0.0 }   # constant ocean current [m/s], NED (default 0)
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
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.params.design import load_design_config
from rovlab.params.validate import Collector, ConfigError, PackagedFiles, Problem, TableReader, read_toml
from rovlab.params.vehicle import PLAUSIBLE, load_vehicle

_DEG = math.pi / 180.0
DOF_NAMES = ("surge", "sway", "heave", "yaw")
PLANTS = ("process", "observer")
INITIAL_KEYS = {"x": 1.0, "y": 1.0, "z": 1.0, "heading_deg": _DEG, "u": 1.0, "v": 1.0, "w": 1.0,
                "r_deg_s": _DEG}
TRUTH_PARAMETERS = ("mass", "I_zz", "X_udot", "Y_vdot", "Z_wdot", "N_rdot", "displaced_volume")

# Plausibility (issue 15: a plant step of 1e-9 s tried to allocate 46 GiB, 5e-324 overflowed, a
# bias std of 1e15 N made the plant NaN). Ranges for a BlueROV-class vehicle, stated in
# docs/simulation.md; vehicle quantities use the vehicle file's ranges (docs/vehicle-file.md).
PLANT_STEP_RANGE = (1e-4, 1.0)  # [s]
MAX_PLANT_STEPS = 10_000_000  # duration_s / plant_step_s: ~160 MB of random numbers per run
POSITION_RANGE = (-1e4, 1e4)  # x, y, z [m]
HEADING_RANGE_DEG = (-720.0, 720.0)
SPEED_RANGE = (-10.0, 10.0)  # u, v, w [m/s]
YAW_RATE_RANGE_DEG_S = (-720.0, 720.0)
_INITIAL_RANGES = {"x": POSITION_RANGE, "y": POSITION_RANGE, "z": POSITION_RANGE, "heading_deg": HEADING_RANGE_DEG,
                   "u": SPEED_RANGE, "v": SPEED_RANGE, "w": SPEED_RANGE, "r_deg_s": YAW_RATE_RANGE_DEG_S}
PSD_RANGE = (0.0, 1e4)  # process-noise spectral density [N^2/Hz, (N m)^2/Hz]
BIAS_STD_RANGE = {"surge": (0.0, 1e3), "sway": (0.0, 1e3), "heave": (0.0, 1e3), "yaw": (0.0, 1e2)}  # [N, N m]
BIAS_TIME_RANGE = (0.1, 1e8)  # [s]
BUOYANCY_OFFSET_RANGE = (-1e3, 1e3)  # [N]
PWM_RESOLUTION_RANGE = (1e-3, 100.0)  # [us], or 0 (none): ArduSub commands whole microseconds (SERVO_OUTPUT_RAW
# is uint16 us); 1e-3 us would be a 1 GHz timer. Finer: cmd / res overflowed to PWM = inf (issue 28)
CURRENT_RANGE = (-5.0, 5.0)  # ocean current per NED axis [m/s]
CURRENT_KEYS = ("north", "east", "down")


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
    current: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [truth] current, NED [m/s]
    reference_x: np.ndarray | None = None  # (k,) north set-point [m] from reference_times (None: initial x)
    reference_y: np.ndarray | None = None  # (k,) east set-point [m]

    def reference_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """North and east set-points per reference time (the initial position where none given)."""
        k = len(self.reference_times)
        rx = self.reference_x if self.reference_x is not None else np.full(k, float(self.initial[0]))
        ry = self.reference_y if self.reference_y is not None else np.full(k, float(self.initial[1]))
        return rx, ry

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
    return _read(concrete, col, file, seed)  # raises with every problem, the draw's included


def has_distributions(data: Mapping[str, Any]) -> bool:
    """Whether a scenario's raw TOML has any distribution table (so its values depend on the seed)."""
    def walk(node: Any) -> bool:
        if isinstance(node, Mapping):
            return "dist" in node or any(walk(v) for v in node.values())
        if isinstance(node, list):
            return any(walk(v) for v in node)
        return False

    return walk(data)


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


def _component_name(top: TableReader, kind: str) -> str | None:
    """A scenario's choice of estimator or controller (None: the design configuration's), checked
    against the registry here (names only, nothing imported), so that no command builds a compile
    line or a cache key from a name that is not one."""
    from rovlab.core.components import component_names, unknown_component

    name = top.string(kind, "") or None
    if name is not None and name not in component_names(kind):
        top.problem(kind, name, unknown_component(kind, name))
        return None
    return name


def _read(data: dict[str, Any], col: Collector, file: str, seed: int) -> Scenario:
    top = TableReader(data, col)
    top.raw("seed", 0)  # already handled
    name = top.name("name")
    description = top.string("description", "")
    source = top.string("source")
    vehicle = _resolve_relative(top.string("vehicle", "udrone"), file)
    design = _resolve_relative(top.string("design", "default"), file)
    plant = top.string("plant", "process", choices=PLANTS)
    estimator = _component_name(top, "estimator")
    controller = _component_name(top, "controller")
    duration = top.number("duration_s", positive=True, hi=1e6)
    step = top.number("plant_step_s", 0.01, positive=True, plausible=PLANT_STEP_RANGE, what="s")
    if math.isfinite(duration) and math.isfinite(step) and duration / step > MAX_PLANT_STEPS:
        top.problem("plant_step_s", step, f"at most {MAX_PLANT_STEPS:.0e} plant steps per run "
                    f"(duration_s / plant_step_s is {duration / step:.3g}): a longer step or a shorter run")

    ini = top.table("initial", required=False)
    initial = np.zeros(8)
    order = ("x", "y", "z", "heading_deg", "u", "v", "w", "r_deg_s")
    for i, key in enumerate(order):
        initial[i] = ini.number(key, 0.0, nonnegative=key == "z", plausible=_INITIAL_RANGES[key],
                                what="m, depth below the free surface (z = 0)" if key == "z" else "") * INITIAL_KEYS[key]
    ini.finish()

    times: list[float] = []
    zs: list[float] = []
    psis: list[float] = []
    xs: list[float] = []
    ys: list[float] = []
    z_now = initial[2]
    psi_now = initial[3]
    x_now, y_now = initial[0], initial[1]
    for r in top.tables("reference", required=False):
        t = r.number("t_s", nonnegative=True)
        x_now = r.number("x", x_now, plausible=POSITION_RANGE, what="m, north")
        y_now = r.number("y", y_now, plausible=POSITION_RANGE, what="m, east")
        xs.append(x_now)
        ys.append(y_now)
        z_now = r.number("z", z_now, nonnegative=True, plausible=POSITION_RANGE,
                         what="m, depth below the free surface (z = 0; the vehicle cannot be sent above it)")
        psi_now = r.number("heading_deg", psi_now / _DEG, plausible=HEADING_RANGE_DEG) * _DEG
        r.finish()
        if times and math.isfinite(t) and t <= times[-1]:
            r.problem("t_s", t, f"a time after the previous reference ({times[-1]:g} s)")
        times.append(t)
        zs.append(z_now)
        psis.append(psi_now)
    if not times:
        times, zs, psis = [0.0], [float(initial[2])], [float(initial[3])]
        xs, ys = [float(initial[0])], [float(initial[1])]

    dropouts = []
    for d in top.tables("dropout", required=False):
        target = d.name("sensor")
        start = d.number("start_s", nonnegative=True)
        end = d.number("end_s", nonnegative=True)
        if math.isfinite(start) and math.isfinite(end) and end <= start:
            d.problem("end_s", end, f"a time after start_s ({start:g})")
        d.finish()
        sensor, _, channel = target.partition(".")
        dropouts.append(Dropout(sensor, channel or None, start, end))

    tr = top.table("truth", required=False)
    psd = _dof_numbers(tr, "process_noise_psd", {"surge": 1e-2, "sway": 1e-2, "heave": 1e-2, "yaw": 1e-4},
                       ranges={d: PSD_RANGE for d in DOF_NAMES})
    bias_std = _dof_numbers(tr, "bias_std", {"surge": 0.2, "sway": 0.2, "heave": 0.3, "yaw": 0.005},
                            ranges=BIAS_STD_RANGE)
    bias_T = _dof_numbers(tr, "bias_time_constant_s", {d: 60.0 for d in DOF_NAMES}, positive=True,
                          ranges={d: BIAS_TIME_RANGE for d in DOF_NAMES})
    buoy = tr.number("buoyancy_offset", 0.0, plausible=BUOYANCY_OFFSET_RANGE, what="N")
    pwm_res = tr.number("pwm_resolution_us", 1.0, what="us")
    if pwm_res != 0.0 and not PWM_RESOLUTION_RANGE[0] <= pwm_res <= PWM_RESOLUTION_RANGE[1]:  # NaN: reported
        if not math.isnan(pwm_res):
            tr.problem("pwm_resolution_us", pwm_res, "0 (none) or a resolution within "
                       f"{PWM_RESOLUTION_RANGE[0]:g} .. {PWM_RESOLUTION_RANGE[1]:g} us (an ESC's command step)")
        pwm_res = math.nan
    cur = tr.table("current", required=False)
    current = np.array([cur.number(k, 0.0, plausible=CURRENT_RANGE, what="m/s, NED") for k in CURRENT_KEYS])
    cur.finish()
    params = tr.table("parameters", required=False)
    truth_params: dict[str, float] = {}
    for key in TRUTH_PARAMETERS:
        if params.has(key):
            if key in ("mass", "I_zz", "displaced_volume"):
                truth_params[key] = params.number(key, positive=True, plausible=PLAUSIBLE[key])
            else:
                truth_params[key] = params.number(key, nonpositive=True, plausible=PLAUSIBLE["added_mass"],
                                                  what="SNAME sign")
    params.finish()
    events = _events(tr)
    tether = _tether(tr)
    tr.finish()
    top.finish()
    _check_references(top, vehicle, design, step, duration, dropouts)
    col.raise_if_any("scenario file")
    return Scenario(
        name=name, description=description, source=source, vehicle=vehicle, design=design, plant=plant,
        duration_s=duration, seed=seed, plant_step_s=step, initial=initial,
        reference_times=np.array(times), reference_z=np.array(zs), reference_psi=np.array(psis),
        dropouts=tuple(dropouts), process_noise_psd=psd, bias_std=bias_std, bias_time_constant_s=bias_T,
        buoyancy_offset=buoy, pwm_resolution_us=pwm_res, truth_parameters=truth_params, file=file,
        estimator=estimator, controller=controller, events=events, tether=tether, current=current,
        reference_x=np.array(xs), reference_y=np.array(ys),
    )


def _check_references(top: TableReader, vehicle: str, design: str, step: float, duration: float,
                      dropouts: list[Dropout]) -> None:
    """Problems that need the files the scenario names, collected with the scenario's own (so a
    file reports all its problems at once): the vehicle and the configuration load, the plant
    step divides the filter's sample time, the run lasts at least one control step (a shorter
    one is a single row: duration_s = 1e-308 gave metrics of one sample), and each drop-out
    names a sensor channel of the vehicle.
    """
    v = _load_reference(top, "vehicle", vehicle, load_vehicle)
    c = _load_reference(top, "design", design, load_design_config)
    if c is not None and math.isfinite(step):
        h = c.sample_time
        n_sub = int(round(h / step))
        if n_sub < 1 or abs(n_sub * step - h) > 1e-9 * h:
            top.problem("plant_step_s", step, f"a step that divides the filter's sample time {h:g} s")
    if c is not None and math.isfinite(duration) and duration < c.sample_time:
        top.problem("duration_s", duration, f"at least one control step of the design (its sample_time, "
                    f"{c.sample_time:g} s)")
    if v is None:
        return
    for i, d in enumerate(dropouts):
        if not d.sensor:
            continue
        sensors = {s.name: s for s in v.sensors}
        if d.sensor not in sensors:
            top.collector.add(f"dropout[{i}].sensor", d.sensor,
                              f"a sensor of vehicle {v.name!r}: " + ", ".join(sensors))
        elif d.channel is not None and d.channel not in sensors[d.sensor].channels():
            top.collector.add(f"dropout[{i}].sensor", f"{d.sensor}.{d.channel}",
                              f"a channel of sensor {d.sensor!r}: "
                              + ", ".join(f"{d.sensor}.{ch}" for ch in sensors[d.sensor].channels()))


_REFERENCES: dict[tuple, Any] = {}


def _load_reference(top: TableReader, key: str, ref: str, loader: Any) -> Any:
    """Load a referenced vehicle/configuration (cached per file and modification time), adding
    its problems under ``key``; None when it does not load."""
    if not ref:
        return None
    try:
        path = Path(ref)
        stamp = path.stat().st_mtime_ns if path.exists() else None
    except (OSError, ValueError):
        stamp = None
    cache_key = (key, ref, stamp)
    if cache_key not in _REFERENCES:
        try:
            _REFERENCES[cache_key] = loader(ref)
        except ConfigError as exc:
            _REFERENCES[cache_key] = exc
        except (OSError, ValueError) as exc:  # e.g. a NUL in the path
            _REFERENCES[cache_key] = ConfigError([Problem(ref, "", ref, f"a readable file ({exc})")], key)
        if len(_REFERENCES) > 64:
            _REFERENCES.pop(next(iter(_REFERENCES)))
    hit = _REFERENCES[cache_key]
    if isinstance(hit, ConfigError):
        for p in hit.problems:
            top.problem(key, ref, f"a loadable {key}: {p}")
        return None
    return hit


def _dof_numbers(tr: TableReader, key: str, defaults: dict[str, float], positive: bool = False,
                 ranges: Mapping[str, tuple[float, float]] | None = None) -> np.ndarray:
    sub = tr.table(key, required=False)
    out = np.array([sub.number(d, defaults[d], nonnegative=not positive, positive=positive,
                               plausible=ranges[d] if ranges else None) for d in DOF_NAMES])
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
