"""``prt``: the *rigid pipeline* of Franke thesis §4.3 with AR-OOF relighting (§5.2).

* **prepare** (once per world and mesh content): per virtual mesh the per-vertex diffuse
  transfer (:mod:`arlight.realtime.prt_transfer`: ray-traced self-occlusion, optional diffuse
  inter-reflection, ``order`` 2 or 3 → 9 or 16 SH coefficients), cached on disk by the mesh's
  content hash, with a progress bar on a terminal; the world's light as radiance SH seen from
  the virtual objects (environment maps projected exactly and rotated by their
  ``rotation_deg``; point, spot, area and directional lights as SH delta lights from the
  objects' centre, ``E = I/d²``); the reduced lights and occlusion field of the real-surface
  relighting (as ``ibl``).
* **render** (per frame): the light rotated into each object's frame (exact SH rotation,
  ``l_obj = rotate(l, Rᵀ)``) and dotted with every vertex's transfer (Eq. 2.37); the virtual
  pixels interpolate those vertex values with the barycentrics of their primary hit and
  multiply by the G-buffer albedo; real pixels get ``ibl``'s multiplicative shadow factor.
* **glossy** (option ``glossy``, default on; thesis §4.3 "PRT for low-frequency
  self-shadowing × SoG for the material"): ``phong`` and ``roughconductor`` virtual pixels
  add ``F0 · V · Σ_k w_k 2πσ_k² L̄_{σ_k}(ω_r ⊕ µ_k e_1)`` (Eqs. 4.25–4.26,
  :mod:`arlight.realtime.sog`: K = 3 Gaussians fitted per α at N = 16 view angles, F0 the
  specular reflectance and α as ``ibl`` takes them, ``L̄`` the environment's mip chain that
  ``ibl`` uses, at the level whose texel solid angle is ``2πσ_k²``); ``V`` =
  ``clip(Σ_rgb s / Σ_rgb u, 0, 1)``, the ratio of the pixel's shadowed PRT value ``s`` to the
  unshadowed SH irradiance ``u = E(n)/π`` of the same light at its normal. The glossy term
  reflects the distant (environment) light only, as in ``ibl``.

Moving the object
(``view.object_transforms``) re-uses the cached transfer: only the light rotation changes.
Stats: ``time_gbuffer``, ``time_shade_virtual`` (the per-frame PRT shading),
``time_shade_real``, ``time_assemble``; ``prt_vertices``, ``prt_seconds_per_vertex`` (the
precomputation, 0 when cached). See ``docs/methods/prt.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays
from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.backend.rays import np3
from arlight.errors import InputError
from arlight.methods.base import BaseMethod, Layers, RenderSettings
from arlight.methods.fragments import GBUFFER_OPTIONS, REDUCTION_OPTIONS
from arlight.methods.ibl import render_layers, specular_tables
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.ibl_shading import MipEnvironment, environment_map, rot_y
from arlight.realtime.light_reduction import LightSet, reduce_lights
from arlight.realtime.oof import OOF_OPTIONS, OcclusionField, field_from_options, virtual_scene
from arlight.realtime.prt_transfer import (
    PRTTransfer,
    cached_transfer,
    progress_bar,
    rotation_part,
    vertex_values,
)
from arlight.realtime.shading import ambient_irradiance_dr, emitted_intensity
from arlight.realtime.sog import SoGTables
from arlight.scene.model import FrameView, MeshData, Shape, World
from arlight.sphere.sh import (
    directional_light_coeffs,
    irradiance,
    n_coeffs,
    project_equirect,
    rotate,
)
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "order": Field("int", 2, "SH order of the transfer (2: 9 coefficients, 3: 16)", "", min=1,
                   max=6),
    "directions": Field("int", 512, "visibility rays per vertex in the precomputation", "",
                        min=16, max=16384),
    "bounces": Field("int", 0, "diffuse inter-reflection bounces in the transfer", "", min=0,
                     max=8),
    "shadowed": Field("bool", True, "trace self-occlusion (false: unshadowed transfer, i.e. "
                      "SH irradiance)"),
    "glossy": Field("bool", True, "Sum-of-Gaussians glossy reflection of the environment "
                    "for phong / roughconductor (Eqs. 4.25–4.26; false: diffuse part only)"),
    "cache": Field("bool", True, "cache precomputed transfer on disk (<cache>/prt/<hash>.npz)"),
    **OOF_OPTIONS,
    **REDUCTION_OPTIONS,
    "area_grid": Field("int", 3, "cosine point lights per side of an area light (3 × 3: a "
                       "soft shadow; bunny-box +0.45 dB over 1)", "", min=1, max=16),
    **GBUFFER_OPTIONS,
}

SPEC = MethodSpec(
    name="prt",
    description="Rigid pipeline (Franke §4.3): per-vertex SH precomputed radiance transfer "
                "with self-occlusion, rotated with the object; AR-OOF shadows; real time.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True,
                              materials=frozenset({"diffuse", "phong", "roughconductor"})),
)


def light_sh(world: World, order: int, centre: np.ndarray, area_grid: int = 1) -> np.ndarray:
    """Radiance SH ``((order+1)², 3)`` of all the world's light as seen from ``centre``
    (module docstring). Environment maps are projected, then rotated (exact), so turning a
    map by ``rotation_deg`` turns its SH exactly."""
    out = np.zeros((n_coeffs(order), 3))
    for lt in world.lights:
        if lt.type in ("envmap", "sh"):
            sh = project_equirect(np.asarray(lt.radiance_map, np.float64)[..., :3], order)
            sh *= float(lt.params.get("scale", 1.0))
            out += rotate(sh, rot_y(float(lt.params.get("rotation_deg", 0.0))))
        elif lt.type == "constant":
            out[0] += np.asarray(lt.params["radiance"], np.float64) * math.sqrt(4 * math.pi)
    local = World([], [lt for lt in world.lights if lt.type not in ("envmap", "sh",
                                                                     "constant")])
    if local.lights:
        for lt in reduce_lights(local, env_lights=0, area_grid=area_grid).lights:
            if lt.kind == "directional":
                to_light, e = -np.asarray(lt.axis, np.float64), np.asarray(lt.intensity)
            else:
                d = np.asarray(lt.position, np.float64) - centre
                r = max(float(np.linalg.norm(d)), 1e-9)
                to_light = d / r
                w = mi.Vector3f(*[float(x) for x in -to_light])
                e = np.array(emitted_intensity(lt, w), np.float64).reshape(3) / (r * r)
            out += directional_light_coeffs(to_light, e, order)
    return out


@dataclass
class PRTObject:
    """One virtual mesh: its world shape index, transfer, world rotation and the face table
    as the Mitsuba mesh holds it."""

    shape: int
    transfer: PRTTransfer
    rotation: np.ndarray
    faces: np.ndarray


@dataclass
class PRTData:
    """What ``prepare_world`` keeps (see the module docstring)."""

    world: World
    views: SceneViews
    lights: LightSet
    light: np.ndarray
    objects: list[PRTObject]
    occluder: mi.Scene | None
    field: OcclusionField | None
    face_offset: mi.UInt32
    faces: mi.UInt32
    env: MipEnvironment | None = None
    sog: SoGTables | None = None
    ks: mi.Color3f | None = None

    def vertex_values(self, order: int | None = None) -> list[np.ndarray]:
        """Per object ``Σ_k t_k l_k`` per vertex ``(V, 3)`` this frame."""
        return [vertex_values(o.transfer, self.light, o.rotation, order) for o in self.objects]


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


def prepare(world: World, options: Options, cache_dir: Path | None = None) -> PRTData:
    """Transfer (cached), light SH, reduced lights and occlusion field of ``world``; with
    ``glossy`` the mip-mapped environment and the SoG tables (:func:`glossy_tables`)."""
    from arlight.cache import default_cache_dir

    views = build_views(world)
    lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
    objects = []
    cache = (cache_dir or default_cache_dir()) if options.cache else None
    loaded = {sh.id(): sh for sh in views.mixed.scene.shapes()}
    for i, s in enumerate(world.shapes):
        if not s.is_virtual:
            continue
        mesh, faces = object_mesh(s, loaded.get(str(i)))
        try:
            rot = rotation_part(s.to_world)
            tr = cached_transfer(mesh, cache, options.order, options.directions,
                                 options.bounces, s.material.params.get(
                                     "albedo", s.material.params.get("kd", [0.5] * 3)),
                                 s.name, progress_bar(f"prt {s.name}"),
                                 shadowed=options.shadowed)
        except ValueError as exc:
            raise InputError(str(exc), field=f"shapes.{s.name}") from exc
        objects.append(PRTObject(i, tr, rot, faces))
    occluder = virtual_scene(world)
    field = field_from_options(world, options) if occluder is not None else None
    offs = np.zeros(max(len(world.shapes), 1), np.uint32)
    base_v, base_f, all_f = 0, 0, []
    for o in objects:
        offs[o.shape] = base_f
        all_f.append(o.faces + base_v)
        base_v += o.transfer.vertices
        base_f += len(o.faces)
    faces = np.concatenate(all_f).astype(np.uint32).reshape(-1) if all_f else np.zeros(3,
                                                                                        np.uint32)
    centre = np.zeros(3)
    if occluder is not None:
        b = occluder.bbox()
        centre = (np.array([b.min.x, b.min.y, b.min.z]) + np.array([b.max.x, b.max.y,
                                                                    b.max.z])) / 2.0
    env, sog, ks = glossy_tables(world) if options.glossy else (None, None, None)
    return PRTData(world, views, lights, light_sh(world, options.order, centre,
                                                  options.area_grid),
                   objects, occluder, field, mi.UInt32(offs), mi.UInt32(faces), env, sog, ks)


def glossy_tables(world: World) -> tuple[MipEnvironment | None, SoGTables | None,
                                         mi.Color3f | None]:
    """The mip-mapped environment (as ``ibl`` builds it), the per-shape SoG tables and the
    specular reflectance ``F0`` per shape (``ibl.specular_tables``: phong ``α = √(2/(n+2))``,
    ``ks``; roughconductor ``alpha``, ``reflectance``); all None without a distant light or
    a glossy virtual shape."""
    env_img = environment_map(world)
    alpha, ks, glossy = specular_tables(world)
    if env_img is None or not glossy:
        return None, None, None
    a, k = np.asarray(alpha, np.float64), np.asarray(ks, np.float64).reshape(-1, 3)
    alphas = [float(a[i]) if s.is_virtual and np.any(k[i]) else None
              for i, s in enumerate(world.shapes)]
    return MipEnvironment.build(env_img), SoGTables.build(alphas), ks


def unshadowed(light: np.ndarray, n: mi.Vector3f, order: int) -> mi.Color3f:
    """``E(n)/π``: the unshadowed diffuse transfer of radiance SH ``light`` (truncated to
    ``order``) at unit world normals ``n`` (W/(sr·m²) per unit albedo)."""
    if order <= 2:
        sh9 = np.zeros((9, 3))
        sh9[:min(9, len(light))] = light[:9]
        return ambient_irradiance_dr(LightSet([], sh9), n) * (1.0 / math.pi)
    e = irradiance(light, np3(n),
                   max_order=order) / math.pi
    return mi.Color3f(*[mi.Float(e[:, c].astype(np.float32)) for c in range(3)])


def self_shadowing(shadowed: mi.Color3f, free: mi.Color3f) -> mi.Float:
    """Low-frequency self-shadowing factor of the glossy term: the ratio of the shadowed
    (PRT) to the unshadowed diffuse transfer at the pixel, summed over RGB, clamped to
    [0, 1] (1 where the unshadowed value vanishes)."""
    num = shadowed.x + shadowed.y + shadowed.z
    den = free.x + free.y + free.z
    return dr.select(den > 1e-8, dr.clip(num / dr.maximum(den, 1e-8), 0.0, 1.0), 1.0)


def shade_virtual(data: PRTData, gb: GBuffer, view: FrameView, options: Options,
                  seed: int = 0) -> tuple[mi.Color3f, mi.UInt32]:
    """Radiance (W/(sr·m²)) of the virtual lanes: vertex values (light rotated into each
    object's frame) interpolated with the barycentrics of the lanes' primary hits, times the
    albedo; plus, with ``glossy``, the SoG specular term times the self-shadowing factor
    (module docstring)."""
    idx = dr.compress(gb.virtual)
    if dr.width(idx) == 0 or not data.objects:
        return dr.zeros(mi.Color3f, 0), dr.zeros(mi.UInt32, 0)
    vals = np.concatenate(data.vertex_values(options.order)).astype(np.float32)
    table = mi.Float(vals.reshape(-1))
    k = idx % gb.spp
    ray = mi.Ray3f(generate_rays(view.camera, dr.gather(mi.UInt32, gb.pixel, idx), k,
                                 gb.spp, mi.UInt32(seed)))
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


class PRTMethod(BaseMethod):
    """Per-vertex SH PRT for rigid virtual objects with AR object occlusion fields."""

    spec = SPEC

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> PRTData:
        return prepare(world, options)

    def render_view(self, data: PRTData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        layers = render_layers(data, view, options, settings, timer, shade_virtual)
        n_v = sum(o.transfer.vertices for o in data.objects)
        secs = sum(o.transfer.seconds for o in data.objects)
        layers.stats["prt_vertices"] = float(n_v)
        layers.stats["prt_seconds_per_vertex"] = secs / n_v if n_v else 0.0
        return layers


__all__ = ["OPTIONS", "PRTData", "PRTMethod", "PRTObject", "SPEC", "glossy_tables", "light_sh",
           "object_mesh", "prepare", "self_shadowing", "shade_virtual", "unshadowed"]
