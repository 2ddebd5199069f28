"""``dvct`` and the distant light (issue #33): what a virtual object's specular cone sees
where it leaves the volume, and the ambient remainder the objects block or reflect.

Every comparison is against Mitsuba's ``path`` (:func:`arlight.synthetic.synthesize`, the
mixed world's ground truth) or an analytic value; each test names the wrong implementation
it rejects."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.methods import RenderSettings, get_method
from arlight.scene.load import parse_scene
from arlight.synthetic import synthesize

LUM = np.array([0.2126, 0.7152, 0.0722])
SMALL = {"volume_size": 64, "rsm_size": 64, "cone_scale": 1}
LOOK = {"origin": [0.0, 0.9, 2.2], "target": [0.0, 0.35, 0.0]}
SKY = 1.0
"""Radiance of the constant sky (W sr⁻¹ m⁻²)."""


def _scene(ball: dict, lights: list[dict], w: int = 64, h: int = 48) -> dict:
    """A grey real floor and a virtual sphere of material ``ball`` floating above it."""
    return {"camera": {"resolution": [w, h], "fov_y_deg": 30, "look_at": LOOK},
            "shapes": [
                {"name": "floor", "role": "real", "type": "rectangle", "size": [4, 4],
                 "normal": [0, 1, 0], "material": {"type": "diffuse", "albedo": 0.5}},
                {"name": "ball", "role": "virtual", "type": "sphere", "radius": 0.25,
                 "transform": {"translate": [0.0, 0.45, 0.0]}, "material": ball}],
            "lights": lights}


def _world(eval_cache, ball: dict, lights: list[dict]):
    world = parse_scene(_scene(ball, lights))
    photo = synthesize(world, spp=256, max_depth=4, cache_dir=eval_cache)
    return world.with_frame(photo.frame), photo


def _ball(out, photo) -> tuple[float, float]:
    """Mean luminance (linear) of dvct and of the ground truth on the sphere's pixels that
    are wholly covered (mask 1)."""
    m = photo.mask > 0.999
    return float((out.composite[m] @ LUM).mean()), float((photo.ground_truth[m] @ LUM).mean())


def _top(out, photo, rows: int) -> float:
    """Mean luminance (linear) of dvct on the sphere's wholly covered pixels in its
    ``rows`` top image rows (normals towards the sky)."""
    m = photo.mask > 0.999
    first = np.nonzero(m.any(1))[0][0]
    m[first + rows:] = False
    return float((out.composite[m] @ LUM).mean())


def _run(scene, **opts):
    return get_method("dvct")(scene, RenderSettings(options={**SMALL, **opts}))


@pytest.fixture(scope="module")
def mirror_under_sky(eval_cache):
    return _world(eval_cache, {"type": "mirror", "reflectance": 0.9},
                  [{"type": "constant", "radiance": SKY}])


def test_a_mirror_under_a_constant_sky_reflects_the_sky(mirror_under_sky):
    """A mirror sphere (reflectance 0.9) above a floor under a constant sky: its upper
    rows reflect the sky, ``0.9 L`` (analytic) within 5 % (measured 0.899), its lower half
    the floor (the photograph at the reflected ray's hit). The sphere's mean is Mitsuba's
    within 10 % (measured 0.92×). Rejects cones that add nothing where they leave the
    volume (the mirror black: 0.0 — the sky has no reduced light, so ``V_ρ`` is empty)."""
    scene, photo = mirror_under_sky
    got, want = _ball(_run(scene), photo)
    assert got == pytest.approx(want, rel=0.10)
    # the top pixels (reflecting the sky) are 0.9 L, analytic
    assert _top(_run(scene), photo, 3) == pytest.approx(0.9 * SKY, rel=0.05)


@pytest.fixture(scope="module")
def diffuse_under_sky(eval_cache):
    return _world(eval_cache, {"type": "diffuse", "albedo": 0.6},
                  [{"type": "constant", "radiance": SKY}])


def test_a_diffuse_sphere_under_a_constant_sky_reaches_pi_l(diffuse_under_sky):
    """A diffuse sphere (ρ = 0.6) under a constant sky: its top sees the whole sky,
    ``E = πL`` and radiance ``ρ L`` (analytic) within 5 % (measured 0.987 ρL); its mean over
    the sphere is Mitsuba's within 10 % (measured 0.99×). Rejects the real floor taken for
    open sky — the volume's cones see only the real geometry inside it (mean 1.17×) — and
    the hidden directions lost without the floor's own ambient radiance ``ρ_r L̄`` (0.84×)."""
    scene, photo = diffuse_under_sky
    out = _run(scene)
    assert _top(out, photo, 2) == pytest.approx(0.6 * SKY, rel=0.05)
    got, want = _ball(out, photo)
    assert got == pytest.approx(want, rel=0.10)


def test_the_objects_sky_shadow_on_the_floor_follows_mitsuba(diffuse_under_sky):
    """The floor under the sphere (constant sky only) loses the sky the sphere hides but
    gains the sphere's reflection of it (``realtime.ambient`` Eq. 3: the blocked radiance
    ``L − ρ_v L``): the darkening (frame − composite) summed over the floor's pixels is
    Mitsuba's (frame − ground truth) within 50 % (measured 1.38×: the wide cones' coarse
    blocks make the sphere's footprint too large). Rejects the blocked sky lost without
    the object's own reflection (3.5× Mitsuba's darkening at ρ = 0.6)."""
    scene, photo = diffuse_under_sky
    out = _run(scene)
    real = photo.mask < 0.001
    frame = scene.view.frame
    got = ((frame - out.composite)[real] @ LUM).sum()
    want = ((frame - photo.ground_truth)[real] @ LUM).sum()
    assert want > 0.0
    assert got == pytest.approx(want, rel=0.5)


@pytest.fixture(scope="module")
def glossy_under_envmap(eval_cache):
    from arlight.demo import DEMO_DIR

    return _world(eval_cache, {"type": "roughconductor", "alpha": 0.1, "reflectance": 0.9},
                  [{"type": "envmap", "file": str(DEMO_DIR / "lebombo_512x256.hdr")}])


def test_a_glossy_sphere_under_an_environment_counts_it_once(glossy_under_envmap):
    """A rough conductor (GGX α = 0.1, reflectance 0.9) under an HDR environment: the
    environment reaches its specular once — through the prefiltered map where the cone
    leaves the volume, not again through the directional lights the light reduction
    extracted from its highlights. The sphere's mean is Mitsuba's within 15 % (measured
    0.91×) and so is its highlight, the 99th percentile of its luminance, within 20 %
    (measured 0.91×). Rejects the extracted lights' GGX specular kept beside the map
    (highlight 1.42×, mean 1.06×)."""
    scene, photo = glossy_under_envmap
    out = _run(scene)
    got, want = _ball(out, photo)
    assert got == pytest.approx(want, rel=0.15)
    m = photo.mask > 0.999
    hi = np.percentile(out.composite[m] @ LUM, 99)
    assert hi == pytest.approx(np.percentile(photo.ground_truth[m] @ LUM, 99), rel=0.20)
