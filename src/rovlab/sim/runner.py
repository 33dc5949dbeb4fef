"""Preparing and running a scenario: the designs, the components and the one call of the loop.

:func:`prepare` resolves a scenario into a :class:`Prepared` run (the model vehicle, the plant's
truth, the designed estimator and controller, the plant, sensors and actuators as components, and
every random draw of the run made from its seed). :class:`Simulation` advances the components
through the compiled loop (rovlab.sim.loop) chunk by chunk; it is the only caller of the loop,
for batch runs (:func:`run_prepared`), Monte Carlo (rovlab.sim.montecarlo) and the live HMI
(rovlab.sim.live) alike, and :func:`columns` names what the loop logged, once for all of them.

Designs that many runs share (Monte Carlo) are held by a :class:`DesignBook` the caller owns and
passes in: there is no hidden cache in this module.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rovlab import _jit
from rovlab.allocation.solvers import Allocator
from rovlab.core.components import (
    TRUTH_INDEX,
    ControllerSpec,
    EstimatorSpec,
    fresh,
    plant_draws,
)
from rovlab.models import kinetics as kin
from rovlab.models.discretise import discretise
from rovlab.models.noise import gauss_markov_coefficients, psd_factor
from rovlab.models.sensors import SensorBank
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.design import DesignConfig, load_design_config
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle, load_vehicle
from rovlab.sim import metrics as mx
from rovlab.sim.actuators import Actuators, make_actuators
from rovlab.sim.compile import note_cached, record
from rovlab.sim.components import build_pair
from rovlab.sim.loop import Drive, Logs, draw, explain_allocation, loop_for, new_logs, new_work, run_loop
from rovlab.sim.plant import ObserverPlant, ProcessPlant
from rovlab.sim.scenario import Scenario, scenario_from_dict

# --------------------------------------------------------------------------------------------
# Designs (shared by runs)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Design:
    """What depends only on the model vehicle, the configuration and the plant fidelity."""

    vehicle: Vehicle
    config: DesignConfig
    estimator: EstimatorSpec
    controller: ControllerSpec
    allocator: Allocator
    plant: str  # "process" or "observer"
    plant_step: float
    observer_plant: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # (Phi, Delta, L) at the plant step


def make_design(vehicle: Vehicle, config: DesignConfig, *, plant: str, plant_step: float,
                estimator: str | None = None, controller: str | None = None, file: str | None = None) -> Design:
    """Design the estimator, controller and allocation (raises ConfigError)."""
    est, ctl = build_pair(vehicle, config, estimator=estimator, controller=controller, file=file)
    alloc = Allocator(vehicle)
    check_heave_capacity(ctl, alloc, file or config.file or config.name)
    observer = None
    if plant == "observer":
        fm = est.model
        if fm is None or not hasattr(fm, "A") or fm.A.shape != (6, 6):
            raise ConfigError([Problem(file or config.file, "plant", plant,
                                       "the process plant: the observer plant is the depth-and-heading "
                                       "filter's own model and needs estimator = \"kf\"")], "scenario file")
        disc = discretise(fm.A, fm.B, fm.E, fm.W, plant_step)
        observer = (np.ascontiguousarray(disc.Phi), np.ascontiguousarray(disc.Delta),
                    np.ascontiguousarray(psd_factor(disc.Q)))
    return Design(vehicle, config, est, ctl, alloc, plant, plant_step, observer)


def check_heave_capacity(ctl: ControllerSpec, alloc: Allocator, where: str) -> None:
    """A controller whose design says what heave force its reference model takes
    (``model.heave_force_needed`` = (down, up) [N], e.g. MRAC) must get it from the thrusters
    (allocation with K = M = 0); ConfigError naming the [mrac] keys otherwise."""
    need = getattr(ctl.model, "heave_force_needed", None)
    if need is None:
        return
    down_cap = float(alloc.allocate(np.array([0.0, 0.0, 1e6, 0.0])).achieved[2])
    up_cap = float(alloc.allocate(np.array([0.0, 0.0, -1e6, 0.0])).achieved[2])
    down, up = float(need[0]), float(need[1])
    if down > down_cap or up < up_cap:
        cfg = ctl.model.config
        raise ConfigError([Problem(where, "mrac.bandwidth", cfg.bandwidth,
                                   f"a reference model the thrusters can follow: a {cfg.max_step:g} m depth step "
                                   f"(mrac.max_step) with bandwidth {cfg.bandwidth:g} rad/s and damping "
                                   f"{cfg.damping:g} takes {down:.1f} N down / {up:.1f} N on the model (holding its "
                                   f"net weight), the thrusters give {down_cap:.1f} N down / {up_cap:.1f} N; lower "
                                   "the bandwidth or max_step")], "filter configuration")


class DesignBook:
    """Loaded vehicle/configuration files and designs, shared by the runs of a caller (e.g. a
    Monte Carlo). Owned and passed in explicitly; files are reloaded when they change on disk."""

    def __init__(self) -> None:
        self._files: dict[tuple, Any] = {}
        self._designs: dict[tuple, Design] = {}

    def load(self, loader: Callable[[str], Any], ref: str) -> Any:
        path = Path(ref)
        stamp = path.stat().st_mtime_ns if path.exists() else None
        key = (loader.__name__, ref, stamp)
        if key not in self._files:
            self._files[key] = loader(ref)
        return self._files[key]

    def design(self, vehicle: Vehicle, config: DesignConfig, **kw: Any) -> Design:
        key = (id(vehicle), id(config), *sorted(kw.items()))
        hit = self._designs.get(key)
        if hit is None or hit.vehicle is not vehicle or hit.config is not config:
            hit = self._designs[key] = make_design(vehicle, config, **kw)
        return hit


# --------------------------------------------------------------------------------------------
# Preparing a run
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Prepared:
    """A scenario with everything the loop needs: components at their initial state and the
    run's random draws (``drive``). Running it does not change it (runs copy the state)."""

    scenario: Scenario
    vehicle: Vehicle  # the vehicle as the estimator/controller know it
    truth: Vehicle  # the plant's true vehicle
    config: DesignConfig
    design: Design
    plant: ProcessPlant | ObserverPlant
    sensors: SensorBank
    actuators: Actuators
    drive: Drive  # the whole run's draws, schedule and references
    n_ctrl: int
    h: float
    nav_of: np.ndarray  # int64: TRUTH index of each estimator state
    nees_idx: np.ndarray  # int64: estimator states with a truth to compare to

    @property
    def filter_model(self) -> Any:
        return self.design.estimator.model

    @property
    def allocator(self) -> Allocator:
        return self.design.allocator

    @property
    def K(self) -> np.ndarray:
        return self.design.controller.model.K

    @property
    def Pref(self) -> np.ndarray:
        return self.design.controller.model.P

    @property
    def channels(self) -> tuple[Any, ...]:
        return self.design.estimator.channels

    @property
    def loop_key(self) -> str:
        """The combination of components the loop is compiled for, e.g. "process-kf-lqg"."""
        sc = self.scenario
        return _jit.loop_key(sc.plant, sc.estimator or self.config.estimator,
                             sc.controller or self.config.controller)


