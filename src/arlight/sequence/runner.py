"""Running a sequence job: the sequential loop or Ray, progress, resume, video, summary.

:func:`run_sequence` checks everything before any work (the output folder, Ray's
reachability), opens the output folder (:class:`arlight.sequence.store.SequenceStore`),
renders only the frames not done yet — in a plain loop in this process, or as Ray tasks
(:mod:`arlight.sequence.distributed`) — writing each as it completes, then encodes the video
and writes ``summary.json``. A progress task reports frames done, frames per second and the
ETA.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.progress import task
from arlight.sequence.frames import FrameSource, InputFrame
from arlight.sequence.job import FrameResult, SequenceJob, merge_parts, render_frame
from arlight.sequence.store import SequenceStore


@dataclass
class RunOptions:
    """How to run a job.

    Attributes:
        ray: None (sequential loop), ``"auto"`` (a local Ray instance) or a cluster address.
        workers: Ray tasks run at once (local: CPUs given to Ray); default all CPUs.
        videos: containers to encode at the end (``"mp4"``, ``"webm"``); empty: none.
        restart: replace another job's frames in the output folder.
        progress: show the progress bar.
    """

    ray: str | None = None
    workers: int | None = None
    videos: tuple[str, ...] = ("mp4",)
    restart: bool = False
    progress: bool = True


@dataclass
class RunSummary:
    """What a run did (``summary.json``)."""

    frames: int
    rendered: int
    resumed: int
    seconds: float
    frame_seconds: list[float] = field(default_factory=list)
    prepare_seconds: float = 0.0
    stages: dict[str, float] = field(default_factory=dict)
    backend: str = "sequential"
    workers: int = 1
    videos: list[str] = field(default_factory=list)
    processes: int = 0
    connect_seconds: float = 0.0
    render_seconds: float = 0.0
    driver_seconds: float = 0.0
    task_seconds: list[float] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        fs = self.frame_seconds
        per = ({"median": statistics.median(fs), "mean": statistics.fmean(fs), "min": min(fs),
                "max": max(fs)} if fs else {})
        return {"frames": self.frames, "rendered": self.rendered, "resumed": self.resumed,
                "seconds": self.seconds,
                "frames_per_second": self.rendered / self.seconds if self.seconds else 0.0,
                "frame_seconds": per, "prepare_seconds": self.prepare_seconds,
                "connect_seconds": self.connect_seconds,
                "render_seconds": self.render_seconds,
                "driver_seconds": self.driver_seconds,
                "stage_medians": self.stages, "backend": self.backend,
                "workers": self.workers, "processes": self.processes, "videos": self.videos}


def _frames_with_depth(source: FrameSource, wanted: set[int],
                       depths: Sequence[Any] | None) -> Iterator[tuple[InputFrame, Any]]:
    for fr in source.frames(wanted):
        d = None
        if depths is not None:
            d = depths[fr.index]
            if not isinstance(d, np.ndarray):
                from arlight.io.images import read_depth

                d = read_depth(d)
        yield fr, d


class _Bar:
    """Frames done, as a progress task with the frame rate as its status (silent when
    disabled; the CLI draws it, see :mod:`arlight.progress`)."""

    def __init__(self, total: int, done: int, enabled: bool, label: str):
        self.task = task(label, total, done=done, enabled=enabled)
        self.t0 = time.perf_counter()
        self.n = 0

    def advance(self) -> None:
        self.n += 1
        rate = self.n / max(time.perf_counter() - self.t0, 1e-9)
        self.task.advance(info=f"{rate:.2f} frames/s")

    def close(self) -> None:
        self.task.close()


def validate_depths(depths: Sequence[Any], size: tuple[int, int]) -> None:
    """Read every depth image once (InputError naming the file) and check its size."""
    from arlight.io.images import read_depth

    for d in depths:
        arr = d if isinstance(d, np.ndarray) else read_depth(d)
        if (arr.shape[1], arr.shape[0]) != tuple(size):
            raise InputError(f"depth image is {arr.shape[1]}×{arr.shape[0]} but the frames are "
                             f"{size[0]}×{size[1]}", file=None if isinstance(d, np.ndarray)
                             else str(d), field="--depth")


def _output_bytes(job: SequenceJob) -> int:
    """What a run writes at most: 16-bit RGB PNG frames, and float layers with --layers."""
    px = job.camera.width * job.camera.height
    return job.count * px * (6 + (4 * 3 * 4 if job.layers else 0))


def run_sequence(job: SequenceJob, source: FrameSource, out: str | Path,
                 options: RunOptions | None = None, depths: Sequence[Any] | None = None,
                 inputs: tuple[Path, ...] = ()) -> RunSummary:
    """Render every frame of ``job`` not yet in ``out``; see the module docstring.

    ``depths``: per-frame depth images (arrays or files), or None. ``inputs``: every input
    file and folder (the output may not be, contain or lie in one, and no video or summary
    may resolve to one). Raises :class:`InputError` before writing anything when the inputs
    disagree (frame and pose counts, sizes), a frame or depth image does not decode, or the
    folder or the Ray cluster cannot be used; the output folder is created (or, with
    ``restart``, emptied) only when the first frame is written.
    """
    opts = options or RunOptions()
    if source.count != job.count:
        raise InputError(f"{source.count} frames but {job.count} poses; give one pose per "
                         "frame (or keyframes spanning all frames)", file=str(source.path),
                         field="--poses")
    if depths is not None and len(depths) != job.count:
        raise InputError(f"{len(depths)} depth images for {job.count} frames",
                         field="--depth")
    if source.size != (job.camera.width, job.camera.height):
        raise InputError(f"frames are {source.size[0]}×{source.size[1]} but the camera is "
                         f"{job.camera.width}×{job.camera.height}", file=str(source.path),
                         field="--frames")
    from arlight.methods import get_method

    if get_method(job.method).spec.capabilities.needs_depth and depths is None:
        raise InputError(f"{job.method} needs a depth image per frame", field="--depth")
    # every input in full before the output folder is looked at, let alone changed
    source.validate()
    if depths is not None:
        validate_depths(depths, source.size)
    store = SequenceStore(out, job)
    store.check(opts.restart, inputs, opts.videos, _output_bytes(job))
    info = None
    t0 = time.perf_counter()
    if opts.ray is not None:
        from arlight.sequence import distributed

        info = distributed.connect(opts.ray, opts.workers, job.threads or 1)  # fails here
    connected = time.perf_counter()
    try:
        done = store.begin(opts.restart)  # nothing is changed before the first frame
        todo = store.missing
        summary = RunSummary(frames=job.count, rendered=0, resumed=len(done), seconds=0.0,
                             backend="sequential" if info is None else f"ray ({opts.ray})",
                             connect_seconds=connected - t0)
        stage_runs: list[dict[str, float]] = []
        pids: set[Any] = set()
        bar = _Bar(job.count, len(done), opts.progress,
                   f"{job.method} {'sequence' if info is None else 'on Ray'}")

        def take(res: FrameResult) -> None:
            t = time.perf_counter()
            store.write(res)
            summary.rendered += 1
            summary.frame_seconds.append(float(res.stats.get("seconds", 0.0)))
            summary.prepare_seconds += float(res.stats.get("prepare_seconds", 0.0))
            summary.task_seconds.append(float(res.stats.get("task_seconds", 0.0)))
            stage_runs.append({k[5:]: float(v) for k, v in res.stats.items()
                               if k.startswith("time_")})
            pids.add((res.stats.get("host"), res.stats.get("pid")))
            bar.advance()
            summary.driver_seconds += time.perf_counter() - t

        frames = _frames_with_depth(source, set(todo), depths)
        t_loop = time.perf_counter()
        try:
            if info is None:
                for fr, d in frames:
                    take(merge_parts(job, [render_frame(job, fr, d, k)
                                           for k in range(job.split)]))
                summary.workers = 1
            else:
                from arlight.sequence import distributed

                summary.workers = int(opts.workers or info["cpus"] // (job.threads or 1) or 1)
                distributed.run(job, frames, summary.workers, take)
        except KeyboardInterrupt:
            bar.close()
            import sys

            print(f"sequence: {len(store.done)} of {job.count} frames are done in "
                  f"{store.out}; run the same command again to render the rest",
                  file=sys.stderr, flush=True)
            raise
        finally:
            bar.close()
        summary.render_seconds = time.perf_counter() - t_loop
        keys = {k for r in stage_runs for k in r}
        summary.stages = {k: statistics.median(r.get(k, 0.0) for r in stage_runs)
                          for k in sorted(keys)}
        summary.processes = len(pids)
        if store.missing:
            raise RuntimeError(f"frames {store.missing[:5]} were not rendered")
        summary.videos = [str(p) for p in store.write_video(opts.videos)]
    finally:
        if info is not None:
            from arlight.sequence import distributed

            distributed.shutdown()
    summary.seconds = time.perf_counter() - t0
    store.write_summary(summary.as_dict())
    return summary


__all__ = ["RunOptions", "RunSummary", "run_sequence", "validate_depths"]
