"""Monte Carlo at the machine's limit (issue 16 part 2): whole processes, warm numba cache.

``rovlab simulate step-process-model --runs 1000 --no-figures`` as a user runs it (a fresh
process: imports, the single run and its files, the 1000 runs, the statistics and their files;
the loop built ahead of time, rovlab.sim.prebuilt, as every run after the first few uses it),
with 1 and with 2 worker processes, against the peer a user would otherwise write: a plain
``multiprocessing.Pool`` (fork) mapping ``summarise(simulate(scenario, seed=s))`` over the seeds,
also a whole process, with the same number of processes and writing nothing. Next to them, the
single run alone (``--runs 1``): the part of the Monte Carlo command that is not the runs; the
same Monte Carlo with the runs one by one (``ROVLAB_LANES=0``: no lanes over runs) and through
numba's JIT (``ROVLAB_AOT=0``); and, in this process, the compiled loop alone: one run at a time
against sixteen runs in lanes (rovlab.sim.loop.run_loop_lanes), per core.

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
from rovlab.sim.runner import simulate, summarise

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


JIT = {**os.environ, "ROVLAB_AOT": "0"}  # the JIT loop (numba's start-up in every process)
ONE_BY_ONE = {**os.environ, "ROVLAB_LANES": "0"}  # the built loop, one run at a time (no lanes)


def loop_rates() -> tuple[float, float]:
    """Vehicle-steps per second of the compiled loop alone, in this process, on one core: 16
    runs one at a time against the same 16 in lanes (the JIT loops, compiled beforehand)."""
    from rovlab.core.components import LANES
    from rovlab.sim.montecarlo import Campaign
    from rovlab.sim.runner import Simulation, reseed, run_lanes
    from rovlab.sim.scenario import load_scenario_data

    data, file = load_scenario_data(SCENARIO)
    template = Campaign(data, file, 0).template
    preps = [reseed(template, s) for s in range(LANES)]
    run_lanes(preps, built=False)  # compiled (or loaded from numba's cache) before timing
    Simulation(preps[0]).advance(preps[0].drive, built=False)
    steps = LANES * (preps[0].n_ctrl - 1) * preps[0].plant.n_sub
    one, lanes = [], []
    for _ in range(7):
        t0 = time.perf_counter()
        for prep in preps:
            Simulation(prep).advance(prep.drive, built=False)
        t1 = time.perf_counter()
        run_lanes(preps, built=False)
        t2 = time.perf_counter()
        one.append(t1 - t0)
        lanes.append(t2 - t1)
    return steps / min(one), steps / min(lanes)


def _timed(argv: list[str], cwd: str, env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the process and its workers) of one whole process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr}")
    return dt, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def best(argv: list[str], cwd: str, env: dict[str, str] | None = None) -> tuple[float, float]:
    """Best wall time of REPEAT runs, and the least CPU time (the machine is shared: the least
    disturbed run is the closest to what the code costs)."""
    runs = [_timed(argv, cwd, env) for _ in range(REPEAT)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def main() -> None:
    from rovlab.sim.scenario import load_scenario

    sc = load_scenario(SCENARIO)
    steps = RUNS * round(sc.duration_s / sc.plant_step_s)
    with tempfile.TemporaryDirectory(prefix="rovlab-mc-") as work:
        peer = Path(work) / "peer.py"
        peer.write_text(PEER, encoding="utf-8")
        out = str(Path(work) / "out")
        cli = [PY, "-m", "rovlab.interfaces.cli", "simulate", SCENARIO, "--no-figures", "--out", out]
        # warm the numba cache (a no-op when it is); one by one, so that it starts no background build
        _timed(cli + ["--runs", "2"], work, env=ONE_BY_ONE)
        # the loops built ahead of time (one run's and the lanes'), as the first runs and the first
        # Monte Carlo start them in the background (waits for them)
        _timed([PY, "-m", "rovlab.sim.prebuilt", "build", SCENARIO], work)
        _timed([PY, "-m", "rovlab.sim.prebuilt", "build", SCENARIO, "--lanes"], work)
        load = os.getloadavg()[0]
        t_single, c_single = best(cli, work)
        t_single_jit, _ = best(cli, work, env=JIT)
        rows = []
        for workers in (1, 2):
            ours = best(cli + ["--runs", str(RUNS), "--workers", str(workers)], work)
            theirs = best([PY, str(peer), SCENARIO, str(RUNS), str(workers)], work)
            rows.append((workers, ours, theirs))
        jit = best(cli + ["--runs", str(RUNS), "--workers", "2"], work, env=JIT)
        one_by_one = best(cli + ["--runs", str(RUNS), "--workers", "2"], work, env=ONE_BY_ONE)
        load_end = os.getloadavg()[0]
    rate_one, rate_lanes = loop_rates()
    print(f"\n== Monte Carlo, {SCENARIO}, {RUNS} runs of {sc.duration_s:g} s = {steps / 1e6:.1f} M vehicle-steps, "
          f"whole processes, best of {REPEAT} (load {load:.1f} at start, {load_end:.1f} at end, "
          f"{os.cpu_count()} cores) ==")
    print(f"{'workers':>7s}  {'rovlab simulate --runs: wall':>28s} {'(CPU)':>8s} {'M steps/s':>10s}   "
          f"{'Pool.map(simulate+summarise): wall':>34s} {'(CPU)':>8s} {'M steps/s':>10s}  {'speed-up':>8s}")
    for workers, (ours, ours_cpu), (theirs, theirs_cpu) in rows:
        print(f"{workers:7d}  {ours:26.2f} s {ours_cpu:6.2f} s {steps / ours / 1e6:10.2f}   {theirs:32.2f} s "
              f"{theirs_cpu:6.2f} s {steps / theirs / 1e6:10.2f}  {theirs / ours:7.2f}x")
    (jit_wall, jit_cpu) = jit
    (obo_wall, obo_cpu) = one_by_one
    print(f"{'2, 1by1':>7s}  {obo_wall:26.2f} s {obo_cpu:6.2f} s {steps / obo_wall / 1e6:10.2f}   "
          "(ROVLAB_LANES=0: the built loop, one run at a time, no lanes)")
    print(f"{'2, JIT':>7s}  {jit_wall:26.2f} s {jit_cpu:6.2f} s {steps / jit_wall / 1e6:10.2f}   "
          "(ROVLAB_AOT=0: the loop through numba's JIT, one run at a time, whose start-up every process pays)")
    print(f"   the compiled loop alone, one core, best of 7: one run at a time {rate_one / 1e6:.2f} M steps/s, "
          f"16 runs in lanes {rate_lanes / 1e6:.2f} M steps/s ({rate_lanes / rate_one:.2f}x)")
    print(f"   the single run alone (--runs 1: process start, imports, design, its CSV/MCAP files): {t_single:.2f} s "
          f"wall, {c_single:.2f} s CPU ({t_single_jit:.2f} s with the JIT loop); goal >= 5 M steps/s whole process "
          f"= {RUNS} runs in <= {steps / 5e6:.2f} s")


if __name__ == "__main__":
    main()
