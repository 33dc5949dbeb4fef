"""Kernels compiled ahead of time, for commands whose work is one kernel (``rovlab filter``).

A process that calls a numba kernel pays once for numba's compiler set-up (its CPU target's
registries, which import scipy.linalg for BLAS): ~0.5-0.7 s on the 2-core machine, loading from
the disk cache included, on top of numba's import -- most of what ``rovlab filter`` spends
before reading its log. The same kernels compiled ahead of time (numba.pycc) into an extension
module load in under a millisecond and never start the compiler; ``rovlab filter`` on a CSV log
then does not import numba at all (rovlab._jit.run_without_numba).

The kernels of :data:`KERNELS` are compiled from the same Python functions as the JIT ones and
for this machine's CPU, each into its own extension module (numba.pycc fails to type one of them
when both share a module). They are built once per version of rovlab's sources and per CPU, in
the background the first time ``rovlab filter`` runs (``python -m rovlab._aot build``, ~20-60 s
at low priority), into ``<cache>/aot/<sources>-<cpu>/`` (pruned with the other caches,
rovlab.prune_caches), and used from then on. Until they exist, or with ``ROVLAB_AOT=0``, the JIT
kernels run; both write the same bytes (tests/estimation/test_aot.py). numba.pycc is pending
deprecation in numba (no replacement yet); if it goes, the build fails, its log says why, and
the JIT kernels keep running.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

MODULE = "rovlab_aot"  # + "_" + the kernel's name
BUILD_KEY = "aot-kernels"  # lock and log of the background build (rovlab._jit.start_detached)
FAILED = "build-failed.txt"  # in the version's folder: why its build failed (not retried)

# exported name -> (module, function, argument arrays as "<dtype>:<ndim>[w]", result): the kernels
# and the aligned C-contiguous arrays they are built for ("w": the kernel writes it; scalars are
# not needed by these kernels)
KERNELS = {
    # kf_run(model, x, P, ch, t, u, y, present, n_predict, X, V, status, reason, event, innov, S, flags)
    "kf_run": ("rovlab.estimation.kalman", "kf_run",
               ("f8:1", "f8:1w", "f8:2w", "f8:2w", "f8:1", "f8:2", "f8:2", "b1:2", "i8:1", "f8:2w", "f8:2w", "i1:2w",
                "i1:2w", "i1:2w", "f8:2w", "f8:2w", "i1:1w"), "void"),
    # _rows(F, Fbits, sig, codes, kinds, index, lab, lab_off, out, left) -> (bytes written, values left)
    "csv_rows": ("rovlab.io.csvtext", "_rows",
                 ("f8:2", "u8:2", "i8:1", "i8:2", "i8:1", "i8:1", "u1:1", "i8:1", "u1:1w", "i8:2w"), "i8,i8"),
}
_DTYPES = {"f8": "float64", "i8": "int64", "i1": "int8", "u1": "uint8", "u8": "uint64", "b1": "bool"}

_loaded: dict[str, Any] = {}  # this process's loaded modules, by kernel (once per process, like sys.modules)


def _signature(name: str) -> Any:
    """The numba signature of a kernel of KERNELS (at build time)."""
    from numba.core import types
    from numba.np.numpy_support import from_dtype

    def array(spec: str) -> Any:
        code, ndim = spec.split(":")
        return types.Array(from_dtype(np.dtype(_DTYPES[code])), int(ndim.rstrip("w")), "C")

    _, _, args, result = KERNELS[name]
    ret = types.void if result == "void" else types.Tuple([from_dtype(np.dtype(_DTYPES[c])) for c in result.split(",")])
    return ret(*(array(a) for a in args))


def _fits(name: str, args: tuple[Any, ...]) -> bool:
    """Whether ``args`` are exactly the arrays the kernel was built for (the compiled wrapper
    trusts them: another dtype or rank, a strided or misaligned view would be read wrongly, a
    read-only output written)."""
    specs = KERNELS[name][2]
    if len(args) != len(specs):
        return False
    for a, spec in zip(args, specs):
        code, ndim = spec.split(":")
        if not (isinstance(a, np.ndarray) and a.ndim == int(ndim.rstrip("w")) and a.dtype == _DTYPES[code]
                and a.flags.c_contiguous and a.flags.aligned and (a.flags.writeable or not ndim.endswith("w"))):
            return False
    return True


def call(name: str, jit: Callable[..., Any], *args: Any) -> Any:
    """``name`` ahead-of-time compiled when it is built and the arguments fit it, else ``jit``
    (the same kernel through numba's JIT). The results are the same either way."""
    fn = kernel(name)
    if fn is not None and _fits(name, args):
        return fn(*args)
    return jit(*args)


def _cpu() -> str:
    """A short key of this machine's CPU (architecture and instruction-set flags): a module
    built for one CPU must not run on another (a home folder shared between machines)."""
    import hashlib
    import platform

    text = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith(("flags", "Features", "isa")):
                    text += line
                    break
    except OSError:
        text += platform.processor()
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def folder() -> Path | None:
    """Where this version's module is (or goes); None if rovlab's sources cannot be read."""
    from rovlab import cache_home, source_digest

    digest = source_digest()
    return None if digest is None else cache_home() / "aot" / f"{digest[:16]}-{_cpu()}"


def _module_file(where: Path, name: str) -> Path | None:
    return module_file(where, f"{MODULE}_{name}")


def module_file(where: Path, module: str) -> Path | None:
    """The built extension module ``module`` in ``where``, if it is there."""
    import importlib.machinery

    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = where / f"{module}{suffix}"
        if path.is_file():
            return path
    return None


def load(path: Path, module: str, name: str) -> Callable[..., Any] | None:
    """The function ``name`` of the built module at ``path``; None when the module cannot be
    loaded (damaged, or built by another numba or Python: then the JIT kernel runs)."""
    import importlib.util

    fn = None
    try:
        spec = importlib.util.spec_from_file_location(module, path)
        if spec is not None and spec.loader is not None:
            mod = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(mod)
            fn = getattr(mod, name, None)
    except (ImportError, OSError):
        fn = None
    try:
        os.utime(path.parent)  # its last use (rovlab.prune_caches)
    except OSError:
        pass
    return fn


def built() -> bool:
    """Whether every kernel of this version is built for this CPU."""
    where = folder()
    return where is not None and all(_module_file(where, name) is not None for name in KERNELS)


def failed() -> str | None:
    """Why building this version's kernels failed here (then it is not retried until rovlab's
    sources change: each try costs a minute of CPU), or None."""
    where = folder()
    if where is None:
        return None
    try:
        return (where / FAILED).read_text(encoding="utf-8").strip() or "unknown"
    except OSError:
        return None


def enabled() -> bool:
    """ROVLAB_AOT: 1/auto (default: use the module when it is built) or 0 (never)."""
    return os.environ.get("ROVLAB_AOT", "1").strip().lower() not in ("0", "no", "off", "false")


def kernel(name: str) -> Callable[..., Any] | None:
    """The ahead-of-time compiled ``name`` (a key of :data:`KERNELS`), loaded once per process;
    None when it is not built yet, disabled (ROVLAB_AOT=0) or unloadable: then the JIT kernel runs."""
    if name in _loaded:
        return _loaded[name]
    where = folder() if enabled() else None
    path = _module_file(where, name) if where is not None else None
    fn = load(path, f"{MODULE}_{name}", name) if path is not None else None
    _loaded[name] = fn
    return fn


def build(where: Path | None = None) -> Path:
    """Compile :data:`KERNELS` into ``where`` (default :func:`folder`) for this CPU; returns the
    folder. Needs a C compiler (numba.pycc builds with distutils' toolchain)."""
    import importlib

    where = where or folder()
    if where is None:
        raise RuntimeError("rovlab's sources cannot be read: no cache folder to build into")
    for name, (mod_name, func, _, _) in KERNELS.items():
        fn = getattr(importlib.import_module(mod_name), func)
        compile_module(where, f"{MODULE}_{name}", name, getattr(fn, "py_func", fn), _signature(name))
    return where


def compile_module(where: Path, module: str, name: str, func: Callable[..., Any], signature: Any, *,
                   release_gil: bool = True) -> Path:
    """Compile the plain function ``func`` for ``signature`` (numba types) into the extension
    module ``where/module`` exporting it as ``name``, for this CPU; returns the module's path. The
    functions ``func`` calls are compiled as the JIT compiles them (their own flags; from numba's
    disk cache when they are there, which makes a build take seconds instead of minutes).
    ``release_gil``: as its JIT version's ``nogil`` (the filter's kernels release it, the
    simulator's loop does not: threads sharing a run's scratch arrays stay serialised)."""
    import shutil
    import tempfile

    CC, host_cpu = _pycc()
    _RELEASE_GIL[0] = release_gil
    where.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".build-", dir=where) as tmp:
        cc = CC(module)
        cc.output_dir = tmp
        cc.target_cpu = host_cpu
        cc.verbose = False
        cc.export(name, signature)(func)
        cc.compile()
        made = module_file(Path(tmp), module)
        if made is None:
            raise RuntimeError(f"numba.pycc produced no {module} extension in {tmp}")
        partial = where / f".{made.name}.tmp"
        shutil.move(str(made), str(partial))
        os.replace(partial, where / made.name)
        return where / made.name


