"""Designs shared by runs: the estimator, the controller and the allocation designed from a model
vehicle and a design configuration, and the book that holds them for the runs of one caller.

:func:`make_design` asks each component what it needs: the checks a controller declares against
the vehicle's thrusters (rovlab.core.components.ComponentInfo.check, e.g. MRAC's heave force) and
the linear model an estimator offers as the observer plant (ComponentInfo.observer_model, the
depth-and-heading KF's). There is no hidden cache here: a :class:`DesignBook` is owned by its
caller and passed in (rovlab.sim.prepare.prepare).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.allocation.solvers import Allocator
from rovlab.core.components import ControllerSpec, EstimatorSpec, component, component_names
from rovlab.models.discretise import discretise
from rovlab.models.noise import psd_factor
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle
from rovlab.sim.components import build_pair


@dataclass(frozen=True, eq=False)
class Design:
    """What depends only on the model vehicle, the configuration and the plant fidelity."""

    vehicle: Vehicle
    config: DesignConfig
    estimator: EstimatorSpec
    controller: ControllerSpec
    allocator: Allocator
    plant: str  # "process" or "observer"
    plant_step: float
    observer_plant: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # (Phi, Delta, L) at the plant step


def make_design(vehicle: Vehicle, config: DesignConfig, *, plant: str, plant_step: float,
                estimator: str | None = None, controller: str | None = None, file: str | None = None) -> Design:
    """Design the estimator, controller and allocation (raises ConfigError), with the checks the
    components declare (rovlab.core.components.ComponentInfo.check / observer_model)."""
    est, ctl = build_pair(vehicle, config, estimator=estimator, controller=controller, file=file)
    est_info = component("estimator", estimator or config.estimator)
    ctl_info = component("controller", controller or config.controller)
    alloc = Allocator(vehicle, pwm_hysteresis_us=config.pwm_hysteresis_us)  # the closed loop's PWM commands
    where = config.file or config.name
    for info, spec in ((est_info, est), (ctl_info, ctl)):
        if info is not None and info.check is not None:
            info.check(spec, alloc, where)
    observer = None
    if plant == "observer":
        model = est_info.observer_model(est) if est_info is not None and est_info.observer_model else None
        if model is None or np.shape(model[0]) != (6, 6):
            offer = [n for n in component_names("estimator")
                     if (i := component("estimator", n)) is not None and i.observer_model is not None]
            raise ConfigError([Problem(file or config.file, "plant", plant,
                                       "the process plant: the observer plant is an estimator's own linear "
                                       f"depth-and-heading model, which estimator {est_info.name if est_info else '?'!r} "
                                       f"does not offer (estimators that do: {', '.join(offer) or 'none'})")],
                              "scenario file")
        A, B, E, W = model
        disc = discretise(A, B, E, W, plant_step)
        observer = (np.ascontiguousarray(disc.Phi), np.ascontiguousarray(disc.Delta),
                    np.ascontiguousarray(psd_factor(disc.Q)))
    return Design(vehicle, config, est, ctl, alloc, plant, plant_step, observer)


class DesignBook:
    """Loaded vehicle/configuration files and designs, shared by the runs of a caller (e.g. a
    Monte Carlo). Owned and passed in explicitly; files are reloaded when they change on disk."""

    def __init__(self) -> None:
        self._files: dict[tuple, Any] = {}
        self._designs: dict[tuple, Design] = {}

    def load(self, loader: Callable[[str], Any], ref: str) -> Any:
        path = Path(ref)
        stamp = path.stat().st_mtime_ns if path.exists() else None
        key = (loader.__name__, ref, stamp)
        if key not in self._files:
            self._files[key] = loader(ref)
        return self._files[key]

    def design(self, vehicle: Vehicle, config: DesignConfig, **kw: Any) -> Design:
        key = (id(vehicle), id(config), *sorted(kw.items()))
        hit = self._designs.get(key)
        if hit is None or hit.vehicle is not vehicle or hit.config is not config:
            hit = self._designs[key] = make_design(vehicle, config, **kw)
        return hit


