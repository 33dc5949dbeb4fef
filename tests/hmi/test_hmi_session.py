"""The HMI session: commands reach the running loop, bad ones are refused and change nothing."""

from __future__ import annotations

import math

import pytest

from rovlab.interfaces.hmi.session import CommandError, Session
from rovlab.interfaces.hmi.source import SimulationSource, Source
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


def _refused(session, command):
    with pytest.raises(CommandError) as err:
        session.handle(command)
    return err.value


def test_the_simulation_source_fulfils_the_source_protocol(session):
    assert isinstance(session.source, SimulationSource)
    assert isinstance(session.source, Source)
    desc = session.source.describe()
    assert [c["name"] for c in desc["channels"]] == ["qualisys.z", "pressure.z", "qualisys.psi"]
    assert desc["sensors"] == ["qualisys", "pressure"] and len(desc["thrusters"]) == 6


def test_it_starts_at_the_scenario_start_even_after_warming_up(session):
    assert session.source.time == 0.0
    msgs = session.advance(3)
    assert [t for topic, t, _ in msgs if topic == "/rovlab/truth"] == pytest.approx([0.0, 0.1, 0.2])
    assert session.log.rows == 3


def test_a_model_change_reaches_the_loop_and_leaves_the_plant_alone(session):
    session.advance(5)
    out = session.handle({"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": "7.9"})
    assert out.documents_changed and out.result["applied"] == {"rigid_body.mass": 7.9}
    loop = session.source.loop_summary()
    assert loop["vehicle"]["mass"] == 7.9 and loop["truth"]["mass"] == 7.31
    assert session.source.time == pytest.approx(0.5)  # the run goes on from where it was


def test_a_truth_change_gives_a_mismatch(session):
    session.handle({"cmd": "set", "target": "truth", "changes": {
        "restoring.displaced_volume": 8.2e-3, "damping.heave.quadratic": -50}})
    loop = session.source.loop_summary()
    assert loop["truth"]["displaced_volume"] == 8.2e-3 and loop["vehicle"]["displaced_volume"] == 7.99e-3
    assert loop["truth"]["damping_quadratic"][2] == -50.0


def test_an_observer_change_redesigns_the_filter(session):
    q_before = session.source.loop_summary()["Q_diag"]
    session.handle({"cmd": "set", "target": "config", "key": "process_noise.psd.b_w", "value": 2.0})
    assert session.source.loop_summary()["Q_diag"][4] > 5 * q_before[4]
    session.handle({"cmd": "set", "target": "config", "key": "measurements[1].variance", "value": "1e-3"})
    assert session.source.loop_summary()["R"]["pressure.z"] == 1e-3


def test_an_lqr_change_recomputes_the_gains(session):
    K = session.source.loop_summary()["K"]
    session.handle({"cmd": "set", "target": "config", "key": "lqr.state_max.z", "value": 0.5})
    K2 = session.source.loop_summary()["K"]
    assert K2[0][0] > 2 * K[0][0]


@pytest.mark.parametrize("target, key, value, words", [
    ("vehicle", "rigid_body.mass", "-1", "positive"),
    ("vehicle", "rigid_body.mass", "abc", "a number"),
    ("vehicle", "rigid_body.mass", "nan", "finite"),
    ("vehicle", "damping.heave.linear", "3", "<= 0"),
    ("truth", "added_mass.Z_wdot", 5, "<= 0"),
    ("vehicle", "thrusters[name=T1].quadratic.K_L_pos", -0.1, ">= 0"),
    ("config", "measurements[0].variance", -1e-9, "positive"),
    ("config", "process_noise.psd.w", "-1", ">= 0"),
    ("config", "lqr.input_max.Z", 0, "positive"),
    ("config", "no_such_key", 1, "unknown keys"),
])
def test_a_bad_value_is_refused_with_the_loaders_reason_and_nothing_changes(session, target, key, value, words):
    doc_before = session.documents[target].data
    loop_before = session.source.loop_summary()
    err = _refused(session, {"cmd": "set", "target": target, "key": key, "value": value})
    assert words in err.message and err.problems and err.key == key
    assert session.documents[target].data is doc_before
    assert session.source.loop_summary() == loop_before
    payload = err.payload()
    assert payload["problems"][0]["key"] and payload["problems"][0]["expected"]


def test_an_unobservable_sensor_set_is_refused(session):
    keep = [m for m in session.documents["config"].data["measurements"] if m["quantity"] == "z"]
    err = _refused(session, {"cmd": "set", "target": "config", "key": "measurements", "value": keep})
    assert "cannot be estimated" in err.message and "psi" in err.message
    assert len(session.source.describe()["channels"]) == 3


