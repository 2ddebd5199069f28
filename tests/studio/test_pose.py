"""Studio poses: T(anchor + offset) R_y S T(-anchor), exactly."""

from __future__ import annotations

import numpy as np
import pytest

from arlight.studio.pose import ObjectPose


def test_rest_pose_is_the_identity():
    assert np.array_equal(ObjectPose((0.3, 0.0, -0.2)).matrix(), np.eye(4))


def test_anchor_is_the_fixed_point_of_rotation_and_scale():
    p = ObjectPose((0.3, 0.1, -0.2), yaw_deg=37.0, scale=2.5)
    m = p.matrix()
    a = np.array([0.3, 0.1, -0.2, 1.0])
    np.testing.assert_allclose(m @ a, a, atol=1e-15)
    # a point 1 m along +x of the anchor turns counter-clockwise seen from above (+Y)
    q = m @ (a + [1.0, 0, 0, 0])
    np.testing.assert_allclose(q[:3] - a[:3], 2.5 * np.array(
        [np.cos(np.radians(37)), 0.0, -np.sin(np.radians(37))]), atol=1e-12)
    assert np.isclose(np.linalg.det(m[:3, :3]), 2.5 ** 3)


def test_moved_to_puts_the_anchor_there_and_keeps_yaw_and_scale():
    p = ObjectPose((0.3, 0.0, -0.2), yaw_deg=90.0, scale=0.5).moved_to(np.array([1, 0.2, 3]))
    np.testing.assert_allclose(p.matrix() @ [0.3, 0.0, -0.2, 1.0], [1, 0.2, 3, 1], atol=1e-12)
    assert (p.yaw_deg, p.scale) == (90.0, 0.5)
    np.testing.assert_allclose(p.position, [1, 0.2, 3])


@pytest.mark.parametrize("kwargs", [{"scale": 0.0}, {"scale": 1e9}, {"scale": float("nan")},
                                    {"yaw_deg": float("inf")}, {"offset": (1e9, 0, 0)},
                                    {"offset": (float("nan"), 0, 0)}])
def test_bad_poses_are_refused(kwargs):
    with pytest.raises(ValueError):
        ObjectPose((0.0, 0.0, 0.0), **kwargs)