_RELEASE_GIL = [True]  # what the module being built does (compile_module's release_gil)


def _pycc() -> tuple[Any, str]:
    """numba.pycc's CC, set up (once per process) to build as the JIT builds, and this CPU's name."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc is pending deprecation (no replacement yet)
        from llvmlite import binding
        from numba.core import codegen
        from numba.core.registry import cpu_target
        from numba.pycc import CC
        from numba.pycc import compiler as pycc_compiler

    if not getattr(pycc_compiler, "_rovlab_ready", False):
        # Built as the JIT builds them (this process only builds): releasing the GIL as the
        # kernels' nogil=True asks (pycc starts from default flags: the log's reader and writer
        # threads would wait), and for this CPU's name *and* features (pycc derives features from
        # the name alone, which a virtual machine that masks some would not run).
        class _Flags(pycc_compiler.Flags):
            def __init__(self, *args: Any, **kwargs: Any) -> None:
                super().__init__(*args, **kwargs)
                self.release_gil = _RELEASE_GIL[0]  # type: ignore[assignment]

        pycc_compiler.Flags = _Flags  # type: ignore[misc]
        codegen.AOTCPUCodegen._customize_tm_features = lambda self: self._get_host_cpu_features()  # type: ignore[method-assign]
        # the JIT refreshes the typing and target registries before compiling; numba.pycc does
        # not, and without them some kernels fail to type (an inlined kernel's integer codes)
        cpu_target.typing_context.refresh()
        cpu_target.target_context.refresh()
        pycc_compiler._rovlab_ready = True  # type: ignore[attr-defined]
    return CC, binding.get_host_cpu_name()


def record_failure(path: Path, why: str) -> None:
    """Write why a build failed (it is then not retried until rovlab's sources change)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(why + "\n", encoding="utf-8")
    except OSError:
        pass  # the next run tries again


def build_in_background() -> str | None:
    """Start ``python -m rovlab._aot build`` detached and at low priority unless it runs already;
    returns its log file (None when there is nowhere to build)."""
    from rovlab import _jit

    if folder() is None:
        return None
    return _jit.start_detached(BUILD_KEY, ["rovlab._aot", "build"])


def main(argv: list[str] | None = None) -> int:
    import argparse
    import time

    p = argparse.ArgumentParser(prog="python -m rovlab._aot", description=__doc__.splitlines()[0])
    p.add_argument("action", choices=["build", "where"], help="build the module, or print where it goes")
    p.add_argument("--lock", default=None, help="lock file to remove when done (the background build)")
    args = p.parse_args(argv)
    try:
        if args.action == "where":
            print(folder())
            return 0
        if args.lock:
            try:
                os.nice(10)  # behind the user's foreground work
            except OSError:
                pass
        t0 = time.perf_counter()
        path = build()
        print(f"built {path} in {time.perf_counter() - t0:.1f} s")
        return 0
    except Exception as exc:  # the log says why; the foreground runs keep using the JIT kernels
        why = f"{type(exc).__name__}: {exc}"
        print(f"building the ahead-of-time kernels failed: {why}", file=sys.stderr)
        where = folder()
        if where is not None:
            record_failure(where / FAILED, why)
        return 1
    finally:
        if args.lock:
            Path(args.lock).unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
