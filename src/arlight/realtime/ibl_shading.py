"""Image-based shading of virtual objects: the *dynamic pipeline* of Franke thesis §4.2.

* :func:`environment_map` — the world's distant light (``envmap``, ``sh``, ``constant``
  lights, with their ``scale`` and ``rotation_deg``) as one equirect radiance map.
* :class:`MipEnvironment` — that map as a mip chain (2×2 box filter per level, the
  hardware mip generation the thesis uses) in one flat Dr.Jit array, looked up bilinearly
  per level and linearly between levels.
* **split-sum GGX specular** (Karis 2013; issue #33): :func:`prefilter_ggx` — the map
  prefiltered with the GGX lobe per roughness level (half vectors by inverting the GGX CDF,
  thesis Eqs. 4.20–4.21, each sample fetched from the box mip level of its solid angle,
  Eq. 4.23 — filtered importance sampling at prepare instead of per pixel); :func:`dfg_table`
  / :func:`dfg_lookup` — the Fresnel-scaled GGX albedo ``F0 A + F90 B``;
  :func:`specular_split_sum` — their product towards the dominant direction;
  :func:`specular_occlusion` — Lagarde's AO-derived cone occlusion; :func:`schlick`,
  :func:`ggx_reflectance` — the BRDF itself for local lights.
* :func:`specular_tables` — per world shape the GGX ``α`` and Schlick ``F0``/``F90`` of its
  material (``phong``: ``α = √(2/(n+2))``; ``roughconductor``; ``mirror`` as
  :data:`MIRROR_ALPHA`; ``pbr`` by :func:`pbr_lobes`), the tables the split sum, the local
  lights' GGX and the SoG lobes look up; :func:`diffuse_weights` the factor on the G-buffer
  albedo (``pbr``: ``(1 − metallic)(1 − transmission)``).
* :func:`bounce_probe` — the change the real scene makes to the distant light at the virtual
  objects (path traced from their centre), for the ambient SH of ``ibl`` and ``prt``.
* :func:`ggx_d`, :func:`smith_g1` — the GGX normal distribution and Smith masking (the one
  copy; ``dvct``'s direct GGX specular uses them too).
* :func:`ambient_occlusion` — ray-traced ambient occlusion of the virtual object (thesis
  Eq. 2.29, ``A = (1/π) ∫ V <n,ω>+ dω``, cosine-weighted rays against the virtual shapes;
  the thesis uses SSAO, a screen-space estimate of the same integral).
* :func:`hammersley` — the 2-D low-discrepancy pattern both use.

Units: radiance W/(sr·m²), angles radians, lengths metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.mitsuba_scene import SceneView
from arlight.jit import FREEZE_LOCK, aligned, opaques
from arlight.realtime.gbuffer import GBuffer
from arlight.scene.model import World
from arlight.scene.schema import Field
from arlight.sphere.envmap import resize_equirect, rotate_equirect

ENV_HEIGHT = 128
"""Rows of the equirect map the mip chain starts from (width twice that)."""

MIRROR_ALPHA = 1e-3
"""GGX roughness standing in for a perfect mirror."""


def rot_y(deg: float) -> np.ndarray:
    """Rotation about +Y by ``deg`` degrees (Mitsuba's ``rotate`` and the envmap's
    ``rotation_deg``; :mod:`arlight.realtime.light_reduction` uses the same matrix)."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def environment_map(world: World, height: int = ENV_HEIGHT) -> np.ndarray | None:
    """Sum of the world's distant lights as an equirect radiance map ``(height, 2·height,
    3)`` float32 (None when it has none). Rotations follow Mitsuba's envmap ``to_world``
    (about +Y by ``rotation_deg``), as :func:`arlight.realtime.light_reduction.reduce_lights`
    does."""
    out = None
    for lt in world.lights:
        if lt.type in ("envmap", "sh"):
            img = resize_equirect(np.asarray(lt.radiance_map, np.float32)[..., :3], height)
            img = img * float(lt.params.get("scale", 1.0))
            rot = float(lt.params.get("rotation_deg", 0.0))
            if rot:
                img = rotate_equirect(img, rot_y(rot))
        elif lt.type == "constant":
            img = np.broadcast_to(np.asarray(lt.params["radiance"], np.float32),
                                  (height, 2 * height, 3))
        else:
            continue
        out = img.astype(np.float32) if out is None else out + img
    return out


