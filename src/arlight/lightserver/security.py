"""Who may talk to a light server: CURVE keys, loopback rules and the connection gate.

ZeroMQ's CURVE mechanism (CurveZMQ: Curve25519 key exchange, every message authenticated
and encrypted) protects both sockets of a server. The server holds a secret key; a client
*pins* the server's public key (a peer that does not know it cannot even finish the
handshake, and a client talks to no other server) and brings a key pair of its own, which the
server may check against a folder of allowed public keys (``--allow-clients``).

- :func:`keygen` writes key pairs in pyzmq's certificate format
  (:func:`zmq.auth.create_certificates`: ``NAME.key`` public, ``NAME.key_secret`` secret,
  mode 0600), never over existing files.
- :func:`load_secret` / :func:`load_public` read them, naming the option at fault.
- :func:`check_exposure`: a server bound off loopback needs keys (or an explicit
  ``insecure``); wildcard binds get a warning line.
- :class:`Gate`: the ZAP handler every connection to the server's sockets passes, with or
  without CURVE: it applies the key allow-list and the bound on connections admitted at
  once per socket (``max_clients``), counting the handshakes it admits; a slot is freed
  when the socket monitor (read by the gate itself) reports that connection's disconnect.

See docs/lightserver.md, "Threat model and defaults".
"""

from __future__ import annotations

import ipaddress
import os
import re
import shutil
import stat
import struct
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import zmq
import zmq.auth
import zmq.utils.z85

from arlight.errors import ArlightError, InputError

ZAP_DOMAINS = {"pub": b"arlight-light-pub", "snapshot": b"arlight-light-snapshot"}
"""The ZAP domain of each server socket: the gate counts peers per socket."""

_TCP_HOST = re.compile(r"^tcp://(?P<host>\[[^\]]+\]|[^:/\[\]]+):")
WILDCARD_HOSTS = ("*", "0.0.0.0", "::", "[::]")


def has_curve() -> bool:
    """True when this libzmq was built with CURVE (libsodium or tweetnacl)."""
    return bool(zmq.has("curve"))


def endpoint_host(endpoint: str) -> str | None:
    """The host part of a ``tcp://`` endpoint (None for ipc/inproc)."""
    m = _TCP_HOST.match(endpoint)
    return None if m is None else m["host"]


def is_loopback(endpoint: str) -> bool:
    """True for ``ipc://``/``inproc://`` endpoints and TCP on 127.0.0.0/8, ::1 or localhost.

    Anything else — another address, a host or interface name, a wildcard — counts as
    reachable from other machines.
    """
    host = endpoint_host(endpoint)
    if host is None:
        return endpoint.startswith(("ipc://", "inproc://"))
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_wildcard(endpoint: str) -> bool:
    """True for a TCP bind on every interface (``*``, ``0.0.0.0``, ``::``)."""
    return endpoint_host(endpoint) in WILDCARD_HOSTS


def check_exposure(endpoints: dict[str, str], secure: bool, insecure: bool) -> list[str]:
    """Refuse a non-loopback bind without CURVE keys unless ``insecure``; return warnings.

    ``endpoints``: option name → endpoint (e.g. ``{"--bind": ..., "--snapshot-bind": ...}``).
    Raises :class:`InputError` naming the first exposed option; returns the warning lines
    (wildcard binds, ``insecure`` off loopback) for the caller to print.
    """
    warnings = []
    exposed = [(f, e) for f, e in endpoints.items() if not is_loopback(e)]
    if exposed and not secure and not insecure:
        field, ep = exposed[0]
        raise InputError(f"{ep!r} is reachable from other machines and the light server has "
                         "no CURVE keys: give --server-key (arlight serve-light --keygen DIR "
                         "makes one) or pass --insecure to serve unauthenticated", field=field)
    for field, ep in exposed:
        if not secure:
            warnings.append(f"{field} {ep}: serving WITHOUT authentication or encryption "
                            "(--insecure): anyone who can reach this address can read the "
                            "light and send to the server")
        elif is_wildcard(ep):
            warnings.append(f"{field} {ep}: binding every interface; any host that can reach "
                            "it can connect (only peers that hold the server's public key get "
                            "through the CURVE handshake)")
    return warnings


# -- keys ------------------------------------------------------------------------------------

KEY_NAMES = ("server", "client")


