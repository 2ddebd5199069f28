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
from arlight.scene.schema import MAX_LENGTH, REQUIRED, Field, Validator
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


RIG_FIELDS: dict[str, Field] = {
    "cameras": Field("table", REQUIRED, "`[[cameras]]` tables, one per fisheye camera"),
}
RIG_CAMERA_FIELDS: dict[str, Field] = {
    "name": Field("str", None, "unique name (default `cam<k>`)"),
    "position": Field("vec3", REQUIRED, "the camera's centre, world", "m",
                      min=-MAX_LENGTH, max=MAX_LENGTH),
    "look": Field("vec3", REQUIRED, "optical axis, world (not zero)",
                  min=-MAX_LENGTH, max=MAX_LENGTH),
    "up": Field("vec3", [0.0, 1.0, 0.0], "image up, world (not zero, not along look)",
                min=-MAX_LENGTH, max=MAX_LENGTH),
    "calibration": Field("path", None, "OCamCalib calib_results.txt, OpenCV .yml/.xml or "
                         "JSON, relative to the rig file"),
    "fov_deg": Field("float", None, "field of view for a `calibration` that lacks one",
                     "deg", min=0.0, max=360.0, exclusive_min=True),
    "equidistant": Field("table", None, "an ideal lens: `{ size = [w, h], fov_deg = 180 }`"),
    "image": Field("str", None, "the camera's HDR image, relative to the rig file "
                   "(`arlight light atlas`)"),
}
EQUIDISTANT_FIELDS: dict[str, Field] = {
    "size": Field("vec2", REQUIRED, "image width and height", "px",
                  min=MIN_IMAGE_SIDE, max=MAX_IMAGE_SIDE),
    "fov_deg": Field("float", 180.0, "field of view", "deg", min=0.0, max=360.0,
                     exclusive_min=True),
}
"""The fields of ``cams.toml`` (module docstring), read by the scene schema's ``Validator``."""


def _model(v: Validator, cam: dict, where: str) -> Model:
    """The lens model of one ``[[cameras]]`` table (already validated field by field)."""
    if cam["calibration"] is not None:
        model = load_camera(Path(cam["calibration"]), cam["fov_deg"])
        if not all(MIN_IMAGE_SIDE <= x <= MAX_IMAGE_SIDE for x in model.size):
            raise v.fail(f"{where}.calibration", f"the calibration's image sides must be "
                         f"{MIN_IMAGE_SIDE} to {MAX_IMAGE_SIDE} px, got {list(model.size)}")
        return model
    if cam["equidistant"] is not None:
        q = v.fields(v.table(cam["equidistant"], f"{where}.equidistant"), EQUIDISTANT_FIELDS,
                     f"{where}.equidistant")
        size = q["size"]
        if any(x != int(x) for x in size):
            raise v.fail(f"{where}.equidistant.size", f"expected two integers, got {size}")
        return FisheyeCamera.equidistant((int(size[0]), int(size[1])), q["fov_deg"])
    raise v.fail(f"{where}.calibration", "uncalibrated fisheye: give `calibration = \"file\"` "
                 "(OCamCalib / OpenCV / JSON) or `equidistant = { size = [w, h], fov_deg = "
                 "180 }`")


def load_rig(path: str | Path) -> list[RigCamera]:
    """Read ``cams.toml`` (module docstring; fields :data:`RIG_CAMERA_FIELDS`) through the
    scene schema's ``Validator``; relative paths are relative to the file.

    Raises:
        InputError: unreadable file, no cameras, an unknown field, a camera without
            calibration (neither ``calibration`` nor ``equidistant``), bad vectors, a
            calibration that fails to load; each names the file and field.
    """
    path = Path(path)
    v = Validator(str(path), path.parent)
    try:
        data = tomllib.loads(read_text(path, "camera rig file"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"cannot read the camera rig file ({exc})", file=str(path)) from exc
    entries = v.fields(data, RIG_FIELDS, "")["cameras"]
    if not isinstance(entries, list) or not entries:
        raise v.fail("cameras", "expected at least one [[cameras]] table")
    rig, names = [], set()
    for k, e in enumerate(entries):
        where = f"cameras[{k}]"
        cam = v.fields(v.table(e, where), RIG_CAMERA_FIELDS, where)
        name = cam["name"] or f"cam{k}"
        if name in names:
            raise v.fail(f"{where}.name", f"duplicate camera name {name!r}")
        names.add(name)
        for key in ("look", "up"):
            if not any(cam[key]):
                raise v.fail(f"{where}.{key}", "a direction must not be zero")
        try:
            rot = look_rotation(cam["look"], cam["up"])
        except ValueError as exc:
            raise v.fail(f"{where}.up", str(exc)) from exc
        model = _model(v, cam, where)
        model.world_from_camera = rot
        image = (path.parent / cam["image"]).resolve() if cam["image"] else None
        rig.append(RigCamera(name, model, np.asarray(cam["position"], np.float64), image))
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
