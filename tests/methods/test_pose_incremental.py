"""Incremental pose (issue #32): a method with ``incremental_pose`` moves its prepared state
in place when a view moves a virtual object, and renders bitwise what preparing the posed
world from scratch renders.

Each test names the wrong implementation it rejects."""

from __future__ import annotations

from dataclasses import replace

import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import build_views
from arlight.demo import DEMO_DIR
from arlight.methods import RenderSettings, get_method
from arlight.scene.load import load_scene
from arlight.scene.model import World

SMALL: dict[str, dict] = {
    "dir": {"vpls": 64},
    "dlpv": {"volume_size": 16, "rsm_size": 32},
    "dvct": {"volume_size": 16, "rsm_size": 32},
    "ibl": {"oof_directions": 64, "oof_shells": 6},
    "prt": {"oof_directions": 64, "oof_shells": 6, "directions": 64},
    "onepass": {},
    "reference": {},
    "probeless": {"variant": "REG4"},
    "nearfield": {"directions": 64, "shadow_map_size": 32, "vals": 2},
}
"""Small options per method (the identities do not depend on the sizes); nearfield also gets
a light file (:func:`nearfield_light`)."""


def rigid(angle_deg: float, shift) -> np.ndarray:
    """A rotation about +y by ``angle_deg`` then a shift (metres), 4×4."""
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[[0, 0, 2, 2], [0, 2, 0, 2]] = [np.cos(a), np.sin(a), -np.sin(a), np.cos(a)]
    m[:3, 3] = shift
    return m


MOVES = [rigid(30.0, [0.03, 0.0, -0.02]), rigid(-15.0, [-0.05, 0.0, 0.04])]
POSES = [{"bunny": MOVES[0]}, {"bunny": MOVES[1]}, {"bunny": rigid(0.0, [0.002, 0.0, 0.0])},
         {"bunny": MOVES[0], "blue_ball": rigid(0.0, [0.0, 0.0, 0.05])}]
"""Object transforms of the frames: two moves of the bunny, one by 2 mm (a volume snapped to
its cells stays), and one that moves a real shape too (methods keeping real-only solutions
prepare again)."""


@pytest.fixture(scope="module")
def demo():
    """The demo scene at 80×60 (the bunny is a mesh; a box, a sphere and a rectangle are
    real)."""
    return load_scene(DEMO_DIR / "scene.toml").resized(80, 60)


@pytest.fixture(scope="module")
def nearfield_light(tmp_path_factory) -> str:
    """A NearFieldLight file for the demo: two VALs above the table (one of them close to the
    bunny, so its shadow maps see the occluder) and the bunny's SH block."""
    from arlight.nearfield.lightfile import save_light
    from arlight.nearfield.state import NearFieldLight

    sh = np.zeros((1, 9, 3))
    sh[0, 0] = 0.4
    sh[0, 1:4] = [[0.2, 0.1, 0.05], [0.1, 0.1, 0.1], [0.15, 0.05, 0.1]]  # not y-symmetric
    light = NearFieldLight(np.array([[0.0, 0.6, 0.0], [0.25, 0.3, 0.1]]),
                           np.array([[0.0, -1.0, 0.0], [-0.6, -0.8, 0.0]]),
                           np.array([[3.0, 2.5, 2.0], [1.0, 1.0, 1.5]]),
                           np.array([0.01, 0.004]), sh)
    path = tmp_path_factory.mktemp("nearfield") / "vals.json"
    save_light(light, path)
    return str(path)


def options_for(method: str, request) -> dict:
    """:data:`SMALL`'s options of ``method`` (nearfield's with the light file)."""
    if method == "nearfield":
        return {**SMALL[method], "light": request.getfixturevalue("nearfield_light")}
    return SMALL[method]


def _equal(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k))
               for k in ("mixed", "delta", "mask", "composite"))


def _hits(views, scene) -> dict[str, np.ndarray]:
    """Distance, shape index and normal of one ray per pixel in both views."""
    cam = scene.camera
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    o, d = cam.pixel_rays(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1))
    return view_hits(views, mi.Ray3f(mi.Point3f(*(o.T.astype(np.float32))),
                                     mi.Vector3f(*(d.T.astype(np.float32)))))


def view_hits(views, ray) -> dict[str, np.ndarray]:
    """Per ray: distance, normal and hit shape index in the real and the mixed view."""
    out = {}
    for name in ("real", "mixed"):
        view = getattr(views, name)
        si = view.scene.ray_intersect(ray)
        out[name] = np.concatenate([np.array(si.t)[:, None], np.array(si.n).T,
                                    np.array(view.hit_shape(si))[:, None]], axis=1)
    return out


