"""Which real points the virtual objects can shadow: a conservative test per lane (issue #33).

The virtual objects' change of the reduced lights' direct irradiance at a real point ``p``,
``ΔE_d = Σ_i E⊥_i <n, ω_i>+ (V_ρ,i − V_µ,i)`` (:func:`arlight.realtime.shading.
direct_terms`), is zero unless one of the shadow rays from ``p`` to light ``i`` meets a
virtual object: the mixed scene is the real one plus the virtual objects, so a ray that
misses them is blocked in both or in neither. Every such ray lies in a cone from ``p``:

* a directional light of angular radius ``spread`` (``σ``): the rays ``p + t ω`` with
  ``∠(ω, ω_0) ≤ σ`` around its direction ``ω_0``;
* a point, spot or ``cosine`` light at ``q`` with a patch of half-edge vectors ``a, b``
  (``extent``): the segments from ``p`` to the points of ``q ± a ± b``, inside the ball of
  radius ``r_e = |a| + |b|`` around ``q``, hence inside the cone of half-angle
  ``asin(r_e / |q − p|)`` around ``q − p`` and no longer than ``|q − p| + r_e``.

A ball (centre ``c``, radius ``R``) meets a cone of apex ``p``, axis ``u`` and half-angle
``θ`` only if ``∠(c − p, u) ≤ θ + asin(R / |c − p|)`` (the ball subtends that half-angle
from ``p``; ``p`` inside the ball always passes), and a segment of length ``ℓ`` only if
``|c − p| − R ≤ ℓ``. Lanes that fail the test for every light cannot change: their shadow
rays (two scenes × ``shadow_samples`` per extended light) need not be cast. The test is
exact in the sense that it never drops a lane whose change is non-zero (the bounding ball
holds every virtual triangle), and costs a few flops per lane and light.
:func:`arlight.realtime.shading.direct_terms_gbuffer` (``world=``) culls with it: a lane
a light cannot reach traces that light's rays in the real scene only (for the real scene's
own irradiance ``E_µ,d``, where it is wanted), and no ray where it is not.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import opaque, opaques
from arlight.realtime.light_reduction import LightSet, ReducedLight

PAD = 1e-3
"""Relative padding of the bounding ball's radius (and ``1e-4`` m absolute): the shadow
rays start ``SHADOW_EPS`` off the surface and float round-off must not cull a grazing ray."""


def bounding_ball(box: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, float]:
    """Centre and radius (m) of the ball around an axis-aligned box ``(lo, hi)``, padded by
    :data:`PAD`."""
    lo, hi = (np.asarray(b, np.float64) for b in box)
    r = float(np.linalg.norm(hi - lo)) / 2.0
    return (lo + hi) / 2.0, r * (1.0 + PAD) + 1e-4


def _angle(u: mi.Vector3f, v: mi.Vector3f) -> mi.Float:
    """Angle (rad) between two non-zero vectors."""
    return dr.acos(dr.clip(dr.dot(u, v) * dr.rsqrt(dr.maximum(
        dr.squared_norm(u) * dr.squared_norm(v), 1e-30)), -1.0, 1.0))


def _half_angle(radius: float | mi.Float, dist: mi.Float) -> mi.Float:
    """Half-angle (rad) a ball of ``radius`` subtends at ``dist`` (π where ``dist ≤
    radius``: the apex is inside)."""
    return dr.select(dist > radius, dr.asin(dr.minimum(radius / dr.maximum(dist, 1e-30), 1.0)),
                     math.pi)


def light_reach(light: ReducedLight, p: mi.Point3f, centre: mi.Point3f,
                radius: float | mi.Float) -> mi.Bool:
    """Whether a shadow ray from ``p`` to ``light`` (any point of its extent) can meet the
    ball ``(centre, radius)`` (module docstring; True may be a false positive, False never a
    false negative)."""
    to_c = centre - p
    d_c = dr.norm(to_c)
    ball = _half_angle(radius, d_c)
    if light.kind == "directional":
        w0 = -mi.Vector3f(*opaques(light.axis))
        return _angle(to_c, w0) <= ball + opaque(light.spread)
    q = mi.Point3f(*opaques(light.position))
    ext = np.asarray(light.extent, np.float64).reshape(-1, 3)
    r_e = opaque(float(np.linalg.norm(ext, axis=1).sum()) if ext.size else 0.0)
    to_q = q - p
    d_q = dr.norm(to_q)
    return ((_angle(to_c, to_q) <= ball + _half_angle(r_e, d_q))
            & (d_c - radius <= d_q + r_e))


def shadow_reach(lights: LightSet, p: mi.Point3f, ball: tuple[np.ndarray, float]
                 ) -> mi.Bool:
    """Lanes where some light's shadow rays can meet the virtual objects' bounding ``ball``
    (:func:`bounding_ball`): the only lanes whose direct change can be non-zero."""
    centre, radius = mi.Point3f(*opaques(ball[0])), opaque(ball[1])
    out = dr.zeros(mi.Bool, dr.width(p))
    for lt in lights.lights:
        out |= light_reach(lt, p, centre, radius)
    return out


__all__ = ["PAD", "bounding_ball", "light_reach", "shadow_reach"]
