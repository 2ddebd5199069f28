"""What the studio shows: a layer of the current frame as display code values, encoded.

Radiance layers go through the camera's own transfer function
(:meth:`arlight.camera_response.Transfer.to_display`) with the user's exposure offset added, so at
0 EV a composite with no virtual object shows the camera frame's own code values.
"""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np

from arlight.camera_response import Transfer

FORMATS = {"jpeg": ("JPEG", "image/jpeg"), "png": ("PNG", "image/png"),
           "webp": ("WEBP", "image/webp")}
ERROR_GAIN = 4.0
"""The error layer shows ``|composite − ground truth|`` times this gain (dimensionless)."""


def display(layer: str, images: dict[str, np.ndarray], transfer: Transfer, ev: float,
            ground_truth: np.ndarray | None) -> np.ndarray:
    """``(H, W, 3)`` uint8 display codes of ``layer`` at exposure offset ``ev`` (EV).

    * ``composite``, ``mixed``: radiance through the camera transfer;
    * ``delta`` (signed): mid-grey 0.5 ± half the encoded ``|delta|`` per channel — darker
      where the virtual object takes light away (shadows), brighter where it adds (bounce);
    * ``mask``: coverage in [0, 1] as grey;
    * ``error``: ``ERROR_GAIN · |composite − ground truth|`` through the transfer (black
      when the scene has no ground truth).
    """
    tr = replace(transfer, exposure=transfer.exposure + ev)
    if layer in ("composite", "mixed"):
        return tr.to_display(images[layer])
    if layer == "delta":
        d = np.asarray(images["delta"], np.float64) * tr.scale
        v = 0.5 + 0.5 * np.sign(d) * tr.encode(np.abs(d))
        return np.rint(np.clip(v, 0, 1) * 255).astype(np.uint8)
    if layer == "mask":
        m = np.clip(np.asarray(images["mask"], np.float64), 0, 1)
        return np.repeat(np.rint(m * 255).astype(np.uint8)[..., None], 3, axis=2)
    if layer == "error":
        if ground_truth is None:
            return np.zeros(images["composite"].shape, np.uint8)
        return tr.to_display(ERROR_GAIN * np.abs(images["composite"] - ground_truth))
    raise ValueError(f"unknown layer {layer!r}")


def encode(codes: np.ndarray, fmt: str = "jpeg", quality: int = 85) -> bytes:
    """``(H, W, 3)`` uint8 as JPEG, PNG or WebP bytes (``quality`` for the lossy ones)."""
    from PIL import Image

    pil_format, _ = FORMATS[fmt]
    buf = io.BytesIO()
    kwargs = {"quality": int(quality)} if fmt in ("jpeg", "webp") else {"compress_level": 1}
    Image.fromarray(np.ascontiguousarray(codes)).save(buf, pil_format, **kwargs)
    return buf.getvalue()


def webp_available() -> bool:
    """Whether this Pillow can write WebP."""
    from PIL import features

    return bool(features.check("webp"))
