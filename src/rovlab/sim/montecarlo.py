"""Monte Carlo: one scenario run many times with independent seeds, in parallel.

Run i uses seed ``base_seed + i``; its distributions and all its noise are drawn from that seed
alone, so ``rovlab simulate SCENARIO --seed S`` replays any run. The scenario is resolved and
designed once per process (:class:`Campaign`); each run then only redraws what its seed decides.
Runs go to a pool of worker processes (stdlib ``concurrent.futures``; the parent designs and
runs the first seed first, which compiles the loop or loads it from numba's cache, so the workers
find it in the cache) or, with ``backend="dask"``, to a Dask cluster. The pool's workers are
forked on Linux (they inherit the design and the loaded loop) and spawned elsewhere (macOS,
Windows; or ``start_method="spawn"``): a spawned worker designs once and loads
the loop from the cache. Workers return only the metrics and the NEES/NIS series, not the logs.

Ctrl-C is the parent's alone: the pool's workers ignore SIGINT (a terminal sends it to the whole
process group), and the parent, on KeyboardInterrupt, ends the pool at once and returns the runs
that had finished (fewer than the seeds given, which is how a caller tells).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import numpy as np

from rovlab.sim import metrics as mx


class Campaign:
    """What the runs of one scenario share within a process: the loaded files and the design
    (a DesignBook) and, when the scenario has no distributions, one prepared run that every seed
    reseeds (rovlab.sim.prepare.reseed: only the plant's initial bias and the draws are redone).
    A scenario with distributions is prepared afresh per seed, its values being drawn from it."""

    def __init__(self, data: Mapping[str, Any], file: str, first_seed: int) -> None:
        from rovlab.sim.designs import DesignBook
        from rovlab.sim.prepare import prepare
        from rovlab.sim.scenario import has_distributions

        self.data, self.file = data, file
        self.book = DesignBook()
        self.template = None if has_distributions(data) else prepare(data, file=file, seed=first_seed, book=self.book)

    def prepared(self, seed: int) -> Any:
        from rovlab.sim.prepare import prepare, reseed

        if self.template is None:
            return prepare(self.data, file=self.file, seed=seed, book=self.book)
        return reseed(self.template, seed)

    def run(self, seed: int) -> dict[str, Any]:
        """One run: its metrics (metrics.json of the run) and its NEES/NIS series."""
        from rovlab.sim.runner import run_prepared

        return _outcome(seed, run_prepared(self.prepared(seed)))

    def run_all(self, seeds: Sequence[int], each: Callable[[dict[str, Any]], None] | None = None
                ) -> list[dict[str, Any]]:
        """:meth:`run` of each seed, in order; ``each`` is called with every result as soon as it
        is there."""
        out: list[dict[str, Any]] = []
        for s in seeds:
            out.append(self.run(s))
            if each is not None:
                each(out[-1])
        return out


def _outcome(seed: int, result: Any) -> dict[str, Any]:
    """What a worker returns of a run: its metrics (metrics.json of the run), flattened for the
    statistics, and its NEES/NIS series."""
    from rovlab.sim.results import summarise

    metrics = summarise(result)
    # flattened here, in the worker, rather than by summarise_runs in the parent after the runs
    return {"seed": seed, "metrics": metrics, "nees": result.nees, "nis": result.nis, "flat": _flatten(metrics)}


def _chunk(data: Mapping[str, Any], file: str, seeds: Sequence[int]) -> list[dict[str, Any]]:
    """A chunk of runs where nothing is shared with the caller's process (a Dask worker)."""
    campaign = Campaign(data, file, seeds[0])
    return campaign.run_all(seeds)


_worker: Campaign | None = None  # the campaign of a pool worker process (set by _init_worker)


def _init_worker(campaign: Campaign | None, data: Mapping[str, Any], file: str, first_seed: int) -> None:
    """Pool worker start: a forked worker inherits the parent's campaign (designed, compiled loop
    loaded); a spawned one builds its own, once (the loop then loads from numba's cache).

    Ctrl-C is left to the parent (which stops the pool): a worker that took the terminal's SIGINT
    would die with a traceback between two chunks and break the pool under the parent's feet. The
    worker starts with SIGINT blocked (:func:`_sigint_blocked`), so one sent while it started is
    dropped here rather than delivered."""
    global _worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    _worker = campaign if campaign is not None else Campaign(data, file, first_seed)


def _worker_chunk(seeds: Sequence[int]) -> list[dict[str, Any]]:
    if _worker is None:
        raise RuntimeError("a Monte Carlo pool worker was started without its campaign (_init_worker)")
    return _worker.run_all(seeds)


def run_many(data: Mapping[str, Any], file: str, seeds: Sequence[int], *, workers: int | None = None,
             backend: str = "processes", scheduler: str | None = None,
             progress: Callable[[int, int], None] | None = None,
             meanwhile: Callable[[], None] | None = None, start_method: str | None = None) -> list[dict[str, Any]]:
    """Run the scenario once per seed; results in seed order. ``meanwhile`` is the caller's own
    work (e.g. writing the files of its single run), done in this process while the workers run
    (before the runs when there are no workers); an error in it stops the runs and is raised.
    ``start_method``: how the pool starts its workers (multiprocessing's "fork", "spawn" or
    "forkserver"; default: "fork" on Linux, the platform's default elsewhere).

    Ctrl-C (KeyboardInterrupt) once the runs have started ends them at once, ``meanwhile`` too if
    it was under way, and returns the runs that had finished, in seed order: fewer than
    ``seeds``. Before any run has finished (or in ``meanwhile`` without workers) it propagates."""
    seeds = list(seeds)
    workers = max(1, workers or os.cpu_count() or 1)
    if backend == "dask":
        return _run_dask(data, file, seeds, scheduler, progress, meanwhile)
    if backend != "processes":
        raise ValueError(f"unknown Monte Carlo backend {backend!r}; expected 'processes' or 'dask'")
    n = len(seeds)
    if n == 0 or workers == 1 or n == 1:
        if meanwhile is not None:
            meanwhile()
        if n == 0:
            return []
        meanwhile = None
    campaign = Campaign(data, file, seeds[0])  # the design, once; forked workers inherit it
    out: list[dict[str, Any]] = []
    if workers == 1 or n == 1:
        def keep(result: dict[str, Any]) -> None:
            out.append(result)
            if progress:
                progress(len(out), n)

        try:
            campaign.run_all(seeds, keep)
        except KeyboardInterrupt:  # keep what finished, as the parallel path does
            if not out:
                raise
        return out
    # the first run here: it loads the compiled loop before the fork, so no worker pays for it
    results: dict[int, dict[str, Any]] = {}
    first = campaign.run(seeds[0])
    results[seeds[0]] = first
    rest = seeds[1:]
    chunks = _guided_chunks(rest, workers)
    if start_method is None:  # fork on Linux only: macOS has it, but forking after LLVM and its frameworks
        start_method = "fork" if sys.platform.startswith("linux") else None  # loaded is unsafe (Python's own default)
    ctx = mp.get_context(start_method)
    fork = ctx.get_start_method() == "fork"
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=ctx, initializer=_init_worker,
                               initargs=(campaign if fork else None, data, file, seeds[0]))
    futures: list[Any] = []
    try:
        with _sigint_blocked():  # the workers are started by the submits: with SIGINT blocked (_init_worker)
            futures = [pool.submit(_worker_chunk, c) for c in chunks]
        if meanwhile is not None:  # the workers are busy: the caller's own work now
            try:
                meanwhile()
            except KeyboardInterrupt:
                raise
            except BaseException:  # its error ends the command: stop the workers at once
                _stop(pool)
                raise
        if progress:
            progress(len(results), n)
        for fut in as_completed(futures):
            for r in fut.result():
                results[r["seed"]] = r
            if progress:
                progress(len(results), n)
    except KeyboardInterrupt:
        # keep what finished (chunks done but not yet read too); the caller writes their statistics
        for fut in futures:
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                for r in fut.result():
                    results[r["seed"]] = r
        _stop(pool)
        return [results[s] for s in seeds if s in results]
    pool.shutdown()
    return [results[s] for s in seeds]


