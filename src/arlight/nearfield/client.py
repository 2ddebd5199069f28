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


def _v(a) -> mi.Vector3f:
    return mi.Vector3f(float(a[0]), float(a[1]), float(a[2]))


def _table(a: np.ndarray) -> mi.Vector3f:
    a = np.asarray(a, np.float32).reshape(-1, 3)
    return mi.Vector3f(*[mi.Float(np.ascontiguousarray(a[:, i])) for i in range(3)])


@dataclass
class _Tables:
    """Per-VAL parameters as Dr.Jit arrays, read with an opaque index so that one compiled
    kernel serves every chunk of VALs (literal constants would compile one per chunk)."""

    P: mi.Vector3f
    N: mi.Vector3f
    I: mi.Vector3f
    R2: mi.Float
    origin: mi.Vector3f | None = None
    axis: mi.Vector3f | None = None
    u: mi.Vector3f | None = None
    v: mi.Vector3f | None = None
    tan: mi.Float | None = None


def _tables(light: NearFieldLight, maps: ShadowMaps | None, disc: bool) -> _Tables:
    r2 = light.area / math.pi if disc else np.zeros(light.count)
    t = _Tables(_table(light.positions + EPS * light.normals), _table(light.normals),
                _table(light.intensity), mi.Float(r2.astype(np.float32)))
    if maps is not None:
        t.origin, t.axis = _table(maps.origin), _table(maps.axis)
        t.u, t.v = _table(maps.u), _table(maps.v)
        t.tan = mi.Float(maps.tan_half.astype(np.float32))
    return t


def _lookup(maps: ShadowMaps, tab: _Tables, j: mi.UInt32, x: mi.Point3f, bias_texels: float
            ) -> tuple[mi.Bool, mi.Bool]:
    """``(V, V̂)`` of VAL ``j`` at points ``x`` from its two maps (outside the frustum:
    ``(True, True)``)."""
    S = maps.size
    d = x - dr.gather(mi.Vector3f, tab.origin, j)
    dist = dr.norm(d)
    z = dr.dot(d, dr.gather(mi.Vector3f, tab.axis, j))
    t = dr.gather(mi.Float, tab.tan, j)
    zt = dr.maximum(z * t, 1e-12)
    s = dr.dot(d, dr.gather(mi.Vector3f, tab.u, j)) / zt
    q = dr.dot(d, dr.gather(mi.Vector3f, tab.v, j)) / zt
    inside = (z > 0) & (dr.abs(s) < 1.0) & (dr.abs(q) < 1.0)
    col = dr.clip(mi.Int32((s + 1.0) * (0.5 * S)), 0, S - 1)
    row = dr.clip(mi.Int32((q + 1.0) * (0.5 * S)), 0, S - 1)
    idx = j * (S * S) + mi.UInt32(row * S + col)
    bias = dist * (t * (bias_texels * 2.0 / S)) + 2e-3
    real = dr.gather(mi.Float, maps.real, idx, inside)
    virt = dr.gather(mi.Float, maps.virtual, idx, inside)
    return ~inside | (real >= dist - bias), ~inside | (virt >= dist - bias)


def _ray_visible(scene: mi.Scene | None, x: mi.Point3f, target: mi.Point3f,
                 active: mi.Bool) -> mi.Bool:
    if scene is None:
        return mi.Bool(True)
    d = target - x
    dist = dr.norm(d)
    ray = mi.Ray3f(x, d / dr.maximum(dist, 1e-12))
    ray.maxt = dr.maximum(dist - EPS, 0.0)
    return ~scene.ray_test(ray, active)


@dataclass
class _Lanes:
    """The G-buffer lanes one VAL shades (possibly a compacted subset)."""

    p: mi.Point3f
    n: mi.Vector3f
    albedo: mi.Color3f
    to_eye: mi.Vector3f
    virtual: mi.Bool
    valid: mi.Bool
    kind: mi.Int32
    ks: mi.Color3f
    ex: mi.Float
    eta: mi.Color3f
    k: mi.Color3f

    def take(self, idx: mi.UInt32) -> _Lanes:
        return _Lanes(*[dr.gather(type(a), a, idx) for a in vars(self).values()])