def first_rows(drive: Drive, n: int) -> Drive:
    """The draws and schedule of a run's first n control steps."""
    n_sub = drive.plant_normals.shape[0] // max(1, drive.refs.shape[0])
    return Drive(drive.plant_normals[:n * n_sub], drive.bias_normals[:n], drive.sensor_normals[:n],
                 drive.dropout[:n], drive.refs[:n], drive.heave_force[:n], drive.pset[:n])


def prepare(data: Mapping[str, Any] | Scenario, *, file: str = "<dict>", seed: int | None = None,
            vehicle: Vehicle | None = None, truth: Vehicle | None = None,
            config: DesignConfig | None = None, book: DesignBook | None = None) -> Prepared:
    """Resolve a scenario (a dict from its TOML, or a Scenario) into a runnable Prepared.

    ``vehicle`` / ``config`` replace the scenario's vehicle (the model the estimator and the
    controller use) and filter/controller configuration; ``truth`` replaces the plant's vehicle
    (by default the model vehicle with the scenario's [truth] parameters). ``book`` shares loaded
    files and designs between calls.
    """
    sc = data if isinstance(data, Scenario) else scenario_from_dict(data, file=file, seed=seed)
    book = book if book is not None else DesignBook()
    vehicle = vehicle if vehicle is not None else _load_ref(sc, "vehicle", load_vehicle, book)
    config = config if config is not None else _load_ref(sc, "design", load_design_config, book)
    design = book.design(vehicle, config, plant=sc.plant, plant_step=sc.plant_step_s,
                         estimator=sc.estimator, controller=sc.controller, file=sc.file)
    est = design.estimator
    h = est.h
    n_sub = int(round(h / sc.plant_step_s))
    if n_sub < 1 or abs(n_sub * sc.plant_step_s - h) > 1e-9 * h:
        raise ConfigError([Problem(sc.file, "plant_step_s", sc.plant_step_s,
                                   f"a step that divides the filter's sample time {h:g} s")], "scenario file")
    n_ctrl = int(math.floor(sc.duration_s / h + 1e-9)) + 1
    truth = truth if truth is not None else _truth_vehicle(vehicle, sc)
    rng = np.random.default_rng(sc.seed)

    sensors = sensor_bank(est.channels, truth, h)
    times = np.arange(n_ctrl) * h
    dropout, refs = schedule(sc, est.channels, times)
    heave, pset = disturbances(sc, times, observer=sc.plant == "observer", g=truth.gravity)

    # plant: initial state, then every draw of the run in a fixed order (rovlab.sim.loop.draw);
    # reseed() redoes exactly these draws for another seed: keep the two in step
    bias0 = sc.bias_std * rng.standard_normal(4)  # start in the stationary distribution
    plant = make_plant(design, sc, truth, n_sub, bias0)
    normals = draw(rng, n_ctrl, n_sub, plant_draws(plant), len(est.channels))
    plant_n, bias_n, sensor_n = normals
    drive = Drive(plant_n, bias_n, sensor_n, dropout, refs, heave, pset)

    alloc = design.allocator
    same = truth.thrusters is vehicle.thrusters
    bank = alloc.bank if same else ThrusterBank.from_vehicle(truth)
    B_true = alloc.B if same else Allocator(truth).B
    actuators = make_actuators(alloc, bank, B_true, sc.pwm_resolution_us, real=sc.plant == "process")
    nav_of = np.array([TRUTH_INDEX[q] for q in est.nav], dtype=np.int64)
    nees = [i for i, q in enumerate(est.nav) if sc.plant == "observer" or not q.startswith("b_")]
    return Prepared(sc, vehicle, truth, config, design, plant, sensors, actuators, drive, n_ctrl, h, nav_of,
                    np.array(nees, dtype=np.int64))


