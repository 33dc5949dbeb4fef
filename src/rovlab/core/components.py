"""The slots of the closed loop: how a plant, an estimator and a controller plug into it.

The simulator's compiled loop (:mod:`rovlab.sim.loop`) runs, at every control sample,

    plant -> sensors -> estimator (correct) -> controller -> allocation and thrusters
          -> estimator (predict) -> controller (actuated) -> plant (advance)

and calls each component only through the slot functions below. A **component** is a
``typing.NamedTuple`` of numpy arrays and scalars: its constants (gains, packed models, sizes
taken from its model) and its state (covariance, channel states, integrators, adaptive
parameters) as arrays that the kernels update in place. Its registration names its state
fields (``state=(...)``), so a caller can copy, save and restore the state of any component
without knowing what it is (:func:`state_fields`, :func:`fresh`, :func:`state_of`,
:func:`restore`).

Slot functions (all compiled; the arrays are float64 unless noted):

``plant_truth(plant, truth)``
    the true state at t_k into ``truth`` (N_TRUTH, layout TRUTH).
``plant_advance(plant, drive, row, tau_cmd, tau_real)``
    integrate from t_k to t_k + h with the wrench held: ``tau_cmd`` (4: X, Y, Z, N) is what the
    allocation asked of the thrusters, ``tau_real`` (4) what their PWM commands really give;
    ``drive`` holds the run's noise draws (row = this chunk's step index).
``plant_advance_lanes(plants, drives, row, lanes)``
    the same for several runs at once (a Monte Carlo's lanes, rovlab.sim.loop.run_loop_lanes):
    ``plants`` is the runs' plants stacked (:func:`stacked`: each state field with a leading
    lane axis, the constants shared), ``drives`` their drives stacked the same way
    (rovlab.sim.loop.stacked_drive), and ``lanes`` (rovlab.sim.loop.Lanes) holds each lane's
    tau_cmd and tau_real (LANES x 4), which lanes are running (``active``) and a scratch array.
    A plant may register a kernel that advances the lanes together (vectorised); without one,
    each running lane is advanced by its ``plant_advance`` (on :func:`lane_of` the stack).
    Either way every lane gets exactly the numbers of its run alone.
``estimator_correct(est, t, y, present, rep)``
    correct with the samples y (m) that arrived (present, bool); fill ``rep`` (m x N_REP of
    rovlab.estimation.fusion). Every estimator has the fields ``x`` (n), ``P`` (n x n) and
    ``ch`` (m x N_CH, the sensor-management state), which the loop reads after the correction.
``estimator_predict(est, t, tau)``
    project to t + h with the wrench tau (4: X, Y, Z, N) the allocation achieved.
``controller_step(ctrl, t, nav, ref, tau)``
    the demanded wrench tau (4: X, Y, Z, N) from the estimate ``nav`` (N_TRUTH, layout TRUTH;
    entries the estimator does not estimate are 0) and the reference ``ref`` (4: x, y, z, psi).
    Every controller has a field ``state`` (1-D, possibly empty) that the loop logs.
``controller_actuated(ctrl, t, tau_demanded, tau_achieved)``
    what the allocation could give (for anti-windup and adaptation); a no-op for most laws.

Registering a component class binds its kernels to the slots (``register_plant``,
``register_estimator``, ``register_controller``). The binding is resolved when the loop is
compiled (numba ``overload``), so a loop compiled for one estimator and one controller contains
those and nothing else, and is cached on disk per combination.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rovlab import _jit

# Layout of the truth vector and of the estimate handed to controllers (world position and
# heading, body velocities, and the force/moment biases per DOF).
TRUTH = ("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N")
N_TRUTH = len(TRUTH)
TRUTH_INDEX = {name: i for i, name in enumerate(TRUTH)}
ANGLES = frozenset({"psi"})
# Layout of the reference vector and of a wrench.
REFERENCE = ("x", "y", "z", "psi")
WRENCH = ("X", "Y", "Z", "N")

# Runs a Monte Carlo advances together (rovlab.sim.loop.run_loop_lanes): sixteen float64 fill
# two AVX-512 vectors (four AVX2 ones), and the lanes loop is compiled for this one count.
LANES = 16
LANE_SCRATCH_ROWS = 64  # rows of LANES float64 of scratch a plant's lanes kernel may use (rovlab.sim.loop.Lanes)

_STATE: dict[type, tuple[str, ...]] = {}  # component class -> its state fields
_DRAWS: dict[type, int] = {}  # plant class -> standard normal draws per integration step
_REGISTRY: dict[str, dict[type, Callable[..., Any]]] = {
    "plant_truth": {}, "plant_advance": {}, "plant_advance_lanes": {},
    "estimator_correct": {}, "estimator_predict": {},
    "controller_step": {}, "controller_actuated": {},
}


def _fields(cls: type) -> tuple[str, ...]:
    fields = getattr(cls, "_fields", None)
    if not (isinstance(cls, type) and issubclass(cls, tuple) and isinstance(fields, tuple)):
        raise TypeError(f"{cls!r} is not a NamedTuple class")
    return fields


def _register_state(cls: type, state: tuple[str, ...], required: tuple[str, ...]) -> None:
    fields = _fields(cls)
    for f in (*state, *required):
        if f not in fields:
            raise TypeError(f"{cls.__name__} has no field {f!r} (its fields: {', '.join(fields)})")
    _STATE[cls] = tuple(state)
    _jit.aliases_its_arguments(cls)  # lane_of builds the class in compiled code (a lane's views)


def register_plant(cls: type, *, state: tuple[str, ...], draws: int, truth: Callable, advance: Callable,
                   advance_lanes: Callable | None = None) -> None:
    """Bind a plant class: truth(plant, truth), advance(plant, drive, row, tau_cmd, tau_real);
    ``draws`` standard normal numbers per integration step come in drive.plant_normals;
    ``advance_lanes(plants, drives, row, lanes)`` optionally advances a Monte Carlo's lanes
    together (by default each lane is advanced alone)."""
    _register_state(cls, state, ())
    _DRAWS[cls] = int(draws)
    _REGISTRY["plant_truth"][cls] = truth
    _REGISTRY["plant_advance"][cls] = advance
    _REGISTRY["plant_advance_lanes"][cls] = advance_lanes if advance_lanes is not None else _lane_by_lane


def register_estimator(cls: type, *, state: tuple[str, ...], correct: Callable, predict: Callable) -> None:
    """Bind an estimator class: correct(est, t, y, present, rep), predict(est, t, tau)."""
    _register_state(cls, state, ("x", "P", "ch"))
    _REGISTRY["estimator_correct"][cls] = correct
    _REGISTRY["estimator_predict"][cls] = predict


def register_controller(cls: type, *, state: tuple[str, ...], step: Callable,
                        actuated: Callable | None = None) -> None:
    """Bind a controller class: step(ctrl, t, nav, ref, tau), actuated(ctrl, t, tau_d, tau_a)."""
    _register_state(cls, state, ("state",))
    _REGISTRY["controller_step"][cls] = step
    _REGISTRY["controller_actuated"][cls] = actuated if actuated is not None else _no_actuated


def _no_actuated(ctrl, t, tau_demanded, tau_achieved):  # pragma: no cover - compiled
    return None


def _lane_by_lane(plants, drives, row, lanes):
    """plant_advance_lanes of a plant without a lanes kernel: each running lane by its
    plant_advance."""
    for lane in range(lanes.active.shape[0]):
        if lanes.active[lane]:
            plant_advance(lane_of(plants, lane), lane_of(drives, lane), row, lanes.tau_cmd[lane],
                          lanes.tau_real[lane])


# --------------------------------------------------------------------------------------------
# Copying state without knowing the component
# --------------------------------------------------------------------------------------------

def state_fields(component: Any) -> tuple[str, ...]:
    """The names of a registered component's state fields."""
    try:
        return _STATE[type(component)]
    except KeyError:
        raise TypeError(f"{type(component).__name__} is not a registered component") from None


