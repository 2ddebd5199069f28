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

Nothing in the folder is touched before the first frame is written (:meth:`SequenceStore.
begin` only reads): a run that fails on its inputs leaves an earlier sequence — also with
``--restart`` — byte for byte as it was, and creates no folder. An existing folder is used
only when everything in it is laid out as above (a ``frames/`` folder of someone's pictures is
not a sequence output), and the video and summary replace only files arlight recorded as its
own (:mod:`arlight.output_guard`) unless ``--restart`` is given.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
from collections.abc import Iterable
from fnmatch import fnmatch
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
         ".sequence.*", ".frames.*", ".summary.*", ".arlight-written.json",
         ".arlight-written.json.*")
"""Top-level entries of a sequence folder (an existing folder of only these is ours): the
files above, the temporaries of :func:`atomic_write` a killed run may leave, and the ledger
of :mod:`arlight.output_guard`."""

_FRAME_FILE = re.compile(r"^(\d{6}\.png|\.\d{6}\..*\.png)$")
_LAYER_DIR = re.compile(r"^\d{6}$")
_LAYER_FILE = re.compile(r"^\.?[A-Za-z0-9_]+(\..*)?\.exr$")
_TEMPORARY = re.compile(r"^\.(sequence|frames|summary)\..+")


def frame_file(index: int) -> str:
    return f"frames/{index:06d}.png"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _check_layout(out: Path) -> None:
    """Refuse a folder whose files are not all a sequence's own (see the module
    docstring): ``frames/`` holding other pictures, a ``layers/`` of other files, or any
    file without the ``sequence.json`` every run writes before its first frame."""
    if not out.is_dir():
        return

    def foreign(rel: str) -> InputError:
        return InputError(f"holds {rel!r}, which a sequence run did not write; the folder "
                          "is not a sequence output (choose an empty or new folder)",
                          file=str(out), field="--out")

    files = []
    for p in sorted(out.rglob("*")):
        rel = p.relative_to(out)
        parts = rel.parts
        if p.is_symlink() or not (p.is_dir() or p.is_file()):
            raise foreign(str(rel))
        if p.is_dir():
            ok = (parts[0] in ("frames", "layers") and len(parts) == 1) or \
                (parts[0] == "layers" and len(parts) == 2 and _LAYER_DIR.match(parts[1]))
        elif len(parts) == 1:
            ok = any(fnmatch(rel.name, g) for g in KNOWN)
        elif parts[0] == "frames":
            ok = len(parts) == 2 and bool(_FRAME_FILE.match(parts[1]))
        else:
            ok = parts[0] == "layers" and len(parts) == 3 and \
                bool(_LAYER_DIR.match(parts[1])) and bool(_LAYER_FILE.match(parts[2]))
        if not ok:
            raise foreign(str(rel))
        if p.is_file() and not _TEMPORARY.match(rel.name) and \
                rel.name != ".arlight-written.json":
            files.append(rel)
    if files and not (out / HEADER).is_file():
        raise InputError(f"holds {str(files[0])!r} but no {HEADER}: not a sequence output "
                         "(choose an empty or new folder)", file=str(out),
                         field="--out")


