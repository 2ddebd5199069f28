"""Per-frame poses of a sequence: files, keyframes and their interpolation.

A *pose* is a 4×4 rigid matrix. The camera's is ``world_from_camera`` in OpenCV camera axes
(x right, y down, z forward; ``docs/conventions.md``); an object's is the world-space motion
applied on the left of its rest transform (``FrameView.object_transforms``).

Two file formats (``docs/sequence.md``):

* **poses text** (``poses.txt``): one line per frame or per keyframe, ``#`` starts a comment,
  numbers separated by blanks or commas::

      FRAME tx ty tz qx qy qz qw            # translation (m) + unit quaternion (Hamilton)
      FRAME r00 r01 r02 tx r10 ... r22 tz   # the top 3×4 rows of the matrix, row-major

  An object file puts the shape's name after the frame index (``FRAME NAME tx ...``).
* **keyframes TOML**: ``[[camera]]`` tables with ``frame`` and ``look_at = {origin, target,
  up}`` or ``world_from_camera``, and ``[[objects.<name>]]`` tables with ``frame`` and a scene
  ``transform`` table (``translate``, ``rotate``, ``scale`` or ``matrix``).

When the frame indices of a track are sparse they are keyframes: frames between two
keyframes get the translation linearly interpolated, the rotation by spherical linear
interpolation of the quaternions (slerp, Shoemake 1985) and the scale log-linearly. The
keyframes must span the sequence (first at frame 0, last at frame N − 1).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arlight.errors import InputError, read_text
from arlight.rotations import matrix_to_quat, quat_to_matrix, slerp

MAX_COORDINATE = 1e6
"""Largest translation (m) or scale a pose may have: anything beyond is a unit error."""

OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Camera-axes flip between OpenCV (y down, z forward) and OpenGL/ARKit (y up, z backward)."""


# quaternions (x, y, z, w): arlight.rotations (scipy's Rotation and Slerp), re-exported here


