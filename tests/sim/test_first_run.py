"""The first run of a loop (issue 16, part 1): interpreted with the same numbers as compiled,
the compile in the background and said on the terminal, the cache markers."""

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

from rovlab import _jit
from rovlab.interfaces.cli_sim import first_run_tier
from rovlab.sim.runner import Simulation, first_rows, prepare
from rovlab.sim.scenario import load_scenario_data

# Every combination of components that a packaged scenario runs, with a scenario that exercises
# it (drop-outs and dead reckoning in the DP one, a truth event in the heave one).
COMBINATIONS = [
    ("step-process-model", None),  # process-kf-lqg
    ("step-observer-model", None),  # observer-kf-lqg
    ("dp-mocap-dropout", None),  # process-ekf-dp
    ("heave-buoyancy-step", "mrac"),  # process-kf-mrac
]

# Runs a scenario with numba's decorators returning the plain functions (what `rovlab simulate`
# does for a first run) and saves the logs.
_INTERPRETED = """
import os, sys
os.environ["NUMBA_DISABLE_JIT"] = "1"
import numpy as np
from rovlab import _jit
from rovlab.sim.runner import Simulation, prepare
from rovlab.sim.scenario import load_scenario_data
assert _jit.interpreting()
data, file = load_scenario_data(sys.argv[1])
if sys.argv[2] != "-":
    data["controller"] = sys.argv[2]
prep = prepare(data, file=file)
logs = Simulation(prep).advance(prep.drive)
np.savez(sys.argv[3], **logs._asdict())
"""


def _prepared(name: str, controller: str | None):
    data, file = load_scenario_data(name)
    if controller:
        data["controller"] = controller
    return prepare(data, file=file)


@pytest.mark.parametrize(("name", "controller"), COMBINATIONS)
def test_the_interpreted_loop_gives_the_compiled_loops_numbers(tmp_path, name, controller):
    out = tmp_path / "interpreted.npz"
    subprocess.run([sys.executable, "-c", _INTERPRETED, name, controller or "-", str(out)], check=True, timeout=300)
    interpreted = np.load(out)
    prep = _prepared(name, controller)
    compiled = Simulation(prep).advance(prep.drive)._asdict()
    for field, values in compiled.items():
        if values.dtype.kind == "f":
            np.testing.assert_allclose(interpreted[field], values, rtol=1e-9, atol=1e-12, equal_nan=True,
                                       err_msg=f"{name}: logs.{field}")
        else:
            np.testing.assert_array_equal(interpreted[field], values, err_msg=f"{name}: logs.{field}")


def test_short_work_is_interpreted_long_work_compiles_and_a_cached_loop_is_used():
    assert first_run_tier("auto", False, 601, 1) == "interpret"  # one 60 s case study
    assert first_run_tier("auto", False, 1401, 1) == "interpret"  # dp-square, 140 s
    assert first_run_tier("auto", False, 0, 1) == "interpret"  # a live (paced) simulation
    assert first_run_tier("auto", False, 1000 * 601, 2) == "compile"  # Monte Carlo 1000 x 60 s
    assert first_run_tier("auto", True, 1000 * 601, 2) == "cached"
    assert first_run_tier("auto", True, 601, 1) == "cached"
    assert first_run_tier("compile", False, 601, 1) == "compile"
    assert first_run_tier("interpret", True, 10**7, 1) == "interpret"


def test_a_compiled_run_leaves_a_marker_with_its_compile_time(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))  # markers only: numba keeps its own folder
    prep = _prepared("step-observer-model", None)
    assert prep.loop_key == "observer-kf-lqg"
    assert not _jit.is_compiled(prep.loop_key)
    Simulation(prep).advance(first_rows(prep.drive, 3))
    assert _jit.is_compiled(prep.loop_key)
    marker = json.loads((tmp_path / "rovlab-ready" / "observer-kf-lqg.json").read_text())
    assert marker["key"] == "observer-kf-lqg" and marker["compile_seconds"] >= 0


def test_the_mode_is_checked(monkeypatch):
    monkeypatch.setenv("ROVLAB_JIT", "fast")
    with pytest.raises(ValueError, match="ROVLAB_JIT='fast': expected one of auto, compile, interpret"):
        _jit.jit_mode()
    monkeypatch.setenv("ROVLAB_JIT", " Compile ")
    assert _jit.jit_mode() == "compile"


def _cli(args, cache: Path, **env) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT", "ROVLAB_JIT")}
    environ.update(XDG_CACHE_HOME=str(cache), **env)
    return subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", *args], env=environ, capture_output=True,
                          text=True, timeout=300)


