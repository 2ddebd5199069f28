"""Final shading of differential irradiance caching: direct light by the one-pass rules from
the camera plus albedo × cached indirect irradiance, read through the reprojection into the
splat buffer (Kán thesis §4.2, §4.2.5, §3.3).

Each camera sample follows a *Whitted* walk: at every vertex it collects emission (seen by
the camera or through delta-specular bounces), and at a vertex with a smooth BSDF it adds

* direct light: one light sample (the tracer's :class:`LightSelection`, environment maps
  importance-sampled) and one BSDF sample whose ray only collects emission, combined by the
  power heuristic as the one-pass tracer's first vertex, with the one-pass rules: a mixed
  shadow ray and, on a walk that has not touched a virtual object, a real one where the
  mixed one is blocked (µ ⊂ ρ); the BSDF ray is mixed, with a real one where it hits a
  virtual object. (The records collect no emission at their rays' first hits, so light
  reaching the vertex directly is counted here only);
* indirect light: ``ρ_d / π · E`` with ``E`` read from the splat buffer at the pixel the
  vertex *projects to* (Kán §4.2.5; outside the image the buffer is tiled repetitively), so
  depth of field, antialiasing samples, mirrors and glass read the irradiance of the points
  they actually see; ``E_m`` for the mixed solution, ``E_m − E_d`` for the real one.

and ends there; delta-specular vertices (mirrors, glass, Mitsuba's stochastic
reflect/refract choice) continue the walk, and so — with ``glossy`` (dic's default, issue
#33) — do glossy vertices without a diffuse lobe (rough metals, rough glass), along the BSDF
sample whose emission the vertex just counted (MIS-weighted; the next vertex does not count
it again): the cache holds diffuse irradiance only, so without this a rough metal showed
direct light alone. Glossy lobes beside a diffuse one (phong, plastic) are not continued:
their indirect glossy reflection is still missing. The walk has no rules of its own: it follows the
one-pass tracer's (:mod:`arlight.tracing.onepass`) — :class:`HitRules` (a mixed walk that
hits a virtual object forks: it goes on mixed-only, and its *real continuation*, the ray
passing through the virtual object, is traced afterwards for the forked lanes only, in µ
from their camera rays; the shadow rays of rules 1 and 3), :class:`LightSelection` (dic hands
it the record tracer's) and the tracer's random dimensions of a
:class:`~arlight.sampling.stream.LaneSampler` (``rand_nee``, ``rand_lobe``, ``rand_bsdf``:
functions of (lane, depth, dimension), so the retraced shared prefix is bit for bit the
same). With paths of two vertices the walk *is* the tracer's direct-light estimator, sample
by sample (``tests/tracing/test_shared_rules.py``). Without a virtual object every walk is
shared and ``L_m == L_r`` exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import Projection
from arlight.backend.mitsuba_scene import ROLE_VIRTUAL, SceneView, SceneViews
from arlight.backend.rays import np3
from arlight.jit import aligned, columns, opaque
from arlight.realtime.gbuffer import facing, surface_albedo
from arlight.sampling.stream import LaneSampler
from arlight.scene.camera import Camera
from arlight.tracing.irradiance_cache import (
    NORMAL_SCALE,
    Records,
    SplatGeometry,
    effective_radius,
)
from arlight.tracing.onepass import (
    HitRules,
    LightSelection,
    as_sampler,
    hit_emitter,
    hit_sample,
    mis_weight,
    rand_bsdf,
    rand_lobe,
    rand_nee,
)

UNLIMITED_SPECULAR = 16
"""Longest delta-specular chain when ``max_depth = -1``."""
WALK_COUNTERS = ("rays_mixed_radiance", "rays_real_radiance", "rays_mixed_shadow",
                 "rays_real_shadow", "rays_mixed_radiance_direct", "rays_real_radiance_direct",
                 "lookups", "lookups_rejected", "lookups_unresolved")
"""Per-lane counters of the camera walk: rays by type, and the splat-buffer lookups of the
mixed walk — all, those whose pixel failed the depth/normal check, and those of them no
record weighed on (the pixel's value kept)."""


_HASH = (73856093, 19349663, 83492791)
"""Multipliers of the grid's spatial hash (Teschner et al. 2003), modulo 2³²."""
_GRID_PAIRS_PER_RECORD = 32
"""(cell, record) pairs a :class:`RecordGrid` holds per record at most (its cell size
doubles until they fit): building millions of pairs cost seconds per frame on outdoor
worlds whose far records have footprints 100× the near ones."""


def _cell_hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, mask: int) -> np.ndarray:
    """Bucket of integer cells ``(ix, iy, iz)``: ``(ix·A ⊕ iy·B ⊕ iz·C) mod 2³² & mask``,
    the same bits as :meth:`RecordGrid.bucket` on the device."""
    out = np.zeros(np.shape(ix), np.uint64)
    for c, m in zip((ix, iy, iz), _HASH, strict=True):
        out ^= ((np.asarray(c, np.int64) & 0xFFFFFFFF).astype(np.uint64) * np.uint64(m)
                ) & np.uint64(0xFFFFFFFF)
    return (out & np.uint64(mask)).astype(np.int64)


