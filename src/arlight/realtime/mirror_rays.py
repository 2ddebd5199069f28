"""Traced reflections of near-mirror lanes (issue #33, dvct's virtual mirror).

Franke's specular cone (thesis Eq. 5.22 / 5.25) reads the voxel volume along the reflected
view direction with a full aperture ``β = 2 atan(α)``; a mirror (GGX ``α → 0``) gets dvct's
smallest aperture, and what the cone meets inside the volume is ``V_ρ``/``V_Δ`` — the first
bounce of the *reduced* lights in cells a few centimetres wide. A virtual mirror that looks at
the real floor therefore shows a blurred floor lit by the reduced lights alone (the
environment's share of the floor's light, most of it outdoors, is in no volume), and the
cone's transmittance ``1 − α_all`` hides the photograph of the floor beyond it: on held-out
world-1000009 the mirror cube's lower half came out black (see docs/methods/dvct.md).

For lanes whose GGX ``α`` is at most ``mirror_alpha`` (dvct's option) this module replaces
the cone by **one ray along the mirror direction** ``r = 2 <v,n> n − v`` into the *mixed*
proxy scene and shades what it meets as dvct shades that surface:

* **miss**: the distant light, the split-sum ``L̃(r, α) (F0 A + F90 B)`` of the prefiltered
  environment ([Kar13]; :func:`~arlight.realtime.ibl_shading.specular_split_sum`);
* **a real surface the camera sees** (the hit's projection unoccluded in the real proxy, as
  onepass reprojects, Kán §5.2): the photograph ``B`` there plus the change of its direct
  light, ``ρ̂/π (E_ρ − E_µ)`` — the reduced lights with shadow rays in the mixed and in the
  real proxy at the hit, ``ρ̂`` the albedo read from the photograph
  (:func:`~arlight.realtime.photo_albedo.photo_albedo`), as dvct changes its real pixels:
  the virtual objects' shadows on the floor the mirror shows, also where the camera's own
  lane there is covered by a virtual object — times the lane's directional albedo
  ``F0 A + F90 B``;
* **a real surface the camera does not see, or a virtual surface**: its radiance shaded
  locally, ``ρ/π (E_direct + E_amb)`` (the reduced lights with shadow rays in the mixed scene,
  the SH remainder unoccluded) plus its own glossy reflection of the distant light
  (split-sum at the hit, view ``−r``; no further rays), times ``F0 A + F90 B``.

On real lanes (a real mirror or glossy floor under a virtual object) the ray changes the
reflection. A perfect mirror's photograph ``B`` is the radiance along the ray: where the ray
meets a virtual surface, ``h B`` is hidden (``a = 1``, §5.4.2's occlusion weighting) and the
surface's radiance times ``F0 A + F90 B`` takes its place (:func:`~arlight.methods.dvct.
mirror_terms`). A rougher lobe's photograph also holds light from directions the one ray
does not test — a lamp's glossy highlight around the object's reflection, which hiding
``h B`` blacked out (training world-53: a floating dragon's reflection black on the halo of
a small bright lamp; ``tests/methods/test_dvct_mirror.py``) — so it keeps ``B`` and gains
the difference of what the ray meets in the mixed and in the real scene (Debevec's
differential rendering along the one ray), ``(F0 A + F90 B)(L_µ(r) − L_ρ(r))``: the virtual
surface's radiance minus what the same ray meets in the real proxy (the photograph where the
camera sees that real surface, else the surface shaded locally, and for a miss the
prefiltered environment ``L̃(r, α)``, also where no virtual shape is glossy and dvct keeps
none). Where the ray meets a real surface the camera sees, the reflection keeps the
photograph and gains the change there (times ``F0 A + F90 B``).

The ray carries the radiance along the mirror direction only: for ``α > 0`` the lobe's
blur of what is hit is lost (the miss keeps the prefiltered environment), which is why the
threshold is an option chosen on training worlds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_REAL, ROLE_VIRTUAL, SceneViews
from arlight.backend.reproject import Reprojector
from arlight.realtime.gbuffer import facing, surface_albedo
from arlight.realtime.ibl_shading import (
    MipEnvironment,
    SpecularTables,
    dfg_lookup,
    dfg_table,
    environment_map,
    ggx_reflectance,
    prefilter_ggx,
    specular_split_sum,
    specular_tables,
)
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.photo_albedo import photo_albedo
from arlight.realtime.shading import (
    ambient_irradiance_dr,
    direct_irradiance,
    direct_light,
    split_lights,
)
from arlight.realtime.shadow_reach import shadow_reach


@dataclass
class MirrorLight:
    """What a mirror ray's hit is shaded with: the ``views`` (the ray is cast in
    ``views.mixed``), the reduced ``lights`` (direct light at hits, with shadow rays) and their
    SH remainder, the per-shape GGX ``tables``, the split-sum ``dfg`` table, the prefiltered
    environment ``env`` (None: no distant light, a miss sees nothing), the reduced lights
    ``near`` that are not part of the environment (their glossy highlight on a real lane is
    direct light, :func:`~arlight.realtime.shading.split_lights`) and per shape index whether
    the shape is ``real``."""

    views: SceneViews
    lights: LightSet
    tables: SpecularTables
    dfg: mi.Float
    env: MipEnvironment | None
    near: LightSet
    real: mi.Bool


    @staticmethod
    def of(views: SceneViews, lights: LightSet, world: object, distant: object | None
           ) -> MirrorLight:
        """From dvct's :class:`~arlight.methods.dvct.DistantLight` ``distant`` (its tables,
        DFG table and environment), or without one (no glossy virtual shape) the tables of
        ``world`` and its environment prefiltered as dvct's (``prefilter_ggx``, cached by
        the map's content; dvct builds this once per world and lighting): a real
        lane's ray that meets a virtual surface hides the environment it reflected."""
        real = mi.Bool([not s.is_virtual for s in world.shapes])
        if distant is not None:
            return MirrorLight(views, lights, distant.tables, distant.dfg, distant.env,
                               distant.near, real)
        img = environment_map(world)
        return MirrorLight(views, lights, specular_tables(world),
                           mi.Float(dfg_table().reshape(-1)),
                           None if img is None else prefilter_ggx(img),
                           split_lights(world, lights)[1], real)


