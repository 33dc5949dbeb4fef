"""Issue 16, part 2: the closed loop built ahead of time (rovlab.sim.prebuilt).

A run whose loop is built starts no JIT (numba's registries are never set up: no
numba.np.arraymath in the process) and writes the very same time series as the JIT loop. The
first run of a combination starts the build in the background; the arguments a build was not
made for go to the JIT loop. The processes share the suite's numba cache (so a build links the
compiled loop in seconds) and have an ahead-of-time folder of their own.
"""

from __future__ import annotations

import importlib.machinery
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rovlab.sim import prebuilt
from rovlab.sim.runner import Simulation, prepare
from rovlab.sim.scenario import load_scenario

_REPORT = ("import json, sys\nfrom rovlab.interfaces.cli import main\ncode = main({argv!r})\n"
           "print(json.dumps({{'code': code, 'jit_started': 'numba.np.arraymath' in sys.modules, "
           "'numba': 'numba' in sys.modules, 'scipy_linalg': 'scipy.linalg' in sys.modules}}), file=sys.stderr)\n")


def _arguments(name: str = "step-process-model"):
    return Simulation(prepare(load_scenario(name))).loop_arguments()


def test_a_plan_describes_every_leaf_and_the_wrapper_rebuilds_the_components():
    args = _arguments()
    leaves, shape = prebuilt.flatten(args)
    description = prebuilt.describe(shape)
    source, classes, specs = prebuilt.wrapper_source(description)
    assert len(specs) == len(leaves) and len(description) == len(args)
    assert description[0][0] == "rovlab.sim.plant:ProcessPlant"
    assert source.startswith(f"def {prebuilt.EXPORT}(k0, k1, h, a0, ") and "run_loop(k0, k1, h, " in source
    assert {c.__name__ for c in classes.values()} >= {"ProcessPlant", "Drive", "Logs", "Work"}
    # the actuators' tables are shared read-only between runs: typed as such
    act = args[4]
    assert not act.rows.flags.writeable
    assert "<f8:2:r" in specs and "<f8:1:w" in specs and "i8" in specs and "f8" in specs and "b1" in specs
    # the same combination gives the same module; another plant type another one
    assert prebuilt.module_name(description) == prebuilt.module_name(prebuilt.describe(prebuilt.flatten(_arguments())[1]))
    other = prebuilt.describe(prebuilt.flatten(_arguments("step-observer-model"))[1])
    assert prebuilt.module_name(other) != prebuilt.module_name(description)


def test_arguments_a_build_cannot_take_have_no_plan():
    args = list(_arguments())
    drive = args[7]
    strided = drive._replace(refs=np.asfortranarray(drive.refs))  # not C-contiguous
    assert prebuilt.flatten([*args[:7], strided, *args[8:]]) is None
    assert prebuilt.flatten([*args[:7], drive._replace(pset=[0] * len(drive.pset)), *args[8:]]) is None
    # and the loop still runs them (the JIT loop)
    assert prebuilt.runner([*args[:7], strided, *args[8:]]) is None


def test_disabled_in_the_suite_and_never_requested():
    assert not prebuilt.enabled()  # tests/conftest.py: ROVLAB_AOT=0
    assert prebuilt.runner(_arguments()) is None and prebuilt.request(_arguments(), "process-kf-lqg") is None


def _env(cache, aot: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("ROVLAB_AOT",)}
    # the suite's numba cache (the compiled loop is linked from it), an ahead-of-time folder of its own
    env.update(XDG_CACHE_HOME=str(cache), ROVLAB_AOT=aot, ROVLAB_JIT="compile",
               NUMBA_CACHE_DIR=os.environ["NUMBA_CACHE_DIR"])
    return env


def _simulate(out, cache, aot: str, *more: str) -> tuple[dict, str]:
    argv = ["simulate", "step-process-model", "--seed", "7", "--out", str(out), "--no-figures", *more]
    res = subprocess.run([sys.executable, "-c", _REPORT.format(argv=argv)], capture_output=True, text=True,
                         env=_env(cache, aot), timeout=900)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stderr.strip().splitlines()[-1]), res.stderr


