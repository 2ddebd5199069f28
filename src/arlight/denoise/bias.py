"""The bias of a (denoised) result: mean signed error against the ground truth by region.

    b = region_bias(composite, ground_truth, frame, mask)   # {"shadow": ..., ...}

A denoiser trades variance for bias; the bias is where it hides: shadows are brightened
(the denoiser blurs a dark, noisy delta), the virtual object loses contrast, silhouettes
bleed. Per region, the relative mean signed error of the luminance

    b_R = Σ_{p∈R} (Y(result_p) − Y(gt_p)) / Σ_{p∈R} Y(gt_p)

(dimensionless; +0.02: 2 % too bright on average). Regions, from the ground truth only (so
they are the same for every method):

* ``shadow`` — real pixels (mask 0 with a 1-pixel margin from the silhouette) that the
  insertion darkens by more than :data:`SHADOW_DROP` of the frame: ``gt < (1 − drop)·frame``.
* ``object`` — pixels fully covered by the virtual object (mask ≥ 0.999, eroded by a pixel).
* ``silhouette`` — the object's edge: 0 < mask < 0.999, grown by one pixel on both sides.

An empty region gives NaN. ``pixels_<region>`` counts each region's pixels.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

SHADOW_DROP = 0.05
"""Relative darkening of the frame from which a real pixel belongs to the shadow region."""


def luminance(img: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of ``(H, W, 3)`` linear RGB."""
    return img[..., 0] * 0.2126 + img[..., 1] * 0.7152 + img[..., 2] * 0.0722


def regions(ground_truth: np.ndarray, frame: np.ndarray, mask: np.ndarray
            ) -> dict[str, np.ndarray]:
    """``shadow``, ``object`` and ``silhouette`` masks ``(H, W)`` (see module docstring)."""
    m = np.asarray(mask, np.float64)
    full = m >= 0.999
    edge = (m > 0) & ~full
    near = ndimage.binary_dilation(m > 0, iterations=1)
    y_gt, y_f = luminance(ground_truth), luminance(frame)
    return {"shadow": ~near & (y_gt < (1.0 - SHADOW_DROP) * y_f),
            "object": ndimage.binary_erosion(full, iterations=1),
            "silhouette": ndimage.binary_dilation(edge, iterations=1)}


def region_bias(result: np.ndarray, ground_truth: np.ndarray, frame: np.ndarray,
                mask: np.ndarray) -> dict[str, float]:
    """Relative mean signed luminance error of ``result`` per region, plus the regions'
    pixel counts (``pixels_<region>``)."""
    out: dict[str, float] = {}
    y_r, y_gt = luminance(result).astype(np.float64), luminance(ground_truth).astype(np.float64)
    for name, reg in regions(ground_truth, frame, mask).items():
        n = int(reg.sum())
        den = float(y_gt[reg].sum())
        out[name] = float((y_r[reg] - y_gt[reg]).sum() / den) if n and den > 0 else float("nan")
        out[f"pixels_{name}"] = float(n)
    return out


__all__ = ["SHADOW_DROP", "luminance", "region_bias", "regions"]
