"""The session log rebuilds the time-series columns from the messages, run by run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rovlab.interfaces.hmi.log import SessionLog
from rovlab.io.logreader import read_log
from rovlab.sim.live import LiveSimulation


@pytest.fixture(scope="module")
def sim_rows():
    sim = LiveSimulation("step-process-model")
    messages = sim.advance(40)
    return messages, sim.last_columns


def test_messages_turn_back_into_the_columns_they_came_from(tmp_path, sim_rows):
    messages, columns = sim_rows
    log = SessionLog(tmp_path)
    log.add(messages)
    got = log.run.arrays()
    assert len(log.run) == 40
    for name, col in columns.items():
        np.testing.assert_array_equal(got[name], np.asarray(col, dtype=float), err_msg=name)


def test_a_reset_starts_a_new_run_and_each_run_gets_its_files(tmp_path, sim_rows):
    pytest.importorskip("mcap")
    messages, _ = sim_rows
    log = SessionLog(tmp_path, stem="s")
    log.add(messages)
    log.event(4.0, "reset")
    log.new_run()
    log.add(messages[:10])  # two rows of the same times again
    paths = log.write(["csv", "mcap"])
    names = sorted(p.name for p in paths)
    assert names == ["s-events.json", "s-run1.csv", "s-run1.mcap", "s-run1.rovlab.mcap", "s-run2.csv", "s-run2.mcap",
                     "s-run2.rovlab.mcap"]
    run1, run2 = read_log(tmp_path / "s-run1.csv"), read_log(tmp_path / "s-run2.csv")
    assert len(run1) == 40 and len(run2) == 2
    assert run2.time[0] == 0.0 and "status_z_qualisys" in run1.columns
    assert json.loads((tmp_path / "s-events.json").read_text())[0]["what"] == "reset"


def test_a_channel_that_appears_later_is_backfilled_with_no_values(tmp_path):
    log = SessionLog(tmp_path)
    log.add([("/rovlab/measurement", 0.0, {"t": 0.0, "values": {"z_a": 1.0}})])
    log.add([("/rovlab/measurement", 0.1, {"t": 0.1, "values": {"z_a": 2.0, "z_b": 5.0}}),
             ("/rovlab/unknown", 0.1, {"x": 1})])
    cols = log.run.arrays()
    assert np.isnan(cols["meas_z_b"][0]) and cols["meas_z_b"][1] == 5.0
    assert list(cols) == ["time_s", "meas_z_a", "meas_z_b"]


def test_the_session_log_has_the_columns_order_and_words_of_timeseries_csv(tmp_path, sim_rows):
    """Issue 15: the HMI's session log and a simulation's timeseries.csv are the same table."""
    from rovlab.io.messages import order_columns
    from rovlab.sim.runner import simulate

    messages, _ = sim_rows
    log = SessionLog(tmp_path, stem="s")
    log.add(messages)
    (csv,) = [p for p in log.write(["csv"]) if p.suffix == ".csv"]
    header = csv.read_text(encoding="utf-8").splitlines()[0].split(",")
    batch = list(order_columns(simulate("step-process-model").columns))
    assert header == [c for c in batch if c in header]  # same relative order
    assert set(batch) - set(header) <= {c for c in batch if c.startswith("tau_") and c.endswith("_demanded")}
    statuses = set(read_log(csv).text["status_z_qualisys"])
    assert statuses <= {"ok", "recovering", "lost", "off"} and statuses
