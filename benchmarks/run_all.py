"""Run every benchmark script in this folder, one after the other, in fresh processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
here = Path(__file__).parent
status = 0
for script in sorted(here.glob("bench_*.py")):
    print(f"\n#### {script.name}", flush=True)
    status |= subprocess.call([sys.executable, str(script)], env=env)
sys.exit(status)