@dataclass
class MipEnvironment:
    """Mip chain of an equirect map in one flat RGB array (level ``k``: ``h_k × 2h_k``
    texels from ``offset[k]``).

    Attributes:
        data: all levels, texel-major RGB (``Color3f``-gatherable).
        offset, height: per-level first texel and rows (Dr.Jit tables).
        levels: number of levels (the last has one row).
        base_height: rows of level 0.
    """

    data: mi.Float
    offset: mi.UInt32
    height: mi.UInt32
    levels: int
    base_height: int

    @classmethod
    def build(cls, image: np.ndarray) -> MipEnvironment:
        """Mip chain of ``image`` ``(H, 2H, 3)`` by 2×2 box averaging (H a power of two is
        not required: odd rows/columns are dropped at each level)."""
        lvl = np.asarray(image, np.float32)[..., :3]
        levels = [lvl]
        while lvl.shape[0] >= 2:
            h, w = lvl.shape[0] // 2, lvl.shape[1] // 2
            lvl = lvl[:2 * h, :2 * w].reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
            levels.append(lvl)
        return cls.from_levels(levels)

    @classmethod
    def from_levels(cls, levels: list[np.ndarray]) -> MipEnvironment:
        """The flat table of equirect maps ``(h_k, 2h_k, 3)``, level ``k`` = ``levels[k]``
        (any heights: a box mip chain or :func:`prefilter_ggx`'s roughness levels)."""
        imgs = [np.asarray(x, np.float32)[..., :3] for x in levels]
        hs = [x.shape[0] for x in imgs]
        offs = np.concatenate([[0], np.cumsum([x.shape[0] * x.shape[1] for x in imgs])[:-1]])
        return cls(mi.Float(np.concatenate([x.reshape(-1) for x in imgs])),
                   mi.UInt32(offs.astype(np.uint32)), mi.UInt32(np.array(hs, np.uint32)),
                   len(imgs), hs[0])

    def _bilinear(self, u: mi.Float, v: mi.Float, level: mi.UInt32) -> mi.Color3f:
        h = dr.gather(mi.UInt32, self.height, level)
        off = dr.gather(mi.UInt32, self.offset, level)
        hf = mi.Float(h)
        wf = 2.0 * hf
        x = u * wf - 0.5
        y = v * hf - 0.5
        x0 = dr.floor(x)
        y0 = dr.floor(y)
        fx = x - x0
        fy = y - y0
        w = 2 * h
        # wrap in longitude in floating point: an integer modulo by a per-lane divisor
        # raises SIGFPE in Dr.Jit's LLVM backend (the vector's padding lanes divide by 0)
        xi0 = mi.UInt32(dr.clip(x0 - wf * dr.floor(x0 / wf), 0.0, wf - 1.0))
        xi1 = dr.select(xi0 + 1 >= w, 0, xi0 + 1)
        yi0 = mi.UInt32(dr.clip(mi.Int32(y0), 0, mi.Int32(h) - 1))
        yi1 = mi.UInt32(dr.clip(mi.Int32(y0) + 1, 0, mi.Int32(h) - 1))

        def tex(xi: mi.UInt32, yi: mi.UInt32) -> mi.Color3f:
            return dr.gather(mi.Color3f, self.data, off + yi * w + xi)

        top = tex(xi0, yi0) * (1.0 - fx) + tex(xi1, yi0) * fx
        bottom = tex(xi0, yi1) * (1.0 - fx) + tex(xi1, yi1) * fx
        return top * (1.0 - fy) + bottom * fy

    def lookup(self, d: mi.Vector3f, level: mi.Float) -> mi.Color3f:
        """Radiance towards unit directions ``d`` at fractional mip ``level`` (trilinear)."""
        u = dr.atan2(d.x, -d.z) * (0.5 / math.pi)
        u = u - dr.floor(u)
        v = dr.acos(dr.clip(d.y, -1.0, 1.0)) * (1.0 / math.pi)
        lv = dr.clip(level, 0.0, float(self.levels - 1))
        l0 = dr.floor(lv)
        t = lv - l0
        i0 = mi.UInt32(l0)
        i1 = dr.minimum(i0 + 1, self.levels - 1)
        return self._bilinear(u, v, i0) * (1.0 - t) + self._bilinear(u, v, i1) * t


PROBE_HEIGHT = 16
"""Rows of the bounce probe (:func:`bounce_probe`; width twice that)."""

PROBE_RECORDINGS = 8
"""Frozen recordings of the probe's path tracing kept (scene generations × spp × depth)."""


PROBE_OPTIONS: dict[str, Field] = {
    "probe": Field("bool", True, "light probe at the virtual objects from the reconstructed "
                   "real scene (bounce light, hidden sky; bounce_probe)"),
    "probe_spp": Field("int", 16, "path-traced rays per texel of the 16×32 probe", "",
                       min=1, max=1024),
    "probe_follow": Field("bool", True, "trace the probe again at every pose of the objects "
                          "(off: the probe of the pose the state was prepared in is kept — "
                          "an approximation the studio's drag frames use)"),
}
"""The options of :func:`probe_for_world`, shared by ``ibl`` and ``prt``."""


def probe_drag_options(options, factor: int) -> dict[str, bool]:
    """Options of a studio frame at 1/``factor`` of the size while dragging (issue #32;
    ``MethodSpec.drag_options`` of ``ibl`` and ``prt``): the bounce probe is not traced
    again at each pose (``probe_follow`` off) — its cost does not shrink with the image
    (a replay of its frozen recording: ~15 ms on 2 busy cores; ~0.1 s of Python tracing
    before it was frozen); the frame at rest traces it."""
    return {"probe_follow": False}


