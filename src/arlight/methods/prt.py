"""``prt``: the *rigid pipeline* of Franke thesis §4.3 with AR-OOF relighting (§5.2).

* **prepare** (once per world and mesh content): per virtual mesh the per-vertex diffuse
  transfer (:mod:`arlight.realtime.prt_transfer`: ray-traced self-occlusion, optional diffuse
  inter-reflection, ``order`` 2 or 3 → 9 or 16 SH coefficients), cached on disk by the mesh's
  content hash, with a progress bar on a terminal; the world's *distant* light as radiance
  SH (environment maps projected exactly and rotated by their ``rotation_deg``, constant
  skies) plus the bounce probe's SH (:func:`arlight.realtime.ibl_shading.bounce_probe`, the
  real scene's change to it at the objects, recomputed per pose); the reduced lights and
  occlusion field of the real-surface relighting (as ``ibl``).
* **local lights** (issue #33): point, spot, area and directional world lights are shaded
  per pixel with one shadow ray each (:func:`shade_prt`), diffuse and GGX — not folded into
  SH at the objects' centre (no fall-off across the object, smeared self-shadows).
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
  unshadowed SH irradiance ``u = E(n)/π`` of the same light at its normal. The SoG term
  reflects the environment map; local lights add their GGX reflection in :func:`shade_prt`.

The transfer and face tables of the meshes (:func:`arlight.realtime.prt_shading.prt_meshes`)
and the per-frame shading of the virtual pixels
(:func:`arlight.realtime.prt_shading.shade_virtual`) are shared with ``nearfield``; the frame
(G-buffer, shading, AR-OOF relighting, assembly) with ``ibl``
(:func:`arlight.realtime.oof.render_layers`). Moving the object
(``view.object_transforms``) re-uses the cached transfer: only the light rotation changes.
Stats: ``time_gbuffer``, ``time_shade_virtual`` (the per-frame PRT shading),
``time_shade_real``, ``time_assemble``; ``prt_vertices``, ``prt_seconds_per_vertex`` (the
precomputation, 0 when cached). See ``docs/methods/prt.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
)
from arlight.methods.fragments import GBUFFER_OPTIONS, REDUCTION_OPTIONS, place_occluded
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.ibl_shading import (
    PROBE_OPTIONS,
    MipEnvironment,
    SpecularTables,
    environment_map,
    probe_drag_options,
    probe_for_world,
    rot_y,
    specular_tables,
    virtual_glossy,
)
from arlight.realtime.light_reduction import REDUCIBLE_LIGHTS, LightSet, reduce_lights
from arlight.realtime.oof import (
    OOF_OPTIONS,
    Occluder,
    OcclusionField,
    field_from_options,
    make_occluder,
    pose_field,
    render_layers,
)
from arlight.realtime.prt_shading import (
    PRTObject,
    prt_meshes,
    shade_virtual,
)
from arlight.realtime.prt_transfer import rotation_part, vertex_values
from arlight.realtime.shading import direct_light, split_lights
from arlight.realtime.sog import SoGTables
from arlight.scene.model import FrameView, World
from arlight.sphere.sh import n_coeffs, project_equirect, rotate
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
    **PROBE_OPTIONS,
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
                              materials=frozenset({"diffuse", "phong", "roughconductor"}),
                              # per-vertex transfer: analytic spheres and disks have no
                              # vertices (realtime.prt_shading.object_mesh)
                              virtual_shapes=frozenset({"mesh", "box", "rectangle"}),
                              lights=REDUCIBLE_LIGHTS),
    drag_options=probe_drag_options,
)


def distant_sh(world: World, order: int) -> np.ndarray:
    """Radiance SH ``((order+1)², 3)`` of the world's distant lights (environment maps,
    projected then rotated exactly, so turning a map by ``rotation_deg`` turns its SH
    exactly; constant skies): the part of :func:`light_sh` that no position changes."""
    out = np.zeros((n_coeffs(order), 3))
    for lt in world.lights:
        if lt.type in ("envmap", "sh"):
            sh = project_equirect(np.asarray(lt.radiance_map, np.float64)[..., :3], order)
            sh *= float(lt.params.get("scale", 1.0))
            out += rotate(sh, rot_y(float(lt.params.get("rotation_deg", 0.0))))
        elif lt.type == "constant":
            out[0] += np.asarray(lt.params["radiance"], np.float64) * math.sqrt(4 * math.pi)
    return out


@dataclass
class PRTData:
    """What ``prepare_world`` keeps (see the module docstring)."""

    world: World
    views: SceneViews
    lights: LightSet
    light: np.ndarray
    objects: list[PRTObject]
    occluder: Occluder | None
    field: OcclusionField | None
    face_offset: mi.UInt32
    faces: mi.UInt32
    env: MipEnvironment | None = None
    sog: SoGTables | None = None
    ks: mi.Color3f | None = None
    distant: np.ndarray | None = None  # distant_sh: the light SH no pose changes
    spec: SpecularTables | None = None  # GGX tables of the local lights' specular

    def vertex_values(self, order: int | None = None) -> list[np.ndarray]:
        """Per object ``Σ_k t_k l_k`` per vertex ``(V, 3)`` this frame."""
        return [vertex_values(o.transfer, self.light, o.rotation, order) for o in self.objects]


def prepare(world: World, options: Options, cache_dir: Path | None = None) -> PRTData:
    """Transfer (cached), light SH, reduced lights and occlusion field of ``world``; with
    ``glossy`` the mip-mapped environment and the SoG tables (:func:`glossy_tables`)."""
    from arlight.cache import default_cache_dir

    views = build_views(world)
    lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
    cache = (cache_dir or default_cache_dir()) if options.cache else None
    meshes = prt_meshes(world, views, cache, options.order, options.directions,
                        options.bounces, options.shadowed)
    occluder = make_occluder(world)
    field = field_from_options(world, options) if occluder is not None else None
    env, sog, ks = glossy_tables(world) if options.glossy else (None, None, None)
    distant = distant_sh(world, options.order)
    return PRTData(world, views, lights, distant + _probe_sh(world, views, options),
                   meshes.objects, occluder, field,
                   meshes.face_offset, meshes.faces, env, sog, ks, distant,
                   specular_tables(world))


def _probe_sh(world: World, views: SceneViews, options: Options) -> np.ndarray | float:
    """Radiance SH, order ``order``, of the bounce probe's change of the distant light at the
    virtual objects (:func:`~arlight.realtime.ibl_shading.probe_for_world`; 0 without
    one)."""
    probe = probe_for_world(world, views, environment_map(world), options)
    if probe is None:
        return 0.0
    return project_equirect(probe.full.astype(np.float64), options.order)


def pose(data: PRTData, world: World, transforms: dict[str, np.ndarray], options: Options
         ) -> PRTData | None:
    """``data`` (prepared for ``world`` in any pose) moved in place to
    ``world.posed(transforms)`` (issue #32): the shapes move in the Mitsuba views; each
    object keeps its object-space transfer and takes its new rotation; the light SH is
    measured from the new centre (distant part kept); occluder and occlusion field are
    looked up through the new pose (:func:`~arlight.realtime.oof.move_occluder`,
    :func:`~arlight.realtime.oof.pose_field`). Bitwise the
    data :func:`prepare` makes of the posed world; None (nothing changed) when a real shape
    moves or a virtual primitive (its object mesh is read back from the loaded mesh) does."""
    if any(world.shapes[o.shape].mesh is None for o in data.objects):
        return None
    moved = place_occluded(data.views, data.occluder, world, data.world, transforms)
    if moved is None:
        return None
    posed, occluder = moved
    objects = [replace(o, rotation=rotation_part(posed.shapes[o.shape].to_world))
               for o in data.objects]
    light = (data.distant + _probe_sh(posed, data.views, options) if options.probe_follow
             else data.light)
    return replace(data, world=posed, objects=objects, light=light, occluder=occluder,
                   field=pose_field(data.field, posed, options, data.world))


def glossy_tables(world: World) -> tuple[MipEnvironment | None, SoGTables | None,
                                         mi.Color3f | None]:
    """The mip-mapped environment (as ``ibl`` builds it), the per-shape SoG tables and the
    specular reflectance ``F0`` per shape
    (:func:`arlight.realtime.ibl_shading.specular_tables`: phong ``α = √(2/(n+2))``,
    ``ks``; roughconductor ``alpha``, ``reflectance``); all None without a distant light or
    a glossy virtual shape."""
    env_img = environment_map(world)
    spec = specular_tables(world)
    if env_img is None or not spec.glossy:
        return None, None, None
    a, k = np.asarray(spec.alpha, np.float64), np.asarray(spec.f0, np.float64).reshape(-1, 3)
    alphas = [float(a[i]) if s.is_virtual and np.any(k[i]) else None
              for i, s in enumerate(world.shapes)]
    return MipEnvironment.build(env_img), SoGTables.build(alphas), spec.f0


def shade_prt(data: PRTData, gb: GBuffer, view: FrameView, options: Options, seed: int = 0
              ) -> tuple[mi.Color3f, mi.UInt32]:
    """Radiance (W/(sr·m²)) of the virtual lanes: the PRT shading of the distant light
    (:func:`arlight.realtime.prt_shading.shade_virtual`) plus the local lights (point, spot,
    area patches, sun) per pixel with one shadow ray each in the mixed scene
    (:func:`arlight.realtime.shading.direct_light`): ``ρ/π Σ_i V_i E_i <n,ω_i>+`` and, for
    glossy shapes, their GGX reflection (:func:`~arlight.realtime.ibl_shading.
    ggx_reflectance`) — the fall-off across the object and sharp self-shadows that an SH
    light seen from the object's centre cannot give."""
    rad, idx = shade_virtual(data, gb, view, options, seed)
    _, near = split_lights(data.world, data.lights)
    if dr.width(idx) == 0 or not near.lights:
        return rad, idx
    p = dr.gather(mi.Point3f, gb.position, idx)
    n = dr.gather(mi.Vector3f, gb.normal, idx)
    shape = dr.gather(mi.Int32, gb.shape, idx)
    glossy = virtual_glossy(data.spec, gb, idx, shape) if data.spec.glossy else None
    e, s = direct_light(data.views.mixed, near, p, n, mi.Bool(True),
                        specular=None if glossy is None else glossy.reflectance(n))
    rad = rad + dr.gather(mi.Color3f, gb.albedo, idx) * (1.0 / math.pi) * e
    if s is not None:
        rad += s
    dr.eval(rad)
    return rad, idx


class PRTMethod(BaseMethod):
    """Per-vertex SH PRT for rigid virtual objects with AR object occlusion fields."""

    spec = SPEC
    incremental_pose = True

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> PRTData:
        return prepare(world, options)

    move = staticmethod(pose)  # in place; a moved real shape prepares again

    def relit(self, data: PRTData, world: World, options: Options) -> PRTData | None:
        """Light update (issue #32, :meth:`BaseMethod.relight`): the views' emitters set in
        place, the lights reduced again and the bounce probe traced again (it sees the moved
        lamps); the transfer, the distant lights' SH, the occluder, its occlusion field and
        the glossy tables are kept. None
        (prepare again) when a distant light changed."""
        from arlight.methods.base import distant_changed, relight_views

        if distant_changed(data.world.lights, world.lights) or not relight_views(
                data.views, data.world.lights, world.lights):
            return None
        # the probe sees the real scene, whose lamps just moved in place: traced again
        return replace(data, world=world, lights=reduce_lights(
            world, env_lights=options.env_lights, area_grid=options.area_grid),
            light=data.distant + _probe_sh(world, data.views, options))

    def render_view(self, data: PRTData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        layers = render_layers(data, view, options, settings.seed, timer, shade_prt)
        n_v = sum(o.transfer.vertices for o in data.objects)
        secs = sum(o.transfer.seconds for o in data.objects)
        layers.stats["prt_vertices"] = float(n_v)
        layers.stats["prt_seconds_per_vertex"] = secs / n_v if n_v else 0.0
        return layers


__all__ = ["OPTIONS", "PRTData", "PRTMethod", "SPEC", "distant_sh", "glossy_tables", "pose",
           "prepare", "shade_prt"]
