"""Poses files, keyframes and slerp (arlight.sequence.poses).

Rejects: a quaternion convention other than Hamilton (x, y, z, w); interpolating the
rotation matrices or quaternions linearly (nlerp: non-constant angular velocity, and lerp
of matrices is not a rotation); slerp along the long arc; keyframes that do not land
exactly on their frames; silently accepting pose files whose count differs from the frames.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight.errors import InputError
from arlight.scene.camera import look_at
from arlight.sequence.poses import (
    Keyframe,
    camera_poses,
    interpolate,
    matrix_to_quat,
    object_transforms,
    quat_to_matrix,
    read_pose_lines,
    slerp,
    write_poses,
)


def _rot(axis, angle) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _angle(r: np.ndarray) -> float:
    return math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1))


def test_quaternion_is_hamilton_xyzw():
    # 90° about +z: (0, 0, sin 45°, cos 45°) turns +x into +y
    r = quat_to_matrix([0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    rng = np.random.default_rng(3)
    for _ in range(50):
        r = _rot(rng.normal(size=3), rng.uniform(0, math.pi))
        q = matrix_to_quat(r)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        assert np.allclose(quat_to_matrix(q), r, atol=1e-12)
    # near 180° (the trace branch of Shepperd's method is not the accurate one)
    r = _rot([1, 2, 3], math.pi - 1e-9)
    assert np.allclose(quat_to_matrix(matrix_to_quat(r)), r, atol=1e-9)


def test_slerp_has_constant_angular_velocity_on_the_short_arc():
    theta = math.radians(150)
    q0 = matrix_to_quat(np.eye(3))
    q1 = matrix_to_quat(_rot([0, 1, 0], theta))
    for t in np.linspace(0, 1, 11):
        r = quat_to_matrix(slerp(q0, q1, t))
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert _angle(r) == pytest.approx(t * theta, abs=1e-9)  # nlerp is off by ~4°
    assert np.allclose(slerp(q0, q1, 0), q0) and np.allclose(slerp(q0, q1, 1), q1)
    # q and −q are the same rotation: the short way round, not 360° − θ
    mid = quat_to_matrix(slerp(q0, -q1, 0.5))
    assert _angle(mid) == pytest.approx(theta / 2, abs=1e-9)


def test_keyframes_interpolate_translation_rotation_and_scale():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = _rot([0, 1, 0], math.radians(90)) * 4.0  # scale 4
    b[:3, 3] = [1.0, 2.0, -4.0]
    poses = interpolate([Keyframe.from_matrix(4, b), Keyframe.from_matrix(0, a)], 5)
    assert np.array_equal(poses[0], Keyframe.from_matrix(0, a).matrix())
    assert np.allclose(poses[4], b, atol=1e-12)
    mid = poses[2]
    s = np.linalg.norm(mid[:3, :3], axis=0)
    assert np.allclose(s, 2.0)  # log-linear: sqrt(1 · 4)
    assert _angle(mid[:3, :3] / s) == pytest.approx(math.radians(45), abs=1e-12)
    assert np.allclose(mid[:3, 3], [0.5, 1.0, -2.0])


def test_keyframes_must_span_the_sequence():
    k = [Keyframe.from_matrix(0, np.eye(4)), Keyframe.from_matrix(3, np.eye(4))]
    with pytest.raises(InputError, match="0..3.*5 frames"):
        interpolate(k, 5)
    with pytest.raises(InputError, match="given twice"):
        interpolate([*k, Keyframe.from_matrix(3, np.eye(4))], 4)
    with pytest.raises(InputError, match="shear or mirroring"):
        Keyframe.from_matrix(0, np.diag([1.0, 1.0, -1.0, 1.0]))


def test_poses_file_round_trip_and_both_line_forms(tmp_path):
    poses = [look_at([math.sin(a), 0.5, math.cos(a) * 2], [0, 0, 0])
             for a in np.linspace(0, 1, 6)]
    p = write_poses(tmp_path / "poses.txt", poses)
    back = camera_poses(p, 6)
    assert all(np.allclose(x, y, atol=1e-12) for x, y in zip(back, poses, strict=True))
    m = poses[3]
    (tmp_path / "m.txt").write_text(
        "# 3x4 rows\n0, " + ", ".join(repr(float(x)) for x in m[:3].ravel()) + "\n"
        "2 " + " ".join(repr(float(x)) for x in m[:3].ravel()) + "  # keyframe\n")
    got = camera_poses(tmp_path / "m.txt", 3)
    assert np.allclose(got[1], m, atol=1e-12)  # slerp between equal poses
    # OpenGL/ARKit camera axes: y up, z backward
    gl = camera_poses(tmp_path / "m.txt", 3, axes="opengl")
    assert np.allclose(gl[0][:3, 2], -m[:3, 2]) and np.allclose(gl[0][:3, 0], m[:3, 0])


@pytest.mark.parametrize("text, message", [
    ("0 1 2 3\n", "expected 7 numbers"),
    ("0 0 0 0 0 0 0 2\n", "unit quaternion"),
    ("x 0 0 0 0 0 0 1\n", "integer frame index"),
    ("0 0 0 nan 0 0 0 1\n", "non-finite"),
    ("# nothing\n", "no poses"),
])
def test_bad_poses_file_names_file_and_line(tmp_path, text, message):
    p = tmp_path / "p.txt"
    p.write_text("0 0 0 0 0 0 0 1\n" + text if "nothing" not in text else text)
    with pytest.raises(InputError, match=message) as e:
        read_pose_lines(p)
    assert str(p) in str(e.value)
    if "nothing" not in text:
        assert "line 2" in str(e.value)


def test_pose_count_must_match_the_frames(tmp_path):
    p = write_poses(tmp_path / "p.txt", [np.eye(4)] * 4)
    with pytest.raises(InputError, match="4 lines.*6 frames"):
        camera_poses(p, 6)


def test_keyframes_toml_camera_and_objects(tmp_path):
    (tmp_path / "k.toml").write_text("""
