"""Sum-of-Gaussians (SoG) glossy transfer (Franke thesis §4.3, Eqs. 4.25–4.26, after
Green, Kautz & Durand 2007 [GKD07a]).

The outgoing glossy radiance of Eq. 4.25,

    L(x, ω_o) = ∫ T_{θo}(δ) L_i(ω_r ⊕ δ) dδ,

integrates the transfer over the 2-D angular displacement ``δ = (δ_1, δ_2)`` (radians) from
the mirror direction ``ω_r``: ``ω_r ⊕ δ = cos|δ| ω_r + sin|δ| (δ_1 e_1 + δ_2 e_2)/|δ|``
(the exponential map at ``ω_r``), ``e_1`` the unit vector in the plane of incidence,
perpendicular to ``ω_r`` and leaning towards the normal, ``e_2 = ω_r × e_1``. The transfer is
the GGX microfacet lobe of :mod:`arlight.realtime.ibl_shading` (``ggx_d``, ``smith_g1``)
times the cosine, as a density in ``δ`` (with the map's Jacobian ``sin|δ|/|δ|``):

    T_{θo}(δ) = f_s(ω_i, ω_o) <n, ω_i>+ sin|δ|/|δ|,
    f_s = D(h) G1(ω_o) G1(ω_i) / (4 <n,ω_i> <n,ω_o>)   with Fresnel factored out (F = 1).

Fresnel is applied at runtime as the constant specular reflectance ``F0`` (the material's
``ks``/``reflectance``): exact for ``prt``'s materials (Mitsuba's ``roughconductor`` with
``material = none`` is ``F = 1`` times its reflectance; Kán's Phong has no Fresnel term).
Eq. 4.26 fits, per
roughness ``α`` and each of ``N`` view angles ``θ_o`` (default 16, uniform in ``cos θ_o``:
``cos θ_o,j = (j + ½)/N``), ``K`` (default 3) isotropic Gaussians

    T_{θo}(δ) ≈ Σ_k w_k exp(−|δ − µ_k e_1|² / (2 σ_k²))                       (Eq. 4.26)

(``w_k`` 1/sr, mean ``µ_k`` along the plane of incidence and width ``σ_k`` in radians), by
:func:`scipy.optimize.least_squares` on a polar ``δ`` grid covering the whole sphere, with
the area-weighted residual plus one row that holds the lobe's integral (the directional
albedo ``Σ_k w_k 2π σ_k² = ∫ f_s cos dω``). Tables are cached per ``α``
(:func:`sog_table`). A view whose relative L2 residual exceeds ``max_residual`` is
*flagged* (``SoGTable.flagged``) and a :class:`RuntimeWarning` names it.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import lru_cache

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.optimize import least_squares

from arlight.realtime.ibl_shading import MipEnvironment, ggx_d, smith_g1

VIEWS = 16
"""Default number of view angles ``N`` (uniform in cos θ_o)."""
LOBES = 3
"""Default number of Gaussians ``K`` per view angle."""
MAX_RESIDUAL = 0.3
"""Default largest accepted relative L2 residual of a fitted view."""
_RADIAL, _ANGULAR = 96, 72


def ggx_transfer(alpha: float, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``f_s(ω_i, ω_o) <n, ω_i>+`` (1/sr, F = 1) of the GGX lobe for unit local-frame
    directions ``(M, 3)`` (normal +z), using :func:`ggx_d` and :func:`smith_g1`."""
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    ci, co = wi[..., 2], wo[..., 2]
    a = float(alpha)
    d = np.asarray(ggx_d(mi.Float(a), mi.Float(h[..., 2].astype(np.float32))), np.float64)
    g = (np.asarray(smith_g1(mi.Float(a), mi.Float(ci.astype(np.float32))), np.float64)
         * np.asarray(smith_g1(mi.Float(a), mi.Float(co.astype(np.float32))), np.float64))
    ok = (ci > 0.0) & (co > 0.0) & (np.sum(wi * h, axis=-1) > 0.0)
    return np.where(ok, d * g / (4.0 * np.maximum(co, 1e-6)), 0.0)


