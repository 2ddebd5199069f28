"""Camera registration from a printed ChArUco board or ArUco marker (OpenCV's detectors).

Frames and conventions (see ``docs/insert.md``):

* **Board frame = the scene's world frame.** OpenCV describes a board in its own frame
  (origin at the top-left corner of the printed board image, x to the right, y down the
  image, z into the table). arlight's world is +Y up (``docs/conventions.md``), so the
  insert pipeline uses ``X = x_board``, ``Y = −z_board`` (up, out of the board), ``Z =
  y_board``: :data:`WORLD_FROM_BOARD`. The board lies in the plane ``Y = 0``, its squares in
  ``0 ≤ X ≤ cols·square``, ``0 ≤ Z ≤ rows·square`` (metres). A single ArUco marker's centre
  is the origin, its printed top edge towards −Z.
* **Pixels.** OpenCV puts pixel centres at integer coordinates, arlight at +0.5
  (``docs/conventions.md``); detection and the reprojection error are computed in OpenCV's
  convention on the original (distorted) photo, the scene camera gets ``cx + 0.5, cy + 0.5``.
* **Distortion** is removed, not carried: the photo is resampled (bilinear, edges
  replicated) into the pinhole camera with the same ``K`` and resolution, which is the
  scene's camera. A photo without distortion coefficients is used unchanged.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from arlight.errors import InputError, read_text

WORLD_FROM_BOARD = np.array([[1.0, 0.0, 0.0, 0.0],
                             [0.0, 0.0, -1.0, 0.0],
                             [0.0, 1.0, 0.0, 0.0],
                             [0.0, 0.0, 0.0, 1.0]])
"""4×4 rotation from OpenCV's board frame (x right, y down the print, z into the table) to
the scene's world frame (+Y up out of the board)."""

MIN_CORNERS = 6
"""Fewest ChArUco corners a pose is computed from (4 points fix a plane's pose exactly; a
few more average out the detector's noise)."""


@dataclass(frozen=True)
class MarkerSpec:
    """A printed target.

    Attributes:
        kind: ``"charuco"`` (a ChArUco board) or ``"aruco"`` (one ArUco marker).
        squares: (columns, rows) of a ChArUco board (OpenCV's ``size``); (1, 1) for a marker.
        square_length: side of a chessboard square (m); the marker side for ``aruco``.
        marker_length: side of the ArUco markers inside the squares (m).
        dictionary: OpenCV dictionary name, e.g. ``"DICT_6X6_250"``.
        marker_id: the marker's id for ``aruco`` (None: the first one found).
    """

    kind: str
    squares: tuple[int, int]
    square_length: float
    marker_length: float
    dictionary: str
    marker_id: int | None = None

    @property
    def extent(self) -> tuple[float, float]:
        """Board size (X, Z) in metres in the world frame."""
        return self.squares[0] * self.square_length, self.squares[1] * self.square_length

    def outline_world(self) -> np.ndarray:
        """The printed target's four corners ``(4, 3)`` in world coordinates (m)."""
        if self.kind == "aruco":
            h = self.marker_length / 2
            return np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]])
        w, d = self.extent
        return np.array([[0, 0, 0], [w, 0, 0], [w, 0, d], [0, 0, d]], float)

    def centre_world(self) -> np.ndarray:
        """Centre of the target in world coordinates (m)."""
        return self.outline_world().mean(axis=0)

    def cv_dictionary(self):
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def cv_board(self):
        """OpenCV's ``CharucoBoard`` (only for ``kind == "charuco"``)."""
        return cv2.aruco.CharucoBoard(self.squares, self.square_length, self.marker_length,
                                      self.cv_dictionary())


def _dictionary_name(name: str, field: str) -> str:
    name = name.strip().upper()
    if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise InputError(f"unknown ArUco dictionary {name!r}; expected an OpenCV name such "
                         "as DICT_6X6_250", field=field)
    return name


