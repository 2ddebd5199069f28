"""The nearfield client's shadow maps (``arlight.nearfield.shading.shadow_maps``, traced in
one Dr.Jit pass since issue #32) against an independent per-texel ray cast in NumPy."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.methods import get_method
from arlight.methods.nearfield import prepare
from arlight.nearfield.shading import frusta, shadow_maps
from arlight.nearfield.state import NearFieldLight
from tests.nearfield.conftest import room, vbox, world

SLAB = [{"name": "slab", "role": "real", "type": "box", "size": [0.6, 0.05, 0.3],
         "transform": {"translate": [0.2, 0.8, 0.1]},
         "material": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}}]
# long in x, short in z: a map with u and v (rows and columns) swapped differs
BAR = vbox("bar", at=(0.1, 0.5, 0.0), size=(0.5, 0.08, 0.12))


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
    ``inf``) equal a per-VAL NumPy ray cast to float32 precision. Wrong implementations it
    rejects: rows and columns swapped (u ↔ v), a lane read with another VAL's frame, the
    real and virtual scenes swapped."""
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
    for got, scene in ((maps.real, data.proxy), (maps.virtual, data.occluder)):
        got = np.asarray(got, np.float64)
        want = _expected(light, scene, data.sphere, size)
        fin = np.isfinite(want)
        assert np.isfinite(got).sum() > 0.1 * fin.size  # both maps see something
        assert np.mean(np.isfinite(got) != fin) < 0.01  # silhouettes may flip in float32
        both = fin & np.isfinite(got)
        assert np.allclose(got[both], want[both], rtol=1e-4, atol=1e-5)
        assert np.all(np.isinf(got.reshape(3, -1)[2]))
