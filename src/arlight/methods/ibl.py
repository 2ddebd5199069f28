"""``ibl``: the *dynamic pipeline* of Franke thesis §4.2 with AR-OOF relighting (§5.2).

Per frame:

1. a ray-cast G-buffer (:mod:`arlight.realtime.gbuffer`);
2. **virtual pixels** (compacted): ``ρ/π (E_dir + A · E_amb(n)) + S``, where

   * ``E_dir`` — the reduced lights (:mod:`arlight.realtime.light_reduction`: point, spot,
     area patches and the environment's brightest regions as directional lights) with one
     shadow ray each in the mixed scene;
   * ``E_amb(n)`` — SH irradiance of the ambient remainder, order ``sh_order`` (2: Ramamoorthi
     & Hanrahan's 9 coefficients, thesis Eqs. 4.4–4.9; higher orders are the map's SH minus
     the SH of the extracted lights);
   * ``A`` — ray-traced ambient occlusion of the virtual objects (Eq. 2.29, ``ao_rays``);
   * ``S`` — GGX specular of the environment by the split sum (Karis 2013; issue #33): the
     map prefiltered per roughness level (``samples`` = 64 importance samples per texel, once
     per map) times ``F0 A + F90 B`` from the DFG table, times the AO-derived specular
     occlusion (option ``specular_occlusion``), for ``phong`` (``α = √(2/(n+2))``),
     ``roughconductor``, ``mirror`` and ``pbr`` materials (``pbr``: one diffuse and one GGX
     lobe per shape with Schlick's Fresnel to ``F90 = 1``,
     :func:`arlight.realtime.ibl_shading.pbr_lobes`; no normal map); point, spot, area and
     sun lights add their GGX reflection per pixel through their shadow ray;
   * the ambient SH includes the bounce probe (option ``probe``): the change the
     reconstructed real scene makes to the distant light at the objects
     (:func:`arlight.realtime.ibl_shading.bounce_probe`, recomputed per pose);
3. **real pixels** (:func:`arlight.realtime.oof.shade_real`): ``B · f`` with the
   multiplicative shadow factor of :func:`arlight.realtime.oof.shadow_factor` — shadow rays
   for the reduced lights, the AR object occlusion field for the ambient part;
   ``delta = B (f − 1) ≤ 0``.

The frame (G-buffer, both shadings, assembly) is :func:`arlight.realtime.oof.render_layers`,
shared with ``prt``; the GGX tables per shape are
:func:`arlight.realtime.ibl_shading.specular_tables`.

Layers: ``mixed`` is the shaded virtual object on virtual pixels and ``B + delta``
elsewhere; ``delta`` the darkening; ``mask`` the G-buffer coverage. Without virtual objects
``delta`` is exactly zero. Stats: ``time_gbuffer``, ``time_shade_virtual``,
``time_shade_real``, ``time_assemble`` (s), ``virtual_lanes``, ``lights``. See
``docs/methods/ibl.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews, build_views
from arlight.backend.rays import np3
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
)
from arlight.methods.fragments import GBUFFER_OPTIONS, REDUCTION_OPTIONS, place_occluded
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.ambient import ao_distance
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.ibl_shading import (
    PROBE_OPTIONS,
    MipEnvironment,
    SpecularTables,
    ambient_occlusion,
    dfg_table,
    diffuse_weights,
    environment_map,
    prefilter_ggx,
    probe_drag_options,
    probe_for_world,
    specular_occlusion,
    specular_split_sum,
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
from arlight.realtime.shading import (
    ambient_irradiance_dr,
    direct_light,
    split_lights,
)
from arlight.scene.model import FrameView, World
from arlight.sphere.sh import directional_light_coeffs, irradiance, n_coeffs, project_equirect
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "sh_order": Field("int", 2, "SH order of the ambient irradiance (2: the 9 coefficients of "
                      "Ramamoorthi & Hanrahan)", "", min=0, max=8),
    "samples": Field("int", 64, "GGX importance samples per texel of the prefiltered "
                     "environment (split sum, computed once per map)", "", min=1, max=1024),
    "specular_occlusion": Field("bool", True, "darken the environment's specular by the "
                                "AO-derived specular occlusion (Lagarde & de Rousiers 2014)"),
    "ao_rays": Field("int", 16, "ambient-occlusion rays per virtual pixel (0: no AO)", "",
                     min=0, max=1024),
    "ao_distance": Field("float", 0.0, "longest AO ray; 0: the virtual objects' bounding "
                         "diameter", "m", min=0.0),
    **PROBE_OPTIONS,
    **OOF_OPTIONS,
    **REDUCTION_OPTIONS,
    "area_grid": Field("int", 3, "cosine point lights per side of an area light (3 × 3: a "
                       "soft shadow; bunny-box +0.45 dB over 1)", "", min=1, max=16),
    **GBUFFER_OPTIONS,
}

MATERIALS = frozenset({"diffuse", "phong", "roughconductor", "mirror", "pbr"})
"""``pbr`` is approximated by one diffuse and one GGX lobe per shape
(:func:`arlight.realtime.ibl_shading.pbr_lobes`): no normal map, constant metallic and
roughness (texture means)."""
SPEC = MethodSpec(
    name="ibl",
    description="Dynamic pipeline (Franke §4.2): SH irradiance, GGX filtered importance "
                "sampling, AO; AR-OOF shadows on real surfaces; real time.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, materials=MATERIALS,
                              lights=REDUCIBLE_LIGHTS),
    drag_options=probe_drag_options,
)


def ambient_sh(world: World, lights: LightSet, order: int, env: np.ndarray | None
               ) -> np.ndarray:
    """Radiance SH ``(n, 3)`` of the light that is not in the reduced lights, to ``order``:
    the reduction's remainder for ``order <= 2``, above that the environment's SH minus the
    SH of the directional lights extracted from it (the lights plus the remainder partition
    the map, :mod:`arlight.light.extract`)."""
    if order <= 2 or env is None:
        out = np.zeros((n_coeffs(order), 3))
        k = min(n_coeffs(order), 9)
        out[:k] = lights.ambient_sh[:k]
        return out
    names = {lt.name or f"light{i}" for i, lt in enumerate(world.lights)
             if lt.type in ("envmap", "sh", "constant")}
    out = project_equirect(np.asarray(env, np.float64), order)
    for lt in lights.lights:
        if lt.kind == "directional" and lt.source in names:
            out -= directional_light_coeffs(-np.asarray(lt.axis), lt.intensity, order)
    return out


@dataclass
class IBLData:
    """What ``prepare_world`` keeps (see the module docstring)."""

    world: World
    views: SceneViews
    lights: LightSet
    ambient: np.ndarray
    env: MipEnvironment | None  # GGX-prefiltered per roughness level (prefilter_ggx)
    occluder: Occluder | None
    field: OcclusionField | None
    spec: SpecularTables
    ao_distance: float
    kd_weight: mi.Float | None = None  # per shape, on the G-buffer albedo (pbr metals)
    dfg: mi.Float | None = None  # the split-sum DFG table (dfg_table), flattened
    env_map: np.ndarray | None = None  # environment_map(world)
    ambient_env: np.ndarray | None = None  # ambient SH without the probe


def prepare(world: World, options: Options) -> IBLData:
    """Mitsuba views, reduced lights, ambient SH, the GGX-prefiltered environment and the
    DFG table (split sum; only with a glossy virtual shape), the virtual occluder and its
    occlusion field."""
    views = build_views(world)
    lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
    env_img = environment_map(world)
    spec = specular_tables(world)
    env = (prefilter_ggx(env_img, options.samples)
           if env_img is not None and spec.glossy else None)
    occluder = make_occluder(world)
    field = field_from_options(world, options) if occluder is not None else None
    dfg = mi.Float(dfg_table().reshape(-1)) if spec.glossy else None
    ambient = ambient_sh(world, lights, options.sh_order, env_img)
    return IBLData(world, views, lights, ambient + _probe_sh(world, views, env_img, options),
                   env, occluder, field, spec, _ao_distance(world, views, options),
                   diffuse_weights(world), dfg, env_img, ambient)


def _probe_sh(world: World, views: SceneViews, env_img: np.ndarray | None, options: Options
              ) -> np.ndarray | float:
    """Radiance SH, order ``sh_order``, of the bounce probe's diffuse change at the virtual
    objects (:func:`~arlight.realtime.ibl_shading.probe_for_world`; 0 without one)."""
    probe = probe_for_world(world, views, env_img, options, options.env_lights)
    if probe is None:
        return 0.0
    return project_equirect(probe.diffuse.astype(np.float64), options.sh_order)


def _ao_distance(world: World, views: SceneViews, options: Options) -> float:
    """The AO ray length (m): the option, or the diagonal of the virtual objects' box."""
    if options.ao_distance > 0.0:
        return float(options.ao_distance)
    return ao_distance(world, views.mixed)


