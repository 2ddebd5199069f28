"""Synthetic photographs: Mitsuba-rendered frame, ground truth and mask; batch standard
errors; the content-hash cache.

Each test's docstring names the bug it is there to catch.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import arlight.synthetic as syn
from arlight.errors import InputError
from arlight.scene.load import parse_scene
from arlight.synthetic import batch_plan, content_key, synthesize
from tests.conftest import LOOK, area_light_scene

# ------------------------------------------------------------------------------------------
# Batches and standard errors
# ------------------------------------------------------------------------------------------


def test_batch_plan_splits_spp_evenly_and_refuses_one_batch():
    """The plan sums to spp with sizes differing by at most one, uses at most spp batches,
    and refuses plans without a standard error: catches a dropped remainder (fewer samples
    than asked) and a single batch (stderr 0/0)."""
    assert batch_plan(256, 16) == [16] * 16
    assert batch_plan(37, 16) == [3] * 5 + [2] * 11
    assert batch_plan(5, 16) == [1] * 5
    for spp, batches, field in ((1, 16, "spp"), (8, 1, "batches")):
        with pytest.raises(InputError) as err:
            batch_plan(spp, batches)
        assert err.value.field == field


def test_mean_and_stderr_weight_batches_by_their_spp(monkeypatch, tmp_path):
    """With a stand-in for mitsuba.render that returns a known value per call, the mean is
    the spp-weighted mean of the batch means and the stderr sqrt(Σ n_b (m_b − m)² /
    ((B − 1) N)); every render gets its own seed. Catches an unweighted mean, a wrong
    degree-of-freedom count, a missing square root or N, and batches or streams (frame,
    ground truth, mask) that reuse a seed (correlated noise). (The `independent` sampler:
    the only one whose plan has unequal batches.)"""
    import mitsuba as mi

    calls: list[tuple[int, int]] = []

    def fake_render(scene, sensor=None, integrator=None, spp=0, seed=0):
        calls.append((spp, seed))
        value = [2.0, 5.0, 1.0, 3.0, 0.25][len(calls) - 1]
        return np.full((6, 8, 3), value)

    monkeypatch.setattr(mi, "render", fake_render)
    world = parse_scene(area_light_scene(8, 6))
    p = synthesize(world, spp=5, batches=2, cache_dir=tmp_path, progress=True,
                   sampler="independent")
    assert [n for n, _ in calls] == [3, 2, 3, 2, 64]  # frame, ground truth, mask
    assert len({s for _, s in calls}) == 5

    def expected(x0, x1):
        m = (3 * x0 + 2 * x1) / 5
        return m, np.sqrt((3 * (x0 - m) ** 2 + 2 * (x1 - m) ** 2) / (1 * 5))

    for img, se, (x0, x1) in ((p.frame, p.frame_stderr, (2.0, 5.0)),
                              (p.ground_truth, p.ground_truth_stderr, (1.0, 3.0))):
        m, s = expected(x0, x1)
        assert np.allclose(img, m, rtol=1e-6) and np.allclose(se, s, rtol=1e-6)
    assert np.all(p.mask == 0.25)


@pytest.mark.slow  # 10–40 s on 2 cores: the fast tier stays under ~15 min (./dev test-all runs it)
def test_stderr_matches_the_scatter_of_independent_photos(tmp_path):
    """Two photos with different seeds differ by about their combined standard error
    (mean z² near 1): catches standard errors off by a factor (per-batch instead of
    per-mean, or N for sqrt(N)) and batches that share random numbers (stderr near 0)."""
    world = parse_scene(area_light_scene(16, 12))
    a = synthesize(world, spp=64, seed=1, use_cache=False)
    b = synthesize(world, spp=64, seed=2, use_cache=False)
    for x, y, sx, sy in ((a.frame, b.frame, a.frame_stderr, b.frame_stderr),
                         (a.ground_truth, b.ground_truth, a.ground_truth_stderr,
                          b.ground_truth_stderr)):
        lit = (sx > 0) & (sy > 0)
        z2 = (x - y)[lit] ** 2 / (sx**2 + sy**2)[lit]
        assert lit.mean() > 0.9 and 0.6 < z2.mean() < 1.6, z2.mean()


# ------------------------------------------------------------------------------------------
# What is rendered
# ------------------------------------------------------------------------------------------


def test_frame_excludes_and_ground_truth_includes_virtual(tmp_path):
    """Where the virtual ball covers pixels the ground truth differs from the frame:
    catches the frame and ground truth being rendered from the same view."""
    world = parse_scene(area_light_scene(16, 12))
    p = synthesize(world, spp=16, seed=1, cache_dir=tmp_path)
    assert p.frame.shape == (12, 16, 3) and p.mask.shape == (12, 16) and p.mask.max() == 1.0
    covered = p.mask == 1.0
    diff = np.abs(p.ground_truth - p.frame)[covered].max(axis=1)
    se = np.hypot(p.ground_truth_stderr, p.frame_stderr)[covered].max(axis=1)
    assert np.mean(diff > 3 * se) > 0.5


def test_without_virtual_objects_mask_is_zero_and_renders_are_independent():
    """No virtual shape: the mask is 0 and the ground truth is an independent render of the
    same world: catches a ground truth that reuses the frame's seed (its noise would cancel
    in every composite-vs-ground-truth comparison)."""
    world = parse_scene(area_light_scene(16, 12, virtual=False))
    p = synthesize(world, spp=32, seed=4, use_cache=False)
    assert np.all(p.mask == 0)
    assert not np.array_equal(p.frame, p.ground_truth)
    z = np.abs(p.frame - p.ground_truth) / np.maximum(
        np.hypot(p.frame_stderr, p.ground_truth_stderr), 1e-6)
    assert np.mean(z.max(axis=2) <= 3.5) >= 0.97


def _cards_scene(n_px: int):
    """Two virtual cards before a camera looking down −Z, edges at fractional pixels; the
    right card faces away from the camera (rotated 180° about y)."""
    f = 20.0
    return parse_scene({
        "camera": {"resolution": [n_px, n_px],
                   "intrinsics": {"fx": f, "fy": f, "cx": n_px / 2, "cy": n_px / 2},
                   "world_from_camera": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0],
                                         [0, 0, 0, 1]]},
        "shapes": [
            {"role": "real", "type": "rectangle", "size": [20, 20],
             "transform": {"translate": [0, 0, -5]}},
            {"role": "virtual", "type": "rectangle", "size": [0.5, 0.62],
             "transform": {"translate": [-0.33, -0.07, -2.0]}},
            {"role": "virtual", "type": "rectangle", "size": [0.45, 0.9],
             "transform": {"rotate": [0, 1, 0, 180],
                           "translate": [0.41, 0.13, -2.0]}},
        ],
        "lights": [{"type": "constant", "radiance": 1.0}]})


def _card_coverage(n_px: int) -> np.ndarray:
    """Exact pixel coverage of the two cards (pinhole f = 20 px, depth 2 m, y down)."""
    f, z, c = 20.0, 2.0, n_px / 2
    edges = np.arange(n_px + 1)

    def overlap(a, b):
        return np.clip(np.minimum(edges[1:], b) - np.maximum(edges[:-1], a), 0, 1)

    out = np.zeros((n_px, n_px))
    for x, y, w, h in ((-0.33, -0.07, 0.5, 0.62), (0.41, 0.13, 0.45, 0.9)):
        cols = overlap((x - w / 2) * f / z + c, (x + w / 2) * f / z + c)
        rows = overlap(-(y + h / 2) * f / z + c, -(y - h / 2) * f / z + c)
        out += np.outer(rows, cols)
    return out


def test_mask_is_the_covered_fraction_of_each_pixel():
    """The mask equals the exact coverage of two virtual cards, one seen from behind: 1 and 0
    exactly away from edges, edge pixels within 5 binomial standard errors of the
    max(spp, 64) = 256 mask samples (sqrt(c(1 − c)/256) ≤ 0.031). Catches a half-pixel
    shift (errors up to 0.5), a flipped image axis, one-sided coverage (the back-facing card
    would read 0) and a mask counting real or missed rays."""
    n_px = 16
    exact = _card_coverage(n_px)
    p = synthesize(_cards_scene(n_px), spp=256, seed=3, use_cache=False)
    partial = (exact > 0) & (exact < 1)
    assert partial.sum() >= 30 and (exact == 1).sum() >= 20
    assert np.all(p.mask[exact == 1] == 1) and np.all(p.mask[exact == 0] == 0)
    tol = 5 * np.sqrt(exact * (1 - exact) / 256) + 1e-6
    err = np.abs(p.mask - exact)
    assert np.all(err[partial] <= tol[partial]), (err - tol).max()


def _camera_world(kind: str, width: int, height: int):
    d = area_light_scene(width, height)
    if kind == "pinhole-off-centre":
        f = 0.5 * height / np.tan(np.radians(45) / 2)
        d["camera"] = {"resolution": [width, height], "look_at": LOOK,
                       "intrinsics": {"fx": f, "fy": f, "cx": 0.41 * width,
                                      "cy": 0.44 * height}}
    else:
        d["camera"].update(aperture_radius=0.1, focus_distance=1.0)
    return parse_scene(d)


@pytest.mark.parametrize("kind", ["pinhole-off-centre", "thin-lens"])
def test_mitsuba_photo_and_reference_method_see_the_same_world(kind):
    """Proxy == world: the ``reference`` method (our camera rays, our passes) on the
    Mitsuba-rendered frame reproduces the Mitsuba-rendered ground truth — composite within
    3 SE on ≥ 99 % of pixels, image means of mixed and real within 4 SE, masks within 5
    binomial SE. The two renderers share only the scene translation, so this catches any
    disagreement about the camera: a flipped x or y axis, a half-pixel shift or a principal
    point offset with the wrong sign (masks differ by ~0.5 at edges), a wrong field of view,
    a thin lens with another focus distance or aperture size."""
    from arlight.methods import RenderSettings, get_method
    from arlight.stats import agreement_fraction

    world = _camera_world(kind, 64, 48)
    # 64 batches: the photo's standard errors have 63 degrees of freedom, so the 3-SE rule
    # holds with margin (about 0.5 % of pixels fail it with a correct camera; 1 % allowed)
    photo = synthesize(world, spp=1024, seed=21, use_cache=False, batches=64)
    layers = get_method("reference")(world.with_frame(photo.frame),
                                     RenderSettings(spp=256, seed=5))
    keep = (1.0 - layers.mask)[..., None]
    se = np.sqrt(layers.stderr["composite"] ** 2 + (keep * photo.frame_stderr) ** 2)
    frac = agreement_fraction(layers.composite, se, photo.ground_truth,
                              photo.ground_truth_stderr)
    assert frac >= 0.99, frac
    for ours, our_se, theirs, their_se in (
            (layers.mixed, layers.stderr["mixed"], photo.ground_truth,
             photo.ground_truth_stderr),
            (layers.real, layers.stderr["real"], photo.frame, photo.frame_stderr)):
        se_mean = np.sqrt((our_se**2).sum() + (their_se**2).sum()) / ours.size
        assert abs(ours.mean() - theirs.mean()) <= 4 * se_mean, (ours.mean(), theirs.mean())
    # reference: 16×16 stratified samples; photo: 1024 independent ones, sd ≤ 0.5/32
    assert np.abs(layers.mask - photo.mask).max() <= 5 * np.sqrt(0.25 / 1024 + 0.25 / 256)


def test_square_aperture_is_refused():
    """Mitsuba has no square aperture: a clear InputError instead of a photo of another
    camera."""
    d = area_light_scene(8, 6)
    d["camera"].update(aperture_radius=0.05, aperture_shape="square")
    with pytest.raises(InputError, match="square") as err:
        synthesize(parse_scene(d), spp=4, use_cache=False)
    assert err.value.field == "camera.aperture_shape"


# ------------------------------------------------------------------------------------------
# Cache
# ------------------------------------------------------------------------------------------


def test_cache_round_trip(tmp_path, monkeypatch):
    """The second call reads the file the first wrote (rendering is made impossible):
    catches a key that is not stable between calls."""
    world = parse_scene(area_light_scene(12, 9))
    a = synthesize(world, spp=4, seed=3, cache_dir=tmp_path)
    files = list((tmp_path / "synthetic").glob("*.npz"))
    assert len(files) == 1 and files[0].name == f"{a.key}.npz"
    monkeypatch.setattr(syn, "_render", lambda *a, **k: pytest.fail("rendered again"))
    b = synthesize(world, spp=4, seed=3, cache_dir=tmp_path)
    for name in ("frame", "frame_stderr", "ground_truth", "ground_truth_stderr", "mask"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert b.key == a.key == content_key(world, spp=4, seed=3)


@pytest.fixture(scope="module")
def cached_photo(tmp_path_factory):
    """A small world, its photograph and the cache folder that photograph was written to
    (rendered once for the damage cases below; each damages a copy)."""
    cache = tmp_path_factory.mktemp("synthetic-cache")
    world = parse_scene(area_light_scene(8, 6))
    return world, synthesize(world, spp=4, seed=3, cache_dir=cache), cache


@pytest.mark.parametrize("damage", ["truncated", "garbage", "missing-array", "wrong-shape"])
def test_damaged_cache_file_is_a_miss(tmp_path, damage, cached_photo):
    """A truncated, corrupt or foreign cache file is rendered again and replaced, not an
    exception; the re-render is bitwise the original (same seeds)."""
    world, a, cache = cached_photo
    shutil.copytree(cache, tmp_path, dirs_exist_ok=True)
    path = tmp_path / "synthetic" / f"{a.key}.npz"
    assert path.is_file()
    data = path.read_bytes()
    if damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(b"\x00" * 100)
    else:
        arrays = {k: getattr(a, k) for k in ("frame", "frame_stderr", "ground_truth",
                                             "ground_truth_stderr", "mask")}
        if damage == "missing-array":
            del arrays["mask"]
        else:
            arrays["frame"] = arrays["frame"][:2]
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)
    b = synthesize(world, spp=4, seed=3, cache_dir=tmp_path)
    assert np.array_equal(a.ground_truth, b.ground_truth) and np.array_equal(a.mask, b.mask)
    with np.load(path) as z:
        assert np.array_equal(z["frame"], a.frame)


def _write_uv_mesh(path, subdivisions: int | None = None) -> None:
    import trimesh

    mesh = trimesh.creation.box() if subdivisions is None else trimesh.creation.icosphere(
        subdivisions)
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    mesh.export(path)


def _key_world(tmp_path, edit=None):
    """A world with a mesh, a texture file and a Phong material; ``edit(d)`` changes it."""
    from arlight.io.images import write_png

    if not (tmp_path / "m.obj").exists():
        _write_uv_mesh(tmp_path / "m.obj")
        write_png(tmp_path / "t.png", np.full((4, 4, 3), 120, np.uint8))
    d = area_light_scene(8, 6)
    d["description"] = "a test world"
    d["shapes"].append({"name": "cube", "role": "virtual", "type": "mesh", "file": "m.obj",
                        "material": {"type": "diffuse", "texture": "t.png"}})
    if edit is not None:
        edit(d)
    return parse_scene(d, base_dir=tmp_path)


def _set(path: str, value):
    def edit(d):
        node = d
        keys = path.split(".")
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node[k]
        node[keys[-1]] = value
    return edit


def _rewrite(tmp_path, name: str):
    def edit(d):
        from arlight.io.images import write_png

        if name == "m.obj":
            _write_uv_mesh(tmp_path / "m.obj", 1)
        else:
            write_png(tmp_path / "t.png", np.full((4, 4, 3), 121, np.uint8))
    return edit


CHANGES_IMAGE = {
    "phong exponent": lambda tmp: _set("shapes.3.material.exponent", 21),
    "light radiance": lambda tmp: _set("lights.0.radiance", 13.0),
    "camera pose": lambda tmp: _set("camera.look_at", {"origin": [0, 0.9, 2.3],
                                                       "target": LOOK["target"]}),
    "mesh file content": lambda tmp: _rewrite(tmp, "m.obj"),
    "texture file content": lambda tmp: _rewrite(tmp, "t.png"),
}
IMAGE_NEUTRAL = {
    "scene description": lambda tmp: _set("description", "another text"),
    "shape name": lambda tmp: _set("shapes.0.name", "ground"),
    "transfer function": lambda tmp: _set("camera.exposure", 1.5),
}


@pytest.mark.parametrize("change", list(CHANGES_IMAGE))
def test_key_changes_with_what_changes_the_image(tmp_path, change):
    """Edits that change the rendered images change the key, including the content of files
    the world references: catches a stale photo served from the cache."""
    base = content_key(_key_world(tmp_path), spp=4)
    assert content_key(_key_world(tmp_path, CHANGES_IMAGE[change](tmp_path)), spp=4) != base


@pytest.mark.parametrize("change", list(IMAGE_NEUTRAL))
def test_key_ignores_edits_that_do_not_change_the_image(tmp_path, change):
    """Names, the description text and the display transfer do not enter the render, so
    they keep the key (and the cached photo): catches a key over the scene file's text."""
    base = content_key(_key_world(tmp_path), spp=4)
    assert content_key(_key_world(tmp_path, IMAGE_NEUTRAL[change](tmp_path)), spp=4) == base


