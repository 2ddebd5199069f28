"""Pinhole / thin-lens camera with OpenCV intrinsics (conventions in docs/conventions.md).

Camera space is OpenCV's: x right, y down, z forward. A pixel coordinate ``(u, v)`` has the
top-left corner of the image at ``(0, 0)``. The ray through ``(u, v)`` of a pinhole camera has
camera-space direction ``((u − cx)/fx, (v − cy)/fy, 1)``.

Thin lens (Kán Eq. 3.1–3.3): the point ``I = d · f_d`` on the focal plane ``z = f_d`` is
kept, the origin moves to a point ``O'`` on the aperture, and the ray is ``I − O'``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from arlight.camera_response import Transfer

ApertureShape = Literal["disk", "square"]


def look_at(origin, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-from-camera 4×4 matrix (OpenCV axes) for a camera at ``origin`` facing ``target``.

    Raises ValueError when ``target == origin`` or ``up`` is parallel to the view direction.
    """
    o = np.asarray(origin, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - o
    n = np.linalg.norm(z)
    if n == 0:
        raise ValueError("look_at: target equals origin")
    z /= n
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)  # right = forward × up for a y-down camera
    nx = np.linalg.norm(x)
    if nx < 1e-9:
        raise ValueError("look_at: up is parallel to the view direction")
    x /= nx
    y = np.cross(z, x)  # down
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, o
    return m


@dataclass(frozen=True)
class Camera:
    """A calibrated camera.

    Attributes:
        width, height: resolution in pixels.
        fx, fy, cx, cy: OpenCV intrinsics in pixels.
        world_from_camera: 4×4 rigid pose, camera axes x right, y down, z forward.
        aperture_radius: lens radius in metres (0 = pinhole). For ``aperture_shape="square"``
            it is the half side of the square aperture (Kán's ``r_x, r_y ∈ (−1, 1)`` scaled).
        focus_distance: distance of the plane in focus along the view axis, metres.
        transfer: the frame's transfer function and exposure.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_from_camera: np.ndarray = field(default_factory=lambda: np.eye(4))
    aperture_radius: float = 0.0
    focus_distance: float = 1.0
    aperture_shape: ApertureShape = "disk"
    transfer: Transfer = field(default_factory=Transfer)

    @staticmethod
    def from_fov(width: int, height: int, fov_y_deg: float, **kwargs) -> Camera:
        """Camera with square pixels, centred principal point and vertical field of view."""
        f = 0.5 * height / np.tan(np.radians(fov_y_deg) / 2.0)
        return Camera(width, height, f, f, width / 2.0, height / 2.0, **kwargs)

    def resized(self, width: int, height: int) -> Camera:
        """The same camera with another image size: intrinsics scale with the image, so
        every pixel keeps looking in the same direction (field of view unchanged)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the usual name of the intrinsic matrix
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def position(self) -> np.ndarray:
        return self.world_from_camera[:3, 3].copy()

    def camera_from_world(self) -> np.ndarray:
        return np.linalg.inv(self.world_from_camera)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``(N, 3)`` to pixel coordinates ``(N, 2)`` and depths ``(N,)``.

        Depth is the camera-space z (metres); points behind the camera get depth <= 0.
        """
        p = np.asarray(points, dtype=np.float64)
        m = self.camera_from_world()
        pc = p @ m[:3, :3].T + m[:3, 3]
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy],
                          axis=1)
        return uv, z

    def pixel_rays(self, uv: np.ndarray,
                   lens: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World-space rays through pixel positions ``uv (N, 2)``.

        Args:
            uv: pixel coordinates (top-left corner of the image is (0, 0)).
            lens: optional ``(N, 2)`` points on the unit aperture (disk or square, in
                [−1, 1]²), scaled by ``aperture_radius``.

        Returns:
            origins ``(N, 3)`` and unit directions ``(N, 3)``.
        """
        uv = np.asarray(uv, dtype=np.float64)
        d = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy,
                      np.ones(len(uv))], axis=1)
        o = np.zeros_like(d)
        if lens is not None and self.aperture_radius > 0:
            o[:, :2] = np.asarray(lens, dtype=np.float64) * self.aperture_radius
            d = d * self.focus_distance - o  # Kán Eq. 3.1-3.3: I - O'
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = self.world_from_camera[:3, :3]
        return o @ r.T + self.world_from_camera[:3, 3], d @ r.T

    def circle_of_confusion(self, depth: np.ndarray) -> np.ndarray:
        """Thin-lens blur-circle diameter in pixels for points at camera depth ``depth`` (m).

        ``c = 2 A f |z − z_f| / (z z_f)`` with ``f`` the focal length in pixels (fy).
        """
        z = np.asarray(depth, dtype=np.float64)
        return 2 * self.aperture_radius * self.fy * np.abs(z - self.focus_distance) / (
            z * self.focus_distance)
