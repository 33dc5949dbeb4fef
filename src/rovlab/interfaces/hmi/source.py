"""Where the HMI's live data comes from: a *source* publishes the messages of
:mod:`rovlab.io.messages` and takes a handful of commands.

:class:`SimulationSource` wraps :class:`rovlab.sim.live.LiveSimulation`. A bridge to the real
vehicle (ROS 2, MAVLink) implements the same :class:`Source` protocol: it returns the messages
that arrived since the last call instead of computing them, publishes no ``/rovlab/truth``, and
says ``paced = False`` so the HMI does not try to drive its clock. Everything the HMI shows and
logs is built from these messages only, so it cannot tell the two apart.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from rovlab.estimation.fusion import CH_MODE, MODE_NAMES
from rovlab.models.kinetics import mass_matrix
from rovlab.params.design import DesignConfig
from rovlab.params.vehicle import Vehicle
from rovlab.sim.live import LiveSimulation

Message = tuple[str, float, dict[str, Any]]
"""(topic, time [s], message) as built by rovlab.io.messages."""


@runtime_checkable
class Source(Protocol):
    """What the HMI needs from a simulation or a vehicle bridge (SI units, radians)."""

    kind: str  # "simulation" or "vehicle"
    paced: bool  # True: the HMI decides when steps happen (advance(n)); False: own clock

    @property
    def h(self) -> float:
        """Control period [s]."""

    @property
    def time(self) -> float:
        """Time of the next control step [s]."""

    def describe(self) -> dict[str, Any]:
        """Names and fixed facts: channels (name, column, sensor, quantity, offset), sensors, thrusters,
        and (optional) ``references``: which of x, y, z, psi the running controller holds (the page
        offers north/east set-points only when x and y are among them)."""

    def status(self) -> dict[str, Any]:
        """What the commands changed: reference, sensor availability, filter channel modes."""

    def advance(self, n: int) -> list[Message]:
        """Messages of the next n control steps (a bridge: the messages that arrived)."""

    def reset(self) -> None: ...

    def set_reference(self, z: float | None = None, psi: float | None = None, *, x: float | None = None,
                      y: float | None = None) -> None: ...

    def follow_schedule(self) -> None:
        """Go back to the scenario's (or mission's) reference schedule."""

    def set_sensor_available(self, sensor: str, available: bool) -> None: ...

    def set_filter_mode(self, channel: str, mode: str) -> None: ...

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        """Swap in new parameters (validated and designed first; raises and changes nothing on error)."""

    def loop_summary(self) -> dict[str, Any]:
        """The parameters and gains the running loop uses now (for display and checks)."""


class SimulationSource:
    """A :class:`LiveSimulation` seen through the :class:`Source` protocol."""

    kind = "simulation"
    paced = True

    def __init__(self, sim: LiveSimulation) -> None:
        self.sim = sim

    @property
    def h(self) -> float:
        return self.sim.h

    @property
    def time(self) -> float:
        return self.sim.time

    def describe(self) -> dict[str, Any]:
        sim = self.sim
        sc = sim.scenario
        est = sim.prep.design.estimator  # what every estimator declares (EstimatorSpec), a plugin's too
        return {
            "kind": self.kind,
            "scenario": {"name": sc.name, "description": sc.description, "plant": sc.plant, "seed": sc.seed,
                         "file": sc.file},
            "vehicle": sim.vehicle.name,
            "config": sim.config.name,
            "h": self.h,
            "has_truth": True,
            "states": list(est.states),
            "channels": [{"name": c.name, "column": c.column, "sensor": c.sensor, "quantity": c.quantity,
                          "offset": c.offset} for c in est.channels],
            "sensors": list(sim.sensor_available),
            "thrusters": list(sim.prep.allocator.bank.names),
            "controller": _controller_name(sim.prep),
            "controller_states": list(sim.prep.design.controller.state_names),
            "references": list(sim.prep.design.controller.references),  # of x, y, z, psi: what it holds
        }

    def status(self) -> dict[str, Any]:
        sim = self.sim
        modes = {name: MODE_NAMES[int(sim.state["chs"][j, CH_MODE])] for j, name in enumerate(sim.channels)}
        z, psi = sim.reference
        x, y = sim.reference_xy
        return {
            "time_s": sim.time,
            "reference": {"z": float(z), "psi": float(psi), "x": float(x), "y": float(y),
                          "schedule": bool(sim.reference_follows_scenario)},
            "sensors": dict(sim.sensor_available),
            "filter_modes": modes,
        }

    def advance(self, n: int) -> list[Message]:
        return self.sim.advance(n)

    def reset(self) -> None:
        self.sim.reset()

    def set_reference(self, z: float | None = None, psi: float | None = None, *, x: float | None = None,
                      y: float | None = None) -> None:
        self.sim.set_reference(z=z, psi=psi, x=x, y=y)

    def follow_schedule(self) -> None:
        self.sim.reference_follows_scenario = True

    def set_sensor_available(self, sensor: str, available: bool) -> None:
        self.sim.set_sensor_available(sensor, available)

    def set_filter_mode(self, channel: str, mode: str) -> None:
        self.sim.set_filter_mode(channel, mode)

    def apply(self, *, vehicle: Vehicle | None = None, truth: Vehicle | None = None,
              config: DesignConfig | None = None) -> None:
        self.sim.apply(vehicle=vehicle, truth=truth, config=config)

    def loop_summary(self) -> dict[str, Any]:
        prep = self.sim.prep
        return design_summary(prep.design, truth=prep.truth, controller=_controller_name(prep),
                              estimator=prep.scenario.estimator or prep.config.estimator)


def design_summary(design: Any, *, truth: Vehicle, controller: str, estimator: str | None = None) -> dict[str, Any]:
    """The parameters and gains of a running design (rovlab.sim.designs.Design), as the HMI shows
    them: shared by the simulation and the vehicle bridges' sources. Built from what the components
    declare (ComponentInfo.summary, their tables), so a plugin's estimator or controller is shown
    like a shipped one; the keys the page's bespoke forms read (model, K, P, Q_diag, mrac, dp) come
    from those summaries where a component gives them."""
    from rovlab.core.components import component, component_names
    from rovlab.core.summary import table_values

    v, config = design.vehicle, design.config
    estimator = estimator or config.estimator
    M = np.diag(mass_matrix(v))
    parts: dict[str, Any] = {}
    tables: dict[str, Any] = {}
    for kind, name, spec in (("estimator", estimator, design.estimator), ("controller", controller, design.controller)):
        info = component(kind, name)
        summary = info.summary(spec) if info is not None and info.summary is not None else {}
        parts[kind] = {"name": name, "description": info.description if info is not None else "", "summary": summary}
        if info is not None and info.default_table is not None:
            tables[name] = table_values(config.table(name))
    est, ctl = parts["estimator"]["summary"], parts["controller"]["summary"]
    model = {**config.model_values(v), "M_w": float(M[2]), "M_r": float(M[3]), **est.get("model", {})}
    out: dict[str, Any] = {
        "model": model,
        "vehicle": _vehicle_summary(v),
        "truth": _vehicle_summary(truth),
        "R": {c.name: c.variance for c in design.estimator.channels},
        "Q_diag": _floats(np.diag(np.asarray(est["Q"], dtype=float))) if "Q" in est else [],
        "lqr_Q": _floats(config.lqr_Q),
        "lqr_R": _floats(config.lqr_R),
        "K": [_floats(row) for row in ctl.get("K", [])],
        "P": [_floats(row) for row in ctl.get("P", [])],
        "estimator": estimator,
        "controller": controller,
        "components": parts,
        "tables": tables,
        "controllers": [{"name": n, "description": getattr(component("controller", n), "description", "")}
                        for n in component_names("controller")],
    }
    for key in ("mrac", "dp"):  # the adaptive law's design, the DP gains per axis: the page's own views
        if key in ctl:
            out[key] = ctl[key]
    return out


def _controller_name(prep: Any) -> str:
    return prep.scenario.controller or prep.config.controller


def _floats(a: Any) -> list[float]:
    return [float(x) for x in np.asarray(a, dtype=float).ravel()]


def _vehicle_summary(v: Vehicle) -> dict[str, Any]:
    return {
        "name": v.name, "mass": v.mass, "I_zz": v.I_zz, "displaced_volume": v.displaced_volume,
        "net_buoyancy": v.buoyancy - v.weight, "added_mass": _floats(v.added_mass),
        "damping_linear": _floats(v.damping_linear), "damping_quadratic": _floats(v.damping_quadratic),
        "damping_cubic": _floats(v.damping_cubic),
        "thrusters": {th.name: ([th.curve.K_L_pos, th.curve.K_NL_pos, th.curve.K_L_neg, th.curve.K_NL_neg]
                                if th.curve is not None else {"table": th.table, "voltage": th.voltage})
                      for th in v.thrusters},
    }

