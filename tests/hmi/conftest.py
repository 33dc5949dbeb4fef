"""Fixtures of the HMI tests: a paused simulation session writing into a temporary folder, and the
headless browser of the end-to-end tests with its helpers."""

from __future__ import annotations

import json
import os
import time
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("aiohttp", reason="the HMI needs the 'hmi' extra (aiohttp)")


@pytest.fixture
def session(tmp_path):
    from rovlab.interfaces.hmi.session import Session

    return Session.simulation("step-process-model", out_dir=tmp_path / "out", running=False)


# --------------------------------------------------------------------------------------------
# The real browser of the end-to-end tests: Debian's Chromium (/usr/bin/chromium) driven by
# Playwright. We never download a browser (no `playwright install`); without Chromium the tests
# that ask for it skip with the reason, except in CI (environment variable CI set), where they fail.
# --------------------------------------------------------------------------------------------

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "hmi"  # screenshots, kept by CI
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
WAIT_MS = 20000


def _missing_browser() -> str | None:
    if not CHROMIUM.exists():
        return f"{CHROMIUM} is missing (install Debian's chromium: scripts/ensure-chromium.sh)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[dev]')"
    return None


@pytest.fixture(scope="module")
def browser():
    reason = _missing_browser()
    if reason is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the HMI browser tests: {reason}", pytrace=False)
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    # Playwright gives every launch a fresh, empty profile (its own --user-data-dir)
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        yield b
        b.close()


def state_of(server) -> dict:
    """The HMI's /api/state."""
    with urllib.request.urlopen(server.url + "api/state", timeout=10) as r:
        return json.load(r)


def wait_until(predicate, what: str = "condition", timeout: float = WAIT_MS / 1000):
    """predicate's first truthy value within timeout seconds (AssertionError naming what, else)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def hmi_state():
    return state_of


@pytest.fixture
def hmi_wait():
    return wait_until


@pytest.fixture
def artifacts():
    """Where end-to-end tests put their screenshots (test-artifacts/hmi)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS
