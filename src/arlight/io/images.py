"""Reading and writing images.

LDR images (PNG/JPEG/PPM/PGM) are returned as raw integer code values; converting them to
linear radiance is the job of :mod:`arlight.camera_response`, because it depends on the camera's
declared transfer function. HDR images (OpenEXR, Radiance ``.hdr``) are read as linear
float32 through Mitsuba's ``Bitmap`` (which also reads tiled and mip-mapped EXR, level 0).

Every writer is atomic: it writes a temporary file in the target folder and renames it, so
an interrupted run never leaves a half-written image behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from arlight.errors import InputError

HDR_SUFFIXES = {".exr", ".hdr", ".rgbe", ".pfm"}
LDR_SUFFIXES = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff"}


def _bitmap_module():
    """Mitsuba with any variant set (Bitmap I/O does not depend on the variant)."""
    import mitsuba as mi

    if mi.variant() is None:
        from arlight.jit import ensure_variant

        ensure_variant()
    return mi


def to_bitmap(array: np.ndarray, pixel_format=None):
    """A ``mitsuba.Bitmap`` holding a copy of ``array`` (``(H, W)`` or ``(H, W, C)``).

    Mitsuba's binding refuses read-only and non-contiguous arrays (``TypeError``:
    "incompatible function arguments"); arrays that come out of Ray's object store (a
    world's environment map in a ``sequence --ray`` worker, layers returned to the driver)
    are read-only. Those are copied first; any other array is handed over as it is (the
    Bitmap copies it anyway)."""
    mi = _bitmap_module()
    arr = np.require(array, requirements=("C", "W"))
    return mi.Bitmap(arr) if pixel_format is None else mi.Bitmap(arr, pixel_format)


def is_hdr_path(path: str | Path) -> bool:
    return Path(path).suffix.lower() in HDR_SUFFIXES


def read_hdr(path: str | Path) -> np.ndarray:
    """Read an HDR image as linear float32 ``(H, W, 3)``.

    Raises :class:`InputError` naming the file when it is missing, unreadable, not RGB(A),
    or holds NaN/Inf values.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", file=str(path))
    mi = _bitmap_module()
    try:
        bmp = mi.Bitmap(str(path))
        if (bmp.pixel_format(), bmp.component_format()) != (mi.Bitmap.PixelFormat.RGB,
                                                            mi.Struct.Type.Float32):
            bmp = bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                              srgb_gamma=False)
        # the bitmap's own (writable) memory: a copy would double the peak on 4k maps
        arr = np.asarray(bmp, dtype=np.float32)
    except Exception as exc:  # Mitsuba raises RuntimeError with its own wording
        raise InputError(f"cannot read HDR image ({exc})", file=str(path)) from exc
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise InputError(f"{bad} NaN/Inf values in HDR image", file=str(path))
    return arr


def read_ldr(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image as raw code values ``(H, W, 3)`` (uint8 or uint16).

    Grey images are expanded to three channels and alpha is dropped.
    """
    import imageio.v3 as iio

    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", file=str(path))
    try:
        arr = iio.imread(path)
    except Exception as exc:
        raise InputError(f"cannot read image ({exc})", file=str(path)) from exc
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise InputError(f"expected an RGB image, got shape {arr.shape}", file=str(path))
    if arr.dtype not in (np.uint8, np.uint16):
        raise InputError(f"unsupported LDR sample type {arr.dtype}", file=str(path))
    return np.ascontiguousarray(arr[..., :3])


def read_linear(path: str | Path) -> np.ndarray:
    """Read any image as linear float32 ``(H, W, 3)``.

    HDR files are returned as stored. LDR files are sRGB-decoded (IEC 61966-2-1) to [0, 1]:
    *relative* radiance of a display-referred picture, clipped where the sensor saturated.
    For camera frames with a declared transfer function and exposure use
    :meth:`arlight.camera_response.Transfer.to_radiance` on :func:`read_ldr` instead.
    """
    if is_hdr_path(path):
        return read_hdr(path)
    from arlight.camera_response import srgb_decode

    codes = read_ldr(path)
    return srgb_decode(codes / float(np.iinfo(codes.dtype).max)).astype(np.float32)


def mean_linear(path: str | Path) -> np.ndarray:
    """Mean linear RGB ``(3,)`` of an image (:func:`read_linear`, averaged in its float32):
    a texture's mean albedo, as a reconstruction that lost the texture would estimate it."""
    return read_linear(path)[..., :3].reshape(-1, 3).mean(axis=0)


@contextlib.contextmanager
def atomic_write(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success only."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix or path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the usual mode
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Write a float image ``(H, W)``, ``(H, W, 1)`` or ``(H, W, 3)`` as a float32 OpenEXR."""
    mi = _bitmap_module()
    arr = np.ascontiguousarray(image, dtype=np.float32)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    with atomic_write(path, ".exr") as tmp:
        fmt = mi.Bitmap.PixelFormat.Y if arr.ndim == 2 else mi.Bitmap.PixelFormat.RGB
        to_bitmap(arr, fmt).write(str(tmp))
    return Path(path)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Write uint8/uint16 code values ``(H, W)`` or ``(H, W, 3)`` as a PNG."""
    import imageio.v3 as iio

    if image.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"write_png expects uint8/uint16 code values, got {image.dtype}")
    with atomic_write(path, ".png") as tmp:
        iio.imwrite(tmp, image, extension=".png")
    return Path(path)


def read_depth(path: str | Path, units_per_metre: float | None = None) -> np.ndarray:
    """Read a depth image as float32 ``(H, W)``: metres along the camera's +z axis.

    ``.npy`` files hold a 2-D float array; image files (EXR, PFM, ...) are read through
    Mitsuba's Bitmap and their first channel is used (a single-channel ``Y``/``Z`` EXR is the
    usual form). With ``units_per_metre`` the file holds raw sensor values instead (16-bit PNG
    of an RGB-D camera: 1000 = millimetres, TUM 5000), read unconverted by OpenCV and divided.
    NaN and 0 mark unknown depth; negative or infinite values are errors.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", file=str(path))
    try:
        if units_per_metre is not None:
            import cv2

            raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if raw is None:
                raise ValueError("OpenCV cannot read it")
            if raw.ndim != 2:  # a sensor's depth has one channel; three is a colour image
                raise ValueError(f"raw depth must be one channel, got shape {raw.shape}")
            arr = raw.astype(np.float32) / np.float32(units_per_metre)
        elif path.suffix.lower() == ".npy":
            arr = np.load(path, allow_pickle=False)
        else:
            mi = _bitmap_module()
            bmp = mi.Bitmap(str(path))
            arr = np.array(bmp.convert(component_format=mi.Struct.Type.Float32), copy=True)
    except Exception as exc:  # NumPy and Mitsuba raise their own types
        raise InputError(f"cannot read depth image ({exc})", file=str(path)) from exc
    arr = np.asarray(arr, dtype=np.float32)
    if arr.ndim == 3:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise InputError(f"expected a 2-D depth image, got shape {arr.shape}", file=str(path))
    if np.any(np.isinf(arr)) or np.any(arr < 0):
        raise InputError("depth must be >= 0 metres (NaN or 0 = unknown); found negative or "
                         "infinite values", file=str(path))
    return arr
