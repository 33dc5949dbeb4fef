"""Filter and controller configuration: a frozen, validated, closed-schema TOML file.

A configuration holds everything the depth-and-heading observer and the LQR need beyond the
vehicle file (Sandøy 2016, secs. 5.1-5.2): the sample time, optional overrides of the model parameters,
the white-noise power spectral densities W and the bias time constants, the measurement set
(which sensor channels are fused, their variances and the sensor-management settings), the
initial belief and the LQR weights. Packaged configurations live in ``params/configs``:

* ``default``: the vehicle file's own model parameters and sensor variances; motion capture z
  and psi plus pressure depth; a wide initial covariance so the filter locks on from any start.
* ``thesis``: the design values of Sandøy 2016 (secs. 5.1-5.2, appendix scripts A.3-A.4).

File format (every table is closed: unknown keys are errors; ``source`` is required). Besides the
tables below, each estimator or controller may own a table named after it (``[mrac]``, ``[ekf]``,
``[dp]``, a plugin's ``[pd]``), read by the component's own reader with this module's TableReader
(rovlab.core.components.ComponentInfo) and given to its design as ``config.table(name)``::

    name = "thesis"
    source = "where the numbers came from"
    sample_time = 0.1                      # h [s], filter and controller step
    estimator = "kf"                       # optional: the estimator component (default "kf")
    controller = "lqg"                     # optional: the controller component (default "lqg")
    pwm_hysteresis_us = 20.0               # optional: the dead band's hysteresis in the PWM commands
                                           # (0, the default: none; rovlab.sim.actuators)

    [model]                                # optional; absent keys come from the vehicle file
    source = "..."
    mass = 7.31                            # m [kg]
    I_zz = 0.16                            # [kg m^2]
    Z_wdot = -11.13                        # [kg]   (SNAME sign, <= 0)
    N_rdot = -0.1                          # [kg m^2]
    Z_w = -5.18                            # [N s/m]
    N_r = -0.06656                         # [N m s/rad]

    [process_noise]
    source = "..."
    psd = { w = 1e-2, r = 1e-8, b_w = 2e-1, b_r = 1e-3 }   # W of [w_w, w_r, w_bw, w_br]
    bias_time_per_mass = 100.0             # T = 100 M (s per kg), or:
    # bias_time_constant = { w = 1844.0, r = 26.0 }        # [s]
    thrust_uncertainty = 0.0               # optional: relative sigma of the wrench the thrusters give
                                           # for their PWM (0: known, as in the thesis's lab; a real
                                           # vehicle's log: the thrust curve at its voltage, at the
                                           # surface, on deck) -- rovlab.estimation.kalman.predict_arrays

    [initial]
    source = "..."
    state = { z = 1.05, psi_deg = 52.0 }   # missing entries are 0; keys z psi_deg w r_deg_s b_w b_r
    std = {}                               # P0 = diag(std^2), missing entries 0

    [fusion]                               # defaults for every measurement (all optional)
    timeout_s = 0.5                        # lost when no finite sample for this long
    gate_probability = 0.9999              # chi-square (1 dof) innovation gate; 1.0 = no gate
    gate_failures_to_lose = 3              # consecutive gate failures that declare a sensor lost
    startup_s = 2.5                        # no gate this long after the start (default: from the design)
    recovery_time_s = 5.0                  # a returning sensor's correction is spread over this long
                                           # (0 = abrupt return, as in the thesis)
    reacquire_after_s = 5.0                # re-admit a gate-lost sensor that disagrees this long
                                           # (unless a redundant sensor confirms the prediction)
    stuck_window_s = 1.0                   # variance check over blocks this long; 0 = off
    maneuver_acceleration = 1.0            # m/s^2 (rad/s^2 for headings): how fast a change the model
                                           # missed may pull the truth away; 0 = no such allowance

(The former ``recovery_variance_factor`` is refused: a returning sensor is now under-weighted
relative to the filter's own prior variance, see rovlab.estimation.fusion.)

    [[measurements]]
    sensor = "qualisys"                    # a sensor name of the vehicle file, or kind = "..."
    quantity = "z"                         # z, psi, w or r
    variance = 1.987803e-09                # optional; default: the vehicle file's variance
    # any [fusion] key may be overridden here

    [lqr]
    source = "..."
    state_max = { z = 1.5, psi_deg = 30.0, w = 0.5, r_deg_s = 1.8 }   # Bryson's rule, or
    input_max = { Z = 10.0, N = 0.031415926535897934 }
    input_weight = { Z = 0.1, N = 0.01 }   # optional multipliers (state_weight likewise)
    # Q_diag = [...4...]  R_diag = [...2...]   # explicit weights instead of Bryson's rule
    reference_gain = "discrete"            # or "continuous" (what the thesis computed)

    [mrac] / [ekf] / [dp] / a plugin's [pd]   # optional: a component's own table, documented
                                           # in its module (rovlab.control.mrac, rovlab.estimation.ekf,
                                           # rovlab.control.dp) and in docs/mrac.md, docs/dp.md

A measurement's quantity is one the estimator can fuse (ComponentInfo.measurable: with
``estimator = "ekf"`` also x, y, u or v, motion capture position and DVL velocity).
Units are SI and radians, except keys ending in ``_deg`` / ``_deg_s``
(degrees, degrees/s).
This module only reads and checks the file; the maths lives in ``rovlab.estimation`` and
``rovlab.control``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.components import KINDS, component, component_names, load_failure, unknown_component
from rovlab.core.weights import bryson_diagonal
from rovlab.params.validate import Collector, ConfigError, PackagedFiles, Problem, TableReader, read_toml
from rovlab.params.vehicle import PLAUSIBLE, SENSOR_CHANNELS, Sensor, Vehicle

OBSERVER_STATES = ("z", "psi", "w", "r", "b_w", "b_r")
CONTROL_STATES = ("z", "psi", "w", "r")
INPUTS = ("Z", "N")
MEASURABLE = ("z", "psi", "w", "r")  # quantities the depth-and-heading model can fuse
MODEL_KEYS = ("mass", "I_zz", "Z_wdot", "N_rdot", "Z_w", "N_r")
PSD_KEYS = ("w", "r", "b_w", "b_r")
_DEG = math.pi / 180.0
# state key in files -> (state index, factor to SI)
_STATE_KEYS = {"z": (0, 1.0), "psi_deg": (1, _DEG), "w": (2, 1.0), "r_deg_s": (3, _DEG),
               "b_w": (4, 1.0), "b_r": (5, 1.0)}
_LQR_STATE_KEYS = {"z": (0, 1.0), "psi_deg": (1, _DEG), "w": (2, 1.0), "r_deg_s": (3, _DEG)}
# Plausibility outside the vehicle file's ranges (issue 15: a sample time of 1e-7 s meant 1e6
# predictions per logged row; a bias time of 5e-324 s per kg a ValueError deep in the design).
SAMPLE_TIME_RANGE = (1e-3, 10.0)  # h [s]: 1 kHz .. 0.1 Hz
BIAS_TIME_PER_MASS_RANGE = (1e-3, 1e5)  # [s/kg]: the thesis uses 100
BIAS_TIME_RANGE = (0.1, 1e8)  # T_w, T_r [s]
PSD_RANGE = (0.0, 1e6)  # white-noise spectral densities, SI
# Plausible initial states and standard deviations per state key of a design file, in the file's
# units (the KF's [initial] and a component's initial_state / initial_std tables): the [initial]
# ranges, extended to the 4-DOF states
STATE_KEY_RANGES: dict[str, tuple[float, float]] = {
    "x": (-1e4, 1e4), "y": (-1e4, 1e4), "z": (-1e4, 1e4), "psi_deg": (-720.0, 720.0),
    "u": (-10.0, 10.0), "v": (-10.0, 10.0), "w": (-10.0, 10.0), "r_deg_s": (-720.0, 720.0),
    "b_X": (-1e4, 1e4), "b_Y": (-1e4, 1e4), "b_Z": (-1e4, 1e4), "b_N": (-1e3, 1e3),
    "b_w": (-1e4, 1e4), "b_r": (-1e3, 1e3),
}
_STATE_RANGES = {k: STATE_KEY_RANGES[k] for k in _STATE_KEYS}  # the KF's [initial]
_MODEL_RANGES = {"mass": PLAUSIBLE["mass"], "I_zz": PLAUSIBLE["I_zz"], "Z_wdot": PLAUSIBLE["added_mass"],
                 "N_rdot": PLAUSIBLE["added_mass"], "Z_w": PLAUSIBLE["damping_linear"],
                 "N_r": PLAUSIBLE["damping_linear"]}


@dataclass(frozen=True)
class FusionSettings:
    """Sensor management of one measurement channel (see rovlab.estimation.fusion)."""

    timeout_s: float | None = None  # None: 5 sample periods of the sensor's rate_hz
    gate_probability: float = 0.9999
    gate_failures_to_lose: int = 3
    startup_s: float | None = None  # None: computed from the design (estimation.model.startup_time)
    recovery_time_s: float = 5.0
    reacquire_after_s: float = 5.0
    stuck_window_s: float = 1.0
    maneuver_acceleration: float = 1.0


@dataclass(frozen=True)
class MeasurementConfig:
    """One fused channel: a quantity of a sensor picked by name or by kind."""

    quantity: str
    sensor: str | None  # vehicle sensor name
    kind: str | None  # or the first vehicle sensor of this kind
    variance: float | None  # None: the vehicle file's variance for this channel
    fusion: FusionSettings
    key: str  # where it was read, e.g. "measurements[1]" (for error messages)
    source: str = ""

    def resolve(self, vehicle: Vehicle, file: str = "") -> Sensor:
        """The vehicle's sensor this measurement refers to (ConfigError naming ``file`` if absent)."""
        if self.sensor is not None:
            for s in vehicle.sensors:
                if s.name == self.sensor:
                    return s
            names = ", ".join(s.name for s in vehicle.sensors) or "none"
            raise ConfigError([Problem(file, f"{self.key}.sensor", self.sensor,
                                       f"a sensor of vehicle {vehicle.name!r} ({names})")],
                              "filter configuration")
        for s in vehicle.sensors:
            if s.kind == self.kind:
                return s
        kinds = ", ".join(sorted({s.kind for s in vehicle.sensors})) or "none"
        raise ConfigError([Problem(file, f"{self.key}.kind", self.kind,
                                   f"a sensor kind present on vehicle {vehicle.name!r} ({kinds})")],
                          "filter configuration")


