"""Excitation manoeuvres for identification from a dive, and how well they will determine each
parameter before anything is flown (issue 29; rovlab.ident.dive identifies from the log).

A plan is a piecewise-constant wrench per DOF (heave force Z, yaw moment N), one value per
command step (0.1 s), flown open loop on top of two things that keep the vehicle in a safe depth
band: the trim force of the vehicle file's net buoyancy, and a weak proportional depth law
(``depth_gain`` N/m towards the middle of the band; its time constant, ``M / (D + gain)``-ish
seconds, is much longer than the excitation's holds). A depth guard pauses the excitation (and
the yaw moment) while the measured depth is outside the band and resumes it once the depth is back
in the middle half, the depth law then pulling four times as hard. What the thrusters do is
logged (PWM), so the identification sees the wrench that was really commanded, whatever the
guard and the depth law added.

The excitation is a random multi-level sequence (Ljung 1999, sec. 13.3; a PRBS with levels):
holds of 0.5-3 s (reversals excite the added mass, holds the damping), levels log-uniform from
5 % to 100 % of an amplitude that reaches ``heave_speed`` / ``yaw_rate`` at steady state according to the
vehicle file's damping (two speeds apart separate linear from quadratic damping), capped at 80 %
of what the allocation can give in that DOF alone (``dof_capacity``). Heave holds are cut short
where the vehicle file's model predicts that the depth would leave the middle 70 % of the band,
and their sign is chosen towards the middle when the depth is off-centre. Rests of ``rest_s``
with no excitation every ``rest_every_s`` show the net buoyancy.

Expected standard deviations: the plan is flown on the vehicle file's own model without noise
(rovlab.ident.dive.fly_plan), and the Fisher information of the output-error problem that
``rovlab identify dive`` will solve (the same windows and nuisance initial states, on the first
70 % of the log) is J^T R^-1 J, with J the sensitivities of the predicted depth (2 Hz), heading
and yaw rate (20 Hz) to the parameters at the vehicle file's values and R the sensors' variances
from the vehicle file. A sensor that reports an estimate (ArduSub's AHRS heading) has errors
correlated over ``AHRS_TAU_S`` (0.5 s) in the virtual dive; its variance is taken as the
long-run variance of such an error, (1 + phi)/(1 - phi) times the file's (phi = exp(-0.05/0.5)),
so that its 20 Hz samples are not counted as independent. The inverse of the information is the
Cramér-Rao bound: the smallest covariance any unbiased estimator reaches, and what output error
reaches in the limit when the model is right.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.params.vehicle import Vehicle

PLAN_DOFS = ("heave", "yaw")
_W6 = {"heave": 2, "yaw": 5}


@dataclass(frozen=True, eq=False)
class DivePlan:
    """A planned excitation manoeuvre (SI): wrench per command step, depth band and depth law."""

    vehicle: str
    dofs: tuple[str, ...]
    dt: float  # command step [s]
    Z: np.ndarray  # heave force per command step [N] (the excitation; trim and depth law come on top)
    N: np.ndarray  # yaw moment per command step [N m]
    depth_min: float
    depth_max: float
    start_depth: float
    depth_gain: float  # [N/m]
    trim_Z: float  # [N]: the file's net buoyancy B - W held by the vertical thrusters
    capacity: Mapping[str, tuple[float, float]]  # per DOF: (most negative, most positive) wrench
    seed: int
    source: str = ""
    settings: Mapping[str, Any] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return float(len(self.Z) * self.dt)

    def flyer(self) -> Flyer:
        return Flyer(self)


class Flyer:
    """The wrench to command at each step: excitation + trim + depth law, with the depth guard."""

    def __init__(self, plan: DivePlan) -> None:
        self.plan = plan
        self.mid = 0.5 * (plan.depth_min + plan.depth_max)
        band = plan.depth_max - plan.depth_min
        self.inner = (plan.depth_min + 0.25 * band, plan.depth_max - 0.25 * band)
        self.guarded = False

    def step(self, k: int, depth: float) -> tuple[list[float], bool]:
        p = self.plan
        if depth < p.depth_min or depth > p.depth_max:
            self.guarded = True
        elif self.guarded and self.inner[0] <= depth <= self.inner[1]:
            self.guarded = False
        gain = p.depth_gain * (4.0 if self.guarded else 1.0)
        exc_z = 0.0 if self.guarded else float(p.Z[k])
        exc_n = 0.0 if self.guarded else float(p.N[k])
        lo, hi = p.capacity.get("heave", (-math.inf, math.inf))
        z = min(max(p.trim_Z + exc_z + gain * (self.mid - depth), 0.95 * lo), 0.95 * hi)
        return [0.0, 0.0, z, exc_n], self.guarded


def dof_capacity(vehicle: Vehicle) -> dict[str, tuple[float, float]]:
    """(most negative, most positive) force [N] / moment [N m] the thrusters give in heave and in
    yaw alone, along the allocation's pseudo-inverse direction within the thrust limits."""
    from rovlab.allocation.solvers import Allocator

    alloc = Allocator(vehicle, compiled=False)
    out = {}
    for dof, i in _W6.items():
        e = np.zeros(6)
        e[i] = 1.0
        f = alloc.T @ e
        caps = []
        for sign in (1.0, -1.0):
            fs = sign * f
            lim = [(alloc.f_max[j] / fs[j]) if fs[j] > 1e-12 else (alloc.f_min[j] / fs[j]) if fs[j] < -1e-12 else math.inf
                   for j in range(fs.size)]
            caps.append(min(lim))
        out[dof] = (-caps[1], caps[0])
    return out


