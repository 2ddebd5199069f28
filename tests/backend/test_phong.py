"""Kán's plausible Phong BSDF: sampling, pdf and evaluation are consistent."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.phong import PLUGIN_NAME, register

N = 400_000


def _bsdf(kd, ks, n):
    register()
    return mi.load_dict({"type": PLUGIN_NAME, "kd": mi.ScalarColor3f(kd),
                         "ks": mi.ScalarColor3f(ks), "n": n})


def _si(theta_i: float, n: int):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(float(np.sin(theta_i)), 0.0, float(np.cos(theta_i)))
    return si


def _uniform_hemisphere(n: int, seed: int):
    rng = np.random.default_rng(seed)
    u = mi.Point2f(*rng.random((2, n)).astype(np.float32))
    return mi.warp.square_to_uniform_hemisphere(u), 1.0 / (2 * np.pi)


@pytest.mark.parametrize("theta_i", [0.2, 1.2])
def test_pdf_integrates_to_one(theta_i):
    """Near normal incidence the whole lobe is above the horizon: ∫pdf = 1; at grazing
    incidence the lobe mass below the horizon is lost (samples there are rejected): < 1."""
    bsdf = _bsdf([0.4, 0.4, 0.4], [0.5, 0.5, 0.5], 15.0)
    wo, p_uniform = _uniform_hemisphere(N, 1)
    vals = np.array(bsdf.pdf(mi.BSDFContext(), _si(theta_i, N), wo)) / p_uniform
    mean, se = vals.mean(), vals.std() / np.sqrt(N)
    if theta_i < 0.5:
        assert abs(mean - 1.0) < 3 * se
    else:
        assert mean < 1.0 - 3 * se


@pytest.mark.parametrize("theta_i", [0.3, 1.0])
def test_sample_weight_matches_eval_integral(theta_i):
    kd, ks, n = [0.5, 0.3, 0.2], [0.3, 0.4, 0.5], 25.0
    bsdf = _bsdf(kd, ks, n)
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(2)
    s1 = mi.Float(rng.random(N).astype(np.float32))
    s2 = mi.Point2f(*rng.random((2, N)).astype(np.float32))
    _, weight = bsdf.sample(ctx, _si(theta_i, N), s1, s2)
    w = np.array(weight).T  # (N, 3)
    wo, p_uniform = _uniform_hemisphere(N, 3)
    f = np.array(bsdf.eval(ctx, _si(theta_i, N), wo)).T / p_uniform
    for c in range(3):
        se = np.hypot(w[:, c].std(), f[:, c].std()) / np.sqrt(N)
        assert abs(w[:, c].mean() - f[:, c].mean()) < 4 * se + 1e-4


def test_lambertian_limit_has_albedo_kd():
    bsdf = _bsdf([0.8, 0.5, 0.2], [0.0, 0.0, 0.0], 10.0)
    rng = np.random.default_rng(4)
    n = 10_000
    _, weight = bsdf.sample(mi.BSDFContext(), _si(0.4, n),
                            mi.Float(rng.random(n).astype(np.float32)),
                            mi.Point2f(*rng.random((2, n)).astype(np.float32)))
    assert np.allclose(np.array(weight).T, [0.8, 0.5, 0.2], atol=1e-5)


def test_specular_peak_value():
    """At the mirror direction f = k_d/π + k_s (n+2)/(2π) (times cos θ_o in eval)."""
    kd, ks, n = 0.2, 0.6, 40.0
    bsdf = _bsdf([kd] * 3, [ks] * 3, n)
    th = 0.5
    wo = mi.Vector3f(-float(np.sin(th)), 0.0, float(np.cos(th)))
    val = np.array(bsdf.eval(mi.BSDFContext(), _si(th, 1), wo))[0, 0]
    assert val == pytest.approx((kd / np.pi + ks * (n + 2) / (2 * np.pi)) * np.cos(th), rel=1e-5)
