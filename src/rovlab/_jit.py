"""numba kernels compiled on first use, so that importing a module does not import numba.

A kernel module is plain Python written in numba's subset (no numba import). The module that
publishes the kernels makes a :class:`LazyKernels` of it and exposes the compiled versions as
module attributes through PEP 562's ``__getattr__``::

    from rovlab.models import thruster_kernels as _plain
    _kernels = LazyKernels(_plain, ("bank_force", "bank_pwm", ...), cache=True)
    __getattr__ = _kernels.module_getattr(__name__)

``from rovlab.models.thrusters import bank_pwm`` then returns a numba dispatcher (what njit code
such as the simulator's loop needs), while one-shot commands call ``_plain.bank_pwm`` directly
and never pay numba's import (~0.3 s) or a compilation. The compiled copies resolve each other
through their own namespace (a copy of the plain module's, with every kernel replaced by its
dispatcher), so a compiled kernel never calls a plain one.
"""

from __future__ import annotations

import sys
import types
from collections.abc import Callable, Iterable
from typing import Any


class LazyKernels:
    """The plain functions ``names`` of ``module``, compiled together with numba on first use."""

    def __init__(self, module: types.ModuleType, names: Iterable[str], **options: Any) -> None:
        self.module = module
        self.names = tuple(names)
        self.options = dict(options)
        self._compiled: dict[str, Any] | None = None

    def plain(self, name: str) -> Callable:
        return getattr(self.module, name)

    def compiled(self) -> dict[str, Any]:
        """{name: numba dispatcher}; creating them imports numba (compilation itself is lazy)."""
        if self._compiled is None:
            import numba

            use_user_cache_folder()
            namespace = dict(vars(self.module))
            out = {}
            for name in self.names:
                f = namespace[name]
                copy = types.FunctionType(f.__code__, namespace, f.__name__, f.__defaults__, f.__closure__)
                copy.__qualname__, copy.__module__, copy.__doc__ = f.__qualname__, f.__module__, f.__doc__
                out[name] = namespace[name] = numba.njit(**self.options)(copy)
            self._compiled = out
        return self._compiled

    def module_getattr(self, module_name: str) -> Callable[[str], Any]:
        def __getattr__(name: str) -> Any:
            if name in self.names:
                return self.plain(name) if _without_numba else self.compiled()[name]
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")

        return __getattr__


# numba's option (private, stable since numba 0.4x) for a function compiled without reference
# counting: the closed loop and the node's control step (rovlab.sim.loop explains why), and its
# opposite for a function they call that allocates, which would otherwise inherit it
WITHOUT_NRT: dict[str, Any] = {"_nrt": False}
WITH_NRT: dict[str, Any] = {"_nrt": True}

