"""Reflective shadow maps (Dachsbacher & Stamminger 2005) by ray casting from the light.

An RSM of ``N × N`` texels stores, per texel, the surface the light sees first: position,
normal (turned towards the light), diffuse albedo, role, the flux that reaches it ``Φ_r``
(W) and the flux it reflects ``Φ_p = ρ Φ_r`` (W) — every texel is a diffuse VPL (Franke
§2.5, Eq. 12). The texel → direction maps are equal-measure, so every texel of one light
carries the same share of its emission:

* ``point``: uniform sphere (``mi.warp.square_to_uniform_sphere``), ``Φ_r = I · 4π/N²``;
* ``cosine`` (area-light patch): Malley's cosine-weighted hemisphere around the normal,
  ``Φ_r = I0 · π/N²`` (equal projected solid angle per texel);
* ``spot``: uniform cone of the cutoff angle, ``Φ_r = I0 · falloff(θ) · 2π(1−cos θ_c)/N²``;
* ``directional``: an orthographic ``N × N`` grid over the disk that covers ``bounds`` (a
  bounding sphere), ``Φ_r = E · (2r/N)²``.

**Aimed maps** (issue #33): a whole-sphere map of a point light puts few texels on a small
virtual object (bunny-box: ~2,000 of ~27,000 injected texels of a 512² map). With ``aims``
(:class:`Aim`: the sphere of the scene the camera sees, the virtual objects' sphere),
:func:`light_rays` adds per aim a map uniform over the cone (or, for directional lights,
the square) that the sphere subtends, and gives every texel the flux of the deterministic
mixture ``Φ_texel = I(ω) / Σ_k n_k p_k(ω)`` (Veach's balance heuristic over all the maps'
densities): the texels' flux still sums to the light's flux onto the scene, with more,
smaller texels where the aims are. Contract for every consumer: ``flux_in``/``flux_out`` is
each texel's flux in W (texels no longer carry equal shares when aimed).

The same rays are cast into the mixed view (``R_ρ``) and the real-only view (``R_µ``)
(Franke §4.3: "the same process is repeated for a second RSM R^µ"). A ray whose first hit in
the mixed scene is real (or a miss) sees the same in the real-only scene, so
:func:`render_rsm_pair` casts only the texels that hit a virtual object again and copies the
rest: those texels carry bit-identical values in both maps. When the real proxy and the
lights stay put between frames (the prepared world: only virtual objects move),
:func:`render_rsm_pair_reusing` goes further: ``R_µ`` is cast once (:func:`render_rsm`) and
each frame casts into the mixed view only the rays that cross the virtual objects' bounding
box — the same pair, for a fraction of the rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import (
    LIGHT_SHAPE_INDEX,
    ROLE_MISS,
    ROLE_VIRTUAL,
    SceneView,
    SceneViews,
)
from arlight.errors import InputError
from arlight.jit import aligned, opaque, opaques
from arlight.realtime.gbuffer import facing, surface_albedo
from arlight.realtime.light_reduction import LightSet, ReducedLight
from arlight.realtime.sh_volume import Grid
from arlight.realtime.shading import spot_falloff

BYTES_PER_TEXEL = 4 * 32
"""Rough memory per RSM texel while it is built (rays, interaction, outputs), bytes."""


@dataclass
class LightRays:
    """The ``N²`` rays of one light's RSM and the flux each carries (W, RGB)."""

    origin: mi.Point3f
    direction: mi.Vector3f
    flux: mi.Color3f
    res: int


@dataclass
class RSM:
    """One reflective shadow map (Dr.Jit arrays of ``res²`` texels).

    Attributes:
        position, normal, albedo: the surface each texel sees (normal towards the light).
        role: −1 miss, 0 real, 1 virtual. shape: shape index (−1 miss).
        t: ray distance (m). direction: unit direction of the light's ray (travel).
        flux_in: ``Φ_r`` (W) reaching the texel's surface; 0 on a miss.
        flux_out: ``Φ_p = ρ Φ_r`` (W), the VPL's flux.
    """

    position: mi.Point3f
    normal: mi.Vector3f
    albedo: mi.Color3f
    role: mi.Int32
    shape: mi.Int32
    t: mi.Float
    direction: mi.Vector3f
    flux_in: mi.Color3f
    flux_out: mi.Color3f
    res: int

    @property
    def valid(self) -> mi.Bool:
        return self.role != ROLE_MISS


