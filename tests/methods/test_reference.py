"""The reference method: null test, unbiasedness against ground truth, mask coverage."""

import imageio.v3 as iio
import numpy as np
import pytest

from arlight.io.images import write_png
from arlight.layer_files import write_layers
from arlight.methods import RenderSettings, get_method
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
@pytest.mark.parametrize("sampler", ["independent", "multijitter"])
def test_mask_edges_match_analytic_coverage(n, sampler):
    """N×N multi-jittered samples: single-edge pixels within 1/N² of the exact coverage.
    `independent`: the pass engine's multi-jittered camera; `multijitter` with one replica:
    the camera position from Mitsuba's multi-jittered set of N² points (with R replicas each
    is its own set of N²/R points, so the bound is 1/(N²/R) per replica)."""
    n_px = 16
    scene = with_constant_frame(_card_scene(n_px), 0.0)
    layers = reference(scene, RenderSettings(spp=n * n, seed=1,
                                             options={"sampler": sampler, "replicas": 1}))
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


# ------------------------------------------------------------------------------------------
# Low-discrepancy sampling (option `sampler = multijitter`; the default is independent)
# ------------------------------------------------------------------------------------------


def _unreachable_virtual_scene():
    """The room with a virtual ball no path can reach (under the floor, whose footprint holds
    every other surface): the mixed and real paths see the same world."""
    d = area_light_scene(24, 18)
    d["shapes"][-1]["transform"] = {"translate": [0.0, -50.0, 0.0]}
    return with_constant_frame(parse_scene(d))


@pytest.mark.parametrize("options", [{"sampler": "independent"}, {"sampler": "multijitter"},
                                     {"sampler": "multijitter", "replicas": 4}])
def test_mixed_and_real_paths_read_identical_random_sequences(options):
    """With a virtual object no ray reaches, every lane's mixed and real paths are the same
    path only if both read the same random numbers: the delta is exactly 0 and the mask 0,
    over several passes (spp_per_pass forces 4 passes of the low-discrepancy sets). Catches
    one sampler shared by both traces (the second would continue the first's dimensions), or
    traces of one lane at different points of the set (a pass index applied to one only)."""
    scene = _unreachable_virtual_scene()
    layers = reference(scene, RenderSettings(spp=16, seed=3, spp_per_pass=4, options=options))
    assert np.all(layers.mask == 0)
    assert np.all(layers.delta == 0)
    assert np.array_equal(layers.mixed, layers.real)
    assert layers.mixed.max() > 0


def test_passes_continue_each_replica_set():
    """Pass p of a plan with m points per pass draws points p·m … p·m + m − 1 of every
    (pixel, replica) set, so after s/m passes each set is one complete multi-jittered set:
    with s = 16 points drawn one per pass, every set holds one point in each of the 4×4 cells
    and in each of the 16 columns and rows (n-rooks). Catches passes that restart the set
    (the same point 16 times), sequences not aligned with the replicas, or sets seeded per
    pass (independent points)."""
    import drjit as dr
    import mitsuba as mi

    from arlight.methods.reference import ld_plan, pass_sampler

    plan = ld_plan("multijitter", spp=32, replicas=2, pixels=10, spp_per_pass=2)
    assert (plan.replicas, plan.set_size, plan.sample_count, plan.per_pass) == (2, 16, 16, 1)
    lanes = 10 * plan.spp_per_pass  # 10 pixels × 2 replicas, one lane each per pass
    pts = []
    for p in range(16):
        u = pass_sampler(plan, 7, lanes, p).next_2d()
        dr.eval(u)
        pts.append(np.stack([np.array(u.x), np.array(u.y)], axis=1))
    pts = np.stack(pts, axis=1)  # (sets, 16 points, 2)
    for xy in pts:
        cells = (np.floor(xy[:, 0] * 4) * 4 + np.floor(xy[:, 1] * 4)).astype(int)
        assert sorted(cells) == list(range(16))
        assert sorted(np.floor(xy[:, 0] * 16).astype(int)) == list(range(16))
        assert sorted(np.floor(xy[:, 1] * 16).astype(int)) == list(range(16))
    assert len({tuple(np.round(x[0], 6)) for x in pts}) == len(pts)  # sets randomised apart
    assert isinstance(pass_sampler(plan, 7, lanes, 0), mi.Sampler)


