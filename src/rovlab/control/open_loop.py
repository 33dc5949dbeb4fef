"""An open-loop controller component: the wrench it demands is the one set from outside.

A vehicle node that flies a dive plan (rovlab.interfaces.node.flight) computes each step's
wrench itself (the plan's excitation, trim and weak depth law: rovlab.ident.plan.Flyer) and
hands it to this component's ``state`` before the step; the compiled control step
(rovlab.sim.step.control_step) then allocates it, turns it into PWM and lets the estimator
predict with the wrench the allocation achieved, exactly as it does for a feedback law. No
maths of its own::

    tau = state        # [X, Y, Z, N], set by the caller before each step
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.components import register_controller


class OpenLoop(NamedTuple):
    """The controller slot's component for a wrench commanded from outside (module docstring)."""

    state: np.ndarray  # (4) the wrench to demand at the next step [X, Y, Z, N] (N, N m)


@njit(cache=True, **WITHOUT_NRT)  # called by the control step: compiled alike whoever calls it first
def _open_loop_step(ctrl, t, nav, ref, tau):
    for i in range(4):
        tau[i] = ctrl.state[i]


def open_loop() -> OpenLoop:
    """A fresh component demanding zero wrench until its ``state`` is set."""
    return OpenLoop(state=np.zeros(4))


register_controller(OpenLoop, state=("state",), step=_open_loop_step)

__all__ = ["OpenLoop", "open_loop"]
