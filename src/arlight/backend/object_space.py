"""Virtual objects traced in object space (issue #32): a pose moves no Mitsuba scene.

Mitsuba 3.9's Embree backend rebuilds the acceleration structure of *every* shape of a scene
on any parameter update (10–45 ms for the demo's mixed view on 2 loaded cores; a Mitsuba
``instance`` costs the same). Here each virtual shape is loaded once, alone, at the identity
pose (its *object-space scene*), and a ray ``r(t) = o + t·d`` is tested against it as
``r'(t) = M⁻¹o + t·M⁻¹d`` with ``M`` the shape's ``to_world`` (an affine 4×4; the direction is
not renormalised, so ``t`` and ``maxt`` keep their world meaning). The real part of the
scene is a Mitsuba scene that then never changes when an object moves; a pose swaps the 4×4
frames (opaque Dr.Jit scalars: one kernel for every pose).

* :class:`PosedObject` — one virtual shape: its object-space scene and its frame.
* :class:`ObjectSpaceScene` — a static real ``mi.Scene`` (or none) plus posed objects,
  duck-typing the ``ray_intersect`` / ``ray_intersect_preliminary`` / ``ray_test`` /
  ``shapes`` / ``bbox`` of ``mi.Scene``: the nearer of the real hit and every object's hit.
* :class:`SplitView` — an :class:`~arlight.backend.mitsuba_scene.SceneView` look-alike over
  an :class:`ObjectSpaceScene` (the methods' mixed view ρ: the real view µ's scene plus the
  objects), with the registry-id → shape-index / role tables of both; moving an object
  (:meth:`SplitView.place`) rebuilds nothing. :func:`build_split_views` makes the pair.

What the merge returns for an object hit (:meth:`PosedObject.to_world`): the
``SurfaceInteraction3f`` of the object-space hit with ``t`` (the world ray's parameter),
``p = M p'``, ``dp_du``, ``dp_dv`` (``A ·``, ``A`` the linear part of ``M``), the geometric
normal ``n`` and the shading normal ``sh_frame.n`` taken through the inverse transpose
``A⁻ᵀ`` and renormalised (normals stay perpendicular to the surface under non-uniform
scale), ``dn_du``, ``dn_dv`` through ``A⁻ᵀ`` (not renormalised), ``sh_frame`` rebuilt from
``sh_frame.n`` and ``dp_du`` (:meth:`initialize_sh_frame`, as Mitsuba's meshes do) and ``wi``
the world ray's reversed unit direction in it; ``uv``, ``prim_index``, ``shape`` (the
object-space shape: ``si.bsdf()`` works), ``instance``, ``time``, ``wavelengths`` as the
object-space hit has them. ``duv_dx``, ``duv_dy`` are zero (no ray differentials).
Preliminary intersections keep the object-space ``prim_uv`` / ``prim_index`` / ``shape``
(barycentrics and primitive indices do not depend on the pose) and the world ``t``; their
``compute_surface_interaction`` needs the object-space ray, so call :meth:`ray_intersect`
for surface data instead.

Precision: the object-space hit is the world-space one up to float32 rounding of the
transformed ray (tests/backend/test_object_space.py compares both against a scene that
holds the object in world space). Units: metres.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend import mitsuba_scene as ms
from arlight.scene.model import ARScene, Shape


def _opaque_rows(m: np.ndarray, rows: int) -> list[list[mi.Float]]:
    """The first ``rows`` rows of a 4×4 matrix as opaque Dr.Jit scalars (a new pose is new
    data for the same kernel, never a new literal)."""
    return [[dr.opaque(mi.Float, float(m[r, c])) for c in range(4)] for r in range(rows)]


def _affine(m: list[list[mi.Float]], v: Any, point: bool) -> list[Any]:
    """``m · v`` for a point (with the translation column) or a vector (without)."""
    return [m[r][0] * v.x + m[r][1] * v.y + m[r][2] * v.z + (m[r][3] if point else 0.0)
            for r in range(3)]


class PosedObject:
    """One virtual shape loaded alone at the identity pose, posed by ``frame``.

    Attributes:
        index: the shape's index in the world's ``shapes`` (its name in the views).
        scene: the shape alone at the identity pose (loaded as the views load shapes).
        frame: world from object, 4×4 (m), any invertible affine transform.
    """

    def __init__(self, index: int, scene: mi.Scene, frame: np.ndarray) -> None:
        self.index = int(index)
        self.scene = scene
        self.frame = np.asarray(frame, np.float64)
        inv = np.linalg.inv(self.frame)
        self._to_world = _opaque_rows(self.frame, 3)
        self._to_local = _opaque_rows(inv, 3)
        # normals: the inverse transpose of the linear part, row r = column r of inv
        self._normal = [[dr.opaque(mi.Float, float(inv[c, r])) for c in range(3)] + [0.0]
                        for r in range(3)]

    @staticmethod
    def load(index: int, shape: Shape) -> PosedObject:
        """``shape`` (a virtual shape of a world, index ``index``) loaded at the identity pose
        and posed by its ``to_world``."""
        rest = replace(shape, to_world=np.eye(4))
        name = str(index)
        view = ms.load_view({"objects": {name: ms.describe_shape(rest)}},
                            {name: ms.ROLE_VIRTUAL})
        return PosedObject(index, view.scene, shape.to_world)

    def posed(self, frame: np.ndarray) -> PosedObject:
        """The same loaded object in another pose (nothing loaded or rebuilt)."""
        return PosedObject(self.index, self.scene, frame)

    def local_ray(self, ray: mi.Ray3f) -> mi.Ray3f:
        """``ray`` in the object's frame: origin and direction through ``frame⁻¹``, the
        direction not renormalised (``t`` and ``maxt`` keep their world meaning)."""
        local = mi.Ray3f(mi.Point3f(*_affine(self._to_local, ray.o, True)),
                         mi.Vector3f(*_affine(self._to_local, ray.d, False)))
        local.maxt = ray.maxt
        local.time = ray.time
        return local

    def normal(self, n: Any) -> mi.Vector3f:
        """A normal (or normal derivative) through the inverse transpose, not renormalised."""
        return mi.Vector3f(*_affine(self._normal, n, False))

    def to_world(self, si: mi.SurfaceInteraction3f, ray: mi.Ray3f
                 ) -> mi.SurfaceInteraction3f:
        """The object-space hit ``si`` of ``local_ray(ray)`` in world space (module
        docstring: which fields are transformed and how)."""
        out = mi.SurfaceInteraction3f(si)
        out.p = mi.Point3f(*_affine(self._to_world, si.p, True))
        out.n = mi.Normal3f(dr.normalize(self.normal(si.n)))
        out.dp_du = mi.Vector3f(*_affine(self._to_world, si.dp_du, False))
        out.dp_dv = mi.Vector3f(*_affine(self._to_world, si.dp_dv, False))
        out.dn_du = self.normal(si.dn_du)
        out.dn_dv = self.normal(si.dn_dv)
        out.sh_frame = mi.Frame3f(dr.normalize(self.normal(si.sh_frame.n)))
        out.initialize_sh_frame()
        out.wi = out.to_local(-dr.normalize(ray.d))
        out.duv_dx = dr.zeros(mi.Vector2f)
        out.duv_dy = dr.zeros(mi.Vector2f)
        return out


class ObjectSpaceScene:
    """A static real scene plus virtual objects traced in object space (module docstring).
    Duck-types the parts of ``mi.Scene`` the methods' tracers call."""

    def __init__(self, real: mi.Scene | None, objects: Sequence[PosedObject]) -> None:
        self.real = real
        self.objects = list(objects)

    def posed(self, frames: dict[int, np.ndarray]) -> ObjectSpaceScene:
        """The same scene with the objects of the shape indices in ``frames`` re-posed."""
        return ObjectSpaceScene(self.real, [o.posed(frames[o.index]) if o.index in frames
                                            else o for o in self.objects])

    def ray_intersect(self, ray: mi.Ray3f, active: mi.Bool | bool = True
                      ) -> mi.SurfaceInteraction3f:
        """The nearest hit among the real scene and the objects, in world space (ties go to
        the real scene, then to the earlier object). One surface interaction is computed
        per lane, from the merged preliminary hit and the ray in its shape's space."""
        pi, rays, owner = self._nearest(ray, active)
        si = pi.compute_surface_interaction(rays, mi.RayFlags.All, active)
        for k, obj in enumerate(self.objects):
            si = dr.select(owner == k, obj.to_world(si, ray), si)
        return si

    def _nearest(self, ray: mi.Ray3f, active: mi.Bool | bool
                 ) -> tuple[mi.PreliminaryIntersection3f, mi.Ray3f, mi.Int32]:
        """The nearest preliminary hit, the ray in the space of its shape (the world ray or
        an object's local one) and the index of the object hit (−1: the real scene)."""
        pi = (self.real.ray_intersect_preliminary(ray, active=active)
              if self.real is not None
              else dr.zeros(mi.PreliminaryIntersection3f, dr.width(ray.o)))
        rays = mi.Ray3f(ray)
        owner = dr.full(mi.Int32, -1, dr.width(pi.t))
        for k, obj in enumerate(self.objects):
            local = obj.local_ray(ray)
            hit = obj.scene.ray_intersect_preliminary(local, active=active)
            nearer = hit.is_valid() & (hit.t < pi.t)
            pi = dr.select(nearer, hit, pi)
            rays = dr.select(nearer, local, rays)
            owner = dr.select(nearer, k, owner)
        return pi, rays, owner

    def ray_intersect_preliminary(self, ray: mi.Ray3f, active: mi.Bool | bool = True
                                  ) -> mi.PreliminaryIntersection3f:
        """The nearest preliminary hit: world ``t``; for an object hit, its object-space
        shape, primitive and barycentrics (module docstring)."""
        return self._nearest(ray, active)[0]

    def ray_test(self, ray: mi.Ray3f, active: mi.Bool | bool = True) -> mi.Bool:
        """Whether each ray hits anything before ``ray.maxt``."""
        hit = (self.real.ray_test(ray, active) if self.real is not None
               else dr.zeros(mi.Bool, dr.width(ray.o)))
        for obj in self.objects:
            hit |= obj.scene.ray_test(obj.local_ray(ray), active)
        return hit

    def shapes(self) -> list[mi.Shape]:
        """The real scene's shapes, then each object's (object-space) shape."""
        out = list(self.real.shapes()) if self.real is not None else []
        for obj in self.objects:
            out.extend(obj.scene.shapes())
        return out

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre (m) and radius (m) of a sphere around the objects (not the real scene):
        each object's object-space bounding-box circumsphere through its pose (centre
        ``M c``, radius ``r · ‖A‖₂``, the largest singular value of the linear part: a
        similarity's scale), so it does not grow as an object turns; several objects: the
        sphere about the centre of their spheres' bounding box that holds them all."""
        if not self.objects:
            raise ValueError("no object to bound")
        spheres = []
        for obj in self.objects:
            b = obj.scene.bbox()
            lo = np.array([b.min.x, b.min.y, b.min.z], np.float64)
            hi = np.array([b.max.x, b.max.y, b.max.z], np.float64)
            c, r = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0)
            a = obj.frame[:3, :3]
            spheres.append((a @ c + obj.frame[:3, 3], r * float(np.linalg.norm(a, 2))))
        if len(spheres) == 1:
            return spheres[0]
        lo = np.min([c - r for c, r in spheres], axis=0)
        hi = np.max([c + r for c, r in spheres], axis=0)
        centre = (lo + hi) / 2.0
        return centre, max(float(np.linalg.norm(c - centre)) + r for c, r in spheres)

    def bbox(self) -> mi.ScalarBoundingBox3f:
        """World-space bounds: the real scene's and each object's box corners posed."""
        box = mi.ScalarBoundingBox3f()
        if self.real is not None:
            box.expand(self.real.bbox())
        for obj in self.objects:
            b = obj.scene.bbox()
            for corner in itertools.product(*zip([b.min.x, b.min.y, b.min.z],
                                                 [b.max.x, b.max.y, b.max.z], strict=True)):
                p = obj.frame[:3, :3] @ np.asarray(corner) + obj.frame[:3, 3]
                box.expand(mi.ScalarPoint3f(*[float(x) for x in p]))
        return box


