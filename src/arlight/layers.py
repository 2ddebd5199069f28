"""The delta idea of differential rendering, in one place: the compositing equation, the
layers every method produces, and the per-sample composite of Monte Carlo methods.

Differential rendering (Debevec 1998; Kán Eq. 2.20; Franke Eq. 3.3):

    I_f = M ⊙ I_m + (1 − M) ⊙ (I_c + (I_m − I_r))

with ``mixed = I_m``, ``delta = I_m − I_r`` and ``background = I_c``. The delta is added
as one term, so a zero delta leaves the background bit-exact.

* :func:`composite` — the one compositing equation every method shares.
* :class:`Layers` — what a method returns (``mixed``, ``delta``, ``mask``, the composite,
  standard errors, stats); :meth:`Layers.assemble` builds the composite through
  :func:`composite`.
* :func:`photo_scale` / :func:`ratio_change` — the photo-consistent (ratio) change
  ``B + s (I_m − I_r)``, ``s = clip(B / I_r, 0, 1/ρ)`` (option ``delta = ratio``).
* :func:`differential_samples` / :func:`layers_from_passes` — the per-sample layers of a
  differential Monte Carlo method and the layers from their moments.

Core tier: imports NumPy only (Dr.Jit arrays are passed in, never imported here).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def composite(background: np.ndarray, mixed: np.ndarray, delta: np.ndarray,
              mask: np.ndarray) -> np.ndarray:
    """Composite virtual pixels over the relit background.

    Args:
        background: camera frame ``I_c`` as linear radiance, ``(H, W, 3)``.
        mixed: radiance of the real proxy plus virtual objects ``I_m``, ``(H, W, 3)``.
        delta: change of the real scene caused by the virtual objects, ``(H, W, 3)``.
        mask: virtual-object coverage ``M`` in [0, 1], ``(H, W)`` or ``(H, W, 1)``.

    Returns:
        ``(H, W, 3)`` linear radiance in the dtype of ``background`` promoted with the others.
        Pixels where ``M == 0`` and ``delta == 0`` equal ``background`` exactly.
    """
    m = np.asarray(mask)
    if m.ndim == 2:
        m = m[..., None]
    if background.shape != mixed.shape or background.shape != delta.shape:
        raise ValueError(f"shape mismatch: background {background.shape}, mixed {mixed.shape},"
                         f" delta {delta.shape}")
    if m.shape[:2] != background.shape[:2]:
        raise ValueError(f"mask shape {m.shape[:2]} does not match image {background.shape[:2]}")
    out_type = np.result_type(background, mixed, delta, m)
    relit = np.add(background, delta, dtype=out_type)
    covered = np.flatnonzero(m[..., 0] > 0)
    if covered.size:  # blend the covered pixels only (uncovered ones never read mixed)
        flat = relit.reshape(-1, relit.shape[-1])
        mc = m.reshape(-1, 1)[covered].astype(out_type, copy=False)
        flat[covered] = mc * mixed.reshape(flat.shape)[covered] + (1.0 - mc) * flat[covered]
    return relit


@functools.lru_cache(maxsize=32)
def _taps(n: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear taps from ``m`` samples to ``n``, pixel centres aligned, edges clamped:
    ``(i0, i1, w)``, output ``j`` = ``(1 − w[j])·in[i0[j]] + w[j]·in[i1[j]]``."""
    x = np.clip((np.arange(n) + 0.5) * (m / n) - 0.5, 0.0, m - 1)
    i0 = np.floor(x).astype(np.intp)
    return i0, np.minimum(i0 + 1, m - 1), (x - i0).astype(np.float32)


def touching(n: int, m: int, lo: int, hi: int) -> slice:
    """The output positions of a bilinear upsampling of ``m`` samples to ``n``
    (:func:`upsample`) whose taps read any input sample in ``lo … hi`` (inclusive): one
    contiguous slice (the taps increase with the position); outside it the output is
    computed from other samples only (zero where they are zero)."""
    i0, i1, _ = _taps(n, m)
    idx = np.flatnonzero((i1 >= lo) & (i0 <= hi))
    return slice(int(idx[0]), int(idx[-1]) + 1) if idx.size else slice(0, 0)