# ------------------------------------------------------------------------- decomposition
@dataclass(frozen=True)
class Keyframe:
    """A pose at one frame, decomposed as ``T · R · S`` (translation m, unit quaternion
    ``(x, y, z, w)``, per-axis scale)."""

    frame: int
    translation: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))

    @staticmethod
    def from_matrix(frame: int, m: np.ndarray, where: str = "") -> Keyframe:
        """Decompose an affine 4×4 ``T·R·S`` (S diagonal, positive); InputError otherwise."""
        m = np.asarray(m, np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or \
                not np.allclose(m[3], [0, 0, 0, 1]):
            raise InputError("expected a finite affine 4×4 matrix", field=where or None)
        if np.any(np.abs(m[:3, 3]) > MAX_COORDINATE):
            raise InputError(f"translation beyond ±{MAX_COORDINATE:g} m", field=where or None)
        a = m[:3, :3]
        s = np.linalg.norm(a, axis=0)
        if np.any(s < 1e-9):
            raise InputError("the matrix is singular", field=where or None)
        if np.any(s > MAX_COORDINATE):
            raise InputError(f"scale beyond {MAX_COORDINATE:g}", field=where or None)
        r = a / s
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
            raise InputError("expected translation · rotation · positive axis scale (no "
                             "shear or mirroring)", field=where or None)
        return Keyframe(frame, m[:3, 3].copy(), matrix_to_quat(r), s)

    def matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(self.rotation) * self.scale
        m[:3, 3] = self.translation
        return m


def interpolate(keys: list[Keyframe], n_frames: int, where: str = "poses") -> list[np.ndarray]:
    """4×4 poses of frames ``0 .. n_frames−1`` from keyframes (sorted here).

    A frame that is a keyframe gets its matrix exactly; frames between keyframes ``a`` and
    ``b`` get ``t = (f − a)/(b − a)``: translation ``(1−t)·T_a + t·T_b``, rotation
    ``slerp(q_a, q_b, t)``, scale ``S_a^(1−t) · S_b^t``. Raises :class:`InputError` when the
    keyframes do not span ``0 .. n_frames−1`` or a frame is given twice.
    """
    keys = sorted(keys, key=lambda k: k.frame)
    frames = [k.frame for k in keys]
    if not keys:
        raise InputError("no poses given", field=where)
    dup = sorted({f for f in frames if frames.count(f) > 1})
    if dup:
        raise InputError(f"frame {dup[0]} is given twice", field=where)
    if frames[0] != 0 or frames[-1] != n_frames - 1:
        raise InputError(f"poses for frames {frames[0]}..{frames[-1]} ({len(keys)} lines) but "
                         f"the sequence has {n_frames} frames (0..{n_frames - 1}); give a pose "
                         "for every frame, or keyframes from 0 to the last frame", field=where)
    out: list[np.ndarray] = []
    j = 0
    for f in range(n_frames):
        while keys[j].frame < f:
            j += 1
        if keys[j].frame == f:
            out.append(keys[j].matrix())
            continue
        a, b = keys[j - 1], keys[j]
        t = (f - a.frame) / (b.frame - a.frame)
        out.append(Keyframe(f, (1 - t) * a.translation + t * b.translation,
                            slerp(a.rotation, b.rotation, t),
                            np.exp((1 - t) * np.log(a.scale) + t * np.log(b.scale))).matrix())
    return out


# ------------------------------------------------------------------------------ text files
_SPLIT = re.compile(r"[\s,]+")


def _pose_numbers(nums: list[float], where: str) -> np.ndarray:
    """4×4 from 7 numbers (t, q) or 12 (3×4 row-major)."""
    if len(nums) == 7:
        q = np.asarray(nums[3:])
        if not 0.9 < np.linalg.norm(q) < 1.1:
            raise InputError(f"quaternion (qx, qy, qz, qw) has norm {np.linalg.norm(q):.4f}; "
                             "expected a unit quaternion", field=where)
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(q)
        m[:3, 3] = nums[:3]
        return m
    if len(nums) == 12:
        m = np.eye(4)
        m[:3, :] = np.asarray(nums).reshape(3, 4)
        return m
    raise InputError(f"expected 7 numbers (tx ty tz qx qy qz qw) or 12 (a 3×4 matrix "
                     f"row-major) after the frame index, got {len(nums)}", field=where)


def read_pose_lines(path: str | Path, named: bool = False
                    ) -> dict[str, list[Keyframe]]:
    """Keyframes of a poses text file by track name (``""`` for the camera file).

    ``named``: every line has a shape name after the frame index (object files).
    Raises :class:`InputError` naming the file and line.
    """
    path = Path(path)
    text = read_text(path, "poses file")
    tracks: dict[str, list[Keyframe]] = {}
    for no, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p for p in _SPLIT.split(line) if p]
        where = f"line {no}"
        name = ""
        if named:
            if len(parts) < 2:
                raise InputError("expected FRAME NAME followed by the pose", file=str(path),
                                 field=where)
            name = parts.pop(1)
        try:
            frame = int(parts[0])
            nums = [float(x) for x in parts[1:]]
        except ValueError as exc:
            raise InputError(f"expected an integer frame index and numbers ({exc})",
                             file=str(path), field=where) from exc
        if frame < 0:
            raise InputError(f"frame index must be >= 0, got {frame}", file=str(path),
                             field=where)
        if not all(math.isfinite(x) for x in nums):
            raise InputError("non-finite number", file=str(path), field=where)
        try:
            m = _pose_numbers(nums, where)
            tracks.setdefault(name, []).append(Keyframe.from_matrix(frame, m, where))
        except InputError as exc:
            raise InputError(exc.message, file=str(path), field=where) from exc
    if not tracks:
        raise InputError("no poses in the file", file=str(path))
    return tracks


def write_poses(path: str | Path, poses: list[np.ndarray], comment: str = "") -> Path:
    """Write camera poses as ``FRAME tx ty tz qx qy qz qw`` lines (full float precision)."""
    from arlight.io.images import atomic_write

    lines = ["# arlight poses: frame tx ty tz qx qy qz qw (world_from_camera, OpenCV axes, m)"]
    if comment:
        lines.append(f"# {comment}")
    for i, m in enumerate(poses):
        q = matrix_to_quat(m[:3, :3])
        lines.append(" ".join([str(i), *(repr(float(x)) for x in (*m[:3, 3], *q))]))
    with atomic_write(path, ".txt") as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Path(path)


