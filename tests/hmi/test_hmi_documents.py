"""Parameter documents: key-path edits on plain dicts, validation, saving with comments kept."""

from __future__ import annotations

import math
import tomllib

import pytest

from rovlab.interfaces.hmi.documents import ParameterDocument, coerce_text, get_path, set_path
from rovlab.params.design import design_config_from_dict, load_design_config, resolve_config_path
from rovlab.params.validate import ConfigError, read_toml
from rovlab.params.vehicle import load_vehicle, resolve_vehicle_path, vehicle_from_dict


def _vehicle_doc():
    path = resolve_vehicle_path("udrone")
    return ParameterDocument("vehicle", read_toml(path), origin=path, label="udrone.toml",
                             validate=lambda d, f: vehicle_from_dict(d, file=f), packaged=True)


def _config_doc(name="thesis"):
    path = resolve_config_path(name)
    return ParameterDocument("config", read_toml(path), origin=path, label=f"{name}.toml",
                             validate=lambda d, f: design_config_from_dict(d, file=f), packaged=True)


@pytest.mark.parametrize("text, value", [
    ("7.5", 7.5), (" -5 ", -5), ("1e-3", 1e-3), ("[1, 2.5]", [1, 2.5]), ("true", True),
    ("abc", "abc"), ("2024-01-01", "2024-01-01"), ("", ""),
])
def test_typed_text_is_read_as_a_toml_value(text, value):
    assert coerce_text(text) == value


def test_nan_typed_in_the_page_stays_nan_for_the_loader_to_refuse():
    assert math.isnan(coerce_text("nan"))


def test_key_paths_reach_tables_entries_by_name_and_index():
    data = {"a": {"b": 1}, "t": [{"name": "T1", "q": {"k": 1}}, {"name": "T2", "q": {"k": 2}}]}
    set_path(data, "a.c.d", 3)
    set_path(data, "t[name=T2].q.k", 5)
    set_path(data, "t[0].q.k", 4)
    assert data["a"]["c"]["d"] == 3 and data["t"][1]["q"]["k"] == 5 and data["t"][0]["q"]["k"] == 4
    assert get_path(data, "t[name=T2].q.k") == 5 and get_path(data, "nope.x") is None
    set_path(data, "a.b", None)  # None deletes
    assert "b" not in data["a"]
    set_path(data, "t[0]", None)
    assert [e["name"] for e in data["t"]] == ["T2"]


@pytest.mark.parametrize("path", ["t[name=T9].k", "a.b.c", "t[5].k", "bad path!"])
def test_a_key_path_that_does_not_fit_is_refused_with_its_name(path):
    data = {"a": {"b": 1}, "t": [{"name": "T1"}]}
    with pytest.raises(ConfigError) as err:
        set_path(data, path, 1, file="f.toml")
    assert "f.toml" in str(err.value)


def test_a_refused_candidate_leaves_the_document_unchanged():
    doc = _vehicle_doc()
    before = doc.get("rigid_body.mass")
    with pytest.raises(ConfigError) as err:
        doc.candidate({"rigid_body.mass": "-2"})
    assert "rigid_body.mass" in str(err.value) and "positive" in str(err.value)
    assert doc.get("rigid_body.mass") == before
    data, vehicle = doc.candidate({"rigid_body.mass": "7.9"})
    assert vehicle.mass == 7.9 and doc.get("rigid_body.mass") == before  # not committed yet
    doc.commit(data, vehicle)
    assert doc.value.mass == 7.9


def test_saving_keeps_the_comments_and_reloads(tmp_path):
    doc = _vehicle_doc()
    data, v = doc.candidate({"rigid_body.mass": 7.9, "thrusters[name=T3].quadratic.K_L_pos": 0.09,
                             "damping.heave.linear": -6.0})
    doc.commit(data, v)
    path, kept = doc.save(tmp_path / "v.toml")
    assert kept
    text = path.read_text()
    original = doc.origin.read_text()
    assert "# m [kg]" in text and "Sandøy" in text  # comments survive
    assert len(text.splitlines()) == len(original.splitlines())  # layout too
    back = load_vehicle(path)
    assert back.mass == 7.9 and back.damping_linear[2] == -6.0
    assert back.thruster("T3").curve.K_L_pos == 0.09
    # the untouched spelling stays (7.22e-2 is not rewritten as 0.0722)
    assert "K_L_pos = 7.22e-2" in text


def test_a_changed_measurement_list_and_switched_forms_save_and_reload(tmp_path):
    doc = _config_doc()
    keep = [m for m in doc.data["measurements"] if m["sensor"] != "pressure"]
    data, cfg = doc.candidate({"measurements": keep, "process_noise.bias_time_per_mass": None,
                               "process_noise.bias_time_constant": {"w": 1000.0, "r": 20.0}})
    doc.commit(data, cfg)
    path, kept = doc.save(tmp_path / "c.toml")
    assert kept
    back = load_design_config(path)
    assert len(back.measurements) == 2 and back.bias_time_constant == (1000.0, 20.0)
    assert back.bias_time_per_mass is None
    with path.open("rb") as fh:
        assert tomllib.load(fh) == doc.data