@dataclass(frozen=True, eq=False)
class DesignConfig:
    """A validated filter/controller configuration (SI units, radians)."""

    name: str
    description: str
    sample_time: float  # h [s]
    model_overrides: Mapping[str, float]  # subset of MODEL_KEYS
    psd: np.ndarray  # W diagonal for [w_z, w_psi, w_w, w_r, w_bw, w_br] (first two are 0)
    bias_time_per_mass: float | None  # T = factor * M, or
    bias_time_constant: tuple[float, float] | None  # (T_w, T_r) [s]
    measurements: tuple[MeasurementConfig, ...]
    initial_state: np.ndarray  # x0 (6)
    initial_std: np.ndarray  # sqrt(diag P0) (6)
    lqr_Q: np.ndarray  # diagonal (4) of the state weight
    lqr_R: np.ndarray  # diagonal (2) of the input weight
    lqr_bryson: Mapping[str, np.ndarray] | None  # state_max, input_max, state_weight, input_weight
    reference_gain: str  # "discrete" | "continuous"
    sources: Mapping[str, str] = field(default_factory=dict)
    file: str = ""
    estimator: str = "kf"  # the estimator component (rovlab.core.components.component)
    controller: str = "lqg"  # the controller component
    tables: Mapping[str, Any] = field(default_factory=dict)  # the components' tables the file has, parsed
    thrust_uncertainty: float = 0.0  # relative sigma of the thrusters' wrench ([process_noise])
    pwm_hysteresis_us: float = 0.0  # the dead band's hysteresis of the PWM commands [us] (rovlab.sim.actuators)

    def table(self, name: str) -> Any:
        """The component ``name``'s table ([mrac], [ekf], [dp], a plugin's [pd] ...) as parsed from
        this file, or the component's default when the file has none (rovlab.core.components)."""
        if name in self.tables:
            return self.tables[name]
        for kind in KINDS:
            info = component(kind, name)
            if info is not None and info.default_table is not None:
                return info.default_table()
        raise KeyError(f"no component {name!r} has a table in design files")

    def with_table(self, name: str, value: Any) -> DesignConfig:
        """This configuration with the component ``name``'s table replaced by ``value``."""
        return replace(self, tables={**self.tables, name: value})

    @property
    def W(self) -> np.ndarray:
        """Power spectral density matrix (6x6, diagonal) of the observer's white noise."""
        return np.diag(self.psd)

    @property
    def P0(self) -> np.ndarray:
        return np.diag(self.initial_std**2)

    def model_values(self, vehicle: Vehicle) -> dict[str, float]:
        """m, I_zz, Z_wdot, N_rdot, Z_w, N_r: the vehicle's values with this file's overrides."""
        values = {
            "m": vehicle.mass, "I_zz": vehicle.I_zz,
            "Z_wdot": float(vehicle.added_mass[2]), "N_rdot": float(vehicle.added_mass[3]),
            "Z_w": float(vehicle.damping_linear[2]), "N_r": float(vehicle.damping_linear[3]),
        }
        for key, value in self.model_overrides.items():
            values["m" if key == "mass" else key] = float(value)
        return values

    def bias_time_constants(self, M_w: float, M_r: float) -> tuple[float, float]:
        """(T_w, T_r) [s] of the Gauss-Markov bias states."""
        if self.bias_time_constant is not None:
            return self.bias_time_constant
        k = float(self.bias_time_per_mass)  # type: ignore[arg-type]
        return k * M_w, k * M_r


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------