def check_memory(res: int, count: int = 2) -> None:
    """InputError (field ``options.rsm_size``) when ``count`` RSMs of ``res²`` texels would
    not fit in the available memory (``MemAvailable`` of ``/proc/meminfo``)."""
    need = BYTES_PER_TEXEL * res * res * count
    avail = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
    except OSError:  # pragma: no cover - not Linux
        return
    if avail is not None and need > avail:
        raise InputError(f"{count} RSMs of {res}² texels need about {need / 2**30:.1f} GiB; "
                         f"{avail / 2**30:.1f} GiB available", field="options.rsm_size")


def _texel_uv(res: int) -> mi.Point2f:
    i = dr.arange(mi.UInt32, res * res)
    u = (mi.Float(i % res) + 0.5) / res
    v = (mi.Float(i // res) + 0.5) / res
    return mi.Point2f(u, v)


@dataclass(frozen=True)
class Aim:
    """A sphere an aimed RSM puts extra texels on (the camera's view of the scene, the
    virtual objects), m.

    Attributes:
        centre, radius: the sphere (m).
        share: aimed texels per texel of the light's own map: the aimed map has
            ``round(res·√share)²`` texels (at least one when ``share > 0``).
    """

    centre: np.ndarray
    radius: float
    share: float = 1.0

    def side(self, res: int) -> int:
        """Texels per side of this aim's map next to a base map of ``res²`` texels."""
        return 0 if self.share <= 0.0 else max(1, int(round(res * math.sqrt(self.share))))


def _emission(light: ReducedLight, cos_axis: mi.Float) -> mi.Float:
    """Radiant intensity ``I(ω)/I0`` of a point, cosine or spot light at ``<axis, ω>``."""
    if light.kind == "point":
        return dr.zeros(mi.Float, dr.width(cos_axis)) + 1.0
    if light.kind == "cosine":
        return dr.maximum(cos_axis, 0.0)
    return dr.select(cos_axis >= light.cos_cutoff, spot_falloff(light, cos_axis), 0.0)


def _base_pdf(light: ReducedLight, cos_axis: mi.Float) -> mi.Float:
    """Solid-angle density (1/sr) of the light's own texel map at ``<axis, ω>``: uniform
    sphere (point), cosine hemisphere (cosine), uniform cone (spot)."""
    if light.kind == "point":
        return dr.zeros(mi.Float, dr.width(cos_axis)) + 1.0 / (4.0 * math.pi)
    if light.kind == "cosine":
        return dr.maximum(cos_axis, 0.0) * (1.0 / math.pi)
    return dr.select(cos_axis >= light.cos_cutoff,
                     1.0 / (2.0 * math.pi * (1.0 - light.cos_cutoff)), 0.0)


def _cat(parts: list):
    if len(parts) == 1:
        return parts[0]
    return type(parts[0])(*(dr.concat([a[i] for a in parts]) for i in range(3)))


def _aimed_cones(light: ReducedLight, res: int, aims: list[Aim], dirs: mi.Vector3f,
                 n_base: int) -> tuple[mi.Vector3f, mi.Color3f]:
    """Directions of a point/cosine/spot map with ``aims`` added, and each texel's flux.

    Each aim whose sphere does not hold the light adds a ``side²`` map uniform over the cone
    that the sphere subtends (``cos α = √(1 − r²/d²)``, density ``1/(2π(1 − cos α))``). The
    texels of all maps together estimate ``Φ = ∫ I(ω) dω`` with the deterministic mixture
    (multi-sample balance heuristic, Veach 1997 Eq. 9.12 with ``n_k`` samples of ``p_k``):
    ``Φ_texel = I(ω) / (n_0 p_0(ω) + Σ_k n_k p_k(ω))`` (W), unbiased for any aim."""
    pos = np.asarray(light.position, np.float64)
    cones = []
    for a in aims:
        to = np.asarray(a.centre, np.float64) - pos
        d = float(np.linalg.norm(to))
        m = a.side(res)
        if m == 0 or d <= a.radius * (1.0 + 1e-6):
            continue  # the light is inside the sphere: its own map already covers it
        cones.append((to / d, math.sqrt(max(1.0 - (a.radius / d) ** 2, 0.0)), m))
    # the aims move every frame: their numbers are opaque (one kernel for every pose)
    cones = [(mi.Vector3f(*opaques(axis)), opaque(cos_a),
              opaque(m * m / (2.0 * math.pi * (1.0 - cos_a))), m) for axis, cos_a, m in cones]
    all_dirs = [dirs]
    for axis, cos_a, _, m in cones:
        frame = mi.Frame3f(axis)
        all_dirs.append(frame.to_world(mi.warp.square_to_uniform_cone(_texel_uv(m), cos_a)))
    d = _cat(all_dirs)
    lax = mi.Vector3f(*opaques(light.axis))
    cos_axis = dr.dot(d, lax)
    den = _base_pdf(light, cos_axis) * float(n_base)
    for axis, cos_a, density, _ in cones:
        den += dr.select(dr.dot(d, axis) >= cos_a, density, 0.0)
    i0 = mi.Color3f(*opaques(light.intensity))
    flux = i0 * dr.select(den > 0.0, _emission(light, cos_axis) / dr.maximum(den, 1e-30), 0.0)
    return d, flux


def _aimed_parallel(light: ReducedLight, res: int, bounds: tuple[np.ndarray, float],
                    aims: list[Aim]) -> tuple[mi.Point3f, mi.Vector3f, mi.Color3f]:
    """Origins, directions and flux of a directional light's map with ``aims``: the base
    ``res²`` grid over the square ``[−r, r]²`` around ``bounds`` (perpendicular to the light,
    area density ``1/(4r²)``) plus, per aim, a ``side²`` grid over the square around the aim
    sphere's projection (density ``1/(4r_k²)``). Flux per texel: the mixture estimate of
    ``Φ = ∫ E dA``: ``E / (n_0 p_0(x) + Σ_k n_k p_k(x))`` (W)."""
    centre, radius = bounds
    axis = np.asarray(light.axis, np.float64)
    frame = mi.Frame3f(mi.Vector3f(*opaques(axis)))
    r = float(radius)
    squares = [(0.0, 0.0, r, res)]
    tangents = np.array([np.array(frame.s, np.float64).ravel(),
                         np.array(frame.t, np.float64).ravel()])  # the light's frame, fixed
    for a in aims:
        m = a.side(res)
        if m > 0:
            cx, cy = tangents @ (np.asarray(a.centre, np.float64) - centre)
            squares.append((float(cx), float(cy), float(a.radius), m))
    # the bounds and aims move every frame: opaque numbers (one kernel for every pose)
    squares = [(opaque(cx), opaque(cy), opaque(h), opaque(m * m / (4.0 * h * h)), m)
               for cx, cy, h, m in squares]
    lx, ly = [], []
    for cx, cy, h, _, m in squares:
        uv = _texel_uv(m)
        lx.append((2.0 * uv.x - 1.0) * h + cx)
        ly.append((2.0 * uv.y - 1.0) * h + cy)
    x, y = dr.concat(lx), dr.concat(ly)
    den = dr.zeros(mi.Float, dr.width(x))
    for cx, cy, h, density, _ in squares:
        inside = (dr.abs(x - cx) <= h) & (dr.abs(y - cy) <= h)
        den += dr.select(inside, density, 0.0)
    start = np.asarray(centre, np.float64) - axis * (4.0 * r + 1.0)
    origin = mi.Point3f(mi.Point3f(*opaques(start)) + frame.to_world(mi.Vector3f(x, y, 0.0)))
    d = dr.zeros(mi.Vector3f, dr.width(x)) + mi.Vector3f(*opaques(axis))
    i0 = mi.Color3f(*opaques(light.intensity))
    return origin, d, i0 * (1.0 / dr.maximum(den, 1e-30))


def light_rays(light: ReducedLight, res: int, bounds: tuple[np.ndarray, float],
               aims: list[Aim] | tuple[Aim, ...] = ()) -> LightRays:
    """The rays of ``light``'s RSM. ``bounds``: (centre, radius) of the region a
    directional light's map must cover (m).

    ``aims`` (an aimed RSM, issue #33): extra texels on each :class:`Aim`'s sphere — the part
    of the scene the camera sees, the virtual objects — after the light's own ``res²`` map,
    with every texel's flux from the mixture density of all the maps (see
    :func:`_aimed_cones`, :func:`_aimed_parallel`), so the texels' flux still sums to an
    unbiased estimate of the light's flux onto the scene. Without aims: the equal-measure
    maps of the module docstring (``res`` set: a square map)."""
    aims = list(aims)
    if aims and light.kind == "directional":
        origin, d, flux = _aimed_parallel(light, res, bounds, aims)
        dr.eval(origin, d, flux)
        return LightRays(origin, d, flux, 0)
    uv = _texel_uv(res)
    i0 = mi.Color3f(*opaques(light.intensity))
    pos = mi.Point3f(*opaques(light.position))
    if light.kind == "point":
        d = mi.warp.square_to_uniform_sphere(uv)
        flux = i0 * (4.0 * math.pi / res**2)
        origin = dr.zeros(mi.Point3f, res * res) + pos
    elif light.kind in ("cosine", "spot"):
        frame = mi.Frame3f(mi.Vector3f(*opaques(light.axis)))
        if light.kind == "cosine":
            local = mi.warp.square_to_cosine_hemisphere(uv)
            flux = i0 * (math.pi / res**2)
        else:
            local = mi.warp.square_to_uniform_cone(uv, float(light.cos_cutoff))
            fall = spot_falloff(light, local.z)  # every texel lies inside the cone
            flux = i0 * (fall * (2.0 * math.pi * (1.0 - light.cos_cutoff) / res**2))
        d = frame.to_world(local)
        origin = dr.zeros(mi.Point3f, res * res) + pos
    else:
        centre, radius = bounds
        axis = np.asarray(light.axis, np.float64)
        frame = mi.Frame3f(mi.Vector3f(*opaques(axis)))
        r = float(radius)
        local = mi.Vector3f((2.0 * uv.x - 1.0) * r, (2.0 * uv.y - 1.0) * r, 0.0)
        start = np.asarray(centre, np.float64) - axis * (4.0 * r + 1.0)
        origin = mi.Point3f(mi.Point3f(*opaques(start)) + frame.to_world(local))
        d = dr.zeros(mi.Vector3f, res * res) + mi.Vector3f(*opaques(axis))
        flux = i0 * ((2.0 * r / res) ** 2)
    if aims:
        d, flux = _aimed_cones(light, res, aims, mi.Vector3f(d), res * res)
        origin = dr.zeros(mi.Point3f, dr.width(d)) + pos
        dr.eval(origin, d, flux)
        return LightRays(origin, d, flux, 0)
    flux = dr.zeros(mi.Color3f, res * res) + flux
    dr.eval(origin, d, flux)
    return LightRays(origin, d, flux, res)


def concat_rays(parts: list[LightRays]) -> LightRays:
    """The rays of several lights as one batch (``res`` 0: not a square map), so that one
    :func:`render_rsm` per view casts them all."""
    if len(parts) == 1:
        return parts[0]

    def cat(arrays: list):
        return type(arrays[0])(*(dr.concat([a[i] for a in arrays]) for i in range(3)))

    return LightRays(cat([p.origin for p in parts]), cat([p.direction for p in parts]),
                     cat([p.flux for p in parts]), 0)


SELF_HIT = 1e-4
"""Hits on light geometry closer to a ray's origin than this × (1 + |origin|) (m) are the
ray's own emitter (:func:`render_rsm`)."""


def render_rsm(view: SceneView, rays: LightRays) -> RSM:
    """Cast ``rays`` into ``view``: the RSM of that view (``R_ρ`` for ``views.mixed``,
    ``R_µ`` for ``views.real``)."""
    ray = mi.Ray3f(rays.origin, rays.direction)
    si = view.scene.ray_intersect(ray)
    # an area light's rays start on its own emitter: a hit on light geometry within
    # SELF_HIT of the origin is the light itself, cast on from there (issue #33: every ray of
    # an area light stopped there, so its RSMs and its shadows in dlpv/dvct were empty)
    own = (view.hit_shape(si) == LIGHT_SHAPE_INDEX) & (si.t < SELF_HIT * (
        1.0 + dr.norm(mi.Vector3f(ray.o))))
    if dr.any(own):
        si = dr.select(own, view.scene.ray_intersect(si.spawn_ray(ray.d), own), si)
    valid = si.is_valid()
    role = view.hit_role(si)
    shape = view.hit_shape(si)
    n = facing(mi.Vector3f(si.sh_frame.n), -ray.d)
    albedo = surface_albedo(si, valid)
    flux_in = dr.select(valid, rays.flux, mi.Color3f(0.0))
    flux_out = flux_in * albedo
    t = dr.select(valid, si.t, dr.inf)
    pos = mi.Point3f(si.p)
    dr.eval(pos, n, albedo, role, shape, t, flux_in, flux_out)
    return RSM(pos, n, albedo, role, shape, t, mi.Vector3f(ray.d), flux_in, flux_out, rays.res)


_RSM_ARRAYS = ("position", "normal", "albedo", "role", "shape", "t", "direction", "flux_in",
               "flux_out")


def rsm_subset(r: RSM, idx: mi.UInt32) -> RSM:
    """The texels ``idx`` of ``r`` as an RSM of ``width(idx)`` lanes (``res`` 0)."""
    return RSM(**{name: dr.gather(type(getattr(r, name)), getattr(r, name), idx)
                  for name in _RSM_ARRAYS}, res=0)


@dataclass
class RSMPair:
    """``R_ρ`` and ``R_µ`` of one light's rays, ``R_µ`` stored only where it differs.

    Attributes:
        rho: ``R_ρ``, every texel (the mixed scene).
        changed: indices of the texels whose mixed-scene hit is virtual; everywhere else
            ``R_µ`` equals ``R_ρ`` bit for bit (a real hit or a miss is the same in both).
        mu_changed: ``R_µ`` on the ``changed`` texels, in that order (``res`` 0).
    """

    rho: RSM
    changed: mi.UInt32
    mu_changed: RSM

    def rho_changed(self) -> RSM:
        """``R_ρ`` on the ``changed`` texels (the VPLs that ``R_µ`` does not cancel)."""
        return rsm_subset(self.rho, self.changed)

    def mu(self) -> RSM:
        """``R_µ`` on every texel (``R_ρ`` with the changed texels replaced)."""
        return replace_texels(self.rho, self.changed, self.mu_changed)


def replace_texels(base: RSM, idx: mi.UInt32, sub: RSM) -> RSM:
    """``base`` with the texels ``idx`` replaced by ``sub`` (``width(idx)`` lanes, in that
    order); ``base`` itself when ``idx`` is empty."""
    if dr.width(idx) == 0:
        return base
    n = dr.width(base.role)
    slot = dr.zeros(mi.UInt32, n)
    dr.scatter(slot, dr.arange(mi.UInt32, dr.width(idx)), idx)
    hit = dr.zeros(mi.Bool, n)
    dr.scatter(hit, True, idx)
    fields = {name: dr.select(hit, dr.gather(type(getattr(base, name)), getattr(sub, name),
                                             slot, hit), getattr(base, name))
              for name in _RSM_ARRAYS}
    dr.eval(*fields.values())
    return RSM(**fields, res=base.res)


def subset_rays(rays: LightRays, idx: mi.UInt32) -> LightRays:
    """The rays ``idx`` of ``rays`` (``res`` 0: not a square map)."""
    return LightRays(dr.gather(mi.Point3f, rays.origin, idx),
                     dr.gather(mi.Vector3f, rays.direction, idx),
                     dr.gather(mi.Color3f, rays.flux, idx), 0)


def render_rsm_pair(views: SceneViews, rays: LightRays) -> RSMPair:
    """``R_ρ`` cast into the mixed view, and ``R_µ`` cast into the real-only view for the
    texels that hit a virtual object only: equal to two :func:`render_rsm` calls (see
    :meth:`RSMPair.mu`) for the cost of one plus the virtual object's texels."""
    rho = render_rsm(views.mixed, rays)
    changed = dr.compress(rho.role == ROLE_VIRTUAL)
    if dr.width(changed) == 0:  # no virtual object in the light's view: R_µ = R_ρ
        return RSMPair(rho, changed, rsm_subset(rho, changed))
    return RSMPair(rho, changed, render_rsm(views.real, subset_rays(rays, changed)))


def render_rsm_pair_reusing(views: SceneViews, rays: LightRays, mu: RSM,
                            box: tuple[np.ndarray, np.ndarray]) -> RSMPair:
    """The pair of :func:`render_rsm_pair` from ``mu = render_rsm(views.real, rays)`` cast
    earlier: only the rays that cross ``box`` (lo, hi: the virtual objects' world bounding
    box, m) are cast into the mixed view — no other ray can reach a virtual object, so
    everywhere else ``R_ρ`` is ``R_µ`` (the same first hit) — and those texels replace
    ``R_µ``'s in ``R_ρ``. The same texels as :func:`render_rsm_pair`; a real surface's hit
    point can differ in the last bits, since the two views' acceleration structures round
    differently (measured: 81 coordinates of a directional map on the demo scene, ~1e-7 m;
    bit for bit on tests/realtime's scenes)."""
    return render_rsm_pairs_reusing(views, [rays], [mu], box)[0]


def _box_candidates(rays: LightRays, box: tuple[np.ndarray, np.ndarray]) -> mi.UInt32:
    """Indices of the rays that cross ``box`` (lo, hi, m; padded so that rays grazing it
    stay candidates)."""
    lo, hi = (np.asarray(b, np.float64) for b in box)
    pad = 1e-4 * max(float(np.max(hi - lo)), 1e-3)
    # opaque: the box follows the objects; as literals it compiled a kernel every frame
    bbox = mi.BoundingBox3f(mi.Point3f(*opaques(lo - pad)), mi.Point3f(*opaques(hi + pad)))
    crosses, _, _ = bbox.ray_intersect(mi.Ray3f(rays.origin, rays.direction))
    return dr.compress(crosses)


def render_rsm_pairs_reusing(views: SceneViews, rays: list[LightRays], mus: list[RSM],
                             box: tuple[np.ndarray, np.ndarray]) -> list[RSMPair]:
    """:func:`render_rsm_pair_reusing` of several lights' maps (``rays[i]``, ``mus[i]``)
    with **one** cast into the mixed view: the candidate rays of every map concatenated
    (issue #32: a cast costs some 4 ms of tracing and launching on the CPU whatever its
    width — 47 rays or 4096 —, a third of a dlpv drag frame with three lights). Bit for bit
    one call per map: a ray's hit does not depend on the rays cast with it."""
    cands = [_box_candidates(r, box) for r in rays]
    widths = [dr.width(c) for c in cands]
    sub = None
    if any(widths):  # indices into every light's rays, concatenated on the host: Dr.Jit
        # concatenations of per-frame sizes compile a kernel per size (offsets as literals)
        starts = np.cumsum([0] + [dr.width(r.origin) for r in rays[:-1]])
        idx = np.concatenate([np.array(c, np.int64) + s for c, s in zip(cands, starts,
                                                                           strict=True)])
        sub = render_rsm(views.mixed, subset_rays(concat_rays(rays),
                                                  mi.UInt32(aligned(idx, np.uint32))))
    # the virtual hits of the cast, split by light on the host (one small transfer)
    virt = np.flatnonzero(np.array(sub.role) == ROLE_VIRTUAL) if sub is not None else None
    out, offset = [], 0
    for mu, cand, n in zip(mus, cands, widths, strict=True):
        if n == 0:
            out.append(RSMPair(mu, cand, rsm_subset(mu, cand)))
            continue
        mine = virt[(virt >= offset) & (virt < offset + n)]
        changed = dr.gather(mi.UInt32, cand, mi.UInt32(aligned(mine - offset, np.uint32)))
        offset += n
        dr.eval(changed)
        rho = replace_texels(mu, changed, rsm_subset(sub, mi.UInt32(aligned(mine, np.uint32))))
        out.append(RSMPair(rho, changed, rsm_subset(mu, changed)))
    return out


def shared_texels(a: RSM, b: RSM) -> mi.Bool:
    """Texels that see the same surface point in both maps (same shape and distance): their
    VPLs cancel in a delta (Franke §4.3.1: "VPLs visible in both RSMs are eliminated")."""
    return (a.shape == b.shape) & ((a.t == b.t) | ((a.role == ROLE_MISS) & (b.role == ROLE_MISS)))


@dataclass
class RealMaps:
    """Per reduced light, the rays of its RSM and ``R_µ`` (the real proxy's map), cast once
    when the world is prepared: the proxy and the lights do not change between frames, so a
    frame casts only the rays that can reach a virtual object
    (:func:`~arlight.realtime.rsm.render_rsm_pair_reusing`)."""

    lights: LightSet  # the lights they were cast for (a replaced LightSet: cast again)
    res: int
    rays: list[LightRays]
    mu: list[RSM]
    box: tuple[np.ndarray, np.ndarray]  # the virtual objects' world bounding box (m)
    coverage: tuple[np.ndarray, float]
    """(centre, radius) the directional maps cover, m (:func:`real_maps`)."""


class RSMState(Protocol):
    """What :func:`rsm_pair` needs of a method's prepared state (dlpv's, dvct's)."""

    views: SceneViews
    lights: LightSet
    grid: Grid | None
    real_maps: RealMaps | None


def _coverage(grid: Grid) -> tuple[np.ndarray, float]:
    """(centre, radius) a directional light's map covers: the volume's bounding sphere, m."""
    return grid.centre, grid.size * np.sqrt(3.0) / 2.0


def same_grid(a: Grid | None, b: Grid | None) -> bool:
    """Whether two grids are the same cells (same count, size and origin, bitwise)."""
    return (a is not None and b is not None and a.n == b.n and a.cell == b.cell
            and np.array_equal(a.origin, b.origin))


def real_maps(views: SceneViews, lights: LightSet, grid: Grid, res: int,
              box: tuple[np.ndarray, np.ndarray],
              coverage: tuple[np.ndarray, float] | None = None) -> RealMaps:
    """Every reduced light's RSM rays (directional maps cover ``coverage``, (centre,
    radius) in m, by default the volume's bounding sphere) and ``R_µ`` cast into the
    real-only view."""
    cover = coverage or _coverage(grid)
    rays = [light_rays(lt, res, cover) for lt in lights.lights]
    return RealMaps(lights, res, rays, [render_rsm(views.real, r) for r in rays], box,
                    cover)


def same_coverage(a: tuple[np.ndarray, float] | None,
                  b: tuple[np.ndarray, float] | None) -> bool:
    """Whether two (centre, radius) coverages are bitwise the same sphere."""
    return (a is not None and b is not None and a[1] == b[1]
            and np.array_equal(a[0], b[0]))


def moved_maps(maps: RealMaps, views: SceneViews, grid: Grid,
               box: tuple[np.ndarray, np.ndarray],
               coverage: tuple[np.ndarray, float] | None = None) -> RealMaps:
    """``real_maps(views, maps.lights, grid, maps.res, box, coverage)`` after the virtual
    objects moved and the proxy did not (incremental pose, issue #32): a light's rays and
    ``R_µ`` are kept unless they depend on the coverage — a directional light's map covers
    ``coverage`` (default the volume's bounding sphere) — and it differs from the sphere
    ``maps`` were cast for; those are cast again. Bit for bit the maps :func:`real_maps`
    casts (the same rays into the same real-only view)."""
    cover = coverage or _coverage(grid)
    moved = not same_coverage(maps.coverage, cover)
    rays, mu = [], []
    for lt, r, m in zip(maps.lights.lights, maps.rays, maps.mu, strict=True):
        if moved and lt.kind == "directional":
            r = light_rays(lt, maps.res, cover)
            m = render_rsm(views.real, r)
        rays.append(r)
        mu.append(m)
    return RealMaps(maps.lights, maps.res, rays, mu, box, cover)


def rsm_pair(data: RSMState) -> list[RSMPair]:
    """``(R_ρ, R_µ)`` per reduced light of ``data`` (any prepared state with ``views``,
    ``lights``, ``grid`` and ``real_maps``: dlpv's and dvct's), from the prepared ``R_µ``
    — cast again, for this call only, when ``data.lights`` is not the set they were cast
    for."""
    maps = data.real_maps
    if maps is None:
        return []
    if maps.lights is not data.lights:
        maps = real_maps(data.views, data.lights, data.grid, maps.res, maps.box,
                         maps.coverage)
    return render_rsm_pairs_reusing(data.views, maps.rays, maps.mu, maps.box)


__all__ = ["Aim", "LightRays", "RSM", "RSMPair", "RSMState", "RealMaps", "check_memory",
           "concat_rays", "light_rays", "moved_maps", "real_maps", "render_rsm", "render_rsm_pair",
           "render_rsm_pair_reusing", "render_rsm_pairs_reusing", "replace_texels", "rsm_pair",
           "rsm_subset", "same_coverage", "same_grid",
           "shared_texels", "subset_rays"]
