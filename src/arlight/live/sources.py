"""Where ``arlight live`` gets its frames: a video file played at its own rate, or a camera.

Live means the newest frame, never a backlog. :func:`paced` plays a decoded video against
the wall clock: frame ``k`` *arrives* at ``t0 + k / fps``; whenever the loop is ready for a
frame it gets the newest one that has arrived (waiting for the next one when none is new),
and every frame that arrived while it was busy is **dropped** — counted, never queued.
:class:`CameraSource` does the same for an OpenCV ``VideoCapture``: a reader thread keeps
only the newest frame in a one-slot mailbox and counts the frames it overwrote.
:func:`unpaced` hands over every frame, as fast as the loop takes them (deterministic: the
tests and the benchmark's throughput).

Each frame comes as :class:`Captured`: the frame, its capture time on the loop's clock
(seconds; the start of a latency) and how many frames were dropped just before it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from arlight.errors import InputError
from arlight.sequence.frames import FrameSource, InputFrame


class Clock(Protocol):
    """Seconds on a monotonic clock, and a way to wait (tests pass a fake one)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """:func:`time.perf_counter` and :func:`time.sleep`."""

    def now(self) -> float:
        return time.perf_counter()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


@dataclass
class Captured:
    """A frame handed to the loop: ``captured_at`` (clock seconds) and ``dropped``, the
    frames that arrived since the previous hand-over and were skipped."""

    frame: InputFrame
    captured_at: float
    dropped: int = 0


def unpaced(frames: Iterable[InputFrame], clock: Clock) -> Iterator[Captured]:
    """Every frame in order, none dropped; captured when it is handed over."""
    for fr in frames:
        yield Captured(fr, clock.now(), 0)


def paced(frames: Iterable[InputFrame], fps: float, clock: Clock) -> Iterator[Captured]:
    """Frames played at ``fps`` (frames per second) on ``clock``; see the module docstring.

    Frame ``k`` of the stream arrives at ``t0 + k/fps``. When the loop asks (resumes the
    generator) at time ``t``, the newest arrived frame ``⌊(t − t0)·fps⌋`` is handed over
    (its capture time is its arrival time) and the ones between the previous hand-over and
    it count as dropped; if that frame was handed over already, the generator sleeps until
    the next one arrives. Frames are still decoded in order (a video cannot be seeked
    cheaply), only not rendered.
    """
    if not fps > 0:
        raise InputError(f"must be > 0 frames per second, got {fps}", field="--fps")
    it = iter(frames)
    current = next(it, None)
    if current is None:
        return
    k = 0  # stream position of `current`
    t0 = clock.now()
    while current is not None:
        now = clock.now()
        due = math.floor((now - t0) * fps + 1e-9)
        if due < k:  # nothing new has arrived: wait for frame k
            clock.sleep(t0 + k / fps - now)
            due = k
        dropped = 0
        while k < due:  # frames that arrived while the loop was busy: skip to the newest
            nxt = next(it, None)
            if nxt is None:
                break
            current, k, dropped = nxt, k + 1, dropped + 1
        yield Captured(current, t0 + k / fps, dropped)
        current, k = next(it, None), k + 1


class VideoSource:
    """A video file (or a folder of images) as a stream, optionally played ``loops`` times
    (0: forever); frames are re-indexed by stream position."""

    def __init__(self, path: str | Path, loops: int = 1, fps: float | None = None) -> None:
        try:
            self.source = FrameSource(path)
        except InputError as exc:  # named after live's option
            raise InputError(exc.message, file=exc.file, field="--video") from exc
        self.loops = int(loops)
        self.fps = float(fps or self.source.fps or 30.0)
        self.size = self.source.size
        self.name = Path(path).name

    def frames(self) -> Iterator[InputFrame]:
        k = 0
        n = 0
        while self.loops == 0 or n < self.loops:
            for fr in self.source:
                yield InputFrame(k, fr.name, codes=fr.codes, radiance=fr.radiance)
                k += 1
            n += 1