_PACKAGED = PackagedFiles("rovlab.params", "configs", "filter configuration")


def packaged_config_names() -> list[str]:
    return _PACKAGED.names()


def packaged_config_path(name: str) -> Path:
    return _PACKAGED.path(name)


def resolve_config_path(name_or_path: str | Path) -> Path:
    """A packaged configuration name (``thesis``, ``default``) or a path to a TOML file."""
    return _PACKAGED.resolve(name_or_path)


def load_design_config(name_or_path: str | Path = "default") -> DesignConfig:
    """Load and validate a configuration; raises :class:`ConfigError` listing every problem."""
    path = resolve_config_path(name_or_path)
    return design_config_from_dict(read_toml(path), file=str(path))


def design_config_from_dict(data: Mapping[str, Any], *, file: str = "<dict>") -> DesignConfig:
    col = Collector(file)
    top = TableReader(dict(data), col)
    sources: dict[str, str] = {}
    name = top.name("name")
    description = top.string("description", "")
    sources["config"] = top.string("source")
    h = top.number("sample_time", positive=True, plausible=SAMPLE_TIME_RANGE,
                   what="filter and controller step in s")
    estimator = top.string("estimator", "kf")
    controller = top.string("controller", "lqg")
    hysteresis = top.number("pwm_hysteresis_us", 0.0, nonnegative=True, hi=PWM_HYSTERESIS_MAX_US,
                            what="PWM beyond the dead band in us, 0 = none")
    estimator_info = component("estimator", estimator) if estimator else None
    if estimator and estimator_info is None:
        top.problem("estimator", estimator, unknown_component("estimator", estimator))
    if controller and controller not in component_names("controller"):  # (its module is imported when built)
        top.problem("controller", controller, unknown_component("controller", controller))
    measurable = estimator_info.measurable if estimator_info is not None and estimator_info.measurable else MEASURABLE

    overrides: dict[str, float] = {}
    if top.has("model"):
        mt = top.table("model")
        sources["model"] = mt.string("source")
        for key in MODEL_KEYS:
            if mt.has(key):
                if key in ("mass", "I_zz"):
                    overrides[key] = mt.number(key, positive=True, plausible=_MODEL_RANGES[key])
                else:
                    overrides[key] = mt.number(key, nonpositive=True, plausible=_MODEL_RANGES[key],
                                               what="SNAME sign: <= 0")
        mt.finish()

    pn = top.table("process_noise")
    sources["process_noise"] = pn.string("source")
    psd = np.zeros(6)
    pt = pn.table("psd")
    for i, key in enumerate(PSD_KEYS):
        psd[2 + i] = pt.number(key, nonnegative=True, plausible=PSD_RANGE, what="power spectral density, SI")
    pt.finish()
    per_mass: float | None = None
    constants: tuple[float, float] | None = None
    if pn.has("bias_time_per_mass") == pn.has("bias_time_constant"):
        pn.problem("bias_time_per_mass", "both" if pn.has("bias_time_per_mass") else "neither",
                   "exactly one of bias_time_per_mass and bias_time_constant = { w = ..., r = ... }")
        pn.raw("bias_time_per_mass", None)
        pn.raw("bias_time_constant", None)
    elif pn.has("bias_time_per_mass"):
        per_mass = pn.number("bias_time_per_mass", positive=True, plausible=BIAS_TIME_PER_MASS_RANGE,
                             what="T = factor * M, s/kg")
    else:
        bt = pn.table("bias_time_constant")
        constants = (bt.number("w", positive=True, plausible=BIAS_TIME_RANGE, what="s"),
                     bt.number("r", positive=True, plausible=BIAS_TIME_RANGE, what="s"))
        bt.finish()
    thrust_uncertainty = pn.number("thrust_uncertainty", 0.0, nonnegative=True, hi=10.0,
                                   what="relative sigma of the thrusters' wrench (0.5 = 50 %)")
    pn.finish()

    it = top.table("initial")
    sources["initial"] = it.string("source")
    x0 = _state_table(it, "state", _STATE_KEYS, nonnegative=False)
    std = _state_table(it, "std", _STATE_KEYS, nonnegative=True)
    with np.errstate(over="ignore"):
        huge = [k for k, (i, _) in _STATE_KEYS.items() if np.isfinite(std[i]) and not np.isfinite(std[i] ** 2)]
    for key in huge:  # P0 = diag(std^2) must be finite
        i, factor = _STATE_KEYS[key]
        it.problem(f"std.{key}", float(std[i] / factor), "a standard deviation whose square is finite")
    it.finish()

    defaults = _fusion_settings(top.table("fusion", required=False), FusionSettings(), col)

    measurements: list[MeasurementConfig] = []
    for mr in top.tables("measurements", min_count=1):
        # what the chosen estimator can fuse (the depth-and-heading filter z, psi, w, r; the 4-DOF EKF x, y, u, v too)
        measurements.append(_measurement(mr, defaults, measurable))
    seen: dict[tuple[str | None, str | None, str], str] = {}
    for m in measurements:
        ident = (m.sensor, m.kind, m.quantity)
        if ident in seen:
            top.problem("measurements", f"{m.key} repeats {seen[ident]}",
                        "each sensor quantity at most once")
        seen[ident] = m.key

    lt = top.table("lqr")
    sources["lqr"] = lt.string("source")
    Q, R, bryson = _lqr_weights(lt)
    with np.errstate(all="ignore"):
        if np.all(~np.isnan(Q)) and np.all(~np.isnan(R)) and not (
                np.all(np.isfinite(Q)) and np.all(np.isfinite(R)) and np.all(R > 0)):
            lt.problem("state_max" if bryson else "Q_diag", {"Q": Q.tolist(), "R": R.tolist()},
                       "weights that are finite (and positive for the inputs): a maximum so small "
                       "that 1/max^2 overflows is not a limit")
    reference = lt.string("reference_gain", "discrete", choices=("discrete", "continuous"))
    lt.finish()
    # the components' own tables, each named after its component and read by the component's parser
    tables: dict[str, Any] = {}
    for kind in KINDS:
        for cname in component_names(kind):
            if not top.has(cname) or cname in tables:
                continue
            info = component(kind, cname)
            if info is None or info.parse_table is None:
                top.problem(cname, "a table", f"no such table: {kind} {cname!r} has none" if info is not None
                            else f"the table of a {kind} that loads; {kind} {cname!r} did not: "
                                 f"{load_failure(kind, cname)}")
                top.raw(cname, None)
                continue
            tables[cname] = info.parse_table(top.table(cname))
            source = getattr(tables[cname], "source", None)
            if isinstance(source, str):
                sources[cname] = source
    top.finish()
    col.raise_if_any("filter configuration")

    for arr in (psd, x0, std, Q, R):
        arr.setflags(write=False)
    return DesignConfig(
        name=name, description=description, sample_time=h, model_overrides=overrides, psd=psd,
        bias_time_per_mass=per_mass, bias_time_constant=constants, measurements=tuple(measurements),
        initial_state=x0, initial_std=std, lqr_Q=Q, lqr_R=R, lqr_bryson=bryson,
        reference_gain=reference, sources=sources, file=file, estimator=estimator, controller=controller,
        tables=tables, thrust_uncertainty=thrust_uncertainty, pwm_hysteresis_us=hysteresis,
    )


