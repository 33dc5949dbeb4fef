"""End-to-end tests of the HMI in a real headless browser: Debian's Chromium (/usr/bin/chromium)
driven by Playwright. We never download a browser (no `playwright install`); without Chromium
these tests skip with the reason, except in CI (environment variable CI set), where they fail.

Screenshots go to test-artifacts/hmi/ (kept by CI as artifacts of the test output folder).
"""

from __future__ import annotations

import json
import time
import urllib.request
from pathlib import Path

import pytest

from rovlab.interfaces.hmi.server import ServerThread
from rovlab.interfaces.hmi.session import Session
from rovlab.params.vehicle import load_vehicle

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "hmi"  # as conftest's: the Page helper saves here
WAIT_MS = 20000


def _serve(tmp_path, **kwargs):
    options = {"out_dir": tmp_path / "out", "speed": 5.0, "running": True}
    options.update(kwargs)
    session = Session.simulation("step-process-model", **options)
    return ServerThread(session).start()


@pytest.fixture
def server(tmp_path):
    st = _serve(tmp_path)
    yield st
    st.stop()


class Page:
    """A page of the HMI with what it asked for from the network, and its console errors."""

    def __init__(self, browser, url: str):
        self.context = browser.new_context(viewport={"width": 1600, "height": 1000})
        self.local = url.rstrip("/")
        self.requests: list[str] = []
        self.external: list[str] = []
        self.errors: list[str] = []

        def route(r):
            self.requests.append(r.request.url)
            if r.request.url.startswith(self.local + "/"):
                r.continue_()
            else:  # nothing may come from anywhere else; block and remember it
                self.external.append(r.request.url)
                r.abort()

        self.context.route("**/*", route)
        self.page = self.context.new_page()
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("websocket", lambda ws: self.requests.append(ws.url))

    def open(self):
        t0 = time.perf_counter()
        self.page.goto(self.local + "/", wait_until="load")
        self.load_s = time.perf_counter() - t0
        self.page.wait_for_function("() => window.hmi && window.hmi.stats.hellos > 0", timeout=WAIT_MS)
        return self

    def tab(self, name: str):
        self.page.click(f"#tabs button[data-tab={name}]")

    def field(self, target: str, key: str):
        return self.page.locator(f'input[data-target="{target}"][data-key="{key}"]')

    def shot(self, name: str):
        self.page.screenshot(path=str(ARTIFACTS / f"{name}.png"))

    def close(self):
        self.context.close()


@pytest.fixture
def page(browser, server):
    p = Page(browser, server.url).open()
    yield p
    p.close()


def _state(server) -> dict:
    with urllib.request.urlopen(server.url + "api/state", timeout=10) as r:
        return json.load(r)


