"""One-shot commands import no numba or compile nothing (README, "One-shot commands"); the command
table is complete. Each check runs in a fresh interpreter (the test process has long imported
numba)."""

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
    environ = dict(os.environ)
    environ.update(NUMBA_CACHE_DIR=str(tmp_path / "cache"), **env)
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