def _stop_background(cache: Path) -> None:
    for lock in cache.glob("rovlab/numba/*/rovlab-ready/*.lock"):
        try:
            os.killpg(int(lock.read_text()), signal.SIGKILL)  # its own session: the whole group
        except (ValueError, ProcessLookupError, PermissionError):
            pass


def test_a_first_run_in_an_empty_cache_is_interpreted_and_compiles_in_the_background(tmp_path):
    cache = tmp_path / "cache"
    try:
        proc = _cli(["simulate", "step-observer-model", "--no-figures", "--out", str(tmp_path / "run")], cache)
        assert proc.returncode == 0, proc.stderr
        assert "first run of the kf + lqg loop (observer plant) here: it runs interpreted this time" in proc.stderr
        assert "it compiles in the background for the next runs" in proc.stderr
        ready = next(cache.glob("rovlab/numba/*/rovlab-ready"))
        lock = ready / "observer-kf-lqg.lock"
        assert (ready / "observer-kf-lqg.log").exists()
        if lock.exists():  # still compiling (it takes a minute): a second start joins it
            pid = lock.read_text()
            env = dict(os.environ, NUMBA_CACHE_DIR=str(ready.parent))
            again = subprocess.run([sys.executable, "-c", "from rovlab import _jit; import sys; "
                                    "print(_jit.compile_in_background('observer-kf-lqg', 'step-observer-model'))"],
                                   env=env, capture_output=True, text=True, timeout=60)
            assert again.stdout.strip() == str(ready / "observer-kf-lqg.log")
            assert lock.read_text() == pid
        # the interpreted run's numbers are the compiled loop's
        metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
        from rovlab.sim.runner import run_prepared, summarise

        expected = json.loads(json.dumps(summarise(run_prepared(_prepared("step-observer-model", None))),
                                         default=float))
        assert metrics["rms_error"] == pytest.approx(expected["rms_error"], rel=1e-9)
        assert metrics["nees"]["mean"] == pytest.approx(expected["nees"]["mean"], rel=1e-9)
    finally:
        _stop_background(cache)


def test_a_long_first_run_says_it_compiles(tmp_path):
    cache = tmp_path / "cache"
    # Monte Carlo is long work: it compiles in the foreground, after saying so (the process stops
    # right after deciding, before compiling anything)
    code = ("import sys; from rovlab.interfaces.cli_sim import first_run; "
            "from rovlab.sim.scenario import load_scenario_data; "
            "first_run(*load_scenario_data('step-observer-model'), 'step-observer-model', 5000, 2); "
            "import rovlab._jit as j; print('interpreting' if j.interpreting() else 'compiling')")
    environ = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT", "ROVLAB_JIT")}
    proc = subprocess.run([sys.executable, "-c", code], env=dict(environ, XDG_CACHE_HOME=str(cache)),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "compiling"
    assert ("compiling the kf + lqg loop (observer plant) once (a minute or more on a 2-core machine); "
            "later runs load it from the cache") in proc.stderr
    assert not list(cache.glob("rovlab/numba/*/rovlab-ready/*.lock"))


def test_the_hmi_starts_at_once_in_an_empty_cache(tmp_path):
    import re
    import urllib.request

    cache = tmp_path / "cache"
    environ = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT", "ROVLAB_JIT")}
    environ.update(XDG_CACHE_HOME=str(cache), PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "rovlab.interfaces.cli", "hmi", "--port", "0", "--speed", "10",
                             "--out", str(tmp_path / "hmi")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=environ)
    try:
        url = None
        while url is None:
            line = proc.stdout.readline()
            if not line:
                break
            m = re.search(r"http://127\.0\.0\.1:\d+/", line)
            url = m.group(0) if m else None
        assert url, proc.stderr.read()
        # it runs from the start (a hang guard, not a timing bound: compiling would take minutes)
        state = {}
        for _ in range(120 * 4):
            with urllib.request.urlopen(url + "api/state", timeout=10) as r:
                state = json.loads(r.read())
            if state["time_s"] >= 5.0:
                break
            time.sleep(0.25)
        assert state["time_s"] >= 5.0, state
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        _stop_background(cache)
    assert proc.returncode == 0, err
    assert "first run of the kf + lqg loop (process plant) here: it runs interpreted" in err
    log = next((tmp_path / "hmi").glob("session-*.csv"))
    assert log.read_text().count("\n") > 50
