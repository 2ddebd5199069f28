"""The client of Rohmer et al. 2015 (§5): one frame from a :class:`NearFieldLight`.

Per G-buffer sample (``arlight.realtime.gbuffer``) with position ``x``, normal ``n``, albedo
ρ and role:

* **indirect** (virtual samples): per-vertex PRT ``ρ/π Σ_k C_k C_vk`` with the object's own
  9 SH coefficients (Eq. 8), interpolated over the hit triangle — ``arlight.methods.prt``'s
  transfer and shading are reused as they are;
* **direct**: per VAL ``j`` the disc term of Eq. 5 and two visibilities, ``V_j`` through the
  reconstructed (proxy) scene and ``V̂_j`` through the virtual objects;
* **Eq. 14**: virtual samples ``L_Ind + Σ_j V_j V̂_j L_VAL_j``; real samples
  ``L_background − Σ_j V_j (1 − V̂_j) L_VAL_j`` (``delta`` of the layers), so a real pixel
  loses only direct light that a virtual object blocks and that real geometry did not
  already block.

Visibility (``shadows``): ``"maps"`` — Rohmer's two shadow maps per VAL (real and virtual,
``size²``, default 128²), ray-traced depth maps from the VAL centre over a frustum that
tightly contains the virtual objects' bounding sphere (outside it ``V̂ = 1`` and nothing
changes); a VAL inside that sphere falls back to rays. ``"rays"`` — one shadow ray per
sample, VAL and scene (exact, slower).

Glossy and metal materials: :mod:`arlight.nearfield.materials`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.nearfield.materials import eta_for_f0, phong_exponent, schlick_complex
from arlight.nearfield.state import NearFieldLight
from arlight.scene.model import World

KIND_DIFFUSE, KIND_GLOSSY, KIND_METAL = 0, 1, 2
EPS = 1e-3
"""Offsets, m: shadow-ray origins leave receivers, and VAL centres leave their surface."""


@dataclass
class MaterialTable:
    """Per world shape: BRDF class, specular colour, Blinn-Phong exponent, complex IOR."""

    kind: mi.Int32
    ks: mi.Color3f
    exponent: mi.Float
    eta: mi.Color3f
    k: mi.Color3f


def material_table(world: World, metal_k: list[float]) -> MaterialTable:
    """The :class:`MaterialTable` of ``world``'s shapes (phong: glossy; roughconductor:
    metal, ``n`` from its reflectance and ``metal_k``)."""
    n = max(len(world.shapes), 1)
    kind = np.zeros(n, np.int32)
    ks = np.zeros((n, 3))
    ex = np.ones(n)
    eta = np.ones((n, 3))
    kk = np.zeros((n, 3))
    for i, s in enumerate(world.shapes):
        p = s.material.params
        if s.material.type == "phong":
            kind[i] = KIND_GLOSSY
            ks[i] = p["ks"]
            ex[i] = float(p["exponent"])
        elif s.material.type == "roughconductor":
            kind[i] = KIND_METAL
            ks[i] = 1.0
            ex[i] = phong_exponent(float(p["alpha"]))
            kk[i] = metal_k
            eta[i] = eta_for_f0(np.asarray(p["reflectance"], np.float64), kk[i])

    def c3(a):
        return mi.Color3f(*[mi.Float(a[:, c].astype(np.float32)) for c in range(3)])

    return MaterialTable(mi.Int32(kind), c3(ks), mi.Float(ex.astype(np.float32)), c3(eta),
                         c3(kk))


@dataclass
class ShadowMaps:
    """Two ray-traced depth maps per VAL (module docstring), flattened ``(M·S²)``.

    Attributes:
        origin, axis, u, v: (M, 3) map frames (origin = VAL centre + EPS·normal).
        tan_half: (M,) tangent of the half field of view (0: this VAL uses rays).
        real, virtual: Dr.Jit Float depth maps (distance to the first hit, inf: none).
        size: S.
    """

    origin: np.ndarray
    axis: np.ndarray
    u: np.ndarray
    v: np.ndarray
    tan_half: np.ndarray
    real: mi.Float
    virtual: mi.Float
    size: int


def _frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, t)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def shadow_maps(light: NearFieldLight, proxy: mi.Scene, virtual: mi.Scene,
                sphere: tuple[np.ndarray, float], size: int = 128) -> ShadowMaps:
    """Real and virtual depth maps of every VAL over the virtual objects' bounding
    ``sphere`` (centre, radius)."""
    c, rad = sphere
    M, S = light.count, int(size)
    origin = light.positions + EPS * light.normals
    axis, us, vs = np.zeros((M, 3)), np.zeros((M, 3)), np.zeros((M, 3))
    tan_half = np.zeros(M)
    g = (np.arange(S) + 0.5) / S * 2.0 - 1.0
    gy, gx = np.meshgrid(g, g, indexing="ij")
    dirs = []
    for j in range(M):
        d = c - origin[j]
        dist = float(np.linalg.norm(d))
        if dist <= rad * 1.05:
            dirs.append(np.zeros((0, 3)))
            continue
        a = d / dist
        u, v = _frame(a)
        t = math.tan(math.asin(min(rad * 1.05 / dist, 0.999)))
        axis[j], us[j], vs[j], tan_half[j] = a, u, v, t
        w = a[None] + t * (gx.reshape(-1, 1) * u[None] + gy.reshape(-1, 1) * v[None])
        dirs.append(w / np.linalg.norm(w, axis=1, keepdims=True))
    real = np.full(M * S * S, np.inf, np.float32)
    virt = np.full(M * S * S, np.inf, np.float32)
    live = [j for j in range(M) if tan_half[j] > 0]
    if live:
        o = np.concatenate([np.repeat(origin[j][None], S * S, 0) for j in live])
        d = np.concatenate([dirs[j] for j in live])
        idx = np.concatenate([np.arange(j * S * S, (j + 1) * S * S) for j in live])
        ray = mi.Ray3f(mi.Point3f(*[o[:, i].astype(np.float32) for i in range(3)]),
                       mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)]))
        for scene, out in ((proxy, real), (virtual, virt)):
            pi = scene.ray_intersect_preliminary(ray)
            t = np.asarray(dr.select(pi.is_valid(), pi.t, dr.inf), np.float32)
            out[idx] = t
    return ShadowMaps(origin, axis, us, vs, tan_half, mi.Float(real), mi.Float(virt), S)


def _v3(a) -> mi.Vector3f:
    return mi.Vector3f(float(a[0]), float(a[1]), float(a[2]))


def _c3(a) -> mi.Color3f:
    return mi.Color3f(float(a[0]), float(a[1]), float(a[2]))


def _lookup(maps: ShadowMaps, j: int, x: mi.Point3f, bias_texels: float
            ) -> tuple[mi.Bool, mi.Bool]:
    """``(V, V̂)`` of VAL ``j`` at points ``x`` from its two maps (outside the frustum:
    ``(True, True)``)."""
    S = maps.size
    d = x - _v3(maps.origin[j])
    dist = dr.norm(d)
    z = dr.dot(d, _v3(maps.axis[j]))
    t = float(maps.tan_half[j])
    s = dr.dot(d, _v3(maps.u[j])) / dr.maximum(z * t, 1e-12)
    q = dr.dot(d, _v3(maps.v[j])) / dr.maximum(z * t, 1e-12)
    inside = (z > 0) & (dr.abs(s) < 1.0) & (dr.abs(q) < 1.0)
    col = dr.clip(mi.Int32((s + 1.0) * 0.5 * S), 0, S - 1)
    row = dr.clip(mi.Int32((q + 1.0) * 0.5 * S), 0, S - 1)
    idx = mi.UInt32(j * S * S) + mi.UInt32(row * S + col)
    bias = dist * (bias_texels * 2.0 * t / S) + 2e-3
    real = dr.gather(mi.Float, maps.real, idx, inside)
    virt = dr.gather(mi.Float, maps.virtual, idx, inside)
    v = ~inside | (real >= dist - bias)
    vh = ~inside | (virt >= dist - bias)
    return v, vh


def _ray_visible(scene: mi.Scene | None, x: mi.Point3f, target: mi.Point3f,
                 active: mi.Bool) -> mi.Bool:
    if scene is None:
        return mi.Bool(True)
    d = target - x
    dist = dr.norm(d)
    ray = mi.Ray3f(x, d / dr.maximum(dist, 1e-12))
    ray.maxt = dr.maximum(dist - EPS, 0.0)
    return ~scene.ray_test(ray, active)


def direct_light(light: NearFieldLight, p: mi.Point3f, n: mi.Vector3f, albedo: mi.Color3f,
                 to_eye: mi.Vector3f, virtual: mi.Bool, valid: mi.Bool, shape: mi.Int32,
                 mats: MaterialTable, proxy: mi.Scene, occluder: mi.Scene | None,
                 maps: ShadowMaps | None, disc: bool = True, bias_texels: float = 2.0
                 ) -> tuple[mi.Color3f, mi.Color3f]:
    """``(Σ_j V_j V̂_j L_VAL_j, Σ_j V_j (1 − V̂_j) L_VAL_j)`` per lane (module docstring);
    the first is meant for virtual lanes, the second for real ones."""
    kind = dr.gather(mi.Int32, mats.kind, mi.UInt32(dr.maximum(shape, 0)), valid)
    ks = dr.gather(mi.Color3f, mats.ks, mi.UInt32(dr.maximum(shape, 0)), valid)
    ex = dr.gather(mi.Float, mats.exponent, mi.UInt32(dr.maximum(shape, 0)), valid)
    eta = dr.gather(mi.Color3f, mats.eta, mi.UInt32(dr.maximum(shape, 0)), valid)
    kk = dr.gather(mi.Color3f, mats.k, mi.UInt32(dr.maximum(shape, 0)), valid)
    x = p + n * EPS
    lit = mi.Color3f(0.0)
    lost = mi.Color3f(0.0)
    spec_on = (kind != KIND_DIFFUSE) & virtual
    for j in range(light.count):
        P = _v3(light.positions[j] + EPS * light.normals[j])
        N = _v3(light.normals[j])
        d = P - p
        r2 = dr.squared_norm(d)
        r = dr.sqrt(dr.maximum(r2, 1e-20))
        ell = d / r
        cos_r = dr.maximum(dr.dot(n, ell), 0.0)
        cos_s = dr.maximum(-dr.dot(N, ell), 0.0)
        R2 = float(light.area[j]) / math.pi if disc else 0.0
        e = _c3(light.intensity[j]) * (cos_r * cos_s / (r2 + R2))  # irradiance, W/m²
        active = valid & (cos_r > 0) & (cos_s > 0)
        brdf = albedo * (1.0 / math.pi)
        h = dr.normalize(ell + to_eye)
        nh = dr.maximum(dr.dot(n, h), 0.0)
        lobe = (ex + 2.0) * (0.5 / math.pi) * dr.power(nh, ex)
        fres = schlick_complex(dr.maximum(dr.dot(h, to_eye), 0.0), eta, kk)
        spec = dr.select(kind == KIND_METAL, fres, ks) * lobe
        brdf = brdf + dr.select(spec_on, spec, mi.Color3f(0.0))
        L = dr.select(active, brdf * e, mi.Color3f(0.0))
        if maps is not None and maps.tan_half[j] > 0:
            v, vh = _lookup(maps, j, p, bias_texels)
        else:
            v = _ray_visible(proxy, x, P, active)
            vh = _ray_visible(occluder, x, P, active)
        lit += dr.select(v & vh, L, mi.Color3f(0.0))
        lost += dr.select(v & ~vh, L, mi.Color3f(0.0))
    return lit, lost


class PerObjectSH(SimpleNamespace):
    """Adapter for ``arlight.methods.prt.shade_virtual``: its ``vertex_values`` uses each
    object's own SH block (Rohmer: one probe per virtual object) instead of one light."""

    def vertex_values(self, order: int | None = None) -> list[np.ndarray]:
        from arlight.realtime.prt_transfer import vertex_values

        return [vertex_values(o.transfer, self.sh[k], o.rotation, 2)
                for k, o in enumerate(self.objects)]


__all__ = ["EPS", "KIND_DIFFUSE", "KIND_GLOSSY", "KIND_METAL", "MaterialTable",
           "PerObjectSH", "ShadowMaps", "direct_light", "material_table", "shadow_maps"]