class RecordGrid:
    """World-space search over the cache records on the device: Tabellion-weighted
    interpolation (Eq. 2.15, 4.11) at any point, the fallback of a lookup the splat buffer
    cannot serve (Ward's irradiance cache is searched in world space, Kán §2.4.2/§4.2.4).

    A uniform grid of cell size ``h`` hashed into a table of ``T`` buckets (CSR lists of
    record indices): each record is listed in every bucket of a cell that its footprint's
    bounding cube (``‖x − x_i‖ < R_i/(2κ)``, the clamped ``R_i`` of
    :func:`~arlight.tracing.irradiance_cache.effective_radius`) overlaps, so a point's own
    cell lists every record whose weight can be positive there (hash collisions only add
    candidates; each is weighted exactly). ``h`` starts at the 90th-percentile footprint
    diameter and doubles until at most :data:`_GRID_PAIRS_PER_RECORD` pairs per record are
    listed (longer lists cost only the rejected lookups that walk them).

    The cubes are those of the *relaxed* footprint ``RELAX · R_i/(2κ)``: a point no record
    weighs on at ``κ`` (a silhouette's grazing side, the floor just behind an object) is
    interpolated at ``κ/RELAX`` (twice the footprint, normals within 20°) rather than left
    to the wrong pixel.
    """

    RELAX = 2.0
    """Footprint factor of the relaxed search (its κ is ``κ / RELAX``)."""

    def __init__(self, records: Records, camera: Camera, kappa: float, min_px: float,
                 max_px: float):
        n = len(records)
        radius, _, _ = effective_radius(records, camera, kappa, min_px, max_px)
        foot = self.RELAX * radius / (2.0 * kappa)  # relaxed w_i > 0 inside this (m)
        x = np.asarray(records.position, np.float64)
        # float32 rounding of the device's cell index: pad the cubes by more than it
        pad = 1e-5 * (1.0 + np.abs(x).max(initial=0.0)) + 1e-7
        h = max(2.0 * float(np.percentile(foot, 90)) if n else 1.0, 1e-6)
        while True:
            lo = np.floor((x - (foot + pad)[:, None]) / h).astype(np.int64)
            hi = np.floor((x + (foot + pad)[:, None]) / h).astype(np.int64)
            ext = hi - lo + 1
            counts = ext.prod(axis=1)
            if counts.sum() <= _GRID_PAIRS_PER_RECORD * max(n, 1):
                break
            h *= 2.0
        size = 1 << max(10, int(np.ceil(np.log2(max(2 * n, 1)))))
        rec = np.repeat(np.arange(n), counts)
        local = np.arange(len(rec)) - np.repeat(np.cumsum(counts) - counts, counts)
        e = ext[rec]
        cell = lo[rec] + np.stack([local % e[:, 0], (local // e[:, 0]) % e[:, 1],
                                   local // (e[:, 0] * e[:, 1])], axis=1)
        bucket = _cell_hash(cell[:, 0], cell[:, 1], cell[:, 2], size - 1)
        pairs = np.unique(bucket * max(n, 1) + rec)  # one entry per (bucket, record)
        bucket, rec = pairs // max(n, 1), pairs % max(n, 1)
        start = np.searchsorted(bucket, np.arange(size + 1))
        self.cell_size, self.buckets, self.pairs = h, size, len(rec)
        self.start = mi.UInt32(aligned(start, np.uint32))
        self.entries = mi.UInt32(aligned(np.append(rec, 0), np.uint32))
        self.position = mi.Point3f(*columns(x, np.float32))
        self.normal = mi.Vector3f(*columns(records.normal, np.float32))
        self.inv_half = mi.Float(aligned(2.0 / np.maximum(radius, 1e-30), np.float32))
        self.e_mixed = mi.Color3f(*columns(records.e_mixed, np.float32))
        self.e_delta = mi.Color3f(*columns(records.e_delta, np.float32))
        self.inv_h = opaque(1.0 / h)
        self.mask = dr.opaque(mi.UInt32, size - 1)
        self.kappa = opaque(kappa)
        self.empty = n == 0

    def bucket(self, p: mi.Point3f) -> mi.UInt32:
        """The hash bucket of the grid cell holding ``p``."""
        out = mi.UInt32(0)
        for c, m in zip((p.x, p.y, p.z), _HASH, strict=True):
            i = mi.Int32(dr.floor(c * self.inv_h))
            out ^= dr.reinterpret_array(mi.UInt32, i) * m
        return out & self.mask

    def interpolate(self, p: mi.Point3f, n: mi.Vector3f, active: mi.Bool
                    ) -> tuple[mi.Float, mi.Color3f, mi.Color3f]:
        """``(Σ w_i, Σ w_i E_m,i, Σ w_i E_d,i)`` over the records with ``w_i(p, n) > 0``
        (Eq. 2.15 at κ; where none has, the same at ``κ/RELAX``; ``n`` unit, facing the side
        the records were made from)."""
        zero = dr.zeros(mi.Float, dr.width(p))
        if self.empty:
            return zero, mi.Color3f(zero), mi.Color3f(zero)
        b = self.bucket(p)
        i0 = dr.gather(mi.UInt32, self.start, b, active)
        i1 = dr.gather(mi.UInt32, self.start, b + 1, active)
        scale = NORMAL_SCALE / math.sqrt(2.0)

        relaxed = self.kappa * (1.0 / self.RELAX)

        def cond(i, *_):
            return active & (i < i1)

        def body(i, ws, wm, wd, vs, vm, vd):
            act = active & (i < i1)
            r = dr.gather(mi.UInt32, self.entries, i, act)
            xi = dr.gather(mi.Point3f, self.position, r, act)
            ni = dr.gather(mi.Vector3f, self.normal, r, act)
            dist = dr.norm(p - xi) * dr.gather(mi.Float, self.inv_half, r, act)
            err = dr.maximum(dist, dr.norm(n - ni) * scale)
            w = 1.0 - self.kappa * err
            v = 1.0 - relaxed * err
            ok = act & (v > 0.0)
            em = dr.gather(mi.Color3f, self.e_mixed, r, ok)
            ed = dr.gather(mi.Color3f, self.e_delta, r, ok)
            w = dr.select(ok & (w > 0.0), w, 0.0)
            v = dr.select(ok, v, 0.0)
            return i + 1, ws + w, wm + w * em, wd + w * ed, vs + v, vm + v * em, vd + v * ed

        z3 = mi.Color3f(zero)
        _, ws, wm, wd, vs, vm, vd = dr.while_loop(
            state=(mi.UInt32(i0), zero, z3, z3, zero, z3, z3), cond=cond, body=body,
            label="dic_record_grid")
        strict = ws > 0.0
        return (dr.select(strict, ws, vs), dr.select(strict, wm, vm),
                dr.select(strict, wd, vd))


def validity_tolerance(geom: SplatGeometry, camera: Camera, min_px: float) -> np.ndarray:
    """Per pixel, how far (m) a point may lie from the pixel's G-buffer point and still read
    the pixel: the smallest record footprint there, ``min_px`` pixels at the pixel's depth
    (every footprint spans at least that, :func:`~arlight.tracing.irradiance_cache.
    effective_radius`); −1 at pixels without a surface (never valid)."""
    _, z = camera.project(geom.position)
    tol = min_px * np.maximum(np.asarray(z, np.float64), 0.0) / float(camera.fy)
    return np.where(geom.valid, tol, -1.0)


@dataclass
class Lookup:
    """What :meth:`SplatLookup.lookup` read: irradiances (W/m²) and per-lane flags."""

    e_mixed: mi.Color3f
    e_delta: mi.Color3f
    rejected: mi.Bool
    """The pixel failed the depth/normal check (the world-space search was asked)."""
    unresolved: mi.Bool
    """Rejected and no record weighs on the point: the pixel's value was kept."""


class SplatLookup:
    """The splat buffer on the device, read at the camera projection of world points
    (Kán §4.2.5), optionally *validated*: the pixel a point projects to serves it only when
    its G-buffer surface is the point's — within the pixel's :func:`validity_tolerance`
    and with normals closer than Eq. 2.15's limit (``√(1 − n·n_g)/√(1 − cos 10°) < 1/κ``);
    otherwise (a silhouette, a point hidden behind another surface, a lens sample off the
    pinhole's surface) the records are searched in world space (:class:`RecordGrid`), and
    only where no record weighs on the point the pixel's value is kept."""

    def __init__(self, camera: Camera, e_mixed: np.ndarray, e_delta: np.ndarray,
                 geom: SplatGeometry | None = None, tolerance: np.ndarray | None = None,
                 grid: RecordGrid | None = None, kappa: float = 1.0):
        self.mixed = mi.Color3f(*columns(e_mixed, np.float32))
        self.delta = mi.Color3f(*columns(e_delta, np.float32))
        self.proj = Projection(camera)
        self.validate = geom is not None
        if geom is not None:
            if tolerance is None:
                raise ValueError("a validated lookup needs the per-pixel tolerance")
            self.g_position = mi.Point3f(*columns(geom.position, np.float32))
            self.g_normal = mi.Vector3f(*columns(geom.normal, np.float32))
            self.tolerance = mi.Float(aligned(tolerance, np.float32))
            self.kappa = opaque(kappa)
        self.grid = grid

    def pixel(self, p: mi.Point3f) -> mi.UInt32:
        """Pixel index of the projection of ``p``, wrapped into the image (Kán §4.2.5)."""
        u, v, _ = self.proj.project(p, min_z=1e-9)
        u, v = dr.clip(u, -1e7, 1e7), dr.clip(v, -1e7, 1e7)
        w, h = mi.Float(self.proj.width), mi.Float(self.proj.height)
        cu, cv = dr.floor(u), dr.floor(v)
        col = cu - w * dr.floor(cu / w)
        row = cv - h * dr.floor(cv / h)
        col = dr.clip(mi.Int32(col), 0, mi.Int32(self.proj.width) - 1)
        row = dr.clip(mi.Int32(row), 0, mi.Int32(self.proj.height) - 1)
        return mi.UInt32(row * mi.Int32(self.proj.width) + col)

    def read(self, p: mi.Point3f, active: mi.Bool, n: mi.Vector3f | None = None) -> Lookup:
        """``(E_m, E_d)`` (W/m²) at ``p`` with unit normal ``n`` (facing the viewer; needed
        when validated)."""
        idx = self.pixel(p)
        e_m = dr.gather(mi.Color3f, self.mixed, idx, active)
        e_d = dr.gather(mi.Color3f, self.delta, idx, active)
        no = mi.Bool(False)
        if not self.validate or n is None:
            return Lookup(e_m, e_d, no, no)
        gp = dr.gather(mi.Point3f, self.g_position, idx, active)
        gn = dr.gather(mi.Vector3f, self.g_normal, idx, active)
        tol = dr.gather(mi.Float, self.tolerance, idx, active)
        dev = dr.norm(n - gn) * (NORMAL_SCALE / math.sqrt(2.0))
        ok = (dr.norm(p - gp) <= tol) & (self.kappa * dev < 1.0)
        rejected = active & ~ok
        if self.grid is None:
            return Lookup(e_m, e_d, rejected, rejected)
        ws, wm, wd = self.grid.interpolate(p, n, rejected)
        found = rejected & (ws > 0.0)
        inv = dr.select(found, dr.rcp(ws), 0.0)
        return Lookup(dr.select(found, wm * inv, e_m), dr.select(found, wd * inv, e_d),
                      rejected, rejected & ~found)

    def lookup(self, p: mi.Point3f, active: mi.Bool,
               n: mi.Vector3f | None = None) -> tuple[mi.Color3f, mi.Color3f]:
        """``(E_m, E_d)`` (W/m²) at the projections of ``p`` (validated when built with a
        G-buffer and ``n`` is given)."""
        r = self.read(p, active, n)
        return r.e_mixed, r.e_delta


@dataclass
class WalkResult:
    """Per-lane radiance of both solutions, the primary-hit mask and ray counts."""

    mixed: mi.Color3f
    real: mi.Color3f
    mask: mi.Float
    rays: dict[str, int]


class CameraWalk:
    """The camera side of DIC over the mixed (ρ) and real (µ) views.

    Follows the one-pass tracer's rules: its :class:`~arlight.tracing.onepass.HitRules`
    (forks, shadow rays, real continuations), a
    :class:`~arlight.tracing.onepass.LightSelection` (``selection``; default: Mitsuba's
    uniform selection, the records' — pass the record tracer's ``light_selection`` to share
    the very object) and its random dimensions (``rand_nee``, ``rand_lobe``, ``rand_bsdf`` of
    a :class:`~arlight.sampling.stream.LaneSampler`).
    """

    def __init__(self, views: SceneViews, lookup: SplatLookup, max_depth: int,
                 selection: LightSelection | None = None, glossy: bool = False,
                 trace_unresolved: bool = False):
        self.mixed, self.real = views.mixed, views.real
        self.same_views = views.mixed is views.real
        self.rules = HitRules(views.mixed, views.real)
        self.light_selection = selection or LightSelection(views.mixed, views.real)
        self.lookup = lookup
        self.max_depth = max_depth
        self.glossy = glossy
        self.trace_unresolved = trace_unresolved
        self.ctx = mi.BSDFContext()

    def _limit(self, depth: mi.UInt32, extra: int) -> mi.Bool | bool:
        """``depth + extra < max_depth`` (vertices, Mitsuba's convention)."""
        if self.max_depth < 0:
            return depth + extra < UNLIMITED_SPECULAR + extra
        return depth + extra < self.max_depth

    def trace(self, rays: mi.Ray3f, key: mi.UInt32 | LaneSampler) -> WalkResult:
        """Walk the camera rays; ``key``: per-lane keys (independent numbers) or a sampler."""
        key = as_sampler(key)
        n = dr.width(rays.d)
        fork_enabled = not self.same_views
        zero_u = dr.zeros(mi.UInt32, n)
        state = (mi.Ray3f(rays), dr.full(mi.Color3f, 1.0, n), dr.full(mi.Bool, True, n),
                 dr.zeros(mi.Color3f, n), dr.zeros(mi.Color3f, n), dr.zeros(mi.Float, n),
                 mi.UInt32(zero_u), dr.full(mi.Bool, False, n), mi.UInt32(zero_u),
                 dr.full(mi.Bool, True, n), [mi.UInt32(zero_u) for _ in WALK_COUNTERS])

        def cond(ray, beta, active, lm, lr, mask, depth, forked, fork_depth, emit, cnt):
            return active

        def body(ray, beta, active, lm, lr, mask, depth, forked, fork_depth, emit, cnt):
            c = dict(zip(WALK_COUNTERS, cnt, strict=True))
            c["rays_mixed_radiance"] += dr.select(active, 1, 0)
            si = self.mixed.scene.ray_intersect(ray, mi.RayFlags.All, False, active)
            role = self.mixed.hit_role(si)
            mask = dr.select((depth == 0) & (role == ROLE_VIRTUAL), 1.0, mask)
            if fork_enabled:
                forked, fork_depth, to_real = self.rules.fork(active, role, depth, forked,
                                                              fork_depth)
            else:
                to_real = mi.Bool(True)
            ray, beta, active, lm, lr, emit = self._vertex(self.mixed, si, ray, beta, active,
                                                           key, depth, lm, lr, to_real, True,
                                                           c, emit)
            return (ray, beta, active, lm, lr, mask, depth + 1, forked, fork_depth, emit,
                    [c[k] for k in WALK_COUNTERS])

        _, _, _, lm, lr, mask, _, forked, fork_depth, _, cnt = dr.while_loop(
            state=state, cond=cond, body=body, label="dic_camera_mixed")
        dr.eval(lm, lr, mask, forked, fork_depth, cnt)
        counts = {k: int(dr.sum(v)[0]) for k, v in zip(WALK_COUNTERS, cnt, strict=True)}
        if fork_enabled:
            lr = self._trace_forks(rays, forked, fork_depth, key, lr, counts)
        else:
            lr = lm
        return WalkResult(lm, lr, mask, counts)

    def _trace_forks(self, rays: mi.Ray3f, forked: mi.Bool, fork_depth: mi.UInt32,
                     key: LaneSampler, lr: mi.Color3f, counts: dict[str, int]) -> mi.Color3f:
        """The real continuations of the forked lanes, retraced in µ from the camera."""
        idx, rays_b, key_b, start = self.rules.continuations(rays, forked, fork_depth, key)
        m = dr.width(idx)
        if m == 0:
            return lr
        zero_u = dr.zeros(mi.UInt32, m)
        state = (rays_b, dr.full(mi.Color3f, 1.0, m),
                 dr.full(mi.Bool, True, m), dr.gather(mi.Color3f, lr, idx), mi.UInt32(zero_u),
                 dr.full(mi.Bool, True, m), mi.UInt32(zero_u), mi.UInt32(zero_u))

        def cond(ray, beta, active, lr_b, depth, emit, n_rad, n_sh, n_dir):
            return active

        def body(ray, beta, active, lr_b, depth, emit, n_rad, n_sh, n_dir):
            c = {"rays_real_shadow": n_sh, "rays_real_radiance_direct": n_dir}
            n_rad += dr.select(active, 1, 0)
            si = self.real.scene.ray_intersect(ray, mi.RayFlags.All, False, active)
            ray, beta, active, _, lr_b, emit = self._vertex(
                self.real, si, ray, beta, active, key_b, depth, None, lr_b, depth >= start,
                False, c, emit)
            return (ray, beta, active, lr_b, depth + 1, emit, n_rad, c["rays_real_shadow"],
                    c["rays_real_radiance_direct"])

        _, _, _, lr_b, _, _, n_rad, n_sh, n_dir = dr.while_loop(
            state=(*state, mi.UInt32(zero_u)), cond=cond, body=body, label="dic_camera_real")
        lr = mi.Color3f(lr)
        dr.scatter(lr, lr_b, idx)
        dr.eval(lr, n_rad, n_sh, n_dir)
        counts["rays_real_radiance"] += int(dr.sum(n_rad)[0])
        counts["rays_real_shadow"] += int(dr.sum(n_sh)[0])
        counts["rays_real_radiance_direct"] += int(dr.sum(n_dir)[0])
        return lr

    def _bsdf_emission(self, view: SceneView, si: mi.SurfaceInteraction3f, ray: mi.Ray3f,
                       bs: mi.BSDFSample3f, throughput: mi.Color3f, active: mi.Bool
                       ) -> tuple[mi.Color3f, mi.Int32]:
        """Emission found along a BSDF-sampled ray, MIS-weighted against light sampling
        (power heuristic, as the one-pass tracer), and the role of what the ray hit."""
        scene = view.scene
        si_b = scene.ray_intersect(ray, mi.RayFlags.All, False, active)
        ds = hit_sample(view, si_b, si)
        em_pdf = self.light_selection.pdf(view, si, ds, active)
        le = throughput * mis_weight(bs.pdf, em_pdf) * ds.emitter.eval(si_b, active)
        return dr.select(active, le, 0.0), view.hit_role(si_b)

    def _vertex(self, view: SceneView, si: mi.SurfaceInteraction3f, ray: mi.Ray3f,
                beta: mi.Color3f, active: mi.Bool, key: LaneSampler, depth: mi.UInt32,
                lm: mi.Color3f | None, lr: mi.Color3f, to_real: mi.Bool, to_mixed: bool,
                c: dict[str, mi.UInt32], emit: mi.Bool):
        """Shade one walk vertex in ``view``; returns the advanced walk, the radiances and
        whether the next vertex's emission is still to be counted."""
        # emission: every vertex of the walk is seen by the camera or through delta bounces
        # (after a glossy bounce it was counted, MIS-weighted, at the vertex before)
        le = beta * hit_emitter(view, si).eval(si, active & emit)
        if to_mixed:
            lm = lm + le
        lr = lr + dr.select(to_real, le, 0.0)
        act = active & si.is_valid()
        bsdf = si.bsdf()
        smooth = act & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        # direct light (1): one light sample, MIS against the BSDF, one-pass shadow rays
        nee = smooth & self._limit(depth, 1)
        ds, em_w = self.light_selection.sample(view, si, rand_nee(key, depth), nee)
        nee &= ds.pdf != 0.0
        f, pdf_b = bsdf.eval_pdf(self.ctx, si, si.to_local(ds.d), nee)
        contrib = beta * f * em_w * dr.select(ds.delta, 1.0, mis_weight(ds.pdf, pdf_b))
        nee &= dr.max(contrib) > 0
        vis_m, vis_r = self.rules.shadow(si.spawn_ray_to(ds.p), nee, to_mixed=to_mixed,
                                         to_real=to_real, c=c)
        if to_mixed:
            lm = lm + dr.select(vis_m, contrib, 0.0)
        lr = lr + dr.select(vis_r, contrib, 0.0)
        # indirect light: albedo/π × the splat buffer at the reprojected pixel (§4.2.5)
        gather = smooth & self._limit(depth, 2)
        alb = surface_albedo(si, gather)
        gather &= dr.max(alb) > 0
        look = self.lookup.read(si.p, gather, facing(mi.Vector3f(si.sh_frame.n), -ray.d))
        e_m, e_d = look.e_mixed, look.e_delta
        if "lookups" in c:  # the mixed walk counts its lookups (the retraced real part not)
            c["lookups"] += dr.select(gather, 1, 0)
            c["lookups_rejected"] += dr.select(look.rejected, 1, 0)
            c["lookups_unresolved"] += dr.select(look.unresolved, 1, 0)
        # an unresolved lookup (neither the pixel nor any record serves the point: a surface
        # the camera does not see, e.g. reflected in a glossy floor) would read another
        # surface's irradiance; with trace_unresolved the walk path traces on from it
        # instead (along the BSDF sample below: emission MIS-weighted here, the next vertex
        # shades and gathers as this one) — the rendering equation's own estimator
        unres = gather & look.unresolved if self.trace_unresolved else mi.Bool(False)
        gather &= ~unres
        ind_m = beta * alb * e_m * (1.0 / math.pi)
        ind_r = beta * alb * (e_m - e_d) * (1.0 / math.pi)
        if to_mixed:
            lm = lm + dr.select(gather, ind_m, 0.0)
        lr = lr + dr.select(gather & to_real, ind_r, 0.0)
        # direct light (2): the BSDF sample's ray, emission MIS-weighted against the light
        #   sample (a mixed ray; a real one where it hits a virtual object on a shared walk)
        bs, weight = bsdf.sample(self.ctx, si, rand_lobe(key, depth), rand_bsdf(key, depth),
                                 act)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        lit = smooth & ~delta & self._limit(depth, 1) & (dr.max(weight) > 0)
        if not to_mixed:
            lit &= to_real  # nothing to gather on the retraced shared prefix
        ray_b = si.spawn_ray(si.to_world(bs.wo))
        kind = "mixed" if to_mixed else "real"
        c[f"rays_{kind}_radiance_direct"] += dr.select(lit, 1, 0)
        le_b, role_b = self._bsdf_emission(view, si, ray_b, bs, beta * weight, lit)
        if to_mixed:
            lm = lm + le_b
            if not self.same_views:
                need_r = lit & to_real & (role_b == ROLE_VIRTUAL)
                c["rays_real_radiance_direct"] += dr.select(need_r, 1, 0)
                le_r, _ = self._bsdf_emission(self.real, si, ray_b, bs, beta * weight, need_r)
                le_b = dr.select(need_r, le_r, le_b)
        lr = lr + dr.select(to_real, le_b, 0.0)
        # delta-specular vertices continue the walk; so do glossy ones without a diffuse
        # lobe (metals, rough glass: nothing of theirs is cached), along the BSDF sample
        # whose emission was just counted, where the next vertex can still take light
        cont = act & delta & self._limit(depth, 1) & (dr.max(weight) > 0)
        gl = unres & ~delta & (dr.max(weight) > 0)  # (gather implies smooth, depth + 2 < max)
        if self.glossy:
            gl |= (smooth & ~delta & self._limit(depth, 2) & (dr.max(weight) > 0)
                   & ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.DiffuseReflection))
        emit = dr.select(gl, False, dr.select(cont, True, emit))
        cont |= gl
        ray = dr.select(cont, ray_b, ray)
        beta = dr.select(cont, beta * weight, beta)
        return ray, beta, cont, lm, lr, emit



def splat_geometry(view: SceneView, camera: Camera) -> SplatGeometry:
    """The splat buffer's surface: first hits through the pixel centres of the pinhole camera
    (the rasteriser's G-buffer of Kán §4.2.3: position, normal, real/virtual flag)."""
    w, h = camera.width, camera.height
    v, u = np.mgrid[0:h, 0:w]
    uv = np.stack([u.ravel() + 0.5, v.ravel() + 0.5], axis=1)
    o, d = camera.pixel_rays(uv)
    ray = mi.Ray3f(mi.Point3f(*columns(o, np.float32)), mi.Vector3f(*columns(d, np.float32)))
    si = view.scene.ray_intersect(ray)
    valid = si.is_valid()
    n = facing(mi.Vector3f(si.sh_frame.n), -ray.d)
    alb = surface_albedo(si, valid)
    role = view.hit_role(si)
    dr.eval(si.p, n, alb, role, valid)
    pos = np3(si.p)
    nrm = np3(n)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    ok = np.asarray(valid, bool)
    albedo = np3(alb)
    pos[~ok] = 0.0
    nrm[~ok] = 0.0
    return SplatGeometry(pos, nrm, ok & (albedo.max(axis=1) > 0), ok,
                         np.asarray(role, np.int64) == ROLE_VIRTUAL, w, h, albedo)


__all__ = ["CameraWalk", "Lookup", "RecordGrid", "SplatLookup", "UNLIMITED_SPECULAR",
           "WALK_COUNTERS", "WalkResult", "splat_geometry", "validity_tolerance"]
