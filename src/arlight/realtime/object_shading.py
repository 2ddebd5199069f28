"""The virtual objects' own shading for the additive real-time methods ``dir`` and ``dlpv``
(issue #33): one function, :func:`shade_objects`, for both; each method hands in its own
indirect irradiance (``dir``: the VPL gather, ``dlpv``: the ``V_ρ`` read).

On a virtual lane (surface point ``x``, unit normal ``n``, direction to the camera ``v``,
diffuse albedo ``ρ``, GGX lobe ``α, F0, F90`` of its material) the outgoing radiance is

    L_o = ρ/π (E_dir(x) + E_a(x) + E_ind(x))                                        (1)
        + Σ_i V_i f_s(ω_i, v) <n, ω_i>+ E⊥_i                                         (2)
        + [L̃_rest(d, α) + L̃_probe(d, α)] (F0 A + F90 B)                             (3)

* ``E_dir`` — the reduced lights (:mod:`arlight.realtime.light_reduction`) with one shadow
  ray each in the mixed scene (Franke Eq. 5.14);
* ``E_a`` — the SH ambient remainder, occluded by the objects themselves
  (:func:`arlight.realtime.ambient.virtual_ambient`, Eq. 2 there), plus, with ``probe``,
  the bounce probe (:func:`arlight.realtime.ibl_shading.bounce_probe`): what the real scene
  changes of the remainder at the objects (the floor's bounce in place of the sky it
  hides), projected on order-2 SH — the environment capture of Franke's dynamic pipeline
  (§4.2). The probe path-traces the real scene's light, so it already holds the bounce of
  the reduced lights off real surfaces: the method then leaves out ``E_ind`` (``dir``: no
  VPL gather on object lanes; ``dlpv``: no ``V_ρ``);
* ``E_ind`` — the method's own indirect term (only with ``probe`` off);
* (2) — the GGX specular (Walter et al. 2007, :func:`~arlight.realtime.ibl_shading.
  ggx_reflectance`) of **every** reduced light, the environment's extracted directional
  lights included, through the same shadow rays as ``E_dir``
  (:func:`arlight.realtime.shading.direct_light`);
* (3) — the GGX specular of the rest of the distant light by the split sum (Karis 2013,
  :func:`~arlight.realtime.ibl_shading.specular_split_sum`: a map prefiltered per
  roughness, times the DFG table's ``F0 A + F90 B``): ``L̃_rest`` of
  :func:`remainder_map` — the environment less the extracted lights, so that those are
  counted once, in (2) — and ``L̃_probe`` of the probe's change of it (a box mip chain).

``phong`` objects map to GGX by :func:`~arlight.realtime.ibl_shading.specular_tables`
(``α = √(2/(n+2))``, ``F0 = F90 = k_s``); their G-buffer albedo is ``k_d``. Without the
``object_specular`` option the objects are shaded as pure diffuse, (1) alone (before
issue #33's change). Units: radiance W/(sr·m²), irradiance W/m².
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews
from arlight.realtime.ambient import AmbientOcclusion, virtual_ambient
from arlight.realtime.gbuffer import GBuffer
from arlight.realtime.ibl_shading import (
    PROBE_OPTIONS,
    MipEnvironment,
    SpecularTables,
    dfg_table,
    environment_map,
    prefilter_ggx,
    probe_for_world,
    specular_split_sum,
    specular_tables,
    virtual_glossy,
)
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.shading import direct_light
from arlight.scene.model import World
from arlight.scene.schema import Field
from arlight.sphere.sh import project_equirect

PREFILTER_SAMPLES = 64
"""GGX importance samples per texel of the prefiltered environment (``ibl``'s default)."""

OBJECT_OPTIONS: dict[str, Field] = {
    "object_specular": Field("bool", True, "the virtual objects' GGX specular (phong: α = "
                             "√(2/(n+2)), F = k_s): the environment's by the split sum, the "
                             "local lights' through their shadow rays "
                             "(arlight.realtime.object_shading); off: pure diffuse"),
    **PROBE_OPTIONS,
}
"""Options of :func:`shade_objects` (the ``probe`` ones are ``ibl``'s)."""

IndirectFn = Callable[[mi.UInt32, mi.Point3f, mi.Vector3f], mi.Color3f]
"""A method's indirect irradiance (W/m²) at the compacted object lanes: ``(lane indices,
points, normals) ↦ E_ind``."""


@dataclass
class ObjectLight:
    """What :func:`shade_objects` keeps per prepared world.

    Attributes:
        spec: the GGX tables per shape (:func:`~arlight.realtime.ibl_shading.
            specular_tables`); ``spec.glossy`` False or ``specular`` off: diffuse only.
        env: the GGX-prefiltered environment (None: no distant light or no glossy object).
        dfg: the split-sum DFG table, flattened (None with ``env``).
        env_map: the environment's remainder (:func:`remainder_map`; the probe's
            reference; None without an environment).
        probe_sh: the bounce probe's diffuse change as order-2 radiance SH ``(9, 3)``
            (zeros with ``probe`` off).
        probe_env: the same change as a box mip chain, the specular's correction of the
            environment map where the real scene hides it (None with ``probe`` off).
        specular: the ``object_specular`` option.
    """

    spec: SpecularTables
    env: MipEnvironment | None
    dfg: mi.Float | None
    env_map: np.ndarray | None
    probe_sh: np.ndarray
    specular: bool
    probe_env: MipEnvironment | None = None

    @property
    def probe(self) -> bool:
        """Whether the bounce probe is in (the method then drops its real-surface bounce
        on object lanes)."""
        return bool(np.any(self.probe_sh))


def _probe(world: World, views: SceneViews, rest: np.ndarray | None, options
           ) -> tuple[np.ndarray, MipEnvironment | None]:
    """The bounce probe's change of the remainder ``rest`` (:func:`remainder_map`: the
    extracted lights' directions are left to their shadow rays) at the objects, as
    order-2 radiance SH ``(9, 3)`` and as a box mip chain (zeros and None with ``probe``
    off or nothing virtual)."""
    probe = probe_for_world(world, views, rest, options, 0)
    if probe is None:
        return np.zeros((9, 3)), None
    sh = project_equirect(probe.diffuse.astype(np.float64), 2)
    return np.asarray(sh, np.float64).reshape(9, 3), MipEnvironment.build(probe.diffuse)


def remainder_map(env_map: np.ndarray, env_lights: int) -> np.ndarray:
    """The part of the environment map that the light reduction leaves to the SH remainder
    (W/(sr·m²)), as :meth:`arlight.light.estimate.LightEstimate.from_envmap` splits it for
    :func:`~arlight.realtime.light_reduction.reduce_lights`: the highlight regions above
    :func:`~arlight.light.extract.auto_threshold`'s 4 × the mean luminance that become
    directional lights (:func:`~arlight.light.extract.highlight_regions`, at most
    ``env_lights``) clipped at the threshold, the regions it drops (over the cap, too faint
    or too wide) whole; the whole map when no light is extracted (``env_lights`` 0)."""
    from arlight.light.estimate import _clip_band
    from arlight.light.extract import auto_threshold, highlight_regions, luminance

    if env_lights <= 0:
        return env_map
    lum = luminance(env_map)
    thr = auto_threshold(env_map, 4.0)
    found = highlight_regions(env_map, thr, lum=lum, max_lights=env_lights)
    return _clip_band(thr, found.dropped, lum)(0, env_map.shape[0], env_map)


def prepare_object_light(world: World, views: SceneViews, options) -> ObjectLight:
    """The tables, prefiltered environment (only with a glossy virtual shape and
    ``object_specular``) and bounce probe of ``world``."""
    spec = specular_tables(world)
    env_map = environment_map(world)
    rest = remainder_map(env_map, options.env_lights) if env_map is not None else None
    glossy = bool(options.object_specular and spec.glossy)
    env = prefilter_ggx(rest, PREFILTER_SAMPLES) if glossy and rest is not None else None
    dfg = mi.Float(dfg_table().reshape(-1)) if glossy else None
    sh, mip = _probe(world, views, rest, options)
    return ObjectLight(spec, env, dfg, rest, sh, glossy, mip)


def pose_object_light(obj: ObjectLight, world: World, views: SceneViews, options
                      ) -> ObjectLight:
    """``obj`` for the objects posed in ``world`` (views already moved): the probe traced
    again at their new centre (kept with ``probe_follow`` off); tables and environment
    kept (materials and distant light do not move)."""
    if not options.probe or not options.probe_follow:
        return obj
    sh, mip = _probe(world, views, obj.env_map, options)
    return replace(obj, probe_sh=sh, probe_env=mip)


def shade_objects(obj: ObjectLight, world: World, views: SceneViews, lights: LightSet,
                  ambient: AmbientOcclusion, gb: GBuffer, indirect: IndirectFn | None,
                  ao_rays: int, seed: int = 0) -> mi.Color3f:
    """Radiance (W/(sr·m²)) of the virtual lanes of ``gb`` by Eqs. 1–3 of the module
    docstring, zero on other lanes. Only the virtual lanes are traced (compacted)."""
    virt = gb.virtual
    idx = dr.compress(virt)
    out = dr.zeros(mi.Color3f, dr.width(virt))
    if dr.width(idx) == 0:
        return out
    p = dr.gather(mi.Point3f, gb.position, idx)
    n = dr.gather(mi.Vector3f, gb.normal, idx)
    albedo = dr.gather(mi.Color3f, gb.albedo, idx)
    glossy = None
    if obj.specular:
        glossy = virtual_glossy(obj.spec, gb, idx, dr.gather(mi.Int32, gb.shape, idx))
    e_dir, s_dir = direct_light(views.mixed, lights, p, n, mi.Bool(True),
                                specular=None if glossy is None else glossy.reflectance(n))
    remainder = LightSet([], np.asarray(lights.ambient_sh, np.float64) + obj.probe_sh)
    e = e_dir + virtual_ambient(ambient, remainder, p, n, ao_rays, seed)
    if indirect is not None:
        e += indirect(idx, p, n)
    rad = albedo * (1.0 / math.pi) * e
    if s_dir is not None:
        rad += s_dir
    if glossy is not None and obj.dfg is not None:
        for env in (obj.env, obj.probe_env):  # the remainder map, the probe's change of it
            if env is not None:
                rad += specular_split_sum(env, obj.dfg, n, glossy.v, glossy.alpha,
                                          glossy.f0, glossy.f90)
    dr.scatter(out, rad, idx)
    dr.eval(out)
    return out


__all__ = ["OBJECT_OPTIONS", "PREFILTER_SAMPLES", "IndirectFn", "ObjectLight",
           "pose_object_light", "prepare_object_light", "shade_objects"]
