"""The world-fixed visibility directions of Gruber et al. 2014 and their interleaved subsets.

Gruber §3.2 casts visibility rays along ``N = 81`` directions fixed in *world* space (a
"spherical visibility space") and, with interleaving, only the subset ``f mod k`` of them in
frame ``f``; each subset must "evenly sample the entire visibility space". We use a spherical
Fibonacci point set (equal area, so the quadrature weight is ``w = 4π/N`` sr, digest E3) and
the subsets ``j ≡ s (mod k)``: for ``N = 81, k = 4`` they have 21/20/20/20 directions and
each subset is itself a near-uniform Fibonacci-like spiral (mean vector norm < 0.03).

The SH basis on the directions is that of :mod:`arlight.sphere.sh` (our convention,
``docs/conventions.md``), 4 bands = 16 coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from arlight.sphere import sh as SH
from arlight.sphere.points import fibonacci_sphere

N_DIRECTIONS = 81
"""Visibility ray directions per sample point (Gruber §3.2)."""
SH_ORDER = 3
"""SH order L of the transfer and the light: 4 bands, ``(L+1)² = 16`` coefficients."""
N_COEFFS = SH.n_coeffs(SH_ORDER)


@dataclass(frozen=True)
class DirectionSet:
    """``n`` world-space directions split into ``k`` interleaved subsets.

    Attributes:
        n: number of directions (81 in the paper).
        k: interleave interval in frames (4 in the paper; 1 = every direction every frame).
    """

    n: int = N_DIRECTIONS
    k: int = 4

    def __post_init__(self) -> None:
        if self.k < 1 or self.k > self.n:
            raise ValueError(f"interleave k must be in [1, {self.n}], got {self.k}")

    @cached_property
    def directions(self) -> np.ndarray:
        """Unit directions ``(n, 3)``, world space."""
        d = fibonacci_sphere(self.n)
        d.setflags(write=False)
        return d

    @property
    def weight(self) -> float:
        """Quadrature weight per direction, ``4π/n`` sr (equal-area set)."""
        return 4.0 * np.pi / self.n

    @cached_property
    def basis(self) -> np.ndarray:
        """``Y_k(ω_j)`` ``(n, 16)`` in our SH convention."""
        y = SH.sh_basis(self.directions, SH_ORDER)
        y.setflags(write=False)
        return y

    def subset(self, phase: int) -> np.ndarray:
        """Indices of the directions of interleave phase ``phase mod k``: ``j ≡ phase (mod k)``."""
        return np.arange(phase % self.k, self.n, self.k)

    def subsets(self) -> list[np.ndarray]:
        """All ``k`` subsets, in phase order (disjoint, union = every direction)."""
        return [self.subset(s) for s in range(self.k)]


def unoccluded_transfer(normals: np.ndarray) -> np.ndarray:
    """Analytic unshadowed transfer ``T_lm(n) = Â_l Y_lm(n)`` ``(M, 16)`` (digest E6), with
    ``Â = π, 2π/3, π/4, 0`` for bands 0..3 (Ramamoorthi & Hanrahan 2001)."""
    Y = SH.sh_basis(np.asarray(normals, np.float64), SH_ORDER)
    A = np.array([SH.clamped_cosine_band(int(lb)) for lb in SH.band_of_each_coeff(SH_ORDER)])
    return Y * A[None, :]


__all__ = ["N_COEFFS", "N_DIRECTIONS", "SH_ORDER", "DirectionSet", "fibonacci_sphere",
           "unoccluded_transfer"]
