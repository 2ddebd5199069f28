"""Building a :class:`~arlight.sequence.job.SequenceJob` from a scene file, frames and poses.

Where the camera poses come from (``--poses``):

* a **poses text file** or a **keyframes TOML** file (:mod:`arlight.sequence.poses`),
  interpolated (slerp) where the frame indices are sparse;
* ``scene``: the scene file's camera pose for every frame (a fixed camera: a turntable);
* ``marker``: the camera registered on a printed ChArUco board or ArUco marker in every frame
  (:func:`arlight.insert.registration.register`, with ``--calib`` and ``--marker``); the
  frames are undistorted, the intrinsics are the calibration's. The scene's world frame is
  then the board frame, as in an ``arlight insert`` scene.

Object transforms (``--objects``) come from an object poses file or the
``[[objects.NAME]]`` keyframes of a TOML file. Everything is validated here, before the
output folder is touched.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.scene.camera import Camera
from arlight.scene.model import ARScene
from arlight.sequence.frames import FrameSource, InputFrame
from arlight.sequence.job import SequenceJob, scaled_settings
from arlight.sequence.poses import camera_poses, object_transforms

if TYPE_CHECKING:
    from arlight.insert.registration import Calibration, MarkerSpec


def fit_camera(camera: Camera, size: tuple[int, int], where: str) -> Camera:
    """The scene camera for frames of ``size`` (w, h): unchanged when equal, scaled
    (:meth:`Camera.resized`) when the aspect ratio agrees within 0.5 %, else an error."""
    w, h = size
    if (w, h) == (camera.width, camera.height):
        return camera
    if abs((w / h) / (camera.width / camera.height) - 1) > 0.005:
        raise InputError(f"frames are {w}×{h} but the scene camera is {camera.width}×"
                         f"{camera.height} (another aspect ratio)", file=where,
                         field="--frames")
    return camera.resized(w, h)


def marker_codes(frame: InputFrame, camera: Camera) -> np.ndarray:
    """The 8-bit code values the marker is detected in: the frame's own codes (16-bit ones
    shifted down), or an HDR frame's radiance through the camera's transfer function."""
    if frame.codes is not None:
        return frame.codes if frame.codes.dtype == np.uint8 else \
            (frame.codes >> 8).astype(np.uint8)
    assert frame.radiance is not None
    return camera.transfer.to_display(frame.radiance)


def marker_pose(frame: InputFrame, calib: Calibration, spec: MarkerSpec, camera: Camera,
                where: str) -> np.ndarray:
    """``world_from_camera`` (4×4, OpenCV axes, m) of one frame registered on the marker
    (:func:`arlight.insert.registration.register`, distortion included); InputError naming
    ``where`` when the marker is not found. The one per-frame tracking step of ``sequence
    --poses marker`` and ``arlight live``."""
    from arlight.insert.registration import register

    return register(marker_codes(frame, camera), calib, spec, where).world_from_camera


def calibrated_camera(camera: Camera, calib: Calibration, size: tuple[int, int]) -> Camera:
    """The scene camera with the calibration's intrinsics at ``size`` (w, h) px (OpenCV's
    integer pixel centres shifted by +0.5 to arlight's), its lens and transfer kept."""
    K = calib.K
    return replace(camera, width=size[0], height=size[1], fx=float(K[0, 0]),
                   fy=float(K[1, 1]), cx=float(K[0, 2]) + 0.5, cy=float(K[1, 2]) + 0.5)


def marker_poses(source: FrameSource, calib_path: str | Path, marker: str,
                 camera: Camera) -> tuple[Camera, list[np.ndarray], object]:
    """Camera (calibrated intrinsics, the scene camera's transfer) and per-frame poses
    registered on the marker; InputError naming the first frame where it is not found."""
    from arlight.insert.registration import load_calibration, parse_marker

    calib = load_calibration(calib_path)
    spec = parse_marker(marker)
    w, h = source.size
    calib.check_size(w, h, str(source.path))
    poses = [marker_pose(fr, calib, spec, camera, f"{source.path} frame {fr.index} "
                         f"({fr.name})") for fr in source]
    return calibrated_camera(camera, calib, (w, h)), poses, calib


