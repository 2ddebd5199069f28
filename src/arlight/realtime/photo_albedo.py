"""The real surfaces' diffuse albedo read from the photograph (issue #33).

The differential methods change a real pixel by ``ρ/π ΔE`` (Franke Eq. 5.14 with the delta
irradiance ``ΔE`` of shadows, bounce and occlusion). With the proxy's albedo ``ρ`` this is
only as right as the proxy: a texture the reconstruction averaged to its mean makes the
shadow too deep on dark texels (below zero, clipped black) and too shallow on bright ones,
and a glossy highlight the light put into the photograph is never taken away. The
photograph knows the surface better: for a diffuse surface under the model's irradiance
``E_r`` (the reduced lights with shadow rays in the real proxy — the direct change's
own rays where the caller shares them — plus the SH ambient remainder) it shows
``B = ρ E_r / π``, so

    ρ̂ = clip(π B / E_r, 0, 1)                        (per channel)

is the albedo that reproduces the photograph, and ``ρ̂/π ΔE = B ΔE / E_r`` is the change
as a *ratio* of the light the pixel already receives — the multiplicative form of the
AR-OOF shadow factor (:func:`arlight.realtime.oof.shadow_factor`, ``B (f − 1)`` with
``f = (E_r + ΔE)/E_r``), which is independent of the albedo. The clip keeps ``ρ̂`` a
physical albedo where the model misses light that reaches the surface (its bounce, say:
then ``E_r`` is too small) and makes a shadow remove at most the pixel's own radiance.
Where the model gives the surface no light at all the proxy's albedo is kept.

It is the path tracers' photo-consistent change (option ``delta = ratio``) written for a
model irradiance: with ``I_r = ρ E_r / π``, ``ρ̂ = ρ s`` for
``s = clip(B / I_r, 0, 1/ρ)`` of :func:`arlight.layers.photo_scale`, the one function both
use (here on Dr.Jit lanes).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView
from arlight.jit import aligned
from arlight.layers import photo_scale
from arlight.realtime.light_reduction import LightSet
from arlight.realtime.shading import ambient_irradiance_dr, direct_irradiance, on_active


def model_irradiance(real: SceneView, lights: LightSet, p: mi.Point3f, n: mi.Vector3f,
                     active: mi.Bool, direct: mi.Color3f | None = None) -> mi.Color3f:
    """``E_r`` (W/m²) at ``p`` (normals ``n``) in the real proxy: the reduced lights'
    direct irradiance plus the SH ambient remainder (unoccluded, clamped at 0), on the
    ``active`` lanes (zero elsewhere). ``direct``: the direct part as the caller traced it
    (:func:`arlight.realtime.shading.direct_terms_gbuffer`'s ``real``: the real scene's
    visibility through the shadow rays of the direct change, soft for extended lights);
    None: one shadow ray per light traced here, for the ``active`` lanes only."""
    if direct is not None:
        e = direct
    elif lights.lights:
        e = on_active(lambda q, m: direct_irradiance(real, lights, q, m, mi.Bool(True)),
                      p, n, active)
    else:
        e = dr.zeros(mi.Color3f, dr.width(p))
    amb = dr.maximum(ambient_irradiance_dr(lights, n), 0.0)
    return dr.select(active, e + amb, mi.Color3f(0.0))


def photo_albedo(real: SceneView, lights: LightSet, frame: np.ndarray, pixel: mi.UInt32,
                 p: mi.Point3f, n: mi.Vector3f, proxy_albedo: mi.Color3f,
                 active: mi.Bool, extra: mi.Color3f | None = None,
                 direct: mi.Color3f | None = None) -> mi.Color3f:
    """Per lane ``ρ̂ = clip(π B / E_r, 0, 1)`` (module docstring): ``B`` the photograph
    ``frame`` (``(H, W, 3)`` linear radiance) at the lane's ``pixel`` (row-major index),
    ``E_r`` :func:`model_irradiance`; computed as ``ρ s`` with ``s`` =
    :func:`arlight.layers.photo_scale` of ``I_r = ρ E_r / π`` (``ρ`` = ``proxy_albedo``,
    kept on inactive lanes and in channels where ``I_r`` < :data:`arlight.layers.RATIO_MIN`).
    ``extra``: irradiance (W/m²) the caller's model adds to ``E_r`` (``dir``: the real
    scene's indirect light from its VPLs), None: none. ``direct``: ``E_r``'s direct part
    from the caller's shadow rays (:func:`model_irradiance`), None: traced here."""
    b = dr.gather(mi.Color3f, mi.Float(aligned(np.reshape(frame, -1), np.float32)), pixel)
    e_r = model_irradiance(real, lights, p, n, active, direct)
    if extra is not None:
        e_r += dr.select(active, extra, mi.Color3f(0.0))
    s = photo_scale(b, proxy_albedo * e_r * (1.0 / math.pi), proxy_albedo, dr)
    return dr.select(active, proxy_albedo * s, proxy_albedo)


__all__ = ["model_irradiance", "photo_albedo"]
