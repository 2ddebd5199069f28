"""The studio's denoise toggle (issue #31): a refining Monte Carlo method shows the denoised
running mean of its raw frames — the image ``arlight render --progressive`` with
``denoise = oidn`` gives — and a malformed toggle is refused."""

from __future__ import annotations

import numpy as np
import pytest

from tests.studio.conftest import run_clients, studio_engine, studio_server  # noqa: F401

pytest.importorskip("pyoidn")


def _latest_session(engine):
    return max(engine.sessions, key=lambda s: s.id)


def test_denoise_toggle_shows_the_denoised_running_mean(studio_server,  # noqa: F811
                                                        studio_engine):  # noqa: F811
    """Rejects: the toggle ignored, a mean of denoised frames (it differs from the
    denoised mean), a toggle accepted with a non-boolean value."""
    from arlight.methods import RenderSettings
    from arlight.progressive import refine

    async def go(a):
        await a.wait_frame()
        await a.send({"type": "denoise", "on": "yes"})
        err = await a.wait_json("error")
        await a.send({"type": "method", "name": "onepass", "seq": 5})
        await a.send({"type": "denoise", "on": True, "seq": 6})
        head, _ = await a.wait_frame(lambda h: h["seq"] == 6 and h["refine"] >= 3,
                                     timeout=240)
        s = _latest_session(studio_engine)
        n, image = studio_engine.call(
            lambda: (s.refine, s.images["composite"].copy())).result(60)
        return err, head, n, image

    err, head, n, image = run_clients(studio_server, go)
    assert "denoise" in err["message"]
    assert "time_denoise" in head["stats"] or "time_render" in head["stats"]

    def reference():
        steps = list(refine(studio_engine.scene, "onepass",
                            RenderSettings(spp=1, seed=0, options={"denoise": "oidn"}),
                            frames=n))
        return steps[-1].image, steps[-1].layers

    want, last = studio_engine.call(reference).result(300)
    assert np.allclose(image, want, atol=1e-5)
    # not the plain running mean of the raw frames
    plain = studio_engine.call(lambda: list(refine(
        studio_engine.scene, "onepass", RenderSettings(spp=1, seed=0), frames=n))[-1].image
    ).result(300)
    assert not np.allclose(image, plain, atol=1e-4)
