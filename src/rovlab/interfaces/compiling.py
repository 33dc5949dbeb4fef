"""What the commands say about compiling the simulator's loop (rovlab.sim.compile): before a loop
that numba has not cached yet is compiled, and how long it took."""

from __future__ import annotations

import math
import sys
from typing import Any


def loop_of(data, file, controller: str | None = None, design: str | None = None) -> tuple[str, str, float] | None:
    """(marker key, description, duration in control steps) of the loop a scenario runs, read
    without importing the simulator (so without compiling anything); None if the scenario or its
    configuration is bad (the run itself then reports it, with file and key)."""
    from rovlab import _jit
    from rovlab.params.design import load_design_config
    from rovlab.params.validate import ConfigError
    from rovlab.sim.scenario import scenario_from_dict

    try:
        sc = scenario_from_dict(data, file=file)
        config = load_design_config(design or sc.design)
    except ConfigError:
        return None
    estimator, controller = sc.estimator or config.estimator, controller or sc.controller or config.controller
    rows = math.floor(sc.duration_s / config.sample_time + 1e-9) + 1
    return (_jit.loop_key(sc.plant, estimator, controller), f"the {estimator} + {controller} loop ({sc.plant} plant)",
            rows)


def announce_compile(loops: list[tuple[str, str, float] | None]) -> None:
    """Say which loops compile now (those numba has not cached yet), before they do."""
    from rovlab.sim.compile import needs_compiling

    todo = list(dict.fromkeys(what for key, what, _ in filter(None, loops) if needs_compiling(key, shipped=_shipped(key))))
    if todo:
        print(f"compiling {', '.join(todo)} (once per machine: numba caches {'it' if len(todo) == 1 else 'them'}; "
              f"up to ~30 s {'' if len(todo) == 1 else 'each '}on 2 cores, less when they share kernels) ...",
              file=sys.stderr, flush=True)


def _shipped(key: str) -> bool:
    """Whether the estimator and controller of a loop key are rovlab's own."""
    from rovlab.core.components import SHIPPED

    _plant, rest = key.split("-", 1)
    return any(rest == f"{e}-{c}" for e in SHIPPED["estimator"] for c in SHIPPED["controller"])


def ensure_compiled(prep: Any, *, say: bool = True) -> float | None:
    """Compile the loop a prepared run needs if numba has not cached it yet, saying so (unless
    not ``say``: the caller says it) and how long it took; the seconds, or None if it was cached."""
    from rovlab.sim.compile import needs_compiling
    from rovlab.sim.runner import compile_loop, shipped_components

    shipped = shipped_components(prep)
    if not needs_compiling(prep.loop_key, shipped=shipped):
        return None
    sc = prep.scenario
    what = f"the {sc.estimator or prep.config.estimator} + {sc.controller or prep.config.controller} loop ({sc.plant} plant)"
    how = "once per machine: numba caches it for later runs" if shipped else \
        "components from outside rovlab: compiled in every process"
    if say:
        print(f"compiling {what} ({how}) ...", file=sys.stderr, flush=True)
    seconds = compile_loop(prep)
    if say:
        print(f"compiled {what} in {seconds:.1f} s", file=sys.stderr, flush=True)
    return seconds