@pytest.mark.parametrize(("spp", "replicas", "cap", "want"), [
    (64, 16, None, (16, 4, 4, 4)), (64, 16, 16, (16, 4, 4, 1)), (80, 16, None, (16, 5, 6, 1)),
    (48, 4, None, (4, 12, 12, 12)), (7, 16, None, (7, 1, 1, 1))])
def test_ld_plan(spp, replicas, cap, want):
    """R = the largest divisor of spp not above `replicas`; s = spp/R points per set; the
    sampler's own count for s (5 → 6 for multijitter: the first 5 of 6 points are used); m
    divides both and m·R fits the pass cap, so every pass has the same size."""
    from arlight.methods.reference import ld_plan

    plan = ld_plan("multijitter", spp, replicas, pixels=100, spp_per_pass=cap)
    assert (plan.replicas, plan.set_size, plan.sample_count, plan.per_pass) == want
    assert spp % plan.spp_per_pass == 0


def test_multijitter_errors_are_lower_and_their_standard_errors_honest():
    """32×24 room, 64 spp, 3 seeds, against a 4096-spp `independent` render. (a) The
    multijitter sampler (16 replicas): pooled squared error / squared standard error near 1
    for the mixed, real, delta and composite layers, few |z| > 3.5 in mixed and real (the
    delta of 64 samples is exactly 0 where no path reached the ball, which the truth's 4096
    did: a rare-event tail of every sampler, so not counted) — while the same samples
    with a per-sample-variance error (one replica) overstate it (ratio < 0.75: rejected by
    the same bound). (b) Its mean squared error is well below `independent`'s at equal spp
    (measured ≈ 0.45–0.75 per layer; the bound fails a sampler that is not applied)."""
    scene = with_constant_frame(parse_scene(area_light_scene(32, 24)))
    truth = reference(scene, RenderSettings(spp=4096, seed=99,
                                            options={"sampler": "independent"}))
    layers = ("mixed", "real", "delta", "composite")

    def pooled(options):
        err2, se2, z = [], [], []
        for seed in (1, 2, 3):
            out = reference(scene, RenderSettings(spp=64, seed=seed, options=options))
            for k in layers:
                d2 = (getattr(out, k).astype(np.float64) - getattr(truth, k)) ** 2
                t2 = truth.stderr[k].astype(np.float64) ** 2
                s2 = out.stderr[k].astype(np.float64) ** 2
                err2.append(d2 - t2)
                se2.append(s2)
                z.append(np.sqrt(d2 / np.maximum(s2 + t2, 1e-12)))
        err2, se2, z = (np.stack(a).reshape(3, len(layers), -1) for a in (err2, se2, z))
        return err2.mean(axis=(0, 2)), se2.mean(axis=(0, 2)), (z[:, :2] > 3.5).mean()

    ld_e, ld_s, ld_tail = pooled({"sampler": "multijitter"})
    ratio = ld_e / ld_s
    assert np.all((ratio > 0.75) & (ratio < 1.35)) and ld_tail < 0.03, (ratio, ld_tail)
    one_e, one_s, _ = pooled({"sampler": "multijitter", "replicas": 1})
    assert np.all(one_e / one_s < 0.75), one_e / one_s  # per-sample variance: overstated
    ind_e, ind_s, _ = pooled({"sampler": "independent"})
    assert np.all((ind_e / ind_s > 0.75) & (ind_e / ind_s < 1.35)), ind_e / ind_s
    assert np.all(ld_e / ind_e < 0.85) and (ld_e / ind_e)[:2].max() < 0.7, ld_e / ind_e