def reseed(prep: Prepared, seed: int) -> Prepared:
    """The same run with another seed: equal to ``prepare`` of the same scenario with ``seed``
    when the scenario has no distributions (rovlab.sim.scenario.has_distributions; with them,
    the scenario's own values depend on the seed: call prepare). Only what is drawn from the
    seed is redone -- the plant's initial bias and the run's draws, in prepare's order -- and
    the design, sensors, actuators, schedule and disturbances are shared with ``prep``, so a
    Monte Carlo prepares once and reseeds per run."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    sc = replace(prep.scenario, seed=int(seed))
    rng = np.random.default_rng(sc.seed)
    bias0 = sc.bias_std * rng.standard_normal(4)  # prepare's first draw, also for the observer plant
    plant = prep.plant
    if isinstance(plant, ProcessPlant):
        plant = plant._replace(bias=np.asarray(bias0, dtype=float).copy())
    plant_n, bias_n, sensor_n = draw(rng, prep.n_ctrl, plant.n_sub, plant_draws(plant), len(prep.channels))
    drive = prep.drive._replace(plant_normals=plant_n, bias_normals=bias_n, sensor_normals=sensor_n)
    return replace(prep, scenario=sc, plant=plant, drive=drive)


def sensor_bank(channels: tuple[Any, ...], truth: Vehicle, h: float) -> SensorBank:
    """The simulated sensors behind the estimator's channels, with the true vehicle's noise."""
    quantity = np.array([TRUTH_INDEX[c.quantity] for c in channels], dtype=np.int64)
    offset = np.array([c.offset for c in channels], dtype=float)
    std = np.array([math.sqrt(truth.sensor(c.sensor).variance.get(c.quantity, c.variance)) for c in channels])
    period = np.array([max(1, int(round(1.0 / (truth.sensor(c.sensor).rate_hz * h)))) for c in channels],
                      dtype=np.int64)
    angle = np.array([c.quantity == "psi" for c in channels], dtype=np.bool_)
    return SensorBank(quantity, offset, std, period, angle)


def schedule(sc: Scenario, channels: tuple[Any, ...], times: np.ndarray,
             unavailable: frozenset[str] = frozenset()) -> tuple[np.ndarray, np.ndarray]:
    """Drop-out mask (rows x channels) and references (rows x 4: x, y, z, psi) at the given times,
    from the scenario's windows and schedule; sensors in ``unavailable`` give no samples at all."""
    m = len(channels)
    dropout = np.zeros((len(times), m), dtype=np.bool_)
    known = {c.sensor for c in channels}
    problems = []
    for i, d in enumerate(sc.dropouts):
        if d.sensor not in known:
            problems.append(Problem(sc.file, f"dropout[{i}].sensor", d.sensor,
                                    "a sensor the filter uses: " + ", ".join(sorted(known))))
            continue
        cols = [j for j, c in enumerate(channels) if c.sensor == d.sensor and d.channel in (None, c.quantity)]
        if not cols:
            problems.append(Problem(sc.file, f"dropout[{i}].sensor", f"{d.sensor}.{d.channel}",
                                    "a channel the filter uses: " + ", ".join(c.name for c in channels)))
        window = (times >= d.start_s) & (times < d.end_s)
        for j in cols:
            dropout[window, j] = True
    if problems:
        raise ConfigError(problems, "scenario file")
    for j, c in enumerate(channels):
        if c.sensor in unavailable:
            dropout[:, j] = True
    idx = np.maximum(np.searchsorted(sc.reference_times, times, side="right") - 1, 0)
    ref_x, ref_y = sc.reference_xy()
    refs = np.column_stack([ref_x[idx], ref_y[idx], sc.reference_z[idx], sc.reference_psi[idx]])
    return dropout, refs


