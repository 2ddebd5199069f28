"""Shading helpers shared by the real-time methods: direct light from reduced lights with
shadow rays, SH ambient irradiance, and the virtual objects' bounding box."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView, SceneViews
from arlight.jit import opaque, opaques
from arlight.realtime.light_reduction import LightSet, ReducedLight
from arlight.realtime.shadow_reach import bounding_ball, light_reach
from arlight.scene.model import World

if TYPE_CHECKING:
    from arlight.realtime.gbuffer import GBuffer

SHADOW_EPS = 1e-4
"""Offset of shadow-ray origins along the normal, metres."""


def emitted_intensity(light: ReducedLight, w_out: mi.Vector3f) -> mi.Color3f:
    """Radiant intensity (W/sr) of a point-like light towards unit ``w_out`` (from the
    light): isotropic, ``I0 <axis, ω>+`` (cosine) or Mitsuba's spot falloff (linear in angle
    between the beam and the cutoff)."""
    i0 = mi.Color3f(*opaques(light.intensity))
    if light.kind == "point":
        return i0 + 0.0 * w_out.x
    axis = mi.Vector3f(*opaques(light.axis))
    c = dr.dot(axis, w_out)
    if light.kind == "cosine":
        return i0 * dr.maximum(c, 0.0)
    return i0 * dr.select(c > light.cos_cutoff, spot_falloff(light, c), 0.0)


def spot_falloff(light: ReducedLight, c: mi.Float) -> mi.Float:
    """Mitsuba's spot profile at ``c = <axis, ω>``: 1 inside the beam, falling linearly in
    angle to 0 at the cutoff (not masked outside the cone)."""
    cut, beam = math.acos(light.cos_cutoff), math.acos(light.cos_beam)
    width = max(cut - beam, 1e-9)
    ang = dr.acos(dr.clip(c, -1.0, 1.0))
    return dr.select(c >= light.cos_beam, 1.0, dr.clip((cut - ang) / width, 0.0, 1.0))


def direct_irradiance(view: SceneView, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                      active: mi.Bool, shadows: bool = True) -> mi.Color3f:
    """Irradiance (W/m²) at points ``p`` (normals ``n``) from the reduced lights, with one
    shadow ray per light in ``view`` (Franke Eq. 5.14: ``Σ_i L_i <n, ω_i>+``; the thesis
    leaves the direct visibility to shadow maps, we trace it)."""
    return direct_light(view, lights, p, n, active, shadows)[0]


def direct_light(view: SceneView, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                 active: mi.Bool, shadows: bool = True,
                 specular: Callable[[mi.Vector3f], mi.Color3f] | None = None
                 ) -> tuple[mi.Color3f, mi.Color3f | None]:
    """:func:`direct_irradiance` and, with ``specular`` (``ω ↦ f_s(ω, v) <n, ω>+``, sr⁻¹,
    e.g. :func:`arlight.realtime.ibl_shading.ggx_reflectance`), the specular radiance
    ``Σ_i V_i f_s(ω_i, v) <n, ω_i>+ E⊥_i`` (W/(sr·m²)) of the same lights through the same
    shadow rays (None without ``specular``)."""
    out = mi.Color3f(0.0)
    spec = mi.Color3f(0.0) if specular is not None else None
    for _, w, e, ray, lit in light_terms(lights, p, n, active):
        if shadows:
            lit &= ~view.scene.ray_test(ray, lit)
        out += dr.select(lit, e * dr.dot(n, w), mi.Color3f(0.0))
        if spec is not None:
            spec += dr.select(lit, e * specular(w), mi.Color3f(0.0))
    return out, spec


def light_terms(lights: LightSet, p: mi.Point3f, n: mi.Vector3f, active: mi.Bool):
    """Per reduced light: ``(light, ω, E⊥, shadow ray, lit)`` at points ``p`` (normals
    ``n``): the unit direction towards the light, the irradiance (W/m²) it gives a surface
    facing it (directional: its intensity; else ``I(−ω)/d²``), the shadow ray from ``p``
    (offset :data:`SHADOW_EPS` along ``n``, ending just before the light, :func:`shadow_ray`)
    and the ``active`` lanes that face it (``<n, ω> > 0``)."""
    origin = p + n * SHADOW_EPS
    for lt in lights.lights:
        if lt.kind == "directional":
            w = -mi.Vector3f(*opaques(lt.axis))
            e = mi.Color3f(*opaques(lt.intensity))
        else:
            to = mi.Point3f(*opaques(lt.position)) - origin
            dist = dr.norm(to)
            w = to / dr.maximum(dist, 1e-12)
            e = emitted_intensity(lt, -w) / dr.maximum(dist * dist, 1e-12)
        yield lt, w, e, shadow_ray(lt, origin), active & (dr.dot(n, w) > 0.0)


def shadow_ray(light: ReducedLight, origin: mi.Point3f,
               u: tuple[mi.Float, mi.Float] | None = None) -> mi.Ray3f:
    """The shadow ray from ``origin`` to ``light``: to its position (ending just before it)
    or along its direction, or with ``u ∈ [0, 1)²`` to a point of its extent: a direction
    uniform in the cone of half angle ``spread`` around a directional light's (solid angle
    ``2π(1 − cos spread)``), a point uniform on the patch ``position ± extent`` of a
    ``cosine`` light (:class:`~arlight.realtime.light_reduction.ReducedLight`)."""
    if light.kind == "directional":
        w = -mi.Vector3f(*opaques(light.axis))
        if u is not None and light.spread > 0.0:
            cos_t = 1.0 - u[0] * dr.opaque(mi.Float, 1.0 - math.cos(light.spread))
            sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
            phi = 2.0 * math.pi * u[1]
            w = mi.Frame3f(w).to_world(mi.Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi),
                                                   cos_t))
        ray = mi.Ray3f(origin, w)
        ray.maxt = dr.largest(mi.Float)
        return ray
    target = mi.Point3f(*opaques(light.position))
    if u is not None and np.any(light.extent):
        a, b = (mi.Vector3f(*opaques(e)) for e in light.extent)
        target = target + a * (2.0 * u[0] - 1.0) + b * (2.0 * u[1] - 1.0)
    to = target - origin
    dist = dr.norm(to)
    ray = mi.Ray3f(origin, to / dr.maximum(dist, 1e-12))
    ray.maxt = dist * (1.0 - 1e-4)
    return ray


def extended(light: ReducedLight) -> bool:
    """Whether ``light`` has a size for soft shadows (``spread`` or ``extent``)."""
    return (light.kind == "directional" and light.spread > 0.0) or bool(np.any(light.extent))


class DirectTerms(NamedTuple):
    """The reduced lights' direct irradiance at real points through one set of shadow rays
    (:func:`direct_terms`), both W/m²."""

    change: mi.Color3f
    """``ΔE_d = Σ_i E⊥_i <n, ω_i>+ (V_ρ,i − V_µ,i)`` (``≤ 0``): the virtual objects' change."""
    real: mi.Color3f
    """``E_µ,d = Σ_i E⊥_i <n, ω_i>+ V_µ,i``: the real scene's own direct irradiance (the
    direct part of the photograph's model irradiance ``E_r``,
    :func:`arlight.realtime.photo_albedo.model_irradiance`)."""


