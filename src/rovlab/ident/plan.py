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

**Surge and sway** (``--dofs ...,surge,sway``; they need a position sensor -- kind motion_capture
with x, y: USBL, motion capture, ArduSub's LOCAL_POSITION_NED -- or a DVL in the vehicle file: the
log must carry position or velocity, and the guard must know where the vehicle is). Body-frame
forces turn with the heading, and a turning vehicle couples surge and sway through the Coriolis
terms (M_v v r in surge, -M_u u r in sway). So the plan time-shares: the 40 s excitation periods
alternate between yaw (the yaw moment excited, no surge or sway force) and horizontal ones (random
multi-level surge and sway forces, independent of each other, while the yaw excitation is off and
a weak heading law -- ``heading_gain`` (psi_ref - psi) - ``heading_damping`` r, about a 1 rad/s,
0.7-damped loop on the file's yaw inertia -- holds the heading the period began with). Heave is
excited throughout. Without yaw in ``dofs`` every period is horizontal. rovlab.ident.dive
still models the rotation (the logged heading and yaw rate are inputs), so what the heading law
lets through costs nothing. Levels: log-uniform as for heave, reaching ``surge_speed`` /
``sway_speed`` by the file's damping, capped at 80 % of ``dof_capacity``. A horizontal guard keeps
the vehicle in a box of ``box_m`` about its start (a pool is small): a weak position law
(``position_gain`` N/m towards the start, turned into the body frame by the heading) and, when
the position leaves the box, the excitation paused and the law four times as strong until the
vehicle is back in the box's middle half -- as the depth band does for heave. The guard's position
is the positioning system's, or with only a DVL its velocity integrated with the heading (dead
reckoning, as ArduSub's EKF gives LOCAL_POSITION_NED from a DVL). Surge and sway holds are cut
short where the file's model predicts leaving the middle 70 % of the box, and point back to the
middle when off-centre.
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

PLAN_DOFS = ("heave", "yaw", "surge", "sway")
HORIZONTAL = ("surge", "sway")
_W6 = {"heave": 2, "yaw": 5, "surge": 0, "sway": 1}


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
    # surge and sway (module docstring); None / 0 in a heave and yaw plan
    X: np.ndarray | None = None  # surge force per command step [N] (the excitation; the position law on top)
    Y: np.ndarray | None = None  # sway force per command step [N]
    hold: np.ndarray | None = None  # True where the heading law holds the heading (yaw excitation off)
    box_m: float = 0.0  # side of the square about the start the vehicle is kept in [m]
    position_gain: float = 0.0  # [N/m]
    heading_gain: float = 0.0  # [N m/rad]
    heading_damping: float = 0.0  # [N m s/rad]

    @property
    def horizontal(self) -> bool:
        return self.X is not None and any(d in HORIZONTAL for d in self.dofs)

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
        self.h_guarded = False  # outside the box (surge / sway plans)
        self.origin: tuple[float, float] | None = None
        self.psi_ref: float | None = None

    def step(self, k: int, depth: float, *, heading: float | None = None, rate: float | None = None,
             position: tuple[float, float] | None = None) -> tuple[list[float], bool]:
        """The wrench [X, Y, Z, N] to command at step ``k`` from the measured depth and, for a surge
        and sway plan, the measured heading, yaw rate and NED position (x, y); and whether a guard
        holds the excitation."""
        p = self.plan
        if depth < p.depth_min or depth > p.depth_max:
            self.guarded = True
        elif self.guarded and self.inner[0] <= depth <= self.inner[1]:
            self.guarded = False
        if not p.horizontal:
            gain = p.depth_gain * (4.0 if self.guarded else 1.0)
            exc_z = 0.0 if self.guarded else float(p.Z[k])
            exc_n = 0.0 if self.guarded else float(p.N[k])
            lo, hi = p.capacity.get("heave", (-math.inf, math.inf))
            z = min(max(p.trim_Z + exc_z + gain * (self.mid - depth), 0.95 * lo), 0.95 * hi)
            return [0.0, 0.0, z, exc_n], self.guarded
        return self._step_horizontal(k, depth, heading, rate, position)

    def _step_horizontal(self, k: int, depth: float, heading: float | None, rate: float | None,
                         position: tuple[float, float] | None) -> tuple[list[float], bool]:
        p = self.plan
        assert p.X is not None and p.Y is not None and p.hold is not None
        if heading is None or position is None:
            raise ValueError("a surge and sway plan is flown with the measured heading and position")
        if self.origin is None:
            self.origin = (float(position[0]), float(position[1]))
        dn, de = position[0] - self.origin[0], position[1] - self.origin[1]
        half = 0.5 * p.box_m
        if abs(dn) > half or abs(de) > half:
            self.h_guarded = True
        elif self.h_guarded and abs(dn) <= 0.5 * half and abs(de) <= 0.5 * half:
            self.h_guarded = False
        guarded = self.guarded or self.h_guarded
        gain = p.depth_gain * (4.0 if self.guarded else 1.0)
        exc = 0.0 if guarded else 1.0
        lo, hi = p.capacity.get("heave", (-math.inf, math.inf))
        z = min(max(p.trim_Z + exc * float(p.Z[k]) + gain * (self.mid - depth), 0.95 * lo), 0.95 * hi)
        if p.hold[k]:
            if self.psi_ref is None:
                self.psi_ref = heading
            err = math.remainder(self.psi_ref - heading, 2.0 * math.pi)
            n = p.heading_gain * err - p.heading_damping * (rate or 0.0)
        else:
            self.psi_ref = None
            n = exc * float(p.N[k])
        lo_n, hi_n = p.capacity.get("yaw", (-math.inf, math.inf))
        n = min(max(n, 0.95 * lo_n), 0.95 * hi_n)
        kp = p.position_gain * (4.0 if self.h_guarded else 1.0)
        fn, fe = -kp * dn, -kp * de  # towards the start, NED
        c, s = math.cos(heading), math.sin(heading)
        x = exc * float(p.X[k]) + c * fn + s * fe
        y = exc * float(p.Y[k]) - s * fn + c * fe
        lo_x, hi_x = p.capacity.get("surge", (-math.inf, math.inf))
        lo_y, hi_y = p.capacity.get("sway", (-math.inf, math.inf))
        x = min(max(x, 0.95 * lo_x), 0.95 * hi_x)
        y = min(max(y, 0.95 * lo_y), 0.95 * hi_y)
        return [x, y, z, n], guarded


def dof_capacity(vehicle: Vehicle) -> dict[str, tuple[float, float]]:
    """(most negative, most positive) force [N] / moment [N m] the thrusters give in heave, yaw,
    surge and sway alone, along the allocation's pseudo-inverse direction within the thrust limits."""
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
              rest_s: float = 5.0, depth_gain: float = 4.0, fraction: float = 0.8, surge_speed: float = 0.4,
              sway_speed: float = 0.3, box_m: float = 10.0, position_gain: float = 2.0,
              heading_bandwidth: float = 1.0) -> DivePlan:
    """A random multi-level excitation of the DOFs (module docstring); ValueError on bad settings."""
    from rovlab.ident.dive import dof_model, simulate
    from rovlab.models.kinetics import hull_height

    dofs = tuple(dict.fromkeys(dofs))
    bad = [d for d in dofs if d not in PLAN_DOFS]
    if bad or not dofs:
        raise ValueError(f"--dofs: {', '.join(bad) or 'none'}: dive plans cover {', '.join(PLAN_DOFS)}")
    horiz = tuple(d for d in dofs if d in HORIZONTAL)
    if horiz:
        _horizontal_sensor(vehicle)
        for name, x in (("surge speed", surge_speed), ("sway speed", sway_speed), ("box", box_m),
                        ("position gain", position_gain), ("heading bandwidth", heading_bandwidth)):
            if not (math.isfinite(x) and x > 0):
                raise ValueError(f"{name} must be a positive number, got {x}")
        if box_m < 2.0:
            raise ValueError(f"box {box_m:g} m: give at least 2 m (the vehicle moves ~1 m per hold at the plan's speeds)")
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
    for dof in amp:
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
    if not horiz:
        return DivePlan(vehicle.name, dofs, dt, Z, N, float(depth_min), float(depth_max), float(mid),
                        float(depth_gain), trim, cap, int(seed), settings=settings)
    # surge and sway (module docstring): a second random stream, so heave and yaw keep their sequences
    period = rest_every_s + rest_s if rest_every_s > 0 else 45.0
    cycle = np.floor(t / period + 1e-9).astype(int)
    hold = (cycle % 2 == 1) if "yaw" in dofs else np.ones(n, dtype=bool)
    N[hold] = 0.0
    rng_h = np.random.default_rng([seed, 1])
    XY = {"surge": np.zeros(n), "sway": np.zeros(n)}
    speeds = {"surge": surge_speed, "sway": sway_speed}
    for dof in horiz:
        i = _W6[dof]
        amp[dof] = min(min(-cap[dof][0], cap[dof][1]) * fraction, _damping_force(vehicle, i, speeds[dof]))
        if not amp[dof] > 0:
            raise ValueError(f"{vehicle.name}: the vehicle file's {dof} damping is 0, so no amplitude reaches a speed; "
                             "give the file a damping guess")
        model = dof_model(vehicle, dof)
        pos, vel = 0.0, 0.0
        lim = 0.35 * box_m
        k = 0
        while k < n:
            m = max(1, int(round(rng_h.uniform(*hold_s) / dt)))
            sign = rng_h.choice((-1.0, 1.0))
            if abs(pos) > box_m / 6:
                sign = -1.0 if pos > 0 else 1.0
            level = sign * amp[dof] * _level(rng_h)
            for j in range(k, min(k + m, n)):
                on = hold[j] and not rest[j]
                f = (level if on else 0.0) - position_gain * pos
                ps, vs = simulate(model, [f, f], 0.5 * dt, pos, vel)
                pos, vel = ps[-1], vs[-1]
                XY[dof][j] = level if on else 0.0
                if on and ((pos > lim and level > 0) or (pos < -lim and level < 0)):
                    k = j + 1
                    break
            else:
                k = min(k + m, n)
        XY[dof] = np.round(XY[dof], 3)
    inertia = float(vehicle.I_zz - vehicle.added_mass[3])
    settings |= {"surge_speed": surge_speed, "sway_speed": sway_speed, "heading_bandwidth": heading_bandwidth,
                 "amplitude": {d: float(a) for d, a in amp.items()}}
    return DivePlan(vehicle.name, dofs, dt, Z, np.round(N, 5), float(depth_min), float(depth_max), float(mid),
                    float(depth_gain), trim, cap, int(seed), settings=settings, X=XY["surge"], Y=XY["sway"], hold=hold,
                    box_m=float(box_m), position_gain=float(position_gain),
                    heading_gain=round(inertia * heading_bandwidth**2, 4),
                    heading_damping=round(2.0 * 0.7 * heading_bandwidth * inertia, 4))


