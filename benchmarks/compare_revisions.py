"""The closed loop of this working tree against an earlier revision, timed in the same run.

    python benchmarks/compare_revisions.py [--base REV] [--also REV ...] [--rounds N] [--repeat N]

Exports the base revision's ``src/`` into a temporary folder (``git archive``), then times one
60 s case study (``simulate`` of each packaged case, after a warm-up that also compiles) in
fresh subprocesses, alternating base and this tree round by round so that machine noise hits
both alike, and prints the best times and their ratio. The default base is the last revision
before the loop was split into components (issue 9).

Not part of ``make bench`` (it needs git and compiles the base's loop once).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_BASE = "53493b4"  # main before the component redesign

SNIPPET = r"""
import json, sys, time
from rovlab.sim.runner import prepare, run_prepared
from rovlab.sim.scenario import load_scenario
out = {}
for name in ("step-process-model", "step-observer-model", "dropout"):
    prep = prepare(load_scenario(name))
    run_prepared(prep)  # warm-up (compile or load the cache)
    best = float("inf")
    for _ in range(int(sys.argv[1])):
        t0 = time.perf_counter()
        run_prepared(prep)
        best = min(best, time.perf_counter() - t0)
    out[name] = best
print(json.dumps(out))
"""


def _time(src: Path, repeat: int) -> dict[str, float]:
    # ROVLAB_AOT=0 is for older revisions only (those of issue 16 built the loop ahead of time in a
    # background process and ran it instead of the JIT loop); this tree and revisions since issue
    # 25 have one compile path (numba.njit(cache=True)) and ignore it
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1", ROVLAB_AOT="0")
    out = subprocess.run([sys.executable, "-c", SNIPPET, str(repeat)], env=env, check=True,
                         capture_output=True, text=True, cwd=tempfile.gettempdir())
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default=DEFAULT_BASE, help="git revision to compare against")
    ap.add_argument("--also", nargs="*", default=[], help="more revisions to time in the same rounds "
                                                         "(e.g. 3ec9749: the component redesign itself)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (each a fresh process)")
    ap.add_argument("--repeat", type=int, default=20, help="timed runs per case per round")
    args = ap.parse_args()
    revs = [args.base, *args.also]
    with tempfile.TemporaryDirectory() as tmp:
        trees: dict[str, Path] = {}
        for i, rev in enumerate(revs):
            archive = Path(tmp) / f"{i}.tar"
            subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev, "src"], check=True)
            with tarfile.open(archive) as tf:
                tf.extractall(Path(tmp) / str(i), filter="data")
            trees[rev] = Path(tmp) / str(i) / "src"
        trees["this"] = ROOT / "src"
        for src in trees.values():
            _time(src, 1)  # compile (or load) each tree's loops before any timing
        best: dict[str, dict[str, float]] = {k: {} for k in trees}
        for _ in range(args.rounds):
            for label, src in trees.items():
                for case, t in _time(src, args.repeat).items():
                    best[label][case] = min(best[label].get(case, float("inf")), t)
    print(f"== Closed loop, one 60 s case: best of {args.rounds} x {args.repeat}, ratios to {args.base} ==")
    print(f"{'case':24s} " + " ".join(f"{label[:10]:>18s}" for label in trees))
    for case in best[args.base]:
        b = best[args.base][case]
        print(f"{case:24s} " + " ".join(f"{best[label][case] * 1e3:7.3f} ms {best[label][case] / b:5.2f}x"
                                        for label in trees))

if __name__ == "__main__":
    main()