def _shade_one(lanes: _Lanes, tab: _Tables, jj: mi.UInt32, maps: ShadowMaps | None,
               proxy: mi.Scene, occluder: mi.Scene | None, bias_texels: float
               ) -> tuple[mi.Color3f, mi.Color3f]:
    """``(V V̂ L_VAL, V (1 − V̂) L_VAL)`` of VAL ``jj`` on ``lanes`` (maps when given)."""
    p, n = lanes.p, lanes.n
    P = dr.gather(mi.Vector3f, tab.P, jj)
    N = dr.gather(mi.Vector3f, tab.N, jj)
    d = P - p
    r2 = dr.squared_norm(d)
    ell = d * dr.rsqrt(dr.maximum(r2, 1e-20))
    cos_r = dr.maximum(dr.dot(n, ell), 0.0)
    cos_s = dr.maximum(-dr.dot(N, ell), 0.0)
    e = mi.Color3f(dr.gather(mi.Vector3f, tab.I, jj)) * (
        cos_r * cos_s / (r2 + dr.gather(mi.Float, tab.R2, jj)))  # irradiance, W/m²
    active = lanes.valid & (cos_r > 0) & (cos_s > 0)
    h = dr.normalize(ell + lanes.to_eye)
    lobe = (lanes.ex + 2.0) * (0.5 / math.pi) * dr.power(dr.maximum(dr.dot(n, h), 0.0),
                                                         lanes.ex)
    fres = schlick_complex(dr.maximum(dr.dot(h, lanes.to_eye), 0.0), lanes.eta, lanes.k)
    spec = dr.select(lanes.kind == KIND_METAL, fres, lanes.ks) * lobe
    spec_on = (lanes.kind != KIND_DIFFUSE) & lanes.virtual
    brdf = lanes.albedo * (1.0 / math.pi) + dr.select(spec_on, spec, mi.Color3f(0.0))
    L = dr.select(active, brdf * e, mi.Color3f(0.0))
    if maps is not None:
        v, vh = _lookup(maps, tab, jj, p, bias_texels)
    else:
        x = p + n * EPS
        v = _ray_visible(proxy, x, P, active)
        vh = _ray_visible(occluder, x, P, active & (lanes.virtual | v))
    zero = mi.Color3f(0.0)
    return dr.select(v & vh, L, zero), dr.select(v & ~vh, L, zero)


def _candidates(lanes: _Lanes, tab: _Tables, jj: mi.UInt32, use_map: bool,
                sphere: tuple[np.ndarray, float]) -> mi.Bool:
    """Lanes VAL ``jj`` can change: virtual ones, and real ones inside its shadow frustum
    (maps) or whose segment to it crosses the virtual objects' bounding sphere (rays)."""
    p = lanes.p
    if use_map:
        d = p - dr.gather(mi.Vector3f, tab.origin, jj)
        z = dr.dot(d, dr.gather(mi.Vector3f, tab.axis, jj))
        zt = dr.maximum(z * dr.gather(mi.Float, tab.tan, jj), 1e-12)
        s = dr.dot(d, dr.gather(mi.Vector3f, tab.u, jj)) / zt
        q = dr.dot(d, dr.gather(mi.Vector3f, tab.v, jj)) / zt
        real = (z > 0) & (dr.abs(s) < 1.0) & (dr.abs(q) < 1.0)
    else:
        c, rad2 = _v(sphere[0]), float(sphere[1]) ** 2
        d = dr.gather(mi.Vector3f, tab.P, jj) - p
        t = dr.clip(dr.dot(c - p, d) / dr.maximum(dr.squared_norm(d), 1e-20), 0.0, 1.0)
        real = dr.squared_norm(c - (p + t * d)) <= rad2
    return lanes.valid & (lanes.virtual | real)


def direct_light(light: NearFieldLight, p: mi.Point3f, n: mi.Vector3f, albedo: mi.Color3f,
                 to_eye: mi.Vector3f, virtual: mi.Bool, valid: mi.Bool, shape: mi.Int32,
                 mats: MaterialTable, proxy: mi.Scene, occluder: mi.Scene | None,
                 maps: ShadowMaps | None, disc: bool = True, bias_texels: float = 2.0,
                 sphere: tuple[np.ndarray, float] | None = None
                 ) -> tuple[mi.Color3f, mi.Color3f]:
    """``(Σ_j V_j V̂_j L_VAL_j, Σ_j V_j (1 − V̂_j) L_VAL_j)`` per lane (module docstring);
    the first is meant for virtual lanes, the second for real ones.

    ``sphere`` (centre, radius), the virtual objects' bounds, culls lanes per VAL (the role
    of Rohmer's tile culling): a real lane is shaded for VAL ``j`` only inside its shadow
    frustum (maps) or when its segment to the VAL crosses the sphere (rays); elsewhere
    ``V̂_j = 1`` and nothing changes. Those lanes are compacted, shaded and added back.
    VAL parameters are read through an opaque index, so one kernel serves every VAL.
    """
    sid = mi.UInt32(dr.maximum(shape, 0))
    lanes = _Lanes(p, n, albedo, to_eye, mi.Bool(virtual), mi.Bool(valid),
                   dr.gather(mi.Int32, mats.kind, sid, valid),
                   dr.gather(mi.Color3f, mats.ks, sid, valid),
                   dr.gather(mi.Float, mats.exponent, sid, valid),
                   dr.gather(mi.Color3f, mats.eta, sid, valid),
                   dr.gather(mi.Color3f, mats.k, sid, valid))
    dr.eval(*vars(lanes).values())
    tab = _tables(light, maps, disc)
    width = dr.width(p)
    lit = dr.zeros(mi.Color3f, width)
    lost = dr.zeros(mi.Color3f, width)
    for j in range(light.count):
        jj = dr.opaque(mi.UInt32, j)
        use_map = maps is not None and maps.tan_half[j] > 0
        m = maps if use_map else None
        if sphere is None:
            a, b = _shade_one(lanes, tab, jj, m, proxy, occluder, bias_texels)
            lit += a
            lost += b
        else:
            idx = dr.compress(_candidates(lanes, tab, jj, use_map, sphere))
            if dr.width(idx) == 0:
                continue
            a, b = _shade_one(lanes.take(idx), tab, jj, m, proxy, occluder, bias_texels)
            dr.scatter_add(lit, a, idx)
            dr.scatter_add(lost, b, idx)
        dr.eval(lit, lost)
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
