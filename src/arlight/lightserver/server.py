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

Exposure (docs/lightserver.md, "Threat model and defaults"): with a CURVE key pair
(``curve``) both sockets authenticate and encrypt every connection, optionally only for
allowed client keys (``allow_clients``); off loopback the server refuses to start without
keys unless ``insecure``. Every connection passes the :class:`~.security.Gate` (at most
``max_clients`` connections admitted at once per socket); every inbound frame is capped at
:data:`~.transport.MAX_REQUEST_BYTES` (so is every subscription topic, which libzmq keeps
per connection); the publish socket is an XPUB in manual mode that applies only the empty
subscription (a topic never selects anything);
snapshot requests are answered at most once per ``snapshot_interval`` per peer.
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field

import zmq

from arlight.errors import ArlightError
from arlight.lightserver import security, transport, wire
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
    snapshots_limited: int = 0
    """Snapshot requests dropped by the per-peer rate limit."""
    subscriptions: int = 0
    """Empty-topic subscriptions applied (one per subscribing connection)."""
    bad_subscriptions: int = 0
    """Subscriptions to a non-empty topic (ignored; clients subscribe to everything)."""
    bytes_last: int = 0
    bytes_total: int = 0
    produce_seconds: deque[float] = field(default_factory=lambda: deque(maxlen=HISTORY))
    publish_seconds: deque[float] = field(default_factory=lambda: deque(maxlen=HISTORY))
    started: float = 0.0
    stopped: float = 0.0
    refused: dict = field(default_factory=dict)
    """Connections the gate refused: ``full`` (max_clients reached), ``key`` (CURVE key not
    allowed), ``other`` (a mechanism or ZAP domain the server does not use)."""
    clients: dict = field(default_factory=dict)
    """Slots the gate holds per socket (``pub``, ``snapshot``): connections admitted and not
    yet seen to disconnect; never more than ``max_clients``."""


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
        curve: the server's CURVE key pair (:func:`~.security.load_secret`): both sockets
            authenticate and encrypt; clients must pin its public key.
        allow_clients: with ``curve``, the client public keys (Z85) allowed (None: any key).
        insecure: allow a non-loopback bind without ``curve`` (otherwise InputError).
        max_clients: connections per socket the gate lets through at once.
        snapshot_interval: a peer's snapshot requests are answered at most once per this
            many seconds (the rest are dropped; a client asks again).
    """

    def __init__(self, producer: Producer, *, bind: str = "tcp://127.0.0.1:5556",
                 snapshot_bind: str | None = None, rate_hz: float = 20.0,
                 heartbeat_s: float = 0.25, count: int | None = None,
                 duration: float | None = None, sndhwm: int = 16,
                 epoch: int | None = None, curve: security.KeyPair | None = None,
                 allow_clients: dict[bytes, bool] | None = None, insecure: bool = False,
                 max_clients: int = 256, snapshot_interval: float = 0.05):
        if rate_hz < 0 or heartbeat_s <= 0:
            raise ArlightError("LightServer: rate_hz must be >= 0 and heartbeat_s > 0")
        if max_clients < 1 or snapshot_interval < 0 or sndhwm < 1:
            raise ArlightError("LightServer: max_clients >= 1, sndhwm >= 1 and "
                               "snapshot_interval >= 0 required")
        if allow_clients is not None and curve is None:
            raise ArlightError("LightServer: allow_clients needs curve keys")
        if curve is not None and not security.has_curve():
            raise ArlightError("this libzmq has no CURVE support (pyzmq wheels have it)")
        snap_addr = snapshot_bind or transport.next_port_endpoint(bind)
        transport.check_endpoint(bind, "--bind", bind=True)
        transport.check_endpoint(snap_addr, "--snapshot-bind", bind=True)
        self.warnings = security.check_exposure({"--bind": bind, "--snapshot-bind": snap_addr},
                                                curve is not None, insecure)
        """Lines the caller should show (wildcard or unauthenticated exposure)."""
        self.curve = curve
        self.max_clients = int(max_clients)
        self.snapshot_interval = float(snapshot_interval)
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
        self._gate: security.Gate | None = None
        self._snap_seen: OrderedDict[bytes, float] = OrderedDict()
        try:
            self._pub = self._ctx.socket(zmq.XPUB)
            self._pub.setsockopt(zmq.XPUB_MANUAL, 1)  # we decide which subscriptions apply
            self._pub.setsockopt(zmq.SNDHWM, int(sndhwm))
            self._snap = self._ctx.socket(zmq.ROUTER)
            self._snap.setsockopt(zmq.ROUTER_MANDATORY, 0)
            self._snap.setsockopt(zmq.SNDHWM, 4)  # replies queued per peer (then dropped)
            self._snap.setsockopt(zmq.RCVHWM, 64)
            for sock, name in ((self._pub, "pub"), (self._snap, "snapshot")):
                sock.setsockopt(zmq.LINGER, 0)
                sock.setsockopt(zmq.MAXMSGSIZE, transport.MAX_REQUEST_BYTES_CURVE if curve
                                else transport.MAX_REQUEST_BYTES)
                sock.setsockopt(zmq.ZAP_DOMAIN, security.ZAP_DOMAINS[name])
                if curve is not None:
                    sock.setsockopt(zmq.CURVE_SERVER, 1)
                    sock.setsockopt(zmq.CURVE_PUBLICKEY, curve.public)
                    sock.setsockopt(zmq.CURVE_SECRETKEY, curve.secret)
            # the gate (ZAP handler) must listen before any socket binds
            self._gate = security.Gate(self._ctx, self.max_clients, {
                security.ZAP_DOMAINS["pub"]: self._pub,
                security.ZAP_DOMAINS["snapshot"]: self._snap})
            if curve is not None:
                self._gate.configure(allow_clients)
            self._gate.start()
            self._pull = self._ctx.socket(zmq.PAIR)
            self._pull.bind(self._inproc)
            pub_ep = transport.bind(self._pub, bind, "--bind")
            snap_ep = transport.bind(self._snap, snap_addr, "--snapshot-bind")
        except BaseException:
            self._shutdown()
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
        self._shutdown()

    def _shutdown(self) -> None:
        if self._gate is not None:
            self._gate.stop()
            self._gate = None
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
            if self._gate is not None:
                s.refused = dict(self._gate.refused)
                s.clients = {name: self._gate.held(domain)
                             for name, domain in security.ZAP_DOMAINS.items()}
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
        poller.register(self._pub, zmq.POLLIN)  # subscriptions (XPUB)
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
            if self._pub in events:
                self._read_subscriptions()
            if time.monotonic() - last_sent >= self.heartbeat_s:
                with self._lock:
                    seq = self._stats.published
                    self._stats.heartbeats += 1
                self._pub.send(wire.encode_heartbeat(seq, epoch=self.epoch, sent=time.time()))
                last_sent = time.monotonic()

    def _read_subscriptions(self) -> None:
        """Apply empty-topic subscriptions (the only kind a client makes), ignore the rest
        (XPUB_MANUAL: nothing is stored for them); unsubscriptions are ignored."""
        for _ in range(10_000):  # bounded per pass: updates and heartbeats go on
            try:
                frame = self._pub.recv(flags=zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            self._note(security.ZAP_DOMAINS["pub"], frame)
            msg = frame.bytes
            if msg == b"\x01":
                self._pub.setsockopt(zmq.SUBSCRIBE, b"")  # for the peer that just sent it
                with self._lock:
                    self._stats.subscriptions += 1
            elif msg[:1] == b"\x01":
                with self._lock:
                    self._stats.bad_subscriptions += 1

    def _recv_request(self) -> list[bytes] | None:
        """One request from the ROUTER: at most 3 frames kept (the rest read and dropped;
        each frame is at most MAX_REQUEST_BYTES)."""
        try:
            frames = [self._snap.recv(flags=zmq.NOBLOCK)]  # the peer's routing id
        except zmq.Again:
            return None
        while self._snap.getsockopt(zmq.RCVMORE):
            part = self._snap.recv(copy=False)  # the whole message is already here
            if len(frames) == 1:
                self._note(security.ZAP_DOMAINS["snapshot"], part)
            if len(frames) < 3:
                frames.append(part.bytes)
        return frames

    def _note(self, domain: bytes, frame: zmq.Frame) -> None:
        """Show the gate a message: it ties the connection to its slot (User-Id, fd)."""
        gate = self._gate
        if gate is not None:
            gate.note(domain, frame)

    def _answer_snapshot(self) -> None:
        for _ in range(1000):
            frames = self._recv_request()
            if frames is None:
                return
            self._answer_one(frames)

    def _answer_one(self, frames: list[bytes]) -> None:
        if len(frames) != 2 or frames[1] != transport.SNAPSHOT_REQUEST:
            with self._lock:
                self._stats.bad_requests += 1
            return
        now = time.monotonic()
        last = self._snap_seen.pop(frames[0], None)
        self._snap_seen[frames[0]] = now if last is None or (
            now - last >= self.snapshot_interval) else last
        while len(self._snap_seen) > 4 * self.max_clients + 16:  # bounded: oldest peers go
            self._snap_seen.popitem(last=False)
        if last is not None and now - last < self.snapshot_interval:
            with self._lock:
                self._stats.snapshots_limited += 1
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
