"""Monte Carlo agreement statistics shared by tests, benchmarks and the evaluation harness."""

from __future__ import annotations

import numpy as np


def z_scores(a: np.ndarray, se_a: np.ndarray, b: np.ndarray, se_b: np.ndarray | float = 0.0,
             floor: float = 1e-6) -> np.ndarray:
    """Per-pixel ``|a − b| / sqrt(se_a² + se_b²)`` for two independent estimates.

    ``floor`` (absolute, in the images' units) keeps deterministic pixels (zero standard
    error on both sides, e.g. both exactly 0) from dividing by zero: there the difference
    itself must be below ``floor``.
    """
    se = np.sqrt(np.square(se_a) + np.square(se_b) + floor * floor)
    return np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)) / se


def agreement_fraction(a: np.ndarray, se_a: np.ndarray, b: np.ndarray,
                       se_b: np.ndarray | float = 0.0, k: float = 3.0,
                       floor: float = 1e-6) -> float:
    """Fraction of pixels (max over channels) whose difference is within ``k`` standard errors.

    The acceptance rule used throughout arlight: two unbiased estimators agree when this is
    ≥ 0.99 with ``k = 3``.
    """
    z = z_scores(a, se_a, b, se_b, floor)
    if z.ndim == 3:
        z = z.max(axis=2)
    return float(np.mean(z <= k))
