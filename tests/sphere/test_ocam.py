"""OCamCalib (Scaramuzza) fisheye model: calib_results.txt, pixel <-> direction (issue 10)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from arlight.errors import ArlightError
from arlight.sphere.envmap import from_equirect, to_equirect
from arlight.sphere.fisheye import FisheyeCamera, OcamCamera, load_camera

DATA = Path(__file__).resolve().parents[2] / "src" / "arlight" / "data" / "light"
CALIB = DATA / "ocamcalib_fisheye_calib_results.txt"
PHOTO = DATA / "ocamcalib_fisheye.jpg"


@pytest.fixture
def cam() -> OcamCamera:
    return load_camera(CALIB)


def pixel_grid(cam: OcamCamera, step: int = 4) -> np.ndarray:
    w, h = cam.size
    xs, ys = np.meshgrid(np.arange(0, w, step) + 0.5, np.arange(0, h, step) + 0.5)
    return np.stack([xs, ys], axis=-1)


def test_reads_the_bundled_calibration(cam):
    """The five records land in the right fields (size is width x height; centre is row,
    column). Rejects swapping the centre's or the size's order."""
    assert isinstance(cam, OcamCamera)
    assert cam.size == (1024, 768)
    assert cam.center == pytest.approx((381.777786, 505.480427))
    assert cam.pol[0] == pytest.approx(-551.7655) and cam.invpol.size == 8
    assert 140 < cam.fov_deg < 160  # the calibrated field of view reaches the corners


def test_round_trip_within_a_tenth_of_a_pixel(cam):
    """pixel -> direction -> pixel over every valid pixel of the calibrated field of view:
    <= 0.1 px (it is exact to rounding: Newton on the direct polynomial), and the toolbox's
    own inverse polynomial alone is within 0.1 px too. Rejects a projection that uses the
    invpol with swapped argument (angle from the axis instead of elevation) or the wrong
    sign of z (both are off by tens of pixels)."""
    p = pixel_grid(cam)
    d, valid = cam.unproject(p)
    q, valid2 = cam.project(d)
    assert valid.mean() > 0.99 and (valid2 | ~valid).all()
    err = np.linalg.norm(q - p, axis=-1)[valid]
    assert err.max() <= 0.1 and err.max() < 1e-6
    # the invpol start value alone (the toolbox's world2cam)
    from arlight.sphere.fisheye import _ocam_to_opencv

    oc = _ocam_to_opencv(d @ cam.world_from_camera)
    theta = np.arctan2(oc[..., 2], np.hypot(oc[..., 0], oc[..., 1]))
    rho_inv = np.polynomial.polynomial.polyval(theta, cam.invpol)
    rho = np.linalg.norm(cam._sensor(p), axis=-1)
    assert np.abs(rho_inv - rho)[valid].max() <= 0.1


def test_axes_and_radial_angle(cam):
    """Default (zenith) pose: the centre looks up (+Y), image right is +X, image down is
    -Z, and a pixel r px right of the centre is atan2(r, -pol(r)) off axis. Rejects the
    row/column swap of the toolbox's frame and an inverted optical axis."""
    c = np.array([cam.center[1] + 0.5, cam.center[0] + 0.5])
    d, _ = cam.unproject(np.stack([c, c + [200, 0], c + [0, 200]]))
    np.testing.assert_allclose(d[0], [0, 1, 0], atol=1e-12)
    assert d[1, 0] > 0.3 and abs(d[1, 2]) < 1e-12
    assert d[2, 2] < -0.3 and abs(d[2, 0]) < 1e-12
    expect = np.arctan2(200.0, -np.polynomial.polynomial.polyval(200.0, cam.pol))
    assert np.arccos(d[1, 1]) == pytest.approx(expect, abs=1e-12)


def test_fov_from_file_unless_given(cam):
    """The calibration's field of view is used unless a value is given explicitly; rays
    beyond it are invalid. Rejects a loader that always applies a default 180 deg."""
    narrow = load_camera(CALIB, fov_deg=60.0)
    assert narrow.fov_deg == 60.0 and cam.fov_deg != 60.0
    dirs = np.array([[np.sin(np.radians(40)), np.cos(np.radians(40)), 0.0]])
    assert cam.project(dirs)[1][0] and not narrow.project(dirs)[1][0]


