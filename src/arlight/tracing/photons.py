"""Differential caustic photon mapping (Kán thesis §4.1.2, §4.5.1; ISMAR 2012).

Caustics (light paths ``L S+ D``) from point and spot lights through delta-specular objects
(glass, mirrors), real or virtual, for the one-pass differential renderer ``onepass``
(option ``caustics = "photons"``). A path tracer cannot find these paths at all (the
connection light → specular vertex is a delta–delta one), so the photon estimate adds to the
path-traced radiance without double counting. Three stages, timed by ``onepass``:

1. **Shooting** (``t_p``, :func:`emit_photons`, :func:`trace_photons`). At every frame the
   *caustic generators* (shapes with glass or mirror material) are bounded by spheres; for
   each light the spheres whose cones (seen from the light) overlap are merged into one
   bounding sphere, so no direction is sampled twice; each light/cone gets photons in
   proportion to its power ``I(axis)·Ω``; the photons of a cone are stratified (jittered
   ``m × m`` grid, concentric map) on the disk through the sphere centre facing the light,
   and each carries the flux ``Φ = I(ω) / (N_g · p(ω))`` with ``p(ω) = r³ / (d · A_disk)`` the
   solid-angle density of the disk sample, so ``Σ Φ`` is an unbiased (and, stratified, very
   low variance) estimate of the power the light sends into the cone. The disk radius is
   ``R·d/√(d² − R²)`` (the cone tangent to the sphere): the thesis's disk of radius ``R``
   subtends ``atan(R/d) < asin(R/d)`` and would miss the sphere's rim. Photons are traced in
   one Dr.Jit symbolic loop (importance transport: Mitsuba's exact Fresnel/Snell, stochastic
   reflect/refract) and stored at the first non-delta hit after at least one specular bounce.
2. **Differential bookkeeping** (inferred design, Kán does not spell it out; digest §6.4).
   Photons are traced in the mixed view ρ; a photon whose path touched no virtual shape is
   *shared* (it exists identically in the real-only view µ and feeds ``L_m`` and ``L_r``:
   real caustics cancel in ``I_m − I_r``). Photons that touched a virtual shape are
   *mixed-only* where ρ stored them (caustics of virtual objects, real caustics bent by
   virtual glass), and are retraced in µ with the same random numbers (the retraced prefix
   is bit-identical), where they become *real-only* photons (real caustics that the virtual
   object blocks, subtracted through ``L_r``).
3. **Index** (``t_b``, :class:`PhotonMap`): a uniform grid with cell size ``h`` (the kernel
   radius) wrapped into ``2^n ≥ 2N`` buckets (low bits of the cell coordinates, so any 3×3×3
   block of cells has distinct buckets): keys computed in Dr.Jit, a stable NumPy sort,
   bucket start/end tables. A fixed-radius query visits the ≤ 27 cells its ball overlaps.
   (``benchmarks/bench_photons.py`` measures it against ``scipy.spatial.cKDTree``.)
4. **Density estimation** (in ``t_r``, :func:`gather_caustics`): at the first non-delta hit
   of each camera sample after a (possibly empty) chain of delta-specular vertices, the
   fixed-radius kernel estimate (Kán Eq. 4.4 with d = 2 and the Epanechnikov kernel of
   Eq. 4.5, ``K(x) = (2/π)(1 − |x|²)``):

       L_c(x, ω) = f_d(x) · Σ_p Φ_p · K(|x − x_p| / h) / h²    [W·sr⁻¹·m⁻²]

   over photons arriving on the query's side of the surface, ``f_d`` the BSDF's diffuse
   value (exact for Lambertian surfaces, the thesis's case). Shared photons count in both
   sums in the same order, so a world without virtual objects gets bitwise equal caustics in
   ``L_m`` and ``L_r``.

**Progressive photon mapping** (``ppm_iterations = K > 1``): K independent photon maps with
radii ``h_{i+1}² = h_i² (i + α)/(i + 1)`` — Hachisuka et al. 2008's radius reduction with a
global radius (the probabilistic form of Knaus & Zwicker 2011), under which the average of
the K estimates converges (bias → 0 as the radius shrinks while the photons in it grow).
Each camera sample uses one of the K maps, chosen uniformly at random, so the pixel mean is
the average over the maps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import (
    LIGHT_PREFIX,
    ROLE_REAL,
    ROLE_VIRTUAL,
    SceneView,
    SceneViews,
)
from arlight.errors import InputError
from arlight.sampling.stream import LaneSampler
from arlight.scene.model import World
from arlight.tracing.onepass import (
    DIM_CAUSTIC_DIR,
    DIM_CAUSTIC_LOBE,
    DIMS_PER_DEPTH,
    lane_keys,
)

GENERATOR_MATERIALS = ("glass", "mirror")
"""Material types whose shapes are caustic generators (delta-specular BSDFs)."""
PHOTON_LIGHTS = ("point", "spot")
"""Light types that shoot caustic photons (delta positions: a path tracer finds none of their
caustics, so the photon estimate adds without double counting)."""
SHARED, MIXED_ONLY, REAL_ONLY = 0, 1, 2
# Random numbers come from :class:`LaneSampler` (``independent``) on the one-pass tracer's
# layout of ``DIMS_PER_DEPTH`` dimensions per depth. Photons have keys of their own (per
# photon), on which the light walk uses slot 0 (lobe) and 1–2 (direction) of each depth and
# the emission jitter dimensions 0–1; the camera samples' caustic walk reads the camera
# sample's key at the tracer's slots DIM_CAUSTIC_* (disjoint from the path tracer's), and the
# choice of a PPM map one dimension far from every depth.
_PHOTON_LOBE, _PHOTON_DIR = 0, 1
_EMIT_JITTER = 0
_MAP_CHOICE = 0x7FFF0001


def _concat(parts: list, cls):
    """Dr.Jit arrays of type ``cls`` (a 3-vector type or ``mi.UInt32``) joined in order.
    Empty parts are skipped: ``dr.concat`` rejects zero-width arrays."""
    parts = [x for x in parts if dr.width(x) > 0] or parts[:1]
    if len(parts) == 1:
        return cls(parts[0])
    if cls is mi.UInt32:
        return dr.concat(parts)
    return cls(*[dr.concat([x[c] for x in parts]) for c in range(3)])


@dataclass(frozen=True)
class PhotonSettings:
    """Settings of the caustic photon map.

    Attributes:
        photons: photons emitted per photon map (split over lights and generators).
        radius: kernel radius ``h`` of the density estimate, metres (first map under PPM).
        ppm_iterations: number of photon maps with shrinking radii (1: Kán's fixed radius).
        ppm_alpha: Hachisuka's α in ``h_{i+1}² = h_i² (i + α)/(i + 1)``, in (0, 1).
        max_depth: longest light path in vertices, Mitsuba's convention: a photon makes at most
            ``max_depth − 2`` specular bounces before the diffuse hit (-1: 64 vertices).
        seed: seed of the photon random numbers.
    """

    photons: int = 200_000
    radius: float = 0.01
    ppm_iterations: int = 1
    ppm_alpha: float = 0.7
    max_depth: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        if self.photons < 1:
            raise InputError(f"must be >= 1, got {self.photons}", field="options.photons")
        if not (self.radius > 0 and math.isfinite(self.radius)):
            raise InputError(f"must be a positive length in metres, got {self.radius}",
                             field="options.photon_radius")
        if self.ppm_iterations < 1:
            raise InputError(f"must be >= 1, got {self.ppm_iterations}",
                             field="options.ppm_iterations")
        if not 0.0 < self.ppm_alpha < 1.0:
            raise InputError(f"must be in (0, 1), got {self.ppm_alpha}",
                             field="options.ppm_alpha")

    def radii(self) -> list[float]:
        """Kernel radii of the K maps, metres: ``h_{i+1}² = h_i² (i + α)/(i + 1)``."""
        out, r2 = [], self.radius ** 2
        for i in range(1, self.ppm_iterations + 1):
            out.append(math.sqrt(r2))
            r2 *= (i + self.ppm_alpha) / (i + 1)
        return out


# ------------------------------------------------------------------------------ emission
@dataclass
class Cone:
    """A bounding sphere of caustic generators seen from a light (centre, radius, metres)."""

    center: np.ndarray
    radius: float


def generator_spheres(world: World, view: SceneView) -> list[Cone]:
    """Bounding spheres of the generator shapes in ``view``: exact for spheres (under
    uniform scale), else centred on the box centre, holding every vertex (meshes) or the box
    (other primitives)."""
    out = []
    for sh in view.scene.shapes():
        sid = sh.id()
        if not sid.isdigit():
            continue
        shape = world.shapes[int(sid)]
        if shape.material.type not in GENERATOR_MATERIALS:
            continue
        b = sh.bbox()
        lo, hi = np.array(b.min, dtype=np.float64), np.array(b.max, dtype=np.float64)
        center = (lo + hi) / 2
        radius = float(np.linalg.norm(hi - lo) / 2)
        m = np.asarray(shape.to_world, dtype=np.float64)
        scales = np.linalg.norm(m[:3, :3], axis=0)
        if shape.type == "sphere" and np.allclose(scales, scales[0], rtol=1e-6):
            center = m[:3, 3].copy()
            radius = float(shape.params["radius"] * scales[0]) * (1 + 1e-6)
        elif isinstance(sh, mi.Mesh):
            v = np.asarray(sh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
            radius = float(np.sqrt(np.max(np.sum((v - center) ** 2, axis=1)))) * (1 + 1e-6)
        out.append(Cone(center, radius))
    return out


def _half_angle(cone: Cone, light: np.ndarray) -> float:
    """Half-angle of the cone tangent to the sphere from ``light``, radians (π: inside)."""
    d = float(np.linalg.norm(cone.center - light))
    return math.pi if d <= cone.radius * (1 + 1e-6) else math.asin(cone.radius / d)


def merge_cones(spheres: list[Cone], light: np.ndarray) -> list[Cone]:
    """Spheres whose cones from ``light`` overlap are replaced by their bounding sphere until
    no two overlap (Kán §4.1.2: no direction is sampled twice)."""
    cones = [Cone(s.center.copy(), s.radius) for s in spheres]
    merged = True
    while merged and len(cones) > 1:
        merged = False
        for i in range(len(cones)):
            for j in range(i + 1, len(cones)):
                a, b = cones[i], cones[j]
                ta, tb = _half_angle(a, light), _half_angle(b, light)
                da, db = a.center - light, b.center - light
                cosang = float(np.dot(da, db) / (np.linalg.norm(da) * np.linalg.norm(db)))
                if ta + tb < math.pi and math.acos(min(max(cosang, -1.0), 1.0)) >= ta + tb:
                    continue
                sep = float(np.linalg.norm(b.center - a.center))
                if sep + b.radius <= a.radius:
                    big = a
                elif sep + a.radius <= b.radius:
                    big = b
                else:  # smallest sphere holding both
                    r = (sep + a.radius + b.radius) / 2
                    c = a.center + (b.center - a.center) * ((r - a.radius) / sep)
                    big = Cone(c, r)
                cones = [c for k, c in enumerate(cones) if k not in (i, j)] + [big]
                merged = True
                break
            if merged:
                break
    return cones


@dataclass
class EmittedPhotons:
    """Photon rays with their flux (Dr.Jit arrays), and counts."""

    rays: mi.Ray3f
    flux: mi.Color3f
    count: int

    @property
    def power(self) -> np.ndarray:
        """``Σ Φ``, watts (read back from the device: for tests, not the per-frame path)."""
        if self.count == 0:
            return np.zeros(3)
        return np.array([float(dr.sum(self.flux[i])[0]) for i in range(3)])


def _light_emitters(world: World, view: SceneView) -> list[tuple[np.ndarray, mi.Emitter]]:
    by_id = {em.id(): em for em in view.scene.emitters()}
    out = []
    for i, light in enumerate(world.lights):
        if light.type in PHOTON_LIGHTS:
            out.append((np.asarray(light.params["position"], dtype=np.float64),
                        by_id[f"{LIGHT_PREFIX}{i}"]))
    return out


def _intensity(emitter: mi.Emitter, pos: mi.Point3f, target: mi.Point3f) -> mi.Color3f:
    """Radiant intensity ``I(ω)`` (W/sr) of a point/spot emitter toward ``target``: Mitsuba's
    own ``sample_direction`` value (``I/r²``) times ``r²``."""
    it = dr.zeros(mi.Interaction3f, dr.width(target))
    it.p = target
    ds, val = emitter.sample_direction(it, dr.zeros(mi.Point2f, dr.width(target)))
    return mi.Color3f(val) * dr.square(ds.dist)


def emit_photons(world: World, views: SceneViews, n_photons: int, seed: int) -> EmittedPhotons:
    """Photons from every point/spot light toward the caustic generators (Kán §4.1.2).

    Returns rays and fluxes ``Φ = I(ω)/(N_g p(ω))`` (watts); the number of photons of a cone
    is the largest square ``m² ≤ N·w_g/Σw``, ``w_g = lum(I(axis))·Ω_g``, at least 1.
    """
    spheres = generator_spheres(world, views.mixed)
    lights = _light_emitters(world, views.mixed)
    plans = []
    for pos, em in lights:
        for cone in merge_cones(spheres, pos):
            theta = _half_angle(cone, pos)
            omega = 4 * math.pi if theta >= math.pi else 2 * math.pi * (1 - math.cos(theta))
            i_axis = _intensity(em, mi.Point3f(*(dr.opaque(mi.Float, float(x)) for x in pos)),
                                mi.Point3f(*(dr.opaque(mi.Float, float(x))
                                             for x in cone.center)))
            lum = float(np.mean(np.array(i_axis)))
            plans.append((pos, em, cone, theta, max(lum, 1e-12) * omega))
    if not plans:
        empty = dr.zeros(mi.Ray3f, 0)
        return EmittedPhotons(empty, dr.zeros(mi.Color3f, 0), 0)
    total_w = sum(p[4] for p in plans)
    rays_o, rays_d, fluxes, count = [], [], [], 0
    for k, (pos, em, cone, theta, w) in enumerate(plans):
        m = max(1, int(math.isqrt(int(n_photons * w / total_w))))
        n = m * m
        # per-frame values enter the kernels as opaque variables, not literals: a new seed or
        # a moved generator must not compile new kernels every frame
        def op(x: float) -> mi.Float:
            return dr.opaque(mi.Float, float(x))

        idx = dr.arange(mi.UInt32, n)
        rng = LaneSampler.independent(
            lane_keys(n, dr.opaque(mi.UInt32, (seed * 7919 + k) & 0xFFFFFFFF)))
        jit = rng.next_2d(_EMIT_JITTER)
        mu, mf = dr.opaque(mi.UInt32, m), op(m)
        u = mi.Point2f((mi.Float(idx % mu) + jit.x) / mf, (mi.Float(idx // mu) + jit.y) / mf)
        origin = mi.Point3f(*(op(x) for x in pos))
        if theta >= math.pi:  # light inside the bounding sphere: the whole sphere
            d = mi.warp.square_to_uniform_sphere(u)
            pdf = dr.full(mi.Float, 1 / (4 * math.pi), n)
            target = origin + d
        else:
            c = cone.center
            axis = (c - pos) / np.linalg.norm(c - pos)
            dist = float(np.linalg.norm(c - pos))
            rd = cone.radius * dist / math.sqrt(dist * dist - cone.radius ** 2)
            frame = mi.Frame3f(mi.Vector3f(*(op(x) for x in axis)))
            q = mi.warp.square_to_uniform_disk_concentric(u) * op(rd)
            target = (mi.Point3f(*(op(x) for x in c)) + frame.s * q.x + frame.t * q.y)
            v = target - origin
            r = dr.norm(v)
            d = v / r
            pdf = r * r * r / (op(dist * math.pi * rd * rd))  # p(ω) = r²/(cos θ · A), cos = d/r
        flux = _intensity(em, origin, target) / (pdf * op(n))
        rays_o.append(dr.zeros(mi.Point3f, n) + origin)
        rays_d.append(mi.Vector3f(d))
        fluxes.append(flux)
        count += n

    rays = mi.Ray3f(_concat(rays_o, mi.Point3f), _concat(rays_d, mi.Vector3f))
    flux = _concat(fluxes, mi.Color3f)
    dr.eval(rays, flux)
    return EmittedPhotons(rays, flux, count)


# ------------------------------------------------------------------------------- tracing
@dataclass
class StoredPhotons:
    """Stored caustic photons (Dr.Jit arrays): position (m), direction toward where the
    photon came from, flux (W), class (SHARED / MIXED_ONLY / REAL_ONLY)."""

    p: mi.Point3f
    wi: mi.Vector3f
    flux: mi.Color3f
    cls: mi.UInt32

    @property
    def count(self) -> int:
        return dr.width(self.cls)

    def without(self, cls: int) -> StoredPhotons:
        """The photons not of class ``cls`` (same order)."""
        if self.count == 0:  # Dr.Jit rejects comparing a zero-width array with a scalar
            return self
        keep = dr.compress(self.cls != cls)
        return StoredPhotons(dr.gather(mi.Point3f, self.p, keep),
                             dr.gather(mi.Vector3f, self.wi, keep),
                             dr.gather(mi.Color3f, self.flux, keep),
                             dr.gather(mi.UInt32, self.cls, keep))

    def class_counts(self) -> dict[str, int]:
        c = np.bincount(np.asarray(self.cls, dtype=np.int64), minlength=3)
        return {"photons_shared": int(c[0]), "photons_mixed_only": int(c[1]),
                "photons_real_only": int(c[2])}


def _is_delta(flags: mi.UInt32) -> mi.Bool:
    """Lanes whose BSDF is purely delta-specular (glass, mirror): walks continue there."""
    return mi.has_flag(flags, mi.BSDFFlags.Delta) & ~mi.has_flag(flags, mi.BSDFFlags.Smooth)


def _specular_bounce(bsdf, ctx, si, s1: mi.Float, s2: mi.Point2f, go: mi.Bool, weight,
                     ray: mi.Ray3f):
    """Continue the lanes ``go`` through their (delta) BSDF: the weight times the sampled
    BSDF weight, the ray along the sampled direction; lanes whose weight became 0 stop.
    Returns ``(weight, ray, go)``."""
    bs, w = bsdf.sample(ctx, si, s1, s2, go)
    weight = dr.select(go, weight * w, weight)
    ray = dr.select(go, si.spawn_ray(si.to_world(bs.wo)), ray)
    return weight, ray, go & (dr.max(weight) > 0)


def _photon_walk(view: SceneView, rays: mi.Ray3f, flux: mi.Color3f, rng: LaneSampler,
                 max_depth: int) -> tuple[mi.Point3f, mi.Vector3f, mi.Color3f, mi.Bool, mi.Bool]:
    """Trace photons in ``view`` through delta-specular vertices; a photon is stored at its
    first non-delta hit after ≥ 1 specular bounce. Returns (p, wi, flux, stored, touched
    virtual), one symbolic loop, no scatter inside it."""
    n = dr.width(rng.key)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    state = (mi.Ray3f(rays), mi.Color3f(flux), dr.full(mi.Bool, True, n), dr.zeros(mi.UInt32, n),
             dr.zeros(mi.UInt32, n), dr.full(mi.Bool, False, n), dr.full(mi.Bool, False, n),
             dr.zeros(mi.Point3f, n))

    def cond(ray, phi, active, depth, nspec, stored, touched, sp):
        return active

    def body(ray, phi, active, depth, nspec, stored, touched, sp):
        si = view.scene.ray_intersect(ray, mi.RayFlags.All, False, active)
        valid = active & si.is_valid()
        touched |= valid & (view.hit_role(si) == ROLE_VIRTUAL)
        bsdf = si.bsdf()
        flags = bsdf.flags()
        delta = _is_delta(flags)
        store = valid & ~delta & (nspec > 0)
        stored |= store
        sp = dr.select(store, si.p, sp)
        go = valid & delta & (depth + 3 <= max_depth)  # L S^(depth+1) D: depth + 3 vertices
        base = depth * DIMS_PER_DEPTH
        s1 = rng.next_1d(base + _PHOTON_LOBE)
        s2 = rng.next_2d(base + _PHOTON_DIR)
        phi, ray, go = _specular_bounce(bsdf, ctx, si, s1, s2, go, phi, ray)
        return ray, phi, go, depth + 1, nspec + 1, stored, touched, sp

    ray, phi, _, _, _, stored, touched, sp = dr.while_loop(state=state, cond=cond, body=body,
                                                          label="photon_trace")
    return sp, -ray.d, phi, stored, touched


def trace_photons(views: SceneViews, emitted: EmittedPhotons, max_depth: int,
                  seed: int) -> StoredPhotons:
    """Trace the emitted photons in ρ, retrace those that touched a virtual shape in µ, and
    return the stored photons with their classes (module docstring, item 2)."""
    n = emitted.count
    md = 64 if max_depth < 0 else max_depth
    if n == 0:
        z = dr.zeros(mi.Float, 0)
        return StoredPhotons(mi.Point3f(z, z, z), mi.Vector3f(z, z, z), mi.Color3f(z, z, z),
                             dr.zeros(mi.UInt32, 0))
    rng = LaneSampler.independent(lane_keys(n, dr.opaque(mi.UInt32, (seed * 31 + 17) & 0xFFFFFFFF)))
    p, wi, phi, stored, touched = _photon_walk(views.mixed, emitted.rays, emitted.flux, rng, md)
    same = views.mixed is views.real  # then no shape is virtual and nothing is touched
    cls = dr.select(touched, mi.UInt32(MIXED_ONLY), mi.UInt32(SHARED))
    dr.eval(p, wi, phi, stored, cls)
    keep = dr.compress(stored)
    parts = [(dr.gather(mi.Point3f, p, keep), dr.gather(mi.Vector3f, wi, keep),
              dr.gather(mi.Color3f, phi, keep), dr.gather(mi.UInt32, cls, keep))]
    if not same:
        fork = dr.compress(touched)
        if dr.width(fork) > 0:
            rays_b = dr.gather(mi.Ray3f, emitted.rays, fork)
            p2, wi2, phi2, st2, _ = _photon_walk(
                views.real, rays_b, dr.gather(mi.Color3f, emitted.flux, fork),
                rng.gather(fork), md)
            dr.eval(p2, wi2, phi2, st2)
            k2 = dr.compress(st2)
            parts.append((dr.gather(mi.Point3f, p2, k2), dr.gather(mi.Vector3f, wi2, k2),
                          dr.gather(mi.Color3f, phi2, k2),
                          dr.full(mi.UInt32, REAL_ONLY, dr.width(k2))))
    out = StoredPhotons(*(_concat([x[i] for x in parts], cls) for i, cls in
                          enumerate((mi.Point3f, mi.Vector3f, mi.Color3f, mi.UInt32))))
    dr.eval(out.p, out.wi, out.flux, out.cls)
    return out


# --------------------------------------------------------------------------------- index
def _grid_bits(size: int, cells: np.ndarray) -> tuple[int, int, int]:
    """Bits of the x, y, z cell coordinates in a bucket id of a table of ``size`` = 2^n
    buckets (n ≥ 6): each axis keeps ≥ 2 bits (3 neighbouring cells never share a bucket);
    the rest go one by one to the axis that wraps most (``cells``: the photons' extent in
    cells per axis), so a flat photon cloud does not waste bits on its thin axis."""
    n = int(math.log2(size))
    bits = [2, 2, 2]
    for _ in range(n - 6):
        a = int(np.argmax([cells[i] / (1 << bits[i]) for i in range(3)]))
        bits[a] += 1
    return bits[0], bits[1], bits[2]


def _bucket(ix: mi.Int32, iy: mi.Int32, iz: mi.Int32, mx: mi.UInt32, my: mi.UInt32,
            mz: mi.UInt32, sy: mi.UInt32, sz: mi.UInt32) -> mi.UInt32:
    """Bucket of the integer cell (ix, iy, iz): the low bits of each coordinate side by side
    (``m*`` masks, ``s*`` shifts). The grid wraps around: cells far apart may share a
    bucket (their photons fail the distance test), but any 3×3×3 block of cells maps to 27
    distinct buckets, so a query never visits a bucket twice."""
    return ((mi.UInt32(ix) & mx) | ((mi.UInt32(iy) & my) << sy)
            | ((mi.UInt32(iz) & mz) << sz))


@dataclass
class PhotonMap:
    """K grids over stored photons (one per PPM iteration), as flat Dr.Jit tables.

    Map i has cell size ``h_i`` and ``2^n ≥ 2·count`` buckets (:func:`_bucket`); its photons
    are sorted by bucket and ``start[off_i + b] .. end[off_i + b]`` indexes bucket ``b``.
    """

    p: mi.Point3f
    wi: mi.Vector3f
    flux: mi.Color3f
    cls: mi.UInt32
    start: mi.UInt32
    end: mi.UInt32
    radius: mi.Float
    bits: tuple[mi.UInt32, ...]  # per map: mx, my, mz, sy, sz, table offset
    radii: list[float]
    stored: int

    @staticmethod
    def build(maps: list[StoredPhotons], radii: list[float]) -> PhotonMap:
        """Sort each map's photons into its grid (keys in Dr.Jit, stable NumPy sort)."""
        ps, wis, fl, cl, st, en = [], [], [], [], [], []
        bits: list[list[int]] = [[] for _ in range(6)]
        poff = toff = 0
        for sp, h in zip(maps, radii, strict=True):
            n = sp.count
            size = 1 << max(6, int(math.ceil(math.log2(max(2 * n, 1)))))
            if n:
                lo = np.array([dr.min(sp.p[i])[0] for i in range(3)], dtype=np.float64)
                hi = np.array([dr.max(sp.p[i])[0] for i in range(3)], dtype=np.float64)
                cells = (hi - lo) / h + 1.0
            else:
                cells = np.ones(3)
            bx, by, bz = _grid_bits(size, cells)
            row = [(1 << bx) - 1, (1 << by) - 1, (1 << bz) - 1, bx, bx + by, toff]
            for j, v in enumerate(row):
                bits[j].append(v)
            if n:
                cell = dr.floor(sp.p * dr.opaque(mi.Float, 1.0 / h))
                u = [dr.opaque(mi.UInt32, v) for v in row[:5]]
                keys = np.asarray(_bucket(mi.Int32(cell.x), mi.Int32(cell.y),
                                          mi.Int32(cell.z), *u), dtype=np.uint32)
            else:
                keys = np.zeros(0, np.uint32)
            order = np.argsort(keys, kind="stable").astype(np.uint32)
            counts = np.bincount(keys, minlength=size)
            ends = np.cumsum(counts).astype(np.uint32)
            starts = ends - counts.astype(np.uint32)
            o = mi.UInt32(order)
            ps.append(dr.gather(mi.Point3f, sp.p, o))
            wis.append(dr.gather(mi.Vector3f, sp.wi, o))
            fl.append(dr.gather(mi.Color3f, sp.flux, o))
            cl.append(dr.gather(mi.UInt32, sp.cls, o))
            st.append(starts + poff)
            en.append(ends + poff)
            poff += n
            toff += size

        pm = PhotonMap(
            p=_concat(ps, mi.Point3f), wi=_concat(wis, mi.Vector3f), flux=_concat(fl, mi.Color3f),
            cls=_concat(cl, mi.UInt32),
            start=mi.UInt32(np.concatenate(st)), end=mi.UInt32(np.concatenate(en)),
            radius=mi.Float(np.array(radii, np.float32)),
            bits=tuple(mi.UInt32(np.array(b, np.uint32)) for b in bits),
            radii=list(radii), stored=poff)
        dr.eval(pm.p, pm.wi, pm.flux, pm.cls, pm.start, pm.end)
        return pm

    def estimate(self, x: mi.Point3f, n: mi.Vector3f, which: mi.UInt32,
                 active: mi.Bool) -> tuple[mi.Color3f, mi.Color3f]:
        """Kernel sums ``Σ Φ_p K(|x − x_p|/h)/h²`` (W/m²) of map ``which`` at ``x`` over
        photons arriving on the side ``n`` faces (Kán Eq. 4.4–4.5, d = 2), split into the
        mixed (shared + mixed-only) and real (shared + real-only) solutions.

        One symbolic loop per query: it visits the (up to 3×3×3) cells of size h that the
        ball of radius h overlaps, loading a cell's photon range when the previous one is
        done, so each iteration handles one photon or one cell."""
        m = dr.width(x)
        h = dr.gather(mi.Float, self.radius, which, active)
        mx, my, mz, sy, sz, toff = (dr.gather(mi.UInt32, b, which, active) for b in self.bits)
        lo = dr.floor((x - h) / h)
        hi = dr.floor((x + h) / h)
        lo_i = [mi.Int32(lo.x), mi.Int32(lo.y), mi.Int32(lo.z)]
        span = [mi.Int32(hi.x) - lo_i[0], mi.Int32(hi.y) - lo_i[1], mi.Int32(hi.z) - lo_i[2]]
        h2 = h * h
        norm = (2.0 / math.pi) / h2
        zero_c = dr.zeros(mi.Color3f, m)
        state = (dr.select(active, 0, 27), dr.zeros(mi.UInt32, m), dr.zeros(mi.UInt32, m),
                 mi.Color3f(zero_c), mi.Color3f(zero_c))

        def cond(k, cur, end, acc_m, acc_r):
            return (k < 27) | (cur < end)

        def body(k, cur, end, acc_m, acc_r):
            proc = cur < end
            pp = dr.gather(mi.Point3f, self.p, cur, proc)
            d2 = dr.squared_norm(pp - x)
            wi = dr.gather(mi.Vector3f, self.wi, cur, proc)
            use = proc & (d2 < h2) & (dr.dot(wi, n) > 0)
            phi = dr.gather(mi.Color3f, self.flux, cur, use)
            cls = dr.gather(mi.UInt32, self.cls, cur, use)
            c = phi * ((1.0 - d2 / h2) * norm)
            acc_m += dr.select(use & (cls != REAL_ONLY), c, 0.0)
            acc_r += dr.select(use & (cls != MIXED_ONLY), c, 0.0)
            cur = dr.select(proc, cur + 1, cur)
            load = ~proc & (k < 27)
            d = [mi.Int32(k % 3), mi.Int32((k // 3) % 3), mi.Int32(k // 9)]
            inside = load & (d[0] <= span[0]) & (d[1] <= span[1]) & (d[2] <= span[2])
            b = _bucket(lo_i[0] + d[0], lo_i[1] + d[1], lo_i[2] + d[2], mx, my, mz, sy, sz)
            s = dr.gather(mi.UInt32, self.start, toff + b, inside)
            e = dr.gather(mi.UInt32, self.end, toff + b, inside)
            cur = dr.select(inside, s, cur)
            end = dr.select(inside, e, end)
            k = dr.select(load, k + 1, k)
            return k, cur, end, acc_m, acc_r

        k0, cur0, end0, acc_m, acc_r = state
        _, _, _, acc_m, acc_r = dr.while_loop(state=(mi.UInt32(k0), cur0, end0, acc_m, acc_r),
                                              cond=cond, body=body, label="photon_gather")
        return acc_m, acc_r


def build_photon_maps(world: World, views: SceneViews, ps: PhotonSettings
                      ) -> tuple[list[StoredPhotons], dict[str, float]]:
    """Shoot and trace the K photon maps (stage ``photons``, ``t_p``); stats of the shoot."""
    maps, emitted = [], 0
    for i in range(ps.ppm_iterations):
        seed = (ps.seed * 1_000_003 + i) & 0x7FFFFFFF
        em = emit_photons(world, views, ps.photons, seed)
        maps.append(trace_photons(views, em, ps.max_depth, seed))
        emitted += em.count
    stats = {"photons_emitted": float(emitted),
             "photons_stored": float(sum(m.count for m in maps))}
    for m in maps:
        for k, v in m.class_counts().items():
            stats[k] = stats.get(k, 0.0) + v
    return maps, stats


# ------------------------------------------------------------------------ camera gather
def _gather_walk(view: SceneView, rays: mi.Ray3f, rng: LaneSampler, max_depth: int
                 ) -> tuple[mi.Point3f, mi.Vector3f, mi.Color3f, mi.Bool, mi.Bool, mi.Int32,
                            mi.Bool]:
    """Follow camera rays through delta-specular vertices to the first non-delta hit.

    Returns (point, normal facing the arriving ray, throughput × diffuse BSDF value, found,
    a virtual shape was passed before the point (``wasSpecular`` of Kán §5.2), its role,
    the walk touched a virtual shape anywhere, the point included)."""
    n = dr.width(rng.key)
    ctx = mi.BSDFContext()
    state = (mi.Ray3f(rays), dr.full(mi.Color3f, 1.0, n), dr.full(mi.Bool, True, n),
             dr.zeros(mi.UInt32, n), dr.full(mi.Bool, False, n), dr.zeros(mi.Point3f, n),
             dr.zeros(mi.Vector3f, n), dr.zeros(mi.Color3f, n), dr.full(mi.Bool, False, n),
             dr.full(mi.Bool, False, n), dr.zeros(mi.Int32, n))

    def cond(ray, beta, active, depth, touched, qp, qn, qf, found, qt, qrole):
        return active

    def body(ray, beta, active, depth, touched, qp, qn, qf, found, qt, qrole):
        si = view.scene.ray_intersect(ray, mi.RayFlags.All, False, active)
        valid = active & si.is_valid()
        role = view.hit_role(si)
        bsdf = si.bsdf()
        flags = bsdf.flags()
        delta = _is_delta(flags)
        here = valid & ~delta & mi.has_flag(flags, mi.BSDFFlags.Diffuse)
        wo = mi.Vector3f(0.0, 0.0, dr.select(si.wi.z < 0, -1.0, 1.0))
        f = bsdf.eval(ctx, si, wo, here)  # f·|cos θ| at the normal: the diffuse value
        sgn = dr.select(dr.dot(si.n, ray.d) < 0, 1.0, -1.0)
        qp = dr.select(here, si.p, qp)
        qn = dr.select(here, si.n * sgn, qn)
        qf = dr.select(here, beta * f, qf)
        qt = dr.select(here, touched, qt)
        qrole = dr.select(here, role, qrole)
        found |= here
        touched |= valid & (role == ROLE_VIRTUAL)
        go = valid & delta & (depth + 2 <= max_depth)
        base = depth * DIMS_PER_DEPTH
        s1 = rng.next_1d(base + DIM_CAUSTIC_LOBE)
        # the direction's second coordinate cannot be the next dimension (it is the path
        # tracer's light sample of the next depth): a 7-round TEA hash of the same one, the
        # one number here not drawn through LaneSampler (kept: the renders are unchanged)
        d = base + DIM_CAUSTIC_DIR
        s2 = mi.Point2f(rng.next_1d(d), mi.sample_tea_float32(rng.key, d, 7))
        beta, ray, go = _specular_bounce(bsdf, ctx, si, s1, s2, go, beta, ray)
        return ray, beta, go, depth + 1, touched, qp, qn, qf, found, qt, qrole

    out = dr.while_loop(state=state, cond=cond, body=body, label="caustic_walk")
    _, _, _, _, touched, qp, qn, qf, found, qt, qrole = out
    return qp, qn, qf, found, qt, qrole, touched


def build_indices(maps: list[StoredPhotons], radii: list[float], views: SceneViews
                  ) -> tuple[PhotonMap, PhotonMap | None]:
    """The index over all photons and, when the views differ, one over the photons the real
    solution uses (shared + real-only): the µ walks of forked camera samples query only
    that, so a caustic of virtual glass (all mixed-only) costs them nothing."""
    full = PhotonMap.build(maps, radii)
    if views.mixed is views.real:
        return full, None
    return full, PhotonMap.build([m.without(MIXED_ONLY) for m in maps], radii)


def gather_caustics(views: SceneViews, pmap: PhotonMap, rays: mi.Ray3f, key: mi.UInt32,
                    max_depth: int, reprojector=None, pmap_real: PhotonMap | None = None
                    ) -> tuple[mi.Color3f, mi.Color3f]:
    """Caustic radiance ``(L_m, L_r)`` per camera sample (W·sr⁻¹·m⁻²), one-pass style.

    The walk in ρ gives ``L_m``; where it touched no virtual shape it is the walk of µ too,
    so ``L_r`` comes from the same point; the other lanes are compacted and walked in µ,
    querying ``pmap_real`` (the shared and real-only photons, :func:`build_indices`) when
    given, else ``pmap``.
    With camera-image reprojection (Kán §5.2) a mixed path that reaches a real diffuse point
    through virtual specular vertices takes that point's radiance from the frame, which
    already shows the real caustic there, so only the difference ``Σ_m − Σ_r`` is added.
    """
    md = 64 if max_depth < 0 else max_depth
    n = dr.width(key)
    rng = LaneSampler.independent(key)
    if pmap.stored == 0:  # no point/spot light or no generator: no caustic photons at all
        return dr.zeros(mi.Color3f, n), dr.zeros(mi.Color3f, n)
    which = dr.zeros(mi.UInt32, n)
    k = len(pmap.radii)
    if k > 1:
        u = rng.next_1d(_MAP_CHOICE)
        which = dr.minimum(mi.UInt32(u * k), k - 1)
    qp, qn, qf, found, qt, qrole, touched = _gather_walk(views.mixed, rays, rng, md)
    sm, sr = pmap.estimate(qp, qn, which, found)
    lm = qf * sm
    if reprojector is not None:
        cand = found & qt & (qrole == ROLE_REAL)
        ok = reprojector.lookup(qp, cand).ok
        lm = dr.select(ok, qf * (sm - sr), lm)
    if views.mixed is views.real:
        return lm, qf * sr
    lr = qf * sr
    dr.eval(lm, lr, touched)
    fork = dr.compress(touched)
    real_map = pmap if pmap_real is None else pmap_real
    if dr.width(fork) > 0 and real_map.stored == 0:
        lr = mi.Color3f(lr)
        dr.scatter(lr, dr.zeros(mi.Color3f, dr.width(fork)), fork)
    elif dr.width(fork) > 0:
        qp2, qn2, qf2, found2, _, _, _ = _gather_walk(views.real, dr.gather(mi.Ray3f, rays, fork),
                                                   rng.gather(fork), md)
        _, sr2 = real_map.estimate(qp2, qn2, dr.gather(mi.UInt32, which, fork), found2)
        lr = mi.Color3f(lr)
        dr.scatter(lr, qf2 * sr2, fork)
    return lm, lr


__all__ = ["GENERATOR_MATERIALS", "PHOTON_LIGHTS", "PhotonMap", "PhotonSettings",
           "StoredPhotons", "build_indices", "build_photon_maps", "emit_photons", "gather_caustics",
           "merge_cones", "trace_photons"]
