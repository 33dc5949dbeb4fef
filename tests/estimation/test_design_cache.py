"""`rovlab filter` loads its filter design from disk after the first run (cached_filter_model): the
same model, designed afresh whenever the vehicle, the configuration or rovlab's sources change."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rovlab.estimation import model as model_module
from rovlab.estimation.model import build_filter_model, cached_filter_model
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    return tmp_path / "rovlab" / "design"


def test_stored_once_then_loaded(cache, monkeypatch):
    vehicle, config = load_vehicle("udrone"), load_design_config("default")
    first = cached_filter_model(vehicle, config)
    assert len(list(cache.iterdir())) == 1
    fresh = build_filter_model(vehicle, config)
    for name in ("Phi", "Delta", "Q", "H", "R", "x0", "P0"):
        np.testing.assert_array_equal(getattr(first, name), getattr(fresh, name))
    assert [repr(c) for c in first.channels] == [repr(c) for c in fresh.channels]

    def no_design(*args, **kwargs):
        raise AssertionError("designed again")

    monkeypatch.setattr(model_module, "build_filter_model", no_design)
    again = cached_filter_model(vehicle, config)
    np.testing.assert_array_equal(again.Phi, first.Phi)


def test_another_configuration_is_designed_afresh(cache):
    vehicle, config = load_vehicle("udrone"), load_design_config("default")
    cached_filter_model(vehicle, config)
    other = dataclasses.replace(config, sample_time=config.sample_time / 2)
    model = cached_filter_model(vehicle, other)
    assert model.h == other.sample_time and len(list(cache.iterdir())) == 2


def test_a_damaged_file_is_designed_afresh(cache):
    vehicle, config = load_vehicle("udrone"), load_design_config("default")
    cached_filter_model(vehicle, config)
    (path,) = cache.iterdir()
    path.write_bytes(b"not a pickle")
    model = cached_filter_model(vehicle, config)
    np.testing.assert_array_equal(model.Phi, build_filter_model(vehicle, config).Phi)
