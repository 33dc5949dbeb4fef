"""The closed loop built ahead of time, per combination of components (no JIT start-up).

Calling a numba dispatcher costs a process ~0.4 s the first time, even when the compiled loop
comes from the disk cache: numba sets up its typing and lowering registries before it can look
the loop up, and importing numba costs another ~0.2 s. For `rovlab simulate --runs 1000` that
was a third of the time. The loop built into an extension module (numba.pycc, rovlab._aot)
loads in under a millisecond, and its logs are bit-identical to the JIT loop's (tested).

numba.pycc exports functions of arrays and scalars, not of components (NamedTuples), so each
combination gets a flat wrapper: its arguments are the leaves of :func:`rovlab.sim.loop.run_loop`'s
arguments, in order, and it rebuilds the NamedTuples and calls the loop, which numba compiles as
the JIT does (with its own flags, without reference counting). A **plan** describes one such
wrapper: the component classes and, per leaf, its dtype, rank and whether it is written
("<f8:2:w"; C-contiguous and aligned arrays only) or its scalar type. Its digest names the
module (``rovlab_loop_<digest>`` in rovlab._aot's folder for these sources and this CPU).

When the JIT loop has run and the combination is not built yet, :func:`request` starts
``python -m rovlab.sim.prebuilt build --plan FILE`` detached and at low priority; it takes a few
seconds when the JIT loop is in numba's cache (what the build links), a few minutes otherwise.
From then on :class:`rovlab.sim.runner.Simulation` calls the built module whenever the
arguments are exactly those of its plan (any other array, e.g. a strided view, goes to the JIT
loop). ``ROVLAB_AOT=0`` turns this off; so does running interpreted (ROVLAB_JIT=interpret).
``python -m rovlab.sim.prebuilt build SCENARIO`` builds a scenario's loop in the foreground.

The Monte Carlo's loop over lanes of runs (rovlab.sim.loop.run_loop_lanes, LOOPS) is built the
same way (``--lanes``; a Monte Carlo requests it when it ends), and only ever run built: a
Monte Carlo whose lanes loop is not built runs its seeds one by one.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rovlab import _aot

PREFIX = "rovlab_loop_"  # + digest: the module (and its build's lock and log)
EXPORT = "run_flat"  # the exported function: run_flat(k0, k1, h, *leaves) -> rows done
FAILED = ".failed.txt"  # <module>.failed.txt beside the modules: why its build failed (not retried)
MARKER = ".loop"  # <loop key>.loop beside the modules: the module built for that combination

_SCALARS = {bool: "b1", int: "i8", float: "f8"}  # Python scalars as numba types them


class NotBuilt(RuntimeError):
    """A process without numba (rovlab._jit.run_without_numba) met loop arguments that no built
    module takes: its loop would run interpreted. ``rovlab simulate`` starts again with the JIT."""


def flatten(args: Sequence[Any]) -> tuple[list[Any], tuple[Any, ...]] | None:
    """(leaves, shape) of the loop's arguments after k0, k1, h: the leaves in order and a
    hashable description (classes and leaf types); None if some leaf cannot be passed (only
    aligned C-contiguous numeric arrays and numeric scalars can). Runs before every call, so it
    is written for speed (~0.3 us a leaf)."""
    leaves: list[Any] = []
    shape: list[Any] = []
    stack = list(reversed(args))
    while stack:
        v = stack.pop()
        t = type(v)
        if t is np.ndarray:
            f = v.flags
            dt = v.dtype
            if not (f.c_contiguous and f.aligned) or dt.kind not in "biuf":
                return None
            shape.append((dt, v.ndim, f.writeable))
            leaves.append(v)
        elif t in _SCALARS:
            shape.append(_SCALARS[t])
            leaves.append(v)
        elif isinstance(v, tuple):
            shape.append(t if hasattr(t, "_fields") else tuple)
            shape.append(len(v))
            stack.extend(reversed(v))
        elif isinstance(v, np.generic) and not isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
            shape.append(("s", v.dtype))
            leaves.append(v)
        else:  # an ndarray subclass, an object, None ...: only the JIT loop can say what it makes of it
            return None
    return leaves, tuple(shape)


def _spec(leaf: Any) -> str:
    """A leaf's type as text: "<f8:2:w" (dtype, rank, written or read-only), "s<i4" (a numpy
    scalar), "b1", "i8", "f8" (Python scalars)."""
    if isinstance(leaf, str):
        return leaf
    if leaf[0] == "s":
        return f"s{leaf[1].str}"
    dt, ndim, writeable = leaf
    return f"{dt.str}:{ndim}:{'w' if writeable else 'r'}"


def describe(shape: tuple[Any, ...]) -> list[Any]:
    """The shape as JSON-able nested lists: a NamedTuple as ["module:qualname", [fields]], a
    plain tuple as ["tuple", [items]], a leaf as its spec."""
    items = iter(shape)

    def node() -> Any:
        item = next(items)
        if isinstance(item, type):
            n = next(items)
            name = "tuple" if item is tuple else f"{item.__module__}:{item.__qualname__}"
            return [name, [node() for _ in range(n)]]
        return _spec(item)

    out = []
    while True:
        try:
            out.append(node())
        except StopIteration:
            return out


LOOPS = ("run_loop", "run_loop_lanes")  # the loops of rovlab.sim.loop that can be built


def digest(description: list[Any], loop: str = "run_loop") -> str:
    """The module's key: the loop, the description and numpy's version (a module built against
    one numpy must not be loaded by another; the folder is already per rovlab sources and CPU)."""
    which = "" if loop == "run_loop" else f"{loop} "
    return hashlib.sha1(f"numpy {np.__version__} {which}".encode() + json.dumps(description).encode()).hexdigest()[:16]


def module_name(description: list[Any], loop: str = "run_loop") -> str:
    return PREFIX + digest(description, loop)


# --------------------------------------------------------------------------------------------
# Using a built loop
# --------------------------------------------------------------------------------------------

_names: dict[tuple[Any, ...], str] = {}  # (loop, shape) -> module name (this process)
_loaded: dict[str, Callable[..., Any]] = {}  # module name -> its loaded function (this process)
_requested: set[str] = set()  # modules whose build this process asked for


def enabled() -> bool:
    from rovlab import _jit

    return _aot.enabled() and not _jit.interpreting()


def runner(args: Sequence[Any], loop: str = "run_loop") -> Callable[[int, int, float], int] | None:
    """The built ``loop`` (one of LOOPS) for these arguments (after k0, k1, h), bound to them;
    None when it is not built (or disabled, or the arguments are not plain C arrays and scalars)."""
    if not enabled():
        return None
    flat = flatten(args)
    if flat is None:
        return None
    leaves, shape = flat
    name = _names.get((loop, shape))
    if name is None:
        name = _names[(loop, shape)] = module_name(describe(shape), loop)
    fn = _loaded.get(name) or _load(name)  # not found yet: looked for again next time (a build may end)
    if fn is None:
        return None
    return lambda k0, k1, h: fn(k0, k1, h, *leaves)


def _load(name: str) -> Callable[..., Any] | None:
    """The built module ``name``'s loop, loaded once per process; None if it is not built. A
    module that is there but does not load (damaged, or built by another numpy or Python) is
    removed with its markers, so that the next run that compiles the JIT loop builds it again."""
    where = _aot.folder()
    path = _aot.module_file(where, name) if where is not None else None
    if path is None:
        return None
    fn = _aot.load(path, name, EXPORT)
    if fn is None:
        for gone in (path, *path.parent.glob(f"*{MARKER}")):
            try:
                if gone == path or gone.read_text(encoding="utf-8").strip() == name:
                    gone.unlink()
            except OSError:
                pass
        return None
    _loaded[name] = fn
    return fn


def _marked(key: str) -> tuple[Path, str] | None:
    """(folder, module name) that the marker of the combination ``key`` names, if any."""
    where = _aot.folder() if enabled() else None
    if where is None:
        return None
    try:
        return where, (where / f"{key}{MARKER}").read_text(encoding="utf-8").strip()
    except OSError:
        return None


def built_for(key: str) -> bool:
    """Whether a loop for the combination of components ``key`` (rovlab._jit.loop_key) is built:
    then a first run need neither compile nor interpret (rovlab.interfaces.cli_sim.first_run)."""
    marked = _marked(key)
    return marked is not None and _aot.module_file(*marked) is not None


def loads_for(key: str) -> bool:
    """Whether the module built for the combination ``key`` is there and loads (what a process
    checks before it goes without numba: rovlab.interfaces.cli_sim.first_run)."""
    marked = _marked(key)
    return marked is not None and (_loaded.get(marked[1]) is not None or _load(marked[1]) is not None)


def request(args: Sequence[Any], key: str, loop: str = "run_loop") -> str | None:
    """Start building ``loop`` for these arguments (the combination ``key``) in the background
    unless it is built, failed before, under way or disabled (once per process and
    combination); returns the build's log file when one was started or is under way."""
    from rovlab import _jit

    if not enabled():
        return None
    flat = flatten(args)
    where = _aot.folder()
    if flat is None or where is None:
        return None
    description = describe(flat[1])
    name = module_name(description, loop)
    if name in _requested:
        return None
    _requested.add(name)
    if _aot.module_file(where, name) is not None or (where / f"{name}{FAILED}").is_file():
        return None
    try:
        where.mkdir(parents=True, exist_ok=True)
        plan = where / f"{name}.json"
        _write(plan, json.dumps({"loop": loop, "arguments": description}))
    except OSError:
        return None
    return _jit.start_detached(name, ["rovlab.sim.prebuilt", "build", "--plan", str(plan), "--key", key])