def keygen(folder: Path, names: tuple[str, ...] = KEY_NAMES) -> list[Path]:
    """Write a CURVE key pair per name into ``folder`` (created if missing): ``NAME.key``
    (public) and ``NAME.key_secret`` (secret, mode 0600). Existing key files are never
    overwritten (InputError naming ``--keygen``); returns the files written."""
    folder = Path(folder)
    targets = [folder / f"{n}{suffix}" for n in names for suffix in (".key", ".key_secret")]
    clash = [p for p in targets if p.exists() or p.is_symlink()]
    if clash:
        raise InputError(f"{clash[0].name} already exists; keys are never overwritten "
                         "(choose another folder or remove the old keys yourself)",
                         file=str(folder), field="--keygen")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".keygen-", dir=folder))  # mode 0700
    except OSError as exc:
        raise InputError(f"cannot create the key folder: {exc.strerror}", file=str(folder),
                         field="--keygen") from exc
    written: list[Path] = []
    try:
        for n in names:
            pub, sec = (Path(p) for p in zmq.auth.create_certificates(staging, n))
            os.chmod(sec, 0o600)
            os.chmod(pub, 0o644)
            for src in (pub, sec):
                dst = folder / src.name
                os.link(src, dst)  # fails if dst appeared meanwhile: never overwrite
                written.append(dst)
    except OSError as exc:
        for p in written:
            p.unlink(missing_ok=True)
        raise InputError(f"cannot write keys: {exc.strerror}", file=str(folder),
                         field="--keygen") from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return written


@dataclass(frozen=True)
class KeyPair:
    """A CURVE key pair, Z85 text as bytes (40 characters each)."""

    public: bytes
    secret: bytes


