"""A simulated vehicle stepped from outside: PWM commands in, truth and sensor samples out.

The one simulated vehicle behind every middleware: where the closed-loop simulator runs
estimator, controller and plant in one compiled loop, a :class:`SimulatedVehicle` runs only the
plant and the sensors of a scenario, one control period per :meth:`SimulatedVehicle.step`, with
the thrust of the PWM commands it was given. A command given with the time it reached the vehicle
(``set_pwm(..., at=t)``: a middleware in real time) acts from that time: a period in which it
arrived has the mean wrench of the commands in force over it, so the thrust never leads the
command (applied from the start of its period, the thrust had led the logged SERVO_OUTPUT_RAW by
0.05 s on average at 10 Hz, and identify dive found the added mass 12-40 % low from recordings of
`rovlab mavlink sim`). A command without a time acts from the start of the period to come
(a caller that steps and commands in turn, as the closed loop does). A middleware paces it in real time and
sends its samples as the real vehicle would: the ROS simulators (``rovlab ros2|ros1 sim``,
rovlab.interfaces.node) on the vehicle's topics, the MAVLink simulator (``rovlab mavlink sim``,
rovlab.interfaces.mavlink.vehicle_sim) as ArduSub's telemetry. Same components, same noise model,
biases, drop-out windows and truth events as the scenario's batch run
(rovlab.sim.step.plant_push / plant_sample).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rovlab.core.angles import wrap_angle
from rovlab.core.components import N_TRUTH, TRUTH, fresh, plant_draws
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle
from rovlab.sim.designs import DesignBook
from rovlab.sim.loop import Drive, draw
from rovlab.sim.prepare import disturbances, prepare, schedule
from rovlab.sim.scenario import Scenario, load_scenario

_CHUNK = 600  # control steps of noise drawn at a time


@dataclass(frozen=True, eq=False)
class VehicleSample:
    """What the simulated vehicle gives at step k (SI units, radians, NED/FRD)."""

    k: int
    t: float  # k h [s]
    truth: dict[str, float]  # TRUTH layout by name
    samples: tuple[tuple[str, str, float], ...]  # (sensor, quantity, raw value incl. lever arm) that arrived
    reference: tuple[float, float]  # the scenario's schedule at t: (z [m], psi [rad])
    tau: np.ndarray  # wrench [X, Y, Z, N] the commands gave over the last period


class SimulatedVehicle:
    """A scenario's plant and sensors, advanced one control period at a time (one thread steps it;
    :meth:`set_pwm` may be called from another)."""

    def __init__(self, scenario: str | Scenario, *, seed: int | None = None, vehicle: Vehicle | None = None,
                 truth: Vehicle | None = None, config: DesignConfig | None = None,
                 initial: Mapping[str, float] | None = None) -> None:
        """``vehicle`` replaces the scenario's vehicle (model and truth), ``truth`` only the plant's;
        ``initial`` replaces entries of the scenario's true initial state by name (x, y, z [m],
        psi [rad], u, v, w [m/s], r [rad/s]); ValueError for an unknown name or a value that is not
        finite."""
        from rovlab.models.thrusters import bank_pwm

        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario, seed=seed)
        if initial:
            sc = replace(sc, initial=_initial_state(sc.initial, initial))
        self.scenario = sc
        seed = self.scenario.seed if seed is None else seed
        self.prep = prepare(replace(self.scenario, duration_s=0.0), vehicle=vehicle, truth=truth, config=config,
                            book=DesignBook())
        self.plant = fresh(self.prep.plant)
        self.rng = np.random.default_rng(seed)
        self.rng.standard_normal(4)  # the initial bias draw, as in rovlab.sim.prepare.prepare
        act = self.prep.actuators
        self.neutral_pwm = np.asarray(bank_pwm(act.rows, act.grid_pwm, act.grid_force, np.zeros(act.rows.shape[0])))
        self.pwm = self.neutral_pwm.copy()  # the last command given
        self._pwm_start = self.pwm  # the command in force at the start of the period to simulate
        self._changes: list[tuple[float, np.ndarray]] = []  # (time it arrived [s], command) since then
        self._commands = threading.Lock()  # set_pwm may come from a middleware's callback thread (rospy)
        self.k = 0
        self._k0 = 0
        self._drive: Drive | None = None
        m = len(self.prep.channels)
        self._truth = np.empty(N_TRUTH)
        self._y = np.empty(m)
        self._present = np.zeros(m, dtype=np.bool_)
        self._tau = np.zeros(4)
        self.unavailable: set[str] = set()

    @property
    def h(self) -> float:
        return float(self.prep.h)

    @property
    def thrusters(self) -> tuple[str, ...]:
        return tuple(self.prep.allocator.bank.names)

    @property
    def channels(self) -> tuple[Any, ...]:
        """The filter channels the sensors serve (rovlab.estimation.model.Channel)."""
        return tuple(self.prep.channels)

    def sensor_kind(self, sensor: str) -> str:
        return self.prep.truth.sensor(sensor).kind

    def set_pwm(self, pwm_us: Any, *, at: float | None = None) -> None:
        """The thrusters' PWM commands [us], in the vehicle file's order (held until the next call).
        ``at``: the simulated time [s] the command reached the vehicle; it acts from then (module
        docstring). None: from the start of the next period :meth:`step` simulates. ValueError, and
        the old commands kept, for a wrong length or a value that is not finite."""
        if at is not None and not math.isfinite(at):
            raise ValueError(f"the time a PWM command arrived must be finite, got {at!r}")
        try:
            a = np.asarray(pwm_us, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"PWM commands must be numbers, got {pwm_us!r}") from None
        if a.shape[0] != len(self.thrusters):
            raise ValueError(f"{a.shape[0]} PWM commands for {len(self.thrusters)} thrusters "
                             f"({', '.join(self.thrusters)})")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"PWM commands must be finite, got {a.tolist()}")
        with self._commands:
            if at is None:
                self.pwm = self._pwm_start = a.copy()
                self._changes = []
            elif not np.array_equal(a, self.pwm):  # a middleware repeats the command it holds: not a change
                self.pwm = a.copy()
                self._changes.append((float(at), self.pwm))

    def step(self) -> VehicleSample:
        """Advance to the next control step (the first call gives step 0 without advancing)."""
        from rovlab.sim.step import plant_push, plant_sample

        k = self.k
        if k > 0:
            drive = self._chunk_for(k - 1)
            pwms, weights = self._period_commands((k - 1) * self.h, k * self.h)
            plant_push(self.plant, self.prep.actuators, drive, k - 1 - self._k0, pwms, weights, self._tau)
        drive = self._chunk_for(k)
        if not plant_sample(k, self.plant, self.prep.sensors, drive, k - self._k0, self._truth, self._y,
                            self._present):
            raise RuntimeError(f"the simulated plant diverged at t = {k * self.h:g} s")
        samples = tuple((c.sensor, c.quantity, float(self._y[j])) for j, c in enumerate(self.prep.channels)
                        if self._present[j] and c.sensor not in self.unavailable)
        t = k * self.h
        self.k = k + 1
        return VehicleSample(k, t, dict(zip(TRUTH, map(float, self._truth))), samples,
                             self.scenario.reference_at(t), self._tau.copy())

    def compile(self) -> float:
        """Compile the plant's step if numba has not cached it yet, without advancing this vehicle
        (on copies of its state, with draws of their own); the seconds it took. A middleware calls
        it before it announces the vehicle, so nothing waits on a vehicle that cannot step yet."""
        from rovlab.sim.step import plant_push, plant_sample

        t0 = time.perf_counter()
        prep = self.prep
        plant = fresh(prep.plant)
        m = len(prep.channels)
        plant_push(plant, prep.actuators, prep.drive, 0, self.neutral_pwm[None, :].copy(), np.ones(1), np.zeros(4))
        plant_sample(0, plant, prep.sensors, prep.drive, 0, np.empty(N_TRUTH), np.empty(m),
                     np.zeros(m, dtype=np.bool_))
        return time.perf_counter() - t0

    def _period_commands(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """The commands in force over [t0, t1] and the fraction of it each was (for plant_push);
        commands that arrived after t1 stay for the next period."""
        with self._commands:
            return self._take_commands(t0, t1)

    def _take_commands(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        current, since = self._pwm_start, t0
        rows: list[np.ndarray] = []
        weights: list[float] = []
        later: list[tuple[float, np.ndarray]] = []
        for at, pwm in self._changes:
            if at >= t1:
                later.append((at, pwm))
                continue
            at = max(at, since)
            if at > since:
                rows.append(current)
                weights.append((at - since) / (t1 - t0))
            current, since = pwm, at
        rows.append(current)
        weights.append((t1 - since) / (t1 - t0))
        self._pwm_start, self._changes = current, later
        return np.array(rows), np.array(weights)

    def _chunk_for(self, k: int) -> Drive:
        if self._drive is None or not (self._k0 <= k < self._k0 + _CHUNK):
            prep, sc = self.prep, self.scenario
            times = (k + np.arange(_CHUNK)) * self.h
            dropout, refs = schedule(sc, prep.channels, times)
            plant_n, bias_n, sensor_n = draw(self.rng, _CHUNK, prep.plant.n_sub, plant_draws(prep.plant),
                                             len(prep.channels))
            heave, pset = disturbances(sc, times, observer=sc.plant == "observer", g=prep.truth.gravity)
            self._drive = Drive(plant_n, bias_n, sensor_n, dropout, refs, heave, pset)
            self._k0 = k
        return self._drive


_STATE = ("x", "y", "z", "psi", "u", "v", "w", "r")  # layout of Scenario.initial


def _initial_state(initial: np.ndarray, names: Mapping[str, float]) -> np.ndarray:
    out = np.array(initial, dtype=float)
    for name, value in names.items():
        if name not in _STATE:
            raise ValueError(f"no initial state {name!r}; the state is {', '.join(_STATE)}")
        v = float(value)
        if not np.isfinite(v):
            raise ValueError(f"initial {name} must be finite, got {value!r}")
        out[_STATE.index(name)] = wrap_angle(v) if name == "psi" else v
    return out