class SplitView:
    """The mixed view ρ as the real view µ's scene plus virtual objects in object space.

    Duck-types :class:`~arlight.backend.mitsuba_scene.SceneView` (``scene``,
    ``shape_index``, ``role``, ``hit_role``, ``hit_shape``, ``params``, ``update``,
    ``generation``): parameters are the real view's (a relit lamp goes through the real
    view; :attr:`base` names it), and :meth:`place` moves objects by their frames alone.

    Attributes:
        real: the real view µ whose scene this view shares.
        scene: the :class:`ObjectSpaceScene` (``real.scene`` plus the objects).
        shape_index, role: registry id -> shape index / role, over the real view's shapes
            and the objects' (``ROLE_VIRTUAL``).
    """

    def __init__(self, real: ms.SceneView, objects: Sequence[PosedObject]) -> None:
        self.real = real
        self.scene = ObjectSpaceScene(real.scene, objects)
        idx = np.array(real.shape_index, np.int32)
        role = np.array(real.role, np.int32)
        ids = {int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(sh))[0]): o.index
               for o in objects for sh in o.scene.shapes()}
        size = max([len(idx), *[i + 1 for i in ids]])
        idx = np.concatenate([idx, np.full(size - len(idx), -1, np.int32)])
        role = np.concatenate([role, np.full(size - len(role), ms.ROLE_MISS, np.int32)])
        for reg, index in ids.items():
            idx[reg], role[reg] = index, ms.ROLE_VIRTUAL
        self.shape_index, self.role = mi.Int32(idx), mi.Int32(role)
        self._generation = next(ms._GENERATIONS)
        self._real_generation = real.generation

    hit_role = ms.SceneView.hit_role
    hit_shape = ms.SceneView.hit_shape

    @property
    def base(self) -> ms.SceneView:
        """The loaded view whose parameters this view's scene reads (the real view)."""
        return self.real

    @property
    def params(self) -> mi.SceneParameters:
        """The real view's parameters (the objects have none that a method sets)."""
        return self.real.params

    def update(self, values: dict[str, Any]) -> None:
        """Set parameters of the real view (:meth:`SceneView.update`)."""
        self.real.update(values)

    @property
    def generation(self) -> int:
        """A new number at every change: of the real view, or of an object's pose."""
        if self.real.generation != self._real_generation:
            self._real_generation = self.real.generation
            self._generation = next(ms._GENERATIONS)
        return self._generation

    def place(self, shapes: Sequence[Shape], moved: set[int]) -> None:
        """Give the objects among the ``moved`` shape indices their pose in ``shapes`` (no
        Mitsuba scene changes; real shapes move in the real view, which this view shares)."""
        frames = {o.index: shapes[o.index].to_world for o in self.scene.objects
                  if o.index in moved}
        if frames:
            self.scene = self.scene.posed(frames)
            self._generation = next(ms._GENERATIONS)


def build_split_views(scene: ARScene) -> ms.SceneViews:
    """The views of ``scene`` with the mixed one a :class:`SplitView` (the real view's scene
    plus each virtual shape in object space); without virtual shapes the plain views."""
    ms.ensure_variant()
    if not scene.has_virtual:
        return ms.build_views(scene)
    roles = {str(i): ms.ROLE_VIRTUAL if s.is_virtual else ms.ROLE_REAL
             for i, s in enumerate(scene.shapes)}
    real = ms.load_view(ms.describe_views(scene)["real"], roles)
    objects = [PosedObject.load(i, s) for i, s in enumerate(scene.shapes) if s.is_virtual]
    return ms.SceneViews(real=real, mixed=SplitView(real, objects), shapes=list(scene.shapes))


__all__ = ["ObjectSpaceScene", "PosedObject", "SplitView", "build_split_views"]
