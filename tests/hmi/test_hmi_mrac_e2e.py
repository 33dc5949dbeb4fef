"""The MRAC controller in the HMI, in a real headless browser (Debian's Chromium via Playwright,
as tests/hmi/test_hmi_e2e.py; skipped without it, except in CI): choose MRAC in the Control tab,
tune a gain, and see the adapted parameters plotted live."""

from __future__ import annotations

from rovlab.interfaces.hmi.server import ServerThread
from rovlab.interfaces.hmi.session import Session

WAIT_MS = 20000


def test_mrac_is_offered_tuned_and_its_parameters_plotted(tmp_path, browser, artifacts, hmi_state, hmi_wait):
    session = Session.simulation("heave-buoyancy-step", out_dir=tmp_path / "out", speed=10.0, running=True)
    server = ServerThread(session).start()
    errors: list[str] = []
    try:
        context = browser.new_context(viewport={"width": 1600, "height": 1000})
        try:
            page = context.new_page()
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url, wait_until="load")
            page.wait_for_function("() => window.hmi && window.hmi.stats.hellos > 0", timeout=WAIT_MS)
            page.click("#tabs button[data-tab=lqr]")
            page.select_option('select[data-key="controller"]', "mrac")
            hmi_wait(lambda: hmi_state(server)["loop"]["controller"] == "mrac", "MRAC in the loop")
            # its gains appear in the tab, and a change reaches the loop
            ks = page.locator('input[data-target="config"][data-key="mrac.k_s"]')
            ks.wait_for(timeout=WAIT_MS)
            ks.fill("60")
            ks.press("Enter")
            hmi_wait(lambda: hmi_state(server)["loop"]["mrac"]["k_s"] == 60.0, "the new k_s in the loop")
            page.wait_for_function("() => document.querySelector('#loop-lqr').textContent.includes('MRAC (heave)')",
                                   timeout=WAIT_MS)
            # the adapted parameters are plotted live
            page.wait_for_function("() => hmi.charts.mrac_F && hmi.charts.mrac_F.get('F_hat').ring.length > 10",
                                   timeout=WAIT_MS)
            assert page.evaluate("hmi.charts.mrac_M.get('M_hat').ring.length > 10")
            assert page.evaluate("hmi.charts.z.get('zm').ring.length > 10")
            page.screenshot(path=str(artifacts / "mrac.png"))
        finally:
            context.close()
    finally:
        server.stop()
    assert errors == []
