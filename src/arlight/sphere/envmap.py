"""Environment-map parameterisations and conversions between them.

Every mapping is a pair of functions between world unit directions and continuous pixel
coordinates ``(x, y)`` (top-left corner of the image at (0, 0), so the centre of the top-left
pixel is (0.5, 0.5)):

* ``"equirect"`` (latitude-longitude), exactly ``docs/conventions.md`` / Mitsuba's envmap:
  ``u = x/W = phi/(2pi)``, ``v = y/H = theta/pi``, ``d = (sin th sin ph, cos th, -sin th cos ph)``.
* ``"angular"``: Debevec's angular light-probe map (square image; same formulas as
  skylibs' ``angular`` format): the centre looks along -Z, image right is +X and image up
  is +Y, and the distance from the centre is proportional to the angle from -Z:
  ``r = acos(-z)/pi`` in units of the disk radius (r = 1 is the +Z direction).
* ``"ball"``: a photograph of a mirror ball, given its centre ``(cx, cy)`` and radius in
  pixels. Orthographic viewer (distant camera) looking along camera +z, OpenCV camera axes,
  ``world_from_camera`` (default: camera looking along world -Z with +Y up). A pixel at
  normalised offset ``(a, b)`` from the centre sees the ball normal
  ``n = (a, b, -sqrt(1-a^2-b^2))`` and the reflected ray ``r = v - 2 (v.n) n``.
* ``"fisheye"``: :class:`arlight.sphere.fisheye.FisheyeCamera` (equidistant or OpenCV
  fisheye) or :class:`~arlight.sphere.fisheye.OcamCamera` (OCamCalib), optionally
  mirroring the upper hemisphere into the lower one (Kan 2014 Sec. 5.3).

:func:`to_equirect` resamples any of them onto our equirect grid (bilinear with
supersampling); :func:`from_equirect` renders an equirect map into any of them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from arlight.errors import InputError
from arlight.sphere.fisheye import FisheyeCamera, OcamCamera

MAPPINGS = ("equirect", "angular", "ball", "fisheye")

# ----------------------------------------------------------------------------- equirect


def equirect_directions(height: int, width: int | None = None) -> np.ndarray:
    """Unit direction of every pixel centre of an equirect map -> ``(H, W, 3)`` float64."""
    W = 2 * height if width is None else width
    theta = (np.arange(height) + 0.5) * np.pi / height
    phi = (np.arange(W) + 0.5) * 2 * np.pi / W
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    sp, cp = np.sin(phi)[None, :], np.cos(phi)[None, :]
    return np.stack([st * sp, np.broadcast_to(ct, (height, W)), -st * cp], axis=-1)


def equirect_row_solid_angle(height: int, width: int | None = None) -> np.ndarray:
    """Exact solid angle (sr) of one pixel of each row ``(H,)``: ``(2pi/W)(cos th0 -
    cos th1)`` (every pixel of a row has the same; use this instead of the full
    :func:`equirect_solid_angle` plane for large maps)."""
    W = 2 * height if width is None else width
    edges = np.cos(np.linspace(0.0, np.pi, height + 1))
    return (edges[:-1] - edges[1:]) * (2 * np.pi / W)


def equirect_solid_angle(height: int, width: int | None = None) -> np.ndarray:
    """Exact solid angle (sr) of every pixel ``(H, W)``: ``(2pi/W)(cos th0 - cos th1)``.

    Equal to the conventions' ``(2pi/W)(pi/H) sin th`` up to O(H^-2); sums to 4 pi."""
    W = 2 * height if width is None else width
    row = equirect_row_solid_angle(height, W)
    return np.broadcast_to(row[:, None], (height, W)).copy()


def direction_to_equirect(directions: np.ndarray, height: int,
                          width: int | None = None) -> np.ndarray:
    """World directions ``(..., 3)`` -> continuous pixel coordinates ``(..., 2)`` (x, y)."""
    W = 2 * height if width is None else width
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    phi = np.mod(np.arctan2(d[..., 0], -d[..., 2]), 2 * np.pi)
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    return np.stack([phi / (2 * np.pi) * W, theta / np.pi * height], axis=-1)


