"""Caps on command-line size values and a cost estimate checked before a render starts.

The estimate is deliberately simple and conservative (documented in ``docs/cli.md``):

* memory: the wavefront of one pass, ``min(pixels × spp, MAX_LANES)`` lanes (at least one
  sample per pixel: a pass never holds less than the whole image) × :data:`BYTES_PER_LANE`,
  plus the per-pixel accumulators, ``pixels × BYTES_PER_PIXEL`` (the scene's meshes are
  not counted);
* time: ``pixels × spp × paths`` samples at :data:`SAMPLES_PER_SECOND_PER_CORE` per CPU core
  (a low rate for the LLVM backend; a GPU is much faster, so the time limit errs on the
  safe side there).

A request whose memory estimate exceeds :data:`MEMORY_FRACTION` of the available memory, or
whose time estimate exceeds :data:`MAX_SECONDS`, is refused with the estimate unless
``--force`` is given.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from arlight.errors import InputError
from arlight.jit import MAX_LANES  # the pass engine's wavefront cap

MAX_SPP = 1 << 20
MAX_FRAMES = 1_000_000
MAX_SECONDS_BUDGET = 7 * 24 * 3600.0
MAX_SEED = (1 << 32) - 1
MAX_SH_HEIGHT = 8192
MAX_SH_ORDER = 16
MAX_LIGHTS = 4096
MAX_REPEATS = 1000

BYTES_PER_LANE = 1024
BYTES_PER_PIXEL = 512
SAMPLES_PER_SECOND_PER_CORE = 250_000.0
MEMORY_FRACTION = 0.75
MAX_SECONDS = 6 * 3600.0


def check_range(value: float, field: str, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False) -> None:
    """Raise :class:`InputError` naming ``field`` when ``value`` is NaN or out of range."""
    import math

    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"must be a finite number, got {value}", field=field)
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise InputError(f"must be {'>' if lo_open else '>='} {lo:g}, got {value:g}",
                         field=field)
    if hi is not None and value > hi:
        raise InputError(f"must be <= {hi:g}, got {value:g}", field=field)


def check_seed(seed: int, field: str = "--seed") -> None:
    """Seeds are 32-bit unsigned integers (Mitsuba's sampler seed)."""
    check_range(seed, field, 0, MAX_SEED)


@dataclass(frozen=True)
class Estimate:
    """Cost of a request: bytes of memory at the peak, seconds, bytes written."""

    memory_bytes: float
    seconds: float
    output_bytes: float

    def text(self) -> str:
        return (f"about {self.memory_bytes / 2**30:.2f} GiB of memory and "
                f"{_duration(self.seconds)} on {os.cpu_count() or 1} CPU cores, "
                f"{self.output_bytes / 2**20:.1f} MiB written")


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def estimate(width: int, height: int, spp: int, paths: float = 1.0, layers: int = 12,
             renders: float = 1.0) -> Estimate:
    """Estimate a render of ``width × height`` pixels and ``spp`` samples per pixel.

    ``paths``: paths traced per sample (2 for a differential render: with and without the
    virtual objects); ``layers``: float RGB images written; ``renders``: how many such
    renders the command does in total (time only).
    """
    pixels = float(width) * float(height)
    lanes = max(min(pixels * spp, MAX_LANES), pixels)
    memory = lanes * BYTES_PER_LANE + pixels * BYTES_PER_PIXEL
    rate = SAMPLES_PER_SECOND_PER_CORE * (os.cpu_count() or 1)
    seconds = pixels * spp * paths * renders / rate
    return Estimate(memory, seconds, pixels * layers * 3 * 4)


def available_memory() -> float:
    """Bytes of memory available now (psutil), or +inf when unknown."""
    try:
        import psutil

        return float(psutil.virtual_memory().available)
    except Exception:  # noqa: BLE001 - no psutil or no /proc: do not refuse anything
        return float("inf")


def check_estimate(est: Estimate, what: str, force: bool,
                   lower: str = "--spp or the resolution", field: str = "bounds") -> None:
    """Refuse ``est`` beyond the limits (InputError with the estimate) unless ``force``.

    ``lower``: what the user can lower (named in the message); ``field``: the field of the
    error (``bounds``, or the option whose value makes the request too big)."""
    if force:
        return
    avail = available_memory()
    reasons = []
    if est.memory_bytes > MEMORY_FRACTION * avail:
        reasons.append(f"more than {MEMORY_FRACTION:.0%} of the {avail / 2**30:.1f} GiB "
                       "of memory available")
    if est.seconds > MAX_SECONDS:
        reasons.append(f"longer than {_duration(MAX_SECONDS)}")
    if reasons:
        raise InputError(f"{what} would need {est.text()}: {' and '.join(reasons)}; lower "
                         f"{lower}, or pass --force to run it anyway", field=field)


def work_estimate(memory_bytes: float, operations: float = 0.0, output_bytes: float = 0.0,
                  ops_per_second_per_core: float = 50e6) -> Estimate:
    """An :class:`Estimate` of work that is not a render: ``memory_bytes`` at the peak and
    ``operations`` elementary steps (a voxel update, a texel of a pass, ...) at
    ``ops_per_second_per_core`` per CPU core (a low rate: numpy/Open3D run mostly on one)."""
    seconds = float(operations) / (ops_per_second_per_core * (os.cpu_count() or 1))
    return Estimate(float(memory_bytes), seconds, float(output_bytes))


def image_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(width, height)`` of an image file from its header alone (nothing is decoded), so
    that a command can bound what reading it will allocate; None when the format is not
    recognised or the header is unreadable (the reader then reports the file).

    OpenEXR (``dataWindow``), Radiance ``.hdr``, PFM, NumPy ``.npy`` and what Pillow opens
    lazily (PNG, JPEG, TIFF, BMP, PPM/PGM, ...)."""
    import struct

    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    try:
        if head[:4] == b"\x76\x2f\x31\x01":  # OpenEXR: attributes after the version
            i = 8
            while i < len(head) and head[i] != 0:
                name_end = head.index(b"\0", i)
                type_end = head.index(b"\0", name_end + 1)
                (size,) = struct.unpack_from("<i", head, type_end + 1)
                if head[i:name_end] == b"dataWindow":
                    x0, y0, x1, y1 = struct.unpack_from("<4i", head, type_end + 5)
                    return x1 - x0 + 1, y1 - y0 + 1
                i = type_end + 5 + size
            return None
        if head[:2] in (b"#?",):  # Radiance: header lines, a blank line, "-Y H +X W"
            lines = head.split(b"\n")
            blank = lines.index(b"")
            parts = lines[blank + 1].split()
            return int(parts[3]), int(parts[1])
        if head[:2] in (b"PF", b"Pf"):
            w, h = head.split(b"\n")[1].split()[:2]
            return int(w), int(h)
        if head[:6] == b"\x93NUMPY":
            import numpy as np

            shape = np.load(path, mmap_mode="r").shape
            return (int(shape[1]), int(shape[0])) if len(shape) >= 2 else None
        from PIL import Image

        limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # header only here
        try:
            with Image.open(path) as im:
                return int(im.size[0]), int(im.size[1])
        finally:
            Image.MAX_IMAGE_PIXELS = limit
    except Exception:  # noqa: BLE001 - any unreadable header: let the reader report it
        return None


__all__ = ["Estimate", "MAX_FRAMES", "MAX_SEED", "MAX_SH_HEIGHT", "MAX_SPP", "check_estimate",
           "check_range", "check_seed", "estimate", "image_size", "work_estimate"]
