"""First run and one-shot commands: whole processes with an empty numba cache (issue 16 part 1).

Each command runs as a fresh process with XDG_CACHE_HOME pointing at a new empty folder, so
rovlab's numba cache (XDG_CACHE_HOME/rovlab/numba) is empty: what a new user or a fresh
reinstall sees. Next to them, the floor every Python tool pays on this machine (the interpreter,
numpy, scipy.linalg, numba imports), so the table says what dominates. `rovlab filter` and
`rovlab simulate` compile kernels the first time: they are timed cold and then warm.

Run: ``.venv/bin/python benchmarks/bench_first_run.py [--quick]`` (``--quick``: no simulate).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import os  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import _timing  # noqa: E402,F401  (pins the BLAS/numba threads to 1)

PY = sys.executable
ROVLAB = [PY, "-m", "rovlab.interfaces.cli"]
REPEAT = 3


def timed(argv: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """(wall seconds, peak RSS MiB) of one whole process."""
    # peak memory by /usr/bin/time where there is one (a child's ru_maxrss also counts the parent's
    # memory it was forked from, before its exec)
    timer = ["/usr/bin/time", "-f", "%M"] if os.path.exists("/usr/bin/time") else []
    t0 = time.perf_counter()
    proc = subprocess.Popen(timer + argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    dt = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}):\n{err}")
    return dt, (float(err.strip().splitlines()[-1]) / 1024.0 if timer else usage.ru_maxrss / 1024.0)


def cold(argv: list[str], work: str, repeat: int = REPEAT) -> list[tuple[float, float]]:
    out = []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
            env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
            env["XDG_CACHE_HOME"] = cache
            out.append(timed(argv, env, work))
    return out


def row(name: str, runs: list[tuple[float, float]], floor: float | None = None) -> None:
    ts = sorted(t for t, _ in runs)
    mem = max(m for _, m in runs)
    spread = f"{ts[0]:.2f}-{ts[-1]:.2f} s" if len(ts) > 1 else f"{ts[0]:.2f} s"
    extra = f"  (+{statistics.median(ts) - floor:.2f} s over numpy)" if floor is not None else ""
    print(f"{name:58s} {statistics.median(ts):7.2f} s  [{spread:>13s}] {mem:7.0f} MiB{extra}")


def main() -> None:
    quick = "--quick" in sys.argv
    with tempfile.TemporaryDirectory(prefix="rovlab-bench-") as work:
        print(f"whole processes, empty numba cache each time; median of {REPEAT} [range], peak RSS")
        print(f"{'command':58s} {'median':>9s}  {'range':>15s} {'peak':>11s}")
        base = {}
        for name, code in [("python -c pass", "pass"), ("python -c 'import numpy'", "import numpy"),
                           ("... + scipy.linalg", "import numpy, scipy.linalg"),
                           ("... + numba", "import numpy, scipy.linalg, numba")]:
            runs = cold([PY, "-c", code], work)
            base[name] = statistics.median(t for t, _ in runs)
            row(name, runs)
        floor = base["python -c 'import numpy'"]
        one_shot = [
            ["thruster", "--thruster", "T1", "--force", "5", "--json"],
            ["allocate", "--wrench", "30", "0", "40", "2", "--json"],
            ["allocate", "--vehicle", "bluerov2_heavy", "--wrench", "300", "0", "40", "2", "--json"],
            ["vehicle", "show", "udrone"],
            ["vehicle", "check", "bluerov2_heavy"],
            ["design", "--config", "thesis"],
            ["added-mass", "--length", "0.45", "--width", "0.33", "--height", "0.25", "--area-front", "0.08",
             "--area-side", "0.11", "--area-top", "0.14"],
        ]
        print("\none-shot commands (no compilation):")
        for argv in one_shot:
            row("rovlab " + " ".join(argv), cold(ROVLAB + argv, work), floor)

        # commands that compile: cold once, then warm (the cache of that first run)
        import numpy as np

        log = Path(work) / "log.csv"
        t = np.arange(600) * 0.1
        lines = ["time_s,tau_Z,tau_N,z_qualisys,z_pressure,psi_qualisys"]
        lines += [f"{x:.1f},0,0,{1 + 0.1 * np.sin(x):.6f},{1.0465 + 0.1 * np.sin(x):.6f},0.5" for x in t]
        log.write_text("\n".join(lines) + "\n")
        compiling = [["filter", str(log), "--out", str(Path(work) / "est.csv")]]
        print("\ncommands that compile kernels: first run (empty cache), then warm")
        for argv in compiling:
            with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
                env = _cold_env(cache)
                first = timed(ROVLAB + argv, env, work)
                warm = [timed(ROVLAB + argv, env, work) for _ in range(REPEAT)]
            label = "rovlab " + " ".join(a if not a.startswith(work) else Path(a).name for a in argv)
            row(label + " (first)", [first])
            row(label + " (warm)", warm, floor)
        if not quick:
            simulate_rows(work, floor)
        print("\ngoal (issue 16): one-shot commands <= 0.5 s cold; first simulate <= 10 s")


def _cold_env(cache: str, **extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT", "ROVLAB_JIT")}
    env["XDG_CACHE_HOME"] = cache
    env.update(extra)
    return env


def _background_done(cache: str, since: float, limit: float = 900.0) -> float | None:
    """Wait for the background compile started in ``cache`` to end; seconds since ``since``."""
    while time.perf_counter() - since < limit:
        if not list(Path(cache).glob("rovlab/numba/*/rovlab-ready/*.lock")):
            return time.perf_counter() - since
        time.sleep(0.5)
    return None


def simulate_rows(work: str, floor: float) -> None:
    """`rovlab simulate step-process-model`: the first run as a user gets it (interpreted, the
    loop compiling in the background), when that background compile is done, the runs after it,
    and a first run that compiles in the foreground (ROVLAB_JIT=compile: the compile itself)."""
    argv = ROVLAB + ["simulate", "step-process-model", "--out", str(Path(work) / "sim")]  # figures and report too
    label = "rovlab simulate step-process-model"
    with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
        env = _cold_env(cache)
        t0 = time.perf_counter()
        first = timed(argv, env, work)
        row(label + " (first: interpreted)", [first])
        done = _background_done(cache, t0)
        print(f"{'  ... its background compile (nice 10) done after':58s} "
              + (f"{done:7.2f} s" if done is not None else "  (not within 15 min)"))
        warm = [timed(argv, env, work) for _ in range(REPEAT)]
        row(label + " (after it)", warm, floor)
    with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
        row(label + " (ROVLAB_JIT=compile, first)", [timed(argv, _cold_env(cache, ROVLAB_JIT="compile"), work)])


if __name__ == "__main__":
    main()
