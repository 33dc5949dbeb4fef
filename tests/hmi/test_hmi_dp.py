"""Dynamic positioning in the HMI session (no browser): the DP scenarios run, north/east
set-points reach the loop, the xy track's data is published."""

from __future__ import annotations

import pytest

from rovlab.interfaces.hmi.session import CommandError, Session


@pytest.fixture
def dp_session(tmp_path):
    return Session.simulation("dp-station-keeping", out_dir=tmp_path / "out", running=False)


def test_the_dp_scenario_describes_itself_as_a_position_controller(dp_session):
    desc = dp_session.source.describe()
    assert desc["controller"] == "dp"
    assert desc["states"][:4] == ["x", "y", "z", "psi"]
    assert "x_d" in desc["controller_states"]
    assert desc["references"] == ["x", "y", "z", "psi"]  # the page shows north/east fields for these


def test_north_east_set_points_reach_the_loop_and_are_published(dp_session):
    dp_session.handle({"cmd": "reference", "north_m": 1.5, "east_m": -0.5, "heading_deg": 90})
    ref = dp_session.state()["reference"]
    assert (ref["north_m"], ref["east_m"], ref["schedule"]) == (1.5, -0.5, False)
    msgs = dp_session.advance(20)
    refs = [m["state"] for topic, _, m in msgs if topic == "/rovlab/reference"]
    assert refs[-1]["x"] == 1.5 and refs[-1]["y"] == -0.5
    est = [m["state"] for topic, _, m in msgs if topic == "/rovlab/estimate"]
    assert "x" in est[-1] and "y" in est[-1]
    ctrl = [m["controller"] for topic, _, m in msgs if topic == "/rovlab/command"]
    assert ctrl[-1]["x_d"] > ctrl[0]["x_d"]  # the reference model moves toward the new set-point
    dp_session.handle({"cmd": "reference", "schedule": True})
    dp_session.advance(1)
    assert dp_session.state()["reference"]["north_m"] == 0.0


def test_a_bad_position_set_point_is_refused(dp_session):
    for bad in ({"cmd": "reference", "north_m": "far"}, {"cmd": "reference", "east_m": 1e9}):
        with pytest.raises(CommandError) as err:
            dp_session.handle(bad)
        assert err.value.key in ("north_m", "east_m")
