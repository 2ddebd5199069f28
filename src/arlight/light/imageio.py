"""Image reading and atomic writing for the light package (one reader, one writer).

HDR files (.hdr/.exr/.pfm) are read through Mitsuba's ``Bitmap`` (handles tiled and
mip-mapped EXR, level 0) as linear float32. LDR files (PNG/JPEG/...) are read with
OpenCV and linearised with the sRGB transfer curve (IEC 61966-2-1), scaled to [0, 1]:
an LDR photo is a display-referred picture, not radiance, and the result is only
*relative* radiance (clipped where the sensor saturated).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

HDR_SUFFIXES = {".hdr", ".exr", ".pfm", ".rgbe"}


class ImageReadError(ValueError):
    """Raised with the file name when an image cannot be read."""


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """Inverse sRGB transfer function on [0, 1] code values."""
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as linear float32 ``(H, W, 3)`` (row 0 at the top).

    Greyscale images are replicated to RGB; alpha is dropped. Raises
    :class:`ImageReadError` naming the file when it is missing or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"{path}: file not found")
    if path.suffix.lower() in HDR_SUFFIXES:
        try:
            import mitsuba as mi

            if mi.variant() is None:
                mi.set_variant("scalar_rgb")
            bmp = mi.Bitmap(str(path))
            arr = np.array(bmp, dtype=np.float32, copy=True)
        except Exception as exc:  # Mitsuba raises RuntimeError with its own words
            raise ImageReadError(f"{path}: cannot read HDR image ({exc})") from exc
    else:
        import cv2

        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise ImageReadError(f"{path}: cannot read image (unknown or corrupt format)")
        scale = 65535.0 if raw.dtype == np.uint16 else 255.0
        if raw.ndim == 3:
            raw = cv2.cvtColor(raw[..., :3], cv2.COLOR_BGR2RGB)
        arr = srgb_to_linear(raw.astype(np.float32) / scale)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    arr = arr[..., :3]
    if not np.all(np.isfinite(arr)):
        raise ImageReadError(f"{path}: image holds NaN or Inf values")
    return np.ascontiguousarray(arr, dtype=np.float32)


def atomic_write(path: str | Path, writer: Callable[[str], None]) -> Path:
    """Call ``writer(tmp_path)`` on a temporary file next to ``path`` then rename it onto
    ``path`` (``os.replace``), so a failure never leaves a partial file behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        writer(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Write a float RGB image as OpenEXR (through Mitsuba), atomically."""
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    arr = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    return atomic_write(path, lambda tmp: mi.Bitmap(arr).write(tmp))
