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
reflect/refract choice) continue the walk. The walk has no rules of its own: it follows the
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
from arlight.jit import columns
from arlight.realtime.gbuffer import facing, surface_albedo
from arlight.sampling.stream import LaneSampler
from arlight.scene.camera import Camera
from arlight.tracing.irradiance_cache import SplatGeometry
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
                 "rays_real_shadow", "rays_mixed_radiance_direct", "rays_real_radiance_direct")


class SplatLookup:
    """The splat buffer on the device, read at the camera projection of world points."""

    def __init__(self, camera: Camera, e_mixed: np.ndarray, e_delta: np.ndarray):
        self.mixed = mi.Color3f(*columns(e_mixed, np.float32))
        self.delta = mi.Color3f(*columns(e_delta, np.float32))
        self.proj = Projection(camera)

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

    def lookup(self, p: mi.Point3f, active: mi.Bool) -> tuple[mi.Color3f, mi.Color3f]:
        """``(E_m, E_d)`` (W/m²) at the projections of ``p``."""
        idx = self.pixel(p)
        return (dr.gather(mi.Color3f, self.mixed, idx, active),
                dr.gather(mi.Color3f, self.delta, idx, active))


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
                 selection: LightSelection | None = None):
        self.mixed, self.real = views.mixed, views.real
        self.same_views = views.mixed is views.real
        self.rules = HitRules(views.mixed, views.real)
        self.light_selection = selection or LightSelection(views.mixed, views.real)
        self.lookup = lookup
        self.max_depth = max_depth
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
                 [mi.UInt32(zero_u) for _ in WALK_COUNTERS])

        def cond(ray, beta, active, lm, lr, mask, depth, forked, fork_depth, cnt):
            return active

        def body(ray, beta, active, lm, lr, mask, depth, forked, fork_depth, cnt):
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
            ray, beta, active, lm, lr = self._vertex(self.mixed, si, ray, beta, active, key,
                                                     depth, lm, lr, to_real, True, c)
            return (ray, beta, active, lm, lr, mask, depth + 1, forked, fork_depth,
                    [c[k] for k in WALK_COUNTERS])

        _, _, _, lm, lr, mask, _, forked, fork_depth, cnt = dr.while_loop(
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
                 mi.UInt32(zero_u), mi.UInt32(zero_u))

        def cond(ray, beta, active, lr_b, depth, n_rad, n_sh, n_dir):
            return active

        def body(ray, beta, active, lr_b, depth, n_rad, n_sh, n_dir):
            c = {"rays_real_shadow": n_sh, "rays_real_radiance_direct": n_dir}
            n_rad += dr.select(active, 1, 0)
            si = self.real.scene.ray_intersect(ray, mi.RayFlags.All, False, active)
            ray, beta, active, _, lr_b = self._vertex(self.real, si, ray, beta, active, key_b,
                                                      depth, None, lr_b, depth >= start,
                                                      False, c)
            return (ray, beta, active, lr_b, depth + 1, n_rad, c["rays_real_shadow"],
                    c["rays_real_radiance_direct"])

        _, _, _, lr_b, _, n_rad, n_sh, n_dir = dr.while_loop(
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
                c: dict[str, mi.UInt32]):
        """Shade one walk vertex in ``view``; returns the advanced walk and the radiances."""
        # emission: every vertex of the walk is seen by the camera or through delta bounces
        le = beta * hit_emitter(view, si).eval(si, active)
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
        e_m, e_d = self.lookup.lookup(si.p, gather)
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
        # delta-specular vertices continue the walk
        cont = act & delta & self._limit(depth, 1) & (dr.max(weight) > 0)
        ray = dr.select(cont, ray_b, ray)
        beta = dr.select(cont, beta * weight, beta)
        return ray, beta, cont, lm, lr



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


__all__ = ["CameraWalk", "SplatLookup", "UNLIMITED_SPECULAR", "WALK_COUNTERS", "WalkResult",
           "splat_geometry"]
