"""The nearfield client's shadow maps (``arlight.nearfield.shading.shadow_maps``, traced in
one Dr.Jit pass since issue #32) against an independent per-texel ray cast in NumPy."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.object_space import ObjectSpaceScene
from arlight.methods import get_method
from arlight.methods.nearfield import prepare
from arlight.nearfield.shading import frusta, shadow_maps
from arlight.nearfield.state import NearFieldLight
from arlight.realtime.oof import virtual_scene
from tests.nearfield.conftest import room, vbox, world

SLAB = [{"name": "slab", "role": "real", "type": "box", "size": [0.6, 0.05, 0.3],
         "transform": {"translate": [0.2, 0.8, 0.1]},
         "material": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}]
# long in x, short in z (a map with u and v swapped differs), scaled and turned (a
# similarity: the occluder is traced in the bar's own frame)
BAR = {**vbox("bar", size=(0.25, 0.04, 0.06)),
       "transform": {"scale": 2.0, "rotate": [0.0, 1.0, 0.0, 20.0],
                     "translate": [0.1, 0.5, 0.0]}}


def _expected(light: NearFieldLight, scene, sphere, size: int) -> np.ndarray:
    """Depth per texel by the definition (float64 directions, one VAL at a time):
    texel ``(r, c)`` looks along ``a + tan_half (g_c u + g_r v)``."""
    fr = frusta(light, sphere)
    g = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    out = np.full((light.count, size, size), np.inf)
    for j in range(light.count):
        if fr.tan_half[j] <= 0:
            continue
        gr, gc = np.meshgrid(g, g, indexing="ij")
        w = (fr.axis[j] + fr.tan_half[j] * (gc[..., None] * fr.u[j] + gr[..., None]
                                            * fr.v[j])).reshape(-1, 3)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        o = np.broadcast_to(fr.origin[j], w.shape).astype(np.float32)
        d = w.astype(np.float32)
        pi = scene.ray_intersect_preliminary(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)))
        t = np.asarray(dr.select(pi.is_valid(), pi.t, dr.inf), np.float64)
        out[j] = t.reshape(size, size)
    return out.reshape(-1)


def test_maps_match_a_per_texel_ray_cast():
    """Both maps of three VALs (one of them inside the bounding sphere: no frustum, all
    ``inf``) equal a per-VAL NumPy ray cast to float32 precision, the virtual map traced
    through the object-space occluder against the bar loaded in world space. Wrong
    implementations it rejects: rows and columns swapped (u ↔ v), a lane read with another
    VAL's frame, the real and virtual scenes swapped, an object-space hit distance not in
    the world ray's units (a renormalised local direction, on a scaled object)."""
    w = world(room(virtual=[BAR], extra=SLAB))
    opts = get_method("nearfield").spec.parse_options({"light": "x.json"})
    sh = np.zeros((1, 9, 3))
    light = NearFieldLight(np.array([[0.0, 1.99, 0.0], [-0.9, 1.2, 0.3], [0.1, 0.5, 0.0]]),
                           np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                           np.ones((3, 3)), np.full(3, 0.01), sh)
    data = prepare(w, opts, light)
    size = 24
    maps = shadow_maps(light, data.proxy, data.occluder, data.sphere, size)
    assert maps.tan_half[2] == 0 and np.all(maps.tan_half[:2] > 0)
    assert isinstance(data.occluder, ObjectSpaceScene)  # traced in the bar's own frame
    # the references: the proxy, and the bar loaded in world space
    for got, scene in ((maps.real, data.proxy), (maps.virtual, virtual_scene(w))):
        got = np.asarray(got, np.float64)
        want = _expected(light, scene, data.sphere, size)
        fin = np.isfinite(want)
        assert np.isfinite(got).sum() > 0.1 * fin.size  # both maps see something
        assert np.mean(np.isfinite(got) != fin) < 0.01  # silhouettes may flip in float32
        both = fin & np.isfinite(got)
        assert np.allclose(got[both], want[both], rtol=1e-4, atol=1e-5)
        assert np.all(np.isinf(got.reshape(3, -1)[2]))


def test_object_space_sphere_holds_the_posed_object():
    """The bounding sphere of an object-space occluder (``ObjectSpaceScene.bounding_sphere``)
    contains every vertex of the scaled, turned bar in world space and is no larger than
    the sphere around its world-space bounding box. Wrong implementations it rejects: the
    radius without the pose's scale (vertices outside), the centre left in object space,
    the scale applied twice (larger than the world box's sphere)."""
    from arlight.nearfield.pipeline import virtual_objects

    w = world(room(virtual=[BAR]))
    opts = get_method("nearfield").spec.parse_options({"light": "x.json"})
    data = prepare(w, opts, NearFieldLight(np.zeros((0, 3)), np.zeros((0, 3)),
                                           np.zeros((0, 3)), np.zeros(0), np.zeros((1, 9, 3))))
    c, r = data.sphere
    v = virtual_objects(w)[0].vertices
    assert np.all(np.linalg.norm(v - c, axis=1) <= r * (1 + 1e-6))
    b = virtual_scene(w).bbox()
    lo, hi = np.array([b.min.x, b.min.y, b.min.z]), np.array([b.max.x, b.max.y, b.max.z])
    assert r <= np.linalg.norm(hi - lo) / 2 * (1 + 1e-6)
