"""Noise-free auxiliary buffers for the denoiser: first-hit albedo and normal.

    aux = aux_buffers(view, camera, samples=4)      # AuxBuffers(albedo, normal)

A camera-ray pass through the Mitsuba scene of the *mixed* view (real proxy plus virtual
objects; :class:`~arlight.backend.mitsuba_scene.SceneView`), independent of the tracers:
``samples`` stratified sub-pixel positions (the multi-jittered camera of
:func:`arlight.backend.camera_rays.generate_rays` at a fixed seed; on a thin-lens camera
``max(samples, 16)`` so that the lens is covered too) are box-filtered per pixel, so the
buffers are anti-aliased like the render and carry no Monte Carlo noise of their own apart
from the edge coverage.

At a purely specular surface (a mirror, smooth glass: every BSDF lobe a delta) the ray
follows the specular direction of a fixed sample (the transmitted one through glass unless
it is totally reflected) and the buffers take the first non-specular hit, its albedo
multiplied by the specular weights on the way — what Cycles and the OIDN documentation do
for perfect specular surfaces. At most :data:`MAX_SPECULAR` specular bounces are followed
(then albedo and normal stay 0).

Albedo: Mitsuba's ``eval_diffuse_reflectance`` (π·f(wi, n) at the hit; the diffuse
reflectance of diffuse and Phong surfaces, the normal-incidence lobe of rough conductors),
clamped to [0, 1]. Normal: the world-space shading normal, in [-1, 1] (averaged over the
samples, not renormalised). Misses (the environment): albedo 0, normal 0.

Between frames (the studio, sequences) :class:`AuxCache` reuses the buffers while nothing
they depend on changed: the same Mitsuba scene object, the same camera (all but its
transfer function), the same object transforms and sample count (``AUX_CACHE``, used by
:meth:`arlight.methods.base.BaseMethod.denoise`).
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays
from arlight.backend.mitsuba_scene import SceneView
from arlight.jit import MAX_LANES, ensure_variant
from arlight.scene.camera import Camera

MAX_SPECULAR = 4
"""Specular bounces followed before the buffers give up on a pixel."""
AUX_SEED = 0x5EED
"""Fixed seed of the sub-pixel positions (the buffers are the same for every render)."""


@dataclass(frozen=True)
class AuxBuffers:
    """``albedo`` in [0, 1] and world-space ``normal`` in [-1, 1], each ``(H, W, 3)``
    float32."""

    albedo: np.ndarray
    normal: np.ndarray

    def crop(self, rows: slice, cols: slice) -> AuxBuffers:
        return AuxBuffers(np.ascontiguousarray(self.albedo[rows, cols]),
                          np.ascontiguousarray(self.normal[rows, cols]))


def _first_diffuse_hit(view: SceneView, ray: mi.Ray3f) -> tuple[mi.Color3f, mi.Vector3f]:
    """Per-lane albedo and normal of the first non-specular hit along ``ray``."""
    scene = view.scene
    active = mi.Bool(True)
    weight = mi.Color3f(1.0)
    albedo = mi.Color3f(0.0)
    normal = mi.Vector3f(0.0)
    ctx = mi.BSDFContext()
    for bounce in range(MAX_SPECULAR + 1):
        si = scene.ray_intersect(ray, active)
        hit = active & si.is_valid()
        bsdf = si.bsdf()
        flags = bsdf.flags()
        specular = hit & ~mi.has_flag(flags, mi.BSDFFlags.Smooth)
        done = hit & ~specular
        refl = dr.clip(mi.Color3f(bsdf.eval_diffuse_reflectance(si, done)), 0.0, 1.0)
        albedo = dr.select(done, weight * refl, albedo)
        normal = dr.select(done, si.sh_frame.n, normal)
        if bounce == MAX_SPECULAR or not bool(dr.any(specular)):
            break  # (no specular hit left: one evaluation instead of MAX_SPECULAR launches)
        active = specular
        bs, w = bsdf.sample(ctx, si, mi.Float(0.999), mi.Point2f(0.5, 0.5), active)
        active &= bs.pdf > 0
        weight = dr.select(active, weight * mi.Color3f(w), weight)
        ray = dr.select(active, si.spawn_ray(si.to_world(bs.wo)), ray)
    return albedo, normal


def aux_buffers(view: SceneView, camera: Camera, samples: int = 4,
                rows: slice | None = None, cols: slice | None = None) -> AuxBuffers:
    """Box-filtered first-hit albedo and normal of ``camera``'s pixels in ``view``.

    Args:
        view: the mixed view's Mitsuba scene (virtual objects included).
        camera: the frame's camera (pinhole or thin lens).
        samples: sub-pixel positions per pixel (a perfect square is stratified;
            at least 16 on a thin-lens camera).
        rows, cols: a window of the image (default: all of it).

    Returns:
        :class:`AuxBuffers` of the window, ``(rows, cols, 3)``.
    """
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    ensure_variant()
    spp = max(samples, 16) if camera.aperture_radius > 0 else samples
    r0, r1, _ = (rows or slice(None)).indices(camera.height)
    c0, c1, _ = (cols or slice(None)).indices(camera.width)
    h, w = r1 - r0, c1 - c0
    pixels = h * w
    albedo = np.zeros((pixels, 3), np.float64)
    normal = np.zeros((pixels, 3), np.float64)
    step = max(1, MAX_LANES // spp)  # pixels per launch

    def u32(x: int) -> mi.UInt32:  # opaque: another window or launch reuses the kernels
        return dr.opaque(mi.UInt32, x)

    for p0 in range(0, pixels, step):
        n = min(step, pixels - p0)
        lane = dr.arange(mi.UInt32, n * spp)
        local = lane // u32(spp) + u32(p0)
        pixel = (local // u32(w) + u32(r0)) * u32(camera.width) + local % u32(w) + u32(c0)
        k = lane % u32(spp)
        rays = generate_rays(camera, pixel, k, spp, mi.UInt32(AUX_SEED))
        a, nrm = _first_diffuse_hit(view, mi.Ray3f(rays))
        a_np = np.asarray(a, np.float64).reshape(3, n, spp)  # Dr.Jit: channel-major
        n_np = np.asarray(nrm, np.float64).reshape(3, n, spp)
        albedo[p0:p0 + n] = a_np.mean(axis=2).T
        normal[p0:p0 + n] = n_np.mean(axis=2).T
    return AuxBuffers(albedo.reshape(h, w, 3).astype(np.float32),
                      normal.reshape(h, w, 3).astype(np.float32))


def camera_key(camera: Camera) -> tuple:
    """Everything of ``camera`` that the buffers depend on: resolution, intrinsics, pose,
    lens (not the transfer function: the buffers are not exposed)."""
    return (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
            np.asarray(camera.world_from_camera, np.float64).tobytes(),
            camera.aperture_radius, camera.focus_distance, camera.aperture_shape)


def transforms_key(transforms: dict[str, np.ndarray] | None) -> tuple:
    """The object transforms a view was posed with, as a hashable key (empty: rest pose)."""
    return tuple(sorted((name, np.asarray(m, np.float64).tobytes())
                        for name, m in (transforms or {}).items()))


class AuxCache:
    """The auxiliary buffers of recent frames, reused while nothing they depend on changed.

    An entry is keyed by the Mitsuba scene view and the world it was prepared for (by
    identity, held weakly: a view prepared again is a new object, a relit state —
    :meth:`arlight.methods.base.BaseMethod.relight` moves area lamps in place — has a new
    world, and a dead one never matches), :func:`camera_key`, :func:`transforms_key` (a view
    moved in place by an incremental pose is the same object in another pose) and the
    sample count. A window inside the cached one is a crop of it
    (bitwise what :func:`aux_buffers` of that window gives: every pixel is traced alone); a
    window reaching outside traces the union of both windows again. At most ``capacity``
    entries, least recently used dropped first.
    """

    def __init__(self, capacity: int = 4) -> None:
        self.capacity = capacity
        self.entries: list[tuple[tuple, tuple, slice, slice, AuxBuffers]] = []
        self.hits = 0
        self.misses = 0
        self.lock = threading.Lock()

    def clear(self) -> None:
        with self.lock:
            self.entries.clear()

    def get(self, view: SceneView, camera: Camera, samples: int,
            transforms: dict[str, np.ndarray] | None, rows: slice, cols: slice,
            world: object | None = None) -> tuple[AuxBuffers, bool]:
        """The buffers of window ``(rows, cols)`` and whether they came from the cache
        (arguments as :func:`aux_buffers`; ``transforms``: the pose ``view`` is in;
        ``world``: the (rest-pose) world ``view`` was prepared or relit for)."""
        key = (camera_key(camera), transforms_key(transforms), samples)
        q0, q1, _ = rows.indices(camera.height)
        p0, p1, _ = cols.indices(camera.width)
        r0, r1, c0, c1 = q0, q1, p0, p1  # the window to trace on a miss
        with self.lock:
            self.entries = [e for e in self.entries if _alive(e[0])]
            found = next((e for e in self.entries if e[1] == key and all(
                x is y for x, y in zip(_deref(e[0]), (view, world), strict=True))), None)
            if found is not None:
                self.entries.remove(found)
                _, _, er, ec, buf = found
                if er.start <= q0 and q1 <= er.stop and ec.start <= p0 and p1 <= ec.stop:
                    self.entries.append(found)
                    self.hits += 1
                    return buf.crop(slice(q0 - er.start, q1 - er.start),
                                    slice(p0 - ec.start, p1 - ec.start)), True
                r0, r1 = min(q0, er.start), max(q1, er.stop)
                c0, c1 = min(p0, ec.start), max(p1, ec.stop)
            self.misses += 1
        buf = aux_buffers(view, camera, samples, slice(r0, r1), slice(c0, c1))
        with self.lock:
            refs = (weakref.ref(view), None if world is None else weakref.ref(world))
            self.entries.append((refs, key, slice(r0, r1), slice(c0, c1), buf))
            del self.entries[:-self.capacity]
        return buf.crop(slice(q0 - r0, q1 - r0), slice(p0 - c0, p1 - c0)), False


def _deref(refs: tuple) -> tuple:
    return tuple(None if r is None else r() for r in refs)


def _alive(refs: tuple) -> bool:
    return all(r is None or r() is not None for r in refs)


AUX_CACHE = AuxCache()
"""The process's cache of auxiliary buffers (:meth:`arlight.methods.base.BaseMethod.denoise`)."""


__all__ = ["AUX_CACHE", "AUX_SEED", "AuxBuffers", "AuxCache", "MAX_SPECULAR", "aux_buffers",
           "camera_key", "transforms_key"]
