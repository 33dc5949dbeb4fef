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

# Layout of the truth vector and of the estimate handed to controllers (world position and
# heading, body velocities, and the force/moment biases per DOF).
TRUTH = ("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N")
N_TRUTH = len(TRUTH)
TRUTH_INDEX = {name: i for i, name in enumerate(TRUTH)}
ANGLES = frozenset({"psi"})
# Layout of the reference vector and of a wrench.
REFERENCE = ("x", "y", "z", "psi")
WRENCH = ("X", "Y", "Z", "N")
# The same layouts as named indices, for kernels (a module-level integer is a constant to numba:
# nav[NAV_W] compiles to what nav[6] did)
NAV_X, NAV_Y, NAV_Z, NAV_PSI, NAV_U, NAV_V, NAV_W, NAV_R, NAV_BX, NAV_BY, NAV_BZ, NAV_BN = range(12)
REF_X, REF_Y, REF_Z, REF_PSI = range(4)
TAU_X, TAU_Y, TAU_Z, TAU_N = range(4)
if TRUTH != ("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N"):  # pragma: no cover - a reminder
    raise ImportError("rovlab.core.components: the NAV_* indices no longer follow TRUTH")

_STATE: dict[type, tuple[str, ...]] = {}  # component class -> its state fields
_DRAWS: dict[type, int] = {}  # plant class -> standard normal draws per integration step
_REGISTRY: dict[str, dict[type, Callable[..., Any]]] = {
    "plant_truth": {}, "plant_advance": {},
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


def register_plant(cls: type, *, state: tuple[str, ...], draws: int, truth: Callable, advance: Callable) -> None:
    """Bind a plant class: truth(plant, truth), advance(plant, drive, row, tau_cmd, tau_real);
    ``draws`` standard normal numbers per integration step come in drive.plant_normals."""
    _register_state(cls, state, ())
    _DRAWS[cls] = int(draws)
    _REGISTRY["plant_truth"][cls] = truth
    _REGISTRY["plant_advance"][cls] = advance


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


# --------------------------------------------------------------------------------------------
# Copying state without knowing the component
# --------------------------------------------------------------------------------------------

def state_fields(component: Any) -> tuple[str, ...]:
    """The names of a registered component's state fields."""
    try:
        return _STATE[type(component)]
    except KeyError:
        raise TypeError(f"{type(component).__name__} is not a registered component: its module must call "
                        "rovlab.core.components.register_estimator, register_controller or register_plant for it, "
                        "naming its state fields (docs/architecture.md, step 3)") from None


def plant_draws(plant: Any) -> int:
    """Standard normal draws per integration step that a registered plant takes."""
    return _DRAWS[type(plant)]


def fresh(component: Any) -> Any:
    """The component with its own copies of its state arrays (the constants are shared)."""
    return component._replace(**{f: np.array(getattr(component, f), copy=True) for f in state_fields(component)})


def state_of(component: Any) -> dict[str, np.ndarray]:
    """A copy of the component's state, by field name."""
    return {f: np.array(getattr(component, f), copy=True) for f in state_fields(component)}


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
# overloads below). Called from Python (NUMBA_DISABLE_JIT set by the user: every kernel plain)
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


def estimator_correct(est, t, y, present, rep):
    return _bound("estimator_correct", est)(est, t, y, present, rep)


def estimator_predict(est, t, tau):
    return _bound("estimator_predict", est)(est, t, tau)


def controller_step(ctrl, t, nav, ref, tau):
    return _bound("controller_step", ctrl)(ctrl, t, nav, ref, tau)


def controller_actuated(ctrl, t, tau_demanded, tau_achieved):
    return _bound("controller_actuated", ctrl)(ctrl, t, tau_demanded, tau_achieved)


def _install_overloads() -> None:
    """Make the slot functions compile to the registered kernels (numba ``overload``, numba's
    public extension API)."""
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


_install_overloads()


# --------------------------------------------------------------------------------------------
# Which estimators and controllers exist: each declares itself (ComponentInfo), shipped or not
# --------------------------------------------------------------------------------------------

KINDS = ("estimator", "controller")
# The components that ship with rovlab, by name -> the module that declares them. Components of
# other packages are found through Python entry points in the groups ENTRY_POINT_GROUPS, whose
# name is the component's name and whose value is the module that declares it (importing it calls
# register_component), e.g. in a plugin's pyproject.toml:
#     [project.entry-points."rovlab.estimators"]
#     complementary = "rovlab_example_plugin.complementary"
SHIPPED = {
    "estimator": {"kf": "rovlab.estimation.kf", "ekf": "rovlab.estimation.ekf"},
    "controller": {"lqg": "rovlab.control.lqg", "mrac": "rovlab.control.mrac", "dp": "rovlab.control.dp"},
}
ENTRY_POINT_GROUPS = {"estimator": "rovlab.estimators", "controller": "rovlab.controllers"}
# the keys every design file has (rovlab.params.design): no component's table may take one
RESERVED = frozenset({"name", "description", "source", "sample_time", "estimator", "controller", "model",
                      "process_noise", "initial", "fusion", "measurements", "lqr"})


@dataclass(frozen=True, eq=False)
class ComponentInfo:
    """What an estimator or a controller declares about itself (its module calls
    :func:`register_component` with it when imported).

    ``build(vehicle, config)`` designs it from a vehicle and a design configuration
    (rovlab.params.design.DesignConfig) and returns an :class:`EstimatorSpec` or
    :class:`ControllerSpec`. A component may own a table of the design file named after it
    (``[mrac]``, ``[pd]``): ``parse_table(reader)`` reads it with the loader's own TableReader
    (rovlab.params.validate: the same checks and messages; the table's keys are closed), and
    ``default_table()`` gives the value a file without the table gets; the design reads it as
    ``config.table(name)``. An estimator names the quantities a measurement may give it
    (``measurable``, e.g. z, psi, w, r).

    ``check(spec, allocator, where)``, if given, is called with the built spec and the vehicle's
    allocation (rovlab.allocation.solvers.Allocator) when a design is made: it raises ConfigError
    (file ``where``, the key of its table) when the vehicle's thrusters cannot do what the design
    asks (MRAC: the heave force of its reference model). ``observer_model(spec)``, if given, makes
    an estimator's own linear model usable as a scenario's observer plant (plant = "observer"):
    the continuous (A, B, E, W) of its six states [z, w, b_w, psi, r, b_r] (the depth-and-heading
    KF's, Sandøy 2016 sec. 5.1).

    ``summary(spec)``, if given, is what ``rovlab design --json``, the HMI and the nodes show of a
    designed component: named numbers and arrays (SI units, JSON values); ``describe(spec)`` the
    same for people, as lines of text (default: the summary, rendered by rovlab.core.summary). A
    component with neither is shown by its table's values.
    """

    name: str
    kind: str  # "estimator" or "controller"
    build: Callable[..., Any]
    description: str = ""
    parse_table: Callable[[Any], Any] | None = None
    default_table: Callable[[], Any] | None = None
    measurable: tuple[str, ...] = ()
    check: Callable[[Any, Any, str], None] | None = None
    observer_model: Callable[[Any], tuple[Any, Any, Any, Any]] | None = None
    summary: Callable[[Any], dict[str, Any]] | None = None
    describe: Callable[[Any], list[str]] | None = None


_COMPONENTS: dict[str, dict[str, ComponentInfo]] = {k: {} for k in KINDS}
_FAILED: dict[str, dict[str, str]] = {k: {} for k in KINDS}  # name -> why its module did not load


def register_component(info: ComponentInfo) -> None:
    """Declare an estimator or a controller (called by its module when imported)."""
    if info.kind not in KINDS:
        raise ValueError(f"component {info.name!r}: kind must be one of {', '.join(KINDS)}, got {info.kind!r}")
    if not info.name or not info.name.replace("_", "").replace("-", "").isalnum():
        raise ValueError(f"component name {info.name!r}: letters, digits, '-' and '_' only")
    if (info.parse_table is None) != (info.default_table is None):
        raise ValueError(f"component {info.name!r}: parse_table and default_table go together")
    if info.name in RESERVED:
        raise ValueError(f"component name {info.name!r} is a key of every design file; choose another")
    shipped = SHIPPED[info.kind].get(info.name)
    if shipped is not None and getattr(info.build, "__module__", None) != shipped:
        raise ValueError(f"{info.kind} {info.name!r} is rovlab's own ({shipped}); a plugin chooses another name")
    _COMPONENTS[info.kind][info.name] = info


_FOUND: dict[str, dict[str, Callable[[], Any]]] = {}  # kind -> the declared components, looked up once


def _declared(kind: str) -> dict[str, Callable[[], Any]]:
    """name -> how to import the module that declares it: the shipped ones, then the entry points
    of installed packages (read once per process: scanning the installed packages' metadata costs
    tens of milliseconds, and a design file is loaded per run by some callers)."""
    found = _FOUND.get(kind)
    if found is not None:
        return found
    import functools
    import importlib

    out: dict[str, Callable[[], Any]] = {}
    for name, module in SHIPPED[kind].items():
        out[name] = functools.partial(importlib.import_module, module)
    eps: Any = ()
    try:
        from importlib.metadata import entry_points

        eps = entry_points(group=ENTRY_POINT_GROUPS[kind])
    except Exception:  # noqa: BLE001 - broken package metadata must not stop rovlab
        pass
    for ep in eps:
        if ep.name not in out:  # a shipped name cannot be taken over
            out[ep.name] = ep.load
    _FOUND[kind] = out
    return out


def component_names(kind: str) -> tuple[str, ...]:
    """Every estimator or controller name there is (shipped and installed plugins), without
    importing them."""
    return tuple(dict.fromkeys([*_declared(kind), *_COMPONENTS[kind]]))


def component(kind: str, name: str) -> ComponentInfo | None:
    """The declaration of a component (importing its module the first time), or None if there is
    no such component or its module failed to load (:func:`load_failure` says why)."""
    if name in _COMPONENTS[kind]:
        return _COMPONENTS[kind][name]
    load = _declared(kind).get(name)
    if load is None:
        return None
    try:
        loaded = load()
    except Exception as exc:  # noqa: BLE001 - a broken plugin is reported by name, not a traceback
        if name in SHIPPED[kind]:
            raise  # a bug in rovlab itself: its traceback, not a user error
        _FAILED[kind][name] = f"{type(exc).__name__}: {exc}"
        return None
    if isinstance(loaded, ComponentInfo):
        register_component(loaded)
    info = _COMPONENTS[kind].get(name)
    if info is None:
        _FAILED[kind][name] = (f"its module was imported but declared no {kind} named {name!r}: it must end with "
                               f"register_component(ComponentInfo({name!r}, {kind!r}, build, ...))")
    return info


def load_failure(kind: str, name: str) -> str | None:
    """Why a declared component could not be loaded (None if it loaded or was never tried)."""
    return _FAILED[kind].get(name)


def unknown_component(kind: str, name: str) -> str:
    """What to say of an estimator or controller name that :func:`component` did not find."""
    why = load_failure(kind, name)
    if why is not None:
        return f"a {kind} that loads; {kind} {name!r} did not: {why}"
    return "one of: " + ", ".join(component_names(kind))


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
