"""``dir``: Differential Instant Radiosity (Knecht et al. 2010; Franke thesis §5.5 baseline).

Instant radiosity (Keller 1997) run twice per frame from the same reflective shadow maps:

* per reduced light, an **aimed** RSM (:func:`~arlight.realtime.rsm.light_rays` with
  :class:`~arlight.realtime.rsm.Aim` spheres, issue #33): ``s² ≈ rsm_size² ×`` its power
  share texels over the light's own emission plus ``aim_object`` × as many on the virtual
  objects' sphere and ``aim_view`` × on the sphere of the scene the camera sees, each
  texel's flux from the mixture density (so the texels still sum to the light's flux),
  cast into the mixed view (``R_ρ``: VPLs on real and virtual surfaces) and the real view
  (``R_µ``);
* ``vpls`` VPLs are **picked by importance** among the texels of all lights:
  ``q_i = max(Y(Φ_ρ,i), Y(Φ_µ,i)) · (1 + β · prox_i)`` with ``prox = 1/(1 + (d/r)²)``, ``d``
  the texel's distance outside the virtual objects' sphere of radius ``r`` (``β`` =
  ``vpl_importance``); texels with ``vpls · q_i/Σq ≥ 1`` are kept with probability 1, the
  rest by systematic sampling with inclusion probability ``π_i = n q_i/Σq`` and flux
  ``Φ_i/π_i`` (Horvitz–Thompson: an unbiased estimate of the sum over all texels); the same
  texels in ``R_ρ`` and ``R_µ``, so the pairs stay paired;
* every G-buffer pixel gathers ``L = ρ/π Σ_v Φ_v/π · G_b(x, v) · V(x, v)`` (Franke Eq. 2.43)
  with the clamped geometry term ``G_b = min(<n_x,ω>+ <n_v,−ω>+ / d², 1/d_c²)`` (Eq. 2.45)
  and ray-traced visibility ``V``, in the mixed scene for ``R_ρ``'s VPLs and in the real
  scene for ``R_µ``'s; direct light from the reduced lights with shadow rays in both (on
  real pixels the real-scene ray only where the mixed one is blocked, and several rays over
  an extended light's region or patch: ``shadow_samples``,
  :func:`~arlight.realtime.shading.direct_change`);
* virtual pixels show the mixed solution (plus SH ambient); real pixels get
  ``delta = mixed − real`` (Knecht's differential: only the change is added to the frame),
  with the photograph's albedo ``ρ̂ = clip(π B / E_r, 0, 1)`` (``real_albedo = photo``,
  :mod:`arlight.realtime.real_lane`; ``E_r`` with ``R_µ``'s gathered indirect light).

Cost control: with ``interleave = k`` (Segovia et al. 2006's interleaved sampling, our
choice in place of Knecht's imperfect shadow maps) pixel ``(x, y)`` gathers only the VPLs
``j ≡ (x mod k) + k (y mod k) (mod k²)`` at ``k²`` × their flux, and a ``k × k``
geometry-aware box filter (depth within 5 %, normals within 37°) recombines the subsets.
``interleave = 1`` gathers every VPL at every pixel (exact instant radiosity). With
``gbuffer_spp = n > 1`` the pixel's subset is split once more over its samples (sample ``s``
gathers the subset's VPLs ``s, s + n, …`` at ``n k²`` × their flux) and the filter averages
the same sample of the neighbouring pixels: the pixel's mean over its samples counts every
VPL of the ``k × k`` block once, and the gather costs what one sample per pixel costs.
A VPL pair seen identically in both maps needs the real-scene ray only where the mixed one is
blocked (the mixed scene contains the real one).

Stats: ``time_gbuffer``, ``time_rsm``, ``time_direct``, ``time_gather``, ``time_filter``,
``time_assemble`` (s); ``vpls``, ``shadow_rays``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import ROLE_VIRTUAL, SceneViews, build_views
from arlight.jit import aligned
from arlight.methods.base import (
    BaseMethod,
    Layers,
    RenderSettings,
    place_views,
)
from arlight.methods.fragments import (
    AA_GBUFFER_SPP,
    GBUFFER_FRAME_OPTIONS,
    REDUCTION_OPTIONS,
    drag_gbuffer_spp,
    gbuffer_options,
)
from arlight.methods.spec import Capabilities, Field, MethodSpec, Options
from arlight.realtime.ambient import (
    AMBIENT_OPTIONS,
    AmbientOcclusion,
    ambient_drag_options,
    pose_ambient,
    prepare_ambient,
    real_ambient_loss,
)
from arlight.realtime.gbuffer import GBuffer, assemble, render_gbuffer
from arlight.realtime.ibl_shading import probe_drag_options
from arlight.realtime.light_reduction import REDUCIBLE_LIGHTS, LightSet, reduce_lights
from arlight.realtime.object_shading import (
    OBJECT_OPTIONS,
    ObjectLight,
    pose_object_light,
    prepare_object_light,
    shade_objects,
)
from arlight.realtime.real_lane import REAL_LANE_OPTIONS, real_albedo
from arlight.realtime.rsm import (
    RSM,
    Aim,
    concat_rays,
    light_rays,
    render_rsm_pair,
    replace_texels,
    rsm_subset,
    shared_texels,
)
from arlight.realtime.shading import (
    SHADOW_EPS,
    direct_terms_gbuffer,
    scene_bounds,
    virtual_bounds,
)
from arlight.scene.model import FrameView, World
from arlight.sphere.sh import LUMINANCE
from arlight.timing import StageTimer

OPTIONS: dict[str, Field] = {
    "vpls": Field("int", 256, "virtual point lights per frame, all lights together (Knecht "
                  "2010, Franke Fig. 5.19: 256)", "", min=1, max=65536),
    "rsm_size": Field("int", 64, "side of the VPL candidates' RSM, all lights together: each "
                      "light's own map has rsm_size² × its power share texels (aimed texels "
                      "come on top)", "texels", min=1, max=1024),
    "aim_object": Field("float", 1.0, "aimed texels on the virtual objects' sphere per texel "
                        "of a light's own map (0: none)", "", min=0.0, max=64.0),
    "aim_view": Field("float", 0.0, "aimed texels on the sphere of the scene the camera sees "
                      "per texel of a light's own map (0: none; > 0 makes the light maps "
                      "depend on the camera, so every camera move casts them again)", "",
                      min=0.0, max=64.0),
    "vpl_importance": Field("float", 4.0, "β of the VPL importance flux × (1 + β · proximity "
                            "to the virtual objects); 0: VPLs picked by flux alone", "",
                            min=0.0, max=1.0e4),
    "clamp_distance": Field("float", 0.05, "geometry-term clamp: G ≤ 1/d_c² (Eq. 2.45)", "m",
                            min=0.0, max=1.0e6),
    "interleave": Field("int", 4, "interleaved sampling block k (k² VPL subsets; 1: every "
                        "VPL at every pixel)", "pixels", min=1, max=16),
    **AMBIENT_OPTIONS,
    **OBJECT_OPTIONS,
    **REAL_LANE_OPTIONS,
    **REDUCTION_OPTIONS,
    **gbuffer_options(AA_GBUFFER_SPP),
}


def _check(opts: Options) -> None:
    from arlight.errors import InputError

    if opts.interleave ** 2 > opts.vpls:
        raise InputError(f"interleave {opts.interleave} needs at least "
                         f"{opts.interleave ** 2} VPLs (one per subset)",
                         file="method 'dir'", field="options.interleave")


def drag_options(options: Options, factor: int) -> dict[str, int]:
    """Options of a studio frame at 1/``factor`` of the size while dragging (issue #32):
    ``vpls`` and ``rsm_size`` divided by ``factor`` (at least 64 VPLs, 16 texels) and one
    G-buffer sample (:func:`~arlight.methods.fragments.drag_gbuffer_spp`), so the
    VPLs' RSMs and their selection shrink with the image as the gathering does; the
    ambient occlusion field's rays and shells too
    (:func:`~arlight.realtime.ambient.ambient_drag_options`); the objects' bounce probe
    is not traced again per pose (:func:`~arlight.realtime.ibl_shading.probe_drag_options`)."""
    return {"vpls": max(64, options.vpls // factor),
            "rsm_size": max(16, options.rsm_size // factor),
            **drag_gbuffer_spp(options, factor),
            **ambient_drag_options(options, factor), **probe_drag_options(options, factor)}


SPEC = MethodSpec(
    name="dir",
    description="Differential instant radiosity (Knecht et al. 2010): RSM VPLs with "
                "ray-traced visibility, mixed minus real.",
    options=OPTIONS,
    capabilities=Capabilities(interactive=True, materials=frozenset({"diffuse", "phong"}),
                              lights=REDUCIBLE_LIGHTS),
    check=_check,
    drag_options=drag_options,
    frame_options=GBUFFER_FRAME_OPTIONS,
)


@dataclass
class DIRData:
    """The world, its Mitsuba views, the reduced lights, the scene's bounding sphere and the
    virtual objects' occlusion of the SH ambient remainder (:mod:`arlight.realtime.ambient`).
    """

    world: World
    views: SceneViews
    lights: LightSet
    bounds: tuple[np.ndarray, float]
    ambient: AmbientOcclusion = dataclasses.field(default_factory=AmbientOcclusion.none)
    objects: ObjectLight | None = None


OBJECT_PAD = 1.5
"""The virtual objects' aim sphere: their bounding sphere × this, so that the proxy next to
them (where their shadow and bounce fall, where ``R_µ`` sees behind them) gets texels too."""


@dataclass
class VPLs:
    """The VPLs of both solutions, paired by texel (Dr.Jit arrays of length V).

    Attributes:
        on_object: VPLs whose ``R_ρ`` texel lies on a virtual object (reported as a stat).
    """

    rho: RSM
    mu: RSM
    shared: mi.Bool
    count: int
    on_object: int = 0


def pick_by_importance(q: np.ndarray, count: int, xi: float) -> tuple[np.ndarray, np.ndarray]:
    """``count`` indices drawn without replacement with inclusion probabilities
    ``π_i ∝ q_i`` (``Σ π_i = count``, at most 1), and those ``π_i``.

    Indices whose share ``count · q_i / Σq`` reaches 1 are kept with ``π_i = 1`` (repeatedly,
    over what remains); the others by systematic sampling (Madow 1949) at the points
    ``(j + ξ)``, ``j = 0 … n−1`` of their cumulated ``π``: each index at most once, with
    probability ``π_i`` over ``ξ ~ U[0, 1)``, so ``Σ_picked f_i / π_i`` is an unbiased
    (Horvitz–Thompson) estimate of ``Σ_i f_i`` over every ``i`` with ``q_i > 0``.
    Fewer than ``count`` indices when fewer have ``q_i > 0``."""
    q = np.where(np.isfinite(q) & (q > 0.0), q, 0.0).astype(np.float64)
    positive = q > 0.0
    if int(positive.sum()) <= count:
        idx = np.flatnonzero(positive)
        return idx, np.ones(idx.size)
    sure = np.zeros(q.size, bool)
    while True:
        rest = positive & ~sure
        n = count - int(sure.sum())
        pi = np.where(rest, q * (n / q[rest].sum()), 0.0)
        big = pi >= 1.0
        if not big.any():
            break
        sure |= big
    cum = np.cumsum(pi)
    u = np.arange(n) + float(xi)
    picked = np.searchsorted(cum, u, side="right")
    picked = picked[picked < q.size]
    idx = np.concatenate([np.flatnonzero(sure), picked])
    return idx, np.concatenate([np.ones(int(sure.sum())), pi[picked]])


def frame_aims(data: DIRData, gb: GBuffer, options: Options) -> list[Aim]:
    """The frame's aims: the sphere of the G-buffer's visible points (``aim_view``) and the
    virtual objects' bounding sphere × :data:`OBJECT_PAD` (``aim_object``)."""
    aims = []
    p = np.array(gb.position, np.float64).reshape(3, -1)[:, np.array(gb.valid, bool)]
    if p.size and options.aim_view > 0.0:
        lo, hi = p.min(axis=1), p.max(axis=1)
        aims.append(Aim((lo + hi) / 2.0, float(np.linalg.norm(hi - lo)) / 2.0 + 1e-3,
                        options.aim_view))
    box = virtual_bounds(data.world, data.views.mixed)
    if box is not None and options.aim_object > 0.0:
        lo, hi = box
        aims.append(Aim((lo + hi) / 2.0, OBJECT_PAD * float(np.linalg.norm(hi - lo)) / 2.0,
                        options.aim_object))
    return aims


def map_sides(lights: LightSet, total: int, bounds: tuple[np.ndarray, float]) -> list[int]:
    """Side ``s`` of each light's own RSM: ``s² ≈ total × power share`` (directional lights:
    the power through the scene's disk), at least 4."""
    radius = bounds[1]
    powers = []
    for lt in lights.lights:
        if lt.kind == "directional":
            y = float(np.asarray(lt.intensity) @ LUMINANCE)
            powers.append(y * math.pi * radius * radius)
        else:
            powers.append(lt.power)
    tot = sum(powers) or 1.0
    return [max(4, int(math.floor(math.sqrt(total * p / tot) + 1e-9))) for p in powers]


def make_vpls(data: DIRData, total: int, res: int = 64, aims: list[Aim] | None = None,
              importance: float = 0.0, xi: float = 0.5) -> VPLs:
    """``total`` VPLs picked by importance (:func:`pick_by_importance`) among the texels of
    every light's aimed RSM pair (``res²`` texels shared by power, :func:`map_sides`, plus
    ``aims``), flux ``Φ_i / π_i`` (W)."""
    aims = list(aims or [])
    sides = map_sides(data.lights, res * res, data.bounds)
    rays = concat_rays([light_rays(lt, s, data.bounds, aims)
                        for lt, s in zip(data.lights.lights, sides, strict=True)])
    pair = render_rsm_pair(data.views, rays)
    rho = pair.rho
    y = np.asarray(LUMINANCE, np.float64)
    q = y @ np.array(rho.flux_out, np.float64).reshape(3, -1)
    changed = np.array(pair.changed, np.int64)  # R_µ differs from R_ρ on these texels only
    if changed.size:
        q[changed] = np.maximum(q[changed], y @ np.array(pair.mu_changed.flux_out,
                                                         np.float64).reshape(3, -1))
    role = np.array(rho.role)
    box = virtual_bounds(data.world, data.views.mixed)
    if importance > 0.0 and box is not None:
        lo, hi = box
        c, r = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
        pos = np.array(rho.position, np.float64).reshape(3, -1).T
        out = np.maximum(np.linalg.norm(pos - c, axis=1) - r, 0.0) / r
        q = q * (1.0 + importance / (1.0 + out * out))
    idx, pi = pick_by_importance(q, total, xi)
    w = mi.Float(aligned(1.0 / pi, np.float32))
    rho_v = rsm_subset(rho, mi.UInt32(aligned(idx, np.uint32)))
    # R_µ of the picked texels: R_ρ's, with those that changed taken from pair.mu_changed
    slot = np.full(role.size, -1, np.int64)
    slot[changed] = np.arange(changed.size)
    moved = slot[idx] >= 0
    mu_v = replace_texels(rho_v, mi.UInt32(aligned(np.flatnonzero(moved), np.uint32)),
                          rsm_subset(pair.mu_changed,
                                     mi.UInt32(aligned(slot[idx[moved]], np.uint32))))
    # new RSMs: mu_v is rho_v itself when no picked texel changed
    rho_v = dataclasses.replace(rho_v, flux_out=rho_v.flux_out * w)
    mu_v = dataclasses.replace(mu_v, flux_out=mu_v.flux_out * w)
    shared = shared_texels(rho_v, mu_v)
    dr.eval(shared, rho_v.flux_out, mu_v.flux_out)
    on_object = int(np.count_nonzero(role[idx] == ROLE_VIRTUAL))
    return VPLs(rho_v, mu_v, shared, int(idx.size), on_object)


def frame_vpls(data: DIRData, gb: GBuffer, options: Options, seed: int) -> VPLs:
    """The VPLs of one frame: :func:`make_vpls` with the options' map size, the frame's
    aims (:func:`frame_aims`) and ``ξ`` from the seed (golden-ratio sequence)."""
    xi = (0.5 + 0.6180339887498949 * int(seed)) % 1.0
    return make_vpls(data, options.vpls, options.rsm_size, frame_aims(data, gb, options),
                     options.vpl_importance, xi)


def _vpl(r: RSM, idx: mi.UInt32, active: mi.Bool):
    p = dr.gather(mi.Point3f, r.position, idx, active)
    n = dr.gather(mi.Vector3f, r.normal, idx, active)
    phi = dr.gather(mi.Color3f, r.flux_out, idx, active)
    ok = dr.gather(mi.Bool, r.valid, idx, active)
    return p, n, phi, ok


def _contribution(x: mi.Point3f, nx: mi.Vector3f, vp: mi.Point3f, vn: mi.Vector3f,
                  phi: mi.Color3f, bound: float):
    """``Φ/π · G_b`` (irradiance at x, W/m², before visibility) and the shadow ray."""
    to = vp - x
    d2 = dr.squared_norm(to)
    d = dr.sqrt(d2)
    w = to / dr.maximum(d, 1e-12)
    g = dr.maximum(dr.dot(nx, w), 0.0) * dr.maximum(-dr.dot(vn, w), 0.0) / dr.maximum(d2, 1e-20)
    g = dr.minimum(g, bound)
    origin = x + nx * SHADOW_EPS
    ray = mi.Ray3f(origin, w)
    ray.maxt = dr.maximum(d - 2.0 * SHADOW_EPS, 0.0)
    return phi * (g * (1.0 / math.pi)), ray, g > 0.0


def gather(data: DIRData, gb: GBuffer, vpls: VPLs, k: int, bound: float,
           objects: bool = True) -> tuple[mi.Color3f, mi.Color3f, int]:
    """Per-lane indirect irradiance ``(mixed, delta)`` from the VPLs (interleaved by ``k``)
    and the number of shadow rays traced. ``objects`` False: the virtual lanes gather
    nothing (their indirect light comes from the bounce probe,
    :mod:`arlight.realtime.object_shading`; ``mixed`` is then 0 there)."""
    virt = gb.virtual
    real = gb.valid & ~virt
    x, nx = gb.position, gb.normal
    col = gb.pixel % gb.width
    row = gb.pixel // gb.width
    # lane p·spp + s gathers the s-th of every spp-th VPL of pixel p's subset: each VPL is
    # gathered by one sample of one pixel in every k × k block, whatever gbuffer_spp is
    spp = max(gb.spp, 1)
    sample = dr.arange(mi.UInt32, dr.width(gb.pixel)) % spp if spp > 1 else mi.UInt32(0)
    subsets = k * k
    group = (col % k) + k * (row % k) + subsets * sample
    stride = subsets * spp
    per = int(math.ceil(vpls.count / stride))
    weight = float(stride)
    e_mix = mi.Color3f(0.0)
    e_delta = mi.Color3f(0.0)
    rays = 0
    for i in range(per):
        idx = group + stride * i
        have = gb.valid & (idx < vpls.count)
        idx = dr.select(have, idx, 0)
        shared = dr.gather(mi.Bool, vpls.shared, idx, have)
        p, n, phi, ok = _vpl(vpls.rho, idx, have)
        c_r, ray_r, front_r = _contribution(x, nx, p, n, phi, bound)
        act_r = have & ok & front_r
        if not objects:  # the object lanes take their indirect light from the probe
            act_r &= ~virt
        vis_r = act_r & ~data.views.mixed.scene.ray_test(ray_r, act_r)
        rays += int(dr.count(act_r)[0]) if dr.width(act_r) else 0
        e_r = dr.select(vis_r, c_r, mi.Color3f(0.0))
        e_mix += e_r
        # the real solution: the same VPL where the texel is shared (its ray is needed only
        # where the mixed ray was blocked), else R_µ's VPL
        pm, nm, phim, okm = _vpl(vpls.mu, idx, have & ~shared)
        pm = dr.select(shared, p, pm)
        nm = dr.select(shared, n, nm)
        phim = dr.select(shared, phi, phim)
        okm = dr.select(shared, ok, okm)
        c_m, ray_m, front_m = _contribution(x, nx, pm, nm, phim, bound)
        act_m = real & have & okm & front_m & ~(shared & vis_r)
        vis_m = act_m & ~data.views.real.scene.ray_test(ray_m, act_m)
        vis_m |= real & shared & vis_r
        rays += int(dr.count(act_m)[0]) if dr.width(act_m) else 0
        e_m = dr.select(vis_m, c_m, mi.Color3f(0.0))
        e_delta += dr.select(real, e_r - e_m, mi.Color3f(0.0))
        dr.eval(e_mix, e_delta)
    return e_mix * weight, e_delta * weight, rays


def _filter_pass(gb: GBuffer, values: list, k: int, axis: int) -> list:
    """One 1-D pass of :func:`interleave_filter` along ``axis`` (0: rows, 1: columns)."""
    w, h = gb.width, gb.height
    col = mi.Int32(gb.pixel % w)
    row = mi.Int32(gb.pixel // w)
    sample = dr.arange(mi.UInt32, dr.width(gb.pixel)) % gb.spp if gb.spp > 1 else None
    lo = -(k // 2)
    acc = [mi.Color3f(0.0) for _ in values]
    wsum = mi.Float(0.0)
    for off in range(lo, lo + k):
        cx, cy = (col + off, row) if axis == 0 else (col, row + off)
        inside = (cx >= 0) & (cy >= 0) & (cx < w) & (cy < h)
        j = mi.UInt32(dr.select(inside, cx + w * cy, 0))
        if sample is not None:  # lane p·spp + k: the same sample k of the neighbour pixel
            j = j * gb.spp + sample
        dj = dr.gather(mi.Float, gb.depth, j, inside)
        nj = dr.gather(mi.Vector3f, gb.normal, j, inside)
        rj = dr.gather(mi.Int32, gb.role, j, inside)
        ok = inside & (rj == gb.role) & dr.isfinite(dj) & (
            dr.abs(dj - gb.depth) <= 0.05 * gb.depth) & (dr.dot(nj, gb.normal) > 0.8)
        wt = dr.select(ok, 1.0, 0.0)
        wsum += wt
        for a, v in enumerate(values):
            acc[a] += dr.gather(mi.Color3f, v, j, ok) * wt
    out = [dr.select(wsum > 0, a / dr.maximum(wsum, 1.0), v) for a, v in zip(acc, values,
                                                                               strict=True)]
    dr.eval(out)
    return out


def interleave_filter(gb: GBuffer, values: list, k: int) -> list:
    """``k × k`` geometry-aware box filter over the pixel grid (Dr.Jit; with several G-buffer
    samples per pixel, over the same sample of each pixel), applied separably: a ``k``-tap
    pass along rows, then one along columns. In each pass, neighbours of the same role whose
    depth is within 5 % and whose normal is within 37° (cos > 0.8) of the pixel's are
    averaged; ``values`` are per-lane ``mi.Color3f``. Every ``k × k`` window holds each of
    the ``k²`` VPL subsets once (Segovia et al. 2006): the row pass mixes the ``k`` subsets
    of ``x mod k``, the column pass those of ``y mod k``. On continuous surfaces this equals
    the 2-D box filter; at geometric edges the column pass weighs the row averages by the
    centre pixels only (the usual separable approximation of a cross-bilateral filter), for
    ``2k`` instead of ``k²`` taps."""
    if k == 1:
        return values
    return _filter_pass(gb, _filter_pass(gb, values, k, 0), k, 1)


class DIRMethod(BaseMethod):
    """Differential instant radiosity (Knecht et al. 2010)."""

    spec = SPEC

    incremental_pose = True

    def prepare_world(self, world: World, options: Options, settings: RenderSettings
                      ) -> DIRData:
        views = build_views(world)
        lights = reduce_lights(world, env_lights=options.env_lights,
                               area_grid=options.area_grid)
        return DIRData(world, views, lights, scene_bounds(views.mixed),
                       prepare_ambient(world, views.mixed, options),
                       prepare_object_light(world, views, options))

    def move(self, data: DIRData, world: World, transforms: dict[str, np.ndarray],
             options: Options) -> DIRData | None:
        """The shapes moved in place (the lights do not depend on them), the bounds
        measured again, the ambient occluder and its field posed
        (:func:`~arlight.realtime.ambient.pose_ambient`); nothing else is kept between
        frames."""
        before = data.world
        posed = place_views(data.views, world, transforms, real_moves=True)
        if posed is None:
            return None
        amb = pose_ambient(data.ambient, before, posed, data.views.mixed, options)
        if amb is None:
            return None
        return DIRData(posed, data.views, data.lights, scene_bounds(data.views.mixed), amb,
                       pose_object_light(data.objects, posed, data.views, options))

    def relit(self, data: DIRData, world: World, options: Options) -> DIRData | None:
        """Light update (issue #32, :meth:`BaseMethod.relight`): the views' emitters set in
        place, the lights reduced again, the bounds measured again (an area lamp is geometry
        of the views); the VPLs are made per frame anyway."""
        from dataclasses import replace

        from arlight.methods.base import relight_views

        if not relight_views(data.views, data.world.lights, world.lights):
            return None
        return replace(data, world=world, bounds=scene_bounds(data.views.mixed),
                       lights=reduce_lights(world, env_lights=options.env_lights,
                                            area_grid=options.area_grid),
                       objects=prepare_object_light(world, data.views, options))

    def render_view(self, data: DIRData, view: FrameView, options: Options,
                    settings: RenderSettings, timer: StageTimer) -> Layers:
        with timer.stage("gbuffer"):
            gb = render_gbuffer(data.views.mixed, view.camera, options.gbuffer_spp,
                                settings.seed)
        virt = gb.virtual
        real = gb.valid & ~virt
        with timer.stage("direct"):
            # the real lanes' direct change: shadow rays in the mixed scene, in the real one
            # where those are blocked (soft for extended lights with shadow_samples > 1);
            # none without virtual objects (the two views' BVHs may round a grazing ray apart)
            # (and through the same rays the real scene's direct irradiance, E_r's for ρ̂)
            # (the mixed scene's rays only where they can meet the objects; exact)
            terms = direct_terms_gbuffer(data.views, data.lights, gb, real,
                                         options.shadow_samples, data.world) \
                if data.world.has_virtual else None
            e_dd = terms.change if terms is not None else mi.Color3f(0.0)
            dr.eval(e_dd, terms.real if terms is not None else e_dd)
        rays = 0
        with timer.stage("rsm"):
            vpls = frame_vpls(data, gb, options, settings.seed) \
                if data.world.has_virtual and data.lights.lights else None
        with timer.stage("gather"):
            if vpls is not None:
                bound = 1.0 / options.clamp_distance ** 2 if options.clamp_distance > 0 \
                    else float("inf")
                e_im, e_id, rays = gather(data, gb, vpls, options.interleave, bound,
                                          objects=not data.objects.probe)
        with timer.stage("filter"):
            if vpls is not None:
                e_im, e_id = interleave_filter(gb, [e_im, e_id], options.interleave)
            else:
                e_im = e_id = mi.Color3f(0.0)
        with timer.stage("assemble"):
            # the SH ambient remainder's part blocked by the virtual objects on real lanes
            # (issue #33, arlight.realtime.ambient)
            e_loss = real_ambient_loss(data.ambient, data.lights, gb.position, gb.normal,
                                       real)
            # ρ̂ from the photograph under E_r with the real solution's indirect light: on
            # real lanes e_im − e_id is R_µ's gather (arlight.realtime.real_lane)
            rho_real = real_albedo(options.real_albedo, data.views, data.lights, view.frame,
                                   gb, real, e_im - e_id,
                                   terms.real if terms is not None else None) * (1.0 / math.pi)
            delta = dr.select(real, rho_real * (e_dd + e_id - e_loss),
                              mi.Color3f(0.0))
            # the objects' own shading (arlight.realtime.object_shading), with the VPLs'
            # indirect irradiance only without the bounce probe
            e_ind = e_im
            mixed = shade_objects(data.objects, data.world, data.views, data.lights,
                                  data.ambient, gb,
                                  None if vpls is None or data.objects.probe else
                                  lambda idx, p, n: dr.gather(mi.Color3f, e_ind, idx),
                                  options.ao_rays, settings.seed)
            layers = assemble(gb, view.frame, mixed, delta,
                              {"vpls": float(vpls.count if vpls else 0),
                               "vpls_on_object": float(vpls.on_object if vpls else 0),
                               "shadow_rays": float(rays)})
        if not data.world.has_virtual:
            assert not np.any(layers.delta), "dir: delta must vanish without virtual objects"
        return layers


__all__ = ["DIRData", "DIRMethod", "OPTIONS", "SPEC", "gather", "interleave_filter",
           "frame_aims", "frame_vpls", "make_vpls", "map_sides", "pick_by_importance"]