def _damping_force(vehicle: Vehicle, i: int, v: float) -> float:
    return abs(float(vehicle.damping_linear[i]) * v + float(vehicle.damping_quadratic[i]) * v * abs(v)
               + float(vehicle.damping_cubic[i]) * v**3)


LEVEL_RANGE = (0.05, 1.0)  # share of the amplitude, log-uniform: as many holds at 5-10 % as at 50-100 %


def _level(rng: np.random.Generator) -> float:
    """A level's share of the amplitude, log-uniform over LEVEL_RANGE: low levels (slow speeds,
    where the linear damping shows) as often as high ones (where the quadratic damping shows)."""
    lo, hi = LEVEL_RANGE
    return float(lo * (hi / lo) ** rng.uniform())


def plan_dive(vehicle: Vehicle, dofs: Sequence[str] = PLAN_DOFS, duration_s: float = 300.0, *, seed: int = 0,
              depth_min: float = 1.0, depth_max: float = 3.0, dt: float = 0.1, heave_speed: float = 0.4,
              yaw_rate: float = 1.0, hold_s: tuple[float, float] = (0.5, 3.0), rest_every_s: float = 40.0,
              rest_s: float = 5.0, depth_gain: float = 4.0, fraction: float = 0.8) -> DivePlan:
    """A random multi-level excitation of the DOFs (module docstring); ValueError on bad settings."""
    from rovlab.ident.dive import dof_model, simulate
    from rovlab.models.kinetics import hull_height

    dofs = tuple(dict.fromkeys(dofs))
    bad = [d for d in dofs if d not in PLAN_DOFS]
    if bad or not dofs:
        raise ValueError(f"--dofs: {', '.join(bad) or 'none'}: dive plans cover {', '.join(PLAN_DOFS)} (surge and sway "
                         "need position or velocity in the log, which a pressure sensor and an AHRS do not give)")
    for name, x in (("duration", duration_s), ("heave speed", heave_speed), ("yaw rate", yaw_rate), ("dt", dt),
                    ("depth gain", depth_gain)):
        if not (math.isfinite(x) and x > 0):
            raise ValueError(f"{name} must be a positive number, got {x}")
    if not 30.0 <= duration_s <= 7200.0:
        raise ValueError(f"duration must be 30 .. 7200 s, got {duration_s:g}")
    half = 0.5 * hull_height(vehicle)
    if not (math.isfinite(depth_min) and math.isfinite(depth_max)) or depth_min < half + 0.2:
        raise ValueError(f"depth band {depth_min:g} .. {depth_max:g} m: its top must be at least {half + 0.2:.2f} m deep "
                         "(half the hull's height + 0.2 m): the plan stays submerged, away from the free surface")
    if depth_max - depth_min < 0.8:
        raise ValueError(f"depth band {depth_min:g} .. {depth_max:g} m: give at least 0.8 m between the two")
    if not 0 < hold_s[0] <= hold_s[1]:
        raise ValueError(f"hold times {hold_s}: expected 0 < shortest <= longest")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s / dt))
    cap = dof_capacity(vehicle)
    trim = float(vehicle.buoyancy - vehicle.weight)
    band = depth_max - depth_min
    mid = 0.5 * (depth_min + depth_max)
    Z = np.zeros(n)
    N = np.zeros(n)
    rest = np.zeros(n, dtype=bool)
    t = dt * np.arange(n)
    if rest_s > 0 and rest_every_s > 0:
        rest = (t % (rest_every_s + rest_s)) >= rest_every_s
    amp = {}
    if "heave" in dofs:
        room = min(-cap["heave"][0], cap["heave"][1]) * fraction - abs(trim) - depth_gain * 0.5 * band
        if room <= 0:
            raise ValueError(f"{vehicle.name}: no heave thrust left for excitation after the trim {trim:g} N and the "
                             "depth law")
        amp["heave"] = min(room, _damping_force(vehicle, 2, heave_speed))
    if "yaw" in dofs:
        amp["yaw"] = min(min(-cap["yaw"][0], cap["yaw"][1]) * fraction, _damping_force(vehicle, 3, yaw_rate))
    for dof in dofs:
        if not amp[dof] > 0:
            raise ValueError(f"{vehicle.name}: the vehicle file's {dof} damping is 0, so no amplitude reaches a speed; "
                             "give the file a damping guess")
    if "yaw" in dofs:
        k = 0
        while k < n:
            m = int(round(rng.uniform(*hold_s) / dt))
            N[k:k + m] = rng.choice((-1.0, 1.0)) * amp["yaw"] * _level(rng)
            k += max(m, 1)
        N[rest] = 0.0
    if "heave" in dofs:
        model = dof_model(vehicle, "heave")
        z, w = mid, 0.0
        lo, hi = depth_min + 0.15 * band, depth_max - 0.15 * band
        k = 0
        while k < n:
            m = max(1, int(round(rng.uniform(*hold_s) / dt)))
            sign = rng.choice((-1.0, 1.0))
            if abs(z - mid) > band / 6:
                sign = -1.0 if z > mid else 1.0  # towards the middle (z down: a positive Z goes deeper)
            level = sign * amp["heave"] * _level(rng)
            for j in range(k, min(k + m, n)):
                if rest[j]:
                    level_j = 0.0
                else:
                    level_j = level
                f = trim + level_j + depth_gain * (mid - z)
                ps, vs = simulate(model, [f, f], 0.5 * dt, z, w)
                z, w = ps[-1], vs[-1]
                Z[j] = level_j
                if not rest[j] and ((z > hi and level > 0) or (z < lo and level < 0)):
                    k = j + 1
                    break
            else:
                k = min(k + m, n)
    Z, N = np.round(Z, 3), np.round(N, 5)  # as the plan file writes them (rovlab lab dive flies the file)
    settings = {"heave_speed": heave_speed, "yaw_rate": yaw_rate, "hold_s": list(hold_s), "rest_every_s": rest_every_s,
                "rest_s": rest_s, "fraction": fraction, "amplitude": {d: float(a) for d, a in amp.items()}}
    return DivePlan(vehicle.name, dofs, dt, Z, N, float(depth_min), float(depth_max), float(mid), float(depth_gain),
                    trim, cap, int(seed), settings=settings)


