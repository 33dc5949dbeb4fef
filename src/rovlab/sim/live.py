"""A closed-loop simulation run step by step, with its parameters changed while it runs.

This is what the HMI drives (and what a test or a notebook can drive): the same compiled loop as
:func:`rovlab.sim.runner.run_prepared`, advanced a few control steps at a time, publishing the
messages of :mod:`rovlab.io.messages` -- the ones a real vehicle's bridge publishes -- so a
client cannot tell it from a vehicle (except that the simulation also publishes its truth).

Changes take effect between steps and never break the running loop: a new vehicle (the
model the filter and controller use), a new plant truth, or a new filter/controller
configuration is validated and designed first (Phi, Q, LQR gains ...); only if that succeeds is it
swapped in, keeping the vehicle's state, the filter's estimate and covariance (and the sensor
management state while the channel set is unchanged).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from rovlab.core.components import plant_draws, restore, state_of
from rovlab.estimation.fusion import CH_MODE, MODE_AUTO, MODE_OFF, MODE_ON, new_channel_state
from rovlab.io.messages import rows_to_messages
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle
from rovlab.sim.designs import DesignBook
from rovlab.sim.loop import Drive, draw
from rovlab.sim.prepare import Prepared, disturbances, prepare, schedule
from rovlab.sim.results import columns
from rovlab.sim.runner import Simulation
from rovlab.sim.scenario import Scenario, load_scenario

_MODES = {"auto": MODE_AUTO, "off": MODE_OFF, "on": MODE_ON}


class LiveSimulation:
    """A scenario advanced on demand. Not thread-safe: drive it from one thread (or task).

    The live run uses the batch run's components, loop and columns; N steps advanced in one
    chunk give exactly the batch run of the same seed (in several chunks the noise is drawn
    chunk by chunk, so the sample paths differ while the statistics do not).
    """

    def __init__(self, scenario: str | Scenario, *, seed: int | None = None, vehicle: Vehicle | None = None,
                 truth: Vehicle | None = None, config: DesignConfig | None = None) -> None:
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario, seed=seed)
        self._seed = self.scenario.seed if seed is None else seed
        self._overrides: dict[str, Any] = {"vehicle": vehicle, "truth": truth, "config": config}
        self._book = DesignBook()
        self.reset()

    # -- lifecycle ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scenario's initial state (parameters changed so far are kept)."""
        self.prep = _prepare(self.scenario, self._book, **self._overrides)
        self.sim = Simulation(self.prep)
        self.rng = np.random.default_rng(self._seed)
        self.rng.standard_normal(4)  # the initial bias draw, as in rovlab.sim.prepare.prepare
        self.reference = self.scenario.reference_at(0.0)
        rx, ry = self.scenario.reference_xy()
        self.reference_xy = (float(rx[0]), float(ry[0]))  # north, east set-point [m] (position controllers)
        self.reference_follows_scenario = True
        self.sensor_available = {c.sensor: True for c in self.prep.channels}

    @property
    def k(self) -> int:
        """Index of the next control step."""
        return self.sim.k

    @property
    def state(self) -> dict[str, np.ndarray]:
        """The live state arrays by name (the estimator's channel states as ``chs``)."""
        est = self.sim.estimator
        return {"x": est.x, "P": est.P, "chs": est.ch}

    @property
    def h(self) -> float:
        return float(self.prep.h)

    @property
    def time(self) -> float:
        """Time of the next control step [s]."""
        return self.k * self.h

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.prep.channels)

    @property
    def vehicle(self) -> Vehicle:
        return self.prep.vehicle

    @property
    def truth(self) -> Vehicle:
        return self.prep.truth

    @property
    def config(self) -> DesignConfig:
        return self.prep.config

    # -- commands ----------------------------------------------------------------------------
    def set_reference(self, z: float | None = None, psi: float | None = None, *, x: float | None = None,
                      y: float | None = None) -> None:
        """New depth [m], heading [rad] and/or north/east position [m] set-point (stops following the
        scenario's schedule; x and y matter to position controllers such as "dp")."""
        for name, v in (("z", z), ("psi", psi), ("x", x), ("y", y)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"reference {name} must be a finite number, got {v!r}")
        if z is not None and z < 0:
            raise ValueError(f"reference depth z must be >= 0 m (the free surface is z = 0), got {z!r}")
        zr, pr = self.reference
        self.reference = (float(z) if z is not None else zr, float(psi) if psi is not None else pr)
        xr, yr = self.reference_xy
        self.reference_xy = (float(x) if x is not None else xr, float(y) if y is not None else yr)
        self.reference_follows_scenario = False

    def set_sensor_available(self, sensor: str, available: bool) -> None:
        """Simulate a sensor dropping out (no samples) or coming back."""
        if sensor not in self.sensor_available:
            raise ValueError(f"unknown sensor {sensor!r}; the filter uses {', '.join(self.sensor_available)}")
        self.sensor_available[sensor] = bool(available)

    def set_filter_mode(self, channel: str, mode: str) -> None:
        """Force a filter channel off or on ('off', 'on') or back to automatic ('auto')."""
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
        if channel not in self.channels:
            raise ValueError(f"unknown channel {channel!r}; the filter has {', '.join(self.channels)}")
        self.sim.estimator.ch[self.channels.index(channel), CH_MODE] = _MODES[mode]

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        """Swap in a new model vehicle, plant truth and/or configuration, keeping the state.

        Every component's state (plant, estimator, controller) carries over where its shape
        still fits; the channel states follow the channels by name. Raises ConfigError (and
        changes nothing) if the design fails, e.g. an unobservable sensor set.
        """
        overrides = dict(self._overrides)
        for key, value in (("vehicle", vehicle), ("truth", truth), ("config", config)):
            if value is not None:
                overrides[key] = value
        new = _prepare(self.scenario, self._book, **overrides)  # raises before anything changes
        old_sim, old_channels = self.sim, self.channels
        sim = Simulation(new)
        sim.k = old_sim.k
        for slot, comp in old_sim.components().items():
            saved = state_of(comp)
            if slot == "estimator":
                saved.pop("ch")
            restore(sim.components()[slot], saved)
        new_channels = tuple(c.name for c in new.channels)
        old_ch = old_sim.estimator.ch
        if new_channels == old_channels:
            sim.estimator.ch[...] = old_ch
        else:
            modes = {name: old_ch[j, CH_MODE] for j, name in enumerate(old_channels)}
            chs = new_channel_state(len(new_channels))
            for j, name in enumerate(new_channels):
                chs[j, CH_MODE] = modes.get(name, MODE_AUTO)
            sim.estimator.ch[...] = chs
        self.prep, self.sim, self._overrides = new, sim, overrides
        self.sensor_available = {c.sensor: self.sensor_available.get(c.sensor, True) for c in new.channels}

    # -- running -----------------------------------------------------------------------------
    def advance(self, n: int = 1) -> list[tuple[str, float, dict[str, Any]]]:
        """Run n control steps; returns their messages (topic, time, message) in order."""
        if n < 1:
            return []
        prep = self.prep
        k0 = self.k
        times = (k0 + np.arange(n)) * self.h
        unavailable = frozenset(s for s, ok in self.sensor_available.items() if not ok)
        dropout, refs = schedule(self.scenario, prep.channels, times, unavailable)
        if self.reference_follows_scenario:
            self.reference = (float(refs[-1, 2]), float(refs[-1, 3]))
            self.reference_xy = (float(refs[-1, 0]), float(refs[-1, 1]))
        else:
            refs[:, 2], refs[:, 3] = self.reference
            refs[:, 0], refs[:, 1] = self.reference_xy
        n_sub = prep.plant.n_sub
        normals = draw(self.rng, n, n_sub, plant_draws(prep.plant), len(prep.channels))
        heave, pset = disturbances(self.scenario, times, observer=self.scenario.plant == "observer",
                                   g=prep.truth.gravity)
        plant_n, bias_n, sensor_n = normals
        logs = self.sim.advance(Drive(plant_n, bias_n, sensor_n, dropout, refs, heave, pset))
        cols = columns(prep, logs, times, refs)
        out: list[tuple[str, float, dict[str, Any]]] = list(rows_to_messages(cols))
        self.last_columns = cols
        return out


def _prepare(sc: Scenario, book: DesignBook, *, vehicle: Vehicle | None, truth: Vehicle | None,
             config: DesignConfig | None) -> Prepared:
    """prepare() for a live run: no fixed length; noise is drawn per chunk."""
    return prepare(replace(sc, duration_s=0.0), vehicle=vehicle, truth=truth, config=config, book=book)