def parse_marker(spec: str, field: str = "--marker") -> MarkerSpec:
    """Parse a target description.

    Forms: ``charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT`` (e.g.
    ``charuco:5x7:0.04:0.02:DICT_6X6_250``), ``aruco:SIDE_M:DICT[:ID]``, or the path of a
    TOML file with ``type`` (``charuco``/``aruco``), ``squares = [cols, rows]``,
    ``square_length``, ``marker_length``, ``dictionary`` and optional ``id``.
    Raises :class:`InputError` naming ``field`` (or the file and its key).
    """
    if spec.lower().endswith(".toml"):
        return _marker_from_toml(Path(spec))
    parts = spec.split(":")
    kind = parts[0].strip().lower()
    try:
        if kind == "charuco" and len(parts) == 5:
            cols, rows = (int(x) for x in parts[1].lower().split("x"))
            sq, mk = float(parts[2]), float(parts[3])
            return _checked(MarkerSpec("charuco", (cols, rows), sq, mk,
                                       _dictionary_name(parts[4], field)), field)
        if kind == "aruco" and len(parts) in (3, 4):
            side = float(parts[1])
            mid = int(parts[3]) if len(parts) == 4 else None
            return _checked(MarkerSpec("aruco", (1, 1), side, side,
                                       _dictionary_name(parts[2], field), mid), field)
    except ValueError as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"cannot parse {spec!r} ({exc})", field=field) from exc
    raise InputError(f"cannot parse {spec!r}; expected charuco:COLSxROWS:SQUARE_M:MARKER_M:"
                     "DICT, aruco:SIDE_M:DICT[:ID] or a .toml file", field=field)


def dictionary_size(name: str) -> int:
    """Number of markers in OpenCV's predefined dictionary ``name``."""
    return int(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0])


def charuco_markers(squares: tuple[int, int]) -> int:
    """Markers on a ChArUco board of ``squares`` (one in every other square)."""
    return squares[0] * squares[1] // 2


def _checked(m: MarkerSpec, field: str) -> MarkerSpec:
    """Refuse a target that cannot exist before OpenCV builds it: a ChArUco board needs one
    distinct marker of its dictionary per white square, so its size is bounded by the
    dictionary (at most 1024 markers), which also bounds the memory of the board's model and
    its detection (``charuco:100000x100000:...`` would ask for 10¹⁰ corners)."""
    if min(m.squares) < 1 or (m.kind == "charuco" and min(m.squares) < 2):
        raise InputError(f"a ChArUco board needs at least 2×2 squares, got {m.squares}",
                         field=field)
    if not (np.isfinite(m.square_length) and np.isfinite(m.marker_length)
            and 1e-4 <= m.marker_length <= m.square_length <= 100):
        raise InputError("lengths must be finite, in metres (0.0001 … 100), the marker no "
                         "larger than the square", field=field)
    size = dictionary_size(m.dictionary)
    if m.kind == "charuco" and charuco_markers(m.squares) > size:
        raise InputError(f"a {m.squares[0]}×{m.squares[1]} ChArUco board has "
                         f"{charuco_markers(m.squares)} markers but {m.dictionary} has only "
                         f"{size}; such a board cannot be printed (check the board size)",
                         field=field)
    if m.marker_id is not None and not 0 <= m.marker_id < size:
        raise InputError(f"marker id must be in 0 … {size - 1} ({m.dictionary}), got "
                         f"{m.marker_id}", field=field)
    return m


def _marker_from_toml(path: Path) -> MarkerSpec:
    try:
        d = tomllib.loads(read_text(path, "marker file"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"cannot read the marker file ({exc})", file=str(path)) from exc
    known = {"type", "squares", "square_length", "marker_length", "dictionary", "id"}
    if extra := sorted(set(d) - known):
        raise InputError(f"unknown key; expected {', '.join(sorted(known))}", file=str(path),
                         field=extra[0])
    try:
        kind = str(d["type"]).lower()
        if kind not in ("charuco", "aruco"):
            raise InputError(f"unknown target type {kind!r}; expected charuco or aruco",
                             file=str(path), field="type")
        side = float(d.get("square_length", d.get("marker_length")))
        sq = tuple(int(x) for x in d.get("squares", [1, 1]))
        m = MarkerSpec(kind, (sq[0], sq[1]), side, float(d.get("marker_length", side)),
                       _dictionary_name(str(d["dictionary"]), "dictionary"),
                       int(d["id"]) if "id" in d else None)
    except InputError as exc:
        raise InputError(exc.message, file=str(path), field=exc.field) from exc
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"missing or malformed value ({exc})", file=str(path)) from exc
    try:
        return _checked(m, "--marker")
    except InputError as exc:
        raise InputError(exc.message, file=str(path), field="--marker") from exc


