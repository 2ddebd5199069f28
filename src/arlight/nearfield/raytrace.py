"""Batched ray queries of the near-field pipeline, NumPy in and out (Dr.Jit / Mitsuba).

The proxy is traced as one triangle mesh (:class:`~arlight.nearfield.atlas.ProxyMesh`), so a
hit's ``prim_index`` is the proxy face, which maps the hit into the atlas.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import aligned, columns, ensure_variant

EPS = 1e-4
"""Ray offset, m: origins leave surfaces and segments stop this short of their end."""


def mesh_scene(meshes: list[tuple[np.ndarray, np.ndarray]]) -> mi.Scene:
    """A Mitsuba scene of world-space triangle meshes ``[(vertices (V, 3), faces (F, 3))]``;
    mesh ``k`` has id ``"m<k>"`` (shape order of :meth:`mi.Scene.shapes` is not relied on)."""
    ensure_variant()
    objs: dict = {"type": "scene"}
    for k, (v, f) in enumerate(meshes):
        m = mi.Mesh(f"m{k}", len(v), len(f))
        p = mi.traverse(m)
        p["vertex_positions"] = mi.Float(np.asarray(v, np.float32).reshape(-1))
        p["faces"] = mi.UInt32(np.asarray(f, np.uint32).reshape(-1))
        p.update()
        objs[f"m{k}"] = m
    return mi.load_dict(objs)


def _rays(o: np.ndarray, d: np.ndarray, tmax: np.ndarray | None = None) -> mi.Ray3f:
    # aligned columns: a strided view's alignment varies per call and is part of the
    # kernel's code, so it recompiled every frame (tests/methods/test_kernel_reuse.py)
    ray = mi.Ray3f(mi.Point3f(*columns(o, np.float32)), mi.Vector3f(*columns(d, np.float32)))
    if tmax is not None:
        ray.maxt = mi.Float(aligned(tmax, np.float32))
    return ray


def segment_visible(scene: mi.Scene | None, a: np.ndarray, b: np.ndarray,
                    eps: float = EPS) -> np.ndarray:
    """(N,) bool: nothing of ``scene`` lies on the segments ``a[i]``–``b[i]`` (shortened by
    ``eps`` at both ends); all True for ``scene=None``."""
    a = np.asarray(a, np.float64)
    d = np.asarray(b, np.float64) - a
    dist = np.linalg.norm(d, axis=1)
    if scene is None or len(a) == 0:
        return np.ones(len(a), bool)
    u = d / np.maximum(dist, 1e-30)[:, None]
    ray = _rays(a + u * eps, u, np.maximum(dist - 2 * eps, 0.0))
    occ = scene.ray_test(ray)
    return ~np.asarray(occ, bool)


def first_hits(scene: mi.Scene, o: np.ndarray, d: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest hits: ``t`` (inf on a miss), ``prim`` index, barycentrics ``(N, 2)`` and the
    hit mesh id number ``k`` of ``"m<k>"`` (−1 on a miss)."""
    ray = _rays(o, d)
    pi = scene.ray_intersect_preliminary(ray)
    valid = pi.is_valid()
    ids = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0]): int(s.id()[1:])
           for s in scene.shapes()}
    table = np.full(max(ids) + 1, -1, np.int64)
    for reg, k in ids.items():
        table[reg] = k
    reg = dr.reinterpret_array(mi.UInt32, pi.shape)
    dr.eval(pi.t, pi.prim_index, pi.prim_uv, valid, reg)
    ok = np.asarray(valid, bool)
    t = np.where(ok, np.asarray(pi.t, np.float64), np.inf)
    prim = np.asarray(pi.prim_index, np.int64)
    uv = np.stack([np.asarray(pi.prim_uv.x), np.asarray(pi.prim_uv.y)], 1).astype(np.float64)
    r = np.asarray(reg, np.int64)
    mesh = np.where(ok, table[np.clip(r, 0, len(table) - 1)], -1)
    return t, prim, uv, mesh


__all__ = ["EPS", "first_hits", "mesh_scene", "segment_visible"]
