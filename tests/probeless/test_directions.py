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


def test_unoccluded_transfer_matches_zonal_harmonics():
    """An isolated point's 81-ray transfer is Â_l·Y_lm(n) within 3 % of ‖T‖ (band 3 ≈ 0);
    10k directions agree within 0.2 %. Rejects a missing cosine, a wrong quadrature weight
    (e.g. 2π/N) or a sign error in the basis."""
    rng = np.random.default_rng(3)
    n = rng.normal(size=(6, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = np.zeros((6, 3))
    views = views_of([box("far", (0.01, 0.01, 0.01), (5.0, 5.0, 5.0))])
    exact = unoccluded_transfer(n)
    t81 = compute_transfer(views, p, n, DirectionSet(81, 1)).real
    err = np.linalg.norm(t81 - exact, axis=1) / np.linalg.norm(exact, axis=1)
    assert err.max() < 0.03
    assert np.abs(exact[:, 9:]).max() < 1e-12  # Â_3 = 0
    t10k = compute_transfer(views, p, n, DirectionSet(10000, 1)).real
    err10k = np.linalg.norm(t10k - exact, axis=1) / np.linalg.norm(exact, axis=1)
    assert err10k.max() < 2e-3