def test_key_follows_render_settings():
    """spp, seed, batches, max_depth and rr_depth each change the key; batch counts above
    spp render the same plan and share it."""
    world = parse_scene(area_light_scene(8, 6))
    base = dict(spp=16, seed=1, max_depth=8, rr_depth=5, batches=16)
    k = content_key(world, **base)
    for name, value in (("spp", 32), ("seed", 2), ("batches", 8), ("max_depth", 3),
                        ("rr_depth", 2)):
        assert content_key(world, **{**base, name: value}) != k, name
    assert content_key(world, **{**base, "batches": 64}) == k
    small = world.resized(4, 3)
    assert content_key(small, **base) != k


def test_key_follows_the_phong_plugin_source_only_when_used(monkeypatch):
    """The Python Phong BSDF is code that determines the image: editing it changes the key
    of worlds with a Phong material and of no others."""
    phong = parse_scene(area_light_scene(8, 6))
    d = area_light_scene(8, 6, virtual=False)
    plain = parse_scene(d)
    before = content_key(phong), content_key(plain)
    real = syn._module_source
    monkeypatch.setattr(syn, "_module_source", lambda name: real(name) + "\n# edited\n")
    assert content_key(phong) != before[0] and content_key(plain) == before[1]


# ------------------------------------------------------------------------------------------
# Low-discrepancy samplers
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("spp", "batches"), [(256, 64), (64, 64), (100, 16), (37, 16),
                                              (70, 8), (1024, 64)])
