"""Designing the estimator and the controller a configuration or a scenario names.

Which estimators and controllers exist is declared by the components themselves
(rovlab.core.components.ComponentInfo: the shipped ones and those of installed packages, found
through entry points); a design configuration or a scenario chooses them with
``estimator = "<name>"`` and ``controller = "<name>"``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from rovlab.core.components import ControllerSpec, EstimatorSpec, component, unknown_component
from rovlab.params.design import DesignConfig
from rovlab.params.validate import ConfigError, Problem
from rovlab.params.vehicle import Vehicle


def build_pair(vehicle: Vehicle, config: DesignConfig, *, estimator: str | None = None,
               controller: str | None = None, file: str | None = None,
               estimator_options: Mapping[str, Any] | None = None) -> tuple[EstimatorSpec, ControllerSpec]:
    """Design the chosen estimator and controller; ConfigError if a name is unknown or the
    controller needs something the estimator does not estimate. ``estimator``/``controller``
    override the configuration's choice (from ``file``, e.g. a scenario); ``estimator_options``
    are keyword arguments of the estimator's build (e.g. the KF's ``require_observable``)."""
    cfg_file = config.file or config.name
    est_name = estimator or config.estimator
    ctl_name = controller or config.controller
    est_where = (file or cfg_file) if estimator else cfg_file
    where = (file or cfg_file) if controller else cfg_file
    problems = []
    est_info = component("estimator", est_name)
    ctl_info = component("controller", ctl_name)
    if est_info is None:
        problems.append(Problem(est_where, "estimator", est_name, unknown_component("estimator", est_name)))
    if ctl_info is None:
        problems.append(Problem(where, "controller", ctl_name, unknown_component("controller", ctl_name)))
    if problems or est_info is None or ctl_info is None:
        raise ConfigError(problems, "filter configuration")
    est = est_info.build(vehicle, config, **(estimator_options or {}))
    ctl = ctl_info.build(vehicle, config)
    _check_specs(est_name, est, ctl_name, ctl)
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


def _check_specs(est_name: str, est: EstimatorSpec, ctl_name: str, ctl: ControllerSpec) -> None:
    """What a component's build returned, checked against the loop's layouts (a mistake in a new
    component, named, instead of an IndexError after a whole run)."""
    from rovlab.core.components import REFERENCE, TRUTH, WRENCH

    where = "docs/architecture.md, step 4"
    bad = [q for q in est.nav if q not in TRUTH]
    if bad:
        raise TypeError(f"estimator {est_name!r}: EstimatorSpec.nav names {', '.join(map(repr, bad))}, not quantities of "
                        f"the estimate (rovlab.core.components.TRUTH: {', '.join(TRUTH)}; {where})")
    n = np.asarray(est.kernel.x).shape[0]
    if len(est.states) != n or len(est.nav) != n:
        raise TypeError(f"estimator {est_name!r}: {len(est.states)} state names and {len(est.nav)} nav entries for an "
                        f"estimate x of {n} entries ({where})")
    for field, names, layout in (("needs", ctl.needs, TRUTH), ("references", ctl.references, REFERENCE),
                                 ("outputs", ctl.outputs, WRENCH)):
        bad = [q for q in names if q not in layout]
        if bad:
            raise TypeError(f"controller {ctl_name!r}: ControllerSpec.{field} names {', '.join(map(repr, bad))}, not "
                            f"in {'TRUTH' if layout is TRUTH else 'REFERENCE' if layout is REFERENCE else 'WRENCH'} "
                            f"({', '.join(layout)}; {where})")
    m = np.asarray(ctl.kernel.state).shape[0] if hasattr(ctl.kernel, "state") else 0
    if ctl.state_names and len(ctl.state_names) != m:
        raise TypeError(f"controller {ctl_name!r}: ControllerSpec.state_names has {len(ctl.state_names)} names for a "
                        f"state array of {m} entries ({where})")
