"""HMI benchmark: page load time in Chromium, and how well the server keeps real time while it
streams to several clients.

Starts ``rovlab hmi`` as its own process (as a user would), then

1. loads the page N times in headless Chromium (Debian's /usr/bin/chromium driven by Playwright,
   a fresh context each time): navigation to the load event, to the first data frame, to the
   first plotted data;
2. paces the default scenario at 1x real time (10 Hz control steps) for ``--seconds`` with one
   browser page plotting and ``--clients`` extra WebSocket clients, then at 10x: the lag of each
   published step behind its due wall time and the compute time per step (the server's own
   statistics), frames received per client, whether the simulated time kept up with the wall
   clock, and how far the page's plots trailed the server.

Prints numbers only; nothing here asserts a wall-clock bound. Run: ``python benchmarks/bench_hmi.py``
(``make bench`` runs it with the others).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def start_server(out: Path, speed: float) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "rovlab.interfaces.cli", "hmi", "--port", "0", "--speed", str(speed),
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        m = re.search(r"http://127\.0\.0\.1:\d+/", line)
        if m:
            return proc, m.group(0)
    proc.kill()
    raise RuntimeError("rovlab hmi did not start: " + proc.stderr.read())


def ms(x: float | None) -> str:
    return "-" if x is None else f"{x * 1000:.1f} ms"


def dist(values: list[float]) -> str:
    if not values:
        return "-"
    v = sorted(values)
    def q(p):
        return v[min(len(v) - 1, int(p * (len(v) - 1) + 0.5))]
    return f"median {ms(q(0.5))}, p90 {ms(q(0.9))}, p99 {ms(q(0.99))}, max {ms(v[-1])} (n={len(v)})"


async def page_loads(browser, url: str, n: int) -> None:
    loads, firsts, plotted = [], [], []
    for _ in range(n):
        ctx = await browser.new_context(viewport={"width": 1600, "height": 1000})
        page = await ctx.new_page()
        t0 = time.perf_counter()
        await page.goto(url, wait_until="load")
        t_load = time.perf_counter() - t0
        await page.wait_for_function("() => window.hmi && window.hmi.stats.frames > 0")
        t_first = time.perf_counter() - t0
        await page.wait_for_function("() => window.hmi.stats.draws > 0 && window.hmi.stats.frames > 0")
        t_plot = time.perf_counter() - t0
        nav = await page.evaluate("() => { const e = performance.getEntriesByType('navigation')[0];"
                                  " return [e.domContentLoadedEventEnd, e.loadEventEnd]; }")
        loads.append(t_load)
        firsts.append(t_first)
        plotted.append(t_plot)
        await ctx.close()
    print(f"page load (goto -> load event): {dist(loads)}")
    print(f"  browser's own timing of the last load: DOMContentLoaded {nav[0]:.0f} ms, load {nav[1]:.0f} ms")
    print(f"  to the first data frame:        {dist(firsts)}")
    print(f"  to the first plotted data:      {dist(plotted)}")


async def ws_client(url: str, stop: asyncio.Event, record: dict) -> None:
    import aiohttp

    async with aiohttp.ClientSession() as http, http.ws_connect(url.replace("http", "ws") + "ws") as ws:
        record.update(frames=0, rows=0, gaps=[], last=None)
        while not stop.is_set():
            try:
                msg = await ws.receive(timeout=0.5)
            except TimeoutError:
                continue
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            frame = json.loads(msg.data)
            if frame["type"] == "data":
                now = time.perf_counter()
                if record["last"] is not None:
                    record["gaps"].append(now - record["last"])
                record["last"] = now
                record["frames"] += 1
                record["rows"] += frame["rows"]


async def state(url: str) -> dict:
    import aiohttp

    async with aiohttp.ClientSession() as http, http.get(url + "api/state") as r:
        return await r.json()


async def pacing(browser, url: str, seconds: float, clients: int, speed: float) -> None:
    ctx = await browser.new_context(viewport={"width": 1600, "height": 1000})
    page = await ctx.new_page()
    await page.goto(url, wait_until="load")
    await page.wait_for_function("() => window.hmi && window.hmi.stats.frames > 0")
    stop = asyncio.Event()
    records: list[dict] = [{} for _ in range(clients)]
    tasks = [asyncio.create_task(ws_client(url, stop, r)) for r in records]
    await asyncio.sleep(1.0)  # everyone connected
    before = await state(url)
    draws0 = await page.evaluate("() => window.hmi.stats.draws")
    trail = []
    w0 = time.perf_counter()
    while time.perf_counter() - w0 < seconds:
        await asyncio.sleep(0.5)
        s = await state(url)
        page_t = await page.evaluate("() => window.hmi.stats.lastT")
        trail.append(max(0.0, s["time_s"] - 0.1 - page_t))  # sim seconds the page's plots are behind
    wall = time.perf_counter() - w0
    after = await state(url)
    draws = await page.evaluate("() => window.hmi.stats.draws") - draws0
    stop.set()
    await asyncio.gather(*tasks)
    await ctx.close()
    p = after["pacing"]
    sim = after["time_s"] - before["time_s"]
    steps = p["steps"] - before["pacing"]["steps"]
    print(f"\n== pacing at {speed:g}x real time, {wall:.1f} s, 1 browser page + {clients} WebSocket clients ==")
    print(f"simulated {sim:.1f} s in {wall:.1f} s of wall time: {sim / wall:.3f}x (target {speed:g}x), "
          f"{steps} control steps, {steps / wall:.1f} steps/s")
    lag, st = p["lag_s"], p["step_time_s"]
    print(f"publish lag behind each step's due time (server): median {ms(lag['p50'])}, "
          f"p90 {ms(lag['p90'])}, p99 {ms(lag['p99'])}, max {ms(lag['max'])}")
    print(f"compute per control step (loop + messages + log): mean {ms(st['mean'])}, median {ms(st['p50'])}, "
          f"p99 {ms(st['p99'])}, max {ms(st['max'])}")
    print(f"batch size (steps per wake-up): median {p['batch_size']['p50']:g}, max {p['batch_size']['max']:g}; "
          f"clock re-anchored {p['slips']} times; data frames dropped for slow clients: {p['dropped_frames']}")
    frames = [r.get("frames", 0) for r in records]
    gaps = [g for r in records for g in r.get("gaps", [])]
    print(f"frames per client: min {min(frames)}, max {max(frames)} ({min(frames) / wall:.1f}/s); "
          f"gap between frames: {dist(gaps)}")
    print(f"page: {draws / wall:.1f} redraws/s; plots behind the server by median {statistics.median(trail):.2f} s, "
          f"max {max(trail):.2f} s of simulated time (sampled every 0.5 s)")


async def main_async(args) -> None:
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        print(f"rovlab hmi, scenario step-process-model; Chromium {browser.version}")
        # a fresh server per phase, so that each phase's pacing statistics are its own
        for phase, speed in (("load", 1.0), ("pace", 1.0), ("pace", 10.0)):
            with tempfile.TemporaryDirectory() as tmp:
                proc, url = start_server(Path(tmp), speed)
                try:
                    if phase == "load":
                        await page_loads(browser, url, args.loads)
                    else:
                        await pacing(browser, url, args.seconds if speed == 1.0 else args.seconds / 2,
                                     args.clients, speed)
                finally:
                    proc.send_signal(2)
                    try:
                        proc.communicate(timeout=30)
                    except subprocess.TimeoutExpired:
                        proc.kill()
        await browser.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of the 1x pacing run (default 20)")
    ap.add_argument("--clients", type=int, default=8, help="extra WebSocket clients (default 8)")
    ap.add_argument("--loads", type=int, default=5, help="page loads to time (default 5)")
    args = ap.parse_args()
    if not Path(CHROMIUM).exists():
        print(f"bench_hmi: {CHROMIUM} is missing (scripts/ensure-chromium.sh installs it); skipped")
        return 0
    try:
        import aiohttp  # noqa: F401
        import playwright  # noqa: F401
    except ImportError as exc:
        print(f"bench_hmi: {exc.name} is missing (pip install -e '.[dev]'); skipped")
        return 0
    asyncio.run(main_async(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
