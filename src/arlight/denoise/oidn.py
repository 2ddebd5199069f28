"""Intel Open Image Denoise (OIDN 2.x) on the CPU, through the ``pyoidn`` wheel.

    out = denoise_rgb(color, albedo, normal, quality="high", input_scale=None)

The wheel ships the OIDN libraries with the trained weights compiled into
``libOpenImageDenoise_core.so``: nothing is downloaded at run time. OIDN is Apache-2.0
(Intel), the ``pyoidn`` binding MIT (its wheel metadata and LICENSE).

One device per process and kind (``cpu``; ``cuda``: OIDN's CUDA device, shipped in the
same wheel — an NVIDIA GPU, the same filter, weights and ``inputScale``; images copied
through device buffers) and one ``RT`` filter per (device, quality, auxiliary images) are
kept and re-bound per call (creating a filter loads its network, ~10× a small image's
denoise). The ``cuda`` path could not be run on this project's machines (no CUDA device):
:func:`check_device` refuses it there with one line.
Calls are serialised by a lock. OIDN on the CPU is deterministic: equal inputs give equal
outputs bit for bit, which :mod:`arlight.denoise.differential` relies on (where ``I_m`` and
``I_r`` agree over the filter's receptive field, their denoised difference is exactly 0).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

QUALITIES = ("fast", "balanced", "high")
"""OIDN quality levels (``OIDN_QUALITY_*``), fastest first."""
DEVICES = ("cpu", "cuda")
"""OIDN device kinds."""

_LOCK = threading.Lock()
_STATE: dict[str, Any] = {}


def check_device(kind: str) -> None:
    """Raise :class:`~arlight.errors.InputError` (field ``options.denoise_device``) when
    OIDN has no device of ``kind`` here (``cuda`` without an NVIDIA GPU and driver)."""
    import pyoidn

    from arlight.errors import InputError

    if kind not in DEVICES:
        raise InputError(f"must be one of {', '.join(DEVICES)}, got {kind!r}",
                         field="options.denoise_device")
    if kind == "cuda" and not pyoidn.Device.is_cuda_available():
        raise InputError("OIDN finds no CUDA device on this machine (an NVIDIA GPU and "
                         "driver are needed); use denoise_device=cpu",
                         field="options.denoise_device")


def _device(kind: str = "cpu"):
    """The process's committed OIDN device of ``kind`` (created on first use)."""
    import pyoidn

    if kind not in _STATE:
        check_device(kind)
        dev = pyoidn.Device({"cpu": pyoidn.OIDN_DEVICE_TYPE_CPU,
                             "cuda": pyoidn.OIDN_DEVICE_TYPE_CUDA}[kind])
        dev.commit()
        err = dev.get_error()
        if err:
            raise RuntimeError(f"OIDN {kind} device: {err}")
        _STATE[kind] = dev
        _STATE.setdefault("filters", {})
    return _STATE[kind]


def _filter(quality: str, aux: tuple[bool, bool], kind: str = "cpu"):
    import pyoidn

    dev = _device(kind)
    key = (kind, quality, aux)
    flt = _STATE["filters"].get(key)
    if flt is None:
        flt = pyoidn.Filter(dev, pyoidn.OIDN_FILTER_TYPE_RT)
        flt.set_quality({"fast": pyoidn.OIDN_QUALITY_FAST,
                         "balanced": pyoidn.OIDN_QUALITY_BALANCED,
                         "high": pyoidn.OIDN_QUALITY_HIGH}[quality])
        _STATE["filters"][key] = flt
    return flt


def denoise_rgb(color: np.ndarray, albedo: np.ndarray | None = None,
                normal: np.ndarray | None = None, quality: str = "high",
                input_scale: float | None = None, device: str = "cpu") -> np.ndarray:
    """OIDN's ``RT`` filter on an HDR image.

    Args:
        color: ``(H, W, 3)`` linear radiance, non-negative (negative values are clamped
            to 0 first: OIDN's HDR input is non-negative).
        albedo: ``(H, W, 3)`` first-hit albedo in [0, 1], noise-free (``cleanAux``), or None.
        normal: ``(H, W, 3)`` first-hit normals in [-1, 1], noise-free; only with ``albedo``.
        quality: ``fast`` | ``balanced`` | ``high``.
        input_scale: OIDN's ``inputScale`` (multiplies the colour so that 1 is a mid
            value); None: OIDN's automatic exposure of this image. Two images denoised to
            be subtracted should share it.
        device: ``cpu`` | ``cuda`` (:func:`check_device`).

    Returns:
        ``(H, W, 3)`` float32 denoised radiance.
    """
    import pyoidn

    if quality not in QUALITIES:
        raise ValueError(f"quality must be one of {', '.join(QUALITIES)}, got {quality!r}")
    if normal is not None and albedo is None:
        raise ValueError("OIDN takes a normal image only together with an albedo image")
    c = np.ascontiguousarray(np.maximum(np.asarray(color, np.float32), 0.0))
    if c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"color must be (H, W, 3), got {c.shape}")
    images = {"color": c}
    for name, img in (("albedo", albedo), ("normal", normal)):
        if img is not None:
            a = np.ascontiguousarray(np.asarray(img, np.float32))
            if a.shape != c.shape:
                raise ValueError(f"{name} has shape {a.shape}; color has {c.shape}")
            images[name] = a
    out = np.empty_like(c)
    h, w = c.shape[:2]
    with _LOCK:
        flt = _filter(quality, (albedo is not None, normal is not None), device)
        buffers = []
        for name, img in (*images.items(), ("output", out)):
            if device == "cpu":  # host memory shared with OIDN
                flt.set_image(name, img, pyoidn.OIDN_FORMAT_FLOAT3)
                continue
            buf = pyoidn.Buffer(_STATE[device], img.nbytes)  # device memory
            if name != "output":
                buf.write(0, img.nbytes, img)
            buffers.append(buf)
            flt.set_image(name, buf, pyoidn.OIDN_FORMAT_FLOAT3, w, h)
        flt.set_bool("hdr", True)
        flt.set_bool("cleanAux", albedo is not None)
        flt.set_float("inputScale", float("nan") if input_scale is None else input_scale)
        flt.commit()
        flt.execute()
        if buffers:
            buffers[-1].read(0, out.nbytes, out)
        err = _STATE[device].get_error()
        for name in (*images, "output"):
            flt.unset_image(name)
        for buf in buffers:
            buf.release()
    if err:
        raise RuntimeError(f"OIDN: {err}")
    return out


def auto_scale(*images: np.ndarray) -> float:
    """An ``inputScale`` shared by ``images``: 0.18 over the geometric-mean luminance of
    their pixels (OIDN's own auto-exposure rule, on all images together), so that
    ``D(a) − D(b)`` does not pick up a difference of exposures."""
    lum = np.concatenate([(0.2126 * np.maximum(i[..., 0], 0) + 0.7152 * np.maximum(i[..., 1], 0)
                           + 0.0722 * np.maximum(i[..., 2], 0)).ravel() for i in images])
    lum = lum[lum > 1e-8]
    if lum.size == 0:
        return 1.0
    return float(0.18 / np.exp(np.mean(np.log(lum))))


__all__ = ["DEVICES", "QUALITIES", "auto_scale", "check_device", "denoise_rgb"]
