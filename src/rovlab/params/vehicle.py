"""Vehicle description: frozen, validated parameters loaded from a closed-schema TOML file.

Units are SI and radians; positions are in metres in the body frame (x forward, y starboard,
z down) relative to the vehicle origin VO (= CG for the packaged vehicles). Hydrodynamic
derivatives keep their SNAME signs (added mass and damping are <= 0). See docs/conventions.md
and docs/vehicle-file.md for the file format.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.params.validate import (
    Collector,
    ConfigError,
    PackagedFiles,
    Problem,
    TableReader,
    plausible_expectation,
    read_toml,
)

DOF4 = ("surge", "sway", "heave", "yaw")
WRENCH6 = ("X", "Y", "Z", "K", "M", "N")
ADDED_MASS_KEYS = ("X_udot", "Y_vdot", "Z_wdot", "N_rdot")
SENSOR_CHANNELS: dict[str, tuple[str, ...]] = {
    "motion_capture": ("x", "y", "z", "phi", "theta", "psi"),
    "pressure": ("z",),
    "imu": ("phi", "theta", "psi", "r"),
    "dvl": ("u", "v", "w"),
}
THRUST_TABLES = ("t200",)

# Physical plausibility: the ranges a BlueROV-class vehicle (a small ROV of 0.1 kg to 1 t, in
# water, on Earth) can have. A value outside is refused by the loader before anything runs (a
# fuzzer's damping of -9e18 or gravity of 1.8e19 made the plant NaN from t = 0.1 s). The table is
# restated in docs/vehicle-file.md; widen a bound here and there together if a real vehicle needs it.
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "mass": (0.1, 1000.0),  # [kg]
    "I_zz": (1e-4, 1000.0),  # [kg m^2]
    "offset": (-1.0, 1.0),  # r_g, r_b components [m]
    "displaced_volume": (1e-4, 1.0),  # [m^3]
    "water_density": (950.0, 1100.0),  # [kg/m^3]: fresh water ~998, sea water ~1025 (DNV-RP-H103)
    "gravity": (9.7, 9.9),  # [m/s^2]: 9.78 at the equator to 9.83 at the poles
    "buoyancy_ratio": (0.5, 2.0),  # B / W: a ROV is trimmed near neutral buoyancy
    "added_mass": (-1000.0, 0.0),  # X_udot, Y_vdot, Z_wdot [kg], N_rdot [kg m^2]
    "damping_linear": (-1e4, 0.0),  # [N s/m], [N m s/rad]
    "damping_quadratic": (-1e4, 0.0),  # [N s^2/m^2], [N m s^2/rad^2]
    "damping_cubic": (-1e5, 0.0),  # [N s^3/m^3], [N m s^3/rad^3]
    "size": (0.01, 10.0),  # geometry lengths [m]
    "area": (1e-4, 100.0),  # projected areas [m^2]
    "position": (-5.0, 5.0),  # thruster and sensor position components [m]
    "K_L": (0.0, 10.0),  # [N/us]
    "K_NL": (0.0, 1.0),  # [N/us^2]
    "rate_hz": (0.01, 1e4),  # sensor sample rate [Hz]
    "variance": (1e-15, 1e4),  # sensor variance per channel [SI units squared]
    "resolution": (1e-9, 10.0),  # sensor quantisation step per channel [SI units]
}
SENSOR_REPORTS = ("measurement", "estimate")  # a raw sensor's samples, or an autopilot's estimate


def _frozen(a: Any) -> np.ndarray:
    arr = np.array(a, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class QuadraticCurve:
    """Dead-band thrust curve f = K_L s + K_NL s|s| with s = u -/+ d (Sandøy 2016, ch. 2).

    Coefficients are per microsecond of PWM offset: K_L in N/us, K_NL in N/us^2; all >= 0.
    """

    K_L_pos: float
    K_NL_pos: float
    K_L_neg: float
    K_NL_neg: float


@dataclass(frozen=True, eq=False)
class Thruster:
    name: str
    position: np.ndarray  # r_i, body frame from VO [m]
    direction: np.ndarray  # e_i, unit thrust direction for a positive command
    model: str  # "quadratic" | "table"
    curve: QuadraticCurve | None
    table: str | None  # name of a packaged bollard-thrust table ("t200")
    voltage: float | None  # supply voltage for a tabulated model [V]
    pwm_min_us: float
    pwm_max_us: float
    pwm_neutral_us: float
    deadband_us: float
    source: str = ""
    # "shift": the curve starts at the dead band's edge (s = u -+ d, the MC-Lab fit); "cut": the curve of the
    # whole offset u, zero within the band (ArduPilot SITL's SIM_Submarine); rovlab.models.thruster_kernels
    deadband_kind: str = "shift"


@dataclass(frozen=True, eq=False)
class Sensor:
    name: str
    kind: str  # a key of SENSOR_CHANNELS
    position: np.ndarray  # lever arm l in the body frame [m]
    rate_hz: float
    variance: Mapping[str, float]  # channel -> variance (SI units squared)
    source: str = ""
    # what it sends: "measurement" (a raw sensor: its samples scatter like white noise) or
    # "estimate" (an autopilot's own filtered output, e.g. ArduSub's AHRS heading: smooth, so its
    # scatter says nothing about a frozen value; only an exact repetition does)
    reports: str = "measurement"
    resolution: Mapping[str, float] = field(default_factory=dict)  # channel -> quantisation step (SI)

    def channels(self) -> tuple[str, ...]:
        return tuple(self.variance)


@dataclass(frozen=True, eq=False)
class Geometry:
    length: float  # L along x [m]
    width: float  # W along y [m]
    height: float  # H along z [m]
    area_front: float  # projected area seen from the front (YZ plane) [m^2]
    area_side: float  # seen from the side (XZ plane) [m^2]
    area_top: float  # seen from the top (XY plane) [m^2]
    source: str = ""


@dataclass(frozen=True, eq=False)
class Vehicle:
    """Everything rovlab knows about one vehicle. Immutable; use ``with_updates`` to change."""

    name: str
    description: str
    mass: float  # m [kg]
    I_zz: float  # yaw moment of inertia about VO [kg m^2] (the 4-DOF model needs no other)
    r_g: np.ndarray  # CG from VO [m]
    r_b: np.ndarray  # CB from VO [m]
    displaced_volume: float  # [m^3]
    water_density: float  # rho [kg/m^3]
    gravity: float  # g [m/s^2]
    added_mass: np.ndarray  # [X_udot, Y_vdot, Z_wdot, N_rdot] (<= 0)
    damping_linear: np.ndarray  # [X_u, Y_v, Z_w, N_r] (<= 0)
    damping_quadratic: np.ndarray  # [X_|u|u, Y_|v|v, Z_|w|w, N_|r|r] (<= 0)
    damping_cubic: np.ndarray  # [X_uuu, Y_vvv, Z_www, N_rrr] (<= 0)
    thrusters: tuple[Thruster, ...]
    sensors: tuple[Sensor, ...]
    geometry: Geometry | None = None
    sources: Mapping[str, str] = field(default_factory=dict)
    file: str = ""

    @property
    def weight(self) -> float:
        """W = m g [N]."""
        return self.mass * self.gravity

    @property
    def buoyancy(self) -> float:
        """B = rho g Delta [N]."""
        return self.water_density * self.gravity * self.displaced_volume

    @property
    def thruster_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.thrusters)

    def thruster(self, name: str) -> Thruster:
        for t in self.thrusters:
            if t.name == name:
                return t
        raise KeyError(f"vehicle {self.name!r} has no thruster {name!r}; it has {', '.join(self.thruster_names)}")

    def sensor(self, name: str) -> Sensor:
        for s in self.sensors:
            if s.name == name:
                return s
        names = ", ".join(s.name for s in self.sensors) or "none"
        raise KeyError(f"vehicle {self.name!r} has no sensor {name!r}; it has {names}")

    def with_updates(self, **changes: Any) -> Vehicle:
        """A copy with some fields replaced (arrays are copied and frozen)."""
        fixed: dict[str, Any] = {
            k: _frozen(v) if isinstance(v, (list, tuple, np.ndarray)) and k not in ("thrusters", "sensors") else v
            for k, v in changes.items()}
        return replace(self, **fixed)


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------

_PACKAGED = PackagedFiles("rovlab.params", "vehicles", "vehicle")


def packaged_vehicle_names() -> list[str]:
    return _PACKAGED.names()


def packaged_vehicle_path(name: str) -> Path:
    return _PACKAGED.path(name)


def resolve_vehicle_path(name_or_path: str | Path) -> Path:
    """A packaged vehicle name (``udrone``) or a path to a TOML file."""
    return _PACKAGED.resolve(name_or_path)


def load_vehicle(name_or_path: str | Path = "udrone") -> Vehicle:
    """Load and validate a vehicle; raises :class:`ConfigError` listing every problem."""
    path = resolve_vehicle_path(name_or_path)
    data = read_toml(path)
    return vehicle_from_dict(data, file=str(path))


def check_vehicle_file(name_or_path: str | Path) -> list[Problem]:
    """Every problem of a vehicle file (empty list when valid)."""
    try:
        load_vehicle(name_or_path)
    except ConfigError as exc:
        return exc.problems
    return []


def vehicle_from_dict(data: Mapping[str, Any], *, file: str = "<dict>") -> Vehicle:
    col = Collector(file)
    top = TableReader(dict(data), col)
    sources: dict[str, str] = {}

    name = top.name("name")
    description = top.string("description", "")
    sources["vehicle"] = top.string("source")

    rb = top.table("rigid_body")
    sources["rigid_body"] = rb.string("source")
    mass = rb.number("mass", positive=True, plausible=PLAUSIBLE["mass"], what="kg")
    I_zz = rb.number("I_zz", positive=True, plausible=PLAUSIBLE["I_zz"],
                     what="yaw moment of inertia about VO in kg m^2")
    r_g = _offset(rb, "r_g", "CG from VO in m")
    rb.finish()

    rs = top.table("restoring")
    sources["restoring"] = rs.string("source")
    volume = rs.number("displaced_volume", positive=True, plausible=PLAUSIBLE["displaced_volume"], what="m^3")
    rho = rs.number("water_density", 1000.0, positive=True, plausible=PLAUSIBLE["water_density"],
                    what="kg/m^3")
    grav = rs.number("gravity", 9.81, positive=True, plausible=PLAUSIBLE["gravity"], what="m/s^2")
    r_b = _offset(rs, "r_b", "CB from VO in m")
    if all(np.isfinite([mass, volume, rho, grav])):
        ratio = rho * volume / mass
        lo, hi = PLAUSIBLE["buoyancy_ratio"]
        if not lo <= ratio <= hi:
            rs.problem("displaced_volume", volume,
                       f"a buoyancy B = rho g Delta within {lo:g} .. {hi:g} times the weight m g "
                       f"(B/W is {ratio:.3g} with mass {mass:g} kg; a ROV is trimmed near neutral; docs/vehicle-file.md)")
    rs.finish()

    geometry = None
    if top.has("geometry"):
        gt = top.table("geometry")
        vals = {k: gt.number(k, positive=True, plausible=PLAUSIBLE["area" if k.startswith("area") else "size"],
                             what="m^2" if k.startswith("area") else "m")
                for k in ("length", "width", "height", "area_front", "area_side", "area_top")}
        geometry = Geometry(**vals, source=gt.string("source"))
        sources["geometry"] = geometry.source
        gt.finish()

    am = top.table("added_mass")
    sources["added_mass"] = am.string("source")
    added = np.array([am.number(k, nonpositive=True, plausible=PLAUSIBLE["added_mass"],
                                what="SNAME sign: added mass is <= 0") for k in ADDED_MASS_KEYS])
    am.finish()

    dm = top.table("damping")
    sources["damping"] = dm.string("source")
    lin, quad, cub = np.zeros(4), np.zeros(4), np.zeros(4)
    for i, dof in enumerate(DOF4):
        d = dm.table(dof)
        for arr, order, default in ((lin, "linear", _MISSING_DEFAULT), (quad, "quadratic", 0.0),
                                    (cub, "cubic", 0.0)):
            arr[i] = d.number(order, *(() if default is _MISSING_DEFAULT else (default,)), nonpositive=True,
                              plausible=PLAUSIBLE[f"damping_{order}"], what="SNAME sign: damping is <= 0")
        d.finish()
    dm.finish()

    thrusters = tuple(_read_thruster(t) for t in top.tables("thrusters", min_count=1))
    names = [t.name for t in thrusters]
    for dup in sorted({n for n in names if names.count(n) > 1}):
        top.problem("thrusters", dup, "unique thruster names")

    sensors = tuple(_read_sensor(s) for s in top.tables("sensors", min_count=1))
    snames = [s.name for s in sensors]
    for dup in sorted({n for n in snames if snames.count(n) > 1}):
        top.problem("sensors", dup, "unique sensor names")
    top.finish()

    if not col.problems:
        _check_configuration(thrusters, col)
    col.raise_if_any("vehicle file")

    return Vehicle(
        name=name, description=description, mass=mass, I_zz=I_zz, r_g=_frozen(r_g),
        r_b=_frozen(r_b), displaced_volume=volume, water_density=rho, gravity=grav,
        added_mass=_frozen(added), damping_linear=_frozen(lin), damping_quadratic=_frozen(quad),
        damping_cubic=_frozen(cub), thrusters=thrusters, sensors=sensors, geometry=geometry,
        sources=sources, file=file,
    )


_MISSING_DEFAULT = object()


def _offset(t: TableReader, key: str, what: str) -> np.ndarray:
    """An optional 3-vector (default 0) whose components lie in PLAUSIBLE["offset"]."""
    return _bounded_vector(t, key, PLAUSIBLE["offset"], what, default=[0.0, 0.0, 0.0])


def _bounded_vector(t: TableReader, key: str, bounds: tuple[float, float], what: str, **kw: Any) -> np.ndarray:
    vec = t.vector(key, 3, what=what, **kw)
    if np.all(np.isfinite(vec)) and not np.all((vec >= bounds[0]) & (vec <= bounds[1])):
        t.problem(key, vec.tolist(), "components " + plausible_expectation(bounds, what)[2:])
        return np.full(3, np.nan)
    return vec


def _read_thruster(t: TableReader) -> Thruster:
    name = t.name("name")
    position = _bounded_vector(t, "position", PLAUSIBLE["position"], "m from VO, body frame")
    direction = t.vector("direction", 3, what="unit thrust direction")
    with np.errstate(over="ignore"):
        norm = float(np.sqrt(np.sum(np.square(direction)))) if np.all(np.isfinite(direction)) else 1.0
    if not abs(norm - 1.0) <= 1e-6:
        t.problem("direction", direction.tolist(), f"a unit vector (its norm is {norm:.6g})")
        direction = np.full(3, np.nan)
    model = t.string("model", "quadratic", choices=("quadratic", "table"))
    curve = None
    table = None
    voltage = None
    if model == "quadratic":
        q = t.table("quadratic")
        curve = QuadraticCurve(*(q.number(k, nonnegative=True, plausible=PLAUSIBLE[k[:-4]],
                                          what="N/us" if k.startswith("K_L_") else "N/us^2")
                                 for k in ("K_L_pos", "K_NL_pos", "K_L_neg", "K_NL_neg")))
        q.finish()
        if all(np.isfinite([curve.K_L_pos, curve.K_NL_pos])) and curve.K_L_pos + curve.K_NL_pos == 0:
            t.problem("quadratic", "zero forward coefficients", "a curve that produces thrust")
        if all(np.isfinite([curve.K_L_neg, curve.K_NL_neg])) and curve.K_L_neg + curve.K_NL_neg == 0:
            t.problem("quadratic", "zero reverse coefficients", "a curve that produces thrust")
        default_range = (1100.0, 1900.0)
    elif model == "table":
        tt = t.table("table")
        table = tt.string("name", choices=THRUST_TABLES)
        voltage = tt.number("voltage", lo=10.0, hi=20.0, what="supply voltage in V within the table's 10-20 V")
        tt.finish()
        default_range = (1100.0, 1900.0)
    else:
        default_range = (1100.0, 1900.0)
    pwm_min = t.number("pwm_min_us", default_range[0], lo=500.0, hi=2500.0)
    pwm_max = t.number("pwm_max_us", default_range[1], lo=500.0, hi=2500.0)
    neutral = t.number("pwm_neutral_us", 1500.0, lo=500.0, hi=2500.0)
    dead = t.number("deadband_us", 25.0, nonnegative=True)
    if all(np.isfinite([pwm_min, pwm_max, neutral, dead])):
        if not (pwm_min < neutral - dead and neutral + dead < pwm_max):  # dead = 0: no dead band
            t.problem("pwm_min_us", [pwm_min, neutral, dead, pwm_max],
                      "pwm_min_us < pwm_neutral_us - deadband_us and pwm_neutral_us + deadband_us < pwm_max_us")
    dead_kind = t.string("deadband_kind", "shift", choices=("shift", "cut"))
    if dead_kind == "cut":
        if model != "quadratic":
            t.problem("deadband_kind", dead_kind, f"'shift' or no deadband_kind for model = {model!r} (a cut dead "
                      "band applies to the quadratic model; a table has its own dead band)")
        elif np.isfinite(dead) and dead <= 0.0:
            t.problem("deadband_kind", dead_kind, f"a dead band to cut: deadband_us > 0 (it is {dead:g}; without a "
                      "dead band, leave deadband_kind out)")
        elif all(np.isfinite([pwm_min, pwm_max, neutral, dead])) and not (
                pwm_min <= neutral - dead - 1.0 and neutral + dead + 1.0 <= pwm_max):
            t.problem("deadband_kind", [pwm_min, neutral, dead, pwm_max], "a cut dead band's least pulses within "
                      "the range: pwm_min_us <= pwm_neutral_us - deadband_us - 1 and pwm_neutral_us + deadband_us + 1 "
                      "<= pwm_max_us")
    source = t.string("source", "")
    t.finish()
    return Thruster(name=name, position=_frozen(position), direction=_frozen(direction), model=model,
                    curve=curve, table=table, voltage=voltage, pwm_min_us=pwm_min, pwm_max_us=pwm_max,
                    pwm_neutral_us=neutral, deadband_us=dead, source=source, deadband_kind=dead_kind or "shift")


def _read_sensor(s: TableReader) -> Sensor:
    name = s.name("name")
    kind = s.string("kind", choices=tuple(SENSOR_CHANNELS))
    position = _bounded_vector(s, "position", PLAUSIBLE["position"], "lever arm in m, body frame",
                               default=[0.0, 0.0, 0.0])
    rate = s.number("rate_hz", positive=True, plausible=PLAUSIBLE["rate_hz"], what="Hz")
    channels = SENSOR_CHANNELS.get(kind, ())
    variance = s.numbers_table("variance", channels, positive=True, plausible=PLAUSIBLE["variance"])
    if kind in SENSOR_CHANNELS and not variance:
        s.problem("variance", {}, "a variance for at least one of " + ", ".join(channels))
    reports = s.string("reports", "measurement", choices=SENSOR_REPORTS)
    resolution = s.numbers_table("resolution", channels, positive=True, plausible=PLAUSIBLE["resolution"]) \
        if s.has("resolution") else {}
    source = s.string("source", "")
    s.finish()
    return Sensor(name=name, kind=kind, position=_frozen(position), rate_hz=rate,
                  variance=dict(variance), source=source, reports=reports, resolution=dict(resolution))


def _check_configuration(thrusters: tuple[Thruster, ...], col: Collector) -> None:
    """Every DOF of the 4-DOF model (X, Y, Z, N) must be producible independently."""
    # Columns [e_i; r_i x e_i] (rovlab.allocation builds the full matrix; only X, Y, Z, N here).
    e = np.array([t.direction for t in thrusters]).T
    moment_n = np.cross(np.array([t.position for t in thrusters]), e.T)[:, 2]
    B4 = np.vstack([e, moment_n])
    for j, label in zip(range(4), ("X (surge)", "Y (sway)", "Z (heave)", "N (yaw)")):
        unit = np.zeros(4)
        unit[j] = 1.0
        sol, *_ = np.linalg.lstsq(B4, unit, rcond=None)
        if np.linalg.norm(B4 @ sol - unit) > 1e-6:
            col.add("thrusters", f"{len(thrusters)} thrusters",
                    f"a thruster configuration that can produce {label} independently of the other DOFs")
