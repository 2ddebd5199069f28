"""The studio is closed to strangers (issue #28): the per-launch token on the page and the
WebSocket, the Host check (DNS rebinding), the Origin check (a page from another origin in
a real Chromium), saves that never replace a file the studio did not write, preparation off
the shared render path, round-robin scheduling and the session cap.

All traffic goes to loopback servers these tests start; every wait is bounded.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import http.client
import http.server
import json
import os
import threading
import time
from pathlib import Path

import pytest

from arlight.studio.browser import launch, why_no_browser
from tests.studio.conftest import Client, run_clients

WS_HEADERS = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
              "Sec-WebSocket-Key": base64.b64encode(os.urandom(16)).decode()}


def _request(srv, path: str, headers: dict[str, str] | None = None, ws: bool = False,
             host: str | None = "default") -> tuple[int, bytes]:
    """One raw HTTP request to the studio with exactly these headers (``host`` None: no
    Host header); (status, body). A WebSocket handshake that succeeds (101) is closed."""
    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=30)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        if host == "default":
            host = f"127.0.0.1:{srv.port}"
        if host is not None:
            conn.putheader("Host", host)
        for k, v in {**(WS_HEADERS if ws else {}), **(headers or {})}.items():
            conn.putheader(k, v)
        conn.endheaders()
        resp = conn.getresponse()
        body = b"" if resp.status == 101 else resp.read()
        return resp.status, body
    finally:
        conn.close()


def _wait_sessions(engine, n: int, timeout: float = 30.0) -> None:
    """Wait until at most ``n`` sessions are open (the server closes them as sockets close)."""
    end = time.monotonic() + timeout
    while len(engine.sessions) > n and time.monotonic() < end:
        time.sleep(0.05)
    assert len(engine.sessions) <= n, engine.sessions


def _folder_state(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir()) if p.is_file()}


# ---------------------------------------------------------------------- token
def test_page_and_websocket_need_the_token(studio_server, studio_engine):
    _wait_sessions(studio_engine, 0)
    opened = studio_engine.sessions_opened
    token = studio_server.token
    wrong = token[:-1] + ("A" if token[-1] != "A" else "B")
    for path in ("/", "/?token=", f"/?token={wrong}", f"/?token={token[:8]}",
                 f"/?token={token}x", "/?token=%C3%A9"):
        status, body = _request(studio_server, path)
        assert status == 403, path
        assert b"token" in body and token.encode() not in body
        status, _ = _request(studio_server, path.replace("/?", "/ws?"), ws=True)
        assert status == 403, path
    assert _request(studio_server, "/ws", ws=True)[0] == 403
    assert studio_engine.sessions_opened == opened  # no session for a refused request
    # the right token: the page and the WebSocket
    status, page = _request(studio_server, f"/?token={token}")
    assert status == 200 and b"studio.js" in page and token.encode() not in page
    assert _request(studio_server, f"/ws?token={token}", ws=True)[0] == 101
    assert studio_engine.sessions_opened == opened + 1
    # the page's public assets need no token (they hold no secret)
    for name in ("studio.js", "studio.css"):
        status, body = _request(studio_server, f"/static/{name}")
        assert status == 200 and token.encode() not in body


def test_security_headers_keep_the_token_in_the_page(studio_server):
    conn = http.client.HTTPConnection("127.0.0.1", studio_server.port, timeout=30)
    try:
        conn.request("GET", f"/?token={studio_server.token}")
        resp = conn.getresponse()
        resp.read()
    finally:
        conn.close()
    assert resp.getheader("Referrer-Policy") == "no-referrer"
    assert "frame-ancestors 'none'" in resp.getheader("Content-Security-Policy")


def test_token_options(monkeypatch):
    from arlight.errors import InputError
    from arlight.studio.server import TOKEN_ENV, resolve_token

    monkeypatch.delenv(TOKEN_ENV, raising=False)
    a, b = resolve_token(), resolve_token()
    assert a != b and len(a) >= 43  # 32 random bytes, URL-safe
    monkeypatch.setenv(TOKEN_ENV, "from-the-environment-1234")
    assert resolve_token() == "from-the-environment-1234"
    assert resolve_token("given-on-the-command-line") == "given-on-the-command-line"
    for bad in ("short", "has space in it 12345", "x" * 300, "semi;colon;0123456789"):
        with pytest.raises(InputError):
            resolve_token(bad)


# ---------------------------------------------------------------------- Host, Origin
@pytest.mark.parametrize("host", ["evil.example:{port}", "evil.example", "127.0.0.1",
                                  "127.0.0.1:{other}", "localhost.evil.example:{port}",
                                  "127.0.0.1.evil.example:{port}", "[::1]:{other}",
                                  "10.0.0.1:{port}", "", None])
def test_a_foreign_host_header_is_refused(studio_server, studio_engine, host):
    """DNS rebinding: a name the attacker controls resolving to 127.0.0.1 arrives with
    the attacker's Host; refused even with the token."""
    opened = studio_engine.sessions_opened
    refused = studio_server.access.refused["host"]
    if host is not None:
        host = host.format(port=studio_server.port, other=studio_server.port + 1)
    token = studio_server.token
    want = {403} if host is not None else {400, 403}  # aiohttp's parser: no Host, 400
    assert _request(studio_server, f"/?token={token}", host=host)[0] in want
    assert _request(studio_server, f"/ws?token={token}", ws=True, host=host)[0] in want
    assert _request(studio_server, "/static/studio.js", host=host)[0] in want
    if host is not None:
        assert studio_server.access.refused["host"] == refused + 3
    assert studio_engine.sessions_opened == opened


