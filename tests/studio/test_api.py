"""The studio over its WebSocket API (no browser): frames, bad input, isolation between
clients, latest-wins, progressive refinement, saving, static files."""

from __future__ import annotations

import io
import json
import urllib.error
import urllib.request

import numpy as np
import pytest
from PIL import Image

from tests.studio.conftest import SIZE, run_clients

BAD = [
    {"type": "method", "name": "no_such_method"},
    {"type": "method", "name": "reference"},  # registered, not interactive
    '{"type": "pick", "x": NaN, "y": 10}',
    '{"type": "drag", "x": 1e308, "y": 10}',
    {"type": "pick", "x": 10 * SIZE[0], "y": 10},
    {"type": "pose", "object": "bunny", "scale": 1e30},
    {"type": "pose", "object": "bunny", "yaw_deg": 1e300},
    {"type": "pose", "object": "teapot", "scale": 2},
    {"type": "save", "name": "../escape"},
    {"type": "save", "name": "/tmp/abs"},
    {"type": "layer", "name": "error"},  # the demo has no ground truth
    {"type": "drag", "x": 10, "y": 10},  # nothing picked yet
    "{not json",
    json.dumps({"type": "reset", "pad": "x" * 10000}),
]


def _image(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _latest_session(engine):
    return max(engine.sessions, key=lambda s: s.id)


def test_first_frame_and_bad_input_answered_with_errors(studio_server, studio_engine):
    async def go(a, b):
        h, img = await a.wait_frame()
        assert a.info["width"] == SIZE[0] and h["method"] == "dir"
        assert _image(img).shape == (SIZE[1], SIZE[0], 3)
        await b.wait_frame()
        for bad in BAD:
            await a.send(bad)
            err = await a.wait_json("error")
            assert err["message"], bad
        # binary messages too
        await a.ws.send_bytes(b"\x00\x01")
        assert "binary" in (await a.wait_json("error"))["message"]
        # the connection still works ...
        await a.send({"type": "pick", "x": 5.0, "y": 115.0})
        assert (await a.wait_json("picked"))["object"] is None
        # ... and the other client saw none of it and still renders
        await b.send({"type": "pose", "object": "bunny", "yaw_deg": 45, "seq": 1})
        h, _ = await b.wait_frame(lambda h: h["seq"] == 1)
        assert h["objects"]["bunny"]["yaw_deg"] == 45
        assert not [m for m in b.json if m["type"] == "error"]
        return True

    assert run_clients(studio_server, go, n=2)


def test_oversized_message_closes_only_that_connection(studio_server):
    async def go(a):
        await a.wait_frame()
        await a.ws.send_str("x" * (2 << 20))  # beyond the 1 MiB WebSocket limit
        with pytest.raises(AssertionError, match="connection ended"):
            for _ in range(10):
                await a.next(timeout=30)

    run_clients(studio_server, go)

    async def again(a):  # the server runs on
        h, _ = await a.wait_frame()
        return h["type"]

    assert run_clients(studio_server, again) == "frame"


def test_a_burst_of_drags_renders_the_newest_not_a_queue(studio_server, studio_engine):
    proxy = studio_engine.proxy
    rest = studio_engine.rest_poses["bunny"]

    async def go(a):
        await a.wait_frame()
        head = proxy.project(rest.position + [0, 0.05, 0])
        await a.send({"type": "pick", "x": head[0], "y": head[1]})
        assert (await a.wait_json("picked"))["object"] == "bunny"
        xs = np.linspace(head[0], 30.0, 40)
        for i, x in enumerate(xs):
            await a.send({"type": "drag", "x": float(x), "y": head[1] + 15.0, "seq": 100 + i})
        h, _ = await a.wait_frame(lambda h: h["seq"] == 139)
        return h, len(a.frames)

    h, frames = run_clients(studio_server, go)
    assert frames < 15  # 40 drags, far fewer frames: no stale queue
    # the newest drag decided the pose: the anchor stands on the table under pointer + grab
    head = proxy.project(rest.position + [0, 0.05, 0])
    grab = np.subtract(proxy.project(rest.position), head)
    want = np.add((30.0, head[1] + 15.0), grab)
    got = proxy.project(np.array(h["objects"]["bunny"]["position"]))
    np.testing.assert_allclose(got, want, atol=1e-3)


def test_progressive_refinement_equals_arlight_render_progressive(studio_server,
                                                                  studio_engine):
    from arlight.methods import RenderSettings
    from arlight.progressive import refine

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "method", "name": "onepass", "seq": 5})
        await a.wait_frame(lambda h: h["seq"] == 5 and h["refine"] >= 3, timeout=180)
        s = _latest_session(studio_engine)
        # read the session between two worker jobs (the worker refines on)
        return studio_engine.call(lambda: (s.refine, s.images["composite"].copy())).result(60)

    n, image = run_clients(studio_server, go)
    assert n >= 3

    def reference():
        steps = list(refine(studio_engine.scene, "onepass", RenderSettings(spp=1, seed=0),
                            frames=n))
        return steps[-1].image

    want = studio_engine.call(reference).result(300)
    assert np.array_equal(image, want)


