"""What a live run renders: the job (world, calibrated camera, method) and its tracker.

:func:`live_job` builds the :class:`~arlight.sequence.job.SequenceJob` that ``arlight
sequence SCENE --poses marker`` would build for frames of the same size — the scene camera
fitted to the frames (:func:`arlight.sequence.build.fit_camera`), the calibration's
intrinsics (:func:`arlight.sequence.build.calibrated_camera`) and its distortion removed
from every frame — but without per-frame poses: the live loop tracks them as frames come.
The world's lights can be replaced by a :class:`~arlight.light.estimate.LightEstimate`
file (its explicit lights as directional lights plus its SH remainder,
:meth:`LightEstimate.to_scene_lights`).
"""

from __future__ import annotations

from pathlib import Path

from arlight.errors import InputError
from arlight.methods import RenderSettings, get_method
from arlight.scene.model import ARScene
from arlight.sequence.job import SequenceJob, scaled_settings


def with_light_estimate(scene: ARScene, light: str | Path) -> ARScene:
    """``scene`` with its lights replaced by the estimate in ``light`` (a light JSON of
    ``arlight light estimate``); InputError naming the file for a bad one."""
    from arlight.light.estimate import LightEstimate
    from arlight.scene.load import parse_scene

    est = LightEstimate.load(light)
    data = {**scene.world.raw, "lights": est.to_scene_lights("directional")}
    cam = scene.camera
    data["camera"] = {"resolution": [cam.width, cam.height],
                      "intrinsics": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy},
                      "world_from_camera": cam.world_from_camera.tolist(),
                      **{k: v for k, v in scene.world.raw.get("camera", {}).items()
                         if k in ("transfer", "exposure", "gamma")}}
    where = str(scene.source) if scene.source else "<scene>"
    return parse_scene(data, base_dir=Path(where).parent, file=where)


def live_job(scene: ARScene, size: tuple[int, int], method: str, settings: RenderSettings,
             calib: str | Path, marker: str, fps: float, threads: int | None = None,
             source_name: str = "<frames>", has_depth: bool = False, render_scale: int = 1
             ) -> tuple[SequenceJob, object, object]:
    """(job, calibration, marker spec) for frames of ``size`` (w, h) px; InputError for an
    unknown method or option, a method that cannot render the world, one that needs depth
    when ``has_depth`` is False, a calibration of another size or an unknown marker
    dictionary."""
    from arlight.insert.registration import load_calibration, parse_marker
    from arlight.sequence.build import calibrated_camera, fit_camera

    where = str(scene.source) if scene.source else "<scene>"
    spec = parse_marker(marker)
    calibration = load_calibration(calib)
    calibration.check_size(size[0], size[1], source_name)
    fn = get_method(method)
    fn.spec.parse_options(settings.options)
    reason = fn.spec.unsupported_reason(scene.world, None)
    if reason:
        raise InputError(reason, file=where, field="--method")
    if fn.spec.capabilities.needs_depth and not has_depth:
        raise InputError(f"{method} needs a depth image per frame", field="--depth")
    camera = calibrated_camera(fit_camera(scene.camera, size, where), calibration, size)
    job = SequenceJob(world=scene.world, camera=camera, poses=[], objects=[], method=method,
                      settings=scaled_settings(method, settings, render_scale), fps=fps,
                      calibration=calibration, threads=threads,
                      frames_fingerprint=f"live:{source_name}", render_scale=render_scale)
    return job, calibration, spec


__all__ = ["live_job", "with_light_estimate"]
