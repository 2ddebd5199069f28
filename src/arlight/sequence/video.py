"""Video files through imageio-ffmpeg (the ffmpeg binary it ships): count, decode, encode.

Decoding yields RGB ``uint8`` code values ``(H, W, 3)`` per frame. Encoding writes H.264
(``.mp4``, yuv420p, CRF 18) or VP9 (``.webm``) from uint8 frames; frames of odd size are
padded by one replicated row/column (yuv420p needs even sizes). The encoder runs
single-threaded with ffmpeg's ``bitexact`` flags, so the same frames always give the same
bytes (a resumed run's video equals an uninterrupted run's).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from arlight.errors import InputError

VIDEO_SUFFIXES = {".mp4", ".mov", ".mkv", ".webm", ".avi", ".m4v", ".mpg", ".mpeg"}
CODECS = {".mp4": ["-c:v", "libx264", "-crf", "18", "-preset", "medium"],
          ".webm": ["-c:v", "libvpx-vp9", "-crf", "30", "-b:v", "0", "-row-mt", "0"]}
"""Encoder arguments per output container."""


def is_video_path(path: str | Path) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def probe(path: str | Path) -> tuple[int, tuple[int, int], float]:
    """``(frames, (width, height), fps)`` of a video; frames counted by decoding (exact).

    Raises :class:`InputError` naming the file when ffmpeg cannot read it."""
    import imageio_ffmpeg

    p = Path(path)
    if not p.is_file():
        raise InputError("video file not found", file=str(p), field="--frames")
    try:
        gen = imageio_ffmpeg.read_frames(str(p))
        meta = next(gen)
        gen.close()
        n, _ = imageio_ffmpeg.count_frames_and_secs(str(p))
    except (OSError, RuntimeError, StopIteration, ValueError) as exc:
        msg = " ".join(str(exc).split())[-200:]
        raise InputError(f"cannot decode the video ({msg})", file=str(p),
                         field="--frames") from exc
    w, h = (int(x) for x in meta["size"])
    if n < 1:
        raise InputError("the video has no frames", file=str(p), field="--frames")
    return int(n), (w, h), float(meta.get("fps") or 0.0)


def decode(path: str | Path) -> Iterator[np.ndarray]:
    """Frames of a video as uint8 ``(H, W, 3)`` arrays, in order."""
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
    meta = next(gen)
    w, h = (int(x) for x in meta["size"])
    try:
        for buf in gen:
            yield np.frombuffer(buf, np.uint8).reshape(h, w, 3)
    finally:
        gen.close()


def _even(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    return np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def encode(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Encode uint8 ``(H, W, 3)`` frames into ``path`` (``.mp4`` or ``.webm``), atomically
    (a temporary file renamed on success)."""
    import imageio_ffmpeg

    from arlight.io.images import atomic_write

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CODECS:
        raise InputError(f"unsupported video container {suffix!r}; expected "
                         f"{', '.join(CODECS)}", field="--video")
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise ValueError("no frames to encode")
    first = _even(np.ascontiguousarray(first, np.uint8))
    h, w = first.shape[:2]
    with atomic_write(path, suffix) as tmp:
        gen = imageio_ffmpeg.write_frames(
            str(tmp), (w, h), fps=fps, codec=None, macro_block_size=1, quality=None,
            input_params=["-threads", "1"],
            output_params=[*CODECS[suffix], "-threads", "1", "-fflags", "+bitexact",
                           "-flags:v", "+bitexact", "-map_metadata", "-1"],
            ffmpeg_log_level="error")
        gen.send(None)
        gen.send(first)
        for img in it:
            gen.send(_even(np.ascontiguousarray(img, np.uint8)))
        gen.close()
    return path
