"""The Dr.Jit splat matches the NumPy reference splat (same pairs, same weights, float32).

Wrong implementations rejected: a bin list that drops records overlapping several bins, a
missing box test (weights leaking past the clamp), float atomics (sums that change between
runs), a normal term that rounds the own pixel's weight away at large κ."""

from __future__ import annotations

import numpy as np

from arlight.tracing.irradiance_cache import splat
from arlight.tracing.irradiance_splat import splat_dr
from tests.tracing.test_irradiance_cache import plane_geometry, records_at


def test_dr_splat_matches_numpy_reference():
    cam, geom = plane_geometry(40, 30)
    geom.valid[::5] = False
    rng = np.random.default_rng(3)
    pix = rng.choice(40 * 30, 40, replace=False)
    recs = records_at(geom, pix, rng.random((40, 3)), radius=0.8)
    tilt = rng.normal(0, 0.05, (40, 3))
    recs.normal = recs.normal + tilt
    recs.normal /= np.linalg.norm(recs.normal, axis=1, keepdims=True)
    recs.stderr_mixed, recs.stderr_delta = rng.random((40, 3)), rng.random((40, 3))
    for kappa, lo, hi in ((1.0, 0.5, 1000.0), (0.5, 2.0, 5.0), (3.0, 0.5, 9.0)):
        ref = splat(recs, geom, cam, kappa, lo, hi)
        got = splat_dr(recs, geom, cam, kappa, lo, hi, bin_px=4)
        np.testing.assert_allclose(got.weight, ref.weight, atol=1e-5, rtol=1e-5)
        np.testing.assert_allclose(got.w_mixed, ref.w_mixed, atol=1e-5, rtol=1e-5)
        np.testing.assert_allclose(got.w_delta, ref.w_delta, atol=1e-5, rtol=1e-5)
        np.testing.assert_allclose(got.w2_var_mixed, ref.w2_var_mixed, atol=1e-5, rtol=1e-5)
        np.testing.assert_allclose(got.w2_var_delta, ref.w2_var_delta, atol=1e-5, rtol=1e-5)
        again = splat_dr(recs, geom, cam, kappa, lo, hi, bin_px=4)
        assert np.array_equal(again.w_mixed, got.w_mixed)
    assert splat_dr(recs.take(np.arange(0)), geom, cam, 1.0, 1.0, 2.0).weight.sum() == 0


def test_own_pixel_keeps_full_weight_at_large_kappa():
    cam, geom = plane_geometry(20, 15)
    pix = np.arange(0, 300, 7)
    recs = records_at(geom, pix, np.ones((len(pix), 3)))
    buf = splat_dr(recs, geom, cam, 1000.0, 0.25, 0.25)
    assert np.all(buf.weight[pix] == 1.0)
    assert np.count_nonzero(buf.weight) == len(pix)
