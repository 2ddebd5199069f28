import numpy as np
import pytest

from arlight.scene.camera import Camera, look_at


def test_look_at_axes_follow_opencv_convention():
    m = look_at([0, 0, 5], [0, 0, 0], [0, 1, 0])
    assert np.allclose(m[:3, 2], [0, 0, -1])  # z forward
    assert np.allclose(m[:3, 0], [1, 0, 0])  # x right
    assert np.allclose(m[:3, 1], [0, -1, 0])  # y down
    assert np.isclose(np.linalg.det(m[:3, :3]), 1.0)


def test_project_inverts_pixel_rays():
    cam = Camera(64, 48, 50.0, 55.0, 30.0, 25.0, look_at([1, 2, 3], [0, 0, 0]))
    uv = np.array([[0.5, 0.5], [10.25, 40.0], [63.5, 47.5]])
    o, d = cam.pixel_rays(uv)
    uv2, depth = cam.project(o + 2.0 * d)
    assert np.allclose(uv2, uv) and np.all(depth > 0)


def test_from_fov_principal_point_and_focal():
    cam = Camera.from_fov(640, 480, 90.0)
    assert cam.cx == 320 and cam.cy == 240
    assert cam.fy == pytest.approx(240.0)


def test_thin_lens_rays_meet_on_focal_plane():
    cam = Camera.from_fov(32, 32, 40.0, world_from_camera=look_at([0, 0, 4], [0, 0, 0]),
                          aperture_radius=0.1, focus_distance=4.0)
    uv = np.repeat([[12.3, 20.1]], 5, axis=0)
    lens = np.array([[0, 0], [1, 0], [0, -1], [0.5, 0.5], [-0.7, 0.2]])
    o, d = cam.pixel_rays(uv, lens)
    t = (0.0 - o[:, 2]) / d[:, 2]  # focal plane z = 0 in world
    p = o + t[:, None] * d
    assert np.allclose(p, p[0], atol=1e-9)


def test_resized_camera_keeps_ray_directions():
    cam = Camera(640, 480, 500.0, 510.0, 322.0, 239.0, look_at([1, 2, 3], [0, 0, 0]))
    small = cam.resized(160, 120)
    _, d_big = cam.pixel_rays(np.array([[320.0, 240.0], [0.0, 0.0], [640.0, 480.0]]))
    _, d_small = small.pixel_rays(np.array([[80.0, 60.0], [0.0, 0.0], [160.0, 120.0]]))
    assert np.allclose(d_big, d_small)
