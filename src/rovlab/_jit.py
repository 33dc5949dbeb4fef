"""rovlab's one compile path: ``numba.njit(cache=True)``, through numba's public API.

Every compiled kernel of rovlab is decorated by :func:`njit` below, which is ``numba.njit`` with
two things added and nothing of numba changed:

* **No writable cache.** numba looks for a place to cache a ``cache=True`` function (next to the
  source in ``__pycache__``, else in the user's cache folder, or where the user's own
  ``NUMBA_CACHE_DIR`` says) and raises ``RuntimeError: cannot cache function ...: no locator
  available`` when there is none (a read-only install with a read-only home). rovlab then
  compiles that kernel in memory for this process, and says so once on stderr.
* **Kernels that call kernels of other files.** numba keys a cached function on its own source
  file only (numba's documentation, "Notes on caching": a change in a function it calls from
  another file is not seen), and rovlab's loop compiles the kernels of a dozen files into one
  function. So rovlab writes a stamp beside the cache files of its kernels (the cache folder numba
  reports in ``dispatcher.stats.cache_path``): a digest of the source files of every kernel
  module (:data:`KERNEL_MODULES`) and of numpy's, numba's and scipy's versions. When the stamp
  differs, the cache files of rovlab's kernels in that folder are removed before numba reads
  them, and numba compiles afresh. Nothing else invalidates them: editing a file that holds no
  kernel (the command line, the docs) keeps every compiled kernel.

Nothing here sets an environment variable, reloads or patches numba, or starts a process: a
user's own numba code and settings (``NUMBA_CACHE_DIR``, ``numba.config.DISABLE_JIT``, their
cached kernels) are theirs alone. A user's ``NUMBA_DISABLE_JIT=1`` is honoured like numba does
(every kernel runs as plain Python: the same numbers, slowly).

Kernels compiled on first use, so that importing a module does not import numba: a kernel module
that one-shot commands use (thrusters, allocation) is plain Python written in numba's subset, and
the module that publishes the kernels makes a :class:`LazyKernels` of it::

    from rovlab.models import thruster_kernels as _plain
    _kernels = LazyKernels(_plain, ("bank_force", "bank_pwm", ...), cache=True)
    __getattr__ = _kernels.module_getattr(__name__)

``from rovlab.models.thrusters import bank_pwm`` then returns a numba dispatcher (what compiled
code such as the simulator's loop needs), while one-shot commands call ``_plain.bank_pwm``
directly and never import numba or compile anything.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

# The modules whose source the compiled kernels are made of: those that define kernels, and those
# whose module-level constants numba compiles into them (estimation/layout.py's column indices,
# allocation/lexicographic.py's tolerances). Their digest keys rovlab's compiled kernels;
# tests/test_compile_path.py checks that every module a kernel module imports from is listed, or
# named there as plain Python (design code numba never compiles).
KERNEL_MODULES = (
    "allocation/kernels.py", "allocation/lexicographic.py", "allocation/solvers.py",
    "control/dp.py", "control/lqg.py", "control/mrac.py", "control/open_loop.py",
    "core/angles.py", "core/components.py",
    "estimation/ekf.py", "estimation/fusion.py", "estimation/kalman.py", "estimation/kf.py", "estimation/layout.py",
    "estimation/offline.py",
    "models/kinetics.py", "models/sensors.py", "models/thruster_kernels.py", "models/thrusters.py",
    "sim/actuators.py", "sim/loop.py", "sim/plant.py", "sim/step.py",
)
STAMP = "rovlab-kernels.stamp"  # beside numba's cache files of rovlab's kernels

# numba's compile option for a function without reference counting, for the five entry points that
# run components (rovlab.sim.loop.run_loop; rovlab.sim.step's control_step, plant_push and
# plant_sample; rovlab.estimation.offline.replay), and its opposite for a kernel they call that
# allocates (which would otherwise inherit it). The one option rovlab uses that numba does not
# document (it is spelled with an underscore; numba's own test suite uses it, and it has not
# changed since numba 0.4x). Measured on the 2-core machine (numba 0.68.1, step-process-model,
# 60 s): the loop takes 0.82 ms with it and 2.42 ms without (the components' arrays are increfed
# and decrefed at every call boundary), and a 1000-run Monte Carlo 1.6 s against 2.4 s as a whole
# process (issue 25's floor is 3.5 M vehicle-steps/s: 1.7 s). Every use goes through these two
# dictionaries (tests/test_compile_path.py checks it): with a numba that drops the option,
# emptying them is the whole fix (slower, not wrong).
WITHOUT_NRT: dict[str, Any] = {"_nrt": False}
WITH_NRT: dict[str, Any] = {"_nrt": True}

_lock = threading.Lock()
_checked: set[str] = set()  # cache folders whose stamp this process has checked
_in_memory: list[str] = []  # kernels compiled without a disk cache (no writable place for one)
_digest: list[str] = []


def kernel_digest() -> str:
    """SHA-1 (hex) of the kernel modules' sources and of numpy's, numba's and scipy's versions."""
    if not _digest:
        import numba
        import numpy
        import scipy

        h = hashlib.sha1(f"numpy {numpy.__version__} numba {numba.__version__} scipy {scipy.__version__}".encode())
        root = Path(__file__).resolve().parent
        for name in KERNEL_MODULES:
            h.update(f"\n{name}\n".encode())
            try:
                h.update((root / name).read_bytes())
            except OSError:
                h.update(b"<unreadable>")
        _digest.append(h.hexdigest())
    return _digest[0]


def _check_stamp(folder: str) -> None:
    """Remove the cache files of rovlab's kernels in ``folder`` if they were compiled from other
    kernel sources or versions (the stamp differs), then write the stamp; once per folder and
    process. A folder that cannot be read or written is left as it is (numba copes with both)."""
    if folder in _checked:
        return
    _checked.add(folder)
    path = Path(folder)
    stamp = path / STAMP
    digest = kernel_digest()
    try:
        if stamp.read_text().strip() == digest:
            return
    except OSError:
        pass  # no stamp yet: a first compile here, or caches of an older rovlab
    try:
        for f in path.iterdir():
            # rovlab's own cache files only: this folder is numba's for rovlab's package folder,
            # and its index/data files are named after rovlab's kernel modules
            if f.suffix in (".nbi", ".nbc") and f.name.split(".")[0] + ".py" in _MODULE_FILES:
                f.unlink(missing_ok=True)
        path.mkdir(parents=True, exist_ok=True)
        tmp = path / f".{STAMP}.{os.getpid()}.{threading.get_ident()}.tmp"
        tmp.write_text(digest + "\n")
        tmp.replace(stamp)
    except OSError:
        pass


_MODULE_FILES = frozenset(name.rsplit("/", 1)[-1] for name in KERNEL_MODULES)


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit`` for rovlab's kernels (module docstring): with ``cache=True``, the disk cache
    checked against the kernel sources first, or compiled in memory where nothing can be cached."""
    if len(args) == 1 and callable(args[0]) and not options:
        return _decorate(args[0], {})
    if args:
        raise TypeError("rovlab._jit.njit takes options by keyword only")
    return lambda f: _decorate(f, options)