PWM_HYSTERESIS_MAX_US = 400.0  # half the T200/ESC command range (1100-1900 us): a wider one never changes side
MAX_TABLE_MAGNITUDE = 1e6  # |value| of a component table's per-key number (SI units or the file's degrees)
# Issue 28's fuzzing: [ekf] bias_psd = 2e298 overflowed the EKF's discretisation (LinAlgError in
# simulate) and [dp] bandwidth = 1e300 gave NaN in the demanded wrench; at 1e6 every [ekf] noise
# density and [dp] bandwidth, reference bandwidth and speed limit still ran finite
# (dp-station-keeping, 20 s). Physical ranges are the component's own (``plausible``).



def per_key(t: TableReader, name: str, keys: tuple[str, ...], base: np.ndarray, *, factors: tuple[float, ...] | None = None,
             positive: bool = False, nonnegative: bool = False, what: str = "",
             plausible: tuple[float, float] | Mapping[str, tuple[float, float]] | None = None) -> np.ndarray:
    """An inline table of numbers per key (missing keys keep ``base``), times ``factors``.

    Each value (in the file's units, before ``factors``) must lie within ``plausible`` -- one
    (lo, hi) for every key or one per key (a key it does not list: the magnitude bound) -- and in
    any case within +-``MAX_TABLE_MAGNITUDE``: a value beyond what any BlueROV-class design can
    mean is refused here, with the file and key, instead of overflowing in the design or the
    kernels."""
    out = np.array(base, dtype=float)
    sub = t.table(name, required=False)
    for i, key in enumerate(keys):
        if sub.has(key):
            bounds = plausible.get(key) if isinstance(plausible, Mapping) else plausible
            lo, hi = bounds if bounds is not None else (-MAX_TABLE_MAGNITUDE, MAX_TABLE_MAGNITUDE)
            lo, hi = max(lo, -MAX_TABLE_MAGNITUDE), min(hi, MAX_TABLE_MAGNITUDE)
            if positive or nonnegative:
                lo = max(lo, 0.0)
            out[i] = sub.number(key, positive=positive, nonnegative=nonnegative, plausible=(lo, hi), what=what) * (
                factors[i] if factors else 1.0)
    sub.finish()
    return out


