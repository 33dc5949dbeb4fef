"""The HMI web server with aiohttp's test client: page and files, the WebSocket protocol,
garbage and disconnects, several clients, pacing. Plain asyncio (no pytest plugin)."""

from __future__ import annotations

import asyncio
import json

import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient, TestServer

from rovlab.interfaces.hmi.server import HmiServer, ServerThread, encode

TIMEOUT = 20.0


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT))


async def _client(session, **kwargs):
    server = HmiServer(session, **kwargs)
    client = TestClient(TestServer(server.app, host="127.0.0.1"))
    await client.start_server()
    return server, client


async def _next(ws, kind, *, skip=("data", "state", "documents", "reset")):
    """The next frame of type `kind` (other frames in between are skipped)."""
    while True:
        msg = await ws.receive(timeout=10)
        assert msg.type == WSMsgType.TEXT, msg
        frame = json.loads(msg.data)
        if frame["type"] == kind:
            return frame
        assert frame["type"] in skip, frame


def test_the_page_and_its_files_are_served_locally_with_a_strict_policy(session):
    async def main():
        _, client = await _client(session)
        try:
            r = await client.get("/")
            html = await r.text()
            assert r.status == 200 and "/static/app.js" in html
            csp = r.headers["Content-Security-Policy"]
            assert "default-src 'self'" in csp and "connect-src 'self'" in csp
            for name, ctype in (("app.js", "text/javascript"), ("plot.js", "text/javascript"),
                                ("style.css", "text/css")):
                r = await client.get(f"/static/{name}")
                assert r.status == 200 and r.content_type == ctype
                text = await r.text()
                assert "http://" not in text and "https://" not in text  # nothing from the internet
            assert (await client.get("/static/../session.py")).status == 404
            assert (await client.get("/static/nope.js")).status == 404
            assert (await client.get("/files/secret.toml")).status == 404
            r = await client.get("/", headers={"Host": "evil.example:80"})
            assert r.status == 403  # DNS rebinding
        finally:
            await client.close()

    run(main())


def test_hello_then_commands_and_replies(session):
    async def main():
        _, client = await _client(session)
        try:
            ws = await client.ws_connect("/ws")
            hello = await _next(ws, "hello")
            assert hello["source"]["scenario"]["name"] == "step-process-model"
            assert set(hello["documents"]["documents"]) == {"vehicle", "truth", "config"}
            await ws.send_str(json.dumps({"cmd": "set", "id": 7, "target": "vehicle", "key": "rigid_body.mass",
                                          "value": "7.8"}))
            reply = await _next(ws, "reply")
            assert reply["id"] == 7 and reply["ok"] and reply["result"]["applied"]["rigid_body.mass"] == 7.8
            r = await client.get("/api/state")
            state = await r.json()
            assert state["loop"]["vehicle"]["mass"] == 7.8 and state["documents"]["vehicle"]["rigid_body"]["mass"] == 7.8
            await ws.send_str(json.dumps({"cmd": "set", "id": 8, "target": "vehicle", "key": "rigid_body.mass",
                                          "value": "-3"}))
            err = await _next(ws, "error")
            assert err["id"] == 8 and "positive" in err["message"]
            assert err["problems"][0]["key"] == "rigid_body.mass"
            assert (await (await client.get("/api/state")).json())["loop"]["vehicle"]["mass"] == 7.8
            await ws.close()
        finally:
            await client.close()

    run(main())


def test_garbage_goes_back_to_its_sender_only_and_the_server_keeps_running(session):
    async def main():
        _, client = await _client(session)
        try:
            good = await client.ws_connect("/ws")
            bad = await client.ws_connect("/ws")
            await _next(good, "hello")
            await _next(bad, "hello")
            garbage = ["not json", "{", "[1, 2]", "null", '{"cmd": 5}', '{"cmd": "self-destruct"}',
                       '{"cmd": "speed", "value": "ludicrous"}', "[" * 100000 + "]" * 100000,
                       '{"cmd": "set", "target": "vehicle", "key": "rigid_body.mass", "value": NaN}']
            for g in garbage:
                await bad.send_str(g)
                err = await _next(bad, "error")
                assert err["message"]
            await bad.send_bytes(b"\x00\x01")
            assert "binary" in (await _next(bad, "error"))["message"]
            # the other client heard none of it, and still gets answers
            await good.send_str(json.dumps({"cmd": "state", "id": "s"}))
            reply = await _next(good, "reply", skip=("state",))
            assert reply["id"] == "s"
            # a message over the size limit closes only that connection
            await bad.send_str("x" * (300 * 1024))
            msg = await bad.receive(timeout=10)
            while msg.type == WSMsgType.TEXT:
                msg = await bad.receive(timeout=10)
            assert msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSED, WSMsgType.CLOSING)
            await good.send_str(json.dumps({"cmd": "start", "id": 1}))
            assert (await _next(good, "reply"))["id"] == 1
            await good.close()
        finally:
            await client.close()

    run(main())


