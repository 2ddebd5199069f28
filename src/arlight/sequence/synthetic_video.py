"""A synthetic video with ground truth: a camera orbit and a moving virtual object.

:func:`synthetic_sequence` takes a suite scene (``bunny-box`` by default: its detailed
*world* and coarser *proxy*, :mod:`arlight.evaluate.suite`), moves the camera along an arc
about the scene's look-at target (:func:`orbit_poses`) and the virtual object along a path
(:func:`object_path`: a slide and a turn about its own vertical axis), and renders every
frame with :func:`arlight.synthetic.synthesize` — the camera frame ``I_c`` (world without
virtual objects), the ground truth (world with them) and the coverage mask, with Mitsuba's
own path tracer, cached on disk by content hash, every frame with the same seeds. A sensor's
depth of the real world (:func:`arlight.synthetic.sensor_depth`) is made for the
methods that need depth.

A method then renders the *proxy* with these frames, poses and object transforms
(:func:`sequence_job`), and :func:`sequence_metrics` compares its composites with the ground
truth: PSNR per frame (display, Franke Eq. 5.28) and the temporal flicker
(:func:`arlight.evaluate.metrics.temporal_flicker`: mean |e(t+1) − e(t)| of the error
e = composite − GT).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from arlight.methods import RenderSettings
from arlight.scene.camera import look_at
from arlight.scene.model import ARScene, FrameView
from arlight.sequence.frames import InputFrame
from arlight.sequence.job import SequenceJob


def orbit_poses(camera_pose: np.ndarray, target, n: int, arc_deg: float,
                up=(0.0, 1.0, 0.0)) -> list[np.ndarray]:
    """``n`` look-at poses on a horizontal arc of ``arc_deg`` degrees centred on the
    camera's position, rotating it about the vertical axis through ``target`` (m)."""
    t = np.asarray(target, np.float64)
    o = camera_pose[:3, 3] - t
    out = []
    for i in range(n):
        a = math.radians(arc_deg) * ((i / (n - 1) if n > 1 else 0.5) - 0.5)
        c, s = math.cos(a), math.sin(a)
        p = np.array([c * o[0] + s * o[2], o[1], -s * o[0] + c * o[2]]) + t
        out.append(look_at(p, t, up))
    return out


def object_path(rest: np.ndarray, n: int, slide, turn_deg: float) -> list[np.ndarray]:
    """World-space motions of an object whose rest ``to_world`` is ``rest``: frame ``i`` of
    ``n`` slides it by ``u·slide`` (m) and turns it by ``u·turn_deg`` about the vertical
    axis through its origin, ``u = i/(n−1)``."""
    p = rest[:3, 3]
    out = []
    for i in range(n):
        u = i / (n - 1) if n > 1 else 0.0
        a = math.radians(turn_deg * u)
        r = np.eye(4)
        r[[0, 0, 2, 2], [0, 2, 0, 2]] = [math.cos(a), math.sin(a), -math.sin(a), math.cos(a)]
        to, back, move = np.eye(4), np.eye(4), np.eye(4)
        to[:3, 3], back[:3, 3] = -p, p
        move[:3, 3] = u * np.asarray(slide, np.float64)
        out.append(move @ back @ r @ to)
    return out


@dataclass
class SyntheticSequence:
    """A synthetic video: per-frame inputs and ground truth (radiance ``(H, W, 3)``)."""

    name: str
    world: ARScene
    proxy: ARScene
    poses: list[np.ndarray]
    objects: list[dict[str, np.ndarray]]
    frames: list[np.ndarray] = field(default_factory=list)
    ground_truth: list[np.ndarray] = field(default_factory=list)
    ground_truth_stderr: list[np.ndarray] = field(default_factory=list)
    masks: list[np.ndarray] = field(default_factory=list)
    depths: list[np.ndarray] = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.poses)

    def world_view(self, i: int) -> ARScene:
        """The world scene of frame ``i`` (posed camera and objects)."""
        cam = replace(self.world.camera, world_from_camera=self.poses[i])
        return ARScene.compose(self.world.world, FrameView(camera=cam,
                                                           object_transforms=self.objects[i]))

    def input_frames(self) -> list[InputFrame]:
        return [InputFrame(i, f"{self.name}#{i}", radiance=f)
                for i, f in enumerate(self.frames)]