def test_affine_and_equirect_round_trip(make_smooth):
    """A skewed model (c, d, e != 1, 0, 0) still round-trips, and an equirect rendered
    into the OCam image and back matches inside the field of view. Rejects applying the
    affine matrix instead of its inverse when unprojecting."""
    cam = OcamCamera(pol=[-300.0, 0.0, 6e-4, -2e-7], invpol=[400.0, 200.0],
                     center=(239.5, 319.5), affine=(1.01, 0.02, -0.01), size=(640, 480))
    p = pixel_grid(cam, 7)
    d, v = cam.unproject(p)
    q, _ = cam.project(d)
    assert np.abs(q - p)[v].max() < 1e-6
    env = make_smooth(64)
    img, valid = from_equirect(env, "fisheye", cam.size, camera=cam)
    back = to_equirect(img, "fisheye", height=64, camera=cam)
    from arlight.sphere.envmap import equirect_directions

    dirs = equirect_directions(64)
    xy, ok = cam.project(dirs)
    w, h = cam.size
    m = 24  # px: an equirect pixel at this height spans ~15 fisheye pixels
    inner = ok & (xy[..., 0] > m) & (xy[..., 0] < w - m) & (xy[..., 1] > m) & (xy[..., 1] < h - m)
    inner &= dirs[..., 1] > np.cos(np.radians(cam.fov_deg / 2 - 6))  # off the fov's edge
    assert inner.mean() > 0.2
    assert np.abs(back - env)[inner].max() < 0.05 * env.max()


@pytest.mark.parametrize("text,needle", [
    ("%YAML:1.0\ncamera_matrix: !!opencv-matrix\n", "expected 5 records"),
    ("#p\n3 -1 0 1\n#i\n2 1 2\n#c\n1 2\n#a\n1 0 0\n#s\n10\n", "image size"),
    ("#p\n4 -1 0 1\n#i\n2 1 2\n#c\n1 2\n#a\n1 0 0\n#s\n10 10\n", "direct polynomial"),
    ("#p\n3 1 0 1\n#i\n2 1 2\n#c\n1 2\n#a\n1 0 0\n#s\n10 10\n", "a0 must be < 0"),
    ("#p\n3 -1 x 1\n#i\n2 1 2\n#c\n1 2\n#a\n1 0 0\n#s\n10 10\n", "not a number"),
])
def test_foreign_or_broken_files_name_the_file(tmp_path, text, needle):
    """Unreadable, foreign or inconsistent calibration files raise ArlightError naming the
    file (and the record). Rejects silently reading a partial model."""
    f = tmp_path / "calib_results.txt"
    f.write_text(text)
    with pytest.raises(ArlightError) as exc:
        load_camera(f)
    assert str(f) in str(exc.value) and needle in str(exc.value)


def test_binary_file_and_folder(tmp_path):
    """A binary .txt and a folder give clear errors (not a traceback, not 'not found')."""
    f = tmp_path / "calib.txt"
    f.write_bytes(b"\xff\xfe\x00\x81" * 20)
    with pytest.raises(ArlightError, match="binary"):
        load_camera(f)
    with pytest.raises(ArlightError, match="is a folder"):
        load_camera(tmp_path)


def test_opencv_models_still_load(tmp_path):
    """load_camera dispatches JSON calibrations to FisheyeCamera, keeping their fov_deg
    unless one is given. Rejects the CLI default overriding the file."""
    import json

    f = tmp_path / "cal.json"
    f.write_text(json.dumps({"K": [[50, 0, 50], [0, 50, 50], [0, 0, 1]], "size": [100, 100],
                             "fov_deg": 170}))
    assert isinstance(load_camera(f), FisheyeCamera)
    assert load_camera(f).fov_deg == 170 and load_camera(f, 150).fov_deg == 150


def test_real_photo_end_to_end(tmp_path):
    """The real OCamCalib photo with its calibration: `arlight light estimate` succeeds,
    warns about its clipped whites, and reports the observed fraction of the sphere as
    confidence (< 0.5: the image crops the circle). Rejects a size/centre mix-up (the
    image would not match the calibration)."""
    from arlight.light.cli import app
    from arlight.light.estimate import LightEstimate
    from tests.cli_invoke import MainRunner

    out = tmp_path / "fish.json"
    r = MainRunner().invoke(app, ["estimate", str(PHOTO), "--kind", "fisheye",
                                 "--fisheye-calib", str(CALIB), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "clipped" in r.output
    est = LightEstimate.load(out)
    assert 0.1 < est.confidence < 0.5
    assert est.main_direction[1] > 0.5  # the lights of the room are above the camera
