"""Run every benchmark script in this folder, one after the other, in fresh processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
here = Path(__file__).parent


def _machine() -> str:
    """Date, CPU and load: what the numbers below were measured on (for the README table)."""
    import datetime
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    versions = []
    for mod in ("numpy", "scipy", "numba", "pyarrow"):
        try:
            versions.append(f"{mod} {__import__(mod).__version__}")
        except ImportError:
            versions.append(f"{mod} -")
    return (f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M UTC}; {cpu}, {os.cpu_count()} cores; "
            f"load {load:.1f} at start; Python {platform.python_version()}, {', '.join(versions)}")


print(f"# make bench: {_machine()}", flush=True)
status = 0
for script in sorted(here.glob("bench_*.py")):
    print(f"\n#### {script.name}", flush=True)
    status |= subprocess.call([sys.executable, str(script)], env=env)
sys.exit(status)