def upsample(image: np.ndarray, height: int, width: int, rows: slice = slice(None),
             cols: slice = slice(None)) -> np.ndarray:
    """Bilinear upsampling of ``(h, w[, c])`` to ``(height, width[, c])`` float32, pixel
    centres aligned (``x_src = (x + 0.5)·w/width − 0.5``) and edges clamped: a constant
    image stays constant, a linear ramp stays linear. Separable, in place where it can
    (no BLAS: its threads fight for the cores of a loaded machine). ``rows``/``cols``
    (slices of the output, step 1): only that window of the output, bit for bit the same
    pixels as the window cut from the whole output (the studio upsamples only the
    insertion's footprint, issue #32)."""
    a = np.asarray(image, np.float32)
    for axis, n, win in ((0, height, rows), (1, width, cols)):
        if a.shape[axis] == n and win == slice(None):
            continue
        i0, i1, w = (t[win] for t in _taps(n, a.shape[axis]))
        shape = [1] * a.ndim
        shape[axis] = i0.size
        lo, hi = np.take(a, i0, axis=axis), np.take(a, i1, axis=axis)
        hi -= lo
        hi *= w.reshape(shape)
        lo += hi
        a = lo
    return a


def _check_image(layer: str, value: Any, shape: tuple[int, ...], where: str,
                 strict_dtype: bool, finite: bool = True) -> np.ndarray:
    """``value`` as a float32 array of ``shape``, or a ValueError naming the layer.

    ``strict_dtype``: only float32 passes (else any floating type, converted). ``finite``:
    reject NaN and ±inf (else only NaN).
    """
    a = np.asarray(value)
    want = "(H, W, 3)" if len(shape) == 3 else "(H, W)"
    if a.shape != shape:
        raise ValueError(f"{where}: layer {layer!r} has shape {a.shape}; expected {want} = "
                         f"{shape}")
    if a.dtype != np.float32 and (strict_dtype or a.dtype.kind != "f"):
        extra = "" if strict_dtype else " (other float types are converted)"
        raise ValueError(f"{where}: layer {layer!r} has dtype {a.dtype}; expected float32"
                         f"{extra}")
    a = a.astype(np.float32, copy=False)
    bad = np.isnan(a) if not finite else ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        kind = "non-finite" if finite else "NaN"
        raise ValueError(f"{where}: layer {layer!r} has {int(bad.sum())} {kind} values "
                         f"(first at {idx}: {a[idx]})")
    return a


def _image_shape(layer: str, h: int, w: int) -> tuple[int, ...]:
    return (h, w) if layer == "mask" else (h, w, 3)


