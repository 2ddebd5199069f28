"""Camera rays: agreement with the NumPy camera model and multi-jitter stratification."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from arlight.backend.camera_rays import generate_rays, pixel_key, stratified_2d
from arlight.scene.camera import Camera, look_at


def test_stratified_points_are_multi_jittered():
    n = 6
    spp = n * n
    key = pixel_key(mi.UInt32(np.full(spp, 17, np.uint32)), mi.UInt32(5))
    p = stratified_2d(key, dr.arange(mi.UInt32, spp), spp, 0)
    x, y = np.array(p.x), np.array(p.y)
    cells = set(zip((x * n).astype(int), (y * n).astype(int), strict=True))
    assert len(cells) == spp  # one sample per N×N cell
    assert len(set((x * spp).astype(int))) == spp  # one per thin column
    assert len(set((y * spp).astype(int))) == spp  # one per thin row


def test_same_seed_same_rays_other_seed_other_rays():
    cam = Camera.from_fov(8, 6, 50.0, world_from_camera=look_at([0, 1, 3], [0, 0, 0]))
    pix = dr.arange(mi.UInt32, 48)
    k = mi.UInt32(np.full(48, 3, np.uint32))
    a = np.array(generate_rays(cam, pix, k, 16, mi.UInt32(1)).d)
    b = np.array(generate_rays(cam, pix, k, 16, mi.UInt32(1)).d)
    c = np.array(generate_rays(cam, pix, k, 16, mi.UInt32(2)).d)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("aperture", [0.0, 0.05])
def test_rays_pass_through_their_pixel(aperture):
    """Projecting a point on each ray at the focus distance lands inside its pixel."""
    cam = Camera(16, 12, 14.0, 15.0, 7.3, 6.1, look_at([0.3, 1, 3], [0, 0, 0]),
                 aperture_radius=aperture, focus_distance=2.5)
    n_pix = 16 * 12
    pix = dr.arange(mi.UInt32, n_pix * 4)
    k = pix // n_pix
    rays = generate_rays(cam, pix % n_pix, k, 4, mi.UInt32(9))
    o, d = np.array(rays.o).T, np.array(rays.d).T
    fwd = cam.world_from_camera[:3, 2]
    t = cam.focus_distance / (d @ fwd) - (o - cam.position) @ fwd / (d @ fwd)
    uv, _ = cam.project(o + t[:, None] * d)
    p = np.arange(n_pix * 4) % n_pix
    assert np.all(np.floor(uv[:, 0]) == p % 16)
    assert np.all(np.floor(uv[:, 1]) == p // 16)