def _wait_for_build(name: str) -> str:
    """The log of the background build of module ``name``, once it has ended."""
    ready = Path(os.environ["NUMBA_CACHE_DIR"]) / "rovlab-ready"  # the build's lock and log
    lock = ready / f"{name}.lock"
    try:
        deadline = time.time() + 600
        while lock.exists() and time.time() < deadline:
            time.sleep(0.5)
    finally:  # never leave the build running past the test
        try:
            if lock.exists():
                os.kill(int(lock.read_text().strip()), signal.SIGKILL)
        except (OSError, ValueError):
            pass
    return (ready / f"{name}.log").read_text()


def _monte_carlo(folder) -> dict:
    mc = json.loads((folder / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]
    for timing in ("wall_time_s", "vehicle_steps_per_s"):
        mc.pop(timing)
    return mc


@pytest.mark.skipif(not (shutil.which("gcc") or shutil.which("cc")), reason="building needs a C compiler")
def test_first_run_builds_the_loop_then_runs_it_without_numba(tmp_path):
    cache = tmp_path / "cache"
    status, err = _simulate(tmp_path / "jit", cache, "1")  # the JIT loop; the build starts
    assert status["code"] == 0 and status["jit_started"], err
    name = prebuilt.module_name(prebuilt.describe(prebuilt.flatten(_arguments())[1]))
    log = _wait_for_build(name)
    assert "built" in log, log
    # built: no numba at all, and the design comes from the disk (no scipy.linalg either)
    status, err = _simulate(tmp_path / "aot", cache, "1")
    assert status == {"code": 0, "jit_started": False, "numba": False, "scipy_linalg": False}, err
    status, err = _simulate(tmp_path / "jit2", cache, "0")  # ROVLAB_AOT=0: the JIT loop again
    assert status["code"] == 0 and status["jit_started"], err
    assert (tmp_path / "aot" / "timeseries.csv").read_bytes() == (tmp_path / "jit" / "timeseries.csv").read_bytes() \
        == (tmp_path / "jit2" / "timeseries.csv").read_bytes()
    m_aot = json.loads((tmp_path / "aot" / "metrics.json").read_text())
    m_jit = json.loads((tmp_path / "jit" / "metrics.json").read_text())
    assert m_aot == m_jit
    # a Monte Carlo in forked workers without numba: the same statistics as with the JIT loop
    status, err = _simulate(tmp_path / "mc-aot", cache, "1", "--runs", "5", "--workers", "2")
    assert status == {"code": 0, "jit_started": False, "numba": False, "scipy_linalg": False}, err
    status, err = _simulate(tmp_path / "mc-jit", cache, "0", "--runs", "5", "--workers", "2")
    assert status["code"] == 0 and status["jit_started"], err
    assert _monte_carlo(tmp_path / "mc-aot") == _monte_carlo(tmp_path / "mc-jit")
    assert (tmp_path / "mc-aot" / "timeseries.csv").read_bytes() == (tmp_path / "jit" / "timeseries.csv").read_bytes()


def test_a_built_loop_that_does_not_fit_starts_the_command_again_with_the_jit(tmp_path, monkeypatch):
    """The combination's marker points at a module, but not one that takes these arguments (e.g.
    a scenario whose components are made differently): the numba-free process must not run the
    loop interpreted; it says so and starts again with ROVLAB_AOT=0."""
    from rovlab import _aot

    cache = tmp_path / "cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    where = _aot.folder()
    where.mkdir(parents=True)
    (where / f"process-kf-lqg{prebuilt.MARKER}").write_text("rovlab_loop_0000000000000000")
    (where / f"rovlab_loop_0000000000000000{importlib.machinery.EXTENSION_SUFFIXES[0]}").write_bytes(b"")
    assert prebuilt.built_for("process-kf-lqg") is False  # ROVLAB_AOT=0 in the suite
    status, err = _simulate(tmp_path / "out", cache, "1")
    assert "starting again with the JIT loop (ROVLAB_AOT=0)" in err, err
    assert status["code"] == 0 and status["jit_started"], err
    assert (tmp_path / "out" / "timeseries.csv").is_file()