@dataclass
class Layers:
    """The result of a method; images are ``(H, W, 3)`` float32 linear radiance.

    Attributes:
        background: the camera frame ``I_c``.
        mixed: ``I_m`` — real proxy plus virtual objects.
        delta: ``I_m − I_r`` — the change of the real scene (negative in shadows).
        mask: ``M`` in [0, 1] ``(H, W)`` — virtual coverage, averaged over samples.
        composite: ``M·I_m + (1 − M)·(I_c + delta)`` (Kán Eq. 2.20).
        real: ``I_r`` where the method computes it, else None.
        stderr: per-pixel standard errors of Monte Carlo layers, by layer name (+inf where
            a pixel has a single sample).
        stats: ``seconds`` (wall time of the call), ``time_<stage>`` (seconds per stage, see
            :mod:`arlight.timing`), counts (``samples``, ``rays``) and rates.
        method: the registered name of the method that produced the layers.
    """

    background: np.ndarray
    mixed: np.ndarray
    delta: np.ndarray
    mask: np.ndarray
    composite: np.ndarray
    real: np.ndarray | None = None
    stderr: dict[str, np.ndarray] = field(default_factory=dict)
    stats: dict[str, float] = field(default_factory=dict)
    method: str = ""

    @staticmethod
    def assemble(background: np.ndarray, mixed: np.ndarray, delta: np.ndarray,
                 mask: np.ndarray, **kwargs) -> Layers:
        """Build layers and the composite through the one shared compositing function.

        ``background``, ``mixed``, ``delta`` (and ``real``) must be ``(H, W, 3)`` and
        ``mask`` ``(H, W)`` floating-point arrays of finite values (converted to float32);
        ``H, W`` come from ``background``. Anything else raises a ValueError naming the layer
        and the expected shape.
        """
        where = "Layers.assemble"
        bg = np.asarray(background)
        if bg.ndim != 3 or bg.shape[2] != 3:
            raise ValueError(f"{where}: layer 'background' has shape {bg.shape}; expected "
                             "(H, W, 3)")
        h, w = bg.shape[:2]
        arrays = {"background": bg, "mixed": mixed, "delta": delta, "mask": mask}
        if kwargs.get("real") is not None:
            arrays["real"] = kwargs["real"]
        checked = {k: _check_image(k, v, _image_shape(k, h, w), where, strict_dtype=False)
                   for k, v in arrays.items()}
        if "real" in checked:
            kwargs["real"] = checked.pop("real")
        bg, mixed, delta, mask = (checked[k] for k in ("background", "mixed", "delta", "mask"))
        return Layers(background=bg, mixed=mixed, delta=delta, mask=mask,
                      composite=composite(bg, mixed, delta, mask).astype(np.float32), **kwargs)

    def upsampled(self, background: np.ndarray) -> Layers:
        """These layers (rendered at a fraction of ``background``'s size) at the size of
        ``background``: ``mixed``, ``delta`` and ``mask`` upsampled bilinearly
        (:func:`upsample`) and composited over ``background``, the full-size frame (so
        pixels the insertion does not change stay the frame's own). Same stats and method;
        ``real`` and the standard errors are dropped (they describe the small render)."""
        h, w = background.shape[:2]
        if self.mixed.shape[:2] == (h, w):
            return self
        mixed, delta, mask = (upsample(a, h, w) for a in (self.mixed, self.delta, self.mask))
        return Layers(background, mixed, delta, mask,
                      composite(background, mixed, delta, mask).astype(np.float32,
                                                                         copy=False),
                      stats=self.stats, method=self.method)

    def check(self, height: int, width: int, where: str = "Layers") -> None:
        """Raise a ValueError naming the first layer that is not a finite float32 array of
        ``(height, width, 3)`` (``(height, width)`` for the mask); standard errors (float32
        or float64) may be +inf (a single sample) but not NaN."""
        images = {"background": self.background, "mixed": self.mixed, "delta": self.delta,
                  "mask": self.mask, "composite": self.composite}
        if self.real is not None:
            images["real"] = self.real
        for name, img in images.items():
            _check_image(name, img, _image_shape(name, height, width), where,
                         strict_dtype=True)
        for name, img in self.stderr.items():
            _check_image(f"stderr_{name}", img, _image_shape(name, height, width), where,
                         strict_dtype=False, finite=False)


RATIO_MIN = 1e-6
"""Real radiance ``I_r`` (W m⁻² sr⁻¹) below which a channel keeps the additive change."""


def photo_scale(photo: Any, real: Any, albedo: Any, ops: Any = np) -> Any:
    """The photo-consistent scale ``s`` of a real pixel's change (issue #31; per channel).

    Differential rendering adds ``I_m − I_r`` to the photograph ``B``: right only where the
    proxy reproduces the photograph. Where it does not (a texture the reconstruction
    averaged, a highlight it lacks), the ratio form (Debevec 1998's multiplicative variant;
    the AR-OOF shadow factor) changes the pixel in proportion to what it shows:

        B + s (I_m − I_r),   s = clip(B / I_r, 0, 1/ρ)   (= B I_m / I_r unclipped)

    For a diffuse first hit ``I_r = ρ E_r / π``, so ``ρ s = clip(π B / E_r, 0, 1)`` is the
    albedo that reproduces the photograph (:mod:`arlight.realtime.photo_albedo`), and the
    clip keeps it physical (``ρ̂ = ρ s ≤ 1``). ``s = 1`` (the additive change) where
    ``I_r < RATIO_MIN``.

    Args:
        photo: ``B``, linear radiance (negative values read as 0).
        real: ``I_r``, the proxy's radiance at the same pixel (a denoised or converged one:
            the ratio of noisy estimates is biased, ``E[1/X] > 1/E[X]``).
        albedo: ``ρ``, the proxy's first-hit diffuse albedo in [0, 1].
        ops: ``numpy`` (NumPy arrays) or ``drjit`` (Dr.Jit arrays): where ``minimum``,
            ``maximum`` and ``select`` (NumPy: ``where``) come from.

    Returns:
        ``s``, same shape/type as the inputs, in ``[0, 1/ρ]``.
    """
    select = np.where if ops is np else ops.select
    s = ops.minimum(ops.maximum(photo, 0.0) / ops.maximum(real, RATIO_MIN),
                    1.0 / ops.maximum(albedo, RATIO_MIN))
    return select(real >= RATIO_MIN, s, 1.0)


