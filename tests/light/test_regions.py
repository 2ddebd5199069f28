"""Main lights from connected highlight regions on the sphere (issue 10, item 1)."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.light.estimate import LightEstimate
from arlight.light.extract import highlight_regions, luminance, sphere_components
from arlight.sphere import sh
from arlight.sphere.envmap import equirect_directions, equirect_solid_angle


def unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def sun_map(height: int, toward, radius_deg: float, radiance: float = 5000.0,
            sky: float = 0.5) -> np.ndarray:
    """A uniform grey sky plus a uniform disc ``radius_deg`` around ``toward``."""
    d = equirect_directions(height)
    disc = d @ unit(toward) >= np.cos(np.radians(radius_deg))
    img = np.full(d.shape, sky, np.float32)
    img[disc] = radiance
    return img


def disc_energy(img: np.ndarray, toward, radius_deg: float, sky: float) -> float:
    """Exact luminance energy of the disc above the sky level, summed independently."""
    d = equirect_directions(img.shape[0])
    disc = d @ unit(toward) >= np.cos(np.radians(radius_deg))
    om = equirect_solid_angle(img.shape[0])
    return float(((img[..., :3] @ sh.LUMINANCE - sky) * om)[disc].sum())


def angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(unit(a) @ unit(b), -1, 1))))


@pytest.mark.parametrize("toward", [
    [0.0, 0.3, -1.0],    # on the longitude seam (u = 0 is -Z): split in two by the image edge
    [0.05, 1.0, 0.02],   # over the north pole: spread over every column of the top rows
    [0.7, 0.5, 0.5],     # an ordinary place
])
def test_a_sun_is_one_light_with_its_energy(toward):
    """A compact source is ONE light holding (nearly) all of its energy, at its centre,
    wherever it is. Rejects median-cut fragments (the sun in 8-16 equal pieces), labelling
    that forgets the seam or the pole (two or many lights for one sun), and image-space
    centroids (biased near the pole)."""
    img = sun_map(128, toward, 3.0, sky=0.5)
    est = LightEstimate.from_envmap(img, n_lights=16)
    E = disc_energy(img, toward, 3.0, 0.5)
    main = float(est.main_irradiance @ sh.LUMINANCE)
    assert not est.lights, "one sun must give one light"
    assert angle_deg(est.main_direction, toward) < 0.5
    assert 0.97 * E <= main <= 1.001 * E
    assert np.degrees(est.main_spread) == pytest.approx(3.0, abs=0.8)
    assert est.main_solid_angle == pytest.approx(2 * np.pi * (1 - np.cos(np.radians(3))),
                                                 rel=0.25)
    assert est.explicit_fraction == pytest.approx(main / (4 * np.pi * float(
        (luminance(img) * equirect_solid_angle(128)).sum() / (4 * np.pi))), rel=1e-6)


def test_two_sources_two_lights_and_area_source_keeps_extent():
    """A sun and a large window are two lights: the window's spread is its size (~20 deg),
    the sun's is small. Rejects merging everything into one light, and a fixed light count
    (16 returned for a map with two sources)."""
    img = sun_map(128, [0.6, 0.6, 0.5], 1.5, radiance=20000.0, sky=0.3)
    window = sun_map(128, [-0.8, 0.2, -0.3], 20.0, radiance=30.0, sky=0.0)
    img = img + window
    est = LightEstimate.from_envmap(img, n_lights=16)
    assert len(est.lights) == 1
    win = est.lights[0]
    assert angle_deg(est.main_direction, [0.6, 0.6, 0.5]) < 0.5
    assert angle_deg(win.direction, [-0.8, 0.2, -0.3]) < 1.0
    assert np.degrees(win.spread) == pytest.approx(20.0, abs=2.0)
    assert np.degrees(est.main_spread) < 2.5
    capped = LightEstimate.from_envmap(img, n_lights=1)
    assert not capped.lights
    # the window's energy went back to the SH remainder: total energy unchanged
    np.testing.assert_allclose(capped.total_sh(2)[0], sh.project_equirect(img, 2)[0], rtol=1e-5)


def test_fragments_within_the_gap_merge():
    """Two halves of a lamp separated by a 0.5-deg dark bar are one light with the default
    1-deg gap, two with gap 0. Rejects a labelling that ignores the gap setting."""
    img = sun_map(180, [0.0, 0.0, 1.0], 4.0, radiance=1000.0, sky=0.2)
    d = equirect_directions(180)
    bar = np.abs(d[..., 0]) < np.sin(np.radians(0.6))
    img[bar & (d[..., 2] > 0.9)] = 0.2
    assert len(highlight_regions(img, 10.0, gap_deg=1.0).lights) == 1
    assert len(highlight_regions(img, 10.0, gap_deg=0.0).lights) == 2


def test_sphere_components_seam_and_poles():
    """Labels join across u = 0/1 (diagonally too) and around each pole, and nowhere else.
    Rejects plain image-space connected components."""
    m = np.zeros((8, 16), bool)
    m[3, 0] = m[4, 15] = True          # diagonal neighbours across the seam
    m[0, 2] = m[0, 10] = True          # opposite sides of the north pole
    m[7, 5] = True                     # alone at the south pole
    m[4, 7] = True                     # alone in the middle
    labels, n = sphere_components(m)
    assert n == 4
    assert labels[3, 0] == labels[4, 15] and labels[0, 2] == labels[0, 10]
    assert len({labels[3, 0], labels[0, 2], labels[7, 5], labels[4, 7]}) == 4
    assert (labels[~m] == 0).all()


def test_estimate_memory_stays_near_one_map():
    """from_envmap on a 1024x2048 map allocates (NumPy, traced) under 0.9 more maps:
    luminance once in float32, sparse highlights, SH by row bands. Rejects a float64 copy
    of the map (2 maps), an (H, W) float64 solid-angle plane (2/3 map) or a materialised
    clipped remainder (1 map)."""
    import tracemalloc

    img = sun_map(1024, [0.3, 0.8, 0.5], 2.0, sky=0.4)
    tracemalloc.start()
    try:
        LightEstimate.from_envmap(img, keep_map=False)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 0.9 * img.nbytes, peak / img.nbytes  # measured 0.78
