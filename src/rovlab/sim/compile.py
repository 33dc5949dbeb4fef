"""Whether the simulator's loop will be compiled, for the commands that say so.

The loop (rovlab.sim.loop.run_loop) is compiled by numba once per combination of components
(plant, estimator, controller) and kept in numba's disk cache (rovlab._jit), so only the first
run of a combination on a machine waits for it (~10-30 s on a 2-core machine) and every later
process loads it (~0.3 s). Nothing compiles in the background: the command that needs the loop
compiles it in the foreground and says so, and ``rovlab compile`` prepares the cache ahead
(e.g. in a Dockerfile). Components from outside rovlab (a plugin, a script) never enter that
cache: their loop is compiled in every process (rovlab.sim.loop.loop_for).

:func:`needs_compiling` tells a command whether it will wait. It reads a small record beside
numba's cache files of the loop: the combinations that ran through the cached loop, with their
compile times, valid while the kernel sources (rovlab._jit.kernel_digest) and the loop's source
file (whose modification time and size numba checks itself) are those it was written with. The
record is only a hint for that message: numba decides what it loads.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

RECORD = "rovlab-loops.json"
_noted: set[str] = set()  # combinations this process has seen run through the cached loop


def _record_file() -> Path | None:
    """The record beside numba's cache of the loop (None where the loop cannot be cached)."""
    from rovlab.sim.loop import run_loop

    folder = getattr(getattr(run_loop, "stats", None), "cache_path", None)
    return Path(folder) / RECORD if folder else None


def _sources() -> dict[str, Any]:
    from rovlab import _jit
    from rovlab.sim import loop

    try:
        st = os.stat(loop.__file__)
        stamp: Any = [st.st_mtime, st.st_size]
    except OSError:
        stamp = None
    return {"kernels": _jit.kernel_digest(), "loop_file": stamp}


def _read() -> dict[str, Any]:
    path = _record_file()
    if path is None:
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict) or not isinstance(data.get("loops"), dict) \
            or any(data.get(k) != v for k, v in _sources().items()):
        return {}  # compiled from other sources (or the loop's file touched): numba compiles again
    return data["loops"]


def needs_compiling(key: str, *, shipped: bool = True) -> bool:
    """Whether the loop for this combination of components (rovlab._jit.loop_key) is not in
    numba's cache, as far as rovlab's record knows; always for components from outside rovlab
    (``shipped`` False), whose loop is compiled in every process."""
    from rovlab import _jit
    from rovlab.sim.loop import run_loop

    if not hasattr(run_loop, "stats"):
        return False  # numba's JIT is disabled (NUMBA_DISABLE_JIT): everything runs as plain Python
    return not shipped or bool(_jit.compiled_in_memory()) or key not in _read()


def record(key: str, seconds: float | None = None) -> None:
    """Note that the loop for ``key`` is in numba's cache (compiled in ``seconds``, if known)."""
    from rovlab._jit import compiled_in_memory

    path = _record_file()
    if path is None or compiled_in_memory():
        return
    loops = dict(_read())
    if seconds is not None or key not in loops:
        loops[key] = None if seconds is None else round(seconds, 1)
    tmp = path.with_name(f".{RECORD}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps({**_sources(), "loops": loops}, indent=1))
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)  # a cache folder we cannot write: only the message is affected


def note_cached(key: str) -> None:
    """Called after a run through the cached loop (rovlab.sim.runner.Simulation): record the
    combination if the record does not have it yet (once per process and combination)."""
    if key in _noted:
        return
    _noted.add(key)
    if key not in _read():
        record(key)