# --------------------------------------------------------------------------------------------
# Building
# --------------------------------------------------------------------------------------------

def wrapper_source(description: list[Any], loop: str = "run_loop") -> tuple[str, dict[str, type], list[str]]:
    """(source of run_flat, the classes it names, the leaf specs in order) for a description."""
    import importlib

    classes: dict[str, type] = {}
    specs: list[str] = []

    def expr(item: Any) -> str:
        if isinstance(item, list):
            kind, fields = item
            parts = [expr(f) for f in fields]
            if kind == "tuple":
                return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"
            module, qualname = kind.split(":", 1)
            cls: Any = importlib.import_module(module)
            for part in qualname.split("."):
                cls = getattr(cls, part)
            alias = f"_C{len(classes)}"
            classes[alias] = cls
            return f"{alias}({', '.join(parts)})"
        specs.append(str(item))
        return f"a{len(specs) - 1}"

    args = [expr(item) for item in description]
    params = "".join(f", a{i}" for i in range(len(specs)))
    source = (f"def {EXPORT}(k0, k1, h{params}):\n"
              f"    return {loop}(k0, k1, h, {', '.join(args)})\n")
    return source, classes, specs


def _numba_type(spec: str) -> Any:
    from numba.core import types
    from numba.np.numpy_support import from_dtype

    if spec in ("b1", "i8", "f8"):
        return {"b1": types.boolean, "i8": types.int64, "f8": types.float64}[spec]
    if spec.startswith("s"):
        return from_dtype(np.dtype(spec[1:]))
    dtype, ndim, access = spec.split(":")
    return types.Array(from_dtype(np.dtype(dtype)), int(ndim), "C", readonly=access == "r")