def view_cosines(n_views: int = VIEWS) -> np.ndarray:
    """The ``N`` fitted ``cos θ_o`` values ``(j + ½)/N``."""
    return (np.arange(n_views) + 0.5) / n_views


def _grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Polar ``δ`` grid over the disk ``|δ| ≤ π`` (the whole sphere): ``δ_1, δ_2`` and the
    area weights ``r dr dφ`` (radial nodes ``r = π u²`` crowd near the mirror direction)."""
    u = (np.arange(_RADIAL) + 0.5) / _RADIAL
    r = math.pi * u * u
    dr_ = 2.0 * math.pi * u / _RADIAL
    phi = (np.arange(_ANGULAR) + 0.5) * (2.0 * math.pi / _ANGULAR)
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    area = (r * dr_)[:, None] * (2.0 * math.pi / _ANGULAR) * np.ones_like(pp)
    return (rr * np.cos(pp)).ravel(), (rr * np.sin(pp)).ravel(), area.ravel()


def transfer_on_grid(alpha: float, cos_o: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                          np.ndarray]:
    """``T_{θo}(δ)`` (module docstring, Jacobian included) on the polar grid: returns
    ``δ_1, δ_2``, the area weights (rad²) and ``T``."""
    d1, d2, area = _grid()
    s = math.sqrt(max(0.0, 1.0 - cos_o * cos_o))
    wo = np.array([s, 0.0, cos_o])
    wr = np.array([-s, 0.0, cos_o])
    e1 = np.array([cos_o, 0.0, s])
    e2 = np.cross(wr, e1)
    r = np.hypot(d1, d2)
    sinc = np.sin(r) / r
    wi = (np.cos(r)[:, None] * wr + (sinc * d1)[:, None] * e1 + (sinc * d2)[:, None] * e2)
    t = ggx_transfer(alpha, wi, np.broadcast_to(wo, wi.shape)) * sinc
    return d1, d2, area, t


def sog_eval(w: np.ndarray, mu: np.ndarray, sigma: np.ndarray, d1: np.ndarray,
             d2: np.ndarray) -> np.ndarray:
    """Eq. 4.26: ``Σ_k w_k exp(−|δ − µ_k e_1|²/(2σ_k²))`` at ``δ = (d1, d2)``."""
    q = (d1[:, None] - mu[None]) ** 2 + d2[:, None] ** 2
    return np.sum(w[None] * np.exp(-q / (2.0 * sigma[None] ** 2)), axis=1)


@dataclass
class LobeFit:
    """One view angle's fit: weights ``w`` (1/sr), means ``mu`` and widths ``sigma`` (rad),
    ``(K,)`` each; ``residual`` the relative area-weighted L2 error; ``albedo`` the grid
    integral ``∫ T dδ`` (the directional albedo, F = 1)."""

    w: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    residual: float
    albedo: float


def fit_lobe(alpha: float, cos_o: float, lobes: int = LOBES) -> LobeFit:
    """Least-squares fit of Eq. 4.26 to ``T_{θo}`` (module docstring) for roughness ``alpha``
    and ``cos θ_o``; the extra residual row (weight 10) keeps ``Σ w 2πσ²`` at the albedo."""
    d1, d2, area, t = transfer_on_grid(alpha, cos_o)
    albedo = float(np.sum(area * t))
    sw = np.sqrt(area)
    norm = max(float(np.sqrt(np.sum(area * t * t))), 1e-30)
    mass = max(albedo, 1e-30)
    mean = float(np.sum(area * t * d1)) / mass
    spread = math.sqrt(max(float(np.sum(area * t * ((d1 - mean) ** 2 + d2 ** 2))) / (2 * mass),
                           1e-6))
    sig0 = spread * np.geomspace(0.5, 2.0, lobes) if lobes > 1 else np.array([spread])
    share = np.full(lobes, 1.0 / lobes)
    x0 = np.concatenate([np.log(share * mass / (2 * math.pi * sig0 ** 2)),
                         np.full(lobes, mean), np.log(sig0)])

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.exp(x[:lobes]), x[lobes:2 * lobes], np.exp(x[2 * lobes:])

    def residuals(x: np.ndarray) -> np.ndarray:
        w, mu, sig = unpack(x)
        pts = sw * (sog_eval(w, mu, sig, d1, d2) - t) / norm
        total = 10.0 * (float(np.sum(w * 2 * math.pi * sig ** 2)) - albedo) / mass
        return np.append(pts, total)

    def jacobian(x: np.ndarray) -> np.ndarray:
        w, mu, sig = unpack(x)
        dd = d1[:, None] - mu[None]
        q = dd * dd + d2[:, None] ** 2
        wg = w[None] * np.exp(-q / (2.0 * sig[None] ** 2)) * (sw / norm)[:, None]
        pts = np.concatenate([wg, wg * dd / sig[None] ** 2, wg * q / sig[None] ** 2], axis=1)
        mass_k = 10.0 * w * 2 * math.pi * sig ** 2 / mass
        total = np.concatenate([mass_k, np.zeros(lobes), 2.0 * mass_k])
        return np.vstack([pts, total[None]])

    lo = np.concatenate([np.full(lobes, -60.0), np.full(lobes, -1.5), np.full(lobes, -9.0)])
    hi = np.concatenate([np.full(lobes, 60.0), np.full(lobes, 1.5), np.full(lobes, 1.0)])
    sol = least_squares(residuals, np.clip(x0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                        jac=jacobian, x_scale="jac")
    w, mu, sig = unpack(sol.x)
    res = float(np.linalg.norm(residuals(sol.x)[:-1]))
    return LobeFit(w, mu, sig, res, albedo)


@dataclass(frozen=True)
class SoGTable:
    """Eq. 4.26 coefficients of one roughness: ``w``, ``mu``, ``sigma`` ``(N, K)`` over the
    view cosines ``cos_o`` ``(N,)``; ``residual`` ``(N,)``; ``flagged`` the views whose
    residual exceeds the accepted one (thesis: two ``K × N`` textures)."""

    alpha: float
    cos_o: np.ndarray
    w: np.ndarray
    mu: np.ndarray
    sigma: np.ndarray
    residual: np.ndarray
    flagged: np.ndarray

    def albedo(self) -> np.ndarray:
        """``Σ_k w_k 2π σ_k²`` per view: the SoG's reflectance of a constant environment."""
        return np.sum(self.w * 2.0 * math.pi * self.sigma ** 2, axis=1)


