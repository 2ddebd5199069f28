"""The studio's web server (aiohttp): one page, its static files, one WebSocket per tab.

* ``GET /?token=T`` — the page; ``GET /static/<file>`` — only the files of
  :data:`STATIC_FILES` (a fixed list: no path from a request ever reaches the file system);
* ``GET /ws?token=T`` — the WebSocket of :mod:`arlight.studio.protocol`.

Every request first passes :mod:`arlight.studio.access` (a middleware): the ``Host``
header must name the served address, an ``Origin`` must be the served origin, and
everything but the two static assets needs the launch's token — else HTTP 403 and no
engine work. Beyond the engine's ``max_sessions`` open WebSockets a new one gets HTTP 503.

Each connection has its own :class:`~arlight.studio.engine.Session`. Outgoing messages go
through an :class:`Outbox`: JSON replies in order, frames latest-wins (a slow client gets
the newest frame, never a backlog). A malformed message is answered with an ``error``
message and the connection stays open; an exception in one connection never reaches
another. The server binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import asyncio
import collections
import errno
import logging
import os
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from arlight.errors import ArlightError, InputError
from arlight.studio import protocol
from arlight.studio.access import Access, new_token
from arlight.studio.engine import Engine, SaveExists, Session, SessionLimit

log = logging.getLogger("arlight.studio")

STATIC_FILES = {"studio.js": "text/javascript", "studio.css": "text/css"}
"""The static files served (from ``arlight/studio/static``), with their content types."""

ENGINE_KEY = web.AppKey("engine", Engine)
ACCESS_KEY = web.AppKey("access", Access)
TOKEN_ENV = "ARLIGHT_STUDIO_TOKEN"
"""Environment variable that sets the token (``--token`` wins)."""
PUBLIC_PATHS = frozenset({*(f"/static/{name}" for name in STATIC_FILES), "/favicon.ico"})
"""Paths served without the token: the page's script and style, public code holding no
secret (the token lives only in the page's URL), and an empty favicon."""
SECURITY_HEADERS = {
    # the token is in the page's URL: never send it on as a Referer
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    # never framed by another page (clickjacking), no plugins, no <base> or form tricks
    "Content-Security-Policy": "frame-ancestors 'none'; object-src 'none'; "
                               "base-uri 'none'; form-action 'none'",
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-store",
}
MAX_QUEUED_JSON = 256
"""Most JSON messages kept for a client that does not read (the oldest are dropped): a
flood of bad messages from a tab that never reads its replies cannot grow the server."""


def _static(name: str) -> bytes:
    return resources.files("arlight.studio").joinpath("static", name).read_bytes()


class Outbox:
    """A connection's outgoing messages: JSON in order, frames latest-wins.

    ``post`` may be called from any thread (the render worker); the sender coroutine
    awaits :meth:`next`.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.json: collections.deque[dict[str, Any]] = collections.deque()
        self.frame: bytes | None = None
        self.event = asyncio.Event()
        self.dropped = 0  # frames replaced and JSON messages dropped before they were sent

    def post(self, kind: str, payload: Any) -> None:
        """Thread-safe: queue ``payload`` (``kind`` "json" or "frame")."""
        try:
            self.loop.call_soon_threadsafe(self._put, kind, payload)
        except RuntimeError:  # the loop is closed: the connection is gone
            pass

    def _put(self, kind: str, payload: Any) -> None:
        if kind == "frame":
            if self.frame is not None:
                self.dropped += 1
            self.frame = payload
        else:
            if len(self.json) >= MAX_QUEUED_JSON:
                self.json.popleft()
                self.dropped += 1
            self.json.append(payload)
        self.event.set()

    async def next(self) -> tuple[str, Any]:
        while not self.json and self.frame is None:
            self.event.clear()
            await self.event.wait()
        if self.json:
            return "json", self.json.popleft()
        frame, self.frame = self.frame, None
        return "frame", frame


async def _sender(ws: web.WebSocketResponse, box: Outbox) -> None:
    while not ws.closed:
        kind, payload = await box.next()
        if kind == "json":
            await ws.send_json(payload)
        else:
            await ws.send_bytes(payload)


@web.middleware
async def guard(request: web.Request, handler):
    """Host, Origin and token checks before any handler (see :mod:`arlight.studio.access`)."""
    access: Access = request.app[ACCESS_KEY]
    why = access.refusal(request.headers.get("Host"), request.headers.get("Origin"),
                         request.query.get("token"),
                         needs_token=request.path not in PUBLIC_PATHS)
    if why is not None:
        log.warning("studio: refused %s %s: %s", request.method, request.path, why)
        raise web.HTTPForbidden(text=f"403 forbidden: {why}\n")
    return await handler(request)


async def _headers(request: web.Request, response: web.StreamResponse) -> None:
    if not isinstance(response, web.WebSocketResponse):
        for k, v in SECURITY_HEADERS.items():
            response.headers.setdefault(k, v)


async def index(request: web.Request) -> web.Response:
    return web.Response(body=_static("index.html"), content_type="text/html")


async def favicon(request: web.Request) -> web.Response:
    return web.Response(status=204)  # none; answered so browsers do not log a 403


async def static(request: web.Request) -> web.Response:
    name = request.match_info["name"]
    if name not in STATIC_FILES:
        raise web.HTTPNotFound()
    return web.Response(body=_static(name), content_type=STATIC_FILES[name])


async def websocket(request: web.Request) -> web.WebSocketResponse:
    engine: Engine = request.app[ENGINE_KEY]
    box = Outbox(asyncio.get_running_loop())
    try:
        session = engine.open_session(box.post)
    except SessionLimit as exc:
        log.warning("studio: refused a WebSocket: %s", exc)
        raise web.HTTPServiceUnavailable(text=f"503 service unavailable: {exc}\n",
                                         headers={"Retry-After": "10"}) from None
    try:
        ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=1 << 20)
        await ws.prepare(request)
    except BaseException:
        engine.close_session(session)
        raise
    box.post("json", engine.info())
    sender = asyncio.create_task(_sender(ws, box))
    try:
        async for msg in ws:
            if msg.type == WSMsgType.TEXT:
                reply = await _handle(engine, session, msg.data)
            elif msg.type == WSMsgType.BINARY:
                reply = _error("binary messages are not accepted; send JSON text")
            else:  # ERROR (e.g. a message over max_msg_size) or CLOSE
                break
            if reply is not None:
                box.post("json", reply)
    finally:
        engine.close_session(session)
        sender.cancel()
        await asyncio.gather(sender, return_exceptions=True)
    return ws


def _error(message: str, request: str | None = None, **extra: Any) -> dict[str, Any]:
    return {"type": "error", "message": message, "request": request, **extra}


async def _handle(engine: Engine, session: Session, text: str) -> dict[str, Any] | None:
    """Apply one text message; the reply (or an error message) for the client."""
    kind = None
    try:
        msg = protocol.parse(text, engine.width, engine.height)
        kind = msg.type
        fut = engine.apply(session, msg)
        if fut is None:
            return None
        return await asyncio.wrap_future(fut)
    except SaveExists as exc:  # the page may ask the user and send overwrite: true
        return _error(str(exc), kind, exists=exc.names)
    except (protocol.ProtocolError, ArlightError) as exc:
        return _error(str(exc), kind)
    except Exception as exc:  # noqa: BLE001 — reported to this client, logged, not raised
        log.exception("studio: %s message failed", kind)
        return _error(f"internal error: {type(exc).__name__}: {exc}", kind)


def resolve_token(token: str | None = None) -> str:
    """The launch's token: ``token``, else ``$ARLIGHT_STUDIO_TOKEN``, else a new random one
    (a given one must be URL-safe, 16–256 characters)."""
    from arlight.studio.access import check_token

    if token is not None:
        return check_token(token, "--token")
    env = os.environ.get(TOKEN_ENV)
    if env:
        return check_token(env, TOKEN_ENV)
    return new_token()


def create_app(engine: Engine, access: Access) -> web.Application:
    """The aiohttp application serving ``engine`` behind ``access`` (bind its port before
    serving requests; the engine starts and stops with the app)."""
    app = web.Application(client_max_size=1 << 16, middlewares=[guard])
    app[ENGINE_KEY] = engine
    app[ACCESS_KEY] = access
    app.on_response_prepare.append(_headers)
    app.router.add_get("/", index)
    app.router.add_get("/static/{name}", static)
    app.router.add_get("/ws", websocket)
    app.router.add_get("/favicon.ico", favicon)

    async def on_startup(app: web.Application) -> None:
        await asyncio.get_running_loop().run_in_executor(None, engine.start)

    async def on_cleanup(app: web.Application) -> None:
        await asyncio.get_running_loop().run_in_executor(None, engine.stop)

    app.on_startup.append(on_startup)
    app.on_cleanup.append(on_cleanup)
    return app


def _bound_port(site: web.TCPSite) -> int:
    return site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]


def serve(engine: Engine, host: str = "127.0.0.1", port: int = 8000,
          print_fn=print, token: str | None = None) -> None:
    """Run the studio until interrupted; prints the page's URL with the token."""
    access = Access(resolve_token(token), host)

    async def main() -> None:
        runner = web.AppRunner(create_app(engine, access), handle_signals=True)
        await runner.setup()
        site = web.TCPSite(runner, host, port)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise InputError(f"cannot serve on {host}:{port}: {exc.strerror or exc}",
                             field="--port" if exc.errno == errno.EADDRINUSE
                             else "--host") from exc
        access.bind(_bound_port(site))
        print_fn(f"arlight studio: {access.page_url()}  ({engine.source.name}, "
                 f"{engine.width}×{engine.height}, at most {engine.max_sessions} tabs; "
                 "Ctrl-C stops)")
        print_fn("open that URL (with its token) in a browser; without the token the "
                 "studio answers 403")
        try:
            await asyncio.Event().wait()
        finally:
            await runner.cleanup()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass


class BackgroundServer:
    """The studio on a loopback port in a background thread (tests, benchmarks, docs).

    ``with BackgroundServer(engine) as srv: page.goto(srv.url)``; ``srv.url`` is the page
    with the token, ``srv.ws_url`` the WebSocket with the token, ``srv.base_url`` the bare
    ``http://host:port``; port 0 picks a free port; ``token`` None makes a random one.
    """

    def __init__(self, engine: Engine, host: str = "127.0.0.1", port: int = 0,
                 token: str | None = None) -> None:
        self.engine, self.host, self.port = engine, host, port
        self.access = Access(token or new_token(), host)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._thread = None

    @property
    def token(self) -> str:
        return self.access.token

    @property
    def url(self) -> str:
        """The page's URL with the token (what a browser opens)."""
        return self.access.page_url()

    @property
    def ws_url(self) -> str:
        """The WebSocket's URL with the token."""
        return self.access.ws_url()

    @property
    def base_url(self) -> str:
        """``http://host:port`` (no token, no trailing slash)."""
        return self.access.base_url()

    def __enter__(self) -> BackgroundServer:
        import threading

        ready = threading.Event()
        failure: list[BaseException] = []

        def run() -> None:
            self._loop = asyncio.new_event_loop()
            asyncio.set_event_loop(self._loop)
            try:
                self._runner = web.AppRunner(create_app(self.engine, self.access),
                                             handle_signals=False)
                self._loop.run_until_complete(self._runner.setup())
                site = web.TCPSite(self._runner, self.host, self.port)
                self._loop.run_until_complete(site.start())
                self.port = _bound_port(site)
                self.access.bind(self.port)
            except BaseException as exc:  # noqa: BLE001 — re-raised in __enter__
                failure.append(exc)
                ready.set()
                return
            ready.set()
            self._loop.run_forever()
            self._loop.run_until_complete(self._runner.cleanup())
            self._loop.close()

        self._thread = threading.Thread(target=run, name="arlight-studio-server", daemon=True)
        self._thread.start()
        ready.wait()
        if failure:
            raise failure[0]
        return self

    def __exit__(self, *exc: object) -> None:
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=60)