def _wait(predicate, timeout=WAIT_MS / 1000, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_the_page_loads_with_no_external_requests(page):
    assert page.external == []
    kinds = sorted(u.rsplit("/", 1)[-1] for u in page.requests)
    assert kinds == ["", "app.js", "plot.js", "style.css", "ws"]
    assert all(u.startswith(("http://127.0.0.1:", "ws://127.0.0.1:")) for u in page.requests)
    assert "step-process-model" in page.page.inner_text("#title")
    assert page.page.inner_text("#conn") == "online"
    assert page.errors == []
    print(f"page load: {page.load_s * 1000:.0f} ms")  # measured in benchmarks/bench_hmi.py


def test_the_plots_update(page, server):
    p = page.page
    p.wait_for_function("() => hmi.stats.lastT > 2 && hmi.stats.draws > 3", timeout=WAIT_MS)
    before = p.evaluate("[hmi.stats.lastT, hmi.stats.draws, hmi.charts.z.get('est').ring.length]")
    p.wait_for_function(f"() => hmi.stats.lastT > {before[0] + 2} && hmi.stats.draws > {before[1] + 3}", timeout=WAIT_MS)
    after = p.evaluate("[hmi.stats.lastT, hmi.stats.draws, hmi.charts.z.get('est').ring.length]")
    assert after[2] > before[2]
    for name in ("z", "psi", "w", "r", "b_w", "b_r", "tau_Z", "tau_N", "pwm"):
        assert p.evaluate(f"hmi.charts['{name}'].series.some(s => s.ring.length > 0)"), name
    # the canvas really has ink on it (not a blank white box)
    inked = p.evaluate("""(() => { const c = document.querySelector('[data-chart=z] canvas');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
        for (let i = 0; i < d.length; i += 4) if (d[i] < 200 && d[i + 3] > 0) n++; return n; })()""")
    assert inked > 500
    assert _state(server)["time_s"] >= after[0]
    badges = p.locator("#badges .badge")
    assert badges.count() == 3
    page.shot("plots")


def test_a_parameter_change_reaches_the_loop(page, server):
    page.tab("vehicle")
    mass = page.field("vehicle", "rigid_body.mass")
    assert mass.input_value() == "7.31"
    mass.fill("7.9")
    mass.press("Enter")
    _wait(lambda: _state(server)["loop"]["vehicle"]["mass"] == 7.9, what="the model mass in the loop")
    assert _state(server)["loop"]["truth"]["mass"] == 7.31  # the plant keeps its own
    page.tab("lqr")
    zmax = page.field("config", "lqr.state_max.z")
    k_before = _state(server)["loop"]["K"][0][0]
    zmax.fill("0.5")
    zmax.press("Enter")
    _wait(lambda: _state(server)["loop"]["K"][0][0] > 2 * k_before, what="new LQR gains")
    shown = f"{_state(server)['loop']['K'][0][0]:.5g}"[:4]  # the page shows the new gain
    page.page.wait_for_function("(s) => document.querySelector('#loop-lqr').textContent.includes(s)",
                                arg=shown, timeout=WAIT_MS)
    page.shot("lqr-tuned")


def test_a_bad_value_is_rejected_with_a_message(page, server):
    page.tab("vehicle")
    mass = page.field("vehicle", "rigid_body.mass")
    msg = page.page.locator('[data-msg-for="vehicle:rigid_body.mass"]')
    for bad, words in (("-3", "expected a positive number"), ("abc", "expected a number"),
                       ("nan", "expected a finite number")):
        mass.fill(bad)
        mass.press("Enter")
        page.page.wait_for_function(
            f"() => document.querySelector('[data-msg-for=\"vehicle:rigid_body.mass\"]').textContent.includes('{words}')",
            timeout=WAIT_MS)
        assert "rigid_body.mass" in msg.inner_text()
        assert "bad" in mass.get_attribute("class")
        assert _state(server)["loop"]["vehicle"]["mass"] == 7.31  # the running loop is untouched
    page.shot("bad-value")
    # positive damping on the plant, a negative variance, an unobservable sensor set
    page.tab("truth")
    damp = page.field("truth", "damping.heave.linear")
    damp.fill("4")
    damp.press("Enter")
    page.page.wait_for_function("() => [...document.querySelectorAll('#form-truth .field-msg')]"
                                ".some(e => e.textContent.includes('damping is <= 0'))", timeout=WAIT_MS)
    page.tab("observer")
    var = page.field("config", "measurements[1].variance")
    var.fill("-1e-4")
    var.press("Enter")
    page.page.wait_for_function("() => [...document.querySelectorAll('#form-observer .field-msg')]"
                                ".some(e => e.textContent.includes('positive'))", timeout=WAIT_MS)
    page.page.click('input[data-measurement="qualisys:psi"]')
    page.page.wait_for_function("() => [...document.querySelectorAll('#form-observer .field-msg')]"
                                ".some(e => e.textContent.includes('cannot be estimated'))", timeout=WAIT_MS)
    assert page.page.is_checked('input[data-measurement="qualisys:psi"]')  # put back: refused
    state = _state(server)
    assert set(state["loop"]["R"]) == {"qualisys.z", "pressure.z", "qualisys.psi"}
    assert state["loop"]["truth"]["damping_linear"][2] == -5.18
    page.shot("bad-observer")


def test_a_sensor_switch_gives_dead_reckoning_and_recovery(page, server):
    p = page.page
    p.wait_for_function("() => hmi.stats.lastT > 8", timeout=WAIT_MS)  # past the initial transient
    p.click('button[data-sensor="qualisys"]')
    badge = '#badges .badge[data-channel="qualisys.psi"]'
    p.wait_for_selector(f'{badge}[data-status="lost"]', timeout=WAIT_MS)
    assert p.get_attribute('#badges .badge[data-channel="pressure.z"]', "data-status") == "ok"
    state = _state(server)
    assert state["sensors"]["qualisys"] is False
    v0 = state["latest"]["/rovlab/estimate"]["variance"]["psi"]
    _wait(lambda: _state(server)["latest"]["/rovlab/estimate"]["variance"]["psi"] > 10 * v0,
          what="the heading variance to grow (dead reckoning)")
    page.shot("dead-reckoning")
    p.click('button[data-sensor="qualisys"]')
    p.wait_for_selector(f'{badge}[data-status="recovering"]', timeout=WAIT_MS)
    p.wait_for_selector(f'{badge}[data-status="ok"]', timeout=WAIT_MS)
    assert _state(server)["sensors"]["qualisys"] is True
    page.shot("recovered")


def test_a_saved_file_reloads(page, server, browser, tmp_path):
    page.tab("vehicle")
    izz = page.field("vehicle", "rigid_body.I_zz")
    izz.fill("0.21")
    izz.press("Enter")
    _wait(lambda: _state(server)["loop"]["vehicle"]["I_zz"] == 0.21, what="I_zz in the loop")
    page.tab("files")
    page.page.click('button[data-save="all"]')
    page.page.wait_for_selector("#saved li a", timeout=WAIT_MS)
    paths = page.page.eval_on_selector_all("#saved li a", "els => els.map(e => e.title)")
    vehicle_file = next(p for p in paths if Path(p).name.startswith("vehicle-"))
    config_file = next(p for p in paths if Path(p).name.startswith("config-"))
    assert load_vehicle(vehicle_file).I_zz == 0.21
    assert "# yaw moment of inertia" in Path(vehicle_file).read_text()  # comments kept
    page.shot("saved")
    # a new HMI on the saved files shows the tuned value
    again = _serve(tmp_path / "again", vehicle=vehicle_file, config=config_file, running=False)
    try:
        p2 = Page(browser, again.url).open()
        p2.tab("vehicle")
        assert p2.field("vehicle", "rigid_body.I_zz").input_value() == "0.21"
        p2.close()
    finally:
        again.stop()


def test_controls_start_pause_reset_speed_and_export(page, server):
    p = page.page
    p.wait_for_function("() => hmi.stats.lastT > 1", timeout=WAIT_MS)
    p.click("#btn-run")  # pause
    _wait(lambda: _state(server)["running"] is False, what="pause")
    t = _state(server)["time_s"]
    p.click("#btn-step")
    _wait(lambda: _state(server)["time_s"] > t, what="one step")
    p.select_option("#speed", "20")
    _wait(lambda: _state(server)["speed"] == 20.0, what="speed")
    p.click("#btn-run")
    _wait(lambda: _state(server)["time_s"] > t + 5, what="running at 20x")
    p.click("#btn-reset")
    p.wait_for_function("() => hmi.charts.z.get('est').ring.length < 30", timeout=WAIT_MS)
    page.tab("run")
    p.fill("#ref-depth", "0.4")
    p.fill("#ref-heading", "-45")
    p.click("#ref-set")
    _wait(lambda: abs(_state(server)["reference"]["heading_deg"] + 45) < 1e-9, what="reference")
    p.fill("#ref-depth", "deep")
    p.click("#ref-set")
    p.wait_for_function("() => document.querySelector('#ref-msg').textContent.includes('depth_m')", timeout=WAIT_MS)
    page.tab("files")
    p.click("#export")
    p.wait_for_selector("#exported li a", timeout=WAIT_MS)
    names = p.eval_on_selector_all("#exported li a", "els => els.map(e => e.textContent)")
    assert any(n.endswith(".csv") for n in names) and any(n.endswith("-events.json") for n in names)
    assert page.errors == []


# --------------------------------------------------------------------------------------------
# Issue 28: what a new user hit on the Run tab and in the heading plot
# --------------------------------------------------------------------------------------------

def _next_state_frame(p):
    """Wait for the next state frame (the server sends one a second): the live refresh of the page."""
    p.evaluate("() => { window.__state0 = hmi.state; }")
    p.wait_for_function("() => hmi.state !== window.__state0", timeout=WAIT_MS)


def test_set_sends_every_edited_reference_and_the_refresh_keeps_what_was_typed(page, server):
    p = page.page
    page.tab("run")
    # the step scenario's LQG holds depth and heading: no north/east fields (they used to show, and
    # what was typed there went nowhere)
    assert not p.locator("#ref-north").is_visible() and not p.locator("#ref-east").is_visible()
    p.fill("#ref-depth", "0.45")
    p.fill("#ref-heading", "-45")  # the focus moves on: depth is no longer focused
    _next_state_frame(p)
    # the refresh used to put the live 0.7 back into the unfocused depth field, so Set sent the heading only
    assert p.input_value("#ref-depth") == "0.45" and "edited" in (p.get_attribute("#ref-depth", "class") or "")
    assert p.get_attribute("#ref-depth", "placeholder") == "0.7"  # the live value stays in view
    p.click("#ref-set")
    _wait(lambda: _state(server)["reference"]["depth_m"] == 0.45
          and abs(_state(server)["reference"]["heading_deg"] + 45) < 1e-9, what="depth and heading in the loop")
    # an absurd heading is refused with the server's reason under the fields, nothing changes
    p.fill("#ref-heading", "1e308")
    p.press("#ref-heading", "Enter")
    p.wait_for_function("() => document.querySelector('#ref-msg').textContent.includes("
                        "'heading_deg must be within -720 .. 720 deg')", timeout=WAIT_MS)
    assert "bad" in p.get_attribute("#ref-heading", "class")
    _next_state_frame(p)
    assert p.input_value("#ref-heading") == "1e308"  # kept for correction, not replaced by the refresh
    assert abs(_state(server)["reference"]["heading_deg"] + 45) < 1e-9
    page.shot("reference-refused")
    p.press("#ref-heading", "Escape")  # cancel the edit: the live value comes back
    assert p.input_value("#ref-heading") == "-45"
    assert page.errors == []


_PLOT_PAGE = "<!doctype html><html><body><canvas id=c style='width:600px;height:240px;display:block'></canvas></body></html>"
_HEADING = """(values) => {
    const c = new RovPlot.StripChart(document.getElementById('c'), {title: 'heading', unit: 'deg', minSpan: 2,
                                                                    period: 360});
    c.add({name: 'band', kind: 'band'}); c.add({name: 'est'}); c.add({name: 'meas', kind: 'dots'});
    c.add({name: 'ref', kind: 'step'});
    const wrap = (a) => a - 360 * Math.ceil((a - 180) / 360);  // as the messages give it: (-180, 180]
    values.forEach((v, k) => { const t = 0.1 * k, w = wrap(v);
        c.push('est', t, w); c.pushBand('band', t, w - 1, w + 1); c.push('meas', t, wrap(v + 0.3)); c.push('ref', t, 180); });
    const labels = [];
    const fill = c.ctx.fillText.bind(c.ctx);
    c.ctx.fillText = (text, x, y) => { labels.push(text); fill(text, x, y); };
    c.draw();
    return {view: c.view, labels: labels.filter((s) => /^-?[0-9.]+$/.test(s)).map(Number).filter((_, i, a) => i < a.length)};
}"""


def test_a_heading_about_180_deg_is_one_line_and_a_full_turn_is_not_drawn_across_the_plot(browser):
    plot_js = (Path(__file__).resolve().parents[2] / "src/rovlab/interfaces/hmi/static/plot.js").read_text()
    context = browser.new_context(viewport={"width": 700, "height": 300})
    try:
        p = context.new_page()
        p.set_content(_PLOT_PAGE)
        p.add_script_tag(content=plot_js)
        # held at 180 deg: the truth dithers across +-180 (the messages wrap it); it used to be drawn
        # as 360 deg steps on a chart spanning -180 .. 180
        import math
        held = [180.0 + 1.5 * math.sin(0.7 * k) for k in range(300)]
        out = p.evaluate(_HEADING, held)
        view = out["view"]
        assert view["y1"] - view["y0"] < 10 and view["breaks"] == 0, view
        assert abs(abs(view["center"]) - 180) < 2
        ticks = [x for x in out["labels"] if abs(x) > 100]  # the y labels (time labels are 0 .. 30 s)
        assert ticks and all(-180 < x <= 180 for x in ticks) and min(ticks) < 0 < max(ticks), ticks
        # two full turns in 60 s: the line leaves at one edge and comes back at the other
        turning = [12.0 * 0.1 * k for k in range(600)]
        view = p.evaluate(_HEADING, turning)["view"]
        assert view["breaks"] >= 2 and view["y1"] - view["y0"] <= 1.2 * 360, view  # the estimate and its band
    finally:
        context.close()