@pytest.mark.parametrize("shape", ["bunny", "red_box", "blue_ball", "table"])
def test_placed_views_trace_what_a_fresh_build_traces(demo, shape):
    """Moving one shape in place (a mesh, Mitsuba's cube, a sphere, a rectangle) gives
    bitwise the hits of views built from the posed world, in both views. Rejects a place
    that moves only the mixed view's copy of a real shape, transforms mesh normals wrongly,
    or leaves the acceleration structure stale."""
    views = build_views(demo.world)
    rest = _hits(views, demo)
    posed = demo.world.posed({shape: MOVES[0]})
    assert views.place(posed.shapes) == {
        i for i, s in enumerate(demo.world.shapes) if s.name == shape}
    moved = _hits(views, demo)
    fresh = _hits(build_views(posed), demo)
    for name in ("real", "mixed"):
        assert np.array_equal(moved[name], fresh[name], equal_nan=True)
    assert not np.array_equal(moved["mixed"], rest["mixed"], equal_nan=True)
    views.place(demo.world.shapes)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in
               zip(_hits(views, demo).values(), rest.values(), strict=True))


def test_place_refuses_what_is_not_a_pose(demo):
    """Another shape list (here one shape fewer) is no re-posing: a ValueError, the views
    untouched. Rejects a place that silently skips the difference."""
    views = build_views(demo.world)
    with pytest.raises(ValueError):
        views.place(demo.world.shapes[:-1])
    other = World(shapes=[replace(s, params={**s.params}) for s in demo.world.shapes],
                  lights=demo.world.lights)
    with pytest.raises(ValueError):
        views.place(other.posed({"bunny": MOVES[0]}).shapes)


@pytest.mark.parametrize("method", ["dir", "dlpv", "dvct", "ibl", "prt", "onepass",
                                    "reference", "probeless", "nearfield"])
def test_incremental_pose_equals_a_fresh_preparation(demo, method, request):
    """For each of two rigid moves of the virtual bunny, the frame rendered from the one
    prepared state equals bitwise the frame of ``prepare(world.posed(T))``; afterwards the
    rest pose renders bitwise as before the moves. Rejects a pose that forgets to move the
    Mitsuba shape, a cache of the object (occlusion field, transfer, voxels) or the bounds,
    and a state left in the last pose when the view moves nothing (nearfield: the virtual
    occluder scene, the rotation of the PRT transfer, the bounding sphere of the shadow maps
    and the cached maps; probeless: the views)."""
    m = get_method(method)
    s = RenderSettings(spp=1, options=options_for(method, request))
    state = m.prepare(demo.world, s)
    rest = m.render(state, demo.view, s)
    for transforms in POSES:
        view = replace(demo.view, object_transforms=transforms)
        posed = m.render(state, view, s)
        fresh = m.render(m.prepare(demo.world.posed(transforms), s), demo.view, s)
        assert _equal(posed, fresh)
        assert not _equal(posed, rest)
    assert _equal(m.render(state, demo.view, s), rest)


def test_dlpv_pose_keeps_the_proxy_maps_that_do_not_depend_on_the_volume(demo):
    """A 2 mm move keeps the snapped volume and every light's ``R_µ``; a move that shifts the
    volume keeps the non-directional lights' maps and casts the directional ones again.
    Rejects a pose that recasts the proxy's RSMs every frame, or keeps a directional map
    that no longer covers the volume."""
    m = get_method("dlpv")
    s = RenderSettings(options=SMALL["dlpv"])
    state = m.prepare(demo.world, s)
    rest = state.data.real_maps
    small = m.pose(state, {"bunny": rigid(0.0, [0.002, 0.0, 0.0])}, s)
    assert small.grid.origin.tolist() == state.data.grid.origin.tolist()
    assert all(a is b for a, b in zip(small.real_maps.mu, rest.mu, strict=True))
    far = m.pose(state, {"bunny": MOVES[0]}, s)
    kinds = [lt.kind for lt in state.data.lights.lights]
    assert "directional" in kinds and set(kinds) != {"directional"}
    for kind, a, b in zip(kinds, far.real_maps.mu, rest.mu, strict=True):
        assert (a is b) == (kind != "directional")


def test_a_still_frame_poses_nothing(demo):
    """The same transforms again return the last posed data as it is; other transforms move
    it. Rejects a pose that re-does its work on every still frame, or one that keys the
    shortcut on the transforms' identity instead of their values."""
    m = get_method("dir")
    s = RenderSettings(options=SMALL["dir"])
    state = m.prepare(demo.world, s)
    first = m.pose(state, {"bunny": MOVES[0].copy()}, s)
    assert m.pose(state, {"bunny": MOVES[0].copy()}, s) is first
    other = m.pose(state, {"bunny": MOVES[1]}, s)
    assert other is not first and other.world.shapes[3].to_world[0, 3] != \
        first.world.shapes[3].to_world[0, 3]