def lobe_albedo(light: MirrorLight, n: mi.Vector3f, v: mi.Vector3f, shape: mi.UInt32
                ) -> mi.Color3f:
    """The GGX lobe's directional albedo ``F0 A + F90 B`` (the split sum's second factor,
    :func:`~arlight.realtime.ibl_shading.dfg_table`) of ``shape`` at ``<n, v>``: the weight
    of the radiance along the mirror direction (for a perfect mirror of reflectance ``k``,
    ``k``)."""
    nv = dr.maximum(dr.dot(n, v), 1e-4)
    alpha = dr.gather(mi.Float, light.tables.alpha, shape)
    a, b = dfg_lookup(light.dfg, nv, dr.sqrt(dr.maximum(alpha, 0.0)))
    return (dr.gather(mi.Color3f, light.tables.f0, shape) * a
            + dr.gather(mi.Color3f, light.tables.f90, shape) * b)


def distant_specular(light: MirrorLight, n: mi.Vector3f, v: mi.Vector3f, shape: mi.UInt32
                     ) -> mi.Color3f:
    """The split-sum specular radiance of the distant light at lanes of ``shape`` (0 without
    an environment)."""
    if light.env is None:
        return mi.Color3f(0.0)
    tab = light.tables
    return specular_split_sum(light.env, light.dfg, n, v, dr.gather(mi.Float, tab.alpha, shape),
                              dr.gather(mi.Color3f, tab.f0, shape),
                              dr.gather(mi.Color3f, tab.f90, shape))


def _hit_radiance(light: MirrorLight, scene: object, si: mi.SurfaceInteraction3f,
                  d: mi.Vector3f, hit: mi.Bool) -> tuple[mi.Color3f, mi.Color3f]:
    """The radiance towards ``−d`` of the surfaces ``si`` a ray along ``d`` met in ``scene``
    (a view of :class:`~arlight.backend.mitsuba_scene.SceneViews`), shaded locally:
    ``ρ/π (E_direct + E_amb)`` (the reduced lights with shadow rays in ``scene``, the SH
    remainder unoccluded) plus the hit's own glossy reflection of the distant light
    (split-sum, view ``−d``; no further rays). Returns ``(radiance, E_direct)`` (W sr⁻¹ m⁻²,
    W/m²; 0 where not ``hit``)."""
    nh = facing(mi.Vector3f(si.n), -d)
    e_direct = direct_irradiance(scene, light.lights, si.p, nh, hit)
    local = surface_albedo(si, hit) * (1.0 / math.pi) * (
        e_direct + dr.maximum(ambient_irradiance_dr(light.lights, nh), 0.0))
    shape = mi.UInt32(dr.maximum(scene.hit_shape(si), 0))
    local += dr.select(hit, distant_specular(light, nh, -d, shape), mi.Color3f(0.0))
    return local, e_direct