@lru_cache(maxsize=64)
def sog_table(alpha: float, n_views: int = VIEWS, lobes: int = LOBES,
              max_residual: float = MAX_RESIDUAL) -> SoGTable:
    """Fitted (and cached per argument tuple) SoG table of GGX roughness ``alpha``; warns
    (RuntimeWarning) when a view's residual exceeds ``max_residual``."""
    cos_o = view_cosines(n_views)
    fits = [fit_lobe(float(alpha), float(c), lobes) for c in cos_o]
    res = np.array([f.residual for f in fits])
    flagged = res > max_residual
    if np.any(flagged):
        warnings.warn(f"SoG fit of GGX alpha={alpha:g} with K={lobes}: relative residual up to "
                      f"{res.max():.3f} > {max_residual:g} at cos θ_o = "
                      f"{np.round(cos_o[flagged], 3).tolist()}", RuntimeWarning, stacklevel=2)
    return SoGTable(float(alpha), cos_o, np.stack([f.w for f in fits]),
                    np.stack([f.mu for f in fits]), np.stack([f.sigma for f in fits]), res,
                    flagged)


def mip_level(env: MipEnvironment, d: mi.Vector3f, sigma: mi.Float) -> mi.Float:
    """Mip level whose texel solid angle matches the Gaussian's ``Ω_G = 2π σ²`` (its
    integral over its peak): ``l = max(0, ½ log2(Ω_G / Ω_p))`` with the level-0 equirect
    texel ``Ω_p = (2π/W)(π/H) sin θ_d`` (W = 2H; ``sin θ`` clamped at ``½/H`` near the
    poles), each level quadrupling the texel's solid angle."""
    h0 = float(env.base_height)
    sin_d = dr.maximum(dr.safe_sqrt(1.0 - d.y * d.y), 0.5 / h0)
    omega_p = (2.0 * math.pi / (2.0 * h0)) * (math.pi / h0) * sin_d
    return dr.maximum(0.0, 0.5 * dr.log2(2.0 * math.pi * sigma * sigma / omega_p))


