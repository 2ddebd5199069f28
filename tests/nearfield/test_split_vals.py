"""Checklist items 5 (τ split), 6 (importance sampling), 7 (coherence), 8 (energy),
9 (Eq. 5 vs Eq. 4) and 16 (VPL baseline, Eq. 15)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from arlight.errors import InputError
from arlight.nearfield.radiometry import direct_radiance
from arlight.nearfield.split import split
from arlight.nearfield.vals import (
    extract_vals,
    integrate,
    sample_texels,
    texel_pdf,
    vpl_lights,
)


def _atlas(n=400, seed=0):
    rng = np.random.default_rng(seed)
    L = rng.exponential(0.2, (n, 3))
    L[:20] += [8.0, 1.0, 0.5]           # a bright reddish source
    L[50:60, 2] += 6.0                  # a blue source on a grey-ish region
    area = rng.uniform(0.5e-3, 1.5e-3, n)
    return L, area


@pytest.mark.parametrize("tau", [0.3, 0.75, 0.9, 0.98])
def test_split_is_the_shortest_prefix_per_channel(tau):
    L, a = _atlas()
    sp = split(L, a, tau)
    inten = L * a[:, None]
    for c in range(3):
        d = sp.is_direct[:, c]
        total = inten[:, c].sum()
        assert inten[d, c].sum() >= tau * total
        dimmest = np.argmin(np.where(d, inten[:, c], np.inf))
        assert inten[d, c].sum() - inten[dimmest, c] < tau * total
        # every direct texel is at least as bright as every indirect one
        assert inten[d, c].min() >= inten[~d, c].max()
    assert np.allclose(sp.direct + sp.indirect, L)
    if tau >= 0.75:
        assert sp.is_direct[50:60, 2].all()  # the blue source is direct in blue


def test_tau_extremes_and_bad_tau():
    L, a = _atlas()
    s1 = split(L, a, 1.0)
    assert np.all(s1.indirect == 0) and s1.is_direct.all()
    s0 = split(L, a, 0.0)
    assert not s0.is_direct.any() and np.array_equal(s0.indirect, L)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(InputError, match="τ"):
            split(L, a, bad)


def test_importance_sampling_matches_the_pdf():
    rng = np.random.default_rng(3)
    inten = rng.exponential(1.0, (40, 3))
    inten[[3, 17, 30]] = 0.0
    pdf = texel_pdf(inten)
    idx = sample_texels(pdf, 100_000, seed=5)
    counts = np.bincount(idx, minlength=40)
    assert counts[[3, 17, 30]].sum() == 0
    nz = pdf > 0
    _, p = stats.chisquare(counts[nz], 100_000 * pdf[nz])
    assert p > 0.01


def _direct_scene(n_side=24):
    """Two emitting patches on a ceiling (z up = y) and texel geometry."""
    xs = (np.arange(n_side) + 0.5) / n_side * 0.4
    gx, gz = np.meshgrid(xs, xs)
    a = np.column_stack([gx.ravel() - 0.6, np.full(gx.size, 2.0), gz.ravel()])
    b = np.column_stack([gx.ravel() + 0.3, np.full(gx.size, 2.0), gz.ravel() - 0.5])
    pos = np.vstack([a, b])
    nrm = np.tile([0.0, -1.0, 0.0], (len(pos), 1))
    area = np.full(len(pos), (0.4 / n_side) ** 2)
    L = np.vstack([np.tile([10.0, 9.0, 8.0], (len(a), 1)), np.tile([2.0, 3.0, 4.0],
                                                                     (len(b), 1))])
    return pos, nrm, area, L


def test_energy_is_conserved_and_areas_add_up():
    pos, nrm, area, L = _direct_scene()
    v = extract_vals(pos, nrm, area, L, np.ones(len(pos), bool), 8, 3.0)
    total = (L * area[:, None]).sum(0)
    assert np.allclose(v.intensity.sum(0), total, rtol=1e-6, atol=0)
    assert np.isclose(v.area.sum(), area.sum(), rtol=1e-9)
    with pytest.raises(InputError, match="M"):
        extract_vals(pos, nrm, area, L, np.ones(len(pos), bool), 0, 3.0)


def test_clustering_is_coherent():
    pos, nrm, area, L = _direct_scene()
    mask = np.ones(len(pos), bool)
    v1 = extract_vals(pos, nrm, area, L, mask, 8, 3.0, seed=2)
    v2 = extract_vals(pos, nrm, area, L, mask, 8, 3.0, init=v1.centres, seed=2)
    v3 = extract_vals(pos, nrm, area, L, mask, 8, 3.0, init=v2.centres, seed=2)
    assert np.allclose(v2.positions, v3.positions, atol=1e-12)
    assert np.array_equal(v2.labels, v3.labels)
    # 1 % radiance noise, warm start: mean VAL shift below one texel width
    texel = 0.4 / 24
    rng = np.random.default_rng(9)
    prev = v3
    shifts = []
    for _ in range(5):
        noisy = L * (1 + 0.01 * rng.standard_normal(L.shape))
        cur = extract_vals(pos, nrm, area, noisy, mask, 8, 3.0, init=prev.centres, seed=2)
        d = np.linalg.norm(cur.positions[:, None] - prev.positions[None], axis=2)
        shifts.append(d.min(axis=1).mean())
        prev = cur
    assert np.mean(shifts) < texel


def test_single_val_matches_the_texel_sum_far_away_and_exactly_per_texel():
    pos, nrm, area, L = _direct_scene()
    sel = slice(0, 24 * 24)  # one patch, one cluster
    lab = np.zeros(24 * 24, np.int64)
    P, N, I, A = integrate(lab, 1, pos[sel], nrm[sel], area[sel], L[sel])
    R = np.sqrt(A[0] / np.pi)
    # receivers on the floor at >= 5 cluster radii from the VAL centre
    x = np.array([[P[0, 0] + dx, 2.0 - h, P[0, 2]] for dx, h in
                  ((0.0, 6 * R), (0.5, 1.8), (-0.3, 1.2))])
    n = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    alb = np.array([0.5, 0.5, 0.5])
    per_texel = direct_radiance(x, n, alb, pos[sel], nrm[sel], L[sel] * area[sel, None],
                                area[sel], disc=False)
    val = direct_radiance(x, n, alb, P, N, I, A, disc=True)
    assert np.all(np.abs(val / per_texel - 1) < 0.02)
    # M = N_Dir: every texel its own VAL reproduces Eq. 4 (V = 1) exactly
    each = np.arange(len(pos))
    P2, N2, I2, A2 = integrate(each, len(pos), pos, nrm, area, L)
    eq4 = direct_radiance(x, n, alb, pos, nrm, L * area[:, None], area, disc=False)
    eq7 = direct_radiance(x, n, alb, P2, N2, I2, A2, disc=False)
    assert np.allclose(eq7, eq4, rtol=1e-12)


def test_vpl_total_intensity_is_unbiased():
    pos, nrm, area, L = _direct_scene(8)
    truth = (L * area[:, None]).sum(0)
    totals = np.array([vpl_lights(pos, nrm, area, L, 16, seed=s)[2].sum(0)
                       for s in range(200)])
    mean, se = totals.mean(0), totals.std(0, ddof=1) / np.sqrt(len(totals))
    assert np.all(np.abs(mean - truth) <= 3 * se + 1e-12)
