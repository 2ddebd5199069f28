"""Auxiliary buffers reused between frames (issue #31): :class:`arlight.denoise.aux.AuxCache`
serves a frame the buffers ``aux_buffers`` would trace for it, and traces again when the
camera, the object's pose or the sample count changed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from arlight.denoise.aux import AUX_CACHE, AuxCache, aux_buffers
from arlight.methods import RenderSettings, get_method
from arlight.methods.base import place_views
from tests.conftest import area_light_scene, load

pytest.importorskip("pyoidn")

W, H = 48, 36
ROWS, COLS = slice(4, 30), slice(6, 40)


def _prepared():
    scene = load(area_light_scene(W, H))
    scene = scene.with_frame(np.full((H, W, 3), 0.4, np.float32))
    method = get_method("onepass")
    state = method.prepare(scene.world, RenderSettings(spp=1))
    return scene, method, state


def _moved_camera(camera, dx: float = 0.08):
    m = np.array(camera.world_from_camera, np.float64)
    m[:3, 3] += m[:3, 0] * dx  # along the camera's right axis
    return replace(camera, world_from_camera=m)


def _same(a, b) -> bool:
    return np.array_equal(a.albedo, b.albedo) and np.array_equal(a.normal, b.normal)


def test_cache_serves_what_aux_buffers_traces_for_the_frame():
    """Every answer of the cache equals a fresh :func:`aux_buffers` of that frame, bit for
    bit: a window inside the cached one is a crop (hit), a window reaching outside is traced
    (miss), and a moved camera, a moved object (moved in place: the same scene object) or
    another sample count are traced again (miss) — each of those frames differs from the
    cached one, so a stale answer would fail. Rejects a key without the camera, without the
    object transforms or without the sample count, and a crop at the wrong offset."""
    scene, method, state = _prepared()
    view, cam = method.aux_view(state.data), scene.camera
    cache = AuxCache()

    first, hit = cache.get(view, cam, 4, {}, ROWS, COLS)
    assert not hit and _same(first, aux_buffers(view, cam, 4, ROWS, COLS))

    inner = (slice(9, 25), slice(11, 33))
    got, hit = cache.get(view, cam, 4, {}, *inner)
    assert hit and _same(got, aux_buffers(view, cam, 4, *inner))

    outer = (slice(0, 20), slice(0, W))
    got, hit = cache.get(view, cam, 4, {}, *outer)
    assert not hit and _same(got, aux_buffers(view, cam, 4, *outer))
    got, hit = cache.get(view, cam, 4, {}, ROWS, COLS)  # the union was kept: a hit now
    assert hit and _same(got, first)

    moved = _moved_camera(cam)
    fresh = aux_buffers(view, moved, 4, ROWS, COLS)
    assert not _same(fresh, first), "the moved camera must see other buffers"
    got, hit = cache.get(view, moved, 4, {}, ROWS, COLS)
    assert not hit and _same(got, fresh)

    fresh = aux_buffers(view, cam, 1, ROWS, COLS)
    assert not _same(fresh, first)
    got, hit = cache.get(view, cam, 1, {}, ROWS, COLS)
    assert not hit and _same(got, fresh)

    shift = np.eye(4)
    shift[:3, 3] = [0.12, 0.0, 0.05]
    assert place_views(state.data.views, scene.world, {"ball": shift}, real_moves=True)
    fresh = aux_buffers(view, cam, 4, ROWS, COLS)
    assert not _same(fresh, first), "the moved ball must change the buffers"
    got, hit = cache.get(view, cam, 4, {"ball": shift}, ROWS, COLS)
    assert not hit and _same(got, fresh)


def test_a_new_scene_object_is_never_served_an_old_ones_buffers():
    """The cache holds scene views weakly and matches them by identity: the same camera
    and pose in another prepared world (another virtual object) is traced again. Rejects a
    key by ``id()`` alone or without the view."""
    scene, method, state = _prepared()
    cache = AuxCache()
    got, _ = cache.get(method.aux_view(state.data), scene.camera, 4, {}, ROWS, COLS)
    spec = area_light_scene(W, H)
    spec["shapes"][-1]["radius"] = 0.35
    other = load(spec)
    state2 = method.prepare(other.world, RenderSettings(spp=1))
    view2 = method.aux_view(state2.data)
    got2, hit = cache.get(view2, other.camera, 4, {}, ROWS, COLS)
    assert not hit and _same(got2, aux_buffers(view2, other.camera, 4, ROWS, COLS))
    assert not _same(got2, got)


def test_a_still_frame_reuses_the_buffers_and_renders_the_same():
    """Through ``method.render``: a second frame of the same state and camera reuses the
    buffers (stat ``denoise_aux_cached`` 1) and its denoised composite equals the first bit
    for bit; a frame from a moved camera traces them again (0) and equals the frame
    rendered with an empty cache. Rejects a cache consulted with a key that ignores the
    camera (the moved frame would be denoised with the old buffers)."""
    scene, method, state = _prepared()
    settings = RenderSettings(spp=2, seed=3, options={"denoise": "oidn"})
    AUX_CACHE.clear()
    first = method.render(state, scene.view, settings)
    assert first.stats["denoise_aux_cached"] == 0.0
    again = method.render(state, scene.view, settings)
    assert again.stats["denoise_aux_cached"] == 1.0
    assert np.array_equal(again.composite, first.composite)

    view = replace(scene.view, camera=_moved_camera(scene.camera))
    moved = method.render(state, view, settings)
    assert moved.stats["denoise_aux_cached"] == 0.0
    AUX_CACHE.clear()
    cold = method.render(state, view, settings)
    assert cold.stats["denoise_aux_cached"] == 0.0
    assert np.array_equal(moved.composite, cold.composite)


def test_a_relit_state_traces_the_buffers_again():
    """``relight`` moves an area lamp in place (the same scene object, a new world): the
    state's world is part of the key, so the same window of the same view and camera is
    traced again after it, and served from the cache before it. Rejects a key without the
    world (a lamp seen by the camera would keep its old place in the albedo and normal)."""
    scene, method, state = _prepared()
    view, cam, before = method.aux_view(state.data), scene.camera, state.world
    cache = AuxCache()
    cache.get(view, cam, 4, {}, ROWS, COLS, before)
    assert cache.get(view, cam, 4, {}, ROWS, COLS, before)[1]
    lights = []
    for lt in state.world.lights:
        p = dict(lt.params)
        if lt.type == "area":
            m = np.array(p["to_world"], np.float64)
            m[:3, 3] += [-0.2, -0.1, 0.0]
            p["to_world"] = m
        lights.append(replace(lt, params=p))
    method.relight(state, lights)
    assert method.aux_view(state.data) is view, "relight must keep the view (in place)"
    got, hit = cache.get(view, cam, 4, {}, ROWS, COLS, state.world)
    assert not hit and _same(got, aux_buffers(view, cam, 4, ROWS, COLS))