def _horizontal_sensor(vehicle: Vehicle) -> str:
    """'position' or 'dvl': what tells a surge / sway plan where the vehicle is; ValueError naming
    the vehicle and the sensor needed when it has neither."""
    from rovlab.ident.dive import sensor_channels

    sens = sensor_channels(vehicle)
    if "x" in sens and "y" in sens:
        return "position"
    if "u" in sens and "v" in sens:
        return "dvl"
    raise ValueError(f"{vehicle.name}: surge and sway need position or velocity in the log and a position for the box "
                     "guard, and the vehicle file has no such sensor; add a [[sensors]] of kind motion_capture with x "
                     "and y (USBL, motion capture, ArduSub's LOCAL_POSITION_NED) or of kind dvl with u and v (bottom "
                     "track, e.g. the packaged bluerov2_heavy_dvl)")


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
        if dof in HORIZONTAL:
            continue
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
    horiz = [d for d in plan.dofs if d in HORIZONTAL]
    if horiz:  # surge and sway together, as rovlab.ident.dive.fit_horizontal fits them
        starts = {d: dive.dof_model(vehicle, d) for d in HORIZONTAL}
        hkeys = [(d, k) for d in horiz for k in dive.KEYS if k in free and k != "net_buoyancy"]
        hp = dive.HorizontalProblem(data, starts, hkeys, a, t1)
        J = hp.jacobian(hp.initial(), hp.sigma)
        cov = np.linalg.pinv(J.T @ J)
        for i, (d, k) in enumerate(hkeys):
            out.append(Expected(d, k, dive.NAMES[d][k], dive.UNITS[d][k], float(getattr(starts[d], k)),
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
    if plan.horizontal:
        assert plan.X is not None and plan.Y is not None and plan.hold is not None
        change = np.flatnonzero(np.r_[True, (np.diff(plan.Z) != 0) | (np.diff(plan.N) != 0) | (np.diff(plan.X) != 0)
                                      | (np.diff(plan.Y) != 0) | (np.diff(plan.hold.astype(int)) != 0)])
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
    if plan.horizontal:
        g["box_m"] = plan.box_m
        g["position_gain"] = plan.position_gain
        g["heading_gain"] = plan.heading_gain
        g["heading_damping"] = plan.heading_damping
        g["capacity_X"] = [round(x, 4) for x in plan.capacity.get("surge", (0.0, 0.0))]
        g["capacity_Y"] = [round(x, 4) for x in plan.capacity.get("sway", (0.0, 0.0))]
    doc["guard"] = g
    s = tomlkit.table()
    for k, v in plan.settings.items():
        s[k] = v
    doc["settings"] = s
    e = tomlkit.table()
    e["t_s"] = [round(float(x), 6) for x in change * plan.dt]
    e["Z"] = [round(float(x), 3) for x in plan.Z[change]]
    e["N"] = [round(float(x), 5) for x in plan.N[change]]
    if plan.horizontal:
        assert plan.X is not None and plan.Y is not None and plan.hold is not None
        e.add(tomlkit.comment("X, Y: surge and sway force [N] on top of the position law; hold: 1 where the heading law "
                              "holds the heading (the yaw excitation off)"))
        e["X"] = [round(float(x), 3) for x in plan.X[change]]
        e["Y"] = [round(float(x), 3) for x in plan.Y[change]]
        e["hold"] = [int(x) for x in plan.hold[change]]
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
    horiz = any(d in HORIZONTAL for d in dofs)
    if horiz:
        box = g.number("box_m", positive=True, hi=1e4, what="m")
        pgain = g.number("position_gain", nonnegative=True, hi=1e4, what="N/m")
        hgain = g.number("heading_gain", nonnegative=True, hi=1e4, what="N m/rad")
        hdamp = g.number("heading_damping", nonnegative=True, hi=1e4, what="N m s/rad")
        capx = g.vector("capacity_X", 2)
        capy = g.vector("capacity_Y", 2)
    g.finish()
    settings = top.table("settings", required=False)
    settings_data = {k: settings.raw(k) for k in list(settings.data)}  # informative only
    e = top.table("excitation")
    ts = e.vector("t_s")
    zs = e.vector("Z")
    ns = e.vector("N")
    if horiz:
        xs, ys, hs = e.vector("X"), e.vector("Y"), e.vector("hold")
    e.finish()
    top.raw("expected", None)  # informative only (what plan-dive expected)
    top.finish()
    if math.isfinite(dmin) and math.isfinite(dmax) and dmax <= dmin:
        col.add("guard.depth_max", dmax, f"a depth below depth_min ({dmin:g} m)")
    elif math.isfinite(start) and not dmin <= start <= dmax:  # the flight starts there (the bridge's --fly)
        col.add("guard.start_depth", start, f"a depth within the band {dmin:g} .. {dmax:g} m")
    # what a flight commands is bounded by these: a capacity without its two signs, or an excitation beyond
    # it, is another vehicle's plan or a hand edit (the bridge's --fly would command it)
    for key, bounds, values in (("Z", capz, zs), ("N", capn, ns)):
        if np.all(np.isfinite(bounds)) and not bounds[0] < 0.0 < bounds[1]:
            col.add(f"guard.capacity_{key}", [float(c) for c in bounds], "[most negative < 0, most positive > 0]")
        elif np.all(np.isfinite(bounds)) and values.size and np.all(np.isfinite(values)) \
                and (values.min() < bounds[0] or values.max() > bounds[1]):
            col.add(f"excitation.{key}", f"{values.min():g} .. {values.max():g}",
                    f"values within guard.capacity_{key} ({bounds[0]:g} .. {bounds[1]:g})")
    if ts.size and not (ts.size == zs.size == ns.size):
        col.add("excitation", f"{ts.size}, {zs.size}, {ns.size} values", "t_s, Z and N of one length")
    elif ts.size and (np.any(np.diff(ts) <= 0) or ts[0] != 0.0):
        col.add("excitation.t_s", "not increasing from 0", "times increasing from 0")
    if horiz and ts.size and not (ts.size == xs.size == ys.size == hs.size):
        col.add("excitation", f"{ts.size}, {xs.size}, {ys.size}, {hs.size} values", "t_s, X, Y and hold of one length")
    elif horiz and hs.size and not np.all((hs == 0) | (hs == 1)):
        col.add("excitation.hold", "values other than 0 and 1", "0 or 1 (1: the heading law holds the heading)")
    col.raise_if_any("dive plan")
    n = int(round(duration / dt))
    tk = dt * np.arange(n)
    idx = np.searchsorted(ts, tk + 1e-9, side="right") - 1
    Z = zs[np.maximum(idx, 0)]
    N = ns[np.maximum(idx, 0)]
    cap = {"heave": (float(capz[0]), float(capz[1])), "yaw": (float(capn[0]), float(capn[1]))}
    if not horiz:
        return DivePlan(vehicle, dofs, dt, Z, N, dmin, dmax, start, gain, trim, cap, seed, source, settings_data)
    cap |= {"surge": (float(capx[0]), float(capx[1])), "sway": (float(capy[0]), float(capy[1]))}
    i = np.maximum(idx, 0)
    return DivePlan(vehicle, dofs, dt, Z, N, dmin, dmax, start, gain, trim, cap, seed, source, settings_data,
                    X=xs[i], Y=ys[i], hold=hs[i] > 0.5, box_m=box, position_gain=pgain, heading_gain=hgain,
                    heading_damping=hdamp)