@dataclass(frozen=True)
class Calibration:
    """Intrinsics in OpenCV's pixel convention (centres at integers), distortion
    coefficients (OpenCV order k1 k2 p1 p2 [k3 ...]) and the image size they belong to."""

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int] | None  # (width, height) in pixels, None when the file has none
    source: str = "<calibration>"

    def check_size(self, width: int, height: int, photo: str) -> None:
        """InputError unless the photo has the calibrated size (a calibration made at another
        resolution has other intrinsics in pixels)."""
        if self.size is not None and self.size != (width, height):
            raise InputError(f"calibrated for {self.size[0]}×{self.size[1]} images but the "
                             f"photo {photo} is {width}×{height}; calibrate at the photo's "
                             "resolution (or scale K)", file=self.source, field="image_width")
        if self.size is None and not (0 < self.K[0, 2] < width and 0 < self.K[1, 2] < height):
            raise InputError(f"principal point ({self.K[0, 2]:.1f}, {self.K[1, 2]:.1f}) lies "
                             f"outside the {width}×{height} photo {photo}",
                             file=self.source, field="camera_matrix")


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration: OpenCV FileStorage YAML/XML (``camera_matrix``,
    ``distortion_coefficients``, ``image_width``, ``image_height``) or JSON with ``K``
    (OpenCV convention, 3×3), optional ``dist`` and ``size`` [w, h]."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise InputError("calibration file not found", file=src)
    if path.suffix.lower() == ".json":
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            K = np.asarray(d["K"], np.float64)
            dist = np.asarray(d.get("dist", []), np.float64).ravel()
            size = tuple(int(x) for x in d["size"]) if "size" in d else None
        except (OSError, KeyError, TypeError, ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"bad calibration ({exc})", file=src) from exc
    else:
        try:
            fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:
            msg = " ".join(str(exc).split())
            raise InputError(f"cannot parse the calibration ({msg[-160:]})", file=src) from exc
        if not fs.isOpened():
            raise InputError("cannot open the calibration (not OpenCV YAML/XML?)", file=src)
        try:
            K = fs.getNode("camera_matrix").mat()
            dn = fs.getNode("distortion_coefficients")
            dist = np.zeros(0) if dn.empty() else np.asarray(dn.mat(), np.float64).ravel()
            w, h = fs.getNode("image_width").real(), fs.getNode("image_height").real()
            size = (int(w), int(h)) if w and h else None
        except (cv2.error, TypeError) as exc:
            raise InputError(f"bad calibration field ({exc})", file=src) from exc
        finally:
            fs.release()
        if K is None:
            raise InputError("missing camera_matrix", file=src, field="camera_matrix")
        K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError("camera_matrix must be a finite 3×3 matrix with fx, fy > 0",
                         file=src, field="camera_matrix")
    if dist.size not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise InputError("distortion_coefficients must be 4, 5, 8, 12 or 14 finite numbers",
                         file=src, field="distortion_coefficients")
    if size is not None and min(size) <= 0:
        raise InputError("image size must be positive", file=src, field="image_width")
    return Calibration(K=K, dist=dist, size=size, source=src)


@dataclass(frozen=True)
class Registration:
    """The camera's pose in the world (= board) frame and how well it fits.

    Attributes:
        world_from_camera: 4×4 rigid pose, OpenCV camera axes (x right, y down, z forward).
        reprojection_px: mean distance (px) between the detected corners and the board's
            corners projected with the pose, on the original photo (distortion applied).
        reprojection_max_px: the largest of those distances (px).
        corners: number of corners the pose rests on.
        image_points: ``(N, 2)`` detected corners (OpenCV pixel convention, distorted photo).
        world_points: ``(N, 3)`` the same corners in world coordinates (m).
    """

    world_from_camera: np.ndarray
    reprojection_px: float
    reprojection_max_px: float
    corners: int
    image_points: np.ndarray
    world_points: np.ndarray

    def summary(self) -> dict:
        """JSON-ready report."""
        return {"reprojection_error_px": self.reprojection_px,
                "reprojection_error_max_px": self.reprojection_max_px,
                "corners": self.corners,
                "world_from_camera": self.world_from_camera.tolist()}