def pose(data: IBLData, world: World, transforms: dict[str, np.ndarray], options: Options
         ) -> IBLData | None:
    """``data`` (prepared for ``world`` in any pose) moved in place to
    ``world.posed(transforms)`` (issue #32): the shapes move in the Mitsuba views; the
    object-space occluder and occlusion field are looked up through the new pose
    (:func:`~arlight.realtime.oof.move_occluder`, :func:`~arlight.realtime.oof.pose_field`;
    with several virtual shapes the world-space occluder's shapes move in place and the
    world-space field is sampled again when a virtual shape moved); lights, environment
    and tables are kept, the bounce probe traced again (kept with ``probe_follow`` off).
    Bitwise the data :func:`prepare` makes of the posed world (with ``probe_follow`` on);
    None (nothing changed) when a real shape moves."""
    moved = place_occluded(data.views, data.occluder, world, data.world, transforms)
    if moved is None:
        return None
    posed, occluder = moved
    ambient = (data.ambient_env + _probe_sh(posed, data.views, data.env_map, options)
               if options.probe_follow else data.ambient)
    return replace(data, world=posed, occluder=occluder, ambient=ambient,
                   field=pose_field(data.field, posed, options, data.world),
                   ao_distance=_ao_distance(posed, data.views, options))


def ambient_irradiance(data: IBLData, n: mi.Vector3f, order: int) -> mi.Color3f:
    """SH irradiance of the ambient light at unit normals ``n`` (W/m², ≥ 0): order ≤ 2 as
    Dr.Jit polynomial (:func:`arlight.realtime.shading.ambient_irradiance_dr`), higher
    orders through :func:`arlight.sphere.sh.irradiance`."""
    if order <= 2:
        sh9 = np.zeros((9, 3))
        sh9[:len(data.ambient)] = data.ambient[:9]
        return dr.maximum(ambient_irradiance_dr(LightSet([], sh9), n), 0.0)
    e = np.maximum(irradiance(data.ambient, np3(n), max_order=order), 0.0).astype(np.float32)
    return mi.Color3f(e[:, 0], e[:, 1], e[:, 2])