# --------------------------------------------------------------------------------------------
# Expected standard deviations (Fisher information at the vehicle file's guess)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Expected:
    dof: str
    key: str
    name: str
    unit: str
    guess: float
    sigma: float

    @property
    def percent(self) -> float:
        return 100.0 * self.sigma / abs(self.guess) if self.guess != 0 else math.inf


def expected_sigmas(vehicle: Vehicle, plan: DivePlan, *, split: float = 0.7,
                    free: Sequence[str] | None = None) -> list[Expected]:
    """Cramér-Rao standard deviations of the parameters that ``rovlab identify dive`` estimates
    from this plan (module docstring)."""
    from rovlab.ident import dive

    free = tuple(free or dive.DEFAULT_FREE)
    flight = dive.fly_plan(plan, vehicle, vehicle, noise=False)
    data = dive.dive_from_columns(flight.columns, vehicle, file="<nominal flight>")
    sens = dive.sensor_channels(vehicle)
    phi = math.exp(-0.05 / dive.AHRS_TAU_S)
    inflate = {}
    for key in ("heading",):
        if key in sens and vehicle.sensor(sens[key][1]).reports == "estimate":
            inflate[sens[key][0]] = math.sqrt((1 + phi) / (1 - phi))
    a, b = data.span
    t1 = a + split * (b - a)
    out: list[Expected] = []
    for dof in plan.dofs:
        start = dive.dof_model(vehicle, dof)
        keys = [k for k in dive.KEYS if k in free and not (dof == "yaw" and k == "net_buoyancy")]
        prob = dive._Problem(data, dof, start, keys, a, t1)
        w = np.array([c.sigma * inflate.get(c.name, 1.0) for c in prob.channels])
        theta = prob.initial(start)
        J = prob.jacobian(theta, w)
        cov = np.linalg.pinv(J.T @ J)
        for i, k in enumerate(keys):
            out.append(Expected(dof, k, dive.NAMES[dof][k], dive.UNITS[dof][k], float(getattr(start, k)),
                                float(math.sqrt(max(cov[i, i], 0.0)))))
    return out