def _decorate(f: Callable, options: dict[str, Any]) -> Any:
    import numba

    if not options.get("cache"):
        return numba.njit(**options)(f)
    with _lock:
        try:
            dispatcher = numba.njit(**options)(f)
        except RuntimeError as exc:
            if "cannot cache" not in str(exc):
                raise
            _in_memory.append(f"{f.__module__}.{f.__qualname__}")
            if len(_in_memory) == 1:
                print("rovlab: numba finds no writable cache folder here (a read-only install and home; "
                      "NUMBA_CACHE_DIR names one), so the kernels are compiled in memory for this process",
                      file=sys.stderr, flush=True)
            return numba.njit(**{**options, "cache": False})(f)
        folder = getattr(getattr(dispatcher, "stats", None), "cache_path", None)
        if folder:
            _check_stamp(str(folder))
        return dispatcher


def compiled_in_memory() -> tuple[str, ...]:
    """The kernels this process compiled without a disk cache (none where numba can cache)."""
    return tuple(_in_memory)


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
            namespace = dict(vars(self.module))
            out = {}
            for name in self.names:
                f = namespace[name]
                copy = types.FunctionType(f.__code__, namespace, f.__name__, f.__defaults__, f.__closure__)
                copy.__qualname__, copy.__module__, copy.__doc__ = f.__qualname__, f.__module__, f.__doc__
                out[name] = namespace[name] = njit(**self.options)(copy)
            self._compiled = out
        return self._compiled

    def module_getattr(self, module_name: str) -> Callable[[str], Any]:
        def __getattr__(name: str) -> Any:
            if name in self.names:
                return self.compiled()[name]
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")

        return __getattr__


def plain(fn: Any) -> Any:
    """A kernel (a numba dispatcher or a plain function) as plain Python whose calls to other
    kernels are plain too, all the way down: for set-up code that calls a kernel once from
    Python (designing a filter), which would otherwise compile it and everything it calls.
    Copies are made once per kernel."""
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


def with_progress(work: Callable[[], Any], log: Callable[[str], None], what: str, *, after_s: float = 1.0,
                  every_s: float = 15.0, hint: str = "") -> tuple[Any, float]:
    """Run ``work()`` (a first call that may compile) and return (its result, seconds). When it
    takes longer than ``after_s``, ``log`` says that ``what`` is being compiled (with ``hint``),
    then the elapsed time every ``every_s`` seconds until it is done, so that a first start on a
    loaded machine does not look like a hang. The reporting thread ends before this returns."""
    import time

    done = threading.Event()
    started = time.perf_counter()

    def report() -> None:
        if done.wait(after_s):
            return
        log(f"compiling {what} (a first run on this machine; numba caches it for later runs){hint} ...")
        while not done.wait(every_s):
            log(f"  ... still compiling {what}: {time.perf_counter() - started:.0f} s")

    thread = threading.Thread(target=report, name="rovlab-compile-progress", daemon=True)
    thread.start()
    try:
        result = work()
    finally:
        done.set()
        thread.join()
    return result, time.perf_counter() - started


def loop_key(plant: str, estimator: str, controller: str) -> str:
    """The name of one combination of components (one compiled loop), e.g. "process-kf-lqg"."""
    return f"{plant}-{estimator}-{controller}"
