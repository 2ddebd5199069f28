"""``dic``: differential irradiance caching (Kán §4.2) against the one-pass path tracer.

Wrong implementations these tests reject: records that also count the light they see
directly (direct light twice), a record path one bounce too long or short, irradiance
without the 1/π of a Lambertian BRDF, real pixels shaded with E_m instead of E_d, a camera
walk without the one-pass shadow rules or the real continuation, re-evaluation with fresh
random numbers (a static sequence flickers), a cache that is not dropped near a moved
object, options out of range accepted.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.methods.dic import DicMethod, DicSequence, render_frame
from arlight.stats import agreement_fraction
from arlight.timing import StageTimer
from arlight.tracing.onepass import OnePassTracer, TracerOptions, lane_keys
from arlight.tracing.scenes import prepare_scenes
from tests.conftest import area_light_scene, diffuse, env_mirror_scene, load, with_constant_frame


def scene_of(d: dict):
    return with_constant_frame(load(d))


def diffuse_scene(width: int = 24, height: int = 18):
    """The area-light room with the virtual ball made Lambertian (all diffuse)."""
    d = area_light_scene(width, height)
    d = copy.deepcopy(d)
    d["shapes"][-1]["material"] = diffuse([0.3, 0.5, 0.8])
    return scene_of(d)


def options(**kw) -> dict:
    return {"rays": 64, **kw}


# ------------------------------------------------------------------ exact identities
# ------------------------------------------------------------ indirect vs path tracer
def _centre_rays(camera, n: int) -> mi.Ray3f:
    h, w = camera.height, camera.width
    v, u = np.mgrid[0:h, 0:w]
    uv = np.repeat(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1), n, axis=0)
    o, d = camera.pixel_rays(uv)
    o, d = o.astype(np.float32), d.astype(np.float32)
    return mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))


def _np(c) -> np.ndarray:
    return np.stack([np.asarray(x, np.float64) for x in (c.x, c.y, c.z)], axis=1)


def path_traced_indirect(scene, n: int, max_depth: int):
    """Per pixel centre: the one-pass tracer's indirect term (paths of ``max_depth`` minus
    paths of 2 vertices, same random numbers) for L_m and L_m − L_r, means and SEs."""
    views = prepare_scenes(scene.world).views
    rays = _centre_rays(scene.camera, n)
    key = lane_keys(dr.width(rays.d), mi.UInt32(11))
    out = []
    for md in (max_depth, 2):
        t = OnePassTracer(views.mixed, views.real, TracerOptions(max_depth=md, reproject=False))
        r = t.trace_onepass(rays, key)
        out.append((_np(r.mixed), _np(r.real)))
    ind_m = out[0][0] - out[1][0]
    ind_d = ind_m - (out[0][1] - out[1][1])
    res = []
    for x in (ind_m, ind_d):
        x = x.reshape(-1, n, 3)
        res.append((x.mean(axis=1), x.std(axis=1, ddof=1) / np.sqrt(n)))
    return res


def test_indirect_term_converges_to_the_one_pass_path_tracer():
    """A record at every pixel (tile 1) that reaches only its own pixel (κ → large): the
    splatted indirect term ρ/π·E is the record's path-traced estimate and must agree with
    the one-pass tracer's indirect term at the pixel centres within 3 SE, for the mixed
    solution and for the differential (E_d) alike, and have no bias over the image."""
    scene = diffuse_scene(24, 18)
    max_depth = 4
    s = RenderSettings(spp=1, max_depth=max_depth, seed=2,
                       options=options(rays=1024, tile=1, accuracy=1000.0, min_radius_px=0.25,
                                       max_radius_px=0.25))
    data = prepare_scenes(scene.world)
    opts = DicMethod.spec.parse_options(s.options)
    res = render_frame(data, scene.view, opts, s, StageTimer())
    geom, recs = res.geometry, res.cache.records
    assert res.layers.stats["iterations"] == 2  # all pixels at once, then nothing missing
    assert len(recs) == int(geom.needs.sum())
    e_m, e_d = res.buffer.irradiance()
    pix = np.flatnonzero(geom.needs)  # records were created in pixel order
    assert np.array_equal(recs.position, geom.position[pix])
    alb = geom.albedo[pix] / np.pi
    real = ~geom.virtual[pix]  # E_d is what real pixels take (virtual ones take E_m)
    dic = {"mixed": (alb * e_m[pix], alb * recs.stderr_mixed),
           "delta": ((alb * e_d[pix])[real], (alb * recs.stderr_delta)[real])}
    (pm, pm_se), (pd, pd_se) = path_traced_indirect(scene, 1024, max_depth)
    pt = {"mixed": (pm[pix], pm_se[pix]), "delta": (pd[pix][real], pd_se[pix][real])}
    assert real.sum() > 0.6 * len(pix) and (~real).sum() > 20
    for name in ("mixed", "delta"):
        a, sa = dic[name]
        b, sb = pt[name]
        frac = agreement_fraction(a[:, None], sa[:, None], b[:, None], sb[:, None])
        assert frac >= 0.99, (name, frac)
        z = (a - b).sum(axis=0) / np.sqrt((sa ** 2 + sb ** 2).sum(axis=0))
        assert np.all(np.abs(z) < 4), (name, z)
    # the term is not trivially zero: the ball darkens the floor next to it
    assert pm[pix].max() > 0.02 and pd[pix][real].min() < -0.01


# ---------------------------------------------------------------- direct light rules
@pytest.mark.slow
@pytest.mark.parametrize("kind", ["area", "env_mirror"])
def test_direct_light_agrees_with_onepass(kind):
    """With paths of two vertices (direct light only; the records are then zero) the camera
    walk — one light sample, one-pass shadow rays, real continuation at virtual hits,
    delta-specular continuation — is an unbiased estimate of what onepass computes. (Slow
    tier: the fast tier checks the stronger sample-by-sample identity of the walk and the
    tracer, ``tests/tracing/test_shared_rules.py``.)"""
    d = area_light_scene(20, 15) if kind == "area" else env_mirror_scene(20, 15)
    scene = scene_of(d)
    s = RenderSettings(spp=256, max_depth=2, seed=4, options=options(rays=4))
    a = get_method("dic")(scene, s)
    b = get_method("onepass")(scene, replace(s, seed=9, options={}))
    for layer in ("mixed", "delta"):
        stderr_a = a.stderr[layer]
        frac = agreement_fraction(getattr(a, layer), stderr_a, getattr(b, layer),
                                  b.stderr[layer])
        assert frac >= 0.99, (layer, frac)
    assert np.array_equal(a.mask > 0, b.mask > 0) or np.mean(a.mask != b.mask) < 0.05


# ------------------------------------------------------------------------ temporal
def test_static_sequence_frames_are_bitwise_identical():
    """Records re-evaluated every frame (t_max = 1) with their own random sequence: frames
    of a static scene are bitwise equal (no flicker)."""
    scene = diffuse_scene(16, 12)
    seq = DicSequence(scene.world, RenderSettings(spp=1, options=options(t_max=1)))
    f1 = seq.render(scene.view)
    f2 = seq.render(scene.view)
    assert f2.stats["records_reevaluated"] == f1.stats["records"] > 0
    assert f2.stats["records_new"] == 0
    for k in ("mixed", "delta", "composite"):
        assert np.array_equal(getattr(f1, k), getattr(f2, k)), k


def test_moved_object_drops_nearby_records_and_updates():
    scene = diffuse_scene(24, 18)
    s = RenderSettings(spp=1, options=options(invalidate_distance=0.2))
    seq = DicSequence(scene.world, s)
    seq.render(scene.view)
    n_before = len(seq.cache.records)
    move = np.eye(4)
    move[:3, 3] = [-0.35, 0.0, 0.25]
    moved_view = replace(scene.view, object_transforms={"ball": move})
    f2 = seq.render(moved_view)
    assert 0 < f2.stats["records_dropped"] < n_before
    assert f2.stats["records_new"] > 0
    fresh = get_method("dic")(replace_view(scene, moved_view), s)
    assert np.array_equal(f2.mask, fresh.mask)
    # the shadow moved with the ball: the frame agrees with a fresh render far better than
    # with the frame before the move
    err_fresh = np.abs(f2.delta - fresh.delta).mean()
    err_old = np.abs(f2.delta - seq_first_delta(scene, s)).mean()
    assert err_fresh < 0.5 * err_old


def replace_view(scene, view):
    from arlight.scene.model import ARScene

    return ARScene.compose(scene.world, view)


def seq_first_delta(scene, s):
    return get_method("dic")(scene, s).delta


# ---------------------------------------------------------------------- bad input
def test_min_radius_above_max_is_refused():
    with pytest.raises(InputError, match="min_radius_px"):
        DicMethod.spec.parse_options({"min_radius_px": 10.0, "max_radius_px": 2.0})