# --------------------------------------------------------------------------------------------
# Plan files (TOML)
# --------------------------------------------------------------------------------------------

def write_plan(path: str | Path, plan: DivePlan, expected: Sequence[Expected] = (), *, command: str = "") -> Path:
    """The plan as TOML: settings, depth guard and the wrench at each change (held until the next)."""
    import tomlkit

    from rovlab.core.files import atomic_write_text

    change = np.flatnonzero(np.r_[True, (np.diff(plan.Z) != 0) | (np.diff(plan.N) != 0)])
    doc = tomlkit.document()
    doc.add(tomlkit.comment("rovlab dive plan: an excitation manoeuvre for rovlab identify dive (docs/identification.md)"))
    doc.add(tomlkit.comment("the wrench [Z N, N m] from each time t_s on, on top of the trim and the depth law"))
    doc["vehicle"] = plan.vehicle
    doc["dofs"] = list(plan.dofs)
    doc["duration_s"] = plan.duration_s
    doc["command_step_s"] = plan.dt
    doc["seed"] = plan.seed
    doc["source"] = command or f"rovlab lab plan-dive ({_dt.date.today().isoformat()})"
    g = tomlkit.table()
    g["depth_min"] = plan.depth_min
    g["depth_max"] = plan.depth_max
    g["start_depth"] = plan.start_depth
    g["depth_gain"] = plan.depth_gain
    g["trim_Z"] = round(plan.trim_Z, 6)
    g["capacity_Z"] = [round(x, 4) for x in plan.capacity.get("heave", (0.0, 0.0))]
    g["capacity_N"] = [round(x, 4) for x in plan.capacity.get("yaw", (0.0, 0.0))]
    doc["guard"] = g
    s = tomlkit.table()
    for k, v in plan.settings.items():
        s[k] = v
    doc["settings"] = s
    e = tomlkit.table()
    e["t_s"] = [round(float(x), 6) for x in change * plan.dt]
    e["Z"] = [round(float(x), 3) for x in plan.Z[change]]
    e["N"] = [round(float(x), 5) for x in plan.N[change]]
    doc["excitation"] = e
    if expected:
        ex = tomlkit.aot()
        for x in expected:
            t = tomlkit.table()
            t["parameter"] = x.name
            t["dof"] = x.dof
            t["guess"] = x.guess
            t["sigma"] = float(f"{x.sigma:.4g}")
            ex.append(t)
        doc["expected"] = ex
    path = Path(path)
    atomic_write_text(path, tomlkit.dumps(doc))
    return path