[[camera]]
frame = 0
look_at = { origin = [0, 1, 2], target = [0, 0, 0] }
[[camera]]
frame = 4
look_at = { origin = [2, 1, 0], target = [0, 0, 0] }
[[objects.ball]]
frame = 0
transform = { translate = [0, 0, 0] }
[[objects.ball]]
frame = 4
transform = { translate = [0.4, 0, 0], rotate = [0, 1, 0, 80] }
""")
    cams = camera_poses(tmp_path / "k.toml", 5)
    assert np.allclose(cams[0], look_at([0, 1, 2], [0, 0, 0]))
    assert np.allclose(cams[4], look_at([2, 1, 0], [0, 0, 0]))
    # the keyframes differ by 90° about +y: halfway is 45° about +y (the translation is
    # linear, so the camera cuts the corner of the arc)
    assert np.allclose(cams[2][:3, :3], _rot([0, 1, 0], math.radians(45)) @ cams[0][:3, :3],
                       atol=1e-12)
    assert np.allclose(cams[2][:3, 3], [1, 1, 1])
    objs = object_transforms(tmp_path / "k.toml", 5, {"ball": None})
    assert np.allclose(objs[1]["ball"][:3, 3], [0.1, 0, 0])
    assert _angle(objs[1]["ball"][:3, :3]) == pytest.approx(math.radians(20))
    with pytest.raises(InputError, match="no shape named 'ball'"):
        object_transforms(tmp_path / "k.toml", 5, {"bunny": None})
    (tmp_path / "bad.toml").write_text("[[camera]]\nframe = 0\n")
    with pytest.raises(InputError, match=r"camera\[0\].*exactly one"):
        camera_poses(tmp_path / "bad.toml", 1)


def test_object_poses_text_file(tmp_path):
    (tmp_path / "o.txt").write_text("0 ball 0 0 0 0 0 0 1\n2 ball 0.2 0 0 0 0 0 1\n"
                                    "0 box 0 0 0 0 0 0 1\n2 box 0 0 0 0 0 0 1\n")
    objs = object_transforms(tmp_path / "o.txt", 3, {"ball": 0, "box": 0})
    assert set(objs[1]) == {"ball", "box"}
    assert np.allclose(objs[1]["ball"][:3, 3], [0.1, 0, 0])