def test_dropping_a_measurement_changes_the_channels_and_keeps_running(session):
    session.advance(3)
    keep = [m for m in session.documents["config"].data["measurements"] if m["sensor"] != "pressure"]
    session.handle({"cmd": "set", "target": "config", "key": "measurements", "value": keep})
    assert [c["name"] for c in session.source.describe()["channels"]] == ["qualisys.z", "qualisys.psi"]
    msgs = session.advance(2)
    meas = [m for topic, _, m in msgs if topic == "/rovlab/measurement"]
    assert set(meas[-1]["values"]) == {"z_qualisys", "psi_qualisys"}


def test_switching_a_sensor_off_gives_dead_reckoning_and_back_on_recovery(session):
    session.advance(100)  # 10 s: settled
    session.handle({"cmd": "sensor", "sensor": "qualisys", "available": False})
    msgs = session.advance(30)
    est = [m for topic, _, m in msgs if topic == "/rovlab/estimate"]
    assert est[-1]["sensors"]["psi_qualisys"] == "lost" and est[-1]["sensors"]["z_pressure"] == "ok"
    assert est[-1]["variance"]["psi"] > 10 * est[0]["variance"]["psi"]  # heading dead-reckons
    assert session.state()["sensors"]["qualisys"] is False
    session.handle({"cmd": "sensor", "sensor": "qualisys", "available": True})
    statuses = [m["sensors"]["psi_qualisys"] for topic, _, m in session.advance(80) if topic == "/rovlab/estimate"]
    assert "recovering" in statuses and statuses[-1] == "ok"


def test_a_filter_channel_can_be_forced_off(session):
    session.handle({"cmd": "filter_mode", "channel": "pressure.z", "mode": "off"})
    est = [m for topic, _, m in session.advance(2) if topic == "/rovlab/estimate"]
    assert est[-1]["sensors"]["z_pressure"] == "off"
    assert session.state()["filter_modes"]["pressure.z"] == "off"
    _refused(session, {"cmd": "filter_mode", "channel": "pressure.z", "mode": "sometimes"})
    _refused(session, {"cmd": "filter_mode", "channel": "gps.x", "mode": "off"})


def test_references_are_degrees_at_the_edge_and_radians_inside(session):
    session.handle({"cmd": "reference", "depth_m": 0.5, "heading_deg": 270})
    z, psi = session.source.sim.reference
    assert z == 0.5 and psi == pytest.approx(-math.pi / 2)
    assert session.state()["reference"]["heading_deg"] == pytest.approx(-90)
    assert session.state()["reference"]["schedule"] is False
    session.handle({"cmd": "reference", "schedule": True})
    session.advance(1)
    assert session.state()["reference"]["schedule"] is True
    assert session.state()["reference"]["heading_deg"] == pytest.approx(30)
    _refused(session, {"cmd": "reference", "depth_m": "deep"})
    _refused(session, {"cmd": "reference"})


@pytest.mark.parametrize("command", [
    {"cmd": "speed", "value": 0}, {"cmd": "speed", "value": "fast"}, {"cmd": "speed", "value": True},
    {"cmd": "speed", "value": 1e9}, {"cmd": "warp"}, {"cmd": 3}, {"nocmd": 1}, [1, 2], "start", None,
    {"cmd": "sensor", "sensor": "qualisys", "available": "no"}, {"cmd": "sensor", "sensor": "gps", "available": False},
    {"cmd": "set", "target": "boat", "key": "a", "value": 1}, {"cmd": "set", "target": "vehicle"},
    {"cmd": "set", "target": "vehicle", "key": "rigid_body.mass"}, {"cmd": "set", "target": "vehicle", "changes": []},
    {"cmd": "step", "n": 0}, {"cmd": "save", "target": "vehicle", "name": "../../etc/passwd"},
    {"cmd": "save", "target": "vehicle", "in_place": True}, {"cmd": "export", "formats": ["xls"]},
])
def test_garbage_commands_are_refused_with_a_message(session, command):
    before = session.state()
    err = _refused(session, command)
    assert err.message
    assert session.state() == before


