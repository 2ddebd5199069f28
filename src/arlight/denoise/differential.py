"""Denoised differential rendering: denoise what the method rendered, never the photograph.

    out = denoise_layers(layers, DenoiseSettings(), aux=lambda rows, cols: ...)

The composite stays Kán Eq. 2.20 / Franke Eq. 3.3, with the noisy layers replaced by
denoised ones (``D``: OIDN, :func:`arlight.denoise.oidn.denoise_rgb`):

    I_f = M ⊙ D(I_m) + (1 − M) ⊙ (I_c + Δ_D),   Δ_D = F ⊙ (D(I_m) − D(I_r))     (separate)
                                                Δ_D = F ⊙ (D(Δ⁺) − D(Δ⁻))        (delta)

``I_c`` (the photograph) never enters the denoiser. ``F`` is the insertion's *footprint*
(:func:`footprint`): the pixels where the raw delta is non-zero or the mask covers, dilated
by :func:`footprint_radius` pixels so that the denoiser may fill shadow pixels whose few
samples happened to miss the object. Outside ``F`` the delta is exactly 0 and the mask 0, so
the composite is the photograph bit for bit (:func:`arlight.layers.composite` adds the delta
as one term). Only the bounding box of ``F`` plus :data:`CONTEXT_PX` pixels of context is
denoised (the time is proportional to it); ``mixed`` outside the box keeps its raw values
(no composite pixel reads them: ``M = 0`` there).

``separate`` (default): ``I_m`` and ``I_r`` share the auxiliary buffers and one OIDN
exposure (:func:`arlight.denoise.oidn.auto_scale` of both), so where they agree over the
filter's receptive field their denoised difference is exactly 0, and the delta of a shadow
is the difference of two images denoised alike. ``delta``: the signed delta split into its
positive and negative parts (OIDN's HDR input is non-negative), each denoised with its own
exposure; ``I_m`` is denoised for the virtual pixels.

The result is a :class:`DenoisedLayers`: a :class:`~arlight.layers.Layers` whose ``noisy``
holds the method's raw layers with their standard errors (the unbiased estimate, for
error bars and for the unbiasedness tests); its own ``stderr`` is empty (a denoised pixel
has no Monte Carlo standard error) and its ``stats`` add ``denoise_pixels`` (pixels given
to the denoiser per image), ``denoise_runs`` and ``footprint_pixels``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from arlight.denoise.oidn import auto_scale, check_device, denoise_rgb
from arlight.denoise.options import DenoiseSettings
from arlight.layers import Layers

CONTEXT_PX = 16
"""Pixels of context around the footprint's bounding box handed to the denoiser."""

AuxFn = Callable[[slice, slice], object]
"""``aux(rows, cols) -> AuxBuffers`` of that window (:func:`arlight.denoise.aux.aux_buffers`)."""


@dataclass
class DenoisedLayers(Layers):
    """Layers with denoised ``mixed``, ``real``, ``delta`` and composite; ``noisy`` keeps
    the method's raw layers (and their standard errors)."""

    noisy: Layers | None = None


def footprint_radius(width: int) -> int:
    """Dilation of the footprint, px: 1/80 of the image width, at least 2 (8 px at 640)."""
    return max(2, round(width / 80))


def footprint(delta: np.ndarray, mask: np.ndarray, radius: int) -> np.ndarray:
    """``(H, W)`` bool: pixels with a non-zero raw delta or mask, dilated by ``radius`` px
    (a disc)."""
    seed = np.any(delta != 0, axis=-1) | (np.asarray(mask) > 0)
    if radius <= 0 or not seed.any():
        return seed
    y, x = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return ndimage.binary_dilation(seed, structure=x * x + y * y <= radius * radius)


def window(region: np.ndarray, margin: int) -> tuple[slice, slice]:
    """Bounding box of ``region``'s True pixels, grown by ``margin`` px and clipped."""
    rows = np.flatnonzero(region.any(axis=1))
    cols = np.flatnonzero(region.any(axis=0))
    h, w = region.shape
    return (slice(max(0, rows[0] - margin), min(h, rows[-1] + 1 + margin)),
            slice(max(0, cols[0] - margin), min(w, cols[-1] + 1 + margin)))


def _runner(settings: DenoiseSettings, aux) -> tuple[Callable[..., np.ndarray], list[int]]:
    runs = [0]
    albedo = None if aux is None else aux.albedo
    normal = None if aux is None else aux.normal

    def run(img: np.ndarray, scale: float | None) -> np.ndarray:
        if not np.any(img > 0):
            return np.zeros_like(img)  # D(0) = 0: nothing to denoise
        runs[0] += 1
        return denoise_rgb(img, albedo, normal, settings.quality, scale, settings.device)

    return run, runs


