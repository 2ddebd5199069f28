"""The light server: produce near-field light states and broadcast them (Rohmer §4).

A *producer* (any callable ``frame index → NearFieldLight``: the radiance atlas → τ split →
VALs → SH pipeline on fisheye frames, a replay of recorded states, or the synthetic moving
light of :mod:`arlight.lightserver.producers`) runs on its own thread, paced at ``rate_hz``.
Each state gets the next sequence number and a timestamp, is packed once
(:func:`arlight.lightserver.wire.encode`) and handed to the I/O thread, which owns every
socket:

- PUB (``bind``): every update, stamped with its publication time; a heartbeat (header
  only, carrying the latest sequence) when no update went out for ``heartbeat_s``. PUB never
  blocks: a subscriber whose queue (``sndhwm`` messages) is full simply misses messages, so a
  slow client cannot stall the server or the other clients.
- ROUTER (``snapshot_bind``): answers a snapshot request with the latest update at once
  (late joiners, clients that noticed a gap or a restart).

A restarted server draws a new random ``epoch``; clients accept its sequence from scratch.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import zmq

from arlight.errors import ArlightError
from arlight.lightserver import transport, wire
from arlight.nearfield.state import NearFieldLight

HISTORY = 100_000
"""Timings kept per series (the latest ones; a long-running server does not grow)."""

Producer = Callable[[int], NearFieldLight]
"""Frame index (0, 1, 2, ...) → light state; sequence and timestamp are set by the server."""


@dataclass
class ServerStats:
    """Counters of a running or finished server (read with :meth:`LightServer.stats`)."""

    published: int = 0
    heartbeats: int = 0
    snapshots: int = 0
    bad_requests: int = 0
    bytes_last: int = 0
    bytes_total: int = 0
    produce_seconds: deque[float] = field(default_factory=lambda: deque(maxlen=HISTORY))
    publish_seconds: deque[float] = field(default_factory=lambda: deque(maxlen=HISTORY))
    started: float = 0.0
    stopped: float = 0.0


class LightServer:
    """Broadcast a stream of :class:`NearFieldLight` updates over ZeroMQ.

    Args:
        producer: frame index → NearFieldLight (called on the producer thread).
        bind: PUB endpoint, e.g. ``tcp://127.0.0.1:5556`` (``tcp://127.0.0.1:*`` picks a
            free port; see :attr:`endpoints`).
        snapshot_bind: ROUTER endpoint for snapshots; default: ``bind``'s port + 1.
        rate_hz: updates per second at most (0 = as fast as the producer). Rohmer's server
            reaches ≈ 18 Hz (digest §10, Table 1). A producer slower than that sets the pace;
            when it speeds up again the schedule restarts from now (no burst).
        heartbeat_s: a heartbeat goes out when no update was published for this long (s).
        count: stop after this many updates (None = never).
        duration: stop after this many seconds (None = never).
        sndhwm: per-subscriber send queue in messages; beyond it PUB drops for that
            subscriber only.
        epoch: server incarnation id (default: random).
    """

    def __init__(self, producer: Producer, *, bind: str = "tcp://127.0.0.1:5556",
                 snapshot_bind: str | None = None, rate_hz: float = 20.0,
                 heartbeat_s: float = 0.25, count: int | None = None,
                 duration: float | None = None, sndhwm: int = 16,
                 epoch: int | None = None):
        if rate_hz < 0 or heartbeat_s <= 0:
            raise ArlightError("LightServer: rate_hz must be >= 0 and heartbeat_s > 0")
        self.producer = producer
        self.rate_hz = float(rate_hz)
        self.heartbeat_s = float(heartbeat_s)
        self.count = count
        self.duration = duration
        self.epoch = int.from_bytes(os.urandom(4), "little") if epoch is None else int(epoch)
        self._ctx = zmq.Context()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._stats = ServerStats()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._inproc = f"inproc://lightserver-{id(self)}"
        try:
            self._pub = self._ctx.socket(zmq.PUB)
            self._pub.setsockopt(zmq.SNDHWM, int(sndhwm))
            self._pub.setsockopt(zmq.LINGER, 0)
            self._snap = self._ctx.socket(zmq.ROUTER)
            self._snap.setsockopt(zmq.LINGER, 0)
            self._snap.setsockopt(zmq.ROUTER_MANDATORY, 0)
            self._pull = self._ctx.socket(zmq.PAIR)
            self._pull.bind(self._inproc)
            pub_ep = transport.bind(self._pub, bind, "--bind")
            snap_addr = snapshot_bind or transport.next_port_endpoint(bind)
            snap_ep = transport.bind(self._snap, snap_addr, "--snapshot-bind")
        except BaseException:
            self._ctx.destroy(linger=0)
            raise
        self.endpoints = (pub_ep, snap_ep)
        """(publish, snapshot) endpoints actually bound."""
        self._latest: bytes | None = None

    # -- life cycle ----------------------------------------------------------------------

    def start(self) -> LightServer:
        """Start the producer and I/O threads; returns self."""
        self._stats.started = time.time()
        self._threads = [threading.Thread(target=self._io_loop, name="lightserver-io",
                                          daemon=True),
                         threading.Thread(target=self._produce_loop,
                                          name="lightserver-producer", daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def stop(self) -> None:
        """Ask both threads to stop (returns at once; :meth:`close` waits)."""
        self._stop.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the server stops by itself (count/duration/error) or :meth:`stop`;
        True when it stopped. Re-raises a producer error."""
        done = self._stop.wait(timeout)
        if self._error is not None:
            raise self._error
        return done

    def close(self, timeout: float = 5.0) -> None:
        """Stop, join the threads and release the sockets."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        self._stats.stopped = time.time()
        self._ctx.destroy(linger=0)

    def __enter__(self) -> LightServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self) -> ServerStats:
        """Start, block until done (or KeyboardInterrupt), close; returns the stats."""
        self.start()
        try:
            while not self.wait(0.2):
                pass
        finally:
            self.close()
        return self.stats()

    def stats(self) -> ServerStats:
        """A copy of the counters."""
        with self._lock:
            s = dataclasses.replace(self._stats)
            s.produce_seconds = deque(self._stats.produce_seconds, maxlen=HISTORY)
            s.publish_seconds = deque(self._stats.publish_seconds, maxlen=HISTORY)
        return s

    @property
    def latest_sequence(self) -> int:
        """Sequence number of the latest published update (0 before the first)."""
        with self._lock:
            return self._stats.published

    # -- threads -------------------------------------------------------------------------

    def _produce_loop(self) -> None:
        push = self._ctx.socket(zmq.PAIR)
        push.setsockopt(zmq.LINGER, 0)
        push.connect(self._inproc)
        period = 1.0 / self.rate_hz if self.rate_hz > 0 else 0.0
        start = time.monotonic()
        frame = 0
        try:
            while not self._stop.is_set():
                if self.count is not None and frame >= self.count:
                    break
                if self.duration is not None and time.monotonic() - start >= self.duration:
                    break
                due = start + frame * period
                wait = due - time.monotonic()
                if wait < -period:  # a slow producer: re-anchor, never burst to catch up
                    start -= wait
                elif wait > 0 and self._stop.wait(wait):
                    break
                t0 = time.perf_counter()
                light = self.producer(frame)
                light = dataclasses.replace(light, sequence=frame + 1, timestamp=time.time())
                msg = wire.encode(light, epoch=self.epoch)
                with self._lock:
                    self._stats.produce_seconds.append(time.perf_counter() - t0)
                push.send(msg, copy=False)
                frame += 1
            # let the I/O thread drain the last message before stopping
            push.send(b"")
        except BaseException as exc:  # noqa: BLE001 - reported by wait()
            self._error = exc
            self._stop.set()
        finally:
            push.close(linger=0)

    def _io_loop(self) -> None:
        poller = zmq.Poller()
        poller.register(self._pull, zmq.POLLIN)
        poller.register(self._snap, zmq.POLLIN)
        last_sent = time.monotonic()
        while not self._stop.is_set():
            timeout = max(0.0, last_sent + self.heartbeat_s - time.monotonic())
            events = dict(poller.poll(min(timeout, 0.1) * 1000.0))
            if self._pull in events:
                msg = self._pull.recv()
                if not msg:  # the producer is done
                    self._stop.set()
                    break
                t0 = time.perf_counter()
                out = wire.restamp(msg, time.time())
                self._pub.send(out, copy=False)
                last_sent = time.monotonic()
                with self._lock:
                    self._latest = out
                    self._stats.published += 1
                    self._stats.bytes_last = len(out)
                    self._stats.bytes_total += len(out)
                    self._stats.publish_seconds.append(time.perf_counter() - t0)
            if self._snap in events:
                self._answer_snapshot()
            if time.monotonic() - last_sent >= self.heartbeat_s:
                with self._lock:
                    seq = self._stats.published
                    self._stats.heartbeats += 1
                self._pub.send(wire.encode_heartbeat(seq, epoch=self.epoch, sent=time.time()))
                last_sent = time.monotonic()

    def _answer_snapshot(self) -> None:
        frames = self._snap.recv_multipart()
        if len(frames) != 2 or frames[1] != transport.SNAPSHOT_REQUEST:
            with self._lock:
                self._stats.bad_requests += 1
            return
        with self._lock:
            latest = self._latest
            self._stats.snapshots += 1
        reply = (wire.restamp(latest, time.time()) if latest is not None else
                 wire.encode_heartbeat(0, epoch=self.epoch, sent=time.time()))
        try:
            self._snap.send_multipart([frames[0], reply], flags=zmq.NOBLOCK)
        except zmq.Again:  # the requester's queue is full: it will ask again
            pass
