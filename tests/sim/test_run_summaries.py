"""Run summaries say what fits the run (issue 28, a new user): a DP station-keeping run was
summarised as the thesis's LQG step case (settling time and overshoot of a vehicle asked to stay
put, a footnote about "the thesis's heading LQR", "RMS z" without saying it is the estimation
error); a Monte Carlo on the process plant reported its NEES far outside the chi-square bounds
without saying that the plant is outside the filter's model; metrics.json named no units."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rovlab.interfaces.cli import main
from rovlab.io.report import summary_rows
from rovlab.sim import metrics as mx
from rovlab.sim.montecarlo import run_many, summarise_runs
from rovlab.sim.results import summarise
from rovlab.sim.runner import simulate
from rovlab.sim.scenario import load_scenario_data


@pytest.fixture(scope="module")
def station_keeping():
    return summarise(simulate("dp-station-keeping"))


def test_holds_station_from_the_logged_set_points():
    t = np.arange(5.0)
    held = {"time_s": t, "ref_x": np.zeros(5), "ref_y": np.ones(5), "ref_z": np.full(5, 1.0), "ref_psi": np.zeros(5)}
    assert mx.holds_station(held)
    assert not mx.holds_station({**held, "ref_psi": np.array([0.0, 0, 0, 1.5, 1.5])})  # a heading change
    assert not mx.holds_station({"time_s": t, "ref_z": np.full(5, 1.0), "ref_psi": np.zeros(5)})  # depth and heading only


def test_station_keeping_has_no_step_metrics_but_its_excursion(station_keeping):
    m = station_keeping
    # dp-station-keeping starts 0.3 m and 10 deg off its one set-point: formerly a "step" with 113 s
    # settling and 15 % overshoot of depth
    assert m["task"] == "station keeping"
    assert not {"steps", "settling_time_s", "overshoot"} & set(m)
    for a in ("x", "y", "z", "psi"):
        assert 0.0 < m["tracking_rms"][a] <= m["tracking_max"][a]
    assert max(m["tracking_max"]["x"], m["tracking_max"]["y"]) <= m["tracking_horizontal_max_m"] \
        <= math.hypot(m["tracking_max"]["x"], m["tracking_max"]["y"])
    labels = [label for label, _ in summary_rows(m)]
    assert not any("settling" in lb or "overshoot" in lb for lb in labels)
    assert "station keeping: largest horizontal excursion [m]" in labels
    assert any(lb.startswith("RMS estimation error (estimate - truth) z") for lb in labels)


def test_a_run_with_set_point_changes_keeps_its_step_response():
    m = summarise(simulate("step-process-model"))
    assert m["task"] == "set-point changes"
    assert {s["axis"] for s in m["steps"]} == {"z", "psi"} and "z" in m["settling_time_s"]
    labels = [label for label, _ in summary_rows(m)]
    assert "settling time z [s] (2 %)" in labels and "overshoot z [%]" in labels
    assert not any(lb.startswith("station keeping") for lb in labels)


def test_simulate_prints_what_fits_the_run(capsys, tmp_path):
    assert main(["simulate", "dp-station-keeping", "--out", str(tmp_path / "dp"), "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert "heading LQR" not in out and "settle" not in out and "overshoot" not in out
    assert "est.err z [m]" in out and "estimate - truth" in out
    assert "dp-station-keeping: station keeping" in out and "largest excursion horizontal" in out
    assert main(["simulate", "step-observer-model", "--out", str(tmp_path / "lqg"), "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert "settle z [s]" in out and "heading LQR" not in out
    assert "expected only where the plant is the filter's model" not in out  # the observer plant is


def _numbers(value, path=()):
    """(key path, value) of every number in a metrics.json, lists as []."""
    if isinstance(value, dict):
        for k, v in value.items():
            if path == ("monte_carlo",) and k == "metrics":
                for key in v:
                    yield f"monte_carlo.metrics.{key}", 0.0
                continue
            yield from _numbers(v, (*path, k))
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v, (*path, "[]"))
    elif value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        yield ".".join(path).replace(".[]", "[]"), value


@pytest.mark.parametrize("scenario, runs", [("step-observer-model", 3), ("dropout", 1), ("dp-mocap-dropout", 2)])
def test_metrics_json_gives_the_unit_of_every_number(tmp_path, scenario, runs):
    out = tmp_path / "run"
    assert main(["simulate", scenario, "--out", str(out), "--no-figures", "--runs", str(runs), "--workers", "1"]) == 0
    files = [out / "metrics.json"] + ([out / "monte_carlo" / "metrics.json"] if runs > 1 else [])
    for f in files:
        data = json.loads(f.read_text())
        units = data["units"]
        missing = sorted({k for k, _ in _numbers({k: v for k, v in data.items() if k != "units"})
                          if k not in units and not k.startswith(("seed", "monte_carlo.metrics.seed",
                                                                  "monte_carlo.seeds"))})
        assert missing == [], f"{f}: numbers without a unit"
    units = json.loads((out / "metrics.json").read_text())["units"]
    assert units["rms_error.z"] == "m" and units["rms_error.psi"] == "rad" and units["rms_error.r"] == "rad/s"
    assert units["nees.mean"].startswith("1") and units["nees.dof"] == "count"
    if scenario == "dp-mocap-dropout":
        assert units["tracking_rms.psi"] == "rad" and units["tracking_horizontal_max_m"] == "m"
        assert units["thrusters.T1.max_abs_pwm_offset_us"] == "us"
        assert units["dropouts[].during.psi.drift"] == "rad"
    if scenario == "step-observer-model":
        assert units["settling_time_s.z"] == "s" and units["steps[].overshoot"].startswith("1 (fraction")
        assert units["monte_carlo.metrics.rms_error.z"] == "m" and units["monte_carlo.wall_time_s"] == "s"


def test_monte_carlo_on_the_process_plant_says_it_is_outside_the_filter_model(capsys, tmp_path):
    data, file = load_scenario_data("step-process-model")
    process = summarise_runs(run_many(data, file, [1, 2, 3], workers=1))
    assert "outside the filter's model" in process["consistency_note"]
    data, file = load_scenario_data("step-observer-model")
    assert "consistency_note" not in summarise_runs(run_many(data, file, [1, 2], workers=1))
    assert main(["simulate", "step-process-model", "--runs", "3", "--workers", "1", "--no-figures",
                 "--out", str(tmp_path / "mc")]) == 0
    out = capsys.readouterr().out
    nees_line = next(i for i, line in enumerate(out.splitlines()) if line.startswith("  NEES:"))
    assert "outside the filter's model" in out.splitlines()[nees_line + 1]
    mc = json.loads((tmp_path / "mc" / "monte_carlo" / "metrics.json").read_text())["monte_carlo"]
    assert "outside the filter's model" in mc["consistency_note"]
