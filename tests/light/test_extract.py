"""Light extraction: median cut, variance minimisation, highlight split, Kan's blob."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.light import extract as X
from arlight.sphere import sh
from arlight.sphere.envmap import equirect_directions, equirect_solid_angle


def disk_map(height: int = 64, center=(0.3, 0.8, -0.5), radius_deg: float = 8.0,
             value=(50.0, 40.0, 30.0), floor: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(center, float)
    c /= np.linalg.norm(c)
    d = equirect_directions(height)
    inside = d @ c > np.cos(np.radians(radius_deg))
    img = np.full(d.shape, floor, np.float32)
    img[inside] = value
    return img, c


def map_integral(img: np.ndarray) -> np.ndarray:
    return (img.astype(np.float64) * equirect_solid_angle(img.shape[0])[..., None]).sum((0, 1))


@pytest.mark.parametrize("method", ["median_cut", "variance"])
def test_total_power_equals_map_integral(grace, method):
    lights = X.median_cut(grace, 16, method=method)
    assert len(lights) == 16
    total = sum(lt.irradiance for lt in lights)
    np.testing.assert_allclose(total, map_integral(grace), rtol=1e-2)
    # a partition of the sphere: the solid angles add up to 4 pi
    assert sum(lt.solid_angle for lt in lights) == pytest.approx(4 * np.pi, rel=1e-9)


@pytest.mark.parametrize("method", ["median_cut", "variance"])
def test_bright_disk_yields_lights_inside_disk(method):
    img, c = disk_map(floor=0.0)
    lights = X.median_cut(img, 16, method=method)
    E_disk = map_integral(img)[0]
    lit = [lt for lt in lights if lt.irradiance[0] > 0]
    assert len(lit) >= 8
    for lt in lit:  # every light that carries energy sits inside the disk
        assert np.degrees(np.arccos(np.clip(lt.direction @ c, -1, 1))) < 8.0
    assert sum(lt.irradiance[0] for lt in lit) == pytest.approx(E_disk, rel=1e-9)


def test_disk_on_faint_background_keeps_energy_in_disk():
    img, c = disk_map(floor=0.01)
    lights = X.variance_minimisation(img, 16)
    w = np.array([lt.irradiance[0] for lt in lights])
    ang = np.degrees(np.arccos(np.clip([lt.direction @ c for lt in lights], -1, 1)))
    assert w[ang < 8.0].sum() > 0.8 * w.sum()


def test_non_power_of_two_and_brightest_first(grace):
    lights = X.median_cut(grace, 5)
    assert len(lights) == 5
    lum = [lt.irradiance @ sh.LUMINANCE for lt in lights]
    assert lum == sorted(lum, reverse=True)


def test_variance_minimisation_is_tighter_than_median_cut(grace):
    """VD09's criterion: lower summed energy-weighted angular spread of the regions."""
    d = equirect_directions(grace.shape[0]).reshape(-1, 3)
    w = ((grace @ sh.LUMINANCE) * equirect_solid_angle(grace.shape[0])).ravel()

    def spread(lights):
        dirs = np.stack([lt.direction for lt in lights])
        nearest = np.argmax(d @ dirs.T, axis=1)
        return np.sum(w * (1 - np.sum(d * dirs[nearest], axis=1)))

    assert spread(X.median_cut(grace, 16, "variance")) < spread(X.median_cut(grace, 16))


def test_split_highlights_conserves_energy(grace):
    thr = X.auto_threshold(grace)
    bright, rest = X.split_highlights(grace, thr)
    np.testing.assert_allclose(bright + rest, grace, rtol=1e-5, atol=1e-6)
    assert (rest @ sh.LUMINANCE).max() <= thr * (1 + 1e-5)
    assert bright.min() >= 0


def test_light_tables():
    lt = X.ExtractedLight(direction=[0, 2, 0], irradiance=[1, 2, 3])
    d = lt.to_directional()
    assert d["type"] == "directional" and d["direction"] == [0, -1, 0]
    p = lt.to_point(3.0, origin=np.array([1.0, 0, 0]))
    assert p["position"] == [1.0, 3.0, 0.0] and p["intensity"] == [9.0, 18.0, 27.0]


def test_brightest_blob_on_equirect_with_distractor():
    img, c = disk_map(radius_deg=10.0)
    # a smaller, brighter distractor elsewhere
    d = equirect_directions(img.shape[0])
    other = np.array([-0.7, 0.2, 0.68])
    other /= np.linalg.norm(other)
    img[d @ other > np.cos(np.radians(4.0))] = 200.0
    lt = X.brightest_blob(img, d, equirect_solid_angle(img.shape[0]), threshold=1.0,
                          wrap_columns=True)
    assert np.degrees(np.arccos(lt.direction @ c)) < 180 / img.shape[0]
    # irradiance of the blob = its radiance x its solid angle
    omega = 2 * np.pi * (1 - np.cos(np.radians(10.0)))
    np.testing.assert_allclose(lt.irradiance, np.array([50.0, 40.0, 30.0]) * omega, rtol=0.05)


def test_brightest_blob_across_the_seam():
    img, c = disk_map(center=(0.0, 0.3, -1.0), radius_deg=12.0)  # -Z: u = 0 seam
    d = equirect_directions(img.shape[0])
    lt = X.brightest_blob(img, d, equirect_solid_angle(img.shape[0]), threshold=1.0,
                          wrap_columns=True)
    assert np.degrees(np.arccos(lt.direction @ c)) < 1.0


def test_brightest_blob_none_when_dark():
    img = np.zeros((8, 16, 3), np.float32)
    assert X.brightest_blob(img, equirect_directions(8), equirect_solid_angle(8)) is None