def disturbances(sc: Scenario, times: np.ndarray, *, observer: bool = False, g: float = 9.81
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per control step: the extra downward heave force [N] and the plant's parameter set (the
    number of truth events that have happened; rovlab.sim.plant). The observer plant has no
    parameter sets: its events act as a force (buoyancy and weight only)."""
    times = np.asarray(times, dtype=float)
    heave = np.zeros(len(times))
    if sc.tether.amplitude != 0.0 or sc.tether.mean != 0.0:
        heave += sc.tether.force(times)
    ev_t = np.array([e.t_s for e in sc.events], dtype=float)
    pset = np.searchsorted(ev_t, times + 1e-9, side="right").astype(np.int64)  # events at t <= t_k
    if observer and sc.events:
        net = np.concatenate([[0.0], np.cumsum([e.buoyancy_change - e.mass_change * g for e in sc.events])])
        heave -= net[pset]  # buoyancy gained pulls up (negative z)
        pset[:] = 0
    return heave, pset


def parameter_sets(truth: Vehicle, sc: Scenario) -> np.ndarray:
    """Packed parameters of the true vehicle before and after each truth event (cumulative)."""
    rows = []
    dm = db = 0.0
    problems = []
    for i, e in enumerate([None, *sc.events]):
        if e is not None:
            dm += e.mass_change
            db += e.buoyancy_change
        mass = truth.mass + dm
        if not mass > 0.0:
            problems.append(Problem(sc.file, f"truth.event[{i - 1}].mass_change", e.mass_change if e else dm,
                                    f"a change that leaves a positive mass (vehicle {truth.mass:g} kg, "
                                    f"total change {dm:g} kg)"))
            mass = truth.mass
        p = kin.pack(truth.with_updates(mass=mass) if dm else truth)
        # extra buoyancy (positive = lighter): the scenario's offset plus the events so far
        p[kin.P_BUOY] += db + sc.buoyancy_offset
        p[kin.P_GZ] += db + sc.buoyancy_offset
        p[kin.P_VC:kin.P_VC + 3] = sc.current  # the ocean current (NED), 0 unless the scenario sets one
        rows.append(p)
    if problems:
        raise ConfigError(problems, "scenario file")
    return np.ascontiguousarray(np.array(rows))


def make_plant(design: Design, sc: Scenario, truth: Vehicle, n_sub: int,
               bias0: np.ndarray) -> ProcessPlant | ObserverPlant:
    """The plant component at the scenario's initial state."""
    if design.observer_plant is not None:
        Phi_p, Delta_p, L_p = design.observer_plant
        x0 = np.array([sc.initial[2], sc.initial[3], sc.initial[6], sc.initial[7], 0.0, 0.0])
        if any(e.mass_change for e in sc.events):
            raise ConfigError([Problem(sc.file, "truth.event", "a mass_change",
                                       "buoyancy changes only: the observer plant is the linear design "
                                       "model with a fixed mass (use plant = \"process\")")], "scenario file")
        return ObserverPlant(Phi_p, Delta_p, L_p, x0, n_sub, np.empty(6), np.empty(2), np.zeros(1))
    p_sets = parameter_sets(truth, sc)
    p = p_sets[0].copy()
    phi, std = gauss_markov_coefficients(sc.bias_std**2, 1.0 / sc.bias_time_constant_s, design.estimator.h)
    return ProcessPlant(p, sc.initial.astype(float).copy(), np.asarray(bias0, dtype=float).copy(),
                        np.asarray(phi, dtype=float), np.asarray(std, dtype=float),
                        np.sqrt(sc.process_noise_psd / sc.plant_step_s), float(sc.plant_step_s), int(n_sub),
                        np.empty(4), p_sets, np.zeros(2))