_without_numba: list[bool] = []  # set once by run_without_numba() in a process that asks for it


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit`` for rovlab's kernels: in a process that called :func:`run_without_numba`
    first (one that runs only kernels built ahead of time: ``rovlab filter``, a simulation whose
    loop is built, rovlab.sim.prebuilt), the plain function instead, and numba is never imported."""
    if _without_numba:
        if len(args) == 1 and callable(args[0]) and not options:
            return args[0]
        return lambda f: f
    import numba

    return numba.njit(*args, **options)


_lanes_unsupported: list[str] = []  # why this numba cannot run the lanes' loop (rovlab.sim.loop.run_loop_lanes)


def lanes_supported() -> bool:
    """Whether the Monte Carlo's loop over lanes can run correctly here: always without numba
    (it runs built ahead of time, by a numba that could build it), else only if numba's alias
    analysis could be fixed (:func:`_alias_analysis_to_fixpoint`; its signature is checked)."""
    if _without_numba or "numba" not in sys.modules:
        return not _lanes_unsupported
    _alias_analysis_to_fixpoint()
    return not _lanes_unsupported


def _alias_analysis_to_fixpoint() -> None:
    """Make numba's alias analysis (numba.core.ir_utils.find_potential_aliases, which decides
    what dead-code elimination may remove) independent of the order it visits the blocks in.

    It marks a variable as an alias of the function's arguments only if the variable it comes
    from is already marked when its block is visited. After numba inlines functions into a
    loop, a block can be visited before the block that marks its source, and then stores into
    an argument's array through that variable are removed as dead code (numba 0.68: the
    controllers' scratch stores in rovlab.sim.loop.run_loop_lanes). Repeating the analysis,
    starting from what the previous pass marked, until nothing is added fixes it; it only ever
    keeps more code alive."""
    import inspect

    from numba.core import ir_utils

    if getattr(ir_utils.find_potential_aliases, "_rovlab_fixpoint", False):
        return
    once = ir_utils.find_potential_aliases
    expected = ["blocks", "args", "typemap", "func_ir", "alias_map", "arg_aliases"]
    if list(inspect.signature(once).parameters) != expected or not hasattr(ir_utils, "alias_func_extensions"):
        _lanes_unsupported.append(f"numba {getattr(sys.modules.get('numba'), '__version__', '?')} changed "
                                  "find_potential_aliases, which rovlab patches for the lanes")
        return

    def to_fixpoint(blocks, args, typemap, func_ir, alias_map=None, arg_aliases=None):
        while True:
            before = None if arg_aliases is None else len(arg_aliases)
            alias_map, arg_aliases = once(blocks, args, typemap, func_ir, alias_map, arg_aliases)
            if before is not None and len(arg_aliases) == before:
                return alias_map, arg_aliases

    to_fixpoint._rovlab_fixpoint = True  # type: ignore[attr-defined]
    ir_utils.find_potential_aliases = to_fixpoint


def aliases_its_arguments(*callables: Any) -> None:
    """Tell numba that what these callables return (NamedTuples of arrays built inside compiled
    code: the lanes' views of a Monte Carlo's stacked components, rovlab.sim.loop) shares the
    arrays of their arguments. numba's dead-code elimination only keeps a store into an array
    it can trace back to the function's arguments; a store into ``tup.field`` of a tuple built
    by a call was removed as dead (numba 0.68: run_loop_lanes lost every log write and the
    controllers' scratch). Nothing to do without numba."""
    if _without_numba:
        return
    from numba.core import ir_utils

    _alias_analysis_to_fixpoint()

    def alias(lhs: str, args: list[Any], alias_map: dict[str, set[str]], arg_aliases: set[str]) -> None:
        # as if it were one of the function's arguments: numba visits the blocks in no particular
        # order, so whether the call's own arguments are known to alias an argument yet is luck
        arg_aliases.add(lhs)

    for fn in callables:
        target = getattr(fn, "py_func", fn)
        ir_utils.alias_func_extensions[(target.__name__, target.__module__)] = alias


def without_numba() -> bool:
    """Whether this process runs without numba (:func:`run_without_numba` took effect)."""
    return bool(_without_numba)


def plain(fn: Any) -> Any:
    """A kernel (a numba dispatcher or a plain function) as plain Python whose calls to other
    kernels are plain too, all the way down: for set-up code that calls a kernel once from
    Python, which would otherwise start numba's JIT (~0.4 s of registries) in a process that
    runs only code built ahead of time (rovlab.sim.prebuilt). Copies are made once per kernel."""
    f = getattr(fn, "py_func", fn)
    copy = _plain.get(f)
    if copy is None:
        namespace = dict(f.__globals__)
        copy = types.FunctionType(f.__code__, namespace, f.__name__, f.__defaults__, f.__closure__)
        _plain[f] = copy
        for k, v in namespace.items():  # after the memo: kernels that call each other
            if hasattr(v, "py_func") and callable(v):
                namespace[k] = plain(v)
            elif isinstance(v, types.ModuleType) and v.__name__.startswith("rovlab."):
                namespace[k] = _PlainModule(v)  # kin.jacobian_into(...) and the like
    return copy


class _PlainModule:
    """A rovlab module seen through :func:`plain`: its kernels as plain Python (a module of
    LazyKernels gives its plain functions without creating numba's dispatchers)."""

    def __init__(self, module: types.ModuleType) -> None:
        self._module = module

    def __getattr__(self, name: str) -> Any:
        lazy = getattr(self._module, "_kernels", None)
        if isinstance(lazy, LazyKernels) and name in lazy.names:
            return lazy.plain(name)
        value = getattr(self._module, name)
        return plain(value) if hasattr(value, "py_func") and callable(value) else value


_plain: dict[Any, Any] = {}


# the modules whose kernels take njit from here (or register numba overloads): run_without_numba
# must come before any of them is imported
_NUMBA_FREE_IF = ("rovlab.core.angles", "rovlab.estimation.fusion", "rovlab.estimation.kalman", "rovlab.io.csvtext",
                  "rovlab.core.components", "rovlab.models.kinetics", "rovlab.models.sensors",
                  "rovlab.estimation.kf", "rovlab.estimation.ekf", "rovlab.control.lqg", "rovlab.control.dp",
                  "rovlab.control.mrac", "rovlab.sim.actuators", "rovlab.sim.plant", "rovlab.sim.loop",
                  "rovlab.sim.step")


def run_without_numba() -> bool:
    """Make the kernels of the modules above plain Python functions in this process, so that a
    command whose compiled work is done by kernels built ahead of time (rovlab._aot,
    rovlab.sim.prebuilt) does not pay numba's import (~0.2 s). Only possible before those
    modules are imported and while numba is not; returns whether it took effect. Afterwards
    nothing in the process may compile code that calls them (a kernel call that cannot go to a
    built module runs interpreted: the same numbers, slowly; rovlab simulate restarts itself
    with ROVLAB_AOT=0 rather than do that, rovlab.interfaces.cli_sim)."""
    import sys

    if _without_numba:
        return True
    if "numba" in sys.modules or any(m in sys.modules for m in _NUMBA_FREE_IF):
        return False
    _without_numba.append(True)
    return True


def use_user_cache_folder() -> None:
    """Make an already imported numba pick up the NUMBA_CACHE_DIR that rovlab set.

    numba reads its environment variables when ``numba.core.config`` is imported and again only
    when it compiles; a ``cache=True`` function picks its cache folder when it is *decorated*.
    So if numba was imported before rovlab (a user script doing ``import numba`` first), every
    kernel decorated before the first compilation would cache into ``__pycache__`` next to the
    installed sources. Reloading the configuration here closes that window.
    """
    import sys

    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.reload_config()


# --------------------------------------------------------------------------------------------
# The first run of a loop: interpret it, or compile it (and say so)
# --------------------------------------------------------------------------------------------
#
# The simulator's loop is compiled per combination of components (plant, estimator, controller)
# and cached on disk; compiling one takes a minute or more on a 2-core machine, while the same
# loop run by the Python interpreter (NUMBA_DISABLE_JIT: numba's decorators return the plain
# functions) does a 60 s case study in well under a second, with the same numbers. So the first
# run of a short scenario is interpreted while a low-priority background process compiles the
# loop for the next runs; long runs and Monte Carlo compile in the foreground after saying so.
# A marker file per combination in the cache folder says that its loop is in numba's cache (the
# folder is keyed on rovlab's sources, so an edit or a reinstall starts without markers).

JIT_MODES = ("auto", "compile", "interpret")


def loop_key(plant: str, estimator: str, controller: str) -> str:
    """The name of one combination of components (one compiled loop), e.g. "process-kf-lqg"."""
    return f"{plant}-{estimator}-{controller}"


def jit_mode() -> str:
    """ROVLAB_JIT: auto (default), compile (always compile) or interpret (never compile)."""
    import os

    mode = os.environ.get("ROVLAB_JIT", "auto").strip().lower() or "auto"
    if mode not in JIT_MODES:
        raise ValueError(f"ROVLAB_JIT={os.environ['ROVLAB_JIT']!r}: expected one of {', '.join(JIT_MODES)}")
    return mode


def _ready_folder():
    import os
    from pathlib import Path

    cache = os.environ.get("NUMBA_CACHE_DIR")
    return Path(cache) / "rovlab-ready" if cache else None


def is_compiled(key: str) -> bool:
    """Whether the loop for this combination of components is in numba's disk cache."""
    folder = _ready_folder()
    return folder is not None and (folder / f"{key}.json").is_file()


_marked: set[tuple[str, str]] = set()  # (cache folder, key) whose marker this process has seen or written


def mark_compiled(key: str, seconds: float) -> None:
    """Record that the loop for ``key`` is cached, and how long compiling it took (nothing when
    the loop ran interpreted). Checks the file once per process and key (a Monte Carlo calls
    this for every run)."""
    import json
    import os

    memo = (os.environ.get("NUMBA_CACHE_DIR", ""), key)
    if memo in _marked or interpreting():
        return
    _marked.add(memo)
    folder = _ready_folder()
    if folder is None or (folder / f"{key}.json").is_file():
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{key}.json.tmp"
        tmp.write_text(json.dumps({"key": key, "compile_seconds": round(seconds, 1)}))
        tmp.replace(folder / f"{key}.json")
    except OSError:
        pass  # a read-only cache: the next run compiles again, nothing is lost


def compile_estimate(key: str) -> float | None:
    """Seconds the loop for ``key`` took to compile here before (an older cache folder of this
    machine: rovlab's sources changed since), or None if never."""
    import json

    folder = _ready_folder()
    if folder is None:
        return None
    times = []
    for marker in folder.parent.parent.glob(f"*/rovlab-ready/{key}.json"):
        try:
            times.append((marker.stat().st_mtime, float(json.loads(marker.read_text())["compile_seconds"])))
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return max(times)[1] if times else None


def interpreting() -> bool:
    """Whether numba's decorators in this process return plain Python functions."""
    import os
    import sys

    config = sys.modules.get("numba.core.config")
    if config is not None:
        return bool(config.DISABLE_JIT)
    return os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")


def interpret_this_process() -> bool:
    """Make every kernel imported from now on run interpreted; False if it is too late (the
    simulator's kernels were already imported, compiled) -- then nothing changes."""
    import os
    import sys

    if any(m.startswith("rovlab.sim.loop") for m in sys.modules):
        return interpreting()
    os.environ["NUMBA_DISABLE_JIT"] = "1"
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.reload_config()
    return True


def compile_in_background(key: str, scenario: str, design: str | None = None) -> str | None:
    """Start a detached, low-priority process that compiles the loop ``scenario`` needs into the
    cache (rovlab.sim.warm) unless one is already running for ``key``; returns the log file of
    the compile under way, or None if there is no cache to fill."""
    return start_detached(key, ["rovlab.sim.warm", scenario, "--key", key] + (["--config", design] if design else []))


def start_detached(key: str, module_argv: list[str]) -> str | None:
    """Run ``python -m <module_argv> --lock LOCK`` detached (its own session, output to
    ``<key>.log`` next to the markers) unless a process started for ``key`` is still running;
    the module removes LOCK when it ends. Returns the log file, or None without a cache folder."""
    import os
    import subprocess
    import sys

    folder = _ready_folder()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = folder / f"{key}.lock"
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                text = lock.read_text().strip()
                if not text:
                    import time

                    if time.time() - lock.stat().st_mtime < 60:
                        return str(folder / f"{key}.log")  # its process is being started
                else:
                    os.kill(int(text), 0)
                    return str(folder / f"{key}.log")  # a process for this key is under way
            except (ProcessLookupError, ValueError):
                pass  # a stale lock: its process is gone
            except PermissionError:
                return str(folder / f"{key}.log")  # alive, another user's
            lock.unlink(missing_ok=True)
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        log = folder / f"{key}.log"
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_DISABLE_JIT"}
        env["ROVLAB_JIT"] = "compile"
        argv = [sys.executable, "-m", *module_argv, "--lock", str(lock)]
        try:
            with open(log, "wb") as out:
                proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                        env=env, start_new_session=True)
            os.write(fd, str(proc.pid).encode())
        except OSError:
            lock.unlink(missing_ok=True)  # nothing started: the next run may try again
            raise
        finally:
            os.close(fd)
        return str(log)
    except OSError:
        return None
