"""Fisheye cameras: equidistant and OpenCV (Kannala-Brandt) models, round trips, blobs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arlight.light import extract as X
from arlight.sphere import envmap as E
from arlight.sphere.fisheye import FisheyeCamera


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def kb_camera() -> FisheyeCamera:
    return FisheyeCamera(K=[[160.0, 0, 256.5], [0, 161.0, 255.0], [0, 0, 1]],
                         D=[0.03, -0.01, 0.002, -0.0003], size=(512, 512), fov_deg=185)


def upper_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d[:, 1] = np.abs(d[:, 1])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("cam", [FisheyeCamera.equidistant((400, 400), fov_deg=185),
                                 kb_camera()], ids=["equidistant", "kannala-brandt"])
def test_direction_pixel_direction_roundtrip(cam):
    d = upper_dirs(2000)
    xy, valid = cam.project(d)
    assert valid.all()  # the whole upper hemisphere is inside a 185 deg lens
    d2, valid2 = cam.unproject(xy)
    assert valid2.all()
    assert angle_deg(d, d2).max() < 0.1
    # and pixel -> direction -> pixel on the image grid
    px = cam.pixel_centres().reshape(-1, 2)
    dd, ok = cam.unproject(px)
    back, _ = cam.project(dd[ok])
    assert np.abs(back - px[ok]).max() < 1e-6


def test_matches_opencv_fisheye_inside_90_degrees():
    import cv2

    cam = kb_camera()
    d = upper_dirs(500, seed=1)
    dc = d @ cam.world_from_camera
    sel = dc[:, 2] > 0.05
    pts, _ = cv2.fisheye.projectPoints(dc[sel][:, None, :], np.zeros(3), np.zeros(3),
                                       cam.K, cam.D)
    xy, _ = cam.project(d[sel])
    # same K: OpenCV counts pixel centres from 0, we from 0.5 -- identical numbers here
    np.testing.assert_allclose(pts[:, 0], xy, atol=1e-8)


def test_zenith_pose_and_solid_angle():
    cam = FisheyeCamera.equidistant((300, 300), fov_deg=180)
    xy, _ = cam.project(np.array([[0, 1.0, 0], [1.0, 1e-9, 0], [0, 1e-9, 1.0]]))
    np.testing.assert_allclose(xy[0], [150, 150], atol=1e-9)  # zenith at the centre
    assert xy[1, 0] > 290  # +X to the right
    assert xy[2, 1] < 10  # +Z at the top of the image
    assert cam.pixel_solid_angle().sum() == pytest.approx(2 * np.pi, rel=2e-3)


def test_synthetic_fisheye_from_equirect_roundtrip(make_smooth):
    env = make_smooth(128)
    cam = FisheyeCamera.equidistant((512, 512), fov_deg=180)
    img, valid = E.from_equirect(env, "fisheye", (512, 512), camera=cam)
    assert valid.mean() == pytest.approx(np.pi / 4, rel=0.02)
    back = E.to_equirect(img, "fisheye", height=64, camera=cam, mirror_lower=True)
    ref = E.to_equirect(env, "equirect", height=64)
    upper = slice(2, 30)  # away from the horizon row where the image circle ends
    rel = np.abs(back[upper] - ref[upper]).mean() / ref[upper].mean()
    assert rel < 0.01
    np.testing.assert_allclose(back[-1], back[0], rtol=1e-5)  # lower = mirrored upper


def render_blobs(cam: FisheyeCamera, blobs, ss: int = 4) -> np.ndarray:
    """Analytic fisheye render of disks ``(direction, radius_deg, radiance)``, ss^2 spp."""
    w, h = cam.size
    img = np.zeros((h, w, 3))
    offs = (np.arange(ss) + 0.5) / ss
    for oy in offs:
        for ox in offs:
            xs, ys = np.meshgrid(np.arange(w) + ox, np.arange(h) + oy)
            d, ok = cam.unproject(np.stack([xs, ys], -1))
            for c, r, L in blobs:
                img[(d @ c > np.cos(np.radians(r))) & ok] += L / ss**2
    return img.astype(np.float32)


@pytest.mark.parametrize("cam", [FisheyeCamera.equidistant((360, 360), fov_deg=185),
                                 kb_camera()], ids=["equidistant", "kannala-brandt"])
def test_bright_blob_recovered_within_one_pixel(cam):
    theta, phi = np.radians(50.0), np.radians(120.0)  # from +Y; phi as in the equirect
    target = np.array([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)])
    distractor = np.array([-0.5, 0.6, 0.62])
    distractor /= np.linalg.norm(distractor)
    img = render_blobs(cam, [(target, 6.0, 40.0), (distractor, 3.0, 80.0)])
    d, ok = cam.unproject(cam.pixel_centres())
    lt = X.brightest_blob(img, d, cam.pixel_solid_angle(), threshold=5.0)
    assert np.radians(angle_deg(lt.direction, target)) < cam.pixel_angle()
    # Kan's room-size point light: position along that direction
    p = lt.to_point(3.0)
    np.testing.assert_allclose(np.asarray(p["position"]) / 3.0, lt.direction)


def test_load_opencv_yaml_and_json(tmp_path):
    import cv2

    K = np.array([[300.0, 0, 319.5], [0, 300.0, 239.5], [0, 0, 1]])
    fs = cv2.FileStorage(str(tmp_path / "cal.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array([[0.1, 0.01, 0.0, 0.0]]))
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.release()
    cam = FisheyeCamera.load(tmp_path / "cal.yml", fov_deg=190)
    assert cam.size == (640, 480) and cam.fov_deg == 190
    assert cam.K[0, 2] == pytest.approx(320.0)  # +0.5 into our pixel convention
    np.testing.assert_allclose(cam.D, [0.1, 0.01, 0, 0])
    (tmp_path / "cal.json").write_text(json.dumps({"K": K.tolist(), "size": [640, 480]}))
    assert FisheyeCamera.load(tmp_path / "cal.json").K[0, 2] == pytest.approx(319.5)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ValueError, match="bad.json"):
        FisheyeCamera.load(tmp_path / "bad.json")
