"""ZeroMQ addresses and sockets shared by the light server and its clients.

The server publishes on a PUB socket (``--bind``) and answers snapshot requests on a ROUTER
socket (``--snapshot-bind``, by default the next port): the ZeroMQ "clone" pattern, so a
client that joins late gets the current state at once instead of waiting for the next
update. Addresses are ZeroMQ endpoints: ``tcp://HOST:PORT`` (``PORT`` may be ``*`` for an
ephemeral port when binding), ``ipc:///path`` or ``inproc://name``.
"""

from __future__ import annotations

import re

import zmq

from arlight.errors import InputError

SNAPSHOT_REQUEST = b"SNAP1"
"""The one request a snapshot socket understands; the reply is the latest update message
(or a heartbeat with sequence 0 while the server has none)."""

MAX_REQUEST_BYTES = 64
"""``ZMQ_MAXMSGSIZE`` of the server's sockets without CURVE: what a peer may send is a 5-byte
snapshot request (ROUTER) or a 1-byte subscription (PUB side). libzmq applies the cap to every
frame on the wire, from the frame header, before anything is allocated, and drops the
connection: a 64 MiB frame costs the server nothing, and a subscription topic — which libzmq
stores for the connection's lifetime — is at most this long."""
MAX_REQUEST_BYTES_CURVE = 384
"""The same with CURVE: the handshake's INITIATE command (≈ 300 bytes with its metadata) must
fit."""

FRAME_OVERHEAD = 256
"""Bytes a transport may add to a message frame (a CURVE MESSAGE command: 33 bytes): the
clients' cap is the largest legal light message plus this."""

_TCP = re.compile(r"^tcp://(?P<host>\[[^\]]+\]|[^:/\[\]]+):(?P<port>\*|\d+)$")


def check_endpoint(address: str, field: str, *, bind: bool) -> str:
    """Check a ZeroMQ endpoint's form (and TCP port range); returns it unchanged.

    Raises :class:`InputError` naming ``field`` (e.g. ``--bind``) for anything else.
    """
    if address.startswith(("ipc://", "inproc://")) and len(address.split("://", 1)[1]) > 0:
        return address
    m = _TCP.match(address)
    if not m:
        raise InputError(f"{address!r} is not a ZeroMQ endpoint (tcp://HOST:PORT, "
                         "ipc:///PATH or inproc://NAME)", field=field)
    port = m["port"]
    if port == "*":
        if not bind:
            raise InputError(f"{address!r}: a client needs the server's port, not '*'",
                             field=field)
        return address
    if not 1 <= int(port) <= 65535:
        raise InputError(f"{address!r}: port {port} is outside 1..65535", field=field)
    return address


def next_port_endpoint(address: str) -> str:
    """The default snapshot endpoint next to a publish endpoint: port + 1 for TCP
    (ephemeral stays ephemeral), ``-snapshot`` appended for ipc/inproc."""
    m = _TCP.match(address)
    if m is None:
        return address + "-snapshot"
    port = m["port"]
    new = "*" if port == "*" else str(int(port) + 1)
    return f"tcp://{m['host']}:{new}"


def bind(sock: zmq.Socket, address: str, field: str) -> str:
    """Bind ``sock`` and return the endpoint actually bound (the real port for ``*``)."""
    check_endpoint(address, field, bind=True)
    try:
        sock.bind(address)
    except zmq.ZMQError as exc:
        raise InputError(f"cannot bind {address!r}: {exc.strerror}", field=field) from exc
    return sock.getsockopt_string(zmq.LAST_ENDPOINT)


def connect(sock: zmq.Socket, address: str, field: str) -> None:
    """Connect ``sock`` (ZeroMQ connects lazily and retries on its own)."""
    check_endpoint(address, field, bind=False)
    try:
        sock.connect(address)
    except zmq.ZMQError as exc:
        raise InputError(f"cannot connect to {address!r}: {exc.strerror}",
                         field=field) from exc
