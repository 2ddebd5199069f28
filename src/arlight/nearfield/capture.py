"""Synthetic HDR fisheye captures: what the rig's cameras would record in a world.

Every pixel of a :class:`~arlight.nearfield.cameras.RigCamera` is unprojected through its
fisheye model (jittered inside the pixel) and traced by Mitsuba's own ``path`` integrator in
the world's *real* scene (virtual objects do not exist for a real camera), ``spp`` paths per
pixel; pixels outside the lens's field of view are 0. The result is linear radiance,
W/(sr·m²) — what Rohmer's calibrated HDR cameras deliver (§3.1, after the response curve and
the colour matrix). It gives the near-field pipeline data with known ground truth: the same
world renders the suite's reference images.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import build_views
from arlight.backend.rays import np3
from arlight.jit import ensure_variant
from arlight.nearfield.cameras import RigCamera
from arlight.scene.model import World

CHUNK = 1 << 20
"""Path samples per Mitsuba launch."""


def real_scene(world: World) -> mi.Scene:
    """The Mitsuba scene of the world's real shapes and lights."""
    ensure_variant()
    real = World([s for s in world.shapes if not s.is_virtual], world.lights, world.source)
    return build_views(real).real.scene


def capture(scene: mi.Scene, camera: RigCamera, spp: int = 64, seed: int = 0,
            max_depth: int = 8) -> np.ndarray:
    """The HDR image ``(H, W, 3)`` float32 of ``camera`` in ``scene`` (module docstring)."""
    ensure_variant()
    w, h = camera.size
    integrator = mi.load_dict({"type": "path", "max_depth": int(max_depth)})
    n = w * h * spp
    acc = np.zeros((w * h, 3))
    rng = np.random.default_rng(seed)
    for k, start in enumerate(range(0, n, CHUNK)):
        idx = np.arange(start, min(n, start + CHUNK))
        pix = idx // spp
        xy = np.stack([pix % w, pix // w], 1) + rng.random((len(idx), 2))
        d, ok = camera.model.unproject(xy)
        d = np.where(ok[:, None], d, np.array([0.0, 0.0, 1.0]))
        o = np.broadcast_to(camera.position, d.shape)
        ray = mi.Ray3f(mi.Point3f(*[np.ascontiguousarray(o[:, i], np.float32)
                                    for i in range(3)]),
                       mi.Vector3f(*[np.ascontiguousarray(d[:, i], np.float32)
                                     for i in range(3)]))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(int(seed) * 7919 + k, len(idx))
        spec, _, _ = integrator.sample(scene, sampler, ray)
        col = np3(spec)
        col[~ok] = 0.0
        col[~np.isfinite(col)] = 0.0
        np.add.at(acc, pix, col) if spp > 1 else acc.__setitem__(pix, col)
        del spec
        dr.flush_malloc_cache()
    return (acc / spp).reshape(h, w, 3).astype(np.float32)


def capture_rig(world: World, rig: list[RigCamera], spp: int = 64, seed: int = 0,
                max_depth: int = 8) -> list[np.ndarray]:
    """One HDR image per camera of ``rig`` (module docstring)."""
    scene = real_scene(world)
    return [capture(scene, cam, spp, seed + 1000 * i, max_depth) for i, cam in enumerate(rig)]


__all__ = ["capture", "capture_rig", "real_scene"]