@pytest.mark.parametrize("host", ["127.0.0.1:{port}", "localhost:{port}",
                                  "LOCALHOST:{port}", "[::1]:{port}"])
def test_the_served_host_names_are_accepted(studio_server, host):
    host = host.format(port=studio_server.port)
    assert _request(studio_server, f"/?token={studio_server.token}", host=host)[0] == 200


@pytest.mark.parametrize("origin", ["http://127.0.0.1:{other}", "http://evil.example",
                                    "http://evil.example:{port}", "null",
                                    "https://127.0.0.1:{port}", "http://127.0.0.2:{port}",
                                    "file://", "http://127.0.0.1:{port}/x"])
def test_a_websocket_from_another_origin_is_refused_even_with_the_token(
        studio_server, studio_engine, origin):
    opened = studio_engine.sessions_opened
    origin = origin.format(port=studio_server.port, other=studio_server.port + 1)
    status, _ = _request(studio_server, f"/ws?token={studio_server.token}", ws=True,
                         headers={"Origin": origin})
    assert status == 403
    assert studio_engine.sessions_opened == opened


@pytest.mark.parametrize("origin", ["http://127.0.0.1:{port}", "http://localhost:{port}"])
def test_the_served_origin_may_open_the_websocket(studio_server, origin):
    origin = origin.format(port=studio_server.port)
    assert _request(studio_server, f"/ws?token={studio_server.token}", ws=True,
                    headers={"Origin": origin})[0] == 101


def test_access_rules_for_other_binds():
    from arlight.studio.access import Access

    lan = Access("t" * 20, "192.168.1.5")
    lan.bind(8000)
    assert lan.host_ok("192.168.1.5:8000")
    assert not lan.host_ok("localhost:8000") and not lan.host_ok("evil.example:8000")
    anyip = Access("t" * 20, "0.0.0.0")
    anyip.bind(8000)
    assert anyip.host_ok("10.1.2.3:8000") and anyip.host_ok("localhost:8000")
    assert anyip.host_ok("[fe80::1]:8000")
    assert not anyip.host_ok("evil.example:8000") and not anyip.host_ok("10.1.2.3:8001")
    assert anyip.origin_ok("http://10.1.2.3:8000") and not anyip.origin_ok("http://x:8000")
    web = Access("t" * 20, "127.0.0.1")
    web.bind(80)  # a browser leaves the default port out of Host and Origin
    assert web.host_ok("127.0.0.1") and web.origin_ok("http://localhost")
    assert Access("t" * 20).host_ok("127.0.0.1:8000") is False  # not bound yet