def mirror_rays(light: MirrorLight, position: mi.Point3f, normal: mi.Vector3f,
                to_camera: mi.Vector3f, shape: mi.Int32, active: mi.Bool,
                seen: Reprojector | None, change_only: mi.Bool | None = None,
                ball: tuple[np.ndarray, float] | None = None
                ) -> tuple[mi.Color3f, mi.Color3f, mi.Int32]:
    """:func:`_mirror_rays` with Dr.Jit's virtual calls symbolic also where the studio's
    drag frames evaluate them (as dvct's surround rays, issue #32: evaluated, the hits'
    shape and BSDF calls compiled kernels per instance on every moving frame).

    ``change_only``: lanes whose caller reads only the change and whether the ray met a
    virtual surface (dvct's real lanes), with ``ball`` the virtual objects' bounding ball
    (:func:`~arlight.realtime.shadow_reach.bounding_ball`). Where such a lane's ray misses,
    or meets a real surface from which no light's shadow ray can meet the ball
    (:func:`~arlight.realtime.shadow_reach.shadow_reach`), and no local light's shadow ray
    from the lane's own point can (its blocked highlight), the mixed and real scenes light
    the hit and the lane alike and its change is exactly zero: the lane is not shaded (radiance and
    change 0, role −1), which at 640×480 spared a held-out room whose glossy floor fills
    the frame four of its five rays per lane."""
    with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, True):
        if change_only is not None and ball is not None:
            lean = active & change_only
            active = active & ~(lean & ~_may_change(light, position, normal, to_camera,
                                                   lean, ball))
        return _mirror_rays(light, position, normal, to_camera, shape, active, seen)


def _reflection_ray(position: mi.Point3f, normal: mi.Vector3f, to_camera: mi.Vector3f,
                    idx: mi.UInt32
                    ) -> tuple[mi.Point3f, mi.Vector3f, mi.Vector3f, mi.Ray3f]:
    """The lanes ``idx``'s position, normal, view direction and mirror ray ``r = 2 <v,n> n
    − v`` (leaving the surface 10⁻⁴ m along ``n``)."""
    p = dr.gather(mi.Point3f, position, idx)
    n = dr.gather(mi.Vector3f, normal, idx)
    v = dr.gather(mi.Vector3f, to_camera, idx)
    return p, n, v, mi.Ray3f(p + n * 1e-4, 2.0 * dr.dot(v, n) * n - v)


def _may_change(light: MirrorLight, position: mi.Point3f, normal: mi.Vector3f,
                to_camera: mi.Vector3f, active: mi.Bool, ball: tuple[np.ndarray, float]
                ) -> mi.Bool:
    """The ``active`` lanes whose mirror ray meets a virtual surface, or a real one from
    which some light's shadow ray can meet ``ball``, or whose own point some local light's
    shadow ray can (their blocked highlight, ``light.near``)."""
    out = dr.zeros(mi.Bool, dr.width(active))
    idx = dr.compress(active)
    if dr.width(idx) == 0:
        return out
    mixed = light.views.mixed
    p, _, _, ray = _reflection_ray(position, normal, to_camera, idx)
    si = mixed.scene.ray_intersect(ray)
    role = mixed.hit_role(si)
    need = (role == ROLE_VIRTUAL) | ((role == ROLE_REAL) & shadow_reach(light.lights, si.p,
                                                                          ball))
    if light.near.lights:
        need |= shadow_reach(light.near, p, ball)
    dr.scatter(out, need, idx)
    return out


