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

_REPORT = ("import json, sys\nfrom rovlab.interfaces.cli import main\nsys.argv = ['rovlab', *{argv!r}]\n"
           "code = main()\n"
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


def test_arguments_a_build_cannot_take_have_no_plan(tmp_path, monkeypatch):
    monkeypatch.setenv("ROVLAB_AOT", "1")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    args = list(_arguments())
    drive = args[7]
    strided = drive._replace(refs=np.asfortranarray(drive.refs))  # not C-contiguous
    assert prebuilt.flatten([*args[:7], strided, *args[8:]]) is None
    assert prebuilt.flatten([*args[:7], drive._replace(pset=[0] * len(drive.pset)), *args[8:]]) is None  # a list
    misaligned = np.zeros(8 * len(drive.heave_force) + 1, np.uint8)[1:].view(np.float64)
    assert not misaligned.flags.aligned
    assert prebuilt.flatten([*args[:7], drive._replace(heave_force=misaligned), *args[8:]]) is None
    sub = drive.heave_force.view(np.recarray)  # an ndarray subclass: only the JIT loop knows what it makes of it
    assert prebuilt.flatten([*args[:7], drive._replace(heave_force=sub), *args[8:]]) is None
    # so the loop runs them through the JIT (no module even looked for)
    assert prebuilt.runner([*args[:7], strided, *args[8:]]) is None


def test_every_type_the_compiled_wrapper_would_read_differently_makes_another_module():
    """The wrapper trusts its arguments, so whatever numba would type differently must change
    the module: dtype (and byte order), rank, read-only, and Python bool/int/float against numpy
    scalars."""
    args = list(_arguments())
    base = prebuilt.module_name(prebuilt.describe(prebuilt.flatten(args)[1]))
    drive, plant = args[7], args[0]
    readonly = drive.refs.copy()
    readonly.flags.writeable = False
    variants = {
        "int32": drive._replace(pset=drive.pset.astype(np.int32)),
        "big-endian": drive._replace(refs=drive.refs.astype(">f8")),
        "rank": drive._replace(heave_force=drive.heave_force[:, None].copy()),
        "read-only": drive._replace(refs=readonly),
    }
    names = {base}
    for what, changed in variants.items():
        name = prebuilt.module_name(prebuilt.describe(prebuilt.flatten([*args[:7], changed, *args[8:]])[1]))
        assert name not in names, what
        names.add(name)
    assert isinstance(plant.n_sub, int) and isinstance(plant.h, float)
    for what, value in {"bool": True, "float": 10.0, "numpy int": np.int64(10), "numpy int32": np.int32(10)}.items():
        name = prebuilt.module_name(prebuilt.describe(prebuilt.flatten([plant._replace(n_sub=value), *args[1:]])[1]))
        assert name not in names, what
        names.add(name)


def test_the_runner_passes_the_leaves_in_order_to_the_module_it_finds(monkeypatch):
    monkeypatch.setenv("ROVLAB_AOT", "1")
    args = _arguments()
    leaves, shape = prebuilt.flatten(args)
    name = prebuilt.module_name(prebuilt.describe(shape))
    calls = []
    monkeypatch.setitem(prebuilt._loaded, name, lambda *a: calls.append(a) or 7)
    run = prebuilt.runner(args)
    assert run is not None and run(3, 10, 0.1) == 7
    (got,) = calls
    assert got[:3] == (3, 10, 0.1) and len(got) == 3 + len(leaves)
    assert all(a is b for a, b in zip(got[3:], leaves))
    assert got[3] is args[0][0] and got[-1] is args[-1][-1]  # depth first: the plant's first field ... work's last


def test_disabled_in_the_suite_and_never_requested(monkeypatch):
    assert not prebuilt.enabled()  # tests/conftest.py: ROVLAB_AOT=0
    assert prebuilt.runner(_arguments()) is None and prebuilt.request(_arguments(), "process-kf-lqg") is None
    from rovlab import _jit

    monkeypatch.setenv("ROVLAB_AOT", "1")
    assert prebuilt.enabled()
    monkeypatch.setattr(_jit, "interpreting", lambda: True)  # running interpreted: never the built loop either
    assert not prebuilt.enabled()


def _env(cache, aot: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("ROVLAB_AOT",)}
    # the suite's numba cache (the compiled loop is linked from it), an ahead-of-time folder of its own
    env.update(XDG_CACHE_HOME=str(cache), ROVLAB_AOT=aot, ROVLAB_JIT="compile",
               NUMBA_CACHE_DIR=os.environ["NUMBA_CACHE_DIR"])
    return env


def _simulate(out, cache, aot: str, *more: str, env: dict[str, str] | None = None) -> tuple[dict, str]:
    argv = ["simulate", "step-process-model", "--seed", "7", "--out", str(out), "--no-figures", *more]
    res = subprocess.run([sys.executable, "-c", _REPORT.format(argv=argv)], capture_output=True, text=True,
                         env={**_env(cache, aot), **(env or {})}, timeout=900)
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


def _lanes_module() -> str:
    from rovlab.sim.runner import lane_arguments, reseed

    prep = prepare(load_scenario("step-process-model"))
    args, lanes, _ = lane_arguments([reseed(prep, 0), reseed(prep, 1)])
    return prebuilt.module_name(prebuilt.describe(prebuilt.flatten((*args, lanes))[1]), "run_loop_lanes")


def _monte_carlo(folder) -> dict:
    mc = json.loads((folder / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]
    for timing in ("wall_time_s", "vehicle_steps_per_s", "runs_in_lanes"):
        mc.pop(timing)
    return mc


def _in_lanes(folder) -> int:
    return json.loads((folder / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]["runs_in_lanes"]


@pytest.mark.skipif(not (shutil.which("gcc") or shutil.which("cc")), reason="building needs a C compiler")
def test_first_run_builds_the_loop_then_runs_it_without_numba(tmp_path):
    cache = tmp_path / "cache"
    name = prebuilt.module_name(prebuilt.describe(prebuilt.flatten(_arguments())[1]))
    for earlier in (name, _lanes_module()):  # logs of an earlier run of the suite
        (Path(os.environ["NUMBA_CACHE_DIR"]) / "rovlab-ready" / f"{earlier}.log").unlink(missing_ok=True)
    status, err = _simulate(tmp_path / "jit", cache, "1")  # the JIT loop; the build starts
    assert status["code"] == 0 and status["jit_started"], err
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
    # that Monte Carlo asked for the loop over lanes when it ended; once built, the runs go
    # sixteen at a time through it (here up to four at a time: the pool's chunks get shorter
    # towards the end, and a chunk of one runs alone), without numba, with the statistics of the
    # runs one by one
    log = _wait_for_build(_lanes_module())
    assert "built" in log, log
    status, err = _simulate(tmp_path / "lanes-aot", cache, "1", "--runs", "40", "--workers", "2")
    assert status == {"code": 0, "jit_started": False, "numba": False, "scipy_linalg": False}, err
    status, err = _simulate(tmp_path / "lanes-jit", cache, "0", "--runs", "40", "--workers", "2")
    assert _monte_carlo(tmp_path / "lanes-aot") == _monte_carlo(tmp_path / "lanes-jit")
    assert _in_lanes(tmp_path / "lanes-aot") >= 20 and _in_lanes(tmp_path / "lanes-jit") == 0
    status, err = _simulate(tmp_path / "lanes-off", cache, "1", "--runs", "40", "--workers", "2",
                            env={"ROVLAB_LANES": "0"})
    assert _monte_carlo(tmp_path / "lanes-off") == _monte_carlo(tmp_path / "lanes-jit")
    assert _in_lanes(tmp_path / "lanes-off") == 0
    # a marker pointing at a module that loads but does not take the run's arguments (here: the
    # observer plant's combination pointed at the process plant's module): no interpreted loop,
    # the command says so and starts again with the JIT loop
    folder = next((cache / "rovlab" / "aot").iterdir())
    (folder / f"observer-kf-lqg{prebuilt.MARKER}").write_text(name)
    argv = ["simulate", "step-observer-model", "--out", str(tmp_path / "restart"), "--no-figures"]
    res = subprocess.run([sys.executable, "-c", _REPORT.format(argv=argv)], capture_output=True, text=True,
                         env=_env(cache, "1"), timeout=900)
    assert res.returncode == 0, res.stderr
    assert "starting again with the JIT loop (ROVLAB_AOT=0)" in res.stderr, res.stderr
    status = json.loads(res.stderr.strip().splitlines()[-1])
    assert status["code"] == 0 and status["jit_started"], res.stderr
    assert (tmp_path / "restart" / "timeseries.csv").is_file()


def test_a_module_that_does_not_load_is_removed_and_the_run_uses_the_jit(tmp_path, monkeypatch):
    """The combination's marker points at a damaged module: the process does not go without
    numba, the run takes the JIT loop, and the module and its marker are removed (so the next
    run that compiles builds it again)."""
    from rovlab import _aot

    cache = tmp_path / "cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    monkeypatch.setenv("ROVLAB_AOT", "1")
    where = _aot.folder()
    where.mkdir(parents=True)
    marker = where / f"process-kf-lqg{prebuilt.MARKER}"
    marker.write_text("rovlab_loop_0000000000000000")
    damaged = where / f"rovlab_loop_0000000000000000{importlib.machinery.EXTENSION_SUFFIXES[0]}"
    damaged.write_bytes(b"not a shared object")
    assert prebuilt.built_for("process-kf-lqg")  # the files are there ...
    status, err = _simulate(tmp_path / "out", cache, "1")
    assert status["code"] == 0 and status["jit_started"] and status["numba"], err  # ... but it did not load
    assert "starting again" not in err
    assert not damaged.exists() and not marker.exists()
    assert (tmp_path / "out" / "timeseries.csv").is_file()