def direct_terms(views: SceneViews, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                 active: mi.Bool, samples: int = 1,
                 strata: tuple[mi.UInt32, mi.UInt32, int] | None = None,
                 far: list[mi.Bool] | None = None) -> DirectTerms:
    """The virtual objects' change of the reduced lights' direct irradiance at real points
    ``p`` (normals ``n``) and the real scene's direct irradiance, through the same shadow
    rays (:class:`DirectTerms`; zero on inactive lanes).

    ``ΔE_d = Σ_i E⊥_i <n, ω_i>+ (V_ρ,i − V_µ,i)`` (Franke Eq. 5.14 in the mixed scene minus
    the same in the real one: Knecht 2010's differential of the direct light), with the
    visibilities ``V_ρ`` in the mixed view and ``V_µ`` in the real one traced by shadow
    rays. The mixed scene holds the real one, so a ray the mixed scene lets through
    arrives in the real one too (``V_ρ ≤ V_µ``): the real-scene ray is traced only where
    the mixed one is blocked, and that one test gives both ``V_ρ − V_µ`` (``ΔE_d ≤ 0``) and
    ``V_µ`` — ``E_µ,d = Σ_i E⊥_i <n, ω_i>+ V_µ,i``, the real scene's direct irradiance of
    the photograph's albedo, comes without rays of its own.

    With ``samples = K > 1`` an extended light (:func:`extended`: a directional light
    standing for a region of sky, a cosine point for a patch of an area light) casts a soft
    shadow: ``V`` is the fraction of ``K`` shadow rays to points of its extent
    (:func:`shadow_ray`) that arrive — the visible fraction of an area light, as ray-traced
    soft shadows compute it (Cook et al. 1984), with the unshadowed irradiance kept at
    the reduced light's (so ``E_µ,d`` holds the real scene's soft shadows too). The ``K``
    points are a rank-1 lattice (the R2 sequence, :func:`r2_point`) rotated per pixel by a
    hash of its index (TEA; Cranley–Patterson), so neighbouring pixels sample the extent
    differently and a penumbra shows noise, not ``K`` copies of a hard shadow.

    ``strata = (pixel, sample, m)`` (a G-buffer with ``m`` samples per pixel,
    :func:`direct_terms_gbuffer`): the ``K`` points are split over a pixel's samples —
    sample ``s`` casts points ``s, s + m, …`` of one lattice rotated by a hash of the pixel —
    so the pixel's ``m`` samples cast ``max(K, m)`` rays together, not ``m K``; each
    sample's ``V`` is the fraction of its own points that arrive. None: each lane is its
    own pixel (key: its index) with one sample.

    ``far`` (one mask per light; None: every lane traces both scenes): light ``i`` is
    traced on the lanes ``far[i]`` only, whose rays cannot meet a virtual object
    (:func:`arlight.realtime.shadow_reach.light_reach`), and in the real scene only: such a
    ray meets real geometry alone, so the mixed scene blocks it exactly where the real one
    does (``V_ρ = V_µ``, no change) — ``E_µ,d`` from the same rays, so the same ``V_µ``
    as tracing both scenes."""
    change = mi.Color3f(0.0)
    real = mi.Color3f(0.0)
    if strata is None:
        strata = (dr.arange(mi.UInt32, dr.width(p)), mi.UInt32(0), 1)
    rot = None
    for i, (lt, w, e, ray, lit) in enumerate(light_terms(lights, p, n, active)):
        k = samples if samples > 1 and extended(lt) else 1
        if rot is None and k > 1:
            rot = (mi.sample_tea_float32(strata[0], 0), mi.sample_tea_float32(strata[0], 1))
        origin = p + n * SHADOW_EPS
        lost = mi.Float(0.0)
        shaded = mi.Float(0.0)
        cast = mi.Float(0.0)
        for r, on in _extent_rays(lt, ray, origin, rot, k, strata):
            on = lit & on
            if far is None:  # the real scene only where the mixed one blocks the ray
                blocked = on & views.mixed.scene.ray_test(r, on)
                in_real = blocked & views.real.scene.ray_test(r, blocked)
            else:  # no virtual object on the ray: V_ρ = V_µ
                on &= far[i]
                blocked = mi.Bool(False)
                in_real = on & views.real.scene.ray_test(r, on)
            lost += dr.select(blocked & ~in_real, 1.0, 0.0)
            shaded += dr.select(in_real, 1.0, 0.0)
            cast += dr.select(on, 1.0, 0.0)
        per_ray = e * (dr.dot(n, w) / dr.maximum(cast, 1.0))
        change -= per_ray * lost
        real += per_ray * (cast - shaded)
    return DirectTerms(change, real)


