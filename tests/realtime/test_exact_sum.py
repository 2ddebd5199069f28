"""Order-independent scatter sums (arlight.realtime.exact_sum)."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from arlight.jit import ensure_variant
from arlight.realtime.exact_sum import fixed_point_scale, scatter_sum_exact, scatter_sums_exact


@pytest.fixture(autouse=True)
def _variant():
    ensure_variant()


def _sum(vals: np.ndarray, idx: np.ndarray, act: np.ndarray, size: int) -> np.ndarray:
    (out,) = scatter_sum_exact([mi.Float(vals)], mi.UInt32(idx), mi.Bool(act), size)
    return np.array(out)


def test_equals_an_exact_float64_sum_and_ignores_inactive_lanes():
    rng = np.random.default_rng(1)
    n, size = 200_000, 64
    vals = (rng.standard_normal(n) * np.exp(rng.uniform(-8, 4, n))).astype(np.float32)
    idx = rng.integers(0, size, n).astype(np.uint32)
    act = rng.random(n) < 0.8
    want = np.bincount(idx[act], weights=vals[act].astype(np.float64), minlength=size)
    got = _sum(vals, idx, act, size)
    # float32 rounding of the result dominates: bug caught: a scale that overflows int64 or
    # loses the small values (a fixed 2^20 scale would be off by ~1e-7 absolute)
    assert np.allclose(got, want, rtol=2e-7, atol=np.abs(vals).max() * 2.0 ** -40)


def test_bitwise_equal_for_any_order_of_the_lanes():
    """Bug caught: float atomics (the sum depends on the order lanes are added in)."""
    rng = np.random.default_rng(2)
    n, size = 50_000, 8
    vals = rng.standard_normal(n).astype(np.float32) * 1e3
    idx = rng.integers(0, size, n).astype(np.uint32)
    act = np.ones(n, bool)
    first = _sum(vals, idx, act, size)
    for seed in range(3):
        p = np.random.default_rng(seed).permutation(n)
        assert np.array_equal(_sum(vals[p], idx[p], act[p], size), first)


def test_scale_keeps_the_total_inside_int64():
    for max_abs, lanes in [(1e-30, 1), (3.0, 262_144), (1e30, 1 << 24), (0.0, 10)]:
        s = fixed_point_scale(max_abs, lanes)
        assert max_abs * s * max(lanes, 1) < 2.0 ** 63
        if max_abs > 0:
            assert max_abs * s * max(lanes, 1) >= 2.0 ** 59  # and uses most of it


def test_groups_add_into_one_sum_in_any_order():
    """Several groups of different widths (dvct's lights, ``+R_ρ`` and ``−R_µ``) into one
    set of sums, against a float64 ``bincount`` of all lanes. Bugs caught: a scale chosen
    from one group's peak or lane count (the others overflow int64 or lose precision), a
    group dropped (e.g. an empty one shifting the rest), the groups' channels mixed up, and
    a result that depends on the order of the groups."""
    rng = np.random.default_rng(4)
    size, groups, lanes = 4, [], []
    for n, amp, sign in [(70, 1e-3, 1.0), (30_000, 1.0, 1.0), (0, 1.0, 1.0), (20_000, 1e4, -1.0)]:
        vals = [(rng.random(n) * amp * sign * (c + 1)).astype(np.float32) for c in range(2)]
        idx = rng.integers(0, size, n).astype(np.uint32)
        act = rng.random(n) < 0.9
        groups.append(([mi.Float(v) for v in vals], mi.UInt32(idx), mi.Bool(act)))
        lanes.append((vals, idx, act))
    got = [np.array(x) for x in scatter_sums_exact(groups, size)]
    peak = max(np.abs(v).max() for vals, _, _ in lanes if len(vals[0]) for v in vals)
    for c in range(2):
        want = sum(np.bincount(idx[act], weights=vals[c][act].astype(np.float64),
                               minlength=size) for vals, idx, act in lanes)
        assert np.allclose(got[c], want, rtol=2e-7, atol=peak * 2.0 ** -30)
    back = [np.array(x) for x in scatter_sums_exact(groups[::-1], size)]
    assert all(np.array_equal(a, b) for a, b in zip(got, back, strict=True))
    assert [np.count_nonzero(np.array(x)) for x in scatter_sums_exact(groups[2:3], size)] \
        == [0, 0]
