"""The distributed near-field light of Rohmer et al. 2015 (§4–5): one light server, many
clients.

The server turns fisheye HDR frames into a :class:`~arlight.nearfield.NearFieldLight`
(VALs + SH per virtual object) and broadcasts each update over ZeroMQ in the paper's binary
layout (:mod:`~arlight.lightserver.wire`: 32 B per VAL, 108 B of SH per object, a 48-byte
versioned header); clients keep the latest state and render their own frames with it.
See docs/lightserver.md.
"""

from arlight.lightserver.client import ClientGroup, ClientStats, LightClient
from arlight.lightserver.producers import ReplayProducer, SyntheticMovingLight
from arlight.lightserver.server import LightServer, ServerStats
from arlight.lightserver.wire import WireError, WireVersionError, decode, encode

__all__ = ["ClientGroup", "ClientStats", "LightClient", "LightServer", "ReplayProducer",
           "ServerStats", "SyntheticMovingLight", "WireError", "WireVersionError", "decode",
           "encode"]