def _load_ref(sc: Scenario, key: str, loader: Callable[[str], Any], book: DesignBook) -> Any:
    ref = getattr(sc, key)
    try:
        return book.load(loader, ref)
    except ConfigError as exc:
        # say which scenario key pointed there
        raise ConfigError([Problem(sc.file, key, ref, f"a loadable {key}: {p}") for p in exc.problems],
                          "scenario file") from None


def _truth_vehicle(vehicle: Vehicle, sc: Scenario) -> Vehicle:
    tp = dict(sc.truth_parameters)
    if not tp:
        return vehicle
    changes: dict[str, Any] = {}
    for key in ("mass", "I_zz", "displaced_volume"):
        if key in tp:
            changes[key] = tp[key]
    added = vehicle.added_mass.copy()
    for i, key in enumerate(("X_udot", "Y_vdot", "Z_wdot", "N_rdot")):
        if key in tp:
            added[i] = tp[key]
    changes["added_mass"] = added
    return vehicle.with_updates(**changes)


# --------------------------------------------------------------------------------------------
# Running: the one call site of the compiled loop
# --------------------------------------------------------------------------------------------

class PlantDiverged(RuntimeError):
    """The plant's true state stopped being finite: its parameters or forces are absurd."""

    def __init__(self, t: float, logs: Logs, rows: int) -> None:
        super().__init__(f"the plant diverged at t = {t:g} s (its true state is no longer finite): check the "
                         "vehicle's and the scenario's parameters (masses, damping, disturbances)")
        self.t = t
        self.logs = logs  # rows 0 .. rows-1 are valid
        self.rows = rows