def probe_for_world(world: World, views, env: np.ndarray | None, options,
                    env_lights: int = 0) -> BounceProbe | None:
    """:func:`bounce_probe` at the centre of the virtual objects' bounding box in the real
    view, with the threshold of the light extraction when ``env_lights`` > 0 (None when
    ``options.probe`` is off or nothing is virtual)."""
    from arlight.light.extract import auto_threshold
    from arlight.realtime.shading import virtual_bounds

    if not options.probe or not world.has_virtual:
        return None
    b = virtual_bounds(world, views.mixed)
    if b is None:
        return None
    thr = auto_threshold(env, 4.0) if env is not None and env_lights > 0 else math.inf
    return bounce_probe(views.real, (b[0] + b[1]) / 2.0, env, thr,
                        spp=options.probe_spp)


@dataclass
class BounceProbe:
    """What the real scene changes of the distant light seen from the virtual objects
    (:func:`bounce_probe`), two equirect maps ``(h, 2h, 3)`` W/(sr·m²), ≥ −env:

    Attributes:
        full: ``blocked · (L_real − L_env)`` — added to ``prt``'s SH light (no light is
            extracted there).
        diffuse: the same with ``L_env`` counted only below the highlight threshold of the
            light extraction (a blocked extracted light is already removed by its shadow
            ray), added to ``ibl``'s SH remainder.
    """

    full: np.ndarray
    diffuse: np.ndarray


def bounce_probe(view: SceneView | mi.Scene, centre: np.ndarray, env: np.ndarray | None,
                 threshold: float = math.inf, height: int = PROBE_HEIGHT, spp: int = 16,
                 max_depth: int = 6, seed: int = 0) -> BounceProbe:
    """A light probe at ``centre`` (m) in the real-only scene, as a change to the distant
    light: per direction ``ω`` whose ray from ``centre`` hits a real surface, the radiance
    ``L_real(ω)`` that surface sends (path traced by Mitsuba's ``path`` integrator,
    ``max_depth`` bounces, its own emission removed: the local lights are shaded per pixel
    with shadow rays) minus the environment's ``L_env(ω)`` that the surface hides; 0 for
    rays that escape. ``spp`` jittered rays per texel of a ``height × 2·height`` map (the
    direction convention of :meth:`MipEnvironment.lookup`). This is the environment capture
    at the object's position of Franke's dynamic pipeline (§4.2, the camera-captured map),
    taken from the reconstructed real scene: indoors, the walls' and floor's bounce light
    that a world without an environment map would lack; outdoors, the lit ground instead of
    the map's own horizon. Computed at prepare and again for each pose of the object (the
    diffuse SH only: the specular prefilter is of the environment map alone).

    ``view`` is the real view (:class:`~arlight.backend.mitsuba_scene.SceneView`): the path
    tracing is then a frozen Dr.Jit function (:func:`_probe_radiance`, ``dr.freeze``)
    recorded once per view :attr:`~arlight.backend.mitsuba_scene.SceneView.generation` and
    replayed for every other centre — ~0.1 s of Python tracing of Mitsuba's integrator
    becomes a few ms, bitwise the same probe (tests/methods/test_bounce_probe.py). A bare
    ``mi.Scene`` (and a scene without shapes or without lights, which Dr.Jit cannot record:
    no instance of the called classes among the inputs) is traced anew at each call, and so
    is every probe while Dr.Jit's virtual calls are evaluated (``JitFlag.SymbolicCalls``
    off: a frozen function cannot record them)."""
    w = 2 * height
    n = height * w * spp
    # the centre opaque: one kernel for every pose of the object (the probe follows it)
    origin = mi.Point3f(*opaques(centre))
    args = (origin, n, spp, w, height, int(max_depth), int(seed))
    scene = view if isinstance(view, mi.Scene) else view.scene
    # frozen where the scene holds the instances of every class the tracing calls into:
    # Dr.Jit finds the members of called objects through the inputs (a scene without
    # shapes or lights cannot be recorded; its probe is traced as it is), and only with
    # symbolic virtual calls: with evaluated ones (the studio's drag frames) the recording
    # fails on the calls' evaluated members ("created before recording was started")
    if isinstance(view, mi.Scene) or not (scene.shapes() and scene.emitters()) or \
            not dr.flag(dr.JitFlag.SymbolicCalls):
        radiance, hit, d = _probe_radiance(scene, *args)
    else:
        with FREEZE_LOCK:  # the studio prepares and renders on several threads
            radiance, hit, d = _frozen_probe_radiance(scene, *args, view.generation)
    if env is not None:
        l_env = MipEnvironment.build(env).lookup(d, mi.Float(0.0))
        lum = 0.2126 * l_env.x + 0.7152 * l_env.y + 0.0722 * l_env.z
        l_dim = dr.select(lum < threshold, l_env, mi.Color3f(0.0))
    else:
        l_env = l_dim = mi.Color3f(0.0)
    maps = []
    for sub in (l_env, l_dim):
        c = dr.select(hit, radiance - sub, mi.Color3f(0.0))
        rgb = np.stack([np.asarray(dr.block_sum(x, spp), np.float64) for x in (c.x, c.y, c.z)],
                       -1) / spp
        maps.append(rgb.reshape(height, w, 3).astype(np.float32))
    return BounceProbe(maps[0], maps[1])