def plant_draws(plant: Any) -> int:
    """Standard normal draws per integration step that a registered plant takes."""
    return _DRAWS[type(plant)]


def fresh(component: Any) -> Any:
    """The component with its own copies of its state arrays (the constants are shared)."""
    return component._replace(**{f: np.array(getattr(component, f), copy=True) for f in state_fields(component)})


def state_of(component: Any) -> dict[str, np.ndarray]:
    """A copy of the component's state, by field name."""
    return {f: np.array(getattr(component, f), copy=True) for f in state_fields(component)}


def register_lanes(cls: type, *, stacked: tuple[str, ...]) -> None:
    """Make :func:`lane_of` work on a NamedTuple that is not a component but has per-run fields
    in the lanes' loop (rovlab.sim.loop: the drives' draws, the logs): ``stacked`` are the
    fields that get a leading lane axis."""
    _register_state(cls, stacked, ())


def stacked(components: Any) -> Any:
    """Runs' components of one class stacked for the lanes of a Monte Carlo: the first one's
    constants (the runs must share them) and each state field with a leading lane axis (lane i
    is a copy of components[i]'s state). :func:`lane_of` gives a lane back as a component."""
    first = components[0]
    fields = state_fields(first)
    for c in components[1:]:
        if type(c) is not type(first):
            raise TypeError(f"stacked: {type(c).__name__} among {type(first).__name__}")
    return first._replace(**{f: np.ascontiguousarray(np.stack([np.asarray(getattr(c, f)) for c in components]))
                             for f in fields})


