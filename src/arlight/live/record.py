"""Recording a live run (``--record OUT.mp4`` or ``--record FOLDER``), never over an input.

Every composited frame is written as it is shown, as a PNG (``frame_000000.png``, fast
zlib level 1) into a staging folder, by a writer thread (a queue of at most
:data:`QUEUE_FRAMES` frames: the loop hands a frame over and goes on; it waits only when
the disk falls that far behind — every shown frame is kept). For a folder target
:class:`arlight.staged_output.StagedOutput` swaps it in at the end; for a video target
(``.mp4``, ``.webm``) the frames are encoded at the end (:func:`arlight.sequence.video.
encode`, written atomically) at the rate the run composited them, then the staging folder is
removed and the video recorded as arlight's (:func:`arlight.output_guard.record_written`).
Either way the output appears whole or not at all. :func:`check_record` refuses, before the
run starts, a target that is an input, lies in one, or is a user's file
(:mod:`arlight.output_guard`).
"""

from __future__ import annotations

import queue
import shutil
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from arlight.live.loop import LiveFrame
from arlight.sequence.video import VIDEO_SUFFIXES

RECORD_FILES = ("frame_*.png",)
QUEUE_FRAMES = 8
"""Frames waiting for the writer thread at most (then the loop waits: none is lost)."""


def is_video_target(path: str | Path) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def check_record(target: str | Path, inputs: Iterable[str | Path]) -> None:
    """InputError (field ``--record``) unless ``target`` can be written without destroying
    anything: a video of a supported container that is not an input nor a user's file, or
    a folder that is empty, new or an earlier recording."""
    from arlight.errors import InputError
    from arlight.output_guard import check_outputs
    from arlight.sequence.video import CODECS
    from arlight.staged_output import check_output_dir

    p = Path(target)
    if is_video_target(p):
        if p.suffix.lower() not in CODECS:
            raise InputError(f"cannot record into {p.suffix}; use "
                             f"{' or '.join(CODECS)} or a folder", file=str(p),
                             field="--record")
        check_outputs({"--record": p}, inputs, overwrite=False)
    else:
        check_output_dir(p, RECORD_FILES, 0, inputs, field="--record")


class Recorder:
    """A sink that keeps every composited frame (see the module docstring)."""

    name = "record"

    def __init__(self, target: str | Path) -> None:
        import cv2  # noqa: F401 — fail here, not on the first frame

        self.target = Path(target)
        self.count = 0
        self._staged = None
        self._queue: queue.Queue = queue.Queue(QUEUE_FRAMES)
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        if is_video_target(self.target):
            self.target.parent.mkdir(parents=True, exist_ok=True)
            self.folder = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.frames-",
                                                dir=self.target.parent))
        else:
            from arlight.staged_output import StagedOutput

            self._staged = StagedOutput(self.target, "live", RECORD_FILES)
            self.folder = self._staged.__enter__()

    def _write(self) -> None:
        import cv2

        while True:
            item = self._queue.get()
            if item is None:
                return
            i, img = item
            try:
                if not cv2.imwrite(str(self.folder / f"frame_{i:06d}.png"), img,
                                   [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                    raise OSError(f"cannot write frame {i} into {self.folder}")
            except BaseException as exc:  # noqa: BLE001 — re-raised by show/close
                self._error = exc

    def show(self, frame: LiveFrame) -> None:
        """Hand the composite to the writer thread (BGR, 8 bits)."""
        if self._error is not None:
            raise self._error
        if self._thread is None:
            self._thread = threading.Thread(target=self._write, name="arlight-live-record",
                                            daemon=True)
            self._thread.start()
        img = frame.display
        if img.dtype != np.uint8:  # 16-bit input: the video is 8-bit
            img = (img >> 8).astype(np.uint8)
        self._queue.put((self.count, np.ascontiguousarray(img[..., ::-1])))
        self.count += 1

    def _drain(self) -> None:
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None

    def _frames(self) -> Iterator[np.ndarray]:
        import cv2

        for i in range(self.count):
            yield cv2.imread(str(self.folder / f"frame_{i:06d}.png"),
                             cv2.IMREAD_UNCHANGED)[..., ::-1]

    def close(self, fps: float, ok: bool = True) -> Path | None:
        """Finish: the output written (``fps``: its frame rate) when ``ok`` and frames were
        recorded, else everything staged removed. Returns the output, or None."""
        self._drain()
        ok = ok and self._error is None
        if self._staged is not None:
            if ok and self.count:
                self._staged.__exit__(None, None, None)
                return self.target
            self._staged.__exit__(RuntimeError, RuntimeError("not recorded"), None)
            return None
        try:
            if not (ok and self.count):
                return None
            from arlight.output_guard import record_written
            from arlight.sequence.video import encode

            out = encode(self.target, self._frames(), max(float(fps), 1.0))
            record_written([out])
            return out
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


__all__ = ["Recorder", "check_record", "is_video_target"]