def sample_equirect(image: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an equirect map at directions ``(..., 3)`` -> ``(..., C)``
    (wraps in longitude, clamps in latitude)."""
    img = np.asarray(image)
    H, W = img.shape[:2]
    xy = direction_to_equirect(directions, H, W) - 0.5
    x0 = np.floor(xy[..., 0]).astype(np.int64)
    y0 = np.floor(xy[..., 1]).astype(np.int64)
    fx = (xy[..., 0] - x0)[..., None]
    fy = (xy[..., 1] - y0)[..., None]
    xa, xb = np.mod(x0, W), np.mod(x0 + 1, W)
    ya, yb = np.clip(y0, 0, H - 1), np.clip(y0 + 1, 0, H - 1)
    top = img[ya, xa] * (1 - fx) + img[ya, xb] * fx
    bot = img[yb, xa] * (1 - fx) + img[yb, xb] * fx
    return top * (1 - fy) + bot * fy


def rotate_equirect(image: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Turn the environment by rotation ``R``: ``out(d) = in(R^T d)``."""
    H, W = image.shape[:2]
    dirs = equirect_directions(H, W)
    return sample_equirect(image, dirs @ np.asarray(R, np.float64)).astype(np.float32)


def mirror_lower_hemisphere(image: np.ndarray) -> np.ndarray:
    """Replace the lower half of an equirect map by the mirror image of the upper half
    (``L(x, -y, z) = L(x, y, z)``; Kan 2014 Sec. 5.3 for upward fisheye captures)."""
    out = np.array(image, copy=True)
    H = out.shape[0]
    out[H - H // 2:] = out[: H // 2][::-1]
    return out


def resize_equirect(image: np.ndarray, height: int) -> np.ndarray:
    """Resample an equirect map to ``(height, 2*height)`` (area averaging when shrinking)."""
    import cv2

    img = np.asarray(image, dtype=np.float32)
    if img.shape[0] == height and img.shape[1] == 2 * height:
        return img.copy()
    interp = cv2.INTER_AREA if height < img.shape[0] else cv2.INTER_LINEAR
    out = cv2.resize(img, (2 * height, height), interpolation=interp)
    return out.reshape(height, 2 * height, -1) if img.ndim == 3 else out


# ----------------------------------------------------------------------------- angular


def angular_project(directions: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions -> pixel coords in a ``size x size`` angular map (Debevec) + valid mask."""
    d = np.asarray(directions, np.float64)
    rxy = np.hypot(d[..., 0], d[..., 1])
    alpha = np.arccos(np.clip(-d[..., 2], -1.0, 1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(rxy > 1e-15, (alpha / np.pi) / rxy, 0.0)
    a, b = d[..., 0] * s, d[..., 1] * s
    xy = np.stack([(a + 1) * size / 2, (1 - b) * size / 2], axis=-1)
    return xy, np.ones(d.shape[:-1], bool)


def angular_unproject(pixels: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(pixels, np.float64)
    a = 2 * p[..., 0] / size - 1
    b = 1 - 2 * p[..., 1] / size
    r = np.hypot(a, b)
    alpha = np.pi * r
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(r > 0, np.sin(alpha) / r, 0.0)
    d = np.stack([a * s, b * s, -np.cos(alpha)], axis=-1)
    return d, r <= 1.0


# ----------------------------------------------------------------------------- mirror ball


def _ball_camera(world_from_camera: np.ndarray | None) -> np.ndarray:
    # default: camera looks along world -Z, image right = +X, image down = -Y
    if world_from_camera is None:
        return np.diag([1.0, -1.0, -1.0])
    return np.asarray(world_from_camera, np.float64).reshape(3, 3)


def ball_project(directions: np.ndarray, center: tuple[float, float], radius: float,
                 world_from_camera: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Directions -> pixel coords on a mirror-ball photograph + valid mask."""
    Rwc = _ball_camera(world_from_camera)
    r = np.asarray(directions, np.float64) @ Rwc  # camera coordinates
    n = r - np.array([0.0, 0.0, 1.0])  # n is parallel to r - v
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    valid = norm[..., 0] > 1e-9
    n = n / np.where(norm > 1e-9, norm, 1.0)
    xy = np.stack([center[0] + radius * n[..., 0], center[1] + radius * n[..., 1]], axis=-1)
    return xy, valid


def ball_unproject(pixels: np.ndarray, center: tuple[float, float], radius: float,
                   world_from_camera: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(pixels, np.float64)
    a = (p[..., 0] - center[0]) / radius
    b = (p[..., 1] - center[1]) / radius
    q = a * a + b * b
    valid = q <= 1.0
    nz = -np.sqrt(np.clip(1 - q, 0, None))
    # r = v - 2 (v.n) n with v = (0, 0, 1): v.n = nz
    r = np.stack([-2 * nz * a, -2 * nz * b, 1 - 2 * nz * nz], axis=-1)
    return r @ _ball_camera(world_from_camera).T, valid


# ----------------------------------------------------------------------------- dispatch


def _projector(mapping: str, shape: tuple[int, int], kw: dict
               ) -> tuple[Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                          Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]]:
    """(project, unproject) closures for ``mapping`` on an image of ``shape = (H, W)``."""
    H, W = shape
    if mapping == "equirect":
        def proj(d):
            return direction_to_equirect(d, H, W), np.ones(d.shape[:-1], bool)

        def unproj(p):
            u, v = p[..., 0] / W, p[..., 1] / H
            th, ph = np.pi * v, 2 * np.pi * u
            d = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1)
            return d, (v >= 0) & (v <= 1)
        return proj, unproj
    if mapping == "angular":
        if H != W:
            raise InputError(f"an angular map must be square, got {W}x{H}", field="image")
        return (lambda d: angular_project(d, W)), (lambda p: angular_unproject(p, W))
    if mapping == "ball":
        try:
            center, radius = kw["center"], float(kw["radius"])
        except KeyError as exc:
            raise InputError("mapping 'ball' needs center=(cx, cy) and radius (pixels)",
                             field="center") from exc
        rot = kw.get("world_from_camera")
        return (lambda d: ball_project(d, center, radius, rot),
                lambda p: ball_unproject(p, center, radius, rot))
    if mapping == "fisheye":
        cam = kw.get("camera")
        if not isinstance(cam, FisheyeCamera | OcamCamera):
            raise ValueError("mapping 'fisheye' needs camera=FisheyeCamera(...) or "
                             "OcamCamera(...)")
        if (W, H) != cam.size:
            raise InputError(f"fisheye image is {W}x{H} but the calibration is for "
                             f"{cam.size[0]}x{cam.size[1]}", field="image")
        return cam.project, cam.unproject
    raise ValueError(f"unknown mapping {mapping!r}; expected one of {MAPPINGS}")


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``image (H, W, C)`` at continuous pixel coords, zero outside."""
    import cv2

    H, W = image.shape[:2]
    mx = (xy[..., 0] - 0.5).astype(np.float32)
    my = (xy[..., 1] - 0.5).astype(np.float32)
    out = cv2.remap(np.ascontiguousarray(image, dtype=np.float32), mx, my,
                    interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=0)
    return out.reshape(xy.shape[:-1] + (-1,))


def to_equirect(image: np.ndarray, mapping: str, height: int | None = None,
                supersample: int = 2, mirror_lower: bool = False, **kwargs) -> np.ndarray:
    """Resample an environment image in ``mapping`` onto our equirect grid.

    Returns ``(height, 2*height, 3)`` float32 (``height`` defaults to the source height,
    or half of it for the square angular/ball/fisheye images). Directions the source does
    not see are 0, unless ``mirror_lower`` fills the lower hemisphere from the upper one
    (Kan). Extra keyword arguments: ``center``/``radius``/``world_from_camera`` for
    ``"ball"``, ``camera`` (a :class:`FisheyeCamera` or :class:`OcamCamera`) for
    ``"fisheye"``.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] < 3:
        raise InputError(f"expected an (H, W, 3) image, got shape {img.shape}", field="image")
    img = img[..., :3]
    if height is None:
        height = img.shape[0] if mapping == "equirect" else max(8, img.shape[0] // 2)
    height = int(height)
    if mapping == "equirect":
        if img.shape[1] != 2 * img.shape[0]:
            raise InputError(f"an equirect map must be 2:1, got {img.shape[1]}x{img.shape[0]}",
                             field="image")
        out = resize_equirect(img, height)
        return mirror_lower_hemisphere(out) if mirror_lower else out
    proj, _ = _projector(mapping, img.shape[:2], kwargs)
    ss = max(1, int(supersample))
    dirs = equirect_directions(height * ss)
    if mirror_lower:
        dirs = dirs.copy()
        dirs[..., 1] = np.abs(dirs[..., 1])
    xy, valid = proj(dirs)
    out = _bilinear(img, np.where(valid[..., None], xy, -10.0))
    if ss > 1:
        out = out.reshape(height, ss, 2 * height, ss, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(out, dtype=np.float32)


def from_equirect(equirect: np.ndarray, mapping: str, size: tuple[int, int] | int,
                  **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Render an equirect map into another mapping: returns the image ``(H, W, C)`` and its
    valid mask ``(H, W)``. ``size`` is ``(width, height)`` or one int for square images."""
    W, H = (size, size) if isinstance(size, int) else size
    _, unproj = _projector(mapping, (H, W), kwargs)
    xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d, valid = unproj(np.stack([xs, ys], axis=-1))
    out = sample_equirect(np.asarray(equirect, np.float32), d).astype(np.float32)
    out[~valid] = 0.0
    return out, valid


def project_directions(mapping: str, shape: tuple[int, int], directions: np.ndarray,
                       **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of world directions in an image of ``mapping``, plus valid mask."""
    proj, _ = _projector(mapping, shape, kwargs)
    return proj(np.asarray(directions, np.float64))
