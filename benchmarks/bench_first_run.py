"""First run and one-shot commands: whole processes, numba's cache empty or warm (issue 25).

rovlab has one compile path, numba.njit(cache=True), caching where numba does (or in the
NUMBA_CACHE_DIR the user sets). Every process here gets NUMBA_CACHE_DIR pointing at a fresh
temporary folder, so numba's cache of rovlab's kernels is empty: what a new user, a fresh
install or edited kernel sources give. Measured:

(a) one-shot commands (``thruster``, ``allocate``, ``vehicle``, ``design``, ...), median of
    REPEAT runs, each with its own empty cache. They must compile nothing: checked by no numba
    cache file (.nbi/.nbc) appearing in that folder. Next to them, the floor every Python tool
    pays on this machine (the interpreter, numpy, scipy.linalg, numba imports).
(b) the first ``rovlab simulate step-process-model --no-figures`` on an empty cache: wall time,
    and the "compiled ... in N s" it prints (the loop compiling in the foreground);
(c) the same command again, warm (the same cache folder), median of REPEAT.
Also ``rovlab filter`` on a short log, first run and warm (its kernels compile too).

Run: ``.venv/bin/python benchmarks/bench_first_run.py [--quick]`` (``--quick``: (a) and the
filter only, no simulate).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import os  # noqa: E402
import re  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import _timing  # noqa: E402,F401  (pins the BLAS/numba threads to 1)

PY = sys.executable
ROVLAB = [PY, "-m", "rovlab.interfaces.cli"]
REPEAT = 3
SCENARIO = "step-process-model"
COMPILED = re.compile(r"^compiled (.+) in ([0-9.]+) s$", re.MULTILINE)


def timed(argv: list[str], env: dict, cwd: str) -> tuple[float, float, str]:
    """(wall seconds, peak RSS MiB, stderr) of one whole process."""
    # peak memory by /usr/bin/time where there is one (a child's ru_maxrss also counts the parent's
    # memory it was forked from, before its exec); it writes it as the last line of stderr
    timer = ["/usr/bin/time", "-f", "%M"] if os.path.exists("/usr/bin/time") else []
    t0 = time.perf_counter()
    proc = subprocess.Popen(timer + argv, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    dt = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}):\n{err}")
    if timer:
        lines = err.rstrip().splitlines()
        return dt, float(lines[-1]) / 1024.0, "\n".join(lines[:-1])
    return dt, usage.ru_maxrss / 1024.0, err


def cache_env(cache: str) -> dict:
    """This process's environment with numba's cache in ``cache`` (and numba's JIT on)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_DISABLE_JIT"}
    env["NUMBA_CACHE_DIR"] = cache
    return env


def cache_files(cache: str) -> int:
    """numba's cache files (index .nbi, data .nbc) in ``cache``: one pair per compiled signature."""
    return sum(1 for f in Path(cache).rglob("*") if f.suffix in (".nbi", ".nbc"))


def cold(argv: list[str], work: str, repeat: int = REPEAT) -> tuple[list[tuple[float, float]], int]:
    """``repeat`` runs, each with its own empty numba cache; and the most cache files one left."""
    out, written = [], 0
    for _ in range(repeat):
        with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
            t, mem, _ = timed(argv, cache_env(cache), work)
            out.append((t, mem))
            written = max(written, cache_files(cache))
    return out, written


def row(name: str, runs: list[tuple[float, float]], floor: float | None = None, note: str = "") -> None:
    ts = sorted(t for t, _ in runs)
    mem = max(m for _, m in runs)
    spread = f"{ts[0]:.2f}-{ts[-1]:.2f} s" if len(ts) > 1 else f"{ts[0]:.2f} s"
    extra = f"  (+{statistics.median(ts) - floor:.2f} s over numpy)" if floor is not None else ""
    print(f"{name:58s} {statistics.median(ts):7.2f} s  [{spread:>13s}] {mem:7.0f} MiB{extra}{note}", flush=True)


def main() -> None:
    quick = "--quick" in sys.argv
    failures: list[str] = []
    with tempfile.TemporaryDirectory(prefix="rovlab-bench-") as work:
        print(f"whole processes, NUMBA_CACHE_DIR a fresh empty folder for each; median of {REPEAT} [range], "
              f"peak RSS; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        print(f"{'command':58s} {'median':>9s}  {'range':>15s} {'peak':>11s}")
        base = {}
        for name, code in [("python -c pass", "pass"), ("python -c 'import numpy'", "import numpy"),
                           ("... + scipy.linalg", "import numpy, scipy.linalg"),
                           ("... + numba", "import numpy, scipy.linalg, numba")]:
            runs, _ = cold([PY, "-c", code], work)
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
        print("\n(a) one-shot commands, empty cache (must compile nothing: no numba cache file written)")
        for argv in one_shot:
            runs, written = cold(ROVLAB + argv, work)
            label = "rovlab " + " ".join(argv)
            if written:
                failures.append(f"{label}: compiled ({written} numba cache files written)")
            row(label, runs, floor, f"  COMPILED: {written} cache files" if written else "")

        # rovlab filter compiles its kernels: first run (empty cache), then warm (that cache)
        import numpy as np

        log = Path(work) / "log.csv"
        t = np.arange(600) * 0.1
        lines = ["time_s,tau_Z,tau_N,z_qualisys,z_pressure,psi_qualisys"]
        lines += [f"{x:.1f},0,0,{1 + 0.1 * np.sin(x):.6f},{1.0465 + 0.1 * np.sin(x):.6f},0.5" for x in t]
        log.write_text("\n".join(lines) + "\n")
        argv = ["filter", str(log), "--out", str(Path(work) / "est.csv")]
        print("\nrovlab filter (compiles its kernels): first run on an empty cache, then warm (the same cache)")
        with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
            env = cache_env(cache)
            first = timed(ROVLAB + argv, env, work)
            warm = [timed(ROVLAB + argv, env, work) for _ in range(REPEAT)]
        label = "rovlab filter <600-row log> --out est.csv"
        row(label + " (first)", [first[:2]])
        row(label + " (warm)", [w[:2] for w in warm], floor)
        if not quick:
            failures += simulate_rows(work, floor)
        print("\nfloors (issue 25): one-shot commands <= 0.5 s with an empty cache, compiling nothing; the first "
              "simulate on an empty cache <= 30 s (quiet machine), saying it compiles and how long it took")
    if failures:
        raise SystemExit("\n".join(["FAILED:"] + failures))


def simulate_rows(work: str, floor: float) -> list[str]:
    """(b) the first `rovlab simulate step-process-model --no-figures` on an empty cache (the
    loop compiles in the foreground and says how long that took), (c) the same command warm."""
    failures = []
    argv = ROVLAB + ["simulate", SCENARIO, "--no-figures", "--out", str(Path(work) / "sim")]
    label = f"rovlab simulate {SCENARIO} --no-figures"
    print(f"\n(b) the first {label}, empty cache; (c) then warm (the same cache)")
    with tempfile.TemporaryDirectory(prefix="rovlab-cold-") as cache:
        env = cache_env(cache)
        t, mem, err = timed(argv, env, work)
        said = COMPILED.search(err)
        row(label + " (b: first)", [(t, mem)])
        if said:
            print(f"  ... of which, as it printed, \"compiled {said.group(1)} in {said.group(2)} s\" "
                  f"(the rest, {t - float(said.group(2)):.2f} s: start-up, design, the run, its files)")
        else:
            failures.append(f"{label} on an empty cache printed no 'compiled ... in N s':\n{err}")
            print("  ... it printed no 'compiled ... in N s' line")
        warm = [timed(argv, env, work) for _ in range(REPEAT)]
        recompiled = sum("compiling" in err for _, _, err in warm)
        if recompiled:
            failures.append(f"{label} warm: {recompiled} of {REPEAT} runs compiled again")
        row(label + " (c: warm)", [w[:2] for w in warm], floor,
            f"  ({recompiled} runs COMPILED again)" if recompiled else "")
    return failures


if __name__ == "__main__":
    main()