def _load(path: Path, field: str) -> tuple[bytes, bytes | None]:
    path = Path(path)
    if not path.is_file():
        raise InputError("no such key file", file=str(path), field=field)
    try:
        if path.stat().st_size > 64 * 1024:
            raise ValueError("too large for a key file")
        public, secret = zmq.auth.load_certificate(path)
        for key in (public, secret):
            if key is not None:
                zmq.utils.z85.decode(key)
                if len(key) != 40:
                    raise ValueError("a CURVE key is 40 Z85 characters")
    except (OSError, ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise InputError(f"not a CURVE key file (write one with arlight serve-light --keygen "
                         f"DIR): {exc}", file=str(path), field=field) from exc
    return public, secret


def load_secret(path: Path, field: str) -> KeyPair:
    """A key pair from a ``.key_secret`` file (InputError naming ``field`` otherwise)."""
    public, secret = _load(path, field)
    if secret is None:
        raise InputError("holds no secret key (give the .key_secret file)", file=str(path),
                         field=field)
    mode = stat.S_IMODE(Path(path).stat().st_mode)
    if mode & 0o077:
        raise InputError(f"secret key readable by others (mode {mode:04o}); chmod 600 it",
                         file=str(path), field=field)
    return KeyPair(public, secret)


def load_public(path: Path, field: str) -> bytes:
    """The public key of a ``.key`` (or ``.key_secret``) file."""
    return _load(path, field)[0]


def load_allowed(folder: Path, field: str = "--allow-clients") -> dict[bytes, bool]:
    """Public keys (``*.key``) in ``folder``; refuses a folder without any."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder of client public keys", file=str(folder), field=field)
    keys = {}
    for p in sorted(folder.glob("*.key")):
        keys[load_public(p, field)] = True
    if not keys:
        raise InputError("no client public keys (*.key) in the folder", file=str(folder),
                         field=field)
    return keys


# -- the gate --------------------------------------------------------------------------------

ZAP_ENDPOINT = "inproc://zeromq.zap.01"
"""Where libzmq sends the ZAP requests of a context's sockets (RFC 27)."""
_FD = getattr(zmq, "SRCFD", 2)
"""``zmq_msg_get`` property: the file descriptor a message was read from."""


@dataclass
class _Slots:
    """The gate's view of one server socket (``Gate`` holds its lock around every use).

    ``open``: connections the socket monitor reported accepted and not yet disconnected
    (fd → the number of the ACCEPTED event, counted per socket); ``linked``: open
    connections known to hold a slot (fd → the token the handshake got); ``floating``:
    admitted handshakes not (yet) tied to a connection (token → the ACCEPTED count when
    it was admitted), oldest first.
    """

    monitor: zmq.Socket
    accepted: int = 0
    open: dict[int, int] = field(default_factory=dict)
    linked: dict[int, str] = field(default_factory=dict)
    floating: OrderedDict[str, int] = field(default_factory=OrderedDict)

    def held(self) -> int:
        return len(self.linked) + len(self.floating)

    def event(self, event: int, fd: int) -> None:
        """A monitor event of the socket (in the order libzmq emitted them)."""
        if event == zmq.EVENT_ACCEPTED:
            self.accepted += 1
            self.linked.pop(fd, None)  # a reused fd: that connection is gone
            self.open[fd] = self.accepted
        elif event == zmq.EVENT_DISCONNECTED:
            self.open.pop(fd, None)
            self.linked.pop(fd, None)

    def clamp(self) -> None:
        """An admitted connection not linked is an open connection not linked: at most as
        many floating slots as such connections (the oldest tokens go)."""
        while len(self.floating) > len(self.open) - len(self.linked):
            self.floating.popitem(last=False)


class Gate:
    """ZAP handler of a light server: the CURVE allow-list and at most ``max_clients``
    connections admitted at once on each server socket.

    The handler is the authority that admits, so it counts *admitted handshakes*: every
    ``200`` reply takes a slot of its socket and names it with a token (the reply's
    User-Id, which libzmq attaches to every message of that connection). A slot is freed
    by the disconnect of its connection, which the gate learns from a socket monitor it
    reads itself; the two are tied when the server's I/O thread sees the first message of
    the connection (:meth:`note`: its User-Id and the fd it came from). Until then the
    slot *floats*: it is freed once fewer connections that are not tied remain open than
    slots float. Every count can only be late in one direction: a slot is held until the
    disconnect event has been read (a little longer than the connection), never given
    back early, so the bound is exact.

    Why the ordering holds: before each decision the handler reads every pending monitor
    event, and libzmq emits a connection's ACCEPTED event before its handshake starts
    (one I/O thread: the listener queues the connection before it runs), so the
    connection being decided is already in the handler's view.

    Args:
        context: the server's ZeroMQ context (one I/O thread; the handler binds
            ``inproc://zeromq.zap.01``: one gate per context).
        max_clients: connections admitted at once per socket; beyond it a handshake is
            refused (``400``; the peer's libzmq reconnects and asks again).
        sockets: ZAP domain → the server socket of that domain (not bound yet; the gate
            must run before any of them binds, or connections would skip it).

    CURVE keys are set with :meth:`configure` before :meth:`start`.
    """

    def __init__(self, context: zmq.Context, max_clients: int,
                 sockets: dict[bytes, zmq.Socket]):
        if context.get(zmq.IO_THREADS) != 1:
            raise ArlightError("Gate: the context must have one I/O thread (the monitor "
                               "events would not precede the handshakes)")
        self.max_clients = int(max_clients)
        self.refused: dict[str, int] = {"full": 0, "key": 0, "other": 0}
        self._lock = threading.Lock()
        self._curve = False
        self._allowed: dict[bytes, bool] | None = None
        self._tokens = 0
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._slots: dict[bytes, _Slots] = {}
        self._own: list[zmq.Socket] = []
        try:
            for domain, sock in sockets.items():
                addr = f"inproc://arlight-gate-{id(self)}-{len(self._slots)}"
                sock.monitor(addr, zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED)
                mon = self._socket(context, zmq.PAIR)
                mon.setsockopt(zmq.RCVHWM, 0)  # never drop a connection event
                mon.connect(addr)
                self._slots[domain] = _Slots(mon)
            self._zap = self._socket(context, zmq.REP)
            self._zap.bind(ZAP_ENDPOINT)
            self._control = self._socket(context, zmq.PAIR)
            self._control.bind(f"inproc://arlight-gate-{id(self)}-control")
            self._control_peer = self._socket(context, zmq.PAIR)
            self._control_peer.connect(f"inproc://arlight-gate-{id(self)}-control")
        except BaseException:
            self._close()
            raise

    def _socket(self, context: zmq.Context, kind: int) -> zmq.Socket:
        sock = context.socket(kind)
        sock.setsockopt(zmq.LINGER, 0)
        self._own.append(sock)
        return sock

    def configure(self, allowed: dict[bytes, bool] | None) -> None:
        """Connections use CURVE: accept any client key (None) or only ``allowed``
        (Z85 public keys)."""
        with self._lock:
            self._curve = True
            self._allowed = None if allowed is None else dict(allowed)

    # -- life cycle ----------------------------------------------------------------------

    def start(self) -> None:
        """Answer ZAP requests and read the monitors on a thread of the gate's own."""
        self._thread = threading.Thread(target=self._run, name="lightserver-gate",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and close the gate's sockets (the server sockets stay)."""
        if self._thread is not None:
            self._control_peer.send(b"STOP")
            self._thread.join(10)
            self._thread = None
        self._close()

    def _close(self) -> None:
        for sock in self._own:
            sock.close(linger=0)
        self._own = []

    def _run(self) -> None:
        poller = zmq.Poller()
        for sock in (self._control, self._zap, *(s.monitor for s in self._slots.values())):
            poller.register(sock, zmq.POLLIN)
        try:
            while True:
                ready = dict(poller.poll())
                if self._control in ready:
                    return
                with self._lock:
                    self._drain()
                for _ in range(1000):
                    try:
                        request = self._zap.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    with self._lock:
                        self._drain()  # this connection's ACCEPTED is among them
                        reply = self._decide(request)
                    self._zap.send_multipart(reply)
        except zmq.ContextTerminated:
            pass
        except BaseException as exc:  # noqa: BLE001 - no ZAP answers from here on: closed
            self._error = exc

    # -- bookkeeping (under the lock) ----------------------------------------------------

    def _drain(self) -> None:
        for slots in self._slots.values():
            while True:
                try:
                    event, value = _parse_event(slots.monitor.recv_multipart(zmq.NOBLOCK))
                except zmq.Again:
                    break
                slots.event(event, value)
            slots.clamp()

    def _decide(self, request: list[bytes]) -> list[bytes]:
        if len(request) < 6 or request[0] != b"1.0":
            self.refused["other"] += 1
            return [b"1.0", request[1] if len(request) > 1 else b"", b"400",
                    b"malformed request", b"", b""]
        request_id, domain, mechanism, credentials = (request[1], request[2], request[5],
                                                      request[6:])

        def refuse(why: str, text: bytes) -> list[bytes]:
            self.refused[why] += 1
            return [b"1.0", request_id, b"400", text, b"", b""]

        slots = self._slots.get(domain)
        if slots is None:
            return refuse("other", b"unknown ZAP domain")
        if self._curve:
            if mechanism != b"CURVE" or len(credentials) != 1 or len(credentials[0]) != 32:
                return refuse("other", b"CURVE required")
            if self._allowed is not None and not self._allowed.get(
                    zmq.utils.z85.encode(credentials[0])):
                return refuse("key", b"client key not allowed")
        elif mechanism != b"NULL":
            return refuse("other", b"unexpected mechanism")
        if slots.held() >= self.max_clients:
            return refuse("full", b"too many clients")
        self._tokens += 1
        token = str(self._tokens)
        slots.floating[token] = slots.accepted
        # the connection may have gone while its request waited (its DISCONNECTED already
        # read: no later event would free the slot)
        slots.clamp()
        return [b"1.0", request_id, b"200", b"OK", token.encode(), b""]

    # -- from the server's I/O thread ----------------------------------------------------

    def note(self, domain: bytes, frame: zmq.Frame) -> None:
        """Tie a floating slot to its connection, from a message of that connection
        (received with ``copy=False``: its User-Id and source fd). Both properties are
        libzmq's: a peer's own ZMTP metadata cannot replace them (libzmq keeps the first
        value of a name, and sets these before the peer's)."""
        try:
            token = frame.get("User-Id")
        except zmq.ZMQError:  # no handshake through the gate (inproc)
            return
        with self._lock:
            slots = self._slots.get(domain)
            if slots is None or token not in slots.floating:
                return
            try:
                fd = frame.get(_FD)
            except zmq.ZMQError:
                return
            # the fd's open connection was open when the token was admitted: it is the
            # token's (one connection per fd at a time); a later one reuses the fd
            accepted = slots.open.get(fd)
            if accepted is None or accepted > slots.floating[token] or fd in slots.linked:
                return
            slots.linked[fd] = token
            del slots.floating[token]

    def held(self, domain: bytes) -> int:
        """Slots taken on the socket of ``domain``: admitted connections, counted until
        their disconnect has been seen."""
        with self._lock:
            return self._slots[domain].held()


def _parse_event(msg: list[bytes]) -> tuple[int, int]:
    """(event, value) of a socket monitor message (libzmq's v1 format)."""
    if len(msg) != 2 or len(msg[0]) != 6:
        return 0, 0
    event, value = struct.unpack("=Hi", msg[0])
    return event, value


__all__ = ["Gate", "KeyPair", "ZAP_DOMAINS", "ZAP_ENDPOINT", "check_exposure",
           "endpoint_host", "has_curve", "is_loopback", "is_wildcard", "keygen",
           "load_allowed", "load_public", "load_secret"]
