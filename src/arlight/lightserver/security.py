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
- :class:`Gate`: the ZAP handler (a :class:`zmq.auth.thread.ThreadAuthenticator`) every
  connection to the server's sockets passes, with or without CURVE: it applies the key
  allow-list and the bound on connected peers per socket (``max_clients``). The server's I/O
  thread counts connections from socket monitor events (:meth:`Gate.on_monitor_event`).

See docs/lightserver.md, "Threat model and defaults".
"""

from __future__ import annotations

import ipaddress
import os
import re
import shutil
import stat
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from arlight.errors import InputError

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

class Gate(ThreadAuthenticator):
    """ZAP handler of a light server: CURVE allow-list plus at most ``max_clients`` peers
    connected to each socket (counted from monitor events by the server's I/O thread).

    Args:
        context: the server's ZeroMQ context (the handler binds ``inproc://zeromq.zap.01``).
        max_clients: peers per socket; beyond it a handshake is refused (the peer retries).

    CURVE keys are set with :meth:`configure`.
    """

    def __init__(self, context: zmq.Context, max_clients: int):
        super().__init__(context)
        self.max_clients = int(max_clients)
        self._peers: dict[bytes, set[int]] = {d: set() for d in ZAP_DOMAINS.values()}
        self._peer_lock = threading.Lock()
        self.refused: dict[str, int] = {"full": 0, "key": 0}

    def configure(self, allowed: dict[bytes, bool] | None) -> None:
        """Accept any CURVE client key (None) or only ``allowed``."""
        if allowed is None:
            self.configure_curve(domain="*", location=zmq.auth.CURVE_ALLOW_ANY)
        else:  # pyzmq looks keys up per ZAP domain
            for domain in ZAP_DOMAINS.values():
                self.certs[domain.decode()] = dict(allowed)

    def on_monitor_event(self, domain: bytes, event: int, fd: int) -> None:
        """A connection accepted (+1) or closed (−1) on the socket of ``domain``."""
        with self._peer_lock:
            peers = self._peers[domain]
            if event == zmq.EVENT_ACCEPTED:
                peers.add(fd)
            elif event in (zmq.EVENT_DISCONNECTED, zmq.EVENT_CLOSED):
                peers.discard(fd)

    def peers(self, domain: bytes) -> int:
        """Connections currently open on the socket of ``domain``."""
        with self._peer_lock:
            return len(self._peers[domain])

    async def handle_zap_message(self, msg: list[bytes]) -> None:
        if len(msg) >= 6 and msg[2] in self._peers:
            # the connection being checked is already counted (accepted before its handshake)
            if self.peers(msg[2]) > self.max_clients:
                self.refused["full"] += 1
                self._send_zap_reply(msg[1], b"400", b"too many clients")
                return
        certs = self.certs.get(msg[2].decode(errors="replace")) if len(msg) >= 7 else None
        if certs is not None and msg[5] == b"CURVE" and not self.allow_any:
            if not certs.get(zmq.utils.z85.encode(msg[6])):
                self.refused["key"] += 1
        await super().handle_zap_message(msg)


__all__ = ["Gate", "KeyPair", "ZAP_DOMAINS", "check_exposure", "endpoint_host", "has_curve",
           "is_loopback", "is_wildcard", "keygen", "load_allowed", "load_public",
           "load_secret"]