def test_exposure_and_layer_re_encode_without_rendering(studio_server, studio_engine):
    async def go(a):
        h0, img0 = await a.wait_frame()
        await a.send({"type": "exposure", "ev": 2.0})
        h1, img1 = await a.wait_frame(lambda h: h["exposure"] == 2.0)
        await a.send({"type": "layer", "name": "mask"})
        h2, img2 = await a.wait_frame(lambda h: h["layer"] == "mask")
        return (h0, _image(img0)), (h1, _image(img1)), (h2, _image(img2))

    (h0, i0), (h1, i1), (h2, i2) = run_clients(studio_server, go)
    assert h0["version"] == h1["version"] == h2["version"]  # no new render
    assert i1.astype(float).mean() > i0.astype(float).mean() + 20  # +2 EV is brighter
    # the mask: white on the bunny (image centre), black on the table corner
    assert i2[70, 80].mean() > 200 and i2[115, 5].max() < 30


def test_save_writes_a_scene_that_loads_with_the_new_pose(studio_server, studio_engine):
    from arlight.scene.load import load_scene

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "place", "object": "bunny", "x": 40.0, "y": 90.0, "seq": 1})
        await a.send({"type": "pose", "object": "bunny", "yaw_deg": 30.0, "scale": 1.5,
                      "seq": 2})
        h, _ = await a.wait_frame(lambda h: h["seq"] == 2)
        await a.send({"type": "save", "name": "moved"})
        return h, await a.wait_json("saved")

    h, saved = run_clients(studio_server, go)
    folder = studio_engine.save_dir
    assert saved["scene"] == "moved.toml" and (folder / "moved.png").is_file()
    sc = load_scene(folder / "moved.toml")
    bunny = next(s for s in sc.shapes if s.name == "bunny")
    rest = next(s for s in studio_engine.full.shapes if s.name == "bunny")
    pose = studio_engine.rest_poses["bunny"].moved_to(
        np.array(h["objects"]["bunny"]["position"])).with_(30.0, 1.5)
    np.testing.assert_allclose(bunny.to_world, pose.matrix() @ rest.to_world, atol=1e-9)
    assert sc.raw["render"]["method"] == "dir"
    assert sc.resolution == studio_engine.full.resolution  # saved at the scene's size
    assert np.array_equal(sc.frame_codes, studio_engine.full.frame_codes)


def test_save_never_overwrites_the_scene_inputs(studio_server, studio_engine, tmp_path,
                                                monkeypatch):
    # the engine's inputs include the scene file and every file it references
    from arlight.demo import DEMO_DIR

    for name in ("scene.toml", "frame.png", "bunny.ply", "lebombo_512x256.hdr"):
        assert (DEMO_DIR / name).resolve() in studio_engine.inputs
    # a save folder holding an input (here a stand-in, so that a broken check cannot
    # overwrite the bundled scene): refused, the file untouched
    sentinel = tmp_path / "scene.toml"
    sentinel.write_text("original")
    monkeypatch.setattr(studio_engine, "save_dir", tmp_path.resolve())
    monkeypatch.setattr(studio_engine, "inputs", {*studio_engine.inputs, sentinel.resolve()})

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "save", "name": "scene"})
        return await a.wait_json("error")

    err = run_clients(studio_server, go)
    assert "input of the scene" in err["message"]
    assert sentinel.read_text() == "original"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]


