"""The MRAC controller in the HMI, in a real headless browser (Debian's Chromium via Playwright,
as tests/hmi/test_hmi_e2e.py; skipped without it, except in CI): choose MRAC in the Control tab,
tune a gain, and see the adapted parameters plotted live."""

from __future__ import annotations

import json
import os
import time
import urllib.request
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "hmi"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
WAIT_MS = 20000


def _reason() -> str | None:
    if not CHROMIUM.exists():
        return f"{CHROMIUM} is missing (install Debian's chromium: scripts/ensure-chromium.sh)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[dev]')"
    return None


if _reason() is not None:
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the HMI browser tests: {_reason()}", pytrace=False)
    pytest.skip(str(_reason()), allow_module_level=True)

from playwright.sync_api import sync_playwright

from rovlab.interfaces.hmi.server import ServerThread
from rovlab.interfaces.hmi.session import Session


def _state(server) -> dict:
    with urllib.request.urlopen(server.url + "api/state", timeout=10) as r:
        return json.load(r)


def _wait(predicate, what: str, timeout: float = WAIT_MS / 1000):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_mrac_is_offered_tuned_and_its_parameters_plotted(tmp_path):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    session = Session.simulation("heave-buoyancy-step", out_dir=tmp_path / "out", speed=10.0, running=True)
    server = ServerThread(session).start()
    errors: list[str] = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
            page = browser.new_context(viewport={"width": 1600, "height": 1000}).new_page()
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url, wait_until="load")
            page.wait_for_function("() => window.hmi && window.hmi.stats.hellos > 0", timeout=WAIT_MS)
            page.click("#tabs button[data-tab=lqr]")
            page.select_option('select[data-key="controller"]', "mrac")
            _wait(lambda: _state(server)["loop"]["controller"] == "mrac", "MRAC in the loop")
            # its gains appear in the tab, and a change reaches the loop
            ks = page.locator('input[data-target="config"][data-key="mrac.k_s"]')
            ks.wait_for(timeout=WAIT_MS)
            ks.fill("60")
            ks.press("Enter")
            _wait(lambda: _state(server)["loop"]["mrac"]["k_s"] == 60.0, "the new k_s in the loop")
            page.wait_for_function("() => document.querySelector('#loop-lqr').textContent.includes('MRAC (heave)')",
                                   timeout=WAIT_MS)
            # the adapted parameters are plotted live
            page.wait_for_function("() => hmi.charts.mrac_F && hmi.charts.mrac_F.get('F_hat').ring.length > 10",
                                   timeout=WAIT_MS)
            assert page.evaluate("hmi.charts.mrac_M.get('M_hat').ring.length > 10")
            assert page.evaluate("hmi.charts.z.get('zm').ring.length > 10")
            page.screenshot(path=str(ARTIFACTS / "mrac.png"))
            browser.close()
    finally:
        server.stop()
    assert errors == []
