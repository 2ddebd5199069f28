"""The input frames of a sequence: a folder of images or a video file.

A folder's images (PNG, JPEG, EXR, ...; see :mod:`arlight.io.images`) are taken in natural
sort order of their names (``f2.png`` before ``f10.png``); every one must have the same size.
A video is decoded by ffmpeg (:mod:`arlight.sequence.video`). :class:`FrameSource` reads
only headers when opened (count, size); :meth:`FrameSource.validate` decodes every frame
once (a truncated or unreadable frame, one of another size), which the runner does before
the output folder is touched, so a bad input fails before any output is written.

A frame comes back as :class:`InputFrame`: LDR code values (uint8/uint16, decoded to linear
radiance through the scene camera's transfer function by the renderer) or linear HDR
radiance (float32).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arlight.errors import InputError
from arlight.io.images import HDR_SUFFIXES, LDR_SUFFIXES, is_hdr_path
from arlight.sequence import video

IMAGE_SUFFIXES = HDR_SUFFIXES | LDR_SUFFIXES


@dataclass
class InputFrame:
    """One input frame: ``codes`` (LDR code values) or ``radiance`` (HDR), and its name."""

    index: int
    name: str
    codes: np.ndarray | None = None
    radiance: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        a = self.codes if self.codes is not None else self.radiance
        assert a is not None
        return a.shape[1], a.shape[0]


def _natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


class FrameSource:
    """Frames from a folder of images or a video file (``path``); see the module docstring.

    Attributes:
        path: the folder or video file.
        count: number of frames.
        size: (width, height) in pixels.
        fps: frames per second of a video (0 for a folder).
        fingerprint: identifies the content (file names, sizes and modification times).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.files: list[Path] = []
        self.fps = 0.0
        p = self.path
        if p.is_dir():
            self.files = sorted((f for f in p.iterdir() if f.is_file()
                                 and f.suffix.lower() in IMAGE_SUFFIXES
                                 and not f.name.startswith(".")),
                                key=lambda f: _natural_key(f.name))
            if not self.files:
                raise InputError(f"no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in the "
                                 "folder", file=str(p), field="--frames")
            self.count = len(self.files)
            from arlight.bounds import image_size

            # the size from the first file's header: nothing is decoded before the cost of
            # the run is checked (a 100 000 × 100 000 frame is refused, not decoded)
            size = image_size(self.files[0])
            self.size = size if size is not None else self._read_file(0).size
            hdr = {is_hdr_path(f) for f in self.files}
            if len(hdr) > 1:
                raise InputError("the folder mixes HDR and LDR images", file=str(p),
                                 field="--frames")
        elif p.is_file():
            if not video.is_video_path(p):
                raise InputError(f"not a folder of images or a video file (expected one of "
                                 f"{', '.join(sorted(video.VIDEO_SUFFIXES))})", file=str(p),
                                 field="--frames")
            self.count, self.size, self.fps = video.probe(p)
        else:
            raise InputError("no such folder or video file", file=str(p), field="--frames")

    @property
    def is_video(self) -> bool:
        return not self.files

    @property
    def fingerprint(self) -> str:
        from arlight.content_hash import content_hash

        stats = [(f.name, f.stat()) for f in self.files or [self.path]]
        return content_hash([(name, st.st_size, st.st_mtime_ns) for name, st in stats],
                            length=24)

    def _read_file(self, i: int) -> InputFrame:
        from arlight.io.images import read_hdr, read_ldr

        f = self.files[i]
        try:
            if is_hdr_path(f):
                frame = InputFrame(i, f.name, radiance=read_hdr(f))
            else:
                frame = InputFrame(i, f.name, codes=read_ldr(f))
        except InputError as exc:
            raise InputError(exc.message, file=str(f), field="--frames") from exc
        size = getattr(self, "size", None)
        if size is not None and frame.size != size:
            raise InputError(f"image is {frame.size[0]}×{frame.size[1]} but the first frame "
                             f"is {size[0]}×{size[1]}", file=str(f), field="--frames")
        return frame

    def validate(self) -> None:
        """Decode every frame once and check its size (InputError naming the file): a
        folder's images one at a time (never all in memory); a video was decoded in full
        when opened (its frame count is counted by decoding)."""
        if getattr(self, "validated", False):
            return
        for i in range(len(self.files)):
            self._read_file(i)
        self.validated = True

    def __len__(self) -> int:
        return self.count

    def __iter__(self) -> Iterator[InputFrame]:
        """Every frame in order (a video is decoded once, front to back)."""
        if self.files:
            for i in range(self.count):
                yield self._read_file(i)
            return
        n = 0
        for n, codes in enumerate(video.decode(self.path)):
            if n >= self.count:
                break
            yield InputFrame(n, f"{self.path.name}#{n}", codes=np.array(codes))
        if n + 1 < self.count:
            raise InputError(f"the video ended after {n + 1} of {self.count} frames",
                             file=str(self.path), field="--frames")

    def frames(self, wanted: set[int] | None = None) -> Iterator[InputFrame]:
        """The frames whose index is in ``wanted`` (all when None), in order. A folder reads
        only those files; a video decodes up to the last one wanted."""
        if wanted is None:
            yield from self
            return
        if self.files:
            for i in sorted(wanted):
                yield self._read_file(i)
            return
        last = max(wanted, default=-1)
        for fr in self:
            if fr.index > last:
                return
            if fr.index in wanted:
                yield fr


__all__ = ["FrameSource", "InputFrame"]
