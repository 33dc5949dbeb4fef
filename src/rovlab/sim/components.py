"""Which estimators and controllers the simulator (and the vehicle nodes) can run, by name.

This is the registration step of a new component: write its module (a registered NamedTuple
with its kernels and a ``build(vehicle, config)`` returning an EstimatorSpec or ControllerSpec,
see docs/architecture.md), then add one line here. A design configuration or a scenario chooses
them with ``estimator = "<name>"`` and ``controller = "<name>"``.
"""

from __future__ import annotations

from collections.abc import Callable

from rovlab.control import dp, lqg, mrac
from rovlab.core.components import ControllerSpec, EstimatorSpec
from rovlab.estimation import ekf, kf
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle

ESTIMATORS: dict[str, Callable[[Vehicle, DesignConfig], EstimatorSpec]] = {
    "kf": kf.build,  # depth-and-heading Kalman filter (Sandøy 2016, sec. 5.1)
    "ekf": ekf.build,  # 4-DOF extended Kalman filter (Sandøy 2016, further work; rovlab.estimation.ekf)
}
CONTROLLERS: dict[str, Callable[[Vehicle, DesignConfig], ControllerSpec]] = {
    "lqg": lqg.build,  # LQR depth and heading with bias feed-forward (Sandøy 2016, sec. 5.2)
    "mrac": mrac.build,  # model-reference adaptive heave control, LQR heading (Sandøy 2016, sec. 5.2)
    "dp": dp.build,  # dynamic positioning x, y, z, psi (Fossen 2011, nonlinear PID + reference model)
}


def build_pair(vehicle: Vehicle, config: DesignConfig, *, estimator: str | None = None,
               controller: str | None = None, file: str | None = None) -> tuple[EstimatorSpec, ControllerSpec]:
    """Design the chosen estimator and controller; ConfigError if a name is unknown or the
    controller needs something the estimator does not estimate. ``estimator``/``controller``
    override the configuration's choice (from ``file``, e.g. a scenario)."""
    cfg_file = config.file or config.name
    est_name = estimator or config.estimator
    ctl_name = controller or config.controller
    est_where = (file or cfg_file) if estimator else cfg_file
    where = (file or cfg_file) if controller else cfg_file
    problems = []
    if est_name not in ESTIMATORS:
        problems.append(Problem(est_where, "estimator", est_name, "one of: " + ", ".join(ESTIMATORS)))
    if ctl_name not in CONTROLLERS:
        problems.append(Problem(where, "controller", ctl_name, "one of: " + ", ".join(CONTROLLERS)))
    if problems:
        raise ConfigError(problems, "filter configuration")
    est = ESTIMATORS[est_name](vehicle, config)
    ctl = CONTROLLERS[ctl_name](vehicle, config)
    missing = [q for q in ctl.needs if q not in est.provides]
    if missing:
        raise ConfigError([Problem(where, "controller", ctl_name,
                                   f"an estimator that estimates {', '.join(missing)} "
                                   f"(estimator {est_name!r} estimates {', '.join(est.nav)})")],
                          "filter configuration")
    if abs(est.h - config.sample_time) > 1e-12:
        raise ConfigError([Problem(cfg_file, "sample_time", config.sample_time,
                                   f"the estimator's sample time {est.h:g} s")], "filter configuration")
    return est, ctl
