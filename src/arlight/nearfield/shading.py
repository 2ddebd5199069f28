"""Shading of the client of Rohmer et al. 2015 (§5): one frame from a :class:`NearFieldLight`.

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

Tile culling (:func:`tile_lanes`, Rohmer's 8×8 tiles): a VAL shades only the tiles whose
hit points can change — not behind its plane, and inside its frustum unless the tile holds
virtual samples.

Glossy and metal materials: :mod:`arlight.nearfield.materials`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.jit import aligned, columns
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


@dataclass
class Frusta:
    """Per VAL the frustum from its centre that tightly contains the virtual objects'
    bounding sphere (shared by both shadow maps and the tile culling).

    Attributes:
        origin, axis, u, v: (M, 3) apex (VAL centre + EPS·normal) and orthonormal frame.
        tan_half: (M,) tangent of the half opening (0: the VAL lies inside the sphere, no
            frustum — such a VAL uses rays and shades every lane).
    """

    origin: np.ndarray
    axis: np.ndarray
    u: np.ndarray
    v: np.ndarray
    tan_half: np.ndarray

    def coords(self, j: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frustum coordinates ``(z, s, q)`` of points ``x (N, 3)`` for VAL ``j`` (inside:
        ``z > 0`` and ``|s|, |q| < 1``)."""
        d = x - self.origin[j]
        z = d @ self.axis[j]
        zt = np.maximum(z * self.tan_half[j], 1e-12)
        return z, (d @ self.u[j]) / zt, (d @ self.v[j]) / zt


def frusta(light: NearFieldLight, sphere: tuple[np.ndarray, float]) -> Frusta:
    """The :class:`Frusta` of ``light``'s VALs around ``sphere`` (centre, radius; 5 %
    margin)."""
    c, rad = np.asarray(sphere[0], np.float64), float(sphere[1])
    M = light.count
    origin = light.positions + EPS * light.normals
    axis, us, vs = np.zeros((M, 3)), np.zeros((M, 3)), np.zeros((M, 3))
    tan_half = np.zeros(M)
    for j in range(M):
        d = c - origin[j]
        dist = float(np.linalg.norm(d))
        if dist <= rad * 1.05:
            continue
        a = d / dist
        u, v = _frame(a)
        axis[j], us[j], vs[j] = a, u, v
        tan_half[j] = math.tan(math.asin(min(rad * 1.05 / dist, 0.999)))
    return Frusta(origin, axis, us, vs, tan_half)


def shadow_maps(light: NearFieldLight, proxy: mi.Scene, virtual: mi.Scene,
                sphere: tuple[np.ndarray, float], size: int = 128) -> ShadowMaps:
    """Real and virtual depth maps of every VAL over the virtual objects' bounding
    ``sphere`` (centre, radius).

    Texel ``(r, c)`` of VAL ``j``'s maps holds the distance (m) from the frustum apex
    ``o_j`` to the first hit of ``proxy`` (real) or ``virtual`` along
    ``normalize(a_j + tan_half_j (g_c u_j + g_r v_j))``, ``g_i = (i + ½)/S · 2 − 1``
    (``inf``: no hit, or a VAL without frustum). Traced in one Dr.Jit pass of ``M·S²``
    lanes (no NumPy ray set-up: a moving object redraws the maps every frame, issue #32)."""
    fr = frusta(light, sphere)
    M, S = light.count, int(size)
    if not np.any(fr.tan_half > 0):
        return ShadowMaps(fr.origin, fr.axis, fr.u, fr.v, fr.tan_half,
                          dr.full(mi.Float, dr.inf, M * S * S),
                          dr.full(mi.Float, dr.inf, M * S * S), S)
    lane = dr.arange(mi.UInt32, M * S * S)
    j = lane // (S * S)
    texel = lane - j * (S * S)
    row = texel // S
    col = texel - row * S

    def per_val(a: np.ndarray) -> mi.Vector3f:
        return dr.gather(mi.Vector3f, mi.Vector3f(*columns(a, np.float32)), j)

    tan_half = dr.gather(mi.Float, mi.Float(aligned(fr.tan_half, np.float32)), j)
    live = tan_half > 0.0
    gx = (mi.Float(col) + 0.5) * (2.0 / S) - 1.0
    gy = (mi.Float(row) + 0.5) * (2.0 / S) - 1.0
    d = dr.normalize(per_val(fr.axis) + tan_half * (gx * per_val(fr.u) + gy * per_val(fr.v)))
    ray = mi.Ray3f(mi.Point3f(per_val(fr.origin)), d)
    depth = []
    for scene in (proxy, virtual):
        pi = scene.ray_intersect_preliminary(ray, active=live)
        depth.append(dr.select(pi.is_valid(), pi.t, dr.inf))
    dr.eval(*depth)
    return ShadowMaps(fr.origin, fr.axis, fr.u, fr.v, fr.tan_half, depth[0], depth[1], S)


