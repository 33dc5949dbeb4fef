"""Shared fixtures. Every random test takes its seed from here or states it."""

from __future__ import annotations

from pathlib import Path

import pytest

from rovlab.params import load_vehicle

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def udrone():
    return load_vehicle("udrone")


@pytest.fixture(scope="session")
def heavy():
    return load_vehicle("bluerov2_heavy")


@pytest.fixture(scope="session")
def udrone_dvl():
    """uDrone with the DVL its dynamic-positioning scenarios use."""
    return load_vehicle("udrone_dvl")


@pytest.fixture(scope="session")
def udrone_dp():
    """The EKF + DP design of uDrone's dynamic-positioning scenarios."""
    from rovlab.params.design import load_design_config

    return load_design_config("udrone_dp")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(20161)
