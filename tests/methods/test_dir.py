"""``dir`` (Knecht et al. 2010, differential instant radiosity). Each test names the wrong
implementation it rejects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.backend.rays import visible
from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.methods.dir import SPEC, frame_vpls, interleave_filter
from arlight.realtime.gbuffer import GBuffer, render_gbuffer
from arlight.realtime.shading import SHADOW_EPS
from tests.methods.test_dlpv import box_scene, make


def run(scene, **opts):
    return get_method("dir")(scene, RenderSettings(options=opts))


def _np(c) -> np.ndarray:
    return np.array(c, np.float64).reshape(3, -1).T


def test_delta_equals_brute_force_instant_radiosity():
    """With interleave 1 the delta equals a NumPy instant-radiosity gather written from Eq.
    2.43/2.45 — every VPL (the frame's aimed, importance-picked VPLs) at every real pixel,
    clamped G, visibility by arlight.backend.rays.visible in the mixed scene for R_ρ and the
    real scene for R_µ — plus the direct-light difference. Rejects visibility traced in the
    wrong scene, an unclamped or wrongly normalised G, and dropping the R_µ VPLs that the
    object hides."""
    scene = make(box_scene(w=24, h=18))
    # the proxy's albedo (the frame is a constant: no photograph to read it from)
    opts = {"vpls": 36, "interleave": 1, "clamp_distance": 0.3, "real_albedo": "proxy",
            "gbuffer_spp": 1}  # one G-buffer sample: the gather at the pixel centres
    method = get_method("dir")
    settings = RenderSettings(options=opts)
    state = method.prepare(scene.world, settings)
    layers = method.render(state, scene.view, settings)
    data = state.data
    gb = render_gbuffer(data.views.mixed, scene.camera, 1, 0)
    vp = frame_vpls(data, gb, SPEC.parse_options(opts), settings.seed)
    x, nx, alb = _np(gb.position), _np(gb.normal), _np(gb.albedo)
    role = np.array(gb.role)
    real = role == 0
    bound = 1.0 / 0.3 ** 2
    e = np.zeros_like(x)
    for r, view, sign in ((vp.rho, data.views.mixed, 1.0), (vp.mu, data.views.real, -1.0)):
        vpos, vn, phi = _np(r.position), _np(r.normal), _np(r.flux_out)
        ok = np.array(r.valid)
        for j in np.nonzero(ok)[0]:
            to = vpos[j] - x
            d = np.linalg.norm(to, axis=1)
            w = to / d[:, None]
            g = np.maximum((nx * w).sum(1), 0) * np.maximum(-(w @ vn[j]), 0) / d**2
            g = np.minimum(g, bound)
            o = x + nx * SHADOW_EPS
            tgt = o + w * (d - 2 * SHADOW_EPS)[:, None]
            vis = visible(view, o, tgt)
            e += sign * (vis * g)[:, None] * phi[j] / math.pi
    # direct: the point light, shadow rays in both scenes
    lt = data.lights.lights[0]
    o = x + nx * SHADOW_EPS
    to = lt.position - o
    d = np.linalg.norm(to, axis=1)
    w = to / d[:, None]
    ed = np.maximum((nx * w).sum(1), 0) / d**2
    vm = visible(data.views.mixed, o, o + w * (d * (1 - 1e-4))[:, None])
    vr = visible(data.views.real, o, o + w * (d * (1 - 1e-4))[:, None])
    e += ((vm.astype(float) - vr) * ed)[:, None] * lt.intensity
    want = np.where(real[:, None], alb / math.pi * e, 0.0).reshape(18, 24, 3)
    assert np.abs(want).max() > 1e-3
    assert np.allclose(layers.delta, want, atol=2e-3 * np.abs(want).max(), rtol=0)


def test_interleaving_keeps_a_uniform_field_and_is_close_to_full_gather():
    """Interleaved sampling + the geometry-aware filter stays close to the full gather (mean
    delta within 10 %) and keeps the shadow; rejects forgetting the k² weight."""
    scene = make(box_scene(w=48, h=36))
    full = run(scene, vpls=64, interleave=1).delta
    inter = run(scene, vpls=64, interleave=4).delta
    assert inter.sum() == pytest.approx(full.sum(), rel=0.1)


def _flat_gbuffer(w: int, h: int, depth: np.ndarray) -> GBuffer:
    """A hand-made G-buffer: every pixel real, normal +z, the given depth (H, W)."""
    import drjit as dr
    import mitsuba as mi

    n = w * h
    z = mi.Float(np.ascontiguousarray(depth, np.float32).ravel())
    zero = dr.zeros(mi.Float, n)
    return GBuffer(position=mi.Point3f(zero, zero, z), normal=mi.Vector3f(zero, zero, zero + 1),
                   albedo=mi.Color3f(zero), role=dr.zeros(mi.Int32, n), depth=z,
                   pixel=dr.arange(mi.UInt32, n), to_camera=mi.Vector3f(zero, zero, zero - 1),
                   spp=1, width=w, height=h)


def _box_mean(img: np.ndarray, k: int, same: np.ndarray) -> np.ndarray:
    """NumPy reference: mean over the k × k window (clipped at the border) of the pixels
    with the same ``same`` label."""
    h, w = img.shape[:2]
    lo = -(k // 2)
    out = np.zeros_like(img)
    for y in range(h):
        for x in range(w):
            ys = slice(max(y + lo, 0), min(y + lo + k, h))
            xs = slice(max(x + lo, 0), min(x + lo + k, w))
            sel = same[ys, xs] == same[y, x]
            out[y, x] = img[ys, xs][sel].mean(axis=0)
    return out


@pytest.mark.parametrize("k", [2, 4, 5])
def test_interleave_filter_is_the_box_filter_on_surfaces(k):
    """On a plane the separable filter equals the k × k box average (clipped at the image
    border), and across a depth step (left half 1 m, right half 2 m) it averages each side
    alone. Rejects a pass that skips an axis, a wrong tap offset, normalising by k instead
    of the weights, and mixing across a depth edge."""
    import mitsuba as mi

    w, h = 13, 9
    rng = np.random.default_rng(k)
    vals = rng.random((h, w, 3)).astype(np.float32)
    depth = np.ones((h, w))
    depth[:, w // 2:] = 2.0
    gb = _flat_gbuffer(w, h, depth)
    flat = vals.reshape(-1, 3)
    (out,) = interleave_filter(gb, [mi.Color3f(*(np.ascontiguousarray(flat[:, c])
                                                  for c in range(3)))], k)
    got = np.array(out).T.reshape(h, w, 3)
    assert np.allclose(got, _box_mean(vals, k, depth), atol=1e-5)


def test_interleave_filter_filters_each_gbuffer_sample_with_its_own_neighbours():
    """With 2 G-buffer samples per pixel (lane ``p·2 + k``) the filter averages sample ``k``
    of the neighbouring pixels: each sample's output is the box mean of that sample's image.
    Rejects gathering neighbours by pixel index (which reads the lanes of other pixels)."""
    import drjit as dr
    import mitsuba as mi

    w, h, k, spp = 11, 7, 3, 2
    rng = np.random.default_rng(1)
    vals = rng.random((h, w, spp, 3)).astype(np.float32)
    depth = np.ones((h, w))
    depth[:, w // 2:] = 2.0
    one = _flat_gbuffer(w * spp, h, np.repeat(depth.reshape(h, w, 1), spp, axis=2))
    gb = GBuffer(one.position, one.normal, one.albedo, one.role, one.depth,
                 dr.arange(mi.UInt32, w * h * spp) // spp, one.to_camera, spp, w, h)
    flat = vals.reshape(-1, 3)
    (out,) = interleave_filter(gb, [mi.Color3f(*(np.ascontiguousarray(flat[:, c])
                                                  for c in range(3)))], k)
    got = np.array(out).T.reshape(h, w, spp, 3)
    for s in range(spp):
        assert np.allclose(got[:, :, s], _box_mean(vals[:, :, s], k, depth), atol=1e-5)


def test_several_gbuffer_samples_per_pixel():
    """``gbuffer_spp`` 4: no virtual object still returns the frame exactly; with the cube
    the coverage is fractional on its silhouette and the delta stays within 15 % of one
    sample per pixel (measured 11 %: the silhouette's fractional coverage adds about −2 to a
    sum of −17, as it added −1.7 to the unaimed VPLs' −22; ``aim_view`` 0 keeps the same
    VPLs in both, since the view's aim sphere follows the jittered samples). Rejects a filter
    or assembly that mixes samples of different pixels."""
    empty = make(box_scene(virtual=False))
    layers = run(empty, vpls=16, gbuffer_spp=4)
    assert np.array_equal(layers.composite, empty.frame) and not layers.delta.any()
    scene = make(box_scene())
    one = run(scene, vpls=64, aim_view=0.0)
    four = run(scene, vpls=64, gbuffer_spp=4, aim_view=0.0)
    assert ((four.mask > 0) & (four.mask < 1)).any()
    assert four.delta.sum() == pytest.approx(one.delta.sum(), rel=0.15)


def test_gbuffer_samples_split_the_pixel_subset_and_count_every_vpl_once():
    """With ``n`` G-buffer samples per pixel each sample gathers every ``n``-th VPL of the
    pixel's subset at ``n`` × the weight: on a G-buffer whose ``n`` samples of a pixel lie
    at one point, the pixel's mean over its samples equals the one-sample gather (interleave
    1: every VPL at every pixel) to float rounding, with the same shadow rays (each
    pixel–VPL pair once). Rejects every sample gathering the whole subset (n × the rays, or
    n × too bright without the 1/n), samples gathering the same part (VPLs missed), and a
    split that drops the remainder when the subset does not divide by n (38 VPLs, n = 4)."""
    import drjit as dr
    import mitsuba as mi

    from arlight.methods.dir import gather

    scene = make(box_scene(w=24, h=18))
    opts = {"vpls": 38, "interleave": 1, "clamp_distance": 0.3, "real_albedo": "proxy",
            "gbuffer_spp": 1}
    method = get_method("dir")
    settings = RenderSettings(options=opts)
    data = method.prepare(scene.world, settings).data
    one = render_gbuffer(data.views.mixed, scene.camera, 1, 0)
    vp = frame_vpls(data, one, SPEC.parse_options(opts), settings.seed)
    n = 4
    lane = dr.arange(mi.UInt32, dr.width(one.pixel) * n) // n
    rep = GBuffer(*(dr.gather(type(a), a, lane) for a in (
        one.position, one.normal, one.albedo, one.role, one.depth, one.pixel,
        one.to_camera)), n, one.width, one.height)
    e_mix1, e_delta1, rays1 = gather(data, one, vp, 1, 1.0 / 0.3 ** 2)
    e_mixn, e_deltan, raysn = gather(data, rep, vp, 1, 1.0 / 0.3 ** 2)
    for a, b in ((e_mix1, e_mixn), (e_delta1, e_deltan)):
        want = _np(a)
        got = _np(b).reshape(-1, n, 3).mean(axis=1)
        assert np.abs(want).max() > 1e-3
        assert np.allclose(got, want, atol=1e-5 * np.abs(want).max(), rtol=1e-5)
    assert raysn == rays1


def test_shadow_negative_bleeding_red():
    """Rejects an inverted delta: the cube's shadow is negative, its bounce red."""
    layers = run(make(box_scene(w=80, h=60)))
    d, real = layers.delta, layers.mask == 0
    lum = d @ np.array([0.2126, 0.7152, 0.0722])
    assert lum[real].min() < -0.02
    pos = real & (d[..., 0] > 1e-4)
    assert pos.any() and d[pos, 0].sum() > 2 * d[pos, 2].sum()


@pytest.mark.parametrize("opts,field", [({"vpls": 0}, "options.vpls"),
                                        ({"vpls": 8, "interleave": 4}, "options.interleave"),
                                        ({"clamp_distance": -1.0}, "options.clamp_distance")])
def test_bad_options(opts, field):
    with pytest.raises(InputError) as e:
        SPEC.parse_options(opts)
    assert e.value.field == field




@pytest.mark.parametrize("name", ["bunny-box", "cornell-near-field", "red-paper"])
def test_quality_against_ground_truth(name):
    """Looser than the path tracers' unbiasedness tests (DIR clamps G and interleaves VPLs,
    so it is biased): against Mitsuba's ground truth the composite beats the untouched frame
    overall, on the virtual pixels and in the relit ring (measured MSE ratios 0.37–0.92,
    0.14–0.47, 0.59–0.83). Rejects a wrong-sign delta, a missing shadow, an unlit object."""
    from tests.methods.test_dlpv import suite_quality

    r = suite_quality("dir", name)
    assert r["all"] < 0.97 and r["virtual"] < 0.6 and r["ring"] < 0.95, r


def test_vpl_flux_is_texel_flux_over_inclusion_probability():
    """Without a virtual object (R_µ = R_ρ, no texel changed) the VPLs picked by flux carry
    ``Φ_i/π_i`` in both maps: equal in R_ρ and R_µ, and their luminance sums to the whole
    RSM's (with ``π_i ∝ Y(Φ_i)`` every VPL carries ``ΣY/n``: the Horvitz–Thompson sum is
    exact). Rejects weighting R_µ twice when it is R_ρ's object (no changed texel: the
    delta of a world whose light does not see the object was 2× the real VPLs' light) and
    weights other than 1/π."""
    import mitsuba as mi

    from arlight.methods.dir import make_vpls, map_sides
    from arlight.realtime.rsm import concat_rays, light_rays, render_rsm
    from arlight.sphere.sh import LUMINANCE

    scene = make(box_scene(virtual=False))
    data = get_method("dir").prepare(scene.world, RenderSettings()).data
    vp = make_vpls(data, 64, 16, [], 0.0, 0.5)
    rho = np.array(vp.rho.flux_out, np.float64)
    assert np.array_equal(rho, np.array(vp.mu.flux_out, np.float64))
    sides = map_sides(data.lights, 16 * 16, data.bounds)
    rays = concat_rays([light_rays(lt, s, data.bounds)
                        for lt, s in zip(data.lights.lights, sides, strict=True)])
    full = np.array(render_rsm(data.views.mixed, rays).flux_out, np.float64)
    y = np.asarray(LUMINANCE)
    assert vp.count == 64 and isinstance(vp.rho.flux_out, mi.Color3f)
    assert (y @ rho.reshape(3, -1)).sum() == pytest.approx((y @ full.reshape(3, -1)).sum(),
                                                           rel=1e-4)