def denoise_layers(layers: Layers, settings: DenoiseSettings,
                   aux: AuxFn | None = None) -> DenoisedLayers:
    """Denoise a method's layers (see the module docstring for the equations).

    Args:
        layers: the raw Monte Carlo layers (``real`` may be None: ``I_r = I_m − Δ``).
        settings: quality, auxiliary buffers on/off, ``separate`` or ``delta``.
        aux: the auxiliary buffers of a window (called once, with the denoised window), or
            None for colour-only denoising.

    Returns:
        :class:`DenoisedLayers` (``noisy`` = ``layers``).
    """
    check_device(settings.device)
    h, w = layers.mixed.shape[:2]
    fp = footprint(layers.delta, layers.mask, footprint_radius(w))
    stats = {**layers.stats, "footprint_pixels": float(fp.sum()), "denoise_pixels": 0.0,
             "denoise_runs": 0.0}
    keep = dict(background=layers.background, mask=layers.mask, stats=stats,
                method=layers.method, noisy=layers)
    if not fp.any():  # nothing inserted: the raw layers (delta 0, composite = photo)
        return DenoisedLayers(mixed=layers.mixed, delta=layers.delta, real=layers.real,
                              composite=layers.composite, **keep)
    rows, cols = window(fp, CONTEXT_PX)
    box = (rows, cols)
    run, runs = _runner(settings, None if aux is None or not settings.aux
                        else aux(rows, cols))
    real = layers.real if layers.real is not None else layers.mixed - layers.delta
    im, ir = layers.mixed[box], real[box]
    if settings.target == "separate":
        scale = auto_scale(im, ir)
        dm, dr_ = run(im, scale), run(ir, scale)
        d_box = dm - dr_
    elif settings.target == "delta":
        dm, dr_ = run(im, None), None
        d = layers.delta[box]
        pos, neg = np.maximum(d, 0.0), np.maximum(-d, 0.0)
        scale = auto_scale(pos, neg)
        d_box = run(pos, scale) - run(neg, scale)
    else:
        raise ValueError(f"denoise target must be 'separate' or 'delta', got "
                         f"{settings.target!r}")
    delta = np.zeros_like(layers.delta)
    delta[box] = d_box
    delta[~fp] = 0.0
    mixed = layers.mixed.copy()
    mixed[box] = dm
    real_out = layers.real
    if dr_ is not None and layers.real is not None:
        real_out = layers.real.copy()
        real_out[box] = dr_
    stats.update(denoise_pixels=float((rows.stop - rows.start) * (cols.stop - cols.start)),
                 denoise_runs=float(runs[0]))
    out = Layers.assemble(layers.background, mixed, delta, layers.mask, real=real_out)
    return DenoisedLayers(**{**vars(out), **keep, "stderr": {}})


class RunningLayers:
    """Running means of a method's raw layers over progressive frames (Kán Eq. 4.12 per
    layer, float64): with ``denoise = oidn`` the refinement denoises the mean of the raw
    frames, never a mean of denoised frames (whose bias would not fall with more samples).
    At silhouettes the composite of the mean layers differs from the mean of the composites
    by the covariance of ``M`` and ``I_m`` over frames (a partial-coverage pixel only)."""

    def __init__(self) -> None:
        self.count = 0
        self.sums: dict[str, np.ndarray] = {}
        self.background: np.ndarray | None = None

    def add(self, layers: Layers) -> Layers:
        """Fold in one frame's raw layers; returns the layers of the running means."""
        raw = undenoised(layers)
        real = raw.real if raw.real is not None else raw.mixed - raw.delta
        self.count += 1
        self.background = raw.background
        for k, v in (("mixed", raw.mixed), ("real", real), ("delta", raw.delta),
                     ("mask", raw.mask)):
            v = np.asarray(v, np.float64)
            self.sums[k] = self.sums[k] + v if k in self.sums else v.copy()
        m = {k: (v / self.count).astype(np.float32) for k, v in self.sums.items()}
        return Layers.assemble(self.background, m["mixed"], m["delta"], m["mask"],
                               real=m["real"], stats={"frames": float(self.count)},
                               method=raw.method)


def undenoised(layers: Layers) -> Layers:
    """The raw Monte Carlo layers behind ``layers`` (``layers`` itself when not
    denoised)."""
    noisy = getattr(layers, "noisy", None)
    return noisy if noisy is not None else layers


__all__ = ["CONTEXT_PX", "DenoisedLayers", "RunningLayers", "denoise_layers", "footprint",
           "footprint_radius", "undenoised", "window"]


