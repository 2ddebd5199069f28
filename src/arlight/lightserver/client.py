"""The client side: subscribe to a light server and keep the latest light state.

:class:`LightClient` receives on one thread that owns its sockets (a SUB socket on the
server's publish endpoint, a DEALER socket on its snapshot endpoint); a :class:`ClientGroup`
serves many clients from one thread (one poll over all their sockets). Every message is
decoded and validated completely (:func:`arlight.lightserver.wire.decode`) before the
client's state — one immutable :class:`~arlight.nearfield.NearFieldLight` — is replaced by a
single reference assignment, so a renderer that reads :attr:`LightClient.latest` once per
frame never sees a half-applied update. Bad messages are counted and dropped.

Ordering, gaps and restarts:

- Updates with a sequence at or below the current one (same server epoch) are stale and
  dropped; a jump counts the skipped updates as ``gaps`` (the latest state is what matters).
- A heartbeat announcing a newer sequence than the client holds (an update was dropped by a
  high-water mark or conflation) triggers a snapshot request: the client ends on the latest
  state even when it missed the update itself.
- A new epoch (the server restarted) is accepted from its first message.
- No message for ``heartbeat_timeout`` seconds: the server is taken as lost; the client
  closes and reopens both sockets and asks for a snapshot, again every ``heartbeat_timeout``
  until the server answers (``reconnects`` counts the attempts). It never raises on this.

A sequence number a peer cannot poison (without CURVE anyone on the path can forge one):

- an update of the current epoch more than ``max_jump`` (2^20) beyond the current sequence
  is rejected (``rejected["jump"]``) and a snapshot is asked for; a snapshot reply may jump
  any distance (a client that was away for long);
- updates (or heartbeats) that stay stale for ``stale_limit`` messages or
  ``heartbeat_timeout`` seconds mean the client's sequence is ahead of the server's — a
  forged one: it asks for a snapshot and adopts it, epoch and sequence, even when it is
  "older" (``recoveries``).

With the server's public key (``server_public_key``) both sockets use CURVE: the client
talks to that server only, and everything it receives is authenticated and encrypted.
Both sockets refuse frames larger than :data:`~arlight.lightserver.wire.MAX_MESSAGE_BYTES`.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field, replace

import zmq

from arlight.errors import ArlightError, InputError
from arlight.lightserver import security, transport, wire
from arlight.nearfield.state import NearFieldLight

HISTORY = 100_000
"""Latencies kept (the latest ones)."""
MAX_SEQUENCE_JUMP = 1 << 20
"""Largest forward jump of the sequence an update may make (within an epoch) without a
snapshot confirming it: 16 hours of updates at 18 Hz."""
STALE_LIMIT = 8
"""Stale messages in a row after which the client re-synchronises by snapshot."""


@dataclass
class ClientStats:
    """Counters of a client (read a copy with :meth:`LightClient.stats`).

    ``latencies`` are publication → receipt seconds of the updates received on the
    subscription (header ``sent`` to the moment the decoded state was swapped in; the
    server and client clocks must agree, as on one machine).
    """

    received: int = 0
    applied: int = 0
    from_snapshot: int = 0
    heartbeats: int = 0
    stale: int = 0
    gaps: int = 0
    restarts: int = 0
    reconnects: int = 0
    snapshot_requests: int = 0
    recoveries: int = 0
    """Snapshots adopted over a sequence that had run ahead of the server's (forged)."""
    rejected: Counter = field(default_factory=Counter)
    bytes_received: int = 0
    latencies: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    last_version_seen: int | None = None

    @property
    def rejected_total(self) -> int:
        """Messages dropped as invalid (all reasons)."""
        return sum(self.rejected.values())


