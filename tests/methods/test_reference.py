"""The reference method: null test, unbiasedness against ground truth, mask coverage."""

import imageio.v3 as iio
import numpy as np
import pytest

from arlight.io.images import write_png
from arlight.methods import RenderSettings, get_method
from arlight.output import write_layers
from arlight.scene.load import parse_scene
from arlight.stats import agreement_fraction
from arlight.synthetic import synthesize
from tests.conftest import area_light_scene, env_mirror_scene, with_constant_frame

reference = get_method("reference")


def test_null_test_composite_is_frame_and_png_is_byte_identical(tmp_path):
    d = area_light_scene(virtual=False)
    rng = np.random.default_rng(0)
    codes = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    write_png(tmp_path / "frame.png", codes)
    d["frame"] = {"image": "frame.png"}
    scene = parse_scene(d, base_dir=tmp_path)
    layers = reference(scene, RenderSettings(spp=4))
    assert np.array_equal(layers.composite, scene.frame)
    assert np.all(layers.delta == 0) and np.all(layers.mask == 0)
    paths = write_layers(layers, scene, tmp_path / "out")
    assert np.array_equal(iio.imread(paths["composite_png"]), codes)
    assert paths["composite_png"].read_bytes() == (tmp_path / "frame.png").read_bytes()


def test_virtual_pixels_show_mixed_and_shadow_darkens():
    scene = with_constant_frame(parse_scene(area_light_scene()))
    layers = reference(scene, RenderSettings(spp=16, seed=3))
    full = layers.mask == 1.0
    assert full.sum() > 20
    assert np.array_equal(layers.composite[full], layers.mixed[full])
    z = layers.delta / np.maximum(layers.stderr["delta"], 1e-9)
    assert np.sum((z < -5).any(axis=2) & (layers.mask == 0)) >= 5  # a real shadow


def test_same_seed_bitwise_identical():
    scene = with_constant_frame(parse_scene(area_light_scene(16, 12)))
    a = reference(scene, RenderSettings(spp=4, seed=11))
    b = reference(scene, RenderSettings(spp=4, seed=11))
    c = reference(scene, RenderSettings(spp=4, seed=12))
    assert np.array_equal(a.composite, b.composite)
    assert not np.array_equal(a.composite, c.composite)


def _card_scene(n_px: int):
    """A virtual square card facing a camera that looks down −Z, edges at fractional pixels."""
    f = 20.0
    half = n_px / 2
    return parse_scene({
        "camera": {"resolution": [n_px, n_px],
                   "intrinsics": {"fx": f, "fy": f, "cx": half, "cy": half},
                   "world_from_camera": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0],
                                         [0, 0, 0, 1]]},
        "shapes": [{"role": "virtual", "type": "rectangle", "size": [0.74, 0.62],
                    "transform": {"translate": [0.04, -0.07, -2.0]}}],
        "lights": []})


def _analytic_coverage(n_px: int):
    f, z, half = 20.0, 2.0, n_px / 2
    x0, x1 = (0.04 - 0.37) * f / z + half, (0.04 + 0.37) * f / z + half
    y0, y1 = -(-0.07 + 0.31) * f / z + half, -(-0.07 - 0.31) * f / z + half  # y down
    edges = np.arange(n_px + 1)

    def overlap(a, b):
        return np.clip(np.minimum(edges[1:], b) - np.maximum(edges[:-1], a), 0, 1)

    return np.outer(overlap(y0, y1), overlap(x0, x1))


@pytest.mark.parametrize("n", [4, 8])
def test_mask_edges_match_analytic_coverage(n):
    """N×N multi-jittered samples: single-edge pixels within 1/N² of the exact coverage."""
    n_px = 16
    scene = with_constant_frame(_card_scene(n_px), 0.0)
    layers = reference(scene, RenderSettings(spp=n * n, seed=1))
    exact = _analytic_coverage(n_px)
    err = np.abs(layers.mask - exact)
    partial = (exact > 0) & (exact < 1)
    fractional_rows = (exact > 0).sum(axis=1) > 0
    assert partial.sum() >= 20
    assert np.all(err[exact == 1] == 0) and np.all(layers.mask[exact == 0] == 0)
    single_edge = partial & ((exact == exact.max(axis=1, keepdims=True))
                             | (exact == exact.max(axis=0, keepdims=True)))
    assert fractional_rows.any()
    assert np.all(err[single_edge] <= 1.0 / n**2 + 1e-6), err[single_edge].max()
    assert np.all(err[partial] <= 2.0 / n**2 + 1e-6)  # corners: two edges


