"""Differential irradiance at cache records by one-pass path tracing (Kán thesis §4.2.2).

All records of an iteration are evaluated in one wavefront: lane ``l`` is ray ``l % N`` of
record ``l // N``. Each ray leaves the record in a cosine-weighted direction about its normal
and is a *mixed radiance ray* of the one-pass tracer (:class:`arlight.tracing.onepass.
OnePassTracer`, its four ray types and hit rules: a real continuation ray where it hits a
virtual object, mixed and real shadow rays at real hits, random multi-bounce continuation), so

    E_m ≈ (π/N) Σ L_m,i,   E_r ≈ (π/N) Σ L_r,i,   E_d = E_m − E_r          (Eq. 4.6–4.10)

with the tracer collecting no emission at the ray's first hit (``first_emission_depth = 1``):
the records hold *indirect* irradiance, the direct light being computed from the camera.
``R_i`` is the minimum distance of the first hits (Tabellion & Lamorlette), in the mixed view.

The directions are a Fibonacci lattice on the unit square (``u_k = (k + s_1)/N mod 1``,
``v_k = k φ + s_2 mod 1``) with a per-record random shift ``s`` (Cranley–Patterson rotation,
unbiased), mapped to the cosine-weighted hemisphere; the shift and the tracer's per-lane keys
come from the record's 32-bit key — its fixed random sequence, so a re-evaluated record of a
static scene gets bitwise the same value (Kán §4.2.1: temporal coherence).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneViews
from arlight.backend.rays import np3
from arlight.jit import MAX_LANES, aligned, columns
from arlight.realtime.shading import SHADOW_EPS
from arlight.tracing.onepass import RAY_TYPES, OnePassTracer, TracerOptions

GOLDEN = 0.6180339887498949


def record_tracer(views: SceneViews, max_depth: int, rr_depth: int) -> OnePassTracer:
    """The one-pass tracer for record rays, for paths of at most ``max_depth`` vertices
    counted from the camera (Mitsuba's convention; -1 unlimited).

    A record ray's first hit is the camera path's third vertex, so the tracer runs one
    vertex shorter, with Russian roulette one vertex earlier; no camera-image reprojection
    (the records integrate the proxy's light).
    """
    md = -1 if max_depth < 0 else max(max_depth - 1, 1)
    return OnePassTracer(views.mixed, views.real,
                         TracerOptions(max_depth=md, rr_depth=max(rr_depth - 1, 0),
                                       reproject=False, first_emission_depth=1))


@dataclass
class RecordValues:
    """Per-record results (NumPy float64): irradiances (W/m²) and their standard errors,
    the minimum hit distance (m, inf if every ray escaped), ray counts by type."""

    e_mixed: np.ndarray
    e_real: np.ndarray
    stderr_mixed: np.ndarray
    stderr_delta: np.ndarray
    radius: np.ndarray
    rays: dict[str, int]

    @property
    def e_delta(self) -> np.ndarray:
        return self.e_mixed - self.e_real


def _record_rays(pos: mi.Point3f, nrm: mi.Vector3f, key: mi.UInt32, k: mi.UInt32,
                 n_rays: int) -> tuple[mi.Ray3f, mi.UInt32]:
    """Cosine-weighted rays (lattice with the record's shift) and per-lane tracer keys."""
    s1 = mi.sample_tea_float32(key, mi.UInt32(1), 6)
    s2 = mi.sample_tea_float32(key, mi.UInt32(2), 6)
    kf = mi.Float(k)
    u = _frac((kf + s1) / float(n_rays))
    v = _frac(kf * GOLDEN + s2)
    local = mi.warp.square_to_cosine_hemisphere(mi.Point2f(u, v))
    frame = mi.Frame3f(nrm)
    d = dr.normalize(frame.to_world(local))
    scale = 1.0 + dr.max(dr.abs(mi.Vector3f(pos)))
    origin = pos + nrm * (SHADOW_EPS * scale)
    lane_key = mi.sample_tea_32(k, key, 4)[0]
    return mi.Ray3f(origin, d), lane_key


def _chunk_rays(position: np.ndarray, normal: np.ndarray, keys: np.ndarray, n_rays: int,
                a: int, b: int) -> tuple[mi.Ray3f, mi.UInt32]:
    """The rays (and tracer keys) of records ``a:b``, lane ``l`` = ray ``l % N`` of record
    ``a + l // N``."""
    lanes = (b - a) * n_rays
    lane = dr.arange(mi.UInt32, lanes)
    rec = lane // n_rays
    k = lane - rec * n_rays
    pos = dr.gather(mi.Point3f, mi.Point3f(*columns(position[a:b], np.float32)), rec)
    nrm = dr.gather(mi.Vector3f, mi.Vector3f(*columns(normal[a:b], np.float32)), rec)
    key = dr.gather(mi.UInt32, mi.UInt32(aligned(keys[a:b], np.uint32)), rec)
    return _record_rays(pos, nrm, key, k, n_rays)


def record_radius(views: SceneViews, position: np.ndarray, normal: np.ndarray,
                  keys: np.ndarray, n_rays: int) -> np.ndarray:
    """``R_i`` alone (m): the minimum first-hit distance of exactly the rays
    :func:`evaluate_records` traces, from one intersection kernel — what splat weights and
    cache-miss detection need, without the paths."""
    m = len(position)
    radius = np.full(m, np.inf)
    per = max(MAX_LANES // n_rays, 1)
    for a in range(0, m, per):
        b = min(a + per, m)
        rays, _ = _chunk_rays(position, normal, keys, n_rays, a, b)
        t = views.mixed.scene.ray_intersect_preliminary(rays).t
        radius[a:b] = np.asarray(t, np.float64).reshape(b - a, n_rays).min(axis=1)
    return radius


def evaluate_records(tracer: OnePassTracer, views: SceneViews, position: np.ndarray,
                     normal: np.ndarray, keys: np.ndarray, n_rays: int) -> RecordValues:
    """Mixed and real indirect irradiance at records ``(M, 3)`` with ``n_rays`` rays each.

    One wavefront per at most :data:`MAX_LANES` lanes (usually one launch per iteration).
    """
    if n_rays < 1:
        raise ValueError(f"n_rays must be >= 1, got {n_rays}")
    m = len(position)
    e_m = np.zeros((m, 3))
    e_r = np.zeros((m, 3))
    se_m = np.zeros((m, 3))
    se_d = np.zeros((m, 3))
    radius = np.full(m, np.inf)
    counts = dict.fromkeys(RAY_TYPES, 0)
    per = max(MAX_LANES // n_rays, 1)
    for a in range(0, m, per):
        b = min(a + per, m)
        rays, lane_key = _chunk_rays(position, normal, keys, n_rays, a, b)
        t = views.mixed.scene.ray_intersect_preliminary(rays).t
        res = tracer.trace_onepass(rays, lane_key)
        dr.eval(res.mixed, res.real, t)
        for kname, v in res.rays.items():
            counts[kname] += v
        lm = np3(res.mixed).reshape(b - a, n_rays, 3) * np.pi
        lr = np3(res.real).reshape(b - a, n_rays, 3) * np.pi
        e_m[a:b] = lm.mean(axis=1)
        e_r[a:b] = lr.mean(axis=1)
        if n_rays > 1:
            se_m[a:b] = lm.std(axis=1, ddof=1) / np.sqrt(n_rays)
            se_d[a:b] = (lm - lr).std(axis=1, ddof=1) / np.sqrt(n_rays)
        else:
            se_m[a:b] = se_d[a:b] = np.inf
        radius[a:b] = np.asarray(t, np.float64).reshape(b - a, n_rays).min(axis=1)
    return RecordValues(e_m, e_r, se_m, se_d, radius, counts)


def _frac(x: mi.Float) -> mi.Float:
    """``x mod 1`` in [0, 1)."""
    return dr.minimum(x - dr.floor(x), dr.one_minus_epsilon(mi.Float))


__all__ = ["RecordValues", "evaluate_records", "record_radius", "record_tracer"]