# ---------------------------------------------------------------------- a foreign page
ATTACK_PAGE = """<!doctype html><meta charset="utf-8"><title>attacker</title>
<script>
window.results = [];
function attempt(label, url) {
  let opened = false;
  const ws = new WebSocket(url);
  ws.onopen = () => {
    opened = true;
    ws.send(JSON.stringify({type: "place", object: "bunny", x: 10, y: 100}));
    ws.send(JSON.stringify({type: "save", name: "pwned", overwrite: true}));
  };
  ws.onclose = (ev) => window.results.push({label, opened, code: ev.code});
}
attempt("with token", "ws://127.0.0.1:%(port)d/ws?token=%(token)s");
attempt("without token", "ws://127.0.0.1:%(port)d/ws");
</script>"""


@pytest.mark.skipif(why_no_browser() is not None,
                    reason=f"studio browser tests: {why_no_browser()}")
def test_a_page_from_another_origin_cannot_use_the_studio(studio_server, studio_engine,
                                                          tmp_path, monkeypatch):
    """A page served from another loopback origin (another port), open in headless
    Chromium, tries the studio's WebSocket — even with the leaked token: refused by the
    Origin check; no session, no save, no file changed."""
    from playwright.sync_api import sync_playwright

    from arlight.demo import DEMO_DIR

    monkeypatch.setattr(studio_engine, "save_dir", tmp_path.resolve())
    (tmp_path / "keep.txt").write_text("the user's file")
    before = (_folder_state(tmp_path), _folder_state(Path(DEMO_DIR)))
    _wait_sessions(studio_engine, 0)
    opened = studio_engine.sessions_opened
    refused = studio_server.access.refused["origin"]
    body = (ATTACK_PAGE % {"port": studio_server.port, "token": studio_server.token}).encode()

    class Attacker(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 — http.server's name
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    attacker = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Attacker)
    thread = threading.Thread(target=attacker.serve_forever, daemon=True)
    thread.start()
    try:
        with sync_playwright() as p:
            browser = launch(p)
            try:
                page = browser.new_page()
                page.goto(f"http://127.0.0.1:{attacker.server_address[1]}/")
                page.wait_for_function("window.results.length === 2", timeout=60_000)
                results = page.evaluate("window.results")
            finally:
                browser.close()
    finally:
        attacker.shutdown()
        attacker.server_close()
        thread.join(timeout=10)
    assert [r["opened"] for r in results] == [False, False], results
    assert studio_server.access.refused["origin"] == refused + 2  # they reached the studio
    assert studio_engine.sessions_opened == opened
    assert (_folder_state(tmp_path), _folder_state(Path(DEMO_DIR))) == before


# ---------------------------------------------------------------------- saves
def test_a_save_never_replaces_a_file_it_did_not_create(studio_server, studio_engine,
                                                        tmp_path, monkeypatch):
    from arlight.output_guard import record_written

    monkeypatch.setattr(studio_engine, "save_dir", tmp_path.resolve())
    user = tmp_path / "mine.toml"
    user.write_bytes(b"# the user's own scene\n")
    earlier = tmp_path / "earlier.png"  # written by an earlier arlight run (ledger)
    earlier.write_bytes(b"an earlier run's composite")
    record_written([earlier])

    async def go(a: Client):
        await a.wait_frame()
        out = {}
        await a.send({"type": "save", "name": "mine"})
        out["mine"] = await a.wait_json("error")
        await a.send({"type": "save", "name": "earlier"})
        out["earlier"] = await a.wait_json("error")
        await a.send({"type": "save", "name": "fresh"})
        out["fresh"] = await a.wait_json("saved")
        out["fresh_toml"] = (tmp_path / "fresh.toml").read_text()
        await a.send({"type": "pose", "object": "bunny", "yaw_deg": 77.0, "seq": 1})
        await a.wait_frame(lambda h: h["seq"] == 1)
        await a.send({"type": "save", "name": "fresh"})  # its own file: replaced
        out["again"] = await a.wait_json("saved")
        with open(tmp_path / "fresh.toml", "a") as f:  # the user edits it
            f.write("# edited\n")
        await a.send({"type": "save", "name": "fresh"})
        out["edited"] = await a.wait_json("error")
        await a.send({"type": "save", "name": "mine", "overwrite": True})  # confirmed
        out["confirmed"] = await a.wait_json("saved")
        return out

    before_user = user.read_bytes()
    out = run_clients(studio_server, go)
    assert out["mine"]["request"] == "save" and out["mine"]["exists"] == ["mine.toml"]
    assert out["earlier"]["exists"] == ["earlier.png"]  # a ledger entry is not enough
    assert earlier.read_bytes() == b"an earlier run's composite"
    assert out["fresh"]["files"] == ["fresh.toml", "fresh.frame.png", "fresh.png"]
    assert out["again"]["scene"] == "fresh.toml"
    assert (tmp_path / "fresh.toml").read_text() != out["fresh_toml"]  # replaced
    assert out["edited"]["exists"] == ["fresh.toml"]
    assert (tmp_path / "fresh.toml").read_text().endswith("# edited\n")
    # the refused saves wrote nothing; the confirmed one replaced the user's file
    assert out["confirmed"]["scene"] == "mine.toml"
    assert user.read_bytes() != before_user
    names = sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".arlight"))
    assert names == ["earlier.png", "fresh.frame.png", "fresh.png", "fresh.toml",
                     "mine.frame.png", "mine.png", "mine.toml"]


