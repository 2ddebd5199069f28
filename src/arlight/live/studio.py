"""The live loop shown in the studio's page, through the studio's own server.

:class:`LiveFeed` is a frame source with the interface the studio server drives
(:func:`arlight.studio.server.create_app`: ``open_session``, ``close_session``, ``info``,
``apply``, ``start``, ``stop``, ``width``, ``height``, ``max_sessions``, ``source``), so
``arlight live`` serves the same page behind the same access checks (:mod:`arlight.studio.
access`: Host and Origin checked, the launch's token required) without a second web
server. Each composited frame is encoded once (JPEG) and posted to every open tab in the
studio's binary frame format (:func:`arlight.studio.protocol.frame_message`); the server's
per-connection outbox keeps only the newest frame for a slow tab. The page's controls have
no effect on a live feed (the loop drives the frames): their messages are ignored.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

from arlight.live.loop import LiveFrame


@dataclass
class _Source:
    name: str


@dataclass
class LiveSession:
    """One open tab: how to post to it."""

    id: int
    post: Any
    closed: bool = False
    frames_sent: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


class LiveFeed:
    """A sink of the live loop and the studio server's frame source (module docstring)."""

    name = "show"

    def __init__(self, title: str, method: str, description: str, size: tuple[int, int],
                 quality: int = 85, max_sessions: int = 4, clock=None) -> None:
        self.source = _Source(title)
        self.method, self.description = method, description
        self.width, self.height = size
        self.quality = int(quality)
        self.max_sessions = int(max_sessions)
        self.clock = clock or time.perf_counter
        self._sessions: dict[int, LiveSession] = {}
        self._lock = threading.Lock()
        self._next = 1
        self.frames_posted = 0

    # -- the studio server's interface ---------------------------------------------------
    def info(self) -> dict[str, Any]:
        return {"type": "info", "width": self.width, "height": self.height,
                "scene": self.source.name, "live": True,
                "methods": [{"name": self.method, "description": self.description,
                             "progressive": False, "unsupported": None, "denoise": False}],
                "method": self.method, "objects": {}, "layers": ["composite"],
                "ground_truth": False, "format": "image/jpeg", "error_gain": 1.0}

    def start(self, timeout: float = 0.0) -> None:
        return None

    def stop(self) -> None:
        with self._lock:
            for s in self._sessions.values():
                s.closed = True
            self._sessions.clear()

    def open_session(self, post) -> LiveSession:
        from arlight.studio.engine import SessionLimit

        with self._lock:
            if len(self._sessions) >= self.max_sessions:
                raise SessionLimit(f"the live view already has {len(self._sessions)} open "
                                   f"tabs (at most {self.max_sessions})")
            s = LiveSession(self._next, post)
            self._next += 1
            self._sessions[s.id] = s
        return s

    def close_session(self, s: LiveSession) -> None:
        s.closed = True
        with self._lock:
            self._sessions.pop(s.id, None)

    def apply(self, s: LiveSession, msg: Any) -> None:
        """Client messages change nothing in a live feed (the loop drives the frames)."""
        return None

    # -- the loop's sink -------------------------------------------------------------------
    def show(self, frame: LiveFrame) -> None:
        """Encode the composite once and post it to every open tab (latest wins there)."""
        from arlight.studio.imaging import encode
        from arlight.studio.protocol import frame_message

        with self._lock:
            sessions = list(self._sessions.values())
        if not sessions:
            return
        codes = frame.display
        if codes.dtype != "uint8":
            codes = (codes >> 8).astype("uint8")
        data = encode(codes, "jpeg", self.quality)
        header = {"type": "frame", "seq": None, "method": self.method, "width": self.width,
                  "height": self.height, "factor": 1, "refine": 0, "objects": {},
                  "frame": frame.index, "tracked": frame.tracked,
                  "dropped": frame.dropped, "bytes": len(data),
                  "latency_ms": 1e3 * (self.clock() - frame.captured_at),
                  "stats": {k: float(v) for k, v in frame.timings.items()}}
        msg = frame_message(header, data)
        for s in sessions:
            if not s.closed:
                s.post("frame", msg)
                s.frames_sent += 1
        self.frames_posted += 1


__all__ = ["LiveFeed", "LiveSession"]
