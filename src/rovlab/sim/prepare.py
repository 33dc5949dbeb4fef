"""Preparing a run: a scenario resolved into a :class:`Prepared` run -- the model vehicle, the
plant's truth, the designed estimator and controller (rovlab.sim.designs), the plant, sensors and
actuators as components, the reference schedule, drop-outs and disturbances, and every random
draw of the run made from its seed. :func:`reseed` redoes only the draws for another seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rovlab import _jit
from rovlab.allocation.solvers import Allocator
from rovlab.core.components import (
    TRUTH_INDEX,
    plant_draws,
)
from rovlab.models import kinetics as kin
from rovlab.models.noise import gauss_markov_coefficients
from rovlab.models.sensors import SensorBank
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.design import DesignConfig, load_design_config
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle, load_vehicle
from rovlab.sim.actuators import Actuators, make_actuators
from rovlab.sim.designs import Design, DesignBook
from rovlab.sim.loop import Drive, draw
from rovlab.sim.plant import ObserverPlant, ProcessPlant
from rovlab.sim.scenario import Scenario, scenario_from_dict


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
    # the dead band's hysteresis protects real ESCs: the observer plant (the thesis's perfect model) has none
    actuators = make_actuators(alloc, bank, B_true, sc.pwm_resolution_us, real=sc.plant == "process",
                               hold_us=None if sc.plant == "process" else 0.0)
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


