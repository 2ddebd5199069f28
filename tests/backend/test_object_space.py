"""Virtual objects traced in object space (``arlight.backend.object_space``, issue #32)
against the same scene built with the objects in world space (``build_views``).

Each test names the wrong implementation it rejects."""

from __future__ import annotations

from dataclasses import replace

import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.mitsuba_scene import ROLE_VIRTUAL, build_views
from arlight.backend.object_space import ObjectSpaceScene, build_split_views
from arlight.demo import DEMO_DIR
from arlight.methods.base import relight_views
from arlight.realtime.gbuffer import render_gbuffer, surface_albedo
from arlight.scene.load import load_scene


@pytest.fixture(scope="module")
def demo():
    """The demo scene at 160×120 (the bunny is a virtual mesh)."""
    return load_scene(DEMO_DIR / "scene.toml").resized(160, 120)


def skewed(world, name: str) -> np.ndarray:
    """A pose of shape ``name`` about its own origin: non-uniform scale (1.6, 0.7, 1.2),
    then a 35° turn about +y, then a 2 cm shift (4×4, applied on the left)."""
    c = np.asarray(next(s for s in world.shapes if s.name == name).to_world)[:3, 3]
    a = np.radians(35.0)
    r = np.eye(4)
    r[[0, 0, 2, 2], [0, 2, 0, 2]] = [np.cos(a), np.sin(a), -np.sin(a), np.cos(a)]
    to, back = np.eye(4), np.eye(4)
    to[:3, 3], back[:3, 3] = -c, c + [0.02, 0.0, -0.01]
    return back @ r @ np.diag([1.6, 0.7, 1.2, 1.0]) @ to


def pixel_rays(scene) -> mi.Ray3f:
    cam = scene.camera
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    o, d = cam.pixel_rays(np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1))
    return mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))


def np3(v) -> np.ndarray:
    return np.array(v, np.float64).T


def test_split_view_hits_equal_a_world_space_scene(demo):
    """Under a turn with non-uniform scale, every primary ray's hit in the split mixed view
    matches the world-space mixed view: the same shape and role (the bunny covers hundreds
    of pixels), ``t`` and ``p`` to float32 precision, the geometric normal to 1e-5 (both
    are the normal of the same triangle), the primitive index and barycentrics of the
    preliminary hit, the diffuse albedo (``si.bsdf()`` of the object-space shape), and a
    shading frame that is orthonormal with ``wi`` the reversed ray. Rejects normals taken
    through the pose instead of its inverse transpose (the bunny's normals tilt by up to
    ~30° here), a local ray whose direction is renormalised (``t`` in object units), hits
    left in object space (``p``), a merge that keeps the farther hit, and a role table
    without the object's registry id."""
    world = demo.world.posed({"bunny": skewed(demo.world, "bunny")})
    ref, split = build_views(world), build_split_views(world)
    ray = pixel_rays(demo)
    a, b = ref.mixed.scene.ray_intersect(ray), split.mixed.scene.ray_intersect(ray)
    sa, sb = np.array(ref.mixed.hit_shape(a)), np.array(split.mixed.hit_shape(b))
    ra, rb = np.array(ref.mixed.hit_role(a)), np.array(split.mixed.hit_role(b))
    assert np.mean(sa != sb) < 0.002 and np.mean(ra != rb) < 0.002
    assert np.array_equal(rb == ROLE_VIRTUAL, sb == 3)
    bunny = (sa == 3) & (sb == 3)
    same = (sa == sb) & (sa >= 0)
    assert bunny.sum() > 300
    assert np.allclose(np.array(b.t)[same], np.array(a.t)[same], rtol=2e-6)
    assert np.allclose(np3(b.p)[same], np3(a.p)[same], atol=1e-5)
    na, nb = np3(a.n)[bunny], np3(b.n)[bunny]
    assert np.min(np.sum(na * nb, axis=1)) > 1 - 1e-5
    pa = ref.mixed.scene.ray_intersect_preliminary(ray)
    pb = split.mixed.scene.ray_intersect_preliminary(ray)
    assert np.array_equal(np.array(pa.prim_index)[same], np.array(pb.prim_index)[same])
    assert np.allclose(np3(pa.prim_uv)[bunny], np3(pb.prim_uv)[bunny], atol=2e-3)  # tiny
    # triangles: float32 barycentrics
    assert np.array_equal(np.array(pb.t), np.array(b.t))
    alb_a = np3(surface_albedo(a, a.is_valid()))[same]
    alb_b = np3(surface_albedo(b, b.is_valid()))[same]
    assert np.allclose(alb_a, alb_b, atol=1e-6)
    frame = b.sh_frame
    n, s, t = np3(frame.n)[bunny], np3(frame.s)[bunny], np3(frame.t)[bunny]
    for u, v in ((n, s), (n, t), (s, t)):
        assert np.max(np.abs(np.sum(u * v, axis=1))) < 1e-4
    d = np3(ray.d)[bunny]
    back = np3(b.to_world(b.wi))[bunny]
    assert np.allclose(back, -d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-4)
    # shading normals: the world scene's are recomputed from the scaled mesh, ours are the
    # object's through the inverse transpose; they agree where the surface is smooth
    ca = np.sum(np3(a.sh_frame.n)[bunny] * np3(frame.n)[bunny], axis=1)
    assert np.median(ca) > 0.9999