# ------------------------------------------------------------------------------- TOML keys
def read_keyframes_toml(path: str | Path) -> tuple[list[Keyframe], dict[str, list[Keyframe]]]:
    """Camera keyframes and object keyframes (by shape name) of a keyframes TOML file."""
    from arlight.scene import schema
    from arlight.scene.camera import look_at
    from arlight.scene.load import transform_matrix
    from arlight.scene.schema import Validator

    path = Path(path)
    try:
        data = tomllib.loads(read_text(path, "keyframes file"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"cannot read the keyframes file ({exc})", file=str(path)) from exc
    v = Validator(str(path), path.parent.resolve())
    v.check_keys(data, {"camera", "objects"}, "")

    def frame_of(tab: dict, where: str) -> int:
        f = tab.get("frame")
        if not isinstance(f, int) or isinstance(f, bool) or f < 0:
            raise v.fail(f"{where}.frame", f"expected an integer >= 0, got {f!r}")
        return f

    cams = []
    items = data.get("camera", [])
    if not isinstance(items, list):
        raise v.fail("camera", "expected an array of tables [[camera]]")
    for i, tab in enumerate(items):
        where = f"camera[{i}]"
        tab = v.table(tab, where)
        v.check_keys(tab, {"frame", "look_at", "world_from_camera"}, where)
        if ("look_at" in tab) == ("world_from_camera" in tab):
            raise v.fail(where, "give exactly one of `look_at` and `world_from_camera`")
        if "look_at" in tab:
            la = v.table(tab["look_at"], f"{where}.look_at")
            v.check_keys(la, {"origin", "target", "up"}, f"{where}.look_at")
            try:
                m = look_at(v.vector(la.get("origin"), 3, f"{where}.look_at.origin"),
                            v.vector(la.get("target"), 3, f"{where}.look_at.target"),
                            v.vector(la.get("up", [0, 1, 0]), 3, f"{where}.look_at.up"))
            except ValueError as exc:
                raise v.fail(f"{where}.look_at", str(exc)) from exc
        else:
            m = np.array(v.value(tab["world_from_camera"], schema.Field("mat4"),
                                 f"{where}.world_from_camera"), np.float64)
        try:
            cams.append(Keyframe.from_matrix(frame_of(tab, where), m))
        except InputError as exc:
            raise v.fail(where, exc.message) from exc
    objects: dict[str, list[Keyframe]] = {}
    for name, items in v.table(data.get("objects", {}), "objects").items():
        if not isinstance(items, list):
            raise v.fail(f"objects.{name}", "expected an array of tables [[objects.NAME]]")
        for i, tab in enumerate(items):
            where = f"objects.{name}[{i}]"
            tab = v.table(tab, where)
            v.check_keys(tab, {"frame", "transform"}, where)
            m = transform_matrix(v, tab.get("transform"), f"{where}.transform")
            try:
                objects.setdefault(name, []).append(
                    Keyframe.from_matrix(frame_of(tab, where), m))
            except InputError as exc:
                raise v.fail(f"{where}.transform", exc.message) from exc
    return cams, objects


# ----------------------------------------------------------------------------- what to use
def camera_poses(source: str | Path, n_frames: int, axes: str = "opencv") -> list[np.ndarray]:
    """``n_frames`` camera poses (world_from_camera, OpenCV axes) from a poses text file or a
    keyframes TOML file (interpolated where sparse). ``axes="opengl"``: the file's camera
    axes are OpenGL/ARKit's (y up, z backward) and are converted."""
    path = Path(source)
    if path.suffix.lower() == ".toml":
        keys, _ = read_keyframes_toml(path)
        if not keys:
            raise InputError("no [[camera]] keyframes", file=str(path), field="camera")
    else:
        tracks = read_pose_lines(path)
        keys = tracks[""]
    try:
        poses = interpolate(keys, n_frames)
    except InputError as exc:
        raise InputError(exc.message, file=str(path), field=exc.field) from exc
    if axes == "opengl":
        poses = [p @ OPENGL_FROM_OPENCV for p in poses]
    elif axes != "opencv":
        raise InputError(f"unknown camera axes {axes!r}; expected opencv or opengl",
                         field="--pose-axes")
    return poses


def object_transforms(source: str | Path, n_frames: int,
                      shape_names: Mapping[str, object] | None = None
                      ) -> list[dict[str, np.ndarray]]:
    """Per-frame object transforms ``[{name: 4×4}, ...]`` from an object poses text file
    (``FRAME NAME ...`` lines) or the ``[[objects.NAME]]`` keyframes of a TOML file.
    ``shape_names``: the world's shapes; an unknown name is an :class:`InputError`."""
    path = Path(source)
    if path.suffix.lower() == ".toml":
        _, tracks = read_keyframes_toml(path)
    else:
        tracks = read_pose_lines(path, named=True)
    out: list[dict[str, np.ndarray]] = [{} for _ in range(n_frames)]
    for name, keys in tracks.items():
        if shape_names is not None and name not in shape_names:
            raise InputError(f"no shape named {name!r} in the scene (shapes: "
                             f"{', '.join(sorted(shape_names))})", file=str(path),
                             field=f"objects.{name}")
        try:
            poses = interpolate(keys, n_frames, where=f"objects.{name}")
        except InputError as exc:
            raise InputError(exc.message, file=str(path), field=exc.field) from exc
        for i, m in enumerate(poses):
            out[i][name] = m
    return out


__all__ = ["Keyframe", "camera_poses", "interpolate", "matrix_to_quat", "object_transforms",
           "quat_to_matrix", "read_keyframes_toml", "read_pose_lines", "slerp", "write_poses"]
