"""The distributed near-field light of Rohmer et al. 2015 (§4–5): one light server, many
clients.

The server turns fisheye HDR frames into a :class:`~arlight.nearfield.NearFieldLight`
(VALs + SH per virtual object) and broadcasts each update over ZeroMQ in the paper's binary
layout (:mod:`~arlight.lightserver.wire`: 32 B per VAL, 108 B of SH per object, a 48-byte
versioned header); clients keep the latest state and render their own frames with it.
See docs/lightserver.md.
"""

import importlib

_EXPORTS = {"ClientGroup": "client", "ClientStats": "client", "LightClient": "client",
            "ReplayProducer": "producers", "SyntheticMovingLight": "producers",
            "LightServer": "server", "ServerStats": "server", "WireError": "wire",
            "WireVersionError": "wire", "decode": "wire", "encode": "wire"}


def __getattr__(name: str):
    """The names below, imported on first use: ``import arlight.cli`` (which mounts the
    ``serve-light``/``client`` commands) then does not load ZeroMQ and numpy."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ClientGroup", "ClientStats", "LightClient", "LightServer", "ReplayProducer",
           "ServerStats", "SyntheticMovingLight", "WireError", "WireVersionError", "decode",
           "encode"]