def read_plan(path: str | Path) -> DivePlan:
    """A plan file written by :func:`write_plan`; ConfigError naming the key for anything wrong."""
    from rovlab.params.validate import Collector, TableReader, read_toml

    data = read_toml(path)
    col = Collector(str(path))
    top = TableReader(data, col)
    vehicle = top.string("vehicle")
    raw_dofs = top.raw("dofs", ["heave", "yaw"])
    dofs = tuple(raw_dofs) if isinstance(raw_dofs, list) else ()
    if not dofs or not all(d in PLAN_DOFS for d in dofs):
        top.problem("dofs", raw_dofs, f"a list of {', '.join(PLAN_DOFS)}")
    duration = top.number("duration_s", positive=True, hi=7200.0)
    dt = top.number("command_step_s", positive=True, hi=10.0)
    seed = top.integer("seed", 0, lo=0)
    source = top.string("source", "")
    g = top.table("guard")
    dmin = g.number("depth_min", nonnegative=True, hi=1e4)
    dmax = g.number("depth_max", positive=True, hi=1e4)
    start = g.number("start_depth", nonnegative=True, hi=1e4)
    gain = g.number("depth_gain", nonnegative=True, hi=1e4, what="N/m")
    trim = g.number("trim_Z", lo=-1e4, hi=1e4, what="N")
    capz = g.vector("capacity_Z", 2)
    capn = g.vector("capacity_N", 2)
    g.finish()
    settings = top.table("settings", required=False)
    settings_data = {k: settings.raw(k) for k in list(settings.data)}  # informative only
    e = top.table("excitation")
    ts = e.vector("t_s")
    zs = e.vector("Z")
    ns = e.vector("N")
    e.finish()
    top.raw("expected", None)  # informative only (what plan-dive expected)
    top.finish()
    if math.isfinite(dmin) and math.isfinite(dmax) and dmax <= dmin:
        col.add("guard.depth_max", dmax, f"a depth below depth_min ({dmin:g} m)")
    if ts.size and not (ts.size == zs.size == ns.size):
        col.add("excitation", f"{ts.size}, {zs.size}, {ns.size} values", "t_s, Z and N of one length")
    elif ts.size and (np.any(np.diff(ts) <= 0) or ts[0] != 0.0):
        col.add("excitation.t_s", "not increasing from 0", "times increasing from 0")
    col.raise_if_any("dive plan")
    n = int(round(duration / dt))
    tk = dt * np.arange(n)
    idx = np.searchsorted(ts, tk + 1e-9, side="right") - 1
    Z = zs[np.maximum(idx, 0)]
    N = ns[np.maximum(idx, 0)]
    return DivePlan(vehicle, dofs, dt, Z, N, dmin, dmax, start, gain, trim,
                    {"heave": (float(capz[0]), float(capz[1])), "yaw": (float(capn[0]), float(capn[1]))}, seed, source,
                    settings_data)
