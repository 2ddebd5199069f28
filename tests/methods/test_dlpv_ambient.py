"""The virtual object's shadow of the SH ambient remainder on real surfaces, for ``dlpv`` and
``dir`` (issue #33, :mod:`arlight.realtime.ambient`), against Mitsuba's path tracer.

Scene: a white floor under a constant environment (radiance 1, no other light — all of it
is the ambient remainder) and a red cube resting on it. Reference: ``path`` mixed scene
minus real scene — independent code: at ``max_depth`` 2 (direct light only) the floor's
lost sky light, Eq. 1 of :mod:`arlight.realtime.ambient`; at ``max_depth`` 8 also the cube's
reflection of the sky onto the floor, which Eq. 3 models (``ambient_bounce``). Read on the
floor ring 2–6 px around the cube (:class:`~tests.methods.one_bounce.OneBounce`'s regions).
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from arlight.backend.mitsuba_scene import build_views, mitsuba_sensor
from arlight.methods import RenderSettings, get_method
from arlight.realtime.gbuffer import render_gbuffer
from tests.conftest import parsed_with_constant_frame as make
from tests.methods.test_dlpv import box_scene

W, H = 40, 30
PASSES, SPP = 4, 64
BAND = 0.15
"""Tolerance on the ratio of the ring means (method / Mitsuba): the occlusion field holds
the cube's occlusion at SH order 4 and interpolates it between shells; measured 0.97."""
FILL = 0.12
"""Tolerance on the fraction of the lost light the cube's reflection returns (measured: 0.90
vs Mitsuba's 0.81 in red, 0.10 vs 0.09 in green)."""


def _scene():
    """The box scene of ``test_dlpv.py`` without the wall, lit by a constant environment."""
    d = box_scene(w=W, h=H)
    d["shapes"] = [s for s in d["shapes"] if s["name"] != "wall"]
    d["lights"] = [{"type": "constant", "radiance": 1.0}]
    return make(d)


def _render(view, camera, depth: int) -> np.ndarray:
    """Mean of ``PASSES`` Mitsuba ``path`` renders at ``max_depth`` ``depth``, (H, W, 3)."""
    imgs = [np.array(mi.render(view.scene, sensor=mitsuba_sensor(camera, SPP), seed=k,
                               spp=SPP, integrator=mi.load_dict(
                                   {"type": "path", "max_depth": depth})))[..., :3]
            for k in range(PASSES)]
    return np.mean(imgs, axis=0, dtype=np.float64)


@pytest.fixture(scope="module")
def reference():
    """The scene, the floor ring, and Mitsuba's change (mixed − real) at depth 2 and 8."""
    scene = _scene()
    views = build_views(scene.world)
    gb = render_gbuffer(views.mixed, scene.camera, 1, 0)
    role = np.array(gb.role).reshape(H, W)
    ring = (binary_dilation(role == 1, iterations=6)
            & ~binary_dilation(role == 1, iterations=1) & (role == 0))
    delta = {d: _render(views.mixed, scene.camera, d) - _render(views.real, scene.camera, d)
             for d in (2, 8)}
    return scene, ring, delta


def _ring_mean(reference, method: str, **opts) -> np.ndarray:
    """Per channel: the method's mean change (its ``delta`` layer) on the ring."""
    scene, ring, _ = reference
    opts = {"real_albedo": "proxy", **opts}  # the ring's albedo is the proxy's, a constant
    return get_method(method)(scene, RenderSettings(options=opts)).delta[ring].mean(axis=0)


@pytest.mark.parametrize("method", ["dlpv", "dir"])
def test_the_cube_shadows_the_ambient_light_on_the_floor(reference, method):
    """The floor ring loses as much sky light as Mitsuba's direct-only render says (Eq. 1,
    the occlusion field's lookup, ``ambient_bounce`` off): ratio 1 ± ``BAND`` in every
    channel. Rejects the unoccluded ambient remainder (the code before issue #33: no change
    on the real surfaces, ratio 0; mutation-checked)."""
    _, ring, delta = reference
    assert ring.sum() > 50 and np.all(delta[2][ring].mean(axis=0) < -0.01)
    r = _ring_mean(reference, method, ambient_bounce=False) / delta[2][ring].mean(axis=0)
    np.testing.assert_allclose(r, 1.0, atol=BAND)


@pytest.mark.parametrize("method", ["dlpv", "dir"])
def test_the_cube_reflects_the_ambient_light_into_its_shadow(reference, method):
    """With ``ambient_bounce`` (Eq. 3: the blocked sky replaced by the cube's radiance
    ``ρ_v L̄``) the fraction of the lost sky light that comes back, ``1 − Δ_full/Δ_direct``
    on the ring, matches Mitsuba's (full path tracing vs direct only) within ``FILL`` in
    every channel: red ≈ 0.8, green ≈ 0.09 for the red cube (Eq. 3 says 0.9 and 0.1: it
    takes the cube's faces as lit by the whole sky, where its sides see half of it and the
    floor's reflection). Rejects dropping the fill (0 in every channel), a grey fill (the
    mean albedo in both; both mutation-checked) and a fill of the whole environment's
    radiance (1)."""
    _, ring, delta = reference
    ref = 1.0 - delta[8][ring].mean(axis=0) / delta[2][ring].mean(axis=0)
    assert ref[0] > 0.5 and ref[1] < 0.2  # the reference: the red cube fills red
    fill = 1.0 - (_ring_mean(reference, method)
                  / _ring_mean(reference, method, ambient_bounce=False))
    np.testing.assert_allclose(fill, ref, atol=FILL)
