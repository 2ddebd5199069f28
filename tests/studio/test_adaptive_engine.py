"""Adaptive resolution in the running studio (issue #32): a drag frame is rendered
downscaled and upsampled to the studio's size, its header says so and gives its latency,
and once the pointer rests the same state is rendered once at full size."""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
from PIL import Image

from arlight.layers import upsample
from arlight.studio.adaptive import ScaleController
from tests.studio.conftest import SIZE, run_clients


def test_drag_frames_are_downscaled_then_refined_once_at_rest(studio_server, studio_engine,
                                                             monkeypatch):
    """Rejects: a drag frame rendered at full size although over budget; a downscaled
    frame that is not the render at that size upsampled and composited over the photo; a
    studio that never goes back to full size at rest, or keeps re-rendering it; a drag
    frame not rendered with ``drag_threads`` Dr.Jit workers and evaluated calls, or a
    full-size frame left with them; an evaluated-call drag frame that is not bit for bit
    the symbolic render; a rest that shows the antialiased frame without the one-sample
    full-size preview first (dir takes 4 G-buffer samples), a preview rendered with more
    than one sample, or a preview left on screen (no antialiased frame after it)."""
    import drjit as dr

    from arlight.methods import get_method
    from arlight.methods.dir import DIRMethod
    from arlight.studio.engine import _transforms

    eng = studio_engine
    threads = []  # (width rendered, Dr.Jit workers) of each dir frame
    plain = DIRMethod.render

    spps = []  # (width rendered, gbuffer_spp) of each dir frame

    def render(self, state, view, settings=None):
        threads.append((view.camera.width, dr.thread_count(),
                        dr.flag(dr.JitFlag.SymbolicCalls)))
        spps.append((view.camera.width, self.options(settings).gbuffer_spp))
        return plain(self, state, view, settings)

    monkeypatch.setattr(DIRMethod, "render", render)
    default = eng.call(dr.thread_count).result(60)
    monkeypatch.setattr(eng.config, "drag_threads", default + 1)  # not the default
    assert eng.factors == (1, 2)
    slow = ScaleController(eng.factors, budget_s=1e-9)  # nothing fits: the coarsest
    slow.observe(1, 1.0)
    monkeypatch.setattr(eng, "_scales", {"dir": slow})
    monkeypatch.setattr(eng, "rest_s", 1.0)  # time to read the downscaled frame's layers
    rest = eng.rest_poses["bunny"]
    head = eng.proxy.project(rest.position + [0.0, 0.05, 0.0])

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "pick", "x": head[0], "y": head[1]})
        assert (await a.wait_json("picked"))["object"] == "bunny"
        await a.send({"type": "drag", "x": head[0] - 20.0, "y": head[1] + 10.0, "seq": 7})
        small, img = await a.wait_frame(lambda h: h["seq"] == 7)
        s = max(eng.sessions, key=lambda s: s.id)
        shown = eng.call(lambda: (dict(s.poses), s.images["composite"].copy())).result(60)
        first, _ = await a.wait_frame(lambda h: h["seq"] == 7 and h["factor"] == 1,
                                      timeout=60)
        full, _ = await a.wait_frame(lambda h: h["seq"] == 7 and h["factor"] == 1
                                     and not h["preview"], timeout=60)
        try:  # nothing more: the preview and one antialiased frame at rest, not a loop
            extra = await a.next(timeout=1.0)
        except TimeoutError:
            extra = None
        return small, img, shown, first, full, extra

    small, img, (poses, composite), first, full, extra = run_clients(studio_server, go)
    assert first["preview"] and not small["preview"]
    assert [spp for w, spp in spps if w == SIZE[0]][-2:] == [1, 4]
    assert (small["factor"], small["width"], small["height"]) == (2, SIZE[0] // 2,
                                                                  SIZE[1] // 2)
    assert np.asarray(Image.open(io.BytesIO(img))).shape == (SIZE[1], SIZE[0], 3)
    assert 0 < small["latency_ms"] < full["latency_ms"]
    assert full["latency_ms"] >= 1000.0  # rendered only after the 1 s rest
    assert (full["width"], full["height"]) == SIZE and not full["superseded"]
    assert extra is None
    assert (SIZE[0] // 2, default + 1, False) in threads
    assert threads[-1] == (SIZE[0], default, True)
    assert {w for w, n, _ in threads if n == default + 1} == {SIZE[0] // 2}
    assert {w for w, _, symbolic in threads if not symbolic} == {SIZE[0] // 2}
    assert 0 < small["stats"]["footprint"] <= 1 and small["stats"]["wait_s"] >= 0
    assert "footprint" not in full["stats"]
    monkeypatch.undo()

    def expected():
        fn = get_method("dir")
        view = replace(eng.views[2], object_transforms=_transforms(poses))
        drag = eng._drag["dir"]  # dir's drag options: its own state and settings at 1/2
        assert drag.settings(2).options["vpls"] < 256
        layers = fn.render(drag.state(2), view, drag.settings(2))
        h, w = SIZE[1], SIZE[0]
        m, d, k = (upsample(x, h, w) for x in (layers.mixed, layers.delta, layers.mask))
        from arlight.layers import composite as comp

        return comp(eng.view.frame, m, d, k)

    want = eng.call(expected).result(120)  # symbolic calls: the worker's default
    np.testing.assert_array_equal(composite, want)


def test_prepared_states_are_out_of_the_collectors_reach(studio_engine):
    """After a state arrives from a preparation thread the worker freezes the heap, so a
    full collection does not scan the prepared states during a drag. Rejects a worker that
    never freezes it."""
    import gc

    studio_engine.prepared("dir")
    studio_engine.call(lambda: None).result(60)  # the worker has taken the handoff
    assert gc.get_freeze_count() > 1000