def test_start_pause_step_speed_reset(session):
    session.handle({"cmd": "start"})
    assert session.running
    _refused(session, {"cmd": "step"})  # single steps only while paused
    session.handle({"cmd": "pause"})
    out = session.handle({"cmd": "step", "n": 3})
    assert len(out.messages) == 15 and session.source.time == pytest.approx(0.3)
    assert session.handle({"cmd": "speed", "value": 4}).pacing_changed and session.speed == 4.0
    session.handle({"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": 8})
    out = session.handle({"cmd": "reset"})
    assert out.reset and session.source.time == 0.0 and len(session.log.runs) == 2
    assert session.source.loop_summary()["vehicle"]["mass"] == 8.0  # tuned parameters survive a reset


def test_save_all_writes_files_that_reload(session, tmp_path):
    session.handle({"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": 7.7})
    session.handle({"cmd": "set", "target": "truth", "key": "rigid_body.mass", "value": 7.4})
    session.handle({"cmd": "set", "target": "config", "key": "lqr.state_max.z", "value": 1.0})
    saved = session.handle({"cmd": "save", "target": "all"}).result["saved"]
    assert all(s["comments_kept"] for s in saved.values())
    assert load_vehicle(saved["vehicle"]["path"]).mass == 7.7
    assert load_vehicle(saved["truth"]["path"]).mass == 7.4
    cfg = load_design_config(saved["config"]["path"])
    assert cfg.lqr_bryson["state_max"][0] == 1.0
    # a session started from the saved files has the tuned values
    again = Session.simulation(vehicle=saved["vehicle"]["path"], config=saved["config"]["path"],
                               out_dir=tmp_path / "again", running=False)
    assert again.source.loop_summary()["vehicle"]["mass"] == 7.7
    assert again.documents["config"].get("lqr.state_max.z") == 1.0


def test_a_users_own_file_can_be_saved_in_place(tmp_path):
    from rovlab.params.vehicle import resolve_vehicle_path

    mine = tmp_path / "mine.toml"
    mine.write_text(resolve_vehicle_path("udrone").read_text())
    s = Session.simulation(vehicle=str(mine), out_dir=tmp_path / "out", running=False)
    s.handle({"cmd": "set", "target": "vehicle", "key": "rigid_body.I_zz", "value": 0.2})
    s.handle({"cmd": "save", "target": "vehicle", "in_place": True})
    assert load_vehicle(mine).I_zz == 0.2 and "# yaw moment of inertia" in mine.read_text()
    _refused(s, {"cmd": "save", "target": "truth", "in_place": True})


def test_export_writes_the_log_and_the_events(session):
    _refused(session, {"cmd": "export"})  # nothing logged yet
    session.advance(20)
    session.handle({"cmd": "sensor", "sensor": "pressure", "available": False})
    files = session.handle({"cmd": "export", "formats": ["csv"]}).result["files"]
    names = [f["path"].rsplit("/", 1)[1] for f in files]
    assert names == [f"{session.log.stem}.csv", f"{session.log.stem}-events.json"]
    assert set(names) <= set(session.files)


def test_the_scenarios_plant_parameters_become_the_truth_document(tmp_path):
    from rovlab.params.vehicle import resolve_vehicle_path

    sc = tmp_path / "heavy.toml"
    sc.write_text(f'name = "x"\nsource = "test"\nvehicle = "{resolve_vehicle_path("udrone")}"\n'
                  'design = "thesis"\nduration_s = 10.0\n[truth]\nparameters = { mass = 7.6, Z_wdot = -12.0 }\n')
    s = Session.simulation(str(sc), out_dir=tmp_path / "out", running=False)
    assert s.documents["truth"].get("rigid_body.mass") == 7.6
    assert s.documents["truth"].get("added_mass.Z_wdot") == -12.0
    assert s.documents["vehicle"].get("rigid_body.mass") == 7.31
    assert s.source.loop_summary()["truth"]["mass"] == 7.6


# --------------------------------------------------------------------------------------------
# Issue 15 item 12: what the fuzzer found in the HMI commands
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("command", [
    {"cmd": "save", "target": "vehicle", "name": "evil.toml\n"},  # used to write 'evil.toml⏎'
    {"cmd": "set", "target": "truth", "key": "damping.heave.linear", "value": -1e18},
    {"cmd": "set", "target": "config", "key": "initial.state.z", "value": -1e308},
    {"cmd": "step", "n": 10000},  # froze every client for a second
    {"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": "[" * 20 + "1" + "]" * 20},
])
def test_fuzzer_findings_are_refused_and_nothing_changes(session, command):
    before = {t: d.data for t, d in session.documents.items()}
    time_before = session.source.time
    with pytest.raises(CommandError) as info:
        session.handle(command)
    assert info.value.message
    assert {t: d.data for t, d in session.documents.items()} == before
    assert session.source.time == time_before
    assert not any(p.name.startswith("evil") for p in session.out_dir.glob("*")) if session.out_dir.exists() else True


