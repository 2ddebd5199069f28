"""Non-diffuse approximations of Rohmer §6.6 (digest §7).

* **Glossy** (Blinn-Phong): the VAL centre is the one representative sample of the specular
  lobe: ``L_s = k_s (e + 2)/(2π) ⟨n, h⟩⁺^e · I cos θ_j cos θ/(r² + R²)``, ``h`` the half
  vector of the directions to the VAL and to the eye; the diffuse part keeps PRT.
* **Metal**: Schlick's approximation rescaled for a complex index ``n + ik`` per channel,
  ``F(θ) = ((n−1)² + 4n(1−cos θ)⁵ + k²)/((n+1)² + k²)``, on the same lobe (exponent from the
  GGX roughness, ``e = 2/α² − 2``); no PRT diffuse term. :func:`eta_for_f0` picks ``n`` so
  that ``F(0°)`` equals the material's reflectance for a given ``k``.
* **Glass** composite (Eq. 16), ``L = max(f L_refl, L_direct) + (1 − f) T L_refr`` with the
  Beer–Lambert ``T = exp(−σ d)``; the ``nearfield`` method does not render glass (it has no
  image-space refraction pass), the formula is here for completeness of Eq. 16.
"""

from __future__ import annotations

import numpy as np


def schlick_complex(cos_theta, n, k):
    """Rescaled Schlick Fresnel for a complex IOR (module docstring); NumPy or Dr.Jit."""
    c = 1.0 - cos_theta
    c5 = c * c * c * c * c
    return ((n - 1.0) ** 2 + 4.0 * n * c5 + k * k) / ((n + 1.0) ** 2 + k * k)


def eta_for_f0(f0: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Real index ``n ≥ 1`` with ``((n−1)² + k²)/((n+1)² + k²) = f0`` (per channel; f0 is
    clamped to [k²/((1+1)²+k²)… , 0.999])."""
    f0 = np.clip(np.asarray(f0, np.float64), 0.0, 0.999)
    k2 = np.asarray(k, np.float64) ** 2
    # (1 - f0) n² - 2 (1 + f0) n + (1 - f0)(1 + k²) = 0
    a, b, c = 1.0 - f0, -2.0 * (1.0 + f0), (1.0 - f0) * (1.0 + k2)
    disc = np.maximum(b * b - 4 * a * c, 0.0)
    return np.maximum((-b + np.sqrt(disc)) / (2 * a), 1.0)


def phong_exponent(alpha: float) -> float:
    """Blinn-Phong exponent of a GGX / Beckmann roughness α (``2/α² − 2``, ≥ 1)."""
    a = max(float(alpha), 1e-3)
    return max(2.0 / (a * a) - 2.0, 1.0)


def glass_composite(f, l_reflected, l_direct, transmittance, l_refracted):
    """Eq. 16: ``max(f L_refl, L_direct) + (1 − f) T L_refr``."""
    return (np.maximum(f * np.asarray(l_reflected), np.asarray(l_direct))
            + (1.0 - f) * transmittance * np.asarray(l_refracted))


def beer_lambert(sigma, thickness):
    """``T = exp(−σ d)`` (σ in 1/m, d in m)."""
    return np.exp(-np.asarray(sigma, np.float64) * np.asarray(thickness, np.float64))


__all__ = ["beer_lambert", "eta_for_f0", "glass_composite", "phong_exponent",
           "schlick_complex"]
