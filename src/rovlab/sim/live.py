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
from typing import Any, Mapping

import numpy as np

from rovlab.estimation.fusion import CH_MODE, MODE_AUTO, MODE_OFF, MODE_ON, new_channel_state
from rovlab.io.messages import row_messages
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle
from rovlab.sim.runner import Prepared, closed_loop, prepare
from rovlab.sim.scenario import Scenario, load_scenario

_MODES = {"auto": MODE_AUTO, "off": MODE_OFF, "on": MODE_ON}
_STATE_KEYS = ("xp", "bias", "xo", "xf", "Pf", "chs")


class LiveSimulation:
    """A scenario advanced on demand. Not thread-safe: drive it from one thread (or task)."""

    def __init__(self, scenario: str | Scenario, *, seed: int | None = None, vehicle: Vehicle | None = None,
                 truth: Vehicle | None = None, config: DesignConfig | None = None) -> None:
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario, seed=seed)
        self._seed = self.scenario.seed if seed is None else seed
        self._overrides = {"vehicle": vehicle, "truth": truth, "config": config}
        self.reset()

    # -- lifecycle ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scenario's initial state (parameters changed so far are kept)."""
        self.prep = _prepare(self.scenario, **self._overrides)
        self.state = {k: np.array(self.prep.arrays[k], copy=True) for k in _STATE_KEYS}
        self.k = 0
        self.rng = np.random.default_rng(self._seed)
        self.reference = self.scenario.reference_at(0.0)
        self.reference_follows_scenario = True
        self.sensor_available = {c.sensor: True for c in self.prep.filter_model.channels}

    @property
    def h(self) -> float:
        return float(self.prep.arrays["h"])

    @property
    def time(self) -> float:
        """Time of the next control step [s]."""
        return self.k * self.h

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.prep.filter_model.channels)

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
    def set_reference(self, z: float | None = None, psi: float | None = None) -> None:
        """New depth [m] and/or heading [rad] set-point (stops following the scenario's schedule)."""
        for name, v in (("z", z), ("psi", psi)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"reference {name} must be a finite number, got {v!r}")
        zr, pr = self.reference
        self.reference = (float(z) if z is not None else zr, float(psi) if psi is not None else pr)
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
        self.state["chs"][self.channels.index(channel), CH_MODE] = _MODES[mode]

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        """Swap in a new model vehicle, plant truth and/or configuration, keeping the state.

        Raises ConfigError (and changes nothing) if the design fails, e.g. an unobservable sensor set.
        """
        overrides = dict(self._overrides)
        for key, value in (("vehicle", vehicle), ("truth", truth), ("config", config)):
            if value is not None:
                overrides[key] = value
        new = _prepare(self.scenario, **overrides)  # raises before anything changes
        old_channels = self.channels
        self.prep = new
        self._overrides = overrides
        if self.channels != old_channels:
            modes = {name: self.state["chs"][j, CH_MODE] for j, name in enumerate(old_channels)}
            chs = new_channel_state(len(self.channels))
            for j, name in enumerate(self.channels):
                chs[j, CH_MODE] = modes.get(name, MODE_AUTO)
            self.state["chs"] = chs
            self.sensor_available = {c.sensor: self.sensor_available.get(c.sensor, True)
                                     for c in new.filter_model.channels}
        # the truth's parameters changed: its packed vector is in the new arrays already

    # -- running -----------------------------------------------------------------------------
    def advance(self, n: int = 1) -> list[tuple[str, float, dict[str, Any]]]:
        """Run n control steps; returns their messages (topic, time, message) in order."""
        if n < 1:
            return []
        a = self.prep.arrays
        m = len(self.channels)
        nt = a["rows"].shape[0]
        n_sub = a["n_sub"]
        k0 = self.k
        refs = np.empty((n, 2))
        for i in range(n):
            refs[i] = self.scenario.reference_at((k0 + i) * self.h) if self.reference_follows_scenario \
                else self.reference
        if self.reference_follows_scenario:
            self.reference = tuple(refs[-1])
        dropout = np.zeros((n, m), dtype=np.bool_)
        for j, c in enumerate(self.prep.filter_model.channels):
            if not self.sensor_available.get(c.sensor, True):
                dropout[:, j] = True
        times = (k0 + np.arange(n)) * self.h
        for d in self.scenario.dropouts:
            w = (times >= d.start_s) & (times < d.end_s)
            for j, c in enumerate(self.prep.filter_model.channels):
                if c.sensor == d.sensor and d.channel in (None, c.quantity):
                    dropout[w, j] = True
        observer = a["plant_kind"] == 1
        f32 = np.float32  # plant noise draws in single precision, as in rovlab.sim.runner.prepare
        plant_normals = np.zeros((0, 4), f32) if observer else self.rng.standard_normal((n * n_sub, 4), dtype=f32)
        obs_normals = self.rng.standard_normal((n * n_sub, 6), dtype=f32) if observer else np.zeros((0, 6), f32)
        bias_normals = self.rng.standard_normal((n, 4))
        sensor_normals = self.rng.standard_normal((n, m))
        logs = dict(
            log_true=np.empty((n, 4)), log_y=np.empty((n, m)), log_x=np.empty((n, 6)), log_P=np.empty((n, 6, 6)),
            log_u=np.empty((n, 4)), log_pwm=np.empty((n, nt)), log_status=np.empty((n, m)),
            log_cons=np.empty((n, 3)), log_bias=np.zeros((n, 4)),
        )
        st = self.state
        closed_loop(
            k0, k0 + n, a["h"], n_sub, a["h_plant"], a["plant_kind"],
            a["p_truth"], st["xp"], a["noise_std"], plant_normals, st["bias"], a["bias_phi"], a["bias_std"],
            bias_normals, a["Phi_p"], a["Delta_p"], a["L_p"], st["xo"], obs_normals,
            a["ch_quantity"], a["ch_offset"], a["ch_std"], a["ch_period"], dropout, sensor_normals,
            a["fmodel"], st["xf"], st["Pf"], st["chs"], a["K"], a["Pref"], refs,
            a["B"], a["T"], a["s_alloc"], a["f_min"], a["f_max"], a["level"], a["n_levels"], a["rows"],
            a["grid_pwm"], a["grid_force"], a["pwm_res"],
            logs["log_true"], logs["log_y"], logs["log_x"], logs["log_P"], logs["log_u"], logs["log_pwm"],
            logs["log_status"], logs["log_cons"], logs["log_bias"],
        )
        self.k = k0 + n
        cols = _columns(self.prep, logs, times, refs)
        out = []
        for i in range(n):
            out.extend(row_messages(cols, i))
        self.last_columns = cols
        return out


