"""dic's incremental pose (issue #32): a moved virtual object moves in place in both Mitsuba
views, and :class:`DicSequence` drops only the records near the object's old and new
positions.

The contract (``docs/methods/dic.md``, "Incremental pose"):

* ``DicMethod.render`` of a posed view is **bitwise** ``render`` of a fresh preparation of
  the posed world (dic builds its cache per frame from the posed views);
* a :class:`DicSequence` frame after a move drops exactly the records within
  ``invalidate_distance`` of the object's bounds before or after the move, keeps the others
  bit for bit (values, ages, ids), and is bitwise what :func:`render_frame` makes from a
  fresh preparation of the posed world with the same cache.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from arlight.methods import RenderSettings, get_method
from arlight.methods.dic import DicMethod, DicSequence, render_frame
from arlight.scene.model import ARScene
from arlight.timing import StageTimer
from arlight.tracing.scenes import prepare_scenes
from tests.conftest import area_light_scene, diffuse, load, with_constant_frame

BALL_CENTRE = np.array([0.15, 0.25, 0.1])
BALL_RADIUS = 0.25
"""The virtual ball of :func:`tests.conftest.area_light_scene` (m)."""


def scene_of(width: int = 24, height: int = 18):
    d = copy.deepcopy(area_light_scene(width, height))
    d["shapes"][-1]["material"] = diffuse([0.3, 0.5, 0.8])
    return with_constant_frame(load(d))


def shift(x: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = [x, 0.0, z]
    return m


def _equal(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k))
               for k in ("mixed", "delta", "mask", "composite"))


SETTINGS = RenderSettings(spp=2, seed=3, options={"rays": 32})


def test_posed_renders_equal_a_fresh_preparation():
    """One prepared state renders two moves of the ball and the rest pose again; each frame
    is bitwise the one-shot render of the posed world. Rejects a pose that leaves the shapes
    where they were (the first move would render the rest pose), moves only one of the two
    views (the real continuation / shadow rules would see the old ball) or does not return
    to rest when a view moves nothing."""
    scene = scene_of()
    method = get_method("dic")
    assert isinstance(method, DicMethod) and method.incremental_pose
    state = method.prepare(scene.world, SETTINGS)
    for transforms in ({"ball": shift(-0.3, 0.2)}, {"ball": shift(0.2, -0.1)}, {}):
        view = replace(scene.view, object_transforms=transforms)
        got = method.render(state, view, SETTINGS)
        fresh = method(ARScene.compose(scene.world.posed(transforms),
                                       replace(view, object_transforms={})), SETTINGS)
        assert _equal(got, fresh), transforms
    rest = method(scene, SETTINGS)
    assert _equal(got, rest)
    moved = method.render(state, replace(scene.view,
                                         object_transforms={"ball": shift(-0.3, 0.2)}),
                          SETTINGS)
    assert not np.array_equal(moved.mask, rest.mask)  # the move is visible at this size


def _box(move: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = BALL_CENTRE + move[:3, 3]
    return c - BALL_RADIUS, c + BALL_RADIUS


def _dist_to_box(p: np.ndarray, box) -> np.ndarray:
    lo, hi = box
    return np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)


def test_sequence_drops_only_the_records_near_the_old_and_new_positions():
    """The ball moves 0.35 m; the records kept are exactly those farther than
    ``invalidate_distance`` from the ball's box before *and* after the move (boxes from the
    scene's sphere, not from the code's bounds), with bitwise the values, ages and ids they
    had; the frame equals :func:`render_frame` on a fresh preparation of the posed world
    with that cache. Rejects: dropping every record (a full re-computation), dropping only
    near the new position (the old shadow stays in the cache), re-evaluating the kept
    records, a frame that differs from the posed world's."""
    scene = scene_of()
    dist = 0.15
    s = RenderSettings(spp=2, seed=3, options={"rays": 32, "invalidate_distance": dist,
                                               "t_max": 100})
    seq = DicSequence(scene.world, s)
    seq.render(scene.view)
    before = seq.cache
    move = shift(-0.35, 0.0)
    view = replace(scene.view, object_transforms={"ball": move})
    frame = seq.render(view)
    old, new = _box(np.eye(4)), _box(move)
    p = before.records.position
    near = (_dist_to_box(p, old) <= dist) | (_dist_to_box(p, new) <= dist)
    assert 0 < near.sum() < len(p) and (_dist_to_box(p, new) <= dist).sum() < near.sum()
    assert frame.stats["records_dropped"] == near.sum()
    kept_before = before.records.take(~near)
    after = seq.cache.records
    kept = after.take(np.arange(len(kept_before)))
    for f in ("position", "normal", "e_mixed", "e_delta", "radius", "key", "ident"):
        assert np.array_equal(getattr(kept, f), getattr(kept_before, f)), f
    assert np.array_equal(kept.age, kept_before.age + 1)
    assert frame.stats["records_reevaluated"] == 0 and frame.stats["records_new"] > 0
    # the in-place move is invisible: a fresh preparation of the posed world, same cache
    opts = DicMethod.spec.parse_options(s.options)
    fresh = render_frame(prepare_scenes(scene.world.posed({"ball": move})),
                         replace(view, object_transforms={}), opts, s, StageTimer(),
                         before, moved=True)
    assert _equal(frame, fresh.layers)
