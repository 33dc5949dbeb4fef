"""Fixtures of the HMI tests: a paused simulation session writing into a temporary folder."""

from __future__ import annotations

import pytest

pytest.importorskip("aiohttp", reason="the HMI needs the 'hmi' extra (aiohttp)")


@pytest.fixture
def session(tmp_path):
    from rovlab.interfaces.hmi.session import Session

    return Session.simulation("step-process-model", out_dir=tmp_path / "out", running=False)