def _mirror_rays(light: MirrorLight, position: mi.Point3f, normal: mi.Vector3f,
                to_camera: mi.Vector3f, shape: mi.Int32, active: mi.Bool,
                seen: Reprojector | None) -> tuple[mi.Color3f, mi.Color3f, mi.Int32]:
    """One reflection ray per ``active`` lane into the mixed scene (module docstring):
    ``(radiance, change, role)`` — the specular radiance the lane reflects towards the camera
    (W sr⁻¹ m⁻², the lobe's albedo applied; 0 on inactive lanes); the change the virtual
    objects bring to it, ``(F0 A + F90 B)(L_µ(r) − L_ρ(r))`` (what a rough real lane adds to
    its photograph): at a virtual hit its radiance minus the real proxy's along the same ray,
    at a real hit the camera sees the change of its direct light, 0 elsewhere; and what the
    ray met (``ROLE_REAL``, ``ROLE_VIRTUAL``, or −1 for a miss and on inactive lanes)."""
    n_l = dr.width(active)
    out, out_change = dr.zeros(mi.Color3f, n_l), dr.zeros(mi.Color3f, n_l)
    role_out = dr.full(mi.Int32, -1, n_l)
    idx = dr.compress(active)
    if dr.width(idx) == 0:
        return out, out_change, role_out
    p, n, v, ray = _reflection_ray(position, normal, to_camera, idx)
    sh = mi.UInt32(dr.maximum(dr.gather(mi.Int32, shape, idx), 0))
    d = ray.d
    mixed = light.views.mixed
    si = mixed.scene.ray_intersect(ray)
    role = mixed.hit_role(si)
    hit = role >= 0
    value, e_mixed = _hit_radiance(light, mixed, si, d, hit)
    change = mi.Color3f(0.0)
    if seen is not None:
        real_hit = hit & (role == ROLE_REAL)
        nh = facing(mi.Vector3f(si.n), -d)
        photo, ok, _, pix = seen.lookup(si.p, real_hit)
        e_real = direct_irradiance(light.views.real, light.lights, si.p, nh, ok)
        rho = photo_albedo(light.views.real, light.lights, seen.frame, pix, si.p, nh,
                           surface_albedo(si, ok), ok, direct=e_real)
        change = dr.select(ok, rho * (1.0 / math.pi) * (e_mixed - e_real), mi.Color3f(0.0))
        value = dr.select(ok, dr.maximum(photo + change, 0.0), value)
    w = lobe_albedo(light, n, v, sh)
    env = distant_specular(light, n, v, sh)
    val = dr.select(hit, value * w, env)
    # a real lane whose ray meets a virtual surface: what the real scene showed along the ray
    # (the share of the photograph the surface hides), the same ray in the real proxy
    on_virtual = hit & (role == ROLE_VIRTUAL)
    si_r = light.views.real.scene.ray_intersect(ray, on_virtual)
    hit_r = on_virtual & si_r.is_valid()
    before = _hit_radiance(light, light.views.real, si_r, d, hit_r)[0]
    if seen is not None:
        photo_r, ok_r = seen.lookup(si_r.p, hit_r)[:2]
        before = dr.select(ok_r, photo_r, before)
    before = dr.select(hit_r, before * w, env)
    change = dr.select(on_virtual, val - before, change * w)
    # a rough real lane's glossy highlight of the local lights (not in its ray's L̃): what the
    # objects block of it, f_s <n, ω_i>+ E⊥_i (V_µ,i − V_ρ,i) through shadow rays in the mixed
    # and in the real proxy (on a mirror the hiding of h B takes it away)
    real_lane = dr.gather(mi.Bool, light.real, sh)
    if light.near.lights:
        tab = light.tables
        alpha = dr.gather(mi.Float, tab.alpha, sh)
        f0, f90 = dr.gather(mi.Color3f, tab.f0, sh), dr.gather(mi.Color3f, tab.f90, sh)

        def lobe(wi: mi.Vector3f) -> mi.Color3f:
            return ggx_reflectance(n, v, wi, alpha, f0, f90)

        change += (direct_light(mixed, light.near, p, n, real_lane, specular=lobe)[1]
                   - direct_light(light.views.real, light.near, p, n, real_lane,
                                  specular=lobe)[1])
    dr.scatter(out_change, change, idx)
    dr.scatter(out, val, idx)
    dr.scatter(role_out, dr.select(hit, role, -1), idx)
    return out, out_change, role_out


__all__ = ["ROLE_REAL", "ROLE_VIRTUAL", "MirrorLight", "distant_specular",
           "lobe_albedo", "mirror_rays"]
