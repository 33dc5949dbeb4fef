"""Monte Carlo (replayable runs, parallel = sequential), the simulate CLI contract and its files."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from rovlab.interfaces.cli import main
from rovlab.sim.montecarlo import run_many, summarise_runs
from rovlab.sim.results import summarise
from rovlab.sim.runner import simulate
from rovlab.sim.scenario import load_scenario_data

CONTRACT = ["time_s", "true_z", "true_psi", "true_w", "true_r", "est_z", "est_psi", "est_w", "est_r", "est_b_w",
            "est_b_r", "meas_z_qualisys", "meas_z_pressure", "meas_psi_qualisys", "ref_z", "ref_psi", "tau_Z",
            "tau_N"]


def test_parallel_runs_equal_sequential_runs_and_replay_from_their_seed():
    data, file = load_scenario_data("dropout")
    seeds = [5, 6, 7, 8]
    par = run_many(data, file, seeds, workers=2)
    seq = run_many(data, file, seeds, workers=1)
    for a, b in zip(par, seq):
        assert a["seed"] == b["seed"]
        np.testing.assert_array_equal(a["nees"], b["nees"])
        assert a["metrics"]["rms_error"] == b["metrics"]["rms_error"]
    # run 2 of the campaign replayed on its own
    alone = summarise(simulate("dropout", seed=7))
    assert alone["rms_error"] == par[2]["metrics"]["rms_error"]
    summary = summarise_runs(par)
    assert summary["runs"] == 4 and summary["seeds"] == seeds
    assert summary["metrics"]["rms_error.z"]["count"] == 4
    assert summary["nees"]["runs"] == 4 and len(summary["nees"]["bounds_per_step"]) == 2


def test_observer_model_filter_is_consistent_over_monte_carlo():
    """With the plant equal to the filter's model, the average NEES over runs is chi-square
    distributed: it must sit near the state dimension (Bar-Shalom et al. 2001, sec. 5.4)."""
    data, file = load_scenario_data("step-observer-model")
    runs = run_many(data, file, list(range(100, 140)), workers=2)
    s = summarise_runs(runs)
    assert s["nees"]["dof"] == 6
    assert abs(s["nees"]["mean"] - 6.0) < 0.5
    assert s["nees"]["share_inside"] > 0.85


def test_simulate_cli_writes_the_contract(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["simulate", "dropout", "--out", str(out), "--seed", "4"])
    assert code == 0
    text = capsys.readouterr().out
    assert "dropout" in text and "seed 4" in text
    with (out / "timeseries.csv").open() as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    assert header[: len(CONTRACT)] == CONTRACT
    assert [h for h in header if h.startswith("pwm_")] == [f"pwm_T{i}" for i in range(1, 7)]
    assert len(rows) == 602
    k = header.index("meas_z_qualisys")
    assert rows[1 + 250][k] == ""  # t = 25 s: Qualisys lost, no sample
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= {"rms_error", "settling_time_s", "overshoot", "nees", "dropouts"}
    for name in ("states.png", "errors.png", "biases.png", "control.png", "report.html", "timeseries.mcap",
                 "timeseries.rovlab.mcap"):
        assert (out / name).stat().st_size > 1000, name
    html = (out / "report.html").read_text()
    assert "data:image/png;base64" in html and "http" not in html.split("<body>")[1][:2000]


def test_simulate_cli_monte_carlo(tmp_path, capsys):
    out = tmp_path / "mc"
    code = main(["simulate", "step-observer-model", "--out", str(out), "--runs", "6", "--workers", "2",
                 "--no-figures"])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    mc = metrics["monte_carlo"]
    assert mc["runs"] == 6 and mc["seeds"] == [1, 2, 3, 4, 5, 6]
    assert mc["metrics"]["rms_error.z"]["count"] == 6
    assert "NEES" in capsys.readouterr().out


def test_mcap_log_reads_back(tmp_path):
    from mcap.reader import make_reader

    out = tmp_path / "run"
    assert main(["simulate", "step-process-model", "--out", str(out), "--no-figures"]) == 0
    topics: dict[str, int] = {}
    with (out / "timeseries.rovlab.mcap").open("rb") as fh:  # rovlab's series; timeseries.mcap is the ROS 2 bag
        for _schema, channel, message in make_reader(fh).iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            if channel.topic == "/rovlab/estimate" and topics[channel.topic] == 1:
                first = json.loads(message.data)
                assert first["state"]["z"] == pytest.approx(1.05) and first["sensors"]["z_qualisys"] == "ok"
    assert topics["/rovlab/estimate"] == 601 and topics["/rovlab/truth"] == 601


@pytest.mark.parametrize("argv, expected", [
    (["simulate", "no-such-scenario"], "packaged scenario name"),
    (["simulate", "dropout", "--runs", "0"], "--runs must be at least 1"),
    (["simulate", "dropout", "--seed", "-2"], "--seed must be >= 0"),
])
def test_simulate_cli_bad_input(argv, expected, capsys, tmp_path):
    assert main(argv + ["--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err


def test_scenario_pointing_at_a_bad_vehicle_names_both(tmp_path, capsys):
    bad_vehicle = tmp_path / "v.toml"
    bad_vehicle.write_text("name = 'x'\n")
    sc = tmp_path / "s.toml"
    sc.write_text('name = "s"\nsource = "test"\nvehicle = "v.toml"\nduration_s = 1.0\n')
    assert main(["simulate", str(sc), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "s.toml: vehicle" in err and "v.toml" in err and "rigid_body" in err