def test_split_view_shadow_queries_and_bounds(demo):
    """``ray_test`` and the G-buffer through a split view agree with the world-space view,
    and the bounding sphere of the posed objects holds every posed vertex. Rejects a
    ``ray_test`` that ignores ``maxt`` or the objects, and a sphere whose radius misses the
    pose's largest stretch."""
    world = demo.world.posed({"bunny": skewed(demo.world, "bunny")})
    ref, split = build_views(world), build_split_views(world)
    ray = pixel_rays(demo)
    si = ref.mixed.scene.ray_intersect(ray)
    real = np.array(ref.mixed.hit_role(si)) == 0
    origin = np3(si.p)[real] + 1e-3 * np3(si.n)[real]
    bunny = next(s for s in world.shapes if s.name == "bunny")
    target = np.asarray(bunny.to_world)[:3, 3] + [0.05, 0.6, 0.02]
    shadow = mi.Ray3f(mi.Point3f(*origin.T.astype(np.float32)),
                      mi.Vector3f(*(target - origin).T.astype(np.float32)))
    shadow.maxt = 1.0  # the segment to the target (direction not normalised)
    want = np.array(ref.mixed.scene.ray_test(shadow))
    got = np.array(split.mixed.scene.ray_test(shadow))
    assert np.mean(want != got) < 0.002 and 100 < got.sum() < 0.9 * got.size
    shadow.maxt = 0.02  # stops short of everything but nearby real walls
    assert np.mean(np.array(split.mixed.scene.ray_test(shadow))
                   != np.array(ref.mixed.scene.ray_test(shadow))) < 0.002
    ga, gb = render_gbuffer(ref.mixed, demo.camera), render_gbuffer(split.mixed, demo.camera)
    assert np.mean(np.array(ga.role) != np.array(gb.role)) < 0.002
    occ = ObjectSpaceScene(None, split.mixed.scene.objects)
    c, r = occ.bounding_sphere()
    mesh = next(s for s in world.shapes if s.name == "bunny")
    m = np.asarray(mesh.to_world)
    v = np.asarray(mesh.mesh.vertices, np.float64) @ m[:3, :3].T + m[:3, 3]
    assert np.all(np.linalg.norm(v - c, axis=1) <= r * (1 + 1e-6))
    assert r < 1.01 * np.linalg.norm(v.max(0) - v.min(0))


