"""Eight tabs dragging at once (slow: the 60 s version is benchmarks/bench_studio.py)."""

from __future__ import annotations

import asyncio
import random
import time

import pytest

from tests.studio.conftest import SIZE, run_clients


@pytest.mark.slow
def test_eight_clients_dragging_get_frames_and_no_errors(studio_server, studio_engine):
    rest = studio_engine.rest_poses["bunny"]
    head = studio_engine.proxy.project(rest.position + [0.0, 0.04, 0.0])

    async def one(client, seed):
        rng = random.Random(seed)
        await client.wait_frame()
        await client.send({"type": "pick", "x": head[0], "y": head[1]})
        await client.wait_json("picked")
        for i in range(100):
            await client.send({"type": "drag", "x": rng.uniform(10, SIZE[0] - 10),
                               "y": rng.uniform(0.6 * SIZE[1], SIZE[1] - 2), "seq": i + 1})
            await asyncio.sleep(0.05)
        await client.wait_frame(lambda h: h["seq"] == 100, timeout=300)
        return [m for m in client.json if m["type"] == "error"], len(client.frames)

    async def go(*clients):
        return await asyncio.gather(*[one(c, i) for i, c in enumerate(clients)])

    results = run_clients(studio_server, go, n=8)
    assert all(errors == [] for errors, _ in results)
    assert all(frames >= 2 for _, frames in results)
    assert studio_engine._thread.is_alive()
    end = time.monotonic() + 30  # the server closes the sessions as the sockets close
    while studio_engine.sessions and time.monotonic() < end:
        time.sleep(0.1)
    assert not studio_engine.sessions
