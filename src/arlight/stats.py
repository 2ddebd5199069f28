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


def welch_dof(se_a: np.ndarray, dof_a: float, se_b: np.ndarray | float,
              dof_b: float) -> np.ndarray:
    """Welch–Satterthwaite degrees of freedom of ``sqrt(se_a² + se_b²)``:
    ``(va + vb)² / (va²/dof_a + vb²/dof_b)`` with ``v = se²`` (``inf``: exact variance)."""
    va = np.square(np.asarray(se_a, np.float64))
    vb = np.square(np.asarray(se_b, np.float64))
    den = va * va / dof_a + vb * vb / dof_b
    with np.errstate(divide="ignore", invalid="ignore"):
        nu = np.square(va + vb) / den
    return np.where(den > 0, nu, np.inf)


def t_threshold(k: float, dof: np.ndarray | float) -> np.ndarray:
    """The Student-t quantile with ``dof`` degrees of freedom whose two-sided tail equals
    the normal tail beyond ``k`` (``k`` itself for ``dof = inf``): a standard error estimated
    from few independent replicas needs a wider band for the same false-alarm rate."""
    from scipy import stats as sps

    dof = np.asarray(dof, np.float64)
    tail = sps.norm.sf(k)
    out = sps.t.isf(tail, np.where(np.isfinite(dof), np.maximum(dof, 1.0), 1.0))
    return np.where(np.isfinite(dof), out, k)


def agreement_fraction(a: np.ndarray, se_a: np.ndarray, b: np.ndarray,
                       se_b: np.ndarray | float = 0.0, k: float = 3.0,
                       floor: float = 1e-6, dof_a: float = np.inf,
                       dof_b: float = np.inf) -> float:
    """Fraction of pixels (max over channels) whose difference is within ``k`` standard errors.

    The acceptance rule used throughout arlight: two unbiased estimators agree when this is
    ≥ 0.99 with ``k = 3``. ``dof_a``/``dof_b``: degrees of freedom of the standard errors
    (``Layers.stats["stderr_dof"]`` of a method whose errors come from a few replicas); the
    band is then widened per pixel to the Student-t quantile of the same tail probability
    (Welch–Satterthwaite), so few-replica errors are not rejected for their own noise.
    """
    z = z_scores(a, se_a, b, se_b, floor)
    if np.isfinite(dof_a) or np.isfinite(dof_b):
        z = z / t_threshold(k, welch_dof(se_a, dof_a, se_b, dof_b)) * k
    if z.ndim == 3:
        z = z.max(axis=2)
    return float(np.mean(z <= k))