def test_low_discrepancy_plan_renders_exactly_what_it_says(spp, batches):
    """A low-discrepancy plan is equal batches (i.i.d. batch means: an honest spread) that
    sum to spp, at least min(batches, spp) of them, each a count Mitsuba's sampler renders
    without rounding (asked of the plugin). Catches a plan of counts the sampler rounds up
    (5 → 6 for multijitter: more samples than the plan weights), unequal LD batches, or
    fewer batches than asked."""
    import mitsuba as mi

    plan = batch_plan(spp, batches, "multijitter")
    assert sum(plan) == spp and len(set(plan)) == 1 and len(plan) >= min(batches, spp)
    n = plan[0]
    mi.set_log_level(mi.LogLevel.Error)
    try:
        assert mi.load_dict({"type": "multijitter", "sample_count": n}).sample_count() == n
    finally:
        mi.set_log_level(mi.LogLevel.Warn)
    assert batch_plan(256, 64, "ldsampler") == [4] * 64
    with pytest.raises(InputError) as err:
        batch_plan(64, 64, "ldsampler")  # 1 sample per batch: ldsampler renders 4
    assert err.value.field == "spp"
    with pytest.raises(InputError) as err:
        batch_plan(64, 8, "sobol")
    assert err.value.field == "sampler"


