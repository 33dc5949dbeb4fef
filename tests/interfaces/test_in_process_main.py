"""`rovlab.interfaces.cli.main([...])` called from a script returns its exit code in that process
(issue 28, fuzzing campaign: a test harness calling main in-process was replaced by a re-run of
its own script, because the simulator's self-restart re-executed sys.orig_argv when no prebuilt
loop fitted -- 2bac9d6, removed with the whole prebuilt machinery in d1b09ad; no os.exec*,
sys.orig_argv or subprocess of rovlab's own command line is left in src, which
tests/test_compile_path.py::test_nothing_of_the_old_machinery_is_left also holds).

The script runs with an empty numba cache, so the loop compiles inside main -- the path where the
restart was -- and its top level counts how often it ran."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from rovlab.sim.scenario import resolve_scenario_path

SCRIPT = """
import json, os, sys
with open(sys.argv[1], "a") as fh:  # every run of this file's top level leaves a line
    fh.write(json.dumps({"started": os.getpid()}) + "\\n")
from rovlab.interfaces.cli import main
code = main(["simulate", sys.argv[2], "--out", sys.argv[3], "--no-figures"])
with open(sys.argv[1], "a") as fh:
    fh.write(json.dumps({"returned": code, "pid": os.getpid()}) + "\\n")
print("after main", code)
"""


def test_main_in_a_script_compiles_and_returns_without_re_running_the_script(tmp_path):
    scenario = tmp_path / "short.toml"
    text = resolve_scenario_path("step-observer-model").read_text(encoding="utf-8")
    scenario.write_text(text.replace("duration_s = 60.0", "duration_s = 2.0"), encoding="utf-8")
    assert "duration_s = 2.0" in scenario.read_text(encoding="utf-8")
    script, marks = tmp_path / "harness.py", tmp_path / "marks.jsonl"
    script.write_text(SCRIPT, encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "empty-cache")
    res = subprocess.run([sys.executable, str(script), str(marks), str(scenario), str(tmp_path / "out")],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert res.returncode == 0, res.stderr
    assert "compiling the kf + lqg loop" in res.stderr, res.stderr  # the compile path was taken
    lines = [json.loads(line) for line in marks.read_text(encoding="utf-8").splitlines()]
    assert len(lines) == 2, lines  # the script's top level ran once
    assert lines[1] == {"returned": 0, "pid": lines[0]["started"]}  # main returned, in the same process
    assert res.stdout.strip().splitlines()[-1] == "after main 0"
    assert (tmp_path / "out" / "timeseries.csv").is_file()


def test_no_re_execution_is_left_in_src():
    src = Path(__file__).resolve().parents[2] / "src" / "rovlab"
    for path in src.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        for word in ("orig_argv", "os.execv", "os.execl", "os.spawn", "os.posix_spawn", "sys.executable"):
            assert word not in text, f"{path.relative_to(src)} uses {word}"
