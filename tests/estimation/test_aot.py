"""Issue 16, part 3: `rovlab filter` without numba's compiler start-up (rovlab._aot).

The first `rovlab filter` of a version starts building its kernels ahead of time in the
background and says so; once built, a run loads them instead of starting numba's compiler (no
numba.np.arraymath, no scipy.linalg in the process) and writes the very same bytes as the JIT
kernels. Everything runs in fresh interpreters on a cache folder of its own.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rovlab import _aot

_REPORT = ("import json, sys\nfrom rovlab.interfaces.cli import main\ncode = main({argv!r})\n"
           "print(json.dumps({{'code': code, 'jit_started': 'numba.np.arraymath' in sys.modules, "
           "'scipy_linalg': 'scipy.linalg' in sys.modules, 'numba': 'numba' in sys.modules}}), file=sys.stderr)\n")


def _env(cache, aot: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "ROVLAB_AOT")}
    env.update(XDG_CACHE_HOME=str(cache), ROVLAB_AOT=aot)
    return env


def _filter(log, out, cache, aot: str) -> tuple[dict, str]:
    code = _REPORT.format(argv=["filter", str(log), "--out", str(out)])
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(cache, aot),
                         cwd=log.parent, timeout=900)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stderr.strip().splitlines()[-1]), res.stderr


def _log(path, rng) -> None:
    """A 30 s log at 10 Hz (uDrone's default sensors) with a motion-capture drop-out, a NaN
    input and a heading spike."""
    n = 300
    t = np.arange(n) * 0.1
    z = 1.0 + 0.1 * np.sin(t / 3)
    psi = 0.3 * np.sin(t / 5)
    cols = {"time_s": t, "tau_Z": 5.0 + rng.normal(0, 1, n), "tau_N": rng.normal(0, 0.1, n),
            "z_qualisys": z + rng.normal(0, 0.002, n), "z_pressure": z - 0.04 + rng.normal(0, 0.01, n),
            "psi_qualisys": psi + rng.normal(0, 0.002, n)}
    cols["z_qualisys"][100:160] = np.nan
    cols["psi_qualisys"][100:160] = np.nan
    cols["tau_Z"][50] = np.nan
    cols["psi_qualisys"][200] += 3.0
    lines = [",".join(cols)] + [",".join(repr(float(c[i])) for c in cols.values()) for i in range(n)]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.skipif(not (shutil.which("gcc") or shutil.which("cc")), reason="building needs a C compiler")
def test_first_run_builds_in_background_then_runs_without_jit_start_up(tmp_path, rng):
    cache = tmp_path / "cache"
    log = tmp_path / "log.csv"
    _log(log, rng)
    status, err = _filter(log, tmp_path / "jit.csv", cache, "1")  # first run: JIT, build starts
    assert status["code"] == 0 and status["jit_started"], status
    assert "ahead of time in the background" in err, err
    lock = next((cache / "rovlab" / "numba").glob("*/rovlab-ready/aot-kernels.lock"), None)
    try:
        deadline = time.time() + 600
        while lock is not None and lock.exists() and time.time() < deadline:
            time.sleep(1.0)
    finally:  # never leave the build running past the test
        try:
            if lock is not None and lock.exists():
                os.kill(int(lock.read_text().strip()), signal.SIGKILL)
        except (OSError, ValueError):
            pass
    build_log = next((cache / "rovlab" / "numba").glob("*/rovlab-ready/aot-kernels.log")).read_text()
    assert "built" in build_log, build_log
    status, err = _filter(log, tmp_path / "aot.csv", cache, "1")
    assert status == {"code": 0, "jit_started": False, "scipy_linalg": False, "numba": False}, (status, err)
    assert "background" not in err
    status, err = _filter(log, tmp_path / "aot2.csv", cache, "1")  # and it is not started again
    assert "background" not in err and not status["jit_started"]
    status, _ = _filter(log, tmp_path / "jit2.csv", cache, "0")  # ROVLAB_AOT=0: the JIT kernels
    assert status["jit_started"]
    assert (tmp_path / "aot.csv").read_bytes() == (tmp_path / "jit.csv").read_bytes() == \
        (tmp_path / "jit2.csv").read_bytes()


def test_arguments_the_kernels_were_not_built_for_go_to_the_jit(monkeypatch):
    called = []

    def built_kernel(*args):
        called.append("aot")

    def jit_kernel(*args):
        called.append("jit")

    monkeypatch.setitem(_aot._loaded, "csv_rows", built_kernel)
    F = np.zeros((4, 2))
    args = [F, F.view(np.uint64), np.zeros(2, np.int64), np.zeros((4, 0), np.int64), np.zeros(2, np.int64),
            np.arange(2), np.zeros(0, np.uint8), np.zeros(1, np.int64), np.zeros(100, np.uint8),
            np.zeros((64, 2), np.int64)]
    _aot.call("csv_rows", jit_kernel, *args)
    strided = list(args)
    strided[0] = np.zeros((4, 4))[:, ::2]  # a view the compiled wrapper would read wrongly
    _aot.call("csv_rows", jit_kernel, *strided)
    wrong = list(args)
    wrong[2] = np.zeros(2, np.int32)
    _aot.call("csv_rows", jit_kernel, *wrong)
    _aot.call("csv_rows", jit_kernel, *args[:-1])
    assert called == ["aot", "jit", "jit", "jit"]


def test_signatures_cover_every_argument():
    import importlib
    import inspect

    for name, (module, func, args, _) in _aot.KERNELS.items():
        fn = getattr(importlib.import_module(module), func)
        params = inspect.signature(getattr(fn, "py_func", fn)).parameters
        assert len(params) == len(args), name
        sig = _aot._signature(name)
        assert len(sig.args) == len(args)


@pytest.mark.parametrize("value", ["0", "off", "no"])
def test_rovlab_aot_off(monkeypatch, value):
    monkeypatch.setenv("ROVLAB_AOT", value)
    assert not _aot.enabled()
