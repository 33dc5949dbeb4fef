"""Scenario values that ran and gave nonsense (issue 28, fuzzing campaign): `[truth]
pwm_resolution_us = 1e-308` exited 0 with PWM = inf in every row (the quantisation cmd / res
overflowed), `duration_s = 1e-308` exited 0 with a one-row run and metrics of one sample."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from rovlab.interfaces.cli import main
from rovlab.params.validate import ConfigError
from rovlab.sim.scenario import load_scenario, resolve_scenario_path


def _scenario(tmp_path: Path, old: str, new: str) -> Path:
    text = resolve_scenario_path("dropout").read_text(encoding="utf-8").replace("duration_s = 60.0", "duration_s = 2.0")
    assert old in text
    path = tmp_path / "scenario.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize("value", ["1e-308", "5e-324", "1e-9", "0.0009"])
def test_a_pwm_resolution_finer_than_any_esc_is_refused(tmp_path, value):
    path = _scenario(tmp_path, "pwm_resolution_us = 1.0", f"pwm_resolution_us = {value}")
    with pytest.raises(ConfigError, match=rf"{path}: truth.pwm_resolution_us: got {float(value)!r}; expected 0 \(none\) or "
                                          r"a resolution within 0.001 .. 100 us"):
        load_scenario(path)


@pytest.mark.parametrize("value", ["0.0", "0.001", "1.0", "100.0"])
def test_no_quantisation_or_a_plausible_one_is_accepted(tmp_path, value):
    path = _scenario(tmp_path, "pwm_resolution_us = 1.0", f"pwm_resolution_us = {value}")
    assert load_scenario(path).pwm_resolution_us == float(value)


@pytest.mark.parametrize("value", ["1e-308", "0.01", "0.099"])
def test_a_run_shorter_than_one_control_step_is_refused(tmp_path, value):
    """dropout's design is the thesis's, h = 0.1 s (Sandøy 2016, appendix A.3): shorter is a single row."""
    path = _scenario(tmp_path, "duration_s = 2.0", f"duration_s = {value}")
    with pytest.raises(ConfigError, match=rf"{path}: duration_s: got {float(value)!r}; expected at least one control step "
                                          r"of the design \(its sample_time, 0.1 s\)"):
        load_scenario(path)
    assert load_scenario(_scenario(tmp_path, "duration_s = 2.0", "duration_s = 0.1")).duration_s == 0.1


def test_simulate_refuses_them_with_exit_2_and_writes_nothing(tmp_path, capsys):
    for old, new in (("pwm_resolution_us = 1.0", "pwm_resolution_us = 1e-308"), ("duration_s = 2.0", "duration_s = 1e-308")):
        path = _scenario(tmp_path, old, new)
        out = tmp_path / "out"
        assert main(["simulate", str(path), "--out", str(out), "--no-figures"]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and str(path) in err and "expected" in err, err
        assert not out.exists()


def test_the_smallest_accepted_resolution_gives_finite_pwm(tmp_path, capsys):
    path = _scenario(tmp_path, "pwm_resolution_us = 1.0", "pwm_resolution_us = 0.001")
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--no-figures"]) == 0
    with open(out / "timeseries.csv", newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    pwm = [float(r[k]) for r in rows for k in r if k.startswith("pwm_")]
    assert pwm and all(math.isfinite(p) and 1100.0 <= p <= 1900.0 for p in pwm)