def ratio_change(layers: Layers, albedo: np.ndarray, rows: slice = slice(None),
                 cols: slice = slice(None)) -> Layers:
    """``layers`` with the photo-consistent change ``s ⊙ delta`` (:func:`photo_scale`, with
    ``I_r`` = ``layers.real``, else ``mixed − delta``) in the window ``(rows, cols)`` (which
    must hold every non-zero delta) and the composite (:func:`composite`) recomputed;
    ``albedo`` is the window's ``(h, w, 3)``. A zero delta stays exactly zero, so pixels the
    insertion does not change are the photograph bit for bit. The composite's standard error
    (where there is one) becomes ``s``·that of the delta on uncovered pixels (``s`` taken as
    exact). Other fields (``noisy`` of denoised layers) are kept."""
    box = (rows, cols)
    real = layers.real if layers.real is not None else layers.mixed - layers.delta
    s = photo_scale(layers.background[box], real[box], albedo).astype(np.float32)
    delta = layers.delta.copy()
    delta[box] *= s
    stderr = dict(layers.stderr)
    if "composite" in stderr and "delta" in stderr:
        se = stderr["composite"].copy()
        free = layers.mask[box] <= 0
        se[box][free] = (stderr["delta"][box] * s)[free]
        stderr["composite"] = se
    comp = composite(layers.background, layers.mixed, delta, layers.mask).astype(np.float32)
    return dataclasses.replace(layers, delta=delta, composite=comp, stderr=stderr)


def differential_samples(mixed, real, mask, background) -> dict:
    """Per-sample layers of a differential Monte Carlo method (Dr.Jit arrays per lane).

    ``delta = L_m − L_r`` per sample (paired, so its standard error is that of the
    difference) and the per-sample composite ``m·L_m + (1 − m)(I_c + delta)``, whose moments
    give the composite's standard error. Feed the dict to :func:`arlight.backend.passes.
    run_passes` and its result to :func:`layers_from_passes`.
    """
    delta = mixed - real
    comp = mask * mixed + (1.0 - mask) * (background + delta)
    return {"mixed": mixed, "real": real, "delta": delta, "mask": mask, "composite": comp}


def layers_from_passes(frame: np.ndarray, result, **stats: float) -> Layers:
    """Layers from the moments of :func:`differential_samples` (a ``PassResult``).

    Layers are the per-pixel means, ``stderr`` their standard errors; ``stats`` gets the
    timing and sample counts (``seconds``, ``samples``, ``spp``, ``samples_per_second``) plus
    the method's own entries. ``seconds`` here is the time of the passes; :class:`BaseMethod`
    replaces it with the wall time of the whole call.
    """
    mom = result.moments
    samples = result.lanes
    spp = mom["mixed"].count
    base = {"seconds": result.seconds, "samples": float(samples), "spp": float(spp),
            "samples_per_second": samples / max(result.seconds, 1e-9)}
    return Layers.assemble(frame, mom["mixed"].mean, mom["delta"].mean,
                           mom["mask"].mean[..., 0], real=mom["real"].mean,
                           stderr={k: mom[k].stderr for k in ("mixed", "real", "delta",
                                                              "composite")},
                           stats={**base, **stats})


__all__ = ["Layers", "RATIO_MIN", "composite", "differential_samples", "layers_from_passes",
           "photo_scale", "ratio_change", "upsample"]