def _state_table(t: TableReader, name: str, keys: Mapping[str, tuple[int, float]], *,
                 nonnegative: bool) -> np.ndarray:
    out = np.zeros(6)
    sub = t.table(name, required=False)
    for key, (i, factor) in keys.items():
        if sub.has(key):
            lo, hi = _STATE_RANGES[key]
            out[i] = sub.number(key, nonnegative=nonnegative, plausible=(0.0 if nonnegative else lo, hi)) * factor
    sub.finish()
    return out


def _fusion_settings(t: TableReader, base: FusionSettings, col: Collector) -> FusionSettings:
    timeout = t.number("timeout_s", base.timeout_s, positive=True) if t.has("timeout_s") else base.timeout_s
    settings = FusionSettings(
        timeout_s=timeout,
        gate_probability=t.number("gate_probability", base.gate_probability, lo=0.5, hi=1.0,
                                  what="chi-square gate probability; 1.0 disables the gate"),
        gate_failures_to_lose=t.integer("gate_failures_to_lose", base.gate_failures_to_lose, lo=1),
        startup_s=(t.number("startup_s", nonnegative=True, what="s without the gate after the start; "
                            "0 = gate from the first sample") if t.has("startup_s") else base.startup_s),
        recovery_time_s=t.number("recovery_time_s", base.recovery_time_s, nonnegative=True,
                                 what="s over which a returning sensor's correction is spread; 0 = abrupt return"),
        reacquire_after_s=t.number("reacquire_after_s", base.reacquire_after_s, nonnegative=True,
                                   what="0 = never re-admit a sensor the gate keeps rejecting"),
        stuck_window_s=t.number("stuck_window_s", base.stuck_window_s, nonnegative=True,
                                what="s per block of the stuck-sensor variance check; 0 = no check"),
        maneuver_acceleration=t.number("maneuver_acceleration", base.maneuver_acceleration, nonnegative=True,
                                       plausible=(0.0, 50.0),
                                       what="m/s^2 (rad/s^2 for headings) a change the model missed may "
                                            "accelerate the truth away from the prediction; 0 = off"),
    )
    if t.has("recovery_variance_factor"):
        # The old transitional R (factor * R decaying to R) did not spread the correction once the
        # prior variance outgrew factor * R, and factor = 1 left a gate-lost sensor out for good
        # (the closed loop diverged): refuse it rather than silently ignore it.
        t.problem("recovery_variance_factor", t.raw("recovery_variance_factor"),
                  "no such key any more: a returning sensor is now under-weighted relative to the filter's "
                  "prior variance over recovery_time_s (0 = abrupt return); delete this key")
    if t.path == "fusion":
        t.finish()
    return settings


