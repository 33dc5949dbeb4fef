"""Issue 15 item 12: configurations the fuzzer found crashing or hanging the design are refused
by the loader, naming the file, the key, the value and the plausible range."""

from __future__ import annotations

import pytest

from rovlab.interfaces.cli import main
from rovlab.params.design import packaged_config_path

THESIS_TEXT = packaged_config_path("thesis").read_text(encoding="utf-8")


@pytest.mark.parametrize(("old", "new", "key", "expected"), [
    ("bias_time_per_mass = 100.0", "bias_time_per_mass = 5e-324", "process_noise.bias_time_per_mass",
     "0.001 .. 100000"),
    ("mass = 7.31 ", "mass = 1e-300 ", "model.mass", "0.1 .. 1000"),
    ("sample_time = 0.1 ", "sample_time = 1e-7 ", "sample_time", "0.001 .. 10"),
    ("Z_w = -5.18 ", "Z_w = -9e18 ", "model.Z_w", "-10000 .. 0"),
    ("psd = { w = 1e-2,", "psd = { w = 1e300,", "process_noise.psd.w", "0 .. 1e+06"),
    ("input_max = { Z = 10.0,", "input_max = { Z = 1e-200,", "lqr.state_max", "finite"),
])
def test_implausible_configuration_is_refused_with_exit_2(tmp_path, capsys, old, new, key, expected):
    assert old in THESIS_TEXT
    path = tmp_path / "bad.toml"
    path.write_text(THESIS_TEXT.replace(old, new, 1), encoding="utf-8")
    assert main(["design", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if f"{path}: {key}:" in line]
    assert lines, err
    assert expected in lines[0]
    assert "Traceback" not in err


def test_a_configuration_name_with_a_newline_is_refused(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(THESIS_TEXT.replace('name = "thesis"', 'name = "the\\nsis"', 1), encoding="utf-8")
    assert main(["design", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: name:" in err and "one line" in err