def test_many_clients_see_the_same_stream_and_disconnects_are_harmless(session):
    async def main():
        _, client = await _client(session)
        try:
            sockets = [await client.ws_connect("/ws") for _ in range(6)]
            for ws in sockets:
                await _next(ws, "hello")
            await sockets[0].send_str(json.dumps({"cmd": "speed", "value": 20}))
            await sockets[0].send_str(json.dumps({"cmd": "start"}))
            for ws in sockets[3:]:
                await ws.close()  # three leave at once
            for ws in sockets[:3]:
                frame = await _next(ws, "data", skip=("state", "reply", "documents"))
                topics = {m[0] for m in frame["messages"]}
                assert topics == {"/rovlab/truth", "/rovlab/estimate", "/rovlab/measurement",
                                  "/rovlab/reference", "/rovlab/command"}
            # an abrupt disconnect (no close handshake)
            sockets[2]._response.connection.transport.abort()
            await asyncio.sleep(0.3)
            state = await (await client.get("/api/state")).json()
            assert state["clients"] == 2 and state["pacing"]["steps"] > 0
            for ws in sockets[:2]:
                await ws.close()
        finally:
            await client.close()

    run(main())


def test_the_pacer_keeps_time_and_a_reset_clears_the_clients(session):
    async def main():
        server, client = await _client(session)
        try:
            ws = await client.ws_connect("/ws")
            await _next(ws, "hello")
            await ws.send_str(json.dumps({"cmd": "speed", "value": 50}))
            await ws.send_str(json.dumps({"cmd": "start"}))
            t = 0.0
            while t < 3.0:  # 3 s of simulated time at 50x real time
                frame = await _next(ws, "data", skip=("state", "reply"))
                t = frame["messages"][-1][1]["t"]
                assert frame["rows"] >= 1 and frame["decimated"] >= 1
            await ws.send_str(json.dumps({"cmd": "pause"}))
            await _next(ws, "reply", skip=("state", "data"))
            steps = session.source.sim.k
            assert server.stats.steps == steps and session.log.rows == steps
            await ws.send_str(json.dumps({"cmd": "reset"}))
            await _next(ws, "reset", skip=("reply", "state", "data"))
            assert session.source.time == 0.0
            await ws.close()
        finally:
            await client.close()

    run(main())


def test_a_websocket_from_another_origin_is_refused(session):
    async def main():
        _, client = await _client(session)
        try:
            r = await client.get("/ws", headers={"Origin": "http://evil.example", "Connection": "Upgrade",
                                                 "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
                                                 "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="})
            assert r.status == 403
            ok = await client.ws_connect("/ws", headers={"Origin": str(client.make_url("/")).rstrip("/")})
            assert (await _next(ok, "hello"))["type"] == "hello"
            await ok.close()
        finally:
            await client.close()

    run(main())


def test_saved_and_exported_files_can_be_downloaded(session):
    async def main():
        _, client = await _client(session)
        try:
            ws = await client.ws_connect("/ws")
            await _next(ws, "hello")
            await ws.send_str(json.dumps({"cmd": "step", "n": 5, "id": 1}))
            await _next(ws, "reply")
            await ws.send_str(json.dumps({"cmd": "save", "target": "vehicle", "id": 2}))
            saved = (await _next(ws, "reply"))["result"]["saved"]["vehicle"]
            r = await client.get(saved["url"])
            assert r.status == 200 and "mass" in await r.text()
            await ws.send_str(json.dumps({"cmd": "export", "formats": ["csv"], "id": 3}))
            files = (await _next(ws, "reply"))["result"]["files"]
            r = await client.get(files[0]["url"])
            text = await r.text()
            assert r.status == 200 and text.startswith("time_s,") and text.count("\n") == 6
            await ws.close()
        finally:
            await client.close()

    run(main())