def _measurement(t: TableReader, defaults: FusionSettings,
                 quantities: tuple[str, ...] = MEASURABLE) -> MeasurementConfig:
    sensor = t.string("sensor") if t.has("sensor") else None
    kind = t.string("kind", choices=tuple(SENSOR_CHANNELS)) if t.has("kind") else None
    if (sensor is None) == (kind is None):
        t.problem("sensor", "both sensor and kind" if sensor is not None else "neither sensor nor kind",
                  "exactly one of sensor = NAME (a vehicle sensor) and kind = KIND")
    quantity = t.string("quantity", choices=quantities)
    if kind and quantity and quantity not in SENSOR_CHANNELS.get(kind, ()):
        t.problem("quantity", quantity, f"a channel of a {kind} sensor: "
                  + ", ".join(c for c in SENSOR_CHANNELS[kind] if c in quantities))
    # plausible: sigma from 1e-10 (a variance below 1e-20 makes the filter's gain and its design's
    # Riccati step overflow: 1e-310 reached the HMI as scipy's "must not contain infs or NaNs") to 1e3
    variance = (t.number("variance", positive=True, plausible=(1e-20, 1e6), what="SI units squared")
                if t.has("variance") else None)
    source = t.string("source", "")
    fusion = _fusion_settings(t, defaults, t.collector)
    t.finish()
    return MeasurementConfig(quantity=quantity, sensor=sensor, kind=kind, variance=variance,
                             fusion=fusion, key=t.path, source=source)


