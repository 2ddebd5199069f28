"""The virtual objects' shadows on real surfaces in ``dir`` and ``dlpv`` (issue #33):
:func:`arlight.realtime.shading.direct_change` (shadow rays, soft for extended lights) and
dlpv's ``direct = rays``, against Mitsuba's own direct-only render of the world (``path``,
max_depth 2: the photograph without and with the cube) — independent code. The cube is
black and the floor the only real surface: no bounce, the change is the shadow alone."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.realtime.gbuffer import render_gbuffer
from arlight.realtime.light_reduction import ReducedLight, reduce_lights
from arlight.realtime.shading import (
    direct_change,
    direct_irradiance,
    direct_terms_gbuffer,
    r2_point,
    shadow_ray,
)
from arlight.scene.load import parse_scene
from tests.shadow_worlds import AREA, LUM, shadow_error, shadow_scene


def _removed(scene, photo, samples: int, area_grid: int = 1):
    """Per floor pixel: the share of its direct light the cube takes away, Mitsuba's
    ``(B − GT)/B`` and the model's ``−ΔE_d / E_r`` (:func:`direct_change` over the real
    scene's :func:`direct_irradiance`), and the floor mask."""
    views = build_views(scene.world)
    lights = reduce_lights(scene.world, area_grid=area_grid)
    gb = render_gbuffer(views.mixed, scene.camera, 1, 0)
    real = gb.valid & ~gb.virtual
    d = direct_change(views, lights, gb.position, gb.normal, real, samples)
    e = direct_irradiance(views.real, lights, gb.position, gb.normal, real)
    h, w = scene.camera.height, scene.camera.width
    dm = np.array(d, np.float64).T.reshape(h, w, 3) @ LUM
    em = np.array(e, np.float64).T.reshape(h, w, 3) @ LUM
    fr = np.asarray(photo.frame, np.float64) @ LUM
    gt = np.asarray(photo.ground_truth, np.float64) @ LUM
    floor = np.array(real, bool).reshape(h, w) & (np.asarray(photo.mask).reshape(h, w) < 1e-6)
    floor &= (fr > 1e-3) & (em > 1e-6)
    return (fr - gt) / np.maximum(fr, 1e-9), -dm / np.maximum(em, 1e-9), floor


def test_point_shadow_matches_mitsuba(point_world):
    """Under a point light the shadow rays' change removes, pixel by pixel, the share of
    the floor's direct light that Mitsuba's render loses (mean absolute difference of the
    removed share < 0.03 over the floor, core ≥ 0.95 removed in both). Rejects the first
    shadow ray traced in the real scene instead of the mixed one (no shadow at all;
    mutation-checked) and a change without the light's cosine (the removed share would
    exceed 1 on the grazing floor)."""
    scene, photo = point_world
    want, got, floor = _removed(scene, photo, 1)
    core = floor & (want > 0.9)
    assert core.sum() > 30
    assert np.abs(got - want)[floor].mean() < 0.03, np.abs(got - want)[floor].mean()
    assert got[core].mean() > 0.95


def test_area_light_soft_shadow_matches_mitsuba(area_world):
    """Under an area light (reduced to one cosine point) Mitsuba's shadow has a wide
    penumbra. With 32 shadow rays over the patch the removed share in the penumbra
    (Mitsuba removes 10–90 %) is within 0.1 of Mitsuba's on average; the hard shadow of
    the reduced point (``shadow_samples = 1``, the wrong implementation this rejects:
    a point's shadow for an extended light) is off by > 0.2 there."""
    scene, photo = area_world
    want, soft, floor = _removed(scene, photo, 32)
    _, hard, _ = _removed(scene, photo, 1)
    pen = floor & (want > 0.1) & (want < 0.9)
    assert pen.sum() > 100
    e_soft = np.abs(soft - want)[pen].mean()
    e_hard = np.abs(hard - want)[pen].mean()
    assert e_soft < 0.1, (e_soft, e_hard)
    assert e_hard > 0.2, (e_soft, e_hard)


