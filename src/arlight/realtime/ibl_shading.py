"""Image-based shading of virtual objects: the *dynamic pipeline* of Franke thesis §4.2.

* :func:`environment_map` — the world's distant light (``envmap``, ``sh``, ``constant``
  lights, with their ``scale`` and ``rotation_deg``) as one equirect radiance map.
* :class:`MipEnvironment` — that map as a mip chain (2×2 box filter per level, the
  hardware mip generation the thesis uses) in one flat Dr.Jit array, looked up bilinearly
  per level and linearly between levels.
* :func:`specular_fis` — **filtered importance sampling** of a GGX lobe [KC08]:
  half vectors by inverting the GGX CDF (Eqs. 4.15–4.21: ``φ = 2π ξ_φ``,
  ``θ = arccos √((1 − ξ_θ)/((α² − 1) ξ_θ + 1))``), ``N`` (40) samples per pixel on a fixed
  Hammersley pattern, each fetched from the mip level of its pdf (Eqs. 4.22–4.23)

      p = D(h) <n,h> / (4 <v,h>),   l = max(0, ½ log2(Ω_s / Ω_p)),
      Ω_s = 1/(N p),   Ω_p = (2π/W)(π/H) sin θ_l,

  i.e. the thesis's ``½ log2(wh/N) − ½ log2 p`` with the equirect texel's solid angle in
  place of ``1/(wh)``; the estimator of ``∫ f_s L <n,l> dω`` for the microfacet BRDF
  ``f_s = F D G / (4 <n,l> <n,v>)`` is ``(1/N) Σ L(l) F G <v,h> / (<n,h> <n,v>)`` with
  Smith's separable GGX ``G = G1(v) G1(l)`` and ``F`` the specular reflectance.
* :func:`specular_tables` — per world shape the GGX ``α`` and specular reflectance of its
  material (``phong``: ``α = √(2/(n+2))``; ``roughconductor``; ``mirror`` as
  :data:`MIRROR_ALPHA`; ``pbr`` by :func:`pbr_lobes`), the tables :func:`specular_fis` and
  the SoG lobes look up; :func:`diffuse_weights` the factor on the G-buffer albedo
  (``pbr``: ``(1 − metallic)(1 − transmission)``).
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

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import aligned
from arlight.scene.model import World
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
        chunks, offs, hs = [], [], []
        off = 0
        while True:
            chunks.append(lvl.reshape(-1))
            offs.append(off)
            hs.append(lvl.shape[0])
            off += lvl.shape[0] * lvl.shape[1]
            if lvl.shape[0] < 2:
                break
            h, w = lvl.shape[0] // 2, lvl.shape[1] // 2
            lvl = lvl[:2 * h, :2 * w].reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
        return cls(mi.Float(np.concatenate(chunks)), mi.UInt32(np.array(offs, np.uint32)),
                   mi.UInt32(np.array(hs, np.uint32)), len(hs), int(image.shape[0]))

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


def specular_fis(env: MipEnvironment, n: mi.Vector3f, v: mi.Vector3f, alpha: mi.Float,
                 ks: mi.Color3f, samples: int = 40) -> mi.Color3f:
    """GGX specular radiance ``∫ f_s L <n,l>+ dω`` by filtered importance sampling (module
    docstring) for ``K`` lanes; ``samples`` fetches per lane, one kernel of ``K·samples``
    lanes summed per block."""
    K = dr.width(n)
    if K == 0:
        return dr.zeros(mi.Color3f, 0)
    xi_t, xi_p = hammersley(samples)
    lane = dr.arange(mi.UInt32, K * samples)
    pix = lane // samples
    s = lane % samples
    e1 = dr.gather(mi.Float, mi.Float(xi_t.astype(np.float32)), s)
    e2 = dr.gather(mi.Float, mi.Float(xi_p.astype(np.float32)), s)
    nn = dr.gather(mi.Vector3f, n, pix)
    vv = dr.gather(mi.Vector3f, v, pix)
    a = dr.maximum(dr.gather(mi.Float, alpha, pix), 1e-3)
    ks_p = dr.gather(mi.Color3f, ks, pix)
    a2 = a * a
    cos_h = dr.sqrt((1.0 - e1) / ((a2 - 1.0) * e1 + 1.0))  # Eq. 4.21
    sin_h = dr.safe_sqrt(1.0 - cos_h * cos_h)
    phi = 2.0 * math.pi * e2  # Eq. 4.20
    t1, t2 = local_frame(nn)
    h = t1 * (sin_h * dr.cos(phi)) + t2 * (sin_h * dr.sin(phi)) + nn * cos_h
    vh = dr.dot(vv, h)
    light = h * (2.0 * vh) - vv
    nl = dr.dot(nn, light)
    nv = dr.maximum(dr.dot(nn, vv), 1e-4)
    ok = (nl > 0.0) & (vh > 0.0)
    pdf = ggx_d(a, cos_h) * cos_h / (4.0 * dr.maximum(vh, 1e-6))  # Eq. 4.22
    omega_s = 1.0 / (samples * dr.maximum(pdf, 1e-12))
    sin_l = dr.safe_sqrt(1.0 - light.y * light.y)
    h0 = float(env.base_height)
    omega_p = (2.0 * math.pi / (2.0 * h0)) * (math.pi / h0) * dr.maximum(sin_l, 0.5 / h0)
    level = dr.maximum(0.0, 0.5 * dr.log2(omega_s / omega_p))  # Eq. 4.23
    radiance = env.lookup(light, level)
    weight = smith_g1(a, nv) * smith_g1(a, nl) * vh / (dr.maximum(cos_h, 1e-6) * nv)
    contrib = dr.select(ok, radiance * ks_p * weight, mi.Color3f(0.0))
    out = mi.Color3f(*[dr.block_sum(c, samples) for c in (contrib.x, contrib.y, contrib.z)])
    return out * (1.0 / samples)


def specular_tables(world: World) -> tuple[mi.Float, mi.Color3f, bool]:
    """Per world shape: GGX ``α`` and specular reflectance ``k_s`` (Dr.Jit tables indexed
    by the G-buffer's shape index), and whether any virtual shape is glossy."""
    alpha = np.ones(max(len(world.shapes), 1), np.float32)
    ks = np.zeros((max(len(world.shapes), 1), 3), np.float32)
    for i, s in enumerate(world.shapes):
        p = s.material.params
        if s.material.type == "phong":
            alpha[i] = math.sqrt(2.0 / (float(p["exponent"]) + 2.0))
            ks[i] = p["ks"]
        elif s.material.type == "roughconductor":
            alpha[i], ks[i] = float(p["alpha"]), p["reflectance"]
        elif s.material.type == "mirror":
            alpha[i], ks[i] = MIRROR_ALPHA, p["reflectance"]
        elif s.material.type == "pbr":
            _, alpha[i], ks[i] = pbr_lobes(p)
    glossy = any(np.any(ks[i]) for i, s in enumerate(world.shapes) if s.is_virtual)
    return mi.Float(alpha), mi.Color3f(ks[:, 0], ks[:, 1], ks[:, 2]), glossy


def _texture_mean(tex, channels) -> np.ndarray | float:
    return 1.0 if tex is None else np.asarray(tex.pixels, np.float64)[..., channels].mean(
        axis=(0, 1))


def pbr_lobes(p: dict) -> tuple[float, float, np.ndarray]:
    """The ``pbr`` material as one diffuse + one GGX lobe with constants per shape (the
    texture means): ``(diffuse weight, α, specular reflectance)``.

    The diffuse weight multiplies the G-buffer albedo (Mitsuba's principled BSDF reports its
    base colour there, texture included): ``(1 − metallic)(1 − transmission)``. The GGX
    lobe has ``α = roughness²`` (floored at :data:`MIRROR_ALPHA`) and the constant Fresnel
    ``F0 = (1 − metallic)·((ior − 1)/(ior + 1))² + metallic·base colour`` (the mean base
    colour). Not modelled: normal maps, occlusion and emission textures, the Fresnel rise
    at grazing angles, texture variation of metallic and roughness within a shape."""
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
    ray.maxt = float(max_distance) if math.isfinite(max_distance) else dr.largest(mi.Float)
    open_ = mi.Float(~scene.ray_test(ray))
    return dr.block_sum(open_, rays) * (1.0 / rays)


__all__ = ["ENV_HEIGHT", "MIRROR_ALPHA", "MipEnvironment", "ambient_occlusion",
           "environment_map", "ggx_d", "hammersley", "local_frame", "rot_y", "smith_g1",
           "specular_fis", "specular_tables", "pbr_lobes", "diffuse_weights"]
