"""The HMI's web server (aiohttp): the page, a WebSocket for the live stream and the commands, and
a pacing task that advances the source in real time (or faster) and broadcasts its messages.

Routes (bound to 127.0.0.1 only):

* ``GET /``, ``GET /static/NAME``: the page, its script, plotting module and style sheet, all
  shipped inside the package (no CDN, no web fonts: it works with no internet).
* ``GET /ws``: the WebSocket. The server sends JSON text frames::

      {"type": "hello", "source": {...}, "state": {...}, "documents": {...}, ...}   on connect
      {"type": "data", "messages": [[topic, message], ...], "rows": n, "decimated": k}
      {"type": "state", ...}            run state, every second and after every change
      {"type": "documents", ...}        parameter documents and the loop's design, after a change
      {"type": "reset"}                 the run restarted: clear the plots
      {"type": "reply", "id": ..., "cmd": ..., "ok": true, "result": {...}}      to the sender only
      {"type": "error", "id": ..., "cmd": ..., "message": ..., "key": ..., "problems": [...]}

  and takes the commands of :mod:`rovlab.interfaces.hmi.session` as JSON text. ``messages`` are
  exactly those of :mod:`rovlab.io.messages` (topics ``/rovlab/truth``, ``/rovlab/estimate``,
  ``/rovlab/measurement``, ``/rovlab/reference``, ``/rovlab/command``).
* ``GET /api/state``: the run state, the pacing statistics and the loop's current design (JSON).
* ``GET /files/NAME``: a file this session wrote (saved parameters, exported logs).

Robustness: garbage, unknown commands and wrong types get an error frame on that connection only;
a slow client loses data frames (counted) instead of slowing the others or the pacer; a client
that disconnects is simply dropped. Each client's commands are queued (at most
``MAX_PENDING_COMMANDS``; more are refused with an error frame) and carried out one at a time,
with the event loop given at least as long as each command took before the next one: a burst of
commands from one client (200 ``set`` in a row) delays the pacer and the other clients by one
command at a time, never by the whole burst. WebSocket connections from other web origins
(including https://localhost: this server speaks plain http) are refused (a page from elsewhere
must not drive the vehicle), and so is any Host header other than localhost (DNS rebinding); a
malformed Host header gets 400, not 500.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import sys
import threading
import time
import traceback
from collections import deque
from importlib import resources
from typing import Any, Self
from urllib.parse import urlsplit

import numpy as np
from aiohttp import WSMsgType, web

from rovlab.interfaces.hmi.session import CommandError, Outcome, Session

HOST = "127.0.0.1"
_LOCAL_NAMES = {"127.0.0.1", "localhost", "::1"}
_CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                  ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml"}
_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; connect-src 'self'; "
                               "style-src 'self'; script-src 'self'; font-src 'self'; object-src 'none'; "
                               "base-uri 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Cache-Control": "no-cache",
    "Referrer-Policy": "no-referrer",
}
MAX_MESSAGE_BYTES = 256 * 1024
MAX_PENDING_COMMANDS = 64  # per client; a burst beyond this is refused, not queued
COMMAND_REST_MAX_S = 0.05  # after a command the client's worker yields for as long as it took (capped)


def _static_files() -> dict[str, tuple[bytes, str]]:
    folder = resources.files("rovlab.interfaces.hmi") / "static"
    out = {}
    for entry in folder.iterdir():
        name = entry.name
        suffix = name[name.rfind("."):] if "." in name else ""
        if entry.is_file() and suffix in _CONTENT_TYPES:
            out[name] = (entry.read_bytes(), _CONTENT_TYPES[suffix])
    return out


def encode(obj: Any) -> str:
    """Compact JSON; NaN and infinities (which browsers cannot parse) become null."""
    try:
        return json.dumps(obj, separators=(",", ":"), allow_nan=False)
    except ValueError:
        return json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False)


def _finite(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


class PacingStats:
    """How well the pacer keeps up: lag of each published step behind its due time, and the
    compute time per control step (source + log), over the last ``keep`` batches."""

    def __init__(self, keep: int = 20000) -> None:
        self.lag: deque[float] = deque(maxlen=keep)  # [s] wall-clock delay of a batch's last step behind its due time
        self.step_time: deque[float] = deque(maxlen=keep)  # [s] compute time per control step
        self.batch_size: deque[int] = deque(maxlen=keep)
        self.steps = 0
        self.batches = 0
        self.slips = 0  # times the pacer fell > 1 s behind and re-anchored its clock
        self.frames = 0
        self.dropped_frames = 0

    def record(self, n: int, compute_s: float, lag_s: float) -> None:
        self.steps += n
        self.batches += 1
        self.lag.append(lag_s)
        self.step_time.append(compute_s / n)
        self.batch_size.append(n)

    def summary(self) -> dict[str, Any]:
        return {"steps": self.steps, "batches": self.batches, "slips": self.slips, "frames": self.frames,
                "dropped_frames": self.dropped_frames, "lag_s": _distribution(self.lag),
                "step_time_s": _distribution(self.step_time), "batch_size": _distribution(self.batch_size)}


def _distribution(values: deque) -> dict[str, float | int | None]:
    if not values:
        return {"count": 0}
    a = np.fromiter(values, dtype=float)
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"count": int(a.size), "mean": float(a.mean()), "p50": float(p50), "p90": float(p90),
            "p99": float(p99), "max": float(a.max()), "last": float(a[-1])}


class _Client:
    """One WebSocket connection with its own outgoing queue (data frames may be dropped, replies not)."""

    MAX_DATA = 40  # queued data frames before new ones are dropped for this client
    MAX_TOTAL = 2000  # queued frames before the connection is closed (a client that never reads)

    def __init__(self, ws: web.WebSocketResponse, ident: int) -> None:
        self.ws = ws
        self.ident = ident
        self.queue: deque[tuple[str, bool]] = deque()
        self.pending_data = 0
        self.dropped = 0
        self.wake = asyncio.Event()
        self.commands: deque[str] = deque()  # received, not yet carried out
        self.command_ready = asyncio.Event()

    def send(self, text: str, *, data: bool = False) -> bool:
        if data and self.pending_data >= self.MAX_DATA:
            self.dropped += 1
            return False
        if len(self.queue) >= self.MAX_TOTAL:
            asyncio.ensure_future(self.ws.close(code=1008, message=b"too many unread frames"))
            return False
        self.queue.append((text, data))
        if data:
            self.pending_data += 1
        self.wake.set()
        return True

    async def run(self) -> None:
        try:
            while not self.ws.closed:
                await self.wake.wait()
                self.wake.clear()
                while self.queue and not self.ws.closed:
                    text, data = self.queue.popleft()
                    if data:
                        self.pending_data -= 1
                    await self.ws.send_str(text)
        except (ConnectionError, RuntimeError, asyncio.CancelledError):
            pass  # disconnected or shutting down


class HmiServer:
    """The web app around one :class:`Session`. ``await start()`` returns the page's URL."""

    def __init__(self, session: Session, *, port: int = 0, frame_interval_s: float = 0.05,
                 max_rows_per_frame: int = 25, state_interval_s: float = 1.0, quiet: bool = True) -> None:
        self.session = session
        self.port = port
        self.frame_interval_s = frame_interval_s
        self.max_rows_per_frame = max_rows_per_frame
        self.state_interval_s = state_interval_s
        self.quiet = quiet
        self.stats = PacingStats()
        self.clients: set[_Client] = set()
        self.url = ""
        self._static = _static_files()
        self._runner: web.AppRunner | None = None
        self._tasks: list[asyncio.Task] = []
        self._wake: asyncio.Event | None = None
        self._anchor: tuple[float, float] | None = None  # (wall time, source time) of the pacing clock
        self._next_id = 0
        self.app = self._make_app()

    # -- app ---------------------------------------------------------------------------------
    def _make_app(self) -> web.Application:
        app = web.Application(middlewares=[self._local_only], client_max_size=MAX_MESSAGE_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/api/state", self._api_state)
        app.router.add_get("/files/{name}", self._file)
        app.on_startup.append(self._on_startup)
        app.on_shutdown.append(self._on_shutdown)
        app.on_cleanup.append(self._on_cleanup)
        return app

    async def _on_startup(self, app: web.Application) -> None:
        self._wake = asyncio.Event()
        self._tasks = [asyncio.create_task(self._pace(), name="hmi-pacer"),
                       asyncio.create_task(self._tick(), name="hmi-state")]

    async def _on_shutdown(self, app: web.Application) -> None:
        for t in self._tasks:
            t.cancel()
        for c in list(self.clients):
            with contextlib.suppress(Exception):
                await c.ws.close(code=1001, message=b"server shutting down")

    async def _on_cleanup(self, app: web.Application) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._tasks = []

    @web.middleware
    async def _local_only(self, request: web.Request, handler):
        try:
            host = urlsplit(f"//{request.host}").hostname or ""
        except ValueError:  # e.g. "Host: [::1" (an unclosed IPv6 bracket) or a bad port
            return web.Response(status=400, text="malformed Host header")
        if host not in _LOCAL_NAMES:
            return web.Response(status=403, text="this server answers to 127.0.0.1 / localhost only")
        response = await handler(request)
        if not isinstance(response, web.WebSocketResponse):
            for k, v in _HEADERS.items():
                response.headers.setdefault(k, v)
        return response

    async def _index(self, request: web.Request) -> web.Response:
        body, ctype = self._static["index.html"]
        return web.Response(body=body, content_type=ctype.split(";")[0], charset="utf-8")

    async def _static_file(self, request: web.Request) -> web.Response:
        item = self._static.get(request.match_info["name"])
        if item is None:
            raise web.HTTPNotFound(text="no such file")
        body, ctype = item
        return web.Response(body=body, content_type=ctype.split(";")[0],
                            charset="utf-8" if "charset" in ctype else None)

    async def _api_state(self, request: web.Request) -> web.Response:
        return web.Response(text=encode(self.full_state()), content_type="application/json")

    async def _file(self, request: web.Request) -> web.StreamResponse:
        path = self.session.files.get(request.match_info["name"])
        if path is None or not path.is_file():
            raise web.HTTPNotFound(text="no such file in this session")
        return web.FileResponse(path, headers={"Content-Disposition": f'attachment; filename="{path.name}"'})

    def full_state(self) -> dict[str, Any]:
        s = self.session
        return {**s.state(), "pacing": self.stats.summary(), "clients": len(self.clients),
                "latest": s.latest, "loop": s.source.loop_summary(),
                "documents": {t: d.data for t, d in s.documents.items()}}

    # -- lifecycle ---------------------------------------------------------------------------
    async def start(self) -> str:
        self._runner = web.AppRunner(self.app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, HOST, self.port)
        await site.start()
        self.port = self._runner.addresses[0][1]  # the port chosen for port 0
        self.url = f"http://{HOST}:{self.port}/"
        return self.url

    async def stop(self) -> None:
        """Close every connection, stop pacing and release the port."""
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    # -- pacing ------------------------------------------------------------------------------
    def _reanchor(self) -> None:
        self._anchor = None
        if self._wake is not None:
            self._wake.set()

    async def _pace(self) -> None:
        """Advance the source one control step per h/speed seconds of wall time, in batches of
        the steps due since the last wake-up (at most one wake-up per frame interval), and
        broadcast each batch as one data frame."""
        loop = asyncio.get_running_loop()
        assert self._wake is not None
        while True:
            s = self.session
            if not s.source.paced:  # a vehicle bridge runs on its own clock: collect what it produced
                try:
                    messages = s.advance(1)
                except Exception as exc:  # noqa: BLE001 - keep serving; tell everyone
                    traceback.print_exc(file=sys.stderr)
                    self.broadcast({"type": "error", "cmd": None, "message": f"the source failed: {exc!r}"})
                    messages = []
                if messages:
                    self._broadcast_messages(messages)
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), timeout=max(self.frame_interval_s, 0.02))
                self._wake.clear()
                continue
            if not (s.running and s.source.paced):
                self._anchor = None
                await self._wake.wait()
                self._wake.clear()
                continue
            h, speed = s.source.h, s.speed
            now = loop.time()
            if self._anchor is None:
                self._anchor = (now, s.source.time)
            wall0, sim0 = self._anchor
            target = sim0 + (now - wall0) * speed  # source time that is due now
            n = math.floor((target - s.source.time) / h + 1e-9) + 1 if target >= s.source.time - 1e-12 else 0
            if n * h / speed > 1.0:  # more than a second of wall time behind (suspended?): re-anchor
                self.stats.slips += 1
                self._anchor = (now, s.source.time)
                wall0, sim0 = self._anchor
                n = 1
            if n > 0:
                t0 = time.perf_counter()
                try:
                    messages = s.advance(n)
                except Exception as exc:  # noqa: BLE001 - keep serving; tell everyone
                    traceback.print_exc(file=sys.stderr)
                    s.running = False
                    self.broadcast({"type": "error", "cmd": None, "message": f"the run stopped: {exc!r}"})
                    self.broadcast_state()
                    continue
                compute = time.perf_counter() - t0
                due_last = wall0 + (s.source.time - h - sim0) / speed
                self.stats.record(n, compute, max(0.0, loop.time() - due_last))
                self._broadcast_messages(messages)
            next_due = wall0 + (s.source.time - sim0) / speed
            delay = max(next_due - loop.time(), self.frame_interval_s if speed * self.frame_interval_s > h else 0.0)
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._wake.wait(), timeout=max(0.0, delay))
            self._wake.clear()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(self.state_interval_s)
            if self.clients:
                self.broadcast_state()

    # -- broadcasting ------------------------------------------------------------------------
    def broadcast(self, obj: Any, *, data: bool = False) -> None:
        if not self.clients:
            return
        text = encode(obj)
        for c in list(self.clients):
            if not c.send(text, data=data):
                self.stats.dropped_frames += 1 if data else 0

    def broadcast_state(self) -> None:
        self.broadcast({"type": "state", **self.session.state(), "pacing": self._pacing_brief(),
                        "clients": len(self.clients)})

    def _pacing_brief(self) -> dict[str, Any]:
        lag = self.stats.lag[-1] if self.stats.lag else None
        st = self.stats.step_time[-1] if self.stats.step_time else None
        return {"lag_s": lag, "step_time_s": st, "slips": self.stats.slips,
                "dropped_frames": self.stats.dropped_frames}

    def _broadcast_messages(self, messages: list) -> None:
        if not self.clients or not messages:
            return
        rows: list[list] = []
        last_t = None
        for topic, t, msg in messages:
            if t != last_t:
                rows.append([])
                last_t = t
            rows[-1].append([topic, msg])
        k = max(1, math.ceil(len(rows) / self.max_rows_per_frame))
        keep = rows[k - 1::k] if k > 1 else rows
        if k > 1 and keep[-1] is not rows[-1]:
            keep.append(rows[-1])  # always show the newest row
        self.stats.frames += 1
        self.broadcast({"type": "data", "messages": [m for row in keep for m in row], "rows": len(rows),
                        "decimated": k}, data=True)

    # -- the WebSocket -----------------------------------------------------------------------
    def _origin_ok(self, request: web.Request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:
            return True  # not a browser page (a script, a test client)
        try:
            parts = urlsplit(origin)
            hostname = parts.hostname
        except ValueError:
            return False
        # this server speaks plain http: a page served over https (or any other scheme) is elsewhere
        return parts.scheme == "http" and hostname in _LOCAL_NAMES and parts.netloc == request.host

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._origin_ok(request):
            return web.Response(status=403, text="WebSocket from another origin refused")
        ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=MAX_MESSAGE_BYTES)
        await ws.prepare(request)
        self._next_id += 1
        client = _Client(ws, self._next_id)
        self.clients.add(client)
        sender = asyncio.create_task(client.run())
        worker = asyncio.create_task(self._command_worker(client))
        client.send(encode({"type": "hello", **self.session.info(), "pacing": self._pacing_brief()}))
        self.broadcast_state()  # everyone sees the client count
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._enqueue(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    client.send(encode({"type": "error", "cmd": None,
                                        "message": "binary frames are not understood; send JSON text"}))
                elif msg.type == WSMsgType.ERROR:
                    break
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self.clients.discard(client)
            for task in (worker, sender):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            if self.clients:
                self.broadcast_state()
        return ws

    def _enqueue(self, client: _Client, text: str) -> None:
        """Queue a command of this client, or refuse it when too many are waiting."""
        if len(client.commands) >= MAX_PENDING_COMMANDS:
            ident = None
            with contextlib.suppress(Exception):
                head = json.loads(text) if len(text) < 4096 else None
                if isinstance(head, dict) and isinstance(head.get("id"), (str, int)):
                    ident = head["id"]
            client.send(encode({"type": "error", "id": ident, "cmd": None,
                                "message": f"too many commands waiting ({MAX_PENDING_COMMANDS}); this one was "
                                           "dropped: wait for the replies before sending more"}))
            return
        client.commands.append(text)
        client.command_ready.set()

    async def _command_worker(self, client: _Client) -> None:
        """Carry out one client's commands in order, resting after each as long as it took."""
        while True:
            await client.command_ready.wait()
            client.command_ready.clear()
            while client.commands:
                text = client.commands.popleft()
                t0 = time.perf_counter()
                self._on_command(client, text)
                await asyncio.sleep(min(time.perf_counter() - t0, COMMAND_REST_MAX_S))

    def _on_command(self, client: _Client, text: str) -> None:
        ident: Any = None
        name: Any = None
        try:
            try:
                command = json.loads(text)
            except (ValueError, RecursionError) as exc:
                raise CommandError(f"not JSON: {exc}") from None
            if isinstance(command, dict):
                ident = command.get("id") if isinstance(command.get("id"), (str, int)) else None
                name = command.get("cmd") if isinstance(command.get("cmd"), str) else None
            outcome = self.session.handle(command)
        except CommandError as exc:
            client.send(encode({"type": "error", "id": ident, "cmd": name, **exc.payload()}))
            return
        except Exception as exc:  # noqa: BLE001 - a bug must not take the server down
            traceback.print_exc(file=sys.stderr)
            client.send(encode({"type": "error", "id": ident, "cmd": name,
                                "message": f"internal error ({type(exc).__name__}: {exc}); the run is unchanged"}))
            return
        client.send(encode({"type": "reply", "id": ident, "cmd": name, "ok": True, "result": outcome.result}))
        self._after(outcome)

    def _after(self, outcome: Outcome) -> None:
        if outcome.reset:
            self.broadcast({"type": "reset"})
        if outcome.messages:
            self._broadcast_messages(outcome.messages)
        if outcome.documents_changed:
            self.broadcast({"type": "documents", **self.session.documents_payload()})
        if outcome.state_changed:
            self.broadcast_state()
        if outcome.pacing_changed:
            self._reanchor()


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------

class ServerThread:
    """An :class:`HmiServer` on its own event loop in a background thread (tests, benchmarks,
    notebooks). ``url`` is set once started; ``stop()`` shuts it down and joins the thread."""

    def __init__(self, session: Session, **kwargs: Any) -> None:
        self.session = session
        self.server: HmiServer | None = None
        self.url = ""
        self._kwargs = kwargs
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="rovlab-hmi", daemon=True)

    def start(self, timeout: float = 30.0) -> Self:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError("the HMI server did not start in time")
        if self._error is not None:
            raise self._error
        return self

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        try:
            self.server = HmiServer(self.session, **self._kwargs)
            self.url = self._loop.run_until_complete(self.server.start())
        except BaseException as exc:  # noqa: BLE001 - reported by start()
            self._error = exc
            self._ready.set()
            self._loop.close()
            return
        self._ready.set()
        self._loop.run_forever()
        self._loop.run_until_complete(self.server.stop())
        self._loop.run_until_complete(self._loop.shutdown_asyncgens())
        self._loop.close()

    def call(self, fn, *args: Any, timeout: float = 10.0) -> Any:
        """Run fn(*args) on the server's loop (safe access to the session) and return its result."""
        async def wrapper():
            return fn(*args)

        return asyncio.run_coroutine_threadsafe(wrapper(), self._loop).result(timeout)

    def stop(self) -> None:
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(30.0)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
