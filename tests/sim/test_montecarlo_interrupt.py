"""Ctrl-C during a Monte Carlo (issue 28, a new user): the terminal sends SIGINT to the whole
process group, parent and pool workers alike. The command must stop the pool without a
traceback (it printed ``InvalidStateError: CANCELLED`` from the pool's thread), write the
statistics and the NEES figure of the runs that finished, say how many of how many, and exit
130; no worker may outlive it. Before the fix a Ctrl-C while the single run's figures were being
drawn left no statistics at all."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rovlab.sim.montecarlo import run_many
from rovlab.sim.scenario import load_scenario_data

RUNS = 3000  # step-observer-model: far more than finish in the moments before the signal


def _start(out: Path, stderr: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "rovlab.interfaces.cli", "simulate", "step-observer-model", "--runs", str(RUNS),
           "--workers", "2", "--out", str(out), *extra]
    with stderr.open("w") as err:
        # a session of its own: the signal goes to the group, as a terminal's Ctrl-C does
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, start_new_session=True)


def _wait_for(proc: subprocess.Popen, ready, what: str, timeout_s: float = 600.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if proc.poll() is not None:
            pytest.fail(f"the Monte Carlo ended (status {proc.returncode}) before {what}")
        if time.monotonic() > deadline:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail(f"no {what} within {timeout_s:g} s")
        time.sleep(0.05)


def _group_gone(pgid: int, timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.1)
    return False


@pytest.mark.parametrize("when", ["while the first run's figures are drawn", "after the first chunks finished"])
def test_ctrl_c_keeps_the_finished_runs_and_exits_130_without_a_traceback(tmp_path, when):
    out = tmp_path / "mc"
    err_file = tmp_path / "stderr.txt"
    drawing = when.startswith("while")
    # with figures the single run's files take seconds (on a loaded machine long enough for every
    # run to finish meanwhile): the second case goes without them, so that it meets runs under way
    proc = _start(out, err_file, *(() if drawing else ("--no-figures",)))
    try:
        if drawing:
            # the single run's files are written while the workers run; the CSV comes first, the
            # figures take seconds after it
            _wait_for(proc, lambda: (out / "timeseries.csv").exists(), "timeseries.csv")
        else:
            # the progress prints a line per tenth of the runs when stderr is a file
            _wait_for(proc, lambda: f"/{RUNS} runs" in err_file.read_text()
                      and any(int(line.split("] ")[1].split("/")[0]) > 1 for line in err_file.read_text().splitlines()
                              if f"/{RUNS} runs" in line), "a progress line past the first run")
        os.killpg(proc.pid, signal.SIGINT)
        stdout, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = err_file.read_text()
    assert proc.returncode == 130, (stdout, err)
    assert "Traceback" not in err and "InvalidStateError" not in err and "Error" not in err, err
    assert _group_gone(proc.pid), "a Monte Carlo worker outlived the command"
    mc = json.loads((out / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]
    kept = mc["runs"]
    assert 1 <= kept < RUNS and mc["runs_requested"] == RUNS and mc["interrupted"] is True
    assert mc["seeds"] == sorted(mc["seeds"]) and mc["metrics"]["rms_error.z"]["count"] == kept
    assert mc["nees"]["runs"] == kept
    if drawing:
        assert (out / "monte_carlo" / "nees.png").stat().st_size > 1000
    assert f"interrupted: {kept} of {RUNS} runs finished" in err
    assert f"Monte Carlo: {kept} of {RUNS} runs" in stdout
    top = json.loads((out / "metrics.json").read_text())
    assert top["monte_carlo"]["runs"] == kept  # the run's metrics.json carries the same block
    if drawing:
        assert "own files were being written" in err  # says what is missing, and how to get it


def test_run_many_keeps_finished_chunks_when_interrupted_in_meanwhile():
    """In process: Ctrl-C (a KeyboardInterrupt) in the caller's own work while the workers run
    returns the finished runs in seed order, each equal to the same seed run alone, and leaves no
    pool thread failing behind it."""
    import threading

    data, file = load_scenario_data("step-observer-model")
    seeds = list(range(1, 5001))  # far more than finish before the interrupt
    failures: list[BaseException] = []
    hook = threading.excepthook
    threading.excepthook = lambda a: failures.append(a.exc_value)  # type: ignore[assignment]
    try:
        def meanwhile():
            time.sleep(0.5)  # the workers finish chunks meanwhile
            raise KeyboardInterrupt

        try:
            kept = run_many(data, file, seeds, workers=2, meanwhile=meanwhile)
        except KeyboardInterrupt:  # (not let through to pytest, which would end the session)
            pytest.fail("run_many raised the interrupt instead of returning the finished runs")
        time.sleep(0.5)  # the pool's thread has noticed its workers ending
    finally:
        threading.excepthook = hook
    assert failures == []
    assert 1 <= len(kept) < len(seeds)
    got = [r["seed"] for r in kept]
    assert got == sorted(got) and got[0] == 1
    alone = run_many(data, file, got[-1:], workers=1)[0]
    assert alone["metrics"]["rms_error"] == kept[-1]["metrics"]["rms_error"]
    np.testing.assert_array_equal(alone["nees"], kept[-1]["nees"])