def test_a_save_refuses_the_scene_inputs_even_with_overwrite(studio_server, studio_engine,
                                                             tmp_path, monkeypatch):
    # stand-ins for inputs in a temporary save folder, so that a broken check cannot
    # touch the bundled scene: the scene file, a referenced image that the composite
    # <name>.png would hit, and a symlink to an input
    scene = tmp_path / "scene.toml"
    frame = tmp_path / "frame.png"
    scene.write_text("original scene")
    frame.write_bytes(b"original frame")
    (tmp_path / "link.toml").symlink_to(scene)
    monkeypatch.setattr(studio_engine, "save_dir", tmp_path.resolve())
    monkeypatch.setattr(studio_engine, "inputs",
                        {*studio_engine.inputs, scene.resolve(), frame.resolve()})
    before = _folder_state(tmp_path)

    async def go(a: Client):
        await a.wait_frame()
        errs = []
        for name in ("scene", "frame", "link"):
            for overwrite in (False, True):
                await a.send({"type": "save", "name": name, "overwrite": overwrite})
                errs.append(await a.wait_json("error"))
        return errs

    errs = run_clients(studio_server, go)
    assert all("exists" not in e for e in errs), errs  # nothing for the page to confirm
    assert all("input" in e["message"] or "outside" in e["message"] for e in errs), errs
    assert _folder_state(tmp_path) == before
    assert (tmp_path / "link.toml").is_symlink()


def test_overwrite_must_be_a_boolean():
    from arlight.studio.protocol import ProtocolError, parse

    assert parse('{"type": "save", "name": "a", "overwrite": true}', 10, 10)["overwrite"]
    with pytest.raises(ProtocolError):
        parse('{"type": "save", "name": "a", "overwrite": 1}', 10, 10)


# ---------------------------------------------------------------------- scheduling
def _other_method(engine) -> str:
    for name in ("ibl", "dlpv", "dvct", "prt"):
        if name in engine.catalogue and not engine.catalogue[name].unsupported:
            return name
    pytest.skip("no second non-progressive interactive method supports the demo")


def test_one_tabs_slow_preparation_does_not_stall_another_tabs_frames(
        studio_server, studio_engine, monkeypatch):
    """Tab A switches to a method whose preparation is held on an Event; tab B's change is
    rendered while A's preparation is still held (ordering, no wall-clock threshold)."""
    slow = _other_method(studio_engine)
    monkeypatch.delitem(studio_engine._states, slow, raising=False)  # restored afterwards
    entered, release = threading.Event(), threading.Event()
    prepare = studio_engine._prepare_state

    def held(name):
        if name == slow:
            entered.set()
            if not release.wait(120):
                raise RuntimeError("the test never released the preparation")
        return prepare(name)

    monkeypatch.setattr(studio_engine, "_prepare_state", held)

    async def go(a: Client, b: Client):
        try:
            await a.wait_frame()
            await b.wait_frame()
            await a.send({"type": "method", "name": slow, "seq": 1})
            status = await a.wait_json("status")
            assert status.get("preparing") == slow
            assert await asyncio.to_thread(entered.wait, 60)
            await b.send({"type": "pose", "object": "bunny", "yaw_deg": 33.0, "seq": 1})
            hb, _ = await b.wait_frame(lambda h: h["seq"] == 1, timeout=60)
            still = not release.is_set() and slow in studio_engine.preparing
            a_frames = [h for h, _ in a.frames if h["method"] == slow]
            release.set()
            ha, _ = await a.wait_frame(lambda h: h["seq"] == 1, timeout=300)
            return hb, still, a_frames, ha
        finally:
            release.set()

    hb, still, a_frames, ha = run_clients(studio_server, go, n=2)
    assert still and hb["method"] == "dir" and hb["objects"]["bunny"]["yaw_deg"] == 33.0
    assert a_frames == []  # A had no frame of the method before its preparation ended
    assert ha["method"] == slow


