"""Spherical harmonics: basis (Franke Eq. 4.4-4.7), projection, irradiance, rotation, C_ijk."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arlight.sphere import sh
from arlight.sphere.envmap import equirect_directions, equirect_solid_angle, rotate_equirect


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_y00_and_closed_forms():
    assert sh.sh_basis(np.array([[0.3, 0.4, np.sqrt(0.75)]]), 0)[0, 0] == pytest.approx(0.282095,
                                                                                      abs=1e-6)
    d = random_dirs(50)
    Y = sh.sh_basis(d, 2)
    x, y, z = d.T
    c1 = np.sqrt(3 / (4 * np.pi))
    # our frame: pole +Y, Condon-Shortley phase kept (Franke Eq. 4.5)
    np.testing.assert_allclose(Y[:, 1], -c1 * x, atol=1e-12)
    np.testing.assert_allclose(Y[:, 2], c1 * y, atol=1e-12)
    np.testing.assert_allclose(Y[:, 3], c1 * z, atol=1e-12)
    np.testing.assert_allclose(Y[:, 6], 0.315392 * (3 * y * y - 1), atol=1e-6)


def test_legendre_matches_scipy():
    from scipy.special import lpmv

    x = np.linspace(-1, 1, 41)
    P = sh.legendre_all(6, x)
    for (l, m), v in P.items():
        np.testing.assert_allclose(v, lpmv(m, l, x), atol=1e-9, err_msg=f"P_{l}^{m}")


@pytest.mark.parametrize("order", [3, 6])
def test_gram_matrix_exact_quadrature(order):
    d, w = sh.sphere_quadrature(2 * order)
    Y = sh.sh_basis(d, order)
    G = (Y * w[:, None]).T @ Y
    np.testing.assert_allclose(G, np.eye(sh.n_coeffs(order)), atol=1e-12)


def test_gram_matrix_monte_carlo():
    n = 100_000
    d = random_dirs(n, seed=1)
    Y = sh.sh_basis(d, 3)
    prod = Y[:, :, None] * Y[:, None, :] * 4 * np.pi
    G = prod.mean(axis=0)
    se = prod.std(axis=0) / np.sqrt(n)
    assert np.abs(G - np.eye(16)).max() < 1e-2
    assert np.all(np.abs(G - np.eye(16)) < 5 * se + 1e-12)


def test_projection_reconstruction_roundtrip():
    c = np.random.default_rng(2).normal(size=(16, 3))
    m = sh.sh_to_equirect(c, 128)
    c2 = sh.project_equirect(m, 3)
    np.testing.assert_allclose(c2, c, atol=2e-3)
    # evaluation on the grid agrees with pointwise evaluation
    d = equirect_directions(32)
    np.testing.assert_allclose(sh.sh_to_equirect(c, 32), sh.sh_eval(c, d), atol=1e-5)


def test_project_equirect_matches_midpoint_rule(smooth):
    H = smooth.shape[0]
    d = equirect_directions(H).reshape(-1, 3)
    w = equirect_solid_angle(H).ravel()
    brute = sh.project_samples(d, smooth.reshape(-1, 3).astype(np.float64), w, 4)
    tol = 2e-3 * np.abs(brute).max()
    np.testing.assert_allclose(sh.project_equirect(smooth, 4), brute, atol=tol)


def test_constant_environment_irradiance_is_pi_L():
    L = np.array([0.5, 1.0, 2.0])
    env = np.broadcast_to(L, (32, 64, 3)).astype(np.float32)
    c = sh.project_equirect(env, 2)
    E = sh.irradiance(c, random_dirs(200))
    np.testing.assert_allclose(E, np.broadcast_to(np.pi * L, E.shape), rtol=1e-6)


def test_irradiance_nine_coefficients_within_3_percent(make_smooth):
    env = make_smooth(64)
    c = sh.project_equirect(env, 2)
    normals = random_dirs(60, seed=3)
    d = equirect_directions(64).reshape(-1, 3)
    w = equirect_solid_angle(64).ravel()
    cos = np.clip(normals @ d.T, 0, None) * w  # (N, pixels)
    brute = cos @ env.reshape(-1, 3).astype(np.float64)
    approx = sh.irradiance(c, normals)
    rel = np.abs(approx - brute) / brute
    assert rel.mean() < 0.03
    # and it must be a real approximation, not the trivial constant term
    const_only = sh.irradiance(c[:1], normals)
    assert np.abs(const_only - brute).mean() > 3 * np.abs(approx - brute).mean()


def test_clamped_cosine_weights():
    assert sh.clamped_cosine_band(0) == pytest.approx(np.pi)
    assert sh.clamped_cosine_band(1) == pytest.approx(2 * np.pi / 3)
    assert sh.clamped_cosine_band(2) == pytest.approx(np.pi / 4)
    assert sh.clamped_cosine_band(3) == 0.0
    assert sh.clamped_cosine_band(4) == pytest.approx(-np.pi / 24)
    # numerically: project max(cos(angle to +Y), 0) and compare the zonal coefficients
    c = sh.project_function(lambda d: np.clip(d[:, 1], 0, None), 4, degree=200)
    for l in range(5):
        zonal = c[sh.sh_index(l, 0)]  # A_hat_l = sqrt(4 pi / (2l+1)) * zonal coefficient
        assert np.sqrt(4 * np.pi / (2 * l + 1)) * zonal == pytest.approx(
            sh.clamped_cosine_band(l), abs=2e-3), l


@pytest.mark.parametrize("order", [2, 5])
def test_rotation_preserves_energy_and_composes(order):
    c = np.random.default_rng(4).normal(size=(sh.n_coeffs(order), 3))
    R1 = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    R2 = Rotation.from_euler("zyx", [-0.7, 0.4, 0.9]).as_matrix()
    r = sh.rotate(c, R1)
    bands = sh.band_of_each_coeff(order)
    for l in range(order + 1):
        np.testing.assert_allclose(np.sum(r[bands == l] ** 2, axis=0),
                                   np.sum(c[bands == l] ** 2, axis=0), rtol=1e-10)
    np.testing.assert_allclose(sh.rotate(sh.rotate(c, R1), R2), sh.rotate(c, R2 @ R1),
                               atol=1e-10)
    # pointwise definition g(d) = f(R^T d)
    d = random_dirs(20, seed=5)
    np.testing.assert_allclose(sh.sh_eval(r, d), sh.sh_eval(c, d @ R1), atol=1e-10)


def test_rotation_matches_projection_of_rotated_map(make_smooth):
    env = make_smooth(128)
    R = Rotation.from_euler("yxz", [1.0, 0.5, -0.3]).as_matrix()
    c_rot = sh.rotate(sh.project_equirect(env, 4), R)
    c_map = sh.project_equirect(rotate_equirect(env, R), 4)
    scale = np.abs(c_map).max()
    assert np.abs(c_rot - c_map).max() < 5e-3 * scale


def test_dominant_direction_points_to_light(make_smooth):
    target = np.array([0.2, 0.9, -0.4])
    target /= np.linalg.norm(target)
    c = sh.directional_light_coeffs(target, [1.0, 1.0, 1.0], 2)
    np.testing.assert_allclose(sh.dominant_direction(c), target, atol=1e-12)
    env = make_smooth(64)
    dom = sh.dominant_direction(sh.project_equirect(env, 1))
    assert dom @ np.array([0.6, 0.64, 0.48]) > 0.95


def test_triple_product_tensor():
    L = 2
    C = sh.triple_product_tensor(L)
    n = sh.n_coeffs(L)
    np.testing.assert_allclose(C, C.transpose(1, 0, 2), atol=1e-13)
    np.testing.assert_allclose(C, C.transpose(2, 1, 0), atol=1e-13)
    np.testing.assert_allclose(C[0], np.eye(n) / (2 * np.sqrt(np.pi)), atol=1e-13)
    # product of two band-1 functions is band 2: exact in an order-2 output
    rng = np.random.default_rng(6)
    f = np.zeros(n)
    g = np.zeros(n)
    f[:4], g[:4] = rng.normal(size=4), rng.normal(size=4)
    brute = sh.project_function(lambda d: sh.sh_eval(f, d) * sh.sh_eval(g, d), L)
    np.testing.assert_allclose(sh.product(f, g, C), brute, atol=1e-12)


def test_bad_coefficient_count_is_rejected():
    with pytest.raises(ValueError):
        sh.sh_to_equirect(np.zeros((8, 3)), 8)
