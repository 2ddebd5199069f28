"""Reading an RGB-D sequence folder: colour + depth images, poses, intrinsics.

Layout of ``RGBD_DIR``::

    color/   (or colour/, rgb/)   one image per frame, any format imageio/OpenCV reads
    depth/                        one 16-bit image per frame (PNG/PGM), same sorted order
    intrinsics.json               optional: {"fx":..., "fy":..., "cx":..., "cy":...}
                                  (or give them with --intrinsics fx,fy,cx,cy)

Poses (``--poses FILE``): one line per frame, either ``tx ty tz qx qy qz qw`` (slambook /
TUM order; a leading timestamp column is allowed, 8 numbers) giving ``world_from_camera``, or
a Redwood/Open3D ``.log`` trajectory (a header line then 4 rows of the camera-to-world
matrix per frame). Camera axes are OpenCV's (x right, y down, z forward).

Every check runs before any work and raises :class:`~arlight.errors.InputError` naming the
file and the field: colour and depth of different sizes, fewer poses than frames, a frame
without valid depth, non-finite poses.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from arlight.errors import InputError
from arlight.probeless.reconstruct import RGBDFrame
from arlight.rotations import pose_matrix
from arlight.scene.camera import Camera

_COLOUR_DIRS = ("color", "colour", "rgb")
_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".tif", ".tiff", ".bmp"}


def quaternion_pose(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """4×4 ``world_from_camera`` from a translation and a unit quaternion ``(x, y, z, w)``
    (:func:`arlight.rotations.pose_matrix`)."""
    return pose_matrix(t, q)


def read_poses(path: Path) -> list[np.ndarray]:
    """Poses of a ``tx ty tz qx qy qz qw`` file or a Redwood ``.log`` trajectory."""
    try:
        lines = [ln.split() for ln in Path(path).read_text().splitlines()
                 if ln.strip() and not ln.lstrip().startswith("#")]
    except OSError as exc:
        raise InputError(f"cannot read poses ({exc.strerror or exc})", file=str(path),
                         field="poses") from exc
    poses: list[np.ndarray] = []
    try:
        if lines and len(lines[0]) == 3 and all(len(ln) == 4 for ln in lines[1:5]):
            for i in range(0, len(lines), 5):
                poses.append(np.array([[float(v) for v in ln] for ln in lines[i + 1:i + 5]]))
        else:
            for ln in lines:
                v = [float(x) for x in ln]
                if len(v) not in (7, 8):
                    raise ValueError(f"expected 7 or 8 numbers per line, got {len(v)}")
                v = np.array(v[-7:])
                if not np.all(np.isfinite(v)) or not np.any(v[3:]):
                    poses.append(np.full((4, 4), np.nan))  # refused below, by its index
                else:
                    poses.append(quaternion_pose(v[:3], v[3:]))
    except (ValueError, IndexError) as exc:
        raise InputError(f"malformed pose line ({exc})", file=str(path), field="poses") from exc
    for i, p in enumerate(poses):
        if p.shape != (4, 4) or not np.all(np.isfinite(p)):
            raise InputError(f"pose {i} is not a finite 4×4 matrix", file=str(path),
                             field=f"poses[{i}]")
    return poses


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT)


def image_dirs(folder: str | Path) -> list[Path]:
    """The colour and depth image folders of an RGB-D folder that exist."""
    folder = Path(folder)
    return [folder / n for n in (*_COLOUR_DIRS, "depth") if (folder / n).is_dir()]


def frame_files(folder: str | Path) -> tuple[list[Path], list[Path]]:
    """The colour and depth image files of an RGB-D folder, in frame order (unchecked)."""
    folder = Path(folder)
    cdir = next((folder / n for n in _COLOUR_DIRS if (folder / n).is_dir()), None)
    depth = folder / "depth"
    return (_images(cdir) if cdir else [], _images(depth) if depth.is_dir() else [])


def parse_intrinsics(text: str | None, folder: Path) -> tuple[float, float, float, float]:
    """``fx,fy,cx,cy`` from the option, else ``RGBD_DIR/intrinsics.json``."""
    if text is not None:
        try:
            fx, fy, cx, cy = (float(v) for v in text.split(","))
        except ValueError as exc:
            raise InputError(f"expected fx,fy,cx,cy in pixels, got {text!r}",
                             field="--intrinsics") from exc
        vals = (fx, fy, cx, cy)
    else:
        f = folder / "intrinsics.json"
        if not f.is_file():
            raise InputError("no intrinsics: give --intrinsics fx,fy,cx,cy or put "
                             "intrinsics.json in the folder", file=str(folder),
                             field="intrinsics")
        try:
            d = json.loads(f.read_text())
            vals = tuple(float(d[k]) for k in ("fx", "fy", "cx", "cy"))
        except (ValueError, KeyError, TypeError) as exc:
            raise InputError(f"expected fx, fy, cx, cy numbers ({exc})", file=str(f),
                             field="intrinsics") from exc
    if (not all(np.isfinite(vals)) or vals[0] <= 0 or vals[1] <= 0
            or max(abs(v) for v in vals) > 1e7):
        raise InputError(f"intrinsics must be finite with 0 < fx, fy and |values| <= 1e7 px, "
                         f"got {vals}", field="--intrinsics" if text is not None
                         else "intrinsics")
    return vals  # type: ignore[return-value]


def read_sequence(folder: str | Path, poses: str | Path | None,
                  intrinsics: str | None = None, depth_scale: float = 1000.0,
                  max_frames: int | None = None) -> list[RGBDFrame]:
    """Read and check every frame of an RGB-D folder (see the module docstring)."""
    from arlight.io.images import read_depth, read_linear

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", file=str(folder), field="RGBD_DIR")
    cdir = next((folder / n for n in _COLOUR_DIRS if (folder / n).is_dir()), None)
    if cdir is None or not (folder / "depth").is_dir():
        raise InputError("expected color/ and depth/ subfolders", file=str(folder),
                         field="RGBD_DIR")
    colours, depths = _images(cdir), _images(folder / "depth")
    if not colours:
        raise InputError("no colour images", file=str(cdir), field="color")
    if len(colours) != len(depths):
        raise InputError(f"{len(colours)} colour images but {len(depths)} depth images",
                         file=str(folder / "depth"), field="depth")
    if poses is None:
        raise InputError("missing poses: give --poses FILE (one camera-to-world pose per "
                         "frame)", field="--poses")
    pose_list = read_poses(Path(poses))
    if len(pose_list) < len(colours):
        raise InputError(f"{len(pose_list)} poses for {len(colours)} frames",
                         file=str(poses), field="poses")
    if not np.isfinite(depth_scale) or depth_scale <= 0:
        raise InputError(f"must be > 0, got {depth_scale}", field="--depth-scale")
    fx, fy, cx, cy = parse_intrinsics(intrinsics, folder)
    n = len(colours) if max_frames is None else min(len(colours), max_frames)
    frames = []
    for i in range(n):
        col = read_linear(colours[i])
        dep = read_depth(depths[i], depth_scale)
        if col.shape[:2] != dep.shape:
            raise InputError(f"depth is {dep.shape[1]}×{dep.shape[0]} but colour "
                             f"{colours[i].name} is {col.shape[1]}×{col.shape[0]}",
                             file=str(depths[i]), field="depth")
        if not np.any(np.isfinite(dep) & (dep > 0)):
            raise InputError("the frame has no valid depth (all zero)", file=str(depths[i]),
                             field="depth")
        h, w = dep.shape
        cam = Camera(w, h, fx, fy, cx, cy, world_from_camera=pose_list[i])
        frames.append(RGBDFrame(colour=col.astype(np.float32), depth=dep, camera=cam,
                                name=colours[i].name, timestamp=float(i)))
    return frames


__all__ = ["frame_files", "image_dirs", "parse_intrinsics", "quaternion_pose", "read_poses",
           "read_sequence"]
