"""Virtual area lights from the direct atlas (Rohmer §4.3, Eq. 6) and the VPL baselines
(Eq. 15).

1. **Importance sampling.** The pdf over direct texels is their grey radiant intensity
   ``p_t = ḡ(L_t ΔA_t) / Σ ḡ(L ΔA)`` (ḡ: the mean over RGB; Rohmer samples by radiance, but
   texels of unequal area carry light in proportion to ``L ΔA``); a prefix sum and an inverse
   CDF draw ``S`` samples (4k) with stratified uniforms and a fixed seed.
2. **k-means** on the samples' (position, normal): distance² = ``|Δp|²/D² + w_n²|Δn|²``,
   ``D`` the proxy's bounding-box diagonal and ``w_n`` the normal weight (Rohmer does not
   state the weighting); ``M`` clusters, 20 Lloyd iterations, **warm-started** from the
   previous update's centres (temporal coherence) or, the first time, k-means++ with the fixed
   seed. An emptied cluster restarts at the sample farthest from its centre.
3. **Integration.** Every direct texel joins its nearest centre (same metric); per cluster
   ``I_j = Σ L_k ΔA_k`` (Eq. 6, RGB, W/sr), ``area_j = Σ ΔA_k``, position and normal the
   intensity-weighted mean of its texels' (the centre of its light; the normal renormalised).
   The cluster becomes a one-sided Lambertian **disc** of that area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arlight.errors import InputError


def grey(x: np.ndarray) -> np.ndarray:
    """Mean over the last axis (RGB)."""
    return np.asarray(x, np.float64).mean(axis=-1)


def texel_pdf(intensity: np.ndarray) -> np.ndarray:
    """Normalised grey pdf ``(N,)`` over texels of RGB ``intensity (N, 3)`` (all 0 when there
    is no light)."""
    g = np.maximum(grey(intensity), 0.0)
    s = g.sum()
    return g / s if s > 0 else g


def sample_texels(pdf: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """``count`` texel indices drawn from ``pdf`` by inverse CDF with stratified uniforms
    (``(k + ξ_k)/count``, ξ from a generator seeded with ``seed``). Texels of zero pdf are
    never drawn."""
    cdf = np.cumsum(pdf)
    if len(cdf) == 0 or cdf[-1] <= 0:
        return np.zeros(0, np.int64)
    cdf /= cdf[-1]
    rng = np.random.default_rng(seed)
    u = (np.arange(count) + rng.random(count)) / count
    idx = np.searchsorted(cdf, u, side="right")
    idx = np.minimum(idx, len(cdf) - 1)
    # a zero-pdf texel shares its cdf value with the texel before it: side="right" skips it
    return idx


def features(position: np.ndarray, normal: np.ndarray, scale: float,
             normal_weight: float) -> np.ndarray:
    """k-means feature vectors ``(N, 6)``: position / scale and normal × weight."""
    return np.concatenate([np.asarray(position, np.float64) / scale,
                           np.asarray(normal, np.float64) * normal_weight], axis=1)


def nearest(x: np.ndarray, centres: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """Index of the nearest centre (Euclidean) for every row of ``x``."""
    out = np.empty(len(x), np.int64)
    c2 = (centres**2).sum(1)
    for s in range(0, len(x), chunk):
        xs = x[s:s + chunk]
        d = c2[None, :] - 2.0 * xs @ centres.T
        out[s:s + chunk] = np.argmin(d, axis=1)
    return out


def kmeans_pp(x: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """k-means++ initial centres (deterministic in ``seed``)."""
    rng = np.random.default_rng(seed)
    centres = [x[rng.integers(len(x))]]
    d2 = ((x - centres[0])**2).sum(1)
    for _ in range(1, k):
        s = d2.sum()
        i = int(rng.choice(len(x), p=d2 / s)) if s > 0 else int(rng.integers(len(x)))
        centres.append(x[i])
        d2 = np.minimum(d2, ((x - x[i])**2).sum(1))
    return np.array(centres)


def kmeans(x: np.ndarray, k: int, iterations: int = 20, init: np.ndarray | None = None,
           seed: int = 0) -> np.ndarray:
    """Lloyd's k-means on ``x (S, D)``: ``k`` centres after ``iterations`` steps, starting
    from ``init`` when it has ``k`` rows (warm start), else k-means++."""
    if init is not None and len(init) == k:
        c = np.array(init, np.float64, copy=True)
    else:
        c = kmeans_pp(x, k, seed)
    for _ in range(int(iterations)):
        lab = nearest(x, c)
        counts = np.bincount(lab, minlength=k)
        sums = np.zeros_like(c)
        np.add.at(sums, lab, x)
        full = counts > 0
        c[full] = sums[full] / counts[full, None]
        for j in np.flatnonzero(~full):  # restart an empty cluster at the worst sample
            d = ((x - c[lab])**2).sum(1)
            i = int(np.argmax(d))
            c[j] = x[i]
            lab[i] = j
    return c


@dataclass
class VALSet:
    """Clustered direct light.

    Attributes:
        positions, normals, intensity, area: as in :class:`~arlight.nearfield.state.
            NearFieldLight` (M rows).
        centres: (M, 6) k-means centres in feature space (the next update's warm start).
        labels: (N,) cluster of every texel (−1: not direct).
    """

    positions: np.ndarray
    normals: np.ndarray
    intensity: np.ndarray
    area: np.ndarray
    centres: np.ndarray
    labels: np.ndarray


def integrate(labels: np.ndarray, m: int, position: np.ndarray, normal: np.ndarray,
              area: np.ndarray, direct: np.ndarray) -> tuple[np.ndarray, ...]:
    """Eq. 6 per cluster: ``(positions, normals, intensity, area)`` of ``m`` clusters from
    texel ``labels`` (−1: ignored); empty clusters are dropped."""
    sel = labels >= 0
    lab = labels[sel]
    a = area[sel]
    inten = direct[sel] * a[:, None]
    g = np.maximum(grey(inten), 0.0)
    I = np.zeros((m, 3))
    A = np.zeros(m)
    W = np.zeros(m)
    P = np.zeros((m, 3))
    N = np.zeros((m, 3))
    np.add.at(I, lab, inten)
    np.add.at(A, lab, a)
    np.add.at(W, lab, g)
    np.add.at(P, lab, position[sel] * g[:, None])
    np.add.at(N, lab, normal[sel] * g[:, None])
    keep = W > 0
    P = P[keep] / W[keep, None]
    N = N[keep]
    ln = np.linalg.norm(N, axis=1)
    N = np.where(ln[:, None] > 1e-12, N / np.maximum(ln, 1e-300)[:, None], [0.0, 1.0, 0.0])
    return P, N, I[keep], A[keep]


def extract_vals(position: np.ndarray, normal: np.ndarray, area: np.ndarray,
                 direct: np.ndarray, is_direct: np.ndarray, m: int, scale: float,
                 samples: int = 4096, iterations: int = 20, normal_weight: float = 0.3,
                 init: np.ndarray | None = None, seed: int = 0,
                 timer=None) -> VALSet:
    """VALs of the direct atlas (module docstring). ``position, normal (N, 3)``, ``area
    (N,)``, ``direct (N, 3)`` and ``is_direct (N,)`` over the covered texels; ``scale``: D,
    m. ``timer``: optional StageTimer (stages ``sampling``, ``kmeans``, ``integrate``).

    Raises:
        InputError: ``m < 1``.
    """
    from contextlib import nullcontext

    if int(m) < 1:
        raise InputError(f"the number of VALs M must be >= 1, got {m}", field="vals")

    def stage(name):
        return timer.stage(name) if timer is not None else nullcontext()

    dsel = np.flatnonzero(is_direct)
    labels = np.full(len(area), -1, np.int64)
    if len(dsel) == 0:
        z = np.zeros((0, 3))
        return VALSet(z, z, z, np.zeros(0), np.zeros((0, 6)), labels)
    with stage("sampling"):
        pdf = texel_pdf(direct[dsel] * area[dsel, None])
        pick = dsel[sample_texels(pdf, samples, seed)]
        x = features(position[pick], normal[pick], scale, normal_weight)
    with stage("kmeans"):
        k = min(int(m), len(np.unique(x, axis=0)))
        centres = kmeans(x, k, iterations, init, seed)
    with stage("integrate"):
        f_all = features(position[dsel], normal[dsel], scale, normal_weight)
        labels[dsel] = nearest(f_all, centres)
        P, N, I, A = integrate(labels, k, position, normal, area, direct)
    return VALSet(P, N, I, A, centres, labels)


def vpl_lights(position: np.ndarray, normal: np.ndarray, area: np.ndarray,
               radiance: np.ndarray, count: int, seed: int = 0
               ) -> tuple[np.ndarray, ...]:
    """Classical VPLs (Eq. 15): ``count`` texels drawn from the grey-intensity pdf of
    ``radiance``, each ``I = I_s / (N p_s)``; ``(positions, normals, intensity, area)`` with
    the drawn texel's area (duplicates are kept as separate lights)."""
    inten = np.asarray(radiance, np.float64) * np.asarray(area, np.float64)[:, None]
    pdf = texel_pdf(inten)
    idx = sample_texels(pdf, count, seed)
    if len(idx) == 0:
        z = np.zeros((0, 3))
        return z, z, z, np.zeros(0)
    I = inten[idx] / (count * pdf[idx])[:, None]
    return position[idx], normal[idx], I, area[idx]


__all__ = ["VALSet", "extract_vals", "features", "grey", "integrate", "kmeans", "kmeans_pp",
           "nearest", "sample_texels", "texel_pdf", "vpl_lights"]