def test_json_out_never_holds_nan():
    assert encode({"a": float("nan"), "b": [float("inf"), 1.0]}) == '{"a":null,"b":[null,1.0]}'


def test_the_server_runs_in_a_thread_and_stops_cleanly(session):
    import urllib.request

    with ServerThread(session) as st:
        assert st.url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(st.url + "api/state", timeout=10) as r:
            assert json.load(r)["running"] is False
        assert st.call(lambda: session.source.time) == 0.0
    with pytest.raises(OSError):
        urllib.request.urlopen(st.url, timeout=2)


# --------------------------------------------------------------------------------------------
# Issue 15 item 12: what the fuzzer found in the server
# --------------------------------------------------------------------------------------------

def test_a_malformed_host_header_is_a_400_not_a_500(session):
    async def main():
        _, client = await _client(session)
        try:
            for host in ("[::1", "[zz]:80"):
                r = await client.get("/", headers={"Host": host})
                assert r.status in (400, 403), (host, r.status)
        finally:
            await client.close()

    run(main())


def test_an_https_origin_is_refused(session):
    async def main():
        _, client = await _client(session)
        try:
            base = str(client.make_url("/")).rstrip("/")
            for origin in (base.replace("http://", "https://"), base.replace("http://", "ws://"), "null",
                           "http://[::1"):
                r = await client.get("/ws", headers={"Origin": origin, "Connection": "Upgrade",
                                                     "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
                                                     "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="})
                assert r.status == 403, origin
        finally:
            await client.close()

    run(main())


def test_a_burst_of_commands_from_one_client_does_not_freeze_the_others(session):
    from rovlab.interfaces.hmi.server import MAX_PENDING_COMMANDS

    async def main():
        server, client = await _client(session)
        try:
            noisy = await client.ws_connect("/ws")
            calm = await client.ws_connect("/ws")
            await _next(noisy, "hello")
            await _next(calm, "hello")
            n = 200
            for i in range(n):  # each redesigns the LQR: tens of ms apiece
                await noisy.send_str(json.dumps({"cmd": "set", "target": "config", "id": i,
                                                 "key": "lqr.input_weight.Z", "value": 0.1 + 1e-4 * i}))
            await calm.send_str(json.dumps({"cmd": "state", "id": "calm"}))
            reply = await _next(calm, "reply")
            assert reply["id"] == "calm"
            # the calm client was answered while the burst was still being worked through
            pending = max(len(c.commands) for c in server.clients)
            assert pending > 0
            assert pending <= MAX_PENDING_COMMANDS
            answered, refused = 0, 0
            while answered + refused < n:
                frame = json.loads((await noisy.receive(timeout=30)).data)
                if frame["type"] == "reply":
                    answered += 1
                elif frame["type"] == "error":
                    assert "too many commands waiting" in frame["message"]
                    refused += 1
            assert answered >= MAX_PENDING_COMMANDS
            await noisy.close()
            await calm.close()
        finally:
            await client.close()

    asyncio.run(asyncio.wait_for(main(), 120))


def test_absurd_set_points_get_an_error_frame_naming_the_field(session):
    # issue 28: a heading of 1e308 deg became -95.7 deg; a depth of -5 m was an "internal error"
    async def main():
        _, client = await _client(session)
        try:
            ws = await client.ws_connect("/ws")
            await _next(ws, "hello")
            cases = [('"heading_deg": 1e308', "heading_deg", "within -720 .. 720 deg"),
                     ('"heading_deg": 1e400', "heading_deg", "finite number, got inf"),  # JSON's 1e400 is inf
                     ('"heading_deg": NaN', "heading_deg", "finite number, got nan"),
                     ('"heading_deg": "north"', "heading_deg", "finite number, got 'north'"),
                     ('"depth_m": -5', "depth_m", "within 0 .. 1000 m"),
                     ('"north_m": 2', "north_m", "holds z, psi only")]
            for i, (args, key, words) in enumerate(cases):
                await ws.send_str(f'{{"cmd": "reference", "id": {i}, {args}}}')
                err = await _next(ws, "error")
                assert (err["id"], err["key"]) == (i, key) and words in err["message"], err
                assert "internal error" not in err["message"]
            state = await (await client.get("/api/state")).json()
            assert state["reference"]["schedule"] is True  # the scenario's reference, untouched
            assert state["reference"]["heading_deg"] == pytest.approx(30.0)
            await ws.close()
        finally:
            await client.close()

    run(main())
