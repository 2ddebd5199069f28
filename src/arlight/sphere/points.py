"""Point sets on the unit sphere."""

from __future__ import annotations

import numpy as np


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` spherical Fibonacci unit directions ``(n, 3)`` (equal-area, +Y is the pole): the
    quadrature weight of each is ``4π/n`` sr."""
    if n < 1:
        raise ValueError(f"need at least one direction, got {n}")
    i = np.arange(n, dtype=np.float64)
    y = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.clip(1.0 - y * y, 0.0, None))
    golden = np.pi * (3.0 - np.sqrt(5.0))
    phi = golden * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


__all__ = ["fibonacci_sphere"]
