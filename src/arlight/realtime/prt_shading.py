"""Per-vertex PRT shading of virtual meshes: the per-frame half of the rigid pipeline (Franke
thesis §4.3), shared by the ``prt`` and ``nearfield`` methods.

* :func:`prt_meshes` — per virtual mesh of a world its object-space mesh, the precomputed
  transfer (:func:`arlight.realtime.prt_transfer.cached_transfer`, cached on disk) and the
  face tables the G-buffer's hits index (:class:`PRTMeshes`).
* :func:`shade_virtual` — radiance of the virtual G-buffer lanes: the per-vertex values
  ``Σ_k t_k l_k`` (light rotated into each object's frame, Eq. 2.37) interpolated with the
  barycentrics of the lanes' primary hits, times the albedo; with ``glossy`` plus the
  Sum-of-Gaussians specular term (:mod:`arlight.realtime.sog`, Eqs. 4.25–4.26) times the
  low-frequency self-shadowing factor :func:`self_shadowing`.

The blocks take small protocols (:class:`PRTShadingState`, :class:`PRTShadingOptions`), not a
method's data class: ``prt`` passes its prepared data (one light SH for every object),
``nearfield`` an adapter whose ``vertex_values`` uses one SH block per object.

Units: radiance W/(sr·m²).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays
from arlight.backend.mitsuba_scene import SceneViews
from arlight.backend.rays import np3
from arlight.errors import InputError
from arlight.jit import aligned
from arlight.progress import reporter
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.ibl_shading import MipEnvironment
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.prt_transfer import (
    PRTTransfer,
    cached_transfer,
    rotation_part,
)
from arlight.realtime.shading import ambient_irradiance_dr
from arlight.realtime.sog import SoGTables
from arlight.scene.model import FrameView, MeshData, Shape, World
from arlight.sphere.sh import irradiance


@dataclass
class PRTObject:
    """One virtual mesh: its world shape index, transfer, world rotation and the face table
    as the Mitsuba mesh holds it."""

    shape: int
    transfer: PRTTransfer
    rotation: np.ndarray
    faces: np.ndarray


@dataclass
class PRTMeshes:
    """The virtual meshes of a world with their transfer (:func:`prt_meshes`).

    Attributes:
        objects: one :class:`PRTObject` per virtual shape, in world order.
        face_offset: per world shape the index of its first triangle in ``faces`` (Dr.Jit).
        faces: every object's triangles, vertex indices into the concatenated vertex values
            (Dr.Jit, 3 per triangle).
    """

    objects: list[PRTObject]
    face_offset: mi.UInt32
    faces: mi.UInt32


class PRTShadingState(Protocol):
    """What :func:`shade_virtual` reads of a prepared world: the views the G-buffer was cast
    into, the meshes' face tables, the per-vertex light values, and for the glossy term the
    light SH, mip-mapped environment, SoG tables and ``F0`` per shape (None: diffuse only)."""

    views: SceneViews
    objects: Sequence[PRTObject]
    face_offset: mi.UInt32
    faces: mi.UInt32
    light: np.ndarray
    env: MipEnvironment | None
    sog: SoGTables | None
    ks: mi.Color3f | None

    def vertex_values(self, order: int | None = None) -> list[np.ndarray]:
        """Per object ``Σ_k t_k l_k`` per vertex ``(V, 3)`` this frame."""
        ...


class PRTShadingOptions(Protocol):
    """The options :func:`shade_virtual` reads: SH ``order`` and ``glossy``."""

    order: int
    glossy: bool


def object_mesh(shape: Shape, loaded: mi.Shape | None) -> tuple[MeshData, np.ndarray]:
    """The object-space mesh of a virtual shape and the faces ``(F, 3)`` of the Mitsuba mesh
    it was loaded as (the hits' ``prim_index`` and barycentrics refer to those). Mesh files
    keep their object-space data; ``box`` and ``rectangle`` primitives (Mitsuba meshes) are
    read back from the loaded mesh and taken into object space by ``to_world⁻¹``; analytic
    spheres and disks have no vertices: InputError."""
    if not isinstance(loaded, mi.Mesh):
        raise InputError(f"prt needs triangle meshes; virtual shape {shape.name!r} is an "
                         f"analytic {shape.type} (use a mesh file, or the ibl method)",
                         field=f"shapes.{shape.name}")
    params = mi.traverse(loaded)
    faces = np.asarray(params["faces"], np.int64).reshape(-1, 3)
    if shape.mesh is not None:
        return shape.mesh, faces
    m = np.asarray(shape.to_world, np.float64)
    inv = np.linalg.inv(m)
    v = np.asarray(params["vertex_positions"], np.float64).reshape(-1, 3)
    v = v @ inv[:3, :3].T + inv[:3, 3]
    n = np.asarray(params["vertex_normals"], np.float64).reshape(-1, 3)
    normals = None
    if len(n) == len(v):
        n = n @ m[:3, :3]  # normals transform with the inverse transpose of to_world⁻¹
        normals = (n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
    return MeshData(v.astype(np.float32), faces.astype(np.uint32), None,
                    None if normals is None else normals.astype(np.float32)), faces


def prt_meshes(world: World, views: SceneViews, cache: Path | None, order: int,
               directions: int, bounces: int, shadowed: bool = True) -> PRTMeshes:
    """Transfer (``order``, ``directions`` rays per vertex, ``bounces``, ``shadowed``; cached
    under ``cache``, None: not cached, with a progress bar on a terminal) and face tables of
    the virtual meshes of ``world`` as loaded in ``views.mixed``."""
    objects = []
    loaded = {sh.id(): sh for sh in views.mixed.scene.shapes()}
    for i, s in enumerate(world.shapes):
        if not s.is_virtual:
            continue
        mesh, faces = object_mesh(s, loaded.get(str(i)))
        try:
            rot = rotation_part(s.to_world)
            tr = cached_transfer(mesh, cache, order, directions, bounces,
                                 s.material.params.get(
                                     "albedo", s.material.params.get("kd", [0.5] * 3)),
                                 s.name, reporter(f"prt transfer {s.name}"),
                                 shadowed=shadowed)
        except ValueError as exc:
            raise InputError(str(exc), field=f"shapes.{s.name}") from exc
        objects.append(PRTObject(i, tr, rot, faces))
    offs = np.zeros(max(len(world.shapes), 1), np.uint32)
    base_v, base_f, all_f = 0, 0, []
    for o in objects:
        offs[o.shape] = base_f
        all_f.append(o.faces + base_v)
        base_v += o.transfer.vertices
        base_f += len(o.faces)
    faces = np.concatenate(all_f).astype(np.uint32).reshape(-1) if all_f else np.zeros(3,
                                                                                        np.uint32)
    return PRTMeshes(objects, mi.UInt32(offs), mi.UInt32(faces))


def unshadowed(light: np.ndarray, n: mi.Vector3f, order: int) -> mi.Color3f:
    """``E(n)/π``: the unshadowed diffuse transfer of radiance SH ``light`` (truncated to
    ``order``) at unit world normals ``n`` (W/(sr·m²) per unit albedo)."""
    if order <= 2:
        sh9 = np.zeros((9, 3))
        sh9[:min(9, len(light))] = light[:9]
        return ambient_irradiance_dr(LightSet([], sh9), n) * (1.0 / math.pi)
    e = irradiance(light, np3(n),
                   max_order=order) / math.pi
    return mi.Color3f(*[mi.Float(aligned(e[:, c], np.float32)) for c in range(3)])


def self_shadowing(shadowed: mi.Color3f, free: mi.Color3f) -> mi.Float:
    """Low-frequency self-shadowing factor of the glossy term: the ratio of the shadowed
    (PRT) to the unshadowed diffuse transfer at the pixel, summed over RGB, clamped to
    [0, 1] (1 where the unshadowed value vanishes)."""
    num = shadowed.x + shadowed.y + shadowed.z
    den = free.x + free.y + free.z
    return dr.select(den > 1e-8, dr.clip(num / dr.maximum(den, 1e-8), 0.0, 1.0), 1.0)


def shade_virtual(data: PRTShadingState, gb: GBuffer, view: FrameView,
                  options: PRTShadingOptions, seed: int = 0
                  ) -> tuple[mi.Color3f, mi.UInt32]:
    """Radiance (W/(sr·m²)) of the virtual lanes: vertex values (light rotated into each
    object's frame) interpolated with the barycentrics of the lanes' primary hits, times the
    albedo; plus, with ``glossy``, the SoG specular term times the self-shadowing factor
    (module docstring)."""
    idx = dr.compress(gb.virtual)
    if dr.width(idx) == 0 or not data.objects:
        return dr.zeros(mi.Color3f, 0), dr.zeros(mi.UInt32, 0)
    vals = np.concatenate(data.vertex_values(options.order)).astype(np.float32)
    table = mi.Float(aligned(vals.reshape(-1), np.float32))
    k = idx % gb.spp
    ray = mi.Ray3f(generate_rays(view.camera, dr.gather(mi.UInt32, gb.pixel, idx), k,
                                 gb.spp, dr.opaque(mi.UInt32, seed)))
    pi = data.views.mixed.scene.ray_intersect_preliminary(ray)
    reg = dr.reinterpret_array(mi.UInt32, pi.shape)
    shape = dr.gather(mi.Int32, data.views.mixed.shape_index, reg)
    tri = dr.gather(mi.UInt32, data.face_offset, mi.UInt32(shape)) + pi.prim_index
    b1, b2 = pi.prim_uv.x, pi.prim_uv.y
    out = mi.Color3f(0.0)
    for c, w in enumerate((1.0 - b1 - b2, b1, b2)):
        vid = dr.gather(mi.UInt32, data.faces, tri * 3 + c)
        out += w * dr.gather(mi.Color3f, table, vid)
    rad = dr.maximum(out, 0.0) * dr.gather(mi.Color3f, gb.albedo, idx)
    if data.sog is not None and data.env is not None and options.glossy:
        n = dr.gather(mi.Vector3f, gb.normal, idx)
        shape_idx = dr.gather(mi.Int32, gb.shape, idx)
        vis = self_shadowing(out, unshadowed(data.light, n, options.order))
        spec = data.sog.radiance(data.env, shape_idx, n, dr.gather(mi.Vector3f, gb.to_camera,
                                                                   idx))
        rad += spec * dr.gather(mi.Color3f, data.ks, shape_idx) * vis
    out = rad
    dr.eval(out)
    return out, idx


__all__ = ["PRTMeshes", "PRTObject", "PRTShadingOptions", "PRTShadingState", "object_mesh",
           "prt_meshes", "self_shadowing", "shade_virtual", "unshadowed"]
