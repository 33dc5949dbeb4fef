"""Editing vehicle files in place (rovlab.params.edit): comments kept, values by key path, source notes,
validation before writing, atomic replacement."""

from __future__ import annotations

import os
import stat

import pytest
import tomlkit

from rovlab.params import ConfigError, load_vehicle
from rovlab.params.edit import DELETE, apply_edits, edit_vehicle_file, format_float, parse_path
from rovlab.params.vehicle import packaged_vehicle_path


@pytest.fixture
def udrone_copy(tmp_path):
    path = tmp_path / "my_udrone.toml"
    path.write_text(packaged_vehicle_path("udrone").read_text(encoding="utf-8"), encoding="utf-8")
    return path


@pytest.fixture
def heavy_copy(tmp_path):
    src = packaged_vehicle_path("bluerov2_heavy")
    if not src.exists():  # pragma: no cover - added by another change
        pytest.skip("bluerov2_heavy is not packaged")
    path = tmp_path / "heavy.toml"
    path.write_text(src.read_text(encoding="utf-8"), encoding="utf-8")
    return path


def test_values_change_and_everything_else_stays(udrone_copy):
    before = udrone_copy.read_text(encoding="utf-8")
    v = edit_vehicle_file(udrone_copy, {"added_mass.X_udot": -5.56, "damping.surge.linear": -4.2,
                                        "sensors[name=pressure].variance.z": 1.2e-4},
                          sources={"added_mass": "X_udot: rovlab identify step relay.csv"})
    after = udrone_copy.read_text(encoding="utf-8")
    assert v.added_mass[0] == -5.56 and v.damping_linear[0] == -4.2
    assert v.sensor("pressure").variance["z"] == 1.2e-4
    reloaded = load_vehicle(udrone_copy)
    assert reloaded.added_mass[0] == -5.56
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines()) if a != b]
    assert len(before.splitlines()) == len(after.splitlines())
    assert len(changed) == 4  # three values and one source line
    # trailing comments and the file's header survive
    assert "X_udot = -5.56              # [kg]" in after
    assert after.startswith("# uDrone: BlueROV kit (2015)")
    assert "(thesis table 4.3); step-response SI gave X_udot = -5.52; X_udot: rovlab identify step relay.csv" in after


def test_thruster_switched_from_table_to_quadratic(heavy_copy):
    curve = {"K_L_pos": 0.0593, "K_NL_pos": 2.48e-4, "K_L_neg": 0.0481, "K_NL_neg": 1.87e-4}
    v = edit_vehicle_file(heavy_copy, {"thrusters[name=T3].model": "quadratic", "thrusters[name=T3].quadratic": curve,
                                       "thrusters[name=T3].table": DELETE},
                          sources={"thrusters[name=T3]": "curve: rovlab identify thrust rig.csv"})
    t3 = v.thruster("T3")
    assert t3.model == "quadratic" and t3.curve.K_NL_pos == 2.48e-4
    assert v.thruster("T2").model == "table"
    text = heavy_copy.read_text(encoding="utf-8")
    assert "K_NL_pos = 2.48e-4" in text
    assert "motor 3; curve: rovlab identify thrust rig.csv" in text


def test_invalid_result_writes_nothing(udrone_copy):
    before = udrone_copy.read_text(encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        edit_vehicle_file(udrone_copy, {"damping.yaw.cubic": 0.3})  # positive damping: not allowed
    msg = str(err.value)
    assert "nothing was written" in msg and "damping.yaw.cubic" in msg and "<= 0" in msg
    assert udrone_copy.read_text(encoding="utf-8") == before
    assert [p.name for p in udrone_copy.parent.iterdir()] == [udrone_copy.name]  # no temp file left


def test_bad_paths_are_all_reported(udrone_copy):
    before = udrone_copy.read_text(encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        edit_vehicle_file(udrone_copy, {"thrusters[name=T9].deadband_us": 30.0, "sensors[7].rate_hz": 5.0})
    msg = str(err.value)
    assert "with name = 'T9' (there are: T1, T2, T3, T4, T5, T6)" in msg
    assert "sensors[7]" in msg and "an index below 3" in msg
    assert udrone_copy.read_text(encoding="utf-8") == before


def test_permissions_are_kept_and_output_can_be_another_file(udrone_copy, tmp_path):
    os.chmod(udrone_copy, 0o640)
    edit_vehicle_file(udrone_copy, {"rigid_body.mass": 7.5})
    assert stat.S_IMODE(udrone_copy.stat().st_mode) == 0o640
    out = tmp_path / "other.toml"
    v = edit_vehicle_file(udrone_copy, {"rigid_body.mass": 8.0}, output=out)
    assert v.mass == 8.0 and load_vehicle(out).mass == 8.0 and load_vehicle(udrone_copy).mass == 7.5


def test_source_replace_mode_and_new_keys():
    doc = tomlkit.parse('[a]\nsource = "old"\nx = 1.0  # keep\n[[t]]\nname = "p"\n')
    apply_edits(doc, {"a.y": 2.5e-7, "t[name=p].sub.k": 3, "b.c": "new"}, sources={"a": "fresh"},
                source_mode="replace")
    text = tomlkit.dumps(doc)
    assert 'source = "fresh"' in text and "x = 1.0  # keep" in text
    assert doc.unwrap() == {"a": {"source": "fresh", "x": 1.0, "y": 2.5e-7}, "t": [{"name": "p", "sub": {"k": 3}}],
                            "b": {"c": "new"}}


def test_paths_and_number_format():
    steps = parse_path("thrusters[name=T1].quadratic.K_L_pos")
    assert [s.label() for s in steps] == ["thrusters[name=T1]", "quadratic", "K_L_pos"]
    assert parse_path("sensors[2]")[0].index == 2
    with pytest.raises(ValueError, match="malformed key path"):
        parse_path("a..b")
    assert format_float(3.33e-4) == "3.33e-4"
    assert format_float(0.0607) == "0.0607"
    assert format_float(25.0) == "25.0"
    assert float(format_float(1.189622e-04)) == 1.189622e-04


def test_unchanged_values_keep_their_spelling(udrone_copy):
    before = udrone_copy.read_text(encoding="utf-8")
    edit_vehicle_file(udrone_copy, {"thrusters[name=T1].deadband_us": 25.0, "thrusters[name=T1].model": "quadratic",
                                    "thrusters[name=T1].quadratic": {"K_L_pos": 0.0607}})
    assert udrone_copy.read_text(encoding="utf-8") == before  # 25 stays 25, 6.07e-2 stays 6.07e-2


def test_directory_and_binary_targets_are_named(tmp_path):
    with pytest.raises(ConfigError, match="got 'a directory'; expected a TOML file"):
        edit_vehicle_file(tmp_path, {"mass": 7.0})
    binary = tmp_path / "v.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="undecodable bytes"):
        edit_vehicle_file(binary, {"mass": 7.0})
