"""Quaternions in one place (:mod:`arlight.rotations`, on scipy's Rotation and Slerp).

Rejects: a scalar-first reading of ``(x, y, z, w)`` quaternions (a 90° turn about +z read as
another rotation); a pose reader with its own conversion (the sequence poses and the RGB-D
poses of ``light probeless`` must agree on every file line); slerp along the long arc or at a
non-constant angular velocity; a quaternion with ``w < 0`` from a matrix.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from arlight import rotations
from arlight.probeless import rgbd_io
from arlight.sequence import poses


def test_one_implementation_is_shared():
    assert poses.quat_to_matrix is rotations.quat_to_matrix
    assert poses.matrix_to_quat is rotations.matrix_to_quat
    assert poses.slerp is rotations.slerp


def test_pose_lines_read_alike_by_both_readers(tmp_path):
    """``tx ty tz qx qy qz qw`` (TUM order, scalar last) in both readers."""
    rng = np.random.default_rng(5)
    lines = []
    for i in range(6):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        lines.append(f"{i} " + " ".join(f"{x:.17g}" for x in [*rng.normal(size=3), *q]))
    f = tmp_path / "poses.txt"
    f.write_text("\n".join(lines) + "\n")
    a = rgbd_io.read_poses(f)
    b = poses.camera_poses(f, 6)
    assert len(a) == len(b) == 6
    for x, y in zip(a, b, strict=True):
        assert np.allclose(x, y, atol=1e-12)
    # 90° about +z turns +x into +y
    f.write_text("0 1 2 3 0 0 0.70710678118654752 0.70710678118654752\n")
    m = rgbd_io.read_poses(f)[0]
    assert np.allclose(m[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    assert np.allclose(m[:3, 3], [1, 2, 3])


def test_rgbd_reader_refuses_a_zero_or_nan_quaternion_by_index(tmp_path):
    from arlight.errors import InputError

    f = tmp_path / "poses.txt"
    for q in ("0 0 0 0", "nan 0 0 1"):
        f.write_text(f"0 0 0 0 0 0 0 1\n0 0 0 {q}\n")
        with pytest.raises(InputError, match=r"pose 1 is not a finite") as exc:
            rgbd_io.read_poses(f)
        assert exc.value.field == "poses[1]"


def test_slerp_and_canonical_sign():
    r = rotations.quat_to_matrix([0, 0, -math.sqrt(0.5), -math.sqrt(0.5)])  # w < 0
    q = rotations.matrix_to_quat(r)
    assert q[3] > 0 and np.allclose(q, [0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    q0, q1 = np.array([0, 0, 0, 1.0]), rotations.matrix_to_quat(
        rotations.quat_to_matrix([0, math.sin(1.2), 0, math.cos(1.2)]))  # 137.5° about y
    for t in (0.0, 0.3, 1.0):
        ang = 2 * math.acos(min(1.0, abs(rotations.slerp(q0, -q1, t)[3])))
        assert ang == pytest.approx(t * 2.4, abs=1e-9)  # short arc, constant velocity
