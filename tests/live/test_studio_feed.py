"""The live feed through the studio's own server: same token and origin checks, frames in
the studio's format.

Rejects: a live view served without the token (or to another origin), a feed that posts
something other than the composite's codes (the JPEG decodes to the composite within JPEG
error), a header without the frame's latency and stages, and page messages that fail the
connection instead of being ignored.
"""

from __future__ import annotations

import asyncio
import io
import json
import time

import numpy as np
import pytest

from arlight.live.loop import LiveFrame
from arlight.live.studio import LiveFeed
from arlight.studio.browser import why_no_browser
from arlight.studio.server import BackgroundServer
from tests.studio.test_security import _request


def _frame() -> LiveFrame:
    y, x = np.mgrid[0:48, 0:64]
    img = np.stack([x * 4, y * 5, np.full_like(x, 128)], axis=-1).astype(np.uint8)
    return LiveFrame(3, img, np.eye(4), True, timings={"track": 0.01, "render": 0.05},
                     captured_at=time.perf_counter() - 0.2, dropped=2)


def test_the_live_page_needs_the_token_and_shows_the_composite():
    import aiohttp
    from PIL import Image

    from arlight.studio.protocol import split_frame

    feed = LiveFeed("live: test", "dir", "direct light", (64, 48))
    with BackgroundServer(feed) as srv:
        assert _request(srv, "/")[0] == 403
        assert _request(srv, "/ws", ws=True)[0] == 403
        assert _request(srv, f"/ws?token={srv.token}", ws=True,
                        headers={"Origin": "http://evil.example"})[0] == 403
        assert _request(srv, f"/?token={srv.token}")[0] == 200
        fr = _frame()

        async def client():
            async with aiohttp.ClientSession() as http, http.ws_connect(srv.ws_url) as ws:
                info = json.loads((await ws.receive(timeout=30)).data)
                await ws.send_str(json.dumps({"type": "exposure", "ev": 1.0}))  # ignored
                while not feed._sessions:
                    await asyncio.sleep(0.01)
                feed.show(fr)
                msg = await ws.receive(timeout=30)
                return info, split_frame(msg.data)

        info, (header, data) = asyncio.run(client())
    assert info["type"] == "info" and info["live"] and (info["width"], info["height"]) == \
        (64, 48)
    assert header["frame"] == 3 and header["dropped"] == 2 and header["latency_ms"] >= 200
    assert header["stats"] == {"track": 0.01, "render": 0.05}
    shown = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), np.int32)
    assert np.abs(shown - fr.display).mean() < 3
    assert feed.frames_posted == 1


@pytest.mark.skipif(why_no_browser() is not None, reason=f"browser: {why_no_browser()}")
def test_the_studio_page_draws_live_frames_in_chromium():
    """The studio's own page, unchanged, shows a live feed: every posted frame reaches the
    canvas (rejects a feed whose info or headers the page cannot use: a script error or no
    frame drawn)."""
    from playwright.sync_api import sync_playwright

    from arlight.studio.browser import launch

    feed = LiveFeed("live: test", "dir", "direct light", (64, 48))
    with BackgroundServer(feed) as srv, sync_playwright() as p:
        browser = launch(p)
        try:
            pg = browser.new_page()
            errors: list[str] = []
            pg.on("pageerror", lambda exc: errors.append(str(exc)))
            pg.goto(srv.url)
            pg.wait_for_function("window.studio && window.studio.ready", timeout=60_000)
            fr = _frame()
            for i in range(3):
                fr.index = i
                feed.show(fr)
                pg.wait_for_function(f"window.studio.frames >= {i + 1}", timeout=60_000)
            data = pg.evaluate("""() => {
                const c = document.getElementById('frame');
                return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height)
                                  .data);}""")
        finally:
            browser.close()
    canvas = np.array(data, np.float64).reshape(48, 64, 4)[..., :3]
    assert np.abs(canvas - fr.display).mean() < 4
    assert errors == []
