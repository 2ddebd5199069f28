"""What the studio shows: a layer of the current frame as display code values, encoded.

Radiance layers go through the camera's own transfer function
(:meth:`arlight.camera_response.Transfer.to_display`) with the user's exposure offset added, so at
0 EV a composite with no virtual object shows the camera frame's own code values.
"""

from __future__ import annotations

import functools
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
        return to_display(tr, images[layer])
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


BUCKET_BITS = 12
""":func:`to_display` looks float32 radiance up by its bit pattern shifted by this many bits:
buckets of 4096 consecutive floats (a relative width of 2⁻¹¹)."""
AMBIGUOUS = np.uint16(0xFFFF)


@functools.lru_cache(maxsize=16)
def code_table(transfer: Transfer) -> np.ndarray:
    """uint16 per bucket of :data:`BUCKET_BITS` float32 bit patterns: the display code
    (:meth:`Transfer.to_display`, 8 bits) every float of the bucket has, or
    :data:`AMBIGUOUS` where a code changes inside it (read-only).

    The code of a finite ``x ≥ 0`` is non-decreasing in ``x``, and positive floats are
    ordered like their bit patterns, so it is the number of *thresholds* ``t_k`` (the
    smallest float whose code reaches ``k``, found by bisection over the bit patterns,
    ``k = 1 … 255``) at or below ``x``: a bucket is ambiguous only where a threshold lies
    inside it (255 of 2²⁰ buckets, and the one holding +inf and NaNs); negative floats and
    NaNs display 0."""
    def codes(bits: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", over="ignore"):
            return transfer.to_display(bits.astype(np.uint32).view(np.float32))

    inf = 0x7F800000
    k = np.arange(1, 256)
    lo, hi = np.zeros(255, np.int64), np.full(255, inf, np.int64)  # code(0) = 0, (inf) = 255
    while np.any(lo < hi):  # hi: the smallest bit pattern whose code is >= k
        mid = (lo + hi) // 2
        ok = codes(mid) >= k
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid + 1)
    table = np.zeros(1 << (32 - BUCKET_BITS), np.uint16)  # NaNs, negative floats: 0
    last = inf >> BUCKET_BITS  # the bucket of +inf (and the first NaNs)
    starts = np.arange(last, dtype=np.int64) << BUCKET_BITS
    table[:last] = np.searchsorted(hi, starts, side="right")
    inside = hi & ((1 << BUCKET_BITS) - 1) != 0  # a threshold after a bucket's first float
    table[hi[inside] >> BUCKET_BITS] = AMBIGUOUS
    table[last] = AMBIGUOUS
    table.setflags(write=False)
    return table


def to_display(transfer: Transfer, radiance: np.ndarray) -> np.ndarray:
    """``transfer.to_display(radiance)`` (uint8 codes), bit for bit, from :func:`code_table`
    for float32 radiance (the floats of an ambiguous bucket through ``to_display`` itself):
    0.3× its time on a 640×480 frame (issue #32: the studio displays every frame)."""
    x = np.asarray(radiance)
    if x.dtype != np.float32:
        return transfer.to_display(x)
    x = np.ascontiguousarray(x)
    codes = code_table(transfer)[x.view(np.uint32) >> BUCKET_BITS]
    amb = codes == AMBIGUOUS
    if amb.any():
        codes[amb] = transfer.to_display(x[amb])
    return codes.astype(np.uint8)


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