TILE = 8
"""Tile side in pixels (Rohmer: 8×8 tiles, 64 threads)."""


def tile_lanes(light: NearFieldLight, position: np.ndarray, valid: np.ndarray,
               virtual: np.ndarray, width: int, height: int, spp: int,
               sphere: tuple[np.ndarray, float]) -> list[np.ndarray]:
    """Per VAL the lanes it must shade (Rohmer's tile culling, §5): lanes (pixel-major,
    ``spp`` per pixel, as the G-buffer lays them out) are grouped into 8×8-pixel tiles with
    the bounding box of their hit points; a tile is kept for VAL ``j`` unless its box lies
    entirely behind the VAL's plane (a one-sided emitter lights nothing there) or — for a
    tile without virtual lanes — entirely outside the VAL's frustum around the virtual
    objects (there ``V̂_j = 1`` and nothing changes). Returns, per VAL, the kept valid lanes
    (tile by tile)."""
    T = TILE
    hp, wp = -(-height // T) * T, -(-width // T) * T
    ty, tx = hp // T, wp // T

    def tiled(a: np.ndarray, fill) -> np.ndarray:  # (H, W, spp, c) -> (ty, tx, T*T*spp, c)
        a = a.reshape(height, width, spp, -1)
        out = np.full((hp, wp, spp, a.shape[-1]), fill, a.dtype)
        out[:height, :width] = a
        return out.reshape(ty, T, tx, T, spp, -1).transpose(0, 2, 1, 3, 4, 5).reshape(
            ty * tx, T * T * spp, -1)

    ok = np.asarray(valid, bool)
    pos = np.asarray(position, np.float32)

    def box(fill: float, fold) -> np.ndarray:  # (tiles, 3) per-tile min or max of hit points
        # channel-first, folded column by column: NumPy reduces short strided axes slowly
        a = np.full((3, hp, wp * spp), fill, np.float32)
        a[:, :height, :width * spp] = np.where(ok[None], pos.T, fill).reshape(3, height, -1)
        a = a.reshape(3, hp, tx, T * spp)
        rows = a[..., 0].copy()
        for k in range(1, T * spp):
            fold(rows, a[..., k], out=rows)
        rows = rows.reshape(3, ty, T, tx)
        out = rows[:, :, 0].copy()
        for k in range(1, T):
            fold(out, rows[:, :, k], out=out)
        return out.reshape(3, ty * tx).T

    lo, hi = box(np.inf, np.minimum), box(-np.inf, np.maximum)
    has = np.isfinite(lo[:, 0])
    has_virtual = np.any(tiled((ok & np.asarray(virtual, bool))[:, None], False)[..., 0], 1)
    corners = np.stack([np.where(np.array(b)[None, :] == 1, hi, lo) for b in
                        np.ndindex(2, 2, 2)], axis=1)  # (tiles, 8, 3)
    corners = np.where(has[:, None, None], corners, 0.0).astype(np.float64)
    lanes_of_tile = tiled(np.where(ok, np.arange(len(ok), dtype=np.int32), -1)[:, None],
                          -1)[..., 0]
    fr = frusta(light, sphere)
    # all VALs at once, as one matrix product: (corner − origin) · {normal, axis, u, v}
    M = light.count
    frame = np.concatenate([light.normals, fr.axis, fr.u, fr.v])  # (4M, 3), float64
    off = np.einsum("mi,mi->m", np.tile(fr.origin, (4, 1)), frame)
    proj = (corners.reshape(-1, 3) @ frame.T - off).reshape(len(corners), 8, 4, M)
    proj = proj.transpose(2, 3, 0, 1)  # (4, M, tiles, 8)
    behind = np.all(proj[0] <= 0, 2)
    keep = has[None] & ~behind
    z = proj[1]
    zt = np.maximum(z * fr.tan_half[:, None, None], 1e-12)
    sc = proj[2] / zt
    qc = proj[3] / zt
    front = z > 0
    outside = (np.all(~front, 2) | np.all(front & (sc >= 1), 2) | np.all(front & (sc <= -1), 2)
               | np.all(front & (qc >= 1), 2) | np.all(front & (qc <= -1), 2))
    framed = fr.tan_half > 0  # VALs inside the sphere keep every lit tile
    keep &= ~framed[:, None] | has_virtual[None] | ~outside
    out = []
    for j in range(light.count):
        cand = lanes_of_tile[keep[j]].reshape(-1)
        out.append(cand[cand >= 0].view(np.uint32))  # non-negative: same bits
    return out


def _table(a: np.ndarray) -> mi.Vector3f:
    return mi.Vector3f(*columns(np.asarray(a).reshape(-1, 3), np.float32))


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
                _table(light.intensity), mi.Float(aligned(r2, np.float32)))
    if maps is not None:
        t.origin, t.axis = _table(maps.origin), _table(maps.axis)
        t.u, t.v = _table(maps.u), _table(maps.v)
        t.tan = mi.Float(aligned(maps.tan_half, np.float32))
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
    kind: mi.Int32 | None = None  # the material fields are None when every shape is diffuse
    ks: mi.Color3f | None = None
    ex: mi.Float | None = None
    eta: mi.Color3f | None = None
    k: mi.Color3f | None = None

    def take(self, idx: mi.UInt32) -> _Lanes:
        return _Lanes(*[None if a is None else dr.gather(type(a), a, idx)
                        for a in vars(self).values()])


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
    brdf = lanes.albedo * (1.0 / math.pi)
    if lanes.kind is not None:
        h = dr.normalize(ell + lanes.to_eye)
        lobe = (lanes.ex + 2.0) * (0.5 / math.pi) * dr.power(dr.maximum(dr.dot(n, h), 0.0),
                                                             lanes.ex)
        fres = schlick_complex(dr.maximum(dr.dot(h, lanes.to_eye), 0.0), lanes.eta, lanes.k)
        spec = dr.select(lanes.kind == KIND_METAL, fres, lanes.ks) * lobe
        spec_on = (lanes.kind != KIND_DIFFUSE) & lanes.virtual
        brdf = brdf + dr.select(spec_on, spec, mi.Color3f(0.0))
    L = dr.select(active, brdf * e, mi.Color3f(0.0))
    if maps is not None:
        v, vh = _lookup(maps, tab, jj, p, bias_texels)
    else:
        x = p + n * EPS
        v = _ray_visible(proxy, x, P, active)
        vh = _ray_visible(occluder, x, P, active & (lanes.virtual | v))
    zero = mi.Color3f(0.0)
    return dr.select(v & vh, L, zero), dr.select(v & ~vh, L, zero)


