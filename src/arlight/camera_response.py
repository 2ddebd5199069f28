"""Camera transfer functions: code values <-> linear radiance.

A camera frame stores display code values ``v`` in ``[0, 2^bits - 1]``. The scene declares the
frame's transfer function and an exposure in EV, and the two directions are exact inverses:

    radiance = decode(v / v_max) / 2**exposure            (inverse tone mapping, Kán §3.6)
    v        = round(encode(clip(radiance * 2**exposure, 0, 1)) * v_max)

so a frame that goes through ``to_radiance`` and back through ``to_display`` comes out
byte-identical. This is what makes the null test (no virtual object: output == input frame)
hold after tone mapping; Kán's thesis leaves the forward operator unspecified (digest §4), so we
use the exact inverse of the declared camera response rather than a photographic operator.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal

import numpy as np

TransferKind = Literal["srgb", "gamma", "linear"]
TRANSFER_KINDS: tuple[str, ...] = ("srgb", "gamma", "linear")


def srgb_decode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB electro-optical transfer: code in [0,1] -> linear in [0,1]."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def srgb_encode(y: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_decode`: linear in [0,1] -> code in [0,1]."""
    y = np.asarray(y, dtype=np.float64)
    return np.where(y <= 0.0031308, y * 12.92, 1.055 * np.power(np.maximum(y, 0.0031308),
                                                                1.0 / 2.4) - 0.055)


@dataclass(frozen=True)
class Transfer:
    """A frame's transfer function and exposure.

    Attributes:
        kind: ``"srgb"`` (IEC 61966-2-1), ``"gamma"`` (``code = linear^(1/gamma)``) or
            ``"linear"``.
        gamma: exponent for ``kind="gamma"`` (ignored otherwise).
        exposure: exposure in EV; radiance ``L`` displays as ``L * 2**exposure``, so a
            display value of 1 (white) corresponds to ``2**-exposure`` W/(sr·m²).
    """

    kind: TransferKind = "srgb"
    gamma: float = 2.2
    exposure: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in TRANSFER_KINDS:
            raise ValueError(f"unknown transfer function {self.kind!r}; use one of "
                             f"{', '.join(TRANSFER_KINDS)}")
        if not (np.isfinite(self.gamma) and self.gamma > 0):
            raise ValueError(f"gamma must be a positive number, got {self.gamma}")
        if not np.isfinite(self.exposure):
            raise ValueError(f"exposure must be finite, got {self.exposure}")

    @property
    def scale(self) -> float:
        """Radiance-to-display gain ``2**exposure`` (exact power of two for integer EV)."""
        return float(2.0 ** self.exposure)

    def decode(self, x: np.ndarray) -> np.ndarray:
        """Normalised code value in [0,1] -> normalised linear value in [0,1] (float64)."""
        x = np.asarray(x, dtype=np.float64)
        if self.kind == "srgb":
            return srgb_decode(x)
        if self.kind == "gamma":
            return np.power(np.clip(x, 0.0, None), self.gamma)
        return x

    def encode(self, y: np.ndarray) -> np.ndarray:
        """Normalised linear value in [0,1] -> normalised code value in [0,1] (float64)."""
        y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
        if self.kind == "srgb":
            return srgb_encode(y)
        if self.kind == "gamma":
            return np.power(y, 1.0 / self.gamma)
        return y

    def to_radiance(self, codes: np.ndarray) -> np.ndarray:
        """Integer code values (uint8/uint16) -> linear radiance W/(sr·m²), float64.

        A table lookup: every code's radiance is computed once per transfer and dtype
        (:func:`_radiance_table`), the same float64 operations as decoding each pixel, so
        the result is bitwise the direct decode at a fraction of the cost (a 640×480 frame
        per video frame in ``live`` and ``sequence``)."""
        codes = np.asarray(codes)
        if codes.dtype not in (np.uint8, np.uint16):
            v_max = float(np.iinfo(codes.dtype).max)
            return self.decode(codes.astype(np.float64) / v_max) / self.scale
        return _radiance_table(self, codes.dtype.str)[codes]

    def to_display(self, radiance: np.ndarray, dtype: type = np.uint8) -> np.ndarray:
        """Linear radiance -> integer code values; out-of-range radiance is clipped."""
        v_max = float(np.iinfo(dtype).max)
        y = np.asarray(radiance, dtype=np.float64) * self.scale
        y = np.nan_to_num(y, nan=0.0, posinf=1.0, neginf=0.0)
        return np.rint(self.encode(y) * v_max).astype(dtype)


@functools.lru_cache(maxsize=32)
def _radiance_table(transfer: Transfer, dtype: str) -> np.ndarray:
    """Radiance of every code value of ``dtype`` (``uint8``/``uint16``) under ``transfer``:
    ``decode(v / v_max) / scale`` for ``v = 0 … v_max``, read-only."""
    v_max = np.iinfo(np.dtype(dtype)).max
    table = transfer.decode(np.arange(v_max + 1, dtype=np.float64) / float(v_max))
    table = table / transfer.scale
    table.setflags(write=False)
    return table
