"""Scatter-adds whose result does not depend on thread timing.

``dr.scatter_reduce(Add)`` on floats adds the lanes in whatever order the threads reach
the target, and float addition is not associative: equal inputs gave images differing in
~2k pixels from run to run (DLPV's injection). Here the values are added as 64-bit
fixed-point integers, whose sum is the same in any order, and converted back once.

Fixed point: one power-of-two scale per call, the largest that keeps
``lanes × max|value|`` below 2⁶²; the step is ``max|value| · 2⁻⁽⁶¹⁻⌈log₂ lanes⌉⁾`` — for
262 144 lanes (a 512² RSM) 2⁻⁴³ of the largest value, far below float32's own rounding of
that value (2⁻²⁴).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import drjit as dr
import mitsuba as mi


def fixed_point_scale(max_abs: float, lanes: int) -> float:
    """The power of two that maps ``max_abs`` to at most ``2⁶¹ / lanes``; 1 for zero input."""
    if not max_abs > 0.0 or not math.isfinite(max_abs):
        return 1.0
    headroom = 61 - max(1, math.ceil(math.log2(max(lanes, 1))))
    return math.ldexp(1.0, headroom - math.frexp(max_abs)[1])


def scatter_sum_exact(values: Sequence[mi.Float], index: mi.UInt32, active: mi.Bool,
                      size: int, max_abs: float | None = None) -> list[mi.Float]:
    """Per value array, the float array of ``size`` whose entry ``i`` is the sum of the active
    lanes with ``index == i`` — the same bits whatever order the lanes are added in (all
    ``values`` share one fixed-point scale).

    ``max_abs``: a bound on ``|value|`` over the active lanes when the caller knows one
    (saves a reduction per array); it sets the scale, so a loose bound costs precision.
    """
    return scatter_sums_exact([(values, index, active)], size, max_abs)


def scatter_sums_exact(groups: Sequence[tuple[Sequence[mi.Float], mi.UInt32, mi.Bool]],
                       size: int, max_abs: float | None = None) -> list[mi.Float]:
    """:func:`scatter_sum_exact` of several groups ``(values, index, active)`` (each with
    the same number of value arrays, any widths) into one set of sums: entry ``i`` of sum
    ``c`` adds value ``c`` of every group's active lanes with ``index == i`` — integers in
    one fixed-point scale for all groups, converted to float once (dvct's injection of
    every light's VPLs: one conversion per volume instead of a full-grid pass per light)."""
    count = len(groups[0][0]) if groups else 0
    groups = [g for g in groups if dr.width(g[1]) > 0]
    dr.eval([g for grp in groups for g in grp])
    if not groups:
        return [dr.zeros(mi.Float, size) for _ in range(count)]
    lanes = sum(dr.width(g[1]) for g in groups)
    if max_abs is None:
        peaks = [dr.max(dr.select(act, dr.abs(v), 0.0)) for vals, _, act in groups
                 for v in vals]
        dr.eval(peaks)  # one launch, one wait
        max_abs = max(float(p[0]) for p in peaks)
    if not math.isfinite(max_abs):
        raise ValueError("scatter_sum_exact: non-finite values")
    scale = fixed_point_scale(max_abs, lanes)
    # opaque: the scale follows the data, and a literal compiled new kernels whenever it
    # changed (every frame of a moving object, issue #32)
    up, down = dr.opaque(mi.Float, scale), dr.opaque(mi.Float, 1.0 / scale)
    accs = [dr.zeros(mi.Int64, size) for _ in range(count)]
    for vals, index, active in groups:
        for acc, v in zip(accs, vals, strict=True):
            # ``v * scale`` is exact (a power of two) and so is its rounding to an integer
            dr.scatter_reduce(dr.ReduceOp.Add, acc, mi.Int64(dr.round(v * up)), index,
                              active)
    return [mi.Float(acc) * down for acc in accs]  # one rounding, then exact scaling


__all__ = ["fixed_point_scale", "scatter_sum_exact", "scatter_sums_exact"]
