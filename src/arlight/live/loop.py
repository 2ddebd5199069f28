"""The live AR loop: capture → track → render → show, one frame at a time, staying live.

Per frame (:meth:`LiveCompositor.__call__`):

0. **light** — with the light server, its newest state installed
   (:class:`arlight.live.server_light.ServerLight`).
1. **track** — the camera pose registered on the printed marker
   (:func:`arlight.sequence.build.marker_pose`, the same call ``arlight sequence --poses
   marker`` makes per frame). When the marker is not found the previous pose is kept (the
   frame counts as ``lost``); before the first registration the frame is shown unchanged.
2. **render** — :func:`arlight.sequence.job.render_frame`, the one per-frame function of
   ``arlight sequence``, with the tracked pose: the method is prepared once for the job and
   every frame is ``method.render(state, view)``, object and camera motion going through the
   method's incremental ``pose`` path. The composite is the display codes ``sequence`` writes.
3. **show** — every sink (the studio page, the recorder) gets the frame.

:func:`run_live` drives it from :mod:`arlight.live.sources` (a paced video or a camera drops
the frames that arrive while one renders) and writes one JSON line per frame to the log:
capture and show times, the **latency** ``shown − captured`` (seconds on the loop's clock:
from the frame's arrival to the composite handed to every sink), the stage times and the
frames dropped before it. :class:`LiveSummary` has the frame rate (composited frames per
second of wall time), the latency percentiles and the stage medians.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol, TextIO

import numpy as np

from arlight.errors import InputError
from arlight.live.sources import Captured, Clock, WallClock
from arlight.scene.camera import Camera
from arlight.sequence.frames import InputFrame
from arlight.sequence.job import SequenceJob, render_frame


@dataclass
class LiveFrame:
    """A composited frame.

    Attributes:
        index: stream position of the input frame.
        display: the composite as display codes ``(H, W, 3)`` (as ``sequence`` writes it).
        pose: ``world_from_camera`` used (None: no pose yet, the input shown unchanged).
        tracked: the marker was found in this frame.
        stats: the method's numeric stats (``seconds``, ``time_<stage>``, counters).
        timings: stage → seconds (``track``, ``render``, then each sink's name).
        captured_at, shown_at: clock seconds; ``dropped``: frames skipped just before.
    """

    index: int
    display: np.ndarray
    pose: np.ndarray | None
    tracked: bool
    stats: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    captured_at: float = 0.0
    shown_at: float = 0.0
    dropped: int = 0

    @property
    def latency(self) -> float:
        """Seconds from capture to the composite handed to every sink."""
        return self.shown_at - self.captured_at


class Sink(Protocol):
    """Something that shows or keeps composited frames (``name`` is its stage's name)."""

    name: str

    def show(self, frame: LiveFrame) -> None: ...


class MarkerTracker:
    """Per-frame camera pose on a printed marker, holding the last pose when it is lost."""

    def __init__(self, calib: Any, spec: Any, camera: Camera) -> None:
        self.calib, self.spec, self.camera = calib, spec, camera
        self.last: np.ndarray | None = None
        self.lost = 0

    def __call__(self, frame: InputFrame) -> tuple[np.ndarray | None, bool]:
        """(pose, tracked): this frame's registration, or the last pose and False."""
        from arlight.sequence.build import marker_pose

        try:
            self.last = marker_pose(frame, self.calib, self.spec, self.camera,
                                    f"live frame {frame.index}")
            return self.last, True
        except InputError:
            self.lost += 1
            return self.last, False


class LiveCompositor:
    """Track and render one frame (module docstring, steps 1–2) of ``job`` — a
    :class:`SequenceJob` without per-frame poses (its camera holds the calibrated
    intrinsics, its ``calibration`` the distortion removed from every frame)."""

    def __init__(self, job: SequenceJob, tracker: Callable[[InputFrame],
                 tuple[np.ndarray | None, bool]], clock: Clock | None = None,
                 light: Callable[[], bool] | None = None,
                 depth: Callable[[InputFrame], np.ndarray] | None = None) -> None:
        self.job, self.tracker = job, tracker
        self.clock = clock or WallClock()
        self.depth = depth  # the frame's depth image (metres along +z), or None
        self.light = light  # called once before each frame: a new light installed?

    def prepare(self) -> float:
        """Prepare the method now (seconds), not on the first frame."""
        from arlight.sequence.job import prepared

        return prepared(self.job)[2]

    def passthrough(self, frame: InputFrame) -> np.ndarray:
        """The input frame's display codes, undistorted like a rendered frame's background."""
        view = self.job.view(frame, pose=self.job.camera.world_from_camera, objects={})
        if view.frame_codes is not None:
            return view.frame_codes
        return self.job.camera.transfer.to_display(view.frame)

    def __call__(self, cap: Captured) -> LiveFrame:
        c = self.clock
        tl = c.now()
        new_light = self.light() if self.light is not None else False
        t0 = c.now()
        pose, tracked = self.tracker(cap.frame)
        t1 = c.now()
        if pose is None:
            display, stats = self.passthrough(cap.frame), {}
        else:
            d = None if self.depth is None else self.depth(cap.frame)
            res = render_frame(self.job, cap.frame, d, pose=pose, objects={})
            display, stats = res.display, res.stats
        t2 = c.now()
        timings = {"track": t1 - t0, "render": t2 - t1}
        if self.light is not None:
            timings["light"] = t0 - tl
            stats = {**stats, "new_light": float(new_light)}
        timings.update({k[5:]: float(v) for k, v in stats.items() if k.startswith("time_")})
        return LiveFrame(cap.frame.index, display, pose, tracked, stats, timings,
                         cap.captured_at, 0.0, cap.dropped)


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


@dataclass
class LiveSummary:
    """What a live run did: composited ``frames``, ``dropped`` and ``lost`` (marker not
    found) frames, wall ``seconds`` from the first capture to the last frame shown,
    latencies (seconds) and per-stage medians (seconds)."""

    frames: int = 0
    dropped: int = 0
    lost: int = 0
    seconds: float = 0.0
    prepare_seconds: float = 0.0
    latencies: list[float] = field(default_factory=list)
    stages: dict[str, list[float]] = field(default_factory=dict)

    @property
    def fps(self) -> float:
        """Composited frames per second of wall time."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:
        lat = [1e3 * x for x in self.latencies]
        return {"frames": self.frames, "dropped": self.dropped, "lost": self.lost,
                "seconds": self.seconds, "frames_per_second": self.fps,
                "prepare_seconds": self.prepare_seconds,
                "latency_ms_p50": _percentile(lat, 50), "latency_ms_p95": _percentile(lat, 95),
                "latency_ms_max": max(lat) if lat else float("nan"),
                "stage_ms_median": {k: 1e3 * statistics.median(v)
                                    for k, v in self.stages.items() if v}}


def log_line(fr: LiveFrame, t0: float) -> str:
    """One JSON line of the log (times in ms from the run's first capture)."""
    return json.dumps({
        "frame": fr.index, "captured_ms": 1e3 * (fr.captured_at - t0),
        "shown_ms": 1e3 * (fr.shown_at - t0), "latency_ms": 1e3 * fr.latency,
        "dropped_before": fr.dropped, "tracked": fr.tracked,
        "stages_ms": {k: 1e3 * v for k, v in fr.timings.items()},
        "pose": None if fr.pose is None else np.asarray(fr.pose).ravel().tolist()})


def run_live(captures: Iterable[Captured], process: Callable[[Captured], LiveFrame],
             sinks: Iterable[Sink] = (), clock: Clock | None = None,
             log: TextIO | None = None, max_frames: int | None = None,
             on_frame: Callable[[LiveFrame], None] | None = None) -> LiveSummary:
    """Composite every frame ``captures`` hands over (see the module docstring) until it
    ends, ``max_frames`` are shown, or KeyboardInterrupt (the summary so far is returned)."""
    clock = clock or WallClock()
    sinks = list(sinks)
    summary = LiveSummary()
    t_first: float | None = None
    try:
        for cap in captures:
            if t_first is None:
                t_first = cap.captured_at
            summary.dropped += cap.dropped
            fr = process(cap)
            for sink in sinks:
                t = clock.now()
                sink.show(fr)
                fr.timings[sink.name] = clock.now() - t
            fr.shown_at = clock.now()
            summary.frames += 1
            summary.lost += 0 if fr.tracked else 1
            summary.latencies.append(fr.latency)
            for k, v in fr.timings.items():
                summary.stages.setdefault(k, []).append(v)
            summary.seconds = fr.shown_at - t_first
            if log is not None:
                log.write(log_line(fr, t_first) + "\n")
                log.flush()
            if on_frame is not None:
                on_frame(fr)
            if max_frames is not None and summary.frames >= max_frames:
                break
    except KeyboardInterrupt:
        pass
    finally:
        close = getattr(captures, "close", None)
        if close is not None:
            close()
    return summary


__all__ = ["LiveCompositor", "LiveFrame", "LiveSummary", "MarkerTracker", "Sink", "log_line",
           "run_live"]