@pytest.mark.parametrize("method", ["ibl", "prt"])
def test_two_virtual_shapes_pose_like_a_fresh_preparation(demo, method):
    """With the red box virtual too, ``ibl``'s occlusion field covers two shapes and is
    sampled in world space (again per pose), and ``prt`` has a virtual primitive (prepared
    again per pose); both still render bitwise what preparing the posed world renders.
    Rejects an object-space field used for several shapes (the box would not move with the
    bunny's frame) and a prt pose that keeps a primitive's read-back mesh."""
    shapes = [replace(s, role="virtual") if s.name == "red_box" else s
              for s in demo.world.shapes]
    world = replace(demo.world, shapes=shapes)
    m = get_method(method)
    s = RenderSettings(spp=1, options=SMALL[method])
    state = m.prepare(world, s)
    rest = m.render(state, demo.view, s)
    transforms = {"bunny": MOVES[0]}
    posed = m.render(state, replace(demo.view, object_transforms=transforms), s)
    fresh = m.render(m.prepare(world.posed(transforms), s), demo.view, s)
    assert _equal(posed, fresh)
    assert not _equal(posed, rest)
    assert _equal(m.render(state, demo.view, s), rest)


@pytest.mark.parametrize("method", ["ibl"])
def test_a_world_space_field_is_sampled_again_only_when_a_virtual_shape_moves(demo, method):
    """With two virtual shapes the occlusion field is in world space: a pose that leaves
    the virtual shapes where they are keeps the very field (sampling it again took about
    1 s on the first frame of a fresh state); one that moves the bunny samples a new field.
    Rejects a pose that samples the field again whatever moved, and one that keeps it
    when a virtual shape moved. (prt shares ``pose_field``; its pose prepares again when a
    virtual primitive, the box here, is in the world.)"""
    import importlib

    shapes = [replace(s, role="virtual") if s.name == "red_box" else s
              for s in demo.world.shapes]
    world = replace(demo.world, shapes=shapes)
    m = get_method(method)
    s = RenderSettings(spp=1, options=SMALL[method])
    data = m.prepare(world, s).data
    assert data.field is not None and data.field.frame is None
    pose = importlib.import_module(f"arlight.methods.{method}").pose
    options = m.options(s)
    assert pose(data, world, {}, options).field is data.field
    assert pose(data, world, {"bunny": MOVES[0]}, options).field is not data.field


def test_nearfield_moves_skewed_and_primitive_objects_in_place(demo, tmp_path):
    """nearfield traces its virtual objects in object space (``backend.object_space``):
    a pose with non-uniform scale of the bunny and a move of a virtual box (a primitive)
    are done in place — the proxy scene and the real view are kept — and render bitwise
    what preparing the posed world renders; the rest pose renders as before. Rejects a move
    that reads a primitive's object mesh from its posed vertices, an occluder left at the
    old frame for the second object, and a sphere that misses the stretch."""
    from arlight.nearfield.lightfile import save_light
    from arlight.nearfield.state import NearFieldLight

    shapes = [replace(s, role="virtual") if s.name == "red_box" else s
              for s in demo.world.shapes]
    world = replace(demo.world, shapes=shapes)
    sh = np.zeros((2, 9, 3))
    sh[:, 0] = 0.4
    sh[0, 1:4] = [[0.2, 0.1, 0.05], [0.1, 0.1, 0.1], [0.15, 0.05, 0.1]]
    path = tmp_path / "vals.json"
    save_light(NearFieldLight(np.array([[0.0, 0.6, 0.0], [0.25, 0.3, 0.1]]),
                              np.array([[0.0, -1.0, 0.0], [-0.6, -0.8, 0.0]]),
                              np.array([[3.0, 2.5, 2.0], [1.0, 1.0, 1.5]]),
                              np.array([0.01, 0.004]), sh), path)
    m = get_method("nearfield")
    s = RenderSettings(spp=1, options={**SMALL["nearfield"], "light": str(path)})
    state = m.prepare(world, s)
    rest = m.render(state, demo.view, s)
    skew = rigid(35.0, [0.02, 0.0, -0.01]) @ np.diag([1.3, 0.8, 1.1, 1.0])
    for transforms in ({"bunny": skew}, {"bunny": MOVES[1], "red_box": MOVES[0]}):
        posed = m.render(state, replace(demo.view, object_transforms=transforms), s)
        assert state.last.proxy is state.data.proxy  # moved in place, not prepared again
        assert state.last.views.real is state.data.views.real
        fresh = m.render(m.prepare(world.posed(transforms), s), demo.view, s)
        assert _equal(posed, fresh)
        assert not _equal(posed, rest)
    assert _equal(m.render(state, demo.view, s), rest)
