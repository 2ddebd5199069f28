"""The direct change culled light by light inside
:func:`arlight.realtime.shading.direct_terms_gbuffer` (``world=``, ``real_on=``; issue #33):
a lane whose shadow rays to a light cannot meet the ball around the virtual objects
(:func:`arlight.realtime.shadow_reach.light_reach`) traces that light's rays in the real
scene only — ``V_ρ = V_µ`` there — for the real scene's irradiance ``E_µ,d``, and none
where that is not wanted.

Reference: the same function without ``world``, which traces every lane's rays in the
mixed scene and, where blocked, in the real one (itself checked against Mitsuba in
``test_shading_shadows.py``). The world has a real occluder whose shadow falls on lanes
no light can reach the virtual cube from, soft lights (an area light's patch, 8 rays split
over 4 G-buffer samples) and a point light."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.realtime.gbuffer import render_gbuffer
from arlight.realtime.light_reduction import reduce_lights
from arlight.realtime.shading import direct_irradiance, direct_terms_gbuffer, virtual_bounds
from arlight.realtime.shadow_reach import bounding_ball, light_reach
from arlight.scene.load import parse_scene
from tests.shadow_worlds import AREA, shadow_scene

SAMPLES = 8
"""Shadow rays per extended light (split over the pixel's 4 G-buffer samples)."""


@pytest.fixture(scope="module")
def occluded():
    """A floor, the black virtual cube of :func:`~tests.shadow_worlds.shadow_scene`, a real
    post beside it, an area light and a point light; views, reduced lights, a 4-sample
    G-buffer, its real lanes and the lanes each light can reach the cube from."""
    data = shadow_scene({**AREA, "size": [0.2, 0.2]})
    data["shapes"].append({"name": "post", "role": "real", "type": "box",
                           "size": [0.12, 0.5, 0.12],
                           "transform": {"translate": [0.55, 0.25, 0.35]},
                           "material": {"type": "diffuse", "albedo": 0.5}})
    data["lights"].append({"type": "point", "position": [0.2, 1.4, 0.9], "intensity": 2.0})
    scene = parse_scene(data)
    views = build_views(scene.world)
    lights = reduce_lights(scene.world, area_grid=1)
    gb = render_gbuffer(views.mixed, scene.camera, 4, 0)
    real = gb.valid & ~gb.virtual
    centre, radius = bounding_ball(virtual_bounds(scene.world, views.mixed))
    c = mi.Point3f(*(float(x) for x in centre))
    reach = [np.array(real & light_reach(lt, gb.position, c, radius), bool)
             for lt in lights.lights]
    return scene, views, lights, gb, real, reach


def _np(x) -> np.ndarray:
    return np.array(x, np.float64).T


def test_culled_terms_equal_every_lane_traced(occluded):
    """With ``world`` both outputs equal the unculled call's on every lane: the change
    (the cube's shadows) bit for bit, ``E_µ,d`` (the post's soft shadow, on lanes that no
    light can reach the cube from, included) to float rounding (summed in another order);
    each light's mixed-scene rays run on under 80 % of the real lanes. Rejects a cull that
    drops a lane whose rays can meet the cube (``light_reach`` without the ball's angular
    radius ``asin(R/d)``: the change differs) and culled lanes that trace no ray for
    ``E_µ,d`` (read unshadowed: the post's shadow gone); mutation-checked. (Culled lanes
    tracing the mixed scene instead of the real one is an equivalent mutant: neither
    scene's rays meet the cube there.)"""
    scene, views, lights, gb, real, reach = occluded
    full = direct_terms_gbuffer(views, lights, gb, real, SAMPLES)
    cut = direct_terms_gbuffer(views, lights, gb, real, SAMPLES, scene.world)
    f_ch, f_re = _np(full.change), _np(full.real)
    assert np.abs(f_ch).max() > 0.1  # the cube's shadow is there
    sel = np.array(real, bool)
    for near in reach:
        assert near.sum() < 0.8 * sel.sum(), (near.sum(), sel.sum())
    # the post shadows lanes that no light can reach the cube from
    far = sel & ~np.any(reach, axis=0)
    bare = _np(direct_irradiance(views.real, lights, gb.position, gb.normal, real, False))
    post = far & (f_re.sum(1) < 0.5 * bare.sum(1))
    assert post.sum() > 20, post.sum()
    assert np.array_equal(_np(cut.change), f_ch)
    np.testing.assert_allclose(_np(cut.real), f_re, rtol=1e-6, atol=1e-7 * f_re.max())


def test_real_only_where_wanted(occluded):
    """``real_on`` (here: nowhere beyond the reaching lanes, then one image half): ``change``
    is still the unculled one bit for bit, ``real`` equals it (to float rounding) on every
    lane some light can reach the cube from and on the ``real_on`` lanes, and is zero on the
    rest (no rays
    traced there). Rejects ``real`` left out on a lane that one light reaches and another
    does not (the lane's ``E_µ,d`` would miss the second light, and ``ρ̂`` be too bright)
    and ``real_on`` ignored; mutation-checked."""
    scene, views, lights, gb, real, reach = occluded
    full = direct_terms_gbuffer(views, lights, gb, real, SAMPLES)
    f_ch, f_re = _np(full.change), _np(full.real)
    any_reach = np.any(reach, axis=0)
    assert (any_reach & ~np.all(reach, axis=0)).sum() > 20  # reached by some lights only
    half = gb.position.x > 0.0
    for real_on, extra in ((mi.Bool(False), False), (half, np.array(half, bool))):
        got = direct_terms_gbuffer(views, lights, gb, real, SAMPLES, scene.world, real_on)
        wanted = np.array(real, bool) & (any_reach | extra)
        assert np.array_equal(_np(got.change), f_ch)
        np.testing.assert_allclose(_np(got.real)[wanted], f_re[wanted], rtol=1e-6,
                                   atol=1e-7 * f_re.max())
        assert not _np(got.real)[~wanted].any()
        assert (f_re[~wanted] > 0).any()  # a lane left out would have had light


def test_one_far_ray_is_the_central_rays_irradiance(occluded):
    """``far_samples = 1`` (dvct's ``E_r``): on lanes that no light can reach the cube from,
    ``real`` is the reduced lights' irradiance through one central shadow ray each in the
    real scene — :func:`~arlight.realtime.shading.direct_irradiance`, written apart — within
    float rounding, the post's hard shadow included; on lanes every light reaches, the
    soft ``E_µ,d`` of the unculled call; the change unchanged. Rejects ``far_samples``
    ignored (the post's penumbra soft on the far lanes) and the far pass tracing the lanes
    a light reaches again (counted twice there); mutation-checked."""
    scene, views, lights, gb, real, reach = occluded
    full = direct_terms_gbuffer(views, lights, gb, real, SAMPLES)
    got = direct_terms_gbuffer(views, lights, gb, real, SAMPLES, scene.world, None, 1)
    hard = _np(direct_irradiance(views.real, lights, gb.position, gb.normal, real))
    sel = np.array(real, bool)
    far = sel & ~np.any(reach, axis=0)
    every = sel & np.all(reach, axis=0)
    assert far.sum() > 1000 and every.sum() > 100
    g_re = _np(got.real)
    np.testing.assert_allclose(g_re[far], hard[far], rtol=1e-5, atol=1e-6 * hard.max())
    assert np.abs(_np(full.real)[far] - hard[far]).max() > 0.01 * hard.max()  # soft ≠ hard
    np.testing.assert_allclose(g_re[every], _np(full.real)[every], rtol=1e-6,
                               atol=1e-7 * hard.max())
    assert np.array_equal(_np(got.change), _np(full.change))