def test_place_reposes_objects_without_loading(demo):
    """Moving the bunny through ``SceneViews.place`` swaps its frame only: the real scene
    and the object's loaded scene stay the same objects, and the split view then traces
    bitwise what split views built from the posed world trace; the generation changes.
    Rejects a place that forgets the split view, re-poses the wrong object, or rebuilds."""
    views = build_split_views(demo.world)
    real, obj_scene = views.real.scene, views.mixed.scene.objects[0].scene
    gen = views.mixed.generation
    posed = demo.world.posed({"bunny": skewed(demo.world, "bunny")})
    assert views.place(posed.shapes) == {3}
    assert views.real.scene is real and views.mixed.scene.real is real
    assert views.mixed.scene.objects[0].scene is obj_scene
    assert views.mixed.generation != gen
    ray = pixel_rays(demo)
    fresh = build_split_views(posed)
    for field in ("t", "n", "p"):
        got = np3(getattr(views.mixed.scene.ray_intersect(ray), field))
        want = np3(getattr(fresh.mixed.scene.ray_intersect(ray), field))
        assert np.array_equal(got, want, equal_nan=True)


def test_relit_lamp_reaches_the_split_view_once(demo):
    """``relight_views`` on split views updates the real view's scene, which the split view
    shares (one update, a new generation on both). Rejects a split view that keeps its own
    stale copy of the emitters or is skipped."""
    views = build_split_views(demo.world)
    lights = [replace(lt, params={**lt.params, "radiance": [2.0 * c for c in
                                                            lt.params["radiance"]]})
              if lt.type == "area" else lt for lt in demo.world.lights]
    gens = views.real.generation, views.mixed.generation
    assert relight_views(views, demo.world.lights, lights)
    assert views.real.generation != gens[0] and views.mixed.generation != gens[1]
    fresh = build_views(replace(demo.world, lights=lights))
    key = next(k for k in fresh.real.params.keys() if k.endswith("radiance.value"))
    assert np.array_equal(np.array(views.mixed.params[key]), np.array(fresh.real.params[key]))


@pytest.mark.parametrize("name", ["red_box", "blue_ball", "table"])
def test_primitives_in_object_space(demo, name):
    """A Mitsuba primitive made virtual next to the bunny (two objects: a cube mesh, an
    analytic sphere under a similarity — Mitsuba's world-space sphere takes no non-uniform
    scale — or a rectangle, stretched) traces like the world-space view: the same shapes,
    ``t``, ``p`` and geometric normals. Rejects a surface interaction computed from the
    world ray instead of the object-space one (analytic shapes place ``p`` along the ray),
    and a merge of several objects that keeps the last one tested."""
    shapes = [replace(s, role="virtual") if s.name == name else s for s in demo.world.shapes]
    world = replace(demo.world, shapes=shapes)
    index = next(i for i, s in enumerate(shapes) if s.name == name)
    pose = skewed(world, name)
    if name == "blue_ball":  # a turn and a uniform scale about the ball's centre
        c = np.asarray(shapes[index].to_world)[:3, 3]
        pose = np.eye(4)
        pose[:3, :3] = 1.3 * skewed(world, "bunny")[:3, :3] @ np.diag([1 / 1.6, 1 / 0.7,
                                                                        1 / 1.2])
        pose[:3, 3] = c - pose[:3, :3] @ c + [0.01, 0.0, 0.0]
    world = world.posed({name: pose, "bunny": skewed(world, "bunny")})
    ref, split = build_views(world), build_split_views(world)
    ray = pixel_rays(demo)
    a, b = ref.mixed.scene.ray_intersect(ray), split.mixed.scene.ray_intersect(ray)
    sa, sb = np.array(ref.mixed.hit_shape(a)), np.array(split.mixed.hit_shape(b))
    assert np.mean(sa != sb) < 0.003 and np.sum(sb == index) > 200
    same = (sa == sb) & (sa >= 0)
    assert np.allclose(np.array(b.t)[same], np.array(a.t)[same], rtol=1e-5)
    assert np.allclose(np3(b.p)[same], np3(a.p)[same], atol=1e-5)
    hit = same & (sa == index)
    assert np.min(np.sum(np3(a.n)[hit] * np3(b.n)[hit], axis=1)) > 1 - 1e-5