def lane_of(stack: Any, lane: int) -> Any:
    """Lane ``lane`` of :func:`stacked` components (or of a :func:`register_lanes` tuple): the
    component whose state fields are views of that lane (compiled code builds it in registers,
    without copying)."""
    return stack._replace(**{f: getattr(stack, f)[lane] for f in state_fields(stack)})


def restore(component: Any, state: dict[str, np.ndarray]) -> list[str]:
    """Copy saved state into the component where the field exists and the shape matches;
    returns the fields that were restored."""
    done = []
    for f in state_fields(component):
        if f in state:
            target = getattr(component, f)
            src = np.asarray(state[f])
            if src.shape == target.shape:
                target[...] = src
                done.append(f)
    return done


# --------------------------------------------------------------------------------------------
# Slot functions (resolved at compile time)
# --------------------------------------------------------------------------------------------

# Called from compiled code, a slot is replaced by the registered kernel at compile time (the
# overloads below). Called from Python (an interpreted run: NUMBA_DISABLE_JIT, see rovlab._jit)
# it looks the kernel up by the component's class.

def _bound(slot: str, component: Any) -> Callable[..., Any]:
    try:
        return _REGISTRY[slot][type(component)]
    except KeyError:
        raise TypeError(f"{slot}: {type(component).__name__} is not registered "
                        f"(rovlab.core.components.register_*)") from None


def plant_truth(plant, truth):
    return _bound("plant_truth", plant)(plant, truth)


def plant_advance(plant, drive, row, tau_cmd, tau_real):
    return _bound("plant_advance", plant)(plant, drive, row, tau_cmd, tau_real)


def plant_advance_lanes(plants, drives, row, lanes):
    return _bound("plant_advance_lanes", plants)(plants, drives, row, lanes)


def estimator_correct(est, t, y, present, rep):
    return _bound("estimator_correct", est)(est, t, y, present, rep)


def estimator_predict(est, t, tau):
    return _bound("estimator_predict", est)(est, t, tau)


def controller_step(ctrl, t, nav, ref, tau):
    return _bound("controller_step", ctrl)(ctrl, t, nav, ref, tau)


def controller_actuated(ctrl, t, tau_demanded, tau_achieved):
    return _bound("controller_actuated", ctrl)(ctrl, t, tau_demanded, tau_achieved)


