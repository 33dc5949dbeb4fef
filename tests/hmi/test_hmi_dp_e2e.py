"""Dynamic positioning in the HMI, in a real headless browser (Debian's Chromium via Playwright,
as tests/hmi/test_hmi_e2e.py; skipped without it, except in CI): a DP scenario shows north/east
set-point fields and a live xy track, and a set-point typed on the page reaches the loop; no label
of the side panel is cut."""

from __future__ import annotations

from rovlab.interfaces.hmi.server import ServerThread
from rovlab.interfaces.hmi.session import Session

WAIT_MS = 20000


def test_dp_set_points_and_the_live_xy_track(tmp_path, browser, artifacts, hmi_state, hmi_wait):
    session = Session.simulation("dp-square", out_dir=tmp_path / "out", speed=10.0, running=True)
    server = ServerThread(session).start()
    errors: list[str] = []
    try:
        context = browser.new_context(viewport={"width": 1600, "height": 1000})
        try:
            page = context.new_page()
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
            # a set-point typed on the page reaches the loop, both fields even with a live refresh
            # between typing them (issue 28: the refresh put the live value back into the field
            # that had lost the focus, and Set sent the other one only)
            page.fill("#ref-north", "1.25")
            page.fill("#ref-east", "-0.75")
            page.evaluate("() => { window.__state0 = hmi.state; }")
            page.wait_for_function("() => hmi.state !== window.__state0", timeout=WAIT_MS)
            page.click("#ref-set")
            hmi_wait(lambda: (hmi_state(server)["reference"]["north_m"], hmi_state(server)["reference"]["east_m"])
                     == (1.25, -0.75), "the north/east set-point in the loop")
            assert hmi_state(server)["reference"]["schedule"] is False
            # a bad value is refused with a message naming the field
            page.fill("#ref-north", "far")
            page.click("#ref-set")
            page.wait_for_function("() => document.querySelector('#ref-msg').textContent.includes('north_m')",
                                   timeout=WAIT_MS)
            assert "bad" in (page.get_attribute("#ref-north", "class") or "")
            page.screenshot(path=str(artifacts / "dp-track.png"))
            # no label, unit or selector of any tab is cut (issue 28: the Observer tab's were,
            # e.g. "spread a returning sensor'..."); DP has the most fields of any scenario
            for tab in ("run", "vehicle", "truth", "observer", "lqr", "files"):
                page.click(f"#tabs button[data-tab={tab}]")
                cut = page.evaluate("""() => [...document.querySelectorAll(
                        '.tab:not([hidden]) .field-label, .tab:not([hidden]) .unit, .tab:not([hidden]) h4')]
                    .filter((e) => e.scrollWidth > e.clientWidth + 1 || e.scrollHeight > e.clientHeight + 1)
                    .map((e) => e.textContent)""")
                assert cut == [], (tab, cut)
                overflow = page.evaluate("""() => { const p = document.querySelector('aside.panel');
                    return [...p.querySelectorAll('.tab:not([hidden]) *')].filter((e) => e.offsetParent !== null
                        && e.getBoundingClientRect().right > p.getBoundingClientRect().right + 0.5
                        && !e.closest('.matrix')).map((e) => e.tagName + ' ' + (e.textContent || '').slice(0, 40)); }""")
                assert overflow == [], (tab, overflow)
                if tab == "observer":
                    page.locator("aside.panel").screenshot(path=str(artifacts / "observer-tab.png"))
        finally:
            context.close()
    finally:
        server.stop()
    assert errors == []
