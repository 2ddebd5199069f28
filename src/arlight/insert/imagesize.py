"""The pixel size of an image file from its header, without decoding the pixels.

``arlight insert`` (the photo) and ``arlight sequence`` (the frames) estimate the cost of a
request from the image size before anything is decoded: a 100 000 × 100 000 PNG must be
refused from its header, not after decoding 30 GB of pixels.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path


def _exr_size(path: Path) -> tuple[int, int] | None:
    """OpenEXR ``dataWindow`` (single-part header): ``(width, height)``."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if head[:4] != b"\x76\x2f\x31\x01":
        return None
    pos = 8
    while pos < len(head) and head[pos] != 0:
        end = head.index(b"\0", pos)
        name = head[pos:end]
        tend = head.index(b"\0", end + 1)
        (size,) = struct.unpack_from("<i", head, tend + 1)
        value = tend + 5
        if name == b"dataWindow" and size == 16:
            x0, y0, x1, y1 = struct.unpack_from("<4i", head, value)
            return x1 - x0 + 1, y1 - y0 + 1
        pos = value + size
    return None


def image_size(path: str | Path) -> tuple[int, int] | None:
    """``(width, height)`` read from the header of an LDR image (PNG, JPEG, …, via Pillow) or
    an OpenEXR file; None when the header cannot be read this way (the caller then decodes
    the file and reports its own error)."""
    p = Path(path)
    try:
        if p.suffix.lower() == ".exr":
            return _exr_size(p)
        from PIL import Image

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            limit = Image.MAX_IMAGE_PIXELS
            Image.MAX_IMAGE_PIXELS = None  # the size is what we want; nothing is decoded
            try:
                with Image.open(p) as im:
                    w, h = im.size
            finally:
                Image.MAX_IMAGE_PIXELS = limit
        return int(w), int(h)
    except (OSError, ValueError, struct.error, SyntaxError):
        return None


__all__ = ["image_size"]
