"""Fisheye camera models: equidistant, OpenCV fisheye (Kannala-Brandt) and OCamCalib
(Scaramuzza's polynomial model, :class:`OcamCamera`; :func:`load_camera` reads any of
their calibration files).

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

from arlight.errors import InputError


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
            raise InputError(f"fisheye distortion must have 4 coefficients, got {self.D.size}",
                             field="D")
        self.world_from_camera = np.asarray(self.world_from_camera, np.float64).reshape(3, 3)
        self.size = (int(self.size[0]), int(self.size[1]))
        for name, m in (("K", self.K), ("D", self.D), ("world_from_camera",
                                                       self.world_from_camera)):
            if not np.all(np.isfinite(m)):
                raise InputError("holds NaN/Inf values", field=name)
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise InputError(f"fisheye focal lengths must be > 0, got fx={self.K[0, 0]}, "
                             f"fy={self.K[1, 1]}", field="K")
        if min(self.size) < 1:
            raise InputError(f"fisheye image size must be positive, got {self.size}",
                             field="size")
        if not 0 < self.fov_deg <= 360:
            raise InputError(f"must be in (0, 360], got {self.fov_deg}", field="fov_deg")

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
            raise InputError("calibration file not found", file=str(path))
        if path.suffix.lower() == ".json":
            try:
                d = json.loads(path.read_text())
                return cls(K=d["K"], D=d.get("D", [0, 0, 0, 0]), size=tuple(d["size"]),
                           fov_deg=float(fov_deg or d.get("fov_deg", 180.0)),
                           world_from_camera=d.get("world_from_camera", zenith_camera()))
            except InputError as exc:  # the model's check, naming the field
                raise InputError(exc.message, file=str(path), field=exc.field) from exc
            except (KeyError, TypeError, ValueError, AttributeError, UnicodeDecodeError,
                    OverflowError) as exc:
                raise InputError(f"bad fisheye calibration ({exc})", file=str(path)) from exc
        import cv2

        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:  # a parse error of the YAML/XML
            msg = " ".join(str(exc).split())
            raise InputError(f"cannot parse calibration file ({msg[-160:]})",
                             file=str(path)) from exc
        if not fs.isOpened():
            raise InputError("cannot open calibration file", file=str(path))
        try:
            K = next((fs.getNode(k).mat() for k in ("camera_matrix", "K")
                      if not fs.getNode(k).empty()), None)
            D = next((fs.getNode(k).mat() for k in ("distortion_coefficients", "D")
                      if not fs.getNode(k).empty()), None)
            w = fs.getNode("image_width").real()
            h = fs.getNode("image_height").real()
        except cv2.error as exc:
            msg = " ".join(str(exc).split())
            raise InputError(f"bad calibration field ({msg[-160:]})", file=str(path)) from exc
        finally:
            fs.release()
        if K is None or not w or not h or np.shape(K) != (3, 3):
            raise InputError("needs camera_matrix, image_width and image_height",
                             file=str(path))
        D = np.zeros(4) if D is None else np.asarray(D, np.float64).ravel()[:4]
        K = np.array(K, np.float64)
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and np.isfinite(w)
                and np.isfinite(h) and w > 0 and h > 0):
            raise InputError("camera_matrix, distortion_coefficients and the image size "
                             "must be finite (and the size positive)", file=str(path))
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


# ----------------------------------------------------------------------------- OCamCalib


def solid_angle_from_unproject(unproject, size: tuple[int, int]) -> np.ndarray:
    """Solid angle (sr) of every pixel ``(H, W)`` of any camera, from its ``unproject``:
    ``|d(x+1/2) - d(x-1/2)| x |d(y+1/2) - d(y-1/2)|`` (central differences; exact to
    O(pixel^2) for smooth models), zero where a pixel centre is invalid."""
    w, h = size
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    p = np.stack([xs, ys], axis=-1)
    half = np.array([0.5, 0.0]), np.array([0.0, 0.5])
    dx = unproject(p + half[0])[0] - unproject(p - half[0])[0]
    dy = unproject(p + half[1])[0] - unproject(p - half[1])[0]
    sa = np.linalg.norm(np.cross(dx, dy), axis=-1)
    sa[~unproject(p)[1]] = 0.0
    return sa


def _ocam_to_opencv(d: np.ndarray) -> np.ndarray:
    """OCamCalib camera axes (x along image rows = down, y along columns = right, z away
    from the scene: the optical axis looks along -z) -> OpenCV's (x right, y down, z
    forward). A rotation (both frames are right-handed), its own inverse."""
    return np.stack([d[..., 1], d[..., 0], -d[..., 2]], axis=-1)


@dataclass
class OcamCamera:
    """Scaramuzza's omnidirectional camera model (OCamCalib toolbox; Scaramuzza, Martinelli
    & Siegwart, ICVS 2006), as written by the toolbox to ``calib_results.txt``.

    A pixel at ``(row, col)`` (the toolbox's C convention: 0-based, pixel centres at
    integers, so ours are ``(col + 0.5, row + 0.5)``) is taken to the sensor plane by the
    inverse of the affine ``[row - xc, col - yc] = [[c, d], [e, 1]] [u, v]``; its ray is
    ``(u, v, pol(rho))`` with ``rho = |(u, v)|`` and ``pol`` the DIRECT polynomial
    (ascending powers, ``pol[0] < 0``: the optical axis is -z). ``invpol`` gives ``rho``
    from the elevation ``atan(z / |(x, y)|)`` of a ray; :meth:`project` starts from it and
    refines with Newton steps on the direct polynomial, so pixel -> direction -> pixel is
    exact to rounding (the bare ``invpol`` fit is good to ~0.1 px).

    ``fov_deg``: full field of view; rays beyond it are invalid. Default (``None``): the
    calibrated field of view, twice the largest off-axis angle that the direct polynomial
    reaches monotonically inside the image. ``world_from_camera`` as for
    :class:`FisheyeCamera` (OpenCV camera axes; default :func:`zenith_camera`).
    """

    pol: np.ndarray
    invpol: np.ndarray
    center: tuple[float, float]          # (xc = row, yc = column), 0-based C convention
    affine: tuple[float, float, float]   # (c, d, e)
    size: tuple[int, int]                # (width, height)
    fov_deg: float | None = None
    world_from_camera: np.ndarray = field(default_factory=zenith_camera)
    r_max: float = field(init=False)  # calibrated sensor radius (px), see _calibrated_radius

    def __post_init__(self) -> None:
        self.pol = np.asarray(self.pol, np.float64).reshape(-1)
        self.invpol = np.asarray(self.invpol, np.float64).reshape(-1)
        self.center = (float(self.center[0]), float(self.center[1]))
        self.affine = tuple(float(a) for a in self.affine)  # type: ignore[assignment]
        self.size = (int(self.size[0]), int(self.size[1]))
        self.world_from_camera = np.asarray(self.world_from_camera, np.float64).reshape(3, 3)
        for name, v in (("pol", self.pol), ("invpol", self.invpol), ("center", self.center),
                        ("affine", self.affine), ("world_from_camera",
                                                  self.world_from_camera)):
            if not np.all(np.isfinite(v)):
                raise InputError("holds NaN/Inf values", field=name)
        if self.pol.size < 2 or self.invpol.size < 1:
            raise InputError("OCamCalib model needs >= 2 direct and >= 1 inverse "
                             "coefficients", field="pol" if self.pol.size < 2 else "invpol")
        if not self.pol[0] < 0:
            raise InputError(f"a0 must be < 0 (the optical axis is -z), got {self.pol[0]}",
                             field="direct polynomial")
        c, d, e = self.affine
        if abs(c - d * e) < 1e-12:
            raise InputError(f"(c, d, e) = {self.affine} is singular", field="affine")
        if min(self.size) < 1:
            raise InputError(f"must be positive, got {self.size}", field="image size")
        self.r_max = self._calibrated_radius()
        limit = 2 * np.degrees(self._axis_angle(np.array(self.r_max)))
        if self.fov_deg is None:
            self.fov_deg = float(limit)
        elif not 0 < float(self.fov_deg) <= 360:
            raise InputError(f"must be in (0, 360], got {self.fov_deg}", field="fov_deg")
        self.fov_deg = float(self.fov_deg)

    # ------------------------------------------------------------------ file

    @classmethod
    def load(cls, path: str | Path, fov_deg: float | None = None) -> OcamCamera:
        """Read an OCamCalib ``calib_results.txt``: five records separated by ``#`` comment
        lines: ``n a0 .. a(n-1)`` (direct), ``m p0 .. p(m-1)`` (inverse), ``xc yc``
        (row, column), ``c d e``, ``height width``. Errors name the file and the record."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise InputError("not an OCamCalib calib_results.txt (binary data)",
                             file=str(path)) from exc
        except OSError as exc:
            raise InputError(f"cannot read ({exc.strerror or exc})", file=str(path)) from exc
        records = [ln.split() for ln in text.splitlines()
                   if ln.strip() and not ln.lstrip().startswith("#")]
        names = ("direct polynomial", "inverse polynomial", "center", "affine", "image size")
        if len(records) != 5:
            raise InputError(f"expected 5 records ({', '.join(names)}), found {len(records)}; "
                             "not an OCamCalib calib_results.txt", file=str(path))
        try:
            nums = [[float(x) for x in r] for r in records]
        except ValueError as exc:
            raise InputError(f"not a number ({exc})", file=str(path)) from exc
        for k, name in enumerate(names[:2]):
            n = nums[k][0]
            if n != int(n) or int(n) != len(nums[k]) - 1:
                raise InputError(f"count {n:g} does not match its {len(nums[k]) - 1} "
                                 "coefficients", file=str(path), field=name)
        for k, (name, n) in enumerate(zip(names[2:], (2, 3, 2), strict=True), start=2):
            if len(nums[k]) != n:
                raise InputError(f"expected {n} numbers, got {len(nums[k])}", file=str(path),
                                 field=name)
        h, w = nums[4]
        if h != int(h) or w != int(w) or h < 1 or w < 1:
            raise InputError(f"expected positive integers, got {h:g} {w:g}", file=str(path),
                             field="image size")
        try:
            return cls(pol=nums[0][1:], invpol=nums[1][1:], center=tuple(nums[2]),
                       affine=tuple(nums[3]), size=(int(w), int(h)), fov_deg=fov_deg)
        except InputError as exc:  # the model's check, naming the record
            raise InputError(exc.message, file=str(path), field=exc.field) from exc

    # ------------------------------------------------------------------ the model

    def _axis_angle(self, rho: np.ndarray) -> np.ndarray:
        """Angle (rad) between the optical axis and the ray at sensor radius ``rho``."""
        return np.arctan2(rho, -np.polynomial.polynomial.polyval(rho, self.pol))

    def _calibrated_radius(self) -> float:
        """The largest sensor radius inside the image up to which the off-axis angle grows
        monotonically (beyond it the polynomial folds back and is not a lens)."""
        w, h = self.size
        corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
        r_img = float(np.max(np.linalg.norm(self._sensor(corners), axis=-1)))
        r = np.linspace(0.0, r_img, 4097)
        grows = np.diff(self._axis_angle(r)) > 0
        stop = int(np.argmin(grows)) if not grows.all() else len(grows)
        return float(r[stop])

    def _sensor(self, pixels: np.ndarray) -> np.ndarray:
        """Our pixel coordinates ``(..., 2)`` -> sensor-plane ``(u, v)`` (rows, columns)."""
        p = np.asarray(pixels, np.float64)
        c, d, e = self.affine
        m1 = p[..., 1] - 0.5 - self.center[0]
        m2 = p[..., 0] - 0.5 - self.center[1]
        det = c - d * e
        return np.stack([(m1 - d * m2) / det, (-e * m1 + c * m2) / det], axis=-1)

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``(..., 2)`` -> world unit directions ``(..., 3)`` and a
        validity mask (inside the field of view and the calibrated radius)."""
        uv = self._sensor(pixels)
        rho = np.hypot(uv[..., 0], uv[..., 1])
        z = np.polynomial.polynomial.polyval(rho, self.pol)
        d = np.concatenate([uv, z[..., None]], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        valid = (rho <= self.r_max) & (self._axis_angle(rho) <= np.radians(self.fov_deg / 2)
                                       + 1e-12)
        return _ocam_to_opencv(d) @ self.world_from_camera.T, valid

    def project(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World unit directions ``(..., 3)`` -> pixel coordinates ``(..., 2)`` (top-left
        pixel centre at (0.5, 0.5)) and a validity mask.

        ``rho`` solves ``pol(rho) |(x, y)| = z rho`` (the ray through ``(u, v, pol(rho))``
        is parallel to the direction): the toolbox's ``invpol`` gives the start, Newton
        steps on the direct polynomial the rest."""
        d = _ocam_to_opencv(np.asarray(directions, np.float64) @ self.world_from_camera)
        x, y, z = d[..., 0], d[..., 1], d[..., 2]
        norm = np.hypot(x, y)
        theta = np.arctan2(z, norm)
        rho = np.polynomial.polynomial.polyval(theta, self.invpol)
        dpol = np.polynomial.polynomial.polyder(self.pol)
        for _ in range(30):
            g = np.polynomial.polynomial.polyval(rho, self.pol) * norm - z * rho
            gd = np.polynomial.polynomial.polyval(rho, dpol) * norm - z
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(gd != 0, g / gd, 0.0)
            rho = np.clip(rho - step, 0.0, 2 * self.r_max + 1.0)
            if np.max(np.abs(step), initial=0.0) < 1e-10:
                break
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(norm > 0, rho / norm, 0.0)
        u, v = x * s, y * s
        c, dd, e = self.affine
        row = c * u + dd * v + self.center[0]
        col = e * u + v + self.center[1]
        off_axis = np.arctan2(norm, -z)
        valid = (off_axis <= np.radians(self.fov_deg / 2) + 1e-12) & (rho <= self.r_max)
        return np.stack([col + 0.5, row + 0.5], axis=-1), valid

    def pixel_solid_angle(self) -> np.ndarray:
        """Solid angle (sr) of every pixel ``(H, W)`` (numerical, from :meth:`unproject`)."""
        return solid_angle_from_unproject(self.unproject, self.size)

    def pixel_angle(self) -> float:
        """Angle (rad) subtended by one pixel at the image centre: ``1 / |a0|``."""
        return float(1.0 / abs(self.pol[0]))


def is_ocamcalib_file(path: str | Path) -> bool:
    """Whether ``path`` looks like an OCamCalib ``calib_results.txt`` (its first line is
    the toolbox's ``#polynomial coefficients for the DIRECT mapping function`` header)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError:
        return False
    return head.lstrip().lower().startswith(b"#polynomial coefficients for the direct")


def load_camera(path: str | Path, fov_deg: float | None = None
                ) -> FisheyeCamera | OcamCamera:
    """Read a fisheye calibration of any supported kind: OCamCalib ``calib_results.txt``,
    OpenCV FileStorage YAML/XML or our JSON (:meth:`FisheyeCamera.load`).

    ``fov_deg``: an explicit field of view; None keeps the file's (the calibrated field of
    view for OCamCalib, ``fov_deg`` of a JSON file, 180 deg otherwise)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, expected a calibration file", file=str(path))
    if not path.is_file():
        raise InputError("calibration file not found", file=str(path))
    if is_ocamcalib_file(path) or path.suffix.lower() == ".txt":
        return OcamCamera.load(path, fov_deg)
    return FisheyeCamera.load(path, fov_deg)