def test_gbuffer_samples_split_the_shadow_rays_of_a_pixel(area_world):
    """With ``n`` G-buffer samples per pixel :func:`direct_terms_gbuffer` splits an extended
    light's ``K`` points over the pixel's samples (``K/n`` rays each, one lattice per pixel):
    on a G-buffer whose 4 samples of a pixel lie at one point, the pixel's mean change equals
    the one-sample change with all ``K`` points (float rounding of the points flips a ray
    on < 1 % of the floor), and it still matches Mitsuba's penumbra. Rejects samples that
    each take the same ``K/n`` points (the pixel's mean is then a ``K/n``-ray estimate: 9 %
    of the floor off), an unnormalised share (``lost/K`` instead of the share cast: 4 × too
    weak, 11 % off) and a rotation per lane instead of per pixel (the samples' points no
    longer form one lattice: 9 % off); mutation-checked."""
    scene, photo = area_world
    views = build_views(scene.world)
    lights = reduce_lights(scene.world, area_grid=1)
    one = render_gbuffer(views.mixed, scene.camera, 1, 0)
    n, k = 4, 32
    lane = dr.arange(mi.UInt32, dr.width(one.pixel) * n) // n
    rep = type(one)(*(dr.gather(type(a), a, lane) for a in (
        one.position, one.normal, one.albedo, one.role, one.depth, one.pixel,
        one.to_camera)), n, one.width, one.height)
    h, w = scene.camera.height, scene.camera.width
    full = np.array(direct_terms_gbuffer(views, lights, one, one.valid & ~one.virtual, k).change,
                    np.float64).T.reshape(h, w, 3) @ LUM
    split = (np.array(direct_terms_gbuffer(views, lights, rep, rep.valid & ~rep.virtual, k).change,
                      np.float64).T.reshape(h, w, n, 3) @ LUM).mean(axis=2)
    want, _, floor = _removed(scene, photo, 1)
    pen = floor & (want > 0.1) & (want < 0.9)
    scale = np.abs(full[floor]).max()
    assert scale > 0 and pen.sum() > 100
    off = np.abs(split - full) > 1e-4 * scale
    assert off[floor].mean() < 0.01, off[floor].mean()
    e = direct_irradiance(views.real, lights, one.position, one.normal,
                          one.valid & ~one.virtual)
    em = np.array(e, np.float64).T.reshape(h, w, 3) @ LUM
    got = -split / np.maximum(em, 1e-9)
    assert np.abs(got - want)[pen].mean() < 0.1