@contextlib.contextmanager
def _sigint_blocked() -> Iterator[None]:
    """SIGINT held back in this thread (POSIX; elsewhere nothing): the processes it starts begin
    with it blocked, and a Ctrl-C in the meantime arrives when the block ends."""
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _stop(pool: ProcessPoolExecutor, *, timeout_s: float = 10.0) -> None:
    """End the pool now: what has not started is dropped and the workers are ended (a chunk under
    way would otherwise run to its end before the interpreter may exit).

    The pool cancels its own pending futures (shutdown with cancel_futures): a future cancelled
    from outside while the pool still holds it makes the pool's thread fail on the ended workers
    (concurrent.futures sets BrokenProcessPool on every future it holds; on a cancelled one that is
    InvalidStateError: CANCELLED, printed as a traceback)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public way before Python 3.14
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    for proc in processes:
        proc.join(timeout_s)
    if manager is not None:
        manager.join(timeout_s)


def _guided_chunks(seeds: Sequence[int], workers: int, *, largest: int = 96, smallest: int = 1) -> list[list[int]]:
    """Chunks of seeds for the pool, each a share of what is left (guided scheduling): long chunks
    first (few round trips), short ones at the end, so that no worker idles while another finishes
    a long last chunk; the progress bar moves throughout."""
    out = []
    i, n = 0, len(seeds)
    while i < n:
        size = max(smallest, min(largest, (n - i) // (workers * 4)))
        out.append(list(seeds[i:i + size]))
        i += size
    return out


def dask_available() -> bool:
    """Whether the Dask backend can run here (the optional extra rovlab[dask])."""
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _run_dask(data, file, seeds, scheduler, progress, meanwhile=None):
    """Runs as Dask tasks, in chunks like the process pool: on the scheduler at ``scheduler``
    (e.g. tcp://host:8786) or on a local cluster of one single-threaded worker process per core."""
    if not dask_available():
        raise RuntimeError("the Dask backend needs dask[distributed]: pip install 'rovlab[dask]'")
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler:
        client = Client(scheduler, timeout="30s")
    else:
        cluster = LocalCluster(n_workers=os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None)
        client = Client(cluster)
    n = len(seeds)
    out: dict[int, dict[str, Any]] = {}
    try:
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        size = max(1, min(48, n // (workers * 4) or 1))
        chunks = [seeds[i:i + size] for i in range(0, n, size)]
        futures = [client.submit(_chunk, data, file, c, pure=False) for c in chunks]
        try:
            if meanwhile is not None:
                try:
                    meanwhile()
                except KeyboardInterrupt:
                    raise
                except BaseException:
                    client.cancel(futures)
                    raise
            for fut in as_completed(futures):
                for r in fut.result():
                    out[r["seed"]] = r
                if progress:
                    progress(len(out), n)
        except KeyboardInterrupt:  # keep what finished, as the process pool does
            for fut in futures:
                if fut.status == "finished":
                    for r in fut.result():
                        out[r["seed"]] = r
            client.cancel(futures)
        return [out[s] for s in seeds if s in out]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def summarise_runs(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Spread of every numeric metric over the runs, and the Monte Carlo NEES/NIS consistency."""
    flat = [r["flat"] if "flat" in r else _flatten(r["metrics"]) for r in runs]
    keys = sorted({k for f in flat for k in f})
    stats: dict[str, Any] = {}
    for k in keys:
        vals = np.array([f.get(k, np.nan) for f in flat], dtype=float)
        ok = vals[np.isfinite(vals)]
        if ok.size == 0:
            stats[k] = {"count": 0}
            continue
        stats[k] = {"count": int(ok.size), "mean": float(ok.mean()), "std": float(ok.std(ddof=1)) if ok.size > 1 else 0.0,
                    "min": float(ok.min()), "p5": float(np.percentile(ok, 5)), "median": float(np.median(ok)),
                    "p95": float(np.percentile(ok, 95)), "max": float(ok.max())}
    out: dict[str, Any] = {"runs": len(runs), "seeds": [int(r["seed"]) for r in runs], "metrics": stats}
    note = mx.consistency_note(str(runs[0]["metrics"].get("plant", ""))) if runs else None
    if note:  # NEES/NIS outside their bounds on a plant that is not the filter's model is no fault
        out["consistency_note"] = note
    nees = np.array([r["nees"] for r in runs], dtype=float)
    if nees.size:
        dof = int(runs[0]["metrics"]["nees"]["dof"])
        out["nees"] = mx.consistency(nees, dof)
    nis = np.array([r["nis"] for r in runs], dtype=float)
    if nis.size:
        out["nis"] = mx.consistency(nis, 1)
    losses = [r["metrics"].get("sensor_losses") for r in runs if r["metrics"].get("sensor_losses")]
    if losses:  # false alarms: sensors declared lost outside the scenario's drop-out windows
        reasons: dict[str, int] = {}
        for x in losses:
            for e in x["events"]:
                if not e["expected"]:
                    reasons[e["reason"]] = reasons.get(e["reason"], 0) + 1
        out["sensor_losses"] = {"runs_with_false_alarms": sum(1 for x in losses if x["unexpected"]),
                                "false_alarms": sum(x["unexpected"] for x in losses),
                                "false_alarms_by_reason": dict(sorted(reasons.items()))}
    return out


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """The numbers of a run's metrics by dotted key ("rms_error.z", "steps[0].overshoot")."""
    out: dict[str, float] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        t = type(v)
        if t is float or t is int or t is bool:  # most entries: the exact types first (cheapest)
            out[key] = float(v)
        elif t is dict:
            out.update(_flatten(v, key + "."))
        elif isinstance(v, (int, float)):  # numpy's floats and the like
            out[key] = float(v)
        elif isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        elif k == "events":
            continue  # per-event records (sensor losses) are summarised apart
        elif isinstance(v, list) and v and all(isinstance(x, Mapping) for x in v):
            for i, x in enumerate(v):
                out.update(_flatten(x, f"{key}[{i}]."))
    return out


class Progress:
    """A one-line progress bar on stderr (no dependency)."""

    def __init__(self, label: str, stream=sys.stderr) -> None:
        self.label = label
        self.stream = stream
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        width = 30
        fill = int(width * done / max(total, 1))
        dt = time.perf_counter() - self.t0
        line = f"{self.label} [{'#' * fill}{'.' * (width - fill)}] {done}/{total} runs  {dt:5.1f} s"
        if getattr(self.stream, "isatty", lambda: False)():
            self.stream.write("\r" + line + ("\n" if done >= total else ""))
        else:  # a log file: a line per tenth, not a carriage-return animation
            tenth = int(10 * done / max(total, 1))
            if tenth != getattr(self, "_last", -1) or done >= total:
                self._last = tenth
                self.stream.write(line + "\n")
        self.stream.flush()