def direct_change(views: SceneViews, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                  active: mi.Bool, samples: int = 1,
                  strata: tuple[mi.UInt32, mi.UInt32, int] | None = None) -> mi.Color3f:
    """``ΔE_d`` (W/m², ``≤ 0``) of :func:`direct_terms` alone."""
    return direct_terms(views, lights, p, n, active, samples, strata).change


def _extent_rays(light: ReducedLight, ray: mi.Ray3f, origin: mi.Point3f, rot, k: int,
                 strata: tuple[mi.UInt32, mi.UInt32, int]):
    """``(shadow ray, lanes that cast it)`` pairs of :func:`direct_terms`: the one ray to
    the light (``k`` 1), or a sample's share of ``max(k, m)`` lattice points rotated by
    ``rot`` (``m`` samples per pixel: point ``s + m t`` for sample ``s``; lanes whose share
    has fewer points skip the last; every sample casts at least one)."""
    if k == 1:
        yield ray, mi.Bool(True)
        return
    _, sample, spp = strata
    k = max(k, spp)
    for t in range(-(-k // spp)):
        j = sample + spp * t
        u = r2_point(mi.Float(j))
        yield (shadow_ray(light, origin, (_frac(rot[0] + u[0]), _frac(rot[1] + u[1]))),
               mi.Bool(True) if k % spp == 0 else j < k)


def direct_terms_gbuffer(views: SceneViews, lights: LightSet, gb: GBuffer, active: mi.Bool,
                         samples: int = 1, world: World | None = None,
                         real_on: mi.Bool | None = None, far_samples: int | None = None
                         ) -> DirectTerms:
    """:func:`direct_terms` (W/m²) at the G-buffer's ``active`` lanes only (compacted with
    :func:`on_active`, scattered back; zero elsewhere), the ``samples`` points of an
    extended light split over each pixel's ``gb.spp`` samples (``strata``): the real
    pixels' direct change of ``dir``, ``dlpv`` and ``dvct`` and, through the same rays,
    the direct part of their photograph's model irradiance (``real``, for
    :func:`arlight.realtime.photo_albedo.photo_albedo`'s ``direct``).

    ``world`` (the views' world; None: no culling) culls light by light
    (:mod:`arlight.realtime.shadow_reach`): each light's rays in both scenes only on the
    lanes whose rays to it can meet the ball around the virtual objects
    (:func:`~arlight.realtime.shadow_reach.light_reach`; compacted per light), the only
    lanes whose change can be non-zero; on the other ``real_on`` lanes ``V_ρ,i = V_µ,i``
    and the light's rays are traced in the real scene only, for ``E_µ,d`` (every light in
    one pass, ``far_samples`` rays per extended light — None: ``samples``, then both
    outputs equal the unculled ones, ``real`` to float rounding: the lights are summed in
    another order; 1: the central ray, a hard real shadow). ``real_on``: lanes (within
    ``active``) where ``real`` is wanted besides those some light can reach the objects
    from, where it is always computed; None: every ``active`` lane. ``real`` is zero on
    the lanes left out (with a caller's ``ρ/π ΔE`` they multiply a zero change). On a
    held-out outdoor world at 640×480 with seven reduced lights 5 of 8 real lanes per light
    can reach nothing."""
    if not lights.lights:
        z = dr.zeros(mi.Color3f, dr.width(gb.position))
        return DirectTerms(z, mi.Color3f(z))
    sample = dr.arange(mi.UInt32, dr.width(gb.pixel)) % gb.spp
    box = None if world is None else virtual_bounds(world, views.mixed)
    if world is None:  # every lane in both scenes
        def terms(p: mi.Point3f, n: mi.Vector3f, pixel: mi.UInt32, s: mi.UInt32
                  ) -> DirectTerms:
            return direct_terms(views, lights, p, n, mi.Bool(True), samples,
                                (pixel, s, gb.spp))

        return DirectTerms(*on_active(terms, gb.position, gb.normal, active, gb.pixel, sample,
                                      outputs=2))
    if box is None:  # no virtual object: no light reaches one
        reach = [dr.zeros(mi.Bool, dr.width(gb.position)) for _ in lights.lights]
    else:
        centre, radius = bounding_ball(box)
        # opaque: the ball moves with the objects, one kernel for every pose (issue #32)
        c, r = mi.Point3f(*opaques(centre)), opaque(radius)
        reach = [active & light_reach(lt, gb.position, c, r) for lt in lights.lights]
    n_l = dr.width(gb.position)
    # added light by light into two arrays: a sum of per-light arrays, read by the caller's
    # shading kernel, made it read 6 arrays per light (126 inputs at 640×480 with 7 lights)
    change, real = dr.zeros(mi.Color3f, n_l), dr.zeros(mi.Color3f, n_l)
    for lt, near in zip(lights.lights, reach, strict=True):
        def one(p: mi.Point3f, n: mi.Vector3f, pixel: mi.UInt32, s: mi.UInt32,
                lt: ReducedLight = lt) -> DirectTerms:
            return direct_terms(views, LightSet([lt]), p, n, mi.Bool(True), samples,
                                (pixel, s, gb.spp))

        on_active(one, gb.position, gb.normal, near, gb.pixel, sample, outputs=2,
                  into=(change, real))
    want = active
    if real_on is not None:
        want = active & real_on
        for near in reach:
            want |= near

    def rest(p: mi.Point3f, n: mi.Vector3f, pixel: mi.UInt32, s: mi.UInt32, *near: mi.Bool
             ) -> DirectTerms:
        return direct_terms(views, lights, p, n, mi.Bool(True),
                            samples if far_samples is None else far_samples,
                            (pixel, s, gb.spp), [~x for x in near])

    on_active(rest, gb.position, gb.normal, want, gb.pixel, sample, *reach, outputs=2,
              into=(None, real))
    dr.eval(change, real)
    return DirectTerms(change, real)


def _frac(x):
    return x - (math.floor(x) if isinstance(x, float | int) else dr.floor(x))


def r2_point(j):
    """Point ``j`` of the R2 rank-1 lattice in ``[0, 1)²`` (Roberts 2018: ``frac(0.5 + j
    (1/φ₂, 1/φ₂²))``, ``φ₂`` the plastic number 1.3247…), for a Python number or per lane
    (``mi.Float``)."""
    g = 1.32471795724474602596
    return _frac(0.5 + j * (1.0 / g)), _frac(0.5 + j * (1.0 / (g * g)))


def split_lights(world: World, lights: LightSet) -> tuple[LightSet, LightSet]:
    """``lights`` as (the part that stands for the distant light — directional lights
    extracted from environment maps, plus the SH remainder — and the local part: point, spot,
    area and ``directional`` world lights, no remainder), by each light's ``source``."""
    env = {lt.name or f"light{i}" for i, lt in enumerate(world.lights)
           if lt.type in ("envmap", "sh", "constant")}
    far = [lt for lt in lights.lights if lt.source in env]
    near = [lt for lt in lights.lights if lt.source not in env]
    return LightSet(far, lights.ambient_sh), LightSet(near)


def direct_irradiance_compact(view: SceneView, lights: LightSet, p: mi.Point3f,
                              n: mi.Vector3f, active: mi.Bool) -> mi.Color3f:
    """:func:`direct_irradiance` on the ``active`` lanes only (compacted, scattered back;
    zero elsewhere), so that shadow rays are set up for those lanes alone."""
    if not lights.lights:
        return dr.zeros(mi.Color3f, dr.width(p))
    return on_active(lambda pc, nc: direct_irradiance(view, lights, pc, nc, mi.Bool(True)),
                     p, n, active)


def on_active(fn, p: mi.Point3f, n: mi.Vector3f, active: mi.Bool, *extra,
              outputs: int = 0, into: tuple | None = None):
    """``fn(p, n, *extra)`` evaluated on the ``active`` lanes only (compacted with
    ``dr.compress``, scattered back; zero elsewhere): pays off for costly per-lane work on
    few lanes. ``extra``: more per-lane arrays, compacted alike. ``fn`` returns an
    ``mi.Color3f`` (``outputs`` 0) or a tuple of ``outputs`` of them (a tuple comes back).
    ``into``: full-width arrays, one per output (None: that output is dropped), that the
    results are added to in place (``dr.scatter_add``) instead of being returned."""
    idx = dr.compress(active)
    count = max(outputs, 1)
    outs = into if into is not None else tuple(dr.zeros(mi.Color3f, dr.width(p))
                                               for _ in range(count))
    if dr.width(idx) > 0:
        pc = mi.Point3f(dr.gather(type(p), p, idx))
        nc = mi.Vector3f(dr.gather(type(n), n, idx))
        got = fn(pc, nc, *(dr.gather(type(a), a, idx) for a in extra))
        for o, g in zip(outs, (got,) if outputs == 0 else got, strict=True):
            if o is None:
                continue
            if into is not None:
                dr.scatter_add(o, g, idx)
            else:
                dr.scatter(o, g, idx)
    if into is not None:
        return None
    return outs[0] if outputs == 0 else outs


def ambient_irradiance(lights: LightSet, n: np.ndarray) -> np.ndarray:
    """Irradiance (W/m², ``(N, 3)``) of the SH ambient remainder for normals ``(N, 3)``,
    unoccluded (Ramamoorthi & Hanrahan 2001)."""
    if not np.any(lights.ambient_sh):
        return np.zeros((len(n), 3))
    from arlight.sphere.sh import irradiance

    return np.asarray(irradiance(lights.ambient_sh, n), np.float64).reshape(len(n), 3)


def ambient_irradiance_dr(lights: LightSet, n: mi.Vector3f) -> mi.Color3f:
    """:func:`ambient_irradiance` as a Dr.Jit expression: the 9-coefficient irradiance is a
    quadratic polynomial of the normal, ``E(n) = nᵀ A n + b·n + c`` per channel (Ramamoorthi &
    Hanrahan 2001, Eq. 12), fitted exactly from :func:`arlight.sphere.sh.irradiance` at 26
    directions (so it follows that module's basis convention)."""
    if not np.any(lights.ambient_sh):
        return mi.Color3f(0.0)
    d = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                  if (x, y, z) != (0, 0, 0)], np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e = ambient_irradiance(lights, d)  # (26, 3)
    x, y, z = d.T
    feats = np.stack([x * x, y * y, z * z, x * y, y * z, x * z, x, y, z, np.ones_like(x)], 1)
    coef, *_ = np.linalg.lstsq(feats, e, rcond=None)  # (10, 3)
    terms = [n.x * n.x, n.y * n.y, n.z * n.z, n.x * n.y, n.y * n.z, n.x * n.z, n.x, n.y, n.z]
    out = mi.Color3f(*opaques(coef[9]))
    for f, row in zip(terms, coef[:9], strict=True):
        out += mi.Color3f(*opaques(row)) * f
    return out


def virtual_bounds(world: World, view: SceneView) -> tuple[np.ndarray, np.ndarray] | None:
    """World-space bounding box (lo, hi) of the virtual shapes loaded in ``view`` (None if
    there are none)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for sh in view.scene.shapes():
        sid = sh.id()
        if not sid.isdigit() or not world.shapes[int(sid)].is_virtual:
            continue
        b = sh.bbox()
        lo = np.minimum(lo, np.array([b.min.x, b.min.y, b.min.z], np.float64))
        hi = np.maximum(hi, np.array([b.max.x, b.max.y, b.max.z], np.float64))
    return None if not np.all(np.isfinite(lo)) else (lo, hi)


def scene_bounds(view: SceneView) -> tuple[np.ndarray, float]:
    """(centre, radius) of the bounding sphere of ``view``'s geometry, metres."""
    b = view.scene.bbox()
    lo = np.array([b.min.x, b.min.y, b.min.z], np.float64)
    hi = np.array([b.max.x, b.max.y, b.max.z], np.float64)
    return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0)


__all__ = ["DirectTerms", "ambient_irradiance", "ambient_irradiance_dr", "direct_change",
           "direct_irradiance", "direct_terms",
           "direct_terms_gbuffer",
           "direct_irradiance_compact", "direct_light", "emitted_intensity", "extended",
           "light_terms", "on_active", "r2_point", "shadow_ray",
           "scene_bounds", "split_lights", "spot_falloff", "virtual_bounds"]