class LightClient:
    """Subscribe to a light server; :attr:`latest` is the newest valid state.

    Args:
        connect: the server's publish endpoint, e.g. ``tcp://127.0.0.1:5556``.
        snapshot: its snapshot endpoint (default: ``connect``'s port + 1).
        heartbeat_timeout: seconds without any message before the server counts as lost
            and the client reconnects (the server sends a heartbeat every 0.25 s by default).
        conflate: keep only the newest message in the receive queue (ZMQ_CONFLATE; for a
            client that reads slower than the server publishes).
        rcvhwm: receive queue length in messages (without ``conflate``).
        context: a ZeroMQ context to share (many clients in one process); default: own.
        server_public_key: the server's CURVE public key (Z85, 40 bytes): pins the server
            and turns CURVE on for both sockets.
        client_key: this client's key pair (the server may allow only known keys); default
            with ``server_public_key``: a fresh pair per client.
        insecure: allow a non-loopback server without ``server_public_key``.
        max_jump: see :data:`MAX_SEQUENCE_JUMP`; stale_limit: see :data:`STALE_LIMIT`.
    """

    def __init__(self, connect: str, snapshot: str | None = None, *,
                 heartbeat_timeout: float = 1.0, conflate: bool = False, rcvhwm: int = 64,
                 context: zmq.Context | None = None, server_public_key: bytes | None = None,
                 client_key: security.KeyPair | None = None, insecure: bool = False,
                 max_jump: int = MAX_SEQUENCE_JUMP, stale_limit: int = STALE_LIMIT):
        self.connect = transport.check_endpoint(connect, "--connect", bind=False)
        self.snapshot = transport.check_endpoint(
            snapshot or transport.next_port_endpoint(connect), "--snapshot", bind=False)
        if heartbeat_timeout <= 0:
            raise InputError("must be > 0 seconds", field="heartbeat_timeout")
        if client_key is not None and server_public_key is None:
            raise InputError("a client key needs the server's public key",
                             field="--server-public-key")
        if server_public_key is None and not insecure:
            for field_, ep in (("--connect", self.connect), ("--snapshot", self.snapshot)):
                if not security.is_loopback(ep):
                    raise InputError(f"{ep!r} is not on this machine: give the server's "
                                     "public key (--server-public-key) so that the light is "
                                     "authenticated, or pass --insecure", field=field_)
        if server_public_key is not None:
            if not security.has_curve():
                raise InputError("this libzmq has no CURVE support",
                                 field="--server-public-key")
            if client_key is None:
                client_key = security.KeyPair(*zmq.curve_keypair())
        self.server_public_key = server_public_key
        self.client_key = client_key
        self.max_jump = int(max_jump)
        self.stale_limit = int(stale_limit)
        self.heartbeat_timeout = float(heartbeat_timeout)
        self.conflate = conflate
        self.rcvhwm = int(rcvhwm)
        self._own_ctx = context is None
        self._ctx = context or zmq.Context()
        self._latest: NearFieldLight | None = None
        self._epoch: int | None = None
        self._stats = ClientStats()
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._group: ClientGroup | None = None
        self._sub: zmq.Socket | None = None
        self._snap: zmq.Socket | None = None
        self._last_heard = 0.0
        self._snap_asked = 0.0
        self._stale_run = 0
        self._stale_since = 0.0
        self._recover = False
        self.error: BaseException | None = None
        """An unexpected error that ended the receiver thread (None while healthy)."""

    # -- public API ----------------------------------------------------------------------

    @property
    def latest(self) -> NearFieldLight | None:
        """The newest valid light state (None before the first); read it once per frame."""
        return self._latest

    @property
    def epoch(self) -> int | None:
        """The epoch of the server the current state came from."""
        return self._epoch

    def start(self) -> LightClient:
        """Start receiving on a thread of its own (a :class:`ClientGroup` of one)."""
        self._group = ClientGroup([self]).start()
        return self

    def close(self, timeout: float = 5.0) -> None:
        """Stop receiving and release the sockets (and the context, when it is our own)."""
        if self._group is not None:
            self._group.close(timeout)
            self._group = None
        if self._own_ctx:
            self._ctx.destroy(linger=0)

    def __enter__(self) -> LightClient:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def stats(self) -> ClientStats:
        """A copy of the counters."""
        with self._lock:
            return replace(self._stats, rejected=Counter(self._stats.rejected),
                           latencies=deque(self._stats.latencies, maxlen=HISTORY))

    def wait_for(self, sequence: int = 1, timeout: float = 5.0,
                 epoch: int | None = None) -> NearFieldLight:
        """Block until a state with at least ``sequence`` (of ``epoch``, if given) is held.

        Raises :class:`WireVersionError` when nothing valid came but messages of another wire
        version did, and :class:`ArlightError` on timeout.
        """
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                cur = self._latest
                if cur is not None and cur.sequence >= sequence and (
                        epoch is None or self._epoch == epoch):
                    return cur
                if cur is None and self._stats.rejected.get("version"):
                    raise wire.WireVersionError(self._stats.last_version_seen or -1)
                if self.error is not None:
                    raise ArlightError(f"light client stopped: {self.error}")
                left = deadline - time.monotonic()
                if left <= 0:
                    have = "no state" if cur is None else f"update {cur.sequence}"
                    raise ArlightError(f"no light update {sequence} from {self.connect} "
                                       f"within {timeout:g} s (have {have})")
                self._changed.wait(min(left, 0.05))

    # -- receiver thread -----------------------------------------------------------------

    def _secure(self, sock: zmq.Socket) -> zmq.Socket:
        """Frame size cap and, with the server's key, CURVE (set before connecting)."""
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, wire.MAX_MESSAGE_BYTES + transport.FRAME_OVERHEAD)
        if self.server_public_key is not None:
            sock.setsockopt(zmq.CURVE_SERVERKEY, self.server_public_key)
            sock.setsockopt(zmq.CURVE_PUBLICKEY, self.client_key.public)
            sock.setsockopt(zmq.CURVE_SECRETKEY, self.client_key.secret)
        return sock

    def _open(self) -> tuple[zmq.Socket, zmq.Socket]:
        sub = self._secure(self._ctx.socket(zmq.SUB))
        if self.conflate:
            sub.setsockopt(zmq.CONFLATE, 1)
        else:
            sub.setsockopt(zmq.RCVHWM, self.rcvhwm)
        sub.setsockopt(zmq.SUBSCRIBE, b"")  # the only subscription a server applies
        transport.connect(sub, self.connect, "--connect")
        snap = self._secure(self._ctx.socket(zmq.DEALER))
        snap.setsockopt(zmq.SNDHWM, 1)
        snap.setsockopt(zmq.RCVHWM, 4)
        transport.connect(snap, self.snapshot, "--snapshot")
        return sub, snap

    def _request_snapshot(self, snap: zmq.Socket) -> None:
        try:
            snap.send(transport.SNAPSHOT_REQUEST, flags=zmq.NOBLOCK)
            with self._lock:
                self._stats.snapshot_requests += 1
        except zmq.Again:  # one request is already queued
            pass

    def _connect_sockets(self) -> list[zmq.Socket]:
        """Open both sockets and ask for a snapshot; returns the sockets to poll."""
        self._sub, self._snap = self._open()
        self._request_snapshot(self._snap)
        self._last_heard = time.monotonic()
        return [self._sub, self._snap]

    def _close_sockets(self) -> None:
        for s in (self._sub, self._snap):
            if s is not None:
                s.close(linger=0)
        self._sub = self._snap = None

    def _on_readable(self, sock: zmq.Socket) -> None:
        """Drain what ``sock`` (our SUB or DEALER) holds."""
        from_snapshot = sock is self._snap
        while True:
            try:
                msg = sock.recv(flags=zmq.NOBLOCK, copy=True)
            except zmq.Again:
                return
            self._last_heard = time.monotonic()
            if self._handle(msg, from_snapshot=from_snapshot) and (
                    self._last_heard - self._snap_asked > 0.1):
                self._request_snapshot(self._snap)
                self._snap_asked = self._last_heard

    def _note_stale(self) -> bool:
        """One more stale message (lock held); True when the client should re-synchronise
        by snapshot: ``stale_limit`` in a row, or stale for ``heartbeat_timeout`` seconds."""
        now = time.monotonic()
        if self._stale_run == 0:
            self._stale_since = now
        self._stale_run += 1
        if (self._stale_run >= self.stale_limit
                or now - self._stale_since >= self.heartbeat_timeout):
            self._recover = True  # the next snapshot reply is adopted whatever its sequence
        return self._recover

    def _lost(self, now: float) -> bool:
        """True when nothing came for ``heartbeat_timeout``: the server counts as lost."""
        return now - self._last_heard > self.heartbeat_timeout

    def _handle(self, msg: bytes, *, from_snapshot: bool) -> bool:
        """Decode and apply one message; True when a snapshot should be requested."""
        with self._lock:
            self._stats.received += 1
            self._stats.bytes_received += len(msg)
        try:
            header, light = wire.decode(msg)
        except wire.WireVersionError as exc:
            with self._lock:
                self._stats.rejected["version"] += 1
                self._stats.last_version_seen = exc.version
                self._changed.notify_all()
            return False
        except wire.WireError as exc:
            with self._lock:
                self._stats.rejected[exc.reason] += 1
            return False
        with self._changed:
            st = self._stats
            new_epoch = self._epoch is None or header.epoch != self._epoch
            cur = 0 if new_epoch or self._latest is None else self._latest.sequence
            if light is None:  # heartbeat (or an empty snapshot)
                if not from_snapshot:
                    st.heartbeats += 1
                    if not new_epoch and header.sequence < cur:  # we are ahead of the server
                        return self._note_stale()
                return header.sequence > cur
            adopt = from_snapshot and self._recover
            if not new_epoch and header.sequence <= cur and not adopt:
                if from_snapshot:  # an older snapshot reply is no disorder
                    return False
                st.stale += 1
                return self._note_stale()
            if (not new_epoch and not from_snapshot and cur > 0
                    and header.sequence - cur > self.max_jump):
                st.rejected["jump"] += 1  # confirmed only by a snapshot
                return True
            if adopt and not new_epoch and header.sequence <= cur:
                st.recoveries += 1
            if new_epoch and self._epoch is not None:
                st.restarts += 1
            elif not new_epoch and header.sequence > cur + 1 and cur > 0:
                st.gaps += header.sequence - cur - 1
            self._latest = light  # the atomic swap: a complete, validated, immutable state
            self._epoch = header.epoch
            self._stale_run = 0
            self._recover = False
            st.applied += 1
            if from_snapshot:
                st.from_snapshot += 1
            else:
                st.latencies.append(time.time() - header.sent)
            self._changed.notify_all()
        return False