def sequence_inputs(raw: dict, scene: str | Path, source: FrameSource,
                    depths: list[Path] | None = None, poses: str | Path = "scene",
                    objects: str | Path | None = None, calib: str | Path | None = None,
                    marker: str | None = None) -> tuple[Path, ...]:
    """Every file and folder a sequence reads: the scene file and the files it references
    (meshes, textures, environment maps, its frame; ``raw`` holds them as absolute paths),
    the frames (folder and files, or the video), depth images, poses, object, calibration
    and marker files. The output may not be, contain or replace any of them."""
    from arlight.scene.load import PATH_KEYS

    found: list[Path] = [Path(scene), source.path, *source.files, *(depths or [])]

    def walk(node: object, key: str = "") -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, k)
        elif isinstance(node, list):
            for v in node:
                walk(v, key)
        elif key in PATH_KEYS and isinstance(node, str):
            found.append(Path(node))

    walk(raw)
    if depths:
        found.append(Path(depths[0]).parent)
    for p in (objects, calib):
        if p is not None:
            found.append(Path(p))
    if str(poses) not in ("scene", "marker"):
        found.append(Path(poses))
    if marker is not None and marker.lower().endswith(".toml"):
        found.append(Path(marker))
    return tuple(dict.fromkeys(found))


def build_job(scene: ARScene, source: FrameSource, method: str, settings: RenderSettings,
              poses: str | Path = "scene", objects: str | Path | None = None,
              axes: str = "opencv", calib: str | Path | None = None,
              marker: str | None = None, fps: float | None = None, vary_seed: bool = False,
              layers: bool = False, threads: int | None = None, split: int = 1,
              render_scale: int = 1) -> SequenceJob:
    """A job for ``scene`` (its world and camera) over the frames of ``source``.

    Raises :class:`InputError` for an unknown method or option, a pose file whose frame count
    differs from the frames', unknown object names, or a marker missing from a frame."""
    where = str(scene.source) if scene.source else "<scene>"
    camera = fit_camera(scene.camera, source.size, where)
    n = source.count
    calibration = None
    # the cheap files first (poses, object motion), then the method (loading the methods
    # takes seconds), then the per-frame marker registration (the expensive part)
    if str(poses) == "scene":
        pose_list = [camera.world_from_camera.copy() for _ in range(n)]
    elif str(poses) != "marker":
        pose_list = camera_poses(poses, n, axes)
    names = {s.name: s for s in scene.shapes}
    names.update({s.group: s for s in scene.shapes if s.group})  # a model moves as one
    obj = [{} for _ in range(n)] if objects is None else object_transforms(objects, n, names)
    if str(poses) == "marker":
        if calib is None or marker is None:
            raise InputError("--poses marker needs --calib and --marker", field="--poses")
        from arlight.insert.registration import load_calibration, parse_marker

        parse_marker(marker)
        load_calibration(calib)
    fn = get_method(method)
    fn.spec.parse_options(settings.options)
    if split > 1 and not fn.spec.capabilities.progressive:
        raise InputError(f"--split needs a progressive method (independent estimates per "
                         f"seed, averaged); {method!r} is not", field="--split")
    if str(poses) == "marker":
        assert calib is not None and marker is not None
        camera, pose_list, calibration = marker_poses(source, calib, marker, camera)
    world = scene.world
    reason = fn.spec.unsupported_reason(world, None)
    if reason:
        raise InputError(reason, file=where, field="method")
    rate = fps if fps else (source.fps or 24.0)
    return SequenceJob(world=world, camera=camera, poses=pose_list, objects=obj,
                       method=method, settings=scaled_settings(method, settings, render_scale),
                       vary_seed=vary_seed, layers=layers,
                       fps=rate, calibration=calibration, threads=threads,
                       frames_fingerprint=source.fingerprint, split=split,
                       render_scale=render_scale)


__all__ = ["build_job", "calibrated_camera", "fit_camera", "marker_codes", "marker_pose",
           "marker_poses", "sequence_inputs"]