class DepthFrames:
    """Per-frame depth images of a video (a folder, one per video frame in natural name
    order; RGB-D sensors' 16-bit PNGs with ``units_per_metre``): frame ``k`` of the stream
    gets image ``k mod count`` (a looped video gets its depth again)."""

    def __init__(self, folder: str | Path, count: int, size: tuple[int, int],
                 units_per_metre: float | None = None) -> None:
        self.files = FrameSource(folder).files if Path(folder).is_dir() else []
        if not self.files:
            raise InputError("expected a folder of depth images", file=str(folder),
                             field="--depth")
        if len(self.files) != count:
            raise InputError(f"{len(self.files)} depth images for {count} video frames",
                             file=str(folder), field="--depth")
        self.units = units_per_metre
        self.size = size

    def validate(self) -> None:
        """Read every image once: InputError naming the file (unreadable, another size)."""
        for f in self.files:
            self.read(f)

    def read(self, f: Path) -> np.ndarray:
        from arlight.io.images import read_depth

        try:
            d = read_depth(f, self.units)
        except InputError as exc:
            raise InputError(exc.message, file=str(f), field="--depth") from exc
        if (d.shape[1], d.shape[0]) != tuple(self.size):
            raise InputError(f"depth image is {d.shape[1]}×{d.shape[0]} but the frames are "
                             f"{self.size[0]}×{self.size[1]}", file=str(f), field="--depth")
        return d

    def __call__(self, frame: InputFrame) -> np.ndarray:
        return self.read(self.files[frame.index % len(self.files)])


class CameraSource:
    """An OpenCV camera (``VideoCapture(index)``): a reader thread keeps the newest frame
    (RGB uint8) in a one-slot mailbox; a frame overwritten before the loop took it counts
    as dropped."""

    def __init__(self, index: int, size: tuple[int, int] | None = None,
                 capture=None) -> None:
        import cv2

        self.name = f"camera {index}"
        cap = capture if capture is not None else cv2.VideoCapture(int(index))
        if size is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
        ok, first = (cap.read() if cap.isOpened() else (False, None))
        if not ok or first is None:
            cap.release()
            raise InputError(f"cannot open camera {index} (no such device, or it gives no "
                             "frames)", field="--camera")
        self.cap = cap
        self.size = (int(first.shape[1]), int(first.shape[0]))
        self.fps = float(cap.get(cv2.CAP_PROP_FPS) or 30.0)
        self._cond = threading.Condition()
        self._slot: tuple[np.ndarray, float] | None = None
        self._dropped = 0
        self._ended = False
        self._stop = False
        self._thread: threading.Thread | None = None

    def _read(self, clock: Clock) -> None:
        import cv2

        while not self._stop:
            ok, bgr = self.cap.read()
            t = clock.now()
            with self._cond:
                if not ok:
                    self._ended = True
                    self._cond.notify_all()
                    return
                if self._slot is not None:
                    self._dropped += 1
                self._slot = (cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), t)
                self._cond.notify_all()

    def start(self, clock: Clock) -> None:
        """Start the reader thread (:meth:`captures` does when it has not been)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._read, args=(clock,),
                                            name="arlight-live-camera", daemon=True)
            self._thread.start()

    def captures(self, clock: Clock) -> Iterator[Captured]:
        """The newest frame each time the loop asks (blocking until one arrives)."""
        self.start(clock)
        k = 0
        try:
            while True:
                with self._cond:
                    while self._slot is None and not self._ended:
                        self._cond.wait(0.5)
                    if self._slot is None:
                        return
                    (img, t), self._slot = self._slot, None
                    dropped, self._dropped = self._dropped, 0
                yield Captured(InputFrame(k, f"{self.name}#{k}", codes=img), t, dropped)
                k += 1
        finally:
            self.close()

    def close(self) -> None:
        self._stop = True
        if self._thread is not None:
            self._thread.join(timeout=2)
        self.cap.release()


__all__ = ["CameraSource", "Captured", "DepthFrames", "Clock", "VideoSource", "WallClock", "paced",
           "unpaced"]
