"""Owen-scrambled Sobol points and the per-lane samplers (issue #22).

Wrong implementations these tests reject: a Sobol generator with wrong direction numbers or
an index shuffle that is not a nested scramble (the (0, m, 2)-net property breaks); a
scramble that is not a bijection of aligned blocks; numbers that depend on the lane or the
pass instead of (pixel, sample, dimension); dimension sets that repeat each other's points
(shuffles missing); replicas that share a scrambling (their means would not scatter
independently); biased points (a scramble that is not uniform).
"""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.sampling.sobol import (
    direction_numbers,
    owen_scramble,
    sobol_1d,
    sobol_2d,
    sobol_4d_half,
)
from arlight.sampling.stream import LaneSampler


def _net_cells(x: np.ndarray, y: np.ndarray, m: int) -> set[int]:
    """Sizes of the sets of occupied elementary intervals of every shape 2^a × 2^(m−a)."""
    return {len(set(zip((x * 2**a).astype(int), (y * 2**(m - a)).astype(int), strict=True)))
            for a in range(m + 1)}


@pytest.mark.parametrize("seed", [0, 1, 12345, 0xDEADBEEF])
def test_every_power_of_two_prefix_is_a_02_net(seed):
    """One point per elementary interval of area 2^-m, for every block of 2^m points."""
    p = sobol_2d(dr.arange(mi.UInt32, 1024), mi.UInt32(seed))
    x, y = np.array(p.x), np.array(p.y)
    for m in (2, 4, 6, 10):
        n = 2**m
        for start in (0, n) if 2 * n <= 1024 else (0,):
            assert _net_cells(x[start:start + n], y[start:start + n], m) == {n}
    u = np.array(sobol_1d(dr.arange(mi.UInt32, 256), mi.UInt32(seed)))
    assert len(set((u * 256).astype(int))) == 256  # 1D: stratified
    assert np.all((x >= 0) & (x < 1) & (y >= 0) & (y < 1))


def test_unscrambled_points_match_scipy_sobol():
    """Dimensions 0 and 1 equal SciPy's unscrambled Sobol points (as sets of each 2^m
    prefix: SciPy draws them in Gray-code order)."""
    from scipy.stats import qmc

    def point(i, d):
        v, x = direction_numbers(d), 0
        for k in range(32):
            if (i >> k) & 1:
                x ^= v[k]
        return x / 2**32
    ref = qmc.Sobol(4, scramble=False).random(256)
    ours = np.array([[point(i, d) for d in range(4)] for i in range(256)])
    for n in (4, 16, 64, 256):
        assert sorted(map(tuple, ours[:n])) == sorted(map(tuple, ref[:n]))


def test_4d_sets_are_jointly_stratified():
    """The two halves of a 4D set: the first is a (0, m, 2)-net, and the 4D point set puts
    exactly two points in every 4×4×4×2 cell (volume 2^(1−m), t = 1) — what independent
    2D paddings cannot do (random pairing leaves cells empty and others crowded)."""
    idx = dr.arange(mi.UInt32, 256)
    a, b = sobol_4d_half(idx, mi.UInt32(99), 0), sobol_4d_half(idx, mi.UInt32(99), 1)
    x = np.stack([np.array(a.x), np.array(a.y), np.array(b.x), np.array(b.y)], 1)
    assert _net_cells(x[:, 0], x[:, 1], 8) == {256}
    cells = (x * [4, 4, 4, 2]).astype(int)
    _, counts = np.unique(cells, axis=0, return_counts=True)
    assert len(counts) == 128 and set(counts) == {2}
    np.testing.assert_array_equal(x[:, :2], np.stack([np.array(sobol_2d(idx, mi.UInt32(99)).x),
                                                      np.array(sobol_2d(idx, mi.UInt32(99)).y)],
                                                     1))


def test_owen_scramble_permutes_aligned_blocks():
    """A nested scramble maps the 2^k-aligned blocks of [0, 2^m) onto each other."""
    x = dr.arange(mi.UInt32, 256)
    s = np.array(owen_scramble(x, mi.UInt32(777)), dtype=np.uint64)
    low = s & 0xFF  # the high 24 bits are one constant for all 256 inputs
    assert len(set((s >> 8).tolist())) == 1
    assert sorted(low.tolist()) == list(range(256))
    for k in (2, 4, 6):
        blocks = {frozenset((low[b * 2**k:(b + 1) * 2**k] >> k).tolist()) for b in range(256 >> k)}
        assert all(len(b) == 1 for b in blocks)


def test_dimension_sets_are_decorrelated():
    """Two 2D sets of the same pixel are different nets (shuffled), not the same points."""
    smp = LaneSampler.for_samples("sobol", mi.UInt32(np.zeros(256, np.uint32)),
                                  mi.UInt32(0), dr.arange(mi.UInt32, 256), mi.UInt32(3))
    a, b = smp.next_2d(0), smp.next_2d(3)
    ax, bx = np.array(a.x), np.array(b.x)
    assert abs(np.corrcoef(ax, bx)[0, 1]) < 0.2
    assert _net_cells(ax, np.array(a.y), 8) == {256} == _net_cells(bx, np.array(b.y), 8)


@pytest.mark.parametrize("kind", ["sobol", "independent"])
def test_numbers_depend_on_sample_not_on_lane(kind):
    """Drawing a pixel's samples in another order (other passes) gives the same numbers."""
    n = 64
    idx = dr.arange(mi.UInt32, n)
    perm = np.random.default_rng(0).permutation(n).astype(np.uint32)
    pix = mi.UInt32(np.full(n, 42, np.uint32))
    a = LaneSampler.for_samples(kind, pix, mi.UInt32(2), idx, mi.UInt32(9))
    b = LaneSampler.for_samples(kind, pix, mi.UInt32(2), mi.UInt32(perm), mi.UInt32(9))
    for dim in (0, 7, 21):
        va, vb = np.array(a.next_1d(mi.UInt32(dim))), np.array(b.next_1d(mi.UInt32(dim)))
        np.testing.assert_array_equal(va[perm], vb)
    c = a.gather(mi.UInt32(perm))
    np.testing.assert_array_equal(np.array(c.next_2d(5).x), np.array(b.next_2d(5).x))


def test_replicas_are_independent_uniform_randomisations():
    """Replica means of a discontinuous integrand: unbiased, and spread like independent
    randomisations (the variance of the replica means matches across pixels)."""
    n_pix, n = 4096, 16
    pix = dr.arange(mi.UInt32, n_pix * n) // n
    j = dr.arange(mi.UInt32, n_pix * n) % n
    vals = []
    for r in range(2):
        smp = LaneSampler.for_samples("sobol", pix, mi.UInt32(r), j, mi.UInt32(1))
        p = smp.next_2d(0)
        f = np.array(dr.select(p.x + p.y < 1.1, 1.0, 0.0)).reshape(n_pix, n).mean(axis=1)
        vals.append(f)
    truth = 1.0 - 0.9 * 0.9 / 2
    a, b = vals
    se = np.sqrt(a.var(ddof=1) / n_pix)
    assert abs(a.mean() - truth) < 4 * se and abs(b.mean() - truth) < 4 * se
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.06  # independent scrambles per replica
    # QMC: the 16-point nets beat independent sampling's variance p(1-p)/16 clearly
    assert a.var() < 0.5 * truth * (1 - truth) / n