def build(description: list[Any], where: Path | None = None, loop: str = "run_loop") -> Path:
    """Compile the flat wrapper of ``description`` with ``loop`` into an extension module."""
    from numba.core import types

    from rovlab.sim import loop as loops

    if loop not in LOOPS:
        raise ValueError(f"cannot build {loop!r}: expected one of {', '.join(LOOPS)}")
    if loop == "run_loop_lanes":
        from rovlab import _jit

        if not _jit.lanes_supported():
            raise RuntimeError("this numba's dead-code elimination cannot be fixed for the loop over lanes "
                               "(rovlab._jit.lanes_supported): Monte Carlo runs one by one")
    where = where or _aot.folder()
    if where is None:
        raise RuntimeError("rovlab's sources cannot be read: no cache folder to build into")
    source, classes, specs = wrapper_source(description, loop)
    namespace: dict[str, Any] = {loop: getattr(loops, loop), **classes}
    name = module_name(description, loop)
    exec(compile(source, f"<rovlab.sim.prebuilt {name}>", "exec"), namespace)
    signature = types.int64(types.int64, types.int64, types.float64, *(_numba_type(s) for s in specs))
    return _aot.compile_module(where, name, EXPORT, namespace[EXPORT], signature, release_gil=False)


def simulation(scenario: str, design: str | None = None) -> Any:
    """A Simulation of a scenario (packaged name or TOML path), for its loop's arguments."""
    from rovlab.params.design import load_design_config
    from rovlab.sim.runner import Simulation, prepare
    from rovlab.sim.scenario import load_scenario

    config = load_design_config(design) if design else None
    return Simulation(prepare(load_scenario(scenario), config=config))