class ClientGroup:
    """Several :class:`LightClient` s served by one receiver thread (one poll over all their
    sockets): how a process holds many subscriptions without a thread each (the load test's
    receivers). ``LightClient.start()`` is a group of one.
    """

    def __init__(self, clients: list[LightClient]):
        self.clients = list(clients)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> ClientGroup:
        self._thread = threading.Thread(target=self._run, name="lightclient", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def __enter__(self) -> ClientGroup:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # noqa: BLE001 - surfaced by wait_for / .error
            for c in self.clients:
                c.error = exc
                with c._changed:
                    c._changed.notify_all()
        finally:
            for c in self.clients:
                c._close_sockets()

    def _loop(self) -> None:
        poller = zmq.Poller()
        owner: dict[zmq.Socket, LightClient] = {}

        def attach(c: LightClient) -> None:
            for s in c._connect_sockets():
                poller.register(s, zmq.POLLIN)
                owner[s] = c

        for c in self.clients:
            attach(c)
        while not self._stop.is_set():
            for sock, _ in poller.poll(50):
                owner[sock]._on_readable(sock)
            now = time.monotonic()
            for c in self.clients:
                if c._lost(now):  # reopen both sockets, ask for a snapshot
                    for s in (c._sub, c._snap):
                        poller.unregister(s)
                        owner.pop(s, None)
                    c._close_sockets()
                    attach(c)
                    with c._lock:
                        c._stats.reconnects += 1