class Simulation:
    """The components of one run, advanced chunk by chunk through the compiled loop.

    Holds its own copies of the plant's, the estimator's and the controller's state, so a
    Prepared can be run many times. ``advance(drive)`` runs len(drive.refs) control steps.
    """

    def __init__(self, prep: Prepared) -> None:
        self.prep = prep
        self.plant = fresh(prep.plant)
        self.estimator = fresh(prep.design.estimator.kernel)
        self.controller = fresh(prep.design.controller.kernel)
        self.work = new_work(len(prep.channels), prep.nees_idx.shape[0], prep.actuators.rows.shape[0])
        self.k = 0

    def components(self) -> dict[str, Any]:
        """The stateful components by slot (for saving/restoring state, rovlab.core.components)."""
        return {"plant": self.plant, "estimator": self.estimator, "controller": self.controller}

    def loop_arguments(self, drive: Drive | None = None) -> tuple[Any, ...]:
        """run_loop's arguments after (k0, k1, h) for a chunk driven by ``drive`` (default: the
        whole run), with new logs for it."""
        prep = self.prep
        drive = prep.drive if drive is None else drive
        logs = new_logs(drive.refs.shape[0], len(prep.channels), self.estimator.x.shape[0],
                        prep.actuators.rows.shape[0], self.controller.state.shape[0])
        return (self.plant, prep.sensors, self.estimator, self.controller, prep.actuators, prep.nav_of,
                prep.nees_idx, drive, logs, self.work)

    def advance(self, drive: Drive) -> Logs:
        """Run len(drive.refs) control steps (the loop is compiled, or loaded from numba's cache,
        on the first call of a process for its combination of components)."""
        prep = self.prep
        n = drive.refs.shape[0]
        args = self.loop_arguments(drive)
        logs = args[_LOGS]
        loop = loop_for(self.plant, self.estimator, self.controller)
        with explain_allocation((self.plant, self.estimator, self.controller)):
            done = loop(self.k, self.k + n, prep.h, *args)
        if loop is run_loop:  # in numba's cache now: commands need not say they compile it next time
            note_cached(prep.loop_key)
        self.k += done
        if done < n:
            raise PlantDiverged(self.k * prep.h, logs, done)
        return logs


_LOGS = 8  # position of the logs in Simulation.loop_arguments


def shipped_components(prep: Prepared) -> bool:
    """Whether every component of a prepared run is rovlab's own (its loop is in numba's disk
    cache; components from outside rovlab are compiled in every process)."""
    return loop_for(prep.plant, prep.design.estimator.kernel, prep.design.controller.kernel) is run_loop


def compile_loop(prep: Prepared) -> float:
    """Compile the loop for a prepared run's components (or load it from numba's cache) by running
    its first control step on a copy of its components; returns the seconds it took."""
    t0 = time.perf_counter()
    Simulation(prep).advance(first_rows(prep.drive, 1))
    seconds = time.perf_counter() - t0
    if shipped_components(prep):
        record(prep.loop_key, seconds)
    return seconds


def columns(prep: Prepared, logs: Logs, times: np.ndarray, refs: np.ndarray) -> dict[str, np.ndarray]:
    """The named time-series columns of a chunk of logs (timeseries.csv, the HMI's stream)."""
    est, ctl = prep.design.estimator, prep.design.controller
    cols: dict[str, np.ndarray] = {"time_s": times}
    for s, i in zip(est.states, prep.nav_of):
        cols[f"true_{s}"] = logs.truth[:, i]
    for i, s in enumerate(est.states):
        cols[f"est_{s}"] = logs.x[:, i]
    for j, c in enumerate(est.channels):
        cols[f"meas_{c.column}"] = logs.y[:, j]
    for r in ctl.references:
        cols[f"ref_{r}"] = refs[:, ["x", "y", "z", "psi"].index(r)]
    for o in ctl.outputs:
        cols[f"tau_{o}"] = logs.wrench[:, "XYZN".index(o)]
    for i, name in enumerate(prep.allocator.bank.names):
        cols[f"pwm_{name}"] = logs.pwm[:, i]
    for i, s in enumerate(est.states):
        cols[f"var_{s}"] = logs.P[:, i, i]
    for j, c in enumerate(est.channels):
        cols[f"status_{c.column}"] = logs.status[:, j]
    for o in ctl.outputs:
        cols[f"tau_{o}_demanded"] = logs.wrench[:, 4 + "XYZN".index(o)]
    for i, s in enumerate(ctl.state_names):
        cols[f"ctrl_{s}"] = logs.ctrl[:, i]
    return cols


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SimResult:
    """Logs of one run (rows at the control rate) and what is needed to read them."""

    scenario: Scenario
    columns: dict[str, np.ndarray]  # the time-series contract (timeseries.csv)
    P: np.ndarray  # (K, n, n) corrected covariances
    nees: np.ndarray  # (K,) NEES of the states in nees_states
    nees_states: tuple[str, ...]
    nis: np.ndarray  # (K,) NIS per used measurement (NaN when none was used)
    channels: tuple[str, ...]
    thrusters: tuple[str, ...]
    meta: dict[str, Any]
    reason: np.ndarray | None = None  # (K, m) why each channel is lost/off (fusion REASON_*)

    def status_codes(self) -> dict[str, np.ndarray]:
        """status_<column> as one code per sample for status and reason
        (rovlab.estimation.fusion.status_code: 4 lost-timeout ... 8 lost-stuck)."""
        from rovlab.estimation.fusion import STATUS_LOST

        out = {}
        for j, name in enumerate(k for k in self.columns if k.startswith("status_")):
            s = np.asarray(self.columns[name], dtype=float)
            r = self.reason[:, j] if self.reason is not None else np.zeros(len(s))
            out[name] = np.where((s == STATUS_LOST) & (r >= 1) & (r <= 5), 3 + r, s)
        return out

    def status_words(self) -> dict[str, list[str]]:
        """status_<column> as words ('ok', 'recovering', 'lost-timeout', 'lost-gate', 'off' ...),
        the same words `rovlab filter` writes."""
        from rovlab.estimation.fusion import status_label

        out = {}
        for j, name in enumerate(k for k in self.columns if k.startswith("status_")):
            codes = self.columns[name]
            reasons = self.reason[:, j] if self.reason is not None else np.zeros(len(codes))
            cache: dict[tuple[int, int], str] = {}
            out[name] = [cache.setdefault((int(s), int(r)), status_label(int(s), int(r)))
                         for s, r in zip(codes.tolist(), reasons.tolist())]
        return out


