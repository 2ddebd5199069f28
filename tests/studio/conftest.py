"""Fixtures of the studio tests: one engine on the bundled demo scene at 160×120 (every
method prepared once per test run), served on a free loopback port, and a WebSocket client."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from arlight.demo import DEMO_DIR

SIZE = (160, 120)


@pytest.fixture(scope="session")
def studio_engine(tmp_path_factory):
    from arlight.studio import Engine, StudioConfig

    save_dir = tmp_path_factory.mktemp("studio-saves")
    return Engine(StudioConfig(Path(DEMO_DIR) / "scene.toml", resolution=SIZE,
                               method="dir", save_dir=save_dir))


@pytest.fixture(scope="session")
def studio_server(studio_engine):
    from arlight.studio.server import BackgroundServer

    with BackgroundServer(studio_engine) as srv:
        yield srv


class Client:
    """A test WebSocket client: send JSON, read JSON replies and frames."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.info = None
        self.frames: list[tuple[dict, bytes]] = []
        self.json: list[dict] = []

    async def send(self, msg: dict | str) -> None:
        await self.ws.send_str(msg if isinstance(msg, str) else json.dumps(msg))

    async def next(self, timeout: float = 60.0):
        """The next message: ("json", dict) or ("frame", (header, image))."""
        import aiohttp

        from arlight.studio.protocol import split_frame

        m = await self.ws.receive(timeout=timeout)
        if m.type == aiohttp.WSMsgType.BINARY:
            item = split_frame(m.data)
            self.frames.append(item)
            return "frame", item
        if m.type == aiohttp.WSMsgType.TEXT:
            msg = json.loads(m.data)
            self.json.append(msg)
            if msg["type"] == "info":
                self.info = msg
            return "json", msg
        raise AssertionError(f"connection ended: {m.type} {m.data}")

    async def wait_json(self, kind: str, timeout: float = 60.0) -> dict:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            what, msg = await self.next(max(end - loop.time(), 0.01))
            if what == "json" and msg["type"] == kind:
                return msg

    async def wait_frame(self, pred=lambda h: True, timeout: float = 90.0) -> tuple[dict, bytes]:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            what, item = await self.next(max(end - loop.time(), 0.01))
            if what == "frame" and pred(item[0]):
                return item


def run_clients(server, fn, n: int = 1):
    """Run ``await fn(client, ...)`` with ``n`` clients connected to ``server`` (a
    BackgroundServer: its WebSocket URL carries the token); returns its result."""
    import aiohttp

    async def main():
        async with aiohttp.ClientSession() as cs:
            wss = [await cs.ws_connect(server.ws_url) for _ in range(n)]
            clients = [Client(ws) for ws in wss]
            try:
                return await fn(*clients)
            finally:
                for ws in wss:
                    await ws.close()

    return asyncio.run(main())
