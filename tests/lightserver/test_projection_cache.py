"""The light server's camera→texel projection cached per rig and proxy (issue #32, part 4).

A cached update must give what projecting from scratch gives, and any change of the rig or
the proxy must recompute the taps. What each test rejects:

* cached == uncached, **bitwise** (radiance atlas, weights and the whole light state; and
  == ``merge`` of ``project_camera`` from scratch): the cached path samples the same taps
  with the same arithmetic and sums the cameras in the same order, so any difference is a
  bug — taps sampled with other rounding, cameras summed in another order, an update
  writing into the cached arrays, warm-start state lost on a hit;
* against an **independent** resampling (SciPy's ``map_coordinates`` and the weights from
  ``camera_weights``), to float tolerance (1e-12 relative: float64 sums in another order) —
  rejects tap indices or fractions that are wrong in both paths (x/y swapped, an off-by-half
  pixel, taps of another camera);
* a cache hit traces **no ray** (the update re-projects radiance only);
* a camera moved, turned or recalibrated in place, the rig replaced by a subset, a real shape
  of the proxy moved: the next update equals a fresh server's on the changed input (and
  differs from the old result, so the change matters) — rejects a key of camera names or
  object identity, a key of the rig or of the proxy alone, a key computed once;
* an equal rig built anew hits the cache (a key of content, not of identity).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from arlight.nearfield import projection as projection_module
from arlight.nearfield.cameras import auto_rig
from arlight.nearfield.pipeline import NearFieldServer, NearFieldSettings
from arlight.nearfield.projection import camera_weights, merge, project_camera
from arlight.nearfield.projection_cache import ProjectionCache, proxy_key, rig_key
from tests.nearfield.conftest import room, vbox, world

SIZE = 32  # px per side of the fisheyes
BOX = {"name": "rbox", "role": "real", "type": "box", "size": [0.4, 0.5, 0.4],
       "transform": {"translate": [0.35, 0.25, -0.3]},
       "material": {"type": "diffuse", "albedo": [0.6, 0.5, 0.4]}}


def settings() -> NearFieldSettings:
    return NearFieldSettings(atlas_resolution=48, tau=0.8, vals=6)


@pytest.fixture(scope="module")
def scene():
    """A room with a real box (occlusion), a virtual box, 5 fisheyes, two frames."""
    w = world(room(virtual=[vbox()], extra=[BOX]))
    rig = auto_rig(np.array([-1, 0, -1.0]), np.array([1, 2, 1.0]), SIZE)[:5]
    rng = np.random.default_rng(7)
    frames = []
    for k in range(2):
        imgs = [rng.uniform(0.1, 0.3, (SIZE, SIZE, 3)).astype(np.float32) for _ in rig]
        for im in imgs:
            im[8 + 4 * k:12 + 4 * k, 10:14] = 30.0  # bright spots that move
        frames.append(imgs)
    return w, rig, frames


def _server(w, rig) -> NearFieldServer:
    return NearFieldServer(w, copy.deepcopy(rig), settings())


def _assert_light_equal(a, b) -> None:
    for name in ("positions", "normals", "intensity", "area", "sh"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_cached_update_equals_the_uncached_one_bitwise(scene):
    w, rig, (f0, f1) = scene
    cached = _server(w, rig)
    cached.update(f0)
    a = cached.update(f1)
    assert (cached.projections.misses, cached.projections.hits) == (1, 1)
    assert "visibility" not in cached.stats
    fresh = _server(w, rig)
    fresh.update(f0)  # the same warm start for the k-means
    fresh.projections.clear()
    b = fresh.update(f1)
    assert fresh.projections.misses == 2 and "visibility" in fresh.stats
    np.testing.assert_array_equal(cached.last.radiance, fresh.last.radiance)
    np.testing.assert_array_equal(cached.last.weight, fresh.last.weight)
    _assert_light_equal(a, b)
    assert a.count > 0 and np.any(a.sh != 0)  # both VALs and SH are compared
    # and the public from-scratch path: project every camera, merge the full-size arrays
    rad, wsum = merge([project_camera(cached.geometry, cam, img, cached.proxy_scene)
                       for cam, img in zip(cached.cameras, f1, strict=True)])
    np.testing.assert_array_equal(cached.last.radiance, rad)
    np.testing.assert_array_equal(cached.last.weight, wsum)


def test_cached_projection_matches_an_independent_resampling(scene):
    from scipy.ndimage import map_coordinates

    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)
    server.update(f1)  # a cache hit
    acc = np.zeros((len(server.area), 3))
    wsum = np.zeros(len(server.area))
    for cam, img in zip(server.cameras, f1, strict=True):
        wt, pix = camera_weights(server.geometry, cam, server.proxy_scene)
        seen = wt > 0
        x = np.clip(pix[seen, 0] - 0.5, 0, SIZE - 1)
        y = np.clip(pix[seen, 1] - 0.5, 0, SIZE - 1)
        for c in range(3):
            acc[seen, c] += wt[seen] * map_coordinates(img[..., c].astype(np.float64),
                                                       [y, x], order=1, mode="nearest")
        wsum += wt
    want = np.where(wsum[:, None] > 0, acc / np.maximum(wsum, 1e-300)[:, None], 0.0)
    assert (wsum > 0).sum() > 0.5 * len(wsum)  # the rig sees most of the proxy
    np.testing.assert_array_equal(server.last.weight, wsum)
    np.testing.assert_allclose(server.last.radiance, want, rtol=1e-12, atol=1e-12)


def test_a_cache_hit_traces_no_ray(scene, monkeypatch):
    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)

    def no_rays(*args, **kwargs):
        raise AssertionError("a cached update traced visibility rays")

    monkeypatch.setattr(projection_module, "segment_visible", no_rays)
    server.update(f1)  # hit: samples only
    server.projections.clear()
    with pytest.raises(AssertionError, match="visibility rays"):
        server.update(f1)


def _turn(m: np.ndarray, deg: float) -> np.ndarray:
    a = np.radians(deg)
    r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return r @ m


RIG_CHANGES = {
    "moved in place": lambda cams: cams[1].position.__iadd__(np.array([0.07, -0.05, 0.03])),
    "turned": lambda cams: setattr(cams[2].model, "world_from_camera",
                                   _turn(cams[2].model.world_from_camera, 9.0)),
    "recalibrated in place": lambda cams: cams[0].model.K.__setitem__((0, 0),
                                                                      cams[0].model.K[0, 0] * 1.1),
}


@pytest.mark.parametrize("change", sorted(RIG_CHANGES))
def test_a_changed_camera_recomputes_the_projection(scene, change):
    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)
    server.update(f1)
    before = server.last.radiance.copy()
    RIG_CHANGES[change](server.cameras)  # the server's own camera objects, changed in place
    server.update(f1)
    assert server.projections.misses == 2
    fresh = _server(w, server.cameras)  # a server that never saw the old rig
    fresh.update(f1)
    np.testing.assert_array_equal(server.last.radiance, fresh.last.radiance)
    np.testing.assert_array_equal(server.last.weight, fresh.last.weight)
    assert not np.array_equal(server.last.radiance, before)


def test_a_rig_replaced_by_a_subset_recomputes_the_projection(scene):
    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)
    server.cameras = server.cameras[:4]
    server.update(f1[:4])
    fresh = _server(w, rig[:4])
    fresh.update(f1[:4])
    np.testing.assert_array_equal(server.last.radiance, fresh.last.radiance)
    np.testing.assert_array_equal(server.last.weight, fresh.last.weight)


def test_a_moved_real_shape_recomputes_the_atlas_and_the_projection(scene):
    """The real box moves (a tracked real object): the atlas keeps its layout (same charts,
    same texel count), so stale taps would be used silently with a key of the rig alone."""
    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)
    server.update(f1)
    before = server.last.radiance.copy()
    n_before = len(server.area)
    t = np.eye(4)
    t[:3, 3] = [-0.25, 0.0, 0.2]
    moved = w.posed({"rbox": t})
    server.set_world(moved)
    server.update(f1)
    assert server.projections.misses == 2 and len(server.area) == n_before
    fresh = NearFieldServer(moved, copy.deepcopy(rig), settings())
    fresh.update(f1)
    np.testing.assert_array_equal(server.position, fresh.position)
    np.testing.assert_array_equal(server.last.radiance, fresh.last.radiance)
    np.testing.assert_array_equal(server.last.weight, fresh.last.weight)
    assert not np.array_equal(server.last.radiance, before)
    # moving only the virtual object keeps the proxy: the taps stay cached
    v = np.eye(4)
    v[:3, 3] = [0.1, 0.0, 0.0]
    server.set_object_transforms({"obj": v})
    server.update(f0)
    assert (server.projections.misses, server.projections.hits) == (2, 2)


def test_an_equal_rig_built_anew_hits_the_cache(scene):
    w, rig, (f0, f1) = scene
    server = _server(w, rig)
    server.update(f0)
    server.cameras = copy.deepcopy(server.cameras)
    for cam in server.cameras:
        cam.image = None  # the image path is not part of the projection
    server.update(f1)
    assert (server.projections.misses, server.projections.hits) == (1, 1)


def test_keys_name_every_input():
    rig = auto_rig(np.array([-1, 0, -1.0]), np.array([1, 2, 1.0]), 16)[:2]
    base = rig_key(rig)
    assert rig_key(copy.deepcopy(rig)) == base
    changed = copy.deepcopy(rig)
    changed[1].name = "other"
    assert rig_key(changed) != base
    changed = copy.deepcopy(rig)
    changed[0].model.D = np.array([0.01, 0.0, 0.0, 0.0])
    assert rig_key(changed) != base
    assert rig_key(rig[::-1]) != base
    v = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    k = proxy_key(v, f, 64, 4)
    assert k == proxy_key(v.copy(), f.copy(), 64, 4)
    assert len({k, proxy_key(v, f, 128, 4), proxy_key(v, f, 64, 2),
                proxy_key(v + 1e-9, f, 64, 4), proxy_key(v, f[:, ::-1], 64, 4)}) == 5


def test_cache_capacity_and_failed_builds():
    cache = ProjectionCache(capacity=2)
    assert cache.get("a", lambda: ["A"]) == ["A"]
    cache.get("b", lambda: ["B"])
    assert cache.get("a", lambda: ["new"]) == ["A"]  # a is now the most recent
    cache.get("c", lambda: ["C"])  # drops b, the least recently used
    assert "b" not in cache and "a" in cache and len(cache) == 2

    def fail():
        raise ValueError("no")

    with pytest.raises(ValueError):
        cache.get("d", fail)
    assert "d" not in cache
    with pytest.raises(ValueError):
        ProjectionCache(capacity=0)
