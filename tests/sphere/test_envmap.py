"""Environment-map mappings, conversions and the importance-sampling CDF."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.light.sampling import EnvmapSampler
from arlight.sphere import envmap as E
from arlight.sphere import sh


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def test_equirect_convention_axes():
    # conventions.md: top row +Y, u=0 -> -Z, u=0.25 -> +X, u=0.5 -> +Z, u=0.75 -> -X
    xy = E.direction_to_equirect(np.array([[0, 0, -1.0], [1, 0, 0], [0, 0, 1], [-1, 0, 0],
                                           [0, 1, 0]]), 100)
    np.testing.assert_allclose(xy[:4, 0] % 200, [0, 50, 100, 150], atol=1e-9)
    assert xy[4, 1] == pytest.approx(0.0)
    d = E.equirect_directions(4, 8)
    assert d[0, 0, 1] > 0.9 and d[-1, 0, 1] < -0.9
    assert E.equirect_solid_angle(16).sum() == pytest.approx(4 * np.pi)


@pytest.mark.parametrize("mapping,shape,kw", [
    ("equirect", (64, 128), {}),
    ("angular", (200, 200), {}),
    ("ball", (220, 240), {"center": (120.0, 105.0), "radius": 95.0}),
])
def test_mapping_roundtrip(mapping, shape, kw):
    d = random_dirs(500)
    xy, valid = E.project_directions(mapping, shape, d, **kw)
    proj, unproj = E._projector(mapping, shape, kw)
    d2, valid2 = unproj(xy)
    assert valid.mean() > 0.99
    assert angle_deg(d[valid & valid2], d2[valid & valid2]).max() < 1e-4


def test_angular_and_ball_orientation():
    xy, _ = E.project_directions("angular", (200, 200), np.array([[0, 0, -1.0], [1, 0, 0],
                                                                  [0, 1, 0]]))
    np.testing.assert_allclose(xy, [[100, 100], [150, 100], [100, 50]], atol=1e-9)
    # a light straight above a mirror ball (camera looking along -Z) shows at the top
    xy, _ = E.project_directions("ball", (200, 200), np.array([[0, 1.0, 0], [0, 0, 1.0]]),
                                 center=(100, 100), radius=100)
    assert xy[0, 1] < 40 and xy[0, 0] == pytest.approx(100)
    np.testing.assert_allclose(xy[1], [100, 100], atol=1e-9)  # the camera sees itself


@pytest.mark.parametrize("mapping,size,kw", [
    ("angular", 256, {}),
    ("ball", 256, {"center": (128.0, 128.0), "radius": 127.0}),
])
def test_conversion_preserves_sh(mapping, size, kw, make_smooth):
    env = make_smooth(64)
    img, _ = E.from_equirect(env, mapping, size, **kw)
    back = E.to_equirect(img, mapping, height=64, **kw)
    assert back.shape == (64, 128, 3) and back.dtype == np.float32
    c0 = sh.project_equirect(env, 2)
    c1 = sh.project_equirect(back, 2)
    # the ball loses a little around the grazing rim (+Z behind the ball)
    assert np.abs(c1 - c0).max() < 0.03 * np.abs(c0).max()


def test_to_equirect_equirect_resizes_and_mirrors(make_smooth):
    env = make_smooth(64)
    small = E.to_equirect(env, "equirect", height=32)
    assert small.shape == (32, 64, 3)
    assert small.mean() == pytest.approx(env.mean(), rel=1e-3)
    m = E.to_equirect(env, "equirect", mirror_lower=True)
    np.testing.assert_array_equal(m[-1], env[0])


def test_to_equirect_rejects_bad_input():
    with pytest.raises(ValueError, match="2:1"):
        E.to_equirect(np.zeros((10, 10, 3)), "equirect")
    with pytest.raises(ValueError, match="unknown mapping"):
        E.to_equirect(np.zeros((10, 10, 3)), "cubemap")
    with pytest.raises(ValueError, match="center"):
        E.to_equirect(np.zeros((10, 10, 3)), "ball")


def test_rotate_equirect_moves_a_lobe(make_smooth):
    from scipy.spatial.transform import Rotation

    env = make_smooth(64)
    R = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    rot = E.rotate_equirect(env, R)
    d_before = sh.dominant_direction(sh.project_equirect(env, 1))
    d_after = sh.dominant_direction(sh.project_equirect(rot, 1))
    assert angle_deg(R @ d_before, d_after) < 1.0


def test_sampler_pdf_consistent_and_unbiased(grace):
    s = EnvmapSampler(grace)
    rng = np.random.default_rng(0)
    n = 100_000
    d, pdf = s.sample(rng.random(n), rng.random(n))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(pdf, s.pdf(d), rtol=1e-9)
    # pdf integrates to one over the sphere (uniform Monte Carlo, with its standard error)
    u = random_dirs(n, seed=7)
    vals = s.pdf(u) * 4 * np.pi
    assert abs(vals.mean() - 1) < 4 * vals.std() / np.sqrt(n)
    # importance-sampled estimate of the luminance integral matches the exact sum
    lum = grace @ sh.LUMINANCE
    exact = (lum * E.equirect_solid_angle(grace.shape[0])).sum()
    xy = E.direction_to_equirect(d, grace.shape[0]).astype(int)
    f = lum[np.clip(xy[:, 1], 0, grace.shape[0] - 1), np.clip(xy[:, 0], 0, grace.shape[1] - 1)]
    est = f / pdf
    assert abs(est.mean() - exact) < 4 * est.std() / np.sqrt(n) + 1e-3 * exact


def test_sampler_prefers_bright_pixels():
    img = np.full((32, 64, 3), 0.01, np.float32)
    img[8:10, 40:42] = 100.0
    s = EnvmapSampler(img)
    rng = np.random.default_rng(1)
    d, _ = s.sample(rng.random(2000), rng.random(2000))
    xy = E.direction_to_equirect(d, 32)
    inside = (xy[:, 0] >= 40) & (xy[:, 0] < 42) & (xy[:, 1] >= 8) & (xy[:, 1] < 10)
    assert inside.mean() > 0.9
