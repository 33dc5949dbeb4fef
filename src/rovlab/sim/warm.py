"""Compile the simulator's loop for one scenario's components into the disk cache, and exit.

Started by ``rovlab simulate`` (rovlab._jit.compile_in_background) as a detached, low-priority
process while the first run of a combination of components runs interpreted, so that the next
runs load the compiled loop instead of waiting for it::

    python -m rovlab.sim.warm SCENARIO --key KEY [--config CONFIG] --lock LOCKFILE

It prepares the scenario and runs its first control step through the one call site of the loop
(rovlab.sim.runner.Simulation), which compiles the loop and everything it calls and records the
combination as compiled. Its output goes to the log file next to the marker.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m rovlab.sim.warm", description=__doc__.splitlines()[0])
    p.add_argument("scenario", help="packaged scenario name or TOML path")
    p.add_argument("--key", required=True, help="the combination of components (rovlab._jit markers)")
    p.add_argument("--config", default=None, help="filter/controller configuration (default: the scenario's)")
    p.add_argument("--lock", default=None, help="lock file to remove when done")
    args = p.parse_args(argv)
    try:
        os.nice(10)  # behind the user's foreground work
    except OSError:
        pass
    try:
        from rovlab import _jit
        from rovlab.params.design import load_design_config
        from rovlab.sim.runner import Simulation, first_rows, prepare
        from rovlab.sim.scenario import load_scenario

        if _jit.interpreting():
            print("NUMBA_DISABLE_JIT is set: nothing to compile", file=sys.stderr)
            return 2
        t0 = time.perf_counter()
        config = load_design_config(args.config) if args.config else None
        prep = prepare(load_scenario(args.scenario), config=config)
        if prep.loop_key != args.key:
            print(f"note: the scenario's components are {prep.loop_key}, not {args.key}", file=sys.stderr)
        # the JIT loop itself, not a module built ahead of time (advance then starts that build)
        Simulation(prep).advance(first_rows(prep.drive, 1), built=False)
        print(f"compiled the loop for {prep.loop_key} in {time.perf_counter() - t0:.1f} s")
        return 0
    except Exception as exc:  # a log for the curious; the foreground run has its own errors
        print(f"compiling in the background failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        if args.lock:
            Path(args.lock).unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
