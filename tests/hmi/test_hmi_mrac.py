"""The HMI offers MRAC (issue 12): the controller is chosen and tuned in the configuration
document, its design is shown, and its adapted parameters reach the page with the commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rovlab.interfaces.hmi.session import CommandError, Session


@pytest.fixture
def heave(tmp_path):
    return Session.simulation("heave-buoyancy-step", out_dir=tmp_path / "out", running=False)


def test_switching_to_mrac_reaches_the_loop_and_streams_the_adapted_parameters(heave):
    assert heave.source.loop_summary()["controller"] == "lqg"
    heave.advance(5)
    out = heave.handle({"cmd": "set", "target": "config", "key": "controller", "value": "mrac"})
    assert out.documents_changed
    loop = heave.source.loop_summary()
    assert loop["controller"] == "mrac" and loop["mrac"]["parameters"] == ["M", "D_l", "D_q", "F"]
    json.dumps(heave.documents_payload())  # what the server sends must be JSON
    desc = heave.source.describe()
    assert desc["controller"] == "mrac" and "F_hat" in desc["controller_states"]
    msgs = heave.advance(3)
    cmds = [m for topic, _, m in msgs if topic == "/rovlab/command"]
    assert len(cmds) == 3
    assert set(cmds[-1]["controller"]) == {"M_hat", "D_l_hat", "D_q_hat", "F_hat", "z_m", "w_m"}
    # the reference model starts where the vehicle is when MRAC takes over
    est = [m for topic, _, m in msgs if topic == "/rovlab/estimate"][0]
    assert cmds[0]["controller"]["z_m"] == pytest.approx(est["state"]["z"])
    # and the session log keeps them (columns ctrl_<name>, as in a batch run's timeseries.csv)
    cols = heave.log.run.arrays()
    assert {"ctrl_F_hat", "ctrl_M_hat", "ctrl_z_m"} <= set(cols)
    assert np.isnan(cols["ctrl_F_hat"][0]) and np.isfinite(cols["ctrl_F_hat"][-1])  # LQG first, then MRAC
    csv = [p for p in heave.export(["csv"]) if p.suffix == ".csv"]
    assert any("ctrl_F_hat" in p.read_text().splitlines()[0] for p in csv)


def test_mrac_gains_are_tuned_live_and_bad_ones_refused(heave):
    heave.handle({"cmd": "set", "target": "config", "key": "controller", "value": "mrac"})
    heave.handle({"cmd": "set", "target": "config", "changes": {"mrac.k_s": "60"}})
    assert heave.source.loop_summary()["mrac"]["k_s"] == 60.0
    with pytest.raises(CommandError) as err:
        heave.handle({"cmd": "set", "target": "config", "changes": {"mrac.k_s": "500"}})
    assert any(p.key == "mrac.k_s" and "stable" in p.expected for p in err.value.problems)
    with pytest.raises(CommandError) as err:
        heave.handle({"cmd": "set", "target": "config", "changes": {"mrac.bandwidth": "3", "mrac.max_step": "1"}})
    assert any(p.key == "mrac.bandwidth" and "thrusters" in p.expected for p in err.value.problems)
    assert heave.source.loop_summary()["mrac"]["k_s"] == 60.0  # unchanged


def test_a_new_mrac_table_needs_a_source(tmp_path):
    s = Session.simulation("step-process-model", out_dir=tmp_path / "out", running=False)
    doc = s.documents["config"]
    doc_data = dict(doc.data)
    doc_data.pop("mrac", None)
    doc.commit(doc_data, doc.validate(doc_data))
    with pytest.raises(CommandError) as err:
        s.handle({"cmd": "set", "target": "config", "changes": {"mrac.k_s": "60"}})
    assert any(p.key == "mrac.source" for p in err.value.problems)
    s.handle({"cmd": "set", "target": "config", "changes": {"mrac.k_s": "60", "mrac.source": "HMI"}})