def _install_overloads() -> None:
    """Make the slot functions compile to the registered kernels (numba ``overload``). Not done
    in a process that runs without numba (rovlab._jit.run_without_numba: the loop built ahead of
    time), where the slots are only ever called from Python."""
    from numba.core import types
    from numba.core.errors import TypingError
    from numba.extending import overload

    def _lookup(slot: str, comp_type) -> Callable:
        cls = getattr(comp_type, "instance_class", None)
        if isinstance(comp_type, types.BaseNamedTuple) and cls in _REGISTRY[slot]:
            return _REGISTRY[slot][cls]
        raise TypingError(f"{slot}: {cls.__name__ if cls else comp_type} is not registered "
                          f"(rovlab.core.components.register_*)")


    @overload(plant_truth, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_plant_truth(plant, truth):
        fn = _lookup("plant_truth", plant)
        return lambda plant, truth: fn(plant, truth)


    @overload(plant_advance, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_plant_advance(plant, drive, row, tau_cmd, tau_real):
        fn = _lookup("plant_advance", plant)
        return lambda plant, drive, row, tau_cmd, tau_real: fn(plant, drive, row, tau_cmd, tau_real)


    @overload(plant_advance_lanes)  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_plant_advance_lanes(plants, drives, row, lanes):
        fn = _lookup("plant_advance_lanes", plants)
        if fn is _lane_by_lane:
            return lambda plants, drives, row, lanes: _lanes_alone(plants, drives, row, lanes)
        return lambda plants, drives, row, lanes: fn(plants, drives, row, lanes)


    @overload(lane_of, inline="always")
    def _ol_lane_of(stack, index):
        cls = getattr(stack, "instance_class", None)
        if cls not in _STATE:
            raise TypingError(f"lane_of: {stack} is not a registered component")
        state = _STATE[cls]
        parts = ", ".join(f"stack.{f}[index]" if f in state else f"stack.{f}" for f in cls._fields)
        namespace: dict[str, Any] = {"cls": cls}
        exec(f"def lane_of_impl(stack, index):\n    return cls({parts})\n", namespace)
        return namespace["lane_of_impl"]


    @overload(estimator_correct, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_estimator_correct(est, t, y, present, rep):
        fn = _lookup("estimator_correct", est)
        return lambda est, t, y, present, rep: fn(est, t, y, present, rep)


    @overload(estimator_predict, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_estimator_predict(est, t, tau):
        fn = _lookup("estimator_predict", est)
        return lambda est, t, tau: fn(est, t, tau)


    @overload(controller_step, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_controller_step(ctrl, t, nav, ref, tau):
        fn = _lookup("controller_step", ctrl)
        return lambda ctrl, t, nav, ref, tau: fn(ctrl, t, nav, ref, tau)


    @overload(controller_actuated, inline="always")  # no cache: a non-rovlab component must not enter a shared cache index
    def _ol_controller_actuated(ctrl, t, tau_demanded, tau_achieved):
        fn = _lookup("controller_actuated", ctrl)
        if fn is _no_actuated:
            return lambda ctrl, t, tau_demanded, tau_achieved: None
        return lambda ctrl, t, tau_demanded, tau_achieved: fn(ctrl, t, tau_demanded, tau_achieved)


if not _jit.without_numba():
    _install_overloads()
    _jit.aliases_its_arguments(lane_of)
    _lanes_alone = _jit.njit(_lane_by_lane)


# --------------------------------------------------------------------------------------------
# What a component's builder returns (Python side: names and sizes for logs, checks, display)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class EstimatorSpec:
    """A designed estimator: its compiled component and what the loop needs to know of it."""

    kernel: Any  # the component (a registered NamedTuple) with its initial state
    states: tuple[str, ...]  # names of its states (log columns est_<name>)
    nav: tuple[str, ...]  # per state, the TRUTH quantity it estimates
    channels: tuple[Any, ...]  # the measurement channels it fuses (rovlab.estimation.model.Channel)
    h: float  # sample time [s]
    model: Any = None  # the design behind it (for display), e.g. a FilterModel

    @property
    def provides(self) -> frozenset[str]:
        return frozenset(self.nav)


@dataclass(frozen=True, eq=False)
class ControllerSpec:
    """A designed controller: its compiled component and what it needs from the estimate."""

    kernel: Any
    needs: tuple[str, ...]  # TRUTH quantities it reads from the estimate
    references: tuple[str, ...]  # REFERENCE entries it follows
    outputs: tuple[str, ...] = WRENCH  # WRENCH entries it commands (log columns tau_<name>)
    state_names: tuple[str, ...] = ()  # names of the entries of kernel.state (log columns)
    model: Any = None  # the design behind it (for display), e.g. an LQRDesign