class SequenceStore:
    """The output folder of one job; see the module docstring."""

    def __init__(self, out: str | Path, job: SequenceJob):
        self.out = Path(os.path.abspath(Path(out).expanduser()))
        self.job = job
        self.done: dict[int, dict[str, Any]] = {}
        self._restart = False
        self._opened = False

    # --------------------------------------------------------------- before any work
    def check(self, restart: bool = False, inputs: Iterable[str | Path] = (),
              videos: tuple[str, ...] = (), expected_bytes: int = 0) -> dict[int, dict]:
        """Check the folder (nothing is written): the frames already done of this job.

        Raises :class:`InputError` when the folder is an input or lies inside an input folder
        (the frames), contains an input, cannot be written, holds files that are not a
        sequence output, holds another job's sequence (unless ``restart``), or when a video
        or summary path resolves to an input or to a file arlight did not write (unless
        ``restart``). ``inputs``: every file and folder the run reads."""
        self.check_paths(self.out, restart, inputs, videos, expected_bytes)
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

    @staticmethod
    def check_paths(out: str | Path, restart: bool = False, inputs: Iterable[str | Path] = (),
                    videos: tuple[str, ...] = (), expected_bytes: int = 0) -> None:
        """The checks of :meth:`check` that need no job (the command makes them before it
        builds one): ``out`` against the inputs, its layout, the video and summary paths."""
        from arlight.output_guard import check_outputs
        from arlight.staged_output import check_output_dir

        out = Path(os.path.abspath(Path(out).expanduser()))
        inputs = [Path(p) for p in inputs]
        real = Path(os.path.realpath(out))
        for p in inputs:
            rp = Path(os.path.realpath(p))
            if rp == real:
                raise InputError(f"is the input {p}; the output would replace it (choose "
                                 "another output folder)", file=str(out), field="--out")
            if rp.is_dir() and real.is_relative_to(rp):
                raise InputError(f"lies inside the input folder {p}; the output would add "
                                 "files to it (choose a folder outside it)",
                                 file=str(out), field="--out")
        check_output_dir(out, KNOWN, expected_bytes, inputs=inputs)
        check_outputs({"--video": [out / f"sequence.{v}" for v in videos],
                       "summary": out / SUMMARY},
                      [p for p in inputs if not p.is_dir()], overwrite=restart,
                      overwrite_flag="--restart")
        _check_layout(out)

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
    def begin(self, restart: bool = False) -> dict[int, dict]:
        """The frames already done (none with ``restart``). Reads only: the folder is created
        — or, with ``restart``, emptied — when the first file is written
        (:meth:`_ensure_open`), so a run that fails before its first frame changes nothing."""
        self._restart = restart
        self._opened = False
        self.done = {} if restart else self._read_log()
        return dict(self.done)

    def open(self, restart: bool = False) -> dict[int, dict]:
        """Create or reopen the folder for this job now; returns the frames already done."""
        done = self.begin(restart)
        self._ensure_open()
        return done

    def _ensure_open(self) -> None:
        if self._opened:
            return
        if self._restart and self.out.is_dir():
            for name in os.listdir(self.out):  # only a sequence's own entries (checked)
                if name == HEADER or not any(fnmatch(name, g) for g in KNOWN):
                    continue
                p = self.out / name
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        self.out.mkdir(parents=True, exist_ok=True)
        header = {"format": FORMAT, "key": self.job.key, "parts": self.job.parts,
                  "frames": self.job.count, "method": self.job.method, "fps": self.job.fps}
        with atomic_write(self.out / HEADER, ".json") as tmp:  # first: the folder is ours
            tmp.write_text(json.dumps(header, indent=1), encoding="utf-8")
        (self.out / "frames").mkdir(exist_ok=True)
        for p in (self.out / "frames").glob(".*"):  # temporaries of a killed run
            with contextlib.suppress(OSError):
                p.unlink()
        # the log without torn lines or stale entries, so appends start on a clean line
        with atomic_write(self.out / LOG, ".jsonl") as tmp:
            tmp.write_text("".join(json.dumps(self.done[i]) + "\n" for i in sorted(self.done)),
                           encoding="utf-8")
        self._opened = True

    def write(self, res: FrameResult) -> dict:
        """Write one frame's files, then append its line to the log (durably)."""
        self._ensure_open()
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
        from arlight.output_guard import record_written
        from arlight.sequence.video import encode

        self._ensure_open()
        paths = [encode(self.out / f"sequence.{fmt}", self.frames_display(), self.job.fps)
                 for fmt in formats]
        record_written(paths)
        return paths

    def write_summary(self, summary: dict) -> Path:
        from arlight.output_guard import record_written

        self._ensure_open()
        with atomic_write(self.out / SUMMARY, ".json") as tmp:
            tmp.write_text(json.dumps(summary, indent=1), encoding="utf-8")
        record_written([self.out / SUMMARY])
        return self.out / SUMMARY


__all__ = ["FORMAT", "KNOWN", "SequenceStore", "frame_file"]