@pytest.mark.parametrize("path", ["static/../engine.py", "static/%2E%2E%2Fengine.py",
                                  "static/..%2F..%2Fscene.toml", "static/index.html",
                                  "static/%2Fetc%2Fpasswd", "../../etc/passwd"])
def test_static_files_are_a_fixed_list(studio_server, path):
    # with the token too: a path outside the fixed list is never served
    with pytest.raises(urllib.error.HTTPError) as err:
        urllib.request.urlopen(f"{studio_server.base_url}/{path}?token={studio_server.token}",
                               timeout=30)
    assert err.value.code in (403, 404)


def test_page_and_assets_are_served(studio_server):
    page = urllib.request.urlopen(studio_server.url, timeout=30).read().decode()
    assert "/static/studio.js" in page and "http" not in page.replace("http-equiv", "")
    assert studio_server.token not in page  # the token stays in the URL, not the page
    js = urllib.request.urlopen(studio_server.base_url + "/static/studio.js",
                                timeout=30).read()
    assert b"new WebSocket" in js


def test_holding_an_object_pauses_refinement_until_release(studio_server, studio_engine):
    import asyncio

    rest = studio_engine.rest_poses["bunny"]
    head = studio_engine.proxy.project(rest.position + [0.0, 0.04, 0.0])

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "method", "name": "onepass", "seq": 1})
        await a.wait_frame(lambda h: h["seq"] == 1 and h["refine"] >= 2, timeout=180)
        await a.send({"type": "pick", "x": head[0], "y": head[1]})
        assert (await a.wait_json("picked"))["object"] == "bunny"
        s = _latest_session(studio_engine)
        n0 = studio_engine.call(lambda: s.refine).result(60)
        await asyncio.sleep(1.0)  # four times the idle delay: held, so no refinement
        n1 = studio_engine.call(lambda: s.refine).result(60)
        await a.send({"type": "release"})
        h, _ = await a.wait_frame(lambda h: h["refine"] > n1, timeout=120)
        return n0, n1, h["refine"]

    n0, n1, n2 = run_clients(studio_server, go)
    assert n1 == n0 and n2 > n1


def test_a_failing_render_is_reported_to_its_tab_only(studio_server, studio_engine,
                                                      monkeypatch):
    failing: set[int] = set()
    render = studio_engine._render

    def flaky(s, refine, settle=False):
        if s.id in failing:
            raise RuntimeError("render exploded")
        return render(s, refine, settle)

    monkeypatch.setattr(studio_engine, "_render", flaky)

    async def go(a, b):
        await a.wait_frame()
        await b.wait_frame()
        failing.add(_latest_session(studio_engine).id - 1)  # a's session (opened first)
        await a.send({"type": "pose", "object": "bunny", "yaw_deg": 10, "seq": 1})
        await b.send({"type": "pose", "object": "bunny", "yaw_deg": 20, "seq": 1})
        err = await a.wait_json("error")
        hb, _ = await b.wait_frame(lambda h: h["seq"] == 1)
        failing.clear()  # the tab recovers with its next change
        await a.send({"type": "pose", "object": "bunny", "yaw_deg": 30, "seq": 2})
        ha, _ = await a.wait_frame(lambda h: h["seq"] == 2)
        return err, hb, ha, [m for m in b.json if m["type"] == "error"]

    err, hb, ha, b_errors = run_clients(studio_server, go, n=2)
    assert "render exploded" in err["message"]
    assert hb["objects"]["bunny"]["yaw_deg"] == 20 and not b_errors
    assert ha["objects"]["bunny"]["yaw_deg"] == 30