@dataclass
class SoGTables:
    """Per world shape, flat Dr.Jit tables of ``w``, ``µ``, ``σ`` indexed
    ``(shape · N + j) · K + k`` (zeros for shapes without a specular part)."""

    w: mi.Float
    mu: mi.Float
    sigma: mi.Float
    views: int
    lobes: int

    @classmethod
    def build(cls, alphas: list[float | None], n_views: int = VIEWS, lobes: int = LOBES
              ) -> SoGTables:
        """Tables for the shapes' roughness (``None``: not glossy)."""
        n = max(len(alphas), 1)
        w = np.zeros((n, n_views, lobes), np.float32)
        mu = np.zeros_like(w)
        sig = np.ones_like(w)
        for i, a in enumerate(alphas):
            if a is not None:
                t = sog_table(round(float(a), 6), n_views, lobes)
                w[i], mu[i], sig[i] = t.w, t.mu, t.sigma
        return cls(mi.Float(w.ravel()), mi.Float(mu.ravel()), mi.Float(sig.ravel()), n_views,
                   lobes)

    def radiance(self, env: MipEnvironment, shape: mi.Int32, n: mi.Vector3f,
                 v: mi.Vector3f) -> mi.Color3f:
        """Eq. 4.25 with Eq. 4.26 (F = 1): ``Σ_k w_k 2πσ_k² L̄_{σ_k}(ω_r ⊕ µ_k e_1)`` for
        lanes with unit normal ``n`` and unit direction to the camera ``v``; ``L̄_σ`` the
        mip-mapped environment at :func:`mip_level`. Coefficients are linear in
        ``cos θ_o`` between the two nearest fitted views."""
        c = dr.clip(dr.dot(n, v), 1e-4, 1.0)
        r = n * (2.0 * c) - v
        e1 = n - r * c
        ln = dr.norm(e1)
        e1 = dr.select(ln > 1e-5, e1 / dr.maximum(ln, 1e-12), mi.Frame3f(n).s)
        x = dr.clip(c * float(self.views) - 0.5, 0.0, float(self.views - 1))
        j0 = mi.UInt32(dr.floor(x))
        j1 = dr.minimum(j0 + 1, self.views - 1)
        t = x - dr.floor(x)
        base = mi.UInt32(dr.maximum(shape, 0)) * self.views
        out = mi.Color3f(0.0)
        for k in range(self.lobes):
            i0 = (base + j0) * self.lobes + k
            i1 = (base + j1) * self.lobes + k

            def lerp(table: mi.Float, i0: mi.UInt32 = i0, i1: mi.UInt32 = i1) -> mi.Float:
                return (dr.gather(mi.Float, table, i0) * (1.0 - t)
                        + dr.gather(mi.Float, table, i1) * t)

            w, mu, sig = lerp(self.w), lerp(self.mu), lerp(self.sigma)
            d = r * dr.cos(mu) + e1 * dr.sin(mu)
            out += env.lookup(d, mip_level(env, d, sig)) * (w * 2.0 * math.pi * sig * sig)
        return out


__all__ = ["LOBES", "LobeFit", "MAX_RESIDUAL", "SoGTable", "SoGTables", "VIEWS", "fit_lobe",
           "ggx_transfer", "mip_level", "sog_eval", "sog_table", "transfer_on_grid",
           "view_cosines"]
