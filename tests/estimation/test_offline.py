"""`rovlab filter --estimator NAME` (issue 26): any registered estimator replays a log through its
slots (rovlab.estimation.offline), so the offline and the in-loop estimator are the same component."""

from __future__ import annotations

import numpy as np

from rovlab.interfaces.cli import main
from rovlab.io.logreader import read_log


def test_the_ekf_replays_a_dp_run_with_the_estimates_it_had_in_the_loop(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["simulate", "dp-mocap-dropout", "--out", str(run), "--no-figures"]) == 0
    est = tmp_path / "est.csv"
    # the configuration's estimator (ekf) by default; the vehicle with its DVL as in the scenario
    assert main(["filter", str(run / "timeseries.csv"), "--vehicle", "udrone_dvl", "--config", "udrone_dp",
                 "--out", str(est)]) == 0
    assert "estimator ekf" in capsys.readouterr().out
    a, b = read_log(run / "timeseries.csv"), read_log(est)
    for s in ("x", "y", "z", "psi", "u", "v", "w", "r", "b_X", "b_Y", "b_Z", "b_N"):
        # the same numbers but for the log's 10 significant digits of the samples and inputs
        np.testing.assert_allclose(b[f"est_{s}"], a[f"est_{s}"], rtol=1e-8, atol=1e-8, err_msg=s)
        np.testing.assert_allclose(b[f"var_{s}"], a[f"var_{s}"], rtol=1e-6, atol=1e-12, err_msg=s)
    statuses = [c for c in a.text if c.startswith("status_")]
    assert len(statuses) == 9 and all(list(a.text[c]) == list(b.text[c]) for c in statuses)
    assert "lost-timeout" in set(a.text["status_x_qualisys"])  # the motion-capture drop-out, seen alike


def test_an_unknown_estimator_is_refused_with_the_names_there_are(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["simulate", "step-observer-model", "--out", str(run), "--no-figures"]) == 0
    capsys.readouterr()
    assert main(["filter", str(run / "timeseries.csv"), "--estimator", "nope", "--out", str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err
    assert "--estimator" in err and "'nope'" in err and "kf" in err and "ekf" in err
    assert not (tmp_path / "e.csv").exists()
    # kf by its name is the depth-and-heading filter's own replay, as without the option
    assert main(["filter", str(run / "timeseries.csv"), "--estimator", "kf", "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["filter", str(run / "timeseries.csv"), "--out", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
