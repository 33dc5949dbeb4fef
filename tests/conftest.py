"""Shared fixtures. Every random test takes its seed from here or states it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# The filter's ahead-of-time kernels (rovlab._aot) are tested in tests/estimation/test_aot.py,
# in their own cache folder; elsewhere the JIT kernels run (the same numbers) and no test's
# `rovlab filter` starts a background build that could outlive the test run.
os.environ["ROVLAB_AOT"] = "0"

from rovlab.params import load_vehicle

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def udrone():
    return load_vehicle("udrone")


@pytest.fixture(scope="session")
def heavy():
    return load_vehicle("bluerov2_heavy")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(20161)