def shade_virtual(data: IBLData, gb: GBuffer, view: FrameView, options: Options,
                  seed: int = 0) -> tuple[mi.Color3f, mi.UInt32]:
    """Radiance (W/(sr·m²)) of the virtual lanes and their lane indices."""
    idx = dr.compress(gb.virtual)
    if dr.width(idx) == 0:
        return dr.zeros(mi.Color3f, 0), idx
    p = dr.gather(mi.Point3f, gb.position, idx)
    n = dr.gather(mi.Vector3f, gb.normal, idx)
    shape = dr.gather(mi.Int32, gb.shape, idx)
    glossy = virtual_glossy(data.spec, gb, idx, shape) if data.spec.glossy else None
    far, near = split_lights(data.world, data.lights)
    e_far, _ = direct_light(data.views.mixed, far, p, n, mi.Bool(True))
    e_near, s_near = direct_light(data.views.mixed, near, p, n, mi.Bool(True),
                                  specular=None if glossy is None else glossy.reflectance(n))
    ao = ambient_occlusion(data.occluder, p, n, options.ao_rays, data.ao_distance, seed)
    albedo = dr.gather(mi.Color3f, gb.albedo, idx)
    if data.kd_weight is not None:
        albedo *= dr.gather(mi.Float, data.kd_weight, shape)
    out = albedo * (1.0 / math.pi) * (e_far + e_near + ao * ambient_irradiance(
        data, n, options.sh_order))
    if s_near is not None:
        out += s_near
    if glossy is not None and data.env is not None and data.dfg is not None:
        env = specular_split_sum(data.env, data.dfg, n, glossy.v, glossy.alpha, glossy.f0,
                                 glossy.f90)
        if options.specular_occlusion:
            env *= specular_occlusion(dr.dot(n, glossy.v), ao, glossy.alpha)
        out += env
    dr.eval(out)
    return out, idx


class IBLMethod(BaseMethod):
    """Dynamic IBL pipeline with AR object occlusion fields (Franke §4.2, §5.2)."""

    spec = SPEC
    incremental_pose = True

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> IBLData:
        return prepare(world, options)

    move = staticmethod(pose)  # in place; a moved real shape prepares again

    def relit(self, data: IBLData, world: World, options: Options) -> IBLData | None:
        """Light update (issue #32, :meth:`BaseMethod.relight`): the views' emitters set in
        place, the lights reduced again, the ambient SH projected again and the bounce probe
        traced again (it sees the moved lamps); the occluder, its occlusion field, the
        environment and the material tables are kept. None
        (prepare again) when a distant light changed: the environment is made from it."""
        from arlight.methods.base import distant_changed, relight_views

        if distant_changed(data.world.lights, world.lights) or not relight_views(
                data.views, data.world.lights, world.lights):
            return None
        lights = reduce_lights(world, env_lights=options.env_lights, area_grid=options.area_grid)
        ambient_env = ambient_sh(world, lights, options.sh_order, data.env_map)
        # the probe sees the real scene, whose lamps just moved in place: traced again
        return replace(data, world=world, lights=lights, ambient_env=ambient_env,
                       ambient=ambient_env + _probe_sh(world, data.views, data.env_map,
                                                       options))

    def render_view(self, data: IBLData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        return render_layers(data, view, options, settings.seed, timer, shade_virtual)


__all__ = ["IBLData", "IBLMethod", "OPTIONS", "SPEC", "ambient_irradiance", "ambient_sh",
           "prepare", "shade_virtual"]
