"""Make docs/hmi.png: the HMI in Debian's Chromium (Playwright, as the end-to-end tests) during a
motion-capture drop-out and its recovery, driven through the page as a user would.

    .venv/bin/python tests/hmi/docs_screenshot.py [OUT.png]     (default: docs/hmi.png)

The story (docs/hmi.md's caption): ``step-process-model`` (seed 2) at 3x real time, a 1600 x 1000
window; at t = 15 s the plant's displaced volume is raised in the Plant tab by 1 N of buoyancy
(1 N / (rho g) with the plant's own rho and g), which the model does not know; from t = 28 s to
42 s Qualisys is switched off in the Run tab; the picture is taken at t = 59 s with the Run tab
open. It takes about 25 s of wall time. Not a test (pytest does not collect it).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from playwright.sync_api import sync_playwright

from rovlab.interfaces.hmi.server import ServerThread
from rovlab.interfaces.hmi.session import Session

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
WAIT_MS = 120_000


def main(out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        session = Session.simulation("step-process-model", out_dir=tmp, speed=3.0, running=False)
        truth = session.documents["truth"].data
        env = truth.get("environment", {})
        rho, g = float(env.get("water_density", 1000.0)), float(env.get("gravity", 9.81))
        volume = float(truth["restoring"]["displaced_volume"]) + 1.0 / (rho * g)  # +1 N of buoyancy
        server = ServerThread(session).start()
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                            args=["--no-sandbox", "--disable-gpu"])
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(server.url, wait_until="load")
                page.wait_for_function("() => window.hmi && hmi.stats.hellos > 0", timeout=WAIT_MS)
                page.click("#btn-run")

                def at(t: float) -> None:
                    page.wait_for_function(f"() => hmi.stats.lastT >= {t}", timeout=WAIT_MS)

                at(15.0)
                page.click("#tabs button[data-tab=truth]")
                field = page.locator('input[data-target="truth"][data-key="restoring.displaced_volume"]')
                field.fill(f"{volume:.6g}")
                field.press("Enter")
                page.click("#tabs button[data-tab=run]")
                at(28.0)
                page.click('button[data-sensor="qualisys"]')
                at(42.0)
                page.click('button[data-sensor="qualisys"]')
                at(59.0)
                page.screenshot(path=str(out))
                browser.close()
        finally:
            server.stop()
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "hmi.png")
