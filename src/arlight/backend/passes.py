"""Pixel estimates from many samples, in passes, with per-pixel standard errors.

A render of ``spp`` samples per pixel is split into passes of ``spp_per_pass`` samples so
memory stays bounded; each pass is one wavefront of ``n · W · H`` lanes laid out
pixel-major (lane ``l`` → pixel ``l // n``, sample ``l % n``), so a pixel's samples are
neighbours (coherent rays) and the per-pixel sums are block reductions done by Dr.Jit in
the same kernel. A *kernel* turns the lanes' camera rays into named per-lane values
(radiance, mask, ...); :func:`run_passes` sums them and their squares per pixel, so every
layer comes with the standard error of its mean.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from arlight.backend.camera_rays import generate_rays
from arlight.scene.camera import Camera

Kernel = Callable[[mi.RayDifferential3f, mi.UInt32, mi.UInt32, int],
                  dict[str, mi.Float | mi.Color3f]]
"""kernel(rays, pixel_index, sampler_seed, n_lanes) -> {name: per-lane Float or Color3f}"""


@dataclass
class PixelMoments:
    """Running per-pixel sums of a sampled quantity ``(H, W, C)`` (float64)."""

    total: np.ndarray
    total_sq: np.ndarray
    count: int = 0

    @property
    def mean(self) -> np.ndarray:
        return self.total / max(self.count, 1)

    @property
    def variance(self) -> np.ndarray:
        """Unbiased per-sample variance."""
        n = self.count
        if n < 2:
            return np.full_like(self.total, np.inf)
        return np.maximum(self.total_sq - self.total * self.total / n, 0.0) / (n - 1)

    @property
    def stderr(self) -> np.ndarray:
        """Standard error of the per-pixel mean."""
        return np.sqrt(self.variance / max(self.count, 1))


@dataclass
class PassResult:
    """Moments of every kernel output plus timing and lane counts."""

    moments: dict[str, PixelMoments] = field(default_factory=dict)
    seconds: float = 0.0
    lanes: int = 0


def _to_image(x, height: int, width: int) -> np.ndarray:
    """Per-pixel Dr.Jit values (Float or 3-vector) -> ``(H, W, C)`` float64."""
    a = np.array(x, dtype=np.float64)
    a = a[:, None] if a.ndim == 1 else a.T  # Dr.Jit 3-vectors convert channel-major (3, N)
    return a.reshape(height, width, a.shape[-1])


def run_passes(camera: Camera, spp: int, kernel: Kernel, seed: int = 0,
               spp_per_pass: int | None = None, progress: str | None = None,
               max_lanes: int = 2_000_000) -> PassResult:
    """Evaluate ``kernel`` on ``spp`` camera samples per pixel and accumulate moments.

    Args:
        camera: the camera whose rays are traced.
        spp: samples per pixel in total (stratified when a perfect square).
        kernel: per-lane estimator (see :data:`Kernel`).
        seed: master seed; the same seed gives bitwise identical results.
        spp_per_pass: samples per pass (default: as many as fit in ``max_lanes``).
        progress: label for a progress bar (None: silent).
    """
    w, h = camera.width, camera.height
    n_pix = w * h
    per_pass = spp_per_pass or max(1, min(spp, max_lanes // n_pix))
    result = PassResult()
    start = time.perf_counter()
    bar = _progress(progress, spp)
    try:
        k0 = 0
        while k0 < spp:
            n = min(per_pass, spp - k0)
            lanes = n * n_pix
            idx = dr.arange(mi.UInt32, lanes)
            pixel = idx // n
            k = idx % n + dr.opaque(mi.UInt32, k0)
            rays = generate_rays(camera, pixel, k, spp, dr.opaque(mi.UInt32, seed))
            pass_seed = dr.opaque(mi.UInt32, (seed * 0x9E3779B1 + k0 * 0x85EBCA77) & 0xFFFFFFFF)
            outputs = kernel(rays, pixel, pass_seed, lanes)
            dr.eval(outputs)  # one render kernel; the reductions below read its results
            sums = {name: (dr.block_sum(v, n), dr.block_sum(v * v, n))
                    for name, v in outputs.items()}
            dr.eval(sums)
            for name, (total, total_sq) in sums.items():
                mom = result.moments.get(name)
                if mom is None:
                    shape = (h, w, 1 if isinstance(total, mi.Float) else 3)
                    mom = result.moments[name] = PixelMoments(np.zeros(shape), np.zeros(shape))
                mom.total += _to_image(total, h, w)
                mom.total_sq += _to_image(total_sq, h, w)
                mom.count += n
            result.lanes += lanes
            k0 += n
            if bar is not None:
                bar[0].update(bar[1], advance=n)
    finally:
        if bar is not None:
            bar[0].stop()
    result.seconds = time.perf_counter() - start
    return result


def _progress(label: str | None, total: int):
    if label is None:
        return None
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(),
                    TextColumn("{task.completed}/{task.total} spp"), TimeRemainingColumn(),
                    transient=True)
    prog.start()
    return prog, prog.add_task(label, total=total)
