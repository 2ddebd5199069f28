"""Radiance transfer with short-range visibility (Gruber et al. 2014, digest E3), batched.

For a Lambertian point ``x`` with normal ``n`` the transfer vector of the 16 SH coefficients
(4 bands) is

    T_k(x) = Σ_j  w · V(x, ω_j) · max(0, n·ω_j) · Y_k(ω_j)          (E3, w = 4π/N sr)

over the world-fixed directions ``ω_j`` of :class:`~arlight.probeless.directions.DirectionSet`;
``V`` tests occlusion only up to ``max_distance`` (10 cm in the paper). It is evaluated as
the exact unoccluded transfer (E6, ``Â_l Y_lm(n)``) minus the quadrature of the *blocked*
directions,

    T_k(x) = Â_l Y_k(n) − Σ_j w · (1 − V(x, ω_j)) · max(0, n·ω_j) · Y_k(ω_j),

equal to E3 with the cosine lobe integrated exactly instead of by 81 samples (their error is
~3 % of ‖T‖ and puts energy in band 3, where the clamped cosine has none): a point with no
blocked ray gets exactly E6, the transfer the visibility-state cache gives its free points
without rays, so cached and cast points no longer disagree (issue #33: on Gruber's static
sequence ART4's upper-hemisphere error had been 0.01–0.02 above REG4's for that reason). A
subset of the directions carries ``|subset|/N`` of the E6 term. It is evaluated twice:
against the reconstruction only (``T_real``) and against reconstruction + virtual objects
(``T_mix``). All rays of a call go to Mitsuba in one batch (``Scene.ray_test``; chunked only to
bound memory); the per-point sums are one matrix product. The mixed scene contains the real
one, so a ray unblocked in the mixed scene is unblocked in the real one: real-scene rays are
cast only where the mixed ray was blocked (and none when there is no virtual object).

Any subset of the directions can be evaluated (interleaved sampling): SH projection is linear,
so the partial transfers of disjoint subsets add up to the full transfer.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_REAL, SceneView, SceneViews
from arlight.probeless.directions import N_COEFFS, DirectionSet, unoccluded_transfer

MAX_DISTANCE = 0.10
"""Visibility rays end after this distance (m), Gruber §3. Kept after issue #33's choice on
training light setups with a near-lamp guard (``benchmarks/tune_light_estimation.py --part
setups``; kept again with the plane-fit normals): longer ranges lower the error under
distant light (Gruber's held-out cap light 0.290 → 0.255 at 0.2 m) but turn the estimate
away from a near lamp, whose shadows no distant direction casts (bunny-box dot 0.99 → 0.97
at 0.2 m, 0.77 at 1 m; docs/methods/probeless.md, *Near lamps and the visibility range*)."""
RAY_OFFSET = 2e-3
"""Ray origins are moved this far (m) along the normal, off the surface they start on."""
_CHUNK = 1 << 22  # rays per Mitsuba batch (memory bound, not a per-ray loop)
_POINTS = 1 << 16  # points per batch of compute_transfer


@dataclass
class Transfer:
    """Transfer vectors of ``M`` points.

    Attributes:
        real: ``T_real`` ``(M, 16)``, visibility against the reconstruction only (sr).
        mixed: ``T_mix`` ``(M, 16)``, visibility against reconstruction + virtual objects.
        cast: rays cast per point in the mixed scene (directions above the horizon).
        blocked: of those, how many were blocked in the mixed scene.
        rays: total rays cast (mixed + real), for the ray counts of the variants.
    """

    real: np.ndarray
    mixed: np.ndarray
    cast: np.ndarray
    blocked: np.ndarray
    rays: int

    @staticmethod
    def zeros(m: int) -> Transfer:
        z = np.zeros((m, N_COEFFS))
        return Transfer(z, z.copy(), np.zeros(m, np.int64), np.zeros(m, np.int64), 0)

    @property
    def blocked_fraction(self) -> np.ndarray:
        """Blocked share of the cast rays per point (0 where none was cast)."""
        return self.blocked / np.maximum(self.cast, 1)


def _ray_test(view: SceneView, origins: np.ndarray, dirs: np.ndarray,
              max_distance: float) -> np.ndarray:
    """Occlusion of the rays ``origins + t dirs``, ``0 < t < max_distance``; bool ``(L,)``."""
    out = np.empty(len(origins), dtype=bool)
    for a in range(0, len(origins), _CHUNK):
        o = np.ascontiguousarray(origins[a:a + _CHUNK].T, dtype=np.float32)
        d = np.ascontiguousarray(dirs[a:a + _CHUNK].T, dtype=np.float32)
        ray = mi.Ray3f(mi.Point3f(o[0], o[1], o[2]), mi.Vector3f(d[0], d[1], d[2]))
        ray.maxt = mi.Float(float(max_distance))
        occ = view.scene.ray_test(ray)
        dr.eval(occ)
        out[a:a + _CHUNK] = np.array(occ, dtype=bool)
    return out


def _lanes(normals: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point index, direction index and cosine of every (point, direction) pair above the
    point's horizon (the only rays worth casting: the others have zero weight)."""
    cos = normals @ dirs.T
    ii, jj = np.nonzero(cos > 0.0)
    return ii, jj, cos[ii, jj]


def compute_transfer(views: SceneViews, points: np.ndarray, normals: np.ndarray,
                     directions: DirectionSet, subset: np.ndarray | None = None,
                     need_real: np.ndarray | None = None,
                     max_distance: float = MAX_DISTANCE,
                     ray_offset: float = RAY_OFFSET) -> Transfer:
    """Partial transfer (E3) of ``points (M, 3)`` with unit ``normals (M, 3)`` over the
    directions ``subset`` (indices into ``directions``; default all).

    ``need_real (M,)``: points that need ``T_real`` (real pixels; default all). Elsewhere no
    real-scene ray is cast and ``T_real`` is the unoccluded sum: not meaningful, unused.
    """
    return compute_transfers(views, [(points, normals, subset, need_real)], directions,
                             max_distance, ray_offset)[0]


Group = tuple[np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None"]
"""``(points, normals, subset, need_real)``: one group of :func:`compute_transfers`."""


@dataclass
class _Batch:
    """At most ``_POINTS`` points of one group and their rays: point index ``ii``, direction
    index ``jj`` (into ``subset``) and cosine of every pair above the point's horizon."""

    group: int
    normals: np.ndarray
    subset: np.ndarray
    ii: np.ndarray
    jj: np.ndarray
    cos: np.ndarray
    origins: np.ndarray
    dirs: np.ndarray
    need_real: np.ndarray | None


def _batches(groups: list[Group], directions: DirectionSet, ray_offset: float
             ) -> list[_Batch]:
    """The groups split into batches of at most ``_POINTS`` points (bounding the
    points × directions matrices), with their rays."""
    out = []
    for g, (points, normals, subset, need_real) in enumerate(groups):
        points = np.asarray(points, np.float64).reshape(-1, 3)
        normals = np.asarray(normals, np.float64).reshape(-1, 3)
        idx = np.arange(directions.n) if subset is None else np.asarray(subset)
        nr = None if need_real is None else np.asarray(need_real, bool)
        if len(points) == 0 or len(idx) == 0:
            out.append(_Batch(g, normals, idx, *(np.zeros(0, np.int64),) * 2, np.zeros(0),
                              np.zeros((0, 3)), np.zeros((0, 3)), None))
            continue
        d = directions.directions[idx]
        for a in range(0, len(points), _POINTS):
            p, n = points[a:a + _POINTS], normals[a:a + _POINTS]
            ii, jj, cos = _lanes(n, d)
            out.append(_Batch(g, n, idx, ii, jj, cos, p[ii] + ray_offset * n[ii], d[jj],
                              None if nr is None else nr[a:a + _POINTS]))
    return out


def compute_transfers(views: SceneViews, groups: list[Group], directions: DirectionSet,
                      max_distance: float = MAX_DISTANCE,
                      ray_offset: float = RAY_OFFSET) -> list[Transfer]:
    """:func:`compute_transfer` of several groups of points, each with its own direction
    subset, the rays of all groups cast as one batch per scene view (ART's interleaved
    phases: the current phase of every sample and the other phases of the samples the
    reprojection caches miss, issue #33). Each group's result is bit for bit what its own
    :func:`compute_transfer` call gives (rays are independent; the per-point sums are the
    same products); one batch instead of up to ``k`` saves the per-call cost of a Mitsuba
    ray batch and of its NumPy set-up."""
    batches = _batches(groups, directions, ray_offset)
    origins = np.concatenate([b.origins for b in batches])
    dirs = np.concatenate([b.dirs for b in batches])
    occ_m = (_ray_test(views.mixed, origins, dirs, max_distance) if len(origins)
             else np.zeros(0, bool))
    same = views.real is views.mixed
    occ_r = occ_m
    ask = np.zeros(len(occ_m), bool)
    if not same:
        ask = occ_m.copy()
        start = 0
        for b in batches:
            if b.need_real is not None:
                ask[start:start + len(b.ii)] &= b.need_real[b.ii]
            start += len(b.ii)
        occ_r = np.zeros_like(occ_m)
        if np.any(ask):
            occ_r[ask] = _ray_test(views.real, origins[ask], dirs[ask], max_distance)
    parts: list[list[Transfer]] = [[] for _ in groups]
    start = 0
    for b in batches:
        sl = slice(start, start + len(b.ii))
        start += len(b.ii)
        if len(b.normals) == 0 or len(b.subset) == 0:
            parts[b.group].append(Transfer.zeros(len(b.normals)))
            continue
        rays = len(b.ii) + int(ask[sl].sum())
        parts[b.group].append(_assemble(b, directions, occ_m[sl],
                                        occ_m[sl] if same else occ_r[sl], same, rays))
    return [ps[0] if len(ps) == 1 else
            Transfer(np.concatenate([p.real for p in ps]), np.concatenate([p.mixed for p in ps]),
                     np.concatenate([p.cast for p in ps]),
                     np.concatenate([p.blocked for p in ps]), sum(p.rays for p in ps))
            for ps in parts]


def _assemble(b: _Batch, directions: DirectionSet, occ_m: np.ndarray, occ_r: np.ndarray,
              same: bool, rays: int) -> Transfer:
    """E3 of one batch as "unoccluded minus occluded": the subset's share of the exact
    unoccluded transfer (E6) less the quadrature of the blocked directions (``same``: no
    virtual object, ``T_real = T_mix``)."""
    m, ii, jj = len(b.normals), b.ii, b.jj
    Y = directions.basis[b.subset]
    w = directions.weight
    free = unoccluded_transfer(b.normals) * (len(b.subset) / directions.n)
    Cm = np.zeros((m, len(b.subset)))
    Cm[ii, jj] = w * b.cos * occ_m
    mixed = free - Cm @ Y
    if same:
        real = mixed.copy()
    else:
        Cr = np.zeros((m, len(b.subset)))
        Cr[ii, jj] = w * b.cos * occ_r
        real = free - Cr @ Y
    cast = np.bincount(ii, minlength=m)
    blocked = np.bincount(ii, weights=occ_m.astype(np.float64), minlength=m).astype(np.int64)
    return Transfer(real=real, mixed=mixed, cast=cast, blocked=blocked, rays=rays)


def real_hits_from(views: SceneViews, points: np.ndarray, normals: np.ndarray,
                   directions: DirectionSet, subset: np.ndarray | None = None,
                   max_distance: float = MAX_DISTANCE,
                   ray_offset: float = RAY_OFFSET) -> tuple[np.ndarray, int]:
    """World points ``(H, 3)`` where visibility rays from ``points`` (virtual surface points)
    hit *real* geometry within ``max_distance`` in the mixed scene, and the rays cast: the
    real surfaces a virtual object can shadow (Gruber §3.1, dense real samples)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros((0, 3)), 0
    idx = np.arange(directions.n) if subset is None else np.asarray(subset)
    d = directions.directions[idx]
    ii, jj, _ = _lanes(np.asarray(normals, np.float64).reshape(-1, 3), d)
    o = points[ii] + ray_offset * normals[ii]
    dd = d[jj]
    found = []
    for a in range(0, len(ii), _CHUNK):
        oo = np.ascontiguousarray(o[a:a + _CHUNK].T, dtype=np.float32)
        dv = np.ascontiguousarray(dd[a:a + _CHUNK].T, dtype=np.float32)
        ray = mi.Ray3f(mi.Point3f(oo[0], oo[1], oo[2]), mi.Vector3f(dv[0], dv[1], dv[2]))
        ray.maxt = mi.Float(float(max_distance))
        si = views.mixed.scene.ray_intersect(ray)
        role = views.mixed.hit_role(si)
        dr.eval(si.p, role)
        hit = np.array(role, dtype=np.int32) == ROLE_REAL
        found.append(np.array(si.p, dtype=np.float64).T[hit])
    return (np.concatenate(found) if found else np.zeros((0, 3))), len(ii)


__all__ = ["MAX_DISTANCE", "RAY_OFFSET", "Transfer", "compute_transfer", "compute_transfers",
           "real_hits_from"]
