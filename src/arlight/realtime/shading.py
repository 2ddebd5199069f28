"""Shading helpers shared by the real-time methods: direct light from reduced lights with
shadow rays, SH ambient irradiance, and the virtual objects' bounding box."""

from __future__ import annotations

import math
from collections.abc import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView
from arlight.jit import opaques
from arlight.realtime.light_reduction import LightSet, ReducedLight
from arlight.scene.model import World

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
    origin = p + n * SHADOW_EPS
    for lt in lights.lights:
        if lt.kind == "directional":
            w = -mi.Vector3f(*opaques(lt.axis))
            e = mi.Color3f(*opaques(lt.intensity))
            dist = mi.Float(dr.inf)
        else:
            to = mi.Point3f(*opaques(lt.position)) - origin
            dist = dr.norm(to)
            w = to / dr.maximum(dist, 1e-12)
            e = emitted_intensity(lt, -w) / dr.maximum(dist * dist, 1e-12)
        cos = dr.maximum(dr.dot(n, w), 0.0)
        lit = active & (cos > 0.0)
        if shadows:
            ray = mi.Ray3f(origin, w)
            ray.maxt = dr.select(dr.isinf(dist), dr.largest(mi.Float), dist * (1.0 - 1e-4))
            lit &= ~view.scene.ray_test(ray, lit)
        out += dr.select(lit, e * cos, mi.Color3f(0.0))
        if spec is not None:
            spec += dr.select(lit, e * specular(w), mi.Color3f(0.0))
    return out, spec


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


def on_active(fn, p: mi.Point3f, n: mi.Vector3f, active: mi.Bool) -> mi.Color3f:
    """``fn(p, n)`` evaluated on the ``active`` lanes only (compacted with ``dr.compress``,
    scattered back; zero elsewhere): pays off for costly per-lane work on few lanes."""
    idx = dr.compress(active)
    out = dr.zeros(mi.Color3f, dr.width(p))
    if dr.width(idx) == 0:
        return out
    pc = mi.Point3f(dr.gather(type(p), p, idx))
    nc = mi.Vector3f(dr.gather(type(n), n, idx))
    dr.scatter(out, fn(pc, nc), idx)
    return out


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


__all__ = ["ambient_irradiance", "ambient_irradiance_dr", "direct_irradiance",
           "direct_irradiance_compact", "direct_light", "emitted_intensity", "on_active",
           "scene_bounds", "split_lights", "spot_falloff", "virtual_bounds"]
