"""Digest §10 items 1-4: SH basis, direction set and interleaving, ray length, E6."""

from __future__ import annotations

import numpy as np

from arlight.probeless.directions import (
    DirectionSet,
    fibonacci_sphere,
    unoccluded_transfer,
)
from arlight.probeless.transfer import compute_transfer
from arlight.sphere import sh as SH
from tests.probeless.conftest import box, views_of


def test_gram_identity_16_coefficients():
    """Y_0..Y_15 are orthonormal on a dense Fibonacci quadrature (|G − I| < 1e-3).
    Rejects a basis with a wrong normalisation constant or a band-3 index mix-up."""
    d = fibonacci_sphere(40000)
    Y = SH.sh_basis(d, 3)
    G = Y.T @ Y * (4 * np.pi / len(d))
    assert G.shape == (16, 16)
    assert np.abs(G - np.eye(16)).max() < 1e-3


def test_interleaved_subsets_cover_all_81_directions():
    """Four disjoint subsets of 21/20/20/20 directions whose union is all 81, each evenly
    spread (mean vector norm < 0.03). Rejects contiguous blocks (a subset = one cap of the
    sphere) and overlapping or missing directions."""
    ds = DirectionSet(81, 4)
    subs = ds.subsets()
    assert [len(s) for s in subs] == [21, 20, 20, 20]
    allidx = np.concatenate(subs)
    assert len(np.unique(allidx)) == 81 and sorted(allidx.tolist()) == list(range(81))
    assert np.allclose(np.linalg.norm(ds.directions, axis=1), 1.0)
    for s in subs:
        assert np.linalg.norm(ds.directions[s].mean(axis=0)) < 0.03
    assert abs(ds.weight - 4 * np.pi / 81) < 1e-15


def test_ray_limit_10_cm():
    """A 1 cm² occluder 9 cm along a direction blocks that ray, at 11 cm it does not.
    Rejects unlimited visibility rays (distant occluders counted) and a limit < 9 cm."""
    ds = DirectionSet(81, 1)
    j = int(np.argmax(ds.directions[:, 1]))  # the most upward direction
    w = ds.directions[j]
    p = np.zeros((1, 3))
    n = np.array([[0.0, 1.0, 0.0]])
    free = box("far", (0.01, 0.01, 0.01), (5.0, 5.0, 5.0))
    t_free = compute_transfer(views_of([free]), p, n, ds, ray_offset=0.0)
    assert t_free.blocked[0] == 0
    for dist, blocked in ((0.09, 1), (0.11, 0)):
        occ = box("occ", (0.01, 0.001, 0.01), w * dist)
        t = compute_transfer(views_of([occ]), p, n, ds, ray_offset=0.0)
        assert t.blocked[0] == blocked, dist
        lost = t_free.mixed - t.mixed
        expect = blocked * ds.weight * w[1] * ds.basis[j]
        assert np.allclose(lost[0], expect, atol=1e-9)


