"""Who may talk to the studio: the per-launch token and the Host and Origin rules.

The studio is a local server that moves objects and writes files, and a browser runs
pages from every site the user visits. Three checks, made on every request before any
engine work, keep those pages out (``docs/studio.md``, "Threat model and defaults"):

* **Token.** A random token per launch (:func:`new_token`: ``secrets.token_urlsafe(32)``,
  or one the user sets with ``--token`` / ``ARLIGHT_STUDIO_TOKEN``) must be given as the
  ``token`` query parameter of the page (``/?token=...``, the URL the studio prints) and of
  the WebSocket (``/ws?token=...``, which the page adds). Compared with
  :func:`hmac.compare_digest`. Only the two static assets (``/static/studio.js``,
  ``/static/studio.css``: the public code of the page, no secret) are served without it.
* **Host** (DNS rebinding): the ``Host`` header must name the served address — the bound
  host and port, and for a loopback bind also ``localhost``, ``127.0.0.1`` and ``[::1]``
  with that port. For a bind to all interfaces (``0.0.0.0``, ``::``): any IP literal
  (an IP cannot be rebound), ``localhost`` and this machine's host names, with the port.
  A hostname an attacker controls never matches.
* **Origin**: a request that carries an ``Origin`` header (every browser WebSocket does)
  must come from a served origin, ``http://`` + an accepted host:port; anything else —
  another port, another host, ``null``, ``https://`` — is refused. Clients that send no
  Origin (scripts, aiohttp, curl) are not browsers' pages; they still need the token.

A refused request gets HTTP 403 with a one-line reason; :attr:`Access.refused` counts the
refusals by reason (tests, logs).
"""

from __future__ import annotations

import collections
import hmac
import ipaddress
import re
import secrets
import socket

from arlight.errors import InputError

TOKEN_RE = re.compile(r"[A-Za-z0-9_.~-]{16,256}")
"""A token set by the user: URL-safe characters (it goes into a URL as is), 16 or more."""

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
WILDCARD = ("0.0.0.0", "::", "")


def new_token() -> str:
    """A fresh random token (256 bits, URL-safe)."""
    return secrets.token_urlsafe(32)


def check_token(token: str, field: str = "--token") -> str:
    """``token`` if it is usable (URL-safe characters, 16–256 of them), else InputError."""
    if not TOKEN_RE.fullmatch(token):
        raise InputError("a token needs 16 to 256 characters from A-Z a-z 0-9 _ . ~ - "
                         f"(got {len(token)} characters)", field=field)
    return token


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is this machine only."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def split_host(value: str) -> tuple[str, int | None] | None:
    """``Host``-style ``name[:port]`` → (lower-case name, port or None); None if malformed.
    IPv6 literals are bracketed (``[::1]:8000``); the name comes back without brackets."""
    value = value.strip().lower()
    if not value:
        return None
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            return None
        name, rest = value[1:end], value[end + 1:]
        if not _is_ip(name):
            return None
        if not rest:
            return name, None
        if not rest.startswith(":"):
            return None
        port_text = rest[1:]
    else:
        name, sep, port_text = value.rpartition(":")
        if not sep:
            name, port_text = value, ""
        if not name or ":" in name:
            return None
        if not sep:
            return name, None
    if not port_text.isdigit() or len(port_text) > 5:
        return None
    port = int(port_text)
    return (name, port) if 0 < port < 65536 else None


class Access:
    """The checks of one studio launch: its token and the address it serves.

    ``Access(token, host)``; :meth:`bind` with the port once the socket is bound (port 0
    picks one). :meth:`refusal` answers None for an allowed request, else the reason.
    """

    def __init__(self, token: str, host: str = "127.0.0.1") -> None:
        self.token = token
        self.host = host.strip("[]").lower()
        self.port: int | None = None
        self.refused: collections.Counter[str] = collections.Counter()
        if self.host in WILDCARD:
            names = {"localhost"}
            for fn in (socket.gethostname, socket.getfqdn):
                try:
                    names.add(fn().lower())
                except OSError:
                    pass
            self.names = {n for n in names if n}
            self.any_ip = True
        else:
            self.names = {self.host}
            if is_loopback(self.host):
                self.names.update(LOOPBACK_NAMES)
            self.any_ip = False

    def bind(self, port: int) -> None:
        self.port = int(port)

    # ------------------------------------------------------------------ checks
    def host_ok(self, value: str | None) -> bool:
        """Whether a ``Host`` header (or an origin's host[:port]) names the served
        address."""
        if value is None or self.port is None:
            return False
        parsed = split_host(value)
        if parsed is None:
            return False
        name, port = parsed
        if port is None:
            port = 80  # what a browser leaves out
        if port != self.port:
            return False
        return name in self.names or (self.any_ip and _is_ip(name))

    def origin_ok(self, origin: str) -> bool:
        """Whether an ``Origin`` header is a served origin (``http://`` + accepted host)."""
        scheme, sep, rest = origin.strip().partition("://")
        return bool(sep) and scheme.lower() == "http" and "/" not in rest \
            and self.host_ok(rest)

    def token_ok(self, given: str | None) -> bool:
        """Constant-time comparison of a given token with the launch's."""
        if given is None:
            return False
        return hmac.compare_digest(given.encode("utf-8", "surrogatepass"),
                                   self.token.encode("utf-8"))

    def refusal(self, host: str | None, origin: str | None, token: str | None,
                needs_token: bool) -> str | None:
        """Why a request is refused (None: allowed); counted in :attr:`refused`."""
        if not self.host_ok(host):
            why = ("host", "the Host header does not name this studio's address")
        elif origin is not None and not self.origin_ok(origin):
            why = ("origin", "a page from another origin may not use the studio")
        elif needs_token and not self.token_ok(token):
            why = ("token", "missing or wrong token; open the URL (with ?token=...) that "
                   "`arlight studio` printed")
        else:
            return None
        self.refused[why[0]] += 1
        return why[1]

    # ------------------------------------------------------------------ URLs
    def base_url(self) -> str:
        """``http://host:port`` for the user (a wildcard bind prints 127.0.0.1)."""
        host = "127.0.0.1" if self.host in WILDCARD else self.host
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self.port}"

    def page_url(self) -> str:
        """The page's URL with the token, as printed (Jupyter-style)."""
        return f"{self.base_url()}/?token={self.token}"

    def ws_url(self) -> str:
        return f"{self.base_url().replace('http://', 'ws://', 1)}/ws?token={self.token}"


__all__ = ["Access", "check_token", "is_loopback", "new_token", "split_host"]