def _lqr_weights(t: TableReader) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray] | None]:
    bryson_keys = ("state_max", "input_max", "state_weight", "input_weight")
    uses_bryson = t.has("state_max") or t.has("input_max")
    uses_explicit = t.has("Q_diag") or t.has("R_diag")
    if uses_bryson == uses_explicit:
        t.problem("state_max", "both forms" if uses_bryson else "neither form",
                  "either Bryson's rule (state_max and input_max) or explicit Q_diag and R_diag")
        for k in bryson_keys + ("Q_diag", "R_diag"):
            t.raw(k, None)
        return np.full(4, np.nan), np.full(2, np.nan), None
    if uses_explicit:
        Q = t.vector("Q_diag", 4, what="weights of z, psi, w, r (SI)")
        R = t.vector("R_diag", 2, what="weights of Z, N (SI)")
        for name, arr in (("Q_diag", Q), ("R_diag", R)):
            if np.all(np.isfinite(arr)) and (np.any(arr < 0) or (name == "R_diag" and np.any(arr <= 0))):
                t.problem(name, arr.tolist(), "non-negative state weights and positive input weights")
        return Q, R, None
    smax = np.full(4, np.nan)
    sub = t.table("state_max")
    for key, (i, factor) in _LQR_STATE_KEYS.items():
        given = sub.number(key, positive=True)
        smax[i] = given * factor
        if given > 0 and not smax[i] > 0:  # 5e-324 deg is 0 rad: Bryson's 1/max^2 would be a NaN weight
            sub.problem(key, given, "a maximum whose value in SI units is a positive number (this one underflows "
                                    "to 0 when converted)")
    sub.finish()
    umax = np.full(2, np.nan)
    sub = t.table("input_max")
    for i, key in enumerate(INPUTS):
        umax[i] = sub.number(key, positive=True, what="N or N m")
    sub.finish()
    sw = np.ones(4)
    sub = t.table("state_weight", required=False)
    for key in ("z", "psi", "w", "r"):
        if sub.has(key):
            sw[CONTROL_STATES.index(key)] = sub.number(key, nonnegative=True)
    sub.finish()
    uw = np.ones(2)
    sub = t.table("input_weight", required=False)
    for i, key in enumerate(INPUTS):
        if sub.has(key):
            uw[i] = sub.number(key, positive=True)
    sub.finish()
    # Bryson's rule (Bryson & Ho 1975): weight_i / max_i^2 (NaN where the file's value was refused;
    # an overflow is reported by the caller)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        Q = bryson_diagonal(np.where(np.isfinite(smax) & (smax > 0), smax, np.nan), sw)
        R = bryson_diagonal(np.where(np.isfinite(umax) & (umax > 0), umax, np.nan), uw)
    return Q, R, {"state_max": smax, "input_max": umax, "state_weight": sw, "input_weight": uw}


def check_design_config_file(name_or_path: str | Path) -> list[Problem]:
    """Every problem of a configuration file (empty list when valid)."""
    try:
        load_design_config(name_or_path)
    except ConfigError as exc:
        return exc.problems
    return []
