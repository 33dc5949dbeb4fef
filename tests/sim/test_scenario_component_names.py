"""A scenario's estimator and controller names are checked where the scenario is read (issue 28,
fuzzing campaign): an unknown name was accepted by the reader and reached the commands'
"compiling the ../dp + lqg loop ..." line (rovlab compare, rovlab hmi) before the run refused it,
and earlier a 300-character one went into a cache file name ("File name too long")."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from rovlab.interfaces.cli import main
from rovlab.params.validate import ConfigError
from rovlab.sim.scenario import load_scenario, resolve_scenario_path

NAMES = ["../dp", "x" * 300, "nosuch", "dp/../../etc", "LQG", "kf\x00"]


def _scenario(tmp_path: Path, key: str, name: str) -> Path:
    text = resolve_scenario_path("dropout").read_text(encoding="utf-8")
    text = text.replace('plant = "process"', f'plant = "process"\n{key} = {name!r}'.replace("'", '"'), 1)
    text = text.replace("\\x00", "\\u0000").replace("duration_s = 60.0", "duration_s = 2.0")
    path = tmp_path / "scenario.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("key", ["estimator", "controller"])
@pytest.mark.parametrize("name", NAMES, ids=["dotdot", "300 chars", "nosuch", "path", "case", "nul"])
def test_the_scenario_reader_refuses_an_unknown_component_naming_file_key_and_choices(tmp_path, key, name):
    path = _scenario(tmp_path, key, name)
    with pytest.raises(ConfigError) as exc:
        load_scenario(path)
    text = str(exc.value)
    assert f"{path}: {key}: got" in text and "invalid scenario file" in text, text
    if "\x00" in name:  # the text reader's own refusal
        assert "expected text without control characters" in text
    else:
        assert "expected one of: " + ("kf, ekf" if key == "estimator" else "lqg, mrac, dp") in text, text
    assert len(max(text.splitlines(), key=len)) < 250  # a 300-character name is shortened in the message


@pytest.mark.parametrize("argv", [["compare", "--controllers", "lqg", "--runs", "1"], ["simulate", "--no-figures"],
                                  ["compile"]], ids=lambda a: a[0])
@pytest.mark.parametrize("name", ["../dp", "x" * 300], ids=["dotdot", "300 chars"])
def test_commands_refuse_it_before_they_announce_a_compile(tmp_path, capsys, argv, name):
    path = _scenario(tmp_path, "estimator", name)
    command = [argv[0], str(path), *argv[1:]]
    if argv[0] != "compile":
        command += ["--out", str(tmp_path / "out")]
    assert main(command) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "compiling" not in err, err
    assert re.search(rf"{re.escape(str(path))}: estimator: got '.*; expected one of:", err), err
    assert not (tmp_path / "out").exists()


def test_the_hmi_compile_line_is_not_made_for_a_bad_scenario(tmp_path):
    from rovlab.interfaces.compiling import loop_of
    from rovlab.sim.scenario import load_scenario_data

    assert loop_of(*load_scenario_data(str(_scenario(tmp_path, "controller", "../dp")))) is None
    assert loop_of(*load_scenario_data(str(_scenario(tmp_path, "controller", "dp")))) is not None
