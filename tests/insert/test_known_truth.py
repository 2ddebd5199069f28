"""``arlight insert`` against a synthetic table top with known truth (tests/insert/world.py):
a ChArUco board printed on a wood table, photographed by a known camera (with known lens
distortion for the pose test), lit by a known sun and sky; the ground truth is the same
world with the object in it, rendered by Mitsuba's own path tracer (:mod:`arlight.synthetic`).
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from arlight.camera_response import Transfer
from arlight.insert import InsertRequest, build_scene, run_insert
from arlight.io.images import write_exr, write_png
from arlight.methods import RenderSettings
from arlight.scene.load import load_scene, parse_scene
from arlight.stats import agreement_fraction
from arlight.synthetic import synthesize
from tests.insert import world as W

ORIGIN, TARGET = (0.3, 0.42, 0.62), (0.08, 0.0, 0.17)
RADIUS = 0.04
AT = (-0.045, 0.0, 0.12)  # the ball stands beside the board; its shadow falls onto it


def _texture_vs_truth(texture: np.ndarray, table_png) -> float:
    """Correlation, over the printed board, of the estimated albedo texture (the default
    1 m × 1 m plane centred on the board) with the table texture the world was made of."""
    from arlight.io.images import read_linear

    truth = read_linear(table_png)[..., 1]
    nz, nx = texture.shape[:2]
    cx, cz = W.SQUARES[0] * W.SQUARE / 2, W.SQUARES[1] * W.SQUARE / 2
    x = cx - 0.5 + (np.arange(nx) + 0.5) / nx
    z = cz - 0.5 + (np.arange(nz) + 0.5) / nz
    inside_x = (x > 0.005) & (x < 2 * cx - 0.005)
    inside_z = (z > 0.005) & (z < 2 * cz - 0.005)
    cols = ((x[inside_x] - W.TABLE_LO[0]) * W.PX_PER_M).astype(int)
    rows = ((z[inside_z] - W.TABLE_LO[1]) * W.PX_PER_M).astype(int)
    est = texture[np.ix_(inside_z, inside_x)][..., 1]
    return float(np.corrcoef(est.ravel(), truth[np.ix_(rows, cols)].ravel())[0, 1])


def _pose_errors(estimated: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, camera position error in metres)."""
    r = estimated[:3, :3].T @ true[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
    return float(angle), float(np.linalg.norm(estimated[:3, 3] - true[:3, 3]))


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    folder = tmp_path_factory.mktemp("insert_world")
    return folder, W.sphere_mesh(folder / "ball.obj", RADIUS)


def test_pose_and_albedo_from_a_distorted_ldr_photo(ball):
    """Pose within 1 px mean reprojection error, 1° and 5 mm, and the table's albedo within
    5 %, from an 8-bit sRGB photo taken through a lens with known barrel distortion and a
    calibration in OpenCV's YAML. Rejects: a board frame that is not the world frame (a
    missing or transposed WORLD_FROM_BOARD rotates the pose by 90°), an albedo without π
    or with the wrong irradiance (off by 3× or by the sun's cosine)."""
    folder, obj = ball
    w, h, fx = 480, 360, 495.0
    scene = parse_scene(W.world(folder, (w, h), fx, ORIGIN, TARGET), folder)
    photo = synthesize(scene, spp=16, batches=4, cache_dir=folder / "cache")
    K = W.opencv_K(fx, w, h)
    dist = np.array([-0.12, 0.05, 0.0, 0.0, 0.0])
    codes = Transfer().to_display(photo.frame)
    write_png(folder / "distorted.png", W.distort(codes, K, dist))
    fs = cv2.FileStorage(str(folder / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", w)
    fs.write("image_height", h)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", dist.reshape(1, 5))
    fs.release()
    req = InsertRequest(photo=folder / "distorted.png", calib=folder / "cam.yml",
                        marker=W.MARKER_SPEC, light=W.LIGHT, object=obj, at=AT,
                        albedo_mode="median")
    result = build_scene(req, folder)
    reg = result.registration
    angle, shift = _pose_errors(reg.world_from_camera, scene.camera.world_from_camera)
    assert reg.reprojection_px < 1.0, reg.reprojection_px
    assert angle < 1.0 and shift < 0.005, (angle, shift)
    err = np.abs(result.albedo.median / W.WOOD_ALBEDO - 1)
    assert np.all(err < 0.05), (result.albedo.median, W.WOOD_ALBEDO)


def test_composite_agrees_with_the_ground_truth(ball, tmp_path):
    """The composite of ``run_insert`` (reference method, per-texel albedo) is within 3
    standard errors of the ground truth of the same world with the ball in it on >= 99 % of
    the pixels (the frame's own noise counted where it shows), the pose is within 1°/5 mm,
    the scene camera projects the board's corners onto the detected ones, and the written
    scene file loads back to the rendered scene. Rejects: a shadow of the wrong direction or
    strength (sun direction negated, albedo without π), an object placed by its origin
    instead of its bottom (sunk 4 cm into the table), the plane's albedo texture mirrored or
    transposed (its squares do not correlate with the printed board's), OpenCV's integer
    pixel centres taken for ours (every corner 0.5 px off)."""
    folder, obj = ball
    w, h, fx = 240, 180, 260.0
    spp = 64
    world = parse_scene(W.world(folder, (w, h), fx, ORIGIN, TARGET, obj, AT, RADIUS), folder)
    photo = synthesize(world, spp=spp, batches=spp, cache_dir=folder / "cache")
    write_exr(tmp_path / "photo.exr", photo.frame)
    (tmp_path / "cam.json").write_text(json.dumps({"K": W.opencv_K(fx, w, h).tolist(),
                                                   "size": [w, h]}))
    req = InsertRequest(photo=tmp_path / "photo.exr", calib=tmp_path / "cam.json",
                        marker=W.MARKER_SPEC, light=W.LIGHT, object=obj, at=AT,
                        color=(0.8, 0.8, 0.8), transfer="linear")
    out = tmp_path / "out"
    result, layers = run_insert(req, out, "reference", RenderSettings(spp=spp, seed=5))
    angle, shift = _pose_errors(result.registration.world_from_camera,
                                world.camera.world_from_camera)
    assert angle < 1.0 and shift < 0.005, (angle, shift)
    reg = result.registration  # the scene camera sees the corners where they were detected
    uv, _ = result.scene.camera.project(reg.world_points)
    off = np.linalg.norm(uv - (reg.image_points + 0.5), axis=1).mean()
    assert off <= reg.reprojection_px + 0.05, (off, reg.reprojection_px)
    se = np.sqrt(np.square(layers.stderr["composite"])
                 + np.square((1 - layers.mask)[..., None] * photo.frame_stderr))
    frac = agreement_fraction(layers.composite, se, photo.ground_truth,
                              photo.ground_truth_stderr)
    assert frac >= 0.99, frac
    assert agreement_fraction(photo.frame, photo.frame_stderr, photo.ground_truth,
                              photo.ground_truth_stderr) < 0.99  # the ball shows
    board = _texture_vs_truth(result.albedo.texture, folder / "table.png")
    assert board > 0.8, f"albedo texture vs the printed board: correlation {board:.2f}"
    saved = load_scene(out / "scene.toml")
    np.testing.assert_allclose(saved.camera.world_from_camera,
                               result.scene.camera.world_from_camera)
    assert (out / "render" / "composite.png").is_file()
    assert json.loads((out / "registration.json").read_text())["corners"] >= 6
