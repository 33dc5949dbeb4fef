"""Compiling the simulator's loop: when, how long, and saying so.

The loop (rovlab.sim.loop.run_loop) is compiled by numba once per combination of components
(plant, estimator, controller) and kept in numba's disk cache (rovlab._jit), so only the first
run of a combination on a machine waits for it (~20-30 s on a 2-core machine) and every later
process loads it (~0.3 s). Nothing compiles in the background: the command that needs the loop
compiles it in the foreground and says so, and ``rovlab compile`` prepares the cache ahead
(e.g. in a Dockerfile).

:func:`needs_compiling` tells a command whether it will wait (so it can say so first). It reads
a small record that :func:`compile_loop` writes beside numba's cache files of the loop: the
combinations compiled from the present kernel sources, with their compile times. The record is
only a hint for that message: numba decides what it loads.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

RECORD = "rovlab-loops.json"


def _record_file() -> Path | None:
    """The record beside numba's cache of the loop (None where the loop cannot be cached)."""
    from rovlab.sim.loop import run_loop

    folder = getattr(getattr(run_loop, "stats", None), "cache_path", None)
    return Path(folder) / RECORD if folder else None


def _read() -> dict[str, Any]:
    from rovlab._jit import kernel_digest

    path = _record_file()
    if path is None:
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict) or data.get("kernels") != kernel_digest() or not isinstance(data.get("loops"), dict):
        return {}  # compiled from other kernel sources or versions: numba compiles again
    return data["loops"]


def needs_compiling(key: str) -> bool:
    """Whether the loop for this combination of components (rovlab._jit.loop_key) is not in
    numba's cache yet, as far as rovlab's record knows."""
    from rovlab._jit import compiled_in_memory

    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False  # the user runs numba's kernels as plain Python: nothing compiles
    return bool(compiled_in_memory()) or key not in _read()


def record(key: str, seconds: float) -> None:
    """Note that the loop for ``key`` is in numba's cache now (after compiling it in ``seconds``)."""
    from rovlab._jit import compiled_in_memory, kernel_digest

    path = _record_file()
    if path is None or compiled_in_memory():
        return
    loops = dict(_read())
    loops[key] = round(seconds, 1)
    tmp = path.with_name(f".{RECORD}.{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps({"kernels": kernel_digest(), "loops": loops}, indent=1))
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)  # a cache folder we cannot write: only the message is affected


def compile_loop(prep: Any) -> float:
    """Compile the loop for a prepared run's components (or load it from numba's cache) by running
    its first control step on a copy of its components; returns the seconds it took."""
    from rovlab.sim.runner import Simulation, first_rows

    t0 = time.perf_counter()
    Simulation(prep).advance(first_rows(prep.drive, 1))
    seconds = time.perf_counter() - t0
    record(prep.loop_key, seconds)
    return seconds
