"""The photograph at the camera projection of world points (Kán §5.2's reprojection).

A path that reaches a real surface the camera sees can take the photograph's radiance there
instead of tracing on: ``onepass`` does so at its first real diffuse hit, the photon gather
for its caustics, and ``dvct`` where its surround, distant-specular and mirror rays meet the
real proxy. One implementation serves them all.
"""

from __future__ import annotations

from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import Projection
from arlight.backend.mitsuba_scene import SceneView
from arlight.scene.camera import Camera


class Reprojection(NamedTuple):
    """What :meth:`Reprojector.lookup` finds per lane: ``radiance`` the photograph's pixel
    (linear, W sr⁻¹ m⁻²; 0 where not ``ok``), ``ok`` the point projects into the image and
    no real surface lies between the camera and it, ``inside`` it projects into the image
    (the visibility ray was traced), ``pixel`` the row-major pixel index (clamped into the
    image; meaningful where ``ok``)."""

    radiance: mi.Color3f
    ok: mi.Bool
    inside: mi.Bool
    pixel: mi.UInt32


class Reprojector:
    """The photograph ``frame`` (``(H, W, 3)`` linear radiance) of ``camera``, looked up at
    world points that the ``real`` proxy does not hide from the camera."""

    def __init__(self, camera: Camera, frame: np.ndarray, real: SceneView):
        self.frame = np.ascontiguousarray(frame, dtype=np.float32)
        flat = self.frame.reshape(-1, 3)
        self.table = mi.Color3f(flat[:, 0], flat[:, 1], flat[:, 2])
        self.proj = Projection(camera)
        self.real = real

    def lookup(self, p: mi.Point3f, active: mi.Bool) -> Reprojection:
        """The photograph at the camera projection of the points ``p`` (metres, world) on the
        ``active`` lanes: nearest pixel, one visibility ray to the camera centre in the real
        proxy (shortened by 10⁻⁴ of its length so the surface at ``p`` does not hide
        itself)."""
        pr = self.proj
        u, v, z = pr.project(p)
        inside = active & (z > 0) & (u >= 0) & (v >= 0) & (u < mi.Float(pr.width)) & (
            v < mi.Float(pr.height))
        d = p - pr.center
        dist = dr.norm(d)
        ray = mi.Ray3f(pr.center, d / dist)
        ray.maxt = dist * (1.0 - 1e-4)
        ok = inside & ~self.real.scene.ray_test(ray, inside)
        col = dr.minimum(mi.UInt32(dr.maximum(u, 0.0)), pr.width - 1)
        row = dr.minimum(mi.UInt32(dr.maximum(v, 0.0)), pr.height - 1)
        pixel = row * pr.width + col
        return Reprojection(dr.gather(mi.Color3f, self.table, pixel, ok), ok, inside, pixel)


__all__ = ["Reprojection", "Reprojector"]