def test_a_deeply_nested_command_is_refused_without_recursion(session):
    deep: object = 1
    for _ in range(5000):  # deeper than Python's recursion limit
        deep = [deep]
    with pytest.raises(CommandError, match="nested deeper than"):
        session.handle({"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": deep})


def test_step_accepts_up_to_its_bound(session):
    from rovlab.interfaces.hmi.session import MAX_STEPS_PER_COMMAND

    session.handle({"cmd": "pause"})
    out = session.handle({"cmd": "step", "n": MAX_STEPS_PER_COMMAND})
    assert out.messages


# --------------------------------------------------------------------------------------------
# Issue 28: set-points a new user and a fuzzer typed
# --------------------------------------------------------------------------------------------

def _reference_now(session):
    return session.state()["reference"], session.source.sim.reference, session.source.sim.reference_xy


@pytest.mark.parametrize("heading", [1e308, -1e308, 721.0, 9000.0])
def test_an_absurd_heading_is_refused_not_wrapped(session, heading):
    # 1e308 deg used to become -95.7 deg (math.remainder of a number whose every digit below 1e292
    # is lost); 9000 (90 deg in MAVLink's centidegrees) would wrap to 0 deg without a word
    before = _reference_now(session)
    err = _refused(session, {"cmd": "reference", "depth_m": 0.4, "heading_deg": heading})
    assert err.key == "heading_deg" and "heading_deg must be within -720 .. 720 deg" in err.message
    assert _reference_now(session) == before  # the depth given with it is not applied either


@pytest.mark.parametrize("heading, wrapped", [(370.0, 10.0), (-720.0, 0.0), (720.0, 0.0), (540.0, 180.0),
                                              (-190.0, 170.0)])
def test_a_heading_past_a_turn_is_wrapped(session, heading, wrapped):
    session.handle({"cmd": "reference", "heading_deg": heading})
    assert abs(session.state()["reference"]["heading_deg"]) == pytest.approx(abs(wrapped), abs=1e-12)
    assert math.cos(session.source.sim.reference[1] - math.radians(wrapped)) == pytest.approx(1.0)


def test_a_depth_above_the_surface_is_refused_with_a_message_not_an_internal_error(session):
    # -5 m passed the session's old -100 .. 1000 m range and the simulation's own check raised a
    # ValueError, which the server reported as an internal error
    before = _reference_now(session)
    err = _refused(session, {"cmd": "reference", "depth_m": -5})
    assert err.key == "depth_m" and "0 .. 1000 m" in err.message and "got -5" in err.message
    assert _reference_now(session) == before
    session.handle({"cmd": "reference", "depth_m": 0})  # the surface itself is a depth
    assert session.source.sim.reference[0] == 0.0


def test_a_position_set_point_is_refused_when_the_controller_holds_depth_and_heading_only(session):
    # it used to be accepted and dropped: the LQG holds z and psi, north/east went nowhere
    assert session.source.describe()["references"] == ["z", "psi"]
    before = _reference_now(session)
    for command in ({"cmd": "reference", "north_m": 1.0}, {"cmd": "reference", "east_m": -2.0, "depth_m": 0.5}):
        err = _refused(session, command)
        assert err.key in ("north_m", "east_m") and "'lqg' holds z, psi only" in err.message
        assert _reference_now(session) == before


def test_a_sources_own_refusal_is_a_message_naming_the_field(session, monkeypatch):
    # a vehicle bridge's source says nothing about its references and raises ValueError itself
    describe = session.source.describe
    monkeypatch.setattr(session.source, "describe", lambda: {k: v for k, v in describe().items() if k != "references"})

    def no_position(z=None, psi=None, *, x=None, y=None):
        raise ValueError("the bridge holds depth and heading only")

    monkeypatch.setattr(session.source, "set_reference", no_position)
    err = _refused(session, {"cmd": "reference", "north_m": 1.0})
    assert err.key == "north_m" and err.message == "reference refused: the bridge holds depth and heading only"


@pytest.mark.parametrize("value", [10**400, -(10**400)], ids=["+1e400", "-1e400"])
def test_an_integer_beyond_a_float_is_refused_not_an_overflow(session, value):
    for command in ({"cmd": "reference", "depth_m": value}, {"cmd": "speed", "value": value}):
        err = _refused(session, command)
        assert "an integer of 401 digits" in err.message
