"""Unit quaternions ``(x, y, z, w)`` (Hamilton, scalar last) ↔ rotation matrices, and slerp.

The one place arlight converts quaternions, on :class:`scipy.spatial.transform.Rotation` and
:class:`~scipy.spatial.transform.Slerp` (scipy's own convention is scalar last too). Every pose
file arlight reads (``tx ty tz qx qy qz qw`` lines: TUM, our sequence poses, the RGB-D poses of
``light probeless``) stores the quaternion in this order; a reader of another layout reorders
before calling. A bottom-tier module (numpy and scipy only), so any package may import it.
scipy is imported on first use: the command line imports the readers without converting.
"""

from __future__ import annotations

import numpy as np


def _rotation():
    from scipy.spatial.transform import Rotation

    return Rotation


def quat_to_matrix(q) -> np.ndarray:
    """3×3 rotation of the quaternion ``q = (x, y, z, w)`` (normalised here; a zero
    quaternion is a ``ValueError``)."""
    return _rotation().from_quat(np.asarray(q, np.float64)).as_matrix()


def matrix_to_quat(r) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` with ``w >= 0`` of a 3×3 rotation matrix."""
    return _rotation().from_matrix(np.asarray(r, np.float64)).as_quat(canonical=True)


def pose_matrix(translation, q) -> np.ndarray:
    """4×4 rigid transform ``[R(q) | t]`` of a translation and a quaternion ``(x, y, z, w)``."""
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(q)
    m[:3, 3] = np.asarray(translation, np.float64)
    return m


def slerp(q0, q1, t: float) -> np.ndarray:
    """Spherical linear interpolation from ``q0`` (``t = 0``) to ``q1`` (``t = 1``): constant
    angular velocity along the shorter arc (``q`` and ``-q`` are the same rotation); returns
    the unit quaternion with ``w >= 0``."""
    from scipy.spatial.transform import Slerp

    keys = _rotation().from_quat(np.stack([np.asarray(q0, np.float64),
                                           np.asarray(q1, np.float64)]))
    return Slerp([0.0, 1.0], keys)(float(t)).as_quat(canonical=True)


__all__ = ["matrix_to_quat", "pose_matrix", "quat_to_matrix", "slerp"]
