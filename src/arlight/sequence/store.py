"""The output folder of a sequence, written frame by frame so that a run can resume.

Layout of ``OUT/``::

    sequence.json        the job: format, key, per-input hashes, frame count (written first)
    frames.jsonl         one line per finished frame: index, file, SHA-256, stats
    frames/000000.png    the composite of each frame (display codes, the camera's transfer)
    layers/000000/*.exr  composite, mixed, delta, mask of each frame (with --layers)
    sequence.mp4/.webm   the video (written once every frame is done)
    summary.json         frames, times, per-frame statistics (written last)

Every file is written to a temporary name and renamed (:func:`arlight.io.images.
atomic_write`); a frame's line is appended to ``frames.jsonl`` (and flushed to disk) only
after its files are in place. A run killed at any moment — SIGINT, SIGKILL, a lost machine —
therefore leaves finished frames that are complete and listed, and at most a torn last line,
which the next run drops (it rewrites the log without it). The next run of the *same* job
(equal ``sequence.json`` hashes) renders only the frames that are not listed, or whose file is
missing or differs from its SHA-256; a different job in the same folder is refused, naming
what changed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from arlight.errors import InputError
from arlight.io.images import atomic_write, write_exr, write_png
from arlight.sequence.job import FrameResult, SequenceJob

FORMAT = "arlight-sequence/1"
HEADER = "sequence.json"
LOG = "frames.jsonl"
SUMMARY = "summary.json"
KNOWN = (HEADER, LOG, SUMMARY, "frames", "layers", "sequence.mp4", "sequence.webm",
         ".sequence.*")
"""Top-level entries of a sequence folder (an existing folder of only these is ours)."""


def frame_file(index: int) -> str:
    return f"frames/{index:06d}.png"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class SequenceStore:
    """The output folder of one job; see the module docstring."""

    def __init__(self, out: str | Path, job: SequenceJob):
        self.out = Path(os.path.abspath(Path(out).expanduser()))
        self.job = job
        self.done: dict[int, dict[str, Any]] = {}

    # --------------------------------------------------------------- before any work
    def check(self, restart: bool = False, inputs: tuple[Path, ...] = ()) -> dict[int, dict]:
        """Check the folder (nothing is written): the frames already done of this job.

        Raises :class:`InputError` when the folder cannot be written, holds files that are
        not a sequence output, or holds another job's sequence (unless ``restart``)."""
        from arlight.outputs_atomic import check_output_dir

        check_output_dir(self.out, KNOWN, inputs=inputs)
        header = self._read_header()
        if header is None or restart:
            return {}
        if header.get("key") != self.job.key:
            old = header.get("parts", {})
            diff = [k for k, v in self.job.parts.items() if old.get(k) != v] or ["format"]
            raise InputError(f"holds the frames of another sequence job (different "
                             f"{', '.join(diff)}); choose another folder, or --restart to "
                             "replace it", file=str(self.out), field="--out")
        return self._read_log()

    def _read_header(self) -> dict | None:
        p = self.out / HEADER
        if not p.is_file():
            return None
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputError(f"unreadable {HEADER} ({exc}); --restart replaces it",
                             file=str(self.out), field="--out") from exc
        return d if isinstance(d, dict) else None

    def _read_log(self) -> dict[int, dict]:
        """Finished frames whose file is present and matches its hash (torn lines dropped)."""
        done: dict[int, dict] = {}
        p = self.out / LOG
        if not p.is_file():
            return done
        for line in p.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                rec = json.loads(line)
                i = int(rec["index"])
            except (ValueError, KeyError, TypeError):
                continue  # a torn last line of a killed run
            if not 0 <= i < self.job.count:
                continue
            f = self.out / rec.get("file", "")
            if f.is_file() and _sha256(f) == rec.get("sha256"):
                done[i] = rec
        return done

    # --------------------------------------------------------------------- writing
    def open(self, restart: bool = False) -> dict[int, dict]:
        """Create or reopen the folder for this job; returns the frames already done."""
        if restart and self.out.is_dir():
            for name in os.listdir(self.out):
                p = self.out / name
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "frames").mkdir(exist_ok=True)
        for p in (self.out / "frames").glob(".*"):  # temporaries of a killed run
            with contextlib.suppress(OSError):
                p.unlink()
        self.done = {} if restart else self._read_log()
        header = {"format": FORMAT, "key": self.job.key, "parts": self.job.parts,
                  "frames": self.job.count, "method": self.job.method, "fps": self.job.fps}
        with atomic_write(self.out / HEADER, ".json") as tmp:
            tmp.write_text(json.dumps(header, indent=1), encoding="utf-8")
        # the log without torn lines or stale entries, so appends start on a clean line
        with atomic_write(self.out / LOG, ".jsonl") as tmp:
            tmp.write_text("".join(json.dumps(self.done[i]) + "\n" for i in sorted(self.done)),
                           encoding="utf-8")
        return dict(self.done)

    def write(self, res: FrameResult) -> dict:
        """Write one frame's files, then append its line to the log (durably)."""
        rel = frame_file(res.index)
        write_png(self.out / rel, res.display)
        if res.layers:
            d = self.out / "layers" / f"{res.index:06d}"
            for name, img in res.layers.items():
                write_exr(d / f"{name}.exr", img)
        rec = {"index": res.index, "file": rel, "sha256": _sha256(self.out / rel),
               "stats": res.stats}
        with open(self.out / LOG, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(rec) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.done[res.index] = rec
        return rec

    @property
    def missing(self) -> list[int]:
        return [i for i in range(self.job.count) if i not in self.done]

    def frames_display(self):
        """The finished frames' display images in order (uint8 for the video)."""
        from arlight.io.images import read_ldr

        for i in range(self.job.count):
            codes = read_ldr(self.out / frame_file(i))
            yield codes if codes.dtype == np.uint8 else (codes >> 8).astype(np.uint8)

    def write_video(self, formats: tuple[str, ...]) -> list[Path]:
        """Encode the frames into ``sequence.<fmt>`` for each format (atomically)."""
        from arlight.sequence.video import encode

        return [encode(self.out / f"sequence.{fmt}", self.frames_display(), self.job.fps)
                for fmt in formats]

    def write_summary(self, summary: dict) -> Path:
        with atomic_write(self.out / SUMMARY, ".json") as tmp:
            tmp.write_text(json.dumps(summary, indent=1), encoding="utf-8")
        return self.out / SUMMARY


__all__ = ["FORMAT", "KNOWN", "SequenceStore", "frame_file"]
