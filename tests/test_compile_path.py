"""One compile path (rovlab._jit): numba.njit(cache=True) through numba's public API, and nothing of
the user's process changed by importing or calling rovlab.

What a user of a notebook, a ROS 2 container or a read-only install relies on:
* importing rovlab and running a simulation leave their environment variables and numba's
  settings as they were (their NUMBA_CACHE_DIR, numba.config.DISABLE_JIT, their cached kernels),
  and patch nothing of numba's;
* no writable cache: one line, and the command works (compiled in memory);
* two processes compiling into an empty cache at once both work;
* the cache is invalidated by kernel sources and numpy/numba/scipy versions, nothing else;
* a Monte Carlo with spawned workers gives the numbers of the forked one, and no process is
  left behind.

Each check that needs a fresh interpreter runs one (the test process has long imported numba).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

import rovlab
from rovlab import _jit

ROOT = Path(rovlab.__file__).resolve().parent


def _python(code: str, cwd: Path, env: dict[str, str] | None = None, timeout: float = 600
            ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, timeout=timeout,
                          env={**os.environ, **(env or {})})


def test_import_and_a_simulation_leave_the_users_process_as_it_was(tmp_path):
    """The notebook case: a user's own cached kernel, their NUMBA_CACHE_DIR and numba's settings,
    then rovlab's CLI called in-process (a scenario run through the compiled loop)."""
    code = f"""
import json, os, sys
import numba
from numba.core import config, ir_utils
before_env = dict(os.environ)
before = (config.DISABLE_JIT, config.CACHE_DIR, ir_utils.find_potential_aliases, ir_utils.alias_func_extensions.copy())

@numba.njit(cache=True)
def users_kernel(x):
    return 2.0 * x

users_kernel(1.0)
files = [os.path.join(root, p) for root, _, names in os.walk({str(tmp_path / 'mine')!r}) for p in names
         if 'users_kernel' in p]

import rovlab
from rovlab.interfaces.cli import main
code = main(["simulate", "step-observer-model", "--out", {str(tmp_path / 'out')!r}, "--no-figures"])
after = (config.DISABLE_JIT, config.CACHE_DIR, ir_utils.find_potential_aliases, ir_utils.alias_func_extensions.copy())
print(json.dumps({{"code": code, "env_same": dict(os.environ) == before_env, "numba_same": after == before,
                  "users_kernel": users_kernel(2.0), "disable_jit": config.DISABLE_JIT,
                  "users_files_kept": all(os.path.exists(f) for f in files) and bool(files)}}))
"""
    script = tmp_path / "users_script.py"  # numba caches functions of files, not of `python -c`
    script.write_text(code)
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "mine")})
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out == {"code": 0, "env_same": True, "numba_same": True, "users_kernel": 4.0, "disable_jit": 0,
                   "users_files_kept": True}, (out, res.stderr)


def test_importing_rovlab_sets_nothing(tmp_path):
    code = """
import json, os, sys
env = dict(os.environ)
import rovlab, rovlab.sim.runner, rovlab.estimation.kalman
import numba
from numba.core import config
print(json.dumps({"env_same": dict(os.environ) == env, "cache_dir": config.CACHE_DIR,
                  "disable_jit": config.DISABLE_JIT}))
"""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == {"env_same": True, "cache_dir": "", "disable_jit": 0}


def test_a_users_numba_disable_jit_is_honoured(tmp_path):
    """NUMBA_DISABLE_JIT=1 set by the user: every kernel runs as plain Python, the same numbers
    (rovlab neither compiles nor says it does)."""
    code = """
import json
from rovlab.sim.prepare import prepare
from rovlab.sim.runner import run_prepared
from rovlab.sim.scenario import load_scenario
import numba
r = run_prepared(prepare(load_scenario("step-observer-model", seed=3)))
print(json.dumps({"dispatcher": hasattr(__import__("rovlab.sim.loop", fromlist=["x"]).run_loop, "py_func"),
                  "z": float(r.columns["est_z"][-1])}))
"""
    res = _python(code, tmp_path, {"NUMBA_DISABLE_JIT": "1"})
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    from rovlab.sim.prepare import prepare
    from rovlab.sim.runner import run_prepared
    from rovlab.sim.scenario import load_scenario

    compiled = run_prepared(prepare(load_scenario("step-observer-model", seed=3)))
    assert out["dispatcher"] is False and "compil" not in res.stderr
    assert out["z"] == float(compiled.columns["est_z"][-1])


