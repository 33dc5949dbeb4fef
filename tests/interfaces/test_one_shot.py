"""Issue 16, part 1: one-shot commands compile nothing, and numba's cache lives in the user's
cache folder whatever the import order. Each check runs in a fresh interpreter (the test process
has long imported numba)."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys

import pytest

from rovlab.interfaces import cli


def _python(code: str, tmp_path, **env) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    environ.update(XDG_CACHE_HOME=str(tmp_path / "cache"), **env)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ,
                          cwd=tmp_path, timeout=600)


ONE_SHOT = [
    ["thruster", "--thruster", "T1", "--force", "5", "--json"],
    ["thruster", "--vehicle", "bluerov2_heavy", "--thruster", "T1", "--pwm", "1700", "--json"],
    ["allocate", "--wrench", "30", "0", "40", "2", "--json"],
    ["allocate", "--vehicle", "bluerov2_heavy", "--wrench", "300", "0", "40", "2", "--mode", "scale", "--json"],
    ["vehicle", "show", "bluerov2_heavy", "--json"],
]
# design builds the filter model, whose stuck-sensor threshold comes from fusion (a numba module):
# it imports numba (~0.3 s) but compiles nothing
COMPILE_FREE = ONE_SHOT + [["design", "--config", "thesis", "--json"]]


@pytest.mark.parametrize("argv", ONE_SHOT, ids=lambda a: " ".join(a[:2]))
def test_one_shot_commands_never_import_numba(argv, tmp_path):
    code = (f"import sys\nfrom rovlab.interfaces.cli import main\ncode = main({argv!r})\n"
            "print(json.dumps({'code': code, 'numba': 'numba' in sys.modules}), file=sys.stderr)\n")
    res = _python("import json\n" + code, tmp_path)
    status = json.loads(res.stderr.strip().splitlines()[-1])
    assert status == {"code": 0, "numba": False}, res.stderr
    json.loads(res.stdout)  # and they answered


@pytest.mark.parametrize("argv", COMPILE_FREE, ids=lambda a: " ".join(a[:2]))
def test_one_shot_commands_compile_nothing(argv, tmp_path):
    res = _python(f"from rovlab.interfaces.cli import main\nraise SystemExit(main({argv!r}))", tmp_path)
    assert res.returncode == 0, res.stderr
    json.loads(res.stdout)
    assert not list((tmp_path / "cache").rglob("*.nbi")) and not list((tmp_path / "cache").rglob("*.nbc"))


def test_numba_cache_in_the_user_folder_even_if_numba_was_imported_first(tmp_path):
    # numba reads NUMBA_CACHE_DIR when imported and a cache=True function picks its folder when
    # decorated: without a reload, kernels cached into the installed package's __pycache__.
    code = """
import numba
import rovlab
from rovlab.models.thrusters import bank_pwm
from rovlab.estimation.fusion import wrap_angle
print(bank_pwm._cache._cache_path)
print(wrap_angle._cache._cache_path)
"""
    res = _python(code, tmp_path)
    assert res.returncode == 0, res.stderr
    paths = res.stdout.split()
    assert len(paths) == 2
    for path in paths:
        assert path.startswith(str(tmp_path / "cache" / "rovlab" / "numba")), path


def test_a_user_numba_cache_dir_wins(tmp_path):
    res = _python("import numba, rovlab\nfrom rovlab.models.thrusters import bank_force\n"
                  "print(bank_force._cache._cache_path)", tmp_path, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().startswith(str(tmp_path / "mine"))


def test_command_table_names_every_command_of_every_module():
    for module in cli._COMMAND_MODULES:
        parser = argparse.ArgumentParser()
        sub = parser.add_subparsers()
        importlib.import_module(module).register(sub)
        for name in sub.choices:
            assert cli._COMMAND_MODULE.get(name) == module, (name, module)


def test_unknown_command_and_top_level_help_still_list_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["nonsense"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "'filter'" in err and "'hmi'" in err


def test_python_dash_m_reports_user_errors_without_traceback(tmp_path):
    # as `python -m rovlab.interfaces.cli`, __main__ is a second copy of the module: its UserError
    # class must not be the one main() catches
    res = subprocess.run([sys.executable, "-m", "rovlab.interfaces.cli", "thruster", "--thruster", "T9", "--pwm", "1500"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert res.returncode == 2 and "Traceback" not in res.stderr and "T9" in res.stderr, res.stderr


def _aged(path, days_ago: float, now: float) -> None:
    os.utime(path, (now - days_ago * 86400, now - days_ago * 86400))


def test_prune_caches_keeps_what_is_in_use_and_recent(tmp_path, monkeypatch):
    import time

    import rovlab

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    now = time.time()
    numba_dir, design_dir = tmp_path / "rovlab" / "numba", tmp_path / "rovlab" / "design"
    design_dir.mkdir(parents=True)
    ages = {"current": 0.0, "today": 0.3, "yesterday": 1.5, "week": 7.0, "ten": 10.0, "twelve": 12.0,
            "old": 40.0, "compiling": 50.0}
    for name in ages:
        (numba_dir / name / "rovlab-ready").mkdir(parents=True)
        (numba_dir / name / "k.nbi").write_bytes(b"x")
    (numba_dir / "compiling" / "rovlab-ready" / "loop.lock").write_text(str(os.getpid()))  # a live compile
    (numba_dir / "old" / "rovlab-ready" / "loop.lock").write_text("999999999")  # a dead one's
    for name, age in ages.items():
        _aged(numba_dir / name, age, now)
    for name, age in {"fresh.pickle": 2.0, "stale.pickle": 30.0}.items():
        (design_dir / name).write_bytes(b"x")
        _aged(design_dir / name, age, now)
    (design_dir / "notes.txt").write_text("not ours")
    _aged(design_dir / "notes.txt", 90.0, now)
    removed = rovlab.prune_caches(keep=numba_dir / "current", now=now)
    left = sorted(p.name for p in numba_dir.iterdir())
    # the one in use, one used today and one still compiling whatever their rank, then the most
    # recently used up to CACHE_KEEP_RECENT in all; 'old' is past the age limit
    assert left == sorted(["current", "today", "yesterday", "week", "compiling"]), left
    assert sorted(p.name for p in design_dir.iterdir()) == ["fresh.pickle", "notes.txt"]
    assert {p.name for p in removed} == {"ten", "twelve", "old", "stale.pickle"}
    # without a cache folder at all nothing happens
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "none"))
    assert rovlab.prune_caches() == []


def test_a_new_source_version_prunes_on_first_import(tmp_path):
    import time

    now = time.time()
    numba_dir = tmp_path / "cache" / "rovlab" / "numba"
    for name, age in {"0000000000000000": 30.0, "1111111111111111": 1.0}.items():
        (numba_dir / name).mkdir(parents=True)
        _aged(numba_dir / name, age, now)
    res = _python("import os, rovlab\nprint(os.environ['NUMBA_CACHE_DIR'])", tmp_path)
    assert res.returncode == 0, res.stderr
    mine = res.stdout.strip()
    assert sorted(p.name for p in numba_dir.iterdir()) == sorted(["1111111111111111", os.path.basename(mine)])
