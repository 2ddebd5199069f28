"""Importance sampling of an equirect environment map with a 2D piecewise-constant CDF.

The density over the unit square ``(u, v)`` is proportional to luminance x ``sin theta``
per pixel (a marginal CDF over rows, a conditional CDF over columns; PBRT's
``Distribution2D``). Within a pixel, ``(u, v)`` is uniform, so the density with respect to
solid angle is ``p(w) = p_uv(u, v) / (2 pi^2 sin theta)`` (Jacobian of the equirect
parameterisation; Mitsuba's envmap emitter uses the same construction).
"""

from __future__ import annotations

import numpy as np

from arlight.sphere.envmap import direction_to_equirect
from arlight.sphere.sh import LUMINANCE


class EnvmapSampler:
    """Draw directions from an equirect map ``(H, W, 3)`` in proportion to its luminance.

    ``floor`` (relative to the mean weight) keeps every pixel sampleable, so black
    regions still have a finite, non-zero pdf (useful for MIS).

    >>> import numpy as np
    >>> s = EnvmapSampler(np.ones((8, 16, 3), np.float32))
    >>> d, pdf = s.sample(np.array([0.3]), np.array([0.6]))
    >>> bool(abs(pdf[0] - 1 / (4 * np.pi)) < 0.05)
    True
    """

    def __init__(self, image: np.ndarray, floor: float = 0.0) -> None:
        img = np.asarray(image, dtype=np.float64)
        lum = img[..., :3] @ LUMINANCE if img.ndim == 3 else img
        H, W = lum.shape
        self.height, self.width = H, W
        sin_t = np.sin((np.arange(H) + 0.5) * np.pi / H)
        w = np.clip(lum, 0.0, None) * sin_t[:, None]
        if floor > 0:
            w = w + floor * max(w.mean(), 1e-30) * sin_t[:, None]
        total = w.sum()
        if not np.isfinite(total) or total <= 0:
            w = np.broadcast_to(sin_t[:, None], (H, W)).copy()
            total = w.sum()
        # density over the unit square (integrates to 1)
        self.p_uv = w / total * (H * W)
        row = w.sum(axis=1)
        self._row_cdf = np.concatenate([[0.0], np.cumsum(row)]) / row.sum()
        rs = np.where(row > 0, row, 1.0)
        cols = np.concatenate([np.zeros((H, 1)), np.cumsum(w, axis=1)], axis=1)
        self._col_cdf = cols / rs[:, None]
        self._flat_cdf = (self._col_cdf + np.arange(H)[:, None]).ravel()

    def sample(self, u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map uniform numbers in [0, 1) to directions ``(N, 3)`` and their pdf with respect
        to solid angle ``(N,)`` (1/sr)."""
        u1 = np.atleast_1d(np.asarray(u1, np.float64))
        u2 = np.atleast_1d(np.asarray(u2, np.float64))
        H, W = self.height, self.width
        r = np.clip(np.searchsorted(self._row_cdf, u1, side="right") - 1, 0, H - 1)
        c0, c1 = self._row_cdf[r], self._row_cdf[r + 1]
        fv = np.where(c1 > c0, (u1 - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.5)
        # one searchsorted for all rows: row k's CDF is shifted into [k, k+1]
        idx = np.searchsorted(self._flat_cdf, r + u2, side="right") - 1
        c = np.clip(idx - r * (W + 1), 0, W - 1)
        a0, a1 = self._col_cdf[r, c], self._col_cdf[r, c + 1]
        fu = np.where(a1 > a0, (u2 - a0) / np.where(a1 > a0, a1 - a0, 1.0), 0.5)
        u = (c + np.clip(fu, 0, 1)) / W
        v = (r + np.clip(fv, 0, 1)) / H
        theta, phi = np.pi * v, 2 * np.pi * u
        st = np.sin(theta)
        d = np.stack([st * np.sin(phi), np.cos(theta), -st * np.cos(phi)], axis=-1)
        with np.errstate(divide="ignore"):
            pdf = np.where(st > 0, self.p_uv[r, c] / (2 * np.pi**2 * st), 0.0)
        return d, pdf

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        """Density (1/sr) of :meth:`sample` at the given unit directions ``(N, 3)``."""
        xy = direction_to_equirect(directions, self.height, self.width)
        c = np.clip(np.floor(xy[..., 0]).astype(int), 0, self.width - 1)
        r = np.clip(np.floor(xy[..., 1]).astype(int), 0, self.height - 1)
        st = np.sqrt(np.clip(1 - np.asarray(directions, np.float64)[..., 1] ** 2, 0, None))
        with np.errstate(divide="ignore"):
            return np.where(st > 0, self.p_uv[r, c] / (2 * np.pi**2 * st), 0.0)
