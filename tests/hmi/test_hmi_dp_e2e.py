"""Dynamic positioning in the HMI, in a real headless browser (Debian's Chromium via Playwright,
as tests/hmi/test_hmi_e2e.py; skipped without it, except in CI): a DP scenario shows north/east
set-point fields and a live xy track, and a set-point typed on the page reaches the loop."""

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


def test_dp_set_points_and_the_live_xy_track(tmp_path):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    session = Session.simulation("dp-square", out_dir=tmp_path / "out", speed=10.0, running=True)
    server = ServerThread(session).start()
    errors: list[str] = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
            page = browser.new_context(viewport={"width": 1600, "height": 1000}).new_page()
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(server.url, wait_until="load")
            page.wait_for_function("() => window.hmi && window.hmi.stats.hellos > 0", timeout=WAIT_MS)
            # the position set-point fields are shown for the DP controller
            page.locator("#ref-north").wait_for(state="visible", timeout=WAIT_MS)
            assert page.locator("#ref-east").is_visible()
            # the xy track fills with the truth, the estimate and the reference model
            page.wait_for_function("() => hmi.charts.track && hmi.charts.track.get('est').ring.length > 20 "
                                   "&& hmi.charts.track.get('truth').ring.length > 20 "
                                   "&& hmi.charts.track.get('ref_model').ring.length > 20", timeout=WAIT_MS)
            page.wait_for_function("() => hmi.charts.track.points > 60", timeout=WAIT_MS)
            inked = page.evaluate("""(() => { const c = document.querySelector('[data-chart=track] canvas');
                const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
                for (let i = 0; i < d.length; i += 4) if (d[i] < 200 && d[i + 3] > 0) n++; return n; })()""")
            assert inked > 300
            # a set-point typed on the page reaches the loop
            # (both fields in one turn of the page: a state update between two fills re-renders the
            # field that lost focus, as it should for a user who has not pressed Set)
            page.evaluate("""() => { document.querySelector('#ref-north').value = '1.25';
                document.querySelector('#ref-east').value = '-0.75';
                document.querySelector('#ref-set').click(); }""")
            _wait(lambda: _state(server)["reference"]["north_m"] == 1.25 and _state(server)["reference"]["east_m"] == -0.75,
                  "the north/east set-point in the loop")
            assert _state(server)["reference"]["schedule"] is False
            # a bad value is refused with a message naming the field
            page.fill("#ref-north", "far")
            page.click("#ref-set")
            page.wait_for_function("() => document.querySelector('#ref-msg').textContent.includes('north_m')",
                                   timeout=WAIT_MS)
            assert "bad" in (page.get_attribute("#ref-north", "class") or "")
            page.screenshot(path=str(ARTIFACTS / "dp-track.png"))
            browser.close()
    finally:
        server.stop()
    assert errors == []
