"""Fisheye camera models: equidistant and OpenCV fisheye (Kannala-Brandt).

A fisheye pixel is mapped through the angle ``theta`` between its ray and the optical axis:

* equidistant: ``r = f theta`` (normalised: ``rho = theta``);
* OpenCV fisheye / Kannala-Brandt (``cv2.fisheye``):
  ``rho = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,

then ``(u, v) = K [rho cos psi, rho sin psi, 1]^T`` with ``psi`` the azimuth around the
axis. Camera space is OpenCV's (x right, y down, z forward). We implement the model
ourselves rather than calling ``cv2.fisheye.projectPoints``/``undistortPoints`` because
those go through ``x/z`` and so cannot represent rays at or beyond 90 deg off-axis, which
a 180-185 deg lens covering the upper hemisphere (Kan 2014 Sec. 3.2.1) needs; the tests
check that both agree inside 90 deg.

Default pose (:func:`zenith_camera`): the optical axis looks straight up (+Y world),
image right is world +X and image up (-y) is world +Z, like a camera lying on its back on
the table, marker-aligned.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


def zenith_camera() -> np.ndarray:
    """``world_from_camera`` rotation of an upward-looking camera: x->+X, y->-Z, z->+Y."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass
class FisheyeCamera:
    """A fisheye camera: intrinsics ``K`` (pixels), Kannala-Brandt ``D = (k1..k4)`` (zeros =
    equidistant), image ``size = (width, height)``, maximal field of view ``fov_deg`` (full
    angle; rays beyond are invalid) and ``world_from_camera`` (3x3 rotation)."""

    K: np.ndarray
    size: tuple[int, int]
    D: np.ndarray = field(default_factory=lambda: np.zeros(4))
    fov_deg: float = 180.0
    world_from_camera: np.ndarray = field(default_factory=zenith_camera)

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.D = np.asarray(self.D, dtype=np.float64).reshape(-1)
        if self.D.size != 4:
            raise ValueError(f"fisheye distortion must have 4 coefficients, got {self.D.size}")
        self.world_from_camera = np.asarray(self.world_from_camera, np.float64).reshape(3, 3)
        self.size = (int(self.size[0]), int(self.size[1]))
        for name, m in (("K", self.K), ("D", self.D), ("world_from_camera",
                                                       self.world_from_camera)):
            if not np.all(np.isfinite(m)):
                raise ValueError(f"fisheye {name} holds NaN/Inf values")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise ValueError(f"fisheye focal lengths must be > 0, got fx={self.K[0, 0]}, "
                             f"fy={self.K[1, 1]}")
        if min(self.size) < 1:
            raise ValueError(f"fisheye image size must be positive, got {self.size}")
        if not 0 < self.fov_deg <= 360:
            raise ValueError(f"fov_deg must be in (0, 360], got {self.fov_deg}")

    # ------------------------------------------------------------------ construction

    @classmethod
    def equidistant(cls, size: tuple[int, int], fov_deg: float = 180.0,
                    image_circle_diameter: float | None = None,
                    world_from_camera: np.ndarray | None = None) -> FisheyeCamera:
        """Equidistant lens whose ``fov_deg`` circle has the given diameter in pixels
        (default: the shorter image side), centred in the image."""
        w, h = size
        dia = float(image_circle_diameter or min(w, h))
        f = (dia / 2) / np.radians(fov_deg / 2)
        K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
        return cls(K=K, size=size, fov_deg=fov_deg,
                   world_from_camera=zenith_camera() if world_from_camera is None
                   else world_from_camera)

    @classmethod
    def load(cls, path: str | Path, fov_deg: float | None = None) -> FisheyeCamera:
        """Read a calibration: OpenCV FileStorage YAML/XML with ``camera_matrix`` (or ``K``),
        ``distortion_coefficients`` (or ``D``), ``image_width``/``image_height`` (OpenCV's
        principal point is shifted by +0.5 px into our pixel convention); or JSON with
        ``K`` (our convention), ``D``, ``size`` [w, h], optional ``fov_deg`` and
        ``world_from_camera``."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: calibration file not found")
        if path.suffix.lower() == ".json":
            try:
                d = json.loads(path.read_text())
                return cls(K=d["K"], D=d.get("D", [0, 0, 0, 0]), size=tuple(d["size"]),
                           fov_deg=float(fov_deg or d.get("fov_deg", 180.0)),
                           world_from_camera=d.get("world_from_camera", zenith_camera()))
            except (KeyError, TypeError, ValueError, AttributeError, UnicodeDecodeError,
                    OverflowError) as exc:
                raise ValueError(f"{path}: bad fisheye calibration ({exc})") from exc
        import cv2

        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:  # a parse error of the YAML/XML
            msg = " ".join(str(exc).split())
            raise ValueError(f"{path}: cannot parse calibration file ({msg[-160:]})") from exc
        if not fs.isOpened():
            raise ValueError(f"{path}: cannot open calibration file")
        try:
            K = next((fs.getNode(k).mat() for k in ("camera_matrix", "K")
                      if not fs.getNode(k).empty()), None)
            D = next((fs.getNode(k).mat() for k in ("distortion_coefficients", "D")
                      if not fs.getNode(k).empty()), None)
            w = fs.getNode("image_width").real()
            h = fs.getNode("image_height").real()
        except cv2.error as exc:
            msg = " ".join(str(exc).split())
            raise ValueError(f"{path}: bad calibration field ({msg[-160:]})") from exc
        finally:
            fs.release()
        if K is None or not w or not h or np.shape(K) != (3, 3):
            raise ValueError(f"{path}: needs camera_matrix, image_width and image_height")
        D = np.zeros(4) if D is None else np.asarray(D, np.float64).ravel()[:4]
        K = np.array(K, np.float64)
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and np.isfinite(w)
                and np.isfinite(h) and w > 0 and h > 0):
            raise ValueError(f"{path}: camera_matrix, distortion_coefficients and the image "
                             "size must be finite (and the size positive)")
        K[0, 2] += 0.5  # OpenCV puts pixel centres at integers; we put them at +0.5
        K[1, 2] += 0.5
        return cls(K=K, D=np.pad(D, (0, 4 - D.size)), size=(int(w), int(h)),
                   fov_deg=float(fov_deg or 180.0))

    # ------------------------------------------------------------------ the model

    def _distort(self, theta: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        k1, k2, k3, k4 = self.D
        return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _distort_derivative(self, theta: np.ndarray) -> np.ndarray:
        t2 = theta * theta
        k1, k2, k3, k4 = self.D
        return 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))

    def _undistort(self, rho: np.ndarray) -> np.ndarray:
        """Solve ``rho = theta_d(theta)`` for theta in [0, pi] by (clamped) Newton steps;
        radii beyond the field of view or unreachable by the model get ``theta = inf``."""
        rho = np.asarray(rho, dtype=np.float64)
        if not np.any(self.D):
            return rho.copy()
        theta = np.full(rho.shape, np.inf)
        limit = self._distort(np.radians(min(self.fov_deg / 2 + 1.0, 180.0)))
        todo = rho <= limit
        r = rho[todo]
        t = r.copy()
        for _ in range(50):
            step = (self._distort(t) - r) / self._distort_derivative(t)
            t = np.clip(t - step, 0.0, np.pi)
            if np.max(np.abs(step), initial=0.0) < 1e-14:
                break
        t[np.abs(self._distort(t) - r) > 1e-9 * np.maximum(1.0, r)] = np.inf
        theta[todo] = t
        return theta

    def project(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World unit directions ``(..., 3)`` -> pixel coordinates ``(..., 2)`` (x, y with
        the top-left pixel's centre at (0.5, 0.5)) and a validity mask (inside the fov)."""
        d = np.asarray(directions, np.float64) @ self.world_from_camera  # camera coords
        rxy = np.hypot(d[..., 0], d[..., 1])
        theta = np.arctan2(rxy, d[..., 2])
        rho = self._distort(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(rxy > 0, rho / rxy, 0.0)
        xn, yn = d[..., 0] * s, d[..., 1] * s
        K = self.K
        px = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
        py = K[1, 1] * yn + K[1, 2]
        valid = theta <= np.radians(self.fov_deg / 2) + 1e-12
        return np.stack([px, py], axis=-1), valid

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``(..., 2)`` -> world unit directions ``(..., 3)`` and a
        validity mask (inside the fov)."""
        p = np.asarray(pixels, np.float64)
        K = self.K
        yn = (p[..., 1] - K[1, 2]) / K[1, 1]
        xn = (p[..., 0] - K[0, 2] - K[0, 1] * yn) / K[0, 0]
        rho = np.hypot(xn, yn)
        theta = self._undistort(rho)
        valid = theta <= np.radians(self.fov_deg / 2) + 1e-12
        theta = np.where(np.isfinite(theta), theta, np.pi)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.where(rho > 0, np.sin(theta) / rho, 1.0)
        d_cam = np.stack([xn * s, yn * s, np.cos(theta)], axis=-1)
        return d_cam @ self.world_from_camera.T, valid

    def pixel_centres(self) -> np.ndarray:
        w, h = self.size
        xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        return np.stack([xs, ys], axis=-1)

    def pixel_solid_angle(self) -> np.ndarray:
        """Solid angle (sr) of every pixel ``(H, W)``, zero outside the fov:
        ``dw/dA = sin(theta) / (rho theta_d'(theta)) / (fx fy)``."""
        p = self.pixel_centres()
        K = self.K
        yn = (p[..., 1] - K[1, 2]) / K[1, 1]
        xn = (p[..., 0] - K[0, 2] - K[0, 1] * yn) / K[0, 0]
        rho = np.hypot(xn, yn)
        theta = self._undistort(rho)
        inside = theta <= np.radians(self.fov_deg / 2)
        theta = np.where(np.isfinite(theta), theta, np.pi)
        with np.errstate(invalid="ignore", divide="ignore"):
            j = np.where(rho > 1e-12, np.sin(theta) / (rho * self._distort_derivative(theta)),
                         1.0)
        sa = j / (K[0, 0] * K[1, 1])
        sa[~inside] = 0.0
        return sa

    def pixel_angle(self) -> float:
        """Angle (rad) subtended by one pixel at the image centre."""
        return float(1.0 / self.K[0, 0])
