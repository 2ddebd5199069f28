"""Image metrics for AR composites against ground truth.

Conventions (all functions take NumPy ``(H, W, 3)`` images; ``test`` is the method's output,
``ref`` the ground truth):

* **Radiance** metrics work on linear radiance W/(sr·m²) (``rmse``, ``psnr`` with the
  reference's peak, HDR-FLIP).
* **Display** metrics work on the display image ``encode(clip(radiance · 2^exposure))`` in
  [0, 1] — what a viewer sees through the camera's transfer function
  (:class:`arlight.camera_response.Transfer`): PSNR with R = 1, SSIM, LDR-FLIP, error heat maps.
* A ``region`` is a boolean ``(H, W)`` mask; a metric "on the region" averages only over its
  pixels (see :func:`changed_region`).

PSNR follows Franke (thesis Eq. 5.28): ``PSNR = 10·log10(R² / MSE)``, ``R`` the maximum pixel
value. On display images ``R = 1`` (the largest code value, normalised). On radiance ``R`` is
the maximum of the *reference* (ground-truth) image over the evaluated pixels, so the score
does not reward a method for producing a bright outlier. Identical images (MSE = 0) give
:data:`PSNR_CAP` = 100 dB instead of infinity so that tables, JSON and plots stay finite.
"""

from __future__ import annotations

import math

import numpy as np

from arlight.camera_response import Transfer

PSNR_CAP = 100.0  # dB, returned for identical images (MSE = 0)

