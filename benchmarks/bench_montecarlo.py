"""Monte Carlo at the machine's limit (issues 16 and 25): whole processes, warm numba cache.

``rovlab simulate step-process-model --runs 1000 --no-figures`` as a user runs it (a fresh
process: imports, the loop loaded from numba's cache, the single run and its files, the 1000
runs, the statistics and their files), with 2 and with 1 worker processes, against the peer a
user would otherwise write: a plain ``multiprocessing.Pool`` (fork) mapping
``summarise(simulate(scenario, seed=s))`` over the seeds, also a whole process, with the same
number of processes and writing nothing. The cache is warmed first with
``rovlab compile step-process-model`` (numba's own cache: in-tree ``__pycache__`` or the
NUMBA_CACHE_DIR of this environment), so no row includes the compile (bench_first_run.py times
that). Next to them, the single 60 s run as a whole process (``rovlab simulate
step-process-model --no-figures``: what the Monte Carlo command costs besides its runs), and, in
this process, the compiled loop alone, one run at a time on one core.

Rate = vehicle-steps per second of wall time, a vehicle-step being one plant integration step
(0.01 s): 1000 runs of 60 s = 6.0 M. Goal: >= 5 M/s with 2 workers (10 M/s stretch).

Run: ``.venv/bin/python benchmarks/bench_montecarlo.py`` (ROVLAB_BENCH_MC_RUNS, default 1000;
ROVLAB_BENCH_MC_REPEAT, best of, default 3).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import os  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import _timing  # noqa: E402,F401  (pins the BLAS/numba threads to 1)

SCENARIO = "step-process-model"
RUNS = int(os.environ.get("ROVLAB_BENCH_MC_RUNS", "1000"))
REPEAT = int(os.environ.get("ROVLAB_BENCH_MC_REPEAT", "3"))
PY = sys.executable

PEER = """
import multiprocessing as mp, sys
from rovlab.sim.results import summarise
from rovlab.sim.runner import simulate

def one(seed):
    r = simulate(sys.argv[1], seed=seed)
    return seed, summarise(r), r.nees, r.nis

if __name__ == "__main__":
    runs, workers = int(sys.argv[2]), int(sys.argv[3])
    one(0)  # compiled loop loaded before the fork, as rovlab does
    with mp.get_context("fork").Pool(workers) as pool:
        out = pool.map(one, range(runs), chunksize=max(1, runs // (workers * 8)))
    assert len(out) == runs
"""


def loop_rate() -> float:
    """Vehicle-steps per second of the compiled loop alone, in this process, on one core: 16 runs
    one at a time (the loop loaded from numba's cache beforehand), best of 7."""
    from rovlab.sim.montecarlo import Campaign
    from rovlab.sim.prepare import reseed
    from rovlab.sim.runner import Simulation
    from rovlab.sim.scenario import load_scenario_data

    data, file = load_scenario_data(SCENARIO)
    template = Campaign(data, file, 0).template
    preps = [reseed(template, s) for s in range(16)]
    Simulation(preps[0]).advance(preps[0].drive)  # loaded (or compiled) before timing
    steps = len(preps) * (preps[0].n_ctrl - 1) * preps[0].plant.n_sub
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        for prep in preps:
            Simulation(prep).advance(prep.drive)
        times.append(time.perf_counter() - t0)
    return steps / min(times)


def _timed(argv: list[str], cwd: str) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the process and its workers) of one whole process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr}")
    if "compiling" in done.stderr:  # the cache was invalidated in between (kernel sources edited)
        print(f"   warning: {' '.join(argv[2:6])} ... compiled its loop ({dt:.2f} s): not a warm run", flush=True)
    return dt, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def best(argv: list[str], cwd: str) -> tuple[float, float]:
    """Best wall time of REPEAT runs, and the least CPU time (the machine is shared: the least
    disturbed run is the closest to what the code costs)."""
    runs = [_timed(argv, cwd) for _ in range(REPEAT)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def main() -> None:
    from rovlab.sim.scenario import load_scenario

    sc = load_scenario(SCENARIO)
    per_run = round(sc.duration_s / sc.plant_step_s)
    steps = RUNS * per_run
    with tempfile.TemporaryDirectory(prefix="rovlab-mc-") as work:
        peer = Path(work) / "peer.py"
        peer.write_text(PEER, encoding="utf-8")
        out = str(Path(work) / "out")
        cli = [PY, "-m", "rovlab.interfaces.cli", "simulate", SCENARIO, "--no-figures", "--out", out]
        # warm numba's cache (a no-op when it is): no row below includes the compile
        t0 = time.perf_counter()
        subprocess.run([PY, "-m", "rovlab.interfaces.cli", "compile", SCENARIO], cwd=work, check=True,
                       stdout=subprocess.DEVNULL)
        warm_up = time.perf_counter() - t0
        load = os.getloadavg()[0]
        t_single, c_single = best(cli, work)
        rows = []
        for workers in (2, 1):
            ours = best(cli + ["--runs", str(RUNS), "--workers", str(workers)], work)
            theirs = best([PY, str(peer), SCENARIO, str(RUNS), str(workers)], work)
            rows.append((workers, ours, theirs))
        load_end = os.getloadavg()[0]
    rate_loop = loop_rate()
    print(f"\n== Monte Carlo, {SCENARIO}, {RUNS} runs of {sc.duration_s:g} s = {steps / 1e6:.1f} M vehicle-steps, "
          f"whole processes, warm numba cache, best of {REPEAT} (load {load:.1f} at start, {load_end:.1f} at end, "
          f"{os.cpu_count()} cores) ==")
    print(f"   (rovlab compile {SCENARIO} beforehand: {warm_up:.2f} s)")
    print(f"{'workers':>7s}  {'rovlab simulate --runs: wall':>28s} {'(CPU)':>8s} {'M steps/s':>10s}   "
          f"{'Pool.map(simulate+summarise): wall':>34s} {'(CPU)':>8s} {'M steps/s':>10s}  {'speed-up':>8s}")
    for workers, (ours, ours_cpu), (theirs, theirs_cpu) in rows:
        print(f"{workers:7d}  {ours:26.2f} s {ours_cpu:6.2f} s {steps / ours / 1e6:10.2f}   {theirs:32.2f} s "
              f"{theirs_cpu:6.2f} s {steps / theirs / 1e6:10.2f}  {theirs / ours:7.2f}x")
    print(f"   the single 60 s run, whole process, best of {REPEAT}: {t_single:.2f} s wall, {c_single:.2f} s CPU\n"
          f"      (rovlab simulate {SCENARIO} --no-figures: process start, imports, the loop from the cache, "
          f"design, the run, its CSV/MCAP files)")
    print(f"   the compiled loop alone, in process, one core, one run at a time, best of 7: "
          f"{rate_loop / 1e6:.2f} M steps/s ({per_run / rate_loop * 1e3:.2f} ms per 60 s run)")
    print(f"   floor (issue 25): >= 3.5 M steps/s whole process on 2 workers = {RUNS} runs in <= {steps / 3.5e6:.2f} s; "
          "a single 60 s case <= 1.0 s (issue 16's goal was 5 M steps/s)")


if __name__ == "__main__":
    main()