@pytest.mark.parametrize("make", [area_light_scene, env_mirror_scene],
                         ids=["diffuse-area-light", "env-mirror"])
def test_reference_is_unbiased_against_ground_truth(make):
    """Proxy == world: composite and ground truth agree within 3 SE on >= 99 % of pixels."""
    world = parse_scene(make(32, 24))
    photo = synthesize(world, spp=256, seed=21)
    layers = reference(world.with_frame(photo.frame), RenderSettings(spp=64, seed=5))
    keep = (1.0 - layers.mask)[..., None]
    se = np.sqrt(layers.stderr["composite"] ** 2 + (keep * photo.frame_stderr) ** 2)
    frac = agreement_fraction(layers.composite, se, photo.ground_truth,
                              photo.ground_truth_stderr)
    assert frac >= 0.99, frac
    # and the test can fail: a wrong light level is detected
    frac_bad = agreement_fraction(layers.composite * 1.1, se, photo.ground_truth,
                                  photo.ground_truth_stderr)
    assert frac_bad < 0.9


def _plane_under_sky(light: dict, albedo: float = 0.6):
    return {"camera": {"resolution": [12, 9], "fov_y_deg": 30,
                       "look_at": {"origin": [0, 2, 0.5], "target": [0, 0, 0]}},
            "shapes": [{"role": "real", "type": "disk", "radius": 50.0, "normal": [0, 1, 0],
                        "material": {"type": "diffuse", "albedo": albedo}}],
            "lights": [light]}


@pytest.mark.parametrize("light", [
    {"type": "constant", "radiance": 2.0},
    {"type": "sh", "coefficients": [[2.0 / 0.28209479177387814] * 3] + [[0.0] * 3] * 8},
], ids=["constant", "sh-L0"])
def test_constant_sky_gives_albedo_times_radiance(light):
    """Kán checklist 13: a plane under a uniform sky of radiance L reflects ρ·L (the disk is
    so large that the sky below its horizon hardly matters; its solid angle is < 1e-3)."""
    scene = with_constant_frame(parse_scene(_plane_under_sky(light)), 1.2)
    layers = reference(scene, RenderSettings(spp=256, max_depth=2, seed=2))
    expected = 0.6 * 2.0
    z = np.abs(layers.mixed - expected) / np.maximum(layers.stderr["mixed"], 1e-6)
    assert np.mean(z.max(axis=2) <= 3.0) >= 0.95
    assert abs(layers.mixed.mean() - expected) < 0.01


def test_angular_probe_and_texture_load_and_render(tmp_path):
    from arlight.io.images import write_exr

    n = 64
    yy, xx = np.mgrid[0:n, 0:n]
    inside = (xx + 0.5 - n / 2) ** 2 + (yy + 0.5 - n / 2) ** 2 <= (n / 2) ** 2
    probe = np.where(inside[..., None], 3.0, 0.0).astype(np.float32) * np.ones(3, np.float32)
    write_exr(tmp_path / "probe.exr", probe)
    tex = np.zeros((4, 8, 3), np.uint8)
    tex[:, :4, 0] = 255
    tex[:, 4:, 1] = 255
    write_png(tmp_path / "tex.png", tex)
    d = _plane_under_sky({"type": "envmap", "file": "probe.exr", "mapping": "angular"})
    d["shapes"][0] = {"role": "real", "type": "rectangle", "size": [3, 3], "normal": [0, 1, 0],
                      "material": {"type": "diffuse", "texture": "tex.png"}}
    scene = with_constant_frame(parse_scene(d, base_dir=tmp_path))
    env = scene.lights[0].radiance_map
    assert env.shape[1] == 2 * env.shape[0]
    assert np.allclose(np.median(env), 3.0, rtol=0.05)
    layers = reference(scene, RenderSettings(spp=16, max_depth=2))
    red = layers.mixed[..., 0] > 4 * layers.mixed[..., 1]
    green = layers.mixed[..., 1] > 4 * layers.mixed[..., 0]
    assert red.sum() > 10 and green.sum() > 10
