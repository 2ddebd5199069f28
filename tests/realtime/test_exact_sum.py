"""Order-independent scatter sums (arlight.realtime.exact_sum)."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from arlight.jit import ensure_variant
from arlight.realtime.exact_sum import fixed_point_scale, scatter_sum_exact


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