def test_key_follows_the_sampler():
    """The sampler changes the images, so it changes the key (a photo rendered with another
    sampler is not served from the cache)."""
    world = parse_scene(area_light_scene(8, 6))
    keys = {content_key(world, spp=64, batches=16, sampler=s) for s in syn.SAMPLERS}
    assert len(keys) == len(syn.SAMPLERS)
    assert content_key(world, spp=64, batches=16) == content_key(
        world, spp=64, batches=16, sampler=syn.DEFAULT_SAMPLER)


@pytest.mark.slow  # 10–40 s on 2 cores: the fast tier stays under ~15 min (./dev test-all runs it)
def test_low_discrepancy_photos_are_closer_to_the_truth_with_honest_stderr():
    """Photos of a diffuse room at 64 spp in 16 batches, against a 4096-spp `independent`
    render: (a) with the default low-discrepancy sampler the squared errors average to the
    squared standard errors (pooled ratio near 1, few |z| > 3): the batch spread is honest.
    A per-sample variance (what one batch of stratified samples would give) overstates the
    error about 2.5× here (ratio ≈ 0.4) and batches sharing a randomisation give SE ≈ 0
    (huge ratio): both fail. (b) Its mean squared error is well below `independent`'s at
    equal spp (measured ≈ 0.4×; the bound 0.75 fails a sampler that is not applied, ≈ 1×),
    and so are its standard errors."""
    world = parse_scene(area_light_scene(32, 24, virtual=False))
    truth = synthesize(world, spp=4096, seed=7, sampler="independent", use_cache=False)
    stats = {}
    for sampler in (syn.DEFAULT_SAMPLER, "independent"):
        err2, se2, z = [], [], []
        for seed in (1, 2, 3):
            p = synthesize(world, spp=64, batches=16, seed=seed, sampler=sampler,
                           use_cache=False)
            for img, se, t, t_se in ((p.frame, p.frame_stderr, truth.frame,
                                      truth.frame_stderr),
                                     (p.ground_truth, p.ground_truth_stderr,
                                      truth.ground_truth, truth.ground_truth_stderr)):
                lit = se > 0
                d2 = (img.astype(np.float64) - t)[lit] ** 2
                s2 = se.astype(np.float64)[lit] ** 2
                t2 = t_se.astype(np.float64)[lit] ** 2
                err2.append(d2 - t2)  # the truth's own noise taken out
                se2.append(s2)
                z.append(np.sqrt(d2 / (s2 + t2)))
        err2, se2, z = (np.concatenate(a) for a in (err2, se2, z))
        stats[sampler] = (err2.mean(), se2.mean(), np.mean(z > 3))
    ld, ind = stats[syn.DEFAULT_SAMPLER], stats["independent"]
    for name, (e2, s2, tail) in stats.items():
        assert 0.75 < e2 / s2 < 1.35 and tail < 0.04, (name, e2 / s2, tail)
    assert ld[0] / ind[0] < 0.75 and ld[1] / ind[1] < 0.75, (ld, ind)


def test_spec_key_is_the_content_hash_in_insertion_order():
    """The cache key uses arlight.content_hash, keeping the order of dict items (a view's
    objects in scene order) and the type tags (1 and 1.0, "1" and 1 differ)."""
    from arlight.synthetic import spec_key
    assert spec_key({"a": 1, "b": 2}) != spec_key({"b": 2, "a": 1})
    assert spec_key({"a": 1}) != spec_key({"a": 1.0}) != spec_key({"a": "1"})
    assert len(spec_key({"a": [1, 2]})) == 32
