"""A sequence job: one world, one method, many views — and the rendering of one frame.

:class:`SequenceJob` holds everything a frame needs except the frame's pixels: the world,
the base camera (intrinsics, lens, transfer), the per-frame camera poses and object
transforms, the method and its settings. It is plain picklable data, so a Ray worker on
another machine receives it once (``ray.put``) and renders any frame of it.

:func:`render_frame` is the only place a frame is rendered, in the sequential loop and in
Ray workers alike: the method is prepared **once per process and job**
(``method.prepare(world)``, kept in a module cache) and every frame is
``method.render(state, view)`` — interactive methods keep their scene-level state across
frames, and object motion goes through the method's ``pose()``. Every frame uses the same
seed (Kán's fixed per-frame random sequence, thesis §4.4: a static scene renders bitwise
identically frame after frame, so path-traced sequences do not flicker from noise alone);
``vary_seed`` gives each frame its own seed instead (for comparison).

A high-spp frame of a *progressive* method (independent estimates for different seeds) can
be split into ``split`` parts — separate tasks on Ray — each with ``spp / split`` samples
and seed :func:`arlight.progressive.frame_seed` ``(seed, part)``; :func:`merge_parts`
averages their composites weighted by samples (Kán Eq. 4.12 accumulates the same way), in
part order, so the merged frame does not depend on which part finished first.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from arlight.content_hash import content_hash
from arlight.methods import RenderSettings
from arlight.scene.camera import Camera
from arlight.scene.model import FrameView, World
from arlight.sequence.frames import InputFrame

SEED_STRIDE = 0x9E3779B1
"""Frame ``i`` of a ``vary_seed`` job renders with seed ``seed + i·stride`` (mod 2³²)."""


@dataclass
class SequenceJob:
    """What every frame of a sequence shares.

    Attributes:
        world: the static world (proxy, virtual objects in rest pose, lights).
        camera: the camera of every frame before its pose (intrinsics for the frames'
            size, lens, transfer function).
        poses: ``world_from_camera`` (4×4, OpenCV axes) of each frame.
        objects: per frame, shape name → 4×4 world-space transform (may be empty dicts).
        method: registered method name.
        settings: render settings (``progress`` is ignored).
        vary_seed: give frame ``i`` seed ``seed + i·SEED_STRIDE`` instead of the same seed.
        layers: also return the float layers (mixed, delta, mask, composite) of each frame.
        fps: frames per second of the output video (and the views' timestamps).
        calibration: a :class:`arlight.insert.registration.Calibration` whose distortion is
            removed from every frame (marker-tracked sequences), or None.
        threads: Dr.Jit threads per process (None: Dr.Jit's default, all cores).
        frames_fingerprint: identifies the input frames (for resuming).
        test_hook: folder of the fault-injection test (see :func:`_test_hook`), or None.
        split: parts each frame is rendered in (progressive methods only; 1: whole frames).
        render_scale: render each frame at ``1/render_scale`` of its size (the view's frame
            and depth box-filtered, :meth:`FrameView.resized`) and composite the bilinearly
            upsampled layers over the full-size frame (:meth:`Layers.upsampled`), as the
            studio does while the pointer drags; 1: full size. Must divide the frame size.
            The jobs' builders give such a job :func:`scaled_settings`.
    """

    world: World
    camera: Camera
    poses: list[np.ndarray]
    objects: list[dict[str, np.ndarray]]
    method: str
    settings: RenderSettings
    vary_seed: bool = False
    layers: bool = False
    fps: float = 24.0
    calibration: Any = None
    threads: int | None = None
    frames_fingerprint: str = ""
    test_hook: str | None = None
    split: int = 1
    render_scale: int = 1
    parts: dict[str, str] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if len(self.objects) != len(self.poses):
            raise ValueError("objects and poses must have one entry per frame")
        if not 1 <= self.split <= self.settings.spp:
            from arlight.errors import InputError

            raise InputError(f"must be between 1 and --spp ({self.settings.spp}), got "
                             f"{self.split}", field="--split")
        k, cam = self.render_scale, self.camera
        if k < 1 or cam.width % k or cam.height % k:
            from arlight.errors import InputError

            raise InputError(f"must be a whole number >= 1 dividing the frame size "
                             f"{cam.width}×{cam.height}, got {k}", field="--render-scale")
        self.parts = self._part_hashes()

    @property
    def count(self) -> int:
        return len(self.poses)

    def _part_hashes(self) -> dict[str, str]:
        """A hash per input of the job; equal hashes ⇒ equal frames (resume check)."""

        def h(*items: Any) -> str:  # canonical, type-tagged (arlight.content_hash)
            return content_hash(*items, length=16)

        cam = self.camera
        s = self.settings
        calib = self.calibration
        return {
            "scene": h(self.world.raw),
            "camera": h([cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                         cam.aperture_radius, cam.focus_distance, cam.aperture_shape,
                         repr(cam.transfer)],
                        *([] if calib is None else [calib.K, calib.dist])),
            "poses": h(self.poses),
            "objects": h(self.objects),  # per frame: which frame a motion belongs to counts
            "method": h(self.method, s.options),
            "settings": h(s.spp, s.max_depth, s.rr_depth, s.seed, s.spp_per_pass,
                          self.vary_seed, *([self.split] if self.split > 1 else []),
                          *([("render_scale", self.render_scale)]
                            if self.render_scale > 1 else [])),
            "frames": self.frames_fingerprint,
            "layers": h(self.layers),
        }

    @property
    def key(self) -> str:
        """The job's identity (hash of :attr:`parts`)."""
        return content_hash(self.parts, length=24)

    def frame_settings(self, index: int, part: int = 0) -> RenderSettings:
        """Settings of frame ``index`` (part ``part`` of :attr:`split`)."""
        seed = self.settings.seed
        if self.vary_seed:
            seed = (seed + index * SEED_STRIDE) & 0xFFFFFFFF
        if self.split == 1:
            return replace(self.settings, progress=False, seed=seed)
        from arlight.progressive import frame_seed

        return replace(self.settings, progress=False, seed=frame_seed(seed, part),
                       spp=self.part_spp(part))

    def part_spp(self, part: int) -> int:
        """Samples per pixel of part ``part``: ``spp`` split as evenly as possible."""
        q, r = divmod(self.settings.spp, self.split)
        return q + (1 if part < r else 0)

    def view(self, frame: InputFrame, depth: np.ndarray | None = None,
             pose: np.ndarray | None = None,
             objects: dict[str, np.ndarray] | None = None) -> FrameView:
        """The view of ``frame``: its pose, object transforms, background (linear radiance,
        undistorted with :attr:`calibration`), optional depth and timestamp ``i / fps``.
        ``pose`` / ``objects``: this frame's camera pose and object transforms when they are
        not in :attr:`poses` / :attr:`objects` (``arlight live`` tracks them per frame)."""
        i = frame.index
        pose = self.poses[i] if pose is None else pose
        objects = self.objects[i] if objects is None else objects
        cam = replace(self.camera, world_from_camera=np.asarray(pose, np.float64))
        codes = frame.codes
        if codes is not None:
            if self.calibration is not None:
                from arlight.insert.registration import undistort

                codes = undistort(codes, self.calibration)
            radiance = cam.transfer.to_radiance(codes).astype(np.float32)
        else:
            assert frame.radiance is not None
            radiance = frame.radiance
            if self.calibration is not None:
                from arlight.insert.registration import undistort

                radiance = undistort(radiance, self.calibration)
        return FrameView(camera=cam, frame=np.asarray(radiance, np.float32), frame_codes=codes,
                         depth=depth, object_transforms=dict(objects),
                         timestamp=i / self.fps if self.fps > 0 else None)


@dataclass
class FrameResult:
    """What rendering one frame returns (small: it travels back from Ray workers).

    Attributes:
        index: frame index.
        display: the composite as display code values ``(H, W, 3)`` (uint8, or uint16 when
            the input frame was 16-bit), through the camera's transfer function.
        layers: float32 layers (``composite``, ``mixed``, ``delta``, ``mask``) when the job
            asks for them, else empty.
        stats: the method's stats (``seconds``, ``time_<stage>``, counters) plus
            ``prepare_seconds`` (0 when this process had the method prepared already),
            ``task_seconds`` (preparation, view, render and display conversion) and
            ``pid``/``host`` of the process that rendered it.
    """

    index: int
    display: np.ndarray
    layers: dict[str, np.ndarray]
    stats: dict[str, Any]
    part: int = 0


_PREPARED: dict[str, tuple[Any, Any]] = {}
"""Job key → (method, prepared state) of this process (one job at a time)."""


def configure_threads(threads: int | None) -> None:
    """Limit Dr.Jit's worker threads in this process (Ray workers share a machine)."""
    if threads:
        import drjit as dr

        from arlight.jit import ensure_variant

        ensure_variant()
        if dr.thread_count() != threads:
            dr.set_thread_count(int(threads))


def prepared(job: SequenceJob) -> tuple[Any, Any, float]:
    """(method, state, seconds spent preparing now) — prepared once per process and job."""
    from arlight.methods import get_method

    hit = _PREPARED.get(job.key)
    if hit is not None:
        return hit[0], hit[1], 0.0
    _PREPARED.clear()  # one job per process: release the previous job's state
    configure_threads(job.threads)
    t0 = time.perf_counter()
    method = get_method(job.method)
    state = method.prepare(job.world, job.frame_settings(0))
    _PREPARED[job.key] = (method, state)
    return method, state, time.perf_counter() - t0


def install_prepared(job: SequenceJob, method: Any, state: Any) -> None:
    """Make ``(method, state)`` this process's preparation of ``job``: a state prepared
    elsewhere or changed since (``arlight live`` installs the light server's newest light
    into a ``nearfield`` state this way before a frame); :func:`render_frame` then uses it."""
    _PREPARED.clear()
    _PREPARED[job.key] = (method, state)


def _test_hook(job: SequenceJob, index: int) -> None:
    """Fault-injection for tests: with ``job.test_hook = DIR`` and a file ``DIR/frame``
    holding a frame index, the first attempt at that frame records its process id in
    ``DIR/pid`` and sleeps (the test kills the process; Ray retries the task, and the
    retry, seeing ``DIR/killed``, goes on). ``ARLIGHT_TEST_FRAME_DELAY`` (seconds) slows
    every frame down (interruption tests)."""
    delay = float(os.environ.get("ARLIGHT_TEST_FRAME_DELAY", "0") or 0)
    if delay:
        time.sleep(delay)
    if not job.test_hook:
        return
    from pathlib import Path

    d = Path(job.test_hook)
    try:
        target = int((d / "frame").read_text())
    except (OSError, ValueError):
        return
    with open(d / "attempts", "a") as fh:
        fh.write(f"{index} {os.getpid()}\n")
    if index == target and not (d / "killed").exists():
        (d / "pid").write_text(str(os.getpid()))
        time.sleep(120)


def scaled_settings(method: str, settings: RenderSettings, render_scale: int
                    ) -> RenderSettings:
    """``settings`` for frames rendered at 1/``render_scale`` of their size: the method's
    own reduced options for that size (:meth:`MethodSpec.drag`, what the studio renders
    drag frames with: light maps, VPLs, volumes shrunk with the image) over the given ones;
    unchanged at 1 or for methods without such options."""
    from arlight.methods import get_method

    spec = get_method(method).spec
    extra = spec.drag(spec.parse_options(settings.options), render_scale)
    return replace(settings, options={**settings.options, **extra}) if extra else settings


def render_frame(job: SequenceJob, frame: InputFrame, depth: np.ndarray | None = None,
                 part: int = 0, pose: np.ndarray | None = None,
                 objects: dict[str, np.ndarray] | None = None) -> FrameResult:
    """Render frame ``frame.index`` of ``job`` (the method prepared once per process); with
    ``job.split > 1`` only part ``part`` of it (its layers always hold the composite).
    ``pose`` / ``objects``: see :meth:`SequenceJob.view` — ``arlight live`` renders every
    frame through this function with the pose it tracked."""
    import socket

    _test_hook(job, frame.index)
    t0 = time.perf_counter()
    method, state, prep = prepared(job)
    view = job.view(frame, depth, pose, objects)
    k = job.render_scale
    small = view if k == 1 else view.resized(view.camera.width // k, view.camera.height // k)
    layers = method.render(state, small, job.frame_settings(frame.index, part))
    if k > 1:
        layers = layers.upsampled(view.frame)
    cam = view.camera
    # the bit depth of the input frame (as arlight.layer_files.display_dtype)
    dtype = np.uint16 if view.frame_codes is not None and \
        view.frame_codes.dtype == np.uint16 else np.uint8
    display = cam.transfer.to_display(layers.composite, dtype)
    out_layers = {}
    if job.layers:
        out_layers = {"composite": layers.composite, "mixed": layers.mixed,
                      "delta": layers.delta, "mask": layers.mask}
    elif job.split > 1:
        out_layers = {"composite": layers.composite}
    stats = {k: v for k, v in layers.stats.items() if isinstance(v, int | float)}
    stats.update(prepare_seconds=prep, pid=os.getpid(), host=socket.gethostname(),
                 task_seconds=time.perf_counter() - t0, display_bits=display.dtype.itemsize * 8)
    return FrameResult(frame.index, display, out_layers, stats, part)


def merge_parts(job: SequenceJob, results: list[FrameResult]) -> FrameResult:
    """One frame from its ``job.split`` parts: every layer averaged with the parts' samples
    per pixel as weights (float64, in part order), the display codes from the merged
    composite; times and counters summed, ``prepare_seconds`` summed."""
    results = sorted(results, key=lambda r: r.part)
    if [r.part for r in results] != list(range(job.split)):
        raise ValueError(f"frame {results[0].index}: parts {[r.part for r in results]}")
    if len(results) == 1:
        return results[0]
    w = np.array([job.part_spp(r.part) for r in results], np.float64)
    w /= w.sum()
    layers = {}
    for name in results[0].layers:
        acc = np.zeros(results[0].layers[name].shape, np.float64)
        for wk, r in zip(w, results, strict=True):
            acc += wk * r.layers[name]
        layers[name] = acc.astype(np.float32)
    dtype = np.uint16 if results[0].stats.get("display_bits") == 16 else np.uint8
    display = job.camera.transfer.to_display(layers["composite"], dtype)
    stats: dict[str, Any] = dict(results[0].stats)
    for r in results[1:]:
        for k, v in r.stats.items():
            if isinstance(v, int | float) and k not in ("pid", "display_bits") and \
                    isinstance(stats.get(k), int | float):
                stats[k] += v
    stats["parts"] = job.split
    if not job.layers:
        layers = {}
    return FrameResult(results[0].index, display, layers, stats)


__all__ = ["FrameResult", "SequenceJob", "configure_threads", "install_prepared",
           "merge_parts", "prepared", "render_frame"]