def _columns(prep: Prepared, logs: Mapping[str, np.ndarray], times: np.ndarray, refs: np.ndarray) -> dict:
    fm = prep.filter_model
    cols: dict[str, np.ndarray] = {"time_s": times}
    for i, s in enumerate(("z", "psi", "w", "r")):
        cols[f"true_{s}"] = logs["log_true"][:, i]
    if prep.scenario.plant == "observer":
        cols["true_b_w"] = logs["log_bias"][:, 2]
        cols["true_b_r"] = logs["log_bias"][:, 3]
    for i, s in enumerate(fm.states):
        cols[f"est_{s}"] = logs["log_x"][:, i]
        cols[f"var_{s}"] = logs["log_P"][:, i, i]
    for j, c in enumerate(fm.channels):
        cols[f"meas_{c.column}"] = logs["log_y"][:, j]
        cols[f"status_{c.column}"] = logs["log_status"][:, j]
    cols["ref_z"] = refs[:, 0]
    cols["ref_psi"] = refs[:, 1]
    cols["tau_Z"] = logs["log_u"][:, 0]
    cols["tau_N"] = logs["log_u"][:, 1]
    for i, name in enumerate(prep.allocator.bank.names):
        cols[f"pwm_{name}"] = logs["log_pwm"][:, i]
    return cols


def _prepare(sc: Scenario, *, vehicle: Vehicle | None, truth: Vehicle | None, config: DesignConfig | None) -> Prepared:
    """prepare() for a live run: long horizon, optional vehicle/truth/config objects."""
    from dataclasses import replace

    live = replace(sc, duration_s=0.0)  # live runs have no fixed length; noise is drawn per chunk
    return prepare(live, vehicle=vehicle, truth=truth, config=config)