def test_unoccluded_transfer_is_e6_exactly():
    """E3 is evaluated as E6 minus the quadrature of the blocked directions, so an isolated
    point's 81-ray transfer is Â_l·Y_lm(n) to rounding (band 3 = 0), and the k = 4 interleaved
    partial transfers sum to it: the visibility-state cache's free points (E6, no rays) and
    cast points share one unoccluded part. Rejects the plain 81-ray sum (3 % off ‖T‖, band 3
    ≠ 0) and a subset's share of E6 other than its direction count / 81."""
    rng = np.random.default_rng(3)
    n = rng.normal(size=(6, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = np.zeros((6, 3))
    views = views_of([box("far", (0.01, 0.01, 0.01), (5.0, 5.0, 5.0))])
    exact = unoccluded_transfer(n)
    assert np.abs(exact[:, 9:]).max() < 1e-12  # Â_3 = 0
    t81 = compute_transfer(views, p, n, DirectionSet(81, 1)).real
    assert np.abs(t81 - exact).max() < 1e-12
    ds = DirectionSet(81, 4)
    parts = sum(compute_transfer(views, p, n, ds, s).real for s in ds.subsets())
    assert np.abs(parts - exact).max() < 1e-12


def _slab_blocked(o: np.ndarray, d: np.ndarray, lo, hi, tmax: float) -> np.ndarray:
    """Whether rays ``o + t d`` (one origin, directions ``(N, 3)``) hit the axis-aligned box
    ``[lo, hi]`` for ``0 < t < tmax`` (slab test, NumPy: independent of Mitsuba)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lo) - o) / d
        t2 = (np.asarray(hi) - o) / d
    tn = np.nanmax(np.minimum(t1, t2), axis=1)
    tf = np.nanmin(np.maximum(t1, t2), axis=1)
    return (tn <= tf) & (tf > 0) & (tn < tmax)


def test_occluded_transfer_against_a_dense_numpy_quadrature():
    """24 points on a floor 1–8 cm from a 10 cm box (in front of a face and off a corner):
    the 81-ray transfer (Mitsuba's ray tests) against E3 summed over 200 000 directions with a
    NumPy slab test for the box: within 15 % of ‖T‖ at every point (measured ≤ 12.5 %, the
    81-direction quadrature of the blocked part), and on average as close as the plain 81-ray
    sum (E3 over the same directions, NumPy visibility). Rejects a sign error on the blocked
    part (the box would add light), blocked directions not weighted by their cosine, and a
    visibility range ignored (rays hit the box beyond 10 cm)."""
    lo, hi = np.array([0.0, 0.0, -0.05]), np.array([0.1, 0.1, 0.05])
    views = views_of([box("occ", hi - lo, (lo + hi) / 2)])
    r = np.repeat([0.01, 0.02, 0.03, 0.045, 0.06, 0.08], 4)
    ang = np.tile(np.radians([180.0, 150.0, 120.0, 215.0]), 6)
    p = np.stack([r * np.cos(ang), np.zeros_like(r), r * np.sin(ang)], axis=1)
    p[:, 2] += np.where(ang > np.pi, -0.05, 0.0)  # the last azimuth: off the corner
    n = np.tile([0.0, 1.0, 0.0], (len(p), 1))
    t81 = compute_transfer(views, p, n, DirectionSet(81, 1), ray_offset=0.0).real

    def plain(dirs: np.ndarray, pt: np.ndarray) -> np.ndarray:
        cos = np.clip(dirs[:, 1], 0.0, None)
        vis = ~_slab_blocked(pt, dirs, lo, hi, 0.10)
        return (4 * np.pi / len(dirs)) * (cos * vis) @ SH.sh_basis(dirs, 3)

    dense, d81 = fibonacci_sphere(200000), DirectionSet(81, 1).directions
    err, err_plain = [], []
    for i in range(len(p)):
        ref = plain(dense, p[i])
        err.append(np.linalg.norm(t81[i] - ref) / np.linalg.norm(ref))
        err_plain.append(np.linalg.norm(plain(d81, p[i]) - ref) / np.linalg.norm(ref))
    assert max(err) < 0.15, max(err)
    # the two 81-direction forms are alike where rays are blocked (mean 5.7 % and 5.8 %):
    # the gain of E6-minus-blocked is the unoccluded part, exact (test above)
    assert np.mean(err) < 1.5 * np.mean(err_plain), (np.mean(err), np.mean(err_plain))


def test_batched_groups_equal_separate_calls(monkeypatch):
    """:func:`compute_transfers` (the rays of every interleave phase in one batch, issue #33's
    ART timing) gives each group bit for bit what its own :func:`compute_transfer` call gives,
    with a virtual box (real rays cast only where the mixed ray was blocked and the group
    asks for ``T_real``), groups of different subsets and sizes, an empty group, and groups
    split into several point batches (``_POINTS`` set to 7). Rejects a group reading another
    group's slice of the rays (an offset error in the split), ``need_real`` applied to the
    wrong lanes (``T_real`` is checked against the world without the virtual box where a
    group asks for it and the unoccluded share elsewhere), and ray counts of the whole batch
    given to each group."""
    from arlight.probeless import transfer as T

    virt = box("v", (0.04, 0.04, 0.04), (-0.05, 0.03, 0.09), role="virtual")
    views = views_of([box("occ", (0.1, 0.1, 0.1), (0.05, 0.05, 0.0)), virt])
    assert views.real is not views.mixed
    rng = np.random.default_rng(4)
    ds = DirectionSet(81, 4)
    groups = []
    for m, phase in ((23, 0), (0, 1), (9, 2), (31, 3), (17, 1)):
        p = np.stack([rng.uniform(-0.12, 0.0, m), np.zeros(m), rng.uniform(-0.08, 0.08, m)], 1)
        n = np.tile([0.0, 1.0, 0.0], (m, 1))
        groups.append((p, n, ds.subset(phase), rng.random(m) < 0.6))
    monkeypatch.setattr(T, "_POINTS", 7)
    batched = T.compute_transfers(views, groups, ds)
    assert sum(np.count_nonzero(b.blocked) for b in batched) > 10
    assert any(np.any(b.real != b.mixed) for b in batched)  # the virtual box is seen
    real_only = views_of([box("occ", (0.1, 0.1, 0.1), (0.05, 0.05, 0.0))])
    for g, got in zip(groups, batched, strict=True):
        ref = T.compute_transfer(views, g[0], g[1], ds, g[2], g[3])
        for k in ("real", "mixed", "cast", "blocked"):
            assert np.array_equal(getattr(got, k), getattr(ref, k)), k
        assert got.rays == ref.rays
        if len(g[0]) == 0:
            continue
        # T_real where asked: the transfer in the world without the virtual box; elsewhere
        # the unoccluded share (no real ray cast)
        alone = T.compute_transfer(real_only, g[0], g[1], ds, g[2]).mixed
        np.testing.assert_allclose(got.real[g[3]], alone[g[3]], atol=1e-12)
        free = unoccluded_transfer(g[1]) * (len(g[2]) / ds.n)
        np.testing.assert_allclose(got.real[~g[3]], free[~g[3]], atol=1e-12)