def _write(path: Path, text: str) -> None:
    from rovlab.core.files import atomic_write_text

    atomic_write_text(path, text)


def main(argv: list[str] | None = None) -> int:
    import argparse
    import os
    import time

    p = argparse.ArgumentParser(prog="python -m rovlab.sim.prebuilt", description=__doc__.splitlines()[0])
    p.add_argument("action", choices=["build", "status"])
    p.add_argument("scenario", nargs="?", help="packaged scenario name or TOML path (the loop it runs)")
    p.add_argument("--config", default=None, help="filter/controller configuration (default: the scenario's)")
    p.add_argument("--plan", default=None, help="a plan file written by a run (the background build)")
    p.add_argument("--force", action="store_true", help="build again even if it is built")
    p.add_argument("--lanes", action="store_true",
                   help="the Monte Carlo's loop over lanes of runs (rovlab.sim.loop.run_loop_lanes) instead of one run's")
    p.add_argument("--key", default=None, help="the combination of components (rovlab._jit.loop_key) of --plan")
    p.add_argument("--lock", default=None, help="lock file to remove when done (the background build)")
    args = p.parse_args(argv)
    if (args.scenario is None) == (args.plan is None):
        p.error("give a scenario or --plan FILE")
    where = _aot.folder()
    name = None
    try:
        if args.lock:
            try:
                os.nice(10)  # behind the user's foreground work
            except OSError:
                pass
        key = args.key
        loop = "run_loop_lanes" if args.lanes else "run_loop"
        if args.plan:
            if args.lanes:
                p.error("--lanes goes with a scenario; a plan names its loop")
            plan = json.loads(Path(args.plan).read_text())
            if isinstance(plan, list):  # a plan written before the lanes: the one-run loop
                loop, description = "run_loop", plan
            else:
                loop, description = plan["loop"], plan["arguments"]
        else:
            sim = simulation(args.scenario, args.config)
            key = sim.prep.loop_key
            if args.lanes:
                from rovlab.sim.runner import lane_arguments, reseed

                lane_args, lanes, _ = lane_arguments([reseed(sim.prep, s) for s in range(2)])
                loop_args = (*lane_args, lanes)
            else:
                loop_args = sim.loop_arguments()
            flat = flatten(loop_args)
            if flat is None:
                print("this scenario's components cannot be built ahead of time (not plain arrays and scalars)")
                return 1
            description = describe(flat[1])
        name = module_name(description, loop)
        if loop != "run_loop":
            key = None  # markers name one run's module (what a first run looks for)
        if args.action == "status":
            path = _aot.module_file(where, name) if where else None
            print(f"{name}: {'built, ' + str(path) if path else 'not built'}")
            return 0
        built_path = _aot.module_file(where, name) if where is not None else None
        if built_path is not None and not args.force:
            if key:
                try:
                    _write(built_path.parent / f"{key}{MARKER}", name)
                except OSError:
                    pass
            print(f"already built: {built_path}")
            return 0
        t0 = time.perf_counter()
        path = build(description, where, loop)
        print(f"built {path} in {time.perf_counter() - t0:.1f} s")
        if key and where is not None:
            try:
                _write(where / f"{key}{MARKER}", name)
            except OSError as exc:  # built all the same: a run that prepares its arguments finds it
                print(f"note: could not write the marker of {key}: {exc}", file=sys.stderr)
        return 0
    except Exception as exc:  # the log says why; the runs keep using the JIT loop
        why = f"{type(exc).__name__}: {exc}"
        print(f"building the loop ahead of time failed: {why}", file=sys.stderr)
        if where is not None and name is not None:
            _aot.record_failure(where / f"{name}{FAILED}", why)
        return 1
    finally:
        if args.lock:
            Path(args.lock).unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
