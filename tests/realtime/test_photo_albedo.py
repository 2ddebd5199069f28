"""The albedo read from the photograph (``arlight.realtime.photo_albedo``, issue #33).

The world's floor is a checkerboard of dark and bright albedo; the proxy, as the held-out
worlds' reconstructions do, has lost the texture to its mean. The truth is Mitsuba's own
render of the world (direct light only), independent of the methods' code."""

from __future__ import annotations

import math

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from arlight.backend.mitsuba_scene import build_views
from arlight.methods import RenderSettings, get_method
from arlight.realtime.gbuffer import render_gbuffer
from arlight.realtime.light_reduction import LightSet, ReducedLight
from arlight.realtime.photo_albedo import photo_albedo
from arlight.realtime.real_lane import real_albedo
from arlight.realtime.shading import direct_terms_gbuffer
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize

DARK, BRIGHT = 0.12, 0.72
"""The checker's two albedos; the proxy's floor has their mean."""
LIGHT = {"type": "point", "position": [-0.35, 1.2, -0.25], "intensity": 2.5}
LOOK = {"origin": [0.6, 0.8, 1.5], "target": [0.1, 0.0, 0.1]}


def _checker(tmp_path) -> str:
    """A 16×16 checkerboard of :data:`DARK` / :data:`BRIGHT` (linear), as an 8-bit PNG the
    loader reads as sRGB-encoded (so it decodes to these albedos up to 8-bit rounding)."""
    cells = (np.indices((16, 16)).sum(0) % 2).astype(np.float64)
    lin = np.where(cells[..., None] > 0, BRIGHT, DARK) * np.ones(3)
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    path = tmp_path / "checker.png"
    iio.imwrite(path, np.round(enc.repeat(8, 0).repeat(8, 1) * 255).astype(np.uint8))
    return str(path)


def _scene(floor: dict, w: int = 128, h: int = 96, light: dict = LIGHT) -> dict:
    return {"camera": {"resolution": [w, h], "fov_y_deg": 40, "look_at": LOOK},
            "shapes": [
                {"name": "floor", "role": "real", "type": "rectangle", "size": [2, 2],
                 "normal": [0, 1, 0], "material": floor},
                {"name": "cube", "role": "virtual", "type": "box", "size": [0.3] * 3,
                 "transform": {"translate": [0.0, 0.35, 0.0]},
                 "material": {"type": "diffuse", "albedo": 0.5}}],
            "lights": [light]}


@pytest.fixture(scope="module")
def checker_world(tmp_path_factory, eval_cache):
    tmp = tmp_path_factory.mktemp("checker")
    tex = _checker(tmp)
    world = parse_scene(_scene({"type": "diffuse", "texture": tex}), base_dir=tmp)
    proxy = parse_scene(_scene({"type": "diffuse", "albedo": (DARK + BRIGHT) / 2}),
                        base_dir=tmp)
    photo = synthesize(world, spp=256, max_depth=2, cache_dir=eval_cache)
    # the texture's albedo per pixel: the world's G-buffer (the texture sampled at the hit)
    views = build_views(world.world)
    gb = render_gbuffer(views.real, world.camera, 1, 0)
    truth = np.array(gb.albedo, np.float64).T.reshape(world.camera.height,
                                                      world.camera.width, 3)
    return world, proxy.with_frame(photo.frame), photo, truth


