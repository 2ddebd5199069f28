"""Ray queries of the studio against the scene: which virtual object is under the pointer,
and where on the real proxy an object dragged to a pixel stands.

Both are camera rays through a pixel (:meth:`arlight.scene.camera.Camera.pixel_rays`)
intersected with Mitsuba scenes (:func:`arlight.backend.rays.intersect`), built once:

* the *real* view — the proxy of the real world (support surfaces);
* one scene per virtual shape, in its rest pose. A posed shape ``M · rest`` is hit by a
  world ray exactly when the rest shape is hit by the ray mapped through ``M⁻¹``, so
  picking needs no rebuild when objects move (one scene each, so that another object's
  rest pose cannot occlude it).

Dr.Jit state is not shared between threads here: call these from one thread (the studio's
render worker).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from arlight.backend.mitsuba_scene import SceneView, build_views
from arlight.backend.rays import intersect
from arlight.scene.model import ARScene
from arlight.studio.pose import ObjectPose

MIN_SUPPORT_COS = 0.7
"""A surface supports a dragged object when its normal is within ~45° of +Y (cos ≥ 0.7):
a table top or a box lid, not a wall."""


@dataclass(frozen=True)
class SupportHit:
    """A point of the real proxy an object can stand on (world metres, unit normal)."""

    position: np.ndarray
    normal: np.ndarray
    shape: str


class Proxy:
    """Ray queries against the real proxy and the virtual objects of ``scene``.

    Args:
        scene: the studio's scene (its camera defines the pixel coordinates).
    """

    def __init__(self, scene: ARScene) -> None:
        self.scene = scene
        self.camera = scene.camera
        self.real: SceneView = build_views(scene.without_virtual()).real
        self.real_names = [s.name for s in scene.real_shapes]
        # one object per virtual shape, or per model entry (its parts move together)
        objects: dict[str, list] = {}
        for shape in scene.virtual_shapes:
            objects.setdefault(shape.group or shape.name, []).append(shape)
        self.virtual_names = list(objects)
        self.virtual: dict[str, SceneView] = {}
        self.anchors: dict[str, tuple[float, float, float]] = {}
        for name, shapes in objects.items():
            view = build_views(replace(scene, shapes=shapes, lights=[])).mixed
            b = view.scene.bbox()
            self.virtual[name] = view
            self.anchors[name] = (0.5 * (b.min.x + b.max.x), float(b.min.y),
                                  0.5 * (b.min.z + b.max.z))

    def rest_poses(self) -> dict[str, ObjectPose]:
        """The identity pose of every virtual shape (anchored at its bounding box's base)."""
        return {n: ObjectPose(tuple(float(x) for x in a)) for n, a in self.anchors.items()}

    def _ray(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        o, d = self.camera.pixel_rays(np.array([[x, y]], np.float64))
        return o, d

    def real_hit_t(self, x: float, y: float) -> float:
        """Distance along the pixel's ray to the real proxy (inf on a miss), metres."""
        o, d = self._ray(x, y)
        return float(intersect(self.real, o, d).t[0])

    def support(self, x: float, y: float) -> SupportHit | None:
        """The real surface seen through pixel ``(x, y)`` if an object can stand on it
        (a real shape whose normal, turned toward the camera, is within ~45° of +Y)."""
        o, d = self._ray(x, y)
        hits = intersect(self.real, o, d)
        if not hits.hit[0] or hits.shape[0] < 0:  # a miss or the lamp's own geometry
            return None
        n = hits.normal[0] / max(np.linalg.norm(hits.normal[0]), 1e-12)
        if float(n @ d[0]) > 0:  # the side the camera sees
            n = -n
        if n[1] < MIN_SUPPORT_COS:
            return None
        return SupportHit(hits.position[0].copy(), n,
                          self.real_names[int(hits.shape[0])])

    def pick(self, x: float, y: float, poses: dict[str, ObjectPose]) -> str | None:
        """The virtual shape seen through pixel ``(x, y)`` in the given poses, or None when
        the ray misses them all or a real surface is nearer."""
        if not self.virtual:
            return None
        o, d = self._ray(x, y)
        best, best_t = None, self.real_hit_t(x, y)
        for name, view in self.virtual.items():
            m = poses[name].matrix() if name in poses else np.eye(4)
            inv = np.linalg.inv(m)
            lo = inv[:3, :3] @ o[0] + inv[:3, 3]
            ld = inv[:3, :3] @ d[0]
            ld /= np.linalg.norm(ld)
            hits = intersect(view, lo[None], ld[None])
            if not hits.hit[0]:
                continue
            p = m[:3, :3] @ hits.position[0] + m[:3, 3]
            t = float(np.linalg.norm(p - o[0]))
            if t < best_t:
                best, best_t = name, t
        return best

    def project(self, point: np.ndarray) -> tuple[float, float] | None:
        """Pixel coordinates of a world point (None behind the camera)."""
        uv, z = self.camera.project(np.asarray(point, np.float64)[None])
        if z[0] <= 0:
            return None
        return float(uv[0, 0]), float(uv[0, 1])