def _cosine_irradiance(lights, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Unshadowed irradiance (W/m², ``(N, 3)``) of reduced ``cosine`` lights at points ``p``
    with normals ``n``, from the equation ``E = I0 <a, −ω>+ <n, ω>+ / d²`` (NumPy, not the
    module's code)."""
    out = np.zeros((len(p), 3))
    for lt in lights.lights:
        assert lt.kind == "cosine"
        to = np.asarray(lt.position, np.float64) - p
        d = np.linalg.norm(to, axis=1, keepdims=True)
        w = to / d
        cos_l = np.maximum(-(w @ np.asarray(lt.axis, np.float64)), 0.0)
        cos_s = np.maximum(np.sum(n * w, axis=1), 0.0)
        out += np.asarray(lt.intensity, np.float64)[None] * (cos_l * cos_s)[:, None] / d ** 2
    return out


def _lanes(x, h: int, w: int, spp: int = 1) -> np.ndarray:
    return np.array(x, np.float64).T.reshape(h, w, spp, -1)


def test_shared_rays_give_the_real_scenes_irradiance_without_the_virtual_object(area_world):
    """``direct_terms_gbuffer``'s ``real`` (the direct part of the photograph's model
    irradiance ``E_r``, from the direct change's own shadow rays) is the real scene's
    irradiance: the floor here has no real occluder, so it is the unshadowed irradiance of
    the equation (NumPy, :func:`_cosine_irradiance`) on every floor lane, within float
    rounding — in the cube's shadow too, at 1 and 4 G-buffer samples, 32 rays and 1. Rejects
    ``V_ρ`` (the mixed scene's visibility, the cube's shadow in ``E_r``: ρ̂ would explode
    there), counting the rays the virtual object blocks as shaded, and a share that is not
    normalised by the rays cast (``K`` × too bright); mutation-checked."""
    scene, _ = area_world
    views = build_views(scene.world)
    lights = reduce_lights(scene.world, area_grid=1)
    h, w = scene.camera.height, scene.camera.width
    for spp in (1, 4):
        gb = render_gbuffer(views.mixed, scene.camera, spp, 0)
        real = gb.valid & ~gb.virtual
        for k in (1, 32):
            terms = direct_terms_gbuffer(views, lights, gb, real, k)
            sel = np.array(real, bool)
            p = np.array(gb.position, np.float64).T[sel]
            n = np.array(gb.normal, np.float64).T[sel]
            want = _cosine_irradiance(lights, p, n)
            got = np.array(terms.real, np.float64).T[sel]
            change = np.array(terms.change, np.float64).T[sel]
            assert (change < -1e-3 * want.max()).sum() > 50  # the cube's shadow is there
            np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6 * want.max())
            assert _lanes(terms.real, h, w, spp)[~np.array(real, bool).reshape(
                h, w, spp)].max() == 0.0


def test_shared_rays_give_the_real_occluders_soft_shadow(area_world):
    """With the cube made real (no virtual object: the mixed view is the real one, every
    blocked ray blocked in the real scene) ``real`` / the unshadowed irradiance is the
    visible share of the area light: within 0.1 of Mitsuba's (its render of the cube,
    ground truth / photograph, black cube, direct light only) on average over the
    penumbra at 32 rays split over 4 G-buffer samples (measured 0.08), where the reduced
    point's hard shadow (one ray, the central ray ``E_r`` used to trace) is off by > 0.2
    (0.31). Rejects
    ``real`` that drops the rays blocked in the real scene from the share cast (then it
    would be unshadowed) or counts only the last ray; mutation-checked."""
    scene, photo = area_world
    data = shadow_scene(AREA)
    data["shapes"][1]["role"] = "real"
    solid = parse_scene(data)
    views = build_views(solid.world)
    lights = reduce_lights(solid.world, area_grid=1)
    h, w = solid.camera.height, solid.camera.width
    want, _, floor = _removed(scene, photo, 1)
    pen = floor & (want > 0.1) & (want < 0.9)
    assert pen.sum() > 100
    errs = {}
    for k, spp in ((32, 4), (1, 1)):
        gb = render_gbuffer(views.mixed, solid.camera, spp, 0)
        real = gb.valid
        terms = direct_terms_gbuffer(views, lights, gb, real, k)
        sel = np.array(real, bool)
        e0 = np.zeros((dr.width(real), 3))
        e0[sel] = _cosine_irradiance(lights, np.array(gb.position, np.float64).T[sel],
                                     np.array(gb.normal, np.float64).T[sel])
        got = np.array(terms.real, np.float64).T @ LUM
        vis = (got / np.maximum(e0 @ LUM, 1e-12)).reshape(h, w, spp).mean(axis=2)
        errs[k] = float(np.abs((1.0 - vis) - want)[pen].mean())
    assert errs[32] < 0.1 and errs[1] > 0.2, errs


def test_r2_point_per_lane_is_the_lattice():
    """``r2_point`` per lane (``mi.Float``, as the shadow rays use it) equals the R2
    lattice of Roberts (2018) computed here in double precision, ``frac(0.5 + j/φ₂^d)``
    with the plastic number from its cubic ``x³ = x + 1`` (Newton). Rejects the golden
    ratio's lattice and a missing 0.5 offset."""
    g = 1.3
    for _ in range(50):
        g -= (g ** 3 - g - 1) / (3 * g * g - 1)
    j = np.arange(64)
    want = np.stack([(0.5 + j / g) % 1.0, (0.5 + j / g ** 2) % 1.0], 1)
    got = np.stack([np.array(c, np.float64) for c in r2_point(mi.Float(j))], 1)
    assert np.abs(got - want).max() < 1e-5
    assert np.abs(np.array(r2_point(5)) - want[5]).max() < 1e-12


def test_cone_samples_cover_the_spread():
    """``shadow_ray`` of a directional light with ``spread`` α: every direction within α
    of the light's, and their mean cosine to it ``(1 + cos α)/2``, a uniform cone's
    (computed here, not by the module). Rejects samples uniform in angle (mean cosine
    higher) or a cone of the wrong size."""
    alpha = math.radians(12.0)
    axis = np.array([0.3, -1.0, 0.2])
    axis /= np.linalg.norm(axis)
    lt = ReducedLight("directional", np.zeros(3), axis, np.ones(3), spread=alpha)
    n = 4096
    u = (mi.Float(np.random.default_rng(1).random(n)),
         mi.Float(np.random.default_rng(2).random(n)))
    ray = shadow_ray(lt, mi.Point3f(0.0), u)
    d = np.array(ray.d, np.float64).T.reshape(-1, 3)
    c = d @ -axis
    assert c.min() >= math.cos(alpha) - 1e-6
    assert abs(c.mean() - (1 + math.cos(alpha)) / 2) < 2e-4
    assert dr.width(ray.d) == n


def test_dlpv_shadow_from_rays_matches_mitsuba(point_world):
    """dlpv's shadow with ``direct = rays`` (``lost_bounce`` off) against Mitsuba's
    direct-only render: its error on the changed floor pixels below 10 % of the change
    (:func:`shadow_error`; measured 0.04 at 4 G-buffer samples per pixel — at one, 0.14
    is the aliased shadow edge), as dir's; Franke's direct lobes in ``V_Δ`` (``direct =
    volume``: the thesis's "blurry circular blob", the wrong implementation this rejects)
    above 20 % (0.26), and no direct change (``none``) 0.68."""
    scene, photo = point_world
    small = {"volume_size": 16, "steps": 16, "rsm_size": 128, "gbuffer_spp": 4}
    rays = shadow_error(scene, photo, "dlpv", **small, direct="rays", lost_bounce=False)
    blob = shadow_error(scene, photo, "dlpv", **small, direct="volume")
    knecht = shadow_error(scene, photo, "dir", gbuffer_spp=4, vpls=64)
    assert rays < 0.1 and knecht < 0.1 and blob > 0.2, (rays, knecht, blob)