# Rec. 709 / sRGB luminance weights, used for the signed error of colour images.
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _region(img: np.ndarray, region: np.ndarray | None) -> np.ndarray:
    """Pixels of ``img`` inside ``region`` as ``(N, C)`` (all pixels when region is None)."""
    a = np.asarray(img, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if region is None:
        return a.reshape(-1, a.shape[-1])
    region = np.asarray(region, dtype=bool)
    if region.shape != a.shape[:2]:
        raise ValueError(f"region shape {region.shape} != image shape {a.shape[:2]}")
    return a[region]


def _check(test: np.ndarray, ref: np.ndarray) -> None:
    if np.shape(test) != np.shape(ref):
        raise ValueError(f"image shapes differ: {np.shape(test)} vs {np.shape(ref)}")


def mse(test: np.ndarray, ref: np.ndarray, region: np.ndarray | None = None) -> float:
    """Mean squared error over pixels and channels (NaN for an empty region)."""
    _check(test, ref)
    d = _region(test, region) - _region(ref, region)
    return float(np.mean(d * d)) if d.size else math.nan


def rmse(test: np.ndarray, ref: np.ndarray, region: np.ndarray | None = None) -> float:
    """Root mean squared error, in the images' units."""
    return math.sqrt(mse(test, ref, region))


def psnr(test: np.ndarray, ref: np.ndarray, peak: float | None = None,
         region: np.ndarray | None = None, cap: float = PSNR_CAP) -> float:
    """Peak signal-to-noise ratio ``10·log10(R²/MSE)`` in dB (Franke Eq. 5.28).

    Args:
        peak: ``R``; default the maximum of ``ref`` over the evaluated pixels (pass 1.0 for
            display images in [0, 1]).
        cap: value returned when MSE = 0 (identical images); results are also limited to it.
    """
    e = mse(test, ref, region)
    if math.isnan(e):
        return math.nan
    r = float(np.max(_region(ref, region))) if peak is None else float(peak)
    if e == 0.0:
        return cap
    if r <= 0.0:
        return -math.inf
    return min(cap, 10.0 * math.log10(r * r / e))


def display(radiance: np.ndarray, transfer: Transfer) -> np.ndarray:
    """Display image in [0, 1] (float64): ``encode(clip(radiance · 2^exposure))``."""
    y = np.nan_to_num(np.asarray(radiance, dtype=np.float64) * transfer.scale, nan=0.0,
                      posinf=1.0, neginf=0.0)
    return transfer.encode(y)


def ssim(test: np.ndarray, ref: np.ndarray, region: np.ndarray | None = None) -> float:
    """Mean structural similarity (scikit-image, Wang et al. 2004) of two display images in
    [0, 1]; 1 for identical images. With ``region`` the SSIM map is averaged over it."""
    from skimage.metrics import structural_similarity

    _check(test, ref)
    h, w = np.shape(ref)[:2]
    win = min(7, h, w)
    win -= 1 - win % 2  # odd window, at most the image size
    if win < 3:
        return math.nan
    _, smap = structural_similarity(np.asarray(ref, np.float64), np.asarray(test, np.float64),
                                    channel_axis=2, data_range=1.0, win_size=win, full=True)
    vals = _region(smap, region)
    return float(np.mean(vals)) if vals.size else math.nan


def flip_map(test: np.ndarray, ref: np.ndarray, hdr: bool = False) -> np.ndarray:
    """Per-pixel FLIP error ``(H, W)`` in [0, 1] (flip-evaluator; Andersson et al. 2020/2021).

    LDR-FLIP expects display images in [0, 1] (sRGB-encoded); HDR-FLIP expects non-negative
    linear radiance (already multiplied by ``2^exposure``) and sweeps exposures computed from
    the reference. 0 means identical.
    """
    import flip_evaluator as flip

    _check(test, ref)
    r = np.ascontiguousarray(np.clip(ref, 0.0, None), dtype=np.float32)
    t = np.ascontiguousarray(np.clip(test, 0.0, None), dtype=np.float32)
    if not hdr:
        r, t = np.clip(r, 0.0, 1.0), np.clip(t, 0.0, 1.0)
    err, _, _ = flip.evaluate(r, t, "HDR" if hdr else "LDR", applyMagma=False)
    return np.asarray(err, dtype=np.float64).reshape(r.shape[:2])


def flip(test: np.ndarray, ref: np.ndarray, hdr: bool = False,
         region: np.ndarray | None = None) -> float:
    """Mean FLIP error (0 = identical) over the image or ``region``."""
    vals = _region(flip_map(test, ref, hdr), region)
    return float(np.mean(vals)) if vals.size else math.nan


def signed_error(test: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per-pixel signed luminance error ``Y(test) − Y(ref)`` ``(H, W)``: > 0 too bright."""
    _check(test, ref)
    d = np.asarray(test, np.float64) - np.asarray(ref, np.float64)
    return d @ LUMA if d.ndim == 3 else d


def heatmap(err: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """Colour a signed error ``(H, W)`` as ``(H, W, 3)`` uint8, Franke's Fig. 5.19 style.

    ``t = clip(gain · |err|, 0, 1)``; too bright (err > 0): black → blue (t = ½) → white
    (t = 1); too dark (err < 0): black → red (t = ½) → yellow (t = 1); exact: black.
    """
    err = np.asarray(err, dtype=np.float64)
    t = np.clip(gain * np.abs(err), 0.0, 1.0)
    lo, hi = np.clip(2.0 * t, 0.0, 1.0), np.clip(2.0 * t - 1.0, 0.0, 1.0)
    bright = np.stack([hi, hi, lo], axis=-1)  # blue, then white
    dark = np.stack([lo, hi, np.zeros_like(t)], axis=-1)  # red, then yellow
    rgb = np.where((err > 0)[..., None], bright, np.where((err < 0)[..., None], dark, 0.0))
    return np.rint(rgb * 255.0).astype(np.uint8)


def changed_region(frame: np.ndarray, ground_truth: np.ndarray, mask: np.ndarray,
                   frame_stderr: np.ndarray | None = None,
                   gt_stderr: np.ndarray | None = None, k: float = 3.0,
                   tol: float = 1e-6) -> np.ndarray:
    """The pixels a virtual object changes: ``(H, W)`` bool.

    A pixel is in the region when the virtual objects cover it (``mask > 0``) or the ground
    truth differs *significantly* from the frame in any channel: ``|GT − I_c| >
    k·sqrt(se_GT² + se_c²) + tol`` (with standard errors; without them ``> tol``). This is the
    real region the object relights (shadows, colour bleeding, reflections, caustics) plus
    the object itself; outside it every method should return the frame, so whole-image
    metrics are diluted by its size (Gruber 2014 §7).
    """
    d = np.abs(np.asarray(ground_truth, np.float64) - np.asarray(frame, np.float64))
    se = 0.0
    if frame_stderr is not None or gt_stderr is not None:
        se = np.sqrt(np.square(0.0 if frame_stderr is None else frame_stderr)
                     + np.square(0.0 if gt_stderr is None else gt_stderr))
    changed = (d > k * se + tol)
    if changed.ndim == 3:
        changed = changed.any(axis=2)
    return changed | (np.asarray(mask) > 0)


def temporal_flicker(tests: list[np.ndarray] | np.ndarray,
                     refs: list[np.ndarray] | np.ndarray | None = None) -> float:
    """Mean absolute frame-to-frame change of the error of a sequence.

    ``e_t = test_t − ref_t`` (or ``test_t`` alone without references);
    ``flicker = mean_t mean_pixels |e_{t+1} − e_t|``. A method whose error is constant in
    time (even if large) scores 0; Monte Carlo noise and unstable caches score > 0.
    """
    tests = np.asarray(tests, dtype=np.float64)
    if tests.shape[0] < 2:
        raise ValueError("temporal_flicker needs at least two frames")
    err = tests if refs is None else tests - np.asarray(refs, dtype=np.float64)
    return float(np.mean(np.abs(np.diff(err, axis=0))))


def image_metrics(test: np.ndarray, ref: np.ndarray, transfer: Transfer,
                  region: np.ndarray | None = None, prefix: str = "") -> dict[str, float]:
    """All scalar metrics of one radiance image against its reference.

    Keys (with ``prefix``): ``rmse`` (radiance), ``psnr_hdr`` (radiance, R = max of ref),
    ``psnr`` (display, R = 1), ``ssim`` (display), ``flip`` (LDR-FLIP, display), ``hdr_flip``
    (HDR-FLIP on radiance · 2^exposure).
    """
    dt, dr = display(test, transfer), display(ref, transfer)
    s = transfer.scale
    out = {
        "rmse": rmse(test, ref, region),
        "psnr_hdr": psnr(test, ref, region=region),
        "psnr": psnr(dt, dr, peak=1.0, region=region),
        "ssim": ssim(dt, dr, region),
        "flip": flip(dt, dr, hdr=False, region=region),
        "hdr_flip": flip(np.asarray(test) * s, np.asarray(ref) * s, hdr=True, region=region),
    }
    return {prefix + k: v for k, v in out.items()}