def direct_light(light: NearFieldLight, p: mi.Point3f, n: mi.Vector3f, albedo: mi.Color3f,
                 to_eye: mi.Vector3f, virtual: mi.Bool, valid: mi.Bool, shape: mi.Int32,
                 mats: MaterialTable, proxy: mi.Scene, occluder: mi.Scene | None,
                 maps: ShadowMaps | None, disc: bool = True, bias_texels: float = 2.0,
                 lanes_per_val: list[np.ndarray] | None = None
                 ) -> tuple[mi.Color3f, mi.Color3f]:
    """``(Σ_j V_j V̂_j L_VAL_j, Σ_j V_j (1 − V̂_j) L_VAL_j)`` per lane (module docstring);
    the first is meant for virtual lanes, the second for real ones.

    ``lanes_per_val`` (:func:`tile_lanes`): per VAL the lanes to shade (tile culling);
    those lanes are gathered, shaded and added back. None: every lane, every VAL. VAL
    parameters are read through an opaque index, so one kernel serves every VAL.
    """
    sid = mi.UInt32(dr.maximum(shape, 0))
    lanes = _Lanes(p, n, albedo, to_eye, mi.Bool(virtual), mi.Bool(valid))
    if np.any(np.array(mats.kind) != KIND_DIFFUSE):  # glossy / metal shapes exist
        lanes = _Lanes(p, n, albedo, to_eye, mi.Bool(virtual), mi.Bool(valid),
                       dr.gather(mi.Int32, mats.kind, sid, valid),
                       dr.gather(mi.Color3f, mats.ks, sid, valid),
                       dr.gather(mi.Float, mats.exponent, sid, valid),
                       dr.gather(mi.Color3f, mats.eta, sid, valid),
                       dr.gather(mi.Color3f, mats.k, sid, valid))
    dr.eval(*[a for a in vars(lanes).values() if a is not None])
    tab = _tables(light, maps, disc)
    width = dr.width(p)
    lit = dr.zeros(mi.Color3f, width)
    lost = dr.zeros(mi.Color3f, width)
    for j in range(light.count):
        jj = dr.opaque(mi.UInt32, j)
        use_map = maps is not None and maps.tan_half[j] > 0
        m = maps if use_map else None
        if lanes_per_val is None:
            a, b = _shade_one(lanes, tab, jj, m, proxy, occluder, bias_texels)
            lit += a
            lost += b
        else:
            if len(lanes_per_val[j]) == 0:
                continue
            # aligned: Dr.Jit compiles a NumPy buffer's alignment into the kernel, and
            # these lanes are new every frame (tests/methods/test_kernel_reuse.py)
            idx = mi.UInt32(aligned(lanes_per_val[j], np.uint32))
            a, b = _shade_one(lanes.take(idx), tab, jj, m, proxy, occluder, bias_texels)
            # a VAL's lanes are distinct: plain read-modify-write, no atomics or the
            # full-size per-thread buffers of the default (Local/Expand) reduction
            dr.scatter_add(lit, a, idx, mode=dr.ReduceMode.NoConflicts)
            dr.scatter_add(lost, b, idx, mode=dr.ReduceMode.NoConflicts)
        dr.eval(lit, lost)
    return lit, lost


class PerObjectSH(SimpleNamespace):
    """Adapter for ``arlight.realtime.prt_shading.shade_virtual``: its ``vertex_values`` uses each
    object's own SH block (Rohmer: one probe per virtual object) instead of one light."""

    def vertex_values(self, order: int | None = None) -> list[np.ndarray]:
        from arlight.realtime.prt_transfer import vertex_values

        return [vertex_values(o.transfer, self.sh[k], o.rotation, 2)
                for k, o in enumerate(self.objects)]


__all__ = ["EPS", "KIND_DIFFUSE", "KIND_GLOSSY", "KIND_METAL", "TILE", "Frusta",
           "MaterialTable", "PerObjectSH", "ShadowMaps", "direct_light", "frusta",
           "material_table", "shadow_maps", "tile_lanes"]