def _detect(gray: np.ndarray, marker: MarkerSpec, photo: str) -> tuple[np.ndarray, np.ndarray]:
    """Corresponding board points ``(N, 3)`` (board frame) and image points ``(N, 2)``."""
    if marker.kind == "charuco":
        board = marker.cv_board()
        cc, ci, mc, mi = cv2.aruco.CharucoDetector(board).detectBoard(gray)
        if mi is None or len(mi) == 0:
            raise InputError(f"no {marker.dictionary} marker of the board found",
                             file=photo, field="--marker")
        n = 0 if ci is None else len(ci)
        if n < MIN_CORNERS:
            raise InputError(f"only {n} ChArUco corners found ({len(mi)} markers); at least "
                             f"{MIN_CORNERS} are needed for a pose (is the board fully in "
                             "view and the --marker description right?)",
                             file=photo, field="--marker")
        obj, img = board.matchImagePoints(cc, ci)
        return obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)
    det = cv2.aruco.ArucoDetector(marker.cv_dictionary())
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        raise InputError(f"no {marker.dictionary} marker found", file=photo, field="--marker")
    ids = ids.ravel()
    k = 0 if marker.marker_id is None else int(np.flatnonzero(ids == marker.marker_id)[0]) \
        if np.any(ids == marker.marker_id) else -1
    if k < 0:
        raise InputError(f"marker id {marker.marker_id} not found (found {sorted(ids)})",
                         file=photo, field="--marker")
    h = marker.marker_length / 2
    # OpenCV's marker corner order: top-left, top-right, bottom-right, bottom-left (z = 0)
    obj = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
    return obj, corners[k].reshape(4, 2).astype(np.float64)


def register(image_codes: np.ndarray, calib: Calibration, marker: MarkerSpec,
             photo: str = "<photo>") -> Registration:
    """Detect ``marker`` in the photo (uint8/uint16 ``(H, W, 3)`` code values, or grey
    ``(H, W)``) and solve the camera pose with the calibration (distortion included).

    Raises :class:`InputError` naming the photo when the target is not found or too few of
    its corners are."""
    img = np.asarray(image_codes)
    if img.dtype != np.uint8:
        img = (img.astype(np.float64) / np.iinfo(img.dtype).max * 255 + 0.5).astype(np.uint8)
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    obj, pts = _detect(gray, marker, photo)
    flag = cv2.SOLVEPNP_IPPE_SQUARE if marker.kind == "aruco" else cv2.SOLVEPNP_IPPE
    ok, rvec, tvec = cv2.solvePnP(obj, pts, calib.K, calib.dist, flags=flag)
    if not ok:
        raise InputError("no camera pose fits the detected corners", file=photo,
                         field="--marker")
    rvec, tvec = cv2.solvePnPRefineLM(obj, pts, calib.K, calib.dist, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, calib.K, calib.dist)
    err = np.linalg.norm(proj.reshape(-1, 2) - pts, axis=1)
    cam_from_board = np.eye(4)
    cam_from_board[:3, :3] = cv2.Rodrigues(rvec)[0]
    cam_from_board[:3, 3] = tvec.ravel()
    world_from_camera = WORLD_FROM_BOARD @ np.linalg.inv(cam_from_board)
    world_pts = obj @ WORLD_FROM_BOARD[:3, :3].T
    return Registration(world_from_camera=world_from_camera, reprojection_px=float(err.mean()),
                        reprojection_max_px=float(err.max()), corners=len(pts),
                        image_points=pts, world_points=world_pts)


def undistort(image: np.ndarray, calib: Calibration) -> np.ndarray:
    """The photo resampled into the pinhole camera with the same ``K`` and size (bilinear,
    borders replicated); returned unchanged when there is no distortion. Works on code values
    or linear radiance, any dtype OpenCV remaps."""
    if not np.any(calib.dist):
        return image
    h, w = image.shape[:2]
    mx, my = cv2.initUndistortRectifyMap(calib.K, calib.dist, None, calib.K, (w, h),
                                         cv2.CV_32FC1)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
