"""Running a prepared scenario: :class:`Simulation` advances its components through the compiled
loop (rovlab.sim.loop) chunk by chunk; it is the only caller of the loop, for batch runs
(:func:`run_prepared`, :func:`simulate`), Monte Carlo (rovlab.sim.montecarlo) and the live HMI
(rovlab.sim.live) alike. Preparing is rovlab.sim.prepare, naming and judging what the loop logged
is rovlab.sim.results.
"""

from __future__ import annotations

import time
from typing import Any

from rovlab.core.components import (
    fresh,
)
from rovlab.sim.actuators import fresh_actuators
from rovlab.sim.compile import note_cached, record
from rovlab.sim.loop import Drive, Logs, explain_allocation, loop_for, new_logs, new_work, run_loop
from rovlab.sim.prepare import Prepared, first_rows, prepare
from rovlab.sim.results import SimResult, result_of


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

    Holds its own copies of the plant's, the estimator's, the controller's and the actuators'
    state, so a Prepared can be run many times. ``advance(drive)`` runs len(drive.refs) control steps.
    """

    def __init__(self, prep: Prepared) -> None:
        self.prep = prep
        self.plant = fresh(prep.plant)
        self.estimator = fresh(prep.design.estimator.kernel)
        self.controller = fresh(prep.design.controller.kernel)
        self.actuators = fresh_actuators(prep.actuators)  # the thrusters' dead-band side: the run's own
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
        return (self.plant, prep.sensors, self.estimator, self.controller, self.actuators, prep.nav_of,
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


def run_prepared(prep: Prepared) -> SimResult:
    """Run a prepared scenario from its start to its end."""
    started = time.time()
    return result_of(prep, Simulation(prep).advance(prep.drive), started)


def simulate(name_or_path: str, *, seed: int | None = None) -> SimResult:
    """Load a scenario (packaged name or TOML path), run it and return the logs."""
    from rovlab.sim.scenario import load_scenario

    return run_prepared(prepare(load_scenario(name_or_path, seed=seed)))
