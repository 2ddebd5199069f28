"""Camera poses tracked on a printed marker in every frame (``--poses marker``).

Rejects: poses that are not the per-frame registration (e.g. the first frame's pose for
every frame, or the board frame not mapped to the world's +Y-up frame); intrinsics without
OpenCV's half-pixel shift; frames left distorted; a frame without the marker passing
silently.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.insert.registration import load_calibration, parse_marker, register, undistort
from arlight.io.images import read_ldr, write_png
from arlight.methods import RenderSettings
from arlight.scene.load import parse_scene
from arlight.sequence.build import build_job
from arlight.sequence.frames import FrameSource
from tests.insert.test_real_photo import PHOTOS

MARKER = "charuco:5x7:0.04:0.02:DICT_6X6_250"


def _scene():
    return parse_scene(json.loads(json.dumps({
        "camera": {"resolution": [640, 480], "fov_y_deg": 45,
                   "look_at": {"origin": [0, 1, 1], "target": [0, 0, 0]}},
        "shapes": [{"role": "real", "type": "rectangle", "size": [1, 1], "normal": [0, 1, 0]}],
        "lights": [{"type": "constant", "radiance": 1.0}]})))


def test_marker_poses_are_the_registration_of_each_frame(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    photo = read_ldr(PHOTOS / "choriginal.jpg")
    shutil.copy(PHOTOS / "choriginal.jpg", frames / "a0.jpg")
    write_png(frames / "a1.png", np.roll(photo, 24, axis=1))  # shifted: another pose
    calib_path = PHOTOS / "tutorial_camera_charuco.yml"
    src = FrameSource(frames)
    job = build_job(_scene(), src, "reference", RenderSettings(spp=1), poses="marker",
                    calib=calib_path, marker=MARKER)
    calib = load_calibration(calib_path)
    spec = parse_marker(MARKER)
    frames_read = list(src)
    for fr, pose in zip(frames_read, job.poses, strict=True):
        assert np.array_equal(pose, register(fr.codes, calib, spec).world_from_camera)
    assert not np.allclose(job.poses[0], job.poses[1], atol=1e-3)
    assert job.poses[0][1, 3] > 0.1  # the camera is above the board (+Y up)
    assert (job.camera.cx, job.camera.cy) == (calib.K[0, 2] + 0.5, calib.K[1, 2] + 0.5)
    view = job.view(frames_read[0])
    assert np.array_equal(view.frame_codes, undistort(frames_read[0].codes, calib))
    assert "camera" in job.parts and job.calibration is not None


def test_a_frame_without_the_marker_is_an_error_naming_it(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(PHOTOS / "choriginal.jpg", frames / "0.jpg")
    write_png(frames / "1.png", np.full((480, 640, 3), 128, np.uint8))
    with pytest.raises(InputError, match=r"frame 1 \(1.png\).*no DICT_6X6_250 marker"):
        build_job(_scene(), FrameSource(frames), "reference", RenderSettings(spp=1),
                  poses="marker", calib=PHOTOS / "tutorial_camera_charuco.yml", marker=MARKER)
