"""Batched ray queries against a scene view, NumPy in and out.

For methods written in NumPy (irradiance caches, photon maps, volumes) that need visibility
and hit points without writing Dr.Jit code.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView


@dataclass
class RayHits:
    """Results of :func:`intersect` for N rays.

    Attributes:
        t: hit distance ``(N,)`` in metres, ``inf`` on a miss.
        position: world hit points ``(N, 3)`` (undefined on a miss).
        normal: shading normals ``(N, 3)``, facing where the shape's normal faces.
        role: ``(N,)`` int8: −1 miss, 0 real, 1 virtual.
        shape: ``(N,)`` int32 index into ``ARScene.shapes`` (−1 miss, −2 area-light geometry).
        material: ``(N,)`` int32 index of the hit shape's material in
            :func:`material_table` order (−1 when the hit is not one of our shapes).
    """

    t: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    role: np.ndarray
    shape: np.ndarray
    material: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.t)


def material_table(shapes) -> tuple[list[str], np.ndarray]:
    """Unique material names and, per shape, the index of its material."""
    names: list[str] = []
    per_shape = []
    for s in shapes:
        if s.material.name not in names:
            names.append(s.material.name)
        per_shape.append(names.index(s.material.name))
    return names, np.asarray(per_shape, dtype=np.int32)


def np3(v) -> np.ndarray:
    """A Dr.Jit 3-vector array (Point3f, Vector3f, Color3f) as NumPy ``(N, 3)`` float64."""
    return np.stack([np.asarray(c, np.float64) for c in (v.x, v.y, v.z)], 1)


def _vec(a: np.ndarray) -> list[np.ndarray]:
    a = np.ascontiguousarray(a, dtype=np.float32)
    return [a[:, 0], a[:, 1], a[:, 2]]


def intersect(view: SceneView, origins: np.ndarray, directions: np.ndarray,
              shapes=None, t_max: float | np.ndarray = np.inf) -> RayHits:
    """Closest hits of rays ``origins + t · directions`` (``(N, 3)`` each, directions unit).

    Args:
        view: ``views.real`` (virtual objects ignored) or ``views.mixed``.
        shapes: the scene's shapes, to report material indices (optional).
        t_max: maximal distance (scalar or ``(N,)``).
    """
    n = len(origins)
    ray = mi.Ray3f(mi.Point3f(*_vec(origins)), mi.Vector3f(*_vec(directions)))
    if np.ndim(t_max) or np.isfinite(t_max):
        ray.maxt = mi.Float(np.broadcast_to(np.asarray(t_max, np.float32), (n,)).copy())
    si = view.scene.ray_intersect(ray)
    role = view.hit_role(si)
    shape = view.hit_shape(si)
    dr.eval(si.t, si.p, si.sh_frame.n, role, shape)
    t = np.array(si.t, dtype=np.float64)
    t[~np.isfinite(t)] = np.inf
    shape_np = np.array(shape, dtype=np.int32)
    material = np.full(n, -1, dtype=np.int32)
    if shapes is not None:
        _, per_shape = material_table(shapes)
        ok = shape_np >= 0
        material[ok] = per_shape[shape_np[ok]]
    return RayHits(t=t, position=np.array(si.p, dtype=np.float64).T,
                   normal=np.array(si.sh_frame.n, dtype=np.float64).T,
                   role=np.array(role, dtype=np.int8), shape=shape_np, material=material)


def visible(view: SceneView, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mutual visibility of point pairs ``a[i]``–``b[i]`` (``(N, 3)``) in ``view``; bool."""
    d = np.asarray(b, np.float64) - np.asarray(a, np.float64)
    dist = np.linalg.norm(d, axis=1)
    dirs = d / np.maximum(dist, 1e-12)[:, None]
    ray = mi.Ray3f(mi.Point3f(*_vec(a)), mi.Vector3f(*_vec(dirs)))
    ray.maxt = mi.Float((dist * (1 - 1e-4)).astype(np.float32))
    occluded = view.scene.ray_test(ray)
    return ~np.array(occluded, dtype=bool)