def test_a_failed_preparation_is_reported_to_its_tab_and_retried(
        studio_server, studio_engine, monkeypatch):
    slow = _other_method(studio_engine)
    monkeypatch.delitem(studio_engine._states, slow, raising=False)
    prepare = studio_engine._prepare_state
    fail = [True]

    def flaky(name):
        if name == slow and fail[0]:
            fail[0] = False
            raise RuntimeError("preparation exploded")
        return prepare(name)

    monkeypatch.setattr(studio_engine, "_prepare_state", flaky)

    async def go(a: Client):
        await a.wait_frame()
        await a.send({"type": "method", "name": slow, "seq": 1})
        err = await a.wait_json("error")
        await a.send({"type": "pose", "object": "bunny", "yaw_deg": 5.0, "seq": 2})
        h, _ = await a.wait_frame(lambda h: h["seq"] == 2, timeout=300)
        return err, h

    err, h = run_clients(studio_server, go)
    assert "preparation exploded" in err["message"] and h["method"] == slow


def test_sessions_with_pending_work_are_served_round_robin(studio_server, studio_engine):
    """A tab that always has new work gets one frame per turn, not every turn."""
    studio_engine.prepared("dir", timeout=300)

    def order():
        ss = [studio_engine.open_session(lambda kind, payload: None) for _ in range(3)]
        try:
            mine = {s.id: i for i, s in enumerate(ss)}
            with studio_engine._cond:
                for s in ss:
                    s.method = "dir"
                    s.rendered_version = s.displayed_version = 0
                seen = []
                for _ in range(5):
                    work = studio_engine._next_work()
                    while work is not None and work[0].id not in mine:
                        work = studio_engine._next_work()
                    if work is None:
                        break
                    s = work[0]
                    seen.append(mine[s.id])
                    s.rendered_version, s.displayed_version = s.version, s.display_version
                    if mine[s.id] == 0:
                        s.bump(None)  # tab 0 has new work again at once
            return seen
        finally:
            for s in ss:
                studio_engine.close_session(s)

    seen = studio_engine.call(order).result(60)
    assert sorted(seen[:3]) == [0, 1, 2] and seen[3:] == [0, 0], seen


def test_the_session_cap_refuses_a_new_websocket_with_503(studio_server, studio_engine,
                                                          monkeypatch):
    import aiohttp

    _wait_sessions(studio_engine, 0)
    monkeypatch.setattr(studio_engine, "max_sessions", 2)

    async def go():
        async with aiohttp.ClientSession() as cs:
            a = await cs.ws_connect(studio_server.ws_url)
            b = await cs.ws_connect(studio_server.ws_url)
            opened = studio_engine.sessions_opened
            with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
                await cs.ws_connect(studio_server.ws_url)
            body = await asyncio.to_thread(_request, studio_server,
                                           f"/ws?token={studio_server.token}", None, True)
            refused_opened = studio_engine.sessions_opened
            await a.close()
            await asyncio.to_thread(_wait_sessions, studio_engine, 1)
            c = await cs.ws_connect(studio_server.ws_url)  # room again
            first = json.loads((await c.receive(timeout=60)).data)
            await b.close()
            await c.close()
            return exc.value.status, body, opened, refused_opened, first

    status, (raw_status, raw_body), opened, refused_opened, first = asyncio.run(go())
    assert status == 503 and raw_status == 503
    assert b"at most 2" in raw_body
    assert refused_opened == opened  # no session for a refused connection
    assert first["type"] == "info"


def test_max_sessions_is_checked():
    from arlight.demo import DEMO_DIR
    from arlight.errors import InputError
    from arlight.studio import Engine, StudioConfig

    with pytest.raises(InputError, match="max-sessions"):
        Engine(StudioConfig(Path(DEMO_DIR) / "scene.toml", max_sessions=0))