def _texels(truth: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dark and the bright texels' interiors in ``region``: pixels whose G-buffer albedo
    and their 8 neighbours' are within 3 % of :data:`DARK` or :data:`BRIGHT` (8-bit
    rounding; the photograph's pixel filter mixes both at a border)."""
    a = np.asarray(truth[..., 0])
    return tuple(region & binary_erosion(np.abs(a - v) < 0.03 * v, np.ones((3, 3), bool))
                 for v in (DARK, BRIGHT))


def _point_light() -> LightSet:
    """The world's point light as the one reduced light of a LightSet."""
    pos = np.array(LIGHT["position"], np.float64)
    return LightSet([ReducedLight(kind="point", position=pos, axis=np.zeros(3),
                                  intensity=np.full(3, LIGHT["intensity"]), source="l0")])


def test_reads_the_texture_the_proxy_lost(checker_world):
    """On the lit floor ρ̂ is each texel's own albedo within 5 % (the photograph's noise at
    256 spp), dark and bright alike. Rejects the proxy's albedo (the mean: 2.5× the dark
    texels', 0.6× the bright), ``B / E_r`` without π, and an ``E_r`` without the light's
    cosine or fall-off (off by tens of per cent across the floor)."""
    world, proxy, photo, truth = checker_world
    views = build_views(proxy.world)
    gb = render_gbuffer(views.real, proxy.camera, 1, 0)
    lights = _point_light()
    real = gb.valid & ~gb.virtual
    rho = photo_albedo(views.real, lights, proxy.frame, gb.pixel, gb.position, gb.normal,
                       gb.albedo, real)
    h, w = proxy.camera.height, proxy.camera.width
    est = np.array(rho, np.float64).T.reshape(h, w, 3)
    floor = np.array(real, bool).reshape(h, w) & (np.asarray(photo.mask) < 1e-6).reshape(h, w)
    # texel borders mix two albedos inside one pixel: read the texel interiors
    for sel in _texels(truth, floor):
        assert sel.sum() > 50
        np.testing.assert_allclose(np.median(est[sel], axis=0),
                                   np.median(truth[sel], axis=0), rtol=0.05)
    assert math.isclose(np.median(np.array(gb.albedo, np.float64)), (DARK + BRIGHT) / 2,
                        rel_tol=1e-3)


def test_shared_shadow_rays_give_the_same_albedo(checker_world):
    """``real_albedo`` with ``direct`` (E_r's direct part from the direct change's own
    shadow rays, :func:`~arlight.realtime.shading.direct_terms_gbuffer`, as ``dir`` passes
    it) equals ``real_albedo`` tracing its own ray per light, on every real lane — under a
    point light both are one ray to the point, the real scene's visibility — in the cube's
    shadow too (where a shared ray is blocked in the mixed scene and traced again in the
    real one). Rejects sharing the mixed scene's visibility (E_r = 0 in the shadow: the
    proxy's albedo kept there) and an E_r without the shared part (ρ̂ clipped to 1);
    mutation-checked."""
    _, proxy, photo, _ = checker_world
    views = build_views(proxy.world)
    gb = render_gbuffer(views.mixed, proxy.camera, 1, 0)
    lights = _point_light()
    real = gb.valid & ~gb.virtual
    terms = direct_terms_gbuffer(views, lights, gb, real, 8)
    own = np.array(real_albedo("photo", views, lights, proxy.frame, gb, real), np.float64)
    shared = np.array(real_albedo("photo", views, lights, proxy.frame, gb, real,
                                  direct=terms.real), np.float64)
    sel = np.array(real, bool)
    shadow = sel & (np.array(terms.change, np.float64)[0] < 0.0)
    assert shadow.sum() > 50
    np.testing.assert_allclose(shared[:, sel], own[:, sel], rtol=1e-5, atol=1e-7)


def test_dvct_shadow_on_a_texture_the_proxy_averaged(checker_world):
    """dvct's composite in the cube's shadow core against Mitsuba's ground truth: with the
    photograph's albedo the dark and the bright texels both within 25 %; with the proxy's
    (option off, Franke's ``ρ/π ΔE``) the dark texels' shadow is far too deep (the mean
    albedo removes 3× the light they reflect) — the wrong implementation this rejects."""
    world, proxy, photo, truth = checker_world
    method = get_method("dvct")
    small = {"volume_size": 64, "rsm_size": 128, "cone_scale": 1}
    gt = np.asarray(photo.ground_truth, np.float64)
    frame = np.asarray(photo.frame, np.float64)
    lum = np.array([0.2126, 0.7152, 0.0722])
    core = ((gt @ lum) < 0.25 * (frame @ lum)) & (np.asarray(photo.mask).reshape(gt.shape[:2])
                                                   < 1e-6)
    assert core.sum() > 20
    errs = {}
    for on in (True, False):
        out = method(proxy, RenderSettings(options={**small, "photo_albedo": on}))
        comp = np.asarray(out.composite, np.float64)
        for target, sel in zip((DARK, BRIGHT), _texels(truth, core), strict=True):
            if sel.sum() < 5:
                continue
            # the shadow's depth: light removed, as a share of what the truth removes
            removed = (frame[sel] - comp[sel]) @ lum
            want = (frame[sel] - gt[sel]) @ lum
            errs[on, target] = float(np.median(removed) / np.median(want))
    assert errs, "no shadow-core texels"
    for (on, target), ratio in errs.items():
        if on:
            assert abs(ratio - 1.0) < 0.25, (target, ratio)
    assert {t for on, t in errs if on} == {DARK, BRIGHT}, errs
    assert all(abs(r - 1.0) > 0.3 for (on, _), r in errs.items() if not on), errs



def test_dvct_delta_with_the_photographs_albedo_follows_the_photograph(checker_world):
    """With ``photo_albedo`` the change is a ratio of the light the pixel receives: a model
    light twice as bright, with the same photograph, gives the same delta (ρ̂ halves).
    Rejects the proxy's albedo (its delta doubles: Franke's form is linear in the light,
    tests/methods/test_dvct.py) and a ρ̂ not divided by the model's irradiance."""
    world, proxy, photo, truth = checker_world
    small = {"volume_size": 32, "rsm_size": 64, "cone_scale": 1, "photo_albedo": True}
    method = get_method("dvct")
    base = method(proxy, RenderSettings(options=small)).delta
    bright = parse_scene(_scene({"type": "diffuse", "albedo": (DARK + BRIGHT) / 2},
                                light={**LIGHT, "intensity": 2 * LIGHT["intensity"]}))
    twice = method(bright.with_frame(photo.frame), RenderSettings(options=small)).delta
    assert np.abs(base).max() > 1e-2
    np.testing.assert_allclose(twice, base, rtol=1e-3, atol=1e-5 * np.abs(base).max())


# --------------------------------------------------------------------------------------------
# The path tracers' photo-consistent change (option ``delta = ratio``, issue #31): the same
# ratio (arlight.layers.photo_scale) applied to the real render I_r
# --------------------------------------------------------------------------------------------

def _shadow_depths(out, photo, truth) -> dict[float, float]:
    """Per texel kind (:data:`DARK`, :data:`BRIGHT`) in the cube's shadow core on the floor:
    the light the composite removes as a share of what Mitsuba's ground truth removes
    (median luminance)."""
    gt = np.asarray(photo.ground_truth, np.float64)
    frame = np.asarray(photo.frame, np.float64)
    lum = np.array([0.2126, 0.7152, 0.0722])
    core = ((gt @ lum) < 0.25 * (frame @ lum)) & (np.asarray(photo.mask).reshape(gt.shape[:2])
                                                   < 1e-6)
    comp = np.asarray(out.composite, np.float64)
    out_ = {}
    for target, sel in zip((DARK, BRIGHT), _texels(truth, core), strict=True):
        assert sel.sum() >= 5, target
        out_[target] = float(np.median((frame[sel] - comp[sel]) @ lum)
                             / np.median((frame[sel] - gt[sel]) @ lum))
    return out_


@pytest.mark.parametrize("spp, extra", [(64, {}), (4, {"denoise": "oidn"})],
                         ids=["64spp", "4spp-oidn"])
def test_onepass_ratio_shadow_on_a_texture_the_proxy_averaged(checker_world, spp, extra):
    """onepass's composite in the cube's shadow core against Mitsuba's render of the
    textured world: with ``delta = ratio`` the dark and the bright texels' shadows within
    20 % of the truth's depth (measured: 1.00 at 64 spp and at 4 spp denoised, where ``s``
    reads the denoised ``I_r``); the additive change (``delta = additive``: the proxy's mean
    albedo's shadow, the wrong implementation this rejects) removes 3.5× the light the truth
    removes on the dark texels and 0.58× on the bright ones."""
    _, proxy, photo, truth = checker_world
    method = get_method("onepass")
    depths = {}
    for delta in ("ratio", "additive"):
        out = method(proxy, RenderSettings(spp=spp, max_depth=2, seed=3,
                                           options={**extra, "delta": delta}))
        depths[delta] = _shadow_depths(out, photo, truth)
    for target, r in depths["ratio"].items():
        assert abs(r - 1.0) < 0.2, (target, depths)
    assert depths["additive"][DARK] > 1.8 and depths["additive"][BRIGHT] < 0.8, depths


def test_ratio_change_keeps_the_photograph_where_nothing_changes(checker_world):
    """With ``delta = ratio`` every pixel whose raw delta is zero and mask zero is the
    photograph bit for bit (``s`` scales the change, never the photo), and without a
    virtual object the composite is the photograph. Rejects a ratio composite written as
    ``B · I_m / I_r`` (rounding changes unchanged pixels)."""
    _, proxy, photo, _ = checker_world
    method = get_method("onepass")
    out = method(proxy, RenderSettings(spp=4, max_depth=2, options={"delta": "ratio"}))
    still = np.all(out.delta == 0, axis=-1) & (out.mask == 0)
    assert still.sum() > 1000 and (~still).sum() > 100
    np.testing.assert_array_equal(out.composite[still], proxy.frame[still])
    bare = proxy.without_virtual()
    empty = method(bare, RenderSettings(spp=4, max_depth=2, options={"delta": "ratio"}))
    np.testing.assert_array_equal(empty.composite, bare.frame)


def test_photo_scale_one_function_for_numpy_and_drjit():
    """``photo_scale`` on NumPy and on Dr.Jit arrays (dvct's lanes) gives the same ``s``:
    ``B / I_r`` inside the clip, ``1/ρ`` above it (implied albedo 1), 0 for a negative
    photo, 1 (the additive change) where ``I_r`` < RATIO_MIN. Rejects an unclipped ratio
    and a fallback of 0 (a dark proxy pixel would lose its change)."""
    import drjit as dr
    import mitsuba as mi

    from arlight.jit import ensure_variant
    from arlight.layers import RATIO_MIN, photo_scale

    ensure_variant()
    b = np.array([0.2, 0.9, -0.1, 0.3], np.float32)
    r = np.array([0.4, 0.3, 0.2, RATIO_MIN / 10], np.float32)
    rho = np.array([0.5, 0.5, 0.5, 0.5], np.float32)
    want = np.array([0.5, 2.0, 0.0, 1.0], np.float32)
    np.testing.assert_allclose(photo_scale(b, r, rho), want, rtol=1e-6)
    s = photo_scale(mi.Float(b), mi.Float(r), mi.Float(rho), dr)
    np.testing.assert_allclose(np.asarray(s), want, rtol=1e-6)