def _unwritable_install(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A copy of rovlab where numba finds no place to cache (works as root too): a file where each
    package folder's __pycache__ would go, and a home and cache folder under a plain file."""
    site = tmp_path / "site"
    shutil.copytree(ROOT, site / "rovlab", ignore=shutil.ignore_patterns("__pycache__"))
    for folder in [site / "rovlab", *(p for p in (site / "rovlab").rglob("*") if p.is_dir())]:
        (folder / "__pycache__").write_text("not a folder")
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, so nothing can be created below it")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(PYTHONPATH=str(site), HOME=str(blocker / "home"), XDG_CACHE_HOME=str(blocker / "cache"),
               PYTHONDONTWRITEBYTECODE="1")
    return site, env


def test_without_a_writable_cache_the_kernels_compile_in_memory_with_one_line(tmp_path):
    site, env = _unwritable_install(tmp_path)
    code = """
import json, sys
import rovlab
assert rovlab.__file__.startswith(sys.argv[1]), rovlab.__file__
from rovlab import _jit
from rovlab.interfaces.cli import main
code = main(["filter", sys.argv[2], "--out", sys.argv[3]])
print(json.dumps({"code": code, "in_memory": len(_jit.compiled_in_memory())}))
"""
    log = tmp_path / "log.csv"
    from rovlab.interfaces.cli import main

    assert main(["simulate", "step-observer-model", "--out", str(tmp_path / "run"), "--no-figures"]) == 0
    shutil.copy(tmp_path / "run" / "timeseries.csv", log)
    res = subprocess.run([sys.executable, "-c", code, str(site), str(log), str(tmp_path / "est.csv")],
                         capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["code"] == 0 and out["in_memory"] > 0
    assert res.stderr.count("compiled in memory for this process") == 1, res.stderr
    assert "Traceback" not in res.stderr and (tmp_path / "est.csv").stat().st_size > 0


def test_the_cache_key_is_the_kernel_sources_and_the_versions(tmp_path, monkeypatch):
    """Editing a file that holds no kernel keeps every compiled kernel; editing a kernel module (even
    one that is only inlined into others) or another numpy, numba or scipy invalidates them."""
    copy = tmp_path / "rovlab"
    shutil.copytree(ROOT, copy, ignore=shutil.ignore_patterns("__pycache__"))

    def digest() -> str:
        monkeypatch.setattr(_jit, "__file__", str(copy / "_jit.py"))
        monkeypatch.setattr(_jit, "_digest", [])
        return _jit.kernel_digest()

    base = digest()
    (copy / "interfaces" / "cli_sim.py").write_text((copy / "interfaces" / "cli_sim.py").read_text() + "\n# edited\n")
    (copy / "README.txt").write_text("not a kernel")
    assert digest() == base
    kin = copy / "models" / "kinetics.py"
    kin.write_text(kin.read_text().replace("h6 = h / 6.0", "h6 = h * (1.0 / 6.0)"))
    assert digest() != base
    kin.write_text((ROOT / "models" / "kinetics.py").read_text())
    assert digest() == base
    import numpy

    monkeypatch.setattr(numpy, "__version__", "0.0.0")
    assert digest() != base


def test_a_stale_stamp_removes_rovlabs_cache_files_and_nothing_else(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    folder.mkdir()
    ours = ["loop.run_loop-216.py311.nbi", "loop.run_loop-216.py311.1.nbc", "kinetics.rhs-161.py311.nbi"]
    theirs = ["mymodule.kernel-3.py311.nbi", "notes.txt", "loop.cpython-311.pyc"]
    for name in ours + theirs:
        (folder / name).write_bytes(b"x")
    (folder / _jit.STAMP).write_text("an older digest\n")
    monkeypatch.setattr(_jit, "_checked", set())
    _jit._check_stamp(str(folder))
    assert sorted(p.name for p in folder.iterdir()) == sorted([*theirs, _jit.STAMP])
    assert (folder / _jit.STAMP).read_text().strip() == _jit.kernel_digest()
    # the stamp up to date: nothing removed
    for name in ours:
        (folder / name).write_bytes(b"x")
    monkeypatch.setattr(_jit, "_checked", set())
    _jit._check_stamp(str(folder))
    assert all((folder / name).exists() for name in ours)


# Modules that kernel modules import from but numba never compiles (design code, file readers, the
# design summaries, the decorator itself): their edits cannot change a compiled kernel.
PYTHON_ONLY = {"_jit.py", "allocation/capacity.py", "allocation/geometry.py", "control/lqr.py",
               "estimation/filtering.py", "estimation/model.py", "estimation/streaming.py", "models/discretise.py",
               "params/design.py", "params/validate.py", "params/vehicle.py", "core/summary.py", "core/units.py"}


def test_what_kernels_are_compiled_from_is_in_the_cache_key():
    """numba compiles the module-level constants a kernel reads into it (estimation/layout.py's
    column indices, allocation/lexicographic.py's tolerances): every rovlab module a kernel
    module imports names from is a kernel module itself, or named above as plain Python."""
    import ast

    listed = set(_jit.KERNEL_MODULES)
    missing = {}
    for name in listed:
        for node in ast.walk(ast.parse((ROOT / name).read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("rovlab."):
                base = node.module[len("rovlab."):].replace(".", "/")
                targets = [f"{base}/{a.name}.py" for a in node.names if (ROOT / base / f"{a.name}.py").is_file()] \
                    or [f"{base}.py"]
                for t in targets:
                    if t not in listed and t not in PYTHON_ONLY:
                        missing.setdefault(t, set()).add(name)
    assert not missing, f"add to rovlab._jit.KERNEL_MODULES (or to PYTHON_ONLY here, if numba never compiles it): {missing}"


def test_numbas_undocumented_nrt_option_is_used_in_one_place():
    """_nrt (numba's reference counting) goes through rovlab._jit.WITHOUT_NRT / WITH_NRT only, so
    a numba without it needs one edit (the docstring there)."""
    import re

    for path in ROOT.rglob("*.py"):
        if path.name != "_jit.py":
            assert not re.search(r"\b_nrt\s*=", path.read_text(encoding="utf-8")), path.relative_to(ROOT)


def test_every_module_with_kernels_is_in_the_cache_key():
    import re

    listed = set(_jit.KERNEL_MODULES)
    found = set()
    kernel_import = re.compile(r"^\s*(from rovlab\._jit import .*\b(njit|LazyKernels)\b|from numba\.extending import)", re.M)
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT).as_posix()
        if kernel_import.search(path.read_text(encoding="utf-8")):
            found.add(rel)
        if rel in ("models/thruster_kernels.py", "allocation/kernels.py"):  # plain kernels, compiled by LazyKernels
            found.add(rel)
    assert found <= listed, f"kernel modules missing from rovlab._jit.KERNEL_MODULES: {sorted(found - listed)}"
    assert all((ROOT / name).is_file() for name in listed)


def test_nothing_of_the_old_machinery_is_left():
    """No self-restart, no background process, no platform-only call, no patch of numba."""
    banned = ("os.execv", "os.nice", "os.kill(", "start_new_session", "numba.pycc", "NUMBA_CACHE_DIR\"] =",
              "reload_config", "find_potential_aliases", "alias_func_extensions", "os.environ[\"NUMBA")
    for path in ROOT.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        for word in banned:
            assert word not in text, f"{path.relative_to(ROOT)} uses {word}"


def test_two_processes_compile_into_an_empty_cache_at_once(tmp_path):
    """Both work, both say they compile and how long it took; a third process loads the loop."""
    cache = tmp_path / "cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    cmd = [sys.executable, "-m", "rovlab.interfaces.cli", "simulate", "step-observer-model", "--no-figures"]
    procs = [subprocess.Popen([*cmd, "--out", str(tmp_path / f"out{i}")], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path) for i in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (_out, err) in zip(procs, outs):
        assert p.returncode == 0, err
        assert "compiling the kf + lqg loop (observer plant)" in err and "compiled the kf + lqg loop" in err, err
    a = (tmp_path / "out0" / "timeseries.csv").read_bytes()
    assert a == (tmp_path / "out1" / "timeseries.csv").read_bytes()
    third = subprocess.run([*cmd, "--out", str(tmp_path / "out2")], capture_output=True, text=True, env=env,
                           cwd=tmp_path, timeout=600)
    assert third.returncode == 0 and "compil" not in third.stderr, third.stderr
    assert (tmp_path / "out2" / "timeseries.csv").read_bytes() == a


def test_rovlab_compile_prepares_the_cache_and_refuses_bad_arguments(tmp_path, capsys):
    from rovlab.interfaces.cli import main

    assert main(["compile", "step-observer-model", "dropout"]) == 0
    out = capsys.readouterr().out
    assert "observer-kf-lqg" in out and "process-kf-lqg" in out and "2 loops ready" in out
    assert main(["compile", "step-observer-model"]) == 0
    assert "cached" in capsys.readouterr().out
    assert main(["compile"]) == 2
    assert main(["compile", "no-such-scenario"]) == 2


def test_a_monte_carlo_with_spawned_workers_equals_the_forked_one_and_leaves_no_process():
    import multiprocessing as mp

    from rovlab.sim.montecarlo import run_many, summarise_runs
    from rovlab.sim.scenario import load_scenario_data

    data, file = load_scenario_data("step-observer-model")
    seeds = list(range(40, 46))
    spawned = run_many(data, file, seeds, workers=2, start_method="spawn")
    forked = run_many(data, file, seeds, workers=2) if "fork" in mp.get_all_start_methods() else None
    serial = run_many(data, file, seeds, workers=1)
    assert [r["seed"] for r in spawned] == seeds
    for other in filter(None, (forked, serial)):
        for a, b in zip(spawned, other):
            np.testing.assert_array_equal(a["nees"], b["nees"])
        assert summarise_runs(spawned)["metrics"] == summarise_runs(other)["metrics"]
    assert mp.active_children() == []


def test_a_loop_that_ran_elsewhere_is_known_as_cached_and_one_whose_source_changed_is_not(tmp_path):
    """rovlab compare (or a Monte Carlo, or the HMI) compiles a loop without saying how long: the
    next command must not announce a compile that will not happen. And numba recompiles the loop
    when its own file is touched: then the announcement must come back."""
    code = """
import json, os, sys
from rovlab.interfaces.cli import main
from rovlab.sim import compile as c, loop
assert c.needs_compiling("process-kf-mrac")
assert main(["compare", "heave-payload", "--controllers", "mrac", "--runs", "1", "--out", sys.argv[1], "--no-figure"]) == 0
after_compare = c.needs_compiling("process-kf-mrac")
real = c._sources
st = os.stat(loop.__file__)
c._sources = lambda: {**real(), "loop_file": [st.st_mtime + 1.0, st.st_size]}  # as if loop.py was touched
print(json.dumps({"after_compare": after_compare, "after_touch": c.needs_compiling("process-kf-mrac")}))
"""
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path / "cmp")], capture_output=True, text=True,
                         timeout=600, cwd=tmp_path, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout.strip().splitlines()[-1]) == {"after_compare": False, "after_touch": True}


def test_rovlab_compile_prepares_a_nodes_control_step_and_the_realtime_plant(capsys):
    """Issue 28: the first start of a node or bridge compiled for minutes with no word after the
    first line. `rovlab compile --node --realtime` prepares both ahead, for the bridge's defaults or
    a named vehicle and configuration."""
    from rovlab.interfaces.cli import main

    assert main(["compile", "--node", "--vehicle", "udrone", "--config", "thesis", "--realtime"]) == 0
    out = capsys.readouterr().out
    assert "node control step kf + lqg (thesis)" in out
    assert "plant of bluerov2-heavy-step" in out and "plant of step-observer-model" in out and "ready in" in out
    assert main(["compile", "--node", "--config", "no-such-config"]) == 2


def test_a_long_first_call_reports_its_progress_and_leaves_no_thread():
    import threading
    import time

    from rovlab._jit import with_progress

    lines: list[str] = []
    result, seconds = with_progress(lambda: time.sleep(0.5) or 42, lines.append, "the test kernel",
                                    after_s=0.05, every_s=0.1, hint="; a hint")
    assert result == 42 and seconds >= 0.5
    assert lines[0].startswith("compiling the test kernel") and "; a hint" in lines[0]
    assert any("still compiling the test kernel" in line for line in lines[1:])
    assert not any(t.name == "rovlab-compile-progress" for t in threading.enumerate())
    quiet: list[str] = []
    assert with_progress(lambda: 1, quiet.append, "a cached kernel")[0] == 1 and quiet == []
