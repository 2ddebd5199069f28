"""Splitting the radiance atlas into a direct and an indirect atlas (Rohmer §4.2).

``τ`` is the share of the **total** radiant intensity ``Σ L·ΔA`` that becomes direct light.
Per colour channel the texels are ordered by their radiant intensity ``L_c·ΔA`` (W/sr),
brightest first, and the shortest prefix holding at least ``τ`` of the channel's total is
the direct set; its texels go to the direct atlas, all others to the indirect atlas
(``L = L_dir + L_ind`` texel by texel). Rohmer finds the threshold from a histogram on the
GPU; sorting gives the exact prefix. The per-channel split keeps a coloured source on a
monochrome surface in the direct atlas (Rohmer §4.2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arlight.errors import InputError

DEFAULT_TAU = 0.6
"""The server's, the method's and ``arlight light atlas``'s default ``τ``: the best of
0.5–0.98 on cornell-near-field (benchmarks/RESULTS.md). Re-examined on generated worlds
(issue #30, ``benchmarks/tune_light_estimation.py``): the training rooms chose 0.75 of
{0.3, 0.45, 0.6, 0.75, 0.9} (on 2 rooms, one indifferent to τ within 0.25 dB), which was
worse than 0.6 on every held-out room; 0.6 stays (docs/methods/nearfield.md)."""


@dataclass
class SplitAtlas:
    """The direct and indirect radiance of the covered texels (flat).

    Attributes:
        direct: (N, 3) direct-atlas radiance, W/(sr·m²).
        indirect: (N, 3) the rest.
        is_direct: (N, 3) bool, per channel.
        threshold: (3,) intensity threshold per channel, W/sr (inf: nothing direct).
    """

    direct: np.ndarray
    indirect: np.ndarray
    is_direct: np.ndarray
    threshold: np.ndarray

    @property
    def any_direct(self) -> np.ndarray:
        """(N,) texels direct in at least one channel."""
        return self.is_direct.any(axis=1)


def check_tau(tau: float) -> float:
    """``tau`` as a float in [0, 1], or an InputError naming the field ``tau``."""
    t = float(tau)
    if not np.isfinite(t) or not 0.0 <= t <= 1.0:
        raise InputError(f"the direct share τ must be in [0, 1], got {tau}", field="tau")
    return t


def split(radiance: np.ndarray, area: np.ndarray, tau: float) -> SplitAtlas:
    """Split per channel (module docstring): ``radiance (N, 3)``, texel areas ``area (N,)``
    (m²). τ = 1 puts every texel with light into the direct atlas; τ = 0 none."""
    t = check_tau(tau)
    L = np.asarray(radiance, np.float64)
    a = np.asarray(area, np.float64)
    inten = L * a[:, None]
    is_dir = np.zeros(L.shape, bool)
    thr = np.full(3, np.inf)
    for c in range(3):
        total = inten[:, c].sum()
        if t == 0.0 or total <= 0:
            continue
        order = np.argsort(-inten[:, c], kind="stable")
        if t == 1.0:
            k = int(np.count_nonzero(inten[:, c] > 0))
        else:
            cum = np.cumsum(inten[order, c])
            k = int(np.searchsorted(cum, t * total, side="left")) + 1
            k = min(k, len(order))
        is_dir[order[:k], c] = True
        thr[c] = inten[order[k - 1], c]
    direct = np.where(is_dir, L, 0.0)
    return SplitAtlas(direct, L - direct, is_dir, thr)


__all__ = ["DEFAULT_TAU", "SplitAtlas", "check_tau", "split"]
