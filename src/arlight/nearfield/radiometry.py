"""Direct light from texels (Eq. 4) and from virtual area lights (Eqs. 5, 7), NumPy.

Receiver at ``x`` with unit normal ``n`` and diffuse albedo ρ (``f_r = ρ/π``); a sender at
``p`` with unit normal ``m``, radiant intensity ``I`` along ``m`` (W/sr) and area ``A``:

    L = ρ/π · I · cos θ_j cos θ / (r² + R²)          (Eq. 5 with a disc of radius R)

``cos θ_j = ⟨n, p − x⟩⁺/r`` at the receiver, ``cos θ = ⟨m, x − p⟩⁺/r`` at the sender,
``R² = A/π`` (``disc=True``; exact on the axis of a Lambertian disc, and it removes the 1/r²
singularity) or 0 (a point: Eq. 4 per texel with ``I = L ΔA``).
"""

from __future__ import annotations

import numpy as np


def geometry_terms(x: np.ndarray, n: np.ndarray, p: np.ndarray, m: np.ndarray,
                   area: np.ndarray, disc: bool = True) -> np.ndarray:
    """``cos θ_j cos θ / (r² + R²)`` ``(X, L)`` for receivers ``x, n (X, 3)`` and senders
    ``p, m (L, 3)``, ``area (L,)`` (m⁻²)."""
    d = np.asarray(p, np.float64)[None] - np.asarray(x, np.float64)[:, None]  # (X, L, 3)
    r2 = (d * d).sum(-1)
    r = np.sqrt(np.maximum(r2, 1e-300))
    cj = np.clip(np.einsum("xi,xli->xl", n, d) / r, 0.0, None)
    cs = np.clip(-np.einsum("li,xli->xl", m, d) / r, 0.0, None)
    r_disc = np.asarray(area, np.float64)[None] / np.pi if disc else 0.0
    return cj * cs / (r2 + r_disc)


def direct_radiance(x: np.ndarray, n: np.ndarray, albedo: np.ndarray, p: np.ndarray,
                    m: np.ndarray, intensity: np.ndarray, area: np.ndarray,
                    visibility: np.ndarray | None = None, disc: bool = True) -> np.ndarray:
    """Eq. 7: ``Σ_j V_j · ρ/π · I_j G_j`` ``(X, 3)`` (Eq. 4 when every texel is a sender and
    ``disc=False``); ``visibility (X, L)`` optional (1)."""
    g = geometry_terms(x, n, p, m, area, disc)
    if visibility is not None:
        g = g * visibility
    return np.asarray(albedo, np.float64) / np.pi * (g @ np.asarray(intensity, np.float64))


__all__ = ["direct_radiance", "geometry_terms"]
