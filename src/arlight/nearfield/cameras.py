"""The rig of HDR fisheye cameras that observe the room (Rohmer §3.1).

A :class:`RigCamera` is a calibrated fisheye model (:class:`~arlight.sphere.fisheye.
FisheyeCamera` — equidistant or Kannala-Brandt — or OCamCalib's
:class:`~arlight.sphere.fisheye.OcamCamera`), whose ``world_from_camera`` rotation is its
orientation, plus its centre in the world. ``cams.toml``::

    [[cameras]]
    name = "front"
    position = [0.0, 1.0, 0.9]        # m, world
    look = [0.0, 0.0, -1.0]           # optical axis, world
    up = [0.0, 1.0, 0.0]              # image up, world
    calibration = "front_calib.txt"   # OCamCalib calib_results.txt, OpenCV .yml/.xml, JSON
    # or, for an ideal lens:  equidistant = { size = [256, 256], fov_deg = 180.0 }
    image = "front.exr"               # optional: the HDR image (``arlight light atlas``)

:func:`auto_rig` places cameras for a world that has no rig (synthetic capture): one 180°
equidistant camera per axis direction, a quarter of the way from the centre of the real
geometry's bounding box towards each face of the box, looking outwards (the centre is lifted
to at least a quarter of the box diagonal above its floor, so a flat proxy is seen from
above). Cameras that see nothing of the proxy are dropped by :func:`seeing_cameras`.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arlight.errors import InputError, read_text
from arlight.scene.schema import MAX_LENGTH
from arlight.sphere.fisheye import FisheyeCamera, OcamCamera, load_camera

Model = FisheyeCamera | OcamCamera

MIN_IMAGE_SIDE = 8
MAX_IMAGE_SIDE = 16384
"""Sides (px) a rig camera's image may have (memory is bounded further by ``light atlas``'s
estimate)."""


@dataclass
class RigCamera:
    """One fisheye camera of the rig.

    Attributes:
        name: label used in errors and stats.
        model: intrinsics and orientation (``world_from_camera``: OpenCV axes, z = optical
            axis).
        position: (3,) centre of projection, m (world).
        image: path of its HDR image, if the rig file names one.
    """

    name: str
    model: Model
    position: np.ndarray
    image: Path | None = None

    @property
    def axis(self) -> np.ndarray:
        """Unit main direction d_i in the world (Rohmer's α is measured from it)."""
        return self.model.world_from_camera[:, 2].copy()

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.model.size


def look_rotation(look, up) -> np.ndarray:
    """``world_from_camera`` (OpenCV axes: x right, y down, z forward) of a camera looking
    along ``look`` with image-up ``up`` (both world; need not be unit or orthogonal)."""
    z = np.asarray(look, np.float64)
    z = z / np.linalg.norm(z)
    u = np.asarray(up, np.float64)
    y = -(u - (u @ z) * z)
    ny = np.linalg.norm(y)
    if ny < 1e-9:
        raise ValueError("up is parallel to look")
    y /= ny
    return np.stack([np.cross(y, z), y, z], axis=1)


def _vec3(entry: dict, key: str, where: str, file: str) -> np.ndarray:
    v = entry.get(key)
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.abs(a).max() > MAX_LENGTH:
        raise InputError(f"expected 3 finite numbers of magnitude <= {MAX_LENGTH:g}, got "
                         f"{v!r}", file=file, field=f"{where}.{key}")
    if key != "position" and not np.any(a):
        raise InputError("a direction must not be zero", file=file, field=f"{where}.{key}")
    return a


def load_rig(path: str | Path) -> list[RigCamera]:
    """Read ``cams.toml`` (module docstring); relative paths are relative to the file.

    Raises:
        InputError: unreadable file, no cameras, a camera without calibration (neither
            ``calibration`` nor ``equidistant``), bad vectors, a calibration that fails to
            load; each names the file and field.
    """
    path = Path(path)
    file = str(path)
    try:
        data = tomllib.loads(read_text(path, "camera rig file"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"cannot read the camera rig file ({exc})", file=file) from exc
    entries = data.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise InputError("expected at least one [[cameras]] table", file=file,
                         field="cameras")
    rig, names = [], set()
    for k, e in enumerate(entries):
        where = f"cameras[{k}]"
        if not isinstance(e, dict):
            raise InputError("expected a table", file=file, field=where)
        name = str(e.get("name", f"cam{k}"))
        if name in names:
            raise InputError(f"duplicate camera name {name!r}", file=file,
                             field=f"{where}.name")
        names.add(name)
        pos = _vec3(e, "position", where, file)
        look = _vec3(e, "look", where, file)
        up = _vec3(e, "up", where, file) if "up" in e else np.array([0.0, 1.0, 0.0])
        try:
            rot = look_rotation(look, up)
        except ValueError as exc:
            raise InputError(str(exc), file=file, field=f"{where}.up") from exc
        model: Model
        if "calibration" in e:
            calib = (path.parent / str(e["calibration"])).resolve()
            fov_deg = e.get("fov_deg")
            if fov_deg is not None and (isinstance(fov_deg, bool)
                                        or not isinstance(fov_deg, int | float)
                                        or not 0 < fov_deg <= 360):
                raise InputError(f"expected a field of view in (0, 360] degrees, got "
                                 f"{fov_deg!r}", file=file, field=f"{where}.fov_deg")
            model = load_camera(calib, fov_deg)
            if not all(MIN_IMAGE_SIDE <= x <= MAX_IMAGE_SIDE for x in model.size):
                raise InputError(f"the calibration's image sides must be {MIN_IMAGE_SIDE} to "
                                 f"{MAX_IMAGE_SIDE} px, got {list(model.size)}", file=file,
                                 field=f"{where}.calibration")
        elif "equidistant" in e:
            q = e["equidistant"]
            try:
                if not isinstance(q, dict) or len(q["size"]) != 2 or not all(
                        isinstance(x, int) and not isinstance(x, bool) for x in q["size"]):
                    raise ValueError(f"size must be two integers, got {q.get('size')!r}"
                                     if isinstance(q, dict) else "not a table")
                size = (int(q["size"][0]), int(q["size"][1]))
                fov = float(q.get("fov_deg", 180.0))
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                raise InputError(f"expected {{ size = [w, h], fov_deg = … }} ({exc})",
                                 file=file, field=f"{where}.equidistant") from exc
            if not all(MIN_IMAGE_SIDE <= x <= MAX_IMAGE_SIDE for x in size):
                raise InputError(f"image sides must be {MIN_IMAGE_SIDE} to {MAX_IMAGE_SIDE} "
                                 f"px, got {list(size)}", file=file,
                                 field=f"{where}.equidistant.size")
            if not (np.isfinite(fov) and 0 < fov <= 360):
                raise InputError(f"expected a field of view in (0, 360] degrees, got {fov}",
                                 file=file, field=f"{where}.equidistant.fov_deg")
            model = FisheyeCamera.equidistant(size, fov)
        else:
            raise InputError("uncalibrated fisheye: give `calibration = \"file\"` "
                             "(OCamCalib / OpenCV / JSON) or `equidistant = { size = [w, h],"
                             " fov_deg = 180 }`", file=file, field=f"{where}.calibration")
        model.world_from_camera = rot
        image = (path.parent / str(e["image"])).resolve() if "image" in e else None
        rig.append(RigCamera(name, model, pos, image))
    return rig


def auto_rig(bounds_min: np.ndarray, bounds_max: np.ndarray, size: int = 256,
             fov_deg: float = 180.0) -> list[RigCamera]:
    """Six outward-looking equidistant fisheyes inside a bounding box (module docstring)."""
    lo, hi = np.asarray(bounds_min, np.float64), np.asarray(bounds_max, np.float64)
    c, half = (lo + hi) / 2, (hi - lo) / 2
    c[1] = max(c[1], lo[1] + 0.25 * float(np.linalg.norm(hi - lo)))  # above a flat floor
    rig = []
    for axis, label in enumerate("xyz"):
        for sign in (1.0, -1.0):
            look = np.zeros(3)
            look[axis] = sign
            up = np.array([0.0, 0.0, 1.0]) if axis == 1 else np.array([0.0, 1.0, 0.0])
            pos = c + look * half * 0.25
            model = FisheyeCamera.equidistant((size, size), fov_deg,
                                              world_from_camera=look_rotation(look, up))
            rig.append(RigCamera(f"{'+' if sign > 0 else '-'}{label}", model, pos))
    return rig


def default_rig(world, size: int = 64) -> list[RigCamera]:
    """:func:`auto_rig` inside the bounding box of ``world``'s real geometry (its proxy
    mesh)."""
    from arlight.nearfield.atlas import proxy_mesh

    v = proxy_mesh(world).vertices
    return auto_rig(v.min(0), v.max(0), size=size)


def seeing_cameras(rig: list[RigCamera], geometry, proxy) -> list[RigCamera]:
    """The cameras of ``rig`` that see at least one texel of the atlas ``geometry``
    (``proxy``: the Mitsuba scene of the proxy mesh).

    Raises:
        InputError: none does.
    """
    from arlight.nearfield.projection import camera_weights

    keep = [c for c in rig if np.any(camera_weights(geometry, c, proxy)[0] > 0)]
    if not keep:
        raise InputError("no camera of the rig sees the proxy", field="cameras")
    return keep


__all__ = ["Model", "RigCamera", "auto_rig", "default_rig", "load_rig", "look_rotation",
           "seeing_cameras"]