def synthetic_sequence(scene: str = "bunny-box", n_frames: int = 32, width: int = 96,
                       spp: int = 32, batches: int = 8, arc_deg: float = 30.0,
                       obj: str = "bunny", slide=(0.06, 0.0, 0.0), turn_deg: float = 60.0,
                       depth: bool = True, cache_dir: str | Path | None = None,
                       progress=None) -> SyntheticSequence:
    """Render (or load from the cache) the synthetic sequence of a suite scene.

    Args:
        scene: suite scene name; its camera is scaled to ``width`` px (same aspect).
        n_frames: frames of the orbit.
        spp, batches: samples per pixel and batches of each frame's ground truth.
        arc_deg: the camera's arc about the scene's look-at target (degrees).
        obj: the virtual shape that moves; ``slide`` (m) and ``turn_deg`` its motion.
        depth: also make each frame's sensor depth (for methods that need it).
        progress: called with ``(i, n)`` after each frame.
    """
    from arlight.evaluate.suite import get_scene
    from arlight.synthetic import synthesize

    s = get_scene(scene, quick=True)
    w0, h0 = s.world.resolution
    height = max(1, round(width * h0 / w0))
    world = replace(s.world, camera=s.world.camera.resized(width, height))
    proxy = replace(s.proxy, camera=s.proxy.camera.resized(width, height), depth=None,
                    frame=None, frame_codes=None)
    la = world.raw.get("camera", {}).get("look_at", {})
    target = la.get("target", [0.0, 0.0, 0.0])
    poses = orbit_poses(world.camera.world_from_camera, target, n_frames, arc_deg)
    rest = {x.name: x for x in world.shapes}
    if obj not in rest:
        raise ValueError(f"scene {scene!r} has no shape {obj!r}")
    objects = [{obj: m} for m in object_path(rest[obj].to_world, n_frames, slide, turn_deg)]
    seq = SyntheticSequence(scene, world, proxy, poses, objects)
    for i in range(n_frames):
        wv = seq.world_view(i)
        photo = synthesize(wv, spp=spp, seed=1, batches=batches, cache_dir=cache_dir)
        seq.frames.append(photo.frame)
        seq.ground_truth.append(photo.ground_truth)
        seq.ground_truth_stderr.append(photo.ground_truth_stderr)
        seq.masks.append(photo.mask)
        if depth:
            from arlight.synthetic import sensor_depth

            seq.depths.append(np.nan_to_num(sensor_depth(wv), nan=0.0))
        if progress:
            progress(i + 1, n_frames)
    return seq


def sequence_job(seq: SyntheticSequence, method: str, settings: RenderSettings,
                 vary_seed: bool = False, threads: int | None = None) -> SequenceJob:
    """The job of rendering ``seq`` with ``method`` on the proxy."""
    return SequenceJob(world=seq.proxy.world, camera=seq.proxy.camera, poses=seq.poses,
                       objects=seq.objects, method=method, settings=settings,
                       vary_seed=vary_seed, threads=threads, frames_fingerprint=seq.name)


def ground_truth_flicker_floor(seq: SyntheticSequence) -> float:
    """The flicker (radiance) the ground truth's Monte Carlo noise would contribute if it
    were independent from frame to frame: ``mean_t mean_pixels sqrt(2/π)·sqrt(se_t² +
    se_{t+1}²)``, the mean of |N(0, σ²)| for the difference of two independent errors with
    the per-pixel standard errors ``se``. The sequence renders every frame with the same
    seeds, so its noise is correlated between frames and contributes less: an upper bound."""
    se = np.asarray(seq.ground_truth_stderr, np.float64)
    return float(np.mean(math.sqrt(2 / math.pi) * np.sqrt(se[1:] ** 2 + se[:-1] ** 2)))


def sequence_metrics(composites: list[np.ndarray], seq: SyntheticSequence) -> dict[str, float]:
    """PSNR (display, dB: mean, min over frames), RMSE (radiance) and flicker (radiance and
    display) of a method's composites against the ground truth."""
    from arlight.evaluate import metrics as M

    tr = seq.world.camera.transfer
    psnrs = [M.psnr(M.display(c, tr), M.display(g, tr), peak=1.0)
             for c, g in zip(composites, seq.ground_truth, strict=True)]
    disp = [M.display(c, tr) for c in composites]
    disp_gt = [M.display(g, tr) for g in seq.ground_truth]
    return {"psnr": float(np.mean(psnrs)), "psnr_min": float(np.min(psnrs)),
            "rmse": float(np.mean([M.rmse(c, g) for c, g in
                                   zip(composites, seq.ground_truth, strict=True)])),
            "flicker": M.temporal_flicker(composites, seq.ground_truth),
            "flicker_display": M.temporal_flicker(disp, disp_gt)}


__all__ = ["SyntheticSequence", "ground_truth_flicker_floor", "object_path", "orbit_poses",
           "sequence_job", "sequence_metrics", "synthetic_sequence"]
