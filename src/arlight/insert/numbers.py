"""Numbers from the command line of ``arlight insert`` (and the sequence's marker): one parser
for every comma-separated option, refusing NaN, infinities and absurd magnitudes.

Every number that enters ``insert`` goes through :func:`floats` or :func:`number`, so a value
a render cannot use (``--at nan,0,0``, ``--scale 1e300``, ``--light-scale inf``) is an
:class:`~arlight.errors.InputError` naming the option before any work.
"""

from __future__ import annotations

import math

from arlight.errors import InputError

MAX_LENGTH_M = 1e3
"""Largest coordinate or length (m) accepted: a table top is metres, not kilometres."""

MAX_ANGLE_DEG = 3600.0
"""Largest rotation angle (degrees, either sign): ten turns."""


def number(value: float, field: str, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False) -> float:
    """``value`` as a float when it is finite and in ``[lo, hi]`` (``(lo, hi]`` with
    ``lo_open``); else :class:`InputError` naming ``field``."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"expected a number, got {value!r}", field=field) from exc
    if not math.isfinite(v):
        raise InputError(f"must be a finite number, got {value!r}", field=field)
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise InputError(f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}", field=field)
    if hi is not None and v > hi:
        raise InputError(f"must be <= {hi:g}, got {v:g}", field=field)
    return v


def floats(text: str, n: int, field: str, lo: float = -MAX_LENGTH_M,
           hi: float = MAX_LENGTH_M) -> tuple[float, ...]:
    """``n`` comma-separated finite numbers in ``[lo, hi]`` (InputError naming ``field``)."""
    parts = str(text).split(",")
    if len(parts) != n:
        raise InputError(f"expected {n} numbers separated by commas, got {text!r}",
                         field=field)
    try:
        v = tuple(float(x) for x in parts)
    except ValueError as exc:
        raise InputError(f"cannot parse {text!r} ({exc})", field=field) from exc
    if not all(math.isfinite(x) for x in v):
        raise InputError(f"expected {n} finite numbers, got {text!r}", field=field)
    if not all(lo <= x <= hi for x in v):
        raise InputError(f"expected numbers in [{lo:g}, {hi:g}], got {text!r}", field=field)
    return v


def rotation(text: str, field: str = "--rotate") -> tuple[float, float, float, float]:
    """``AX,AY,AZ,DEG``: a non-zero finite axis and an angle within ±:data:`MAX_ANGLE_DEG`."""
    ax, ay, az, deg = floats(text, 4, field, -1e6, 1e6)
    if math.hypot(ax, ay, az) < 1e-12:
        raise InputError(f"the rotation axis must not be zero, got {text!r}", field=field)
    number(deg, field, -MAX_ANGLE_DEG, MAX_ANGLE_DEG)
    return ax, ay, az, deg


__all__ = ["MAX_ANGLE_DEG", "MAX_LENGTH_M", "floats", "number", "rotation"]