def _probe_radiance(scene: mi.Scene, origin: mi.Point3f, n: int, spp: int, w: int,
                    height: int, max_depth: int, seed: int, generation: int = 0
                    ) -> tuple[mi.Color3f, mi.Bool, mi.Vector3f]:
    """The path tracing of :func:`bounce_probe`: ``n = height · w · spp`` rays from
    ``origin``, ``spp`` per texel of the ``height × w`` equirect map (jittered by Mitsuba's
    ``independent`` sampler seeded with ``seed``); per ray ``L_real`` of the surface hit
    (W/(sr·m²), its own emission removed), whether it hit, and its direction. ``generation``
    is unused here: it keys the frozen recordings (:data:`_frozen_probe_radiance`)."""
    lane = dr.arange(mi.UInt32, n)
    tex = lane // spp
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    jitter = sampler.next_2d()
    phi = (mi.Float(tex % w) + jitter.x) * (2.0 * math.pi / w)
    theta = (mi.Float(tex // w) + jitter.y) * (math.pi / height)
    st = dr.sin(theta)
    d = mi.Vector3f(st * dr.sin(phi), dr.cos(theta), -st * dr.cos(phi))
    ray = mi.Ray3f(origin, d)
    si = scene.ray_intersect(ray)
    hit = si.is_valid()
    integrator = _path_integrator(max_depth)
    radiance, _, _ = integrator.sample(scene, sampler, mi.RayDifferential3f(ray), None, hit)
    emitter = si.emitter(scene, hit)
    radiance -= dr.select(hit & (dr.reinterpret_array(mi.UInt32, emitter) != 0),
                          emitter.eval(si, hit), mi.Color3f(0.0))
    return radiance, hit, d


_frozen_probe_radiance = dr.freeze(_probe_radiance, limit=PROBE_RECORDINGS,
                                   warn_after=1_000_000)
""":func:`_probe_radiance` frozen (``dr.freeze``): a call with the same scene generation
and sizes replays the recorded kernels (the scene's Dr.Jit members and the origin are its
inputs, traversed at each call); another generation, spp or depth records anew. The
generation is in the key although Dr.Jit's traversal saw every in-place change tried
(lamps moved and recoloured by ``relight``, environment data of another size; the stale
replay once seen was the relit probe bug fixed in 0ab400c): scalar plugin members compiled
into the kernels as literals would not be seen. At most :data:`PROBE_RECORDINGS` kept
(least recently used dropped); no warning for the re-recordings that generations cause."""


@lru_cache(maxsize=4)
def _path_integrator(max_depth: int) -> mi.SamplingIntegrator:
    """Mitsuba's ``path`` integrator (one per depth, loaded once)."""
    return mi.load_dict({"type": "path", "max_depth": max_depth})


def hammersley(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n``-point Hammersley set ``((i + ½)/n, radical inverse base 2 of i)``."""
    i = np.arange(n, dtype=np.uint64)
    bits = np.zeros(n, np.float64)
    x = i.copy()
    scale = 0.5
    while np.any(x):
        bits += (x & 1).astype(np.float64) * scale
        x >>= np.uint64(1)
        scale *= 0.5
    return (np.arange(n) + 0.5) / n, bits


def local_frame(n: mi.Vector3f) -> tuple[mi.Vector3f, mi.Vector3f]:
    """Two unit tangents completing ``n`` (Frisvad / Duff et al. branchless ONB)."""
    f = mi.Frame3f(n)
    return f.s, f.t


def ggx_d(alpha: mi.Float, cos_h: mi.Float) -> mi.Float:
    """GGX / Trowbridge–Reitz NDF (thesis Eq. 4.11): ``α² / (π (cos²θ (α² − 1) + 1)²)``."""
    a2 = alpha * alpha
    k = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * k * k)


def smith_g1(alpha: mi.Float, cos_t: mi.Float) -> mi.Float:
    """Smith's GGX masking ``2 cosθ / (cosθ + √(α² + (1 − α²) cos²θ))``."""
    a2 = alpha * alpha
    c = dr.maximum(cos_t, 1e-6)
    return 2.0 * c / (c + dr.sqrt(a2 + (1.0 - a2) * c * c))


PREFILTER_LEVELS = 6
"""Roughness levels of the prefiltered environment: level ``k`` holds the GGX lobe of
perceptual roughness ``r_k = k/(L − 1)`` (``α = r²``; level 0 is the map itself, the mirror),
looked up at the fractional level ``√α (L − 1)`` (Karis 2013)."""
PREFILTER_MIN_HEIGHT = 16
"""Rows of the coarsest prefiltered level (level ``k`` has ``max(16, H >> k)`` rows)."""
DFG_SIZE = 32
"""Resolution of the DFG table per axis (``<n,v>`` × perceptual roughness)."""
DFG_SAMPLES = 512
"""GGX importance samples per DFG texel."""

_PREFILTERED: dict[tuple[bytes, int, int], MipEnvironment] = {}


def _ggx_half_vectors(alpha: mi.Float, xi_t: mi.Float, xi_p: mi.Float, n: mi.Vector3f
                      ) -> tuple[mi.Vector3f, mi.Float]:
    """GGX-distributed half vectors about unit ``n`` by inverting the CDF of ``D <n,h>``
    (thesis Eqs. 4.20–4.21: ``φ = 2π ξ_φ``, ``cos θ = √((1 − ξ_θ)/((α² − 1) ξ_θ + 1))``) and
    their ``cos θ``."""
    a2 = alpha * alpha
    cos_h = dr.sqrt((1.0 - xi_t) / ((a2 - 1.0) * xi_t + 1.0))
    sin_h = dr.safe_sqrt(1.0 - cos_h * cos_h)
    phi = 2.0 * math.pi * xi_p
    t1, t2 = local_frame(n)
    return t1 * (sin_h * dr.cos(phi)) + t2 * (sin_h * dr.sin(phi)) + n * cos_h, cos_h


def prefilter_ggx(image: np.ndarray, samples: int = 64, levels: int = PREFILTER_LEVELS
                  ) -> MipEnvironment:
    """The equirect radiance map ``image`` ``(H, 2H, 3)`` prefiltered with the GGX lobe per
    roughness level (Karis 2013, "Real Shading in Unreal Engine 4", the first sum of the
    split-sum approximation, with ``n = v = R``):

        L̃(R, α) = Σ_s L(l_s) <R, l_s>+ / Σ_s <R, l_s>+,   l_s = 2 <R, h_s> h_s − R,

    ``h_s`` GGX half vectors (``samples`` Hammersley points, :func:`_ggx_half_vectors`);
    each ``L(l_s)`` is read from the box mip chain at the level of the sample's solid angle
    (filtered importance sampling, Colbert & Křivánek 2007 / thesis Eq. 4.23, ``+1`` level
    as Karis), so few samples give a smooth map. Level 0 is ``image`` (the mirror). Computed
    once per map and sample count (cached in memory by the map's bytes); W/(sr·m²)."""
    img = np.ascontiguousarray(np.asarray(image, np.float32)[..., :3])
    key = (img.tobytes(), int(samples), int(levels))
    if key in _PREFILTERED:
        return _PREFILTERED[key]
    src = MipEnvironment.build(img)
    h0 = img.shape[0]
    u1, u2 = hammersley(samples)
    out = [img]
    for k in range(1, levels):
        r = k / (levels - 1)
        h = max(PREFILTER_MIN_HEIGHT, h0 >> k)
        w = 2 * h
        lane = dr.arange(mi.UInt32, h * w * samples)
        tex = lane // samples
        s = lane % samples
        x = mi.Float(tex % w) + 0.5
        y = mi.Float(tex // w) + 0.5
        phi = x * (2.0 * math.pi / w)
        theta = y * (math.pi / h)
        st = dr.sin(theta)
        rr = mi.Vector3f(st * dr.sin(phi), dr.cos(theta), -st * dr.cos(phi))  # lookup()'s map
        alpha = dr.opaque(mi.Float, max(r * r, MIRROR_ALPHA))
        xi_t = dr.gather(mi.Float, mi.Float(aligned(u1, np.float32)), s)
        xi_p = dr.gather(mi.Float, mi.Float(aligned(u2, np.float32)), s)
        hv, cos_h = _ggx_half_vectors(alpha, xi_t, xi_p, rr)
        light = hv * (2.0 * dr.dot(rr, hv)) - rr
        nl = dr.dot(rr, light)
        pdf = ggx_d(alpha, cos_h) * 0.25  # D <n,h>/(4 <v,h>) with n = v
        omega_s = 1.0 / (samples * dr.maximum(pdf, 1e-12))
        sin_l = dr.safe_sqrt(1.0 - light.y * light.y)
        omega_p = (math.pi / h0) * (math.pi / h0) * dr.maximum(sin_l, 0.5 / h0)
        level = dr.maximum(0.0, 0.5 * dr.log2(omega_s / omega_p) + 1.0)
        wgt = dr.maximum(nl, 0.0)
        c = src.lookup(light, level) * wgt
        sums = [np.asarray(dr.block_sum(v, samples), np.float64)
                for v in (c.x, c.y, c.z, wgt)]
        rgb = np.stack(sums[:3], -1) / np.maximum(sums[3], 1e-12)[:, None]
        out.append(rgb.reshape(h, w, 3).astype(np.float32))
    env = MipEnvironment.from_levels(out)
    if len(_PREFILTERED) >= 8:
        _PREFILTERED.pop(next(iter(_PREFILTERED)))
    _PREFILTERED[key] = env
    return env


@lru_cache(maxsize=4)
def dfg_table(size: int = DFG_SIZE, samples: int = DFG_SAMPLES) -> np.ndarray:
    """The split-sum DFG table ``(size, size, 2)`` (Karis 2013, the second sum): at
    ``<n,v> = (i + ½)/size`` and perceptual roughness ``r = (j + ½)/size`` (``α = r²``),

        A = (1/N) Σ (1 − F_c) G V,   B = (1/N) Σ F_c G V,   G V = G1(v) G1(l) <v,h>/(<n,h> <n,v>),

    ``F_c = (1 − <v,h>)⁵``, over ``samples`` GGX half vectors, so that the directional
    albedo of the GGX BRDF with Schlick's Fresnel ``F = F0 + (F90 − F0)(1 − <v,h>)⁵`` is
    ``F0 A + F90 B`` (a constant reflectance ``k``: ``F0 = F90 = k``, ``k (A + B)``).
    Computed once per process (Dr.Jit, one kernel)."""
    u1, u2 = hammersley(samples)
    lane = dr.arange(mi.UInt32, size * size * samples)
    cell = lane // samples
    s = lane % samples
    nv = (mi.Float(cell // size) + 0.5) * (1.0 / size)
    r = (mi.Float(cell % size) + 0.5) * (1.0 / size)
    alpha = dr.maximum(r * r, MIRROR_ALPHA)
    n = mi.Vector3f(0.0, 0.0, 1.0)
    v = mi.Vector3f(dr.safe_sqrt(1.0 - nv * nv), 0.0, nv)
    xi_t = dr.gather(mi.Float, mi.Float(aligned(u1, np.float32)), s)
    xi_p = dr.gather(mi.Float, mi.Float(aligned(u2, np.float32)), s)
    h, cos_h = _ggx_half_vectors(alpha, xi_t, xi_p, n)
    vh = dr.dot(v, h)
    light = h * (2.0 * vh) - v
    ok = (light.z > 0.0) & (vh > 0.0)
    gv = smith_g1(alpha, nv) * smith_g1(alpha, light.z) * vh / (dr.maximum(cos_h, 1e-6) * nv)
    fc = dr.power(1.0 - dr.clip(vh, 0.0, 1.0), 5.0)
    a = dr.select(ok, (1.0 - fc) * gv, 0.0)
    b = dr.select(ok, fc * gv, 0.0)
    out = [np.asarray(dr.block_sum(x, samples), np.float64) / samples for x in (a, b)]
    return np.stack(out, -1).reshape(size, size, 2).astype(np.float32)


def dfg_lookup(table: mi.Float, nv: mi.Float, rough: mi.Float, size: int = DFG_SIZE
               ) -> tuple[mi.Float, mi.Float]:
    """``(A, B)`` of :func:`dfg_table` (flattened into ``table``) at ``<n,v>`` and perceptual
    roughness, bilinear between texel centres, clamped at the edges."""
    x = dr.clip(nv * size - 0.5, 0.0, size - 1.0)
    y = dr.clip(rough * size - 0.5, 0.0, size - 1.0)
    x0 = dr.minimum(dr.floor(x), size - 2.0)
    y0 = dr.minimum(dr.floor(y), size - 2.0)
    fx, fy = x - x0, y - y0
    i0 = mi.UInt32(x0) * size + mi.UInt32(y0)

    def at(i: mi.UInt32) -> mi.Vector2f:
        return mi.Vector2f(dr.gather(mi.Float, table, 2 * i), dr.gather(mi.Float, table,
                                                                        2 * i + 1))

    top = at(i0) * (1.0 - fy) + at(i0 + 1) * fy
    bot = at(i0 + size) * (1.0 - fy) + at(i0 + size + 1) * fy
    ab = top * (1.0 - fx) + bot * fx
    return ab.x, ab.y


def schlick(f0: mi.Color3f, f90: mi.Color3f, cos_d: mi.Float) -> mi.Color3f:
    """Schlick's Fresnel ``F0 + (F90 − F0)(1 − cos)⁵`` (``F90 = F0``: a constant
    reflectance, e.g. Mitsuba's ``roughconductor`` with ``material = none``)."""
    return f0 + (f90 - f0) * dr.power(1.0 - dr.clip(cos_d, 0.0, 1.0), 5.0)


def ggx_reflectance(n: mi.Vector3f, v: mi.Vector3f, light: mi.Vector3f, alpha: mi.Float,
                    f0: mi.Color3f, f90: mi.Color3f) -> mi.Color3f:
    """``f_s(l, v) <n,l>+`` (sr⁻¹) of the GGX microfacet BRDF ``F D G1(v) G1(l) / (4 <n,l>
    <n,v>)`` (Walter et al. 2007; thesis Eq. 4.11) with :func:`schlick` Fresnel, for unit
    ``n``, ``v`` (to the viewer) and ``light`` (to the light); 0 below either horizon. A
    point light of irradiance ``E⊥`` at normal incidence reflects ``ggx_reflectance · E⊥``."""
    a = dr.maximum(alpha, MIRROR_ALPHA)
    h = dr.normalize(v + light)
    nl = dr.dot(n, light)
    nv = dr.dot(n, v)
    g = smith_g1(a, nv) * smith_g1(a, nl)
    f = schlick(f0, f90, dr.dot(v, h))
    val = f * (ggx_d(a, dr.maximum(dr.dot(n, h), 0.0)) * g / (4.0 * dr.maximum(nv, 1e-4)))
    return dr.select((nl > 0.0) & (nv > 0.0), val, mi.Color3f(0.0))


def specular_split_sum(env: MipEnvironment, dfg: mi.Float, n: mi.Vector3f, v: mi.Vector3f,
                       alpha: mi.Float, f0: mi.Color3f, f90: mi.Color3f) -> mi.Color3f:
    """GGX specular radiance ``∫ f_s L <n,l>+ dω`` of the distant light by the split-sum
    approximation (Karis 2013): ``L̃(d, α) · (F0 A + F90 B)``, ``L̃`` the
    :func:`prefilter_ggx` map at level ``√α (L − 1)`` towards the dominant direction
    ``d = normalize(lerp(n, R, s))``, ``s = (1 − α)(√(1 − α) + α)`` (Lagarde & de Rousiers
    2014, Frostbite, §4.9.3, with their ``roughness`` read as ``α``: on a roughconductor
    sphere under an HDR map against Mitsuba, ``α`` gives 7.6/8.1/8.3 % mean error at
    α = 0.1/0.3/0.6, ``√α`` 13/11/5 %, no lerp 7/13/23 %; ``R`` the mirror direction) and
    ``(A, B)`` from :func:`dfg_table` at ``<n,v>``."""
    nv = dr.maximum(dr.dot(n, v), 1e-4)
    refl = n * (2.0 * nv) - v
    rough = dr.sqrt(dr.maximum(alpha, 0.0))
    s = (1.0 - alpha) * (dr.sqrt(1.0 - alpha) + alpha)
    d = dr.normalize(n + (refl - n) * s)
    a, b = dfg_lookup(dfg, nv, rough)
    return env.lookup(d, rough * float(env.levels - 1)) * (f0 * a + f90 * b)


def specular_occlusion(nv: mi.Float, ao: mi.Float, alpha: mi.Float) -> mi.Float:
    """Specular occlusion from ambient occlusion (Lagarde & de Rousiers 2014, Frostbite,
    §4.10.2, Eq. in Listing 26): ``clip((<n,v> + A)^(2^(−16α − 1)) − 1 + A, 0, 1)`` — the
    visible fraction of a cone about the reflection, 1 where ``A = 1`` (unoccluded), 0 where
    ``A = 0``, and darker for smooth lobes at grazing views."""
    e = dr.exp2(-16.0 * alpha - 1.0)
    return dr.clip(dr.power(dr.maximum(nv, 0.0) + ao, e) - 1.0 + ao, 0.0, 1.0)


@dataclass
class SpecularTables:
    """Per world shape (Dr.Jit tables indexed by the G-buffer's shape index): GGX ``alpha``,
    Schlick ``f0`` and ``f90`` (:func:`schlick`), and whether any virtual shape is glossy.

    ``phong`` (Kán's plausible Phong, no Fresnel): ``α = √(2/(n+2))``, ``F0 = F90 = ks``;
    ``roughconductor``/``mirror`` (Mitsuba ``material = none``: ``F = 1`` times the
    ``specular_reflectance``): ``F0 = F90 = reflectance``, ``α`` the material's
    (:data:`MIRROR_ALPHA` for a mirror); ``pbr`` (Mitsuba's ``principled``, Schlick-like):
    ``F0`` of :func:`pbr_lobes`, ``F90 = 1``."""

    alpha: mi.Float
    f0: mi.Color3f
    f90: mi.Color3f
    glossy: bool


def specular_tables(world: World) -> SpecularTables:
    """The :class:`SpecularTables` of ``world``'s shapes."""
    alpha = np.ones(max(len(world.shapes), 1), np.float32)
    ks = np.zeros((max(len(world.shapes), 1), 3), np.float32)
    f90 = np.zeros_like(ks)
    for i, s in enumerate(world.shapes):
        p = s.material.params
        if s.material.type == "phong":
            alpha[i] = math.sqrt(2.0 / (float(p["exponent"]) + 2.0))
            ks[i] = f90[i] = p["ks"]
        elif s.material.type == "roughconductor":
            alpha[i], ks[i] = float(p["alpha"]), p["reflectance"]
            f90[i] = ks[i]
        elif s.material.type == "mirror":
            alpha[i], ks[i] = MIRROR_ALPHA, p["reflectance"]
            f90[i] = ks[i]
        elif s.material.type == "pbr":
            _, alpha[i], ks[i] = pbr_lobes(p)
            f90[i] = 1.0
    glossy = any(np.any(ks[i]) for i, s in enumerate(world.shapes) if s.is_virtual)
    return SpecularTables(mi.Float(alpha), mi.Color3f(ks[:, 0], ks[:, 1], ks[:, 2]),
                          mi.Color3f(f90[:, 0], f90[:, 1], f90[:, 2]), glossy)


@dataclass
class GlossyLanes:
    """The GGX lobe of the virtual lanes: view direction ``v`` (to the camera), ``alpha``,
    Schlick ``f0``, ``f90`` (:class:`~arlight.realtime.ibl_shading.SpecularTables`)."""

    v: mi.Vector3f
    alpha: mi.Float
    f0: mi.Color3f
    f90: mi.Color3f

    def reflectance(self, n: mi.Vector3f):
        """``ω ↦ f_s(ω, v) <n, ω>+`` for :func:`~arlight.realtime.shading.direct_light`."""
        return lambda w: ggx_reflectance(n, self.v, w, self.alpha, self.f0, self.f90)


def virtual_glossy(spec: SpecularTables, gb: GBuffer, idx: mi.UInt32, shape: mi.Int32
                   ) -> GlossyLanes:
    """:class:`GlossyLanes` of the compacted virtual lanes ``idx`` (shape indices
    ``shape``)."""
    return GlossyLanes(dr.gather(mi.Vector3f, gb.to_camera, idx),
                       dr.gather(mi.Float, spec.alpha, shape),
                       dr.gather(mi.Color3f, spec.f0, shape),
                       dr.gather(mi.Color3f, spec.f90, shape))


def _texture_mean(tex, channels) -> np.ndarray | float:
    return 1.0 if tex is None else np.asarray(tex.pixels, np.float64)[..., channels].mean(
        axis=(0, 1))


def pbr_lobes(p: dict) -> tuple[float, float, np.ndarray]:
    """The ``pbr`` material as one diffuse + one GGX lobe with constants per shape (the
    texture means): ``(diffuse weight, α, specular reflectance)``.

    The diffuse weight multiplies the G-buffer albedo (Mitsuba's principled BSDF reports its
    base colour there, texture included): ``(1 − metallic)(1 − transmission)``. The GGX
    lobe has ``α = roughness²`` (floored at :data:`MIRROR_ALPHA`) and Schlick's Fresnel from
    ``F0 = (1 − metallic)·((ior − 1)/(ior + 1))² + metallic·base colour`` (the mean base
    colour) to ``F90 = 1`` (:class:`SpecularTables`). Not modelled: normal maps, occlusion
    and emission textures, texture variation of metallic and roughness within a shape."""
    mr = p.get("metallic_roughness_texture")
    metallic = float(p["metallic"] * _texture_mean(mr, 2))
    roughness = float(p["roughness"] * _texture_mean(mr, 1))
    base = np.asarray(p["base_color"], np.float64) * _texture_mean(
        p.get("base_color_texture"), slice(0, 3))
    dielectric = ((p["ior"] - 1.0) / (p["ior"] + 1.0)) ** 2
    f0 = (1.0 - metallic) * dielectric + metallic * base
    return ((1.0 - metallic) * (1.0 - float(p["transmission"])),
            max(roughness * roughness, MIRROR_ALPHA), f0)


def diffuse_weights(world: World) -> mi.Float:
    """Per world shape: the factor on its G-buffer albedo (1, except ``pbr``: see
    :func:`pbr_lobes`), a Dr.Jit table indexed by the G-buffer's shape index."""
    w = np.ones(max(len(world.shapes), 1), np.float32)
    for i, s in enumerate(world.shapes):
        if s.material.type == "pbr":
            w[i] = pbr_lobes(s.material.params)[0]
    return mi.Float(w)


def ambient_occlusion(scene: mi.Scene | None, p: mi.Point3f, n: mi.Vector3f, rays: int,
                      max_distance: float, seed: int = 0, eps: float = 1e-4) -> mi.Float:
    """Ambient occlusion (Eq. 2.29: the visible fraction of the cosine-weighted hemisphere,
    1 = open) of ``K`` lanes against ``scene``: ``rays`` cosine-distributed rays per lane
    from a Hammersley set under a per-lane Cranley–Patterson rotation (deterministic in
    ``seed``), up to ``max_distance`` metres."""
    K = dr.width(p)
    if scene is None or rays <= 0 or K == 0:
        return dr.full(mi.Float, 1.0, K)
    u1, u2 = hammersley(rays)
    lane = dr.arange(mi.UInt32, K * rays)
    pix = lane // rays
    s = lane % rays
    # the seed opaque and the point set aligned: one kernel for every frame (arlight.jit)
    r1 = mi.sample_tea_float32(pix, dr.opaque(mi.UInt32, seed))
    r2 = mi.sample_tea_float32(pix, dr.opaque(mi.UInt32, seed + 0x9E3779B9 & 0xFFFFFFFF))
    x1 = dr.gather(mi.Float, mi.Float(aligned(u1, np.float32)), s) + r1
    x2 = dr.gather(mi.Float, mi.Float(aligned(u2, np.float32)), s) + r2
    x1 -= dr.floor(x1)
    x2 -= dr.floor(x2)
    local = mi.warp.square_to_cosine_hemisphere(mi.Point2f(x1, x2))
    nn = dr.gather(mi.Vector3f, n, pix)
    d = mi.Frame3f(nn).to_world(local)
    o = dr.gather(mi.Point3f, p, pix) + nn * eps
    ray = mi.Ray3f(o, d)
    # opaque: the length follows the objects' box (ibl's ao_distance changes as the bunny
    # turns); a literal compiled a new kernel on every moving frame (issue #32)
    ray.maxt = dr.opaque(mi.Float, float(max_distance)) if math.isfinite(max_distance) \
        else dr.largest(mi.Float)
    open_ = mi.Float(~scene.ray_test(ray))
    return dr.block_sum(open_, rays) * (1.0 / rays)


__all__ = ["DFG_SIZE", "ENV_HEIGHT", "MIRROR_ALPHA", "PREFILTER_LEVELS", "PROBE_HEIGHT",
           "PROBE_OPTIONS", "BounceProbe", "GlossyLanes", "bounce_probe", "probe_drag_options",
           "probe_for_world",
           "MipEnvironment", "SpecularTables", "ambient_occlusion", "dfg_lookup", "dfg_table",
           "diffuse_weights", "environment_map", "ggx_d", "ggx_reflectance", "hammersley",
           "local_frame", "pbr_lobes", "prefilter_ggx", "rot_y", "schlick", "smith_g1",
           "specular_occlusion", "specular_split_sum", "specular_tables", "virtual_glossy"]