def run_prepared(prep: Prepared) -> SimResult:
    """Run a prepared scenario from its start to its end."""
    started = time.time()
    return result_of(prep, Simulation(prep).advance(prep.drive), started)


def result_of(prep: Prepared, logs: Logs, started: float) -> SimResult:
    """The result of a whole run from its logs; ``started`` is the wall clock of its start [s]."""
    result = _result(prep, logs)
    result.meta["start_time_unix_s"] = started  # wall clock of the run's start (log times)
    return result


def _result(prep: Prepared, logs: Logs) -> SimResult:
    sc = prep.scenario
    est = prep.design.estimator
    t = np.arange(prep.n_ctrl) * prep.h
    cols = columns(prep, logs, t, prep.drive.refs)
    nees = logs.cons[:, 2]
    nis_sum, used = logs.cons[:, 0], logs.cons[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        nis = np.where(used > 0, nis_sum / np.maximum(used, 1), np.nan)
    meta = {
        "scenario": sc.name, "seed": sc.seed, "plant": sc.plant, "vehicle": prep.vehicle.name,
        "design": prep.config.name, "title": f"{sc.name} (seed {sc.seed})",
        "estimator": sc.estimator or prep.config.estimator, "controller": sc.controller or prep.config.controller,
        "dropouts": [{"sensor": d.sensor + (f".{d.channel}" if d.channel else ""), "start_s": d.start_s,
                      "end_s": d.end_s} for d in sc.dropouts],
        "channels": [c.name for c in est.channels], "thrusters": list(prep.allocator.bank.names),
        "measurement_offsets": {f"meas_{c.column}": c.offset for c in est.channels},
        "sample_time_s": prep.h, "plant_step_s": sc.plant_step_s,
    }
    return SimResult(sc, cols, logs.P, nees, tuple(est.states[i] for i in prep.nees_idx), nis,
                     tuple(c.name for c in est.channels), tuple(prep.allocator.bank.names), meta, logs.reason)


def simulate(name_or_path: str, *, seed: int | None = None) -> SimResult:
    """Load a scenario (packaged name or TOML path), run it and return the logs."""
    from rovlab.sim.scenario import load_scenario

    return run_prepared(prepare(load_scenario(name_or_path, seed=seed)))


def summarise(result: SimResult) -> dict[str, Any]:
    """metrics.json of one run (Sandøy 2016, sec. 5.3.1): RMS error per state, step response per axis,
    drop-out drift and NEES/NIS consistency."""
    c = result.columns
    sc = result.scenario
    t = c["time_s"]
    out: dict[str, Any] = {"scenario": sc.name, "seed": sc.seed, "plant": sc.plant}
    # the depth-and-heading quantities the estimator estimates (every shipped one does; a plugin may not)
    n = len(t)
    states = [q for q in ("z", "psi", "w", "r") if f"est_{q}" in c and f"true_{q}" in c]
    error = {q: mx.estimation_error(np.column_stack([c[f"est_{q}"]]), np.column_stack([c[f"true_{q}"]]),
                                    angle_columns=(0,) if q == "psi" else ())[:, 0] for q in states}
    out["rms_error"] = {q: float(mx.rms(error[q])) for q in states}
    if sc.plant == "observer" and "est_b_w" in c and "est_b_r" in c:
        eb = np.column_stack([c["est_b_w"] - c["true_b_w"], c["est_b_r"] - c["true_b_r"]])
        out["rms_error"].update(dict(zip(("b_w", "b_r"), map(float, mx.rms(eb)))))
    # steps of the reference schedule, per axis, judged on the true state
    steps = []
    prev_z, prev_psi = sc.initial[2], sc.initial[3]
    times = list(sc.reference_times) + [sc.duration_s + 1.0]
    for i, t0 in enumerate(sc.reference_times):
        t1 = times[i + 1]
        z1, psi1 = float(sc.reference_z[i]), float(sc.reference_psi[i])
        if abs(z1 - prev_z) > 1e-12 and "true_z" in c:
            r = mx.step_response(t, c["true_z"], t0, prev_z, z1, t1, band=0.02, min_band=0.005)
            steps.append({"axis": "z", **r})
        if abs(mx.wrap(psi1 - prev_psi)) > 1e-12 and "true_psi" in c:
            r = mx.step_response(t, c["true_psi"], t0, prev_psi, psi1, t1, band=0.02, min_band=math.radians(0.5),
                                 angle=True)
            steps.append({"axis": "psi", **r})
        prev_z, prev_psi = z1, psi1
    out["steps"] = steps
    out["settling_time_s"] = {}
    out["overshoot"] = {}
    for axis in ("z", "psi"):
        mine = [s for s in steps if s["axis"] == axis]
        if mine:
            st = [s["settling_time_s"] for s in mine]
            out["settling_time_s"][axis] = None if any(v is None for v in st) else max(st)
            out["overshoot"][axis] = max(s["overshoot"] or 0.0 for s in mine)
    # drop-outs: what dead reckoning costs, measured honestly: the "before" window starts after
    # the start-up has settled, the recovery is judged on psi_hat, r_hat and tau_N
    coded = {**c, **result.status_codes()}
    drops = []
    for d, rec in zip(sc.dropouts, mx.dropout_metrics(coded, result.meta["dropouts"])):
        w = (t >= d.start_s) & (t < d.end_s)
        if not w.any():
            continue
        e_psi = error.get("psi", np.full(n, np.nan))
        i0 = int(np.argmax(w))
        i1 = int(len(w) - 1 - np.argmax(w[::-1]))
        drops.append({
            **rec,
            "heading_drift_rad": float(e_psi[i1] - e_psi[i0]),
            "heading_error_max_rad": float(np.max(np.abs(e_psi[w]))),
            "heading_error_rms_before": rec["before"].get("psi"),
            "depth_error_rms_before": rec["before"].get("z"),
            "depth_error_rms_during": float(mx.rms(error["z"][w])) if "z" in error else None,
        })
    out["dropouts"] = drops
    events = mx.sensor_loss_events(coded, dropouts=result.meta["dropouts"])
    out["sensor_losses"] = {**mx.loss_event_counts(events), "events": events}
    # consistency: NEES of the corrected estimate, NIS per used measurement
    out["nees"] = {"states": list(result.nees_states), **mx.consistency(result.nees, len(result.nees_states))}
    out["nis"] = mx.consistency(result.nis, 1)
    if "est_x" in c:  # a 4-DOF estimate (e.g. estimator "ekf"): the planar and dynamic-positioning numbers
        out.update(mx.positioning_metrics(c, result.meta["dropouts"], observer=sc.plant == "observer"))
    return out
